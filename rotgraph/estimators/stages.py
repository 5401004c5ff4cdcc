"""The stages that every multiple rotation averaging shares, around the ones that differ.

One pipeline, driven by :func:`.rotation_averaging.average_rotations`:

1. **prepare** (:func:`prepare`): the graph checked, its largest connected component (the
   cameras, edges and relative rotations solved), the log of the stages.
2. **solve**: a method's stages (start, L1, noise model, IRLS, refine: :mod:`.methods`, the
   table :data:`rotgraph.choices.METHOD_TABLE`) or, when the graph carries gravity priors
   (:attr:`~rotgraph.viewgraph.ViewGraph.gravity`), their gravity variant
   (:mod:`.gravity_solve`). Either hands a :class:`Solution` to the last stage.
3. **finish** (:func:`finish`): outlier marking (:func:`mark_outliers`), the cameras left
   out, the variant's cost and final edge weights, scatter-back from the component to the
   whole graph, the :class:`~.types.AveragingResult`.

Rig frames change the problem, not the stages: the frame graph
(:mod:`.rig_rotation_averaging`) goes through the same pipeline, with its frames' gravity
priors when the images have some.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Callable

import numpy as np

from ..errors import UnsolvableError
from ..viewgraph import ViewGraph
from .noise_model import standardised
from .types import AveragingResult, SolveOptions, scatter_to_graph

if TYPE_CHECKING:
    from .noise_model import NoiseModel

__all__ = ["OUTLIER_THRESHOLD_DEG", "Component", "Solution", "Marking", "prepare", "mark_outliers", "finish"]

logger = logging.getLogger(__name__)

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


def prepare(graph: ViewGraph) -> Component:
    """The first stage: ``graph`` checked (edges to solve), its largest connected component."""
    t0 = time.perf_counter()
    if graph.n_nodes == 0 or graph.n_edges == 0:
        raise UnsolvableError("the view graph has no edges")
    labels = graph.components()
    n_components = int(labels.max()) + 1
    sub, nodes, eidx = graph.largest_component(labels)
    if n_components > 1:
        logger.info("solving the largest of %d components: %d of %d cameras", n_components, sub.n_nodes, graph.n_nodes)
    return Component(graph, sub, nodes, eidx, n_components, sub.relative_quaternion_rows(), t0)


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


def mark_outliers(theta: np.ndarray, model, diagnostics: dict, opts: SolveOptions,
                  leverage: Callable[[], np.ndarray]) -> Marking:
    """Which edges are inliers at the residual sizes ``theta``: by the fitted model's posterior
    (the flags model the method left in ``diagnostics["flags"]``, popped: never left there) or
    by a threshold (``opts.outlier_threshold_deg``, else :data:`OUTLIER_THRESHOLD_DEG`)."""
    threshold = opts.outlier_threshold_deg
    flags_model = diagnostics.pop("flags", model)  # (a model object: never left in the diagnostics)
    if threshold is None and model is not None:
        # the model describes leverage-standardised residuals: each edge's own posterior
        flag_weights = flags_model.weights(standardised(theta, leverage()))
        threshold = float(np.degrees(flags_model.outlier_threshold()))
        diagnostics.update(model.describe(), outlier_threshold_deg=threshold)
        return Marking(flag_weights[1] >= 0.5, threshold, flag_weights, flags_model)
    threshold = OUTLIER_THRESHOLD_DEG if threshold is None else threshold
    return Marking(np.degrees(theta) <= threshold, threshold)


def _left_out(comp: Component, marks: Marking, robust: bool) -> np.ndarray:
    """(n,) bool: the cameras of the component left out, every edge of theirs an outlier
    (a robust variant's; they have no consensus behind their rotation: unsolved, the CLI's
    contract)."""
    n = comp.n
    if robust and n > 1:
        rejected = np.bincount(comp.edges[marks.inlier].ravel(), minlength=n) == 0
    else:  # no outlier rejection: every camera solved stays in the output
        rejected = np.zeros(n, dtype=bool)
    if rejected.all():
        raise UnsolvableError(f"every edge is an outlier (residual > {marks.threshold:g} deg): no camera can be trusted")
    if rejected.any():
        logger.info("%d camera(s) left out: every edge of theirs is an outlier", int(rejected.sum()))
    return rejected


def finish(comp: Component, sol: Solution, opts: SolveOptions) -> AveragingResult:
    """The last stage: outliers marked on the residual sizes the variant weighted
    (Mahalanobis norms with information matrices), cameras left out, the variant's cost and
    weights, and the result for every node and edge of the input graph (the residuals
    reported are angles)."""
    theta = sol.theta()
    marks = mark_outliers(theta, sol.model, sol.diagnostics, opts, sol.leverage)
    rejected = _left_out(comp, marks, sol.robust)
    cost, weights = sol.score(theta, marks)
    graph = comp.graph
    arrays = scatter_to_graph(graph.n_nodes, graph.n_edges, comp.nodes, comp.eidx, sol.rotations(), rejected,
                              sol.residuals_deg(),  # also the (outlier) edges of left-out cameras
                              marks.inlier, weights)
    seconds = time.perf_counter() - comp.t0
    logger.info("%s: %d cameras, %d edges, %d outliers, %d iterations, %.2f s", sol.method, comp.n, comp.sub.n_edges,
                int((~marks.inlier).sum()), sol.iterations, seconds)
    return AveragingResult(**arrays, iterations=sol.iterations, cost=cost, converged=sol.converged, method=sol.method,
                           anchor=int(comp.nodes[sol.anchor]), n_components=comp.n_components, seconds=seconds,
                           stages=comp.stages, outlier_threshold_deg=float(marks.threshold),
                           diagnostics=sol.diagnostics)
