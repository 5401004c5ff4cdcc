"""COLMAP projects: database and sparse-model readers, rig-aware solving, outputs.

Every project is built here with pycolmap's synthetic tools (``pycolmap.synthesize_dataset``
and friends, through :func:`rotgraph.synth.synthesize_colmap_project`, plus one built
with pycolmap alone); the real-photo project ``../shared/datasets/lund_door`` is used when
present. Accuracy is checked against the ground-truth model, matched by image name.
"""

from __future__ import annotations

import hashlib
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

pycolmap = pytest.importorskip("pycolmap")

from rotgraph import so3  # noqa: E402
from rotgraph.errors import InputError, UnsolvableError  # noqa: E402
from rotgraph.estimators.rotation_averaging import average_rotations  # noqa: E402
from rotgraph.evaluate import compare_rotations, match_by_key  # noqa: E402
from rotgraph.io.colmap import USABLE_CONFIGS, find_colmap_project, is_colmap_project  # noqa: E402
from rotgraph.io.colmap_model import read_colmap_model_rotations, rotations_by_name, unposed_reconstruction, write_to_reconstruction  # noqa: E402
from rotgraph.pipeline.colmap import read_colmap_project  # noqa: E402
from rotgraph.pipeline.solve import default_options  # noqa: E402
from rotgraph.synth import synthesize_colmap_project  # noqa: E402
from rotgraph.viewgraph import Rigs  # noqa: E402

LUND = Path(__file__).resolve().parents[2] / "shared" / "datasets" / "lund_door"
GLOMAP_RA_LUND_MEDIAN_DEG = 0.517  # lund_door/README.md: pycolmap.run_rotation_averaging


# --------------------------------------------------------------------------- helpers


def snapshot(folder: Path) -> dict:
    """Every file under ``folder``: (sha256, size, mtime_ns); also catches new files."""
    out = {}
    for p in sorted(folder.rglob("*")):
        if p.is_file():
            st = p.stat()
            out[str(p.relative_to(folder))] = (hashlib.sha256(p.read_bytes()).hexdigest(), st.st_size, st.st_mtime_ns)
    return out


def errors_vs_model(names, R, model) -> object:
    _, gt_names, gt_R = read_colmap_model_rotations(model)
    E, G, _ = match_by_key(names, R, gt_names, gt_R)
    return compare_rotations(E, G)


def solve(graph, **overrides):
    """The COLMAP defaults, rig-aware unless ``rig_aware=False``."""
    return average_rotations(graph, default_options("colmap"), **overrides)


def edge_errors_deg(graph) -> np.ndarray:
    gt = graph.gt_cam_from_world
    pred = gt[graph.edges[:, 1]] @ np.swapaxes(gt[graph.edges[:, 0]], 1, 2)
    return np.degrees(so3.angle_between(graph.cam2_from_cam1, pred))


@pytest.fixture(scope="module")
def projects(tmp_path_factory):
    """Small realistic projects (1 px noise, 30 % wrong raw matches, doppelgangers)."""
    base = tmp_path_factory.mktemp("colmap")
    made = {}
    specs = {
        "plain": dict(n_frames=12, n_points=250, doppelgangers=2, seed=11),
        "stored": dict(n_frames=10, n_points=250, doppelgangers=1, store_relative_pose=True, seed=12),
        "rig": dict(n_frames=7, cameras_per_rig=2, n_points=250, doppelgangers=1, seed=13),
        "txt": dict(n_frames=8, n_points=200, model_format="txt", seed=14),
    }
    for name, kw in specs.items():
        made[name] = (base / name, synthesize_colmap_project(base / name, **kw))
    return made


@pytest.fixture(scope="module")
def plain_graph(projects):
    return read_colmap_project(projects["plain"][0])


# --------------------------------------------------------------------------- locating


def test_find_and_detect(projects, tmp_path):
    folder, info = projects["plain"]
    db, model = find_colmap_project(folder)
    assert db == folder / "database.db" and model == folder / "sparse" / "0"
    assert find_colmap_project(folder / "database.db") == (folder / "database.db", folder / "sparse" / "0")
    assert find_colmap_project(folder / "sparse" / "0") == (None, folder / "sparse" / "0")
    assert is_colmap_project(folder) and is_colmap_project(folder / "database.db") and is_colmap_project(folder / "sparse" / "0")
    (tmp_path / "x.txt").write_text("0 1 1 0 0 0\n")
    assert not is_colmap_project(tmp_path / "x.txt")
    assert not is_colmap_project(tmp_path)


# --------------------------------------------------------------------------- database path


def test_database_without_poses_is_estimated(projects, plain_graph):
    folder, info = projects["plain"]
    g = plain_graph
    m = g.meta
    assert m["source"] == "database" and g.format == "colmap"
    assert m["n_pairs_stored"] == 0 and m["n_pairs_estimated"] == g.n_edges > 0
    assert m["n_pairs_stored"] + m["n_pairs_estimated"] + m["n_pairs_skipped"] == m["n_pairs_verified"]
    assert set(m["configs"]) <= set(pycolmap.TwoViewGeometryConfiguration.__members__)
    # nodes = COLMAP image ids and names; weights = inlier counts
    rec = pycolmap.Reconstruction(info["model"])
    assert sorted(g.node_ids.tolist()) == sorted(int(i) for i in rec.images)
    assert all(rec.images[int(i)].name == n for i, n in zip(g.node_ids, g.names))
    assert np.all(g.weights >= 15) and np.all(g.weights == np.round(g.weights))
    # the doppelganger pairs carry their wrong rotation, the others are accurate
    err = edge_errors_deg(g)
    dopp = {(a, b) for a, b, _ in info["doppelgangers"]}
    is_dopp = np.array([(int(g.node_ids[i]), int(g.node_ids[j])) in dopp for i, j in g.edges])
    assert is_dopp.sum() == len(dopp)
    assert np.all(err[is_dopp] > 20) and np.median(err[~is_dopp]) < 0.5


def test_solve_estimated_matches_ground_truth(projects, plain_graph):
    folder, info = projects["plain"]
    graph = plain_graph
    result = solve(graph)
    ids, names, R = graph.node_ids, graph.names, result.cam_from_world
    assert result.solved.all() and result.n_solved == len(ids)
    ev = errors_vs_model(names, R, info["model"])
    assert ev.n_evaluated == len(ids) and ev.median < 0.2 and ev.max < 1.0
    # the doppelgangers are rejected as outliers
    dopp = {(a, b) for a, b, _ in info["doppelgangers"]}
    for k, (i, j) in enumerate(graph.edges):
        if (int(graph.node_ids[i]), int(graph.node_ids[j])) in dopp:
            assert not result.inliers[k] and result.residuals_deg[k] > 20


def test_stored_relative_poses(projects):
    folder, info = projects["stored"]
    g = read_colmap_project(folder)
    assert g.meta["n_pairs_stored"] == g.n_edges > 0 and g.meta["n_pairs_estimated"] == 0
    ev = errors_vs_model(g.names, solve(g).cam_from_world, info["model"])
    assert ev.median < 0.2


def test_stored_and_estimated_rotations_agree(projects, tmp_path):
    """A stored cam2_from_cam1 (COLMAP's compute_relative_pose) equals what rotgraph
    estimates from the same inlier matches once the pose is removed from the database."""
    folder, _ = projects["stored"]
    shutil.copyfile(folder / "database.db", tmp_path / "database.db")
    db = pycolmap.Database.open(str(tmp_path / "database.db"))
    pair_ids, geoms = db.read_two_view_geometries()
    for pid, g in zip(pair_ids, geoms):
        g.cam2_from_cam1 = None
        db.update_two_view_geometry(*pycolmap.pair_id_to_image_pair(pid), g)
    db.close()
    stored = read_colmap_project(folder, model=None)
    for vectorize in (True, False):
        est = read_colmap_project(tmp_path, vectorize=vectorize)
        assert est.meta["n_pairs_stored"] == 0 and est.meta["n_pairs_estimated"] == stored.n_edges
        assert np.array_equal(est.edges, stored.edges)
        assert np.degrees(so3.angle_between(est.cam2_from_cam1, stored.cam2_from_cam1)).max() < 1e-6


def test_vectorised_decomposition_equals_pycolmap(projects):
    for name in ("plain", "rig"):
        a = read_colmap_project(projects[name][0], model=None, vectorize=True)
        b = read_colmap_project(projects[name][0], model=None, vectorize=False)
        assert np.array_equal(a.edges, b.edges)
        assert np.degrees(so3.angle_between(a.cam2_from_cam1, b.cam2_from_cam1)).max() < 1e-7


def test_database_file_path_and_parallel_workers(projects, plain_graph):
    folder, _ = projects["plain"]
    g = read_colmap_project(folder / "database.db", workers=2, vectorize=False)
    assert np.array_equal(g.edges, plain_graph.edges)
    assert np.degrees(so3.angle_between(g.cam2_from_cam1, plain_graph.cam2_from_cam1)).max() < 1e-7
    assert g.gt_cam_from_world is not None  # the model beside the database


def test_pycolmap_synthetic_with_stored_poses(tmp_path):
    """A project made with pycolmap alone: noise-free matches, relative poses stored."""
    opts = pycolmap.SyntheticDatasetOptions()
    opts.num_rigs, opts.num_cameras_per_rig, opts.num_frames_per_rig = 1, 1, 9
    opts.num_points3D = 150
    opts.two_view_geometry_has_relative_pose = True
    db = pycolmap.Database.open(str(tmp_path / "database.db"))
    rec = pycolmap.synthesize_dataset(opts, db)
    db.close()
    (tmp_path / "sparse" / "0").mkdir(parents=True)
    rec.write(str(tmp_path / "sparse" / "0"))
    g = read_colmap_project(tmp_path)
    assert g.meta["n_pairs_stored"] == g.n_edges == 36
    assert edge_errors_deg(g).max() < 1e-6
    assert errors_vs_model(g.names, solve(g).cam_from_world, tmp_path / "sparse" / "0").max < 1e-4


def test_no_usable_pair_is_an_input_error(projects):
    folder, _ = projects["plain"]
    with pytest.raises(InputError, match=r"no usable image pair.*fewer than 1000 inliers"):
        read_colmap_project(folder, min_inliers=1000)
    with pytest.raises(InputError, match=r"configuration CALIBRATED"):
        read_colmap_project(folder, configs=["PLANAR"])
    with pytest.raises(InputError, match=r"estimate_missing=False"):
        read_colmap_project(folder, estimate_missing=False)
    with pytest.raises(ValueError, match="unknown two-view configuration"):
        read_colmap_project(folder, configs=["BOGUS"])
    assert "WATERMARK" not in USABLE_CONFIGS and "MULTIPLE" not in USABLE_CONFIGS and "DEGENERATE" not in USABLE_CONFIGS


def test_images_without_pairs_and_skipped_configs(projects, tmp_path):
    folder, _ = projects["plain"]
    shutil.copyfile(folder / "database.db", tmp_path / "database.db")
    db = pycolmap.Database.open(str(tmp_path / "database.db"))
    iid = db.write_image(pycolmap.Image(name="lonely.png", camera_id=1))
    frame = pycolmap.Frame()
    frame.rig_id = 1
    frame.add_data_id(db.read_image(iid).data_id)
    db.write_frame(frame)
    pair_ids, geoms = db.read_two_view_geometries()
    for pid, g, config in zip(pair_ids[:2], geoms[:2], ("WATERMARK", "MULTIPLE")):
        g.config = getattr(pycolmap.TwoViewGeometryConfiguration, config)
        db.update_two_view_geometry(*pycolmap.pair_id_to_image_pair(pid), g)
    db.close()
    g = read_colmap_project(tmp_path)
    assert g.meta["images_without_pairs"] == ["lonely.png"]
    assert g.meta["skipped"] == {"configuration WATERMARK": 1, "configuration MULTIPLE": 1}
    assert g.meta["n_pairs_skipped"] == 2
    res = solve(g)
    lonely = list(g.names).index("lonely.png")
    assert not res.solved[lonely] and np.isnan(res.cam_from_world[lonely]).all()
    assert res.solved.sum() == len(g.names) - 1


# --------------------------------------------------------------------------- rigs


def test_rig_aware_solve(projects):
    folder, info = projects["rig"]
    g = read_colmap_project(folder)
    assert len(np.unique(g.rigs.frame_ids)) == 7 and g.n_nodes == 14
    S = g.rigs.cam_from_rig
    assert np.isfinite(S).all() and (np.abs(S - np.eye(3)).max(axis=(1, 2)) > 1e-3).sum() == 7  # the non-reference sensor
    res = solve(g)
    assert res.solved.all()
    fg = res.frames.graph
    assert fg.n_nodes == 7 and res.frames.n_intra_frame_pairs == 7
    assert fg.n_edges == g.n_edges - 7  # every inter-frame image pair is one frame edge
    # each image is sensor_from_rig * rig_from_world of its frame
    F = res.frames.result.cam_from_world
    _, group = np.unique(g.rigs.frame_ids, return_inverse=True)
    assert np.allclose(res.cam_from_world, S @ F[group.ravel()], atol=1e-12)
    ev = errors_vs_model(g.names, res.cam_from_world, info["model"])
    assert ev.median < 0.2
    # frame edges agree with the ground-truth frame rotations
    rec = pycolmap.Reconstruction(info["model"])
    fid = np.unique(g.rigs.frame_ids)
    Fgt = np.stack([so3.from_pycolmap(rec.frames[int(f)].rig_from_world.rotation) for f in fid])
    pred = Fgt[fg.edges[:, 1]] @ np.swapaxes(Fgt[fg.edges[:, 0]], 1, 2)
    assert np.median(np.degrees(so3.angle_between(fg.cam2_from_cam1, pred))) < 0.5
    # rig-less solve of the same images also works (every image its own node)
    ev2 = errors_vs_model(g.names, solve(g, rig_aware=False).cam_from_world, info["model"])
    assert ev2.median < 0.5


def test_unknown_sensor_from_rig_is_estimated(projects):
    """A sensor without sensor_from_rig (issue #17): estimated by default (its images share
    one cam_from_rig, close to the model's); with rig_extrinsics="fixed" its images are
    frames of their own, as before."""
    folder, info = projects["rig"]
    g = read_colmap_project(folder)
    S_true = g.rigs.cam_from_rig.copy()
    g.rigs.cam_from_rig = g.rigs.cam_from_rig.copy()
    nonref = np.abs(g.rigs.cam_from_rig - np.eye(3)).max(axis=(1, 2)) > 1e-3
    assert (g.rigs.is_reference == ~nonref).all() and len(np.unique(g.rigs.sensor_ids)) == 2
    g.rigs.cam_from_rig[nonref] = np.nan  # pretend the second sensor is uncalibrated
    res = solve(g)
    assert res.solved.all() and res.frames.graph.n_nodes == 7
    s = res.sensors
    assert list(s.status) == ["reference", "estimated"] and s.n_frames[1] == 7
    k = np.flatnonzero(nonref)[0]
    assert np.degrees(so3.angle_between(s.cam_from_rig[1], S_true[k])) < 0.5
    assert errors_vs_model(g.names, res.cam_from_world, info["model"]).median < 0.3
    old = solve(g, rig_extrinsics="fixed")
    n_frames = g.n_nodes if old.frames is None else old.frames.graph.n_nodes  # None: one image a frame
    assert n_frames == 7 + nonref.sum() and old.sensors is None and old.solved.all()


# --------------------------------------------------------------------------- sparse models


@pytest.mark.parametrize("name", ["plain", "txt"])
def test_model_folder_alone(projects, name):
    folder, info = projects[name]
    model = Path(info["model"])
    fmt = "txt" if name == "txt" else "bin"
    assert (model / f"images.{fmt}").is_file()
    g = read_colmap_project(model)
    assert g.meta["source"] == "model" and g.n_edges > 0 and g.meta["n_ground_truth"] == g.n_nodes
    assert edge_errors_deg(g).max() < 1e-8  # exact relative rotations of the model
    assert errors_vs_model(g.names, solve(g).cam_from_world, model).max < 1e-5


def test_model_rotations_bin_and_txt(projects, tmp_path):
    folder, info = projects["plain"]
    ids, names, R = read_colmap_model_rotations(info["model"])
    rec = pycolmap.Reconstruction(info["model"])
    rec.write_text(str(tmp_path))
    ids2, names2, R2 = read_colmap_model_rotations(tmp_path)
    assert np.array_equal(ids, ids2) and list(names) == list(names2)
    assert np.allclose(R, R2, atol=1e-9)
    assert np.allclose(R @ np.swapaxes(R, 1, 2), np.eye(3), atol=1e-9)
    # a project folder finds its model
    ids3, _, _ = read_colmap_model_rotations(folder)
    assert np.array_equal(ids, ids3)


def test_model_without_points3d_gives_ground_truth(projects, tmp_path):
    folder, info = projects["txt"]
    for f in ("cameras.txt", "images.txt", "rigs.txt", "frames.txt"):
        if (Path(info["model"]) / f).is_file():
            shutil.copyfile(Path(info["model"]) / f, tmp_path / f)
    ids, names, R = read_colmap_model_rotations(tmp_path)
    assert len(ids) == 8
    with pytest.raises(InputError, match="no 3D points"):
        read_colmap_project(tmp_path)


# --------------------------------------------------------------------------- outputs


def test_rotations_by_name_and_write_to_reconstruction(projects):
    for name in ("plain", "rig"):
        folder, info = projects[name]
        g = read_colmap_project(folder)
        R = solve(g).cam_from_world
        rots = rotations_by_name(g.names, R)
        assert set(rots) == set(g.names) and all(isinstance(r, pycolmap.Rotation3d) for r in rots.values())
        k = 3
        assert np.allclose(so3.from_pycolmap(rots[g.names[k]]), R[k], atol=1e-12)
        rec = pycolmap.Reconstruction(info["model"])
        t_before = {int(f): np.asarray(fr.rig_from_world.translation).copy() for f, fr in rec.frames.items()}
        n = write_to_reconstruction(rec, rots)
        assert n == rec.num_frames()
        for iid, im in rec.images.items():
            k = list(g.names).index(im.name)
            assert np.degrees(so3.angle_between(so3.from_pycolmap(im.cam_from_world().rotation), R[k])) < 1e-6
        for f, fr in rec.frames.items():
            assert np.allclose(np.asarray(fr.rig_from_world.translation), t_before[int(f)])
        # by image id, with matrices
        rec2 = pycolmap.Reconstruction(info["model"])
        assert write_to_reconstruction(rec2, {int(i): Ri for i, Ri in zip(g.node_ids, R)}) == rec2.num_frames()


def test_write_to_unposed_reconstruction(projects):
    folder, _ = projects["plain"]
    g = read_colmap_project(folder)
    R = solve(g).cam_from_world
    rec = unposed_reconstruction(folder / "database.db")  # cameras, rigs, frames, images; no poses
    assert rec.num_reg_frames() == 0
    assert write_to_reconstruction(rec, rotations_by_name(g.names, R)) == rec.num_frames()
    assert rec.num_reg_frames() == rec.num_frames()
    im = rec.images[int(g.node_ids[0])]
    assert np.allclose(np.asarray(im.cam_from_world().translation), 0)


# --------------------------------------------------------------------------- inputs untouched


def test_inputs_are_never_modified(projects):
    for name in ("plain", "rig", "txt"):
        folder, info = projects[name]
        before = snapshot(folder)
        g = read_colmap_project(folder)
        solve(g)
        read_colmap_model_rotations(info["model"])
        read_colmap_project(info["model"])
        read_colmap_project(folder / "database.db", vectorize=False)
        assert snapshot(folder) == before  # same bytes, same mtimes, no new file (-wal, -shm)


def test_read_only_database_file(projects, tmp_path):
    folder, _ = projects["plain"]
    shutil.copyfile(folder / "database.db", tmp_path / "database.db")
    os.chmod(tmp_path / "database.db", 0o444)
    os.chmod(tmp_path, 0o555)
    try:
        g = read_colmap_project(tmp_path)
        assert g.n_edges > 0
    finally:
        os.chmod(tmp_path, 0o755)


# --------------------------------------------------------------------------- bad inputs


def test_empty_database_file(tmp_path):
    (tmp_path / "database.db").write_bytes(b"")
    with pytest.raises(InputError, match="empty file") as exc:
        read_colmap_project(tmp_path)
    assert exc.value.path == str(tmp_path / "database.db")
    assert "\n" not in str(exc.value)
    assert (tmp_path / "database.db").stat().st_size == 0  # not turned into a database


def test_corrupt_database_file(tmp_path, projects):
    (tmp_path / "database.db").write_bytes(os.urandom(4096))
    with pytest.raises(InputError, match="not an SQLite file"):
        read_colmap_project(tmp_path / "database.db")
    # a real database with its pages damaged after the header
    data = bytearray((projects["plain"][0] / "database.db").read_bytes())
    data[100:8192] = os.urandom(8092)
    (tmp_path / "database.db").write_bytes(bytes(data))
    with pytest.raises(InputError) as exc:
        read_colmap_project(tmp_path / "database.db")
    assert exc.value.path == str(tmp_path / "database.db") and "\n" not in str(exc.value)


def test_sqlite_without_colmap_tables_and_database_without_pairs(tmp_path, projects):
    import sqlite3

    con = sqlite3.connect(tmp_path / "database.db")
    con.execute("CREATE TABLE t (x)")
    con.commit()
    con.close()
    before = snapshot(tmp_path)
    with pytest.raises(InputError, match="no images"):
        read_colmap_project(tmp_path)
    assert snapshot(tmp_path) == before
    other = tmp_path / "nopairs"
    other.mkdir()
    shutil.copyfile(projects["plain"][0] / "database.db", other / "database.db")
    db = pycolmap.Database.open(str(other / "database.db"))
    db.clear_two_view_geometries()
    db.close()
    with pytest.raises(InputError, match="no verified image pairs"):
        read_colmap_project(other)


def test_folder_without_database_or_model(tmp_path):
    (tmp_path / "notes.txt").write_text("nothing here\n")
    with pytest.raises(InputError, match="no COLMAP database"):
        read_colmap_project(tmp_path)
    with pytest.raises(InputError, match="no such file"):
        read_colmap_project(tmp_path / "missing")
    with pytest.raises(InputError, match="no COLMAP sparse model"):
        read_colmap_model_rotations(tmp_path)


def test_model_without_images(tmp_path, projects):
    model = Path(projects["txt"][1]["model"])
    shutil.copyfile(model / "cameras.txt", tmp_path / "cameras.txt")
    (tmp_path / "images.txt").write_text("# Image list with two lines of data per image:\n")
    (tmp_path / "points3D.txt").write_text("")
    with pytest.raises(InputError, match="no images") as exc:
        read_colmap_model_rotations(tmp_path)
    assert "images.txt" in exc.value.path
    with pytest.raises(InputError, match="no images"):
        read_colmap_project(tmp_path)


def test_corrupt_model(tmp_path, projects):
    model = Path(projects["plain"][1]["model"])
    for f in model.iterdir():
        shutil.copyfile(f, tmp_path / f.name)
    data = (tmp_path / "images.bin").read_bytes()
    (tmp_path / "images.bin").write_bytes(data[: len(data) // 3])
    with pytest.raises(InputError, match="cannot read the sparse model"):
        read_colmap_model_rotations(tmp_path)


def test_all_pairs_within_frames_is_unsolvable(projects):
    folder, _ = projects["rig"]
    g = read_colmap_project(folder)
    group = g.rigs.frame_ids
    g.rigs = Rigs(np.zeros_like(group), np.broadcast_to(np.eye(3), (g.n_nodes, 3, 3)).copy())  # one frame holding every image
    with pytest.raises(UnsolvableError, match="within one rig frame"):
        solve(g)


# --------------------------------------------------------------------------- real photos


@pytest.mark.skipif(not (LUND / "database.db").is_file(), reason="../shared/datasets/lund_door not present")
def test_lund_door_real_project():
    before = snapshot(LUND)
    g = read_colmap_project(LUND, model=LUND / "gt")
    assert g.n_nodes == 12 and g.n_edges == 66 and g.meta["n_pairs_estimated"] == 66
    assert g.meta["configs"] == {"CALIBRATED": 66} and g.meta["n_ground_truth"] == 12
    # the relative rotations are those documented with the data set
    ref = np.loadtxt(LUND / "relative_rotations.txt", usecols=range(6))
    key = {(int(a), int(b)): k for k, (a, b) in enumerate(ref[:, :2])}
    for k, (i, j) in enumerate(g.edges):
        r = ref[key[(int(g.node_ids[i]), int(g.node_ids[j]))]]
        assert np.degrees(so3.angle_between(g.cam2_from_cam1[k], so3.matrices_from_quaternions(r[2:6]))) < 1e-6
    ev = compare_rotations(solve(g).cam_from_world, g.gt_cam_from_world)
    assert ev.n_evaluated == 12
    assert ev.median <= 1.02 * GLOMAP_RA_LUND_MEDIAN_DEG
    assert snapshot(LUND) == before


def test_default_options_are_the_colmap_ones():
    o = default_options("colmap")
    assert o.use_information and o.method == "adaptive"  # the library's default method
    assert not o.use_weights and default_options("colmap", use_information=False).use_weights  # inlier counts without information
    assert default_options("colmap", method="l2").method == "l2"


BUNDLED = Path(__file__).resolve().parents[1] / "datasets" / "colmap_synthetic"


@pytest.mark.skipif(not (BUNDLED / "database.db").is_file(), reason="bundled datasets/colmap_synthetic not present")
def test_bundled_colmap_project():
    before = snapshot(BUNDLED)
    g = read_colmap_project(BUNDLED)
    r = solve(g)
    assert g.n_nodes == 14 and g.n_edges == 91 and r.solved.all()
    bad = {(int(g.node_ids[i]), int(g.node_ids[j])) for k, (i, j) in enumerate(g.edges) if not r.inliers[k]}
    assert bad == {(4, 12), (9, 13)}  # the two doppelgangers (datasets/colmap_synthetic/README.md)
    ev = compare_rotations(r.cam_from_world, g.gt_cam_from_world)
    assert ev.median < 0.15 and ev.max < 0.5
    assert snapshot(BUNDLED) == before


def test_model_argument(projects, tmp_path):
    folder, info = projects["plain"]
    g = read_colmap_project(folder, model=None)
    assert g.gt_cam_from_world is None and "model_path" not in g.meta
    g = read_colmap_project(folder / "database.db", model=info["model"])
    assert g.meta["n_ground_truth"] == g.n_nodes
    with pytest.raises(InputError, match="no COLMAP sparse model"):
        read_colmap_project(folder, model=tmp_path)  # an explicit model must exist
    # a model-only folder is read as the input whatever `model` says
    assert read_colmap_project(info["model"], model=None).meta["source"] == "model"
    # a file inside a model folder names the model
    ids, _, _ = read_colmap_model_rotations(Path(info["model"]) / "images.bin")
    assert len(ids) == 12


def test_rig_path_reports_left_out_frames_like_the_plain_path():
    """A frame whose every edge is an outlier is left out; its images' edges keep their
    residuals and count as outliers, exactly as a rig-less solve reports a left-out camera.
    Frames 0-8 are consistent; frame 9 hangs on two edges 120 deg apart."""
    from rotgraph.estimators.rotation_averaging import SolveOptions
    from rotgraph.viewgraph import Rigs, ViewGraph

    rng = np.random.default_rng(7)
    F = so3.random_rotations(10, rng)  # rig_from_world per frame
    S2 = so3.random_rotations(1, rng)[0]  # cam_from_rig of the second sensor
    frame_ids = np.repeat(np.arange(10), 2)
    S = np.stack([np.eye(3), S2] * 10)
    R = S @ F[frame_ids]  # cam_from_world of the 20 images
    i, j = np.triu_indices(20, 1)
    fi, fj = frame_ids[i], frame_ids[j]
    keep = (fi != fj) & ((fj < 9) | ((j == 18) & ((i == 0) | (i == 2))))  # image 18 <- images 0, 2
    i, j = i[keep], j[keep]
    rel = R[j] @ np.swapaxes(R[i], 1, 2)
    bad = frame_ids[j] == 9
    twist = so3.exp(np.array([[0.0, 0.0, np.deg2rad(120.0)]]))[0]
    rel[bad & (i == 2)] = twist @ rel[bad & (i == 2)]
    g = ViewGraph.from_edges(i, j, rel, node_ids=np.arange(20))
    g.rigs = Rigs(frame_ids, S)
    opts = SolveOptions(method="irls", loss_scale_deg=100.0, rescale=False)  # robust, L2-like here (l2 rejects nothing)
    rig = average_rotations(g, opts)
    plain = average_rotations(g, opts, rig_aware=False)
    assert not rig.solved[frame_ids == 9].any() and rig.solved[frame_ids != 9].all()
    assert np.isfinite(rig.residuals_deg).all() and np.isfinite(plain.residuals_deg).all()
    assert not rig.inliers[bad].any() and rig.inliers[~bad].all()
    assert rig.n_outliers == int(bad.sum()) == plain.n_outliers == 2
    assert rig.n_rejected == 2 and plain.n_rejected == 1  # frame 9's two images; image 18 alone


def test_vectorised_cheirality_counts_match_a_per_ray_loop():
    """_calibrated_rotations (padded per-pair blocks, rays in any order) counts, for each of
    the four candidate poses, the rays in front of both cameras exactly as a plain loop does."""
    from rotgraph.estimators.relative_pose import _calibrated_rotations

    rng = np.random.default_rng(5)
    P = 6
    seg = np.repeat(np.arange(P), rng.integers(1, 40, P))
    E = rng.normal(size=(P, 3, 3))
    r1, r2 = rng.normal(size=(2, len(seg), 3))
    r1 /= np.linalg.norm(r1, axis=1, keepdims=True)
    r2 /= np.linalg.norm(r2, axis=1, keepdims=True)
    perm = rng.permutation(len(seg))
    cands, counts = _calibrated_rotations(E, r1[perm], r2[perm], seg[perm])
    for p in range(P):
        U, _, Vt = np.linalg.svd(E[p])
        t = U[:, 2] * np.sign(np.linalg.det(U))
        for c, (R, sign) in enumerate([(cands[0][p], 1), (cands[1][p], 1), (cands[0][p], -1), (cands[1][p], -1)]):
            n = 0
            for a, b in zip(r1[seg == p], r2[seg == p]):
                # triangulate x = s1 (R a) and x = s2 b - t' (mid-point depths s1, s2 > 0)
                Ra, tt = R @ a, sign * t
                M = np.stack([Ra, -b], axis=1)
                s1, s2 = np.linalg.lstsq(M, -tt, rcond=None)[0]
                n += bool(s1 > 0 and s2 > 0)
            assert counts[c, p] == n, (p, c)


def test_colmap_preset_keeps_inlier_weights_without_information():
    """Without information matrices (e.g. a COLMAP model read without its database) the
    COLMAP preset keeps the inlier-count weights; they give way only to information."""
    assert default_options("colmap", False).use_weights
    assert not default_options("colmap", True).use_weights
