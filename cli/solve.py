"""``rotgraph solve``, ``eval``, ``synth`` and ``info``: multiple rotation averaging commands."""

from __future__ import annotations

import logging
import sys

import click

from rotgraph.choices import EDGE_FORMATS, GRAPHS, OUTLIER_MODELS, OUTPUT_FORMATS

from .common import EXIT_UNSOLVABLE, OVERWRITE_OPTION, emit_json, plural
from .options import COLUMNS_OPTION, DUPLICATES_OPTION, solve_overrides, solver_options
from .plots import check_plot_path, plot_errors, plot_info
from .progress import Progress

logger = logging.getLogger("rotgraph")


@click.command()
@click.argument("input_path", metavar="INPUT", type=click.Path(path_type=str))
@click.option("-o", "--output", type=click.Path(path_type=str), required=True,
              help="Output: CSV id,name,qw,qx,qy,qz (cam_from_world); by the extension (or --output-format): .json, "
                   ".txt (IMAGE_NAME QW QX QY QZ), a folder (ending in / or existing) for a COLMAP model.")
@click.option("--output-format", type=click.Choice(OUTPUT_FORMATS), default="auto", show_default=True,
              help="Format of -o: csv, text (IMAGE_NAME QW QX QY QZ), json, colmap (model folder, .bin), colmap-txt "
                   "(model folder, .txt; COLMAP project inputs; frames' rotations set, translations zero). auto: by -o.")
@solver_options
@click.option("--edges-out", type=click.Path(dir_okay=False, path_type=str), default=None, help="Also write i,j,residual_deg,inlier for every input edge.")
@click.option("--certify", "certify_", is_flag=True,
              help="Also certify the result: the Lagrangian-duality test of global optimality of the chordal cost on the "
                   "inlier edges of a robust method (adaptive, irls, l1), on every edge for the others (JSON key "
                   "certificate); exit 1 when it fails (the outputs are written).")
@click.option("--rigs", "rigs_file", type=click.Path(dir_okay=False, path_type=str), default=None,
              help="Rig file: 'image_id frame_id sensor_id [qw qx qy qz]' per image (cam_from_rig when known; see the "
                   "README): the cameras' rigs, frames and sensors, for inputs without COLMAP's.")
@click.option("--extrinsics-out", type=click.Path(dir_okay=False, path_type=str), default=None,
              help="Inputs with rigs: write sensor_id,status,qw,qx,qy,qz,n_frames,spread_deg,n_outlier_frames "
                   "(each sensor's cam_from_rig: estimated, refined or as given).")
@click.option("--frames-out", type=click.Path(dir_okay=False, path_type=str), default=None,
              help="Inputs with rigs: write frame_id,qw,qx,qy,qz (each frame's rig_from_world).")
@click.option("--gravity", "gravity_file", type=str, default=None, metavar="FILE|colmap",
              help="Gravity priors: 'image_id gx gy gz [sigma_deg]' lines (the down direction in each camera's frame, "
                   "COLMAP's PosePrior.gravity), or 'colmap': the pose priors of the input project's database.")
@click.option("--gravity-sigma", type=click.FloatRange(min=0), default=None, metavar="DEG",
              help="Noise of the gravity directions, degrees per tilt axis, for images the file gives none (0: exact, "
                   "the tilt held fixed as COLMAP does) [default: estimated from the data].")
@click.option("--workers", type=click.IntRange(min=1), default=None,
              help="Solve on a local Dask cluster of this many worker processes (one thread each): INPUT a folder of "
                   "Parquet parts, each read by a worker; the default method, the same outputs (needs rotgraph[distributed]).")
@click.option("--scheduler", type=str, default=None, metavar="ADDRESS",
              help="Solve on an existing Dask scheduler (e.g. tcp://host:8786) instead: its workers must import rotgraph "
                   "and see INPUT under the same absolute path; while the solve runs they neither spill to disk nor pause "
                   "(their settings are put back after).")
@click.option("--memory-limit", type=str, default=None, metavar="SIZE",
              help="With --workers: each worker's memory limit, e.g. 2GB [default: Dask's share of the RAM].")
@click.option("--blocks", type=click.IntRange(min=1), default=None,
              help="With --workers / --scheduler: cut the cameras into this many blocks [default: one a worker].")
@OVERWRITE_OPTION
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object with the summary.")
@click.option("-q", "--quiet", is_flag=True, help="No progress or summary (errors still go to stderr).")
@click.pass_context
def solve(ctx, input_path, output, output_format, fmt, duplicates, edges_out, certify_, rigs_file, extrinsics_out, frames_out,
          gravity_file, gravity_sigma, workers, scheduler, memory_limit, blocks, overwrite, as_json, quiet, **solver):
    """Multiple rotation averaging: absolute rotations from the relative rotations in INPUT.

    Writes OUTPUT with one row per solved camera (the largest connected component). The
    defaults suit the input's format (COLMAP projects: edges weighted by inlier counts);
    each option given replaces that one setting.

    Examples (in an empty folder; 'rotgraph synth' makes a problem with ground truth):

    \b
      rotgraph synth -o problem --n 50
      rotgraph solve problem/edges.txt -o rotations.csv
      rotgraph solve problem/edges.txt -o r.csv --edges-out residuals.csv --json
    """
    from rotgraph.io.atomic import writes_to_stdout
    from rotgraph.pipeline.solve import solve_file

    if as_json and any(writes_to_stdout(p) for p in (output, edges_out, extrinsics_out, frames_out)):
        raise click.UsageError("--json and an output on standard output (-o -) would mix on stdout: choose one")
    progress = Progress(quiet or as_json)
    distributed = workers is not None or scheduler is not None
    if not distributed and (memory_limit is not None or blocks is not None):
        raise click.UsageError("--memory-limit and --blocks go with --workers or --scheduler")
    if distributed:
        _check_distributed(workers, scheduler, memory_limit, output, output_format, fmt, duplicates, edges_out=edges_out,
                           certify=certify_, rigs=rigs_file, extrinsics_out=extrinsics_out, frames_out=frames_out,
                           gravity=gravity_file, columns=solver.get("columns"))
    try:
        if distributed:
            from rotgraph.pipeline.distributed import solve_distributed

            summary = solve_distributed(input_path, output, workers=workers, scheduler=scheduler, memory_limit=memory_limit,
                                        blocks=blocks, overrides=solve_overrides(ctx, solver), callback=progress,
                                        overwrite=overwrite)
        else:
            summary = solve_file(input_path, output, fmt=fmt, duplicates=duplicates, edges_out=edges_out, callback=progress,
                                 read_progress=progress.count if progress.enabled else None,  # off a terminal: nothing counted
                                 overrides=solve_overrides(ctx, solver), certify=certify_, columns=solver.get("columns"),
                                 rigs=rigs_file, extrinsics_out=extrinsics_out, frames_out=frames_out,
                                 gravity=gravity_file, gravity_sigma_deg=gravity_sigma, output_format=output_format,
                                 overwrite=overwrite)
    finally:
        progress.close()
    if as_json:
        emit_json(summary)
    elif not quiet:
        from rotgraph.io.atomic import writes_to_stdout

        s = summary
        to_stderr = any(writes_to_stdout(p) for p in (output, edges_out, extrinsics_out, frames_out))  # -o -: stdout holds the CSV only
        rejected = f" ({s['n_rejected']} with only outlier edges)" if s["n_rejected"] else ""
        click.echo(
            f"rotgraph solve: {plural(s['n_cameras'], 'camera')}, {plural(s['n_edges'], 'edge')}, "
            f"{plural(s['n_components'], 'component')}; solved {s['n_solved']}, left out {s['n_unsolved']}{rejected}; "
            f"{plural(s['n_outliers'], 'outlier edge')} (> {s['outlier_threshold_deg']:.3g} deg); {s['method']}, "
            f"{plural(s['iterations'], 'iteration')}{'' if s['converged'] else ' (not converged)'}; {s['seconds']:.2f} s -> {output}",
            err=to_stderr,
        )
        if "eval" in summary:
            e = summary["eval"]
            tilt = (f" (tilt {e['tilt_median_deg']:.3f}, yaw {e['yaw_median_deg']:.3f})"
                    if "tilt_median_deg" in e else "")
            click.echo(f"  vs ground truth in the input: median {e['median']:.3f} deg{tilt}, mean {e['mean']:.3f} deg over "
                       f"{e['n_evaluated']} cameras", err=to_stderr)
        if "sensors" in summary:
            rows = [r for r in summary["sensors"] if r["status"] in ("estimated", "refined", "unobservable")]
            words = ", ".join(f"sensor {r['sensor_id']} {r['status']}"
                              + (f" (spread {r['spread_deg']:.2f} deg over {r['n_frames']} frames)" if r["spread_deg"] is not None else "")
                              for r in rows[:6])
            click.echo(f"  rig extrinsics ({summary['n_frames']} frames): {words}{' ...' if len(rows) > 6 else ''}", err=to_stderr)
        if "certificate" in summary:
            from .certify import verdict_words

            click.echo(f"  {verdict_words(summary['certificate'])}", err=to_stderr)
    if "certificate" in summary and not summary["certificate"]["certified"]:
        sys.exit(EXIT_UNSOLVABLE)


def _check_distributed(workers, scheduler, memory_limit, output, output_format, fmt, duplicates, **others) -> None:
    """The options ``solve --workers`` / ``--scheduler`` do not take (yet): a usage error each."""
    from rotgraph.pipeline.solve import output_format_of

    if workers is not None and scheduler is not None:
        raise click.UsageError("--workers sizes a local cluster; with --scheduler the scheduler's workers are used")
    if memory_limit is not None and scheduler is not None:
        raise click.UsageError("--memory-limit sets the local cluster's workers (--workers); a scheduler's workers set their own")
    given = [k.replace("_", "-") for k, v in others.items() if v not in (None, False)]
    if fmt not in ("auto", "rotgraph"):
        given.append(f"format {fmt}")
    if duplicates not in (None, "error"):
        given.append(f"duplicates {duplicates}")
    if output_format_of(output, output_format) != "csv":
        given.append("an output other than CSV")
    if given:
        raise click.UsageError(f"--workers / --scheduler: {', '.join('--' + g if ' ' not in g else g for g in given)} not "
                               "available in the distributed solve yet (it writes the rotations CSV of a folder of Parquet parts)")


@click.command(name="eval")
@click.argument("estimate", type=click.Path(path_type=str))
@click.argument("gt", type=click.Path(path_type=str))
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object with the statistics (and the 10 worst cameras).")
@click.option("--plot", type=click.Path(dir_okay=False, path_type=str), default=None,
              help="Write an error CDF and histogram: .png, .pdf or .svg by the extension (needs matplotlib).")
@click.option("--per-camera", type=click.Path(dir_okay=False, path_type=str), default=None,
              help="Write id,name,error_deg for every evaluated camera to this CSV.")
@click.option("--tilt-yaw", is_flag=True,
              help="Also split the errors into tilt (the gravity direction, COLMAP's world +y) and yaw (about it).")
@OVERWRITE_OPTION
def evaluate(estimate, gt, as_json, plot, per_camera, tilt_yaw, overwrite):
    """Compare estimated rotations with ground truth, after aligning the gauge.

    ESTIMATE is a rotgraph CSV (id,name,qw,qx,qy,qz) or 'id qw qx qy qz' text; GT the same,
    or an input that carries ground truth (.mat with Rgt, 1DSfM with gt_bundle.out, synth gt.txt).
    Cameras are matched by name when both files carry names (ids differ between projects),
    by id where a file has none; fewer than half of either file matched is an error (exit 3).

    Examples (in an empty folder):

    \b
      rotgraph synth -o problem --n 50
      rotgraph solve problem/edges.txt -o rotations.csv
      rotgraph eval rotations.csv problem/gt.txt
      rotgraph eval rotations.csv problem/gt.txt --json --per-camera errors.csv
    """
    from rotgraph.evaluate import MATCHED_BY
    from rotgraph.io.atomic import output_group
    from rotgraph.io.outputs import check_outputs
    from rotgraph.io.writers import write_camera_errors
    from rotgraph.pipeline.solve import evaluate_files

    if plot:
        check_plot_path(plot)
    check_outputs([plot, per_camera], [estimate, gt], overwrite=overwrite)
    ev = evaluate_files(estimate, gt, tilt_yaw=tilt_yaw)
    ty = None
    if tilt_yaw:
        ev, ty = ev
    with output_group():  # both files or neither
        if per_camera:
            write_camera_errors(per_camera, ev.ids, ev.names, ev.errors_deg)
        if plot:
            plot_errors(ev.errors_deg, plot)
    if as_json:
        emit_json({**ev.to_dict(), **(ty or {})})
    else:
        click.echo(f"cameras evaluated: {ev.n_evaluated} (matched {MATCHED_BY[ev.matched_by]}; "
                   f"estimated {ev.n_estimated}, ground truth {ev.n_ground_truth})")
        click.echo(f"error [deg]: mean {ev.mean:.4f}  median {ev.median:.4f}  rmse {ev.rmse:.4f}  max {ev.max:.4f}")
        if ty:
            click.echo(f"tilt / yaw [deg]: median {ty['tilt_median_deg']:.4f} / {ty['yaw_median_deg']:.4f}")
        click.echo(f"under 1/2/5/10 deg: {ev.under_1deg:.1%} / {ev.under_2deg:.1%} / {ev.under_5deg:.1%} / {ev.under_10deg:.1%}")
        worst = ev.worst(3)
        click.echo("worst: " + ", ".join(f"{w['name']} {w['error_deg']:.3f} deg" for w in worst))


def _rig_shape(ctx, param, value):
    if value is None:
        return None
    try:
        a, b = (int(x) for x in value.lower().split("x"))
    except ValueError:
        raise click.BadParameter(f"expected SENSORSxFRAMES, e.g. 3x20, got {value!r}") from None
    if a < 1 or b < 2:
        raise click.BadParameter(f"need at least 1 sensor and 2 frames, got {value!r}")
    return a, b


def _noise_mix(ctx, param, value):
    if value is None:
        return None
    try:
        f, s = (float(x) for x in value.split(":"))
    except ValueError:
        raise click.BadParameter(f"expected FRACTION:SIGMA, e.g. 0.5:5, got {value!r}") from None
    if not (0.0 <= f <= 1.0 and s >= 0.0):
        raise click.BadParameter(f"the fraction must be in [0, 1] and the sigma >= 0, got {value!r}")
    return f, s


@click.command()
@click.option("-o", "--output", "out_dir", type=click.Path(file_okay=False, path_type=str), required=True, help="Folder for edges.txt (or .npz), gt.txt, meta.json.")
@click.option("--n", type=click.IntRange(min=2), default=100, show_default=True, help="Number of cameras.")
@click.option("--degree", type=click.FloatRange(min=1), default=10.0, show_default=True,
              help="Average number of edges per camera (posegraph: 3-6 is SLAM-like).")
@click.option("--sigma", type=click.FloatRange(min=0), default=2.0, show_default=True,
              help="Noise on each relative rotation: R_ij = R_j R_i^T exp([e]x), e ~ N(0, sigma^2 I), degrees per axis "
                   "(median angle about 1.54 sigma).")
@click.option("--outliers", type=click.FloatRange(min=0, max=1), default=0.0, show_default=True,
              help="uniform: fraction of edges replaced by random rotations (posegraph: loop closures only); "
                   "flip: fraction of the flipped group's edges that see its cameras turned.")
@click.option("--graph", type=click.Choice(GRAPHS), default="er", show_default=True,
              help="er: random graph (SfM-like); traj: a camera trajectory with loop closures; "
                   "posegraph: a SLAM robot's laps, odometry (i, i+1) (and (i, i+2) from degree 5) plus loop closures.")
@click.option("--outlier-model", type=click.Choice(OUTLIER_MODELS), default="uniform", show_default=True,
              help="uniform: random rotations; flip: a consistent wrong hypothesis, --flip-group of the cameras "
                   "seen turned 180 deg about the world y axis (a symmetric scene, doppelgangers).")
@click.option("--flip-group", type=click.FloatRange(min=0, max=1), default=0.2, show_default=True,
              help="flip model: fraction of the cameras in the turned group.")
@click.option("--noise-mix", metavar="FRACTION:SIGMA", default=None, callback=_noise_mix,
              help="Mixed edge quality: that fraction of the edges (at random) gets SIGMA degrees instead of --sigma "
                   "(no weights written), e.g. --sigma 0.5 --noise-mix 0.5:5.")
@click.option("--uncertainty-spread", type=click.FloatRange(min=1), default=None, metavar="K",
              help="Per-edge anisotropic noise: standard deviations sigma*exp(u), u ~ U(-ln K, ln K), along three random "
                   "axes of each edge, R_ij = exp([d]x) R_j R_i^T; edges.txt then carries each edge's true information "
                   "matrix (info columns).")
@click.option("--rig", "rig", default=None, metavar="SENSORSxFRAMES", callback=_rig_shape,
              help="A multi-camera rig problem instead (--n and --graph are then unused): e.g. 3x20, 3 sensors (sensor 0 "
                   "the reference) in 20 frames; writes rigs.txt (rotgraph solve --rigs) and gt_extrinsics.csv.")
@click.option("--rigs", "n_rigs", type=click.IntRange(min=1), default=1, show_default=True, help="--rig: number of rigs.")
@click.option("--rig-known", type=click.Choice(["none", "half", "all"]), default="none", show_default=True,
              help="--rig: which sensors' cam_from_rig rigs.txt gives (the others are to be estimated).")
@click.option("--within-frame", type=click.FloatRange(min=0, max=1), default=1.0, show_default=True,
              help="--rig: probability that a pair of images of one frame is an edge.")
@click.option("--gravity-noise", type=click.FloatRange(min=0), default=None, metavar="DEG",
              help="Also write gravity.txt: each camera's gravity direction (COLMAP's world +y seen in the camera) with "
                   "this noise, degrees per tilt axis (rotgraph solve --gravity).")
@click.option("--edges-format", type=click.Choice(["txt", "npz", "both"]), default="txt", show_default=True,
              help="edges.txt (rotgraph text), edges.npz (the binary edge format: arrays i j qw qx qy qz weight [h_xx..h_zz], "
                   "read in about a second for 10^7 edges) or both (same edges, same order).")
@click.option("--seed", type=int, default=0, show_default=True)
@OVERWRITE_OPTION
def synth(out_dir, n, degree, sigma, outliers, graph, outlier_model, flip_group, noise_mix, uncertainty_spread, rig, n_rigs,
          rig_known, within_frame, gravity_noise, seed, overwrite, edges_format="txt"):
    """Write a synthetic problem with ground truth: edges.txt (or edges.npz), gt.txt, meta.json.

    meta.json records the parameters, the convention and the edges that are outliers
    (outlier_edges: 0-based rows of edges.txt).

    Examples (each writes one folder here):

    \b
      rotgraph synth -o problem --n 500 --degree 20 --sigma 2 --outliers 0.1
      rotgraph synth -o slam --graph posegraph --n 1000 --degree 4 --outliers 0.05
      rotgraph synth -o sym --outlier-model flip --outliers 0.4 --sigma 1
      rotgraph synth -o mixed --degree 20 --sigma 0.5 --noise-mix 0.5:5
      rotgraph synth -o aniso --degree 12 --sigma 2 --uncertainty-spread 3
      rotgraph synth -o rig --rig 4x50 --sigma 1 --outliers 0.1 --gravity-noise 1
    """
    from rotgraph.errors import OptionError
    from rotgraph.pipeline.synth import make_synthetic

    try:
        p = make_synthetic(out_dir, rig=rig, n_rigs=n_rigs, rig_known=rig_known, within_frame=within_frame,
                           gravity_noise_deg=gravity_noise, edges_format=edges_format, overwrite=overwrite, n=n,
                           degree=degree, sigma_deg=sigma, outliers=outliers, graph=graph, seed=seed,
                           outlier_model=outlier_model, flip_group=flip_group, noise_mix=noise_mix,
                           uncertainty_spread=uncertainty_spread)
    except OptionError as exc:  # options that cannot go together: click's usage error (exit 2)
        raise click.UsageError(str(exc)) from None
    click.echo(f"rotgraph synth: {plural(p.meta['n'], 'camera')}, {plural(p.graph.n_edges, 'edge')} "
               f"({plural(p.meta['n_outlier_edges'], 'outlier')}) -> {p.folder}")


@click.command()
@click.argument("input_path", metavar="INPUT", type=click.Path(path_type=str))
@click.option("--format", "fmt", type=click.Choice(EDGE_FORMATS), default="auto", show_default=True)
@DUPLICATES_OPTION
@COLUMNS_OPTION
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
@click.option("--plot", type=click.Path(dir_okay=False, path_type=str), default=None,
              help="Write degree and cycle-error histograms (and, up to 300 cameras, the graph coloured by residual): "
                   ".png, .pdf or .svg by the extension.")
@OVERWRITE_OPTION
def info(input_path, fmt, duplicates, columns, as_json, plot, overwrite):
    """View-graph summary: cameras, edges, components, degrees, cycle consistency.

    Examples (in an empty folder):

    \b
      rotgraph synth -o problem --n 50
      rotgraph info problem/edges.txt
      rotgraph info problem/edges.txt --json
    """
    from rotgraph.pipeline.info import view_graph_info

    if plot:
        check_plot_path(plot)
    about = view_graph_info(input_path, fmt, duplicates, columns, plot=plot, overwrite=overwrite)
    s = about.summary
    if plot:
        plot_info(about, plot)
    if as_json:
        emit_json(s)
        return
    click.echo(f"cameras: {s['n_cameras']}   edges: {s['n_edges']}   components: {s['n_components']} (largest {s['largest_component']})")
    click.echo(f"degree: min {s['degree_min']}  median {s['degree_median']:g}  max {s['degree_max']}")
    if s["n_triangles_checked"]:
        click.echo(
            f"cycle consistency over {s['n_triangles_checked']} triangles [deg]: median {s['cycle_error_median_deg']:.3f}  mean {s['cycle_error_mean_deg']:.3f}  "
            f"p90 {s['cycle_error_p90_deg']:.3f}; < 2 deg {s['cycle_under_2deg']:.1%}, > 10 deg {s['cycle_over_10deg']:.1%}"
        )
    else:
        click.echo("cycle consistency: no triangles")
    if s["n_ground_truth"]:
        click.echo(f"ground truth in the input: {s['n_ground_truth']} cameras")
    if s["n_initial_guess"]:
        click.echo(f"initial guess in the input: {s['n_initial_guess']} cameras (not ground truth; --init vertices starts from it)")
