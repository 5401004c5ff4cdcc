"""Multiple rotation averaging with gravity priors (issue #17, item 3).

Each image ``i`` may carry a gravity direction ``g_i``: a unit vector in the camera's frame,
the direction "down" as the camera sees it. COLMAP's convention (``PosePrior.gravity``,
``pycolmap.run_rotation_averaging(use_gravity=True)``): the world's down direction is
``d = (0, 1, 0)`` (:data:`GRAVITY_WORLD`) and a perfect prior satisfies ``g_i = R_i d``
with ``R_i`` = cam_from_world. With an exact gravity an image keeps one degree of freedom,
its yaw about ``d``; with a noisy one (``sigma`` degrees) its tilt may move within that noise.

Noise model (the one this module assumes and reports in ``diagnostics["gravity"]``):

* **tilt** - a measured ``g_i`` is the true one turned about an axis perpendicular to it by a
  2-D Gaussian vector of standard deviation ``sigma_i`` per axis (so the tilt angle is
  Rayleigh distributed: median 1.18 sigma, RMS 1.41 sigma). ``sigma_i = 0``: exact (a hard
  constraint). The prior term of image ``i`` is ``|t_i|^2 / (2 sigma_i^2)`` with ``t_i`` the
  rotation vector taking ``d`` to ``R_i^T g_i`` (information ``sigma^-2`` on the two tilt
  axes, none about gravity).
* **edges** - ``R_ij = R_j R_i^T exp(e)``, ``e`` isotropic with standard deviation
  ``sigma_edge`` per axis (estimated from the yaw residuals, whose first-order part is free
  of the gravity errors), under the robust loss of :mod:`rotgraph.losses` (``SolveOptions``:
  ``loss``, ``loss_scale_deg``, its re-fit to the inliers, ``outlier_threshold_deg``).

Algorithm
---------
1. **Gravity alignment.** ``A_i`` (COLMAP's ``GravityAlignedRotation``: ``A_i e_y = g_i``)
   and ``C`` with ``C e_y = d``. Every gravity image is ``R_i = A_i Y(theta_i) C^T``
   (``Y``: a rotation about ``e_y``), so an edge between two of them measures
   ``M_ij = A_j^T R_ij A_i = Y(theta_j - theta_i)``: its twist about ``e_y`` (swing-twist
   decomposition) is the yaw difference ``phi_ij``, its swing how far the pair disagrees
   with gravity.
2. **Robust 1-D synchronisation** of ``theta`` on the gravity edges' largest component:
   maximum spanning tree start (:func:`~.spanning_tree.spanning_tree_rotations` on the pure
   yaw rotations), an L1 stage, then IRLS with the robust loss (weights from each edge's
   full residual angle, twist and swing), its scale re-fitted to the inliers as in
   ``method="irls"``; residuals wrapped to ``(-pi, pi]``. Each step: one anchored scalar
   Laplacian solve (:class:`~.laplacian.AnchoredLaplacian`, one right-hand side).
2b. **Gravity noise estimate** (images whose ``sigma`` is None / NaN; section below).
3. **3-DOF refinement** when some ``sigma_i > 0`` or some image has no gravity (mixed
   case): Gauss-Newton IRLS on the robust edge cost plus the gravity prior terms, the
   update ``R_i <- R_i exp(w_i)`` with ``w_i`` restricted to ``span(d)`` for exact gravity
   images (their tilt stays exact) and free otherwise; the gauge is the yaw of one gravity
   image. In the mixed case the images the 1-D stage does not reach start from rotgraph's
   unconstrained solve (:func:`~.rotation_averaging.average_rotations`), rotated into the
   gravity frame (geodesic L1 mean over the images of the 1-D stage); gravity images
   outside it are projected onto their gravity.

Estimating the gravity noise
----------------------------
Each edge predicts one image's gravity from the other's: ``R_ij^T g_j`` at ``i``. Under the
model above a prediction is off the true gravity by ``a_j + e_perp`` (the neighbour's tilt
noise and two axes of the edge noise) and the measured ``g_i`` by its own ``a_i``. Per image,
the neighbours' predictions get a robust centre (coordinate-wise median of the unit
vectors), those within 4 pooled noise units of it are kept (outlier edges, wrong neighbour
gravities out) and averaged; the 2-D angle ``c_i`` between that mean and ``g_i`` has
``E |c_i|^2 / 2 = s_i^2 + V_i``, ``V_i = sum_j (s_j^2 + sigma_edge^2) / m_i^2`` the variance of
the mean prediction (``m_i`` kept): the solve-free analogue of the solve's own error, so
that exact gravity gives ``s ~ 0``. ``V_i`` is estimated without bias from the kept
predictions' own scatter ``S_i / (m_i (m_i - 1))`` (whatever the neighbours' sigmas; no
edge noise model); a model value (``sigma_edge`` from the yaw residuals of step 2, free of
the gravity noise to first order) sets the weights and the outlier test only. One ``s`` for
all images to estimate (images with ``m_i >= 3``): a robust start (the median of
``|c_i|^2 / (2 E)`` at its Exp(1) value ln 2), images with ``|c_i|^2 / (2 E) > 9.21``
(p < 1e-4) flagged as wrong gravity (``diagnostics["gravity"]["gravity_outliers"]``; solved
without their gravity, started from their neighbours), a second pass without them as
predictors, then the weighted mean of ``|c_i|^2 / 2 - V_i`` (weights ``1 / (s^2 + V_i)^2``)
with its empirical standard error. Within :data:`HARD_Z` standard errors of zero it is
taken as 0: the hard constraint. Measured (er graphs, degree 10, 2-deg edges, 10 % outlier
edges, 3 seeds): 0.46-0.51 / 0.95-0.99 / 1.94-2.00 deg for 0.5 / 1 / 2 at n = 1000,
0.50-0.60 / 0.97-1.05 / 1.92-2.00 at n = 200; exact gravity: 0 (hard); the solve's error
with the estimate within 2 % of that with the true sigma. Thin graphs (degree 4) read high
(0.62-0.64 for 0.5 at n = 500; 2 standard errors) at no cost in the solve (<= 1.3 %).

Without any gravity image in the largest component the result is that of
:func:`~.rotation_averaging.average_rotations`. Rigs are not used (images are solved one
by one) and neither are per-edge information matrices (``diagnostics`` says so).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np

from .. import so3
from ..errors import InputError, OptionError, UnsolvableError
from ..losses import loss_rho, positive_loss_weight
from ..options import resolve_options
from ..viewgraph import ViewGraph, connected_components
from .irls import L1_FLOOR
from .laplacian import block_pcg, make_laplacian, one_blas_thread
from .noise_model import fit_gaussian
from .spanning_tree import spanning_tree_rotations
from .stats import median, percentile
from .types import AveragingResult, SolveOptions, scatter_to_graph

__all__ = [
    "GRAVITY_WORLD",
    "TiltYawErrors",
    "average_rotations_with_gravity",
    "gravity_aligned_rotations",
    "gravity_of",
    "perturb_gravity",
    "tilt_yaw_errors",
]

logger = logging.getLogger(__name__)

#: The world's "down" direction in COLMAP's convention (``RotationEstimatorOptions.gravity_dir``,
#: ``SyntheticDatasetOptions.prior_gravity_in_world``): a perfect prior is ``R_i @ GRAVITY_WORLD``.
GRAVITY_WORLD = np.array([0.0, 1.0, 0.0])

#: Outlier threshold of the robust stages when ``SolveOptions.outlier_threshold_deg`` is None.
OUTLIER_THRESHOLD_DEG = 10.0
#: The re-fitted loss scale never drops below this (as in rotation_averaging).
MIN_SCALE_DEG = 2.0
#: The edge noise estimate never drops below this (noise-free data: the prior terms still count).
MIN_EDGE_SIGMA_DEG = 1e-3
# Median of the half-normal distribution in units of sigma (the Maxwell's, the 3-D one:
# stats.MAXWELL_MEDIAN).
_HALF_NORMAL_MEDIAN = 0.6745


# --------------------------------------------------------------------------- geometry


def _unit_rows(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def gravity_aligned_rotations(gravity: np.ndarray) -> np.ndarray:
    """Rotations ``A`` (n, 3, 3) with ``A e_y = g`` (second column the unit gravity ``g``), as
    COLMAP's ``GravityAlignedRotation`` (which completes the basis by a Householder QR; the
    yaw about ``g`` chosen here differs, which changes no solution: it is absorbed by the
    yaw unknowns)."""
    g = _unit_rows(np.atleast_2d(np.asarray(gravity, dtype=np.float64)))
    helper = np.zeros_like(g)
    use_z = np.abs(g[:, 0]) > 0.9
    helper[~use_z, 0] = 1.0
    helper[use_z, 2] = 1.0
    x = _unit_rows(helper - (helper * g).sum(axis=1, keepdims=True) * g)
    z = np.cross(x, g)
    return np.stack([x, g, z], axis=2)


def gravity_of(cam_from_world: np.ndarray, gravity_world=GRAVITY_WORLD) -> np.ndarray:
    """The exact gravity directions ``R_i d`` (n, 3) of rotations ``R_i`` (cam_from_world)."""
    return np.asarray(cam_from_world, dtype=np.float64) @ _unit_rows(np.asarray(gravity_world, dtype=np.float64))


def perturb_gravity(gravity: np.ndarray, sigma_deg, rng=None) -> np.ndarray:
    """Noisy gravity directions under this module's tilt model: each ``g`` turned about an axis
    perpendicular to it by a 2-D Gaussian vector, ``sigma_deg`` per axis (scalar or (n,))."""
    rng = np.random.default_rng(rng)
    g = _unit_rows(np.asarray(gravity, dtype=np.float64))
    A = gravity_aligned_rotations(g)
    z = rng.standard_normal((len(g), 2)) * np.deg2rad(np.broadcast_to(np.asarray(sigma_deg, float), (len(g),)))[:, None]
    v = A[:, :, 0] * z[:, :1] + A[:, :, 2] * z[:, 1:]  # perpendicular to g
    return _unit_rows(np.einsum("nab,nb->na", so3.exp(v), g))


def _yaw_quaternion_rows(phi: np.ndarray) -> np.ndarray:
    """Quaternion rows (4, K) of rotations by ``phi`` about ``e_y``."""
    z = np.zeros_like(phi)
    return np.stack([np.cos(0.5 * phi), z, np.sin(0.5 * phi), z])


def _wrap(a: np.ndarray) -> np.ndarray:
    """Angles wrapped to ``[-pi, pi)``."""
    return (a + np.pi) % (2.0 * np.pi) - np.pi


def _swing_twist(q: np.ndarray, axis: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Swing-twist decomposition of quaternion rows ``q`` (4, K) about the unit ``axis``:
    ``(twist angle in (-pi, pi], swing angle in [0, pi], total angle)``."""
    p = axis @ q[1:]  # the vector part along the axis
    twist = _wrap(2.0 * np.arctan2(p, q[0]))
    wp = np.sqrt(q[0] ** 2 + p**2)
    swing = 2.0 * np.arctan2(np.sqrt(np.maximum(1.0 - wp * wp, 0.0)), wp)
    v = np.sqrt((q[1:] ** 2).sum(axis=0))
    total = 2.0 * np.arctan2(v, np.abs(q[0]))
    return twist, swing, total


# --------------------------------------------------------------------------- evaluation


@dataclass
class TiltYawErrors:
    """Per-image errors (degrees) split about gravity: ``tilt_deg`` the angle between the
    estimated and the true gravity direction in the camera (the swing of the error),
    ``yaw_deg`` the error's twist about gravity, ``total_deg`` its whole angle; NaN rows
    for images missing from either input. ``alignment`` the gauge ``S`` (``R_est ~ R_gt S``)."""

    tilt_deg: np.ndarray
    yaw_deg: np.ndarray
    total_deg: np.ndarray
    alignment: np.ndarray
    align: str

    def _median(self, x):
        x = x[np.isfinite(x)]
        return float(np.median(x)) if len(x) else float("nan")

    @property
    def median_tilt(self) -> float:
        return self._median(self.tilt_deg)

    @property
    def median_yaw(self) -> float:
        return self._median(self.yaw_deg)

    @property
    def median_total(self) -> float:
        return self._median(self.total_deg)

    def to_dict(self) -> dict:
        return {"align": self.align, "median_tilt_deg": self.median_tilt, "median_yaw_deg": self.median_yaw,
                "median_deg": self.median_total, "n_evaluated": int(np.isfinite(self.total_deg).sum())}


def tilt_yaw_errors(R_est, R_gt, *, gravity_world=GRAVITY_WORLD, align: str = "yaw") -> TiltYawErrors:
    """Errors of ``R_est`` vs ``R_gt`` (both (n, 3, 3) cam_from_world, NaN rows for missing
    images) split into tilt and yaw about the world's gravity ``gravity_world``.

    ``align="yaw"`` (an estimate made with gravity priors, in the gravity frame): only the
    yaw gauge is aligned, ``S`` a rotation about gravity (robust circular mean of the images'
    yaw offsets, then their median). ``align="full"`` (an estimate without gravity, whose
    world is arbitrary): the whole gauge, ``S`` the geodesic L1 mean of ``R_gt_i^T R_est_i``
    as :func:`rotgraph.evaluate.compare_rotations` aligns it. Each image's world-frame error
    ``F_i = R_gt_i^T R_est_i S^T`` is split into a twist about gravity (yaw) and a swing
    (tilt: the angle between the estimated and the true gravity in the camera).
    """
    E = np.asarray(R_est, dtype=np.float64)
    G = np.asarray(R_gt, dtype=np.float64)
    if E.shape != G.shape or E.ndim != 3 or E.shape[1:] != (3, 3):
        raise InputError(f"expected two (n,3,3) arrays of the same shape, got {E.shape} and {G.shape}")
    if align not in ("yaw", "full"):
        raise OptionError("align must be 'yaw' or 'full'")
    d = _unit_rows(np.asarray(gravity_world, dtype=np.float64))
    both = np.isfinite(E).all(axis=(1, 2)) & np.isfinite(G).all(axis=(1, 2))
    if not both.any():
        raise InputError("no camera has both an estimate and ground truth")
    D = np.swapaxes(G[both], 1, 2) @ E[both]  # ~ S
    if align == "full":
        from .single import mean

        S = mean(D, metric="geodesic", norm="l1").rotation
    else:
        twist = _swing_twist(so3.quaternion_rows_from_matrices(D), d)[0]
        a0 = np.arctan2(np.sin(twist).sum(), np.cos(twist).sum())
        alpha = a0 + float(np.median(_wrap(twist - a0)))
        S = so3.exp(alpha * d)
    F = D @ S.T
    twist, swing, total = _swing_twist(so3.quaternion_rows_from_matrices(F), d)
    out = np.full((3, len(E)), np.nan)
    out[:, both] = np.degrees(np.stack([swing, np.abs(twist), total]))
    return TiltYawErrors(out[0], out[1], out[2], S, align)


# --------------------------------------------------------------------------- inputs


def _check_gravity(gravity, sigma_deg, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(unit gravity (n, 3) with NaN rows, has (n,) bool, sigma (n,) radians, NaN: to estimate)``."""
    g = np.asarray(gravity, dtype=np.float64)
    if g.shape != (n, 3):
        raise ValueError(f"gravity must be ({n}, 3) (NaN rows for images without gravity), got {g.shape}")
    has = np.isfinite(g).all(axis=1)
    norm = np.linalg.norm(np.where(has[:, None], g, 0.0), axis=1)
    if (has & ~(norm > 1e-12)).any():
        k = int(np.argmax(has & ~(norm > 1e-12)))
        raise ValueError(f"gravity of node {k} is the zero vector")
    g = np.where(has[:, None], g / np.where(has, norm, 1.0)[:, None], np.nan)
    s = np.full(n, np.nan) if sigma_deg is None else np.asarray(sigma_deg, dtype=np.float64)
    if s.ndim > 1 or (s.ndim == 1 and len(s) != n):
        raise ValueError(f"sigma_deg must be a scalar, None or ({n},) (NaN: estimate), got shape {s.shape}")
    s = np.broadcast_to(s, (n,)).copy()
    if (s[has] < 0).any():
        raise OptionError("sigma_deg must be >= 0 (inf: no prior; NaN or None: estimated) for every image with gravity")
    has &= ~np.isposinf(s)  # an infinite sigma is no prior
    return g, has, np.deg2rad(np.where(has, s, np.nan))


# --------------------------------------------------------------------------- 1-D stage


def _yaw_irls(theta, edges, phi, swing2, weight, anchor, max_iterations, tol, lap):
    """IRLS of the yaw angles ``theta`` (n,) on edges measuring ``theta_j - theta_i ~ phi``:
    weights ``weight(r)`` of each edge's full residual angle ``r`` (twist residual and the
    swing ``swing2 = qx^2 + qz^2`` of its aligned measurement), one anchored Laplacian solve
    a step. Returns ``(theta, iterations, converged)``."""
    i, j = edges[:, 0], edges[:, 1]
    n = len(theta)
    for it in range(1, max_iterations + 1):
        res, r = _yaw_residuals(theta, edges, phi, swing2)
        u = weight(r)
        umax = u.max()
        if not umax > 0:
            raise UnsolvableError("every gravity edge has zero weight under the robust loss")
        u = np.maximum(u, 1e-12 * umax)
        # min sum u (x_j - x_i + res)^2: L x = -A^T (u res)
        b = np.bincount(i, weights=u * res, minlength=n) - np.bincount(j, weights=u * res, minlength=n)
        b[anchor] = 0.0
        x = lap.solve(u, b[None])[:, 0]
        theta = _wrap(theta + x)
        step = median(np.abs(x))
        if step < tol:
            return theta, it, True
    return theta, max_iterations, False


def _loss_weight(w, loss, scale):
    floor = L1_FLOOR if loss in ("l1", "half_norm") else 1e-12
    return lambda r: w * positive_loss_weight(loss, np.maximum(r, floor), scale)


def _leverage(n: int, edges: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Each edge's leverage, ``w_e (1/d_i + 1/d_j)`` with weighted degrees ``d`` (capped at
    0.95): the well-connected-graph approximation of :func:`~.noise_model.leverage`, whose
    exact path (a dense factorisation up to 1000 cameras) took 0.3-0.5 s of a 1.3 s solve
    at n = 1000; only the noise model's scale depends on it."""
    deg = np.bincount(edges.ravel(), weights=np.concatenate([w, w]), minlength=n)
    return np.minimum(w * (1.0 / deg[edges[:, 0]] + 1.0 / deg[edges[:, 1]]), 0.95)


class _ModelWeight:
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
        return max(float(self.model.sigma[0]), np.deg2rad(MIN_EDGE_SIGMA_DEG))


def _yaw_residuals(theta, edges, phi, swing2):
    res = _wrap(theta[edges[:, 1]] - theta[edges[:, 0]] - phi)
    r = 2.0 * np.arctan2(np.sqrt(swing2 + np.sin(0.5 * res) ** 2), np.abs(np.cos(0.5 * res)))
    return res, r


#: Above this many cameras, on graphs of at least CG_MIN_DEGREE average degree, the linear
#: solves use Jacobi-preconditioned CG (rtol 1e-8) instead of a sparse LU: an Erdős–Rényi graph
#: of 1000 cameras and degree 10 fills its LU in (scalar Laplacian: LU 52 ms, CG 1.2 ms;
#: n = 1000 solve 1.3 s -> see benchmarks/README.md), the results agree to ~1e-7 deg.
CG_MIN_CAMERAS = 500
CG_MIN_DEGREE = 6.0


def _use_cg(n: int, n_edges: int) -> bool:
    return n > CG_MIN_CAMERAS and 2.0 * n_edges / n >= CG_MIN_DEGREE


def _linear_solver(n: int, n_edges: int, solver: str) -> str:
    return "cg" if solver == "auto" and _use_cg(n, n_edges) else solver


def _solve_yaw(n, edges, phi, swing2, w, w_mst, opts, mark):
    """The robust 1-D synchronisation (module docstring, step 2) on a connected graph:
    ``(theta, anchor, loss scale, final weights (a _ModelWeight), iterations, converged)``."""
    theta_q, anchor, _ = spanning_tree_rotations(n, edges, _yaw_quaternion_rows(phi), w_mst)
    theta = _wrap(2.0 * np.arctan2(theta_q[2], theta_q[0]))
    mark("yaw_spanning_tree", 0, True)
    iterations, converged = 0, True
    scale = np.deg2rad(opts.loss_scale_deg)
    model = _ModelWeight(w, _leverage(n, edges, w), opts.seed)
    if n > 1 and len(edges):
        lap = make_laplacian(n, edges, anchor, _linear_solver(n, len(edges), opts.linear_solver))
        return _solve_yaw_stages(n, edges, phi, swing2, w, theta, anchor, model, opts, mark, lap)
    return theta, anchor, scale, model, iterations, converged


def _solve_yaw_stages(n, edges, phi, swing2, w, theta, anchor, model, opts, mark, lap):
    """:func:`_solve_yaw`'s IRLS stages: L1, the loss (re-scaled), the noise model."""
    iterations = 0
    scale = np.deg2rad(opts.loss_scale_deg)
    tol = np.deg2rad(opts.step_tol_deg)
    stage_tol = max(np.deg2rad(opts.stage_tol_deg), tol)
    theta, it, conv = _yaw_irls(theta, edges, phi, swing2, _loss_weight(w, "l1", scale), anchor, opts.l1_iterations,
                                stage_tol, lap)
    iterations += it
    mark("yaw_l1", it, conv)
    theta, it, conv = _yaw_irls(theta, edges, phi, swing2, _loss_weight(w, opts.loss, scale), anchor,
                                opts.max_iterations, stage_tol, lap)
    iterations += it
    if opts.rescale:
        r = _yaw_residuals(theta, edges, phi, swing2)[1]
        new_scale = max(3.0 * percentile(r, 25) / 1.10, np.deg2rad(MIN_SCALE_DEG))
        if abs(new_scale - scale) > 0.2 * scale:
            mark("yaw_" + opts.loss, it, conv)
            scale = new_scale
            theta, it, conv = _yaw_irls(theta, edges, phi, swing2, _loss_weight(w, opts.loss, scale), anchor,
                                        opts.max_iterations, stage_tol, lap)
            iterations += it
            mark("yaw_" + opts.loss + "_rescaled", it, conv)
        else:
            mark("yaw_" + opts.loss, it, conv)
    else:
        mark("yaw_" + opts.loss, it, conv)
    # Final stage: the fitted noise model's weights (the loss above brings the yaw into
    # its basin; its weights on the inliers cost efficiency: 0.47 vs 0.36 deg on a clean
    # 2-deg graph).
    theta, it, conv = _yaw_irls(theta, edges, phi, swing2, model, anchor, opts.max_iterations, tol, lap)
    iterations += it
    converged = conv
    mark("yaw_noise_model", it, conv)
    return theta, anchor, scale, model, iterations, converged


# --------------------------------------------------------------------------- 3-DOF stage


def _node_basis(hard: np.ndarray, has: np.ndarray, anchor: int, d: np.ndarray):
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


def _tilt_residuals(R: np.ndarray, g: np.ndarray, d: np.ndarray) -> np.ndarray:
    """``t_i`` (n, 3): the rotation vector (perpendicular to ``d``) taking ``d`` to ``R_i^T g_i``."""
    h = np.einsum("nba,nb->na", R, g)  # R^T g
    c = np.cross(d, h)
    s = np.linalg.norm(c, axis=1)
    ang = np.arctan2(s, h @ d)
    with np.errstate(invalid="ignore", divide="ignore"):
        f = np.where(s > 1e-15, ang / np.where(s > 1e-15, s, 1.0), 1.0)
    return c * f[:, None]


def _refine(R, edges, qrel, weight, g, has, hard, sigma, anchor, d, max_iterations, tol, use_cg=False):
    """Gauss-Newton IRLS of the robust edge cost plus the gravity priors (module docstring,
    step 3). ``weight(residual angles) -> (E,)``: each edge's information (isotropic, with its
    robust or noise-model factor). Returns ``(R, iterations, converged)``."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    n = len(R)
    i, j = edges[:, 0], edges[:, 1]
    T = _node_basis(hard, has, anchor, d)
    soft = has & ~hard
    P = np.eye(3) - np.outer(d, d)
    info_g = np.where(soft, 1.0 / np.where(soft, sigma, 1.0) ** 2, 0.0)
    q = so3.quaternion_rows_from_matrices(R)
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
        qe = so3.qmul_rows(so3.qconj_rows(q[:, j]), so3.qmul_rows(qrel, q[:, i]))
        v, theta = so3.qlog_rows(qe)
        u = weight(theta)
        umax = u.max()
        if not umax > 0:
            raise UnsolvableError("every edge has zero weight under the robust loss")
        u = np.maximum(u, 1e-12 * umax)
        Rm = so3.matrices_from_quaternion_rows(q)
        t = _tilt_residuals(Rm, np.nan_to_num(g), d)
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
        q = so3.qmul_rows(q, so3.qexp_rows(np.ascontiguousarray(x.T)))
        q /= np.sqrt((q * q).sum(axis=0))
        step = median(np.linalg.norm(x, axis=1))
        if step < tol:
            converged = True
            break
    R = so3.matrices_from_quaternion_rows(q)
    # exact gravity images: remove the last rounding drift of the tilt
    return R, it, converged


# --------------------------------------------------------------------------- gravity noise estimate

#: Chi-square(2) / 2 quantile above which an image's gravity is flagged wrong (p = 1e-4).
GRAVITY_OUTLIER_Z = 9.21
#: The estimated gravity sigma is taken as zero (the hard constraint) below this many standard errors.
HARD_Z = 3.0
#: An estimated gravity sigma below this (degrees) is taken as zero (noise-free data).
MIN_GRAVITY_SIGMA_DEG = 1e-3
#: Fewest images (with >= 3 consistent neighbour predictions) to estimate the gravity noise from.
MIN_ESTIMATE_IMAGES = 10


def _group_median(keys: np.ndarray, vals: np.ndarray, n: int) -> np.ndarray:
    """Median of ``vals`` (K, c) per group ``keys`` (K,) in ``range(n)``: (n, c), NaN for empty groups."""
    out = np.full((n, vals.shape[1]), np.nan)
    cnt = np.bincount(keys, minlength=n)
    start = np.concatenate([[0], np.cumsum(cnt)[:-1]])
    ok = cnt > 0
    lo = (start + (cnt - 1) // 2)[ok]
    hi = (start + cnt // 2)[ok]
    for c in range(vals.shape[1]):
        s = vals[np.lexsort((vals[:, c], keys)), c]
        out[ok, c] = 0.5 * (s[lo] + s[hi])
    return out


def _log_at_y(v: np.ndarray) -> np.ndarray:
    """The 2-D log map (x, z; radians) at ``e_y`` of unit vectors ``v`` (K, 3)."""
    xz = v[:, [0, 2]]
    s = np.linalg.norm(xz, axis=1)
    ang = np.arctan2(s, v[:, 1])
    f = np.where(s > 1e-300, ang / np.where(s > 1e-300, s, 1.0), 1.0)
    return xz * f[:, None]


def _gravity_predictions(edges, Rrel, g, A, use):
    """Each usable edge's two predictions of a gravity from the other end's: at ``i``,
    ``R_ij^T g_j``; at ``j``, ``R_ij g_i``; each in the node's aligned frame (``A^T p``: its
    own gravity is ``e_y``). Returns ``(node (K,), other (K,), unit vectors (K, 3))``."""
    e = np.flatnonzero(use[edges[:, 0]] & use[edges[:, 1]])
    i, j = edges[e, 0], edges[e, 1]
    Re = Rrel[e]
    p_i = np.einsum("kba,kb->ka", Re, g[j])  # R^T g_j, at i
    p_j = np.einsum("kab,kb->ka", Re, g[i])  # R g_i, at j
    node = np.concatenate([i, j])
    other = np.concatenate([j, i])
    p = np.concatenate([p_i, p_j])
    return node, other, np.einsum("kab,ka->kb", A[node], p)


def _estimate_gravity_sigma(edges, Rrel, g, A, has, sigma, sigma_edge):
    """The gravity noise of the images whose ``sigma`` (radians) is NaN, from how far each
    image's gravity lies from the gravities its neighbours predict through the edges
    (module docstring, "Estimating the gravity noise"). Returns ``(sigma (n,) with the NaN
    filled, flagged (n,) bool: gravity inconsistent with the neighbours', report dict)``."""
    n = len(g)
    est = has & np.isnan(sigma)
    report: dict = {"method": "each image's gravity vs the mean of its neighbours' gravities carried through the "
                              "edges (robust: median centre, 4-sigma cut), less that mean's variance from the "
                              "predictions' scatter; weighted mean over the images, 0 within 3 standard errors"}
    flagged = np.zeros(n, dtype=bool)
    se2 = sigma_edge**2
    use = has.copy()
    s2 = None
    m = y = G = U = S = None
    for _pass in range(2):  # second pass: without the flagged images as predictors
        node, other, p = _gravity_predictions(edges, Rrel, g, A, use)
        if len(node) == 0:
            break
        order = np.argsort(node, kind="stable")
        node, other, p = node[order], other[order], p[order]
        med = _group_median(node, p, n)  # a robust centre per image
        med[~(np.linalg.norm(np.nan_to_num(med), axis=1) > 1e-12)] = [0.0, 1.0, 0.0]
        med = _unit_rows(med)
        dev = np.arctan2(np.linalg.norm(np.cross(p, med[node]), axis=1), (p * med[node]).sum(axis=1))
        # pooled prediction noise per axis (Rayleigh median 1.1774 sigma); keep within 4 of it
        sp = max(median(dev) / 1.1774, np.deg2rad(1e-4))
        keep = dev <= 4.0 * sp
        m = np.bincount(node[keep], minlength=n).astype(float)
        v = np.stack([np.bincount(node[keep], weights=p[keep, a], minlength=n) for a in range(3)], axis=1)
        v[m == 0] = [0.0, 1.0, 0.0]
        c = _log_at_y(_unit_rows(v))  # the image's gravity residual: mean prediction vs e_y
        y = 0.5 * (c * c).sum(axis=1)  # E y = s_i^2 + (sum_j s_j^2 + m sigma_e^2) / m^2
        # the kept predictions' scatter: E S = (m - 1) / m * sum_j (s_j^2 + sigma_e^2) (per axis)
        dl = _log_at_y(p[keep])
        mk = np.maximum(m, 1.0)
        dbar = np.stack([np.bincount(node[keep], weights=dl[:, a], minlength=n) for a in range(2)], axis=1) / mk[:, None]
        S = 0.5 * np.bincount(node[keep], weights=((dl - dbar[node[keep]]) ** 2).sum(axis=1), minlength=n)
        given = np.where(np.isnan(sigma), 0.0, sigma) ** 2
        G = np.bincount(node[keep], weights=given[other[keep]], minlength=n)
        U = np.bincount(node[keep], weights=est[other[keep]].astype(float), minlength=n)
        ok = est & (m >= 3) & ~flagged
        if ok.sum() < MIN_ESTIMATE_IMAGES:
            break
        y_, m_, G_, U_ = y[ok], m[ok], G[ok], U[ok]
        a_ = 1.0 + U_ / m_**2
        b_ = G_ / m_**2 + se2 / m_
        # robust start: the median of y / E y is that of Exp(1), ln 2 (bisection on s^2)
        lo, hi = 0.0, max(float(np.max(y_)), 1e-30)
        if median(y_ / b_) <= np.log(2.0):
            s2 = 0.0
        else:
            for _ in range(60):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if median(y_ / (mid * a_ + b_)) > np.log(2.0) else (lo, mid)
            s2 = 0.5 * (lo + hi)
        # flag images whose gravity is far outside the noise (p < 1e-4)
        z = y / np.maximum(s2 * (1.0 + U / np.maximum(m, 1.0) ** 2) + G / np.maximum(m, 1.0) ** 2
                           + se2 / np.maximum(m, 1.0), 1e-300)
        new = est & (m >= 3) & (z > GRAVITY_OUTLIER_Z) & ~flagged
        flagged |= new
        if not new.any():
            break
        use = has & ~flagged
    ok = est & (m >= 3) & ~flagged if s2 is not None else np.zeros(n, dtype=bool)
    if ok.sum() < MIN_ESTIMATE_IMAGES:
        report.update(estimated=False, decision="hard (no estimate)",
                      reason=f"fewer than {MIN_ESTIMATE_IMAGES} images with >= 3 consistent gravity neighbours")
        return np.where(est, 0.0, sigma), flagged, report
    y_, m_, G_, U_ = y[ok], m[ok], G[ok], U[ok]
    # each image's unbiased s_i^2: y minus the variance of its mean prediction, that from
    # the predictions' own scatter (S / (m (m - 1)); independent of y for Gaussian noise):
    # no edge noise model needed, whatever the neighbours' sigmas
    t_ = y_ - S[ok] / (m_ * (m_ - 1.0))
    b_ = (G_ + U_ * s2) / m_**2 + se2 / m_  # the model's value of that variance: weights only
    for _ in range(20):  # weighted mean, weights 1 / Var(y) = 1 / (s^2 + b)^2 (y exponential)
        w = 1.0 / (s2 + b_) ** 2
        new_s2 = max(float((w * t_).sum() / w.sum()), 0.0)
        converged_s2 = abs(new_s2 - s2) <= 1e-6 * max(s2, 1e-30)
        s2 = new_s2
        b_ = (G_ + U_ * s2) / m_**2 + se2 / m_
        if converged_s2:
            break
    w = 1.0 / (s2 + b_) ** 2
    se_s2 = float(np.sqrt((w * w * (t_ - s2) ** 2).sum()) / w.sum())  # empirical (sandwich) standard error
    hard = s2 < HARD_Z * se_s2 or s2 < np.deg2rad(MIN_GRAVITY_SIGMA_DEG) ** 2
    s_hat = 0.0 if hard else float(np.sqrt(s2))
    report.update(
        estimated=True, n_images_used=int(ok.sum()), raw_sigma_deg=float(np.degrees(np.sqrt(s2))),
        variance_deg2=float(np.degrees(np.degrees(s2))), variance_se_deg2=float(np.degrees(np.degrees(se_s2))),
        edge_sigma_deg=float(np.degrees(sigma_edge)),
        decision=f"hard: the estimate is within {HARD_Z:g} standard errors of zero (or below "
                 f"{MIN_GRAVITY_SIGMA_DEG:g} deg)" if hard else "soft",
    )
    out = sigma.copy()
    out[est] = s_hat
    return out, flagged, report


# --------------------------------------------------------------------------- driver


@one_blas_thread
def average_rotations_with_gravity(graph: ViewGraph, gravity, sigma_deg=None, options: SolveOptions | None = None, *,
                                   gravity_world=GRAVITY_WORLD, unconstrained=None, **overrides) -> AveragingResult:
    """Multiple rotation averaging of ``graph`` with per-image gravity priors: the engine of
    ``rotgraph.average_rotations(graph, gravity=..., gravity_sigma_deg=...)``, which is how to
    call it (it passes ``unconstrained``, the solver without gravity, ``f(graph, options) ->
    AveragingResult``, that images without gravity and a graph without any need: this module
    does not import the solver it is called from).

    ``gravity`` (n, 3): each node's gravity direction in its camera frame (normalised here;
    NaN rows: no gravity), COLMAP's ``PosePrior.gravity``: ``g_i ~ R_i gravity_world``.
    ``sigma_deg``: the gravity noise per tilt axis in degrees, scalar or (n,) (0: exact, the
    tilt is held fixed; inf: no prior; None, the default, or NaN entries: estimated from the
    data, one value for all those images, given values win; 0 when not distinguishable from
    zero). The estimate, how it was made and the images whose gravity was found wrong (solved
    without it) are in ``diagnostics["gravity"]``: ``sigma_deg_estimated``,
    ``sigma_estimation``, ``gravity_outliers`` (node indices). ``options`` (:class:`SolveOptions`, or keyword
    overrides of its fields): ``loss``, ``loss_scale_deg``, ``rescale``, ``l1_iterations``,
    ``max_iterations``, ``step_tol_deg``, ``stage_tol_deg``, ``outlier_threshold_deg`` (None:
    10 deg), ``use_weights``, ``linear_solver``; the mixed case's unconstrained start uses
    them all. The result is in the gravity frame (``R_i gravity_world ~ g_i``); the gauge is
    the yaw of ``result.anchor``. ``result.diagnostics["gravity"]`` reports the error model
    (tilt and yaw), the stages and the counts. See the module docstring.
    """
    t0 = time.perf_counter()
    opts = resolve_options(SolveOptions, options, overrides)
    if graph.n_nodes == 0 or graph.n_edges == 0:
        raise UnsolvableError("the view graph has no edges")
    d = _unit_rows(np.asarray(gravity_world, dtype=np.float64))
    g_all, has_all, sig_all = _check_gravity(gravity, sigma_deg, graph.n_nodes)
    labels = graph.components()
    n_components = int(labels.max()) + 1
    sub, nodes, eidx = graph.largest_component(labels)
    n, edges = sub.n_nodes, sub.edges
    g, has, sigma = g_all[nodes], has_all[nodes], sig_all[nodes]
    diag: dict = {"n_images": n, "n_with_gravity": int(has.sum())}
    if unconstrained is None:
        def unconstrained(*_):
            raise OptionError("images without gravity need the unconstrained solver: call "
                             "rotgraph.average_rotations(graph, gravity=..., gravity_sigma_deg=...)")
    if not has.any():
        logger.info("no image of the solved component has a gravity prior: solving without gravity")
        res = unconstrained(graph, opts)
        res.diagnostics["gravity"] = dict(diag, used=False, reason="no gravity prior in the solved component")
        return res
    stages: list = []

    def mark(stage, iterations, converged):
        stages.append({"stage": stage, "iterations": iterations, "converged": converged, "seconds": time.perf_counter() - t0})

    w_mst = sub.weights
    w = sub.weights / median(sub.weights) if opts.use_weights else np.ones(sub.n_edges)
    qrel = sub.relative_quaternion_rows()

    # -- 1. gravity alignment: aligned measurements of the gravity edges
    gedge = has[edges[:, 0]] & has[edges[:, 1]]
    A = np.full((n, 3, 3), np.nan)
    A[has] = gravity_aligned_rotations(g[has])
    C = gravity_aligned_rotations(d[None])[0]
    ge = np.flatnonzero(gedge)
    M = np.swapaxes(A[edges[ge, 1]], 1, 2) @ sub.cam2_from_cam1[ge] @ A[edges[ge, 0]]
    qm = so3.quaternion_rows_from_matrices(M)
    phi = _wrap(2.0 * np.arctan2(qm[2], qm[0]))
    swing2 = (qm[1] ** 2 + qm[3] ** 2) / np.maximum(qm[0] ** 2 + qm[2] ** 2 + qm[1] ** 2 + qm[3] ** 2, 1e-300)

    # -- 2. 1-D synchronisation on the gravity edges' largest component
    R = np.full((n, 3, 3), np.nan)
    in_yaw = np.zeros(n, dtype=bool)
    scale = np.deg2rad(opts.loss_scale_deg)
    iterations, converged = 0, True
    anchor = None
    sigma_edge = None
    m_in = 0
    if len(ge):
        ncomp, lab = connected_components(n, edges[ge])
        sizes = np.bincount(lab[has], minlength=ncomp)
        big = int(np.argmax(sizes))
        yaw_nodes = np.flatnonzero((lab == big) & has)
        if len(yaw_nodes) >= 2:
            remap = np.full(n, -1)
            remap[yaw_nodes] = np.arange(len(yaw_nodes))
            keep = (remap[edges[ge, 0]] >= 0) & (remap[edges[ge, 1]] >= 0)
            ye = ge[keep]
            theta, a_loc, scale, _, it, conv = _solve_yaw(len(yaw_nodes), remap[edges[ye]], phi[keep], swing2[keep], w[ye],
                                                      w_mst[ye], opts, mark)
            iterations += it
            converged = conv
            anchor = int(yaw_nodes[a_loc])
            R[yaw_nodes] = A[yaw_nodes] @ so3.exp(theta[:, None] * np.array([0.0, 1.0, 0.0])) @ C.T
            in_yaw[yaw_nodes] = True
            res, r = _yaw_residuals(theta, remap[edges[ye]], phi[keep], swing2[keep])
            thr = np.deg2rad(opts.outlier_threshold_deg or OUTLIER_THRESHOLD_DEG)
            inl = r <= thr
            m_in = int(inl.sum())
            dof = m_in - (len(yaw_nodes) - 1)
            if m_in >= 10 and dof > 0:
                # yaw residuals: one axis of the edge noise, less the leverage of the 1-D fit
                sigma_edge = median(np.abs(res[inl])) / _HALF_NORMAL_MEDIAN * np.sqrt(m_in / dof)
                diag["edge_sigma_from"] = "yaw residuals"
    diag["n_yaw_stage"] = int(in_yaw.sum())

    # -- 2b. the gravity noise of the images without a given sigma (module docstring)
    to_estimate = has & np.isnan(sigma)
    sigma_estimated = None
    flagged = np.zeros(n, dtype=bool)
    if to_estimate.any():
        if sigma_edge is None:
            sigma = np.where(to_estimate, 0.0, sigma)
            report = {"estimated": False, "reason": "too few gravity edges to estimate the edge noise from the yaw stage"}
        else:
            sigma, flagged, report = _estimate_gravity_sigma(
                edges, sub.cam2_from_cam1, g, A, has, sigma, max(sigma_edge, np.deg2rad(MIN_EDGE_SIGMA_DEG)))
        sigma_estimated = float(np.degrees(sigma[to_estimate & ~flagged][0])) if (to_estimate & ~flagged).any() else 0.0
        report["n_images"] = int(to_estimate.sum())
        mark("gravity_sigma_estimate", 0, True)
        if flagged.any():
            logger.warning("gravity: %d image(s) whose gravity disagrees with their neighbours' far beyond the noise: "
                           "solved without it", int(flagged.sum()))
            has &= ~flagged
            in_yaw &= ~flagged
            R[flagged] = np.nan
            sigma[flagged] = np.nan
            if anchor is not None and flagged[anchor]:
                cand = np.flatnonzero(in_yaw)
                anchor = int(cand[np.argmax(sub.degrees()[cand])]) if len(cand) else None
        diag["sigma_estimation"] = report
    hard = has & (sigma == 0)

    # -- 3. 3-DOF refinement: noisy gravity, or images the 1-D stage did not reach
    need_refine = bool((has & ~hard).any() or (~in_yaw).any())
    refined = False
    if need_refine and n > 1:
        if (~in_yaw).any() and in_yaw.any() and (~in_yaw).sum() <= 0.1 * n and \
                _fill_from_neighbours(R, in_yaw, edges, sub.cam2_from_cam1):
            # few images outside the 1-D stage (wrong gravity, or a few without): each started
            # from its neighbours (geodesic L1 mean of their predictions), no unconstrained solve
            mark("neighbour_start", 0, True)
            proj = ~in_yaw & has
            if proj.any():
                Mi = np.swapaxes(A[proj], 1, 2) @ R[proj] @ C
                th = _wrap(2.0 * np.arctan2(*so3.quaternion_rows_from_matrices(Mi)[[2, 0]]))
                R[proj] = A[proj] @ so3.exp(th[:, None] * np.array([0.0, 1.0, 0.0])) @ C.T
        elif (~in_yaw).any():
            base = unconstrained(sub, opts)
            iterations += base.iterations
            mark("unconstrained_start", base.iterations, base.converged)
            R0 = base.cam_from_world
            ok0 = np.isfinite(R0).all(axis=(1, 2))
            if not ok0.all():  # cameras the robust solve left out: chain them later from neighbours
                R0 = np.where(ok0[:, None, None], R0, np.eye(3))
            if in_yaw.any():
                from .single import mean

                both = in_yaw & ok0
                W = mean(np.swapaxes(R0[both], 1, 2) @ R[both], metric="geodesic", norm="l1").rotation
            else:
                # no gravity edge: rotate the solution so that the gravity images agree on
                # average (chordal mean of the rotations taking R_i^T g_i to d)
                W = _gravity_frame(R0[has & ok0], g[has & ok0], d)
                anchor = int(np.flatnonzero(has)[np.argmax(sub.degrees()[has])])
            fill = ~in_yaw
            R[fill] = R0[fill] @ W
            proj = fill & has
            if proj.any():  # onto their gravity: keep the yaw, take the measured tilt
                Mi = np.swapaxes(A[proj], 1, 2) @ R[proj] @ C
                th = _wrap(2.0 * np.arctan2(*so3.quaternion_rows_from_matrices(Mi)[[2, 0]]))
                R[proj] = A[proj] @ so3.exp(th[:, None] * np.array([0.0, 1.0, 0.0])) @ C.T
        weight = _ModelWeight(w, _leverage(n, edges, w), opts.seed)
        R, it, conv = _refine(R, edges, qrel, weight, g, has, hard, sigma, anchor, d, opts.max_iterations,
                              np.deg2rad(opts.step_tol_deg), _linear_solver(n, len(edges), opts.linear_solver) == "cg")
        sigma_edge = weight.sigma
        diag["edge_sigma_from"] = "noise model of the 3-DOF refinement"
        diag["noise_model"] = weight.model.describe()
        iterations += it
        converged = conv
        refined = True
        mark("refine_3dof", it, conv)

    # -- results for every input node and edge
    theta = so3.angle_between(sub.cam2_from_cam1, R[edges[:, 1]] @ np.swapaxes(R[edges[:, 0]], 1, 2))
    threshold = opts.outlier_threshold_deg or OUTLIER_THRESHOLD_DEG
    inlier_sub = np.degrees(theta) <= threshold
    rejected = np.bincount(edges[inlier_sub].ravel(), minlength=n) == 0 if n > 1 else np.zeros(n, bool)
    if rejected.all():
        raise UnsolvableError(f"every edge is an outlier (residual > {threshold:g} deg): no camera can be trusted")
    prior_cost = 0.0
    soft = has & ~hard
    if soft.any():
        t = _tilt_residuals(R[soft], g[soft], d)
        prior_cost = float(0.5 * ((t * t).sum(axis=1) / sigma[soft] ** 2).sum())
    edge_scale = 1.0 if sigma_edge is None else max(sigma_edge, np.deg2rad(MIN_EDGE_SIGMA_DEG))
    cost = float(w @ loss_rho(opts.loss, theta, scale)) / edge_scale**2 + prior_cost
    arrays = scatter_to_graph(graph.n_nodes, graph.n_edges, nodes, eidx, R, rejected, np.degrees(theta), inlier_sub,
                              w * positive_loss_weight(opts.loss, np.maximum(theta, 1e-12), scale))
    sig_deg = np.degrees(sigma[has])
    diag.update(
        used=True,
        gravity_world=d.tolist(),
        n_exact=int(hard.sum()),
        sigma_deg_estimated=sigma_estimated,
        gravity_outliers=nodes[flagged].tolist() if sigma_estimated is not None else None,
        n_without_gravity=int((~has).sum()),
        refined_3dof=refined,
        error_model={
            "tilt": ("exact: the tilt is held to the gravity (1 DOF per image)" if hard[has].all() else
                     f"Gaussian per tilt axis, sigma {np.median(sig_deg):.3g} deg (median; information sigma^-2 on the "
                     "two axes perpendicular to gravity, none about it)"),
            "yaw": f"{opts.loss} on each edge's residual angle, scale {np.degrees(scale):.3g} deg" +
                   ("" if sigma_edge is None else f"; isotropic edge noise {np.degrees(sigma_edge):.3g} deg per axis (estimated)"),
            "gravity_sigma_deg_median": float(np.median(sig_deg)),
            "edge_sigma_deg": None if sigma_edge is None else float(np.degrees(sigma_edge)),
            "loss": opts.loss,
            "loss_scale_deg": float(np.degrees(scale)),
        },
        information={"used": False} if sub.information is not None else None,
        rigs="not used (images solved one by one)" if sub.rigs is not None else None,
    )
    diag = {k: v for k, v in diag.items() if v is not None}
    seconds = time.perf_counter() - t0
    logger.info("gravity: %d cameras (%d with gravity), %d edges, %d outliers, %d iterations, %.2f s", n, int(has.sum()),
                sub.n_edges, int((~inlier_sub).sum()), iterations, seconds)
    return AveragingResult(
        **arrays, iterations=iterations, cost=cost, converged=converged, method="gravity", anchor=int(nodes[anchor]),
        n_components=n_components, seconds=seconds, stages=stages, outlier_threshold_deg=float(threshold),
        diagnostics={"gravity": diag},
    )


def _fill_from_neighbours(R, known, edges, Rrel, max_layers: int = 5) -> bool:
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


def _gravity_frame(R: np.ndarray, g: np.ndarray, d: np.ndarray) -> np.ndarray:
    """A rotation ``W`` with ``R_i W d ~ g_i`` on average: ``W^T`` takes ``R_i^T g_i`` to ``d``
    (the rotation of least angle taking their normalised mean to ``d``)."""
    h = np.einsum("nba,nb->na", R, g).mean(axis=0)
    h /= np.linalg.norm(h)
    c = np.cross(h, d)
    s = np.linalg.norm(c)
    ang = np.arctan2(s, h @ d)
    if s < 1e-15:
        Wt = np.eye(3) if ang < 1 else so3.exp(np.pi * gravity_aligned_rotations(d[None])[0][:, 0])
    else:
        Wt = so3.exp(c / s * ang)
    return Wt.T
