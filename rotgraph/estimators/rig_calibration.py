"""Rig solve with unknown, partly known or fixed extrinsics: conjugate and multiple rotation
averaging together (issue #17).

Model. Image ``a``, taken by sensor ``k`` in frame ``f`` of a rig, has
``cam_from_world_a = S_k F_f`` with ``S_k = cam_from_rig`` (the sensor's rotation in its
rig, the identity for the rig's reference sensor) and ``F_f = rig_from_world`` (the rig at
that frame). An image pair ``(a, b)`` measures ``R_ab = S_l F_g F_f^T S_k^T``; a pair within
one frame (``f = g``) measures ``S_l S_k^T`` alone: the direct evidence on the extrinsics
that a frame-level solve skips.

Algorithm (:func:`solve_rig`; the frame-level solves are the one pipeline of stages,
:func:`.stages.run`, on each round's frame graph, so the method, noise model, outlier test and
thresholds are the same as everywhere else):

1. Round 0: the frame-level solve with the given extrinsics (``fixed`` / ``refined``
   sensors), every image of a sensor to estimate a frame of its own: all images get
   rotations in one gauge. It only starts the extrinsics: the adaptive solver's stages up
   to the Gaussian + outliers model, at the intermediate stages' tolerance, and without the
   pairs within one frame (biased, overconfident near-panoramic rotations) unless a sensor
   is seen in no frame with a calibrated one without them.
2. Start of the extrinsics: for each sensor to estimate, one sample ``R_a F_f^T`` per frame
   where the sensor's image and a calibrated sensor's image are both solved (``F_f`` the
   chordal mean of the calibrated images' ``S_c^T R_c``), averaged by rotgraph's robust
   single rotation averaging (the geodesic L1 median; samples beyond the outlier
   threshold are counted as outlier frames). Sensors seen only with sensors calibrated this
   way are calibrated next (a chain through the rig); a sensor never seen in a frame with a
   calibrated one is *unobservable*: a warning, its images solved on their own.
3. Rounds 1..: the frame-level solve with those extrinsics (its robust weights and inlier
   set; started from the previous round's frames), then a joint Gauss-Newton refinement of
   frames and extrinsics in one sparse system, with every image pair at the frame solve's final weights (pairs within a frame,
   which the frame solve skips, at the inliers' median weight scaled by how much noisier
   they are: near-panoramic, their information from the matches can be 80x overconfident):
   an image's world-frame update is ``w_a = delta_f + R_a^T sigma_k`` for
   ``F_f <- F_f exp(delta_f)``, ``S_k <- exp(sigma_k) S_k``, so the image-level
   Gauss-Newton rows ``w_a - w_b`` become rows over (frames, sensors)
   (:func:`.rig_refine.joint_refine`: normal equations dense Cholesky up to ``DENSE_MAX``
   unknowns, else block-Jacobi CG; factorised once while the steps shrink fast, stopped when
   the predicted distance to the fixed point is below ``REFINE_TOL``). Another round only
   when the extrinsics moved on the scale of the residuals that set the weights
   (``ROUND_FRACTION`` of their median; at most ``MAX_ROUNDS``).

Noise-free inputs give the extrinsics and rotations exactly (step 2 is exact, step 3 stays
there).
"""

from __future__ import annotations

import copy
import logging
import time
from dataclasses import replace

import numpy as np

from .. import choices, so3, so3_checks, so3_rows
from ..viewgraph import ViewGraph
from .residuals import EdgeSystem
from .rig_refine import joint_refine
from .rig_rotation_averaging import frame_problem, lone_frames
from .stages import run
from .types import AveragingResult, SensorSolution, SolveOptions

__all__ = ["given_sensor_solution", "sensor_table", "initial_extrinsics", "joint_refine", "solve_rig", "needs_calibration"]

logger = logging.getLogger(__name__)

MAX_ROUNDS = 3
#: The frame solves after round 0 start from the previous round's frames (``init="vertices"``
#: on the frame graph) when the options leave the start to the solver (``init="auto"``), for
#: the methods of :data:`~rotgraph.choices.METHOD_TABLE` marked ``warm_start``.
WARM_START_METHODS = choices.WARM_START_METHODS
# Stop the rounds (frame solve, joint refinement) when no extrinsic moved more than this, or
# than ROUND_FRACTION of the median inlier residual (the weights of the next frame solve
# would hardly change).
ROUND_TOL_DEG = 1e-3
ROUND_FRACTION = 0.1
ROUND0_STEP_TOL_DEG = 0.02
#: Step tolerance (rad) of the L1 median of a sensor's samples: a start for the joint
#: refinement (measured: 34 Weiszfeld iterations instead of 311 on r6x60's first sensor,
#: 3e-7 rad from the 1e-10 rad optimum; its extrinsic error is 1e-4 rad).
START_TOL = 1e-8
# Samples of a sensor's rotation beyond this (degrees) from their median are outlier frames
# when the solve has no outlier threshold of its own (L2 methods).
DEFAULT_OUTLIER_DEG = 10.0


class SensorTable:
    """The sensors of ``graph.rigs`` (those with ``sensor_ids >= 0``).

    ``keys`` (K,) sensor ids; ``of_image`` (n,) index into them (-1: no sensor); ``given``
    (K, 3, 3) the given ``cam_from_rig`` (NaN unknown; the identity for references);
    ``status`` (K,) as :class:`~.types.SensorSolution`.
    """

    def __init__(self, keys, of_image, given, status):
        self.keys, self.of_image, self.given, self.status = keys, of_image, given, status

    @property
    def free(self) -> np.ndarray:
        return np.isin(self.status, ("refined", "estimated"))


def sensor_table(rigs, mode: str) -> SensorTable:
    """The sensors of ``rigs`` and what the solve does with each under ``mode``
    (``SolveOptions.rig_extrinsics``)."""
    n = len(rigs.frame_ids)
    sid = rigs.sensor_ids
    valid = sid >= 0
    keys, inv = np.unique(sid[valid], return_inverse=True)
    K = len(keys)
    of_image = np.full(n, -1, dtype=np.int64)
    of_image[valid] = inv
    ref = np.zeros(K, dtype=bool)
    np.logical_or.at(ref, inv, rigs.is_reference[valid])
    finite = valid & np.isfinite(rigs.cam_from_rig).all(axis=(1, 2))
    given = np.full((K, 3, 3), np.nan)
    if finite.any():
        idx = np.flatnonzero(finite)
        first_sensor, first = np.unique(of_image[idx], return_index=True)
        given[first_sensor] = rigs.cam_from_rig[idx[first]]
        spread = so3.angle_between(rigs.cam_from_rig[idx], given[of_image[idx]])
        if spread.size and float(spread.max()) > 1e-6:
            logger.warning("images of one sensor disagree on its cam_from_rig by up to %.3g deg: the first is used",
                           np.degrees(spread.max()))
    given[ref] = np.eye(3)
    known = np.isfinite(given).all(axis=(1, 2))
    status = np.empty(K, dtype=object)
    status[ref] = "reference"
    if mode in ("auto", "fixed"):
        status[~ref & known] = "fixed"
        status[~ref & ~known] = "estimated" if mode == "auto" else "unobservable"
    elif mode == "refine":
        status[~ref & known] = "refined"
        status[~ref & ~known] = "estimated"
    else:  # unknown
        status[~ref] = "estimated"
        given[~ref] = np.nan
    return SensorTable(keys, of_image, given, status)


def given_sensor_solution(rigs) -> SensorSolution | None:
    """The extrinsics as given (``reference`` / ``fixed`` / ``unobservable`` for those
    without one), for reports of a solve that estimated none; None without sensor ids."""
    if rigs is None or rigs.sensor_ids is None:
        return None
    t = sensor_table(rigs, "fixed")
    K = len(t.keys)
    return SensorSolution(t.keys.copy(), t.given.copy(), t.status.copy(), np.zeros(K, np.int64), np.full(K, np.nan),
                          np.zeros(K, np.int64), 0)


def needs_calibration(graph: ViewGraph, opts: SolveOptions) -> bool:
    """Whether ``graph`` has sensors whose extrinsics the solve must estimate or refine."""
    rigs = graph.rigs
    if rigs is None or rigs.sensor_ids is None or opts.rig_extrinsics == "fixed":
        return False
    return bool(sensor_table(rigs, opts.rig_extrinsics).free.any())


def _frame_means(R: np.ndarray, frame_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(keys, F)``: per frame key, the chordal mean of the rotations ``R`` of that frame."""
    keys, inv = np.unique(frame_ids, return_inverse=True)
    acc = np.zeros((len(keys), 3, 3))
    np.add.at(acc, inv, R)
    return keys, so3_checks.project_to_so3(acc)


def initial_extrinsics(cam_from_world: np.ndarray, solved: np.ndarray, frame_ids: np.ndarray, table: SensorTable,
                       S: np.ndarray) -> tuple[np.ndarray, dict]:
    """Step 2 of the module docstring: ``S`` (K, 3, 3) with the sensors ``table.status ==
    "estimated"`` filled in from per-frame samples (rows left NaN: unobservable). Returns
    ``(S, samples)``: ``samples[k]`` (m, 3, 3) the per-frame samples ``R_a F_f^T`` of every
    free sensor ``k`` seen with a calibrated one (refined sensors: their given value is kept)."""
    from .single import mean
    from .single_iterative import geodesic_l1_means

    S = S.copy()
    samples: dict = {}
    todo = set(np.flatnonzero(table.free).tolist())
    sensor = table.of_image
    while todo:
        known = np.isfinite(S).all(axis=(1, 2)) & ~np.isin(np.arange(len(S)), list(todo))
        calibrated = solved & (sensor >= 0) & known[np.maximum(sensor, 0)]
        if not calibrated.any():
            break
        F_img = np.swapaxes(S[sensor[calibrated]], 1, 2) @ cam_from_world[calibrated]
        keys, F = _frame_means(F_img, frame_ids[calibrated])
        progress, batch = False, []
        for k in sorted(todo):
            mine = np.flatnonzero(solved & (sensor == k))
            pos = np.minimum(np.searchsorted(keys, frame_ids[mine]), len(keys) - 1)
            hit = keys[pos] == frame_ids[mine]
            if not hit.any():
                continue
            samples[k] = cam_from_world[mine[hit]] @ np.swapaxes(F[pos[hit]], 1, 2)
            if table.status[k] == "estimated":
                if len(samples[k]) >= 3:
                    batch.append(k)
                else:  # the L1 median of two is any point between them
                    S[k] = mean(samples[k], metric="geodesic", norm="l2", step_tol_rad=START_TOL).rotation
            todo.discard(k)
            progress = True
        if batch:  # the geodesic L1 medians of this pass's sensors at once
            starts = np.r_[0, np.cumsum([len(samples[k]) for k in batch])]
            Q = so3_rows.quaternion_rows_from_matrices(np.concatenate([samples[k] for k in batch]))
            S[batch] = so3_rows.matrices_from_quaternion_rows(geodesic_l1_means(Q, starts, tol=START_TOL))
        if not progress:
            break
    return S, samples


def _residual_sizes(graph: ViewGraph, edges: np.ndarray, R: np.ndarray, information) -> tuple[np.ndarray, np.ndarray]:
    """``(angles, sizes)`` (radians) of the edges ``edges`` at the image rotations ``R``: each
    residual's angle and its size, the Mahalanobis norm under its information matrix (the
    angle without); inf where an end is unsolved."""
    solved = np.isfinite(R).all(axis=(1, 2))
    ok = solved[graph.edges[edges, 0]] & solved[graph.edges[edges, 1]]
    angles, sizes = np.full(len(edges), np.inf), np.full(len(edges), np.inf)
    sel = edges[ok]
    if len(sel):
        q = so3_rows.quaternion_rows_from_matrices(np.where(solved[:, None, None], R, np.eye(3)))
        system = EdgeSystem(len(R), graph.edges[sel], graph.relative_quaternion_rows(sel), 0,
                            information=None if information is None else information[sel])
        angles[ok] = system.rotation_angles(q)
        sizes[ok] = system.angles(q)
    return angles, sizes


def _edge_weights_for_refinement(graph: ViewGraph, problem, fres: AveragingResult, R: np.ndarray,
                                 threshold_deg: float, information) -> np.ndarray:
    """``u`` (E,): the frame solve's final weight of each frame-to-frame edge (its robust or
    noise-model weight; with information matrices divided by the isotropic precision that
    :func:`joint_refine` puts back by whitening); for pairs within a frame (which the frame
    solve never saw) the median weight of the inlier edges, divided by how much noisier the
    within-frame pairs are than the frame-to-frame inliers at ``R`` (the squared ratio of the
    median residual sizes, Mahalanobis with information: the relative poses of a rig's
    sensors at one instant are near-panoramic, and their information from the matches can be
    80x overconfident: measured on pycolmap's synthetic rigs), 0 for a pair whose angle
    exceeds ``threshold_deg``."""
    E = graph.n_edges
    u = np.zeros(E)
    if fres.edge_weights is not None:
        u[problem.edge_index] = np.nan_to_num(fres.edge_weights, nan=0.0)
        if information is not None:
            iso = np.trace(information, axis1=1, axis2=2) / 3.0
            u[problem.edge_index] /= np.maximum(iso[problem.edge_index], 1e-300)
    else:
        u[problem.edge_index] = np.where(fres.inliers, 1.0, 0.0)
    ref = u[problem.edge_index][fres.inliers]
    typical = float(np.median(ref[ref > 0])) if (ref > 0).any() else 1.0
    within = np.flatnonzero(~problem.inter)
    if len(within):
        inl = problem.edge_index[fres.inliers]
        ang, size = _residual_sizes(graph, np.concatenate([within, inl]), R, information)
        keep = np.degrees(ang[: len(within)]) <= threshold_deg
        m_in, m_w = size[len(within):], size[: len(within)][keep]
        scale = 1.0
        if np.isfinite(m_in).any() and np.isfinite(m_w).any():
            mi, mw = float(np.median(m_in[np.isfinite(m_in)])), float(np.median(m_w[np.isfinite(m_w)]))
            if mi > 0 and mw > 0:
                scale = float(np.clip((mw / mi) ** 2, 1e-2, 1e6))
        u[within] = np.where(keep, typical / scale, 0.0)
    return u


def _round0(graph: ViewGraph, table: SensorTable, opts: SolveOptions, qall: np.ndarray, frame_solve):
    """Round 0 of :func:`solve_rig`: the extrinsics' starting values from frame solves at the
    given extrinsics (refined ones as starting values), the rest on their own. Returns
    ``(result, threshold, S, samples)``: round 0's image-level result, its outlier threshold
    (deg), the extrinsics and each sensor's per-frame samples
    (:func:`initial_extrinsics`)."""
    rigs = graph.rigs
    S = table.given.copy()
    # Round 0 only starts the extrinsics (averaged robustly over frames, then refined): it
    # stops at the intermediate stages' tolerance, after the adaptive solver's Gaussian +
    # outliers stage (its inliers and outlier threshold; the search for another noise
    # model is left to the rounds that set the final weights).
    # Pairs within one frame are left out, as in the frame solves: the rig's sensors see the
    # scene from one place, and these near-panoramic relative rotations are biased (measured
    # on pycolmap's synthetic rigs: their L1 median is 0.1-1.2 deg from the true extrinsics,
    # round 0's samples 0.01 deg) with overconfident information, which also pulled the chordal
    # start 2x further from the solution (five L1 iterations instead of two). Only when a
    # sensor is then seen in no frame with a calibrated one is round 0 solved with them.
    o0 = replace(opts, step_tol_deg=max(opts.step_tol_deg, ROUND0_STEP_TOL_DEG))
    within = rigs.frame_ids[graph.edges[:, 0]] == rigs.frame_ids[graph.edges[:, 1]]
    graphs0 = [(graph, qall)]
    if within.any() and not within.all():
        graph0, e0 = graph.subgraph(np.arange(graph.n_nodes), edge_mask=~within)
        graphs0.insert(0, (graph0, qall[:, e0]))
    for graph0, q0 in graphs0:
        problem, fres = frame_solve(S, o0, full=False, image_graph=graph0, qrel=q0)
        res0 = problem.image_result(fres, 0.0)
        threshold = fres.outlier_threshold_deg if np.isfinite(fres.outlier_threshold_deg) else DEFAULT_OUTLIER_DEG
        S0, samples = initial_extrinsics(res0.cam_from_world, res0.solved, rigs.frame_ids, table, S)
        if set(samples) == set(np.flatnonzero(table.free).tolist()):
            break
    return res0, threshold, S0, samples


def _sensor_status(table: SensorTable, samples: dict, S: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(status, free, unobservable)`` of each sensor after round 0: a free sensor seen in no
    frame with a calibrated one is kept at its given value ("fixed") or, with none,
    "unobservable" (its ``S`` row set to NaN here, in place); ``free``: the sensors the joint
    refinement moves."""
    K = len(table.keys)
    status = table.status.copy()
    unseen = table.free & ~np.isin(np.arange(K), list(samples))
    status[unseen & (table.status == "refined")] = "fixed"  # its given value stays: nothing to refine it on
    unobservable = unseen & (table.status == "estimated")
    status[unobservable] = "unobservable"
    S[unobservable] = np.nan
    if unseen.any():
        logger.warning("rig extrinsics: %d sensor(s) never seen in a frame with a calibrated sensor (ids %s): "
                       "%d without cam_from_rig (their images solved on their own), %d kept at the given value",
                       int(unseen.sum()), ", ".join(str(k) for k in table.keys[unseen][:10]),
                       int(unobservable.sum()), int((unseen & ~unobservable).sum()))
    free = np.isin(status, ("refined", "estimated"))
    return status, free, unobservable


def _refinement_rounds(graph: ViewGraph, frame_solve, per_image, sensor: np.ndarray, S: np.ndarray, free: np.ndarray,
                       threshold: float, info, start: np.ndarray):
    """The rounds of :func:`solve_rig` after round 0: a frame solve (started at the image
    rotations ``start``), then :func:`joint_refine` of frames and free extrinsics, until the
    extrinsics stop moving on the residuals' scale. Returns ``(problem, frame result at the
    refined frames, S, rounds)``."""
    rounds = 0
    for rounds in range(1, MAX_ROUNDS + 1):
        problem, fres = frame_solve(S, start=start)
        S_before = S.copy()
        F, S, iters = joint_refine(graph, problem.group, fres.cam_from_world, problem.cam_from_rig, sensor, S, free,
                                   _edge_weights_for_refinement(graph, problem, fres, problem.image_result(fres, 0.0).cam_from_world,
                                                                threshold, info),
                                   fres.anchor, info)
        fres = replace(fres, cam_from_world=F)
        S_img = per_image(S)  # the images at the refined frames and extrinsics: the next round's start
        S_img[~np.isfinite(S_img).all(axis=(1, 2))] = np.eye(3)
        start = S_img @ F[problem.group]
        moved = np.degrees(so3.angle_between(S[free], S_before[free])) if free.any() else np.zeros(0)
        logger.info("rig extrinsics round %d: %d Gauss-Newton iterations, extrinsics moved up to %.3g deg",
                    rounds, iters, moved.max() if moved.size else 0.0)
        # Another frame solve only re-weights the edges: worth it when the extrinsics moved on
        # the scale of the residuals that set the weights.
        scale = fres.residuals_deg[fres.inliers]
        scale = float(np.median(scale)) if scale.size and np.isfinite(scale).any() else 0.0
        if not moved.size or moved.max() < max(ROUND_TOL_DEG, ROUND_FRACTION * scale):
            break
    return problem, fres, S, rounds


def _with_sensors(graph: ViewGraph, opts: SolveOptions, result: AveragingResult, table: SensorTable, S: np.ndarray,
                  status: np.ndarray, unobservable: np.ndarray, samples: dict, threshold: float,
                  rounds: int) -> AveragingResult:
    """The rig solve's image-level ``result`` with every edge's residual, the
    :class:`~.types.SensorSolution` and the ``rig_extrinsics`` diagnostics."""
    K = len(table.keys)
    angles = _residual_sizes(graph, np.arange(graph.n_edges), result.cam_from_world, None)[0]
    residuals = np.where(np.isfinite(angles), np.degrees(angles), np.nan)  # NaN: an end unsolved
    # per sensor: how well one rotation fits every frame (the round-0 samples, each frame's
    # own R_image R_frame^T before the rig constraint)
    n_frames = np.zeros(K, dtype=np.int64)
    spread = np.full(K, np.nan)
    n_out = np.zeros(K, dtype=np.int64)
    for k, smp in samples.items():
        ang = np.degrees(so3.angle_between(smp, np.broadcast_to(S[k], smp.shape)))
        n_frames[k], spread[k], n_out[k] = len(ang), float(np.median(ang)), int((ang > threshold).sum())
    S_out = S.copy()
    S_out[unobservable] = np.nan
    sensors = SensorSolution(table.keys.copy(), S_out, status, n_frames, spread, n_out, rounds)
    diagnostics = dict(result.diagnostics)
    diagnostics["rig_extrinsics"] = {"mode": opts.rig_extrinsics, "rounds": rounds,
                                     "sensors": {s: int((status == s).sum()) for s in np.unique(status.astype(str))}}
    return replace(result, residuals_deg=residuals, sensors=sensors, diagnostics=diagnostics)


def solve_rig(graph: ViewGraph, opts: SolveOptions, callback=None) -> AveragingResult:
    """The rig solve of the module docstring, each frame-level solve the one pipeline of
    stages (:func:`.stages.run`) on that round's frame graph. The result is
    per image, with ``frames`` (the last frame-level solve) and ``sensors``
    (:class:`~.types.SensorSolution`). With gravity priors (``graph.gravity``: the frame
    graphs carry their frames') the joint refinement does not use them, so the final frames
    come from a last frame solve at the refined extrinsics (the extrinsics are those of the
    joint refinement)."""
    t0 = time.perf_counter()
    gravity = graph.gravity is not None
    rigs = graph.rigs
    table = sensor_table(rigs, opts.rig_extrinsics)
    sensor = table.of_image
    info = graph.information if opts.use_information else None

    def per_image(S):
        out = rigs.cam_from_rig.copy()
        has = sensor >= 0
        out[has] = S[sensor[has]]  # NaN rows (not yet estimated / unobservable): frames of their own
        return out

    qall = graph.relative_quaternion_rows()  # once, for every frame problem of this solve

    def frame_solve(S, o=opts, full=True, start=None, image_graph=graph, qrel=qall):
        """The frame-level solve at the extrinsics ``S``; ``start`` (n, 3, 3): image rotations
        of the previous round (NaN: unsolved), the frames' start (each frame the chordal mean
        of its images' ``S_a^T R_a``) in place of the spanning tree / chordal start; ``qrel``
        the relative rotations of ``image_graph`` as quaternion rows."""
        problem = frame_problem(image_graph, per_image(S), qrel)
        if problem is None:  # every image a frame of its own with identity extrinsics
            problem = lone_frames(image_graph)
        frame_graph = problem.frame_graph
        if start is not None and not gravity and o.init == "auto" and o.method in WARM_START_METHODS:
            ok = np.isfinite(start).all(axis=(1, 2))
            groups, means = _frame_means(np.swapaxes(problem.cam_from_rig[ok], 1, 2) @ start[ok], problem.group[ok])
            F0 = np.full((frame_graph.n_nodes, 3, 3), np.nan)
            F0[groups] = means
            frame_graph = copy.copy(frame_graph)  # (dataclasses.replace would make its quaternions matrices)
            frame_graph.initial_cam_from_world = F0
            o = replace(o, init="vertices")
        return problem, run(frame_graph, o, callback, full=full)

    res0, threshold, S, samples = _round0(graph, table, opts, qall, frame_solve)
    status, free, unobservable = _sensor_status(table, samples, S)
    problem, fres, S, rounds = _refinement_rounds(graph, frame_solve, per_image, sensor, S, free, threshold, info,
                                                  res0.cam_from_world)
    # the image-level result at the refined frames and extrinsics
    if gravity:  # frames that respect their gravity priors, at the final extrinsics
        problem, fres = frame_solve(S)
    else:
        final = frame_problem(graph, per_image(S), qall)  # the same frames, the final extrinsics
        if final is not None and len(final.edge_index) == len(problem.edge_index):
            problem = final
    result = problem.image_result(fres, time.perf_counter() - t0)
    return _with_sensors(graph, opts, result, table, S, status, unobservable, samples, threshold, rounds)
