"""View graphs from edge files: :func:`read_edge_file`, and the text edge formats.

Every reader returns rotgraph's conventions (see :mod:`rotgraph`): absolute rotations are
``cam_from_world`` (world -> camera), the edge ``(i, j)`` carries ``R_ij = R_j R_i^T``
(``cam2_from_cam1`` with ``cam1 = i``), quaternions are ``(w, x, y, z)``. Each format's
own convention, and how its conversion was checked, is stated with its reader; the
numbers quoted come from the readers on the shared benchmark files (``shared/datasets``)
and are pinned by ``tests/test_io_edges.py``.

Edge formats (:func:`read_edge_file`, names as in CLI.md; told apart by :mod:`rotgraph.io.formats`)
---------------------------------------------------------------------------------------------------
``rotgraph``
    Text, one edge a line: ``i j qw qx qy qz [weight]`` (lines with and without the
    weight may mix; a missing weight is 1). The quaternion is ``R_ij = R_j R_i^T``.
    Ids are non-negative integers or names without white space: when every id of the
    file is a run of ASCII digits the ids are ``int64``, otherwise all ids are strings.
    Convention: rotgraph's own (the definition); checked by round trips through
    :func:`write_edges` of ``R_j R_i^T`` built from random ``R_i``.
    Optional per-edge information: ``i j qw qx qy qz [weight] h_xx h_xy h_xz h_yy h_yz
    h_zz`` (12 or 13 fields), the upper triangle of the edge's rotation information
    matrix ``H`` (radians^-2) in rotgraph's convention ``R_ij,measured = exp([d]x) R_ij``,
    ``d ~ N(0, H^-1)`` (``d`` in camera ``j``'s frame; see
    :class:`~rotgraph.viewgraph.ViewGraph`). The first data line decides: with 12 or 13
    fields every line must have that many, otherwise 6 or 7 as above. ``H`` goes through
    :func:`~rotgraph.graph_build.check_information` (positive definite; errors name the line).
``csv``
    A header naming the columns ``i,j,qw,qx,qy,qz`` and optionally ``weight`` (any
    order; other columns are ignored), then one edge a row. Same convention and ids as
    ``rotgraph``. Fields may be quoted CSV-style (``"a,b"``). Optional information
    columns ``info_xx,info_xy,info_xz,info_yy,info_yz,info_zz`` (as ``h_..`` of
    ``rotgraph``): all six or none (a partial set is an error at the header line).
``glomap``
    GLOMAP's relative-pose text ``IMG1 IMG2 QW QX QY QZ TX TY TZ`` (image names; the
    translation is read and ignored). The pose is ``cam2_from_cam1`` with cam1 = IMG1,
    i.e. ``R_ij`` as is. Node ids and names are the image names (always strings).
    Checked against GLOMAP's own reader and writer (``glomap/io/pose_io.cc``: ReadRelPose
    stores the four numbers after the names as ``coeffs()[(k + 3) % 4]``, i.e. w first,
    into ``ImagePair(image1, image2, cam2_from_cam1)``; WriteRelPose writes the same).
``1dsfm``
    A 1DSfM scene folder or its ``EGs.txt``: :mod:`rotgraph.io.onedsfm`.
``mat``
    Chatterjee-Govindu ``.mat``: :mod:`rotgraph.io.matlab`.
``g2o``
    3D pose graph (``VERTEX_SE3:QUAT``, ``EDGE_SE3:QUAT``): :mod:`rotgraph.io.g2o` (which
    also says how g2o's 6x6 edge information becomes rotgraph's rotation information).
binary ``rotgraph`` (``.npz`` or Parquet)
    The ``rotgraph`` format as arrays (:func:`~rotgraph.io.writers.write_edges_npz`): ``i``,
    ``j`` (integers, or strings read as the text ids are: all digits -> ``int64``), ``qw qx qy qz``, optionally ``weight`` and ``h_xx .. h_zz``
    (all six or none), one entry per edge; told by the extension (``.npz``, ``.parquet``) or
    the zip / Parquet magic, whatever ``fmt`` says (but ``mat``); ``graph.format`` is
    ``rotgraph``. Errors name the file and the edge (0-based row). 10^7 edges in ~3 s.
    A folder of Parquet parts (Dask, Spark, Arrow; :func:`~rotgraph.io.parts.parquet_parts`)
    reads as the one file its parts were cut from, in the natural order of their names;
    errors name the part and the edge's row in it (:mod:`rotgraph.io.edges_binary`).
``colmap``
    A COLMAP project folder or ``database.db``: not a file format of this module. Its
    relative poses may need estimating, so :func:`rotgraph.read_view_graph`
    (:mod:`rotgraph.pipeline.read`) reads it through :mod:`rotgraph.pipeline.colmap`.

Named columns (``columns=``, the command line's ``--columns``)
------------------------------------------------------------
A white-space (``rotgraph``) or comma-separated (``csv``) table of another layout, e.g. the
8 columns of an exported ``relative_rotations.txt`` or any table with extra columns, is
read with its columns named in order (:func:`parse_columns`): ``i j qw qx qy qz`` (needed),
``weight``, ``h_xx h_xy h_xz h_yy h_yz h_zz`` (all six or none; ``info_xx`` .. as aliases),
and ``-`` (or ``tx``, ``ty``, ``tz``) for a column to ignore, e.g.
``i,j,qw,qx,qy,qz,weight,-``. Every data line must then have that many fields; a first
data line whose quaternion, weight and information fields are none of them numbers is a
header and is skipped (a CSV header's names are then replaced by these). Same convention,
ids and checks as ``rotgraph``. Without ``columns``, a ``rotgraph`` file whose first line
has another field count, or a CSV header without the needed names, is an error that says
how to name the columns.

Compressed files: every format may be gzip, bzip2 or xz compressed (told by the magic
bytes; see :mod:`rotgraph.io.compressed`): ``edges.txt.gz`` reads as ``edges.txt``.

Common rules for the text formats: the tables are read by :mod:`rotgraph.io.tables`
(blank lines and lines whose first non-blank character is ``#`` are skipped, a ``#``
later in a line is data; fields are split on white space, ``csv`` on commas; a clean
``rotgraph`` file is streamed from disk through pyarrow's CSV parser,
:func:`~rotgraph.io.table_stream.read_table_file`, ~1 s for 10^6 edges; otherwise one
``np.loadtxt`` pass for a clean file, else the line-by-line parser that locates errors). Quaternions and 3x3 matrices go through the one check of
:mod:`rotgraph.so3` (:func:`~rotgraph.so3.check_quaternions`,
:func:`~rotgraph.so3.check_rotations`): a non-unit quaternion is accepted as a scaled
one (one warning with the count when some ``| |q| - 1 | > 1e-3``), a zero one is an
error; a 3x3 matrix must be within 1e-3 (max entry) of a rotation and is projected onto
SO(3). Every malformed input raises :class:`~rotgraph.errors.InputError` naming the file
and, when there is one, the 1-based line: wrong field count, non-numeric, NaN or infinite
field, zero quaternion, self-loop, duplicate pair (``duplicates="error"``), no edges.

The writers (:mod:`rotgraph.io.writers`), the absolute-rotation reader
(:func:`rotgraph.io.rotations.read_absolute_rotations`) and format detection
(:mod:`rotgraph.io.formats`) live in their own modules.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from ..errors import OptionError
from ..viewgraph import ViewGraph
from .compressed import reading_progress
# The binary format is its own module, the pieces every edge reader shares are graphs'; the
# names of both that this module had are names of it still.
from .edges_binary import BINARY_COLUMNS, BINARY_REQUIRED, read_binary_edges, read_parquet_part  # noqa: F401
from .formats import EDGE_FORMATS, binary_edge_format, detect_format
from .g2o import read_g2o
from .graphs import INFORMATION_CSV_COLUMNS, INFORMATION_TEXT_COLUMNS, checked_rotations, graph_from_codes, no_edges
from .matlab import read_mat
from .onedsfm import read_1dsfm
from .table_lines import first_data_line
from .table_stream import read_table_file
from .tables import read_csv_table, read_table, symmetric_from_upper
from .text import is_float, read_head, read_text

__all__ = ["BINARY_REQUIRED", "read_edge_flags", "read_parquet_part", "INFORMATION_CSV_COLUMNS", "INFORMATION_TEXT_COLUMNS", "read_edge_file",
           "parse_columns", "COLUMN_NAMES", "IGNORED_COLUMNS"]

logger = logging.getLogger(__name__)


def read_edge_file(path, fmt: str = "auto", duplicates: str = "error", columns=None, progress=None) -> ViewGraph:
    """Read a view graph (cameras and relative rotations ``R_ij = R_j R_i^T``) from an edge file.

    ``fmt`` is one of :data:`EDGE_FORMATS` but ``colmap`` (the module docstring describes
    each, with its direction convention and how it was checked); ``duplicates`` is ``error``, ``merge``
    or ``keep`` (see :class:`~rotgraph.viewgraph.ViewGraph`). Ground truth or initial
    guesses carried by the file land in ``graph.gt_cam_from_world`` ((n, 3, 3), NaN for
    cameras without); ``graph.format`` records the format read. ``columns`` (a spec such
    as ``"i,j,qw,qx,qy,qz,weight,-"`` or a sequence of names, :func:`parse_columns`) names
    the columns of a ``rotgraph`` or ``csv`` table of another layout (module docstring);
    a bad spec, or ``columns`` with another format, is an
    :class:`~rotgraph.errors.OptionError`. ``progress(stage, done, total)`` follows the
    reading of a large file (``"read"``, bytes: :mod:`rotgraph.io.compressed`). Any file
    may be gzip, bzip2 or xz compressed.

    Raises :class:`~rotgraph.errors.InputError` (naming the file and line) for any bad
    input, including a file without edges.
    """
    if fmt not in EDGE_FORMATS:
        raise OptionError(f"unknown format {fmt!r}; expected one of {', '.join(EDGE_FORMATS)}")
    if columns is not None:
        columns = parse_columns(columns)
    with reading_progress(progress):
        return _read_edge_file(Path(path), fmt, duplicates, columns)


def _read_edge_file(path: Path, fmt: str, duplicates: str, columns) -> ViewGraph:
    p, given = path, fmt
    if fmt == "auto":
        fmt = detect_format(p)
        logger.debug("%s: detected format %s", path, fmt)
    if fmt == "colmap":
        if columns is not None:
            _columns_refused(p, "colmap")
        raise OptionError(f"{path}: a COLMAP project, read by rotgraph.read_view_graph (rotgraph.pipeline.read)")
    binary = binary_edge_format(p) if fmt != "mat" else None
    if columns is not None:
        # a white-space table detected as glomap or 1dsfm (by its field count or name) is
        # one of named columns too; other formats have no columns to name
        table_fmt = fmt if given != "auto" else "rotgraph" if fmt in ("glomap", "1dsfm") and p.is_file() else fmt
        if binary is not None or table_fmt not in ("rotgraph", "csv"):
            _columns_refused(p, "binary rotgraph" if binary is not None else fmt)
        graph = _read_named_columns(p, table_fmt, columns, duplicates)
        graph.format = table_fmt
        return graph
    if binary is not None:  # the binary encoding of the rotgraph format, whatever the text sniffer said
        graph = read_binary_edges(p, binary, duplicates)
        graph.format = "rotgraph"
        return graph
    reader = {
        "rotgraph": _read_rotgraph,
        "csv": _read_csv_edges,
        "glomap": _read_glomap,
        "1dsfm": read_1dsfm,
        "mat": read_mat,
        "g2o": read_g2o,
    }[fmt]
    graph = reader(p, duplicates)
    graph.format = fmt
    return graph


_ROTGRAPH_WHAT = "i j qw qx qy qz [weight]"
_ROTGRAPH_COLUMNS = ("i", "j", "qw", "qx", "qy", "qz", "weight")


def _read_rotgraph_fast(path: Path):
    """``(table, ncol)`` of a clean ``rotgraph`` file streamed by pyarrow
    (:func:`~rotgraph.io.table_stream.read_table_file`), or None (the text parsers then read it)."""
    first = first_data_line(read_head(path))
    ncol = 0 if first is None else len(first[2].split())
    if ncol not in (6, 7, 12, 13):
        return None
    table = read_table_file(path, kinds=("id", "id") + ("f",) * (ncol - 2), names=_rotgraph_names(ncol))
    return None if table is None else (table, ncol)


def _rotgraph_names(ncol: int) -> tuple:
    return _ROTGRAPH_COLUMNS[: ncol - 6] + INFORMATION_TEXT_COLUMNS if ncol in (12, 13) else _ROTGRAPH_COLUMNS[:ncol]


def _read_rotgraph(path: Path, duplicates: str) -> ViewGraph:
    fast = _read_rotgraph_fast(path)
    if fast is not None:
        table, ncol = fast
        weights = table.cols[6] if ncol in (7, 13) else None
        information = symmetric_from_upper(table.floats(ncol - 6, ncol), 3) if ncol in (12, 13) else None
        return _rotgraph_graph(path, table, weights, information, duplicates)
    text = read_text(path)
    first = first_data_line(text)
    ncol = 0 if first is None else len(first[2].split())
    if ncol in (12, 13):  # information columns: every line as the first one
        names = _ROTGRAPH_COLUMNS[: ncol - 6] + INFORMATION_TEXT_COLUMNS
        what = f"{' '.join(names)}, as the first data line (line {first[0]}): all lines of a file have the same columns"
        table = read_table(path, text, counts=(ncol,), kinds=("id", "id") + ("f",) * (ncol - 2), names=names, what=what,
                           hint=_columns_hint)
        weights = table.cols[6] if ncol == 13 else None
        information = symmetric_from_upper(table.floats(ncol - 6, ncol), 3)
    else:
        what = f"{_ROTGRAPH_WHAT}, or 12 or 13 with {' '.join(INFORMATION_TEXT_COLUMNS)} on every line"
        table = read_table(
            path, text, counts=(6, 7), kinds=("id", "id", "f", "f", "f", "f", "f"), names=_ROTGRAPH_COLUMNS,
            what=what, defaults={6: 1.0}, hint=_columns_hint,
        )
        weights, information = table.cols[6], None
    return _rotgraph_graph(path, table, weights, information, duplicates)


def _rotgraph_graph(path, table, weights, information, duplicates) -> ViewGraph:
    if len(table) == 0:
        raise no_edges(path, _ROTGRAPH_WHAT)
    rel = checked_rotations(table.cols[2:6], path, table.lines)
    return graph_from_codes(path, table.lines, *table.index(0, 1), rel, weights, duplicates, information=information)


_CSV_REQUIRED = ("i", "j", "qw", "qx", "qy", "qz")


def _read_csv_fast(path: Path):
    """``(header, table)`` of a clean edge CSV (no quotes or blanks in the data rows, every
    column once, the information columns all or none) streamed by pyarrow, or None (the
    text parsers then)."""
    from ..errors import InputError
    from .tables import csv_header

    head = read_head(path)
    if head.startswith(b"\xef\xbb\xbf"):
        return None
    try:
        header, _, hline = csv_header(path, head.decode("utf-8"), _CSV_REQUIRED, ("weight",) + INFORMATION_CSV_COLUMNS)
    except (InputError, UnicodeDecodeError):
        return None
    if len(set(header)) != len(header) or 0 < sum(c in header for c in INFORMATION_CSV_COLUMNS) < 6:
        return None
    numeric = set(_CSV_REQUIRED[2:] + ("weight",) + INFORMATION_CSV_COLUMNS)
    kinds = tuple("id" if h in ("i", "j") else "f" if h in numeric else "skip" for h in header)
    table = read_table_file(path, kinds=kinds, names=tuple(header), sep=",", header_line=hline)
    return None if table is None or len(table) == 0 else (header, table)


def _read_csv_edges(path: Path, duplicates: str) -> ViewGraph:
    fast = _read_csv_fast(path)
    if fast is not None:
        header, table = fast
    else:
        text = read_text(path)
        header, table = read_csv_table(path, text, _CSV_REQUIRED, ("weight",) + INFORMATION_CSV_COLUMNS,
                                       kinds={"i": "id", "j": "id"}, noun="edges", all_or_none=(INFORMATION_CSV_COLUMNS,),
                                       hint=_columns_hint)
    return _named_graph(path, header, table, INFORMATION_CSV_COLUMNS, duplicates)


def _named_graph(path, header, table, information_columns, duplicates) -> ViewGraph:
    """The view graph of a table whose columns are named by ``header`` (``i j qw qx qy qz``,
    optionally ``weight`` and the six ``information_columns``; other columns ignored)."""
    col = {h: c for h, c in zip(header, table.cols) if c is not None}
    rel = checked_rotations([col[c] for c in ("qw", "qx", "qy", "qz")], path, table.lines)
    information = None
    if information_columns[0] in col:
        information = symmetric_from_upper(np.stack([col[c] for c in information_columns], axis=1), 3)
    index = table.index(header.index("i"), header.index("j"))
    return graph_from_codes(path, table.lines, *index, rel, col.get("weight"), duplicates, information=information)


#: The names ``columns=`` (``--columns``) gives the columns of an edge table: the ``rotgraph``
#: format's, ``-`` for a column to ignore, and ``tx ty tz`` (a translation, ignored).
COLUMN_NAMES = _ROTGRAPH_COLUMNS + INFORMATION_TEXT_COLUMNS
IGNORED_COLUMNS = ("-", "tx", "ty", "tz")
_COLUMN_ALIASES = dict(zip(INFORMATION_CSV_COLUMNS, INFORMATION_TEXT_COLUMNS))


def parse_columns(spec) -> tuple[str, ...]:
    """The column names of ``spec``: a comma-separated string (``"i,j,qw,qx,qy,qz,weight,-"``,
    the command line's ``--columns``) or a sequence of names, one per column of the table
    in order. Names (case-insensitive): :data:`COLUMN_NAMES` (``i j qw qx qy qz`` needed,
    each at most once; ``h_xx .. h_zz`` all six or none, ``info_xx ..`` the same) and
    :data:`IGNORED_COLUMNS` (any number of times). A bad spec is an
    :class:`~rotgraph.errors.OptionError`."""
    names = spec.split(",") if isinstance(spec, str) else list(spec)
    out: list[str] = []
    for raw in names:
        name = str(raw).strip().lower()
        name = _COLUMN_ALIASES.get(name, name)
        if name not in COLUMN_NAMES + IGNORED_COLUMNS:
            raise OptionError(f"--columns: unknown column name {str(raw).strip()!r}; expected {', '.join(COLUMN_NAMES)}, "
                              "or - (also tx, ty, tz) for a column to ignore, e.g. --columns i,j,qw,qx,qy,qz,weight,-")
        if name in out and name not in IGNORED_COLUMNS:
            raise OptionError(f"--columns: {name} is named twice")
        out.append(name)
    missing = [c for c in _ROTGRAPH_COLUMNS[:6] if c not in out]
    if missing:
        raise OptionError(f"--columns: no {', '.join(missing)} column (i, j, qw, qx, qy, qz are needed), got {','.join(out)}")
    info = [c for c in INFORMATION_TEXT_COLUMNS if c in out]
    if info and len(info) < 6:
        raise OptionError(f"--columns: {', '.join(info)} without the others of {' '.join(INFORMATION_TEXT_COLUMNS)} "
                          "(all six or none)")
    return tuple(out)


def _columns_refused(path, fmt: str):
    raise OptionError(f"--columns names the columns of a text table (formats rotgraph and csv); {path} is {fmt}")


def _columns_hint(nfields: int) -> str:
    """The advice of a wrong field count: name the columns with ``--columns``."""
    if nfields > 6:
        return f" (name the columns with --columns, e.g. --columns i,j,qw,qx,qy,qz{',-' * (nfields - 6)})"
    return " (a table of other columns: name them with --columns)"


def _read_named_columns(path: Path, fmt: str, columns: tuple, duplicates: str) -> ViewGraph:
    """A ``rotgraph`` (white space) or ``csv`` table of the named ``columns`` (module docstring)."""
    sep = "," if fmt == "csv" else None
    kinds = tuple("id" if c in ("i", "j") else "skip" if c in IGNORED_COLUMNS else "f" for c in columns)
    what = f"{' '.join(columns)}, as named by --columns"
    split = (lambda t: t.split()) if sep is None else (lambda t: t.split(sep))
    first = first_data_line(read_head(path).decode("utf-8-sig", errors="replace"))
    header = None  # the number of a header line: no quaternion, weight or information field is a number
    if first is not None:
        fields = split(first[2])
        if not any(is_float(fields[k]) for k, kind in enumerate(kinds) if kind == "f" and k < len(fields)):
            header = first[0]
    table = read_table_file(path, kinds=kinds, names=columns, sep=sep, header_line=header)
    if table is None:
        text = read_text(path)
        start = 0
        if header is not None:
            _, end, _ = first_data_line(text)
            start = min(end + 1, len(text))
        table = read_table(path, text, counts=(len(columns),), kinds=kinds, names=columns, what=what, sep=sep, start=start)
    if len(table) == 0:
        raise no_edges(path, what)
    return _named_graph(path, list(columns), table, INFORMATION_TEXT_COLUMNS, duplicates)


_GLOMAP_WHAT = "IMG1 IMG2 QW QX QY QZ TX TY TZ"


def _read_glomap(path: Path, duplicates: str) -> ViewGraph:
    text = read_text(path)
    table = read_table(
        path, text, counts=(9,), kinds=("name", "name", "f", "f", "f", "f", "u", "u", "u"),
        names=("IMG1", "IMG2", "QW", "QX", "QY", "QZ", "TX", "TY", "TZ"), what=_GLOMAP_WHAT,
    )
    if len(table) == 0:
        raise no_edges(path, _GLOMAP_WHAT)
    rel = checked_rotations(table.cols[2:6], path, table.lines)
    names, codes_i, codes_j = table.index(0, 1)
    return graph_from_codes(path, table.lines, names, codes_i, codes_j, rel, None, duplicates, names=names)


def read_edge_flags(path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, np.ndarray]:
    """Read the ``--edges-out`` CSV of ``rotgraph solve`` (``i,j,residual_deg,inlier[,...]``):
    ``(ids_i, ids_j, inlier (bool), weight or None, lines)``, one row an edge in the file's
    order. ``inlier`` must be 0 or 1 (``FILE:LINE`` error otherwise); ``weight`` (the
    solve's final-iteration weights; ``nan`` for edges outside the solve) when the file has the column."""
    from ..errors import InputError

    path = Path(path)
    header, table = read_csv_table(path, read_text(path), ("i", "j", "inlier"), ("residual_deg",),
                                   kinds={"i": "id", "j": "id", "residual_deg": "u", "weight": "u"}, noun="edges")
    col = dict(zip(header, table.cols))
    flag = np.asarray(col["inlier"], dtype=np.float64)
    bad = (flag != 0) & (flag != 1)
    if bad.any():
        k = int(np.argmax(bad))
        raise InputError(f"inlier must be 0 or 1, got {flag[k]:g}", str(path), int(table.lines[k]))
    weight = None if col.get("weight") is None else np.asarray(col["weight"], dtype=np.float64)
    return np.asarray(col["i"]), np.asarray(col["j"]), flag == 1, weight, np.asarray(table.lines)
