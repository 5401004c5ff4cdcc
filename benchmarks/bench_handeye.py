#!/usr/bin/env python
"""Benchmark hand-eye rotation (``rotgraph.estimators.handeye``) against OpenCV's ``cv2.calibrateHandEye``.

Run from the repository root::

    python benchmarks/bench_handeye.py            # full grid (about 5 minutes on 2 cores)
    python benchmarks/bench_handeye.py --quick    # smoke run, well under a minute

and read ``benchmarks/README.md`` for what the columns mean. The output is markdown.

Problems (all seeded). A hand-eye rig: ``X = gripper_from_camera`` (Haar rotation,
translation ``N(0, 5 cm)``), a fixed target ``base_from_target`` (Haar rotation, 0.6 m
away) and ``n`` robot poses ``base_from_gripper`` ``G_k = [exp(w_k) R0 | t_k]`` with
``w_k ~ N(0, (30 deg)^2 I_3)`` (the orientations a robot can take while the camera sees
the target) and ``t_k ~ N((0.4, 0, 0.3), 0.2 m)``. The camera poses are
``cam_from_target C_k = X^-1 G_k^-1 T``. Noise: every measured rotation (robot and camera)
is right-multiplied by ``exp(e)``, ``e ~ N(0, sigma^2 I_3)``, every translation gets
``N(0, (0.1 m * sigma_rad)^2)``. Wrong pairs: ``round(f n)`` poses (random positions) get a
camera pose that is unrelated to the robot pose (Haar rotation, random translation), as a
wrong target detection or a mismatched pair does.

Contenders, on the same problems in the same run: OpenCV (``TSAI``, ``PARK``, ``HORAUD``,
``ANDREFF``, ``DANIILIDIS``) on the absolute poses (rotations and translations), and
rotgraph on the motions formed from the same poses, with their translations, by
``motions_from_poses(..., pairs="all")`` (every pose pair ``i < j``, the motion set OpenCV
builds internally): ``solve_handeye(method="robust", robot_translations=...,
camera_translations=...)`` (default options: ``S`` and ``t_X`` estimated jointly),
the same with ``rotation_only=True`` (``S`` from the rotations alone, as before the joint
estimate) and ``method="l2"`` (rotation-only geodesic L2). rotgraph's times include
forming the motions. Error = angle between the estimated and the true
``gripper_from_camera`` in degrees; the tables give its median over seeds, and the time
per call (median). Table 6 gives the error of the translation ``t_X`` in mm.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time

import numpy as np
import scipy

import rotgraph
from rotgraph import so3
from rotgraph.estimators.handeye import motions_from_poses, pose_residuals, solve_handeye

from _common import cpu_model, fmt_time, git_commit, load_average, table  # noqa: E402

try:
    import cv2
except ImportError:  # pragma: no cover
    sys.exit("bench_handeye needs OpenCV: pip install 'opencv-python-headless<5'")

OPENCV = {
    "TSAI": cv2.CALIB_HAND_EYE_TSAI,
    "PARK": cv2.CALIB_HAND_EYE_PARK,
    "HORAUD": cv2.CALIB_HAND_EYE_HORAUD,
    "ANDREFF": cv2.CALIB_HAND_EYE_ANDREFF,
    "DANIILIDIS": cv2.CALIB_HAND_EYE_DANIILIDIS,
}
ROTATION_ONLY = ("TSAI", "PARK", "HORAUD")  # rotation estimated from the rotations alone
# rotgraph contenders: name -> solve_handeye options (all get the motions' translations).
RG_OPTIONS = {
    "robust": dict(method="robust"),  # joint (S, t_X): the default with translations
    "rot-only": dict(method="robust", rotation_only=True),
    "l2": dict(method="l2"),
    "quaternion": dict(method="quaternion"),
    "procrustes": dict(method="procrustes"),
    "l1": dict(method="l1"),
}
RG = ("robust", "rot-only", "l2")
RG_ALL = ("quaternion", "procrustes", "l2", "l1", "rot-only", "robust")

SPREAD_DEG = 30.0  # per-axis spread of the robot orientations
T_NOISE_M_PER_RAD = 0.1  # translation noise (m) per radian of rotation noise

FULL = dict(noise=[0.1, 0.5, 1.0, 2.0], wrong=[0.0, 0.2, 0.4], n=[5, 20, 50, 200], seeds=15, seeds_large=6)
QUICK = dict(noise=[0.1, 2.0], wrong=[0.0, 0.2, 0.4], n=[5, 50], seeds=4, seeds_large=4)
LARGE_N = 200  # cells with at least this many poses use ``seeds_large`` seeds (OpenCV: ~1 s per call there)

TARGET_CLEAN = 1.05  # no wrong pairs: rotgraph error <= 1.05 x the best OpenCV method
TARGET_WRONG = 0.5  # 20 % wrong pairs: rotgraph error < 0.5 x the best OpenCV method
TARGET_EXACT_DEG = 1e-9  # noise-free: recovered to 1e-9 degrees


# --------------------------------------------------------------------------- problems


def make_problem(n: int, noise_deg: float, wrong: float, seed: int, t_noise: float | None = None) -> dict:
    rng = np.random.default_rng([seed, n, int(round(noise_deg * 1000)), int(round(wrong * 1000))])
    X = np.eye(4)
    X[:3, :3] = so3.random_rotations(rng=rng)
    X[:3, 3] = rng.normal(0.0, 0.05, 3)
    T = np.eye(4)
    T[:3, :3] = so3.random_rotations(rng=rng)
    T[:3, 3] = [0.6, 0.0, 0.0]
    G = np.tile(np.eye(4), (n, 1, 1))
    G[:, :3, :3] = so3.exp(rng.normal(0.0, np.deg2rad(SPREAD_DEG), (n, 3))) @ so3.random_rotations(rng=rng)
    G[:, :3, 3] = rng.normal(0.0, 0.2, (n, 3)) + [0.4, 0.0, 0.3]
    C = np.linalg.inv(X) @ np.linalg.inv(G) @ T  # cam_from_target = X^-1 G^-1 T
    sigma = np.deg2rad(noise_deg)
    if sigma > 0:
        G[:, :3, :3] = so3.perturb(G[:, :3, :3], sigma, rng)
        C[:, :3, :3] = so3.perturb(C[:, :3, :3], sigma, rng)
        tn = T_NOISE_M_PER_RAD if t_noise is None else t_noise
        G[:, :3, 3] += rng.normal(0.0, tn * sigma, (n, 3))
        C[:, :3, 3] += rng.normal(0.0, tn * sigma, (n, 3))
    bad = np.zeros(n, dtype=bool)
    n_bad = int(round(wrong * n))
    if n_bad:
        bad[rng.choice(n, n_bad, replace=False)] = True
        C[bad, :3, :3] = so3.random_rotations(n_bad, rng=rng)
        C[bad, :3, 3] = rng.normal(0.0, 0.3, (n_bad, 3)) + [0.0, 0.0, 0.5]
    return {"X": X[:3, :3], "tX": X[:3, 3], "G": G, "C": C, "bad": bad}


FAILURES: dict[str, int] = {}  # calls that raised or returned a non-finite rotation


def run_opencv(p: dict, method: int) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's ``(R_cam2gripper, t_cam2gripper)``; NaN when the call fails."""
    G, C = p["G"], p["C"]
    try:
        R, t = cv2.calibrateHandEye(list(G[:, :3, :3]), list(G[:, :3, 3]), list(C[:, :3, :3]), list(C[:, :3, 3]), method=method)
    except cv2.error:  # e.g. "Rotation normalization issue" on corrupted data
        R, t = np.full((3, 3), np.nan), np.full(3, np.nan)
    return np.asarray(R, dtype=np.float64), np.asarray(t, dtype=np.float64).reshape(3)


class _Failed:
    """Stands for a rotgraph call that raised (degenerate or no consensus): 180° error, all flagged."""

    def __init__(self, n: int):
        self.rotation = np.full((3, 3), np.nan)
        self.translation = np.full(3, np.nan)
        self.residuals_deg = np.full(n, 180.0)
        self.inliers = np.zeros(n, dtype=bool)


def run_rotgraph(p: dict, name: str):
    """rotgraph's contender ``name`` (``RG_OPTIONS``) on the motions of every pose pair, with translations."""
    m = motions_from_poses(p["G"], p["C"], pairs="all")
    try:
        res = solve_handeye(m.robot, m.camera, robot_translations=m.robot_translations,
                            camera_translations=m.camera_translations, **RG_OPTIONS[name])
        return res, m.pairs
    except rotgraph.RotgraphError:
        return _Failed(len(m.pairs)), m.pairs


def err_deg(R: np.ndarray, X: np.ndarray, name: str = "") -> float:
    """Angle to the truth in degrees; a failed call (exception, NaN) counts as 180."""
    if not np.isfinite(R).all():
        FAILURES[name] = FAILURES.get(name, 0) + 1
        return 180.0
    return float(np.degrees(so3.angle_between(so3.project_to_so3(R), X)))


def err_mm(t, tX: np.ndarray) -> float:
    """Distance of ``t_X`` to the truth in mm (inf when missing or NaN)."""
    if t is None or not np.isfinite(t).all():
        return float("inf")
    return float(1000.0 * np.linalg.norm(np.asarray(t) - tX))


# --------------------------------------------------------------------------- output helpers


def fmt_err(x: float) -> str:
    if not np.isfinite(x):
        return "nan"
    if x == 0:
        return "0"
    if x < 1e-3:
        return f"{x:.1e}"
    return f"{x:.3f}" if x < 10 else f"{x:.1f}"


def mark(ok: bool) -> str:
    return "yes" if ok else "**NO**"


def environment() -> str:
    commit, cpu, load = git_commit(), cpu_model(), load_average()
    return "\n".join([
        f"- python {platform.python_version()}, numpy {np.__version__}, scipy {scipy.__version__}, "
        f"OpenCV {cv2.__version__}, rotgraph {rotgraph.__version__} (git {commit})",
        f"- CPU: {cpu}; os.cpu_count() = {os.cpu_count()}; load average at start {load}",
        f"- date: {time.strftime('%Y-%m-%d %H:%M:%S %Z')}",
    ])


def progress(msg: str) -> None:
    print(f"[bench_handeye] {msg}", file=sys.stderr, flush=True)


# --------------------------------------------------------------------------- runs


def noise_free_table(ns: list[int], seeds: int) -> tuple[str, bool]:
    """Largest error over seeds, every rotgraph method and OpenCV, noise-free poses."""
    rows, ok_all = [], True
    for wrong in (0.0, 0.2, 0.4):
        for n in ns:
            worst = {name: 0.0 for name in list(OPENCV) + list(RG_ALL)}
            for seed in range(seeds):
                p = make_problem(n, 0.0, wrong, seed)
                for name, m in OPENCV.items():
                    worst[name] = max(worst[name], err_deg(run_opencv(p, m)[0], p["X"], name))
                for method in RG_ALL:
                    if wrong > 0 and method not in ("robust", "rot-only"):
                        worst[method] = float("nan")
                        continue
                    worst[method] = max(worst[method], err_deg(run_rotgraph(p, method)[0].rotation, p["X"], f"rg {method}"))
            rg = [worst[m] for m in RG_ALL if np.isfinite(worst[m])]
            ok = max(rg) < TARGET_EXACT_DEG
            ok_all &= ok
            rows.append([f"{wrong:.0%}", str(n)] + [fmt_err(worst[k]) for k in OPENCV] +
                        [fmt_err(worst[m]) if np.isfinite(worst[m]) else "–" for m in RG_ALL] + [mark(ok)])
    header = ["wrong", "n"] + list(OPENCV) + [f"rg {m}" for m in RG_ALL[:-1]] + ["rg robust (joint)", "rg < 1e-9°"]
    return table(header, rows), ok_all


def main_grid(cfg: dict):
    cells = []
    times: dict[tuple[int, str], list[float]] = {}
    names = list(OPENCV) + [f"rg {m}" for m in RG]
    warmed = False
    total = len(cfg["noise"]) * len(cfg["wrong"]) * len(cfg["n"])
    t_start = time.perf_counter()
    for ci, (noise, wrong, n) in enumerate([(a, b, c) for a in cfg["noise"] for b in cfg["wrong"] for c in cfg["n"]]):
        errs = {k: [] for k in names}
        terrs = {k: [] for k in names}
        flags = {"wrong_poses": 0, "wrong_flagged": 0, "clean_poses": 0, "clean_flagged": 0,
                 "wrong_motions": 0, "wrong_motions_flagged": 0, "clean_motions": 0, "clean_motions_flagged": 0}
        for seed in range(cfg["seeds"] if n < LARGE_N else cfg["seeds_large"]):
            p = make_problem(n, noise, wrong, seed)
            calls = [(k, (lambda m=m: run_opencv(p, m))) for k, m in OPENCV.items()]
            calls += [(f"rg {m}", (lambda m=m: run_rotgraph(p, m))) for m in RG]
            if not warmed:
                for _, f in calls:
                    f()
                warmed = True
            shift = seed % len(calls)  # rotate the call order
            for k, f in calls[shift:] + calls[:shift]:
                t0 = time.perf_counter()
                out = f()
                times.setdefault((n, k), []).append(time.perf_counter() - t0)
                if k.startswith("rg"):
                    res, pairs = out
                    errs[k].append(err_deg(res.rotation, p["X"], k))
                    terrs[k].append(err_mm(res.translation, p["tX"]))
                    if k == "rg robust":
                        _, pose_ok = pose_residuals(res.residuals_deg, res.inliers, pairs, n)
                        bad = p["bad"]
                        mbad = bad[pairs[:, 0]] | bad[pairs[:, 1]]
                        flags["wrong_poses"] += int(bad.sum())
                        flags["wrong_flagged"] += int((bad & ~pose_ok).sum())
                        flags["clean_poses"] += int((~bad).sum())
                        flags["clean_flagged"] += int((~bad & ~pose_ok).sum())
                        flags["wrong_motions"] += int(mbad.sum())
                        flags["wrong_motions_flagged"] += int((mbad & ~res.inliers).sum())
                        flags["clean_motions"] += int((~mbad).sum())
                        flags["clean_motions_flagged"] += int((~mbad & ~res.inliers).sum())
                else:
                    errs[k].append(err_deg(out[0], p["X"], k))
                    terrs[k].append(err_mm(out[1], p["tX"]))
        med = {k: float(np.median(v)) for k, v in errs.items()}
        tmed = {k: float(np.median(v)) for k, v in terrs.items()}
        cells.append({"noise": noise, "wrong": wrong, "n": n, "median": med, "t_median": tmed, "flags": flags})
        progress(f"cell {ci + 1}/{total} (noise {noise} deg, wrong {wrong:.0%}, n {n}) done at {time.perf_counter() - t_start:.0f} s")
    return cells, times


def _best(med: dict, names) -> tuple[str, float]:
    name = min(names, key=lambda k: med[k] if np.isfinite(med[k]) else np.inf)
    return name, med[name]


def grid_table(cells: list[dict]) -> str:
    rows = []
    for c in cells:
        med = c["median"]
        best_name, best = _best(med, OPENCV)
        _, best_rot = _best(med, ROTATION_ONLY)
        ratio = med["rg robust"] / best if best > 0 else float("nan")
        ratio_ro = med["rg rot-only"] / best_rot if best_rot > 0 else float("nan")
        f = c["flags"]
        wrong_flag = f"{f['wrong_flagged']}/{f['wrong_poses']}" if f["wrong_poses"] else "–"
        clean_flag = f"{f['clean_flagged']}/{f['clean_poses']}"
        if c["wrong"] == 0:
            target = f"≤ {TARGET_CLEAN}: {mark(ratio <= TARGET_CLEAN)}"
        elif abs(c["wrong"] - 0.2) < 1e-9:
            target = f"< {TARGET_WRONG}, all flagged: {mark(ratio < TARGET_WRONG and f['wrong_flagged'] == f['wrong_poses'])}"
        else:
            target = "–"
        rows.append([f"{c['noise']:g}", f"{c['wrong']:.0%}", str(c["n"])] + [fmt_err(med[k]) for k in OPENCV] +
                    [f"{fmt_err(best)} ({best_name})", fmt_err(med["rg robust"]), fmt_err(med["rg rot-only"]),
                     fmt_err(med["rg l2"]), f"{ratio:.3f}", f"{ratio_ro:.3f}", wrong_flag, clean_flag, target])
    header = ["σ (°)", "wrong", "n"] + list(OPENCV) + ["best OpenCV", "rg robust", "rg rot-only", "rg l2", "robust / best",
                                                       "rot-only / best rot-only", "wrong poses flagged",
                                                       "clean poses flagged", "target"]
    return table(header, rows)


def translation_table(seeds: int) -> str:
    """sigma = 1 deg, no wrong pairs, the translation noise varied: how much the joint
    methods (ANDREFF, DANIILIDIS, rg robust) gain from the translations, and that very
    noisy translations do not make the joint estimate worse than the rotation-only one."""
    rows = []
    rg = ["rg robust", "rg rot-only"]
    for n in (20, 50):
        for tn in (0.0, T_NOISE_M_PER_RAD, 1.0, 10.0):
            errs = {k: [] for k in list(OPENCV) + rg}
            for seed in range(seeds):
                p = make_problem(n, 1.0, 0.0, 2000 + seed, t_noise=tn)
                for k, m in OPENCV.items():
                    errs[k].append(err_deg(run_opencv(p, m)[0], p["X"], k))
                for k in rg:
                    errs[k].append(err_deg(run_rotgraph(p, k[3:])[0].rotation, p["X"], k))
            med = {k: float(np.median(v)) for k, v in errs.items()}
            _, best = _best(med, OPENCV)
            rows.append([str(n), f"{tn:g}" + (" (grid)" if tn == T_NOISE_M_PER_RAD else ""), f"{1000 * tn * np.deg2rad(1.0):.3g}"]
                        + [fmt_err(med[k]) for k in list(OPENCV) + rg]
                        + [f"{med['rg robust'] / best:.3f}", f"{med['rg robust'] / med['rg rot-only']:.3f}"])
    return table(["n", "t noise (m/rad)", "t noise at 1° (mm)"] + list(OPENCV) + rg + ["robust / best", "robust / rot-only"],
                 rows)


def translation_error_table(cells: list[dict]) -> str:
    """Median error of ``t_X`` (mm) per grid cell without and with 20 % wrong pairs."""
    names = list(OPENCV) + [f"rg {m}" for m in RG]
    rows = []
    for c in cells:
        if c["wrong"] not in (0.0, 0.2):
            continue
        rows.append([f"{c['noise']:g}", f"{c['wrong']:.0%}", str(c["n"])] + [fmt_err(c["t_median"][k]) for k in names])
    return table(["σ (°)", "wrong", "n"] + names, rows)


def time_table(times: dict, ns: list[int]) -> str:
    names = list(OPENCV) + [f"rg {m}" for m in RG]
    rows = []
    for n in ns:
        rows.append([str(n), str(n * (n - 1) // 2)] + [fmt_time(statistics.median(times[(n, k)]), digits=0) for k in names])
    return table(["n poses", "motions"] + names, rows)


def rotgraph_methods_table(seeds: int) -> str:
    """rotgraph's methods on one setting (n = 50 poses, sigma = 1 deg); ``robust`` is the joint estimate."""
    rows = []
    for wrong in (0.0, 0.2):
        errs = {m: [] for m in RG_ALL}
        for seed in range(seeds):
            p = make_problem(50, 1.0, wrong, 1000 + seed)
            for m in RG_ALL:
                errs[m].append(err_deg(run_rotgraph(p, m)[0].rotation, p["X"], f"rg {m}"))
        rows.append([f"{wrong:.0%}"] + [fmt_err(float(np.median(errs[m]))) for m in RG_ALL])
    return table(["wrong"] + list(RG_ALL), rows)


def targets(cells: list[dict], exact_ok: bool) -> str:
    clean = [c for c in cells if c["wrong"] == 0]
    w20 = [c for c in cells if abs(c["wrong"] - 0.2) < 1e-9]

    def ratio(c, names=tuple(OPENCV), rg="rg robust"):
        return c["median"][rg] / _best(c["median"], names)[1]

    def summary(cs, names, limit, rg="rg robust"):
        r = [ratio(c, names, rg) for c in cs]
        ok = sum(x <= limit for x in r)
        return f"{ok}/{len(cs)} cells (worst {max(r):.3f}, geometric mean {np.exp(np.mean(np.log(r))):.3f})"

    def summary_vs_rot(cs):
        r = [c["median"]["rg robust"] / c["median"]["rg rot-only"] for c in cs]
        return (f"≤ 1 in {sum(x <= 1 for x in r)}/{len(cs)} cells (range {min(r):.3f}–{max(r):.3f}, "
                f"geometric mean {np.exp(np.mean(np.log(r))):.3f})")

    w20_flag = [c for c in w20 if c["flags"]["wrong_flagged"] == c["flags"]["wrong_poses"]]
    lines = [
        f"- noise-free, every rotgraph method (and robust with 20 %/40 % wrong pairs) within {TARGET_EXACT_DEG:g}°: {mark(exact_ok)}",
        f"- no wrong pairs, rg robust ≤ {TARGET_CLEAN} × best OpenCV: {summary(clean, tuple(OPENCV), TARGET_CLEAN)}",
        f"- no wrong pairs, rg robust ≤ {TARGET_CLEAN} × best rotation-only OpenCV method ({', '.join(ROTATION_ONLY)}): "
        f"{summary(clean, ROTATION_ONLY, TARGET_CLEAN)}",
        f"- no wrong pairs, rg rot-only (rotation_only=True) ≤ {TARGET_CLEAN} × best rotation-only OpenCV method: "
        f"{summary(clean, ROTATION_ONLY, TARGET_CLEAN, 'rg rot-only')}",
        f"- no wrong pairs, rg robust (joint) / rg rot-only: {summary_vs_rot(clean)}",
        f"- 20 % wrong pairs, rg robust < {TARGET_WRONG} × best OpenCV: {summary(w20, tuple(OPENCV), TARGET_WRONG - 1e-12)}; "
        f"every wrong pose flagged: {len(w20_flag)}/{len(w20)} cells",
    ]
    fl = {k: sum(c["flags"][k] for c in cells) for k in cells[0]["flags"]}
    lines.append(
        f"- flags over the whole grid: wrong poses flagged {fl['wrong_flagged']}/{fl['wrong_poses']}, clean poses flagged "
        f"{fl['clean_flagged']}/{fl['clean_poses']}; wrong motions flagged {fl['wrong_motions_flagged']}/{fl['wrong_motions']}, "
        f"clean motions flagged {fl['clean_motions_flagged']}/{fl['clean_motions']}"
    )
    return "\n".join(lines)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="small grid, few seeds (smoke run)")
    ap.add_argument("--seeds", type=int, default=None, help="seeds per grid cell (all sizes)")
    args = ap.parse_args(argv)
    cfg = dict(QUICK if args.quick else FULL)
    if args.seeds:
        cfg["seeds"] = cfg["seeds_large"] = args.seeds
    t0 = time.perf_counter()
    print("# Hand-eye rotation: rotgraph vs OpenCV calibrateHandEye\n")
    print(environment())
    print(f"- grid: σ {cfg['noise']} °, wrong pairs {[f'{w:.0%}' for w in cfg['wrong']]}, n {cfg['n']} pose pairs, "
          f"{cfg['seeds']} seeds per cell ({cfg['seeds_large']} for n ≥ {LARGE_N}){' (--quick)' if args.quick else ''}\n")
    progress("noise-free table")
    exact, exact_ok = noise_free_table(cfg["n"], min(cfg["seeds"], 5))
    progress("main grid")
    cells, times = main_grid(cfg)
    progress("rotgraph methods")
    methods = rotgraph_methods_table(cfg["seeds"])
    progress("translation noise")
    trans = translation_table(cfg["seeds"])

    print("## Table 1: noise-free poses, largest error over seeds (degrees)\n")
    print(exact + "\n")
    print("## Table 2: median rotation error (degrees) over seeds\n")
    print("rg robust: the default with translations (S and t_X estimated jointly); rg rot-only: the same with "
          "`rotation_only=True` (S from the rotations alone); rg l2: rotation-only geodesic L2. "
          "`wrong poses flagged`: wrong pose pairs that rg robust flags as outliers (from its motion flags by "
          "`pose_residuals`: a pose is an inlier when at least half as many of its motions are inliers as for the best "
          "pose), summed over seeds; `clean poses flagged`: false alarms.\n")
    print(grid_table(cells) + "\n")
    print("## Table 3: time per call (median over the grid)\n")
    print(time_table(times, cfg["n"]) + "\n")
    print("## Table 4: rotgraph's methods, n = 50 poses, σ = 1°, median error (degrees)\n")
    print(methods + "\n")
    print("## Table 5: the translations, σ = 1°, no wrong pairs, median error (degrees)\n")
    print("ANDREFF, DANIILIDIS and rg robust (the joint estimate) estimate rotation and translation together, so "
          "precise translations also inform their rotation; TSAI, PARK, HORAUD and rg rot-only use the rotations "
          "alone. rg robust weights its translation block by the translation noise it estimates, so very noisy "
          "translations leave it near the rotation-only estimate (`robust / rot-only` near 1).\n")
    print(trans + "\n")
    print("## Table 6: translation t_X, median error (mm) over the seeds of the grid\n")
    print("rg l2 and rg rot-only fit t_X by least squares given their rotation-only S (rot-only: over the inlier "
          "pairs, translation outliers left out); rg robust estimates S and t_X jointly.\n")
    print(translation_error_table(cells) + "\n")
    print("## Targets\n")
    print(targets(cells, exact_ok))
    if FAILURES:
        print("- failed calls (an exception or a NaN rotation; counted as a 180° error): "
              + ", ".join(f"{k} {v}" for k, v in sorted(FAILURES.items())))
    print(f"\n(total {time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
