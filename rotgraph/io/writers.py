"""Writers of rotgraph's files: rotations, edges and per-edge residuals, all atomic.

* :func:`write_rotations` - ``id,name,qw,qx,qy,qz[,extra...]``, the ``rotgraph solve`` output;
* :func:`write_absolute_rotations_text` - ``id qw qx qy qz`` lines (``rotgraph synth``'s ``gt.txt``);
* :func:`write_edges` - the ``rotgraph`` edge text format ``i j qw qx qy qz weight``, and
  ``h_xx h_xy h_xz h_yy h_yz h_zz`` after it when the edges have information matrices;
* :func:`write_edges_csv` - ``i,j,residual_deg,inlier`` (``--edges-out``).

Conventions: quaternions ``(w, x, y, z)`` with ``w >= 0``, of ``cam_from_world`` for
absolute rotations and of ``R_ij = R_j R_i^T`` for edges; floats at full precision (the
shortest repr that reads back to the same float); ids as written, CSV fields quoted when
needed. Every file goes through :func:`~rotgraph.io.atomic.atomic_write`: never half-written.
Bad arguments (wrong shapes, non-finite rotations, ids a white-space format cannot hold)
are a ``ValueError`` before anything is written.
"""

from __future__ import annotations

import numpy as np

from .. import so3, so3_rows
from ..errors import OptionError
from ..graph_build import check_information
from ..viewgraph import ViewGraph
from .atomic import atomic_write

__all__ = ["write_rotations", "write_absolute_rotations_text", "write_edges", "write_edges_csv", "write_rigs", "write_extrinsics",
           "write_frames", "write_rotations_text", "write_rotations_json", "write_edges_npz", "write_edges_text_blocks",
           "write_camera_errors", "json_safe"]


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

    Parameters
    ----------
    path : str or os.PathLike
        The CSV file to write.
    ids : (N,) array_like
        The cameras' ids.
    names : (N,) array_like or None
        Their names (None: the ids).
    cam_from_world : (N, 3, 3) array_like
        The absolute rotations (world-to-camera), finite; written as quaternions
        ``(w, x, y, z)`` with ``w >= 0``.
    extra_columns : dict, optional
        Column name -> (N,) values, appended after ``qz``.

    Returns
    -------
    None

    Raises
    ------
    ValueError
        Arrays of the wrong length or shape, non-finite rotations, a bad column name.
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


def write_edges(path, graph_or_ids_i, ids_j=None, cam2_from_cam1=None, weights=None, *, information=None) -> None:
    """Write edges in the ``rotgraph`` text format (``# i j qw qx qy qz weight``), atomically.

    Pass a :class:`~rotgraph.viewgraph.ViewGraph`, or the arrays ``ids_i``, ``ids_j``,
    ``cam2_from_cam1`` (``R_ij = R_j R_i^T``) and optionally ``weights`` (default 1) and
    ``information`` (E, 3, 3). With information (the graph's, or the argument) each line
    ends with its upper triangle ``h_xx h_xy h_xz h_yy h_yz h_zz`` (radians^-2, rotgraph's
    convention: :class:`~rotgraph.viewgraph.ViewGraph`), checked by
    :func:`~rotgraph.graph_build.check_information` (an :class:`~rotgraph.errors.InputError`,
    a ValueError, before anything is written). Quaternions have ``w >= 0``; ids must be
    non-negative integers or names without white space (string ids made only of digits
    are read back as integers).

    Parameters
    ----------
    path : str or os.PathLike
        The edge file to write.
    graph_or_ids_i : ViewGraph or (E,) array_like
        A view graph, or the first camera id ``i`` of each edge.
    ids_j : (E,) array_like, optional
        The second camera id ``j`` of each edge (with ``ids_i``).
    cam2_from_cam1 : (E, 3, 3) array_like, optional
        Each edge's relative rotation ``R_ij = R_j R_i^T`` (with ``ids_i``), written as a
        quaternion ``(w, x, y, z)``.
    weights : (E,) array_like, optional
        Edge weights (default 1).
    information : (E, 3, 3) array_like, optional
        Rotation information matrices (radians^-2); default the graph's, if any.

    Returns
    -------
    None

    Raises
    ------
    OptionError
        Neither a ViewGraph nor ``ids_i``, ``ids_j`` and ``cam2_from_cam1`` (also a
        ``ValueError``).
    ValueError
        Arrays of the wrong length or shape, ids that cannot be written; an
        :class:`~rotgraph.errors.InputError` for bad information matrices.
    """
    ids_i, ids_j, rel, w, information = _edge_arrays(graph_or_ids_i, ids_j, cam2_from_cam1, weights, information)
    q = so3.quaternions_from_matrices(rel)
    cols = [_id_strings(ids_i, "id", csv_field=False), _id_strings(ids_j, "id", csv_field=False)]
    cols += [_float_strings(q[:, c]) for c in range(4)] + [_float_strings(w)]
    header = "# i j qw qx qy qz weight"
    if information is not None:  # checked by _edge_arrays
        cols += [_float_strings(information[:, r, c]) for r, c in zip(*np.triu_indices(3))]
        header += " h_xx h_xy h_xz h_yy h_yz h_zz"
    with atomic_write(path) as fh:
        fh.write(header + "\n")
        fh.writelines(" ".join(row) + "\n" for row in zip(*cols))


def write_edges_csv(path, ids_i, ids_j, residual_deg, inlier, names_i=None, names_j=None, weight=None) -> None:
    """Write ``i,j,residual_deg,inlier`` (``--edges-out``; inlier as 0/1), atomically; with
    ``names_i``/``names_j`` (e.g. COLMAP image names) also ``name_i,name_j`` after them; with
    ``weight`` (each edge's weight in the solve's final iteration, ``nan`` for edges outside
    the solve) a last column ``weight``."""
    ids_i, ids_j = np.asarray(ids_i), np.asarray(ids_j)
    res = np.asarray(residual_deg, dtype=np.float64)
    inl = np.asarray(inlier)
    m = len(ids_i)
    if not (len(ids_j) == len(res) == len(inl) == m):
        raise ValueError(f"expected {m} values in every column, got {len(ids_j)}, {len(res)}, {len(inl)}")
    cols = [_id_strings(ids_i, "id", csv_field=True), _id_strings(ids_j, "id", csv_field=True), _float_strings(res),
            ["1" if bool(x) else "0" for x in inl.tolist()]]
    header = "i,j,residual_deg,inlier"
    if names_i is not None and names_j is not None:
        if not (len(names_i) == len(names_j) == m):
            raise ValueError(f"expected {m} names on each side, got {len(names_i)}, {len(names_j)}")
        cols += [_id_strings(names_i, "name", csv_field=True), _id_strings(names_j, "name", csv_field=True)]
        header += ",name_i,name_j"
    if weight is not None:
        wt = np.asarray(weight, dtype=np.float64)
        if len(wt) != m:
            raise ValueError(f"expected {m} weights, got {len(wt)}")
        cols.append(_float_strings(wt))
        header += ",weight"
    with atomic_write(path) as fh:
        fh.write(header + "\n")
        fh.writelines(",".join(row) + "\n" for row in zip(*cols))


def write_camera_errors(path, ids, names, errors_deg) -> None:
    """Write ``id,name,error_deg`` (``rotgraph eval --per-camera``), one row per evaluated
    camera, atomically (``name`` is the id when ``names`` is None)."""
    ids = np.asarray(ids)
    err = np.asarray(errors_deg, dtype=np.float64)
    if len(err) != len(ids) or (names is not None and len(names) != len(ids)):
        raise ValueError(f"expected {len(ids)} names and errors, got {None if names is None else len(names)}, {len(err)}")
    cols = [_id_strings(ids, "id", csv_field=True), _id_strings(ids if names is None else names, "name", csv_field=True),
            _float_strings(err)]
    with atomic_write(path) as fh:
        fh.write("id,name,error_deg\n")
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


def write_rigs(path, node_ids, rigs) -> None:
    """Write a rig file (:mod:`rotgraph.io.rigs`: ``image_id frame_id sensor_id [qw qx qy
    qz]``), atomically: one line per image with a sensor (``rigs.sensor_ids >= 0``), the
    quaternion where its ``cam_from_rig`` is known."""
    keep = np.flatnonzero(rigs.sensor_ids >= 0) if rigs.sensor_ids is not None else np.zeros(0, dtype=np.int64)
    ids = _id_strings(np.asarray(node_ids)[keep], "id", csv_field=False)
    S = rigs.cam_from_rig[keep]
    known = np.isfinite(S).all(axis=(1, 2))
    q = np.full((len(keep), 4), np.nan)
    if known.any():
        q[known] = so3.quaternions_from_matrices(S[known])
    qs = [_float_strings(q[:, c]) for c in range(4)]
    with atomic_write(path) as fh:
        fh.write("# image_id frame_id sensor_id [qw qx qy qz: cam_from_rig when known]\n")
        for k in range(len(keep)):
            row = [ids[k], str(int(rigs.frame_ids[keep[k]])), str(int(rigs.sensor_ids[keep[k]]))]
            if known[k]:
                row += [qs[c][k] for c in range(4)]
            fh.write(" ".join(row) + "\n")


def write_extrinsics(path, sensors) -> None:
    """Write a rig solve's extrinsics (:class:`~rotgraph.estimators.types.SensorSolution`) as
    CSV ``sensor_id,status,qw,qx,qy,qz,n_frames,spread_deg,n_outlier_frames`` (empty
    quaternion fields where unobservable), atomically."""
    rows = sensors.to_rows()
    with atomic_write(path) as fh:
        fh.write("sensor_id,status,qw,qx,qy,qz,n_frames,spread_deg,n_outlier_frames\n")
        for r in rows:
            q = ["" if r[c] is None else repr(float(r[c])) for c in ("qw", "qx", "qy", "qz")]
            spread = "" if r["spread_deg"] is None else repr(float(r["spread_deg"]))
            fh.write(",".join([str(r["sensor_id"]), r["status"], *q, str(r["n_frames"]), spread, str(r["n_outlier_frames"])]) + "\n")


def write_frames(path, frame_ids, rig_from_world) -> None:
    """Write frame rotations as CSV ``frame_id,qw,qx,qy,qz`` (``rig_from_world``; rows of
    unsolved frames left out), atomically."""
    R = np.asarray(rig_from_world, dtype=np.float64)
    ok = np.isfinite(R).all(axis=(1, 2))
    q = so3.quaternions_from_matrices(R[ok]) if ok.any() else np.zeros((0, 4))
    ids = np.asarray(frame_ids)[ok]
    qs = [_float_strings(q[:, c]) for c in range(4)]
    with atomic_write(path) as fh:
        fh.write("frame_id,qw,qx,qy,qz\n")
        fh.writelines(",".join([str(int(ids[k]))] + [qs[c][k] for c in range(4)]) + "\n" for k in range(len(ids)))


def write_rotations_text(path, ids, names, cam_from_world) -> None:
    """Write GLOMAP/COLMAP-style ``IMAGE_NAME QW QX QY QZ`` lines (``cam_from_world``, ``w >=
    0``; the id where there are no names), atomically. Names must not contain white space."""
    ids = np.asarray(ids)
    R = _rotations_array(cam_from_world, len(ids))
    q = so3.quaternions_from_matrices(R)
    keys = _id_strings(ids if names is None else np.asarray(names), "name", csv_field=False)
    qs = [_float_strings(q[:, c]) for c in range(4)]
    with atomic_write(path) as fh:
        fh.write("# IMAGE_NAME QW QX QY QZ (cam_from_world)\n")
        fh.writelines(" ".join([keys[k]] + [qs[c][k] for c in range(4)]) + "\n" for k in range(len(ids)))


def write_rotations_json(path, ids, names, cam_from_world, extra: dict | None = None) -> None:
    """Write ``{"convention": ..., "cameras": [{"id", "name", "qw", "qx", "qy", "qz"}, ...],
    **extra}`` (``cam_from_world``, ``w >= 0``), atomically."""
    import json

    ids = np.asarray(ids)
    R = _rotations_array(cam_from_world, len(ids))
    q = so3.quaternions_from_matrices(R).tolist()
    nm = ids if names is None else np.asarray(names)
    cams = [{"id": i.item() if hasattr(i, "item") else i, "name": str(n), "qw": a, "qx": b, "qy": c, "qz": d}
            for i, n, (a, b, c, d) in zip(ids, nm, q)]
    data = {"convention": "cam_from_world quaternions (w, x, y, z), w >= 0", "cameras": cams, **(extra or {})}
    with atomic_write(path) as fh:
        json.dump(data, fh, indent=1)
        fh.write("\n")


# ------------------------------------------------------------ large edge lists (issue #19)

#: Edges per block of the large-file edge writers (bounds their temporaries).
EDGE_BLOCK = 1 << 20
#: The columns of the binary edge format (``.npz``; :func:`write_edges_npz`).
BINARY_EDGE_COLUMNS = ("i", "j", "qw", "qx", "qy", "qz", "weight", "h_xx", "h_xy", "h_xz", "h_yy", "h_yz", "h_zz")


def _edge_arrays(graph_or_ids_i, ids_j, cam2_from_cam1, weights, information):
    """``(ids_i, ids_j, rel, weights, information)`` checked as :func:`write_edges` checks them."""
    if isinstance(graph_or_ids_i, ViewGraph):
        g = graph_or_ids_i
        ids_i, ids_j = g.node_ids[g.edges[:, 0]], g.node_ids[g.edges[:, 1]]
        rel, w, information = g.cam2_from_cam1, g.weights, g.information
    else:
        ids_i, rel, w = graph_or_ids_i, cam2_from_cam1, weights
        if ids_j is None or rel is None:
            raise OptionError("expected a ViewGraph or ids_i, ids_j and cam2_from_cam1")
    ids_i, ids_j = np.asarray(ids_i), np.asarray(ids_j)
    m = len(ids_i)
    if len(ids_j) != m:
        raise ValueError(f"expected {m} ids_j, got {len(ids_j)}")
    rel = np.asarray(rel, dtype=np.float64)
    if rel.shape != (m, 3, 3):
        raise ValueError(f"expected ({m}, 3, 3) rotations, got {rel.shape}")
    for s in range(0, m, EDGE_BLOCK):  # finite, in blocks (no (E, 3, 3) temporaries)
        _rotations_array(rel[s:s + EDGE_BLOCK])
    w = np.ones(m) if w is None else np.asarray(w, dtype=np.float64)
    if w.shape != (m,):
        raise ValueError(f"expected ({m},) weights, got {w.shape}")
    if information is not None:
        information = check_information(information, m)
    for ids in (ids_i, ids_j):
        if ids.dtype.kind not in "iu":
            _id_strings(np.unique(ids), "id", csv_field=False)
    return ids_i, ids_j, rel, w, information


def write_edges_npz(path, graph_or_ids_i, ids_j=None, cam2_from_cam1=None, weights=None, *, information=None) -> None:
    """Write edges in rotgraph's binary edge format, atomically: an uncompressed ``.npz``
    (``np.savez``) of the arrays ``i``, ``j`` (int64, or unicode names), ``qw qx qy qz``
    (float64, ``R_ij = R_j R_i^T``, ``w >= 0``), ``weight`` and, when the edges have
    information matrices, ``h_xx h_xy h_xz h_yy h_yz h_zz`` (their upper triangle,
    radians^-2), one entry per edge in the graph's order. Arguments as
    :func:`write_edges`; read back by :func:`rotgraph.io.edges.read_edge_file` (by the
    extension or the zip magic), ~1 s for 10^7 edges."""
    ids_i, ids_j, rel, w, information = _edge_arrays(graph_or_ids_i, ids_j, cam2_from_cam1, weights, information)
    q = so3_rows.quaternion_rows_from_matrices(rel)  # in cache-sized blocks
    arrays = {"i": ids_i.astype(np.int64) if ids_i.dtype.kind in "iu" else ids_i.astype(str),
              "j": ids_j.astype(np.int64) if ids_j.dtype.kind in "iu" else ids_j.astype(str),
              "qw": q[0], "qx": q[1], "qy": q[2], "qz": q[3], "weight": w}
    if information is not None:
        for name, (r, c) in zip(BINARY_EDGE_COLUMNS[7:], zip(*np.triu_indices(3))):
            arrays[name] = np.ascontiguousarray(information[:, r, c])
    with atomic_write(path, "wb") as fh:
        np.savez(fh, **arrays)


def write_edges_text_blocks(path, graph_or_ids_i, ids_j=None, cam2_from_cam1=None, weights=None, *, information=None) -> None:
    """:func:`write_edges` for large edge lists: the same ``rotgraph`` text lines (same
    header, columns and values; a float may be spelled differently, e.g. ``1e-07`` or
    ``1``, and reads back as the same float), formatted by pyarrow's CSV writer in blocks
    of :data:`EDGE_BLOCK` edges: memory O(E) in arrays, not in Python strings (10^7 edges:
    seconds instead of minutes, and no 5 GB of strings). Atomic."""
    import pyarrow as pa
    import pyarrow.csv as pacsv

    ids_i, ids_j, rel, w, information = _edge_arrays(graph_or_ids_i, ids_j, cam2_from_cam1, weights, information)
    m = len(ids_i)
    names = list(BINARY_EDGE_COLUMNS[:7]) + (list(BINARY_EDGE_COLUMNS[7:]) if information is not None else [])
    header = "# " + " ".join(names) + "\n"
    opts = pacsv.WriteOptions(include_header=False, delimiter=" ", quoting_style="none")
    tri = list(zip(*np.triu_indices(3)))
    with atomic_write(path, "wb") as fh:
        fh.write(header.encode())
        for s in range(0, m, EDGE_BLOCK):
            b = slice(s, s + EDGE_BLOCK)
            q = so3.quaternions_from_matrices(rel[b])
            cols = [ids_i[b] if ids_i.dtype.kind in "iu" else ids_i[b].astype(str),
                    ids_j[b] if ids_j.dtype.kind in "iu" else ids_j[b].astype(str),
                    q[:, 0], q[:, 1], q[:, 2], q[:, 3], w[b]]
            if information is not None:
                cols += [np.ascontiguousarray(information[b, r, c]) for r, c in tri]
            sink = pa.BufferOutputStream()
            pacsv.write_csv(pa.table(dict(zip(names, cols))), sink, opts)
            fh.write(sink.getvalue())


def json_safe(obj):
    """``obj`` (dicts, lists, tuples, numbers, strings) with every non-finite float (NaN: not
    measured; inf) as None: JSON has no NaN, and ``json.dumps`` would write a bare ``NaN``
    that strict parsers reject. The one conversion of rotgraph's JSON outputs."""
    if isinstance(obj, float):
        return obj if np.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    return obj
