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


@pytest.mark.skipif(not (LUND / "database.db").is_file(), reason="../shared/datasets/lund_door not present")
def test_real_photos(tmp_path):
    from rotgraph.pipeline.reconstruct import reconstruct

    before = hashlib.sha256((LUND / "database.db").read_bytes()).hexdigest()
    s = reconstruct(LUND, tmp_path / "m", seed=0, ground_truth=LUND / "gt")
    assert hashlib.sha256((LUND / "database.db").read_bytes()).hexdigest() == before
    assert not any(Path(str(LUND / "database.db") + x).exists() for x in ("-wal", "-shm", "-journal"))
    e = s["eval"]
    assert e["n_evaluated"] == 12 and e["rotation_median_deg"] < 0.1 and e["position_median_rel"] < 0.01


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
