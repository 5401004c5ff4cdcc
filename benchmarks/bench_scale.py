#!/usr/bin/env python
"""rotgraph at scale (#19): 10^6 to 10^7 edges, synth, read and the whole ``rotgraph solve``.

Run from the repository root::

    python benchmarks/bench_scale.py --quick          # n = 20 000 / 10^6 edges only (~2 min)
    python benchmarks/bench_scale.py                  # 20k/1M, 100k/5M, 200k/10M (~10 min)
    python benchmarks/bench_scale.py --max-rss-gb 8   # a shared machine: stop a stage above 8 GB
    python benchmarks/bench_scale.py --rows 200000x100 --work /data/scale --clean

Problems: ``rotgraph synth --n N --degree 100 --sigma 2 --outliers 0.1 --seed 0
--edges-format both`` (the issue's 10^7-edge problem is ``200000x100``), written once into
``--work/nN_dD`` and reused while its ``meta.json`` matches (``--fresh`` remakes them; the
synth time is then measured again). Every stage runs as its own process, one at a time, so
that its wall time and peak RSS are its own:

* ``synth``: the ``rotgraph synth`` command (both edge files, gt.txt, meta.json);
* ``read txt`` / ``read npz``: ``rotgraph.read_view_graph`` of edges.txt / edges.npz in a fresh
  interpreter (time of the call; peak RSS of the process, imports included);
* ``solve``: the whole ``rotgraph solve edges.txt -o r.csv --json`` command (wall, peak RSS
  from ``/usr/bin/time -v`` or the child's rusage; its own ``seconds_read`` and
  ``seconds_solve``; ``iterations``), then ``rotgraph eval`` against gt.txt for the median error.

``--json FILE`` writes the rows. ``--skip-solve`` measures synth and read only.

``--information K`` (issue #33): the problems carry per-edge anisotropic information
(``synth --uncertainty-spread K``: standard deviations ``2 deg * exp(u)`` along three random axes,
``u ~ U(-ln K, ln K)``; the true information matrices in the h_* columns), written as edges.npz
only (``nN_dD_uK``); each is solved twice, with the information (the default) and with
``--no-use-information`` (the scalar solve of the same file), and the table gives both and
their ratio.

Measured 2026-12-02 (AMD EPYC, 2 shared cores, load average 3.3-4.5 from other jobs;
commit 0085322 plus another engineer's uncommitted solver changes in the checkout)::

    n / edges             synth s (MB)  txt MB  npz MB  read txt s  read npz s  solve s (read + solve)  solve MB  median  it
    20,000 / 1,000,000    5.5 (775)     88      53      1.13        0.28        13.8 (1.2 + 11.8)       1727      0.325   8
    100,000 / 5,000,000   20.1 (1347)   442     267     5.49        1.00        67.0 (5.4 + 60.6)       7402      0.327   8
    200,000 / 10,000,000  38.0 (2480)   895     534     13.49       2.25        196.4 (12.5 + 182.0)    14605     0.326   8

Before #19 (issue text, same machine): synth 10^7 125 s / 7.6 GB, read 51 s (19 MB/s); at
10^6 the text read took 3.3 s (469 MB) where it takes 1.0 s (417 MB) now. The solve's
memory is the solver's (issue #19 item 2): 1.6 GB at 10^6 before the new readers too.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import cpu_model, git_commit, load_average, table, usable_cpus  # noqa: E402

ROWS = [(20_000, 100), (100_000, 100), (200_000, 100)]
SIGMA, OUTLIERS, SEED = 2.0, 0.1, 0
TIME = "/usr/bin/time"

READ_SNIPPET = """
import json, resource, sys, time
from rotgraph.pipeline.read import read_view_graph
t = time.perf_counter()
g = read_view_graph(sys.argv[1])
print(json.dumps({"seconds": time.perf_counter() - t, "n_edges": int(g.n_edges),
                  "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


GLOMAP_SNIPPET = """
import json, os, resource, sys, time
sys.path.insert(0, os.path.dirname(sys.argv[3]))
from bench_multiple import run_glomap
from rotgraph.evaluate import compare_rotations
from rotgraph.io.rotations import read_absolute_rotations
from rotgraph.pipeline.read import read_view_graph
g = read_view_graph(sys.argv[1])
R, info = run_glomap(g)
ids, _, gt = read_absolute_rotations(sys.argv[2])
order = {int(k): i for i, k in enumerate(ids.tolist())}
G = gt[[order[int(k)] for k in g.node_ids.tolist()]]
ev = compare_rotations(R, G)
print(json.dumps({"solve_s": info["solve_seconds"], "median_deg": ev.median,
                  "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""
GLOMAP_TIMEOUT_S = 20 * 60  # the issue: GLOMAP where it finishes within 20 minutes


def glomap_once(folder: Path) -> dict:
    """GLOMAP's rotation averaging (pycolmap.run_rotation_averaging, bench_multiple.run_glomap)
    on the same problem in a subprocess: its solve time, peak RSS and median error; stopped
    after GLOMAP_TIMEOUT_S."""
    cmd = [sys.executable, "-c", GLOMAP_SNIPPET, str(folder / "edges.txt"), str(folder / "gt.txt"), os.path.abspath(__file__)]
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=GLOMAP_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        return {"glomap": f"> {GLOMAP_TIMEOUT_S // 60} min"}
    if p.returncode != 0:
        return {"glomap": f"failed ({p.returncode})"}
    r = json.loads(p.stdout.strip().splitlines()[-1])
    return {"glomap_s": r["solve_s"], "glomap_rss_mb": r["rss_mb"], "glomap_median_deg": r["median_deg"]}


MAX_RSS_MB = None  # --max-rss-gb: a stage above it is stopped (shared machines)


def _tree_rss_mb(pid: int) -> float:
    """Resident memory of ``pid`` and its descendants (Linux /proc), MB."""
    total, todo = 0.0, [pid]
    while todo:
        p = todo.pop()
        try:
            with open(f"/proc/{p}/status") as fh:
                for line in fh:
                    if line.startswith("VmRSS:"):
                        total += int(line.split()[1]) / 1024
            with open(f"/proc/{p}/task/{p}/children") as fh:
                todo += [int(c) for c in fh.read().split()]
        except (OSError, ValueError):
            pass
    return total


def run(cmd: list[str]) -> tuple[subprocess.CompletedProcess, float, float]:
    """Run ``cmd``: (process, wall seconds, peak RSS in MB of the command itself). With
    ``--max-rss-gb`` the command is stopped (RuntimeError) when its memory passes the limit."""
    timed = os.path.exists(TIME)
    full = ([TIME, "-v"] if timed else []) + cmd
    t = time.perf_counter()
    over: list[float] = []
    # its own process group, so that a stage above --max-rss-gb is stopped with its children
    with subprocess.Popen(full, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True) as proc:
        if MAX_RSS_MB:
            import signal
            import threading

            def watch():
                while proc.poll() is None:
                    rss_now = _tree_rss_mb(proc.pid)
                    if rss_now > MAX_RSS_MB:
                        over.append(rss_now)
                        os.killpg(proc.pid, signal.SIGKILL)
                        return
                    time.sleep(0.25)

            threading.Thread(target=watch, daemon=True).start()
        out, err = proc.communicate()
    p = subprocess.CompletedProcess(full, proc.returncode, out, err)
    wall = time.perf_counter() - t
    if over:
        raise RuntimeError(f"{' '.join(map(str, cmd))}: stopped at {over[0]:.0f} MB, above --max-rss-gb")
    rss = float("nan")
    if timed:
        for line in p.stderr.splitlines():
            if "Maximum resident set size" in line:
                rss = int(line.split(":")[1]) / 1024
    else:
        rss = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024  # the largest child so far
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(map(str, cmd))} failed ({p.returncode}):\n{p.stdout[-2000:]}\n{p.stderr[-3000:]}")
    return p, wall, rss


def rotgraph_cmd() -> list[str]:
    exe = shutil.which("rotgraph")
    return [exe] if exe else [sys.executable, "-m", "rotgraph"]


def make_problem(folder: Path, n: int, degree: float, fresh: bool, spread: float | None = None) -> dict:
    meta_path = folder / "meta.json"
    want = {"n": n, "degree": float(degree), "sigma_deg": SIGMA, "outliers": OUTLIERS, "seed": SEED}
    if spread is not None:
        want["uncertainty_spread"] = float(spread)
    info = {"synth_s": None, "synth_rss_mb": None}
    if not fresh and meta_path.exists() and (folder / "edges.npz").exists() and (spread or (folder / "edges.txt").exists()):
        meta = json.loads(meta_path.read_text())
        if all(meta.get(k) == v for k, v in want.items()):
            print(f"  reusing {folder}", flush=True)
            return info
    if folder.exists():
        shutil.rmtree(folder)
    extra = ["--edges-format", "both"] if spread is None else ["--edges-format", "npz", "--uncertainty-spread", str(spread)]
    _, wall, rss = run(rotgraph_cmd() + ["synth", "-o", str(folder), "--n", str(n), "--degree", str(degree),
                                         "--sigma", str(SIGMA), "--outliers", str(OUTLIERS), "--seed", str(SEED), *extra])
    info.update(synth_s=wall, synth_rss_mb=rss)
    print(f"  synth {wall:.1f} s, {rss:.0f} MB", flush=True)
    return info


def read_once(path: Path, repeats: int) -> dict:
    best = None
    for _ in range(repeats):
        p, _, _ = run([sys.executable, "-c", READ_SNIPPET, str(path)])
        r = json.loads(p.stdout.strip().splitlines()[-1])
        best = r if best is None or r["seconds"] < best["seconds"] else best
    return best


def solve_once(folder: Path, edges: str = "edges.txt", extra: tuple = (), key: str = "") -> dict:
    """The whole ``rotgraph solve`` of ``folder/edges`` (with ``extra`` options), then its error;
    the row's keys get ``key`` after their first word (``solve_s`` -> ``solve<key>_s``,
    ``iterations`` -> ``iterations<key>``)."""
    out = folder / "r.csv"
    p, wall, rss = run(rotgraph_cmd() + ["solve", str(folder / edges), "-o", str(out), "--json", *extra])
    summary = json.loads(p.stdout[p.stdout.index("{"):])
    e, _, _ = run(rotgraph_cmd() + ["eval", str(out), str(folder / "gt.txt"), "--json"])
    ev = json.loads(e.stdout[e.stdout.index("{"):])
    row = {"solve_s": wall, "solve_rss_mb": rss, "solve_read_s": summary.get("seconds_read"),
           "solve_solve_s": summary.get("seconds_solve"), "iterations": summary.get("iterations"),
           "median_deg": ev.get("median"), "mean_deg": ev.get("mean")}
    return {(k + key) if "_" not in k else k.replace("_", key + "_", 1): v for k, v in row.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="the 20k / 10^6 row only")
    ap.add_argument("--rows", default=None, help="comma-separated NxDEGREE, e.g. 20000x100,200000x100")
    ap.add_argument("--work", default="/tmp/rotgraph_bench_scale", help="folder for the problems (reused)")
    ap.add_argument("--fresh", action="store_true", help="remake the problems (and time synth)")
    ap.add_argument("--clean", action="store_true", help="remove each problem after its row")
    ap.add_argument("--skip-solve", action="store_true")
    ap.add_argument("--repeats", type=int, default=1, help="read repeats (best kept)")
    ap.add_argument("--json", dest="json_out", default=None)
    ap.add_argument("--glomap", action="store_true",
                    help=f"also GLOMAP's rotation averaging (pycolmap) on each row, stopped after {GLOMAP_TIMEOUT_S // 60} min")
    ap.add_argument("--max-rss-gb", type=float, default=None,
                    help="stop a stage whose memory (process tree RSS) passes this; its row then says so")
    ap.add_argument("--information", type=float, default=None, metavar="K",
                    help="problems with anisotropic information (synth --uncertainty-spread K), solved with and without it")
    args = ap.parse_args()
    global MAX_RSS_MB
    MAX_RSS_MB = None if args.max_rss_gb is None else args.max_rss_gb * 1024
    rows = ROWS[:1] if args.quick else ROWS
    if args.rows:
        rows = [(int(a), float(b)) for a, b in (r.lower().split("x") for r in args.rows.split(","))]
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    print(f"# rotgraph bench_scale: commit {git_commit()}, {cpu_model()}, {usable_cpus()} CPUs, "
          f"load {load_average()}", flush=True)
    results = []
    for n, degree in rows:
        spread = args.information
        folder = work / (f"n{n}_d{degree:g}" + ("" if spread is None else f"_u{spread:g}"))
        print(f"n = {n}, degree {degree:g}" + ("" if spread is None else f", information (spread {spread:g})") + ":", flush=True)
        res = {"n": n, "degree": degree, "uncertainty_spread": spread, **make_problem(folder, n, degree, args.fresh, spread)}
        has_txt = (folder / "edges.txt").exists()
        res["txt_mb"] = (folder / "edges.txt").stat().st_size / 2**20 if has_txt else None
        res["npz_mb"] = (folder / "edges.npz").stat().st_size / 2**20
        rt = read_once(folder / "edges.txt", args.repeats) if has_txt else {"seconds": None, "rss_mb": None}
        rb = read_once(folder / "edges.npz", args.repeats)
        res.update(n_edges=rb["n_edges"], read_txt_s=rt["seconds"], read_txt_rss_mb=rt["rss_mb"],
                   read_npz_s=rb["seconds"], read_npz_rss_mb=rb["rss_mb"])
        print(("" if not has_txt else f"  read txt {rt['seconds']:.1f} s ({res['txt_mb'] / max(rt['seconds'], 1e-9):.0f} MB/s), ")
              + f"  npz {rb['seconds']:.2f} s", flush=True)
        solves = [("", "edges.txt", ())] if spread is None else [("", "edges.npz", ()), ("_scalar", "edges.npz", ("--no-use-information",))]
        for key, edges_file, extra in solves if not args.skip_solve else []:
            try:
                res.update(solve_once(folder, edges_file, extra, key))
                print(f"  solve{key.replace('_', ' ')} {res[f'solve{key}_s']:.1f} s, {res[f'solve{key}_rss_mb']:.0f} MB, "
                      f"median {res[f'median{key}_deg']:.3f} deg, {res[f'iterations{key}']} iterations", flush=True)
            except RuntimeError as exc:
                if "max-rss-gb" not in str(exc):
                    raise
                res[f"solve{key}_stopped"] = str(exc).rsplit(": ", 1)[-1]
                print(f"  solve{key.replace('_', ' ')} {res[f'solve{key}_stopped']}", flush=True)
        if args.glomap:
            res.update(glomap_once(folder))
            if "glomap_s" in res:
                print(f"  GLOMAP {res['glomap_s']:.1f} s, {res['glomap_rss_mb']:.0f} MB, median {res['glomap_median_deg']:.3f} deg",
                      flush=True)
            else:
                print(f"  GLOMAP {res['glomap']}", flush=True)
        results.append(res)
        if args.clean:
            shutil.rmtree(folder)

    def f(x, fmt):
        return "—" if x is None else format(x, fmt)

    header = ["n / edges", "synth s (peak MB)", "edges.txt MB", "edges.npz MB", "read txt s (MB/s)", "read npz s",
              "solve s (read + solve)", "solve peak MB", "median err deg", "iterations"]
    if args.information is not None:
        header += ["solve without information s (read + solve)", "its peak MB", "its median deg", "solve time ratio with / without"]
    if args.glomap:
        header += ["GLOMAP s (peak MB)", "GLOMAP median deg", "time ratio rotgraph / GLOMAP"]
    body = []
    for r in results:
        body.append([
            f"{r['n']:,} / {r['n_edges']:,}",
            "reused" if r["synth_s"] is None else f"{r['synth_s']:.1f} ({r['synth_rss_mb']:.0f})",
            f(r["txt_mb"], ".0f"), f"{r['npz_mb']:.0f}",
            "—" if r["read_txt_s"] is None else f"{r['read_txt_s']:.2f} ({r['txt_mb'] / max(r['read_txt_s'], 1e-9):.0f})",
            f"{r['read_npz_s']:.2f}",
            r.get("solve_stopped", "—") if "solve_s" not in r else
            f"{r['solve_s']:.1f} ({f(r['solve_read_s'], '.1f')} + {f(r['solve_solve_s'], '.1f')})",
            "—" if "solve_s" not in r else f"{r['solve_rss_mb']:.0f}",
            "—" if "solve_s" not in r else f(r["median_deg"], ".3f"),
            "—" if "solve_s" not in r else str(r["iterations"]),
        ])
        if args.information is not None:
            if "solve_scalar_s" in r:
                ratio = f"{r['solve_solve_s'] / r['solve_scalar_solve_s']:.2f}" if "solve_s" in r and r["solve_solve_s"] else "—"
                body[-1] += [f"{r['solve_scalar_s']:.1f} ({f(r['solve_scalar_read_s'], '.1f')} + {f(r['solve_scalar_solve_s'], '.1f')})",
                             f"{r['solve_scalar_rss_mb']:.0f}", f(r["median_scalar_deg"], ".3f"), ratio]
            else:
                body[-1] += [r.get("solve_scalar_stopped", "—"), "—", "—", "—"]
        if args.glomap:
            if "glomap_s" in r:
                ratio = f"{r['solve_s'] / r['glomap_s']:.3f}" if "solve_s" in r else "—"
                body[-1] += [f"{r['glomap_s']:.1f} ({r['glomap_rss_mb']:.0f})", f"{r['glomap_median_deg']:.3f}", ratio]
            else:
                body[-1] += [r.get("glomap", "—"), "—", "—"]
    print()
    print(table(header, body))
    print(f"\nload after: {load_average()}")
    if args.json_out:
        Path(args.json_out).write_text(json.dumps({"commit": git_commit(), "cpu": cpu_model(), "rows": results}, indent=1))


if __name__ == "__main__":
    main()
