"""Files of absolute rotations, and the ``rotgraph mean`` input.

* :func:`read_absolute_rotations` - ground truth or an estimate, ``cam_from_world``
  (``rotgraph eval``; the formats in :data:`~rotgraph.io.formats.ROTATION_FORMATS`);
* :func:`read_weighted_quaternions` - rotations to average (``qw qx qy qz [weight]``
  lines, or a CSV), also the motions of ``rotgraph handeye`` (:mod:`rotgraph.io.handeye`).

Quaternions are ``(w, x, y, z)``; they go through :func:`rotgraph.so3.check_quaternions`
(normalised, one warning when some ``| |q| - 1 | > 1e-3``, a zero one is an error). The
tables are read by :mod:`rotgraph.io.tables`: every malformed line is an
:class:`~rotgraph.errors.InputError` naming the file and line. The writers of rotations
are in :mod:`rotgraph.io.writers`.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from .. import so3, so3_checks
from ..errors import InputError, OptionError
from .formats import ROTATION_FORMATS, TABLE_FORMATS, detect_rotation_format, detect_table_format
from .matlab import read_mat
from .onedsfm import read_1dsfm, read_bundler
from .table_lines import first_data_line
from .tables import read_csv_table, read_table
from .text import read_text

__all__ = ["read_absolute_rotations", "read_weighted_quaternions", "read_quaternion_table"]

logger = logging.getLogger(__name__)

_QCOLS = ("qw", "qx", "qy", "qz")
_GT_READERS = {"mat": read_mat, "1dsfm": read_1dsfm}
#: Why a g2o file is not a ground-truth (or rotations) file: its vertices are odometry.
G2O_NOT_GROUND_TRUTH = ("g2o vertices are initial guesses (odometry), not ground truth; give a ground-truth file "
                        "('id qw qx qy qz' text, a rotgraph CSV, a COLMAP sparse model, or a .mat/1DSfM input with "
                        "ground truth)")


def read_absolute_rotations(path, fmt: str = "auto") -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """Read absolute rotations (ground truth or an estimate): ``(ids, names, cam_from_world)``.

    Formats (:data:`~rotgraph.io.formats.ROTATION_FORMATS`):

    * ``csv`` - a header with ``qw,qx,qy,qz`` and ``id`` and/or ``name`` (other columns
      are ignored): the ``rotgraph solve`` output ``id,name,qw,qx,qy,qz[,...]`` or e.g.
      ``name,qw,qx,qy,qz``. Without an ``id`` column the ids are the names.
    * ``text`` - ``id qw qx qy qz`` or ``id name qw qx qy qz`` lines (one layout per file;
      ``#`` comments). ``id`` may be a name (GLOMAP's rotation output ``NAME QW QX QY QZ``).
    * ``bundler`` - a Bundler v0.3 file (``gt_bundle.out``): cameras ``0..N-1`` with a
      nonzero rotation, converted to the computer-vision frame (``D R``, see
      :mod:`rotgraph.io.onedsfm`).
    * ``mat``, ``1dsfm`` - the ground truth inside those inputs (as
      :func:`rotgraph.io.edges.read_edge_file` reads it).
    * ``g2o`` - refused (:class:`InputError`): its ``VERTEX_SE3:QUAT`` lines are initial
      guesses (dead-reckoned odometry), never ground truth
      (``ViewGraph.initial_cam_from_world``, ``--init vertices``).
    * ``colmap`` - the images of a COLMAP sparse model (:mod:`rotgraph.io.colmap_model`).
    * ``json`` - ``rotgraph solve -o X.json``: ``{"cameras": [{"id", "name", "qw", "qx", "qy",
      "qz"}, ...]}`` (:func:`rotgraph.io.writers.write_rotations_json`).

    Quaternions are ``(w, x, y, z)`` of ``cam_from_world`` and are normalised. Ids are
    int64 when all are non-negative integers, else strings; duplicate ids are an error.

    Parameters
    ----------
    path : str or os.PathLike
        The file (or COLMAP model folder) to read.
    fmt : str, default "auto"
        One of :data:`~rotgraph.io.formats.ROTATION_FORMATS`; ``auto`` detects it.

    Returns
    -------
    ids : (N,) ndarray
        The cameras' ids (int64 or str).
    names : (N,) ndarray or None
        Their names, when the file has them.
    cam_from_world : (N, 3, 3) float64 ndarray
        The absolute rotations (world-to-camera).

    Raises
    ------
    OptionError
        An unknown ``fmt`` (also a ``ValueError``).
    InputError
        A bad file (also a ``ValueError``).
    """
    if fmt not in ROTATION_FORMATS:
        raise OptionError(f"unknown format {fmt!r}; expected one of {', '.join(ROTATION_FORMATS)}")
    p = Path(path)
    if fmt == "auto":
        fmt = detect_rotation_format(p)
    if fmt == "colmap":
        from .colmap_model import read_colmap_model_rotations

        return read_colmap_model_rotations(p)
    if fmt == "g2o":
        raise InputError(G2O_NOT_GROUND_TRUTH, str(path))
    if fmt == "json":
        return _read_json_rotations(p)
    if fmt in _GT_READERS:
        graph = _GT_READERS[fmt](p, "keep")
        gt = graph.gt_cam_from_world
        has = np.zeros(graph.n_nodes, bool) if gt is None else np.isfinite(gt).all(axis=(1, 2))
        if not has.any():
            raise InputError(f"no absolute rotations (ground truth) in this {fmt} input", str(path))
        names = None if graph.names is None else graph.names[has]
        return graph.node_ids[has], names, gt[has]
    if fmt == "bundler":
        R = read_bundler(p)
        has = np.isfinite(R).all(axis=(1, 2))
        if not has.any():
            raise InputError("no registered camera (every rotation is zero)", str(path))
        return np.flatnonzero(has).astype(np.int64), None, R[has]
    text = read_text(p)
    if fmt == "csv":
        header, table = read_csv_table(p, text, _QCOLS, kinds={"id": "id", "name": "name"}, noun="rotations",
                                       require_any=("id", "name"))
        col = dict(zip(header, table.cols))
        names = col.get("name")
        ids = col["id"] if "id" in col else names
        q = np.stack([col[c] for c in _QCOLS], axis=1)
    else:
        first = first_data_line(text)
        if first is None:
            raise InputError("no rotations (expected lines 'id qw qx qy qz' or 'id name qw qx qy qz')", str(p))
        nf = len(first[2].split())
        if nf not in (5, 6):
            raise InputError(f"expected 5 fields 'id qw qx qy qz' or 6 'id name qw qx qy qz', got {nf}", str(p), first[0])
        kinds = ("id",) + (("name",) if nf == 6 else ()) + ("f",) * 4
        names_ = ("id",) + (("name",) if nf == 6 else ()) + _QCOLS
        table = read_table(p, text, counts=(nf,), kinds=kinds, names=names_, what=" ".join(names_))
        ids = table.cols[0]
        names = table.cols[1] if nf == 6 else None
        if names is None and ids.dtype.kind in "OUS":  # GLOMAP's `NAME QW QX QY QZ`: the ids are names
            names = ids
        q = table.floats(nf - 4, nf)
    q = so3_checks.check_quaternions(q, path=p, lines=table.lines)
    order = np.argsort(ids, kind="stable")
    dup = np.flatnonzero(ids[order][1:] == ids[order][:-1])
    if len(dup):
        k = int(order[dup[0] + 1])
        raise InputError(f"camera {ids[k].item()!r} appears twice", str(p), int(table.lines[k]))
    return ids, names, so3.matrices_from_quaternions(q)


def read_quaternion_table(path, fmt: str, *, text_layout: str, extra: tuple[str, ...], noun: str):
    """The table of a ``mean`` or ``handeye`` input: ``(text, lines, quaternions (N, 4) as
    read, {extra column: (N,) array})`` (the extras present in the file), or ``(text,
    None, None, None)`` for a text table, which the caller parses (its layout is its own).

    ``fmt`` is ``auto`` (``csv`` when the first data line has a comma), ``text`` or
    ``csv`` (a header naming ``qw,qx,qy,qz`` and optionally the ``extra`` columns; other
    columns are ignored; ``noun`` names its rows). An empty file is an
    :class:`InputError` at line 1 saying what was expected: ``text_layout`` or the header.
    """
    if fmt not in TABLE_FORMATS:
        raise OptionError(f"unknown format {fmt!r}; expected auto, text or csv")
    text = read_text(path)
    first = first_data_line(text)
    if fmt == "auto":
        fmt = detect_table_format(None if first is None else first[2])
    if first is None:
        expected = f"a header {','.join(_QCOLS)}[,{','.join(extra)}]" if fmt == "csv" else text_layout
        raise InputError(f"the file is empty, expected {expected}", str(path), 1)
    if fmt == "text":
        return text, None, None, None
    header, table = read_csv_table(path, text, _QCOLS, extra, noun=noun)
    col = dict(zip(header, table.cols))
    return text, table.lines, np.stack([col[c] for c in _QCOLS], axis=1), {c: col[c] for c in extra if c in col}


def read_weighted_quaternions(path, fmt: str = "auto") -> tuple[np.ndarray, np.ndarray, list[int]]:
    """Read rotations and weights for single rotation averaging.

    Formats: ``text`` - one rotation a line, ``qw qx qy qz [weight]`` (``#`` comments);
    ``csv`` - a header naming ``qw,qx,qy,qz`` and optionally ``weight`` (other columns are
    ignored). ``auto`` picks ``csv`` when the first data line has a comma.

    Quaternions are normalised (non-unit input is accepted as a scaled quaternion, with one
    warning when some ``| |q| - 1 | > 1e-3``); a zero quaternion, a NaN, a negative weight
    or a line with the wrong number of fields is an :class:`InputError` naming the file and
    line.

    Returns ``(quaternions (N, 4), weights (N,), line_numbers)``.
    """
    layout = "qw qx qy qz [weight]"
    text, lines, q, extra = read_quaternion_table(path, fmt, text_layout=f"lines '{layout}'", extra=("weight",),
                                                  noun="rotations")
    if lines is None:
        table = read_table(path, text, counts=(4, 5), kinds=("f",) * 5, names=_QCOLS + ("weight",), what=layout,
                           defaults={4: 1.0})
        lines, q, w = table.lines, table.floats(0, 4), table.cols[4]
    else:
        w = extra.get("weight", np.ones(len(q)))
    if (w < 0).any():
        k = int(np.argmax(w < 0))
        raise InputError(f"negative weight {w[k]:g}", str(path), int(lines[k]))
    if w.sum() <= 0:
        raise InputError("all weights are zero", str(path), int(lines[0]))
    return so3_checks.check_quaternions(q, path=path, lines=lines), w, lines.tolist()


def _read_json_rotations(p: Path) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """The ``cameras`` of a ``rotgraph solve`` JSON output (see :func:`read_absolute_rotations`)."""
    import json

    try:
        data = json.loads(read_text(p))
    except json.JSONDecodeError as exc:
        raise InputError(f"not valid JSON ({exc.msg})", str(p), exc.lineno) from None
    cams = data.get("cameras") if isinstance(data, dict) else None
    if not isinstance(cams, list) or not cams:
        raise InputError("expected a JSON object with a non-empty list 'cameras' of {id, name, qw, qx, qy, qz}", str(p))
    try:
        q = np.array([[float(c[k]) for k in _QCOLS] for c in cams], dtype=np.float64)
        raw_ids = [c.get("id", c.get("name")) for c in cams]
        names = [c.get("name") for c in cams]
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise InputError(f"a camera lacks a number qw, qx, qy or qz ({exc})", str(p)) from None
    if any(i is None for i in raw_ids):
        raise InputError("a camera has neither 'id' nor 'name'", str(p))
    ids = (np.array(raw_ids, dtype=np.int64) if all(isinstance(i, int) and i >= 0 for i in raw_ids)
           else np.array([str(i) for i in raw_ids]))
    names_arr = None if any(n is None for n in names) else np.array([str(n) for n in names])
    q = so3_checks.check_quaternions(q, path=p)
    order = np.argsort(ids, kind="stable")
    dup = np.flatnonzero(ids[order][1:] == ids[order][:-1])
    if len(dup):
        raise InputError(f"camera {ids[order][dup[0]].item()!r} appears twice", str(p))
    return ids, names_arr, so3.matrices_from_quaternions(q)
