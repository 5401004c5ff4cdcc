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
    :func:`~rotgraph.viewgraph.check_information` (positive definite; errors name the line).
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
``colmap``
    A COLMAP project folder or ``database.db``: not a file format of this module. Its
    relative poses may need estimating, so :func:`rotgraph.read_view_graph`
    (:mod:`rotgraph.pipeline.read`) reads it through :mod:`rotgraph.pipeline.colmap`.

Common rules for the text formats: the tables are read by :mod:`rotgraph.io.tables`
(blank lines and lines whose first non-blank character is ``#`` are skipped, a ``#``
later in a line is data; fields are split on white space, ``csv`` on commas; a clean
``rotgraph`` file is streamed from disk through pyarrow's CSV parser,
:func:`~rotgraph.io.tables.read_table_file`, ~1 s for 10^6 edges; otherwise one
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
import zipfile
from pathlib import Path

import numpy as np

from .. import so3
from ..viewgraph import QuaternionRotations, ViewGraph
from .formats import EDGE_FORMATS, binary_edge_format, detect_format
from .g2o import read_g2o
from .graphs import graph_from_codes, no_edges
from .matlab import read_mat
from .onedsfm import read_1dsfm
from .tables import first_data_line, read_csv_table, read_table, read_table_file, resolve_ids, symmetric_from_upper, unique
from .text import read_head, read_text

__all__ = ["BINARY_REQUIRED", "read_edge_flags", "INFORMATION_CSV_COLUMNS", "INFORMATION_TEXT_COLUMNS", "read_edge_file"]

#: The information columns of the ``rotgraph`` and ``csv`` edge formats: the upper triangle
#: of ``H`` (radians^-2), row-major.
INFORMATION_TEXT_COLUMNS = ("h_xx", "h_xy", "h_xz", "h_yy", "h_yz", "h_zz")
INFORMATION_CSV_COLUMNS = ("info_xx", "info_xy", "info_xz", "info_yy", "info_yz", "info_zz")
#: The arrays of the binary edge format (:func:`rotgraph.io.writers.write_edges_npz`).
BINARY_COLUMNS = ("i", "j", "qw", "qx", "qy", "qz", "weight") + INFORMATION_TEXT_COLUMNS

logger = logging.getLogger(__name__)


def read_edge_file(path, fmt: str = "auto", duplicates: str = "error") -> ViewGraph:
    """Read a view graph (cameras and relative rotations ``R_ij = R_j R_i^T``) from an edge file.

    ``fmt`` is one of :data:`EDGE_FORMATS` but ``colmap`` (the module docstring describes
    each, with its direction convention and how it was checked); ``duplicates`` is ``error``, ``merge``
    or ``keep`` (see :class:`~rotgraph.viewgraph.ViewGraph`). Ground truth or initial
    guesses carried by the file land in ``graph.gt_cam_from_world`` ((n, 3, 3), NaN for
    cameras without); ``graph.format`` records the format read.

    Raises :class:`~rotgraph.errors.InputError` (naming the file and line) for any bad
    input, including a file without edges.
    """
    if fmt not in EDGE_FORMATS:
        raise ValueError(f"unknown format {fmt!r}; expected one of {', '.join(EDGE_FORMATS)}")
    p = Path(path)
    if fmt == "auto":
        fmt = detect_format(p)
        logger.debug("%s: detected format %s", path, fmt)
    if fmt == "colmap":
        raise ValueError(f"{path}: a COLMAP project, read by rotgraph.read_view_graph (rotgraph.pipeline.read)")
    binary = binary_edge_format(p) if fmt != "mat" else None
    if binary is not None:  # the binary encoding of the rotgraph format, whatever the text sniffer said
        graph = _read_binary(p, binary, duplicates)
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
    (:func:`~rotgraph.io.tables.read_table_file`), or None (the text parsers then read it)."""
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
        table = read_table(path, text, counts=(ncol,), kinds=("id", "id") + ("f",) * (ncol - 2), names=names, what=what)
        weights = table.cols[6] if ncol == 13 else None
        information = symmetric_from_upper(table.floats(ncol - 6, ncol), 3)
    else:
        what = f"{_ROTGRAPH_WHAT}, or 12 or 13 with {' '.join(INFORMATION_TEXT_COLUMNS)} on every line"
        table = read_table(
            path, text, counts=(6, 7), kinds=("id", "id", "f", "f", "f", "f", "f"), names=_ROTGRAPH_COLUMNS,
            what=what, defaults={6: 1.0},
        )
        weights, information = table.cols[6], None
    return _rotgraph_graph(path, table, weights, information, duplicates)


def _rotgraph_graph(path, table, weights, information, duplicates) -> ViewGraph:
    if len(table) == 0:
        raise no_edges(path, _ROTGRAPH_WHAT)
    rel = _rotations(table.cols[2:6], path, table.lines)
    return graph_from_codes(path, table.lines, *table.index(0, 1), rel, weights, duplicates, information=information)


def _rotations(cols, path, lines=None, label=None) -> QuaternionRotations:
    """Relative rotations of the quaternion columns ``cols`` (qw, qx, qy, qz), checked and
    normalised by :func:`~rotgraph.so3.check_quaternion_rows` (block by block):
    :class:`~rotgraph.viewgraph.QuaternionRotations`, whose (E, 3, 3) matrices are made
    only if someone asks for them (the solver takes the quaternions)."""
    return QuaternionRotations(so3.check_quaternion_rows(cols, path=path, lines=lines, label=label))


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
                                       kinds={"i": "id", "j": "id"}, noun="edges", all_or_none=(INFORMATION_CSV_COLUMNS,))
    col = dict(zip(header, table.cols))
    rel = _rotations([col[c] for c in ("qw", "qx", "qy", "qz")], path, table.lines)
    information = None
    if INFORMATION_CSV_COLUMNS[0] in col:
        information = symmetric_from_upper(np.stack([col[c] for c in INFORMATION_CSV_COLUMNS], axis=1), 3)
    index = table.index(header.index("i"), header.index("j"))
    return graph_from_codes(path, table.lines, *index, rel, col.get("weight"), duplicates, information=information)


#: The arrays every binary edge file has (then optionally ``weight`` and ``h_xx .. h_zz``).
BINARY_REQUIRED = ("i", "j", "qw", "qx", "qy", "qz")


def _read_binary(path: Path, kind: str, duplicates: str) -> ViewGraph:
    """The binary edge format: arrays (npz) or columns (Parquet) ``i j qw qx qy qz`` and
    optionally ``weight`` and ``h_xx h_xy h_xz h_yy h_yz h_zz`` (all six or none), one entry
    per edge; ids integers or strings. Errors name the file and the edge (0-based row)."""
    from ..errors import InputError

    try:
        if kind == "npz":
            with np.load(path, allow_pickle=False) as z:
                names = list(z.files)
                cols = {c: z[c] for c in names if c in BINARY_COLUMNS}
        else:
            import pyarrow.parquet as pq

            tbl = pq.read_table(path)
            names = tbl.column_names
            cols = {c: tbl.column(c).to_numpy() for c in names if c in BINARY_COLUMNS}
            del tbl
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile) as exc:
        raise InputError(f"cannot read the binary edge file ({kind}): {exc}", str(path)) from None
    missing = [c for c in BINARY_REQUIRED if c not in cols]
    if missing:
        raise InputError(f"binary edge file lacks array(s) {', '.join(missing)} (has {', '.join(names)[:200]}; "
                         f"expected {' '.join(BINARY_REQUIRED)} [weight] [{' '.join(INFORMATION_TEXT_COLUMNS)}])", str(path))
    info_given = [c for c in INFORMATION_TEXT_COLUMNS if c in cols]
    if info_given and len(info_given) < 6:
        raise InputError(f"binary edge file has {', '.join(info_given)} but not all six of "
                         f"{' '.join(INFORMATION_TEXT_COLUMNS)}", str(path))
    m = len(cols["i"])
    for c, a in cols.items():
        if a.ndim != 1 or len(a) != m:
            raise InputError(f"binary edge file: array {c} has shape {a.shape}, expected ({m},) as i", str(path))
        if c not in ("i", "j") and a.dtype.kind not in "fiu":
            raise InputError(f"binary edge file: array {c} is {a.dtype}, expected numbers", str(path))
    if m == 0:
        raise no_edges(path, " ".join(BINARY_REQUIRED))
    label = lambda k: f"edge {k} (0-based)"  # noqa: E731
    ids = []
    for c in ("i", "j"):
        a = cols.pop(c)
        if a.dtype.kind == "u" and a.max() > np.iinfo(np.int64).max:
            raise InputError(f"binary edge file: id in {c} too large for a signed 64-bit integer", str(path))
        if a.dtype.kind in "iu":
            a = a.astype(np.int64, copy=False)
        elif a.dtype.kind in "OSU":
            a = a.astype(str)
        else:
            raise InputError(f"binary edge file: ids {c} are {a.dtype}, expected integers or strings", str(path))
        ids.append(a)
    if ids[0].dtype.kind != ids[1].dtype.kind:
        raise InputError("binary edge file: i and j must both be integers or both strings", str(path))
    if ids[0].dtype.kind == "i" and min(int(ids[0].min()), int(ids[1].min())) < 0:
        ids = [np.array(a.astype(str).tolist()) for a in ids]  # integer ids are non-negative (CLI.md): "-1" is a name, as in text
    index = None
    if ids[0].dtype.kind == "U":  # names, or digits: integer ids, as in the text formats
        ids, index = resolve_ids(ids, None, path, ("i", "j"), label=label)
    rel = _rotations([cols.pop(c) for c in ("qw", "qx", "qy", "qz")], path, label=label)
    weights = cols.pop("weight", None)
    information = None
    if info_given:
        upper = np.stack([cols.pop(c).astype(np.float64, copy=False) for c in INFORMATION_TEXT_COLUMNS], axis=1)
        bad = ~np.isfinite(upper).all(axis=1)
        if bad.any():
            raise InputError(f"{label(int(np.argmax(bad)))}: information is not finite", str(path))
        information = symmetric_from_upper(upper, 3)
        del upper
    if index is None:
        node_ids, codes = unique(np.concatenate(ids), return_inverse=True)
        index = (node_ids, [codes[:m], codes[m:]])
    del ids
    lines = np.arange(1, m + 1)  # the edge's 1-based row, for messages
    node_ids, (codes_i, codes_j) = index
    return graph_from_codes(path, lines, node_ids, codes_i, codes_j, rel,
                            None if weights is None else weights.astype(np.float64, copy=False), duplicates,
                            information=information)


_GLOMAP_WHAT = "IMG1 IMG2 QW QX QY QZ TX TY TZ"


def _read_glomap(path: Path, duplicates: str) -> ViewGraph:
    text = read_text(path)
    table = read_table(
        path, text, counts=(9,), kinds=("name", "name", "f", "f", "f", "f", "u", "u", "u"),
        names=("IMG1", "IMG2", "QW", "QX", "QY", "QZ", "TX", "TY", "TZ"), what=_GLOMAP_WHAT,
    )
    if len(table) == 0:
        raise no_edges(path, _GLOMAP_WHAT)
    rel = _rotations(table.cols[2:6], path, table.lines)
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
