"""The binary edge format: the ``rotgraph`` format as arrays (``.npz``) or columns (Parquet,
one file or a folder of parts), one entry per edge (see :mod:`rotgraph.io.edges`, which reads
every edge format and calls :func:`read_binary_edges` for these).

Arrays ``i j qw qx qy qz`` and optionally ``weight`` and ``h_xx h_xy h_xz h_yy h_yz h_zz``
(all six or none); ids integers or strings (read as the text ids are: all digits ->
``int64``). Errors name the file and the edge (0-based row); in a folder of Parquet parts,
the part and the edge's row in it.
"""

from __future__ import annotations

import io
import re
import zipfile
from pathlib import Path

import numpy as np

from .. import so3_checks
from ..viewgraph import ViewGraph
from .compressed import input_bytes, is_compressed
from .formats import PARQUET_PARTS
from .graphs import INFORMATION_TEXT_COLUMNS, checked_rotations, graph_from_codes, no_edges
from .parts import parquet_parts
from .table_columns import resolve_ids, unique
from .tables import symmetric_from_upper

__all__ = ["BINARY_COLUMNS", "BINARY_REQUIRED", "read_binary_edges", "read_parquet_part"]

#: The arrays of the binary edge format (:func:`rotgraph.io.writers.write_edges_npz`).
BINARY_COLUMNS = ("i", "j", "qw", "qx", "qy", "qz", "weight") + INFORMATION_TEXT_COLUMNS


#: The arrays every binary edge file has (then optionally ``weight`` and ``h_xx .. h_zz``).
BINARY_REQUIRED = ("i", "j", "qw", "qx", "qy", "qz")


def read_binary_edges(path: Path, kind: str, duplicates: str) -> ViewGraph:
    """The binary edge format: arrays (npz) or columns (Parquet) ``i j qw qx qy qz`` and
    optionally ``weight`` and ``h_xx h_xy h_xz h_yy h_yz h_zz`` (all six or none), one entry
    per edge; ids integers or strings. Errors name the file and the edge (0-based row).
    ``kind`` :data:`~rotgraph.io.formats.PARQUET_PARTS`: a folder of Parquet parts
    (:func:`_read_parquet_parts`)."""
    if kind == PARQUET_PARTS:
        return _read_parquet_parts(path, duplicates)
    names, cols = _binary_columns(path, kind)
    m = _checked_binary_columns(path, names, cols)
    if m == 0:
        raise no_edges(path, " ".join(BINARY_REQUIRED))
    return _binary_graph(path, cols, m, duplicates, lambda k: f"edge {k} (0-based)")


def _binary_columns(path: Path, kind: str) -> tuple[list, dict]:
    """``(names of all the file's arrays, {name: array} of those of the format)`` of a
    ``.npz`` or Parquet edge file (possibly compressed)."""
    from ..errors import InputError

    source = io.BytesIO(input_bytes(path)) if is_compressed(path) else path  # .npz.gz: decompressed in memory
    try:
        if kind == "npz":
            with np.load(source, allow_pickle=False) as z:
                return list(z.files), {c: z[c] for c in z.files if c in BINARY_COLUMNS}
        import pyarrow.parquet as pq

        tbl = pq.read_table(source)
        return tbl.column_names, {c: tbl.column(c).to_numpy() for c in tbl.column_names if c in BINARY_COLUMNS}
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile) as exc:
        raise InputError(f"cannot read the binary edge file ({kind}): {exc}", str(path)) from None


def _checked_binary_columns(path: Path, names, cols: dict) -> int:
    """The column checks of the binary edge format, on the arrays ``cols`` of one file (or one
    Parquet part; ``names``: all its arrays): the needed ones there, the information all six
    or none, one entry per edge, numbers, ids integers or strings (``cols["i"]``, ``["j"]``
    become int64 or str arrays). Errors name ``path``; returns the number of edges."""
    from ..errors import InputError

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
    for c in ("i", "j"):
        a = cols[c]
        if a.dtype.kind == "u" and m and a.max() > np.iinfo(np.int64).max:
            raise InputError(f"binary edge file: id in {c} too large for a signed 64-bit integer", str(path))
        if a.dtype.kind in "iu":
            cols[c] = a.astype(np.int64, copy=False)
        elif a.dtype.kind in "OSU":
            cols[c] = a.astype(str)
        else:
            raise InputError(f"binary edge file: ids {c} are {a.dtype}, expected integers or strings", str(path))
    if cols["i"].dtype.kind != cols["j"].dtype.kind:
        raise InputError("binary edge file: i and j must both be integers or both strings", str(path))
    return m


def _binary_graph(path: Path, cols: dict, m: int, duplicates: str, label) -> ViewGraph:
    """The view graph of the checked arrays ``cols`` (:func:`_checked_binary_columns`) of
    ``m`` edges: ids as the text ids are (digits -> int64), quaternions, weights and information
    checked; ``label(k)`` names the edge of row ``k`` in messages."""
    from ..errors import InputError

    ids = [cols.pop("i"), cols.pop("j")]
    if ids[0].dtype.kind == "i" and min(int(ids[0].min()), int(ids[1].min())) < 0:
        ids = [np.array(a.astype(str).tolist()) for a in ids]  # integer ids are non-negative (CLI.md): "-1" is a name, as in text
    index = None
    if ids[0].dtype.kind == "U":  # names, or digits: integer ids, as in the text formats
        ids, index = resolve_ids(ids, None, path, ("i", "j"), label=label)
    rel = checked_rotations([cols.pop(c) for c in ("qw", "qx", "qy", "qz")], path, label=label)
    weights = cols.pop("weight", None)
    information = None
    if INFORMATION_TEXT_COLUMNS[0] in cols:
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


def _read_parquet_parts(folder: Path, duplicates: str) -> ViewGraph:
    """A folder of Parquet parts (:func:`~rotgraph.io.parts.parquet_parts`) as one binary
    edge file: the parts read by ``pyarrow.dataset`` in the natural order of their names, the
    edges of each in its order. Each part has the columns of a Parquet edge file, checked as
    one (:func:`_checked_binary_columns`; errors name the part), and the same ones of the
    format as the first part; an empty part adds nothing. Errors of an edge name its part and
    its row in the part (:func:`_graph_of_parts`)."""
    from ..errors import InputError

    parts = parquet_parts(folder)
    pieces, sizes, first = [], [], None
    for part, (names, cols) in zip(parts, _part_columns(parts)):
        sizes.append(_checked_binary_columns(part, names, cols))
        have = [c for c in BINARY_COLUMNS if c in cols]
        if first is None:
            first = (part, have)
        elif have != first[1]:
            lacks, extra = [c for c in first[1] if c not in have], [c for c in have if c not in first[1]]
            raise InputError(f"Parquet part has other columns than the first part {first[0].relative_to(folder)}: "
                             + "; ".join(([f"no {', '.join(lacks)}"] if lacks else []) + ([f"also {', '.join(extra)}"] if extra else [])),
                             str(part))
        pieces.append(cols)
    m = sum(sizes)
    if m == 0:
        raise no_edges(folder, " ".join(BINARY_REQUIRED))
    cols = {}
    for c in first[1]:  # one array a column; ids of integer and string parts as strings (then as the text ids)
        arrays = [p.pop(c) for p, n in zip(pieces, sizes) if n]
        if c in ("i", "j") and len({a.dtype.kind for a in arrays}) > 1:
            arrays = [a.astype(str) for a in arrays]
        cols[c] = np.concatenate(arrays)
        del arrays
    return _graph_of_parts(folder, parts, sizes, lambda label: _binary_graph(folder, cols, m, duplicates, label))


def read_parquet_part(part, columns=None) -> dict:
    """One Parquet part of an edge dataset, checked as a binary edge file
    (:func:`_checked_binary_columns`: errors name the part): ``{name: array}`` of its columns
    of the format (ids ``i``, ``j`` int64 or str), the quaternions ``q`` (4, m) checked and
    normalised (:func:`~rotgraph.so3.check_quaternion_rows`, errors name the edge's 0-based
    row in the part) in place of ``qw .. qz``; ``columns``: only these of the format (``("i",
    "j")``: the ids, not checked further). What a worker of the distributed solve reads of
    its part (:mod:`rotgraph.pipeline.distributed`); the whole folder is
    :func:`_read_parquet_parts`."""
    from ..errors import InputError

    part = Path(part)
    if columns is not None:
        import pyarrow.parquet as pq

        try:
            tbl = pq.read_table(part, columns=list(columns))
        except (OSError, ValueError, KeyError) as exc:
            raise InputError(f"cannot read the Parquet part: {exc}", str(part)) from None
        return {c: tbl.column(c).to_numpy() for c in columns}
    ((names, cols),) = list(_part_columns([part]))
    m = _checked_binary_columns(part, names, cols)
    if m:
        cols["q"] = so3_checks.check_quaternion_rows([cols.pop(c) for c in ("qw", "qx", "qy", "qz")], path=str(part),
                                              label=lambda k: f"edge {k} (0-based)")
    else:
        cols["q"] = np.zeros((4, 0))
    return cols


def _part_columns(parts: list):
    """``(names, columns)`` of each Parquet part, as :func:`_binary_columns`, read one at a
    time by ``pyarrow.dataset`` (its own columns: the parts' schemas may differ)."""
    import pyarrow as pa
    import pyarrow.dataset as ds

    from ..errors import InputError

    dataset = ds.dataset([str(p) for p in parts], format="parquet", schema=pa.schema([]))  # no file opened yet
    for part, fragment in zip(parts, dataset.get_fragments()):
        try:
            schema = fragment.physical_schema
            tbl = fragment.to_table(schema=schema, columns=[c for c in schema.names if c in BINARY_COLUMNS])
        except (OSError, ValueError) as exc:
            why = re.sub(r"^Could not open Parquet input source '[^']*': ", "", str(exc))  # (names the part again)
            hint = "" if part.suffix.lower() in (".parquet", ".pq") else (
                " (every file of a folder of Parquet parts is read as a part, but hidden and _-prefixed ones)")
            raise InputError(f"cannot read the Parquet part: {why}{hint}", str(part)) from None
        yield schema.names, {c: tbl.column(c).to_numpy() for c in tbl.column_names}
        del tbl


def _graph_of_parts(folder: Path, parts: list, sizes: list, build) -> ViewGraph:
    """``build(label)`` (the graph of the parts' edges, one after the other) with its errors
    moved to the part: an :class:`~rotgraph.errors.InputError` naming ``folder`` and a row
    of all the edges (1-based ``line``, or ``label(k)``'s 0-based ``k``) names the part and
    the row in it instead."""
    from ..errors import InputError

    starts = np.cumsum([0] + list(sizes))
    named = []  # the part of the edge a message names through label

    def part_of(k: int) -> int:
        return int(np.searchsorted(starts, k, side="right")) - 1  # empty parts skipped

    def label(k: int) -> str:
        named.append(part_of(k))
        return f"edge {k - int(starts[named[-1]])} (0-based)"

    try:
        return build(label)
    except InputError as exc:
        if exc.path != str(folder) or (exc.line is None and not named):
            raise
        if exc.line is None:
            raise InputError(exc.message, str(parts[named[-1]])) from None
        p = part_of(exc.line - 1)
        raise InputError(exc.message, str(parts[p]), exc.line - int(starts[p])) from None
