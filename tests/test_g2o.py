"""g2o pose graphs as rotgraph treats them (issue #15): parallel edges are kept by default
for g2o, and only for g2o.

The g2o files are written here by hand in g2o's own conventions (world_from_body poses,
quaternions x, y, z, w, edge = T_i^-1 T_j), never with rotgraph's writers.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from cli_helpers import assert_clean_error, run
from rotgraph.errors import InputError
from rotgraph.pipeline.read import DUPLICATES_BY_FORMAT, default_duplicates, read_view_graph

INFO = " ".join(["1"] * 21)  # the 21 information entries (read, not used)


def xyzw(R) -> str:
    return " ".join(f"{v:.17g}" for v in Rotation.from_matrix(R).as_quat())


def write_g2o(path: Path, R, pairs, vertices=None, parallel=()) -> Path:
    """A g2o file whose edge (i, j) has rotation ``R_j R_i^T`` (rotgraph's convention) and
    whose vertices are ``vertices`` (cam_from_world, default ``R``; rows of NaN: no line).
    ``parallel``: edges written a second time, with a 0.5 degree twist."""
    V = R if vertices is None else vertices
    lines = [f"VERTEX_SE3:QUAT {k} 0 0 0 {xyzw(V[k].T)}" for k in range(len(V)) if np.isfinite(V[k]).all()]
    for i, j in pairs:
        lines.append(f"EDGE_SE3:QUAT {i} {j} 1 0 0 {xyzw(R[i] @ R[j].T)} {INFO}")  # Q_i^T Q_j = R_i R_j^T
    twist = Rotation.from_rotvec([0, 0, np.radians(0.5)]).as_matrix()
    for i, j in parallel:
        lines.append(f"EDGE_SE3:QUAT {i} {j} 1 0 0 {xyzw(R[i] @ R[j].T @ twist)} {INFO}")
    path.write_text("\n".join(lines) + "\n")
    return path


def trajectory(n=12, seed=0):
    """Rotations along a path, odometry edges (k, k+1) and a few loop closures."""
    rng = np.random.default_rng(seed)
    steps = Rotation.from_rotvec(rng.normal(scale=0.2, size=(n, 3))).as_matrix()
    R = np.empty((n, 3, 3))
    R[0] = np.eye(3)
    for k in range(1, n):
        R[k] = steps[k] @ R[k - 1]
    pairs = [(k, k + 1) for k in range(n - 1)] + [(0, n // 2), (2, n - 1), (3, n - 2)]
    return R, pairs


@pytest.fixture
def g2o_file(tmp_path) -> tuple[Path, np.ndarray]:
    R, pairs = trajectory()
    return write_g2o(tmp_path / "graph.g2o", R, pairs, parallel=[(0, 1), (4, 5)]), R


# ----------------------------------------------------------------------- parallel edges


def test_parallel_edges_are_kept_by_default_for_g2o_only(g2o_file, tmp_path):
    path, R = g2o_file
    assert default_duplicates("g2o") == "keep" == DUPLICATES_BY_FORMAT["g2o"]
    assert all(default_duplicates(f) == "error" for f in ("rotgraph", "csv", "glomap", "1dsfm", "mat", "colmap"))
    assert read_view_graph(path, duplicates=None).n_edges == 16  # 14 + 2 parallel
    with pytest.raises(InputError, match="duplicate pair"):
        read_view_graph(path)  # the library's own default stays explicit: error
    r = run("solve", path, "-o", tmp_path / "o.csv", "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["n_edges"] == 16
    r = run("info", path, "--json")
    assert r.exit_code == 0 and json.loads(r.stdout)["n_edges"] == 16
    for cmd in (["solve", path, "-o", tmp_path / "o2.csv"], ["info", path]):
        r = run(*cmd, "--duplicates", "error")
        assert_clean_error(r, path, code=3)
        assert "duplicate pair" in r.stderr
    merged = run("info", path, "--json", "--duplicates", "merge")
    assert json.loads(merged.stdout)["n_edges"] == 14
    # the same pairs as a rotgraph text file: an error by default
    txt = tmp_path / "e.txt"
    txt.write_text("0 1 1 0 0 0\n1 2 1 0 0 0\n1 0 1 0 0 0\n")
    for cmd in (["solve", txt, "-o", tmp_path / "o3.csv"], ["info", txt]):
        assert_clean_error(run(*cmd), txt, code=3)


@pytest.mark.parametrize("cmd", ["solve", "info", "batch"])
def test_help_states_the_per_format_duplicates_default(cmd):
    r = run(cmd, "--help")
    text = " ".join(r.stdout.split())
    assert "default: (error; keep for g2o)" in text
    assert all(f"{policy} for {fmt}" in text for fmt, policy in DUPLICATES_BY_FORMAT.items())


@pytest.mark.slow
def test_batch_follows_the_per_format_default(g2o_file, tmp_path):
    pytest.importorskip("distributed")
    path, _ = g2o_file
    txt = tmp_path / "dup.txt"
    txt.write_text("0 1 1 0 0 0\n1 2 1 0 0 0\n1 0 1 0 0 0\n")
    out = tmp_path / "out"
    p = subprocess.run([sys.executable, "-m", "rotgraph", "batch", str(path), str(txt), "--out-dir", str(out),
                        "--workers", "1", "--json", "-q"], capture_output=True, text=True, timeout=300)
    manifest = {Path(e["input"]).name: e for e in json.loads(p.stdout)}
    assert p.returncode == 1, p.stderr
    assert manifest["graph.g2o"]["status"] == "ok" and manifest["graph.g2o"]["n_edges"] == 16
    assert manifest["dup.txt"]["status"] == "failed" and "duplicate pair" in manifest["dup.txt"]["error"]
