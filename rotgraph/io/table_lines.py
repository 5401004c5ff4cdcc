"""Lines of a text table: the one sniffer of rotgraph's inputs (:func:`first_data_line`),
whether ``\n`` numbers the lines as ``str.splitlines`` does, and where the ``#`` comment
lines and the data lines are, for the fast passes of :mod:`rotgraph.io.tables` and
:mod:`rotgraph.io.table_stream` (which number their rows as the line-by-line parser does).

A data line is one that is neither blank nor a comment (``#`` its first non-blank character;
a ``#`` later in a line is data).
"""

from __future__ import annotations

import numpy as np

__all__ = ["first_data_line", "simple_line_breaks", "comment_lines", "comment_line_numbers", "data_line_numbers"]


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


def comment_lines(text: str | bytes, first_line: int = 1, stop_at_data_hash: bool = False):
    """The ``#`` comment lines of ``text`` (``#`` the first non-blank character of the line):
    ``(number, start, end)`` each (``end`` after its line break; the first line of ``text``
    numbered ``first_line``), and whether some ``#`` stands later in a line (data for the
    line-by-line parser; with ``stop_at_data_hash`` the scan ends there). The one scan behind
    :func:`comment_line_numbers` and :func:`_strip_comments`."""
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


def comment_line_numbers(text: str | bytes) -> list[int] | None:
    """Line numbers of the ``#`` comment lines, or None if some ``#`` is not the first
    non-blank character of its line (then np.loadtxt's comment handling would differ)."""
    lines, data_hash = comment_lines(text, stop_at_data_hash=True)
    return None if data_hash else [number for number, _, _ in lines]


_BLANK = np.zeros(256, dtype=bool)
_BLANK[list(b" \t\n\r\x0b\x0c")] = True  # what bytes.strip() strips


def data_line_numbers(text: bytes, comments: list[int], n_data: int, first_line: int = 1) -> np.ndarray | None:
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
