"""COLMAP projects: finding them and reading their database (read-only).

* finding a project's database and sparse model (:func:`find_colmap_project`,
  :func:`locate_colmap_project`);
* reading the database: :func:`read_two_view_geometries` (images, rigs and usable pairs;
  :func:`rotgraph.pipeline.colmap.read_colmap_project` estimates the relative poses the
  database does not store and builds the view graph);
* sparse models, read and written: :mod:`rotgraph.io.colmap_model`.

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
from collections import Counter
from pathlib import Path
from typing import NamedTuple

import numpy as np

from .. import so3
from ..errors import InputError
from ..viewgraph import Rigs

__all__ = [
    "USABLE_CONFIGS",
    "DEFAULT_MIN_INLIERS",
    "find_colmap_project",
    "is_colmap_project",
    "locate_colmap_project",
    "read_two_view_geometries",
    "TwoViewGeometries",
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
    """Per image: frame id, ``cam_from_rig`` rotation (identity for a rig's reference
    sensor, NaN when unknown), sensor key (the camera id: one sensor per COLMAP camera) and
    whether it is its rig's reference sensor."""

    def __init__(self, image_ids: np.ndarray, frame_ids: np.ndarray, cam_from_rig: np.ndarray,
                 sensor_ids: np.ndarray, is_reference: np.ndarray):
        self.image_ids = image_ids
        self.frame_ids = frame_ids
        self.cam_from_rig = cam_from_rig
        self.sensor_ids = sensor_ids
        self.is_reference = is_reference

    def rigs(self) -> Rigs:
        return Rigs(self.frame_ids, self.cam_from_rig, self.sensor_ids, self.is_reference)


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
    sensor_ids = np.array([im.camera_id for im in images], dtype=np.int64)
    is_reference = np.zeros(len(images), dtype=bool)
    for k, im in enumerate(images):
        fid = frame_of.get(int(im.image_id))
        if fid is None:
            frame_ids[k] = next_frame
            next_frame += 1
            R[k] = np.eye(3)
            sensor_ids[k] = -1  # a frame of its own: no sensor to calibrate
            continue
        frame_ids[k] = fid
        rig = rigs.get(rig_of_frame.get(fid))
        R[k] = _cam_from_rig(pycolmap, rig, im.camera_id)
        is_reference[k] = _is_reference(pycolmap, rig, im.camera_id)
    return _Rigging(image_ids, frame_ids, R, sensor_ids, is_reference)


def _is_reference(pycolmap, rig, camera_id: int) -> bool:
    if rig is None:
        return True
    try:
        return bool(rig.is_ref_sensor(pycolmap.sensor_t(type=pycolmap.SensorType.CAMERA, id=int(camera_id))))
    except Exception:
        return False


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


# =========================================================================== the database


def locate_colmap_project(path, model="auto") -> tuple[Path | None, Path | None, bool]:
    """``(database, sparse model, model given explicitly)`` of a COLMAP input: a project
    folder (``database.db`` and/or a sparse model in the folder, ``sparse/0``, ``sparse``
    or ``0/``), a database file, or a model folder; ``model`` is ``"auto"`` (the project's
    model), a folder, or None. Raises :class:`InputError` when there is neither."""
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
    if db_path is None:
        model_path = model_path or found_model
    return db_path, model_path, not auto


def read_two_view_geometries(
    db_path, min_inliers: int = DEFAULT_MIN_INLIERS, configs=None, estimate_missing: bool = True, *, all_keypoints: bool = False
) -> TwoViewGeometries:
    """The images, rigs and usable verified pairs of a COLMAP database (see the module
    docstring), read from a private copy: what the view graph is built from.

    Pairs whose configuration is not in ``configs`` (default :data:`USABLE_CONFIGS`), with
    fewer than ``min_inliers`` inlier matches, of unknown images or without a stored
    relative pose (when not ``estimate_missing``) are counted in ``skipped``; the
    keypoints are read only for the pairs whose relative pose must be estimated, or with
    ``all_keypoints`` for every usable pair (the stored ones too: their inlier matches
    give each pair's rotation uncertainty). A stored pair whose inlier matches index past
    its images' keypoints stays an edge (its pose is stored); :meth:`TwoViewGeometries.points`
    cannot be used for it.
    """
    db_path = Path(db_path)
    if min_inliers < 0:
        raise ValueError("min_inliers must be >= 0")
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

        # Keypoints only of the images whose pairs need estimating (all_keypoints: of all).
        keypoints = {}
        need = {x for k in (todo + stored if all_keypoints else todo) for x in keep_pairs[k]}
        try:
            for i in sorted(need):
                kp = np.asarray(db.read_keypoints(i))
                keypoints[i] = np.ascontiguousarray(kp[:, :2], dtype=np.float64) if kp.size else np.zeros((0, 2))
        except Exception as exc:
            raise InputError(f"cannot read keypoints: {_one_line(exc)}", path=where) from None

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

    return TwoViewGeometries(
        where, image_ids, names, rigging.rigs(), cam_of, keep_pairs, keep_geoms, keep_inliers, keypoints, stored,
        valid_todo, skipped, config_counts, len(pair_ids), pycolmap,
    )


class TwoViewGeometries(NamedTuple):
    """What :func:`read_two_view_geometries` reads. Pair ``k`` joins the images
    ``pairs[k]`` (COLMAP ids; None when skipped after all) with ``geometries[k]`` (a
    ``pycolmap.TwoViewGeometry``) and its ``inliers[k]`` (M, 2) keypoint indices;
    ``stored`` lists the pairs with a stored ``cam2_from_cam1``, ``todo`` those whose
    relative pose must be estimated from ``keypoints`` (image id -> (K, 2) pixels) and
    ``cameras`` (image id -> ``pycolmap.Camera``)."""

    path: str
    image_ids: np.ndarray
    names: np.ndarray
    rigs: Rigs
    cameras: dict
    pairs: list
    geometries: list
    inliers: list
    keypoints: dict
    stored: list
    todo: list
    skipped: Counter
    configs: Counter
    n_verified: int
    pycolmap: object

    def points(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates of the inlier matches of pair ``k`` in its two images."""
        i, j = self.pairs[k]
        inl = self.inliers[k].astype(np.int64)
        return self.keypoints[i][inl[:, 0]], self.keypoints[j][inl[:, 1]]

    def stored_quaternion(self, k: int) -> np.ndarray | None:
        """The stored ``cam2_from_cam1`` of pair ``k`` as ``(w, x, y, z)``, None if unusable."""
        q = np.asarray(self.geometries[k].cam2_from_cam1.rotation.quat, dtype=np.float64)  # x, y, z, w
        if not np.all(np.isfinite(q)) or np.linalg.norm(q) < 0.5:
            return None
        return np.array([q[3], q[0], q[1], q[2]])
