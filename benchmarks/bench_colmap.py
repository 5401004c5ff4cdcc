#!/usr/bin/env python
"""rotgraph vs GLOMAP's rotation averaging on COLMAP projects (one command, markdown table).

Run from the repository root::

    python benchmarks/bench_colmap.py            # all projects (about 4 min on 2 cores)
    python benchmarks/bench_colmap.py --quick    # two small synthetic projects
    python benchmarks/bench_colmap.py --repeats 5 --projects bundled,rig3x20,lund_door
    python benchmarks/bench_colmap.py --projects none --folder big=/path/to/project  # any project folder
    python benchmarks/bench_colmap.py --projects none --sizes 100,400,1000 --keep /tmp/colmap-sizes  # #33's sizes

Projects: ``datasets/colmap_synthetic`` (bundled, 14 images); synthetic ones made on the
fly with ``rotgraph.synth.synthesize_colmap_project`` (pycolmap's synthetic scene, 1 px
keypoint noise, 30 % wrong raw matches, doppelganger pairs = consistent matches of a rotated
copy of the scene, then COLMAP's geometric verification; ground truth = the synthetic
model; see ``PROJECTS`` for sizes, noise and seeds); and ``../shared/datasets/lund_door``
(12 real photos, reference model) when present.

Contenders, each on the same ``database.db`` (GLOMAP always on a private copy):

* **rotgraph**: ``rotgraph.pipeline.colmap.read_colmap_project(project, uncertainty=True,
  uncertainty_sample=UNCERTAINTY_SAMPLE)``, as ``rotgraph solve`` reads: reading (the
  database opened read-only, only the tables needed decoded, no copy; relative poses stored
  or estimated as ``pycolmap.estimate_two_view_geometry_pose`` does, each pair's rotation
  information from its inlier matches), then
  ``average_rotations(graph, default_options("colmap"))``: the rig-aware solve with the
  COLMAP preset. Times: ``read``, ``solve`` and their sum.
* **rotgraph --no-use-information**: the same without the pairs' information (inlier-count
  weights instead), as before rotgraph estimated them.
* **GLOMAP RA**: ``pycolmap.run_rotation_averaging(RotationEstimatorOptions(random_seed=0),
  PoseGraph, Reconstruction, [])`` on exactly rotgraph's relative poses (one edge per image
  pair, ``num_matches`` = inliers) and a reconstruction holding the database's cameras,
  rigs, frames and images: the rotation-averaging stage alone, the fair baseline for
  the solve time.
* **GLOMAP pipeline**: ``pycolmap.global_mapping`` with track establishment, global
  positioning, bundle adjustment and retriangulation skipped: COLMAP 4's own reading of
  the database, relative-pose decomposition, rotation averaging with its 10 deg filter and
  re-run. ``total`` is the whole call; ``solve`` is the stage time COLMAP logs
  ("Rotation averaging done in ...").

``--folder NAME=PATH`` adds a project folder of your own (``database.db`` and a ground-truth
model in ``sparse/0`` or ``gt``). The last table sums, over the projects, rotgraph's read +
solve (with the pairs' information, as ``rotgraph solve``) and GLOMAP pipeline's total
(#18: "COLMAP read + solve after start-up <= 1.0x GLOMAP's relative-pose + rotation-averaging
work, summed over our projects"); every time is a median of warm runs (start-up excluded).

``--sizes N,...`` (#33) adds, for each N, a synthetic project of N images (``syn{N}``:
``SIZE_POINTS`` scene points, about ``SIZE_DEGREE`` matched images an image, N / 20 doppelganger
pairs; ``size_project``) and its twin without the lying pairs (``syn{N}-clean``: the same
database with the doppelganger pairs' rows deleted), and a last table per size: rotgraph's
read, solve and whole time with and without information against GLOMAP pipeline's
relative-pose stage (``read/decompose``: its whole call less its rotation averaging), its
rotation averaging and its whole call, the ratios #33 judges (whole <= 0.5x, read <= 1.0x
the relative-pose stage) and the median errors. With ``--keep`` the projects are made once
and reused (``size.json`` in each says how it was made and how long that took).

Errors: per image, after aligning the gauge (``rotgraph.evaluate.compare_rotations``), vs
the ground-truth model, matched by image name; ``ratio`` = rotgraph median / GLOMAP RA
median. Times: median over ``--repeats`` runs.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # see bench_multiple.py

import argparse
import contextlib
import platform
import re
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import pycolmap  # noqa: E402
from _common import cpu_model, git_commit, load_average, usable_cpus  # noqa: E402

from rotgraph import so3  # noqa: E402
from rotgraph.estimators.rotation_averaging import average_rotations  # noqa: E402
from rotgraph.evaluate import compare_rotations, match_by_key  # noqa: E402
from rotgraph.io.colmap import to_pycolmap  # noqa: E402
from rotgraph.io.colmap_model import read_colmap_model_rotations, unposed_reconstruction  # noqa: E402
from rotgraph.pipeline.colmap import UNCERTAINTY_SAMPLE, read_colmap_project  # noqa: E402
from rotgraph.pipeline.solve import default_options  # noqa: E402
from rotgraph.synth import synthesize_colmap_project  # noqa: E402

LUND = ROOT.parent / "shared" / "datasets" / "lund_door"

PROJECTS = {
    # name: (synthesize_colmap_project keyword arguments)
    "syn40": dict(n_frames=40, n_points=500, doppelgangers=6, seed=1),
    "syn40-stored": dict(n_frames=40, n_points=500, doppelgangers=6, store_relative_pose=True, seed=2),
    "syn120-sparse": dict(n_frames=120, n_points=800, doppelgangers=20, match_sparsity=0.85, seed=3),
    "rig3x20": dict(n_frames=20, cameras_per_rig=3, n_points=500, doppelgangers=6, seed=4),
    "noisy60": dict(n_frames=60, n_points=500, noise_px=3.0, outlier_match_ratio=0.5, doppelgangers=12, match_sparsity=0.5, seed=5),
    "syn300-sparse": dict(n_frames=300, n_points=1500, doppelgangers=40, match_sparsity=0.96, seed=6),
}
BUNDLED = ROOT / "datasets" / "colmap_synthetic"
#: ``--sizes``: scene points of the synthetic projects (each image sees most of them: ~SIZE_POINTS
#: keypoints an image, ~0.7 of them inliers of a pair), and how many other images each is matched
#: with (``match_sparsity = 1 - SIZE_DEGREE / (N - 1)``; all pairs below SIZE_DEGREE + 1 images).
SIZE_POINTS, SIZE_DEGREE = 400, 100


def size_project(work: Path, n_images: int, seed: int = 33) -> tuple[Path, Path, Path]:
    """The ``--sizes`` projects of ``n_images`` images in ``work``: ``(with doppelgangers, without
    them, ground-truth model)``, made once (``size.json``) and reused. The twin without lying pairs
    is a copy of the database with the doppelganger pairs' two-view geometries and matches deleted."""
    import json
    import sqlite3

    from rotgraph.io.colmap import pair_ids

    folder, clean = work / f"syn{n_images}", work / f"syn{n_images}-clean"
    meta = folder / "size.json"
    params = dict(n_frames=n_images, n_points=SIZE_POINTS, doppelgangers=max(2, n_images // 20),
                  match_sparsity=max(0.0, 1.0 - SIZE_DEGREE / max(n_images - 1, 1)), seed=seed)
    if not (meta.is_file() and json.loads(meta.read_text()).get("params") == params and (clean / "database.db").is_file()):
        for f in (folder, clean):
            shutil.rmtree(f, ignore_errors=True)
        t = time.perf_counter()
        with captured_stderr():
            info = synthesize_colmap_project(folder, **params)
        seconds = time.perf_counter() - t
        (clean / "sparse").mkdir(parents=True)
        shutil.copytree(folder / "sparse" / "0", clean / "sparse" / "0")
        shutil.copyfile(folder / "database.db", clean / "database.db")
        fake = [int(x) for x in pair_ids(np.array([a for a, _, _ in info["doppelgangers"]]),
                                          np.array([b for _, b, _ in info["doppelgangers"]]))]
        with contextlib.closing(sqlite3.connect(clean / "database.db")) as con, con:
            for table in ("two_view_geometries", "matches"):
                con.executemany(f"DELETE FROM {table} WHERE pair_id = ?", [(x,) for x in fake])
        meta.write_text(json.dumps({"params": params, "seconds": seconds, "doppelgangers": info["doppelgangers"]}))
        print(f"[bench_colmap] syn{n_images} made in {seconds:.0f} s", file=sys.stderr)
    return folder, clean, folder / "sparse" / "0"
QUICK = ("syn40", "rig3x20")


@contextlib.contextmanager
def captured_stderr():
    """Capture what native code (glog) writes to file descriptor 2."""
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile(mode="w+b") as tmp:
        os.dup2(tmp.fileno(), 2)
        box = {"text": ""}
        try:
            yield box
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            box["text"] = tmp.read().decode("utf-8", "replace")


def errors(names, R, gt_names, gt_R):
    E, G, _ = match_by_key(names, R, gt_names, gt_R)
    return compare_rotations(E, G)


def run_glomap_ra(graph, db_path: str):
    """GLOMAP's rotation averaging on rotgraph's relative poses: (R (n,3,3), seconds)."""
    rec = unposed_reconstruction(db_path)
    pg = pycolmap.PoseGraph()
    for k, (i, j) in enumerate(graph.edges):
        edge = pycolmap.PoseGraphEdge(pycolmap.Rigid3d(to_pycolmap(graph.cam2_from_cam1[k]), np.zeros(3)))
        edge.num_matches = int(graph.weights[k])
        pg.add_edge(int(graph.node_ids[i]), int(graph.node_ids[j]), edge)
    opts = pycolmap.RotationEstimatorOptions()
    opts.random_seed = 0
    with captured_stderr():
        t = time.perf_counter()
        ok = pycolmap.run_rotation_averaging(opts, pg, rec, [])
        dt = time.perf_counter() - t
    R = np.full((graph.n_nodes, 3, 3), np.nan)
    if ok:
        for k, i in enumerate(graph.node_ids):
            im = rec.images[int(i)]
            if im.has_pose:
                R[k] = so3.from_pycolmap(im.cam_from_world().rotation)
    return R, dt


def run_glomap_pipeline(db_path: str):
    """pycolmap.global_mapping up to rotation averaging: (names, R, total s, stage s)."""
    with tempfile.TemporaryDirectory() as tmp:
        copy = os.path.join(tmp, "database.db")
        shutil.copyfile(db_path, copy)
        out = os.path.join(tmp, "out")
        images = os.path.join(tmp, "images")
        os.makedirs(out), os.makedirs(images)
        opts = pycolmap.GlobalPipelineOptions()
        opts.random_seed = 0
        m = opts.mapper
        m.skip_track_establishment = True
        m.skip_global_positioning = True
        m.skip_bundle_adjustment = True
        m.skip_retriangulation = True
        with captured_stderr() as log:
            t = time.perf_counter()
            recs = pycolmap.global_mapping(copy, images, out, opts)
            total = time.perf_counter() - t
    stage = [float(x) for x in re.findall(r"Rotation averaging done in ([0-9.eE+-]+) seconds", log["text"])]
    names, R = [], []
    for rec in recs.values():
        for iid in rec.reg_image_ids():
            im = rec.images[int(iid)]
            names.append(im.name)
            R.append(so3.from_pycolmap(im.cam_from_world().rotation))
    return names, np.array(R).reshape(-1, 3, 3), total, (sum(stage) if stage else float("nan"))


def bench_project(name: str, folder: Path, model: Path, repeats: int) -> list[dict]:
    db_path = str(folder / "database.db")
    gt_ids, gt_names, gt_R = read_colmap_model_rotations(model)
    rows = []
    t_read, t_solve, graph, res = [], [], None, None
    for _ in range(repeats):
        t = time.perf_counter()
        graph = read_colmap_project(folder, model=None, uncertainty=True, uncertainty_sample=UNCERTAINTY_SAMPLE)
        t_read.append(time.perf_counter() - t)
        t = time.perf_counter()
        res = average_rotations(graph, default_options("colmap"))
        t_solve.append(time.perf_counter() - t)
    ev = errors(graph.names, res.cam_from_world, gt_names, gt_R)
    # the same without the pairs' rotation information (--no-use-information): inlier-count weights
    t_read0, t_solve0, res0 = [], [], None
    for _ in range(repeats):
        t = time.perf_counter()
        graph0 = read_colmap_project(folder, model=None)
        t_read0.append(time.perf_counter() - t)
        t = time.perf_counter()
        res0 = average_rotations(graph0, default_options("colmap", use_information=False))
        t_solve0.append(time.perf_counter() - t)
    meta = graph.meta
    n_frames = len(np.unique(graph.rigs.frame_ids)) if graph.rigs is not None else graph.n_nodes
    desc = f"{graph.n_nodes} img, {n_frames} fr, {graph.n_edges} pairs ({meta['n_pairs_stored']} stored, {meta['n_pairs_estimated']} est.)"
    rows.append(dict(project=name, desc=desc, method="rotgraph", ev=ev, read=np.median(t_read), solve=np.median(t_solve)))
    rows.append(dict(project=name, desc=desc, method="rotgraph --no-use-information", ev=errors(graph0.names, res0.cam_from_world, gt_names, gt_R),
                     read=np.median(t_read0), solve=np.median(t_solve0)))
    t_ra, R_ra = [], None
    for _ in range(repeats):
        R_ra, dt = run_glomap_ra(graph, db_path)
        t_ra.append(dt)
    rows.append(dict(project=name, desc=desc, method="GLOMAP RA", ev=errors(graph.names, R_ra, gt_names, gt_R), read=np.nan, solve=np.median(t_ra)))
    t_tot, t_stage, res = [], [], None
    for _ in range(repeats):
        names, R, total, stage = run_glomap_pipeline(db_path)
        t_tot.append(total), t_stage.append(stage)
        res = (names, R)
    rows.append(dict(project=name, desc=desc, method="GLOMAP pipeline", ev=errors(res[0], res[1], gt_names, gt_R) if len(res[0]) else None,
                     read=np.median(t_tot) - np.median(t_stage), solve=np.median(t_stage)))
    return rows


def fmt_ms(x: float) -> str:
    return "—" if not np.isfinite(x) else f"{1000 * x:.1f}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--projects", default=None, help="comma-separated: " + ",".join(["bundled"] + list(PROJECTS) + ["lund_door"]))
    ap.add_argument("--quick", action="store_true", help="only " + ", ".join(QUICK))
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--keep", default=None, help="folder to keep the generated projects in")
    ap.add_argument("--sizes", default=None, metavar="N,...",
                    help="also synthetic projects of these many images, with and without doppelganger pairs (#33)")
    ap.add_argument("--folder", action="append", default=[], metavar="NAME=PATH",
                    help="also a project folder of your own (database.db + model in sparse/0 or gt)")
    args = ap.parse_args(argv)
    names = args.projects.split(",") if args.projects else (list(QUICK) if args.quick else ["bundled"] + list(PROJECTS) + ["lund_door"])
    names = [n for n in names if n and n != "none"]
    folders = dict(f.split("=", 1) for f in args.folder)
    names += list(folders)
    sizes = [int(x) for x in args.sizes.split(",")] if args.sizes else []
    names += [f"syn{n}{twin}" for n in sizes for twin in ("", "-clean")]
    work = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="bench-colmap-"))
    rows = []
    try:
        for name in names:
            t0 = time.perf_counter()
            size = re.fullmatch(r"syn(\d+)(-clean)?", name)
            if size and int(size.group(1)) in sizes:
                dop, clean, model = size_project(work, int(size.group(1)))
                folder = clean if size.group(2) else dop
            elif name in folders:
                folder = Path(folders[name])
                model = next(m for m in (folder / "sparse" / "0", folder / "gt", folder / "sparse") if m.is_dir())
            elif name == "bundled":
                folder, model = BUNDLED, BUNDLED / "sparse" / "0"
            elif name == "lund_door":
                if not (LUND / "database.db").is_file():
                    print(f"[bench_colmap] {LUND} not found: lund_door skipped", file=sys.stderr)
                    continue
                folder, model = LUND, LUND / "gt"
            else:
                folder = work / name
                with captured_stderr():
                    info = synthesize_colmap_project(folder, **PROJECTS[name])
                model = Path(info["model"])
            rows += bench_project(name, folder, model, args.repeats)
            print(f"[bench_colmap] {name} done in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)

    print("# rotgraph vs GLOMAP rotation averaging on COLMAP projects\n")
    print(f"python {platform.python_version()}, pycolmap {pycolmap.__version__}, rotgraph git {git_commit()}, "
          f"{cpu_model()} ({usable_cpus()} CPUs usable), load {load_average()}; times: median of {args.repeats} runs, ms\n")
    print("| project | graph | method | median ° | mean ° | max ° | solved | read/decompose ms | solve ms | total ms | median ratio |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    base = {r["project"]: r["ev"].median for r in rows if r["method"] == "GLOMAP RA" and r["ev"] is not None}
    for r in rows:
        ev = r["ev"]
        med = "—" if ev is None else f"{ev.median:.4f}"
        mean = "—" if ev is None else f"{ev.mean:.4f}"
        mx = "—" if ev is None else f"{ev.max:.3f}"
        solved = "—" if ev is None else f"{ev.n_evaluated}/{ev.n_ground_truth}"
        total = r["solve"] + (r["read"] if np.isfinite(r["read"]) else 0.0)
        ratio = f"{ev.median / base[r['project']]:.3f}" if ev is not None and base.get(r["project"]) else "—"
        print(f"| {r['project']} | {r['desc']} | {r['method']} | {med} | {mean} | {mx} | {solved} | {fmt_ms(r['read'])} | {fmt_ms(r['solve'])} | {fmt_ms(total)} | {ratio} |")
    print("\n| project | rotgraph read + solve ms | GLOMAP pipeline ms | ratio |")
    print("|---|---|---|---|")
    sums = [0.0, 0.0]
    for project in dict.fromkeys(r["project"] for r in rows):
        ours = next(r for r in rows if r["project"] == project and r["method"] == "rotgraph")
        theirs = next(r for r in rows if r["project"] == project and r["method"] == "GLOMAP pipeline")
        a, b = ours["read"] + ours["solve"], theirs["read"] + theirs["solve"]
        sums[0] += a
        sums[1] += b
        print(f"| {project} | {fmt_ms(a)} | {fmt_ms(b)} | {a / b:.2f}x |")
    if rows:
        print(f"| **sum** | {fmt_ms(sums[0])} | {fmt_ms(sums[1])} | **{sums[0] / sums[1]:.2f}x** |")
    if sizes:
        size_table(rows, [f"syn{n}{twin}" for n in sizes for twin in ("", "-clean")])
    return 0


def size_table(rows: list[dict], projects: list[str]) -> None:
    """#33's table of the ``--sizes`` projects: rotgraph's read / solve / whole (s) with and without
    information, GLOMAP pipeline's relative-pose stage / rotation averaging / whole, the ratios
    judged (whole, and read against the relative-pose stage) and the median errors (deg)."""
    print("\n| project | pairs | rotgraph read / solve / whole s | whole / GLOMAP | read / GLOMAP rel. poses | "
          "without information: read / solve / whole s | whole / GLOMAP | GLOMAP rel. poses / RA / whole s | "
          "median deg: rotgraph / without information / GLOMAP |")
    print("|---|---|---|---|---|---|---|---|---|")
    for project in projects:
        got = {r["method"]: r for r in rows if r["project"] == project}
        if "GLOMAP pipeline" not in got:
            continue
        ours, plain, glomap = got["rotgraph"], got["rotgraph --no-use-information"], got["GLOMAP pipeline"]
        whole_g = glomap["read"] + glomap["solve"]
        med = [("—" if r["ev"] is None else f"{r['ev'].median:.4f}") for r in (ours, plain, glomap)]
        pairs = re.search(r"(\d+) pairs", ours["desc"]).group(1)
        w, w0 = ours["read"] + ours["solve"], plain["read"] + plain["solve"]
        print(f"| {project} | {pairs} | {ours['read']:.2f} / {ours['solve']:.2f} / {w:.2f} | {w / whole_g:.2f}x | "
              f"{ours['read'] / glomap['read']:.2f}x | {plain['read']:.2f} / {plain['solve']:.2f} / {w0:.2f} | {w0 / whole_g:.2f}x | "
              f"{glomap['read']:.2f} / {glomap['solve']:.2f} / {whole_g:.2f} | {' / '.join(med)} |")


if __name__ == "__main__":
    raise SystemExit(main())
