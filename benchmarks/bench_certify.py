#!/usr/bin/env python
"""Benchmark the global-optimality certificate (``rotgraph.estimators.certify``) against
GTSAM's ``ShonanAveraging3.checkOptimality``, and the rank-lifted escape against Shonan.

Run from the repository root::

    python benchmarks/bench_certify.py            # full sweep (~15-30 min on 2 cores)
    python benchmarks/bench_certify.py --quick    # a subset, a few minutes

The output is markdown (and ``--out FILE.json``: every number).

Problems (``rotgraph.synth.random_problem``, Erdos-Renyi graphs, seeded): sigma {1, 5, 15,
30, 60} deg x degree {4, 10, 40} x n {50, 500, 2000}, without outliers and with 10 %
uniform outliers; the real pose graphs parking-garage.g2o and cubicle.g2o (``duplicates=
"keep"``; unit weights: the chordal certificate has no place for their information
matrices) when present under ``$ROTGRAPH_DATASETS`` (default ``../shared/datasets``).

Then sparse graphs where the local solution is not the global minimum (``HARD``: synthetic
trajectories and pose graphs, 10-20 deg; the staircase and Shonan run whatever n).

Candidate, the same for both certificates:

* without outliers: rotgraph's ``method="l2"`` answer (geodesic, not a critical point of the
  chordal cost) taken to the nearest critical point of the chordal cost by
  ``refine_chordal`` (``solve s`` = both);
* with outliers: rotgraph's default (adaptive, robust) solve, its inlier edges, the chordal
  cost on them only (``refine_chordal(..., inliers=...)``): the certified final stage of a
  robust solve (issue #20 item 3); GTSAM gets the same inlier edges.

rotgraph: ``certify`` (verdict, lambda_min of ``M`` and, at a critical point, the smallest
eigenvalue beyond the gauge, duality gap, seconds). GTSAM: ``ShonanAveraging3`` built from
``BinaryMeasurementRot3(i, j, Rot3(R_ij^T), Isotropic.Sigma(3, 1))`` (its ``A`` is rotgraph's
``M`` entry by entry), ``checkOptimality`` and ``computeMinEigenValue`` on the candidate as
``SOn`` values (``wR_i = R_i^T``); ``GTSAM s`` = one ``checkOptimality`` (its Lanczos; the
build, a Python loop over the edges, is excluded). ``agree``: same verdict; ``(close)``:
rotgraph's smallest eigenvalue beyond the gauge within GTSAM's Lanczos precision (1e-3
absolute) of the threshold -1e-4, where the two can differ without either being wrong.

Where the candidate is not certified (and n <= ``--staircase-max-n``): ``certified_chordal``
(the Riemannian staircase to rank 10, rounding) and GTSAM's ``ShonanAveraging3.run(random,
3, 10)`` in a subprocess (``--shonan-timeout``); both costs are the chordal cost of the
returned rotations on the same edges. Shonan runs GTSAM's ``run`` loop step by step
(``tryOptimizingAt``, ``computeMinEigenVector``, ``initializeWithDescent``) so that an
uncertified rank-10 answer is still rounded and scored (``run`` throws), with its
Levenberg-Marquardt tightened to 1e-14 (``--shonan-default`` for GTSAM's defaults, which
stop ~1e-5 relative above the minimum).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time
from pathlib import Path

from _common import (
    ROOT,
    cpu_model,
    early_thread_settings,
    git_commit,
    load_average,
    table,
    usable_cpus,
)

if __name__ == "__main__":
    early_thread_settings()

import numpy as np

import rotgraph
from rotgraph import average_rotations
from rotgraph.estimators.certify import certify, chordal_cost
from rotgraph.estimators.staircase import certified_chordal, refine_chordal
from rotgraph.synth import random_problem

DATA = Path(os.environ.get("ROTGRAPH_DATASETS", ROOT.parent / "shared" / "datasets"))
REAL = {"garage": ("parking_garage/parking-garage.g2o", {}), "cubicle": ("cubicle/cubicle.g2o", {"duplicates": "keep"})}
SIGMAS, DEGREES, SIZES = (1, 5, 15, 30, 60), (4, 10, 40), (50, 500, 2000)
QUICK = {"sigmas": (5, 30, 60), "degrees": (4, 10), "sizes": (50, 500)}
# Sparse graphs where the local solution (from rotgraph's L2 answer) is not the global
# minimum: (graph, n, degree, sigma_deg, seed); the staircase runs whatever n.
HARD = [("traj", 100, 4, 20, 0), ("traj", 100, 4, 20, 1), ("posegraph", 300, 4, 10, 1), ("posegraph", 100, 4, 20, 2),
        ("traj", 2000, 4, 10, 0), ("posegraph", 2000, 4, 10, 0)]
QUICK_HARD = HARD[:3]
CLOSE = 2e-3  # GTSAM's Lanczos precision (1e-3 absolute), twice


class _Sub:
    """The arrays bench_multiple's Shonan runner reads, for a relabelled edge subset."""

    def __init__(self, n, edges, rel):
        self.n_nodes, self.n_edges = n, len(edges)
        self.edges, self.cam2_from_cam1, self.weights = edges, rel, np.ones(len(edges))


def relabel(R, edges, rel, mask):
    """The edges ``mask`` and the cameras they touch (solved), nodes renumbered 0..m-1."""
    ok = mask & np.isfinite(R).all(axis=(1, 2))[edges].all(axis=1)
    used = np.zeros(len(R), dtype=bool)
    used[edges[ok].ravel()] = True
    index = np.cumsum(used) - 1
    return R[used], index[edges[ok]], rel[ok], used


def gtsam_check(R, edges, rel):
    """GTSAM's verdict, lambda and the check's seconds on rotations R (all nodes used)."""
    import gtsam

    ms = gtsam.BinaryMeasurementsRot3()
    unit = gtsam.noiseModel.Isotropic.Sigma(3, 1.0)
    for (i, j), Rij in zip(edges.tolist(), rel):
        ms.append(gtsam.BinaryMeasurementRot3(i, j, gtsam.Rot3(np.ascontiguousarray(Rij.T)), unit))
    sa = gtsam.ShonanAveraging3(ms)
    values = gtsam.Values()
    for k, Rk in enumerate(R):
        values.insert(k, gtsam.SOn.FromMatrix(np.ascontiguousarray(Rk.T)))
    try:
        t0 = time.perf_counter()
        ok = bool(sa.checkOptimality(values))
        seconds = time.perf_counter() - t0
        lam = float(sa.computeMinEigenValue(values))
    except RuntimeError as e:  # "SparseMinimumEigenValue failed ..."
        return {"error": str(e)}
    return {"certified": ok, "lambda": lam, "seconds": seconds}


def shonan_staircase(arrays, p_min: int = 3, p_max: int = 10, tight: bool = True):
    """GTSAM's ``ShonanAveraging3::run`` step by step (random start; ``tight``: its
    Levenberg-Marquardt run to a relative error of 1e-14 as in ``bench_multiple``'s
    convention check, else GTSAM's default parameters, which stop at ~1e-5 relative):
    ``tryOptimizingAt(p)``, ``computeMinEigenVector``, ``initializeWithDescent(p + 1)``, up
    to ``p_max``; unlike ``run`` it returns the rounded solution when ``p_max`` is reached
    uncertified instead of throwing. For ``bench_multiple.run_isolated`` (a subprocess)."""
    import gtsam

    unit = gtsam.noiseModel.Isotropic.Sigma(3, 1.0)
    ms = gtsam.BinaryMeasurementsRot3()
    for (i, j), Rij in zip(arrays.edges.tolist(), arrays.cam2_from_cam1):
        ms.append(gtsam.BinaryMeasurementRot3(i, j, gtsam.Rot3(np.ascontiguousarray(Rij.T)), unit))
    if tight:
        lm = gtsam.LevenbergMarquardtParams.CeresDefaults()
        lm.setMaxIterations(1000)
        lm.setRelativeErrorTol(1e-14)
        lm.setAbsoluteErrorTol(1e-20)
        sa = gtsam.ShonanAveraging3(ms, gtsam.ShonanAveragingParameters3(lm))
    else:
        sa = gtsam.ShonanAveraging3(ms)
    values = sa.initializeRandomlyAt(p_min)
    certified, lam = False, float("nan")
    for p in range(p_min, p_max + 1):
        Q = sa.tryOptimizingAt(p, values)
        lam, vec = sa.computeMinEigenVector(Q)
        if lam > -1e-4:  # ShonanAveragingParameters' default optimalityThreshold
            certified = True
            break
        if p < p_max:
            values = sa.initializeWithDescent(p + 1, Q, vec, lam)
    rounded = sa.roundSolution(Q)
    R = np.full((arrays.n_nodes, 3, 3), np.nan)
    for k in range(arrays.n_nodes):
        if rounded.exists(k):
            R[k] = rounded.atRot3(k).matrix().T
    return R, {"certified": certified, "p": p, "min_eigenvalue": float(lam)}


def run_problem(name, g, outliers, args, staircase_any_n: bool = False) -> dict:
    row = {"problem": name, "n": g.n_nodes, "edges": g.n_edges}
    t0 = time.perf_counter()
    if outliers:
        res = average_rotations(g)
        mask = res.inliers.copy()
    else:
        res = average_rotations(g, method="l2")
        mask = np.ones(g.n_edges, dtype=bool)
    row["solve_s"] = time.perf_counter() - t0
    t1 = time.perf_counter()
    R, it, _ = refine_chordal(res.cam_from_world, g.edges, g.cam2_from_cam1, inliers=mask)
    row["refine_s"] = time.perf_counter() - t1
    row["refine_iterations"] = it
    c = certify(R, g.edges, g.cam2_from_cam1, inliers=mask)
    row["rotgraph"] = c.to_dict()
    Rs, es, rels, _ = relabel(R, g.edges, g.cam2_from_cam1, mask)
    row["n_certified"], row["edges_certified"] = len(Rs), len(es)
    if not args.no_gtsam:
        row["gtsam"] = gtsam_check(Rs, es, rels)
        if "certified" in row["gtsam"]:
            row["agree"] = row["gtsam"]["certified"] == c.certified
            lam_c = c.lambda_complement if c.lambda_complement == c.lambda_complement else c.lambda_min
            row["close_call"] = abs(lam_c + c.tolerance) < CLOSE
    if not c.certified and (g.n_nodes <= args.staircase_max_n or staircase_any_n):
        sol = certified_chordal(R, g.edges, g.cam2_from_cam1, inliers=mask, max_rank=args.max_rank)
        row["staircase"] = {"certified": sol.certificate.certified, "local_cost": sol.history[0]["cost"],
                            "cost": sol.cost, "lower_bound": sol.lower_bound, "relative_gap": sol.relative_gap,
                            "max_rank": sol.max_rank, "relaxation_solved": sol.relaxation_solved,
                            "seconds": sol.seconds, "summary": sol.summary}
        if not args.no_shonan:
            import bench_multiple as bm

            Rsh, info = bm.run_isolated(shonan_staircase, _Sub(len(Rs), es, rels), args.shonan_timeout, p_max=args.max_rank,
                                        tight=not args.shonan_default)
            row["shonan"] = {k: info.get(k) for k in ("seconds", "status", "certified", "p", "min_eigenvalue", "error")}
            if Rsh is not None:
                # the same normalisation as certify (unit weights: median 1)
                row["shonan"]["cost"] = chordal_cost(Rsh, es, rels)
    return row


def fmt(x, spec=".3g"):
    return "" if x is None or (isinstance(x, float) and math.isnan(x)) else format(x, spec)


def verdict(d):
    if d is None:
        return ""
    if "error" in d:
        return "error"
    return "yes" if d["certified"] else "no"


def render(rows, args, meta) -> str:
    L = ["# Certificate of global optimality: rotgraph `certify` vs GTSAM `checkOptimality`\n"]
    L.append(f"`python benchmarks/bench_certify.py{' --quick' if args.quick else ''}` at {meta['commit']}, "
             f"{meta['cpu']} ({meta['cpus']} usable CPUs), load {meta['load_start']} at the start and "
             f"{meta['load_end']} at the end; numpy {np.__version__}, gtsam {meta['gtsam']}; {meta['seconds']:.0f} s.\n")
    header = ["problem", "n", "edges", "solve s", "rotgraph", "λ_min (beyond gauge)", "gap", "certify s",
              "GTSAM", "GTSAM λ", "GTSAM s", "agree"]
    body = []
    for r in rows:
        c, gt = r["rotgraph"], r.get("gtsam")
        lam = f"{fmt(c['lambda_min'])} ({fmt(c['lambda_complement'])})" if c["lambda_complement"] is not None else fmt(c["lambda_min"])
        if not c["certified"] and c["reason"].startswith("not critical"):
            lam += " not critical"
        agree = "" if "agree" not in r else ("yes" if r["agree"] else "**no**") + (" (close)" if r["close_call"] else "")
        st = r.get("staircase")
        if "agree" in r and not r["agree"] and st and st["cost"] < st["local_cost"] * (1 - 1e-9):
            agree += " (a lower cost exists: below)"
        body.append([r["problem"], str(r["n_certified"]), str(r["edges_certified"]), fmt(r["solve_s"] + r["refine_s"], ".2f"),
                     "yes" if c["certified"] else "no", lam, fmt(c["duality_gap"], ".2g"), fmt(c["seconds"], ".3f"),
                     verdict(gt), fmt(gt.get("lambda")) if gt else "", fmt(gt.get("seconds"), ".3f") if gt else "", agree])
    L.append(table(header, body))
    decided = [r for r in rows if "agree" in r and not r["close_call"]]
    close = [r for r in rows if "agree" in r and r["close_call"]]
    n_cert = sum(r["rotgraph"]["certified"] for r in rows)
    refuted = [r for r in decided if not r["agree"] and r.get("staircase")
               and r["staircase"]["cost"] < r["staircase"]["local_cost"] * (1 - 1e-9)]
    L.append(f"\nAgreement with GTSAM: {sum(r['agree'] for r in decided)} / {len(decided)} decided problems "
             f"({len(refuted)} of the others: GTSAM certified a candidate than which `certified_chordal` found a lower "
             f"cost); close calls {sum(r['agree'] for r in close)} / {len(close)}. rotgraph certified {n_cert} of "
             f"{len(rows)} candidates.")
    big = [r for r in rows if r["n"] == 2000 and r["edges"] >= 39000]
    if big:
        L.append("n = 2000, degree 40 (40k edges): certify " + ", ".join(fmt(r["rotgraph"]["seconds"], ".3f") for r in big)
                 + " s; solve + refine " + ", ".join(fmt(r["solve_s"] + r["refine_s"], ".2f") for r in big) + " s.")
    st = [r for r in rows if "staircase" in r]
    if st:
        L.append("\n## Where the candidate is not certified: the rank-lifted solve vs Shonan\n")
        header = ["problem", "local cost", "certified_chordal", "rank", "cost", "lower bound (gap)", "s",
                  "Shonan lifted (rank)", "Shonan cost", "(ours − Shonan) / Shonan", "Shonan s"]
        body = []
        for r in st:
            s, sh = r["staircase"], r.get("shonan") or {}
            rel = (s["cost"] - sh["cost"]) / sh["cost"] if sh.get("cost") else None
            shv = "" if not sh else (sh.get("status") if sh.get("status") != "ok" else
                                     ("certified" if sh.get("certified") else "not certified") + f" ({sh.get('p')})")
            ours = "**certified**" if s["certified"] else ("relaxation solved" if s["relaxation_solved"] else "not solved")
            body.append([r["problem"], fmt(s["local_cost"], ".8g"), ours, str(s["max_rank"]), fmt(s["cost"], ".8g"),
                         f"{fmt(s['lower_bound'], '.8g')} ({fmt(s['relative_gap'], '.1e')})", fmt(s["seconds"], ".2f"),
                         shv, fmt(sh.get("cost"), ".8g"), fmt(rel, ".1e"), fmt(sh.get("seconds"), ".2f")])
        L.append(table(header, body))
        L.append("\n`certified_chordal`: **certified** (the rounded rotations pass `certify`), `relaxation solved` (a "
                 "lifted solution passed: the lower bound is the semidefinite relaxation's optimum; the rotations are "
                 "not certified, within the gap shown of it), `not solved` (rank 10 reached). `Shonan lifted`: whether "
                 "GTSAM's lifted solution passed its `checkOptimality` at that rank (its `run` then rounds and stops).")
    return "\n".join(L) + "\n"


def large(args, meta) -> int:
    """``--large``: the n = 20,000 / 400k-edge problem, rotgraph's solve and certificate and
    GTSAM's check, with the process's peak memory after each."""
    import resource

    def rss():
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024

    g = random_problem(n=20_000, degree=40, sigma_deg=5, seed=args.seed)
    out = {"edges": g.n_edges, "rss_start_mb": rss()}
    t = time.perf_counter()
    res = average_rotations(g)
    out["solve_s"], out["rss_solve_mb"] = time.perf_counter() - t, rss()
    t = time.perf_counter()
    R = refine_chordal(res.cam_from_world, g.edges, g.cam2_from_cam1)[0]
    out["refine_s"] = time.perf_counter() - t
    c = certify(R, g.edges, g.cam2_from_cam1)
    out["rss_certify_mb"] = rss()
    out["certify"] = c.to_dict()
    if not args.no_gtsam:
        out["gtsam"] = gtsam_check(R, g.edges, g.cam2_from_cam1)
        out["rss_gtsam_mb"] = rss()
    print(f"n = 20,000, {g.n_edges} edges, sigma 5 deg ({meta['commit']}, load {meta['load_start']}): rotgraph default solve "
          f"{out['solve_s']:.2f} s (peak {out['rss_solve_mb']:.0f} MB), refine_chordal {out['refine_s']:.2f} s, certify "
          f"{c.seconds:.2f} s ({c.method}, {c.eigen_iterations} iterations; {c.reason.split(' (')[0]}, lambda beyond the gauge "
          f"{c.lambda_complement:.3g}; peak {out['rss_certify_mb']:.0f} MB)"
          + ("" if args.no_gtsam else f"; GTSAM checkOptimality {out['gtsam'].get('seconds', float('nan')):.2f} s "
             f"({verdict(out['gtsam'])}, peak {out['rss_gtsam_mb']:.0f} MB with its matrices)"))
    if args.out:
        Path(args.out).write_text(json.dumps({"meta": meta, "large": out}, indent=1, default=str))
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="sigma 5/30/60, degree 4/10, n 50/500, garage")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-gtsam", action="store_true")
    ap.add_argument("--no-shonan", action="store_true", help="skip GTSAM's Shonan runs (the staircase still runs)")
    ap.add_argument("--no-outliers", action="store_true", help="only the problems without outliers")
    ap.add_argument("--real", default=None, help="comma-separated subset of garage,cubicle, or none")
    ap.add_argument("--staircase-max-n", type=int, default=500, help="run certified_chordal / Shonan up to this n (default 500)")
    ap.add_argument("--max-rank", type=int, default=10)
    ap.add_argument("--shonan-timeout", type=float, default=120.0)
    ap.add_argument("--shonan-default", action="store_true", help="GTSAM's default LM parameters for Shonan")
    ap.add_argument("--out", help="write every number to this JSON file")
    ap.add_argument("--render", metavar="JSON", help="print the tables of an earlier --out file and exit")
    ap.add_argument("--large", action="store_true",
                    help="only n = 20,000 / 400k edges (sigma 5, degree 40): times and peak memory")
    args = ap.parse_args(argv)
    if args.render:
        saved = json.loads(Path(args.render).read_text())
        args.quick = saved["meta"].get("quick", False)
        print(render(saved["rows"], args, saved["meta"]))
        return 0
    sigmas, degrees, sizes = (QUICK["sigmas"], QUICK["degrees"], QUICK["sizes"]) if args.quick else (SIGMAS, DEGREES, SIZES)
    real = args.real.split(",") if args.real else (["garage"] if args.quick else list(REAL))
    real = [] if real == ["none"] else real
    if args.no_gtsam:
        args.no_shonan = True
    meta = {"commit": git_commit(), "cpu": cpu_model(), "cpus": usable_cpus(), "load_start": load_average(),
            "python": platform.python_version(), "quick": args.quick}
    try:
        from importlib.metadata import version

        import gtsam  # noqa: F401

        meta["gtsam"] = version("gtsam")
    except Exception:  # noqa: BLE001
        meta["gtsam"] = "not installed"
        args.no_gtsam = args.no_shonan = True
    if args.large:
        return large(args, meta)
    t0 = time.perf_counter()
    rows = []
    for out in ([False] if args.no_outliers else [False, True]):
        for n in sizes:
            for degree in degrees:
                for sigma in sigmas:
                    g = random_problem(n=n, degree=degree, sigma_deg=sigma, outliers=0.1 if out else 0.0, seed=args.seed)
                    name = f"σ{sigma} d{degree} n{n}" + (" 10% out" if out else "")
                    rows.append(run_problem(name, g, out, args))
                    print(f"{name}: {rows[-1]['rotgraph']['reason'][:60]} | GTSAM {verdict(rows[-1].get('gtsam'))}",
                          file=sys.stderr, flush=True)
    for graph, n, degree, sigma, seed in (QUICK_HARD if args.quick else HARD):
        g = random_problem(n=n, degree=degree, sigma_deg=sigma, graph=graph, seed=seed)
        name = f"{graph} σ{sigma} d{degree} n{n} seed {seed}"
        rows.append(run_problem(name, g, False, args, staircase_any_n=True))
        print(f"{name}: {rows[-1]['rotgraph']['reason'][:60]}", file=sys.stderr, flush=True)
    for key in real:
        path, kw = REAL[key]
        if not (DATA / path).exists():
            print(f"{key}: {DATA / path} not found, skipped", file=sys.stderr)
            continue
        g = rotgraph.read_view_graph(DATA / path, **kw)
        for out in (False, True):
            name = f"{key}" + (" (default solve, inliers)" if out else " (l2)")
            rows.append(run_problem(name, g, out, args))
            print(f"{name}: {rows[-1]['rotgraph']['reason'][:60]}", file=sys.stderr, flush=True)
    meta["seconds"] = time.perf_counter() - t0
    meta["load_end"] = load_average()
    print(render(rows, args, meta))
    if args.out:
        Path(args.out).write_text(json.dumps({"meta": meta, "rows": rows}, indent=1, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
