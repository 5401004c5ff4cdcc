"""COLMAP sparse models: read (ground truth, a view graph of covisible images) and written
(rotations set in a ``pycolmap.Reconstruction``).

A model folder (``cameras``, ``images``, ``points3D`` as ``.bin`` or ``.txt``; ``rigs`` and
``frames`` in COLMAP 3.12+) gives ground truth (``cam_from_world`` of the registered
images, matched to database images by name) and, without a database, a view graph: the
exact relative rotations between registered images that share at least ``min_shared``
3D points (weight = shared points). Those rotations are derived from the model's own
poses, so a solve reproduces the model (a 0.000 degree "error" against it): the reader
warns (:data:`POSES_WARNING`) and sets ``meta["relative_rotations_from_poses"]``; the
database's two-view geometries are the real measurements. pycolmap is reached through
:func:`rotgraph.io.colmap_project.import_pycolmap`, as everywhere in rotgraph.
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from .. import so3, so3_checks
from ..errors import InputError
from ..viewgraph import ViewGraph
from .colmap import DEFAULT_MIN_INLIERS
from .colmap_project import (cam_from_rig, database_copy, find_model, import_pycolmap, make_rigging, model_format, one_line,
                             to_pycolmap)

__all__ = [
    "read_colmap_model_rotations",
    "read_colmap_model_graph",
    "attach_ground_truth",
    "rotations_by_name",
    "unposed_reconstruction",
    "write_to_reconstruction",
    "read_model",
]

logger = logging.getLogger(__name__)

#: The warning of :func:`read_colmap_model_graph` (``{model}`` is the model folder).
POSES_WARNING = (
    "{model}: no database.db, so the relative rotations are derived from the model's own poses: a solve "
    "reproduces those poses (0.000 deg 'error' against them), it does not measure anything. To average the "
    "two-view geometries instead, give the project folder that holds database.db, or the database.db itself "
    "(the model beside it is then the ground truth)"
)


def read_model(path: Path, fmt: str | None = None):
    """``pycolmap.Reconstruction`` of a sparse model folder, with clear errors. A model
    without ``points3D`` (e.g. poses only) is read from a temporary copy with an empty one.
    ``fmt`` (``"bin"`` or ``"txt"``): the model of that format (a folder may hold both; a
    temporary copy of that format's files then); default: the one pycolmap reads."""
    pycolmap = import_pycolmap()
    path = Path(path)
    both = model_format(path) is not None and fmt is not None and all(
        (path / f"cameras.{e}").is_file() for e in ("bin", "txt"))
    fmt = fmt or model_format(path)
    if fmt is None or not (path / f"cameras.{fmt}").is_file() or not (path / f"images.{fmt}").is_file():
        raise InputError("not a COLMAP sparse model (expected cameras and images .bin or .txt)", path=str(path))
    tmp = None
    try:
        src = path
        if both or not (path / f"points3D.{fmt}").is_file():
            tmp = tempfile.mkdtemp(prefix="rotgraph-model-")
            for name in ("cameras", "images", "points3D", "rigs", "frames"):
                f = path / f"{name}.{fmt}"
                if f.is_file():
                    shutil.copyfile(f, os.path.join(tmp, f.name))
            if not (path / f"points3D.{fmt}").is_file():
                if fmt == "txt":
                    Path(tmp, "points3D.txt").write_text("# no 3D points\n")
                else:
                    Path(tmp, "points3D.bin").write_bytes(np.uint64(0).tobytes())
            src = Path(tmp)
        try:
            rec = pycolmap.Reconstruction(str(src))
        except Exception as exc:
            raise InputError(f"cannot read the sparse model (a truncated or corrupt {fmt} file?): {one_line(exc)}", path=str(path)) from None
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
    if rec.num_images() == 0:
        raise InputError(f"sparse model holds no images (images.{fmt})", path=str(path / f"images.{fmt}"))
    return rec


def _model_rotations(rec) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    ids = np.array(sorted(int(i) for i in rec.reg_image_ids()), dtype=np.int64)
    names = np.array([rec.images[int(i)].name for i in ids], dtype=object)
    R = np.empty((len(ids), 3, 3))
    for k, i in enumerate(ids):
        R[k] = so3.from_pycolmap(rec.images[int(i)].cam_from_world().rotation)
    return ids, names.astype(str), R


def read_colmap_model_rotations(path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Registered images of a COLMAP sparse model: ``(image_ids, names, cam_from_world)``.

    ``path`` is a model folder (``cameras``/``images``/``points3D`` ``.bin`` or ``.txt``)
    or a project folder holding one (see :func:`find_colmap_project`). Ids are int64,
    names str, rotations ``(N, 3, 3)`` world-to-camera. Use the names to match another
    estimate (``rotgraph eval``): COLMAP image ids differ between projects.
    """
    p = Path(path)
    if not p.exists():
        raise InputError("no such file or folder", path=str(p))
    if p.is_file():  # e.g. images.txt: its folder
        model = p.parent if model_format(p.parent) else None
    else:
        model = p if model_format(p) else find_model(p)
    if model is None:
        raise InputError("no COLMAP sparse model here (cameras and images .bin or .txt, in the folder, sparse/0 or 0/)", path=str(p))
    rec = read_model(model)
    ids, names, R = _model_rotations(rec)
    if len(ids) == 0:
        raise InputError("sparse model has no registered image (no pose)", path=str(model))
    return ids, names, R


def attach_ground_truth(graph: ViewGraph, model: Path | None, explicit: bool) -> None:
    """Set ``graph.gt_cam_from_world`` from a sparse model's registered images, matched by
    image name (a model that cannot be read is an error if ``explicit``, else a warning)."""
    if model is None:
        return
    try:
        _, names, R = read_colmap_model_rotations(model)
    except InputError as exc:
        if explicit:
            raise
        logger.warning("ground truth not read: %s", exc)
        return
    pos = {n: k for k, n in enumerate(names)}
    gt = np.full((graph.n_nodes, 3, 3), np.nan)
    hit = 0
    for k, name in enumerate(graph.names):
        p = pos.get(str(name))
        if p is not None:
            gt[k] = R[p]
            hit += 1
    graph.gt_cam_from_world = gt if hit else None
    graph.meta["model_path"] = str(model)
    graph.meta["n_ground_truth"] = hit
    logger.info("%s: ground truth for %d of %d images (matched by name)", model, hit, graph.n_nodes)


_POINT2D_BIN = np.dtype([("x", "<f8"), ("y", "<f8"), ("point3D_id", "<u8")])
_NO_POINT3D = np.iinfo(np.uint64).max  # COLMAP's kInvalidPoint3DId


def _observations_bin(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """``(image ids, point3D ids)`` of every observation of a 3D point in ``images.bin``
    (COLMAP's ``WriteImagesBinary``: per image its id, pose, camera id, name and its 2D
    points as (x, y, point3D_id) records): one Python step per image, numpy per point."""
    data = Path(path).read_bytes()
    n_images = int(np.frombuffer(data, "<u8", 1, 0)[0])
    pos = 8
    img, pts = [], []
    for _ in range(n_images):
        image_id = int(np.frombuffer(data, "<u4", 1, pos)[0])
        pos += 4 + 7 * 8 + 4  # image id, qvec, tvec, camera id
        pos = data.index(b"\0", pos) + 1  # the name
        n = int(np.frombuffer(data, "<u8", 1, pos)[0])
        pos += 8
        ids = np.frombuffer(data, _POINT2D_BIN, n, pos)["point3D_id"]
        pos += n * _POINT2D_BIN.itemsize
        ids = ids[ids != _NO_POINT3D]
        img.append(np.full(len(ids), image_id, dtype=np.int64))
        pts.append(ids.astype(np.int64))
    if pos != len(data):
        raise ValueError(f"{len(data) - pos} bytes left over")
    return (np.concatenate(img), np.concatenate(pts)) if img else (np.zeros(0, np.int64), np.zeros(0, np.int64))


def _observations_txt(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """``(image ids, point3D ids)`` of every observation in ``images.txt`` (per image one
    line ``IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`` and the next line
    ``X Y POINT3D_ID ...``, -1 for none; COLMAP's ``ReadImagesText``)."""
    img, pts = [], []
    with open(path, encoding="utf-8") as fh:
        for line in fh:
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            image_id = int(line.split(maxsplit=1)[0])
            values = np.array(next(fh, "").split(), dtype=np.float64).reshape(-1, 3)
            ids = values[:, 2]
            ids = ids[ids >= 0].astype(np.int64)
            img.append(np.full(len(ids), image_id, dtype=np.int64))
            pts.append(ids)
    return (np.concatenate(img), np.concatenate(pts)) if img else (np.zeros(0, np.int64), np.zeros(0, np.int64))


def _observations(rec, model: Path | None) -> tuple[np.ndarray, np.ndarray]:
    """``(image ids, point3D ids)`` of the model's observations of its 3D points: decoded
    vectorised from the model's ``images.bin``/``.txt``, the file ``rec`` was read from,
    kept only where the 3D point exists in ``rec``; from ``rec`` itself, a Python loop over
    every track element (seconds per million), only when the file cannot be decoded. The
    caller drops observations of points ``rec`` does not hold."""
    fmt = model_format(model) if model is not None else None
    if fmt is not None:
        try:
            return (_observations_bin if fmt == "bin" else _observations_txt)(model / f"images.{fmt}")
        except (ValueError, OSError, StopIteration) as exc:
            logger.info("%s: images.%s not decoded (%s): observations from pycolmap", model, fmt, exc)
    images, points = [], []
    for pid, point in rec.points3D.items():
        for el in point.track.elements:
            images.append(int(el.image_id))
            points.append(int(pid))
    return np.asarray(images, dtype=np.int64), np.asarray(points, dtype=np.int64)


def _index_of(keys: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Position of each of ``values`` in ``keys`` (distinct non-negative ints), -1 when absent:
    a lookup table when the keys are dense enough (COLMAP's ids count from 1), else a
    binary search."""
    out = np.full(len(values), -1, dtype=np.int64)
    if not len(keys) or not len(values):
        return out
    top = int(keys.max())
    if top <= 4 * len(keys) + 1024:
        lut = np.full(top + 1, -1, dtype=np.int64)
        lut[keys] = np.arange(len(keys))
        ok = (values >= 0) & (values <= top)
        out[ok] = lut[values[ok]]
        return out
    order = np.argsort(keys)
    at = np.minimum(np.searchsorted(keys[order], values), len(keys) - 1)
    hit = keys[order][at] == values
    out[hit] = order[at[hit]]
    return out


def _covisibility(rec, reg_ids: np.ndarray, model: Path | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pairs (indices into ``reg_ids``) of registered images and their shared 3D points."""
    import scipy.sparse as sp

    if rec.num_points3D() == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
    image_ids, point_ids = _observations(rec, model)
    existing = np.sort(np.fromiter(rec.point3D_ids(), dtype=np.int64, count=rec.num_points3D()))
    rows, cols = _index_of(reg_ids, image_ids), _index_of(existing, point_ids)
    keep = (rows >= 0) & (cols >= 0)
    rows, cols = rows[keep], cols[keep]
    if not len(rows):
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
    n, m = len(reg_ids), len(existing)
    A = sp.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, m)).tocsr()
    A.data[:] = 1.0  # an image observing a point twice counts once
    C = sp.triu(A @ A.T, k=1).tocoo()
    return C.row.astype(np.int64), C.col.astype(np.int64), C.data


def read_colmap_model_graph(model, min_shared: int = DEFAULT_MIN_INLIERS) -> ViewGraph:
    """The view graph of a sparse model alone: its registered images, edges between those
    sharing ``>= min_shared`` 3D points (exact relative rotations of the model's poses,
    weight = shared points), ground truth = the model, rig frames from the model.

    The edges are derived from the poses, so solving this graph gives the poses back: one
    warning says so (:data:`POSES_WARNING`: use the database's two-view geometries) and
    ``meta["relative_rotations_from_poses"]`` is True."""
    model = Path(model)
    pycolmap = import_pycolmap()
    rec = read_model(model)
    ids, names, R = _model_rotations(rec)
    if len(ids) == 0:
        raise InputError("sparse model has no registered image (no pose)", path=str(model))
    a, b, shared = _covisibility(rec, ids, model)
    keep = shared >= max(min_shared, 1)
    a, b, shared = a[keep], b[keep], shared[keep]
    if len(a) == 0:
        what = "holds no 3D points" if rec.num_points3D() == 0 else f"has no image pair sharing >= {max(min_shared, 1)} 3D points"
        raise InputError(f"sparse model {what}, so it gives no relative rotations (give the project's database.db)", path=str(model))
    rel = R[b] @ np.swapaxes(R[a], 1, 2)
    images = [rec.images[int(i)] for i in ids]
    rigging = make_rigging(pycolmap, images, list(rec.frames.values()), {int(k): v for k, v in rec.rigs.items()})
    graph = ViewGraph.from_edges(ids[a], ids[b], rel, shared.astype(np.float64), node_ids=ids, names=names, source_path=str(model))
    graph.gt_cam_from_world = R.copy()
    graph.meta.update(
        source="model",
        model_path=str(model),
        n_images=len(ids),
        n_pairs_stored=0,
        n_pairs_estimated=0,
        n_pairs_model=len(a),
        n_pairs_skipped=int((~keep).sum()),
        skipped={f"fewer than {max(min_shared, 1)} shared 3D points": int((~keep).sum())} if (~keep).any() else {},
        images_without_pairs=[str(n) for n in names[graph.degrees() == 0]],
        n_ground_truth=len(ids),
        relative_rotations_from_poses=True,
    )
    graph.rigs = rigging.rigs()
    graph.meta["summary"] = f"{len(ids)} registered images, {len(a)} covisible pairs (>= {max(min_shared, 1)} shared 3D points)"
    graph.format = "colmap"
    logger.info("%s: %s", model, graph.meta["summary"])
    logger.warning("%s", POSES_WARNING.format(model=model))
    return graph


# =========================================================================== output


def rotations_by_name(names, cam_from_world) -> dict:
    """``{image_name: pycolmap.Rotation3d}`` (cam_from_world) of the solved images.

    ``names`` (n,), e.g. ``graph.names``; ``cam_from_world`` (n, 3, 3), e.g. the
    ``cam_from_world`` of ``average_rotations(graph, ...)``. NaN rows (unsolved images)
    are left out.
    """
    R = np.asarray(cam_from_world, dtype=np.float64)
    names = [str(n) for n in names]
    if R.shape != (len(names), 3, 3):
        raise ValueError(f"expected ({len(names)}, 3, 3) rotations, got {R.shape}")
    ok = np.isfinite(R).all(axis=(1, 2))
    if not ok.any():
        return {}
    rots = to_pycolmap(R[ok])
    return dict(zip([n for n, o in zip(names, ok) if o], rots))


def _as_matrix(r) -> np.ndarray:
    if hasattr(r, "matrix"):
        return so3.from_pycolmap(r)
    if hasattr(r, "rotation"):  # Rigid3d
        return so3.from_pycolmap(r.rotation)
    R = np.asarray(r, dtype=np.float64)
    if R.shape == (4,):
        return so3.matrices_from_quaternions(R)
    if R.shape != (3, 3):
        raise ValueError(f"expected a Rotation3d, a (3, 3) matrix or a (w, x, y, z) quaternion, got shape {R.shape}")
    return R


def unposed_reconstruction(database):
    """A ``pycolmap.Reconstruction`` holding the cameras, rigs, frames and images of a
    COLMAP database, without poses: the target of :func:`write_to_reconstruction` when
    there is no sparse model yet. The database is only read: pycolmap opens a private copy
    of just those tables."""
    pycolmap = import_pycolmap()
    rec = pycolmap.Reconstruction()
    with database_copy(Path(database), ("cameras", "rigs", "rig_sensors", "frames", "frame_data", "images")) as db:
        for c in db.read_all_cameras():
            rec.add_camera(c)
        for r in db.read_all_rigs():
            rec.add_rig(r)
        for f in db.read_all_frames():
            rec.add_frame(f)
        for im in db.read_all_images():
            rec.add_image(im)
    return rec


def write_to_reconstruction(reconstruction, rotations_by_image) -> int:
    """Set the rotation of each frame's ``rig_from_world`` in a ``pycolmap.Reconstruction``
    from per-image ``cam_from_world`` rotations; returns the number of frames set.

    ``rotations_by_image`` maps image names (str) or image ids (int) to a
    ``pycolmap.Rotation3d``, a (3, 3) matrix or a ``(w, x, y, z)`` quaternion (e.g. the
    output of :func:`rotations_by_name`). A frame's rotation is ``cam_from_rig^T
    cam_from_world`` of its images with a known ``cam_from_rig`` (their chordal mean when
    several). Translations are kept; a frame without a pose gets a zero translation (and
    is registered), ready for a global positioning step. Frames of which no image has a
    rotation are left untouched.
    """
    pycolmap = import_pycolmap()
    by_name = {str(k): v for k, v in rotations_by_image.items() if isinstance(k, str)}
    by_id = {int(k): v for k, v in rotations_by_image.items() if not isinstance(k, str)}
    n_set = 0
    reg = set(int(f) for f in reconstruction.reg_frame_ids())
    for fid in list(reconstruction.frames.keys()):
        frame = reconstruction.frame(int(fid))
        rig = reconstruction.rig(int(frame.rig_id)) if reconstruction.exists_rig(int(frame.rig_id)) else None
        acc = np.zeros((3, 3))
        count = 0
        for d in frame.image_ids:
            iid = int(d.id)
            if not reconstruction.exists_image(iid):
                continue
            image = reconstruction.image(iid)
            r = by_id.get(iid, by_name.get(image.name))
            if r is None:
                continue
            S = cam_from_rig(pycolmap, rig, image.camera_id)
            if not np.isfinite(S).all():
                continue
            acc += S.T @ _as_matrix(r)
            count += 1
        if count == 0:
            continue
        Rf = so3_checks.project_to_so3(acc)
        has_pose = frame.has_pose()
        t = np.asarray(frame.rig_from_world.translation, dtype=np.float64) if has_pose else np.zeros(3)
        frame.rig_from_world = pycolmap.Rigid3d(to_pycolmap(Rf), t)
        if int(fid) not in reg:
            with contextlib.suppress(Exception):
                reconstruction.register_frame(int(fid))
        n_set += 1
    return n_set
