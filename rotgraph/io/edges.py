"""View graphs (relative rotations) and absolute rotations: file readers and writers.

Every reader returns rotgraph's conventions (see :mod:`rotgraph`): absolute rotations are
``cam_from_world`` (world -> camera), the edge ``(i, j)`` carries ``R_ij = R_j R_i^T``
(``cam2_from_cam1`` with ``cam1 = i``), quaternions are ``(w, x, y, z)``. Each format's
own convention, and how its conversion was checked, is stated below; the numbers quoted
come from this module's readers on the shared benchmark files (``shared/datasets``) and
are pinned by ``tests/test_io_edges.py``.

Edge formats (:func:`read_view_graph`, names as in CLI.md)
-----------------------------------------------------------
``rotgraph``
    Text, one edge a line: ``i j qw qx qy qz [weight]`` (lines with and without the
    weight may mix; a missing weight is 1). The quaternion is ``R_ij = R_j R_i^T``.
    Ids are non-negative integers or names without white space: when every id of the
    file is a run of ASCII digits the ids are ``int64``, otherwise all ids are strings.
    Convention: rotgraph's own (the definition); checked by round trips through
    :func:`write_edges` of ``R_j R_i^T`` built from random ``R_i``.
``csv``
    A header naming the columns ``i,j,qw,qx,qy,qz`` and optionally ``weight`` (any
    order; other columns are ignored), then one edge a row. Same convention and ids as
    ``rotgraph``. Fields may be quoted CSV-style (``"a,b"``).
``glomap``
    GLOMAP's relative-pose text ``IMG1 IMG2 QW QX QY QZ TX TY TZ`` (image names; the
    translation is read and ignored). The pose is ``cam2_from_cam1`` with cam1 = IMG1,
    i.e. ``R_ij`` as is. Node ids and names are the image names (always strings).
    Checked against GLOMAP's own reader and writer (``glomap/io/pose_io.cc``: ReadRelPose
    stores the four numbers after the names as ``coeffs()[(k + 3) % 4]``, i.e. w first,
    into ``ImagePair(image1, image2, cam2_from_cam1)``; WriteRelPose writes the same).
``1dsfm``
    A 1DSfM scene folder (``EGs.txt``; optional ``list.txt``, ``gt_bundle.out``,
    ``cc.txt``) or the path of its ``EGs.txt``. ``EGs.txt`` lines are
    ``i j r11 r12 ... r33 t1 t2 t3`` (row-major). The EG rotation is ``R = R_i R_j^T``
    (camera j -> camera i) in the Bundler camera frame (x right, y up, looking down -z),
    so ``R_ij = R^T``; the reader also converts to the computer-vision camera frame
    (x right, y down, z forward): ``R_ij = D R^T D`` with ``D = diag(1, -1, -1)``.
    ``gt_bundle.out`` (Bundler v0.3, world -> camera) gives ``gt_cam_from_world = D R``
    for every camera whose rotation is not all zero (Bundler's mark of an unregistered
    camera); ``list.txt`` gives the node names (its first field, as written, e.g.
    ``images/NAME.jpg``; line index = id). ``cc.txt`` is informational only.
    How the direction was established (there is no 1DSfM ground truth in shared/): (1)
    TheiaSfM's 1DSfM reader (``read_1dsfm.cc``: "the rotation defines the camera 2 to
    camera 1 transformation ... we read in the transpose", then conjugates with
    diag(1, -1, -1)); (2) 1DSfM's ``sfminit`` places camera j at ``EG.R^T`` with camera i
    at the identity; (3) the Chatterjee-format files packed from 1DSfM scenes use
    ``RR = inv(EG R)`` and match ``Rgt_j Rgt_i^T`` - which Ellis.mat's ground truth
    confirms (see ``mat``); (4) on Madrid_Metropolis the triangle closures are smaller as
    read than transposed (5th/10th/25th percentiles 1.7/3.0/8.7 vs 3.0/5.1/11.7 degrees over
    20,000 random triangles; a weak test, landmark scenes turn mostly about one axis). The
    D conjugation does not change the direction; it only keeps the edges and the
    ground truth in one (computer-vision) frame.
``mat``
    Chatterjee-Govindu ``.mat`` (scipy.io.loadmat; MATLAB v7.3/HDF5 files are not
    supported): ``RR`` 3x3xM relative rotations, ``I`` 2xM 1-based edge indices (any
    integer type; Ellis.mat stores uint8, cast before subtracting 1), optional ``Rgt``
    3x3xN world -> camera ground truth (all-zero slices = no ground truth). ``RR(:,:,k) =
    Rgt_j Rgt_i^T`` for ``I(:,k) = (i, j)``: used as is. Also accepted: ``I`` as Mx2,
    ``RR``/``Rgt`` as Mx3x3, and a single 3x3 slice. Node ids are ``0 .. N-1`` with N the
    larger of ``max(I)`` and Rgt's N (but when more than half of them would have neither
    an edge nor ground truth, only the ids in ``I`` and Rgt's ``0 .. N-1``: one huge index
    must not allocate billions of cameras). Checked on Ellis.mat against its ``Rgt``: median
    input-edge error 2.894 degrees as read, vs 33.1 degrees read as ``R_i R_j^T`` and
    31.8 degrees read as ``R_j^T R_i``.
``g2o``
    3D pose graph: ``VERTEX_SE3:QUAT id x y z qx qy qz qw`` (world_from_body) and
    ``EDGE_SE3:QUAT i j x y z qx qy qz qw`` + 21 information entries. The quaternions are
    **x, y, z, w** in the file. The edge is ``T_i^-1 T_j``, whose rotation is
    ``Q_ij = Q_i^T Q_j``; with ``R_i = Q_i^T`` (body_from_world) that is ``R_ij = Q_ij^T``,
    which the reader returns. Every edge weighs 1. Vertex rotations give
    ``gt_cam_from_world = Q_i^T`` - but in the SE-Sync sets (garage, cubicle, ...) the
    vertices are odometry / initial guesses, NOT ground truth: ``meta
    ["g2o_vertices_are_initial_guess"]`` is True. Checked on parking-garage.g2o: the 1660
    odometry edges ``(i, i+1)`` equal ``R_{i+1} R_i^T`` of the vertices to 1.7e-4 degrees
    (median 3.5e-5: the file's 6-digit rounding) as read, vs median 2.8 and max 88 degrees
    transposed; triangle closure median 0.039 as read vs 0.69 degrees transposed.
    ``FIX``, ``VERTEX_TRACKXYZ``, ``VERTEX_XYZ``, ``EDGE_SE3_TRACKXYZ`` and
    ``PARAMS_SE3OFFSET`` lines are skipped (one warning with the counts); 2D tags (``VERTEX_SE2``, ``EDGE_SE2...``) and any other tag are an
    error. The translation is parsed, the 21 information entries are counted (a line
    must have exactly 31 fields) but not parsed: rotgraph uses neither. Parallel edges
    occur (cubicle.g2o): ``duplicates`` decides.
``colmap``
    A COLMAP project folder or ``database.db``: read by :func:`rotgraph.io.colmap.read_colmap_project`
    (the image-level graph; ``rotgraph solve`` uses the rig-aware
    :func:`rotgraph.io.colmap.solve_colmap`).

Common rules for the text formats: blank lines and lines whose first non-blank character
is ``#`` are skipped (a ``#`` later in a line is data); fields are split on white space
(``csv``: on commas). Quaternions are normalised: a non-unit one is accepted as a scaled
quaternion (one warning with the count when some ``| |q| - 1 | > 1e-3``), a zero one is an
error; a 3x3 matrix must be within 1e-3 (max entry) of a rotation and is projected onto
SO(3). Every malformed input raises :class:`~rotgraph.errors.InputError` naming the file
and, when there is one, the 1-based line: wrong field count, non-numeric, NaN or infinite
field, zero quaternion, self-loop, duplicate pair (``duplicates="error"``), no edges.

Speed: numeric tables go through ``np.loadtxt`` with a structured dtype (one C pass),
g2o lines are sorted by tag with vectorised byte compares, and ids are indexed by sorting
(numpy >= 2.3's hash-based ``np.unique`` is ~10x slower on 10^6 ids); only when the fast
pass fails does a line-by-line parser run, to name the first bad line. About 4 s for 10^6
edges (rotgraph text or 10^6 g2o lines) on one core of a loaded 2-core machine.
"""

from __future__ import annotations

import csv
import io
import logging
import math
import warnings
from pathlib import Path

import numpy as np

from .. import so3
from ..errors import InputError
from ..viewgraph import ViewGraph
from .text import atomic_write, is_float, read_text

__all__ = [
    "EDGE_FORMATS",
    "ROTATION_FORMATS",
    "detect_format",
    "read_view_graph",
    "read_absolute_rotations",
    "write_rotations",
    "write_edges",
    "write_edges_csv",
    "write_absolute_rotations_text",
]

logger = logging.getLogger(__name__)

EDGE_FORMATS = ("auto", "rotgraph", "csv", "glomap", "1dsfm", "mat", "g2o", "colmap")
ROTATION_FORMATS = ("auto", "csv", "text", "bundler", "mat", "g2o", "1dsfm", "colmap")

_INT64_MAX = 2**63 - 1
# D = diag(1, -1, -1) as a sign pattern: D A D == _DSIGN * A, D A == _DSIGN_ROWS * A.
_DSIGN = np.outer([1.0, -1.0, -1.0], [1.0, -1.0, -1.0])
_DSIGN_ROWS = np.array([1.0, -1.0, -1.0])[:, None]
_ROTATION_TOL = 1e-3  # max entry distance of a 3x3 matrix from SO(3) that is accepted
_G2O_SKIPPED = ("FIX", "VERTEX_TRACKXYZ", "VERTEX_XYZ", "EDGE_SE3_TRACKXYZ", "PARAMS_SE3OFFSET")


# =========================================================================== text tables


def _first_data_line(text: str, start: int = 0) -> tuple[int, int, str] | None:
    """``(line number, end offset, stripped line)`` of the first line after offset ``start``
    that is neither blank nor a ``#`` comment (``start`` must be a line start; line numbers
    count ``\\n`` only, callers use it on text with simple line breaks or just to sniff)."""
    number = text.count("\n", 0, start) + 1
    pos = start
    while pos < len(text):
        end = text.find("\n", pos)
        end = len(text) if end < 0 else end
        s = text[pos:end].strip()
        if s and not s.startswith("#"):
            return number, end, s
        pos, number = end + 1, number + 1
    return None


def _simple_line_breaks(text: str) -> bool:
    """Whether ``\\n`` (or ``\\r\\n``) is the only line break, so that counting ``\\n``
    gives the line numbers of ``str.splitlines`` (the line-by-line parser's numbers)."""
    odd = ("\x0b", "\x0c", "\x1c", "\x1d", "\x1e")
    if not text.isascii():
        odd += ("\x85", "\u2028", "\u2029")
    if any(ch in text for ch in odd):
        return False
    return "\r" not in text or text.count("\r") == text.count("\r\n")


def _comment_line_numbers(text: str) -> list[int] | None:
    """Line numbers of the ``#`` comment lines, or None if some ``#`` is not the first
    non-blank character of its line (then np.loadtxt's comment handling would differ)."""
    out: list[int] = []
    pos = text.find("#")
    line, last = 1, 0
    while pos >= 0:
        start = text.rfind("\n", 0, pos) + 1
        if text[start:pos].strip():
            return None
        line += text.count("\n", last, pos)
        last = pos
        out.append(line)
        end = text.find("\n", pos)
        if end < 0:
            break
        pos = text.find("#", end)
    return out


def _data_line_numbers(text: str, comments: list[int], n_data: int) -> np.ndarray | None:
    """1-based numbers of the data lines (not blank, not comments); None if they are not
    ``n_data`` lines (the caller then falls back to the line-by-line parser)."""
    total = text.count("\n") + (1 if text and not text.endswith("\n") else 0)
    if total - len(comments) == n_data:  # no blank lines: everything else is data
        keep = np.ones(total + 1, dtype=bool)
        keep[0] = False
        keep[comments] = False
        numbers = np.flatnonzero(keep)
    else:
        numbers = np.array(
            [k for k, s in enumerate(text.split("\n"), 1) if s.strip() and not s.lstrip().startswith("#")],
            dtype=np.int64,
        )
    return numbers if len(numbers) == n_data else None


def _unique(a: np.ndarray, return_inverse: bool = False):
    """Sorted distinct values (and the inverse map): np.unique by sorting, which is ~10x
    faster than numpy 2.3+'s hash-based np.unique on 10^6 ids."""
    a = np.asarray(a).ravel()
    order = np.argsort(a, kind="stable")
    s = a[order]
    first = np.ones(len(s), dtype=bool)
    if len(s):
        first[1:] = s[1:] != s[:-1]
    uniq = s[first]
    if not return_inverse:
        return uniq
    inverse = np.empty(len(a), dtype=np.int64)
    inverse[order] = np.cumsum(first) - 1
    return uniq, inverse


class _Table:
    """Parsed columns of a text table: ``lines`` (M,) 1-based line numbers, ``cols`` one
    array per column (int64, float64 or str), ``nfields`` (M,) fields per row."""

    def __init__(self, lines, cols, nfields, index=None):
        self.lines = np.asarray(lines, dtype=np.int64)
        self.cols = cols
        self.nfields = nfields
        self._index = index  # (sorted distinct ids, codes of the id columns), when known

    def index(self, ci: int, cj: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(node_ids, codes_i, codes_j)``: the sorted distinct ids of columns ``ci`` and
        ``cj`` and each row's position in them."""
        if self._index is None or set(self._index[1]) != {ci, cj}:
            uniq, inverse = _unique(np.concatenate([self.cols[ci], self.cols[cj]]), return_inverse=True)
            self._index = (uniq, {ci: inverse[: len(self)], cj: inverse[len(self):]})
        uniq, codes = self._index
        return uniq, codes[ci], codes[cj]

    def __len__(self) -> int:
        return len(self.lines)

    def floats(self, a: int, b: int) -> np.ndarray:
        return np.stack(self.cols[a:b], axis=1) if len(self) else np.zeros((0, b - a))


def _count_text(counts) -> str:
    counts = sorted(counts)
    return str(counts[0]) if len(counts) == 1 else " or ".join(str(c) for c in counts)


_LOADTXT_DTYPE = {"int": "i8", "f": "f8", "u": "f8", "name": "O", "skip": "O"}


def _read_table(path, text, *, counts, kinds, names, what, defaults=None, sep=None, start=0) -> _Table:
    """Parse the data lines of ``text`` after offset ``start`` (a line start).

    ``kinds[c]`` says what column ``c`` holds: ``id`` (non-negative integer or name: one
    decision for all ``id`` columns of the file), ``int`` (non-negative integer),
    ``name`` (string), ``f`` (finite float), ``u`` (float, not checked: unused) or
    ``skip``. Rows may have any field count in ``counts``; columns missing from a short
    row take ``defaults[c]``. ``what`` describes a line for messages.
    """
    defaults = defaults or {}
    first = _first_data_line(text, start)
    if first is None:
        return _Table([], [np.zeros(0) for _ in kinds], np.zeros(0, np.int64))
    _, _, line0 = first
    fields0 = line0.split() if sep is None else line0.split(sep)
    fast = (
        len(fields0) in counts
        and _simple_line_breaks(text)
        and not (sep is not None and '"' in text)
    )
    comments = _comment_line_numbers(text) if fast else None
    if comments is not None:
        ncol = len(fields0)
        has_ids = "id" in kinds[:ncol]
        ids_look_int = all(fields0[c].strip().isdigit() for c in range(ncol) if kinds[c] == "id")
        for id_dtype in (("i8", "O") if has_ids and ids_look_int else ("O",) if has_ids else ("i8",)):
            table = _fast_table(path, text, kinds[:ncol], names, id_dtype, sep, start, comments, defaults, len(kinds))
            if table is not None:
                return table
    return _slow_table(path, text, counts=counts, kinds=kinds, names=names, what=what, defaults=defaults, sep=sep, start=start)


def _fast_table(path, text, kinds, names, id_dtype, sep, start, comments, defaults, nkinds) -> _Table | None:
    """One np.loadtxt pass; None when it fails (bad data or a layout it cannot read)."""
    dtype = np.dtype([(f"c{c}", id_dtype if k == "id" else _LOADTXT_DTYPE[k]) for c, k in enumerate(kinds)])
    skiprows = text.count("\n", 0, start)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "input contained no data"
            arr = np.loadtxt(io.BytesIO(text.encode("utf-8")), dtype=dtype, delimiter=sep, comments="#",
                             skiprows=skiprows, ndmin=1, quotechar=None, encoding="utf-8")
    except (ValueError, TypeError, OverflowError):
        return None
    header = [c for c in comments if c <= skiprows]
    lines = _data_line_numbers(text, comments, len(arr) + skiprows - len(header))
    if lines is None:
        return None
    lines = lines[len(lines) - len(arr):]
    cols: list[np.ndarray] = []
    id_cols = []
    for c, kind in enumerate(kinds):
        col = arr[f"c{c}"]
        if kind in ("name", "skip") or (kind == "id" and id_dtype == "O"):
            col = col.astype(str) if len(col) else np.zeros(0, dtype=str)
            if sep is not None:  # CSV fields may be padded
                col = np.char.strip(col)
        elif kind == "f":
            bad = ~np.isfinite(col)
            if bad.any():
                r = int(np.argmax(bad))
                raise InputError(f"{names[c]} is not finite ({col[r]})", path, int(lines[r]))
        elif kind == "int" and len(col) and col.min() < 0:
            r = int(np.argmax(col < 0))
            raise InputError(f"{names[c]} must be a non-negative integer, got {col[r]}", path, int(lines[r]))
        if kind == "id":
            id_cols.append(c)
        cols.append(col)
    if id_cols and id_dtype == "i8" and any(len(cols[c]) and cols[c].min() < 0 for c in id_cols):
        return None  # a negative number is a name (see _resolve_ids): re-read as strings
    index = None
    if id_cols and id_dtype == "O":
        resolved, index = _resolve_ids([cols[c] for c in id_cols], lines, path, [names[c] for c in id_cols])
        for c, col in zip(id_cols, resolved):
            cols[c] = col
        if index is not None:
            index = (index[0], dict(zip(id_cols, index[1])))
    for c in range(len(kinds), nkinds):  # optional columns absent from the whole file
        cols.append(np.full(len(arr), float(defaults[c])))
    return _Table(lines, cols, np.full(len(arr), len(kinds)), index)


def _resolve_ids(cols: list[np.ndarray], lines: np.ndarray, path, names):
    """Id columns as strings -> int64 if every id is a run of ASCII digits, else strings.

    Returns the columns and, for two id columns, ``(sorted distinct ids, [codes per
    column])`` (see :meth:`_Table.index`), else None."""
    both = np.concatenate(cols)
    empty = both == ""
    if empty.any():
        k = int(np.argmax(empty))
        raise InputError(f"empty {names[k // len(lines)]}", path, int(lines[k % len(lines)]))
    uniq, inverse = _unique(both, return_inverse=True)
    values = uniq.tolist()
    if not all(u.isascii() and u.isdigit() for u in values):
        return cols, ((uniq, list(inverse.reshape(len(cols), -1))) if len(cols) == 2 else None)
    ints = [int(u) for u in values]
    big = [u for u, v in zip(values, ints) if v > _INT64_MAX]
    if big:
        k = int(np.argmax(both == big[0]))
        raise InputError(
            f"{names[k // len(lines)]} {big[0][:30]} is too large: integer ids must fit in a signed 64-bit integer",
            path, int(lines[k % len(lines)]),
        )
    as_int = np.array(ints, dtype=np.int64)
    # "7" and "007" are the same integer id, so the index is rebuilt from the ints (lazily)
    return list(as_int[inverse].reshape(len(cols), -1)), None


def _split_csv(s: str) -> list[str]:
    return next(csv.reader([s])) if '"' in s else s.split(",")


def _slow_table(path, text, *, counts, kinds, names, what, defaults, sep, start) -> _Table:
    """The line-by-line parser: slower, and the reference for what is an error where."""
    start_line = text.count("\n", 0, start)
    numbers: list[int] = []
    rows: list[list[str]] = []
    for k, raw in enumerate(text.splitlines(), 1):
        if k <= start_line:
            continue
        s = raw.strip()
        if not s or s.startswith("#"):
            continue
        f = s.split() if sep is None else [x.strip() for x in _split_csv(s)]
        if len(f) not in counts:
            raise InputError(f"expected {_count_text(counts)} fields ({what}), got {len(f)}", path, k)
        numbers.append(k)
        rows.append(f)
    lines = np.array(numbers, dtype=np.int64)
    nfields = np.array([len(r) for r in rows], dtype=np.int64)
    cols: list[np.ndarray] = []
    id_cols = []
    for c, kind in enumerate(kinds):
        vals = [r[c] if c < len(r) else None for r in rows]
        if kind in ("f", "u"):
            cols.append(_floats(vals, lines, path, names[c], finite=kind == "f", default=defaults.get(c)))
        elif kind == "int":
            cols.append(_nonneg_ints(vals, lines, path, names[c]))
        else:
            if kind == "id":
                id_cols.append(c)
            cols.append(np.array(vals, dtype=str) if vals else np.zeros(0, dtype=str))
    index = None
    if id_cols and len(rows):
        resolved, index = _resolve_ids([cols[c] for c in id_cols], lines, path, [names[c] for c in id_cols])
        for c, col in zip(id_cols, resolved):
            cols[c] = col
        if index is not None:
            index = (index[0], dict(zip(id_cols, index[1])))
    return _Table(lines, cols, nfields, index)


def _floats(vals, lines, path, name, finite=True, default=None) -> np.ndarray:
    if default is not None:
        vals = [repr(float(default)) if v is None else v for v in vals]
    try:
        out = np.array(vals, dtype=np.float64)
    except (ValueError, TypeError):
        out = None
    if out is None:
        for ln, v in zip(lines, vals):
            try:
                float(v)
            except (ValueError, TypeError):
                raise InputError(f"{name} is not a number: {str(v)[:40]!r}", path, int(ln)) from None
        raise AssertionError("unreachable")  # pragma: no cover
    if finite:
        bad = ~np.isfinite(out)
        if bad.any():
            r = int(np.argmax(bad))
            raise InputError(f"{name} is not finite ({vals[r]})", path, int(lines[r]))
    return out


def _nonneg_ints(vals, lines, path, name) -> np.ndarray:
    out = np.empty(len(vals), dtype=np.int64)
    for r, v in enumerate(vals):
        if not (v.isascii() and v.isdigit()):
            raise InputError(f"{name} must be a non-negative integer, got {v[:40]!r}", path, int(lines[r]))
        x = int(v)
        if x > _INT64_MAX:
            raise InputError(f"{name} {v[:30]} is too large (must fit in a signed 64-bit integer)", path, int(lines[r]))
        out[r] = x
    return out


# =========================================================================== rotations


def _unit_quaternions(q: np.ndarray, lines, path) -> np.ndarray:
    """Normalise ``(M, 4)`` quaternions; zero -> InputError at its line, non-unit -> one warning."""
    norm = np.linalg.norm(q, axis=1)
    bad = ~(norm > 1e-12)
    if bad.any():
        k = int(np.argmax(bad))
        raise InputError("zero quaternion (all four components 0)", path, None if lines is None else int(lines[k]))
    off = np.abs(norm - 1.0) > 1e-3
    if off.any():
        logger.warning(
            "%s: %d of %d quaternions are not unit length (| |q| - 1 | up to %.3g); normalised",
            path, int(off.sum()), len(q), float(np.abs(norm - 1.0).max()),
        )
    return q / norm[:, None]


def _checked_rotations(M: np.ndarray, path, lines=None, label=None) -> np.ndarray:
    """Project near-rotations ``(K, 3, 3)`` onto SO(3); anything farther than 1e-3 is an error.

    ``lines`` gives the line of each matrix, or ``label(k)`` names it (e.g. ``RR(:,:,5)``).
    """
    if len(M) == 0:
        return M
    _, err = so3.rotation_errors(M)
    bad = ~(err <= _ROTATION_TOL)
    if bad.any():
        k = int(np.argmax(bad))
        what = "not finite" if not np.isfinite(M[k]).all() else f"max entry {err[k]:.3g} from the nearest rotation"
        where = "" if label is None else f"{label(k)}: "
        raise InputError(f"{where}not a rotation matrix ({what})", path, None if lines is None else int(lines[k]))
    return so3.project_to_so3(M) if float(err.max()) > 1e-12 else M


# =========================================================================== detection


def _sniff(path: Path, n: int = 65536) -> bytes:
    try:
        with open(path, "rb") as fh:
            return fh.read(n)
    except FileNotFoundError:
        raise InputError("no such file", path=str(path)) from None
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror or exc}", path=str(path)) from None


def _is_colmap(p: Path) -> bool:
    from .colmap import is_colmap_project

    return is_colmap_project(p)


def detect_format(path) -> str:
    """The edge format of ``path`` (see :data:`EDGE_FORMATS`), by extension and content.

    Folder with ``EGs.txt`` -> ``1dsfm``; a COLMAP folder (``database.db`` or a sparse
    model) or ``.db`` file -> InputError (not read here yet); ``.mat`` or a MATLAB header
    -> ``mat``; ``.g2o`` or a first tag ``VERTEX_...``/``EDGE_...`` -> ``g2o``; a file
    named ``EGs.txt``, or 14 numeric fields a line -> ``1dsfm``; ``.csv`` or a comma in the
    first data line -> ``csv``; exactly 9 fields whose 3rd..6th form a unit quaternion ->
    ``glomap``; otherwise ``rotgraph``.
    """
    p = Path(path)
    if p.is_dir():
        if (p / "EGs.txt").is_file():
            return "1dsfm"
        if _is_colmap(p):
            return "colmap"
        raise InputError(
            "folder holds no input rotgraph can read (expected EGs.txt of a 1DSfM scene, or a COLMAP "
            "database.db / sparse model)",
            path=str(path),
        )
    if not p.exists():
        raise InputError("no such file", path=str(path))
    ext = p.suffix.lower()
    head = _sniff(p)
    if ext == ".mat" or head.startswith(b"MATLAB") or head.startswith(b"\x89HDF"):
        return "mat"
    if ext == ".db" or head.startswith(b"SQLite format 3\x00"):
        return "colmap"
    if ext == ".g2o":
        return "g2o"
    if p.name.lower() == "egs.txt":
        return "1dsfm"
    first = _first_data_line(head.decode("utf-8-sig", errors="replace"))
    tokens = first[2].split() if first else []
    if tokens and tokens[0].startswith(("VERTEX_", "EDGE_")) or tokens[:1] and tokens[0] in _G2O_SKIPPED:
        return "g2o"
    if ext == ".csv" or (first is not None and "," in first[2]):
        return "csv"
    if len(tokens) == 9 and all(is_float(t) for t in tokens[2:9]):
        q = np.array([float(t) for t in tokens[2:6]])
        if abs(np.linalg.norm(q) - 1.0) < 1e-2:
            return "glomap"
    if len(tokens) == 14 and tokens[0].isdigit() and tokens[1].isdigit() and all(is_float(t) for t in tokens[2:]):
        return "1dsfm"
    return "rotgraph"


# =========================================================================== edge readers


def read_view_graph(path, fmt: str = "auto", duplicates: str = "error", progress=None) -> ViewGraph:
    """Read a view graph (cameras and relative rotations ``R_ij = R_j R_i^T``).

    ``fmt`` is one of :data:`EDGE_FORMATS` (the module docstring describes each, with its
    direction convention and how it was checked); ``duplicates`` is ``error``, ``merge``
    or ``keep`` (see :class:`~rotgraph.viewgraph.ViewGraph`). Ground truth or initial
    guesses carried by the file land in ``graph.gt_cam_from_world`` ((n, 3, 3), NaN for
    cameras without); ``graph.format`` records the format read. ``progress(stage, done,
    total)`` follows the readers that count work (COLMAP relative-pose estimation).

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
        from .colmap import read_colmap_project

        return read_colmap_project(p, progress=progress)
    reader = {
        "rotgraph": _read_rotgraph,
        "csv": _read_csv_edges,
        "glomap": _read_glomap,
        "1dsfm": _read_1dsfm,
        "mat": _read_mat,
        "g2o": _read_g2o,
    }[fmt]
    graph = reader(p, duplicates)
    graph.format = fmt
    return graph


def _no_edges(path, what: str, line=None):
    return InputError(f"no edges (expected lines '{what}')", str(path), line)


def _graph(path, lines, node_ids, codes_i, codes_j, rel, weights, duplicates, names=None) -> ViewGraph:
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


_ROTGRAPH_WHAT = "i j qw qx qy qz [weight]"


def _read_rotgraph(path: Path, duplicates: str) -> ViewGraph:
    text = read_text(path)
    table = _read_table(
        path, text, counts=(6, 7), kinds=("id", "id", "f", "f", "f", "f", "f"),
        names=("i", "j", "qw", "qx", "qy", "qz", "weight"), what=_ROTGRAPH_WHAT, defaults={6: 1.0},
    )
    if len(table) == 0:
        raise _no_edges(path, _ROTGRAPH_WHAT)
    q = _unit_quaternions(table.floats(2, 6), table.lines, path)
    rel = so3.matrices_from_quaternions(q)
    return _graph(path, table.lines, *table.index(0, 1), rel, table.cols[6], duplicates)


def _csv_header(path, text, required, optional=()):
    """``(header names, offset after the header line, header line number)``."""
    first = _first_data_line(text)
    if first is None:
        raise InputError(f"empty file, expected a CSV header {','.join(required)}", str(path), None)
    number, end, line = first
    header = [h.strip().lower() for h in _split_csv(line)]
    missing = [c for c in required if c not in header]
    if missing:
        raise InputError(f"CSV header lacks column(s) {', '.join(missing)} (header: {line[:80]!r})", str(path), number)
    dup = [h for h in set(header) if header.count(h) > 1 and h in tuple(required) + tuple(optional)]
    if dup:
        raise InputError(f"CSV header names column {dup[0]!r} twice", str(path), number)
    return header, min(end + 1, len(text)), number


def _read_csv_edges(path: Path, duplicates: str) -> ViewGraph:
    text = read_text(path)
    required = ("i", "j", "qw", "qx", "qy", "qz")
    header, start, hline = _csv_header(path, text, required, ("weight",))
    kinds = tuple("id" if h in ("i", "j") else "f" if h in required or h == "weight" else "skip" for h in header)
    table = _read_table(
        path, text, counts=(len(header),), kinds=kinds, names=tuple(header),
        what=f"as in the header, {','.join(header)}"[:120], sep=",", start=start,
    )
    if len(table) == 0:
        raise InputError("no edges after the CSV header", str(path), hline)
    col = {h: table.cols[c] for c, h in enumerate(header)}
    q = _unit_quaternions(np.stack([col[c] for c in ("qw", "qx", "qy", "qz")], axis=1), table.lines, path)
    rel = so3.matrices_from_quaternions(q)
    index = table.index(header.index("i"), header.index("j"))
    return _graph(path, table.lines, *index, rel, col.get("weight"), duplicates)


_GLOMAP_WHAT = "IMG1 IMG2 QW QX QY QZ TX TY TZ"


def _read_glomap(path: Path, duplicates: str) -> ViewGraph:
    text = read_text(path)
    table = _read_table(
        path, text, counts=(9,), kinds=("name", "name", "f", "f", "f", "f", "u", "u", "u"),
        names=("IMG1", "IMG2", "QW", "QX", "QY", "QZ", "TX", "TY", "TZ"), what=_GLOMAP_WHAT,
    )
    if len(table) == 0:
        raise _no_edges(path, _GLOMAP_WHAT)
    q = _unit_quaternions(table.floats(2, 6), table.lines, path)
    rel = so3.matrices_from_quaternions(q)
    names, codes_i, codes_j = table.index(0, 1)
    return _graph(path, table.lines, names, codes_i, codes_j, rel, None, duplicates, names=names)


# --------------------------------------------------------------------------- 1DSfM

_EGS_WHAT = "i j r11 r12 r13 r21 r22 r23 r31 r32 r33 t1 t2 t3"


def _read_1dsfm(path: Path, duplicates: str) -> ViewGraph:
    folder = path if path.is_dir() else path.parent
    egs = folder / "EGs.txt" if path.is_dir() else path
    if path.is_dir() and not egs.is_file():
        raise InputError("1DSfM folder without EGs.txt", str(path))
    # list.txt / gt_bundle.out / cc.txt belong to the scene: read them beside EGs.txt only.
    scene = path.is_dir() or path.name.lower() == "egs.txt"
    text = read_text(egs)
    names = ("i", "j") + tuple(f"r{a}{b}" for a in (1, 2, 3) for b in (1, 2, 3)) + ("t1", "t2", "t3")
    table = _read_table(egs, text, counts=(14,), kinds=("int", "int") + ("f",) * 9 + ("u",) * 3, names=names, what=_EGS_WHAT)
    if len(table) == 0:
        raise _no_edges(egs, _EGS_WHAT)
    R = _checked_rotations(table.floats(2, 11).reshape(-1, 3, 3), egs, table.lines)
    # EG R = R_i R_j^T (Bundler frame) -> R_ij = R^T; to the computer-vision frame: D R^T D.
    rel = _DSIGN * np.swapaxes(R, 1, 2)
    ids_i, ids_j = table.cols[0], table.cols[1]
    node_ids, codes_i, codes_j = table.index(0, 1)
    node_names = None
    list_path = folder / "list.txt"
    if scene and list_path.is_file():
        listed = _read_1dsfm_list(list_path)
        if node_ids[-1] >= len(listed):
            k = int(np.argmax((ids_i >= len(listed)) | (ids_j >= len(listed))))
            raise InputError(
                f"camera id {int(max(ids_i[k], ids_j[k]))} has no line in {list_path} ({len(listed)} images)",
                str(egs), int(table.lines[k]),
            )
        node_names = listed[node_ids]
    graph = _graph(egs, table.lines, node_ids, codes_i, codes_j, rel, None, duplicates, names=node_names)
    bundle = folder / "gt_bundle.out"
    if scene and bundle.is_file():
        gt_all = _read_bundler(bundle)
        gt = np.full((graph.n_nodes, 3, 3), np.nan)
        inside = graph.node_ids < len(gt_all)
        gt[inside] = gt_all[graph.node_ids[inside]]
        if not inside.all():
            logger.warning("%s: %d cameras of EGs.txt are beyond its %d cameras", bundle, int((~inside).sum()), len(gt_all))
        graph.gt_cam_from_world = gt
        graph.meta["gt_source"] = str(bundle)
    cc = folder / "cc.txt"
    if scene and cc.is_file():
        graph.meta["1dsfm_cc_path"] = str(cc)
    graph.meta["camera_frame"] = "computer vision (x right, y down, z forward); converted from Bundler by D = diag(1,-1,-1)"
    return graph


def _read_1dsfm_list(path: Path) -> np.ndarray:
    names = []
    for line in read_text(path).splitlines():
        s = line.strip()
        names.append(s.split()[0] if s else "")
    while names and names[-1] == "":
        names.pop()
    return np.array(names, dtype=str)


def _read_bundler(path: Path) -> np.ndarray:
    """World -> camera rotations ``(N, 3, 3)`` of a Bundler v0.3 file, converted to the
    computer-vision camera frame (``D R``); NaN for unregistered (all-zero) cameras."""
    text = read_text(path)
    lines = text.splitlines()
    k = 0
    while k < len(lines) and (not lines[k].strip() or lines[k].lstrip().startswith("#")):
        k += 1
    if k == len(lines):
        raise InputError("empty Bundler file (expected '# Bundle file v0.3', then 'num_cameras num_points')", str(path), None)
    counts = lines[k].split()
    if len(counts) != 2 or not all(c.isdigit() for c in counts):
        raise InputError(f"expected 'num_cameras num_points', got {lines[k].strip()[:60]!r}", str(path), k + 1)
    n = int(counts[0])
    first = k + 1
    need = first + 5 * n
    if len(lines) < need:
        raise InputError(f"truncated: {n} cameras need {5 * n} lines after the counts", str(path), len(lines))
    block = lines[first:need]
    try:
        vals = np.array(" ".join(block).split(), dtype=np.float64)
    except ValueError:
        vals = None
    if vals is None or vals.size != 15 * n:
        for r, s in enumerate(block):
            f = s.split()
            if len(f) != 3 or not all(is_float(x) for x in f):
                raise InputError(f"expected 3 numbers, got {s.strip()[:60]!r}", str(path), first + r + 1)
        raise AssertionError("unreachable")  # pragma: no cover
    cams = vals.reshape(n, 5, 3)
    R = cams[:, 1:4, :]
    registered = np.any(R != 0, axis=(1, 2))
    out = np.full((n, 3, 3), np.nan)
    idx = np.flatnonzero(registered)
    out[idx] = _DSIGN_ROWS * _checked_rotations(R[idx], path, lines=first + 5 * idx + 2)
    return out


# --------------------------------------------------------------------------- .mat


def _read_mat(path: Path, duplicates: str) -> ViewGraph:
    import scipy.io

    if not path.is_file():
        raise InputError("no such file" if not path.exists() else "is a folder, expected a .mat file", str(path))
    try:
        data = scipy.io.loadmat(str(path))
    except NotImplementedError:
        raise InputError("MATLAB v7.3 (HDF5) .mat files are not supported: save with -v7 instead", str(path)) from None
    except Exception as exc:  # scipy raises ValueError, TypeError, OSError ... on garbage
        raise InputError(f"not a readable MATLAB .mat file ({type(exc).__name__}: {str(exc)[:100]})", str(path)) from None
    spath = str(path)

    def var(name, required=True):
        if name not in data:
            if not required:
                return None
            have = sorted(k for k in data if not k.startswith("__"))
            raise InputError(
                f"variable {name!r} missing (the file has: {', '.join(have) or 'nothing'}); expected RR, I and optionally Rgt",
                spath,
            )
        v = data[name]
        if not isinstance(v, np.ndarray) or v.dtype.kind not in "biuf":
            raise InputError(f"variable {name!r} must be a numeric array, got {getattr(v, 'dtype', type(v))}", spath)
        return v

    RR = _mat_stack(var("RR"), "RR", spath)
    M = len(RR)
    I = var("I")
    if I.ndim != 2 or 2 not in I.shape:
        raise InputError(f"variable 'I' must be 2xM (or Mx2), got shape {I.shape}", spath)
    if I.shape != (2, M):
        if I.shape != (M, 2):
            m = I.shape[1] if I.shape[0] == 2 else I.shape[0]
            raise InputError(f"variable 'I' has {m} edges but 'RR' has {M}", spath)
        I = I.T
    if I.dtype.kind == "f":
        if not (np.isfinite(I).all() and (I == np.round(I)).all()):
            raise InputError("variable 'I' must hold integer indices", spath)
    if M == 0:
        raise InputError("no edges (RR and I are empty)", spath)
    if I.min() < 1:
        k = int(np.argmax((I < 1).any(axis=0)))
        raise InputError(f"I(:,{k + 1}) = {tuple(I[:, k].tolist())}: indices are 1-based, got < 1", spath)
    if I.max() > _INT64_MAX:  # uint64 or float indices beyond int64
        k = int(np.argmax((I > _INT64_MAX).any(axis=0)))
        raise InputError(f"I(:,{k + 1}) = {tuple(I[:, k].tolist())}: index too large (must fit in a signed 64-bit integer)", spath)
    I = I.astype(np.int64)  # before subtracting 1: Ellis.mat stores I as uint8
    if not np.isfinite(RR).all():
        k = int(np.argmax(~np.isfinite(RR).all(axis=(1, 2))))
        raise InputError(f"RR(:,:,{k + 1}) is not finite", spath)
    rel = _checked_rotations(RR, spath, label=lambda k: f"RR(:,:,{k + 1})")
    Rgt = var("Rgt", required=False)
    n_gt = 0
    if Rgt is not None:
        Rgt = _mat_stack(Rgt, "Rgt", spath)
        n_gt = len(Rgt)
    n = max(int(I.max()), n_gt)
    # Cameras 0 .. n-1, unless most of them would have neither edges nor ground truth (e.g.
    # one huge index in a small file: 0 .. n-1 could be too many to allocate); then only the
    # cameras in I and Rgt.
    known = _unique(np.concatenate([np.arange(n_gt, dtype=np.int64), (I - 1).ravel()]))
    node_ids = np.arange(n, dtype=np.int64) if n <= 2 * len(known) else known
    gt = None
    if Rgt is not None:
        gt = np.full((len(node_ids), 3, 3), np.nan)
        has = np.isfinite(Rgt).all(axis=(1, 2)) & np.any(Rgt != 0, axis=(1, 2))
        idx = np.flatnonzero(has)
        gt[idx] = _checked_rotations(Rgt[idx], spath, label=lambda k: f"Rgt(:,:,{idx[k] + 1})")
    loops = np.flatnonzero(I[0] == I[1])
    if len(loops):
        k = int(loops[0])
        raise InputError(f"I(:,{k + 1}) = {tuple(I[:, k].tolist())}: self-loop, an edge from a camera to itself", spath)
    graph = ViewGraph.from_edges(I[0] - 1, I[1] - 1, rel, None, node_ids=node_ids, duplicates=duplicates, source_path=spath)
    graph.gt_cam_from_world = gt
    return graph


def _mat_stack(v: np.ndarray, name: str, path: str) -> np.ndarray:
    """A MATLAB 3x3xK array (or 3x3, or Kx3x3) as ``(K, 3, 3)`` float64."""
    v = np.asarray(v, dtype=np.float64)
    if v.shape == (3, 3):
        return v[None].copy()
    if v.ndim == 3 and v.shape[:2] == (3, 3):
        return np.ascontiguousarray(np.moveaxis(v, 2, 0))
    if v.ndim == 3 and v.shape[1:] == (3, 3):
        return np.ascontiguousarray(v)
    if v.size == 0:
        return np.zeros((0, 3, 3))
    raise InputError(f"variable {name!r} must be 3x3xK, got shape {v.shape}", path)


# --------------------------------------------------------------------------- g2o

_G2O_EDGE = "EDGE_SE3:QUAT"
_G2O_VERTEX = "VERTEX_SE3:QUAT"


class _LineIndex:
    """Byte offsets of the lines of a text (numbered as ``str.splitlines`` numbers them),
    so that lines can be picked out and parsed without a Python object per line."""

    def __init__(self, text: str):
        if not _simple_line_breaks(text):
            text = "\n".join(text.splitlines())
        self.raw = text.encode("utf-8")
        self.data = np.frombuffer(self.raw, dtype=np.uint8)
        nl = np.flatnonzero(self.data == 10)
        self.starts = np.concatenate(([0], nl + 1))
        self.ends = np.concatenate((nl, [len(self.raw)]))
        if not self.raw or self.raw.endswith(b"\n"):
            self.starts, self.ends = self.starts[:-1], self.ends[:-1]

    def __len__(self) -> int:
        return len(self.starts)

    def line(self, k: int) -> str:
        return self.raw[self.starts[k]:self.ends[k]].decode("utf-8")

    def starting_with(self, tag: str) -> np.ndarray:
        """Mask of the lines that begin with ``tag`` followed by a space or a tab."""
        t = np.frombuffer(tag.encode(), dtype=np.uint8)
        mask = (self.ends - self.starts) > len(t)
        idx = np.flatnonzero(mask)
        s = self.starts[idx]
        hit = np.ones(len(idx), dtype=bool)
        for c, byte in enumerate(t.tolist()):
            hit &= self.data[s + c] == byte
        sep = self.data[s + len(t)]
        hit &= (sep == 32) | (sep == 9)
        out = np.zeros(len(self), dtype=bool)
        out[idx[hit]] = True
        return out

    def join(self, idx: np.ndarray) -> bytes:
        """The lines ``idx`` (sorted) as one text; runs of consecutive lines are one slice."""
        if len(idx) == 0:
            return ""
        brk = np.flatnonzero(np.diff(idx) != 1)
        first = np.concatenate(([0], brk + 1))
        last = np.concatenate((brk, [len(idx) - 1]))
        parts = [self.raw[a:b] for a, b in zip(self.starts[idx[first]].tolist(), self.ends[idx[last]].tolist())]
        return b"\n".join(parts)


def _read_g2o(path: Path, duplicates: str) -> ViewGraph:
    text = read_text(path)
    spath = str(path)
    lines = _LineIndex(text)
    del text
    # The two common tags are found with vectorised byte compares; the other lines (few:
    # comments, FIX, indented lines, ...) are looked at one by one.
    is_e = lines.starting_with(_G2O_EDGE)
    is_v = lines.starting_with(_G2O_VERTEX)
    skipped: dict[str, int] = {}
    for k in np.flatnonzero(~(is_e | is_v)).tolist():
        s = lines.line(k).strip()
        if not s or s.startswith("#"):
            continue
        tag = s.split(None, 1)[0]
        if tag == _G2O_EDGE:
            is_e[k] = True
        elif tag == _G2O_VERTEX:
            is_v[k] = True
        elif tag in _G2O_SKIPPED:
            skipped[tag] = skipped.get(tag, 0) + 1
        elif tag.startswith(("EDGE_SE2", "VERTEX_SE2")):
            raise InputError(f"2D pose graphs are not supported ({tag})", spath, k + 1)
        else:
            raise InputError(f"unknown g2o tag {tag[:40]!r} (rotgraph reads VERTEX_SE3:QUAT and EDGE_SE3:QUAT)", spath, k + 1)
    if skipped:
        logger.warning("%s: skipped %s", spath, ", ".join(f"{n} {t} line(s)" for t, n in skipped.items()))
    e_idx = np.flatnonzero(is_e)
    v_idx = np.flatnonzero(is_v)
    if len(e_idx) == 0:
        raise InputError("no edges (no EDGE_SE3:QUAT lines)", spath)

    e_what = "EDGE_SE3:QUAT i j x y z qx qy qz qw + 21 information entries"
    ij, eq = _g2o_rows(lines, e_idx, spath, ids=2, nfields=31, what=e_what)
    vid, vq = _g2o_rows(lines, v_idx, spath, ids=1, nfields=9, what="VERTEX_SE3:QUAT id x y z qx qy qz qw")
    e_lines, v_lines = e_idx + 1, v_idx + 1

    # file (x, y, z, w) -> rotgraph (w, x, y, z)
    Qe = so3.matrices_from_quaternions(_unit_quaternions(eq[:, [3, 0, 1, 2]], e_lines, spath))
    rel = np.swapaxes(Qe, 1, 2)  # edge rotation Q_ij = Q_i^T Q_j (world_from_body): R_ij = Q_ij^T
    vid = vid[:, 0]
    order = np.argsort(vid, kind="stable")
    dup = np.flatnonzero(vid[order][1:] == vid[order][:-1])
    if len(dup):
        k = int(order[dup[0] + 1])
        raise InputError(f"vertex {int(vid[k])} is defined twice", spath, int(v_lines[k]))
    edge_nodes = _unique(ij)
    node_ids = _unique(np.concatenate([vid, edge_nodes]))
    if len(vid) and len(node_ids) > len(vid):
        logger.warning("%s: %d camera(s) appear in edges without a VERTEX_SE3:QUAT line", spath, len(node_ids) - len(vid))
    codes = np.searchsorted(node_ids, ij)
    graph = _graph(path, e_lines, node_ids, codes[:, 0], codes[:, 1], rel, None, duplicates)
    if len(vid):
        Qv = so3.matrices_from_quaternions(_unit_quaternions(vq[:, [3, 0, 1, 2]], v_lines, spath))
        gt = np.full((graph.n_nodes, 3, 3), np.nan)
        gt[np.searchsorted(graph.node_ids, vid)] = np.swapaxes(Qv, 1, 2)  # R_i = Q_i^T
        graph.gt_cam_from_world = gt
        graph.meta["g2o_vertices_are_initial_guess"] = True
    if skipped:
        graph.meta["g2o_skipped_lines"] = dict(skipped)
    return graph


def _g2o_rows(lines: _LineIndex, idx: np.ndarray, path, *, ids: int, nfields: int, what: str):
    """Ids ``(K, ids)`` int64 and quaternions ``(K, 4)`` (x, y, z, w, as in the file) of the
    g2o lines ``idx``. The translation is parsed (any float), the fields after the
    quaternion are counted, not parsed."""
    if len(idx) == 0:
        return np.zeros((0, ids), np.int64), np.zeros((0, 4))
    rest = nfields - 1 - ids - 7
    fields = [("tag", "S1"), ("ids", "i8", (ids,)), ("t", "f8", (3,)), ("q", "f8", (4,))]
    if rest:
        fields.append(("rest", "S1", (rest,)))
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            arr = np.loadtxt(io.BytesIO(lines.join(idx)), dtype=np.dtype(fields), comments=None, ndmin=1,
                             quotechar=None, encoding="utf-8")
        ok = len(arr) == len(idx) and arr["ids"].min() >= 0 and np.isfinite(arr["q"]).all()
    except (ValueError, TypeError, OverflowError):
        ok = False
    if ok:
        return arr["ids"].reshape(-1, ids), arr["q"].reshape(-1, 4)
    return _g2o_rows_slow(lines, idx, path, ids=ids, nfields=nfields, what=what)


def _g2o_rows_slow(lines: _LineIndex, idx: np.ndarray, path, *, ids: int, nfields: int, what: str):
    """:func:`_g2o_rows` line by line, to name the first bad line."""
    out_ids = np.empty((len(idx), ids), np.int64)
    out_q = np.empty((len(idx), 4))
    names = ["vertex id"] * ids + ["x", "y", "z", "qx", "qy", "qz", "qw"]
    for r, k in enumerate(idx.tolist()):
        ln = k + 1
        f = lines.line(k).split()
        if len(f) != nfields:
            raise InputError(f"expected {nfields} fields ({what}), got {len(f)}", path, ln)
        for c in range(ids + 7):
            tok, name = f[1 + c], names[c]
            if c < ids:
                if not (tok.isascii() and tok.isdigit()) or int(tok) > _INT64_MAX:
                    raise InputError(f"{name} must be a non-negative 64-bit integer, got {tok[:40]!r}", path, ln)
                out_ids[r, c] = int(tok)
                continue
            try:
                v = float(tok)
            except ValueError:
                raise InputError(f"{name} is not a number: {tok[:40]!r}", path, ln) from None
            if c >= ids + 3:
                if not math.isfinite(v):
                    raise InputError(f"{name} is not finite ({tok})", path, ln)
                out_q[r, c - ids - 3] = v
    return out_ids, out_q


# =========================================================================== absolute rotations


def read_absolute_rotations(path, fmt: str = "auto") -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """Read absolute rotations (ground truth or an estimate): ``(ids, names, cam_from_world)``.

    Formats (:data:`ROTATION_FORMATS`):

    * ``csv`` - a header with ``qw,qx,qy,qz`` and ``id`` and/or ``name`` (other columns
      are ignored): the ``rotgraph solve`` output ``id,name,qw,qx,qy,qz[,...]`` or e.g.
      ``name,qw,qx,qy,qz``. Without an ``id`` column the ids are the names.
    * ``text`` - ``id qw qx qy qz`` or ``id name qw qx qy qz`` lines (one layout per file;
      ``#`` comments). ``id`` may be a name (GLOMAP's rotation output ``NAME QW QX QY QZ``).
    * ``bundler`` - a Bundler v0.3 file (``gt_bundle.out``): cameras ``0..N-1`` with a
      nonzero rotation, converted to the computer-vision frame (``D R``, see ``1dsfm``).
    * ``mat``, ``g2o``, ``1dsfm`` - the ground truth inside those inputs (via
      :func:`read_view_graph`; for ``g2o`` these are the vertices' initial guesses).

    Quaternions are ``(w, x, y, z)`` of ``cam_from_world`` and are normalised. Ids are
    int64 when all are non-negative integers, else strings; duplicate ids are an error.
    """
    if fmt not in ROTATION_FORMATS:
        raise ValueError(f"unknown format {fmt!r}; expected one of {', '.join(ROTATION_FORMATS)}")
    p = Path(path)
    if fmt == "auto":
        fmt = _detect_rotation_format(p)
    if fmt == "colmap":
        from .colmap import read_colmap_model_rotations

        return read_colmap_model_rotations(p)
    if fmt in ("mat", "g2o", "1dsfm"):
        graph = read_view_graph(p, fmt, duplicates="keep")
        gt = graph.gt_cam_from_world
        has = np.zeros(graph.n_nodes, bool) if gt is None else np.isfinite(gt).all(axis=(1, 2))
        if not has.any():
            raise InputError(f"no absolute rotations (ground truth) in this {fmt} input", str(path))
        if fmt == "g2o":
            logger.info("%s: g2o vertex rotations are initial guesses, not ground truth", path)
        names = None if graph.names is None else graph.names[has]
        return graph.node_ids[has], names, gt[has]
    if fmt == "bundler":
        R = _read_bundler(p)
        has = np.isfinite(R).all(axis=(1, 2))
        if not has.any():
            raise InputError("no registered camera (every rotation is zero)", str(path))
        return np.flatnonzero(has).astype(np.int64), None, R[has]
    text = read_text(p)
    if fmt == "csv":
        header, start, hline = _csv_header(p, text, ("qw", "qx", "qy", "qz"))
        if "id" not in header and "name" not in header:
            raise InputError("CSV header needs an 'id' or a 'name' column", str(p), hline)
        kinds = tuple(
            "id" if h == "id" else "name" if h == "name" else "f" if h in ("qw", "qx", "qy", "qz") else "skip"
            for h in header
        )
        table = _read_table(p, text, counts=(len(header),), kinds=kinds, names=tuple(header),
                            what=f"as in the header, {','.join(header)}"[:120], sep=",", start=start)
        if len(table) == 0:
            raise InputError("no rotations after the CSV header", str(p), hline)
        col = {h: table.cols[c] for c, h in enumerate(header)}
        names = col.get("name")
        ids = col["id"] if "id" in col else names
        q = np.stack([col[c] for c in ("qw", "qx", "qy", "qz")], axis=1)
    else:
        first = _first_data_line(text)
        if first is None:
            raise InputError("no rotations (expected lines 'id qw qx qy qz' or 'id name qw qx qy qz')", str(p))
        nf = len(first[2].split())
        if nf not in (5, 6):
            raise InputError(f"expected 5 fields 'id qw qx qy qz' or 6 'id name qw qx qy qz', got {nf}", str(p), first[0])
        kinds = ("id",) + (("name",) if nf == 6 else ()) + ("f",) * 4
        names_ = ("id",) + (("name",) if nf == 6 else ()) + ("qw", "qx", "qy", "qz")
        table = _read_table(p, text, counts=(nf,), kinds=kinds, names=names_, what=" ".join(names_))
        ids = table.cols[0]
        names = table.cols[1] if nf == 6 else None
        q = table.floats(nf - 4, nf)
    q = _unit_quaternions(q, table.lines, str(p))
    order = np.argsort(ids, kind="stable")
    dup = np.flatnonzero(ids[order][1:] == ids[order][:-1])
    if len(dup):
        k = int(order[dup[0] + 1])
        raise InputError(f"camera {ids[k].item()!r} appears twice", str(p), int(table.lines[k]))
    return ids, names, so3.matrices_from_quaternions(q)


def _detect_rotation_format(p: Path) -> str:
    if p.is_dir():
        return detect_format(p)
    if p.parent.is_dir() and p.suffix.lower() in (".bin", ".txt") and p.stem in ("cameras", "images", "points3D", "rigs", "frames"):
        if _is_colmap(p.parent):
            return "colmap"  # a file inside a sparse model: the model
    if not p.exists():
        raise InputError("no such file", path=str(p))
    ext = p.suffix.lower()
    head = _sniff(p)
    if ext in (".mat", ".g2o", ".db") or p.name.lower() == "egs.txt" or head.startswith((b"MATLAB", b"\x89HDF", b"SQLite format 3\x00")):
        return detect_format(p)
    if head.lstrip().startswith(b"# Bundle file"):
        return "bundler"
    first = _first_data_line(head.decode("utf-8-sig", errors="replace"))
    if first is not None and first[2].split()[0].startswith(("VERTEX_", "EDGE_")):
        return "g2o"
    if ext == ".csv" or (first is not None and "," in first[2]):
        return "csv"
    return "text"


# =========================================================================== writers


def _id_strings(ids, what: str, *, csv_field: bool) -> list[str]:
    """Ids/names as text; in a white-space format they must be non-empty, without white
    space and not start with '#'; in CSV they are quoted when needed."""
    a = np.asarray(ids)
    if a.dtype.kind in "iu":
        return a.astype(str).tolist()
    out = [str(x) for x in a.tolist()]
    distinct = set(out)  # check (and quote) each distinct id once
    if csv_field:
        quoted = {s: _csv_quote(s) for s in distinct}
        return [quoted[s] for s in out] if any(quoted[s] != s for s in distinct) else out
    for s in distinct:
        if not s or any(ch.isspace() for ch in s) or s.startswith("#"):
            raise ValueError(
                f"{what} {s!r} cannot be written in a white-space separated file (empty, white space or leading '#')"
            )
    return out


def _csv_quote(s: str) -> str:
    if not s or s != s.strip() or s.startswith("#") or any(ch in s for ch in ',"\n\r'):
        return '"' + s.replace('"', '""') + '"'
    return s


def _float_strings(x) -> list[str]:
    return [repr(v) for v in np.asarray(x, dtype=np.float64).tolist()]  # Python floats: shortest round-trip repr


def _rotations_array(R, n: int | None = None) -> np.ndarray:
    R = np.asarray(R, dtype=np.float64)
    if R.ndim != 3 or R.shape[1:] != (3, 3) or (n is not None and len(R) != n):
        raise ValueError(f"expected ({n if n is not None else 'N'}, 3, 3) rotations, got {R.shape}")
    bad = ~np.isfinite(R).all(axis=(1, 2))
    if bad.any():
        raise ValueError(f"rotations must be finite ({int(bad.sum())} of {len(R)} are not: leave those cameras out)")
    return R


def write_rotations(path, ids, names, cam_from_world, extra_columns: dict | None = None) -> None:
    """Write ``id,name,qw,qx,qy,qz[,extra...]`` (the ``rotgraph solve`` output), atomically.

    One row per camera; the quaternion is ``cam_from_world`` with ``w >= 0``, floats at full
    precision (shortest round-trip repr). ``name`` is the id when ``names`` is None.
    ``extra_columns`` maps column names to ``(N,)`` arrays (floats as repr, bools as 0/1).
    """
    ids = np.asarray(ids)
    n = len(ids)
    R = _rotations_array(cam_from_world, n)
    if names is not None and len(names) != n:
        raise ValueError(f"expected {n} names, got {len(names)}")
    extra = dict(extra_columns or {})
    for key, val in extra.items():
        if key in ("id", "name", "qw", "qx", "qy", "qz") or not key or any(ch in key for ch in ',"\n\r'):
            raise ValueError(f"bad extra column name {key!r}")
        if len(val) != n:
            raise ValueError(f"extra column {key!r} has {len(val)} values, expected {n}")
    q = so3.quaternions_from_matrices(R)
    cols = [_id_strings(ids, "id", csv_field=True), _id_strings(ids if names is None else names, "name", csv_field=True)]
    cols += [_float_strings(q[:, c]) for c in range(4)]
    cols += [_value_strings(v) for v in extra.values()]
    header = ",".join(["id", "name", "qw", "qx", "qy", "qz", *extra.keys()])
    with atomic_write(path) as fh:
        fh.write(header + "\n")
        fh.writelines(",".join(row) + "\n" for row in zip(*cols))


def _value_strings(v) -> list[str]:
    a = np.asarray(v)
    if a.dtype.kind == "b":
        return [str(int(x)) for x in a.tolist()]
    if a.dtype.kind == "f":
        return _float_strings(a)
    return [_csv_quote(str(x)) for x in a.tolist()]


def write_edges(path, graph_or_ids_i, ids_j=None, cam2_from_cam1=None, weights=None) -> None:
    """Write edges in the ``rotgraph`` text format (``# i j qw qx qy qz weight``), atomically.

    Pass a :class:`~rotgraph.viewgraph.ViewGraph`, or the arrays ``ids_i``, ``ids_j``,
    ``cam2_from_cam1`` (``R_ij = R_j R_i^T``) and optionally ``weights`` (default 1).
    Quaternions have ``w >= 0``; ids must be non-negative integers or names without white
    space (string ids made only of digits are read back as integers).
    """
    if isinstance(graph_or_ids_i, ViewGraph):
        g = graph_or_ids_i
        ids_i, ids_j = g.node_ids[g.edges[:, 0]], g.node_ids[g.edges[:, 1]]
        rel, w = g.cam2_from_cam1, g.weights
    else:
        ids_i, rel, w = graph_or_ids_i, cam2_from_cam1, weights
        if ids_j is None or rel is None:
            raise ValueError("write_edges needs a ViewGraph or ids_i, ids_j and cam2_from_cam1")
    ids_i, ids_j = np.asarray(ids_i), np.asarray(ids_j)
    m = len(ids_i)
    if len(ids_j) != m:
        raise ValueError(f"expected {m} ids_j, got {len(ids_j)}")
    rel = _rotations_array(rel, m)
    w = np.ones(m) if w is None else np.asarray(w, dtype=np.float64)
    if w.shape != (m,):
        raise ValueError(f"expected ({m},) weights, got {w.shape}")
    q = so3.quaternions_from_matrices(rel)
    cols = [_id_strings(ids_i, "id", csv_field=False), _id_strings(ids_j, "id", csv_field=False)]
    cols += [_float_strings(q[:, c]) for c in range(4)] + [_float_strings(w)]
    with atomic_write(path) as fh:
        fh.write("# i j qw qx qy qz weight\n")
        fh.writelines(" ".join(row) + "\n" for row in zip(*cols))


def write_edges_csv(path, ids_i, ids_j, residual_deg, inlier) -> None:
    """Write ``i,j,residual_deg,inlier`` (``--edges-out``; inlier as 0/1), atomically."""
    ids_i, ids_j = np.asarray(ids_i), np.asarray(ids_j)
    res = np.asarray(residual_deg, dtype=np.float64)
    inl = np.asarray(inlier)
    m = len(ids_i)
    if not (len(ids_j) == len(res) == len(inl) == m):
        raise ValueError(f"expected {m} values in every column, got {len(ids_j)}, {len(res)}, {len(inl)}")
    cols = [_id_strings(ids_i, "id", csv_field=True), _id_strings(ids_j, "id", csv_field=True), _float_strings(res),
            ["1" if bool(x) else "0" for x in inl.tolist()]]
    with atomic_write(path) as fh:
        fh.write("i,j,residual_deg,inlier\n")
        fh.writelines(",".join(row) + "\n" for row in zip(*cols))


def write_absolute_rotations_text(path, ids, cam_from_world) -> None:
    """Write ``id qw qx qy qz`` lines (cam_from_world, ``w >= 0``; e.g. ``rotgraph synth``'s
    gt.txt) after a ``#`` header line, atomically."""
    ids = np.asarray(ids)
    R = _rotations_array(cam_from_world, len(ids))
    q = so3.quaternions_from_matrices(R)
    cols = [_id_strings(ids, "id", csv_field=False)] + [_float_strings(q[:, c]) for c in range(4)]
    with atomic_write(path) as fh:
        fh.write("# id qw qx qy qz (cam_from_world)\n")
        fh.writelines(" ".join(row) + "\n" for row in zip(*cols))
