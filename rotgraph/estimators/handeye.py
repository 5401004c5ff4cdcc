"""Conjugate rotation averaging: hand-eye calibration (Hartley, Trumpf, Dai & Li 2013, section 6).

Given pairs of rotations ``(L_i, R_i)`` find the rotation ``S`` with

    R_i ~ S^T L_i S        (equivalently  L_i S = S R_i)

minimising ``sum_i w_i d(R_i, S^T L_i S)^p``. In hand-eye calibration ``L_i`` are robot
(gripper) motions, ``R_i`` the camera motions seen over the same steps, and ``S`` is the
hand-eye rotation.

Which rotation ``S`` is
-----------------------
With absolute poses ``base_from_gripper`` ``G_k`` and ``cam_from_target`` ``C_k`` (OpenCV's
``R_gripper2base`` and ``R_target2cam``), :func:`motions_from_poses` forms, for a pair of
poses ``(i, j)``,

    L = G_j^T G_i   (gripper_j_from_gripper_i)      R = C_j C_i^T   (cam_j_from_cam_i)

Since ``G_k X C_k`` is the same for every ``k`` (``base_from_target``, fixed) with
``X = gripper_from_camera``, ``L X = X R``: the solution ``S`` is ``gripper_from_camera``,
which is OpenCV's ``R_cam2gripper`` output of ``cv2.calibrateHandEye``. For eye-to-hand
(camera fixed, target on the gripper) pass ``gripper_from_base`` (``G_k^T``) in place of
``base_from_gripper``, as with OpenCV; ``S`` is then ``base_from_camera``.

In general ``S`` maps the frame of the ``R_i`` into the frame of the ``L_i``: the rotation
axes (log vectors) satisfy ``log(L_i) = S log(R_i)``, and the angles are equal,
``|log L_i| = |log R_i|`` (a pair whose angles differ cannot be fitted exactly by any S).

Symmetries (tested): ``L_i -> W L_i W^T`` gives ``S -> W S``; ``R_i -> V R_i V^T`` gives
``S -> S V^T``; swapping the roles of ``L`` and ``R`` gives ``S^T``; ``q`` and ``-q`` of
any input are the same rotation and give the same result.

Methods (:func:`solve_handeye`)
-------------------------------
``quaternion``  closed form: with unit quaternions ``l_i, r_i, s``, ``r_i = s* l_i s`` is
                ``l_i s - s r_i = 0``, linear in ``s``: ``(Q_left(l_i) - Q_right(r_i)) s = 0``.
                The signs of ``l_i, r_i`` are chosen so that their scalar parts agree (equal
                for exact data), the systems are stacked (rows scaled by ``sqrt(w_i)``) and
                ``s`` is the right singular vector of the smallest singular value; then the
                signs are re-chosen against ``s* l_i s`` and the system re-solved until they
                stop changing. It minimises ``sum w_i d_quat(R_i, S^T L_i S)^2`` with the
                quaternion distance ``d_quat = min |q -+ p| = 2 sin(theta/4)``.
``procrustes``  closed form (Park & Martin 1994): ``log L_i = S log R_i``, so ``S`` is the
                weighted orthogonal Procrustes solution
                ``argmin_S sum w_i |log L_i - S log R_i|^2`` (SVD of ``sum w_i a_L a_R^T``).
                Rotations near a half turn have two nearly opposite log vectors: the branch
                of ``log R_i`` closer to ``S^T log L_i`` is taken and the fit repeated.
``l2``          geodesic L2, ``sum w_i theta_i^2`` with ``theta_i`` the angle of
                ``R_i^T S^T L_i S``: Gauss-Newton on SO(3) (``S <- S exp(omega)``, exact
                Jacobian ``Jr^-1(e_i) (I - M_i^T)`` with ``M_i = S^T L_i S``) from the
                quaternion closed form, every step safeguarded by a descent test.
``l1``          geodesic L1, ``sum w_i theta_i``: IRLS (Weiszfeld-like weights
                ``w_i / theta_i``) with the same Gauss-Newton steps, from the ``l2`` result.
``robust``      (default) minimal-sample consensus then IRLS with a robust loss:

                1. hypotheses from 2 pairs with non-parallel axes (``S`` aligns the unit
                   axes: a 2-vector Procrustes), all pairs of pairs when few, else
                   ``max_hypotheses`` random ones (``seed``);
                2. each hypothesis is scored a contrario (ORSA, Moisan & Stival 2004;
                   Moisan, Moulon & Monasse 2012): for the k smallest residuals, the number
                   of false alarms ``(n - 2) C(n, k) C(k, 2) p(theta_(k))^(k - 2)`` with
                   ``p(t) = (t - sin t) / pi`` the probability that a uniformly random
                   rotation is within ``t`` of the fit. The best (hypothesis, k) needs no
                   threshold and works with more wrong pairs than right ones. ``theta_(k)``
                   is capped at ``4.03 sigma`` (``threshold_deg`` if given), with ``sigma``
                   from the lower quartile of the angle gaps ``|angle(L_i) - angle(R_i)|``
                   (a lower bound of the residual under any S; ``|N(0, sigma^2)|`` for
                   right pairs), so that a loose fit of every pair cannot win;
                3. geodesic L2 on the consensus set, the inlier threshold re-estimated from
                   the inliers' residuals (``threshold_deg``, else ``4.03 sigma``, the
                   99.9 % point of the residual angle ``sigma chi_3`` of isotropic Gaussian
                   noise, with the per-axis ``sigma`` from the median residual, then from
                   the truncated mean square), repeated until the inlier set is stable;
                4. IRLS with ``loss`` (from :mod:`rotgraph.losses`; default
                   ``truncated_l2``, whose IRLS is the geodesic L2 fit over the pairs
                   within the threshold, so clean data lose no accuracy) at scale
                   ``scale_deg`` (default: the threshold);
                5. pairs within the (re-estimated) threshold are flagged as inliers.

Degeneracy. ``S`` is determined only when two rotations have non-parallel axes. The
conditioning ``kappa = sqrt(lambda_min(sum w_i (|v_i|^2 I - v_i v_i^T)) / sum w_i)`` with
``v_i`` the vector part of the quaternion of ``L_i`` (``sin(theta_i/2)`` times the axis;
computed for the ``R_i`` too, the smaller is used) is the root mean square, over the pairs,
of ``sin(theta_i / 2)`` times the sine of the angle between the axis and the least
constrained direction: 0 when all axes are parallel or all rotations are the identity.
Below ``1e-6`` an :class:`~rotgraph.errors.UnsolvableError` says which of the two it is;
below ``0.02`` the result carries a warning (``S`` is poorly determined about that axis).

Translations: the joint estimate
--------------------------------
With full motions ``A_i = [L_i | t_L,i]`` (robot) and ``B_i = [R_i | t_R,i]`` (camera) the
hand-eye equation ``A_i X = X B_i`` for ``X = [S | t_X]`` (``gripper_from_camera``) has a
rotation part ``L_i S = S R_i`` and a translation part

    L_i t_X + t_L,i = S t_R,i + t_X,   i.e.   e_i = (L_i - I) t_X - S t_R,i + t_L,i = 0.

:func:`motions_from_poses` forms ``t_L = R_Gj^T (t_Gi - t_Gj)`` and
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
threshold above (``|e_i| = sigma_t chi_3`` for isotropic noise), so the weighting does not
depend on the units of the translations, and translations much noisier than the rotations
get a small weight: the estimate then tends to the rotation-only one, never much worse.
The translation inlier threshold is ``4.03`` times the noise estimated from the *median*
``|e_i|`` over the rotation inliers (robust: a few bad translations cannot inflate it and
mask themselves). Pairs beyond it (a robot or camera translation that disagrees with the
others) are left out of the translation block (their rotations still count) and flagged in
``translation_inliers``; ``inliers`` keeps its meaning (the rotation residual test).
The model treats the residuals of the motions as independent with one variance per
block; the motions of every pair of poses are not independent, and the translation
residuals grow with the lever arms (rotation noise times the distances), so the weights
are an approximation (a per-motion variance ``a + b (|t_L|^2 + |t_R|^2)`` did not help).
The loss of the ``robust`` method weights both blocks (truncated L2 by default: the
inlier sets above). Translations that carry nothing about ``S`` (every camera motion
translation zero, e.g. all translations zero) make no joint stage: ``S`` is the
rotation-only estimate, ``t_X`` its least-squares fit, and a warning says so. With the
other methods (and ``rotation_only``), ``S`` is the rotation-only estimate and ``t_X`` the
least-squares fit given ``S`` (robust methods: over the inlier pairs, translation outliers
left out).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Literal, NamedTuple

import numpy as np
from scipy.special import gammaln

from .. import so3
from ..errors import InputError, UnsolvableError
from ..losses import check_loss, loss_rho, loss_weight
from .single import _check_weights, as_quaternion_batch, as_single_quaternion

__all__ = [
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

METHODS = ("robust", "quaternion", "procrustes", "l2", "l1")

# Residual angle of isotropic Gaussian tangent noise N(0, sigma^2 I_3) is sigma * chi_3.
_CHI3_MEDIAN = 1.5381722544550522  # sqrt(chi2.ppf(0.5, 3))
_CHI3_Q999 = 4.0331422236561565  # sqrt(chi2.ppf(0.999, 3))
_CHI3_TRUNC_MS = 2.984613605124668  # E[chi2_3 | chi2_3 < chi2.ppf(0.999, 3)]
_MIN_THRESHOLD = 1e-8  # rad: floor of the automatic inlier threshold (noise-free data)
_DEGENERATE = 1e-6  # conditioning below this: unsolvable
_NEAR_DEGENERATE = 0.02  # conditioning below this: warning
_MIN_AXIS_ANGLE = 1e-6  # rad: rotations smaller than this carry no axis (minimal samples)
_SCORE_SUBSET = 1000  # hypotheses are scored on at most this many pairs
_CAP_FACTOR = 1.0  # consensus threshold cap, in units of 4.03 sigma (sigma from the angle gaps)


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
    conditioning : ``kappa`` of the module docstring over the pairs used (0: degenerate).
    warnings : human-readable warnings (near-degenerate data, weak consensus, ...).
    translation : (3,) ``t_X`` (``gripper_from_camera`` translation, the units of the input
        translations), or None when no translations were given.
    translation_residuals : (N,) ``|e_i| = |(L_i - I) t_X - S t_R,i + t_L,i|`` per pair, or None.
    translation_inliers : (N,) bool: ``|e_i|`` within ``translation_threshold`` (all True
        without one), or None.
    translation_threshold : the translation inlier threshold (robust: ``4.03 sigma_t``), or None.
    joint : whether ``S`` was estimated jointly with ``t_X`` (module docstring); then
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


# --------------------------------------------------------------------------- quaternion algebra
# Inside this module quaternions are rows (4, N) (each component a contiguous array: fast
# elementwise work), canonical with w >= 0. Vector sums avoid BLAS level-1 calls (``x @ y``
# on 1-D arrays), which are slow with a multithreaded BLAS on a busy machine.


def _rows(q: np.ndarray) -> np.ndarray:
    """Unit quaternions (N, 4) -> canonical rows (4, N) with w >= 0."""
    r = np.ascontiguousarray(q.T, dtype=np.float64)
    return r * np.where(r[0] < 0, -1.0, 1.0)


def _canonical(q: np.ndarray) -> np.ndarray:
    """A single quaternion (4,) with w >= 0."""
    return q if q[0] >= 0 else -q


def _qleft(q: np.ndarray) -> np.ndarray:
    """(N, 4, 4) with ``q * p = Q_left(q) p`` for quaternion rows ``q`` (4, N)."""
    w, x, y, z = q
    return np.stack(
        [
            np.stack([w, -x, -y, -z], -1),
            np.stack([x, w, -z, y], -1),
            np.stack([y, z, w, -x], -1),
            np.stack([z, -y, x, w], -1),
        ],
        -2,
    )


def _qright(q: np.ndarray) -> np.ndarray:
    """(N, 4, 4) with ``p * q = Q_right(q) p`` for quaternion rows ``q`` (4, N)."""
    w, x, y, z = q
    return np.stack(
        [
            np.stack([w, -x, -y, -z], -1),
            np.stack([x, w, z, -y], -1),
            np.stack([y, -z, w, x], -1),
            np.stack([z, y, -x, w], -1),
        ],
        -2,
    )


def _matrix(s: np.ndarray) -> np.ndarray:
    return so3.matrices_from_quaternions(s)


def _conjugated(s: np.ndarray, lq: np.ndarray) -> np.ndarray:
    """Rows of ``s* l_i s``, the quaternions of ``M_i = S^T L_i S``: same scalar part, vector
    part rotated by ``S^T``."""
    return np.concatenate([lq[:1], _matrix(s).T @ lq[1:]])


def _errors(s: np.ndarray, lq: np.ndarray, rq: np.ndarray):
    """Rows of ``m_i`` (``M_i = S^T L_i S``) and ``e_i`` (``E_i = R_i^T M_i``, w >= 0), and
    the angles ``theta_i`` of ``E_i`` (accurate at 0 and pi)."""
    m = _conjugated(s, lq)
    e = so3.qmul_rows(so3.qconj_rows(rq), m)
    e *= np.where(e[0] < 0, -1.0, 1.0)
    sv = np.sqrt(e[1] * e[1] + e[2] * e[2] + e[3] * e[3])
    theta = 2.0 * np.arctan2(sv, e[0])
    return m, e, theta, sv


def handeye_residuals(S, L, R) -> np.ndarray:
    """Angles (radians) of ``R_i^T S^T L_i S``: the residual of each pair for the rotation ``S``.

    ``S`` is (3, 3) or a quaternion (4,); ``L``, ``R`` (N, 3, 3) or (N, 4).
    """
    s = as_single_quaternion(S)
    return _errors(s, _rows(as_quaternion_batch(L)), _rows(as_quaternion_batch(R)))[2]


def _wsum(w: np.ndarray, x: np.ndarray) -> float:
    return float((w * x).sum())


# --------------------------------------------------------------------------- closed forms


def _smallest_right_singular_vector(A: np.ndarray) -> np.ndarray:
    """Of a tall matrix, through its R factor (QR is backward stable: same accuracy as an
    SVD of ``A``, a fraction of the time for 4N x 4)."""
    if A.shape[0] > 4 * A.shape[1]:
        A = np.linalg.qr(A, mode="r")
    return np.linalg.svd(A)[2][-1]


def _quaternion_closed_form(lq, rq, w, max_passes: int = 20):
    """Smallest right singular vector of the stacked ``sqrt(w_i) (Q_left(l_i) - Q_right(r_i))``,
    with the signs of the ``r_i`` re-chosen until they agree with ``s* l_i s``.

    ``lq``, ``rq`` are canonical rows (w >= 0), so the scalar parts already agree in sign
    (they are equal for exact data). Returns ``(s, cost, passes, converged)`` with
    ``cost = sum w |l s - s r|^2`` (= ``sum w d_quat^2`` once the signs are settled).
    """
    rq = rq.copy()
    Ql = _qleft(lq)
    sw = np.sqrt(w)[:, None, None]
    s = None
    converged = False
    passes = 0
    for passes in range(1, max_passes + 1):
        s = _smallest_right_singular_vector((sw * (Ql - _qright(rq))).reshape(-1, 4))
        m = _conjugated(s, lq)
        flip = (m * rq).sum(axis=0) < 0
        if not flip.any():
            converged = True
            break
        rq[:, flip] *= -1.0
    diff = so3.qmul_rows(lq, s) - so3.qmul_rows(s, rq)
    cost = _wsum(w, (diff * diff).sum(axis=0))
    return s, cost, passes, converged


def _procrustes_rotation(B: np.ndarray) -> np.ndarray:
    """``argmax_{S in SO(3)} <S, B>`` for (..., 3, 3): ``U diag(1, 1, det(U V^T)) V^T``."""
    U, _, Vt = np.linalg.svd(B)
    d = np.sign(np.linalg.det(U @ Vt))
    d = np.where(d == 0, 1.0, d)
    U = U.copy()
    U[..., :, 2] *= d[..., None]
    return U @ Vt


def _procrustes_closed_form(lq, rq, w, max_passes: int = 10):
    """Weighted orthogonal Procrustes on the log vectors: ``argmin sum w |a_L - S a_R|^2``.

    Returns ``(s, cost, passes, converged)``.
    """
    aL = so3.quaternion_log(lq.T)
    aR = so3.quaternion_log(rq.T)
    thR = np.linalg.norm(aR, axis=1)
    # The other branch of the log of R (angle theta - 2 pi): the same rotation, a log vector
    # nearly opposite to the principal one when theta is near pi.
    alt = aR * (1.0 - 2.0 * np.pi / np.where(thR > 0, thR, 1.0))[:, None]
    near_pi = thR > 2.0 * np.pi / 3.0
    use_alt = np.zeros(len(aR), dtype=bool)
    S = np.eye(3)
    converged = False
    passes = 0
    for passes in range(1, max_passes + 1):
        a = np.where(use_alt[:, None], alt, aR)
        S = _procrustes_rotation((aL * w[:, None]).T @ a)
        if not near_pi.any():
            converged = True
            break
        d_main = np.linalg.norm(aL - aR @ S.T, axis=1)
        d_alt = np.linalg.norm(aL - alt @ S.T, axis=1)
        new = near_pi & (d_alt < d_main)
        if np.array_equal(new, use_alt):
            converged = True
            break
        use_alt = new
    a = np.where(use_alt[:, None], alt, aR)
    r = aL - a @ S.T
    cost = _wsum(w, (r * r).sum(axis=1))
    return so3.quaternions_from_matrices(S), cost, passes, converged


# --------------------------------------------------------------------------- iterative


def _gauss_newton_step(s, lq, rq, u) -> np.ndarray:
    """The Gauss-Newton step ``omega`` (``S <- S exp(omega)``) for ``sum u_i theta_i^2``
    (the system of :func:`_gauss_newton_system`)."""
    H, g = _gauss_newton_system(s, lq, rq, u)
    # A tiny Levenberg term keeps the solve defined on (nearly) degenerate data.
    H += (1e-14 * np.trace(H) + 1e-300) * np.eye(3)
    return -np.linalg.solve(H, g)


def _gauss_newton_system(s, lq, rq, u) -> tuple[np.ndarray, np.ndarray]:
    """The Gauss-Newton matrix ``H`` and half-gradient ``g`` of ``sum u_i theta_i^2`` in
    ``omega`` (``S <- S exp(omega)``): the step is ``-H^-1 g``.

    With ``M_i = S^T L_i S``, ``E_i(omega) = R_i^T exp(-omega) M_i exp(omega)
    ~ E_i exp(B_i omega)`` with ``B_i = I - M_i^T``, so ``phi_i = log E_i`` has the
    Jacobian ``A_i = Jr^-1(phi_i) B_i``. Since ``Jr^-T(phi) phi = phi`` the gradient is
    ``2 sum u_i B_i^T phi_i = 2 sum u_i (I - M_i) phi_i``, and with
    ``Jr^-T Jr^-1 = alpha I + beta phi phi^T`` the Gauss-Newton matrix ``sum u_i A_i^T A_i``
    is ``sum u_i (alpha_i B_i^T B_i + beta_i d_i d_i^T)``, ``d_i = B_i^T phi_i``, where
    ``B_i^T B_i = 4 (|v_i|^2 I - v_i v_i^T)`` (``v_i`` the vector part of ``m_i``): a few
    vector operations over the pairs, no 3x3 matrix per pair.
    """
    keep = u > 0
    if not keep.all():
        lq, rq, u = lq[:, keep], rq[:, keep], u[keep]
    m, e, theta, sv = _errors(s, lq, rq)
    f = np.where(sv > 0, theta / np.where(sv > 0, sv, 1.0), 2.0)
    phi = e[1:] * f
    v, mw = m[1:], m[0]
    vxp = np.cross(v, phi, axis=0)
    d = -2.0 * mw * vxp - 2.0 * np.cross(v, vxp, axis=0)  # (I - M_i) phi_i
    g = (d * u).sum(axis=1)
    # Jr^-1(phi) = a I + 1/2 hat(phi) + c phi phi^T with a = 1 - c theta^2 and
    # c = 1/theta^2 - cot(theta/2) / (2 theta) (series below 1e-2; 1/pi^2 at a half turn).
    small = theta < 1e-2
    t = np.where(small, 1.0, theta)
    c = np.where(small, 1.0 / 12.0 + theta**2 / 720.0, 1.0 / t**2 - 0.5 / (t * np.tan(0.5 * t)))
    a = 1.0 - c * theta**2
    alpha = a * a + 0.25 * theta**2
    beta = 2.0 * a * c + c * c * theta**2 - 0.25
    vu = v * (u * alpha)
    du = d * (u * beta)
    H = 4.0 * (float((vu * v).sum()) * np.eye(3) - vu @ v.T) + du @ d.T
    return H, g


def _cost(kind: str, theta: np.ndarray, w: np.ndarray, loss: str | None, c: float | None) -> float:
    if kind == "l2":
        return _wsum(w, theta * theta)
    if kind == "l1":
        return _wsum(w, theta)
    return _wsum(w, loss_rho(loss, theta, c))


def _irls_weights(kind: str, theta: np.ndarray, w: np.ndarray, loss: str | None, c: float | None) -> np.ndarray:
    if kind == "l2":
        return w
    if kind == "l1":
        return w / np.maximum(theta, 1e-15)
    return w * loss_weight(loss, np.maximum(theta, 1e-15), c)


def _iterate(s0, lq, rq, w, kind: str, loss=None, c=None, max_iterations: int = 200, tol: float = 1e-11):
    """Minimise ``sum w_i f(theta_i)`` (``kind``: l2, l1 or robust) by reweighted Gauss-Newton.

    Each iteration takes the Gauss-Newton step of the weighted L2 cost with the IRLS
    weights at the current estimate (``w`` for l2; ``w / theta`` for l1, a Weiszfeld-type
    majorise-minimise step; ``w rho'(theta) / theta`` for a robust loss), halving it along
    the geodesic until the true cost does not rise. Stops when the step is below ``tol``
    radians, or when no step lowers the cost at machine precision.
    Returns ``(s, theta, iterations, converged)``.
    """
    s = s0 / np.linalg.norm(s0)
    theta = _errors(s, lq, rq)[2]
    cost = _cost(kind, theta, w, loss, c)
    converged = False
    it = 0
    for it in range(1, max_iterations + 1):
        u = _irls_weights(kind, theta, w, loss, c)
        if not (u > 0).any():
            converged = True
            break
        omega = _gauss_newton_step(s, lq, rq, u)
        if not np.isfinite(omega).all():
            break
        step = float(np.linalg.norm(omega))
        if step > np.pi / 2:  # a trust region: never jump across the group
            omega *= (np.pi / 2) / step
            step = np.pi / 2
        slack = 1e-13 * abs(cost) + 1e-300
        accepted = False
        for _ in range(40):
            cand = so3.quaternion_multiply(s, so3.quaternion_exp(omega))
            cand /= np.linalg.norm(cand)
            th_c = _errors(cand, lq, rq)[2]
            new = _cost(kind, th_c, w, loss, c)
            if new <= cost + slack:
                accepted = True
                break
            omega *= 0.5
            step *= 0.5
        if not accepted:  # no descent at machine precision: stationary
            converged = True
            break
        s, theta, cost = cand, th_c, new
        if step < tol:
            converged = True
            break
    return s, theta, it, converged


# --------------------------------------------------------------------------- robust


def _unit_axes(q: np.ndarray) -> np.ndarray:
    """(N, 3) unit rotation axes of canonical quaternion rows (arbitrary for the identity)."""
    v = q[1:].T
    n = np.linalg.norm(v, axis=1, keepdims=True)
    return v / np.where(n > 0, n, 1.0)


def _minimal_hypotheses(lq, rq, idx: np.ndarray, max_hypotheses: int, rng) -> np.ndarray:
    """Quaternions (K, 4) of ``S`` from pairs of pairs: ``S`` aligns the unit axes of ``R``
    with those of ``L`` (2-vector Procrustes, exact for noise-free data)."""
    n = len(idx)
    if n < 2:
        return np.zeros((0, 4))
    total = n * (n - 1) // 2
    if total <= max_hypotheses:
        a, b = np.triu_indices(n, 1)
    else:
        a = rng.integers(0, n, size=2 * max_hypotheses)
        b = rng.integers(0, n - 1, size=2 * max_hypotheses)
        b = b + (b >= a)  # b != a, uniform over the others
    i, j = idx[a], idx[b]
    uL, uR = _unit_axes(lq), _unit_axes(rq)
    # Non-parallel axes in both frames (1e-3: about 0.06 degrees).
    ok = (np.linalg.norm(np.cross(uL[i], uL[j]), axis=1) > 1e-3) & (np.linalg.norm(np.cross(uR[i], uR[j]), axis=1) > 1e-3)
    i, j = i[ok][:max_hypotheses], j[ok][:max_hypotheses]
    B = uL[i][:, :, None] * uR[i][:, None, :] + uL[j][:, :, None] * uR[j][:, None, :]
    return so3.quaternions_from_matrices(_procrustes_rotation(B))


def _hypothesis_angles(s: np.ndarray, lq: np.ndarray, rq: np.ndarray) -> np.ndarray:
    """Residual angles (K, n) of K hypotheses on n pairs, via one (K,16) x (16,n) product:
    ``cos(theta/2) = |<s* l s, r>| = |<l s, s r>| = |s^T Q_left(l)^T Q_right(r) s|``."""
    P = np.einsum("nki,nkj->nij", _qleft(lq), _qright(rq)).reshape(lq.shape[1], 16)
    ss = (s[:, :, None] * s[:, None, :]).reshape(len(s), 16)
    c = np.abs(ss @ P.T)
    return 2.0 * np.arccos(np.minimum(c, 1.0))


def _log_binomial(n, k):
    return gammaln(n + 1) - gammaln(k + 1) - gammaln(n - k + 1)


def _orsa(theta: np.ndarray, max_threshold: float = np.inf):
    """A contrario scoring of hypotheses from their residuals (K, n), minimal sample size 2,
    over consensus thresholds up to ``max_threshold`` (all when none fits under it).

    Returns ``(best hypothesis, its number of inliers k, its threshold, log10 NFA)``.
    """
    K, n = theta.shape
    th = np.sort(theta, axis=1)
    k = np.arange(1, n + 1, dtype=np.float64)
    # Probability that a uniform (Haar) random rotation lies within t of a given one:
    # (t - sin t) / pi (its cancellation at tiny t only matters inside the log, where a
    # relative error of even 10 % is harmless), floored away from 0.
    p = th - np.sin(th)
    np.maximum(p, 1e-300, out=p)
    logp = np.log(p, out=p)
    logp -= np.log(np.pi)
    logp *= k - 2
    lognfa = logp
    lognfa += np.log(max(n - 2, 1)) + _log_binomial(n, k) + _log_binomial(k, 2.0)
    lognfa[:, :2] = np.inf  # at least 3 pairs (2 of them the sample)
    capped = np.where(th <= max_threshold, lognfa, np.inf)
    if np.isfinite(capped).any():
        lognfa = capped
    flat = int(np.argmin(lognfa))
    h, kk = divmod(flat, n)
    return h, kk + 1, float(th[h, kk]), float(lognfa[h, kk] / np.log(10))


def _auto_threshold(theta: np.ndarray, inl: np.ndarray, rms: bool = False, floor: float = _MIN_THRESHOLD) -> float:
    """``4.03 sigma`` with ``sigma`` the per-axis noise of the inliers' residual angles
    (``theta = sigma chi_3`` for isotropic Gaussian noise): from their median (robust to
    a few outliers in the set) or, with ``rms``, from their mean square corrected for the
    truncation at the threshold (twice as efficient: fewer false alarms on small sets)."""
    if not inl.any():
        return floor
    x = theta[inl]
    if rms:
        sigma = float(np.sqrt((x * x).mean() / _CHI3_TRUNC_MS))
    else:
        sigma = float(np.median(x)) / _CHI3_MEDIAN
    return max(_CHI3_Q999 * sigma, floor)


def _robust(lq, rq, w, loss, scale, threshold, seed, max_hypotheses, max_iterations, tol):
    rng = np.random.default_rng(seed)
    active = w > 0
    angL = 2.0 * np.arctan2(np.linalg.norm(lq[1:], axis=0), lq[0])
    angR = 2.0 * np.arctan2(np.linalg.norm(rq[1:], axis=0), rq[0])
    informative = np.flatnonzero(active & (angL > _MIN_AXIS_ANGLE) & (angR > _MIN_AXIS_ANGLE))
    warnings: list[str] = []
    hyp = _minimal_hypotheses(lq, rq, informative, max_hypotheses, rng)
    if len(hyp) == 0:
        raise UnsolvableError("degenerate input: no two pairs have non-parallel rotation axes, so S is undetermined")
    act = np.flatnonzero(active)
    score_idx = act if len(act) <= _SCORE_SUBSET else np.sort(rng.choice(act, _SCORE_SUBSET, replace=False))
    # Any S leaves pair i a residual of at least |angle(L_i) - angle(R_i)|: for right pairs
    # about |N(0, sigma^2)| (the noise along the axis), whatever S is. Its lower quartile
    # (0.3186 sigma for right pairs; larger with many wrong ones) estimates the noise
    # without a fit and caps the consensus threshold at 4.03 sigma: without the cap, wrong
    # pairs that share a bad pose (similar residuals) can win on small problems as "every
    # pair fits, loosely". The threshold is re-estimated from the residuals afterwards.
    if threshold is not None:
        cap = threshold
    else:
        delta = np.abs(angL - angR)[act]
        cap = max(_CAP_FACTOR * _CHI3_Q999 * float(np.quantile(delta, 0.25)) / 0.3186, 1e-6)
    h, k, t0, log10nfa = _orsa(_hypothesis_angles(hyp, lq[:, score_idx], rq[:, score_idx]), cap)
    logger.debug("consensus: %d hypotheses, best has %d of %d pairs within %.3g deg (log10 NFA %.1f)",
                 len(hyp), k, len(score_idx), np.degrees(t0), log10nfa)
    if log10nfa >= 0:
        warnings.append(
            f"no meaningful consensus: the best 2-pair hypothesis explains only {k} of {len(score_idx)} pairs "
            f"(within {np.degrees(t0):.3g} deg, log10 NFA {log10nfa:.1f} >= 0); the result may be wrong"
        )
    s = hyp[h]
    theta = _errors(s, lq, rq)[2]
    inl = active & (theta <= max(t0, _MIN_THRESHOLD) * (1 + 1e-9))
    # Geodesic L2 on the consensus set, threshold re-estimated, until the set is stable:
    # first with the median-based noise estimate (robust to stray outliers in the set),
    # then with the more efficient mean-square one.
    t = threshold if threshold is not None else _auto_threshold(theta, inl)
    for rms in (False, True):
        for _ in range(20):
            if inl.sum() < 2:
                break
            s, theta, _, _ = _iterate(s, lq, rq, np.where(inl, w, 0.0), "l2", max_iterations=max_iterations, tol=tol)
            if threshold is None:
                t = _auto_threshold(theta, inl, rms)
            new = active & (theta <= t)
            if np.array_equal(new, inl):
                break
            inl = new
        if threshold is not None:
            break
    c = scale if scale is not None else t
    s, theta, iterations, converged = _iterate(s, lq, rq, w, "robust", loss, c, max_iterations, tol)
    if threshold is None:  # final noise estimate from the residuals within the threshold
        within = active & (theta <= t)
        t = _auto_threshold(theta, within if within.any() else inl, rms=True)
    inl = theta <= t
    return s, theta, inl, t, c, iterations, converged, warnings


# --------------------------------------------------------------------------- translations


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


def _translation_errors(S: np.ndarray, Lm, tL, tR, t: np.ndarray) -> np.ndarray:
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


def handeye_translation_residuals(S, t, L, robot_translations, camera_translations) -> np.ndarray:
    """``|e_i| = |(L_i - I) t - S t_R,i + t_L,i|``: the translation residual of each pair for
    ``X = [S | t]`` (``S`` (3, 3) or a quaternion (4,); ``L`` (N, 3, 3) or (N, 4); the
    motions' translations (N, 3)). The camera rotations ``R_i`` do not enter it."""
    Sm = so3.matrices_from_quaternions(as_single_quaternion(S))
    Lm = so3.matrices_from_quaternions(as_quaternion_batch(L))
    n = len(Lm)
    tL = _check_translations(robot_translations, n, "robot_translations")
    tR = _check_translations(camera_translations, n, "camera_translations")
    return np.linalg.norm(_translation_errors(Sm, Lm, tL, tR, np.asarray(t, dtype=np.float64)), axis=1)


def _joint_cost(theta, e, ur, ut) -> float:
    return _wsum(ur, theta * theta) + _wsum(ut, (e * e).sum(axis=1))


def _joint_iterate(s, t, lq, rq, Lm, tL, tR, ur, ut, tscale: float, fix_rotation: bool, max_iterations: int, tol: float):
    """Gauss-Newton on ``SO(3) x R^3`` for ``sum ur_i theta_i^2 + sum ut_i |e_i|^2``.

    ``S <- S exp(omega)``, ``t <- t + delta``. Rotation block: the Jacobian of the ``l2``
    method (:func:`_gauss_newton_system`); translation block:
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
    S = _matrix(s)
    theta = _errors(s, lq, rq)[2]
    e = _translation_errors(S, Lm, tL, tR, t)
    cost = _joint_cost(theta, e, ur, ut)
    converged = False
    it = 0
    for it in range(1, max_iterations + 1):
        J = np.concatenate([S @ hat_tR, Jt], axis=2).reshape(-1, 6)
        Ju = J * u3
        H = Ju.T @ J
        g = Ju.T @ e[keep].reshape(-1)
        if not fix_rotation and (ur > 0).any():
            Hr, gr = _gauss_newton_system(s, lq, rq, ur)
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
            Sc, tc = _matrix(cand), t + delta
            th_c = _errors(cand, lq, rq)[2]
            e_c = _translation_errors(Sc, Lm, tL, tR, tc)
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
    """``t_X`` given ``S`` (``joint=False``) or ``(S, t_X)`` jointly (module docstring).

    ``rot_in`` are the pairs the rotation estimate flags as inliers (all for non-robust
    methods), ``rot_threshold`` its threshold (radians). Non-robust: one weighted linear
    least-squares fit over ``rot_in``, every translation an inlier. Robust: rounds of
    (fit, re-estimation of ``sigma_r``, ``sigma_t``, the thresholds and the inlier sets).
    """
    active = w > 0
    use = w * rot_in
    tscale = float(np.sqrt(_wsum(use, (tL * tL).sum(axis=1) + (tR * tR).sum(axis=1)) / max(float(use.sum()), 1e-300)))
    tscale = tscale if tscale > 0 else 1.0
    S = _matrix(s)
    t = _linear_translation(S, Lm, tL, tR, use)
    theta = _errors(s, lq, rq)[2]
    e = _translation_errors(S, Lm, tL, tR, t)
    en = np.linalg.norm(e, axis=1)
    if not robust:
        return _TranslationFit(s, t, theta, en, rot_threshold, None, np.ones(len(en), dtype=bool), None, None,
                               _wsum(use, en * en), 1, True)
    floor_t = _MIN_THRESHOLD * tscale

    def translation_noise(en, rot_in):
        # The threshold from the median over the rotation inliers (robust: a few bad
        # translations cannot mask themselves by inflating it), sigma_t from the truncated
        # mean square within it (efficient).
        tt = _auto_threshold(en, rot_in, floor=floor_t)
        tr_in = rot_in & (en <= tt)
        return tt, tr_in, _auto_threshold(en, tr_in if tr_in.any() else rot_in, rms=True, floor=floor_t) / _CHI3_Q999

    rot_in = rot_in & active
    tr = rot_threshold if rot_threshold is not None else _auto_threshold(theta, rot_in, rms=True)
    tt, tr_in, st = translation_noise(en, rot_in)
    prev = None
    iterations, converged, cost = 0, True, 0.0
    for _ in range(_ROUNDS):
        sr = tr / _CHI3_Q999
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
            tr = _auto_threshold(theta, within if within.any() else rot_in, rms=True)
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


def _check_translations(t, n: int, name: str) -> np.ndarray:
    x = np.asarray(t, dtype=np.float64)
    if x.shape != (n, 3):
        raise InputError(f"expected {name} of shape ({n}, 3), got {x.shape}")
    if not np.isfinite(x).all():
        raise InputError(f"{name}: translation {int(np.argmax(~np.isfinite(x).all(axis=1)))} is not finite")
    return x


# --------------------------------------------------------------------------- degeneracy


def conditioning(rotations, weights=None) -> tuple[float, np.ndarray]:
    """``(kappa, axis)``: how well pairs with these rotations determine ``S`` (module docstring).

    ``kappa^2`` is the smallest eigenvalue of ``sum w_i (|v_i|^2 I - v_i v_i^T) / sum w_i``
    with ``v_i`` the vector part of the quaternion (``sin(theta_i / 2)`` times the axis);
    ``axis`` is its eigenvector, the direction about which ``S`` is least constrained.
    ``4 sum w_i (|v_i|^2 I - v_i v_i^T)`` is the Gauss-Newton matrix of the geodesic L2 cost
    at an exact solution (in the frame of the rotations given).
    """
    q = _rows(as_quaternion_batch(rotations))
    w = _check_weights(weights, q.shape[1])
    return _kappa(q, w)


def _kappa(q: np.ndarray, w: np.ndarray) -> tuple[float, np.ndarray]:
    v = q[1:]
    vv = (v * w) @ v.T
    H = (np.trace(vv) * np.eye(3) - vv) / float(w.sum())
    lam, vec = np.linalg.eigh(H)
    return float(np.sqrt(max(lam[0], 0.0))), vec[:, 0]


def _check_conditioning(lq, rq, w, what: str = "the pairs") -> tuple[float, list[str]]:
    """Raise :class:`UnsolvableError` on degenerate data; return ``(kappa, warnings)``."""
    kL, axis = _kappa(lq, w)
    kR, _ = _kappa(rq, w)
    kappa = min(kL, kR)
    active = w > 0
    largest = float(np.degrees(2.0 * np.arcsin(min(float(np.linalg.norm(lq[1:, active], axis=0).max()), 1.0))))
    if kappa < _DEGENERATE:
        if largest < np.degrees(1e-5):
            raise UnsolvableError(
                f"degenerate input: the rotations of {what} are too small (largest angle {largest:.3g} deg); "
                "their axes are undefined, so S cannot be determined"
            )
        ax = ", ".join(f"{x:+.3f}" for x in axis)
        raise UnsolvableError(
            f"degenerate input: all rotation axes of {what} are parallel (to [{ax}] in the frame of A; "
            f"conditioning {kappa:.2g}), so S is undetermined about that axis: add motions about another axis"
        )
    warnings = []
    if kappa < _NEAR_DEGENERATE:
        ax = ", ".join(f"{x:+.3f}" for x in axis)
        warnings.append(
            f"nearly degenerate input (conditioning {kappa:.2g} < {_NEAR_DEGENERATE}): the rotation axes of {what} are "
            f"nearly parallel or the rotations small; S is poorly determined about [{ax}] (frame of A)"
        )
    return kappa, warnings


# --------------------------------------------------------------------------- public


def solve_handeye(
    L,
    R,
    method: Literal["robust", "quaternion", "procrustes", "l2", "l1"] = "robust",
    weights=None,
    *,
    loss: str = "truncated_l2",
    scale_deg: float | None = None,
    threshold_deg: float | None = None,
    seed: int | None = 0,
    max_hypotheses: int = 500,
    max_iterations: int = 200,
    tol: float = 1e-11,
    robot_translations=None,
    camera_translations=None,
    rotation_only: bool = False,
) -> HandEyeResult:
    """Conjugate rotation averaging: ``S = argmin sum_i w_i d(R_i, S^T L_i S)^p``; with the
    motions' translations, hand-eye calibration ``A_i X = X B_i`` (also ``t_X``).

    Parameters
    ----------
    L : (N, 3, 3) rotations or (N, 4) quaternions ``(w, x, y, z)`` (either sign): robot
        motions (``gripper_j_from_gripper_i``, see :func:`motions_from_poses`).
    R : the same for the camera motions (``cam_j_from_cam_i``), pair ``i`` with ``L[i]``.
    method : ``"robust"`` (default), ``"quaternion"``, ``"procrustes"``, ``"l2"``, ``"l1"``
        (module docstring).
    weights : (N,) non-negative pair weights (default 1); zero-weight pairs are not used
        but get residuals.
    loss : robust loss of the ``robust`` method, one of :data:`rotgraph.losses.LOSSES`.
    scale_deg : its scale in degrees (default: the inlier threshold).
    threshold_deg : inlier threshold in degrees. ``robust``: default automatic (4.03 times
        the per-axis noise estimated from the inliers' median residual); the other methods
        flag all pairs as inliers unless it is given.
    seed : seed of the random minimal samples (only used when there are more than
        ``max_hypotheses`` pairs of pairs; otherwise all are tried).
    max_iterations, tol : iterative stages stop after this many iterations or when a step
        is below ``tol`` radians.
    robot_translations, camera_translations : (N, 3) translations ``t_L,i`` and ``t_R,i``
        of the motions (both or neither; :func:`motions_from_poses` forms them), in any
        common unit. Then the result has ``t_X`` (``translation``), and the ``robust``
        method estimates ``S`` and ``t_X`` jointly (module docstring), unless ``rotation_only``.
    rotation_only : with translations, keep ``S`` from the rotations alone (``t_X`` is then
        fitted given ``S``). The other methods are always rotation-only.

    Returns
    -------
    HandEyeResult

    Raises
    ------
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
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; expected one of {', '.join(METHODS)}")
    if method == "robust":
        check_loss(loss)
        if scale_deg is not None and not scale_deg > 0:
            raise ValueError("scale_deg must be positive")
    if threshold_deg is not None and not threshold_deg > 0:
        raise ValueError("threshold_deg must be positive")
    lq = _rows(as_quaternion_batch(L))
    rq = _rows(as_quaternion_batch(R))
    n = lq.shape[1]
    if n != rq.shape[1]:
        raise InputError(f"L has {n} rotations but R has {rq.shape[1]}: expected one pair per index")
    w = _check_weights(weights, n)
    if (robot_translations is None) != (camera_translations is None):
        raise InputError("give both robot_translations and camera_translations, or neither")
    tL = tR = None
    if robot_translations is not None:
        tL = _check_translations(robot_translations, n, "robot_translations")
        tR = _check_translations(camera_translations, n, "camera_translations")
    if int((w > 0).sum()) < 2:
        raise UnsolvableError(f"need at least two pairs (with positive weight), got {int((w > 0).sum())}")
    kappa, warnings = _check_conditioning(lq, rq, w)
    threshold = None if threshold_deg is None else np.deg2rad(threshold_deg)
    scale = None
    iterations, converged = 0, True
    if method == "quaternion":
        s, cost, iterations, converged = _quaternion_closed_form(lq, rq, w)
        theta = _errors(s, lq, rq)[2]
    elif method == "procrustes":
        s, cost, iterations, converged = _procrustes_closed_form(lq, rq, w)
        theta = _errors(s, lq, rq)[2]
    elif method in ("l2", "l1"):
        s0 = _quaternion_closed_form(lq, rq, w)[0]
        s, theta, iterations, converged = _iterate(s0, lq, rq, w, "l2", max_iterations=max_iterations, tol=tol)
        if method == "l1":
            s, theta, iterations, converged = _iterate(s, lq, rq, w, "l1", max_iterations=max_iterations, tol=tol)
        cost = _cost(method, theta, w, None, None)
    else:
        s, theta, inl, threshold, scale, iterations, converged, more = _robust(
            lq, rq, w, loss, None if scale_deg is None else np.deg2rad(scale_deg), threshold, seed,
            max_hypotheses, max_iterations, tol,
        )
        cost = _cost("robust", theta, w, loss, scale)
        use = w * inl
        if int((use > 0).sum()) < 2:
            raise UnsolvableError("fewer than two pairs agree on any S (no consensus among the pairs)")
        # Outliers can hide a degenerate set of inliers: judge the inliers alone.
        kappa, warnings = _check_conditioning(lq, rq, use, "the inlier pairs")
        warnings += more
        n_in = int(inl[w > 0].sum())
        if n_in < 3:
            warnings.append(f"only {n_in} pairs are inliers: S rests on too few pairs to be checked")
    fit = None
    if tL is not None:
        robust = method == "robust"
        rot_in = theta <= threshold if threshold is not None else np.ones(n, dtype=bool)
        joint = robust and not rotation_only
        used = (w > 0) & rot_in
        if not used.any():
            used = w > 0
        t_scale = float(np.sqrt(((tL[used] ** 2).sum(axis=1) + (tR[used] ** 2).sum(axis=1)).max()))
        if joint and not float(np.abs(tR[used]).max()) > _T_ZERO * t_scale:
            joint = False
            warnings.append(
                ("the translations are all zero" if t_scale == 0 else "the camera motions have no translation")
                + ", so the translations do not constrain S: S from the rotations alone"
            )
        fit = _fit_translation(
            s, lq, rq, so3.matrices_from_quaternion_rows(lq), tL, tR, w, rot_in, robust=robust, joint=joint,
            loss=loss, rot_threshold=threshold, scale=None if scale_deg is None else np.deg2rad(scale_deg),
            fixed_threshold=threshold_deg is not None,
            max_iterations=max_iterations, tol=tol,
        )
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
    q = _canonical(s / np.linalg.norm(s))
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
        _, err = so3.rotation_errors(x)
        if not (err <= 1e-6).all():
            raise InputError(f"{name}: pose {int(np.argmax(~(err <= 1e-6)))} has a rotation part that is not a rotation")
        return x, t
    if x.ndim == 2 and x.shape[1] == 4:
        return so3.matrices_from_quaternions(as_quaternion_batch(x)), None
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
        raise ValueError(f"unknown pairs {pairs!r}; expected 'consecutive' or 'all'")
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
