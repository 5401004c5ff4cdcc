"""``rotgraph mean``: single rotation averaging of the rotations in a file.

The work is :func:`rotgraph.pipeline.mean.mean_file`; this module parses the options and
prints its result.
"""

from __future__ import annotations

import logging

import click

from rotgraph.choices import LOSSES, METRICS, NORMS, TABLE_FORMATS

from .common import emit_json


@click.command()
@click.argument("file", type=click.Path(dir_okay=True, path_type=str))
@click.option("--metric", type=click.Choice(METRICS), default="geodesic", show_default=True,
              help="Distance between rotations: the angle, |R - S|_F, or min |q -+ p|.")
@click.option("--norm", type=click.Choice(NORMS), default="l2", show_default=True,
              help="l2: mean; l1: median (Weiszfeld); robust: IRLS with --loss.")
@click.option("--loss", type=click.Choice([name for name in LOSSES if name not in ("l1", "l2")]),
              default="cauchy", show_default=True, help="Robust loss (with --norm robust).")
@click.option("--scale-deg", type=click.FloatRange(min=0, min_open=True), default=None,
              help="Robust loss scale in degrees [default: twice the median residual of the L1 median].")
@click.option("--format", "fmt", type=click.Choice(TABLE_FORMATS), default="auto", show_default=True,
              help="text: 'qw qx qy qz [weight]' lines; csv: header with qw,qx,qy,qz[,weight].")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object (quaternion, cost, ...).")
def mean(file, metric, norm, loss, scale_deg, fmt, as_json):
    """Single rotation averaging: the mean (or median) of the rotations in FILE.

    FILE has one rotation a line, 'qw qx qy qz [weight]', or is a CSV with columns
    qw,qx,qy,qz[,weight]. Prints the mean as 'qw qx qy qz' (w >= 0).

    Examples (in an empty folder): 40 views of the identity with noise (0.05 rad, about 3
    degrees, per axis), then their mean; FILE can be any CSV with qw,qx,qy,qz columns
    too (e.g. a solve output):

    \b
      python -c "import numpy as np; from rotgraph import so3; R = so3.perturb(np.stack([np.eye(3)] * 40), 0.05, 0); np.savetxt('views.txt', so3.quaternions_from_matrices(R))"
      rotgraph mean views.txt --metric geodesic --norm l1
      rotgraph mean views.txt --norm robust --loss cauchy --json
    """
    from rotgraph.pipeline.mean import mean_file

    out = mean_file(file, metric=metric, norm=norm, loss=loss, scale_deg=scale_deg, fmt=fmt)
    res = out.result
    if as_json:
        emit_json(out.to_dict())
    else:
        for msg in res.warnings:
            if "converge" not in msg:  # non-convergence was already logged by the library
                logging.getLogger("rotgraph").warning(msg)  # -q silences it
        click.echo(" ".join(repr(float(v)) for v in res.quaternion))
