"""g2o 3D pose graphs (``.g2o``): the edge format ``g2o`` of :func:`rotgraph.io.edges.read_edge_file`.

3D pose graph: ``VERTEX_SE3:QUAT id x y z qx qy qz qw`` (world_from_body) and
``EDGE_SE3:QUAT i j x y z qx qy qz qw`` + 21 information entries. The quaternions are
**x, y, z, w** in the file. The edge is ``T_i^-1 T_j``, whose rotation is
``Q_ij = Q_i^T Q_j``; with ``R_i = Q_i^T`` (body_from_world) that is ``R_ij = Q_ij^T``,
which the reader returns. Every edge weighs 1. The vertices are an initial guess, NOT
ground truth: in pose graphs (the SE-Sync sets garage, cubicle, ...) they are dead-reckoned
odometry. Their rotations ``Q_i^T`` land in ``graph.initial_cam_from_world`` (NaN rows for
cameras without a vertex line), which ``init="vertices"`` (``--init vertices``) starts the
iterative solvers from; ``graph.gt_cam_from_world`` stays None, and ``rotgraph eval``
refuses a g2o file as ground truth (:func:`rotgraph.io.rotations.read_absolute_rotations`).
Checked on parking-garage.g2o: the 1660 odometry edges ``(i, i+1)`` equal
``R_{i+1} R_i^T`` of the vertices to 1.7e-4 degrees (median 3.5e-5: the file's 6-digit
rounding) as read, vs median 2.8 and max 88 degrees transposed; triangle closure median
0.039 as read vs 0.69 degrees transposed.
``FIX``, ``VERTEX_TRACKXYZ``, ``VERTEX_XYZ``, ``EDGE_SE3_TRACKXYZ`` and
``PARAMS_SE3OFFSET`` lines are skipped (one warning with the counts); 2D tags
(``VERTEX_SE2``, ``EDGE_SE2...``) and any other tag are an error. The translation is
parsed and not used. Parallel edges are normal in pose graphs (cubicle.g2o:
16,869 edges over 12,486 pairs): ``duplicates`` decides; ``rotgraph.read_view_graph``'s
per-format default (``duplicates=None``, what the command line passes) keeps them.

Information: each ``EDGE_SE3:QUAT`` line ends with the 21 entries of the upper triangle,
row-major, of a 6x6 information matrix ``I`` over g2o's error ``(x, y, z, qx, qy, qz)``
(``BaseEdge::readInformationMatrix``: ``for i, for j >= i: is >> information()(i, j)``,
mirrored). g2o's error is ``toVectorMQT(Z^-1 T_i^-1 T_j)`` (``EdgeSE3::computeError``):
the translation and the vector part of the quaternion (``w >= 0``) of the error rotation
``E = M^T Q_i^T Q_j`` (``M`` the measured rotation). With ``E = exp([t]x)`` the vector part
is ``sin(|t|/2) t/|t| ~ t/2``, and ``M^T = exp([t]x) Q_j^T Q_i``: the edge rotation rotgraph
reads (``R_ij = M^T``) is perturbed by exactly ``d = t``, rotgraph's error (camera ``j``'s
frame). The quaternion part's marginal information is the Schur complement of the
translation block, ``S = I_qq - I_qt I_tt^+ I_tq`` (``I_qq`` itself when the cross terms are
zero), and ``d ~ 2 q`` gives ``H = S / 4`` (radians^-2), the ``graph.information`` of every
edge. Checked by a Monte Carlo test (``tests/test_information_io.py``): measurements drawn
in g2o's own error space with a full 6x6 information (cross terms included) give an
empirical covariance of ``d`` equal to ``H^-1`` within a few percent.
The entries must be finite numbers (g2o cannot read others either). A file in which some
edge's ``H`` is not positive definite (placeholders such as all ones or a translation-only
matrix; cubicle.g2o, whose 5,021 edges with cross terms have an indefinite 6x6 matrix) is
read without information, as before rotgraph read it: ``graph.meta["g2o_information_not_used"]``
and an info log (``-v``) name the first such line (the check is
:func:`~rotgraph.graph_build.check_information`). parking-garage.g2o: no cross terms, every
``H`` positive definite. g2o's 2D ``EDGE_SE2`` (information over ``(x, y, theta)``) would
give ``h I3``, ``h`` the Schur complement of theta (no tilt error in 2D), but 2D graphs are
not read.

Speed: the lines of the two common tags are found with vectorised byte compares, and
each tag's lines are parsed as one table by :func:`rotgraph.io.tables.read_table` (one
``np.loadtxt`` pass; about 4 s for 10^6 lines on one core of a loaded 2-core machine).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from .. import so3, so3_checks
from ..errors import InputError
from ..viewgraph import ViewGraph
from .formats import G2O_EDGE, G2O_SKIPPED, G2O_VERTEX
from .graphs import graph_from_codes
from .table_columns import unique
from .table_lines import simple_line_breaks
from .tables import read_table, symmetric_from_upper
from .text import read_text

__all__ = ["read_g2o", "rotation_information_from_g2o"]

logger = logging.getLogger(__name__)


class _LineIndex:
    """Byte offsets of the lines of a text (numbered as ``str.splitlines`` numbers them),
    so that lines can be picked out and parsed without a Python object per line."""

    def __init__(self, text: str):
        if not simple_line_breaks(text):
            text = "\n".join(text.splitlines())
        self.raw = text.encode("utf-8")
        self.data = np.frombuffer(self.raw, dtype=np.uint8)
        nl = np.flatnonzero(self.data == 10)
        self.starts = np.concatenate(([0], nl + 1))
        self.ends = np.concatenate((nl, [len(self.raw)]))
        if not self.raw or self.raw.endswith(b"\n"):
            self.starts, self.ends = self.starts[:-1], self.ends[:-1]

    def __len__(self) -> int:
        return len(self.starts)

    def line(self, k: int) -> str:
        return self.raw[self.starts[k]:self.ends[k]].decode("utf-8")

    def starting_with(self, tag: str) -> np.ndarray:
        """Mask of the lines that begin with ``tag`` followed by a space or a tab."""
        t = np.frombuffer(tag.encode(), dtype=np.uint8)
        mask = (self.ends - self.starts) > len(t)
        idx = np.flatnonzero(mask)
        s = self.starts[idx]
        hit = np.ones(len(idx), dtype=bool)
        for c, byte in enumerate(t.tolist()):
            hit &= self.data[s + c] == byte
        sep = self.data[s + len(t)]
        hit &= (sep == 32) | (sep == 9)
        out = np.zeros(len(self), dtype=bool)
        out[idx[hit]] = True
        return out

    def join(self, idx: np.ndarray) -> bytes:
        """The lines ``idx`` (sorted) as one text; runs of consecutive lines are one slice."""
        if len(idx) == 0:
            return b""
        brk = np.flatnonzero(np.diff(idx) != 1)
        first = np.concatenate(([0], brk + 1))
        last = np.concatenate((brk, [len(idx) - 1]))
        parts = [self.raw[a:b] for a, b in zip(self.starts[idx[first]].tolist(), self.ends[idx[last]].tolist())]
        return b"\n".join(parts)


def read_g2o(path: Path, duplicates: str) -> ViewGraph:
    """Read a g2o pose graph (module docstring); vertex rotations land in
    ``initial_cam_from_world`` (an initial guess, never ground truth)."""
    text = read_text(path)
    spath = str(path)
    lines = _LineIndex(text)
    del text
    # The two common tags are found with vectorised byte compares; the other lines (few:
    # comments, FIX, indented lines, ...) are looked at one by one.
    is_e = lines.starting_with(G2O_EDGE)
    is_v = lines.starting_with(G2O_VERTEX)
    skipped: dict[str, int] = {}
    for k in np.flatnonzero(~(is_e | is_v)).tolist():
        s = lines.line(k).strip()
        if not s or s.startswith("#"):
            continue
        tag = s.split(None, 1)[0]
        if tag == G2O_EDGE:
            is_e[k] = True
        elif tag == G2O_VERTEX:
            is_v[k] = True
        elif tag in G2O_SKIPPED:
            skipped[tag] = skipped.get(tag, 0) + 1
        elif tag.startswith(("EDGE_SE2", "VERTEX_SE2")):
            raise InputError(f"2D pose graphs are not supported ({tag})", spath, k + 1)
        else:
            raise InputError(f"unknown g2o tag {tag[:40]!r} (rotgraph reads VERTEX_SE3:QUAT and EDGE_SE3:QUAT)", spath, k + 1)
    if skipped:
        logger.warning("%s: skipped %s", spath, ", ".join(f"{n} {t} line(s)" for t, n in skipped.items()))
    e_idx = np.flatnonzero(is_e)
    v_idx = np.flatnonzero(is_v)
    if len(e_idx) == 0:
        raise InputError("no edges (no EDGE_SE3:QUAT lines)", spath)

    e_what = "EDGE_SE3:QUAT i j x y z qx qy qz qw + 21 information entries"
    ij, eq, info = _g2o_rows(lines, e_idx, spath, ids=2, nfields=31, what=e_what)
    vid, vq, _ = _g2o_rows(lines, v_idx, spath, ids=1, nfields=9, what="VERTEX_SE3:QUAT id x y z qx qy qz qw")
    e_lines, v_lines = e_idx + 1, v_idx + 1

    # file (x, y, z, w) -> rotgraph (w, x, y, z)
    Qe = so3.matrices_from_quaternions(so3_checks.check_quaternions(so3.wxyz_from_xyzw(eq), path=spath, lines=e_lines))
    rel = np.swapaxes(Qe, 1, 2)  # edge rotation Q_ij = Q_i^T Q_j (world_from_body): R_ij = Q_ij^T
    vid = vid[:, 0]
    order = np.argsort(vid, kind="stable")
    dup = np.flatnonzero(vid[order][1:] == vid[order][:-1])
    if len(dup):
        k = int(order[dup[0] + 1])
        raise InputError(f"vertex {int(vid[k])} is defined twice", spath, int(v_lines[k]))
    edge_nodes = unique(ij)
    node_ids = unique(np.concatenate([vid, edge_nodes]))
    if len(vid) and len(node_ids) > len(vid):
        logger.warning("%s: %d camera(s) appear in edges without a VERTEX_SE3:QUAT line", spath, len(node_ids) - len(vid))
    codes = np.searchsorted(node_ids, ij)
    information = rotation_information_from_g2o(info)
    unused: list[str] = []

    def not_used(exc: InputError) -> None:  # placeholders (e.g. all ones): read as before information was read
        unused.append(f"{exc.location()}{exc.message}")
        logger.info("%s: the file's information matrices are not used", unused[0])

    graph = graph_from_codes(path, e_lines, node_ids, codes[:, 0], codes[:, 1], rel, None, duplicates,
                             information=information, information_not_used=not_used)
    if len(vid):
        Qv = so3.matrices_from_quaternions(so3_checks.check_quaternions(so3.wxyz_from_xyzw(vq), path=spath, lines=v_lines))
        guess = np.full((graph.n_nodes, 3, 3), np.nan)
        guess[np.searchsorted(graph.node_ids, vid)] = np.swapaxes(Qv, 1, 2)  # R_i = Q_i^T
        graph.initial_cam_from_world = guess
    if skipped:
        graph.meta["g2o_skipped_lines"] = dict(skipped)
    if unused:
        graph.meta["g2o_information_not_used"] = unused[0]
    return graph


def rotation_information_from_g2o(upper) -> np.ndarray:
    """rotgraph's rotation information ``(E, 3, 3)`` of g2o ``EDGE_SE3:QUAT`` information
    matrices over ``(x, y, z, qx, qy, qz)``, given as their 21 upper-triangle entries
    (row-major, as in the file: ``(E, 21)``, or 21 columns ``(E,)``): ``S / 4``, ``S`` the
    Schur complement of the translation block (module docstring). Not checked here. Only
    the edges with cross terms (translation-rotation) need their whole 6x6 matrix."""
    cols = list(upper.T) if isinstance(upper, np.ndarray) else list(upper)
    k = {rc: n for n, rc in enumerate(zip(*(a.tolist() for a in np.triu_indices(6))))}
    S = symmetric_from_upper([cols[k[a + 3, b + 3]] for a, b in zip(*np.triu_indices(3))], 3)
    cross = np.zeros(len(S), dtype=bool)
    for a in range(3):
        for b in range(3, 6):
            cross |= cols[k[a, b]] != 0
    cross = np.flatnonzero(cross)
    if len(cross):  # pseudo-inverse: a singular translation block is the limit of no translation information
        info = symmetric_from_upper([col[cross] for col in cols], 6)
        q_t = info[:, 3:, :3]
        with np.errstate(all="ignore"):  # huge entries give non-finite S: rejected by the information check
            S[cross] -= q_t @ np.linalg.pinv(info[:, :3, :3], hermitian=True) @ np.swapaxes(q_t, 1, 2)
    return 0.25 * S


def _g2o_rows(lines: _LineIndex, idx: np.ndarray, path, *, ids: int, nfields: int, what: str):
    """Ids ``(K, ids)`` int64, quaternions ``(K, 4)`` (x, y, z, w, as in the file) and the
    columns after the quaternion (``nfields - ids - 8`` arrays (K,): the information entries,
    finite floats) of the g2o lines ``idx``, parsed as one table
    (:func:`~rotgraph.io.tables.read_table`). The translation is parsed (any float)."""
    rest = nfields - 1 - ids - 7
    if len(idx) == 0:
        return np.zeros((0, ids), np.int64), np.zeros((0, 4)), [np.zeros(0)] * rest
    r, c = np.triu_indices(6) if rest == 21 else ((), ())
    table = read_table(
        path, lines.join(idx), counts=(nfields,),
        kinds=("skip",) + ("int",) * ids + ("u",) * 3 + ("f",) * 4 + ("f",) * rest,
        names=("tag",) + ("vertex id",) * ids + ("x", "y", "z", "qx", "qy", "qz", "qw")
        + tuple(f"information({a},{b})" for a, b in zip(r, c)),
        what=what, line_of=idx + 1,
    )
    a = 1 + ids + 7
    return np.stack(table.cols[1:1 + ids], axis=1), table.floats(a - 4, a), table.cols[a:a + rest]
