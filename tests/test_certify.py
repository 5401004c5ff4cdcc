"""The global-optimality certificate of chordal rotation averaging (rotgraph.estimators.certify).

The mathematics is checked, not just the plumbing: the identities of the derivation, the
matrix against GTSAM's own (entry by entry), the verdicts against brute force on tiny
graphs and against GTSAM's ``checkOptimality`` on a sweep, known non-global critical
points, and the rank-lifted escape.
"""

import json

import numpy as np
import pytest
from scipy.optimize import minimize

from rotgraph import average_rotations, so3
from rotgraph.estimators import certify as C
from rotgraph.estimators.certify import certify, chordal_cost
from rotgraph.estimators.staircase import certified_chordal, refine_chordal
from rotgraph.synth import random_problem
from rotgraph.viewgraph import ViewGraph


def _graph(R, edges, rel, weights=None):
    """The component machinery on (R, edges): a ChordalGraph and the rotations as stacked Y."""
    p = C.chordal_problem(R, edges, rel, weights, None)
    assert len(p.components) == 1
    return C.ChordalGraph(p.n, p.i, p.j, p.rel, p.w), p.R


def _dense_W(n, edges, rel, w=None):
    w = np.ones(len(edges)) if w is None else w
    W = np.zeros((3 * n, 3 * n))
    for (i, j), Rij, wk in zip(edges, rel, w):
        W[3 * j : 3 * j + 3, 3 * i : 3 * i + 3] += wk * Rij
        W[3 * i : 3 * i + 3, 3 * j : 3 * j + 3] += wk * Rij.T
    return W


def _local(g):
    """rotgraph's L2 answer taken to a critical point of the chordal cost."""
    R0 = average_rotations(g, method="l2").cam_from_world
    return refine_chordal(R0, g.edges, g.cam2_from_cam1)[0]


def _ring(n, k=1):
    """A noise-free ring (every R_ij = I, global minimum 0 at R_i = I) and its twisted
    state with k turns about z: R_i = Rz(2 pi k i / n), a critical point of cost
    n * 4 (1 - cos(2 pi k / n))."""
    edges = np.array([(i, (i + 1) % n) for i in range(n)])
    rel = np.repeat(np.eye(3)[None], n, axis=0)
    R = so3.exp(np.outer(2 * np.pi * k * np.arange(n) / n, [0.0, 0.0, 1.0]))
    return edges, rel, R


# --------------------------------------------------------------------------- derivation


def test_cost_identity_and_multipliers():
    g = random_problem(n=12, degree=4, sigma_deg=30, seed=3)
    w = np.random.default_rng(0).uniform(0.5, 2.0, g.n_edges)
    R = so3.random_rotations(12, np.random.default_rng(1))  # any rotations, not critical
    Y = R.reshape(-1, 3)
    W = _dense_W(12, g.edges, g.cam2_from_cam1, w)
    f = chordal_cost(R, g.edges, g.cam2_from_cam1, w)
    assert f == pytest.approx(6 * w.sum() - np.trace(Y.T @ W @ Y), rel=1e-12)  # f = 6 sum w - tr(Y^T W Y)
    G = (W @ Y).reshape(12, 3, 3)
    Lam = C.ChordalGraph.multipliers(R, G)
    assert np.allclose(Lam, np.swapaxes(Lam, 1, 2))
    M = -W.copy()
    for k in range(12):
        M[3 * k : 3 * k + 3, 3 * k : 3 * k + 3] += Lam[k]
    assert np.trace(Lam, axis1=1, axis2=2).sum() == pytest.approx(np.trace(Y.T @ W @ Y), rel=1e-12)
    assert np.abs(Y.T @ M @ Y).max() < 1e-10  # Y^T M Y = 0 for every Y
    # block row i of M Y is -skew(G_i R_i^T) R_i: nonzero here (not critical)
    MY = (M @ Y).reshape(12, 3, 3)
    GR = G @ np.swapaxes(R, 1, 2)
    assert np.allclose(MY, -0.5 * (GR - np.swapaxes(GR, 1, 2)) @ R)
    assert np.abs(MY).max() > 1e-2
    # the sparse operator and dense matrix of the module are this M (weights / median)
    gg, _ = _graph(R, g.edges, g.cam2_from_cam1, w)
    Ms = M / np.median(w)
    assert np.allclose(gg.M_dense(Lam / np.median(w)), Ms)
    X = np.random.default_rng(2).standard_normal((36, 5))
    assert np.allclose(gg.M_times(Lam / np.median(w), X), Ms @ X)


def test_at_a_critical_point_M_Y_is_zero():
    g = random_problem(n=30, degree=6, sigma_deg=20, seed=0)
    R, _, s = refine_chordal(average_rotations(g, method="l2").cam_from_world, g.edges, g.cam2_from_cam1)
    assert s < 1e-10
    gg, Rn = _graph(R, g.edges, g.cam2_from_cam1)
    G = gg.WY(Rn)
    Lam = gg.multipliers(Rn, G)
    Y = Rn.reshape(-1, 3)
    assert np.abs(gg.M_times(Lam, Y)).max() < 1e-8 * gg.degree.max()
    GR = G @ np.swapaxes(Rn, 1, 2)
    assert np.abs(GR - np.swapaxes(GR, 1, 2)).max() < 1e-8 * gg.degree.max()  # (W Y)_i R_i^T symmetric
    c = certify(R, g.edges, g.cam2_from_cam1)
    assert c.stationarity == pytest.approx(s, abs=1e-12)
    # the two stationarity formulas of the docstring agree (away from the critical point)
    R2 = so3.perturb(Rn, 0.05, np.random.default_rng(0))
    G2 = gg.WY(R2)
    GR2 = G2 @ np.swapaxes(R2, 1, 2)
    K = 0.5 * (GR2 - np.swapaxes(GR2, 1, 2))
    s_vee = (np.linalg.norm(so3.vee(K), axis=1) / gg.degree).max()
    assert gg.stationarity(R2, G2, gg.multipliers(R2, G2)) == pytest.approx(s_vee, rel=1e-10)


# --------------------------------------------------------------------------- verdicts


@pytest.mark.parametrize("graph,n,degree", [("er", 30, 6), ("er", 200, 10), ("traj", 150, 4), ("posegraph", 120, 4)])
def test_noise_free_is_certified(graph, n, degree):
    g = random_problem(n=n, degree=degree, sigma_deg=0.0, graph=graph, seed=1)
    gauge = so3.random_rotations(None, np.random.default_rng(5))
    R = g.gt_cam_from_world @ gauge.T  # any gauge
    for method in ("dense", "lobpcg") if 3 * n > 100 else ("dense",):
        c = certify(R, g.edges, g.cam2_from_cam1, method=method)
        assert c.certified, c.reason
        assert c.reason.startswith("certified")
        assert c.lambda_min >= -c.tolerance and abs(c.lambda_min) < 1e-9
        assert c.lambda_complement > 1e-4  # a strict certificate: the graph Laplacian's gap
        assert c.primal_cost < 1e-20
        assert abs(c.duality_gap) < 1e-9 and c.dual_bound <= c.primal_cost + 1e-9
        assert c.stationarity < 1e-12
        assert c.n_nodes == n and c.n_edges == g.n_edges and c.n_components == 1
    gg, Rn = _graph(R, g.edges, g.cam2_from_cam1)
    Y = Rn.reshape(-1, 3)
    assert np.abs(gg.M_times(gg.multipliers(Rn, gg.WY(Rn)), Y)).max() < 1e-10  # M Y = 0


def test_noise_free_lambda_complement_is_the_laplacian_gap():
    # Without noise M = B (L kron I) B^T (B = blkdiag(R_i)): its spectrum is the graph
    # Laplacian's, each eigenvalue three times; beyond the gauge, the Fiedler value.
    g = random_problem(n=40, degree=5, sigma_deg=0.0, seed=2)
    A = np.zeros((40, 40))
    A[g.edges[:, 0], g.edges[:, 1]] = A[g.edges[:, 1], g.edges[:, 0]] = 1.0
    L = np.diag(A.sum(1)) - A
    fiedler = np.linalg.eigvalsh(L)[1]
    for method, rel in (("dense", 1e-9), ("lobpcg", 1e-3)):  # LOBPCG: residual <= 1e-2 theta, error ~ its square
        c = certify(g.gt_cam_from_world, g.edges, g.cam2_from_cam1, method=method)
        assert c.lambda_complement == pytest.approx(fiedler, rel=rel)
        assert c.lambda_complement >= fiedler * (1 - 1e-12)  # a Ritz value bounds the eigenvalue from above


def test_a_near_critical_optimum_is_certified_by_its_bound():
    """Another solver's optimum stops near a critical point (GTSAM Shonan at its default
    tolerances: stationarity 1e-5 - 2e-2): certified within its duality gap, as GTSAM's
    checkOptimality certifies it, with a lower bound below the true minimum; moved further,
    refused."""
    g = random_problem(n=80, degree=8, sigma_deg=10.0, seed=3)
    R = _local(g)
    best = certify(R, g.edges, g.cam2_from_cam1)
    assert best.certified and best.stationarity < 1e-6
    rng = np.random.default_rng(0)
    axis = rng.standard_normal((80, 3))
    axis /= np.linalg.norm(axis, axis=1)[:, None]
    near = certify(so3.exp(1e-3 * axis) @ R, g.edges, g.cam2_from_cam1)
    assert near.certified and near.stationarity > 1e-6 and near.reason.startswith("certified: within")
    assert near.dual_bound <= best.primal_cost <= near.primal_cost  # a valid bound, at a costlier point
    assert near.duality_gap == pytest.approx(near.primal_cost - near.dual_bound)
    assert near.duality_gap <= 3 * 80 * near.tolerance
    far = certify(so3.exp(3e-2 * axis) @ R, g.edges, g.cam2_from_cam1)
    assert not far.certified and far.lambda_min < -far.tolerance and far.reason.startswith("not critical")
    assert far.dual_bound <= best.primal_cost


def test_ground_truth_of_a_noisy_problem_is_not_critical():
    g = random_problem(n=60, degree=8, sigma_deg=10.0, seed=4)
    for method in ("dense", "lobpcg"):
        c = certify(g.gt_cam_from_world, g.edges, g.cam2_from_cam1, method=method)
        assert not c.certified
        assert c.reason.startswith("not critical")
        assert c.stationarity > 1e-2
        assert c.lambda_min < -1e-3  # not critical => a negative eigenvalue (never deflated away)
        assert np.isnan(c.lambda_complement)
    # the local optimum of the same problem is certified, and cheaper than the truth
    R = _local(g)
    c2 = certify(R, g.edges, g.cam2_from_cam1)
    assert c2.certified and c2.primal_cost < c.primal_cost


def test_twisted_ring_is_a_critical_point_but_not_certified():
    # A known non-global critical point: the noise-free ring wound once about z.
    for n in (5, 8, 12):
        edges, rel, R = _ring(n)
        c = certify(R, edges, rel)
        assert c.stationarity < 1e-12  # critical, by symmetry
        assert c.primal_cost == pytest.approx(n * 4 * (1 - np.cos(2 * np.pi / n)))
        assert not c.certified and c.reason.startswith("negative eigenvalue"), c.reason
        assert c.lambda_min < -1e-3
        assert c.dual_bound <= 1e-9  # the global minimum is 0: the bound is valid
    # two cameras, one edge, the second turned by pi: the worst configuration is critical too
    c = certify(np.stack([np.eye(3), so3.exp(np.array([0.0, np.pi, 0.0]))]), np.array([[0, 1]]), np.eye(3)[None])
    assert c.stationarity < 1e-12 and c.primal_cost == pytest.approx(8.0)
    assert not c.certified and c.reason.startswith("negative eigenvalue") and c.lambda_min == pytest.approx(-2.0)


def _brute_force(n, edges, rel, w, starts, rng):
    """Lowest chordal cost of many BFGS runs from random rotations, over unnormalised
    quaternions (node 0 fixed to the identity: the gauge), with the exact gradient of
    ``|R_j - R_ij R_i|_F^2 = 8 (1 - (q_j . q_ij q_i)^2)`` (unit quaternions)."""
    i, j = edges[:, 0], edges[:, 1]
    L = so3.quaternion_left_matrices(so3.quaternions_from_matrices(rel))  # q_ij * p = L p

    def f(x):
        q = np.vstack([[1.0, 0.0, 0.0, 0.0], x.reshape(n - 1, 4)])
        norm = np.linalg.norm(q, axis=1)
        u = q / norm[:, None]
        b = np.einsum("eab,eb->ea", L, u[i])
        s = np.einsum("ea,ea->e", u[j], b)
        gu = np.zeros((n, 4))
        np.add.at(gu, j, (-16.0 * w * s)[:, None] * b)
        np.add.at(gu, i, (-16.0 * w * s)[:, None] * np.einsum("eba,eb->ea", L, u[j]))
        gq = (gu - np.einsum("na,na->n", gu, u)[:, None] * u) / norm[:, None]  # through q / |q|
        return float(w @ (8.0 * (1.0 - s * s))), gq[1:].ravel()

    best = np.inf
    for _ in range(starts):
        x0 = so3.quaternions_from_matrices(so3.random_rotations(n - 1, rng)).ravel()
        best = min(best, minimize(f, x0, jac=True, method="BFGS", options={"gtol": 1e-12}).fun)
    return best


def test_certified_means_brute_force_finds_nothing_lower():
    rng = np.random.default_rng(0)
    certified = refuted = loose = 0
    for trial in range(18):
        n = 3 + trial % 3
        pairs = np.array([(a, b) for a in range(n) for b in range(a + 1, n)])
        keep = rng.random(len(pairs)) < 0.8
        keep[[k for k, (a, b) in enumerate(pairs) if b == a + 1]] = True  # a path: connected
        edges = pairs[keep]
        R_true = so3.random_rotations(n, rng)
        sigma = np.deg2rad([20, 60, 100, 140][trial % 4])
        rel = so3.perturb(R_true[edges[:, 1]] @ np.swapaxes(R_true[edges[:, 0]], 1, 2), sigma, rng)
        w = rng.uniform(0.5, 2.0, len(edges))
        best = _brute_force(n, edges, rel, w, 25, rng)
        for _ in range(3):  # critical points from random starts: local minima are reachable
            R = refine_chordal(so3.random_rotations(n, rng), edges, rel, w)[0]
            c = certify(R, edges, rel, w)
            assert c.stationarity < 1e-9
            cost = chordal_cost(R, edges, rel, w)
            # the dual bound is a lower bound whatever the verdict (weights were divided by their median)
            assert c.dual_bound * c.weight_scale <= best + 1e-9 * max(best, 1.0)
            if c.certified:
                certified += 1
                assert best >= cost - 1e-9 * max(cost, 1.0), (trial, best, cost)
            elif cost > best + 1e-6 * max(cost, 1.0):
                refuted += 1  # not certified, and indeed not the global minimum
            else:
                loose += 1  # the global minimum, but the relaxation is not tight: no certificate exists
    assert certified >= 30 and refuted >= 2 and loose >= 1, (certified, refuted, loose)


def test_certified_chordal_escapes_the_twisted_ring():
    edges, rel, R = _ring(8)
    sol = certified_chordal(R, edges, rel)
    assert sol.certificate.certified, sol.summary
    assert sol.cost < 1e-12 and sol.start_cost > 1.0
    assert sol.max_rank >= 4 and sol.history[0]["stage"] == "local"
    assert "lifting" in sol.summary
    assert so3.angle_between(sol.cam_from_world[1:], sol.cam_from_world[:-1]).max() < 1e-6  # all equal again
    json.dumps(sol.to_dict())


def test_certified_chordal_on_a_hard_trajectory():
    # A trajectory with 20 deg noise: the local solution (from rotgraph's L2 answer) is not
    # the global minimum; the rank-lifted solve finds it and certifies it.
    g = random_problem(n=100, degree=4, sigma_deg=20.0, graph="traj", seed=0)
    R0 = average_rotations(g, method="l2").cam_from_world
    local = certify(refine_chordal(R0, g.edges, g.cam2_from_cam1)[0], g.edges, g.cam2_from_cam1)
    assert not local.certified and local.reason.startswith("negative eigenvalue")
    sol = certified_chordal(R0, g.edges, g.cam2_from_cam1)
    assert sol.certificate.certified, sol.summary
    assert sol.cost < local.primal_cost - 1.0
    assert sol.lower_bound == pytest.approx(sol.cost, rel=1e-8)
    assert [h["stage"] for h in sol.history][-1] == "round"
    assert chordal_cost(sol.cam_from_world, g.edges, g.cam2_from_cam1) == pytest.approx(sol.cost, rel=1e-12)


def test_small_negative_eigenvalue_on_a_pose_graph_is_real():
    # A pose graph whose local solution has lambda_min = -0.0065 only: GTSAM's
    # checkOptimality (Lanczos from the gauge directions, not deflated) calls it optimal;
    # the rank-lifted solve finds a lower cost and certifies it (benchmarks/README.md).
    g = random_problem(n=100, degree=4, sigma_deg=20.0, graph="posegraph", seed=2)
    R = _local(g)
    c = certify(R, g.edges, g.cam2_from_cam1)
    assert not c.certified and -0.01 < c.lambda_min < -1e-3
    sol = certified_chordal(R, g.edges, g.cam2_from_cam1)
    assert sol.certificate.certified
    assert sol.cost < c.primal_cost * (1 - 1e-3)


def test_certified_chordal_reports_a_loose_relaxation():
    # 60 degrees of noise: the relaxation is not tight; the answer is not certified but is
    # no worse than the local solution, and the lower bound stays below it.
    g = random_problem(n=20, degree=4, sigma_deg=60.0, seed=0)
    R0 = average_rotations(g, method="l2").cam_from_world
    sol = certified_chordal(R0, g.edges, g.cam2_from_cam1, max_rank=8)
    local_cost = sol.history[0]["cost"]
    assert not sol.certificate.certified and sol.summary.startswith("not certified")
    assert sol.cost <= local_cost + 1e-9
    assert sol.lower_bound < sol.cost
    lifted = [h["cost"] for h in sol.history if h["stage"] == "lift"]
    assert lifted and all(b <= a + 1e-9 for a, b in zip([local_cost] + lifted, lifted))  # each rank lowers the cost


# --------------------------------------------------------------------------- GTSAM


def _gtsam_shonan(edges, rel, kappa=None):
    gtsam = pytest.importorskip("gtsam")
    ms = gtsam.BinaryMeasurementsRot3()
    kappa = np.ones(len(edges)) if kappa is None else kappa
    for (i, j), Rij, k in zip(np.asarray(edges).tolist(), rel, kappa):
        # GTSAM measures wRi^T wRj = R_i R_j^T = R_ij^T (wR = cam_from_world^T); sigma^-2 = kappa
        ms.append(gtsam.BinaryMeasurementRot3(i, j, gtsam.Rot3(np.ascontiguousarray(Rij.T)),
                                              gtsam.noiseModel.Isotropic.Sigma(3, 1.0 / np.sqrt(k))))
    return gtsam, gtsam.ShonanAveraging3(ms)


def _gtsam_values(gtsam, R):
    values = gtsam.Values()
    for k, Rk in enumerate(R):
        values.insert(k, gtsam.SOn.FromMatrix(np.ascontiguousarray(Rk.T)))
    return values


def test_matrix_is_gtsams_entry_by_entry():
    g = random_problem(n=10, degree=4, sigma_deg=25, seed=7)
    w = np.random.default_rng(3).uniform(0.5, 3.0, g.n_edges)
    gtsam, sa = _gtsam_shonan(g.edges, g.cam2_from_cam1, w / np.median(w))
    R = so3.random_rotations(10, np.random.default_rng(4))
    gg, Rn = _graph(R, g.edges, g.cam2_from_cam1, w)
    W = gg.W.toarray()
    assert np.allclose(np.asarray(sa.denseQ()), W, atol=1e-12)  # GTSAM's Q_ is W
    A = sa.computeA_(_gtsam_values(gtsam, R))
    A = A.toarray() if hasattr(A, "toarray") else np.asarray(A)
    assert np.allclose(A, gg.M_dense(gg.multipliers(Rn, gg.WY(Rn))), atol=1e-12)  # and its A is M


@pytest.mark.parametrize("weighted", [False, True])
def test_verdicts_agree_with_gtsam_check_optimality(weighted):
    agree = decided = 0
    outcomes, methods = set(), set()
    for n in (20, 50, 150):  # 150: LOBPCG (3n > DENSE_MAX), below: LAPACK
        for degree in (4, 10):
            for sigma in (1, 10, 30, 60):
                for seed in range(2):
                    g = random_problem(n=n, degree=degree, sigma_deg=sigma, seed=seed)
                    if g.components().max() > 0:
                        continue
                    w = np.random.default_rng(seed).uniform(0.5, 2.0, g.n_edges) if weighted else None
                    start = (average_rotations(g, method="l2").cam_from_world if seed == 0
                             else so3.random_rotations(n, np.random.default_rng(seed)))
                    R = refine_chordal(start, g.edges, g.cam2_from_cam1, w)[0]
                    c = certify(R, g.edges, g.cam2_from_cam1, w)
                    assert c.stationarity < 1e-9
                    methods.add(c.method)
                    gtsam, sa = _gtsam_shonan(g.edges, g.cam2_from_cam1, None if w is None else w / np.median(w))
                    values = _gtsam_values(gtsam, R)
                    lam = sa.computeMinEigenValue(values)
                    ok = sa.checkOptimality(values)
                    # GTSAM's Lanczos is accurate to 1e-3 (absolute): a smallest eigenvalue beyond
                    # the gauge that close to the threshold is not comparable
                    if abs(c.lambda_complement + c.tolerance) < 2e-3:
                        continue
                    decided += 1
                    agree += ok == c.certified
                    outcomes.add(c.certified)
                    assert ok == c.certified, (n, degree, sigma, seed, c.lambda_min, lam)
                    assert lam == pytest.approx(c.lambda_min, abs=2e-3, rel=1e-3)
    assert decided >= 40 and outcomes == {True, False} and methods == {"dense eigvalsh", "lobpcg"}


# --------------------------------------------------------------------------- solver details


def test_lobpcg_agrees_with_dense():
    for sigma, seed in ((5, 0), (30, 1), (60, 2)):
        g = random_problem(n=120, degree=6, sigma_deg=sigma, seed=seed)
        R = _local(g)
        d = certify(R, g.edges, g.cam2_from_cam1, method="dense")
        lo = certify(R, g.edges, g.cam2_from_cam1, method="lobpcg")
        assert d.method == "dense eigvalsh" and lo.method == "lobpcg"
        assert d.certified == lo.certified
        assert lo.lambda_min == pytest.approx(d.lambda_min, abs=1e-6, rel=1e-3)
        assert lo.lambda_complement == pytest.approx(d.lambda_complement, abs=1e-6, rel=1e-3)
        # not critical: the whole space
        d = certify(g.gt_cam_from_world, g.edges, g.cam2_from_cam1, method="dense")
        lo = certify(g.gt_cam_from_world, g.edges, g.cam2_from_cam1, method="lobpcg")
        assert lo.lambda_min == pytest.approx(d.lambda_min, rel=1e-3)


def test_inliers_unsolved_cameras_components_and_weights():
    g = random_problem(n=40, degree=6, sigma_deg=5, seed=0)
    R = _local(g)
    base = certify(R, g.edges, g.cam2_from_cam1)
    assert base.certified
    # scaling the weights changes nothing (they are divided by their median)
    c = certify(R, g.edges, g.cam2_from_cam1, 7.0 * np.ones(g.n_edges))
    assert c.weight_scale == 7.0 and c.lambda_complement == pytest.approx(base.lambda_complement, rel=1e-9)
    # inliers: the problem on those edges only (a wrong edge added and masked out)
    bad = so3.random_rotations(1, np.random.default_rng(0))
    edges = np.vstack([g.edges, [[0, 1]]])
    rel = np.concatenate([g.cam2_from_cam1, bad])
    mask = np.r_[np.ones(g.n_edges, bool), False]
    c = certify(R, edges, rel, inliers=mask)
    assert c.certified and c.n_edges == g.n_edges and c.primal_cost == pytest.approx(base.primal_cost)
    assert not certify(R, edges, rel).certified  # with the wrong edge R is not even critical
    # an unsolved camera (NaN) and its edges are left out
    R_nan = R.copy()
    R_nan[3] = np.nan
    c = certify(R_nan, g.edges, g.cam2_from_cam1)
    touching = (g.edges == 3).any(axis=1)
    assert c.n_nodes == 39 and c.n_edges == g.n_edges - touching.sum()
    # two components: certified one by one, verdict of both
    h = random_problem(n=25, degree=5, sigma_deg=5, seed=1)
    R2 = np.concatenate([R, _local(h)])
    e2 = np.vstack([g.edges, h.edges + 40])
    rel2 = np.concatenate([g.cam2_from_cam1, h.cam2_from_cam1])
    c = certify(R2, e2, rel2)
    assert c.certified and c.n_components == 2 and c.n_nodes == 65
    edges_ring, rel_ring, R_ring = _ring(6)
    c = certify(np.concatenate([R, R_ring]), np.vstack([g.edges, edges_ring + 40]), np.concatenate([g.cam2_from_cam1, rel_ring]))
    assert not c.certified and c.n_components == 2
    # information matrices are not weights of the chordal cost
    with pytest.raises(ValueError, match="scalar"):
        certify(R, g.edges, g.cam2_from_cam1, np.repeat(np.eye(3)[None], g.n_edges, axis=0))
    with pytest.raises(ValueError):
        certify(R, g.edges, g.cam2_from_cam1, inliers=np.zeros(g.n_edges, bool))


def test_to_dict_and_graph_helper():
    g = random_problem(n=20, degree=4, sigma_deg=3, seed=0)
    R = _local(g)
    c = C.certify_graph(g, R)
    d = json.loads(json.dumps(c.to_dict()))
    assert d["certified"] is True and isinstance(d["lambda_min"], float) and d["reason"].startswith("certified")
    assert set(d) >= {"certified", "lambda_min", "tolerance", "duality_gap", "primal_cost", "dual_bound",
                      "stationarity", "seconds", "method", "reason"}
    d = certify(g.gt_cam_from_world, g.edges, g.cam2_from_cam1).to_dict()
    assert d["lambda_complement"] is None  # NaN -> null
    vg = ViewGraph.from_edges(g.edges[:, 0], g.edges[:, 1], g.cam2_from_cam1, 3.0 * np.ones(g.n_edges))
    assert C.certify_graph(vg, R, use_weights=True).weight_scale == 3.0


def test_refine_chordal_methods_reach_a_critical_point():
    g = random_problem(n=60, degree=6, sigma_deg=15, seed=3)
    R0 = average_rotations(g, method="l2").cam_from_world
    start = chordal_cost(R0, g.edges, g.cam2_from_cam1)
    for method in ("trust-region", "irls"):
        R, it, s = refine_chordal(R0, g.edges, g.cam2_from_cam1, method=method)
        assert s < 1e-10 and it > 0
        assert chordal_cost(R, g.edges, g.cam2_from_cam1) < start
        assert np.allclose(np.linalg.det(R), 1.0)
        assert certify(R, g.edges, g.cam2_from_cam1).certified
    R_nan = R0.copy()
    R_nan[5] = np.nan
    R, _, s = refine_chordal(R_nan, g.edges, g.cam2_from_cam1)
    assert np.isnan(R[5]).all() and np.isfinite(np.delete(R, 5, axis=0)).all() and s < 1e-10
