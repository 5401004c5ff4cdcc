"""`rotgraph certify` and `solve --certify` (issue #20, item 4): the command line and the
pipeline over rotgraph.estimators.certify."""

import json

import numpy as np
import pytest

from rotgraph import average_rotations, compare_rotations
from rotgraph.pipeline.certify import certify_result
from rotgraph.pipeline.solve import default_options
from rotgraph.synth import random_problem

from cli_helpers import run


@pytest.fixture(scope="module")
def problem(tmp_path_factory):
    d = tmp_path_factory.mktemp("cert")
    r = run("synth", "-o", d, "--n", "80", "--degree", "10", "--sigma", "2", "--outliers", "0.1", "--seed", "3")
    assert r.exit_code == 0, r.output
    return d


def test_solve_certify_writes_a_certified_result(problem, tmp_path):
    r = run("solve", problem / "edges.txt", "-o", tmp_path / "r.csv", "--edges-out", tmp_path / "res.csv", "--certify", "--json")
    assert r.exit_code == 0, r.output
    cert = json.loads(r.stdout)["certificate"]
    assert cert["certified"] is True and cert["lambda_min"] >= -cert["tolerance"]
    assert abs(cert["duality_gap"]) < 1e-6 and cert["seconds"] >= 0
    assert cert["final_stage"]["stage"] == "chordal_on_inliers"
    # the written rotations are the certified ones: certify says so again from the files
    r2 = run("certify", tmp_path / "r.csv", problem / "edges.txt", "--inliers", tmp_path / "res.csv", "--json")
    assert r2.exit_code == 0, r2.output
    again = json.loads(r2.stdout)
    assert again["certified"] is True and again["n_edges"] == cert["n_edges"]
    r3 = run("solve", problem / "edges.txt", "-o", tmp_path / "r.csv", "--certify")
    assert r3.exit_code == 0 and "certified globally optimal" in r3.stdout


def test_certify_refuses_a_non_critical_candidate(problem):
    """The ground truth of a noisy problem is not a critical point: not certified, exit 1."""
    r = run("certify", problem / "gt.txt", problem / "edges.txt", "--json")
    assert r.exit_code == 1
    cert = json.loads(r.stdout)
    assert cert["certified"] is False and "not critical" in cert["reason"]
    r = run("certify", problem / "gt.txt", problem / "edges.txt")
    assert r.exit_code == 1 and "NOT certified" in r.stdout


def test_noise_free_truth_is_certified(tmp_path):
    r = run("synth", "-o", tmp_path, "--n", "40", "--degree", "6", "--sigma", "0")
    assert r.exit_code == 0
    r = run("certify", tmp_path / "gt.txt", tmp_path / "edges.txt", "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["certified"] is True


def test_certify_bad_inputs(problem, tmp_path):
    bad = tmp_path / "res.csv"
    bad.write_text("i,j,residual_deg,inlier\n0,1,0.5,1\n9999,1,0.5,1\n")
    r = run("certify", problem / "gt.txt", problem / "edges.txt", "--inliers", bad)
    assert r.exit_code == 3 and f"{bad}:3:" in r.output and "Traceback" not in r.output
    bad.write_text("i,j,residual_deg,inlier\n0,1,0.5,2\n")
    r = run("certify", problem / "gt.txt", problem / "edges.txt", "--inliers", bad)
    assert r.exit_code == 3 and f"{bad}:2:" in r.output and "0 or 1" in r.output
    other = tmp_path / "other.txt"
    other.write_text("foo 1 0 0 0\nbar 1 0 0 0\n")
    r = run("certify", other, problem / "edges.txt")
    assert r.exit_code == 3 and "no camera" in r.output


@pytest.mark.parametrize("kw", [dict(outliers=0.15, degree=20), dict(noise_mix=(0.5, 5.0), degree=20, sigma_deg=0.5)])
def test_certified_final_stage_keeps_the_accuracy(kw):
    """The chordal problem of the solve's own final weights (its fixed point): moving to its
    optimum changes the rotations little and the error not at all (within 2 %)."""
    g = random_problem(n=300, seed=1, **{"sigma_deg": 2.0, **kw})
    opts = default_options(None)
    r = average_rotations(g, opts)
    rc, cert = certify_result(g, r, opts)
    assert cert["certified"]
    e0 = compare_rotations(r.cam_from_world, g.gt_cam_from_world).median
    e1 = compare_rotations(rc.cam_from_world, g.gt_cam_from_world).median
    assert e1 <= 1.02 * e0
    np.testing.assert_array_equal(rc.inliers, r.inliers)


def test_single_mean_certificates():
    """Single rotation averaging: the paper's conditions, the same way (certified / why)."""
    from rotgraph import mean, so3

    rng = np.random.default_rng(0)
    R0 = so3.exp(np.array([0.3, -0.2, 1.0]))
    tight = so3.exp(rng.normal(0, 0.2, (50, 3))) @ R0  # within ~40 deg
    for metric, norm in (("geodesic", "l2"), ("geodesic", "l1"), ("quaternion", "l2"), ("chordal", "l1")):
        c = mean(tight, metric=metric, norm=norm).certificate
        assert c["certified"] and c["max_angle_deg"] < 90, (metric, norm, c)
    spread = so3.random_rotations(50, rng)  # uniform: far beyond a pi/2 ball
    c = mean(spread, metric="geodesic", norm="l2").certificate
    assert not c["certified"] and c["max_angle_deg"] >= 90 and "other minima" in c["reason"]
    assert mean(spread, metric="chordal", norm="l2").certificate["certified"]  # closed form
    assert not mean(tight, norm="robust").certificate["certified"]


def test_mean_json_has_the_certificate(tmp_path):
    f = tmp_path / "q.txt"
    f.write_text("1 0 0 0\n0.999 0.01 0.02 0\n0.998 0 0.03 0.01\n")
    r = run("mean", f, "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["certificate"]["certified"] is True


def test_certified_final_stage_keeps_rigs():
    """A rig solve is certified at the frame level: every image keeps its cam_from_rig."""
    from rotgraph import so3
    from rotgraph.viewgraph import Rigs, ViewGraph

    rng = np.random.default_rng(8)
    frames = 20
    S = np.stack([np.eye(3), so3.exp(np.array([0, 1.2, 0.2])), so3.exp(np.array([0.5, 0, -0.7]))])
    R = (S[None] @ so3.random_rotations(frames, rng)[:, None]).reshape(-1, 3, 3)
    n = len(R)
    pairs = np.array([(a, b) for a in range(n) for b in range(a + 1, n) if a // 3 != b // 3 and rng.random() < 0.3])
    i, j = pairs.T
    rel = so3.exp(rng.normal(0, np.deg2rad(3), (len(pairs), 3))) @ R[j] @ np.swapaxes(R[i], 1, 2)
    g = ViewGraph.from_edges(i, j, rel, node_ids=np.arange(n))
    g.rigs = Rigs(np.arange(n) // 3, S[np.arange(n) % 3])
    opts = default_options(None)
    r = average_rotations(g, opts)
    rc, cert = certify_result(g, r, opts)
    assert cert["certified"] and cert["frame_level"]
    ref = rc.cam_from_world[(np.arange(n) // 3) * 3]  # each frame's reference image (identity cam_from_rig)
    cam_from_rig = rc.cam_from_world @ np.swapaxes(ref, 1, 2)
    assert np.degrees(so3.angle_between(cam_from_rig, S[np.arange(n) % 3])).max() < 1e-9
    assert compare_rotations(rc.cam_from_world, R).median <= 1.02 * compare_rotations(r.cam_from_world, R).median


def test_certify_reads_edges_out_with_unsolved_edges(tmp_path):
    """An --edges-out file lists the edges outside the solved component with residual nan."""
    r = run("synth", "-o", tmp_path, "--n", "30", "--degree", "6", "--sigma", "1", "--seed", "2")
    assert r.exit_code == 0
    with open(tmp_path / "edges.txt", "a") as fh:  # a second component: cameras 100 and 101
        fh.write("100 101 1 0 0 0\n")
    r = run("solve", tmp_path / "edges.txt", "-o", tmp_path / "r.csv", "--edges-out", tmp_path / "e.csv", "--certify")
    assert r.exit_code == 0, r.output
    assert "nan" in (tmp_path / "e.csv").read_text()
    r = run("certify", tmp_path / "r.csv", tmp_path / "edges.txt", "--inliers", tmp_path / "e.csv")
    assert r.exit_code == 0, r.output


def test_solve_certify_climbs_the_staircase_when_the_local_answer_is_not_global(tmp_path):
    """A pose graph (100 cameras, 20 degrees) where the default solve from the spanning tree
    alone (--init mst) ends at a critical point with a negative eigenvalue: `solve --certify`
    lifts, rounds and returns a lower-cost, certified answer, and says how (JSON key
    certificate.staircase). (From the default's two starts it ends at the global minimum.)"""
    from rotgraph.estimators.certify import certify, chordal_cost
    from rotgraph.io.writers import write_edges

    g = random_problem(n=100, degree=4, sigma_deg=20.0, graph="posegraph", seed=3)
    opts = default_options(None, init="mst")
    r = average_rotations(g, opts)
    rc, cert = certify_result(g, r, opts)
    assert cert["certified"] and cert["staircase"]["max_rank"] > 3
    stair = cert["staircase"]
    assert stair["start_certificate_lambda_min"] < -1e-4 and stair["cost"] < stair["start_cost"]
    assert stair["lower_bound"] == pytest.approx(stair["cost"], rel=1e-8)
    # the rotations returned are the certified ones, on the solve's inlier problem
    w = np.where(r.inliers, r.edge_weights, 1.0)
    again = certify(rc.cam_from_world, g.edges, g.cam2_from_cam1, w, inliers=r.inliers)
    assert again.certified
    inl = r.inliers
    assert (chordal_cost(rc.cam_from_world, g.edges[inl], g.cam2_from_cam1[inl], w[inl])
            < chordal_cost(r.cam_from_world, g.edges[inl], g.cam2_from_cam1[inl], w[inl]))
    # and through the command line
    write_edges(tmp_path / "e.txt", g)
    out = run("solve", tmp_path / "e.txt", "-o", tmp_path / "r.csv", "--certify", "--init", "mst", "--json")
    assert out.exit_code == 0, out.output
    assert json.loads(out.stdout)["certificate"]["staircase"]["max_rank"] > 3
    # the default's answer is already the certified global minimum: no climb
    auto = certify_result(g, average_rotations(g, default_options(None)), default_options(None))[1]
    assert auto["certified"] and "staircase" not in auto


def test_non_robust_methods_are_certified_on_every_edge(tmp_path):
    """Issue #31 item 1: --method chordal asks for the chordal cost over every edge. With heavy
    noise its 10-degree report flags most edges, and the certificate used to cover the
    remaining forest (cost ~0, 'certified') while the rotations written were not the
    optimum over all edges. Now every edge is certified, and the file written is that
    optimum: rotgraph certify on it (all edges) agrees to the last digit."""
    from rotgraph.io.writers import write_edges

    g = random_problem(n=200, degree=8, sigma_deg=15.0, outliers=0.0, graph="er", seed=4)
    edges = tmp_path / "e.txt"
    write_edges(edges, g)
    out = tmp_path / "r.csv"
    r = run("solve", edges, "-o", out, "--method", "chordal", "--certify", "--json", "-q")
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    cert = s["certificate"]
    assert s["n_outliers"] > 0.5 * g.n_edges  # the report's flags, by its 10-degree threshold
    assert cert["certified"] and cert["n_edges"] == g.n_edges
    assert cert["primal_cost"] > 1.0 and cert["dual_bound"] == pytest.approx(cert["primal_cost"], rel=1e-9)
    again = json.loads(run("certify", out, edges, "--json").stdout)
    assert again["certified"] and again["primal_cost"] == pytest.approx(cert["primal_cost"], rel=1e-9)
    # a robust method keeps certifying its inlier problem
    r = json.loads(run("solve", edges, "-o", tmp_path / "a.csv", "--certify", "--json", "-q").stdout)
    assert r["certificate"]["n_edges"] == g.n_edges - r["n_outliers"]


def test_certify_refine_reports_the_bound_before_and_after_and_writes_the_certified_rotations(tmp_path):
    """--refine: the ground truth of a noisy problem (not critical, not certified: its gap to
    the bound) taken to the nearest critical point and certified there; -o writes those
    rotations, which certify again as given; an existing file not rotgraph's is refused."""
    r = run("synth", "-o", tmp_path, "--n", "50", "--degree", "8", "--sigma", "5", "--seed", "4")
    assert r.exit_code == 0, r.output
    out = tmp_path / "certified.csv"
    r = run("certify", tmp_path / "gt.txt", tmp_path / "edges.txt", "--refine", "-o", out, "--json")
    assert r.exit_code == 0, r.output
    cert = json.loads(r.stdout)
    before = cert["before"]
    assert not before["certified"] and before["reason"].startswith("not critical") and cert["refine_iterations"] > 0
    assert cert["certified"] and cert["stationarity"] < 1e-6
    # the bound of the truth is a bound: the certified minimum lies between it and the truth's cost
    assert before["dual_bound"] <= cert["primal_cost"] + 1e-9 <= before["primal_cost"] + 1e-9
    again = run("certify", out, tmp_path / "edges.txt", "--json")
    assert again.exit_code == 0 and json.loads(again.stdout)["primal_cost"] == pytest.approx(cert["primal_cost"], rel=1e-9)
    mine = tmp_path / "mine.csv"
    mine.write_text("my notes\n")
    r = run("certify", tmp_path / "gt.txt", tmp_path / "edges.txt", "--refine", "-o", mine)
    assert r.exit_code != 0 and mine.read_text() == "my notes\n"


def test_solve_certify_says_no_certificate_applies_when_the_inliers_split_the_cameras(tmp_path):
    """Two clusters joined by two wrong edges only: the robust solve flags both, and its
    inlier edges leave two parts, each free to turn: no certificate of the chordal cost on
    them is a certificate of the problem solved (exit 1, the reason says why)."""
    from rotgraph import so3
    from rotgraph.io.writers import write_edges
    from rotgraph.viewgraph import ViewGraph

    a, b = random_problem(n=25, degree=8, sigma_deg=1.0, outliers=0.0, seed=1), random_problem(n=25, degree=8, sigma_deg=1.0, outliers=0.0, seed=2)
    edges = np.vstack([a.edges, b.edges + 25, [[0, 25], [1, 26]]])
    rel = np.concatenate([a.cam2_from_cam1, b.cam2_from_cam1, so3.random_rotations(2, np.random.default_rng(0))])
    write_edges(tmp_path / "split.txt", ViewGraph.from_edges(edges[:, 0], edges[:, 1], rel, node_ids=np.arange(50)))
    r = run("solve", tmp_path / "split.txt", "-o", tmp_path / "r.csv", "--certify", "--json")
    assert r.exit_code == 1
    out = json.loads(r.stdout)
    cert = out["certificate"]
    assert out["n_outliers"] == 2 and cert["certified"] is False and cert["applicable"] is False
    assert cert["reason"].startswith("no certificate applies") and "2 components" in cert["reason"]
    # with the clusters joined by three true edges as well, a certificate applies (and says of which cost); each
    # cluster's own gauge is its ground truth's, so R_j R_i^T of the two ground truths is a consistent link
    links = np.array([[2, 27], [3, 28], [4, 29]])
    true = np.stack([b.gt_cam_from_world[j - 25] @ a.gt_cam_from_world[i].T for i, j in links])
    joined = np.vstack([edges, links])
    write_edges(tmp_path / "joined.txt", ViewGraph.from_edges(joined[:, 0], joined[:, 1], np.concatenate([rel, true]),
                                                              node_ids=np.arange(50)))
    r = run("solve", tmp_path / "joined.txt", "-o", tmp_path / "r2.csv", "--certify", "--json")
    cert = json.loads(r.stdout)["certificate"]
    assert "applicable" not in cert and cert["cost"].endswith("on the inlier edges")


def test_certify_gap_tol_certifies_what_is_proven_close_enough(tmp_path):
    """The ground truth of a mildly noisy problem fails the eigenvalue test; its proven gap to
    the global minimum is a few percent: --gap-tol above it certifies it (and says how),
    below it does not; --tolerance moves the eigenvalue test."""
    r = run("synth", "-o", tmp_path, "--n", "40", "--degree", "8", "--sigma", "1", "--seed", "5")
    assert r.exit_code == 0, r.output
    plain = json.loads(run("certify", tmp_path / "gt.txt", tmp_path / "edges.txt", "--json").stdout)
    assert not plain["certified"] and plain["gap_tolerance"] is None
    rel = plain["relative_gap"]
    r = run("certify", tmp_path / "gt.txt", tmp_path / "edges.txt", "--json", "--gap-tol", str(2 * rel))
    cert = json.loads(r.stdout)
    assert r.exit_code == 0 and cert["certified"] and "gap tolerance" in cert["reason"] and cert["gap_tolerance"] == 2 * rel
    r = run("certify", tmp_path / "gt.txt", tmp_path / "edges.txt", "--json", "--gap-tol", str(rel / 2))
    assert r.exit_code == 1 and not json.loads(r.stdout)["certified"]
    r = run("certify", tmp_path / "gt.txt", tmp_path / "edges.txt", "--json", "--tolerance", str(2 * -plain["lambda_min"]))
    assert r.exit_code == 0 and json.loads(r.stdout)["certified"]
