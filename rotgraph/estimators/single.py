"""Single rotation averaging (Hartley, Trumpf, Dai & Li 2013, section 5).

``mean(rotations, MeanOptions(metric, norm), weights=w)`` (or ``mean(rotations,
metric=..., norm=..., weights=w)``) minimises ``sum_i w_i d(R_i, R)^p`` over rotations
``R``, for the three metrics of the paper

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

Every iterative method starts at the chordal L2 mean (or ``init``) and is a descent method
(:mod:`.single_iterative`); the closed forms are in :mod:`.single_quaternion`. The L2
geodesic mean is unique only when the data lie in an open ball of radius pi/2; otherwise
the result carries a warning.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from .. import so3, so3_checks, so3_rows
from ..choices import METRICS, NORMS
from ..errors import InputError
from ..losses import check_loss
from ..options import Options, check_choice, check_fields, legacy_positional, resolve_options
from .single_iterative import angles, Geometry, iterate
from .single_quaternion import chordal_l2, dominant_eigenvector, quaternion_l2_large, quaternion_l2_small

__all__ = ["MeanOptions", "MeanResult", "mean", "METRICS", "NORMS", "as_quaternion_batch"]

logger = logging.getLogger(__name__)

# Above this many rotations, starting points are computed on an evenly strided subsample.
_SUBSAMPLE = 8192
# Up to this many rotations, the L2 means retry from other starts when the data are not
# inside a ball of radius pi/2 (where their costs can have several local minima).
_MULTISTART_MAX = 256
# Squared norms of the quaternions that so3_checks.check_quaternions accepts without a word.
_UNIT_LO = (1.0 - so3_checks.QUATERNION_UNIT_TOL) ** 2
_UNIT_HI = (1.0 + so3_checks.QUATERNION_UNIT_TOL) ** 2


@dataclass(frozen=True)
class MeanOptions(Options):
    """What :func:`mean` minimises and how it stops (single rotation averaging); frozen,
    :meth:`~rotgraph.options.Options.validated` by :func:`mean`.

    Parameters
    ----------
    metric : str, default "geodesic"
        The distance ``d`` between rotations, one of :data:`~rotgraph.choices.METRICS`:
        ``geodesic`` (the angle ``theta``), ``chordal`` (``|R - R_i|_F = 2 sqrt(2)
        sin(theta / 2)``) or ``quaternion`` (``2 sin(theta / 4)``).
    norm : str, default "l2"
        One of :data:`~rotgraph.choices.NORMS`: ``l2`` (the mean, ``sum w_i d_i^2``), ``l1``
        (the median, ``sum w_i d_i``) or ``robust`` (IRLS on ``sum w_i rho(d_i)``).
    loss : str, default "cauchy"
        The robust loss ``rho`` of ``norm="robust"``, one of :data:`rotgraph.losses.LOSSES`.
    scale_deg : float or None, default None
        Its scale as an angle in degrees (> 0; applied to the metric's distance of that
        angle). None: twice the median angle of the data to their L1 median (about 3 sigma
        for isotropic noise), at least 1e-6 degrees.
    max_iterations : int, default 1000
        Maximum iterations of the iterative methods (>= 0).
    step_tol_rad : float, default 1e-10
        Stop when a step (the angle between successive estimates) is below this, in
        radians (>= 0).
    """

    metric: str = "geodesic"  # geodesic, chordal or quaternion
    norm: str = "l2"  # l2 (mean), l1 (median) or robust
    loss: str = "cauchy"  # robust loss of norm="robust"
    scale_deg: float | None = None  # its scale; None: twice the median angle to the L1 median
    max_iterations: int = 1000  # of the iterative methods
    step_tol_rad: float = 1e-10  # stop when a step is below this angle

    def check(self) -> None:
        """An unknown metric, norm or loss, a ``scale_deg`` not positive, a negative
        ``max_iterations`` or ``step_tol_rad``: :class:`~rotgraph.errors.OptionError`."""
        check_choice("metric", self.metric, METRICS)
        check_choice("norm", self.norm, NORMS)
        check_loss(self.loss)
        check_fields(self, ("scale_deg",), lambda v: v > 0, "> 0")
        check_fields(self, ("max_iterations", "step_tol_rad"), lambda v: v >= 0, ">= 0")


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
        return so3.matrices_from_quaternions(self.quaternion)

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

    @cached_property
    def certificate(self) -> dict:
        """Whether this mean is certified the unique global minimum of its cost, and why
        (the paper's conditions, Hartley, Trumpf, Dai & Li 2013, section 5):

        * chordal L2: a closed form (the dominant eigenvector of the quaternions' weighted
          scatter matrix) is the global minimum; certified;
        * the other L2 and L1 costs: when every rotation lies within pi/2 (as an angle) of
          the mean, the data are inside a ball of radius pi/2, where the cost has a unique
          minimum, the mean; otherwise not certified (other minima may exist);
        * robust losses: not convex; no certificate.

        A dict (JSON-ready): ``certified``, ``reason``, ``max_angle_deg`` (the largest angle of
        a rotation to the mean), ``ball_radius_deg`` (90)."""
        theta = self.residuals
        max_deg = float(np.degrees(theta.max())) if len(theta) else 0.0
        out = {"max_angle_deg": max_deg, "ball_radius_deg": 90.0}
        if self.norm == "robust":
            return {"certified": False, "reason": "robust loss: the cost is not convex, no global certificate", **out}
        if self.metric == "chordal" and self.norm == "l2":
            return {"certified": True, "reason": "closed form: the global minimum of the chordal L2 cost", **out}
        if max_deg < 90.0:
            return {"certified": True, "reason": f"every rotation within {max_deg:.3g} deg < 90 deg of the mean: "
                                                 "inside a ball of radius pi/2 the minimum is unique", **out}
        return {"certified": False, "reason": f"a rotation lies {max_deg:.3g} deg >= 90 deg from the mean: "
                                              "the cost may have other minima", **out}



# --------------------------------------------------------------------------- input


def as_quaternion_batch(rotations, name: str | None = None) -> np.ndarray:
    """Validate a batch of rotations and return unit quaternions ``(N, 4)`` (any sign).

    Accepts matrices ``(N, 3, 3)`` (within :data:`rotgraph.so3.ROTATION_TOL` of rotations:
    :func:`rotgraph.so3.check_rotations`), quaternions ``(N, 4)`` as ``(w, x, y, z)``
    (normalised here: :func:`rotgraph.so3.check_quaternions`) or a scipy ``Rotation``.
    ``name`` (e.g. ``"L"``) prefixes the errors' "matrix k" / "quaternion k".
    """
    return np.ascontiguousarray(_quaternion_rows_of(rotations, name).T)


def _labels(name: str | None):
    """The error labels of item ``k``: ``(matrix k, quaternion k)``, prefixed by ``name``."""
    pre = "" if name is None else f"{name}: "
    return (lambda k: f"{pre}matrix {k}"), (lambda k: f"{pre}quaternion {k}")


def _quaternion_rows_of(rotations, name: str | None = None) -> np.ndarray:
    """:func:`as_quaternion_batch` as rows ``(4, N)``, the layout the iterations use."""
    if hasattr(rotations, "as_quat") and hasattr(rotations, "as_matrix"):
        q = np.atleast_2d(rotations.as_quat())
        return np.ascontiguousarray(so3.wxyz_from_xyzw(q).T)
    x = np.asarray(rotations, dtype=np.float64)
    if x.ndim == 3 and x.shape[1:] == (3, 3):
        _, Q = so3_checks.check_rotations(x, label=_labels(name)[0], quaternion_rows=True, project=False)
    elif x.ndim == 2 and x.shape[1] == 4:
        Q = so3_checks.check_quaternion_rows(x.T, label=_labels(name)[1])
    else:
        what = "rotations" if name is None else name
        raise InputError(f"expected {what} of shape (N,3,3) or quaternions (N,4), got {x.shape}")
    if Q.shape[1] == 0:
        raise InputError("no rotations to average")
    return Q


def check_weights(weights, n: int) -> np.ndarray:
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




# --------------------------------------------------------------------------- public


def mean(rotations, options: MeanOptions | None = None, *legacy, weights=None, init=None, **overrides) -> MeanResult:
    """Average rotations: ``argmin_R sum_i w_i d(R_i, R)^p`` (see the module docstring).

    ``options`` (or keyword overrides of its fields) choose the metric, the norm and the
    stopping rule, as ``average_rotations(graph, options, **overrides)`` does.

    Parameters
    ----------
    rotations : (N, 3, 3) float64 array_like, (N, 4) quaternions, or a scipy ``Rotation``
        The rotations to average: matrices, or unit quaternions ``(w, x, y, z)`` (either
        sign; normalised here).
    options : MeanOptions, optional
        The metric, norm, robust loss and stopping rule; default ``MeanOptions()`` (the
        geodesic L2 mean). The positional form of earlier versions, ``mean(rotations,
        metric, norm, weights)``, still works and warns (``DeprecationWarning``).
    weights : (N,) float64 array_like, optional
        Non-negative weights, default all 1. Scaling them changes only the cost.
    init : (3, 3) rotation or (4,) quaternion ``(w, x, y, z)``, optional
        Starting rotation of the iterative methods; default the chordal L2 mean (for
        ``robust``, a rough chordal L1 median).
    **overrides
        Fields of :class:`MeanOptions` that replace those of ``options`` (``metric=``,
        ``norm=``, ``loss=``, ``scale_deg=``, ``max_iterations=``, ``step_tol_rad=``).

    Returns
    -------
    MeanResult
        ``rotation`` (3, 3), ``quaternion`` (4,) ``(w, x, y, z)`` with ``w >= 0``, the cost,
        the iterations, per-rotation ``residuals`` (radians) and ``inliers``.

    Raises
    ------
    OptionError
        A bad option value (also a ``ValueError``); :class:`~rotgraph.errors.UnknownOptionError`
        (also a ``TypeError``) for a keyword that is no field of :class:`MeanOptions`.
    InputError
        Malformed rotations, weights or ``init``.

    Examples
    --------
    >>> import numpy as np, rotgraph
    >>> R = rotgraph.so3.perturb(np.repeat(np.eye(3)[None], 50, 0), 0.05, rng=0)
    >>> res = rotgraph.mean(R, metric="geodesic", norm="l1")
    >>> bool(rotgraph.so3.angle(res.rotation) < 0.05)
    True
    >>> same = rotgraph.mean(R, rotgraph.MeanOptions(norm="l1"))
    >>> bool((same.quaternion == res.quaternion).all())
    True
    """
    options, weights = _legacy_positional(options, legacy, weights, overrides)
    opts = resolve_options(MeanOptions, options, overrides)
    metric, norm, loss, scale_deg = opts.metric, opts.norm, opts.loss, opts.scale_deg
    max_iterations, tol = opts.max_iterations, opts.step_tol_rad
    if norm == "l2" and metric in ("chordal", "quaternion") and init is None:
        return _l2_closed_form(rotations, weights, metric, max_iterations)
    Q = _quaternion_rows_of(rotations)  # (4, N): contiguous rows are fast
    w = check_weights(weights, Q.shape[1])

    if init is None and Q.shape[1] > 4 * _SUBSAMPLE and not (metric == "chordal" and norm == "l2"):
        # Warm start: the same iterations on an evenly strided subsample (from its chordal L2
        # mean) bring the start close to the optimum at a fraction of the cost of full passes.
        step = Q.shape[1] // _SUBSAMPLE
        Qs, ws = np.ascontiguousarray(Q[:, ::step]), w[::step]
        sub_norm = norm if norm != "robust" else "l1"
        sub_metric = metric if norm != "robust" else "chordal"
        m0 = chordal_l2(Qs, ws) if ws.sum() > 0 else chordal_l2(Q, w)
        m0 = iterate(m0, Qs, ws, sub_metric, sub_norm, None, None, 100, 1e-6)[0].m
    else:
        m0 = chordal_l2(Q, w) if init is None else as_single_quaternion(init, "init")
    warnings: list[str] = []
    scale = None
    if metric == "chordal" and norm == "l2":
        g = Geometry(m0, Q, w, "chordal", 2)
        iterations, converged = 0, True
    elif norm == "robust":
        if init is None:  # a rough chordal L1 median: robust, cheap, close enough to start
            m0 = iterate(m0, Q, w, "chordal", "l1", None, None, 50, 1e-4)[0].m
        if scale_deg is None:
            theta0 = angles(m0, Q)
            scale_angle = max(2.0 * float(np.median(theta0 if (w > 0).all() else theta0[w > 0])), np.deg2rad(1e-6))
        else:
            scale_angle = np.deg2rad(scale_deg)
        scale = scale_angle
        c = _distance_from_angle(metric, scale_angle)
        g, iterations, converged = iterate(m0, Q, w, metric, "robust", loss, c, max_iterations, tol)
    else:
        g, iterations, converged = iterate(m0, Q, w, metric, norm, None, None, max_iterations, tol)
        if (
            metric == "geodesic" and norm == "l2" and init is None and Q.shape[1] <= _MULTISTART_MAX
            and g.far
        ):
            # Beyond a ball of radius pi/2 the Karcher cost can have several local minima:
            # retry from the best-supported data points and keep the lowest cost.
            score = np.abs(Q.T @ Q) @ w
            for k in np.argsort(-score)[:3]:
                g2, it2, conv2 = iterate(Q[:, k], Q, w, metric, norm, None, None, max_iterations, tol)
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
    q = so3_rows.positive_w_rows(q)
    logger.debug("%s %s mean: cost %.6g after %d iterations", metric, norm, g.cost, iterations)
    return MeanResult(q, g.cost, iterations, converged, metric, norm, scale, tuple(warnings), Q.T)


def _legacy_positional(options, legacy: tuple, weights, overrides: dict):
    """``(options, weights)`` of a :func:`mean` call; the positional form of earlier versions,
    ``mean(rotations, metric, norm, weights)`` (``options`` a str), moved into ``overrides``
    and ``weights`` with a ``DeprecationWarning`` (:func:`rotgraph.options.legacy_positional`)."""
    if not isinstance(options, str):
        if legacy:
            raise TypeError(f"mean() takes 2 positional arguments but {2 + len(legacy)} were given")
        return options, weights
    legacy_positional("mean(rotations, metric, norm, weights)", (options, *legacy), ("metric", "norm", "weights"),
                      overrides, "give them by keyword (metric=, norm=, weights=) or a MeanOptions", leading=1,
                      taken=() if weights is None else ("weights",), stacklevel=4)
    return None, overrides.pop("weights", weights)


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
        if not (_UNIT_LO <= lo and hi <= _UNIT_HI):
            # Not all finite unit quaternions: the one check raises or warns (the data are
            # normalised through the weights u below, no normalised copy is needed).
            so3_checks.check_quaternions(x, label=_labels(None)[1])
        w = check_weights(weights, len(x))
        u = w / n2  # normalises q q^T
    else:
        x = _quaternion_rows_of(rotations).T  # unit quaternions
        w = check_weights(weights, len(x))
        n2, u = None, w
    W = float(w.sum())
    iterations, converged, warnings = 0, True, []
    if metric == "chordal":
        K = x.T @ (x * u[:, None])
        m = dominant_eigenvector(K)
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
            m, support, iterations, converged, spread = quaternion_l2_small(x, u, v, inv, w, wpos, max_iterations, W)
            if spread:
                warnings.append("data not inside a ball of radius pi/2 around the mean: "
                                "the quaternion L2 mean may not be unique")
        else:
            # Start at the chordal L2 mean (of an evenly strided subsample when N is large:
            # the start only picks the hemisphere of each q_i; the sign iterations use all data).
            step = max(1, len(x) // _SUBSAMPLE)
            K = x[::step].T @ (x[::step] * u[::step, None])
            m, support, iterations, converged = quaternion_l2_large(dominant_eigenvector(K), x, v, inv, max_iterations)
        cost = 2.0 * W - 2.0 * support  # |q -+ q_i|^2 = 2 - 2 |q . q_i|
    if cost < 1e-6 * W:
        # The closed forms cancel (W - ...) for tight clusters: recompute the cost exactly.
        xn = x if n2 is None else x / np.sqrt(n2)[:, None]
        cost = Geometry(m, np.ascontiguousarray(xn.T), w, metric, 2).cost
    cost = max(cost, 0.0)
    if not converged:
        warnings.append(f"did not converge in {max_iterations} iterations")
    for msg in warnings:  # also in the result; "not converged" is worth a logged warning
        (logger.warning if "converge" in msg else logger.info)(msg)
    q = m / np.sqrt(m @ m)
    q = so3_rows.positive_w_rows(q)
    return MeanResult(q, cost, iterations, converged, metric, "l2", None, tuple(warnings), x)


def _distance_from_angle(metric: str, theta):
    if metric == "geodesic":
        return theta
    if metric == "chordal":
        return float(so3.chordal_from_angle(theta))
    return float(so3.quaternion_distance_from_angle(theta))


def as_single_quaternion(rotation, name: str = "the rotation") -> np.ndarray:
    """One rotation, a (3, 3) matrix or a (w, x, y, z) quaternion, as a unit quaternion (4,),
    validated by :func:`rotgraph.so3.check_rotations` / :func:`~rotgraph.so3.check_quaternions`;
    ``name`` names it in the errors."""
    x = np.asarray(rotation, dtype=np.float64)
    if x.shape == (3, 3):
        return so3_checks.check_rotations(x[None], label=lambda k: name, quaternion_rows=True)[1][:, 0]
    if x.shape == (4,):
        return so3_checks.check_quaternions(x[None], label=lambda k: name)[0]
    raise InputError(f"expected {name} as a rotation (3,3) or a quaternion (4,), got {x.shape}")
