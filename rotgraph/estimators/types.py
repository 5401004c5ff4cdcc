"""What goes into multiple rotation averaging and what comes out: :class:`SolveOptions`
and :class:`AveragingResult` (shared by the image-level and the rig-level solvers)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Callable

if TYPE_CHECKING:
    import numpy as np

from ..choices import INITS, LINEAR_SOLVERS, LOSSES, METHODS, RIG_EXTRINSICS
from ..errors import OptionError
from ..options import Options

__all__ = ["SolveOptions", "AveragingResult", "FrameSolution", "SensorSolution", "METHODS", "INITS", "LOSSES", "Callback",
           "scatter_to_graph"]

#: Progress of the iterations: ``callback(stage, iteration, median_step_rad)``.
Callback = Callable[[str, int, float], None]


@dataclass(frozen=True)
class SolveOptions(Options):
    """Options of :func:`average_rotations` (defaults: the winners of the benchmarks).

    Frozen; :meth:`~rotgraph.options.Options.validated` checks the values (an
    :class:`~rotgraph.errors.OptionError`, also a ``ValueError``, for a bad one);
    :func:`average_rotations` calls it.

    Parameters
    ----------
    method : str, default "adaptive"
        One of :data:`~rotgraph.choices.METHODS`: ``adaptive`` (weights from the noise and
        outliers estimated in the data), ``irls`` (GLOMAP's L1 then robust IRLS), ``l1``,
        ``l2``, ``chordal``, ``quaternion``, ``nodewise``, ``spanning_tree``.
    loss : str, default "geman_mcclure"
        Robust loss of the IRLS stage, one of :data:`~rotgraph.choices.LOSSES`.
    loss_scale_deg : float, default 5.0
        Its scale in degrees (> 0).
    rescale : bool, default True
        After converging, re-fit the scale to the inlier residuals and re-run.
    init : str, default "auto"
        Starting point of the iterative methods, one of :data:`~rotgraph.choices.INITS`:
        ``auto``, ``mst``, ``chordal``, ``quaternion`` or ``vertices`` (the input's initial
        guess, ``graph.initial_cam_from_world``).
    l1_iterations : int, default 10
        Maximum iterations of the L1 stage of ``irls`` and ``adaptive``.
    max_iterations : int, default 100
        Maximum iterations of IRLS / L2 / L1 / node-wise.
    step_tol_deg : float, default 1e-3
        Stop when the median camera update is below this (degrees, >= 0).
    stage_tol_deg : float, default 0.02
        The same tolerance for the intermediate stages of ``irls`` (degrees, >= 0).
    outlier_threshold_deg : float or None, default None
        Edges with a larger final residual (degrees, > 0) are outliers. None: adaptive,
        from the fitted noise model; the other robust methods 10 degrees.
    use_weights : bool, default False
        Multiply the edge weights into the averaging cost (the spanning tree uses them always).
    use_information : bool, default True
        Weight each edge by its rotation information matrix, when the input has them.
    linear_solver : str, default "auto"
        Laplacian solves: ``dense``, ``direct``, ``cg`` or ``auto``.
    nodewise_norm : str, default "l1"
        ``l1`` or ``l2``: the norm of ``method="nodewise"``.
    refine : bool, default False
        A final Levenberg-Marquardt on the exact geodesic robust cost.
    rig_aware : bool, default True
        With rigs (``graph.rigs``): average the frame rotations, derive the images'.
    rig_extrinsics : str, default "auto"
        ``auto``, ``fixed``, ``refine`` or ``unknown``: which ``cam_from_rig`` are kept or
        estimated (:data:`~rotgraph.choices.RIG_EXTRINSICS`).
    seed : int, default 0
        Every random choice of a solve: the residuals the adaptive noise model is fitted on
        (> 20 000 edges), its cross-validation folds, the linear start's random vectors.
    """

    method: str = "adaptive"  # see estimators/adaptive.py; "irls" is GLOMAP's pipeline
    loss: str = "geman_mcclure"  # robust loss of the IRLS stage
    loss_scale_deg: float = 5.0  # its scale
    rescale: bool = True  # after converging, re-fit the scale to the inlier residuals and re-run
    # Starting point of the iterative methods: auto (adaptive: the spanning tree and the
    # chordal relaxation, each carried through the robust stages, the answer of lower L1
    # cost over every edge kept; other methods: the spanning tree), mst,
    # chordal, quaternion, or vertices (the input's initial guess,
    # graph.initial_cam_from_world: g2o vertices; cameras without one chained along the
    # spanning tree; an InputError when it has none).
    init: str = "auto"
    l1_iterations: int = 10  # L1RA stage of "irls" and "adaptive" (max)
    max_iterations: int = 100  # IRLS / L2 / L1 / node-wise (max)
    step_tol_deg: float = 1e-3  # stop when the median camera update is below this
    # Tolerance of the intermediate stages of "irls": the L1 start, which only brings the
    # rotations into the robust loss's basin, and the robust pass before the loss scale is
    # re-fitted (the final stage converges to step_tol_deg). On the median update; Theia and
    # GLOMAP stop L1 at a mean update of 1e-3 rad = 0.057 deg. Measured: 0.02 saves 1-3
    # iterations on the COLMAP benchmark projects with the same errors; 0.05 also, but
    # stops L1 early on Ellis Island (mean error 3.13 -> 3.75 deg).
    stage_tol_deg: float = 0.02
    # Edges with a larger final residual are outliers. None: adaptive, from the fitted noise
    # model (an inlier probability below 1/2); the other robust methods (irls, l1): 10 deg.
    outlier_threshold_deg: float | None = None
    use_weights: bool = False  # multiply the edge weights into the averaging cost (MST uses them always)
    # Weight each edge by its rotation information matrix (graph.information), when the input
    # has them: IRLS on whitened residuals (3x3-block Laplacian); False ignores them.
    use_information: bool = True
    linear_solver: str = "auto"  # Laplacian solves: dense (Cholesky), direct (sparse LU), cg (Jacobi-PCG), auto
    nodewise_norm: str = "l1"
    refine: bool = False  # final Levenberg-Marquardt on the exact geodesic robust cost
    rig_aware: bool = True  # with rigs (graph.rigs): average frame rotations, derive the images'
    # The rig extrinsics (cam_from_rig of each sensor; graph.rigs with sensor ids): "auto"
    # (given ones fixed, unknown ones estimated), "fixed" (given ones fixed; images of a
    # sensor without one solved on their own), "refine" (given ones are starting values,
    # every non-reference sensor estimated), "unknown" (given ones ignored). See
    # estimators/rig_calibration.py.
    rig_extrinsics: str = "auto"
    seed: int = 0  # every random choice: the residuals fitted (> 20 000 edges), the CV folds, the linear start

    def check(self) -> None:
        """An unknown method, init, linear solver, rig_extrinsics, nodewise_norm or loss, a
        scale or threshold not positive, or a negative tolerance:
        :class:`~rotgraph.errors.OptionError`."""
        if self.method not in METHODS:
            raise OptionError(f"unknown method {self.method!r}; expected one of {', '.join(METHODS)}")
        if self.init not in INITS:
            raise OptionError(f"unknown init {self.init!r}; expected one of {', '.join(INITS)}")
        if self.linear_solver not in LINEAR_SOLVERS:
            raise OptionError(f"unknown linear solver {self.linear_solver!r}")
        if self.rig_extrinsics not in RIG_EXTRINSICS:
            raise OptionError(f"unknown rig_extrinsics {self.rig_extrinsics!r}; expected one of {', '.join(RIG_EXTRINSICS)}")
        if self.nodewise_norm not in ("l1", "l2"):
            raise OptionError("nodewise_norm must be l1 or l2")
        from ..losses import check_loss

        check_loss(self.loss)
        if not self.loss_scale_deg > 0 or not (self.outlier_threshold_deg is None or self.outlier_threshold_deg > 0):
            raise OptionError("loss_scale_deg and outlier_threshold_deg must be positive")
        if not (self.step_tol_deg >= 0 and self.stage_tol_deg >= 0):
            raise OptionError("step_tol_deg and stage_tol_deg must be >= 0")


@dataclass
class AveragingResult:
    """The outcome of :func:`average_rotations`.

    ``cam_from_world`` has a row for every node of the input graph; rows of nodes that
    could not be solved (outside the largest component, or every edge of theirs an outlier)
    are NaN and ``solved`` is False. ``residuals_deg`` and ``inliers`` have one entry per
    input edge (NaN / False for edges outside the largest component). The gauge is fixed
    by ``anchor`` (identity rotation; it may itself be left out as above).

    Attributes
    ----------
    cam_from_world : (n, 3, 3) float64 ndarray
        The absolute rotations (world-to-camera), NaN rows for unsolved cameras.
    solved : (n,) bool ndarray
        Whether each camera was solved.
    residuals_deg : (E,) float64 ndarray
        Each input edge's residual in degrees: the angle between ``R_ij`` and
        ``R_j R_i^T`` (NaN outside the solved component).
    inliers : (E,) bool ndarray
        Residual within ``outlier_threshold_deg`` (False outside the solved component).
    iterations : int
        Iterations of the solve (every stage; the adaptive method's from both starts).
    cost : float
        The final cost of the method.
    converged : bool
        Whether the stopping test was met.
    method : str
        The method used.
    anchor : int
        The node fixed to the identity (the gauge).
    n_components : int
        Connected components of the input graph.
    seconds : float
        Wall time of the solve.
    stages : list
        One report per stage.
    rejected : (n,) bool ndarray or None
        Cameras of the solved component left out (every edge of theirs an outlier).
    frames : FrameSolution or None
        The rig-level solve behind this result, when rigs were used.
    outlier_threshold_deg : float
        The residual (degrees) above which an edge was called an outlier.
    diagnostics : dict
        What the solver chose and why (start, noise model, ...).
    edge_weights : (E,) float64 ndarray or None
        Each input edge's weight in the final iteration; NaN for edges outside the solve.
    sensors : SensorSolution or None
        The rig extrinsics, when they were estimated or refined.
    """

    cam_from_world: np.ndarray
    solved: np.ndarray
    residuals_deg: np.ndarray
    inliers: np.ndarray
    iterations: int
    cost: float
    converged: bool
    method: str
    anchor: int
    n_components: int
    seconds: float
    stages: list = field(default_factory=list)
    rejected: np.ndarray | None = None  # (n,) bool: in the solved component, left out (every edge an outlier)
    frames: FrameSolution | None = None  # the rig-level solve behind this result, when rigs were used
    outlier_threshold_deg: float = float("nan")  # the residual above which an edge was called an outlier
    diagnostics: dict = field(default_factory=dict)  # what the solver chose and why (start, noise model, ...)
    # (E,) each input edge's weight in the final iteration (input weight, times the robust or
    # noise-model weight, times its isotropic precision with information matrices); NaN for
    # edges outside the solve. The weighted problem whose fixed point the result is.
    edge_weights: np.ndarray | None = None
    sensors: SensorSolution | None = None  # the rig extrinsics, when they were estimated or refined

    @property
    def n_rejected(self) -> int:
        return 0 if self.rejected is None else int(self.rejected.sum())

    @property
    def n_solved(self) -> int:
        return int(self.solved.sum())

    @property
    def n_outliers(self) -> int:
        return int((~self.inliers & (self.residuals_deg == self.residuals_deg)).sum())  # not NaN


@dataclass
class FrameSolution:
    """The rig-level solve behind an image-level :class:`AveragingResult`.

    ``graph`` is the frame graph (a node per frame, or per image whose ``cam_from_rig`` is
    unknown), ``result`` its solution (``cam_from_world`` = ``rig_from_world``),
    ``frame_of_image`` (n,) the frame-graph node of each image, ``image_edge_index`` the
    image edge behind each frame edge, ``n_intra_frame_pairs`` the image pairs within one
    frame (no frame information, skipped).
    """

    graph: object
    result: AveragingResult
    frame_of_image: np.ndarray
    image_edge_index: np.ndarray
    n_intra_frame_pairs: int


@dataclass
class SensorSolution:
    """The rig extrinsics behind a rig solve that estimated or refined them
    (``estimators/rig_calibration.py``), one row per sensor.

    ``sensor_ids`` (K,) the sensor keys of ``graph.rigs.sensor_ids``; ``cam_from_rig``
    (K, 3, 3) (NaN where unobservable); ``status`` (K,) ``reference`` (the identity by
    definition), ``fixed`` (given, kept), ``refined`` (given, re-estimated), ``estimated``
    (unknown, estimated) or ``unobservable`` (never seen in a frame with a calibrated sensor:
    its images solved on their own); ``n_frames`` (K,) the frames it was seen in with a
    solved frame rotation; ``spread_deg`` (K,) the median over those frames of the angle
    between the image's own ``R_image R_frame^T`` and ``cam_from_rig`` (how well one
    rotation fits every frame); ``n_outlier_frames`` (K,) frames whose angle exceeds the
    outlier threshold; ``rounds`` the outer rounds of the solve.
    """

    sensor_ids: np.ndarray
    cam_from_rig: np.ndarray
    status: np.ndarray
    n_frames: np.ndarray
    spread_deg: np.ndarray
    n_outlier_frames: np.ndarray
    rounds: int = 0

    def to_rows(self) -> list[dict]:
        """One JSON-able dict per sensor: ``sensor_id``, ``status``, ``qw qx qy qz``
        (``cam_from_rig``; None when unobservable), ``n_frames``, ``spread_deg``,
        ``n_outlier_frames``."""
        import numpy as np

        from .. import so3

        rows = []
        for k in range(len(self.sensor_ids)):
            S = self.cam_from_rig[k]
            q = so3.quaternions_from_matrices(S).tolist() if np.isfinite(S).all() else None
            rows.append({"sensor_id": int(self.sensor_ids[k]), "status": str(self.status[k]),
                         "qw": None if q is None else q[0], "qx": None if q is None else q[1],
                         "qy": None if q is None else q[2], "qz": None if q is None else q[3],
                         "n_frames": int(self.n_frames[k]),
                         "spread_deg": None if not np.isfinite(self.spread_deg[k]) else float(self.spread_deg[k]),
                         "n_outlier_frames": int(self.n_outlier_frames[k])})
        return rows


def scatter_to_graph(n_nodes: int, n_edges: int, nodes: np.ndarray, eidx: np.ndarray, R_sub: np.ndarray,
                     rejected: np.ndarray, residuals_deg_sub: np.ndarray, inlier_sub: np.ndarray,
                     edge_weights_sub: np.ndarray) -> dict:
    """The per-camera and per-edge arrays of an :class:`AveragingResult` over the whole graph
    from those of the solved component (cameras ``nodes``, edges ``eidx``).

    Parameters
    ----------
    n_nodes, n_edges : the whole graph's size.
    nodes : (n,) int, eidx : (E_sub,) int
        The component's cameras and edges in the whole graph.
    R_sub : (n, 3, 3) float64
        The component's ``cam_from_world`` rotations.
    rejected : (n,) bool
        Cameras left out (every edge an outlier): NaN rotations, not solved.
    residuals_deg_sub, inlier_sub, edge_weights_sub : (E_sub,)
        Per component edge.

    Returns
    -------
    dict
        ``cam_from_world``, ``solved``, ``residuals_deg``, ``inliers``, ``edge_weights`` and
        ``rejected`` over the whole graph (NaN / False outside the component), the keyword
        arguments of :class:`AveragingResult` of those names.
    """
    import numpy as np  # (this module is numpy-free at import: the command line's options import it)

    R = np.full((n_nodes, 3, 3), np.nan)
    R[nodes] = R_sub
    R[nodes[rejected]] = np.nan
    solved = np.zeros(n_nodes, dtype=bool)
    solved[nodes] = ~rejected
    residuals = np.full(n_edges, np.nan)
    residuals[eidx] = residuals_deg_sub
    inliers = np.zeros(n_edges, dtype=bool)
    inliers[eidx] = inlier_sub
    edge_weights = np.full(n_edges, np.nan)
    edge_weights[eidx] = edge_weights_sub
    rejected_all = np.zeros(n_nodes, dtype=bool)
    rejected_all[nodes] = rejected
    return dict(cam_from_world=R, solved=solved, residuals_deg=residuals, inliers=inliers, edge_weights=edge_weights,
                rejected=rejected_all)
