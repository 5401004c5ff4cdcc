"""Rig-aware multiple rotation averaging: frames of a rig averaged, images derived.

COLMAP 4 groups images into frames of a rig: ``cam_from_world = cam_from_rig @
rig_from_world``, with ``cam_from_rig`` (``sensor_from_rig``) known from calibration
(identity for the rig's reference sensor). As GLOMAP does, the frame rotations
``rig_from_world`` are averaged: an image pair ``(i in frame a, j in frame b)`` gives the
frame edge ``R_ab = cam_from_rig_j^T R_ij cam_from_rig_i``; pairs within one frame carry no
frame information and are skipped; images whose ``cam_from_rig`` is unknown become frames
of their own. Each image's rotation is then ``cam_from_rig @ rig_from_world``. A graph
without rigs (or with one image per frame and identity ``cam_from_rig``) is solved as is.
The images' gravity priors become the frames' (:meth:`FrameProblem.frame_priors`): the frame
graph goes through the same stages as an image graph.
"""

from __future__ import annotations

import logging
from typing import NamedTuple

import numpy as np

from .. import so3, so3_rows
from ..errors import UnsolvableError
from ..priors import GravityPriors
from ..graph_build import QuaternionRotations
from ..viewgraph import ViewGraph
from .types import AveragingResult, FrameSolution

__all__ = ["FrameProblem", "frame_problem", "lone_frames"]

logger = logging.getLogger(__name__)


def _frame_groups(graph: ViewGraph, cam_from_rig: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Node -> group index (a frame, or the image alone when its ``cam_from_rig`` is
    unknown) and each node's ``cam_from_rig`` (identity for lone images); ``cam_from_rig``
    in place of the graph's (e.g. estimated extrinsics)."""
    n = graph.n_nodes
    S = (graph.rigs.cam_from_rig if cam_from_rig is None else np.asarray(cam_from_rig, dtype=np.float64)).copy()
    unknown = ~np.isfinite(S).all(axis=(1, 2))
    key = np.where(unknown, -1 - np.arange(n), graph.rigs.frame_ids)  # unknown: a group of its own
    _, group = np.unique(key, return_inverse=True)
    S[unknown] = np.eye(3)
    return group.ravel().astype(np.int64), S


class FrameProblem(NamedTuple):
    """The frame-level problem of an image graph with rigs (see the module docstring)."""

    image_graph: ViewGraph
    frame_graph: ViewGraph
    group: np.ndarray  # (n,) frame-graph node of each image
    cam_from_rig: np.ndarray  # (n, 3, 3), identity for images that are frames of their own
    inter: np.ndarray  # (E,) bool: the image edge joins two frames
    edge_index: np.ndarray  # image edge of each frame edge

    def frame_priors(self, priors: GravityPriors) -> GravityPriors:
        """Gravity priors of the frames from the images' ``priors`` (directions in each
        camera's frame, NaN rows: none): image ``a`` sees ``g_a = S_a g_frame``, so each frame
        gets the normalised mean of ``S_a^T g_a`` over its images, and the smallest of their
        ``sigma_deg`` ((n,) array; NaN: estimate; a scalar or None passes through)."""
        gravity, sigma_deg = priors.direction, priors.sigma_deg
        G = int(self.group.max()) + 1
        has = np.isfinite(gravity).all(axis=1)
        v = np.einsum("nba,nb->na", self.cam_from_rig[has], gravity[has])  # S^T g
        acc = np.zeros((G, 3))
        np.add.at(acc, self.group[has], v)
        norm = np.linalg.norm(acc, axis=1)
        out = np.full((G, 3), np.nan)
        ok = norm > 1e-12
        out[ok] = acc[ok] / norm[ok, None]
        if sigma_deg is None or np.ndim(sigma_deg) == 0:
            return GravityPriors(out, sigma_deg, priors.world)
        sig = np.asarray(sigma_deg, dtype=np.float64)
        fs = np.full(G, np.inf)
        np.fmin.at(fs, self.group[has], sig[has])  # NaN (estimate) loses to a given value
        fs[np.isinf(fs)] = np.nan
        return GravityPriors(out, fs, priors.world)

    def image_result(self, fres: AveragingResult, seconds: float) -> AveragingResult:
        """The image-level result of the frame-level one."""
        graph, group, S, inter, e = self.image_graph, self.group, self.cam_from_rig, self.inter, self.edge_index
        R = S @ fres.cam_from_world[group]  # NaN where the frame is unsolved
        solved = np.isfinite(R).all(axis=(1, 2))
        # Frame-to-frame pairs: the frame edge's residual is the image pair's (conjugation by
        # the rigs' cam_from_rig keeps angles), also for the outlier edges of left-out frames.
        residuals = np.full(graph.n_edges, np.nan)
        inliers = np.zeros(graph.n_edges, dtype=bool)
        residuals[e], inliers[e] = fres.residuals_deg, fres.inliers
        i, j = graph.edges[:, 0], graph.edges[:, 1]
        both = ~inter & solved[i] & solved[j]  # pairs within one (solved) frame
        if both.any():
            pred = R[j[both]] @ np.swapaxes(R[i[both]], 1, 2)
            residuals[both] = np.degrees(so3.angle_between(graph.cam2_from_cam1[both], pred))
            inliers[both] = residuals[both] <= fres.outlier_threshold_deg
        anchor = int(np.flatnonzero(group == fres.anchor)[0]) if (group == fres.anchor).any() else 0
        frames = FrameSolution(self.frame_graph, fres, group, e, int((~inter).sum()))
        edge_weights = None
        if fres.edge_weights is not None:  # the frame edges' (pairs within a frame: none)
            edge_weights = np.full(graph.n_edges, np.nan)
            edge_weights[e] = fres.edge_weights
        return AveragingResult(
            R, solved, residuals, inliers, fres.iterations, fres.cost, fres.converged, fres.method, anchor,
            fres.n_components, seconds, fres.stages, fres.rejected[group], frames, fres.outlier_threshold_deg, fres.diagnostics,
            edge_weights,
        )


def frame_problem(graph: ViewGraph, cam_from_rig: np.ndarray | None = None, qrel: np.ndarray | None = None) -> FrameProblem | None:
    """The frame-level problem of ``graph`` (which has :attr:`~ViewGraph.rigs`), or None
    when every image is a frame of its own with an identity ``cam_from_rig`` (nothing to
    gain: the image graph is solved as is). ``cam_from_rig`` (n, 3, 3): each image's, in
    place of ``graph.rigs.cam_from_rig`` (NaN rows: frames of their own); ``qrel``: the
    graph's :meth:`~ViewGraph.relative_quaternion_rows`, when the caller has them (a rig
    solve makes several frame problems of one graph). Raises :class:`UnsolvableError` when
    every pair lies within one frame."""
    group, S = _frame_groups(graph, cam_from_rig)
    n_groups = int(group.max()) + 1 if graph.n_nodes else 0
    if n_groups == graph.n_nodes and bool((np.abs(S - np.eye(3)) <= 1e-8 + 1e-5 * np.eye(3)).all()):  # np.allclose
        return None
    a, b = group[graph.edges[:, 0]], group[graph.edges[:, 1]]
    inter = a != b
    if not inter.any():
        raise UnsolvableError("every usable image pair lies within one rig frame: no frame-to-frame rotation")
    e = np.flatnonzero(inter)
    ia, ib = graph.edges[e, 0], graph.edges[e, 1]
    # R_frame = S_b^T R_ab S_a as quaternion products (5-10x faster than stacked 3x3 matmuls),
    # kept as quaternions (the frame solve wants them so).
    s = so3_rows.quaternion_rows_from_matrices(S)
    rel = so3_rows.qmul_rows(so3_rows.qmul_rows(so3_rows.qconj_rows(s[:, ib]), graph.relative_quaternion_rows(e) if qrel is None else qrel[:, e]), s[:, ia])
    # Built directly: the image graph was checked, and conjugates of rotations are rotations.
    # The error d of an image edge (camera b's frame) is S_b^T d in the frame's: information
    # S_b^T H S_b (3x3 products on contiguous rows (3, 3, E): so3_rows.congruence_rows).
    info = None
    if graph.information is not None:
        rows = np.ascontiguousarray(S.transpose(1, 2, 0))  # rows[a, b, k] = S_k[a, b]
        H = np.ascontiguousarray(graph.information[e].transpose(1, 2, 0))
        info = so3_rows.congruence_rows(rows[:, :, ib], H)
        info = np.ascontiguousarray(info.transpose(2, 0, 1))
    frame_graph = ViewGraph(np.arange(n_groups), np.stack([a[e], b[e]], axis=1), QuaternionRotations(rel), graph.weights[e],
                            information=info)
    logger.info("rig-aware solve: %d images in %d frames, %d frame edges (%d pairs within frames skipped)",
                graph.n_nodes, n_groups, len(e), int((~inter).sum()))
    problem = FrameProblem(graph, frame_graph, group, S, inter, e)
    if graph.gravity is not None:
        frame_graph.gravity = problem.frame_priors(graph.gravity)
    return problem


def lone_frames(graph: ViewGraph) -> FrameProblem:
    """The frame problem of ``graph`` in which every image is a frame of its own with an
    identity ``cam_from_rig`` (where :func:`frame_problem` gives None): the image graph
    itself, its gravity priors as every frame problem's (:meth:`FrameProblem.frame_priors`)."""
    n = graph.n_nodes
    problem = FrameProblem(graph, graph, np.arange(n), np.broadcast_to(np.eye(3), (n, 3, 3)).copy(),
                           np.ones(graph.n_edges, bool), np.arange(graph.n_edges))
    if graph.gravity is None:
        return problem
    frame_graph = graph.with_gravity(None)  # a copy
    frame_graph.gravity = problem.frame_priors(graph.gravity)
    return problem._replace(frame_graph=frame_graph)
