"""``rotgraph mean``: single rotation averaging of the rotations in a file.

The averaging itself is :func:`rotgraph.estimators.single.mean`; this module reads the
file (:func:`rotgraph.io.rotations.read_weighted_quaternions`), hands the rotations and
weights over and keeps what ``rotgraph mean`` prints.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..estimators.single import MeanResult, mean

__all__ = ["MeanFileResult", "mean_file"]


@dataclass(frozen=True)
class MeanFileResult:
    """The outcome of :func:`mean_file`.

    Attributes
    ----------
    result : the :class:`~rotgraph.estimators.single.MeanResult` (``result.quaternion``:
        the mean as ``(w, x, y, z)``, ``w >= 0``).
    path : the input.
    n_rotations : rotations read.
    loss : the robust loss (``norm="robust"``), else None.
    """

    result: MeanResult
    path: str
    n_rotations: int
    loss: str | None = None

    def to_dict(self) -> dict:
        """The summary ``rotgraph mean --json`` prints."""
        res = self.result
        out = {
            "quaternion": [float(v) for v in res.quaternion],
            "cost": res.cost,
            "metric": res.metric,
            "norm": res.norm,
            "n_rotations": self.n_rotations,
            "iterations": res.iterations,
            "converged": res.converged,
            "median_residual_deg": float(np.degrees(np.median(res.residuals))),
            "warnings": list(res.warnings),
            "certificate": res.certificate,
        }
        if res.norm == "robust":
            out.update(loss=self.loss, scale_deg=float(np.degrees(res.scale)), n_inliers=int(res.inliers.sum()))
        return out


def mean_file(
    path,
    *,
    metric: str = "geodesic",
    norm: str = "l2",
    loss: str = "cauchy",
    scale_deg: float | None = None,
    fmt: str = "auto",
) -> MeanFileResult:
    """The mean (or median) of the rotations in a file.

    Parameters
    ----------
    path : one rotation a line, ``qw qx qy qz [weight]``, or a CSV with columns
        ``qw,qx,qy,qz[,weight]`` (:func:`~rotgraph.io.rotations.read_weighted_quaternions`).
    metric, norm, loss, scale_deg : as for :func:`~rotgraph.estimators.single.mean` (the
        file's weights, when it has some, weight the rotations).
    fmt : ``"text"``, ``"csv"`` or ``"auto"``.

    Returns
    -------
    MeanFileResult

    Raises :class:`~rotgraph.errors.InputError` (naming the file and line) for a bad file.
    """
    from ..io.rotations import read_weighted_quaternions

    q, w, _ = read_weighted_quaternions(path, fmt)
    res = mean(q, metric=metric, norm=norm, weights=w, loss=loss, scale_deg=scale_deg)
    return MeanFileResult(result=res, path=str(path), n_rotations=int(len(q)), loss=loss if norm == "robust" else None)
