"""The iterative means of :func:`rotgraph.estimators.single.mean`: descent on unit quaternions.

Each iteration is a weighted L2 step of the metric (geodesic: a Karcher / Newton step;
chordal: the dominant eigenvector of ``sum u_i q_i q_i^T``; quaternion: the sign-chosen
average) with the weights ``u = w`` (L2), ``w / d`` (L1, Weiszfeld; Hartley, Aftab &
Trumpf, CVPR 2011 for the geodesic median) or ``w rho'(d) / d`` (robust, IRLS with a loss
of :mod:`rotgraph.losses`), safeguarded by a descent test: a step that does not lower the
cost is halved along the geodesic until it does. When an L1 iterate lands on a data point
(the Weiszfeld weight ``1/d`` is infinite there), the point is tested for optimality with
the subgradient condition ``|grad of the others| <= w_k * c_metric``; if it fails, the step
is taken without that point (Vardi & Zhang 2000), which is a descent direction.

Quaternions are rows ``Q`` (4, N) (each component a contiguous array). One pass over the
data per iteration (:class:`_Eval`, blockwise) gives the cost and the sums of the next step.
"""

from __future__ import annotations

import numpy as np

from .. import so3, so3_rows
from ..losses import loss_curvature, loss_rho, loss_weight
from .single_quaternion import dominant_eigenvector

# Weiszfeld steps are stretched by this factor (safeguarded by the descent test).
_L1_OVERRELAX = 1.5
# How close (radians) an iterate must be to a data point to count as "on" it.
_COINCIDENT = 1e-12
# Within this (sin of half the angle) of a datum, the L1 iterations test its optimality.
_NEAR_DATUM = 5e-5
# Local Lipschitz factor of each metric's distance in the tangent angle at 0.
_SLOPE = {"geodesic": 1.0, "chordal": np.sqrt(2.0), "quaternion": 0.5}
# conj(m) = m * _CONJ; L(conj(m)) @ Q are the relative rotations R^T R_i.
_CONJ = np.array([1.0, -1.0, -1.0, -1.0])


# --------------------------------------------------------------------------- geometry


class Geometry:
    """Everything about the data seen from a candidate mean ``m`` (quaternion).

    ``P = conj(m) * q_i`` (4, N) are the relative rotations ``R^T R_i``; with
    ``c = |P_w| = cos(theta/2)`` and ``s = |P_xyz| = sin(theta/2)`` every distance is a
    cheap accurate function of ``(s, c)``: no arccos, and one arctan for the geodesic metric.
    """

    __slots__ = ("m", "P", "c", "s", "d", "_theta", "cost")

    def __init__(self, m, Q, w, metric, power, loss=None, scale=None):
        m = m / np.linalg.norm(m)
        P = so3.quaternion_left_matrices(m * _CONJ) @ Q
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


def _slerp(a: np.ndarray, b: np.ndarray, t: float) -> np.ndarray:
    rel = so3.quaternion_multiply(so3.quaternion_conjugate(a), b)
    return so3.quaternion_multiply(a, so3.quaternion_exp(t * so3.quaternion_log(rel)))


def _step_angle(a: np.ndarray, b: np.ndarray) -> float:
    c = abs(float(a @ b))
    s = np.linalg.norm(so3.quaternion_multiply(so3.quaternion_conjugate(a), b)[1:])
    return 2.0 * float(np.arctan2(s, c))


# --------------------------------------------------------------------------- updates


def _weighted_l2_step(g: Geometry, Q, u, metric):
    """The minimiser (geodesic: one Karcher step) of ``sum u_i d_i^2`` from ``g``."""
    if metric == "geodesic":
        return so3.quaternion_multiply(g.m, so3.quaternion_exp(g.sum_log_vectors(u) / u.sum()))
    if metric == "chordal":
        return dominant_eigenvector((Q * u) @ Q.T)
    return Q @ (u * g.signs)


def _candidate(g: Geometry, Q, w, metric, norm, loss, scale):
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


_BLOCK = 8192
# Half width in cos(theta / 2) of the band of data near the cut locus (angle pi) that the
# Newton steps of the geodesic means take into account.
_BAND = 0.05


def _geodesic_angles(s: np.ndarray, c: np.ndarray) -> np.ndarray:
    """The angles ``theta = 2 arctan(s / c)`` of the data (``s`` = ``sin(theta / 2)``, floored
    at 1e-150 in place; ``c`` = ``|cos(theta / 2)|``)."""
    s = np.maximum(s, 1e-150, out=s)  # theta / s -> 2 / c at s = 0
    with np.errstate(divide="ignore"):  # inf at a half turn: arctan gives pi/2
        d = np.divide(s, c, out=np.empty_like(s))
    d = np.arctan(d, out=d)  # (arctan is twice as fast as arctan2)
    d *= 2.0
    return d


def _cost_and_step_weights(norm: str, wc: np.ndarray, d: np.ndarray, loss, scale) -> tuple[float, np.ndarray]:
    """A block's cost and the step weights ``u`` (``w``, ``w / d`` or ``w rho'(d) / d``) at
    the distances ``d``."""
    if norm == "l2":
        wd = wc * d
        return float(wd @ d), wc
    if norm == "l1":
        return float(wc @ d), wc / np.maximum(d, 1e-300)  # a datum the iterate sits on is handled apart
    return float(wc @ loss_rho(loss, d, scale)), wc * loss_weight(loss, np.maximum(d, _COINCIDENT), scale)


def _hessian_terms(Pv: np.ndarray, wc: np.ndarray, u: np.ndarray, d: np.ndarray, s: np.ndarray, c: np.ndarray,
                   f: np.ndarray, norm: str, loss, scale) -> tuple[float, np.ndarray]:
    """A block's ``(sum u b, sum (curv - u b) / s^2 v v^T)``: the isotropic and the rank-one
    parts of the Riemannian Hessian of ``sum w phi(theta_i)``, ``sum w [phi'' u u^T +
    (phi' / theta) b (I - u u^T)]``, ``b = (theta / 2) cot(theta / 2) = f c / 2``."""
    b = f * c
    b *= 0.5
    ub = u * b
    curv = wc if norm == "l2" else wc * loss_curvature(loss, d, scale)
    coef = (curv - ub) / (s * s)
    X = Pv * coef
    h01, h02, h12 = X[0] @ Pv[1], X[0] @ Pv[2], X[1] @ Pv[2]
    return float(ub.sum()), np.array([[X[0] @ Pv[0], h01, h02], [h01, X[1] @ Pv[1], h12], [h02, h12, X[2] @ Pv[2]]])


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
        L = so3.quaternion_left_matrices(m * _CONJ)
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
                d = _geodesic_angles(s, c)  # (s floored in place)
                if norm == "l2" and not far:
                    if wpos is None:
                        far = bool((s >= c).any())
                    else:
                        far = bool(((s >= c) & wpos[lo:hi]).any())
            elif metric == "chordal":
                d = s * (2.0 * np.sqrt(2.0))
            else:
                d = s * np.sqrt(2.0 / (1.0 + c))  # = 2 sin(theta / 4)
            dcost, u = _cost_and_step_weights(norm, wc, d, loss, scale)
            cost += dcost
            usum += float(u.sum())
            if geodesic:
                # log_i = sign(P0) (theta / s) P[1:]; sum u log_i
                f = d / s
                a = u * f
                G += Pv @ np.copysign(a, P0)
                if newton:
                    dhdiag, dH = _hessian_terms(Pv, wc, u, d, s, c, f, norm, loss, scale)
                    hdiag += dhdiag
                    H += dH
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
            return dominant_eigenvector(self.step)
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


def angles(m, Q) -> np.ndarray:
    """(N,) geodesic angle of each datum to ``m`` (blockwise)."""
    L = so3.quaternion_left_matrices(m / np.linalg.norm(m) * _CONJ)
    n = Q.shape[1]
    out = np.empty(n)
    for lo in range(0, n, _BLOCK):
        hi = min(lo + _BLOCK, n)
        P = L @ Q[:, lo:hi]
        with np.errstate(divide="ignore"):
            np.arctan(np.sqrt(np.einsum("ij,ij->j", P[1:], P[1:])) / np.abs(P[0]), out=out[lo:hi])
    out *= 2.0
    return out


def iterate(m0, Q, w, metric, norm, loss, scale, max_iterations, tol, newton=None):
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
            cand, at_optimum = _candidate(Geometry(g.m, Q, w, metric, power), Q, w, metric, norm, loss, scale)
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
            if 0.5 * _COINCIDENT <= g.smin < _NEAR_DATUM and k not in tried:
                tried.add(k)
                gk = Geometry(Q[:, k], Q, w, metric, power)
                if _candidate(gk, Q, w, metric, norm, loss, scale)[1] and gk.cost <= g.cost + slack:
                    g, converged = _Eval(Q[:, k], *args), True
                    break
    return g, it, converged


# --------------------------------------------------------------------------- many means at once


def geodesic_l1_means(Q: np.ndarray, starts: np.ndarray, tol: float = 1e-6, max_iterations: int = 200) -> np.ndarray:
    """Geodesic L1 means (unit weights) of many small groups of rotations at once.

    ``Q`` (4, N): quaternion rows sorted by group, group ``g`` the columns
    ``starts[g]:starts[g + 1]`` (``starts`` (G + 1,), every group non-empty). Returns the
    means as rows (4, G), ``w >= 0``. The iterations of :func:`iterate` for ``metric =
    "geodesic", norm = "l1"`` on every group in one pass over the data: from each group's
    chordal L2 mean, over-relaxed Weiszfeld steps under the descent test (a step that does
    not lower a group's cost is halved), a group stopping when its step is below ``tol``
    radians or its iterate sits on a datum that satisfies the subgradient condition
    (Vardi & Zhang: a datum on the iterate is left out of the step), which is tested at each
    group's nearest datum whenever that changes (:func:`iterate` tests it within
    :data:`_NEAR_DATUM`; here at any distance, once per datum: a batch cannot afford the
    sublinear creep towards it). Unit weights only. For callers with many
    groups of a few rotations each (per-camera restarts), where a Python loop over
    :func:`~.single.mean` would cost a millisecond a group."""
    Q = np.asarray(Q, dtype=np.float64)
    starts = np.asarray(starts, dtype=np.int64)
    G = len(starts) - 1
    lo = starts[:-1]
    group = np.repeat(np.arange(G), np.diff(starts))
    # each group's chordal L2 mean: the dominant eigenvector of sum q q^T
    K = np.add.reduceat((Q[:, None, :] * Q[None]).reshape(16, -1), lo, axis=1).T.reshape(G, 4, 4)
    m = np.linalg.eigh(K)[1][:, :, -1].T.copy()  # (4, G)

    def evaluate(m):
        """Log vectors (3, N) of each datum in its group's tangent at ``m``, angles (N,), costs (G,)."""
        P = so3_rows.qmul_rows(so3_rows.qconj_rows(m)[:, group], Q)
        v, theta = so3_rows.qlog_rows(P)
        return v, theta, np.add.reduceat(theta, lo)

    def pull(v, theta):
        """Per group: the sum (3, G) of the unit vectors towards the data off the iterate
        (minus the cost's gradient there), the sum of their Weiszfeld weights ``1/theta``,
        and the number of data on the iterate."""
        on = theta < _COINCIDENT
        u = np.where(on, 0.0, 1.0 / np.maximum(theta, _COINCIDENT))
        return np.add.reduceat(v * u, lo, axis=1), np.add.reduceat(u, lo), np.add.reduceat(on.astype(np.float64), lo)

    v, theta, cost = evaluate(m)
    active = np.ones(G, dtype=bool)
    tried = np.full(G, -1)  # per group, the datum whose optimality was last tested
    for _ in range(max_iterations):
        grad, usum, n_on = pull(v, theta)
        gnorm = np.sqrt((grad * grad).sum(axis=0))
        active &= ~((n_on > 0) & (gnorm <= n_on)) & (usum > 0)  # on a datum that is optimal
        step = _L1_OVERRELAX * grad / np.where(usum > 0, usum, 1.0)
        active &= np.sqrt((step * step).sum(axis=0)) >= tol
        if not active.any():
            break
        step[:, ~active] = 0.0
        # descent test: halve the steps of the groups whose cost did not drop
        trial = active.copy()
        for _ in range(31):
            cand = so3_rows.qmul_rows(m, so3_rows.qexp_rows(step))
            cv, ct, ccost = evaluate(cand)
            worse = trial & (ccost > cost + 1e-13 * np.abs(cost))
            if not worse.any():
                break
            step[:, worse] *= 0.5
            trial = worse
        stuck = worse  # no descent at machine precision: stationary
        step[:, stuck] = 0.0
        active &= ~stuck
        if stuck.any():
            cand = so3_rows.qmul_rows(m, so3_rows.qexp_rows(step))
            cv, ct, ccost = evaluate(cand)
        m, v, theta, cost = cand, cv, ct, ccost
        m /= np.sqrt((m * m).sum(axis=0))
        # Weiszfeld creeps towards an optimal datum only sublinearly (0.25 -> 0.0018 rad in
        # 200 iterations on 3 rotations): each group tests the optimality condition at its
        # nearest datum, once per datum (when the nearest changes), and stops on it when it
        # holds (and costs no more).
        gmin = np.minimum.reduceat(theta, lo)
        near = active & (gmin >= _COINCIDENT)
        if near.any():
            idx = np.flatnonzero(near[group] & (theta == gmin[group]))
            gk, first = np.unique(group[idx], return_index=True)
            kpos = idx[first]
            fresh = tried[gk] != kpos
            gk, kpos = gk[fresh], kpos[fresh]
            tried[gk] = kpos
            if len(gk):
                m_try = m.copy()
                m_try[:, gk] = Q[:, kpos]
                tv, tt, tcost = evaluate(m_try)
                grad, _, n_on = pull(tv, tt)
                optimal = (np.sqrt((grad * grad).sum(axis=0)) <= n_on) & (tcost <= cost + 1e-13 * np.abs(cost))
                snap = gk[optimal[gk]]
                if len(snap):
                    cols = np.isin(group, snap)
                    m[:, snap] = m_try[:, snap]
                    v[:, cols], theta[cols], cost[snap] = tv[:, cols], tt[cols], tcost[snap]
                    active[snap] = False
    return so3_rows.positive_w_rows(m)
