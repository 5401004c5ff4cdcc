#!/usr/bin/env python
"""Stage 1 of the distributed solve (#32), the partition, on a local Dask cluster: the peak
memory of the worker that holds the most, the stage's time, and the cut.

Run from the repository root (the parts as ``bench_distributed.py`` writes them)::

    python benchmarks/bench_partition.py --parts /tmp/rotgraph_bench_scale/n200000_d100/parts16
    python benchmarks/bench_partition.py --parts A,B --workers 4 --blocks 4 --json out.json

For each folder of parts, in a process of its own: a local cluster of ``--workers`` worker
processes (one thread each, no memory limit), each worker's peak RSS after its imports
(``getrusage`` in the worker: the baseline), then stages 1-2 of the solve as
:func:`rotgraph.pipeline.distributed.solve_distributed` runs them (``_setup``): at the end of
stage 1 (``partition``: ids, components, degrees, the cut, the blocks' edge counts) each
worker's peak RSS and the stage's time; the plan's cut edges and partitioner once stage 2 has
routed the edges. The same script measured the code before and after the partition was spread
over the parts (benchmarks/README.md).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import cpu_model, git_commit, load_average, table  # noqa: E402

CHILD = """
import json, resource, sys, time
if __name__ == "__main__":
    import dask, distributed
    from rotgraph.estimators.types import SolveOptions
    from rotgraph.pipeline import distributed as dist
    from rotgraph.pipeline.cluster import quiet_worker_config
    parts, workers, blocks = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])

    def peaks(client):
        return sorted(client.run(lambda: resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024).values())

    def warm():
        import pyarrow.parquet, scipy.sparse.csgraph, rotgraph.pipeline.blocks  # noqa: F401  (the imports: baseline)

    with dask.config.set({**quiet_worker_config(), **dist.worker_memory_config()}):
        cluster = distributed.LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                                           host="127.0.0.1", memory_limit=0)
        client = distributed.Client(cluster)
    client.run(warm)
    base = peaks(client)
    got = {}

    def mark(stage, it, step):
        if stage == "partition" and "seconds" not in got:
            got["seconds"] = time.perf_counter() - t0
            got["peaks"] = peaks(client)

    run = dist._Run(client, SolveOptions(), mark)
    t0 = time.perf_counter()
    ids, plan, _ = dist._setup(run, dist._parts_of(parts), blocks)
    client.close(); cluster.close()
    print(json.dumps({"seconds": got["seconds"], "base_mb": base, "peaks_mb": got["peaks"], "cut_edges": plan["cut_edges"],
                      "n_edges": plan["n_edges"], "n_cameras": len(ids), "partitioner": plan["partitioner"],
                      "counts": [int(c) for c in plan["counts"].diagonal()]}))
"""


def measure(parts: str, workers: int, blocks: int) -> dict:
    p = subprocess.run([sys.executable, "-c", CHILD, parts, str(workers), str(blocks)], capture_output=True, text=True)
    if p.returncode:
        raise RuntimeError(f"the partition of {parts} failed ({p.returncode}): {p.stderr[-2000:]}")
    return {"parts": parts, **json.loads(p.stdout.strip().splitlines()[-1])}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--parts", default="/tmp/rotgraph_bench_scale/n200000_d100/parts16", help="folders of parts, comma-separated")
    ap.add_argument("--workers", type=int, default=4)
    ap.add_argument("--blocks", type=int, default=4)
    ap.add_argument("--json", default=None, help="write the rows here")
    args = ap.parse_args()
    rows = [measure(p, args.workers, args.blocks) for p in args.parts.split(",")]
    print(f"rotgraph {git_commit()}, {cpu_model()}, load {load_average()}; {args.workers} workers, {args.blocks} blocks")
    head = ["parts", "cameras / edges", "stage 1 s", "largest worker peak MB (after imports)", "worker peaks MB", "cut edges",
            "partitioner"]
    body = [[Path(r["parts"]).parent.name + "/" + Path(r["parts"]).name, f"{r['n_cameras']:,} / {r['n_edges']:,}",
             f"{r['seconds']:.1f}", f"{max(r['peaks_mb']):.0f} ({max(r['base_mb']):.0f})",
             " ".join(f"{x:.0f}" for x in r["peaks_mb"]), f"{r['cut_edges']:,} ({r['cut_edges'] / r['n_edges']:.1%})",
             r["partitioner"]] for r in rows]
    print(table(head, body))
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
