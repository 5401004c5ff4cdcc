#!/usr/bin/env python
"""Benchmark single rotation averaging (``rotgraph.mean``) against scipy's ``Rotation.mean``.

Run from the repository root::

    python benchmarks/bench_single.py            # full run (~1-3 min on 2 cores)
    python benchmarks/bench_single.py --quick    # smoke run, a few seconds

and read ``benchmarks/README.md`` for what the columns mean. The output is markdown.

Data for each size k (seeded): a Haar-random ground-truth rotation, every sample perturbed
by isotropic tangent-space noise ``N(0, (5 deg)^2 I_3)`` (``rotgraph.so3.perturb``), 20 % of
the samples (random positions) replaced by Haar-uniform outliers, random positive weights
``U(0.5, 2)``. Quaternions are given with random signs (``q`` and ``-q`` mixed).

Timing: ``time.perf_counter``; every contender is called once as a warm-up, then all the
contenders of a table are called in turn once per repeat (interleaved, the order rotated
every repeat) so that machine noise hits all of them alike; the statistic over repeats
(median by default, ``--stat min`` for best-of) is reported. Inputs are prepared outside
the timed region; the garbage collector is off while timing (as in ``timeit``).
"""

from __future__ import annotations

import argparse
import gc
import os
import platform
import statistics
import sys
import time

import numpy as np
import scipy
from scipy.spatial.transform import Rotation

import rotgraph
from rotgraph import so3

from _common import cpu_model, fmt_time, git_commit, load_average, table, usable_cpus  # noqa: E402

NOISE_DEG = 5.0
OUTLIER_FRACTION = 0.2
TARGET_RATIO = 1.5  # closed-form L2 means: rotgraph within 1.5x of scipy
TARGET_ITERATIVE_S = 1.0  # iterative means at k = 10^6: under 1 s
TARGET_ITERATIVE_K = 1_000_000

ITERATIVE = [
    ("geodesic", "l1"),
    ("geodesic", "l2"),
    ("chordal", "l1"),
    ("quaternion", "l1"),
    ("geodesic", "robust"),
]

DEFAULT_SIZES = "10,100,1000,10000,100000,1000000"
QUICK_SIZES = "10,1000,100000"


# --------------------------------------------------------------------------- data


def make_data(k: int, seed: int) -> dict:
    """Synthetic samples of one rotation: noise, outliers, weights (see module docstring)."""
    rng = np.random.default_rng([seed, k])
    truth = so3.random_rotations(rng=rng)
    R = so3.perturb(np.broadcast_to(truth, (k, 3, 3)), np.deg2rad(NOISE_DEG), rng=rng)
    n_out = int(round(OUTLIER_FRACTION * k))
    if n_out:
        idx = rng.choice(k, n_out, replace=False)
        R[idx] = so3.random_rotations(n_out, rng=rng)
    R = np.ascontiguousarray(R)
    q_wxyz = so3.quaternions_from_matrices(R)
    q_wxyz *= rng.choice([-1.0, 1.0], size=(k, 1))  # both signs, as real data have
    q_wxyz = np.ascontiguousarray(q_wxyz)
    q_xyzw = np.ascontiguousarray(np.roll(q_wxyz, -1, axis=1))  # scipy is scalar-last
    w = rng.uniform(0.5, 2.0, size=k)
    return {"truth": truth, "R": R, "q_wxyz": q_wxyz, "q_xyzw": q_xyzw, "w": w}


# --------------------------------------------------------------------------- helpers


def angle_deg(qa_wxyz: np.ndarray, qb_wxyz: np.ndarray) -> float:
    """Geodesic angle in degrees between two rotations given as quaternions (accurate near 0)."""
    rel = so3.quaternion_multiply(so3.quaternion_conjugate(qa_wxyz), qb_wxyz)
    return float(np.degrees(2.0 * np.arctan2(np.linalg.norm(rel[1:]), abs(rel[0]))))


def scipy_wxyz(r: Rotation) -> np.ndarray:
    return np.roll(np.asarray(r.as_quat(), dtype=np.float64).reshape(4), 1)


def interleaved_timing(funcs: dict, repeats: int) -> tuple[dict, dict]:
    """Warm up each callable once, then time them round-robin ``repeats`` times.

    Returns ``(times, warm_results)``: ``times[name]`` the list of per-call seconds and
    ``warm_results[name]`` the warm-up call's return value.
    """
    names = list(funcs)
    warm = {name: funcs[name]() for name in names}
    times = {name: [] for name in names}
    gc.collect()
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        for r in range(repeats):
            shift = r % len(names)  # rotate the order so no contender always goes first
            for name in names[shift:] + names[:shift]:
                f = funcs[name]
                t0 = time.perf_counter()
                f()
                times[name].append(time.perf_counter() - t0)
    finally:
        if was_enabled:
            gc.enable()
    return times, warm


def fmt_ratio(x: float) -> str:
    return f"{x:.2f}"


def mark(ok: bool) -> str:
    return "yes" if ok else "**NO**"


def default_repeats(k: int, which: str) -> int:
    """Repeats per size: many for cheap calls, few for k = 10^6 (keeps the run short)."""
    if which == "closed":
        return 201 if k <= 1000 else 51 if k <= 10_000 else 15 if k <= 100_000 else 7
    return 21 if k <= 1000 else 9 if k <= 10_000 else 5


# --------------------------------------------------------------------------- environment


def environment() -> str:
    commit, cpu, usable = git_commit(), cpu_model(), usable_cpus()
    blas = "?"
    try:
        cfg = np.show_config(mode="dicts")
        b = cfg["Build Dependencies"]["blas"]
        blas = f"{b.get('name', '?')} {b.get('version', '')}".strip()
    except Exception:  # noqa: BLE001
        pass
    load = load_average()
    threads = {v: os.environ[v] for v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
               if v in os.environ}
    return "\n".join(
        [
            f"- python {platform.python_version()} ({platform.python_implementation()}), "
            f"{platform.system()} {platform.machine()}",
            f"- numpy {np.__version__} (BLAS: {blas}), scipy {scipy.__version__}, "
            f"rotgraph {rotgraph.__version__} (git {commit})",
            f"- CPU: {cpu}; os.cpu_count() = {os.cpu_count()}, usable by this process = {usable}"
            + (f"; {threads}" if threads else ""),
            f"- date: {time.strftime('%Y-%m-%d %H:%M:%S %Z')}; load average at start {load}"
            " (other processes share the CPUs: absolute times move, interleaved ratios much less)",
        ]
    )


# --------------------------------------------------------------------------- benchmarks


def bench_closed_form(k: int, data: dict, repeats: int, stat) -> tuple[list[str], list[str], dict]:
    """Table 1 rows for size k: (quaternion-input row, matrix-input row, ratios)."""
    R, q, qs, w = data["R"], data["q_wxyz"], data["q_xyzw"], data["w"]
    pre_built = Rotation.from_quat(qs)  # for the scipy mean-only column
    funcs = {
        "rg_q_chordal": lambda: rotgraph.mean(q, metric="chordal", norm="l2", weights=w),
        "rg_q_quat": lambda: rotgraph.mean(q, metric="quaternion", norm="l2", weights=w),
        "sp_q": lambda: Rotation.from_quat(qs).mean(w),
        "sp_mean_only": lambda: pre_built.mean(w),
        "rg_R_chordal": lambda: rotgraph.mean(R, metric="chordal", norm="l2", weights=w),
        "sp_R": lambda: Rotation.from_matrix(R).mean(w),
    }
    times, warm = interleaved_timing(funcs, repeats)
    t = {name: stat(v) for name, v in times.items()}

    sp_q = scipy_wxyz(warm["sp_q"])
    sp_R = scipy_wxyz(warm["sp_R"])
    agree_q = angle_deg(warm["rg_q_chordal"].quaternion, sp_q)
    agree_R = angle_deg(warm["rg_R_chordal"].quaternion, sp_R)
    quat_vs_chordal = angle_deg(warm["rg_q_quat"].quaternion, warm["rg_q_chordal"].quaternion)

    r_chordal = t["rg_q_chordal"] / t["sp_q"]
    r_quat = t["rg_q_quat"] / t["sp_q"]
    r_R = t["rg_R_chordal"] / t["sp_R"]
    row_q = [
        f"{k:,}",
        str(repeats),
        fmt_time(t["sp_q"]),
        fmt_time(t["sp_mean_only"]),
        fmt_time(t["rg_q_chordal"]),
        fmt_ratio(r_chordal),
        fmt_ratio(t["rg_q_chordal"] / t["sp_mean_only"]),
        fmt_time(t["rg_q_quat"]),
        fmt_ratio(r_quat),
        f"{agree_q:.1e}",
        f"{quat_vs_chordal:.3f}",
        f"{warm['rg_q_quat'].iterations}",
        mark(r_chordal <= TARGET_RATIO and r_quat <= TARGET_RATIO),
    ]
    row_R = [
        f"{k:,}",
        str(repeats),
        fmt_time(t["sp_R"]),
        fmt_time(t["rg_R_chordal"]),
        fmt_ratio(r_R),
        f"{agree_R:.1e}",
        mark(r_R <= TARGET_RATIO),
    ]
    return row_q, row_R, {"chordal L2 (quaternion input)": r_chordal, "quaternion L2 (quaternion input)": r_quat,
                          "chordal L2 (matrix input)": r_R}


def bench_iterative(k: int, data: dict, repeats: int, stat) -> tuple[list[list[str]], dict]:
    """Table 2 rows for size k (one per iterative mean, matrix input) and their times."""
    R, w, truth = data["R"], data["w"], data["truth"]
    truth_q = so3.quaternions_from_matrices(truth)

    def call(metric, norm):
        return lambda: rotgraph.mean(R, metric=metric, norm=norm, weights=w)

    funcs = {f"{m} {n}": call(m, n) for m, n in ITERATIVE}
    times, warm = interleaved_timing(funcs, repeats)
    rows, seconds = [], {}
    for name in funcs:
        t = seconds[name] = stat(times[name])
        res = warm[name]
        if k == TARGET_ITERATIVE_K:
            flag = mark(t < TARGET_ITERATIVE_S)
        else:
            flag = "–"
        note = "; ".join("non-unique-L2 warning" if "pi/2" in s else s for s in res.warnings)
        rows.append(
            [
                f"{k:,}",
                name,
                str(repeats),
                fmt_time(t),
                str(res.iterations),
                "yes" if res.converged else "**no**",
                f"{angle_deg(res.quaternion, truth_q):.3f}",
                flag,
                note,
            ]
        )
    return rows, seconds


# --------------------------------------------------------------------------- main


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--sizes", default=None,
                   help=f"comma-separated sample counts k (default {DEFAULT_SIZES}; "
                        f"with --quick {QUICK_SIZES})")
    p.add_argument("--repeats", type=int, default=None,
                   help="timed repeats per contender and size, for both tables "
                        "(default: by size, from 201 / 21 at k<=1000 down to 7 / 5 at k=10^6)")
    p.add_argument("--quick", action="store_true",
                   help="smoke run: fewer sizes and about a fifth of the repeats")
    p.add_argument("--stat", choices=("median", "min"), default="median",
                   help="statistic over the repeats: median (default) or min (best-of)")
    p.add_argument("--seed", type=int, default=0, help="data seed (default 0)")
    p.add_argument("--skip-iterative", action="store_true", help="only the closed-form table")
    args = p.parse_args(argv)
    sizes_text = args.sizes or (QUICK_SIZES if args.quick else DEFAULT_SIZES)
    try:
        args.sizes = [int(float(s)) for s in sizes_text.split(",") if s.strip()]
    except ValueError:
        p.error(f"--sizes: expected comma-separated integers, got {sizes_text!r}")
    if not args.sizes or min(args.sizes) < 1:
        p.error("--sizes: need at least one size >= 1")
    if args.repeats is not None and args.repeats < 1:
        p.error("--repeats must be >= 1")
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    stat = statistics.median if args.stat == "median" else min
    stat_name = "median" if args.stat == "median" else "best (min)"

    def reps(k, which):
        if args.repeats is not None:
            return args.repeats
        n = default_repeats(k, which)
        return max(3, n // 5) if args.quick else n

    start = time.perf_counter()
    out = print
    out("# rotgraph single rotation averaging vs scipy `Rotation.mean`\n")
    out(environment())
    out(
        f"- data: Haar-random truth, isotropic noise sigma = {NOISE_DEG:g} deg per axis, "
        f"{OUTLIER_FRACTION:.0%} uniform outliers, weights U(0.5, 2), quaternion signs random, "
        f"seed {args.seed}"
    )
    out(
        f"- times: {stat_name} of the repeats (`reps`), `time.perf_counter`, one warm-up call each, "
        "contenders interleaved per repeat; ratio = rotgraph / scipy (< 1: rotgraph faster)\n"
    )
    sys.stdout.flush()

    rows_q, rows_R, rows_it = [], [], []
    ratios: dict[str, list[tuple[float, int]]] = {}
    big_k: dict[str, float] = {}
    for k in args.sizes:
        data = make_data(k, args.seed)
        rq, rR, rr = bench_closed_form(k, data, reps(k, "closed"), stat)
        for name, x in rr.items():
            ratios.setdefault(name, []).append((x, k))
        rows_q.append(rq)
        rows_R.append(rR)
        if not args.skip_iterative:
            rows, seconds = bench_iterative(k, data, reps(k, "iterative"), stat)
            rows_it += rows
            if k == TARGET_ITERATIVE_K:
                big_k = seconds
        del data
        print(f"[bench_single] k={k:,} done at {time.perf_counter() - start:.1f} s", file=sys.stderr, flush=True)

    out("## Table 1a: closed-form L2 means, quaternion input\n")
    out("rotgraph `mean(q_wxyz, metric, \"l2\", w)` vs scipy `Rotation.from_quat(q_xyzw).mean(w)` "
        "(from_quat timed: both sides validate and normalise their input).\n")
    out(table(
        ["k", "reps", "scipy from_quat+mean", "scipy mean only", "rg chordal L2", "ratio",
         "ratio vs mean only", "rg quaternion L2", "ratio", "agree (deg)", "quatL2-chordal (deg)",
         "quatL2 iters", f"both <= {TARGET_RATIO}x"],
        rows_q,
    ))
    out("\n## Table 1b: closed-form chordal L2 mean, matrix input\n")
    out("rotgraph `mean(R, \"chordal\", \"l2\", w)` vs scipy `Rotation.from_matrix(R).mean(w)`.\n")
    out(table(
        ["k", "reps", "scipy from_matrix+mean", "rg chordal L2", "ratio", "agree (deg)",
         f"<= {TARGET_RATIO}x"],
        rows_R,
    ))
    if rows_it:
        out("\n## Table 2: iterative means, matrix input\n")
        out(f"rotgraph `mean(R, metric, norm, w)`, default `tol`/`max_iterations` (robust: Cauchy loss, "
            f"automatic scale). `< 1 s` is judged only at k = {TARGET_ITERATIVE_K:,}.\n")
        out(table(
            ["k", "mean", "reps", "time", "iterations", "converged", "error to truth (deg)",
             "< 1 s", "warnings"],
            rows_it,
        ))
    out("\n## Targets\n")
    for name, xs in ratios.items():
        worst, at = max(xs)
        over = [f"{kk:,}" for x, kk in xs if x > TARGET_RATIO]
        verdict = "met" if not over else f"**not met** at k = {', '.join(over)}"
        out(f"- {name} within {TARGET_RATIO}x of scipy at every k: {verdict} (worst ratio {worst:.2f} at k = {at:,})")
    if big_k:
        slow = [n for n, t in big_k.items() if t >= TARGET_ITERATIVE_S]
        verdict = "met" if not slow else f"**not met** by {', '.join(slow)}"
        out(f"- iterative means under {TARGET_ITERATIVE_S:g} s at k = {TARGET_ITERATIVE_K:,}: {verdict} "
            f"(slowest {max(big_k.values()):.3f} s)")
    elif rows_it:
        out(f"- iterative means under {TARGET_ITERATIVE_S:g} s at k = {TARGET_ITERATIVE_K:,}: not run (k not in --sizes)")
    out(f"\nTotal wall time: {time.perf_counter() - start:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
