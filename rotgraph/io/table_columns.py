"""The parsed columns of a table (:class:`Table`) and the one decision of what an id is
(:func:`resolve_ids`), shared by the text parser (:mod:`rotgraph.io.tables`), the streamed
one (:mod:`rotgraph.io.table_stream`) and the binary readers; ``unique`` by sorting.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError

__all__ = ["INT64_MAX", "Table", "unique", "resolve_ids", "resolve_id_columns"]

INT64_MAX = 2**63 - 1


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


def resolve_id_columns(cols, id_cols, lines, path, names, errors):
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
