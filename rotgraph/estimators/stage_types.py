"""What the stages of a multiple rotation averaging hand each other (the pipeline itself:
:mod:`.stages`).

:class:`Component` is the problem a solve works on (the largest connected component, from
:func:`.stages.prepare`); :class:`Solution` what a variant of the solve stages (a method's
stages in :mod:`.stages`, the gravity variant in :mod:`.gravity_solve`) hands to
:func:`.stages.finish`; :class:`Marking` which edges that stage found inliers. Apart from the
pipeline so that its variants can build on these without importing the pipeline that runs
them.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ..viewgraph import ViewGraph

if TYPE_CHECKING:
    from .noise_model import NoiseModel

__all__ = ["OUTLIER_THRESHOLD_DEG", "Component", "Solution", "Marking"]

#: The outlier threshold of the robust stages without a fitted noise model (``irls``, ``l1``,
#: the gravity variant) when ``SolveOptions.outlier_threshold_deg`` is None.
OUTLIER_THRESHOLD_DEG = 10.0


@dataclass
class Component:
    """The problem a solve works on: the largest connected component ``sub`` of ``graph``
    (its cameras ``nodes`` and edges ``eidx`` in ``graph``; ``qrel`` its relative rotations
    as quaternion rows (4, E)), and the report of its stages."""

    graph: ViewGraph
    sub: ViewGraph
    nodes: np.ndarray
    eidx: np.ndarray
    n_components: int
    qrel: np.ndarray
    t0: float  # time.perf_counter() at the start of the solve
    stages: list = field(default_factory=list)

    @property
    def n(self) -> int:
        return self.sub.n_nodes

    @property
    def edges(self) -> np.ndarray:
        return self.sub.edges

    def mark(self, stage: str, iterations: int, converged: bool, start: str | None = None) -> None:
        """One stage done: its report in the result's ``stages`` (``start``: the adaptive
        method's stages from each of its starts)."""
        self.stages.append({"stage": stage, "iterations": iterations, "converged": converged,
                            "seconds": time.perf_counter() - self.t0, **({} if start is None else {"start": start})})


class Solution:
    """What a variant of the solve stages hands to :func:`finish`: the component's rotations
    and how the variant scores them. Attributes: ``method`` (the result's), ``anchor`` (the
    camera fixing the gauge, an index into the component), ``iterations``, ``converged``,
    ``robust`` (cameras whose every edge is an outlier are left out), ``model`` (a noise
    model fitted to leverage-standardised residuals, or None: outliers by a threshold),
    ``diagnostics`` (the result's)."""

    method: str
    anchor: int
    iterations: int
    converged: bool
    robust: bool
    model: NoiseModel | None = None
    diagnostics: dict

    def theta(self) -> np.ndarray:
        """(E,) the residual sizes (radians) outliers are told on and the cost measured on."""
        raise NotImplementedError

    def leverage(self) -> np.ndarray:
        """(E,) each edge's leverage (asked for only with a ``model``)."""
        raise NotImplementedError

    def rotations(self) -> np.ndarray:
        """(n, 3, 3) the component's ``cam_from_world``."""
        raise NotImplementedError

    def residuals_deg(self) -> np.ndarray:
        """(E,) the residual angles reported, degrees."""
        raise NotImplementedError

    def score(self, theta: np.ndarray, marks: Marking) -> tuple[float, np.ndarray]:
        """``(cost, edge weights (E,))``: the variant's final cost and each edge's weight in
        its final iteration."""
        raise NotImplementedError


@dataclass
class Marking:
    """Which edges are inliers (``inlier`` (E,) bool) and by what: ``threshold`` (degrees),
    and with a fitted model its posterior weights of the residuals (``flag_weights``) under
    the model that told them (``flags``; None: a threshold)."""

    inlier: np.ndarray
    threshold: float
    flag_weights: np.ndarray | None = None
    flags: NoiseModel | None = None


