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

This is the one module of rotgraph that imports :mod:`pycolmap` (through
:func:`import_pycolmap`; :func:`to_pycolmap` makes its rotations; :mod:`rotgraph.synth` and
:mod:`rotgraph.estimators.relative_pose` are handed the module). Sparse models are read
by ``pycolmap.Reconstruction``.

Reading a database: only what rotation averaging needs, the user's file never written
------------------------------------------------------------------------------------
``pycolmap.Database.open`` creates and migrates tables in the file it opens, and copying
the whole file first costs O(its size), nearly all of it descriptors and raw matches. So
the database is opened with :mod:`sqlite3` strictly read-only (:func:`_readonly_connection`:
``mode=ro``, or ``immutable=1`` for a WAL-mode file without pending ``-wal`` content, which
``mode=ro`` would otherwise touch; see :func:`_read_mode` for the measured choice) and, for
a database of COLMAP 4's schema (``PRAGMA user_version`` past pycolmap's last migration),
the tables ``cameras``, ``images``, ``frames``/``frame_data``, ``rigs``/``rig_sensors``,
``two_view_geometries`` (decoded only for the pairs of a usable configuration with enough
inliers) and the ``keypoints`` of the images whose pairs need them are decoded with numpy,
as COLMAP's ``database_sqlite.cc`` writes them (matrices row-major float64, quaternions
``w, x, y, z``, inlier matches uint32 rows of 2, keypoints float32 rows of 2, 4 or 6). An
older schema is copied table by table (descriptors and raw matches left out) into a small
private database that pycolmap opens, migrates and reads (:func:`database_copy`), so it
reads exactly as pycolmap reads the original. The only full copy left is a WAL-mode
database whose ``-wal`` still holds commits (a COLMAP still writing, or killed): SQLite
replays a WAL only by writing beside it, so that file is read from a private copy.

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
from ..errors import InputError, OptionError
from ..viewgraph import Rigs

__all__ = [
    "USABLE_CONFIGS",
    "DEFAULT_MIN_INLIERS",
    "find_colmap_project",
    "is_colmap_project",
    "locate_colmap_project",
    "read_two_view_geometries",
    "TwoViewGeometries",
    "pair_ids",
    "write_pair_rotations",
    "import_pycolmap",
    "to_pycolmap",
    "one_line",
    "model_format",
    "find_model",
    "database_copy",
    "cam_from_rig",
    "make_rigging",
]

logger = logging.getLogger(__name__)

#: Two-view configurations that give a relative rotation (COLMAP 4 / GLOMAP, see above).
USABLE_CONFIGS = frozenset(
    {"CALIBRATED", "UNCALIBRATED", "PLANAR", "PANORAMIC", "PLANAR_OR_PANORAMIC", "CALIBRATED_RIG"}
)
#: COLMAP's ``GlobalPipelineOptions.min_num_matches`` (inlier matches of a pair).
DEFAULT_MIN_INLIERS = 15

_SQLITE_MAGIC = b"SQLite format 3\x00"


def import_pycolmap():
    try:
        import pycolmap
    except ImportError as exc:  # pragma: no cover - pycolmap is a dependency
        raise InputError(f"reading COLMAP projects needs pycolmap ({exc})") from None
    return pycolmap


def to_pycolmap(R: np.ndarray):
    """``pycolmap.Rotation3d`` of a ``(3, 3)`` matrix, or a list of them for a batch
    (:func:`rotgraph.so3.from_pycolmap` goes back).

    Parameters
    ----------
    R : (3, 3) or (N, 3, 3) rotation matrices.

    Returns
    -------
    pycolmap.Rotation3d, or a list of N of them.
    """
    pycolmap = import_pycolmap()
    xyzw = np.ascontiguousarray(so3.xyzw_from_wxyz(so3.quaternions_from_matrices(R)))  # pycolmap stores (x, y, z, w)
    if xyzw.ndim == 1:
        return pycolmap.Rotation3d(xyzw)
    return [pycolmap.Rotation3d(x) for x in xyzw]  # one roll for the batch: 5x faster than one per item


def one_line(exc: BaseException) -> str:
    """A pycolmap exception as one short line (drop the ``[file.cc:123]`` prefix)."""
    text = " ".join(str(exc).split())
    if text.startswith("[") and "] " in text[:80]:
        text = text[text.index("] ") + 2 :]
    return text[:300] or type(exc).__name__


# =========================================================================== locating


def model_format(folder: Path) -> str | None:
    """``"bin"`` or ``"txt"`` when ``folder`` holds a sparse model's cameras and images."""
    for ext in ("bin", "txt"):
        if (folder / f"cameras.{ext}").is_file() and (folder / f"images.{ext}").is_file():
            return ext
    return None


def find_model(root: Path) -> Path | None:
    """The sparse model of a project folder: the folder itself, ``sparse/0``, ``sparse``,
    ``0``, or the lowest-numbered ``sparse/N`` (COLMAP's mapper writes ``sparse/0``, ...)."""
    for cand in (root, root / "sparse" / "0", root / "sparse", root / "0"):
        if cand.is_dir() and model_format(cand):
            return cand
    sparse = root / "sparse"
    if sparse.is_dir():
        numbered = sorted((p for p in sparse.iterdir() if p.name.isdigit() and p.is_dir()), key=lambda p: int(p.name))
        for cand in numbered:
            if model_format(cand):
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
        return p, find_model(p.parent)
    if not p.is_dir():
        return None, None
    db = p / "database.db"
    if not db.is_file():
        dbs = sorted(q for q in p.glob("*.db") if q.is_file())
        db = dbs[0] if len(dbs) == 1 else None
    return db, find_model(p)


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


def _check_header(path: Path) -> bytes:
    """The first 100 bytes of ``path`` (SQLite's header); a clear InputError unless it is a
    non-empty file starting like SQLite."""
    try:
        size = path.stat().st_size
        with open(path, "rb") as fh:
            head = fh.read(100)
    except FileNotFoundError:
        raise InputError("no such file", path=str(path)) from None
    except IsADirectoryError:
        raise InputError("is a folder, expected a COLMAP database file", path=str(path)) from None
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror or exc}", path=str(path)) from None
    if size == 0:
        raise InputError("empty file, not a COLMAP database", path=str(path))
    if head[:16] != _SQLITE_MAGIC:
        raise InputError("not an SQLite file, so not a COLMAP database", path=str(path))
    return head


def _nonempty(path: Path) -> bool:
    try:
        return path.stat().st_size > 0
    except OSError:
        return False


def _read_mode(path: Path, head: bytes) -> str:
    """How :func:`_readonly_connection` opens ``path`` (measured on SQLite 3.40; see
    ``tests/test_colmap_readonly.py``):

    * ``"ro"`` (``?mode=ro``): a rollback-journal database (header bytes 18-19 = 1), the
      SQLite default. A read-only connection takes a shared lock (a concurrent writer is
      waited for, never seen half-way) and creates or changes no file.
    * ``"immutable"`` (``?immutable=1``): a WAL-mode database (bytes 18-19 = 2, as COLMAP
      4 writes them) whose ``-wal`` file is absent or empty, i.e. every committed write is
      in the main file. ``mode=ro`` would create ``-wal`` and ``-shm`` files beside it,
      or write its read marks into an existing ``-shm``; ``immutable=1`` touches nothing
      (no lock either: a writer that *starts* during the read only appends to a new
      ``-wal``; a checkpoint into the main file while rotgraph reads would be missed,
      which needs another process writing 1000 pages meanwhile).
    * ``"copy"``: a WAL-mode database with a non-empty ``-wal`` (a COLMAP still running,
      or one that did not close the database), or a rollback database with a ``-journal``
      to roll back: the committed content needs SQLite to replay those files, which it
      does only by writing (the ``-shm``, or the main file). The database and that file
      are copied, byte for byte, to a private folder and read there: the one case that
      still costs a copy of the file.
    """
    wal = head[18] == 2 or head[19] == 2
    if wal:
        return "copy" if _nonempty(Path(str(path) + "-wal")) else "immutable"
    return "copy" if _nonempty(Path(str(path) + "-journal")) else "ro"


def _connect_readonly(path: Path, mode: str) -> sqlite3.Connection:
    query = "immutable=1" if mode == "immutable" else "mode=ro"
    con = sqlite3.connect(Path(os.path.abspath(path)).as_uri() + "?" + query, uri=True, check_same_thread=False)
    con.execute("PRAGMA query_only = 1")
    return con


@contextlib.contextmanager
def _readonly_connection(path: Path):
    """``(sqlite3 connection, mode)`` reading ``path`` strictly read-only (``mode``: see
    :func:`_read_mode`); the user's files are never written (nor created beside it). A
    file SQLite cannot read raises a one-line InputError naming ``path``."""
    head = _check_header(path)
    mode = _read_mode(path, head)
    tmp = None
    con = None
    try:
        source = path
        if mode == "copy":
            tmp = tempfile.mkdtemp(prefix="rotgraph-colmap-")
            source = Path(tmp, "database.db")
            try:
                shutil.copyfile(path, source)
                for suffix in ("-wal", "-journal"):
                    extra = Path(str(path) + suffix)
                    if extra.is_file():
                        shutil.copyfile(extra, str(source) + suffix)
            except OSError as exc:
                raise InputError(f"cannot copy the database to a temporary folder: {exc.strerror or exc}", path=str(path)) from None
            logger.info("%s: uncommitted %s file: reading a private copy of the database", path,
                        "-wal" if Path(str(path) + "-wal").is_file() else "-journal")
        try:
            if mode == "copy":  # the private copy replays its -wal / -journal on open
                con = sqlite3.connect(str(source), check_same_thread=False)
            else:
                con = _connect_readonly(source, mode)
            con.execute("SELECT count(*) FROM sqlite_master").fetchone()
        except sqlite3.Error as exc:
            raise InputError(f"corrupt or unreadable SQLite file ({exc})", path=str(path)) from None
        yield con, mode
    finally:
        if con is not None:
            con.close()
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)


def _tables(con: sqlite3.Connection) -> dict:
    """``{table name: [column names]}`` of the database."""
    names = [r[0] for r in con.execute("SELECT name FROM sqlite_master WHERE type = 'table'")]
    return {n: [r[1] for r in con.execute(f'PRAGMA table_info("{n}")')] for n in names}


#: Tables a private copy leaves empty unless asked for (:func:`database_copy`): the raw
#: descriptors and matches, nearly all of a database's size, which rotgraph never reads.
BULK_TABLES = ("descriptors", "matches")


@contextlib.contextmanager
def database_copy(path: Path, tables=None):
    """``pycolmap.Database`` opened on a private, *small* copy of ``path`` (never on
    ``path``: pycolmap creates and migrates tables in the file it opens).

    The copy holds the schema of every table and index of ``path`` and the rows of
    ``tables`` (an iterable of table names; None: every table but :data:`BULK_TABLES`,
    the descriptors and raw matches), copied by SQLite from a strictly read-only
    connection (:func:`_readonly_connection`), with ``path``'s ``user_version`` so that
    pycolmap migrates an old schema exactly as it would the whole file. So reading
    cameras, rigs, frames, images, pose priors, keypoints or two-view geometries through
    it gives what pycolmap reads from the original, at the cost of those tables only."""
    pycolmap = import_pycolmap()
    tmp = tempfile.mkdtemp(prefix="rotgraph-colmap-")
    db = None
    try:
        copy = os.path.join(tmp, "database.db")
        with _readonly_connection(Path(path)) as (src, _mode):
            try:
                schema = _tables(src)
                keep = set(schema) - set(BULK_TABLES) if tables is None else set(tables) & set(schema)
                version = src.execute("PRAGMA user_version").fetchone()[0]
                ddl = [(t, n, s) for t, n, s in src.execute("SELECT type, name, sql FROM sqlite_master WHERE sql IS NOT NULL")]
                dst = sqlite3.connect(copy)
                try:
                    dst.execute("PRAGMA journal_mode = OFF")
                    dst.execute("PRAGMA synchronous = OFF")
                    for kind, name, sql in ddl:  # tables first, then indices
                        if kind == "table" and not name.startswith("sqlite_"):
                            dst.execute(sql)
                    for name in sorted(keep):
                        if name.startswith("sqlite_"):
                            continue
                        cols = ", ".join(f'"{c}"' for c in schema[name])
                        rows = src.execute(f'SELECT {cols} FROM "{name}"')
                        marks = ", ".join("?" * len(schema[name]))
                        while True:
                            chunk = rows.fetchmany(4096)
                            if not chunk:
                                break
                            dst.executemany(f'INSERT INTO "{name}" ({cols}) VALUES ({marks})', chunk)
                    if "sqlite_sequence" in schema:
                        dst.execute("DELETE FROM sqlite_sequence")
                        dst.executemany("INSERT INTO sqlite_sequence (name, seq) VALUES (?, ?)",
                                        src.execute("SELECT name, seq FROM sqlite_sequence").fetchall())
                    for kind, name, sql in ddl:
                        if kind in ("index", "trigger", "view"):
                            dst.execute(sql)
                    dst.execute(f"PRAGMA user_version = {int(version)}")
                    dst.commit()
                finally:
                    dst.close()
            except sqlite3.Error as exc:
                raise InputError(f"corrupt or unreadable SQLite file ({exc})", path=str(path)) from None
        try:
            db = pycolmap.Database.open(copy)
        except Exception as exc:  # pycolmap raises ValueError/RuntimeError
            raise InputError(f"cannot open as a COLMAP database: {one_line(exc)}", path=str(path)) from None
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


def cam_from_rig(pycolmap, rig, camera_id: int) -> np.ndarray:
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


def make_rigging(pycolmap, images: list, frames: list, rigs: dict) -> _Rigging:
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
        R[k] = cam_from_rig(pycolmap, rig, im.camera_id)
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
            raise OptionError(f"unknown two-view configuration {c!r}; expected some of {', '.join(sorted(valid))}")
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
        db_path, found_model = p, find_model(p.parent)
    else:
        db_path, found_model = find_colmap_project(p)
        if db_path is None and found_model is None:
            raise InputError("folder holds no COLMAP database (database.db) or sparse model (cameras/images/points3D .bin or .txt)", path=str(p))
    auto = isinstance(model, str) and model == "auto"
    model_path = found_model if auto else (None if model is None else Path(model))
    if db_path is None:
        model_path = model_path or found_model
    return db_path, model_path, not auto


#: The columns the direct reader needs (the schema of COLMAP 4: ``database_sqlite.cc``).
_DIRECT_SCHEMA = {
    "cameras": ("camera_id", "model", "width", "height", "params", "prior_focal_length"),
    "images": ("image_id", "name", "camera_id"),
    "rigs": ("rig_id", "ref_sensor_id", "ref_sensor_type"),
    "rig_sensors": ("rig_id", "sensor_id", "sensor_type", "sensor_from_rig"),
    "frames": ("frame_id", "rig_id"),
    "frame_data": ("frame_id", "data_id", "sensor_id", "sensor_type"),
    "two_view_geometries": ("pair_id", "rows", "cols", "data", "config", "F", "E", "H", "qvec", "tvec"),
    "keypoints": ("image_id", "rows", "cols", "data"),
}
#: ``PRAGMA user_version`` above which pycolmap 4 migrates nothing on open (COLMAP's
#: ``PostMigrateTables``: identity / zero poses and zero E/F/H matrices become NULL in
#: databases of version <= 3.14.0.1, ``MakeDatabaseVersionNumber``).
_MIGRATED_VERSION = 3140001
#: COLMAP's ``kMaxNumImages``: ``pair_id = kMaxNumImages * image_id1 + image_id2``.
_MAX_NUM_IMAGES = 2147483647


def pair_ids(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """COLMAP's ``ImagePairToPairId`` of image ids ``a``, ``b`` (the smaller first), vectorised:
    ``lo * 2147483647 + hi``, which the pair readers below split again."""
    lo, hi = np.minimum(a, b).astype(np.int64), np.maximum(a, b).astype(np.int64)
    return lo * _MAX_NUM_IMAGES + hi


def write_pair_rotations(pycolmap, db, pair_ids: np.ndarray, cam2_from_cam1: np.ndarray) -> int:
    """Into the (private) database ``db``: the rotation of each pair of ``pair_ids`` set to
    its ``cam2_from_cam1`` (its translation kept, (0, 0, 1) where none is stored), every
    other pair's pose cleared. One transaction. Returns the number of rows rewritten."""
    rots = dict(zip(pair_ids.tolist(), to_pycolmap(cam2_from_cam1))) if len(pair_ids) else {}
    unit = np.array([0.0, 0.0, 1.0])
    n = 0
    with pycolmap.DatabaseTransaction(db):
        for pid, tvg in zip(*db.read_two_view_geometries()):
            pid = int(pid)
            old = tvg.cam2_from_cam1
            if pid in rots:
                t = unit if old is None or not np.any(old.translation) else old.translation
                tvg.cam2_from_cam1 = pycolmap.Rigid3d(rots[pid], t)
            elif old is not None:
                tvg.cam2_from_cam1 = None
            else:
                continue
            db.update_two_view_geometry(*pycolmap.pair_id_to_image_pair(pid), tvg)
            n += 1
    return n


_CAMERA = 0  # SensorType::CAMERA


def _direct_readable(con: sqlite3.Connection) -> bool:
    """True when the database has COLMAP 4's schema and needs no migration: its tables are
    then decoded directly (:func:`_read_direct`); otherwise pycolmap reads a small private
    copy (:func:`database_copy`) and migrates it as it would the original."""
    version = con.execute("PRAGMA user_version").fetchone()[0]
    if version <= _MIGRATED_VERSION:
        return False
    tables = _tables(con)
    return all(t in tables and set(cols) <= set(tables[t]) for t, cols in _DIRECT_SCHEMA.items())


def _blob_matrices(blobs: list, n: int, what: str, where: str) -> tuple[np.ndarray, np.ndarray]:
    """``(values (P, n) float64, present (P,) bool)`` of little-endian float64 blobs (NULL:
    absent, NaN; empty: zeros, as COLMAP's ``ReadStaticMatrixBlob``)."""
    P = len(blobs)
    out = np.full((P, n), np.nan)
    present = np.array([b is not None for b in blobs], dtype=bool)
    full = [k for k in np.flatnonzero(present) if len(blobs[k])]
    empty = [k for k in np.flatnonzero(present) if not len(blobs[k])]
    if any(len(blobs[k]) != 8 * n for k in full):
        raise InputError(f"cannot read the COLMAP database: a {what} blob is not {n} doubles", path=where)
    if full:
        out[full] = np.frombuffer(b"".join(blobs[k] for k in full), dtype="<f8").reshape(-1, n)
    out[empty] = 0.0
    return out, present


class _Pose(NamedTuple):
    rotation: object  # .quat: (x, y, z, w), as pycolmap.Rotation3d
    translation: np.ndarray


class _Quat(NamedTuple):
    quat: np.ndarray


class _View:
    """A light, read-only ``pycolmap.TwoViewGeometry`` look-alike (``config``, ``F``, ``E``,
    ``H``: None when not stored; ``cam2_from_cam1``: ``.rotation.quat`` and
    ``.translation``, or None) of pair ``k`` of a :class:`TwoViewGeometries`."""

    __slots__ = ("_d", "_k")

    def __init__(self, data, k: int):
        self._d, self._k = data, k

    @property
    def config(self) -> int:
        return int(self._d.config[self._k])

    def _matrix(self, name):
        d, k = self._d, self._k
        return d.matrices[name][k] if d.has_matrix[name][k] else None

    F = property(lambda self: self._matrix("F"))
    E = property(lambda self: self._matrix("E"))
    H = property(lambda self: self._matrix("H"))

    @property
    def cam2_from_cam1(self):
        d, k = self._d, self._k
        if not d.has_pose[k]:
            return None
        w, x, y, z = d.qvec[k]
        return _Pose(_Quat(np.array([x, y, z, w])), d.tvec[k].copy())


class _Views:
    """Pair ``k`` -> :class:`_View` (built on access)."""

    def __init__(self, data):
        self._d = data

    def __len__(self):
        return len(self._d.config)

    def __getitem__(self, k):
        return _View(self._d, int(k))


class _PycolmapGeometries:
    """Pair ``k`` -> a ``pycolmap.TwoViewGeometry`` (config, F/E/H, ``cam2_from_cam1`` and
    inlier matches of the database), built on first access and kept: what
    ``pycolmap.estimate_two_view_geometry_pose`` takes (and fills in)."""

    def __init__(self, data, pycolmap):
        self._d, self._pycolmap, self._made = data, pycolmap, {}

    def __len__(self):
        return len(self._d.config)

    def __getitem__(self, k):
        k = int(k)
        g = self._made.get(k)
        if g is None:
            pc, d = self._pycolmap, self._d
            g = pc.TwoViewGeometry()
            g.config = pc.TwoViewGeometryConfiguration(int(d.config[k]))
            for name in ("F", "E", "H"):
                if d.has_matrix[name][k]:
                    setattr(g, name, d.matrices[name][k])
            if d.has_pose[k]:
                w, x, y, z = d.qvec[k]
                g.cam2_from_cam1 = pc.Rigid3d(pc.Rotation3d(np.array([x, y, z, w])), d.tvec[k])
            g.inlier_matches = np.ascontiguousarray(d.inliers[k], dtype=np.uint32)
            self._made[k] = g
        return g


class _Segments:
    """``seg[k]``: rows ``start[k]:end[k]`` of one (M, 2) table (no copy)."""

    def __init__(self, table: np.ndarray, start: np.ndarray, end: np.ndarray):
        self.table, self.start, self.end = table, start, end

    def __len__(self):
        return len(self.start)

    def __getitem__(self, k):
        return self.table[self.start[k] : self.end[k]]


class _Raw(NamedTuple):
    """The verified pairs of a database, decoded (one row per pair, in ``pair_id`` order)."""

    pair_ids: np.ndarray  # (P,) int64
    config: np.ndarray  # (P,) int64
    n_inliers: np.ndarray  # (P,) int64
    inliers: object  # k -> (n_inliers[k], 2) uint32
    matrices: dict  # "F"/"E"/"H" -> (P, 3, 3), NaN when absent
    has_matrix: dict  # "F"/"E"/"H" -> (P,) bool
    qvec: np.ndarray  # (P, 4) w, x, y, z
    tvec: np.ndarray  # (P, 3)
    has_pose: np.ndarray  # (P,) bool


def _images_direct(con, where: str, pycolmap):
    """``(image_ids, names, camera_ids, cameras {camera_id: pycolmap.Camera}, rigging)``."""
    rows = con.execute("SELECT image_id, name, camera_id FROM images ORDER BY image_id").fetchall()
    image_ids = np.array([r[0] for r in rows], dtype=np.int64)
    names = np.array([str(r[1]) for r in rows]).astype(str)
    camera_ids = np.array([r[2] for r in rows], dtype=np.int64)
    cameras = {}
    for cid, model, width, height, params, prior in con.execute(
            "SELECT camera_id, model, width, height, params, prior_focal_length FROM cameras"):
        blob = params or b""
        p = np.frombuffer(blob[: len(blob) // 8 * 8], dtype="<f8")
        try:
            model_id = pycolmap.CameraModelId(int(model))
            ok = len(blob) % 8 == 0 and len(p) == _num_params(pycolmap, model_id)
            cam = pycolmap.Camera(camera_id=int(cid), model=model_id, width=int(width), height=int(height), params=p.tolist(),
                                  has_prior_focal_length=bool(prior)) if ok else None
        except Exception:
            ok = False
        if not ok:
            raise InputError(f"cannot read the COLMAP database: camera {cid} has {len(p)} parameters, not those of model {model}", path=where)
        cameras[int(cid)] = cam
    frame_rig = dict(con.execute("SELECT frame_id, rig_id FROM frames").fetchall())
    frame_of = {}
    for fid, data_id, _sid, stype in con.execute("SELECT frame_id, data_id, sensor_id, sensor_type FROM frame_data"):
        if int(stype) == _CAMERA and int(fid) in frame_rig:
            frame_of[int(data_id)] = int(fid)
    rigs = {int(r): ((int(s), int(t)), {}) for r, s, t in con.execute("SELECT rig_id, ref_sensor_id, ref_sensor_type FROM rigs")}
    for rid, sid, stype, blob in con.execute("SELECT rig_id, sensor_id, sensor_type, sensor_from_rig FROM rig_sensors"):
        if int(rid) in rigs:
            rigs[int(rid)][1][(int(sid), int(stype))] = blob
    rigging = _rigging_tables(image_ids, camera_ids, frame_of, {int(k): int(v) for k, v in frame_rig.items()}, rigs)
    return image_ids, names, camera_ids, cameras, rigging


_NUM_PARAMS: dict = {}


def _num_params(pycolmap, model_id) -> int:
    if int(model_id) not in _NUM_PARAMS:
        _NUM_PARAMS[int(model_id)] = len(pycolmap.Camera.create_from_model_id(0, model_id, 1.0, 1, 1).params)
    return _NUM_PARAMS[int(model_id)]


def _rigging_tables(image_ids, camera_ids, frame_of: dict, rig_of_frame: dict, rigs: dict) -> _Rigging:
    """:func:`make_rigging` from the database's tables: ``frame_of`` image id -> frame id (its
    CAMERA data), ``rig_of_frame``, ``rigs`` rig id -> ((ref sensor id, type), {(sensor id,
    type): sensor_from_rig blob (w, x, y, z, tx, ty, tz) or None})."""
    n = len(image_ids)
    next_frame = max(list(frame_of.values()) + [0]) + 1
    frame_ids = np.empty(n, dtype=np.int64)
    R = np.empty((n, 3, 3))
    sensor_ids = camera_ids.astype(np.int64).copy()
    is_reference = np.zeros(n, dtype=bool)
    cache: dict = {}
    for k in range(n):
        fid = frame_of.get(int(image_ids[k]))
        if fid is None:
            frame_ids[k] = next_frame
            next_frame += 1
            R[k] = np.eye(3)
            sensor_ids[k] = -1
            continue
        frame_ids[k] = fid
        key = (rig_of_frame.get(fid), int(camera_ids[k]))
        if key not in cache:
            rig = rigs.get(key[0])
            if rig is None:
                cache[key] = (np.eye(3), True)
            elif rig[0] == (key[1], _CAMERA):
                cache[key] = (np.eye(3), True)
            else:
                blob = rig[1].get((key[1], _CAMERA))
                if blob is None or len(blob) < 32:
                    cache[key] = (np.full((3, 3), np.nan), False)
                else:
                    q = np.frombuffer(blob[:32], dtype="<f8")
                    cache[key] = (_quaternion_matrix(q), False)
        R[k], is_reference[k] = cache[key]
    return _Rigging(image_ids, frame_ids, R, sensor_ids, is_reference)


def _quaternion_matrix(q: np.ndarray) -> np.ndarray:
    """Eigen's ``Quaterniond(w, x, y, z).toRotationMatrix()`` (no normalisation, as pycolmap)."""
    w, x, y, z = (float(v) for v in q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def _pairs_direct(con, where: str, usable_ints, min_count: int) -> tuple[_Raw, np.ndarray, np.ndarray]:
    """``(the candidate pairs decoded, config of every verified pair, its inlier count)``.
    Only pairs of a usable configuration with ``>= min_count`` inliers are decoded."""
    head = np.array(con.execute("SELECT config, rows FROM two_view_geometries ORDER BY pair_id").fetchall(),
                    dtype=np.int64).reshape(-1, 2)
    marks = ", ".join(str(int(c)) for c in sorted(usable_ints)) or "NULL"
    rows = con.execute(
        f"SELECT pair_id, rows, cols, data, config, F, E, H, qvec, tvec FROM two_view_geometries "
        f"WHERE config IN ({marks}) AND rows >= ? ORDER BY pair_id", (int(min_count),)).fetchall()
    P = len(rows)
    pair_ids = np.array([r[0] for r in rows], dtype=np.int64)
    n = np.array([r[1] for r in rows], dtype=np.int64)
    cols = np.array([r[2] for r in rows], dtype=np.int64)
    blobs = [r[3] or b"" for r in rows]
    sizes = np.array([len(b) for b in blobs], dtype=np.int64)
    if P and ((sizes != n * np.where(n > 0, cols, 0) * 4) | ((cols != 2) & (n > 0))).any():
        raise InputError("cannot read the COLMAP database: an inlier-match blob does not hold its rows x 2 indices", path=where)
    table = np.frombuffer(b"".join(blobs), dtype="<u4").reshape(-1, 2)
    end = np.cumsum(n)
    inliers = _Segments(table, end - n, end)
    matrices, has = {}, {}
    for c, name in ((5, "F"), (6, "E"), (7, "H")):
        m, present = _blob_matrices([r[c] for r in rows], 9, name, where)
        matrices[name], has[name] = m.reshape(P, 3, 3), present
    qvec, has_q = _blob_matrices([r[8] for r in rows], 4, "qvec", where)
    tvec, has_t = _blob_matrices([r[9] for r in rows], 3, "tvec", where)
    if (has_q != has_t).any():
        raise InputError("cannot read the COLMAP database: qvec and tvec must both be NULL or both be set", path=where)
    raw = _Raw(pair_ids, np.array([r[4] for r in rows], dtype=np.int64), n, inliers, matrices, has, qvec, tvec, has_q)
    return raw, head[:, 0], head[:, 1]


def _pairs_pycolmap(pair_ids, geometries) -> _Raw:
    """:class:`_Raw` of pycolmap's ``read_two_view_geometries``."""
    P = len(geometries)
    inl = [np.asarray(g.inlier_matches, dtype=np.uint32).reshape(-1, 2) for g in geometries]
    n = np.array([len(x) for x in inl], dtype=np.int64)
    end = np.cumsum(n)
    table = np.concatenate(inl) if P else np.zeros((0, 2), np.uint32)
    matrices = {k: np.full((P, 3, 3), np.nan) for k in ("F", "E", "H")}
    has = {k: np.zeros(P, dtype=bool) for k in ("F", "E", "H")}
    qvec, tvec, has_pose = np.full((P, 4), np.nan), np.full((P, 3), np.nan), np.zeros(P, dtype=bool)
    for k, g in enumerate(geometries):
        for name in ("F", "E", "H"):
            m = getattr(g, name)
            if m is not None:
                matrices[name][k], has[name][k] = np.asarray(m, dtype=np.float64), True
        T = g.cam2_from_cam1
        if T is not None:
            x, y, z, w = np.asarray(T.rotation.quat, dtype=np.float64)
            qvec[k], tvec[k], has_pose[k] = (w, x, y, z), np.asarray(T.translation, dtype=np.float64), True
    config = np.array([int(g.config) for g in geometries], dtype=np.int64)
    return _Raw(np.asarray(pair_ids, dtype=np.int64).reshape(-1), config, n, _Segments(table, end - n, end), matrices, has, qvec, tvec,
                has_pose)


def _keypoints_direct(con, images, where: str) -> dict:
    """Image id -> (K, 2) float64 pixel coordinates of its keypoints (COLMAP's
    ``FeatureKeypointsFromBlob``: float32 rows of 2, 4 or 6 columns, x and y first)."""
    out = {}
    try:
        for i in images:
            row = con.execute("SELECT rows, cols, data FROM keypoints WHERE image_id = ?", (int(i),)).fetchone()
            if row is None or not row[0]:
                out[i] = np.zeros((0, 2))
                continue
            r, c, blob = int(row[0]), int(row[1]), row[2] or b""
            if c not in (2, 4, 6):
                raise InputError("cannot read keypoints: Keypoint format not supported", path=where)
            if len(blob) != 4 * r * c:
                raise InputError(f"cannot read keypoints: the keypoints of image {i} do not hold {r} x {c} floats", path=where)
            out[i] = np.frombuffer(blob, dtype="<f4").reshape(r, c)[:, :2].astype(np.float64)
    except sqlite3.Error as exc:
        raise InputError(f"cannot read keypoints: {exc}", path=where) from None
    return out


def read_two_view_geometries(
    db_path, min_inliers: int = DEFAULT_MIN_INLIERS, configs=None, estimate_missing: bool = True, *, all_keypoints: bool = False
) -> TwoViewGeometries:
    """The images, rigs and usable verified pairs of a COLMAP database (see the module
    docstring): what the view graph is built from. The database is only read
    (:func:`_readonly_connection`), and only its tables of cameras, images, rigs, frames,
    two-view geometries and the keypoints needed, never the descriptors or raw matches.

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
        raise OptionError("min_inliers must be >= 0")
    pycolmap = import_pycolmap()
    usable = _config_names(pycolmap, configs)
    members = pycolmap.TwoViewGeometryConfiguration.__members__
    usable_ints = {int(members[c]) for c in usable}
    config_name = {int(v): k for k, v in members.items()}
    min_count = max(min_inliers, 1)
    where = str(db_path)
    geometries = None
    with _readonly_connection(db_path) as (con, mode):
        try:
            direct = _direct_readable(con)
            if direct:
                image_ids, names, camera_ids, cameras, rigging = _images_direct(con, where, pycolmap)
                raw, all_config, all_count = _pairs_direct(con, where, usable_ints, min_count)
            else:  # an older schema: pycolmap reads (and migrates) a private copy of the tables needed
                with database_copy(db_path, ("cameras", "images", "rigs", "rig_sensors", "frames", "frame_data", "two_view_geometries",
                                              "inlier_matches")) as db:
                    try:
                        cams = {int(c.camera_id): c for c in db.read_all_cameras()}
                        rigs = {int(r.rig_id): r for r in db.read_all_rigs()}
                        frames = list(db.read_all_frames())
                        images = sorted(db.read_all_images(), key=lambda im: im.image_id)
                        pair_ids, geoms = db.read_two_view_geometries()
                    except Exception as exc:
                        raise InputError(f"cannot read the COLMAP database: {one_line(exc)}", path=where) from None
                rigging = make_rigging(pycolmap, images, frames, rigs)
                image_ids = rigging.image_ids
                names = np.array([im.name for im in images]).astype(str)
                camera_ids = np.array([im.camera_id for im in images], dtype=np.int64)
                cameras = cams
                raw_all = _pairs_pycolmap(pair_ids, geoms)
                all_config, all_count = raw_all.config, raw_all.n_inliers
                sel = np.flatnonzero(np.isin(all_config, list(usable_ints)) & (all_count >= min_count))
                raw = _Raw(raw_all.pair_ids[sel], all_config[sel], all_count[sel],
                           _Segments(raw_all.inliers.table, raw_all.inliers.start[sel], raw_all.inliers.end[sel]),
                           {k: v[sel] for k, v in raw_all.matrices.items()}, {k: v[sel] for k, v in raw_all.has_matrix.items()},
                           raw_all.qvec[sel], raw_all.tvec[sel], raw_all.has_pose[sel])
                geometries = [geoms[k] for k in sel]
        except sqlite3.Error as exc:
            raise InputError(f"cannot read the COLMAP database: {exc}", path=where) from None
        if not len(image_ids):
            raise InputError("COLMAP database holds no images (run feature extraction first)", path=where)

        # skipped pairs, in COLMAP's order of checks: configuration, inlier count, images
        skipped: Counter = Counter()
        config_counts: Counter = Counter()
        for c, cnt in zip(*np.unique(all_config, return_counts=True)):
            cname = config_name.get(int(c), f"UNKNOWN({int(c)})")
            config_counts[cname] += int(cnt)
            if int(c) not in usable_ints:
                skipped[f"configuration {cname}"] += int(cnt)
        few = int((np.isin(all_config, list(usable_ints)) & (all_count < min_count)).sum())
        if few:
            skipped[f"fewer than {min_count} inliers"] += few
        i_ids = raw.pair_ids // _MAX_NUM_IMAGES
        j_ids = raw.pair_ids % _MAX_NUM_IMAGES
        known = np.isin(i_ids, image_ids) & np.isin(j_ids, image_ids)
        if (~known).any():
            skipped["unknown image id"] += int((~known).sum())
        cam_of_row = dict(zip(image_ids.tolist(), camera_ids.tolist()))
        has_cam = np.array([cam_of_row.get(int(a)) in cameras and cam_of_row.get(int(b)) in cameras for a, b in zip(i_ids, j_ids)],
                           dtype=bool).reshape(-1)
        if (known & ~has_cam).any():
            skipped["image without camera"] += int((known & ~has_cam).sum())
        keep = np.flatnonzero(known & has_cam)
        data = _select(raw, keep)
        if geometries is not None:
            geometries = [geometries[k] for k in keep]
        cam_of = {int(i): cameras[int(c)] for i, c in zip(image_ids, camera_ids) if int(c) in cameras}
        pairs = list(zip(i_ids[keep].tolist(), j_ids[keep].tolist()))
        stored = np.flatnonzero(data.has_pose).tolist()
        todo = []
        if estimate_missing:
            todo = np.flatnonzero(~data.has_pose).tolist()
        elif (~data.has_pose).any():
            skipped["no stored relative pose (estimate_missing=False)"] += int((~data.has_pose).sum())
            for k in np.flatnonzero(~data.has_pose):
                pairs[k] = None

        # Keypoints only of the images whose pairs need estimating (all_keypoints: of all).
        need = sorted({x for k in (todo + stored if all_keypoints else todo) for x in pairs[k]})
        keypoints = _keypoints_direct(con, need, where)

    # Pairs whose inlier matches index past the keypoints cannot be estimated.
    valid_todo = []
    for k in todo:
        i, j = pairs[k]
        inl = data.inliers[k]
        if inl.size and (int(inl[:, 0].max()) >= len(keypoints[i]) or int(inl[:, 1].max()) >= len(keypoints[j])):
            skipped["inlier match beyond the image's keypoints"] += 1
            pairs[k] = None
        else:
            valid_todo.append(k)

    out = TwoViewGeometries(
        where, image_ids, names, rigging.rigs(), cam_of, pairs, None, data.inliers, keypoints, stored, valid_todo, skipped,
        config_counts, int(len(all_config)), pycolmap, data.config, data.matrices, data.has_matrix, data.qvec, data.tvec,
        data.has_pose, None, mode if direct else f"{mode}, pycolmap (schema migrated)",
    )
    views = _Views(out)
    return out._replace(geometries=geometries if geometries is not None else _PycolmapGeometries(out, pycolmap), views=views)


def _select(raw: _Raw, keep: np.ndarray) -> _Raw:
    if len(keep) == len(raw.pair_ids):
        return raw
    return _Raw(raw.pair_ids[keep], raw.config[keep], raw.n_inliers[keep],
                _Segments(raw.inliers.table, raw.inliers.start[keep], raw.inliers.end[keep]),
                {k: v[keep] for k, v in raw.matrices.items()}, {k: v[keep] for k, v in raw.has_matrix.items()},
                raw.qvec[keep], raw.tvec[keep], raw.has_pose[keep])


class TwoViewGeometries(NamedTuple):
    """What :func:`read_two_view_geometries` reads. Pair ``k`` joins the images
    ``pairs[k]`` (COLMAP ids; None when skipped after all) with its ``inliers[k]`` (M, 2)
    keypoint indices and two-view geometry: ``config[k]``, ``matrices["F"/"E"/"H"][k]``
    (``has_matrix``), the stored ``cam2_from_cam1`` as ``qvec[k]`` (w, x, y, z) and
    ``tvec[k]`` (``has_pose``); ``views[k]`` the same as a light ``pycolmap.TwoViewGeometry``
    look-alike, ``geometries[k]`` as a real ``pycolmap.TwoViewGeometry`` (built on
    access). ``stored`` lists the pairs with a stored ``cam2_from_cam1``, ``todo`` those
    whose relative pose must be estimated from ``keypoints`` (image id -> (K, 2) pixels)
    and ``cameras`` (image id -> ``pycolmap.Camera``). ``read_mode``: how the file was
    opened (:func:`_read_mode`)."""

    path: str
    image_ids: np.ndarray
    names: np.ndarray
    rigs: Rigs
    cameras: dict
    pairs: list
    geometries: object
    inliers: object
    keypoints: dict
    stored: list
    todo: list
    skipped: Counter
    configs: Counter
    n_verified: int
    pycolmap: object
    config: np.ndarray
    matrices: dict
    has_matrix: dict
    qvec: np.ndarray
    tvec: np.ndarray
    has_pose: np.ndarray
    views: object
    read_mode: str

    def points(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates of the inlier matches of pair ``k`` in its two images."""
        i, j = self.pairs[k]
        inl = self.inliers[k].astype(np.int64)
        return self.keypoints[i][inl[:, 0]], self.keypoints[j][inl[:, 1]]

    def stored_quaternion(self, k: int) -> np.ndarray | None:
        """The stored ``cam2_from_cam1`` of pair ``k`` as ``(w, x, y, z)``, None if unusable."""
        q = self.qvec[k]
        if not np.all(np.isfinite(q)) or np.linalg.norm(q) < 0.5:
            return None
        return q.copy()
