#!/usr/bin/env python
"""rotgraph's rig solve vs COLMAP 4's rig rotation averaging (issue #17, item 4).

Run from the repository root::

    python benchmarks/bench_rigs.py                 # all problems (see PROBLEMS)
    python benchmarks/bench_rigs.py --quick         # two small problems, under ~2 min
    python benchmarks/bench_rigs.py --problems r2x20,r4x100 --repeats 5 --out results.json

Problems: synthetic COLMAP projects with rigs, made here with pycolmap's
``synthesize_dataset`` (``num_rigs`` rigs of ``num_cameras_per_rig`` sensors, each rig
``num_frames_per_rig`` frames; sensor_from_rig rotations drawn with
``sensor_from_rig_rotation_stddev`` degrees), 1 px keypoint noise, 30 % wrong raw matches,
then COLMAP's geometric verification (``pycolmap.geometric_verification``). Ground truth =
the synthetic reconstruction, written as a model beside (not inside) the projects. Each
problem in four variants, all sharing the scene:

* ``known``: the database's rigs carry every sensor's ``sensor_from_rig`` (the truth);
* ``unknown``: the same database with the non-reference sensors' ``sensor_from_rig``
  removed (``Rig.reset_sensor_from_rig(sensor)`` + ``Database.update_rig``): the sensor
  stays in the rig, ``Rig.has_sensor_from_rig`` is False and ``Rig.sensor_from_rig``
  returns None, for COLMAP and for rotgraph's reader alike;
* ``known+wrong`` / ``unknown+wrong``: about 10 % of the image pairs are wrong two-view
  geometries: doppelganger pairs (``rotgraph.synth_colmap.add_doppelgangers``: the pair's matches
  replaced by consistent matches of a rotated copy of the scene, 30-90 deg, never two
  images of one frame), verified again by COLMAP; the measured fraction of graph edges
  more than 5 deg from the truth is the ``wrong`` column.

Contenders, on exactly the same relative poses:

* **rotgraph**: ``rotgraph.pipeline.read.read_view_graph(project)`` (as ``rotgraph solve``
  reads: relative poses estimated from the inliers, each pair's information), then
  ``average_rotations(graph, default_options("colmap"))``; ``solve`` times that call only.
* **COLMAP 4**: ``pycolmap.run_rotation_averaging(RotationEstimatorOptions(random_seed=0,
  refine_sensor_from_rig=True), PoseGraph, Reconstruction, [])`` with the pose graph of
  ``bench_colmap.run_glomap_ra`` (rotgraph's edges, ``num_matches`` = inliers) and the
  reconstruction of ``rotgraph.io.colmap_model.unposed_reconstruction`` (the database's
  cameras, rigs -- unknown sensor_from_rig included --, frames and images); ``solve``
  times the call only. Its estimated extrinsics are read back from the reconstruction's
  rigs after the call (``rec.rigs[rig_id].sensor_from_rig(sensor).rotation``; the
  translation is NaN: rotation averaging estimates rotations only).

Errors: image rotations per image after the gauge alignment
(``rotgraph.evaluate.compare_rotations``) vs the ground-truth model, matched by name;
extrinsics per non-reference sensor, the angle between the estimated and the true
``cam_from_rig`` rotation (gauge free). rotgraph's extrinsics are ``result.sensors``
(``SensorSolution``) when rotgraph has it, otherwise derived from its image rotations: per
sensor the geodesic L1 median over the frames of ``R_image R_ref_image^T`` (the table
marks such columns ``derived``). Ratios are rotgraph / COLMAP (below 1: rotgraph better
or faster). Times: median over ``--repeats`` runs.

Generated projects are cached under ``$TMPDIR/rotgraph-bench-rigs`` (``--cache DIR``
elsewhere, ``--fresh`` to regenerate), never in the repository.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # see bench_multiple.py
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import json
import platform
import shutil
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import pycolmap  # noqa: E402
from _common import cpu_model, git_commit, load_average, usable_cpus  # noqa: E402
from bench_colmap import captured_stderr, errors  # noqa: E402

from rotgraph import so3  # noqa: E402
from rotgraph.estimators.rotation_averaging import average_rotations  # noqa: E402
from rotgraph.estimators.single import mean as rotation_mean  # noqa: E402
from rotgraph.io.colmap import to_pycolmap  # noqa: E402
from rotgraph.io.colmap_model import unposed_reconstruction  # noqa: E402
from rotgraph.pipeline.read import read_view_graph  # noqa: E402
from rotgraph.pipeline.solve import default_options  # noqa: E402
from rotgraph.synth_colmap import add_doppelgangers  # noqa: E402

#: Bump when the generator changes: cached projects of another version are remade.
GENERATOR_VERSION = 1

PROBLEMS = {
    # name: rigs x sensors per rig x frames per rig; sensor_deg = stddev of the
    # sensor_from_rig rotations. Matched pairs: all (``sparsity`` 0), a random fraction
    # ``1 - sparsity`` (pycolmap's SPARSE match config), or, for the large problems where
    # pycolmap's SPARSE config is too slow (400 images: 99 s), ``degree``: random image pairs
    # of that mean degree written by :func:`_write_random_matches`.
    "r2x20": dict(rigs=1, sensors=2, frames=20, points=400, sparsity=0.0, sensor_deg=20.0, seed=11),
    "r3x40": dict(rigs=1, sensors=3, frames=40, points=400, sparsity=0.75, sensor_deg=20.0, seed=12),
    "2rigs-3x40": dict(rigs=2, sensors=3, frames=40, points=400, sparsity=0.85, sensor_deg=20.0, seed=13),
    "r4x100": dict(rigs=1, sensors=4, frames=100, points=400, degree=16, sensor_deg=20.0, seed=14),
    "r6x60": dict(rigs=1, sensors=6, frames=60, points=400, degree=16, sensor_deg=20.0, seed=15),
    "r2x500": dict(rigs=1, sensors=2, frames=500, points=400, degree=12, sensor_deg=20.0, seed=16),
    "r6x500": dict(rigs=1, sensors=6, frames=500, points=300, degree=8, sensor_deg=20.0, seed=17),
}
QUICK = ("r2x20", "r3x40")
VARIANTS = ("known", "unknown", "known+wrong", "unknown+wrong")
WRONG_FRACTION = 0.10
WRONG_EDGE_DEG = 5.0  # a graph edge this far from the truth counts as wrong
NOISE_PX = 1.0
OUTLIER_MATCH_RATIO = 0.3


def log(msg: str) -> None:
    print(f"[bench_rigs] {msg}", file=sys.stderr, flush=True)


# =========================================================================== problems


def _verify(db_path: Path, seed: int) -> None:
    """COLMAP's geometric verification of the pairs without a two-view geometry yet."""
    tvg = pycolmap.TwoViewGeometryOptions()
    tvg.compute_relative_pose = False
    tvg.ransac.random_seed = int(seed)
    pycolmap.geometric_verification(str(db_path), verifier_options=pycolmap.GeometricVerifierOptions(), two_view_geometry_options=tvg)


def _write_random_matches(db, rec, degree: float, rng) -> int:
    """Add raw matches for random image pairs (mean degree ``degree``, pairs already matched
    kept) as pycolmap's synthetic matcher makes them: the keypoints of the 3D points both
    images see, plus OUTLIER_MATCH_RATIO of random keypoint pairs. Returns the pairs added."""
    ids = np.array(sorted(int(i) for i in rec.reg_image_ids()))
    n = len(ids)
    point_of = {}  # image id -> {point3D id: keypoint index}
    n_kp = {}
    for iid in ids:
        pts = rec.images[int(iid)].points2D
        n_kp[int(iid)] = len(pts)
        point_of[int(iid)] = {int(p.point3D_id): k for k, p in enumerate(pts) if p.has_point3D()}
    want = int(round(degree * n / 2))
    pairs = set()
    while len(pairs) < want:
        a = rng.integers(0, n, 2 * want)
        b = rng.integers(0, n, 2 * want)
        for x, y in zip(a, b):
            if x != y:
                pairs.add((min(x, y), max(x, y)))
            if len(pairs) >= want:
                break
    added = 0
    for x, y in sorted(pairs):
        i, j = int(ids[x]), int(ids[y])
        if db.exists_matches(i, j):
            continue
        common = sorted(set(point_of[i]) & set(point_of[j]))
        if len(common) < 15:
            continue
        inl = np.array([[point_of[i][p], point_of[j][p]] for p in common], dtype=np.int64)
        n_out = int(round(len(inl) * OUTLIER_MATCH_RATIO / (1.0 - OUTLIER_MATCH_RATIO)))
        out = np.stack([rng.integers(0, n_kp[i], n_out), rng.integers(0, n_kp[j], n_out)], axis=1)
        m = np.concatenate([inl, out])[rng.permutation(len(inl) + n_out)]
        db.write_matches(i, j, m.astype(np.uint32))
        added += 1
    return added


def _forget_extrinsics(db_path: Path) -> int:
    """Remove every non-reference sensor's sensor_from_rig from the database's rigs (the
    sensor stays in its rig, uncalibrated); returns the number of sensors changed."""
    db = pycolmap.Database.open(str(db_path))
    n = 0
    try:
        for rig in db.read_all_rigs():
            for sensor in list(rig.non_ref_sensors):
                rig.reset_sensor_from_rig(sensor)
                n += 1
            db.update_rig(rig)
    finally:
        db.close()
    return n


def _n_verified(db_path: Path) -> int:
    db = pycolmap.Database.open(str(db_path))
    try:
        return int(db.num_verified_image_pairs())
    finally:
        db.close()


def make_problem(folder: Path, spec: dict) -> dict:
    """Write ``folder/gt`` (the ground-truth model) and ``folder/<variant>/database.db`` for
    the four :data:`VARIANTS`; returns the problem's description (also in ``problem.json``)."""
    if folder.exists():
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    seed = int(spec["seed"])
    rng = np.random.default_rng(seed)
    pycolmap.set_random_seed(seed)
    opts = pycolmap.SyntheticDatasetOptions()
    opts.num_rigs = int(spec["rigs"])
    opts.num_cameras_per_rig = int(spec["sensors"])
    opts.num_frames_per_rig = int(spec["frames"])
    opts.num_points3D = int(spec["points"])
    opts.camera_has_prior_focal_length = True
    opts.inlier_match_ratio = 1.0 - OUTLIER_MATCH_RATIO
    opts.sensor_from_rig_rotation_stddev = float(spec["sensor_deg"])
    if "degree" in spec:  # a chain only: the random pairs are written below
        opts.match_config = pycolmap.SyntheticDatasetMatchConfig.CHAINED
    elif spec.get("sparsity", 0) > 0:
        opts.match_config = pycolmap.SyntheticDatasetMatchConfig.SPARSE
        opts.match_sparsity = float(spec["sparsity"])
    known = folder / "known"
    known.mkdir()
    db_path = known / "database.db"
    t0 = time.perf_counter()
    db = pycolmap.Database.open(str(db_path))
    try:
        rec = pycolmap.synthesize_dataset(opts, db)
        if "degree" in spec:
            _write_random_matches(db, rec, float(spec["degree"]), rng)
        noise = pycolmap.SyntheticNoiseOptions()
        noise.point2D_stddev = NOISE_PX
        pycolmap.synthesize_noise(noise, rec, db)
        db.clear_two_view_geometries()
    finally:
        db.close()
    gt = folder / "gt"
    gt.mkdir()
    rec.write_binary(str(gt))
    _verify(db_path, seed)
    n_pairs = _n_verified(db_path)
    n_images = rec.num_images()
    # doppelgangers: replace existing pairs (dense matching) or add new ones (sparse), so
    # that about WRONG_FRACTION of the final pairs are wrong
    density = n_pairs / max(1, n_images * (n_images - 1) // 2)
    count = int(round(WRONG_FRACTION * n_pairs / (1.0 - WRONG_FRACTION * (1.0 - density))))
    wrong = folder / "known+wrong"
    wrong.mkdir()
    shutil.copyfile(db_path, wrong / "database.db")
    db = pycolmap.Database.open(str(wrong / "database.db"))
    try:
        fakes = add_doppelgangers(pycolmap, db, rec, count, (30.0, 90.0), NOISE_PX, rng)
        for i, j, _ in fakes:
            if db.exists_two_view_geometry(i, j):
                db.delete_two_view_geometry(i, j)
    finally:
        db.close()
    _verify(wrong / "database.db", seed)  # only the doppelganger pairs
    for base in ("known", "known+wrong"):
        other = folder / base.replace("known", "unknown")
        other.mkdir()
        shutil.copyfile(folder / base / "database.db", other / "database.db")
        _forget_extrinsics(other / "database.db")
    info = dict(spec=spec, n_images=n_images, n_frames=rec.num_frames(), n_rigs=rec.num_rigs(), n_pairs=n_pairs,
                n_doppelgangers=len(fakes), generator_version=GENERATOR_VERSION, seconds=time.perf_counter() - t0)
    (folder / "problem.json").write_text(json.dumps(info, indent=1))
    return info


def cached_problem(cache: Path, name: str, fresh: bool) -> tuple[Path, dict]:
    spec = PROBLEMS[name]
    folder = cache / f"{name}-v{GENERATOR_VERSION}"
    marker = folder / "problem.json"
    if not fresh and marker.is_file():
        info = json.loads(marker.read_text())
        if info.get("spec") == spec and info.get("generator_version") == GENERATOR_VERSION:
            return folder, info
    with captured_stderr():
        info = make_problem(folder, spec)
    log(f"{name}: generated {info['n_images']} images, {info['n_pairs']} pairs, {info['n_doppelgangers']} doppelgangers in {info['seconds']:.1f} s")
    return folder, info


# =========================================================================== ground truth


class Truth:
    """The ground-truth model: image rotations by name, each image's camera / frame / rig,
    each rig's reference sensor and the true cam_from_rig of every non-reference sensor."""

    def __init__(self, model: Path):
        rec = pycolmap.Reconstruction(str(model))
        self.names, R, self.camera, self.frame, self.rig, self.is_ref = [], [], {}, {}, {}, {}
        for iid in sorted(int(i) for i in rec.reg_image_ids()):
            im = rec.images[iid]
            self.names.append(im.name)
            R.append(so3.from_pycolmap(im.cam_from_world().rotation))
            rig = rec.rigs[int(rec.frames[int(im.frame_id)].rig_id)]
            self.camera[im.name] = int(im.camera_id)
            self.frame[im.name] = int(im.frame_id)
            self.rig[im.name] = int(rig.rig_id)
            self.is_ref[im.name] = int(rig.ref_sensor_id.id) == int(im.camera_id)
        self.R = np.array(R).reshape(-1, 3, 3)
        self.extrinsics = {}  # (rig id, camera id) -> cam_from_rig (3, 3), non-reference sensors
        for rid, rig in rec.rigs.items():
            for sensor, T in rig.non_ref_sensors.items():
                if T is not None:
                    self.extrinsics[(int(rid), int(sensor.id))] = so3.from_pycolmap(T.rotation)

    def extrinsic_errors(self, estimates: dict) -> dict:
        """Angle (deg) per non-reference sensor between ``estimates[(rig, camera)]`` and the
        truth; NaN where there is no estimate."""
        out = {}
        for key, S in self.extrinsics.items():
            E = estimates.get(key)
            out[key] = float("nan") if E is None or not np.isfinite(E).all() else float(np.degrees(so3.angle_between(E, S)))
        return out


def derived_extrinsics(names, R, truth: Truth) -> dict:
    """Per non-reference sensor, the geodesic L1 median over the frames of ``R_image
    R_ref_image^T`` (both images solved)."""
    ref = {}
    for name, Ri in zip(names, R):
        if truth.is_ref.get(name) and np.isfinite(Ri).all():
            ref[truth.frame[name]] = Ri
    samples = defaultdict(list)
    for name, Ri in zip(names, R):
        if name in truth.is_ref and not truth.is_ref[name] and np.isfinite(Ri).all() and truth.frame[name] in ref:
            samples[(truth.rig[name], truth.camera[name])].append(Ri @ ref[truth.frame[name]].T)
    return {k: rotation_mean(np.array(v), metric="geodesic", norm="l1").rotation for k, v in samples.items()}


def rotgraph_extrinsics(result, names, R, truth: Truth) -> tuple[dict, str, dict]:
    """rotgraph's extrinsics: ``result.sensors`` when present (source ``sensors``), else
    derived from the image rotations (source ``derived``). Also per sensor its status /
    spread / frame count when ``result.sensors`` has them."""
    sol = getattr(result, "sensors", None)
    if sol is None:
        return derived_extrinsics(names, R, truth), "derived", {}
    est, extra = {}, {}
    sensor_ids = np.asarray(sol.sensor_ids).astype(np.int64)
    rig_ids = np.asarray(sol.rig_ids).astype(np.int64) if getattr(sol, "rig_ids", None) is not None else None
    S = np.asarray(sol.cam_from_rig, dtype=np.float64)
    rig_of_camera = {cam: rig for (rig, cam) in truth.extrinsics}
    for k, sid in enumerate(sensor_ids):
        rid = int(rig_ids[k]) if rig_ids is not None else rig_of_camera.get(int(sid), -1)
        est[(rid, int(sid))] = S[k]
        row = {}
        for field in ("status", "spread_deg", "n_frames"):
            v = getattr(sol, field, None)
            if v is not None:
                x = np.asarray(v)[k]
                row[field] = x.item() if isinstance(x, np.generic) else x
        extra[(rid, int(sid))] = row
    return est, "sensors", extra


# =========================================================================== contenders


def pose_graph(graph) -> "pycolmap.PoseGraph":
    """rotgraph's edges as COLMAP's pose graph, as ``bench_colmap.run_glomap_ra`` builds it."""
    pg = pycolmap.PoseGraph()
    for k, (i, j) in enumerate(graph.edges):
        edge = pycolmap.PoseGraphEdge(pycolmap.Rigid3d(to_pycolmap(graph.cam2_from_cam1[k]), np.zeros(3)))
        edge.num_matches = int(graph.weights[k])
        pg.add_edge(int(graph.node_ids[i]), int(graph.node_ids[j]), edge)
    return pg


def run_colmap(graph, db_path: Path):
    """COLMAP 4's ``run_rotation_averaging`` on rotgraph's relative poses: (R (n,3,3) NaN
    where unsolved, extrinsics {(rig, camera): (3,3)}, seconds of the call, ok)."""
    rec = unposed_reconstruction(db_path)
    pg = pose_graph(graph)
    opts = pycolmap.RotationEstimatorOptions()
    opts.random_seed = 0
    opts.refine_sensor_from_rig = True  # the default; required when a sensor_from_rig is unknown
    with captured_stderr():
        t = time.perf_counter()
        ok = pycolmap.run_rotation_averaging(opts, pg, rec, [])
        dt = time.perf_counter() - t
    R = np.full((graph.n_nodes, 3, 3), np.nan)
    ext = {}
    if ok:
        for k, i in enumerate(graph.node_ids):
            im = rec.images[int(i)]
            if im.has_pose:
                R[k] = so3.from_pycolmap(im.cam_from_world().rotation)
        for rid, rig in rec.rigs.items():
            for sensor, T in rig.non_ref_sensors.items():
                if T is not None:
                    ext[(int(rid), int(sensor.id))] = so3.from_pycolmap(T.rotation)
    return R, ext, dt, bool(ok)


def wrong_edges(graph, truth: Truth) -> tuple[int, int]:
    """Edges more than WRONG_EDGE_DEG from the true relative rotation, and edges with truth."""
    index = {n: k for k, n in enumerate(truth.names)}
    nodes = np.array([index.get(str(n), -1) for n in graph.names])
    i, j = nodes[graph.edges[:, 0]], nodes[graph.edges[:, 1]]
    ok = (i >= 0) & (j >= 0)
    true = truth.R[j[ok]] @ np.swapaxes(truth.R[i[ok]], 1, 2)
    err = np.degrees(so3.angle_between(graph.cam2_from_cam1[ok], true))
    return int((err > WRONG_EDGE_DEG).sum()), int(ok.sum())


def _ext_stats(errs: dict) -> dict:
    v = np.array([e for e in errs.values()], dtype=float)
    fin = v[np.isfinite(v)]
    return dict(mean=float(fin.mean()) if len(fin) else float("nan"), max=float(fin.max()) if len(fin) else float("nan"),
                n_estimated=int(len(fin)), n_sensors=int(len(v)))


def bench_variant(problem: str, variant: str, folder: Path, truth: Truth, repeats: int) -> dict:
    project = folder / variant
    with captured_stderr():
        graph = read_view_graph(project)
    n_wrong, n_true = wrong_edges(graph, truth)
    opts = default_options("colmap")
    average_rotations(graph, opts)  # warm-up, untimed (first-call costs)
    t_rg, res = [], None
    for _ in range(repeats):
        t = time.perf_counter()
        res = average_rotations(graph, opts)
        t_rg.append(time.perf_counter() - t)
    R_rg = res.cam_from_world
    ev_rg = errors(graph.names, R_rg, truth.names, truth.R)
    ext_rg, source, extra = rotgraph_extrinsics(res, list(map(str, graph.names)), R_rg, truth)
    err_rg = truth.extrinsic_errors(ext_rg)
    run_colmap(graph, project / "database.db")  # warm-up, untimed
    t_cm, R_cm, ext_cm, ok = [], None, {}, False
    for _ in range(repeats):
        R_cm, ext_cm, dt, ok = run_colmap(graph, project / "database.db")
        t_cm.append(dt)
    ev_cm = errors(graph.names, R_cm, truth.names, truth.R) if ok and np.isfinite(R_cm).all(axis=(1, 2)).any() else None
    err_cm = truth.extrinsic_errors(ext_cm)
    n_frames = len(np.unique(graph.rigs.frame_ids)) if graph.rigs is not None else graph.n_nodes

    def ev_dict(ev):
        if ev is None:
            return None
        return dict(median=ev.median, mean=ev.mean, max=ev.max, n_evaluated=ev.n_evaluated, n_ground_truth=ev.n_ground_truth)

    def per_sensor(errs, extra=None):
        return [dict(rig=r, camera=c, error_deg=e, **((extra or {}).get((r, c), {}))) for (r, c), e in sorted(errs.items())]

    return dict(
        problem=problem, variant=variant, n_images=graph.n_nodes, n_frames=int(n_frames), n_pairs=graph.n_edges,
        n_wrong_pairs=n_wrong, wrong_fraction=n_wrong / max(1, n_true),
        rotgraph=dict(images=ev_dict(ev_rg), extrinsics=_ext_stats(err_rg), extrinsics_source=source, sensors=per_sensor(err_rg, extra),
                      solve_s=float(np.median(t_rg)), method=res.method, n_solved=int(res.n_solved)),
        colmap=dict(images=ev_dict(ev_cm), extrinsics=_ext_stats(err_cm), sensors=per_sensor(err_cm), solve_s=float(np.median(t_cm)), ok=ok),
    )


# =========================================================================== table


def _ratio(a, b) -> str:
    if a is None or b is None or not (np.isfinite(a) and np.isfinite(b)):
        return "—"
    if b < 1e-9:  # COLMAP exact (extrinsics given): no ratio
        return "—" if a < 1e-9 else "∞"
    return f"{a / b:.3f}"


def _num(x, fmt="{:.4f}") -> str:
    return "—" if x is None or not np.isfinite(x) else fmt.format(x)


def print_table(rows: list[dict], meta: dict) -> None:
    print("# rotgraph rig solve vs COLMAP 4 rig rotation averaging\n")
    print(f"python {meta['python']}, pycolmap {meta['pycolmap']}, rotgraph git {meta['rotgraph_git']}, "
          f"{meta['cpu']} ({meta['cpus']} CPUs usable), load at start {meta['load_at_start']}, at end {meta.get('load_at_end', '?')}; "
          f"times: median of {meta['repeats']} runs, ms; "
          f"ratio = rotgraph / COLMAP; extrinsic errors: mean / max over the non-reference sensors\n")
    print("| problem | variant | images / frames / pairs (wrong) | rotgraph median ° | COLMAP median ° | ratio | rotgraph mean ° | COLMAP mean ° | ratio "
          "| rotgraph extr. ° | COLMAP extr. ° | ratio | rotgraph ms | COLMAP ms | ratio | solved rg / COLMAP |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        rg, cm = r["rotgraph"], r["colmap"]
        ig, ic = rg["images"], cm["images"]
        eg, ec = rg["extrinsics"], cm["extrinsics"]
        tag = "" if rg["extrinsics_source"] == "sensors" else " (derived)"
        graph = f"{r['n_images']} / {r['n_frames']} / {r['n_pairs']:,} ({100 * r['wrong_fraction']:.1f} %)"
        med = (ig and ig["median"], ic and ic["median"])
        mean = (ig and ig["mean"], ic and ic["mean"])
        solved = f"{ig['n_evaluated'] if ig else 0} / {ic['n_evaluated'] if ic else 0} of {ig['n_ground_truth'] if ig else '?'}"
        print(f"| {r['problem']} | {r['variant']} | {graph} | {_num(med[0])} | {_num(med[1])} | {_ratio(*med)} | {_num(mean[0])} | {_num(mean[1])} | {_ratio(*mean)} "
              f"| {_num(eg['mean'])} / {_num(eg['max'], '{:.3f}')}{tag} | {_num(ec['mean'])} / {_num(ec['max'], '{:.3f}')} | {_ratio(eg['mean'], ec['mean'])} "
              f"| {_num(1000 * rg['solve_s'], '{:.1f}')} | {_num(1000 * cm['solve_s'], '{:.1f}')} | {_ratio(rg['solve_s'], cm['solve_s'])} | {solved} |")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--problems", default=None, help="comma-separated subset of " + ",".join(PROBLEMS))
    ap.add_argument("--variants", default=",".join(VARIANTS), help="comma-separated subset of " + ",".join(VARIANTS))
    ap.add_argument("--quick", action="store_true", help="only " + ", ".join(QUICK))
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--cache", default=None, help="folder for the generated projects (default $TMPDIR/rotgraph-bench-rigs)")
    ap.add_argument("--fresh", action="store_true", help="regenerate the projects even when cached")
    ap.add_argument("--out", default=None, help="write the results (per-sensor errors included) as JSON here")
    ap.add_argument("--table", default=None, metavar="JSON", help="only print the table of a results file written by --out")
    args = ap.parse_args(argv)
    if args.table:
        saved = json.loads(Path(args.table).read_text())
        print_table(saved["rows"], saved["meta"])
        return 0
    names = args.problems.split(",") if args.problems else (list(QUICK) if args.quick else list(PROBLEMS))
    unknown = [n for n in names if n not in PROBLEMS]
    variants = args.variants.split(",")
    if unknown or any(v not in VARIANTS for v in variants):
        ap.error(f"unknown problem or variant: {unknown or variants}")
    cache = Path(args.cache) if args.cache else Path(tempfile.gettempdir()) / "rotgraph-bench-rigs"
    if cache.resolve().is_relative_to(ROOT.resolve()):
        ap.error("the cache must be outside the repository")
    cache.mkdir(parents=True, exist_ok=True)
    meta = dict(python=platform.python_version(), pycolmap=pycolmap.__version__, rotgraph_git=git_commit(), cpu=cpu_model(),
                cpus=usable_cpus(), load_at_start=load_average(), repeats=args.repeats, problems={n: PROBLEMS[n] for n in names})
    rows = []
    for name in names:
        t0 = time.perf_counter()
        folder, info = cached_problem(cache, name, args.fresh)
        truth = Truth(folder / "gt")
        for variant in variants:
            rows.append(bench_variant(name, variant, folder, truth, args.repeats))
            r = rows[-1]
            log(f"{name} {variant}: median {r['rotgraph']['images'] and r['rotgraph']['images']['median']:.4g} / "
                f"{(r['colmap']['images'] or {}).get('median', float('nan')):.4g} deg, solve {1000 * r['rotgraph']['solve_s']:.1f} / "
                f"{1000 * r['colmap']['solve_s']:.1f} ms (rotgraph / COLMAP)")
            if args.out:  # after every row, so that an interrupted run keeps what it measured
                Path(args.out).write_text(json.dumps(dict(meta=meta, rows=rows), indent=1, default=float))
        log(f"{name} done in {time.perf_counter() - t0:.1f} s")
    meta["load_at_end"] = load_average()
    if args.out:
        Path(args.out).write_text(json.dumps(dict(meta=meta, rows=rows), indent=1, default=float))
    print_table(rows, meta)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
