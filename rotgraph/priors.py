"""Per-image priors a view graph may carry besides its edges: gravity directions
(:class:`GravityPriors`, :attr:`rotgraph.viewgraph.ViewGraph.gravity`).

A graph that carries them is solved with them by
:func:`~rotgraph.estimators.rotation_averaging.average_rotations` (the gravity variant of
its stages, :mod:`rotgraph.estimators.gravity_solve`), as a graph with
:attr:`~rotgraph.viewgraph.ViewGraph.rigs` is solved at the frame level.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .errors import OptionError

__all__ = ["GRAVITY_WORLD", "GravityPriors", "CheckedGravity"]

#: The world's "down" direction in COLMAP's convention (``RotationEstimatorOptions.gravity_dir``,
#: ``SyntheticDatasetOptions.prior_gravity_in_world``): a perfect prior is ``R_i @ GRAVITY_WORLD``.
GRAVITY_WORLD = np.array([0.0, 1.0, 0.0])


@dataclass
class CheckedGravity:
    """The priors as the solve uses them: ``direction`` (n, 3) unit vectors (NaN rows: none),
    ``has`` (n,) bool (a direction and a finite sigma), ``sigma`` (n,) radians (NaN: to
    estimate, and for images without a prior)."""

    direction: np.ndarray
    has: np.ndarray
    sigma: np.ndarray


@dataclass
class GravityPriors:
    """Per-image gravity priors (COLMAP's ``PosePrior.gravity``), checked when made.

    Parameters
    ----------
    direction : (n, 3) array_like
        Each image's gravity ("down") direction in its camera frame, ``g_i ~ R_i world``
        (``R_i`` cam_from_world; any length, normalised by the solve); NaN rows for images
        without one.
    sigma_deg : float, (n,) array_like or None, default None
        The noise of the priors in degrees per tilt axis: 0 exact (the tilt is held fixed),
        inf no prior, NaN or None estimated from the data (one value for all those images;
        given values win).
    world : (3,) array_like, default :data:`GRAVITY_WORLD`
        The world's down direction.

    Raises
    ------
    ValueError
        ``direction`` not (n, 3), a zero direction, or ``sigma_deg`` neither a scalar, None
        nor (n,).
    OptionError
        A negative ``sigma_deg`` for an image with a direction.
    """

    direction: np.ndarray
    sigma_deg: float | np.ndarray | None = None
    world: np.ndarray = field(default_factory=GRAVITY_WORLD.copy)

    def __post_init__(self):
        self.direction = np.asarray(self.direction, dtype=np.float64)
        self.world = np.asarray(self.world, dtype=np.float64)
        if self.sigma_deg is not None and np.ndim(self.sigma_deg):
            self.sigma_deg = np.asarray(self.sigma_deg, dtype=np.float64)
        self.checked()

    @property
    def n(self) -> int:
        return len(self.direction)

    def subset(self, nodes: np.ndarray) -> GravityPriors:
        """The priors of the images ``nodes`` (indices)."""
        sigma = self.sigma_deg[nodes] if isinstance(self.sigma_deg, np.ndarray) else self.sigma_deg
        return GravityPriors(self.direction[nodes], sigma, self.world)

    def checked(self) -> CheckedGravity:
        """The priors as the solve uses them (see :class:`CheckedGravity`): unit directions,
        which images have a prior, sigma in radians."""
        g = self.direction
        n = g.shape[0] if g.ndim else 0
        if g.ndim != 2 or g.shape[1] != 3:
            raise ValueError(f"gravity must be ({n}, 3) (NaN rows for images without gravity), got {g.shape}")
        has = np.isfinite(g).all(axis=1)
        norm = np.linalg.norm(np.where(has[:, None], g, 0.0), axis=1)
        if (has & ~(norm > 1e-12)).any():
            k = int(np.argmax(has & ~(norm > 1e-12)))
            raise ValueError(f"gravity of node {k} is the zero vector")
        g = np.where(has[:, None], g / np.where(has, norm, 1.0)[:, None], np.nan)
        s = np.full(n, np.nan) if self.sigma_deg is None else np.asarray(self.sigma_deg, dtype=np.float64)
        if s.ndim > 1 or (s.ndim == 1 and len(s) != n):
            raise ValueError(f"sigma_deg must be a scalar, None or ({n},) (NaN: estimate), got shape {s.shape}")
        s = np.broadcast_to(s, (n,)).copy()
        if (s[has] < 0).any():
            raise OptionError("sigma_deg must be >= 0 (inf: no prior; NaN or None: estimated) for every image with gravity")
        has &= ~np.isposinf(s)  # an infinite sigma is no prior
        return CheckedGravity(g, has, np.deg2rad(np.where(has, s, np.nan)))
