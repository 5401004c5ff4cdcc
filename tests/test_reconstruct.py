"""``rotgraph reconstruct`` (issue #18 item 2): COLMAP's global pipeline from rotgraph's
rotations. The bundled project, a small synthetic one with a rig, the real-photo project of
../shared (skipped when absent), the user's database untouched, bad inputs."""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np
import pytest

from cli_helpers import assert_clean_error, run

pycolmap = pytest.importorskip("pycolmap")

ROOT = Path(__file__).resolve().parents[1]
BUNDLED = ROOT / "datasets" / "colmap_synthetic"
LUND = ROOT.parent / "shared" / "datasets" / "lund_door"


def _digest(folder: Path) -> dict:
    """sha256 of every file of the project folder (a -wal/-shm appearing shows too)."""
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def rig_project(tmp_path_factory):
    from rotgraph.synth import synthesize_colmap_project

    folder = tmp_path_factory.mktemp("rig_project")
    synthesize_colmap_project(folder, n_frames=10, cameras_per_rig=2, n_points=300, seed=3)
    return folder


def test_bundled_project_cli(tmp_path):
    before = _digest(BUNDLED)
    out = tmp_path / "model"
    r = run("reconstruct", BUNDLED, "-o", out, "--json", "--mapper-seed", "1")
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert _digest(BUNDLED) == before  # the user's project byte-identical, nothing created beside it
    assert {p.name for p in out.iterdir()} == {f"{n}.bin" for n in ("cameras", "images", "points3D", "rigs", "frames")}
    rec = pycolmap.Reconstruction(str(out))
    gt = pycolmap.Reconstruction(str(BUNDLED / "sparse" / "0"))
    assert {(i, im.name) for i, im in rec.images.items()} == {(i, im.name) for i, im in gt.images.items()}
    assert rec.num_reg_images() == 14 == s["n_registered"] and s["n_points3D"] == rec.num_points3D() > 50
    assert s["n_pairs_rotation_filtered"] == 2  # the two doppelganger pairs
    e = s["eval"]
    assert e["n_evaluated"] == 14 and e["rotation_median_deg"] < 0.1 and e["position_median_rel"] < 0.005
    assert s["eval_rotation_averaging"]["rotation_median_deg"] < 0.1
    from rotgraph.pipeline.reconstruct import model_errors

    again = model_errors(out, BUNDLED / "sparse" / "0")  # the file written = the summary's
    assert again["rotation_median_deg"] == pytest.approx(e["rotation_median_deg"], abs=1e-6)


def test_tracks_as_colmap(tmp_path):
    """Track establishment gives COLMAP's own counts on the bundled project (its log:
    'Established 88 tracks', 'Kept 59 tracks, discarded 29 due to inconsistency')."""
    s = run("reconstruct", BUNDLED, "-o", tmp_path / "m", "--json", "--mapper-seed", "0")
    s = json.loads(s.stdout)
    assert (s["n_tracks_established"], s["n_tracks"], s["n_tracks_inconsistent"]) == (88, 59, 29)


def test_rig_project_library(rig_project, tmp_path):
    from rotgraph.pipeline.reconstruct import reconstruct

    before = _digest(rig_project)
    s = reconstruct(rig_project, tmp_path / "m", seed=2, text=True)
    assert _digest(rig_project) == before
    rec = pycolmap.Reconstruction(str(tmp_path / "m"))
    assert sorted(p.name for p in (tmp_path / "m").iterdir()) == sorted(
        f"{n}.txt" for n in ("cameras", "images", "points3D", "rigs", "frames"))
    assert rec.num_reg_images() == 20 and rec.num_rigs() == 1 and rec.num_frames() == 10
    e = s["eval"]
    assert e["n_evaluated"] == 20 and e["rotation_median_deg"] < 0.2 and e["position_median_rel"] < 0.01
    assert s["seconds"] > 0 and set(s) >= {"seconds_rotations", "seconds_global_positioning", "seconds_bundle_adjustment"}


def test_pose_graph_edges_are_the_view_graphs(tmp_path):
    """build_pose_graph: one PoseGraph edge per image pair, its rotation the graph's
    measured cam2_from_cam1 (to 1e-12), num_matches its inlier count; the invalid ones are
    exactly the pairs whose measurement disagrees with the solved rotations by > 10 deg."""
    from rotgraph import so3
    from rotgraph.estimators.rotation_averaging import average_rotations
    from rotgraph.io.colmap import _database_copy
    from rotgraph.io.colmap_model import write_to_reconstruction
    from rotgraph.pipeline.read import read_view_graph
    from rotgraph.pipeline.reconstruct import build_pose_graph
    from rotgraph.pipeline.solve import default_options

    graph = read_view_graph(BUNDLED / "database.db", fmt="colmap")
    res = average_rotations(graph, default_options("colmap", graph.information is not None))
    with _database_copy(BUNDLED / "database.db") as db:
        cache = pycolmap.DatabaseCache.create(db, pycolmap.DatabaseCacheOptions())
    rec = pycolmap.Reconstruction()
    rec.load(cache)
    write_to_reconstruction(rec, {int(graph.node_ids[k]): res.cam_from_world[k] for k in range(graph.n_nodes)})
    pg, counts = build_pose_graph(pycolmap, rec, graph, 10.0)
    ids = graph.node_ids
    assert len(pg.edges) == graph.n_edges == counts["n_pairs"]
    R = res.cam_from_world
    disagree = np.degrees(so3.angle_between(graph.cam2_from_cam1, R[graph.edges[:, 1]] @ np.swapaxes(R[graph.edges[:, 0]], 1, 2)))
    for e, (i, j) in enumerate(graph.edges):
        pid = int(pycolmap.image_pair_to_pair_id(int(ids[i]), int(ids[j])))
        edge = pg.edges[pid]
        Rm = so3.from_pycolmap(edge.cam2_from_cam1.rotation)
        if int(ids[i]) > int(ids[j]):  # COLMAP keeps the pair with the smaller id first
            Rm = Rm.T
        np.testing.assert_allclose(Rm, graph.cam2_from_cam1[e], atol=1e-12)
        assert edge.num_matches == graph.weights[e]
        assert edge.valid == (disagree[e] <= 10.0)
    assert counts["n_pairs_rotation_filtered"] == int((disagree > 10.0).sum()) == 2


def _bundled_start():
    """The bundled project's reconstruction with rotgraph's rotations (no 3D points), its
    view graph, the DatabaseCache and the private database copy's keypoints."""
    from rotgraph.estimators.rotation_averaging import average_rotations
    from rotgraph.io.colmap import _database_copy
    from rotgraph.io.colmap_model import write_to_reconstruction
    from rotgraph.pipeline.read import read_view_graph
    from rotgraph.pipeline.solve import default_options

    graph = read_view_graph(BUNDLED / "database.db", fmt="colmap")
    res = average_rotations(graph, default_options("colmap", graph.information is not None))
    with _database_copy(BUNDLED / "database.db") as db:
        cache = pycolmap.DatabaseCache.create(db, pycolmap.DatabaseCacheOptions())
        keypoints = {int(i): db.read_keypoints(int(i)) for i in cache.images}
    rec = pycolmap.Reconstruction()
    rec.load(cache)
    write_to_reconstruction(rec, {int(graph.node_ids[k]): res.cam_from_world[k] for k in range(graph.n_nodes)})
    return rec, graph, cache, keypoints


def test_pose_graph_without_a_pose():
    """An image without a pose: every pair of it invalid (not counted as rotation-filtered),
    its frame outside the component; the other pairs as before."""
    from rotgraph.pipeline.reconstruct import build_pose_graph

    rec, graph, _, _ = _bundled_start()
    full, _ = build_pose_graph(pycolmap, pycolmap.Reconstruction(rec), graph, 10.0)
    lost = int(graph.node_ids[3])
    rec.deregister_frame(rec.image(lost).frame_id)
    assert not rec.image(lost).has_pose
    pg, counts = build_pose_graph(pycolmap, rec, graph, 10.0)
    touches = filtered = 0
    for pid, edge in pg.edges.items():
        a, b = pycolmap.pair_id_to_image_pair(pid)
        if lost in (a, b):
            touches += 1
            assert not edge.valid
        else:
            assert edge.valid == full.edges[pid].valid
            filtered += not edge.valid
    assert touches == int(np.isin(graph.node_ids[graph.edges], lost).any(axis=1).sum()) > 0
    assert counts["n_pairs_rotation_filtered"] == filtered and counts["n_frames_deregistered"] == 1
    assert counts["n_pairs_valid"] == sum(e.valid for e in pg.edges.values())


def test_tracks_read_keypoints_only_where_needed():
    """establish_tracks gives the same tracks with the keypoints as a dict, as a callable
    (the database's read_keypoints) or read from the reconstruction; the callable is asked
    only for images where some track has two observations, each once."""
    from rotgraph.pipeline.reconstruct import build_pose_graph, default_mapper_options, establish_tracks

    rec0, graph, cache, keypoints = _bundled_start()
    pg, _ = build_pose_graph(pycolmap, rec0, graph, 10.0)
    opts = default_mapper_options(0)
    asked = []

    def lookup(iid):
        asked.append(iid)
        return keypoints[iid]

    tracks, counts = [], []
    for kp in (keypoints, lookup, None):
        rec = pycolmap.Reconstruction(rec0)
        counts.append(establish_tracks(pycolmap, rec, cache, pg, opts, kp))
        tracks.append(sorted(tuple(sorted((el.image_id, el.point2D_idx) for el in p.track.elements))
                             for p in rec.points3D.values()))
    assert tracks[0] == tracks[1] == tracks[2] and counts[0] == counts[1] == counts[2]
    assert counts[0]["n_tracks_inconsistent"] > 0 and len(tracks[0]) == counts[0]["n_tracks"]
    assert len(asked) == len(set(asked)) and set(asked) <= set(keypoints)
    # the images asked for: exactly those with two observations of one established track
    cg = cache.correspondence_graph
    ids = sorted(keypoints)
    n = {i: rec0.image(i).num_points2D() for i in ids}
    off = dict(zip(ids, np.cumsum([0] + [n[i] for i in ids[:-1]])))
    edges = []
    for pid, edge in pg.edges.items():
        if edge.valid:
            a, b = pycolmap.pair_id_to_image_pair(pid)
            m = np.asarray(cg.extract_matches_between_images(a, b)).reshape(-1, 2)
            edges += [(off[a] + x, off[b] + y) for x, y in m]
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    e = np.array(edges)
    N = sum(n.values())
    _, lab = connected_components(sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(N, N)), directed=False)
    obs = np.unique(e)
    img = np.searchsorted(np.array([off[i] for i in ids]), obs, side="right") - 1
    pairs = {}
    for o, k in zip(lab[obs].tolist(), img.tolist()):
        pairs[(o, k)] = pairs.get((o, k), 0) + 1
    assert set(asked) == {ids[k] for (_, k), c in pairs.items() if c > 1}
    # COLMAP's "Established T tracks from N observations": the components and observations of the matches
    assert counts[0]["n_track_observations"] == len(obs)
    assert counts[0]["n_tracks_established"] == len(np.unique(lab[obs]))


def test_retriangulation_refines_points_only(tmp_path, monkeypatch):
    """The iterative refinement of the retriangulation moves the 3D points only, as
    pycolmap 4.2.1's global_mapping runs it (its log: points-only problems): the poses
    and intrinsics after it are those the final bundle adjustment starts from (up to
    normalize()'s shift and scale of the whole scene)."""
    from rotgraph.pipeline import reconstruct as rc

    seen = {}
    real = pycolmap.IncrementalMapper

    class Spy:
        def __init__(self, cache):
            self.m = real(cache)

        def __getattr__(self, name):
            return getattr(self.m, name)

        def begin_reconstruction(self, rec):
            seen["rec"] = rec
            return self.m.begin_reconstruction(rec)

        def iterative_global_refinement(self, *args):
            rec = seen["rec"]
            def poses():
                ids = sorted(i for i, im in rec.images.items() if im.has_pose)
                R = np.stack([np.asarray(rec.image(i).cam_from_world().rotation.matrix()) for i in ids])
                C = np.stack([np.asarray(rec.image(i).projection_center()) for i in ids])
                return ids, R, C, {c: cam.params.copy() for c, cam in rec.cameras.items()}

            ids, R0, C0, K0 = poses()
            out = self.m.iterative_global_refinement(*args)
            ids1, R1, C1, K1 = poses()
            assert ids1 == ids
            np.testing.assert_allclose(R1, R0, atol=1e-12)  # rotations and intrinsics untouched
            for c in K0:
                np.testing.assert_array_equal(K1[c], K0[c])
            # centres: only normalize()'s shift and scale (no relative motion)
            d0, d1 = C0 - C0.mean(0), C1 - C1.mean(0)
            scale = np.sum(d0 * d1) / np.sum(d0 * d0)
            assert np.abs(d1 - scale * d0).max() < 1e-9 * np.abs(d1).max()
            seen["checked"] = len(ids)
            return out

    monkeypatch.setattr(pycolmap, "IncrementalMapper", Spy)
    s = rc.reconstruct(BUNDLED, tmp_path / "m", seed=0, ground_truth="auto")
    assert seen["checked"] == 14
    assert s["eval"]["rotation_median_deg"] < 0.1


def test_bundled_as_global_mapping(tmp_path):
    """From nearly the same rotations, the same COLMAP stages give nearly global_mapping's
    model: the same registered images and 3D points, observations within 1 % (2,505 both
    when this was written: the retriangulation's rounds complete and filter the same
    observations), rotation and position errors within 5 %."""
    import shutil

    from rotgraph.pipeline.reconstruct import model_errors, reconstruct

    s = reconstruct(BUNDLED, tmp_path / "rg", seed=0, ground_truth=BUNDLED / "sparse" / "0")
    shutil.copyfile(BUNDLED / "database.db", tmp_path / "database.db")
    opts = pycolmap.GlobalPipelineOptions()
    opts.random_seed = 0
    recs = pycolmap.global_mapping(str(tmp_path / "database.db"), str(tmp_path), str(tmp_path / "gm"), opts)
    gm = max(recs.values(), key=lambda r: r.num_reg_images())
    g = model_errors(gm, BUNDLED / "sparse" / "0")
    assert s["n_registered"] == gm.num_reg_images() == 14
    assert s["n_points3D"] == gm.num_points3D()
    assert abs(s["n_observations"] - gm.compute_num_observations()) <= 0.01 * gm.compute_num_observations()
    e = s["eval"]
    assert e["rotation_median_deg"] == pytest.approx(g["rotation_median_deg"], rel=0.05)
    assert e["position_median_rel"] == pytest.approx(g["position_median_rel"], rel=0.05)


@pytest.mark.skipif(not (LUND / "database.db").is_file(), reason="../shared/datasets/lund_door not present")
def test_real_photos(tmp_path):
    from rotgraph.pipeline.reconstruct import reconstruct

    before = hashlib.sha256((LUND / "database.db").read_bytes()).hexdigest()
    s = reconstruct(LUND, tmp_path / "m", seed=0, ground_truth=LUND / "gt")
    assert hashlib.sha256((LUND / "database.db").read_bytes()).hexdigest() == before
    assert not any(Path(str(LUND / "database.db") + x).exists() for x in ("-wal", "-shm", "-journal"))
    e = s["eval"]
    assert e["n_evaluated"] == 12 and e["rotation_median_deg"] < 0.1 and e["position_median_rel"] < 0.01
    # global_mapping's log on this database: "Established 2422 tracks from 13603 observations",
    # "Kept 1762 tracks, discarded 17 due to inconsistency"
    assert (s["n_tracks_established"], s["n_track_observations"], s["n_tracks"], s["n_tracks_inconsistent"]) == (
        2422, 13603, 1762, 17)


def test_bad_inputs(tmp_path):
    r = run("reconstruct", tmp_path / "nope", "-o", tmp_path / "m")
    assert_clean_error(r, tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    r = run("reconstruct", tmp_path / "empty", "-o", tmp_path / "m")
    assert_clean_error(r, tmp_path / "empty")
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "database.db").write_bytes(b"not a database at all" * 10)
    r = run("reconstruct", bad, "-o", tmp_path / "m")
    assert_clean_error(r, bad / "database.db")
    blocker = tmp_path / "file"
    blocker.write_text("x")
    r = run("reconstruct", BUNDLED, "-o", blocker)
    assert r.exit_code in (2, 3) and "Traceback" not in r.output
    r = run("reconstruct", BUNDLED, "-o", tmp_path / "m", "--format", "g2o")
    assert r.exit_code == 2
    assert not (tmp_path / "m").exists()


def test_output_written_atomically(tmp_path, monkeypatch):
    """A failing write leaves no partial model and no temporary folder."""
    out = tmp_path / "m"
    out.mkdir()
    (out / "keep.txt").write_text("mine")

    def boom(self, path):
        Path(path, "cameras.bin").write_bytes(b"half")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(pycolmap.Reconstruction, "write_binary", boom)
    r = run("reconstruct", BUNDLED, "-o", out, "--mapper-seed", "0")
    assert r.exit_code == 3 and "No space left" in r.stderr
    assert sorted(os.listdir(out)) == ["keep.txt"]


def test_refuses_the_projects_own_model_folder(tmp_path):
    """The output may not be the project or its sparse model (the ground truth it is scored
    against): the one check of model outputs (solve's) applies, nothing is written."""
    import shutil

    proj = tmp_path / "proj"
    shutil.copytree(BUNDLED, proj)
    model = next(p for p in (proj / "sparse").rglob("images.*")).parent
    before = _digest(proj)
    for out in (model, proj):
        r = run("reconstruct", proj, "-o", out)
        assert r.exit_code != 0 and "Traceback" not in r.output and "choose another" in r.output, r.output
    assert _digest(proj) == before
