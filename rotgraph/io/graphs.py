"""What every edge reader shares: the information columns' names, the check of the
quaternion columns, and building the :class:`~rotgraph.viewgraph.ViewGraph` from parsed tables.

Every edge reader (:mod:`~rotgraph.io.edges`, :mod:`~rotgraph.io.onedsfm`,
:mod:`~rotgraph.io.g2o`) hands its edges over as integer codes (positions in the sorted
distinct ids, see :meth:`rotgraph.io.table_columns.Table.index`), which is fast for any kind of id,
and its "no edges" errors are worded here once.
"""

from __future__ import annotations

from .. import so3_checks
from ..errors import InputError
from ..graph_build import QuaternionRotations, check_information
from ..viewgraph import ViewGraph

__all__ = ["INFORMATION_CSV_COLUMNS", "INFORMATION_TEXT_COLUMNS", "checked_rotations", "graph_from_codes", "no_edges"]

#: The information columns of the ``rotgraph`` and ``csv`` edge formats: the upper triangle
#: of ``H`` (radians^-2), row-major.
INFORMATION_TEXT_COLUMNS = ("h_xx", "h_xy", "h_xz", "h_yy", "h_yz", "h_zz")
INFORMATION_CSV_COLUMNS = ("info_xx", "info_xy", "info_xz", "info_yy", "info_yz", "info_zz")


def checked_rotations(cols, path, lines=None, label=None) -> QuaternionRotations:
    """Relative rotations of the quaternion columns ``cols`` (qw, qx, qy, qz), checked and
    normalised by :func:`~rotgraph.so3.check_quaternion_rows` (block by block):
    :class:`~rotgraph.graph_build.QuaternionRotations`, whose (E, 3, 3) matrices are made
    only if someone asks for them (the solver takes the quaternions)."""
    return QuaternionRotations(so3_checks.check_quaternion_rows(cols, path=path, lines=lines, label=label))


def no_edges(path, what: str, line=None) -> InputError:
    """The error for an input without edges; ``what`` describes an edge line."""
    return InputError(f"no edges (expected lines '{what}')", str(path), line)


def graph_from_codes(path, lines, node_ids, codes_i, codes_j, rel, weights, duplicates, names=None,
                     information=None, information_not_used=None) -> ViewGraph:
    """ViewGraph.from_edges on integer codes (``codes=True``: positions in the sorted
    ``node_ids``): fast for any kind of id (sorting and searching 10^6 strings is slow);
    its messages name the cameras.

    ``information`` (E, 3, 3) or None: per-edge rotation information matrices, checked by
    :func:`~rotgraph.graph_build.check_information` (the first bad one names its line), then
    merged or kept with their edges by ``duplicates``. With ``information_not_used`` a
    failed check is handed to it (the :class:`InputError`) and the graph has none.

    ``rel``: (E, 3, 3) matrices, or :class:`~rotgraph.graph_build.QuaternionRotations` (unit
    quaternions, already checked): the graph keeps them (see ``from_edges``' fast path)."""
    if information is not None and information_not_used is not None:
        # g2o: information that fails its check is dropped, not an error (from_edges checks
        # the rest; the graph is built once, its duplicates resolved once)
        try:
            check_information(information, len(codes_i), str(path), lines)
        except InputError as exc:
            information_not_used(exc)
            information = None
    return ViewGraph.from_edges(codes_i, codes_j, rel, weights, node_ids=node_ids, codes=True, names=names,
                                duplicates=duplicates, source_lines=lines, source_path=str(path), information=information)
