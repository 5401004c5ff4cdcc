"""Each edge's leverage in a least-squares fit of the view graph, and what follows from it for
the noise model (:mod:`.noise_model`, which re-exports these names): the residuals
standardised by it, each residual's degrees of freedom, the precision an information matrix
gives an angle.

A residual of a least-squares fit is smaller than the noise by the edge's leverage ``h``
(``E|e|^2 = 3 sigma^2 (1 - h)``; ``h`` the edge's weighted effective resistance, 1 for a
bridge), and holds only ``1 - h`` of a degree of freedom of the noise (see
:mod:`.noise_model`).
"""

from __future__ import annotations

import numpy as np

__all__ = ["leverage", "degree_leverage", "standardised", "residual_dofs", "mean_variance_precision", "isotropic_precision",
           "fitted_residual_dofs", "EXACT_LEVERAGE_MAX_DEGREE", "EXACT_LEVERAGE_MAX_NODES", "EXACT_LEVERAGE_THIN_DEGREE",
           "EXACT_LEVERAGE_THIN_MAX_NODES"]


#: Graphs thinner than this average degree and up to this many cameras get exact leverages
#: (effective resistances from a dense Cholesky factorisation of the grounded Laplacian);
#: the others keep ``1/d_i + 1/d_j``, accurate on well-connected graphs. Measured on
#: SLAM-like pose graphs (n = 400, degree 4, sigma 2 deg, 3 seeds): with the approximation
#: the t model took two clean graphs with per-edge information (72 and 83 "outliers",
#: median error 5.5 / 4.3 deg against L2's 3.4); exact: Gaussian, 3.4 / 3.5. Cost (2-core
#: machine, loaded): n = 400 0.07 s, 1000 0.2-0.5 s, 2000 0.6 s, 2500 0.7-1.0 s, 4000 2.8-3.7 s
#: (a sparse LU solve per edge: 1.2 s at 1000, 6.9 s at 2500). Up to 1000 nodes only until 2026-12:
#: clean pose graphs of 2,500 poses (degree 3, odometry + loop closures, no information; 3
#: seeds) then took a t model and flagged 35-43 clean edges (1.2 %), 1.01-1.08x the L2 answer's
#: error; exact: Gaussian, 0 flagged, the L2 answer; with 5 % outliers 16-19 false flags -> 0.
#: Between 1000 and 3000 nodes only graphs thinner than :data:`EXACT_LEVERAGE_THIN_DEGREE`,
#: where the approximation is poor (n = 1500, ratio of its standardisation factor to the
#: exact one, 5th-95th percentile: pose graphs of degree 3 0.56-1.16, 4 0.84-1.06; random
#: graphs of degree 4 0.85-1.07, 6 0.96-1.02, 10 0.99-1.00), pay for the factorisation (1.0 s
#: of a 4.5 s solve at n = 2000, degree 10). Above 3000 nodes (cubicle.g2o, 5,750 poses) the
#: approximation stays: an exact leverage at that size needs a selected inversion of a sparse
#: factor, not this dense one.
EXACT_LEVERAGE_MAX_DEGREE = 12.0
EXACT_LEVERAGE_MAX_NODES = 1000
EXACT_LEVERAGE_THIN_DEGREE = 6.0
EXACT_LEVERAGE_THIN_MAX_NODES = 3000
_LEVERAGE_CAP = 0.95


def leverage(n: int, edges: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Each edge's leverage ``h_e = w_e R_e`` (in [0, 1]; 1 for a bridge), ``R_e`` its
    effective resistance in the graph of edge weights ``w`` (precisions; 1 when None): the
    fraction of its noise that a least-squares fit absorbs.

    Well-connected or large graphs: ``w_e (1/D_i + 1/D_j)`` with ``D`` the weighted
    degrees. Thin graphs (pose graphs, trajectories; see :data:`EXACT_LEVERAGE_MAX_DEGREE`),
    where leverages are large and uneven: exact."""
    w = np.ones(len(edges)) if weights is None else np.asarray(weights, dtype=np.float64)
    i, j = edges[:, 0], edges[:, 1]
    deg = np.bincount(edges.ravel(), weights=np.repeat(w, 2), minlength=n)
    approx = degree_leverage(edges, deg, w)
    degree = 2.0 * len(edges) / max(n, 1)
    thin = n <= EXACT_LEVERAGE_THIN_MAX_NODES and degree < EXACT_LEVERAGE_THIN_DEGREE
    if n < 3 or (n > EXACT_LEVERAGE_MAX_NODES and not thin) or degree >= EXACT_LEVERAGE_MAX_DEGREE:
        return approx
    from scipy.linalg.lapack import dpotrf, dtrtri

    # Grounded Laplacian (last node's row and column dropped): L = C C^T, and
    # R_e = |C^-1 (e_i - e_j)|^2 with the ground's unit vector zero.
    L = np.zeros((n, n))
    np.add.at(L, (i, i), w)
    np.add.at(L, (j, j), w)
    np.add.at(L, (i, j), -w)
    np.add.at(L, (j, i), -w)
    C, info = dpotrf(L[:-1, :-1], lower=True, clean=True, overwrite_a=True)
    if info != 0:  # not positive definite: a disconnected graph (the caller solves one component)
        return approx
    X, info = dtrtri(C, lower=True, overwrite_c=True)
    if info != 0:
        return approx
    X = np.hstack([X, np.zeros((n - 1, 1))])  # the ground's column
    D = X[:, i] - X[:, j]
    return np.clip(w * np.einsum("ke,ke->e", D, D), 0.0, 1.0)


def degree_leverage(edges: np.ndarray, degrees: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """The leverage of well-connected or large graphs (:func:`leverage`): ``w_e (1/D_i +
    1/D_j)``, capped at 1, from the weighted degrees ``D`` of the whole graph (which a part
    of the edges, e.g. one block of the distributed solve, is given: its own would be too small)."""
    w = 1.0 if weights is None else weights
    return np.minimum(w * (1.0 / degrees[edges[:, 0]] + 1.0 / degrees[edges[:, 1]]), 1.0)


def standardised(theta: np.ndarray, lev: np.ndarray) -> np.ndarray:
    """Residual angles divided by ``sqrt(1 - h)`` (``h`` capped at 0.95: a residual of a
    near-bridge is not blown up; it counts for little anyway, :func:`residual_dofs`)."""
    return theta / np.sqrt(1.0 - np.minimum(lev, _LEVERAGE_CAP))


def residual_dofs(lev: np.ndarray) -> np.ndarray:
    """Each residual's share of the noise's degrees of freedom, ``1 - h`` (module docstring):
    the weight of each residual in the noise model's fits and likelihoods."""
    return np.clip(1.0 - lev, 0.0, 1.0)


def mean_variance_precision(information: np.ndarray) -> np.ndarray:
    """Each edge's ``3 / trace(H^-1)`` (E,), the inverse of its mean variance: what its
    residual angle's scale says of its information (``E|r|^2 = trace(H^-1)``, where trace / 3
    is dominated by the most precise axis). A singular ``H``: 0."""
    H = information
    minors = (H[:, 1, 1] * H[:, 2, 2] - H[:, 1, 2] ** 2) + (H[:, 0, 0] * H[:, 2, 2] - H[:, 0, 2] ** 2) \
        + (H[:, 0, 0] * H[:, 1, 1] - H[:, 0, 1] ** 2)
    det = (H[:, 0, 0] * (H[:, 1, 1] * H[:, 2, 2] - H[:, 1, 2] * H[:, 2, 1])
           - H[:, 0, 1] * (H[:, 1, 0] * H[:, 2, 2] - H[:, 1, 2] * H[:, 2, 0])
           + H[:, 0, 2] * (H[:, 1, 0] * H[:, 2, 1] - H[:, 1, 1] * H[:, 2, 0]))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(minors > 0, 3.0 * det / np.where(minors > 0, minors, 1.0), 0.0)


def isotropic_precision(information: np.ndarray) -> np.ndarray:
    """Each edge's isotropic precision ``trace(H) / 3`` (E,): the scalar weight of its
    information where a stage weighs edges by scalars."""
    return np.trace(information, axis1=1, axis2=2) / 3.0


def fitted_residual_dofs(n: int, edges: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Each residual's share of the noise's degrees of freedom in a *weighted* fit (robust
    weights times precisions, (E,)): ``1 - h`` with ``h`` the leverage in the graph of those
    weights. An edge whose every cycle runs through edges of ~0 weight is a bridge of the
    fit: 0, its residual ~0 whatever its noise. (Weights below 1e-12 of the largest are
    raised to it: the graph stays connected.)"""
    weights = np.asarray(weights, dtype=np.float64)
    return residual_dofs(leverage(n, edges, np.maximum(weights, 1e-12 * weights.max())))
