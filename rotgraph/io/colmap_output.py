"""``rotgraph solve -o MODEL_DIR``: a COLMAP sparse model holding rotgraph's rotations (issue #18).

The model has the project's cameras, rigs, frames and images (from its database, else from
its sparse model), each solved frame registered with ``rig_from_world`` set from the solve
(rotation; the translation is zero: rotation averaging estimates no positions, so a global
positioning step, e.g. ``pycolmap.run_global_positioning`` or ``rotgraph reconstruct``, must
follow before the model is used as a reconstruction) and no 3D points. Extrinsics that the
solve estimated or refined are written into the rigs as ``sensor_from_rig`` (rotation; zero
translation where the rig gave none). Images of a sensor whose ``cam_from_rig`` stays
unknown (``unobservable``) cannot take a pose from their frame and are left unregistered
when their frame has no other image. Written as ``.bin`` (``colmap``) or ``.txt``
(``colmap-txt``), each file atomically into the folder (made if needed).
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from .. import so3
from ..errors import InputError
from .text import atomic_write

__all__ = ["write_colmap_model", "write_model_folder", "set_extrinsics"]

_MODEL_FILES = ("cameras", "images", "points3D", "rigs", "frames")


def _base_reconstruction(pycolmap, project):
    from .colmap import find_colmap_project
    from .colmap_model import unposed_reconstruction

    db, model = find_colmap_project(project)
    if db is not None:
        return unposed_reconstruction(db)
    if model is None:
        raise InputError("a COLMAP model output needs a COLMAP project input (its cameras, rigs, frames and images)",
                         path=str(project))
    src = pycolmap.Reconstruction(str(model))
    rec = pycolmap.Reconstruction()
    for c in src.cameras.values():
        rec.add_camera(c)
    for r in src.rigs.values():
        rec.add_rig(r)
    for f in src.frames.values():
        f = pycolmap.Frame(f)
        f.reset_pose()
        rec.add_frame(f)
    for im in src.images.values():
        rec.add_image(_bare_image(pycolmap, im))
    return rec


def _bare_image(pycolmap, im):
    out = pycolmap.Image()
    out.image_id, out.name, out.camera_id, out.frame_id = im.image_id, im.name, im.camera_id, im.frame_id
    return out


def set_extrinsics(pycolmap, rigs, sensors, stored_only: bool = False) -> tuple[int, list]:
    """``sensor_from_rig`` of every estimated / refined sensor (camera id) of ``sensors`` (a
    :class:`~rotgraph.estimators.types.SensorSolution`) into the ``pycolmap.Rig`` of ``rigs``
    that holds it (its translation kept, zero where none is stored; ``stored_only``: only
    sensors that have a stored one, whose translation is then known). Returns ``(n, rigs)``:
    how many were set, and the rigs changed."""
    changed, n = {}, 0
    if sensors is None:
        return 0, []
    rigs = list(rigs)
    for k, sid in enumerate(sensors.sensor_ids.tolist()):
        if sensors.status[k] not in ("estimated", "refined") or not np.isfinite(sensors.cam_from_rig[k]).all():
            continue
        sensor = pycolmap.sensor_t(type=pycolmap.SensorType.CAMERA, id=int(sid))
        for rig in rigs:
            if rig.has_sensor(sensor) and not rig.is_ref_sensor(sensor):
                old = rig.sensor_from_rig(sensor) if rig.has_sensor_from_rig(sensor) else None
                if old is None and stored_only:
                    continue
                t = np.asarray(old.translation, dtype=np.float64) if old is not None else np.zeros(3)
                rig.set_sensor_from_rig(sensor, pycolmap.Rigid3d(so3.to_pycolmap(sensors.cam_from_rig[k]), t))
                changed[id(rig)] = rig
                n += 1
    return n, list(changed.values())


def write_model_folder(rec, folder, text: bool = False) -> None:
    """Write the ``pycolmap.Reconstruction`` ``rec`` into ``folder`` (made if missing):
    ``.bin`` files (``text``: ``.txt``) written into a temporary folder inside it, then each
    put in place by :func:`~rotgraph.io.text.atomic_write` (no half-written model file; an
    existing symlink is followed and its target replaced, a device or FIFO written through,
    as for every output: CLI.md). An :class:`InputError` when the folder cannot be made or
    written."""
    folder = Path(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot make the output folder: {exc.strerror or exc}", path=str(folder)) from None
    try:
        tmp = tempfile.mkdtemp(prefix=".rotgraph-model-", dir=str(folder))
    except OSError as exc:
        raise InputError(f"cannot write the model: {exc.strerror or exc}", path=str(folder)) from None
    try:
        (rec.write_text if text else rec.write_binary)(tmp)
        ext = ".txt" if text else ".bin"
        for name in _MODEL_FILES:
            src = os.path.join(tmp, name + ext)
            if os.path.exists(src):
                with open(src, "rb") as fin, atomic_write(folder / (name + ext), "wb", newline=None) as fout:
                    shutil.copyfileobj(fin, fout, 1 << 20)
    except OSError as exc:
        raise InputError(f"cannot write the model: {exc.strerror or exc}", path=str(folder)) from None
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def write_colmap_model(folder, project, graph, result, text: bool = False) -> dict:
    """Write the model of the module docstring for ``result`` (an image-level
    :class:`~rotgraph.estimators.types.AveragingResult` of ``graph``, read from the COLMAP
    project ``project``) into ``folder``. Returns counts (``n_frames_registered``,
    ``n_images_registered``, ``n_extrinsics_written``)."""
    from .colmap import _pycolmap

    pycolmap = _pycolmap()
    if graph.format != "colmap":
        raise InputError("a COLMAP model output (-o DIR/, --output-format colmap) needs a COLMAP project input",
                         path=str(project))
    from .colmap_model import write_to_reconstruction

    rec = _base_reconstruction(pycolmap, project)
    # estimated sensor_from_rig rotations, then the solved images' rotations (frames registered)
    n_ext = set_extrinsics(pycolmap, rec.rigs.values(), result.sensors)[0]
    solved = np.flatnonzero(result.solved)
    n_frames = write_to_reconstruction(rec, {int(graph.node_ids[k]): result.cam_from_world[k] for k in solved})
    write_model_folder(rec, folder, text)
    return {"n_frames_registered": int(n_frames), "n_images_registered": int(rec.num_reg_images()),
            "n_extrinsics_written": int(n_ext)}
