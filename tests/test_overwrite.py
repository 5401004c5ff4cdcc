"""The output rule (docs/outputs.md, issue #28): nothing lost, nothing wrong.

An input is never an output; an existing file is replaced only when it is rotgraph's own
output from an earlier run (or empty), unless ``--overwrite``; a failed run leaves earlier
outputs as they were; a model folder is replaced as a whole model, never over a
reconstruction; a full disk is exit 3 naming the file. Each test checks bytes, not messages
alone. The random property test over the writing commands is tests/test_output_property.py.
"""

from __future__ import annotations

import errno
import json
import os
import stat
from pathlib import Path

import numpy as np
import pytest

from cli_helpers import run
from rotgraph.io import atomic
from rotgraph.io.atomic import atomic_write, output_group
from rotgraph.io.outputs import check_outputs, is_rotgraph_output, OWN_SIGNATURES
from rotgraph.io.writers import (write_absolute_rotations_text, write_camera_errors, write_edges, write_edges_csv,
                                 write_edges_npz, write_edges_text_blocks, write_frames, write_rigs, write_rotations,
                                 write_rotations_json, write_rotations_text)
from rotgraph.errors import InputError
from rotgraph.synth import random_problem


@pytest.fixture(scope="module")
def problem(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("problem")
    g = random_problem(n=30, degree=6, sigma_deg=1.0, outliers=0.0, graph="er", seed=3)
    write_edges(folder / "edges.txt", g)
    write_absolute_rotations_text(folder / "gt.txt", g.node_ids, g.gt_cam_from_world)
    return folder / "edges.txt"


def _snapshot(root: Path) -> dict[str, bytes]:
    out = {}
    for dirpath, _, files in os.walk(root):
        for f in files:
            p = Path(dirpath, f)
            if p.is_symlink():
                out[str(p)] = b"->" + os.readlink(p).encode()
            elif p.is_file():
                out[str(p)] = p.read_bytes()
    return out


# =========================================================================== whose file it is


def _rotations(n=4):
    from rotgraph import so3

    return so3.random_rotations(n, np.random.default_rng(0)) if hasattr(so3, "random_rotations") else \
        np.stack([np.eye(3)] * n)


WRITERS = {
    "rotations_csv": lambda p: write_rotations(p, np.arange(4), None, _rotations()),
    "rotations_text": lambda p: write_rotations_text(p, np.arange(4), None, _rotations()),
    "rotations_json": lambda p: write_rotations_json(p, np.arange(4), None, _rotations()),
    "gt_text": lambda p: write_absolute_rotations_text(p, np.arange(4), _rotations()),
    "edges_csv": lambda p: write_edges_csv(p, np.arange(3), np.arange(1, 4), np.ones(3), np.ones(3, bool)),
    "edges_csv_names": lambda p: write_edges_csv(p, np.arange(3), np.arange(1, 4), np.ones(3), np.ones(3, bool),
                                                 np.array(["a", "b", "c"]), np.array(["b", "c", "d"]), weight=np.ones(3)),
    "camera_errors": lambda p: write_camera_errors(p, np.arange(3), None, np.ones(3)),
    "frames": lambda p: write_frames(p, np.arange(4), _rotations()),
    "edges_text": lambda p: write_edges(p, random_problem(n=10, degree=4, sigma_deg=1.0, outliers=0.0, graph="er", seed=0)),
    "edges_text_info": lambda p: write_edges(p, random_problem(n=10, degree=4, sigma_deg=1.0, outliers=0.0, graph="er", seed=0, uncertainty_spread=2.0)),
    "edges_blocks": lambda p: write_edges_text_blocks(p, random_problem(n=10, degree=4, sigma_deg=1.0, outliers=0.0, graph="er", seed=0)),
    "edges_npz": lambda p: write_edges_npz(p, random_problem(n=10, degree=4, sigma_deg=1.0, outliers=0.0, graph="er", seed=0)),
}


@pytest.mark.parametrize("name", sorted(WRITERS))
def test_every_writer_writes_a_file_recognised_as_rotgraphs(name, tmp_path):
    p = tmp_path / "out"
    WRITERS[name](p)
    assert is_rotgraph_output(p)


def test_synth_batch_and_plot_files_are_recognised(problem, tmp_path):
    r = run("synth", "-o", tmp_path / "s", "--rig", "2x5", "--rig-known", "half", "--gravity-noise", "1", "-q")
    assert r.exit_code == 0, r.output
    files = sorted((tmp_path / "s").iterdir())
    assert {f.name for f in files} >= {"edges.txt", "gt.txt", "meta.json", "rigs.txt", "gt_extrinsics.csv", "gravity.txt"}
    for f in files:
        assert is_rotgraph_output(f), f
    from rotgraph.pipeline.batch import _write_manifest

    _write_manifest(tmp_path, [{"input": "x", "output": None, "status": "failed", "error": "e"}])
    _write_manifest(tmp_path / "s", [])
    for f in (tmp_path / "manifest.json", tmp_path / "summary.csv", tmp_path / "s" / "manifest.json"):
        assert is_rotgraph_output(f), f
    pytest.importorskip("matplotlib")
    for ext in ("png", "pdf", "svg"):
        r = run("info", problem, "--plot", tmp_path / f"g.{ext}")
        assert r.exit_code == 0, r.output
        assert is_rotgraph_output(tmp_path / f"g.{ext}"), ext


@pytest.mark.parametrize("content", [b"hello\n", b"id,qw,qx,qy,qz\n0,1,0,0,0\n", b"# my notes\n", b"{\"a\": 1}\n",
                                     b"\x89PNG\r\n\x1a\n" + b"\0" * 64, b"PK\x03\x04junk", b"%PDF-1.4 by someone"])
def test_other_files_are_not_rotgraphs(content, tmp_path):
    p = tmp_path / "f"
    p.write_bytes(content)
    assert not is_rotgraph_output(p)


def test_empty_and_blank_files_hold_nothing_to_lose(tmp_path):
    for body in (b"", b"\n \n"):
        (tmp_path / "f").write_bytes(body)
        assert is_rotgraph_output(tmp_path / "f")


def test_signatures_are_distinct_and_not_prefixes_of_common_inputs():
    assert len(set(OWN_SIGNATURES)) == len(OWN_SIGNATURES)
    for inp in (b"i,j,qw,qx,qy,qz", b"# i j qw qx qy qz\n", b"IMG1 IMG2 QW", b"EDGE_SE3:QUAT"):
        assert not inp.startswith(OWN_SIGNATURES)


# =========================================================================== solve


def test_a_file_of_the_users_is_refused_unless_overwrite(problem, tmp_path):
    out = tmp_path / "notes.csv"
    out.write_text("my results\n")
    r = run("solve", problem, "-o", out)
    assert r.exit_code == 3 and "not a rotgraph output" in r.output and "--overwrite" in r.output
    assert out.read_text() == "my results\n"
    r = run("solve", problem, "-o", out, "--overwrite", "-q")
    assert r.exit_code == 0, r.output
    assert out.read_text().startswith("id,name,qw,qx,qy,qz\n")


def test_own_output_is_replaced_on_a_rerun_and_an_empty_file_too(problem, tmp_path):
    out = tmp_path / "r.csv"
    assert run("solve", problem, "-o", out, "-q").exit_code == 0
    first = out.read_bytes()
    assert run("solve", problem, "-o", out, "-q", "--method", "l2").exit_code == 0
    assert out.read_bytes() != first
    empty = tmp_path / "mktemp.csv"
    empty.touch()
    assert run("solve", problem, "-o", empty, "-q").exit_code == 0
    assert empty.read_bytes().startswith(b"id,name")


def test_read_only_output_is_refused_unless_overwrite(problem, tmp_path):
    out = tmp_path / "r.csv"
    assert run("solve", problem, "-o", out, "-q").exit_code == 0
    before = out.read_bytes()
    os.chmod(out, 0o444)
    r = run("solve", problem, "-o", out, "-q", "--method", "l2")
    assert r.exit_code == 3 and "read-only" in r.output
    assert out.read_bytes() == before
    assert run("solve", problem, "-o", out, "-q", "--method", "l2", "--overwrite").exit_code == 0
    assert out.read_bytes() != before
    assert stat.S_IMODE(out.stat().st_mode) == 0o444  # the mode it had


def test_one_refused_output_stops_the_run_before_any_other_is_written(problem, tmp_path):
    out, edges = tmp_path / "r.csv", tmp_path / "e.csv"
    edges.write_text("precious\n")
    r = run("solve", problem, "-o", out, "--edges-out", edges)
    assert r.exit_code == 3
    assert not out.exists() and edges.read_text() == "precious\n"


def test_a_symlink_to_a_users_file_is_refused_and_to_an_own_output_followed(problem, tmp_path):
    target = tmp_path / "target.csv"
    target.write_text("mine\n")
    link = tmp_path / "link.csv"
    link.symlink_to(target)
    assert run("solve", problem, "-o", link, "-q").exit_code == 3
    assert target.read_text() == "mine\n" and link.is_symlink()
    target.write_text("")
    assert run("solve", problem, "-o", link, "-q").exit_code == 0
    assert link.is_symlink() and target.read_text().startswith("id,name")


def test_the_input_is_never_an_output_even_with_overwrite(problem, tmp_path):
    before = problem.read_bytes()
    for extra in ((), ("--overwrite",)):
        r = run("solve", problem, "-o", problem, *extra)
        assert r.exit_code == 3 and "input" in r.output
        r = run("solve", problem, "-o", tmp_path / "r.csv", "--edges-out", problem, *extra)
        assert r.exit_code == 3
    assert problem.read_bytes() == before


def test_a_failed_write_leaves_every_earlier_output(problem, tmp_path, monkeypatch):
    out, edges = tmp_path / "r.csv", tmp_path / "e.csv"
    assert run("solve", problem, "-o", out, "--edges-out", edges, "-q").exit_code == 0
    before = _snapshot(tmp_path)
    calls = []
    real = os.fsync

    def fsync(fd):  # the second file's write fails: the first must not be in place either
        calls.append(fd)
        if len(calls) == 2:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(fd)

    monkeypatch.setattr(atomic.os, "fsync", fsync)
    r = run("solve", problem, "-o", out, "--edges-out", edges, "-q", "--method", "l2")
    assert r.exit_code == 3, r.output
    assert r.output.strip() == f"rotgraph: error: {edges}: no space left on device"
    assert _snapshot(tmp_path) == before  # no temporary file left either


def test_disk_full_on_a_device_is_exit_3_naming_it(problem):
    if not os.path.exists("/dev/full"):
        pytest.skip("no /dev/full")
    r = run("solve", problem, "-o", "/dev/full", "-q")
    assert r.exit_code == 3
    assert "/dev/full: no space left on device" in r.output


def test_an_unexpected_os_error_names_its_file_and_exits_3(problem, tmp_path, monkeypatch):
    import rotgraph.pipeline.solve as solve_mod

    def boom(*a, **k):
        raise PermissionError(errno.EACCES, "Permission denied", str(tmp_path / "x"))

    monkeypatch.setattr(solve_mod, "_write_outputs", boom)
    r = run("solve", problem, "-o", tmp_path / "r.csv", "-q")
    assert r.exit_code == 3 and f"{tmp_path / 'x'}: permission denied" in r.output


def test_output_group_commits_all_or_nothing(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    a.write_text("old a\n")
    with pytest.raises(RuntimeError):
        with output_group():
            with atomic_write(a) as fh:
                fh.write("new a\n")
            assert a.read_text() == "old a\n"  # not yet in place
            raise RuntimeError
    assert a.read_text() == "old a\n" and not b.exists()
    assert sorted(os.listdir(tmp_path)) == ["a"]
    with output_group(remove=[b]):
        b.write_text("to go\n")
        with atomic_write(a) as fh:
            fh.write("new a\n")
    assert a.read_text() == "new a\n" and not b.exists()


def test_check_outputs_is_the_library_gate(tmp_path):
    p = tmp_path / "x.csv"
    p.write_text("data\n")
    with pytest.raises(InputError, match="not a rotgraph output"):
        check_outputs([p])
    check_outputs([p], overwrite=True)


# =========================================================================== eval, synth, info


def test_eval_per_camera_and_synth_follow_the_rule(problem, tmp_path):
    est = tmp_path / "r.csv"
    assert run("solve", problem, "-o", est, "-q").exit_code == 0
    pc = tmp_path / "pc.csv"
    pc.write_text("keep\n")
    assert run("eval", est, problem.parent / "gt.txt", "--per-camera", pc).exit_code == 3
    assert pc.read_text() == "keep\n"
    assert run("eval", est, problem.parent / "gt.txt", "--per-camera", pc, "--overwrite").exit_code == 0
    s = tmp_path / "s"
    s.mkdir()
    (s / "gt.txt").write_text("my ground truth\n")
    r = run("synth", "-o", s, "--n", "10", "--degree", "4")
    assert r.exit_code == 3 and "gt.txt" in r.output
    assert sorted(os.listdir(s)) == ["gt.txt"] and (s / "gt.txt").read_text() == "my ground truth\n"
    assert run("synth", "-o", s, "--n", "10", "--degree", "4", "--overwrite").exit_code == 0
    assert run("synth", "-o", s, "--n", "12", "--degree", "4").exit_code == 0  # its own files: a re-run replaces them
    assert json.loads((s / "meta.json").read_text())["n"] == 12


# =========================================================================== model folders


@pytest.fixture(scope="module")
def colmap_project(tmp_path_factory):
    pytest.importorskip("pycolmap")
    from rotgraph.synth import synthesize_colmap_project

    base = tmp_path_factory.mktemp("proj")
    synthesize_colmap_project(base / "p", n_frames=6, n_points=150, seed=3)
    return base / "p"


def _reconstruction_folder(project: Path, folder: Path, text: bool) -> None:
    """A COLMAP reconstruction with 3D points and positions (the synthetic project's own
    sparse model), as a user's folder would hold it."""
    import pycolmap

    rec = pycolmap.Reconstruction(str(project / "sparse" / "0"))
    assert rec.num_points3D() > 0
    folder.mkdir(parents=True, exist_ok=True)
    (rec.write_text if text else rec.write_binary)(str(folder))


@pytest.mark.parametrize("text", [False, True])
def test_a_folder_with_a_reconstruction_is_not_replaced(colmap_project, tmp_path, text):
    folder = tmp_path / "model"
    _reconstruction_folder(colmap_project, folder, text)
    (folder / "notes.md").write_text("mine\n")
    before = _snapshot(folder)
    for out in (str(folder), str(folder) + "/"):  # with and without the trailing slash
        r = run("solve", colmap_project, "-o", out, "-q")
        assert r.exit_code == 3 and "--overwrite" in r.output, r.output
        assert _snapshot(folder) == before
    r = run("solve", colmap_project, "-o", folder, "-q", "--overwrite")
    assert r.exit_code == 0, r.output
    assert (folder / "notes.md").read_text() == "mine\n"
    assert sorted(p.name for p in folder.iterdir()) == sorted(["notes.md"] + [f"{n}.bin" for n in
                                                               ("cameras", "frames", "images", "points3D", "rigs")])


def test_a_model_is_replaced_whole_across_formats(colmap_project, tmp_path):
    folder = tmp_path / "m"
    assert run("solve", colmap_project, "-o", f"{folder}/", "-q").exit_code == 0
    assert {p.suffix for p in folder.iterdir()} == {".bin"}
    assert run("solve", colmap_project, "-o", folder, "--output-format", "colmap-txt", "-q").exit_code == 0
    assert {p.suffix for p in folder.iterdir()} == {".txt"}  # the .bin model went in the same step
    assert run("solve", colmap_project, "-o", folder, "-q").exit_code == 0  # an existing folder: colmap .bin
    assert {p.suffix for p in folder.iterdir()} == {".bin"}
    # eval reads the model that is there
    r = run("eval", folder, folder, "--json")
    assert r.exit_code == 0, r.output


def test_a_pose_model_without_points_is_not_a_rotations_only_one(colmap_project, tmp_path):
    import pycolmap

    folder = tmp_path / "m"
    assert run("solve", colmap_project, "-o", f"{folder}/", "-q").exit_code == 0
    rec = pycolmap.Reconstruction(str(folder))
    for f in rec.frames.values():
        if f.has_pose:
            f.rig_from_world = pycolmap.Rigid3d(f.rig_from_world.rotation, np.array([1.0, 2.0, 3.0]))
    rec.write_binary(str(folder))
    before = _snapshot(folder)
    r = run("solve", colmap_project, "-o", folder, "-q")
    assert r.exit_code == 3 and "not a rotgraph rotations-only model" in r.output
    assert _snapshot(folder) == before


# =========================================================================== batch


@pytest.fixture
def dask_or_skip():
    pytest.importorskip("distributed")


@pytest.mark.slow
def test_batch_never_deletes_inputs_and_keeps_earlier_outputs(dask_or_skip, problem, tmp_path):
    dl = tmp_path / "dl"
    dl.mkdir()
    rows = [ln.split() for ln in problem.read_text().splitlines() if not ln.startswith("#")]
    for name in ("p0", "p2"):
        (dl / f"{name}.csv").write_text("i,j,qw,qx,qy,qz,weight\n" + "".join(",".join(r) + "\n" for r in rows))
    before = _snapshot(dl)
    for args in ((dl / "p0.csv", dl / "p2.csv", "-d", dl), (dl / "p0.csv", "--out-dir", dl), (dl / "p0.csv", "-d", dl, "--overwrite")):
        r = run("batch", *args, "-q")
        assert r.exit_code == 3 and "input" in r.output, r.output
        assert _snapshot(dl) == before  # inputs untouched, nothing written (no manifest either)

    inp, out = tmp_path / "in", tmp_path / "out"
    inp.mkdir()
    (inp / "a.txt").write_bytes(problem.read_bytes())
    (inp / "b.txt").write_bytes(problem.read_bytes())
    assert run("batch", inp / "a.txt", inp / "b.txt", "-d", out, "-q", "--workers", "1").exit_code == 0
    good = (out / "a.csv").read_bytes()
    with open(inp / "a.txt", "a") as fh:
        fh.write("1 2 bad line\n")
    r = run("batch", inp / "a.txt", inp / "b.txt", "-d", out, "-q", "--workers", "1")
    assert r.exit_code == 1
    assert (out / "a.csv").read_bytes() == good  # the failed re-run kept the earlier output
    m = {Path(e["input"]).name: e for e in json.loads((out / "manifest.json").read_text())}
    assert m["a.txt"]["status"] == "failed" and m["b.txt"]["status"] == "ok"

    # --resume: same options -> skipped; other options -> solved again
    r = run("batch", inp / "b.txt", "-d", out, "--resume", "--json", "--workers", "1")
    assert r.exit_code == 0 and json.loads(r.stdout)[0]["status"] == "skipped"
    b_adaptive = (out / "b.csv").read_bytes()
    r = run("batch", inp / "b.txt", "-d", out, "--resume", "--json", "--method", "l2", "--workers", "1")
    assert r.exit_code == 0 and json.loads(r.stdout)[0]["status"] == "ok"
    assert (out / "b.csv").read_bytes() != b_adaptive
    r = run("batch", inp / "b.txt", "-d", out, "--resume", "--json", "--method", "l2", "--workers", "1")
    assert json.loads(r.stdout)[0]["status"] == "skipped"

    # a file of the user's where an output would go: refused before any work
    (out / "c.csv").write_text("mine\n")
    (inp / "c.txt").write_bytes(problem.read_bytes())
    before = _snapshot(out)
    r = run("batch", inp / "c.txt", "-d", out, "-q")
    assert r.exit_code == 3 and "c.csv" in r.output
    assert _snapshot(out) == before


def test_a_batch_with_nothing_to_do_is_a_usage_error(dask_or_skip, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "x.csv").write_text("id,name,qw,qx,qy,qz\n")
    r = run("batch", out, "--out-dir", out)
    assert r.exit_code == 2 and "nothing to do" in r.output
    assert sorted(os.listdir(out)) == ["x.csv"]


# =========================================================================== a review's cases


def _tmpfs(path: Path, size: str = "64k"):
    """A small tmpfs at ``path`` (a real full disk), or skip where mounting is not allowed."""
    import subprocess

    path.mkdir()
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)], capture_output=True)
    if r.returncode:
        pytest.skip(f"cannot mount a tmpfs here: {r.stderr.decode().strip()}")
    return path


def _umount(path: Path) -> None:
    import subprocess

    subprocess.run(["umount", str(path)], capture_output=True)


def _fill(path: Path) -> None:
    fd = os.open(path / "fill", os.O_WRONLY | os.O_CREAT)
    try:
        while True:
            os.write(fd, b"\0" * 4096)
    except OSError:
        pass
    finally:
        os.close(fd)


def test_a_real_full_disk_keeps_the_earlier_csv_and_model(colmap_project, tmp_path):
    small = _tmpfs(tmp_path / "small", "256k")
    try:
        big = tmp_path / "big"
        assert run("synth", "-o", big, "--n", "2000", "--degree", "10", "-q").exit_code == 0
        out = small / "r.csv"
        assert run("solve", colmap_project, "-o", out, "-q").exit_code == 0
        model = small / "m"
        assert run("solve", colmap_project, "-o", f"{model}/", "-q").exit_code == 0
        before = _snapshot(small)
        _fill(small)
        r = run("solve", big / "edges.txt", "-o", out, "-q")  # a CSV larger than what is left
        assert r.exit_code == 3 and r.output.strip() == f"rotgraph: error: {out}: no space left on device", r.output
        r = run("solve", colmap_project, "-o", f"{model}/", "-q", "--method", "l2")  # pycolmap reports no error itself
        assert r.exit_code == 3 and "no space left on device" in r.output, r.output
        (small / "fill").unlink()
        assert _snapshot(small) == before
    finally:
        _umount(small)


def test_the_project_model_is_never_an_output_however_named(colmap_project, tmp_path):
    model = colmap_project / "sparse" / "0"
    before = _snapshot(colmap_project)
    link = tmp_path / "link0"
    link.symlink_to(model)
    for args in ((colmap_project / "database.db", "-o", f"{model}/"), (colmap_project, "-o", f"{link}/"),
                 (colmap_project / "database.db", "-o", f"{colmap_project}/")):
        r = run("solve", *args, "-q", "--overwrite")
        assert r.exit_code == 3 and "input" in r.output, (args, r.output)
    assert _snapshot(colmap_project) == before


def test_reconstruct_never_writes_over_its_ground_truth(colmap_project, tmp_path):
    gt = tmp_path / "gt"
    _reconstruction_folder(colmap_project, gt, False)
    before = _snapshot(gt)
    r = run("reconstruct", colmap_project, "-o", gt, "--ground-truth", gt, "--overwrite", "-q")
    assert r.exit_code == 3 and "input" in r.output, r.output
    r = run("reconstruct", colmap_project / "database.db", "-o", colmap_project / "sparse" / "0", "--overwrite", "-q")
    assert r.exit_code == 3
    assert _snapshot(gt) == before


def test_side_outputs_may_not_name_model_files_and_read_only_models_stay(colmap_project, tmp_path):
    m = tmp_path / "m"
    assert run("solve", colmap_project, "-o", f"{m}/", "-q").exit_code == 0
    r = run("solve", colmap_project, "-o", f"{m}/", "--output-format", "colmap-txt", "--edges-out", m / "images.txt", "-q")
    assert r.exit_code == 3 and "names a file of the model" in r.output
    before = _snapshot(m)
    for f in m.iterdir():
        os.chmod(f, 0o444)
    r = run("solve", colmap_project, "-o", f"{m}/", "--output-format", "colmap-txt", "-q")
    assert r.exit_code == 3 and "read-only" in r.output
    assert {k: v for k, v in _snapshot(m).items()} == before


def test_a_model_folder_that_refuses_files_is_found_before_any_work(colmap_project):
    if not os.path.isdir("/sys"):
        pytest.skip("no /sys")
    r = run("solve", colmap_project, "-o", "/sys/rotgraph-model/", "-q")
    assert r.exit_code == 3 and "cannot write here" in r.output, r.output


def test_reruns_into_an_input_folder_replace_their_own_outputs(colmap_project, tmp_path):
    import shutil

    pr = tmp_path / "pr"
    shutil.copytree(colmap_project, pr)
    for out in ("rot.txt", "rotations"):
        for _ in range(2):
            r = run("solve", pr, "-o", pr / out, "-q")
            assert r.exit_code == 0, r.output
    r = run("solve", pr, "-o", pr / "database.db", "--output-format", "csv", "-q", "--overwrite")
    assert r.exit_code == 3


def test_a_users_svg_that_mentions_rotgraph_is_not_a_plot_of_rotgraphs(tmp_path):
    p = tmp_path / "fig.svg"
    p.write_text('<?xml version="1.0"?>\n<svg><text>COLMAP -> rotgraph -> GLOMAP</text></svg>\n')
    assert not is_rotgraph_output(p)
    p.write_bytes(b"%PDF-1.4\n<< /Title (rotgraph results) >>\n")
    assert not is_rotgraph_output(p)


def test_eval_writes_its_two_outputs_together(problem, tmp_path, monkeypatch):
    pytest.importorskip("matplotlib")
    est, pc, pl = tmp_path / "r.csv", tmp_path / "pc.csv", tmp_path / "pl.png"
    assert run("solve", problem, "-o", est, "-q").exit_code == 0
    assert run("eval", est, problem.parent / "gt.txt", "--per-camera", pc, "--plot", pl).exit_code == 0
    before = _snapshot(tmp_path)
    from rotgraph.cli import plots

    def boom(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(plots, "save_figure", boom)
    r = run("eval", est, problem.parent / "gt.txt", "--per-camera", pc, "--plot", pl)
    assert r.exit_code == 130
    assert _snapshot(tmp_path) == before


def test_synth_replaces_a_whole_problem(tmp_path):
    s = tmp_path / "s"
    assert run("synth", "-o", s, "--rig", "2x5", "--gravity-noise", "1", "--edges-format", "both", "-q").exit_code == 0
    (s / "notes.md").write_text("mine\n")
    assert run("synth", "-o", s, "--n", "10", "--degree", "4", "-q").exit_code == 0
    assert sorted(p.name for p in s.iterdir()) == ["edges.txt", "gt.txt", "meta.json", "notes.md"]


def test_synthesize_colmap_project_does_not_replace_a_project(colmap_project):
    from rotgraph.synth import synthesize_colmap_project

    before = _snapshot(colmap_project)
    with pytest.raises(InputError, match="holds a COLMAP project"):
        synthesize_colmap_project(colmap_project, n_frames=4)
    assert _snapshot(colmap_project) == before


def test_nested_groups_drop_what_a_failed_inner_block_wrote(tmp_path):
    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    c.write_text("keep\n")
    with output_group():
        with atomic_write(a) as fh:
            fh.write("a\n")
        with pytest.raises(RuntimeError):
            with output_group(remove=[c]):
                with atomic_write(b) as fh:
                    fh.write("b\n")
                raise RuntimeError
    assert a.read_text() == "a\n" and not b.exists() and c.read_text() == "keep\n"
    assert sorted(os.listdir(tmp_path)) == ["a", "c"]


@pytest.mark.slow
def test_batch_protects_its_gt_and_list_files_and_resumes_a_failed_problem(dask_or_skip, problem, tmp_path):
    s = tmp_path / "s"
    s.mkdir()
    (s / "edges.txt").write_bytes(problem.read_bytes())
    write_rotations(s / "edges.csv", np.arange(3), None, np.stack([np.eye(3)] * 3))  # a ground truth in rotgraph's CSV
    before = _snapshot(s)
    r = run("batch", s / "edges.txt", "-d", s, "--gt", "{dir}/{stem}.csv", "-q", "--overwrite")
    assert r.exit_code == 3 and "input" in r.output, r.output
    lists = tmp_path / "L"
    lists.mkdir()
    (lists / "edges.txt").write_bytes(problem.read_bytes())
    (lists / "edges.csv").write_text("edges.txt\n")  # the list file has the name of the problem's output
    before = _snapshot(lists)
    r = run("batch", f"@{lists / 'edges.csv'}", "-d", lists, "-q", "--overwrite")
    assert r.exit_code == 3 and "input" in r.output, r.output
    assert _snapshot(lists) == before
    # a problem that failed is solved again by --resume, even with the options of the failure
    out = tmp_path / "out"
    dup = tmp_path / "dup.txt"
    lines = problem.read_text().splitlines(True)
    dup.write_text("".join(lines) + lines[1])  # a parallel edge: fails with --duplicates error, solves with merge
    assert run("batch", dup, "-d", out, "--duplicates", "merge", "-q", "--workers", "1").exit_code == 0
    assert run("batch", dup, "-d", out, "--duplicates", "error", "-q", "--workers", "1").exit_code == 1
    r = run("batch", dup, "-d", out, "--duplicates", "error", "--resume", "--json", "--workers", "1")
    assert r.exit_code == 1 and json.loads(r.stdout)[0]["status"] == "failed"


def test_a_model_only_project_writes_a_model_and_reruns(colmap_project, tmp_path):
    """A project with a sparse model and no database (pycolmap 4.2 frames copied), twice."""
    import shutil

    src = tmp_path / "mo"
    shutil.copytree(colmap_project / "sparse", src / "sparse")
    for _ in range(2):
        r = run("solve", src, "-o", f"{tmp_path / 'out'}/", "-q")
        assert r.exit_code == 0, r.output
    r = run("eval", tmp_path / "out", src / "sparse" / "0", "--json")
    assert r.exit_code == 0 and json.loads(r.stdout)["n_evaluated"] == 6
