"""The solver options of ``rotgraph solve``, shared as they are by ``rotgraph batch`` (same
names, choices, defaults and help), so that a batch output equals ``rotgraph solve`` on
the same input.

The choices and defaults come from the library (:mod:`rotgraph.choices`,
:class:`~rotgraph.estimators.types.SolveOptions`). Only the options a user sets are passed
on (:func:`solve_overrides`): the defaults of the input's format (e.g. COLMAP's inlier-count
weights) apply to every other field. ``--duplicates`` likewise: None unless set, and the
reader applies the format's default (keep for g2o, error otherwise). ``--columns`` (None
unless set) is passed to the reader as it is; ``reconstruct`` refuses it.
"""

from __future__ import annotations

import click
from click.core import ParameterSource

from rotgraph.choices import DUPLICATE_POLICIES, EDGE_FORMATS, INITS, LOSSES, METHOD_TABLE, METHODS, RIG_EXTRINSICS
from rotgraph.estimators.types import SolveOptions

_D = SolveOptions()

#: ``--duplicates`` of solve, batch and info. Not set = None: the input format's default
#: (rotgraph.pipeline.read.default_duplicates), which the help states.
DUPLICATES_OPTION = click.option(
    "--duplicates", type=click.Choice(DUPLICATE_POLICIES), default=None, show_default="error; keep for g2o",
    help="What to do with several edges between one pair of cameras: error, merge them into one (weighted chordal "
         "mean), or keep them as separate measurements (normal in pose graphs).")


def _columns(ctx, param, value):
    """``--columns SPEC`` checked at once (a bad spec is a usage error, exit 2)."""
    if value is None:
        return None
    from rotgraph.errors import OptionError
    from rotgraph.io.edges import parse_columns

    try:
        return parse_columns(value)
    except OptionError as exc:
        raise click.BadParameter(str(exc).removeprefix("--columns: ")) from None


#: ``--columns`` of solve, batch, info and certify: the columns of an edge table of another
#: layout (rotgraph.io.edges.parse_columns), e.g. a GLOMAP/COLMAP export with 8 columns.
COLUMNS_OPTION = click.option(
    "--columns", "columns", metavar="SPEC", default=None, callback=_columns,
    help="Name the columns of a white-space or CSV edge table of another layout, in order, comma-separated: i, j, qw, "
         "qx, qy, qz (needed), weight, h_xx h_xy h_xz h_yy h_yz h_zz (rotation information, all six or none), and - (or "
         "tx, ty, tz) for a column to ignore; e.g. --columns i,j,qw,qx,qy,qz,weight,- for an 8-column "
         "relative_rotations.txt. A first line of names is skipped as a header.")

SOLVER_OPTIONS = [
    click.option("--format", "fmt", type=click.Choice(EDGE_FORMATS), default="auto", show_default=True, help="Input format."),
    click.option("--method", type=click.Choice(METHODS), default=_D.method, show_default=True,
                 help="; ".join(f"{m.name}: {m.help}" for m in METHOD_TABLE) + "."),
    click.option("--loss", type=click.Choice(LOSSES), default=_D.loss, show_default=True, help="Robust loss of --method irls."),
    click.option("--loss-scale-deg", type=click.FloatRange(min=0, min_open=True), default=_D.loss_scale_deg, show_default=True,
                 help="Scale of the robust loss of --method irls (degrees)."),
    click.option("--no-rescale", is_flag=True, help="--method irls: keep the loss scale fixed (default: re-fit it to the inlier residuals once)."),
    click.option("--init", type=click.Choice(INITS), default=_D.init, show_default=True,
                 help="Initialisation of the iterative methods: auto (adaptive: the spanning tree and the chordal "
                      "relaxation, each carried through the robust stages, the answer of lower L1 cost over every edge "
                      "kept; other methods: the spanning tree), mst, chordal, quaternion, or "
                      "vertices: the input's own initial guess (g2o VERTEX lines; cameras without one are chained from "
                      "the spanning tree)."),
    click.option("--refine", is_flag=True, help="Finish with Levenberg-Marquardt on the exact geodesic robust cost."),
    click.option("--use-weights/--no-use-weights", default=None,
                 help="Weight edges by their weight column (inlier counts) in the cost, not only in the spanning tree "
                      "[default: on for COLMAP projects without pair information, off otherwise; off, the adaptive "
                      "method tests whether the weights predict the residuals' noise (sigma ~ w^-a, a cross-validated) "
                      "and uses them as precisions w^2a when they do: diagnostics 'weights']."),
    click.option("--use-information/--no-use-information", default=None,
                 help="Weight each edge by its rotation information matrix when the input has them (g2o information, "
                      "the info_* columns, COLMAP pair uncertainties) [default: on]."),
    click.option("--outlier-threshold-deg", type=click.FloatRange(min=0, min_open=True), default=_D.outlier_threshold_deg,
                 help="Edges with a larger final residual are reported as outliers [default: adaptive: where the fitted "
                      "noise model makes an edge more likely an outlier than not; irls, l1: 10]."),
    click.option("--max-iterations", type=click.IntRange(min=1), default=_D.max_iterations, show_default=True),
    click.option("--rig-extrinsics", type=click.Choice(RIG_EXTRINSICS), default=_D.rig_extrinsics, show_default=True,
                 help="Inputs with rigs: auto (given cam_from_rig fixed, unknown ones estimated with the frames), fixed "
                      "(given ones fixed; images of a sensor without one solved on their own), refine (given ones are "
                      "starting values, every non-reference sensor estimated), unknown (given ones ignored)."),
    DUPLICATES_OPTION,
    COLUMNS_OPTION,
    click.option("--seed", type=int, default=0, show_default=True,
                 help="Seed of the random subset of residuals the adaptive noise model is fitted on (graphs of more "
                      "than 20 000 edges): the result is deterministic for a given seed."),
]

# click parameter -> SolveOptions field (and how the value maps)
_FIELDS = {
    "method": ("method", None),
    "loss": ("loss", None),
    "loss_scale_deg": ("loss_scale_deg", None),
    "no_rescale": ("rescale", lambda v: not v),
    "init": ("init", None),
    "refine": ("refine", None),
    "use_weights": ("use_weights", None),
    "use_information": ("use_information", None),
    "outlier_threshold_deg": ("outlier_threshold_deg", None),
    "max_iterations": ("max_iterations", None),
    "rig_extrinsics": ("rig_extrinsics", None),
    "seed": ("seed", None),
}


def solver_options(f):
    """Decorate a command with :data:`SOLVER_OPTIONS` (in their order)."""
    for option in reversed(SOLVER_OPTIONS):
        f = option(f)
    return f


def solve_overrides(ctx: click.Context, params: dict) -> dict:
    """The :class:`SolveOptions` fields the user set on the command line (not defaults)."""
    out = {}
    for name, (field, convert) in _FIELDS.items():
        if ctx.get_parameter_source(name) not in (ParameterSource.DEFAULT, None):
            value = params[name]
            out[field] = convert(value) if convert else value
    return out
