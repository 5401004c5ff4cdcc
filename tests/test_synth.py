"""The synthetic problem generators (rotgraph.synth.random_problem) and ``rotgraph synth``:
deterministic per seed, and the degree, noise and outlier statistics they state."""

from __future__ import annotations

import json

import numpy as np
import pytest

from cli_helpers import run
from rotgraph import so3
from rotgraph.estimators.stats import MAXWELL_MEDIAN
from rotgraph.pipeline.read import read_view_graph
from rotgraph.synth import FLIP_AXIS, random_problem

MEDIAN_ANGLE_PER_SIGMA = MAXWELL_MEDIAN  # median of |e| for e ~ N(0, I_3)


def true_relative(g):
    R = g.gt_cam_from_world
    return R[g.edges[:, 1]] @ np.swapaxes(R[g.edges[:, 0]], 1, 2)


def residual_deg(g):
    """angle(R_ij measured, R_j R_i^T) per edge, degrees."""
    return np.degrees(so3.angle_between(g.cam2_from_cam1, true_relative(g)))


def arrays(g):
    return (g.edges, g.cam2_from_cam1, g.gt_cam_from_world, g.meta["outlier"], g.meta["edge_sigma_deg"])


CASES = [
    dict(graph="er", n=200, degree=12, sigma_deg=2.0, outliers=0.2),
    dict(graph="traj", n=150, degree=8, sigma_deg=1.0, outliers=0.1),
    dict(graph="posegraph", n=300, degree=4, sigma_deg=1.5, outliers=0.05),
    dict(graph="er", n=200, degree=12, sigma_deg=1.0, outliers=0.4, outlier_model="flip"),
    dict(graph="er", n=200, degree=12, sigma_deg=0.5, noise_mix=(0.5, 5.0)),
    dict(graph="posegraph", n=300, degree=6, sigma_deg=1.0, outliers=0.3, outlier_model="flip", flip_group=0.1),
]


@pytest.mark.parametrize("case", CASES, ids=lambda c: "-".join(str(v) for v in c.values()))
def test_deterministic_per_seed(case):
    a, b, c = (random_problem(**case, seed=s) for s in (7, 7, 8))
    for x, y in zip(arrays(a), arrays(b)):
        np.testing.assert_array_equal(x, y)
    assert not np.array_equal(a.cam2_from_cam1[: min(a.n_edges, c.n_edges)], c.cam2_from_cam1[: min(a.n_edges, c.n_edges)])
    assert a.components().max() == 0  # connected
    assert np.allclose(np.linalg.det(a.cam2_from_cam1), 1.0)


@pytest.mark.parametrize("degree,sigma", [(10, 1.0), (25, 2.0), (40, 3.0)])
def test_er_degree_noise_outliers(degree, sigma):
    g = random_problem(n=400, degree=degree, sigma_deg=sigma, outliers=0.3, graph="er", seed=1)
    assert g.n_edges == round(400 * degree / 2)
    assert g.degrees().mean() == pytest.approx(degree, rel=0.01)
    out = g.meta["outlier"]
    assert abs(out.mean() - 0.3) < 4 * np.sqrt(0.3 * 0.7 / g.n_edges)
    r = residual_deg(g)
    assert np.median(r[~out]) == pytest.approx(MEDIAN_ANGLE_PER_SIGMA * sigma, rel=0.2)
    assert np.median(r[out]) > 60  # Haar-random: median angle ~ 126 deg


def test_noise_free_and_heavy_outliers():
    g = random_problem(n=100, degree=10, sigma_deg=0.0, outliers=0.0, graph="er", seed=2)
    assert residual_deg(g).max() < 1e-6
    g = random_problem(n=500, degree=30, sigma_deg=2.0, outliers=0.5, graph="er", seed=3)
    assert abs(g.meta["outlier"].mean() - 0.5) < 0.03


@pytest.mark.parametrize("degree", [3, 4, 5, 6])
def test_posegraph(degree):
    n = 600
    g = random_problem(n=n, degree=degree, sigma_deg=1.5, outliers=0.05, graph="posegraph", seed=degree)
    assert g.components().max() == 0
    assert g.n_edges == round(n * degree / 2)
    assert 3 <= g.degrees().mean() <= 6
    loop = g.meta["loop_closure"]
    i, j = g.edges[:, 0], g.edges[:, 1]
    k = max(1, (degree - 1) // 2)
    # odometry: every (i, i + d), d = 1..k, in time order; loop closures far apart in time
    odo = np.stack([i[~loop], j[~loop]], 1)
    assert len(odo) == sum(n - d for d in range(1, k + 1)) and (j[~loop] - i[~loop] <= k).all()
    assert {(a, a + 1) for a in range(n - 1)} <= set(map(tuple, odo.tolist()))
    assert (np.abs(j[loop] - i[loop]) > 2 * k + 2).all() and loop.sum() >= n // 2 - 1
    # loop closures join nearby poses: their true relative rotation is small
    assert np.median(np.degrees(so3.angle(true_relative(g)[loop]))) < 20
    # outliers: exactly round(0.05 E), all on loop closures
    out = g.meta["outlier"]
    assert out.sum() == round(0.05 * g.n_edges) and not (out & ~loop).any()
    r = residual_deg(g)
    assert np.median(r[~out]) == pytest.approx(MEDIAN_ANGLE_PER_SIGMA * 1.5, rel=0.2)
    clean = random_problem(n=n, degree=degree, sigma_deg=1.5, outliers=0.0, graph="posegraph", seed=degree)
    assert not clean.meta["outlier"].any()
    np.testing.assert_array_equal(clean.edges, g.edges)


def test_flip_is_a_consistent_180_degree_hypothesis():
    g = random_problem(n=300, degree=20, sigma_deg=0.0, outliers=0.4, graph="er", seed=4, outlier_model="flip", flip_group=0.2)
    group = g.meta["flipped_cameras"]
    assert len(group) == 60 and len(np.unique(group)) == 60
    out = g.meta["outlier"]
    r = residual_deg(g)
    np.testing.assert_allclose(r[out], 180.0, atol=1e-6)  # exactly 180 deg off the truth
    assert r[~out].max() < 1e-6
    in_group = np.zeros(g.n_nodes, bool)
    in_group[group] = True
    touches = in_group[g.edges[:, 0]] | in_group[g.edges[:, 1]]
    assert not (out & ~touches).any()
    assert abs(out[touches].mean() - 0.4) < 4 * np.sqrt(0.24 / touches.sum())
    # the wrong edges agree with each other: R_j F R_i^T, the camera turned about the world y axis
    R, F = g.gt_cam_from_world, so3.exp(np.pi * FLIP_AXIS)
    i, j = g.edges[out, 0], g.edges[out, 1]
    hyp = R[j] @ F @ np.swapaxes(R[i], 1, 2)
    assert np.degrees(so3.angle_between(g.cam2_from_cam1[out], hyp)).max() < 1e-6
    # with noise: the flipped edges carry the same noise as the others, around the hypothesis
    g = random_problem(n=300, degree=20, sigma_deg=2.0, outliers=0.4, graph="er", seed=4, outlier_model="flip")
    out = g.meta["outlier"]
    R = g.gt_cam_from_world
    i, j = g.edges[out, 0], g.edges[out, 1]
    around = np.degrees(so3.angle_between(g.cam2_from_cam1[out], R[j] @ F @ np.swapaxes(R[i], 1, 2)))
    assert np.median(around) == pytest.approx(MEDIAN_ANGLE_PER_SIGMA * 2.0, rel=0.2)
    assert np.median(residual_deg(g)[~out]) == pytest.approx(MEDIAN_ANGLE_PER_SIGMA * 2.0, rel=0.2)


def test_noise_mix():
    g = random_problem(n=400, degree=20, sigma_deg=0.5, outliers=0.0, graph="er", seed=5, noise_mix="0.5:5")
    s = g.meta["edge_sigma_deg"]
    assert (s == 5.0).sum() == round(0.5 * g.n_edges) and set(np.unique(s)) == {0.5, 5.0}
    r = residual_deg(g)
    for sigma in (0.5, 5.0):
        assert np.median(r[s == sigma]) == pytest.approx(MEDIAN_ANGLE_PER_SIGMA * sigma, rel=0.2)
    np.testing.assert_array_equal(g.weights, 1.0)  # no weights given: the solver must cope
    g2 = random_problem(n=400, degree=20, sigma_deg=0.5, outliers=0.0, graph="er", seed=5, noise_mix=(0.5, 5.0))
    np.testing.assert_array_equal(g.cam2_from_cam1, g2.cam2_from_cam1)


def test_new_options_leave_the_old_problems_alone():
    """The new draws come after the old ones: the er / traj problems of a seed are unchanged
    by the defaults, and a noise mix changes only the noise."""
    a = random_problem(n=200, degree=10, sigma_deg=2.0, outliers=0.2, graph="er", seed=6)
    b = random_problem(n=200, degree=10, sigma_deg=2.0, outliers=0.2, graph="er", seed=6, noise_mix=(0.0, 5.0))
    np.testing.assert_array_equal(a.cam2_from_cam1, b.cam2_from_cam1)
    c = random_problem(n=200, degree=10, sigma_deg=2.0, outliers=0.2, graph="er", seed=6, noise_mix=(0.3, 5.0))
    np.testing.assert_array_equal(a.meta["outlier"], c.meta["outlier"])
    np.testing.assert_array_equal(a.cam2_from_cam1[a.meta["outlier"]], c.cam2_from_cam1[c.meta["outlier"]])


@pytest.mark.parametrize("kwargs", [dict(graph="tree"), dict(outlier_model="gross"), dict(noise_mix="0.5"),
                                    dict(noise_mix=(1.5, 2.0)), dict(outliers=1.5), dict(sigma_deg=-1.0)])
def test_bad_arguments(kwargs):
    with pytest.raises(ValueError):
        random_problem(n=20, degree=4, **kwargs)


@pytest.mark.parametrize("args,kwargs", [
    (["--graph", "posegraph", "--n", 200, "--degree", 4, "--sigma", 1.5, "--outliers", 0.05],
     dict(graph="posegraph", n=200, degree=4, sigma_deg=1.5, outliers=0.05)),
    (["--outlier-model", "flip", "--flip-group", 0.25, "--outliers", 0.4, "--sigma", 1, "--n", 80],
     dict(n=80, degree=10, sigma_deg=1.0, outliers=0.4, outlier_model="flip", flip_group=0.25)),
    (["--sigma", 0.5, "--noise-mix", "0.5:5", "--n", 60, "--degree", 12],
     dict(n=60, degree=12, sigma_deg=0.5, noise_mix=(0.5, 5.0))),
])
def test_cli_synth_writes_the_generators_problem(tmp_path, args, kwargs):
    r = run("synth", "-o", tmp_path, "--seed", 3, *args)
    assert r.exit_code == 0, r.output
    g = random_problem(**kwargs, seed=3)
    read = read_view_graph(tmp_path / "edges.txt")
    np.testing.assert_array_equal(read.node_ids[read.edges], g.node_ids[g.edges])
    assert np.degrees(so3.angle_between(read.cam2_from_cam1, g.cam2_from_cam1)).max() < 1e-5
    np.testing.assert_array_equal(read.weights, 1.0)
    meta = json.loads((tmp_path / "meta.json").read_text())
    assert meta["outlier_edges"] == np.flatnonzero(g.meta["outlier"]).tolist()
    assert meta["n_outlier_edges"] == int(g.meta["outlier"].sum()) and meta["n_edges"] == g.n_edges
    assert meta["graph"] == kwargs.get("graph", "er")
    assert meta["outlier_model"] == kwargs.get("outlier_model", "uniform")
    if "flip_group" in kwargs:
        assert meta["flipped_cameras"] == g.meta["flipped_cameras"].tolist()
    if kwargs.get("graph") == "posegraph":
        assert meta["n_loop_closures"] == int(g.meta["loop_closure"].sum())
    gt = np.loadtxt(tmp_path / "gt.txt", comments="#")
    assert gt.shape[0] == g.n_nodes


def test_cli_synth_bad_noise_mix(tmp_path):
    for bad in ("0.5", "x:1", "1.5:2"):
        r = run("synth", "-o", tmp_path, "--noise-mix", bad)
        assert r.exit_code == 2 and "--noise-mix" in r.output
        assert not (tmp_path / "edges.txt").exists()


def test_cli_synth_help_documents_the_generators():
    r = run("synth", "--help")
    for word in ("posegraph", "--outlier-model", "flip", "--noise-mix", "--flip-group", "Example"):
        assert word in r.stdout
