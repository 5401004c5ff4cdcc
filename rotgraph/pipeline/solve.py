"""One problem from file to file: what ``rotgraph solve`` does, as a library function.

:func:`solve_file` reads a view graph, averages its rotations, writes the ``solve`` output
CSV (and optionally the per-edge residuals) and returns the summary dictionary that
``rotgraph solve --json`` prints. ``rotgraph solve`` and ``rotgraph batch`` (each of its
workers) both call it, so a batch output is byte-for-byte the ``solve`` output.
"""

from __future__ import annotations

import os
from pathlib import Path
import time
from dataclasses import asdict, replace
from typing import Callable

import numpy as np

from ..errors import UnsolvableError
from ..estimators.types import Callback, SolveOptions
from .heap import heap_for_large_arrays

__all__ = ["solve_file", "default_options", "PRESETS", "evaluate_against_input_gt", "evaluate_files", "output_format_of",
           "check_model_folder"]


def evaluate_against_input_gt(graph, result) -> dict | None:
    """``compare_rotations(...).to_dict()`` against the ground truth carried by the input
    (``graph.gt_cam_from_world``: ``.mat`` ``Rgt``, 1DSfM ``gt_bundle.out``, a COLMAP
    project's sparse model), or None when the input carries none. An initial guess
    (``graph.initial_cam_from_world``, e.g. g2o vertices) is never ground truth."""
    from ..evaluate import compare_rotations

    gt = graph.gt_cam_from_world
    if gt is None or not np.isfinite(gt).all(axis=(1, 2)).any():
        return None
    if not (np.isfinite(gt).all(axis=(1, 2)) & np.isfinite(result.cam_from_world).all(axis=(1, 2))).any():
        return None  # no solved camera has ground truth: nothing to compare
    return compare_rotations(result.cam_from_world, gt).to_dict()


#: Default options by input format (:attr:`ViewGraph.format`, set by the reader), on top of
#: :class:`SolveOptions`' own. COLMAP: edges weighted by their inlier counts and GLOMAP's 5
#: L1 iterations. Measured on the projects of ``benchmarks/bench_colmap.py``: weighting
#: lowers the median error on real data (lund_door 0.528 -> 0.524 deg) and changes nothing
#: on the synthetic ones.
PRESETS: dict[str, dict] = {
    "colmap": {"use_weights": True, "l1_iterations": 5},
}
#: Preset fields that give way when the edges carry information matrices (COLMAP pair
#: uncertainties, on by default): the information already grows with the inlier count.
PRESETS_WITH_INFORMATION: dict[str, dict] = {
    "colmap": {"use_weights": False},
}


def default_options(fmt: str | None, information: bool = True, **overrides) -> SolveOptions:
    """The options ``rotgraph solve`` uses on input of format ``fmt``: :data:`PRESETS`
    (with :data:`PRESETS_WITH_INFORMATION` when the input has information matrices,
    ``information``, and ``use_information=False`` is not among the overrides), then
    ``overrides`` (the options a user set; each replaces that field only).

    Parameters
    ----------
    fmt : str or None
        The input format after detection (e.g. ``"colmap"``, ``"g2o"``); None: no preset.
    information : bool, default True
        Whether the input has rotation information matrices.
    **overrides
        Fields of :class:`SolveOptions` the user set.

    Returns
    -------
    SolveOptions
        The options, validated.

    Raises
    ------
    OptionError
        A bad option value (also a ``ValueError``).
    """
    preset = dict(PRESETS.get(fmt or "", {}))
    if information and overrides.get("use_information", True):
        preset.update(PRESETS_WITH_INFORMATION.get(fmt or "", {}))
    return SolveOptions(**{**preset, **overrides}).validated()


def output_format_of(output, output_format: str = "auto") -> str:
    """The format ``rotgraph solve`` writes ``output`` in: ``output_format`` when given, else
    by ``output``: a path ending in ``/`` or an existing folder -> ``colmap`` (a model
    folder, ``.bin``), ``.json`` -> ``json``, ``.txt`` -> ``text`` (``IMAGE_NAME QW QX QY
    QZ``), ``.csv``, ``-``, a name without an extension (``rotations``, ``/dev/stdout``) and
    an existing device or FIFO whatever its name (written through) -> ``csv``. Any other
    extension (``-o x.xyz``) is an :class:`~rotgraph.errors.OptionError` (the command
    line's exit 2) listing the formats: it used to be written as CSV without a word."""
    import stat

    from ..choices import OUTPUT_FORMATS
    from ..errors import OptionError

    if output_format not in OUTPUT_FORMATS:
        raise OptionError(f"unknown output format {output_format!r}; expected one of {', '.join(OUTPUT_FORMATS)}")
    if output_format != "auto":
        return output_format
    out = str(output)
    if out == "-":
        return "csv"
    if out.endswith(("/", os.sep)) or os.path.isdir(out):
        return "colmap"
    ext = os.path.splitext(out)[1].lower()
    by_extension = {"": "csv", ".csv": "csv", ".json": "json", ".txt": "text"}
    if ext in by_extension:
        return by_extension[ext]
    try:
        if not stat.S_ISREG(os.stat(out).st_mode):  # an existing device or FIFO (/dev/null, a named pipe)
            return "csv"
    except OSError:
        pass
    formats = "|".join(f for f in OUTPUT_FORMATS if f != "auto")
    raise OptionError(f"-o {out}: unknown output extension {ext!r}; expected .csv, .json, .txt (IMAGE_NAME QW QX QY QZ), "
                      f"a folder ending in / (a COLMAP model), a name without extension (CSV) or - (standard output), "
                      f"or name the format with --output-format {formats}")


def wants_information(options: SolveOptions | None, overrides: dict | None) -> bool:
    """Whether the solve will use per-edge information (so the reader should estimate it)."""
    return (options.use_information if options is not None else True) and (overrides or {}).get("use_information", True)


def resolve_options(graph, options: SolveOptions | None, overrides: dict | None) -> SolveOptions:
    """The options of a solve of ``graph``: the defaults of its format (and information),
    or ``options``, with ``overrides`` on top."""
    if options is None:
        return default_options(graph.format, graph.information is not None, **(overrides or {}))
    return replace(options, **(overrides or {}))


def check_model_folder(output, input_path, overwrite: bool = False, other_inputs=(), side_outputs=()) -> None:
    """The checks of a COLMAP model output, before any work: a folder (made if missing) that
    is not the input project, its database's folder, its sparse model or another input
    (``other_inputs``, e.g. ``reconstruct --ground-truth``), whatever the path says
    (symlinks resolved; ``overwrite`` changes nothing here), nor inside an input folder of
    Parquet parts (:func:`~rotgraph.io.outputs.refuse_input_dataset`); where a file can be created
    (:func:`~rotgraph.io.outputs.probe_folder`); no other output of the run (``side_outputs``)
    named as one of its model files; and not holding a model other than a rotgraph
    rotations-only one, or read-only model files, unless ``overwrite``
    (:func:`~rotgraph.io.colmap_output.check_model_output`)."""
    from ..errors import InputError
    from ..io.colmap_project import find_colmap_project
    from ..io.colmap_output import MODEL_FILE_NAMES, check_model_output
    from ..io.outputs import input_datasets, probe_folder, refuse_input_dataset

    if str(output) == "-":
        raise InputError("a COLMAP model cannot go to standard output", path="-")
    p = os.path.realpath(str(output))
    if os.path.exists(p) and not os.path.isdir(p):
        raise InputError("a COLMAP model output must be a folder, this is a file", path=str(output))
    taken = {os.path.realpath(str(input_path))}
    try:
        db, model = find_colmap_project(input_path)
    except Exception:  # noqa: BLE001 - not a COLMAP project: the input itself is all there is
        db, model = None, None
    taken |= {os.path.realpath(os.path.dirname(str(db)))} if db is not None else set()
    taken |= {os.path.realpath(str(model))} if model is not None else set()
    taken |= {os.path.realpath(str(x)) for x in other_inputs if x is not None}
    if p in taken:
        raise InputError("the model folder is the input project, its sparse model or another input: choose another "
                         "(e.g. PROJECT/sparse/rotgraph)", path=str(output))
    refuse_input_dataset(p, input_datasets([input_path, *other_inputs]), output)
    for side in side_outputs:
        if side is not None and str(side) != "-" and os.path.dirname(os.path.realpath(str(side))) == p \
                and os.path.basename(str(side)) in MODEL_FILE_NAMES:
            raise InputError(f"names a file of the model written into {output}: choose another name", path=str(side))
    parent = Path(p)
    while not parent.exists() and parent != parent.parent:  # where the folder will be made
        parent = parent.parent
    probe_folder(parent, str(output))
    check_model_output(output, overwrite)


def _read_gravity(gravity, input_path, graph, sigma_deg):
    """``(gravity (n, 3), sigma_deg (n,))`` for ``graph``'s cameras from a gravity file or,
    for ``"colmap"``, the pose priors of the COLMAP project ``input_path``."""
    from ..errors import InputError
    from ..io.gravity import gravity_for_graph, read_colmap_gravity, read_gravity_file

    if gravity == "colmap":
        from ..io.colmap_project import find_colmap_project

        db = find_colmap_project(input_path)[0] if graph.format == "colmap" else None
        if db is None:
            raise InputError("--gravity colmap needs a COLMAP project with a database (its pose priors)", path=str(input_path))
        table = read_colmap_gravity(db)
        if not len(table.keys):
            raise InputError("the database has no pose prior with a gravity direction", path=str(db))
    else:
        table = read_gravity_file(gravity)
    return gravity_for_graph(table, graph.node_ids, graph.names, np.nan if sigma_deg is None else float(sigma_deg))


def _tilt_yaw(graph, res) -> dict:
    """Tilt and yaw errors (degrees; medians) against the input's ground truth, after
    aligning the whole gauge (:func:`rotgraph.evaluate.tilt_yaw_errors`)."""
    from ..evaluate import tilt_yaw_errors

    gt = graph.gt_cam_from_world
    ok = res.solved & np.isfinite(gt).all(axis=(1, 2))
    if ok.sum() < 2:
        return {}
    e = tilt_yaw_errors(res.cam_from_world[ok], gt[ok], align="full")
    return {"tilt_median_deg": float(np.median(e.tilt_deg)), "yaw_median_deg": float(np.median(e.yaw_deg))}


def _frame_keys(graph, frames) -> np.ndarray:
    """The id of each frame-graph node: the rig's frame id (an image alone in its frame:
    that frame's id too)."""
    keys = np.empty(frames.graph.n_nodes, dtype=np.int64)
    keys[frames.frame_of_image] = graph.rigs.frame_ids
    return keys


@heap_for_large_arrays()
def solve_file(
    input_path,
    output,
    options: SolveOptions | None = None,
    fmt: str = "auto",
    duplicates: str | None = "error",
    edges_out=None,
    callback: Callback | None = None,
    read_progress: Callable[[str, int, int], None] | None = None,
    overrides: dict | None = None,
    certify: bool = False,
    rigs=None,
    extrinsics_out=None,
    frames_out=None,
    gravity=None,
    gravity_sigma_deg: float | None = None,
    output_format: str = "auto",
    overwrite: bool = False,
    columns=None,
) -> dict:
    """Solve the problem in ``input_path`` and write ``output`` (``id,name,qw,qx,qy,qz``).

    ``options`` replaces the defaults entirely; without it the defaults of the input's
    format (:func:`default_options`) apply, with ``overrides`` (field -> value: the options
    the user set) on top. ``edges_out`` (optional) receives ``i,j,residual_deg,inlier``
    (``name_i,name_j`` when the input names its cameras; with ``certify`` also ``weight``,
    the final iteration's) for every input edge. ``callback`` follows the solvers' iterations;
    ``read_progress(stage, done, total)`` the reading stages that count work (COLMAP
    relative-pose estimation). Both files are written atomically. Returns the summary
    (``input``, ``output``, ``n_cameras``, ``n_edges``, ``n_components``, ``n_solved``,
    ``n_unsolved`` (of which ``n_rejected`` in the solved component, every edge of theirs
    an outlier), ``n_outliers``, ``outlier_threshold_deg`` (the one used: fitted to the noise by
    the adaptive default), ``diagnostics`` (what the solver chose and why), ``method``, ``iterations``,
    ``converged``, ``cost``, ``options`` (every field of the options used), ``seconds``,
    ``seconds_read``, ``seconds_solve``, when the input carries ground truth ``eval``, and
    with ``certify`` ``certificate``: the rotations written are then the chordal optimum on
    the inlier edges nearest the solve's, certified there
    (:func:`~rotgraph.pipeline.certify.certify_result`)); a rig solve adds ``n_frames`` and,
    when it estimated or refined extrinsics, ``sensors`` (one dict per sensor:
    :meth:`~rotgraph.estimators.types.SensorSolution.to_rows`). ``rigs``: a rig file
    (:mod:`rotgraph.io.rigs`) giving the input's cameras their rigs, frames and sensors (in
    place of a COLMAP project's own). ``extrinsics_out``: CSV of the extrinsics
    (:func:`~rotgraph.io.writers.write_extrinsics`); ``frames_out``: CSV of the frame
    rotations ``frame_id,qw,qx,qy,qz`` (``rig_from_world``). ``gravity``: per-image gravity
    priors, a gravity file (:mod:`rotgraph.io.gravity`) or ``"colmap"`` (the pose priors of
    the input COLMAP project's database), with noise ``gravity_sigma_deg`` for images the
    file gives none (None: estimated from the data); the summary then has ``gravity`` (the
    solver's report) and, with ground truth, tilt and yaw errors in ``eval``.
    ``output_format`` (:func:`output_format_of`): ``csv`` (default), ``text`` (``IMAGE_NAME QW
    QX QY QZ``), ``json``, ``colmap`` / ``colmap-txt`` (a COLMAP model folder:
    :mod:`rotgraph.io.colmap_output`; COLMAP project inputs only). Raises :class:`~rotgraph.errors.InputError` for
    a bad input and :class:`~rotgraph.errors.UnsolvableError` when the graph cannot be
    solved. ``duplicates`` as :func:`~rotgraph.pipeline.read.read_view_graph` (None: the
    input format's default, ``keep`` for g2o); ``columns`` as there (the columns of a table of
    another layout, e.g. ``"i,j,qw,qx,qy,qz,weight,-"``). The outputs follow the output rule
    (:func:`~rotgraph.io.outputs.check_outputs`, before any work): an existing file that is
    not rotgraph's own earlier output (a model folder: not a rotations-only model) is
    refused unless ``overwrite``; every output is written or none (a failed run leaves the
    earlier ones as they were).

    Parameters
    ----------
    input_path : str or os.PathLike
        The input, anything :func:`~rotgraph.pipeline.read.read_view_graph` reads.
    output : str or os.PathLike
        Where the absolute rotations (``cam_from_world``, quaternions ``(w, x, y, z)``,
        ``w >= 0``) go; ``-`` is stdout.
    options : SolveOptions, optional
        Replaces the defaults entirely.
    fmt : str, default "auto"
        The input format (:data:`~rotgraph.choices.EDGE_FORMATS`).
    duplicates : {"error", "merge", "keep"} or None, default "error"
        As :func:`~rotgraph.pipeline.read.read_view_graph`.
    edges_out : str or os.PathLike, optional
        CSV of every input edge's ``residual_deg`` and ``inlier``.
    callback : callable, optional
        ``callback(stage, iteration, median_step_rad)`` of the solvers' iterations.
    read_progress : callable, optional
        ``read_progress(stage, done, total)`` of the reading stages.
    overrides : dict, optional
        Field -> value of :class:`SolveOptions` on top of the format's defaults.
    certify : bool, default False
        Certify (and refine to) the chordal optimum on the inlier edges.
    rigs : str or os.PathLike, optional
        A rig file giving the input's cameras their rigs, frames and sensors.
    extrinsics_out, frames_out : str or os.PathLike, optional
        CSV of the rig extrinsics; CSV of the frame rotations (``rig_from_world``).
    gravity : str or os.PathLike, optional
        A gravity file, or ``"colmap"`` (the project's pose priors).
    gravity_sigma_deg : float, optional
        Gravity noise in degrees for images the file gives none (None: estimated).
    output_format : str, default "auto"
        ``auto``, ``csv``, ``text``, ``json``, ``colmap`` or ``colmap-txt``
        (:func:`output_format_of`).
    overwrite : bool, default False
        Replace existing files that are not rotgraph's own earlier output.
    columns : str or sequence of str, optional
        The columns of a text table of another layout.

    Returns
    -------
    dict
        The summary (keys above), JSON-able.

    Raises
    ------
    OptionError
        Bad option values or combinations (also a ``ValueError``).
    InputError
        A bad input (also a ``ValueError``).
    UnsolvableError
        The graph cannot be solved.
    """
    from ..estimators.rotation_averaging import average_rotations
    from ..io.atomic import output_group
    from .read import read_view_graph

    extra_inputs = [p for p in (rigs, gravity) if p is not None and p != "colmap"]
    out_fmt = output_format_of(output, output_format)
    model_out = out_fmt in ("colmap", "colmap-txt")
    _check_solve_outputs(input_path, output, model_out, edges_out, extrinsics_out, frames_out, extra_inputs, overwrite)
    t0 = time.perf_counter()
    graph = read_view_graph(input_path, fmt=fmt, duplicates=duplicates, progress=read_progress,
                            uncertainty=wants_information(options, overrides), columns=columns)
    if rigs is not None:
        from ..io.rigs import read_rigs

        graph.rigs = read_rigs(rigs, graph)
    if model_out and graph.format != "colmap":
        from ..errors import InputError

        raise InputError("a COLMAP model output (-o FOLDER/, --output-format colmap) needs a COLMAP project input",
                         path=str(output))
    if gravity is not None:
        graph = graph.with_gravity(*_read_gravity(gravity, input_path, graph, gravity_sigma_deg))
    t_read = time.perf_counter() - t0
    opts = resolve_options(graph, options, overrides)
    try:
        res = average_rotations(graph, opts, callback=callback)
    except UnsolvableError as exc:  # say which input (batch logs hold many)
        raise UnsolvableError(f"{input_path}: {exc}") from exc
    certificate = None
    if certify:  # the certified final stage: the chordal optimum on the inliers, certified
        from .certify import certify_result

        res, certificate = certify_result(graph, res, opts)
    sensors = _output_sensors(graph, res, input_path, extrinsics_out, frames_out)
    with output_group():  # every output or none: a failed write leaves the earlier outputs as they were
        model_counts = _write_outputs(graph, res, input_path, output, out_fmt, edges_out, extrinsics_out, frames_out,
                                      sensors, certify)
    seconds = time.perf_counter() - t0
    return _solve_summary(graph, res, opts, input_path, output, out_fmt, seconds, t_read, certificate, model_counts,
                          gravity is not None)


def _check_solve_outputs(input_path, output, model_out: bool, edges_out, extrinsics_out, frames_out, extra_inputs: list,
                         overwrite: bool) -> None:
    """:func:`solve_file`'s outputs under the output rule, before any work."""
    from ..io.outputs import check_outputs

    check_outputs([None if model_out else output, edges_out, extrinsics_out, frames_out], [input_path] + extra_inputs,
                  overwrite=overwrite)
    if model_out:
        check_model_folder(output, input_path, overwrite, other_inputs=extra_inputs,
                           side_outputs=(edges_out, extrinsics_out, frames_out))


def _output_sensors(graph, res, input_path, extrinsics_out, frames_out):
    """The sensors whose extrinsics :func:`solve_file` writes: the solve's, or with
    ``extrinsics_out`` and none estimated the given ones (UnsolvableError for rig outputs
    of an input without rigs or sensor ids)."""
    sensors = res.sensors
    if (extrinsics_out or frames_out) and res.frames is None:
        raise UnsolvableError(f"{input_path}: --extrinsics-out / --frames-out need an input with rigs "
                              "(a COLMAP project with rigs, or --rigs FILE)")
    if extrinsics_out and sensors is None:
        from ..estimators.rig_calibration import given_sensor_solution

        sensors = given_sensor_solution(graph.rigs)
        if sensors is None:
            raise UnsolvableError(f"{input_path}: --extrinsics-out needs sensor ids (a COLMAP project or --rigs FILE)")
    return sensors


def _solve_summary(graph, res, opts: SolveOptions, input_path, output, out_fmt: str, seconds: float, t_read: float,
                   certificate, model_counts, with_gravity: bool) -> dict:
    """:func:`solve_file`'s summary (its docstring names the keys)."""
    summary = {
        "input": input_path,
        "output": output,
        "n_cameras": graph.n_nodes,
        "n_edges": graph.n_edges,
        "n_components": res.n_components,
        "n_solved": res.n_solved,
        "n_unsolved": graph.n_nodes - res.n_solved,
        "n_rejected": res.n_rejected,
        "n_outliers": res.n_outliers,
        "outlier_threshold_deg": res.outlier_threshold_deg,
        "diagnostics": res.diagnostics,
        "method": opts.method,
        "options": asdict(opts),
        "iterations": res.iterations,
        "converged": res.converged,
        "cost": res.cost,
        "seconds": seconds,
        "seconds_read": t_read,
        "seconds_solve": res.seconds,
    }
    if certificate is not None:
        summary["certificate"] = certificate
    summary["output_format"] = out_fmt
    if model_counts is not None:
        summary["model"] = model_counts
    if res.frames is not None:
        summary["n_frames"] = int(res.frames.graph.n_nodes)
    if res.sensors is not None:
        summary["sensors"] = res.sensors.to_rows()
    for key in ("n_pairs_stored", "n_pairs_estimated", "n_pairs_skipped"):
        if key in graph.meta:
            summary[key] = graph.meta[key]
    if with_gravity and "gravity" in res.diagnostics:
        summary["gravity"] = res.diagnostics["gravity"]
    ev = evaluate_against_input_gt(graph, res)
    if ev is not None:
        if with_gravity:
            ev.update(_tilt_yaw(graph, res))
        summary["eval"] = ev
    return summary


def _write_outputs(graph, res, input_path, output, out_fmt, edges_out, extrinsics_out, frames_out, sensors, certify):
    """Write the outputs of :func:`solve_file`; returns the model counts (None unless a
    COLMAP model was written)."""
    from ..io.writers import write_edges_csv, write_rotations

    ids, names = graph.node_ids[res.solved], (graph.names[res.solved] if graph.names is not None else None)
    model_counts = None
    if out_fmt == "csv":
        write_rotations(output, ids, names, res.cam_from_world[res.solved])
    elif out_fmt == "text":
        from ..io.writers import write_rotations_text

        write_rotations_text(output, ids, names, res.cam_from_world[res.solved])
    elif out_fmt == "json":
        from ..io.writers import write_rotations_json

        write_rotations_json(output, ids, names, res.cam_from_world[res.solved],
                             extra={"sensors": res.sensors.to_rows()} if res.sensors is not None else None)
    else:
        from ..io.colmap_output import write_colmap_model

        model_counts = write_colmap_model(output, input_path, graph, res, text=out_fmt == "colmap-txt")
    if edges_out:
        i, j = graph.edges[:, 0], graph.edges[:, 1]
        names = (graph.names[i], graph.names[j]) if graph.names is not None else (None, None)
        # with certify, the final weights too: `rotgraph certify --inliers` then checks the same problem
        write_edges_csv(edges_out, graph.node_ids[i], graph.node_ids[j], res.residuals_deg, res.inliers, *names,
                        weight=res.edge_weights if certify else None)
    if extrinsics_out:
        from ..io.writers import write_extrinsics

        write_extrinsics(extrinsics_out, sensors)
    if frames_out:
        from ..io.writers import write_frames

        write_frames(frames_out, _frame_keys(graph, res.frames), res.frames.result.cam_from_world)
    return model_counts


def evaluate_files(estimate, gt, tilt_yaw: bool = False):
    """``rotgraph eval ESTIMATE GT``: read both rotation files, match their cameras
    (:func:`~rotgraph.evaluate.match_cameras`: by name when both have names, else by id;
    fewer than half of either file's matched is an :class:`~rotgraph.errors.InputError`)
    and return :func:`~rotgraph.evaluate.compare_rotations`' result, with ``matched_by``
    and ``n_matched``; with ``tilt_yaw`` ``(result, {"tilt_median_deg", "yaw_median_deg"})``
    (gravity along COLMAP's world +y; the whole gauge aligned)."""
    from ..evaluate import match_cameras
    from ..io.rotations import read_absolute_rotations

    match = match_cameras(read_absolute_rotations(estimate), read_absolute_rotations(gt), path=str(gt))
    E, G = match.estimate, match.ground_truth
    ev = match.compare()
    if not tilt_yaw:
        return ev
    from ..evaluate import tilt_yaw_errors

    ok = np.isfinite(E).all(axis=(1, 2)) & np.isfinite(G).all(axis=(1, 2))
    e = tilt_yaw_errors(E[ok], G[ok], align="full")
    return ev, {"tilt_median_deg": float(np.median(e.tilt_deg)), "yaw_median_deg": float(np.median(e.yaw_deg))}
