"""Progress bars: drawn on a terminal, silent in pipes and with --quiet, never in the way."""

from __future__ import annotations

import io

import numpy as np
import pytest

from rotgraph.cli.progress import Progress
from rotgraph.estimators.rotation_averaging import SolveOptions
from rotgraph.pipeline.solve import solve_file
from rotgraph.synth import random_problem


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


@pytest.fixture
def problem(tmp_path):
    from rotgraph.io.writers import write_edges

    g = random_problem(n=60, degree=8, sigma_deg=2.0, outliers=0.1, seed=3)
    path = tmp_path / "edges.txt"
    write_edges(path, g)
    return path


def _solve_with(progress, problem, tmp_path):
    return solve_file(str(problem), str(tmp_path / "out.csv"), SolveOptions(method="irls"), callback=progress, read_progress=progress.count)


def test_bars_on_a_terminal_follow_every_stage(monkeypatch, problem, tmp_path):
    term = _Terminal()
    monkeypatch.setattr("sys.stderr", term)
    progress = Progress(quiet=False, mininterval=0.0)  # draw every update
    summary = _solve_with(progress, problem, tmp_path)
    progress.close()
    text = term.getvalue()
    assert "l1" in text and "geman_mcclure" in text  # one bar per IRLS stage
    assert "step" in text and "deg" in text
    assert summary["iterations"] >= 2
    # the counting interface, as the COLMAP reader uses it
    progress.count("relative poses", 0, 10)
    progress.count("relative poses", 10, 10)
    progress.close()
    assert "relative poses" in term.getvalue() and "10/10" in term.getvalue()


@pytest.mark.parametrize("quiet,tty", [(True, True), (False, False)])
def test_silent_when_quiet_or_not_a_terminal(monkeypatch, problem, tmp_path, quiet, tty):
    err = _Terminal() if tty else io.StringIO()
    monkeypatch.setattr("sys.stderr", err)
    progress = Progress(quiet=quiet)
    _solve_with(progress, problem, tmp_path)
    progress.close()
    assert err.getvalue() == ""


def test_progress_does_not_change_the_result(problem, tmp_path):
    a = solve_file(str(problem), str(tmp_path / "a.csv"), SolveOptions(method="irls"))
    b = _solve_with(Progress(quiet=True), problem, tmp_path)
    assert a["iterations"] == b["iterations"]
    assert (tmp_path / "a.csv").read_bytes() == (tmp_path / "out.csv").read_bytes()


def test_colmap_reader_reports_pairs(tmp_path):
    pytest.importorskip("pycolmap")
    from pathlib import Path

    from rotgraph.pipeline.colmap import read_colmap_project

    project = Path(__file__).resolve().parents[1] / "datasets" / "colmap_synthetic"
    seen = []
    for vectorize in (True, False):
        seen.clear()
        g = read_colmap_project(project, progress=lambda stage, done, total: seen.append((stage, done, total)), vectorize=vectorize, workers=1)
        n = g.meta["n_pairs_estimated"]
        assert seen and all(s == "relative poses" for s, _, _ in seen)
        done = [d for _, d, _ in seen]
        assert done == sorted(done) and seen[-1][1] == seen[-1][2] >= n
    assert np.isfinite(g.cam2_from_cam1).all()
