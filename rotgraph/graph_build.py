"""Building a view graph and converting it: the checks of the edges a reader or a user
gives (:func:`checked_edges`: ids, weights, self-loops, rotations, information matrices),
the duplicate policies (:func:`merged_duplicates`), the one check of information matrices
(:func:`check_information`), relative rotations held as quaternions
(:class:`QuaternionRotations`), and networkx in and out. The graph itself, whose
:meth:`~rotgraph.viewgraph.ViewGraph.from_edges`, ``to_networkx`` and ``from_networkx`` call
these: :mod:`rotgraph.viewgraph`, which re-exports the public names.
"""

from __future__ import annotations

import logging

import numpy as np

from . import so3_checks, so3_rows
from .choices import DUPLICATE_POLICIES
from .errors import InputError, OptionError

__all__ = ["QuaternionRotations", "check_information", "checked_edges", "merged_duplicates", "networkx_graph",
           "edges_from_networkx", "INFORMATION_SYMMETRY_TOL", "CHECK_CHUNK"]

logger = logging.getLogger(__name__)


def _plural(k: int, word: str) -> str:
    return f"{k} {word}" + ("" if k == 1 else "s")


def _show(x) -> str:
    """An id for a message: ``7`` or ``'img.jpg'``, not ``np.int64(7)`` (numpy 2 reprs)."""
    return repr(x.item() if isinstance(x, np.generic) else x)


class QuaternionRotations:
    """Relative rotations held as unit quaternion rows ``(4, E)`` (``w >= 0``) until someone
    asks for the matrices: a reader of quaternions (10^7 edges) hands them to the solver
    without making, page-faulting and converting back 720 MB of matrices. ``rows`` must be
    unit quaternions (the reader checked and normalised them); the object takes them over
    (their signs are made ``w >= 0`` in place: no second (4, E) array)."""

    __slots__ = ("rows",)

    def __init__(self, rows: np.ndarray):
        rows = np.asarray(rows, dtype=np.float64)
        so3_rows.positive_w_rows(rows, out=rows)
        self.rows = rows

    @property
    def shape(self) -> tuple:
        return (self.rows.shape[1], 3, 3)

    def matrices(self) -> np.ndarray:
        return so3_rows.matrices_from_quaternion_rows(self.rows)


#: Relative asymmetry ``|H - H^T| / |H|`` accepted in an information matrix (text files
#: print a handful of digits); the matrix used is its symmetric part.
INFORMATION_SYMMETRY_TOL = 1e-6


#: :func:`check_information` works through the matrices in chunks of this many (temporaries in
#: cache; whole-array ones: 6 s and three 720 MB temporaries at 10^7 edges).
CHECK_CHUNK = 1 << 16


def check_information(information, n_edges: int, path=None, lines=None) -> np.ndarray:
    """The one check of per-edge rotation information matrices: (E, 3, 3), finite,
    symmetric (to :data:`INFORMATION_SYMMETRY_TOL`) and positive definite. Returns the
    symmetrised float64 array; raises :class:`InputError` naming the first bad edge (of the
    first of those three checks that fails)."""
    H = np.asarray(information, dtype=np.float64)
    if H.shape != (n_edges, 3, 3):
        raise InputError(f"expected ({n_edges}, 3, 3) information matrices, got {H.shape}", path=path)
    if not n_edges:
        return H

    def check(bad: np.ndarray, what: str) -> None:
        if bad.any():
            k = int(np.argmax(bad))
            raise InputError(f"edge information matrix {what}", path=path, line=None if lines is None else int(lines[k]))

    chunks = [slice(a, a + CHECK_CHUNK) for a in range(0, n_edges, CHECK_CHUNK)]
    for b in chunks:
        check(~np.isfinite(H[b]).all(axis=(1, 2)), "is not finite")
    out = np.empty_like(H)
    asymmetric, indefinite = np.zeros(n_edges, dtype=bool), np.zeros(n_edges, dtype=bool)
    for b in chunks:
        h = H[b]
        ht = np.swapaxes(h, 1, 2)
        size = np.abs(h).max(axis=(1, 2))
        with np.errstate(over="ignore"):  # entries near the float limit: inf, not symmetric
            asymmetric[b] = np.abs(h - ht).max(axis=(1, 2)) > INFORMATION_SYMMETRY_TOL * np.maximum(size, 1e-300)
        hs = out[b]
        np.add(0.5 * h, 0.5 * ht, out=hs)
        # Positive definite: every leading principal minor positive (Sylvester), of H scaled to a
        # largest entry of 1 (same signs; no overflow of huge entries); the 3x3 determinant by
        # cofactors (np.linalg.det's LU per matrix: 1.5 s at 10^7 edges)
        hs = hs / np.where(size > 0, size, 1.0)[:, None, None]
        with np.errstate(all="ignore"):  # entries down to 1e-320 beside 1: a zero pivot
            m1 = hs[:, 0, 0]
            m2 = hs[:, 0, 0] * hs[:, 1, 1] - hs[:, 0, 1] ** 2
            m3 = (hs[:, 0, 0] * (hs[:, 1, 1] * hs[:, 2, 2] - hs[:, 1, 2] * hs[:, 2, 1])
                  - hs[:, 0, 1] * (hs[:, 1, 0] * hs[:, 2, 2] - hs[:, 1, 2] * hs[:, 2, 0])
                  + hs[:, 0, 2] * (hs[:, 1, 0] * hs[:, 2, 1] - hs[:, 1, 1] * hs[:, 2, 0]))
            indefinite[b] = ~((m1 > 0) & (m2 > 0) & (m3 > 0))
    check(asymmetric, "is not symmetric")
    check(indefinite, "is not positive definite")
    return out


def checked_edges(ids_i, ids_j, cam2_from_cam1, weights=None, *, node_ids=None, codes: bool = False,
                  duplicates: str = "error", source_lines=None, source_path: str | None = None, information=None):
    """The checks of :meth:`~rotgraph.viewgraph.ViewGraph.from_edges` (its docstring says what
    the arguments are), in its order: the duplicate policy's name, shapes, positive finite
    weights, the ids (or ``codes``) to node positions, no self-loop, rotations, information.
    Returns ``(node_ids, edges, rel, weights, lines, information)``: the arrays of the graph
    before its duplicates are resolved (:func:`merged_duplicates`)."""
    if duplicates not in DUPLICATE_POLICIES:
        raise OptionError(f"duplicates must be one of {DUPLICATE_POLICIES}, got {duplicates!r}")
    ids_i = np.asarray(ids_i)
    ids_j = np.asarray(ids_j)
    checked = isinstance(cam2_from_cam1, QuaternionRotations)
    rel = cam2_from_cam1 if checked else np.asarray(cam2_from_cam1, dtype=np.float64)
    m = len(ids_i)
    if ids_j.shape != (m,) or rel.shape != (m, 3, 3):
        raise InputError(f"expected (E,) ids and (E,3,3) rotations, got {ids_i.shape}, {ids_j.shape}, {rel.shape}")
    w = np.ones(m) if weights is None else np.asarray(weights, dtype=np.float64)
    lines = None if source_lines is None else np.asarray(source_lines)

    def where(k: int) -> dict:
        return {"path": source_path, "line": None if lines is None else int(lines[k])}

    if w.shape != (m,):
        raise InputError(f"expected ({m},) weights, got {w.shape}")
    bad = ~(np.isfinite(w) & (w > 0))
    if bad.any():
        k = int(np.argmax(bad))
        raise InputError(f"edge weight must be positive and finite, got {w[k]}", **where(k))
    if node_ids is None:
        if codes:
            raise OptionError("codes need the node_ids they are positions in")
        node_ids = np.unique(np.concatenate([ids_i, ids_j])) if m else np.array([], dtype=np.int64)
    node_ids = np.asarray(node_ids)
    if len(node_ids) > 1 and not (node_ids[1:] > node_ids[:-1]).all():  # not sorted distinct ids
        order = np.argsort(node_ids, kind="stable")
        sorted_ids = node_ids[order]
        if (sorted_ids[1:] == sorted_ids[:-1]).any():
            raise InputError("node ids are not unique")
    else:
        order, sorted_ids = None, node_ids
    if not m:
        edges = np.zeros((0, 2), np.int64)
    elif codes:
        edges = np.stack([ids_i, ids_j], axis=1).astype(np.int64, copy=False)
        if edges.min() < 0 or edges.max() >= len(node_ids):
            raise ValueError(f"codes must be positions in the {len(node_ids)} node_ids")
    else:
        pos_i = np.searchsorted(sorted_ids, ids_i)
        pos_j = np.searchsorted(sorted_ids, ids_j)
        for pos, ids in ((pos_i, ids_i), (pos_j, ids_j)):
            pos_c = np.minimum(pos, max(len(sorted_ids) - 1, 0))
            miss = (len(sorted_ids) == 0) | (sorted_ids[pos_c] != ids)
            if np.any(miss):
                k = int(np.argmax(miss))
                raise InputError(f"edge refers to unknown camera id {_show(ids[k])}", **where(k))
        edges = np.stack([pos_i, pos_j] if order is None else [order[pos_i], order[pos_j]], axis=1).astype(np.int64)

    loops = edges[:, 0] == edges[:, 1]
    if loops.any():
        k = int(np.argmax(loops))
        raise InputError(f"self-loop: edge from camera {_show(node_ids[ids_i[k]] if codes else ids_i[k])} to itself",
                         **where(k))
    if m and not checked:
        rel = so3_checks.check_rotations(rel, path=source_path, lines=lines, label=lambda k: "relative rotation")

    info = None if information is None else check_information(information, m, source_path, lines)
    return node_ids, edges, rel, w, lines, info


def merged_duplicates(graph, policy: str):
    """The duplicate policy ``policy`` (:data:`~rotgraph.choices.DUPLICATE_POLICIES`) on
    ``graph`` (a :class:`~rotgraph.viewgraph.ViewGraph`): None when the graph stays as it is
    (no pair twice, or ``"keep"``); ``"error"`` raises :class:`InputError` naming the first
    repeat; ``"merge"`` returns ``(edges, rel, weights, first, information)`` of the merged
    graph, one edge per unordered pair (``first``: each pair's first edge in ``graph``)."""
    if graph.n_edges == 0:
        return None
    key = np.minimum(graph.edges[:, 0], graph.edges[:, 1])
    key *= graph.n_nodes
    key += np.maximum(graph.edges[:, 0], graph.edges[:, 1])
    sorted_key = np.sort(key)
    if not (sorted_key[1:] == sorted_key[:-1]).any():  # no pair twice: the common case, one sort
        return None
    del sorted_key
    uniq, first, inverse, counts = np.unique(key, return_index=True, return_inverse=True, return_counts=True)
    if policy == "keep":
        logger.info("kept %d parallel edges (%d distinct pairs)", graph.n_edges - len(uniq), len(uniq))
        return None
    if policy == "error":
        dup = counts[inverse] > 1
        # the first edge whose pair came before (the first repeat, not a first occurrence)
        k = int(np.argmax(np.arange(graph.n_edges) != first[inverse.ravel()]))
        a, b = graph.node_ids[graph.edges[k, 0]], graph.node_ids[graph.edges[k, 1]]
        raise InputError(
            f"duplicate pair ({_show(a)}, {_show(b)}): {_plural(int(dup.sum()), 'edge')} on "
            f"{_plural(int((counts > 1).sum()), 'repeated pair')} "
            "(use --duplicates merge or keep)",
            path=graph.source_path,
            line=None if graph.source_lines is None else int(graph.source_lines[k]),
        )
    # merge: orient every edge as (lo, hi), then average per pair (weighted chordal L2).
    lo, hi = np.minimum(graph.edges[:, 0], graph.edges[:, 1]), np.maximum(graph.edges[:, 0], graph.edges[:, 1])
    flip = graph.edges[:, 0] > graph.edges[:, 1]
    rel = np.where(flip[:, None, None], np.swapaxes(graph.cam2_from_cam1, 1, 2), graph.cam2_from_cam1)
    acc = np.zeros((len(uniq), 3, 3))
    np.add.at(acc, inverse, rel * graph.weights[:, None, None])
    wsum = np.bincount(inverse, weights=graph.weights, minlength=len(uniq))
    info = None
    if graph.information is not None:
        # A reversed edge R_ji = R_ij^T has the error -R_ij^T d: information R_ij^T H R_ij.
        # Independent measurements of one pair: their informations add up.
        H = np.where(flip[:, None, None], np.swapaxes(graph.cam2_from_cam1, 1, 2) @ graph.information @ graph.cam2_from_cam1,
                     graph.information)
        info = np.zeros((len(uniq), 3, 3))
        np.add.at(info, inverse, H)
    logger.info("merged %d parallel edges into %d pairs", graph.n_edges, len(uniq))
    return np.stack([lo[first], hi[first]], axis=1), so3_checks.project_to_so3(acc), wsum, first, info


def networkx_graph(graph):
    """:meth:`~rotgraph.viewgraph.ViewGraph.to_networkx` of ``graph``."""
    import networkx as nx

    lo = np.minimum(graph.edges[:, 0], graph.edges[:, 1])
    hi = np.maximum(graph.edges[:, 0], graph.edges[:, 1])
    parallel = len(np.unique(lo * max(graph.n_nodes, 1) + hi)) < graph.n_edges
    G = nx.MultiGraph() if parallel else nx.Graph()
    for k, nid in enumerate(graph.node_ids.tolist()):
        G.add_node(nid, index=k, name=None if graph.names is None else str(graph.names[k]))
    ids = graph.node_ids.tolist()
    for k, (i, j) in enumerate(graph.edges.tolist()):
        G.add_edge(ids[i], ids[j], rotation=graph.cam2_from_cam1[k], source=ids[i], weight=float(graph.weights[k]), index=k,
                   **({} if graph.information is None else {"information": graph.information[k]}))
    return G


def edges_from_networkx(G, rotation: str = "rotation", weight: str = "weight") -> dict:
    """The keyword arguments of :meth:`~rotgraph.viewgraph.ViewGraph.from_edges` for the
    networkx graph ``G`` (:meth:`~rotgraph.viewgraph.ViewGraph.from_networkx`)."""
    ii, jj, rr, ww, hh = [], [], [], [], []
    for u, v, data in G.edges(data=True):
        src = data.get("source", u)
        R = np.asarray(data[rotation], dtype=np.float64)
        if src == v:
            u, v = v, u
        ii.append(u)
        jj.append(v)
        rr.append(R)
        ww.append(float(data.get(weight, 1.0)))
        hh.append(data.get("information"))
    ids = list(G.nodes)
    names = [G.nodes[n].get("name") for n in ids]
    node_ids = np.array(ids)
    return dict(
        ids_i=np.array(ii), ids_j=np.array(jj), cam2_from_cam1=np.array(rr).reshape(-1, 3, 3), weights=np.array(ww),
        node_ids=node_ids, names=np.array(names) if all(n is not None for n in names) else None,
        information=np.array(hh, dtype=np.float64).reshape(-1, 3, 3) if hh and all(h is not None for h in hh) else None,
    )
