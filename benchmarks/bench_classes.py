#!/usr/bin/env python
"""Benchmark of problem classes: rotgraph's default on data it was not tuned on (issue #16).

Run from the repository root::

    python benchmarks/bench_classes.py                   # every class, 3 seeds, real sets
    python benchmarks/bench_classes.py --quick           # one seed, smaller problems
    python benchmarks/bench_classes.py --classes heavy45,slam --seeds 5 --out results.json

Classes (``rotgraph.synth.random_problem``; sizes in ``CLASSES``, seeds 0, 1, ...): SfM-like
Erdős–Rényi graphs (three points of degree 10–40, sigma 1–3 deg, 0–30 % uniform outliers),
SLAM pose graphs (degree 4 and 6, sigma 0.5–3 deg, 0 % and 5 % outliers on loop closures),
heavy outliers (45 % and 60 % uniform), structured outliers (20 % of the cameras seen
turned 180 deg on 40 % of their edges), mixed edge quality (half the edges 0.5 deg, half
5 deg, no weights), trajectories; then the real sets of ``../shared/datasets`` (Ellis
Island with ground truth; parking-garage and cubicle g2o without: residual statistics only,
the g2o vertices are odometry, never ground truth).

Contenders, timed and scored in the same run, problem by problem:

* ``rotgraph`` = ``rotgraph.average_rotations(graph)``, looked up at call time: whatever the
  current default is; ``rotgraph l2`` (``method="l2"``) and ``rotgraph init=chordal``.
* GLOMAP, Theia and GTSAM Shonan: ``bench_multiple``'s runners (Shonan in a subprocess
  with a timeout).
* ``GTSAM LM-Huber``: ``BetweenFactorRot3`` factors (measurement ``Rot3(R_ij^T)``, GTSAM's
  ``wRi^T wRj``) with ``noiseModel.Robust(Huber(k), Unit(3))``, k = ``--huber-deg``
  (default 5 deg, the scale GLOMAP and Theia use), a tight prior on camera 0, started from
  the chordal relaxation (``--gtsam-init``: rotgraph's ``method="chordal"``, default, or
  GTSAM's own ``InitializePose3.initializeOrientations``, which is much slower on dense
  graphs), ``LevenbergMarquardtOptimizer`` with default parameters. In a spawned
  subprocess with a timeout; its time (the chordal start included) is measured there.
* ``oracle``: ``method="l2"`` on the subgraph of the TRUE inlier edges, started from the
  ground truth (``init="vertices"``), to a 1e-6 deg step, no outlier threshold: the best
  any estimator can do with the inliers. On the mixed class each edge is weighted by
  1/sigma^2 of its true noise level (``use_weights``): the ML estimate, which no contender
  can form (they are given no weights). Not timed, not a peer.
* ``L2 opt`` (clean pose graphs and the g2o sets): the least sum of squared geodesic
  residuals ``SSR = sum angle(R_ij, R_j R_i^T)^2`` reached by ``method="l2"`` on all edges
  started from the truth (synthetic) or from the chordal solution and each contender's
  solution (real sets). ``SSR / L2 opt`` of a solution is its SSR over that minimum. On a
  problem with per-edge information matrices (g2o sets, the ``aniso`` classes) both are the
  whitened sum ``d^T H d``, the ML cost, which rotgraph's L2 then minimises; the peers are
  given no information (they cannot use it), the oracle is its ML estimate.

Scores: median and mean error (deg) after gauge alignment (``compare_rotations``) per seed;
a class's value is the mean over its seeds. ``default / best peer`` = rotgraph default's
value over the smallest peer value (peers: GLOMAP, Theia, GTSAM LM-Huber, Shonan; the worst
per-seed ratio in brackets); ``× oracle`` = over the oracle's. A peer that fails or times
out is a cell in the table, not a crash.
"""

from __future__ import annotations

import os
import sys

from _common import early_thread_settings  # noqa: E402 - numpy-free, before any native library

if __name__ == "__main__":
    early_thread_settings()  # libgomp waits passively; --threads N caps OpenMP / BLAS

import argparse
import json
import math
import platform
import resource
import signal
import statistics
import time
import traceback
from dataclasses import replace
from pathlib import Path

import numpy as np

import bench_multiple as bm  # noqa: E402  (the peers' runners, loaders and scoring)
from _common import cpu_model, git_commit, json_clean, load_average, table, usable_cpus  # noqa: E402
from rotgraph.evaluate import compare_rotations
from rotgraph.synth import random_problem

# name: (description, random_problem keyword arguments, n full, n quick, most seeds)
# (n quick None: not in the --quick run unless named; most seeds None: --seeds of them)
CLASSES = {
    "er-a": ("SfM ER: degree 10, σ 1°, no outliers",
             dict(graph="er", degree=10, sigma_deg=1.0, outliers=0.0), 500, 200, None),
    "er-b": ("SfM ER: degree 25, σ 2°, 15 % uniform outliers",
             dict(graph="er", degree=25, sigma_deg=2.0, outliers=0.15), 500, 200, None),
    "er-c": ("SfM ER: degree 40, σ 3°, 30 % uniform outliers",
             dict(graph="er", degree=40, sigma_deg=3.0, outliers=0.30), 500, 200, None),
    "slam": ("SLAM pose graph: degree 4, σ 1.5°, no outliers",
             dict(graph="posegraph", degree=4, sigma_deg=1.5, outliers=0.0), 1000, 300, None),
    "slam-lo": ("SLAM pose graph: degree 6, σ 0.5°, no outliers",
                dict(graph="posegraph", degree=6, sigma_deg=0.5, outliers=0.0), 1000, 300, None),
    "slam-hi": ("SLAM pose graph: degree 4, σ 3°, no outliers",
                dict(graph="posegraph", degree=4, sigma_deg=3.0, outliers=0.0), 1000, 300, None),
    "slam-out": ("SLAM pose graph: degree 4, σ 1.5°, 5 % outliers (on loop closures)",
                 dict(graph="posegraph", degree=4, sigma_deg=1.5, outliers=0.05), 1000, 300, None),
    "heavy45": ("heavy outliers: ER degree 30, σ 2°, 45 % uniform",
                dict(graph="er", degree=30, sigma_deg=2.0, outliers=0.45), 1000, 200, None),
    "heavy60": ("heavy outliers: ER degree 30, σ 2°, 60 % uniform",
                dict(graph="er", degree=30, sigma_deg=2.0, outliers=0.60), 500, 200, None),
    "flip": ("structured: ER degree 20, σ 1°, 20 % of cameras turned 180° on 40 % of their edges",
             dict(graph="er", degree=20, sigma_deg=1.0, outliers=0.4, outlier_model="flip", flip_group=0.2), 500, 200, None),
    "mixed": ("mixed quality: ER degree 20, half the edges σ 0.5°, half 5°, no weights",
              dict(graph="er", degree=20, sigma_deg=0.5, outliers=0.0, noise_mix=(0.5, 5.0)), 500, 200, None),
    "traj": ("trajectory: degree 10, σ 2°, 10 % uniform outliers",
             dict(graph="traj", degree=10, sigma_deg=2.0, outliers=0.1), 500, 200, None),
    "aniso": ("per-edge uncertainty: ER degree 20, σ 2° scaled ×[1/3, 3] per axis, random axes, 10 % uniform outliers; "
              "true information given",
              dict(graph="er", degree=20, sigma_deg=2.0, outliers=0.1, uncertainty_spread=3.0), 500, 200, None),
    "slam-aniso": ("per-edge uncertainty: SLAM pose graph degree 4, σ 1.5° scaled ×[1/3, 3] per axis, no outliers; "
                   "true information given",
                   dict(graph="posegraph", degree=4, sigma_deg=1.5, outliers=0.0, uncertainty_spread=3.0), 1000, 300, None),
    "er2000": ("SfM ER, larger: n 2000, degree 40, σ 3°, 20 % uniform outliers (one seed)",
               dict(graph="er", degree=40, sigma_deg=3.0, outliers=0.2), 2000, None, 1),
}
REAL = {  # name: (path under the datasets folder, has ground truth)
    "ellis": ("ellis_island/Ellis.mat", True),
    "garage": ("parking_garage/parking-garage.g2o", False),
    "cubicle": ("cubicle/cubicle.g2o", False),
}
QUICK_REAL = ["ellis", "garage"]
DEFAULT = "rotgraph"
VARIANTS = {"rotgraph l2": dict(method="l2"), "rotgraph init=chordal": dict(init="chordal")}
GLOMAP, THEIA, LM, SHONAN = "GLOMAP", "Theia", "GTSAM LM-Huber", "Shonan"
PEERS = (GLOMAP, THEIA, LM, SHONAN)
ORACLE = "oracle"
L2_TOL_DEG = 1e-6  # step tolerance of the oracle and of the L2 optimum


def log(msg: str) -> None:
    print(f"[bench_classes {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


# --------------------------------------------------------------------------- contenders


def run_rotgraph(g, **overrides):
    import rotgraph  # at call time: whatever the current default is

    r = rotgraph.average_rotations(g, **overrides)
    return r.cam_from_world, {"internal_seconds": r.seconds, "iterations": r.iterations,
                              "converged": bool(r.converged), "stages": [s.get("stage") for s in r.stages]}


def solve_gtsam_lm(g, huber_deg: float | None = 5.0, init: str = "rotgraph"):
    """GTSAM: chordal initialisation, then Levenberg-Marquardt on Huber-robust Rot3 factors
    (``huber_deg=None``: unit noise, plain L2; bench_family's GTSAM LM).

    ``init="rotgraph"``: the chordal relaxation as rotgraph solves it
    (``average_rotations(method="chordal")``, fast); ``"gtsam"``: GTSAM's own
    (``InitializePose3.initializeOrientations`` on the edges as ``BetweenFactorPose3`` with zero
    translation; the same estimator, but 2-4 s at 500 cameras / 5,000 edges and over 2 min at
    2,000 / 40,000 on this machine).
    """
    import gtsam

    n = g.n_nodes
    t0 = time.perf_counter()
    edges = g.edges.tolist()
    meas = [gtsam.Rot3(np.ascontiguousarray(R.T)) for R in g.cam2_from_cam1]  # wRi^T wRj = R_i R_j^T
    if init == "gtsam":
        pose_graph = gtsam.NonlinearFactorGraph()
        unit6 = gtsam.noiseModel.Unit.Create(6)
        zero = np.zeros(3)
        for (i, j), m in zip(edges, meas):
            pose_graph.add(gtsam.BetweenFactorPose3(i, j, gtsam.Pose3(m, zero), unit6))
        pose_graph.add(gtsam.PriorFactorPose3(0, gtsam.Pose3(), unit6))
        t1 = time.perf_counter()
        values0 = gtsam.InitializePose3.initializeOrientations(pose_graph)
        start = [values0.atRot3(k) if values0.exists(k) else gtsam.Rot3() for k in range(n)]
    else:
        from rotgraph import ViewGraph, average_rotations

        t1 = time.perf_counter()
        vg = ViewGraph(np.arange(n), np.asarray(g.edges), np.asarray(g.cam2_from_cam1), np.ones(g.n_edges))
        R0 = average_rotations(vg, method="chordal").cam_from_world
        start = [gtsam.Rot3(np.ascontiguousarray(R.T)) if np.isfinite(R).all() else gtsam.Rot3() for R in R0]
    t2 = time.perf_counter()
    unit = gtsam.noiseModel.Unit.Create(3)
    robust = unit if huber_deg is None else gtsam.noiseModel.Robust.Create(
        gtsam.noiseModel.mEstimator.Huber.Create(math.radians(huber_deg)), unit)
    graph = gtsam.NonlinearFactorGraph()
    for (i, j), m in zip(edges, meas):
        graph.add(gtsam.BetweenFactorRot3(i, j, m, robust))
    graph.add(gtsam.PriorFactorRot3(0, start[0], gtsam.noiseModel.Isotropic.Sigma(3, 1e-4)))
    initial = gtsam.Values()
    for k in range(n):
        initial.insert(k, start[k])
    t3 = time.perf_counter()
    opt = gtsam.LevenbergMarquardtOptimizer(graph, initial, gtsam.LevenbergMarquardtParams())
    values = opt.optimize()
    t4 = time.perf_counter()
    out = np.full((n, 3, 3), np.nan)
    for k in range(n):
        if values.exists(k):
            out[k] = values.atRot3(k).matrix().T
    return out, {"solve_seconds": t4 - t3, "init_seconds": t2 - t1, "build_seconds": (t1 - t0) + (t3 - t2),
                 "iterations": int(opt.iterations()), "huber_deg": huber_deg, "init": init}


def run_in_subprocess(fn, g, timeout: float, **kwargs):
    """``fn(arrays, **kwargs)`` in a spawned subprocess with a timeout: bench_multiple's
    run_isolated, after an untimed call on a 10-camera problem (imports and first-call costs
    are not timed). R is None on failure or timeout."""
    warmup = bm._Arrays(random_problem(n=10, degree=4, sigma_deg=0.0, outliers=0.0, graph="er", seed=0))
    return bm.run_isolated(fn, g, timeout, warmup=warmup, **kwargs)


def shonan_timeout(args, g) -> float:
    """``--shonan-timeout``, or by default 20 s, or 1 ms per edge when that is more (40 s at
    40,000 edges): where Shonan converges here it takes 3-5 s at 1,000 cameras and 35 s at
    40,000 edges; on the pose graphs it often runs 40-60 s and then fails to converge for
    p_max = 10."""
    return args.shonan_timeout if args.shonan_timeout else max(20.0, 1e-3 * g.n_edges)


def contenders(args, g):
    """[(name, callable(g) -> (R, info))] in the order they run."""
    out = [(DEFAULT, lambda g: run_rotgraph(g))]
    for name, kw in VARIANTS.items():
        out.append((name, lambda g, kw=kw: run_rotgraph(g, **kw)))
    out += [(GLOMAP, bm.run_glomap), (THEIA, bm.run_theia)]
    if not args.no_gtsam:
        out.append((LM, lambda g: run_in_subprocess(solve_gtsam_lm, g, args.gtsam_timeout, huber_deg=args.huber_deg,
                                                    init=args.gtsam_init)))
    if not args.no_shonan:
        out.append((SHONAN, lambda g: bm.run_shonan(g, shonan_timeout(args, g))))
    return out


# --------------------------------------------------------------------------- references


def l2_from(g, start: np.ndarray, weights: np.ndarray | None = None):
    """``method="l2"`` on every edge of ``g`` from the rotations ``start`` (NaN rows chained
    along the spanning tree), to a 1e-6 deg step, without an outlier threshold; with
    ``weights``, the weighted L2 cost."""
    import rotgraph

    h = replace(g, initial_cam_from_world=np.asarray(start, dtype=np.float64))
    if weights is not None:
        h = replace(h, weights=np.asarray(weights, dtype=np.float64))
    r = rotgraph.average_rotations(h, method="l2", init="vertices", step_tol_deg=L2_TOL_DEG, max_iterations=300,
                                   outlier_threshold_deg=180.0, use_weights=weights is not None)
    return r.cam_from_world


def oracle(g):
    """The ML estimate from the true inliers: L2 on the true inlier edges (the largest
    component of them), each weighted by 1/sigma^2 of its true noise level (all equal but
    on the mixed class), started from the ground truth."""
    keep = ~g.meta["outlier"]
    sub, idx = g.subgraph(np.arange(g.n_nodes), keep)
    sigma = np.asarray(g.meta.get("edge_sigma_deg", np.ones(g.n_edges)), dtype=np.float64)[idx]
    weights = None if np.all(sigma == sigma[0]) or not (sigma > 0).all() else 1.0 / sigma**2
    return l2_from(sub, g.gt_cam_from_world, weights)


def ssr(R, g) -> float:
    """Sum over the edges with both ends solved of angle(R_ij, R_j R_i^T)^2 (rad^2); for a
    graph with per-edge information matrices, the whitened sum d^T H d (the ML cost, which
    the L2 optimum then minimises), d = log(R_ij (R_j R_i^T)^T)."""
    if g.information is None:
        res = np.radians(bm.edge_residuals_deg(R, g.edges, g.cam2_from_cam1))
        return float(np.nansum(res * res))
    from rotgraph import so3

    i, j = g.edges[:, 0], g.edges[:, 1]
    ok = np.isfinite(R[i]).all(axis=(1, 2)) & np.isfinite(R[j]).all(axis=(1, 2))
    d = so3.log(g.cam2_from_cam1[ok] @ np.swapaxes(R[j[ok]] @ np.swapaxes(R[i[ok]], 1, 2), 1, 2))
    return float(np.einsum("ea,eab,eb->", d, g.information[ok], d))


def score(R, g, has_gt: bool) -> dict:
    out = bm.score(R, g, has_gt)
    out["ssr"] = ssr(R, g)
    return out


# --------------------------------------------------------------------------- one problem


def bench_one(g, has_gt: bool, args, l2_reference: str | None) -> dict:
    """Every contender on ``g``; the oracle (with GT) and the L2 optimum when asked:
    ``l2_reference`` = "truth" (from the ground truth) or "solutions" (from the chordal
    solution and every contender's)."""
    results, sols = {}, {}
    for name, fn in contenders(args, g):
        try:
            t0 = time.perf_counter()
            R, info = fn(g)
            dt = time.perf_counter() - t0
            if R is None:
                results[name] = {"error": info.get("error", "failed"), **info}
                log(f"  {name}: {results[name]['error']}")
                continue
            if info.get("subprocess"):
                dt = info["seconds"]  # measured in the child around the same call
            sols[name] = R
            results[name] = {**info, "seconds": dt, **score(R, g, has_gt)}
            msg = f"median {results[name]['median_err_deg']:.3f} deg" if has_gt else \
                f"median resid {results[name]['median_edge_residual_deg']:.3f} deg"
            log(f"  {name}: {dt:.2f} s, {msg}")
        except Exception as e:  # noqa: BLE001 - a failing contender is a cell
            results[name] = {"error": f"{type(e).__name__}: {e}", "traceback": traceback.format_exc(limit=3)}
            log(f"  {name} failed: {e}")
    out = {"methods": results}
    if has_gt and "outlier" in g.meta:
        try:
            R = oracle(g)
            out["oracle"] = score(R, g, True)
            out["oracle"]["n_inlier_edges"] = int((~g.meta["outlier"]).sum())
        except Exception as e:  # noqa: BLE001
            out["oracle"] = {"error": f"{type(e).__name__}: {e}"}
    if l2_reference:
        starts = {"truth": g.gt_cam_from_world} if l2_reference == "truth" else {}
        if l2_reference == "solutions":
            import rotgraph

            starts["chordal"] = rotgraph.average_rotations(g, method="chordal").cam_from_world
            starts.update(sols)
        best = None
        for where, R0 in starts.items():
            try:
                R = l2_from(g, R0)
                s = ssr(R, g)
                if best is None or s < best[1]:
                    best = (where, s, R)
            except Exception as e:  # noqa: BLE001
                log(f"  L2 from {where} failed: {e}")
        if best:
            out["l2_opt"] = {"ssr": best[1], "from": best[0], "n_starts": len(starts)}
            for name, r in results.items():
                if "ssr" in r:
                    r["ssr_over_l2opt"] = r["ssr"] / best[1]
                    r["agree_l2opt_deg"] = compare_rotations(sols[name], best[2]).median
    return out


def convention_check(args) -> list[dict]:
    """Every contender on a noise-free problem (n = 100, degree 10) must return the truth;
    also the warm-up (first-call imports) before anything is timed."""
    g = random_problem(n=100, degree=10, sigma_deg=0.0, outliers=0.0, graph="er", seed=1)
    rows = []
    for name, fn in contenders(args, g):
        try:
            R, info = fn(g)
            if R is None:
                raise RuntimeError(info.get("error"))
            ev = compare_rotations(R, g.gt_cam_from_world)
            rows.append({"solver": name, "max_err_deg": ev.max, "n": ev.n_evaluated})
        except Exception as e:  # noqa: BLE001
            rows.append({"solver": name, "error": f"{type(e).__name__}: {e}"})
    try:
        rows.append({"solver": ORACLE, "max_err_deg": compare_rotations(oracle(g), g.gt_cam_from_world).max, "n": 100})
    except Exception as e:  # noqa: BLE001
        rows.append({"solver": ORACLE, "error": f"{type(e).__name__}: {e}"})
    return rows


# --------------------------------------------------------------------------- classes


def bench_class(name: str, args) -> dict:
    desc, kw, n_full, n_quick, most = CLASSES[name]
    n = n_quick if args.quick and n_quick else n_full
    clean_pg = kw["graph"] == "posegraph" and kw["outliers"] == 0
    cls = {"class": name, "description": desc, "n": n, "params": {**kw, "n": n}, "seeds": []}
    for seed in range(min(args.seeds, most or args.seeds)):
        g = random_problem(n=n, seed=seed, **kw)
        log(f"{name} seed {seed}: {g.n_nodes} cameras, {g.n_edges} edges, {int(g.meta['outlier'].sum())} outliers")
        run = bench_one(g, True, args, "truth" if clean_pg else None)
        run.update(seed=seed, E=g.n_edges, n_outliers=int(g.meta["outlier"].sum()))
        cls["seeds"].append(run)
    summarise(cls, has_gt=True)
    return cls


def bench_real(name: str, args) -> dict:
    rel, has_gt = REAL[name]
    bm.REAL.setdefault(name, (rel, has_gt))  # bench_multiple's loader, one more set
    try:
        g, has_gt, source = bm.load_problem(name)
    except FileNotFoundError as e:
        log(f"{name}: data absent ({e}), skipped")
        return {"class": name, "skipped": f"data absent: {e}"}
    except Exception as e:  # noqa: BLE001 - e.g. the library's default refuses parallel edges
        if not rel.endswith(".g2o"):
            raise
        # cubicle.g2o has parallel edges (several measurements of one pair): keep them all,
        # as pose-graph solvers do (rotgraph solve's default for g2o since c593aee)
        from rotgraph.pipeline.read import read_view_graph

        log(f"{name}: {type(e).__name__}: {str(e)[:100]}; read again with duplicates='keep'")
        g = read_view_graph(bm.DATA / rel, duplicates="keep")
        g.gt_cam_from_world = None  # the g2o vertices are odometry, never ground truth
        source = f"{bm.DATA / rel} via rotgraph.read_view_graph(duplicates='keep')"
    full = g.n_nodes
    if g.components().max() > 0:
        g, _, _ = g.largest_component()
        source += f" (largest component: {g.n_nodes} of {full})"
    log(f"{name}: {g.n_nodes} cameras, {g.n_edges} edges")
    run = bench_one(g, has_gt, args, None if has_gt else "solutions")
    run.update(E=g.n_edges, seed=None)
    cls = {"class": name, "description": source, "n": g.n_nodes, "real": True, "has_gt": has_gt, "seeds": [run]}
    summarise(cls, has_gt=has_gt)
    return cls


def _mean(xs):
    xs = [x for x in xs if x is not None and math.isfinite(x)]
    return statistics.fmean(xs) if xs else None


def summarise(cls: dict, has_gt: bool) -> None:
    """Per contender: means over the seeds; the ratios of the default."""
    names = []
    for run in cls["seeds"]:
        names += [m for m in run["methods"] if m not in names]
    agg = {}
    for m in names:
        runs = [run["methods"].get(m, {"error": "not run"}) for run in cls["seeds"]]
        ok = [r for r in runs if "error" not in r]
        errors = sorted({r["error"].splitlines()[0][:80] for r in runs if "error" in r})
        a = {"n_ok": len(ok), "n_runs": len(runs), "errors": errors}
        for key in ("median_err_deg", "mean_err_deg", "median_edge_residual_deg", "ssr_over_l2opt", "agree_l2opt_deg"):
            a[key] = _mean([r.get(key) for r in ok]) if len(ok) == len(runs) else None
        a["seconds"] = statistics.median([r["seconds"] for r in ok]) if ok else None
        a["min_solved"] = min((r["n_solved"] for r in ok), default=None)
        agg[m] = a
    cls["summary"] = agg
    if has_gt:
        oracles = [run.get("oracle", {}) for run in cls["seeds"]]
        if all("median_err_deg" in o for o in oracles):
            cls["oracle"] = {"median_err_deg": _mean([o["median_err_deg"] for o in oracles]),
                             "mean_err_deg": _mean([o["mean_err_deg"] for o in oracles])}
    key = "median_err_deg" if has_gt else "ssr_over_l2opt"
    d = agg.get(DEFAULT, {}).get(key)
    peers = {p: agg[p][key] for p in PEERS if p in agg and agg[p].get(key) is not None}
    if d is not None and peers:
        best = min(peers, key=peers.get)
        cls["best_peer"], cls["ratio_basis"] = best, key
        cls["default_over_best_peer"] = d / peers[best] if peers[best] > 0 else math.inf
        per_seed = []
        for run in cls["seeds"]:
            vals = [run["methods"][p][key] for p in PEERS if key in run["methods"].get(p, {})]
            if key in run["methods"].get(DEFAULT, {}) and vals and min(vals) > 0:
                per_seed.append(run["methods"][DEFAULT][key] / min(vals))
        cls["default_over_best_peer_worst_seed"] = max(per_seed) if per_seed else None
    if d is not None and cls.get("oracle"):
        cls["default_over_oracle"] = d / cls["oracle"]["median_err_deg"]


# --------------------------------------------------------------------------- output


def fmt(x, digits=3):
    return bm.fmt(x, digits)


def render(classes: list[dict], header: dict, checks: list[dict] | None = None) -> str:
    L = ["# Problem classes: rotgraph's default vs GLOMAP / Theia / GTSAM / the inlier-L2 oracle\n"]
    L += [f"- {k}: {v}" for k, v in header.items()]
    if checks:
        L.append("- convention check (noise-free ER, n = 100; also the warm-up), max error °: " + ", ".join(
            f"{c['solver']} {fmt(c['max_err_deg'])}" if "max_err_deg" in c
            else f"{c['solver']} failed ({c['error'][:60]})" for c in checks))
    L.append("\n## Summary\n")
    L.append("Synthetic classes: mean over the seeds of the median error (deg, gauge aligned). "
             "`default / best peer`: rotgraph default over the best of GLOMAP, Theia, GTSAM LM-Huber, Shonan "
             "(worst seed in brackets); `× oracle`: over L2 on the true inliers from the truth; "
             "`SSR / L2 opt`: sum of squared residuals over the L2 optimum (clean pose graphs and g2o sets). "
             "Sets without ground truth are compared by `SSR / L2 opt`.\n")
    rows = []
    for c in classes:
        if "skipped" in c:
            rows.append([c["class"], "", "", "", "", "", "", "", "", f"skipped: {c['skipped']}"])
            continue
        s = c["summary"]
        d = s.get(DEFAULT, {})
        bp = c.get("best_peer")
        gt = not c.get("real") or c.get("has_gt")
        E = statistics.median([r["E"] for r in c["seeds"]])
        ratio = fmt(c.get("default_over_best_peer"))
        if c.get("default_over_best_peer_worst_seed") is not None and len(c["seeds"]) > 1:
            ratio += f" ({fmt(c['default_over_best_peer_worst_seed'])})"
        rows.append([
            c["class"], f"{c['n']:,} / {int(E):,}",
            fmt(d.get("median_err_deg")) if gt else "no GT",
            (f"{fmt(s[bp]['median_err_deg'])} {bp}" if gt else f"{bp}") if bp else "–",
            ratio, fmt(c.get("default_over_oracle")),
            fmt(d.get("ssr_over_l2opt")) + (f" (best peer {fmt(s[bp]['ssr_over_l2opt'])})"
                                            if bp and s[bp].get("ssr_over_l2opt") is not None else "")
            if d.get("ssr_over_l2opt") is not None else "",
            fmt(d.get("seconds")), fmt(s.get(GLOMAP, {}).get("seconds")),
            c["description"],
        ])
    L.append(table(["class", "n / E", "default median °", "best peer median °", "default / best peer",
                    "default × oracle", "default SSR / L2 opt", "default s", "GLOMAP s", "problem"], rows))
    L.append("\n## Every contender\n")
    L.append("Means over the seeds; `s` = median time over the seeds (GTSAM and Shonan: inside their subprocess); "
             "`solved` = fewest cameras solved in a seed; `× oracle` = median error over the oracle's.\n")
    rows = []
    for c in classes:
        if "skipped" in c:
            continue
        gt = not c.get("real") or c.get("has_gt")
        orc = c.get("oracle", {}).get("median_err_deg")
        for m, a in c["summary"].items():
            note = "; ".join(a["errors"])
            if a["n_ok"] < a["n_runs"]:
                note = f"{a['n_runs'] - a['n_ok']}/{a['n_runs']} failed: " + note
            if a["n_ok"] == 0:
                rows.append([c["class"], m, "–", "–", "–", "–", "–", "–", "–", f"**{note}**"])
                continue
            rows.append([
                c["class"], m,
                fmt(a["median_err_deg"]) if gt else "no GT", fmt(a["mean_err_deg"]) if gt else "no GT",
                fmt(a["median_err_deg"] / orc) if gt and orc and a["median_err_deg"] is not None else "",
                fmt(a["median_edge_residual_deg"]),
                fmt(a["ssr_over_l2opt"]) if a["ssr_over_l2opt"] is not None else "",
                fmt(a["seconds"]), f"{a['min_solved']}/{c['n']}", note,
            ])
        if orc is not None:
            rows.append([c["class"], ORACLE, fmt(orc), fmt(c["oracle"]["mean_err_deg"]), "1", "", "", "", "",
                         "L2 on the true inliers, from the truth"])
    L.append(table(["class", "contender", "median °", "mean °", "× oracle", "median resid °", "SSR / L2 opt",
                    "s", "solved", "notes"], rows))
    return "\n".join(L)


def header_info(args) -> dict:
    import scipy

    import rotgraph

    def version(mod):
        try:
            import importlib.metadata

            return importlib.metadata.version(mod)
        except Exception:  # noqa: BLE001
            return "missing"

    return {
        "date": time.strftime("%Y-%m-%d %H:%M:%S"),
        "command": "python benchmarks/bench_classes.py " + " ".join(sys.argv[1:]),
        "rotgraph": f"git {git_commit()} (the benchmark's checkout), imported from {Path(rotgraph.__file__).parent}, "
                    f"default {rotgraph.SolveOptions().method} / init {rotgraph.SolveOptions().init}",
        "python / numpy / scipy": f"{platform.python_version()} / {np.__version__} / {scipy.__version__}",
        "pycolmap / pytheia / gtsam": f"{version('pycolmap')} / {version('pytheia')} / {version('gtsam')}",
        "cpu": f"{cpu_model()}, os.cpu_count() = {os.cpu_count()}, usable = {usable_cpus()}",
        "load average at start": load_average(" "),
        "seeds": f"{args.seeds} per class (0..{args.seeds - 1}), {'quick' if args.quick else 'full'} sizes",
        "timeouts": f"GTSAM LM-Huber {args.gtsam_timeout:g} s, Shonan "
                    + (f"{args.shonan_timeout:g} s" if args.shonan_timeout else "max(20 s, 1 ms per edge)")
                    + " (subprocesses)",
        "GTSAM LM-Huber": f"Huber k = {args.huber_deg:g} deg, unit noise, chordal start by {args.gtsam_init}, "
                          f"LM default parameters",
        "thread environment": ", ".join(f"{k}={os.environ.get(k, '(unset)')}" for k in
                                        ("OMP_WAIT_POLICY", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="classes: " + "; ".join(f"{k}: {v[0]}" for k, v in CLASSES.items()))
    ap.add_argument("--quick", action="store_true", help="one seed, smaller problems, real sets ellis and garage")
    ap.add_argument("--classes", help=f"comma-separated subset of {','.join(CLASSES)} (default: all)")
    ap.add_argument("--real", help=f"comma-separated subset of {','.join(REAL)}, or 'none' "
                                   f"(default: all; --quick: {','.join(QUICK_REAL)})")
    ap.add_argument("--seeds", type=int, help="seeds per class (default 3; --quick 1)")
    ap.add_argument("--out", help="write every number (per seed) to this JSON file")
    ap.add_argument("--shonan-timeout", type=float, default=None,
                    help="seconds (default: 20, or 1 ms per edge on problems over 20,000 edges)")
    ap.add_argument("--gtsam-timeout", type=float, default=120.0, help="GTSAM LM-Huber, seconds (default 120)")
    ap.add_argument("--huber-deg", type=float, default=5.0, help="GTSAM LM-Huber's Huber threshold (default 5 deg)")
    ap.add_argument("--gtsam-init", choices=("rotgraph", "gtsam"), default="rotgraph",
                    help="GTSAM LM-Huber's chordal start: rotgraph's chordal method (default, fast) or GTSAM's "
                         "InitializePose3 (slow on dense graphs)")
    ap.add_argument("--no-shonan", action="store_true")
    ap.add_argument("--no-gtsam", action="store_true", help="skip GTSAM LM-Huber")
    ap.add_argument("--threads", type=int, help="cap OpenMP / BLAS threads (default: library defaults)")
    args = ap.parse_args(argv)
    args.seeds = args.seeds or (1 if args.quick else 3)
    default = [k for k, v in CLASSES.items() if v[3] or not args.quick]
    names = [s.strip() for s in (args.classes or ",".join(default)).split(",") if s.strip()]
    bad = [s for s in names if s not in CLASSES]
    if bad:
        ap.error(f"unknown class(es) {bad}; choose from {list(CLASSES)}")
    real = QUICK_REAL if args.quick and args.real is None else (
        [] if args.real == "none" else [s.strip() for s in (args.real or ",".join(REAL)).split(",") if s.strip()])
    bad = [s for s in real if s not in REAL]
    if bad:
        ap.error(f"unknown real set(s) {bad}; choose from {list(REAL)}")
    bm._quiet_pycolmap()
    header = header_info(args)
    t0 = time.perf_counter()
    log("convention check and warm-up (noise-free problem)")
    checks = convention_check(args)
    # SIGTERM exits through the interpreter, so that the subprocesses (daemons) are ended
    # too; set after the check has loaded pycolmap and pytheia, whose glog installs its own.
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    classes = []
    for kind, run in [(n, bench_class) for n in names] + [(n, bench_real) for n in real]:
        try:
            classes.append(run(kind, args))
        except Exception as e:  # noqa: BLE001 - one broken class must not lose the run
            log(f"{kind} failed: {traceback.format_exc()}")
            classes.append({"class": kind, "skipped": f"failed: {type(e).__name__}: {str(e)[:150]}"})
    header["total wall time"] = f"{time.perf_counter() - t0:.0f} s"
    header["load average at end"] = load_average(" ")
    print(render(classes, header, checks))
    if args.out:
        Path(args.out).write_text(json.dumps(json_clean({"header": header, "checks": checks, "classes": classes,
                                                     "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}),
                                             indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
