"""COLMAP projects with known ground truth, made with pycolmap's synthetic tools (for tests
and benchmarks): :func:`synthesize_colmap_project` (also :func:`rotgraph.synth.synthesize_colmap_project`),
:func:`add_doppelgangers`. The view-graph problems: :mod:`rotgraph.synth`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from . import so3

__all__ = ["synthesize_colmap_project", "add_doppelgangers"]


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
    overwrite: bool = False,
) -> dict:
    """Write a realistic COLMAP project into ``folder`` with pycolmap's synthetic tools
    (for tests and benchmarks): ``database.db`` + ground-truth model ``sparse/0``. A
    folder that already holds either is an :class:`~rotgraph.errors.InputError` unless
    ``overwrite`` (the output rule: a project is never replaced unasked).

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
    from .io.colmap_project import import_pycolmap

    pycolmap = import_pycolmap()
    folder = Path(folder)
    db_path = folder / "database.db"
    if not overwrite and (db_path.exists() or (folder / "sparse" / "0").exists()):
        from .errors import InputError

        raise InputError("holds a COLMAP project already (database.db or sparse/0); overwrite=True replaces it",
                         path=str(folder))
    folder.mkdir(parents=True, exist_ok=True)
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
        fakes = add_doppelgangers(pycolmap, db, rec, doppelgangers, doppelganger_angle_deg, noise_px, rng)
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


def add_doppelgangers(pycolmap, db, rec, count: int, angle_range, noise_px: float, rng) -> list:
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
