"""Rigs with unknown, partly known or fixed extrinsics (issue #17): the joint solve of frame
rotations and cam_from_rig (rotgraph.estimators.rig_calibration), the rig file, the CLI."""

import json
import logging

import numpy as np
import pytest
from scipy.optimize import least_squares

from rotgraph import average_rotations, compare_rotations, so3
from rotgraph.errors import InputError
from rotgraph.estimators.rig_calibration import sensor_table
from rotgraph.estimators.rig_refine import joint_refine
from rotgraph.io.rigs import read_rigs
from rotgraph.io.writers import write_absolute_rotations_text, write_edges, write_rigs
from rotgraph.pipeline.solve import default_options
from rotgraph.synth import random_rig_problem
from rotgraph.viewgraph import Rigs, ViewGraph

from cli_helpers import run


def _ext_error_deg(res, g):
    s = res.sensors
    ok = np.isfinite(s.cam_from_rig).all(axis=(1, 2))
    return np.degrees(so3.angle_between(s.cam_from_rig[ok], g.meta["gt_cam_from_rig"][s.sensor_ids[ok]]))


@pytest.mark.parametrize("kw", [dict(), dict(sensors=4, rigs=2, missing=0.2), dict(known="half", sensors=5),
                                dict(within_frame=0.0, degree=6, n_frames=30)])
def test_noise_free_rigs_are_exact(kw):
    g = random_rig_problem(sigma_deg=0.0, **kw)
    res = average_rotations(g)
    assert res.solved.all()
    assert compare_rotations(res.cam_from_world, g.gt_cam_from_world).max < 1e-6
    assert _ext_error_deg(res, g).max() < 1e-6
    assert set(res.sensors.status) <= {"reference", "estimated", "fixed"}
    assert (res.sensors.status == "estimated").sum() == (sensor_table(g.rigs, "auto").status == "estimated").sum()


def test_gauge_invariance():
    """Turning the world (every frame F -> F Q) changes no extrinsic and turns the answer by Q."""
    g = random_rig_problem(sigma_deg=1.0, outliers=0.1, sensors=3, seed=3)
    Q = so3.exp(np.array([0.3, -1.1, 0.7]))
    res = average_rotations(g)
    res2 = average_rotations(g, init="chordal")  # a different start: the same optimum
    np.testing.assert_allclose(so3.angle_between(res.sensors.cam_from_rig, res2.sensors.cam_from_rig), 0, atol=1e-5)
    R = res.cam_from_world
    # relative rotations do not see the gauge: the same solve on a world turned by Q
    g2 = random_rig_problem(sigma_deg=1.0, outliers=0.1, sensors=3, seed=3)
    g2.gt_cam_from_world = g2.gt_cam_from_world @ Q
    res3 = average_rotations(g2)
    np.testing.assert_allclose(so3.angle_between(res3.sensors.cam_from_rig, res.sensors.cam_from_rig), 0, atol=1e-12)
    assert compare_rotations(res3.cam_from_world, g2.gt_cam_from_world).median == pytest.approx(
        compare_rotations(R, g.gt_cam_from_world).median, rel=1e-9)


@pytest.mark.parametrize("whitened", [False, True])
def test_joint_refine_is_the_least_squares_minimum(whitened):
    """With fixed weights, the joint Gauss-Newton equals a brute-force least-squares
    minimisation over (frames, extrinsics) of sum u |log(R_b^T R_ab R_a)|^2, or with
    anisotropic information matrices H (an error in camera b's frame) of
    sum u d^T H d, d = R_b log(R_b^T R_ab R_a): its Jacobians are exact (with the identity in
    place of J_r^-1 its fixed point was 0.1 deg off at this noise)."""
    g = random_rig_problem(n_frames=6, sensors=3, degree=6, sigma_deg=3.0, seed=5)
    t = sensor_table(g.rigs, "unknown")
    _, group = np.unique(g.rigs.frame_ids, return_inverse=True)
    rng = np.random.default_rng(0)
    F0 = np.stack([g.gt_cam_from_world[np.flatnonzero((group == f) & (t.status[t.of_image] == "reference"))[0]]
                   for f in range(group.max() + 1)])
    F0 = F0 @ so3.exp(rng.normal(0, 0.03, (len(F0), 3)))
    S0 = g.meta["gt_cam_from_rig"] @ so3.exp(rng.normal(0, 0.03, (3, 3)))
    S0[0] = np.eye(3)
    free = t.status == "estimated"
    u, H, L = np.ones(g.n_edges), None, None
    if whitened:
        u = rng.uniform(0.5, 2.0, g.n_edges)
        Q = so3.random_rotations(g.n_edges, rng)
        H = Q @ (np.exp(rng.uniform(-2.0, 2.0, (g.n_edges, 3)))[:, :, None] * np.swapaxes(Q, 1, 2))  # spread e^4
        L = np.linalg.cholesky(H)
    F, S, it = joint_refine(g, group, F0, np.broadcast_to(np.eye(3), (g.n_nodes, 3, 3)), t.of_image, S0, free, u, 0,
                            information=H)
    assert it < 20

    def residuals(x):
        Fx = F0.copy()
        Fx[1:] = so3.exp(x[: 3 * (len(F0) - 1)].reshape(-1, 3)) @ F0[1:]
        Sx = S0.copy()
        Sx[free] = so3.exp(x[3 * (len(F0) - 1):].reshape(-1, 3)) @ S0[free]
        R = Sx[t.of_image] @ Fx[group]
        a, b = g.edges[:, 0], g.edges[:, 1]
        r = so3.log(np.swapaxes(R[b], 1, 2) @ g.cam2_from_cam1 @ R[a])
        if L is not None:  # sqrt(u) L^T d: its square is u d^T H d
            r = np.einsum("eba,eb->ea", L, np.einsum("eab,eb->ea", R[b], r))
        return (np.sqrt(u)[:, None] * r).ravel()

    x = least_squares(residuals, np.zeros(3 * (len(F0) - 1 + free.sum())), xtol=1e-15, ftol=1e-15, gtol=1e-15).x
    F_bf = F0.copy()
    F_bf[1:] = so3.exp(x[: 3 * (len(F0) - 1)].reshape(-1, 3)) @ F0[1:]
    S_bf = S0.copy()
    S_bf[free] = so3.exp(x[3 * (len(F0) - 1):].reshape(-1, 3)) @ S0[free]
    assert np.degrees(so3.angle_between(S[free], S_bf[free])).max() < 1e-7
    assert np.degrees(so3.angle_between(F, F_bf)).max() < 1e-7


@pytest.mark.parametrize("seed", [0, 1])
def test_unknown_extrinsics_recover_the_truth_under_noise_and_outliers(seed):
    g = random_rig_problem(n_frames=60, sensors=4, sigma_deg=2.0, outliers=0.15, seed=seed)
    known = random_rig_problem(n_frames=60, sensors=4, sigma_deg=2.0, outliers=0.15, seed=seed, known="all")
    res = average_rotations(g)
    oracle = average_rotations(known)  # the extrinsics given exactly
    e = compare_rotations(res.cam_from_world, g.gt_cam_from_world).median
    e0 = compare_rotations(oracle.cam_from_world, g.gt_cam_from_world).median
    assert e <= 1.15 * e0
    assert _ext_error_deg(res, g).max() < 0.5
    # the wrong edges are flagged, the right ones kept
    out = g.meta["outlier"]
    assert (~res.inliers[out]).mean() > 0.95 and res.inliers[~out].mean() > 0.95
    # far better than solving each unknown sensor's images on their own
    alone = average_rotations(g, rig_extrinsics="fixed")
    assert e < 0.8 * compare_rotations(alone.cam_from_world, g.gt_cam_from_world).median


def test_refine_corrects_wrong_given_extrinsics_and_fixed_keeps_them():
    g = random_rig_problem(n_frames=40, sensors=3, sigma_deg=1.0, outliers=0.05, known="all", seed=2)
    rng = np.random.default_rng(1)
    wrong = g.rigs.cam_from_rig.copy()
    nonref = ~g.rigs.is_reference
    bias = {k: so3.exp(rng.normal(0, np.radians(3), 3)) for k in np.unique(g.rigs.sensor_ids[nonref])}
    for k, B in bias.items():
        wrong[g.rigs.sensor_ids == k] = B @ wrong[g.rigs.sensor_ids == k]
    g.rigs = Rigs(g.rigs.frame_ids, wrong, g.rigs.sensor_ids, g.rigs.is_reference)
    fixed = average_rotations(g)  # auto: given ones fixed
    refined = average_rotations(g, rig_extrinsics="refine")
    assert fixed.sensors is None
    assert set(refined.sensors.status) == {"reference", "refined"}
    assert _ext_error_deg(refined, g).max() < 0.4
    e_fixed = compare_rotations(fixed.cam_from_world, g.gt_cam_from_world).median
    e_ref = compare_rotations(refined.cam_from_world, g.gt_cam_from_world).median
    assert e_ref < 0.5 * e_fixed
    unknown = average_rotations(g, rig_extrinsics="unknown")  # the given values ignored
    assert set(unknown.sensors.status) == {"reference", "estimated"} and _ext_error_deg(unknown, g).max() < 0.4


def test_a_sensor_never_seen_with_a_calibrated_one_is_reported(caplog):
    """Sensor 2 is only in frames without its rig's reference (and no pair within those
    frames): no frame gives its rotation in the rig. Not a guess: unobservable, a warning,
    its images solved on their own."""
    g = random_rig_problem(n_frames=20, sensors=3, sigma_deg=0.5, seed=4)
    keep = ~((g.rigs.sensor_ids == 2) & (g.rigs.frame_ids < 10)) & ~((g.rigs.sensor_ids == 0) & (g.rigs.frame_ids >= 10))
    keep &= ~((g.rigs.sensor_ids == 1) & (g.rigs.frame_ids >= 10))
    sub = g.subgraph(np.flatnonzero(keep))[0]
    with caplog.at_level(logging.WARNING, logger="rotgraph"):
        res = average_rotations(sub)
    st = dict(zip(res.sensors.sensor_ids.tolist(), res.sensors.status.tolist()))
    assert st[2] == "unobservable" and st[1] == "estimated"
    assert not np.isfinite(res.sensors.cam_from_rig[res.sensors.sensor_ids == 2]).any()
    assert "never seen in a frame with a calibrated sensor" in caplog.text
    assert res.n_solved == np.bincount(sub.components()).max()  # the whole largest component


def test_rig_file_round_trip_and_errors(tmp_path):
    g = random_rig_problem(sensors=4, rigs=2, missing=0.2, known="half")
    write_rigs(tmp_path / "rigs.txt", g.node_ids, g.rigs)
    bare = ViewGraph.from_edges(g.node_ids[g.edges[:, 0]], g.node_ids[g.edges[:, 1]], g.cam2_from_cam1)
    r = read_rigs(tmp_path / "rigs.txt", bare)
    np.testing.assert_array_equal(r.frame_ids, g.rigs.frame_ids)
    np.testing.assert_array_equal(r.sensor_ids, g.rigs.sensor_ids)
    np.testing.assert_array_equal(r.is_reference, g.rigs.is_reference)
    np.testing.assert_allclose(np.nan_to_num(r.cam_from_rig, nan=7), np.nan_to_num(g.rigs.cam_from_rig, nan=7), atol=1e-12)
    # CSV with a header, no quaternions: references are the smallest sensor id of each rig
    (tmp_path / "rigs.csv").write_text("image_id,frame_id,sensor_id\n" + "".join(
        f"{i},{f},{s}\n" for i, f, s in zip(g.node_ids, g.rigs.frame_ids, g.rigs.sensor_ids)))
    r = read_rigs(tmp_path / "rigs.csv", bare)
    np.testing.assert_array_equal(r.is_reference, g.rigs.sensor_ids % 4 == 0)
    assert not np.isfinite(r.cam_from_rig[~r.is_reference]).any()
    bad = {"twice.txt": ("0 0 0\n0 1 0\n", 2, "listed twice"),
           "short.txt": ("0 0 0\n1 0\n", 2, ""),
           "partial.txt": ("0 0 0 1 0 0 0\n1 0 1 1 0\n", 2, ""),
           "clash.txt": ("0 0 1 0 1 0 0\n1 1 1 0 0 1 0\n3 0 0\n", 2, "another cam_from_rig"),
           "none.txt": ("9999 0 0\n", None, "none of the")}
    for name, (text, line, words) in bad.items():
        (tmp_path / name).write_text(text)
        with pytest.raises(InputError) as exc:
            read_rigs(tmp_path / name, bare)
        assert exc.value.line == line and words in str(exc.value), (name, str(exc.value))


def test_cli_solve_with_a_rig_file(tmp_path):
    g = random_rig_problem(sensors=3, sigma_deg=1.0, outliers=0.1, known="none", seed=6)
    write_edges(tmp_path / "e.txt", g)
    write_rigs(tmp_path / "rigs.txt", g.node_ids, g.rigs)
    write_absolute_rotations_text(tmp_path / "gt.txt", g.node_ids, g.gt_cam_from_world)
    r = run("solve", tmp_path / "e.txt", "-o", tmp_path / "r.csv", "--rigs", tmp_path / "rigs.txt",
            "--extrinsics-out", tmp_path / "x.csv", "--frames-out", tmp_path / "f.csv", "--json")
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert s["n_frames"] == 20 and [x["status"] for x in s["sensors"]] == ["reference", "estimated", "estimated"]
    lines = (tmp_path / "x.csv").read_text().splitlines()
    assert lines[0] == "sensor_id,status,qw,qx,qy,qz,n_frames,spread_deg,n_outlier_frames" and len(lines) == 4
    q = np.array([[float(v) for v in ln.split(",")[2:6]] for ln in lines[1:]])
    S = so3.matrices_from_quaternions(q)
    assert np.degrees(so3.angle_between(S, g.meta["gt_cam_from_rig"])).max() < 0.5
    frames = (tmp_path / "f.csv").read_text().splitlines()
    assert frames[0] == "frame_id,qw,qx,qy,qz" and len(frames) == 21
    ev = run("eval", tmp_path / "r.csv", tmp_path / "gt.txt", "--json")
    assert json.loads(ev.stdout)["median"] < 0.5
    # a bad rig file: file and line, exit 3, nothing written
    (tmp_path / "bad.txt").write_text("0 0 0\n0 1 0\n")
    r = run("solve", tmp_path / "e.txt", "-o", tmp_path / "r2.csv", "--rigs", tmp_path / "bad.txt")
    assert r.exit_code == 3 and "bad.txt:2:" in r.output and not (tmp_path / "r2.csv").exists()
    # no rigs: --frames-out is a clear error
    r = run("solve", tmp_path / "e.txt", "-o", tmp_path / "r3.csv", "--frames-out", tmp_path / "f3.csv")
    assert r.exit_code != 0 and "need an input with rigs" in r.output and not (tmp_path / "r3.csv").exists()


def test_overconfident_within_frame_pairs_do_not_pull_the_extrinsics():
    """Pairs within a frame are near-panoramic in real rigs: their relative rotations can be
    0.5 deg off while the information from their matches claims 0.005 deg (measured on
    pycolmap's synthetic rigs). The joint refinement scales their weight by how much noisier
    they really are than the frame-to-frame pairs, so the extrinsics stay as good as without
    them."""
    g = random_rig_problem(n_frames=40, sensors=3, sigma_deg=0.5, degree=12, seed=8)
    rng = np.random.default_rng(0)
    within = g.rigs.frame_ids[g.edges[:, 0]] == g.rigs.frame_ids[g.edges[:, 1]]
    rel = g.cam2_from_cam1.copy()
    rel[within] = so3.exp(rng.normal(0, np.radians(0.5), (int(within.sum()), 3))) @ rel[within]
    info = np.broadcast_to(np.eye(3) / np.radians(0.5) ** 2, (g.n_edges, 3, 3)).copy()
    info[within] = np.eye(3) / np.radians(0.005) ** 2  # 100x overconfident
    h = ViewGraph.from_edges(g.node_ids[g.edges[:, 0]], g.node_ids[g.edges[:, 1]], rel, node_ids=g.node_ids, information=info)
    h.rigs, h.gt_cam_from_world, h.meta = g.rigs, g.gt_cam_from_world, g.meta
    keep = np.flatnonzero(~within)
    h_without = ViewGraph.from_edges(g.node_ids[g.edges[keep, 0]], g.node_ids[g.edges[keep, 1]], rel[keep],
                                     node_ids=g.node_ids, information=info[keep])
    h_without.rigs, h_without.meta = g.rigs, g.meta
    e_with = _ext_error_deg(average_rotations(h), h).max()
    e_without = _ext_error_deg(average_rotations(h_without), h_without).max()
    assert e_with < 1.3 * e_without + 0.005, (e_with, e_without)


def test_a_sensor_seen_only_within_frames_is_estimated_from_those_pairs():
    """Round 0 leaves the pairs within a frame out; a sensor whose images have no other pair
    is then solved with them (noise-free: exactly)."""
    g = random_rig_problem(sigma_deg=0.0, sensors=3, seed=4)
    sid, fid = g.rigs.sensor_ids, g.rigs.frame_ids
    k = sid[~g.rigs.is_reference][0]
    a, b = g.edges[:, 0], g.edges[:, 1]
    touches_k = (sid[a] == k) | (sid[b] == k)
    within = fid[a] == fid[b]
    assert (touches_k & within).any()
    g2, _ = g.subgraph(np.arange(g.n_nodes), edge_mask=~touches_k | within)  # k's images: pairs within frames only
    res = average_rotations(g2)
    row = int(np.flatnonzero(res.sensors.sensor_ids == k)[0])
    assert res.sensors.status[row] == "estimated"
    assert _ext_error_deg(res, g2).max() < 1e-6
    assert compare_rotations(res.cam_from_world[res.solved], g2.gt_cam_from_world[res.solved]).max < 1e-6


def test_joint_refine_by_cg_equals_the_dense_solve(monkeypatch):
    """Above DENSE_MAX unknowns the joint refinement's normal equations go to block-Jacobi CG
    (NORMAL_RTOL): the same frames and extrinsics as the dense Cholesky."""
    import rotgraph.estimators.rig_refine as rr

    g = random_rig_problem(n_frames=30, sensors=3, degree=6, sigma_deg=1.0, seed=2)
    t = sensor_table(g.rigs, "unknown")
    _, group = np.unique(g.rigs.frame_ids, return_inverse=True)
    rng = np.random.default_rng(3)
    ref = np.flatnonzero(t.status[t.of_image] == "reference")
    F0 = np.empty((group.max() + 1, 3, 3))
    F0[group[ref]] = g.gt_cam_from_world[ref]
    F0 = F0 @ so3.exp(rng.normal(0, 0.02, (len(F0), 3)))
    S0 = g.meta["gt_cam_from_rig"] @ so3.exp(rng.normal(0, 0.02, (3, 3)))
    S0[0] = np.eye(3)
    free = t.status == "estimated"
    args = (g, group, F0, np.broadcast_to(np.eye(3), (g.n_nodes, 3, 3)), t.of_image, S0, free, np.ones(g.n_edges), 0)
    F_dense, S_dense, _ = joint_refine(*args, information=g.information)
    monkeypatch.setattr(rr, "DENSE_MAX", 0)
    F_cg, S_cg, _ = joint_refine(*args, information=g.information)
    assert np.degrees(so3.angle_between(S_cg, S_dense)).max() < 1e-8
    assert np.degrees(so3.angle_between(F_cg, F_dense)).max() < 1e-8
