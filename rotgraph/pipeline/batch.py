"""Many rotation-averaging problems at once, on Dask distributed (``rotgraph batch``).

:func:`solve_many` turns its inputs into problems (one view graph each), sends one task per
problem to a Dask cluster and collects a manifest. The same code path runs on a local
cluster started for the call (``distributed.LocalCluster``: worker processes, one thread
each) and on an existing ``dask scheduler`` (``scheduler="tcp://host:8786"``).

Each task runs :func:`rotgraph.pipeline.solve.solve_file` - exactly what ``rotgraph solve``
runs - in a worker, which writes ``OUT_DIR/<stem>.csv`` atomically as soon as its problem
is solved. The client rewrites ``OUT_DIR/manifest.json`` and ``OUT_DIR/summary.csv``
(atomically) as results arrive, so an interrupted batch leaves a valid manifest and every
finished output, and ``resume=True`` picks up where it stopped.

Ctrl-C (SIGINT to the process group, as a terminal sends it) stops a batch promptly: the
local cluster's processes never see SIGINT (they are started with it blocked, see
:func:`_sigint_deferred`), so no worker prints a traceback; the client cancels the
futures, stops the workers at once (a running solve is killed, its temporary file removed)
and writes the manifest as the disk has it - a problem whose output this run wrote
completely is ``ok``, the others ``failed`` with the error ``interrupted`` - then
:func:`solve_many` re-raises the KeyboardInterrupt (the CLI exits 130).

Requirements of a remote cluster: the workers import ``rotgraph`` (same version as the
client) and see the inputs and ``out_dir`` under the same absolute paths as the client
(a shared file system); tasks carry absolute paths, never data.

Dask is optional (``pip install 'rotgraph[batch]'``); without it :func:`solve_many`
raises :class:`~rotgraph.errors.RotgraphError` saying so.
"""

from __future__ import annotations

import contextlib
import csv
import json
import logging
import os
import time
import uuid
from collections.abc import Callable, Mapping
from pathlib import Path

from .. import __version__
from ..errors import InputError, OptionError, RotgraphError
from ..io.writers import json_safe
from ..estimators.rotation_averaging import SolveOptions
from .cluster import DASK_MISSING, QuietDask as _QuietDask, cpu_count as _cpu_count, has_bokeh as _has_bokeh
from .cluster import import_distributed as _import_distributed, quiet_worker_config
from .cluster import sigint_deferred as _sigint_deferred, stop_local_workers
from .inputs import MANIFEST, Problem, SUMMARY, expand_inputs, list_file, output_names

__all__ = ["solve_many", "solve_task", "expand_inputs", "output_names", "Problem", "MANIFEST_KEYS", "DASK_MISSING"]

logger = logging.getLogger(__name__)


#: The keys of every manifest entry (CLI.md requires the first nine).
MANIFEST_KEYS = (
    "input", "output", "status", "error", "n_cameras", "n_edges", "n_solved", "n_outliers", "seconds",
    "eval_median_deg", "eval_mean_deg", "input_path", "error_type", "n_components", "n_unsolved",
    "iterations", "converged", "cost", "method", "seconds_read", "seconds_solve", "eval", "worker", "request",
    "certified", "certificate",
)
SUMMARY_COLUMNS = ("input", "output", "status", "error", "n_cameras", "n_edges", "n_solved", "n_outliers", "seconds",
                   "eval_median_deg", "eval_mean_deg", "certified")

# =========================================================================== manifest entries


def _entry(display: str, output, **values) -> dict:
    e = {k: None for k in MANIFEST_KEYS}
    e.update(input=display, output=output)
    e.update(values)
    return e


def _one_line(exc: BaseException) -> str:
    if isinstance(exc, RotgraphError):
        msg = str(exc)
    elif isinstance(exc, MemoryError):
        msg = "out of memory"
    else:
        msg = f"unexpected {type(exc).__name__}: {exc}"
    return " ".join(msg.split()) or type(exc).__name__


def _write_manifest(out_dir: Path, entries: list[dict]) -> None:
    from ..io.atomic import atomic_write

    clean = [json_safe(e) for e in entries]
    with atomic_write(out_dir / MANIFEST) as fh:
        json.dump(clean, fh, indent=2)
        fh.write("\n")
    with atomic_write(out_dir / SUMMARY) as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(SUMMARY_COLUMNS)
        for e in clean:
            w.writerow(["" if e.get(c) is None else e.get(c) for c in SUMMARY_COLUMNS])


def _load_manifest(out_dir: Path) -> dict[str, dict]:
    """Previous entries by absolute input path (empty when there is no readable manifest)."""
    try:
        old = json.loads((out_dir / MANIFEST).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    if not isinstance(old, list):
        return {}
    return {e["input_path"]: e for e in old if isinstance(e, dict) and isinstance(e.get("input_path"), str)}


def _input_mtime(p: Path) -> float:
    """Modification time of an input; for a folder the newest file in it (scene folders)."""
    if not p.is_dir():
        return p.stat().st_mtime
    newest = p.stat().st_mtime
    for k, (root, _, files) in enumerate(os.walk(p)):
        if k > 50:
            break
        for f in files:
            try:
                newest = max(newest, os.stat(os.path.join(root, f)).st_mtime)
            except OSError:
                pass
    return newest


def _request(options, overrides, fmt, duplicates, gt, columns, certify: bool = False) -> dict:
    """What a problem was asked to be solved with (the manifest's ``request``): ``--resume``
    skips a problem only when its earlier entry holds the same."""
    from dataclasses import asdict

    request = {"options": asdict(options) if options is not None else None, "overrides": dict(overrides or {}),
               "format": fmt, "duplicates": duplicates, "columns": columns, "gt": gt, "version": __version__}
    if certify:  # (absent when not asked: earlier manifests stay resumable)
        request["certify"] = True
    return json.loads(json.dumps(json_safe(request), sort_keys=True, default=str))


def _output_complete(out: Path, previous: dict | None) -> dict | None:
    """What is known of a complete output: the earlier manifest entry when it says ok for
    this output, else ``{"n_solved": rows}`` when the CSV parses; None when incomplete."""
    if previous is not None and previous.get("status") in ("ok", "skipped") and previous.get("output") and Path(previous["output"]).name == out.name:
        return {k: previous.get(k) for k in MANIFEST_KEYS if k not in ("input", "output", "status", "error", "seconds")}
    from ..io.rotations import read_absolute_rotations

    try:
        ids, _, _ = read_absolute_rotations(out, "csv")
    except (RotgraphError, OSError, ValueError):
        return None
    return {"n_solved": int(len(ids))}


# =========================================================================== ground truth


def _gt_path(gt, problem: Problem) -> str | None:
    if gt is None or gt is False:
        return None
    if callable(gt):
        r = gt(problem.input)
    elif isinstance(gt, Mapping):
        r = gt.get(problem.input, gt.get(str(problem.path)))
    else:
        p = problem.path
        folder = p if p.is_dir() else p.parent
        r = os.fspath(gt).format(dir=str(folder), parent=folder.name, stem=p.stem, name=p.name)
    if r is None:
        return None
    r = Path(os.fspath(r)).expanduser()
    return str(r if r.is_absolute() else Path.cwd() / r)


# =========================================================================== the task


def solve_task(job: dict) -> dict:
    """Solve one problem (runs in a Dask worker): write its CSV atomically, return its
    manifest entry. Never raises: any error becomes ``status="failed"`` with a one-line
    message, and the output an earlier run wrote stays as it was (the output rule)."""
    from .solve import evaluate_files, solve_file

    t0 = time.perf_counter()
    opts = job["options"]
    entry = _entry(job["input"], None, input_path=job["path"], method=opts.method if opts is not None else job.get("method"),
                   request=job.get("request"))
    try:
        from distributed import get_worker

        entry["worker"] = get_worker().address
    except Exception:  # not in a worker (direct call) or distributed absent
        entry["worker"] = None
    try:
        s = solve_file(job["path"], job["output_path"], opts, fmt=job["fmt"], duplicates=job["duplicates"],
                       overrides=job.get("overrides"), overwrite=job.get("overwrite", False), columns=job.get("columns"),
                       certify=job.get("certify", False))  # large arrays on the heap (pipeline.heap)
        for k in ("method", "n_cameras", "n_edges", "n_components", "n_solved", "n_unsolved", "n_outliers", "iterations",
                  "converged", "cost", "seconds_read", "seconds_solve"):
            entry[k] = s[k]
        if "certificate" in s:  # solve --certify's final stage and its verdict
            entry.update(certified=bool(s["certificate"]["certified"]), certificate=s["certificate"])
        entry.update(status="ok", output=job["output"])
        ev = None
        gt = job.get("gt")
        if gt and (os.path.exists(gt) or s.get("eval") is None):
            try:
                ev = evaluate_files(job["output_path"], gt).to_dict()
                ev["gt"] = gt
            except Exception as exc:  # the problem is solved: report, do not fail it
                entry["eval"] = {"error": _one_line(exc), "gt": gt}
        elif job.get("eval", True):
            ev = s.get("eval")  # the ground truth the input carries, if any
        if ev is not None:
            entry.update(eval=ev, eval_median_deg=ev["median"], eval_mean_deg=ev["mean"])
    except BaseException as exc:  # noqa: BLE001 - one problem never stops the batch
        if isinstance(exc, (KeyboardInterrupt, SystemExit)):
            raise
        entry.update(status="failed", output=None, error=_one_line(exc), error_type=type(exc).__name__)
    entry["seconds"] = time.perf_counter() - t0
    return entry


# =========================================================================== progress


class _Silent:
    """The progress callback when none is given."""

    def __call__(self, event: str, value=None) -> None:
        pass


# =========================================================================== interrupts


def _temp_files_of(out: Path) -> list[Path]:
    """The temporary files :func:`~rotgraph.io.atomic.atomic_write` makes for ``out``."""
    try:
        return [out.parent / e.name for e in os.scandir(out.parent)
                if e.name.startswith(f".{out.name}.") and e.name.endswith(".tmp")]
    except OSError:
        return []


def _written_in_this_run(out: Path, since_ns: int) -> dict | None:
    """What a complete output written by this run tells (``{"n_solved": rows}``), or None:
    the file exists, is not older than the run's first manifest and parses."""
    try:
        if out.stat().st_mtime_ns < since_ns:
            return None
    except OSError:
        return None
    return _output_complete(out, None)


# =========================================================================== Dask


def _dashboard_link(client) -> str | None:
    """The scheduler's dashboard URL when it serves one (it needs bokeh on the scheduler)."""
    try:
        info = client.scheduler_info()
        if "dashboard" not in info.get("services", {}):
            return None
        if not client.run_on_scheduler(lambda: __import__("importlib.util").util.find_spec("bokeh") is not None):
            logger.info("the Dask dashboard needs bokeh on the scheduler: pip install 'bokeh>=3.1'")
            return None
        return client.dashboard_link or None
    except Exception:
        return None


def _local_cluster_config() -> dict:
    """Dask settings for the workers of the local cluster: :func:`~.cluster.quiet_worker_config`
    (they run one long numpy task each), and no retries of a problem whose worker died: with
    one thread a worker, the death is that problem's (typically out of memory: Dask's nanny
    stops a worker at 95 % of its share of the RAM), and running it again would only kill
    the next worker."""
    return {**quiet_worker_config(), "distributed.scheduler.allowed-failures": 0}


def _run_on_dask(jobs: list[dict], scheduler, workers, on_result, progress) -> None:
    with _QuietDask():
        _run_on_dask_inner(jobs, scheduler, workers, on_result, progress)


def _submit(client, jobs: list[dict], futures: list) -> dict:
    """Submit every job, largest inputs first, appending each future to ``futures`` as it
    goes (so that an interrupted submission cancels what it made); returns future key ->
    job."""
    by_key = {}
    # Largest inputs first: the longest problems start early (better load balance).
    order = sorted(range(len(jobs)), key=lambda k: -jobs[k]["size"])
    run = uuid.uuid4().hex[:8]
    for rank, k in enumerate(order):
        job = jobs[k]
        key = f"rotgraph-solve-{Path(job['output']).stem}-{run}"
        fut = client.submit(solve_task, job, key=key, pure=False, priority=len(order) - rank, retries=0)
        futures.append(fut)
        by_key[fut.key] = job
    return by_key


def _worker_failure(job: dict, exc: BaseException) -> dict:
    """The manifest entry of a job whose task did not finish (a worker died or could not run it)."""
    msg = _one_line(exc)
    if type(exc).__name__ == "KilledWorker":
        msg = "the worker running this problem died (out of memory?); see https://distributed.dask.org/en/stable/killed.html"
    return _entry(job["input"], None, input_path=job["path"], status="failed", error=msg,
                  error_type=type(exc).__name__, method=job.get("method"), seconds=None)


def _report_finished(futures: list, reported: set, on_result) -> None:
    """Results already computed but not yet collected are reported as they are."""
    for fut in futures:
        if fut.key not in reported and fut.status == "finished":
            with contextlib.suppress(Exception):
                entry = fut.result(timeout=2)
                reported.add(fut.key)
                on_result(entry)


def _close_dask(cluster, client, jobs: list[dict], interrupted: bool) -> None:
    """Close the client and the local cluster (its workers stopped at once when
    ``interrupted``) and remove the temporary files of workers killed while writing."""
    t_close = time.perf_counter()
    try:
        if interrupted and cluster is not None:
            stop_local_workers(cluster, reason="rotgraph batch interrupted")
        if client is not None:
            client.close()
    finally:
        if cluster is not None:
            cluster.close()
            # A worker killed while writing leaves its temporary file: remove it.
            for job in jobs:
                for tmp in _temp_files_of(Path(job["output_path"])):
                    with contextlib.suppress(OSError):
                        tmp.unlink()
    logger.info("Dask client%s closed in %.2f s", "" if cluster is None else " and local cluster", time.perf_counter() - t_close)


def _run_on_dask_inner(jobs: list[dict], scheduler, workers, on_result, progress) -> None:
    distributed = _import_distributed()
    cluster = client = None
    t_start = time.perf_counter()
    futures = []
    reported: set = set()
    interrupted = False
    try:
        if scheduler:
            if workers:
                logger.warning("workers=%s ignored: the scheduler at %s brings its own workers", workers, scheduler)
            try:
                client = distributed.Client(scheduler, timeout="20s", set_as_default=False)
            except (OSError, TimeoutError, ValueError) as exc:
                raise RotgraphError(f"cannot connect to the Dask scheduler at {scheduler}: {exc}") from None
        else:
            import dask

            n = min(int(workers or _cpu_count()), len(jobs))
            # The worker processes start with SIGINT blocked (they never see Ctrl-C); a
            # Ctrl-C during the start is raised once the cluster exists (and is closed).
            with _sigint_deferred(), dask.config.set(_local_cluster_config()):
                cluster = distributed.LocalCluster(
                    n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
                    dashboard_address=":8787" if _has_bokeh() else None,
                    silence_logs=logging.WARNING if logging.getLogger("rotgraph").isEnabledFor(logging.DEBUG) else logging.CRITICAL,
                )
                client = distributed.Client(cluster, set_as_default=False)
            logger.info("local Dask cluster: %d worker processes started in %.2f s", n, time.perf_counter() - t_start)
        link = _dashboard_link(client)
        if link:
            progress("note", f"rotgraph batch: Dask dashboard at {link}")
        if scheduler and not client.scheduler_info().get("workers"):
            progress("note", f"rotgraph batch: the scheduler at {scheduler} has no workers yet; waiting for them")
        by_key = _submit(client, jobs, futures)
        progress("running", None)
        for fut in distributed.as_completed(futures, loop=client.loop):
            job = by_key[fut.key]
            if fut.status == "finished":
                entry = fut.result()
            else:  # the task itself never raises: a worker died or could not run it
                entry = _worker_failure(job, fut.exception())
            reported.add(fut.key)
            fut.release()
            on_result(entry)
    except BaseException as exc:
        interrupted = isinstance(exc, KeyboardInterrupt)
        with _sigint_deferred():  # a second Ctrl-C does not cut the clean-up short
            if futures and client is not None:
                _report_finished(futures, reported, on_result)
                with contextlib.suppress(Exception):
                    client.cancel(futures)
        raise
    finally:
        with _sigint_deferred():
            _close_dask(cluster, client, jobs, interrupted)


# =========================================================================== driver


def _make_out_dir(out: Path) -> Path:
    """Make the output folder ``out`` (InputError when it is a file or cannot be made)."""
    try:
        out.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise InputError("output folder is a file", path=str(out)) from None
    except OSError as exc:
        reason = "permission denied" if isinstance(exc, PermissionError) else (exc.strerror or str(exc)).lower()
        raise InputError(f"cannot write here: {reason}", path=str(out)) from None
    return out


def _output_names_checked(inputs, out: Path, problems: list[Problem], gt, overwrite: bool) -> dict:
    """Input path -> output name of every readable problem, after the output rule for every
    problem, before any work: no output is an input, no file of the user's is replaced."""
    from ..io.outputs import check_outputs

    names = dict(zip([pr.path for pr in problems], output_names(problems)))
    lists = [lf for lf in map(list_file, [inputs] if isinstance(inputs, (str, os.PathLike)) else inputs) if lf is not None]
    gts = [g for g in (_gt_path(gt, pr) for pr in problems) if g is not None]
    check_outputs([out / MANIFEST, out / SUMMARY] + [out / names[pr.path] for pr in problems],
                  [pr.path for pr in problems] + lists + gts, overwrite=overwrite)
    return names


def _kept_output(pr: Problem, out_path: Path, prev: dict | None, request: dict) -> dict | None:
    """With ``resume``: the manifest values of the problem ``pr``'s earlier output when it is
    kept (the same request, ok, complete and newer than the input), else None."""
    if not (out_path.is_file() and prev is not None and prev.get("request") == request
            and prev.get("status") in ("ok", "skipped")):
        return None
    try:
        newer = out_path.stat().st_mtime >= _input_mtime(pr.path)
    except OSError:
        newer = False
    kept = _output_complete(out_path, prev) if newer else None
    if kept is not None:
        kept.update(input_path=str(pr.path), request=request)
    return kept


def _input_size(path: Path) -> int:
    """Bytes of the input file (or of a folder's files): the order of the jobs."""
    try:
        return path.stat().st_size if path.is_file() else sum(f.stat().st_size for f in path.iterdir() if f.is_file())
    except OSError:
        return 0


def _settle_pending(entries: list[dict], jobs: list[dict], run_start_ns: int, exc: BaseException) -> None:
    """A stopped batch's pending entries: ok when the output was written in this run (it
    finished while the batch was being stopped), else failed (interrupted or not run)."""
    outputs = {j["path"]: j for j in jobs}
    for k, e in enumerate(entries):
        if e["status"] != "pending":
            continue
        job = outputs[e["input_path"]]
        done = _written_in_this_run(Path(job["output_path"]), run_start_ns)
        if done is not None:  # finished while the batch was being stopped: it is ok
            entries[k] = dict(e, **done, status="ok", output=job["output"], error=None)
        else:
            entries[k] = dict(e, status="failed", error="interrupted" if isinstance(exc, KeyboardInterrupt) else f"not run: {_one_line(exc)}",
                              error_type=type(exc).__name__)


def solve_many(
    inputs,
    out_dir,
    options: SolveOptions | None = None,
    *,
    overrides: dict | None = None,
    fmt: str = "auto",
    duplicates: str = "error",
    workers: int | None = None,
    scheduler: str | None = None,
    resume: bool = False,
    progress: Callable[[str, object], None] | None = None,
    gt=None,
    overwrite: bool = False,
    columns=None,
    certify: bool = False,
) -> list[dict]:
    """Solve many problems on Dask; return the manifest (one entry per problem).

    ``inputs``: paths, folders, glob patterns or ``@LIST`` files (see :func:`expand_inputs`).
    Outputs go to ``out_dir/<stem>.csv`` (see :func:`output_names`), each exactly the file
    ``rotgraph solve INPUT -o OUT`` writes with the same ``options`` (None: the defaults
    of each input's format, see :func:`~rotgraph.pipeline.solve.default_options`),
    ``overrides`` (options the user set, on top), ``fmt``, ``duplicates`` and ``columns`` (as
    :func:`~rotgraph.pipeline.read.read_view_graph`); ``out_dir/manifest.json`` and ``out_dir/summary.csv`` hold one entry
    per problem, in input order, with ``status`` ``ok``, ``failed`` or ``skipped`` (while a
    batch runs, unfinished problems are ``pending``; an interrupted batch marks them
    ``failed`` with the error ``interrupted``).

    ``workers``: size of the local cluster (default: the CPUs this process may use, at
    most one per problem). ``scheduler``: address of an existing Dask scheduler
    (``tcp://host:8786``) instead of a local cluster; ``workers`` is then ignored.
    ``resume``: skip problems whose output exists, is complete, is newer than the input and
    whose earlier manifest entry says ok with the same request (options, overrides, format,
    duplicates, columns, ground truth and rotgraph version: its ``request`` key); the others are
    solved again. ``progress(event, value)``
    follows the run: ``("start", number of problems to solve)``, ``("note", text)`` (the
    dashboard link, waiting for workers), ``("running", None)``, ``("result", manifest
    entry)`` as each problem ends, ``("close", None)``. ``gt``: ground truth for the evaluation -
    None evaluates against the ground truth the input carries (``.mat`` ``Rgt``, 1DSfM
    ``gt_bundle.out``, as ``rotgraph solve`` does); False never evaluates; a template
    string with ``{dir}``, ``{parent}``, ``{stem}``, ``{name}`` of the input (e.g.
    ``"{dir}/gt.txt"`` for ``rotgraph synth`` folders), a mapping input -> file or a
    callable input -> file (or None) names a ground-truth file per problem (when that file
    does not exist, the input's own ground truth is used, if it has one). ``certify``: each
    problem as ``rotgraph solve --certify`` (its CSV holds the certified rotations; its entry
    ``certified`` and ``certificate``).

    The outputs follow the output rule (:func:`~rotgraph.io.outputs.check_outputs`), checked for
    every problem before any work: an output that would be one of the inputs, or an
    existing file that is not rotgraph's own earlier output (unless ``overwrite``), is an
    :class:`~rotgraph.errors.InputError`, and nothing is written; a problem that fails
    leaves the output an earlier run wrote as it was.

    Raises :class:`~rotgraph.errors.RotgraphError` when Dask is not installed or the
    scheduler cannot be reached, :class:`~rotgraph.errors.OptionError` when the inputs name
    no problem at all (nothing to do); problems that fail are reported in the manifest.
    """
    from ..io.outputs import check_outputs, input_datasets, refuse_input_dataset

    method = (options or SolveOptions(**(overrides or {}))).validated().method
    _import_distributed()  # fail early, before touching out_dir, when Dask is missing
    inputs = [inputs] if isinstance(inputs, (str, os.PathLike)) else list(inputs)
    refuse_input_dataset(out_dir, input_datasets(inputs))  # not even made inside an input folder of Parquet parts
    out = _make_out_dir(Path(out_dir))
    check_outputs([out / MANIFEST, out / SUMMARY], overwrite=overwrite)  # a folder that refuses files: before reading any input
    items = expand_inputs(inputs, out)
    if not items:
        raise OptionError(f"nothing to do: the inputs name no problem besides the output folder {out}")
    names = _output_names_checked(inputs, out, [pr for pr in items if pr.error is None], gt, overwrite)
    previous = _load_manifest(out) if resume else {}
    request = _request(options, overrides, fmt, duplicates, gt if isinstance(gt, (str, os.PathLike, type(None), bool)) else "custom",
                       columns, certify)

    entries: list[dict] = []
    jobs: list[dict] = []
    slot: dict[str, int] = {}
    for pr in items:
        if pr.error is not None:
            entries.append(_entry(pr.input, None, status="failed", error=pr.error, error_type="InputError", seconds=0.0))
            continue
        out_path = out / names[pr.path]
        shown = str(out_path)
        kept = _kept_output(pr, out_path, previous.get(str(pr.path)), request) if resume else None
        if kept is not None:
            entries.append(_entry(pr.input, shown, **kept, status="skipped", error=None, seconds=0.0))
            continue
        slot[str(pr.path)] = len(entries)
        entries.append(_entry(pr.input, None, input_path=str(pr.path), status="pending", method=method, request=request))
        size = _input_size(pr.path)
        jobs.append({
            "input": pr.input, "path": str(pr.path), "output": shown, "output_path": str(out_path.resolve()),
            "options": options, "overrides": dict(overrides or {}), "method": method, "fmt": fmt, "duplicates": duplicates, "gt": _gt_path(gt, pr), "eval": gt is not False,
            "size": size, "overwrite": overwrite, "request": request, "columns": columns, "certify": certify,
        })

    bar = progress or _Silent()
    bar("start", len(jobs))
    interval = min(2.0, 0.002 * len(entries))  # manifest rewrites: every result for small batches
    last = [0.0]

    def save(force: bool = False) -> None:
        now = time.perf_counter()
        if force or now - last[0] >= interval:
            # Whole or not at all: a Ctrl-C inside tempfile.mkstemp (the temporary file made,
            # its name not yet returned to atomic_write's cleanup) left a .tmp behind.
            with _sigint_deferred():
                _write_manifest(out, entries)
            last[0] = now

    def on_result(entry: dict) -> None:
        entries[slot[entry["input_path"]]] = entry
        bar("result", entry)
        save()

    run_start_ns = time.time_ns()
    try:
        save(force=True)
        with contextlib.suppress(OSError):  # outputs of this run are not older than its first manifest (file-system clock)
            run_start_ns = (out / MANIFEST).stat().st_mtime_ns
        if jobs:
            try:
                _run_on_dask(jobs, scheduler, workers, on_result, bar)
            finally:
                bar("close", None)
        save(force=True)  # whole, even if Ctrl-C comes now
    except BaseException as exc:
        with _sigint_deferred():  # the manifest is written even if Ctrl-C is pressed again
            _settle_pending(entries, jobs, run_start_ns, exc)
            save(force=True)
        raise
    return [json_safe(e) for e in entries]
