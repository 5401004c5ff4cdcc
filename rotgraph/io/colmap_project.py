"""COLMAP projects: finding them, opening their database without writing to it, and pycolmap.

* finding a project's database and sparse model (a folder of ``cameras``, ``images``,
  ``points3D`` as ``.bin`` or ``.txt``; ``rigs`` and ``frames`` in COLMAP 3.12+; what it
  gives: :mod:`rotgraph.io.colmap_model`): :func:`find_colmap_project`,
  :func:`locate_colmap_project`, :func:`is_colmap_project`, :func:`find_model`,
  :func:`model_format`;
* the database, strictly read-only: :func:`readonly_connection` (:mod:`sqlite3`,
  ``mode=ro`` or ``immutable=1``; :func:`_read_mode` tells which and why), or a
  ``pycolmap.Database`` on a small private copy of its tables (:func:`database_copy`), which
  :func:`write_pair_rotations` may write into; why the database is opened so:
  :mod:`rotgraph.io.colmap`, which reads its two-view geometries;
* rigs and frames, of pycolmap's images (:func:`make_rigging`, :func:`cam_from_rig`) or
  from the database's tables (:func:`rigging_from_tables`).

This is the one module of rotgraph that imports :mod:`pycolmap` (through
:func:`import_pycolmap`; :func:`to_pycolmap` makes its rotations, :func:`one_line` shortens
its errors; :mod:`rotgraph.synth` and :mod:`rotgraph.estimators.relative_pose` are handed
the module). Sparse models are read by ``pycolmap.Reconstruction``
(:mod:`rotgraph.io.colmap_model`).
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import sqlite3
import tempfile
from pathlib import Path

import numpy as np

from .. import so3
from ..errors import InputError
from ..viewgraph import Rigs

__all__ = [
    "BULK_TABLES",
    "CAMERA_SENSOR_TYPE",
    "cam_from_rig",
    "database_copy",
    "find_colmap_project",
    "find_model",
    "import_pycolmap",
    "is_colmap_project",
    "locate_colmap_project",
    "make_rigging",
    "model_format",
    "one_line",
    "readonly_connection",
    "rigging_from_tables",
    "table_columns",
    "to_pycolmap",
    "write_pair_rotations",
]

logger = logging.getLogger(__name__)

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
    """How :func:`readonly_connection` opens ``path`` (measured on SQLite 3.40; see
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
def readonly_connection(path: Path):
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


def table_columns(con: sqlite3.Connection) -> dict:
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
    connection (:func:`readonly_connection`), with ``path``'s ``user_version`` so that
    pycolmap migrates an old schema exactly as it would the whole file. So reading
    cameras, rigs, frames, images, pose priors, keypoints or two-view geometries through
    it gives what pycolmap reads from the original, at the cost of those tables only."""
    pycolmap = import_pycolmap()
    tmp = tempfile.mkdtemp(prefix="rotgraph-colmap-")
    db = None
    try:
        copy = os.path.join(tmp, "database.db")
        with readonly_connection(Path(path)) as (src, _mode):
            try:
                schema = table_columns(src)
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


#: COLMAP's ``SensorType::CAMERA`` (the ``sensor_type`` of a camera in the rig and frame tables).
CAMERA_SENSOR_TYPE = 0


def rigging_from_tables(image_ids, camera_ids, frame_of: dict, rig_of_frame: dict, rigs: dict) -> _Rigging:
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
            elif rig[0] == (key[1], CAMERA_SENSOR_TYPE):
                cache[key] = (np.eye(3), True)
            else:
                blob = rig[1].get((key[1], CAMERA_SENSOR_TYPE))
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

