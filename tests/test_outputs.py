"""What is at an output path is never destroyed (issue #15, CLI.md "No command ever leaves ..."):

* ``-`` is standard output (nothing named ``-`` is created; the summary goes to stderr);
* an existing device or FIFO is written through, never replaced;
* ``/dev/stdout``, ``/dev/fd/N`` write this process's open file (appending where the shell
  redirected it), never a file named after the link;
* a symlink is followed: its target is replaced atomically (mode bits kept), the link stays;
* a folder that refuses new files (``/sys``, ``/proc``, even for root) is exit 3
  ``cannot write here`` naming the output, found before the input is read.

Everything goes through :func:`rotgraph.io.atomic.atomic_write` (every writer) and
:func:`rotgraph.io.outputs.check_outputs` (every command, before any work). Devices are made
with ``mknod`` inside the test folder (never the machine's ``/dev/null``), so a regression
cannot damage the machine.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import stat
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from rotgraph.cli.main import cli
from cli_helpers import refuses_files
from rotgraph.errors import InputError
from rotgraph.io.atomic import atomic_write, writes_to_stdout
from rotgraph.io.outputs import check_outputs
from rotgraph.io.writers import write_absolute_rotations_text, write_edges, write_edges_csv, write_rotations
from rotgraph.synth import random_problem

_EXE = Path(sys.executable).with_name("rotgraph")
ROTGRAPH_EXE = str(_EXE) if _EXE.exists() else shutil.which("rotgraph") or "rotgraph"
HEADER = "id,name,qw,qx,qy,qz"


needs_sys = pytest.mark.skipif(not os.path.isdir("/sys") or not refuses_files("/sys"), reason="/sys accepts files here")
needs_proc = pytest.mark.skipif(not os.path.isdir("/proc") or not refuses_files("/proc"), reason="/proc accepts files here")


def run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=False)


@pytest.fixture(scope="module")
def problem(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("problem")
    g = random_problem(n=30, degree=6, sigma_deg=1.0, outliers=0.0, graph="er", seed=3)
    write_edges(folder / "edges.txt", g)
    return folder / "edges.txt"


def _tmp_files(*folders: Path) -> list[str]:
    return [e.name for f in folders for e in os.scandir(f) if e.name.endswith(".tmp")]


@contextlib.contextmanager
def _fifo_reader(path: Path):
    """A reader on the FIFO at ``path`` (opened first, so a writer's open does not block);
    yields a list that holds everything read once the block ends."""
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    os.set_blocking(fd, True)
    got: list[bytes] = []

    def drain():
        with os.fdopen(fd, "rb") as fh:
            while True:
                chunk = fh.read1(65536) if hasattr(fh, "read1") else fh.read(65536)
                if not chunk:
                    # EOF only means no writer right now: stop once the test is done writing,
                    # after reading what the writer left between this read and the flag
                    if done.is_set():
                        rest = fh.read()
                        if rest:
                            got.append(rest)
                        return
                    done.wait(0.01)
                    continue
                got.append(chunk)

    done = threading.Event()
    t = threading.Thread(target=drain, daemon=True)
    t.start()
    try:
        yield got
    finally:
        done.set()
        t.join(10)
    got[:] = [b"".join(got)]


def _char_device(path: Path) -> Path:
    """A character device node equal to /dev/null at ``path`` (skip where mknod is refused)."""
    try:
        os.mknod(path, 0o666 | stat.S_IFCHR, os.makedev(1, 3))
    except (OSError, AttributeError) as exc:
        pytest.skip(f"cannot make a device node here: {exc}")
    return path


# ============================================================================ -o -


def test_dash_is_stdout_and_the_summary_goes_to_stderr(problem, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    r = run("solve", problem, "-o", "-")
    assert r.exit_code == 0, r.output
    lines = r.stdout.splitlines()
    assert lines[0] == HEADER and len(lines) == 31, r.stdout  # the CSV and nothing else
    assert "rotgraph solve: 30 cameras" in r.stderr and "-> -" in r.stderr
    assert not (tmp_path / "-").exists() and not _tmp_files(tmp_path)


def test_dash_through_the_real_entry_point_equals_the_file(problem, tmp_path):
    out = tmp_path / "out.csv"
    assert run("solve", problem, "-o", out, "-q").exit_code == 0
    p = subprocess.run([ROTGRAPH_EXE, "solve", str(problem), "-o", "-"], capture_output=True, cwd=tmp_path, timeout=120)
    assert p.returncode == 0, p.stderr
    assert p.stdout == out.read_bytes()
    assert b"rotgraph solve:" in p.stderr
    assert not (tmp_path / "-").exists()


def test_dash_for_edges_out_and_binary(problem, tmp_path, capfdbinary):
    with atomic_write("-", "wb") as fh:
        fh.write(b"\x89PNG\r\n")
    with atomic_write("-") as fh:
        fh.write("a,b\n")
    assert capfdbinary.readouterr().out == b"\x89PNG\r\na,b\n"
    r = run("solve", problem, "-o", tmp_path / "out.csv", "--edges-out", "-")
    assert r.exit_code == 0, r.output
    assert r.stdout.splitlines()[0] == "i,j,residual_deg,inlier" and "rotgraph solve:" not in r.stdout


def test_dash_gets_nothing_when_the_writer_fails(capfd):
    with pytest.raises(ValueError):
        with atomic_write("-") as fh:
            fh.write("half a file\n")
            raise ValueError("boom")
    assert capfd.readouterr().out == ""


def test_stdout_named_twice_is_refused(problem, tmp_path):
    for second in ("-", "/dev/stdout", "/dev/fd/1"):
        r = run("solve", problem, "-o", "-", "--edges-out", second)
        assert r.exit_code == 3, r.output
        assert "named twice as an output" in r.stderr and r.stdout == ""
    assert writes_to_stdout("-") and writes_to_stdout("/dev/stdout") and not writes_to_stdout(tmp_path / "x.csv")
    check_outputs(["-", "/dev/stderr", None], [problem])  # different streams: fine


# ============================================================================ open files of this process


def test_dev_fd_writes_the_open_file_appending_where_the_shell_redirected(problem, tmp_path):
    log = tmp_path / "log.txt"
    log.write_bytes(b"earlier line\n")
    with open(log, "ab") as fh:
        p = subprocess.run([ROTGRAPH_EXE, "solve", str(problem), "-o", "/dev/fd/1"], stdout=fh, stderr=subprocess.PIPE,
                           cwd=tmp_path, timeout=120)
    assert p.returncode == 0, p.stderr
    text = log.read_text()
    assert text.startswith("earlier line\n" + HEADER + "\n"), text[:200]  # appended, nothing replaced
    assert len(text.splitlines()) == 1 + 31 and b"rotgraph solve:" in p.stderr
    assert not _tmp_files(tmp_path)


def test_dev_stdout_into_a_pipe(problem, tmp_path):
    p = subprocess.run([ROTGRAPH_EXE, "solve", str(problem), "-o", "/dev/stdout", "-q"], capture_output=True, cwd=tmp_path,
                       timeout=120)
    assert p.returncode == 0, p.stderr
    assert p.stdout.decode().splitlines()[0] == HEADER
    assert os.path.islink("/dev/stdout")


# ============================================================================ devices and FIFOs


def test_a_device_is_written_through_never_replaced(problem, tmp_path):
    dev = _char_device(tmp_path / "null")
    before = os.lstat(dev)
    r = run("solve", problem, "-o", dev, "--edges-out", dev)  # one device twice is fine
    assert r.exit_code == 0, r.output
    after = os.lstat(dev)
    assert stat.S_ISCHR(after.st_mode) and (after.st_ino, after.st_rdev) == (before.st_ino, before.st_rdev)
    assert not _tmp_files(tmp_path)


def test_a_fifo_is_written_through_never_replaced(problem, tmp_path):
    fifo = tmp_path / "pipe.csv"
    os.mkfifo(fifo)
    ino = os.lstat(fifo).st_ino
    with _fifo_reader(fifo) as got:
        r = run("solve", problem, "-o", fifo, "-q")
    assert r.exit_code == 0, r.output
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode) and os.lstat(fifo).st_ino == ino
    lines = got[0].decode().splitlines()
    assert lines[0] == HEADER and len(lines) == 31
    assert not _tmp_files(tmp_path)


@pytest.mark.parametrize("writer", ["rotations", "edges_csv", "edges", "absolute_text", "plot_bytes"])
def test_every_writer_writes_through_a_fifo(writer, tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    R = np.repeat(np.eye(3)[None], 3, axis=0)
    with _fifo_reader(fifo) as got:
        if writer == "rotations":
            write_rotations(fifo, [0, 1, 2], None, R)
        elif writer == "edges_csv":
            write_edges_csv(fifo, [0, 1], [1, 2], [0.5, 20.0], [True, False])
        elif writer == "edges":
            write_edges(fifo, [0, 1], [1, 2], R[:2])
        elif writer == "absolute_text":
            write_absolute_rotations_text(fifo, [0, 1, 2], R)
        else:
            with atomic_write(fifo, "wb") as fh:
                fh.write(b"\x89PNG")
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode) and got[0]
    assert not _tmp_files(tmp_path)


# ============================================================================ symlinks


def test_a_symlink_is_followed_its_target_replaced_and_the_link_kept(problem, tmp_path):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    target = elsewhere / "target.csv"
    target.write_text(HEADER + "\n")  # an earlier output (a file of the user's needs --overwrite: test_overwrite.py)
    os.chmod(target, 0o640)
    link = tmp_path / "link.csv"
    link.symlink_to(os.path.relpath(target, tmp_path))
    r = run("solve", problem, "-o", link, "-q")
    assert r.exit_code == 0, r.output
    assert link.is_symlink() and os.readlink(link) == os.path.relpath(target, tmp_path)
    assert target.read_text().splitlines()[0] == HEADER
    assert stat.S_IMODE(target.stat().st_mode) == 0o640
    assert not _tmp_files(tmp_path, elsewhere)


def test_a_chain_of_symlinks_and_a_dangling_one(problem, tmp_path):
    target = tmp_path / "t.csv"
    (tmp_path / "a").symlink_to("b")
    (tmp_path / "b").symlink_to("t.csv")  # dangling: the file is created where the chain ends
    r = run("solve", problem, "-o", tmp_path / "a", "-q")
    assert r.exit_code == 0, r.output
    assert (tmp_path / "a").is_symlink() and (tmp_path / "b").is_symlink()
    assert target.read_text().splitlines()[0] == HEADER


def test_a_symlink_to_a_device_writes_the_device(problem, tmp_path):
    dev = _char_device(tmp_path / "null")
    link = tmp_path / "out.csv"
    link.symlink_to(dev)
    assert run("solve", problem, "-o", link, "-q").exit_code == 0
    assert link.is_symlink() and stat.S_ISCHR(os.lstat(dev).st_mode)


def test_an_output_symlink_to_the_input_is_refused(problem, tmp_path):
    data = problem.read_bytes()
    link = tmp_path / "out.csv"
    link.symlink_to(problem)
    r = run("solve", problem, "-o", link)
    assert r.exit_code == 3 and "would overwrite the input" in r.stderr, r.output
    assert link.is_symlink() and problem.read_bytes() == data
    # and two names of one file are one output
    other = tmp_path / "other.csv"
    other.symlink_to(tmp_path / "real.csv")
    r = run("solve", problem, "-o", tmp_path / "real.csv", "--edges-out", other)
    assert r.exit_code == 3 and "named twice as an output" in r.stderr, r.output


def test_interrupt_while_writing_through_a_symlink_leaves_the_target_and_no_temp(tmp_path):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    target = elsewhere / "t.csv"
    target.write_text("old\n")
    link = tmp_path / "link.csv"
    link.symlink_to(target)
    with pytest.raises(KeyboardInterrupt):
        with atomic_write(link) as fh:
            fh.write("new\n")
            raise KeyboardInterrupt
    assert target.read_text() == "old\n" and link.is_symlink()
    assert not _tmp_files(tmp_path, elsewhere)


# ============================================================================ folders that refuse files


@needs_sys
def test_an_unwritable_folder_is_exit_3_before_the_input_is_read(tmp_path):
    bad_input = tmp_path / "e.txt"
    bad_input.write_text("this is not a view graph\n")
    r = run("solve", bad_input, "-o", "/sys/out.csv")
    assert r.exit_code == 3, r.output
    assert r.stderr.strip() == "rotgraph: error: /sys/out.csv: cannot write here: permission denied in the folder /sys", r.stderr


@needs_sys
def test_an_unwritable_folder_through_the_real_entry_point(problem, tmp_path):
    edges = tmp_path / "edges.csv"
    edges.write_text("old\n")
    p = subprocess.run([ROTGRAPH_EXE, "solve", str(problem), "-o", "/sys/out.csv", "--edges-out", str(edges)],
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 3, p.stderr
    assert p.stderr.splitlines() == ["rotgraph: error: /sys/out.csv: cannot write here: permission denied in the folder /sys"]
    assert edges.read_text() == "old\n" and not _tmp_files(tmp_path)


@needs_proc
def test_proc_refuses_new_files(problem, tmp_path):
    with pytest.raises(InputError, match="cannot write here"):
        check_outputs([tmp_path / "ok.csv", "/proc/out.csv"], [problem])
    r = run("info", problem, "--plot", "/proc/plot.png")
    assert r.exit_code == 3 and r.stderr.startswith("rotgraph: error: /proc/plot.png: cannot write here"), r.output
    assert not _tmp_files(tmp_path)


@needs_sys
def test_atomic_write_into_an_unwritable_folder_is_an_input_error():
    with pytest.raises(InputError, match="/sys/x.csv: cannot write here"):
        with atomic_write("/sys/x.csv") as fh:
            fh.write("x\n")


def test_json_output_has_no_bare_nan(capsys):
    """--json output is strict JSON: a value not measured (NaN) or infinite is null."""
    import json

    from rotgraph.cli.common import emit_json

    emit_json({"a": float("nan"), "b": [1.0, float("inf"), (2, float("-inf"))], "c": {"d": float("nan"), "e": 2}})
    out = capsys.readouterr().out
    assert "NaN" not in out and "Infinity" not in out
    assert json.loads(out) == {"a": None, "b": [1.0, None, [2, None]], "c": {"d": None, "e": 2}}
