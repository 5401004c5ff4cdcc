"""One view graph solved on Dask distributed: ``rotgraph solve PARTS/ --workers N`` (a local
cluster) or ``--scheduler tcp://HOST:PORT``, the library's :func:`solve_distributed`.

The input is a folder of Parquet parts (:func:`~rotgraph.io.parts.parquet_parts`); each part
is read by a worker, and no edge array ever passes through this process: it holds the
camera-sized arrays (rotations (4, n), updates (n, 3), degrees) and the few thousand
residuals a noise model is fitted on. The stages (docs/algorithms.md, "Distributed solve",
has the design and its convergence; the worker side is :mod:`rotgraph.pipeline.blocks`):

1. **ids and partition** (``partition``; :mod:`rotgraph.pipeline.partition`): each part's
   ``(i, j)`` columns reduced on its worker to camera-sized arrays (its ids, degrees, a
   spanning forest) merged pairwise on the workers: the largest connected component (the one
   solved, as in one process); its cameras cut into ``B`` blocks with few cut edges (METIS by
   pymetis where installed, else reverse Cuthill-McKee runs) on a sample of at most 24 edges a
   camera drawn by the parts.
2. **route** (``route``): each part's edges to the shard that holds them (block ``b``'s
   own edges to shard ``b``, a pair of blocks' cut edges to one of the two); a shard is a
   future on one worker, built from its pieces by pure tasks, so Dask rebuilds it when its
   worker dies.
3. **blocks** (``blocks``): each block's own edges solved by the single-machine default
   (:func:`~rotgraph.estimators.rotation_averaging.average_rotations`, the whole adaptive
   method), in its own gauge.
4. **gauges** (``align``): the cut edges between blocks ``b`` and ``c`` measure their
   relative gauge; the L1 mean of each pair's measurements, then L2 averaging of the block
   graph, put every block in one gauge (``R_i = Q_i W_b``).
5. **refinement** (``l1``, ``graduated``, ``gaussian``, then ``t`` / ``gauss2``): the
   adaptive method's robust stages over the whole graph as map-reduce: each IRLS step the
   client broadcasts the rotations, fits the noise model to residuals sampled on the
   shards, the shards assemble their parts of the weighted Laplacian, and the client runs
   Jacobi-preconditioned conjugate gradients (:func:`~rotgraph.estimators.laplacian.block_pcg`)
   whose matrix products are one exchange with the shards each. Then the model choice of
   the adaptive method (a t or two scales, cross-validated on the sample). The client's side
   of this stage is :mod:`rotgraph.pipeline.distributed_refine`.
6. **finish**: outlier flags (each shard writes its part of ``edges_out``), cameras whose
   every edge is an outlier left out; the CSV written here (camera-sized).
"""

from __future__ import annotations

import contextlib
import logging
import os
import time
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

from .. import so3_rows
from ..errors import InputError, OptionError, UnsolvableError
from . import blocks as bk
from ..estimators.types import Callback, SolveOptions
from .distributed_refine import _refine, _weigh_information
from .cluster import QuietDask, close_cluster, import_distributed, open_cluster, quiet_worker_config, sigint_deferred
from .partition import pairwise, plan_tasks

__all__ = ["solve_distributed", "worker_memory_config", "DISTRIBUTED_MISSING", "DISTRIBUTED_STAGES"]

logger = logging.getLogger(__name__)

DISTRIBUTED_MISSING = ("rotgraph solve --workers / --scheduler needs Dask distributed: pip install 'rotgraph[distributed]' "
                       "(or pip install 'dask[distributed]')")
#: The stages reported to the progress callback, in order (``callback(stage, iteration, step)``).
DISTRIBUTED_STAGES = ("partition", "route", "blocks", "align", "l1", "graduated", "gaussian", "gaussian_reseeded", "t", "gauss2", "l2", "finish")
#: Options the distributed solve does not take yet (their single-process meaning needs every
#: edge in one place, or is not written distributed yet): field -> the value it must keep.
#: Times an exchange with the workers is tried when a worker's connection closes under it.
RETRIES = 5
_FIXED = {"method": "adaptive", "init": "auto", "refine": False, "use_weights": False}


def worker_memory_config() -> dict:
    """Dask's memory management for the workers of a distributed solve: no spilling to disk
    (a shard written out and read back at every iteration would cost more than the solve)
    and no pausing (a paused worker holds a shard every other waits for); the nanny still
    stops a worker at 95 % of its memory limit."""
    return {"distributed.worker.memory.target": False, "distributed.worker.memory.spill": False,
            "distributed.worker.memory.pause": False}


#: The name of :func:`_memory_plugin`'s plugin on a scheduler's workers.
MEMORY_PLUGIN = "rotgraph-solve-memory"


def _memory_plugin():
    """A Dask worker plugin that turns off the spilling and pausing of :func:`worker_memory_config`
    on workers rotgraph did not start (``dask worker`` processes with Dask's defaults: spill to
    disk at 70 % of the memory limit, pause at 80 %). A shard is most of its worker's memory: at
    80 % a paused worker never runs the tasks every other shard waits for (the solve hangs), and a
    shard spilled to disk is read back at every exchange. Registered for the solve (a worker that
    joins meanwhile, a dead one's replacement, gets it too) and unregistered after, which puts
    each worker's own settings back; the nanny still stops a worker at 95 % of its limit."""
    from distributed import WorkerPlugin

    class SolveMemory(WorkerPlugin):
        idempotent = False

        def setup(self, worker):
            mm = getattr(worker, "memory_manager", None)
            self.saved = None if mm is None else (mm.memory_spill_fraction, mm.memory_pause_fraction)
            if mm is not None:
                mm.memory_spill_fraction = mm.memory_pause_fraction = False

        def teardown(self, worker):
            mm = getattr(worker, "memory_manager", None)
            if mm is not None and self.saved is not None:
                mm.memory_spill_fraction, mm.memory_pause_fraction = self.saved

    return SolveMemory()


def _check_options(opts: SolveOptions) -> None:
    for field, value in _FIXED.items():
        if getattr(opts, field) != value:
            raise OptionError(f"the distributed solve runs the default method only: {field.replace('_', '-')} "
                              f"{getattr(opts, field)!r} is not available with --workers / --scheduler")


def _parts_of(input_path) -> list[str]:
    from ..io.parts import parquet_parts

    parts = parquet_parts(input_path)
    if not parts:
        raise OptionError(f"--workers / --scheduler solve a folder of Parquet parts (each part read by a worker); "
                          f"{input_path} is none: write the edges as Parquet parts, or solve in one process")
    return [str(p.resolve()) for p in parts]


class _Run:
    """The client's side of one distributed solve: the shards (futures), the exchanges
    counted, the stages' report."""

    def __init__(self, client, opts: SolveOptions, callback: Callback | None):
        self.client, self.opts = client, opts
        self.callback = callback or (lambda stage, iteration, step: None)
        self.rounds = self.products = 0
        self.t0 = time.perf_counter()
        self.stages: list[dict] = []
        self.shards: list = []
        self.information, self.information_report = False, {}  # with information matrices: the shards carry them

    def gather(self, futures):
        self.rounds += 1
        return self._again(lambda: self.client.gather(futures))

    def total(self, futures):
        """The sum of the futures' results (arrays of one shape, or tuples of them), added
        pairwise on the workers (a tree of log2(B) levels, :func:`~rotgraph.pipeline.blocks.add`):
        the client receives one array, not one a shard (B of them, each n x 3, would be B
        times the bytes through the client's network link and memory)."""
        return self.gather([pairwise(lambda a, b: self.client.submit(bk.add, a, b), futures)])[0]

    def map(self, fn, *args):
        """``fn(shard, *args)`` on every shard (where it lives)."""
        return [self.client.submit(fn, sh, *args) for sh in self.shards]

    def scatter(self, a):
        """``a`` (camera-sized) as a future the shards' tasks take: a task that returns it,
        not scattered data, so that the scheduler can compute it again when the worker that
        held it dies (scattered data has no lineage; a broadcast to a worker killed a moment
        ago waited on its address for minutes)."""
        import warnings

        with warnings.catch_warnings():  # (Dask warns of arguments of megabytes: these are the exchange)
            warnings.simplefilter("ignore", UserWarning)
            return self.client.submit(bk.hold, a, pure=False)

    def _again(self, exchange, tries: int = RETRIES):
        """``exchange()``, tried again (up to ``tries`` times) when a worker's connection
        closed under it (a worker died: the scheduler recomputes what it held, from the
        parts, and the nanny starts another)."""
        from distributed.comm.core import CommClosedError

        for k in range(tries):
            try:
                return exchange()
            except (CommClosedError, OSError, TimeoutError) as exc:
                if k == tries - 1:
                    raise
                logger.info("an exchange with the workers failed (%s); again", exc)
                self.client.wait_for_workers(1, timeout=60)

    def mark(self, stage: str, iterations: int, converged: bool, **more) -> None:
        self.stages.append({"stage": stage, "iterations": iterations, "converged": converged,
                            "seconds": time.perf_counter() - self.t0, **more})
        self.callback(stage, max(iterations, 1), float("nan"))


# --------------------------------------------------------------------------- stages 1-2: partition, route


def _setup(run: _Run, parts: list[str], n_blocks: int | None) -> tuple:
    """Stages 1-2: ``(ids, plan, ids future)``; the shards in ``run.shards``."""
    client = run.client
    ij = [client.submit(bk.read_ids, p) for p in parts]
    # each part's ids, merged pairwise: no worker holds more than two parts' distinct ids
    ids_f = pairwise(lambda a, b: client.submit(bk.union_ids, a, b), [client.submit(bk.union_ids, a) for a in ij])
    workers = sorted(client.nthreads())  # (scheduler_info lists only the first few workers)
    B = int(n_blocks or max(1, len(workers)))
    codes = [client.submit(bk.part_codes, a, ids_f) for a in ij]
    del ij
    plan_f = plan_tasks(client.submit, ids_f, B, codes)
    ids, plan = run.gather([ids_f, plan_f])
    del codes
    run.mark("partition", 1, True)
    routes = [client.submit(bk.route, p, k, ids_f, plan_f, run.opts.use_information) for k, p in enumerate(parts)]
    for s in range(B):
        pieces = [client.submit(bk.pick, r, s) for r in routes]
        run.shards.append(client.submit(bk.make_shard, s, ids_f, plan_f, *pieces,
                                        workers=[workers[s % len(workers)]], allow_other_workers=True))
    del routes, pieces
    run.gather(run.map(bk.shard_edges))  # the shards built (an error of the input raised here), not fetched
    run.information = any(run.gather(run.map(bk.has_information)))
    if run.information:  # normalised to a median isotropic precision of 1, the leverages weighted by them
        unit = _weigh_information(run, plan["n_edges"])
        run.information_report = {"information": {"used": True, "median_sigma_deg": float(np.degrees(1.0 / np.sqrt(unit)))}}
    run.mark("route", 1, True)
    return ids, plan, ids_f


# --------------------------------------------------------------------------- stages 3-4: blocks and their gauges


def _block_start(run: _Run, n: int, plan: dict) -> tuple[np.ndarray, dict]:
    """Stages 3-4: every camera's rotation from its block's solve, the blocks in one gauge
    (NaN rows: cameras without a rotation yet), and what the blocks reported."""
    from ..estimators.rotation_averaging import average_rotations
    from ..graph_build import QuaternionRotations
    from ..viewgraph import ViewGraph

    found = run.gather(run.map(bk.solve_block, run.opts))
    q = np.full((4, n), np.nan)
    for r in found:
        q[:, r["nodes"]] = r["q"]
    report = {"block_cameras": [int(r.get("n_cameras", 0)) for r in found], "block_edges": [r["n_edges"] for r in found],
              "block_models": [r["model"] for r in found], "block_iterations": [r["iterations"] for r in found]}
    run.mark("blocks", max(r["iterations"] for r in found), True)
    B = len(run.shards)
    if B > 1:
        qf = run.scatter(q)
        got = run.gather(run.map(bk.gauge_pairs, qf, B))
        pairs = np.concatenate([g[0] for g in got])
        if not len(pairs):
            raise UnsolvableError("no edge joins two solved blocks: the blocks cannot be put in one gauge")
        means, counts = np.concatenate([g[1] for g in got], axis=1), np.concatenate([g[2] for g in got])
        graph = ViewGraph.from_edges(pairs[:, 0], pairs[:, 1], QuaternionRotations(means), counts.astype(np.float64),
                                     node_ids=np.arange(B), codes=True)
        gauges = average_rotations(graph, SolveOptions(method="l2", use_weights=True))
        W = np.full((4, B), np.nan)
        W[:, gauges.solved] = so3_rows.quaternion_rows_from_matrices(gauges.cam_from_world[gauges.solved])
        block = plan["block"]
        inside = block >= 0
        q[:, inside] = so3_rows.qmul_rows(q[:, inside], W[:, block[inside]])
        q[:, ~inside] = np.nan
        report["block_pairs"] = int(len(pairs))
    _fill_missing(run, q, plan["block"] >= 0)
    a = plan["anchor"]
    q = so3_rows.qmul_rows(q, so3_rows.qconj_rows(q[:, a].copy()))
    run.mark("align", 1, True)
    return so3_rows.positive_w_rows(q / np.sqrt((q * q).sum(axis=0))), report


def _fill_missing(run: _Run, q: np.ndarray, inside: np.ndarray) -> None:
    """Cameras of the component without a rotation (not in their block's solved part) take
    one through an edge to a camera with one, until every camera has one (in place). The
    refinement's L1 stage then corrects them."""
    missing = inside & ~np.isfinite(q[0])
    while missing.any():
        got = run.gather(run.map(bk.predict_missing, run.scatter(q)))
        filled = 0
        for cams, pred in got:
            new = missing[cams]
            q[:, cams[new]] = pred[:, new]
            missing[cams[new]] = False
            filled += int(new.sum())
        if not filled:
            raise UnsolvableError(f"{int(missing.sum())} camera(s) of the component cannot be reached from a solved block")


# --------------------------------------------------------------------------- stage 6 and the driver


def _finish(run: _Run, q: np.ndarray, model, flags, ids_f, edges_out) -> dict:
    """Outlier flags and per-camera inlier counts (each shard's part of ``edges_out``
    written by its worker): ``inlier_degree`` (n,), ``n_outliers``, ``cost`` (the negative
    log-likelihood of the standardised residuals under ``model``), ``threshold_deg``."""
    from ..estimators.stage_types import OUTLIER_THRESHOLD_DEG

    threshold = run.opts.outlier_threshold_deg
    by_model = threshold is None and model is not None
    if by_model:
        threshold = float(np.degrees(flags.outlier_threshold()))
    elif threshold is None:
        threshold = OUTLIER_THRESHOLD_DEG
    qf = run.scatter(q)
    got = run.gather(run.map(bk.finish, qf, flags if by_model else None, threshold, ids_f,
                             None if edges_out is None else str(edges_out)))
    cost = None
    if model is not None:
        scored = got if by_model and flags is model else run.gather(run.map(bk.finish, qf, model, threshold, ids_f, None))
        cost = -sum(g["log_likelihood"] for g in scored)
    run.mark("finish", 1, True)
    return {"inlier_degree": sum(g["inlier_degree"] for g in got), "n_outliers": sum(g["n_outliers"] for g in got),
            "cost": cost, "threshold_deg": threshold}


def _solve(run: _Run, parts: list[str], n_blocks: int | None, edges_out) -> dict:
    """Stages 1-6 on the cluster of ``run.client``: the result arrays and report."""
    ids, plan, ids_f = _setup(run, parts, n_blocks)
    n, inside = len(ids), plan["block"] >= 0
    run.anchor, run.degree = plan["anchor"], plan["degree"]
    total = plan["n_edges"]
    q, report = _block_start(run, n, plan)
    info: dict = {"start": "blocks", **run.information_report}
    q, iterations, converged, model, flags = _refine(run, q, inside, total, info)
    done = _finish(run, q, model, flags, ids_f, edges_out)
    rejected = inside & (done["inlier_degree"] == 0)
    if not (inside & ~rejected).any():
        raise UnsolvableError(f"every edge is an outlier (residual > {done['threshold_deg']:g} deg): no camera can be trusted")
    solved = inside & ~rejected
    diagnostics = {**info, **model.describe(), "outlier_threshold_deg": done["threshold_deg"], "distributed": {
        "workers": len(run.client.nthreads()), "blocks": len(run.shards), "partitioner": plan["partitioner"],
        "cut_edges": plan["cut_edges"], "exchange_rounds": run.rounds, "cg_products": run.products, **report,
        "stages": run.stages}}
    return {"ids": ids, "q": q, "solved": solved, "rejected": rejected, "plan": plan, "iterations": iterations,
            "converged": converged, "diagnostics": diagnostics, **done}


def solve_distributed(input_path, output, options: SolveOptions | None = None, *, workers: int | None = None,
                      scheduler: str | None = None, memory_limit=None, blocks: int | None = None,
                      overrides: dict | None = None, callback: Callback | None = None, edges_out=None,
                      overwrite: bool = False, client=None) -> dict:
    """Solve the view graph of a folder of Parquet parts on Dask and write ``output``
    (``id,name,qw,qx,qy,qz``), as :func:`~rotgraph.pipeline.solve.solve_file` does in one
    process: the default (adaptive) method, each stage as work on blocks of cameras plus
    exchanges of camera-sized arrays (module docstring; docs/algorithms.md). Each part is
    read by a worker; this process holds no edge array. The workers read the parts by their
    absolute paths (a shared file system for a remote cluster) and import the same rotgraph.

    Parameters
    ----------
    input_path : str or os.PathLike
        A folder of Parquet parts (:func:`~rotgraph.io.parts.parquet_parts`) with the
        binary edge format's columns and non-negative integer camera ids.
    output : str or os.PathLike
        The rotations CSV (``-``: standard output).
    options : SolveOptions, optional
        Replaces the defaults entirely; ``method``, ``init``, ``refine``, ``use_weights``
        must keep their defaults (:class:`~rotgraph.errors.OptionError` otherwise).
    workers : int, optional
        Size of the local cluster started for the call (default: the CPUs); ignored with
        ``scheduler`` or ``client``.
    scheduler : str, optional
        Address of an existing Dask scheduler (``tcp://host:8786``). Its workers (and those
        of ``client``) neither spill nor pause while the solve runs (:func:`_memory_plugin`;
        their settings are put back after).
    memory_limit : int or str, optional
        Each local worker's memory limit (Dask's: bytes or ``"2GB"``).
    blocks : int, optional
        How many blocks the cameras are cut into (default: one a worker).
    overrides : dict, optional
        Fields of :class:`SolveOptions` on top of the defaults (the options a user set).
    callback : callable, optional
        ``callback(stage, iteration, step_rad)`` through the stages
        (:data:`DISTRIBUTED_STAGES`; ``step_rad`` NaN at a stage's end).
    edges_out : str or os.PathLike, optional
        A folder that receives ``part.<block>.parquet`` (``i, j, residual_deg, inlier``)
        from each worker.
    overwrite : bool, default False
        Replace an existing output that is not rotgraph's own.
    client : distributed.Client, optional
        A client to use (left open), instead of ``scheduler`` or a local cluster.

    Returns
    -------
    dict
        The summary of :func:`~rotgraph.pipeline.solve.solve_file` (the same keys), with
        ``diagnostics["distributed"]``: ``workers``, ``blocks``, ``partitioner``,
        ``cut_edges``, ``exchange_rounds``, ``cg_products``, the blocks' sizes, models and
        iterations, and ``stages``.

    Raises
    ------
    OptionError
        The input is no folder of Parquet parts, or an option the distributed solve does not take.
    InputError
        A bad part (named), or camera ids that are names.
    RotgraphError
        Dask is not installed, or the scheduler cannot be reached.
    UnsolvableError
        The graph cannot be solved.
    KeyboardInterrupt
        Ctrl-C: a local cluster's workers are stopped at once, and it is raised again.
    """
    from ..io.outputs import check_outputs, input_datasets, refuse_input_dataset
    from ..io.writers import write_rotations
    from .solve import default_options

    t0 = time.perf_counter()
    parts = _parts_of(input_path)
    opts = (replace(options, **(overrides or {})) if options is not None
            else default_options("rotgraph", False, **(overrides or {}))).validated()
    _check_options(opts)
    import_distributed(DISTRIBUTED_MISSING)
    check_outputs([output], [input_path], overwrite=overwrite)
    if edges_out is not None:
        refuse_input_dataset(edges_out, input_datasets([input_path]))
        if not overwrite and Path(edges_out).is_dir() and any(Path(edges_out).iterdir()):
            # a folder of someone's files: the parts written there would replace theirs or mix with them
            raise InputError("exists and is not empty (--overwrite writes the edge parts into it)", path=os.fspath(edges_out))
        Path(edges_out).mkdir(parents=True, exist_ok=True)
    cluster = None
    interrupted = False
    with QuietDask():
        try:
            if client is None:
                cluster, client_used = open_cluster(scheduler, workers, {**quiet_worker_config(), **worker_memory_config()},
                                                   memory_limit, "rotgraph solve")
            else:
                client_used = client
            client_used.wait_for_workers(1)
            if cluster is None:  # a scheduler's workers: their memory settings for the solve
                client_used.register_plugin(_memory_plugin(), name=MEMORY_PLUGIN)
            try:
                res = _solve(_Run(client_used, opts, callback), parts, blocks, edges_out)
            finally:
                if cluster is None:
                    with contextlib.suppress(Exception):  # (a scheduler gone: nothing to put back)
                        client_used.unregister_worker_plugin(MEMORY_PLUGIN)
        except KeyboardInterrupt:
            interrupted = True
            raise
        finally:
            if client is None:
                with sigint_deferred():  # a second Ctrl-C does not cut the clean-up short
                    close_cluster(cluster, locals().get("client_used"), interrupted)
    solved = res["solved"]
    write_rotations(output, res["ids"][solved], None, so3_rows.matrices_from_quaternion_rows(res["q"][:, solved]))
    seconds = time.perf_counter() - t0
    plan = res["plan"]
    return {
        "input": input_path, "output": output, "n_cameras": int(len(res["ids"])), "n_edges": plan["n_input_edges"],
        "n_components": plan["n_components"], "n_solved": int(solved.sum()), "n_unsolved": int(len(solved) - solved.sum()),
        "n_rejected": int(res["rejected"].sum()), "n_outliers": int(res["n_outliers"]),
        "outlier_threshold_deg": res["threshold_deg"], "diagnostics": res["diagnostics"], "method": opts.method,
        "options": asdict(opts), "iterations": res["iterations"], "converged": res["converged"], "cost": res["cost"],
        "seconds": seconds, "seconds_read": 0.0, "seconds_solve": seconds, "output_format": "csv",
    }
