"""Text tables: the one parser behind every text reader of :mod:`rotgraph.io`.

A table is a text file of data lines: blank lines and lines whose first non-blank
character is ``#`` are skipped (a ``#`` later in a line is data); fields are split on
white space, or on commas for CSV (fields stripped, CSV quoting ``"a,b"`` understood).
:func:`read_table` parses its columns into arrays, keeping each data line's 1-based line
number (numbered as ``str.splitlines`` numbers them), and raises
:class:`~rotgraph.errors.InputError` naming the file and the line of the first bad field:
wrong field count, not a number, NaN or infinite, negative or too large integer, empty id.

Speed: :func:`read_table_file` streams a clean white-space (or CSV) table straight from
its file through pyarrow's CSV parser (blocks of :data:`STREAM_BLOCK` bytes: peak memory is the
arrays, not the text; 10^7 edge lines, 0.9 GB: the table in 6-8 s, the whole read into a graph
in ~12 s on a 2-core machine loaded by other jobs, where np.loadtxt alone took 9-15 s);
anything it does not read exactly as the line-by-line parser would (tabs, runs of spaces,
CR line breaks, non-ASCII text, blank lines with spaces, a row of another field count,
a bad or non-finite value, negative ids) makes it give up (None) and the caller reads the
text with :func:`read_table`. There a clean table is read by one ``np.loadtxt`` pass with a structured dtype (one C
pass; about 4 s for 10^6 edge lines), and ids are indexed by sorting (numpy >= 2.3's
hash-based ``np.unique`` is ~10x slower on 10^6 ids; dense integer ids by a presence table). Only when that pass fails does the
line-by-line parser run; it is the reference for what is an error where.
"""

from __future__ import annotations

import csv
import io
import warnings

import numpy as np

from ..errors import InputError
from .compressed import input_head, open_input, read_reporter

__all__ = [
    "INT64_MAX", "Table", "first_data_line", "resolve_ids", "simple_line_breaks", "unique", "split_csv", "csv_header", "read_table",
    "read_csv_table", "symmetric_from_upper", "read_table_file", "STREAM_BLOCK",
]

INT64_MAX = 2**63 - 1


def first_data_line(text: str | bytes, start: int = 0) -> tuple[int, int, str | bytes] | None:
    """``(line number, end offset, stripped line)`` of the first line after offset ``start``
    that is neither blank nor a ``#`` comment, or None: the one sniffer of rotgraph's inputs
    (``start`` must be a line start; line numbers count ``\\n`` only, as in files with
    simple line breaks, see :func:`simple_line_breaks`). ``text`` may be UTF-8 bytes."""
    nl, hash_ = _literals(text)
    number = text.count(nl, 0, start) + 1
    pos = start
    while pos < len(text):
        end = text.find(nl, pos)
        end = len(text) if end < 0 else end
        s = text[pos:end].strip()
        if s and not s.startswith(hash_):
            return number, end, s
        pos, number = end + 1, number + 1
    return None


def _literals(text: str | bytes):
    return ("\n", "#") if isinstance(text, str) else (b"\n", b"#")


# Line breaks of str.splitlines other than \n and \r\n, as text and as UTF-8.
_ODD_BREAKS = ("\x0b", "\x0c", "\x1c", "\x1d", "\x1e")
_ODD_BREAKS_NON_ASCII = ("\x85", "\u2028", "\u2029")


def simple_line_breaks(text: str | bytes) -> bool:
    """Whether ``\\n`` (or ``\\r\\n``) is the only line break, so that counting ``\\n``
    gives the line numbers of ``str.splitlines`` (the line-by-line parser's numbers)."""
    odd = _ODD_BREAKS if text.isascii() else _ODD_BREAKS + _ODD_BREAKS_NON_ASCII
    if isinstance(text, bytes):
        odd = tuple(o.encode("utf-8") for o in odd)
    if any(o in text for o in odd):
        return False
    cr, crlf = ("\r", "\r\n") if isinstance(text, str) else (b"\r", b"\r\n")
    return cr not in text or text.count(cr) == text.count(crlf)


def _comment_lines(text: str | bytes, first_line: int = 1, stop_at_data_hash: bool = False):
    """The ``#`` comment lines of ``text`` (``#`` the first non-blank character of the line):
    ``(number, start, end)`` each (``end`` after its line break; the first line of ``text``
    numbered ``first_line``), and whether some ``#`` stands later in a line (data for the
    line-by-line parser; with ``stop_at_data_hash`` the scan ends there). The one scan behind
    :func:`_comment_line_numbers` and :func:`_strip_comments`."""
    nl, hash_ = _literals(text)
    out: list[tuple[int, int, int]] = []
    line, last, data_hash = first_line, 0, False
    pos = text.find(hash_)
    while pos >= 0:
        start = text.rfind(nl, 0, pos) + 1
        end = text.find(nl, pos)
        end = len(text) if end < 0 else end + 1
        if text[start:pos].strip():
            data_hash = True
            if stop_at_data_hash:
                break
        else:
            line += text.count(nl, last, start)
            last = start
            out.append((line, start, end))
        pos = text.find(hash_, end)
    return out, data_hash


def _comment_line_numbers(text: str | bytes) -> list[int] | None:
    """Line numbers of the ``#`` comment lines, or None if some ``#`` is not the first
    non-blank character of its line (then np.loadtxt's comment handling would differ)."""
    lines, data_hash = _comment_lines(text, stop_at_data_hash=True)
    return None if data_hash else [number for number, _, _ in lines]


_BLANK = np.zeros(256, dtype=bool)
_BLANK[list(b" \t\n\r\x0b\x0c")] = True  # what bytes.strip() strips


def _data_line_numbers(text: bytes, comments: list[int], n_data: int, first_line: int = 1) -> np.ndarray | None:
    """Numbers of the data lines of ``text`` (neither blank nor one of the ``comments``; its
    first line numbered ``first_line``), or None if they are not ``n_data`` lines (the
    caller then falls back to the line-by-line parser): the lines of the rows np.loadtxt or
    pyarrow made of ``text`` (np.loadtxt skips blank lines, pyarrow empty ones and fails on
    a blank one with spaces), when there are as many."""
    total = text.count(b"\n") + (1 if text and not text.endswith(b"\n") else 0)
    if not comments and total == n_data:  # every line is data
        return np.arange(first_line, first_line + total, dtype=np.int64)
    keep = np.ones(total, dtype=bool)
    if comments:
        keep[np.asarray(comments, dtype=np.int64) - first_line] = False
    if total - len(comments) != n_data and total:  # blank lines too: located (vectorised, rare)
        b = np.frombuffer(text, dtype=np.uint8)
        starts = np.concatenate([[0], np.flatnonzero(b == 10) + 1])[:total]
        keep &= np.logical_or.reduceat(~_BLANK[b], starts)  # a non-blank byte between line starts
    numbers = np.flatnonzero(keep) + first_line
    return numbers if len(numbers) == n_data else None


def unique(a: np.ndarray, return_inverse: bool = False):
    """Sorted distinct values (and the inverse map): np.unique by sorting, which is ~10x
    faster than numpy 2.3+'s hash-based np.unique on 10^6 ids."""
    a = np.asarray(a).ravel()
    if a.dtype.kind in "iu" and len(a):  # dense integer ids (0..n-1 and the like): no sort
        lo, hi = int(a.min()), int(a.max())
        if hi - lo <= 4 * len(a) + 1024:
            off = a - lo if lo else a
            present = np.zeros(hi - lo + 1, dtype=bool)
            present[off] = True
            uniq = (np.flatnonzero(present) + lo).astype(a.dtype, copy=False)
            if not return_inverse:
                return uniq
            code = np.cumsum(present, dtype=np.int64) - 1
            return uniq, code[off]
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


class Table:
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
            uniq, inverse = unique(np.concatenate([self.cols[ci], self.cols[cj]]), return_inverse=True)
            self._index = (uniq, {ci: inverse[: len(self)], cj: inverse[len(self):]})
        uniq, codes = self._index
        return uniq, codes[ci], codes[cj]

    def __len__(self) -> int:
        return len(self.lines)

    def floats(self, a: int, b: int) -> np.ndarray:
        """Columns ``a .. b-1`` (floats) as one ``(M, b - a)`` array."""
        return np.stack(self.cols[a:b], axis=1) if len(self) else np.zeros((0, b - a))


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
    comments = _comment_line_numbers(data) if fast else None
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
    lines = _data_line_numbers(data, comments, len(arr) + skiprows - len(header))
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
    index = _ids(cols, id_cols, lines, path, names, errors) if id_cols and id_dtype == "O" else None
    _raise_first(errors)
    for c in range(len(kinds), nkinds):  # optional columns absent from the whole file
        cols.append(np.full(len(arr), float(defaults[c])))
    return Table(lines, cols, np.full(len(arr), len(kinds)), index)


def _ids(cols, id_cols, lines, path, names, errors):
    """Resolve the id columns of ``cols`` in place (see :func:`resolve_ids`); an error is
    added to ``errors``. Returns the index for :class:`Table`, or None."""
    try:
        resolved, index = resolve_ids([cols[c] for c in id_cols], lines, path, [names[c] for c in id_cols])
    except InputError as exc:
        errors.append((exc.line, id_cols[0], exc))
        return None
    for c, col in zip(id_cols, resolved):
        cols[c] = col
    return None if index is None else (index[0], dict(zip(id_cols, index[1])))


def resolve_ids(cols: list[np.ndarray], lines, path, names, label=None):
    """Id columns as strings -> int64 if every id is a run of ASCII digits, else strings:
    the one decision of what an id is, for every edge reader (text and binary), so that the
    same ids are the same node labels whatever the file.

    An empty id, or a digit id beyond int64, is an :class:`InputError` naming ``path`` and
    the id's ``lines[k]`` (its file line) and/or ``label(k)`` (e.g. ``"edge 5 (0-based)"``),
    ``k`` its row. Returns the columns and, for two id columns, ``(sorted distinct ids,
    [codes per column])`` (see :meth:`Table.index`), else None."""
    both = np.concatenate(cols)
    m = len(cols[0])

    def error(k: int, message: str) -> InputError:
        r = k % m
        where = "" if label is None else f"{label(r)}: "
        return InputError(f"{where}{message}", None if path is None else str(path), None if lines is None else int(lines[r]))

    empty = both == ""
    if empty.any():
        k = int(np.argmax(empty))
        raise error(k, f"empty {names[k // m]}")
    uniq, inverse = unique(both, return_inverse=True)
    values = uniq.tolist()
    if not all(u.isascii() and u.isdigit() for u in values):
        return cols, ((uniq, list(inverse.reshape(len(cols), -1))) if len(cols) == 2 else None)
    ints = [int(u) for u in values]
    big = [u for u, v in zip(values, ints) if v > INT64_MAX]
    if big:
        k = int(np.argmax(both == big[0]))
        raise error(k, f"{names[k // m]} {big[0][:30]} is too large: integer ids must fit in a signed 64-bit integer")
    as_int = np.array(ints, dtype=np.int64)
    # "7" and "007" are the same integer id, so the index is rebuilt from the ints (lazily)
    return list(as_int[inverse].reshape(len(cols), -1)), None


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
        index = _ids(cols, id_cols, lines, path, names, errors)
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


#: Bytes per block of :func:`read_table_file` (a block ends at a line end).
STREAM_BLOCK = 1 << 24


def _strip_comments(blk: bytes, first_line: int) -> tuple[bytes, list[int]] | None:
    """``blk`` without its ``#`` comment lines (``#`` the first non-blank character; a
    later ``#`` is data), and the numbers of the lines removed; None for a block with many
    ``#`` (names holding ``#``: the caller gives up)."""
    if b"#" not in blk:
        return blk, []
    if blk.count(b"#") > 1000:
        return None
    lines, _ = _comment_lines(blk, first_line)
    parts, last = [], 0
    for _, start, end in lines:
        parts.append(blk[last:start])
        last = end
    parts.append(blk[last:])
    return b"".join(parts), [number for number, _, _ in lines]


def read_table_file(path, *, kinds, names, block: int | None = None, sep: str | None = None,
                    header_line: int | None = None) -> Table | None:
    """A clean white-space table of ``len(kinds)`` fields on every data line, streamed from
    the file ``path`` through pyarrow's CSV parser (multithreaded, one block of ``block``
    bytes at a time), or None when the file is not one this fast pass reads exactly as the
    line-by-line parser of :func:`read_table` does (the caller then reads it with that; it
    also finds the errors). ``kinds`` as :func:`read_table` (``id``, ``int``, ``name``,
    ``f``, ``u``, ``skip``); ids are int64 when the first data line's ids are digits (then
    every id must parse), else strings resolved as :func:`read_table` resolves them.
    ``sep=","``: CSV without quotes or blanks in any field, ``header_line`` the number of
    its header line (skipped; the first data line). A gzip, bzip2 or xz file is decompressed
    as it streams, and a large file reports its read progress when asked
    (:mod:`rotgraph.io.compressed`)."""
    block = block or STREAM_BLOCK
    ncol = len(kinds)
    try:
        head = input_head(path, 1 << 16)  # decompressed (rotgraph.io.compressed)
    except OSError:
        return None
    if head.startswith((b"\xef\xbb\xbf", b"\xff\xfe", b"\xfe\xff")):
        return None
    first = first_data_line(head)
    if header_line is not None and first is not None and first[0] == header_line:
        first = first_data_line(head, first[1] + 1) if first[1] < len(head) else None
    split = (lambda b: b.split()) if sep is None else (lambda b: b.split(sep.encode()))
    if first is None or len(split(first[2])) != ncol:
        return None
    fields0 = split(first[2])
    digits = all(fields0[c].isdigit() for c in range(ncol) if kinds[c] == "id")
    try:  # ids that fail int64 after a digit-only first line ("+3", names later): the text parsers' job
        return _stream_table(path, kinds, names, block, digits and "id" in kinds, sep, header_line)
    except OSError:
        return None


def _arrow_types(kinds, cnames: list[str], id_int: bool) -> dict:
    """pyarrow's type of each column read (a ``skip`` column is not read)."""
    import pyarrow as pa

    types = {}
    for c, k in enumerate(kinds):
        if k in ("f", "u"):
            types[cnames[c]] = pa.float64()
        elif k == "int" or (k == "id" and id_int):
            types[cnames[c]] = pa.int64()
        elif k in ("id", "name"):
            types[cnames[c]] = pa.string()
    return types


def _csv_options(cnames: list[str], types: dict, sep) -> dict:
    """The keyword arguments of ``pyarrow.csv.read_csv`` for each block."""
    import pyarrow as pa
    import pyarrow.csv as pacsv

    read_opts = pacsv.ReadOptions(column_names=cnames, use_threads=True, block_size=1 << 22)  # 4 chunks a block
    parse_opts = pacsv.ParseOptions(delimiter=sep or " ", quote_char=False, double_quote=False, escape_char=False,
                                    newlines_in_values=False, ignore_empty_lines=True)
    conv_opts = pacsv.ConvertOptions(column_types=types, null_values=[], strings_can_be_null=False,
                                     quoted_strings_can_be_null=False, include_columns=list(types))
    pool = pa.system_memory_pool()  # malloc: freed chunks go back to the system (the solve needs it)
    return dict(read_options=read_opts, parse_options=parse_opts, convert_options=conv_opts, memory_pool=pool)


def _header_as_comment(blk: bytes, line: int, header_line: int) -> bytes | None:
    """The block ``blk`` (its first line numbered ``line``) with the CSV header line made a
    comment line (same length: the numbering holds); None when that line is blank or a
    comment (no header there)."""
    pos = 0
    for _ in range(header_line - line):
        pos = blk.find(b"\n", pos) + 1
    if blk[pos:pos + 1] in (b"", b"\n", b"\r", b"#"):
        return None
    return blk[:pos] + b"#" + blk[pos + 1:]


def _parse_block(blk: bytes, line: int, sep, csv_options: dict):
    """``(table or None, data line numbers)`` of the block ``blk`` of whole lines (its first
    numbered ``line``), or None when the fast path cannot read it (the text parsers then
    read the file and find the errors)."""
    import pyarrow as pa
    import pyarrow.csv as pacsv

    stripped = _strip_comments(blk, line)
    if stripped is None:
        return None
    data, comments = stripped
    if sep is not None and (b'"' in data or b" " in data or b"\t" in data):
        return None  # CSV quoting, padded fields: the text parsers strip and unquote
    try:
        tbl = pacsv.read_csv(pa.py_buffer(data), **csv_options) if data else None
    except (pa.ArrowInvalid, pa.ArrowNotImplementedError, pa.ArrowTypeError):
        return None
    del data
    numbers = _data_line_numbers(blk, comments, 0 if tbl is None else tbl.num_rows, line)
    return None if numbers is None else (tbl, numbers)


def _columns(kinds, cnames: list[str], pieces: dict, id_int: bool):
    """``(columns, id columns)`` from the blocks' ``pieces`` (emptied as they are joined; a
    ``skip`` column None), or None for a value the fast path leaves to the text parsers (a
    float not finite, a negative integer or id)."""
    cols: list[np.ndarray | None] = []
    id_cols = []
    for c, k in enumerate(kinds):
        if cnames[c] not in pieces:
            cols.append(None)
            continue
        parts = pieces.pop(cnames[c])  # one copy (ChunkedArray.to_numpy is ~10x slower on 10^3 chunks)
        col = np.concatenate(parts) if len(parts) != 1 else parts[0]
        del parts
        if col.dtype == object:
            col = col.astype(str)
        if k == "f" and not np.isfinite(col).all():
            return None
        if (k == "int" or (k == "id" and id_int)) and len(col) and col.min() < 0:
            return None
        if k == "id":
            id_cols.append(c)
        cols.append(col)
    return cols, id_cols


def _stream_table(path, kinds, names, block: int, id_int: bool, sep=None, header_line=None) -> Table | None:
    """:func:`read_table_file`'s pass, with int64 (``id_int``) or string ids."""
    ncol = len(kinds)
    cnames = [f"c{c}" for c in range(ncol)]
    with open_input(path, fast=True) as fh:  # gzip, bzip2, xz: decompressed as it is read
        report = read_reporter(fh)  # read progress of a large file, when asked for (rotgraph.io.compressed)
        if report is not None:
            block = min(block, 1 << 22)  # a progress bar that moves: 4 MiB a step (the same table)
        types = _arrow_types(kinds, cnames, id_int)
        csv_options = _csv_options(cnames, types, sep)
        pieces: dict[str, list] = {c: [] for c in types}
        line_pieces: list[np.ndarray] = []
        line, pending, at_eof = 1, b"", False
        while not at_eof:
            chunk = fh.read(block)
            at_eof = not chunk
            if report is not None:
                report(done=at_eof)
            blk = pending + chunk
            del chunk
            if not at_eof:
                cut = blk.rfind(b"\n") + 1
                if cut == 0:  # no line end yet: read on
                    pending = blk
                    continue
                blk, pending = blk[:cut], blk[cut:]
            else:
                pending = b""
            if not blk:
                continue
            if b"\0" in blk or not blk.isascii() or not simple_line_breaks(blk):
                return None
            if header_line is not None and line <= header_line < line + blk.count(b"\n") + (not blk.endswith(b"\n")):
                blk = _header_as_comment(blk, line, header_line)
                if blk is None:
                    return None
            parsed = _parse_block(blk, line, sep, csv_options)
            line += blk.count(b"\n") + (0 if blk.endswith(b"\n") else 1)
            del blk
            if parsed is None:
                return None
            tbl, numbers = parsed
            del parsed  # the table's memory goes with ``del tbl`` below
            if tbl is None:
                continue
            for c in types:  # numeric chunks: views of pyarrow's buffers (no copy yet)
                pieces[c].extend(chunk.to_numpy(zero_copy_only=False) for chunk in tbl.column(c).chunks)
            line_pieces.append(numbers)
            del tbl
    if not line_pieces:
        return None
    lines = np.concatenate(line_pieces)
    del line_pieces
    columns = _columns(kinds, cnames, pieces, id_int)
    if columns is None:
        return None
    cols, id_cols = columns
    index = None
    if id_cols and not id_int:
        errors: list = []
        index = _ids(cols, id_cols, lines, path, names, errors)
        if errors:
            return None
    return Table(lines, cols, np.broadcast_to(np.int64(ncol), (len(lines),)), index)  # read-only, no memory
