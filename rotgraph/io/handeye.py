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

    Rotation blocks must be orthonormal with determinant +1 to 1e-3 (robot controllers
    print few digits); they are projected onto SO(3). The translations (both files in the
    same unit) give the hand-eye translation and, by default, a joint estimate of the
    rotation and translation (:mod:`rotgraph.estimators.handeye`); a CSV without ``tx,ty,tz`` has none.

Every malformed line is an :class:`~rotgraph.errors.InputError` naming the file and line;
``A`` and ``B`` with different numbers of rows is one naming the shorter file (at its end).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .. import so3
from ..errors import InputError
from .rotations import _check_quaternions, _looks_like_csv, read_weighted_quaternions
from .text import Rows, parse_floats, read_csv_table, read_rows, read_text

__all__ = ["MotionPairs", "PosePairs", "read_motion_pairs", "read_poses", "read_pose_pairs"]

_ORTHONORMAL_TOL = 1e-3


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


def _check_rotation_blocks(R: np.ndarray, rows: Rows, layout: str) -> np.ndarray:
    """Rotation blocks (N, 3, 3) close to SO(3), projected onto it; else an error at the line."""
    RRt = R @ np.swapaxes(R, 1, 2)
    off = np.abs(RRt - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(R)
    bad = (off > _ORTHONORMAL_TOL) | (det <= 0)
    if bad.any():
        k = int(np.argmax(bad))
        what = "a reflection (det < 0)" if det[k] <= 0 else f"not orthonormal (max |R R^T - I| = {off[k]:.2g} > {_ORTHONORMAL_TOL:g})"
        raise InputError(f"the rotation block of the {layout} is {what}", rows.path, rows.line_numbers[k])
    return so3.project_to_so3(R)


def read_poses(path, fmt: str = "auto") -> tuple[np.ndarray, np.ndarray | None, list[int]]:
    """Read absolute poses (module docstring): ``(rotations (N,3,3), translations (N,3), line_numbers)``;
    the translations are None for a CSV without ``tx,ty,tz``."""
    if fmt == "auto":
        fmt = "csv" if _looks_like_csv(path) else "text"
    if fmt == "csv":
        header, data = read_csv_table(path, ["qw", "qx", "qy", "qz"], "qw,qx,qy,qz[,tx,ty,tz]", "poses")
        names = ["qw", "qx", "qy", "qz"]
        q = parse_floats(data, [header.index(c) for c in names], names)
        tnames = [c for c in ("tx", "ty", "tz") if c in header]
        t = parse_floats(data, [header.index(c) for c in tnames], tnames) if len(tnames) == 3 else None
        return _rotations_of_quaternions(q, data), t, data.line_numbers
    if fmt != "text":
        raise ValueError(f"unknown format {fmt!r}; expected auto, text or csv")
    data = read_rows(path)
    if len(data) == 0:
        raise InputError("the file is empty, expected one pose a line (16, 12 or 7 numbers)", str(path), 1)
    n_fields = len(data.fields[0])
    if n_fields not in (16, 12, 7):
        raise InputError(
            f"expected a pose: 16 numbers (4x4 row-major), 12 (3x4 [R|t]) or 7 (qw qx qy qz tx ty tz), got {n_fields} fields",
            data.path, data.line_numbers[0],
        )
    for ln, f in zip(data.line_numbers, data.fields):
        if len(f) != n_fields:
            raise InputError(f"expected {n_fields} fields like the first pose line, got {len(f)}", data.path, ln)
    if n_fields == 7:
        names = ["qw", "qx", "qy", "qz", "tx", "ty", "tz"]
        x = parse_floats(data, list(range(7)), names)
        return _rotations_of_quaternions(x[:, :4], data), x[:, 4:], data.line_numbers
    names = [f"m{r + 1}{c + 1}" for r in range(n_fields // 4) for c in range(4)]
    x = parse_floats(data, list(range(n_fields)), names).reshape(-1, n_fields // 4, 4)
    layout = "4x4 matrix" if n_fields == 16 else "3x4 matrix"
    if n_fields == 16:
        bad = np.abs(x[:, 3] - [0.0, 0.0, 0.0, 1.0]).max(axis=1) > 1e-6
        if bad.any():
            k = int(np.argmax(bad))
            got = " ".join(f"{v:g}" for v in x[k, 3])
            raise InputError(f"the last row of a 4x4 pose must be 0 0 0 1, got {got}", data.path, data.line_numbers[k])
    R = _check_rotation_blocks(x[:, :3, :3], data, layout)
    return R, x[:, :3, 3].copy(), data.line_numbers


def _rotations_of_quaternions(q: np.ndarray, rows: Rows) -> np.ndarray:
    return so3.matrices_from_quaternions(_check_quaternions(q, rows))


def read_pose_pairs(path_a, path_b, fmt: str = "auto") -> PosePairs:
    """Read paired absolute poses: ``base_from_gripper`` from ``path_a``, ``cam_from_target`` from ``path_b``."""
    Ra, ta, la = read_poses(path_a, fmt)
    Rb, tb, lb = read_poses(path_b, fmt)
    _check_same_length(path_a, len(Ra), path_b, len(Rb), "poses")
    return PosePairs(Ra, Rb, la, lb, ta, tb)
