"""The ``rotgraph`` command group. Each command parses its arguments, calls the library,
and writes its output; errors from the library become one line on stderr and an exit
code (CLI.md): 1 unsolvable, 2 usage (click's own), 3 bad input, 130 interrupted.
"""

from __future__ import annotations

import logging
import os
import re
import sys

import click

from rotgraph import __version__
from rotgraph.errors import InputError, OptionError, RotgraphError

from .common import EXIT_BAD_INPUT, EXIT_UNSOLVABLE, emit_json, fail

logger = logging.getLogger("rotgraph")


EXIT_USAGE = 2  # CLI.md: usage error (click's own)
EXIT_INTERRUPTED = 130  # CLI.md: Ctrl-C / SIGINT
EXIT_BROKEN_PIPE = 141  # 128 + SIGPIPE, as a shell reports a writer whose reader left


def _is_group_flag(arg: str) -> bool:
    return arg in ("--verbose", "--debug", "--quiet") or re.fullmatch(r"-v+|-q", arg) is not None


class RotgraphGroup(click.Group):
    """Turns rotgraph's exceptions into CLI.md's one-line errors and exit codes, and takes
    the group's flags (``-v``, ``--debug``, ``-q``) before or after the command name."""

    def parse_args(self, ctx: click.Context, args: list[str]) -> list[str]:
        at = next((k for k, a in enumerate(args) if not a.startswith("-")), None)
        # --json after the command name: failures are reported as one JSON object on stdout too.
        ctx.meta["rotgraph.json"] = at is not None and "--json" in args[at + 1 :]
        if at is not None and args[at] in self.commands:
            command = self.commands[args[at]]
            own_quiet = any(p.name == "quiet" for p in command.params)
            rest = args[at + 1 :]
            stop = rest.index("--") if "--" in rest else len(rest)
            flags = [a for a in args[:at] + rest[:stop] if _is_group_flag(a)]
            quiet = [a for a in flags if a in ("-q", "--quiet")] if own_quiet else []
            group = [a for a in flags if a not in quiet]
            keep_head = [a for a in args[:at] if not _is_group_flag(a)]
            keep_rest = [a for a in rest[:stop] if not _is_group_flag(a)] + rest[stop:]
            args = group + keep_head + [args[at]] + quiet + keep_rest
        return super().parse_args(ctx, args)

    def invoke(self, ctx: click.Context):
        as_json = ctx.meta.get("rotgraph.json", False)
        try:
            return super().invoke(ctx)
        except (click.exceptions.Exit, click.Abort, SystemExit):
            raise
        except click.ClickException as exc:
            if as_json:
                emit_json({"error": exc.format_message(), "exit_code": exc.exit_code})
            raise
        except KeyboardInterrupt:
            if ctx.params.get("debug"):
                raise
            self._fail("interrupted", EXIT_INTERRUPTED, as_json)
        except BrokenPipeError:  # the reader of stdout went away (e.g. '| head'): stop quietly
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            sys.exit(EXIT_BROKEN_PIPE)
        except Exception as exc:  # one line, no traceback, unless --debug
            if ctx.params.get("debug"):
                raise
            if isinstance(exc, InputError):
                self._fail(str(exc), EXIT_BAD_INPUT, as_json)
            if isinstance(exc, OptionError):
                self._fail(str(exc), EXIT_USAGE, as_json)
            if isinstance(exc, OSError) and exc.filename is not None:  # a file the library did not expect to fail
                reason = exc.strerror or str(exc)
                self._fail(f"{exc.filename}: {reason[:1].lower() + reason[1:]}", EXIT_BAD_INPUT, as_json)
            if isinstance(exc, RotgraphError):  # UnsolvableError and the others
                self._fail(str(exc), EXIT_UNSOLVABLE, as_json)
            if isinstance(exc, MemoryError):
                self._fail("out of memory", EXIT_UNSOLVABLE, as_json)
            self._fail(f"unexpected {type(exc).__name__}: {exc} (run with --debug for the traceback)", EXIT_UNSOLVABLE, as_json)

    @staticmethod
    def _fail(message: str, code: int, as_json: bool) -> None:
        if as_json:
            emit_json({"error": message, "exit_code": code})
        fail(message, code)


@click.group(cls=RotgraphGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="rotgraph")
@click.option("-v", "--verbose", count=True, help="More log output on stderr (-vv for debug); before or after the command.")
@click.option("--debug", is_flag=True, help="Show Python tracebacks instead of one-line errors.")
@click.option("-q", "--quiet", is_flag=True, help="Only errors on stderr (commands with their own -q also drop progress and summary).")
def cli(verbose: int, debug: bool, quiet: bool) -> None:
    """rotgraph: rotation averaging for Structure-from-Motion.

    Conventions: quaternions are (w, x, y, z); absolute rotations are cam_from_world;
    the edge (i, j) carries R_ij = R_j R_i^T (COLMAP's cam2_from_cam1).

    Example (in an empty folder; 'rotgraph COMMAND --help' has more):

    \b
      rotgraph synth -o problem --n 50
      rotgraph solve problem/edges.txt -o rotations.csv
      rotgraph eval rotations.csv problem/gt.txt
    """
    level = logging.WARNING - 10 * verbose if not debug else logging.DEBUG
    if quiet and not debug:
        level = logging.ERROR
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(_LowerLevelFormatter("rotgraph: %(levelname)s: %(message)s"))
    logging.basicConfig(level=max(level, logging.DEBUG), handlers=[handler], force=True)  # force: each run in a process


class _LowerLevelFormatter(logging.Formatter):
    """``rotgraph: warning: ...``, as the messages the CLI echoes itself."""

    def format(self, record: logging.LogRecord) -> str:
        record = logging.makeLogRecord(record.__dict__)  # other handlers keep the original
        record.levelname = record.levelname.lower()
        return super().format(record)


# The commands live in their own modules (which import from .common, never from here).
from . import batch, certify, handeye, mean, solve  # noqa: E402
from . import reconstruct  # noqa: E402

for _command in (mean.mean, solve.solve, solve.evaluate, solve.synth, solve.info, batch.batch, handeye.handeye,
                 certify.certify):
    cli.add_command(_command)
cli.add_command(reconstruct.reconstruct)

if __name__ == "__main__":  # pragma: no cover
    cli()
