"""Gravity priors: a gravity file, or COLMAP's pose priors (issue #17, item 3).

A gravity direction is a vector in the camera's frame pointing "down" as the camera sees
it: COLMAP's ``PosePrior.gravity``, ``g = R_cam_from_world @ (0, 1, 0)`` for a camera whose
world has y down (:data:`rotgraph.estimators.gravity.GRAVITY_WORLD`). Any length is
accepted (an accelerometer's m/s^2 reading) and normalised; a zero vector is an error.

Gravity file
------------
* text: ``image_id gx gy gz [sigma_deg]`` a line (white space; ``#`` comments);
* CSV: a header naming ``gx,gy,gz`` and ``image_id`` or ``name`` (optionally ``sigma_deg``;
  other columns are ignored), e.g. ``image_id,gx,gy,gz,sigma_deg``.

``image_id`` is a camera id of the view graph, or an image name when the graph has names
(COLMAP projects). ``sigma_deg`` (>= 0, per tilt axis) is that image's gravity noise; images
without one take the solve's default: estimated from the data (see
:class:`rotgraph.priors.GravityPriors`). Every malformed line is an
:class:`~rotgraph.errors.InputError` naming the file and the line.

COLMAP
------
:func:`read_colmap_gravity` reads the pose priors of a COLMAP database (on a private copy,
as :mod:`rotgraph.io.colmap` opens every database) and returns the images whose prior
has a gravity.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError, OptionError
from .formats import detect_table_format
from .table_lines import first_data_line
from .tables import read_csv_table, read_table
from .text import read_text

__all__ = ["GravityTable", "gravity_for_graph", "read_colmap_gravity", "read_gravity_file"]

logger = logging.getLogger(__name__)

_LAYOUT = "image_id gx gy gz [sigma_deg]"


@dataclass
class GravityTable:
    """Gravity priors as read: ``keys`` (m,) image ids or names, ``gravity`` (m, 3) unit
    vectors, ``sigma_deg`` (m,) NaN where the input gives none, ``lines`` (m,) the source
    line of each (None for a database), ``path``."""

    keys: np.ndarray
    gravity: np.ndarray
    sigma_deg: np.ndarray
    lines: np.ndarray | None
    path: str | None


def _normalise(g: np.ndarray, path, lines) -> np.ndarray:
    norm = np.linalg.norm(g, axis=1)
    bad = ~(norm > 1e-12)
    if bad.any():
        k = int(np.argmax(bad))
        raise InputError("gravity vector is zero (expected a direction gx gy gz)", path,
                         None if lines is None else int(lines[k]))
    far = np.abs(norm - 1.0) > 1e-3
    if far.any():
        logger.info("%s: %d gravity vector(s) not of unit length (e.g. %.4g), normalised", path, int(far.sum()),
                    float(norm[np.argmax(far)]))
    return g / norm[:, None]


def _check_keys(keys: np.ndarray, path, lines) -> None:
    order = np.argsort(keys, kind="stable")
    dup = np.flatnonzero(keys[order][1:] == keys[order][:-1])
    if len(dup):
        k = int(order[dup[0] + 1])
        raise InputError(f"image {keys[k].item()!r} has a second gravity line", path, int(lines[k]))


def _csv_sigma(col, m: int, path, lines) -> np.ndarray:
    """The CSV's ``sigma_deg`` column: an empty field is no sigma (NaN)."""
    out = np.full(m, np.nan)
    if col is None:
        return out
    for k, v in enumerate(col.tolist()):
        v = v.strip()
        if not v:
            continue
        try:
            x = float(v)
        except ValueError:
            raise InputError(f"sigma_deg is not a number: {v[:40]!r}", path, int(lines[k])) from None
        if not np.isfinite(x):
            raise InputError(f"sigma_deg is not finite ({v})", path, int(lines[k]))
        out[k] = x
    return out


def read_gravity_file(path, fmt: str = "auto") -> GravityTable:
    """Read a gravity file (module docstring): ``fmt`` is ``auto`` (CSV when the first data
    line has a comma), ``text`` or ``csv``."""
    if fmt not in ("auto", "text", "csv"):
        raise OptionError(f"unknown format {fmt!r}; expected auto, text or csv")
    p = str(path)
    text = read_text(Path(path))
    first = first_data_line(text)
    if first is None:
        raise InputError(f"no gravity directions (expected lines '{_LAYOUT}' or a CSV header image_id,gx,gy,gz)", p, 1)
    if fmt == "auto":
        fmt = detect_table_format(first[2])
    if fmt == "csv":
        header, table = read_csv_table(p, text, ("gx", "gy", "gz"), ("sigma_deg",),
                                       kinds={"image_id": "id", "name": "name", "sigma_deg": "name"},
                                       noun="gravity directions", require_any=("image_id", "name"))
        col = dict(zip(header, table.cols))
        keys = col["image_id"] if "image_id" in col else col["name"]
        g = np.stack([col["gx"], col["gy"], col["gz"]], axis=1)
        sigma = _csv_sigma(col.get("sigma_deg"), len(keys), p, table.lines)
    else:
        nf = len(first[2].split())
        if nf not in (4, 5):
            raise InputError(f"expected 4 or 5 fields '{_LAYOUT}', got {nf}", p, first[0])
        # sigma_deg missing on a line: -1 (negative values given are errors below)
        table = read_table(p, text, counts=(4, 5), kinds=("id", "f", "f", "f", "f"),
                           names=("image_id", "gx", "gy", "gz", "sigma_deg"), what=_LAYOUT, defaults={4: -1.0})
        keys = table.cols[0]
        g = table.floats(1, 4)
        sigma = table.cols[4].copy()
        given = np.asarray(table.nfields) == 5
        bad = given & (sigma < 0)
        if bad.any():
            k = int(np.argmax(bad))
            raise InputError(f"sigma_deg must be >= 0, got {sigma[k]:g}", p, int(table.lines[k]))
        sigma[~given] = np.nan
    if fmt == "csv":
        bad = sigma < 0  # NaN compares False
        if bad.any():
            k = int(np.argmax(bad))
            raise InputError(f"sigma_deg must be >= 0, got {sigma[k]:g}", p, int(table.lines[k]))
    lines = np.asarray(table.lines)
    _check_keys(np.asarray(keys), p, lines)
    return GravityTable(np.asarray(keys), _normalise(g, p, lines), np.asarray(sigma, dtype=np.float64), lines, p)


def read_colmap_gravity(database) -> GravityTable:
    """The gravity of every image whose COLMAP pose prior has one (``PosePrior.gravity``,
    camera frame), from ``database`` opened on a private copy (the file is only read).
    ``keys`` are COLMAP image ids; ``sigma_deg`` NaN (COLMAP stores no gravity noise)."""
    from .colmap_project import database_copy

    path = Path(database)
    ids, gs = [], []
    with database_copy(path) as db:
        image_ids = {im.image_id for im in db.read_all_images()}
        for prior in db.read_all_pose_priors():
            if not prior.has_gravity():
                continue
            cid = prior.corr_data_id
            if str(cid.sensor_id.type).rsplit(".", 1)[-1] != "CAMERA" or cid.id not in image_ids:
                continue
            ids.append(int(cid.id))
            gs.append(np.asarray(prior.gravity, dtype=np.float64))
    keys = np.array(ids, dtype=np.int64)
    g = np.array(gs, dtype=np.float64).reshape(-1, 3)
    if len(keys):
        order = np.argsort(keys, kind="stable")
        keys, g = keys[order], g[order]
        if (keys[1:] == keys[:-1]).any():
            raise InputError(f"image {int(keys[1:][keys[1:] == keys[:-1]][0])} has two pose priors with a gravity", str(path))
        g = _normalise(g, str(path), None)
    return GravityTable(keys, g, np.full(len(keys), np.nan), None, str(path))


def gravity_for_graph(table: GravityTable, node_ids, names=None, default_sigma_deg: float | None = None,
                      ) -> tuple[np.ndarray, np.ndarray]:
    """The ``(gravity (n, 3) NaN rows for images without one, sigma_deg (n,))`` of a graph's
    nodes (``node_ids``, ``names``: :class:`~rotgraph.viewgraph.ViewGraph`'s), for
    :meth:`rotgraph.viewgraph.ViewGraph.with_gravity`.

    The table's keys are matched to the node ids, or to the names when they match more of
    them (a key matching neither is logged, not an error: a gravity file may cover images the
    graph has dropped); no key matching any node is an :class:`InputError`. Images without
    their own ``sigma_deg`` take ``default_sigma_deg``; None (the default): NaN, which the
    solve estimates from the data (a given value always wins).
    """
    node_ids = np.asarray(node_ids)
    n = len(node_ids)
    keys = np.array([str(k) for k in table.keys.tolist()])
    candidates = [("id", np.array([str(k) for k in node_ids.tolist()]))]
    if names is not None:
        candidates.append(("name", np.array([str(k) for k in np.asarray(names).tolist()])))
    best = None
    for what, labels in candidates:
        order = np.argsort(labels, kind="stable")
        pos = np.searchsorted(labels[order], keys)
        pos = np.minimum(pos, max(n - 1, 0))
        hit = (labels[order][pos] == keys) if n else np.zeros(len(keys), bool)
        if best is None or hit.sum() > best[2].sum():
            best = (what, order[pos], hit)
    what, node, hit = best
    if not hit.any():
        raise InputError(f"no gravity line names an image of the view graph (by id{' or name' if names is not None else ''})",
                         table.path, None if table.lines is None else int(table.lines[0]))
    if not hit.all():
        k = int(np.argmax(~hit))
        where = "" if table.lines is None else f" (first: line {int(table.lines[k])})"
        logger.warning("%s: %d gravity direction(s) for images not in the view graph, ignored, e.g. %r%s", table.path,
                       int((~hit).sum()), table.keys[k].item(), where)
    g = np.full((n, 3), np.nan)
    s = np.full(n, np.nan if default_sigma_deg is None else float(default_sigma_deg))
    g[node[hit]] = table.gravity[hit]
    own = hit & np.isfinite(table.sigma_deg)
    s[node[own]] = table.sigma_deg[own]
    logger.info("gravity for %d of %d images (matched by %s)", int(hit.sum()), n, what)
    return g, s
