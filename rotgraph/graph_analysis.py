"""Graph computations on a view graph's arrays: connected components (the one home of that
computation) and the closure errors of its triangles (``rotgraph info``). The graph itself:
:mod:`rotgraph.viewgraph`, which re-exports these names.
"""

from __future__ import annotations

import numpy as np

from . import so3

__all__ = ["connected_components", "cycle_errors", "cycle_statistics"]


def connected_components(n: int, edges) -> tuple[int, np.ndarray]:
    """The connected components of the undirected graph on nodes ``0..n-1`` with ``edges``
    ``(E, 2)`` (parallel edges and self-loops allowed): ``(k, labels)``, ``labels`` (n,) in
    ``0..k-1`` numbered in the order of each component's smallest node (scipy's numbering).

    The one home of this computation: the view graph's components, the estimators' (rows of
    a problem, the gravity edges, a sparsified start graph), the rig file's rigs and the
    pose graph of ``reconstruct`` all call it.
    """
    e = np.asarray(edges).reshape(-1, 2)
    if n == 0:
        return 0, np.zeros(0, dtype=np.int64)
    if n <= 64:
        # Small graphs: reachability by squaring the reflexive adjacency matrix (cheaper
        # than building a sparse matrix); components numbered by their smallest node.
        A = np.eye(n)
        A[e[:, 0], e[:, 1]] = 1.0
        A[e[:, 1], e[:, 0]] = 1.0
        while True:
            B = np.minimum(A @ A, 1.0)
            if (B == A).all():
                break
            A = B
        first = A.argmax(axis=1)  # the smallest node reached
        root = first == np.arange(n)
        return int(root.sum()), (np.cumsum(root) - 1)[first]
    # One triangle is enough: undirected search follows stored entries both ways.
    import scipy.sparse as sp
    from scipy.sparse import csgraph

    A = sp.csr_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    k, labels = csgraph.connected_components(A, directed=False)
    return int(k), labels


def cycle_errors(graph, max_triangles: int = 100_000, seed: int = 0) -> np.ndarray:
    """Closure angles (radians) ``|log(R_ki R_jk R_ij)|`` of up to ``max_triangles`` triangles.

    Triangles are found with sparse products of adjacency rows for a random sample of the
    edges (all of them on small graphs); each triangle is counted once per sampled edge.

    Parameters
    ----------
    graph : ~rotgraph.viewgraph.ViewGraph
        The view graph; edge ``(i, j)`` carries ``R_ij = R_j R_i^T``.
    max_triangles : int, default 100000
        At most this many triangles are evaluated (a random sample beyond it).
    seed : int, default 0
        Seed of the random sample of edges and triangles.

    Returns
    -------
    (T,) float64 ndarray
        The closure angle of each triangle found, in radians (empty with fewer than 3 edges).
    """
    n = graph.n_nodes
    if graph.n_edges < 3:
        return np.zeros(0)
    lo = np.minimum(graph.edges[:, 0], graph.edges[:, 1])
    hi = np.maximum(graph.edges[:, 0], graph.edges[:, 1])
    key = lo * n + hi
    order = np.argsort(key, kind="stable")
    skey = key[order]
    A = graph.adjacency() > 0
    rng = np.random.default_rng(seed)
    m = graph.n_edges
    sample = np.arange(m) if m <= max_triangles // 4 else rng.choice(m, max_triangles // 4, replace=False)
    i, j = graph.edges[sample, 0], graph.edges[sample, 1]
    common = A[i].multiply(A[j]).tocoo()
    e_idx, k = common.row, common.col
    if len(k) > max_triangles:
        pick = rng.choice(len(k), max_triangles, replace=False)
        e_idx, k = e_idx[pick], k[pick]
    i, j = i[e_idx], j[e_idx]
    R_ij = graph.cam2_from_cam1[sample[e_idx]]
    R_ij = np.where((graph.edges[sample[e_idx], 0] == i)[:, None, None], R_ij, np.swapaxes(R_ij, 1, 2))

    def oriented(a, b):
        kk = np.minimum(a, b) * n + np.maximum(a, b)
        e = order[np.searchsorted(skey, kk)]
        R = graph.cam2_from_cam1[e]
        return np.where((graph.edges[e, 0] == a)[:, None, None], R, np.swapaxes(R, 1, 2))

    loop = oriented(k, i) @ oriented(j, k) @ R_ij
    return so3.angle(loop)


def cycle_statistics(cycle_deg: np.ndarray) -> dict:
    """Summary of triangle closure errors in degrees (:func:`cycle_errors`, converted):
    ``n_triangles_checked`` and, when there are any, the median, mean and 90th percentile
    and the fractions under 2 and over 10 degrees (``rotgraph info``)."""
    c = np.asarray(cycle_deg, dtype=np.float64)
    out: dict = {"n_triangles_checked": int(len(c))}
    if len(c):
        out.update(
            cycle_error_median_deg=float(np.median(c)),
            cycle_error_mean_deg=float(c.mean()),
            cycle_error_p90_deg=float(np.percentile(c, 90)),
            cycle_under_2deg=float((c < 2).mean()),
            cycle_over_10deg=float((c > 10).mean()),
        )
    return out
