"""Relative rotations of image pairs from their two-view geometry, as COLMAP computes them.

COLMAP's ``EstimateTwoViewGeometryPose`` (colmap ``src/colmap/estimators/two_view_geometry.cc``)
turns a verified pair's E/F/H matrix, its inlier matches and the two cameras into
``cam2_from_cam1``. The COLMAP reader (:func:`rotgraph.pipeline.colmap.read_colmap_project`) calls
this module for the pairs whose relative pose the database does not store.

Speed: ``pycolmap.estimate_two_view_geometry_pose`` holds the GIL (measured: two threads
take the CPU time of one), so threads do not help. The CALIBRATED (E) and UNCALIBRATED
(F, ``E = K2^T F K1``) pairs, nearly all of them in practice, are therefore decomposed
vectorised in numpy (:func:`estimate_calibrated`): SVD of every E at once, the four
candidate poses, and COLMAP's cheirality vote (mid-point depths along both rays > 0) on up
to :data:`VOTE_SAMPLE` inliers per pair. A pair without a clear vote, and every homography
configuration, goes through pycolmap on all its inliers (:func:`estimate_poses`, in forked
worker processes when there are many). The rotations are those of pycolmap to 1e-12 deg on
every test and benchmark project, 5-7x faster.

This module does not import pycolmap: the caller passes the module (for the per-pair
routine) and its ``TwoViewGeometryConfiguration`` numbers; geometries and cameras are
pycolmap objects, used through their methods only.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from .. import so3

__all__ = ["VOTE_SAMPLE", "PARALLEL_MIN_PAIRS", "estimate_calibrated", "estimate_poses"]

#: Pairs left to pycolmap (homographies, unclear votes): below this many, one process is
#: faster than a pool of forked workers.
PARALLEL_MIN_PAIRS = 4000
#: The vectorised E decomposition votes on this many inlier rays per pair (all when fewer);
#: a pair without a clear vote goes through COLMAP's own routine on all its inliers.
VOTE_SAMPLE = 64


def _fit_missing_matrix(pycolmap, geometry, cam1, cam2, pts1, pts2) -> bool:
    """Fit the E/F/H matrix of ``geometry.config`` when the database did not store it
    (older COLMAP versions), as COLMAP's ``MaybeFitMissingTwoViewGeometryMatrix`` does."""
    name = pycolmap.TwoViewGeometryConfiguration(int(geometry.config)).name
    opts = pycolmap.RANSACOptions()
    opts.random_seed = 0
    try:
        if name == "CALIBRATED" and geometry.E is None:
            rep = pycolmap.estimate_essential_matrix(pts1, pts2, cam1, cam2, opts)
            if rep is None:
                return False
            geometry.E = rep["E"]
        elif name == "UNCALIBRATED" and geometry.F is None:
            rep = pycolmap.estimate_fundamental_matrix(pts1, pts2, opts)
            if rep is None:
                return False
            geometry.F = rep["F"]
        elif name in ("PLANAR", "PANORAMIC", "PLANAR_OR_PANORAMIC") and geometry.H is None:
            rep = pycolmap.estimate_homography_matrix(pts1, pts2, opts)
            if rep is None:
                return False
            geometry.H = rep["H"]
    except Exception:
        return False
    return True


def _estimate_pose(pycolmap, geometry, cam1, cam2, pts1: np.ndarray, pts2: np.ndarray):
    """``(quaternion (w, x, y, z) of cam2_from_cam1, reason)``; reason is None on success.

    ``pts1``/``pts2`` are the pixel coordinates of the inlier matches, in order; the
    geometry's inlier matches are re-indexed to them (only they are used by COLMAP).
    """
    m = len(pts1)
    geometry.inlier_matches = np.repeat(np.arange(m, dtype=np.uint32)[:, None], 2, axis=1)
    for attempt in (0, 1):
        try:
            ok = pycolmap.estimate_two_view_geometry_pose(cam1, pts1, cam2, pts2, geometry)
        except Exception:
            ok = False
            if attempt == 0 and _fit_missing_matrix(pycolmap, geometry, cam1, cam2, pts1, pts2):
                continue
            return None, "pose estimation failed (no usable E/F/H)"
        break
    if not ok or geometry.cam2_from_cam1 is None:
        return None, "pose estimation failed (cheirality)"
    q = np.asarray(geometry.cam2_from_cam1.rotation.quat, dtype=np.float64)  # x, y, z, w
    if not np.all(np.isfinite(q)):
        return None, "pose estimation failed (non-finite)"
    return np.array([q[3], q[0], q[1], q[2]]), None


def _calibrated_rotations(E: np.ndarray, rays1: np.ndarray, rays2: np.ndarray, seg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """COLMAP's ``PoseFromEssentialMatrix`` for many pairs at once: the rotation of the
    candidate pose (of the four in ``DecomposeEssentialMatrix``) with the most inlier rays
    in front of both cameras (``CheckCheirality``, mid-point depths > 0).

    ``E`` (P, 3, 3); ``rays1``/``rays2`` (M, 3) unit bearing vectors of the inlier matches
    of all pairs, ``seg`` (M,) their pair index. Returns the candidate rotations
    ``(R1, R2)`` (each (P, 3, 3)) and the counts (4, P) of rays in front for the candidates
    ``(R1, t), (R2, t), (R1, -t), (R2, -t)``, COLMAP's order.
    """
    P = len(E)
    U, _, Vt = np.linalg.svd(E)
    U = U * np.sign(np.linalg.det(U))[:, None, None]
    Vt = Vt * np.sign(np.linalg.det(Vt))[:, None, None]
    W = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    cands = (U @ W @ Vt, U @ W.T @ Vt)
    t = U[:, :, 2]
    # The rays of each pair in a padded (P, K, 3) block: per-pair products, no gathers.
    if len(seg) > 1 and (np.diff(seg) < 0).any():  # group the rays by pair
        order = np.argsort(seg, kind="stable")
        seg, rays1, rays2 = seg[order], rays1[order], rays2[order]
    per_pair = np.bincount(seg, minlength=P)
    K = int(per_pair.max()) if len(seg) else 0
    slot = np.arange(len(seg)) - (np.cumsum(per_pair) - per_pair)[seg]
    A = np.zeros((P, K, 3))
    B = np.zeros((P, K, 3))
    real = np.zeros((P, K), dtype=bool)
    A[seg, slot], B[seg, slot], real[seg, slot] = rays1, rays2, True
    n2 = (B @ t[:, :, None])[:, :, 0]  # ray2 . t
    counts = np.zeros((4, P))
    eps = np.finfo(float).eps
    for c, R in enumerate(cands):
        RA = A @ np.swapaxes(R, 1, 2)  # R ray1
        n1 = (RA @ t[:, :, None])[:, :, 0]  # (R ray1) . t
        cosang = np.einsum("pki,pki->pk", RA, B)  # (R ray1) . ray2
        ok = real & (1.0 - cosang * cosang > eps)  # a match, rays not parallel
        # depths along ray1 and ray2, times 1 - cos^2 > 0, for +t; both flip for -t
        d1 = cosang * n2 - n1
        d2 = n2 - cosang * n1
        counts[c] = (ok & (d1 > 0) & (d2 > 0)).sum(axis=1)
        counts[c + 2] = (ok & (d1 < 0) & (d2 < 0)).sum(axis=1)
    return cands, counts


def _decide_rotations(cands, counts, n: np.ndarray, exact: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rotation of COLMAP's winning candidate (the first of the largest counts). Where
    the counts come from a sample of the inliers (``~exact``), accept only a clear vote
    (the winning rotation has >= 80 % of the sample in front, the other <= 20 %)."""
    best = np.argmax(counts, axis=0)
    R = np.where((best % 2 == 0)[:, None, None], cands[0], cands[1])
    c1 = np.maximum(counts[0], counts[2])
    c2 = np.maximum(counts[1], counts[3])
    top, other = np.maximum(c1, c2), np.minimum(c1, c2)
    ok = (top > 0) & (exact | ((top >= 0.8 * n) & (other <= 0.2 * n)))
    return R, ok & np.isfinite(R).all(axis=(1, 2))


def estimate_calibrated(
    todo: list[int], geometries, inliers, pairs, cam_of, keypoints, *, calibrated: int, uncalibrated: int
) -> tuple[dict, list[int]]:
    """Vectorised relative rotations of the CALIBRATED pairs with a stored E and the
    UNCALIBRATED ones with a stored F (the common cases), identical to COLMAP's
    ``EstimateTwoViewGeometryPose``: ``({k: quaternion (w, x, y, z)}, [k left to
    pycolmap, per pair])``. Homography configurations (PLANAR, PANORAMIC, ...) and pairs
    without a clear cheirality vote are left to :func:`estimate_poses`.

    ``todo``: pair indices into ``geometries`` (pycolmap ``TwoViewGeometry``), ``inliers``
    ((m, 2) keypoint indices) and ``pairs`` ((image_id1, image_id2)); ``cam_of``: image id
    -> ``pycolmap.Camera``; ``keypoints``: image id -> (K, 2) pixel coordinates;
    ``calibrated``/``uncalibrated``: the numbers of those ``TwoViewGeometryConfiguration``\\ s.
    """
    K: dict = {}

    def calibration(i):  # None for cameras without a pinhole calibration matrix
        if i not in K:
            try:
                K[i] = None if cam_of[i].is_spherical() else np.asarray(cam_of[i].calibration_matrix(), dtype=np.float64)
            except Exception:
                K[i] = None
        return K[i]

    sel, rest, Es = [], [], []
    for k in todo:
        g = geometries[k]
        config = int(g.config)
        E = None
        if config == calibrated and g.E is not None:
            E = np.asarray(g.E, dtype=np.float64)
        elif config == uncalibrated and g.F is not None:
            # COLMAP: E = K2^T F K1 (EssentialFromFundamentalMatrix), then as CALIBRATED
            K1, K2 = calibration(pairs[k][0]), calibration(pairs[k][1])
            if K1 is not None and K2 is not None:
                E = K2.T @ np.asarray(g.F, dtype=np.float64) @ K1
        if E is None or not np.isfinite(E).all():
            rest.append(k)
        else:
            sel.append(k)
            Es.append(E)
    if not sel:
        return {}, rest
    # Unit bearing rays of every keypoint of the images involved, in one table.
    imgs = sorted({x for k in sel for x in pairs[k]})
    offset, tables, n = {}, [], 0
    for i in imgs:
        kp = keypoints[i]
        r = np.asarray(cam_of[i].cam_ray_from_img(kp), dtype=np.float64).reshape(-1, 3) if len(kp) else np.zeros((0, 3))
        tables.append(r / np.maximum(np.linalg.norm(r, axis=1, keepdims=True), 1e-300))
        offset[i] = n
        n += len(r)
    table = np.concatenate(tables)
    out: dict = {}
    ramp = np.arange(VOTE_SAMPLE)
    lo = 0
    while lo < len(sel):  # chunks of at most ~2e6 matches
        hi, size = lo, 0
        while hi < len(sel) and (size < 2_000_000 or hi == lo):
            size += min(len(inliers[sel[hi]]), VOTE_SAMPLE)
            hi += 1
        chunk = sel[lo:hi]
        sample = [inliers[k] if len(inliers[k]) <= VOTE_SAMPLE else inliers[k][(ramp * (len(inliers[k]) - 1)) // (VOTE_SAMPLE - 1)] for k in chunk]
        counts = np.array([len(x) for x in sample])
        exact = np.array([len(inliers[k]) <= VOTE_SAMPLE for k in chunk])
        inl = np.concatenate(sample).astype(np.int64)
        off1 = np.repeat([offset[pairs[k][0]] for k in chunk], counts)
        off2 = np.repeat([offset[pairs[k][1]] for k in chunk], counts)
        seg = np.repeat(np.arange(len(chunk)), counts)
        cands, votes = _calibrated_rotations(np.stack(Es[lo:hi]), table[inl[:, 0] + off1], table[inl[:, 1] + off2], seg)
        R, good = _decide_rotations(cands, votes, counts, exact)
        q = so3.quaternions_from_matrices(np.where(good[:, None, None], R, np.eye(3)))
        for p, k in enumerate(chunk):
            if good[p]:
                out[k] = q[p]
            else:
                rest.append(k)  # let COLMAP's own routine decide (and report) the pair
        lo = hi
    return out, rest


class _PoseJobs(NamedTuple):
    """Everything the per-pair pycolmap routine needs; inherited, not pickled, by forked
    workers."""

    pycolmap: object
    geometries: list
    pairs: list
    cam_of: dict
    points: Callable  # k -> (pts1, pts2), the pixel coordinates of pair k's inlier matches

    def estimate(self, k: int):
        i, j = self.pairs[k]
        return _estimate_pose(self.pycolmap, self.geometries[k], self.cam_of[i], self.cam_of[j], *self.points(k))


# The jobs of a forked worker process, set once by _start_worker when it starts (never in
# the parent process).
_worker_jobs: _PoseJobs | None = None


def _start_worker(jobs: _PoseJobs) -> None:
    global _worker_jobs
    _worker_jobs = jobs


def _estimate_chunk(indices: list[int]) -> list:
    return [_worker_jobs.estimate(k) for k in indices]


def estimate_poses(pycolmap, todo: list[int], geometries, pairs, cam_of, points, workers=None, progress=None) -> list:
    """COLMAP's own ``estimate_two_view_geometry_pose`` for the pairs ``todo`` (indices;
    see :func:`estimate_calibrated` for the containers, ``points(k)`` gives pair ``k``'s
    inlier pixel coordinates ``(pts1, pts2)``): one ``(quaternion or None, reason or
    None)`` per pair, in order. Serial, or with a pool of ``workers`` forked processes
    (None: up to 8 from :data:`PARALLEL_MIN_PAIRS` pairs on; pycolmap holds the GIL in these
    calls, so threads do not help). ``progress(done, total)`` is told after every chunk of
    pairs."""
    jobs = _PoseJobs(pycolmap, geometries, pairs, cam_of, points)
    n = len(todo)
    report = progress or (lambda done, total: None)
    if workers is None:
        cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
        workers = min(cpus, 8) if n >= PARALLEL_MIN_PAIRS else 1
    workers = max(1, int(workers))
    # Workers are forked (cheap, nothing pickled but the indices and results): Linux only.
    if workers == 1 or n < 2 * workers or not sys.platform.startswith("linux"):
        out = []
        for k in todo:
            out.append(jobs.estimate(k))
            if len(out) % 64 == 0 or len(out) == n:
                report(len(out), n)
        return out
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    size = max(64, n // (workers * 8))
    chunks = [todo[s : s + size] for s in range(0, n, size)]
    parts, done = [], 0
    with ProcessPoolExecutor(workers, mp_context=mp.get_context("fork"), initializer=_start_worker, initargs=(jobs,)) as ex:
        for part in ex.map(_estimate_chunk, chunks):  # in order, as they finish
            parts.append(part)
            done += len(part)
            report(done, n)
    return [r for part in parts for r in part]
