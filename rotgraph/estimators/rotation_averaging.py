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
``irls``           (default) L1RA followed by IRLS with a robust loss (weights rho'(r)/r),
                   the pipeline of GLOMAP and Theia.
``nodewise``       node-wise averaging (paper section 7.4; Hartley et al. 2011): Gauss-Seidel
                   sweeps over a greedy colouring of the graph, each node set to the single
                   L1 (Weiszfeld step) or L2 mean of its neighbours' predictions R_ij R_i.

Initialisation (``init``) of the iterative methods (``irls``, ``l1``, ``l2``, ``nodewise``):
``mst`` the spanning tree, ``chordal``/``quaternion`` the linear solutions, ``vertices``
the input's own initial guess (:attr:`~rotgraph.viewgraph.ViewGraph.initial_cam_from_world`,
g2o vertices), see :func:`initial_guess_rotations`.

Linearisation: with ``R_i <- R_i exp(w_i)`` the edge error ``E_ij = R_j^T R_ij R_i``
becomes ``~ exp(log E_ij + w_i - w_j)``, so one step solves
``min sum u_ij |w_j - w_i - log E_ij|^2`` with node ``anchor`` fixed.
"""


from __future__ import annotations

import contextlib
import logging
import time
from dataclasses import replace

import numpy as np

from .. import so3
from ..errors import InputError, UnsolvableError
from ..losses import loss_rho, positive_loss_weight
from ..viewgraph import ViewGraph
from .laplacian import DENSE_MAX, AnchoredLaplacian, block_pcg, single_threaded_blas
from .residuals import EdgeSystem, _unit
from .rig_rotation_averaging import frame_problem
from .spanning_tree import spanning_tree_rotations
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


# IRLS weights 1/r of the L1 stage are capped at 1/L1_FLOOR (radians): below it the cost
# is quadratic (a Huber-like smoothing that keeps the Laplacian well conditioned).
L1_FLOOR = 1e-3
# The re-fitted loss scale never drops below this (noise-free data have zero residuals).
MIN_SCALE_DEG = 2.0


def _percentile(x: np.ndarray, p: float) -> float:
    """``np.percentile(x, p)`` (linear interpolation) of a finite 1-D array, by a partition."""
    pos = (len(x) - 1) * p / 100.0
    k = int(pos)
    if k + 1 >= len(x):
        return float(np.partition(x, k)[k])
    lo, hi = np.partition(x, [k, k + 1])[k : k + 2]
    return float(lo + (pos - k) * (hi - lo))


def _median(x: np.ndarray) -> float:
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


# --------------------------------------------------------------------------- IRLS family


def solve_irls(
    q0: np.ndarray,
    edges: np.ndarray,
    qrel: np.ndarray,
    weights: np.ndarray,
    anchor: int,
    loss: str,
    scale: float,
    max_iterations: int,
    step_tol: float,
    solver: str = "auto",
    laplacian: AnchoredLaplacian | None = None,
    callback: Callback | None = None,
    stage: str = "irls",
    system: EdgeSystem | None = None,
    first_iteration: int = 1,
) -> tuple[np.ndarray, int, bool]:
    """Iteratively reweighted Lie-algebraic averaging from ``q0`` (4, n).

    Each iteration: residuals ``r_ij = log(R_j^T R_ij R_i)``, weights
    ``u_ij = w_ij rho'(|r_ij|)/|r_ij|``, one anchored Laplacian solve for the update
    ``w``, ``R_i <- R_i exp(w_i)``. ``loss="l2"`` is Govindu's L2 averaging, ``"l1"``
    L1RA. Returns ``(q, iterations, converged)``. (``laplacian`` and ``system``: the
    per-graph structures, when the caller runs several stages on one graph;
    ``first_iteration``: the callback's count when a stage goes on.)
    """
    n = q0.shape[1]
    lap = laplacian or AnchoredLaplacian(n, edges, anchor, solver)
    system = system or EdgeSystem(n, edges, qrel, anchor)
    q = _unit(q0)
    floor = L1_FLOOR if loss in ("l1", "half_norm") else 1e-12
    for it in range(1, max_iterations + 1):
        v, f, t = system.errors(q)
        u = weights * positive_loss_weight(loss, np.maximum(2.0 * t, floor), scale)
        umax = u.max()
        if not umax > 0:
            raise UnsolvableError("every edge has zero weight under the robust loss")
        # Nodes whose edges all got zero (or vanishing) weight would make L singular: keep
        # a tiny weight.
        u = np.maximum(u, 1e-12 * umax)
        # The residual is 2 f v: this right-hand side gives half the update.
        x = lap.solve(u, system.rhs(v * (f * u)))
        q, h = system.update(q, x)
        # Median step: a few cameras whose edges all lost their weight can drift slowly
        # without changing anything else; they must not keep the iteration going.
        step = 2.0 * _median(h)
        if callback is not None:
            callback(stage, it + first_iteration - 1, step)
        logger.debug("%s iteration %d: median step %.3g rad", stage, it + first_iteration - 1, step)
        if step < step_tol:
            return q, it, True
    return q, max_iterations, False


# --------------------------------------------------------------------------- linear


def _block_system(n: int, edges: np.ndarray, blocks: np.ndarray, weights: np.ndarray, k: int):
    """Normal matrix of ``sum w |x_j - B_e x_i|^2`` over k-vectors x: blocks (E, k, k)."""
    i, j = edges[:, 0], edges[:, 1]
    a, b = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
    a, b = a.ravel(), b.ravel()
    # Off-diagonal blocks: M_ji = -w B, M_ij = -w B^T.
    rows_ji = (k * j[:, None] + a[None]).ravel()
    cols_ji = (k * i[:, None] + b[None]).ravel()
    vals = (-weights[:, None, None] * blocks).reshape(len(edges), -1).ravel()
    deg = np.bincount(i, weights=weights, minlength=n) + np.bincount(j, weights=weights, minlength=n)
    diag = np.repeat(deg, k)
    rows = np.concatenate([rows_ji, cols_ji, np.arange(k * n)])
    cols = np.concatenate([cols_ji, rows_ji, np.arange(k * n)])
    data = np.concatenate([vals, vals, diag])
    import scipy.sparse as sp

    return sp.coo_matrix((data, (rows, cols)), shape=(k * n, k * n)).tocsr()


def _anchored_solve(M, k: int, anchor: int, x_anchor: np.ndarray, solver: str = "auto") -> np.ndarray:
    """Minimise the quadratic form of ``M`` with the anchor's k-block fixed to x_anchor (k, c)."""
    N = M.shape[0]
    free = np.ones(N, dtype=bool)
    free[k * anchor : k * anchor + k] = False
    Mff = M[free][:, free]
    rhs = -np.asarray(M[free][:, ~free] @ x_anchor)
    if solver == "auto":
        solver = "direct" if M.nnz / N < 12 * k or N < 300 * k else "cg"
    if solver == "direct":
        import scipy.sparse.linalg as spla

        xf = spla.splu(Mff.tocsc(), permc_spec="MMD_AT_PLUS_A").solve(rhs)
    else:
        xf = block_pcg(Mff.tocsr(), rhs)[0]
    X = np.zeros((N, x_anchor.shape[1]))
    X[free] = xf
    X[~free] = x_anchor
    return X


def solve_chordal(n: int, edges: np.ndarray, qrel: np.ndarray, weights: np.ndarray, anchor: int, solver: str = "auto") -> np.ndarray:
    """Linear chordal averaging (Martinec & Pajdla): ``min sum w |R_j - R_ij R_i|_F^2`` with
    ``R_anchor = I`` over unconstrained 3x3 blocks, then each block projected onto SO(3)."""
    Rrel = so3.matrices_from_quaternion_rows(qrel)
    M = _block_system(n, edges, Rrel, weights, 3)
    X = _anchored_solve(M, 3, anchor, np.eye(3), solver)
    R = so3.project_to_so3(X.reshape(n, 3, 3))
    return so3.quaternion_rows_from_matrices(R)


def solve_quaternion(
    n: int, edges: np.ndarray, qrel: np.ndarray, weights: np.ndarray, anchor: int, q_ref: np.ndarray, solver: str = "auto"
) -> np.ndarray:
    """Linear quaternion averaging (Govindu 2001): ``min sum w |q_j - s_ij q_ij q_i|^2`` with
    ``q_anchor`` fixed, the signs ``s_ij`` chosen to agree with the estimate ``q_ref``."""
    pred = so3.qmul_rows(qrel, q_ref[:, edges[:, 0]])
    s = np.where((pred * q_ref[:, edges[:, 1]]).sum(axis=0) < 0, -1.0, 1.0)
    Lq = so3.quaternion_left_matrices((qrel * s).T)  # q * p = L(q) p
    M = _block_system(n, edges, Lq, weights, 4)
    X = _anchored_solve(M, 4, anchor, q_ref[:, anchor : anchor + 1], solver)
    Q = X.reshape(n, 4).T
    Q /= np.sqrt((Q * Q).sum(axis=0))
    return Q * np.where(Q[0] < 0, -1.0, 1.0)


# --------------------------------------------------------------------------- node-wise


def _greedy_colouring(n: int, edges: np.ndarray) -> list[np.ndarray]:
    """Independent sets covering the nodes (largest-first greedy colouring)."""
    import networkx as nx

    G = nx.Graph()
    G.add_nodes_from(range(n))
    G.add_edges_from(map(tuple, edges.tolist()))
    colour = nx.greedy_color(G, strategy="largest_first")
    c = np.array([colour[k] for k in range(n)])
    return [np.flatnonzero(c == k) for k in range(c.max() + 1)]


def solve_nodewise(
    q0: np.ndarray,
    edges: np.ndarray,
    qrel: np.ndarray,
    weights: np.ndarray,
    anchor: int,
    norm: str,
    max_iterations: int,
    step_tol: float,
    callback: Callback | None = None,
) -> tuple[np.ndarray, int, bool]:
    """Node-wise averaging: Gauss-Seidel sweeps, colour class by colour class, each node
    moved to the geodesic L2 mean (one Karcher step) or L1 median (one Weiszfeld step) of its
    neighbours' predictions ``R_ij R_i`` (and ``R_ij^T R_j``). The anchor stays fixed."""
    n = q0.shape[1]
    q = q0.copy()
    classes = [c[c != anchor] for c in _greedy_colouring(n, edges)]
    # Every edge seen from both ends: (node, neighbour, rotation neighbour -> node).
    node = np.concatenate([edges[:, 1], edges[:, 0]])
    nbr = np.concatenate([edges[:, 0], edges[:, 1]])
    rot = np.concatenate([qrel, so3.qconj_rows(qrel)], axis=1)
    w2 = np.concatenate([weights, weights])
    in_class = np.zeros(n, dtype=np.int64)
    for k, c in enumerate(classes):
        in_class[c] = k
    by_class = [np.flatnonzero((in_class[node] == k) & (node != anchor)) for k in range(len(classes))]
    for it in range(1, max_iterations + 1):
        total = 0.0
        for idx in by_class:
            if len(idx) == 0:
                continue
            a, b = node[idx], nbr[idx]
            pred = so3.qmul_rows(rot[:, idx], q[:, b])  # prediction of R_a
            v, theta = so3.qlog_rows(so3.qmul_rows(so3.qconj_rows(q[:, a]), pred))
            nodes = np.unique(a)
            if norm == "l2":
                u = w2[idx]
                num = np.stack([np.bincount(a, weights=u * v[k], minlength=n) for k in range(3)])
                step = num[:, nodes] / np.bincount(a, weights=u, minlength=n)[nodes]
            else:
                # Weiszfeld step per node; predictions the node sits on are set apart
                # (Vardi & Zhang): stay if |sum of the others' unit vectors| <= their weight.
                on = theta < 1e-9
                u = np.where(on, 0.0, w2[idx] / np.where(on, 1.0, theta))
                num = np.stack([np.bincount(a, weights=u * v[k], minlength=n) for k in range(3)])
                den = np.bincount(a, weights=u, minlength=n)[nodes]
                w_on = np.bincount(a, weights=np.where(on, w2[idx], 0.0), minlength=n)[nodes]
                pull = np.sqrt((num[:, nodes] ** 2).sum(axis=0))
                with np.errstate(invalid="ignore", divide="ignore"):
                    factor = np.where(pull > 0, np.maximum(0.0, 1.0 - w_on / pull), 0.0)
                    step = np.where(den > 0, num[:, nodes] / np.where(den > 0, den, 1.0), 0.0) * factor
            q[:, nodes] = so3.qmul_rows(q[:, nodes], so3.qexp_rows(step))
            total += float((step * step).sum())
        rms = float(np.sqrt(total / n))
        if callback is not None:
            callback("nodewise", it, rms)
        if rms < step_tol:
            return q, it, True
    return q, max_iterations, False


# --------------------------------------------------------------------------- initial guess

#: The methods that start from an initialisation (``SolveOptions.init``).
ITERATIVE_METHODS = ("irls", "l1", "l2", "nodewise")


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
    return q * np.where(q[0] < 0, -1.0, 1.0)


# --------------------------------------------------------------------------- driver


def average_rotations(
    graph: ViewGraph, options: SolveOptions | None = None, callback: Callback | None = None, **overrides
) -> AveragingResult:
    """Solve multiple rotation averaging on the largest connected component of ``graph``.

    ``options`` (or keyword overrides of its fields) choose the method; see
    :class:`SolveOptions`. Cameras outside the largest component are reported unsolved.
    A graph with :attr:`~rotgraph.viewgraph.ViewGraph.rigs` is solved at the frame level
    (``options.rig_aware``; see :mod:`.rig_rotation_averaging`): the result is per image,
    with the frame-level solve in ``result.frames``.
    """
    opts = replace(options or SolveOptions(), **overrides).validated()
    if graph.rigs is not None and opts.rig_aware and graph.n_edges:
        t0 = time.perf_counter()
        problem = frame_problem(graph)
        if problem is not None:
            if opts.init == "vertices" and opts.method in ITERATIVE_METHODS:
                raise ValueError("init 'vertices' is not available for a rig-aware solve (graph.rigs): "
                                 "give rig_aware=False or another init")
            fres = _average(problem.frame_graph, opts, callback)
            return problem.image_result(fres, opts.outlier_threshold_deg, time.perf_counter() - t0)
    return _average(graph, opts, callback)


def _average(graph: ViewGraph, opts: SolveOptions, callback: Callback | None) -> AveragingResult:
    """:func:`average_rotations` of a graph without rigs, with validated options."""
    t0 = time.perf_counter()
    if graph.n_nodes == 0 or graph.n_edges == 0:
        raise UnsolvableError("the view graph has no edges")
    labels = graph.components()
    n_components = int(labels.max()) + 1
    if n_components == 1:
        sub, nodes, eidx = graph, np.arange(graph.n_nodes), np.arange(graph.n_edges)
    else:
        nodes = np.flatnonzero(labels == 0)
        sub, eidx = graph.subgraph(nodes)
    n, edges = sub.n_nodes, sub.edges
    qrel = so3.quaternion_rows_from_matrices(sub.cam2_from_cam1)
    w_mst = sub.weights
    w = sub.weights if opts.use_weights else np.ones(sub.n_edges)
    if opts.use_weights:
        w = w / _median(w)
    stages: list = []
    if n_components > 1:
        logger.info("solving the largest of %d components: %d of %d cameras", n_components, n, graph.n_nodes)

    def mark(stage: str, iterations: int, converged: bool) -> None:
        stages.append({"stage": stage, "iterations": iterations, "converged": converged, "seconds": time.perf_counter() - t0})

    q, anchor, tree_edges = spanning_tree_rotations(n, edges, qrel, w_mst)
    mark("spanning_tree", 0, True)
    system = EdgeSystem(n, edges, qrel, anchor)
    method = opts.method
    if method != "spanning_tree" and opts.init in ("chordal", "quaternion") or method in ("chordal", "quaternion"):
        which = method if method in ("chordal", "quaternion") else opts.init
        if which == "chordal":
            q = solve_chordal(n, edges, qrel, w, anchor, opts.linear_solver)
        else:
            q = solve_quaternion(n, edges, qrel, w, anchor, q, opts.linear_solver)
        mark(which, 1, True)
    elif opts.init == "vertices" and method in ITERATIVE_METHODS:
        q = initial_guess_rotations(sub, qrel, tree_edges, anchor)
        mark("vertices", 0, True)

    iterations, converged = 0, True
    tol = np.deg2rad(opts.step_tol_deg)
    scale = np.deg2rad(opts.loss_scale_deg)
    if method in ("irls", "l1", "l2") and n > 1:
        lap = AnchoredLaplacian(n, edges, anchor, opts.linear_solver)
        stage_kw = dict(laplacian=lap, system=system, callback=callback)
        # Dense factorisations of a few hundred unknowns: BLAS threads only contend (on a
        # loaded 2-core machine they made each solve 10x slower); batch runs one per core.
        # (Below DENSE_MAX unknowns BLAS stays on one thread anyway: skip the switch.)
        with single_threaded_blas() if lap.solver == "dense" and n > DENSE_MAX else contextlib.nullcontext():
            # Intermediate stages (the L1 start of irls, the first robust pass before the
            # loss scale is re-fitted) stop at the looser stage_tol_deg.
            stage_tol = max(np.deg2rad(opts.stage_tol_deg), tol)
            if method in ("irls", "l1"):
                l1_max, l1_tol = (opts.l1_iterations, stage_tol) if method == "irls" else (opts.max_iterations, tol)
                q, it, conv = solve_irls(q, edges, qrel, w, anchor, "l1", scale, l1_max, l1_tol, stage="l1", **stage_kw)
                iterations += it
                converged = conv
                mark("l1", it, conv)
            if method in ("irls", "l2"):
                loss = opts.loss if method == "irls" else "l2"
                refit = method == "irls" and opts.rescale
                q, it, conv = solve_irls(q, edges, qrel, w, anchor, loss, scale, opts.max_iterations, stage_tol if refit else tol, stage=loss, **stage_kw)
                iterations += it
                converged = conv
                if refit:
                    # Fit the scale to the noise: the 25th percentile of 3-D Gaussian residual
                    # angles is 1.10 sigma; use 3 sigma. Only a clear change is worth a new
                    # stage; otherwise the first pass goes on to the final tolerance.
                    theta = 2.0 * system.errors(q)[2]
                    new_scale = max(3.0 * _percentile(theta, 25) / 1.10, np.deg2rad(MIN_SCALE_DEG))
                    stage, done = loss, it
                    if abs(new_scale - scale) > 0.2 * scale:
                        mark(loss, it, conv)
                        scale, stage, done = new_scale, loss + "_rescaled", 0
                    q, it, conv = solve_irls(q, edges, qrel, w, anchor, loss, scale, opts.max_iterations - done, tol, stage=stage,
                                             first_iteration=done + 1, **stage_kw)
                    iterations += it
                    converged = conv
                    it += done
                mark(stage if refit else loss, it, conv)
    elif method == "nodewise" and n > 1:
        q, iterations, converged = solve_nodewise(q, edges, qrel, w, anchor, opts.nodewise_norm, opts.max_iterations, tol, callback)
        mark("nodewise", iterations, converged)

    if opts.refine and n > 1:
        from .refine import refine_lm

        loss = opts.loss if method == "irls" else ("l1" if method == "l1" else "l2")
        q, it, conv = refine_lm(q, edges, qrel, w, anchor, loss, scale)
        iterations += it
        mark("refine", it, conv)

    # Results for every input node and edge. A camera all of whose edges are outliers has
    # no consensus behind its rotation: it is reported unsolved (CLI contract), its edges too.
    theta = 2.0 * system.errors(q)[2]
    inlier_sub = np.degrees(theta) <= opts.outlier_threshold_deg
    rejected = np.bincount(edges[inlier_sub].ravel(), minlength=n) == 0 if n > 1 else np.zeros(n, dtype=bool)
    if rejected.all():
        raise UnsolvableError(f"every edge is an outlier (residual > {opts.outlier_threshold_deg:g} deg): no camera can be trusted")
    if rejected.any():
        logger.info("%d camera(s) left out: every edge of theirs is an outlier", int(rejected.sum()))
    R_sub = so3.matrices_from_quaternion_rows(q)
    R_sub[rejected] = np.nan
    R = np.full((graph.n_nodes, 3, 3), np.nan)
    R[nodes] = R_sub
    solved = np.zeros(graph.n_nodes, dtype=bool)
    solved[nodes] = ~rejected
    residuals = np.full(graph.n_edges, np.nan)
    residuals[eidx] = np.degrees(theta)  # also the (outlier) edges of left-out cameras
    inliers = np.zeros(graph.n_edges, dtype=bool)
    inliers[eidx] = inlier_sub
    cost_loss = opts.loss if method == "irls" else ("l1" if method == "l1" else "l2")
    if method == "irls":
        stages[-1]["scale_deg"] = float(np.degrees(scale))
    cost = float(w @ loss_rho(cost_loss, theta, scale))
    seconds = time.perf_counter() - t0
    logger.info("%s: %d cameras, %d edges, %d outliers, %d iterations, %.2f s", method, n, sub.n_edges, int((~inliers[eidx]).sum()), iterations, seconds)
    rejected_all = np.zeros(graph.n_nodes, dtype=bool)
    rejected_all[nodes] = rejected
    return AveragingResult(R, solved, residuals, inliers, iterations, cost, converged, method, int(nodes[anchor]), n_components, seconds, stages,
                           rejected_all)