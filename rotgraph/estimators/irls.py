"""Iteratively reweighted Lie-algebraic averaging: the engine of the L1, L2 and robust stages.

Each iteration: residuals ``r_ij = log(R_j^T R_ij R_i)``, weights ``u_ij = w_ij
rho'(|r_ij|)/|r_ij|`` (or any weights a caller computes), one anchored graph-Laplacian
solve for the update ``w``, ``R_i <- R_i exp(w_i)``.
"""

from __future__ import annotations

import logging
from typing import Callable

import numpy as np

from ..errors import UnsolvableError
from ..losses import positive_loss_weight
from .laplacian import AnchoredBlockLaplacian, AnchoredLaplacian, make_laplacian
from .residuals import EdgeSystem, unit_quaternions
from .stats import median, percentile
from .types import Callback

__all__ = ["solve_irls", "solve_weighted", "damped_step", "loss_weights", "floored_weights", "refitted_scale", "L1_FLOOR", "MIN_SCALE_DEG"]

logger = logging.getLogger(__name__)

# IRLS weights 1/r of the L1 stage are capped at 1/L1_FLOOR (radians): below it the cost
# is quadratic (a Huber-like smoothing that keeps the Laplacian well conditioned).
L1_FLOOR = 1e-3
#: A loss scale re-fitted to the residuals (:func:`refitted_scale`) never drops below this
#: (noise-free data have zero residuals).
MIN_SCALE_DEG = 2.0
#: Step halvings tried in :func:`solve_weighted` when a step raises its ``cost``.
MAX_HALVINGS = 4


# --------------------------------------------------------------------------- IRLS family


def solve_irls(
    q0: np.ndarray,
    edges: np.ndarray,
    qrel: np.ndarray,
    weights: np.ndarray,
    anchor: int,
    loss: str,
    scale: float,
    max_iterations: int,
    step_tol: float,
    solver: str = "auto",
    laplacian: AnchoredLaplacian | AnchoredBlockLaplacian | None = None,
    callback: Callback | None = None,
    stage: str = "irls",
    system: EdgeSystem | None = None,
    first_iteration: int = 1,
    rtol: float | None = None,
) -> tuple[np.ndarray, int, bool]:
    """Iteratively reweighted Lie-algebraic averaging from ``q0`` (4, n).

    Each iteration: residuals ``r_ij = log(R_j^T R_ij R_i)``, weights
    ``u_ij = w_ij rho'(|r_ij|)/|r_ij|``, one anchored Laplacian solve for the update
    ``w``, ``R_i <- R_i exp(w_i)``. ``loss="l2"`` is Govindu's L2 averaging, ``"l1"``
    L1RA. Returns ``(q, iterations, converged)``. (``laplacian`` and ``system``: the
    per-graph structures, when the caller runs several stages on one graph;
    ``first_iteration``: the callback's count when a stage goes on.)
    """
    n = q0.shape[1]
    system = system or EdgeSystem(n, edges, qrel, anchor)
    lap = laplacian or make_laplacian(n, edges, anchor, solver, system.information is not None)
    weight = loss_weights(weights, loss, scale)
    return solve_weighted(q0, system, lap, weight, max_iterations, step_tol, callback, stage, first_iteration, rtol)


def loss_weights(weights: np.ndarray, loss: str, scale: float) -> Callable[[np.ndarray], np.ndarray]:
    """The IRLS weights of a robust loss as a function of the residual sizes ``r`` (radians):
    ``weights * rho'(r) / r``, ``r`` floored (at :data:`L1_FLOOR` for the L1-like losses)."""
    floor = L1_FLOOR if loss in ("l1", "half_norm") else 1e-12

    def weight(theta: np.ndarray) -> np.ndarray:
        return weights * positive_loss_weight(loss, np.maximum(theta, floor), scale)

    return weight


def floored_weights(u: np.ndarray, what: str = "every edge") -> np.ndarray:
    """IRLS weights ``u`` kept above a tiny floor (1e-12 of the largest): nodes whose edges
    all got zero (or vanishing) weight would make the Laplacian singular. Raises
    :class:`~rotgraph.errors.UnsolvableError` when every weight (of ``what``) is zero."""
    umax = u.max()
    if not umax > 0:
        raise UnsolvableError(f"{what} has zero weight under the robust loss")
    return np.maximum(u, 1e-12 * umax)


def refitted_scale(angles: np.ndarray) -> float:
    """A robust loss's scale fitted to the residual angles (radians) of a converged pass:
    3 sigma of 3-D Gaussian residuals, whose 25th percentile is 1.10 sigma; never below
    :data:`MIN_SCALE_DEG`."""
    return max(3.0 * percentile(angles, 25) / 1.10, np.deg2rad(MIN_SCALE_DEG))


def damped_step(q: np.ndarray, x: np.ndarray, update, cost_at, c0: float):
    """The step ``x`` (n, 3) from ``q``, halved up to :data:`MAX_HALVINGS` times until the cost
    does not rise (``update(q, x) -> (q1, |x|)``, ``cost_at(q1) -> float``, ``c0`` the cost at
    ``q``): ``(q1, |x|, its cost)``, or None when no halving descends (:func:`solve_weighted`'s
    guarded steps; the distributed solve's, whose cost is an exchange)."""
    for _ in range(MAX_HALVINGS + 1):
        q1, h = update(q, x)
        c1 = cost_at(q1)
        if c1 <= c0:
            return q1, h, c1
        x = 0.5 * x
    return None


def solve_weighted(
    q0: np.ndarray,
    system: EdgeSystem,
    laplacian: AnchoredLaplacian | AnchoredBlockLaplacian,
    weight,
    max_iterations: int,
    step_tol: float,
    callback: Callback | None = None,
    stage: str = "irls",
    first_iteration: int = 1,
    rtol: float | None = None,
    cost=None,
) -> tuple[np.ndarray, int, bool]:
    """The IRLS loop of :func:`solve_irls` with the edge weights of each iteration given by
    ``weight(residual angles (E,) rad) -> (E,)`` (e.g. a fitted noise model's).

    ``cost(residual angles) -> float``: the objective whose iteratively reweighted
    minimisation this is (e.g. a fixed noise model's negative log-likelihood). Each step is
    then kept only if it does not raise it, else halved up to :data:`MAX_HALVINGS` times;
    when no halving helps the stage ends there (converged: a reweighted Gauss-Newton step on
    the rotations is not guaranteed to descend, as the exact minimisation of the majoriser
    is; on sparse graphs with heavy-tailed models undamped steps had wandered for 100
    iterations, the model's likelihood falling).

    With information matrices (``system.information``; ``laplacian`` then an
    :class:`~.laplacian.AnchoredBlockLaplacian`), the angles are Mahalanobis norms
    (:meth:`~.residuals.EdgeSystem.angles`) and each edge enters the normal equations as the
    3x3 Gauss-Newton block of the whitened residual
    (:meth:`~.residuals.EdgeSystem.gauss_newton_blocks`, exact Jacobians): the fixed point is
    the minimum of the whitened cost, whichever way the edges point.

    ``rtol``: the relative residual at which this stage's conjugate-gradient Laplacian
    solves stop (default the Laplacian's own, :data:`~.laplacian.RTOL`; direct solvers
    ignore it)."""
    q = unit_quaternions(q0)
    c0 = None
    for it in range(1, max_iterations + 1):
        v, f, t = system.errors(q)
        u = floored_weights(weight(system.angles(q)))
        # The residual is 2 f v: this right-hand side gives half the update.
        if system.information is None:
            if system.precision is not None:  # an isotropic view: the cost sum u p |r|^2
                u = u * system.precision
            x = laplacian.solve(u, system.rhs(v * (f * u)), rtol)
        else:  # 3x3 Gauss-Newton blocks instead of scalars u_e (an AnchoredBlockLaplacian)
            U, y = system.gauss_newton_blocks(q, u, laplacian)  # (written straight into a sparse one: U None)
            x = laplacian.solve(U, system.rhs(y), rtol)
        if cost is None:
            q, h = system.update(q, x)
        else:
            if c0 is None:  # the cost at q: the accepted step's of the iteration before
                c0 = cost(system.angles(q))
            step = damped_step(q, x, system.update, lambda q1: cost(system.angles(q1)), c0)
            if step is None:
                return q, it, True  # no descent along this step: a minimum of the cost to the step's resolution
            q, h, c0 = step
        # Median step: a few cameras whose edges all lost their weight can drift slowly
        # without changing anything else; they must not keep the iteration going.
        step = 2.0 * median(h)
        if callback is not None:
            callback(stage, it + first_iteration - 1, step)
        logger.debug("%s iteration %d: median step %.3g rad", stage, it + first_iteration - 1, step)
        if step < step_tol:
            return q, it, True
    return q, max_iterations, False
