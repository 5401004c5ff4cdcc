"""Rotation information of two-view relative poses (rotgraph.estimators.pair_uncertainty):
the analytic Jacobians against finite differences, the predicted covariance against Monte
Carlo re-estimation of the pose, how it scales with correspondences and noise, its
invariances, degenerate pairs, and the COLMAP reader's ``uncertainty=True``.

The Monte Carlo estimators and the reference residuals are written here from scratch
(scipy rotations, an explicit essential matrix), not with the module under test."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from rotgraph.estimators import pair_uncertainty as pu
from rotgraph.viewgraph import check_information


def hat(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def two_view(rng, n=60, rotvec=(0.1, -0.3, 0.05), centre2=(1.0, 0.2, 0.1), depth=(4.0, 8.0), width=2.0, world=None):
    """A two-view scene: ``R`` = cam2_from_cam1, ``t`` (cam2_from_cam1 translation) and
    the noise-free normalised points ``x1``, ``x2`` of ``n`` random 3-D points. With
    ``world`` (3x3), both cameras and the points are first turned by that world rotation
    (the images are the same)."""
    R = Rotation.from_rotvec(rotvec).as_matrix()
    t = -R @ np.asarray(centre2, dtype=float)
    X = np.c_[rng.uniform(-width, width, (n, 2)), rng.uniform(*depth, n)]  # camera 1 = world
    if world is not None:  # cam_from_world R_c W^T, points W X: same images, same R_ij
        W = world
        R1, R2 = W.T, R @ W.T
        Xw = X @ W.T
        Y1 = Xw @ R1.T
        Y2 = Xw @ R2.T + t
        R = R2 @ R1.T
    else:
        Y1, Y2 = X, X @ R.T + t
    return R, t, Y1[:, :2] / Y1[:, 2:], Y2[:, :2] / Y2[:, 2:]


def sampson_reference(R, t, a, b, s1, s2):
    """Whitened Sampson residuals from an explicit E = [t]x R (independent formula)."""
    t = t / np.linalg.norm(t)
    E = hat(t) @ R
    A = np.c_[a, np.ones(len(a))]
    Bh = np.c_[b, np.ones(len(b))]
    Ex1, Etx2 = A @ E.T, Bh @ E
    e = np.sum(Bh * Ex1, axis=1)
    return e / np.sqrt(s2**2 * (Ex1[:, 0] ** 2 + Ex1[:, 1] ** 2) + s1**2 * (Etx2[:, 0] ** 2 + Etx2[:, 1] ** 2))


# =========================================================================== Jacobians


def test_sampson_residuals_and_jacobian_against_finite_differences(rng):
    f1, f2 = 500.0, 800.0
    pairs = [two_view(rng, n=40), two_view(rng, n=25, rotvec=(0.4, 0.2, -0.1), centre2=(-0.3, 1.0, 0.5))]
    x1 = np.concatenate([p[2] + rng.normal(size=p[2].shape) / f1 for p in pairs])
    x2 = np.concatenate([p[3] + rng.normal(size=p[3].shape) / f2 for p in pairs])
    seg = np.repeat([0, 1], [40, 25])
    R = np.stack([p[0] for p in pairs])
    t = np.stack([p[1] for p in pairs])
    kw = dict(scale1=np.array([1 / f1, 1 / f1]), scale2=np.array([1 / f2, 1 / f2]), sigma=1.5)
    r, J, D = pu.sampson_residuals(x1, x2, seg, R, t, **kw)
    for p in range(2):
        m = seg == p
        ref = sampson_reference(R[p], t[p], x1[m], x2[m], 1.5 / f1, 1.5 / f2)
        np.testing.assert_allclose(r[m], ref, rtol=1e-10, atol=1e-10)
    assert 0.5 < np.std(r) < 1.5  # whitened: ~N(0, 1)

    tu = t / np.linalg.norm(t, axis=1, keepdims=True)
    B = pu.tangent_basis(tu)
    assert np.allclose(np.einsum("pi,pik->pk", tu, B), 0) and np.allclose(np.swapaxes(B, 1, 2) @ B, np.eye(2))
    # J is the derivative of e / sqrt(D) with the denominator D held at the point
    h = 1e-6
    fd = np.zeros_like(J)
    for k in range(5):
        for sign in (1.0, -1.0):
            if k < 3:
                Rp = Rotation.from_rotvec(sign * h * np.eye(3)[k]).as_matrix() @ R  # R -> exp([d]x) R
                tp = tu
            else:
                Rp = R
                tp = tu + sign * h * B[:, :, k - 3]
            rp, _, Dp = pu.sampson_residuals(x1, x2, seg, Rp, tp, **kw)
            fd[:, k] += sign * rp * np.sqrt(Dp / D) / (2 * h)
    np.testing.assert_allclose(J, fd, atol=1e-6 * np.abs(J).max())
    # ... which is the exact derivative of r where r = 0 (noise-free correspondences)
    c1 = np.concatenate([p[2] for p in pairs])
    c2 = np.concatenate([p[3] for p in pairs])
    J0 = pu.sampson_residuals(c1, c2, seg, R, t, **kw)[1]
    exact = np.zeros_like(J0)
    for k in range(5):
        for sign in (1.0, -1.0):
            Rp = Rotation.from_rotvec(sign * h * np.eye(3)[k]).as_matrix() @ R if k < 3 else R
            tp = tu if k < 3 else tu + sign * h * B[:, :, k - 3]
            exact[:, k] += sign * pu.sampson_residuals(c1, c2, seg, Rp, tp, **kw)[0] / (2 * h)
    np.testing.assert_allclose(J0, exact, atol=1e-6 * np.abs(J0).max())


def test_transfer_jacobian_against_finite_differences(rng):
    R, _, x1, x2 = two_view(rng, n=30, centre2=(0.0, 0.0, 0.0))
    x1 = x1 + rng.normal(size=x1.shape) / 500
    seg = np.zeros(30, dtype=int)
    rho, J, C = pu.transfer_residuals(x1, x2, seg, R[None], scale1=1 / 500, scale2=1 / 700)
    y = x1 @ R[:, :2].T + R[:, 2]
    np.testing.assert_allclose(rho, y[:, :2] / y[:, 2:] - x2, atol=1e-12)
    assert np.allclose(C, np.swapaxes(C, 1, 2)) and (np.linalg.eigvalsh(C) > 0).all()
    h = 1e-6
    fd = np.zeros_like(J)
    for k in range(3):
        for sign in (1.0, -1.0):
            Rp = Rotation.from_rotvec(sign * h * np.eye(3)[k]).as_matrix() @ R
            fd[:, :, k] += sign * pu.transfer_residuals(x1, x2, seg, Rp[None])[0] / (2 * h)
    np.testing.assert_allclose(J, fd, atol=1e-7)
    # C = s2^2 I + s1^2 A A^T, A = d pi(R x1) / d x1, by finite differences too
    A = np.zeros((30, 2, 2))
    for k in range(2):
        dx = np.zeros(2)
        dx[k] = h
        A[:, :, k] = (pu.transfer_residuals(x1 + dx, x2, seg, R[None])[0] - pu.transfer_residuals(x1 - dx, x2, seg, R[None])[0]) / (2 * h)
    np.testing.assert_allclose(C, np.eye(2) / 700**2 + (A @ np.swapaxes(A, 1, 2)) / 500**2, rtol=1e-6)


# =========================================================================== Monte Carlo


def _whitened_mean(d, H):
    return float(np.mean(np.einsum("ki,kij,kj->k", d, H, d)))


def test_monte_carlo_calibration_epipolar():
    """Re-estimate the pose 300 times under 1 px noise (Sampson error minimised over the
    5 DOF from the truth): the empirical covariance of d = log(R_est R^T) is the inverse
    of the predicted information."""
    rng = np.random.default_rng(7)
    f, sigma, n = 500.0, 1.0, 60
    R, t, x1, x2 = two_view(rng, n=n)
    tu = t / np.linalg.norm(t)
    B = pu.tangent_basis(tu[None])[0]
    s = sigma / f

    def pose(p):
        tt = tu + B @ p[3:]
        return Rotation.from_rotvec(p[:3]).as_matrix() @ R, tt / np.linalg.norm(tt)

    ds, Hs = [], []
    for _ in range(300):
        a = x1 + s * rng.normal(size=x1.shape)
        b = x2 + s * rng.normal(size=x2.shape)
        sol = least_squares(lambda p, a, b: sampson_reference(*pose(p), a, b, s, s), np.zeros(5), args=(a, b), method="lm",
                            xtol=1e-12, ftol=1e-12)
        Rest, test = pose(sol.x)
        ds.append(Rotation.from_matrix(Rest @ R.T).as_rotvec())
        Hs.append(pu.rotation_information(a, b, np.zeros(n, dtype=int), Rest[None], test[None], scale1=1 / f, scale2=1 / f, sigma=sigma)[0])
    d, H = np.array(ds), np.array(Hs)
    empirical = d.T @ d / len(d)
    predicted = np.linalg.inv(H.mean(axis=0))
    rel = np.linalg.norm(empirical - predicted) / np.linalg.norm(predicted)
    assert rel < 0.2, rel
    assert abs(_whitened_mean(d, H) - 3.0) < 0.45
    # anisotropic: the weakest axis has over 10x the variance of the strongest; both are predicted
    ev = np.linalg.eigvalsh(predicted)
    assert ev[-1] > 10 * ev[0]


def test_monte_carlo_calibration_rotation_only():
    """A pure rotation (PANORAMIC): re-estimate R by maximum likelihood (R and the 2-D
    points of image 1 as unknowns, noise in both images) 300 times; the empirical
    covariance matches the inverse of the rotation-only information."""
    rng = np.random.default_rng(11)
    f1, f2, n = 400.0, 600.0, 15
    R, _, x1, x2 = two_view(rng, n=n, rotvec=(0.05, 0.4, -0.1), centre2=(0.0, 0.0, 0.0), width=3.0)
    s1, s2 = 1.0 / f1, 1.0 / f2

    def residuals(p, a, b):
        Rp = Rotation.from_rotvec(p[:3]).as_matrix() @ R
        u = p[3:].reshape(n, 2)
        y = np.c_[u, np.ones(n)] @ Rp.T
        return np.concatenate([((u - a) / s1).ravel(), ((y[:, :2] / y[:, 2:] - b) / s2).ravel()])

    ds, Hs = [], []
    for _ in range(300):
        a = x1 + s1 * rng.normal(size=x1.shape)
        b = x2 + s2 * rng.normal(size=x2.shape)
        sol = least_squares(residuals, np.r_[np.zeros(3), a.ravel()], args=(a, b), method="lm", xtol=1e-12, ftol=1e-12)
        Rest = Rotation.from_rotvec(sol.x[:3]).as_matrix() @ R
        ds.append(Rotation.from_matrix(Rest @ R.T).as_rotvec())
        Hs.append(pu.rotation_information(a, b, np.zeros(n, dtype=int), Rest[None], None, scale1=s1, scale2=s2)[0])
    d, H = np.array(ds), np.array(Hs)
    empirical = d.T @ d / len(d)
    predicted = np.linalg.inv(H.mean(axis=0))
    rel = np.linalg.norm(empirical - predicted) / np.linalg.norm(predicted)
    assert rel < 0.2, rel
    assert abs(_whitened_mean(d, H) - 3.0) < 0.45


# =========================================================================== scaling, invariance


def _info(x1, x2, R, t, **kw):
    return pu.rotation_information(x1, x2, np.zeros(len(x1), dtype=int), R[None], None if t is None else t[None], **kw)[0]


@pytest.mark.parametrize("pure", [False, True])
def test_scaling_with_correspondences_and_noise(rng, pure):
    centre = (0.0, 0.0, 0.0) if pure else (1.0, 0.2, 0.1)
    R, t, x1, x2 = two_view(rng, n=400, centre2=centre)
    t = None if pure else t
    x1 = x1 + rng.normal(size=x1.shape) / 500
    x2 = x2 + rng.normal(size=x2.shape) / 500
    kw = dict(scale1=1 / 500, scale2=1 / 500)
    H = _info(x1[:200], x2[:200], R, t, **kw)
    # the same correspondences twice: exactly twice the information
    np.testing.assert_allclose(_info(np.r_[x1[:200], x1[:200]], np.r_[x2[:200], x2[:200]], R, t, **kw), 2 * H, rtol=1e-9)
    # twice as many (other) correspondences of the scene: about twice
    H2 = _info(x1, x2, R, t, **kw)
    assert np.linalg.norm(H2 - 2 * H) / np.linalg.norm(2 * H) < 0.25
    # twice the pixel noise: exactly a quarter (sigma or the pixel scale)
    np.testing.assert_allclose(_info(x1[:200], x2[:200], R, t, sigma=2.0, **kw), H / 4, rtol=1e-9)
    np.testing.assert_allclose(_info(x1[:200], x2[:200], R, t, scale1=2 / 500, scale2=2 / 500), H / 4, rtol=1e-9)


@pytest.mark.parametrize("pure", [False, True])
def test_invariant_under_a_world_rotation(rng, pure):
    """The same scene seen from the same cameras, all turned by a world rotation W (the
    images and R_ij do not change): the same information."""
    centre = (0.0, 0.0, 0.0) if pure else (1.0, 0.2, 0.1)
    seed = int(rng.integers(1 << 30))
    R0, t0, a0, b0 = two_view(np.random.default_rng(seed), n=50, centre2=centre)
    W = Rotation.random(random_state=rng).as_matrix()
    R1, t1, a1, b1 = two_view(np.random.default_rng(seed), n=50, centre2=centre, world=W)
    np.testing.assert_allclose(R1, R0, atol=1e-12)
    noise = rng.normal(size=(2, 50, 2)) / 500
    kw = dict(scale1=1 / 500, scale2=1 / 500)
    H0 = _info(a0 + noise[0], b0 + noise[1], R0, None if pure else t0, **kw)
    H1 = _info(a1 + noise[0], b1 + noise[1], R1, None if pure else t1, **kw)
    np.testing.assert_allclose(H1, H0, rtol=1e-7)


def test_swapped_pair_is_the_reversed_edge(rng):
    """The pair read the other way round (cam1 <-> cam2: R^T, -R^T t) has the information
    R^T H R, the view graph's rule for a reversed edge (the Sampson error is symmetric)."""
    R, t, x1, x2 = two_view(rng, n=50)
    x1 = x1 + rng.normal(size=x1.shape) / 500
    x2 = x2 + rng.normal(size=x2.shape) / 500
    H = _info(x1, x2, R, t, scale1=1 / 500, scale2=1 / 700)
    Hs = _info(x2, x1, R.T, -R.T @ t, scale1=1 / 700, scale2=1 / 500)
    np.testing.assert_allclose(Hs, R.T @ H @ R, rtol=1e-7, atol=1e-7 * np.abs(H).max())
    # the sign of t does not matter
    np.testing.assert_allclose(_info(x1, x2, R, -t, scale1=1 / 500, scale2=1 / 700), H, rtol=1e-10)


# =========================================================================== many pairs, degeneracies


def test_all_pairs_at_once_equal_each_pair_alone(rng, monkeypatch):
    pairs = [two_view(rng, n=int(rng.integers(5, 60)), rotvec=rng.normal(size=3) * 0.3, centre2=rng.normal(size=3)) for _ in range(12)]
    pure = np.zeros(12, dtype=bool)
    pure[[3, 7]] = True
    x1 = np.concatenate([p[2] for p in pairs]) + rng.normal(size=(sum(len(p[2]) for p in pairs), 2)) / 600
    x2 = np.concatenate([p[3] for p in pairs]) + rng.normal(size=(len(x1), 2)) / 600
    seg = np.repeat(np.arange(12), [len(p[2]) for p in pairs])
    R = np.stack([p[0] for p in pairs])
    t = np.stack([p[1] for p in pairs])
    scale1 = rng.uniform(1 / 900, 1 / 300, 12)
    scale2 = rng.uniform(1 / 900, 1 / 300, 12)
    alone = np.stack([
        pu.rotation_information(x1[seg == p], x2[seg == p], np.zeros((seg == p).sum(), dtype=int), R[p:p + 1], t[p:p + 1],
                                scale1=scale1[p], scale2=scale2[p], rotation_only=pure[p:p + 1])[0]
        for p in range(12)
    ])
    order = rng.permutation(len(seg))  # any order of the correspondences
    together = pu.rotation_information(x1[order], x2[order], seg[order], R, t, scale1=scale1, scale2=scale2, rotation_only=pure)
    np.testing.assert_allclose(together, alone, rtol=1e-9)
    monkeypatch.setattr(pu, "CHUNK", 17)  # chunks cut at pair boundaries
    chunked = pu.rotation_information(x1, x2, seg, R, t, scale1=scale1, scale2=scale2, rotation_only=pure)
    np.testing.assert_allclose(chunked, alone, rtol=1e-9)
    check_information(together, 12)


def test_weights_count_each_correspondence_that_many_times(rng):
    R, t, x1, x2 = two_view(rng, n=30)
    x1 = x1 + rng.normal(size=x1.shape) / 500
    x2 = x2 + rng.normal(size=x2.shape) / 500
    w = rng.integers(1, 4, 30)
    seg = np.zeros(30, dtype=int)
    weighted = pu.rotation_information(x1, x2, seg, R[None], t[None], weights=w.astype(float))
    repeated = pu.rotation_information(np.repeat(x1, w, axis=0), np.repeat(x2, w, axis=0), np.zeros(w.sum(), dtype=int), R[None], t[None])
    np.testing.assert_allclose(weighted, repeated, rtol=1e-9)
    with pytest.raises(ValueError):
        pu.rotation_information(x1, x2, seg, R[None], t[None], weights=-w.astype(float))


def test_degenerate_pairs_stay_positive_definite(rng):
    R, t, x1, x2 = two_view(rng, n=40)
    x1 = x1 + rng.normal(size=x1.shape) / 500
    x2 = x2 + rng.normal(size=x2.shape) / 500
    chunks = [
        (x1[:40], x2[:40]),  # 0: fine
        (x1[:3], x2[:3]),  # 1: too few for the epipolar model
        (x1[:0], x2[:0]),  # 2: none at all
        (np.full((10, 2), np.nan), x2[:10]),  # 3: all not finite (e.g. failed undistortion)
        (np.r_[x1[:20], np.full((5, 2), np.inf)], np.r_[x2[:20], x2[:5]]),  # 4: some not finite
        (np.repeat(x1[:1], 6, axis=0), np.repeat(x2[:1], 6, axis=0)),  # 5: one ray 6 times, rotation-only: rank 2
        (x1[:1], x2[:1]),  # 6: rotation-only with a single correspondence
        (np.repeat(x1[:2], 4, axis=0), np.repeat(x2[:2], 4, axis=0)),  # 7: two rays 4 times each, epipolar: rank 2
    ]
    x1s = np.concatenate([c[0] for c in chunks])
    x2s = np.concatenate([c[1] for c in chunks])
    seg = np.repeat(np.arange(len(chunks)), [len(c[0]) for c in chunks])
    Rs = np.repeat(R[None], len(chunks), axis=0)
    ts = np.repeat(t[None], len(chunks), axis=0)
    ts[5] = 0.0  # t undefined: rotation-only
    with np.errstate(all="raise"):
        H = pu.rotation_information(x1s, x2s, seg, Rs, ts, scale1=1 / 500, scale2=1 / 500, rotation_only=np.arange(8) == 6)
    assert np.isfinite(H).all()
    check_information(H, len(chunks))
    assert (np.linalg.eigvalsh(H) > 0).all()
    for k in (1, 2, 3, 6):
        np.testing.assert_array_equal(H[k], pu.EMPTY_INFORMATION * np.eye(3))
    np.testing.assert_allclose(H[4], _info(x1[:20], x2[:20], R, t, scale1=1 / 500, scale2=1 / 500), rtol=1e-12)
    for k in (5, 7):  # rank deficient: the floor
        ev = np.linalg.eigvalsh(H[k])
        assert ev[0] >= pu.MIN_EIGENVALUE_RATIO * np.trace(H[k]) * (1 - 1e-5)
        assert ev[0] < 2e-6 * np.trace(H[k])
    # pair 5: rotation about the one ray is the free direction
    ray = R @ np.r_[x1[0], 1.0]
    ray /= np.linalg.norm(ray)
    assert ray @ H[5] @ ray < 2e-6 * np.trace(H[5])


def test_translation_directions(rng):
    pairs = [two_view(rng, n=50, rotvec=rng.normal(size=3) * 0.3, centre2=rng.normal(size=3)) for _ in range(6)]
    x1 = np.concatenate([p[2] for p in pairs])
    x2 = np.concatenate([p[3] for p in pairs])
    seg = np.repeat(np.arange(6), 50)
    R = np.stack([p[0] for p in pairs])
    t = np.stack([p[1] / np.linalg.norm(p[1]) for p in pairs])
    est = pu.translation_directions(x1, x2, seg, R)
    np.testing.assert_allclose(np.abs(np.sum(est * t, axis=1)), 1.0, atol=1e-9)  # exact data: exact, up to sign
    noisy = pu.translation_directions(x1 + rng.normal(size=x1.shape) / 500, x2 + rng.normal(size=x2.shape) / 500, seg, R,
                                      scale1=1 / 500, scale2=1 / 500)
    assert (np.abs(np.sum(noisy * t, axis=1)) > np.cos(np.radians(5))).all()
    # fewer than 2 correspondences: undefined (zero)
    est = pu.translation_directions(x1[:1], x2[:1], np.zeros(1, dtype=int), R[:2])
    np.testing.assert_array_equal(est, 0.0)


def test_bad_arguments():
    with pytest.raises(ValueError):
        pu.rotation_information(np.zeros((3, 2)), np.zeros((2, 2)), np.zeros(3, dtype=int), np.eye(3)[None])
    with pytest.raises(ValueError):
        pu.rotation_information(np.zeros((3, 2)), np.zeros((3, 2)), np.array([0, 1, 2]), np.eye(3)[None])
    with pytest.raises(ValueError):
        pu.rotation_information(np.zeros((3, 2)), np.zeros((3, 2)), np.zeros(3, dtype=int), np.eye(3)[None], sigma=0.0)


# =========================================================================== the COLMAP reader


@pytest.fixture(scope="module")
def colmap_projects(tmp_path_factory):
    """Small synthetic COLMAP projects (1 px keypoint noise, wrong raw matches, a
    doppelganger pair): relative poses estimated; stored; a rig of two cameras."""
    pytest.importorskip("pycolmap")
    from rotgraph.synth import synthesize_colmap_project

    base = tmp_path_factory.mktemp("pair_uncertainty")
    specs = {
        "plain": dict(n_frames=14, n_points=300, doppelgangers=1, seed=21),
        "stored": dict(n_frames=8, n_points=250, store_relative_pose=True, seed=22),
        "rig": dict(n_frames=6, cameras_per_rig=2, n_points=250, seed=23),
    }
    return {name: (base / name, synthesize_colmap_project(base / name, **kw)) for name, kw in specs.items()}


def _read(path, **kw):
    from rotgraph.pipeline.colmap import read_colmap_project

    return read_colmap_project(path, **kw)


@pytest.mark.parametrize("name", ["plain", "stored", "rig"])
def test_reader_attaches_information_and_changes_nothing_else(colmap_projects, name):
    folder, _ = colmap_projects[name]
    g0 = _read(folder)
    g1 = _read(folder, uncertainty=True)
    assert g0.information is None
    np.testing.assert_array_equal(g1.edges, g0.edges)
    np.testing.assert_array_equal(g1.node_ids, g0.node_ids)
    np.testing.assert_array_equal(g1.cam2_from_cam1, g0.cam2_from_cam1)
    np.testing.assert_array_equal(g1.weights, g0.weights)
    np.testing.assert_array_equal(g1.rigs.frame_ids, g0.rigs.frame_ids)
    np.testing.assert_array_equal(g1.rigs.cam_from_rig, g0.rigs.cam_from_rig)
    assert g1.information.shape == (g1.n_edges, 3, 3)
    check_information(g1.information, g1.n_edges)
    assert g1.meta["n_pairs_without_information"] == 0 and g1.meta["seconds_uncertainty"] >= 0
    # about (focal / px)^2 * inliers: far above the floor of an empty pair
    assert (np.linalg.eigvalsh(g1.information)[:, 0] > 1e3).all()


def test_reader_information_is_the_module_on_each_pairs_inliers(colmap_projects):
    """Pair by pair, independently of the reader's vectorised gathering: the inlier
    pixels (TwoViewGeometries.points), normalised by the camera, the pose (R of the edge,
    t from pycolmap's own estimate_two_view_geometry_pose) -> the same information."""
    pycolmap = pytest.importorskip("pycolmap")
    from rotgraph.io.colmap import read_two_view_geometries

    for name in ("plain", "stored"):
        folder, _ = colmap_projects[name]
        g = _read(folder, uncertainty=True)
        data = read_two_view_geometries(folder / "database.db", all_keypoints=True)
        index = {int(i): k for k, i in enumerate(g.node_ids)}
        edge_of = {(int(a), int(b)): e for e, (a, b) in enumerate(g.edges)}
        checked = 0
        for k, pair in enumerate(data.pairs):
            if pair is None or (index[pair[0]], index[pair[1]]) not in edge_of:
                continue
            e = edge_of[(index[pair[0]], index[pair[1]])]
            cam1, cam2 = data.cameras[pair[0]], data.cameras[pair[1]]
            p1, p2 = data.points(k)
            geom = data.geometries[k]
            if geom.cam2_from_cam1 is None:
                pycolmap.estimate_two_view_geometry_pose(cam1, p1, cam2, p2, geom)
            t = np.asarray(geom.cam2_from_cam1.translation)
            H = pu.rotation_information(cam1.cam_from_img(p1), cam2.cam_from_img(p2), np.zeros(len(p1), dtype=int),
                                        g.cam2_from_cam1[e][None], t[None],
                                        scale1=1 / cam1.mean_focal_length(), scale2=1 / cam2.mean_focal_length())[0]
            np.testing.assert_allclose(g.information[e], H, rtol=1e-5, atol=1e-6 * np.abs(H).max())
            checked += 1
        assert checked == g.n_edges


def test_reader_information_is_calibrated_on_a_synthetic_project(colmap_projects):
    """The pixel noise of the synthetic project is 1 px: the edges' actual rotation errors
    (vs the ground-truth model), whitened by the predicted information, are chi^2_3 like
    (mean 3; 3.05 here, 4.2 on a 50-image project: the poses are RANSAC estimates, not
    maximum likelihood), and the predicted covariances explain the errors far better than
    isotropic ones scaled by the inlier count (the solver's weights without information):
    Gaussian log-likelihood per edge, each with its noise level refitted."""
    from rotgraph import so3

    folder, info = colmap_projects["plain"]
    g = _read(folder, uncertainty=True)
    G = g.gt_cam_from_world
    i, j = g.edges[:, 0], g.edges[:, 1]
    d = so3.log(g.cam2_from_cam1 @ np.swapaxes(G[j] @ np.swapaxes(G[i], 1, 2), 1, 2))
    inlier = np.degrees(np.linalg.norm(d, axis=1)) < 5.0  # not the doppelganger
    assert inlier.sum() >= g.n_edges - len(info["doppelgangers"])
    d, H, n = d[inlier], g.information[inlier], g.weights[inlier]
    w = np.einsum("ki,kij,kj->k", d, H, d)
    assert 2.0 < w.mean() < 6.0 and 1.2 < np.median(w) < 4.0, (w.mean(), np.median(w))

    def loglik(C):  # mean per edge, the scale of C refitted
        q = np.einsum("ki,kij,kj->k", d, np.linalg.inv(C), d)
        return np.mean(-0.5 * q / (q.mean() / 3) - 0.5 * np.log(np.linalg.det(2 * np.pi * q.mean() / 3 * C)))

    gain = loglik(np.linalg.inv(H)) - loglik(np.eye(3) / n[:, None, None])
    assert gain > 1.0, gain  # 2.5 nats here, 2.4 on a 50-image project, 1.9 on the real lund_door


def test_reader_sample_of_the_inliers_and_blocks(colmap_projects, monkeypatch):
    from rotgraph.pipeline import colmap as pipeline

    folder, _ = colmap_projects["plain"]
    full = _read(folder, uncertainty=True)
    monkeypatch.setattr(pipeline, "INFORMATION_BLOCK", 700)  # blocks of ~2 pairs: the same
    np.testing.assert_allclose(_read(folder, uncertainty=True).information, full.information, rtol=1e-12)
    monkeypatch.undo()
    np.testing.assert_allclose(_read(folder, uncertainty=True, uncertainty_sample=100_000).information, full.information, rtol=1e-12)
    sampled = _read(folder, uncertainty=True, uncertainty_sample=64).information  # of ~300 inliers per pair
    check_information(sampled, full.n_edges)
    ratio = np.trace(sampled, axis1=1, axis2=2) / np.trace(full.information, axis1=1, axis2=2)
    assert 0.9 < np.mean(ratio) < 1.1 and 0.9 < np.median(ratio) < 1.1  # each inlier stands for n / 64
    # pixel noise: information / sigma^2
    np.testing.assert_allclose(_read(folder, uncertainty=True, pixel_sigma=2.0).information, full.information / 4, rtol=1e-9)
    with pytest.raises(ValueError):
        _read(folder, uncertainty=True, uncertainty_sample=3)
    with pytest.raises(ValueError):
        _read(folder, uncertainty=True, pixel_sigma=0.0)


def test_model_only_input_has_no_information(colmap_projects):
    folder, info = colmap_projects["plain"]
    g = _read(info["model"], uncertainty=True)
    assert g.meta["source"] == "model" and g.information is None
