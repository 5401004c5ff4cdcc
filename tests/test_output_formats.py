"""`rotgraph solve -o` in every output format, and `rotgraph eval` reading each back (#18 item 1)."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from rotgraph import average_rotations, so3
from rotgraph.io.colmap_output import write_colmap_model
from rotgraph.io.rotations import read_absolute_rotations
from rotgraph.pipeline.read import read_view_graph
from rotgraph.pipeline.solve import default_options, output_format_of

from cli_helpers import run

ROOT = Path(__file__).resolve().parents[1]
COLMAP = ROOT / "datasets" / "colmap_synthetic"
GT = COLMAP / "sparse" / "0"


def test_output_format_by_extension(tmp_path):
    assert output_format_of("r.csv") == "csv" and output_format_of("r") == "csv" and output_format_of("-") == "csv"
    assert output_format_of("r.json") == "json" and output_format_of("r.TXT") == "text"
    assert output_format_of("model/") == "colmap" and output_format_of(tmp_path) == "colmap"
    assert output_format_of("r.csv", "colmap-txt") == "colmap-txt"


@pytest.fixture(scope="module")
def outputs(tmp_path_factory):
    d = tmp_path_factory.mktemp("outs")
    paths = {"csv": d / "r.csv", "text": d / "r.txt", "json": d / "r.json", "colmap": d / "model", "colmap-txt": d / "model_txt"}
    for fmt, p in paths.items():
        r = run("solve", COLMAP, "-o", p, "--output-format", fmt, "--json")
        assert r.exit_code == 0, r.output
        assert json.loads(r.stdout)["output_format"] == fmt
    return paths


def test_every_output_reads_back_with_the_same_rotations(outputs):
    ids, names, R = read_absolute_rotations(outputs["csv"])
    by_name = dict(zip(names.tolist(), R))
    for fmt in ("text", "json", "colmap", "colmap-txt"):
        i2, n2, R2 = read_absolute_rotations(outputs[fmt])
        keys = (n2 if n2 is not None else i2).tolist()
        assert sorted(keys) == sorted(by_name), fmt
        err = max(float(so3.angle_between(by_name[k], Rk)) for k, Rk in zip(keys, R2))
        assert err < 1e-9, (fmt, err)


def test_eval_gives_the_same_errors_for_every_format(outputs):
    ref = json.loads(run("eval", outputs["csv"], GT, "--json").stdout)
    for fmt in ("text", "json", "colmap", "colmap-txt"):
        r = run("eval", outputs[fmt], GT, "--json")
        assert r.exit_code == 0, (fmt, r.output)
        ev = json.loads(r.stdout)
        assert ev["n_evaluated"] == ref["n_evaluated"] and ev["median"] == pytest.approx(ref["median"], abs=1e-9), fmt
    # and the ground truth may be any of them too
    for fmt in ("text", "json", "colmap"):
        ev = json.loads(run("eval", outputs["csv"], outputs[fmt], "--json").stdout)
        assert ev["max"] < 1e-7 and ev["n_evaluated"] == ref["n_evaluated"]


def test_colmap_model_output_keeps_the_project_structure(outputs):
    pycolmap = pytest.importorskip("pycolmap")
    gt = pycolmap.Reconstruction(str(GT))
    for fmt in ("colmap", "colmap-txt"):
        rec = pycolmap.Reconstruction(str(outputs[fmt]))
        assert sorted(im.name for im in rec.images.values()) == sorted(im.name for im in gt.images.values())
        assert rec.num_rigs() == gt.num_rigs() and rec.num_frames() == gt.num_frames()
        assert rec.num_reg_images() == gt.num_reg_images() and rec.num_points3D() == 0
        for im in rec.images.values():
            assert np.allclose(np.asarray(im.cam_from_world().translation), 0)  # positions: a later step


def test_model_output_writes_estimated_extrinsics(tmp_path):
    """A rig project whose second sensor is uncalibrated: the model gets the estimated
    sensor_from_rig, and every image's rotation equals the solve's."""
    pycolmap = pytest.importorskip("pycolmap")
    from rotgraph.synth import synthesize_colmap_project

    synthesize_colmap_project(tmp_path / "p", n_frames=8, cameras_per_rig=2, n_points=300, seed=1)
    g = read_view_graph(tmp_path / "p")
    g.rigs.cam_from_rig = np.where(g.rigs.is_reference[:, None, None], g.rigs.cam_from_rig, np.nan)
    res = average_rotations(g, default_options("colmap", g.information is not None))
    assert (res.sensors.status == "estimated").sum() == 1
    counts = write_colmap_model(tmp_path / "m", tmp_path / "p", g, res)
    assert counts["n_extrinsics_written"] == 1 and counts["n_images_registered"] == g.n_nodes
    rec = pycolmap.Reconstruction(str(tmp_path / "m"))
    k = int(np.flatnonzero(res.sensors.status == "estimated")[0])
    sensor = pycolmap.sensor_t(type=pycolmap.SensorType.CAMERA, id=int(res.sensors.sensor_ids[k]))
    rig = next(r for r in rec.rigs.values() if r.has_sensor(sensor))
    S = so3.from_pycolmap(rig.sensor_from_rig(sensor).rotation)
    assert so3.angle_between(S, res.sensors.cam_from_rig[k]) < 1e-9
    for n, iid in enumerate(g.node_ids):
        R = so3.from_pycolmap(rec.image(int(iid)).cam_from_world().rotation)
        assert so3.angle_between(R, res.cam_from_world[n]) < 1e-9


def test_model_output_errors(tmp_path):
    r = run("solve", ROOT / "datasets" / "synthetic" / "edges.txt", "-o", tmp_path / "m", "--output-format", "colmap")
    assert r.exit_code == 3 and "COLMAP project" in r.output and not (tmp_path / "m").exists()
    (tmp_path / "file").write_text("x")
    r = run("solve", COLMAP, "-o", tmp_path / "file", "--output-format", "colmap")
    assert r.exit_code == 3 and "must be a folder" in r.output and (tmp_path / "file").read_text() == "x"
    copy = tmp_path / "proj"
    shutil.copytree(COLMAP, copy)
    r = run("solve", copy, "-o", copy / "sparse" / "0", "--output-format", "colmap")
    assert r.exit_code == 3 and "sparse model" in r.output


def test_eval_reads_glomap_style_names_against_a_model(tmp_path, outputs):
    """Issue #18: `rotgraph eval glomap_style.txt gt/` used to exit 3 (names taken for ids)."""
    _, names, R = read_absolute_rotations(outputs["csv"])
    q = so3.quaternions_from_matrices(R)
    (tmp_path / "glomap_style.txt").write_text("".join(f"{n} {a} {b} {c} {d}\n" for n, (a, b, c, d) in zip(names, q.tolist())))
    r = run("eval", tmp_path / "glomap_style.txt", GT, "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["n_evaluated"] == len(names)


def test_model_output_follows_a_symlinked_model_file(tmp_path):
    """A model file of the output folder that is a symlink (CLI.md): its target gets the new
    file and the link stays; the other files are written in place."""
    pycolmap = pytest.importorskip("pycolmap")
    out = tmp_path / "m"
    out.mkdir()
    target = tmp_path / "elsewhere" / "images.bin"
    target.parent.mkdir()
    target.write_bytes(b"old")
    (out / "images.bin").symlink_to(target)
    r = run("solve", COLMAP, "-o", str(out) + "/", "--output-format", "colmap")
    assert r.exit_code == 3 and "--overwrite" in r.output  # b"old" is no model: not replaced unless asked
    assert target.read_bytes() == b"old"
    r = run("solve", COLMAP, "-o", str(out) + "/", "--output-format", "colmap", "--overwrite")
    assert r.exit_code == 0, r.output
    assert (out / "images.bin").is_symlink() and (out / "images.bin").resolve() == target.resolve()
    assert target.read_bytes() != b"old"
    rec = pycolmap.Reconstruction(str(out))
    assert rec.num_reg_images() == pycolmap.Reconstruction(str(GT)).num_reg_images()
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no temporary left behind
