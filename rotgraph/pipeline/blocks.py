"""The worker side of the distributed solve (:mod:`rotgraph.pipeline.distributed`): a view
graph cut into blocks of cameras, each block's edges held by one Dask worker.

Every function here is a pure function of its arguments (numpy arrays, and the
:class:`Shard` objects built from the input's Parquet parts): Dask may run it again on
another worker when the one that held its result died, and gets the same result. The
client holds camera-sized arrays only (rotations (4, n), updates (n, 3), degrees); every
edge-sized array stays in a :class:`Shard` on a worker.

* :func:`read_ids`, :func:`union_ids`, :func:`part_codes`: the camera ids (each part's,
  then merged pairwise) and each part's edges as camera codes, from the ``(i, j)`` columns
  alone; :mod:`rotgraph.pipeline.partition` reduces them to the plan (the largest connected
  component and its cut into blocks) part by part.
* :func:`route`, :func:`make_shard`: each part's edges sent to the shard that holds them:
  block ``b``'s own edges to shard ``b``, the edges between blocks ``b`` and ``c`` to one of
  the two (:func:`holders`: all of a pair in one place, the loads balanced).
* :func:`solve_block`: a block's own edges solved by :func:`~rotgraph.estimators.rotation_averaging.average_rotations`
  (the whole adaptive method), in the block's own gauge.
* :func:`gauge_pairs`: the L1 mean of ``W_c W_b^T`` over the edges between blocks ``b``
  and ``c`` (each edge measures it: ``R_j^T R_ij R_i`` in the blocks' gauges).
* :func:`sample`, :func:`weighted_state`, :func:`state_rhs`, :func:`state_matvec`,
  :func:`finish`: the refinement's tasks, in :mod:`rotgraph.pipeline.blocks_irls` (re-exported).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import so3_rows
from ..errors import InputError, UnsolvableError
from ..estimators.laplacian import make_laplacian
from ..estimators.leverage import degree_leverage, isotropic_precision, mean_variance_precision
from ..estimators.residuals import EdgeSystem, error_quaternions
from .blocks_irls import State, _sample_rows, finish, model_cost, sample, state_matvec, state_rhs, weighted_degrees, weighted_state
from .partition import PARTITION_DEGREE, PARTITIONERS, holders, partition  # noqa: F401  (moved: stage 1)

__all__ = ["read_ids", "union_ids", "codes", "part_codes", "partition", "holders", "route", "pick", "make_shard", "Shard", "solve_block",
           "gauge_pairs", "hold", "add", "shard_edges", "has_information", "predict_missing", "orphan_predictions", "reseed", "information_stats", "with_information", "sample", "model_cost", "weighted_state", "state_rhs", "state_matvec", "weighted_degrees",
           "finish", "PARTITIONERS"]

# --------------------------------------------------------------------------- ids and partition


def read_ids(part: str) -> np.ndarray:
    """The ``(i, j)`` ids of one part's edges, (2, m) int64. The distributed solve reads
    non-negative integer ids (string ids: an :class:`InputError` naming the part)."""
    from ..io.edges_binary import read_parquet_part

    cols = read_parquet_part(part, ("i", "j"))
    ij = [cols["i"], cols["j"]]
    if any(a.dtype.kind not in "iu" for a in ij) or any(len(a) and int(a.min()) < 0 for a in ij):
        raise InputError("the distributed solve reads non-negative integer camera ids; this part has names "
                         "(solve it in one process, without --workers / --scheduler)", part)
    return np.stack(ij).astype(np.int64, copy=False)


def union_ids(*ijs: np.ndarray) -> np.ndarray:
    """The sorted distinct camera ids of all parts (the single-process reader's node order)."""
    from ..io.table_columns import unique

    return unique(np.concatenate([a.ravel() for a in ijs]))


#: Camera ids up to this many times the number of cameras are coded through a lookup table
#: (:func:`codes`; its 4 bytes an id are no more than 32 bytes a camera).
TABLE_SPREAD = 8


def codes(ids: np.ndarray, values: np.ndarray) -> np.ndarray:
    """The positions of ``values`` (each one of ``ids``) in the sorted distinct camera ids
    ``ids``: int32 (int64 from 2^31 cameras). Ids no larger than :data:`TABLE_SPREAD` times the
    cameras (dense numberings, as SfM tools write) are looked up in a table (a gather: the 2 x 10^7
    ids of 10^7 edges in 0.06 s against 2.9-4.9 s for the binary search of random ids, most of
    the route stage); others by ``np.searchsorted``."""
    dtype = np.int32 if len(ids) < 2**31 else np.int64
    if len(ids) and int(ids[0]) >= 0 and int(ids[-1]) < TABLE_SPREAD * len(ids) + 1024:
        table = np.empty(int(ids[-1]) + 1, dtype=dtype)  # (only the entries of ids are read)
        table[ids] = np.arange(len(ids), dtype=dtype)
        return table[values]
    return np.searchsorted(ids, values).astype(dtype)


def part_codes(ij: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """One part's ``(i, j)`` ids as camera codes (:func:`codes`), (2, m) int32 (int64 from 2^31
    cameras), 8 bytes an edge: what :mod:`rotgraph.pipeline.partition` reduces part by part."""
    return codes(ids, ij)


# --------------------------------------------------------------------------- routing


def route(part: str, part_index: int, ids: np.ndarray, plan: dict, use_information: bool) -> list[dict]:
    """One part's edges of the solved component, split by the shard that holds them
    (``plan["holder"]``): a list of one dict per shard (``i``, ``j`` camera codes (int32), ``q``
    (4, k) relative rotations, ``h`` (k, 3, 3) their information matrices or None, ``part``,
    ``row`` for messages). (The weight column is not read: the cost's weights are 1,
    ``use_weights`` being off.)"""
    from ..io.edges_binary import read_parquet_part

    cols = read_parquet_part(part)
    info = _part_information(cols, part) if use_information else None
    ci, cj = codes(ids, cols["i"]), codes(ids, cols["j"])
    loop = np.flatnonzero(ci == cj)
    if len(loop):
        raise InputError(f"edge {int(loop[0])} (0-based): self-loop on camera {ids[ci[loop[0]]]}", part)
    bi, bj = plan["block"][ci], plan["block"][cj]
    keep = bi >= 0
    dest = np.where(keep, plan["holder"][np.maximum(bi, 0), np.maximum(bj, 0)], -1)
    order = np.argsort(dest, kind="stable")
    starts = np.searchsorted(dest[order], np.arange(len(plan["holder"]) + 1))
    out = []
    for s in range(len(plan["holder"])):
        sel = order[starts[s]:starts[s + 1]]
        out.append({"i": ci[sel], "j": cj[sel], "q": cols["q"][:, sel], "part": part_index, "row": sel.astype(np.int32),
                    "h": None if info is None else info[sel]})
    return out


def _part_information(cols: dict, part: str) -> np.ndarray | None:
    """A part's information matrices (m, 3, 3) from its columns ``h_xx .. h_zz``, checked as
    one process checks them (:func:`~rotgraph.graph_build.check_information`: the error names
    the part and the edge's 1-based row), or None without them."""
    from ..graph_build import check_information
    from ..io.graphs import INFORMATION_TEXT_COLUMNS
    from ..io.tables import symmetric_from_upper

    if INFORMATION_TEXT_COLUMNS[0] not in cols:
        return None
    m = len(cols["i"])
    return check_information(symmetric_from_upper([cols[c] for c in INFORMATION_TEXT_COLUMNS], 3), m, part, np.arange(1, m + 1))


def hold(a):
    """``a`` itself: a task whose result is the client's camera-sized array (the rotations, a
    conjugate-gradient direction), recomputable from the task as scattered data is not."""
    return a


def add(a, b):
    """``a + b`` of two arrays, or of two tuples of arrays item by item (one node of the
    client's tree reductions: the shards' sums added up on the workers)."""
    if isinstance(a, tuple):
        return tuple(x + y for x, y in zip(a, b))
    return a + b


def shard_edges(shard: "Shard") -> int:
    """How many edges ``shard`` holds (what the client asks to know that it is built)."""
    return shard.n_edges


def has_information(shard: "Shard") -> bool:
    """Whether ``shard``'s edges carry information matrices."""
    return shard.system.information is not None


def pick(pieces: list, s: int) -> dict:
    """Shard ``s``'s piece of a part (a task of its own: a shard fetches its pieces only)."""
    return pieces[s]


@dataclass
class Shard:
    """The edges one worker holds: shard ``index`` (block ``index``'s own edges and the cut
    edges of the pairs it holds), in the whole graph's camera codes (``n`` cameras, the
    gauge fixed at ``anchor``), with their :class:`~rotgraph.estimators.residuals.EdgeSystem`, the pattern of
    their part of the anchored Laplacian, each edge's leverage in the whole graph and the
    blocks of its ends."""

    index: int
    n: int
    anchor: int
    edges: np.ndarray  # (E, 2) int32 (int64 from 2^31 cameras)
    qrel: np.ndarray  # (4, E)
    bi: np.ndarray  # (E,) block of each edge's tail
    bj: np.ndarray  # (E,) block of its head
    lev: np.ndarray  # (E,) leverage in the whole graph (degree_leverage)
    system: EdgeSystem
    lap: object  # AnchoredLaplacian of these edges (cg): the pattern every iteration's matrix shares
    rough: EdgeSystem | None = None  # with information matrices: the isotropic view (system.isotropic())
    iso: np.ndarray | None = None  # (E,) with information matrices: each edge's normalised isotropic precision

    @property
    def n_edges(self) -> int:
        return len(self.edges)

    def view(self, spec: tuple | None) -> EdgeSystem:
        """The edge system a step of ``spec`` weighs: with information matrices the isotropic
        view for the stages that find the basin (a spec ending in ``"rough"``: L1, graduated; as
        in one process, :func:`~rotgraph.estimators.adaptive._isotropic_stages`), else the
        3x3 blocks."""
        return self.rough if self.rough is not None and spec and spec[-1] == "rough" else self.system

    def __sizeof__(self) -> int:  # what Dask counts when it places tasks and moves data
        arrays = [self.edges, self.qrel, self.bi, self.bj, self.lev, *vars(self.system).values(),
                  *getattr(self.lap, "pattern", ())]
        return int(sum(a.nbytes for a in arrays if isinstance(a, np.ndarray))) + 1000


def _duplicates(edges: np.ndarray, n: int, ids: np.ndarray, pieces) -> None:
    """An :class:`InputError` for two edges between the same cameras (the single-process
    default ``duplicates="error"``), naming both parts and rows."""
    lo, hi = np.minimum(edges[:, 0], edges[:, 1]).astype(np.int64), np.maximum(edges[:, 0], edges[:, 1])
    key = lo * n + hi
    order = np.argsort(key, kind="stable")
    same = np.flatnonzero(key[order][1:] == key[order][:-1])
    if not len(same):
        return
    a, b = order[same[0]], order[same[0] + 1]
    part = np.concatenate([np.full(len(p["i"]), p["part"]) for p in pieces])
    row = np.concatenate([p["row"] for p in pieces])
    raise InputError(f"cameras {ids[lo[a]]} and {ids[hi[a]]} are joined by more than one edge (part {int(part[a])} row "
                     f"{int(row[a])}, part {int(part[b])} row {int(row[b])}, 0-based); the distributed solve takes one "
                     "edge a pair of cameras")


def make_shard(index: int, ids: np.ndarray, plan: dict, *pieces: dict) -> Shard:
    """Shard ``index`` from its piece of every part (:func:`route`)."""
    n, anchor = len(ids), plan["anchor"]
    edges = np.empty((sum(len(p["i"]) for p in pieces), 2), dtype=pieces[0]["i"].dtype if pieces else np.int32)
    np.concatenate([p["i"] for p in pieces], out=edges[:, 0])
    np.concatenate([p["j"] for p in pieces], out=edges[:, 1])
    _duplicates(edges, n, ids, pieces)
    qrel = np.concatenate([p["q"] for p in pieces], axis=1) if pieces else np.zeros((4, 0))
    given = {p["h"] is not None for p in pieces if len(p["i"])}
    if len(given) > 1:
        raise InputError("some Parquet parts have the information columns h_xx .. h_zz and others not "
                         "(every part the same columns)")
    info = np.concatenate([p["h"] for p in pieces if len(p["i"])]) if given == {True} else None
    block = plan["block"]
    lev = degree_leverage(edges, plan["degree"])
    system = EdgeSystem(n, edges, qrel, anchor, information=info)
    lap = make_laplacian(n, edges, anchor, "cg")
    return Shard(index, n, anchor, edges, system.qrel, block[edges[:, 0]], block[edges[:, 1]], lev, system, lap)


def information_stats(shard: Shard, exponent: float, c_median: float, total_edges: int, seed: int) -> tuple:
    """What the information's normalisation needs of this shard's edges, their information
    times ``(c_e / c_median)^(2 exponent)`` (:func:`with_information`): ``(degrees (n,) weighted
    by each edge's isotropic precision, the isotropic precisions of the shard's rows of the fit
    sample)``."""
    if shard.system.information is None:  # (a shard without edges)
        return np.zeros(shard.n), np.zeros(0)
    iso = isotropic_precision(_information(shard, exponent, c_median))
    deg = np.bincount(shard.edges[:, 0], weights=iso, minlength=shard.n) + np.bincount(shard.edges[:, 1], weights=iso, minlength=shard.n)
    return deg, iso[_sample_rows(shard, total_edges, seed)]


def with_information(shard: Shard, exponent: float, c_median: float, degrees: np.ndarray, scale: float,
                     cap: bool = True) -> Shard:
    """``shard`` with its information matrices times ``(c_e / c_median)^(2 exponent)``
    (``c_e``: :func:`~rotgraph.estimators.leverage.mean_variance_precision`; one process's
    ``solve_again``), normalised by ``scale`` (one over the median isotropic precision, as one
    process's), each edge's leverage from the whole graph's ``degrees`` weighted by isotropic
    precisions (:func:`information_stats`, summed), and its isotropic view (``cap``: capped at
    the whole graph's median precision, 1 once normalised; not for the solve again after the
    information test, as in one process: :meth:`~rotgraph.estimators.residuals.EdgeSystem.isotropic`)."""
    from dataclasses import replace

    if shard.system.information is None:  # (a shard without edges)
        return shard
    info = _information(shard, exponent, c_median)
    system = EdgeSystem(shard.n, shard.edges, shard.qrel, shard.anchor, information=info, information_scale=scale)
    iso = isotropic_precision(info)
    return replace(shard, system=system, rough=system.isotropic(cap, median=1.0), iso=iso * scale,
                   lev=degree_leverage(shard.edges, degrees, iso))


def _information(shard: Shard, exponent: float, c_median: float) -> np.ndarray:
    """The shard's information matrices as given, times ``(c_e / c_median)^(2 exponent)``."""
    info = shard.system.information
    if exponent == 0.0:
        return info
    return info * ((mean_variance_precision(info) / c_median) ** (2.0 * exponent))[:, None, None]


# --------------------------------------------------------------------------- blocks and their gauges


def solve_block(shard: Shard, opts) -> dict:
    """Block ``shard.index``'s own edges (its induced subgraph) solved in one process by
    :func:`~rotgraph.estimators.rotation_averaging.average_rotations` with ``opts``: ``nodes`` (global codes of
    the cameras solved), ``q`` (4, k) their rotations in the block's gauge, and what the
    block's solve reports. A block that cannot be solved gives no camera (the others' edges
    place them)."""
    from ..graph_build import QuaternionRotations
    from ..viewgraph import ViewGraph
    from ..estimators.rotation_averaging import average_rotations

    own = np.flatnonzero((shard.bi == shard.index) & (shard.bj == shard.index))
    out = {"block": shard.index, "n_edges": int(len(own)), "nodes": np.zeros(0, np.int64), "q": np.zeros((4, 0)),
           "iterations": 0, "model": None, "n_outliers": 0, "seconds": 0.0}
    if not len(own):
        return out
    nodes, local = np.unique(shard.edges[own].ravel(), return_inverse=True)
    local = local.reshape(-1, 2)
    info = shard.system.information
    graph = ViewGraph.from_edges(local[:, 0], local[:, 1], QuaternionRotations(shard.qrel[:, own].copy()), None,
                                 node_ids=np.arange(len(nodes)), codes=True, information=None if info is None else info[own])
    try:
        res = average_rotations(graph, opts)
    except UnsolvableError:
        return out
    solved = np.flatnonzero(res.solved)
    out.update(nodes=nodes[solved], q=so3_rows.quaternion_rows_from_matrices(res.cam_from_world[solved]),
               iterations=int(res.iterations), model=res.diagnostics.get("model"), n_outliers=int(res.n_outliers),
               seconds=float(res.seconds), n_cameras=int(len(nodes)))
    return out


#: Cut edges a shard measures the blocks' gauges on at most (a fixed random subset): the L1
#: mean of tens of thousands of measurements of one rotation is as good as of millions (its
#: error ~ sigma / sqrt(count), and the refinement corrects it), and the means' work arrays
#: (16 numbers a measurement) stay small: at 10^7 edges all 1.9 million cut edges of a shard
#: had taken 300 MB more than any other stage.
GAUGE_SAMPLE = 100_000


def gauge_pairs(shard: Shard, q: np.ndarray, n_blocks: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What the cut edges of ``shard`` say of the blocks' gauges: with the block solutions
    ``q`` (4, n) (NaN: not solved), the camera ``i`` of block ``b`` is ``R_i = Q_i W_b`` in
    a common gauge, so an edge's ``Q_j^T R_ij Q_i`` measures ``W_c W_b^T`` (the relative
    rotation of the pair of blocks, in rotgraph's edge convention). Returns ``(pairs (K, 2)
    with b < c, their geodesic L1 means (4, K), counts (K,))``."""
    from ..estimators.single_iterative import geodesic_l1_means

    cut = np.flatnonzero(shard.bi != shard.bj)
    if len(cut) > GAUGE_SAMPLE:  # a fixed random subset: the means' memory stays small
        cut = np.sort(np.random.default_rng(shard.index).choice(cut, GAUGE_SAMPLE, replace=False))
    i, j = shard.edges[cut, 0], shard.edges[cut, 1]
    ok = np.isfinite(q[0, i]) & np.isfinite(q[0, j])
    cut, i, j = cut[ok], i[ok], j[ok]
    if not len(cut):
        return np.zeros((0, 2), np.int64), np.zeros((4, 0)), np.zeros(0, np.int64)
    m = error_quaternions(q[:, i], q[:, j], shard.qrel[:, cut])
    b, c = shard.bi[cut].astype(np.int64), shard.bj[cut].astype(np.int64)
    flip = b > c  # the pair (c, b) measured: W_b W_c^T, the inverse
    m[1:, flip] *= -1.0
    key = np.minimum(b, c) * n_blocks + np.maximum(b, c)
    order = np.argsort(key, kind="stable")
    keys, starts, counts = np.unique(key[order], return_index=True, return_counts=True)
    means = geodesic_l1_means(m[:, order], np.r_[starts, len(order)])
    return np.stack([keys // n_blocks, keys % n_blocks], axis=1), means, counts


def predict_missing(shard: Shard, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For cameras without a rotation (NaN in ``q``) that have an edge to one with: one
    prediction each through such an edge (``R_j = R_ij R_i``), ``(cameras, quaternions (4, k))``."""
    known = np.isfinite(q[0])
    i, j = shard.edges[:, 0], shard.edges[:, 1]
    fwd = np.flatnonzero(known[i] & ~known[j])
    back = np.flatnonzero(known[j] & ~known[i])
    cams = np.r_[j[fwd], i[back]]
    pred = np.concatenate([so3_rows.qmul_rows(shard.qrel[:, fwd], q[:, i[fwd]]),
                           so3_rows.qmul_rows(so3_rows.qconj_rows(shard.qrel[:, back]), q[:, j[back]])], axis=1)
    cams, first = np.unique(cams, return_index=True)
    return cams, pred[:, first]


def orphan_predictions(shard: Shard, q: np.ndarray, orphans: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The predictions of the cameras ``orphans`` through this shard's edges to their
    neighbours at ``q`` (:func:`~rotgraph.estimators.adaptive.neighbour_predictions`)."""
    from ..estimators.adaptive import neighbour_predictions

    return neighbour_predictions(q, shard.edges, shard.qrel, orphans)


def reseed(q: np.ndarray, orphans: np.ndarray, *pieces: tuple) -> tuple[np.ndarray, int]:
    """``q`` with the cameras ``orphans`` re-seeded from their predictions on every shard
    (:func:`orphan_predictions`, one piece a shard: a camera's edges may be on several):
    :func:`~rotgraph.estimators.adaptive.reseeded`."""
    from ..estimators.adaptive import reseeded

    return reseeded(q, orphans, np.concatenate([p[0] for p in pieces]), np.concatenate([p[1] for p in pieces], axis=1))
