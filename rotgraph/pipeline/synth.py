"""``rotgraph synth``: a synthetic problem with ground truth, written to a folder.

The problems themselves are made by :func:`rotgraph.synth.random_problem` and
:func:`rotgraph.synth.random_rig_problem`; this module writes one into a folder
(``edges.txt`` and/or ``edges.npz``, ``gt.txt``, ``meta.json``, and for rigs and gravity
priors ``rigs.txt``, ``gt_extrinsics.csv``, ``gravity.txt``), all of them or none.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from .. import so3
from ..errors import InputError, OptionError
from ..viewgraph import ViewGraph

__all__ = ["SyntheticProblem", "make_synthetic"]

#: The files a problem folder may hold; those of an earlier problem that this one does not
#: write are removed with the write (a folder holds one problem).
_PROBLEM_FILES = ("edges.txt", "edges.npz", "rigs.txt", "gt_extrinsics.csv", "gravity.txt")


@dataclass(frozen=True)
class SyntheticProblem:
    """The outcome of :func:`make_synthetic`.

    Attributes
    ----------
    folder : the folder written.
    graph : the problem (:class:`~rotgraph.viewgraph.ViewGraph` with ``gt_cam_from_world``;
        ``graph.meta["outlier"]`` flags the wrong edges).
    meta : what ``meta.json`` holds (``n``, ``n_edges``, ``n_outlier_edges``,
        ``outlier_edges``, ...).
    files : the files written.
    """

    folder: Path
    graph: ViewGraph
    meta: dict
    files: tuple[Path, ...]


def make_synthetic(
    out_dir,
    *,
    rig: tuple[int, int] | None = None,
    n_rigs: int = 1,
    rig_known: Literal["none", "half", "all"] = "none",
    within_frame: float = 1.0,
    gravity_noise_deg: float | None = None,
    edges_format: Literal["txt", "npz", "both"] = "txt",
    overwrite: bool = False,
    **problem,
) -> SyntheticProblem:
    """Write a synthetic problem with ground truth into ``out_dir`` (made if missing).

    Parameters
    ----------
    out_dir : the folder: ``edges.txt`` (or ``edges.npz``, or both), ``gt.txt`` (``id qw qx
        qy qz``, cam_from_world) and ``meta.json`` (the parameters, the convention and the
        0-based rows of the outlier edges).
    rig : ``(sensors, frames)``: a multi-camera rig problem instead
        (:func:`rotgraph.synth.random_rig_problem`; ``n`` and ``graph`` unused), with
        ``n_rigs`` rigs, the ``cam_from_rig`` of ``rig_known`` sensors given and each pair
        of images of one frame an edge with probability ``within_frame``; also writes
        ``rigs.txt`` and ``gt_extrinsics.csv``.
    gravity_noise_deg : also write ``gravity.txt``: each camera's gravity direction with
        this noise, degrees per tilt axis.
    edges_format : ``"txt"``, ``"npz"`` or ``"both"``.
    overwrite : replace existing files that are not rotgraph's own outputs.
    **problem : the problem, fields of :class:`rotgraph.synth.ProblemOptions`
        (``n``, ``degree``, ``sigma_deg``, ``outliers``, ``graph``, ``seed``,
        ``outlier_model``, ``flip_group``, ``noise_mix`` as a ``(fraction, sigma_deg)``
        pair, ``uncertainty_spread``); those not given take its defaults. A rig problem
        uses ``degree``, ``sigma_deg``, ``outliers`` and ``seed``.

    Returns
    -------
    SyntheticProblem

    Raises
    ------
    OptionError
        ``uncertainty_spread`` with ``sigma_deg == 0`` or a ``noise_mix``; a ``rig`` with
        anything but uniform outliers and isotropic noise.
    InputError
        A folder that cannot be made, or outputs that may not be written
        (:func:`rotgraph.io.outputs.check_outputs`).
    TypeError
        A keyword that is no field of :class:`~rotgraph.synth.ProblemOptions`.
    """
    from ..estimators.gravity import gravity_of, perturb_gravity
    from ..io.atomic import atomic_write, output_group
    from ..io.outputs import check_outputs, is_rotgraph_output
    from ..io.writers import write_absolute_rotations_text, write_edges_npz, write_edges_text_blocks, write_rigs
    from ..synth import ProblemOptions, random_problem, random_rig_problem

    p = ProblemOptions(**problem)  # (checked by random_problem, after the folder)
    n, degree, sigma_deg, outliers, graph, seed = p.n, p.degree, p.sigma_deg, p.outliers, p.graph, p.seed
    outlier_model, flip_group, noise_mix, uncertainty_spread = p.outlier_model, p.flip_group, p.noise_mix, p.uncertainty_spread
    if uncertainty_spread is not None and (sigma_deg == 0 or noise_mix is not None):
        raise OptionError("--uncertainty-spread needs --sigma > 0 and no --noise-mix")
    out = Path(out_dir)
    try:  # before the problem is made: a folder that cannot be made is bad input
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot make the output folder: {exc.strerror or exc}", path=str(out)) from None
    extra = ([out / "rigs.txt", out / "gt_extrinsics.csv"] if rig else []) + ([out / "gravity.txt"] if gravity_noise_deg is not None else [])
    edge_files = [out / f"edges.{x}" for x in (("txt", "npz") if edges_format == "both" else (edges_format,))]
    files = edge_files + [out / "gt.txt", out / "meta.json"] + extra
    check_outputs(files, overwrite=overwrite)
    if rig:
        if uncertainty_spread is not None or noise_mix is not None or outlier_model != "uniform":
            raise OptionError("--rig makes uniform outliers and isotropic noise only")
        g = random_rig_problem(n_frames=rig[1], sensors=rig[0], rigs=n_rigs, degree=degree, sigma_deg=sigma_deg,
                               outliers=outliers, within_frame=within_frame, known=rig_known, seed=seed)
        n, graph = g.n_nodes, "rig"
    else:
        g = random_problem(p)
    # The files of an earlier problem in the folder that this one does not have (edges.npz, rigs.txt, ...) go in the
    # same step, when rotgraph wrote them: a folder holds one problem.
    written = {p.name for p in files}
    stale = [out / f for f in _PROBLEM_FILES if f not in written and (out / f).is_file() and is_rotgraph_output(out / f)]
    with output_group(remove=stale):  # the problem's files appear together, or none of them (earlier ones kept)
        for edge_file in edge_files:  # in blocks: 10^7 edges in seconds and O(E) memory
            (write_edges_npz if edge_file.suffix == ".npz" else write_edges_text_blocks)(edge_file, g)
        write_absolute_rotations_text(out / "gt.txt", g.node_ids, g.gt_cam_from_world)
        if rig:
            write_rigs(out / "rigs.txt", g.node_ids, g.rigs)
            q = so3.quaternions_from_matrices(g.meta["gt_cam_from_rig"])
            with atomic_write(out / "gt_extrinsics.csv") as fh:
                fh.write("sensor_id,qw,qx,qy,qz\n")
                fh.writelines(f"{k},{a!r},{b!r},{c!r},{d!r}\n" for k, (a, b, c, d) in enumerate(q.tolist()))
        if gravity_noise_deg is not None:
            gv = perturb_gravity(gravity_of(g.gt_cam_from_world), gravity_noise_deg, np.random.default_rng([seed, 7]))
            with atomic_write(out / "gravity.txt") as fh:
                fh.write("# image_id gx gy gz: the gravity direction in the camera's frame (COLMAP's world +y), "
                         f"noise {gravity_noise_deg} deg per tilt axis\n")
                fh.writelines(f"{i} {a!r} {b!r} {c!r}\n" for i, (a, b, c) in zip(g.node_ids.tolist(), gv.tolist()))
        is_out = g.meta["outlier"]
        meta = {"n": n, "degree": degree, "sigma_deg": sigma_deg, "outliers": outliers, "graph": graph, "seed": seed,
                **({"rig": {"sensors": rig[0], "frames": rig[1], "rigs": n_rigs, "known": rig_known,
                            "within_frame": within_frame}} if rig else {}),
                **({"gravity_noise_deg": gravity_noise_deg} if gravity_noise_deg is not None else {}),
                "outlier_model": outlier_model, "noise_mix": list(noise_mix) if noise_mix else None,
                "uncertainty_spread": uncertainty_spread,
                "n_edges": g.n_edges, "n_outlier_edges": int(is_out.sum()),
                "convention": ("R_ij = exp([d]x) R_j R_i^T, d ~ N(0, H^-1) with H the edge's info columns" if uncertainty_spread
                               else "R_ij = R_j R_i^T exp([e]x)") + ", R = cam_from_world, quaternions (w, x, y, z)"}
        lists = {"outlier_edges": np.flatnonzero(is_out).tolist()}
        if outlier_model == "flip":
            meta.update(flip_group=flip_group, flip="R_j F R_i^T exp([e]x), F = 180 deg about the world y axis")
            lists["flipped_cameras"] = g.meta["flipped_cameras"].tolist()
        if "loop_closure" in g.meta:
            meta["n_loop_closures"] = int(g.meta["loop_closure"].sum())
        text = json.dumps({**meta, **{k: f"@{k}@" for k in lists}}, indent=2)
        for k, v in lists.items():  # each list on one line, not one line per item
            text = text.replace(f'"@{k}@"', json.dumps(v))
        with atomic_write(out / "meta.json") as fh:
            fh.write(text + "\n")
    return SyntheticProblem(folder=out, graph=g, meta={**meta, **lists}, files=tuple(files))

