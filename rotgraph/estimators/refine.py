"""Levenberg-Marquardt refinement of multiple rotation averaging on the exact cost.

Minimises ``sum_ij w_ij rho(|r_ij|)`` with the geodesic residual
``r_ij = log(R_j^T R_ij R_i)``, so the result is a local optimum of the stated cost, not
of its linearisation. With the updates ``R_i <- R_i exp(d_i)``:

* ``dr/dd_i = J_r^{-1}(r)``  (right Jacobian inverse of SO(3)),
* ``dr/dd_j = -J_l^{-1}(r) = -J_r^{-1}(r)^T``,

``J_r^{-1}(p) = I + [p]x / 2 + (1/t^2 - (1 + cos t) / (2 t sin t)) [p]x^2`` with ``t = |p|``.
The robust loss enters through IRLS weights ``w rho'(t) / t`` on ``|r|^2``, whose gradient
is the exact gradient of the robust cost; each accepted step lowers the exact cost.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .. import so3, so3_rows
from ..losses import loss_rho, loss_weight
from .laplacian import block_pcg, direct_is_cheap
from .residuals import edge_errors

__all__ = ["refine_lm"]


def _cost(q, edges, qrel, weights, loss, scale):
    r, theta = edge_errors(q, edges, qrel)
    return float(weights @ loss_rho(loss, theta, scale)), r, theta


def refine_lm(
    q0: np.ndarray,
    edges: np.ndarray,
    qrel: np.ndarray,
    weights: np.ndarray,
    anchor: int,
    loss: str = "l2",
    scale: float = 1.0,
    max_iterations: int = 50,
    tol: float = 1e-10,
) -> tuple[np.ndarray, int, bool]:
    """Levenberg-Marquardt from ``q0`` (4, n); node ``anchor`` fixed. Returns ``(q, iterations, converged)``."""
    n = q0.shape[1]
    q = q0.copy()
    cost, r, theta = _cost(q, edges, qrel, weights, loss, scale)
    lam = 1e-4
    i, j = edges[:, 0], edges[:, 1]
    free = np.ones(3 * n, dtype=bool)
    free[3 * anchor : 3 * anchor + 3] = False
    a, b = np.meshgrid(np.arange(3), np.arange(3), indexing="ij")
    a, b = a.ravel(), b.ravel()
    use_lu = n <= 300 or direct_is_cheap(n, edges, 3)
    for it in range(1, max_iterations + 1):
        floor = 1e-6 if loss in ("l1", "half_norm") else 1e-12
        u = weights * loss_weight(loss, np.maximum(theta, floor), scale)
        A = so3.right_jacobian_inverse(r.T)  # d r / d d_i
        B = -np.swapaxes(A, 1, 2)  # d r / d d_j
        uA, uB = u[:, None, None] * A, u[:, None, None] * B
        Hii = np.swapaxes(A, 1, 2) @ uA
        Hjj = np.swapaxes(B, 1, 2) @ uB
        Hij = np.swapaxes(A, 1, 2) @ uB
        rt = r.T
        gi = np.einsum("eki,ek->ei", uA, rt)
        gj = np.einsum("eki,ek->ei", uB, rt)
        g = np.zeros((n, 3))
        np.add.at(g, i, gi)
        np.add.at(g, j, gj)
        bi = (3 * i[:, None] + a[None]).ravel()
        bj = (3 * j[:, None] + a[None]).ravel()
        ci = (3 * i[:, None] + b[None]).ravel()
        cj = (3 * j[:, None] + b[None]).ravel()
        rows = np.concatenate([bi, bj, bi, cj])
        cols = np.concatenate([ci, cj, cj, bi])
        data = np.concatenate([Hii.reshape(-1), Hjj.reshape(-1), Hij.reshape(-1), Hij.reshape(-1)])
        H = sp.coo_matrix((data, (rows, cols)), shape=(3 * n, 3 * n)).tocsr()[free][:, free]
        gf = g.reshape(-1)[free]
        diag = H.diagonal()
        accepted = False
        for _ in range(12):
            Hd = (H + sp.diags(lam * np.maximum(diag, 1e-12))).tocsc()
            try:
                if use_lu:
                    step = -spla.splu(Hd, permc_spec="MMD_AT_PLUS_A").solve(gf)
                else:  # a sparse LU would fill in (long-range edges): Jacobi CG
                    step = -block_pcg(Hd.tocsr(), gf[:, None], rtol=1e-10, maxiter=5000)[0][:, 0]
            except RuntimeError:
                lam *= 10
                continue
            d = np.zeros(3 * n)
            d[free] = step
            qn = so3_rows.qmul_rows(q, so3_rows.qexp_rows(d.reshape(n, 3).T))
            new_cost, rn, thn = _cost(qn, edges, qrel, weights, loss, scale)
            if new_cost <= cost:
                accepted = True
                decrease = cost - new_cost
                q, cost, r, theta = qn, new_cost, rn, thn
                lam = max(lam / 10, 1e-12)
                break
            lam *= 10
        if not accepted:
            return q, it, True  # no descent at any damping: a local optimum to precision
        if np.sqrt((step * step).sum() / n) < tol or decrease <= 1e-15 * max(cost, 1e-300):
            return q, it, True
    return q, max_iterations, False
