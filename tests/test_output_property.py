"""A property test of the output rule (docs/outputs.md, issue #28) over the commands that write
or read files (solve, eval, synth, certify, mean, info, handeye): random pre-existing states of
every output path (missing, rotgraph's own earlier output, a file of the user's, empty, a
folder, symlinks to either, the input itself, read-only)
and random failures (bad input, a full disk, Ctrl-C), with and without ``--overwrite``.

The oracle: a run that must refuse (an input or a folder as an output; a file of the user's or a
read-only one without ``--overwrite``) or that fails changes no byte anywhere; a run that
succeeds changes only its documented outputs, each now a rotgraph output (a symlink kept and
its target written), and never an input. Draws are seeded: a failure names its seed.
(``batch`` and ``reconstruct`` start clusters or COLMAP pipelines: their cases are in
tests/test_overwrite.py.)
"""

from __future__ import annotations

import errno
import os
from pathlib import Path

import numpy as np
import pytest

from cli_helpers import run
from rotgraph.io import atomic
from rotgraph.io.outputs import is_rotgraph_output
from rotgraph.io.writers import write_absolute_rotations_text, write_edges, write_rotations
from rotgraph.synth import random_problem

OWN = {  # an earlier output of rotgraph, by the output's kind
    "csv": b"id,name,qw,qx,qy,qz\n0,0,1.0,0.0,0.0,0.0\n",
    "edges": b"i,j,residual_deg,inlier\n0,1,0.5,1\n",
    "txt": b"# IMAGE_NAME QW QX QY QZ (cam_from_world)\n0 1.0 0.0 0.0 0.0\n",
    "json": b'{\n "convention": "cam_from_world quaternions (w, x, y, z), w >= 0", "cameras": []}\n',
    "pc": b"id,name,error_deg\n0,0,0.1\n",
    "synth_edges": b"# i j qw qx qy qz weight\n",
    "synth_gt": b"# id qw qx qy qz (cam_from_world)\n",
    "synth_meta": b'{\n  "n": 3\n}\n',
}
STATES = ["missing", "own", "user", "empty", "folder", "link_user", "link_own", "input", "read_only"]
FAILURES = ["none", "bad_input", "disk_full", "sigint"]


def _commands(root: Path) -> dict:
    """name -> (argv, [(output path, kind)], [input paths], whether it reads an edge file)."""
    i, o = root / "in", root / "out"
    return {
        "solve": (["solve", i / "edges.txt", "-o", o / "r.csv", "--edges-out", o / "e.csv", "-q"],
                  [(o / "r.csv", "csv"), (o / "e.csv", "edges")], [i / "edges.txt"], True),
        "solve_txt": (["solve", i / "edges.txt", "-o", o / "r.txt", "-q", "--method", "l2"], [(o / "r.txt", "txt")],
                      [i / "edges.txt"], True),
        "solve_json": (["solve", i / "edges.txt", "-o", o / "r.json", "-q", "--method", "chordal"], [(o / "r.json", "json")],
                       [i / "edges.txt"], True),
        "eval": (["eval", i / "est.csv", i / "gt.txt", "--per-camera", o / "pc.csv"], [(o / "pc.csv", "pc")],
                 [i / "est.csv", i / "gt.txt"], False),
        "synth": (["synth", "-o", o / "s", "--n", "12", "--degree", "4"],
                  [(o / "s" / "edges.txt", "synth_edges"), (o / "s" / "gt.txt", "synth_gt"), (o / "s" / "meta.json", "synth_meta")],
                  [], False),
        "certify": (["certify", i / "est.csv", i / "edges.txt"], [], [i / "est.csv", i / "edges.txt"], True),
        "mean": (["mean", i / "est.csv", "--norm", "l1"], [], [i / "est.csv"], False),
        "info": (["info", i / "edges.txt", "--json"], [], [i / "edges.txt"], True),
        "handeye": (["handeye", i / "est.csv", i / "gt.txt", "--json"], [], [i / "est.csv", i / "gt.txt"], False),
    }


def _snapshot(root: Path) -> dict:
    out = {}
    for dirpath, dirs, files in os.walk(root):
        for d in dirs:
            p = Path(dirpath, d)
            out[str(p)] = b"->" + os.readlink(p).encode() if p.is_symlink() else "dir"
        for f in files:
            p = Path(dirpath, f)
            if p.is_symlink():
                out[str(p)] = b"->" + os.readlink(p).encode()
            else:
                out[str(p)] = (p.read_bytes(), os.stat(p).st_mode)
    return out


def _inputs(folder: Path) -> None:
    folder.mkdir()
    g = random_problem(n=20, degree=5, sigma_deg=1.0, outliers=0.0, graph="er", seed=1)
    write_edges(folder / "edges.txt", g)
    write_absolute_rotations_text(folder / "gt.txt", g.node_ids, g.gt_cam_from_world)
    write_rotations(folder / "est.csv", g.node_ids, None, g.gt_cam_from_world)


def _set_state(path: Path, kind: str, state: str, inputs: list[Path], root: Path) -> Path | None:
    """Make ``state`` at ``path``; returns a path that stands for the output in argv when it
    changes (the input itself), else None."""
    path.parent.mkdir(parents=True, exist_ok=True)
    elsewhere = root / "elsewhere"
    elsewhere.mkdir(exist_ok=True)
    if state == "own":
        path.write_bytes(OWN[kind])
    elif state == "user":
        path.write_bytes(b"my own notes, keep them\n")
    elif state == "empty":
        path.write_bytes(b"")
    elif state == "folder":
        path.mkdir()
    elif state in ("link_user", "link_own"):
        target = elsewhere / f"{path.name}.target"
        target.write_bytes(OWN[kind] if state == "link_own" else b"precious\n")
        path.symlink_to(target)
    elif state == "read_only":
        path.write_bytes(OWN[kind])
        os.chmod(path, 0o444)
    elif state == "input":
        return inputs[0] if inputs else None
    return None


@pytest.mark.parametrize("seed", range(90))
def test_no_byte_outside_the_documented_outputs_changes(seed, tmp_path, monkeypatch):
    rng = np.random.default_rng([28, seed])
    names = sorted(_commands(tmp_path))
    name = names[rng.integers(len(names))]
    argv, outputs, inputs, reads_edges = _commands(tmp_path)[name]
    _inputs(tmp_path / "in")
    (tmp_path / "out").mkdir()
    argv = list(argv)
    states = []
    for path, kind in outputs:
        state = STATES[rng.integers(len(STATES))]
        if state == "input" and not inputs:
            state = "user"
        states.append(state)
        stand_in = _set_state(path, kind, state, inputs, tmp_path)
        if stand_in is not None:
            argv[argv.index(path)] = stand_in
    failure = FAILURES[rng.integers(len(FAILURES))]
    if failure == "bad_input" and not inputs:
        failure = "none"
    if failure == "bad_input":
        with open(inputs[0], "a") as fh:
            fh.write("0 1 this is not a rotation\n")
    overwrite = bool(rng.integers(2))
    if overwrite and outputs:
        argv.append("--overwrite")
    if failure in ("disk_full", "sigint"):
        def fsync(fd, _kind=failure):
            if _kind == "sigint":
                raise KeyboardInterrupt
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

        monkeypatch.setattr(atomic.os, "fsync", fsync)
    before = _snapshot(tmp_path)
    r = run(*argv)
    after = _snapshot(tmp_path)
    case = f"seed {seed}: {name} {states} failure={failure} overwrite={overwrite}: exit {r.exit_code}: {r.output[-400:]}"
    assert "Traceback" not in r.output, case
    for p in inputs:  # inputs: never touched
        assert after[str(p)] == before[str(p)], case
    refused = any(s in ("input", "folder") for s in states) or (
        not overwrite and any(s in ("user", "link_user", "read_only") for s in states))
    bad = failure == "bad_input" and (reads_edges or name in ("eval", "mean", "certify", "handeye"))
    wrote = outputs and failure in ("disk_full", "sigint")
    if refused or bad or wrote:
        assert r.exit_code in (3, 130) or (r.exit_code == 2 and "folder" in states) or (r.exit_code == 1 and name == "certify"), case
        assert after == before, case  # not one byte anywhere
        return
    if not outputs:  # a command that only reads: nothing on disk changes, whatever it answers
        assert after == before, case
        return
    assert r.exit_code == 0, case
    documented = set()
    for (path, _), state in zip(outputs, states):
        target = Path(os.path.realpath(path))
        documented |= {str(path), str(target)}
        assert is_rotgraph_output(target) and target.stat().st_size > 0, case
        if state.startswith("link"):
            assert path.is_symlink(), case
    if name == "synth":
        documented.add(str(tmp_path / "out" / "s"))
    for key in set(before) | set(after):
        if key not in documented:
            assert before.get(key) == after.get(key), f"{key} changed: {case}"
