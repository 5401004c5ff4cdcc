"""Noise models of edge residuals, fitted to the data: what the adaptive solver weighs by.

An edge's residual rotation vector ``e = log(R_j^T R_ij R_i)`` is modelled as a mixture:

* inliers: isotropic noise in the tangent space, ``e ~ N(0, sigma^2 I_3)`` (one or two
  scales: ``gauss`` / ``gauss2``), or a heavy-tailed multivariate Student t (``t``, scale
  ``sigma``, ``nu`` degrees of freedom: a Gaussian scale mixture, as real two-view
  geometries give);
* outliers: rotations drawn uniformly (Haar), whose angle has density ``(1 - cos t) / pi``.

Only the angle ``t = |e|`` is observed: a Gaussian's angle has the Maxwell density
``sqrt(2/pi) t^2 / sigma^3 exp(-t^2 / (2 sigma^2))``. The parameters are maximum-likelihood
estimates by EM. The IRLS weight of an edge is the expected inverse variance of its
noise given its residual (for a Gaussian component ``1 / sigma^2``, for the t ``(nu + 3) /
(nu sigma^2 + t^2)``) times its posterior probability of being an inlier: the iteratively
reweighted solve is then the EM algorithm of the model's maximum-likelihood rotations.

Residuals of a least-squares fit are smaller than the noise by the edge's leverage ``h``
(``E|e|^2 = 3 sigma^2 (1 - h)``): a camera on two edges shares its error with them. The
residuals are divided by ``sqrt(1 - h)`` first, ``h`` the edge's weighted effective
resistance (:func:`.leverage.leverage`: exact on thin graphs, ``1/d_i + 1/d_j`` on well-connected ones).
And a residual holds only ``1 - h`` of a degree of freedom of the noise (they add up to the
graph's ``E - n + 1`` cycles): a bridge's residual is zero whatever the noise, the ``L``
edges of a lone cycle show one cycle error between them. So each residual counts ``1 - h``
in every fit and likelihood (:func:`.leverage.residual_dofs`, the ``weights`` of the fits): without
that, the zero residuals of a sparse graph's bridges made a noise component of zero width
(an unbounded likelihood: sigma 5.7e-5 deg holding 21 % of the edges of a degree-3 graph)
and the edges outside it outliers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .leverage import (
    degree_leverage,
    fitted_residual_dofs,
    leverage,
    mean_variance_precision,
    residual_dofs,
    standardised,
)
from .stats import MAXWELL_MEDIAN, weighted_median

__all__ = ["NoiseModel", "choose_held_out", "cross_validated_log_likelihood", "degree_leverage", "fit_gaussian", "fit_t", "fitted_residual_dofs", "leverage", "mean_variance_precision", "standardised", "residual_dofs",
           "weight_exponent"]

_SQRT_2_PI = 0.5 * np.log(2.0 / np.pi)
_MIN_SIGMA = 1e-6  # rad: the noise of noise-free data (their residuals are rounding, ~1e-12)
# The EM starts' sigma = median(t) / this: stats.MAXWELL_MEDIAN to 3 decimals (1.538), as
# the starts have always used; the full value moves the converged fits, hence the solves,
# in the last digits (~1e-13 deg), so it waits for a change that may move results.
_START_MAXWELL_MEDIAN = round(MAXWELL_MEDIAN, 3)
_NUS = (0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 64.0)  # t degrees of freedom tried (above: Gaussian)
#: Residuals fitted at most: the model has 2-5 parameters, which 20 000 residuals pin down
#: to a fraction of a percent; a fixed random subset keeps each fit O(1) on large graphs.
FIT_MAX = 20_000
#: Residuals the model choice's cross-validation uses at most (:func:`cross_validated_log_likelihood`):
#: it compares two or three models of two to four parameters, which 5,000 residuals tell apart,
#: at a quarter of the cost of :data:`FIT_MAX` (five folds of three fits: ~0.1 s).
CV_MAX = 5_000
#: :meth:`NoiseModel.weights` works through this many residuals at a time.
WEIGHTS_CHUNK = 1 << 16
#: The angles (rad) at which :meth:`NoiseModel.outlier_threshold` is told (0.55 % apart),
#: and its coarse search's stride.
_THRESHOLD_GRID = np.geomspace(1e-9, np.pi, 4000)
_THRESHOLD_STRIDE = 64


@dataclass(frozen=True)
class NoiseModel:
    """A fitted residual model (angles in radians, of leverage-standardised residuals)."""

    kind: str  # "gauss", "gauss2" or "t"
    sigma: tuple  # inlier scale(s)
    inlier_fraction: tuple  # mixing weight of each inlier component
    outlier_fraction: float
    nu: float = np.inf  # t degrees of freedom

    def _log_components(self, t: np.ndarray) -> np.ndarray:
        """log(weight * density) of each component (rows: inlier components, then outliers)."""
        rows = []
        for s, p in zip(self.sigma, self.inlier_fraction):
            if self.kind == "t":
                rows.append(np.log(max(p, 1e-300)) + _t_logpdf(t, s, self.nu))
            else:
                rows.append(np.log(max(p, 1e-300)) + _maxwell_logpdf(t, s))
        rows.append(np.log(max(self.outlier_fraction, 1e-300)) + _uniform_logpdf(t))
        return np.stack(rows)

    def log_likelihood(self, t: np.ndarray, weights: np.ndarray | None = None) -> float:
        """The log-likelihood of residual angles ``t``, each counted ``weights`` times (its
        degrees of freedom: :func:`residual_dofs`; 1 when None)."""
        ll = self.log_likelihood_terms(t)
        return float(ll.sum() if weights is None else ll @ weights)

    def log_likelihood_terms(self, t: np.ndarray) -> np.ndarray:
        """Each residual angle's log-density under the model (mixture of all components)."""
        return np.logaddexp.reduce(self._log_components(t), axis=0)

    def vector_cost(self, t: np.ndarray, weights: np.ndarray | None = None) -> float:
        """The negative log-density of the residual rotation *vectors* of angles ``t`` (each
        counted ``weights`` times), up to a constant: what rotations that maximise the
        model's likelihood minimise. (An angle's density has the volume factor ``4 pi t^2``
        of the sphere of radius ``t``; the vectors' has not, and it is the vectors the
        rotations set: with that factor a zero residual would be infinitely unlikely.)"""
        ll = self.log_likelihood_terms(t) - _log_t2(t)
        return -float(ll.sum() if weights is None else ll @ weights)

    def weights(self, t: np.ndarray, normalise: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """``(IRLS weights (max 1), posterior inlier probabilities)`` of residual angles ``t``
        (in blocks of :data:`WEIGHTS_CHUNK`: at 10^7 edges whole-array temporaries cost 3 s
        a call, mostly page faults). ``normalise=False``: the weights as they are (expected
        inverse variances, rad^-2), the same for a residual wherever it is computed (the
        distributed solve weights each block's edges on its own)."""
        t = np.asarray(t, dtype=np.float64)
        if t.ndim != 1 or len(t) <= WEIGHTS_CHUNK:
            w, inlier = self._weights(t)
        else:
            w, inlier = np.empty(len(t)), np.empty(len(t))
            for a in range(0, len(t), WEIGHTS_CHUNK):
                w[a : a + WEIGHTS_CHUNK], inlier[a : a + WEIGHTS_CHUNK] = self._weights(t[a : a + WEIGHTS_CHUNK])
        return (w / max(float(w.max()), 1e-300) if normalise else w), inlier

    def _weights(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`weights` before the normalisation to a maximum of 1."""
        lc = self._log_components(t)
        post = np.exp(lc - lc.max(axis=0))
        post /= post.sum(axis=0)
        if self.kind == "t":
            s = self.sigma[0]
            w = post[0] * (self.nu + 3.0) / (self.nu * s * s + t * t)
        else:
            w = sum(post[k] / (s * s) for k, s in enumerate(self.sigma))
        return w, 1.0 - post[-1]

    def outlier_threshold(self) -> float:
        """The residual angle (rad) above which an edge is more likely an outlier than not
        (pi when no angle is: no outliers in the model): the first point of
        :data:`_THRESHOLD_GRID` where the inlier posterior is below 1/2, found on every 64th
        point first, then among the points before the first such one (the posterior falls
        with the angle: the same point as a pass over the whole grid, in 1/16 of the work)."""
        grid = _THRESHOLD_GRID
        coarse = grid[::_THRESHOLD_STRIDE]
        out = self._weights(coarse)[1] < 0.5
        if not out.any():
            hi = len(grid)  # none on the coarse points: look after the last of them
            lo = (len(coarse) - 1) * _THRESHOLD_STRIDE + 1
        else:
            hi = int(np.argmax(out)) * _THRESHOLD_STRIDE
            lo = max(hi - _THRESHOLD_STRIDE + 1, 0)
        fine = grid[lo:hi]
        out_fine = self._weights(fine)[1] < 0.5 if len(fine) else np.zeros(0, bool)
        if out_fine.any():
            return float(fine[np.argmax(out_fine)])
        return float(grid[hi]) if hi < len(grid) else float(np.pi)

    def describe(self) -> dict:
        d = {"noise_model": self.kind, "sigma_deg": [float(np.degrees(s)) for s in self.sigma],
             "outlier_fraction": float(self.outlier_fraction)}
        if self.kind == "t":
            d["nu"] = float(self.nu)
        if self.kind == "gauss2":
            d["component_fractions"] = [float(p) for p in self.inlier_fraction]
        return d


def _log_t2(t):
    return 2.0 * np.log(np.maximum(t, 1e-150))


def _maxwell_logpdf(t, s, log_t2=None):
    """Log density of the angle of ``N(0, s^2 I_3)`` (``log_t2``: ``2 log t``, when a fit has it)."""
    return _SQRT_2_PI + (_log_t2(t) if log_t2 is None else log_t2) - 3.0 * np.log(s) - t * t / (2.0 * s * s)


def _t_logpdf(t, s, nu, log_t2=None):
    """Log density of the angle of a 3-D t (scale ``s``, ``nu`` degrees of freedom)."""
    from math import lgamma, log, pi

    c = lgamma((nu + 3) / 2) - lgamma(nu / 2) - 1.5 * log(nu * pi) - 3 * log(s) + log(4 * pi)
    return c + (_log_t2(t) if log_t2 is None else log_t2) - (nu + 3) / 2 * np.log1p(t * t / (nu * s * s))


def _uniform_logpdf(t):
    # (1 - cos t) / pi = 2 sin^2(t/2) / pi: no cancellation at small angles, and the same
    # t^2 behaviour at 0 as the inlier densities (a zero residual is an inlier). Held at its
    # maximum beyond pi: a leverage-standardised residual (standardised) exceeds pi, where
    # the periodic formula fell back to 0 at 2 pi and made a gross error there likelier noise
    # than outlier (a pure Gaussian of 37 deg beat the Gaussian + outliers by 47 in log-likelihood
    # on a 45-camera sequence with 29 % outliers: called clean, 45 deg median error).
    s = np.sin(0.5 * np.clip(t, 1e-150, np.pi))
    return np.log(2.0 * s * s) - np.log(np.pi)


def subset(t: np.ndarray, seed: int, *more: np.ndarray | None, size: int = FIT_MAX):
    """The residuals a model is fitted on: all, or a fixed random ``size`` (:data:`FIT_MAX`)
    of them; with ``more`` arrays (their weights; None stays None), ``(t, *more)`` all taken
    at the same rows (one draw of the rows)."""
    if len(t) <= size:
        return (t, *more) if more else t
    rows = np.random.default_rng(seed).choice(len(t), size, replace=False)
    return (t[rows], *(None if a is None else a[rows] for a in more)) if more else t[rows]


def fit_gaussian(t: np.ndarray, components: int = 1, start: NoiseModel | None = None, iterations: int = 50,
                 tol: float = 1e-5, seed: int = 0, weights: np.ndarray | None = None) -> NoiseModel:
    """EM fit of ``components`` Maxwell components plus uniform outliers (warm-started
    from ``start`` when given), each residual counted ``weights`` times (its degrees of
    freedom, :func:`residual_dofs`; 1 when None)."""
    from math import log, sqrt

    t, om = subset(np.asarray(t, dtype=np.float64), seed, None if weights is None else np.asarray(weights, dtype=np.float64))
    if start is not None and len(start.sigma) == components and start.kind != "t":
        sig, pin, pout = [float(s) for s in start.sigma], [float(p) for p in start.inlier_fraction], start.outlier_fraction
    else:
        s0 = max(weighted_median(t, om) / _START_MAXWELL_MEDIAN, _MIN_SIGMA)
        sig = [0.5 * s0, 2.0 * s0] if components == 2 else [s0]
        pin = [0.9 / components] * components
        pout = 0.1
    m = len(t) if om is None else float(om.sum())
    tt = t * t
    ttw = tt if om is None else tt * om
    log_t2 = _log_t2(t)
    if components == 1:
        # The posterior of the inlier component is a logistic function of the log-density
        # ratio, log(outlier / inlier) = d + log(pout / p) + 3 log s + t^2 / (2 s^2): a few
        # array operations an iteration (the fits run at every IRLS iteration).
        d = _uniform_logpdf(t) - log_t2 - _SQRT_2_PI
        z = np.empty(len(t))
        for _ in range(iterations):
            s, p = sig[0], pin[0]
            np.multiply(tt, 0.5 / (s * s), out=z)
            z += d
            z += log(max(pout, 1e-300)) - log(max(p, 1e-300)) + 3.0 * log(s)
            np.minimum(z, 700.0, out=z)
            np.exp(z, out=z)
            z += 1.0
            np.reciprocal(z, out=z)  # the inlier posteriors
            n_in = float(z.sum() if om is None else z @ om)
            nk = (n_in + 1e-12, (m - n_in) + 1e-12)
            s_new = max(sqrt(float(z @ ttw) / (3.0 * nk[0])), _MIN_SIGMA)
            total = nk[0] + nk[1]
            p_new, pout_new = nk[0] / total, nk[1] / total
            done = abs(s_new - s) <= tol * abs(s) and abs(pout_new - pout) < tol
            sig, pin, pout = [s_new], [p_new], pout_new
            if done:
                break
    else:
        log_uniform = _uniform_logpdf(t)
        lc = np.empty((components + 1, len(t)))
        for _ in range(iterations):
            sa, pa = np.array(sig), np.maximum(np.array(pin), 1e-300)
            np.multiply(tt, (-0.5 / (sa * sa))[:, None], out=lc[:-1])
            lc[:-1] += log_t2
            lc[:-1] += (np.log(pa) + _SQRT_2_PI - 3.0 * np.log(sa))[:, None]
            np.add(log_uniform, log(max(pout, 1e-300)), out=lc[-1])
            lc -= lc.max(axis=0)
            post = np.exp(lc, out=lc)
            post /= post.sum(axis=0)
            nk = (post.sum(axis=1) if om is None else post @ om) + 1e-12
            sig_new = np.maximum(np.sqrt((post[:-1] @ ttw) / (3.0 * nk[:-1])), _MIN_SIGMA)
            frac = nk / nk.sum()
            done = bool((np.abs(sig_new - sa) <= tol * np.abs(sa)).all()) and abs(frac[-1] - pout) < tol
            sig, pin, pout = sig_new.tolist(), frac[:-1].tolist(), float(frac[-1])
            if done:
                break
    return NoiseModel("gauss" if components == 1 else "gauss2", tuple(sig), tuple(pin), pout)


def fit_t(t: np.ndarray, iterations: int = 40, seed: int = 0, enough_nu: float | None = None,
          weights: np.ndarray | None = None, nus: tuple | None = None) -> NoiseModel:
    """EM fit of a multivariate t (3-D, angle observed) plus uniform outliers, the degrees of
    freedom chosen from :data:`_NUS` by likelihood (each fit warm-started from the one
    before). ``enough_nu``: the caller only asks whether the best ``nu`` is below it: the
    sweep stops at the first ``nu >= enough_nu`` once the best so far is one of those (the
    rest are larger still), returning that model.

    Each fit is EM accelerated by squared extrapolation (SQUAREM, Varadhan & Roland 2008:
    two EM steps, a step along their quadratic extrapolation in ``(log sigma, logit
    p_out)``, one EM step from there, kept only when the likelihood at the extrapolated
    point is not below the cycle's start: EM's ascent is never given up), stopped
    when an EM step moves sigma by less than 1e-4 of itself and the outlier fraction by
    less than 1e-5, after at most ``iterations`` EM steps; the parameters of the highest
    likelihood met are the fit. EM alone converges linearly, slowly at small ``nu``
    (measured on rig frame graphs: 30 steps, the cap, short of the maximum by 0.01-0.25 in
    log-likelihood at nu = 0.5; with the extrapolation 10-19 steps). Without the
    likelihood test an extrapolation could jump far (sigma 0.0085 -> 0.25 rad, p_out ->
    0.95 on heavy-tailed residuals) and end the fit 60-120 below plain EM (a review); with
    it, a rejected extrapolation costs a step, and the cap is 40 steps (plain EM's 30): on
    300 random t / uniform residual sets never below plain EM's fit by more than rounding,
    the time as with 30 (the fits stop on the tolerance first). ``weights``: how many times
    each residual counts (its degrees of freedom, :func:`residual_dofs`; 1 when None).
    ``nus``: the degrees of freedom tried (default :data:`_NUS`)."""
    t, om = subset(np.asarray(t, dtype=np.float64), seed, None if weights is None else np.asarray(weights, dtype=np.float64))
    fit = _TFit(t, om)
    best, best_ll = None, -np.inf
    p = (max(weighted_median(t, om) / _START_MAXWELL_MEDIAN, _MIN_SIGMA), 0.1)
    for nu in _NUS if nus is None else nus:
        model, ll, p = fit.at(nu, p, iterations)
        if ll > best_ll:
            best, best_ll = model, ll
        if enough_nu is not None and best.nu >= enough_nu:
            break
    return best


class _TFit:
    """:func:`fit_t`'s EM on the residual angles ``t`` (counted ``om`` times; None: once), with
    the arrays every step reuses."""

    # sigma in [_MIN_SIGMA, pi], p_out in [1e-9, 0.95], in the extrapolation's coordinates
    _LO, _HI = (math.log(_MIN_SIGMA), -20.7), (math.log(np.pi), 2.94)

    def __init__(self, t: np.ndarray, om: np.ndarray | None):
        self.t, self.om = t, om
        self.m = len(t) if om is None else float(om.sum())
        self.tt = t * t
        self.ttw = self.tt if om is None else self.tt * om
        self.log_t2 = _log_t2(t)
        log_u = _uniform_logpdf(t)
        self.sum_log_u = float(log_u.sum() if om is None else log_u @ om)
        # log(t inlier / outlier) = h log1p(x) ... negated: -(d + log(pout / (1 - pout)) - c + 3 log s + h log1p(x))
        self.d = log_u - self.log_t2
        self.x, self.z, self.gam, self.x2 = (np.empty(len(t)) for _ in range(4))

    def total(self, a) -> float:
        return float(a.sum() if self.om is None else a @ self.om)

    def em(self, nu, c, h, sig, pout, likelihood=False):
        """One EM step from ``(sig, pout)``: the next parameters, and (``likelihood``) the
        log-likelihood at ``(sig, pout)``: each residual's ``log(p_out u) + softplus(z)``,
        ``z = log(t part / uniform part)`` (else None)."""
        from math import log, sqrt

        from scipy.special import expit

        x, z, gam = self.x, self.z, self.gam
        np.multiply(self.tt, 1.0 / (nu * sig * sig), out=x)  # t^2 / (nu s^2)
        np.log1p(x, out=z)
        np.multiply(z, -h, out=z)
        np.subtract(z, self.d, out=z)
        np.subtract(z, log(pout) - log(1.0 - pout) - c + 3.0 * log(sig), out=z)  # log(t part / uniform part)
        ll = None
        if likelihood:  # softplus(z) = max(z, 0) + log1p(exp(-|z|)) (np.logaddexp is 3x slower)
            np.abs(z, out=gam)
            np.negative(gam, out=gam)
            np.exp(gam, out=gam)
            np.log1p(gam, out=gam)
            ll = self.m * log(pout) + self.sum_log_u + self.total(gam) + self.total(np.maximum(z, 0.0, out=self.x2))
        expit(z, out=gam)  # posterior of the t component
        n_in = self.total(gam)
        # expected precision scale u = (nu + 3) / (nu + t^2 / s^2) = ((nu + 3) / nu) / (1 + x)
        np.add(x, 1.0, out=x)
        np.divide(gam, x, out=z)
        sig_new = max(sqrt(((nu + 3.0) / nu) * float(z @ self.ttw) / (3.0 * max(n_in, 1e-300))), _MIN_SIGMA)
        return (sig_new, min(max(1.0 - n_in / self.m, 1e-9), 0.95)), ll

    @staticmethod
    def _small(a, b):
        return abs(b[0] - a[0]) < 1e-4 * a[0] and abs(b[1] - a[1]) < 1e-5

    @staticmethod
    def _coords(p):  # unconstrained coordinates of the extrapolation
        from math import log

        return log(p[0]), log(p[1]) - log(1.0 - p[1])

    @classmethod
    def _params(cls, y):
        from math import exp

        a, b = (min(max(v, lo), hi) for v, lo, hi in zip(y, cls._LO, cls._HI))
        return exp(a), 1.0 / (1.0 + exp(-b))

    def at(self, nu: float, p: tuple, iterations: int) -> tuple[NoiseModel, float, tuple]:
        """The fit at ``nu`` degrees of freedom from the parameters ``p = (sigma, p_out)``
        (SQUAREM cycles, :func:`fit_t`): ``(model, its log-likelihood, the last parameters)``,
        the last the next ``nu``'s start."""
        from math import lgamma, log, pi, sqrt

        c = lgamma((nu + 3) / 2) - lgamma(nu / 2) - 1.5 * log(nu * pi) + log(4 * pi)
        h = (nu + 3.0) / 2.0
        top, top_ll = p, -np.inf  # the parameters of the highest likelihood evaluated
        steps = 0
        while True:
            p1, ll0 = self.em(nu, c, h, *p, likelihood=True)  # the cycle's start: its likelihood
            steps += 1
            if ll0 > top_ll:
                top, top_ll = p, ll0
            if self._small(p, p1) or steps >= iterations:
                p = p1
                break
            p2 = self.em(nu, c, h, *p1)[0]
            steps += 1
            if self._small(p1, p2) or steps >= iterations:
                p = p2
                break
            y0, y1, y2 = self._coords(p), self._coords(p1), self._coords(p2)
            r = (y1[0] - y0[0], y1[1] - y0[1])
            v = (y2[0] - 2.0 * y1[0] + y0[0], y2[1] - 2.0 * y1[1] + y0[1])
            vv = v[0] * v[0] + v[1] * v[1]
            a = min(-sqrt((r[0] * r[0] + r[1] * r[1]) / vv), -1.0) if vv > 0 else -1.0
            pe = self._params((y0[0] - 2.0 * a * r[0] + a * a * v[0], y0[1] - 2.0 * a * r[1] + a * a * v[1]))
            p3, lle = self.em(nu, c, h, *pe, likelihood=True)
            steps += 1
            if lle > top_ll:
                top, top_ll = pe, lle
            p = p3 if lle >= ll0 else p2  # the extrapolation only when it did not lose ground
            if steps >= iterations:
                break
        model = NoiseModel("t", (p[0],), (1.0 - p[1],), p[1], nu)
        ll = model.log_likelihood(self.t, self.om)
        if top_ll > ll:  # (stopped on the cap after a step that lost ground)
            model, ll = NoiseModel("t", (top[0],), (1.0 - top[1],), top[1], nu), top_ll
        return model, ll, p


def cross_validated_log_likelihood(t: np.ndarray, weights: np.ndarray | None, fitters: dict, folds: int = 5,
                                   seed: int = 0) -> dict:
    """Each model's held-out log-likelihood of residual angles ``t`` (counted ``weights``
    times each; 1 when None): ``folds``-fold cross-validation over the residuals (a fixed
    random :data:`CV_MAX` of them at most), the model ``fitters[name](t_train,
    weights_train)`` scoring the rest. ``{name: per-residual held-out log-density times its
    count}`` (their sum is the model's score; see :func:`choose_held_out`)."""
    t, om = subset(np.asarray(t, dtype=np.float64), seed, None if weights is None else np.asarray(weights, dtype=np.float64),
                   size=CV_MAX)
    om = np.ones(len(t)) if om is None else om
    fold = np.random.default_rng([seed, 2]).integers(0, folds, len(t))
    held = {name: np.zeros(len(t)) for name in fitters}
    for k in range(folds):
        train, test = fold != k, fold == k
        if not test.any() or om[train].sum() <= 0:
            continue
        for name, fit in fitters.items():
            held[name][test] = fit(t[train], om[train]).log_likelihood_terms(t[test]) * om[test]
    return held


def choose_held_out(held: dict) -> tuple[str, dict]:
    """The model to keep from per-residual held-out scores ``held`` (names in order of
    complexity, simplest first): the simplest whose total is within one standard error of
    the best's (the standard error of the summed per-residual differences): a model of more
    parameters must predict better by more than chance. Returns ``(name, {name: total})``."""
    names = list(held)
    total = {k: float(v.sum()) for k, v in held.items()}
    top = max(names, key=total.get)
    for k in names:
        d = held[top] - held[k]
        if total[top] - total[k] <= float(np.sqrt(len(d)) * d.std()):
            return k, total
    return top, total


#: The exponents ``a`` of ``sigma_e = sigma (w_e / median w)^-a`` that :func:`weight_exponent`
#: tries (0: the weights say nothing about the noise; 0.5: variance inverse to the inlier count).
WEIGHT_EXPONENTS = np.linspace(0.0, 1.5, 13)
#: Folds of its cross-validation.
WEIGHT_FOLDS = 5
#: EM steps of each exponent's Gaussian + uniform fit in the weight test.
WEIGHT_EM_STEPS = 30


def weight_exponent(t: np.ndarray, weights: np.ndarray, counts: np.ndarray, seed: int = 0,
                    reference: float = 0.0) -> tuple[float, dict]:
    """How far an edge file's weights (inlier counts) predict the noise: the exponent ``a`` of
    ``sigma_e = sigma (w_e / median w)^-a`` that best predicts held-out residuals, by
    :data:`WEIGHT_FOLDS`-fold cross-validation over the edges, among :data:`WEIGHT_EXPONENTS`;
    0 when the weights predict nothing (then they are ignored).

    The model of the residuals is the adaptive method's Gaussian + uniform outliers with
    each inlier's scale set by its weight, ``(1 - eps) Maxwell(t; sigma_e) + eps U(t)``; for
    each exponent ``(sigma, eps)`` is fitted by EM (:data:`WEIGHT_EM_STEPS`) on the other
    folds and each held-out residual scored by its log-density. Gross errors are the
    uniform part's whatever the exponent, so neither can pass for the other: wrong pairs
    of high weight do not make the weights look predictive, and the wide noise of
    low-weight edges is not called gross error. (A Gaussian-only score had let a gross
    error counted 1e-11 set the scale; scoring only a heavy-tailed fit's posterior inliers
    left out the very edges whose noise the weights explain.)

    ``t``: standardised residual angles; ``counts``: how much each counts (its degrees of
    freedom in the fit; below 1e-3, left out); ``weights``: the edge weights (positive).
    Returns ``(a, report)``, the report with the held-out log-likelihood gain of ``a`` over
    ``reference`` (an exponent of :data:`WEIGHT_EXPONENTS`: 0, the weights ignored; 0.5 for
    precisions taken as they are) and the exponents tried; of exponents equally good to
    rounding, the one closest to ``reference``."""
    t = np.asarray(t, dtype=np.float64)
    c = np.asarray(weights, dtype=np.float64)
    c = c / np.median(c)
    om = np.asarray(counts, dtype=np.float64)
    with np.errstate(divide="ignore"):
        keep = (om > 1e-3) & np.isfinite(t) & (c > 0) & np.isfinite(np.log(c))
    t, c, om = subset(t[keep], seed, c[keep], om[keep])
    fold = np.random.default_rng([seed, 29]).integers(0, WEIGHT_FOLDS, len(t))
    alogc = WEIGHT_EXPONENTS[:, None] * np.log(c)[None, :]  # (A, m)
    # log Maxwell(t; sigma c^-a) = log Maxwell(t c^a; sigma) + 3 a log c
    base = _SQRT_2_PI + _log_t2(t)[None, :] + 3.0 * alogc
    log_u = _uniform_logpdf(t)[None, :]
    held = np.zeros(len(WEIGHT_EXPONENTS))
    with np.errstate(over="ignore", invalid="ignore"):  # c^2a beyond floating point: held turns non-finite, see below
        s2 = (t * t)[None, :] * np.exp(2.0 * alogc)  # the residuals scaled to a common noise
        held = _weight_folds(held, t, om, fold, base, s2, log_u)
    ref = int(np.argmin(np.abs(WEIGHT_EXPONENTS - reference)))
    if not np.isfinite(held).all():  # weights spanning beyond floating point (c^2a overflows): they tell nothing usable
        held = np.where(np.arange(len(held)) == ref, 0.0, -np.inf)
    good = np.flatnonzero(held >= held.max() - 1e-9 * max(1.0, abs(held.max())))
    best = int(good[np.argmin(np.abs(WEIGHT_EXPONENTS[good] - reference))])
    report = {"exponent": float(WEIGHT_EXPONENTS[best]), "held_out_gain": float(held[best] - held[ref]),
              "folds": WEIGHT_FOLDS, "exponents_tried": [float(x) for x in WEIGHT_EXPONENTS]}
    return float(WEIGHT_EXPONENTS[best]), report


def _weight_folds(held, t, om, fold, base, s2, log_u):
    """The cross-validation folds of :func:`weight_exponent`: each exponent's Gaussian +
    uniform fit on the other folds, its held-out log-likelihood added to ``held``. Each EM
    step is five passes over the (exponents, residuals) table, in place, and two weighted sums:
    half the log-odds of the inlier part ``z / 2`` (the part that does not depend on ``sigma``
    or ``eps`` made once a fold) and twice its posterior, ``1 + tanh(z / 2)`` (with fresh arrays
    for each of a dozen operations the information test had taken a third of a solve with
    information of 2,000 cameras / 20,000 edges)."""
    for k in range(WEIGHT_FOLDS):
        train, test = fold != k, fold == k
        wt = om[train]
        if wt.sum() <= 0 or not test.any():
            continue
        half = 0.5 * (base[:, train] - log_u[:, train])  # log(inlier / outlier part) / 2 but for sigma and eps
        q2 = s2[:, train]
        qw = q2 * wt
        z = np.empty_like(half)
        total = wt.sum()
        var = np.full((len(WEIGHT_EXPONENTS), 1), max(float(np.median(t[train])) / _START_MAXWELL_MEDIAN, _MIN_SIGMA) ** 2)
        eps = np.full((len(WEIGHT_EXPONENTS), 1), 0.1)
        for _ in range(WEIGHT_EM_STEPS):
            np.multiply(q2, -0.25 / var, out=z)
            z += half
            z += 0.5 * (-1.5 * np.log(var) + np.log1p(-eps) - np.log(eps))
            np.tanh(z, out=z)
            z += 1.0  # twice the inlier posterior, 2 expit(z)
            n_in = 0.5 * (z @ wt)
            var = np.maximum(0.5 * np.einsum("ij,ij->i", z, qw) / (3.0 * np.maximum(n_in, 1e-300)), _MIN_SIGMA ** 2)[:, None]
            eps = np.clip(1.0 - n_in / total, 1e-9, 0.95)[:, None]
        log_in = base[:, test] - 1.5 * np.log(var) - s2[:, test] / (2.0 * var) + np.log1p(-eps)
        held += np.logaddexp(log_in, log_u[:, test] + np.log(eps)) @ om[test]
    return held
