"""Spanning-tree initialisation of multiple rotation averaging.

A maximum spanning tree of the view graph (edge weights: confidence, e.g. inlier counts),
rotations chained from the root by pointer jumping: O(n log depth), no recursion. Small
graphs use Kruskal's algorithm in plain Python, large ones ``scipy.sparse.csgraph``; both
break ties the same way (by node pair, then by edge order), so they give the same tree.
"""

from __future__ import annotations

import numpy as np

from .. import so3_rows
from ..errors import UnsolvableError

__all__ = ["spanning_tree_rotations"]

# Up to this many edges the spanning tree is found in plain Python (Kruskal's algorithm):
# 13 us on 66 edges, 0.46 ms on 1834 (n = 300), where scipy's minimum_spanning_tree takes
# about 0.6 ms whatever the size.
MST_PYTHON_MAX_EDGES = 2000


def _dedupe_pairs(n: int, edges: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Indices of one edge per unordered pair, in pair order: the heaviest (ties: the first)."""
    key = np.minimum(edges[:, 0], edges[:, 1]) * n + np.maximum(edges[:, 0], edges[:, 1])
    if weights.min() == weights.max():
        # Equal weights (e.g. an edge list without them): one quicksort of the pairs and the
        # first edge of each (10^7 edges: 2.2 s instead of the three-key lexsort's 5.3).
        order = np.argsort(key)
        key = key[order]
        start = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
        return order if len(start) == len(order) else np.minimum.reduceat(order, start)
    order = np.lexsort((np.arange(len(edges)), -weights, key))
    key = key[order]
    first = np.ones(len(order), dtype=bool)
    first[1:] = key[1:] != key[:-1]
    return order[first]


def spanning_tree_rotations(
    n: int, edges: np.ndarray, qrel: np.ndarray, weights: np.ndarray, root: int | None = None
) -> tuple[np.ndarray, int, np.ndarray]:
    """Chain rotations along a maximum spanning tree of a connected graph.

    Returns ``(q (4, n), root, tree_edges)``; the root gets the identity. The tree: up to
    ``MST_PYTHON_MAX_EDGES`` edges Kruskal's algorithm in plain Python (array calls would cost
    more than the work), above ``scipy.sparse.csgraph``. The rotations are composed to the
    root by pointer jumping (each round doubles the reach of every node at once).
    """
    if n == 1:
        return np.array([[1.0], [0.0], [0.0], [0.0]]), 0, np.zeros(0, np.int64)
    if root is None:
        deg = np.bincount(edges.ravel(), minlength=n)
        root = int(np.argmax(deg))
    if len(edges) <= MST_PYTHON_MAX_EDGES:
        # Kruskal takes the edges heaviest first, ties broken by node pair (as the sparse
        # path's ranks) and then by edge order, and skips any edge whose ends are already
        # joined, parallel edges included: no de-duplication needed.
        key = np.minimum(edges[:, 0], edges[:, 1]) * n + np.maximum(edges[:, 0], edges[:, 1])
        child, parent, tree_edges = _kruskal(n, edges[:, 0], edges[:, 1], np.lexsort((key, -weights)), root)
    else:
        cand = _dedupe_pairs(n, edges, weights)
        # Unique positive costs, increasing as the weight decreases: rank encodes the edge.
        wc = weights[cand]  # heaviest first, ties by pair (cand is in pair order)
        by_rank = np.arange(len(cand)) if wc.min() == wc.max() else np.lexsort((np.arange(len(cand)), -wc))
        rank = np.empty(len(cand), dtype=np.int64)
        rank[by_rank] = np.arange(len(cand))
        a, b = edges[cand, 0], edges[cand, 1]
        import scipy.sparse as sp
        from scipy.sparse import csgraph

        C = sp.csr_matrix((rank + 1.0, (np.minimum(a, b), np.maximum(a, b))), shape=(n, n))
        T = csgraph.minimum_spanning_tree(C).tocoo()
        order, pred = csgraph.breadth_first_order(T.tocsr(), root, directed=False, return_predecessors=True)
        if len(order) != n:
            raise UnsolvableError("the graph is not connected")
        # Each tree edge (stored lo-hi) hangs its child from its parent.
        tree_edges = cand[by_rank[T.data.astype(np.int64) - 1]]
        child = np.where(pred[T.col] == T.row, T.col, T.row)
        parent = pred[child]
    # rel[c] = R_c R_parent^T from the tree edge, whichever way it is stored.
    forward = edges[tree_edges, 0] == parent
    qt = qrel[:, tree_edges]
    rel = np.where(forward, qt, so3_rows.qconj_rows(qt))
    A = np.zeros((4, n))
    A[0] = 1.0
    A[:, child] = rel
    anc = np.arange(n)
    anc[child] = parent
    # Pointer jumping: A[c] = R_c R_anc(c)^T; compose until every ancestor is the root.
    while (anc != root).any():
        A = so3_rows.qmul_rows(A, A[:, anc])
        anc = anc[anc]
    so3_rows.positive_w_rows(A, out=A)
    return A / np.sqrt((A * A).sum(axis=0)), root, tree_edges


def _kruskal(n: int, a: np.ndarray, b: np.ndarray, by_rank: np.ndarray, root: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Maximum spanning tree by Kruskal's algorithm in plain Python (small graphs: no
    sparse-matrix machinery): edges heaviest first (``by_rank``), union-find with path
    halving, stopping at the (n-1)-th tree edge. Ranks are distinct, so the tree is the
    unique one the sparse path finds too. Returns ``(child, parent, index of the edge to
    the parent)``, ordered from the root outwards (each child after its parent)."""
    up = list(range(n))
    al, bl = a.tolist(), b.tolist()
    adj: list[list[int]] = [[] for _ in range(n)]
    need = n - 1
    for k in by_rank.tolist():
        x, y = al[k], bl[k]
        while up[x] != x:
            up[x] = x = up[up[x]]
        while up[y] != y:
            up[y] = y = up[up[y]]
        if x != y:
            up[x] = y
            adj[al[k]].append(k)
            adj[bl[k]].append(k)
            need -= 1
            if not need:
                break
    if need:
        raise UnsolvableError("the graph is not connected")
    child, parent, tree = [], [], []
    seen = [False] * n
    seen[root] = True
    order = [root]
    for v in order:  # breadth first from the root
        for k in adj[v]:
            c = bl[k] if al[k] == v else al[k]
            if not seen[c]:
                seen[c] = True
                child.append(c), parent.append(v), tree.append(k), order.append(c)
    return np.array(child, dtype=np.int64), np.array(parent, dtype=np.int64), np.array(tree, dtype=np.int64)
