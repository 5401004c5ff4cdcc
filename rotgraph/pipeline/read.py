"""Any input to a :class:`~rotgraph.viewgraph.ViewGraph`: the one dispatch on the input format.

Edge files (``rotgraph``, ``csv``, ``glomap``, ``1dsfm``, ``mat``, ``g2o``) are read by
:mod:`rotgraph.io`; a COLMAP project by :mod:`rotgraph.pipeline.colmap`, which estimates
the relative poses its database does not store.
"""

from __future__ import annotations

from pathlib import Path

from ..choices import DUPLICATE_POLICIES, EDGE_FORMATS
from ..errors import OptionError
from ..io.edges import read_edge_file
from ..io.formats import detect_format
from ..viewgraph import ViewGraph

__all__ = ["read_view_graph", "default_duplicates", "DUPLICATES_BY_FORMAT"]

#: The duplicates policy of ``duplicates=None`` (what the command line passes when the user
#: does not set ``--duplicates``), by input format; "error" for the formats not listed.
#: g2o: parallel edges are normal in pose graphs (cubicle.g2o: 16,869 edges over 12,486
#: pairs), each one more measurement, so they are kept.
DUPLICATES_BY_FORMAT: dict[str, str] = {"g2o": "keep"}


def default_duplicates(fmt: str) -> str:
    """The duplicates policy ``read_view_graph(..., duplicates=None)`` uses for format ``fmt``
    (after detection): :data:`DUPLICATES_BY_FORMAT`, else ``"error"``."""
    return DUPLICATES_BY_FORMAT.get(fmt, "error")


def read_view_graph(path, fmt: str = "auto", duplicates: str | None = "error", progress=None, uncertainty: bool = True,
                    columns=None) -> ViewGraph:
    """Read a view graph (cameras and relative rotations ``R_ij = R_j R_i^T``) from any input.

    ``fmt`` is one of :data:`~rotgraph.choices.EDGE_FORMATS` (``auto`` detects it; each
    format and its direction convention: :mod:`rotgraph.io.edges`, COLMAP:
    :mod:`rotgraph.io.colmap`); ``duplicates`` is ``error``, ``merge`` or ``keep`` (see
    :class:`~rotgraph.viewgraph.ViewGraph`; COLMAP pairs are unique), or None for the
    format's default (:func:`default_duplicates`: ``keep`` for g2o, ``error`` otherwise).
    Ground truth carried by the input lands in ``graph.gt_cam_from_world`` ((n, 3, 3),
    NaN for cameras without), an initial guess (g2o vertices) in
    ``graph.initial_cam_from_world``; ``graph.format`` records the format read. ``progress(stage, done, total)``
    follows the stages that count work (COLMAP relative-pose estimation; ``"read"``, the
    bytes of a large edge file read so far, :mod:`rotgraph.io.compressed`). ``columns``
    names the columns of a ``rotgraph`` or ``csv`` table of another layout, e.g.
    ``"i,j,qw,qx,qy,qz,weight,-"`` (:func:`~rotgraph.io.edges.parse_columns`; a bad spec or
    another format is an :class:`~rotgraph.errors.OptionError`). Edge files may be gzip,
    bzip2 or xz compressed. ``uncertainty``:
    a COLMAP project's pairs get their rotation information matrices from their inlier
    matches (:func:`~rotgraph.pipeline.colmap.read_colmap_project`, on at most
    :data:`~rotgraph.pipeline.colmap.UNCERTAINTY_SAMPLE` of them per pair); other formats
    carry theirs in the file or none.

    Raises :class:`~rotgraph.errors.InputError` (naming the file and line) for any bad
    input, including one without edges.

    Parameters
    ----------
    path : str or os.PathLike
        An edge file (possibly compressed), a folder of Parquet parts (Dask, Spark, Arrow), a 1DSfM
        scene folder or a COLMAP project.
    fmt : str, default "auto"
        One of :data:`~rotgraph.choices.EDGE_FORMATS`; ``auto`` detects it.
    duplicates : {"error", "merge", "keep"} or None, default "error"
        Several edges between one pair of cameras; None: the format's default.
    progress : callable, optional
        ``progress(stage, done, total)`` of the stages that count work.
    uncertainty : bool, default True
        A COLMAP project's pairs get rotation information matrices from their inlier matches.
    columns : str or sequence of str, optional
        The columns of a ``rotgraph`` or ``csv`` table of another layout.

    Returns
    -------
    ViewGraph
        ``n`` cameras and ``E`` edges; ``cam2_from_cam1`` (E, 3, 3) float64 holds
        ``R_ij = R_j R_i^T`` for edge ``(i, j)``; ground truth, when the input has it, in
        ``gt_cam_from_world`` (n, 3, 3) (world-to-camera).

    Raises
    ------
    OptionError
        An unknown ``fmt`` or ``duplicates``, or ``columns`` with another format (also a
        ``ValueError``).
    InputError
        Bad input (also a ``ValueError``).
    """
    if fmt not in EDGE_FORMATS:
        raise OptionError(f"unknown format {fmt!r}; expected one of {', '.join(EDGE_FORMATS)}")
    if duplicates is not None and duplicates not in DUPLICATE_POLICIES:
        raise OptionError(f"duplicates must be one of {', '.join(DUPLICATE_POLICIES)} or None, got {duplicates!r}")
    given = fmt
    if fmt == "auto":
        fmt = detect_format(Path(path))
    if duplicates is None:
        duplicates = default_duplicates(fmt)
    if fmt == "colmap" and columns is not None:
        raise OptionError(f"--columns names the columns of a text table (formats rotgraph and csv); {path} is a COLMAP project")
    if fmt == "colmap":
        from .colmap import read_colmap_project

        from .colmap import UNCERTAINTY_SAMPLE

        return read_colmap_project(path, progress=progress, uncertainty=uncertainty, uncertainty_sample=UNCERTAINTY_SAMPLE)
    # with columns, read_edge_file decides from the format as given (a white-space table may be detected as glomap)
    return read_edge_file(path, fmt if columns is None else given, duplicates, columns=columns, progress=progress)
