"""A Dask cluster for the length of a call: what ``rotgraph batch`` (many problems) and the
distributed solve (one problem, :mod:`rotgraph.pipeline.distributed`) share.

:func:`open_cluster` connects to an existing scheduler or starts a local cluster of worker
processes (one thread each) with SIGINT blocked in them (:func:`sigint_deferred`: a
terminal's Ctrl-C reaches the client alone, which stops the workers at once,
:func:`stop_local_workers`, and exits 130), Dask's own logging quiet while it runs
(:class:`QuietDask`). Dask is optional: :func:`import_distributed` raises
:class:`~rotgraph.errors.RotgraphError` with the install hint when it is missing.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import threading
import time

from ..errors import RotgraphError

__all__ = ["DASK_MISSING", "import_distributed", "cpu_count", "has_bokeh", "QuietDask", "sigint_deferred",
           "stop_local_workers", "quiet_worker_config", "open_cluster", "close_cluster"]

logger = logging.getLogger(__name__)

DASK_MISSING = "rotgraph batch needs Dask distributed: pip install 'rotgraph[batch]' (or pip install 'dask[distributed]')"


def cpu_count() -> int:
    """The CPUs this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def import_distributed(missing: str = DASK_MISSING):
    """``distributed``, or :class:`~rotgraph.errors.RotgraphError` (``missing``) without it."""
    try:
        import distributed
    except ImportError:
        raise RotgraphError(missing) from None
    return distributed


def has_bokeh() -> bool:
    import importlib.util

    return importlib.util.find_spec("bokeh") is not None


class QuietDask:
    """Dask's own log messages (cluster start and stop, and errors such as a dead worker,
    which the caller reports itself) off while a call runs, unless rotgraph logs at DEBUG
    (``rotgraph --debug`` or ``-vv``); the levels are restored after. ``asyncio`` too: on
    Ctrl-C the client's pending gathers end with ``AllExit``, which asyncio logs as "Task
    exception was never retrieved" with a traceback when they are collected."""

    NAMES = ("distributed", "bokeh", "tornado", "asyncio")

    def __enter__(self):
        self.saved = {n: logging.getLogger(n).level for n in self.NAMES}
        if not logging.getLogger("rotgraph").isEnabledFor(logging.DEBUG):
            for n in self.NAMES:
                logging.getLogger(n).setLevel(logging.CRITICAL)
        return self

    def __exit__(self, *exc):
        for n, level in self.saved.items():
            logging.getLogger(n).setLevel(level)
        return False


@contextlib.contextmanager
def sigint_deferred():
    """Run the block with SIGINT held back; a Ctrl-C that arrives meanwhile is raised as
    KeyboardInterrupt when the block ends (after it, not in the middle of it).

    Two parts. The calling thread blocks SIGINT, so the threads it starts (Dask's IO loop,
    which spawns the worker processes) and the processes those spawn inherit a mask with
    SIGINT blocked: the local cluster's workers never receive a terminal's Ctrl-C and
    never print a KeyboardInterrupt traceback; the client process alone handles it.
    (``multiprocessing``'s resource tracker unblocks SIGINT in the thread that first starts
    it, so it is started here first.) In the main thread, the Python-level handler is also
    swapped for one that only records the signal, since other threads of this process
    (BLAS pools) still receive it; the default handler is restored when the block ends.
    Where signal masks do not exist (Windows) this does nothing.
    """
    if not hasattr(signal, "pthread_sigmask"):
        yield
        return
    with contextlib.suppress(Exception):
        from multiprocessing import resource_tracker

        resource_tracker.ensure_running()
    caught: list[int] = []
    swapped = threading.current_thread() is threading.main_thread() and signal.getsignal(signal.SIGINT) is signal.default_int_handler
    if swapped:
        signal.signal(signal.SIGINT, lambda signum, frame: caught.append(signum))
    old_mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        if swapped:
            signal.signal(signal.SIGINT, signal.default_int_handler)
        signal.pthread_sigmask(signal.SIG_SETMASK, old_mask)  # a pending SIGINT is raised here
    if caught:
        raise KeyboardInterrupt


def stop_local_workers(cluster, timeout: float = 0.5, reason: str = "rotgraph interrupted") -> None:
    """Stop the local cluster's worker processes now: each nanny asks its worker to close
    and kills it after ``0.8 * timeout`` s (a running task cannot be interrupted, only
    killed); returns once the processes are gone. Dask's own close waits ~4 s first."""
    import asyncio

    async def stop():
        nannies = [w for w in list(cluster.workers.values()) if hasattr(w, "close")]
        await asyncio.gather(*(w.close(timeout=timeout, reason=reason) for w in nannies), return_exceptions=True)

    try:
        cluster.sync(stop, callback_timeout=10 * timeout + 5)
    except Exception:  # noqa: BLE001 - cluster.close() afterwards still cleans up
        logger.debug("stopping the workers", exc_info=True)


def quiet_worker_config() -> dict:
    """Dask settings for local workers that run long numpy tasks (see
    ``rotgraph.pipeline.batch``'s local cluster for the measurements):

    * no ``MALLOC_TRIM_THRESHOLD_=65536`` (Dask sets it before starting a worker process, to
      hand freed memory back to the OS): an explicit trim threshold also freezes glibc's mmap
      threshold at 128 KiB, so every large numpy temporary is a fresh mmap, page-faulted
      in and unmapped again - measured 2x slower solves. The workers inherit this
      process's environment instead (set the variable yourself to keep it).
    * no statistical profiler (it samples the task thread every 10 ms for the dashboard).
    * fewer housekeeping wake-ups (event-loop tick 20 ms -> 500 ms, system monitor 500 ms ->
      2 s, memory monitor 100 ms -> 500 ms, no work stealing between one-thread workers).
    """
    return {
        "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
        "distributed.worker.profile.enabled": False,
        "distributed.admin.tick.interval": "500ms",
        "distributed.admin.system-monitor.interval": "2s",
        "distributed.worker.memory.monitor-interval": "500ms",
        "distributed.scheduler.work-stealing": False,
    }


def open_cluster(scheduler: str | None, workers: int | None, config: dict, memory_limit=None, what: str = "rotgraph"):
    """``(cluster or None, client)``: a client of the scheduler at ``scheduler``
    (``workers`` then ignored, with a warning), or of a local cluster of ``workers``
    processes (one thread each; default: the CPUs) started with ``config`` (Dask settings)
    and ``memory_limit`` per worker (Dask's: bytes or "2GB"; None: Dask's share of the
    RAM), SIGINT blocked in them (:func:`sigint_deferred`). Raises RotgraphError when the
    scheduler cannot be reached."""
    distributed = import_distributed()
    t0 = time.perf_counter()
    if scheduler:
        if workers:
            logger.warning("workers=%s ignored: the scheduler at %s brings its own workers", workers, scheduler)
        try:
            return None, distributed.Client(scheduler, timeout="20s", set_as_default=False)
        except (OSError, TimeoutError, ValueError) as exc:
            raise RotgraphError(f"cannot connect to the Dask scheduler at {scheduler}: {exc}") from None
    import dask

    n = int(workers or cpu_count())
    # The worker processes start with SIGINT blocked (they never see Ctrl-C); a Ctrl-C
    # during the start is raised once the cluster exists, which is then closed here (the
    # caller never gets it: left to the interpreter's exit, its shutdown would log there).
    cluster = client = None
    try:
        with sigint_deferred(), dask.config.set(config):
            cluster = distributed.LocalCluster(
                n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
                dashboard_address=":8787" if has_bokeh() else None,
                memory_limit="auto" if memory_limit is None else memory_limit,
                silence_logs=logging.WARNING if logging.getLogger("rotgraph").isEnabledFor(logging.DEBUG) else logging.CRITICAL,
            )
            client = distributed.Client(cluster, set_as_default=False)
    except KeyboardInterrupt:
        with sigint_deferred():
            close_cluster(cluster, client, True)
        raise
    logger.info("%s: local Dask cluster of %d worker processes started in %.2f s", what, n, time.perf_counter() - t0)
    return cluster, client


def close_cluster(cluster, client, interrupted: bool) -> None:
    """Close ``client`` and the local ``cluster`` (None: an existing scheduler's, left
    running), its workers stopped at once when ``interrupted``."""
    t0 = time.perf_counter()
    try:
        if interrupted and cluster is not None:
            stop_local_workers(cluster)
        if client is not None:
            client.close()
    finally:
        if cluster is not None:
            cluster.close()
    logger.info("Dask client%s closed in %.2f s", "" if cluster is None else " and local cluster", time.perf_counter() - t0)
