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
from scipy.linalg.lapack import dsyevd as _syevd

from .. import so3
from ..errors import InputError
from ..losses import check_loss, loss_rho, loss_weight

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
    def rotation(self) -> np.ndarray:
        return _matrix_of(self.quaternion)

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
    total = w.sum()
    if np.isfinite(total) and total > 0 and w.min() >= 0:  # the common case, two passes
        return w
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


def _eigenvectors(K: np.ndarray) -> np.ndarray:
    """Eigenvectors (columns, ascending eigenvalues) of a symmetric 4x4 matrix (LAPACK
    directly: numpy's ``eigh`` costs 3x more in call overhead at this size)."""
    _, V, info = _syevd(K)
    return V if info == 0 else np.linalg.eigh(K)[1]


def _dominant_eigenvector(K: np.ndarray) -> np.ndarray:
    return _eigenvectors(K)[:, -1]


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


# Data are processed in column blocks of this many: a block's temporaries stay in the CPU
# cache, so one fused pass (distances, cost, weights and the sums of the next step) over
# 10^6 rotations costs about as much as two or three whole-array numpy operations.
_BLOCK = 8192
# Half width in cos(theta / 2) of the band of data near the cut locus (angle pi) that the
# Newton steps of the geodesic means take into account.
_BAND = 0.05


def _loss_curvature(name: str, r: np.ndarray, c: float) -> np.ndarray:
    """``rho''(r)`` of the losses of :mod:`rotgraph.losses` (for the Newton step)."""
    if name == "l2":
        return np.ones_like(r)
    if name == "l1":
        return np.zeros_like(r)
    if name in ("huber", "truncated_l2"):
        return (r <= c).astype(np.float64) if name == "huber" else (r < c).astype(np.float64)
    if name == "cauchy":
        t = (r / c) ** 2
        return (1.0 - t) / (1.0 + t) ** 2
    if name == "geman_mcclure":
        c2, r2 = c * c, r * r
        return c2 * c2 * (c2 - 3.0 * r2) / (c2 + r2) ** 3
    if name == "half_norm":
        return -0.5 * r**-1.5
    raise ValueError(f"unknown loss {name!r}")


class _Eval:
    """One fused pass over the data at a candidate mean ``m``: the cost, and the sums that
    define the next step (so an iteration reads the data once).

    ``step`` holds, for the weights ``u`` of the step (``w``, ``w / d`` or
    ``w rho'(d) / d``): geodesic ``(sum u log_i, sum u[, Hessian])``, chordal
    ``sum u q_i q_i^T``, quaternion ``sum u sign(q_i . m) q_i``. ``smin``/``kmin``: the
    smallest ``sin(theta_i / 2)`` and its index (L1 only); ``far``: whether some datum of
    positive weight is at least pi/2 away (geodesic L2 only).
    """

    __slots__ = ("m", "cost", "smin", "kmin", "far", "step", "usum")

    def __init__(self, m, Q, w, metric, norm, loss=None, scale=None, newton=False, wpos=None):
        m = m / np.linalg.norm(m)
        L = _left(m * _CONJ)
        n = Q.shape[1]
        geodesic = metric == "geodesic"
        cost = 0.0
        usum = 0.0
        smin, kmin, far = np.inf, 0, False
        G = np.zeros(3 if geodesic else 4)
        K = np.zeros((4, 4)) if metric == "chordal" else None
        H = np.zeros((3, 3)) if newton else None
        hdiag = 0.0
        Hcut = np.zeros((3, 3)) if newton else None
        nband = 0
        for lo in range(0, n, _BLOCK):
            hi = min(lo + _BLOCK, n)
            Qc = Q[:, lo:hi] if n > _BLOCK else Q
            wc = w[lo:hi] if n > _BLOCK else w
            P = L @ Qc
            P0 = P[0]
            Pv = P[1:]
            c = np.abs(P0)
            s = np.sqrt(np.einsum("ij,ij->j", Pv, Pv))
            if norm == "l1":
                k = int(np.argmin(s))
                if s[k] < smin:
                    smin, kmin = float(s[k]), lo + k
            if geodesic:
                s = np.maximum(s, 1e-150, out=s)  # theta / s -> 2 / c at s = 0
                with np.errstate(divide="ignore"):  # inf at a half turn: arctan gives pi/2
                    d = np.divide(s, c, out=np.empty_like(s))
                d = np.arctan(d, out=d)  # (arctan is twice as fast as arctan2)
                d *= 2.0
                if norm == "l2" and not far:
                    if wpos is None:
                        far = bool((s >= c).any())
                    else:
                        far = bool(((s >= c) & wpos[lo:hi]).any())
            elif metric == "chordal":
                d = s * (2.0 * np.sqrt(2.0))
            else:
                d = s * np.sqrt(2.0 / (1.0 + c))  # = 2 sin(theta / 4)
            if norm == "l2":
                wd = wc * d
                cost += float(wd @ d)
                u = wc
            elif norm == "l1":
                cost += float(wc @ d)
                u = wc / np.maximum(d, 1e-300)  # a datum the iterate sits on is handled apart
            else:
                cost += float(wc @ loss_rho(loss, d, scale))
                u = wc * loss_weight(loss, np.maximum(d, _COINCIDENT), scale)
            usum += float(u.sum())
            if geodesic:
                # log_i = sign(P0) (theta / s) P[1:]; sum u log_i
                f = d / s
                a = u * f
                G += Pv @ np.copysign(a, P0)
                if newton:
                    # Riemannian Hessian of sum w phi(theta_i): sum w [phi'' u u^T +
                    # (phi' / theta) b (I - u u^T)], b = (theta / 2) cot(theta / 2) = f c / 2
                    b = f * c
                    b *= 0.5
                    ub = u * b
                    hdiag += float(ub.sum())
                    curv = wc if norm == "l2" else wc * _loss_curvature(loss, d, scale)
                    coef = (curv - ub) / (s * s)
                    X = Pv * coef
                    h01, h02, h12 = X[0] @ Pv[1], X[0] @ Pv[2], X[1] @ Pv[2]
                    H += np.array([[X[0] @ Pv[0], h01, h02], [h01, X[1] @ Pv[1], h12], [h02, h12, X[2] @ Pv[2]]])
                    # Data near the cut locus (angle pi, |P0| < _BAND): when the mean moves they
                    # cross it and their log vectors flip, a curvature the local Hessian misses.
                    band = np.flatnonzero(c < _BAND)
                    if len(band):
                        Pb = Pv[:, band]
                        Hcut += (Pb * ((u[band] * d[band]) / (s[band] * s[band]))) @ Pb.T
                        nband += len(band)
            elif metric == "chordal":
                K += (Qc * u) @ Qc.T
            else:
                G += Qc @ np.copysign(u, P0)
        self.m, self.cost, self.smin, self.kmin, self.far, self.usum = m, cost, smin, kmin, far, usum
        if geodesic:
            self.step = (G, H + hdiag * np.eye(3), Hcut / (2.0 * _BAND), nband) if newton else (G, None)
        else:
            self.step = K if metric == "chordal" else G

    def candidate(self, metric):
        """The next iterate from the sums of the pass (None if all step weights vanish)."""
        if not self.usum > 0:
            return None
        if metric == "chordal":
            return _dominant_eigenvector(self.step)
        if metric == "quaternion":
            return self.step
        G, H = self.step[:2]
        v = G / self.usum  # the (weighted) Karcher / Weiszfeld / IRLS step
        if H is not None:
            # Newton step when the Hessian is safely positive definite (quadratic convergence
            # near the minimum); the descent test of the caller safeguards it.
            lam = np.linalg.eigvalsh(H)
            if lam[0] > 1e-8 * lam[-1] and lam[-1] > 0:
                vn = np.linalg.solve(H, G)
                Hcut, nband = self.step[2:]
                # With many data near the cut locus, a step crossing several of them sees the
                # smoothed Hessian H - Hcut (a kernel estimate of the flips' effect): for
                # uniform outliers it cancels their share, as their cost is flat on average.
                # Steps short enough to cross hardly any (about 4 band / (nband |v|)) stay local.
                if nband >= 100 and np.linalg.norm(vn) > 24.0 * _BAND / nband:
                    Hs = H - Hcut
                    lam_s = np.linalg.eigvalsh(Hs)
                    if lam_s[0] > 0.2 * lam[0]:
                        vn = np.linalg.solve(Hs, G)
                if np.isfinite(vn).all() and np.linalg.norm(vn) <= 10.0 * np.linalg.norm(v) + 1e-300:
                    v = vn
        return so3.quaternion_multiply(self.m, so3.quaternion_exp(v))


def _angles(m, Q) -> np.ndarray:
    """(N,) geodesic angle of each datum to ``m`` (blockwise)."""
    L = _left(m / np.linalg.norm(m) * _CONJ)
    n = Q.shape[1]
    out = np.empty(n)
    for lo in range(0, n, _BLOCK):
        hi = min(lo + _BLOCK, n)
        P = L @ Q[:, lo:hi]
        with np.errstate(divide="ignore"):
            np.arctan(np.sqrt(np.einsum("ij,ij->j", P[1:], P[1:])) / np.abs(P[0]), out=out[lo:hi])
    out *= 2.0
    return out


def _iterate(m0, Q, w, metric, norm, loss, scale, max_iterations, tol, newton=None):
    power = 1 if norm == "l1" else 2
    lossname = loss if norm == "robust" else None
    if newton is None:
        newton = metric == "geodesic" and norm in ("l2", "robust")
    wpos = None if (w > 0).all() else w > 0
    args = (Q, w, metric, norm, lossname, scale, newton, wpos)
    g = _Eval(m0, *args)
    converged = False
    it = 0
    tried: set[int] = set()
    for it in range(1, max_iterations + 1):
        if norm == "l1" and g.smin < 0.5 * _COINCIDENT:
            # The iterate sits on a datum: subgradient test and the Weiszfeld step without it.
            cand, at_optimum = _candidate(_Geometry(g.m, Q, w, metric, power), Q, w, metric, norm, loss, scale)
        else:
            cand, at_optimum = g.candidate(metric), False
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
        if step < tol:
            # The next step is below the tolerance: stop here, saving the pass that would
            # evaluate the candidate (this point is within about tol of the optimum).
            converged = True
            break
        slack = 1e-13 * abs(g.cost)  # rounding of a sum of N terms; not a real ascent
        new = _Eval(cand, *args)
        # Descent safeguard: halve the step along the geodesic until the cost drops.
        halvings = 0
        while new.cost > g.cost + slack and halvings < 30:
            halvings += 1
            cand = _slerp(g.m, cand, 0.5)
            step *= 0.5
            new = _Eval(cand, *args)
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
            k = g.kmin
            if 0.5 * _COINCIDENT <= g.smin < 5e-5 and k not in tried:
                tried.add(k)
                gk = _Geometry(Q[:, k], Q, w, metric, power)
                if _candidate(gk, Q, w, metric, norm, loss, scale)[1] and gk.cost <= g.cost + slack:
                    g, converged = _Eval(Q[:, k], *args), True
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

    if init is None and Q.shape[1] > 4 * _SUBSAMPLE and not (metric == "chordal" and norm == "l2"):
        # Warm start: the same iterations on an evenly strided subsample (from its chordal L2
        # mean) bring the start close to the optimum at a fraction of the cost of full passes.
        step = Q.shape[1] // _SUBSAMPLE
        Qs, ws = np.ascontiguousarray(Q[:, ::step]), w[::step]
        sub_norm = norm if norm != "robust" else "l1"
        sub_metric = metric if norm != "robust" else "chordal"
        m0 = _chordal_l2(Qs, ws) if ws.sum() > 0 else _chordal_l2(Q, w)
        m0 = _iterate(m0, Qs, ws, sub_metric, sub_norm, None, None, 100, 1e-6)[0].m
    else:
        m0 = _chordal_l2(Q, w) if init is None else as_single_quaternion(init, "init of shape (3,3) or (4,)")
    warnings: list[str] = []
    scale = None
    if metric == "chordal" and norm == "l2":
        g = _Geometry(m0, Q, w, "chordal", 2)
        iterations, converged = 0, True
    elif norm == "robust":
        if init is None:  # a rough chordal L1 median: robust, cheap, close enough to start
            m0 = _iterate(m0, Q, w, "chordal", "l1", None, None, 50, 1e-4)[0].m
        if scale_deg is None:
            theta0 = _angles(m0, Q)
            scale_angle = max(2.0 * float(np.median(theta0 if (w > 0).all() else theta0[w > 0])), np.deg2rad(1e-6))
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
            and g.far
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
    if metric == "geodesic" and norm == "l2" and g.far:
        warnings.append(
            "data not inside a ball of radius pi/2 around the mean: the L2 geodesic mean may not be unique"
        )
    for msg in warnings:  # also in the result; "not converged" is worth a logged warning
        (logger.warning if "converge" in msg else logger.info)(msg)
    q = g.m / np.linalg.norm(g.m)
    q = q if q[0] >= 0 else -q
    logger.debug("%s %s mean: cost %.6g after %d iterations", metric, norm, g.cost, iterations)
    return MeanResult(q, g.cost, iterations, converged, metric, norm, scale, tuple(warnings), Q.T)


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
        lo, hi = n2.min(), n2.max()  # (NaN propagates to the min)
        if not (lo >= 1e-24 and hi < np.inf):
            if not np.isfinite(n2).all():
                raise InputError(f"quaternion {int(np.argmax(~np.isfinite(n2)))} is not finite")
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
        if n2 is None:
            v, inv = w, None
        else:
            inv = np.sqrt(n2)
            np.divide(1.0, inv, out=inv)
            v = w * inv
        if len(x) <= _MULTISTART_MAX:
            wpos = weights is None or bool(w.min() > 0)
            m, support, iterations, converged, spread = _quaternion_l2_small(x, u, v, inv, w, wpos, max_iterations, W)
            if spread:
                warnings.append("data not inside a ball of radius pi/2 around the mean: "
                                "the quaternion L2 mean may not be unique")
        else:
            # Start at the chordal L2 mean (of an evenly strided subsample when N is large:
            # the start only picks the hemisphere of each q_i; the sign iterations use all data).
            step = max(1, len(x) // _SUBSAMPLE)
            K = x[::step].T @ (x[::step] * u[::step, None])
            m, support, iterations, converged = _quaternion_l2_large(_dominant_eigenvector(K), x, v, inv, max_iterations)
        cost = 2.0 * W - 2.0 * support  # |q -+ q_i|^2 = 2 - 2 |q . q_i|
    if cost < 1e-6 * W:
        # The closed forms cancel (W - ...) for tight clusters: recompute the cost exactly.
        xn = x if n2 is None else x / np.sqrt(n2)[:, None]
        cost = _Geometry(m, np.ascontiguousarray(xn.T), w, metric, 2).cost
    cost = max(cost, 0.0)
    if not converged:
        warnings.append(f"did not converge in {max_iterations} iterations")
    for msg in warnings:  # also in the result; "not converged" is worth a logged warning
        (logger.warning if "converge" in msg else logger.info)(msg)
    q = m / np.sqrt(m @ m)
    q = q if q[0] >= 0 else -q
    return MeanResult(q, cost, iterations, converged, metric, "l2", None, tuple(warnings), x)


_COS_QUARTER_PI = float(np.cos(np.pi / 4))


def _quaternion_l2_small(x, u, v, inv, w, wpos, max_iterations, W=None):
    """Quaternion L2 mean of few rotations: the sign iterations of paper section 5.7 (choose
    each ``q_i``'s sign in the hemisphere of ``m``, average, normalise, until the signs stop
    changing) run from several starts at once, as one (N, starts) problem.

    The first start is the chordal L2 mean. When some datum of positive weight ends beyond
    pi/2 of its fixed point (``|q_i . m| < cos(pi/4)``) the cost can have other local minima,
    and the best fixed point of all the starts is kept: for N <= 64 the 4 data points of
    highest support ``sum_j w_j |q_i . q_j|`` and the second eigenvector of ``sum w q q^T``,
    beyond that the datum of highest chordal support ``sum_j w_j (q_i . q_j)^2``.
    The columns are not normalised during the iterations (signs do not depend on scale);
    at a fixed point ``T = sum v_i sign_i q_i`` the support ``sum v |q_i . m|`` is ``|T|``.
    Returns ``(m, sum v |q_i . m|, iterations, converged, spread)``.
    """
    n = len(x)
    if n <= _EXHAUSTIVE_MAX:
        return _quaternion_l2_exhaustive(x, v, inv, w, wpos)
    xn = x if inv is None else x * inv[:, None]
    K = x.T @ (x * u[:, None])
    V = _eigenvectors(K)
    if n > 64:
        # The datum of highest chordal support sum_j w_j (q_i . q_j)^2 = q_i^T K q_i (O(N)
        # instead of the O(N^2) support of every datum).
        M = np.empty((4, 2))
        M[:, 1] = xn[int(np.argmax(np.einsum("ij,ij->i", xn @ K, xn)))]
    else:
        score = np.abs(xn @ xn.T) @ w
        top = np.argsort(score)[:-5:-1]  # the 4 highest
        M = np.empty((4, len(top) + 2))
        M[:, 1:-1] = xn[top].T
        M[:, -1] = V[:, -2]
    M[:, 0] = V[:, -1]
    vc = v[:, None]
    sg = np.copysign(vc, x @ M)  # v_i sign(q_i . m) per start
    T = x.T @ sg
    it = 0
    converged = False
    for it in range(1, max_iterations + 1):
        S = x @ T
        new = np.copysign(vc, S)
        if not (new != sg).any():
            converged = True
            break
        sg = new
        T = x.T @ sg
    norms = np.sqrt((T * T).sum(axis=0))
    if converged:
        support = norms.tolist()
        changed = [False] * len(support)
    else:
        changed = (np.copysign(vc, x @ T) != sg).any(axis=0)
        S = x @ T  # at the normalised T / |T| below
        support = ((v @ np.abs(S)) / norms).tolist()
    c0 = np.abs(S[:, 0])
    if inv is not None:
        c0 *= inv
    spread = float(c0.min() if wpos else c0[w > 0].min()) < _COS_QUARTER_PI * float(norms[0])
    best = 0
    if spread:
        # Beyond a ball of radius pi/2 the sign iterations may stop in a local minimum: keep
        # the lowest cost (the chordal start unless another is lower beyond rounding).
        W = float(w.sum()) if W is None else W
        for j in range(1, M.shape[1]):
            if 2.0 * support[j] > 2.0 * support[best] + 1e-12 * W:
                best = j
    return T[:, best] / norms[best], support[best], it, not bool(changed[best]), spread


# Up to this many rotations the quaternion L2 mean is found by trying every sign choice.
_EXHAUSTIVE_MAX = 12
_SIGN_TABLES: dict = {}


def _quaternion_l2_exhaustive(x, v, inv, w, wpos):
    """Quaternion L2 mean of at most :data:`_EXHAUSTIVE_MAX` rotations, exactly: the cost
    ``sum w_i (2 - 2 |q . q_i|)`` is minimal where ``sum w_i |q . q_i|`` is maximal, and
    ``max_q sum w_i |q . q_i| = max_s |sum_i s_i w_i q_i|`` over the sign vectors ``s``
    (with ``q`` the normalised sum): one matrix product over all ``2^(N-1)`` of them.
    Returns what :func:`_quaternion_l2_small` returns."""
    n = len(x)
    S = _SIGN_TABLES.get(n)
    if S is None:  # rows: every sign vector with s_0 = +1
        bits = (np.arange(2 ** (n - 1))[:, None] >> np.arange(n - 1)) & 1
        S = _SIGN_TABLES[n] = np.hstack([np.ones((len(bits), 1)), 1.0 - 2.0 * bits])
    T = S @ (x * v[:, None])  # (2^(N-1), 4): sum s_i v_i q_i, v_i = w_i / |q_i|
    norms = np.einsum("ij,ij->i", T, T)
    best = int(np.argmax(norms))
    support = float(np.sqrt(norms[best]))
    m = T[best] / support if support > 0 else np.array([1.0, 0.0, 0.0, 0.0])
    c = np.abs(x @ m)
    if inv is not None:
        c *= inv
    spread = float(c.min() if wpos else c[w > 0].min()) < _COS_QUARTER_PI
    return m, support, 0, True, spread


def _quaternion_l2_large(m, x, v, inv, max_iterations):
    """Sign iterations of the quaternion L2 mean (paper section 5.7) from ``m`` for many data.

    One pass fixes the signs at the start and the weighted sum; then only the data within a
    band of the hemisphere boundary (``|q_i . m| / |q_i| < margin``) can change sign while
    the iterate stays within ``margin`` of the start, so the iterations touch those alone
    (a new band is taken if the iterate moves farther).
    Returns ``(m, sum v |q_i . m|, iterations, converged)``.
    """
    margin = 0.1
    it = 0
    total = None
    while True:
        s = x @ m
        c = np.abs(s)
        if inv is not None:
            c *= inv
        neg = s < 0
        total = x.T @ np.where(neg, -v, v)
        band = np.flatnonzero(c < margin)
        xb, vb, negb = x[band], v[band], neg[band]
        m_ref = m
        while it < max_iterations:
            it += 1
            m = total / np.sqrt(total @ total)
            dm = m - m_ref
            if dm @ dm >= 0.25 * margin * margin:
                break  # left the band's region of validity: take a new one
            new_neg = xb @ m < 0
            flip = np.flatnonzero(new_neg != negb)
            if len(flip) == 0:
                return m, float(m @ total), it, True
            total = total - 2.0 * (xb[flip].T @ np.where(negb[flip], -vb[flip], vb[flip]))
            negb[flip] = ~negb[flip]
        else:
            m = total / np.sqrt(total @ total)
            return m, float(v @ np.abs(x @ m)), it, False


def _distance_from_angle(metric: str, theta):
    if metric == "geodesic":
        return theta
    if metric == "chordal":
        return float(so3.chordal_from_angle(theta))
    return float(so3.quaternion_distance_from_angle(theta))


def as_single_quaternion(rotation, what: str = "a rotation (3,3) or a quaternion (4,)") -> np.ndarray:
    """One rotation, a (3, 3) matrix or a (w, x, y, z) quaternion, as a unit quaternion (4,);
    ``what`` names the expected input in the error message."""
    x = np.asarray(rotation, dtype=np.float64)
    if x.shape == (3, 3):
        return so3.quaternions_from_matrices(x)
    if x.shape == (4,):
        return x / np.linalg.norm(x)
    raise InputError(f"expected {what}, got {x.shape}")
