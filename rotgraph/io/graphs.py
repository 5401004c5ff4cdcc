"""Building the :class:`~rotgraph.viewgraph.ViewGraph` of an edge reader from parsed tables.

Every edge reader (:mod:`~rotgraph.io.edges`, :mod:`~rotgraph.io.onedsfm`,
:mod:`~rotgraph.io.g2o`) hands its edges over as integer codes (positions in the sorted
distinct ids, see :meth:`rotgraph.io.tables.Table.index`), which is fast for any kind of id,
and its "no edges" errors are worded here once.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..viewgraph import ViewGraph

__all__ = ["graph_from_codes", "no_edges"]


def no_edges(path, what: str, line=None) -> InputError:
    """The error for an input without edges; ``what`` describes an edge line."""
    return InputError(f"no edges (expected lines '{what}')", str(path), line)


def graph_from_codes(path, lines, node_ids, codes_i, codes_j, rel, weights, duplicates, names=None) -> ViewGraph:
    """ViewGraph.from_edges on integer codes (positions in the sorted ``node_ids``): fast
    for any kind of id (sorting and searching 10^6 strings is slow). On an error the call
    is repeated with the real ids, so that the message names the cameras."""
    args = dict(names=names, duplicates=duplicates, source_lines=lines, source_path=str(path))
    try:
        graph = ViewGraph.from_edges(codes_i, codes_j, rel, weights, node_ids=np.arange(len(node_ids)), **args)
    except InputError:
        return ViewGraph.from_edges(node_ids[codes_i], node_ids[codes_j], rel, weights, node_ids=node_ids, **args)
    graph.node_ids = node_ids
    return graph
