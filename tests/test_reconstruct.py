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


def test_pipeline_starts_from_rotgraphs_rotations(tmp_path):
    """COLMAP's own rotation averaging, given the pose graph of consistent_pairs, returns
    rotgraph's rotations up to one global rotation: global positioning starts from them."""
    s = run("reconstruct", BUNDLED, "-o", tmp_path / "m", "--json", "--mapper-seed", "0")
    s = json.loads(s.stdout)
    assert s["rotations_start_max_deg"] < 1e-9
    assert s["n_pairs_written"] == s["n_pairs_valid"] == 89
    assert set(s) >= {f"seconds_{k}" for k in ("rotations", "pose_graph", "global_positioning", "bundle_adjustment",
                                                "retriangulation", "write")}


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
    assert s["rotations_start_max_deg"] < 1e-9  # the rig's sensor_from_rig too: every image's rotation is rotgraph's


@pytest.mark.parametrize("mode", ["refine", "unknown"])
def test_estimated_extrinsics_reach_colmap(rig_project, tmp_path, mode):
    """Extrinsics rotgraph re-estimates over the stored ones go into the private copy's rigs
    (translations kept): COLMAP then starts from rotgraph's rotations exactly (with the stored
    extrinsics it started 0.011 deg away), and the user's database is untouched."""
    from rotgraph.pipeline.reconstruct import reconstruct

    before = _digest(rig_project)
    s = reconstruct(rig_project, tmp_path / "m", seed=2, overrides={"rig_extrinsics": mode})
    assert _digest(rig_project) == before
    assert s["n_extrinsics_written"] == 1
    assert s["rotations_start_max_deg"] < 1e-9


def test_a_missing_ground_truth_fails_before_the_work(tmp_path):
    r = run("reconstruct", BUNDLED, "-o", tmp_path / "m", "--ground-truth", tmp_path / "nope")
    assert_clean_error(r, tmp_path / "nope")
    assert r.exit_code == 3 and not (tmp_path / "m").exists()


def _bundled_rotations():
    from rotgraph.estimators.rotation_averaging import average_rotations
    from rotgraph.pipeline.read import read_view_graph
    from rotgraph.pipeline.solve import default_options

    graph = read_view_graph(BUNDLED / "database.db", fmt="colmap")
    return graph, average_rotations(graph, default_options("colmap", graph.information is not None))


def test_consistent_pairs():
    """consistent_pairs keeps exactly the pairs whose measured rotation agrees with the
    solved ones within 10 deg, each with COLMAP's pair id and the rotation R_2 R_1^T of the
    solved rotations (the smaller image id first)."""
    from rotgraph import so3
    from rotgraph.pipeline.reconstruct import consistent_pairs

    graph, res = _bundled_rotations()
    pids, rel, counts = consistent_pairs(graph, res, 10.0)
    R, ids = res.cam_from_world, graph.node_ids
    disagree = np.degrees(so3.angle_between(graph.cam2_from_cam1, R[graph.edges[:, 1]] @ np.swapaxes(R[graph.edges[:, 0]], 1, 2)))
    want = {}
    for e, (i, j) in enumerate(graph.edges):
        if disagree[e] <= 10.0:
            lo, hi = (i, j) if ids[i] < ids[j] else (j, i)
            want[int(pycolmap.image_pair_to_pair_id(int(ids[lo]), int(ids[hi])))] = R[hi] @ R[lo].T
    assert sorted(want) == pids.tolist()
    np.testing.assert_allclose(rel, np.stack([want[p] for p in pids.tolist()]), atol=1e-15)
    assert counts["n_pairs"] == graph.n_edges and counts["n_pairs_valid"] == len(pids) == graph.n_edges - 2
    assert counts["n_pairs_rotation_filtered"] == int((disagree > 10.0).sum()) == 2
    assert counts["n_frames_deregistered"] == 0
    everything, _, c = consistent_pairs(graph, res, 0.0)  # no test: every pair
    assert len(everything) == graph.n_edges and c["n_pairs_rotation_filtered"] == 0


def test_consistent_pairs_without_a_pose():
    """An unsolved image: none of its pairs kept (not counted as rotation-filtered), its
    frame outside the component; the other pairs as before."""
    from rotgraph import so3
    from rotgraph.pipeline.reconstruct import consistent_pairs

    graph, res = _bundled_rotations()
    full, _, _ = consistent_pairs(graph, res, 10.0)
    R, E = res.cam_from_world, graph.edges
    disagree = np.degrees(so3.angle_between(graph.cam2_from_cam1, R[E[:, 1]] @ np.swapaxes(R[E[:, 0]], 1, 2)))
    filtered = int(((disagree > 10.0) & (E != 3).all(axis=1)).sum())
    res.solved = res.solved.copy()
    res.solved[3] = False
    pids, _, counts = consistent_pairs(graph, res, 10.0)
    lost = int(graph.node_ids[3])
    touches = {p for p in full.tolist() if lost in pycolmap.pair_id_to_image_pair(p)}
    assert touches and set(pids.tolist()) == set(full.tolist()) - touches
    assert counts["n_pairs_rotation_filtered"] == filtered and counts["n_frames_deregistered"] == 0
    assert counts["n_pairs_valid"] == len(pids)


def test_written_pose_graph_gives_colmap_rotgraphs_rotations():
    """In the private copy, the kept pairs carry the consistent rotations (translations
    kept), the others no pose; COLMAP's rotation averaging on it (every later stage
    skipped) returns rotgraph's rotations up to one global rotation."""
    from rotgraph import so3
    from rotgraph.io.colmap import database_copy
    from rotgraph.io.colmap import write_pair_rotations as _write_pairs
    from rotgraph.pipeline.reconstruct import _start_deviation, consistent_pairs

    graph, res = _bundled_rotations()
    pids, rel, _ = consistent_pairs(graph, res, 10.0)
    with database_copy(BUNDLED / "database.db") as db:
        before = dict(zip(*db.read_two_view_geometries()))
        assert _write_pairs(pycolmap, db, pids, rel) == len(pids) + sum(
            before[p].cam2_from_cam1 is not None for p in before if p not in set(pids.tolist()))
        after = dict(zip(*db.read_two_view_geometries()))
        assert set(after) == set(before)
        rows = dict(zip(pids.tolist(), rel))
        for p, tvg in after.items():
            np.testing.assert_array_equal(tvg.inlier_matches, before[p].inlier_matches)
            if p in rows:
                np.testing.assert_allclose(so3.from_pycolmap(tvg.cam2_from_cam1.rotation), rows[p], atol=1e-12)
                if before[p].cam2_from_cam1 is not None:
                    np.testing.assert_array_equal(tvg.cam2_from_cam1.translation, before[p].cam2_from_cam1.translation)
            else:
                assert tvg.cam2_from_cam1 is None
        opts = pycolmap.GlobalPipelineOptions()
        opts.decompose_relative_pose = False
        m = opts.mapper
        m.skip_track_establishment = m.skip_global_positioning = m.skip_bundle_adjustment = m.skip_retriangulation = True
        manager = pycolmap.ReconstructionManager()
        pycolmap.GlobalPipeline(opts, db, manager).run()
    rec = manager.get(0)
    assert rec.num_reg_images() == graph.n_nodes
    assert _start_deviation(rec, graph.node_ids.astype(np.int64), res.cam_from_world) < 1e-9


def test_bundled_as_global_mapping(tmp_path):
    """global_mapping's own stages from rotgraph's rotations give global_mapping's model:
    the same registered images, 3D points and observations (2,505 when this was written),
    rotation and position errors within 0.1 % (measured: 4e-5 and 3e-6)."""
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
    assert s["n_observations"] == gm.compute_num_observations()
    e = s["eval"]
    assert e["rotation_median_deg"] == pytest.approx(g["rotation_median_deg"], rel=1e-3)
    assert e["position_median_rel"] == pytest.approx(g["position_median_rel"], rel=1e-3)


@pytest.mark.skipif(not (LUND / "database.db").is_file(), reason="../shared/datasets/lund_door not present")
def test_real_photos(tmp_path):
    from rotgraph.pipeline.reconstruct import reconstruct

    before = hashlib.sha256((LUND / "database.db").read_bytes()).hexdigest()
    s = reconstruct(LUND, tmp_path / "m", seed=0, ground_truth=LUND / "gt")
    assert hashlib.sha256((LUND / "database.db").read_bytes()).hexdigest() == before
    assert not any(Path(str(LUND / "database.db") + x).exists() for x in ("-wal", "-shm", "-journal"))
    e = s["eval"]
    assert e["n_evaluated"] == 12 and e["rotation_median_deg"] < 0.1 and e["position_median_rel"] < 0.01
    assert s["rotations_start_max_deg"] < 1e-9 and s["n_pairs_written"] == s["n_pairs_valid"] == 66


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


def test_an_output_folder_that_refuses_files_fails_before_the_work(tmp_path, monkeypatch):
    """io.outputs.probe_folder, the one writability check: /sys passes permission bits for root
    but refuses new files; the error comes before any stage runs (no rotation averaging)."""
    if not os.path.isdir("/sys"):
        pytest.skip("no /sys to test with")
    import rotgraph.estimators.rotation_averaging as ra

    def no_solve(*a, **k):
        raise AssertionError("the solve ran before the output check")

    monkeypatch.setattr(ra, "average_rotations", no_solve)
    r = run("reconstruct", BUNDLED, "-o", "/sys/rotgraph-test-model")
    assert r.exit_code == 3 and "cannot write here" in r.output and "Traceback" not in r.output, r.output
