"""COLMAP projects: view graphs from ``database.db`` and sparse models; rotations written back.

* finding a project's database and sparse model (:func:`find_colmap_project`);
* reading: :func:`read_two_view_geometries` (a database's images, rigs and usable pairs;
  :func:`rotgraph.pipeline.colmap.read_colmap_project` estimates the relative poses the
  database does not store and builds the view graph), :func:`read_colmap_model_graph` (a
  model alone -> :class:`ViewGraph`, rig frames in ``graph.rigs``), :func:`read_colmap_model_rotations` (ground truth);
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
from collections import Counter
from pathlib import Path
from typing import NamedTuple

import numpy as np

from .. import so3
from ..errors import InputError
from ..viewgraph import Rigs, ViewGraph

__all__ = [
    "USABLE_CONFIGS",
    "DEFAULT_MIN_INLIERS",
    "find_colmap_project",
    "is_colmap_project",
    "locate_colmap_project",
    "read_two_view_geometries",
    "TwoViewGeometries",
    "read_colmap_model_graph",
    "read_colmap_model_rotations",
    "attach_ground_truth",
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


def read_two_view_geometries(db_path, min_inliers: int = DEFAULT_MIN_INLIERS, configs=None, estimate_missing: bool = True) -> TwoViewGeometries:
    """The images, rigs and usable verified pairs of a COLMAP database (see the module
    docstring), read from a private copy: what the view graph is built from.

    Pairs whose configuration is not in ``configs`` (default :data:`USABLE_CONFIGS`), with
    fewer than ``min_inliers`` inlier matches, of unknown images or without a stored
    relative pose (when not ``estimate_missing``) are counted in ``skipped``; the
    keypoints are read only for the pairs whose relative pose must be estimated.
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

        # Keypoints only of the images whose pairs need estimating.
        keypoints = {}
        need = {x for k in todo for x in keep_pairs[k]}
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


def read_colmap_model_graph(model, min_shared: int = DEFAULT_MIN_INLIERS) -> ViewGraph:
    """The view graph of a sparse model alone: its registered images, edges between those
    sharing ``>= min_shared`` 3D points (exact relative rotations of the model's poses,
    weight = shared points), ground truth = the model, rig frames from the model."""
    model = Path(model)
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
    graph.format = "colmap"
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


