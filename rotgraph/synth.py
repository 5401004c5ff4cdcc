"""Synthetic rotation-averaging problems with known ground truth."""

from __future__ import annotations

import numpy as np

from . import so3
from .viewgraph import ViewGraph

__all__ = ["random_problem", "GRAPHS"]

GRAPHS = ("er", "traj")


def _er_pairs(n: int, n_edges: int, rng) -> np.ndarray:
    """A random spanning tree (connectivity guaranteed) plus uniform random extra pairs."""
    perm = rng.permutation(n)
    # Random recursive tree: node perm[k] attaches to a random earlier node.
    parents = perm[(rng.random(n - 1) * np.arange(1, n)).astype(np.int64)]
    pairs = np.stack([parents, perm[1:]], axis=1)
    keys = set((np.minimum(pairs[:, 0], pairs[:, 1]) * n + np.maximum(pairs[:, 0], pairs[:, 1])).tolist())
    target = min(n_edges, n * (n - 1) // 2)
    extra = []
    while len(keys) < target:
        m = int((target - len(keys)) * 1.3) + 16
        a = rng.integers(0, n, m)
        b = rng.integers(0, n, m)
        ok = a != b
        k = np.minimum(a[ok], b[ok]) * n + np.maximum(a[ok], b[ok])
        k = np.unique(k)
        k = k[~np.isin(k, np.fromiter(keys, dtype=np.int64, count=len(keys)))]
        k = rng.permutation(k)[: target - len(keys)]
        keys.update(k.tolist())
        extra.append(k)
    if extra:
        k = np.concatenate(extra)
        pairs = np.concatenate([pairs, np.stack([k // n, k % n], axis=1)])
    flip = rng.random(len(pairs)) < 0.5  # both edge directions occur
    pairs[flip] = pairs[flip][:, ::-1]
    return pairs


def _trajectory(n: int, degree: float, rng) -> tuple[np.ndarray, np.ndarray]:
    """Cameras on a smooth path (yaw sweep with wobble), edges to the next k cameras plus
    random loop closures (10 % of the edges)."""
    t = np.linspace(0, 4 * np.pi, n)
    v = np.stack([0.1 * np.sin(3 * t), t, 0.1 * np.cos(2 * t)], axis=1) + 0.02 * rng.standard_normal((n, 3))
    R = so3.exp(v)
    k = max(1, int(round(0.45 * degree)))
    ii = np.concatenate([np.arange(n - d) for d in range(1, k + 1)])
    jj = np.concatenate([np.arange(d, n) for d in range(1, k + 1)])
    n_loop = max(0, int(0.1 * len(ii)))
    a = rng.integers(0, n, 3 * n_loop + 8)
    b = rng.integers(0, n, 3 * n_loop + 8)
    ok = np.abs(a - b) > k
    pairs = np.concatenate([np.stack([ii, jj], 1), np.stack([a[ok], b[ok]], 1)[:n_loop]])
    lo, hi = np.minimum(pairs[:, 0], pairs[:, 1]), np.maximum(pairs[:, 0], pairs[:, 1])
    _, first = np.unique(lo * n + hi, return_index=True)
    return R, pairs[np.sort(first)]


def random_problem(
    n: int = 100,
    degree: float = 10.0,
    sigma_deg: float = 2.0,
    outliers: float = 0.0,
    graph: str = "er",
    seed: int | None = 0,
) -> ViewGraph:
    """A random view graph with ground truth (``graph.gt_cam_from_world``).

    ``n`` cameras with uniformly random rotations (``er``) or along a trajectory (``traj``),
    about ``n * degree / 2`` edges, each ``R_ij = R_j R_i^T exp(e)`` with isotropic noise
    ``e ~ N(0, sigma^2 I)`` (sigma in degrees), and a fraction ``outliers`` of the edges
    replaced by uniformly random rotations. ``graph.meta["outlier"]`` flags those edges.
    """
    if graph not in GRAPHS:
        raise ValueError(f"graph must be one of {GRAPHS}")
    if n < 2:
        raise ValueError("need at least 2 cameras")
    rng = np.random.default_rng(seed)
    if graph == "er":
        R = so3.random_rotations(n, rng)
        pairs = _er_pairs(n, int(round(n * degree / 2)), rng)
    else:
        R, pairs = _trajectory(n, degree, rng)
    i, j = pairs[:, 0], pairs[:, 1]
    rel = R[j] @ np.swapaxes(R[i], 1, 2)
    if sigma_deg > 0:
        rel = so3.perturb(rel, np.deg2rad(sigma_deg), rng)
    is_out = rng.random(len(pairs)) < outliers
    rel[is_out] = so3.random_rotations(int(is_out.sum()), rng)
    g = ViewGraph.from_edges(i, j, rel, node_ids=np.arange(n))
    g.gt_cam_from_world = R
    g.meta.update(outlier=is_out, sigma_deg=sigma_deg, outliers=outliers, graph=graph, seed=seed)
    return g
