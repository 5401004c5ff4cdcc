"""``rotgraph batch``: many problems at once on Dask (a local cluster or an existing scheduler)."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import click

from .common import OVERWRITE_OPTION, emit_json
from .options import solve_overrides, solver_options
from .progress import BatchProgress


@click.command()
@click.argument("inputs", metavar="INPUT...", nargs=-1, required=True, type=str)
@click.option("-d", "--out-dir", type=click.Path(file_okay=False, path_type=str), required=True,
              help="Folder for one <stem>.csv per problem (as 'rotgraph solve' writes it), manifest.json and summary.csv.")
@click.option("--gt", "gt_template", type=str, default=None, metavar="TEMPLATE",
              help="Ground-truth file per problem for the evaluation, with {dir}, {parent}, {stem}, {name} of the input, "
                   "e.g. '{dir}/gt.txt' for 'rotgraph synth' folders [default: the ground truth the input carries, if any].")
@click.option("--workers", type=click.IntRange(min=1), default=None,
              help="Worker processes of the local Dask cluster (one thread each) [default: the CPUs available].")
@click.option("--scheduler", type=str, default=None, metavar="ADDRESS",
              help="Use an existing Dask scheduler (e.g. tcp://host:8786) instead of a local cluster. Its workers must "
                   "have rotgraph installed and see the inputs and --out-dir under the same paths.")
@click.option("--resume", is_flag=True,
              help="Skip problems whose output exists, is complete, is newer than the input and was solved with the same "
                   "options (status 'skipped'); the others are solved again.")
@click.option("--certify", "certify_", is_flag=True,
              help="Certify each result as 'rotgraph solve --certify' does (manifest keys certified and certificate, "
                   "summary column certified); exit 1 when any is not certified.")
@click.option("--json", "as_json", is_flag=True, help="Print the manifest (a JSON list, one object per problem) on stdout.")
@click.option("-q", "--quiet", is_flag=True, help="No progress, dashboard link or summary (the exit code still tells).")
@solver_options
@OVERWRITE_OPTION
@click.pass_context
def batch(ctx, inputs, out_dir, gt_template, workers, scheduler, resume, overwrite, certify_, as_json, quiet, fmt, duplicates,
          **solver):
    """Solve many problems at once on Dask: one task per problem, results as they finish.

    INPUT is a file, a folder (a 1DSfM scene, COLMAP project or folder of Parquet parts
    is one problem; any other folder gives the view graphs in it, and its sub-folders that
    are such folders, not recursively), a glob pattern (quote it)
    or @LIST (a text file with one input a line; relative paths in it are relative to the
    list file's folder, not to the current folder). Every problem gets OUT_DIR/<stem>.csv
    (<folder>_<stem>.csv when stems clash), exactly what 'rotgraph solve INPUT -o OUT'
    writes with the same options; a problem that fails is reported and never stops the
    others. OUT_DIR/manifest.json (a list, one object
    per problem: input, output, status ok|failed|skipped, error, n_cameras, n_edges,
    n_solved, n_outliers, seconds, eval_median_deg, eval_mean_deg, ...) and summary.csv
    are rewritten as results arrive.

    Default: a local Dask cluster (--workers processes, one thread each); --scheduler uses
    an existing 'dask scheduler'. Needs Dask: pip install 'rotgraph[batch]' (without it:
    exit 1 with that message). Exit 0 when every problem is ok or skipped (and, with
    --certify, certified), 1 otherwise.

    Examples (in an empty folder; the paths in scenes/list.txt are relative to scenes/,
    and the second batch skips the problems the first one solved):

    \b
      rotgraph synth -o scenes/a --n 50
      rotgraph synth -o scenes/b --n 50 --seed 1
      rotgraph batch 'scenes/*/edges.txt' -d out --gt '{dir}/gt.txt' --workers 2
      python -c "open('scenes/list.txt', 'w').write('a/edges.txt\\nb/edges.txt\\n')"
      rotgraph batch @scenes/list.txt -d out --gt '{dir}/gt.txt' --resume --json
    """
    from rotgraph.pipeline.batch import solve_many

    if workers is not None and scheduler:
        raise click.UsageError("--workers sizes the local cluster; with --scheduler the scheduler's workers are used")
    t0 = time.perf_counter()
    manifest = solve_many(list(inputs), out_dir, overrides=solve_overrides(ctx, solver), fmt=fmt, duplicates=duplicates,
                          workers=workers, scheduler=scheduler, resume=resume, progress=BatchProgress(quiet), gt=gt_template,
                          overwrite=overwrite, columns=solver.get("columns"), certify=certify_)
    seconds = time.perf_counter() - t0
    counts = {s: sum(1 for e in manifest if e["status"] == s) for s in ("ok", "skipped", "failed")}
    uncertified = sum(1 for e in manifest if e["status"] in ("ok", "skipped") and e.get("certified") is False)
    if as_json:
        emit_json(manifest)
    elif not quiet:
        tail = f", {uncertified} not certified" if certify_ else ""
        click.echo(f"rotgraph batch: {len(manifest)} problem(s): {counts['ok']} ok, {counts['skipped']} skipped, "
                   f"{counts['failed']} failed{tail}; {seconds:.2f} s -> {Path(out_dir) / 'manifest.json'}")
    if counts["failed"] or (certify_ and uncertified):
        sys.exit(1)

