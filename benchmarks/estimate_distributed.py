#!/usr/bin/env python
"""A paper estimate of the distributed solve (#32) on a real cluster, from unit costs measured here.

Run from the repository root (needs a partitioned problem, e.g. bench_distributed.py's)::

    python benchmarks/estimate_distributed.py                                 # measure, then estimate 10^9 edges
    python benchmarks/estimate_distributed.py --parts /tmp/rotgraph_bench_scale/n200000_d100/parts16
    python benchmarks/estimate_distributed.py --costs costs.json --edges 1e9 --cameras 2e7 --workers 100,250

**Measured** (in this process, one core, on shard 0 of the problem cut into 4 blocks, the
functions the workers and the client run): per edge, the partition (one worker reads every
edge's ids), an IRLS iteration's shard work (:func:`~rotgraph.pipeline.blocks.sample` and
:func:`~rotgraph.pipeline.blocks.weighted_state`), a conjugate-gradient product
(:func:`~rotgraph.pipeline.blocks.state_matvec`); per camera, the client's conjugate-gradient
vector work per product and its rotation update per iteration.

**Assumed** (the options): the counts of IRLS iterations and CG products (measured at 10^6 -
4x10^7 edges on degree-100 random graphs: 10-12 and 60-93), the route and block stages' rates
(from bench_distributed's stage times), the network (``--gbit`` per link, ``--latency-ms`` per
exchange round) and one core a worker.

**The model** (W workers, one shard each; E edges, n cameras): stages partition (one worker,
serial), route and blocks (parallel, E / W edges a worker), then I iterations and K products:

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


def measure(parts: str, n_blocks: int = 4) -> dict:
    """Unit costs on shard 0 of ``parts`` cut into ``n_blocks`` blocks (see the module docstring)."""
    import numpy as np

    from rotgraph.estimators.laplacian import block_pcg
    from rotgraph.estimators.residuals import update_rotations
    from rotgraph.pipeline import blocks as bk
    from rotgraph.pipeline.distributed import _parts_of

    files = _parts_of(parts)
    ij = [bk.read_ids(p) for p in files]
    E_all = sum(a.shape[1] for a in ij)
    t = time.perf_counter()
    ids = bk.union_ids(*ij)
    plan = bk.partition(ids, n_blocks, *(bk.part_codes(a, ids) for a in ij))
    t_part = time.perf_counter() - t
    del ij
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
    return {"parts": str(parts), "edges": E_all, "cameras": n, "shard_edges": E, "partition_s_per_edge": t_part / E_all,
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
        "partition_s": c["partition_s_per_edge"] * E, "partition_gb": args.partition_bytes_per_edge * E / 1e9,
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
    ap.add_argument("--partition-bytes-per-edge", type=float, default=77.0,
                    help="the partition worker's memory: measured 69 bytes an edge above its 8 of codes (tracemalloc, 10^7 edges)")
    ap.add_argument("--worker-bytes-per-edge", type=float, default=280.0, help="measured 250-340 (peaks / shard edges)")
    ap.add_argument("--worker-bytes-per-camera", type=float, default=200.0, help="camera-sized arrays a worker holds")
    ap.add_argument("--client-bytes-per-camera", type=float, default=900.0,
                    help="measured 670-870 above ~110 MB of imports (244 MB at 2x10^5 cameras, 808 MB at 8x10^5)")
    args = ap.parse_args()
    c = json.loads(Path(args.costs).read_text()) if args.costs else measure(args.parts)
    if args.save:
        Path(args.save).write_text(json.dumps(c, indent=2))
    print(f"unit costs ({c['commit']}, {cpu_model()}, load {c['load']}, {c['date']}; {c['edges']:,} edges, shard {c['shard_edges']:,}):")
    print(f"  partition {c['partition_s_per_edge'] * 1e9:.0f} ns/edge (one worker), IRLS iteration {c['iteration_s_per_edge'] * 1e9:.0f} "
          f"ns/edge, CG product {c['product_s_per_edge'] * 1e9:.1f} ns/edge; client: CG {c['client_cg_s_per_camera'] * 1e9:.0f} "
          f"ns/camera a product, update {c['client_update_s_per_camera'] * 1e9:.0f} ns/camera")
    rows = [estimate(c, args.edges, args.cameras, int(w), args) for w in args.workers.split(",")]
    print(f"\nESTIMATE: {args.edges:.0e} edges, {args.cameras:.0e} cameras; {args.iterations} IRLS iterations, {args.products} CG "
          f"products; {args.gbit:g} Gbit/s links, {args.latency_ms:g} ms a round")
    head = ["workers (edges each)", "partition (1 worker)", "route + blocks", "a CG product: compute / client / bcast / reduce",
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
