"""Files of rotations: the ``rotgraph mean`` input (``qw qx qy qz [weight]``)."""

from __future__ import annotations

import logging

import numpy as np

from ..errors import InputError
from .text import Rows, parse_floats, read_csv_table, read_rows, read_text

__all__ = ["read_weighted_quaternions"]

_QCOLS = ["qw", "qx", "qy", "qz"]

logger = logging.getLogger(__name__)


def _looks_like_csv(path) -> bool:
    for line in read_text(path).splitlines():
        s = line.strip()
        if s and not s.startswith("#"):
            return "," in s
    return False


def _check_quaternions(q: np.ndarray, rows: Rows) -> np.ndarray:
    """Normalise quaternions; a zero (or near-zero) quaternion is an error at its line, and
    non-unit ones (``| |q| - 1 | > 1e-3``) get one warning with their count, as the edge
    readers (:mod:`rotgraph.io.edges`) do."""
    n = np.linalg.norm(q, axis=1)
    bad = ~(n >= 1e-9)
    if bad.any():
        k = int(np.argmax(bad))
        raise InputError("zero quaternion (qw qx qy qz all 0)", rows.path, rows.line_numbers[k])
    off = np.abs(n - 1.0) > 1e-3
    if off.any():
        logger.warning(
            "%s: %d of %d quaternions are not unit length (the first at line %d; | |q| - 1 | up to %.3g); normalised",
            rows.path, int(off.sum()), len(q), rows.line_numbers[int(np.argmax(off))], float(np.abs(n - 1.0).max()),
        )
    return q / n[:, None]


def read_weighted_quaternions(path, fmt: str = "auto") -> tuple[np.ndarray, np.ndarray, list[int]]:
    """Read rotations and weights for single rotation averaging.

    Formats: ``text`` — one rotation a line, ``qw qx qy qz [weight]`` (``#`` comments);
    ``csv`` — a header naming ``qw,qx,qy,qz`` and optionally ``weight`` (other columns are
    ignored). ``auto`` picks ``csv`` when the first data line has a comma.

    Quaternions are normalised (non-unit input is accepted as a scaled quaternion, with one
    warning when some ``| |q| - 1 | > 1e-3``); a zero quaternion, a NaN, a negative weight
    or a line with the wrong number of fields is an :class:`InputError` naming the file and
    line.

    Returns ``(quaternions (N, 4), weights (N,), line_numbers)``.
    """
    if fmt == "auto":
        fmt = "csv" if _looks_like_csv(path) else "text"
    if fmt == "csv":
        header, data = read_csv_table(path, _QCOLS, "qw,qx,qy,qz[,weight]", "rotations")
        cols = [header.index(c) for c in _QCOLS]
        q = parse_floats(data, cols, _QCOLS)
        if "weight" in header:
            w = parse_floats(data, [header.index("weight")], ["weight"])[:, 0]
        else:
            w = np.ones(len(data))
    elif fmt == "text":
        data = read_rows(path)
        if len(data) == 0:
            raise InputError("the file is empty, expected lines 'qw qx qy qz [weight]'", str(path), 1)
        for ln, f in zip(data.line_numbers, data.fields):
            if len(f) not in (4, 5):
                raise InputError(f"expected 4 or 5 fields 'qw qx qy qz [weight]', got {len(f)}", data.path, ln)
        q = parse_floats(data, [0, 1, 2, 3], _QCOLS)
        w = np.ones(len(data))
        has_w = np.array([len(f) == 5 for f in data.fields])
        if has_w.any():
            sub = Rows(data.path, [n for n, h in zip(data.line_numbers, has_w) if h], [f for f, h in zip(data.fields, has_w) if h])
            w[has_w] = parse_floats(sub, [4], ["weight"])[:, 0]
    else:
        raise ValueError(f"unknown format {fmt!r}; expected auto, text or csv")
    if (w < 0).any():
        k = int(np.argmax(w < 0))
        raise InputError(f"negative weight {w[k]:g}", data.path, data.line_numbers[k])
    if w.sum() <= 0:
        raise InputError("all weights are zero", data.path, data.line_numbers[0])
    return _check_quaternions(q, data), w, data.line_numbers
