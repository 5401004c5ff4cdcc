"""The ``rotgraph`` command group. Each command parses its arguments, calls the library,
and writes its output; errors from the library become one line on stderr and an exit
code (CLI.md): 1 unsolvable, 2 usage (click's own), 3 bad input.
"""

from __future__ import annotations

import logging
import sys

import click

from rotgraph import __version__
from rotgraph.errors import InputError, RotgraphError, UnsolvableError

from .common import EXIT_BAD_INPUT, EXIT_UNSOLVABLE, fail

logger = logging.getLogger("rotgraph")


class RotgraphGroup(click.Group):
    """Turns rotgraph's exceptions into CLI.md's one-line errors and exit codes."""

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except (click.exceptions.Exit, click.ClickException, click.Abort, SystemExit):
            raise
        except Exception as exc:  # one line, no traceback, unless --debug
            if ctx.params.get("debug"):
                raise
            if isinstance(exc, InputError):
                fail(str(exc), EXIT_BAD_INPUT)
            if isinstance(exc, UnsolvableError):
                fail(str(exc), EXIT_UNSOLVABLE)
            if isinstance(exc, RotgraphError):
                fail(str(exc), EXIT_UNSOLVABLE)
            if isinstance(exc, MemoryError):
                fail("out of memory", EXIT_UNSOLVABLE)
            fail(f"unexpected {type(exc).__name__}: {exc} (run with --debug for the traceback)", EXIT_UNSOLVABLE)


@click.group(cls=RotgraphGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="rotgraph")
@click.option("-v", "--verbose", count=True, help="More log output on stderr (-vv for debug).")
@click.option("--debug", is_flag=True, help="Show Python tracebacks instead of one-line errors.")
def cli(verbose: int, debug: bool) -> None:
    """rotgraph: rotation averaging for Structure-from-Motion.

    Conventions: quaternions are (w, x, y, z); absolute rotations are cam_from_world;
    the edge (i, j) carries R_ij = R_j R_i^T (COLMAP's cam2_from_cam1).
    """
    level = logging.WARNING - 10 * verbose if not debug else logging.DEBUG
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(_LowerLevelFormatter("rotgraph: %(levelname)s: %(message)s"))
    logging.basicConfig(level=max(level, logging.DEBUG), handlers=[handler])


class _LowerLevelFormatter(logging.Formatter):
    """``rotgraph: warning: ...``, as the messages the CLI echoes itself."""

    def format(self, record: logging.LogRecord) -> str:
        record = logging.makeLogRecord(record.__dict__)  # other handlers keep the original
        record.levelname = record.levelname.lower()
        return super().format(record)


# The commands live in their own modules (which import from .common, never from here).
from . import batch, handeye, mean, solve  # noqa: E402

for _command in (mean.mean, solve.solve, solve.evaluate, solve.synth, solve.info, batch.batch, handeye.handeye):
    cli.add_command(_command)

if __name__ == "__main__":  # pragma: no cover
    cli()
