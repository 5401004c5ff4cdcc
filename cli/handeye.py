"""``rotgraph handeye``: conjugate rotation averaging (hand-eye calibration)."""

from __future__ import annotations

import logging
import time

import click
import numpy as np

from rotgraph.errors import UnsolvableError

from .common import emit_json

_METHODS = ["robust", "quaternion", "procrustes", "l2", "l1"]
_LOSSES = ["truncated_l2", "cauchy", "geman_mcclure", "huber", "half_norm", "l1", "l2"]


def _finite_list(x):
    return [None if not np.isfinite(v) else float(v) for v in x]


@click.command()
@click.argument("a", type=click.Path(path_type=str))
@click.argument("b", type=click.Path(path_type=str))
@click.option("--method", type=click.Choice(_METHODS), default="robust", show_default=True,
              help="robust: 2-pair consensus then IRLS (flags wrong pairs), with --poses and translations then "
                   "rotation and translation jointly; quaternion / procrustes: closed forms (quaternion L2, axis "
                   "alignment); l2 / l1: geodesic L2 / L1 (Gauss-Newton, IRLS). All but robust use the rotations alone.")
@click.option("--poses", is_flag=True,
              help="A and B hold absolute poses, not motions: A base_from_gripper (robot), B cam_from_target (camera); "
                   "one pose a line: 16 numbers (4x4 row-major), 12 (3x4 [R|t]) or 'qw qx qy qz tx ty tz' "
                   "(translations in one unit in both files); also prints the translation of S.")
@click.option("--rotation-only", is_flag=True,
              help="With --poses: estimate S from the rotations alone (the translation is then fitted given S); "
                   "by default --method robust estimates S and the translation jointly when the poses have translations.")
@click.option("--pairs", "pairs_mode", type=click.Choice(["all", "consecutive"]), default="all", show_default=True,
              help="With --poses: the motions are formed from every pair of poses i < j (as OpenCV does) or from consecutive poses.")
@click.option("--format", "fmt", type=click.Choice(["auto", "text", "csv"]), default="auto", show_default=True,
              help="text: whitespace-separated lines; csv: header naming qw,qx,qy,qz (and weight, or tx,ty,tz).")
@click.option("--loss", type=click.Choice(_LOSSES), default="truncated_l2", show_default=True,
              help="Robust loss of the IRLS stage (--method robust).")
@click.option("--scale-deg", type=click.FloatRange(min=0, min_open=True), default=None,
              help="Scale of the robust loss in degrees [default: the inlier threshold].")
@click.option("--threshold-deg", type=click.FloatRange(min=0, min_open=True), default=None,
              help="Pairs with a larger residual are flagged as outliers [robust default: automatic, 4.03 x the "
                   "estimated per-axis noise; other methods: no flagging].")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the random minimal samples (robust).")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object (quaternion, residuals_deg, inlier, ...).")
def handeye(a, b, method, poses, rotation_only, pairs_mode, fmt, loss, scale_deg, threshold_deg, seed, as_json):
    """Hand-eye calibration: the rotation S with R_i ~ S^-1 L_i S.

    A holds the robot motions L_i, B the camera motions R_i, one pair per line number:
    'qw qx qy qz [weight]' lines or a CSV with columns qw,qx,qy,qz[,weight]. Motions are
    'j_from_i': gripper_j_from_gripper_i and cam_j_from_cam_i. With --poses, A and B hold
    absolute poses (base_from_gripper, cam_from_target) and the motions are formed from
    them; S is then gripper_from_camera, OpenCV's R_cam2gripper. When the poses have
    translations, the translation t of gripper_from_camera (OpenCV's t_cam2gripper) is
    estimated too, and --method robust (the default) estimates S and t jointly, weighting
    rotations and translations by their noise estimated from the data (--rotation-only: S
    from the rotations alone).

    Prints S as 'qw qx qy qz' (w >= 0), then a residual summary as '#' lines ('# translation
    tx ty tz' with translations). --json prints one object whose residuals_deg and inlier
    have one entry per input line pair (per pose with --poses; the per-motion values are
    under "motions"), and "translation" ([tx, ty, tz] or null).

    Example: rotgraph handeye robot_motions.txt camera_motions.txt --json
    """
    from rotgraph.estimators.handeye import motions_from_poses, pose_residuals, solve_handeye

    t0 = time.perf_counter()
    tL = tR = None
    notes: list[str] = []
    if poses:
        from rotgraph.io.handeye import read_pose_pairs

        data = read_pose_pairs(a, b, fmt)
        full = data.poses()
        if full is not None:
            motions = motions_from_poses(full[0], full[1], pairs=pairs_mode)
        else:
            if (data.base_from_gripper_t is None) != (data.cam_from_target_t is None):
                missing = a if data.base_from_gripper_t is None else b
                notes.append(f"{missing} has no translations (a CSV without tx,ty,tz): the rotations alone are used")
            motions = motions_from_poses(data.base_from_gripper, data.cam_from_target, pairs=pairs_mode)
        L, R, weights = motions.robot, motions.camera, None
        tL, tR = motions.robot_translations, motions.camera_translations
        lines = data.lines_a
    else:
        from rotgraph.io.handeye import read_motion_pairs

        data = read_motion_pairs(a, b, fmt)
        L, R, weights = data.robot, data.camera, data.weights
        lines = data.lines_a
    try:
        res = solve_handeye(L, R, method=method, weights=weights, loss=loss, scale_deg=scale_deg,
                            threshold_deg=threshold_deg, seed=seed, robot_translations=tL, camera_translations=tR,
                            rotation_only=rotation_only)
    except UnsolvableError as exc:  # say which inputs, as solve does (exit 1)
        raise UnsolvableError(f"{a}, {b}: {exc}") from exc
    seconds = time.perf_counter() - t0
    for msg in notes:
        logging.getLogger("rotgraph.estimators.handeye").warning(msg)
    t_res = t_inl = None
    if poses:
        residuals, inlier = pose_residuals(res.residuals_deg, res.inliers, motions.pairs, len(lines))
        if res.translation is not None:
            # per pose: the median translation residual of its motions to the inlier poses
            t_res = pose_residuals(res.translation_residuals, res.inliers, motions.pairs, len(lines))[0]
            t_inl = pose_residuals(res.residuals_deg, res.inliers & res.translation_inliers, motions.pairs, len(lines))[1]
    else:
        residuals, inlier = res.residuals_deg, res.inliers
    if as_json:
        out = {
            "quaternion": [float(v) for v in res.quaternion],
            "rotation": res.rotation.tolist(),
            "convention": "R_i ~ S^-1 L_i S" + ("; S = gripper_from_camera (OpenCV R_cam2gripper)" if poses else ""),
            "method": method,
            "n_pairs": int(len(residuals)),
            "n_inliers": int(inlier.sum()),
            "residuals_deg": [None if not np.isfinite(v) else float(v) for v in residuals],
            "inlier": [bool(v) for v in inlier],
            "cost": res.cost,
            "iterations": res.iterations,
            "converged": res.converged,
            "threshold_deg": res.threshold_deg,
            "conditioning": res.conditioning,
            "warnings": list(res.warnings) + notes,
            "seconds": seconds,
            "translation": None if res.translation is None else [float(v) for v in res.translation],
        }
        if method == "robust":
            out.update(loss=loss, scale_deg=res.scale_deg)
        if res.translation is not None:
            out.update(
                joint=res.joint,
                translation_residuals=_finite_list(t_res),
                translation_inlier=[bool(v) for v in t_inl],
                translation_threshold=res.translation_threshold,
                sigma_deg=res.sigma_deg,
                sigma_translation=res.sigma_translation,
            )
        if poses:
            out["motions"] = {
                "pairs_mode": pairs_mode,
                "n_motions": int(len(res.residuals_deg)),
                "n_inliers": res.n_inliers,
                "pairs": motions.pairs.tolist(),
                "residuals_deg": [float(v) for v in res.residuals_deg],
                "inlier": [bool(v) for v in res.inliers],
            }
            if res.translation is not None:
                out["motions"].update(
                    translation_residuals=[float(v) for v in res.translation_residuals],
                    translation_inlier=[bool(v) for v in res.translation_inliers],
                )
        emit_json(out)
        return
    click.echo(" ".join(repr(float(v)) for v in res.quaternion))
    if res.translation is not None:
        how = "jointly with S" if res.joint else "given S"
        click.echo(f"# translation {' '.join(repr(float(v)) for v in res.translation)} ({how})")
    what = "poses" if poses else "pairs"
    thr = f" (threshold {res.threshold_deg:.3g} deg)" if res.threshold_deg is not None else ""
    finite = residuals[np.isfinite(residuals)]
    click.echo(
        f"# handeye {method}: {len(residuals)} {what}, {int(inlier.sum())} inliers{thr}; residual [deg] "
        f"median {np.median(finite):.4g}, max {finite.max():.4g}"
        + (f"; {len(res.residuals_deg)} motions ({pairs_mode})" if poses else "")
    )
    if not inlier.all():
        bad = [str(lines[k]) for k in np.flatnonzero(~inlier)]
        click.echo(f"# outlier {what} at line{'s' if len(bad) > 1 else ''} {', '.join(bad)} of {a}")
    if t_inl is not None and not t_inl[inlier].all():
        bad = [str(lines[k]) for k in np.flatnonzero(inlier & ~t_inl)]
        click.echo(f"# translation outlier {what} at line{'s' if len(bad) > 1 else ''} {', '.join(bad)} of {a}")
