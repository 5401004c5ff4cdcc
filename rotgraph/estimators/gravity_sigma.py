"""The gravity noise estimate of the gravity variant (:mod:`.gravity_solve`; step 2b of
:mod:`.gravity`): the noise of the gravity priors whose sigma is not given, from how far each
image's gravity lies from the gravities its neighbours predict through the edges.

Each edge predicts one image's gravity from the other's: ``R_ij^T g_j`` at ``i``. Under the
noise model of :mod:`.gravity` a prediction is off the true gravity by ``a_j + e_perp`` (the neighbour's tilt
noise and two axes of the edge noise) and the measured ``g_i`` by its own ``a_i``. Per image,
the neighbours' predictions get a robust centre (coordinate-wise median of the unit
vectors), those within 4 pooled noise units of it are kept (outlier edges, wrong neighbour
gravities out) and averaged; the 2-D angle ``c_i`` between that mean and ``g_i`` has
``E |c_i|^2 / 2 = s_i^2 + V_i``, ``V_i = sum_j (s_j^2 + sigma_edge^2) / m_i^2`` the variance of
the mean prediction (``m_i`` kept): the solve-free analogue of the solve's own error, so
that exact gravity gives ``s ~ 0``. ``V_i`` is estimated without bias from the kept
predictions' own scatter ``S_i / (m_i (m_i - 1))`` (whatever the neighbours' sigmas; no
edge noise model); a model value (``sigma_edge`` from the yaw residuals of step 2, free of
the gravity noise to first order) sets the weights and the outlier test only. One ``s`` for
all images to estimate (images with ``m_i >= 3``): a robust start (the median of
``|c_i|^2 / (2 E)`` at its Exp(1) value ln 2), images with ``|c_i|^2 / (2 E) > 9.21``
(p < 1e-4) flagged as wrong gravity (``diagnostics["gravity"]["gravity_outliers"]``; solved
without their gravity, started from their neighbours), a second pass without them as
predictors, then the weighted mean of ``|c_i|^2 / 2 - V_i`` (weights ``1 / (s^2 + V_i)^2``)
with its empirical standard error. Within :data:`HARD_Z` standard errors of zero it is
taken as 0: the hard constraint. Measured (er graphs, degree 10, 2-deg edges, 10 % outlier
edges, 3 seeds): 0.46-0.51 / 0.95-0.99 / 1.94-2.00 deg for 0.5 / 1 / 2 at n = 1000,
0.50-0.60 / 0.97-1.05 / 1.92-2.00 at n = 200; exact gravity: 0 (hard); the solve's error
with the estimate within 2 % of that with the true sigma. Thin graphs (degree 4) read high
(0.62-0.64 for 0.5 at n = 500; 2 standard errors) at no cost in the solve (<= 1.3 %).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .gravity_geometry import unit_rows
from .stats import median

__all__ = ["GRAVITY_OUTLIER_Z", "HARD_Z", "MIN_GRAVITY_SIGMA_DEG", "MIN_ESTIMATE_IMAGES", "estimate_gravity_sigma"]

#: Chi-square(2) / 2 quantile above which an image's gravity is flagged wrong (p = 1e-4).
GRAVITY_OUTLIER_Z = 9.21
#: The estimated gravity sigma is taken as zero (the hard constraint) below this many standard errors.
HARD_Z = 3.0
#: An estimated gravity sigma below this (degrees) is taken as zero (noise-free data).
MIN_GRAVITY_SIGMA_DEG = 1e-3
#: Fewest images (with >= 3 consistent neighbour predictions) to estimate the gravity noise from.
MIN_ESTIMATE_IMAGES = 10


def _group_median(keys: np.ndarray, vals: np.ndarray, n: int) -> np.ndarray:
    """Median of ``vals`` (K, c) per group ``keys`` (K,) in ``range(n)``: (n, c), NaN for empty groups."""
    out = np.full((n, vals.shape[1]), np.nan)
    cnt = np.bincount(keys, minlength=n)
    start = np.concatenate([[0], np.cumsum(cnt)[:-1]])
    ok = cnt > 0
    lo = (start + (cnt - 1) // 2)[ok]
    hi = (start + cnt // 2)[ok]
    for c in range(vals.shape[1]):
        s = vals[np.lexsort((vals[:, c], keys)), c]
        out[ok, c] = 0.5 * (s[lo] + s[hi])
    return out


def _log_at_y(v: np.ndarray) -> np.ndarray:
    """The 2-D log map (x, z; radians) at ``e_y`` of unit vectors ``v`` (K, 3)."""
    xz = v[:, [0, 2]]
    s = np.linalg.norm(xz, axis=1)
    ang = np.arctan2(s, v[:, 1])
    f = np.where(s > 1e-300, ang / np.where(s > 1e-300, s, 1.0), 1.0)
    return xz * f[:, None]


def _gravity_predictions(edges, Rrel, g, A, use):
    """Each usable edge's two predictions of a gravity from the other end's: at ``i``,
    ``R_ij^T g_j``; at ``j``, ``R_ij g_i``; each in the node's aligned frame (``A^T p``: its
    own gravity is ``e_y``). Returns ``(node (K,), other (K,), unit vectors (K, 3))``."""
    e = np.flatnonzero(use[edges[:, 0]] & use[edges[:, 1]])
    i, j = edges[e, 0], edges[e, 1]
    Re = Rrel[e]
    p_i = np.einsum("kba,kb->ka", Re, g[j])  # R^T g_j, at i
    p_j = np.einsum("kab,kb->ka", Re, g[i])  # R g_i, at j
    node = np.concatenate([i, j])
    other = np.concatenate([j, i])
    p = np.concatenate([p_i, p_j])
    return node, other, np.einsum("kab,ka->kb", A[node], p)


class _Predictions(NamedTuple):
    """Per image, from the kept predictions of its gravity (those within 4 pooled noise units
    of their robust centre): ``m`` their count, ``y`` half the squared 2-D angle between
    their mean and the image's gravity, ``S`` half their scatter about their mean, ``G`` the
    sum of the predicting neighbours' given variances, ``U`` how many of those neighbours
    have theirs estimated."""

    m: np.ndarray
    y: np.ndarray
    S: np.ndarray
    G: np.ndarray
    U: np.ndarray


def _kept(node, p, n):
    """Which predictions ``p`` (K, 3) of the images ``node`` (K,, sorted) are kept: within 4
    pooled noise units of each image's robust centre (coordinate-wise median)."""
    med = _group_median(node, p, n)  # a robust centre per image
    med[~(np.linalg.norm(np.nan_to_num(med), axis=1) > 1e-12)] = [0.0, 1.0, 0.0]
    med = unit_rows(med)
    dev = np.arctan2(np.linalg.norm(np.cross(p, med[node]), axis=1), (p * med[node]).sum(axis=1))
    # pooled prediction noise per axis (Rayleigh median 1.1774 sigma); keep within 4 of it
    sp = max(median(dev) / 1.1774, np.deg2rad(1e-4))
    return dev <= 4.0 * sp


def _prediction_stats(node, other, p, n, sigma, est) -> _Predictions:
    """:class:`_Predictions` of the predictions ``p`` of images ``node`` from ``other``."""
    order = np.argsort(node, kind="stable")
    node, other, p = node[order], other[order], p[order]
    keep = _kept(node, p, n)
    m = np.bincount(node[keep], minlength=n).astype(float)
    v = np.stack([np.bincount(node[keep], weights=p[keep, a], minlength=n) for a in range(3)], axis=1)
    v[m == 0] = [0.0, 1.0, 0.0]
    c = _log_at_y(unit_rows(v))  # the image's gravity residual: mean prediction vs e_y
    y = 0.5 * (c * c).sum(axis=1)  # E y = s_i^2 + (sum_j s_j^2 + m sigma_e^2) / m^2
    # the kept predictions' scatter: E S = (m - 1) / m * sum_j (s_j^2 + sigma_e^2) (per axis)
    dl = _log_at_y(p[keep])
    mk = np.maximum(m, 1.0)
    dbar = np.stack([np.bincount(node[keep], weights=dl[:, a], minlength=n) for a in range(2)], axis=1) / mk[:, None]
    S = 0.5 * np.bincount(node[keep], weights=((dl - dbar[node[keep]]) ** 2).sum(axis=1), minlength=n)
    given = np.where(np.isnan(sigma), 0.0, sigma) ** 2
    G = np.bincount(node[keep], weights=given[other[keep]], minlength=n)
    U = np.bincount(node[keep], weights=est[other[keep]].astype(float), minlength=n)
    return _Predictions(m, y, S, G, U)


def _robust_start(y_, m_, G_, U_, se2) -> float:
    """The common variance ``s^2`` at which the median of ``y / E y`` is that of Exp(1), ln 2
    (bisection), or 0 when it is below that at zero."""
    a_ = 1.0 + U_ / m_**2
    b_ = G_ / m_**2 + se2 / m_
    lo, hi = 0.0, max(float(np.max(y_)), 1e-30)
    if median(y_ / b_) <= np.log(2.0):
        return 0.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if median(y_ / (mid * a_ + b_)) > np.log(2.0) else (lo, mid)
    return 0.5 * (lo + hi)


def _wrong_gravity(st: _Predictions, s2, se2, est, flagged) -> np.ndarray:
    """The images (not yet ``flagged``) whose gravity is far outside the noise (p < 1e-4)."""
    m, y, G, U = st.m, st.y, st.G, st.U
    z = y / np.maximum(s2 * (1.0 + U / np.maximum(m, 1.0) ** 2) + G / np.maximum(m, 1.0) ** 2
                       + se2 / np.maximum(m, 1.0), 1e-300)
    return est & (m >= 3) & (z > GRAVITY_OUTLIER_Z) & ~flagged


def _robust_passes(edges, Rrel, g, A, has, sigma, est, se2):
    """Two passes (the second without the flagged images as predictors): ``(robust start
    s^2 or None, flagged (n,) bool, the last pass's _Predictions or None)``."""
    n = len(g)
    flagged = np.zeros(n, dtype=bool)
    use = has.copy()
    s2 = st = None
    for _pass in range(2):
        node, other, p = _gravity_predictions(edges, Rrel, g, A, use)
        if len(node) == 0:
            break
        st = _prediction_stats(node, other, p, n, sigma, est)
        ok = est & (st.m >= 3) & ~flagged
        if ok.sum() < MIN_ESTIMATE_IMAGES:
            break
        s2 = _robust_start(st.y[ok], st.m[ok], st.G[ok], st.U[ok], se2)
        new = _wrong_gravity(st, s2, se2, est, flagged)
        flagged |= new
        if not new.any():
            break
        use = has & ~flagged
    return s2, flagged, st


def _weighted_variance(st: _Predictions, ok, s2, se2) -> tuple[float, float]:
    """``(s^2, its standard error)``: the weighted mean over the images ``ok`` of each one's
    unbiased ``s_i^2`` (``y`` less the variance of its mean prediction, that from the
    predictions' own scatter ``S / (m (m - 1))``: independent of ``y`` for Gaussian noise, no
    edge noise model needed, whatever the neighbours' sigmas), weights ``1 / Var(y) =
    1 / (s^2 + b)^2`` (``y`` exponential; ``b`` the model's value of that variance, weights
    only), from the robust start ``s2``."""
    y_, m_, G_, U_ = st.y[ok], st.m[ok], st.G[ok], st.U[ok]
    t_ = y_ - st.S[ok] / (m_ * (m_ - 1.0))
    b_ = (G_ + U_ * s2) / m_**2 + se2 / m_
    for _ in range(20):
        w = 1.0 / (s2 + b_) ** 2
        new_s2 = max(float((w * t_).sum() / w.sum()), 0.0)
        converged_s2 = abs(new_s2 - s2) <= 1e-6 * max(s2, 1e-30)
        s2 = new_s2
        b_ = (G_ + U_ * s2) / m_**2 + se2 / m_
        if converged_s2:
            break
    w = 1.0 / (s2 + b_) ** 2
    return s2, float(np.sqrt((w * w * (t_ - s2) ** 2).sum()) / w.sum())  # empirical (sandwich) standard error


def estimate_gravity_sigma(edges, Rrel, g, A, has, sigma, sigma_edge):
    """The gravity noise of the images whose ``sigma`` (radians) is NaN, from how far each
    image's gravity lies from the gravities its neighbours predict through the edges
    (``Rrel`` (E, 3, 3); ``A`` the gravity-aligned rotations of the images ``has``; the
    module docstring). Returns ``(sigma (n,) with the NaN filled, flagged (n,) bool: gravity
    inconsistent with the neighbours', report dict)``."""
    est = has & np.isnan(sigma)
    report: dict = {"method": "each image's gravity vs the mean of its neighbours' gravities carried through the "
                              "edges (robust: median centre, 4-sigma cut), less that mean's variance from the "
                              "predictions' scatter; weighted mean over the images, 0 within 3 standard errors"}
    se2 = sigma_edge**2
    s2, flagged, st = _robust_passes(edges, Rrel, g, A, has, sigma, est, se2)
    ok = est & (st.m >= 3) & ~flagged if s2 is not None else np.zeros(len(g), dtype=bool)
    if ok.sum() < MIN_ESTIMATE_IMAGES:
        report.update(estimated=False, decision="hard (no estimate)",
                      reason=f"fewer than {MIN_ESTIMATE_IMAGES} images with >= 3 consistent gravity neighbours")
        return np.where(est, 0.0, sigma), flagged, report
    s2, se_s2 = _weighted_variance(st, ok, s2, se2)
    hard = s2 < HARD_Z * se_s2 or s2 < np.deg2rad(MIN_GRAVITY_SIGMA_DEG) ** 2
    report.update(
        estimated=True, n_images_used=int(ok.sum()), raw_sigma_deg=float(np.degrees(np.sqrt(s2))),
        variance_deg2=float(np.degrees(np.degrees(s2))), variance_se_deg2=float(np.degrees(np.degrees(se_s2))),
        edge_sigma_deg=float(np.degrees(sigma_edge)),
        decision=f"hard: the estimate is within {HARD_Z:g} standard errors of zero (or below "
                 f"{MIN_GRAVITY_SIGMA_DEG:g} deg)" if hard else "soft",
    )
    out = sigma.copy()
    out[est] = 0.0 if hard else float(np.sqrt(s2))
    return out, flagged, report
