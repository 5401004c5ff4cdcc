"""Conjugate rotation averaging: hand-eye calibration (Hartley, Trumpf, Dai & Li 2013, section 6).

Given pairs of rotations ``(L_i, R_i)`` find the rotation ``S`` with

    R_i ~ S^T L_i S        (equivalently  L_i S = S R_i)

minimising ``sum_i w_i d(R_i, S^T L_i S)^p``. In hand-eye calibration ``L_i`` are robot
(gripper) motions, ``R_i`` the camera motions seen over the same steps, and ``S`` is the
hand-eye rotation: ``gripper_from_camera`` (OpenCV's ``R_cam2gripper``) for the motions that
:func:`motions_from_poses` forms from absolute poses (its docstring says which frames).

In general ``S`` maps the frame of the ``R_i`` into the frame of the ``L_i``: the rotation
axes (log vectors) satisfy ``log(L_i) = S log(R_i)``, and the angles are equal,
``|log L_i| = |log R_i|`` (a pair whose angles differ cannot be fitted exactly by any S).

Symmetries (tested): ``L_i -> W L_i W^T`` gives ``S -> W S``; ``R_i -> V R_i V^T`` gives
``S -> S V^T``; swapping the roles of ``L`` and ``R`` gives ``S^T``; ``q`` and ``-q`` of
any input are the same rotation and give the same result.

:func:`solve_handeye` is the entry point; with the motions' translations it also returns
the translation ``t_X`` of ``X = [S | t_X]`` in ``A_i X = X B_i``. Behind it:

* :mod:`.handeye_rotation`: the rotation estimators (closed forms, Gauss-Newton and IRLS on
  SO(3), minimal 2-pair hypotheses scored a contrario, noise and threshold estimates) and
  the degeneracy test of :func:`conditioning`;
* :mod:`.handeye_translation`: ``t_X`` given ``S``, and the joint estimate of ``S`` and
  ``t_X`` (the default of the ``robust`` method when translations are given).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Literal, NamedTuple

import numpy as np

from .. import so3, so3_checks
from ..choices import HANDEYE_METHODS as METHODS
from ..errors import InputError, OptionError, UnsolvableError
from ..losses import check_loss
from .laplacian import one_blas_thread
from .handeye_rotation import (
    check_conditioning,
    errors,
    iterate,
    kappa_and_axis,
    procrustes_closed_form,
    quaternion_closed_form,
    robust,
    rows,
    weighted_cost,
)
from .handeye_translation import check_translations, translation_errors, translation_stage
from ..options import Options, check_choice, check_fields, resolve_options
from .single import check_weights, as_quaternion_batch, as_single_quaternion

__all__ = [
    "HandEyeOptions",
    "HandEyeResult",
    "Motions",
    "METHODS",
    "solve_handeye",
    "motions_from_poses",
    "handeye_translation_residuals",
    "pose_residuals",
    "handeye_residuals",
    "conditioning",
]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class HandEyeOptions(Options):
    """How :func:`solve_handeye` estimates ``S`` (conjugate rotation averaging, hand-eye
    calibration); frozen, :meth:`~rotgraph.options.Options.validated` by :func:`solve_handeye`.

    Parameters
    ----------
    method : str, default "robust"
        One of :data:`METHODS` (details in :mod:`.handeye_rotation`):

        * ``"robust"``: 2-pair hypotheses scored a contrario (no threshold needed, works
          with more wrong pairs than right ones), geodesic L2 on the consensus set with an
          inlier threshold re-estimated from the data, then IRLS with ``loss``; pairs within
          the threshold are flagged as inliers;
        * ``"quaternion"``: closed form, ``sum w_i d_quat^2`` (``(Q_left(l_i) -
          Q_right(r_i)) s = 0`` in the least-squares sense);
        * ``"procrustes"``: closed form (Park & Martin 1994), the weighted orthogonal
          Procrustes fit of the log vectors, ``log L_i = S log R_i``;
        * ``"l2"`` / ``"l1"``: geodesic L2 (``sum w_i theta_i^2``, Gauss-Newton on SO(3))
          and L1 (``sum w_i theta_i``, IRLS), ``theta_i`` the angle of ``R_i^T S^T L_i S``.
    loss : str, default "truncated_l2"
        Robust loss of the ``robust`` method, one of :data:`rotgraph.losses.LOSSES`.
    scale_deg : float or None, default None
        Its scale in degrees (> 0); None: the inlier threshold.
    threshold_deg : float or None, default None
        Inlier threshold in degrees (> 0). None: ``robust`` sets it from the data (4.03
        times the per-axis noise estimated from the inliers' median residual); the other
        methods flag every pair an inlier.
    seed : int or None, default 0
        Seed of the random minimal samples (drawn only when there are more than
        ``max_hypotheses`` pairs of pairs; otherwise all are tried).
    max_hypotheses : int, default 500
        Pairs of pairs tried as hypotheses by ``robust`` (>= 1).
    max_iterations : int, default 200
        Maximum iterations of the iterative stages (>= 0).
    step_tol_rad : float, default 1e-11
        The iterative stages stop when a step is below this angle in radians (>= 0).
    rotation_only : bool, default False
        With translations, keep ``S`` from the rotations alone (``t_X`` is then fitted
        given ``S``). The methods but ``robust`` are always rotation-only.
    """

    method: str = "robust"  # robust, quaternion, procrustes, l2 or l1
    loss: str = "truncated_l2"  # robust loss of method="robust"
    scale_deg: float | None = None  # its scale; None: the inlier threshold
    threshold_deg: float | None = None  # inlier threshold; None: robust from the data, else all inliers
    seed: int | None = 0  # of the random minimal samples
    max_hypotheses: int = 500  # pairs of pairs tried by robust
    max_iterations: int = 200  # of the iterative stages
    step_tol_rad: float = 1e-11  # the iterative stages stop when a step is below this angle
    rotation_only: bool = False  # with translations: S from the rotations alone

    def check(self) -> None:
        """An unknown method or loss, a scale or threshold not positive, no hypothesis, a
        negative ``max_iterations`` or ``step_tol_rad``: :class:`~rotgraph.errors.OptionError`."""
        check_choice("method", self.method, METHODS)
        check_loss(self.loss)
        check_fields(self, ("scale_deg", "threshold_deg"), lambda v: v > 0, "> 0")
        check_fields(self, ("max_hypotheses",), lambda v: v >= 1, ">= 1")
        check_fields(self, ("max_iterations", "step_tol_rad"), lambda v: v >= 0, ">= 0")


@dataclass(frozen=True)
class HandEyeResult:
    """The outcome of :func:`solve_handeye`.

    Attributes
    ----------
    rotation : (3, 3) ``S`` with ``R_i ~ S^T L_i S`` (``gripper_from_camera`` for poses
        from :func:`motions_from_poses`; OpenCV's ``R_cam2gripper``).
    quaternion : (4,) ``S`` as ``(w, x, y, z)``, ``w >= 0``.
    residuals_deg : (N,) angle of ``R_i^T S^T L_i S`` in degrees, for every pair.
    inliers : (N,) bool: residual within ``threshold_deg`` (all True when there is no
        threshold: non-robust methods without ``threshold_deg``). Zero-weight pairs are
        flagged by the same test but never used.
    cost : the minimised cost: ``sum w d_quat^2`` (quaternion), ``sum w |log L - S log R|^2``
        (procrustes), ``sum w theta^2`` (l2), ``sum w theta`` (l1), ``sum w rho(theta)``
        (robust), angles in radians.
    iterations : iterations of the final stage (sign-fixing passes for the closed forms).
    converged : whether that stage met its stopping test.
    method : the method name.
    threshold_deg : the inlier threshold (degrees), or None.
    scale_deg : the robust loss scale (degrees), or None.
    conditioning : ``kappa`` of :func:`conditioning` over the pairs used (0: degenerate).
    warnings : human-readable warnings (near-degenerate data, weak consensus, ...).
    translation : (3,) ``t_X`` (``gripper_from_camera`` translation, the units of the input
        translations), or None when no translations were given.
    translation_residuals : (N,) ``|e_i| = |(L_i - I) t_X - S t_R,i + t_L,i|`` per pair, or None.
    translation_inliers : (N,) bool: ``|e_i|`` within ``translation_threshold`` (all True
        without one), or None.
    translation_threshold : the translation inlier threshold (robust: ``4.03 sigma_t``), or None.
    joint : whether ``S`` was estimated jointly with ``t_X`` (:mod:`.handeye_translation`); then
        ``cost`` is the joint cost ``sum u_r theta^2 + sum u_t |e|^2`` with the final
        weights ``u = w rho'(r) / r / sigma^2`` of each block, and ``iterations`` counts the
        Gauss-Newton iterations of all rounds.
    sigma_deg, sigma_translation : the per-axis noise ``sigma_r`` (degrees) and ``sigma_t``
        (translation units) that weight the two blocks of the joint cost, or None.
    """

    rotation: np.ndarray
    quaternion: np.ndarray
    residuals_deg: np.ndarray
    inliers: np.ndarray
    cost: float
    iterations: int
    converged: bool
    method: str
    threshold_deg: float | None = None
    scale_deg: float | None = None
    conditioning: float = float("nan")
    warnings: tuple[str, ...] = field(default_factory=tuple)
    translation: np.ndarray | None = None
    translation_residuals: np.ndarray | None = None
    translation_inliers: np.ndarray | None = None
    translation_threshold: float | None = None
    joint: bool = False
    sigma_deg: float | None = None
    sigma_translation: float | None = None

    @property
    def n_inliers(self) -> int:
        return int(self.inliers.sum())


class Motions(NamedTuple):
    """Relative motions formed from absolute poses by :func:`motions_from_poses`.

    The translations are None when the poses were given as rotations only.
    """

    robot: np.ndarray  # (M, 3, 3) L = gripper_j_from_gripper_i = G_j^T G_i
    camera: np.ndarray  # (M, 3, 3) R = cam_j_from_cam_i = C_j C_i^T
    pairs: np.ndarray  # (M, 2) int64 pose indices (i, j)
    robot_translations: np.ndarray | None = None  # (M, 3) t_L = R_Gj^T (t_Gi - t_Gj)
    camera_translations: np.ndarray | None = None  # (M, 3) t_R = t_Cj - R t_Ci


def handeye_residuals(S, L, R) -> np.ndarray:
    """Angles (radians) of ``R_i^T S^T L_i S``: the residual of each pair for the rotation ``S``.

    ``S`` is (3, 3) or a quaternion (4,); ``L``, ``R`` (N, 3, 3) or (N, 4).
    """
    s = as_single_quaternion(S, "S")
    return errors(s, rows(as_quaternion_batch(L, "L")), rows(as_quaternion_batch(R, "R")))[2]


def handeye_translation_residuals(S, t, L, robot_translations, camera_translations) -> np.ndarray:
    """``|e_i| = |(L_i - I) t - S t_R,i + t_L,i|``: the translation residual of each pair for
    ``X = [S | t]`` (``S`` (3, 3) or a quaternion (4,); ``L`` (N, 3, 3) or (N, 4); the
    motions' translations (N, 3)). The camera rotations ``R_i`` do not enter it."""
    Sm = so3.matrices_from_quaternions(as_single_quaternion(S, "S"))
    Lm = so3.matrices_from_quaternions(as_quaternion_batch(L, "L"))
    n = len(Lm)
    tL = check_translations(robot_translations, n, "robot_translations")
    tR = check_translations(camera_translations, n, "camera_translations")
    return np.linalg.norm(translation_errors(Sm, Lm, tL, tR, np.asarray(t, dtype=np.float64)), axis=1)


def conditioning(rotations, weights=None) -> tuple[float, np.ndarray]:
    """``(kappa, axis)``: how well pairs with these rotations determine ``S``.

    ``kappa^2`` is the smallest eigenvalue of ``sum w_i (|v_i|^2 I - v_i v_i^T) / sum w_i``
    with ``v_i`` the vector part of the quaternion (``sin(theta_i / 2)`` times the axis);
    ``axis`` is its eigenvector, the direction about which ``S`` is least constrained.
    ``4 sum w_i (|v_i|^2 I - v_i v_i^T)`` is the Gauss-Newton matrix of the geodesic L2 cost
    at an exact solution (in the frame of the rotations given).

    ``S`` is determined only when two rotations have non-parallel axes: ``kappa`` is the
    root mean square, over the pairs, of ``sin(theta_i / 2)`` times the sine of the angle
    between the axis and the least constrained direction, 0 when all axes are parallel or
    all rotations are the identity. :func:`solve_handeye` computes it for the ``L_i`` and
    the ``R_i`` and uses the smaller: below ``1e-6`` an
    :class:`~rotgraph.errors.UnsolvableError` says which of the two it is; below ``0.02``
    the result carries a warning (``S`` is poorly determined about ``axis``).
    """
    q = rows(as_quaternion_batch(rotations))
    w = check_weights(weights, q.shape[1])
    return kappa_and_axis(q, w)


# --------------------------------------------------------------------------- public


def _checked_pairs(L, R, weights, robot_translations, camera_translations):
    """``(lq, rq, w, tL, tR)``: :func:`solve_handeye`'s pairs as quaternion rows, their
    weights and translations (None without); InputError for malformed input,
    UnsolvableError for fewer than two pairs of positive weight."""
    lq = rows(as_quaternion_batch(L, "L"))
    rq = rows(as_quaternion_batch(R, "R"))
    n = lq.shape[1]
    if n != rq.shape[1]:
        raise InputError(f"L has {n} rotations but R has {rq.shape[1]}: expected one pair per index")
    w = check_weights(weights, n)
    if (robot_translations is None) != (camera_translations is None):
        raise InputError("give both robot_translations and camera_translations, or neither")
    tL = tR = None
    if robot_translations is not None:
        tL = check_translations(robot_translations, n, "robot_translations")
        tR = check_translations(camera_translations, n, "camera_translations")
    if int((w > 0).sum()) < 2:
        raise UnsolvableError(f"need at least two pairs (with positive weight), got {int((w > 0).sum())}")
    return lq, rq, w, tL, tR


def _plain_fit(method: str, lq: np.ndarray, rq: np.ndarray, w: np.ndarray, max_iterations: int, tol: float):
    """``(s, theta, cost, iterations, converged)`` of the non-robust methods."""
    iterations, converged = 0, True
    if method == "quaternion":
        s, cost, iterations, converged = quaternion_closed_form(lq, rq, w)
        theta = errors(s, lq, rq)[2]
    elif method == "procrustes":
        s, cost, iterations, converged = procrustes_closed_form(lq, rq, w)
        theta = errors(s, lq, rq)[2]
    else:  # "l2", "l1"
        s0 = quaternion_closed_form(lq, rq, w)[0]
        s, theta, iterations, converged = iterate(s0, lq, rq, w, "l2", max_iterations=max_iterations, tol=tol)
        if method == "l1":
            s, theta, iterations, converged = iterate(s, lq, rq, w, "l1", max_iterations=max_iterations, tol=tol)
        cost = weighted_cost(method, theta, w, None, None)
    return s, theta, cost, iterations, converged


def _robust_fit(lq: np.ndarray, rq: np.ndarray, w: np.ndarray, loss: str, scale_deg, threshold, seed,
                max_hypotheses: int, max_iterations: int, tol: float):
    """``(s, theta, cost, threshold, scale, iterations, converged, kappa, warnings)`` of the
    ``robust`` method, the conditioning judged on its inliers."""
    s, theta, inl, threshold, scale, iterations, converged, more = robust(
        lq, rq, w, loss, None if scale_deg is None else np.deg2rad(scale_deg), threshold, seed,
        max_hypotheses, max_iterations, tol,
    )
    cost = weighted_cost("robust", theta, w, loss, scale)
    use = w * inl
    if int((use > 0).sum()) < 2:
        raise UnsolvableError("fewer than two pairs agree on any S (no consensus among the pairs)")
    # Outliers can hide a degenerate set of inliers: judge the inliers alone.
    kappa, warnings = check_conditioning(lq, rq, use, "the inlier pairs")
    warnings += more
    n_in = int(inl[w > 0].sum())
    if n_in < 3:
        warnings.append(f"only {n_in} pairs are inliers: S rests on too few pairs to be checked")
    return s, theta, cost, threshold, scale, iterations, converged, kappa, warnings


@one_blas_thread
def solve_handeye(
    L,
    R,
    options: HandEyeOptions | None = None,
    *,
    weights=None,
    robot_translations=None,
    camera_translations=None,
    **overrides,
) -> HandEyeResult:
    """Conjugate rotation averaging: ``S = argmin sum_i w_i d(R_i, S^T L_i S)^p``; with the
    motions' translations, hand-eye calibration ``A_i X = X B_i`` (also ``t_X``).

    ``options`` (or keyword overrides of its fields) choose the method, as
    ``average_rotations(graph, options, **overrides)`` does.

    Parameters
    ----------
    L : (N, 3, 3) float64 array_like or (N, 4) quaternions ``(w, x, y, z)`` (either sign)
        Robot motions (``gripper_j_from_gripper_i``, see :func:`motions_from_poses`).
    R : (N, 3, 3) float64 array_like or (N, 4) quaternions ``(w, x, y, z)``
        The camera motions (``cam_j_from_cam_i``), pair ``i`` with ``L[i]``.
    options : HandEyeOptions, optional
        The method, robust loss, thresholds and stopping rule; default ``HandEyeOptions()``
        (``method="robust"``).
    weights : (N,) float64 array_like, optional
        Non-negative pair weights (default 1); zero-weight pairs are not used but get
        residuals.
    robot_translations, camera_translations : (N, 3) float64 array_like, optional
        Translations ``t_L,i`` and ``t_R,i`` of the motions (both or neither;
        :func:`motions_from_poses` forms them), in any common unit. Then the result has
        ``t_X`` (``translation``), and the ``robust`` method estimates ``S`` and ``t_X``
        jointly (:mod:`.handeye_translation`: the translations then constrain ``S`` too),
        unless ``rotation_only``.
    **overrides
        Fields of :class:`HandEyeOptions` that replace those of ``options`` (``method=``,
        ``loss=``, ``scale_deg=``, ``threshold_deg=``, ``seed=``, ``max_hypotheses=``,
        ``max_iterations=``, ``step_tol_rad=``, ``rotation_only=``).

    Returns
    -------
    HandEyeResult

    Raises
    ------
    OptionError : a bad option value (also a ``ValueError``);
        :class:`~rotgraph.errors.UnknownOptionError` (also a ``TypeError``) for a keyword
        that is no field of :class:`HandEyeOptions`.
    InputError : malformed input (shapes, non-rotations, bad weights).
    UnsolvableError : degenerate input (fewer than two pairs, all rotation axes parallel,
        all rotations near the identity).

    Examples
    --------
    >>> import numpy as np
    >>> from rotgraph import so3
    >>> S = so3.random_rotations(rng=1)
    >>> L = so3.random_rotations(10, rng=2)
    >>> R = S.T @ L @ S
    >>> res = solve_handeye(L, R)
    >>> bool(so3.angle_between(res.rotation, S) < 1e-10)
    True
    """
    opts = resolve_options(HandEyeOptions, options, overrides)
    method, loss, scale_deg, threshold_deg = opts.method, opts.loss, opts.scale_deg, opts.threshold_deg
    max_iterations, tol = opts.max_iterations, opts.step_tol_rad
    lq, rq, w, tL, tR = _checked_pairs(L, R, weights, robot_translations, camera_translations)
    n = lq.shape[1]
    kappa, warnings = check_conditioning(lq, rq, w)
    threshold = None if threshold_deg is None else np.deg2rad(threshold_deg)
    scale = None
    if method == "robust":
        s, theta, cost, threshold, scale, iterations, converged, kappa, warnings = _robust_fit(
            lq, rq, w, loss, scale_deg, threshold, opts.seed, opts.max_hypotheses, max_iterations, tol)
    else:
        s, theta, cost, iterations, converged = _plain_fit(method, lq, rq, w, max_iterations, tol)
    fit = None
    if tL is not None:
        joint = method == "robust" and not opts.rotation_only
        fit, joint, more = translation_stage(
            s, lq, rq, tL, tR, w, theta, threshold, robust=method == "robust", joint=joint, loss=loss,
            scale=None if scale_deg is None else np.deg2rad(scale_deg), fixed_threshold=threshold_deg is not None,
            max_iterations=max_iterations, tol=tol,
        )
        warnings += more
        if joint:
            s, theta, threshold = fit.s, fit.theta, fit.rot_threshold
            iterations, converged, cost = fit.iterations, fit.converged, fit.cost
            if scale_deg is None and scale is not None:
                scale = threshold
    if not converged:
        warnings.append(f"did not converge in {max_iterations} iterations")
    residuals_deg = np.degrees(theta)
    if threshold_deg is not None:
        threshold_out = float(threshold_deg)
    else:
        threshold_out = None if threshold is None else float(np.degrees(threshold))
    inliers = np.ones(n, dtype=bool) if threshold_out is None else residuals_deg <= threshold_out
    for msg in warnings:
        logger.warning(msg)
    q = so3.canonical_quaternions(s)
    return HandEyeResult(
        rotation=so3.matrices_from_quaternions(q),
        quaternion=q,
        residuals_deg=residuals_deg,
        inliers=inliers,
        cost=cost,
        iterations=iterations,
        converged=converged,
        method=method,
        threshold_deg=threshold_out,
        scale_deg=float(scale_deg) if scale_deg is not None else (None if scale is None else float(np.degrees(scale))),
        conditioning=kappa,
        warnings=tuple(warnings),
        translation=None if fit is None else fit.t,
        translation_residuals=None if fit is None else fit.residuals,
        translation_inliers=None if fit is None else fit.inliers,
        translation_threshold=None if fit is None else fit.threshold,
        joint=fit is not None and joint,
        sigma_deg=None if fit is None or fit.sigma_r is None else float(np.degrees(fit.sigma_r)),
        sigma_translation=None if fit is None else fit.sigma_t,
    )


# --------------------------------------------------------------------------- poses


def _pose_parts(poses, name: str) -> tuple[np.ndarray, np.ndarray | None]:
    """Rotations (N, 3, 3) and translations (N, 3) (None for rotations-only input)."""
    x = np.asarray(poses, dtype=np.float64)
    t = None
    if x.ndim == 3 and x.shape[1:] in ((4, 4), (3, 4)):
        t = x[:, :3, 3].copy()
        if not np.isfinite(t).all():
            raise InputError(f"{name}: pose {int(np.argmax(~np.isfinite(t).all(axis=1)))} has a translation that is not finite")
        x = x[:, :3, :3]
    if x.ndim == 3 and x.shape[1:] == (3, 3):
        return so3_checks.check_rotations(x, label=lambda k: f"{name}: pose {k}"), t
    if x.ndim == 2 and x.shape[1] == 4:
        return so3.matrices_from_quaternions(as_quaternion_batch(x, name)), None
    raise InputError(f"{name}: expected poses (N,4,4), (N,3,4), rotations (N,3,3) or quaternions (N,4), got {x.shape}")


def motions_from_poses(base_from_gripper, cam_from_target, pairs: Literal["consecutive", "all"] = "consecutive") -> Motions:
    """Relative motions ``(L, R)`` from absolute poses, for :func:`solve_handeye`.

    Parameters
    ----------
    base_from_gripper : (N, 4, 4) / (N, 3, 4) poses, (N, 3, 3) rotations or (N, 4)
        quaternions: the gripper in the robot base frame (OpenCV's ``R_gripper2base``,
        ``t_gripper2base``; for eye-to-hand pass ``gripper_from_base`` instead, as with OpenCV).
    cam_from_target : the same for the target in the camera frame (``R_target2cam``,
        ``t_target2cam``, e.g. from ``solvePnP``).
    pairs : ``"consecutive"`` (poses ``(k, k+1)``: N - 1 motions) or ``"all"`` (every
        ``i < j``, N (N - 1) / 2 motions, the set ``cv2.calibrateHandEye`` uses).

    Returns
    -------
    Motions ``(robot, camera, pairs, robot_translations, camera_translations)`` with
    ``robot = G_j^T G_i`` (gripper_j_from_gripper_i), ``camera = C_j C_i^T``
    (cam_j_from_cam_i) for each index pair ``(i, j)``, so that ``camera = S^T robot S``
    with ``S = gripper_from_camera`` (OpenCV's ``R_cam2gripper``). When both pose sets have
    translations (4x4 or 3x4 poses), the motions' translations
    ``t_L = R_Gj^T (t_Gi - t_Gj)`` and ``t_R = t_Cj - camera t_Ci`` (pass them to
    :func:`solve_handeye` for ``t_X`` and the joint estimate); otherwise both are None.

    Notes
    -----
    Which rotation ``S`` is: with ``G_k = base_from_gripper`` and ``C_k = cam_from_target``,
    ``G_k X C_k`` is the same for every ``k`` (``base_from_target``, fixed) with
    ``X = gripper_from_camera``, so ``L X = X R`` for ``L = G_j^T G_i`` and
    ``R = C_j C_i^T``: the solution ``S`` is ``gripper_from_camera``, OpenCV's
    ``R_cam2gripper`` output of ``cv2.calibrateHandEye``. For eye-to-hand (camera fixed,
    target on the gripper) pass ``gripper_from_base`` (``G_k^T``) in place of
    ``base_from_gripper``, as with OpenCV; ``S`` is then ``base_from_camera``.
    """
    G, tG = _pose_parts(base_from_gripper, "base_from_gripper")
    C, tC = _pose_parts(cam_from_target, "cam_from_target")
    if len(G) != len(C):
        raise InputError(f"base_from_gripper has {len(G)} poses but cam_from_target has {len(C)}")
    n = len(G)
    if pairs == "consecutive":
        i = np.arange(n - 1)
        j = i + 1
    elif pairs == "all":
        i, j = np.triu_indices(n, 1)
    else:
        raise OptionError(f"unknown pairs {pairs!r}; expected 'consecutive' or 'all'")
    Gjt = np.swapaxes(G[j], 1, 2)
    robot = Gjt @ G[i]
    camera = C[j] @ np.swapaxes(C[i], 1, 2)
    t_robot = t_camera = None
    if tG is not None and tC is not None:
        t_robot = (Gjt @ (tG[i] - tG[j])[:, :, None])[:, :, 0]
        t_camera = tC[j] - (camera @ tC[i][:, :, None])[:, :, 0]
    return Motions(robot, camera, np.stack([i, j], axis=1).astype(np.int64), t_robot, t_camera)


def pose_residuals(residuals_deg, inliers, pairs, n_poses: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-pose residuals and inlier flags from those of the motions formed from the poses.

    A pose is an inlier when at least half as many of its motions are inliers as for the
    best-connected pose (and at least one): with every pair of poses (``pairs="all"``)
    the correct poses agree with each other and a wrong pose agrees with hardly any, while
    with consecutive pairs this is "at least one of its two motions is an inlier". The
    residual of a pose is the median residual of its motions to the inlier poses (to all
    its partners when it has no inlier partner). A pose in no motion gets ``nan``, ``False``.
    """
    residuals_deg = np.asarray(residuals_deg, dtype=np.float64)
    inliers = np.asarray(inliers, dtype=bool)
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    degree = np.bincount(pairs[inliers].ravel(), minlength=n_poses)
    ok = (degree >= max(1, 0.5 * degree.max(initial=0))) if len(pairs) else np.zeros(n_poses, dtype=bool)
    res = np.full(n_poses, np.nan)
    # Each motion seen from both of its poses: (pose, partner, residual).
    pose = np.concatenate([pairs[:, 0], pairs[:, 1]])
    partner = np.concatenate([pairs[:, 1], pairs[:, 0]])
    r = np.concatenate([residuals_deg, residuals_deg])
    order = np.argsort(pose, kind="stable")
    pose, partner, r = pose[order], partner[order], r[order]
    bounds = np.searchsorted(pose, np.arange(n_poses + 1))
    for k in range(n_poses):
        a, b = bounds[k], bounds[k + 1]
        if a == b:
            continue
        good = ok[partner[a:b]]
        res[k] = float(np.median(r[a:b][good] if good.any() else r[a:b]))
    return res, ok
