"""COLMAP projects: view graphs from ``database.db`` and sparse models; rotations written back.

* finding a project's database and sparse model (:func:`find_colmap_project`);
* reading: :func:`read_colmap_project` (database or model -> :class:`ViewGraph`, with rig
  frames in ``graph.rigs``), :func:`read_colmap_model_rotations` (ground truth);
* writing: :func:`rotations_by_name`, :func:`write_to_reconstruction` and
  :func:`unposed_reconstruction` (a ``pycolmap.Reconstruction`` to write into).

Solving is not done here: ``average_rotations(graph, default_options("colmap"))`` (see
:mod:`rotgraph.pipeline.solve`) averages the graph read, rig-aware
(:mod:`rotgraph.estimators.rig_rotation_averaging`).

This is the one module of rotgraph (besides the boundary helpers of :mod:`rotgraph.so3`)
that imports :mod:`pycolmap` (through :func:`_pycolmap`; :mod:`rotgraph.synth` and
:mod:`rotgraph.estimators.relative_pose` are handed the module). Every COLMAP file is read
through pycolmap's own API (``pycolmap.Database``, ``pycolmap.Reconstruction``), never by
parsing the SQLite schema.

Inputs are never modified. ``pycolmap.Database.open`` creates missing tables in the file
it opens, so a user's database (and its ``-wal`` file, if any) is only *copied*, byte for
byte, to a private temporary folder; the copy is checked with :mod:`sqlite3` (``mode=ro``:
is it a readable SQLite file?) and opened by pycolmap, then deleted. (Even a read-only
SQLite connection touches the ``-shm`` file of a WAL-mode database, as COLMAP's are, so
the check never runs on the user's file.)

What becomes an edge (following COLMAP 4 / GLOMAP)
-------------------------------------------------
COLMAP 4's global pipeline (GLOMAP, merged into COLMAP) builds its pose graph from the
database's verified two-view geometries:

* ``DatabaseCache`` keeps pairs with ``>= min_num_matches`` inlier matches
  (``GlobalPipelineOptions.min_num_matches = 15``; colmap ``src/colmap/scene/database_cache.cc``,
  ``UseInlierMatchesCheck``);
* ``MaybeDecomposeRelativePoses`` (colmap ``src/colmap/estimators/two_view_geometry.cc``)
  keeps a stored ``cam2_from_cam1`` as is and otherwise decomposes E/F/H with
  ``EstimateTwoViewGeometryPose``, skipping configurations ``UNDEFINED``, ``DEGENERATE``,
  ``WATERMARK`` and ``MULTIPLE``; GLOMAP's stand-alone reader did the same
  (colmap/glomap ``glomap/io/colmap_converter.cc``, ``ConvertDatabaseToGlomap``: "If the
  image is marked as invalid or watermark, then skip");
* ``PoseGraph::Load`` then takes every pair that has a relative pose
  (colmap ``src/colmap/scene/pose_graph.cc``).

So the usable configurations are ``CALIBRATED``, ``UNCALIBRATED`` (E from F and the
cameras' calibration), ``PLANAR``, ``PANORAMIC``, ``PLANAR_OR_PANORAMIC`` (from H) and
``CALIBRATED_RIG`` (its pose is always stored); :data:`USABLE_CONFIGS`. The edge weight is
the inlier count. Where the relative pose is not stored (the default matching pipeline
stores F/E/H and the inlier matches only), it is estimated as COLMAP's
``EstimateTwoViewGeometryPose`` does, from the stored matrix, the inlier matches and the
cameras (:mod:`rotgraph.estimators.relative_pose`: vectorised for E and F, pycolmap's own
routine for the rest); ``graph.meta`` counts the pairs taken from each path and why pairs
were skipped.

Sparse models
-------------
A model folder (``cameras``, ``images``, ``points3D`` as ``.bin`` or ``.txt``; ``rigs`` and
``frames`` in COLMAP 3.12+) gives ground truth (``cam_from_world`` of the registered
images, matched to database images by name) and, without a database, a view graph: the
exact relative rotations between registered images that share at least ``min_inliers``
3D points (weight = shared points).
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import sqlite3
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np

from .. import so3
from ..errors import InputError
from ..estimators import relative_pose
from ..viewgraph import Rigs, ViewGraph

__all__ = [
    "USABLE_CONFIGS",
    "DEFAULT_MIN_INLIERS",
    "find_colmap_project",
    "is_colmap_project",
    "read_colmap_project",
    "read_colmap_model_rotations",
    "rotations_by_name",
    "write_to_reconstruction",
    "unposed_reconstruction",
]

logger = logging.getLogger(__name__)

#: Two-view configurations that give a relative rotation (COLMAP 4 / GLOMAP, see above).
USABLE_CONFIGS = frozenset(
    {"CALIBRATED", "UNCALIBRATED", "PLANAR", "PANORAMIC", "PLANAR_OR_PANORAMIC", "CALIBRATED_RIG"}
)
#: COLMAP's ``GlobalPipelineOptions.min_num_matches`` (inlier matches of a pair).
DEFAULT_MIN_INLIERS = 15

_SQLITE_MAGIC = b"SQLite format 3\x00"


def _pycolmap():
    try:
        import pycolmap
    except ImportError as exc:  # pragma: no cover - pycolmap is a dependency
        raise InputError(f"reading COLMAP projects needs pycolmap ({exc})") from None
    return pycolmap


def _one_line(exc: BaseException) -> str:
    """A pycolmap exception as one short line (drop the ``[file.cc:123]`` prefix)."""
    text = " ".join(str(exc).split())
    if text.startswith("[") and "] " in text[:80]:
        text = text[text.index("] ") + 2 :]
    return text[:300] or type(exc).__name__


# =========================================================================== locating


def _model_format(folder: Path) -> str | None:
    """``"bin"`` or ``"txt"`` when ``folder`` holds a sparse model's cameras and images."""
    for ext in ("bin", "txt"):
        if (folder / f"cameras.{ext}").is_file() and (folder / f"images.{ext}").is_file():
            return ext
    return None


def _find_model(root: Path) -> Path | None:
    """The sparse model of a project folder: the folder itself, ``sparse/0``, ``sparse``,
    ``0``, or the lowest-numbered ``sparse/N`` (COLMAP's mapper writes ``sparse/0``, ...)."""
    for cand in (root, root / "sparse" / "0", root / "sparse", root / "0"):
        if cand.is_dir() and _model_format(cand):
            return cand
    sparse = root / "sparse"
    if sparse.is_dir():
        numbered = sorted((p for p in sparse.iterdir() if p.name.isdigit() and p.is_dir()), key=lambda p: int(p.name))
        for cand in numbered:
            if _model_format(cand):
                return cand
    return None


def find_colmap_project(path) -> tuple[Path | None, Path | None]:
    """``(database, model)`` of a COLMAP project: either may be None.

    ``path`` is a project folder (``database.db``, or a single ``*.db`` file, and/or a
    sparse model in the folder itself, ``sparse/0``, ``sparse`` or ``0``), a model folder,
    or a database file (then a model is looked for beside it).
    """
    p = Path(path)
    if p.is_file():
        return p, _find_model(p.parent)
    if not p.is_dir():
        return None, None
    db = p / "database.db"
    if not db.is_file():
        dbs = sorted(q for q in p.glob("*.db") if q.is_file())
        db = dbs[0] if len(dbs) == 1 else None
    return db, _find_model(p)


def is_colmap_project(path) -> bool:
    """True when ``path`` is a COLMAP database file (by its SQLite header or ``.db``
    name) or a folder holding a database or a sparse model (see :func:`find_colmap_project`)."""
    p = Path(path)
    if p.is_file():
        if p.suffix.lower() == ".db":
            return True
        try:
            with open(p, "rb") as fh:
                return fh.read(16) == _SQLITE_MAGIC
        except OSError:
            return False
    db, model = find_colmap_project(p)
    return db is not None or model is not None


# =========================================================================== database access


def _check_header(path: Path) -> None:
    """A clear InputError unless ``path`` is a non-empty file starting like SQLite."""
    try:
        size = path.stat().st_size
        with open(path, "rb") as fh:
            head = fh.read(16)
    except FileNotFoundError:
        raise InputError("no such file", path=str(path)) from None
    except IsADirectoryError:
        raise InputError("is a folder, expected a COLMAP database file", path=str(path)) from None
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror or exc}", path=str(path)) from None
    if size == 0:
        raise InputError("empty file, not a COLMAP database", path=str(path))
    if head != _SQLITE_MAGIC:
        raise InputError("not an SQLite file, so not a COLMAP database", path=str(path))


def _check_sqlite(copy: str, path: Path) -> None:
    """A clear InputError unless the private ``copy`` of ``path`` is a readable SQLite
    database (opened read-only; even a read-only connection touches the ``-shm`` file of
    a WAL-mode database, which is why this runs on the copy, never on the user's file)."""
    uri = Path(os.path.abspath(copy)).as_uri() + "?mode=ro"
    try:
        con = sqlite3.connect(uri, uri=True)
        try:
            con.execute("SELECT count(*) FROM sqlite_master").fetchone()
        finally:
            con.close()
    except sqlite3.Error as exc:
        raise InputError(f"corrupt or unreadable SQLite file ({exc})", path=str(path)) from None


@contextlib.contextmanager
def _database_copy(path: Path):
    """``pycolmap.Database`` opened on a private copy of ``path`` (never on ``path``: the
    user's files are only read, byte for byte, by ``shutil.copyfile``)."""
    pycolmap = _pycolmap()
    _check_header(path)
    tmp = tempfile.mkdtemp(prefix="rotgraph-colmap-")
    db = None
    try:
        copy = os.path.join(tmp, "database.db")
        try:
            shutil.copyfile(path, copy)
            wal = Path(str(path) + "-wal")
            if wal.is_file():  # writes of a WAL-mode database not yet checkpointed
                shutil.copyfile(wal, copy + "-wal")
        except OSError as exc:
            raise InputError(f"cannot copy the database to a temporary folder: {exc.strerror or exc}", path=str(path)) from None
        _check_sqlite(copy, path)
        try:
            db = pycolmap.Database.open(copy)
        except Exception as exc:  # pycolmap raises ValueError/RuntimeError
            raise InputError(f"cannot open as a COLMAP database: {_one_line(exc)}", path=str(path)) from None
        yield db
    finally:
        if db is not None:
            with contextlib.suppress(Exception):
                db.close()
        shutil.rmtree(tmp, ignore_errors=True)


# =========================================================================== rigs and frames


class _Rigging:
    """Per image: frame id and ``cam_from_rig`` rotation (identity for a rig's reference
    sensor, NaN when unknown)."""

    def __init__(self, image_ids: np.ndarray, frame_ids: np.ndarray, cam_from_rig: np.ndarray):
        self.image_ids = image_ids
        self.frame_ids = frame_ids
        self.cam_from_rig = cam_from_rig

    def rigs(self) -> Rigs:
        return Rigs(self.frame_ids, self.cam_from_rig)


def _cam_from_rig(pycolmap, rig, camera_id: int) -> np.ndarray:
    nan = np.full((3, 3), np.nan)
    if rig is None:
        return np.eye(3)
    sensor = pycolmap.sensor_t(type=pycolmap.SensorType.CAMERA, id=int(camera_id))
    try:
        if rig.is_ref_sensor(sensor):
            return np.eye(3)
        if not rig.has_sensor(sensor) or not rig.has_sensor_from_rig(sensor):
            return nan
        T = rig.sensor_from_rig(sensor)
    except Exception:  # inconsistent rig: treat the sensor as uncalibrated
        return nan
    if T is None:
        return nan
    return so3.from_pycolmap(T.rotation)


def _rigging(pycolmap, images: list, frames: list, rigs: dict) -> _Rigging:
    """Frames and ``cam_from_rig`` of ``images`` (sorted by id), from database or model
    frames. Images in no frame get a frame of their own (old databases)."""
    image_ids = np.array([im.image_id for im in images], dtype=np.int64)
    frame_of = {}
    rig_of_frame = {}
    for fr in frames:
        rig_of_frame[fr.frame_id] = fr.rig_id
        for d in fr.image_ids:
            frame_of[int(d.id)] = int(fr.frame_id)
    next_frame = max(list(frame_of.values()) + [0]) + 1
    frame_ids = np.empty(len(images), dtype=np.int64)
    R = np.empty((len(images), 3, 3))
    for k, im in enumerate(images):
        fid = frame_of.get(int(im.image_id))
        if fid is None:
            frame_ids[k] = next_frame
            next_frame += 1
            R[k] = np.eye(3)
            continue
        frame_ids[k] = fid
        R[k] = _cam_from_rig(pycolmap, rigs.get(rig_of_frame.get(fid)), im.camera_id)
    return _Rigging(image_ids, frame_ids, R)


# =========================================================================== two-view poses


def _config_names(pycolmap, configs) -> set[str]:
    names = set()
    valid = set(pycolmap.TwoViewGeometryConfiguration.__members__)
    for c in USABLE_CONFIGS if configs is None else configs:
        name = c if isinstance(c, str) else getattr(c, "name", None) or pycolmap.TwoViewGeometryConfiguration(int(c)).name
        name = name.upper()
        if name not in valid:
            raise ValueError(f"unknown two-view configuration {c!r}; expected some of {', '.join(sorted(valid))}")
        names.add(name)
    return names


# =========================================================================== readers


def _read_model(path: Path):
    """``pycolmap.Reconstruction`` of a sparse model folder, with clear errors. A model
    without ``points3D`` (e.g. poses only) is read from a temporary copy with an empty one."""
    pycolmap = _pycolmap()
    fmt = _model_format(path)
    if fmt is None:
        raise InputError("not a COLMAP sparse model (expected cameras and images .bin or .txt)", path=str(path))
    tmp = None
    try:
        src = path
        if not (path / f"points3D.{fmt}").is_file():
            tmp = tempfile.mkdtemp(prefix="rotgraph-model-")
            for name in ("cameras", "images", "rigs", "frames"):
                f = path / f"{name}.{fmt}"
                if f.is_file():
                    shutil.copyfile(f, os.path.join(tmp, f.name))
            if fmt == "txt":
                Path(tmp, "points3D.txt").write_text("# no 3D points\n")
            else:
                Path(tmp, "points3D.bin").write_bytes(np.uint64(0).tobytes())
            src = Path(tmp)
        try:
            rec = pycolmap.Reconstruction(str(src))
        except Exception as exc:
            raise InputError(f"cannot read the sparse model (a truncated or corrupt {fmt} file?): {_one_line(exc)}", path=str(path)) from None
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
        model = p.parent if _model_format(p.parent) else None
    else:
        model = p if _model_format(p) else _find_model(p)
    if model is None:
        raise InputError("no COLMAP sparse model here (cameras and images .bin or .txt, in the folder, sparse/0 or 0/)", path=str(p))
    rec = _read_model(model)
    ids, names, R = _model_rotations(rec)
    if len(ids) == 0:
        raise InputError("sparse model has no registered image (no pose)", path=str(model))
    return ids, names, R


def _attach_ground_truth(graph: ViewGraph, model: Path | None, explicit: bool) -> None:
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


def read_colmap_project(
    path,
    *,
    model="auto",
    min_inliers: int = DEFAULT_MIN_INLIERS,
    configs=None,
    estimate_missing: bool = True,
    workers: int | None = None,
    vectorize: bool = True,
    progress=None,
) -> ViewGraph:
    """The view graph of a COLMAP project (image level; see the module docstring).

    ``path``: a project folder (``database.db`` and/or a sparse model in the folder,
    ``sparse/0``, ``sparse`` or ``0/``), a database file, or a model folder.

    * With a database: nodes are all the database's images (``node_ids`` = COLMAP image
      ids, ``names`` = image names), edges its verified pairs whose configuration is in
      ``configs`` (default :data:`USABLE_CONFIGS`) with ``>= min_inliers`` inlier matches
      (weight = inlier count), rotation ``cam2_from_cam1`` stored or, with
      ``estimate_missing``, estimated from the inlier matches and cameras (``workers``
      processes; None = automatic). Ground truth from the sparse model (``model``:
      ``"auto"`` = the project's model, a folder, or None) matched by image name.
    * Without a database: the model's registered images, edges between those sharing
      ``>= min_inliers`` 3D points (exact relative rotations), ground truth = the model.

    ``progress(stage, done, total)``, if given, follows the relative-pose estimation pair
    by pair (``stage`` = ``"relative poses"``).

    ``graph.format`` is ``"colmap"``; ``graph.rigs`` holds each image's frame id and
    ``cam_from_rig`` (NaN when unknown), for the rig-aware solve. ``graph.meta`` is
    informational only (no solver reads it): ``source`` (``"database"``/``"model"``),
    ``n_images``, ``n_pairs_stored``, ``n_pairs_estimated``, ``n_pairs_skipped``,
    ``skipped`` (reason -> count), ``configs`` (configuration -> count of verified pairs,
    database only), ``images_without_pairs`` (names), ``n_ground_truth``, ``summary`` and
    timings.

    Raises :class:`InputError` for a missing, empty, corrupt or non-COLMAP input, a model
    without images, or a project without any usable pair.
    """
    p = Path(path)
    if not p.exists():
        raise InputError("no such file or folder", path=str(p))
    if p.is_file():
        db_path, found_model = p, _find_model(p.parent)
    else:
        db_path, found_model = find_colmap_project(p)
        if db_path is None and found_model is None:
            raise InputError("folder holds no COLMAP database (database.db) or sparse model (cameras/images/points3D .bin or .txt)", path=str(p))
    auto = isinstance(model, str) and model == "auto"
    model_path = found_model if auto else (None if model is None else Path(model))
    if min_inliers < 0:
        raise ValueError("min_inliers must be >= 0")
    t0 = time.perf_counter()
    if db_path is not None:
        graph = _graph_from_database(db_path, min_inliers, configs, estimate_missing, workers, vectorize, progress)
        _attach_ground_truth(graph, model_path, explicit=not auto)
    else:  # the model is the input
        graph = _graph_from_model(model_path or found_model, min_inliers)
    graph.format = "colmap"
    graph.meta["seconds_read"] = time.perf_counter() - t0
    return graph


def _graph_from_database(db_path: Path, min_inliers: int, configs, estimate_missing: bool, workers, vectorize: bool, progress=None) -> ViewGraph:
    pycolmap = _pycolmap()
    usable = _config_names(pycolmap, configs)
    where = str(db_path)
    with _database_copy(db_path) as db:
        try:
            cameras = {int(c.camera_id): c for c in db.read_all_cameras()}
            rigs = {int(r.rig_id): r for r in db.read_all_rigs()}
            frames = list(db.read_all_frames())
            images = sorted(db.read_all_images(), key=lambda im: im.image_id)
            pair_ids, geometries = db.read_two_view_geometries()
        except Exception as exc:
            raise InputError(f"cannot read the COLMAP database: {_one_line(exc)}", path=where) from None
        if not images:
            raise InputError("COLMAP database holds no images (run feature extraction first)", path=where)
        rigging = _rigging(pycolmap, images, frames, rigs)
        image_ids = rigging.image_ids
        names = np.array([im.name for im in images]).astype(str)
        index = {int(i): k for k, i in enumerate(image_ids)}
        cam_of = {}
        for im in images:
            cam = cameras.get(int(im.camera_id))
            if cam is not None:
                cam_of[int(im.image_id)] = cam

        config_name = {int(v): k for k, v in pycolmap.TwoViewGeometryConfiguration.__members__.items()}
        skipped: Counter = Counter()
        config_counts: Counter = Counter()
        keep_pairs, keep_geoms, keep_inliers, stored, todo = [], [], [], [], []
        for pid, g in zip(pair_ids, geometries):
            i, j = (int(x) for x in pycolmap.pair_id_to_image_pair(int(pid)))
            cname = config_name.get(int(g.config), f"UNKNOWN({int(g.config)})")
            config_counts[cname] += 1
            if cname not in usable:
                skipped[f"configuration {cname}"] += 1
                continue
            inl = np.asarray(g.inlier_matches)
            n_inl = len(inl)
            if n_inl < max(min_inliers, 1):
                skipped[f"fewer than {max(min_inliers, 1)} inliers"] += 1
                continue
            if i not in index or j not in index:
                skipped["unknown image id"] += 1
                continue
            if i not in cam_of or j not in cam_of:
                skipped["image without camera"] += 1
                continue
            k = len(keep_pairs)
            keep_pairs.append((i, j))
            keep_geoms.append(g)
            keep_inliers.append(inl)
            if g.cam2_from_cam1 is not None:
                stored.append(k)
            elif estimate_missing:
                todo.append(k)
            else:
                skipped["no stored relative pose (estimate_missing=False)"] += 1
                keep_pairs[k] = None

        # Keypoints only of the images whose pairs need estimating.
        keypoints = {}
        need = {x for k in todo for x in keep_pairs[k]}
        try:
            for i in sorted(need):
                kp = np.asarray(db.read_keypoints(i))
                keypoints[i] = np.ascontiguousarray(kp[:, :2], dtype=np.float64) if kp.size else np.zeros((0, 2))
        except Exception as exc:
            raise InputError(f"cannot read keypoints: {_one_line(exc)}", path=where) from None

    def points(k):
        i, j = keep_pairs[k]
        inl = keep_inliers[k].astype(np.int64)
        return keypoints[i][inl[:, 0]], keypoints[j][inl[:, 1]]

    # Pairs whose inlier matches index past the keypoints cannot be estimated.
    valid_todo = []
    for k in todo:
        i, j = keep_pairs[k]
        inl = keep_inliers[k]
        if inl.size and (inl[:, 0].max() >= len(keypoints[i]) or inl[:, 1].max() >= len(keypoints[j])):
            skipped["inlier match beyond the image's keypoints"] += 1
            keep_pairs[k] = None
        else:
            valid_todo.append(k)

    t_est = time.perf_counter()
    fast: dict = {}
    if vectorize:
        fast, slow = relative_pose.estimate_calibrated(
            valid_todo, keep_geoms, keep_inliers, keep_pairs, cam_of, keypoints,
            calibrated=int(pycolmap.TwoViewGeometryConfiguration.CALIBRATED),
            uncalibrated=int(pycolmap.TwoViewGeometryConfiguration.UNCALIBRATED),
        )
    else:
        slow = valid_todo
    n_todo = len(valid_todo)
    report = None if progress is None else (lambda done, total: progress("relative poses", n_todo - total + done, n_todo))
    if report is not None:
        report(0, len(slow))  # the vectorised calibrated pairs are done
    estimated = dict(zip(slow, relative_pose.estimate_poses(pycolmap, slow, keep_geoms, keep_pairs, cam_of, points, workers, report)))
    estimated.update((k, (q, None)) for k, q in fast.items())
    estimated = [estimated[k] for k in valid_todo]
    t_est = time.perf_counter() - t_est

    ids_i, ids_j, quats, weights = [], [], [], []
    for k in stored:
        i, j = keep_pairs[k]
        q = np.asarray(keep_geoms[k].cam2_from_cam1.rotation.quat, dtype=np.float64)
        if not np.all(np.isfinite(q)) or np.linalg.norm(q) < 0.5:
            skipped["stored relative pose not a rotation"] += 1
            continue
        ids_i.append(i), ids_j.append(j), quats.append([q[3], q[0], q[1], q[2]]), weights.append(len(keep_inliers[k]))
    n_stored = len(ids_i)
    for k, (q, reason) in zip(valid_todo, estimated):
        if reason is not None:
            skipped[reason] += 1
            continue
        i, j = keep_pairs[k]
        ids_i.append(i), ids_j.append(j), quats.append(q), weights.append(len(keep_inliers[k]))
    n_estimated = len(ids_i) - n_stored
    n_skipped = int(sum(skipped.values()))

    summary = (
        f"{len(image_ids)} images, {len(pair_ids)} verified pairs: {n_stored} with a stored relative pose, "
        f"{n_estimated} estimated from the inlier matches, {n_skipped} skipped"
    )
    if skipped:
        summary += " (" + ", ".join(f"{v} {k}" for k, v in skipped.most_common()) + ")"
    logger.info("%s: %s; estimation %.2f s", where, summary, t_est)
    if not ids_i:
        if not pair_ids:
            raise InputError("COLMAP database has no verified image pairs (two_view_geometries is empty: run matching first)", path=where)
        raise InputError(f"no usable image pair: {summary}", path=where)

    R = so3.matrices_from_quaternions(np.asarray(quats))
    graph = ViewGraph.from_edges(
        np.asarray(ids_i, dtype=np.int64), np.asarray(ids_j, dtype=np.int64), R, np.asarray(weights, dtype=np.float64),
        node_ids=image_ids, names=names, duplicates="error", source_path=where,
    )
    deg = graph.degrees()
    lonely = [str(n) for n in names[deg == 0]]
    if lonely:
        logger.info("%s: %d images have no usable pair: %s%s", where, len(lonely), ", ".join(lonely[:10]), " ..." if len(lonely) > 10 else "")
    graph.meta.update(
        source="database",
        database_path=where,
        n_images=len(image_ids),
        n_pairs_verified=len(pair_ids),
        n_pairs_stored=n_stored,
        n_pairs_estimated=n_estimated,
        n_pairs_skipped=n_skipped,
        skipped=dict(skipped),
        configs=dict(config_counts),
        images_without_pairs=lonely,
        seconds_estimate=t_est,
        summary=summary,
    )
    graph.rigs = rigging.rigs()
    return graph


def _covisibility(rec, reg_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pairs (indices into ``reg_ids``) of registered images and their shared 3D points."""
    import scipy.sparse as sp

    pos = {int(i): k for k, i in enumerate(reg_ids)}
    rows, cols = [], []
    for pid, point in rec.points3D.items():
        for el in point.track.elements:
            k = pos.get(int(el.image_id))
            if k is not None:
                rows.append(k)
                cols.append(int(pid))
    if not rows:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
    rows = np.asarray(rows, dtype=np.int64)
    _, cols = np.unique(np.asarray(cols, dtype=np.int64), return_inverse=True)
    A = sp.coo_matrix((np.ones(len(rows)), (rows, cols.ravel())), shape=(len(reg_ids), int(cols.max()) + 1)).tocsr()
    A.data[:] = 1.0  # an image observing a point twice counts once
    C = sp.triu(A @ A.T, k=1).tocoo()
    return C.row.astype(np.int64), C.col.astype(np.int64), C.data


def _graph_from_model(model: Path, min_shared: int) -> ViewGraph:
    pycolmap = _pycolmap()
    rec = _read_model(model)
    ids, names, R = _model_rotations(rec)
    if len(ids) == 0:
        raise InputError("sparse model has no registered image (no pose)", path=str(model))
    a, b, shared = _covisibility(rec, ids)
    keep = shared >= max(min_shared, 1)
    a, b, shared = a[keep], b[keep], shared[keep]
    if len(a) == 0:
        what = "holds no 3D points" if rec.num_points3D() == 0 else f"has no image pair sharing >= {max(min_shared, 1)} 3D points"
        raise InputError(f"sparse model {what}, so it gives no relative rotations (give the project's database.db)", path=str(model))
    rel = R[b] @ np.swapaxes(R[a], 1, 2)
    images = [rec.images[int(i)] for i in ids]
    rigging = _rigging(pycolmap, images, list(rec.frames.values()), {int(k): v for k, v in rec.rigs.items()})
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
    )
    graph.rigs = rigging.rigs()
    graph.meta["summary"] = f"{len(ids)} registered images, {len(a)} covisible pairs (>= {max(min_shared, 1)} shared 3D points)"
    logger.info("%s: %s", model, graph.meta["summary"])
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
    rots = so3.to_pycolmap(R[ok])
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
    there is no sparse model yet. The database is read from a private copy."""
    pycolmap = _pycolmap()
    rec = pycolmap.Reconstruction()
    with _database_copy(Path(database)) as db:
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
    pycolmap = _pycolmap()
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
            S = _cam_from_rig(pycolmap, rig, image.camera_id)
            if not np.isfinite(S).all():
                continue
            acc += S.T @ _as_matrix(r)
            count += 1
        if count == 0:
            continue
        Rf = so3.project_to_so3(acc)
        has_pose = frame.has_pose()
        t = np.asarray(frame.rig_from_world.translation, dtype=np.float64) if has_pose else np.zeros(3)
        frame.rig_from_world = pycolmap.Rigid3d(so3.to_pycolmap(Rf), t)
        if int(fid) not in reg:
            with contextlib.suppress(Exception):
                reconstruction.register_frame(int(fid))
        n_set += 1
    return n_set


