"""The worker side of the distributed solve's refinement (:mod:`rotgraph.pipeline.distributed_refine`),
split from :mod:`rotgraph.pipeline.blocks` (which re-exports these names): one IRLS iteration
over the whole graph as map-reduce on the :class:`~rotgraph.pipeline.blocks.Shard` objects,
pure functions of their arguments as every task of :mod:`~rotgraph.pipeline.blocks` (``Shard``
in the annotations is :class:`~rotgraph.pipeline.blocks.Shard`).

* :func:`sample`, :func:`weighted_state`, :func:`state_rhs`, :func:`state_matvec`,
  :func:`weighted_degrees`: residual samples for the noise model; the weighted Laplacian's
  right-hand side, diagonal and products for the client's conjugate gradients.
* :func:`finish`: outlier flags, per-camera inlier counts, log-likelihood, and the
  per-edge residuals written as one Parquet part per shard.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from ..losses import positive_loss_weight
from ..estimators.irls import L1_FLOOR
from ..estimators.laplacian import _Negated, make_laplacian
from ..estimators.leverage import degree_leverage, mean_variance_precision, residual_dofs, standardised
from ..estimators.noise_model import FIT_MAX, NoiseModel

__all__ = ["sample", "model_cost", "weighted_state", "state_rhs", "state_matvec", "weighted_degrees", "finish", "State"]


# --------------------------------------------------------------------------- IRLS as map-reduce


def _sample_rows(shard: Shard, total_edges: int, seed: int) -> np.ndarray:
    """The rows of this shard among the residuals a noise model is fitted on: all, or its
    share of :data:`~rotgraph.estimators.noise_model.FIT_MAX` (a fixed random draw, as
    :func:`~rotgraph.estimators.noise_model.subset` makes in one process)."""
    E = shard.n_edges
    if total_edges <= FIT_MAX:
        return np.arange(E)
    k = min(E, int(np.ceil(FIT_MAX * E / total_edges)))
    return np.sort(np.random.default_rng([seed, shard.index]).choice(E, k, replace=False))


def sample(shard: Shard, q: np.ndarray, total_edges: int, seed: int, degrees=None, spec=None, q_fit=None,
           unwhitened: bool = False) -> dict:
    """The statistics of the residuals at ``q`` that the client fits noise models to:
    ``t`` and ``dofs`` (leverage-standardised residual angles and their degrees of freedom,
    :func:`~rotgraph.estimators.leverage.residual_dofs`) of this shard's rows of the fit sample; the sums
    ``t^2 dofs`` and ``dofs`` over all its edges (the graduated stage's starting scale); the
    L1 cost sum. With ``degrees`` (the whole graph's degrees weighted by ``spec``'s weights,
    :func:`weighted_degrees`), each residual counts the smaller of its degrees of freedom in
    the graph and in that weighted fit (:func:`~rotgraph.estimators.leverage.fitted_residual_dofs`), its
    weights at ``q_fit`` (the fitted rotations; default ``q``) times the isotropic precisions.
    Residual sizes are those of ``spec``'s system (:meth:`Shard.view`); ``unwhitened``: the
    rotation angles instead, the degrees of freedom in the fit alone, and ``c`` each row's
    mean-variance precision (the information test, :func:`~rotgraph.estimators.methods._information_test`).
    """
    system = shard.view(spec)
    theta = system.angles(q)
    t = standardised(system.rotation_angles(q) if unwhitened else theta, shard.lev)
    dofs = _dofs(shard, system, theta, degrees, spec, q_fit, graph=not unwhitened)
    rows = _sample_rows(shard, total_edges, seed)
    out = {"t": t[rows], "dofs": dofs[rows], "t2_dofs": float((t * t) @ dofs), "dofs_sum": float(dofs.sum()),
           "l1": float(theta.sum()), "n_edges": shard.n_edges}
    if unwhitened:
        out["c"] = mean_variance_precision(system.information[rows])
    return out


def _dofs(shard: Shard, system, theta: np.ndarray, degrees, spec, q_fit, graph: bool = True) -> np.ndarray:
    """Each residual's degrees of freedom (:func:`sample`): in the graph, or with ``degrees``
    the smaller of those and those in the fit weighted by ``spec`` at ``q_fit`` (residual sizes
    ``theta`` at the rotations sampled); not ``graph``: those in the fit alone (the
    information test's, as one process's)."""
    dofs = residual_dofs(shard.lev)
    if degrees is not None:
        u = _fit_weights(shard, theta if q_fit is None else system.angles(q_fit), spec)
        fit = residual_dofs(degree_leverage(shard.edges, degrees, u))
        dofs = np.minimum(dofs, fit) if graph else fit
    return dofs


def model_cost(shard: Shard, q: np.ndarray, model: NoiseModel, degrees, spec, q_fit) -> float:
    """The negative log-likelihood of this shard's residual vectors at ``q`` under ``model``
    (:meth:`~rotgraph.estimators.noise_model.NoiseModel.vector_cost`), each counted its degrees
    of freedom (:func:`_dofs`): the cost a heavy-tailed stage's steps must not raise, as in one
    process (summed over the shards)."""
    system = shard.view(spec)
    theta = system.angles(q)
    return model.vector_cost(standardised(theta, shard.lev), _dofs(shard, system, theta, degrees, spec, q_fit))


def _fit_weights(shard: Shard, theta: np.ndarray, spec: tuple) -> np.ndarray:
    """The weights of the fit whose leverages give each residual's degrees of freedom: the
    IRLS weights (:func:`_weights`) times each edge's isotropic precision (one process's
    ``w_linear``), floored at 1e-12 of their largest (:func:`~rotgraph.estimators.leverage.fitted_residual_dofs`)."""
    u = _weights(shard, theta, spec)
    if shard.iso is not None:
        u = u * shard.iso
    return np.maximum(u, 1e-12 * u.max()) if len(u) else u


def _weights(shard: Shard, theta: np.ndarray, spec: tuple) -> np.ndarray:
    """The IRLS weights of the edges at residual angles ``theta``: ``("l1",)`` L1RA's
    (capped at 1 / :data:`~rotgraph.estimators.irls.L1_FLOOR`), ``("l2",)`` one, ``("model", NoiseModel)`` the
    model's expected inverse variance times inlier probability of the standardised
    residual (not normalised: the same scale on every shard)."""
    kind = spec[0]
    if kind == "l1":
        u = positive_loss_weight("l1", np.maximum(theta, L1_FLOOR), 1.0)
    elif kind == "l2":
        u = np.ones_like(theta)
    else:
        model: NoiseModel = spec[1]
        u = model.weights(standardised(theta, shard.lev), normalise=False)[0]
    return u


@dataclass
class State:
    """One IRLS iteration's weighted Laplacian on a shard: its reduced matrix (anchor's row
    and column removed), right-hand side (3, n) and weighted degrees (the diagonal)."""

    matrix: object
    rhs: np.ndarray
    diagonal: np.ndarray

    def __sizeof__(self) -> int:
        return int(getattr(self.matrix, "N", self.matrix).data.nbytes + self.rhs.nbytes + self.diagonal.nbytes) + 1000


def weighted_state(shard: Shard, q: np.ndarray, spec: tuple) -> State:
    """The weighted Laplacian system of one IRLS step at ``q`` (:func:`~rotgraph.estimators.irls.solve_weighted`'s,
    for this shard's edges): weights by ``spec`` (:func:`_weights`), floored at 1e-12 of
    their largest, the right-hand side ``A^T (v f u)``."""
    system = shard.view(spec)
    v, f, _ = system.errors(q)
    u = _weights(shard, system.angles(q), spec)
    if len(u):
        u = np.maximum(u, 1e-12 * u.max())
    if system.information is not None:  # 3x3 Gauss-Newton blocks (irls.solve_weighted's): -L and its diagonal blocks
        lap = make_laplacian(shard.n, shard.edges, shard.anchor, "cg", blocks=True, like=shard.lap)
        U, y = system.gauss_newton_blocks(q, u, lap)
        N, D = lap.matrix(U)
        return State(_Negated(N), system.rhs(y), D)
    if system.precision is not None:  # the isotropic view: the cost sum u p |r|^2
        u = u * system.precision
    rhs = system.rhs(v * (f * u))
    lap = make_laplacian(shard.n, shard.edges, shard.anchor, "cg", like=shard.lap)
    deg = np.bincount(shard.edges[:, 0], weights=u, minlength=shard.n) + np.bincount(shard.edges[:, 1], weights=u, minlength=shard.n)
    return State(lap.matrix(u), rhs, deg[np.arange(shard.n) != shard.anchor])


def state_rhs(state: State) -> tuple[np.ndarray, np.ndarray]:
    return state.rhs, state.diagonal


def state_matvec(state: State, p: np.ndarray) -> np.ndarray:
    """This shard's part of the anchored Laplacian times ``p`` ((n - 1, 3), the reduced unknowns;
    with 3x3 blocks (3 (n - 1), 1), node-major)."""
    return state.matrix @ p


def weighted_degrees(shard: Shard, q: np.ndarray, spec: tuple) -> np.ndarray:
    """The degrees (n,) of this shard's edges weighted by ``spec``'s weights at ``q`` (summed
    over the shards: the whole graph's)."""
    u = _fit_weights(shard, shard.view(spec).angles(q), spec)
    return np.bincount(shard.edges[:, 0], weights=u, minlength=shard.n) + np.bincount(shard.edges[:, 1], weights=u, minlength=shard.n)


# --------------------------------------------------------------------------- results


def finish(shard: Shard, q: np.ndarray, model: NoiseModel | None, threshold_deg: float | None, ids: np.ndarray,
           edges_out: str | None) -> dict:
    """The results of the shard's edges at the final rotations ``q``: inlier flags (the
    model's posterior >= 1/2, or a residual within ``threshold_deg``), each camera's count
    of inlier edges (n,), the log-likelihood of the standardised residuals under ``model``,
    and, with ``edges_out`` (a folder), the part ``part.<shard>.parquet`` of
    ``i, j, residual_deg, inlier`` (written whole: a temporary file renamed)."""
    theta = shard.system.angles(q)
    if model is not None:
        t = standardised(theta, shard.lev)
        inlier = model.weights(t)[1] >= 0.5 if len(t) else np.zeros(0, bool)
        ll = float(model.log_likelihood(t)) if len(t) else 0.0
    else:
        inlier, ll = np.degrees(theta) <= threshold_deg, 0.0
    counts = np.bincount(shard.edges[inlier].ravel(), minlength=shard.n)
    if edges_out is not None:
        import pyarrow as pa
        import pyarrow.parquet as pq

        path = os.path.join(edges_out, f"part.{shard.index}.parquet")
        tmp = os.path.join(edges_out, f".part.{shard.index}.parquet.{os.getpid()}.tmp")
        pq.write_table(pa.table({"i": ids[shard.edges[:, 0]], "j": ids[shard.edges[:, 1]],
                                 "residual_deg": np.degrees(shard.system.rotation_angles(q)), "inlier": inlier.astype(np.int8)}), tmp)
        os.replace(tmp, path)
    return {"inlier_degree": counts, "n_outliers": int((~inlier).sum()), "log_likelihood": ll, "n_edges": shard.n_edges}
