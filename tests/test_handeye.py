"""Conjugate rotation averaging (hand-eye): rotgraph.estimators.handeye, its readers and ``rotgraph handeye``.

Problems and reference costs are built with scipy (scalar-last quaternions) and plain numpy,
not with rotgraph, so the tests compare rotgraph against an independent reference.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.optimize import minimize
from scipy.spatial.transform import Rotation

from cli_helpers import assert_clean_error, run
from rotgraph.errors import InputError, UnsolvableError
from rotgraph.estimators.handeye import (
    METHODS,
    conditioning,
    handeye_residuals,
    handeye_translation_residuals,
    motions_from_poses,
    pose_residuals,
    solve_handeye,
)

EXACT_DEG = 1e-9


# ----------------------------------------------------------------------------- helpers


def rot(v) -> np.ndarray:
    return Rotation.from_rotvec(np.asarray(v, dtype=float)).as_matrix()


def angle_deg(A, B) -> float:
    """Geodesic angle between two rotations (degrees), accurate near 0."""
    return float(np.degrees(Rotation.from_matrix(A.T @ B).magnitude()))


def residuals_rad(S, L, R) -> np.ndarray:
    """theta_i = angle of R_i^T S^T L_i S."""
    return Rotation.from_matrix(np.swapaxes(R, 1, 2) @ S.T @ L @ S).magnitude()


def make_pairs(rng, n, sigma_deg=0.0, wrong=0.0, max_angle_deg=180.0):
    """S (Haar), robot motions L_i, camera motions R_i = S^T L_i S, tangent noise of
    sigma on both, and ``round(wrong n)`` camera motions replaced by Haar rotations."""
    S = Rotation.random(random_state=rng).as_matrix()
    axes = rng.standard_normal((n, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = rng.uniform(np.deg2rad(20), np.deg2rad(max_angle_deg), n)
    L = rot(axes * angles[:, None])
    R = S.T @ L @ S
    if sigma_deg:
        s = np.deg2rad(sigma_deg)
        L = L @ rot(s * rng.standard_normal((n, 3)))
        R = R @ rot(s * rng.standard_normal((n, 3)))
    bad = np.zeros(n, dtype=bool)
    k = int(round(wrong * n))
    if k:
        bad[rng.choice(n, k, replace=False)] = True
        R[bad] = Rotation.random(k, random_state=rng).as_matrix()
    return S, L, R, bad


def quats_wxyz(R, rng=None) -> np.ndarray:
    q = np.roll(Rotation.from_matrix(R).as_quat(), 1, axis=1)
    if rng is not None:
        q *= rng.choice([-1.0, 1.0], size=(len(q), 1))
    return q


def brute_force(cost, rng, starts=6):
    """Global minimiser of ``cost(S)`` over SO(3): Nelder-Mead on a rotation vector from
    random (Haar) starts (S = S0 exp(v), a good chart near each start), the best one
    polished from a re-centred chart."""
    found = []
    for S0 in Rotation.random(starts, random_state=rng).as_matrix():
        r = minimize(lambda v, S0=S0: cost(S0 @ rot(v)), np.zeros(3), method="Nelder-Mead",
                     options={"xatol": 1e-7, "fatol": 1e-12, "maxiter": 3000})
        found.append((r.fun, S0 @ rot(r.x)))
    S1 = min(found, key=lambda t: t[0])[1]
    r = minimize(lambda v: cost(S1 @ rot(v)), np.zeros(3), method="Nelder-Mead",
                 options={"xatol": 1e-12, "fatol": 1e-16, "maxiter": 3000})
    return r.fun, S1 @ rot(r.x)


def quaternion_cost(S, L, R, w):
    """sum w min |q(S^T L S) -+ q(R)|^2 (the quaternion closed form's own cost)."""
    a = Rotation.from_matrix(S.T @ L @ S).as_quat()
    b = Rotation.from_matrix(R).as_quat()
    d = np.minimum(((a - b) ** 2).sum(1), ((a + b) ** 2).sum(1))
    return float(w @ d)


def procrustes_cost(S, L, R, w):
    """sum w |log L - S log R|^2 (the axis-alignment closed form's own cost)."""
    aL = Rotation.from_matrix(L).as_rotvec()
    aR = Rotation.from_matrix(R).as_rotvec()
    return float(w @ ((aL - aR @ S.T) ** 2).sum(1))


def l2_cost(S, L, R, w):
    return float(w @ residuals_rad(S, L, R) ** 2)


def l1_cost(S, L, R, w):
    return float(w @ residuals_rad(S, L, R))


OWN_COST = {"quaternion": quaternion_cost, "procrustes": procrustes_cost, "l2": l2_cost, "l1": l1_cost}


# ----------------------------------------------------------------------------- exact data


@pytest.mark.parametrize("method", METHODS)
def test_noise_free_recovery(method, rng):
    for _ in range(3):
        S, L, R, _ = make_pairs(rng, int(rng.integers(3, 30)))
        res = solve_handeye(L, R, method=method)
        assert angle_deg(res.rotation, S) < EXACT_DEG
        assert res.residuals_deg.max() < EXACT_DEG
        assert res.inliers.all() and res.converged and res.warnings == ()
        assert res.quaternion[0] >= 0
        assert np.allclose(Rotation.from_quat(np.roll(res.quaternion, -1)).as_matrix(), res.rotation, atol=1e-14)


@pytest.mark.parametrize("method", METHODS)
def test_noise_free_quaternion_input_any_sign(method, rng):
    S, L, R, _ = make_pairs(rng, 12)
    res = solve_handeye(quats_wxyz(L, rng), quats_wxyz(R, rng), method=method)
    assert angle_deg(res.rotation, S) < EXACT_DEG


@pytest.mark.parametrize("method", METHODS)
def test_noise_free_half_turns(method, rng):
    """Rotations at and near pi: q and -q both have w ~ 0 and the log's axis is ambiguous."""
    S = Rotation.random(random_state=rng).as_matrix()
    axes = rng.standard_normal((10, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.pi - np.array([0, 1e-12, 1e-9, 1e-6, 1e-3, 0, 0, 1e-2, 1e-12, 0.3])
    L = rot(axes * angles[:, None])
    R = S.T @ L @ S
    res = solve_handeye(quats_wxyz(L, rng), quats_wxyz(R, rng), method=method)
    assert angle_deg(res.rotation, S) < EXACT_DEG


def test_the_direction_of_S(rng):
    """R_i = S^T L_i S: the log vectors satisfy log L_i = S log R_i, the angles are equal."""
    S, L, R, _ = make_pairs(rng, 6, max_angle_deg=150)
    aL = Rotation.from_matrix(L).as_rotvec()
    aR = Rotation.from_matrix(R).as_rotvec()
    assert np.allclose(aL, aR @ S.T, atol=1e-12)
    res = solve_handeye(L, R, method="quaternion")
    assert np.allclose(R, res.rotation.T @ L @ res.rotation, atol=1e-12)
    assert angle_deg(res.rotation, S) < EXACT_DEG
    assert np.allclose(handeye_residuals(S, L, R), 0, atol=1e-12)
    assert np.allclose(handeye_residuals(S, L, R[::-1]), residuals_rad(S, L, R[::-1]), atol=1e-12)


# ----------------------------------------------------------------------------- brute force


@pytest.mark.parametrize("method", ["quaternion", "procrustes", "l2", "l1"])
def test_minimises_its_own_cost(method, rng):
    """The closed forms are global minimisers of their costs; l2 and l1 reach the same
    minimum as a multi-start brute-force search."""
    S, L, R, _ = make_pairs(rng, 8, sigma_deg=6.0, max_angle_deg=150)
    w = rng.uniform(0.3, 2.0, 8)
    res = solve_handeye(L, R, method=method, weights=w)
    cost = OWN_COST[method]
    ours = cost(res.rotation, L, R, w)
    best, S_best = brute_force(lambda X: cost(X, L, R, w), rng)
    assert ours <= best + 1e-12 * max(1.0, best)
    assert np.isclose(res.cost, ours, rtol=1e-9, atol=1e-15)
    assert angle_deg(res.rotation, S_best) < 1e-4


# ----------------------------------------------------------------------------- invariances


@pytest.mark.parametrize("method", METHODS)
def test_common_rotation_of_the_robot_motions(method, rng):
    """L_i -> W L_i W^T gives S -> W S (R_i = (W S)^T (W L_i W^T) (W S))."""
    S, L, R, _ = make_pairs(rng, 15, sigma_deg=2.0, wrong=0.2 if method == "robust" else 0.0)
    W = Rotation.random(random_state=rng).as_matrix()
    a = solve_handeye(L, R, method=method)
    b = solve_handeye(W @ L @ W.T, R, method=method)
    assert angle_deg(b.rotation, W @ a.rotation) < 1e-7
    assert np.allclose(a.residuals_deg, b.residuals_deg, atol=1e-7)
    assert np.array_equal(a.inliers, b.inliers)


@pytest.mark.parametrize("method", METHODS)
def test_common_rotation_of_the_camera_motions(method, rng):
    """R_i -> V R_i V^T gives S -> S V^T (V R_i V^T = (S V^T)^T L_i (S V^T))."""
    S, L, R, _ = make_pairs(rng, 15, sigma_deg=2.0, wrong=0.2 if method == "robust" else 0.0)
    V = Rotation.random(random_state=rng).as_matrix()
    a = solve_handeye(L, R, method=method)
    b = solve_handeye(L, V @ R @ V.T, method=method)
    assert angle_deg(b.rotation, a.rotation @ V.T) < 1e-7
    assert np.allclose(a.residuals_deg, b.residuals_deg, atol=1e-7)


@pytest.mark.parametrize("method", ["quaternion", "l2", "l1", "robust"])
def test_swapping_and_inverting(method, rng):
    """(R, L) gives S^T; (L^T, R^T) gives S (the same conjugation)."""
    S, L, R, _ = make_pairs(rng, 12, sigma_deg=2.0)
    a = solve_handeye(L, R, method=method)
    b = solve_handeye(R, L, method=method)
    c = solve_handeye(np.swapaxes(L, 1, 2), np.swapaxes(R, 1, 2), method=method)
    assert angle_deg(b.rotation, a.rotation.T) < 1e-7
    assert angle_deg(c.rotation, a.rotation) < 1e-7


@pytest.mark.parametrize("method", METHODS)
def test_q_and_minus_q(method, rng):
    """Flipping the sign of any input quaternion changes nothing."""
    S, L, R, _ = make_pairs(rng, 14, sigma_deg=3.0, wrong=0.2 if method == "robust" else 0.0)
    qL, qR = quats_wxyz(L), quats_wxyz(R)
    a = solve_handeye(qL, qR, method=method)
    for _ in range(3):
        b = solve_handeye(qL * rng.choice([-1.0, 1.0], (14, 1)), qR * rng.choice([-1.0, 1.0], (14, 1)), method=method)
        assert np.allclose(a.quaternion, b.quaternion, atol=1e-12)
        assert np.allclose(a.residuals_deg, b.residuals_deg, atol=1e-9)
    m = solve_handeye(L, R, method=method)  # matrices give the same
    assert angle_deg(m.rotation, a.rotation) < 1e-9


# ----------------------------------------------------------------------------- weights


@pytest.mark.parametrize("method", ["quaternion", "procrustes", "l2", "l1"])
def test_integer_weights_equal_repeated_pairs(method, rng):
    S, L, R, _ = make_pairs(rng, 7, sigma_deg=4.0, max_angle_deg=150)
    k = np.array([1, 3, 1, 2, 1, 4, 2])
    a = solve_handeye(L, R, method=method, weights=k)
    b = solve_handeye(np.repeat(L, k, 0), np.repeat(R, k, 0), method=method)
    assert angle_deg(a.rotation, b.rotation) < 1e-7
    c = solve_handeye(L, R, method=method, weights=7.5 * k)  # scaling changes only the cost
    assert angle_deg(a.rotation, c.rotation) < 1e-7
    assert np.isclose(c.cost, 7.5 * a.cost, rtol=1e-6)


@pytest.mark.parametrize("method", METHODS)
def test_zero_weight_ignores_a_pair_but_reports_it(method, rng):
    S, L, R, _ = make_pairs(rng, 10, sigma_deg=1.0)
    R[3] = Rotation.random(random_state=rng).as_matrix()  # a wrong pair, weighted out
    w = np.ones(10)
    w[3] = 0
    a = solve_handeye(L, R, method=method, weights=w)
    keep = np.arange(10) != 3
    b = solve_handeye(L[keep], R[keep], method=method)
    assert angle_deg(a.rotation, b.rotation) < 1e-7
    assert len(a.residuals_deg) == 10 and a.residuals_deg[3] > 5


def test_bad_weights_and_shapes(rng):
    S, L, R, _ = make_pairs(rng, 5)
    for w, msg in [(np.ones(4), "shape"), (-np.ones(5), "negative"), (np.zeros(5), "zero"), ([1, 1, np.nan, 1, 1], "finite")]:
        with pytest.raises(InputError, match=msg):
            solve_handeye(L, R, weights=w)
    with pytest.raises(InputError, match="one pair per index"):
        solve_handeye(L, R[:4])
    with pytest.raises(InputError):
        solve_handeye(L[:, :2], R)
    with pytest.raises(ValueError, match="unknown method"):
        solve_handeye(L, R, method="tsai")


# ----------------------------------------------------------------------------- robust


@pytest.mark.parametrize("wrong", [0.2, 0.4, 0.6])
def test_robust_survives_wrong_pairs_and_flags_them(wrong, rng):
    for _ in range(2):
        S, L, R, bad = make_pairs(rng, 50, sigma_deg=1.0, wrong=wrong)
        res = solve_handeye(L, R, method="robust")
        assert not res.inliers[bad].any()  # every wrong pair flagged
        assert (~res.inliers[~bad]).sum() <= 1  # at most one false alarm (99.9 % threshold)
        assert res.n_inliers == res.inliers.sum()
        # As good as an oracle that knows the wrong pairs: L2 on the flagged inliers.
        oracle = solve_handeye(L[res.inliers], R[res.inliers], method="l2")
        assert angle_deg(res.rotation, oracle.rotation) < 1e-7
        assert angle_deg(res.rotation, S) < 2.0


def test_robust_noise_free_with_wrong_pairs_is_exact(rng):
    S, L, R, bad = make_pairs(rng, 40, wrong=0.4)
    res = solve_handeye(L, R)
    assert angle_deg(res.rotation, S) < EXACT_DEG
    assert np.array_equal(res.inliers, ~bad)


@pytest.mark.parametrize("loss", ["truncated_l2", "cauchy", "geman_mcclure", "huber"])
def test_robust_losses_and_options(loss, rng):
    S, L, R, bad = make_pairs(rng, 40, sigma_deg=0.5, wrong=0.25)
    res = solve_handeye(L, R, loss=loss)
    assert not res.inliers[bad].any()
    # Huber does not redescend: every wrong pair still pulls with a bounded force.
    assert angle_deg(res.rotation, S) < (2.0 if loss == "huber" else 0.5)
    fixed = solve_handeye(L, R, loss=loss, threshold_deg=10.0, scale_deg=3.0)
    assert fixed.threshold_deg == 10.0 and fixed.scale_deg == 3.0
    assert np.array_equal(fixed.inliers, fixed.residuals_deg <= 10.0)
    assert not fixed.inliers[bad].any()


def test_robust_many_pairs_is_seeded(rng):
    S, L, R, bad = make_pairs(rng, 300, sigma_deg=0.5, wrong=0.3)  # more pairs of pairs than hypotheses
    a = solve_handeye(L, R, seed=1)
    b = solve_handeye(L, R, seed=1)
    assert np.array_equal(a.quaternion, b.quaternion)
    assert angle_deg(a.rotation, S) < 0.3 and not a.inliers[bad].any()


def test_threshold_flags_for_other_methods(rng):
    S, L, R, bad = make_pairs(rng, 20, sigma_deg=0.5, wrong=0.1)
    res = solve_handeye(L, R, method="l1", threshold_deg=5.0)
    assert np.array_equal(res.inliers, res.residuals_deg <= 5.0)
    assert solve_handeye(L, R, method="l1").inliers.all()


# ----------------------------------------------------------------------------- degeneracy


def test_parallel_axes_are_unsolvable(rng):
    S = Rotation.random(random_state=rng).as_matrix()
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    L = rot(np.outer(rng.uniform(0.2, 2.5, 10) * rng.choice([-1, 1], 10), axis))
    R = S.T @ L @ S
    for method in METHODS:
        with pytest.raises(UnsolvableError, match="parallel"):
            solve_handeye(L, R, method=method)
    # within 1e-9 rad of parallel: still degenerate
    L2 = L @ rot(1e-9 * rng.standard_normal((10, 3)))
    with pytest.raises(UnsolvableError, match="parallel"):
        solve_handeye(L2, S.T @ L2 @ S)


def test_tiny_rotations_are_unsolvable(rng):
    S = Rotation.random(random_state=rng).as_matrix()
    L = rot(1e-9 * rng.standard_normal((10, 3)))
    with pytest.raises(UnsolvableError, match="too small"):
        solve_handeye(L, S.T @ L @ S)
    with pytest.raises(UnsolvableError, match="two pairs"):
        solve_handeye(L[:1], L[:1])


def test_nearly_degenerate_warns_but_solves(rng):
    S = Rotation.random(random_state=rng).as_matrix()
    axes = np.array([0.0, 0.0, 1.0]) + np.deg2rad(0.3) * rng.standard_normal((10, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    L = rot(axes * rng.uniform(0.3, 2.0, (10, 1)))
    res = solve_handeye(L, S.T @ L @ S, method="l2")
    assert any("nearly degenerate" in w for w in res.warnings)
    assert res.conditioning < 0.02
    assert angle_deg(res.rotation, S) < 1e-7
    assert conditioning(L)[0] == pytest.approx(res.conditioning, rel=1e-6)


def test_robust_judges_the_inliers_alone(rng):
    """Outliers can make the data look well-conditioned while the inliers are degenerate."""
    S = Rotation.random(random_state=rng).as_matrix()
    L = rot(np.outer(rng.uniform(0.3, 2.5, 12), [0.0, 0.6, 0.8]))
    R = S.T @ L @ S
    L = np.concatenate([L, Rotation.random(4, random_state=rng).as_matrix()])
    R = np.concatenate([R, Rotation.random(4, random_state=rng).as_matrix()])
    with pytest.raises(UnsolvableError, match="inlier"):
        solve_handeye(L, R, method="robust")


# ----------------------------------------------------------------------------- poses


def make_poses(rng, n):
    """base_from_gripper G_k, cam_from_target C_k = X^-1 G_k^-1 T as 4x4, X = gripper_from_camera."""
    X = np.eye(4)
    X[:3, :3] = Rotation.random(random_state=rng).as_matrix()
    X[:3, 3] = rng.normal(0, 0.05, 3)
    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=rng).as_matrix()
    T[:3, 3] = [0.6, 0.0, 0.0]
    G = np.tile(np.eye(4), (n, 1, 1))
    G[:, :3, :3] = Rotation.random(n, random_state=rng).as_matrix()
    G[:, :3, 3] = rng.normal(0, 0.2, (n, 3))
    C = np.linalg.inv(X) @ np.linalg.inv(G) @ T
    return X, G, C


def test_motions_from_poses_conventions(rng):
    X, G, C = make_poses(rng, 6)
    m = motions_from_poses(G, C)
    assert m.robot.shape == (5, 3, 3) and np.array_equal(m.pairs, [[k, k + 1] for k in range(5)])
    i, j = 1, 2
    assert np.allclose(m.robot[1], G[j, :3, :3].T @ G[i, :3, :3])  # gripper_j_from_gripper_i
    assert np.allclose(m.camera[1], C[j, :3, :3] @ C[i, :3, :3].T)  # cam_j_from_cam_i
    S = X[:3, :3]
    assert np.allclose(m.camera, S.T @ m.robot @ S, atol=1e-12)  # camera = S^T robot S, S = gripper_from_camera
    a = motions_from_poses(G, C, pairs="all")
    assert len(a.pairs) == 15 and np.allclose(a.camera, S.T @ a.robot @ S, atol=1e-12)
    for method in METHODS:
        assert angle_deg(solve_handeye(a.robot, a.camera, method=method).rotation, S) < EXACT_DEG
    q = motions_from_poses(quats_wxyz(G[:, :3, :3]), quats_wxyz(C[:, :3, :3]))
    assert np.allclose(q.robot, m.robot, atol=1e-12)
    with pytest.raises(InputError):
        motions_from_poses(G, C[:4])


def test_eye_to_hand_convention(rng):
    """Camera fixed on the base, target on the gripper: pass gripper_from_base; S = base_from_camera."""
    n = 8
    Y = Rotation.random(random_state=rng).as_matrix()  # base_from_camera
    Z = Rotation.random(random_state=rng).as_matrix()  # gripper_from_target
    G = Rotation.random(n, random_state=rng).as_matrix()  # base_from_gripper
    C = Y.T @ G @ Z  # cam_from_target = cam_from_base base_from_gripper gripper_from_target
    m = motions_from_poses(np.swapaxes(G, 1, 2), C)
    assert angle_deg(solve_handeye(m.robot, m.camera).rotation, Y) < EXACT_DEG


def test_agrees_with_opencv_calibrate_hand_eye(rng):
    cv2 = pytest.importorskip("cv2")
    X, G, C = make_poses(rng, 10)
    m = motions_from_poses(G, C, pairs="all")
    res = solve_handeye(m.robot, m.camera)
    for method in (cv2.CALIB_HAND_EYE_TSAI, cv2.CALIB_HAND_EYE_PARK, cv2.CALIB_HAND_EYE_DANIILIDIS):
        R_cam2gripper, _ = cv2.calibrateHandEye(list(G[:, :3, :3]), list(G[:, :3, 3]), list(C[:, :3, :3]), list(C[:, :3, 3]),
                                                method=method)
        assert angle_deg(res.rotation, R_cam2gripper) < 1e-8  # S is OpenCV's R_cam2gripper
    assert angle_deg(res.rotation, X[:3, :3]) < EXACT_DEG


def test_pose_residuals():
    # poses 0..4, pose 3 wrong: every motion with pose 3 is an outlier
    pairs = np.array([(i, j) for i in range(5) for j in range(i + 1, 5)])
    wrong = (pairs == 3).any(axis=1)
    res_deg = np.where(wrong, 40.0, 0.5) + 0.01 * np.arange(len(pairs))
    inl = ~wrong
    inl[np.flatnonzero(wrong)[0]] = True  # one chance agreement of the wrong pose
    r, ok = pose_residuals(res_deg, inl, pairs, 6)
    assert ok.tolist() == [True, True, True, False, True, False]  # pose 5 is in no motion
    assert np.all(r[[0, 1, 2, 4]] < 1) and r[3] > 30 and np.isnan(r[5])
    # consecutive: a pose is an inlier when one of its two motions is
    r, ok = pose_residuals([0.1, 50, 60, 0.2], [True, False, False, True], [[0, 1], [1, 2], [2, 3], [3, 4]], 5)
    assert ok.tolist() == [True, True, False, True, True]


# ----------------------------------------------------------------------------- translations (joint estimate)


def noisy_poses(rng, n, sigma_deg, t_sigma, wrong=0, spread_deg=None):
    """make_poses with tangent noise of sigma_deg on every measured rotation, N(0, t_sigma^2)
    on every translation, and ``wrong`` camera poses replaced by unrelated ones. With
    ``spread_deg`` the gripper orientations are ``exp(N(0, spread^2 I)) R0`` (a robot whose
    camera keeps the target in view) instead of Haar."""
    X, G, C = make_poses(rng, n)
    if spread_deg is not None:
        T = G[0] @ X @ C[0]  # base_from_target
        R0 = Rotation.random(random_state=rng).as_matrix()
        G[:, :3, :3] = rot(np.deg2rad(spread_deg) * rng.standard_normal((n, 3))) @ R0
        C = np.linalg.inv(X) @ np.linalg.inv(G) @ T
    G0, C0 = G.copy(), C.copy()
    s = np.deg2rad(sigma_deg)
    for P in (G, C):
        P[:, :3, :3] = P[:, :3, :3] @ rot(s * rng.standard_normal((n, 3)))
        P[:, :3, 3] += t_sigma * rng.standard_normal((n, 3))
    bad = np.zeros(n, dtype=bool)
    if wrong:
        bad[rng.choice(n, wrong, replace=False)] = True
        C[bad, :3, :3] = Rotation.random(wrong, random_state=rng).as_matrix()
        C[bad, :3, 3] = rng.normal(0, 0.3, (wrong, 3))
    return X, G, C, bad, G0, C0


def solve_poses(G, C, pairs="all", **kw):
    m = motions_from_poses(G, C, pairs=pairs)
    return solve_handeye(m.robot, m.camera, robot_translations=m.robot_translations,
                         camera_translations=m.camera_translations, **kw), m


def test_motion_translations_satisfy_the_hand_eye_equation(rng):
    """A X = X B: L t_X + t_L = S t_R + t_X for every motion, with motions_from_poses' conventions."""
    X, G, C = make_poses(rng, 6)
    m = motions_from_poses(G, C, pairs="all")
    S, t = X[:3, :3], X[:3, 3]
    i, j = m.pairs.T
    A = np.linalg.inv(G[j]) @ G[i]  # gripper_j_from_gripper_i
    B = C[j] @ np.linalg.inv(C[i])  # cam_j_from_cam_i
    assert np.allclose(m.robot_translations, A[:, :3, 3], atol=1e-12)
    assert np.allclose(m.camera_translations, B[:, :3, 3], atol=1e-12)
    assert np.allclose(A @ X, X @ B, atol=1e-12)
    lhs = m.robot @ t + m.robot_translations
    assert np.allclose(lhs, m.camera_translations @ S.T + t, atol=1e-12)
    assert np.allclose(handeye_translation_residuals(S, t, m.robot, m.robot_translations, m.camera_translations), 0,
                       atol=1e-12)
    # rotations only (or quaternions): no translations
    r = motions_from_poses(G[:, :3, :3], quats_wxyz(C[:, :3, :3]))
    assert r.robot_translations is None and r.camera_translations is None


@pytest.mark.parametrize("wrong", [0, 4])
def test_joint_noise_free_is_exact(rng, wrong):
    X, G, C, bad, _, _ = noisy_poses(rng, 12, 0.0, 0.0, wrong)
    res, m = solve_poses(G, C)
    assert res.joint and res.method == "robust"
    assert angle_deg(res.rotation, X[:3, :3]) < EXACT_DEG
    assert np.linalg.norm(res.translation - X[:3, 3]) < 1e-12
    mbad = bad[m.pairs].any(axis=1)
    assert np.array_equal(res.inliers, ~mbad)
    assert res.translation_residuals[~mbad].max() < 1e-12 and res.translation_inliers[~mbad].all()
    for method in ("quaternion", "l2") if not wrong else ():  # rotation-only methods: t_X given S
        r, _ = solve_poses(G, C, method=method)
        assert not r.joint and np.linalg.norm(r.translation - X[:3, 3]) < 1e-12


def _errors_over_seeds(rng, seeds, n, sigma_deg, t_sigma):
    joint, rot_only, t_joint, t_rot = [], [], [], []
    for _ in range(seeds):
        X, G, C, _, _, _ = noisy_poses(rng, n, sigma_deg, t_sigma, spread_deg=30.0)
        a, _ = solve_poses(G, C)
        b, _ = solve_poses(G, C, rotation_only=True)
        assert a.joint and not b.joint
        joint.append(angle_deg(a.rotation, X[:3, :3]))
        rot_only.append(angle_deg(b.rotation, X[:3, :3]))
        t_joint.append(np.linalg.norm(a.translation - X[:3, 3]))
        t_rot.append(np.linalg.norm(b.translation - X[:3, 3]))
    rms = lambda x: float(np.sqrt(np.mean(np.square(x))))  # noqa: E731
    return rms(joint), rms(rot_only), rms(t_joint), rms(t_rot)


def test_joint_beats_rotation_only_with_informative_translations(rng):
    """1 deg rotation noise, 0.5 mm translation noise, orientations within about 30 deg: the
    translations pin S down better (RMS error over seeds 0.68-0.84 x rotation-only over
    ten random streams; t_X 0.93-1.06 x)."""
    joint, rot_only, t_joint, t_rot = _errors_over_seeds(rng, 12, 10, 1.0, 0.0005)
    assert joint < 0.9 * rot_only
    assert t_joint < 1.15 * t_rot


def test_joint_does_not_degrade_with_useless_translations(rng):
    """Translation noise of 1 m (robot and camera 0.2-0.6 m apart): the translation block
    gets a weight near zero and the joint estimate stays with the rotation-only one (RMS
    error 0.99-1.01 x over ten random streams)."""
    joint, rot_only, _, _ = _errors_over_seeds(rng, 12, 10, 1.0, 1.0)
    assert joint <= 1.03 * rot_only


def test_joint_is_a_minimum_of_its_cost(rng):
    """The joint estimate minimises sum theta^2 / sigma_r^2 + |e|^2 / sigma_t^2 over the pairs
    it used (rotation block: the inliers; translation block: those also within the
    translation threshold) with its reported sigmas: a Nelder-Mead search around it finds
    nothing lower."""
    X, G, C, _, _, _ = noisy_poses(rng, 8, 2.0, 0.002)
    res, m = solve_poses(G, C)
    inl, used = res.inliers, res.inliers & res.translation_inliers
    L, R = m.robot[inl], m.camera[inl]
    Lt, tL, tR = m.robot[used], m.robot_translations[used], m.camera_translations[used]
    sr, st = np.deg2rad(res.sigma_deg), res.sigma_translation

    def cost(x):
        S = res.rotation @ rot(x[:3] * 1e-3)
        t = res.translation + x[3:] * st
        e = Lt @ t - t - tR @ S.T + tL
        return float((residuals_rad(S, L, R) ** 2).sum() / sr**2 + (e**2).sum() / st**2)

    c0 = cost(np.zeros(6))
    assert np.isclose(res.cost, c0, rtol=1e-9)
    r = minimize(cost, np.zeros(6), method="Nelder-Mead", options={"xatol": 1e-9, "fatol": 1e-13, "maxiter": 4000})
    assert r.fun >= c0 - 1e-9 * c0
    assert np.linalg.norm(r.x) < 1e-3


def test_joint_is_unit_free(rng):
    """Translations in mm instead of m: the same S, t_X scaled (the noise levels are estimated)."""
    X, G, C, _, _, _ = noisy_poses(rng, 9, 1.0, 0.001)
    a, _ = solve_poses(G, C)
    G2, C2 = G.copy(), C.copy()
    G2[:, :3, 3] *= 1000.0
    C2[:, :3, 3] *= 1000.0
    b, _ = solve_poses(G2, C2)
    assert angle_deg(a.rotation, b.rotation) < 1e-7
    assert np.allclose(b.translation, 1000.0 * a.translation, rtol=1e-6, atol=1e-9)
    assert b.sigma_translation == pytest.approx(1000.0 * a.sigma_translation, rel=1e-6)


def test_joint_with_wrong_poses_and_a_bad_translation(rng):
    """Wrong camera poses stay rejected; a robot pose whose translation is 10 cm off (its
    rotation right; the motions about 8 sigma_t off) is flagged by the translation test and
    does not pull S."""
    X, G, C, bad, _, _ = noisy_poses(rng, 15, 0.5, 0.0005, wrong=3)
    k = int(np.flatnonzero(~bad)[0])
    G[k, :3, 3] += [0.1, 0.0, 0.0]
    res, m = solve_poses(G, C)
    mbad = bad[m.pairs].any(axis=1)
    assert not res.inliers[mbad].any()
    with_k = (m.pairs == k).any(axis=1)
    assert not res.translation_inliers[with_k & ~mbad].any()
    assert res.translation_inliers[~with_k & ~mbad].mean() > 0.95
    G[k, :3, 3] -= [0.1, 0.0, 0.0]
    ref, _ = solve_poses(G, C)  # the same data without the bad translation (its motions then count)
    assert angle_deg(res.rotation, ref.rotation) < 0.15  # 0.01-0.08 over 16 random streams
    assert angle_deg(res.rotation, X[:3, :3]) < 1.0


def test_translations_that_say_nothing_about_S(rng):
    """All translations zero: no joint stage (a warning), S from the rotations, t_X = 0."""
    X, G, C, _, _, _ = noisy_poses(rng, 8, 0.5, 0.0)
    G[:, :3, 3] = 0.0
    C[:, :3, 3] = 0.0
    res, _ = solve_poses(G, C)
    ref, _ = solve_poses(G[:, :3, :3], C[:, :3, :3])  # rotations only
    assert not res.joint and any("zero" in w for w in res.warnings)
    assert ref.translation is None and not ref.joint
    assert angle_deg(res.rotation, ref.rotation) < 1e-12
    assert np.allclose(res.translation, 0.0, atol=1e-15)


def test_bad_translations():
    L = rot(np.eye(3))
    with pytest.raises(InputError, match="both"):
        solve_handeye(L, L, robot_translations=np.zeros((3, 3)))
    with pytest.raises(InputError, match="shape"):
        solve_handeye(L, L, robot_translations=np.zeros((3, 2)), camera_translations=np.zeros((3, 3)))
    with pytest.raises(InputError, match="finite"):
        solve_handeye(L, L, robot_translations=np.full((3, 3), np.nan), camera_translations=np.zeros((3, 3)))


# ----------------------------------------------------------------------------- command line


def write_quats(path, R, rng=None, weights=None, header="# qw qx qy qz\n"):
    q = quats_wxyz(R, rng)
    lines = [" ".join(repr(float(v)) for v in row) + ("" if weights is None else f" {weights[k]}") for k, row in enumerate(q)]
    path.write_text(header + "\n".join(lines) + "\n")


@pytest.fixture
def motion_files(tmp_path, rng):
    S, L, R, bad = make_pairs(rng, 12, sigma_deg=0.2, wrong=0.25)
    a, b = tmp_path / "robot.txt", tmp_path / "camera.txt"
    write_quats(a, L, rng)
    write_quats(b, R, rng)
    return S, a, b, bad


def test_cli_json(motion_files):
    S, a, b, bad = motion_files
    r = run("handeye", a, b, "--json")
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    for key in ("quaternion", "residuals_deg", "inlier", "method", "n_pairs", "n_inliers", "cost", "warnings"):
        assert key in out
    assert out["n_pairs"] == 12 and len(out["residuals_deg"]) == 12 and len(out["inlier"]) == 12
    assert out["inlier"] == (~bad).tolist() and out["n_inliers"] == int((~bad).sum())
    assert out["translation"] is None  # motions without translations
    q = np.array(out["quaternion"])
    assert q[0] >= 0
    assert angle_deg(Rotation.from_quat(np.roll(q, -1)).as_matrix(), S) < 0.5


@pytest.mark.parametrize("method", METHODS)
def test_cli_methods_and_text_output(motion_files, method):
    S, a, b, bad = motion_files
    r = run("handeye", a, b, "--method", method)
    assert r.exit_code == 0, r.output
    lines = r.stdout.splitlines()
    q = np.array([float(v) for v in lines[0].split()])
    assert q.shape == (4,) and q[0] >= 0
    assert all(line.startswith("# ") for line in lines[1:]) and "12 pairs" in lines[1]
    if method == "robust":
        assert "outlier pairs at lines" in r.stdout


def test_cli_csv_with_weights(tmp_path, rng):
    S, L, R, _ = make_pairs(rng, 8)
    for name, X in (("a.csv", L), ("b.csv", R)):
        q = quats_wxyz(X)
        (tmp_path / name).write_text("name,qw,qx,qy,qz,weight\n" + "".join(f"m{k},{w},{x},{y},{z},2\n" for k, (w, x, y, z) in enumerate(q)))
    r = run("handeye", tmp_path / "a.csv", tmp_path / "b.csv", "--json", "--method", "l2")
    assert r.exit_code == 0, r.output
    q = np.array(json.loads(r.stdout)["quaternion"])
    assert angle_deg(Rotation.from_quat(np.roll(q, -1)).as_matrix(), S) < EXACT_DEG


@pytest.mark.parametrize("layout", ["4x4", "3x4", "qt", "csv"])
def test_cli_poses(tmp_path, rng, layout):
    X, G, C = make_poses(rng, 7)
    C[4, :3, :3] = Rotation.random(random_state=rng).as_matrix()  # a wrong camera pose
    for name, P in (("robot", G), ("camera", C)):
        if layout == "4x4":
            text = "".join(" ".join(repr(float(v)) for v in M.ravel()) + "\n" for M in P)
        elif layout == "3x4":
            text = "".join(" ".join(repr(float(v)) for v in M[:3].ravel()) + "\n" for M in P)
        elif layout == "qt":
            q = quats_wxyz(P[:, :3, :3], rng)
            text = "".join(" ".join(repr(float(v)) for v in (*qq, *M[:3, 3])) + "\n" for qq, M in zip(q, P))
        else:
            q = quats_wxyz(P[:, :3, :3], rng)
            text = "qw,qx,qy,qz,tx,ty,tz\n" + "".join(",".join(repr(float(v)) for v in (*qq, *M[:3, 3])) + "\n" for qq, M in zip(q, P))
        (tmp_path / f"{name}.txt").write_text(text)
    r = run("handeye", tmp_path / "robot.txt", tmp_path / "camera.txt", "--poses", "--json")
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    q = np.array(out["quaternion"])
    assert angle_deg(Rotation.from_quat(np.roll(q, -1)).as_matrix(), X[:3, :3]) < EXACT_DEG
    assert out["n_pairs"] == 7 and out["inlier"] == [True] * 4 + [False] + [True] * 2
    assert out["motions"]["n_motions"] == 21 and len(out["motions"]["pairs"]) == 21
    # the translation of gripper_from_camera, estimated jointly with S
    assert out["joint"] is True and np.linalg.norm(np.array(out["translation"]) - X[:3, 3]) < 1e-9
    assert len(out["translation_residuals"]) == 7 and out["translation_inlier"][:4] == [True] * 4
    assert len(out["motions"]["translation_residuals"]) == 21
    r = run("handeye", tmp_path / "robot.txt", tmp_path / "camera.txt", "--poses", "--pairs", "consecutive", "--json")
    assert json.loads(r.stdout)["motions"]["n_motions"] == 6


def test_cli_poses_translation_and_rotation_only(tmp_path, rng):
    X, G, C, _, _, _ = noisy_poses(rng, 10, 1.0, 0.0005, spread_deg=30.0)
    for name, P in (("robot.txt", G), ("camera.txt", C)):
        (tmp_path / name).write_text("".join(" ".join(repr(float(v)) for v in M.ravel()) + "\n" for M in P))
    a, b = tmp_path / "robot.txt", tmp_path / "camera.txt"
    joint = json.loads(run("handeye", a, b, "--poses", "--json").stdout)
    rot_only = json.loads(run("handeye", a, b, "--poses", "--json", "--rotation-only").stdout)
    ref, _ = solve_poses(G, C)
    ref_rot, _ = solve_poses(G, C, rotation_only=True)
    for out, res, is_joint in ((joint, ref, True), (rot_only, ref_rot, False)):
        assert out["joint"] is is_joint and out["method"] == "robust"
        assert np.allclose(out["quaternion"], res.quaternion, atol=1e-12)
        assert np.allclose(out["translation"], res.translation, atol=1e-12)
        assert out["sigma_translation"] > 0 and out["sigma_deg"] > 0
    assert np.linalg.norm(np.array(joint["translation"]) - X[:3, 3]) < 0.02
    text = run("handeye", a, b, "--poses").stdout.splitlines()
    assert text[1].startswith("# translation ") and text[1].endswith("(jointly with S)")
    assert np.allclose([float(v) for v in text[1].split()[2:5]], joint["translation"], atol=1e-12)
    # a CSV without tx,ty,tz: rotations only, no translation
    for name, P in (("robot.csv", G), ("camera.csv", C)):
        q = quats_wxyz(P[:, :3, :3])
        (tmp_path / name).write_text("qw,qx,qy,qz\n" + "".join(",".join(repr(float(v)) for v in row) + "\n" for row in q))
    out = json.loads(run("handeye", tmp_path / "robot.csv", tmp_path / "camera.csv", "--poses", "--json").stdout)
    assert out["translation"] is None and "joint" not in out and out["warnings"] == []
    assert np.allclose(out["quaternion"], ref_rot.quaternion, atol=1e-9)
    # translations in one file only: rotations alone, with a warning naming the other
    q = quats_wxyz(G[:, :3, :3])
    (tmp_path / "robot.csv").write_text("qw,qx,qy,qz,tx,ty,tz\n" + "".join(
        ",".join(repr(float(v)) for v in (*qq, *M[:3, 3])) + "\n" for qq, M in zip(q, G)))
    out = json.loads(run("handeye", tmp_path / "robot.csv", tmp_path / "camera.csv", "--poses", "--json").stdout)
    assert out["translation"] is None and any("camera.csv has no translations" in w for w in out["warnings"])


def test_solve_handeye_files_is_what_the_cli_prints(tmp_path, rng):
    """The library function behind ``rotgraph handeye`` (#14): per-pose residuals and flags
    from the motions', its to_dict the CLI's JSON (but the timing)."""
    from rotgraph.pipeline.handeye import solve_handeye_files

    X, G, C, _, _, _ = noisy_poses(rng, 8, 0.5, 0.0005, wrong=1)
    for name, P in (("robot.txt", G), ("camera.txt", C)):
        (tmp_path / name).write_text("# pose\n" + "".join(" ".join(repr(float(v)) for v in M.ravel()) + "\n" for M in P))
    a, b = tmp_path / "robot.txt", tmp_path / "camera.txt"
    out = solve_handeye_files(a, b, poses=True)
    ref, m = solve_poses(G, C)
    assert np.allclose(out.result.quaternion, ref.quaternion, atol=1e-12) and out.result.joint
    res, inl = pose_residuals(ref.residuals_deg, ref.inliers, m.pairs, 8)
    assert np.allclose(out.residuals_deg, res, atol=1e-9) and out.inliers.tolist() == inl.tolist()
    assert out.lines == list(range(2, 10)) and out.motion_pairs.tolist() == m.pairs.tolist()
    assert len(out.translation_residuals) == 8 and out.seconds > 0
    cli = json.loads(run("handeye", a, b, "--poses", "--json").stdout)
    mine = out.to_dict()
    cli.pop("seconds"), mine.pop("seconds")
    assert json.loads(json.dumps(mine)) == cli
    q = solve_handeye_files(a, b, poses=True, pairs="consecutive", method="l2")
    assert q.loss is None and len(q.result.residuals_deg) == 7 and "loss" not in q.to_dict()


@pytest.mark.parametrize(
    "which, content, line",
    [
        ("a", "1 0 0 0\n0.5 0.5 0.5\n1 0 0 0\n", 2),
        ("b", "1 0 0 0\n1 0 0 0\n1 0 x 0\n", 3),
        ("a", "# c\n1 0 0 0\n0 0 0 0\n1 0 0 0\n", 3),
        ("b", "1 0 0 0\n1 0 0 0 -1\n1 0 0 0\n", 2),
        ("a", "", 1),
    ],
)
def test_cli_bad_motion_line(tmp_path, which, content, line):
    good = "1 0 0 0\n0 1 0 0\n0 0 1 0\n"
    a, b = tmp_path / "a.txt", tmp_path / "b.txt"
    a.write_text(content if which == "a" else good)
    b.write_text(content if which == "b" else good)
    assert_clean_error(run("handeye", a, b), a if which == "a" else b, line)


@pytest.mark.parametrize(
    "content, line",
    [
        ("1 0 0 0 0 0 0\n1 0 0 0 0 0\n", 2),  # field count changes
        ("1 0 0 0 0 0 0\n0 0 0 0 1 2 3\n", 2),  # zero quaternion
        ("1 0 0 0  0 1 0 0  0 0 1 0  0 0 0 1\n1 0 0 0  0 1 0 0  0 0 1 0  0 0 1 1\n", 2),  # last row
        ("1 0 0 0  0 1 0 0  0 0 1 0  0 0 0 1\n1 0 0 0  0 1.1 0 0  0 0 1 0  0 0 0 1\n", 2),  # not orthonormal
        ("1 0 0 0  0 1 0 0  0 0 1 0  0 0 0 1\n-1 0 0 0  0 1 0 0  0 0 1 0  0 0 0 1\n", 2),  # reflection
        ("1 0 0 0 0\n", 1),  # 5 fields: not a pose
    ],
)
def test_cli_bad_pose_line(tmp_path, content, line):
    a, b = tmp_path / "a.txt", tmp_path / "b.txt"
    a.write_text(content)
    b.write_text(content)
    assert_clean_error(run("handeye", a, b, "--poses"), a, line)


def test_cli_mismatched_counts_name_the_shorter_file(tmp_path):
    a, b = tmp_path / "a.txt", tmp_path / "b.txt"
    a.write_text("1 0 0 0\n0 1 0 0\n0 0 1 0\n")
    b.write_text("# header\n1 0 0 0\n0 1 0 0\n")
    r = run("handeye", a, b)
    assert_clean_error(r, b, 4)  # the end of b.txt (3 lines), where its third pair is missing
    assert str(a) in r.stderr and "one line per pair" in r.stderr
    assert_clean_error(run("handeye", b, a, "--poses"), b, 2)  # not poses: the first data line already fails


def test_cli_degenerate_exit_1(tmp_path):
    a, b = tmp_path / "a.txt", tmp_path / "b.txt"
    L = rot(np.outer([0.3, 0.7, 1.1, -0.4], [0.0, 0.0, 1.0]))
    write_quats(a, L)
    write_quats(b, L)
    r = run("handeye", a, b)
    assert r.exit_code == 1
    # one line naming both inputs, as solve's exit-1 errors name theirs
    assert r.stderr.strip().startswith(f"rotgraph: error: {a}, {b}: degenerate input") and len(r.stderr.strip().splitlines()) == 1


def test_cli_help_has_example():
    r = run("handeye", "--help")
    assert r.exit_code == 0 and "Example:" in r.stdout
