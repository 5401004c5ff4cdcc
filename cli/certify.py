"""``rotgraph certify``: is a set of rotations the global minimum of the chordal cost?"""

from __future__ import annotations

import sys

import click

from rotgraph.choices import DUPLICATE_POLICIES, EDGE_FORMATS

from .common import EXIT_UNSOLVABLE, OVERWRITE_OPTION, emit_json
from .options import COLUMNS_OPTION


def verdict_words(cert: dict) -> str:
    """The summary line's account of a certificate (``certify`` and ``solve --certify``)."""
    lam = cert.get("lambda_min")
    lam_text = "n/a" if lam is None else f"{lam:.3g}"
    if not cert["certified"]:
        word = "NOT certified"
    elif cert["reason"].startswith("certified: within"):  # not a critical point: within its gap of the optimum
        word = "certified within its gap of the global optimum"
    else:
        word = "certified globally optimal"
    text = f"{word} (chordal cost; lambda_min {lam_text}, tolerance {cert['tolerance']:.3g}, gap {cert['duality_gap']:.3g}): {cert['reason']}"
    if "staircase" in cert:  # solve --certify climbed the Riemannian staircase
        text += f"; the local answer was not the global minimum: {cert['staircase']['summary']}"
    return text


@click.command()
@click.argument("rotations", type=click.Path(path_type=str))
@click.argument("edges", type=click.Path(path_type=str))
@click.option("--inliers", type=click.Path(dir_okay=False, path_type=str), default=None,
              help="An --edges-out file of rotgraph solve (i,j,residual_deg,inlier[,...,weight]): certify on its inlier "
                   "edges only, weighted by its weight column (the solve's final weights: the problem it solved).")
@click.option("--format", "fmt", type=click.Choice(EDGE_FORMATS), default="auto", show_default=True, help="Format of EDGES.")
@click.option("--duplicates", type=click.Choice(DUPLICATE_POLICIES), default=None,
              help="Parallel edges in EDGES [default: keep for g2o, error otherwise].")
@click.option("--use-weights", is_flag=True, help="Weight the edges by the weight column of EDGES instead (as solve --use-weights).")
@COLUMNS_OPTION
@click.option("--tolerance", type=click.FloatRange(min=0.0), default=None,
              help="Eigenvalue tolerance: certified when lambda_min >= -TOLERANCE, i.e. within 3 n TOLERANCE of the global "
                   "minimum [default: 1e-4, GTSAM's checkOptimality threshold].")
@click.option("--gap-tol", type=click.FloatRange(min=0.0), default=None,
              help="Also certify rotations proven within this fraction of the global minimum (relative_gap <= GAP_TOL) "
                   "when the eigenvalue test fails, e.g. 1e-3 [default: the eigenvalue test alone].")
@click.option("--refine", is_flag=True,
              help="First take the rotations to the nearest critical point of the chordal cost, then certify there "
                   "(JSON key 'before': the certificate, bound and gap of the rotations as given).")
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=str), default=None,
              help="Write the rotations certified (refined with --refine) to this CSV (id,name,qw,qx,qy,qz).")
@OVERWRITE_OPTION
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object (certified, lambda_min, duality_gap, seconds, ...).")
def certify(rotations, edges, inliers, fmt, duplicates, use_weights, columns, tolerance, gap_tol, refine, output, overwrite,
            as_json):
    """Certify ROTATIONS (any file rotgraph eval reads, e.g. a solve output) as the global
    minimum of the chordal cost sum w |R_j - R_ij R_i|^2 on the edges of EDGES: the
    Lagrangian-duality test (lambda_min of the certificate matrix >= -tolerance, GTSAM's
    checkOptimality): any rotations get a lower bound on the global minimum (dual_bound)
    and their gap to it (duality_gap, relative_gap); certified puts them within 3 n
    tolerance of the global minimum. Exit 0 when certified, 1 when not.

    A global minimum exactly is a certified critical point: the output of 'rotgraph solve
    --certify' is one (its rotations are refined to the nearest critical point of the
    chordal cost on its inlier edges, and --edges-out then gives those edges' weights);
    another solver's optimum is near one (certified within its gap); a plain geodesic solve
    output or the ground truth of a noisy problem in general is neither ('not critical').

    Examples (in an empty folder):

    \b
      rotgraph synth -o problem --n 50
      rotgraph solve problem/edges.txt -o r.csv --edges-out res.csv --certify
      rotgraph certify r.csv problem/edges.txt --inliers res.csv
      rotgraph certify r.csv problem/edges.txt --inliers res.csv --json
      rotgraph certify problem/gt.txt problem/edges.txt --refine -o certified.csv
    """
    from rotgraph.pipeline.certify import certify_files

    cert = certify_files(rotations, edges, inliers, fmt=fmt, duplicates=duplicates, use_weights=use_weights, columns=columns,
                         refine=refine, output=output, overwrite=overwrite, tol=tolerance, gap_tol=gap_tol)
    if as_json:
        emit_json(cert)
    else:
        if refine:
            b = cert["before"]
            click.echo(f"as given: cost {b['primal_cost']:.6g}, lower bound {b['dual_bound']:.6g} (gap {b['duality_gap']:.3g}, "
                       f"{b['relative_gap']:.3g} relative); refined in {cert['refine_iterations']} iterations")
        click.echo(f"rotgraph certify: {cert['n_nodes']} cameras, {cert['n_edges']} edges: {verdict_words(cert)}; "
                   f"{cert['seconds']:.2f} s")
    if not cert["certified"]:
        sys.exit(EXIT_UNSOLVABLE)
