"""A COLMAP project to a view graph: the database read (:mod:`rotgraph.io.colmap`), the
relative poses the database does not store estimated (:mod:`rotgraph.estimators.relative_pose`),
the graph built with its rig frames and the ground truth of the project's sparse model.

This is COLMAP 4's ``DatabaseCache`` + ``MaybeDecomposeRelativePoses`` + ``PoseGraph::Load``
(see :mod:`rotgraph.io.colmap` for which pairs become edges).
"""

from __future__ import annotations

import logging
import time

import numpy as np

from .. import so3
from ..errors import InputError, OptionError
from ..estimators import pair_uncertainty, relative_pose
from ..io import colmap as io
from ..io.colmap_project import locate_colmap_project
from ..io.colmap_model import attach_ground_truth, read_colmap_model_graph
from ..viewgraph import ViewGraph

__all__ = ["read_colmap_project"]

logger = logging.getLogger(__name__)


#: ``rotgraph solve`` computes each pair's rotation information from at most this many of its
#: inlier matches (evenly spaced, each standing for n / sample). Measured (bench_colmap
#: projects, median error over GLOMAP's, all inliers -> 128): bundled 0.454 -> 0.445, syn40
#: 0.490 -> 0.489, syn40-stored 0.467 -> 0.463, rig3x20 0.341 -> 0.343, lund_door 1.000 ->
#: 1.003; read time syn40 0.12 -> 0.08 s, rig3x20 0.27 -> 0.17 s (without information:
#: 0.04 and 0.11 s; the errors were 0.666x and 0.426x).
UNCERTAINTY_SAMPLE = 128


def read_colmap_project(
    path,
    *,
    model="auto",
    min_inliers: int = io.DEFAULT_MIN_INLIERS,
    configs=None,
    estimate_missing: bool = True,
    workers: int | None = None,
    vectorize: bool = True,
    progress=None,
    uncertainty: bool = False,
    pixel_sigma: float = pair_uncertainty.PIXEL_SIGMA,
    uncertainty_sample: int | None = None,
) -> ViewGraph:
    """The view graph of a COLMAP project (image level).

    ``path``: a project folder (``database.db`` and/or a sparse model in the folder,
    ``sparse/0``, ``sparse`` or ``0/``), a database file, or a model folder.

    * With a database: nodes are all the database's images (``node_ids`` = COLMAP image
      ids, ``names`` = image names), edges its verified pairs whose configuration is in
      ``configs`` (default :data:`~rotgraph.io.colmap.USABLE_CONFIGS`) with
      ``>= min_inliers`` inlier matches (weight = inlier count), rotation
      ``cam2_from_cam1`` stored or, with ``estimate_missing``, estimated from the inlier
      matches and cameras (``vectorize``: E and F pairs decomposed in numpy; the rest by
      pycolmap in ``workers`` processes, None = automatic). Ground truth from the sparse
      model (``model``: ``"auto"`` = the project's model, a folder, or None) matched by
      image name.
    * Without a database: the model's registered images, edges between those sharing
      ``>= min_inliers`` 3D points (exact relative rotations), ground truth = the model.

    ``progress(stage, done, total)``, if given, follows the relative-pose estimation pair
    by pair (``stage`` = ``"relative poses"``).

    ``uncertainty`` (database only): ``graph.information`` gets each edge's rotation
    information matrix, from the same inlier matches its relative pose came from
    (:mod:`rotgraph.estimators.pair_uncertainty`: the Sampson error's Gauss-Newton
    Hessian at the pair's pose, translation marginalised; the rotation-only model for
    PANORAMIC pairs), with ``pixel_sigma`` pixels of keypoint noise; keypoints are
    normalised by each camera's calibration (``Camera.cam_from_img``, distortion
    included; pixel scale ``1 / mean focal length``). The translation direction is the
    stored one, else that of the essential matrix the rotation came from, else the one
    that best fits the inliers given the rotation. ``uncertainty_sample``: use at most
    this many (evenly spaced) inliers per pair, each standing for ``n / sample`` (faster,
    noisier; None: all). Edges, their order and ``graph.rigs`` are those of
    ``uncertainty=False``. ``meta``: also
    ``n_pairs_without_information`` (pairs too degenerate or without usable keypoints:
    :data:`~rotgraph.estimators.pair_uncertainty.EMPTY_INFORMATION`), ``pixel_sigma``,
    ``uncertainty_sample`` and ``seconds_uncertainty``. Without a database (the model is the input) there is no
    information.

    ``graph.format`` is ``"colmap"``; ``graph.rigs`` holds each image's frame id and
    ``cam_from_rig`` (NaN when unknown), for the rig-aware solve. ``graph.meta`` is
    informational only (no solver reads it): ``source`` (``"database"``/``"model"``),
    ``n_images``, ``n_pairs_stored``, ``n_pairs_estimated``, ``n_pairs_skipped``,
    ``skipped`` (reason -> count), ``configs`` (configuration -> count of verified pairs,
    database only), ``images_without_pairs`` (names), ``n_ground_truth``, ``summary`` and
    timings.

    Raises :class:`~rotgraph.errors.InputError` for a missing, empty, corrupt or
    non-COLMAP input, a model without images, or a project without any usable pair.
    """
    db_path, model_path, explicit = locate_colmap_project(path, model)
    if min_inliers < 0:
        raise OptionError("min_inliers must be >= 0")
    if uncertainty and not pixel_sigma > 0:
        raise OptionError("pixel_sigma must be positive")
    if uncertainty_sample is not None and uncertainty_sample < pair_uncertainty.MIN_CORRESPONDENCES[0]:
        raise OptionError(f"uncertainty_sample must be None or >= {pair_uncertainty.MIN_CORRESPONDENCES[0]}")
    t0 = time.perf_counter()
    if db_path is not None:
        data = io.read_two_view_geometries(db_path, min_inliers, configs, estimate_missing, all_keypoints=uncertainty)
        graph = _graph_from_pairs(data, workers, vectorize, progress, pixel_sigma if uncertainty else None, uncertainty_sample)
        attach_ground_truth(graph, model_path, explicit)
    else:  # the model is the input
        graph = read_colmap_model_graph(model_path, min_inliers)
    graph.format = "colmap"
    graph.meta["seconds_read"] = time.perf_counter() - t0
    return graph


def _estimate(data: io.TwoViewGeometries, workers, vectorize: bool, progress) -> list:
    """``(quaternion or None, reason)`` of each pair of ``data.todo``, in order."""
    pycolmap = data.pycolmap
    fast: dict = {}
    if vectorize:
        fast, slow = relative_pose.estimate_calibrated(
            data.todo, data.views, data.inliers, data.pairs, data.cameras, data.keypoints,
            calibrated=int(pycolmap.TwoViewGeometryConfiguration.CALIBRATED),
            uncalibrated=int(pycolmap.TwoViewGeometryConfiguration.UNCALIBRATED),
        )
    else:
        slow = data.todo
    n_todo = len(data.todo)
    report = None if progress is None else (lambda done, total: progress("relative poses", n_todo - total + done, n_todo))
    if report is not None:
        report(0, len(slow))  # the vectorised calibrated pairs are done
    poses = relative_pose.estimate_poses(pycolmap, slow, data.geometries, data.pairs, data.cameras, data.points, workers, report)
    estimated = dict(zip(slow, poses))
    estimated.update((k, (q, None)) for k, q in fast.items())
    return [estimated[k] for k in data.todo]


def _graph_from_pairs(data: io.TwoViewGeometries, workers, vectorize: bool, progress, pixel_sigma=None, sample=None) -> ViewGraph:
    """The view graph of ``data``; with ``pixel_sigma`` (not None), each edge's rotation
    information too (:func:`_edge_information`)."""
    t_est = time.perf_counter()
    estimated = _estimate(data, workers, vectorize, progress)
    t_est = time.perf_counter() - t_est
    skipped = data.skipped.copy()

    ids_i, ids_j, quats, weights, ks = [], [], [], [], []
    for k in data.stored:
        q = data.stored_quaternion(k)
        if q is None:
            skipped["stored relative pose not a rotation"] += 1
            continue
        i, j = data.pairs[k]
        ids_i.append(i), ids_j.append(j), quats.append(q), weights.append(len(data.inliers[k])), ks.append(k)
    n_stored = len(ids_i)
    for k, (q, reason) in zip(data.todo, estimated):
        if reason is not None:
            skipped[reason] += 1
            continue
        i, j = data.pairs[k]
        ids_i.append(i), ids_j.append(j), quats.append(q), weights.append(len(data.inliers[k])), ks.append(k)
    n_estimated = len(ids_i) - n_stored
    n_skipped = int(sum(skipped.values()))

    where = data.path
    summary = (
        f"{len(data.image_ids)} images, {data.n_verified} verified pairs: {n_stored} with a stored relative pose, "
        f"{n_estimated} estimated from the inlier matches, {n_skipped} skipped"
    )
    if skipped:
        summary += " (" + ", ".join(f"{v} {k}" for k, v in skipped.most_common()) + ")"
    logger.info("%s: %s; estimation %.2f s", where, summary, t_est)
    if not ids_i:
        if not data.n_verified:
            raise InputError("COLMAP database has no verified image pairs (two_view_geometries is empty: run matching first)", path=where)
        raise InputError(f"no usable image pair: {summary}", path=where)

    R = so3.matrices_from_quaternions(np.asarray(quats))
    info, t_unc = None, None
    if pixel_sigma is not None:
        t_unc = time.perf_counter()
        info = _edge_information(data, ks, R, n_stored, pixel_sigma, sample)
        t_unc = time.perf_counter() - t_unc
    graph = ViewGraph.from_edges(
        np.asarray(ids_i, dtype=np.int64), np.asarray(ids_j, dtype=np.int64), R, np.asarray(weights, dtype=np.float64),
        node_ids=data.image_ids, names=data.names, duplicates="error", source_path=where, information=info,
    )
    lonely = [str(n) for n in data.names[graph.degrees() == 0]]
    if lonely:
        logger.info("%s: %d images have no usable pair: %s%s", where, len(lonely), ", ".join(lonely[:10]), " ..." if len(lonely) > 10 else "")
    graph.meta.update(
        source="database",
        database_path=where,
        n_images=len(data.image_ids),
        n_pairs_verified=data.n_verified,
        n_pairs_stored=n_stored,
        n_pairs_estimated=n_estimated,
        n_pairs_skipped=n_skipped,
        skipped=dict(skipped),
        configs=dict(data.configs),
        images_without_pairs=lonely,
        seconds_estimate=t_est,
        summary=summary,
    )
    if info is not None:
        empty = np.all(info == pair_uncertainty.EMPTY_INFORMATION * np.eye(3), axis=(1, 2))
        graph.meta.update(n_pairs_without_information=int(empty.sum()), seconds_uncertainty=t_unc, pixel_sigma=float(pixel_sigma),
                          uncertainty_sample=sample)
        logger.info("%s: rotation information of %d pairs (%d without usable matches) in %.3f s", where, len(ks), int(empty.sum()), t_unc)
    graph.rigs = data.rigs
    return graph


class _Keypoints:
    """The pixel keypoints of some images in one table, grouped by camera (``offset[i]``,
    ``count[i]``: image ``i``'s rows), normalised on demand (:meth:`normalise`)."""

    def __init__(self, data: io.TwoViewGeometries, images):
        by_camera: dict = {}
        for i in images:
            by_camera.setdefault(int(data.cameras[i].camera_id), []).append(i)
        self.offset, self.count, self.scale, self.cameras = {}, {}, {}, []
        parts, n = [], 0
        for ids in by_camera.values():
            cam = data.cameras[ids[0]]
            try:
                f = float(cam.mean_focal_length())
                ok = not cam.is_spherical() and np.isfinite(f) and f > 0
            except Exception:
                ok = False
            start = n
            for i in ids:
                kp = data.keypoints[i]
                parts.append(kp)
                self.offset[i], self.count[i], self.scale[i] = n, len(kp), (1.0 / f if ok else 1.0)
                n += len(kp)
            self.cameras.append((cam if ok else None, start, n))
        self.pixels = np.concatenate(parts) if parts else np.zeros((0, 2))

    def normalise(self, rows: np.ndarray) -> np.ndarray:
        """(K, 2) table: the rows flagged in ``rows`` (K,) bool normalised
        (``Camera.cam_from_img``: ``(u, v)`` on the plane z = 1, distortion removed; one
        call per camera, on the flagged rows only), NaN elsewhere and for cameras that
        cannot normalise (spherical, failing)."""
        out = np.full(self.pixels.shape, np.nan)
        for cam, a, b in self.cameras:
            if cam is None:
                continue
            sel = a + np.flatnonzero(rows[a:b])
            if not len(sel):
                continue
            try:
                xy = np.asarray(cam.cam_from_img(self.pixels[sel]), dtype=np.float64).reshape(-1, 2)
            except Exception:  # a camera model pycolmap cannot invert: no information from it
                continue
            if xy.shape == (len(sel), 2):
                out[sel] = xy
        return out


#: Matches per vectorised call of :func:`~rotgraph.estimators.pair_uncertainty.rotation_information`
#: (blocks of whole pairs: bounded temporaries on large projects).
INFORMATION_BLOCK = 1 << 20


def _edge_information(data: io.TwoViewGeometries, ks: list, R: np.ndarray, n_stored: int, pixel_sigma: float,
                      sample: int | None = None) -> np.ndarray:
    """Rotation information (E, 3, 3) of the pairs ``ks`` (in edge order; the first
    ``n_stored`` have a stored pose) with rotations ``R`` (E, 3, 3): their inlier matches,
    normalised per camera, handed to :mod:`rotgraph.estimators.pair_uncertainty`,
    vectorised over blocks of pairs of about :data:`INFORMATION_BLOCK` matches.
    ``sample``: at most this many evenly spaced inliers per pair, each standing for
    ``n / sample`` (None: all)."""
    P = len(ks)
    keypoints = _Keypoints(data, sorted({x for k in ks for x in data.pairs[k]}))
    first = [data.pairs[k][0] for k in ks]
    second = [data.pairs[k][1] for k in ks]
    kk = np.asarray(ks, dtype=np.int64)
    start = np.asarray(data.inliers.start, dtype=np.int64)[kk]
    n_inliers = np.asarray(data.inliers.end, dtype=np.int64)[kk] - start
    per_pair = n_inliers if sample is None else np.minimum(n_inliers, sample)
    stands_for = n_inliers / np.maximum(per_pair, 1)
    inlier_table = np.asarray(data.inliers.table)
    offsets = [np.array([keypoints.offset[i] for i in side], dtype=np.int64) for side in (first, second)]
    counts = [np.array([keypoints.count[i] for i in side], dtype=np.int64) for side in (first, second)]

    def block(lo: int, hi: int):
        """Pairs ``lo:hi``: each used inlier's pair (0-based in the block) and its keypoint
        table rows in the two images (-1: past the image's keypoints). The inliers used,
        as rows of the one inlier table (no per-pair Python): all, or ``sample`` evenly
        spaced ones (as relative_pose's vote) where a pair has more. Block-sized
        temporaries only."""
        c = per_pair[lo:hi]
        seg = np.repeat(np.arange(hi - lo), c)
        slot = np.arange(len(seg)) - np.repeat(np.cumsum(c) - c, c)
        if sample is not None:
            n = n_inliers[lo:hi][seg]
            slot = np.where(n > sample, (slot * (n - 1)) // max(sample - 1, 1), slot)
        m = inlier_table[start[lo:hi][seg] + slot]
        rows = []
        for side in (0, 1):
            idx = m[:, side].astype(np.int64)
            r = np.repeat(offsets[side][lo:hi], c) + idx
            past = idx >= np.repeat(counts[side][lo:hi], c)
            if past.any():
                r[past] = -1
            rows.append(r)
        return seg, rows[0], rows[1]

    # blocks of whole pairs of about INFORMATION_BLOCK matches; a first pass over them marks
    # the keypoints used at all (only those are normalised), the second computes
    ends = np.cumsum(per_pair)
    bounds = []
    lo = 0
    while lo < P:
        hi = max(lo + 1, int(np.searchsorted(ends, ends[lo] - per_pair[lo] + INFORMATION_BLOCK, side="right")))
        bounds.append((lo, hi))
        lo = hi
    used = np.zeros(len(keypoints.pixels) + 1, dtype=bool)  # the last entry: row -1
    for lo, hi in bounds:
        _, r1, r2 = block(lo, hi)
        used[r1] = True
        used[r2] = True
    table = np.concatenate([keypoints.normalise(used[:-1]), np.full((1, 2), np.nan)])

    scale1 = np.array([keypoints.scale[i] for i in first], dtype=np.float64)
    scale2 = np.array([keypoints.scale[i] for i in second], dtype=np.float64)
    t = _translations(data, ks, n_stored)
    panoramic = int(data.pycolmap.TwoViewGeometryConfiguration.PANORAMIC)
    rotation_only = data.config[np.asarray(ks, dtype=np.int64)] == panoramic
    H = np.empty((P, 3, 3))
    for lo, hi in bounds:
        seg, r1, r2 = block(lo, hi)
        x1, x2 = table[r1], table[r2]
        c = per_pair[lo:hi]
        kw = dict(scale1=scale1[lo:hi], scale2=scale2[lo:hi], sigma=pixel_sigma)
        tb = t[lo:hi]
        fit = ~np.isfinite(tb).all(axis=1)
        if fit.any():  # the best fit to the inliers given R
            sel = fit[seg]
            sub = np.cumsum(fit) - 1
            tb[fit] = pair_uncertainty.translation_directions(
                x1[sel], x2[sel], sub[seg[sel]], R[lo:hi][fit], scale1=kw["scale1"][fit], scale2=kw["scale2"][fit],
                sigma=pixel_sigma, iterations=1)
        weights = np.repeat(stands_for[lo:hi], c) if (c < n_inliers[lo:hi]).any() else None
        H[lo:hi] = pair_uncertainty.rotation_information(x1, x2, seg, R[lo:hi], tb, rotation_only=rotation_only[lo:hi],
                                                         weights=weights, **kw)
    return H


def _translations(data: io.TwoViewGeometries, ks: list, n_stored: int) -> np.ndarray:
    """The translation direction (P, 3) of each pair's relative pose (its sign does not
    matter): stored (the first ``n_stored`` pairs), else the left null vector of the
    essential matrix the rotation was decomposed from (CALIBRATED: E; UNCALIBRATED:
    ``K2^T F K1``, as :mod:`rotgraph.estimators.relative_pose` and COLMAP do); NaN rows
    for the rest (homographies, no stored matrix, non-pinhole cameras)."""
    configs = data.pycolmap.TwoViewGeometryConfiguration
    calibrated, uncalibrated = int(configs.CALIBRATED), int(configs.UNCALIBRATED)
    P = len(ks)
    t = np.full((P, 3), np.nan)
    E = np.full((P, 3, 3), np.nan)
    K: dict = {}

    def calibration(i):
        if i not in K:
            try:
                K[i] = None if data.cameras[i].is_spherical() else np.asarray(data.cameras[i].calibration_matrix(), dtype=np.float64)
            except Exception:
                K[i] = None
        return K[i]

    ks = np.asarray(ks, dtype=np.int64)
    t[:n_stored] = data.tvec[ks[:n_stored]]
    rest = ks[n_stored:]
    config = data.config[rest]
    calib = (config == calibrated) & data.has_matrix["E"][rest]
    E[n_stored:][calib] = data.matrices["E"][rest[calib]]
    for p in np.flatnonzero((config == uncalibrated) & data.has_matrix["F"][rest]):
        k = rest[p]
        K1, K2 = calibration(data.pairs[k][0]), calibration(data.pairs[k][1])
        if K1 is not None and K2 is not None:
            E[n_stored + p] = K2.T @ data.matrices["F"][k] @ K1
    # t^T E = 0 (E = [t]x R): t is orthogonal to E's columns, along the largest cross
    # product of two of them (rank 2: the other products are multiples of it or zero)
    cols = np.swapaxes(E, 1, 2)
    cands = np.stack([np.cross(cols[:, 0], cols[:, 1]), np.cross(cols[:, 1], cols[:, 2]), np.cross(cols[:, 2], cols[:, 0])], axis=1)
    norms = np.linalg.norm(cands, axis=2)
    has = np.isfinite(norms).all(axis=1) & (np.nan_to_num(norms).max(axis=1) > 0)
    best = cands[np.arange(P), np.argmax(np.nan_to_num(norms, nan=-1.0), axis=1)]
    t = np.where((has & ~np.isfinite(t).all(axis=1))[:, None], best, t)
    return t
