"""Hand-eye calibration from two files: what ``rotgraph handeye`` does, as a library function.

:func:`solve_handeye_files` reads paired motions (or paired absolute poses, which it turns
into motions), solves for ``S`` (and ``t_X`` when the poses have translations) and maps the
per-motion residuals and inlier flags back to the input lines (per pose for poses). The
file formats are those of :mod:`rotgraph.io.handeye`.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from ..errors import UnsolvableError
from ..estimators.handeye import HandEyeResult, motions_from_poses, pose_residuals, solve_handeye

__all__ = ["HandEyeFilesResult", "solve_handeye_files"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class HandEyeFilesResult:
    """The outcome of :func:`solve_handeye_files`.

    Attributes
    ----------
    result : the :class:`~rotgraph.estimators.handeye.HandEyeResult` on the motions
        (``result.quaternion``, ``result.rotation``: ``S``; ``result.translation``: ``t_X``
        or None).
    path_a, path_b : the inputs.
    poses : whether the inputs were absolute poses (the motions formed from them).
    pairs_mode : ``"all"`` or ``"consecutive"`` (poses), else None.
    motion_pairs : (M, 2) pose indices of each motion (poses), else None.
    lines : line numbers in ``path_a`` of the input rows (pairs, or poses).
    residuals_deg, inliers : (len(lines),) per input row: the motion's residual and inlier
        flag, or per pose those of :func:`~rotgraph.estimators.handeye.pose_residuals`.
    translation_residuals, translation_inliers : the same for the translations (poses with
        translations), else None.
    notes : warnings about the input (not the solver's, which are in ``result.warnings``).
    seconds : wall time of reading and solving.
    """

    result: HandEyeResult
    path_a: str
    path_b: str
    poses: bool
    lines: list[int]
    residuals_deg: np.ndarray
    inliers: np.ndarray
    seconds: float
    pairs_mode: str | None = None
    motion_pairs: np.ndarray | None = None
    translation_residuals: np.ndarray | None = None
    translation_inliers: np.ndarray | None = None
    notes: tuple[str, ...] = field(default_factory=tuple)
    loss: str | None = None

    @property
    def warnings(self) -> tuple[str, ...]:
        """The solver's warnings, then the notes about the input."""
        return tuple(self.result.warnings) + self.notes

    def to_dict(self) -> dict:
        """The summary ``rotgraph handeye --json`` prints (one entry per input line in
        ``residuals_deg`` and ``inlier``; with poses the per-motion values under ``motions``)."""
        res = self.result
        out = {
            "quaternion": [float(v) for v in res.quaternion],
            "rotation": res.rotation.tolist(),
            "convention": "R_i ~ S^-1 L_i S" + ("; S = gripper_from_camera (OpenCV R_cam2gripper)" if self.poses else ""),
            "method": res.method,
            "n_pairs": int(len(self.residuals_deg)),
            "n_inliers": int(self.inliers.sum()),
            "residuals_deg": _finite_list(self.residuals_deg),
            "inlier": [bool(v) for v in self.inliers],
            "cost": res.cost,
            "iterations": res.iterations,
            "converged": res.converged,
            "threshold_deg": res.threshold_deg,
            "conditioning": res.conditioning,
            "warnings": list(self.warnings),
            "seconds": self.seconds,
            "translation": None if res.translation is None else [float(v) for v in res.translation],
        }
        if res.method == "robust":
            out.update(loss=self.loss, scale_deg=res.scale_deg)
        if res.translation is not None:
            out.update(
                joint=res.joint,
                translation_residuals=_finite_list(self.translation_residuals),
                translation_inlier=[bool(v) for v in self.translation_inliers],
                translation_threshold=res.translation_threshold,
                sigma_deg=res.sigma_deg,
                sigma_translation=res.sigma_translation,
            )
        if self.poses:
            out["motions"] = {
                "pairs_mode": self.pairs_mode,
                "n_motions": int(len(res.residuals_deg)),
                "n_inliers": res.n_inliers,
                "pairs": self.motion_pairs.tolist(),
                "residuals_deg": [float(v) for v in res.residuals_deg],
                "inlier": [bool(v) for v in res.inliers],
            }
            if res.translation is not None:
                out["motions"].update(
                    translation_residuals=[float(v) for v in res.translation_residuals],
                    translation_inlier=[bool(v) for v in res.translation_inliers],
                )
        return out


def _finite_list(x) -> list:
    return [None if not np.isfinite(v) else float(v) for v in x]


def solve_handeye_files(
    path_a,
    path_b,
    *,
    poses: bool = False,
    pairs: Literal["all", "consecutive"] = "all",
    fmt: str = "auto",
    method: str = "robust",
    loss: str = "truncated_l2",
    scale_deg: float | None = None,
    threshold_deg: float | None = None,
    seed: int | None = 0,
    rotation_only: bool = False,
) -> HandEyeFilesResult:
    """Solve the hand-eye problem of two files: robot motions ``L_i`` in ``path_a`` and
    camera motions ``R_i`` in ``path_b``, one pair per line number.

    With ``poses``, the files hold absolute poses (``base_from_gripper``,
    ``cam_from_target``) and the motions are formed from every pair of poses ``i < j``
    (``pairs="all"``, as OpenCV does) or from consecutive ones; ``S`` is then
    ``gripper_from_camera`` and, when both files have translations, ``t_X`` is estimated
    too (jointly with ``S`` for the ``robust`` method unless ``rotation_only``). A file
    without translations (a CSV without ``tx,ty,tz``) makes the rotations alone count, with
    a note when the other file has some. The other arguments are those of
    :func:`~rotgraph.estimators.handeye.solve_handeye`.

    Raises :class:`~rotgraph.errors.InputError` for a bad file and
    :class:`~rotgraph.errors.UnsolvableError` (naming both files) for degenerate data.
    """
    from ..io.handeye import read_motion_pairs, read_pose_pairs

    t0 = time.perf_counter()
    tL = tR = None
    motions = None
    notes: list[str] = []
    if poses:
        data = read_pose_pairs(path_a, path_b, fmt)
        full = data.poses()
        if full is not None:
            motions = motions_from_poses(full[0], full[1], pairs=pairs)
        else:
            if (data.base_from_gripper_t is None) != (data.cam_from_target_t is None):
                missing = path_a if data.base_from_gripper_t is None else path_b
                notes.append(f"{missing} has no translations (a CSV without tx,ty,tz): the rotations alone are used")
            motions = motions_from_poses(data.base_from_gripper, data.cam_from_target, pairs=pairs)
        L, R, weights = motions.robot, motions.camera, None
        tL, tR = motions.robot_translations, motions.camera_translations
    else:
        data = read_motion_pairs(path_a, path_b, fmt)
        L, R, weights = data.robot, data.camera, data.weights
    lines = list(data.lines_a)
    try:
        res = solve_handeye(L, R, method=method, weights=weights, loss=loss, scale_deg=scale_deg,
                            threshold_deg=threshold_deg, seed=seed, robot_translations=tL, camera_translations=tR,
                            rotation_only=rotation_only)
    except UnsolvableError as exc:  # say which inputs, as solve does
        raise UnsolvableError(f"{path_a}, {path_b}: {exc}") from exc
    seconds = time.perf_counter() - t0
    for msg in notes:
        logger.warning(msg)
    t_res = t_inl = None
    if poses:
        n = len(lines)
        residuals, inliers = pose_residuals(res.residuals_deg, res.inliers, motions.pairs, n)
        if res.translation is not None:
            # per pose: the median translation residual of its motions to the inlier poses
            t_res = pose_residuals(res.translation_residuals, res.inliers, motions.pairs, n)[0]
            t_inl = pose_residuals(res.residuals_deg, res.inliers & res.translation_inliers, motions.pairs, n)[1]
    else:
        residuals, inliers = res.residuals_deg, res.inliers  # (motion files carry no translations)
    return HandEyeFilesResult(
        result=res,
        path_a=str(path_a),
        path_b=str(path_b),
        poses=poses,
        lines=lines,
        residuals_deg=residuals,
        inliers=inliers,
        seconds=seconds,
        pairs_mode=pairs if poses else None,
        motion_pairs=None if motions is None else motions.pairs,
        translation_residuals=t_res,
        translation_inliers=t_inl,
        notes=tuple(notes),
        loss=loss if method == "robust" else None,
    )
