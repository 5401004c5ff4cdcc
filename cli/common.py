"""What every command shares: exit codes (CLI.md), one-line errors, JSON output, plurals.

The command modules import from here, never from :mod:`.main` (which imports them)."""

from __future__ import annotations

import json
import sys

import click

EXIT_UNSOLVABLE = 1
EXIT_BAD_INPUT = 3


def fail(message: str, code: int) -> None:
    """``rotgraph: error: MESSAGE`` on stderr and exit with ``code``."""
    click.echo(f"rotgraph: error: {message}", err=True)
    sys.exit(code)


def plural(k: int, word: str) -> str:
    """``1 edge``, ``2 edges``."""
    return f"{k} {word}" + ("" if k == 1 else "s")


def emit_json(obj) -> None:
    from rotgraph.io.writers import json_safe

    click.echo(json.dumps(json_safe(obj), indent=None, sort_keys=False, allow_nan=False))


#: ``--overwrite`` of every command that writes files (the output rule: docs/outputs.md).
OVERWRITE_OPTION = click.option(
    "--overwrite", is_flag=True,
    help="Replace existing outputs that are not rotgraph's own earlier outputs (a file of yours, a read-only file, a "
         "COLMAP model with 3D points or positions). Without it such an output is refused before any work (exit 3). "
         "An input is never replaced.")
