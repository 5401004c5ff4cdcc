"""``rotgraph handeye``: conjugate rotation averaging (hand-eye calibration).

The work is :func:`rotgraph.pipeline.handeye.solve_handeye_files`; this module parses the
options and prints its result.
"""

from __future__ import annotations

import click

from rotgraph.choices import HANDEYE_METHODS, HANDEYE_POSE_PAIRS, LOSSES, TABLE_FORMATS

from .common import emit_json


@click.command()
@click.argument("a", type=click.Path(path_type=str))
@click.argument("b", type=click.Path(path_type=str))
@click.option("--method", type=click.Choice(HANDEYE_METHODS), default="robust", show_default=True,
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
@click.option("--pairs", "pairs_mode", type=click.Choice(HANDEYE_POSE_PAIRS), default="all", show_default=True,
              help="With --poses: the motions are formed from every pair of poses i < j (as OpenCV does) or from consecutive poses.")
@click.option("--format", "fmt", type=click.Choice(TABLE_FORMATS), default="auto", show_default=True,
              help="text: whitespace-separated lines; csv: header naming qw,qx,qy,qz (and weight, or tx,ty,tz).")
@click.option("--loss", type=click.Choice(LOSSES), default="truncated_l2", show_default=True,
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

    Example: in an empty folder, write 12 robot motions L_i and the camera motions
    S^-1 L_i S for a random S (printed), then recover S:

    \b
      python -c "import numpy as np; from rotgraph import so3; L, S = so3.random_rotations(12, 0), so3.random_rotations(rng=1); q = so3.quaternions_from_matrices; np.savetxt('robot.txt', q(L)); np.savetxt('camera.txt', q(S.T @ L @ S)); print(q(S))"
      rotgraph handeye robot.txt camera.txt
      rotgraph handeye robot.txt camera.txt --method l2 --json
    """
    import numpy as np

    from rotgraph.pipeline.handeye import solve_handeye_files

    out = solve_handeye_files(a, b, poses=poses, pairs=pairs_mode, fmt=fmt, method=method, loss=loss,
                              scale_deg=scale_deg, threshold_deg=threshold_deg, seed=seed, rotation_only=rotation_only)
    if as_json:
        emit_json(out.to_dict())
        return
    res, residuals, inlier, lines = out.result, out.residuals_deg, out.inliers, out.lines
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
    t_inl = out.translation_inliers
    if t_inl is not None and not t_inl[inlier].all():
        bad = [str(lines[k]) for k in np.flatnonzero(inlier & ~t_inl)]
        click.echo(f"# translation outlier {what} at line{'s' if len(bad) > 1 else ''} {', '.join(bad)} of {a}")
