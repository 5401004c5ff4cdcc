"""``rotgraph reconstruct``: COLMAP 4's global pipeline continued from rotgraph's rotations."""

from __future__ import annotations

import logging

import click

from .common import OVERWRITE_OPTION, emit_json, plural
from .options import solve_overrides, solver_options

logger = logging.getLogger("rotgraph")


@click.command()
@click.argument("project", metavar="PROJECT", type=click.Path(path_type=str))
@click.option("-o", "--output", type=click.Path(file_okay=False, path_type=str), required=True,
              help="Folder for the COLMAP model (cameras, images, points3D, rigs, frames); made if needed. A folder "
                   "holding a reconstruction (3D points or positions) is refused unless --overwrite; other files in it "
                   "are never touched.")
@click.option("--text", is_flag=True, help="Write the model as .txt files (default: .bin).")
@solver_options
@click.option("--mapper-seed", type=int, default=None,
              help="COLMAP's random seed (global positioning starts from random positions) [default: COLMAP's, random].")
@click.option("--num-threads", type=int, default=None, help="Threads of COLMAP's solvers [default: COLMAP's, all cores].")
@click.option("--ground-truth", "ground_truth", type=click.Path(path_type=str), default=None,
              help="A COLMAP model to evaluate against (images matched by name) [default: the project's sparse model, "
                   "when it has one].")
@OVERWRITE_OPTION
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object with the summary.")
@click.option("-q", "--quiet", is_flag=True, help="No summary (errors still go to stderr).")
@click.pass_context
def reconstruct(ctx, project, output, text, fmt, duplicates, mapper_seed, num_threads, ground_truth, overwrite, as_json, quiet,
                **solver):
    """Full reconstruction of a COLMAP PROJECT from rotgraph's rotations.

    Rotation averaging by rotgraph (the options of 'rotgraph solve'), then COLMAP 4's
    global pipeline through pycolmap: tracks from the verified two-view inliers, global
    positioning, bundle adjustment, retriangulation. Writes a COLMAP model into OUTPUT.
    PROJECT is a folder holding database.db (or the database file); it is only read.

    Example (in an empty folder: a synthetic COLMAP project made with pycolmap, with its
    ground truth in proj/sparse/0, then reconstructed):

    \b
      python -c "import rotgraph.synth as s; s.synthesize_colmap_project('proj')"
      rotgraph reconstruct proj -o proj/sparse/rotgraph/
    """
    from rotgraph.pipeline.reconstruct import reconstruct as run

    if fmt not in ("auto", "colmap"):
        raise click.BadParameter("reconstruct reads COLMAP projects only", param_hint="--format")
    if duplicates is not None:
        raise click.BadParameter("not used by reconstruct (COLMAP pairs are unique)", param_hint="--duplicates")
    if solver.get("columns") is not None:
        raise click.BadParameter("not used by reconstruct (COLMAP projects have no edge table)", param_hint="--columns")

    def stage(name: str) -> None:
        logger.info("reconstruct: %s", name)

    summary = run(project, output, overrides=solve_overrides(ctx, solver), seed=mapper_seed, num_threads=num_threads,
                  text=text, ground_truth=ground_truth if ground_truth is not None else "auto", callback=stage,
                  pycolmap_log_level=0 if logger.isEnabledFor(logging.DEBUG) else 2, overwrite=overwrite)
    if as_json:
        emit_json(summary)
    elif not quiet:
        s = summary
        click.echo(
            f"rotgraph reconstruct: {plural(s['n_registered'], 'image')} of {s['n_images']} registered, "
            f"{plural(s['n_points3D'], '3D point')}, reprojection error {s['mean_reprojection_error']:.3f} px; "
            f"{s['seconds']:.2f} s -> {output}")
        if "eval" in s and s["eval"]["n_evaluated"]:
            e, r = s["eval"], s["eval_rotation_averaging"]
            click.echo(f"  vs ground truth ({e['n_evaluated']} images): rotation median {e['rotation_median_deg']:.4f} deg "
                       f"(rotation averaging {r['rotation_median_deg']:.4f}), position median {e['position_median']:.4g} "
                       f"({100 * e['position_median_rel']:.3f} % of the scene's radius)")
