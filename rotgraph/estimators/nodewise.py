"""Node-wise averaging (Hartley et al. 2013, section 7.4; Hartley, Aftab & Trumpf 2011):
``method="nodewise"`` of :func:`~.rotation_averaging.average_rotations`."""

from __future__ import annotations

import numpy as np

from .. import so3_rows
from .types import Callback

__all__ = ["solve_nodewise"]


def _greedy_colouring(n: int, edges: np.ndarray) -> list[np.ndarray]:
    """Independent sets covering the nodes (largest-first greedy colouring)."""
    import networkx as nx

    G = nx.Graph()
    G.add_nodes_from(range(n))
    G.add_edges_from(map(tuple, edges.tolist()))
    colour = nx.greedy_color(G, strategy="largest_first")
    c = np.array([colour[k] for k in range(n)])
    return [np.flatnonzero(c == k) for k in range(c.max() + 1)]


def solve_nodewise(
    q0: np.ndarray,
    edges: np.ndarray,
    qrel: np.ndarray,
    weights: np.ndarray,
    anchor: int,
    norm: str,
    max_iterations: int,
    step_tol: float,
    callback: Callback | None = None,
) -> tuple[np.ndarray, int, bool]:
    """Node-wise averaging: Gauss-Seidel sweeps, colour class by colour class, each node
    moved to the geodesic L2 mean (one Karcher step) or L1 median (one Weiszfeld step) of its
    neighbours' predictions ``R_ij R_i`` (and ``R_ij^T R_j``). The anchor stays fixed."""
    n = q0.shape[1]
    q = q0.copy()
    classes = [c[c != anchor] for c in _greedy_colouring(n, edges)]
    # Every edge seen from both ends: (node, neighbour, rotation neighbour -> node).
    node = np.concatenate([edges[:, 1], edges[:, 0]])
    nbr = np.concatenate([edges[:, 0], edges[:, 1]])
    rot = np.concatenate([qrel, so3_rows.qconj_rows(qrel)], axis=1)
    w2 = np.concatenate([weights, weights])
    in_class = np.zeros(n, dtype=np.int64)
    for k, c in enumerate(classes):
        in_class[c] = k
    by_class = [np.flatnonzero((in_class[node] == k) & (node != anchor)) for k in range(len(classes))]
    for it in range(1, max_iterations + 1):
        total = 0.0
        for idx in by_class:
            if len(idx) == 0:
                continue
            a, b = node[idx], nbr[idx]
            pred = so3_rows.qmul_rows(rot[:, idx], q[:, b])  # prediction of R_a
            v, theta = so3_rows.qlog_rows(so3_rows.qmul_rows(so3_rows.qconj_rows(q[:, a]), pred))
            nodes = np.unique(a)
            if norm == "l2":
                u = w2[idx]
                num = np.stack([np.bincount(a, weights=u * v[k], minlength=n) for k in range(3)])
                step = num[:, nodes] / np.bincount(a, weights=u, minlength=n)[nodes]
            else:
                # Weiszfeld step per node; predictions the node sits on are set apart
                # (Vardi & Zhang): stay if |sum of the others' unit vectors| <= their weight.
                on = theta < 1e-9
                u = np.where(on, 0.0, w2[idx] / np.where(on, 1.0, theta))
                num = np.stack([np.bincount(a, weights=u * v[k], minlength=n) for k in range(3)])
                den = np.bincount(a, weights=u, minlength=n)[nodes]
                w_on = np.bincount(a, weights=np.where(on, w2[idx], 0.0), minlength=n)[nodes]
                pull = np.sqrt((num[:, nodes] ** 2).sum(axis=0))
                with np.errstate(invalid="ignore", divide="ignore"):
                    factor = np.where(pull > 0, np.maximum(0.0, 1.0 - w_on / pull), 0.0)
                    step = np.where(den > 0, num[:, nodes] / np.where(den > 0, den, 1.0), 0.0) * factor
            q[:, nodes] = so3_rows.qmul_rows(q[:, nodes], so3_rows.qexp_rows(step))
            total += float((step * step).sum())
        rms = float(np.sqrt(total / n))
        if callback is not None:
            callback("nodewise", it, rms)
        if rms < step_tol:
            return q, it, True
    return q, max_iterations, False
