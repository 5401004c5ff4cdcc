"""`rotgraph synth --rig/--gravity-noise`, `solve --gravity`, `eval --tilt-yaw` (issue #17,
items 3-4): the command line over rotgraph.estimators.gravity and the rig solve."""

import json

import numpy as np
import pytest

from rotgraph import average_rotations, compare_rotations
from rotgraph.estimators.gravity import gravity_of, perturb_gravity
from rotgraph.synth import random_rig_problem

from cli_helpers import run


@pytest.fixture(scope="module")
def rig_problem(tmp_path_factory):
    d = tmp_path_factory.mktemp("rigg")
    r = run("synth", "-o", d, "--rig", "3x40", "--sigma", "2", "--outliers", "0.1", "--gravity-noise", "1", "--seed", "2")
    assert r.exit_code == 0, r.output
    return d


def test_synth_rig_files(rig_problem):
    meta = json.loads((rig_problem / "meta.json").read_text())
    assert meta["rig"] == {"sensors": 3, "frames": 40, "rigs": 1, "known": "none", "within_frame": 1.0}
    assert meta["gravity_noise_deg"] == 1
    assert len((rig_problem / "rigs.txt").read_text().splitlines()) == 1 + 120
    assert (rig_problem / "gt_extrinsics.csv").read_text().splitlines()[0] == "sensor_id,qw,qx,qy,qz"
    g = np.array([[float(v) for v in ln.split()[1:]] for ln in (rig_problem / "gravity.txt").read_text().splitlines()[1:]])
    assert g.shape == (120, 3) and np.allclose(np.linalg.norm(g, axis=1), 1)


def test_solve_with_rigs_and_gravity_beats_either_alone(rig_problem):
    d = rig_problem
    errs = {}
    for name, extra in {"plain": [], "rigs": ["--rigs", d / "rigs.txt"],
                        "rigs+gravity": ["--rigs", d / "rigs.txt", "--gravity", d / "gravity.txt", "--gravity-sigma", "1"]}.items():
        r = run("solve", d / "edges.txt", "-o", d / f"{name}.csv", *extra, "--json")
        assert r.exit_code == 0, r.output
        if name == "rigs+gravity":
            assert json.loads(r.stdout)["gravity"]["n_with_gravity"] == 40  # one per frame
        ev = run("eval", d / f"{name}.csv", d / "gt.txt", "--tilt-yaw", "--json")
        errs[name] = json.loads(ev.stdout)
    assert errs["rigs"]["median"] < 0.8 * errs["plain"]["median"]
    assert errs["rigs+gravity"]["tilt_median_deg"] < errs["rigs"]["tilt_median_deg"]
    assert errs["rigs+gravity"]["median"] < errs["rigs"]["median"]
    # the summary line says what was estimated
    r = run("solve", d / "edges.txt", "-o", d / "x.csv", "--rigs", d / "rigs.txt")
    assert "sensor 1 estimated" in r.stdout


def test_gravity_file_errors(rig_problem, tmp_path):
    (tmp_path / "g.txt").write_text("0 0 1 0\n1 0 0 0\n")
    r = run("solve", rig_problem / "edges.txt", "-o", tmp_path / "r.csv", "--gravity", tmp_path / "g.txt")
    assert r.exit_code == 3 and "g.txt:2:" in r.output and not (tmp_path / "r.csv").exists()
    r = run("solve", rig_problem / "edges.txt", "-o", tmp_path / "r.csv", "--gravity", "colmap")
    assert r.exit_code == 3 and "COLMAP project" in r.output


def test_library_gravity_with_rigs_known_and_unknown_extrinsics():
    rng = np.random.default_rng(0)
    for known in ("all", "none"):
        g = random_rig_problem(n_frames=40, sensors=3, sigma_deg=2.0, outliers=0.1, known=known, seed=1)
        grav = perturb_gravity(gravity_of(g.gt_cam_from_world), 0.5, rng)
        base = compare_rotations(average_rotations(g).cam_from_world, g.gt_cam_from_world).median
        res = average_rotations(g, gravity=grav, gravity_sigma_deg=0.5)
        assert compare_rotations(res.cam_from_world, g.gt_cam_from_world).median < base
        if known == "none":
            assert (res.sensors.status == "estimated").sum() == 2
