"""Benchmark: ``rotgraph batch`` (Dask, local cluster) vs ``rotgraph solve`` one problem at a time.

Eight medium synthetic problems (n = 2500 ... 3500 cameras, degree 150, 2 deg noise,
20 % outliers, 190 000 - 260 000 edges; one solve takes about 2-3 s on one idle core) are
written to a scratch folder; then, interleaved over ``--repeats`` rounds (the order of the
contenders rotates from round to round):

* ``solve x8 (processes)``: ``rotgraph solve P -o OUT`` as 8 subprocesses, one after the
  other (what a shell loop over the problems does; the reference of the target ratio);
* ``solve x8 (in-process)``: :func:`rotgraph.pipeline.solve.solve_file` (the body of
  ``rotgraph solve``) called 8 times in this process (no interpreter start-up per problem:
  a stricter reference);
* ``rotgraph batch``: one ``rotgraph batch P1 ... P8 --out-dir DIR --workers W``
  subprocess (default local Dask cluster: W worker processes, one thread each), wall time
  including the Python start-up, cluster start and shutdown.

Every batch output is compared byte for byte with the ``rotgraph solve`` output. Prints
markdown tables on stdout (progress on stderr). Target: batch <= 0.65 x the one-by-one
``rotgraph solve`` time on 2 cores.

    python benchmarks/bench_batch.py                 # about 3-4 min on 2 idle cores
    python benchmarks/bench_batch.py --repeats 1     # one round
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _common import cpu_model, git_commit, load_average, usable_cpus  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def log(msg: str) -> None:
    print(f"[bench_batch] {msg}", file=sys.stderr, flush=True)


def rotgraph_cmd() -> list[str]:
    exe = shutil.which("rotgraph", path=os.path.dirname(sys.executable)) or shutil.which("rotgraph")
    return [exe] if exe else [sys.executable, "-m", "rotgraph.cli.main"]


def header(workers: int) -> str:
    import numpy
    import scipy

    import rotgraph

    try:
        import dask
        import distributed

        dask_v = f"dask {dask.__version__}, distributed {distributed.__version__}"
    except ImportError:
        dask_v = "dask not installed"
    return (
        f"python {platform.python_version()}, numpy {numpy.__version__}, scipy {scipy.__version__}, rotgraph {rotgraph.__version__} "
        f"({git_commit()}), {dask_v}\n\nCPU: {cpu_model()}; os.cpu_count() = {os.cpu_count()}, usable {usable_cpus()}; "
        f"load average at start {load_average(', ')}; batch workers: {workers}"
    )


def machine_busy() -> float | None:
    """CPU seconds the whole machine has spent busy since boot (Linux), else None."""
    try:
        with open("/proc/stat") as fh:
            v = [int(x) for x in fh.readline().split()[1:]]
    except OSError:
        return None
    return (sum(v[:8]) - v[3] - v[4]) / os.sysconf("SC_CLK_TCK")


def our_cpu() -> float:
    import resource

    a, b = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return a.ru_utime + a.ru_stime + b.ru_utime + b.ru_stime


def wait_idle(limit: float) -> None:
    """Wait (at most ``limit`` s) until the CPUs are >= 85 % idle in 3 one-second samples in a row."""
    if limit <= 0 or machine_busy() is None:
        return
    cores = os.cpu_count() or 1
    t_end, calm = time.monotonic() + limit, 0
    while time.monotonic() < t_end and calm < 3:
        b0 = machine_busy()
        time.sleep(1.0)
        calm = calm + 1 if (machine_busy() - b0) / cores <= 0.15 else 0
    if calm < 3:
        log(f"the machine did not become idle within {limit:.0f} s; timing anyway")


def timed(fn, *args):
    """``(wall seconds, CPU seconds of other processes on the machine meanwhile, fn's result)``."""
    b0, c0, t0 = machine_busy(), our_cpu(), time.perf_counter()
    out = fn(*args)
    wall = time.perf_counter() - t0
    foreign = None if b0 is None else max(0.0, (machine_busy() - b0) - (our_cpu() - c0))
    return wall, foreign, out


def make_problems(folder: Path, count: int, n_min: int, n_max: int, degree: float, seed: int) -> list[dict]:
    from rotgraph.io.writers import write_edges
    from rotgraph.synth import random_problem

    out = []
    for k in range(count):
        n = int(round(n_min + (n_max - n_min) * k / max(1, count - 1)))
        g = random_problem(n=n, degree=degree, sigma_deg=2.0, outliers=0.2, graph="er", seed=seed + k)
        path = folder / f"problem{k}.txt"
        write_edges(path, g)
        out.append({"path": path, "n": n, "edges": g.n_edges})
    return out


def run_solve_processes(problems, ref_dir: Path) -> float:
    t = time.perf_counter()
    for p in problems:
        subprocess.run([*rotgraph_cmd(), "solve", str(p["path"]), "-o", str(ref_dir / (p["path"].stem + ".csv")), "-q"], check=True)
    return time.perf_counter() - t


def run_solve_inprocess(problems, out_dir: Path) -> tuple[float, list[float]]:
    from rotgraph.pipeline.solve import solve_file

    each = []
    t = time.perf_counter()
    for p in problems:
        t1 = time.perf_counter()
        solve_file(str(p["path"]), str(out_dir / (p["path"].stem + ".csv")))
        each.append(time.perf_counter() - t1)
    return time.perf_counter() - t, each


def run_batch(problems, out_dir: Path, workers: int) -> float:
    shutil.rmtree(out_dir, ignore_errors=True)
    cmd = [*rotgraph_cmd(), "batch", *[str(p["path"]) for p in problems], "--out-dir", str(out_dir), "--workers", str(workers), "-q"]
    t = time.perf_counter()
    r = subprocess.run(cmd)
    elapsed = time.perf_counter() - t
    if r.returncode != 0:
        raise SystemExit(f"rotgraph batch failed with exit code {r.returncode}")
    return elapsed


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--problems", type=int, default=8)
    ap.add_argument("--n-min", type=int, default=2500)
    ap.add_argument("--n-max", type=int, default=3500)
    ap.add_argument("--degree", type=float, default=150.0)
    ap.add_argument("--workers", type=int, default=2, help="local cluster size of rotgraph batch (default 2)")
    ap.add_argument("--repeats", type=int, default=3, help="rounds; the median of each contender is reported")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--keep", type=str, default=None, help="write the problems and outputs here and keep them")
    ap.add_argument("--wait-idle", type=float, default=120.0,
                    help="before each timed run, wait up to this many seconds for the CPUs to be idle (0: do not wait; default 120)")
    args = ap.parse_args(argv)

    tmp = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="rotgraph_bench_batch_"))
    tmp.mkdir(parents=True, exist_ok=True)
    try:
        log(f"writing {args.problems} problems to {tmp}")
        problems = make_problems(tmp, args.problems, args.n_min, args.n_max, args.degree, args.seed)
        ref, inproc, batch_dir = tmp / "solve", tmp / "inprocess", tmp / "batch"
        for d in (ref, inproc):
            d.mkdir(exist_ok=True)
        print("# rotgraph batch vs rotgraph solve one by one\n")
        print(header(args.workers) + "\n")
        times = {"seq_proc": [], "seq_api": [], "batch": []}
        other = {k: [] for k in times}
        each_api: list[list[float]] = []
        for r in range(args.repeats):
            # Rotate the order every round, so that machine noise hits all contenders alike.
            order = ["seq_proc", "batch", "seq_api"]
            order = order[r % 3:] + order[: r % 3]
            for name in order:
                wait_idle(args.wait_idle)
                if name == "seq_proc":
                    wall, foreign, _ = timed(run_solve_processes, problems, ref)
                elif name == "seq_api":
                    wall, foreign, (_, each) = timed(run_solve_inprocess, problems, inproc)
                    each_api.append(each)
                else:
                    wall, foreign, _ = timed(run_batch, problems, batch_dir, args.workers)
                times[name].append(wall)
                other[name].append(foreign)
                log(f"round {r + 1}/{args.repeats}: {name} {wall:.2f} s (other processes: {foreign if foreign is None else round(foreign, 1)} CPU s)")
        same = all((ref / (p["path"].stem + ".csv")).read_bytes() == (batch_dir / (p["path"].stem + ".csv")).read_bytes() for p in problems)
        med = {k: statistics.median(v) for k, v in times.items()}

        print("## Problems\n")
        print("| problem | cameras | edges | in-process solve (s, median) |")
        print("|---|---:|---:|---:|")
        for k, p in enumerate(problems):
            print(f"| {p['path'].name} | {p['n']} | {p['edges']} | {statistics.median(e[k] for e in each_api):.2f} |")
        print()
        per_round = [b / p for b, p in zip(times["batch"], times["seq_proc"])]
        print(f"## Wall time, {args.problems} problems (median of {args.repeats} round(s))\n")
        def oth(k):
            v = [x for x in other[k] if x is not None]
            return f"{statistics.median(v):.1f}" if v else "?"

        print("| contender | seconds | batch / this | target | other processes' CPU s meanwhile |")
        print("|---|---:|---:|---|---:|")
        print(f"| `rotgraph solve` x{args.problems}, one subprocess each, one by one | {med['seq_proc']:.2f} | **{med['batch'] / med['seq_proc']:.3f}** | <= 0.65: {'met' if med['batch'] / med['seq_proc'] <= 0.65 else 'NOT met'} | {oth('seq_proc')} |")
        print(f"| `solve_file` x{args.problems} in one process (solve's body, no start-up) | {med['seq_api']:.2f} | {med['batch'] / med['seq_api']:.3f} | (stricter reference) | {oth('seq_api')} |")
        print(f"| `rotgraph batch --workers {args.workers}` (local Dask cluster, start-up and shutdown included) | {med['batch']:.2f} | 1 | | {oth('batch')} |")
        print()
        print("Other processes' CPU s: busy CPU time of the whole machine during the run minus this benchmark's own "
              "(with its children); anything well above 0 means the timings are contaminated by other load.")
        print()
        print("Every round (s): " + "; ".join(
            f"round {r + 1}: solve x{args.problems} processes {times['seq_proc'][r]:.2f}, in-process {times['seq_api'][r]:.2f}, "
            f"batch {times['batch'][r]:.2f} (ratio {per_round[r]:.3f})" for r in range(args.repeats)))
        load = os.getloadavg() if hasattr(os, "getloadavg") else ()
        print(f"\nLoad average at the end: {', '.join(f'{x:.2f}' for x in load)}")
        print(f"\nBatch outputs byte-identical to `rotgraph solve`: {'yes' if same else 'NO'}")
        return 0 if same else 1
    finally:
        if not args.keep:
            shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
