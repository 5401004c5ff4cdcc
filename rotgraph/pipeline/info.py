"""``rotgraph info``: a view graph's summary (cameras, edges, components, degrees, cycle
consistency) and the data of its ``--plot``.

The figure itself is drawn by the command line (matplotlib); this module reads the input,
computes what the summary prints and what the figure shows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..viewgraph import ViewGraph

__all__ = ["ViewGraphInfo", "view_graph_info", "PLOT_GRAPH_MAX_CAMERAS"]

#: Up to this many cameras the ``--plot`` figure also shows the view graph, its edges
#: coloured by their residual after a default solve.
PLOT_GRAPH_MAX_CAMERAS = 300


@dataclass(frozen=True)
class ViewGraphInfo:
    """The outcome of :func:`view_graph_info`.

    Attributes
    ----------
    graph : the view graph read.
    summary : what ``rotgraph info --json`` prints: :meth:`~rotgraph.viewgraph.ViewGraph.summary`,
        :func:`~rotgraph.graph_analysis.cycle_statistics`, ``n_ground_truth`` and
        ``n_initial_guess`` (cameras with a ground-truth rotation, with an initial guess).
    cycle_errors_deg : (T,) closure errors of the triangles checked, degrees.
    edge_residuals_deg : (E,) each edge's residual after a default solve, degrees (NaN for
        edges left out), when a plot was asked for and the graph has at most
        :data:`PLOT_GRAPH_MAX_CAMERAS` cameras and an edge; else None.
    """

    graph: ViewGraph
    summary: dict
    cycle_errors_deg: np.ndarray
    edge_residuals_deg: np.ndarray | None = None


def view_graph_info(path, fmt: str = "auto", duplicates: str | None = None, columns=None, *, plot=None,
                    overwrite: bool = False) -> ViewGraphInfo:
    """Read the view graph of ``path`` and summarise it.

    Parameters
    ----------
    path : any input :func:`~rotgraph.pipeline.read.read_view_graph` reads (a COLMAP
        project's rotation information is not computed: nothing is solved with it).
    fmt, duplicates, columns : as for :func:`~rotgraph.pipeline.read.read_view_graph`.
    plot : the file the caller will draw the figure into, or None: checked as an output
        before the input is read (:func:`~rotgraph.io.outputs.check_outputs`); with it, small
        graphs are solved for the edges' residuals (``edge_residuals_deg``).
    overwrite : the plot may replace a file that is not rotgraph's own output.

    Returns
    -------
    ViewGraphInfo
    """
    from ..estimators.rotation_averaging import average_rotations
    from ..io.outputs import check_outputs
    from ..graph_analysis import cycle_errors, cycle_statistics
    from .read import read_view_graph

    if plot:
        check_outputs([plot], [path], overwrite=overwrite)
    graph = read_view_graph(path, fmt=fmt, duplicates=duplicates, uncertainty=False, columns=columns)
    s = graph.summary()
    cyc = np.degrees(cycle_errors(graph))
    s.update(cycle_statistics(cyc))
    # Ground truth and an initial guess (g2o vertices: odometry) are told apart.
    for key, rows in (("n_ground_truth", graph.gt_cam_from_world), ("n_initial_guess", graph.initial_cam_from_world)):
        s[key] = int(np.isfinite(rows).all(axis=(1, 2)).sum()) if rows is not None else 0
    residuals = None
    if plot and graph.n_nodes <= PLOT_GRAPH_MAX_CAMERAS and graph.n_edges > 0:
        residuals = average_rotations(graph).residuals_deg
    return ViewGraphInfo(graph=graph, summary=s, cycle_errors_deg=cyc, edge_residuals_deg=residuals)
