"""1DSfM scenes and Bundler files: the edge format ``1dsfm`` of
:func:`rotgraph.io.edges.read_edge_file`, and the ``bundler`` ground truth of
:func:`rotgraph.io.rotations.read_absolute_rotations`.

A 1DSfM scene folder (``EGs.txt``; optional ``list.txt``, ``gt_bundle.out``,
``cc.txt``) or the path of its ``EGs.txt``. ``EGs.txt`` lines are
``i j r11 r12 ... r33 t1 t2 t3`` (row-major). The EG rotation is ``R = R_i R_j^T``
(camera j -> camera i) in the Bundler camera frame (x right, y up, looking down -z),
so ``R_ij = R^T``; the reader also converts to the computer-vision camera frame
(x right, y down, z forward): ``R_ij = D R^T D`` with ``D = diag(1, -1, -1)``.
``gt_bundle.out`` (Bundler v0.3, world -> camera) gives ``gt_cam_from_world = D R``
for every camera whose rotation is not all zero (Bundler's mark of an unregistered
camera); ``list.txt`` gives the node names (its first field, as written, e.g.
``images/NAME.jpg``; line index = id). ``cc.txt`` is informational only.
How the direction was established (there is no 1DSfM ground truth in shared/): (1)
TheiaSfM's 1DSfM reader (``read_1dsfm.cc``: "the rotation defines the camera 2 to
camera 1 transformation ... we read in the transpose", then conjugates with
diag(1, -1, -1)); (2) 1DSfM's ``sfminit`` places camera j at ``EG.R^T`` with camera i
at the identity; (3) the Chatterjee-format files packed from 1DSfM scenes use
``RR = inv(EG R)`` and match ``Rgt_j Rgt_i^T`` - which Ellis.mat's ground truth
confirms (see ``mat``); (4) on Madrid_Metropolis the triangle closures are smaller as
read than transposed (5th/10th/25th percentiles 1.7/3.0/8.7 vs 3.0/5.1/11.7 degrees over
20,000 random triangles; a weak test, landmark scenes turn mostly about one axis). The
D conjugation does not change the direction; it only keeps the edges and the
ground truth in one (computer-vision) frame.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from .. import so3_checks
from ..errors import InputError
from ..viewgraph import ViewGraph
from .graphs import graph_from_codes, no_edges
from .tables import read_table
from .compressed import uncompressed_name
from .text import is_float, read_text

__all__ = ["read_1dsfm", "read_bundler"]

logger = logging.getLogger(__name__)

# D = diag(1, -1, -1) as a sign pattern: D A D == _DSIGN * A, D A == _DSIGN_ROWS * A.
_DSIGN = np.outer([1.0, -1.0, -1.0], [1.0, -1.0, -1.0])
_DSIGN_ROWS = np.array([1.0, -1.0, -1.0])[:, None]

_EGS_WHAT = "i j r11 r12 r13 r21 r22 r23 r31 r32 r33 t1 t2 t3"


def read_1dsfm(path: Path, duplicates: str) -> ViewGraph:
    """Read a 1DSfM scene folder or its ``EGs.txt`` (module docstring)."""
    folder = path if path.is_dir() else path.parent
    egs = folder / "EGs.txt" if path.is_dir() else path
    if path.is_dir() and not egs.is_file():
        raise InputError("1DSfM folder without EGs.txt", str(path))
    # list.txt / gt_bundle.out / cc.txt belong to the scene: read them beside EGs.txt only.
    scene = path.is_dir() or uncompressed_name(path).lower() == "egs.txt"  # EGs.txt.gz too
    text = read_text(egs)
    names = ("i", "j") + tuple(f"r{a}{b}" for a in (1, 2, 3) for b in (1, 2, 3)) + ("t1", "t2", "t3")
    table = read_table(egs, text, counts=(14,), kinds=("int", "int") + ("f",) * 9 + ("u",) * 3, names=names, what=_EGS_WHAT)
    if len(table) == 0:
        raise no_edges(egs, _EGS_WHAT)
    R = so3_checks.check_rotations(table.floats(2, 11).reshape(-1, 3, 3), path=egs, lines=table.lines)
    # EG R = R_i R_j^T (Bundler frame) -> R_ij = R^T; to the computer-vision frame: D R^T D.
    rel = _DSIGN * np.swapaxes(R, 1, 2)
    ids_i, ids_j = table.cols[0], table.cols[1]
    node_ids, codes_i, codes_j = table.index(0, 1)
    node_names = None
    list_path = folder / "list.txt"
    if scene and list_path.is_file():
        listed = _read_1dsfm_list(list_path)
        if node_ids[-1] >= len(listed):
            k = int(np.argmax((ids_i >= len(listed)) | (ids_j >= len(listed))))
            raise InputError(
                f"camera id {int(max(ids_i[k], ids_j[k]))} has no line in {list_path} ({len(listed)} images)",
                str(egs), int(table.lines[k]),
            )
        node_names = listed[node_ids]
    graph = graph_from_codes(egs, table.lines, node_ids, codes_i, codes_j, rel, None, duplicates, names=node_names)
    bundle = folder / "gt_bundle.out"
    if scene and bundle.is_file():
        gt_all = read_bundler(bundle)
        gt = np.full((graph.n_nodes, 3, 3), np.nan)
        inside = graph.node_ids < len(gt_all)
        gt[inside] = gt_all[graph.node_ids[inside]]
        if not inside.all():
            logger.warning("%s: %d cameras of EGs.txt are beyond its %d cameras", bundle, int((~inside).sum()), len(gt_all))
        graph.gt_cam_from_world = gt
        graph.meta["gt_source"] = str(bundle)
    cc = folder / "cc.txt"
    if scene and cc.is_file():
        graph.meta["1dsfm_cc_path"] = str(cc)
    graph.meta["camera_frame"] = "computer vision (x right, y down, z forward); converted from Bundler by D = diag(1,-1,-1)"
    return graph


def _read_1dsfm_list(path: Path) -> np.ndarray:
    names = []
    for line in read_text(path).splitlines():
        s = line.strip()
        names.append(s.split()[0] if s else "")
    while names and names[-1] == "":
        names.pop()
    return np.array(names, dtype=str)


def read_bundler(path: Path) -> np.ndarray:
    """World -> camera rotations ``(N, 3, 3)`` of a Bundler v0.3 file, converted to the
    computer-vision camera frame (``D R``); NaN for unregistered (all-zero) cameras."""
    text = read_text(path)
    lines = text.splitlines()
    k = 0
    while k < len(lines) and (not lines[k].strip() or lines[k].lstrip().startswith("#")):
        k += 1
    if k == len(lines):
        raise InputError("empty Bundler file (expected '# Bundle file v0.3', then 'num_cameras num_points')", str(path), None)
    counts = lines[k].split()
    if len(counts) != 2 or not all(c.isdigit() for c in counts):
        raise InputError(f"expected 'num_cameras num_points', got {lines[k].strip()[:60]!r}", str(path), k + 1)
    n = int(counts[0])
    first = k + 1
    need = first + 5 * n
    if len(lines) < need:
        raise InputError(f"truncated: {n} cameras need {5 * n} lines after the counts", str(path), len(lines))
    block = lines[first:need]
    try:
        vals = np.array(" ".join(block).split(), dtype=np.float64)
    except ValueError:
        vals = None
    if vals is None or vals.size != 15 * n:
        for r, s in enumerate(block):
            f = s.split()
            if len(f) != 3 or not all(is_float(x) for x in f):
                raise InputError(f"expected 3 numbers, got {s.strip()[:60]!r}", str(path), first + r + 1)
        raise AssertionError("unreachable")  # pragma: no cover
    cams = vals.reshape(n, 5, 3)
    R = cams[:, 1:4, :]
    registered = np.any(R != 0, axis=(1, 2))
    out = np.full((n, 3, 3), np.nan)
    idx = np.flatnonzero(registered)
    out[idx] = _DSIGN_ROWS * so3_checks.check_rotations(R[idx], path=path, lines=first + 5 * idx + 2)
    return out
