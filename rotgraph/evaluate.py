"""Evaluation of estimated absolute rotations against ground truth (ALGORITHMS.md section 5).

The estimate is defined up to the gauge, one global rotation acting on the right:
``R_hat_i ~ G_i S``. ``S`` is the geodesic L1 median of ``G_i^T R_hat_i`` over the
cameras present in both (robust to a minority of badly estimated cameras); errors are
``angle(R_hat_i, G_i S)`` in degrees.

:func:`tilt_yaw_errors` splits the errors about gravity (tilt and yaw), for a solve with
gravity priors.

Two files are put side by side by :func:`match_cameras`: by name when both carry names, by
id where one does not (:data:`MATCHED_BY`); fewer than half of either side matched is an
:class:`~rotgraph.errors.InputError` (the two files describe different cameras).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from . import so3, so3_rows
from .errors import InputError, OptionError
from .estimators.gravity_geometry import GRAVITY_WORLD, swing_twist, unit_rows, wrap_angle
from .estimators.single import mean

__all__ = ["EvalResult", "CameraMatch", "MATCHED_BY", "compare_rotations", "match_by_key", "match_cameras", "camera_keys",
           "matching_keys", "TiltYawErrors", "tilt_yaw_errors"]

THRESHOLDS_DEG = (1.0, 2.0, 5.0, 10.0)
WORST = 10  # cameras listed by EvalResult.to_dict


@dataclass
class EvalResult:
    """The errors of estimated absolute rotations against ground truth
    (:func:`compare_rotations`), after aligning the gauge.

    Attributes
    ----------
    mean, median, rmse, max : float
        Statistics of the per-camera errors, in degrees.
    under_1deg, under_2deg, under_5deg, under_10deg : float
        The fraction (0 to 1) of evaluated cameras whose error is below 1, 2, 5, 10 degrees.
    n_evaluated : int
        Cameras with both an estimate and ground truth.
    n_ground_truth : int
        Cameras with ground truth.
    n_estimated : int
        Cameras with an estimate.
    errors_deg : (n_evaluated,) float64 ndarray
        Each evaluated camera's error ``angle(R_hat_i, G_i S)`` in degrees.
    alignment : (3, 3) float64 ndarray
        The gauge ``S`` (``R_hat_i ~ G_i S``): the geodesic L1 median of ``G_i^T R_hat_i``.
    ids, names : (n_evaluated,) ndarray or None
        The evaluated cameras' ids and names, when known.
    matched_by : str or None
        How two files' cameras were paired (:data:`MATCHED_BY`), by :func:`match_cameras`.
    n_matched : int or None
        Cameras in both files, by :func:`match_cameras`.
    """

    mean: float
    median: float
    rmse: float
    max: float
    under_1deg: float
    under_2deg: float
    under_5deg: float
    under_10deg: float
    n_evaluated: int
    n_ground_truth: int
    n_estimated: int
    errors_deg: np.ndarray  # (n_evaluated,) per evaluated camera
    alignment: np.ndarray  # S, (3, 3)
    ids: np.ndarray | None = None  # (n_evaluated,) of the evaluated cameras, when known
    names: np.ndarray | None = None
    matched_by: str | None = None  # how two files' cameras were paired (MATCHED_BY), by match_cameras
    n_matched: int | None = None  # cameras in both files, by match_cameras

    def worst(self, k: int = WORST) -> list[dict]:
        """The ``k`` cameras with the largest errors: ``{"id", "name", "error_deg"}``, largest first."""
        order = np.argsort(-self.errors_deg, kind="stable")[:k]
        label = (lambda a, i: None if a is None else _plain(a[i]))
        return [{"id": label(self.ids, i), "name": label(self.names, i), "error_deg": float(self.errors_deg[i])} for i in order]

    def to_dict(self) -> dict:
        """The statistics (and the :meth:`worst` cameras) as plain JSON values."""
        d = {f.name: getattr(self, f.name) for f in fields(self) if f.name not in ("errors_deg", "ids", "names")
             and not (f.name in ("matched_by", "n_matched") and getattr(self, f.name) is None)}
        d["alignment"] = [list(map(float, row)) for row in self.alignment]
        d = {k: (float(v) if isinstance(v, (np.floating,)) else v) for k, v in d.items()}
        d["worst"] = self.worst()
        return d


def _plain(x):
    return x.item() if isinstance(x, np.generic) else x


def compare_rotations(estimate: np.ndarray, ground_truth: np.ndarray, *, ids=None, names=None) -> EvalResult:
    """Error statistics of ``estimate`` vs ``ground_truth``, both (n, 3, 3) cam_from_world
    in the same node order, NaN rows for missing cameras; ``ids``/``names`` (n,) label the
    cameras (for :meth:`EvalResult.worst` and per-camera output).

    Parameters
    ----------
    estimate : (n, 3, 3) array_like
        Estimated absolute rotations (world-to-camera), NaN rows for cameras not estimated.
    ground_truth : (n, 3, 3) array_like
        True absolute rotations in the same order, NaN rows for cameras without.
    ids, names : (n,) array_like, optional
        Labels of the cameras.

    Returns
    -------
    EvalResult
        Error statistics in degrees after aligning the gauge (one rotation on the right).

    Raises
    ------
    InputError
        Arrays of different or wrong shapes, or no camera with both.
    """
    est = np.asarray(estimate, dtype=np.float64)
    gt = np.asarray(ground_truth, dtype=np.float64)
    if est.shape != gt.shape or est.ndim != 3 or est.shape[1:] != (3, 3):
        raise InputError(f"expected two (n,3,3) arrays of the same shape, got {est.shape} and {gt.shape}")
    has_est = np.isfinite(est).all(axis=(1, 2))
    has_gt = np.isfinite(gt).all(axis=(1, 2))
    both = has_est & has_gt
    if not both.any():
        raise InputError("no camera has both an estimate and ground truth")
    E, G = est[both], gt[both]
    S = mean(np.swapaxes(G, 1, 2) @ E, metric="geodesic", norm="l1").rotation
    err = np.degrees(so3.angle_between(E, G @ S))
    return EvalResult(
        mean=float(err.mean()),
        median=float(np.median(err)),
        rmse=float(np.sqrt((err**2).mean())),
        max=float(err.max()),
        under_1deg=float((err < 1).mean()),
        under_2deg=float((err < 2).mean()),
        under_5deg=float((err < 5).mean()),
        under_10deg=float((err < 10).mean()),
        n_evaluated=int(both.sum()),
        n_ground_truth=int(has_gt.sum()),
        n_estimated=int(has_est.sum()),
        errors_deg=err,
        alignment=S,
        ids=None if ids is None else np.asarray(ids)[both],
        names=None if names is None else np.asarray(names)[both],
    )


@dataclass
class TiltYawErrors:
    """Per-image errors (degrees) split about gravity: ``tilt_deg`` the angle between the
    estimated and the true gravity direction in the camera (the swing of the error),
    ``yaw_deg`` the error's twist about gravity, ``total_deg`` its whole angle; NaN rows
    for images missing from either input. ``alignment`` the gauge ``S`` (``R_est ~ R_gt S``)."""

    tilt_deg: np.ndarray
    yaw_deg: np.ndarray
    total_deg: np.ndarray
    alignment: np.ndarray
    align: str

    def _median(self, x):
        x = x[np.isfinite(x)]
        return float(np.median(x)) if len(x) else float("nan")

    @property
    def median_tilt(self) -> float:
        return self._median(self.tilt_deg)

    @property
    def median_yaw(self) -> float:
        return self._median(self.yaw_deg)

    @property
    def median_total(self) -> float:
        return self._median(self.total_deg)

    def to_dict(self) -> dict:
        return {"align": self.align, "median_tilt_deg": self.median_tilt, "median_yaw_deg": self.median_yaw,
                "median_deg": self.median_total, "n_evaluated": int(np.isfinite(self.total_deg).sum())}


def tilt_yaw_errors(R_est, R_gt, *, gravity_world=GRAVITY_WORLD, align: str = "yaw") -> TiltYawErrors:
    """Errors of ``R_est`` vs ``R_gt`` (both (n, 3, 3) cam_from_world, NaN rows for missing
    images) split into tilt and yaw about the world's gravity ``gravity_world``.

    ``align="yaw"`` (an estimate made with gravity priors, in the gravity frame): only the
    yaw gauge is aligned, ``S`` a rotation about gravity (robust circular mean of the images'
    yaw offsets, then their median). ``align="full"`` (an estimate without gravity, whose
    world is arbitrary): the whole gauge, ``S`` the geodesic L1 mean of ``R_gt_i^T R_est_i``
    as :func:`rotgraph.evaluate.compare_rotations` aligns it. Each image's world-frame error
    ``F_i = R_gt_i^T R_est_i S^T`` is split into a twist about gravity (yaw) and a swing
    (tilt: the angle between the estimated and the true gravity in the camera).
    """
    E = np.asarray(R_est, dtype=np.float64)
    G = np.asarray(R_gt, dtype=np.float64)
    if E.shape != G.shape or E.ndim != 3 or E.shape[1:] != (3, 3):
        raise InputError(f"expected two (n,3,3) arrays of the same shape, got {E.shape} and {G.shape}")
    if align not in ("yaw", "full"):
        raise OptionError("align must be 'yaw' or 'full'")
    d = unit_rows(np.asarray(gravity_world, dtype=np.float64))
    both = np.isfinite(E).all(axis=(1, 2)) & np.isfinite(G).all(axis=(1, 2))
    if not both.any():
        raise InputError("no camera has both an estimate and ground truth")
    D = np.swapaxes(G[both], 1, 2) @ E[both]  # ~ S
    if align == "full":
        S = mean(D, metric="geodesic", norm="l1").rotation
    else:
        twist = swing_twist(so3_rows.quaternion_rows_from_matrices(D), d)[0]
        a0 = np.arctan2(np.sin(twist).sum(), np.cos(twist).sum())
        alpha = a0 + float(np.median(wrap_angle(twist - a0)))
        S = so3.exp(alpha * d)
    F = D @ S.T
    twist, swing, total = swing_twist(so3_rows.quaternion_rows_from_matrices(F), d)
    out = np.full((3, len(E)), np.nan)
    out[:, both] = np.degrees(np.stack([swing, np.abs(twist), total]))
    return TiltYawErrors(out[0], out[1], out[2], S, align)


def match_by_key(est_keys, est_R, gt_keys, gt_R) -> tuple[np.ndarray, np.ndarray, list]:
    """Put estimate and ground truth in one order by their keys (ids or names).

    Returns ``(est (m,3,3), gt (m,3,3), keys)`` over the union of keys, NaN where missing.
    """
    est_keys = [str(k) for k in est_keys]
    gt_keys = [str(k) for k in gt_keys]
    keys = list(dict.fromkeys(gt_keys + est_keys))
    pos = {k: p for p, k in enumerate(keys)}
    E = np.full((len(keys), 3, 3), np.nan)
    G = np.full((len(keys), 3, 3), np.nan)
    E[[pos[k] for k in est_keys]] = est_R
    G[[pos[k] for k in gt_keys]] = gt_R
    return E, G, keys


#: How :func:`match_cameras` paired the cameras of an estimate and a ground truth
#: (``EvalResult.matched_by``), in words.
MATCHED_BY = {
    "name": "by name",
    "id": "by id",
    "id-name": "by the estimate's ids against the ground truth's names",
    "name-id": "by the estimate's names against the ground truth's ids",
}


@dataclass
class CameraMatch:
    """An estimate and a ground truth put side by side by :func:`match_cameras`."""

    estimate: np.ndarray  # (m, 3, 3) over the union of both files' cameras, NaN where the estimate lacks one
    ground_truth: np.ndarray  # (m, 3, 3), NaN where the ground truth lacks one
    ids: np.ndarray  # (m,) each camera's id (the estimate's when it has the camera, else the ground truth's)
    names: np.ndarray  # (m,) str, likewise (the id where a file has no names)
    matched_by: str  # a key of MATCHED_BY
    n_matched: int  # cameras in both
    n_estimated: int
    n_ground_truth: int

    def compare(self) -> EvalResult:
        """:func:`compare_rotations` of the matched cameras, with ``matched_by`` and ``n_matched``."""
        ev = compare_rotations(self.estimate, self.ground_truth, ids=self.ids, names=self.names)
        ev.matched_by, ev.n_matched = self.matched_by, self.n_matched
        return ev


def camera_keys(ids, names) -> dict[str, list[str]]:
    """The keys one file really has, ``{"id": [...], "name": [...]}`` as str, without the kind
    its reader filled in from the other: names equal to integer ids are those ids written
    out (a ``rotgraph solve`` CSV of cameras without names), so the file has ids only; ids
    equal to names are the names (GLOMAP's ``IMAGE_NAME QW QX QY QZ`` text, a CSV with a
    ``name`` column only), so it has names only. Names that repeat identify no camera: ids only."""
    ids = np.asarray(ids)
    id_keys = [str(k) for k in ids.tolist()]
    if names is None:
        return {"id": id_keys}
    name_keys = [str(n) for n in np.asarray(names).tolist()]
    if len(set(name_keys)) < len(name_keys):
        return {"id": id_keys}
    if name_keys == id_keys:
        return {"id": id_keys} if ids.dtype.kind in "iu" else {"name": name_keys}
    return {"id": id_keys, "name": name_keys}


def matching_keys(ke: dict, kg: dict) -> tuple[list[str], list[str], str]:
    """``(keys of the first table, keys of the second, how)`` by which two camera tables
    (:func:`camera_keys`) are matched: names when both have names, else ids, or one's ids
    against the other's names, whichever pairs more cameras (ids on a tie); ``how`` is a key
    of :data:`MATCHED_BY`. The one rule of rotgraph for putting two camera tables side by
    side (``eval``, ``certify``)."""
    pairs = [("name", "name")] if "name" in ke and "name" in kg else [(a, b) for a in ke for b in kg]
    a, b = max(pairs, key=lambda ab: len(set(ke[ab[0]]) & set(kg[ab[1]])))  # the first on a tie: (id, id)
    return ke[a], kg[b], (a if a == b else f"{a}-{b}")


def _too_few(m: int, n_e: int, n_g: int, how: str, ke: dict, kg: dict) -> str:
    """The one-line message of a match that pairs no camera, or fewer than half of a side's."""
    by = MATCHED_BY[how]
    if m == 0:
        msg = f"no camera of the estimate ({n_e} cameras) is in the ground truth ({n_g} cameras), matched {by}"
    else:
        short = [f"the {side}'s {n}" for side, n in (("estimate", n_e), ("ground truth", n_g)) if 2 * m < n]
        other = "" if len(short) == 2 else (f" (the ground truth has {n_g})" if 2 * m < n_e else f" (the estimate has {n_e})")
        msg = f"only {m} camera{'s' * (m != 1)} matched {by}: fewer than half of {' and of '.join(short)}{other}"
    if how == "name":
        by_id = len(set(ke.get("id", ())) & set(kg.get("id", ())))
        if by_id > m:
            msg += f"; {by_id} ids match, but when both files have names the names decide (ids differ between projects)"
    return msg


def match_cameras(estimate, ground_truth, *, path=None) -> CameraMatch:
    """Pair the cameras of an estimate and a ground truth, each ``(ids, names, R (n, 3, 3))``
    as :func:`rotgraph.io.rotations.read_absolute_rotations` returns it.

    By name when both files have names (names equal to integer ids are no names: see
    :func:`camera_keys`); else by id, or one file's ids against the other's names (a file that
    has names only, e.g. GLOMAP text, against one that has ids only), whichever pairs more
    cameras (ids on a tie). No camera paired, or fewer than half of either file's, is an
    :class:`~rotgraph.errors.InputError` at ``path`` naming both counts: the files describe
    different cameras, and their errors would mean nothing.
    """
    (e_ids, e_names, e_R), (g_ids, g_names, g_R) = estimate, ground_truth
    ke, kg = camera_keys(e_ids, e_names), camera_keys(g_ids, g_names)
    keys_e, keys_g, how = matching_keys(ke, kg)
    m = len(set(keys_e) & set(keys_g))
    if 2 * m < max(len(keys_e), len(keys_g)):
        raise InputError(_too_few(m, len(keys_e), len(keys_g), how, ke, kg), path=path)
    E, G, keys = match_by_key(keys_e, e_R, keys_g, g_R)
    ids, names = {}, {}
    for key_list, id_list, name_list in ((keys_g, g_ids, g_names), (keys_e, e_ids, e_names)):
        for k, key in enumerate(key_list):
            ids[key] = id_list[k]
            names[key] = key if name_list is None else name_list[k]
    return CameraMatch(E, G, np.array([ids[k] for k in keys]), np.array([str(names[k]) for k in keys]),
                       how, m, len(keys_e), len(keys_g))
