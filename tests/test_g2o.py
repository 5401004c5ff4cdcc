"""g2o pose graphs as rotgraph treats them (issue #15, items 5 and 6): VERTEX lines are an
initial guess (dead-reckoned odometry), never ground truth (``info`` says so, ``eval``
refuses them, ``solve`` never evaluates against them, ``--init vertices`` starts from
them); parallel edges are kept by default for g2o, and only for g2o.

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
from rotgraph import so3
from rotgraph.errors import InputError
from rotgraph.estimators.rotation_averaging import average_rotations, initial_guess_rotations
from rotgraph.estimators.spanning_tree import spanning_tree_rotations
from rotgraph.estimators.types import SolveOptions
from rotgraph.evaluate import compare_rotations
from rotgraph.io.rotations import read_absolute_rotations
from rotgraph.pipeline.read import DUPLICATES_BY_FORMAT, default_duplicates, read_view_graph
from rotgraph.pipeline.solve import evaluate_against_input_gt
from rotgraph.synth import random_problem

DATA = Path(__file__).resolve().parents[2] / "shared" / "datasets"
INFO = " ".join(["1"] * 21)  # the 21 information entries (read, not used)
NOT_GT = "g2o vertices are initial guesses (odometry), not ground truth; give a ground-truth file"


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


# ----------------------------------------------------------------------- vertices: an initial guess


def test_vertices_are_an_initial_guess_never_ground_truth(g2o_file):
    path, R = g2o_file
    g = read_view_graph(path, duplicates=None)
    assert g.gt_cam_from_world is None
    assert g.initial_cam_from_world.shape == (12, 3, 3)
    assert np.abs(g.initial_cam_from_world - R).max() < 1e-12
    assert not any("initial_guess" in k or "ground" in k for k in g.meta)  # a typed field, not meta
    # it follows the nodes through subgraphs and the duplicate policies
    sub, _ = g.subgraph(np.array([3, 5, 7]))
    assert np.abs(sub.initial_cam_from_world - R[[3, 5, 7]]).max() < 1e-12
    merged = read_view_graph(path, duplicates="merge")
    assert merged.n_edges == g.n_edges - 2 and np.abs(merged.initial_cam_from_world - R).max() < 1e-12


def test_info_says_initial_guess_not_ground_truth(g2o_file):
    path, _ = g2o_file
    r = run("info", path)
    assert r.exit_code == 0, r.output
    assert "initial guess in the input: 12 cameras" in r.stdout
    assert "ground truth" not in r.stdout.replace("not ground truth", "")
    s = json.loads(run("info", path, "--json").stdout)
    assert s["n_initial_guess"] == 12 and s["n_ground_truth"] == 0


def test_eval_refuses_g2o_as_ground_truth(g2o_file, tmp_path):
    path, _ = g2o_file
    est = tmp_path / "est.csv"
    assert run("solve", path, "-o", est, "-q").exit_code == 0
    r = run("eval", est, path)
    assert_clean_error(r, path, code=3)
    assert NOT_GT in r.stderr
    with pytest.raises(InputError, match="initial guesses"):
        read_absolute_rotations(path)
    with pytest.raises(InputError, match="initial guesses"):
        read_absolute_rotations(path, "g2o")


def test_solve_never_evaluates_against_vertices(g2o_file, tmp_path):
    path, _ = g2o_file
    r = run("solve", path, "-o", tmp_path / "o.csv", "--json")
    assert r.exit_code == 0, r.output
    assert "eval" not in json.loads(r.stdout)
    r = run("solve", path, "-o", tmp_path / "o.csv")
    assert "ground truth" not in r.stdout


def test_evaluation_decision_reads_no_meta():
    """Ground truth is evaluated because it is in gt_cam_from_world, whatever meta says."""
    g = random_problem(n=20, degree=6, sigma_deg=1.0, outliers=0.0, seed=3)
    res = average_rotations(g)
    g.meta["g2o_vertices_are_initial_guess"] = True  # the old flag: informational at most
    assert evaluate_against_input_gt(g, res)["n_evaluated"] == 20
    g.initial_cam_from_world, g.gt_cam_from_world = g.gt_cam_from_world, None
    assert evaluate_against_input_gt(g, res) is None


# ----------------------------------------------------------------------- --init vertices


def noisy_graph(seed=1, n=40):
    g = random_problem(n=n, degree=6, sigma_deg=2.0, outliers=0.0, graph="traj", seed=seed)
    return g, g.gt_cam_from_world


def test_init_vertices_starts_from_the_guess():
    g, _ = noisy_graph()
    opt = average_rotations(g, method="l2", step_tol_deg=0.0, max_iterations=50).cam_from_world
    g.initial_cam_from_world = opt @ Rotation.random(random_state=5).as_matrix()  # another gauge
    one = dict(method="l2", max_iterations=1, step_tol_deg=0.0)
    res = average_rotations(g, init="vertices", **one)
    assert [s["stage"] for s in res.stages] == ["spanning_tree", "vertices", "l2"]
    assert compare_rotations(res.cam_from_world, opt).max < 1e-6  # one step from the optimum stays there
    assert np.abs(res.cam_from_world[res.anchor] - np.eye(3)).max() < 1e-9  # the solvers' gauge
    far = average_rotations(g, init="mst", **one)  # the spanning tree needs more than one step
    assert compare_rotations(far.cam_from_world, opt).max > 1e-3
    g.initial_cam_from_world = so3.random_rotations(g.n_nodes, np.random.default_rng(0))
    assert compare_rotations(average_rotations(g, init="vertices", **one).cam_from_world, opt).max > 1.0


def test_init_vertices_fills_missing_cameras_along_the_spanning_tree():
    g = random_problem(n=30, degree=5, sigma_deg=0.0, outliers=0.0, graph="traj", seed=2)  # noise-free: chaining is exact
    R = g.gt_cam_from_world
    guess = R.copy()
    qrel = so3.quaternion_rows_from_matrices(g.cam2_from_cam1)
    _, anchor, tree = spanning_tree_rotations(g.n_nodes, g.edges, qrel, g.weights)
    missing = [anchor, 0, 7, 8, 9, 29]  # the anchor too, and a run of neighbours
    guess[missing] = np.nan
    g.initial_cam_from_world = guess
    q = initial_guess_rotations(g, qrel, tree, anchor)
    got = so3.matrices_from_quaternion_rows(q)
    assert np.abs(got[anchor] - np.eye(3)).max() < 1e-9
    assert compare_rotations(got, R).max < 1e-6
    res = average_rotations(g, init="vertices")
    assert res.n_solved == 30 and compare_rotations(res.cam_from_world, R).max < 1e-6


def test_init_vertices_without_a_guess_is_an_input_error(tmp_path):
    g, _ = noisy_graph()
    with pytest.raises(InputError, match="no initial guess"):
        average_rotations(g, init="vertices")
    g.initial_cam_from_world = np.full((g.n_nodes, 3, 3), np.nan)
    with pytest.raises(InputError, match="no camera of the solved component has an initial guess"):
        average_rotations(g, init="vertices")
    average_rotations(g, init="vertices", method="chordal")  # a method without initialisation ignores it
    assert SolveOptions(init="vertices").validated().init == "vertices"
    # the command line: exit 3, one line naming the input
    run("synth", "-o", tmp_path, "--n", 20, "--degree", 5)
    edges = tmp_path / "edges.txt"
    r = run("solve", edges, "-o", tmp_path / "o.csv", "--init", "vertices")
    assert_clean_error(r, edges, code=3)
    assert "no initial guess" in r.stderr


def test_cli_init_vertices_on_g2o(g2o_file, tmp_path):
    path, R = g2o_file
    r = run("solve", path, "-o", tmp_path / "o.csv", "--init", "vertices", "--json")
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert s["options"]["init"] == "vertices" and s["n_solved"] == 12
    _, _, got = read_absolute_rotations(tmp_path / "o.csv")
    assert compare_rotations(got, R).max < 0.5  # two parallel edges are 0.5 degrees off


@pytest.mark.parametrize("name", ["parking_garage/parking-garage.g2o", "cubicle/cubicle.g2o"])
def test_init_vertices_on_the_pose_graph_benchmarks(name):
    path = DATA / name
    if not path.exists():
        pytest.skip(f"shared data set not available: {path}")
    g = read_view_graph(path, duplicates=None)
    default = average_rotations(g, method="irls")  # costs of one fixed loss, comparable
    res = average_rotations(g, method="irls", init="vertices")
    assert res.converged and res.n_solved == g.n_nodes
    # the same optimum or a better one (cubicle: 0.24470 vs 0.24602 from the spanning tree)
    assert res.cost <= default.cost * (1 + 1e-6)


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
