"""Multiple rotation averaging (Hartley et al. 2013, section 7).

Given relative rotations ``R_ij`` on the edges of a view graph, find absolute rotations
``R_i`` (cam_from_world) with ``R_j ~ R_ij R_i``, minimising ``sum_ij w_ij rho(d(R_ij, R_j R_i^T))``.

The solvers work on plain arrays: ``n`` nodes, ``edges`` (E, 2) int64, relative rotations
as quaternion rows ``qrel`` (4, E), weights (E,). Absolute rotations are quaternion rows
(4, n) during the iterations (contiguous rows: fast elementwise work over 10^6 edges).

Methods
-------
``spanning_tree``  maximum spanning tree on the edge weights, rotations chained from the
                   highest-degree node (pointer jumping: O(n log depth), no recursion).
``chordal``        linear chordal averaging (Martinec & Pajdla 2007): sparse least
                   squares for the 3x3 blocks, one anchored, then projection onto SO(3).
``quaternion``     linear quaternion averaging (Govindu 2001): q_j = q_ij q_i with the
                   signs fixed on the spanning-tree estimate, sparse least squares.
``l2``             Lie-algebraic L2 averaging (Govindu 2004): Gauss-Newton steps on the
                   linearised geodesic cost; each step one weighted graph-Laplacian solve
                   (n x n, three right-hand sides), not a 3n x 3n system.
``l1``             L1RA (Chatterjee & Govindu 2013): the same linearisation with an L1 cost,
                   solved by reweighting.
``irls``           L1RA followed by IRLS with a robust loss (weights rho'(r)/r),
                   the pipeline of GLOMAP and Theia.
``adaptive``       (default) weights from the noise and outliers estimated in the data
                   (:mod:`.adaptive`).
``nodewise``       node-wise averaging (paper section 7.4; Hartley et al. 2011): Gauss-Seidel
                   sweeps over a greedy colouring of the graph, each node set to the single
                   L1 (Weiszfeld step) or L2 mean of its neighbours' predictions R_ij R_i.

The table of methods, their properties and help is :data:`rotgraph.choices.METHOD_TABLE`;
each method's stages are a function in :mod:`.methods`, which this module's driver calls on
the prepared problem (largest component, weights, edge system, anchor, start). The driver is
one pipeline of stages (:mod:`.stages`): prepare, the method's stages or, for a graph with
gravity priors, their gravity variant (:mod:`.gravity_solve`), finish.

Initialisation (``init``) of the iterative methods (``adaptive``, ``irls``, ``l1``, ``l2``, ``nodewise``):
``mst`` the spanning tree, ``chordal``/``quaternion`` the linear solutions, ``vertices``
the input's own initial guess (:attr:`~rotgraph.viewgraph.ViewGraph.initial_cam_from_world`,
g2o vertices), see :func:`initial_guess_rotations`.

Linearisation: with ``R_i <- R_i exp(w_i)`` the edge error ``E_ij = R_j^T R_ij R_i``
becomes ``~ exp(log E_ij + w_i - w_j)``, so one step solves
``min sum u_ij |w_j - w_i - log E_ij|^2`` with node ``anchor`` fixed.
"""


from __future__ import annotations

import logging
import time
from dataclasses import replace

import numpy as np

from .. import so3
from ..errors import InputError, OptionError
from ..choices import ITERATIVE_METHODS, METHOD_BY_NAME
from ..losses import loss_rho
from ..options import resolve_options
from ..viewgraph import ViewGraph
from .gravity_solve import GravitySolve
from .laplacian import one_blas_thread
from .methods import AveragingProblem, MethodResult, linear_rotations, method_function
from .residuals import EdgeSystem
from .rig_calibration import needs_calibration, solve_rig
from .rig_rotation_averaging import frame_problem
from .spanning_tree import spanning_tree_rotations
from .irls import loss_weights, solve_irls
from .stages import Component, Solution, finish, prepare
from .stats import median
from .noise_model import mean_variance_precision, standardised
from .linear import solve_chordal, solve_quaternion
from .nodewise import solve_nodewise
from .types import INITS, METHODS, AveragingResult, Callback, SolveOptions

__all__ = [
    "SolveOptions",
    "AveragingResult",
    "average_rotations",
    "METHODS",
    "INITS",
    "solve_irls",
    "solve_chordal",
    "solve_quaternion",
    "solve_nodewise",
    "initial_guess_rotations",
]

logger = logging.getLogger(__name__)


# --------------------------------------------------------------------------- initial guess


def initial_guess_rotations(graph: ViewGraph, qrel: np.ndarray, tree_edges: np.ndarray, anchor: int) -> np.ndarray:
    """The start of ``init="vertices"``: ``graph.initial_cam_from_world`` as quaternion rows
    (4, n), in the gauge of the solvers (``R_anchor = I``: every rotation times
    ``R_anchor^T`` on the right, which changes no relative rotation).

    Cameras without a guess (NaN rows, e.g. a g2o edge to a vertex the file does not
    define) are chained along the spanning tree (``tree_edges``, indices into
    ``graph.edges``; ``qrel`` the edges' quaternion rows) from their nearest neighbour in
    the tree that has one: ``R_j = R_ij R_i``. Raises :class:`InputError` when the graph
    carries no initial guess, or none for a camera of ``graph`` (the solved component).

    Measured (default irls, 2-core machine under load, median of 7): parking-garage.g2o
    (1661 cameras) reaches the same optimum from every start (cost 6.46e-4, 5 iterations
    from the vertices as from the spanning tree; 19 vs 15 ms, this function 3 ms). On
    cubicle.g2o (5750 cameras, parallel edges kept) the vertices start from a worse place
    (1535 edges > 10 deg vs 296 for the tree: odometry drifts) yet end at a lower cost,
    0.244697 vs 0.246019, with 9 outlier edges instead of 11 (2 cameras 41.6 deg apart;
    the chordal start gives the same solution), in 22 iterations as from the tree (0.93 vs
    0.82 s; chordal 1.24 s). So: ``mst`` stays the default; ``vertices`` is the cheap way
    to start near the pose graph's own estimate.
    """
    guess = graph.initial_cam_from_world
    n = graph.n_nodes
    if guess is None:
        raise InputError("init 'vertices' (--init vertices): the input has no initial guess "
                         "(g2o VERTEX_SE3:QUAT lines give one; choose another --init)", path=graph.source_path)
    guess = np.asarray(guess, dtype=np.float64)
    if guess.shape != (n, 3, 3):
        raise ValueError(f"initial_cam_from_world must be ({n}, 3, 3), got {guess.shape}")
    known = np.isfinite(guess).all(axis=(1, 2))
    if not known.any():
        raise InputError("init 'vertices' (--init vertices): no camera of the solved component has an initial guess",
                         path=graph.source_path)
    q = np.zeros((4, n))
    q[:, known] = so3.quaternion_rows_from_matrices(so3.project_to_so3(guess[known]))
    if not known.all():
        logger.info("init vertices: %d of %d camera(s) without an initial guess, chained along the spanning tree",
                    int((~known).sum()), n)
        a, b = graph.edges[tree_edges, 0], graph.edges[tree_edges, 1]
        qt = qrel[:, tree_edges]
        while not known.all():  # one tree level a round; the tree connects every camera
            fwd = known[a] & ~known[b]  # R_b = R_ab R_a
            back = known[b] & ~known[a]  # R_a = R_ab^T R_b
            dst = np.concatenate([b[fwd], a[back]])
            val = np.concatenate([so3.qmul_rows(qt[:, fwd], q[:, a[fwd]]),
                                  so3.qmul_rows(so3.qconj_rows(qt[:, back]), q[:, b[back]])], axis=1)
            dst, first = np.unique(dst, return_index=True)
            q[:, dst] = val[:, first]
            known[dst] = True
    q = so3.qmul_rows(q, so3.qconj_rows(q[:, anchor].copy()))
    q /= np.sqrt((q * q).sum(axis=0))
    return so3.positive_w_rows(q)


# --------------------------------------------------------------------------- driver


@one_blas_thread
def average_rotations(
    graph: ViewGraph, options: SolveOptions | None = None, callback: Callback | None = None, *, gravity=None,
    gravity_sigma_deg=None, **overrides
) -> AveragingResult:
    """Solve multiple rotation averaging on the largest connected component of ``graph``.

    ``options`` (or keyword overrides of its fields) choose the method; see
    :class:`SolveOptions`. Cameras outside the largest component are reported unsolved.
    A graph with :attr:`~rotgraph.viewgraph.ViewGraph.rigs` is solved at the frame level
    (``options.rig_aware``; see :mod:`.rig_rotation_averaging`), its unknown extrinsics
    estimated with the frames (:mod:`.rig_calibration`): the result is per image, with the
    frame-level solve in ``result.frames`` and the extrinsics in ``result.sensors``.
    A graph with gravity priors (:attr:`~rotgraph.viewgraph.ViewGraph.gravity`, or the
    ``gravity`` and ``gravity_sigma_deg`` keywords) is solved by the gravity variant of the
    stages (:mod:`.gravity`; with rigs at the frame level, each frame's gravity from its
    images'). The stages: :mod:`.stages`.

    Parameters
    ----------
    graph : ViewGraph
        The view graph: ``n`` cameras, ``E`` edges; edge ``(i, j)`` carries
        ``R_ij = R_j R_i^T`` (``graph.cam2_from_cam1``, (E, 3, 3)).
    options : SolveOptions, optional
        The solver options; default ``SolveOptions()``.
    callback : callable, optional
        Progress of the iterations: ``callback(stage, iteration, median_step_rad)``.
    gravity : (n, 3) array_like, optional
        Per-image gravity direction in the camera frame (``g_i ~ R_i (0, 1, 0)``), NaN rows
        for images without one: ``graph.with_gravity(gravity, gravity_sigma_deg)`` solved
        (in place of the graph's own priors).
    gravity_sigma_deg : float or (n,) array_like, optional
        Noise of the gravity priors in degrees per tilt axis (0: exact, inf: no prior; NaN or
        None: estimated from the data).
    **overrides
        Fields of :class:`SolveOptions` that replace those of ``options``.

    Returns
    -------
    AveragingResult
        ``cam_from_world`` (n, 3, 3) float64 (world-to-camera, NaN rows for unsolved
        cameras), per-edge ``residuals_deg`` and ``inliers``, and the solve's report.

    Raises
    ------
    OptionError
        A bad option value (also a ``ValueError``).
    InputError
        Bad input (e.g. ``init="vertices"`` on a graph without an initial guess).
    ValueError
        Gravity priors of the wrong shape, or a zero gravity direction.
    UnsolvableError
        The problem cannot be solved as asked.
    """
    opts = resolve_options(SolveOptions, options, overrides)
    if gravity is not None:
        graph = graph.with_gravity(gravity, gravity_sigma_deg)
    if graph.rigs is not None and opts.rig_aware and graph.n_edges:
        t0 = time.perf_counter()
        calibrate = needs_calibration(graph, opts)
        problem = None if calibrate else frame_problem(graph)  # (with the frames' gravity priors)
        if calibrate or problem is not None:
            if opts.init == "vertices" and opts.method in ITERATIVE_METHODS:
                raise OptionError("init 'vertices' is not available for a rig-aware solve (graph.rigs): "
                                 "give rig_aware=False or another init")
            if calibrate:  # extrinsics to estimate or refine: estimators/rig_calibration.py
                return solve_rig(graph, opts, _average, callback)
            return problem.image_result(_average(problem.frame_graph, opts, callback), time.perf_counter() - t0)
    return _average(graph, opts, callback, test_weights=True)


def _solve_again(graph: ViewGraph, sub: ViewGraph, nodes, opts, callback, full):
    """``solve_again(a, q, by="weights")`` of :class:`~.methods.AveragingProblem`: the problem
    of ``graph`` solved again from the rotations ``q`` of its component ``sub`` (``nodes``),
    each edge's information times ``(w_e / median w)^2a``, ``w`` its weight or (``by``
    ``"information"``) its mean-variance precision (:func:`.noise_model.mean_variance_precision`)."""

    def solve_again(a: float, q_start: np.ndarray, by: str = "weights") -> AveragingResult:
        w_all, w_sub = ((graph.weights, sub.weights) if by == "weights"
                        else (mean_variance_precision(graph.information), mean_variance_precision(sub.information)))
        return _average(_weighted_by(graph, nodes, q_start, a, w_all, w_sub, opts), replace(opts, init="vertices",
                        use_information=True), callback, full, test_weights=False)

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
    R[nodes] = so3.matrices_from_quaternion_rows(q)
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


def _average(graph: ViewGraph, opts: SolveOptions, callback: Callback | None, full: bool = True,
             test_weights: bool = False) -> AveragingResult:
    """:func:`average_rotations` of one graph (image- or frame-level; its rigs not used) with
    validated options, as the stages of :mod:`.stages`: prepare, a method's stages
    (:func:`_method_stages`) or their gravity variant (:func:`_gravity_stages`), finish.
    ``full=False``: the adaptive method's first stages only (see
    :func:`.adaptive.solve_adaptive`). ``test_weights``: the adaptive method tests whether the
    edges' weights (inlier counts, not used in the cost: ``use_weights`` off) predict the
    noise of the residuals (:func:`.noise_model.weight_exponent`, cross-validated); when they
    do, the problem is solved again from the answer with them as precisions
    (``diagnostics["weights"]``). With gravity priors the solve is always the full one, and
    tests no weights."""
    comp = prepare(graph)
    if graph.gravity is not None:
        priors = graph.gravity.checked()
        if priors.has[comp.nodes].any():
            return finish(comp, _gravity_stages(comp, priors, graph.gravity.world, opts), opts)
        logger.info("no image of the solved component has a gravity prior: solving without gravity")
        full, test_weights = True, False
    out = _method_stages(comp, opts, callback, full, test_weights)
    res = out if isinstance(out, AveragingResult) else finish(comp, out, opts)
    if graph.gravity is not None:
        res.diagnostics["gravity"] = {"n_images": comp.n, "n_with_gravity": 0, "used": False,
                                      "reason": "no gravity prior in the solved component"}
    return res


def _gravity_stages(comp: Component, priors, world, opts: SolveOptions) -> Solution:
    """The gravity variant of the solve stages (:mod:`.gravity_solve`): the images the 1-D
    stage does not reach start from this pipeline's own solve of the component without its
    priors, when their neighbours cannot start them."""
    s = GravitySolve(comp, priors, world, opts)
    s.yaw_stage()
    s.noise_estimate()
    if s.needs_refine:
        if not s.neighbour_start() and s.needs_start:
            s.unconstrained_start(_average(comp.sub.with_gravity(None), opts, None))
        s.refine()
    return s.solution()


def _method_stages(comp: Component, opts: SolveOptions, callback: Callback | None, full: bool,
                   test_weights: bool) -> Solution | AveragingResult:
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
                               iso, sub.weights, opts, callback, comp.mark, full, solve_again if test_weights and full else None)
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
        return so3.matrices_from_quaternion_rows(self.q)

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
