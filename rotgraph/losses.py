"""Robust losses rho(r) of a residual r >= 0 (radians) with scale c, their IRLS weights
and their curvature rho''(r) (Newton steps).

Each loss is normalised so that ``rho(r) ~ r^2 / 2`` for ``r << c`` (except ``l1`` and
``half_norm``, which have no scale); the IRLS weight is ``rho'(r) / r``.

=================  ======================================  ===========================
name               rho(r)                                  weight rho'(r) / r
=================  ======================================  ===========================
``l2``             r^2 / 2                                 1
``l1``             r                                       1 / r
``huber``          r^2/2 if r <= c else c (r - c/2)        1 if r <= c else c / r
``cauchy``         c^2/2 log(1 + (r/c)^2)                  1 / (1 + (r/c)^2)
``geman_mcclure``  (c^2 r^2 / 2) / (c^2 + r^2)             c^4 / (c^2 + r^2)^2
``half_norm``      2 sqrt(r)   (the L1/2 "norm")            r^(-3/2)
``truncated_l2``   min(r, c)^2 / 2                         1 if r < c else 0
=================  ======================================  ===========================

The weights of ``l1`` and ``half_norm`` are singular at 0: callers pass residuals already
floored at a small positive value.
"""

from __future__ import annotations

import numpy as np

from .choices import LOSSES
from .errors import OptionError

__all__ = ["LOSSES", "loss_rho", "loss_weight", "loss_curvature", "check_loss"]



def check_loss(name: str) -> str:
    if name not in LOSSES:
        raise OptionError(f"unknown loss {name!r}; expected one of {', '.join(LOSSES)}")
    return name


def loss_rho(name: str, r: np.ndarray, c: float = 1.0) -> np.ndarray:
    """rho(r) for residuals ``r`` (same units as the scale ``c``)."""
    r = np.abs(np.asarray(r, dtype=np.float64))
    if name == "l2":
        return 0.5 * r * r
    if name == "l1":
        return r
    if name == "huber":
        return np.where(r <= c, 0.5 * r * r, c * (r - 0.5 * c))
    if name == "cauchy":
        return 0.5 * c * c * np.log1p((r / c) ** 2)
    if name == "geman_mcclure":
        return 0.5 * c * c * r * r / (c * c + r * r)
    if name == "half_norm":
        return 2.0 * np.sqrt(r)
    if name == "truncated_l2":
        m = np.minimum(r, c)
        return 0.5 * m * m
    raise OptionError(f"unknown loss {name!r}; expected one of {', '.join(LOSSES)}")


def loss_weight(name: str, r: np.ndarray, c: float = 1.0) -> np.ndarray:
    """IRLS weight rho'(r) / r."""
    return positive_loss_weight(name, np.abs(np.asarray(r, dtype=np.float64)), c)


def positive_loss_weight(name: str, r: np.ndarray, c: float = 1.0) -> np.ndarray:
    """:func:`loss_weight` of a float64 array ``r >= 0`` (no conversion: the IRLS loops)."""
    if name == "l2":
        return np.ones_like(r)
    if name == "l1":
        return 1.0 / r
    if name == "huber":
        return np.where(r <= c, 1.0, c / np.maximum(r, c))
    if name == "cauchy":
        return 1.0 / (1.0 + (r / c) ** 2)
    if name == "geman_mcclure":
        return c**4 / (c * c + r * r) ** 2
    if name == "half_norm":
        return r**-1.5
    if name == "truncated_l2":
        return (r < c).astype(np.float64)
    raise OptionError(f"unknown loss {name!r}; expected one of {', '.join(LOSSES)}")


def loss_curvature(name: str, r: np.ndarray, c: float = 1.0) -> np.ndarray:
    """rho''(r) of a float64 array ``r >= 0`` (Newton steps; at the kinks of ``huber`` and
    ``truncated_l2`` the side their weight takes: ``r <= c`` and ``r < c``)."""
    if name == "l2":
        return np.ones_like(r)
    if name == "l1":
        return np.zeros_like(r)
    if name == "huber":
        return (r <= c).astype(np.float64)
    if name == "truncated_l2":
        return (r < c).astype(np.float64)
    if name == "cauchy":
        t = (r / c) ** 2
        return (1.0 - t) / (1.0 + t) ** 2
    if name == "geman_mcclure":
        c2, r2 = c * c, r * r
        return c2 * c2 * (c2 - 3.0 * r2) / (c2 + r2) ** 3
    if name == "half_norm":
        return -0.5 * r**-1.5
    raise OptionError(f"unknown loss {name!r}; expected one of {', '.join(LOSSES)}")
