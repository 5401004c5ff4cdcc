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
(``colmap-txt``), into the folder (made if needed), as a whole model: its files appear
together, and a model of the other format in the folder is removed in the same step
(:func:`write_model_folder`). A folder that holds a model other than such a
rotations-only one (3D points, frame positions: a reconstruction) is not replaced without
``overwrite`` (:func:`check_model_output`); other files in the folder are never touched.
"""

from __future__ import annotations

import copy
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from ..errors import InputError
from .atomic import atomic_write, output_group

__all__ = ["write_colmap_model", "write_model_folder", "set_extrinsics", "check_model_output", "model_files",
           "MODEL_FILE_NAMES"]

_MODEL_FILES = ("cameras", "images", "points3D", "rigs", "frames")
#: The file names of a COLMAP model (both formats).
MODEL_FILE_NAMES = frozenset(n + e for n in _MODEL_FILES for e in (".bin", ".txt"))


def model_files(folder, ext: str | None = None) -> list[Path]:
    """The COLMAP model files (``cameras``, ``images``, ``points3D``, ``rigs``, ``frames``;
    ``.bin`` and ``.txt``, or ``ext`` alone) that exist in ``folder``."""
    folder = Path(folder)
    exts = (ext,) if ext else (".bin", ".txt")
    return [folder / (n + e) for e in exts for n in _MODEL_FILES if os.path.lexists(folder / (n + e))]


def _n_points(folder: Path, ext: str) -> int | None:
    """How many 3D points ``points3D`` of that format holds (0 when it is missing; None when
    it cannot be read)."""
    f = folder / f"points3D{ext}"
    if not f.exists():
        return 0
    try:
        if ext == ".bin":
            with open(f, "rb") as fh:
                head = fh.read(8)
            return int(np.frombuffer(head, "<u8")[0]) if len(head) == 8 else (0 if not head else None)
        with open(f, encoding="utf-8", errors="replace") as fh:
            return sum(1 for line in fh if line.strip() and not line.lstrip().startswith("#"))
    except (OSError, ValueError):
        return None


def _rotations_only(folder: Path, ext: str) -> bool:
    """Whether the model of that format in ``folder`` is one ``rotgraph solve -o DIR/``
    writes: no 3D points and every registered frame at the origin (rotation averaging
    estimates no positions). A model that cannot be read is not (another tool's
    rotations-only model cannot be told from rotgraph's: it is replaced as one)."""
    if _n_points(folder, ext) != 0:
        return False
    from .colmap_model import read_model

    try:
        rec = read_model(folder, ext.lstrip("."))
    except (InputError, OSError):  # unreadable, a dangling symlink: not a model rotgraph can judge
        return False
    for frame in rec.frames.values():
        if frame.has_pose and np.abs(np.asarray(frame.rig_from_world.translation, float)).max(initial=0.0) > 0:
            return False
    return True


def check_model_output(folder, overwrite: bool = False) -> None:
    """The output rule for a model folder: an :class:`InputError` (exit 3, before any work)
    when ``folder`` holds COLMAP model files that are not a rotgraph rotations-only model
    (a reconstruction with 3D points or camera positions, or files that do not read as a
    model), unless ``overwrite``. Files that are not model files are never touched."""
    folder = Path(folder)
    if overwrite or not folder.is_dir():
        return
    for f in model_files(folder):
        try:
            if not os.stat(f).st_mode & 0o222:
                raise InputError("exists and is read-only (--overwrite replaces it)", path=str(f))
        except OSError:  # a dangling symlink: written through to where it points, as any output
            pass
    for ext in (".bin", ".txt"):
        if not model_files(folder, ext):
            continue
        n = _n_points(folder, ext)
        if n:
            raise InputError(f"holds a COLMAP reconstruction ({n} 3D points in points3D{ext}); --overwrite replaces it, "
                             "or choose another folder", path=str(folder))
        if not _rotations_only(folder, ext):
            raise InputError(f"holds a COLMAP model ({ext}) that is not a rotgraph rotations-only model (camera positions, "
                             "or files that do not read as a model); --overwrite replaces it, or choose another folder",
                             path=str(folder))


def _base_reconstruction(pycolmap, project):
    from .colmap_project import find_colmap_project
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
        f = copy.copy(f)  # pycolmap 4.2 has no Frame(frame) constructor
        f.reset_pose()
        f.reset_rig_ptr()  # the copy still points at src's rig: add_frame links it to rec's
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
    from .colmap_project import to_pycolmap

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
                rig.set_sensor_from_rig(sensor, pycolmap.Rigid3d(to_pycolmap(sensors.cam_from_rig[k]), t))
                changed[id(rig)] = rig
                n += 1
    return n, list(changed.values())


def _counts(rec) -> tuple:
    return (rec.num_cameras(), rec.num_rigs(), rec.num_frames(), rec.num_images(), rec.num_reg_images(), rec.num_points3D())


def _check_written(rec, tmp: str, folder: Path) -> None:
    """The model pycolmap wrote into ``tmp`` reads back as ``rec``: pycolmap's writers do not
    report a full disk (they leave short or empty files), so a model that does not read
    back whole never replaces the one in ``folder``."""
    try:
        ok = _counts(type(rec)(tmp)) == _counts(rec)
    except Exception:  # noqa: BLE001 - unreadable: not written whole
        ok = False
    if not ok:
        try:
            st = os.statvfs(tmp)
            full = st.f_bavail * st.f_frsize < (1 << 20)
        except OSError:
            full = False
        reason = "no space left on device" if full else "the files pycolmap wrote do not read back as the model"
        raise InputError(f"cannot write the model: {reason}", path=str(folder))


def write_model_folder(rec, folder, text: bool = False) -> None:
    """Write the ``pycolmap.Reconstruction`` ``rec`` into ``folder`` (made if missing):
    ``.bin`` files (``text``: ``.txt``) written into a temporary folder inside it, then put
    in place together by :func:`~rotgraph.io.atomic.atomic_write` in one
    :func:`~rotgraph.io.atomic.output_group` (no half-written model file, no model half old and
    half new; an existing symlink is followed and its target replaced, a device or FIFO
    written through, as for every output: CLI.md). The model files of the other format in
    the folder are removed in the same step (pycolmap would read a ``.bin`` model before a
    ``.txt`` one). An :class:`InputError` when the folder cannot be made or written."""
    folder = Path(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot make the output folder: {exc.strerror or exc}", path=str(folder)) from None
    try:
        tmp = tempfile.mkdtemp(prefix=".rotgraph-model-", dir=str(folder))
    except OSError as exc:
        raise InputError(f"cannot write the model: {exc.strerror or exc}", path=str(folder)) from None
    ext = ".txt" if text else ".bin"
    try:
        (rec.write_text if text else rec.write_binary)(tmp)
        _check_written(rec, tmp, folder)
        with output_group(remove=model_files(folder, ".bin" if text else ".txt")):
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
    from .colmap_project import import_pycolmap

    pycolmap = import_pycolmap()
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
