"""Building the :class:`~rotgraph.viewgraph.ViewGraph` of an edge reader from parsed tables.

Every edge reader (:mod:`~rotgraph.io.edges`, :mod:`~rotgraph.io.onedsfm`,
:mod:`~rotgraph.io.g2o`) hands its edges over as integer codes (positions in the sorted
distinct ids, see :meth:`rotgraph.io.tables.Table.index`), which is fast for any kind of id,
and its "no edges" errors are worded here once.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..viewgraph import QuaternionRotations, ViewGraph, check_information

__all__ = ["graph_from_codes", "no_edges"]


def no_edges(path, what: str, line=None) -> InputError:
    """The error for an input without edges; ``what`` describes an edge line."""
    return InputError(f"no edges (expected lines '{what}')", str(path), line)


def graph_from_codes(path, lines, node_ids, codes_i, codes_j, rel, weights, duplicates, names=None,
                     information=None, information_not_used=None) -> ViewGraph:
    """ViewGraph.from_edges on integer codes (positions in the sorted ``node_ids``): fast
    for any kind of id (sorting and searching 10^6 strings is slow). On an error the call
    is repeated with the real ids, so that the message names the cameras.

    ``information`` (E, 3, 3) or None: per-edge rotation information matrices, checked by
    :func:`~rotgraph.viewgraph.check_information` (the first bad one names its line), then
    merged or kept with their edges by ``duplicates``. With ``information_not_used`` a
    failed check is handed to it (the :class:`InputError`) and the graph has none.

    ``rel``: (E, 3, 3) matrices, or :class:`~rotgraph.viewgraph.QuaternionRotations` (unit
    quaternions, already checked: rotations exact to rounding): then a clean input (positive
    weights, no self-loop, no repeated pair) skips ``from_edges``' id search and checks
    (10^7 edges: ~1 s instead of ~12 s) and the graph keeps the quaternions."""
    if information is None:
        return _graph_from_codes(path, lines, node_ids, codes_i, codes_j, rel, weights, duplicates, names)
    # Built with every edge kept, so that information lines up with the input's edges; the
    # duplicate policy then runs once, information included (from_edges' order of checks).
    graph = _graph_from_codes(path, lines, node_ids, codes_i, codes_j, rel, weights, "keep", names)
    try:
        graph.information = check_information(information, graph.n_edges, str(path), graph.source_lines)
    except InputError as exc:
        if information_not_used is None:
            raise
        information_not_used(exc)
    return graph._resolve_duplicates(duplicates)


def _graph_from_codes(path, lines, node_ids, codes_i, codes_j, rel, weights, duplicates, names) -> ViewGraph:
    args = dict(names=names, duplicates=duplicates, source_lines=lines, source_path=str(path))
    if isinstance(rel, QuaternionRotations):
        graph = _clean_graph(path, lines, node_ids, codes_i, codes_j, rel, weights, names)
        if graph is not None:
            return graph
        rel = rel.matrices()  # from_edges checks (and may merge) matrices
    try:
        graph = ViewGraph.from_edges(codes_i, codes_j, rel, weights, node_ids=np.arange(len(node_ids)), **args)
    except InputError:
        return ViewGraph.from_edges(node_ids[codes_i], node_ids[codes_j], rel, weights, node_ids=node_ids, **args)
    graph.node_ids = node_ids
    return graph


def _clean_graph(path, lines, node_ids, codes_i, codes_j, rel, weights, names) -> ViewGraph | None:
    """The graph ``ViewGraph.from_edges`` builds from codes (positions in the sorted
    ``node_ids``) and the quaternions ``rel``, when the input is clean: weights positive and
    finite, no self-loop, no pair twice (either direction); else None (``from_edges`` then
    runs and reports)."""
    m, n = len(codes_i), len(node_ids)
    w = np.ones(m) if weights is None else np.asarray(weights, dtype=np.float64)
    if m == 0 or w.shape != (m,) or rel.shape != (m, 3, 3) or not (np.isfinite(w) & (w > 0)).all():
        return None
    edges = np.stack([codes_i, codes_j], axis=1).astype(np.int64)
    if (edges[:, 0] == edges[:, 1]).any() or edges.min() < 0 or edges.max() >= n:
        return None
    key = np.minimum(edges[:, 0], edges[:, 1]) * n + np.maximum(edges[:, 0], edges[:, 1])
    key.sort()
    if (key[1:] == key[:-1]).any():
        return None
    del key
    lines = None if lines is None else np.asarray(lines)
    return ViewGraph(np.asarray(node_ids), edges, rel, w, None if names is None else np.asarray(names), lines, str(path))
