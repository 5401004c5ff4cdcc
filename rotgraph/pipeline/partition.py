"""Stage 1 of the distributed solve (:mod:`rotgraph.pipeline.distributed`): the plan (the
largest connected component, its degrees, its cut into blocks) from the parts' camera codes,
without any process holding every edge.

Each part is reduced on its own worker to camera-sized arrays, and these are merged pairwise
on the workers (a tree of log2 P levels, as the solve's sums are):

* :func:`summarise`: a part's degrees (n,) and a spanning forest of its edges (at most
  n - 1 of them: scipy's minimum spanning tree, every weight one); :func:`merge` adds two
  parts' degrees and reduces the union of their forests to a forest again, so the root of
  the tree holds a spanning forest of the whole graph: its components are the graph's,
  exactly (:func:`component`: the largest, the one solved, as in one process).
* :func:`sample`: a part's share of the edges the partitioner sees: the component's edges
  when it has at most :data:`PARTITION_DEGREE` / 2 a camera, else that many in all, each part
  a fixed random draw (seeded by its index) in proportion to its edges in the component.
  :func:`cut` cuts the component's cameras on the union of the samples (METIS by pymetis where
  installed, else reverse Cuthill-McKee runs: :func:`_split`), the only task that sees more
  than camera-sized arrays: the sample, at most ``PARTITION_DEGREE / 2`` edges a camera.
* :func:`pair_counts`: a part's edges within and between the blocks, (B, B), summed pairwise;
  :func:`make_plan` puts the plan together (:func:`holders`: which shard holds each pair).

:func:`plan_tasks` is the one sequence of these tasks, run by a ``submit`` that schedules them
on Dask (the solve) or runs them at once (:func:`partition`: one process, the same plan).
Every task is a pure function of its arguments: Dask may run it again on another worker.
"""

from __future__ import annotations

import numpy as np

__all__ = ["partition", "plan_tasks", "pairwise", "summarise", "merge", "component", "sample", "cut", "pair_counts",
           "make_plan", "holders", "PARTITION_DEGREE", "PARTITIONERS"]

#: How the cameras are cut into blocks: METIS (pymetis, when installed) or the fallback.
PARTITIONERS = ("metis", "rcm")

#: The partitioner sees at most this many edges a camera (a random subset of a denser graph's
#: edges, the same for every run): METIS's memory grows with the edges (at 10^7 edges it needs
#: more than a worker of 35 % of the single-process solve has), the cut hardly changes.
PARTITION_DEGREE = 24

#: The seed of the partitioner's sample (with the part's index: each part its own draw).
SAMPLE_SEED = 0


def pairwise(combine, items: list):
    """``items`` reduced pairwise by ``combine(a, b)``: a tree of ceil(log2 P) levels (on Dask,
    ``combine`` submits a task: no worker receives more than two items at once)."""
    items = list(items)
    while len(items) > 1:
        items = [combine(*items[k:k + 2]) if k + 1 < len(items) else items[k] for k in range(0, len(items), 2)]
    return items[0]


def _adjacency(n: int, i: np.ndarray, j: np.ndarray):
    """The symmetric 0/1 adjacency (CSR, int32 indices where they fit) of the edges ``i - j``."""
    import scipy.sparse as sp

    A = sp.coo_matrix((np.ones(2 * len(i), dtype=np.int8), (np.concatenate([i, j]), np.concatenate([j, i]))),
                      shape=(n, n)).tocsr()
    A.sum_duplicates()
    return A


def _forest(n: int, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """A spanning forest (2, f) of the edges ``i - j`` (no self-loops) on ``n`` cameras: scipy's
    minimum spanning tree with every weight one, f = n minus the components <= n - 1 edges
    whose components are those of the edges."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import minimum_spanning_tree

    A = sp.csr_matrix((np.ones(len(i)), (i, j)), shape=(n, n))  # (duplicates summed: still non-zero)
    T = minimum_spanning_tree(A).tocoo()
    return np.stack([T.row, T.col]).astype(i.dtype, copy=False)


def _edges(codes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A part's ``(i, j)`` codes without self-loops (those are an error of the part, :func:`~rotgraph.pipeline.blocks.route`)."""
    i, j = codes[0], codes[1]
    loop = i == j
    return (i[~loop], j[~loop]) if loop.any() else (i, j)


def summarise(codes: np.ndarray, ids: np.ndarray) -> dict:
    """One part's camera-sized summary: ``degree`` (n,) int64 (its edges at each camera),
    ``forest`` (2, f <= n - 1) a spanning forest of its edges, ``n_input_edges``."""
    n = len(ids)
    i, j = _edges(codes)
    degree = np.bincount(i, minlength=n) + np.bincount(j, minlength=n)
    return {"degree": degree, "forest": _forest(n, i, j), "n_input_edges": int(codes.shape[1])}


def merge(a: dict, b: dict) -> dict:
    """Two summaries' union (:func:`summarise`): degrees added, the union of the two forests
    reduced to a spanning forest again (its components: those of both parts' edges)."""
    f = np.concatenate([a["forest"], b["forest"]], axis=1)
    return {"degree": a["degree"] + b["degree"], "forest": _forest(len(a["degree"]), f[0], f[1]),
            "n_input_edges": a["n_input_edges"] + b["n_input_edges"]}


def component(summary: dict) -> dict:
    """The largest connected component of the whole graph from its merged summary: ``keep``
    (n,) its cameras, ``degree`` (n,) float64 (0 outside it), ``anchor`` (its camera of highest
    degree), ``n_components``, ``n_edges`` (its edges), ``n_input_edges``."""
    from scipy.sparse.csgraph import connected_components

    degree, f = summary["degree"], summary["forest"]
    n_components, labels = connected_components(_adjacency(len(degree), f[0], f[1]), directed=False)
    keep = labels == int(np.argmax(np.bincount(labels)))
    inside = np.where(keep, degree, 0)
    return {"keep": keep, "degree": inside.astype(np.float64), "anchor": int(np.argmax(inside)),
            "n_components": int(n_components), "n_edges": int(inside.sum()) // 2, "n_input_edges": summary["n_input_edges"]}


def sample(codes: np.ndarray, index: int, base: dict) -> np.ndarray:
    """Part ``index``'s edges the partitioner sees, (2, k) codes: its edges in the component
    (``base``, :func:`component`), all of them when the component has at most
    :data:`PARTITION_DEGREE` / 2 edges a camera, else their share of that many (in proportion
    to the part's edges in the component; a fixed random draw, seeded by ``index``)."""
    i, j = _edges(codes)
    rows = np.flatnonzero(base["keep"][i])
    target = PARTITION_DEGREE * int(base["keep"].sum()) // 2
    if base["n_edges"] > target:
        k = int(round(target * len(rows) / base["n_edges"]))
        rows = rows[np.sort(np.random.default_rng([SAMPLE_SEED, index]).choice(len(rows), k, replace=False))]
    return np.stack([i[rows], j[rows]])


def _split(A, n_blocks: int) -> tuple[np.ndarray, str]:
    """Block labels (m,) of the m cameras of the symmetric adjacency ``A`` (CSR, no self
    loops) and the partitioner's name: METIS's k-way cut (pymetis) where installed, else
    the reverse Cuthill-McKee order cut into ``n_blocks`` runs of equal size (neighbours in
    that order are close in the graph: few cut edges on graphs with locality)."""
    m = A.shape[0]
    if n_blocks <= 1 or m <= n_blocks:
        return np.minimum(np.arange(m), n_blocks - 1).astype(np.int32) if m <= n_blocks else np.zeros(m, np.int32), "none"
    try:
        import pymetis
    except ImportError:
        pymetis = None
    if pymetis is not None:
        if hasattr(pymetis, "CSRAdjacency"):  # pymetis 2025.2 on (the xadj / adjncy keywords are deprecated)
            _, membership = pymetis.part_graph(n_blocks, adjacency=pymetis.CSRAdjacency(A.indptr, A.indices))
        else:
            _, membership = pymetis.part_graph(n_blocks, xadj=A.indptr, adjncy=A.indices)
        labels = np.asarray(membership, dtype=np.int32)
        if len(np.unique(labels)) == n_blocks:
            return labels, "metis"
    from scipy.sparse.csgraph import reverse_cuthill_mckee

    order = reverse_cuthill_mckee(A, symmetric_mode=True)
    labels = np.empty(m, dtype=np.int32)
    labels[order] = (np.arange(m) * n_blocks) // m
    return labels, "rcm"


def cut(base: dict, n_blocks: int, *samples: np.ndarray) -> dict:
    """The component's cameras (``base``, :func:`component`) cut into ``n_blocks`` blocks on
    the union of the parts' samples (:func:`sample`): ``block`` (n,) int32 (-1 outside the
    component) and ``partitioner`` (:func:`_split`)."""
    keep = base["keep"]
    i = np.concatenate([s[0] for s in samples])
    j = np.concatenate([s[1] for s in samples])
    local = (np.cumsum(keep) - 1).astype(i.dtype)
    block = np.full(len(keep), -1, dtype=np.int32)
    block[keep], partitioner = _split(_adjacency(int(keep.sum()), local[i], local[j]), n_blocks)
    return {"block": block, "partitioner": partitioner}


def pair_counts(codes: np.ndarray, blocks: dict, n_blocks: int) -> np.ndarray:
    """A part's edges within (diagonal) and between (upper triangle) the blocks (``blocks``,
    :func:`cut`), (B, B) int64; edges outside the component are not counted."""
    i, j = _edges(codes)
    bi, bj = blocks["block"][i], blocks["block"][j]
    inside = bi >= 0
    bi, bj = bi[inside], bj[inside]
    key = np.minimum(bi, bj).astype(np.int64) * n_blocks + np.maximum(bi, bj)
    return np.bincount(key, minlength=n_blocks * n_blocks).reshape(n_blocks, n_blocks)


def holders(counts: np.ndarray) -> np.ndarray:
    """``(B, B)``: the shard that holds the edges between blocks ``b`` and ``c`` (symmetric):
    block ``b``'s own edges shard ``b``; each pair of blocks, largest first, the one of its
    two blocks' shards holding fewer edges so far. ``counts[b, c]`` (b <= c): edges of the pair."""
    B = len(counts)
    holder = np.zeros((B, B), dtype=np.int32)
    load = np.diag(counts).astype(np.float64).copy()
    holder[np.arange(B), np.arange(B)] = np.arange(B)
    pairs = [(int(counts[b, c]), b, c) for b in range(B) for c in range(b + 1, B)]
    for k, b, c in sorted(pairs, reverse=True):
        s = b if load[b] <= load[c] else c
        holder[b, c] = holder[c, b] = s
        load[s] += k
    return holder


def make_plan(base: dict, blocks: dict, counts: np.ndarray) -> dict:
    """The plan of the distributed solve: ``block`` (n,) each camera's block (-1 outside the
    largest connected component, which alone is solved, as in one process), ``degree`` (n,)
    in it, ``anchor`` (its camera of highest degree, the spanning tree's root in one process),
    ``n_components``, ``counts`` (B, B) edges within (diagonal) and between blocks (upper
    triangle), ``holder`` (:func:`holders`), ``partitioner``, ``n_edges`` (of the component),
    ``n_input_edges``, ``cut_edges``."""
    return {"block": blocks["block"], "degree": base["degree"], "anchor": base["anchor"],
            "n_components": base["n_components"], "counts": counts, "holder": holders(counts),
            "partitioner": blocks["partitioner"], "n_edges": base["n_edges"], "n_input_edges": base["n_input_edges"],
            "cut_edges": int(counts.sum() - np.trace(counts))}


def plan_tasks(submit, ids, n_blocks: int, codes: list):
    """The tasks of stage 1 from the parts' camera codes (``codes``: one (2, m) array or future
    a part, :func:`~rotgraph.pipeline.blocks.part_codes`), each by ``submit(fn, *args)`` (Dask's
    ``client.submit``, or a call): the parts' summaries merged pairwise, the component, the
    parts' samples, the cut, the parts' block-pair counts summed pairwise, the plan
    (:func:`make_plan`; what ``submit`` returns for it)."""
    summary = pairwise(lambda a, b: submit(merge, a, b), [submit(summarise, c, ids) for c in codes])
    base = submit(component, summary)
    blocks = submit(cut, base, n_blocks, *[submit(sample, c, k, base) for k, c in enumerate(codes)])
    counts = pairwise(lambda a, b: submit(np.add, a, b), [submit(pair_counts, c, blocks, n_blocks) for c in codes])
    return submit(make_plan, base, blocks, counts)


def partition(ids: np.ndarray, n_blocks: int, *codes: np.ndarray) -> dict:
    """The plan (:func:`make_plan`) of the distributed solve in one process: the tasks of
    :func:`plan_tasks` run one after another (what the solve's workers compute)."""
    return plan_tasks(lambda fn, *args: fn(*args), ids, n_blocks, list(codes))
