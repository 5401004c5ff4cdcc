"""Synthetic problems with known ground truth: view graphs (:func:`random_problem`) and
COLMAP projects (:func:`synthesize_colmap_project`, for tests and benchmarks)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from . import so3
from .choices import GRAPHS
from .viewgraph import ViewGraph

__all__ = ["random_problem", "synthesize_colmap_project", "GRAPHS"]



def _er_pairs(n: int, n_edges: int, rng) -> np.ndarray:
    """A random spanning tree (connectivity guaranteed) plus uniform random extra pairs."""
    perm = rng.permutation(n)
    # Random recursive tree: node perm[k] attaches to a random earlier node.
    parents = perm[(rng.random(n - 1) * np.arange(1, n)).astype(np.int64)]
    pairs = np.stack([parents, perm[1:]], axis=1)
    keys = set((np.minimum(pairs[:, 0], pairs[:, 1]) * n + np.maximum(pairs[:, 0], pairs[:, 1])).tolist())
    target = min(n_edges, n * (n - 1) // 2)
    extra = []
    while len(keys) < target:
        m = int((target - len(keys)) * 1.3) + 16
        a = rng.integers(0, n, m)
        b = rng.integers(0, n, m)
        ok = a != b
        k = np.minimum(a[ok], b[ok]) * n + np.maximum(a[ok], b[ok])
        k = np.unique(k)
        k = k[~np.isin(k, np.fromiter(keys, dtype=np.int64, count=len(keys)))]
        k = rng.permutation(k)[: target - len(keys)]
        keys.update(k.tolist())
        extra.append(k)
    if extra:
        k = np.concatenate(extra)
        pairs = np.concatenate([pairs, np.stack([k // n, k % n], axis=1)])
    flip = rng.random(len(pairs)) < 0.5  # both edge directions occur
    pairs[flip] = pairs[flip][:, ::-1]
    return pairs


def _trajectory(n: int, degree: float, rng) -> tuple[np.ndarray, np.ndarray]:
    """Cameras on a smooth path (yaw sweep with wobble), edges to the next k cameras plus
    random loop closures (10 % of the edges)."""
    t = np.linspace(0, 4 * np.pi, n)
    v = np.stack([0.1 * np.sin(3 * t), t, 0.1 * np.cos(2 * t)], axis=1) + 0.02 * rng.standard_normal((n, 3))
    R = so3.exp(v)
    k = max(1, int(round(0.45 * degree)))
    ii = np.concatenate([np.arange(n - d) for d in range(1, k + 1)])
    jj = np.concatenate([np.arange(d, n) for d in range(1, k + 1)])
    n_loop = max(0, int(0.1 * len(ii)))
    a = rng.integers(0, n, 3 * n_loop + 8)
    b = rng.integers(0, n, 3 * n_loop + 8)
    ok = np.abs(a - b) > k
    pairs = np.concatenate([np.stack([ii, jj], 1), np.stack([a[ok], b[ok]], 1)[:n_loop]])
    lo, hi = np.minimum(pairs[:, 0], pairs[:, 1]), np.maximum(pairs[:, 0], pairs[:, 1])
    _, first = np.unique(lo * n + hi, return_index=True)
    return R, pairs[np.sort(first)]


def random_problem(
    n: int = 100,
    degree: float = 10.0,
    sigma_deg: float = 2.0,
    outliers: float = 0.0,
    graph: str = "er",
    seed: int | None = 0,
) -> ViewGraph:
    """A random view graph with ground truth (``graph.gt_cam_from_world``).

    ``n`` cameras with uniformly random rotations (``er``) or along a trajectory (``traj``),
    about ``n * degree / 2`` edges, each ``R_ij = R_j R_i^T exp(e)`` with isotropic noise
    ``e ~ N(0, sigma^2 I)`` (sigma in degrees), and a fraction ``outliers`` of the edges
    replaced by uniformly random rotations. ``graph.meta["outlier"]`` flags those edges.
    """
    if graph not in GRAPHS:
        raise ValueError(f"graph must be one of {GRAPHS}")
    if n < 2:
        raise ValueError("need at least 2 cameras")
    rng = np.random.default_rng(seed)
    if graph == "er":
        R = so3.random_rotations(n, rng)
        pairs = _er_pairs(n, int(round(n * degree / 2)), rng)
    else:
        R, pairs = _trajectory(n, degree, rng)
    i, j = pairs[:, 0], pairs[:, 1]
    rel = R[j] @ np.swapaxes(R[i], 1, 2)
    if sigma_deg > 0:
        rel = so3.perturb(rel, np.deg2rad(sigma_deg), rng)
    is_out = rng.random(len(pairs)) < outliers
    rel[is_out] = so3.random_rotations(int(is_out.sum()), rng)
    g = ViewGraph.from_edges(i, j, rel, node_ids=np.arange(n))
    g.gt_cam_from_world = R
    g.meta.update(outlier=is_out, sigma_deg=sigma_deg, outliers=outliers, graph=graph, seed=seed)
    return g


def synthesize_colmap_project(
    folder,
    *,
    n_frames: int = 20,
    cameras_per_rig: int = 1,
    n_points: int = 400,
    noise_px: float = 1.0,
    outlier_match_ratio: float = 0.3,
    doppelgangers: int = 0,
    doppelganger_angle_deg: tuple = (30.0, 90.0),
    match_sparsity: float = 0.0,
    store_relative_pose: bool = False,
    prior_focal_length: bool = True,
    sensor_rotation_deg: float = 5.0,
    model_format: str = "bin",
    seed: int = 0,
) -> dict:
    """Write a realistic COLMAP project into ``folder`` with pycolmap's synthetic tools
    (for tests and benchmarks): ``database.db`` + ground-truth model ``sparse/0``.

    ``pycolmap.synthesize_dataset`` makes the scene, cameras (one rig of
    ``cameras_per_rig`` sensors; ``n_frames`` frames), keypoints and raw matches with
    ``outlier_match_ratio`` wrong matches; ``pycolmap.synthesize_noise`` adds
    ``noise_px`` pixel noise to the keypoints; ``doppelgangers`` image pairs get their
    matches replaced by consistent matches of a rotated copy of the scene (a wrong but
    geometrically valid pair, rotated by an angle in ``doppelganger_angle_deg``); finally
    COLMAP's geometric verification (``pycolmap.geometric_verification``) estimates the
    two-view geometries, storing ``cam2_from_cam1`` when ``store_relative_pose``.
    Returns a dict with the paths, counts and the doppelganger pairs.
    """
    from .io.colmap import _pycolmap

    pycolmap = _pycolmap()
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    db_path = folder / "database.db"
    if db_path.exists():
        db_path.unlink()
    rng = np.random.default_rng(seed)
    pycolmap.set_random_seed(int(seed))
    opts = pycolmap.SyntheticDatasetOptions()
    opts.num_rigs = 1
    opts.num_cameras_per_rig = int(cameras_per_rig)
    opts.num_frames_per_rig = int(n_frames)
    opts.num_points3D = int(n_points)
    opts.camera_has_prior_focal_length = bool(prior_focal_length)
    opts.inlier_match_ratio = float(1.0 - outlier_match_ratio)
    opts.sensor_from_rig_rotation_stddev = float(sensor_rotation_deg)
    if match_sparsity > 0:
        opts.match_config = pycolmap.SyntheticDatasetMatchConfig.SPARSE
        opts.match_sparsity = float(match_sparsity)
    db = pycolmap.Database.open(str(db_path))
    try:
        rec = pycolmap.synthesize_dataset(opts, db)
        if noise_px > 0:
            noise = pycolmap.SyntheticNoiseOptions()
            noise.point2D_stddev = float(noise_px)
            pycolmap.synthesize_noise(noise, rec, db)
        fakes = _add_doppelgangers(pycolmap, db, rec, doppelgangers, doppelganger_angle_deg, noise_px, rng)
        db.clear_two_view_geometries()
    finally:
        db.close()
    tvg = pycolmap.TwoViewGeometryOptions()
    tvg.compute_relative_pose = bool(store_relative_pose)
    tvg.ransac.random_seed = int(seed)
    verifier = pycolmap.GeometricVerifierOptions()
    pycolmap.geometric_verification(str(db_path), verifier_options=verifier, two_view_geometry_options=tvg)
    model = folder / "sparse" / "0"
    model.mkdir(parents=True, exist_ok=True)
    if model_format == "txt":
        rec.write_text(str(model))
    else:
        rec.write_binary(str(model))
    return {
        "database": str(db_path),
        "model": str(model),
        "n_images": rec.num_images(),
        "n_frames": rec.num_frames(),
        "doppelgangers": fakes,
    }


def _add_doppelgangers(pycolmap, db, rec, count: int, angle_range, noise_px: float, rng) -> list:
    """Replace the matches of ``count`` random image pairs by matches of a rotated copy
    of the scene: image ``j`` sees the world rotated by W about the scene centre, so the
    pair's geometry is consistent but its relative rotation is off by W."""
    if count <= 0:
        return []
    image_ids = sorted(int(i) for i in rec.reg_image_ids())
    pts = {int(k): np.asarray(p.xyz) for k, p in rec.points3D.items()}
    centre = np.mean(np.stack(list(pts.values())), axis=0)
    done, tries = [], 0
    while len(done) < count and tries < 50 * count:
        tries += 1
        i, j = (int(x) for x in rng.choice(image_ids, 2, replace=False))
        if i > j:
            i, j = j, i
        if (i, j) in [(a, b) for a, b, _ in done]:
            continue
        im_i, im_j = rec.images[i], rec.images[j]
        if im_i.frame_id == im_j.frame_id:
            continue
        cam_j = rec.cameras[im_j.camera_id]
        angle = np.deg2rad(rng.uniform(*angle_range))
        axis = rng.standard_normal(3)
        W = so3.exp(axis / np.linalg.norm(axis) * angle)
        T_j = im_j.cam_from_world()
        Rj, tj = so3.from_pycolmap(T_j.rotation), np.asarray(T_j.translation)
        idx_i, xyz = [], []
        for k, p2 in enumerate(im_i.points2D):
            if p2.has_point3D():
                idx_i.append(k)
                xyz.append(pts[int(p2.point3D_id)])
        if len(idx_i) < 30:
            continue
        X = (np.asarray(xyz) - centre) @ W.T + centre  # the rotated scene
        Xc = X @ Rj.T + tj
        front = Xc[:, 2] > 1e-6
        uv = np.full((len(Xc), 2), np.nan)
        if front.any():
            uv[front] = cam_j.img_from_cam(Xc[front])
        inside = front & np.isfinite(uv).all(axis=1) & (uv[:, 0] >= 0) & (uv[:, 0] < cam_j.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam_j.height)
        if inside.sum() < 30:
            continue
        uv = uv[inside] + noise_px * rng.standard_normal((int(inside.sum()), 2))
        kp = np.asarray(db.read_keypoints(j), dtype=np.float32)
        new = np.zeros((len(uv), kp.shape[1]), dtype=np.float32)
        new[:, :2] = uv
        if kp.shape[1] >= 4:  # scale / orientation or affine shape columns
            new[:, 2:] = kp[: 1, 2:] if len(kp) else 0
        db.update_keypoints(j, np.vstack([kp, new]))
        matches = np.stack([np.asarray(idx_i)[inside], len(kp) + np.arange(len(uv))], axis=1).astype(np.uint32)
        if db.exists_matches(i, j):
            db.delete_matches(i, j)
        db.write_matches(i, j, matches)
        done.append((i, j, float(np.degrees(angle))))
    return done
