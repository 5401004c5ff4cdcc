"""Single rotation averaging (Hartley, Trumpf, Dai & Li 2013, section 5).

``mean(rotations, metric, norm, weights)`` minimises ``sum_i w_i d(R_i, R)^p`` over
rotations ``R``, for the three metrics of the paper

* ``"geodesic"``: the rotation angle ``theta_i = |log(R^T R_i)|``;
* ``"chordal"``: ``|R - R_i|_F = 2 sqrt(2) sin(theta_i / 2)``;
* ``"quaternion"``: ``min(|q - q_i|, |q + q_i|) = 2 sin(theta_i / 4)``;

and ``p = 2`` (``norm="l2"``) or ``p = 1`` (``norm="l1"``); ``norm="robust"`` minimises
``sum_i w_i rho(d_i)`` with a robust loss ``rho`` instead (IRLS, beyond the paper).

Algorithms (all work on unit quaternions, one 4x4-by-4xN product per iteration):

* chordal L2: closed form, the projection of ``sum w_i R_i`` onto SO(3), equal to the
  dominant eigenvector of ``sum w_i q_i q_i^T`` (Markley et al. 2007; scipy's
  ``Rotation.mean``);
* chordal L1: Weiszfeld-type majorise-minimise, each step the weighted chordal L2 mean
  with weights ``w_i / |R - R_i|_F`` (paper section 5.6);
* quaternion L2: pick each ``q_i``'s sign in the hemisphere of the estimate, average,
  normalise, until the signs stop changing (section 5.7);
* quaternion L1: Weiszfeld on the unit 3-sphere with the same sign choice (section 5.8);
* geodesic L2 (Karcher mean): ``R <- R exp(sum w_i log(R^T R_i) / sum w_i)`` (section 5.3);
* geodesic L1 (geodesic median): Weiszfeld on SO(3), Hartley, Aftab & Trumpf, CVPR 2011;
* robust: IRLS, each step the metric's weighted L2 step with the weights
  ``w_i rho'(d_i) / d_i`` of a loss from :mod:`rotgraph.losses`, started at the metric's
  chordal L1 median (breakdown point 1/2), so a large fraction of outliers does not
  capture it.

Convergence care. Every iterative method starts at the chordal L2 mean (or ``init``) and
is a descent method: a step that does not lower the cost is halved along the geodesic
until it does. When an L1 iterate lands on a data point (the Weiszfeld weight ``1/d``
is infinite there), the point is tested for optimality with the subgradient condition
``|grad of the others| <= w_k * c_metric``; if it fails, the step is taken without that
point (Vardi & Zhang 2000), which is a descent direction. The L2 geodesic mean is unique
only when the data lie in an open ball of radius pi/2; otherwise the result carries a
warning.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from functools import cached_property
from typing import Literal

import numpy as np

from . import so3
from .errors import InputError
from .losses import check_loss, loss_rho, loss_weight

__all__ = ["MeanResult", "mean", "METRICS", "NORMS", "as_quaternion_batch"]

logger = logging.getLogger(__name__)

METRICS = ("geodesic", "chordal", "quaternion")
NORMS = ("l1", "l2", "robust")

# Above this many rotations, starting points are computed on an evenly strided subsample.
_SUBSAMPLE = 8192
_L1_OVERRELAX = 1.5
# Up to this many rotations, the L2 means retry from other starts when the data are not
# inside a ball of radius pi/2 (where their costs can have several local minima).
_MULTISTART_MAX = 256
# How close (radians) an iterate must be to a data point to count as "on" it.
_COINCIDENT = 1e-12
# Local Lipschitz factor of each metric's distance in the tangent angle at 0.
_SLOPE = {"geodesic": 1.0, "chordal": np.sqrt(2.0), "quaternion": 0.5}


@dataclass(frozen=True)
class MeanResult:
    """The outcome of :func:`mean`.

    Attributes
    ----------
    rotation : (3, 3) the mean rotation.
    quaternion : (4,) the same as ``(w, x, y, z)``, ``w >= 0``.
    cost : the minimised cost ``sum w_i d_i^p`` (``sum w_i rho(d_i)`` for ``robust``).
    iterations : iterations run (0 for the closed form).
    converged : whether the stopping test was met before ``max_iterations``.
    residuals : (N,) geodesic angle in radians of each input rotation to the mean
        (computed on first access).
    inliers : (N,) bool, angle below ``3 * scale`` (robust), else all True.
    scale : the robust loss scale as an angle in radians (``None`` unless ``norm="robust"``);
        the loss itself is applied to the metric's distance of that angle.
    warnings : human-readable warnings (e.g. non-unique L2 geodesic mean).
    """

    rotation: np.ndarray
    quaternion: np.ndarray
    cost: float
    iterations: int
    converged: bool
    metric: str
    norm: str
    scale: float | None = None
    warnings: tuple[str, ...] = field(default_factory=tuple)
    _data: np.ndarray | None = field(default=None, repr=False, compare=False)  # (N, 4) quaternions

    @cached_property
    def residuals(self) -> np.ndarray:
        x = self._data
        x = x / np.sqrt(np.einsum("ij,ij->i", x, x))[:, None]
        p = so3.quaternion_multiply(so3.quaternion_conjugate(self.quaternion), x)
        return 2.0 * np.arctan2(np.linalg.norm(p[:, 1:], axis=1), np.abs(p[:, 0]))

    @cached_property
    def inliers(self) -> np.ndarray:
        if self.scale is None:
            return np.ones(len(self._data), dtype=bool)
        return self.residuals <= 3.0 * self.scale


def _matrix_of(q: np.ndarray) -> np.ndarray:
    """3x3 matrix of one unit quaternion (cheap: no batch machinery)."""
    w, x, y, z = (float(v) for v in q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


# --------------------------------------------------------------------------- input


def as_quaternion_batch(rotations) -> np.ndarray:
    """Validate a batch of rotations and return unit quaternions ``(N, 4)`` (any sign).

    Accepts matrices ``(N, 3, 3)``, quaternions ``(N, 4)`` as ``(w, x, y, z)`` (normalised
    here; zero quaternions are an error) or a scipy ``Rotation``.
    """
    return np.ascontiguousarray(_quaternion_rows_of(rotations).T)


def _quaternion_rows_of(rotations) -> np.ndarray:
    """:func:`as_quaternion_batch` as rows ``(4, N)``, the layout the iterations use."""
    if hasattr(rotations, "as_quat") and hasattr(rotations, "as_matrix"):
        q = np.atleast_2d(rotations.as_quat())
        return np.ascontiguousarray(np.roll(q, 1, axis=-1).T)
    x = np.asarray(rotations, dtype=np.float64)
    if x.ndim == 3 and x.shape[1:] == (3, 3):
        Q, err = so3.rotation_errors(x)
        if not (err <= 1e-6).all():
            k = int(np.argmax(~(err <= 1e-6)))
            what = "is not finite" if not np.isfinite(err[k]) else "is not a rotation (orthonormal, det +1)"
            raise InputError(f"matrix {k} {what}")
    elif x.ndim == 2 and x.shape[1] == 4:
        Q = np.ascontiguousarray(x.T)
        if not np.isfinite(Q).all():
            raise InputError(f"quaternion {int(np.argmax(~np.isfinite(Q).all(axis=0)))} is not finite")
        n = np.sqrt(np.einsum("ij,ij->j", Q, Q))
        if (n < 1e-12).any():
            raise InputError(f"quaternion {int(np.argmax(n < 1e-12))} is zero")
        Q /= n
    else:
        raise InputError(f"expected rotations of shape (N,3,3) or quaternions (N,4), got {x.shape}")
    if Q.shape[1] == 0:
        raise InputError("no rotations to average")
    return Q


def _check_weights(weights, n: int) -> np.ndarray:
    if weights is None:
        return np.ones(n)
    w = np.asarray(weights, dtype=np.float64)
    if w.shape != (n,):
        raise InputError(f"expected weights of shape ({n},), got {w.shape}")
    if not np.isfinite(w).all():
        raise InputError(f"weight {int(np.argmax(~np.isfinite(w)))} is not finite")
    if (w < 0).any():
        raise InputError(f"weight {int(np.argmax(w < 0))} is negative")
    if w.sum() <= 0:
        raise InputError("all weights are zero")
    return w


# --------------------------------------------------------------------------- geometry


def _left(q: np.ndarray) -> np.ndarray:
    """4x4 matrix L(q) with q * p = L(q) p."""
    w, x, y, z = q
    return np.array([[w, -x, -y, -z], [x, w, -z, y], [y, z, w, -x], [z, -y, x, w]])


class _Geometry:
    """Everything about the data seen from a candidate mean ``m`` (quaternion).

    ``P = conj(m) * q_i`` (4, N) are the relative rotations ``R^T R_i``; with
    ``c = |P_w| = cos(theta/2)`` and ``s = |P_xyz| = sin(theta/2)`` every distance is a
    cheap accurate function of ``(s, c)``: no arccos, and one arctan for the geodesic metric.
    """

    __slots__ = ("m", "P", "c", "s", "d", "_theta", "cost")

    def __init__(self, m, Q, w, metric, power, loss=None, scale=None):
        m = m / np.linalg.norm(m)
        P = _left(m * _CONJ) @ Q
        c = np.abs(P[0])
        s = np.sqrt(np.einsum("ij,ij->j", P[1:], P[1:]))
        theta = None
        if metric == "geodesic":
            with np.errstate(divide="ignore"):
                theta = 2.0 * np.arctan(s / c)  # s / c = inf at a half turn: arctan gives pi/2
            d = theta
        elif metric == "chordal":
            d = 2.0 * np.sqrt(2.0) * s
        else:
            d = s * np.sqrt(2.0 / (1.0 + c))  # = 2 sin(theta / 4)
        if loss is not None:
            cost = float(w @ loss_rho(loss, d, scale))
        else:
            cost = float(w @ (d if power == 1 else d * d))
        self.m, self.P, self.c, self.s, self.d, self._theta, self.cost = m, P, c, s, d, theta, cost

    @property
    def theta(self) -> np.ndarray:
        """(N,) geodesic angle of each datum to ``m``."""
        if self._theta is None:
            with np.errstate(divide="ignore"):
                self._theta = 2.0 * np.arctan(self.s / self.c)
        return self._theta

    @property
    def signs(self) -> np.ndarray:
        """(N,) sign making ``q_i`` lie in the hemisphere of ``m``."""
        return np.where(self.P[0] < 0, -1.0, 1.0)

    def sum_log_vectors(self, u: np.ndarray) -> np.ndarray:
        """``sum u_i log(R^T R_i)`` in the frame of the mean."""
        with np.errstate(invalid="ignore", divide="ignore"):
            f = np.where(self.s > 0, self.theta / self.s, 2.0 / self.c)
        return self.P[1:] @ (self.signs * f * u)

    def sum_unit_vectors(self, u: np.ndarray) -> np.ndarray:
        """``sum u_i log(R^T R_i) / |log(R^T R_i)|`` (0 for data at the mean)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            f = np.where(self.s > 0, 1.0 / self.s, 0.0)
        return self.P[1:] @ (self.signs * f * u)


_CONJ = np.array([1.0, -1.0, -1.0, -1.0])


def _slerp(a: np.ndarray, b: np.ndarray, t: float) -> np.ndarray:
    rel = so3.quaternion_multiply(so3.quaternion_conjugate(a), b)
    return so3.quaternion_multiply(a, so3.quaternion_exp(t * so3.quaternion_log(rel)))


def _step_angle(a: np.ndarray, b: np.ndarray) -> float:
    c = abs(float(a @ b))
    s = np.linalg.norm(so3.quaternion_multiply(so3.quaternion_conjugate(a), b)[1:])
    return 2.0 * float(np.arctan2(s, c))


def _dominant_eigenvector(K: np.ndarray) -> np.ndarray:
    return np.linalg.eigh(K)[1][:, -1]


def _chordal_l2(Q: np.ndarray, w: np.ndarray) -> np.ndarray:
    return _dominant_eigenvector((Q * w) @ Q.T)


# --------------------------------------------------------------------------- updates


def _weighted_l2_step(g: _Geometry, Q, u, metric):
    """The minimiser (geodesic: one Karcher step) of ``sum u_i d_i^2`` from ``g``."""
    if metric == "geodesic":
        return so3.quaternion_multiply(g.m, so3.quaternion_exp(g.sum_log_vectors(u) / u.sum()))
    if metric == "chordal":
        return _dominant_eigenvector((Q * u) @ Q.T)
    return Q @ (u * g.signs)


def _candidate(g: _Geometry, Q, w, metric, norm, loss, scale):
    """One majorise-minimise / Weiszfeld / IRLS update from the geometry ``g``.

    Each is a weighted L2 step with weights ``w`` (L2), ``w / d`` (L1, Weiszfeld) or
    ``w rho'(d) / d`` (robust). Returns ``(candidate quaternion or None, at_optimum)``;
    ``at_optimum`` is True when the iterate sits on a data point that satisfies the
    subgradient optimality condition of the L1 cost.
    """
    if norm == "l2":
        return _weighted_l2_step(g, Q, w, metric), False
    if norm == "robust":
        u = w * loss_weight(loss, np.maximum(g.d, _COINCIDENT), scale)
        if u.sum() <= 0:
            return None, False
        return _weighted_l2_step(g, Q, u, metric), False
    # L1: Weiszfeld weights w / d, with the data points the iterate sits on set apart.
    on = g.s < 0.5 * _COINCIDENT
    u = np.where(on, 0.0, w / np.where(on, 1.0, g.d))
    if on.any():
        # Tangent gradient of the cost of the other points; optimal iff |grad| <= slope * w_on.
        slope = {"geodesic": 1.0, "chordal": np.sqrt(2.0) * np.cos(0.5 * g.theta),
                 "quaternion": 0.5 * np.cos(0.25 * g.theta)}[metric]
        grad = g.sum_unit_vectors(np.where(on, 0.0, w * slope))
        if np.linalg.norm(grad) <= _SLOPE[metric] * w[on].sum() * (1 + 1e-12) or u.sum() <= 0:
            return None, True
    return _weighted_l2_step(g, Q, u, metric), False


def _iterate(m0, Q, w, metric, norm, loss, scale, max_iterations, tol):
    power = 1 if norm == "l1" else 2
    lossname = loss if norm == "robust" else None
    g = _Geometry(m0, Q, w, metric, power, lossname, scale)
    converged = False
    it = 0
    tried: set[int] = set()
    for it in range(1, max_iterations + 1):
        cand, at_optimum = _candidate(g, Q, w, metric, norm, loss, scale)
        if at_optimum:
            converged = True
            break
        if cand is None or not np.isfinite(cand).all() or np.linalg.norm(cand) == 0:
            converged = True
            break
        cand = cand / np.linalg.norm(cand)
        if cand @ g.m < 0:
            cand = -cand
        if norm == "l1":
            # Weiszfeld converges linearly; stepping 1.5x as far (safeguarded by the descent
            # test below) cuts the iterations by 2-3x on SfM-like data.
            cand = _slerp(g.m, cand, _L1_OVERRELAX)
        step = _step_angle(g.m, cand)
        slack = 1e-13 * abs(g.cost)  # rounding of a sum of N terms; not a real ascent
        new = _Geometry(cand, Q, w, metric, power, lossname, scale)
        # Descent safeguard: halve the step along the geodesic until the cost drops.
        halvings = 0
        while new.cost > g.cost + slack and halvings < 30:
            halvings += 1
            cand = _slerp(g.m, cand, 0.5)
            step *= 0.5
            new = _Geometry(cand, Q, w, metric, power, lossname, scale)
        if new.cost > g.cost + slack:
            converged = True  # no descent possible at machine precision: stationary
            break
        g = new
        if step < tol:
            converged = True
            break
        if norm == "l1":
            # Weiszfeld creeps towards an optimal data point only linearly: when the iterate
            # is close to a datum, test that datum's optimality condition directly.
            k = int(np.argmin(g.s))
            if 0.5 * _COINCIDENT <= g.s[k] < 5e-5 and k not in tried:
                tried.add(k)
                gk = _Geometry(Q[:, k], Q, w, metric, power)
                if _candidate(gk, Q, w, metric, norm, loss, scale)[1] and gk.cost <= g.cost + slack:
                    g, converged = gk, True
                    break
    return g, it, converged


# --------------------------------------------------------------------------- public


def mean(
    rotations,
    metric: Literal["geodesic", "chordal", "quaternion"] = "geodesic",
    norm: Literal["l1", "l2", "robust"] = "l2",
    weights=None,
    *,
    loss: str = "cauchy",
    scale_deg: float | None = None,
    init=None,
    max_iterations: int = 1000,
    tol: float = 1e-10,
) -> MeanResult:
    """Average rotations: ``argmin_R sum_i w_i d(R_i, R)^p`` (see the module docstring).

    Parameters
    ----------
    rotations : (N, 3, 3) matrices, (N, 4) quaternions ``(w, x, y, z)``, or a scipy ``Rotation``.
    metric : ``"geodesic"`` (angle), ``"chordal"`` or ``"quaternion"``.
    norm : ``"l2"`` (p = 2), ``"l1"`` (p = 1) or ``"robust"`` (IRLS with ``loss``).
    weights : (N,) non-negative weights, default all 1. Scaling them changes only the cost.
    loss : robust loss name (``norm="robust"`` only), one of :data:`rotgraph.losses.LOSSES`.
    scale_deg : robust loss scale in degrees; default twice the median angle of the data
        to their L1 median (about 3 sigma for isotropic noise), at least 1e-6 degrees.
    init : starting rotation for the iterative methods ((3, 3) or (4,)); default the
        chordal L2 mean (for ``robust``, a rough chordal L1 median).
    max_iterations, tol : stop after this many iterations or when a step is below
        ``tol`` radians.

    Returns
    -------
    MeanResult

    Examples
    --------
    >>> import numpy as np, rotgraph
    >>> R = rotgraph.so3.perturb(np.repeat(np.eye(3)[None], 50, 0), 0.05, rng=0)
    >>> res = rotgraph.mean(R, metric="geodesic", norm="l1")
    >>> bool(rotgraph.so3.angle(res.rotation) < 0.05)
    True
    """
    if metric not in METRICS:
        raise ValueError(f"unknown metric {metric!r}; expected one of {', '.join(METRICS)}")
    if norm not in NORMS:
        raise ValueError(f"unknown norm {norm!r}; expected one of {', '.join(NORMS)}")
    if norm == "robust":
        check_loss(loss)
    if norm == "l2" and metric in ("chordal", "quaternion") and init is None:
        return _l2_closed_form(rotations, weights, metric, max_iterations)
    Q = _quaternion_rows_of(rotations)  # (4, N): contiguous rows are fast
    w = _check_weights(weights, Q.shape[1])

    m0 = _chordal_l2(Q, w) if init is None else _init_quaternion(init)
    if init is None and Q.shape[1] > 4 * _SUBSAMPLE and not (metric == "chordal" and norm == "l2"):
        # Warm start: the same iterations on an evenly strided subsample bring the start
        # close to the optimum at a fraction of the cost of full passes.
        step = Q.shape[1] // _SUBSAMPLE
        sub_norm = norm if norm != "robust" else "l1"
        sub_metric = metric if norm != "robust" else "chordal"
        m0 = _iterate(m0, np.ascontiguousarray(Q[:, ::step]), w[::step], sub_metric, sub_norm, None, None, 100, 1e-6)[0].m
    warnings: list[str] = []
    scale = None
    if metric == "chordal" and norm == "l2":
        g = _Geometry(m0, Q, w, "chordal", 2)
        iterations, converged = 0, True
    elif norm == "robust":
        if init is None:  # a rough chordal L1 median: robust, cheap, close enough to start
            m0 = _iterate(m0, Q, w, "chordal", "l1", None, None, 50, 1e-4)[0].m
        if scale_deg is None:
            theta0 = _Geometry(m0, Q, w, "geodesic", 1).theta
            scale_angle = max(2.0 * float(np.median(theta0[w > 0])), np.deg2rad(1e-6))
        else:
            if not scale_deg > 0:
                raise ValueError("scale_deg must be positive")
            scale_angle = np.deg2rad(scale_deg)
        scale = scale_angle
        c = _distance_from_angle(metric, scale_angle)
        g, iterations, converged = _iterate(m0, Q, w, metric, "robust", loss, c, max_iterations, tol)
    else:
        g, iterations, converged = _iterate(m0, Q, w, metric, norm, None, None, max_iterations, tol)
        if (
            metric == "geodesic" and norm == "l2" and init is None and Q.shape[1] <= _MULTISTART_MAX
            and float(g.theta[w > 0].max()) >= np.pi / 2
        ):
            # Beyond a ball of radius pi/2 the Karcher cost can have several local minima:
            # retry from the best-supported data points and keep the lowest cost.
            score = np.abs(Q.T @ Q) @ w
            for k in np.argsort(-score)[:3]:
                g2, it2, conv2 = _iterate(Q[:, k], Q, w, metric, norm, None, None, max_iterations, tol)
                iterations += it2
                if g2.cost < g.cost - 1e-12 * abs(g.cost):
                    g, converged = g2, conv2

    if not converged:
        warnings.append(f"did not converge in {max_iterations} iterations")
    if metric == "geodesic" and norm == "l2" and float(g.theta[w > 0].max()) >= np.pi / 2:
        warnings.append(
            "data not inside a ball of radius pi/2 around the mean: the L2 geodesic mean may not be unique"
        )
    for msg in warnings:  # also in the result; "not converged" is worth a logged warning
        (logger.warning if "converge" in msg else logger.info)(msg)
    q = g.m / np.linalg.norm(g.m)
    q = q if q[0] >= 0 else -q
    logger.debug("%s %s mean: cost %.6g after %d iterations", metric, norm, g.cost, iterations)
    return MeanResult(_matrix_of(q), q, g.cost, iterations, converged, metric, norm, scale, tuple(warnings), Q.T)


def _l2_closed_form(rotations, weights, metric: str, max_iterations: int) -> MeanResult:
    """Chordal L2 (dominant eigenvector of ``sum w q q^T``) and quaternion L2 (sign-choice
    iterations from it), on (N, 4) quaternions with as few passes over the data as possible."""
    x = None
    if not hasattr(rotations, "as_quat"):
        arr = np.asarray(rotations, dtype=np.float64)
        if arr.ndim == 2 and arr.shape[1] == 4 and len(arr):
            x = arr
    if x is not None:
        n2 = np.einsum("ij,ij->i", x, x)  # NaN/inf anywhere in a row propagate here
        if not np.isfinite(n2).all():
            raise InputError(f"quaternion {int(np.argmax(~np.isfinite(n2)))} is not finite")
        if (n2 < 1e-24).any():
            raise InputError(f"quaternion {int(np.argmax(n2 < 1e-24))} is zero")
        w = _check_weights(weights, len(x))
        u = w / n2  # normalises q q^T
    else:
        x = _quaternion_rows_of(rotations).T  # unit quaternions
        w = _check_weights(weights, len(x))
        n2, u = None, w
    W = float(w.sum())
    iterations, converged, warnings = 0, True, []
    if metric == "chordal":
        K = x.T @ (x * u[:, None])
        m = _dominant_eigenvector(K)
        cost = 8.0 * (W - float(m @ K @ m))  # |R - R_i|^2 = 8 (1 - (q . q_i)^2)
    else:
        # Start at the chordal L2 mean (of an evenly strided subsample when N is large: the
        # start only picks the hemisphere of each q_i; the sign iterations below use all data).
        step = max(1, len(x) // _SUBSAMPLE)
        K = x[::step].T @ (x[::step] * u[::step, None])
        v = w if n2 is None else w / np.sqrt(n2)
        inv = None if n2 is None else 1.0 / np.sqrt(n2)
        m, support, c_min, iterations, converged = _quaternion_l2_from(_dominant_eigenvector(K), x, v, inv, w, max_iterations)
        cost = 2.0 * W - 2.0 * support  # |q -+ q_i|^2 = 2 - 2 |q . q_i|
        if c_min < np.cos(np.pi / 4) and len(x) <= _MULTISTART_MAX:
            # Some data lie beyond pi/2 of the mean: the sign iterations may stop in a local
            # minimum. Restart from the best-supported data points and the second eigenvector.
            xn = x if n2 is None else x / np.sqrt(n2)[:, None]
            score = np.abs(xn @ xn.T) @ w
            starts = [xn[k] for k in np.argsort(-score)[: 1 if len(x) > 64 else 4]]
            if len(x) <= 64:
                starts.append(np.linalg.eigh(K)[1][:, -2])
            for start in starts:
                m2, support2, _, it2, conv2 = _quaternion_l2_from(start, x, v, inv, w, max_iterations)
                cost2 = 2.0 * W - 2.0 * support2
                iterations += it2
                if cost2 < cost - 1e-12 * W:
                    m, cost, converged = m2, cost2, conv2
            warnings.append("data not inside a ball of radius pi/2 around the mean: the quaternion L2 mean may not be unique")
    if cost < 1e-6 * W:
        # The closed forms cancel (W - ...) for tight clusters: recompute the cost exactly.
        xn = x if n2 is None else x / np.sqrt(n2)[:, None]
        cost = _Geometry(m, np.ascontiguousarray(xn.T), w, metric, 2).cost
    cost = max(cost, 0.0)
    if not converged:
        warnings.append(f"did not converge in {max_iterations} iterations")
    for msg in warnings:  # also in the result; "not converged" is worth a logged warning
        (logger.warning if "converge" in msg else logger.info)(msg)
    q = m / np.linalg.norm(m)
    q = q if q[0] >= 0 else -q
    return MeanResult(_matrix_of(q), q, cost, iterations, converged, metric, "l2", None, tuple(warnings), x)


def _quaternion_l2_from(m, x, v, inv, w, max_iterations):
    """Sign iterations of the quaternion L2 mean (paper section 5.7) from ``m``: choose each
    ``q_i``'s sign in the hemisphere of ``m``, average, normalise, until the signs stop changing.

    ``v`` are the weights over the quaternion norms (``inv`` = 1 / norms, None for unit
    input). The weighted sum is updated with the flipped terms only, so an iteration costs one
    pass over the data; the final check pass is skipped when no sign can flip (every datum
    further from the hemisphere boundary than the last step moved).
    Returns ``(m, sum v |q_i . m|, min |q_i . m| / |q_i| over positive weights, iterations, converged)``.
    """
    s = x @ m
    neg = s < 0
    sv = np.where(neg, -v, v)
    total = x.T @ sv
    for it in range(1, max_iterations + 1):
        m_new = total / np.sqrt(total @ total)
        c = np.abs(s) if inv is None else np.abs(s) * inv
        c_min = float(c[w > 0].min())
        move = float(np.sqrt(((m_new - m) ** 2).sum()))
        m = m_new
        if c_min > move:  # |q_i . m| changes by at most |m_new - m|: no sign flips
            return m, float(m @ total), c_min - move, it, True
        s = x @ m
        flip = np.flatnonzero((s < 0) != neg)
        if len(flip) == 0:
            c = np.abs(s) if inv is None else np.abs(s) * inv
            return m, float(m @ total), float(c[w > 0].min()), it, True
        total = total - 2.0 * (x[flip].T @ sv[flip])
        sv[flip] = -sv[flip]
        neg[flip] = ~neg[flip]
    m = total / np.sqrt(total @ total)
    s = x @ m
    c = np.abs(s) if inv is None else np.abs(s) * inv
    return m, float(v @ np.abs(s)), float(c[w > 0].min()), max_iterations, False


def _distance_from_angle(metric: str, theta):
    if metric == "geodesic":
        return theta
    if metric == "chordal":
        return float(so3.chordal_from_angle(theta))
    return float(so3.quaternion_distance_from_angle(theta))


def _init_quaternion(init) -> np.ndarray:
    x = np.asarray(init, dtype=np.float64)
    if x.shape == (3, 3):
        return so3.quaternions_from_matrices(x)
    if x.shape == (4,):
        return x / np.linalg.norm(x)
    raise InputError(f"expected init of shape (3,3) or (4,), got {x.shape}")
