"""Evaluation of estimated absolute rotations against ground truth (ALGORITHMS.md section 5).

The estimate is defined up to the gauge, one global rotation acting on the right:
``R_hat_i ~ G_i S``. ``S`` is the geodesic L1 median of ``G_i^T R_hat_i`` over the
cameras present in both (robust to a minority of badly estimated cameras); errors are
``angle(R_hat_i, G_i S)`` in degrees.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from . import so3
from .errors import InputError
from .estimators.single import mean

__all__ = ["EvalResult", "compare_rotations", "match_by_key"]

THRESHOLDS_DEG = (1.0, 2.0, 5.0, 10.0)
WORST = 10  # cameras listed by EvalResult.to_dict


@dataclass
class EvalResult:
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

    def worst(self, k: int = WORST) -> list[dict]:
        """The ``k`` cameras with the largest errors: ``{"id", "name", "error_deg"}``, largest first."""
        order = np.argsort(-self.errors_deg, kind="stable")[:k]
        label = (lambda a, i: None if a is None else _plain(a[i]))
        return [{"id": label(self.ids, i), "name": label(self.names, i), "error_deg": float(self.errors_deg[i])} for i in order]

    def to_dict(self) -> dict:
        """The statistics (and the :meth:`worst` cameras) as plain JSON values."""
        d = {f.name: getattr(self, f.name) for f in fields(self) if f.name not in ("errors_deg", "ids", "names")}
        d["alignment"] = [list(map(float, row)) for row in self.alignment]
        d = {k: (float(v) if isinstance(v, (np.floating,)) else v) for k, v in d.items()}
        d["worst"] = self.worst()
        return d


def _plain(x):
    return x.item() if isinstance(x, np.generic) else x


def compare_rotations(estimate: np.ndarray, ground_truth: np.ndarray, *, ids=None, names=None) -> EvalResult:
    """Error statistics of ``estimate`` vs ``ground_truth``, both (n, 3, 3) cam_from_world
    in the same node order, NaN rows for missing cameras; ``ids``/``names`` (n,) label the
    cameras (for :meth:`EvalResult.worst` and per-camera output)."""
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
