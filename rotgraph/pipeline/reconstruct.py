"""``rotgraph reconstruct``: COLMAP 4's own global pipeline (GLOMAP, merged into COLMAP)
run from rotgraph's rotations (issue #18 item 2).

COLMAP's ``GlobalPipeline`` runs ``GlobalMapper::Solve`` (colmap
``src/colmap/sfm/global_mapper.cc``): rotation averaging, track establishment, global
positioning, iterative bundle adjustment, iterative retriangulation and refinement, then
``AlignReconstructionToOrigRigScales`` (``src/colmap/controllers/global_pipeline.cc``).
pycolmap 4.2.1 has no way to hand that pipeline rotations: ``GlobalPipeline.run`` makes a
new reconstruction and loads it from its ``DatabaseCache`` (``Reconstruction::Load``: frames
without poses; the database stores none), ``skip_rotation_averaging`` then leaves every frame
unregistered, the ``MODEL_UPDATE_CALLBACK`` first fires after global positioning, pose
priors carry positions and gravity only, and the ``GlobalMapper`` class is not bound. What
the pipeline does read is the pose graph: ``PoseGraph::Load`` takes every pair of the
correspondence graph whose two-view geometry has a ``cam2_from_cam1``
(``src/colmap/scene/pose_graph.cc``), and rotation averaging solves on their rotations.

So :func:`reconstruct` gives COLMAP's rotation averaging a pose graph whose only solution is
rotgraph's rotations, and lets the pipeline run unchanged:

1. **Rotations** -- rotgraph: ``read_view_graph`` + ``average_rotations`` with
   ``default_options("colmap")`` (rig-aware: its images' rotations are rig-consistent).
2. **Pose graph** (:func:`consistent_pairs`) -- as COLMAP's ``FilterEdgesByRelativeRotation``
   does after its rotation averaging, a pair whose measured rotation disagrees with the
   solved ones by more than ``rotation_averaging.max_rotation_error_deg`` (10 deg) is
   dropped, and so is every pair of an unsolved image or outside the largest connected
   component of frames. In a private copy of the database
   (:func:`rotgraph.io.colmap_project.database_copy`: the user's file is never opened by pycolmap)
   every kept pair's ``cam2_from_cam1`` rotation becomes ``R_2 R_1^T`` of rotgraph's
   rotations (its stored translation kept: global positioning uses tracks, not pair
   translations), every other pair's pose is cleared (``NULL``: out of the pose graph, its
   inlier matches still in the correspondence graph that retriangulation uses), and the
   pipeline runs with ``decompose_relative_pose = False`` (nothing re-derived from E/F/H).
   Extrinsics rotgraph estimated or refined over stored ones replace those in the copy's
   rigs (rotation only: the stored translation is kept); sensors with none stored are left
   to COLMAP's averaging, which finds rotgraph's from the pairs.
3. **COLMAP's global pipeline** -- ``pycolmap.GlobalPipeline(options, copy, manager).run()``
   with ``pycolmap.GlobalPipelineOptions()`` (``mapper`` = the mapper options). Its rotation
   averaging (spanning-tree start, L1, IRLS) meets zero residuals on every pair and returns
   rotgraph's rotations up to a global rotation (measured: 1e-14 deg, rigs included; the
   summary's ``rotations_start_max_deg``, measured when global positioning reports, a
   warning above 1e-6 deg); its 10 deg
   filter then drops nothing. Everything after -- tracks, global positioning, bundle
   adjustment, retriangulation, the rig scales -- is global_mapping's own code.

The stage times come from the pipeline's ``MODEL_UPDATE_CALLBACK`` (after global positioning,
after each bundle-adjustment round, after retriangulation). The model is the largest
connected component (rotgraph solves that one); COLMAP with ``multiple_models`` would also
reconstruct the others separately.
"""

from __future__ import annotations

import contextlib
import logging
import time
from pathlib import Path

import numpy as np

from .. import so3, so3_checks
from ..errors import InputError, UnsolvableError
from ..io.colmap_tables import pair_ids
from ..graph_analysis import connected_components

__all__ = ["consistent_pairs", "default_mapper_options", "model_errors", "reconstruct"]

logger = logging.getLogger(__name__)

def default_mapper_options(seed: int | None = None, num_threads: int | None = None):
    """``pycolmap.GlobalMapperOptions`` as ``pycolmap.global_mapping`` runs them: the
    defaults of ``GlobalPipelineOptions().mapper`` with the pipeline's ``num_threads`` and
    ``random_seed`` (``seed``: None = COLMAP's default, -1, random)."""
    from ..io.colmap_project import import_pycolmap

    pycolmap = import_pycolmap()
    pipe = pycolmap.GlobalPipelineOptions()
    mapper = pipe.mapper
    mapper.num_threads = pipe.num_threads if num_threads is None else int(num_threads)
    mapper.random_seed = pipe.random_seed if seed is None else int(seed)
    return mapper


@contextlib.contextmanager
def _pycolmap_log(level: int):
    """pycolmap's (glog) messages at ``level`` and above only, for the duration."""
    from ..io.colmap_project import import_pycolmap

    log = getattr(import_pycolmap(), "logging", None)
    if log is None:  # pragma: no cover
        yield
        return
    old = log.minloglevel
    log.minloglevel = level
    try:
        yield
    finally:
        log.minloglevel = old


# =========================================================================== pose graph


def _largest_component(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The nodes (sorted) of the largest connected component of the edges ``a[k]-b[k]``."""
    if not len(a):
        return np.zeros(0, dtype=np.int64)
    nodes, inv = np.unique(np.concatenate([a, b]), return_inverse=True)
    m = len(a)
    _, labels = connected_components(len(nodes), np.stack([inv[:m], inv[m:]], axis=1))
    best = np.bincount(labels).argmax()
    return nodes[labels == best].astype(np.int64)


def consistent_pairs(graph, result, max_rotation_error_deg: float) -> tuple[np.ndarray, np.ndarray, dict]:
    """The pose graph COLMAP's rotation averaging is given (module docstring, step 2).

    ``graph``: the view graph read from the database; ``result``: rotgraph's image-level
    :class:`~rotgraph.estimators.types.AveragingResult` of it. A pair is kept when both
    images are solved, its measured ``cam2_from_cam1`` is within ``max_rotation_error_deg``
    of the solved rotations (no test when that is <= 0) and its frames are in the largest
    connected component of the kept pairs. Returns ``(pair_ids, cam2_from_cam1, counts)``:
    COLMAP's pair id of each kept pair (the smaller image id first) and the rotation
    ``R_2 R_1^T`` of its two images' solved rotations in that order (k, 3, 3)."""
    ids = graph.node_ids.astype(np.int64)
    ea, eb = graph.edges[:, 0], graph.edges[:, 1]
    R = np.asarray(result.cam_from_world, dtype=np.float64)
    solved = np.asarray(result.solved, dtype=bool)
    posed = solved[ea] & solved[eb]
    err = np.where(posed, np.nan_to_num(result.residuals_deg, nan=np.inf), np.inf)  # each pair's rotation angle
    valid = posed & ((err <= max_rotation_error_deg) if max_rotation_error_deg > 0 else True)
    frames = ids if graph.rigs is None else np.asarray(graph.rigs.frame_ids, dtype=np.int64)
    keep_frames = _largest_component(frames[ea[valid]], frames[eb[valid]])
    n_filtered = int((posed & ~valid).sum())
    valid &= np.isin(frames[ea], keep_frames) & np.isin(frames[eb], keep_frames)
    lo = np.where(ids[ea] < ids[eb], ea, eb)[valid]
    hi = np.where(ids[ea] < ids[eb], eb, ea)[valid]
    pids, first = np.unique(pair_ids(ids[lo], ids[hi]), return_index=True)  # COLMAP pairs are unique
    lo, hi = lo[first], hi[first]
    rel = R[hi] @ np.swapaxes(R[lo], 1, 2)
    counts = {"n_pairs": len(ea), "n_pairs_valid": int(valid.sum()), "n_pairs_rotation_filtered": n_filtered,
              "n_frames_deregistered": int(len(np.unique(frames[solved])) - len(keep_frames))}
    return pids, rel, counts


def _start_deviation(rec, image_ids: np.ndarray, R: np.ndarray) -> float:
    """Largest angle (deg) between the rotations of ``rec``'s posed images and rotgraph's
    (``R`` of ``image_ids``), after the one global rotation that maps the first onto the
    first: 0 when COLMAP's pipeline runs from rotgraph's rotations."""
    rows = {int(i): k for k, i in enumerate(image_ids.tolist())}
    got = [(rows[int(i)], im.cam_from_world().rotation) for i, im in rec.images.items()
           if im.has_pose and int(i) in rows and np.isfinite(R[rows[int(i)]]).all()]
    if not got:
        return float("nan")
    k = np.array([r for r, _ in got])
    W = np.swapaxes(R[k], 1, 2) @ so3.from_pycolmap([q for _, q in got])  # world gauge per image
    return float(np.degrees(so3.angle_between(W, np.broadcast_to(W[0], W.shape))).max())


# =========================================================================== evaluation


def _umeyama(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Similarity ``dst ~ s R src + t`` of least squares (Umeyama 1991, TPAMI 13(4))."""
    mu_s, mu_d = src.mean(0), dst.mean(0)
    S, D = src - mu_s, dst - mu_d
    cov = D.T @ S / len(src)
    R = so3_checks.project_to_so3(cov)  # U diag(1, 1, det(U V^T)) V^T of cov's SVD
    var = (S**2).sum() / len(src)
    s = float(np.trace(R.T @ cov) / var) if var > 0 else 1.0  # = sum sigma_i diag_i
    return s, R, mu_d - s * R @ mu_s


def model_errors(estimate, ground_truth) -> dict:
    """Errors of a reconstruction against a ground-truth model, images matched by name.

    ``estimate``, ``ground_truth``: ``pycolmap.Reconstruction`` or model folders (``estimate``
    also ``{image name: cam_from_world (3, 3)}``: rotations only, no position error). Rotation
    error: rotgraph's evaluator (:func:`rotgraph.evaluate.compare_rotations`: the gauge
    rotation of least geodesic L1 error, then per-image angle). Position error: camera
    centres after the least-squares similarity (Umeyama) onto the ground truth, in the
    ground truth's units; ``position_median_rel`` divides by the median distance of the
    ground-truth centres from their centroid. Images not registered in the estimate count
    in ``n_missing`` (not in the statistics)."""
    from ..evaluate import compare_rotations
    from ..io.colmap_project import import_pycolmap

    from ..io.colmap_model import read_model

    pycolmap = import_pycolmap()
    gt = ground_truth if isinstance(ground_truth, pycolmap.Reconstruction) else read_model(Path(ground_truth))
    rotations_only = isinstance(estimate, dict)
    if rotations_only:
        e_rot = {str(n): np.asarray(r, dtype=np.float64) for n, r in estimate.items() if np.isfinite(r).all()}
    else:
        est = estimate if isinstance(estimate, pycolmap.Reconstruction) else read_model(Path(estimate))
        e_by = {im.name: im for im in est.images.values() if im.has_pose}
        e_rot = {name: so3.from_pycolmap(im.cam_from_world().rotation) for name, im in e_by.items()}
    g_by = {im.name: im for im in gt.images.values() if im.has_pose}
    names = sorted(set(e_rot) & set(g_by))
    out = {"n_ground_truth": len(g_by), "n_registered": len(e_rot), "n_evaluated": len(names),
           "n_missing": len(set(g_by) - set(e_rot))}
    no_positions = {} if rotations_only else dict(position_median=float("nan"), position_mean=float("nan"),
                                                  position_median_rel=float("nan"))
    if len(names) < 3:
        out.update(rotation_median_deg=float("nan"), rotation_mean_deg=float("nan"), **no_positions)
        return out
    Rg = np.stack([so3.from_pycolmap(g_by[n].cam_from_world().rotation) for n in names])
    r = compare_rotations(np.stack([e_rot[n] for n in names]), Rg)
    out.update(rotation_median_deg=r.median, rotation_mean_deg=r.mean)
    if rotations_only:
        return out
    Ce = np.stack([np.asarray(e_by[n].projection_center(), float) for n in names])
    Cg = np.stack([np.asarray(g_by[n].projection_center(), float) for n in names])
    ok = np.isfinite(Ce).all(axis=1) & np.isfinite(Cg).all(axis=1)
    if ok.sum() < 3 or np.ptp(Ce[ok], axis=0).max() <= 0:  # no positions (e.g. rotations only)
        out.update(no_positions)
        return out
    Ce, Cg = Ce[ok], Cg[ok]
    s, R, t = _umeyama(Ce, Cg)
    d = np.linalg.norm((s * Ce @ R.T + t) - Cg, axis=1)
    scale = float(np.median(np.linalg.norm(Cg - Cg.mean(0), axis=1))) or 1.0
    out.update(position_median=float(np.median(d)), position_mean=float(d.mean()),
               position_median_rel=float(np.median(d)) / scale)
    return out


# =========================================================================== the command


def _check_output(output, project: Path, overwrite: bool = False, ground_truth=None) -> Path:
    """The model folder ``output``: a folder (or to be made), not the project, its sparse
    model or the ground truth, somewhere writable, not holding a reconstruction unless
    ``overwrite`` (:func:`~rotgraph.pipeline.solve.check_model_folder`, the one check of
    model outputs)."""
    from .solve import check_model_folder

    out = Path(output)
    check_model_folder(out, project, overwrite, other_inputs=[ground_truth] if ground_truth not in (None, "auto") else ())
    return out


def _check_project(project: Path, output, overwrite: bool, ground_truth) -> tuple[Path, Path, Path | None]:
    """The checks of :func:`reconstruct`'s inputs before any work: ``(database, output
    folder, ground-truth model or None)``."""
    from ..io.colmap_project import find_colmap_project

    if not project.exists():
        raise InputError("no such file or folder", path=str(project))
    db_path, model_path = find_colmap_project(project)
    if db_path is None:
        raise InputError("no COLMAP database here (reconstruct needs database.db: its matches and two-view geometries)",
                         path=str(project))
    out = _check_output(output, project, overwrite, ground_truth)
    gt_model = model_path if ground_truth == "auto" else (Path(ground_truth) if ground_truth else None)
    if ground_truth not in ("auto", None) and not gt_model.exists():  # before the work, not after it
        raise InputError("no such ground-truth model", path=str(gt_model))
    return db_path, out, gt_model


def _pipeline_options(pycolmap, mapper_options, seed: int | None, num_threads: int | None):
    """``pycolmap.GlobalPipelineOptions`` for :func:`reconstruct` (module docstring, step 3);
    seeds COLMAP's generator when ``seed`` >= 0."""
    pipe_opts = pycolmap.GlobalPipelineOptions()
    pipe_opts.mapper = mapper_options if mapper_options is not None else default_mapper_options(seed, num_threads)
    mopts = pipe_opts.mapper  # the pipeline's copy: rotation averaging forced on here, not in the caller's options
    mopts.skip_rotation_averaging = False
    pipe_opts.num_threads = int(mopts.num_threads)
    pipe_opts.random_seed = int(mopts.random_seed)
    pipe_opts.decompose_relative_pose = False
    if seed is not None and int(seed) >= 0:
        pycolmap.set_random_seed(int(seed))
    return pipe_opts


def _model_updates(manager, mopts, image_ids: np.ndarray, R: np.ndarray):
    """``(marks, start, report)``: ``report`` is pycolmap's MODEL_UPDATE_CALLBACK (after global
    positioning, each BA round, retriangulation); it appends the time to ``marks`` and, the
    first time, puts :func:`_start_deviation` into ``start["deg"]``."""
    marks = []
    start = {"deg": float("nan")}

    def report():
        marks.append(time.perf_counter())
        if len(marks) == 1 and not mopts.skip_global_positioning:
            try:
                start["deg"] = _start_deviation(manager.get(0), image_ids, R)
            except Exception as exc:  # pragma: no cover - never into COLMAP's thread
                logger.warning("could not check the starting rotations: %s", exc)

    return marks, start, report


def _write_pose_graph(pycolmap, db, pair_ids: np.ndarray, rel: np.ndarray, sensors, summary: dict) -> None:
    """Into the private database copy: the pose graph's pair rotations and the extrinsics
    rotgraph estimated or refined over stored ones (module docstring, step 2)."""
    from ..io.colmap_output import set_extrinsics
    from ..io.colmap_project import write_pair_rotations

    summary["n_pairs_written"] = write_pair_rotations(pycolmap, db, pair_ids, rel)
    # Extrinsics rotgraph estimated or refined over stored ones go into the copy's rigs
    # too (translations kept): else COLMAP would average the pairs with the stored ones
    # and start 0.01 deg away. Sensors with none stored are left to COLMAP, which
    # estimates them from the pairs (exactly rotgraph's).
    n_ext, rigs = set_extrinsics(pycolmap, db.read_all_rigs(), sensors, stored_only=True)
    for rig in rigs:
        db.update_rig(rig)
    summary["n_extrinsics_written"] = n_ext


def _largest_model(manager, project: Path):
    """The model of most registered images the global mapper made (raises
    :class:`~rotgraph.errors.UnsolvableError` when it made none)."""
    if manager.size() == 0:
        raise UnsolvableError(f"{project}: COLMAP's global mapper failed (see its log: rotgraph reconstruct -v -v)")
    # one model: the pose graph is one connected component by construction (its
    # multiple_models stays as global_mapping runs it: the other path differs slightly)
    if manager.size() > 1:
        logger.warning("COLMAP's global mapper made %d models: the largest is written", manager.size())
    return max((manager.get(k) for k in range(manager.size())), key=lambda r: r.num_reg_images())


def _mapper_stage_times(marks: list, t0: float, mopts, times: dict) -> None:
    """``times`` of the global mapper's stages from the model-update ``marks`` (the mapper
    started at ``t0``; a skipped stage has no mark)."""
    gp, rt = not mopts.skip_global_positioning, not mopts.skip_retriangulation
    t_prev = t0
    if gp and marks:
        times["global_positioning"], t_prev = marks[0] - t0, marks[0]
    ba_marks = marks[int(gp): len(marks) - int(rt)]
    if ba_marks:
        times["bundle_adjustment"], t_prev = ba_marks[-1] - t_prev, ba_marks[-1]
    if rt and marks:
        times["retriangulation"] = marks[-1] - t_prev


def _model_counts(rec) -> dict:
    """The summary's counts of the model ``rec``."""
    return dict(
        n_registered=int(rec.num_reg_images()),
        n_frames_registered=int(rec.num_reg_frames()),
        n_points3D=int(rec.num_points3D()),
        n_observations=int(rec.compute_num_observations()),
        mean_reprojection_error=float(rec.compute_mean_reprojection_error()),
    )


def _evaluate(summary: dict, rec, graph, R: np.ndarray, gt_model: Path, ground_truth) -> None:
    """``summary``'s ``eval`` and ``eval_rotation_averaging`` against ``gt_model``; a ground
    truth found by ``"auto"`` that cannot be read is only a warning."""
    try:
        from ..io.colmap_model import read_model

        gt = read_model(Path(gt_model))  # once, for both evaluations
        summary["eval"] = model_errors(rec, gt)
        summary["eval_rotation_averaging"] = model_errors(
            {str(graph.names[k]): R[k] for k in range(graph.n_nodes)}, gt)
    except Exception as exc:  # a ground truth that cannot be read is no failure of the reconstruction
        if ground_truth not in ("auto", None):
            raise InputError(f"cannot read the ground-truth model: {exc}", path=str(gt_model)) from None
        logger.warning("ground truth not evaluated: %s", exc)


def reconstruct(project, output, options=None, *, mapper_options=None, overrides=None, seed: int | None = None,
                num_threads: int | None = None, text: bool = False, ground_truth="auto", callback=None,
                pycolmap_log_level: int = 2, overwrite: bool = False) -> dict:
    """Reconstruct the COLMAP project ``project`` (a folder with ``database.db``, or the
    database file) with COLMAP's global pipeline run from rotgraph's rotations (module
    docstring) and write the model into the folder ``output`` (``.bin``; ``text``: ``.txt``).

    ``options``: rotgraph's :class:`~rotgraph.estimators.types.SolveOptions` (None: what
    ``rotgraph solve`` uses on COLMAP input, ``default_options("colmap")``, with
    ``overrides``, a dict of fields, applied). ``mapper_options``: a
    ``pycolmap.GlobalMapperOptions`` (None: :func:`default_mapper_options` with ``seed``
    and ``num_threads``; its ``num_threads`` and ``random_seed`` are the pipeline's; the
    ``skip_*`` flags skip those stages, except rotation averaging, through which rotgraph's
    rotations enter). ``ground_truth``: a model folder, ``"auto"`` (the project's sparse
    model, when it has one) or None: with one, the summary has ``eval``
    (:func:`model_errors`) and ``eval_rotation_averaging`` (rotgraph's rotations alone).
    ``callback(stage)`` is called as each stage starts (``"rotations"``, ``"pose graph"``,
    ``"global mapper"``, then ``"write"``). pycolmap's log is limited to
    ``pycolmap_log_level`` (0 info, 1 warning, 2 error) meanwhile. An ``output`` that holds
    a COLMAP model other than a rotgraph rotations-only one (e.g. an earlier
    reconstruction) is refused before any work unless ``overwrite``.

    Returns a summary dict: the input (``n_images``, ``n_edges``, ``n_solved``,
    ``rotation_method``), the pose graph (``n_pairs``, ``n_pairs_valid``,
    ``n_pairs_rotation_filtered``, ``n_frames_deregistered``, ``n_pairs_written``,
    ``n_extrinsics_written``), the model (``n_registered``, ``n_frames_registered``,
    ``n_points3D``, ``n_observations``), ``rotations_start_max_deg`` (how far
    the rotations global positioning started from are from rotgraph's, after one global
    rotation; NaN when it was skipped), ``mean_reprojection_error``, ``seconds`` and
    ``seconds_<stage>`` (``rotations``, ``pose_graph`` (the private copy and pycolmap's
    cache), ``global_positioning`` (COLMAP's rotation averaging, tracks and global
    positioning), ``bundle_adjustment``, ``retriangulation``, ``write``). The user's database
    is only read (never opened by pycolmap). Raises :class:`~rotgraph.errors.InputError` for
    a bad project or output and :class:`~rotgraph.errors.UnsolvableError` when the pipeline
    fails.
    """

    from ..estimators.rotation_averaging import average_rotations
    from ..io.colmap_output import write_model_folder
    from ..io.colmap_project import database_copy, import_pycolmap, one_line
    from .read import read_view_graph
    from .solve import resolve_options, wants_information

    pycolmap = import_pycolmap()
    project = Path(project)
    db_path, out, gt_model = _check_project(project, output, overwrite, ground_truth)
    stage = callback or (lambda name: None)
    times = {}
    t_all = time.perf_counter()

    # 1. rotations
    stage("rotations")
    t0 = time.perf_counter()
    graph = read_view_graph(db_path, fmt="colmap", uncertainty=wants_information(options, overrides))
    opts = resolve_options(graph, options, overrides)
    res = average_rotations(graph, opts)
    times["rotations"] = time.perf_counter() - t0

    pipe_opts = _pipeline_options(pycolmap, mapper_options, seed, num_threads)
    mopts = pipe_opts.mapper
    summary = {"project": str(project), "output": str(out), "n_images": int(graph.n_nodes), "n_edges": int(graph.n_edges),
               "n_solved": int(res.solved.sum()), "rotation_method": res.method}

    # 2. the pose graph whose only solution is rotgraph's rotations
    stage("pose graph")
    t0 = time.perf_counter()
    pair_ids, rel, counts = consistent_pairs(graph, res, float(mopts.rotation_averaging.max_rotation_error_deg))
    summary.update(counts)
    if counts["n_pairs_valid"] == 0:
        raise UnsolvableError(f"{project}: fewer than 2 frames left after rotation averaging")
    R = res.cam_from_world  # NaN rows: unsolved
    manager = pycolmap.ReconstructionManager()
    marks, start, report = _model_updates(manager, mopts, graph.node_ids.astype(np.int64), R)

    with _pycolmap_log(pycolmap_log_level), database_copy(db_path) as db:
        _write_pose_graph(pycolmap, db, pair_ids, rel, res.sensors, summary)
        try:
            pipeline = pycolmap.GlobalPipeline(pipe_opts, db, manager)
        except Exception as exc:
            raise InputError(f"pycolmap cannot read the database: {one_line(exc)}", path=str(db_path)) from None
        pipeline.add_callback(pycolmap.GlobalPipelineCallback.MODEL_UPDATE_CALLBACK, report)
        times["pose_graph"] = time.perf_counter() - t0

        # 3. COLMAP's global mapper: rotation averaging (rotgraph's rotations), tracks, global
        #    positioning, bundle adjustment, retriangulation, the rigs' scales
        stage("global mapper")
        t0 = time.perf_counter()
        try:
            pipeline.run()
        except Exception as exc:  # a failed check inside COLMAP (its log says more)
            raise UnsolvableError(f"{project}: COLMAP's global mapper failed: {one_line(exc)}") from None
    rec = _largest_model(manager, project)
    _mapper_stage_times(marks, t0, mopts, times)
    summary["rotations_start_max_deg"] = start["deg"]
    if np.isfinite(start["deg"]) and start["deg"] > 1e-6:
        logger.warning("COLMAP's global positioning started %.2g deg from rotgraph's rotations", start["deg"])

    stage("write")
    t0 = time.perf_counter()
    write_model_folder(rec, out, text)
    times["write"] = time.perf_counter() - t0
    summary.update(_model_counts(rec), seconds=time.perf_counter() - t_all)
    summary.update({f"seconds_{k}": v for k, v in times.items()})
    if gt_model is not None:
        _evaluate(summary, rec, graph, R, gt_model, ground_truth)
    return summary
