#!/usr/bin/env python
"""One view graph solved on a (simulated) Dask cluster (#32) against the single-process solve.

Run from the repository root::

    python benchmarks/bench_distributed.py                       # 20k cameras / 10^6 edges, 4 workers
    python benchmarks/bench_distributed.py --rows 200000x100     # the issue's 10^7-edge problem
    python benchmarks/bench_distributed.py --rows 20000x100 --workers 4 --limit 0.35 --parts 16 --json out.json
    python benchmarks/bench_distributed.py --rows 200000x100 --real-scheduler    # dask scheduler + dask worker
    python benchmarks/bench_distributed.py --rows 800000x100 --chunked --parts 64 --no-single --limit-mb 4096 --real-scheduler

Each problem is ``rotgraph synth --n N --degree D --sigma 2 --outliers 0.1 --seed 0`` (as
``bench_scale.py`` makes it, in ``--work/nN_dD``, reused), its edges cut into ``--parts``
Parquet parts (``--work/nN_dD/parts``, in a separate process). Then, each in its own process:

* ``single``: ``rotgraph solve PARTS -o single.csv --json`` (wall time, peak RSS);
* ``distributed``: a local Dask cluster of ``--workers`` worker processes (one thread each),
  each with a memory limit of ``--limit`` times the single-process peak (Dask's nanny stops a
  worker at 95 % of it; spilling and pausing off: the shards must stay in memory), and
  :func:`rotgraph.pipeline.distributed.solve_distributed` on it: the whole time (cluster start
  included), each worker's peak RSS (``getrusage`` in the worker), whether any worker was
  restarted (its process id changed), and the client process's peak RSS (with the local
  cluster's scheduler in it: an upper bound of the client's);
* both CSVs evaluated against gt.txt (``rotgraph eval``): median error and its ratio.

``--real-scheduler``: instead, a ``dask scheduler`` and ``--workers`` ``dask worker --nthreads 1
--memory-limit LIMIT`` processes on 127.0.0.1 (Dask's own settings), and ``rotgraph solve PARTS
--scheduler ADDRESS --json`` as a subprocess (:class:`RealCluster`, :func:`solve_real`): its wall
time and peak RSS (the client alone), the workers' peaks and process ids (another client asks
them), everything stopped after. ``--chunked`` generates the problem part by part
(:func:`chunked_problem`) for graphs whose ``rotgraph synth`` would not fit; with
``--no-single --limit-mb MB`` no single-process solve is run (4 x 10^7 edges here).

The issue's bar: workers below their limit (35 % of the single-process peak), the client below
0.2x that peak, the whole time within 3x the single-process time, the median error within
1.01x. Results go to the table printed (and ``--json``); benchmarks/README.md has them.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import cpu_model, git_commit, load_average, table, usable_cpus  # noqa: E402
from bench_scale import OUTLIERS, SEED, SIGMA, make_problem, rotgraph_cmd, run  # noqa: E402

PARTS_SNIPPET = """
import sys, numpy as np, pyarrow as pa, pyarrow.parquet as pq
from pathlib import Path
src, out, k = sys.argv[1], Path(sys.argv[2]), int(sys.argv[3])
out.mkdir(parents=True, exist_ok=True)
with np.load(src) as z:
    cols = {c: z[c] for c in z.files}
m = len(cols["i"])
cuts = np.linspace(0, m, k + 1).astype(int)
for p in range(k):
    pq.write_table(pa.table({c: v[cuts[p]:cuts[p + 1]] for c, v in cols.items()}), out / f"part.{p}.parquet")
"""

DIST_SNIPPET = """
import json, os, resource, sys, time
if __name__ == "__main__":
    t0 = time.perf_counter()
    import dask, distributed
    from rotgraph.pipeline.cluster import quiet_worker_config
    from rotgraph.pipeline.distributed import solve_distributed, worker_memory_config
    parts, out, workers, limit = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
    with dask.config.set({**quiet_worker_config(), **worker_memory_config()}):
        cluster = distributed.LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, memory_limit=limit,
                                           dashboard_address=None, host="127.0.0.1")
        client = distributed.Client(cluster)
    pids0 = client.run(os.getpid)
    s = solve_distributed(parts, out, client=client, overwrite=True)
    peaks = client.run(lambda: resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
    pids1 = client.run(os.getpid)
    wall = time.perf_counter() - t0
    client.close(); cluster.close()
    d = s["diagnostics"]["distributed"]
    print(json.dumps({"seconds": wall, "solve_seconds": s["seconds"], "worker_peak_mb": max(peaks.values()),
                      "worker_peaks_mb": sorted(peaks.values()), "restarted": sorted(set(pids0.values()) ^ set(pids1.values())) != [],
                      "client_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                      "blocks": d["blocks"], "cut_edges": d["cut_edges"], "rounds": d["exchange_rounds"],
                      "products": d["cg_products"], "iterations": s["iterations"], "n_outliers": s["n_outliers"],
                      "n_edges": s["n_edges"], "stages": [(x["stage"], round(x["seconds"], 2)) for x in d["stages"]]}))
"""


WORKER_PEAKS = """
import json, os, resource, sys
from distributed import Client
with Client(sys.argv[1], timeout="20s") as c:
    c.wait_for_workers(int(sys.argv[2]), timeout=120)
    print(json.dumps({"pids": sorted(c.run(os.getpid).values()),
                      "peaks_mb": sorted(v / 1024 for v in c.run(lambda: resource.getrusage(resource.RUSAGE_SELF).ru_maxrss).values())}))
"""


def free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class RealCluster:
    """``dask scheduler`` and ``workers`` x ``dask worker --nthreads 1 --memory-limit LIMIT`` on
    127.0.0.1 as separate processes (Dask's own settings: a nanny each, spilling and pausing as
    Dask sets them), as a user starts them; everything stopped on exit."""

    def __init__(self, workers: int, limit_bytes: int, log: Path):
        self.workers, self.limit, self.log = workers, limit_bytes, log
        self.address = f"tcp://127.0.0.1:{free_port()}"
        self.procs: list = []

    def _start(self, *args) -> None:
        import subprocess

        with open(self.log, "a") as fh:  # (the child keeps its own descriptor)
            self.procs.append(subprocess.Popen([sys.executable, "-m", "dask", *args], stdout=fh, stderr=fh,
                                               start_new_session=True))

    def __enter__(self):
        t0 = time.perf_counter()
        port = self.address.rsplit(":", 1)[1]
        self._start("scheduler", "--host", "127.0.0.1", "--port", port, "--no-dashboard")
        for _ in range(self.workers):
            self._start("worker", self.address, "--nthreads", "1", "--memory-limit", str(self.limit), "--host", "127.0.0.1",
                        "--no-dashboard")
        self.state()  # (waits for the workers)
        self.start_seconds = time.perf_counter() - t0
        return self

    def state(self) -> dict:
        """The workers' process ids and peak RSS in MB (``getrusage`` in each), once all are up."""
        p, _, _ = run([sys.executable, "-c", WORKER_PEAKS, self.address, str(self.workers)])
        return json.loads(p.stdout.strip().splitlines()[-1])

    def __exit__(self, *exc):
        import signal
        import subprocess

        for p in reversed(self.procs):  # workers first (their nannies stop them), the scheduler last
            with contextlib.suppress(ProcessLookupError):
                os.killpg(p.pid, signal.SIGTERM)
        for p in self.procs:
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()
        return False


def solve_real(parts: Path, out: Path, limit_bytes: int, args) -> dict:
    """``rotgraph solve PARTS --scheduler ADDRESS`` (a subprocess, as a user runs it) on a
    :class:`RealCluster`: its whole time and peak RSS (the client), the workers' peaks."""
    with RealCluster(args.workers, limit_bytes, out.with_suffix(".dask.log")) as cluster:
        before = cluster.state()
        p, wall, rss = run(rotgraph_cmd() + ["solve", str(parts), "-o", str(out), "--scheduler", cluster.address, "--json",
                                             "--overwrite"] + (["--blocks", str(args.blocks)] if args.blocks else []))
        if p.returncode:
            raise RuntimeError(f"rotgraph solve --scheduler failed ({p.returncode}): {p.stderr[-2000:]}")
        after = cluster.state()
    s = json.loads(p.stdout)
    d = s["diagnostics"]["distributed"]
    return {"seconds": wall, "cluster_start_seconds": cluster.start_seconds, "solve_seconds": s["seconds"],
            "worker_peak_mb": max(after["peaks_mb"]), "worker_peaks_mb": after["peaks_mb"],
            "restarted": before["pids"] != after["pids"], "client_mb": rss, "blocks": d["blocks"],
            "cut_edges": d["cut_edges"], "rounds": d["exchange_rounds"], "products": d["cg_products"],
            "iterations": s["iterations"], "n_outliers": s["n_outliers"], "n_edges": s["n_edges"],
            "stages": [(x["stage"], round(x["seconds"], 2)) for x in d["stages"]]}


CHUNKED_SNIPPET = """
import json, sys, numpy as np, pyarrow as pa, pyarrow.parquet as pq
from pathlib import Path
from rotgraph import so3
from rotgraph.io.writers import write_rotations
out, n, degree, k, sigma, outliers, seed = Path(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3]), int(sys.argv[4]), float(sys.argv[5]), float(sys.argv[6]), int(sys.argv[7])
parts = out / f"parts{k}"
parts.mkdir(parents=True, exist_ok=True)
q = so3.quaternion_rows_from_matrices(so3.random_rotations(n, np.random.default_rng([seed])))
write_rotations(out / "gt.csv", np.arange(n), None, so3.matrices_from_quaternion_rows(q))
p_edge = degree / (n - 1)
# camera i's edges to cameras j > i: Binomial(n - 1 - i, p) of them; parts cut where the expected counts are equal
cum = np.cumsum((n - 1 - np.arange(n)).astype(np.float64))
cuts = np.r_[0, np.searchsorted(cum, cum[-1] * np.arange(1, k) / k), n]
total = 0
for c in range(k):
    rng = np.random.default_rng([seed, 1 + c])
    a, b = int(cuts[c]), int(cuts[c + 1])
    cams = np.arange(a, b)
    counts = rng.binomial(n - 1 - cams, p_edge)
    i = np.repeat(cams, counts)
    j = i + 1 + (rng.random(len(i)) * (n - 1 - i)).astype(np.int64)
    key = np.unique(i * n + j)  # (a pair drawn twice: one edge)
    i, j = key // n, key % n
    del key
    m = len(i)
    rel = so3.qmul_rows(q[:, j], so3.qconj_rows(q[:, i]))  # R_j R_i^T
    rel = so3.qmul_rows(rel, so3.qexp_rows(np.deg2rad(sigma) * rng.standard_normal((3, m))))  # times exp(e)
    wrong = rng.random(m) < outliers
    u = rng.standard_normal((4, int(wrong.sum())))
    rel[:, wrong] = u / np.sqrt((u * u).sum(axis=0))
    flip = rng.random(m) < 0.5  # both directions occur: (j, i) carries R_ij^T
    i, j = np.where(flip, j, i), np.where(flip, i, j)
    rel[1:, flip] *= -1.0
    rel = so3.positive_w_rows(rel)
    order = rng.permutation(m)
    pq.write_table(pa.table({"i": i[order], "j": j[order], "qw": rel[0, order], "qx": rel[1, order], "qy": rel[2, order],
                             "qz": rel[3, order], "weight": np.ones(m)}), parts / f"part.{c}.parquet")
    total += m
    print(f"part {c}: {m} edges", file=sys.stderr, flush=True)
(out / "meta.json").write_text(json.dumps({"n": n, "degree": degree, "sigma_deg": sigma, "outliers": outliers, "seed": seed,
                                           "parts": k, "edges": total, "generator": "chunked"}))
"""


def chunked_problem(folder: Path, n: int, degree: float, k: int) -> Path:
    """An Erdos-Renyi problem like ``rotgraph synth``'s (sigma 2 deg, 10 % uniform outliers, seed 0;
    not the same draws) generated part by part straight to ``k`` Parquet parts and gt.csv, for
    graphs whose generation in one process would not fit: each camera ``i`` joined to
    Binomial(n - 1 - i, degree / (n - 1)) random cameras ``j > i`` (a pair drawn twice: one
    edge), each part a range of ``i`` with its own seed. Memory: one part's edges at a time."""
    parts = folder / f"parts{k}"
    meta = folder / "meta.json"
    want = {"n": n, "degree": float(degree), "parts": k, "generator": "chunked"}
    if meta.exists() and all(json.loads(meta.read_text()).get(a) == b for a, b in want.items()):
        print(f"  reusing {folder}", flush=True)
        return parts
    p, wall, rss = run([sys.executable, "-c", CHUNKED_SNIPPET, str(folder), str(n), str(degree), str(k), str(SIGMA),
                        str(OUTLIERS), str(SEED)])
    if p.returncode:
        raise RuntimeError(f"generating the parts failed: {p.stderr[-2000:]}")
    print(f"  generated in {wall:.1f} s, {rss:.0f} MB", flush=True)
    return parts


def parts_of(folder: Path, k: int) -> Path:
    out = folder / f"parts{k}"
    if not (out / f"part.{k - 1}.parquet").exists():
        run([sys.executable, "-c", PARTS_SNIPPET, str(folder / "edges.npz"), str(out), str(k)])
    return out


def median_error(csv: Path, gt: Path) -> float:
    p, _, _ = run(rotgraph_cmd() + ["eval", str(csv), str(gt), "--json"])
    return json.loads(p.stdout)["median"]


def bench_row(n: int, degree: float, args) -> dict:
    print(f"{n} cameras, degree {degree:g}:", flush=True)
    if args.chunked:
        folder = Path(args.work) / f"n{n}_d{degree:g}_chunked"
        parts, gt = chunked_problem(folder, n, degree, args.parts), folder / "gt.csv"
    else:
        folder = Path(args.work) / f"n{n}_d{degree:g}"
        make_problem(folder, n, degree, fresh=False)
        parts, gt = parts_of(folder, args.parts), folder / "gt.txt"
    row = {"n": n, "parts": args.parts, "workers": args.workers, "cluster": cluster_kind(args), "single_s": None,
           "single_mb": None, "single_median": None, "single_outliers": None}
    if not args.no_single:
        p, t_single, rss_single = run(rotgraph_cmd() + ["solve", str(parts), "-o", str(folder / "single.csv"), "--json",
                                                        "--overwrite"])
        s = json.loads(p.stdout)
        print(f"  single {t_single:.1f} s, {rss_single:.0f} MB", flush=True)
        row.update(single_s=t_single, single_mb=rss_single, single_outliers=s["n_outliers"],
                   single_median=median_error(folder / "single.csv", gt))
    limit_mb = args.limit_mb or args.limit * row["single_mb"]
    if args.real_scheduler:
        d = solve_real(parts, folder / "dist.csv", int(limit_mb * 2**20), args)
    else:
        p, _, _ = run([sys.executable, "-c", DIST_SNIPPET, str(parts), str(folder / "dist.csv"), str(args.workers),
                       str(int(limit_mb * 2**20))])
        d = json.loads(p.stdout.strip().splitlines()[-1])
    print(f"  distributed ({cluster_kind(args)}) {d['seconds']:.1f} s, workers <= {d['worker_peak_mb']:.0f} MB "
          f"(limit {limit_mb:.0f}), client {d['client_mb']:.0f} MB; stages {d['stages']}", flush=True)
    row.update(edges=d["n_edges"], limit_mb=limit_mb, **{f"dist_{k}": v for k, v in d.items()},
               dist_median=median_error(folder / "dist.csv", gt), load=load_average())
    return row


def cluster_kind(args) -> str:
    return "dask scheduler + dask worker" if args.real_scheduler else "LocalCluster"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rows", default="20000x100", help="comma-separated NxDEGREE (200000x100: 10^7 edges)")
    ap.add_argument("--work", default="/tmp/rotgraph_bench_scale", help="folder for the problems (shared with bench_scale)")
    ap.add_argument("--workers", type=int, default=4)
    ap.add_argument("--limit", type=float, default=0.35, help="each worker's memory limit, times the single-process peak")
    ap.add_argument("--parts", type=int, default=16, help="Parquet parts the edges are cut into")
    ap.add_argument("--real-scheduler", action="store_true",
                    help="a 'dask scheduler' and --workers 'dask worker' processes on 127.0.0.1 and the command line "
                         "'rotgraph solve PARTS --scheduler ADDRESS' instead of a LocalCluster in the benchmark's process")
    ap.add_argument("--limit-mb", type=float, default=None, help="each worker's memory limit in MB (instead of --limit)")
    ap.add_argument("--chunked", action="store_true",
                    help="generate the problems part by part (chunked_problem: graphs whose generation in one process "
                         "would not fit) instead of with rotgraph synth")
    ap.add_argument("--no-single", action="store_true", help="no single-process solve (give --limit-mb)")
    ap.add_argument("--blocks", type=int, default=None, help="rotgraph solve --blocks (default: one a worker)")
    ap.add_argument("--json", dest="json_out", default=None)
    args = ap.parse_args()
    rows = []
    for spec in args.rows.split(","):
        n, d = spec.lower().split("x")
        rows.append(bench_row(int(n), float(d), args))
    print(f"\ncommit {git_commit()}, {cpu_model()}, {usable_cpus()} CPUs, load {load_average()}, {time.strftime('%Y-%m-%d')}")
    head = ["cluster", "n / edges", "single s (MB)", "workers x limit MB", "dist s (x single)", "worker peak MB", "client MB (x single peak)",
            "blocks / cut edges", "rounds / CG products", "median single / dist (ratio)"]
    body = []
    for r in rows:
        single = r["single_s"] is not None
        times = lambda a, b, f: f"{a:{f}} ({a / b:.2f}x)" if single else f"{a:{f}}"  # noqa: E731
        body.append([r["cluster"], f"{r['n']:,} / {r['edges']:,}", f"{r['single_s']:.1f} ({r['single_mb']:.0f})" if single else "-",
                     f"{r['workers']} x {r['limit_mb']:.0f}", times(r["dist_seconds"], r["single_s"], ".1f"),
                     f"{r['dist_worker_peak_mb']:.0f}{' (restarted)' if r['dist_restarted'] else ''}",
                     times(r["dist_client_mb"], r["single_mb"], ".0f"),
                     f"{r['dist_blocks']} / {r['dist_cut_edges']:,}", f"{r['dist_rounds']} / {r['dist_products']}",
                     f"{r['single_median']:.5f} / {r['dist_median']:.5f} ({r['dist_median'] / r['single_median']:.4f})" if single
                     else f"- / {r['dist_median']:.5f}"])
    print(table(head, body))
    if args.json_out:
        Path(args.json_out).write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
