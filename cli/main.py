"""The ``rotgraph`` command group. Each command parses its arguments, calls the library,
and writes its output; errors from the library become one line on stderr and an exit
code (CLI.md): 1 unsolvable, 2 usage (click's own), 3 bad input.
"""

from __future__ import annotations

import json
import logging
import sys

import click
import numpy as np

from rotgraph import __version__
from rotgraph.errors import InputError, RotgraphError, UnsolvableError

EXIT_UNSOLVABLE = 1
EXIT_BAD_INPUT = 3

logger = logging.getLogger("rotgraph")


def fail(message: str, code: int) -> None:
    click.echo(f"rotgraph: error: {message}", err=True)
    sys.exit(code)


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


def plural(k: int, word: str) -> str:
    """``1 edge``, ``2 edges``."""
    return f"{k} {word}" + ("" if k == 1 else "s")


def emit_json(obj) -> None:
    click.echo(json.dumps(obj, indent=None, sort_keys=False))


# --------------------------------------------------------------------------- mean


@cli.command()
@click.argument("file", type=click.Path(dir_okay=True, path_type=str))
@click.option("--metric", type=click.Choice(["geodesic", "chordal", "quaternion"]), default="geodesic", show_default=True,
              help="Distance between rotations: the angle, |R - S|_F, or min |q -+ p|.")
@click.option("--norm", type=click.Choice(["l1", "l2", "robust"]), default="l2", show_default=True,
              help="l2: mean; l1: median (Weiszfeld); robust: IRLS with --loss.")
@click.option("--loss", type=click.Choice(["cauchy", "huber", "geman_mcclure", "half_norm", "truncated_l2"]),
              default="cauchy", show_default=True, help="Robust loss (with --norm robust).")
@click.option("--scale-deg", type=click.FloatRange(min=0, min_open=True), default=None,
              help="Robust loss scale in degrees [default: twice the median residual of the L1 median].")
@click.option("--format", "fmt", type=click.Choice(["auto", "text", "csv"]), default="auto", show_default=True,
              help="text: 'qw qx qy qz [weight]' lines; csv: header with qw,qx,qy,qz[,weight].")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object (quaternion, cost, ...).")
def mean(file, metric, norm, loss, scale_deg, fmt, as_json):
    """Single rotation averaging: the mean (or median) of the rotations in FILE.

    FILE has one rotation a line, 'qw qx qy qz [weight]', or is a CSV with columns
    qw,qx,qy,qz[,weight]. Prints the mean as 'qw qx qy qz' (w >= 0).

    Example: rotgraph mean datasets/sample_rotations.txt --metric geodesic --norm l1
    """
    from rotgraph.io.rotations import read_weighted_quaternions
    from rotgraph.estimators.single import mean as average

    q, w, _ = read_weighted_quaternions(file, fmt)
    res = average(q, metric=metric, norm=norm, weights=w, loss=loss, scale_deg=scale_deg)
    if as_json:
        out = {
            "quaternion": [float(v) for v in res.quaternion],
            "cost": res.cost,
            "metric": metric,
            "norm": norm,
            "n_rotations": int(len(q)),
            "iterations": res.iterations,
            "converged": res.converged,
            "median_residual_deg": float(np.degrees(np.median(res.residuals))),
            "warnings": list(res.warnings),
        }
        if norm == "robust":
            out.update(loss=loss, scale_deg=float(np.degrees(res.scale)), n_inliers=int(res.inliers.sum()))
        emit_json(out)
    else:
        for msg in res.warnings:
            if "converge" not in msg:  # non-convergence was already logged by the library
                click.echo(f"rotgraph: warning: {msg}", err=True)
        click.echo(" ".join(repr(float(v)) for v in res.quaternion))




# Register the commands that live in their own modules.
from . import solve as _solve  # noqa: E402,F401
from . import batch as _batch  # noqa: E402,F401
from . import handeye as _handeye  # noqa: E402,F401

if __name__ == "__main__":  # pragma: no cover
    cli()
