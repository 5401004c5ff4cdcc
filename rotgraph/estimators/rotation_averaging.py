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
each method's stages are a function in :mod:`.methods`, which the pipeline calls on
the prepared problem (largest component, weights, edge system, anchor, start). The solve is
one pipeline of stages (:func:`.stages.run`): prepare, the method's stages or, for a graph
with gravity priors, their gravity variant (:mod:`.gravity_solve`), finish; a graph with rigs
goes through it at the frame level (:mod:`.rig_rotation_averaging`, :mod:`.rig_calibration`).

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

from ..choices import ITERATIVE_METHODS
from ..errors import OptionError
from ..options import resolve_options
from ..viewgraph import ViewGraph
from .irls import solve_irls
from .laplacian import one_blas_thread
from .linear import solve_chordal, solve_quaternion
from .methods import initial_guess_rotations
from .nodewise import solve_nodewise
from .rig_calibration import needs_calibration, solve_rig
from .rig_rotation_averaging import frame_problem
from .spanning_tree import spanning_tree_rotations  # noqa: F401 (imported from here by benchmarks)
from .stages import run
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
                return solve_rig(graph, opts, callback)
            return problem.image_result(run(problem.frame_graph, opts, callback), time.perf_counter() - t0)
    return run(graph, opts, callback, test_weights=True)
