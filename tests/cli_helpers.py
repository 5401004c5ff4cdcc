"""Helpers of the command-line tests (importable: pyproject sets ``pythonpath = ["tests"]``)."""

from __future__ import annotations

from click.testing import CliRunner

from rotgraph.cli.main import cli


def run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=False)


def assert_clean_error(result, path, line=None, code=3):
    """CLI.md's error contract: exit ``code``, one stderr line ``rotgraph: error: PATH[:LINE]:``,
    no traceback."""
    assert result.exit_code == code, result.output
    err = result.stderr.strip().splitlines()
    assert len(err) == 1, result.stderr
    assert err[0].startswith("rotgraph: error: ")
    assert str(path) in err[0]
    if line is not None:
        assert f"{path}:{line}:" in err[0]
    assert "Traceback" not in result.output


def refuses_files(folder: str) -> bool:
    """Whether ``folder`` refuses new files for this process, root included (/sys, /proc)."""
    import os
    import tempfile

    try:
        fd, tmp = tempfile.mkstemp(dir=folder)
    except OSError:
        return True
    os.close(fd)
    os.unlink(tmp)
    return False
