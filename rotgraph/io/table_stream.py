"""The streamed table reader: a clean table read straight from its file through pyarrow's
CSV parser, block by block (:func:`read_table_file`), or None, and the caller reads the text
with :func:`rotgraph.io.tables.read_table` (the reference for what is an error where).

Blocks of :data:`STREAM_BLOCK` bytes: peak memory is the arrays, not the text (10^7 edge
lines, 0.9 GB: the table in 6-8 s on a 2-core machine); anything this pass does not read
exactly as the line-by-line parser would (tabs, runs of spaces, CR line breaks, non-ASCII
text, blank lines with spaces, a row of another field count, a bad or non-finite value,
negative ids) makes it give up.
"""

from __future__ import annotations

import numpy as np

from .compressed import input_head, open_input, read_reporter
from .table_columns import Table, resolve_id_columns
from .table_lines import comment_lines, data_line_numbers, first_data_line, simple_line_breaks

__all__ = ["STREAM_BLOCK", "read_table_file"]


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
    lines, _ = comment_lines(blk, first_line)
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
    numbers = data_line_numbers(blk, comments, 0 if tbl is None else tbl.num_rows, line)
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
        index = resolve_id_columns(cols, id_cols, lines, path, names, errors)
        if errors:
            return None
    return Table(lines, cols, np.broadcast_to(np.int64(ncol), (len(lines),)), index)  # read-only, no memory
