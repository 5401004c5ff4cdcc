"""The examples of every ``rotgraph ... --help`` (issue #28): each prints on its own line
exactly as the docstring has it (click's ``\\b`` paragraphs, not re-wrapped at any terminal
width) and runs as printed, in order, in an empty folder.

Example lines are those that start with ``rotgraph `` or ``python -c`` (a line of several
commands joined by ``&&`` is split). ``rotgraph`` lines run through click's CliRunner,
``python -c`` lines as a subprocess (arguments split as a POSIX shell does, shlex).
"""

from __future__ import annotations

import importlib.util
import inspect
import shlex
import subprocess
import sys

import pytest
from click.testing import CliRunner

from rotgraph.cli.main import cli

WIDTHS = (80, 200)
SLOW = {"batch", "reconstruct"}  # Dask clusters; pycolmap's synthetic project and global mapper (seconds each)
HAS_DASK = importlib.util.find_spec("distributed") is not None


def _command(name: str):
    return cli if name == "" else cli.commands[name]


def _help(name: str, width: int) -> str:
    args = ([name] if name else []) + ["--help"]
    r = CliRunner().invoke(cli, args, terminal_width=width, catch_exceptions=False)
    assert r.exit_code == 0, r.output
    return r.output


def _examples(text: str) -> list[str]:
    """The example commands of a help text or docstring, in order."""
    out = []
    for line in text.splitlines():
        line = line.strip()
        if line.startswith(("rotgraph ", "python -c")):
            out.extend(part.strip() for part in line.split(" && "))
    return out


def _names() -> list[str]:
    return [""] + sorted(cli.commands)


def _param(name: str):
    marks = [pytest.mark.slow] if name in SLOW else []
    return pytest.param(name, id=name or "rotgraph", marks=marks)


def test_every_command_has_examples():
    for name in _names():
        assert _examples(inspect.cleandoc(_command(name).help or "")), f"rotgraph {name}: no example in the help"


@pytest.mark.parametrize("width", WIDTHS)
@pytest.mark.parametrize("name", _names(), ids=lambda n: n or "rotgraph")
def test_help_examples_print_intact(name, width):
    """Each example of the docstring is one line of the rendered help, as written."""
    source = [line.strip() for line in inspect.cleandoc(_command(name).help or "").splitlines()]
    wanted = [line for line in source if line.startswith(("rotgraph ", "python -c"))]
    shown = [line.strip() for line in _help(name, width).splitlines()]
    shown_examples = [line for line in shown if line.startswith(("rotgraph ", "python -c"))]
    assert wanted, f"rotgraph {name}: no example"
    # a re-wrapped example would show only its head here (its tail on the next line)
    assert shown_examples == wanted, f"rotgraph {name} --help at width {width} re-wrapped its examples"


def _run(line: str, cwd) -> tuple[int, str]:
    args = shlex.split(line)
    if args[0] == "rotgraph":
        r = CliRunner().invoke(cli, args[1:])
        if r.exception is not None and not isinstance(r.exception, SystemExit):
            raise r.exception
        return r.exit_code, r.output
    assert args[:2] == ["python", "-c"], line
    p = subprocess.run([sys.executable, *args[1:]], cwd=cwd, capture_output=True, text=True, timeout=300)
    return p.returncode, p.stdout + p.stderr


@pytest.mark.parametrize("name", [_param(n) for n in _names()])
def test_help_examples_run_in_an_empty_folder(name, tmp_path, monkeypatch):
    """Every example, in the order printed, from an empty folder: no usage error, exit 0
    (batch without Dask installed: its one-line 'needs Dask' error, exit 1)."""
    monkeypatch.chdir(tmp_path)
    for line in _examples(inspect.cleandoc(_command(name).help or "")):
        code, output = _run(line, tmp_path)
        assert code != 2, f"usage error: {line}\n{output}"
        if line.startswith("rotgraph batch ") and not HAS_DASK:
            assert code == 1 and "needs Dask" in output, f"{line}\n{output}"
            continue
        assert code == 0, f"exit {code}: {line}\n{output}"
