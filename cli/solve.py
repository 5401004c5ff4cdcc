"""``rotgraph solve``, ``eval``, ``synth`` and ``info``: multiple rotation averaging commands."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import click

from rotgraph.choices import DUPLICATE_POLICIES, EDGE_FORMATS, GRAPHS

from .common import emit_json, plural
from .options import solve_overrides, solver_options
from .progress import Progress

logger = logging.getLogger("rotgraph")


def _read_graph(path: str, fmt: str, duplicates: str):
    from rotgraph.pipeline.read import read_view_graph

    return read_view_graph(path, fmt=fmt, duplicates=duplicates)


@click.command()
@click.argument("input_path", metavar="INPUT", type=click.Path(path_type=str))
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=str), required=True, help="Output CSV: id,name,qw,qx,qy,qz (cam_from_world).")
@solver_options
@click.option("--edges-out", type=click.Path(dir_okay=False, path_type=str), default=None, help="Also write i,j,residual_deg,inlier for every input edge.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object with the summary.")
@click.option("-q", "--quiet", is_flag=True, help="No progress or summary (errors still go to stderr).")
@click.pass_context
def solve(ctx, input_path, output, fmt, duplicates, edges_out, as_json, quiet, seed, **solver):
    """Multiple rotation averaging: absolute rotations from the relative rotations in INPUT.

    Writes OUTPUT with one row per solved camera (the largest connected component). The
    defaults suit the input's format (COLMAP projects: edges weighted by inlier counts);
    each option given replaces that one setting.

    Example: rotgraph solve datasets/synthetic/edges.txt -o rotations.csv
    """
    from rotgraph.pipeline.solve import solve_file

    progress = Progress(quiet or as_json)
    try:
        summary = solve_file(input_path, output, fmt=fmt, duplicates=duplicates, edges_out=edges_out, callback=progress,
                             read_progress=progress.count, overrides=solve_overrides(ctx, solver))
    finally:
        progress.close()
    if as_json:
        emit_json(summary)
    elif not quiet:
        s = summary
        rejected = f" ({s['n_rejected']} with only outlier edges)" if s["n_rejected"] else ""
        click.echo(
            f"rotgraph solve: {plural(s['n_cameras'], 'camera')}, {plural(s['n_edges'], 'edge')}, "
            f"{plural(s['n_components'], 'component')}; solved {s['n_solved']}, left out {s['n_unsolved']}{rejected}; "
            f"{plural(s['n_outliers'], 'outlier edge')} (> {s['outlier_threshold_deg']:g} deg); {s['method']}, "
            f"{plural(s['iterations'], 'iteration')}{'' if s['converged'] else ' (not converged)'}; {s['seconds']:.2f} s -> {output}"
        )
        if "eval" in summary:
            e = summary["eval"]
            click.echo(f"  vs ground truth in the input: median {e['median']:.3f} deg, mean {e['mean']:.3f} deg over {e['n_evaluated']} cameras")


@click.command(name="eval")
@click.argument("estimate", type=click.Path(path_type=str))
@click.argument("gt", type=click.Path(path_type=str))
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object with the statistics.")
@click.option("--plot", type=click.Path(dir_okay=False, path_type=str), default=None, help="Write an error CDF and histogram (PNG; needs matplotlib).")
def evaluate(estimate, gt, as_json, plot):
    """Compare estimated rotations with ground truth, after aligning the gauge.

    ESTIMATE is a rotgraph CSV (id,name,qw,qx,qy,qz) or 'id qw qx qy qz' text; GT the same,
    or an input that carries ground truth (.mat with Rgt, 1DSfM with gt_bundle.out, synth gt.txt).
    Cameras are matched by id, or by name when the ids do not match.

    Example: rotgraph eval rotations.csv datasets/synthetic/gt.txt
    """
    from rotgraph.io.text import check_outputs
    from rotgraph.pipeline.solve import evaluate_files

    if plot:
        check_outputs([plot], [estimate, gt])
    ev = evaluate_files(estimate, gt)
    if plot:
        _plot_errors(ev.errors_deg, plot)
    if as_json:
        emit_json(ev.to_dict())
    else:
        click.echo(f"cameras evaluated: {ev.n_evaluated} (estimated {ev.n_estimated}, ground truth {ev.n_ground_truth})")
        click.echo(f"error [deg]: mean {ev.mean:.4f}  median {ev.median:.4f}  rmse {ev.rmse:.4f}  max {ev.max:.4f}")
        click.echo(f"under 1/2/5/10 deg: {ev.under_1deg:.1%} / {ev.under_2deg:.1%} / {ev.under_5deg:.1%} / {ev.under_10deg:.1%}")


def _plot_errors(errors_deg, path: str) -> None:
    import numpy as np

    from rotgraph.errors import RotgraphError
    from rotgraph.io.text import atomic_write

    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise RotgraphError("--plot needs matplotlib: pip install 'rotgraph[plot]'") from None
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    e = np.sort(errors_deg)
    a.plot(e, np.arange(1, len(e) + 1) / len(e))
    a.set_xscale("log" if e.max() > 0 and e[e > 0].size else "linear")
    a.set_xlabel("rotation error [deg]")
    a.set_ylabel("fraction of cameras")
    a.set_title("error CDF")
    a.grid(True, which="both", alpha=0.3)
    b.hist(e, bins=min(50, max(5, len(e) // 5)))
    b.set_xlabel("rotation error [deg]")
    b.set_ylabel("cameras")
    b.set_title(f"median {np.median(e):.3f} deg, n = {len(e)}")
    fig.tight_layout()
    with atomic_write(path, "wb") as fh:
        fig.savefig(fh, format="png", dpi=100)
    plt.close(fig)


@click.command()
@click.option("-o", "--output", "out_dir", type=click.Path(file_okay=False, path_type=str), required=True, help="Folder for edges.txt, gt.txt, meta.json.")
@click.option("--n", type=click.IntRange(min=2), default=100, show_default=True, help="Number of cameras.")
@click.option("--degree", type=click.FloatRange(min=1), default=10.0, show_default=True, help="Average number of edges per camera.")
@click.option("--sigma", type=click.FloatRange(min=0), default=2.0, show_default=True, help="Noise on each relative rotation (degrees, per axis).")
@click.option("--outliers", type=click.FloatRange(min=0, max=1), default=0.0, show_default=True, help="Fraction of edges replaced by random rotations.")
@click.option("--graph", type=click.Choice(GRAPHS), default="er", show_default=True, help="er: random graph; traj: a camera trajectory with loop closures.")
@click.option("--seed", type=int, default=0, show_default=True)
def synth(out_dir, n, degree, sigma, outliers, graph, seed):
    """Write a synthetic problem with ground truth: edges.txt, gt.txt, meta.json.

    Example: rotgraph synth -o /tmp/problem --n 500 --degree 20 --sigma 2 --outliers 0.1
    """
    from rotgraph.io.writers import write_absolute_rotations_text, write_edges
    from rotgraph.io.text import atomic_write
    from rotgraph.synth import random_problem

    g = random_problem(n, degree, sigma, outliers, graph, seed)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    write_edges(out / "edges.txt", g)
    write_absolute_rotations_text(out / "gt.txt", g.node_ids, g.gt_cam_from_world)
    meta = {"n": n, "degree": degree, "sigma_deg": sigma, "outliers": outliers, "graph": graph, "seed": seed,
            "n_edges": g.n_edges, "n_outlier_edges": int(g.meta["outlier"].sum()),
            "convention": "R_ij = R_j R_i^T, R = cam_from_world, quaternions (w, x, y, z)"}
    with atomic_write(out / "meta.json") as fh:
        json.dump(meta, fh, indent=2)
        fh.write("\n")
    click.echo(f"rotgraph synth: {plural(n, 'camera')}, {plural(g.n_edges, 'edge')} ({plural(meta['n_outlier_edges'], 'outlier')}) -> {out}")


@click.command()
@click.argument("input_path", metavar="INPUT", type=click.Path(path_type=str))
@click.option("--format", "fmt", type=click.Choice(EDGE_FORMATS), default="auto", show_default=True)
@click.option("--duplicates", type=click.Choice(DUPLICATE_POLICIES), default="error", show_default=True)
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
@click.option("--plot", type=click.Path(dir_okay=False, path_type=str), default=None,
              help="Write degree and cycle-error histograms (and, up to 300 cameras, the graph coloured by residual) to a PNG.")
def info(input_path, fmt, duplicates, as_json, plot):
    """View-graph summary: cameras, edges, components, degrees, cycle consistency.

    Example: rotgraph info datasets/synthetic/edges.txt
    """
    import numpy as np

    from rotgraph.io.text import check_outputs
    from rotgraph.viewgraph import cycle_errors, cycle_statistics

    if plot:
        check_outputs([plot], [input_path])

    graph = _read_graph(input_path, fmt, duplicates)
    s = graph.summary()
    cyc = np.degrees(cycle_errors(graph))
    s.update(cycle_statistics(cyc))
    gt = graph.gt_cam_from_world
    s["n_ground_truth"] = int(np.isfinite(gt).all(axis=(1, 2)).sum()) if gt is not None else 0
    if plot:
        _plot_info(graph, cyc, plot)
    if as_json:
        emit_json(s)
        return
    click.echo(f"cameras: {s['n_cameras']}   edges: {s['n_edges']}   components: {s['n_components']} (largest {s['largest_component']})")
    click.echo(f"degree: min {s['degree_min']}  median {s['degree_median']:g}  max {s['degree_max']}")
    if len(cyc):
        click.echo(
            f"cycle consistency over {len(cyc)} triangles [deg]: median {s['cycle_error_median_deg']:.3f}  mean {s['cycle_error_mean_deg']:.3f}  "
            f"p90 {s['cycle_error_p90_deg']:.3f}; < 2 deg {s['cycle_under_2deg']:.1%}, > 10 deg {s['cycle_over_10deg']:.1%}"
        )
    else:
        click.echo("cycle consistency: no triangles")
    if s["n_ground_truth"]:
        click.echo(f"ground truth in the input: {s['n_ground_truth']} cameras")


def _plot_info(graph, cycle_deg, path: str) -> None:
    """Degree and cycle-error histograms; for small graphs also the view graph with edges
    coloured by their residual after a default solve."""
    import numpy as np

    from rotgraph.errors import RotgraphError
    from rotgraph.io.text import atomic_write

    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise RotgraphError("--plot needs matplotlib: pip install 'rotgraph[plot]'") from None
    small = graph.n_nodes <= 300 and graph.n_edges > 0
    fig, axes = plt.subplots(1, 3 if small else 2, figsize=(15 if small else 10, 4.5))
    deg = graph.degrees()
    axes[0].hist(deg, bins=min(50, max(5, int(deg.max() - deg.min() + 1))))
    axes[0].set_xlabel("edges per camera")
    axes[0].set_ylabel("cameras")
    axes[0].set_title(f"degree ({graph.n_nodes} cameras, {graph.n_edges} edges)")
    if len(cycle_deg):
        axes[1].hist(cycle_deg, bins=60, range=(0, max(1.0, float(np.percentile(cycle_deg, 99)))))
        axes[1].set_title(f"triangle closure error, median {np.median(cycle_deg):.2f} deg")
    else:
        axes[1].set_title("no triangles")
    axes[1].set_xlabel("closure error [deg]")
    if small:
        import networkx as nx

        from rotgraph.estimators.rotation_averaging import average_rotations

        res = average_rotations(graph)
        G = nx.Graph()
        G.add_nodes_from(range(graph.n_nodes))
        G.add_edges_from(map(tuple, graph.edges.tolist()))
        pos = nx.spring_layout(G, seed=0)
        resid = np.nan_to_num(res.residuals_deg, nan=90.0)
        segs = [(pos[int(i)], pos[int(j)]) for i, j in graph.edges]
        from matplotlib.collections import LineCollection

        lc = LineCollection(segs, array=np.clip(resid, 0, 10), cmap="viridis", linewidths=0.6)
        axes[2].add_collection(lc)
        xy = np.array([pos[k] for k in range(graph.n_nodes)])
        axes[2].scatter(xy[:, 0], xy[:, 1], s=8, c="k")
        axes[2].autoscale()
        axes[2].set_axis_off()
        axes[2].set_title("edges by residual after solve [deg, clipped at 10]")
        fig.colorbar(lc, ax=axes[2])
    fig.tight_layout()
    with atomic_write(path, "wb") as fh:
        fig.savefig(fh, format="png", dpi=90)
    plt.close(fig)
