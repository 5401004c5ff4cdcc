"""What every command shares: exit codes (CLI.md), one-line errors, JSON output, plurals.

The command modules import from here, never from :mod:`.main` (which imports them)."""

from __future__ import annotations

import json
import math
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


def _json_safe(obj):
    """``obj`` with every non-finite float (NaN: not measured, inf) as None: JSON has no
    NaN, and ``json.dumps`` would write a bare ``NaN`` that strict parsers reject."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_json_safe(v) for v in obj]
    return obj


def emit_json(obj) -> None:
    click.echo(json.dumps(_json_safe(obj), indent=None, sort_keys=False, allow_nan=False))
