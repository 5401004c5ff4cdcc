"""What a new user hits in the first hour (#15): interrupts, flags after the command name,
JSON on failure, per-camera evaluation, names on --edges-out, plot formats."""

import csv
import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from cli_helpers import run

ROOT = Path(__file__).resolve().parents[1]
EDGES = ROOT / "datasets" / "synthetic" / "edges.txt"
GT = ROOT / "datasets" / "synthetic" / "gt.txt"
COLMAP = ROOT / "datasets" / "colmap_synthetic"


def _rotgraph(*args, **kw):
    return subprocess.Popen([sys.executable, "-m", "rotgraph", *map(str, args)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, **kw)


@pytest.mark.slow
def test_ctrl_c_exits_130_without_traceback_or_partial_output(tmp_path, foreground):
    from rotgraph.io.writers import write_edges
    from rotgraph.synth import random_problem

    big = tmp_path / "big.txt"
    # big enough that the read and the solve last well past the signal on a fast machine
    # (6,000 cameras / 180k edges solved in 1.1-1.45 s once the solver got faster)
    write_edges(big, random_problem(n=20000, degree=60, sigma_deg=2.0, outliers=0.2, seed=1))
    out = tmp_path / "out" / "r.csv"
    out.parent.mkdir()
    p = subprocess.Popen(foreground([sys.executable, "-m", "rotgraph", "solve", big, "-o", out]), stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True)
    time.sleep(1.5)  # inside the read or the solve
    p.send_signal(signal.SIGINT)
    stdout, stderr = p.communicate(timeout=60)
    assert p.returncode == 130, (stdout, stderr)
    assert stderr.strip().splitlines() == ["rotgraph: error: interrupted"]
    assert list(out.parent.iterdir()) == []  # no output, no temporary file


def test_group_flags_work_after_the_command_name(tmp_path):
    r = run("solve", EDGES, "-o", tmp_path / "a.csv", "-v")
    assert r.exit_code == 0 and "rotgraph: info:" in r.stderr
    r = run("-q", "solve", EDGES, "-o", tmp_path / "b.csv")  # solve's own -q, given before the name
    assert r.exit_code == 0 and r.stdout == "" and r.stderr == ""
    r = run("mean", ROOT / "datasets" / "sample_rotations.txt", "-q")  # mean has no -q: the group's
    assert r.exit_code == 0 and r.stderr == "" and len(r.stdout.split()) == 4
    r = run("mean", ROOT / "datasets" / "sample_rotations.txt", "--debug", "-vv")
    assert r.exit_code == 0 and "rotgraph: debug:" in r.stderr


def test_json_failure_is_one_object_on_stdout_and_one_line_on_stderr(tmp_path):
    missing = tmp_path / "nope.txt"
    r = run("solve", missing, "-o", tmp_path / "o.csv", "--json")
    assert r.exit_code == 3
    assert json.loads(r.stdout) == {"error": f"{missing}: no such file", "exit_code": 3}
    assert r.stderr.strip().splitlines() == [f"rotgraph: error: {missing}: no such file"]
    r = run("eval", tmp_path / "x.csv", GT, "--json", "--nope")  # a usage error (click's own)
    assert r.exit_code == 2 and json.loads(r.stdout)["exit_code"] == 2


def test_eval_per_camera_and_worst(tmp_path):
    est = tmp_path / "r.csv"
    assert run("solve", EDGES, "-o", est, "-q").exit_code == 0
    per = tmp_path / "per.csv"
    r = run("eval", est, GT, "--json", "--per-camera", per)
    assert r.exit_code == 0, r.output
    ev = json.loads(r.stdout)
    rows = list(csv.DictReader(per.open()))
    assert len(rows) == ev["n_evaluated"] == 200 and set(rows[0]) == {"id", "name", "error_deg"}
    errors = sorted((float(x["error_deg"]) for x in rows), reverse=True)
    assert [w["error_deg"] for w in ev["worst"]] == pytest.approx(errors[:10])
    assert abs(max(errors) - ev["max"]) < 1e-12


def test_edges_out_names_colmap_images(tmp_path):
    r = run("solve", COLMAP, "-o", tmp_path / "r.csv", "--edges-out", tmp_path / "e.csv", "-q")
    assert r.exit_code == 0, r.output
    rows = list(csv.DictReader((tmp_path / "e.csv").open()))
    assert list(rows[0])[:6] == ["i", "j", "residual_deg", "inlier", "name_i", "name_j"]
    names = {row["name"] for row in csv.DictReader((tmp_path / "r.csv").open())}
    assert {row["name_i"] for row in rows} | {row["name_j"] for row in rows} <= names


@pytest.mark.parametrize("ext, magic", [("png", b"\x89PNG"), ("pdf", b"%PDF"), ("svg", b"<?xml")])
def test_plot_writes_the_format_of_its_extension(tmp_path, ext, magic):
    pytest.importorskip("matplotlib")
    est = tmp_path / "r.csv"
    assert run("solve", EDGES, "-o", est, "-q").exit_code == 0
    plot = tmp_path / f"errors.{ext}"
    r = run("eval", est, GT, "--plot", plot)
    assert r.exit_code == 0 and plot.read_bytes().startswith(magic)
    assert f"-> {plot}" in r.stderr


def test_plot_with_an_unknown_extension_is_refused_before_any_work(tmp_path):
    r = run("eval", tmp_path / "missing.csv", GT, "--plot", tmp_path / "errors.jpg")
    assert r.exit_code == 3 and "errors.jpg" in r.stderr and ".png" in r.stderr
    assert not (tmp_path / "errors.jpg").exists()


def test_cli_help_examples_need_no_repository_files():
    """An installed user has no datasets/ folder: the --help examples make their own data."""
    from rotgraph.cli.main import cli

    for name, command in cli.commands.items():
        assert "datasets/" not in (command.help or ""), name


def test_synth_into_a_folder_that_cannot_be_made_is_bad_input(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    r = run("synth", "-o", blocker / "sub", "--n", "10")
    assert r.exit_code == 3 and r.stderr.startswith(f"rotgraph: error: {blocker / 'sub'}: cannot make the output folder")


def test_json_and_csv_on_stdout_together_are_a_usage_error(tmp_path):
    r = run("solve", EDGES, "-o", "-", "--json")
    assert r.exit_code == 2 and "stdout" in r.stderr
    assert json.loads(r.stdout)["exit_code"] == 2
