"""Multiple rotation averaging: recovery, invariances and the edges of the domain."""

from types import SimpleNamespace

import numpy as np
import pytest

from rotgraph import so3, so3_rows
from rotgraph.errors import UnsolvableError
from rotgraph.evaluate import compare_rotations
from rotgraph.estimators.residuals import edge_errors
from rotgraph.estimators.rotation_averaging import METHODS, SolveOptions, average_rotations
from rotgraph.estimators.spanning_tree import spanning_tree_rotations
from rotgraph.synth import random_problem
from rotgraph.viewgraph import ViewGraph


def err_deg(res, graph):
    return compare_rotations(res.cam_from_world, graph.gt_cam_from_world)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("graph", ["er", "traj"])
def test_noise_free_recovery_to_1e6_deg(method, graph):
    g = random_problem(n=60, degree=8, sigma_deg=0.0, outliers=0.0, graph=graph, seed=3)
    for init in ("mst", "chordal"):
        res = average_rotations(g, method=method, init=init)
        ev = err_deg(res, g)
        assert ev.max < 1e-6, (method, init, ev.max)
        assert res.solved.all()
        assert np.nanmax(res.residuals_deg) < 1e-6
        assert res.n_outliers == 0


@pytest.mark.parametrize("method", ["irls", "l1", "nodewise"])
def test_recovers_ground_truth_under_noise_and_outliers(method):
    g = random_problem(n=150, degree=16, sigma_deg=2.0, outliers=0.2, seed=11)
    res = average_rotations(g, method=method)
    ev = err_deg(res, g)
    assert ev.median < 1.5, ev.median
    assert ev.max < (10.0 if method == "nodewise" else 6.0)  # node-wise converges slowly
    # The outlier edges of the generator are flagged, the inliers kept.
    truth = g.meta["outlier"]
    assert (~res.inliers[truth]).mean() > 0.95
    assert res.inliers[~truth].mean() > 0.97


def test_l2_methods_are_not_robust_but_irls_is():
    g = random_problem(n=150, degree=16, sigma_deg=1.0, outliers=0.3, seed=5)
    robust = err_deg(average_rotations(g, method="irls"), g).median
    l2 = err_deg(average_rotations(g, method="l2"), g).median
    assert robust < 1.0 < l2


def test_l2_matches_linearisation_optimum_small_noise():
    """With small noise, Govindu's L2 solution makes the gradient of the cost vanish: the
    exact L2 cost cannot be lowered by Levenberg-Marquardt refinement."""
    g = random_problem(n=40, degree=8, sigma_deg=1.0, seed=2)
    a = average_rotations(g, method="l2")
    b = average_rotations(g, method="l2", refine=True)
    assert b.cost <= a.cost * (1 + 1e-9)
    assert a.cost <= b.cost * (1 + 1e-6)


def test_refine_reaches_local_optimum_of_robust_cost():
    g = random_problem(n=50, degree=8, sigma_deg=2.0, outliers=0.1, seed=4)
    res = average_rotations(g, method="irls", refine=True, rescale=False)  # the GM cost below
    # Perturbing any camera in any direction does not lower the exact robust cost.
    from rotgraph.losses import loss_rho

    q = so3.quaternion_rows_from_matrices(res.cam_from_world)
    qrel = so3.quaternion_rows_from_matrices(g.cam2_from_cam1)
    scale = np.deg2rad(5.0)

    def cost(qq):
        _, th = edge_errors(qq, g.edges, qrel)
        return float(np.sum(loss_rho("geman_mcclure", th, scale)))

    base = cost(q)
    assert base == pytest.approx(res.cost, rel=1e-9)
    rng = np.random.default_rng(0)
    for _ in range(20):
        k = rng.integers(g.n_nodes)
        d = np.zeros((3, g.n_nodes))
        d[:, k] = rng.standard_normal(3) * 1e-4
        assert cost(so3.qmul_rows(q, so3.qexp_rows(d))) >= base - 1e-12


def test_gauge_and_permutation_invariance():
    g = random_problem(n=80, degree=10, sigma_deg=2.0, outliers=0.1, seed=8)
    # Ties in the spanning tree follow the labels, so the start differs: converge tightly.
    tight = dict(step_tol_deg=1e-10, rescale=False, max_iterations=500)
    base = average_rotations(g, **tight)
    # Relabel the cameras: the solution follows the labels.
    perm = np.random.default_rng(1).permutation(g.n_nodes)
    inv = np.argsort(perm)
    g2 = ViewGraph.from_edges(inv[g.edges[:, 0]], inv[g.edges[:, 1]], g.cam2_from_cam1, node_ids=np.arange(g.n_nodes))
    res2 = average_rotations(g2, **tight)
    ev = compare_rotations(res2.cam_from_world[inv], base.cam_from_world)
    assert ev.max < 1e-6
    # Reverse the direction of half the edges (R_ij -> R_ji = R_ij^T): same solution.
    flip = np.random.default_rng(2).random(g.n_edges) < 0.5
    e = np.where(flip[:, None], g.edges[:, ::-1], g.edges)
    rel = np.where(flip[:, None, None], np.swapaxes(g.cam2_from_cam1, 1, 2), g.cam2_from_cam1)
    g3 = ViewGraph.from_edges(e[:, 0], e[:, 1], rel, node_ids=np.arange(g.n_nodes))
    assert compare_rotations(average_rotations(g3, **tight).cam_from_world, base.cam_from_world).max < 1e-6


def test_world_frame_change_is_a_gauge():
    """R_i -> R_i W^T leaves every R_ij unchanged: the error against the rotated ground
    truth is the same."""
    g = random_problem(n=60, degree=10, sigma_deg=1.0, seed=9)
    res = average_rotations(g)
    W = so3.random_rotations(None, 3)
    a = compare_rotations(res.cam_from_world, g.gt_cam_from_world).median
    b = compare_rotations(res.cam_from_world, g.gt_cam_from_world @ W.T).median
    assert a == pytest.approx(b, abs=1e-9)


def test_two_cameras_one_edge():
    R = so3.random_rotations(2, 0)
    g = ViewGraph.from_edges([0], [1], (R[1] @ R[0].T)[None])
    for method in METHODS:
        res = average_rotations(g, method=method)
        assert res.solved.all()
        rel = res.cam_from_world[1] @ res.cam_from_world[0].T
        assert np.degrees(so3.angle_between(rel, R[1] @ R[0].T)) < 1e-9


def test_tree_is_solved_exactly_even_with_noise():
    """A tree has no cycles: any noise is absorbed, every residual is zero."""
    n = 30
    rng = np.random.default_rng(0)
    parent = np.array([rng.integers(k) for k in range(1, n)])
    rel = so3.random_rotations(n - 1, rng)
    g = ViewGraph.from_edges(parent, np.arange(1, n), rel)
    for method in METHODS:
        res = average_rotations(g, method=method)
        assert np.nanmax(res.residuals_deg) < 1e-7, method


def test_disconnected_graph_solves_largest_component():
    a = random_problem(n=40, degree=6, sigma_deg=0.0, seed=1)
    b = random_problem(n=10, degree=4, sigma_deg=0.0, seed=2)
    e = np.concatenate([a.edges, b.edges + 40])
    g = ViewGraph.from_edges(e[:, 0], e[:, 1], np.concatenate([a.cam2_from_cam1, b.cam2_from_cam1]), node_ids=np.arange(50))
    res = average_rotations(g)
    assert res.n_components == 2
    assert res.solved[:40].all() and not res.solved[40:].any()
    assert np.isnan(res.cam_from_world[40:]).all()
    assert np.isnan(res.residuals_deg[a.n_edges:]).all()
    assert compare_rotations(res.cam_from_world[:40], a.gt_cam_from_world).max < 1e-6


def test_equal_components_the_one_with_the_lowest_camera_wins():
    """Documented tie rule (README FAQ): equal sizes -> the component of the lowest index."""
    rel = so3.random_rotations(4, 3)
    g = ViewGraph.from_edges(np.array([4, 5, 0, 1]), np.array([5, 6, 1, 2]), rel, node_ids=np.arange(7))
    res = average_rotations(g)
    assert res.n_components == 3  # {0,1,2}, {3}, {4,5,6}
    assert res.solved.tolist() == [True, True, True, False, False, False, False]


def test_node_whose_edges_are_all_outliers():
    """A camera all of whose edges are wrong is placed somewhere (it cannot be known), the
    rest are unaffected, and its edges are flagged."""
    g = random_problem(n=60, degree=10, sigma_deg=1.0, seed=6)
    bad = np.flatnonzero((g.edges == 7).any(axis=1))
    rel = g.cam2_from_cam1.copy()
    rel[bad] = so3.random_rotations(len(bad), 1)
    g2 = ViewGraph.from_edges(g.edges[:, 0], g.edges[:, 1], rel, node_ids=np.arange(60))
    res = average_rotations(g2)
    keep = np.arange(60) != 7
    ev = compare_rotations(res.cam_from_world[keep], g.gt_cam_from_world[keep])
    assert ev.median < 1.0
    assert (~res.inliers[bad]).sum() >= len(bad) - 1


def test_camera_whose_edges_all_disagree_is_left_out():
    """Camera 9 hangs on two edges 120 deg apart. The L2 solution splits the difference, so
    both residuals exceed the threshold: camera 9 is reported unsolved (CLI contract) and its
    edges count as outliers. A robust solve follows one edge and keeps the camera."""
    g = random_problem(n=40, degree=10, sigma_deg=0.5, seed=4)
    keep = ~(g.edges == 9).any(axis=1)
    R = g.gt_cam_from_world
    e = np.concatenate([g.edges[keep], [[0, 9], [1, 9]]])
    twist = so3.exp(np.array([[0.0, 0.0, np.deg2rad(120.0)]]))[0]
    rel = np.concatenate([g.cam2_from_cam1[keep], [R[9] @ R[0].T, twist @ R[9] @ R[1].T]])
    h = ViewGraph.from_edges(e[:, 0], e[:, 1], rel, node_ids=np.arange(40))
    # l2 rejects nothing (#16): camera 9 stays, its two edges are flagged as outliers.
    res = average_rotations(h, method="l2")
    assert res.solved.all() and res.n_rejected == 0
    assert not res.inliers[-2:].any() and np.isfinite(res.residuals_deg[-2:]).all()
    assert res.n_outliers >= 2
    robust = average_rotations(h, method="irls")
    assert robust.solved.all() and robust.inliers[-2:].sum() == 1


def test_every_camera_left_out_is_unsolvable():
    """Two parallel edges 60 deg apart under a robust method whose loss is L2-like at this
    size (irls, scale 100 deg): both residuals are 30 deg, so no camera has an inlier edge
    -- an UnsolvableError (exit 1), not an empty result. (l2 itself rejects nothing: #16.)"""
    twist = so3.exp(np.array([[0.0, 0.0, np.deg2rad(60.0)]]))[0]
    g = ViewGraph.from_edges(np.array([0, 0]), np.array([1, 1]), np.stack([np.eye(3), twist]), node_ids=np.arange(2), duplicates="keep")
    with pytest.raises(UnsolvableError, match="every edge is an outlier"):
        average_rotations(g, method="irls", loss_scale_deg=100.0, rescale=False)
    assert average_rotations(g, method="l2").solved.all()


def test_empty_graph_is_unsolvable():
    g = ViewGraph.from_edges(np.zeros(0, int), np.zeros(0, int), np.zeros((0, 3, 3)), node_ids=np.arange(3))
    with pytest.raises(UnsolvableError):
        average_rotations(g)


@pytest.mark.parametrize("equal_weights", [False, True])
@pytest.mark.parametrize("n", [2, 10, 40, 64])
def test_kruskal_finds_the_same_tree_as_the_sparse_path(n, equal_weights, monkeypatch):
    import rotgraph.estimators.spanning_tree as M

    g = random_problem(n=n, degree=min(8, n - 1), sigma_deg=1.0, seed=n)
    q = so3.quaternion_rows_from_matrices(g.cam2_from_cam1)
    w = np.random.default_rng(n).integers(1, 5, g.n_edges).astype(float)  # ties broken by edge order
    # parallel edges, some turned round: the sparse path keeps one per pair (the heaviest,
    # then the first), Kruskal skips the others
    extra = np.arange(0, g.n_edges, 3)
    flip = extra % 2 == 1
    e = np.concatenate([g.edges, np.where(flip[:, None], g.edges[extra][:, ::-1], g.edges[extra])])
    q = np.concatenate([q, np.where(flip, so3.qconj_rows(q[:, extra]), q[:, extra])], axis=1)
    w = np.ones(len(e)) if equal_weights else np.concatenate([w, w[extra][::-1]])
    g = SimpleNamespace(edges=e)
    dense = M.spanning_tree_rotations(n, g.edges, q, w)
    monkeypatch.setattr(M, "MST_PYTHON_MAX_EDGES", 0)
    sparse = M.spanning_tree_rotations(n, g.edges, q, w)
    assert dense[1] == sparse[1] and sorted(dense[2]) == sorted(sparse[2])
    assert np.allclose(dense[0], sparse[0], atol=1e-12)


def test_spanning_tree_satisfies_tree_edges_and_prefers_heavy_edges():
    g = random_problem(n=50, degree=8, sigma_deg=3.0, seed=12)
    w = np.random.default_rng(0).uniform(1, 100, g.n_edges)
    qrel = so3.quaternion_rows_from_matrices(g.cam2_from_cam1)
    q, root, tree = spanning_tree_rotations(g.n_nodes, g.edges, qrel, w)
    assert len(tree) == g.n_nodes - 1
    _, th = edge_errors(q, g.edges, qrel)
    assert np.degrees(th[tree]).max() < 1e-9
    # Maximum spanning tree: its weight matches networkx's.
    import networkx as nx

    G = nx.Graph()
    G.add_weighted_edges_from((int(a), int(b), float(x)) for (a, b), x in zip(g.edges, w))
    best = sum(d["weight"] for *_, d in nx.maximum_spanning_tree(G).edges(data=True))
    assert w[tree].sum() == pytest.approx(best)


@pytest.mark.parametrize("solver", ["dense", "direct", "cg"])
def test_linear_solvers_agree(solver):
    g = random_problem(n=120, degree=14, sigma_deg=2.0, outliers=0.1, seed=13)
    a = average_rotations(g, linear_solver="direct")
    b = average_rotations(g, linear_solver=solver)
    assert compare_rotations(a.cam_from_world, b.cam_from_world).max < 1e-4


@pytest.mark.parametrize("outer_max", [0, 10**6])
def test_edge_system_matches_the_direct_formulas(outer_max, monkeypatch):
    """The IRLS kernel's half-angle errors, right-hand side and update agree with
    edge_errors, the incidence matrix and so3, on both product paths (small graphs: einsum
    and outer products; large: so3_rows.qmul_rows), for angles from 0 to 180 deg."""
    import rotgraph.estimators.residuals as M

    monkeypatch.setattr(so3_rows, "OUTER_MAX", outer_max)
    rng = np.random.default_rng(7)
    n, E = 9, 40
    edges = np.stack([rng.integers(0, n, E), rng.integers(0, n, E)], axis=1)
    edges = edges[edges[:, 0] != edges[:, 1]]
    q = so3.quaternion_rows_from_matrices(so3.random_rotations(n, rng))
    qrel = so3.quaternion_rows_from_matrices(so3.random_rotations(len(edges), rng))
    # Exact edges (zero residual) and residuals of exactly 180 deg as well.
    qi, qj = q[:, edges[:3, 0]], q[:, edges[:3, 1]]
    qrel[:, :3] = so3.qmul_rows(qj, so3.qconj_rows(qi))
    qrel[:, 3:5] = so3.qmul_rows(so3.qmul_rows(q[:, edges[3:5, 1]], np.array([0.0, 0.0, 1.0, 0.0])[:, None] * np.ones(2)), so3.qconj_rows(q[:, edges[3:5, 0]]))
    system = M.EdgeSystem(n, edges, qrel, anchor=2)
    v, f, t = system.errors(q)
    r, theta = edge_errors(q, edges, qrel)
    assert np.allclose(2 * t, theta, atol=1e-7)  # asin loses ~1e-8 rad only right at 180 deg
    assert np.allclose(2 * t[5:], theta[5:], atol=1e-12)
    assert np.abs(2 * t[:3]).max() < 1e-7 and np.allclose(np.degrees(2 * t[3:5]), 180.0)
    # The vector part is exact away from 180 deg (at 180 deg the sign is a free choice).
    assert np.allclose((2 * f * v)[:, 5:], r[:, 5:], atol=1e-12)
    # A^T y with the anchor's entries zero.
    y = rng.normal(size=(3, len(edges)))
    A = np.zeros((len(edges), n))
    A[np.arange(len(edges)), edges[:, 1]] += 1.0
    A[np.arange(len(edges)), edges[:, 0]] -= 1.0
    expect = (A.T @ y.T).T
    expect[:, 2] = 0.0
    assert np.allclose(system.rhs(y), expect, atol=1e-12)
    # q exp(2 x) with the half-angle update.
    x = rng.normal(scale=0.3, size=(n, 3))
    q2, h = system.update(q, x)
    assert np.allclose(h, np.linalg.norm(x, axis=1))
    assert np.allclose(q2, so3.qmul_rows(q, so3.qexp_rows(2 * x.T)), atol=1e-14)


def test_the_stage_tolerance_only_shortens_the_intermediate_stages():
    """The L1 start and the first robust pass of irls are intermediate: their tolerance
    changes the iterations spent there, not the optimum the final stage converges to."""
    g = random_problem(n=80, degree=10, sigma_deg=1.0, outliers=0.05, seed=21)
    tight = average_rotations(g, method="irls", stage_tol_deg=1e-6)
    loose = average_rotations(g, method="irls", stage_tol_deg=0.05)
    assert tight.stages[1]["iterations"] > loose.stages[1]["iterations"]
    assert tight.stages[2]["iterations"] > loose.stages[2]["iterations"]
    assert [s["stage"] for s in tight.stages] == [s["stage"] for s in loose.stages]
    assert compare_rotations(tight.cam_from_world, loose.cam_from_world).max < 0.01
    assert np.array_equal(tight.inliers, loose.inliers)
    # Without a re-fit of the scale, the robust pass is the last stage: final tolerance.
    fixed = average_rotations(g, method="irls", rescale=False, stage_tol_deg=0.05)
    assert [s["stage"] for s in fixed.stages] == ["spanning_tree", "l1", "geman_mcclure"]
    fixed_tight = average_rotations(g, method="irls", rescale=False, stage_tol_deg=1e-6)
    assert fixed.converged and compare_rotations(fixed.cam_from_world, fixed_tight.cam_from_world).max < 0.01


def test_the_progress_count_goes_on_when_a_stage_goes_on():
    """Without a re-fit of the scale the robust pass goes on as the same stage: the
    callback's count continues (a progress bar must not stall) and ends at the stage's total."""
    g = random_problem(n=30, degree=6, sigma_deg=2.5, seed=3)
    calls = []
    res = average_rotations(g, method="irls", callback=lambda stage, it, step: calls.append((stage, it)))
    for st in res.stages[1:]:
        counts = [it for stage, it in calls if stage == st["stage"]]
        assert counts == list(range(1, st["iterations"] + 1)), st


def test_tiny_loss_scales_keep_the_laplacian_solvable():
    """A vanishing loss scale makes the robust weights tiny but never singular (floor)."""
    g = random_problem(n=40, degree=8, sigma_deg=1.0, seed=4)
    for loss, scale in (("cauchy", 1e-8), ("geman_mcclure", 1e-4)):
        res = average_rotations(g, loss=loss, loss_scale_deg=scale, rescale=False)
        assert res.solved.all() and np.isfinite(res.cam_from_world).all()


def test_solve_irls_normalises_its_inputs():
    """The public solve_irls takes non-unit quaternions (its half angles assume unit ones)."""
    import rotgraph.estimators.rotation_averaging as M

    g = random_problem(n=20, degree=6, sigma_deg=2.0, outliers=0.1, seed=5)
    qrel = so3.quaternion_rows_from_matrices(g.cam2_from_cam1)
    q0, anchor, _ = spanning_tree_rotations(g.n_nodes, g.edges, qrel, g.weights)
    args = (g.edges, qrel, g.weights, anchor, "geman_mcclure", np.deg2rad(5.0), 50, 1e-9)
    a = M.solve_irls(q0, *args)[0]
    b = M.solve_irls(q0 * 1.01, g.edges, qrel * 0.97, *args[2:])[0]
    assert np.abs(a - b).max() < 1e-10


def test_median_and_percentile_match_numpy():
    import rotgraph.estimators.stats as M

    rng = np.random.default_rng(0)
    for n in (1, 2, 3, 10, 1023, 1024, 1025, 4000):
        x = rng.normal(size=n)
        assert M.median(x) == pytest.approx(np.median(x), abs=1e-15)
        assert M.percentile(x, 25) == pytest.approx(np.percentile(x, 25), abs=1e-15)
        if n > 2:
            y = x.copy()
            y[:2] = np.inf
            assert M.median(y) == np.median(y)
            y[1] = np.nan
            assert np.isnan(M.median(y))


def test_options_are_validated():
    with pytest.raises(ValueError):
        SolveOptions(method="magic").validated()
    with pytest.raises(ValueError):
        SolveOptions(loss="nope").validated()
    with pytest.raises(ValueError):
        SolveOptions(stage_tol_deg=-1.0).validated()


def test_deterministic():
    g = random_problem(n=100, degree=10, sigma_deg=2.0, outliers=0.2, seed=14)
    a = average_rotations(g)
    b = average_rotations(g)
    assert np.array_equal(a.cam_from_world, b.cam_from_world)


def test_sparse_lu_only_where_it_does_not_fill_in():
    """A thin graph with long-range edges (random, degree 8) fills in a sparse LU (20,000
    cameras: 208 s a factorisation, measured): the solvers take CG there, and keep the LU
    for thin graphs that stay local (a pose graph)."""
    from rotgraph.estimators.laplacian import AnchoredBlockLaplacian, direct_is_cheap, make_laplacian
    from rotgraph.synth import random_problem

    er = random_problem(n=20000, degree=8, sigma_deg=1.0, seed=0)
    assert not direct_is_cheap(er.n_nodes, er.edges)
    assert make_laplacian(er.n_nodes, er.edges, 0).solver == "cg"
    pg = random_problem(n=3000, degree=4, sigma_deg=1.0, graph="posegraph", seed=0)
    assert direct_is_cheap(pg.n_nodes, pg.edges, k=3)
    assert make_laplacian(pg.n_nodes, pg.edges, 0).solver == "direct"
    assert AnchoredBlockLaplacian(pg.n_nodes, pg.edges, 0).solver == "direct"


def test_solvers_run_blas_on_one_thread_and_give_the_threads_back():
    """average_rotations runs with every loaded BLAS (numpy's and scipy's OpenBLAS) on one
    thread: their calls are small, and a second thread's hand-offs cost milliseconds each on a
    loaded machine. The caller's setting is back afterwards. In another thread the solver
    leaves BLAS alone (threadpoolctl sets OpenBLAS from one controlling thread only)."""
    from threadpoolctl import threadpool_info, threadpool_limits

    g = random_problem(n=60, degree=8, sigma_deg=1.0, outliers=0.1, seed=3, uncertainty_spread=3)  # information: the dense block Laplacian
    seen = []

    def callback(stage, iteration, step):
        seen.append([d["num_threads"] for d in threadpool_info() if d["user_api"] == "blas"])

    with threadpool_limits(limits=2, user_api="blas"):
        average_rotations(g, callback=callback)
        after = [d["num_threads"] for d in threadpool_info() if d["user_api"] == "blas"]
    # every BLAS loaded (pip wheels: numpy's and scipy's own OpenBLAS, whose LAPACK does the
    # Cholesky) is on one thread during the solve
    assert seen and seen[0] and all(n == [1] * len(n) for n in seen)
    assert after == [2] * len(after)

    import threading

    seen.clear()
    t = threading.Thread(target=lambda: average_rotations(g, callback=callback))
    with threadpool_limits(limits=2, user_api="blas"):
        t.start()
        t.join()
    assert seen and all(n == [2] * len(n) for n in seen)


def test_every_method_of_the_table_has_a_function_and_runs():
    """Issue #30 item 5: a method is one entry of rotgraph.choices.METHOD_TABLE and one
    function in rotgraph.estimators.methods; every entry runs, and its flags hold: an
    iterative method starts from --init, the others ignore it; a robust one finds the
    outliers."""
    import rotgraph
    from rotgraph.choices import ITERATIVE_METHODS, METHOD_TABLE, ROBUST_METHODS, WARM_START_METHODS
    from rotgraph.estimators.methods import METHOD_FUNCTIONS

    assert METHODS == tuple(m.name for m in METHOD_TABLE) == tuple(METHOD_FUNCTIONS)
    assert ITERATIVE_METHODS == tuple(m.name for m in METHOD_TABLE if m.iterative)
    assert ROBUST_METHODS == tuple(m.name for m in METHOD_TABLE if m.robust)
    assert WARM_START_METHODS == tuple(m.name for m in METHOD_TABLE if m.warm_start)
    g = rotgraph.random_problem(n=50, degree=8, sigma_deg=2.0, outliers=0.1, seed=0)
    for m in METHOD_TABLE:
        res = average_rotations(g, method=m.name)
        assert res.method == m.name and res.solved.all() and np.isfinite(res.cost), m.name
        assert res.stages[0]["stage"] == "spanning_tree" and np.isfinite(res.edge_weights).all(), m.name
        from_chordal = average_rotations(g, method=m.name, init="chordal")
        if m.iterative:
            assert [s["stage"] for s in from_chordal.stages][:2] == ["spanning_tree", "chordal"], m.name
        else:
            np.testing.assert_array_equal(from_chordal.cam_from_world, res.cam_from_world)
        if m.robust:
            assert err_deg(res, g).median < 2.0, m.name
            assert (~res.inliers[g.meta["outlier"]]).all(), m.name
