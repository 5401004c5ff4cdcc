"""Any input to a :class:`~rotgraph.viewgraph.ViewGraph`: the one dispatch on the input format.

Edge files (``rotgraph``, ``csv``, ``glomap``, ``1dsfm``, ``mat``, ``g2o``) are read by
:mod:`rotgraph.io`; a COLMAP project by :mod:`rotgraph.pipeline.colmap`, which estimates
the relative poses its database does not store.
"""

from __future__ import annotations

from pathlib import Path

from ..choices import EDGE_FORMATS
from ..io.edges import read_edge_file
from ..io.formats import detect_format
from ..viewgraph import ViewGraph

__all__ = ["read_view_graph"]


def read_view_graph(path, fmt: str = "auto", duplicates: str = "error", progress=None) -> ViewGraph:
    """Read a view graph (cameras and relative rotations ``R_ij = R_j R_i^T``) from any input.

    ``fmt`` is one of :data:`~rotgraph.choices.EDGE_FORMATS` (``auto`` detects it; each
    format and its direction convention: :mod:`rotgraph.io.edges`, COLMAP:
    :mod:`rotgraph.io.colmap`); ``duplicates`` is ``error``, ``merge`` or ``keep`` (see
    :class:`~rotgraph.viewgraph.ViewGraph`; COLMAP pairs are unique). Ground truth carried
    by the input lands in ``graph.gt_cam_from_world`` ((n, 3, 3), NaN for cameras
    without); ``graph.format`` records the format read. ``progress(stage, done, total)``
    follows the stages that count work (COLMAP relative-pose estimation).

    Raises :class:`~rotgraph.errors.InputError` (naming the file and line) for any bad
    input, including one without edges.
    """
    if fmt not in EDGE_FORMATS:
        raise ValueError(f"unknown format {fmt!r}; expected one of {', '.join(EDGE_FORMATS)}")
    if fmt == "auto":
        fmt = detect_format(Path(path))
    if fmt == "colmap":
        from .colmap import read_colmap_project

        return read_colmap_project(path, progress=progress)
    return read_edge_file(path, fmt, duplicates)
