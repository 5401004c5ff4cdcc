"""Order statistics shared by the estimators: the median and percentiles of 1-D arrays
without numpy's overhead, the weighted median, and the median of the Maxwell distribution."""

from __future__ import annotations

import numpy as np

__all__ = ["MAXWELL_MEDIAN", "median", "percentile", "weighted_median"]

#: The median of the Maxwell distribution (``chi_3``) in units of sigma: the residual angle
#: ``|e|`` of isotropic Gaussian tangent noise ``e ~ N(0, sigma^2 I_3)`` has this median,
#: so ``sigma ~ median(angles) / MAXWELL_MEDIAN``. ``sqrt(scipy.stats.chi2.ppf(0.5, 3))``.
MAXWELL_MEDIAN = 1.5381722544550522


def percentile(x: np.ndarray, p: float) -> float:
    """``np.percentile(x, p)`` (linear interpolation) of a finite 1-D array, by a partition."""
    pos = (len(x) - 1) * p / 100.0
    k = int(pos)
    if k + 1 >= len(x):
        return float(np.partition(x, k)[k])
    lo, hi = np.partition(x, [k, k + 1])[k : k + 2]
    return float(lo + (pos - k) * (hi - lo))


def median(x: np.ndarray) -> float:
    """``np.median`` of a 1-D array without its overhead (a sort of small arrays, a
    partition of large ones); NaN if any entry is NaN, as np.median."""
    n = len(x)
    if n <= 1024:
        s = np.sort(x)  # NaN sorts last
        return float("nan") if s[-1] != s[-1] else 0.5 * float(s[(n - 1) // 2] + s[n // 2])
    if np.isnan(x).any():
        return float("nan")
    k = n // 2
    if n % 2:
        return float(np.partition(x, k)[k])
    p = np.partition(x, [k - 1, k])
    return 0.5 * float(p[k - 1] + p[k])


def weighted_median(t: np.ndarray, weights: np.ndarray | None) -> float:
    """The (weighted) median of ``t``: a start of the fits."""
    if weights is None:
        return float(np.median(t))
    order = np.argsort(t)
    c = np.cumsum(weights[order])
    if c[-1] <= 0:
        return float(np.median(t))
    return float(t[order][min(int(np.searchsorted(c, 0.5 * c[-1])), len(t) - 1)])
