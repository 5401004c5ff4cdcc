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
from ..errors import InputError
from ..estimators import relative_pose
from ..io import colmap as io
from ..io.colmap_model import attach_ground_truth, read_colmap_model_graph
from ..viewgraph import ViewGraph

__all__ = ["read_colmap_project"]

logger = logging.getLogger(__name__)


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
    db_path, model_path, explicit = io.locate_colmap_project(path, model)
    if min_inliers < 0:
        raise ValueError("min_inliers must be >= 0")
    t0 = time.perf_counter()
    if db_path is not None:
        data = io.read_two_view_geometries(db_path, min_inliers, configs, estimate_missing)
        graph = _graph_from_pairs(data, workers, vectorize, progress)
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
            data.todo, data.geometries, data.inliers, data.pairs, data.cameras, data.keypoints,
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


def _graph_from_pairs(data: io.TwoViewGeometries, workers, vectorize: bool, progress) -> ViewGraph:
    t_est = time.perf_counter()
    estimated = _estimate(data, workers, vectorize, progress)
    t_est = time.perf_counter() - t_est
    skipped = data.skipped.copy()

    ids_i, ids_j, quats, weights = [], [], [], []
    for k in data.stored:
        q = data.stored_quaternion(k)
        if q is None:
            skipped["stored relative pose not a rotation"] += 1
            continue
        i, j = data.pairs[k]
        ids_i.append(i), ids_j.append(j), quats.append(q), weights.append(len(data.inliers[k]))
    n_stored = len(ids_i)
    for k, (q, reason) in zip(data.todo, estimated):
        if reason is not None:
            skipped[reason] += 1
            continue
        i, j = data.pairs[k]
        ids_i.append(i), ids_j.append(j), quats.append(q), weights.append(len(data.inliers[k]))
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
    graph = ViewGraph.from_edges(
        np.asarray(ids_i, dtype=np.int64), np.asarray(ids_j, dtype=np.int64), R, np.asarray(weights, dtype=np.float64),
        node_ids=data.image_ids, names=data.names, duplicates="error", source_path=where,
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
    graph.rigs = data.rigs
    return graph
