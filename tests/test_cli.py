"""The command line: CLI.md's contract (outputs, JSON keys, exit codes, one-line errors)."""

import json
from pathlib import Path

import numpy as np
import pytest

from rotgraph import so3
from cli_helpers import assert_clean_error, run

ROOT = Path(__file__).resolve().parents[1]
SAMPLE_MEAN = ROOT / "datasets" / "sample_rotations.txt"
SAMPLE_EDGES = ROOT / "datasets" / "synthetic" / "edges.txt"
SAMPLE_GT = ROOT / "datasets" / "synthetic" / "gt.txt"


# ----------------------------------------------------------------------------- mean


def test_mean_prints_the_geodesic_median():
    from rotgraph import mean
    from rotgraph.io.rotations import read_weighted_quaternions

    r = run("mean", SAMPLE_MEAN, "--metric", "geodesic", "--norm", "l1")
    assert r.exit_code == 0
    q = np.array([float(v) for v in r.stdout.split()])
    data, w, _ = read_weighted_quaternions(SAMPLE_MEAN)
    expected = mean(data, metric="geodesic", norm="l1", weights=w).quaternion
    assert q[0] >= 0 and np.allclose(q, expected, atol=1e-12)


@pytest.mark.parametrize("metric", ["geodesic", "chordal", "quaternion"])
@pytest.mark.parametrize("norm", ["l1", "l2", "robust"])
def test_mean_json(metric, norm):
    r = run("mean", SAMPLE_MEAN, "--metric", metric, "--norm", norm, "--json")
    assert r.exit_code == 0
    out = json.loads(r.stdout)
    assert len(out["quaternion"]) == 4 and out["quaternion"][0] >= 0
    assert np.isclose(np.linalg.norm(out["quaternion"]), 1.0)
    assert out["cost"] >= 0 and out["n_rotations"] == 40


def test_mean_csv_input(tmp_path):
    q = so3.quaternions_from_matrices(so3.random_rotations(5, 0))
    f = tmp_path / "r.csv"
    f.write_text("name,qw,qx,qy,qz,weight\n" + "".join(f"a{k},{a},{b},{c},{d},1\n" for k, (a, b, c, d) in enumerate(q)))
    r = run("mean", f, "--metric", "chordal")
    assert r.exit_code == 0
    from scipy.spatial.transform import Rotation

    ref = Rotation.from_quat(np.roll(q, -1, axis=1)).mean().as_quat()
    got = np.roll(np.array([float(v) for v in r.stdout.split()]), -1)
    assert min(np.abs(got - ref).max(), np.abs(got + ref).max()) < 1e-12


@pytest.mark.parametrize(
    "content, line",
    [
        ("", 1),
        ("# only a comment\n", 1),
        ("1 0 0 0\n0.5 0.5 0.5\n", 2),
        ("1 0 0 0\nnan 0 0 1\n", 2),
        ("1 0 0 0\n0 0 0 0\n", 2),
        ("1 0 0 0 1\n0 1 0 0 -2\n", 2),
        ("1 0 0 0\n1 0 x 0\n", 2),
        ("1 0 0 0 1 7\n", 1),
        ("1 0 0 inf\n", 1),
    ],
)
def test_mean_bad_input_one_line_error_exit_3(tmp_path, content, line):
    f = tmp_path / "bad.txt"
    f.write_text(content)
    assert_clean_error(run("mean", f), f, line)


def test_mean_binary_and_missing(tmp_path):
    f = tmp_path / "bin.txt"
    f.write_bytes(b"1 0 0 0\n\x00\x01\x02")
    assert_clean_error(run("mean", f), f, 2)
    assert_clean_error(run("mean", tmp_path / "nope.txt"), tmp_path / "nope.txt")


# ----------------------------------------------------------------------------- solve & co


def test_solve_writes_csv_and_json(tmp_path):
    out = tmp_path / "rot.csv"
    edges = tmp_path / "edges.csv"
    r = run("solve", SAMPLE_EDGES, "-o", out, "--edges-out", edges, "--json")
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    for key in ("n_cameras", "n_edges", "n_solved", "n_outliers", "iterations", "seconds"):
        assert key in s
    assert s["n_cameras"] == 200 and s["n_solved"] == 200
    lines = out.read_text().splitlines()
    assert lines[0].startswith("id,name,qw,qx,qy,qz")
    assert len(lines) == 201
    assert all(float(line.split(",")[2]) >= 0 for line in lines[1:])
    e = edges.read_text().splitlines()
    assert e[0] == "i,j,residual_deg,inlier" and len(e) == s["n_edges"] + 1
    assert sum(line.endswith(",0") for line in e[1:]) == s["n_outliers"]
    # eval against the bundled ground truth
    r = run("eval", out, SAMPLE_GT, "--json")
    assert r.exit_code == 0
    ev = json.loads(r.stdout)
    for key in ("mean", "median", "rmse", "max", "n_evaluated"):
        assert key in ev
    assert ev["n_evaluated"] == 200 and ev["median"] < 2.0


@pytest.mark.parametrize("method", ["irls", "l1", "l2", "chordal", "quaternion", "nodewise", "spanning_tree"])
def test_solve_every_method(tmp_path, method):
    r = run("synth", "-o", tmp_path, "--n", 40, "--degree", 8, "--sigma", 0, "--seed", 1)
    assert r.exit_code == 0
    out = tmp_path / "out.csv"
    r = run("solve", tmp_path / "edges.txt", "-o", out, "--method", method, "--quiet")
    assert r.exit_code == 0 and r.stdout == ""
    r = run("eval", out, tmp_path / "gt.txt", "--json")
    assert json.loads(r.stdout)["max"] < 1e-6


def test_solve_bad_input_leaves_previous_output(tmp_path):
    out = tmp_path / "out.csv"
    out.write_text("id,name,qw,qx,qy,qz\nprevious\n")  # an earlier output (a file of the user's: test_overwrite.py)
    bad = tmp_path / "bad.txt"
    bad.write_text("0 1 1 0 0 0\n1 2 1 0 0\n")
    assert_clean_error(run("solve", bad, "-o", out), bad, 2)
    assert out.read_text() == "id,name,qw,qx,qy,qz\nprevious\n"
    assert [p.name for p in tmp_path.iterdir() if p.name.endswith(".tmp")] == []


def test_solve_self_loop_and_duplicate(tmp_path):
    f = tmp_path / "e.txt"
    f.write_text("0 1 1 0 0 0\n1 1 1 0 0 0\n")
    assert_clean_error(run("solve", f, "-o", tmp_path / "o.csv"), f, 2)
    f.write_text("0 1 1 0 0 0\n1 2 1 0 0 0\n1 0 1 0 0 0\n")
    assert_clean_error(run("solve", f, "-o", tmp_path / "o.csv"), f, 3)
    r = run("solve", f, "-o", tmp_path / "o.csv", "--duplicates", "merge", "--quiet")
    assert r.exit_code == 0


def test_info_json():
    r = run("info", SAMPLE_EDGES, "--json")
    assert r.exit_code == 0
    s = json.loads(r.stdout)
    assert s["n_cameras"] == 200 and s["n_edges"] == 1200 and s["n_components"] == 1
    assert s["n_triangles_checked"] > 0 and 0 < s["cycle_error_median_deg"] < 90


def test_synth_meta(tmp_path):
    r = run("synth", "-o", tmp_path / "p", "--n", 30, "--degree", 6, "--outliers", 0.2, "--graph", "traj")
    assert r.exit_code == 0
    meta = json.loads((tmp_path / "p" / "meta.json").read_text())
    assert meta["n"] == 30 and meta["graph"] == "traj"


def test_eval_plot(tmp_path):
    pytest.importorskip("matplotlib")
    out = tmp_path / "o.csv"
    run("solve", SAMPLE_EDGES, "-o", out, "--quiet")
    png = tmp_path / "err.png"
    r = run("eval", out, SAMPLE_GT, "--plot", png)
    assert r.exit_code == 0 and png.read_bytes()[:4] == b"\x89PNG"


def test_eval_no_common_cameras(tmp_path):
    a = tmp_path / "a.txt"
    b = tmp_path / "b.txt"
    a.write_text("0 1 0 0 0\n")
    b.write_text("5 1 0 0 0\n")
    assert_clean_error(run("eval", a, b), b)


def test_version_and_help():
    assert run("--version").exit_code == 0
    for cmd in ("solve", "eval", "mean", "synth", "info"):
        r = run(cmd, "--help")
        assert r.exit_code == 0 and "Example" in r.stdout


def test_ci_runs_the_readme_commands():
    readme = (ROOT / "README.md").read_text()
    ci = (ROOT / ".ci" / "run").read_text()
    blocks = [b.split("```")[0].strip() for b in readme.split("```bash\n")[1:3]]
    assert len(blocks) == 2
    for cmd in blocks:
        assert cmd in ci, cmd


def test_info_plot(tmp_path):
    pytest.importorskip("matplotlib")
    png = tmp_path / "info.png"
    r = run("info", SAMPLE_EDGES, "--plot", png)
    assert r.exit_code == 0 and png.read_bytes()[:4] == b"\x89PNG"


def test_solve_bundled_colmap_project(tmp_path):
    project = ROOT / "datasets" / "colmap_synthetic"
    before = {p: p.read_bytes() for p in project.rglob("*") if p.is_file()}
    out = tmp_path / "r.csv"
    r = run("solve", project, "-o", out, "--json")
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert s["n_solved"] == 14 and s["eval"]["median"] < 0.2
    assert s["n_pairs_estimated"] + s["n_pairs_stored"] == s["n_edges"]
    r = run("eval", out, project / "sparse" / "0", "--json")
    assert r.exit_code == 0 and json.loads(r.stdout)["median"] < 0.2
    assert {p: p.read_bytes() for p in project.rglob("*") if p.is_file()} == before  # inputs untouched


def test_outputs_never_overwrite_inputs(tmp_path, monkeypatch):
    """check_outputs: an output may not be an input file, nor an existing non-output file
    anywhere inside an input folder (or beside an input database.db); new files and
    rotgraph's own CSV/JSON/PNG outputs are fine; relative and absolute paths agree."""
    from rotgraph.errors import InputError
    from rotgraph.io.outputs import check_outputs

    monkeypatch.chdir(tmp_path)
    (tmp_path / "proj/sparse/0").mkdir(parents=True)
    for f in ("proj/sparse/0/images.bin", "proj/database.db", "proj/old.csv", "e.txt"):
        (tmp_path / f).write_bytes(b"id,name,qw,qx,qy,qz\n" if f.endswith(".csv") else b"x")  # old.csv: an earlier output
    refused = [(["proj/sparse/0/images.bin"], ["proj"]), (["proj/sparse/0/images.bin"], ["proj/database.db"]),
               (["e.txt"], ["e.txt"]), ([str(tmp_path / "e.txt")], ["e.txt"]), (["a.csv", "./a.csv"], []),
               (["missing/out.csv"], []), (["proj"], [])]
    allowed = [(["proj/old.csv"], ["proj"]), (["out.csv"], ["e.txt"]), (["proj/new.bin"], ["proj"]), (["a.csv", "b.csv"], [])]
    for outs, ins in refused:
        with pytest.raises(InputError):
            check_outputs(outs, ins)
    for outs, ins in allowed:
        check_outputs(outs, ins)
    assert all(p.read_bytes() == b"x" for p in [tmp_path / "e.txt", tmp_path / "proj/database.db"])


def test_mean_of_antipodal_data_raises_no_numpy_warning():
    """A datum exactly a half turn from the iterate: no RuntimeWarning leaks to stderr."""
    import warnings

    import rotgraph

    q = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0]])
    for norm in ("l1", "l2", "robust"):
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            rotgraph.mean(q, metric="geodesic", norm=norm)


def test_colmap_model_without_database_warns_that_rotations_come_from_its_poses(tmp_path, caplog):
    """A sparse model read without its database gives relative rotations derived from its
    own poses (a solve reproduces them: 0.000 deg 'error'): one warning saying so and how to
    use the two-view geometries instead; meta marks it. With the database: no warning."""
    import logging
    import shutil
    import subprocess
    import sys

    from rotgraph.io.colmap_model import read_colmap_model_graph
    from rotgraph.pipeline.read import read_view_graph

    pytest.importorskip("pycolmap")
    project = ROOT / "datasets" / "colmap_synthetic"
    model_only = tmp_path / "proj"
    shutil.copytree(project / "sparse", model_only / "sparse")
    with caplog.at_level(logging.WARNING):
        g = read_colmap_model_graph(model_only / "sparse" / "0")
    said = [r.getMessage() for r in caplog.records if "derived from the model's own poses" in r.getMessage()]
    assert len(said) == 1 and "database.db" in said[0] and "project folder" in said[0]
    assert g.meta["relative_rotations_from_poses"] is True
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        g = read_view_graph(project)
    assert not [r for r in caplog.records if "own poses" in r.getMessage()]
    assert "relative_rotations_from_poses" not in g.meta
    # the command line prints it once on stderr
    p = subprocess.run([sys.executable, "-m", "rotgraph", "solve", str(model_only), "-o", str(tmp_path / "r.csv"), "-q"],
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    lines = [s for s in p.stderr.splitlines() if s.strip()]
    assert len(lines) == 1 and lines[0].startswith("rotgraph: warning: ") and "own poses" in lines[0], p.stderr
