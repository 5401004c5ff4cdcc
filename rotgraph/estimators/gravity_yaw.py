"""The 1-D stages of the gravity variant (:mod:`.gravity_solve`; step 2 of :mod:`.gravity`):
robust synchronisation of the yaw angles ``theta`` of the images with gravity, on the edges
between them, each measuring ``theta_j - theta_i ~ phi_ij`` (the twist of its
gravity-aligned rotation) with a swing (how far the pair disagrees with gravity).

Stages: a maximum spanning tree start, L1, the robust loss (its scale re-fitted once, as
``method="irls"``), then the weights of a fitted noise model; residuals wrapped to
``(-pi, pi]``; each step one anchored scalar Laplacian solve
(:class:`~.laplacian.AnchoredLaplacian`, one right-hand side). Also here: the weights of the
noise model (:class:`ModelWeight`, also the 3-DOF refinement's) and the choice of linear
solver both stages make.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .gravity_geometry import wrap_angle, yaw_angle, yaw_quaternion_rows
from .irls import floored_weights, loss_weights, refitted_scale
from .laplacian import make_laplacian
from .noise_model import fit_gaussian
from .spanning_tree import spanning_tree_rotations
from .stats import median

__all__ = ["MIN_EDGE_SIGMA_DEG", "CG_MIN_CAMERAS", "CG_MIN_DEGREE", "linear_solver", "approximate_leverage", "ModelWeight",
           "YawEdges", "solve_yaw"]

#: The edge noise estimate never drops below this (noise-free data: the prior terms still count).
MIN_EDGE_SIGMA_DEG = 1e-3
#: Above this many cameras, on graphs of at least CG_MIN_DEGREE average degree, the linear
#: solves use Jacobi-preconditioned CG (rtol 1e-8) instead of a sparse LU: an Erdős–Rényi graph
#: of 1000 cameras and degree 10 fills its LU in (scalar Laplacian: LU 52 ms, CG 1.2 ms;
#: n = 1000 solve 1.3 s -> see benchmarks/README.md), the results agree to ~1e-7 deg.
CG_MIN_CAMERAS = 500
CG_MIN_DEGREE = 6.0


def linear_solver(n: int, n_edges: int, solver: str) -> str:
    """The linear solver of the gravity stages: ``cg`` for ``auto`` on large, well-connected
    graphs (:data:`CG_MIN_CAMERAS`, :data:`CG_MIN_DEGREE`), else ``solver``."""
    return "cg" if solver == "auto" and n > CG_MIN_CAMERAS and 2.0 * n_edges / n >= CG_MIN_DEGREE else solver


def approximate_leverage(n: int, edges: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Each edge's leverage, ``w_e (1/d_i + 1/d_j)`` with weighted degrees ``d`` (capped at
    0.95): the well-connected-graph approximation of :func:`~.leverage.leverage`, whose
    exact path (a dense factorisation up to 1000 cameras) took 0.3-0.5 s of a 1.3 s solve
    at n = 1000; only the noise model's scale depends on it."""
    deg = np.bincount(edges.ravel(), weights=np.concatenate([w, w]), minlength=n)
    return np.minimum(w * (1.0 / deg[edges[:, 0]] + 1.0 / deg[edges[:, 1]]), 0.95)


class ModelWeight:
    """IRLS weights ``w * P(inlier | r) / sigma^2`` of a Gaussian-plus-uniform noise model
    (:func:`~.noise_model.fit_gaussian`) re-fitted (warm) to the leverage-standardised
    residual angles at every call: near-L2 efficiency on the inliers, outliers at zero."""

    def __init__(self, w, lev, seed=0):
        self.w, self.root = w, np.sqrt(1.0 - lev)
        self.model, self.seed = None, seed

    def __call__(self, r):
        t = r / self.root
        self.model = fit_gaussian(t, 1, start=self.model, iterations=20 if self.model is None else 5, seed=self.seed)
        post = self.model.weights(t)[1]
        return self.w * post / self.sigma**2

    @property
    def sigma(self) -> float:
        """The fitted noise per axis (radians), at least :data:`MIN_EDGE_SIGMA_DEG`."""
        return max(float(self.model.sigma[0]), np.deg2rad(MIN_EDGE_SIGMA_DEG))


@dataclass
class YawEdges:
    """The 1-D problem on a connected graph: ``edges`` (m, 2), the yaw differences ``phi``
    (m,) they measure and the swings ``swing2 = qx^2 + qz^2`` of their aligned measurements,
    the ``anchor`` (its yaw fixed) and the anchored Laplacian ``lap`` of the steps."""

    edges: np.ndarray
    phi: np.ndarray
    swing2: np.ndarray
    anchor: int
    lap: object = None

    def residuals(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(yaw residuals (m,), each edge's full residual angle (m,): twist and swing)``."""
        res = wrap_angle(theta[self.edges[:, 1]] - theta[self.edges[:, 0]] - self.phi)
        r = 2.0 * np.arctan2(np.sqrt(self.swing2 + np.sin(0.5 * res) ** 2), np.abs(np.cos(0.5 * res)))
        return res, r

    def irls(self, theta, weight, max_iterations: int, tol: float) -> tuple[np.ndarray, int, bool]:
        """IRLS of the yaws from ``theta`` (n,): weights ``weight(r)`` of each edge's full
        residual angle, one Laplacian solve a step. Returns ``(theta, iterations, converged)``."""
        i, j = self.edges[:, 0], self.edges[:, 1]
        n = len(theta)
        for it in range(1, max_iterations + 1):
            res, r = self.residuals(theta)
            u = floored_weights(weight(r), "every gravity edge")
            # min sum u (x_j - x_i + res)^2: L x = -A^T (u res)
            b = np.bincount(i, weights=u * res, minlength=n) - np.bincount(j, weights=u * res, minlength=n)
            b[self.anchor] = 0.0
            x = self.lap.solve(u, b[None])[:, 0]
            theta = wrap_angle(theta + x)
            step = median(np.abs(x))
            if step < tol:
                return theta, it, True
        return theta, max_iterations, False


def solve_yaw(n, edges, phi, swing2, w, w_mst, opts, mark):
    """The robust 1-D synchronisation on a connected graph of ``n`` images (``w``: the cost's
    edge weights, ``w_mst`` the spanning tree's; ``mark(stage, iterations, converged)``).
    Returns ``(theta, anchor, loss scale, iterations, converged)``."""
    theta_q, anchor, _ = spanning_tree_rotations(n, edges, yaw_quaternion_rows(phi), w_mst)
    theta = yaw_angle(theta_q)
    mark("yaw_spanning_tree", 0, True)
    if n > 1 and len(edges):
        p = YawEdges(edges, phi, swing2, anchor, make_laplacian(n, edges, anchor, linear_solver(n, len(edges), opts.linear_solver)))
        model = ModelWeight(w, approximate_leverage(n, edges, w), opts.seed)
        theta, scale, iterations, converged = _yaw_stages(p, w, theta, model, opts, mark)
        return theta, anchor, scale, iterations, converged
    return theta, anchor, np.deg2rad(opts.loss_scale_deg), 0, True


def _yaw_stages(p: YawEdges, w, theta, model: ModelWeight, opts, mark):
    """:func:`solve_yaw`'s IRLS stages: L1, the loss (re-scaled), the noise model. Returns
    ``(theta, loss scale, iterations, converged)``."""
    scale = np.deg2rad(opts.loss_scale_deg)
    tol = np.deg2rad(opts.step_tol_deg)
    stage_tol = max(np.deg2rad(opts.stage_tol_deg), tol)
    theta, it, conv = p.irls(theta, loss_weights(w, "l1", scale), opts.l1_iterations, stage_tol)
    iterations = it
    mark("yaw_l1", it, conv)
    theta, it, conv = p.irls(theta, loss_weights(w, opts.loss, scale), opts.max_iterations, stage_tol)
    iterations += it
    stage = "yaw_" + opts.loss
    if opts.rescale:
        new_scale = refitted_scale(p.residuals(theta)[1])
        if abs(new_scale - scale) > 0.2 * scale:
            mark(stage, it, conv)
            scale, stage = new_scale, stage + "_rescaled"
            theta, it, conv = p.irls(theta, loss_weights(w, opts.loss, scale), opts.max_iterations, stage_tol)
            iterations += it
    mark(stage, it, conv)
    # Final stage: the fitted noise model's weights (the loss above brings the yaw into
    # its basin; its weights on the inliers cost efficiency: 0.47 vs 0.36 deg on a clean
    # 2-deg graph).
    theta, it, conv = p.irls(theta, model, opts.max_iterations, tol)
    iterations += it
    mark("yaw_noise_model", it, conv)
    return theta, scale, iterations, conv
