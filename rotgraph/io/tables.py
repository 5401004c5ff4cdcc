"""Text tables: the one parser behind every text reader of :mod:`rotgraph.io`.

A table is a text file of data lines: blank lines and lines whose first non-blank
character is ``#`` are skipped (a ``#`` later in a line is data); fields are split on
white space, or on commas for CSV (fields stripped, CSV quoting ``"a,b"`` understood).
:func:`read_table` parses its columns into arrays, keeping each data line's 1-based line
number (numbered as ``str.splitlines`` numbers them), and raises
:class:`~rotgraph.errors.InputError` naming the file and the line of the first bad field:
wrong field count, not a number, NaN or infinite, negative or too large integer, empty id.

Speed: :func:`read_table_file` (:mod:`rotgraph.io.table_stream`) streams a clean white-space
(or CSV) table straight from its file through pyarrow's CSV parser (blocks of :data:`STREAM_BLOCK`
bytes: peak memory is the arrays, not the text; 10^7 edge lines, 0.9 GB: the table in 6-8 s,
the whole read into a graph in ~12 s on a 2-core machine loaded by other jobs, where
np.loadtxt alone took 9-15 s); anything it does not read exactly as the line-by-line parser
would makes it give up (None) and the caller reads the text with :func:`read_table`.
There a clean table is read by one ``np.loadtxt`` pass with a structured dtype (one C pass; about 4 s for 10^6 edge lines), and ids are indexed by sorting (numpy >= 2.3's
hash-based ``np.unique`` is ~10x slower on 10^6 ids; dense integer ids by a presence table). Only when that pass fails does the
line-by-line parser run; it is the reference for what is an error where.
"""

from __future__ import annotations

import csv
import io
import warnings

import numpy as np

from ..errors import InputError
# The table's pieces live in their own modules (their public names are names of this one too):
# the lines (table_lines), the columns and ids (table_columns), the streamed reader (table_stream).
from .table_columns import INT64_MAX, Table, resolve_id_columns, resolve_ids, unique  # noqa: F401
from .table_lines import comment_line_numbers, data_line_numbers, first_data_line, simple_line_breaks  # noqa: F401
from .table_stream import STREAM_BLOCK, read_table_file  # noqa: F401

__all__ = [
    "INT64_MAX", "Table", "first_data_line", "resolve_ids", "simple_line_breaks", "unique", "split_csv", "csv_header", "read_table",
    "read_csv_table", "symmetric_from_upper", "read_table_file", "STREAM_BLOCK",
]


def symmetric_from_upper(upper, n: int) -> np.ndarray:
    """Symmetric ``(M, n, n)`` matrices from their upper triangles ``(M, n (n + 1) / 2)``,
    row-major (``a_00 a_01 .. a_0n a_11 ..``: the order of ``np.triu_indices``, of the
    information entries of g2o and of rotgraph's ``h_xx h_xy h_xz h_yy h_yz h_zz``); a
    list of ``(M,)`` columns (e.g. from :attr:`Table.cols`) is stacked first."""
    upper = np.asarray(upper if isinstance(upper, np.ndarray) else np.stack(upper, axis=1), dtype=np.float64)
    r, c = np.triu_indices(n)
    if upper.ndim != 2 or upper.shape[1] != len(r):
        raise ValueError(f"expected (M, {len(r)}) upper triangles, got {upper.shape}")
    where = np.empty((n, n), dtype=np.int64)  # the entry of the upper triangle each cell takes
    where[r, c] = where[c, r] = np.arange(len(r))
    return upper[:, where.ravel()].reshape(-1, n, n)


def split_csv(s: str) -> list[str]:
    """The fields of one CSV line (CSV quoting only when the line has a quote)."""
    return next(csv.reader([s])) if '"' in s else s.split(",")


def csv_header(path, text, required, optional=(), hint=None) -> tuple[list[str], int, int]:
    """The header of a CSV table naming at least ``required``: ``(lower-case column names,
    offset after the header line, header line number)``; a missing or twice-named column is
    an :class:`InputError` at the header line (``hint(nfields)`` adds advice to the
    message of missing columns)."""
    first = first_data_line(text)
    if first is None:
        raise InputError(f"empty file, expected a CSV header {','.join(required)}", str(path), None)
    number, end, line = first
    header = [h.strip().lower() for h in split_csv(line)]
    missing = [c for c in required if c not in header]
    if missing:
        advice = hint(len(header)) if hint is not None else ""
        raise InputError(f"CSV header lacks column(s) {', '.join(missing)} (header: {line[:80]!r}){advice}", str(path), number)
    dup = [h for h in set(header) if header.count(h) > 1 and h in tuple(required) + tuple(optional)]
    if dup:
        raise InputError(f"CSV header names column {dup[0]!r} twice", str(path), number)
    return header, min(end + 1, len(text)), number


def read_csv_table(path, text, required, optional=(), *, kinds=None, noun: str, require_any=(),
                   all_or_none=(), hint=None) -> tuple[list[str], Table]:
    """A CSV table with a header: ``(lower-case column names, table)``.

    The header (:func:`csv_header`) must name every column in ``required`` and, when
    ``require_any`` is given, one of those, and of each group of optional columns in
    ``all_or_none`` (tuples of names) all or none; ``kinds`` maps column names to their kind (see
    :func:`read_table`; default ``f`` for the ``required`` and ``optional`` columns, other
    columns are skipped: their array is None). No data row after the header is an
    :class:`InputError` "no ``noun`` after the CSV header" at the header line. ``hint``:
    see :func:`csv_header`.
    """
    header, start, hline = csv_header(path, text, required, optional, hint=hint)
    if require_any and not any(c in header for c in require_any):
        what = " or ".join(f"{'an' if c[0] in 'aeiou' else 'a'} {c!r}" for c in require_any)
        raise InputError(f"CSV header needs {what} column", str(path), hline)
    for group in all_or_none:
        missing = [c for c in group if c not in header]
        if missing and len(missing) < len(group):
            raise InputError(
                f"CSV header lacks column(s) {', '.join(missing)} (the columns {','.join(group)} come all or none)",
                str(path), hline,
            )
    kinds = kinds or {}
    numeric = tuple(required) + tuple(optional)
    table = read_table(
        path, text, counts=(len(header),), names=tuple(header), sep=",", start=start,
        kinds=tuple(kinds.get(h, "f" if h in numeric else "skip") for h in header),
        what=f"as in the header, {','.join(header)}"[:120],
    )
    if len(table) == 0:
        raise InputError(f"no {noun} after the CSV header", str(path), hline)
    return header, table


def _count_text(counts) -> str:
    counts = sorted(counts)
    return str(counts[0]) if len(counts) == 1 else " or ".join(str(c) for c in counts)


_LOADTXT_DTYPE = {"int": "i8", "f": "f8", "u": "f8", "name": "O", "skip": "S1"}


def read_table(path, text, *, counts, kinds, names, what, defaults=None, sep=None, start=0, line_of=None,
               hint=None) -> Table:
    """Parse the data lines of ``text`` (the contents of ``path``; str, or UTF-8 bytes) after
    offset ``start`` (a line start, e.g. after a CSV header).

    ``kinds[c]`` says what column ``c`` holds: ``id`` (non-negative integer or name: one
    decision for all ``id`` columns of the file: int64 when every id is a run of ASCII
    digits, else str), ``int`` (non-negative integer), ``name`` (string), ``f`` (finite
    float), ``u`` (float, not checked: unused) or ``skip`` (not parsed; its column is None).
    Rows may have any field count in ``counts``; columns missing from a short row take
    ``defaults[c]``. ``names[c]`` names column ``c`` and ``what`` describes a line in
    messages. ``sep=None`` splits on white space, ``sep=","`` is CSV. ``line_of`` (when
    ``text`` is a selection of the file's lines) gives the file line of each line of
    ``text``: ``line_of[k - 1]`` for line ``k``. ``hint(nfields)`` (optional) adds advice to
    the message of a wrong field count on the first data line or of more fields than any of
    ``counts`` (e.g. how to name the columns of a table of another layout).

    Errors name the first bad line (and on it the first bad field).
    """
    defaults = defaults or {}
    if isinstance(text, str):  # the fast pass works on the UTF-8 bytes np.loadtxt reads
        data, start_b = text.encode("utf-8"), len(text[:start].encode("utf-8"))
    else:
        data, start_b = text, start
    start_line = data.count(b"\n", 0, start_b)
    first = first_data_line(data, start_b)
    if first is None:
        return Table([], [None if k == "skip" else np.zeros(0) for k in kinds], np.zeros(0, np.int64))
    _, _, line0 = first
    fields0 = line0.split() if sep is None else line0.split(sep.encode())
    fast = (
        len(fields0) in counts
        and simple_line_breaks(data)
        and not (sep is not None and b'"' in data)
    )
    comments = comment_line_numbers(data) if fast else None
    if comments is not None:
        ncol = len(fields0)
        has_ids = "id" in kinds[:ncol]
        ids_look_int = all(fields0[c].strip().isdigit() for c in range(ncol) if kinds[c] == "id")
        for id_dtype in (("i8", "O") if has_ids and ids_look_int else ("O",) if has_ids else ("i8",)):
            table = _fast_table(path, data, kinds[:ncol], names, id_dtype, sep, start_line, comments, defaults,
                                len(kinds), line_of)
            if table is not None:
                return table
    if isinstance(text, bytes):
        text = text.decode("utf-8")
    return _slow_table(path, text, counts=counts, kinds=kinds, names=names, what=what, defaults=defaults, sep=sep,
                       start_line=start_line, line_of=line_of, hint=hint)


def _raise_first(errors: list[tuple[int, int, InputError]]) -> None:
    """Raise the error of the first line (and column) among ``(line, column, error)``."""
    if errors:
        raise min(errors, key=lambda e: e[:2])[2]


def _fast_table(path, data: bytes, kinds, names, id_dtype, sep, skiprows, comments, defaults, nkinds, line_of) -> Table | None:
    """One np.loadtxt pass over ``data`` (UTF-8) after its first ``skiprows`` lines; None when
    it fails (bad data or a layout it cannot read)."""
    dtype = np.dtype([(f"c{c}", id_dtype if k == "id" else _LOADTXT_DTYPE[k]) for c, k in enumerate(kinds)])
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "input contained no data"
            arr = np.loadtxt(io.BytesIO(data), dtype=dtype, delimiter=sep, comments="#" if comments else None,
                             skiprows=skiprows, ndmin=1, quotechar=None, encoding="utf-8")
    except (ValueError, TypeError, OverflowError):
        return None
    header = [c for c in comments if c <= skiprows]
    lines = data_line_numbers(data, comments, len(arr) + skiprows - len(header))
    if lines is None:
        return None
    lines = lines[len(lines) - len(arr):]
    if line_of is not None:
        lines = np.asarray(line_of, dtype=np.int64)[lines - 1]
    cols: list[np.ndarray | None] = []
    id_cols = []
    errors: list[tuple[int, int, InputError]] = []
    for c, kind in enumerate(kinds):
        col = arr[f"c{c}"]
        if kind == "skip":
            col = None
        elif kind == "name" or (kind == "id" and id_dtype == "O"):
            col = col.astype(str) if len(col) else np.zeros(0, dtype=str)
            if sep is not None:  # CSV fields may be padded
                col = np.char.strip(col)
        elif kind == "f":
            bad = ~np.isfinite(col)
            if bad.any():
                r = int(np.argmax(bad))
                errors.append((int(lines[r]), c, InputError(f"{names[c]} is not finite ({col[r]})", path, int(lines[r]))))
        elif kind == "int" and len(col) and col.min() < 0:
            r = int(np.argmax(col < 0))
            errors.append((int(lines[r]), c, InputError(f"{names[c]} must be a non-negative integer, got {col[r]}", path, int(lines[r]))))
        if kind == "id":
            id_cols.append(c)
        cols.append(col)
    if not errors and id_cols and id_dtype == "i8" and any(len(cols[c]) and cols[c].min() < 0 for c in id_cols):
        return None  # a negative number is a name (see resolve_ids): re-read as strings
    index = resolve_id_columns(cols, id_cols, lines, path, names, errors) if id_cols and id_dtype == "O" else None
    _raise_first(errors)
    for c in range(len(kinds), nkinds):  # optional columns absent from the whole file
        cols.append(np.full(len(arr), float(defaults[c])))
    return Table(lines, cols, np.full(len(arr), len(kinds)), index)


def _slow_table(path, text: str, *, counts, kinds, names, what, defaults, sep, start_line, line_of=None, hint=None) -> Table:
    """The line-by-line parser of the lines after the first ``start_line``: slower, and the
    reference for what is an error where (the first bad line; on it, the first bad field)."""
    numbers: list[int] = []
    rows: list[list[str]] = []
    errors: list[tuple[int, int, InputError]] = []  # (line, column, error): the first bad value per column
    for k, raw in enumerate(text.splitlines(), 1):
        if k <= start_line:
            continue
        s = raw.strip()
        if not s or s.startswith("#"):
            continue
        ln = k if line_of is None else int(line_of[k - 1])
        f = s.split() if sep is None else [x.strip() for x in split_csv(s)]
        if len(f) not in counts:  # the rows before it may hold an earlier error
            advice = hint(len(f)) if hint is not None and (not numbers or len(f) > max(counts)) else ""
            errors.append((ln, -1, InputError(f"expected {_count_text(counts)} fields ({what}), got {len(f)}{advice}", path, ln)))
            break
        numbers.append(ln)
        rows.append(f)
    lines = np.array(numbers, dtype=np.int64)
    nfields = np.array([len(r) for r in rows], dtype=np.int64)
    cols: list[np.ndarray | None] = []
    id_cols = []
    for c, kind in enumerate(kinds):
        vals = [r[c] if c < len(r) else None for r in rows]
        try:
            if kind in ("f", "u"):
                cols.append(_floats(vals, lines, path, names[c], finite=kind == "f", default=defaults.get(c)))
            elif kind == "int":
                cols.append(_nonneg_ints(vals, lines, path, names[c]))
            elif kind == "skip":
                cols.append(None)
            else:
                if kind == "id":
                    id_cols.append(c)
                cols.append(np.array(vals, dtype=str) if vals else np.zeros(0, dtype=str))
        except InputError as exc:
            errors.append((exc.line, c, exc))
            cols.append(None)
    index = None
    if id_cols and len(rows) and all(cols[c] is not None for c in id_cols):
        index = resolve_id_columns(cols, id_cols, lines, path, names, errors)
    _raise_first(errors)
    return Table(lines, cols, nfields, index)


def _floats(vals, lines, path, name, finite=True, default=None) -> np.ndarray:
    if default is not None:
        vals = [repr(float(default)) if v is None else v for v in vals]
    try:
        out = np.array(vals, dtype=np.float64)
    except (ValueError, TypeError):
        out = None
    if out is None:  # the first bad row: not a number, or (before it) not finite
        for ln, v in zip(lines, vals):
            try:
                x = float(v)
            except (ValueError, TypeError):
                raise InputError(f"{name} is not a number: {str(v)[:40]!r}", path, int(ln)) from None
            if finite and not np.isfinite(x):
                raise InputError(f"{name} is not finite ({v})", path, int(ln))
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
        if x > INT64_MAX:
            raise InputError(f"{name} {v[:30]} is too large (must fit in a signed 64-bit integer)", path, int(lines[r]))
        out[r] = x
    return out

