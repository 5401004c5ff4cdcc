"""Reading a COLMAP database strictly read-only, without copying it (#18 item 3).

The user's database (and any ``-wal``, ``-shm`` or ``-journal`` beside it) is byte-identical
afterwards and nothing is created beside it, in every SQLite journal state; the direct
(numpy) decoding of COLMAP 4's tables reads exactly what pycolmap reads (the private-copy
path, also used for older schemas): same pairs, geometries, inliers, cameras, rigs.
"""

from __future__ import annotations

import hashlib
import shutil
import sqlite3
from pathlib import Path

import numpy as np
import pytest

pycolmap = pytest.importorskip("pycolmap")

from rotgraph.io import colmap as io  # noqa: E402
from rotgraph.io import colmap_tables  # noqa: E402
from rotgraph.io.colmap_model import unposed_reconstruction  # noqa: E402
from rotgraph.io.colmap_project import readonly_connection  # noqa: E402
from rotgraph.pipeline.colmap import read_colmap_project  # noqa: E402
from rotgraph.synth import synthesize_colmap_project  # noqa: E402


def snapshot(folder: Path) -> dict:
    out = {}
    for p in sorted(folder.rglob("*")):
        if p.is_file():
            st = p.stat()
            out[str(p.relative_to(folder))] = (hashlib.sha256(p.read_bytes()).hexdigest(), st.st_size, st.st_mtime_ns)
    return out


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    base = tmp_path_factory.mktemp("ro")
    synthesize_colmap_project(base / "rig", n_frames=6, cameras_per_rig=2, n_points=200, doppelgangers=1, seed=21)
    synthesize_colmap_project(base / "stored", n_frames=8, n_points=200, store_relative_pose=True, seed=22)
    return base


def graphs_equal(a, b):
    assert np.array_equal(a.edges, b.edges) and np.array_equal(a.node_ids, b.node_ids)
    assert list(a.names) == list(b.names)
    assert np.abs(a.cam2_from_cam1 - b.cam2_from_cam1).max() < 1e-12
    assert np.array_equal(a.weights, b.weights)
    for f in ("frame_ids", "sensor_ids", "is_reference"):
        assert np.array_equal(getattr(a.rigs, f), getattr(b.rigs, f)), f
    np.testing.assert_allclose(a.rigs.cam_from_rig, b.rigs.cam_from_rig, atol=1e-12, rtol=0)
    if a.information is not None:
        np.testing.assert_allclose(a.information, b.information, rtol=1e-9, atol=1e-9 * np.abs(a.information).max())


def wal_copy(src: Path, dst: Path, pending: bool):
    """``dst/database.db`` in WAL mode; with ``pending``, a writer still holds commits in the
    ``-wal`` (the connection is returned open: the caller closes it after reading)."""
    dst.mkdir()
    shutil.copyfile(src / "database.db", dst / "database.db")
    con = sqlite3.connect(dst / "database.db")
    con.execute("PRAGMA journal_mode = WAL")
    con.commit()
    if not pending:
        con.close()
        return None
    con.execute("PRAGMA wal_autocheckpoint = 0")
    # a committed change only the -wal holds: one pair's configuration set to WATERMARK
    pid = con.execute("SELECT pair_id FROM two_view_geometries ORDER BY pair_id LIMIT 1").fetchone()[0]
    con.execute("UPDATE two_view_geometries SET config = ? WHERE pair_id = ?", (int(pycolmap.TwoViewGeometryConfiguration.WATERMARK), pid))
    con.commit()
    return con


def test_direct_read_equals_pycolmap_read(project, monkeypatch):
    for name in ("rig", "stored"):
        folder = project / name
        with readonly_connection(folder / "database.db") as (con, mode):
            assert colmap_tables.direct_readable(con) and mode in ("ro", "immutable")
        for kw in (dict(), dict(uncertainty=True), dict(vectorize=False)):
            direct = read_colmap_project(folder, model=None, **kw)
            with monkeypatch.context() as m:
                m.setattr(io, "direct_readable", lambda con: False)  # pycolmap on a private copy of the tables
                via_pycolmap = read_colmap_project(folder, model=None, **kw)
            graphs_equal(direct, via_pycolmap)
            assert direct.meta["skipped"] == via_pycolmap.meta["skipped"] and direct.meta["configs"] == via_pycolmap.meta["configs"]


def test_geometries_decoded_like_pycolmap(project):
    for name in ("rig", "stored"):
        path = project / name / "database.db"
        data = io.read_two_view_geometries(path, all_keypoints=True)
        with io.database_copy(path, None) as db:
            ref = dict(zip((int(p) for p in db.read_two_view_geometries()[0]), db.read_two_view_geometries()[1]))
            for k, (i, j) in enumerate(data.pairs):
                g = ref[int(pycolmap.image_pair_to_pair_id(i, j))]
                assert int(g.config) == data.views[k].config == int(data.geometries[k].config)
                assert np.array_equal(np.asarray(g.inlier_matches), data.inliers[k])
                for m in ("F", "E", "H"):
                    a, b = getattr(g, m), getattr(data.views[k], m)
                    assert (a is None) == (b is None) and (a is None or np.array_equal(np.asarray(a), b))
                if g.cam2_from_cam1 is not None:
                    assert np.array_equal(np.asarray(g.cam2_from_cam1.rotation.quat), data.views[k].cam2_from_cam1.rotation.quat)
                    assert np.array_equal(np.asarray(g.cam2_from_cam1.translation), data.geometries[k].cam2_from_cam1.translation)
                for x in (i, j):
                    kp = np.asarray(db.read_keypoints(x))[:, :2]
                    assert np.array_equal(kp.astype(np.float64), data.keypoints[x])
            for i, cam in data.cameras.items():
                ref_cam = db.read_camera(cam.camera_id)
                assert ref_cam.model == cam.model and np.array_equal(ref_cam.params, cam.params)
                assert (ref_cam.width, ref_cam.height, ref_cam.has_prior_focal_length) == (cam.width, cam.height, cam.has_prior_focal_length)


@pytest.mark.parametrize("pending", [False, True])
def test_wal_database_is_read_without_touching_it(project, tmp_path, pending):
    """COLMAP 4 writes WAL-mode databases. Without pending commits the file is read in
    place (``immutable=1``: no ``-wal``/``-shm`` created); with commits only the ``-wal``
    holds (a COLMAP still writing), they are read too, from a private copy, and the
    ``-wal`` and ``-shm`` are left byte for byte."""
    writer = wal_copy(project / "stored", tmp_path / "p", pending)
    try:
        before = snapshot(tmp_path / "p")
        assert ("database.db-wal" in before) == pending
        with readonly_connection(tmp_path / "p" / "database.db") as (_con, mode):
            assert mode == ("copy" if pending else "immutable")
        g = read_colmap_project(tmp_path / "p", model=None)
        data = io.read_two_view_geometries(tmp_path / "p" / "database.db")
        assert data.configs.get("WATERMARK", 0) == (1 if pending else 0)
        assert g.meta["skipped"].get("configuration WATERMARK", 0) == (1 if pending else 0)
        unposed_reconstruction(tmp_path / "p" / "database.db")
        assert snapshot(tmp_path / "p") == before
    finally:
        if writer is not None:
            writer.close()


def test_rollback_database_in_a_read_only_folder_creates_nothing(project, tmp_path):
    import os

    (tmp_path / "p").mkdir()
    shutil.copyfile(project / "rig" / "database.db", tmp_path / "p" / "database.db")
    before = snapshot(tmp_path / "p")
    os.chmod(tmp_path / "p", 0o555)
    try:
        g = read_colmap_project(tmp_path / "p", model=None, uncertainty=True)
        assert g.n_edges > 0
    finally:
        os.chmod(tmp_path / "p", 0o755)
    assert snapshot(tmp_path / "p") == before


def test_private_copy_leaves_out_descriptors_and_matches(project):
    path = project / "rig" / "database.db"
    with io.database_copy(path) as db:
        assert db.num_images() > 0 and db.num_keypoints() > 0 and db.num_verified_image_pairs() > 0
        assert db.num_descriptors() == 0 and db.num_matches() == 0
    with io.database_copy(path, ("images",)) as db:
        assert db.num_images() > 0 and db.num_keypoints() == 0 and db.num_cameras() == 0


def test_older_schema_goes_through_pycolmap(project, tmp_path):
    """A database of an older COLMAP (user_version <= 3.14): pycolmap migrates a private
    copy of its tables (e.g. an identity relative pose then means 'not stored'), and the
    graph is the one pycolmap's reading of the whole file gives."""
    (tmp_path / "old").mkdir()
    shutil.copyfile(project / "stored" / "database.db", tmp_path / "old" / "database.db")
    con = sqlite3.connect(tmp_path / "old" / "database.db")
    con.execute("PRAGMA user_version = 3130000")
    pid = con.execute("SELECT pair_id FROM two_view_geometries WHERE qvec IS NOT NULL ORDER BY pair_id LIMIT 1").fetchone()[0]
    con.execute("UPDATE two_view_geometries SET qvec = ?, tvec = ? WHERE pair_id = ?",
                (np.array([1.0, 0, 0, 0]).tobytes(), np.zeros(3).tobytes(), pid))
    con.commit()
    con.close()
    before = snapshot(tmp_path / "old")
    with readonly_connection(tmp_path / "old" / "database.db") as (con, _):
        assert not colmap_tables.direct_readable(con)
    data = io.read_two_view_geometries(tmp_path / "old" / "database.db")
    assert "pycolmap" in data.read_mode
    k = data.pairs.index(tuple(int(x) for x in pycolmap.pair_id_to_image_pair(pid)))
    assert not data.has_pose[k] and k in data.todo  # migrated: identity = not stored
    g = read_colmap_project(tmp_path / "old", model=None)
    assert g.meta["n_pairs_estimated"] == 1
    assert snapshot(tmp_path / "old") == before


def test_bad_blobs_are_input_errors(project, tmp_path):
    (tmp_path / "p").mkdir()
    shutil.copyfile(project / "stored" / "database.db", tmp_path / "p" / "database.db")
    con = sqlite3.connect(tmp_path / "p" / "database.db")
    con.execute("UPDATE two_view_geometries SET data = substr(data, 1, 12) WHERE rowid IN (SELECT rowid FROM two_view_geometries LIMIT 1)")
    con.commit()
    con.close()
    with pytest.raises(io.InputError, match="inlier-match blob") as exc:
        read_colmap_project(tmp_path / "p")
    assert exc.value.path == str(tmp_path / "p" / "database.db")


@pytest.mark.parametrize("fmt", ["bin", "txt"])
def test_model_observations_decoded_like_pycolmap_tracks(project, tmp_path, fmt):
    """The model reader's observations, decoded vectorised from images.bin/.txt, are the
    3D points' track elements (each image-point pair once), and the covisibility graph is
    the same as from pycolmap's tracks."""
    from rotgraph.io import colmap_model as cm

    model = project / "rig" / "sparse" / "0"
    rec = pycolmap.Reconstruction(str(model))
    if fmt == "txt":
        rec.write_text(str(tmp_path))
        model = tmp_path
    fast = cm._observations(rec, model)
    slow = cm._observations(rec, None)  # the loop over every track element
    assert len(fast[0]) == len(slow[0]) > 0
    assert set(zip(*(x.tolist() for x in fast))) == set(zip(*(x.tolist() for x in slow)))
    ids = np.array(sorted(rec.reg_image_ids()), dtype=np.int64)
    a, b = cm._covisibility(rec, ids, model), cm._covisibility(rec, ids, None)
    for x, y in zip(a, b):
        assert np.array_equal(x, y)
