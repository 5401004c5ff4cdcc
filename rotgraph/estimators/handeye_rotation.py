"""The rotation estimators of :func:`rotgraph.estimators.handeye.solve_handeye`: ``S`` with
``R_i ~ S^T L_i S`` from pairs of rotations.

Quaternions are rows ``lq``, ``rq`` (4, N), canonical with ``w >= 0`` (each component a
contiguous array: fast elementwise work). Vector sums avoid BLAS level-1 calls (``x @ y``
on 1-D arrays), which are slow with a multithreaded BLAS on a busy machine.

Methods
-------
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

Degeneracy: :func:`check_conditioning` raises on data that do not determine ``S`` and
warns on nearly degenerate data (the measure ``kappa`` is explained at
:func:`rotgraph.estimators.handeye.conditioning`).
"""

from __future__ import annotations

import logging

import numpy as np
from scipy.special import gammaln

from .. import so3, so3_checks, so3_rows
from ..errors import UnsolvableError
from ..losses import loss_rho, loss_weight
from .stats import MAXWELL_MEDIAN

logger = logging.getLogger(__name__)

# Residual angle of isotropic Gaussian tangent noise N(0, sigma^2 I_3) is sigma * chi_3.
CHI3_Q999 = 4.0331422236561565  # sqrt(chi2.ppf(0.999, 3))
_CHI3_TRUNC_MS = 2.984613605124668  # E[chi2_3 | chi2_3 < chi2.ppf(0.999, 3)]
MIN_THRESHOLD = 1e-8  # rad: floor of the automatic inlier threshold (noise-free data)
_DEGENERATE = 1e-6  # conditioning below this: unsolvable
_NEAR_DEGENERATE = 0.02  # conditioning below this: warning
_MIN_AXIS_ANGLE = 1e-6  # rad: rotations smaller than this carry no axis (minimal samples)
_SCORE_SUBSET = 1000  # hypotheses are scored on at most this many pairs
_CAP_FACTOR = 1.0  # consensus threshold cap, in units of 4.03 sigma (sigma from the angle gaps)


# --------------------------------------------------------------------------- quaternion rows


def rows(q: np.ndarray) -> np.ndarray:
    """Unit quaternions (N, 4) -> canonical rows (4, N) with w >= 0."""
    return so3_rows.positive_w_rows(q.T, out=np.empty(q.shape[::-1]))


def _conjugated(s: np.ndarray, lq: np.ndarray) -> np.ndarray:
    """Rows of ``s* l_i s``, the quaternions of ``M_i = S^T L_i S``: same scalar part, vector
    part rotated by ``S^T``."""
    return np.concatenate([lq[:1], so3.matrices_from_quaternions(s).T @ lq[1:]])


def errors(s: np.ndarray, lq: np.ndarray, rq: np.ndarray):
    """Rows of ``m_i`` (``M_i = S^T L_i S``) and ``e_i`` (``E_i = R_i^T M_i``, w >= 0), and
    the angles ``theta_i`` of ``E_i`` (accurate at 0 and pi)."""
    m = _conjugated(s, lq)
    e = so3_rows.qmul_rows(so3_rows.qconj_rows(rq), m)
    so3_rows.positive_w_rows(e, out=e)
    sv = np.sqrt(e[1] * e[1] + e[2] * e[2] + e[3] * e[3])
    theta = 2.0 * np.arctan2(sv, e[0])
    return m, e, theta, sv


def wsum(w: np.ndarray, x: np.ndarray) -> float:
    return float((w * x).sum())


# --------------------------------------------------------------------------- closed forms


def _smallest_right_singular_vector(A: np.ndarray) -> np.ndarray:
    """Of a tall matrix, through its R factor (QR is backward stable: same accuracy as an
    SVD of ``A``, a fraction of the time for 4N x 4)."""
    if A.shape[0] > 4 * A.shape[1]:
        A = np.linalg.qr(A, mode="r")
    return np.linalg.svd(A)[2][-1]


def quaternion_closed_form(lq, rq, w, max_passes: int = 20):
    """Smallest right singular vector of the stacked ``sqrt(w_i) (Q_left(l_i) - Q_right(r_i))``,
    with the signs of the ``r_i`` re-chosen until they agree with ``s* l_i s``.

    ``lq``, ``rq`` are canonical rows (w >= 0), so the scalar parts already agree in sign
    (they are equal for exact data). Returns ``(s, cost, passes, converged)`` with
    ``cost = sum w |l s - s r|^2`` (= ``sum w d_quat^2`` once the signs are settled).
    """
    rq = rq.copy()
    Ql = so3.quaternion_left_matrices(lq.T)
    sw = np.sqrt(w)[:, None, None]
    s = None
    converged = False
    passes = 0
    for passes in range(1, max_passes + 1):
        s = _smallest_right_singular_vector((sw * (Ql - so3.quaternion_right_matrices(rq.T))).reshape(-1, 4))
        m = _conjugated(s, lq)
        flip = (m * rq).sum(axis=0) < 0
        if not flip.any():
            converged = True
            break
        rq[:, flip] *= -1.0
    diff = so3_rows.qmul_rows(lq, s) - so3_rows.qmul_rows(s, rq)
    cost = wsum(w, (diff * diff).sum(axis=0))
    return s, cost, passes, converged


def procrustes_closed_form(lq, rq, w, max_passes: int = 10):
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
        S = so3_checks.project_to_so3((aL * w[:, None]).T @ a)
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
    cost = wsum(w, (r * r).sum(axis=1))
    return so3.quaternions_from_matrices(S), cost, passes, converged


# --------------------------------------------------------------------------- iterative


def _gauss_newton_step(s, lq, rq, u) -> np.ndarray:
    """The Gauss-Newton step ``omega`` (``S <- S exp(omega)``) for ``sum u_i theta_i^2``
    (the system of :func:`gauss_newton_system`)."""
    H, g = gauss_newton_system(s, lq, rq, u)
    # A tiny Levenberg term keeps the solve defined on (nearly) degenerate data.
    H += (1e-14 * np.trace(H) + 1e-300) * np.eye(3)
    return -np.linalg.solve(H, g)


def gauss_newton_system(s, lq, rq, u) -> tuple[np.ndarray, np.ndarray]:
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
    m, e, theta, sv = errors(s, lq, rq)
    f = np.where(sv > 0, theta / np.where(sv > 0, sv, 1.0), 2.0)
    phi = e[1:] * f
    v, mw = m[1:], m[0]
    vxp = np.cross(v, phi, axis=0)
    d = -2.0 * mw * vxp - 2.0 * np.cross(v, vxp, axis=0)  # (I - M_i) phi_i
    g = (d * u).sum(axis=1)
    # Jr^-1(phi) = a I + 1/2 hat(phi) + c phi phi^T with a = 1 - c theta^2 and c the
    # coefficient of so3.right_jacobian_inverse.
    c = so3_rows.right_jacobian_inverse_coefficient(theta)
    a = 1.0 - c * theta**2
    alpha = a * a + 0.25 * theta**2
    beta = 2.0 * a * c + c * c * theta**2 - 0.25
    vu = v * (u * alpha)
    du = d * (u * beta)
    H = 4.0 * (float((vu * v).sum()) * np.eye(3) - vu @ v.T) + du @ d.T
    return H, g


def weighted_cost(kind: str, theta: np.ndarray, w: np.ndarray, loss: str | None, c: float | None) -> float:
    if kind == "l2":
        return wsum(w, theta * theta)
    if kind == "l1":
        return wsum(w, theta)
    return wsum(w, loss_rho(loss, theta, c))


def _irls_weights(kind: str, theta: np.ndarray, w: np.ndarray, loss: str | None, c: float | None) -> np.ndarray:
    if kind == "l2":
        return w
    if kind == "l1":
        return w / np.maximum(theta, 1e-15)
    return w * loss_weight(loss, np.maximum(theta, 1e-15), c)


def iterate(s0, lq, rq, w, kind: str, loss=None, c=None, max_iterations: int = 200, tol: float = 1e-11):
    """Minimise ``sum w_i f(theta_i)`` (``kind``: l2, l1 or robust) by reweighted Gauss-Newton.

    Each iteration takes the Gauss-Newton step of the weighted L2 cost with the IRLS
    weights at the current estimate (``w`` for l2; ``w / theta`` for l1, a Weiszfeld-type
    majorise-minimise step; ``w rho'(theta) / theta`` for a robust loss), halving it along
    the geodesic until the true cost does not rise. Stops when the step is below ``tol``
    radians, or when no step lowers the cost at machine precision.
    Returns ``(s, theta, iterations, converged)``.
    """
    s = s0 / np.linalg.norm(s0)
    theta = errors(s, lq, rq)[2]
    cost = weighted_cost(kind, theta, w, loss, c)
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
            th_c = errors(cand, lq, rq)[2]
            new = weighted_cost(kind, th_c, w, loss, c)
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
    return so3.quaternions_from_matrices(so3_checks.project_to_so3(B))


def _hypothesis_angles(s: np.ndarray, lq: np.ndarray, rq: np.ndarray) -> np.ndarray:
    """Residual angles (K, n) of K hypotheses on n pairs, via one (K,16) x (16,n) product:
    ``cos(theta/2) = |<s* l s, r>| = |<l s, s r>| = |s^T Q_left(l)^T Q_right(r) s|``."""
    P = np.einsum("nki,nkj->nij", so3.quaternion_left_matrices(lq.T), so3.quaternion_right_matrices(rq.T)).reshape(lq.shape[1], 16)
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


def auto_threshold(theta: np.ndarray, inl: np.ndarray, rms: bool = False, floor: float = MIN_THRESHOLD) -> float:
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
        sigma = float(np.median(x)) / MAXWELL_MEDIAN
    return max(CHI3_Q999 * sigma, floor)


def robust(lq, rq, w, loss, scale, threshold, seed, max_hypotheses, max_iterations, tol):
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
        cap = max(_CAP_FACTOR * CHI3_Q999 * float(np.quantile(delta, 0.25)) / 0.3186, 1e-6)
    h, k, t0, log10nfa = _orsa(_hypothesis_angles(hyp, lq[:, score_idx], rq[:, score_idx]), cap)
    logger.debug("consensus: %d hypotheses, best has %d of %d pairs within %.3g deg (log10 NFA %.1f)",
                 len(hyp), k, len(score_idx), np.degrees(t0), log10nfa)
    if log10nfa >= 0:
        warnings.append(
            f"no meaningful consensus: the best 2-pair hypothesis explains only {k} of {len(score_idx)} pairs "
            f"(within {np.degrees(t0):.3g} deg, log10 NFA {log10nfa:.1f} >= 0); the result may be wrong"
        )
    s = hyp[h]
    theta = errors(s, lq, rq)[2]
    inl = active & (theta <= max(t0, MIN_THRESHOLD) * (1 + 1e-9))
    # Geodesic L2 on the consensus set, threshold re-estimated, until the set is stable:
    # first with the median-based noise estimate (robust to stray outliers in the set),
    # then with the more efficient mean-square one.
    t = threshold if threshold is not None else auto_threshold(theta, inl)
    for rms in (False, True):
        for _ in range(20):
            if inl.sum() < 2:
                break
            s, theta, _, _ = iterate(s, lq, rq, np.where(inl, w, 0.0), "l2", max_iterations=max_iterations, tol=tol)
            if threshold is None:
                t = auto_threshold(theta, inl, rms)
            new = active & (theta <= t)
            if np.array_equal(new, inl):
                break
            inl = new
        if threshold is not None:
            break
    c = scale if scale is not None else t
    s, theta, iterations, converged = iterate(s, lq, rq, w, "robust", loss, c, max_iterations, tol)
    if threshold is None:  # final noise estimate from the residuals within the threshold
        within = active & (theta <= t)
        t = auto_threshold(theta, within if within.any() else inl, rms=True)
    inl = theta <= t
    return s, theta, inl, t, c, iterations, converged, warnings


# --------------------------------------------------------------------------- degeneracy


def kappa_and_axis(q: np.ndarray, w: np.ndarray) -> tuple[float, np.ndarray]:
    v = q[1:]
    vv = (v * w) @ v.T
    H = (np.trace(vv) * np.eye(3) - vv) / float(w.sum())
    lam, vec = np.linalg.eigh(H)
    return float(np.sqrt(max(lam[0], 0.0))), vec[:, 0]


def check_conditioning(lq, rq, w, what: str = "the pairs") -> tuple[float, list[str]]:
    """Raise :class:`UnsolvableError` on degenerate data; return ``(kappa, warnings)``."""
    kL, axis = kappa_and_axis(lq, w)
    kR, _ = kappa_and_axis(rq, w)
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

