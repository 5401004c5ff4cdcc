"""Linear chordal averaging on dense graphs: the block-sparse (BSR) path and the chordal
start on a subset of the edges (rotgraph.estimators.linear)."""

import numpy as np
import pytest

from rotgraph import so3
from rotgraph.estimators import linear
from rotgraph.synth import random_problem


def _problem(n=400, degree=60.0, sigma=2.0, outliers=0.0, seed=0):
    g = random_problem(n=n, degree=degree, sigma_deg=sigma, outliers=outliers, seed=seed)
    qrel = so3.quaternion_rows_from_matrices(g.cam2_from_cam1)
    w = np.random.default_rng(seed).uniform(0.5, 2.0, g.n_edges)
    return g, g.edges, qrel, w


def _angles_deg(qa, qb):
    return np.degrees(2.0 * np.arccos(np.minimum(np.abs(np.einsum("kn,kn->n", qa, qb)), 1.0)))


def test_bsr_path_is_the_chordal_least_squares_solution():
    """The BSR + PCG path (dense graphs) and the generic sparse LU path solve one problem."""
    g, edges, qrel, w = _problem(n=320, degree=40.0)
    edges = np.concatenate([edges, edges[:25]])  # parallel edges: repeated blocks of a row
    qrel = np.concatenate([qrel, so3.quaternion_rows_from_matrices(so3.perturb(g.cam2_from_cam1[:25], 0.03, rng=1))], axis=1)
    w = np.concatenate([w, w[:25]])
    anchor = 17
    assert 2.0 * len(edges) / g.n_nodes >= linear.CHORDAL_BSR_MIN_DEGREE
    q_bsr = linear.solve_chordal(g.n_nodes, edges, qrel, w, anchor, "auto")
    q_lu = linear.solve_chordal(g.n_nodes, edges, qrel, w, anchor, "direct")
    # PCG at CHORDAL_RTOL: the same projected rotations to well under a thousandth of a degree
    assert _angles_deg(q_bsr, q_lu).max() < 1e-3
    assert _angles_deg(q_bsr[:, [anchor]], np.array([[1.0], [0], [0], [0]]))[0] < 1e-12


@pytest.fixture(autouse=True)
def _subsets_of_small_graphs_too(monkeypatch):
    """The tests' graphs are small: let the start take a subset of them all the same."""
    monkeypatch.setattr(linear, "START_MIN_EDGES", 0)


def test_start_edges_keeps_about_the_degree_connected_and_unbiased():
    g, edges, qrel, w = _problem(n=600, degree=120.0)
    n = g.n_nodes
    assert linear.start_edges(n, edges, w, degree=100.0) is None  # not dense enough: all edges
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(linear, "START_MIN_EDGES", len(edges) + 1)
        assert linear.start_edges(n, edges, w, degree=30.0) is None  # too small to be worth it
    keep, wk = linear.start_edges(n, edges, w, degree=30.0, seed=3)
    assert len(np.unique(keep)) == len(keep)
    deg = np.bincount(edges[keep].ravel(), minlength=n)
    assert 27.0 < deg.mean() < 33.0 and deg.min() > 10
    # Horvitz-Thompson weights: the expected weighted degree of every camera is its full one;
    # averaged over the cameras the subset's is within a few per cent.
    full = np.bincount(edges.ravel(), weights=np.repeat(w, 2), minlength=n)
    sub = np.bincount(edges[keep].ravel(), weights=np.repeat(wk, 2), minlength=n)
    assert sub.sum() / full.sum() == pytest.approx(1.0, rel=0.03)
    # deterministic for a seed
    np.testing.assert_array_equal(linear.start_edges(n, edges, w, degree=30.0, seed=3)[0], keep)


def test_start_edges_keeps_every_edge_of_thin_cameras():
    """A camera of low degree hung on a dense core keeps all its edges (p = 1)."""
    g, edges, qrel, w = _problem(n=500, degree=100.0)
    n = g.n_nodes
    thin = np.array([[n, 3], [n, 40], [n + 1, 7]])  # two new cameras, degrees 2 and 1
    edges2 = np.concatenate([edges, thin])
    w2 = np.concatenate([w, np.ones(3)])
    keep, _ = linear.start_edges(n + 2, edges2, w2, degree=32.0)
    assert set(range(len(edges), len(edges) + 3)) <= set(keep.tolist())


@pytest.mark.parametrize("outliers", [0.0, 0.1])
def test_chordal_start_is_as_good_a_start(outliers, monkeypatch):
    """On a dense graph the start from a third of the edges is about as close to the truth as
    the full chordal solution (its noise grows as 1/sqrt(degree); the outliers' share is the
    same), and the adaptive solve from it ends where it ends from the full one."""
    import rotgraph

    g, edges, qrel, w = _problem(n=500, degree=100.0, sigma=2.0, outliers=outliers, seed=2)
    n, anchor = g.n_nodes, 0
    full = linear.solve_chordal(n, edges, qrel, w, anchor)
    start = linear.chordal_start(n, edges, qrel, w, anchor)
    gt = so3.quaternion_rows_from_matrices(g.gt_cam_from_world @ g.gt_cam_from_world[anchor].T)
    err_full, err_start = np.median(_angles_deg(full, gt)), np.median(_angles_deg(start, gt))
    assert err_start < 2.5 * err_full
    R_sub = rotgraph.average_rotations(g).cam_from_world
    monkeypatch.setattr(linear, "START_DEGREE", 1e9)  # the start from every edge
    R_all = rotgraph.average_rotations(g).cam_from_world
    assert so3.angle(np.swapaxes(R_sub, 1, 2) @ R_all).max() < np.radians(1e-3)


def test_single_precision_errors_of_huge_graphs_match_double(monkeypatch):
    """From FLOAT32_MIN_EDGES edges on, the error products run in single precision: the
    same residuals to ~1e-7 rad, exact zeros stay zeros (noise-free edges), and the solve
    ends where the double-precision one does (within its step tolerance)."""
    import rotgraph
    from rotgraph.estimators import residuals

    g = random_problem(n=300, degree=40.0, sigma_deg=2.0, outliers=0.1, seed=5)
    qrel = so3.quaternion_rows_from_matrices(g.cam2_from_cam1)
    qrel[:, 0] = so3.quaternion_rows_from_matrices(g.gt_cam_from_world[[g.edges[0, 1]]] @ g.gt_cam_from_world[g.edges[0, 0]].T)[:, 0]
    q = so3.quaternion_rows_from_matrices(g.gt_cam_from_world)
    monkeypatch.setattr(residuals, "ERRORS_CHUNK", 1000)  # the chunked path, several chunks
    double = residuals.EdgeSystem(g.n_nodes, g.edges, qrel, 0)
    monkeypatch.setattr(residuals, "FLOAT32_MIN_EDGES", 0)
    single = residuals.EdgeSystem(g.n_nodes, g.edges, qrel, 0)
    assert double.single is None and single.single is not None
    (v64, f64, t64), (v32, f32, t32) = double.errors(q), single.errors(q)
    assert v32.dtype == t32.dtype == np.float64
    small = 2 * t64 < np.radians(30)  # inliers; near 180 deg asin(|v|) is ill-conditioned in single precision
    assert small.mean() > 0.8
    assert np.abs(2 * t32 - 2 * t64)[small].max() < 1e-6 and np.abs(v32 * f32 - v64 * f64)[:, small].max() < 1e-6
    assert np.abs(2 * t32 - 2 * t64).max() < 1e-3
    assert np.isfinite(f32).all() and np.abs(2 * t32[0]) < 1e-6  # the exact edge
    R32 = rotgraph.average_rotations(g).cam_from_world
    monkeypatch.setattr(residuals, "FLOAT32_MIN_EDGES", 10**12)
    R64 = rotgraph.average_rotations(g).cam_from_world
    assert np.degrees(so3.angle(np.swapaxes(R32, 1, 2) @ R64)).max() < 2e-3


def test_dense_and_sparse_lu_linear_starts_agree(monkeypatch):
    """A wide graph's linear starts up to DENSE_LINEAR_MAX unknowns are solved densely: the
    same chordal and quaternion solutions as the sparse LU; a trajectory keeps the LU."""
    g, edges, qrel, w = _problem(n=150, degree=12.0)
    assert linear._wide(g.n_nodes, edges) and 3 * g.n_nodes <= linear.DENSE_LINEAR_MAX
    traj = random_problem(n=150, degree=6.0, graph="traj", seed=1)
    assert not linear._wide(traj.n_nodes, traj.edges)
    q_ref = linear.solve_chordal(g.n_nodes, edges, qrel, w, 3, "direct")
    dense = (linear.solve_chordal(g.n_nodes, edges, qrel, w, 3, "direct"),
             linear.solve_quaternion(g.n_nodes, edges, qrel, w, 3, q_ref, "direct"))
    monkeypatch.setattr(linear, "DENSE_LINEAR_MAX", 0)
    lu = (linear.solve_chordal(g.n_nodes, edges, qrel, w, 3, "direct"),
          linear.solve_quaternion(g.n_nodes, edges, qrel, w, 3, q_ref, "direct"))
    for a, b in zip(dense, lu):
        sign = np.where(np.einsum("kn,kn->n", a, b) < 0, -1.0, 1.0)
        assert np.abs(a - sign * b).max() < 1e-12


@pytest.mark.parametrize("graph", ["er", "traj"])
def test_small_linear_systems_solved_dense_agree_with_the_sparse_path(graph, monkeypatch):
    """Up to DENSE_DIRECT_MAX unknowns the chordal and quaternion systems are built and solved
    dense whatever the graph (a wide random graph, a thin trajectory), wide graphs up to
    DENSE_LINEAR_MAX; the sparse path, forced by zero thresholds, gives the same rotations."""
    g = random_problem(n=60, degree=6, sigma_deg=2.0, outliers=0.0, graph=graph, seed=2)
    qrel = so3.quaternion_rows_from_matrices(g.cam2_from_cam1)
    w = np.random.default_rng(1).uniform(0.5, 2.0, g.n_edges)
    dense = linear.solve_chordal(g.n_nodes, g.edges, qrel, w, 3)
    q_ref = dense.copy()
    dense_q = linear.solve_quaternion(g.n_nodes, g.edges, qrel, w, 3, q_ref)
    monkeypatch.setattr(linear, "DENSE_DIRECT_MAX", 0)
    monkeypatch.setattr(linear, "DENSE_LINEAR_MAX", 0)  # wide graphs too
    sparse = linear.solve_chordal(g.n_nodes, g.edges, qrel, w, 3)
    sparse_q = linear.solve_quaternion(g.n_nodes, g.edges, qrel, w, 3, q_ref)
    np.testing.assert_allclose(np.abs((dense * sparse).sum(axis=0)), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.abs((dense_q * sparse_q).sum(axis=0)), 1.0, atol=1e-12)
