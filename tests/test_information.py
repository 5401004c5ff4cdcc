"""Per-edge rotation information matrices in the solvers (issue #16, item 3).

Convention (rotgraph.viewgraph): R_ij,meas = exp([d]x) R_ij, d ~ N(0, H_ij^-1), d in camera
j's frame. The solvers weight each edge's residual by it (a 3x3-block Laplacian).
"""

import numpy as np
import pytest
from scipy.optimize import least_squares

from rotgraph import average_rotations, compare_rotations, so3
from rotgraph.errors import InputError
from rotgraph.estimators.laplacian import AnchoredBlockLaplacian
from rotgraph.synth import random_problem
from rotgraph.viewgraph import Rigs, ViewGraph, check_information


def _median_error(result, graph) -> float:
    return float(compare_rotations(result.cam_from_world, graph.gt_cam_from_world).median)


def _whitened_cost(graph, R) -> float:
    """sum_e d_e^T H_e d_e with d_e = log(R_ij,meas (R_j R_i^T)^T), brute force."""
    i, j = graph.edges.T
    d = so3.log(graph.cam2_from_cam1 @ np.swapaxes(R[j] @ np.swapaxes(R[i], 1, 2), 1, 2))
    return float(np.einsum("ea,eab,eb->", d, graph.information, d))


def test_noise_free_with_information_is_exact():
    g = random_problem(n=60, degree=8, sigma_deg=1.0, outliers=0.0, seed=4, uncertainty_spread=4)
    g.cam2_from_cam1 = g.gt_cam_from_world[g.edges[:, 1]] @ np.swapaxes(g.gt_cam_from_world[g.edges[:, 0]], 1, 2)
    for method in ("adaptive", "irls", "l2", "l1"):
        r = average_rotations(g, method=method)
        assert compare_rotations(r.cam_from_world, g.gt_cam_from_world).max < 1e-6, method


@pytest.mark.parametrize("sigma, rtol", [(5.0, 1e-9), (1.0, 1e-9), (0.2, 1e-9)])
def test_l2_with_information_minimises_the_whitened_cost(sigma, rtol):
    """Brute force (scipy least squares on the exact geodesic whitened residuals) from
    rotgraph's answer finds no lower cost: the Gauss-Newton steps use the exact Jacobians,
    so the fixed point is the minimum (standard deviations up to 20 deg per axis here)."""
    g = random_problem(n=10, degree=4, sigma_deg=sigma, outliers=0.0, seed=3, uncertainty_spread=4)
    R0 = average_rotations(g, method="l2", step_tol_deg=1e-10, max_iterations=200).cam_from_world
    chol = np.linalg.cholesky(g.information)
    i, j = g.edges.T

    def residuals(x):
        R = so3.exp(x.reshape(-1, 3)) @ R0
        d = so3.log(g.cam2_from_cam1 @ np.swapaxes(R[j] @ np.swapaxes(R[i], 1, 2), 1, 2))
        return np.einsum("eba,eb->ea", chol, d).ravel()

    sol = least_squares(residuals, np.zeros(3 * g.n_nodes), xtol=1e-15, ftol=1e-15, gtol=1e-15)
    ours = _whitened_cost(g, R0)
    assert ours == pytest.approx(2 * sol.cost, rel=rtol)
    # and far from the isotropic answer's cost: the information matters
    iso = average_rotations(g, method="l2", use_information=False).cam_from_world
    assert _whitened_cost(g, iso) > ours * 1.001


@pytest.mark.parametrize("method", ["l2", "adaptive", "irls"])
def test_edge_direction_does_not_matter(method):
    """Each edge given the other way round (R_ji = R_ij^T, H_ji = R_ij^T H R_ij) is the same
    measurement: the same solution, to rounding."""
    g = random_problem(n=150, degree=10, sigma_deg=2.0, outliers=0.1, seed=1, uncertainty_spread=4)
    R, H = g.cam2_from_cam1, g.information
    flipped = ViewGraph.from_edges(g.edges[:, 1], g.edges[:, 0], np.swapaxes(R, 1, 2), node_ids=g.node_ids,
                                   information=np.swapaxes(R, 1, 2) @ H @ R)
    a = average_rotations(g, method=method).cam_from_world
    b = average_rotations(flipped, method=method).cam_from_world
    a, b = a @ a[0].T, b @ b[0].T  # one gauge
    assert np.degrees(so3.angle_between(a, b)).max() < 1e-6


@pytest.mark.parametrize("graph, n, degree, outliers", [("er", 300, 12, 0.0), ("er", 400, 16, 0.2), ("posegraph", 400, 4, 0.0)])
def test_information_recovers_ground_truth_better(graph, n, degree, outliers):
    """Anisotropic, heteroscedastic noise with its true information: weighting by it is
    more accurate than ignoring it on every seed, and clearly so on average."""
    ratios = []
    for seed in range(3):
        g = random_problem(n=n, degree=degree, sigma_deg=2.0, outliers=outliers, graph=graph, seed=seed, uncertainty_spread=3)
        with_info = _median_error(average_rotations(g), g)
        without = _median_error(average_rotations(g, use_information=False), g)
        assert with_info < without, (seed, with_info, without)
        ratios.append(with_info / without)
    assert np.mean(ratios) < 0.85, ratios


def test_outliers_flagged_with_information():
    g = random_problem(n=300, degree=14, sigma_deg=2.0, outliers=0.25, seed=2, uncertainty_spread=3)
    r = average_rotations(g)
    truth = g.meta["outlier"]
    assert (~r.inliers[truth]).mean() > 0.97  # outliers found
    assert r.inliers[~truth].mean() > 0.97  # inliers kept
    assert r.diagnostics["information"]["used"] is True


def test_scaling_all_information_changes_nothing():
    g = random_problem(n=80, degree=8, sigma_deg=2.0, outliers=0.1, seed=5, uncertainty_spread=3)
    r1 = average_rotations(g)
    g.information = g.information * 37.0
    r2 = average_rotations(g)
    np.testing.assert_allclose(r2.cam_from_world, r1.cam_from_world, atol=1e-9)
    np.testing.assert_array_equal(r2.inliers, r1.inliers)


def test_isotropic_information_is_the_weighted_solve():
    """H_e = c_e I is the scalar weight c_e: the block solver gives the scalar one's answer."""
    g = random_problem(n=70, degree=8, sigma_deg=2.0, outliers=0.0, seed=6)
    c = np.random.default_rng(0).uniform(0.5, 2.0, g.n_edges)
    g_info = ViewGraph.from_edges(g.node_ids[g.edges[:, 0]], g.node_ids[g.edges[:, 1]], g.cam2_from_cam1,
                                  node_ids=g.node_ids, information=c[:, None, None] * np.eye(3))
    g_w = ViewGraph.from_edges(g.node_ids[g.edges[:, 0]], g.node_ids[g.edges[:, 1]], g.cam2_from_cam1, c, node_ids=g.node_ids)
    a = average_rotations(g_info, method="l2", step_tol_deg=1e-9)
    b = average_rotations(g_w, method="l2", use_weights=True, step_tol_deg=1e-9)
    np.testing.assert_allclose(a.cam_from_world, b.cam_from_world, atol=1e-9)


def test_gauge_invariance_with_information():
    """Turning the world (R_i -> R_i Q) changes no relative rotation and no information:
    the solution is the same up to that gauge."""
    g = random_problem(n=50, degree=8, sigma_deg=2.0, outliers=0.0, seed=7, uncertainty_spread=3)
    r = average_rotations(g, method="l2")
    Q = so3.exp(np.array([0.3, -1.0, 0.5]))
    err = compare_rotations(r.cam_from_world, g.gt_cam_from_world @ Q)
    ref = compare_rotations(r.cam_from_world, g.gt_cam_from_world)
    assert err.median == pytest.approx(ref.median, abs=1e-9)


@pytest.mark.parametrize("graph, n, degree", [("er", 120, 10), ("er", 400, 20), ("posegraph", 300, 4)])
def test_block_laplacian_solvers_agree(graph, n, degree):
    g = random_problem(n=n, degree=degree, sigma_deg=1.0, outliers=0.0, graph=graph, seed=1, uncertainty_spread=3)
    rng = np.random.default_rng(2)
    U = g.information * rng.uniform(0.1, 1.0, g.n_edges)[:, None, None]
    rhs = rng.standard_normal((3, g.n_nodes))
    rhs[:, 0] = 0.0
    xs = []
    for s in ("dense", "direct", "cg"):
        lap = AnchoredBlockLaplacian(g.n_nodes, g.edges, 0, s)
        lap.rtol = 1e-10  # as a linear solver (the IRLS steps stop CG at laplacian.RTOL)
        xs.append(lap.solve(np.moveaxis(U, 0, -1), rhs))  # blocks as rows (3, 3, E)
    # the system itself: sum_e A_e^T U_e A_e x = rhs away from the anchor
    i, j = g.edges.T
    x = xs[0]
    diff = x[j] - x[i]
    flow = np.einsum("eab,eb->ea", U, diff)
    Lx = np.zeros((g.n_nodes, 3))
    np.add.at(Lx, j, flow)
    np.add.at(Lx, i, -flow)
    np.testing.assert_allclose(Lx[1:], rhs.T[1:], atol=1e-8 * np.abs(rhs).max())
    assert np.abs(x[0]).max() == 0.0
    for other in xs[1:]:
        np.testing.assert_allclose(other, x, atol=1e-6 * np.abs(x).max())


def test_merged_parallel_edges_add_their_information():
    rng = np.random.default_rng(3)
    R = so3.random_rotations(2, rng)
    Rij = R[1] @ R[0].T
    H1 = np.diag([1.0, 4.0, 9.0])
    H2 = np.array([[2.0, 0.5, 0.0], [0.5, 3.0, 0.1], [0.0, 0.1, 1.0]])
    # the second edge given the other way round: R_ji = R_ij^T, its information is for R_ji
    g = ViewGraph.from_edges([0, 1], [1, 0], np.stack([Rij, Rij.T]), information=np.stack([H1, H2]), duplicates="merge")
    assert g.n_edges == 1
    np.testing.assert_allclose(g.information[0], H1 + Rij @ H2 @ Rij.T, atol=1e-12)


def test_information_is_checked():
    rel = so3.random_rotations(2, np.random.default_rng(0))
    good = np.stack([np.eye(3), 2 * np.eye(3)])
    assert check_information(good, 2).shape == (2, 3, 3)
    bad_sym = good.copy()
    bad_sym[1, 0, 1] = 0.5
    not_pd = good.copy()
    not_pd[1] = np.diag([1.0, -1.0, 1.0])
    nan = good.copy()
    nan[0, 2, 2] = np.nan
    for bad, words in ((bad_sym, "not symmetric"), (not_pd, "not positive definite"), (nan, "not finite")):
        with pytest.raises(InputError, match=words) as exc:
            ViewGraph.from_edges([0, 1], [1, 2], rel, information=bad, source_path="e.txt", source_lines=[3, 9])
        assert exc.value.line == 9 or exc.value.line == 3
    with pytest.raises(InputError, match="information matrices"):
        ViewGraph.from_edges([0, 1], [1, 2], rel, information=np.eye(3)[None])


def test_rig_frame_problem_carries_information():
    """Images of 2-camera rigs with per-edge information: the frame-level solve uses the
    information turned into the frame (S_b^T H S_b) and is exact on noise-free data, and
    more accurate with the information than without on anisotropic noise."""
    rng = np.random.default_rng(8)
    frames, cams = 40, 2
    S = np.stack([np.eye(3), so3.exp(np.array([0.0, 1.2, 0.2]))])
    Rf = so3.random_rotations(frames, rng)
    R = (S[None] @ Rf[:, None]).reshape(-1, 3, 3)  # image k = frame k // 2, sensor k % 2
    n = len(R)
    pairs = np.array([(a, b) for a in range(n) for b in range(a + 1, n) if a // 2 != b // 2 and rng.random() < 0.15])
    i, j = pairs.T
    std = np.deg2rad(1.5) * np.exp(rng.uniform(-1, 1, (len(pairs), 3)) * np.log(3.0))
    axes = so3.random_rotations(len(pairs), rng)
    H = axes @ (std[:, :, None] ** -2 * np.swapaxes(axes, 1, 2))
    d = np.einsum("eab,eb->ea", axes, std * rng.standard_normal((len(pairs), 3)))
    rel_true = R[j] @ np.swapaxes(R[i], 1, 2)
    rigs = Rigs(np.arange(n) // 2, S[np.arange(n) % 2])
    exact = ViewGraph.from_edges(i, j, rel_true, node_ids=np.arange(n), information=H)
    exact.rigs = rigs
    assert compare_rotations(average_rotations(exact).cam_from_world, R).max < 1e-6
    noisy = ViewGraph.from_edges(i, j, so3.exp(d) @ rel_true, node_ids=np.arange(n), information=H)
    noisy.rigs = rigs
    with_info = compare_rotations(average_rotations(noisy).cam_from_world, R).median
    without = compare_rotations(average_rotations(noisy, use_information=False).cam_from_world, R).median
    assert with_info < 0.9 * without


def test_block_laplacian_with_parallel_edges_and_an_inner_anchor():
    """The assembly (one sparse operator over the edges' blocks) sums parallel edges and drops
    the anchor's blocks wherever the anchor is: dense, sparse LU and CG solve the same system,
    which a brute-force dense Laplacian confirms."""
    g = random_problem(n=40, degree=6, sigma_deg=1.0, outliers=0.0, graph="er", seed=4, uncertainty_spread=3)
    rng = np.random.default_rng(5)
    dup = rng.choice(g.n_edges, 30, replace=False)
    edges = np.concatenate([g.edges, g.edges[dup], g.edges[dup[:10], ::-1]])  # parallel, both ways
    U = np.concatenate([g.information, g.information[dup], g.information[dup[:10]]])
    U = U * rng.uniform(0.1, 1.0, len(U))[:, None, None]
    anchor = 7
    rhs = rng.standard_normal((3, g.n_nodes))
    rhs[:, anchor] = 0.0
    full = np.zeros((g.n_nodes, 3, g.n_nodes, 3))
    for (i, j), Ue in zip(edges, U):
        full[i, :, i] += Ue
        full[j, :, j] += Ue
        full[i, :, j] -= Ue
        full[j, :, i] -= Ue
    keep = np.arange(g.n_nodes) != anchor
    A = full[keep][:, :, keep].reshape(3 * (g.n_nodes - 1), -1)
    x_ref = np.zeros((g.n_nodes, 3))
    x_ref[keep] = np.linalg.solve(A, rhs.T[keep].ravel()).reshape(-1, 3)
    for s in ("dense", "direct", "cg"):
        lap = AnchoredBlockLaplacian(g.n_nodes, edges, anchor, s)
        lap.rtol = 1e-12
        np.testing.assert_allclose(lap.solve(np.moveaxis(U, 0, -1), rhs), x_ref, atol=1e-9 * np.abs(x_ref).max())
    # the sparse solvers also take the blocks chunk by chunk as the Gauss-Newton blocks are made (no U)
    rows = np.moveaxis(U, 0, -1)
    for s in ("direct", "cg"):
        lap = AnchoredBlockLaplacian(g.n_nodes, edges, anchor, s)
        lap.rtol = 1e-12
        for a in range(0, len(edges), 37):
            lap.write_blocks(slice(a, a + 37), rows[:, :, a:a + 37])
        np.testing.assert_allclose(lap.solve(None, rhs), x_ref, atol=1e-9 * np.abs(x_ref).max())
    with pytest.raises(ValueError):
        AnchoredBlockLaplacian(g.n_nodes, edges, anchor, "dense").solve(None, rhs)


def test_information_is_tested_not_trusted():
    """The information's scale is kept when it predicts the residuals (true anisotropic
    information: exponent 0.5, no second solve) and dropped when it does not (each edge's true
    matrix times a random factor 1/30-30: exponent 0, the problem solved again with the
    information's shape only, closer to the truth than with the factors trusted)."""
    from dataclasses import replace

    import rotgraph.estimators.methods as methods
    from rotgraph.estimators.noise_model import mean_variance_precision

    H = np.array([[[4.0, 1.0, 0.0], [1.0, 3.0, 0.5], [0.0, 0.5, 2.0]]])
    assert np.allclose(mean_variance_precision(H), 3.0 / np.trace(np.linalg.inv(H[0])))
    for seed in range(2):
        g = random_problem(n=300, degree=8, sigma_deg=2.0, outliers=0.05, graph="er", seed=seed, uncertainty_spread=3.0)
        f = np.exp(np.random.default_rng(seed).uniform(np.log(1 / 30), np.log(30), g.n_edges))
        bad = replace(g, information=g.information * f[:, None, None])
        true = average_rotations(g).diagnostics["information_test"]
        assert true["exponent"] == 0.5 and not true["used"]
        tested = average_rotations(bad)
        assert tested.diagnostics["information_test"]["exponent"] == 0.0 and tested.diagnostics["information_test"]["used"]
        test = methods._information_test
        try:
            methods._information_test = lambda *a, **k: False
            trusted = average_rotations(bad)
        finally:
            methods._information_test = test
        err = [compare_rotations(r.cam_from_world, g.gt_cam_from_world).median for r in (tested, trusted)]
        assert err[0] < 0.85 * err[1], err


def test_small_graphs_keep_their_true_information():
    """Few residuals make the held-out comparison of 13 exponents noisy: with its true
    information a small graph keeps it (no second solve), below 20 degrees of freedom untested."""
    for seed in range(8):
        g = random_problem(n=30, degree=4, sigma_deg=2.0, outliers=0.0, graph="er", seed=seed, uncertainty_spread=5.0)
        test = average_rotations(g).diagnostics["information_test"]
        assert not test["used"], (seed, test)


@pytest.mark.parametrize("seed", [0, 3])
def test_wrong_edges_of_high_information_do_not_set_the_basin(seed):
    """Wrong edges claiming 25x the information of the true ones (a fifth of a degree-4
    graph) do not decide the basin: the answer is as good as the solve without information
    (before the rough stages capped each edge's precision at the median edge's, these seeds
    ended 108 deg off while flagging half the true edges)."""
    from dataclasses import replace

    g = random_problem(n=150, degree=4, sigma_deg=1.0, outliers=0.2, seed=seed, uncertainty_spread=3)
    wrong = np.asarray(g.meta["outlier"])
    H = g.information.copy()
    H[wrong] *= 25.0
    g = replace(g, information=H)
    r = average_rotations(g)
    plain = average_rotations(g, use_information=False)
    err = [compare_rotations(x.cam_from_world, g.gt_cam_from_world).median for x in (r, plain)]
    assert err[0] < 1.25 * err[1], err
    assert (~r.inliers[wrong]).mean() > 0.7  # the wrong edges found
    assert r.inliers[~wrong].mean() > 0.9  # the true ones kept
