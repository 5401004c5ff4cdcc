"""Files for ``rotgraph handeye``: paired motions (``A``, ``B``) and paired absolute poses.

Motions (the default)
    ``A`` holds the robot motions ``L_i``, ``B`` the camera motions ``R_i``, line ``i`` of
    one paired with line ``i`` of the other: ``qw qx qy qz [weight]`` text lines (``#``
    comments) or a CSV with columns ``qw,qx,qy,qz[,weight]`` (other columns ignored), as
    read by :func:`rotgraph.io.rotations.read_weighted_quaternions`. A pair's weight is the
    product of the weights given in ``A`` and ``B`` (default 1).

Poses (``--poses``)
    ``A`` holds robot poses ``base_from_gripper`` (OpenCV's ``gripper2base``), ``B`` camera
    poses ``cam_from_target`` (OpenCV's ``target2cam``, e.g. from ``solvePnP``), one pose a
    line, every line of a file in the same layout:

    * 16 numbers: a 4x4 homogeneous matrix, row-major (last row ``0 0 0 1``);
    * 12 numbers: the top 3x4 rows ``[R | t]``, row-major;
    * 7 numbers: ``qw qx qy qz tx ty tz``;
    * or a CSV with columns ``qw,qx,qy,qz`` and optionally ``tx,ty,tz``.

    Rotation blocks must be rotations to 1e-3 (max entry; robot controllers print few
    digits; :func:`rotgraph.so3.check_rotations`); they are projected onto SO(3). The translations (both files in the
    same unit) give the hand-eye translation and, by default, a joint estimate of the
    rotation and translation (:mod:`rotgraph.estimators.handeye`); a CSV without ``tx,ty,tz`` has none.

Quaternions go through :func:`rotgraph.so3.check_quaternions` and the tables through
:mod:`rotgraph.io.tables`: every malformed line is an :class:`~rotgraph.errors.InputError`
naming the file and line; ``A`` and ``B`` with different numbers of rows is one naming
the shorter file (at its end).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .. import so3, so3_checks
from ..errors import InputError
from .rotations import read_quaternion_table, read_weighted_quaternions
from .table_lines import first_data_line
from .tables import read_table
from .text import read_text

__all__ = ["MotionPairs", "PosePairs", "read_motion_pairs", "read_poses", "read_pose_pairs"]


class MotionPairs(NamedTuple):
    robot: np.ndarray  # (N, 4) unit quaternions L_i (w, x, y, z)
    camera: np.ndarray  # (N, 4) unit quaternions R_i
    weights: np.ndarray  # (N,)
    lines_a: list[int]  # 1-based line numbers of the pairs in A
    lines_b: list[int]


class PosePairs(NamedTuple):
    base_from_gripper: np.ndarray  # (N, 3, 3) rotations
    cam_from_target: np.ndarray  # (N, 3, 3) rotations
    lines_a: list[int]
    lines_b: list[int]
    base_from_gripper_t: np.ndarray | None = None  # (N, 3) translations (None: not in the file)
    cam_from_target_t: np.ndarray | None = None  # (N, 3)

    def poses(self) -> tuple[np.ndarray, np.ndarray] | None:
        """Both pose sets as (N, 4, 4) homogeneous matrices, or None when either file has no translations."""
        if self.base_from_gripper_t is None or self.cam_from_target_t is None:
            return None
        out = []
        for R, t in ((self.base_from_gripper, self.base_from_gripper_t), (self.cam_from_target, self.cam_from_target_t)):
            P = np.tile(np.eye(4), (len(R), 1, 1))
            P[:, :3, :3] = R
            P[:, :3, 3] = t
            out.append(P)
        return out[0], out[1]


def _end_line(path) -> int:
    """The line just after the last line of the file (where a missing row would go)."""
    return len(read_text(path).splitlines()) + 1


def _check_same_length(path_a, n_a: int, path_b, n_b: int, what: str) -> None:
    if n_a == n_b:
        return
    short, n_short, long_, n_long = (path_a, n_a, path_b, n_b) if n_a < n_b else (path_b, n_b, path_a, n_a)
    raise InputError(
        f"{n_short} {what} in this file but {n_long} in {long_}: A and B must have one line per pair, in the same order",
        str(short),
        _end_line(short),
    )


def read_motion_pairs(path_a, path_b, fmt: str = "auto") -> MotionPairs:
    """Read paired motions: robot ``L_i`` from ``path_a``, camera ``R_i`` from ``path_b``."""
    qa, wa, la = read_weighted_quaternions(path_a, fmt)
    qb, wb, lb = read_weighted_quaternions(path_b, fmt)
    _check_same_length(path_a, len(qa), path_b, len(qb), "rotations")
    w = wa * wb
    if not (w > 0).any():
        raise InputError("every pair has weight zero in A or in B", str(path_a), la[0])
    return MotionPairs(qa, qb, w, la, lb)


_POSE_LAYOUTS = {16: "4x4 matrix", 12: "3x4 matrix", 7: "qw qx qy qz tx ty tz"}


def read_poses(path, fmt: str = "auto") -> tuple[np.ndarray, np.ndarray | None, list[int]]:
    """Read absolute poses (module docstring): ``(rotations (N,3,3), translations (N,3), line_numbers)``;
    the translations are None for a CSV without ``tx,ty,tz``."""
    text, lines, q, extra = read_quaternion_table(
        path, fmt, text_layout="one pose a line (16, 12 or 7 numbers)", extra=("tx", "ty", "tz"), noun="poses",
    )
    if lines is not None:  # CSV
        t = np.stack([extra[c] for c in ("tx", "ty", "tz")], axis=1) if len(extra) == 3 else None
        return _rotations_of_quaternions(q, path, lines), t, lines.tolist()
    number, _, line = first_data_line(text)
    n_fields = len(line.split())
    if n_fields not in _POSE_LAYOUTS:
        raise InputError(
            f"expected a pose: 16 numbers (4x4 row-major), 12 (3x4 [R|t]) or 7 (qw qx qy qz tx ty tz), got {n_fields} fields",
            str(path), number,
        )
    names = ("qw", "qx", "qy", "qz", "tx", "ty", "tz") if n_fields == 7 else tuple(
        f"m{r + 1}{c + 1}" for r in range(n_fields // 4) for c in range(4))
    table = read_table(path, text, counts=(n_fields,), kinds=("f",) * n_fields, names=names, what="like the first pose line")
    lines = table.lines
    x = table.floats(0, n_fields)
    if n_fields == 7:
        return _rotations_of_quaternions(x[:, :4], path, lines), x[:, 4:], lines.tolist()
    x = x.reshape(-1, n_fields // 4, 4)
    if n_fields == 16:
        bad = np.abs(x[:, 3] - [0.0, 0.0, 0.0, 1.0]).max(axis=1) > 1e-6
        if bad.any():
            k = int(np.argmax(bad))
            got = " ".join(f"{v:g}" for v in x[k, 3])
            raise InputError(f"the last row of a 4x4 pose must be 0 0 0 1, got {got}", str(path), int(lines[k]))
    layout = _POSE_LAYOUTS[n_fields]
    R = so3_checks.check_rotations(x[:, :3, :3], path=path, lines=lines, label=lambda k: f"the rotation block of the {layout}")
    return R, x[:, :3, 3].copy(), lines.tolist()


def _rotations_of_quaternions(q: np.ndarray, path, lines) -> np.ndarray:
    return so3.matrices_from_quaternions(so3_checks.check_quaternions(q, path=path, lines=lines))


def read_pose_pairs(path_a, path_b, fmt: str = "auto") -> PosePairs:
    """Read paired absolute poses: ``base_from_gripper`` from ``path_a``, ``cam_from_target`` from ``path_b``."""
    Ra, ta, la = read_poses(path_a, fmt)
    Rb, tb, lb = read_poses(path_b, fmt)
    _check_same_length(path_a, len(Ra), path_b, len(Rb), "poses")
    return PosePairs(Ra, Rb, la, lb, ta, tb)
