"""The one pipeline of every multiple rotation averaging: named stages, with the ones that
differ as variants.

:func:`run` (called by :func:`.rotation_averaging.average_rotations`, and by the rig
calibration for its frame graphs):

1. **prepare** (:func:`prepare`): the graph checked, its largest connected component (the
   cameras, edges and relative rotations solved), the log of the stages.
2. **solve**: a method's stages (:func:`method_stages`: edge weights, spanning tree, start,
   then L1, noise model, IRLS as the method runs them (:mod:`.methods`, the table
   :data:`rotgraph.choices.METHOD_TABLE`), ``refine``) or, when the graph carries gravity
   priors (:attr:`~rotgraph.viewgraph.ViewGraph.gravity`), their gravity variant
   (:func:`gravity_stages`, :mod:`.gravity_solve`). Either hands a
   :class:`~.stage_types.Solution` to the last stage.
3. **finish** (:func:`finish`): outlier marking (:func:`mark_outliers`), the cameras left
   out, the variant's cost and final edge weights, scatter-back from the component to the
   whole graph, the :class:`~.types.AveragingResult`.

Rig frames change the problem, not the stages: the frame graph
(:mod:`.rig_rotation_averaging`) goes through this pipeline, with its frames' gravity
priors when the images have some, and the rig calibration (:mod:`.rig_calibration`) runs it
on each round's frame graph. The objects the stages hand each other are in
:mod:`.stage_types`.
"""

from __future__ import annotations

import logging
import time
from dataclasses import replace
from typing import Callable

import numpy as np

from .. import so3_rows
from ..choices import METHOD_BY_NAME
from ..errors import UnsolvableError
from ..losses import loss_rho
from ..viewgraph import ViewGraph
from .gravity_solve import GravitySolve
from .irls import loss_weights
from .methods import AveragingProblem, MethodResult, initial_guess_rotations, linear_rotations, method_function
from .leverage import mean_variance_precision, standardised
from .residuals import EdgeSystem
from .spanning_tree import spanning_tree_rotations
from .stage_types import OUTLIER_THRESHOLD_DEG, Component, Marking, Solution
from .stats import median
from .types import AveragingResult, Callback, SolveOptions, scatter_to_graph

__all__ = ["OUTLIER_THRESHOLD_DEG", "Component", "Solution", "Marking", "run", "prepare", "method_stages",
           "gravity_stages", "mark_outliers", "finish"]

logger = logging.getLogger(__name__)


def run(graph: ViewGraph, opts: SolveOptions, callback: Callback | None = None, full: bool = True,
        test_weights: bool = False, tested: bool = False) -> AveragingResult:
    """:func:`~.rotation_averaging.average_rotations` of one graph (image- or frame-level; its
    rigs not used) with validated options, as the stages of this module: prepare, a method's stages
    (:func:`method_stages`) or their gravity variant (:func:`gravity_stages`), finish.
    ``full=False``: the adaptive method's first stages only (see
    :func:`.adaptive.solve_adaptive`). ``test_weights``: the adaptive method tests whether the
    edges' weights (inlier counts, not used in the cost: ``use_weights`` off) predict the
    noise of the residuals (:func:`.noise_model.weight_exponent`, cross-validated); when they
    do, the problem is solved again from the answer with them as precisions
    (``diagnostics["weights"]``). With gravity priors the solve is always the full one, and
    tests no weights. ``tested``: the graph's information is what those tests found, and its
    initial rotations the answer they were found at (the solve again): the adaptive method's
    rough stages then weigh it as it is (:meth:`~.residuals.EdgeSystem.isotropic`)."""
    comp = prepare(graph)
    if graph.gravity is not None:
        priors = graph.gravity.checked()
        if priors.has[comp.nodes].any():
            return finish(comp, gravity_stages(comp, priors, graph.gravity.world, opts), opts)
        logger.info("no image of the solved component has a gravity prior: solving without gravity")
        full, test_weights = True, False
    out = method_stages(comp, opts, callback, full, test_weights, tested)
    res = out if isinstance(out, AveragingResult) else finish(comp, out, opts)
    if graph.gravity is not None:
        res.diagnostics["gravity"] = {"n_images": comp.n, "n_with_gravity": 0, "used": False,
                                      "reason": "no gravity prior in the solved component"}
    return res


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


def gravity_stages(comp: Component, priors, world, opts: SolveOptions) -> Solution:
    """The gravity variant of the solve stages (:mod:`.gravity_solve`): the images the 1-D
    stage does not reach start from this pipeline's own solve of the component without its
    priors, when their neighbours cannot start them."""
    s = GravitySolve(comp, priors, world, opts)
    s.yaw_stage()
    s.noise_estimate()
    if s.needs_refine:
        if not s.neighbour_start() and s.needs_start:
            s.unconstrained_start(run(comp.sub.with_gravity(None), opts, None))
        s.refine()
    return s.solution()


def method_stages(comp: Component, opts: SolveOptions, callback: Callback | None, full: bool,
                  test_weights: bool, tested: bool = False) -> Solution | AveragingResult:
    """The stages of ``opts.method`` on the component: the edge weights, the spanning tree
    (the anchor; the start), the iterative methods' init, the method's function
    (:mod:`.methods`), ``--refine``. A finished result instead when the method solved the
    problem again (the adaptive method's tests of its weights and information)."""
    graph, sub, n, edges, qrel = comp.graph, comp.sub, comp.n, comp.edges, comp.qrel
    w, w_mst, w_lin, info, info_scale, iso, diagnostics = _edge_weights(sub, opts)
    q, anchor, tree_edges = spanning_tree_rotations(n, edges, qrel, w_mst)
    comp.mark("spanning_tree", 0, True)
    spec = METHOD_BY_NAME[opts.method]
    solve_again = _solve_again(graph, sub, comp.nodes, opts, callback, full)
    problem = AveragingProblem(n, edges, qrel, anchor, q, EdgeSystem(n, edges, qrel, anchor, information=info,
                                                                      information_scale=info_scale), w, w_lin,
                               iso, sub.weights, opts, callback, comp.mark, full, solve_again if test_weights and full else None,
                               information_tested=tested)
    if spec.iterative and opts.init in ("chordal", "quaternion"):
        problem.q = linear_rotations(problem, opts.init)
    elif spec.iterative and opts.init == "vertices":
        problem.q = initial_guess_rotations(sub, qrel, tree_edges, anchor)
        comp.mark("vertices", 0, True)
    # The method's stages (rotgraph.estimators.methods); a single camera has nothing to iterate.
    out = method_function(opts.method)(problem) if n > 1 or not spec.iterative else MethodResult(problem.q)
    if out.result is not None:
        return out.result
    diagnostics.update(out.diagnostics)
    scale = problem.scale if out.scale is None else out.scale
    q, iterations = out.q, out.iterations
    if opts.refine and n > 1:
        q, it, conv = _refine_stage(q, problem, out.model, w_lin, out.loss, scale)
        iterations += it
        comp.mark("refine", it, conv)
    if out.scale is not None:  # a loss scale of the method's own (irls re-fits it)
        comp.stages[-1]["scale_deg"] = float(np.degrees(scale))
    return _MethodSolution(problem, q, out, scale, iterations, diagnostics, spec.robust)


class _MethodSolution(Solution):
    """A method's rotations ``q`` (quaternion rows) for the last stage: outliers and cost on
    the residual sizes the method weighted (Mahalanobis norms with information matrices), by
    its fitted noise model or its loss; the residuals reported are angles."""

    def __init__(self, problem: AveragingProblem, q, out: MethodResult, scale, iterations, diagnostics, robust):
        self.problem, self.q, self.loss, self.scale = problem, q, out.loss, scale
        self.method, self.anchor, self.iterations, self.converged = problem.opts.method, problem.anchor, iterations, out.converged
        self.robust, self.model, self.diagnostics = robust, out.model, diagnostics

    def theta(self) -> np.ndarray:
        return self.problem.system.angles(self.q)

    def leverage(self) -> np.ndarray:
        return self.problem.leverage

    def rotations(self) -> np.ndarray:
        return so3_rows.matrices_from_quaternion_rows(self.q)

    def residuals_deg(self) -> np.ndarray:
        return np.degrees(self.problem.system.rotation_angles(self.q))

    def score(self, theta, marks) -> tuple[float, np.ndarray]:
        """The negative log-likelihood of the residuals under the fitted model and its
        weights, or the method's loss and its weights (l2: 1); times each edge's isotropic
        precision with information matrices."""
        p, model = self.problem, self.model
        if model is not None:
            t = standardised(theta, p.leverage)
            cost = -model.log_likelihood(t)
            final = p.w * (marks.flag_weights if marks.flags is model else model.weights(t))[0]
        else:
            cost = float(p.w @ loss_rho(self.loss, theta, self.scale))
            final = loss_weights(p.w, self.loss, self.scale)(theta)
        return cost, final * (1.0 if p.iso is None else p.iso)


def _solve_again(graph: ViewGraph, sub: ViewGraph, nodes, opts, callback, full):
    """``solve_again(a, q, by="weights")`` of :class:`~.methods.AveragingProblem`: the problem
    of ``graph`` solved again from the rotations ``q`` of its component ``sub`` (``nodes``),
    each edge's information times ``(w_e / median w)^2a``, ``w`` its weight or (``by``
    ``"information"``) its mean-variance precision (:func:`.leverage.mean_variance_precision`)."""

    def solve_again(a: float, q_start: np.ndarray, by: str = "weights") -> AveragingResult:
        w_all, w_sub = ((graph.weights, sub.weights) if by == "weights"
                        else (mean_variance_precision(graph.information), mean_variance_precision(sub.information)))
        return run(_weighted_by(graph, nodes, q_start, a, w_all, w_sub, opts), replace(opts, init="vertices",
                        use_information=True), callback, full, test_weights=False, tested=True)

    return solve_again


def _weighted_by(graph: ViewGraph, nodes, q, a: float, weights, sub_weights, opts) -> ViewGraph:
    """``graph`` with each edge's information multiplied by ``(w_e / median w)^(2a)`` (``w``:
    ``weights`` of the graph's edges, the median over its solved component's ``sub_weights``;
    an isotropic information where the graph has none, or its own is not used) and the
    rotations ``q`` of its solved component (``nodes``) as the initial guess: the problem
    again, with the weights as the precisions they were found to be
    (:func:`.noise_model.weight_exponent`)."""
    from dataclasses import replace as dc_replace

    p = (weights / np.median(sub_weights)) ** (2.0 * a)
    base = graph.information if graph.information is not None and opts.use_information else np.broadcast_to(np.eye(3), (graph.n_edges, 3, 3))
    R = np.full((graph.n_nodes, 3, 3), np.nan)
    R[nodes] = so3_rows.matrices_from_quaternion_rows(q)
    return dc_replace(graph, information=base * p[:, None, None], initial_cam_from_world=R)


def _edge_weights(sub: ViewGraph, opts: SolveOptions):
    """The edge weights of a solve of ``sub``: ``(w, w_mst, w_lin, info, info_scale, iso,
    diagnostics)`` - the cost's scalar weights, the spanning tree's, the linear starts', the
    information matrices used (or None) and the factor that normalises them (applied in the
    solver's one copy of them, :class:`~.residuals.EdgeSystem`), their normalised isotropic
    parts and the diagnostics saying so.

    Per-edge information matrices are normalised to a median isotropic precision of 1: the
    Mahalanobis norms of the residuals are then angles for an edge of median precision,
    and every threshold and noise level stays in degrees. The stages without a 3x3
    weighting (spanning tree, linear starts, node-wise, refine) use each edge's isotropic
    part, trace(H)/3, as a weight."""
    w_mst = sub.weights
    w = sub.weights if opts.use_weights else np.ones(sub.n_edges)
    if opts.use_weights:
        w = w / median(w)
    info, iso, diagnostics = None, None, {}
    if sub.information is not None and opts.use_information:
        iso = np.trace(sub.information, axis1=1, axis2=2) / 3.0
        unit = median(iso)
        info, iso = sub.information, iso / unit
        w_mst, w_lin = w_mst * iso, w * iso
        diagnostics["information"] = {"used": True, "median_sigma_deg": float(np.degrees(1.0 / np.sqrt(unit)))}
    else:
        w_lin = w
        if sub.information is not None:
            diagnostics["information"] = {"used": False}
    return w, w_mst, w_lin, info, (1.0 if info is None else 1.0 / unit), iso, diagnostics


def _refine_stage(q, problem, model, w_lin, loss, scale):
    """``--refine``: Levenberg-Marquardt on the method's cost, a fitted model's weights held
    fixed (its L2 on the inliers). Returns ``(q, iterations, converged)``."""
    from .refine import refine_lm

    w_refine = w_lin
    if model is not None:
        w_refine = w_lin * model.weights(standardised(problem.system.angles(q), problem.leverage))[0]
    return refine_lm(q, problem.edges, problem.qrel, w_refine, problem.anchor, loss, scale)


