"""Rig files: which image was taken by which sensor of a rig in which frame (issue #17), for
inputs without COLMAP's rigs and frames (edge lists, g2o, ...).

Format: one line per image, white space or CSV (a header ``image_id,frame_id,sensor_id``
with optional ``qw,qx,qy,qz``; ``#`` comments)::

    # image_id frame_id sensor_id [qw qx qy qz]
    0 0 0 1 0 0 0
    1 0 1
    2 1 0 1 0 0 0
    3 1 1

``frame_id``: one capture of the rig (frame ids are global: two rigs never share one);
``sensor_id``: the camera of the rig that took the image (global too: every image of one
sensor shares its rotation in the rig); ``qw qx qy qz``: the sensor's ``cam_from_rig``
rotation when known (the same on every line of the sensor), absent when unknown (then
estimated by ``rotgraph solve``). The rig of a sensor is the set of sensors that share
frames with it; its *reference* sensor (``cam_from_rig`` the identity by definition) is the
sensor given the identity quaternion, else the smallest sensor id (quaternions given for
the others are then relative to it). ``image_id`` matches the input's camera ids, or its
camera names when it has names (COLMAP). Images of the graph absent from the file are
frames of their own.
"""

from __future__ import annotations

import logging

import numpy as np

from .. import so3, so3_checks
from ..errors import InputError
from ..graph_analysis import connected_components
from ..viewgraph import Rigs, ViewGraph
from .formats import detect_table_format
from .table_lines import first_data_line
from .tables import read_csv_table, read_table
from .text import read_text

__all__ = ["read_rigs", "RIG_FILE_COLUMNS"]

logger = logging.getLogger(__name__)

RIG_FILE_COLUMNS = ("image_id", "frame_id", "sensor_id")
_Q = ("qw", "qx", "qy", "qz")
IDENTITY_TOL = 1e-9  # radians: a quaternion this close to the identity marks the reference sensor
CONSISTENT_TOL = 1e-6  # radians: a sensor's quaternions on its lines must agree this well


def _table(path):
    text = read_text(path)
    first = first_data_line(text)
    if first is None:
        raise InputError("the rig file is empty, expected lines image_id frame_id sensor_id [qw qx qy qz]", str(path), 1)
    if detect_table_format(first[2]) == "csv":
        header, t = read_csv_table(path, text, RIG_FILE_COLUMNS, _Q, noun="rig lines", all_or_none=(_Q,),
                                   kinds={"image_id": "id", "frame_id": "int", "sensor_id": "int",
                                          **{c: "u" for c in _Q}})
        col = dict(zip(header, t.cols))
        q = np.stack([np.asarray(col[c], dtype=np.float64) for c in _Q], axis=1) if "qw" in col else np.full((len(t), 4), np.nan)
        return t.lines, col["image_id"], col["frame_id"], col["sensor_id"], q
    t = read_table(path, text, counts=(3, 7), kinds=("id", "int", "int", "u", "u", "u", "u"),
                   names=RIG_FILE_COLUMNS + _Q, what="image_id frame_id sensor_id [qw qx qy qz]",
                   defaults={3: np.nan, 4: np.nan, 5: np.nan, 6: np.nan})
    q = np.stack([np.asarray(t.cols[c], dtype=np.float64) for c in range(3, 7)], axis=1)
    return t.lines, t.cols[0], t.cols[1], t.cols[2], q


def read_rigs(path, graph: ViewGraph) -> Rigs:
    """The :class:`~rotgraph.viewgraph.Rigs` of ``graph``'s cameras from the rig file
    ``path`` (see the module docstring). Raises :class:`InputError` (file and line) for a bad
    line, an image listed twice, a sensor given two different rotations, or a file that
    names none of the graph's cameras."""
    lines, image, frame, sensor, q = _table(path)
    if len(lines) == 0:
        raise InputError("no rig lines in the file", str(path), None)
    given = np.isfinite(q).all(axis=1)
    partial = ~given & np.isfinite(q).any(axis=1)
    if partial.any():
        raise InputError("give all four of qw qx qy qz, or none", str(path), int(lines[np.argmax(partial)]))
    R = np.full((len(lines), 3, 3), np.nan)
    if given.any():
        R[given] = so3.matrices_from_quaternions(so3_checks.check_quaternions(q[given], path=path, lines=lines[given]))
    # image -> graph node: by id, else by name
    keys = np.asarray(image)
    if keys.dtype.kind in "iu":
        pos = np.searchsorted(graph.node_ids, keys)
        pos = np.minimum(pos, len(graph.node_ids) - 1)
        node = np.where(graph.node_ids[pos] == keys, pos, -1)
    else:
        node = np.full(len(keys), -1)
    if graph.names is not None and (node < 0).any():
        by_name = {str(nm): k for k, nm in enumerate(graph.names)}
        miss = np.flatnonzero(node < 0)
        node[miss] = [by_name.get(str(keys[m]), -1) for m in miss]
    order = np.argsort(node, kind="stable")
    s = node[order]
    dup = (s[1:] == s[:-1]) & (s[1:] >= 0)
    if dup.any():
        k = order[1:][dup]
        raise InputError(f"image {keys[k[np.argmin(lines[k])]]} is listed twice", str(path), int(lines[k].min()))
    found = node >= 0
    if not found.any():
        raise InputError(f"none of the {len(lines)} images of the rig file is a camera of the input", str(path), None)
    if not found.all():
        logger.warning("%s: %d of %d images of the rig file are not cameras of the input (the first at line %d): ignored",
                       path, int((~found).sum()), len(lines), int(lines[np.argmax(~found)]))
    lines, node, frame, sensor, R, given = lines[found], node[found], np.asarray(frame)[found], np.asarray(sensor)[found], R[found], given[found]
    # one rotation per sensor
    skeys, sinv = np.unique(sensor, return_inverse=True)
    K = len(skeys)
    S = np.full((K, 3, 3), np.nan)
    gi = np.flatnonzero(given)
    if len(gi):
        first_k, first = np.unique(sinv[gi], return_index=True)
        S[first_k] = R[gi[first]]
        bad = so3.angle_between(R[gi], S[sinv[gi]]) > CONSISTENT_TOL
        if bad.any():
            b = gi[np.argmax(bad)]
            raise InputError(f"sensor {sensor[b]} has another cam_from_rig rotation on an earlier line", str(path), int(lines[b]))
    known = np.isfinite(S).all(axis=(1, 2))
    # rigs: sensors joined by shared frames; each rig's reference sensor
    fkeys, finv = np.unique(frame, return_inverse=True)
    _, label = connected_components(K + len(fkeys), np.stack([sinv, K + finv], axis=1))
    rig_of_sensor = label[:K]
    identity = np.zeros(K, dtype=bool)
    identity[known] = so3.angle(S[known]) <= IDENTITY_TOL
    reference = np.zeros(K, dtype=bool)
    for r in np.unique(rig_of_sensor):  # one per rig: few
        members = np.flatnonzero(rig_of_sensor == r)
        ids = members[identity[members]] if identity[members].any() else members
        reference[ids[np.argmin(skeys[ids])]] = True
    S[reference] = np.eye(3)
    n = graph.n_nodes
    frame_ids = np.empty(n, dtype=np.int64)
    cam_from_rig = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
    sensor_ids = np.full(n, -1, dtype=np.int64)
    is_reference = np.zeros(n, dtype=bool)
    listed = np.zeros(n, dtype=bool)
    listed[node] = True
    frame_ids[node] = frame
    top = int(frame.max()) + 1 if len(frame) else 0
    frame_ids[~listed] = top + np.arange(int((~listed).sum()))  # frames of their own
    cam_from_rig[node] = S[sinv]
    sensor_ids[node] = sensor
    is_reference[node] = reference[sinv]
    logger.info("%s: %d images, %d frames, %d sensors in %d rig(s), %d sensor(s) with a given cam_from_rig",
                path, len(node), len(fkeys), K, len(np.unique(rig_of_sensor)), int((known & ~reference).sum()))
    return Rigs(frame_ids, cam_from_rig, sensor_ids, is_reference)
