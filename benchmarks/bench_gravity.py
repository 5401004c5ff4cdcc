"""Rotation averaging with gravity priors: rotgraph vs COLMAP 4 (issue #17 item 3).

Run (one command; a few minutes with the defaults)::

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_gravity.py
    python benchmarks/bench_gravity.py --sizes 200 --seeds 1          # quick
    python benchmarks/bench_gravity.py --graph traj --sizes 500 --out gravity.json

Problems: ``rotgraph.synth.random_problem`` (``--graph`` er or traj, ``--sizes`` cameras,
``--degree``, edge noise ``--edge-sigma`` deg per axis, ``--outliers`` 10 % uniform outlier
edges). Gravity: the truth ``R_i (0, 1, 0)`` (COLMAP's world is y down) turned by a 2-D Gaussian
tilt of ``sigma`` degrees per axis (``--gravity-sigmas`` 0, 0.5, 1, 2;
``rotgraph.estimators.gravity.perturb_gravity``); ``--wrong-gravity f``: a fraction ``f`` of the
images gets a uniformly random gravity direction instead.

Solvers (the same in-memory problem):

* ``rotgraph+g auto``: ``average_rotations(graph, gravity=gravity)``: sigma estimated from
  the data (the default; column ``σ̂°`` the estimate, mean over the seeds);
* ``rotgraph+g``: ``average_rotations(graph, gravity=gravity, gravity_sigma_deg=sigma)``, the true sigma;
* ``rotgraph+g hard``: the same with ``sigma_deg=0``: gravity taken as exact, as COLMAP does;
* ``rotgraph``: ``average_rotations(graph)`` (default options), no gravity;
* ``COLMAP+g``: ``pycolmap.run_rotation_averaging(RotationEstimatorOptions(use_gravity=True),
  PoseGraph, Reconstruction, pose_priors)``: one trivial rig and frame per image, one
  ``PosePrior`` per image with ``corr_data_id = image.data_id`` and ``gravity = g_i``;
  COLMAP holds each image's tilt to its prior exactly (a 1-DOF unknown per image);
* ``COLMAP``: the same without gravity (``use_gravity=False``).

Scores: ``median`` is ``rotgraph.evaluate.compare_rotations``'s median image error (whole gauge
aligned: the same for every solver); ``tilt`` / ``yaw`` the medians of
``tilt_yaw_errors`` (with gravity: the yaw gauge aligned only, the solution is in the gravity
frame; without: the whole gauge), over the cameras solved (``solved``: their mean count). Each cell is the mean over ``--seeds`` problems. Times:
``time.perf_counter`` around the whole call (for COLMAP: building its structures, the solve,
reading the result back), the median over the seeds, after one untimed warm-up solve each.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import cpu_model, fmt_time, git_commit, load_average, table, usable_cpus

from rotgraph import so3
from rotgraph.estimators.gravity import (
    gravity_of,
    perturb_gravity,
    tilt_yaw_errors,
)
from rotgraph.estimators.rotation_averaging import average_rotations
from rotgraph.evaluate import compare_rotations
from rotgraph.synth import random_problem

HEADER = ["n", "gravity σ°", "solver", "σ̂°", "solved", "median°", "tilt°", "yaw°", "time"]
SOLVERS = ("rotgraph+g auto", "rotgraph+g", "rotgraph+g hard", "rotgraph", "COLMAP+g", "COLMAP")


def run_colmap(g, gravity, use_gravity: bool):
    import pycolmap

    n = g.n_nodes
    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(pycolmap.Camera(camera_id=1, model="SIMPLE_PINHOLE", width=1, height=1,
                                                    params=[1.0, 0.0, 0.0]))
    for k in range(n):
        rec.add_image_with_trivial_frame(pycolmap.Image(image_id=k + 1, camera_id=1))
    q = np.ascontiguousarray(np.roll(so3.quaternion_rows_from_matrices(g.cam2_from_cam1), -1, axis=0).T)  # x y z w
    pg = pycolmap.PoseGraph()
    zero = np.zeros(3)
    for (i, j), qk in zip(g.edges.tolist(), q):
        e = pycolmap.PoseGraphEdge(cam2_from_cam1=pycolmap.Rigid3d(rotation=pycolmap.Rotation3d(qk), translation=zero))
        e.num_matches = 1
        pg.add_edge(i + 1, j + 1, e)
    priors = []
    if use_gravity:
        for k in range(n):
            p = pycolmap.PosePrior()
            p.corr_data_id = rec.image(k + 1).data_id
            p.gravity = gravity[k]
            priors.append(p)
    opts = pycolmap.RotationEstimatorOptions()
    opts.use_gravity = use_gravity
    if not pycolmap.run_rotation_averaging(opts, pg, rec, priors):
        raise RuntimeError("run_rotation_averaging returned False")
    R = np.full((n, 3, 3), np.nan)
    for k in range(n):
        im = rec.image(k + 1)
        if im.has_pose:
            R[k] = im.cam_from_world().rotation.matrix()
    return R


def solve(name, g, gravity, sigma):
    """``(rotations, estimated gravity sigma or None)``."""
    if name == "rotgraph+g auto":
        r = average_rotations(g, gravity=gravity)
        return r.cam_from_world, r.diagnostics["gravity"]["sigma_deg_estimated"]
    if name == "rotgraph+g":
        return average_rotations(g, gravity=gravity, gravity_sigma_deg=sigma).cam_from_world, None
    if name == "rotgraph+g hard":
        return average_rotations(g, gravity=gravity, gravity_sigma_deg=0.0).cam_from_world, None
    if name == "rotgraph":
        return average_rotations(g).cam_from_world, None
    return run_colmap(g, gravity, name == "COLMAP+g"), None


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--graph", default="er", choices=("er", "traj"))
    ap.add_argument("--sizes", default="200,1000")
    ap.add_argument("--degree", type=float, default=10.0)
    ap.add_argument("--edge-sigma", type=float, default=2.0)
    ap.add_argument("--outliers", type=float, default=0.1)
    ap.add_argument("--gravity-sigmas", default="0,0.5,1,2")
    ap.add_argument("--wrong-gravity", type=float, default=0.0,
                    help="fraction of images whose gravity is replaced by a uniformly random direction")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--solvers", default=",".join(SOLVERS))
    ap.add_argument("--out", help="write the rows as JSON")
    args = ap.parse_args(argv)
    solvers = [s for s in args.solvers.split(",") if s]
    try:
        import pycolmap  # noqa: F401
    except ImportError:
        solvers = [s for s in solvers if not s.startswith("COLMAP")]
    print(f"# bench_gravity: commit {git_commit()}, {cpu_model()}, {usable_cpus()} CPUs, load {load_average()}")
    print(f"# {args.graph} graphs, degree {args.degree:g}, edge noise {args.edge_sigma:g} deg per axis, "
          f"{args.outliers:.0%} outlier edges, {args.wrong_gravity:.0%} wrong gravity vectors, {args.seeds} seed(s) per row\n")
    rows, out = [], []
    # warm-up (imports, first-call costs) outside the timings
    g = random_problem(n=60, degree=args.degree, sigma_deg=args.edge_sigma, outliers=args.outliers, graph=args.graph, seed=0)
    for s in solvers:
        solve(s, g, gravity_of(g.gt_cam_from_world), 1.0)
    for n in [int(x) for x in args.sizes.split(",")]:
        for sg in [float(x) for x in args.gravity_sigmas.split(",")]:
            acc = {s: {"median": [], "tilt": [], "yaw": [], "time": [], "sigma": [], "solved": [], "fail": 0} for s in solvers}
            for seed in range(args.seeds):
                g = random_problem(n=n, degree=args.degree, sigma_deg=args.edge_sigma, outliers=args.outliers, graph=args.graph, seed=seed)
                R = g.gt_cam_from_world
                grav = perturb_gravity(gravity_of(R), sg, 1000 + seed)
                if args.wrong_gravity > 0:
                    rng = np.random.default_rng(2000 + seed)
                    bad = rng.choice(n, round(args.wrong_gravity * n), replace=False)
                    grav[bad] = so3.random_rotations(len(bad), rng) @ np.array([0.0, 1.0, 0.0])
                for s in solvers:
                    t0 = time.perf_counter()
                    try:
                        Re, s_hat = solve(s, g, grav, sg)
                    except Exception as exc:  # noqa: BLE001 - a failing peer is a row, not a crash
                        print(f"  {s} n={n} sigma={sg} seed={seed}: {type(exc).__name__}: {exc}", file=sys.stderr)
                        acc[s]["fail"] += 1
                        continue
                    dt = time.perf_counter() - t0
                    e = tilt_yaw_errors(Re, R, align="yaw" if "+g" in s else "full")
                    a = acc[s]
                    a["median"].append(compare_rotations(Re, R).median)
                    a["solved"].append(int(np.isfinite(Re).all(axis=(1, 2)).sum()))
                    a["tilt"].append(e.median_tilt)
                    a["yaw"].append(e.median_yaw)
                    a["time"].append(dt)
                    if s_hat is not None:
                        a["sigma"].append(s_hat)
            for s in solvers:
                a = acc[s]
                if not a["median"]:
                    rows.append([str(n), f"{sg:g}", s, "", "failed", "", "", "", ""])
                    continue
                m = {k: float(np.mean(a[k])) for k in ("median", "tilt", "yaw")}
                tm = float(np.median(a["time"]))
                s_hat = float(np.mean(a["sigma"])) if a["sigma"] else None
                rows.append([str(n), f"{sg:g}", s, "" if s_hat is None else f"{s_hat:.3f}", f"{np.mean(a['solved']):.4g}",
                             f"{m['median']:.3f}",
                             f"{m['tilt']:.3f}", f"{m['yaw']:.3f}", fmt_time(tm) + (f" ({a['fail']} failed)" if a["fail"] else "")])
                out.append(dict(n=n, gravity_sigma_deg=sg, solver=s, seconds=tm, failures=a["fail"], sigma_estimated_deg=s_hat, solved=float(np.mean(a["solved"])),
                                **{k + "_deg": v for k, v in m.items()}))
            print(table(HEADER, rows[-len(solvers):]), flush=True)
            print()
    print(table(HEADER, rows))
    if args.out:
        with open(args.out, "w") as fh:
            json.dump({"args": vars(args), "commit": git_commit(), "rows": out}, fh, indent=1)


if __name__ == "__main__":
    main()
