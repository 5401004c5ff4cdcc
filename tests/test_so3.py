"""Mathematical tests of rotgraph.so3 against scipy, pycolmap and first principles."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import optimize, stats
from scipy.spatial.transform import Rotation

from rotgraph import so3, so3_checks, so3_rows

PI = np.pi
ANGLES = [0.0, 1e-12, 1e-9, 1e-6, 1e-3, 1.0, PI / 2, 2.0, 3.0, PI - 1e-6, PI - 1e-9, PI]


# --------------------------------------------------------------------------- helpers


def wxyz(q_xyzw):
    return np.roll(np.asarray(q_xyzw, dtype=float), 1, axis=-1)


def xyzw(q_wxyz):
    return np.roll(np.asarray(q_wxyz, dtype=float), -1, axis=-1)


def w_nonneg(q):
    """Representative with w >= 0 (w == 0 exactly does not occur in these tests)."""
    q = np.asarray(q, dtype=float)
    return q * np.where(q[..., :1] < 0, -1.0, 1.0)


def unit_axes(rng, n):
    """n random unit vectors plus the 6 signed coordinate axes."""
    a = rng.standard_normal((n, 3))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    return np.concatenate([a, np.eye(3), -np.eye(3)])


def scipy_angle(R):
    """Rotation angle via scipy (independent of rotgraph)."""
    return Rotation.from_matrix(R).magnitude()


def rodrigues(v):
    """exp(hat(v)) by Rodrigues' formula, independent of rotgraph and cheap for one vector."""
    x, y, z = v
    th = math.sqrt(x * x + y * y + z * z)
    a = 1.0 if th == 0 else math.sin(th) / th
    b = 0.5 if th == 0 else 2 * math.sin(th / 2) ** 2 / (th * th)
    K = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + a * K + b * (K @ K)


def max_err(a, b):
    return float(np.max(np.abs(np.asarray(a) - np.asarray(b))))


# --------------------------------------------------------------------------- exp / log


@pytest.mark.parametrize("theta", ANGLES)
def test_exp_log_round_trip(theta, rng):
    axes = unit_axes(rng, 60)
    v = theta * axes
    R = so3.exp(v)
    # exp gives rotations
    assert max_err(R @ np.swapaxes(R, 1, 2), np.eye(3)) < 1e-14
    assert np.all(np.linalg.det(R) > 0)
    # exp agrees with Rodrigues via scipy
    assert max_err(R, Rotation.from_rotvec(v).as_matrix()) < 1e-13
    lv = so3.log(R)
    # |log R| is the angle
    assert max_err(np.linalg.norm(lv, axis=1), theta) < 1e-12
    # exp(log(R)) == R
    assert max_err(so3.exp(lv), R) < 1e-12
    if theta < PI:
        # log(exp(v)) == v for |v| < pi (unique logarithm)
        assert max_err(lv, v) < 1e-12
    else:
        # at pi the logarithm is defined up to the sign of the axis
        same = np.abs(lv - v).max(axis=1)
        opposite = np.abs(lv + v).max(axis=1)
        assert np.minimum(same, opposite).max() < 1e-12
    # so3.angle agrees
    assert max_err(so3.angle(R), theta) < 1e-12


@settings(max_examples=300, deadline=None, derandomize=True)
@given(
    st.lists(st.floats(-1.0, 1.0, allow_nan=False), min_size=3, max_size=3).filter(
        lambda a: np.linalg.norm(a) > 1e-3
    ),
    st.floats(0.0, PI * (1 - 1e-12), allow_nan=False),
)
def test_log_exp_hypothesis(axis, theta):
    v = theta * np.asarray(axis) / np.linalg.norm(axis)
    R = so3.exp(v)
    assert max_err(so3.log(R), v) < 1e-12
    assert max_err(R, Rotation.from_rotvec(v).as_matrix()) < 1e-13


def test_exp_of_long_vectors_wraps(rng):
    # exp is 2 pi periodic along the axis: exp((theta + 2 pi) a) == exp(theta a)
    a = unit_axes(rng, 20)
    th = rng.uniform(0, PI, size=(len(a), 1))
    assert max_err(so3.exp((th + 2 * PI) * a), so3.exp(th * a)) < 1e-12
    # and exp((2 pi - theta) a) == exp(-theta a)
    assert max_err(so3.exp((2 * PI - th) * a), so3.exp(-th * a)) < 1e-12


def test_hat_vee(rng):
    v = rng.standard_normal((10, 3))
    w = rng.standard_normal((10, 3))
    H = so3.hat(v)
    assert max_err(H, -np.swapaxes(H, 1, 2)) == 0.0
    assert max_err(H @ w[..., None], np.cross(v, w)[..., None]) < 1e-14
    assert max_err(so3.vee(H), v) == 0.0


# --------------------------------------------------------------------------- scipy agreement


def test_exp_log_match_scipy(rng):
    v = rng.standard_normal((500, 3))
    v *= (rng.uniform(0, PI, 500) / np.linalg.norm(v, axis=1))[:, None]
    assert max_err(so3.exp(v), Rotation.from_rotvec(v).as_matrix()) < 1e-13
    R = Rotation.random(2000, random_state=rng)
    M = R.as_matrix()
    ref = R.as_rotvec()
    ok = np.linalg.norm(ref, axis=1) < PI - 1e-6  # sign of the axis is unambiguous
    assert ok.sum() > 1990
    assert max_err(so3.log(M)[ok], ref[ok]) < 1e-12


def test_quaternions_from_matrices_match_scipy(rng):
    R = Rotation.random(3000, random_state=rng)
    M = R.as_matrix()
    q = so3.quaternions_from_matrices(M)
    assert np.all(q[:, 0] >= 0)  # rotgraph's sign convention
    assert max_err(np.linalg.norm(q, axis=1), 1.0) < 1e-15 * 10
    ref = w_nonneg(wxyz(R.as_quat()))  # scipy is scalar-last
    assert max_err(q, ref) < 1e-13
    # every Shepperd branch is exercised: angles above and below ~104 deg, each largest diagonal
    tr = np.trace(M, axis1=1, axis2=2)
    hard = tr <= -0.5
    assert hard.any() and (~hard).any()
    assert set(np.argmax(np.diagonal(M[hard], axis1=1, axis2=2), axis=1)) == {0, 1, 2}


@pytest.mark.parametrize("theta", ANGLES)
def test_quaternions_from_matrices_accuracy_at_all_angles(theta, rng):
    axes = unit_axes(rng, 40)
    q_true = np.concatenate([np.full((len(axes), 1), np.cos(theta / 2)), np.sin(theta / 2) * axes], 1)
    M = Rotation.from_quat(xyzw(q_true)).as_matrix()
    q = so3.quaternions_from_matrices(M)
    assert np.all(q[:, 0] >= 0)
    if theta < PI:
        assert max_err(q, q_true) < 1e-13
    else:  # w = 0: either sign is a valid representative
        assert np.minimum(np.abs(q - q_true).max(1), np.abs(q + q_true).max(1)).max() < 1e-13


def test_matrices_from_quaternions_match_scipy(rng):
    q = rng.standard_normal((2000, 4)) * rng.uniform(0.1, 10, (2000, 1))  # not unit: normalised
    M = so3.matrices_from_quaternions(q)
    ref = Rotation.from_quat(xyzw(q)).as_matrix()
    assert max_err(M, ref) < 1e-13
    assert max_err(M @ np.swapaxes(M, 1, 2), np.eye(3)) < 1e-14
    assert np.all(np.abs(np.linalg.det(M) - 1) < 1e-14)


def test_quaternion_matrix_round_trip(rng):
    q = so3.canonical_quaternions(rng.standard_normal((1000, 4)))
    assert max_err(so3.quaternions_from_matrices(so3.matrices_from_quaternions(q)), q) < 1e-13


# --------------------------------------------------------------------------- boundaries


def test_scipy_round_trip(rng):
    M = Rotation.random(50, random_state=rng).as_matrix()
    r = so3.to_scipy(M)
    assert isinstance(r, Rotation)
    assert max_err(r.as_matrix(), M) < 1e-14
    assert max_err(so3.from_scipy(r), M) < 1e-14
    back = so3.from_scipy(so3.to_scipy(M[3]))
    assert back.shape == (3, 3) and max_err(back, M[3]) < 1e-14
    # rotvec through scipy is rotgraph's log
    assert max_err(so3.to_scipy(so3.exp(0.3 * np.ones(3))).as_rotvec(), 0.3 * np.ones(3)) < 1e-14


def test_pycolmap_round_trip(rng):
    pycolmap = pytest.importorskip("pycolmap")
    from rotgraph.io.colmap import to_pycolmap

    M = Rotation.random(30, random_state=rng).as_matrix()
    objs = to_pycolmap(M)
    assert len(objs) == 30 and all(isinstance(o, pycolmap.Rotation3d) for o in objs)
    assert max_err(so3.from_pycolmap(objs), M) < 1e-13
    one = to_pycolmap(M[0])
    assert isinstance(one, pycolmap.Rotation3d)
    assert max_err(so3.from_pycolmap(one), M[0]) < 1e-13
    # the quaternion pycolmap stores (x, y, z, w) is rotgraph's (w, x, y, z)
    q = so3.quaternions_from_matrices(M[0])
    pq = np.asarray(one.quat)
    assert min(max_err(pq, xyzw(q)), max_err(pq, -xyzw(q))) < 1e-14


def test_pycolmap_quaternion_convention(rng):
    pycolmap = pytest.importorskip("pycolmap")
    q = so3.canonical_quaternions(rng.standard_normal((20, 4)))
    for qi in q:
        M_colmap = np.asarray(pycolmap.Rotation3d(xyzw(qi)).matrix())
        assert max_err(M_colmap, so3.matrices_from_quaternions(qi)) < 1e-14
    # a +90 degree turn about z in both: scalar-first (c, 0, 0, s)
    qz = np.array([np.cos(PI / 4), 0, 0, np.sin(PI / 4)])
    Rz = np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])
    assert max_err(so3.matrices_from_quaternions(qz), Rz) < 1e-15
    assert max_err(np.asarray(pycolmap.Rotation3d(xyzw(qz)).matrix()), Rz) < 1e-15


# --------------------------------------------------------------------------- distances


def _pairs(rng, n=400):
    """Pairs (R, S) at angles spread over [0, pi], including the extremes."""
    R = Rotation.random(n, random_state=rng).as_matrix()
    theta = np.concatenate([[0.0, 1e-9, 1e-6, PI - 1e-6, PI], rng.uniform(0, PI, n - 5)])
    S = R @ Rotation.from_rotvec(theta[:, None] * unit_axes(rng, n)[:n]).as_matrix()
    return R, S, theta


def test_distance_relations(rng):
    R, S, theta = _pairs(rng)
    ang = so3.angle_between(R, S)
    assert max_err(ang, theta) < 1e-12
    # independent reference: scipy magnitude of R^T S
    assert max_err(ang, scipy_angle(np.swapaxes(R, 1, 2) @ S)) < 1e-12
    ch = so3.chordal_distance(R, S)
    assert max_err(ch, 2 * np.sqrt(2) * np.sin(ang / 2)) < 1e-13
    assert max_err(ch, np.linalg.norm(R - S, axis=(1, 2))) < 1e-14
    assert max_err(so3.chordal_from_angle(ang), ch) < 1e-13
    qR = so3.quaternions_from_matrices(R)
    qS = so3.quaternions_from_matrices(S)
    flip = rng.random(len(qS)) < 0.5
    qS[flip] *= -1  # sign-invariant
    qd = so3.quaternion_distance(qR, qS)
    assert max_err(qd, 2 * np.sin(ang / 4)) < 1e-13
    assert max_err(so3.quaternion_distance_from_angle(ang), qd) < 1e-13
    # spot values
    assert so3.chordal_from_angle(PI) == pytest.approx(2 * np.sqrt(2), abs=1e-15)
    assert so3.quaternion_distance_from_angle(PI) == pytest.approx(np.sqrt(2), abs=1e-15)
    assert so3.quaternion_distance_from_angle(2 * PI / 3) == pytest.approx(1.0, abs=1e-15)


def test_angle_between_symmetry_and_invariance(rng):
    R, S, _ = _pairs(rng)
    ang = so3.angle_between(R, S)
    assert max_err(so3.angle_between(S, R), ang) < 1e-15
    W = Rotation.random(random_state=rng).as_matrix()
    assert max_err(so3.angle_between(W @ R, W @ S), ang) < 1e-12
    assert max_err(so3.angle_between(R @ W, S @ W), ang) < 1e-12
    assert max_err(so3.angle_between(R, R), 0.0) < 1e-15
    # broadcasting one rotation against a batch
    assert max_err(so3.angle_between(R[0], S), so3.angle_between(np.repeat(R[:1], len(S), 0), S)) == 0.0


def test_angle_triangle_inequality(rng):
    A, B, C = (Rotation.random(3000, random_state=rng).as_matrix() for _ in range(3))
    ab, bc, ac = so3.angle_between(A, B), so3.angle_between(B, C), so3.angle_between(A, C)
    assert np.all(ac <= ab + bc + 1e-12)
    assert np.all((ab >= 0) & (ab <= PI))


# --------------------------------------------------------------------------- quaternion algebra


def test_q_and_minus_q_same_matrix(rng):
    q = rng.standard_normal((500, 4))
    np.testing.assert_array_equal(so3.matrices_from_quaternions(q), so3.matrices_from_quaternions(-q))


def test_quaternion_multiply_is_matrix_product(rng):
    a = rng.standard_normal((500, 4))
    b = rng.standard_normal((500, 4))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    ab = so3.quaternion_multiply(a, b)
    assert max_err(np.linalg.norm(ab, axis=1), 1.0) < 1e-14
    Ra, Rb = so3.matrices_from_quaternions(a), so3.matrices_from_quaternions(b)
    assert max_err(so3.matrices_from_quaternions(ab), Ra @ Rb) < 1e-14
    # scipy composes the same way: (A * B).as_matrix() == A @ B
    ref = (Rotation.from_quat(xyzw(a)) * Rotation.from_quat(xyzw(b))).as_quat()
    assert max_err(w_nonneg(ab), w_nonneg(wxyz(ref))) < 1e-14
    # not commutative, but associative; identity is (1, 0, 0, 0)
    c = so3.canonical_quaternions(rng.standard_normal((500, 4)))
    assert max_err(so3.quaternion_multiply(ab, c), so3.quaternion_multiply(a, so3.quaternion_multiply(b, c))) < 1e-14
    assert max_err(so3.quaternion_multiply(a, [1.0, 0, 0, 0]), a) == 0.0
    assert max_err(ab, so3.quaternion_multiply(b, a)) > 0.1


def test_quaternion_conjugate_is_inverse(rng):
    q = so3.canonical_quaternions(rng.standard_normal((500, 4)))
    qc = so3.quaternion_conjugate(q)
    one = np.array([1.0, 0, 0, 0])
    assert max_err(so3.quaternion_multiply(q, qc), one) < 1e-15 * 4
    assert max_err(so3.quaternion_multiply(qc, q), one) < 1e-15 * 4
    R = so3.matrices_from_quaternions(q)
    assert max_err(so3.matrices_from_quaternions(qc), np.swapaxes(R, 1, 2)) < 1e-15 * 4
    q_before = q.copy()
    so3.quaternion_conjugate(q)
    np.testing.assert_array_equal(q, q_before)  # input not modified


def test_quaternion_exp_log(rng):
    v = rng.standard_normal((500, 3))
    v *= (rng.uniform(0, PI * (1 - 1e-9), 500) / np.linalg.norm(v, axis=1))[:, None]
    q = so3.quaternion_exp(v)
    assert max_err(np.linalg.norm(q, axis=1), 1.0) < 1e-15 * 4
    assert max_err(q, wxyz(Rotation.from_rotvec(v).as_quat())) < 1e-14 * 4
    assert max_err(so3.quaternion_log(q), v) < 1e-12
    assert max_err(so3.quaternion_log(-q), v) < 1e-12  # the short way round
    assert max_err(so3.matrices_from_quaternions(q), so3.exp(v)) < 1e-14
    assert max_err(so3.quaternion_log(np.array([1.0, 0, 0, 0])), 0.0) == 0.0


def test_canonical_quaternions(rng):
    q = rng.standard_normal((500, 4)) * 3
    c = so3.canonical_quaternions(q)
    assert np.all(c[:, 0] >= 0)
    assert max_err(np.linalg.norm(c, axis=1), 1.0) < 1e-15 * 4
    assert max_err(so3.matrices_from_quaternions(c), so3.matrices_from_quaternions(q)) < 1e-14
    np.testing.assert_array_equal(so3.canonical_quaternions(-q), c)
    # w == 0 tie broken on the first nonzero entry, so q and -q still agree
    t = np.array([[0.0, -0.6, 0.8, 0.0], [0.0, 0.0, -1.0, 0.0]])
    np.testing.assert_array_equal(so3.canonical_quaternions(t), so3.canonical_quaternions(-t))
    np.testing.assert_allclose(so3.canonical_quaternions(t), [[0, 0.6, -0.8, 0], [0, 0, 1, 0]], atol=1e-15)


# --------------------------------------------------------------------------- single items


SINGLE_ITEM_CASES = {
    "exp": (lambda x: so3.exp(x), "v"),
    "log": (lambda x: so3.log(x), "R"),
    "angle": (lambda x: so3.angle(x), "R"),
    "quaternions_from_matrices": (lambda x: so3.quaternions_from_matrices(x), "R"),
    "matrices_from_quaternions": (lambda x: so3.matrices_from_quaternions(x), "q"),
    "quaternion_log": (lambda x: so3.quaternion_log(x), "q"),
    "quaternion_exp": (lambda x: so3.quaternion_exp(x), "v"),
    "canonical_quaternions": (lambda x: so3.canonical_quaternions(x), "q"),
    "is_rotation": (lambda x: so3.is_rotation(x), "R"),
    "project_to_so3": (lambda x: so3.project_to_so3(x), "M"),
}


@pytest.mark.parametrize(
    "name",
    [
        n
        for n in SINGLE_ITEM_CASES
    ],
)
def test_single_item_equals_batch_of_one(name, rng):
    """The module promises every function takes a single item and returns the same kind."""
    fn, kind = SINGLE_ITEM_CASES[name]
    x = {
        "v": rng.standard_normal(3),
        "R": Rotation.random(random_state=rng).as_matrix(),
        "q": rng.standard_normal(4),
        "M": rng.standard_normal((3, 3)),
    }[kind]
    single = np.asarray(fn(x))
    batch = np.asarray(fn(x[None]))
    assert single.shape == batch.shape[1:]
    np.testing.assert_allclose(single, batch[0], rtol=0, atol=1e-15)


# --------------------------------------------------------------------------- projection


def _frob_to(M):
    return lambda R: np.linalg.norm(R - M, axis=(-2, -1))


def test_project_identity_on_rotations(rng):
    R = Rotation.random(200, random_state=rng).as_matrix()
    assert max_err(so3.project_to_so3(R), R) < 1e-14
    # idempotent on arbitrary input
    P = so3.project_to_so3(rng.standard_normal((200, 3, 3)))
    assert max_err(so3.project_to_so3(P), P) < 1e-14


@pytest.mark.parametrize("kind", ["noisy", "general", "reflection"])
def test_project_minimises_frobenius(kind, rng):
    n = 8
    R = Rotation.random(n, random_state=rng).as_matrix()
    if kind == "noisy":
        M = R + 0.3 * rng.standard_normal((n, 3, 3))
    elif kind == "general":
        M = 2.0 * rng.standard_normal((n, 3, 3))
    else:
        M = -R + 0.05 * rng.standard_normal((n, 3, 3))  # det < 0
        assert np.all(np.linalg.det(M) < 0)
    P = so3.project_to_so3(M)
    # a proper rotation
    assert max_err(P @ np.swapaxes(P, 1, 2), np.eye(3)) < 1e-14
    assert max_err(np.linalg.det(P), 1.0) < 1e-14
    for Mi, Pi in zip(M, P):
        f = _frob_to(Mi)
        best = f(Pi)
        # random rotations near P (at several scales) and uniformly random ones are no closer
        for s in (1e-4, 1e-2, 0.3):
            near = Pi @ Rotation.from_rotvec(s * rng.standard_normal((300, 3))).as_matrix()
            assert f(near).min() >= best - 1e-12
        assert f(Rotation.random(2000, random_state=rng).as_matrix()).min() >= best - 1e-12
        # local optimisation of ||R0 exp(v) - M|| from several starts does no better
        for R0 in [Pi, *Rotation.random(3, random_state=rng).as_matrix()]:
            r = optimize.minimize(
                lambda v: f(R0 @ rodrigues(v)),
                np.zeros(3),
                method="Nelder-Mead",
                options=dict(xatol=1e-10, fatol=1e-14, maxiter=4000,
                             initial_simplex=np.vstack([np.zeros(3), 0.5 * np.eye(3)])),
            )
            assert r.fun >= best - 1e-10
    # the closed form: U diag(1, 1, det(U V^T)) V^T
    U, _, Vt = np.linalg.svd(M)
    D = np.ones((n, 3))
    D[:, 2] = np.sign(np.linalg.det(U @ Vt))
    assert max_err(P, (U * D[:, None, :]) @ Vt) < 1e-12


def test_project_reflection_of_rotation():
    # -I is a pure reflection (det -1); nearest rotations are the half turns, at distance 2
    P = so3.project_to_so3(-np.eye(3)[None])[0]
    assert max_err(P @ P.T, np.eye(3)) < 1e-15
    assert np.linalg.det(P) == pytest.approx(1.0, abs=1e-15)
    assert np.linalg.norm(P + np.eye(3)) == pytest.approx(2.0, abs=1e-14)
    # diag(1, 1, -1): the nearest rotation is I, at distance 2
    P = so3.project_to_so3(np.diag([1.0, 2.0, -0.5])[None])[0]
    assert max_err(P, np.eye(3)) < 1e-15


# --------------------------------------------------------------------------- is_rotation


def test_is_rotation_and_errors(rng):
    R = Rotation.random(100, random_state=rng).as_matrix()
    assert so3.is_rotation(R).all()
    q, err = so3.rotation_errors(R)
    assert err.max() < 1e-14
    assert max_err(w_nonneg(q.T), so3.quaternions_from_matrices(R)) == 0.0
    shear = np.eye(3)
    shear[0, 1] = 1e-3
    bad = {
        "reflection": -R,
        "mirror": R @ np.diag([1.0, 1.0, -1.0]),
        "scaled": 1.001 * R,
        "shrunk": 0.5 * R,
        "sheared": R @ shear,
        "zero": np.zeros_like(R),
        "nan": np.where(np.arange(9).reshape(3, 3) == 4, np.nan, R),
        "inf": np.where(np.arange(9).reshape(3, 3) == 0, np.inf, R),
    }
    for name, B in bad.items():
        assert not so3.is_rotation(B).any(), name
        _, e = so3.rotation_errors(B)
        assert np.all(e > 1e-5), name
    assert np.all(np.isinf(so3.rotation_errors(bad["nan"])[1]))
    # reflections are far from every rotation
    assert so3.rotation_errors(bad["reflection"])[1].min() > 0.1
    # mixed batch: exactly the bad items are flagged
    mixed = R.copy()
    mixed[[3, 7, 11]] = bad["reflection"][[3, 7, 11]]
    mixed[20, 1, 1] = np.nan
    expect = np.ones(len(R), bool)
    expect[[3, 7, 11, 20]] = False
    np.testing.assert_array_equal(so3.is_rotation(mixed), expect)
    # tolerance semantics: 1e-9 perturbation passes the default tol, 1e-4 does not
    assert so3.is_rotation(R + 1e-9 * rng.standard_normal(R.shape)).all()
    assert not so3.is_rotation(R + 1e-4 * np.sign(rng.standard_normal(R.shape))).any()
    assert so3.is_rotation(R + 1e-4 * np.sign(rng.standard_normal(R.shape)), tol=1e-2).all()
    # single matrix
    assert bool(so3.is_rotation(R[0])) and not bool(so3.is_rotation(-R[0]))


# --------------------------------------------------------------------------- random


def test_random_rotations_uniform(rng):
    R = so3.random_rotations(20000, rng=rng)
    assert max_err(R @ np.swapaxes(R, 1, 2), np.eye(3)) < 1e-14
    assert np.all(np.linalg.det(R) > 0)
    # Haar: E[R] = 0 (entries have variance 1/3, so the sample mean has sd 0.004)
    assert np.abs(R.mean(axis=0)).max() < 0.02
    # Haar: E[R_ij R_kl] = delta_ik delta_jl / 3
    second = np.einsum("nij,nkl->ijkl", R, R) / len(R)
    expect = np.einsum("ik,jl->ijkl", np.eye(3), np.eye(3)) / 3
    assert np.abs(second - expect).max() < 0.02
    # the angle has density (1 - cos t) / pi, CDF (t - sin t) / pi
    theta = scipy_angle(R)
    assert theta.mean() == pytest.approx(PI / 2 + 2 / PI, abs=0.02)
    assert stats.kstest(theta, lambda t: (t - np.sin(t)) / PI).pvalue > 1e-3
    # reproducible, and a single rotation when n is None
    np.testing.assert_array_equal(so3.random_rotations(5, rng=7), so3.random_rotations(5, rng=7))
    one = so3.random_rotations(rng=3)
    assert one.shape == (3, 3) and bool(so3.is_rotation(one))


@pytest.mark.parametrize("sigma", [0.002, 0.02, 0.05])
def test_perturb_angle_statistics(sigma, rng):
    n = 20000
    R = Rotation.random(n, random_state=rng).as_matrix()
    P = so3.perturb(R, sigma, rng=rng)
    assert max_err(P @ np.swapaxes(P, 1, 2), np.eye(3)) < 1e-14
    # the perturbation acts on the right: R^T P = exp(e), e ~ N(0, sigma^2 I)
    e = Rotation.from_matrix(np.swapaxes(R, 1, 2) @ P).as_rotvec()
    theta = np.linalg.norm(e, axis=1)
    # Maxwell distribution of |e|: mean 2 sigma sqrt(2 / pi)
    assert theta.mean() == pytest.approx(2 * sigma * np.sqrt(2 / PI), rel=0.05)
    assert stats.kstest(theta, stats.maxwell(scale=sigma).cdf).pvalue > 1e-3
    np.testing.assert_allclose(e.std(axis=0), sigma, rtol=0.05)
    assert np.abs(e.mean(axis=0)).max() < 0.05 * sigma
    assert np.abs(np.corrcoef(e.T) - np.eye(3)).max() < 0.05
    # deterministic form of the same statement: with the same seed, perturb(R) = R perturb(I)
    Id = np.repeat(np.eye(3)[None], 50, axis=0)
    assert max_err(so3.perturb(R[:50], sigma, rng=5), R[:50] @ so3.perturb(Id, sigma, rng=5)) < 1e-14
    # sigma = 0 changes nothing
    assert max_err(so3.perturb(R[:10], 0.0, rng=rng), R[:10]) == 0.0


def test_qmul_rows_broadcasts_like_the_hamilton_product():
    rng = np.random.default_rng(3)
    a, b = rng.normal(size=(4, 5)), rng.normal(size=(4, 5))
    ref = np.stack([so3.quaternion_multiply(a[:, k], b[:, k]) for k in range(5)], axis=1)
    assert np.allclose(so3.qmul_rows(a, b), ref)
    assert np.allclose(so3.qmul_rows(a[:, :1], b), np.stack([so3.quaternion_multiply(a[:, 0], b[:, k]) for k in range(5)], axis=1))
    assert np.allclose(so3.qmul_rows(a[:, 0], b), so3.qmul_rows(a[:, :1], b))
    assert np.allclose(so3.qmul_rows(a[:, 0], b[:, 0]), ref[:, 0])


@pytest.mark.parametrize("outer_max", [0, 10**6])
def test_qmul_rows_table_and_elementwise_paths_agree(outer_max, monkeypatch):
    """Small products go through the (4, 16) table, large ones elementwise: same result."""
    rng = np.random.default_rng(3)
    a, b = rng.normal(size=(4, 50)), rng.normal(size=(4, 50))
    ref = np.stack([so3.quaternion_multiply(a[:, k], b[:, k]) for k in range(50)], axis=1)
    monkeypatch.setattr(so3_rows, "OUTER_MAX", outer_max)
    assert np.allclose(so3.qmul_rows(a, b), ref, atol=1e-14)


def test_conversions_in_blocks_agree_with_scipy(rng):
    """Batches larger than one conversion block (and not a multiple of it) give scipy's
    quaternions and matrices, at every angle (both Shepperd branches, across block edges)."""
    n = 3 * (so3_rows.CONVERT_BLOCK + 17)
    R = Rotation.random(n, random_state=rng).as_matrix()
    xyzw = Rotation.from_matrix(R).as_quat()
    expect = np.where(xyzw[:, 3:] < 0, -1.0, 1.0) * np.roll(xyzw, 1, axis=1)  # (w, x, y, z), w >= 0
    q_rows = so3.quaternion_rows_from_matrices(R)
    assert q_rows.shape == (4, n) and q_rows.flags.c_contiguous
    assert max_err(q_rows.T, expect) < 1e-14
    assert max_err(so3.quaternions_from_matrices(R.reshape(3, -1, 3, 3)).reshape(-1, 4), expect) < 1e-14
    assert max_err(so3.matrices_from_quaternion_rows(q_rows), R) < 1e-14
    assert max_err(so3.matrices_from_quaternions(expect.reshape(-1, 1, 4)).reshape(-1, 3, 3), R) < 1e-14


# --------------------------------------------------------------------------- the quaternion check


def _reference_check_quaternions(q, lines):
    """check_quaternions before it was blocked (one pass over the whole batch): what it raised
    or warned and returned."""
    q = np.asarray(q, dtype=np.float64)
    finite = np.isfinite(q).all(axis=1)
    if not finite.all():
        return ("error", "quaternion is not finite", int(lines[np.argmax(~finite)]))
    norm = np.sqrt(np.einsum("ij,ij->i", q, q))
    zero = ~(norm >= so3.QUATERNION_ZERO)
    if zero.any():
        return ("error", "zero quaternion (all four components 0)", int(lines[np.argmax(zero)]))
    off = np.abs(norm - 1.0) > so3.QUATERNION_UNIT_TOL
    warn = None
    if off.any():
        warn = (f"{int(off.sum())} of {len(q)} quaternions are not unit length (the first at line "
                f"{int(lines[np.argmax(off)])}); | |q| - 1 | up to {float(np.abs(norm - 1.0).max()):.3g}; normalised")
    return ("ok", q / norm[:, None], warn)


@pytest.mark.parametrize("case", ["clean", "scaled", "zero", "nan", "zero then nan", "nan then zero"])
def test_check_quaternions_rows_and_blocks_agree(case, caplog, monkeypatch):
    """check_quaternions and check_quaternion_rows (the readers' blocked check) are one check:
    the same result, error (a non-finite quaternion before a zero one, in any block) and warning,
    whatever the block size."""
    from rotgraph.errors import InputError

    rng = np.random.default_rng(11)
    n = 1000
    q = so3.canonical_quaternions(rng.standard_normal((n, 4)))
    if case == "scaled":
        q[[5, 700, 701]] *= [[3.0], [0.5], [1.0005]]
    bad = {"zero": [(600, 0.0)], "nan": [(600, np.nan)], "zero then nan": [(100, 0.0), (900, np.inf)],
           "nan then zero": [(100, np.nan), (900, 0.0)]}.get(case, [])
    for k, v in bad:
        q[k] = v
    lines = np.arange(n) * 2 + 3
    expect = _reference_check_quaternions(q, lines)
    for block in (64, 1 << 16):
        monkeypatch.setattr(so3_checks, "QUATERNION_BLOCK", block)
        for rows in (False, True):
            caplog.clear()
            call = (lambda: so3.check_quaternion_rows(list(q.T), path="f.txt", lines=lines).T) if rows else (
                lambda: so3.check_quaternions(q, path="f.txt", lines=lines))
            if expect[0] == "error":
                with pytest.raises(InputError) as exc:
                    call()
                assert (exc.value.line, str(exc.value)) == (expect[2], f"f.txt:{expect[2]}: {expect[1]}")
                continue
            got = call()
            np.testing.assert_array_equal(got, expect[1])
            warnings = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
            assert warnings == ([] if expect[2] is None else [f"f.txt: {expect[2]}"])


def test_rows_layout_matches_the_batched_functions():
    """matrix_rows, matmul_rows and right_jacobian_inverse_rows (component-major, (3, 3, K))
    give what matrices_from_quaternion_rows, matmul and right_jacobian_inverse give on
    (K, 3, 3) stacks, at small, ordinary and near-pi angles."""
    rng = np.random.default_rng(5)
    R = so3.random_rotations(40, rng)
    q = so3.quaternion_rows_from_matrices(R)
    rows = lambda M: np.moveaxis(M, 0, -1)  # noqa: E731 - (K, 3, 3) -> (3, 3, K)
    np.testing.assert_allclose(so3.matrix_rows(q), rows(R), atol=1e-15)
    A, B = rng.standard_normal((2, 40, 3, 3))
    np.testing.assert_allclose(so3.matmul_rows(rows(A), rows(B)), rows(A @ B), atol=1e-14)
    # in blocks above MATMUL_ROWS_BLOCK edges: the same products, bit for bit
    A, B = rng.standard_normal((2, 3, 3, 2 * so3.MATMUL_ROWS_BLOCK + 7))
    assert np.array_equal(so3.matmul_rows(A, B), (A[:, :, None, :] * B[None, :, :, :]).sum(axis=1))
    phi = rng.standard_normal((40, 3))
    phi /= np.linalg.norm(phi, axis=1)[:, None]
    phi *= np.concatenate([np.full(10, 1e-9), np.full(10, 1e-3), rng.uniform(0.1, 3.0, 10), np.full(10, np.pi - 1e-6)])[:, None]
    K = so3.hat(phi)
    expected = np.eye(3) + 0.5 * K + so3.right_jacobian_inverse_coefficient(np.linalg.norm(phi, axis=1))[:, None, None] * (K @ K)
    np.testing.assert_allclose(so3.right_jacobian_inverse_rows(phi.T), rows(expected), atol=1e-12)
    np.testing.assert_allclose(so3.right_jacobian_inverse(phi), expected, atol=1e-12)
    # its defining property: log(exp(phi) exp(d)) = phi + J_r^-1(phi) d + O(|d|^2)
    ok = np.linalg.norm(phi, axis=1) < 3.0
    d = 1e-7 * rng.standard_normal((40, 3))
    moved = so3.log(so3.exp(phi[ok]) @ so3.exp(d[ok]))
    np.testing.assert_allclose(moved - phi[ok], np.einsum("eab,eb->ea", expected[ok], d[ok]), atol=1e-12)
