"""``rotgraph reconstruct``: COLMAP 4's global pipeline (GLOMAP, merged into COLMAP) continued
from rotgraph's rotations, with pycolmap's own components (issue #18 item 2).

COLMAP's ``GlobalPipeline`` runs ``GlobalMapper::Solve`` (colmap ``src/colmap/sfm/global_mapper.cc``):
rotation averaging, track establishment, global positioning, iterative bundle adjustment,
iterative retriangulation and refinement, then ``AlignReconstructionToOrigRigScales``.
pycolmap 4.2.1 exposes neither the ``GlobalMapper`` class nor a way to hand the pipeline
given rotations (``GlobalPipeline.run`` starts from a new, empty reconstruction), so
:func:`reconstruct` runs the same stages itself, in the same order, with the same options
(``pycolmap.GlobalPipelineOptions().mapper`` unless given) and the same pycolmap calls:

1. **Rotations** -- rotgraph: ``read_view_graph`` + ``average_rotations`` with
   ``default_options("colmap")`` (rig-aware; estimated ``sensor_from_rig`` written into the
   rigs). This replaces COLMAP's two ``RunRotationAveraging`` passes.
2. **Reconstruction and pose graph** -- ``pycolmap.DatabaseCache.create`` on a private copy of
   the database (:func:`rotgraph.io.colmap._database_copy`: the user's file is never opened
   by pycolmap), ``Reconstruction.load(cache)``; frames' ``rig_from_world`` rotations set
   from rotgraph's (:func:`rotgraph.io.colmap_model.write_to_reconstruction`, zero
   translations) and registered. A ``pycolmap.PoseGraph`` of the view graph's pairs
   (``cam2_from_cam1`` = the measured relative rotation, ``num_matches`` = inliers). As COLMAP's
   ``FilterEdgesByRelativeRotation`` does after its rotation averaging, pairs whose measured
   rotation disagrees with the solved rotations by more than
   ``rotation_averaging.max_rotation_error_deg`` (10 deg) are invalidated, then every pair
   and frame outside the largest connected component of registered frames.
3. **Tracks** -- ``GlobalMapper::EstablishTracks``, which pycolmap does not expose, vectorised
   (:func:`establish_tracks`): the inlier matches of every valid pair
   (``CorrespondenceGraph.extract_matches_between_images``) joined into tracks by
   connected components (scipy, COLMAP: union-find), a track dropped when two of its
   observations in one image are more than ``track_intra_image_consistency_threshold``
   pixels apart, kept when it spans ``>= track_min_num_views_per_track`` images, longest
   first (``keep_max_num_tracks``, ``track_required_tracks_per_view`` as COLMAP).
4. **Global positioning** -- ``pycolmap.run_global_positioning(options.get_global_positioning(),
   pose_graph, reconstruction)`` and ``GlobalMapper::GlobalPositioning``'s filters with
   ``pycolmap.ObservationManager`` (angular error 2x, the strict angular pass for cameras
   with a prior focal length, triangulation angle, normalized error 10x), ``normalize()``.
5. **Bundle adjustment** -- ``GlobalMapper::IterativeBundleAdjustment``: ``ba_num_iterations``
   rounds of ``pycolmap.create_default_bundle_adjuster`` (all posed images, gauge
   ``TWO_CAMS_FROM_WORLD``), a rotation-fixed stage then the joint one, with COLMAP's
   tightening reprojection filters.
6. **Retriangulation** -- ``GlobalMapper::IterativeRetriangulateAndRefine``:
   ``delete_all_points2D_and_points3D``, ``pycolmap.IncrementalMapper(cache)``
   ``triangulate_image`` of every registered image, ``iterative_global_refinement(5, 0.0005)``
   (whose bundle adjustments move the 3D points only: pycolmap 4.2.1's options there, read off
   global_mapping's log), filters, a last bundle adjustment (the poses), ``normalize``, filters.
7. ``pycolmap.align_reconstruction_to_orig_rig_scales`` and ``update_point_3d_errors``; the
   model is written (``.bin``, or ``.txt``) into a temporary folder inside the output
   folder and its files moved into place.

No bundle adjuster, positioner or triangulator of rotgraph's own is involved: only the
rotations (and the track glue of step 3) differ from ``pycolmap.global_mapping``. The model
is the largest connected component (rotgraph solves that one); COLMAP with
``multiple_models`` would also reconstruct the others separately.
"""

from __future__ import annotations

import contextlib
import logging
import os
import time
from pathlib import Path

import numpy as np

from .. import so3
from ..errors import InputError, UnsolvableError

__all__ = ["reconstruct", "default_mapper_options", "establish_tracks", "model_errors"]

logger = logging.getLogger(__name__)

_INT_MAX = 2**31 - 1


def default_mapper_options(seed: int | None = None, num_threads: int | None = None):
    """``pycolmap.GlobalMapperOptions`` as ``pycolmap.global_mapping`` runs them: the
    defaults of ``GlobalPipelineOptions().mapper`` with the pipeline's ``num_threads`` and
    ``random_seed`` (``seed``: None = COLMAP's default, -1, random)."""
    from ..io.colmap import _pycolmap

    pycolmap = _pycolmap()
    pipe = pycolmap.GlobalPipelineOptions()
    mapper = pipe.mapper
    mapper.num_threads = pipe.num_threads if num_threads is None else int(num_threads)
    mapper.random_seed = pipe.random_seed if seed is None else int(seed)
    return mapper


@contextlib.contextmanager
def _pycolmap_log(level: int):
    """pycolmap's (glog) messages at ``level`` and above only, for the duration."""
    from ..io.colmap import _pycolmap

    log = getattr(_pycolmap(), "logging", None)
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


def _pair_ids(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """COLMAP's ``ImagePairToPairId`` (the smaller id first), vectorised."""
    lo, hi = np.minimum(a, b).astype(np.int64), np.maximum(a, b).astype(np.int64)
    return lo * _INT_MAX + hi


def _image_table(rec) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The images of ``rec``: ids (sorted), their frame ids, and their ``cam_from_world``
    rotations (n, 3, 3), NaN for images without a pose. One Python step per image."""
    items = sorted((int(i), im) for i, im in rec.images.items())
    ids = np.array([i for i, _ in items], dtype=np.int64)
    frames = np.array([int(im.frame_id) for _, im in items], dtype=np.int64)
    R = np.full((len(items), 3, 3), np.nan)
    posed = [k for k, (_, im) in enumerate(items) if im.has_pose]
    if posed:
        R[posed] = so3.from_pycolmap([items[k][1].cam_from_world().rotation for k in posed])
    return ids, frames, R


def _rows_of(ids: np.ndarray, query: np.ndarray) -> np.ndarray:
    """Row of each of ``query`` in the sorted ``ids``, -1 where it is not there."""
    k = np.searchsorted(ids, query).clip(0, max(len(ids) - 1, 0))
    return np.where((ids[k] == query) if len(ids) else np.zeros(len(query), dtype=bool), k, -1)


def _largest_component(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The nodes (sorted) of the largest connected component of the edges ``a[k]-b[k]``."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    if not len(a):
        return np.zeros(0, dtype=np.int64)
    nodes, inv = np.unique(np.concatenate([a, b]), return_inverse=True)
    m = len(a)
    A = sp.coo_matrix((np.ones(m), (inv[:m], inv[m:])), shape=(len(nodes), len(nodes)))
    _, labels = connected_components(A, directed=False)
    best = np.bincount(labels).argmax()
    return nodes[labels == best].astype(np.int64)


def build_pose_graph(pycolmap, rec, graph, max_rotation_error_deg: float):
    """The ``pycolmap.PoseGraph`` of ``graph``'s pairs, filtered as COLMAP's rotation
    averaging leaves it (module docstring, step 2); frames outside the largest component
    de-registered. Returns ``(pose_graph, counts)``."""
    ids = graph.node_ids.astype(np.int64)
    a, b = ids[graph.edges[:, 0]], ids[graph.edges[:, 1]]
    image_ids, frame_ids, R = _image_table(rec)
    ka, kb = _rows_of(image_ids, a), _rows_of(image_ids, b)
    if (ka < 0).any() or (kb < 0).any():
        e = int(np.flatnonzero((ka < 0) | (kb < 0))[0])
        raise ValueError(f"pair ({a[e]}, {b[e]}) of an image the reconstruction does not have")
    posed = np.isfinite(R[ka, 0, 0]) & np.isfinite(R[kb, 0, 0])
    err = np.full(len(a), np.inf)
    if posed.any():
        Ra, Rb = R[ka[posed]], R[kb[posed]]
        err[posed] = np.degrees(so3.angle_between(graph.cam2_from_cam1[posed], Rb @ np.swapaxes(Ra, 1, 2)))
    valid = posed & ((err <= max_rotation_error_deg) if max_rotation_error_deg > 0 else True)
    fa, fb = frame_ids[ka], frame_ids[kb]
    keep_frames = _largest_component(fa[valid], fb[valid])
    in_comp = np.isin(fa, keep_frames) & np.isin(fb, keep_frames)
    n_filtered = int((posed & ~valid).sum())
    valid &= in_comp
    reg_frames = np.array(sorted(int(f) for f in rec.reg_frame_ids()), dtype=np.int64)
    for fid in reg_frames[~np.isin(reg_frames, keep_frames)].tolist():
        rec.deregister_frame(fid)
    pg = pycolmap.PoseGraph()
    pids = _pair_ids(a, b)
    _, first = np.unique(pids, return_index=True)  # COLMAP pairs are unique; a graph read otherwise: first one
    first = np.sort(first)
    w = graph.weights
    matches = np.where(np.isfinite(w), w, 0).astype(np.int64)
    zero = np.zeros(3)
    Rigid, Edge = pycolmap.Rigid3d, pycolmap.PoseGraphEdge
    for k, rot in zip(first.tolist(), so3.to_pycolmap(graph.cam2_from_cam1[first])):
        edge = Edge(Rigid(rot, zero))
        edge.num_matches = int(matches[k])
        pg.add_edge(int(a[k]), int(b[k]), edge)
        if not valid[k]:
            pg.set_invalid_edge(int(pids[k]))
    return pg, {"n_pairs": int(len(a)), "n_pairs_valid": int(valid.sum()), "n_pairs_rotation_filtered": n_filtered,
                "n_frames_deregistered": int(len(np.unique(frame_ids)) - len(keep_frames))}


# =========================================================================== tracks


def establish_tracks(pycolmap, rec, cache, pose_graph, options, keypoints=None) -> dict:
    """COLMAP's ``GlobalMapper::EstablishTracks`` (module docstring, step 3), vectorised:
    adds the tracks to ``rec`` as 3D points (at the origin: global positioning places them).
    ``options``: a ``pycolmap.GlobalMapperOptions``; ``keypoints``: the images' keypoints
    (the points2D of ``rec``), ``image_id -> (n, >= 2) array`` as a callable (e.g. a
    database's ``read_keypoints``) or a dict; asked only for the images where a track has
    two observations (the consistency check needs their coordinates). None: read from
    ``rec`` (a Python step per point, slower). Returns counts."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    if rec.num_points3D() != 0:
        raise ValueError("establish_tracks needs a reconstruction without 3D points")
    reg = np.array(sorted(int(i) for i in rec.reg_image_ids()), dtype=np.int64)
    n_pts = np.array([rec.image(int(i)).num_points2D() for i in reg], dtype=np.int64)
    offset = np.concatenate([[0], np.cumsum(n_pts)])
    cg = cache.correspondence_graph
    pids = np.array([int(pid) for pid, edge in pose_graph.edges.items() if edge.valid], dtype=np.int64)
    first, second = pids // _INT_MAX, pids % _INT_MAX  # COLMAP's PairIdToImagePair
    k1 = np.searchsorted(reg, first).clip(0, max(len(reg) - 1, 0))
    k2 = np.searchsorted(reg, second).clip(0, max(len(reg) - 1, 0))
    bad = (reg[k1] != first) | (reg[k2] != second) if len(reg) else np.ones(len(pids), dtype=bool)
    if bad.any():
        p = int(np.flatnonzero(bad)[0])
        raise ValueError(f"valid pair ({first[p]}, {second[p]}) of an unregistered image")
    extract = cg.extract_matches_between_images
    ms = [np.asarray(extract(int(a), int(b)), dtype=np.int64).reshape(-1, 2) for a, b in zip(first.tolist(), second.tolist())]
    lens = np.array([len(m) for m in ms], dtype=np.int64)
    m = np.concatenate(ms) if ms else np.zeros((0, 2), np.int64)
    rows = m[:, 0] + np.repeat(offset[k1], lens)
    cols = m[:, 1] + np.repeat(offset[k2], lens)
    n = int(offset[-1])
    counts = {"n_track_observations": 0, "n_tracks_established": 0, "n_tracks_inconsistent": 0, "n_tracks": 0}
    if not len(rows):
        return counts
    A = sp.coo_matrix((np.ones(len(rows), dtype=np.int8), (rows, cols)), shape=(n, n))
    _, labels = connected_components(A, directed=False)
    used = np.zeros(n, dtype=bool)
    used[rows] = True
    used[cols] = True
    obs = np.flatnonzero(used)  # the observations in some match
    lab = labels[obs]
    order = np.lexsort((obs, lab))
    obs, lab = obs[order], lab[order]
    img_k = np.searchsorted(offset, obs, side="right") - 1  # index into reg
    pt_idx = obs - offset[img_k]
    starts = np.flatnonzero(np.r_[True, lab[1:] != lab[:-1]])
    track_of = np.cumsum(np.r_[True, lab[1:] != lab[:-1]]) - 1  # per observation: its track
    length = np.diff(np.r_[starts, len(obs)])
    counts["n_track_observations"] = int(len(obs))  # COLMAP's log: "Established T tracks from N observations"
    counts["n_tracks_established"] = int(len(starts))
    # Images spanned and the intra-image consistency: (track, image) groups of > 1 observation.
    ti = track_of * (len(reg) + 1) + img_k  # sorted: by track, then image (obs increase within a track)
    first = np.flatnonzero(np.r_[True, ti[1:] != ti[:-1]])
    uniq, group_size = ti[first], np.diff(np.r_[first, len(ti)])
    n_images = np.bincount(track_of[first], minlength=len(starts))
    bad = np.zeros(len(starts), dtype=bool)
    multi = np.flatnonzero(group_size > 1)
    if len(multi):
        thr2 = float(options.track_intra_image_consistency_threshold) ** 2
        g_of = np.searchsorted(uniq, ti)
        sel = np.flatnonzero(np.isin(g_of, multi))  # observations in a multi-observation group
        xy = np.empty((len(sel), 2))
        lookup = keypoints.get if isinstance(keypoints, dict) else keypoints
        sel_img = img_k[sel]
        by_img = np.argsort(sel_img, kind="stable")
        cut = np.flatnonzero(np.r_[True, sel_img[by_img][1:] != sel_img[by_img][:-1], True])
        for a, b in zip(cut[:-1].tolist(), cut[1:].tolist()):  # per image, numpy per keypoint
            at = by_img[a:b]
            k = int(sel_img[at[0]])
            iid = int(reg[k])
            try:
                kp = lookup(iid) if lookup is not None else None
            except Exception:  # unreadable: the reconstruction's own points2D below
                kp = None
            if kp is not None and len(kp) == n_pts[k]:
                xy[at] = np.asarray(kp, dtype=np.float64)[pt_idx[sel[at]], :2]
            else:
                im = rec.image(iid)
                xy[at] = [im.point2D(int(j)).xy for j in pt_idx[sel[at]]]
        gid = g_of[sel]
        o = np.argsort(gid, kind="stable")
        sel, gid, xy = sel[o], gid[o], xy[o]
        gstart = np.flatnonzero(np.r_[True, gid[1:] != gid[:-1]])
        gsize = np.diff(np.r_[gstart, len(gid)])
        # A group's diameter exceeds the threshold when its bounding box has a side longer than
        # it (surely) and not when the box's diagonal is within it; only the rest need pairs.
        lo = np.minimum.reduceat(xy, gstart, axis=0)
        hi = np.maximum.reduceat(xy, gstart, axis=0)
        side2 = (hi - lo) ** 2
        surely = side2.max(axis=1) > thr2
        bad[track_of[sel[gstart[surely]]]] = True
        unsure = ~surely & (side2.sum(axis=1) > thr2)
        for size in np.unique(gsize[unsure]).tolist():  # groups of one size at a time: all their pairs at once
            starts_s = gstart[unsure & (gsize == size)]
            idx = starts_s[:, None] + np.arange(size)[None, :]  # (groups, size)
            P = xy[idx]
            d2 = ((P[:, :, None, :] - P[:, None, :, :]) ** 2).sum(axis=-1)
            far = (d2 > thr2).any(axis=(1, 2))
            bad[track_of[sel[starts_s[far]]]] = True
    counts["n_tracks_inconsistent"] = int(bad.sum())
    keep = np.flatnonzero(~bad & (n_images >= int(options.track_min_num_views_per_track)))
    keep = keep[np.argsort(-length[keep], kind="stable")]  # longest first
    max_tracks = int(options.keep_max_num_tracks)
    required = int(options.track_required_tracks_per_view)
    if required < _INT_MAX:  # COLMAP's greedy selection: until every image has `required` tracks
        per_image = np.zeros(len(reg), dtype=np.int64)
        images_left = len(reg)
        chosen = []
        for t in keep:
            if len(chosen) >= max_tracks:
                break
            ims = img_k[starts[t] : starts[t] + length[t]]
            if not (per_image[ims] <= required).any():
                continue
            for k in ims:  # COLMAP counts every observation
                if per_image[k] == required:
                    images_left -= 1
                per_image[k] += 1
            chosen.append(t)
            if images_left == 0:
                break
        keep = np.asarray(chosen, dtype=np.int64)
    else:
        keep = keep[:max_tracks]
    image_ids = reg[img_k]
    TE, Track = pycolmap.TrackElement, pycolmap.Track
    zero = np.zeros(3)
    for t in keep.tolist():
        s, e = starts[t], starts[t] + length[t]
        rec.add_point3D(zero, Track([TE(int(i), int(j)) for i, j in zip(image_ids[s:e], pt_idx[s:e])]))
    counts["n_tracks"] = int(len(keep))
    return counts


# =========================================================================== COLMAP's stages


def _bundle_adjust(pycolmap, ba_options, rec) -> bool:
    """COLMAP's ``RunBundleAdjustment`` (global_mapper.cc): every posed image, two cameras
    fixed for the gauge."""
    if rec.num_images() == 0 or rec.num_points3D() == 0:
        return False
    config = pycolmap.BundleAdjustmentConfig()
    for iid, im in rec.images.items():
        if im.has_pose:
            config.add_image(int(iid))
    config.fix_gauge(pycolmap.BundleAdjustmentGauge.TWO_CAMS_FROM_WORLD)
    ba = pycolmap.create_default_bundle_adjuster(ba_options, config, rec)
    return bool(ba.solve().is_solution_usable())


def _filter_reprojection(pycolmap, rec, max_error: float, kind: str) -> int:
    om = pycolmap.ObservationManager(rec)
    return int(om.filter_points3D_with_large_reprojection_error(max_error, rec.point3D_ids(),
                                                                getattr(pycolmap.ReprojectionErrorType, kind)))


def _filter_angle(pycolmap, rec, min_angle_deg: float) -> int:
    om = pycolmap.ObservationManager(rec)
    return int(om.filter_points3D_with_small_triangulation_angle(min_angle_deg, rec.point3D_ids()))


def _strict_angular_pass(pycolmap, rec, max_angular_deg: float) -> None:
    """``GlobalMapper::GlobalPositioning``'s second pass: observations of cameras with a
    prior focal length whose angular error exceeds ``max_angular_deg`` are deleted. When
    every camera has a prior this is ObservationManager's ANGULAR filter; when none has,
    nothing; mixed: per observation."""
    priors = {int(c): bool(cam.has_prior_focal_length) for c, cam in rec.cameras.items()}
    if not any(priors.values()):
        return
    if all(priors.values()):
        _filter_reprojection(pycolmap, rec, max_angular_deg, "ANGULAR")
        return
    max_rad = np.radians(max_angular_deg)
    doomed = []
    for pid, point in rec.points3D.items():
        for el in point.track.elements:
            im = rec.image(int(el.image_id))
            if not priors[int(im.camera_id)]:
                continue
            cam = rec.cameras[int(im.camera_id)]
            ray = cam.cam_ray_from_img(im.point2D(int(el.point2D_idx)).xy)
            x = im.cam_from_world() * point.xyz
            if ray is None:
                continue
            ray, x = np.asarray(ray, float), np.asarray(x, float)
            c = np.dot(ray, x) / max(np.linalg.norm(ray) * np.linalg.norm(x), 1e-300)
            if np.arccos(np.clip(c, -1.0, 1.0)) > max_rad:
                doomed.append((int(el.image_id), int(el.point2D_idx)))
    om = pycolmap.ObservationManager(rec)
    for iid, idx in doomed:
        if rec.image(iid).point2D(idx).has_point3D():
            om.delete_observation(iid, idx)


def _global_positioning(pycolmap, rec, pose_graph, opts) -> bool:
    if not pycolmap.run_global_positioning(opts.get_global_positioning(), pose_graph, rec):
        return False
    _filter_reprojection(pycolmap, rec, 2.0 * opts.max_angular_reproj_error_deg, "ANGULAR")
    _strict_angular_pass(pycolmap, rec, opts.max_angular_reproj_error_deg)
    _filter_angle(pycolmap, rec, opts.min_tri_angle_deg)
    _filter_reprojection(pycolmap, rec, 10.0 * opts.max_normalized_reproj_error, "NORMALIZED")
    rec.normalize()
    return True


def _iterative_bundle_adjustment(pycolmap, rec, opts) -> bool:
    """``GlobalMapper::IterativeBundleAdjustment``, line by line."""
    ba = opts.get_bundle_adjustment()
    n_iter = int(opts.ba_num_iterations)
    ite = 0
    while ite < n_iter:
        if not opts.ba_skip_fixed_rotation_stage:
            fixed = opts.get_bundle_adjustment()
            fixed.constant_rig_from_world_rotation = True
            if fixed.backend == pycolmap.BundleAdjustmentBackend.CASPAR:
                fixed.backend = pycolmap.BundleAdjustmentBackend.CERES
            if not _bundle_adjust(pycolmap, fixed, rec):
                return False
        if not opts.ba_skip_joint_optimization_stage:
            if not _bundle_adjust(pycolmap, ba, rec):
                return False
        rec.normalize()
        status = True
        filtered = 0
        while status and ite < n_iter:
            scaling = max(3 - ite, 1)
            filtered += _filter_reprojection(pycolmap, rec, scaling * opts.max_normalized_reproj_error, "NORMALIZED")
            if filtered > 1e-3 * rec.num_points3D():
                status = False
            else:
                ite += 1
        if status:  # fewer than 0.1 % of the tracks filtered: stop
            break
        ite += 1
    _filter_reprojection(pycolmap, rec, opts.max_normalized_reproj_error, "NORMALIZED")
    _filter_angle(pycolmap, rec, opts.min_tri_angle_deg)
    return True


def _retriangulate_and_refine(pycolmap, rec, cache, opts) -> bool:
    """``GlobalMapper::IterativeRetriangulateAndRefine``."""
    tri = opts.get_retriangulation()
    ba = opts.get_bundle_adjustment()
    rec.delete_all_points2D_and_points3D()
    mapper = pycolmap.IncrementalMapper(cache)
    mapper.begin_reconstruction(rec)
    for iid in sorted(int(i) for i in rec.reg_image_ids()):
        mapper.triangulate_image(tri, iid)
    custom = opts.get_bundle_adjustment()
    custom.print_summary = False
    if custom.ceres is not None:
        # As pycolmap 4.2.1's global_mapping runs this refinement (its verbose log, same
        # project: every one of the 5 bundle adjustments has "Schur complement static
        # structure <2,3,0>" and 3 x the points' count of parameters, i.e. points only,
        # poses, rigs and intrinsics constant, every point included; squared loss, initial
        # cost equal to ours to 2e-4; "Gradient tolerance reached ... <= 1"): only the final
        # bundle adjustment below moves the poses. With these options our log of the bundled
        # project repeats global_mapping's observation counts round by round (completed
        # 419/99/74/72, filtered 697/99/74/72/71, 2,505 observations in the end). Refining every pose here too (as this module did) took
        # 20+ Ceres iterations per round: rig3x20's retriangulation 2-5 s vs its 1.1-1.5 s.
        custom.ceres.loss_function_type = pycolmap.LossFunctionType.TRIVIAL
        so = custom.ceres.solver_options
        so.function_tolerance, so.gradient_tolerance, so.parameter_tolerance = 0.0, 1.0, 0.0
        so.max_num_iterations = 50
        so.max_linear_solver_iterations = 100
        custom.refine_rig_from_world = custom.refine_sensor_from_rig = False
        custom.refine_focal_length = custom.refine_principal_point = custom.refine_extra_params = False
        custom.min_track_length = 0  # every point, 2-view ones too (its log: 3 x all points' parameters)
    mapper_options = pycolmap.IncrementalMapperOptions()
    mapper_options.random_seed = tri.random_seed
    mapper.iterative_global_refinement(5, 0.0005, mapper_options, custom, tri, True)
    mapper.end_reconstruction(False)
    _filter_reprojection(pycolmap, rec, opts.max_normalized_reproj_error, "NORMALIZED")
    # global_mapping's log shows a second, 1-iteration bundle adjustment after this one. It is
    # a no-op: Ceres rejects the step that meets the function tolerance, so the second solve
    # starts where the first stopped, finds the same step (|cost_change|/cost 8.453e-6 vs
    # 8.456e-6 on lund_door), rejects it and leaves the model unchanged. Running it here
    # changed no error on any benchmark project (benchmarks/README.md), so it is not run.
    if not _bundle_adjust(pycolmap, ba, rec):
        return False
    rec.normalize()
    _filter_reprojection(pycolmap, rec, opts.max_normalized_reproj_error, "NORMALIZED")
    _filter_angle(pycolmap, rec, opts.min_tri_angle_deg)
    return True


# =========================================================================== evaluation


def _umeyama(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Similarity ``dst ~ s R src + t`` of least squares (Umeyama 1991, TPAMI 13(4))."""
    mu_s, mu_d = src.mean(0), dst.mean(0)
    S, D = src - mu_s, dst - mu_d
    U, sig, Vt = np.linalg.svd(D.T @ S / len(src))
    E = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt)) or 1.0])
    R = U @ E @ Vt
    var = (S**2).sum() / len(src)
    s = float((sig * np.diag(E)).sum() / var) if var > 0 else 1.0
    return s, R, mu_d - s * R @ mu_s


def model_errors(estimate, ground_truth) -> dict:
    """Errors of a reconstruction against a ground-truth model, images matched by name.

    ``estimate``, ``ground_truth``: ``pycolmap.Reconstruction`` or model folders. Rotation
    error: rotgraph's evaluator (:func:`rotgraph.evaluate.compare_rotations`: the gauge
    rotation of least geodesic L1 error, then per-image angle). Position error: camera
    centres after the least-squares similarity (Umeyama) onto the ground truth, in the
    ground truth's units; ``position_median_rel`` divides by the median distance of the
    ground-truth centres from their centroid. Images not registered in the estimate count
    in ``n_missing`` (not in the statistics)."""
    from ..evaluate import compare_rotations
    from ..io.colmap import _pycolmap

    from ..io.colmap_model import _read_model

    pycolmap = _pycolmap()
    est = estimate if isinstance(estimate, pycolmap.Reconstruction) else _read_model(Path(estimate))
    gt = ground_truth if isinstance(ground_truth, pycolmap.Reconstruction) else _read_model(Path(ground_truth))
    e_by = {im.name: im for im in est.images.values() if im.has_pose}
    g_by = {im.name: im for im in gt.images.values() if im.has_pose}
    names = sorted(set(e_by) & set(g_by))
    out = {"n_ground_truth": len(g_by), "n_registered": len(e_by), "n_evaluated": len(names),
           "n_missing": len(set(g_by) - set(e_by))}
    if len(names) < 3:
        out.update(rotation_median_deg=float("nan"), rotation_mean_deg=float("nan"), position_median=float("nan"),
                   position_median_rel=float("nan"))
        return out
    Re = np.stack([so3.from_pycolmap(e_by[n].cam_from_world().rotation) for n in names])
    Rg = np.stack([so3.from_pycolmap(g_by[n].cam_from_world().rotation) for n in names])
    r = compare_rotations(Re, Rg)
    Ce = np.stack([np.asarray(e_by[n].projection_center(), float) for n in names])
    Cg = np.stack([np.asarray(g_by[n].projection_center(), float) for n in names])
    out.update(rotation_median_deg=r.median, rotation_mean_deg=r.mean)
    ok = np.isfinite(Ce).all(axis=1) & np.isfinite(Cg).all(axis=1)
    if ok.sum() < 3 or np.ptp(Ce[ok], axis=0).max() <= 0:  # no positions (e.g. rotations only)
        out.update(position_median=float("nan"), position_mean=float("nan"), position_median_rel=float("nan"))
        return out
    Ce, Cg = Ce[ok], Cg[ok]
    s, R, t = _umeyama(Ce, Cg)
    d = np.linalg.norm((s * Ce @ R.T + t) - Cg, axis=1)
    scale = float(np.median(np.linalg.norm(Cg - Cg.mean(0), axis=1))) or 1.0
    out.update(position_median=float(np.median(d)), position_mean=float(d.mean()),
               position_median_rel=float(np.median(d)) / scale)
    return out


# =========================================================================== the command


def _check_output(output, project: Path) -> Path:
    """The model folder ``output``: a folder (or to be made), not the project or its own sparse
    model (:func:`~rotgraph.pipeline.solve._check_model_folder`, the one check of model
    outputs), somewhere writable."""
    from .solve import _check_model_folder

    out = Path(output)
    _check_model_folder(out, project)
    parent = out if out.exists() else out.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not os.access(parent, os.W_OK):
        raise InputError("cannot write here (permission denied)", path=str(out))
    return out


def reconstruct(project, output, options=None, *, mapper_options=None, overrides=None, seed: int | None = None,
                num_threads: int | None = None, text: bool = False, ground_truth="auto", callback=None,
                pycolmap_log_level: int = 2) -> dict:
    """Reconstruct the COLMAP project ``project`` (a folder with ``database.db``, or the
    database file) from rotgraph's rotations with COLMAP's global pipeline (module
    docstring) and write the model into the folder ``output`` (``.bin``; ``text``: ``.txt``).

    ``options``: rotgraph's :class:`~rotgraph.estimators.types.SolveOptions` (None: what
    ``rotgraph solve`` uses on COLMAP input, ``default_options("colmap")``, with
    ``overrides``, a dict of fields, applied). ``mapper_options``: a
    ``pycolmap.GlobalMapperOptions`` (None: :func:`default_mapper_options` with ``seed``
    and ``num_threads``; the ``skip_*`` flags skip those stages, except rotation
    averaging, which rotgraph does). ``ground_truth``: a model folder, ``"auto"`` (the
    project's sparse model, when it has one) or None: with one, the summary has ``eval``
    (:func:`model_errors`) and ``eval_rotation_averaging`` (rotgraph's rotations alone).
    ``callback(stage)`` is called as each stage starts. pycolmap's log is limited to
    ``pycolmap_log_level`` (0 info, 1 warning, 2 error) meanwhile.

    Returns a summary dict: counts (``n_images``, ``n_registered``, ``n_points3D``,
    ``n_observations`` of the model; tracks: ``n_tracks_established`` from
    ``n_track_observations``, ``n_tracks_inconsistent``, ``n_tracks``; pairs),
    ``mean_reprojection_error``, ``seconds`` and
    ``seconds_<stage>``. The user's database is only read (never opened by pycolmap).
    Raises :class:`~rotgraph.errors.InputError` for a bad project or output and
    :class:`~rotgraph.errors.UnsolvableError` when a stage fails.
    """

    from ..estimators.rotation_averaging import average_rotations
    from ..io.colmap import _database_copy, _pycolmap, find_colmap_project
    from ..io.colmap_output import apply_result, write_model_folder
    from .read import read_view_graph
    from .solve import resolve_options, wants_information

    pycolmap = _pycolmap()
    project = Path(project)
    if not project.exists():
        raise InputError("no such file or folder", path=str(project))
    db_path, model_path = find_colmap_project(project)
    if db_path is None:
        raise InputError("no COLMAP database here (reconstruct needs database.db: its matches and two-view geometries)",
                         path=str(project))
    out = _check_output(output, project)
    gt_model = model_path if ground_truth == "auto" else (Path(ground_truth) if ground_truth else None)
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

    mopts = mapper_options if mapper_options is not None else default_mapper_options(seed, num_threads)
    if seed is not None and int(seed) >= 0:
        pycolmap.set_random_seed(int(seed))
    summary = {"project": str(project), "output": str(out), "n_images": int(graph.n_nodes), "n_edges": int(graph.n_edges),
               "n_solved": int(res.solved.sum()), "rotation_method": res.method}
    with _pycolmap_log(pycolmap_log_level):
        # 2. reconstruction, rotations, pose graph
        stage("pose graph")
        t0 = time.perf_counter()
        cache_options = pycolmap.DatabaseCacheOptions()
        cache_options.min_num_matches = int(pycolmap.GlobalPipelineOptions().min_num_matches)
        with _database_copy(db_path) as db:  # the private copy, open until the tracks have their keypoints
            try:
                cache = pycolmap.DatabaseCache.create(db, cache_options)
            except Exception as exc:
                from ..io.colmap import _one_line

                raise InputError(f"pycolmap cannot read the database: {_one_line(exc)}", path=str(db_path)) from None
            rec = pycolmap.Reconstruction()
            rec.load(cache)
            apply_result(pycolmap, rec, graph, res)
            pose_graph, pg_counts = build_pose_graph(pycolmap, rec, graph,
                                                     float(mopts.rotation_averaging.max_rotation_error_deg))
            summary.update(pg_counts)
            if rec.num_reg_frames() < 2:
                raise UnsolvableError(f"{project}: fewer than 2 frames left after rotation averaging")
            times["pose_graph"] = time.perf_counter() - t0
            rot_model = pycolmap.Reconstruction(rec) if gt_model is not None else None

            # 3. tracks
            if not mopts.skip_track_establishment:
                stage("tracks")
                t0 = time.perf_counter()
                summary.update(establish_tracks(pycolmap, rec, cache, pose_graph, mopts, db.read_keypoints))
                times["tracks"] = time.perf_counter() - t0
        # 4. global positioning, 5. bundle adjustment, 6. retriangulation (COLMAP's, in order)
        for skip, name, failed, run in (
            (mopts.skip_global_positioning, "global positioning", "global positioning",
             lambda: _global_positioning(pycolmap, rec, pose_graph, mopts)),
            (mopts.skip_bundle_adjustment, "bundle adjustment", "bundle adjustment",
             lambda: _iterative_bundle_adjustment(pycolmap, rec, mopts)),
            (mopts.skip_retriangulation, "retriangulation", "retriangulation and refinement",
             lambda: _retriangulate_and_refine(pycolmap, rec, cache, mopts)),
        ):
            if skip:
                continue
            stage(name)
            t0 = time.perf_counter()
            if not run():
                raise UnsolvableError(f"{project}: {failed} failed")
            times[name.replace(" ", "_")] = time.perf_counter() - t0
        pycolmap.align_reconstruction_to_orig_rig_scales(cache.rigs, rec)
        rec.update_point_3d_errors()

    stage("write")
    t0 = time.perf_counter()
    write_model_folder(rec, out, text)
    times["write"] = time.perf_counter() - t0
    summary.update(
        n_registered=int(rec.num_reg_images()),
        n_frames_registered=int(rec.num_reg_frames()),
        n_points3D=int(rec.num_points3D()),
        n_observations=int(rec.compute_num_observations()),
        mean_reprojection_error=float(rec.compute_mean_reprojection_error()),
        seconds=time.perf_counter() - t_all,
    )
    summary.update({f"seconds_{k}": v for k, v in times.items()})
    if gt_model is not None:
        try:
            from ..io.colmap_model import _read_model

            gt = _read_model(Path(gt_model))  # once, for both evaluations
            summary["eval"] = model_errors(rec, gt)
            summary["eval_rotation_averaging"] = model_errors(rot_model, gt)
            for k in ("position_mean", "position_median_rel", "position_median"):
                summary["eval_rotation_averaging"].pop(k, None)
        except Exception as exc:  # a ground truth that cannot be read is no failure of the reconstruction
            if ground_truth not in ("auto", None):
                raise InputError(f"cannot read the ground-truth model: {exc}", path=str(gt_model)) from None
            logger.warning("ground truth not evaluated: %s", exc)
    return summary
