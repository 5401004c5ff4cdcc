"""A COLMAP database's tables decoded: what :func:`rotgraph.io.colmap.read_two_view_geometries`
reads, in arrays (see :mod:`rotgraph.io.colmap` for what is read and why the user's file is
never written).

A database of COLMAP 4's schema (:func:`direct_readable`) is decoded with numpy straight from
:mod:`sqlite3` (:func:`read_images_direct`, :func:`read_pairs_direct`,
:func:`read_keypoints_direct`), as COLMAP's ``database_sqlite.cc`` writes it (matrices
row-major float64, quaternions ``w, x, y, z``, inlier matches uint32 rows of 2, keypoints
float32 rows of 2, 4 or 6); an older schema is read by pycolmap from a small private copy,
which it migrates (:func:`read_migrated`). Both give the verified pairs as one
:class:`RawPairs`.
"""

from __future__ import annotations

import sqlite3
from typing import NamedTuple

import numpy as np

from ..errors import InputError
from .colmap_project import CAMERA_SENSOR_TYPE, database_copy, make_rigging, one_line, rigging_from_tables, table_columns

__all__ = ["MAX_NUM_IMAGES", "RawPairs", "direct_readable", "pair_ids", "read_images_direct", "read_keypoints_direct",
           "read_migrated", "read_pairs_direct", "select_pairs"]

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
MAX_NUM_IMAGES = 2147483647


def pair_ids(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """COLMAP's ``ImagePairToPairId`` of image ids ``a``, ``b`` (the smaller first), vectorised:
    ``lo * 2147483647 + hi``, which the pair readers below split again."""
    lo, hi = np.minimum(a, b).astype(np.int64), np.maximum(a, b).astype(np.int64)
    return lo * MAX_NUM_IMAGES + hi


def direct_readable(con: sqlite3.Connection) -> bool:
    """True when the database has COLMAP 4's schema and needs no migration: its tables are
    then decoded directly (:func:`read_images_direct`, :func:`read_pairs_direct`); otherwise pycolmap reads a small private
    copy (:func:`database_copy`) and migrates it as it would the original."""
    version = con.execute("PRAGMA user_version").fetchone()[0]
    if version <= _MIGRATED_VERSION:
        return False
    tables = table_columns(con)
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


class _Segments:
    """``seg[k]``: rows ``start[k]:end[k]`` of one (M, 2) table (no copy)."""

    def __init__(self, table: np.ndarray, start: np.ndarray, end: np.ndarray):
        self.table, self.start, self.end = table, start, end

    def __len__(self):
        return len(self.start)

    def __getitem__(self, k):
        return self.table[self.start[k] : self.end[k]]


class RawPairs(NamedTuple):
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


def read_images_direct(con, where: str, pycolmap):
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
        if int(stype) == CAMERA_SENSOR_TYPE and int(fid) in frame_rig:
            frame_of[int(data_id)] = int(fid)
    rigs = {int(r): ((int(s), int(t)), {}) for r, s, t in con.execute("SELECT rig_id, ref_sensor_id, ref_sensor_type FROM rigs")}
    for rid, sid, stype, blob in con.execute("SELECT rig_id, sensor_id, sensor_type, sensor_from_rig FROM rig_sensors"):
        if int(rid) in rigs:
            rigs[int(rid)][1][(int(sid), int(stype))] = blob
    rigging = rigging_from_tables(image_ids, camera_ids, frame_of, {int(k): int(v) for k, v in frame_rig.items()}, rigs)
    return image_ids, names, camera_ids, cameras, rigging


_NUM_PARAMS: dict = {}


def _num_params(pycolmap, model_id) -> int:
    if int(model_id) not in _NUM_PARAMS:
        _NUM_PARAMS[int(model_id)] = len(pycolmap.Camera.create_from_model_id(0, model_id, 1.0, 1, 1).params)
    return _NUM_PARAMS[int(model_id)]


def read_pairs_direct(con, where: str, usable_ints, min_count: int) -> tuple[RawPairs, np.ndarray, np.ndarray]:
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
    raw = RawPairs(pair_ids, np.array([r[4] for r in rows], dtype=np.int64), n, inliers, matrices, has, qvec, tvec, has_q)
    return raw, head[:, 0], head[:, 1]


def _pairs_pycolmap(pair_ids, geometries) -> RawPairs:
    """:class:`RawPairs` of pycolmap's ``read_two_view_geometries``."""
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
    return RawPairs(np.asarray(pair_ids, dtype=np.int64).reshape(-1), config, n, _Segments(table, end - n, end), matrices, has, qvec, tvec,
                   has_pose)


def read_keypoints_direct(con, images, where: str) -> dict:
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


def read_migrated(db_path, where, pycolmap, usable_ints, min_count):
    """:func:`read_two_view_geometries`' tables of an older schema, read by pycolmap from a
    private copy (which it migrates): ``(image_ids, names, camera_ids, cameras, rigging,
    raw, all_config, all_count, geometries)``, ``raw`` and ``geometries`` of the usable pairs."""
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
    names = np.array([im.name for im in images]).astype(str)
    camera_ids = np.array([im.camera_id for im in images], dtype=np.int64)
    raw_all = _pairs_pycolmap(pair_ids, geoms)
    all_config, all_count = raw_all.config, raw_all.n_inliers
    sel = np.flatnonzero(np.isin(all_config, list(usable_ints)) & (all_count >= min_count))
    raw = RawPairs(raw_all.pair_ids[sel], all_config[sel], all_count[sel],
                   _Segments(raw_all.inliers.table, raw_all.inliers.start[sel], raw_all.inliers.end[sel]),
                   {k: v[sel] for k, v in raw_all.matrices.items()}, {k: v[sel] for k, v in raw_all.has_matrix.items()},
                   raw_all.qvec[sel], raw_all.tvec[sel], raw_all.has_pose[sel])
    return rigging.image_ids, names, camera_ids, cams, rigging, raw, all_config, all_count, [geoms[k] for k in sel]


def select_pairs(raw: RawPairs, keep: np.ndarray) -> RawPairs:
    """The pairs of rows ``keep`` of ``raw`` (``raw`` itself when that is all of them)."""
    if len(keep) == len(raw.pair_ids):
        return raw
    return RawPairs(raw.pair_ids[keep], raw.config[keep], raw.n_inliers[keep],
                    _Segments(raw.inliers.table, raw.inliers.start[keep], raw.inliers.end[keep]),
                    {k: v[keep] for k, v in raw.matrices.items()}, {k: v[keep] for k, v in raw.has_matrix.items()},
                    raw.qvec[keep], raw.tvec[keep], raw.has_pose[keep])
