#!/usr/bin/env python
"""Does ``rotgraph certify`` give GTSAM's ``checkOptimality`` verdict on rotations other
solvers return (issue #31 item 2)? Run from the repository root::

    python benchmarks/bench_certify_verdict.py --half dev       # even seeds (develop on these)
    python benchmarks/bench_certify_verdict.py --half report    # odd seeds (report only)

Problems: ``random_problem(n, degree, sigma)`` without outliers, n {50, 200, 800} x
(sigma, degree) {(2, 6), (10, 10), (30, 8)}, 4 seeds of the half. Candidates on each:
GTSAM Shonan's optimum at its default parameters (``ShonanAveraging3``, random start,
ranks 3-10: ``bench_certify.shonan_staircase(tight=False)``), the ground truth, and the
chordal optimum (``refine_chordal`` from the truth) turned by 1e-4, 1e-3, 1e-2 and 3e-2
rad about random axes. Each is judged by ``rotgraph.estimators.certify.certify`` and by
GTSAM's ``checkOptimality`` (``bench_certify.gtsam_check``, unit noise: the same matrix).
Markdown on stdout; ``--out FILE.json`` every number.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from _common import early_thread_settings, git_commit, load_average, table

if __name__ == "__main__":
    early_thread_settings()

import numpy as np

from bench_certify import gtsam_check, shonan_staircase
from rotgraph import so3
from rotgraph.estimators.certify import certify
from rotgraph.estimators.staircase import refine_chordal
from rotgraph.synth import random_problem

SIZES = (50, 200, 800)
NOISE = ((2, 6), (10, 10), (30, 8))  # (sigma deg, degree)
TURNS = (1e-4, 1e-3, 1e-2, 3e-2)  # rad


class _Arrays:
    def __init__(self, g):
        self.edges, self.cam2_from_cam1, self.n_nodes = g.edges, g.cam2_from_cam1, g.n_nodes


def candidates(g, seed):
    """Shonan's optimum, the truth and turned chordal optima of graph ``g``."""
    out = {"shonan": shonan_staircase(_Arrays(g), tight=False)[0], "truth": g.gt_cam_from_world}
    R, _, _ = refine_chordal(g.gt_cam_from_world, g.edges, g.cam2_from_cam1)
    rng = np.random.default_rng(seed)
    for d in TURNS:
        axis = rng.standard_normal((g.n_nodes, 3))
        out[f"optimum turned {d:g}"] = so3.exp(d * axis / np.linalg.norm(axis, axis=1)[:, None]) @ R
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--half", choices=("dev", "report"), required=True, help="dev: seeds 0,2,4,6; report: 1,3,5,7")
    ap.add_argument("--out", default=None, help="write every number to this JSON file")
    args = ap.parse_args(argv)
    seeds = range(0 if args.half == "dev" else 1, 8, 2)
    t0, rows = time.perf_counter(), []
    for n in SIZES:
        for sigma, degree in NOISE:
            for seed in seeds:
                g = random_problem(n=n, degree=degree, sigma_deg=sigma, outliers=0.0, seed=seed)
                for kind, R in candidates(g, seed).items():
                    c = certify(R, g.edges, g.cam2_from_cam1)
                    gt = gtsam_check(R, g.edges, g.cam2_from_cam1)
                    rows.append({"n": n, "sigma_deg": sigma, "degree": degree, "seed": seed, "candidate": kind,
                                 "rotgraph": c.to_dict(), "gtsam": gt})
                print(f"[verdict] n {n} sigma {sigma} seed {seed} done", file=sys.stderr, flush=True)
    if args.out:
        with open(args.out, "w") as fh:
            json.dump(rows, fh, indent=1, default=float)
    L = [f"# rotgraph certify vs GTSAM checkOptimality, {args.half} half\n",
         f"git {git_commit()}, load {load_average()}, {time.perf_counter() - t0:.0f} s\n"]
    body = []
    for kind in dict.fromkeys(r["candidate"] for r in rows):
        rs = [r for r in rows if r["candidate"] == kind]
        ours = [r["rotgraph"]["certified"] for r in rs]
        theirs = [r["gtsam"].get("certified") for r in rs]
        rel = [r["rotgraph"]["relative_gap"] for r in rs]
        stat = [r["rotgraph"]["stationarity"] for r in rs]
        body.append([kind, str(len(rs)), str(sum(ours)), str(sum(bool(t) for t in theirs)),
                     str(sum(a == bool(b) for a, b in zip(ours, theirs))), f"{min(stat):.1e} - {max(stat):.1e}",
                     f"{min(rel):.1e} - {max(rel):.1e}"])
    L.append(table(["candidate", "n", "rotgraph certified", "GTSAM certified", "same verdict", "stationarity", "relative gap"], body))
    print("\n".join(L))
    return 0


if __name__ == "__main__":
    sys.exit(main())
