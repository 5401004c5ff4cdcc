"""Rotation averaging with gravity priors (issue #17 item 3): rotgraph.estimators.gravity and
rotgraph.io.gravity."""

import numpy as np
import pytest

from rotgraph import so3
from rotgraph.errors import InputError
from rotgraph.estimators.gravity import (
    GRAVITY_WORLD,
    average_rotations_with_gravity,
    gravity_aligned_rotations,
    gravity_of,
    perturb_gravity,
    tilt_yaw_errors,
)
from rotgraph.estimators.rotation_averaging import average_rotations
from rotgraph.io.gravity import gravity_for_graph, read_gravity_file
from rotgraph.synth import random_problem


def test_gravity_aligned_rotations():
    g = so3.random_rotations(50, 0) @ GRAVITY_WORLD
    g[0] = [1.0, 0, 0]  # the other helper axis
    A = gravity_aligned_rotations(g)
    assert np.allclose(A[:, :, 1], g) and np.allclose(np.linalg.det(A), 1.0)
    assert np.allclose(A @ np.swapaxes(A, 1, 2), np.eye(3), atol=1e-12)


@pytest.mark.parametrize("outliers", [0.0, 0.15])
def test_noise_free_exact_gravity_is_recovered(outliers):
    g = random_problem(n=80, degree=8, sigma_deg=0.0, outliers=outliers, seed=1)
    R = g.gt_cam_from_world
    r = average_rotations(g, gravity=gravity_of(R), gravity_sigma_deg=0.0)
    e = tilt_yaw_errors(r.cam_from_world, R)
    assert np.nanmax(e.total_deg) < 1e-6
    # the solution is in the gravity frame: its gravity is the prior's exactly
    assert np.allclose(gravity_of(r.cam_from_world), gravity_of(R), atol=1e-12)
    # the outliers are flagged, and only they
    assert (r.inliers == ~g.meta["outlier"]).all()
    assert r.diagnostics["gravity"]["used"] and "exact" in r.diagnostics["gravity"]["error_model"]["tilt"]


def test_yaw_gauge_invariance():
    g = random_problem(n=60, degree=8, sigma_deg=1.0, outliers=0.1, seed=2)
    R = g.gt_cam_from_world
    grav = gravity_of(R)
    r1 = average_rotations(g, gravity=grav, gravity_sigma_deg=0.0)
    # the same problem in a world turned about gravity: the same gravity, the same answer up to yaw
    Y = so3.exp(0.7 * GRAVITY_WORLD)
    R2 = R @ Y.T
    assert np.allclose(gravity_of(R2), grav)
    r2 = average_rotations(g, gravity=gravity_of(R2), gravity_sigma_deg=0.0)
    e = tilt_yaw_errors(r1.cam_from_world, r2.cam_from_world)
    assert np.nanmax(e.total_deg) < 1e-6
    # and the yaw-aligned error against either truth is the same
    e1, e2 = tilt_yaw_errors(r1.cam_from_world, R), tilt_yaw_errors(r1.cam_from_world, R2)
    assert np.allclose(e1.total_deg, e2.total_deg, atol=1e-6)
    assert np.allclose(e1.tilt_deg, 0.0, atol=1e-9)


def test_tilt_yaw_errors_split():
    R = so3.random_rotations(20, 3)
    Y = so3.exp(np.deg2rad(2.0) * GRAVITY_WORLD)
    e = tilt_yaw_errors(R @ Y, R)  # a pure yaw error in the world frame: aligned away
    assert np.nanmax(e.total_deg) < 1e-9
    T = so3.exp(np.deg2rad(3.0) * np.array([1.0, 0, 0]))  # a tilt of every camera
    E = R @ T
    E[0] = np.nan
    e = tilt_yaw_errors(E, R)
    assert np.isnan(e.total_deg[0]) and np.allclose(e.tilt_deg[1:], 3.0) and np.allclose(e.yaw_deg[1:], 0.0, atol=1e-9)
    f = tilt_yaw_errors(E, R, align="full")  # the full gauge absorbs a common tilt
    assert np.nanmax(f.total_deg) < 1e-6


@pytest.mark.parametrize("sigma_g", [0.5, 2.0])
def test_noisy_gravity_beats_no_gravity(sigma_g):
    g = random_problem(n=150, degree=8, sigma_deg=2.0, outliers=0.1, seed=4)
    R = g.gt_cam_from_world
    grav = perturb_gravity(gravity_of(R), sigma_g, 5)
    r = average_rotations(g, gravity=grav, gravity_sigma_deg=sigma_g)
    r0 = average_rotations(g)
    e = tilt_yaw_errors(r.cam_from_world, R)
    e0 = tilt_yaw_errors(r0.cam_from_world, R, align="full")
    assert e.median_total < e0.median_total
    assert e.median_tilt < e0.median_tilt
    assert r.diagnostics["gravity"]["refined_3dof"]
    assert (r.inliers == ~g.meta["outlier"]).mean() > 0.99
    # the tilt moved within its noise: not held to the noisy gravity, not far from it
    t = np.degrees(np.arccos(np.clip((gravity_of(r.cam_from_world) * grav).sum(axis=1), -1, 1)))
    assert 0.2 * sigma_g < np.median(t) < 3 * sigma_g


def test_mixed_gravity_and_none():
    g = random_problem(n=100, degree=8, sigma_deg=0.0, outliers=0.1, seed=6)
    R = g.gt_cam_from_world
    grav = gravity_of(R)
    grav[np.random.default_rng(0).random(len(grav)) < 0.4] = np.nan
    r = average_rotations(g, gravity=grav, gravity_sigma_deg=0.0)
    # every camera the plain solve trusts (camera 59 has 3 outlier edges of 5: neither can)
    assert r.solved[average_rotations(g).solved].all()
    assert np.nanmax(tilt_yaw_errors(r.cam_from_world, R).total_deg) < 1e-6
    has = np.isfinite(grav).all(axis=1)
    assert np.allclose(gravity_of(r.cam_from_world)[has], grav[has], atol=1e-9)
    # no gravity at all: the plain solve
    r = average_rotations(g, gravity=np.full((g.n_nodes, 3), np.nan), gravity_sigma_deg=1.0)
    assert r.diagnostics["gravity"]["used"] is False


def test_bad_gravity_arrays():
    g = random_problem(n=10, degree=4, sigma_deg=0.0, seed=0)
    with pytest.raises(ValueError, match="gravity must be"):
        average_rotations_with_gravity(g, np.zeros((3, 3)), 0.0)
    z = gravity_of(g.gt_cam_from_world)
    z[2] = 0.0
    with pytest.raises(ValueError, match="zero vector"):
        average_rotations(g, gravity=z, gravity_sigma_deg=0.0)
    with pytest.raises(ValueError, match="sigma_deg"):
        average_rotations(g, gravity=gravity_of(g.gt_cam_from_world), gravity_sigma_deg=-1.0)


def test_priors_travel_with_the_graph():
    """Issue #30: the priors are data of the graph (``graph.with_gravity``), which the one
    pipeline solves with; the keywords of average_rotations and average_rotations_with_gravity
    are spellings of it."""
    g = random_problem(n=80, degree=8, sigma_deg=1.0, outliers=0.1, seed=3)
    grav = perturb_gravity(gravity_of(g.gt_cam_from_world), 0.5, 4)
    g2 = g.with_gravity(grav, 0.5)
    assert g.gravity is None and np.array_equal(g2.gravity.direction, grav) and g2.edges is g.edges
    r = average_rotations(g2)
    assert r.method == "gravity" and r.diagnostics["gravity"]["used"]
    for other in (average_rotations(g, gravity=grav, gravity_sigma_deg=0.5), average_rotations_with_gravity(g, grav, 0.5),
                  average_rotations(g2.with_gravity(grav[::-1].copy()), gravity=grav, gravity_sigma_deg=0.5)):
        assert np.array_equal(other.cam_from_world, r.cam_from_world) and other.cost == r.cost
    assert average_rotations(g2.with_gravity(None)).method == "adaptive"
    sub, _ = g2.subgraph(np.arange(40))  # a subgraph carries its images' priors
    assert np.array_equal(sub.gravity.direction, grav[:40]) and sub.gravity.sigma_deg == 0.5
    per_image = g.with_gravity(grav, np.full(g.n_nodes, 0.5)).subgraph(np.arange(10, 20))[0]
    assert per_image.gravity.sigma_deg.shape == (10,)
    with pytest.raises(ValueError, match="gravity must be"):
        g.with_gravity(grav[:5])


def _colmap_gravity_solve(pycolmap, g, grav):
    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(pycolmap.Camera(camera_id=1, model="SIMPLE_PINHOLE", width=1, height=1,
                                                    params=[1.0, 0.0, 0.0]))
    for k in range(g.n_nodes):
        rec.add_image_with_trivial_frame(pycolmap.Image(image_id=k + 1, camera_id=1))
    q = np.roll(so3.quaternion_rows_from_matrices(g.cam2_from_cam1), -1, axis=0).T  # x, y, z, w
    pg = pycolmap.PoseGraph()
    for (i, j), qk in zip(g.edges.tolist(), q):
        pg.add_edge(i + 1, j + 1, pycolmap.PoseGraphEdge(
            cam2_from_cam1=pycolmap.Rigid3d(rotation=pycolmap.Rotation3d(np.ascontiguousarray(qk)), translation=np.zeros(3))))
    priors = []
    for k in range(g.n_nodes):
        p = pycolmap.PosePrior()
        p.corr_data_id = rec.image(k + 1).data_id
        p.gravity = grav[k]
        priors.append(p)
    opts = pycolmap.RotationEstimatorOptions()
    opts.use_gravity = True
    assert pycolmap.run_rotation_averaging(opts, pg, rec, priors)
    return np.array([rec.image(k + 1).cam_from_world().rotation.matrix() for k in range(g.n_nodes)])


def test_agrees_with_colmap_use_gravity_conventions():
    pycolmap = pytest.importorskip("pycolmap")
    if not hasattr(pycolmap, "run_rotation_averaging") or not hasattr(pycolmap.RotationEstimatorOptions(), "use_gravity") \
            or not hasattr(pycolmap.PosePrior(), "gravity"):
        pytest.skip("pycolmap without gravity-aware rotation averaging")
    g = random_problem(n=40, degree=8, sigma_deg=1.0, outliers=0.0, seed=7)
    R = g.gt_cam_from_world
    grav = gravity_of(R)
    Rc = _colmap_gravity_solve(pycolmap, g, grav)
    # COLMAP keeps R_i (0, 1, 0) = g_i exactly, as rotgraph does
    assert np.allclose(gravity_of(Rc), grav, atol=1e-5)
    r = average_rotations(g, gravity=grav, gravity_sigma_deg=0.0)
    assert np.allclose(gravity_of(r.cam_from_world), grav, atol=1e-9)
    # the two solutions differ by a yaw only, and little
    e = tilt_yaw_errors(r.cam_from_world, Rc)
    assert np.nanmax(e.tilt_deg) < 1e-3 and e.median_yaw < 0.3


# --------------------------------------------------------------------------- files


def test_gravity_file_text_and_csv(tmp_path):
    p = tmp_path / "g.txt"
    p.write_text("# image_id gx gy gz [sigma_deg]\n3 0 9.81 0 0.5\n1 0 1 0\n")
    t = read_gravity_file(p)
    assert t.keys.tolist() == [3, 1] and np.allclose(t.gravity, [[0, 1, 0], [0, 1, 0]])
    assert t.sigma_deg[0] == 0.5 and np.isnan(t.sigma_deg[1]) and t.lines.tolist() == [2, 3]
    g, s = gravity_for_graph(t, np.array([1, 2, 3]), default_sigma_deg=1.0)
    assert np.isnan(g[1]).all() and np.allclose(g[[0, 2]], [[0, 1, 0]] * 2) and s.tolist() == [1.0, 1.0, 0.5]
    c = tmp_path / "g.csv"
    c.write_text("name,gx,gy,gz,sigma_deg\nb.jpg,0,0,1,\na.jpg,1,0,0,2\n")
    t = read_gravity_file(c)
    g, s = gravity_for_graph(t, np.array([10, 11]), names=np.array(["a.jpg", "b.jpg"]))
    assert np.allclose(g, [[1, 0, 0], [0, 0, 1]]) and s[0] == 2.0 and np.isnan(s[1])  # NaN: estimated by the solve


@pytest.mark.parametrize("body, line, message", [
    ("1 0 1 0\n2 0 0 0\n", 3, "zero"),
    ("1 0 1 0\n2 0 1\n", 3, "fields"),
    ("1 0 1 0\n2 0 x 0\n", 3, "not a number"),
    ("1 0 1 0 -2\n", 2, "sigma_deg must be >= 0"),
    ("1 0 1 0\n1 0 1 0\n", 3, "second gravity line"),
    ("1 0 inf 0\n", 2, "not finite"),
])
def test_bad_gravity_file_names_file_and_line(tmp_path, body, line, message):
    p = tmp_path / "grav.txt"
    p.write_text("# gravity\n" + body)
    with pytest.raises(InputError, match=message) as exc:
        read_gravity_file(p)
    assert exc.value.path == str(p) and exc.value.line == line
    assert str(exc.value).startswith(f"{p}:{line}: ") and "\n" not in str(exc.value)


def test_bad_gravity_csv_and_unmatched(tmp_path):
    p = tmp_path / "grav.csv"
    p.write_text("image_id,gx,gy\n1,0,1\n")
    with pytest.raises(InputError, match="gz") as exc:
        read_gravity_file(p)
    assert exc.value.line == 1
    p.write_text("image_id,gx,gy,gz,sigma_deg\n1,0,1,0,abc\n")
    with pytest.raises(InputError, match="sigma_deg") as exc:
        read_gravity_file(p)
    assert exc.value.line == 2
    p.write_text("image_id,gx,gy,gz\n7,0,1,0\n")
    with pytest.raises(InputError, match="no gravity line names an image"):
        gravity_for_graph(read_gravity_file(p), np.array([1, 2]))
    (tmp_path / "empty.txt").write_text("# nothing\n")
    with pytest.raises(InputError, match="no gravity directions"):
        read_gravity_file(tmp_path / "empty.txt")


def test_colmap_pose_prior_gravity(tmp_path):
    pycolmap = pytest.importorskip("pycolmap")
    from rotgraph.io.gravity import read_colmap_gravity

    opts = pycolmap.SyntheticDatasetOptions()
    opts.num_rigs, opts.num_frames_per_rig, opts.num_points3D = 1, 5, 30
    opts.prior_gravity = True
    path = tmp_path / "database.db"
    db = pycolmap.Database.open(str(path))
    rec = pycolmap.synthesize_dataset(opts, db)
    db.close()
    before = path.read_bytes()
    t = read_colmap_gravity(path)
    assert path.read_bytes() == before  # read-only
    assert len(t.keys) == rec.num_images()
    R = np.array([rec.image(int(k)).cam_from_world().rotation.matrix() for k in t.keys])
    assert np.allclose(t.gravity, gravity_of(R), atol=1e-6)


# --------------------------------------------------------------------------- estimated sigma


def _solve_errors(g, grav, sigma):
    r = average_rotations(g, gravity=grav, gravity_sigma_deg=sigma)
    return r, tilt_yaw_errors(r.cam_from_world, g.gt_cam_from_world).median_total


@pytest.mark.parametrize("sigma_g", [0.5, 1.0, 2.0])
def test_estimated_sigma(sigma_g):
    g = random_problem(n=300, degree=10, sigma_deg=2.0, outliers=0.1, seed=11)
    grav = perturb_gravity(gravity_of(g.gt_cam_from_world), sigma_g, 12)
    r, e_auto = _solve_errors(g, grav, None)
    d = r.diagnostics["gravity"]
    assert abs(d["sigma_deg_estimated"] / sigma_g - 1) < 0.3
    assert d["sigma_estimation"]["estimated"] and d["sigma_estimation"]["decision"] == "soft"
    assert d["gravity_outliers"] == []
    _, e_true = _solve_errors(g, grav, sigma_g)
    assert e_auto <= 1.05 * e_true
    if sigma_g >= 1.0:
        _, e_hard = _solve_errors(g, grav, 0.0)
        assert e_auto < 0.8 * e_hard
    # the default is the estimate
    assert np.array_equal(average_rotations(g, gravity=grav).cam_from_world, r.cam_from_world)


def test_estimated_sigma_exact_gravity_is_hard():
    g = random_problem(n=300, degree=10, sigma_deg=2.0, outliers=0.1, seed=13)
    grav = gravity_of(g.gt_cam_from_world)
    r = average_rotations(g, gravity=grav)
    d = r.diagnostics["gravity"]
    assert d["sigma_deg_estimated"] == 0.0 and d["sigma_estimation"]["decision"].startswith("hard")
    assert d["sigma_estimation"]["raw_sigma_deg"] < 0.3
    assert np.allclose(gravity_of(r.cam_from_world), grav, atol=1e-9)  # held exactly
    # noise-free: exact, with the default
    g = random_problem(n=80, degree=8, sigma_deg=0.0, outliers=0.15, seed=1)
    r = average_rotations(g, gravity=gravity_of(g.gt_cam_from_world))
    assert r.diagnostics["gravity"]["sigma_deg_estimated"] == 0.0
    assert np.nanmax(tilt_yaw_errors(r.cam_from_world, g.gt_cam_from_world).total_deg) < 1e-6


def test_estimated_sigma_noise_free_edges():
    g = random_problem(n=200, degree=10, sigma_deg=0.0, outliers=0.1, seed=14)
    grav = perturb_gravity(gravity_of(g.gt_cam_from_world), 1.0, 15)
    r, e = _solve_errors(g, grav, None)
    assert abs(r.diagnostics["gravity"]["sigma_deg_estimated"] - 1.0) < 0.3
    assert e < 0.2


@pytest.mark.parametrize("sigma_g", [0.0, 1.0])
def test_wrong_gravity_vectors_are_flagged(sigma_g):
    n = 300
    g = random_problem(n=n, degree=10, sigma_deg=2.0, outliers=0.1, seed=16)
    R = g.gt_cam_from_world
    grav = perturb_gravity(gravity_of(R), sigma_g, 17)
    rng = np.random.default_rng(18)
    bad = rng.choice(n, n // 20, replace=False)
    grav[bad] = so3.random_rotations(len(bad), rng) @ GRAVITY_WORLD  # wildly wrong
    r = average_rotations(g, gravity=grav)
    d = r.diagnostics["gravity"]
    flagged = set(d["gravity_outliers"])
    assert len(flagged & set(bad.tolist())) >= 0.8 * len(bad) and len(flagged - set(bad.tolist())) <= 1
    assert abs(d["sigma_deg_estimated"] - sigma_g) < 0.3 * max(sigma_g, 1.0)
    # not blown up: every camera solved, the error as on the clean gravity
    e = tilt_yaw_errors(r.cam_from_world, R)
    clean = perturb_gravity(gravity_of(R), sigma_g, 17)
    _, e_clean = _solve_errors(g, clean, None)
    assert r.solved[average_rotations(g).solved].all()
    assert e.median_total < 1.1 * e_clean and np.nanmax(e.total_deg[bad]) < 5.0


def test_estimated_sigma_per_image():
    # half the images have a given sigma (2 deg, true), the others (0.5 deg, true) are estimated
    g = random_problem(n=300, degree=10, sigma_deg=2.0, outliers=0.1, seed=3)
    half = np.arange(g.n_nodes) % 2 == 0
    s_true = np.where(half, 2.0, 0.5)
    grav = perturb_gravity(gravity_of(g.gt_cam_from_world), s_true, 7)
    r, e = _solve_errors(g, grav, np.where(half, 2.0, np.nan))
    d = r.diagnostics["gravity"]
    assert abs(d["sigma_deg_estimated"] - 0.5) < 0.15 and d["sigma_estimation"]["n_images"] == int((~half).sum())
    _, e_true = _solve_errors(g, grav, s_true)
    assert e <= 1.05 * e_true
    # given values only: nothing estimated
    r = average_rotations(g, gravity=grav, gravity_sigma_deg=s_true)
    assert r.diagnostics["gravity"]["sigma_deg_estimated"] is None if "sigma_deg_estimated" in r.diagnostics["gravity"] \
        else True
    with pytest.raises(ValueError, match="sigma_deg"):
        average_rotations(g, gravity=grav, gravity_sigma_deg=np.ones(5))
