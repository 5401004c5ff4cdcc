"""The methods of multiple rotation averaging: one function each, registered by name.

:data:`rotgraph.choices.METHOD_TABLE` lists the methods, their properties (iterative,
robust, warm-started by a rig calibration) and their help, without numpy (the command line
builds ``--method`` from it). Here each name gets the function that runs its stages:
``f(problem) -> MethodResult``. The pipeline's method stages (:func:`.stages.method_stages`)
prepare the :class:`AveragingProblem` (the largest component, its weights, the edge system,
the anchor, the start of an iterative method: :func:`linear_rotations`,
:func:`initial_guess_rotations`), call the method's function, and make the result of what it
returns: the optional refinement, then the stages every solve shares
(:func:`.stages.finish`: outliers, residuals, cost).

Adding a method: an entry in :data:`~rotgraph.choices.METHOD_TABLE` and a function here
under :func:`register` (docs/algorithms.md, "Adding a method").
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING, Callable

import numpy as np

from .. import so3_checks, so3_rows
from ..choices import METHODS
from ..errors import InputError
from .adaptive import solve_adaptive
from .irls import refitted_scale, solve_irls
from .laplacian import make_laplacian
from .linear import solve_chordal, solve_quaternion
from .nodewise import solve_nodewise
from .leverage import fitted_residual_dofs, leverage, mean_variance_precision, standardised
from .noise_model import weight_exponent
from .residuals import EdgeSystem
from .types import Callback, SolveOptions

if TYPE_CHECKING:
    from ..viewgraph import ViewGraph
    from .noise_model import NoiseModel
    from .types import AveragingResult

__all__ = ["AveragingProblem", "MethodResult", "register", "method_function", "METHOD_FUNCTIONS", "linear_rotations",
           "initial_guess_rotations"]

logger = logging.getLogger(__name__)


@dataclass
class AveragingProblem:
    """The prepared problem a method solves: a connected graph of ``n`` cameras, anchored."""

    n: int
    edges: np.ndarray  # (E, 2) int64
    qrel: np.ndarray  # (4, E) relative rotations, quaternion rows
    anchor: int  # the camera held fixed (R = I)
    q: np.ndarray  # (4, n) the start: the spanning tree, or for an iterative method its init
    system: EdgeSystem  # edge errors and residual sizes (Mahalanobis norms with information)
    w: np.ndarray  # (E,) weights of the cost (1, or the weight column over its median)
    w_linear: np.ndarray  # (E,) w times each edge's isotropic precision: stages without 3x3 weighting
    iso: np.ndarray | None  # (E,) each edge's isotropic precision, None without information matrices
    weight_column: np.ndarray  # (E,) the edges' own weights (inlier counts), not normalised
    opts: SolveOptions
    callback: Callback | None  # callback(stage, iteration, median_step_rad)
    mark: Callable[..., None]  # mark(stage, iterations, converged, start=None): the result's stages
    full: bool = True  # False: the adaptive method's first stages only (a rig calibration's round 0)
    #: ``solve_again(a, q, by="weights")``: the problem solved again from rotations ``q`` with
    #: each edge's information times ``w^2a``, ``w`` its weight (or, ``by="information"``, its
    #: isotropic precision) over their median (the adaptive method's tests of its weights and
    #: information); None: no test.
    solve_again: Callable[..., AveragingResult] | None = None
    #: The information is what those tests found, at the start ``q`` (the solve again): the
    #: adaptive method's rough stages weigh it uncapped (:meth:`~.residuals.EdgeSystem.isotropic`).
    information_tested: bool = False

    @cached_property
    def laplacian(self):
        """The anchored graph Laplacian of the Gauss-Newton steps (3x3 blocks with information)."""
        return make_laplacian(self.n, self.edges, self.anchor, self.opts.linear_solver, self.iso is not None)

    @cached_property
    def leverage(self) -> np.ndarray:
        """Each edge's leverage in the graph of isotropic precisions (:func:`.leverage.leverage`)."""
        return leverage(self.n, self.edges, self.iso)

    @property
    def scale(self) -> float:
        """The loss scale of the options, radians."""
        return np.deg2rad(self.opts.loss_scale_deg)

    @property
    def tol(self) -> float:
        """The final step tolerance, radians."""
        return np.deg2rad(self.opts.step_tol_deg)

    @property
    def stage_tol(self) -> float:
        """The tolerance of intermediate stages (never below :attr:`tol`), radians."""
        return max(np.deg2rad(self.opts.stage_tol_deg), self.tol)


@dataclass
class MethodResult:
    """What a method returns."""

    q: np.ndarray  # (4, n) the rotations
    iterations: int = 0
    converged: bool = True
    loss: str = "l2"  # the cost minimised: the reported cost, the final weights, --refine's loss
    scale: float | None = None  # the loss scale it ended with (radians, reported); None: the option's
    model: NoiseModel | None = None  # a fitted noise model of leverage-standardised residuals
    diagnostics: dict = field(default_factory=dict)  # merged into the result's diagnostics
    result: AveragingResult | None = None  # a finished result that replaces this one (adaptive's second solve)


#: Method name -> the function that runs its stages.
METHOD_FUNCTIONS: dict[str, Callable[[AveragingProblem], MethodResult]] = {}


def register(name: str):
    """Decorator: the function of method ``name`` (an entry of :data:`~rotgraph.choices.METHOD_TABLE`)."""
    if name not in METHODS:
        raise ValueError(f"method {name!r} is not in rotgraph.choices.METHOD_TABLE")
    if name in METHOD_FUNCTIONS:
        raise ValueError(f"method {name!r} registered twice")

    def add(f):
        METHOD_FUNCTIONS[name] = f
        return f

    return add


def method_function(name: str) -> Callable[[AveragingProblem], MethodResult]:
    """The function of method ``name``."""
    return METHOD_FUNCTIONS[name]


def linear_rotations(p: AveragingProblem, which: str) -> np.ndarray:
    """The linear ``chordal`` or ``quaternion`` solution (the latter's signs fixed on the
    start ``p.q``), marked as a stage: a method of its own, or an iterative method's start."""
    if which == "chordal":
        q = solve_chordal(p.n, p.edges, p.qrel, p.w_linear, p.anchor, p.opts.linear_solver)
    else:
        q = solve_quaternion(p.n, p.edges, p.qrel, p.w_linear, p.anchor, p.q, p.opts.linear_solver)
    p.mark(which, 1, True)
    return q


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
    q[:, known] = so3_rows.quaternion_rows_from_matrices(so3_checks.project_to_so3(guess[known]))
    if not known.all():
        logger.info("init vertices: %d of %d camera(s) without an initial guess, chained along the spanning tree",
                    int((~known).sum()), n)
        a, b = graph.edges[tree_edges, 0], graph.edges[tree_edges, 1]
        qt = qrel[:, tree_edges]
        while not known.all():  # one tree level a round; the tree connects every camera
            fwd = known[a] & ~known[b]  # R_b = R_ab R_a
            back = known[b] & ~known[a]  # R_a = R_ab^T R_b
            dst = np.concatenate([b[fwd], a[back]])
            val = np.concatenate([so3_rows.qmul_rows(qt[:, fwd], q[:, a[fwd]]),
                                  so3_rows.qmul_rows(so3_rows.qconj_rows(qt[:, back]), q[:, b[back]])], axis=1)
            dst, first = np.unique(dst, return_index=True)
            q[:, dst] = val[:, first]
            known[dst] = True
    q = so3_rows.qmul_rows(q, so3_rows.qconj_rows(q[:, anchor].copy()))
    q /= np.sqrt((q * q).sum(axis=0))
    return so3_rows.positive_w_rows(q)


def _irls_stage(p: AveragingProblem, q, loss, scale, max_iterations, tol, stage, first_iteration=1):
    return solve_irls(q, p.edges, p.qrel, p.w, p.anchor, loss, scale, max_iterations, tol, stage=stage,
                      first_iteration=first_iteration, laplacian=p.laplacian, system=p.system, callback=p.callback)


# --------------------------------------------------------------------------- the methods


@register("adaptive")
def _adaptive(p: AveragingProblem) -> MethodResult:
    """:func:`.adaptive.solve_adaptive`; then, when asked (``p.solve_again``) and the edges
    carry weights not used in the cost (``use_weights`` off), whether they predict the noise
    of the residuals (:func:`.noise_model.weight_exponent`, cross-validated): when they do,
    the problem solved again from the answer with them as precisions (``diagnostics["weights"]``)."""
    q, iterations, converged, model, chosen = solve_adaptive(p.q, p.n, p.edges, p.qrel, p.w, p.anchor, p.system, p.laplacian,
                                                             p.leverage, p.opts, p.callback, p.mark, w_linear=p.w_linear,
                                                             full=p.full, cap_rough=not p.information_tested)
    out = MethodResult(q, iterations, converged, model=model, diagnostics=chosen)
    wc = p.weight_column
    test_information = p.solve_again is not None and p.iso is not None and np.ptp(p.iso) > 0
    test_weights = p.solve_again is not None and not p.opts.use_weights and np.ptp(wc) > 0 and wc.min() > 0
    if not (test_information or test_weights):
        return out
    t = standardised(p.system.angles(q), p.leverage)
    # Each residual counts its degrees of freedom in the final weighted fit: an edge the robust weights
    # let fit exactly (an L1 / heavy-t answer interpolates a spanning tree of edges, gross errors among
    # them) tells nothing about its noise. (Outliers are the tests' own model's business.)
    dofs = fitted_residual_dofs(p.n, p.edges, model.weights(t)[0] * p.w_linear)
    if test_information and _information_test(p, q, dofs, out):
        return out
    if test_weights:
        a, report = weight_exponent(t, wc, dofs, p.opts.seed)
        if a > 0:  # the weights predict the noise: solve again with them as precisions, from here
            out.result = p.solve_again(a, q)
            out.result.diagnostics["weights"] = dict(report, used=True)
            if "information_test" in out.diagnostics:  # (the first solve's, kept)
                out.result.diagnostics["information_test"] = out.diagnostics["information_test"]
            return out
        out.diagnostics["weights"] = dict(report, used=False)
    return out


#: Below this many residual degrees of freedom the information is not tested (taken as it is).
#: The test's threshold (:func:`_information_test`) and this floor were chosen on the even seeds
#: of random_problem draws (n 15-300, degree 4-8, spread 2-5, 0-5 % outliers, the information true
#: or each matrix scaled by a factor 1/10-10) as the smallest with no true information replaced;
#: benchmarks/README.md has the odd seeds' count.
INFORMATION_TEST_MIN_DOFS = 20.0
#: The exponent ``a`` of ``sigma_e ~ c_e^-a`` (``c_e = 3 / trace(H_e^-1)``, the inverse of an
#: edge's mean variance) at which the information is taken as it is.
INFORMATION_EXPONENT = 0.5


def _information_test(p: AveragingProblem, q, dofs: np.ndarray, out: MethodResult) -> bool:
    """Whether the edges' information predicts the noise as it says (issue #29 item 4: tested,
    not trusted): the exponent ``a`` of ``sigma_e = sigma (c_e / median c)^-a``, ``c_e = 3 /
    trace(H_e^-1)`` (:func:`mean_variance_precision`), that best
    predicts held-out *unwhitened* residuals (:func:`.noise_model.weight_exponent`; 0.5: the
    information as it is, 0: it says nothing of the noise's scale). Another exponent is taken
    only when it predicts better by more than the log of the residuals' degrees of freedom
    plus the log of the number of exponents tried (the best of them), and with at least
    :data:`INFORMATION_TEST_MIN_DOFS` degrees of freedom: the problem is then solved again
    from ``q`` with each edge's information times ``(c_e / median c)^(2a - 1)`` (True; its
    result in ``out.result``). ``dofs``: each residual's degrees of freedom in the final
    weighted fit. ``diagnostics["information_test"]`` says what was found."""
    t = standardised(p.system.rotation_angles(q), p.leverage)
    if dofs.sum() < INFORMATION_TEST_MIN_DOFS:
        out.diagnostics["information_test"] = {"used": False, "residual_dofs": float(dofs.sum()),
                                               "skipped": f"fewer than {INFORMATION_TEST_MIN_DOFS} residual degrees of freedom"}
        return False
    c = mean_variance_precision(p.system.scaled_information())
    a, report = weight_exponent(t, np.where(c > 0, c, np.median(c)), dofs, p.opts.seed, reference=INFORMATION_EXPONENT)
    # the log of the degrees of freedom, plus the log of the number of exponents tried (the best of
    # them is not one chance but that many)
    penalty = np.log(max(float(dofs.sum()), 2.0)) + np.log(len(report["exponents_tried"]))
    report = dict(report, penalty=float(penalty), used=bool(a != INFORMATION_EXPONENT and report["held_out_gain"] > penalty))
    if report["used"]:
        out.result = p.solve_again(a - INFORMATION_EXPONENT, q, "information")
        out.result.diagnostics["information_test"] = report
        return True
    out.diagnostics["information_test"] = report
    return False


@register("irls")
def _irls(p: AveragingProblem) -> MethodResult:
    """L1RA (``l1_iterations``), then IRLS with the robust loss; its scale re-fitted once to
    the residuals (``rescale``). The intermediate stages stop at ``stage_tol_deg``."""
    opts, loss, scale = p.opts, p.opts.loss, p.scale
    q, it, conv = _irls_stage(p, p.q, "l1", scale, opts.l1_iterations, p.stage_tol, "l1")
    iterations = it
    p.mark("l1", it, conv)
    q, it, conv = _irls_stage(p, q, loss, scale, opts.max_iterations, p.stage_tol if opts.rescale else p.tol, loss)
    iterations += it
    stage = loss
    if opts.rescale:
        # Fit the scale to the noise. Only a clear change is worth a new stage; otherwise the
        # first pass goes on to the final tolerance.
        new_scale = refitted_scale(p.system.angles(q))
        done = it
        if abs(new_scale - scale) > 0.2 * scale:
            p.mark(loss, it, conv)
            scale, stage, done = new_scale, loss + "_rescaled", 0
        q, it, conv = _irls_stage(p, q, loss, scale, opts.max_iterations - done, p.tol, stage, first_iteration=done + 1)
        iterations += it
        it += done
    p.mark(stage, it, conv)
    return MethodResult(q, iterations, conv, loss=loss, scale=scale)


@register("l1")
def _l1(p: AveragingProblem) -> MethodResult:
    """L1RA: the linearised L1 cost, by reweighting."""
    q, it, conv = _irls_stage(p, p.q, "l1", p.scale, p.opts.max_iterations, p.tol, "l1")
    p.mark("l1", it, conv)
    return MethodResult(q, it, conv, loss="l1")


@register("l2")
def _l2(p: AveragingProblem) -> MethodResult:
    """Lie-algebraic L2: Gauss-Newton steps on the linearised geodesic cost."""
    q, it, conv = _irls_stage(p, p.q, "l2", p.scale, p.opts.max_iterations, p.tol, "l2")
    p.mark("l2", it, conv)
    return MethodResult(q, it, conv)


@register("chordal")
def _chordal(p: AveragingProblem) -> MethodResult:
    return MethodResult(linear_rotations(p, "chordal"))


@register("quaternion")
def _quaternion(p: AveragingProblem) -> MethodResult:
    return MethodResult(linear_rotations(p, "quaternion"))


@register("nodewise")
def _nodewise(p: AveragingProblem) -> MethodResult:
    q, it, conv = solve_nodewise(p.q, p.edges, p.qrel, p.w_linear, p.anchor, p.opts.nodewise_norm, p.opts.max_iterations,
                                 p.tol, p.callback)
    p.mark("nodewise", it, conv)
    return MethodResult(q, it, conv)


@register("spanning_tree")
def _spanning_tree(p: AveragingProblem) -> MethodResult:
    return MethodResult(p.q)


_missing = [m for m in METHODS if m not in METHOD_FUNCTIONS]
if _missing:
    raise ImportError(f"no function registered for the method(s) {', '.join(_missing)} of rotgraph.choices.METHOD_TABLE")
