#!/usr/bin/env python
"""Benchmark rotgraph's multiple rotation averaging against peer implementations.

Run from the repository root::

    python benchmarks/bench_multiple.py                 # everything (tens of minutes on 2 cores)
    python benchmarks/bench_multiple.py --quick         # syn500, syn2000 and the real sets
    python benchmarks/bench_multiple.py --problems syn500,ellis --out results.json

Peers (each wrapped: a peer that is missing or fails is a row in the table, not a crash):

* **GLOMAP** (pycolmap): ``pycolmap.run_rotation_averaging(RotationEstimatorOptions(),
  PoseGraph, Reconstruction, [])`` with default options (MST init, L1 then IRLS with
  Geman-McClure, sigma 5 deg). The reconstruction holds one dummy camera with a trivial
  rig and one image with a trivial frame per node (image_id = node + 1); every edge is a
  ``PoseGraphEdge(cam2_from_cam1=Rigid3d(R_ij, t=0))`` added as ``add_edge(i + 1, j + 1)``.
  Result: ``reconstruction.image(k + 1).cam_from_world().rotation.matrix()``.
* **Theia** (pytheia): ``pytheia.sfm.RobustRotationEstimator(RobustRotationEstimatorOptions())
  .EstimateRotations(view_pairs, initial)`` with default options (L1 then IRLS, Huber-like
  sigma 5 deg). ``view_pairs[(i, j)]`` (i < j; edges stored the other way are transposed) is a
  ``TwoViewInfo`` whose ``rotation_2`` is the angle-axis of ``R_j R_i^T``; the orientations
  are angle-axis world -> camera. pytheia does not expose Theia's
  ``OrientationsFromMaximumSpanningTree``, so the initialisation is rotgraph's maximum
  spanning tree (``rotgraph.estimators.rotation_averaging.spanning_tree_rotations``, the same construction: chain
  the relative rotations along a max spanning tree of the edge weights); its time is
  included in Theia's.
* **Shonan** (GTSAM): ``gtsam.ShonanAveraging3(BinaryMeasurementsRot3)`` with default
  parameters, ``run(initializeRandomly(), 3, 10)`` (GTSAM's default p_max). Measurement
  ``BinaryMeasurementRot3(i, j, Rot3(R_ij^T), Unit(3))``: GTSAM's measurement is
  ``wRi^T wRj`` with ``wR = cam_from_world^T``, i.e. ``R_i R_j^T = R_ij^T``. Result
  ``cam_from_world = values.atRot3(k).matrix().T``. Always run in a spawned subprocess with a
  timeout (``--shonan-timeout``, default 120 s); its time is measured inside the child from
  the same arrays (process start-up excluded).

On large problems (> 2000 cameras or > 50k edges) GLOMAP and Theia also run in a spawned
subprocess with a timeout (``--peer-timeout``, default 600 s), timed inside the child the same
way: their C++ solvers cannot be interrupted in-process, and Theia ran for more than 30 min on
syn10000. ``OMP_WAIT_POLICY=PASSIVE`` is set unless given (see ``_common.early_thread_settings``).

Conventions are checked at start-up on a noise-free problem (``--no-check`` skips this).
Every solution is scored by ``rotgraph.evaluate.compare_rotations`` (gauge aligned). Times are
``time.perf_counter`` around the whole call from the same in-memory arrays (for peers: building
their input structures, the solve, and reading the result back into an (n, 3, 3) array), the
median over ``--repeats`` interleaved rounds (order rotated every round); Shonan runs once.
"""

from __future__ import annotations

import os
import sys


from _common import early_thread_settings  # noqa: E402 - numpy-free, before any native library

if __name__ == "__main__":
    THREAD_ENV = early_thread_settings()
else:  # imported (e.g. by the spawned Shonan child): the parent's environment is inherited
    THREAD_ENV = {}

import argparse
import hashlib
import json
import math
import platform
import resource
import statistics
import time
import traceback
from pathlib import Path

import numpy as np

import rotgraph
from rotgraph.evaluate import compare_rotations
from rotgraph.estimators.rotation_averaging import average_rotations, spanning_tree_rotations
from rotgraph import so3
from rotgraph.viewgraph import ViewGraph

from _common import ROOT, cpu_model, git_commit, load_average, usable_cpus  # noqa: E402

DATA = Path(os.environ.get("ROTGRAPH_DATASETS", ROOT.parent / "shared" / "datasets"))

SYNTHETIC = {
    # name: (n, degree, sigma_deg, outlier fraction)
    "syn500": (500, 20, 2.0, 0.10),
    "syn2000": (2000, 40, 3.0, 0.20),
    "syn10000": (10000, 50, 2.0, 0.20),
}
REAL = {
    # name: (path, has ground truth)
    "ellis": ("ellis_island/Ellis.mat", True),
    "madrid": ("madrid_metropolis", False),
    "garage": ("parking_garage/parking-garage.g2o", False),
}
ALL_PROBLEMS = list(SYNTHETIC) + list(REAL)
QUICK_PROBLEMS = ["syn500", "syn2000"] + list(REAL)
SEED = 0
GLOMAP = "GLOMAP"
LARGE_NODES, LARGE_EDGES = 2000, 50_000  # above either: peers in a subprocess with a timeout
PEERS = (GLOMAP, "Theia", "Shonan")


def log(msg: str) -> None:
    print(f"[bench_multiple {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


# --------------------------------------------------------------------------- data


def _load_mat(path: Path):
    """Private fallback reader: Chatterjee-Govindu .mat (RR_k = Rgt_j Rgt_i^T)."""
    import scipy.io

    m = scipy.io.loadmat(str(path))
    RR = np.moveaxis(np.asarray(m["RR"], dtype=np.float64), 2, 0)
    I = np.asarray(m["I"]).astype(np.int64) - 1  # uint8 in Ellis.mat: cast first
    Rgt = np.moveaxis(np.asarray(m["Rgt"], dtype=np.float64), 2, 0)
    n = max(int(I.max()) + 1, len(Rgt))
    gt = np.full((n, 3, 3), np.nan)
    has = np.abs(Rgt).sum(axis=(1, 2)) > 0
    gt[: len(Rgt)][has] = Rgt[has]
    g = ViewGraph.from_edges(I[0], I[1], RR, node_ids=np.arange(n))
    g.gt_cam_from_world = gt
    return g


def _load_1dsfm(folder: Path):
    """Private fallback reader: 1DSfM EGs.txt, EG rotation R = R_i R_j^T, so R_ij = R^T."""
    a = np.loadtxt(folder / "EGs.txt")
    i, j = a[:, 0].astype(np.int64), a[:, 1].astype(np.int64)
    R = a[:, 2:11].reshape(-1, 3, 3)
    return ViewGraph.from_edges(i, j, so3.project_to_so3(np.swapaxes(R, 1, 2)))


def _load_g2o(path: Path):
    """Private fallback reader: g2o EDGE_SE3:QUAT (x y z w); Q_ij = Q_i^T Q_j, R_ij = Q_ij^T."""
    from scipy.spatial.transform import Rotation

    ii, jj, qq = [], [], []
    for line in path.read_text().splitlines():
        f = line.split()
        if f and f[0] == "EDGE_SE3:QUAT":
            ii.append(int(f[1]))
            jj.append(int(f[2]))
            qq.append([float(v) for v in f[6:10]])
    Q = Rotation.from_quat(np.array(qq)).as_matrix()
    return ViewGraph.from_edges(np.array(ii), np.array(jj), np.swapaxes(Q, 1, 2))


def load_problem(name: str):
    """Returns (graph, has_gt, source note) or raises FileNotFoundError for absent data."""
    if name in SYNTHETIC:
        from rotgraph.synth import random_problem

        n, deg, sigma, out = SYNTHETIC[name]
        g = random_problem(n=n, degree=deg, sigma_deg=sigma, outliers=out, graph="er", seed=SEED)
        return g, True, f"random_problem(n={n}, degree={deg}, sigma={sigma}, outliers={out}, er, seed={SEED})"
    rel, has_gt = REAL[name]
    path = DATA / rel
    if not path.exists():
        raise FileNotFoundError(str(path))
    try:
        from rotgraph.pipeline.read import read_view_graph

        g = read_view_graph(path)
        how = "rotgraph.read_view_graph"
    except ImportError:
        g = {".mat": _load_mat, ".g2o": _load_g2o}.get(path.suffix, _load_1dsfm)(path)
        how = "private fallback reader"
    if not has_gt:
        g.gt_cam_from_world = None  # g2o vertices are odometry guesses, not ground truth
    if has_gt and g.gt_cam_from_world is None:
        raise RuntimeError(f"{name}: reader returned no ground truth")
    return g, has_gt, f"{path} via {how}"


# --------------------------------------------------------------------------- solvers
# Each returns (cam_from_world (n, 3, 3) with NaN rows, info dict). The caller times the call.


def run_rotgraph(g, method: str | None = None):
    r = average_rotations(g) if method is None else average_rotations(g, method=method)
    return r.cam_from_world, {
        "internal_seconds": r.seconds,
        "iterations": r.iterations,
        "converged": bool(r.converged),
        "n_solved": r.n_solved,
    }


def run_glomap(g):
    import pycolmap

    t0 = time.perf_counter()
    n = g.n_nodes
    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(
        pycolmap.Camera(camera_id=1, model="SIMPLE_PINHOLE", width=1, height=1, params=[1.0, 0.0, 0.0])
    )
    for k in range(n):
        rec.add_image_with_trivial_frame(pycolmap.Image(image_id=k + 1, camera_id=1))
    q = so3.quaternion_rows_from_matrices(g.cam2_from_cam1)  # (4, E) w, x, y, z
    q_xyzw = np.ascontiguousarray(np.roll(q, -1, axis=0).T)
    w = g.weights
    # num_matches only matters for GLOMAP's MST init / INLIER_MATCH_COUNT reweighting; with
    # all-one weights (every problem here) it is 1 everywhere, i.e. unweighted like rotgraph.
    nm = np.maximum(1, np.rint(w / np.min(w))).astype(int) if (w > 0).all() else np.ones(len(w), int)
    pg = pycolmap.PoseGraph()
    zero = np.zeros(3)
    for (i, j), qk, m in zip(g.edges.tolist(), q_xyzw, nm.tolist()):
        e = pycolmap.PoseGraphEdge(cam2_from_cam1=pycolmap.Rigid3d(rotation=pycolmap.Rotation3d(qk), translation=zero))
        e.num_matches = m
        pg.add_edge(i + 1, j + 1, e)
    opts = pycolmap.RotationEstimatorOptions()
    t1 = time.perf_counter()
    ok = pycolmap.run_rotation_averaging(opts, pg, rec, [])
    t2 = time.perf_counter()
    R = np.full((n, 3, 3), np.nan)
    if ok:
        for k in range(n):
            im = rec.image(k + 1)
            if im.has_pose:
                R[k] = im.cam_from_world().rotation.matrix()
    info = {"success": bool(ok), "solve_seconds": t2 - t1, "build_seconds": t1 - t0}
    if not ok:
        raise RuntimeError("run_rotation_averaging returned False")
    return R, info


def run_theia(g):
    import pytheia
    from scipy.spatial.transform import Rotation

    t0 = time.perf_counter()
    n = g.n_nodes
    # Initialisation: rotgraph's maximum spanning tree (Theia's own MST init is not exposed).
    qrel = so3.quaternion_rows_from_matrices(g.cam2_from_cam1)
    q0, _, _ = spanning_tree_rotations(n, g.edges, qrel, g.weights)
    init_rv = Rotation.from_quat(np.roll(q0, -1, axis=0).T).as_rotvec()
    initial = {k: init_rv[k] for k in range(n)}
    i, j = g.edges[:, 0], g.edges[:, 1]
    flip = i > j
    rel = np.where(flip[:, None, None], np.swapaxes(g.cam2_from_cam1, 1, 2), g.cam2_from_cam1)
    rv = Rotation.from_matrix(rel).as_rotvec()
    lo, hi = np.minimum(i, j).tolist(), np.maximum(i, j).tolist()
    nm = np.maximum(1, np.rint(g.weights / np.min(g.weights))).astype(int).tolist()
    pairs = {}
    for a, b, r, m in zip(lo, hi, rv, nm):
        info = pytheia.sfm.TwoViewInfo()
        info.rotation_2 = r
        info.num_verified_matches = m
        pairs[(a, b)] = info
    if len(pairs) != g.n_edges:
        raise RuntimeError("parallel edges: Theia takes one TwoViewInfo per view pair")
    est = pytheia.sfm.RobustRotationEstimator(pytheia.sfm.RobustRotationEstimatorOptions())
    t1 = time.perf_counter()
    out = est.EstimateRotations(pairs, initial)
    t2 = time.perf_counter()
    R = np.full((n, 3, 3), np.nan)
    if out:
        keys = np.fromiter(out.keys(), dtype=np.int64, count=len(out))
        vals = np.array([np.ravel(v) for v in out.values()])
        R[keys] = Rotation.from_rotvec(vals).as_matrix()
    return R, {"solve_seconds": t2 - t1, "build_seconds": t1 - t0, "init": "rotgraph MST"}


def solve_shonan(g, p_min: int = 3, p_max: int = 10, tight: bool = False):
    """GTSAM Shonan averaging; run it through :func:`run_isolated` (it can take minutes)."""
    import gtsam

    t0 = time.perf_counter()
    noise = gtsam.noiseModel.Unit.Create(3)
    ms = gtsam.BinaryMeasurementsRot3()
    for (i, j), R in zip(g.edges.tolist(), g.cam2_from_cam1):
        # GTSAM measures wRi^T wRj = R_i R_j^T (R = cam_from_world) = R_ij^T
        ms.append(gtsam.BinaryMeasurementRot3(i, j, gtsam.Rot3(np.ascontiguousarray(R.T)), noise))
    if tight:  # only for the convention check: converge fully
        lm = gtsam.LevenbergMarquardtParams.CeresDefaults()
        lm.setMaxIterations(1000)
        lm.setRelativeErrorTol(1e-14)
        lm.setAbsoluteErrorTol(1e-20)
        sa = gtsam.ShonanAveraging3(ms, gtsam.ShonanAveragingParameters3(lm))
    else:
        sa = gtsam.ShonanAveraging3(ms)  # default parameters
    initial = sa.initializeRandomly()
    t1 = time.perf_counter()
    values, min_eig = sa.run(initial, p_min, p_max)
    t2 = time.perf_counter()
    out = np.full((g.n_nodes, 3, 3), np.nan)
    for k in range(g.n_nodes):
        if values.exists(k):
            out[k] = values.atRot3(k).matrix().T
    return out, {"solve_seconds": t2 - t1, "build_seconds": t1 - t0, "min_eigenvalue": float(min_eig)}


class _Arrays:
    """The arrays the peer wrappers read from a ViewGraph (picklable, for the subprocess)."""

    def __init__(self, g):
        self.n_nodes = g.n_nodes
        self.n_edges = g.n_edges
        self.edges = np.ascontiguousarray(g.edges)
        self.cam2_from_cam1 = np.ascontiguousarray(g.cam2_from_cam1)
        self.weights = np.ascontiguousarray(g.weights)


def _isolated_child(conn, kind, arrays, kwargs, warmup=None):
    """Runs in a spawned process: one solver call, timed here, result sent back (after an
    untimed call on ``warmup`` arrays, when given: imports and first-call costs untimed)."""
    try:
        fn = kind if callable(kind) else {"shonan": solve_shonan, "glomap": run_glomap, "theia": run_theia}[kind]
        if kind == "glomap":
            _quiet_pycolmap()
        if warmup is not None:
            try:
                fn(warmup, **kwargs)
            except Exception:  # noqa: BLE001 - the timed call reports
                pass
        t0 = time.perf_counter()
        R, info = fn(arrays, **kwargs)
        info["seconds"] = time.perf_counter() - t0
        info["child_peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        conn.send(("ok", R, info))
    except Exception as e:  # noqa: BLE001 - reported in the table
        conn.send(("error", None, {"error": f"{type(e).__name__}: {e}"}))
    finally:
        conn.close()


def run_isolated(kind, g, timeout: float, warmup=None, **kwargs):
    """One solver call in a spawned subprocess with a timeout. ``kind`` names one of this
    script's peers or is a module-level function ``fn(arrays, **kwargs) -> (R, info)``.

    Returns (R, info); R is None on failure or timeout. ``info["seconds"]`` is measured in the
    child around the same call as in-process (process start-up and transfer excluded).
    """
    import multiprocessing as mp

    ctx = mp.get_context("spawn")
    parent, child = ctx.Pipe(duplex=False)
    p = ctx.Process(target=_isolated_child, args=(child, kind, _Arrays(g), kwargs, warmup), daemon=True)
    t0 = time.perf_counter()
    p.start()
    child.close()
    try:
        if parent.poll(timeout):
            status, R, info = parent.recv()
        else:
            status, R, info = "timeout", None, {"error": f"timeout (> {timeout:g} s)"}
    except EOFError:
        status, R, info = "error", None, {"error": f"child died (exit code {p.exitcode})"}
    wall = time.perf_counter() - t0
    if p.is_alive():
        p.terminate()  # our own child, by its handle
    p.join(5)
    info["wall_with_process_start"] = wall
    info["status"] = status
    info["subprocess"] = True
    return R, info


def run_shonan(g, timeout: float, **kwargs):
    return run_isolated("shonan", g, timeout, **kwargs)


def _quiet_pycolmap():
    try:
        import pycolmap

        pycolmap.logging.minloglevel = 2  # GLOMAP's INFO/WARNING lines off (no effect on the solve)
    except Exception:  # noqa: BLE001
        pass


# --------------------------------------------------------------------------- scoring


def edge_residuals_deg(R: np.ndarray, edges: np.ndarray, rel: np.ndarray) -> np.ndarray:
    """angle(R_ij, R_j R_i^T) per edge, degrees (NaN where an end is unsolved)."""
    Ri, Rj = R[edges[:, 0]], R[edges[:, 1]]
    M = np.swapaxes(rel, 1, 2) @ Rj @ np.swapaxes(Ri, 1, 2)
    c = (np.trace(M, axis1=1, axis2=2) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def chordal_cost(R: np.ndarray, edges: np.ndarray, rel: np.ndarray) -> float:
    """sum ||R_j - R_ij R_i||_F^2 over edges with both ends solved (Shonan's objective)."""
    D = R[edges[:, 1]] - rel @ R[edges[:, 0]]
    v = (D * D).sum(axis=(1, 2))
    return float(np.nansum(v))


def score(R, g, has_gt: bool) -> dict:
    out = {"n_solved": int(np.isfinite(R).all(axis=(1, 2)).sum())}
    res = edge_residuals_deg(R, g.edges, g.cam2_from_cam1)
    ok = np.isfinite(res)
    out["median_edge_residual_deg"] = float(np.median(res[ok])) if ok.any() else math.nan
    out["mean_edge_residual_deg"] = float(np.mean(res[ok])) if ok.any() else math.nan
    out["edges_under_5deg"] = float((res[ok] < 5).mean()) if ok.any() else math.nan
    out["chordal_cost"] = chordal_cost(R, g.edges, g.cam2_from_cam1)
    if has_gt:
        ev = compare_rotations(R, g.gt_cam_from_world)
        out.update(median_err_deg=ev.median, mean_err_deg=ev.mean, rmse_deg=ev.rmse, max_err_deg=ev.max,
                   under_2deg=ev.under_2deg, n_evaluated=ev.n_evaluated)
    return out


def agreement(Ra, Rb) -> dict | None:
    try:
        ev = compare_rotations(Ra, Rb)
    except Exception:  # noqa: BLE001
        return None
    return {"median": ev.median, "mean": ev.mean, "n": ev.n_evaluated}


# --------------------------------------------------------------------------- checks


def convention_checks(timeout: float) -> list[dict]:
    """Noise-free problem: every solver must return the ground truth (error ~ 0)."""
    from rotgraph.synth import random_problem

    g = random_problem(n=100, degree=10, sigma_deg=0.0, outliers=0.0, graph="er", seed=1)
    rows = []
    runs = [
        ("rotgraph", lambda: run_rotgraph(g)),
        (GLOMAP, lambda: run_glomap(g)),
        ("Theia", lambda: run_theia(g)),
        ("Shonan (default params)", lambda: run_shonan(g, timeout)),
        ("Shonan (LM run to 1e-14)", lambda: run_shonan(g, timeout, tight=True)),
    ]
    for name, fn in runs:
        try:
            R, info = fn()
            if R is None:
                raise RuntimeError(info.get("error"))
            ev = compare_rotations(R, g.gt_cam_from_world)
            rows.append({"solver": name, "median_err_deg": ev.median, "max_err_deg": ev.max, "n": ev.n_evaluated})
        except Exception as e:  # noqa: BLE001
            rows.append({"solver": name, "error": f"{type(e).__name__}: {e}"})
    return rows


# --------------------------------------------------------------------------- main loop


def is_large(g) -> bool:
    return g.n_nodes > LARGE_NODES or g.n_edges > LARGE_EDGES


def solvers_for(args, g):
    """[(name, callable(g) -> (R, info), repeatable)]; Shonan runs once per problem.

    On large problems GLOMAP and Theia run in a subprocess with ``--peer-timeout`` (their
    C++ cannot be interrupted in-process; Theia ran > 30 min on syn10000).
    """
    out = [("rotgraph", lambda g: run_rotgraph(g), True)]
    for m in args.extra_methods:
        out.append((f"rotgraph {m}", lambda g, m=m: run_rotgraph(g, m), True))
    if is_large(g) and not args.in_process:
        out.append((GLOMAP, lambda g: run_isolated("glomap", g, args.peer_timeout), True))
        out.append(("Theia", lambda g: run_isolated("theia", g, args.peer_timeout), True))
    else:
        out.append((GLOMAP, run_glomap, True))
        out.append(("Theia", run_theia, True))
    if not args.no_shonan:
        out.append(("Shonan", lambda g: run_shonan(g, args.shonan_timeout), False))
    return out


def bench_problem(name: str, args) -> dict:
    log(f"{name}: loading")
    try:
        g, has_gt, source = load_problem(name)
    except FileNotFoundError as e:
        log(f"{name}: data absent ({e}), skipped")
        return {"problem": name, "skipped": f"data absent: {e}"}
    full_n = g.n_nodes
    if g.components().max() > 0:
        g, _, _ = g.largest_component()
        source += f" (largest component: {g.n_nodes} of {full_n} nodes)"
    prob = {"problem": name, "n": g.n_nodes, "E": g.n_edges, "has_gt": has_gt, "source": source, "methods": {}}
    solvers = solvers_for(args, g)
    times = {s[0]: [] for s in solvers}
    results: dict[str, dict] = {s[0]: {} for s in solvers}
    sols: dict[str, np.ndarray] = {}
    rounds = max(1, args.repeats)
    for rnd in range(rounds):
        k = rnd % len(solvers)
        order = solvers[k:] + solvers[:k]
        for sname, fn, repeatable in order:
            if rnd > 0 and (not repeatable or "error" in results[sname]
                            or (times[sname] and times[sname][0] > args.max_repeat_seconds)):
                continue
            log(f"{name}: round {rnd + 1}/{rounds} {sname}")
            try:
                t0 = time.perf_counter()
                R, info = fn(g)
                dt = time.perf_counter() - t0
                if R is None:
                    results[sname] = {"error": info.get("error", "failed"), **info}
                    continue
                if info.get("subprocess"):
                    dt = info["seconds"]  # measured in the child around the same call
                times[sname].append(dt)
                if rnd == 0:
                    sols[sname] = R
                    results[sname] = {**info, **score(R, g, has_gt)}
                else:
                    for key in ("solve_seconds", "build_seconds", "internal_seconds"):
                        if key in info:
                            results[sname].setdefault(f"all_{key}", [results[sname].get(key)]).append(info[key])
            except Exception as e:  # noqa: BLE001 - a failing peer is a table row
                results[sname] = {"error": f"{type(e).__name__}: {e}", "traceback": traceback.format_exc(limit=3)}
                log(f"{name}: {sname} failed: {e}")
    for sname in results:
        r = results[sname]
        if times[sname]:
            r["seconds"] = statistics.median(times[sname])
            r["all_seconds"] = times[sname]
        for key in ("solve_seconds", "build_seconds", "internal_seconds"):
            if f"all_{key}" in r:
                r[key] = statistics.median(r[f"all_{key}"])
    # agreement between every pair of solutions (gauge aligned)
    names = list(sols)
    prob["agreement"] = {a: {b: agreement(sols[a], sols[b]) for b in names if b != a} for a in names}
    for sname, r in results.items():
        r["agree_rotgraph"] = prob["agreement"].get(sname, {}).get("rotgraph")
        r["agree_glomap"] = prob["agreement"].get(sname, {}).get(GLOMAP)
    prob["methods"] = results
    # rotgraph's median error (or median edge residual without GT) over the best peer's
    key = "median_err_deg" if has_gt else "median_edge_residual_deg"
    peer_vals = [results[p][key] for p in PEERS if p in results and key in results[p]]
    if peer_vals and key in results.get("rotgraph", {}):
        best = min(peer_vals)
        prob["rotgraph_over_best_peer"] = results["rotgraph"][key] / best if best > 0 else math.inf
        prob["ratio_basis"] = key
    return prob


# --------------------------------------------------------------------------- output


def fmt(x, digits=3):
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "–"
    if isinstance(x, float):
        if abs(x) >= 1000:
            return f"{x:,.0f}"
        if abs(x) >= 100:
            return f"{x:.1f}"
        if abs(x) >= 10:
            return f"{x:.2f}"
        if x != 0 and abs(x) < 10 ** -(digits - 1):
            return f"{x:.1e}"
        return f"{x:.{digits}f}"
    return str(x)


def render(problems: list[dict], header: dict, checks) -> str:
    L = []
    L.append("# Multiple rotation averaging: rotgraph vs GLOMAP / Theia / Shonan\n")
    for k, v in header.items():
        L.append(f"- {k}: {v}")
    if checks:
        L.append("\n## Convention check (noise-free ER problem, n = 100, degree 10)\n")
        L.append("| solver | median err (deg) | max err (deg) |")
        L.append("|---|---|---|")
        for c in checks:
            if "error" in c:
                L.append(f"| {c['solver']} | failed: {c['error']} | |")
            else:
                L.append(f"| {c['solver']} | {fmt(c['median_err_deg'])} | {fmt(c['max_err_deg'])} |")
    L.append("\n## Results\n")
    L.append("seconds = median whole-call time over the rounds (peers: build inputs + solve + read back; "
             "Shonan: one run, inside its subprocess); `solve s` = the peer's solver call alone / rotgraph's "
             "`r.seconds`; `×GLOMAP` = seconds / GLOMAP's seconds on the same problem in the same run. "
             "Errors in degrees vs ground truth after gauge alignment (`compare_rotations`); "
             "`agr rg` / `agr GL` = median angle to rotgraph's / GLOMAP's solution after gauge alignment; "
             "`med resid` = median over edges of angle(R_ij, R_j R_i^T). `rg / best peer` = rotgraph's "
             "median error over the best peer's (median edge residual on sets without ground truth).\n")
    L.append("| problem | n | E | method | seconds | solve s | ×GLOMAP | median err | mean err | agr rg | agr GL "
             "| med resid | rg / best peer | notes |")
    L.append("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for p in problems:
        if "skipped" in p:
            L.append(f"| {p['problem']} | | | | | | | | | | | | | skipped: {p['skipped']} |")
            continue
        gl = p["methods"].get(GLOMAP, {}).get("seconds")
        for m, r in p["methods"].items():
            ratio_col = ""
            if m == "rotgraph" and "rotgraph_over_best_peer" in p:
                ratio_col = fmt(p["rotgraph_over_best_peer"]) + ("" if p["has_gt"] else " (resid)")
            if "error" in r:
                L.append(f"| {p['problem']} | {p['n']} | {p['E']} | {m} | – | | | | | | | | {ratio_col} "
                         f"| **{r['error'].splitlines()[0][:90]}** |")
                continue
            notes = [f"solved {r['n_solved']}/{p['n']}", f"{len(r.get('all_seconds', []))} run(s)"]
            if "iterations" in r:
                notes.append(f"{r['iterations']} it")
            if m == "Shonan":
                notes.append(f"λmin {r.get('min_eigenvalue', math.nan):.1e}")
            if r.get("subprocess"):
                notes.append(f"subprocess, wall+spawn {fmt(r.get('wall_with_process_start'))} s")
            if m == "Theia":
                notes.append("init rotgraph MST")
            solve = r.get("internal_seconds", r.get("solve_seconds"))
            agr = lambda a: fmt(a["median"]) if a else ""  # noqa: E731
            L.append(
                f"| {p['problem']} | {p['n']} | {p['E']} | {m} | {fmt(r.get('seconds'))} | {fmt(solve)} | "
                f"{fmt(r['seconds'] / gl) if gl and r.get('seconds') else '–'} | "
                f"{fmt(r.get('median_err_deg')) if p['has_gt'] else 'no GT'} | "
                f"{fmt(r.get('mean_err_deg')) if p['has_gt'] else 'no GT'} | "
                f"{agr(r.get('agree_rotgraph'))} | {agr(r.get('agree_glomap'))} | "
                f"{fmt(r.get('median_edge_residual_deg'))} | {ratio_col} | {', '.join(notes)} |"
            )
    # pairwise agreement and costs for the sets without ground truth
    for p in problems:
        if "skipped" in p or p["has_gt"]:
            continue
        names = list(p["agreement"])
        L.append(f"\n### {p['problem']} (no ground truth): pairwise agreement, median (mean) deg\n")
        L.append("| | " + " | ".join(names) + " |")
        L.append("|---" * (len(names) + 1) + "|")
        for a in names:
            cells = []
            for b in names:
                x = p["agreement"][a].get(b)
                cells.append("·" if a == b else (f"{fmt(x['median'])} ({fmt(x['mean'])})" if x else "–"))
            L.append(f"| {a} | " + " | ".join(cells) + " |")
        L.append("\n| method | median edge resid | mean edge resid | edges < 5° | chordal cost Σ‖R_j − R_ij R_i‖²_F |")
        L.append("|---|---|---|---|---|")
        for m, r in p["methods"].items():
            if "error" not in r:
                L.append(f"| {m} | {fmt(r['median_edge_residual_deg'])} | {fmt(r['mean_edge_residual_deg'])} | "
                         f"{100 * r['edges_under_5deg']:.1f} % | {fmt(r['chordal_cost'])} |")
    return "\n".join(L)


def header_info(args) -> dict:
    def version(mod):
        try:
            import importlib.metadata

            m = __import__(mod)
            return getattr(m, "__version__", None) or importlib.metadata.version(mod)
        except Exception as e:  # noqa: BLE001
            return f"missing ({type(e).__name__})"

    commit, cpu = git_commit(), cpu_model()
    import scipy

    return {
        "date": time.strftime("%Y-%m-%d %H:%M:%S"),
        "python": platform.python_version(),
        "numpy / scipy": f"{np.__version__} / {scipy.__version__}",
        "rotgraph": f"{getattr(rotgraph, '__version__', '?')} (git {commit})",
        "pycolmap / pytheia / gtsam": f"{version('pycolmap')} / {version('pytheia')} / {version('gtsam')}",
        "cpu": f"{cpu}, os.cpu_count() = {os.cpu_count()}, usable = {usable_cpus()}",
        "load average at start": load_average(" "),
        "rounds": f"{args.repeats} interleaved (order rotated each round), time = median; a solver whose "
                  f"first round took > {args.max_repeat_seconds:g} s runs once; Shonan once, "
                  f"timeout {args.shonan_timeout:g} s; GLOMAP / Theia in a subprocess with timeout "
                  f"{args.peer_timeout:g} s on problems with > {LARGE_NODES} cameras or > {LARGE_EDGES} edges",
        "seed": SEED,
        "thread environment": ", ".join(f"{k}={v}" for k, v in THREAD_ENV.items()),
        "sha256 of rotgraph/estimators/rotation_averaging.py (first 12)": _sha(Path(rotgraph.__file__).parent / "estimators" / "rotation_averaging.py"),
    }


def _sha(path: Path) -> str:
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()[:12]
    except OSError:
        return "?"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="syn500, syn2000 and the real sets only")
    ap.add_argument("--problems", help=f"comma-separated subset of {','.join(ALL_PROBLEMS)}")
    ap.add_argument("--out", help="write all numbers to this JSON file")
    ap.add_argument("--repeats", type=int, default=3, help="timed rounds for rotgraph / GLOMAP / Theia (default 3)")
    ap.add_argument("--max-repeat-seconds", type=float, default=60.0,
                    help="a solver whose first round took longer is not repeated (default 60)")
    ap.add_argument("--shonan-timeout", type=float, default=120.0, help="seconds (default 120)")
    ap.add_argument("--peer-timeout", type=float, default=600.0,
                    help="seconds for GLOMAP / Theia on large problems (> 2000 cameras or > 50k edges; default 600)")
    ap.add_argument("--in-process", action="store_true",
                    help="run GLOMAP / Theia in-process even on large problems (no timeout)")
    ap.add_argument("--no-shonan", action="store_true")
    ap.add_argument("--extra-methods", default="l2,chordal",
                    help="extra rotgraph methods as rows (comma-separated, '' for none; default l2,chordal)")
    ap.add_argument("--no-check", action="store_true", help="skip the noise-free convention check")
    ap.add_argument("--threads", type=int, help="cap OpenMP / BLAS threads (default: library defaults)")
    args = ap.parse_args(argv)
    args.extra_methods = [m for m in args.extra_methods.split(",") if m]
    if args.problems:
        names = [s.strip() for s in args.problems.split(",") if s.strip()]
        bad = [s for s in names if s not in ALL_PROBLEMS]
        if bad:
            ap.error(f"unknown problem(s) {bad}; choose from {ALL_PROBLEMS}")
    else:
        names = QUICK_PROBLEMS if args.quick else ALL_PROBLEMS
    _quiet_pycolmap()
    header = header_info(args)
    t_start = time.perf_counter()
    checks = None
    if not args.no_check:
        log("convention checks (noise-free)")
        checks = convention_checks(args.shonan_timeout)
    problems = []
    for name in names:
        problems.append(bench_problem(name, args))
    ru_self = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    ru_child = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    header["total wall time"] = f"{time.perf_counter() - t_start:.0f} s"
    text = render(problems, header, checks)
    text += (f"\n\nPeak RSS of this process (all in-process solvers): {ru_self:.0f} MB; "
             f"largest subprocess (Shonan; GLOMAP / Theia on large problems): {ru_child:.0f} MB (resource.getrusage, ru_maxrss).\n")
    print(text)
    if args.out:
        def clean(o):
            if isinstance(o, dict):
                return {str(k): clean(v) for k, v in o.items() if k != "traceback"}
            if isinstance(o, (list, tuple)):
                return [clean(v) for v in o]
            if isinstance(o, (np.floating, np.integer)):
                return o.item()
            if isinstance(o, float) and not math.isfinite(o):
                return None
            return o

        Path(args.out).write_text(json.dumps(clean({"header": header, "checks": checks, "problems": problems,
                                                    "peak_rss_mb": ru_self, "peak_rss_children_mb": ru_child}),
                                             indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
