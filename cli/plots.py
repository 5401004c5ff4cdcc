"""The figures of ``rotgraph eval --plot`` and ``rotgraph info --plot`` (matplotlib)."""

from __future__ import annotations

from pathlib import Path

import click

from rotgraph.errors import InputError, RotgraphError

#: --plot formats, told by the file extension.
PLOT_FORMATS = ("png", "pdf", "svg")


def check_plot_path(path: str) -> str:
    """The plot format of ``path`` (its extension); an error naming the file otherwise."""
    fmt = Path(path).suffix.lower().lstrip(".")
    if fmt not in PLOT_FORMATS:
        raise InputError(f"--plot writes {', '.join('.' + f for f in PLOT_FORMATS)} (told by the extension), not {Path(path).suffix or 'a file without one'}", path=str(path))
    return fmt


def _pyplot():
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise RotgraphError("--plot needs matplotlib: pip install 'rotgraph[plot]'") from None
    return plt


def save_figure(fig, path: str, dpi: int) -> None:
    """Write ``fig`` in the format of ``path``'s extension, atomically, and say so on stderr."""
    import matplotlib.pyplot as plt

    from rotgraph.io.atomic import atomic_write
    from rotgraph.io.outputs import PLOT_CREATOR

    fmt = check_plot_path(path)
    meta = {"Software": PLOT_CREATOR} if fmt == "png" else {"Creator": PLOT_CREATOR}  # whose file it is (io.text)
    with atomic_write(path, "wb") as fh:
        fig.savefig(fh, format=fmt, dpi=dpi, metadata=meta)
    plt.close(fig)
    click.echo(f"rotgraph: plot ({fmt}) -> {path}", err=True)


def plot_errors(errors_deg, path: str) -> None:
    import numpy as np

    plt = _pyplot()
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
    save_figure(fig, path, dpi=100)


def plot_info(about, path: str) -> None:
    """Degree and cycle-error histograms of a :class:`~rotgraph.pipeline.info.ViewGraphInfo`;
    for small graphs (those it has residuals for) also the view graph with edges coloured by
    their residual after a default solve."""
    import numpy as np

    plt = _pyplot()
    graph, cycle_deg = about.graph, about.cycle_errors_deg
    small = about.edge_residuals_deg is not None
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

        G = nx.Graph()
        G.add_nodes_from(range(graph.n_nodes))
        G.add_edges_from(map(tuple, graph.edges.tolist()))
        pos = nx.spring_layout(G, seed=0)
        resid = np.nan_to_num(about.edge_residuals_deg, nan=90.0)
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
    save_figure(fig, path, dpi=90)
