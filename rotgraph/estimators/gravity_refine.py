"""The 3-DOF stage of the gravity variant (:mod:`.gravity_solve`; step 3 of :mod:`.gravity`):
Gauss-Newton IRLS of the robust edge cost plus the gravity prior terms, the update
``R_i <- R_i exp(w_i)`` with ``w_i`` restricted to ``span(d)`` for exact gravity images
(their tilt stays exact) and free otherwise; the gauge is the yaw of one gravity image. And
the start of the images the 1-D stage did not reach, from their neighbours
(:func:`fill_from_neighbours`).
"""

from __future__ import annotations

import numpy as np

from .. import so3_rows
from .gravity_geometry import gravity_aligned_rotations, tilt_residuals
from .irls import floored_weights
from .laplacian import block_pcg
from .residuals import error_quaternions
from .stats import median

__all__ = ["node_basis", "refine_3dof", "fill_from_neighbours"]


def node_basis(hard: np.ndarray, has: np.ndarray, anchor: int, d: np.ndarray):
    """Columns of the update basis: per node, ``[d]`` (exact gravity), ``I`` (free) or, for
    the anchor (the yaw gauge), nothing (exact) or the two axes perpendicular to ``d``.
    Returns the sparse (3n, k) matrix ``T`` with ``w = T z``."""
    import scipy.sparse as sp

    n = len(hard)
    A = gravity_aligned_rotations(d[None])[0]
    perp = np.stack([A[:, 0], A[:, 2]], axis=1)  # (3, 2)
    rows, cols, vals = [], [], []
    k = 0
    ncols = np.where(hard, 1, 3)
    if has[anchor]:
        ncols[anchor] = 0 if hard[anchor] else 2
    start = np.concatenate([[0], np.cumsum(ncols)])
    # free nodes: identity blocks
    free = np.flatnonzero(ncols == 3)
    for a in range(3):
        rows.append(3 * free + a), cols.append(start[free] + a), vals.append(np.ones(len(free)))
    one = np.flatnonzero(ncols == 1)
    for a in range(3):
        rows.append(3 * one + a), cols.append(start[one]), vals.append(np.full(len(one), d[a]))
    if ncols[anchor] == 2:
        for c in range(2):
            for a in range(3):
                rows.append(np.array([3 * anchor + a])), cols.append(np.array([start[anchor] + c])), vals.append(np.array([perp[a, c]]))
    k = int(start[-1])
    T = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(3 * n, k))
    return T


def refine_3dof(R, edges, qrel, weight, g, has, hard, sigma, anchor, d, max_iterations, tol, use_cg=False):
    """Gauss-Newton IRLS of the robust edge cost plus the gravity priors (module docstring,
    step 3). ``weight(residual angles) -> (E,)``: each edge's information (isotropic, with its
    robust or noise-model factor). Returns ``(R, iterations, converged)``."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    n = len(R)
    i, j = edges[:, 0], edges[:, 1]
    T = node_basis(hard, has, anchor, d)
    soft = has & ~hard
    P = np.eye(3) - np.outer(d, d)
    info_g = np.where(soft, 1.0 / np.where(soft, sigma, 1.0) ** 2, 0.0)
    q = so3_rows.quaternion_rows_from_matrices(R)
    converged = False
    it = 0
    # The (3n x 3n) block Laplacian pattern: L_scalar (x) I3, plus the prior blocks.
    rows_s = np.concatenate([i, j, i, j])
    cols_s = np.concatenate([i, j, j, i])
    sign = np.concatenate([np.ones(2 * len(i)), -np.ones(2 * len(i))])
    prior_nodes = np.flatnonzero(soft)
    pr_r = (3 * prior_nodes[:, None, None] + np.arange(3)[None, :, None]).repeat(3, axis=2).ravel()
    pr_c = (3 * prior_nodes[:, None, None] + np.arange(3)[None, None, :]).repeat(3, axis=1).ravel()
    pr_v = (info_g[prior_nodes, None, None] * P[None]).ravel()
    for it in range(1, max_iterations + 1):
        # edge errors E = R_j^T R_ij R_i (world frame): r = log E
        qe = error_quaternions(q[:, i], q[:, j], qrel)
        v, theta = so3_rows.qlog_rows(qe)
        u = floored_weights(weight(theta))
        Rm = so3_rows.matrices_from_quaternion_rows(q)
        t = tilt_residuals(Rm, np.nan_to_num(g), d)
        t[~soft] = 0.0
        # gradient of 1/2 sum u |r + w_i - w_j|^2 + 1/2 sum s^-2 |t - P w|^2 at w = 0
        grad = np.zeros((n, 3))
        for a in range(3):
            grad[:, a] = np.bincount(i, weights=u * v[a], minlength=n) - np.bincount(j, weights=u * v[a], minlength=n)
        grad -= info_g[:, None] * t
        vals = u[np.tile(np.arange(len(i)), 4)] * sign
        Ls = sp.coo_matrix((vals, (rows_s, cols_s)), shape=(n, n)).tocsr()
        H = sp.kron(Ls, sp.identity(3, format="csr"), format="csr")
        if len(prior_nodes):
            H = H + sp.csr_matrix((pr_v, (pr_r, pr_c)), shape=(3 * n, 3 * n))
        Hr = (T.T @ H @ T).tocsc()
        br = -(T.T @ grad.ravel())
        if Hr.shape[0] == 0:
            return Rm, it, True
        if use_cg:
            z = block_pcg(Hr.tocsr(), br[:, None], rtol=1e-10)[0][:, 0]
        else:
            z = spla.splu(Hr, permc_spec="MMD_AT_PLUS_A").solve(br)
        x = (T @ z).reshape(n, 3)
        q = so3_rows.qmul_rows(q, so3_rows.qexp_rows(np.ascontiguousarray(x.T)))
        q /= np.sqrt((q * q).sum(axis=0))
        step = median(np.linalg.norm(x, axis=1))
        if step < tol:
            converged = True
            break
    R = so3_rows.matrices_from_quaternion_rows(q)
    # exact gravity images: remove the last rounding drift of the tilt
    return R, it, converged


def fill_from_neighbours(R, known, edges, Rrel, max_layers: int = 5) -> bool:
    """Start the rotations of the nodes not ``known`` from their known neighbours, layer by
    layer: each the medoid (least summed chordal distance to the others) of the predictions
    ``R_ij^T R_j`` (or ``R_ij R_i``), in place; the refinement does the rest. True when every
    node was reached within ``max_layers``."""
    known = known.copy()
    i, j = edges[:, 0], edges[:, 1]
    for _ in range(max_layers):
        todo = ~known
        if not todo.any():
            return True
        a = todo[i] & known[j]  # predict i from j: R_i = R_ij^T R_j
        b = todo[j] & known[i]  # predict j from i: R_j = R_ij R_i
        node = np.concatenate([i[a], j[b]])
        if not len(node):
            return False
        pred = np.concatenate([np.swapaxes(Rrel[a], 1, 2) @ R[j[a]], Rrel[b] @ R[i[b]]])
        order = np.argsort(node, kind="stable")
        node, pred = node[order], pred[order]
        starts = np.flatnonzero(np.r_[True, node[1:] != node[:-1]])
        ends = np.r_[starts[1:], len(node)]
        flat = pred.reshape(len(pred), 9)
        for s, e in zip(starts.tolist(), ends.tolist()):
            P = flat[s:e]
            # ||Ra - Rb||_F^2 = 6 - 2 <Ra, Rb>: the medoid maximises the summed square roots
            cost = np.sqrt(np.maximum(6.0 - 2.0 * (P @ P.T), 0.0)).sum(axis=1)
            R[node[s]] = pred[s + int(np.argmin(cost))]
        known[node[starts]] = True
    return bool(known.all())
