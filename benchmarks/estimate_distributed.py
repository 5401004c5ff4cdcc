#!/usr/bin/env python
"""A paper estimate of the distributed solve (#32) on a real cluster, from unit costs measured here.

Run from the repository root (needs a partitioned problem, e.g. bench_distributed.py's)::

    python benchmarks/estimate_distributed.py                                 # measure, then estimate 10^9 edges
    python benchmarks/estimate_distributed.py --parts /tmp/rotgraph_bench_scale/n200000_d100/parts16
    python benchmarks/estimate_distributed.py --costs costs.json --edges 1e9 --cameras 2e7 --workers 100,250

**Measured** (in this process, one core, on shard 0 of the problem cut into 4 blocks, the
functions the workers and the client run): the partition's tasks (:func:`measure_partition`:
per edge the parts' tasks, per camera a level of the merge tree and the serial component and
cut, the cut's peak memory per camera), an IRLS iteration's shard work (:func:`~rotgraph.pipeline.blocks.sample` and
:func:`~rotgraph.pipeline.blocks.weighted_state`), a conjugate-gradient product
(:func:`~rotgraph.pipeline.blocks.state_matvec`); per camera, the client's conjugate-gradient
vector work per product and its rotation update per iteration.

**Assumed** (the options): the counts of IRLS iterations and CG products (measured at 10^6 -
4x10^7 edges on degree-100 random graphs: 10-12 and 60-93), the route and block stages' rates
(from bench_distributed's stage times), the network (``--gbit`` per link, ``--latency-ms`` per
exchange round) and one core a worker.

**The model** (W workers, one shard each; E edges, n cameras): stages partition (the parts'
tasks on E / W edges a worker, then ceil(log2 W) levels of camera-sized merges and the cut of
the sample, <= 12 edges a camera, on one worker: ``c_e E/W + (log2 W c_merge + c_cut) n``
seconds, ``(b_cut + b_cam) n`` bytes on the cut's worker), route and blocks (parallel, E / W
edges a worker), then I iterations and K products:

    T_refine = I * (c_it E/W + c_upd n + bcast(32 n) + reduce(32 n) + rounds_it * lat)
             + K * (c_mv E/W + c_cg n + bcast(24 n) + reduce(24 n) + lat)

``bcast(b)``: the client's array sent to one worker, then fetched by the W - 1 others over that
worker's link (what Dask does today): W b / bandwidth; ``reduce(b)``: the shards' sums
added pairwise on the workers: ceil(log2 W) b / bandwidth. It is an estimate, not a measurement.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import cpu_model, git_commit, load_average, table  # noqa: E402


def forked(fn, *args) -> tuple[float, int]:
    """``fn(*args)`` in a forked child process: its seconds and the bytes its peak RSS rose by
    above its RSS at the start (a fork starts with its peak at its RSS: Linux's ``ru_maxrss``),
    C libraries' memory (METIS's) included, which tracemalloc does not see."""
    import os
    import resource

    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: measure, report, leave at once
        page = os.sysconf("SC_PAGE_SIZE")
        rss0 = int(Path("/proc/self/statm").read_text().split()[1]) * page
        t = time.perf_counter()
        fn(*args)
        seconds = time.perf_counter() - t
        os.write(w, json.dumps([seconds, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 - rss0]).encode())
        os._exit(0)
    os.close(w)
    with os.fdopen(r) as fh:
        got = fh.read()
    os.waitpid(pid, 0)
    seconds, extra = json.loads(got)
    return seconds, int(extra)


def measure_partition(files: list[str], n_blocks: int) -> dict:
    """Stage 1's unit costs (:func:`rotgraph.pipeline.partition.plan_tasks`, its tasks run here one
    after another, each as a worker runs it): the parts' tasks per edge (codes, summary, sample,
    block-pair counts; parallel over the workers), the camera-sized tasks per camera (a merge of
    two summaries, of two parts' ids; the component; the cut on the sample: serial), and the
    cut's memory per camera (:func:`forked`: the task that holds the most, the sample of at most
    ``PARTITION_DEGREE / 2`` edges a camera and METIS's arrays). Also the plan."""
    import numpy as np

    from rotgraph.pipeline import blocks as bk
    from rotgraph.pipeline import partition as pt

    clock = {"edge": 0.0}

    def timed(key, fn, *args):
        t = time.perf_counter()
        out = fn(*args)
        clock[key] = clock.get(key, 0.0) + time.perf_counter() - t
        return out

    try:  # imported before the cut's child is forked: a worker has imported it at the second solve
        import pymetis  # noqa: F401
    except ImportError:
        pass
    pt.partition(np.arange(4), 2, np.array([[0, 1, 2], [1, 2, 3]]))  # the first calls' imports, as a worker has them
    ij = [bk.read_ids(p) for p in files]
    E = sum(a.shape[1] for a in ij)
    uniq = [timed("edge", bk.union_ids, a) for a in ij]
    ids = timed("union", bk.union_ids, uniq[0], uniq[1])
    ids = bk.union_ids(ids, *uniq[2:])
    codes = [timed("edge", bk.part_codes, a, ids) for a in ij]
    del ij, uniq
    summaries = [timed("edge", pt.summarise, c, ids) for c in codes]
    merged = timed("merge", pt.merge, summaries[0], summaries[1])
    root = pt.pairwise(pt.merge, [merged, *summaries[2:]])
    del summaries, merged
    base = timed("serial", pt.component, root)
    del root
    samples = [timed("edge", pt.sample, c, k, base) for k, c in enumerate(codes)]
    cut_s, cut_bytes = forked(pt.cut, base, n_blocks, *samples)
    blocks = pt.cut(base, n_blocks, *samples)
    del samples
    counts = pt.pairwise(np.add, [timed("edge", pt.pair_counts, c, blocks, n_blocks) for c in codes])
    plan = timed("serial", pt.make_plan, base, blocks, counts)
    n = len(ids)
    return {"plan": plan, "edges": E, "partition_s_per_edge": clock["edge"] / E,
            "partition_merge_s_per_camera": (clock["merge"] + clock["union"]) / n,
            "partition_serial_s_per_camera": (clock["serial"] + cut_s) / n, "partition_cut_bytes_per_camera": cut_bytes / n,
            "partition_sample_edges": min(plan["n_edges"], pt.PARTITION_DEGREE * int((plan["block"] >= 0).sum()) // 2)}


def measure(parts: str, n_blocks: int = 4) -> dict:
    """Unit costs on shard 0 of ``parts`` cut into ``n_blocks`` blocks (see the module docstring)."""
    import numpy as np

    from rotgraph.estimators.laplacian import block_pcg
    from rotgraph.estimators.residuals import update_rotations
    from rotgraph.pipeline import blocks as bk
    from rotgraph.pipeline.distributed import _parts_of

    files = _parts_of(parts)
    stage1 = measure_partition(files, n_blocks)
    plan, E_all = stage1.pop("plan"), stage1["edges"]
    ids = bk.union_ids(*(bk.read_ids(p) for p in files))
    routes = [bk.route(p, k, ids, plan, False) for k, p in enumerate(files)]
    pieces = [bk.pick(r, 0) for r in routes]
    del routes
    shard = bk.make_shard(0, ids, plan, *pieces)
    del pieces
    E, n = shard.n_edges, len(ids)
    rng = np.random.default_rng(0)

    def fresh_q():
        q = rng.standard_normal((4, n))
        return q / np.linalg.norm(q, axis=0)

    def best(fn, reps: int = 3) -> float:
        """The least of ``reps`` timings (the machine is shared)."""
        times = []
        for _ in range(reps):
            q = fresh_q()  # a new array: no cached errors
            t = time.perf_counter()
            fn(q)
            times.append(time.perf_counter() - t)
        return min(times)

    # an IRLS iteration on a shard: the residual sample, then the weighted system (the errors
    # computed once: both tasks get the same rotations array)
    def iteration(q):
        bk.sample(shard, q, plan["n_edges"], 0)
        bk.weighted_state(shard, q, ("l1",))

    c_it = best(iteration) / E
    state = bk.weighted_state(shard, fresh_q(), ("l1",))
    P = rng.standard_normal((n - 1, 3))
    c_mv = best(lambda q: bk.state_matvec(state, P), 10) / E

    class Diagonal:  # a free matrix: block_pcg's own vector work alone
        def __init__(self, d):
            self.d = d

        def diagonal(self):
            return self.d

        def __matmul__(self, X):
            return X * self.d[:, None]

    d = 1.0 + 1e-3 * rng.random(n - 1)
    b = rng.standard_normal((n - 1, 3))
    c_cg = best(lambda q: block_pcg(Diagonal(d), b, rtol=1e-300, maxiter=20)) / 20 / n
    x = 1e-3 * rng.standard_normal((n, 3))
    c_upd = best(lambda q: update_rotations(q, x)) / n
    return {**stage1, "parts": str(parts), "edges": E_all, "cameras": n, "shard_edges": E,
            "iteration_s_per_edge": c_it, "product_s_per_edge": c_mv, "client_cg_s_per_camera": c_cg,
            "client_update_s_per_camera": c_upd, "commit": git_commit(), "load": load_average(),
            "date": time.strftime("%Y-%m-%d %H:%M")}


def estimate(c: dict, E: float, n: float, W: int, args) -> dict:
    """The model of the module docstring: seconds per stage, and the bytes and memory."""
    bw = args.gbit * 1e9 / 8
    lat = args.latency_ms / 1e3
    levels = math.ceil(math.log2(W)) if W > 1 else 0
    ew = E / W

    def bcast(b):  # the client's array to one worker (through the scheduler), then to the W - 1 others from it
        return W * b / bw

    def reduce(b):
        return levels * b / bw

    it_work = c["iteration_s_per_edge"] * ew + c["client_update_s_per_camera"] * n + reduce(32 * n) + 4 * lat
    prod_work = c["product_s_per_edge"] * ew + c["client_cg_s_per_camera"] * n + reduce(24 * n) + lat
    it, prod = it_work + bcast(32 * n), prod_work + bcast(24 * n)
    refine = args.iterations * it + args.products * prod
    # the same with a tree broadcast (not implemented: the array copied worker to worker in log2 W levels)
    refine_tree = args.iterations * (it_work + reduce(32 * n)) + args.products * (prod_work + reduce(24 * n))
    return {
        "W": W, "edges_per_worker": ew,
        "partition_s": c["partition_s_per_edge"] * ew + (levels * c["partition_merge_s_per_camera"]
                                                        + c["partition_serial_s_per_camera"]) * n,
        "partition_gb": (c["partition_cut_bytes_per_camera"] + args.worker_bytes_per_camera) * n / 1e9,
        "route_s": args.route_us * 1e-6 * ew, "blocks_s": args.block_us * 1e-6 * ew,
        "product_s": prod, "product_compute_s": c["product_s_per_edge"] * ew, "product_client_s": c["client_cg_s_per_camera"] * n,
        "product_bcast_s": bcast(24 * n), "product_reduce_s": reduce(24 * n), "iteration_s": it,
        "refine_s": refine, "refine_tree_bcast_s": refine_tree,
        "worker_gb": (args.worker_bytes_per_edge * ew + args.worker_bytes_per_camera * n) / 1e9,
        "client_gb": args.client_bytes_per_camera * n / 1e9,
        "bytes_per_product_gb": (W + levels) * 24 * n / 1e9,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--parts", default="/tmp/rotgraph_bench_scale/n200000_d100/parts16",
                    help="a partitioned problem to measure the unit costs on (bench_distributed.py makes it)")
    ap.add_argument("--costs", default=None, help="unit costs of an earlier run (JSON) instead of measuring")
    ap.add_argument("--save", default=None, help="write the measured unit costs here (JSON)")
    ap.add_argument("--edges", type=float, default=1e9)
    ap.add_argument("--cameras", type=float, default=2e7, help="(degree 100, as the measured problems)")
    ap.add_argument("--workers", default="100,250")
    ap.add_argument("--iterations", type=int, default=12, help="IRLS iterations (measured 10-12)")
    ap.add_argument("--products", type=int, default=90, help="CG products (measured 60-93)")
    ap.add_argument("--gbit", type=float, default=10.0, help="network bandwidth per link, Gbit/s")
    ap.add_argument("--latency-ms", type=float, default=40.0,
                    help="per exchange round (measured here: a 5,000-camera solve on 4 dask workers, 17.6 s for 474 exchanges)")
    ap.add_argument("--route-us", type=float, default=4.0, help="route stage, core-us per edge (measured 2.3-4.1)")
    ap.add_argument("--block-us", type=float, default=6.6,
                    help="block stage, core-us per shard edge (one process's rate, 6.6 us/edge at 10^7, on the block's own edges)")
    ap.add_argument("--worker-bytes-per-edge", type=float, default=280.0, help="measured 250-340 (peaks / shard edges)")
    ap.add_argument("--worker-bytes-per-camera", type=float, default=200.0, help="camera-sized arrays a worker holds")
    ap.add_argument("--client-bytes-per-camera", type=float, default=900.0,
                    help="measured 670-870 above ~110 MB of imports (244 MB at 2x10^5 cameras, 808 MB at 8x10^5)")
    args = ap.parse_args()
    c = json.loads(Path(args.costs).read_text()) if args.costs else measure(args.parts)
    if args.save:
        Path(args.save).write_text(json.dumps(c, indent=2))
    print(f"unit costs ({c['commit']}, {cpu_model()}, load {c['load']}, {c['date']}; {c['edges']:,} edges, shard {c['shard_edges']:,}):")
    print(f"  partition {c['partition_s_per_edge'] * 1e9:.0f} ns/edge (the parts' workers), {c['partition_merge_s_per_camera'] * 1e9:.0f} "
          f"ns/camera a merge level, {c['partition_serial_s_per_camera'] * 1e9:.0f} ns/camera serial (component, cut), the cut's "
          f"worker {c['partition_cut_bytes_per_camera']:.0f} bytes/camera above its RSS ({c['partition_sample_edges']:,} sampled edges)")
    print(f"  IRLS iteration {c['iteration_s_per_edge'] * 1e9:.0f} "
          f"ns/edge, CG product {c['product_s_per_edge'] * 1e9:.1f} ns/edge; client: CG {c['client_cg_s_per_camera'] * 1e9:.0f} "
          f"ns/camera a product, update {c['client_update_s_per_camera'] * 1e9:.0f} ns/camera")
    rows = [estimate(c, args.edges, args.cameras, int(w), args) for w in args.workers.split(",")]
    print(f"\nESTIMATE: {args.edges:.0e} edges, {args.cameras:.0e} cameras; {args.iterations} IRLS iterations, {args.products} CG "
          f"products; {args.gbit:g} Gbit/s links, {args.latency_ms:g} ms a round")
    head = ["workers (edges each)", "partition (time; the cut's worker)", "route + blocks", "a CG product: compute / client / bcast / reduce",
            "refinement (tree broadcast)", "whole", "memory: worker / client"]
    body = []
    for r in rows:
        whole = r["partition_s"] + r["route_s"] + r["blocks_s"] + r["refine_s"]
        body.append([f"{r['W']} ({r['edges_per_worker']:.0e})", f"{r['partition_s'] / 60:.0f} min, {r['partition_gb']:.0f} GB",
                     f"{(r['route_s'] + r['blocks_s']) / 60:.1f} min",
                     f"{r['product_compute_s']:.2f} / {r['product_client_s']:.1f} / {r['product_bcast_s']:.1f} / {r['product_reduce_s']:.1f} s",
                     f"{r['refine_s'] / 60:.0f} min ({r['refine_tree_bcast_s'] / 60:.0f} min)", f"{whole / 3600:.1f} h",
                     f"{r['worker_gb']:.1f} / {r['client_gb']:.0f} GB"])
    print(table(head, body))


if __name__ == "__main__":
    main()
