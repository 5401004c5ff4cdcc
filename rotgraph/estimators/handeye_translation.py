"""The translation stage of :func:`rotgraph.estimators.handeye.solve_handeye`: ``t_X``
given ``S``, or ``S`` and ``t_X`` jointly.

With full motions ``A_i = [L_i | t_L,i]`` (robot) and ``B_i = [R_i | t_R,i]`` (camera) the
hand-eye equation ``A_i X = X B_i`` for ``X = [S | t_X]`` (``gripper_from_camera``) has a
rotation part ``L_i S = S R_i`` and a translation part

    L_i t_X + t_L,i = S t_R,i + t_X,   i.e.   e_i = (L_i - I) t_X - S t_R,i + t_L,i = 0.

:func:`~rotgraph.estimators.handeye.motions_from_poses` forms ``t_L = R_Gj^T (t_Gi - t_Gj)`` and
``t_R = t_Cj - R t_Ci`` from poses with translations. ``solve_handeye(...,
robot_translations=t_L, camera_translations=t_R)`` then also returns ``t_X``, and with the
``robust`` method (unless ``rotation_only``) estimates ``S`` and ``t_X`` *jointly*: the
translations constrain ``S`` too (``S t_R,i`` must point along ``t_L,i + (L_i - I) t_X``),
which is how OpenCV's ANDREFF and DANIILIDIS beat every rotation-only method when the
translations are precise. The joint stage minimises, over the inlier pairs of the robust
rotation estimate (wrong pairs stay rejected),

    sum_i w_i ( |log(R_i^T S^T L_i S)|^2 / sigma_r^2  +  |e_i|^2 / sigma_t^2 )

by Gauss-Newton on ``SO(3) x R^3`` (``S <- S exp(omega)``, ``t_X <- t_X + delta``; exact
Jacobians: the rotation block's as for ``l2``, the translation block's
``de/domega = S [t_R]_x``, ``de/dt_X = L - I``; every step safeguarded by a descent test).
It starts from the robust rotation estimate and the linear least-squares ``t_X`` given it.
``sigma_r`` and ``sigma_t`` (per-axis noise of each block) are estimated from the data and
the fit alternated with their re-estimation until both are stable (a few rounds): each is
the truncated root mean square of its block's inlier residuals, as for the rotation
threshold (step 3 of ``robust`` in :mod:`.handeye_rotation`; ``|e_i| = sigma_t chi_3`` for
isotropic noise), so the weighting does not depend on the units of the translations, and
translations much noisier than the rotations get a small weight: the estimate then tends to
the rotation-only one, never much worse. The translation inlier threshold is ``4.03`` times
the noise estimated from the *median* ``|e_i|`` over the rotation inliers (robust: a few
bad translations cannot inflate it and mask themselves). Pairs beyond it (a robot or camera
translation that disagrees with the others) are left out of the translation block (their
rotations still count) and flagged in ``translation_inliers``; ``inliers`` keeps its
meaning (the rotation residual test). The model treats the residuals of the motions as
independent with one variance per block; the motions of every pair of poses are not
independent, and the translation residuals grow with the lever arms (rotation noise times
the distances), so the weights are an approximation (a per-motion variance
``a + b (|t_L|^2 + |t_R|^2)`` did not help). The loss of the ``robust`` method weights both
blocks (truncated L2 by default: the inlier sets above). Translations that carry nothing about
``S`` (every camera motion translation zero, e.g. all translations zero) make no joint
stage: ``S`` is the rotation-only estimate, ``t_X`` its least-squares fit, and a warning
says so. With the other methods (and ``rotation_only``), ``S`` is the rotation-only
estimate and ``t_X`` the least-squares fit given ``S`` (robust methods: over the inlier
pairs, translation outliers left out).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .. import so3, so3_rows
from ..errors import InputError
from ..losses import loss_weight
from .handeye_rotation import CHI3_Q999, MIN_THRESHOLD, auto_threshold, errors, gauss_newton_system, wsum

_T_ZERO = 1e-12  # camera motion translations below this (relative to their scale) say nothing about S
_ROUNDS = 20  # joint stage: at most this many (fit, noise re-estimation) rounds
_ROUND_TOL = 1e-3  # ... stopping when the weights of both blocks change less than this (relative)


class _TranslationFit(NamedTuple):
    s: np.ndarray  # quaternion of S (changed only by the joint stage)
    t: np.ndarray  # (3,) t_X
    theta: np.ndarray  # (N,) rotation residuals (radians) at the final S
    residuals: np.ndarray  # (N,) |e_i|
    rot_threshold: float | None  # radians
    threshold: float | None  # translation inlier threshold
    inliers: np.ndarray  # (N,) translation inliers
    sigma_r: float | None  # radians
    sigma_t: float | None
    cost: float
    iterations: int
    converged: bool


def translation_errors(S: np.ndarray, Lm, tL, tR, t: np.ndarray) -> np.ndarray:
    """Rows ``e_i = (L_i - I) t_X - S t_R,i + t_L,i`` (N, 3)."""
    return Lm @ t - t - tR @ S.T + tL


def _linear_translation(S: np.ndarray, Lm, tL, tR, u) -> np.ndarray:
    """``argmin_t sum u_i |(L_i - I) t - (S t_R,i - t_L,i)|^2`` (the normal equations)."""
    keep = u > 0
    A = (Lm[keep] - np.eye(3)).reshape(-1, 3)
    b = (tR[keep] @ S.T - tL[keep]).reshape(-1)
    Au = A * np.repeat(u[keep], 3)[:, None]
    H = Au.T @ A
    H += (1e-14 * np.trace(H) + 1e-300) * np.eye(3)
    return np.linalg.solve(H, Au.T @ b)


def _joint_cost(theta, e, ur, ut) -> float:
    return wsum(ur, theta * theta) + wsum(ut, (e * e).sum(axis=1))


def _joint_iterate(s, t, lq, rq, Lm, tL, tR, ur, ut, tscale: float, fix_rotation: bool, max_iterations: int, tol: float):
    """Gauss-Newton on ``SO(3) x R^3`` for ``sum ur_i theta_i^2 + sum ut_i |e_i|^2``.

    ``S <- S exp(omega)``, ``t <- t + delta``. Rotation block: the Jacobian of the ``l2``
    method (:func:`gauss_newton_system`); translation block:
    ``e(S exp(omega), t + delta) ~ e + S [t_R]_x omega + (L - I) delta``. Each step is
    halved until the cost does not rise; stops when ``max(|omega|, |delta| / tscale) < tol``
    or no step lowers the cost. With ``fix_rotation`` only ``t`` moves.
    Returns ``(s, t, theta, e, cost, iterations, converged)``.
    """
    keep = ut > 0
    Lk, tRk, utk = Lm[keep], tR[keep], ut[keep]
    Jt = Lk - np.eye(3)
    hat_tR = so3.hat(tRk)
    u3 = np.repeat(utk, 3)[:, None]
    S = so3.matrices_from_quaternions(s)
    theta = errors(s, lq, rq)[2]
    e = translation_errors(S, Lm, tL, tR, t)
    cost = _joint_cost(theta, e, ur, ut)
    converged = False
    it = 0
    for it in range(1, max_iterations + 1):
        J = np.concatenate([S @ hat_tR, Jt], axis=2).reshape(-1, 6)
        Ju = J * u3
        H = Ju.T @ J
        g = Ju.T @ e[keep].reshape(-1)
        if not fix_rotation and (ur > 0).any():
            Hr, gr = gauss_newton_system(s, lq, rq, ur)
            H[:3, :3] += Hr
            g[:3] += gr
        if fix_rotation:
            H, g = H[3:, 3:], g[3:]
        H += np.diag(1e-14 * np.diag(H) + 1e-300)
        step = -np.linalg.solve(H, g)
        if not np.isfinite(step).all():
            break
        omega, delta = (np.zeros(3), step) if fix_rotation else (step[:3], step[3:])
        size = max(float(np.linalg.norm(omega)), float(np.linalg.norm(delta)) / tscale)
        rot = float(np.linalg.norm(omega))
        if rot > np.pi / 2:  # a trust region: never jump across the group
            omega, delta = omega * (np.pi / 2 / rot), delta * (np.pi / 2 / rot)
            size *= np.pi / 2 / rot
        slack = 1e-13 * abs(cost) + 1e-300
        accepted = False
        for _ in range(40):
            cand = so3.quaternion_multiply(s, so3.quaternion_exp(omega))
            cand /= np.linalg.norm(cand)
            Sc, tc = so3.matrices_from_quaternions(cand), t + delta
            th_c = errors(cand, lq, rq)[2]
            e_c = translation_errors(Sc, Lm, tL, tR, tc)
            new = _joint_cost(th_c, e_c, ur, ut)
            if new <= cost + slack:
                accepted = True
                break
            omega, delta, size = 0.5 * omega, 0.5 * delta, 0.5 * size
        if not accepted:  # no descent at machine precision: stationary
            converged = True
            break
        s, S, t, theta, e, cost = cand, Sc, tc, th_c, e_c, new
        if size < tol:
            converged = True
            break
    return s, t, theta, e, cost, it, converged


def _fit_translation(s, lq, rq, Lm, tL, tR, w, rot_in, *, robust: bool, joint: bool, loss: str,
                     rot_threshold: float | None, scale: float | None, fixed_threshold: bool,
                     max_iterations: int, tol: float) -> _TranslationFit:
    """``t_X`` given ``S`` (``joint=False``) or ``(S, t_X)`` jointly (see the module docstring).

    ``rot_in`` are the pairs the rotation estimate flags as inliers (all for non-robust
    methods), ``rot_threshold`` its threshold (radians). Non-robust: one weighted linear
    least-squares fit over ``rot_in``, every translation an inlier. Robust: rounds of
    (fit, re-estimation of ``sigma_r``, ``sigma_t``, the thresholds and the inlier sets).
    """
    active = w > 0
    use = w * rot_in
    tscale = float(np.sqrt(wsum(use, (tL * tL).sum(axis=1) + (tR * tR).sum(axis=1)) / max(float(use.sum()), 1e-300)))
    tscale = tscale if tscale > 0 else 1.0
    S = so3.matrices_from_quaternions(s)
    t = _linear_translation(S, Lm, tL, tR, use)
    theta = errors(s, lq, rq)[2]
    e = translation_errors(S, Lm, tL, tR, t)
    en = np.linalg.norm(e, axis=1)
    if not robust:
        return _TranslationFit(s, t, theta, en, rot_threshold, None, np.ones(len(en), dtype=bool), None, None,
                               wsum(use, en * en), 1, True)
    floor_t = MIN_THRESHOLD * tscale

    def translation_noise(en, rot_in):
        # The threshold from the median over the rotation inliers (robust: a few bad
        # translations cannot mask themselves by inflating it), sigma_t from the truncated
        # mean square within it (efficient).
        tt = auto_threshold(en, rot_in, floor=floor_t)
        tr_in = rot_in & (en <= tt)
        return tt, tr_in, auto_threshold(en, tr_in if tr_in.any() else rot_in, rms=True, floor=floor_t) / CHI3_Q999

    rot_in = rot_in & active
    tr = rot_threshold if rot_threshold is not None else auto_threshold(theta, rot_in, rms=True)
    tt, tr_in, st = translation_noise(en, rot_in)
    prev = None
    iterations, converged, cost = 0, True, 0.0
    for _ in range(_ROUNDS):
        sr = tr / CHI3_Q999
        c_r = scale if scale is not None else tr
        c_t = tt * (c_r / tr)
        ur = (w * rot_in * loss_weight(loss, np.maximum(theta, 1e-300), c_r) / sr**2) if joint else np.zeros_like(w)
        ut = w * rot_in * loss_weight(loss, np.maximum(en, 1e-300), c_t) / st**2
        s, t, theta, e, cost, its, converged = _joint_iterate(
            s, t, lq, rq, Lm, tL, tR, ur, ut, tscale, not joint, max_iterations, tol)
        iterations += its
        en = np.linalg.norm(e, axis=1)
        if joint and not fixed_threshold:
            within = rot_in & (theta <= tr)
            tr = auto_threshold(theta, within if within.any() else rot_in, rms=True)
        new_rot_in = active & (theta <= tr) if joint else rot_in
        sr_used, st_used = sr, st
        tt, new_tr_in, st = translation_noise(en, new_rot_in)
        key = np.array([tr, st])
        stable = (prev is not None and np.array_equal(new_rot_in, rot_in) and np.array_equal(new_tr_in, tr_in)
                  and np.all(np.abs(key / prev - 1.0) < _ROUND_TOL))
        prev, rot_in, tr_in = key, new_rot_in, new_tr_in
        if stable:
            break
    # sigma_r, sigma_t: those that weighted the last fit (the thresholds are re-estimated after it)
    return _TranslationFit(s, t, theta, en, tr, tt, en <= tt, sr_used, st_used, cost, iterations,
                           converged)


def check_translations(t, n: int, name: str) -> np.ndarray:
    x = np.asarray(t, dtype=np.float64)
    if x.shape != (n, 3):
        raise InputError(f"expected {name} of shape ({n}, 3), got {x.shape}")
    if not np.isfinite(x).all():
        raise InputError(f"{name}: translation {int(np.argmax(~np.isfinite(x).all(axis=1)))} is not finite")
    return x


def translation_stage(s, lq, rq, tL, tR, w, theta, threshold, *, robust: bool, joint: bool, loss: str,
                       scale: float | None, fixed_threshold: bool, max_iterations: int, tol: float):
    """The translation stage after a rotation estimate ``s`` with residuals ``theta`` and
    inlier threshold ``threshold`` (radians, None: every pair counts): ``(fit, joint, warnings)``.

    ``joint`` (robust, not rotation-only) is dropped, with a warning, when the camera motion
    translations of the pairs used are all zero: they carry nothing about ``S``.
    """
    rot_in = theta <= threshold if threshold is not None else np.ones(len(w), dtype=bool)
    used = (w > 0) & rot_in
    if not used.any():
        used = w > 0
    warnings = []
    t_scale = float(np.sqrt(((tL[used] ** 2).sum(axis=1) + (tR[used] ** 2).sum(axis=1)).max()))
    if joint and not float(np.abs(tR[used]).max()) > _T_ZERO * t_scale:
        joint = False
        warnings.append(
            ("the translations are all zero" if t_scale == 0 else "the camera motions have no translation")
            + ", so the translations do not constrain S: S from the rotations alone"
        )
    fit = _fit_translation(
        s, lq, rq, so3_rows.matrices_from_quaternion_rows(lq), tL, tR, w, rot_in, robust=robust, joint=joint,
        loss=loss, rot_threshold=threshold, scale=scale, fixed_threshold=fixed_threshold,
        max_iterations=max_iterations, tol=tol,
    )
    return fit, joint, warnings

