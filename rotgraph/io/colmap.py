"""COLMAP databases: reading their images, rigs and two-view geometries (read-only).

* reading the database: :func:`read_two_view_geometries` (images, rigs and usable pairs;
  :func:`rotgraph.pipeline.colmap.read_colmap_project` estimates the relative poses the
  database does not store and builds the view graph);
* finding a project's database and sparse model, opening the database without writing to
  it, and pycolmap: :mod:`rotgraph.io.colmap_project`;
* sparse models, read and written: :mod:`rotgraph.io.colmap_model`.

Solving is not done here: ``average_rotations(graph, default_options("colmap"))`` (see
:mod:`rotgraph.pipeline.solve`) averages the graph read, rig-aware
(:mod:`rotgraph.estimators.rig_rotation_averaging`).

pycolmap is reached through :func:`~rotgraph.io.colmap_project.import_pycolmap`, as
everywhere in rotgraph.

Reading a database: only what rotation averaging needs, the user's file never written
------------------------------------------------------------------------------------
``pycolmap.Database.open`` creates and migrates tables in the file it opens, and copying
the whole file first costs O(its size), nearly all of it descriptors and raw matches. So
the database is opened with :mod:`sqlite3` strictly read-only
(:func:`~rotgraph.io.colmap_project.readonly_connection`: ``mode=ro``, or ``immutable=1``
for a WAL-mode file without pending ``-wal`` content, which ``mode=ro`` would otherwise
touch; see :func:`~rotgraph.io.colmap_project._read_mode` for the measured choice) and, for
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
"""

from __future__ import annotations

import sqlite3
from collections import Counter
from pathlib import Path
from typing import NamedTuple

import numpy as np

from ..errors import InputError, OptionError
from ..viewgraph import Rigs
from .colmap_project import (  # noqa: F401 (some only for __all__)
    database_copy,
    find_colmap_project,
    import_pycolmap,
    is_colmap_project,
    readonly_connection,
    to_pycolmap,
    write_pair_rotations,
)
from .colmap_tables import (  # noqa: F401 (pair_ids only for __all__)
    MAX_NUM_IMAGES,
    RawPairs,
    direct_readable,
    pair_ids,
    read_images_direct,
    read_keypoints_direct,
    read_migrated,
    read_pairs_direct,
    select_pairs,
)

# Besides this module's own, the names of rotgraph.io.colmap_project and colmap_tables that
# tests, benchmarks and the documentation import from here.
__all__ = [
    "USABLE_CONFIGS",
    "DEFAULT_MIN_INLIERS",
    "read_two_view_geometries",
    "TwoViewGeometries",
    "pair_ids",
    "database_copy",
    "find_colmap_project",
    "is_colmap_project",
    "to_pycolmap",
    "write_pair_rotations",
]

#: Two-view configurations that give a relative rotation (COLMAP 4 / GLOMAP, see above).
USABLE_CONFIGS = frozenset(
    {"CALIBRATED", "UNCALIBRATED", "PLANAR", "PANORAMIC", "PLANAR_OR_PANORAMIC", "CALIBRATED_RIG"}
)
#: COLMAP's ``GlobalPipelineOptions.min_num_matches`` (inlier matches of a pair).
DEFAULT_MIN_INLIERS = 15


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


# =========================================================================== the pairs, as pycolmap's


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


def read_two_view_geometries(
    db_path, min_inliers: int = DEFAULT_MIN_INLIERS, configs=None, estimate_missing: bool = True, *, all_keypoints: bool = False
) -> TwoViewGeometries:
    """The images, rigs and usable verified pairs of a COLMAP database (see the module
    docstring): what the view graph is built from. The database is only read
    (:func:`readonly_connection`), and only its tables of cameras, images, rigs, frames,
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
    with readonly_connection(db_path) as (con, mode):
        try:
            direct = direct_readable(con)
            if direct:
                image_ids, names, camera_ids, cameras, rigging = read_images_direct(con, where, pycolmap)
                raw, all_config, all_count = read_pairs_direct(con, where, usable_ints, min_count)
            else:  # an older schema: pycolmap reads (and migrates) a private copy of the tables needed
                (image_ids, names, camera_ids, cameras, rigging, raw, all_config, all_count,
                 geometries) = read_migrated(db_path, where, pycolmap, usable_ints, min_count)
        except sqlite3.Error as exc:
            raise InputError(f"cannot read the COLMAP database: {exc}", path=where) from None
        if not len(image_ids):
            raise InputError("COLMAP database holds no images (run feature extraction first)", path=where)

        # skipped pairs, in COLMAP's order of checks: configuration, inlier count, images
        skipped, config_counts = _skipped_by_configuration(all_config, all_count, usable_ints, config_name, min_count)
        i_ids, j_ids = raw.pair_ids // MAX_NUM_IMAGES, raw.pair_ids % MAX_NUM_IMAGES
        keep = _pairs_of_known_images(i_ids, j_ids, image_ids, camera_ids, cameras, skipped)
        data = select_pairs(raw, keep)
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
        keypoints = read_keypoints_direct(con, need, where)

    valid_todo = _estimable(todo, pairs, data, keypoints, skipped)

    out = TwoViewGeometries(
        where, image_ids, names, rigging.rigs(), cam_of, pairs, None, data.inliers, keypoints, stored, valid_todo, skipped,
        config_counts, int(len(all_config)), pycolmap, data.config, data.matrices, data.has_matrix, data.qvec, data.tvec,
        data.has_pose, None, mode if direct else f"{mode}, pycolmap (schema migrated)",
    )
    views = _Views(out)
    return out._replace(geometries=geometries if geometries is not None else _PycolmapGeometries(out, pycolmap), views=views)


def _skipped_by_configuration(all_config, all_count, usable_ints, config_name, min_count) -> tuple[Counter, Counter]:
    """``(skipped, config_counts)``: the pairs of every configuration, and those skipped for
    theirs or for too few inliers (the first two of COLMAP's checks)."""
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
    return skipped, config_counts


def _pairs_of_known_images(i_ids, j_ids, image_ids, camera_ids, cameras, skipped: Counter) -> np.ndarray:
    """The rows of the pairs whose two images, and their cameras, are in the database (the
    others counted in ``skipped``)."""
    known = np.isin(i_ids, image_ids) & np.isin(j_ids, image_ids)
    if (~known).any():
        skipped["unknown image id"] += int((~known).sum())
    cam_of_row = dict(zip(image_ids.tolist(), camera_ids.tolist()))
    has_cam = np.array([cam_of_row.get(int(a)) in cameras and cam_of_row.get(int(b)) in cameras for a, b in zip(i_ids, j_ids)],
                       dtype=bool).reshape(-1)
    if (known & ~has_cam).any():
        skipped["image without camera"] += int((known & ~has_cam).sum())
    return np.flatnonzero(known & has_cam)


def _estimable(todo: list, pairs: list, data: RawPairs, keypoints, skipped: Counter) -> list:
    """The pairs of ``todo`` whose relative pose can be estimated: not those whose inlier
    matches index past their images' keypoints (counted in ``skipped``, their ``pairs``
    entry set to None)."""
    valid = []
    for k in todo:
        i, j = pairs[k]
        inl = data.inliers[k]
        if inl.size and (int(inl[:, 0].max()) >= len(keypoints[i]) or int(inl[:, 1].max()) >= len(keypoints[j])):
            skipped["inlier match beyond the image's keypoints"] += 1
            pairs[k] = None
        else:
            valid.append(k)
    return valid


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
    opened (:func:`~rotgraph.io.colmap_project._read_mode`)."""

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
