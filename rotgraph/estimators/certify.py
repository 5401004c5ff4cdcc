"""A certificate of global optimality for chordal multiple rotation averaging.

The chordal cost of absolute rotations ``R_i`` (cam_from_world, rotgraph's convention,
``R_ij = R_j R_i^T`` on the edge ``(i, j)``) is

    f(R) = sum_e w_e |R_j - R_ij R_i|_F^2 .

It is not convex, and a local solver can stop at a critical point that is not the global
minimum. Lagrangian duality (Eriksson, Olsson, Kahl & Chin, "Rotation averaging and strong
duality", CVPR 2018 / TPAMI 2019; Rosen et al.'s SE-Sync; GTSAM's Shonan averaging) gives
a test of one candidate: if one symmetric matrix is positive semidefinite, no rotations
have a lower cost, whatever the noise.

Derivation, in rotgraph's convention
------------------------------------
Stack the rotations ``Y = [R_1; R_2; ...; R_n]`` (3n x 3, block row ``i`` is ``R_i``).
Each edge's term expands to ``|R_j|^2 + |R_ij R_i|^2 - 2 tr(R_j^T R_ij R_i)
= 6 - 2 tr(R_j^T R_ij R_i)``. Let ``W`` be the symmetric 3n x 3n matrix with

    block (j, i) = w_e R_ij,      block (i, j) = w_e R_ij^T      (summed over the edges),

zero diagonal blocks. Then ``tr(Y^T W Y) = sum_(a,b) tr(R_a^T W_ab R_b)`` holds each
edge twice, ``tr(R_j^T w R_ij R_i) + tr(R_i^T w R_ij^T R_j) = 2 w tr(R_j^T R_ij R_i)``, so

    f(Y) = 6 sum_e w_e - tr(Y^T W Y),

and minimising ``f`` is maximising ``tr(Y^T W Y)`` subject to ``R_i R_i^T = I`` (and
``det R_i = 1``). The Lagrangian with symmetric multipliers ``Lambda_i`` for
``R_i R_i^T = I`` is ``tr(Y^T W Y) + sum_i tr(Lambda_i (I - R_i R_i^T))``; its gradient in
block row ``i`` vanishes when ``(W Y)_i = Lambda_i R_i``, so (``R_i^T`` on the *right* for
this ``W``)

    Lambda_i = sym((W Y)_i R_i^T),     M = blkdiag(Lambda_1, ..., Lambda_n) - W .

``Y`` is a first-order critical point of ``f`` on SO(3)^n iff every ``(W Y)_i R_i^T`` is
symmetric, i.e. iff ``M Y = 0`` (block row ``i`` of ``M Y`` is ``-skew((W Y)_i R_i^T) R_i``).
For every ``Y``, ``Y^T M Y = 0`` and ``sum_i tr(Lambda_i) = tr(Y^T W Y)``.

Weak duality: for any symmetric ``Lambda'_i`` with ``blkdiag(Lambda') - W >= 0`` and any
rotations ``Y'``, ``tr(Y'^T W Y') <= tr(Y'^T blkdiag(Lambda') Y') = sum_i tr(Lambda'_i)``.
``Lambda'_i = Lambda_i + mu I`` with ``mu = max(0, -lambda_min(M))`` is always feasible, so

    f* >= dual_bound = 6 sum_e w_e - sum_i tr(Lambda_i) - 3 n mu ,

and ``duality_gap = f(Y) - dual_bound = 3 n mu`` (to rounding): when ``M`` is positive
semidefinite (``mu = 0``) the candidate is a global minimum. If ``M >= 0`` then
``tr(Y^T M Y) = 0`` forces ``M Y = 0``, so a candidate that is not critical always has a
negative eigenvalue (its direction mixes span(Y) and the gradient ``M Y``): the ground truth
of a noisy problem is never certified. At a critical point span(Y) is an invariant
subspace of ``M`` with the eigenvalue 0 (three times: the gauge), and ``lambda_min(M) =
min(0, lambda_complement)``, the smallest eigenvalue of ``M`` on the orthogonal complement
of span(Y). ``lambda_complement > 0`` is a strict certificate: the optimum is then also
unique up to the gauge (the semidefinite relaxation has the rank-3 solution ``Y Y^T`` only).

This is GTSAM's matrix: ``ShonanAveraging3`` with measurements ``wRi^T wRj = R_ij^T`` on
keys ``(i, j)``, its ``Stiefel`` element ``S = [wR_1 ... wR_n] = Y^T`` (``wR_i = R_i^T``),
builds ``Q_`` with block ``(i, j) = kappa R_ij^T`` (``= W``, ``kappa = 1 / sigma^2`` of an
isotropic noise model), ``Lambda_j = sym((Q S^T)_j S_j)`` (``= sym((W Y)_j R_j^T)``) and
``A = Lambda - Q`` (``= M``); ``checkOptimality`` is ``lambda_min(A) > -1e-4`` (its
``optimalityThreshold``), computed by Lanczos to an absolute precision of 1e-3. Checked
entry by entry in ``tests/test_certify.py``.

Normalisation
-------------
The weights are divided by their median (over the edges certified): with unit weights
``M`` is GTSAM's ``A`` for ``sigma = 1`` exactly, and the tolerance (default 1e-4, GTSAM's)
means the same in both; with weights, it is GTSAM's for ``kappa_e = w_e / median(w)``.
``primal_cost``, ``dual_bound`` and ``duality_gap`` are in the same normalisation
(``Certificate.weight_scale`` is the median divided out). The verdict needs
``lambda_min(M) >= -tol`` and, in addition, a first-order critical point:
``stationarity = max_i |vee(skew((W Y)_i R_i^T))| / d_i = max_i |(M Y)_i|_F / (sqrt(2)
d_i)`` (``d_i`` the node's weighted degree) below ``stationarity_tol`` (default 1e-6). For
a node whose neighbours agree that it is rotated by ``theta``, that is ``sin(theta)``: a
scale-free measure, in radians for small values. (GTSAM has no such test; an almost-critical candidate can pass its eigenvalue
test, as a small gradient gives only a small negative eigenvalue, of order ``d s^2 / n``.)

Computing lambda_min
--------------------
``W`` is assembled once as a block-sparse matrix (3x3 blocks, two an edge: memory O(E)),
``M X = Lambda X - W X`` applied matrix-free, never factorised (random view graphs fill
in: a sparse LU of the n = 20 000, degree 10 Erdos-Renyi graph's scalar Laplacian alone
took minutes). Small
problems (``3 n <= DENSE_MAX``) use LAPACK's dense symmetric eigensolver; larger ones
LOBPCG (Knyazev 2001; a lean implementation here, as scipy's spends more time in its
bookkeeping than in the products at this size, and its stopping test is all-or-nothing),
a block of 4 seeded random vectors, preconditioned by the inverse weighted degrees (Jacobi:
``M`` is close to a connection Laplacian), BLAS on one thread. At a critical point it runs
on the orthogonal complement of span(Y) (exact deflation: span(Y) is invariant), giving
``lambda_complement``; otherwise on the whole space, started from ``Y`` and random vectors.
A Ritz value is an upper bound of the smallest eigenvalue, so one below ``-tol`` is
conclusive; a non-negative verdict relies on LOBPCG having found the bottom of the
spectrum (as GTSAM's Lanczos does). It stops when the smallest Ritz pair's residual is
below ``max(tol / 4, 1e-2 |theta|)`` (an eigenvalue lies within it of the Ritz value: near
the threshold the absolute term decides, far from it 1e-2 is plenty for the verdict);
without that after ``max_iterations`` and no Ritz value below ``-tol``, the verdict is
``undecided`` (not certified). Pose graphs have a small spectral gap (the smallest
eigenvalue beyond the gauge 4e-4 on parking-garage) that Jacobi does not fix (~400
iterations): after 20 iterations with a Ritz value below 1e-2 of the median degree, a thin
graph (reverse Cuthill-McKee envelope of its Laplacian under 100 entries an edge) goes on
preconditioned by the rotated graph Laplacian ``B ((L + 1e-3 D)^-1 kron I) B^T``, ``B =
blkdiag(R_i)`` (``M`` itself without noise; a sparse LU of the n x n scalar Laplacian, which
does not fill in on such graphs; never of ``M``), ~30 iterations. Measured (2 cores, idle):
n = 2000 / 40k edges 0.07-0.1 s (~10-15 iterations; the default solve takes 0.25-0.36 s),
n = 20 000 / 400k edges ~1 s, no memory above the solve's; parking-garage 0.05 s,
cubicle 0.2 s.

What is certified: the weighted chordal L2 problem on the edges given (``inliers``: on
those only, e.g. the fixed point of a robust solve). Per-edge information matrices have no
place in it (only scalar weights); rotations with NaN entries (unsolved cameras) and their
edges are left out. Several connected components are certified one by one (each has its
own gauge); the verdict is that of all.

Also here: :func:`refine_chordal`, a local solver of the chordal cost (Riemannian
trust-region Newton, or rotgraph's IRLS with the weights ``w sin(theta) / theta`` of
``rho(theta) = 4 (1 - cos theta)``, the chordal distance of two rotations ``theta``
apart), which turns the answer of any other method into a critical point of the chordal
cost; and :func:`certified_chordal`, which escapes a failed certificate by the rank-lifted
(Shonan, Riemannian staircase) solve and reports what it did.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field

import numpy as np

from .. import so3
from ..errors import OptionError
from ..viewgraph import connected_components
from .laplacian import single_threaded_blas

__all__ = [
    "DEFAULT_TOL",
    "DENSE_MAX",
    "STATIONARITY_TOL",
    "Certificate",
    "CertifiedSolution",
    "certified_chordal",
    "certify",
    "certify_graph",
    "chordal_cost",
    "refine_chordal",
]

#: GTSAM's ``ShonanAveragingParameters::optimalityThreshold`` is -1e-4: ``lambda_min(M) >= -DEFAULT_TOL``.
DEFAULT_TOL = 1e-4
#: A candidate is a critical point when its stationarity (module docstring) is below this.
STATIONARITY_TOL = 1e-6
#: Up to this many unknowns (3 n) the eigenvalues come from LAPACK's dense solver.
DENSE_MAX = 300
# LOBPCG: block size, iterations (cap).
_BLOCK = 4
# LOBPCG stops when the smallest Ritz pair's residual is below max(tol / 4, _RELATIVE_RESIDUAL |theta|).
_RELATIVE_RESIDUAL = 1e-2
_MAX_ITERATIONS = 1000
# LOBPCG iterations with the Jacobi preconditioner before a thin graph (reverse Cuthill-McKee
# envelope of its Laplacian below _THIN_ENVELOPE per edge) with a small spectral gap (Ritz
# value below _SMALL_GAP times the median degree) goes on with the rotated graph Laplacian
# (_laplacian_preconditioner), shifted by _LAPLACIAN_SHIFT times the degrees. Measured:
# parking-garage 483 Jacobi iterations (0.42 s) -> 30 (0.05-0.08 s); cubicle 362 (1.0 s)
# -> 30 (0.3 s); Erdos-Renyi graphs converge under Jacobi in 10-100 iterations.
_JACOBI_ITERATIONS = 20
_SMALL_GAP = 1e-2
_THIN_ENVELOPE = 100.0
_LAPLACIAN_SHIFT = 1e-3


@dataclass(frozen=True)
class Certificate:
    """The verdict of :func:`certify` on one candidate (see the module docstring).

    ``certified``: globally optimal for the weighted chordal cost (``lambda_min >=
    -tolerance`` at a critical point). ``lambda_min``: the smallest eigenvalue of ``M``
    (GTSAM's ``computeMinEigenValue``; ~0 when certified: the gauge). ``lambda_complement``:
    the smallest on the complement of span(Y) (only at a critical point, else NaN); > 0 a
    strict certificate. ``primal_cost`` the chordal cost of the candidate, ``dual_bound`` a
    lower bound of every rotations' cost (valid whatever the verdict), ``duality_gap`` their
    difference (``3 n max(0, -lambda_min)``), all with the weights divided by
    ``weight_scale``. ``stationarity``: the first-order residual (sine of the largest
    rotation a node's neighbours ask for). ``reason``: one sentence, starting with
    ``certified``, ``not critical``, ``negative eigenvalue`` or (LOBPCG did not converge)
    ``undecided``. ``method``: ``dense eigvalsh``, ``lobpcg`` or ``lobpcg (graph-Laplacian
    preconditioner)`` (several, joined by ``+``, over components); ``eigen_iterations`` and
    ``eigen_residual`` those of LOBPCG (summed / the largest over components).

    Attributes
    ----------
    certified : bool
        Globally optimal for the weighted chordal cost.
    lambda_min : float
        The smallest eigenvalue of the certificate matrix ``M``.
    tolerance : float
        The eigenvalue tolerance used.
    duality_gap : float
        ``primal_cost - dual_bound`` (``3 n max(0, -lambda_min)``).
    primal_cost : float
        The chordal cost of the candidate.
    dual_bound : float
        A lower bound of every rotations' chordal cost.
    stationarity : float
        The first-order residual (sine of the largest rotation a node's neighbours ask for).
    stationarity_tolerance : float
        The stationarity tolerance used.
    lambda_complement : float
        The smallest eigenvalue on the complement of span(Y) (NaN unless critical).
    seconds : float
        Wall time.
    method : str
        The eigen-solver(s) used.
    reason : str
        One sentence: why the verdict.
    n_nodes, n_edges, n_components : int
        Size of the problem certified (cameras, edges and components used).
    weight_scale : float
        The median weight divided out of the costs.
    eigen_iterations : int
        LOBPCG iterations (summed over components).
    eigen_residual : float
        LOBPCG's residual (the largest over components).
    """

    certified: bool
    lambda_min: float
    tolerance: float
    duality_gap: float
    primal_cost: float
    dual_bound: float
    stationarity: float
    stationarity_tolerance: float
    lambda_complement: float
    seconds: float
    method: str
    reason: str
    n_nodes: int
    n_edges: int
    n_components: int
    weight_scale: float
    eigen_iterations: int = 0
    eigen_residual: float = 0.0

    @property
    def relative_gap(self) -> float:
        """``duality_gap / primal_cost`` (0 when both are 0)."""
        return self.duality_gap / self.primal_cost if self.primal_cost > 0 else 0.0

    def to_dict(self) -> dict:
        """Plain JSON types (NaN becomes None)."""
        out = {}
        for k, v in asdict(self).items():
            if isinstance(v, (bool, np.bool_)):
                out[k] = bool(v)
            elif isinstance(v, (int, np.integer)):
                out[k] = int(v)
            elif isinstance(v, (float, np.floating)):
                out[k] = float(v) if np.isfinite(v) else None
            else:
                out[k] = v
        out["relative_gap"] = float(self.relative_gap)
        return out


# --------------------------------------------------------------------------- the problem


@dataclass
class _Problem:
    """The edges certified, nodes renumbered 0..n-1 (only those with an edge), unit-median weights."""

    n: int
    i: np.ndarray
    j: np.ndarray
    rel: np.ndarray
    w: np.ndarray
    R: np.ndarray
    nodes: np.ndarray  # original index of each node
    edge_index: np.ndarray  # original index of each edge
    weight_scale: float
    components: list = field(default_factory=list)  # node index arrays, one per connected component


def _problem(cam_from_world, edges, cam2_from_cam1, weights, inliers) -> _Problem:
    R = np.asarray(cam_from_world, dtype=np.float64)
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    rel = np.asarray(cam2_from_cam1, dtype=np.float64)
    E = len(edges)
    if R.ndim != 3 or R.shape[1:] != (3, 3):
        raise ValueError(f"cam_from_world must be (N, 3, 3), got {R.shape}")
    if rel.shape != (E, 3, 3):
        raise ValueError(f"cam2_from_cam1 must be ({E}, 3, 3), got {rel.shape}")
    if E and (edges.min() < 0 or edges.max() >= len(R)):
        raise ValueError("edges refer to nodes outside cam_from_world")
    if weights is not None and np.ndim(weights) != 1:
        raise ValueError("the certificate takes scalar edge weights (E,) only: per-edge information "
                         "matrices have no place in the chordal cost")
    w = np.ones(E) if weights is None else np.asarray(weights, dtype=np.float64)
    if w.shape != (E,):
        raise ValueError(f"weights must be ({E},), got {w.shape}")
    keep = np.isfinite(w) & (w > 0) & (edges[:, 0] != edges[:, 1])
    if inliers is not None:
        inl = np.asarray(inliers, dtype=bool).reshape(-1)
        if inl.shape != (E,):
            raise ValueError(f"inliers must be ({E},), got {inl.shape}")
        keep &= inl
    solved = np.isfinite(R).all(axis=(1, 2))
    keep &= solved[edges[:, 0]] & solved[edges[:, 1]]
    keep &= np.isfinite(rel).all(axis=(1, 2))
    eidx = np.flatnonzero(keep)
    if len(eidx) == 0:
        raise ValueError("no edge to certify (every edge is masked out, or touches an unsolved camera)")
    used = np.zeros(len(R), dtype=bool)
    used[edges[eidx].ravel()] = True
    nodes = np.flatnonzero(used)
    index = np.cumsum(used) - 1
    i, j = index[edges[eidx, 0]], index[edges[eidx, 1]]
    w = w[eidx]
    scale = float(np.median(w))
    Rn = R[nodes]
    if not so3.is_rotation(Rn, 1e-9).all():
        Rn = so3.project_to_so3(Rn)
    n = len(nodes)
    k, labels = connected_components(n, np.stack([i, j], axis=1))
    order = np.argsort(labels, kind="stable")
    comps = np.split(order, np.cumsum(np.bincount(labels, minlength=k))[:-1])
    return _Problem(n, i, j, rel[eidx], w / scale, Rn, nodes, eidx, scale, comps)


def _component_edges(p: _Problem, comp: np.ndarray):
    """``(i, j, rel, w)`` of the edges of one component, its nodes renumbered 0..len(comp)-1."""
    if len(p.components) == 1:
        return p.i, p.j, p.rel, p.w
    index = np.full(p.n, -1)
    index[comp] = np.arange(len(comp))
    mask = index[p.i] >= 0
    return index[p.i[mask]], index[p.j[mask]], p.rel[mask], p.w[mask]


class _Graph:
    """One connected component: ``W`` (block-sparse, 3x3 blocks: one index per block, a
    quarter faster to multiply than CSR here; parallel edges are repeated blocks, which the
    product adds up), the weighted degrees, and the maps of the derivation on stacked
    rotations ``Y`` (n, 3, p) (``p = 3``: rotations; ``p > 3``: the rank-lifted problem,
    rows of each block orthonormal)."""

    def __init__(self, n: int, i: np.ndarray, j: np.ndarray, rel: np.ndarray, w: np.ndarray):
        import scipy.sparse as sp

        self.n, self.i, self.j, self.rel, self.w = n, i, j, rel, w
        E = len(i)
        rows = np.concatenate([j, i])
        cols = np.concatenate([i, j])
        order = np.argsort(rows)  # any order within a row: quicksort, 2-3x faster than stable
        data = np.empty((2 * E, 3, 3))
        np.multiply(w[:, None, None], rel, out=data[:E])
        data[E:] = np.swapaxes(data[:E], 1, 2)
        indptr = np.zeros(n + 1, dtype=np.int64)
        np.cumsum(np.bincount(rows, minlength=n), out=indptr[1:])
        self.W = sp.bsr_matrix((data[order], cols[order], indptr), shape=(3 * n, 3 * n))
        self.degree = np.bincount(i, w, n) + np.bincount(j, w, n)
        self.total_weight = float(w.sum())

    def WY(self, Y: np.ndarray) -> np.ndarray:
        """``W Y`` (n, 3, p)."""
        p = Y.shape[2]
        return (self.W @ Y.reshape(3 * self.n, p)).reshape(self.n, 3, p)

    @staticmethod
    def multipliers(Y: np.ndarray, G: np.ndarray) -> np.ndarray:
        """``Lambda_i = sym(G_i Y_i^T)`` (n, 3, 3), ``G = W Y``."""
        GY = G @ np.swapaxes(Y, 1, 2)
        return 0.5 * (GY + np.swapaxes(GY, 1, 2))

    def M_times(self, Lam: np.ndarray, X: np.ndarray) -> np.ndarray:
        """``M X = blkdiag(Lambda) X - W X`` for X (3n, k)."""
        k = X.shape[1]
        return (Lam @ X.reshape(self.n, 3, k)).reshape(3 * self.n, k) - self.W @ X

    def M_dense(self, Lam: np.ndarray) -> np.ndarray:
        A = -self.W.toarray()
        for a in range(3):
            for b in range(3):
                A[3 * np.arange(self.n) + a, 3 * np.arange(self.n) + b] += Lam[:, a, b]
        return A

    def gradient_residual(self, Y: np.ndarray, G: np.ndarray, Lam: np.ndarray) -> np.ndarray:
        """``(M Y)_i = Lambda_i Y_i - G_i`` (n, 3, p): minus half the Riemannian gradient of
        ``tr(Y^T W Y)``; for ``p = 3`` it is ``-skew(G_i R_i^T) R_i``."""
        return Lam @ Y - G

    def stationarity(self, Y: np.ndarray, G: np.ndarray, Lam: np.ndarray) -> float:
        """``max_i |(M Y)_i|_F / (sqrt(2) d_i)`` (= ``|vee(skew(G_i R_i^T))| / d_i`` at p = 3)."""
        r = self.gradient_residual(Y, G, Lam).reshape(self.n, -1)
        return float((np.sqrt(np.einsum("ij,ij->i", r, r)) / (np.sqrt(2.0) * self.degree)).max())

    def cost(self, Y: np.ndarray) -> float:
        """``sum_e w_e |Y_j - R_ij Y_i|_F^2``."""
        D = Y[self.j] - self.rel @ Y[self.i]
        return float(self.w @ np.einsum("eab,eab->e", D, D))


def chordal_cost(cam_from_world, edges, cam2_from_cam1, weights=None) -> float:
    """``sum_e w_e |R_j - R_ij R_i|_F^2`` (edges with an unsolved end left out; weights as given)."""
    R = np.asarray(cam_from_world, dtype=np.float64)
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    D = R[edges[:, 1]] - np.asarray(cam2_from_cam1, dtype=np.float64) @ R[edges[:, 0]]
    v = np.einsum("eab,eab->e", D, D)
    w = np.ones(len(edges)) if weights is None else np.asarray(weights, dtype=np.float64)
    ok = np.isfinite(v)
    return float(w[ok] @ v[ok])


# --------------------------------------------------------------------------- eigenvalues


@dataclass
class _Eigen:
    lam_min: float  # smallest eigenvalue of M (whole space)
    lam_complement: float  # smallest on the complement of span(Y) (NaN when not computed)
    vector: np.ndarray  # (3n,) its eigenvector (on the complement when computed there)
    iterations: int
    residual: float
    converged: bool
    how: str


def _span_basis(Y: np.ndarray) -> np.ndarray:
    """Orthonormal columns spanning the columns of ``Y`` (n, 3, p) stacked as 3n x p."""
    n, _, p = Y.shape
    Z = Y.reshape(3 * n, p)
    if p == 3:
        return Z / np.sqrt(n)  # Y^T Y = n I for rotations
    U, s, _ = np.linalg.svd(Z, full_matrices=False)
    return U[:, s > 1e-10 * s[0]]


def _eigen(g: _Graph, Y: np.ndarray, Lam: np.ndarray, critical: bool, tol: float, method: str,
           rng, max_iterations: int) -> _Eigen:
    """The smallest eigenvalue of ``M`` (module docstring, 'Computing lambda_min')."""
    C = _span_basis(Y)
    N = 3 * g.n
    how = method if method != "auto" else ("dense" if N <= DENSE_MAX else "lobpcg")
    if how == "lobpcg" and N < 8 * (_BLOCK + C.shape[1]):
        how = "dense"  # LOBPCG needs a space several blocks wide
    if how == "dense":
        from scipy.linalg import eigh

        A = g.M_dense(Lam)
        with single_threaded_blas():
            ev, V = eigh(A, subset_by_index=[0, 0], driver="evr")
            lam_min, vec = float(ev[0]), V[:, 0]
            lam_c = float("nan")
            if critical:
                # span(Y) moved up out of the way: the smallest eigenvalue left is the complement's.
                A += (2.0 * float(np.abs(A).sum(axis=1).max()) + 1.0) * (C @ C.T)
                ev, V = eigh(A, subset_by_index=[0, 0], driver="evr")
                lam_c, vec = float(ev[0]), V[:, 0]
                lam_min = min(lam_min, lam_c)
        return _Eigen(lam_min, lam_c, vec, 0, 0.0, True, "dense eigvalsh")
    dinv = np.repeat(1.0 / g.degree, 3)[:, None]

    def matmul(X):
        return g.M_times(Lam, X)

    def jacobi(Rm):
        return dinv * Rm

    constraint = C if critical else None  # deflate span(Y) only where it is invariant
    X0 = rng.standard_normal((N, _BLOCK)) if critical else np.hstack([C, rng.standard_normal((N, _BLOCK))])
    how = "lobpcg"
    with single_threaded_blas():
        first = min(max_iterations, _JACOBI_ITERATIONS)
        theta, X, res, it, conv = _lobpcg(matmul, jacobi, X0, constraint, tol, first)
        if not conv and max_iterations > first:
            # Slow. With a small spectral gap on a thin graph (pose graphs) the rotated
            # graph Laplacian fixes it; otherwise Jacobi goes on.
            small_gap = abs(theta) < _SMALL_GAP * float(np.median(g.degree))
            precondition = _laplacian_preconditioner(g, Y) if small_gap and Y.shape[2] == 3 else None
            if precondition is not None:
                how = "lobpcg (graph-Laplacian preconditioner)"
            theta, X, res, more, conv = _lobpcg(matmul, precondition or jacobi, X, constraint, tol, max_iterations - first)
            it += more
    if critical:
        return _Eigen(min(theta, 0.0), theta, X[:, 0], it, res, conv, how)
    return _Eigen(theta, float("nan"), X[:, 0], it, res, conv, how)


def _rcm_envelope(n: int, i: np.ndarray, j: np.ndarray) -> int:
    """The envelope (profile) of the graph Laplacian in reverse Cuthill-McKee order: an upper
    bound of the fill of its Cholesky factor (:func:`.laplacian.rcm_widths`)."""
    from .laplacian import rcm_widths

    return int(rcm_widths(n, i, j).sum())


def _laplacian_preconditioner(g: _Graph, R: np.ndarray):
    """``X -> B ((L + eps D)^-1 kron I_3) B^T X`` with ``B = blkdiag(R_i)``, ``L`` the weighted
    graph Laplacian, ``D`` its degrees: ``M`` itself without noise (``M = B (L kron I) B^T``),
    symmetric positive definite. Only for thin graphs: None when the reverse Cuthill-McKee
    envelope of ``L`` exceeds :data:`_THIN_ENVELOPE` per edge (a sparse factorisation of a
    well-connected graph fills in; Jacobi serves those well anyway). The factorisation is of
    the n x n scalar Laplacian, not of ``M``."""
    n = g.n
    if _rcm_envelope(n, g.i, g.j) > _THIN_ENVELOPE * len(g.i):
        return None
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    A = sp.coo_matrix((np.r_[g.w, g.w], (np.r_[g.i, g.j], np.r_[g.j, g.i])), shape=(n, n)).tocsc()
    lu = spla.splu((sp.diags(g.degree * (1.0 + _LAPLACIAN_SHIFT)) - A).tocsc(), permc_spec="MMD_AT_PLUS_A")
    Rt = np.ascontiguousarray(np.swapaxes(R, 1, 2))

    def apply(Rm: np.ndarray) -> np.ndarray:
        k = Rm.shape[1]
        Z = (Rt @ Rm.reshape(n, 3, k)).reshape(n, 3 * k)
        return (R @ lu.solve(Z).reshape(n, 3, k)).reshape(3 * n, k)

    return apply


def _orthonormal_basis(S: np.ndarray, AS: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An orthonormal basis ``Q = S C`` of span(S) (SVQB: eigen-decomposition of the scaled
    Gram matrix, directions below 1e-10 of the largest dropped), ``A Q``, and ``C``."""
    norms = np.sqrt(np.einsum("ij,ij->j", S, S))
    norms[norms == 0] = 1.0
    Gm = (S.T @ S) / np.outer(norms, norms)
    ev, U = np.linalg.eigh(Gm)
    keep = ev > 1e-10 * ev[-1]
    C = (U[:, keep] / np.sqrt(ev[keep])) / norms[:, None]
    return S @ C, AS @ C, C


def _lobpcg(matmul, precondition, X0: np.ndarray, C, tol: float, max_iterations: int):
    """Smallest eigenpair of the symmetric operator ``matmul`` by LOBPCG (Knyazev 2001), on
    the orthogonal complement of the orthonormal columns ``C`` when given.

    Preconditioner: ``dinv``, the inverse weighted degree of each node (Jacobi: ``M`` is
    close to a connection Laplacian). Each iteration: one product with the block of
    preconditioned residuals ``W``, a Rayleigh-Ritz step on ``[X, W, P]`` (orthonormalised
    by SVQB). Stops when the smallest Ritz pair's residual is below ``max(tol / 4,
    _RELATIVE_RESIDUAL |theta|)`` (an eigenvalue lies within it of ``theta``). Returns ``(theta, x, residual,
    iterations, converged)``.
    """

    def deflate(Z: np.ndarray) -> np.ndarray:
        return Z if C is None else Z - C @ (C.T @ Z)

    k = X0.shape[1]
    X0 = deflate(X0)
    X, AX, _ = _orthonormal_basis(X0, matmul(X0))
    lam, V = np.linalg.eigh(0.5 * (X.T @ AX + AX.T @ X))
    k = min(k, len(lam))
    X, AX, lam = X @ V[:, :k], AX @ V[:, :k], lam[:k]
    P = AP = None
    for it in range(max_iterations + 1):
        Rm = AX - X * lam
        res = float(np.linalg.norm(Rm[:, 0]))
        theta = float(lam[0])
        if res <= max(tol / 4, _RELATIVE_RESIDUAL * abs(theta)):
            return theta, X, res, it, True
        if it == max_iterations:
            break
        Wm = deflate(precondition(Rm))
        AW = matmul(Wm)
        if P is None:
            S, AS = np.hstack([X, Wm]), np.hstack([AX, AW])
        else:
            S, AS = np.hstack([X, Wm, P]), np.hstack([AX, AW, AP])
        Q, AQ, Cq = _orthonormal_basis(S, AS)
        H = Q.T @ AQ
        lam_all, V = np.linalg.eigh(0.5 * (H + H.T))
        V, lam = V[:, :k], lam_all[:k]
        coeff = Cq @ V  # the new X in the columns of S
        # The new search direction: the part of the update outside the old X.
        P, AP = S[:, k:] @ coeff[k:], AS[:, k:] @ coeff[k:]
        X, AX = Q @ V, AQ @ V
        if C is not None:  # keep rounding errors from creeping back into span(C)
            X = deflate(X)
    return theta, X, res, max_iterations, False


# --------------------------------------------------------------------------- certify


def certify(
    cam_from_world,
    edges,
    cam2_from_cam1,
    weights=None,
    *,
    inliers=None,
    tol: float | None = None,
    stationarity_tol: float | None = None,
    method: str = "auto",
    seed: int = 0,
    max_iterations: int = _MAX_ITERATIONS,
) -> Certificate:
    """Whether ``cam_from_world`` (N, 3, 3) is a global minimum of the weighted chordal cost
    ``sum_e w_e |R_j - R_ij R_i|_F^2`` on ``edges`` (E, 2) with ``cam2_from_cam1`` (E, 3, 3).

    ``weights`` (E,) scalar (default 1; divided by their median; edges of weight 0 left
    out); ``inliers`` (E,) bool: certify the problem on those edges only. Rows of
    ``cam_from_world`` with NaN (unsolved cameras) and their edges are left out; rows not
    orthonormal to 1e-9 are projected onto SO(3) first. ``tol``: the eigenvalue tolerance (default
    :data:`DEFAULT_TOL`, GTSAM's); ``stationarity_tol``: default :data:`STATIONARITY_TOL`.
    ``method``: ``"auto"`` (dense up to :data:`DENSE_MAX` unknowns, else LOBPCG),
    ``"dense"`` or ``"lobpcg"``; ``seed`` seeds LOBPCG's random start, ``max_iterations``
    caps it. See the module docstring for the mathematics and :class:`Certificate` for the
    result.

    Parameters
    ----------
    cam_from_world : (N, 3, 3) array_like
        The candidate absolute rotations (world-to-camera), NaN rows for unsolved cameras.
    edges : (E, 2) array_like of int
        Node indices ``(i, j)`` of each edge.
    cam2_from_cam1 : (E, 3, 3) array_like
        The relative rotation of each edge, ``R_ij = R_j R_i^T``.
    weights : (E,) array_like, optional
        Scalar edge weights (default 1; divided by their median; 0: edge left out).
    inliers : (E,) bool array_like, optional
        Certify the problem on these edges only.
    tol : float, optional
        The eigenvalue tolerance (>= 0; default :data:`DEFAULT_TOL`).
    stationarity_tol : float, optional
        The first-order tolerance (>= 0; default :data:`STATIONARITY_TOL`).
    method : {"auto", "dense", "lobpcg"}, default "auto"
        The eigen-solver.
    seed : int, default 0
        Seed of LOBPCG's random start.
    max_iterations : int, default 1000
        Cap of LOBPCG's iterations.

    Returns
    -------
    Certificate
        The verdict and its numbers.

    Raises
    ------
    OptionError
        A bad ``method`` or a negative tolerance (also a ``ValueError``).
    ValueError
        Arrays of the wrong shapes, or no edge left to certify.
    """
    t0 = time.perf_counter()
    tol = DEFAULT_TOL if tol is None else float(tol)
    stol = STATIONARITY_TOL if stationarity_tol is None else float(stationarity_tol)
    if method not in ("auto", "dense", "lobpcg"):
        raise OptionError(f"method must be auto, dense or lobpcg, got {method!r}")
    if not (tol >= 0 and stol >= 0):
        raise OptionError("tol and stationarity_tol must be >= 0")
    p = _problem(cam_from_world, edges, cam2_from_cam1, weights, inliers)
    return _certify_problem(p, tol, stol, method, seed, max_iterations, t0)[0]


def _certify_problem(p: _Problem, tol, stol, method, seed, max_iterations, t0, R=None):
    """:func:`certify` of a prepared problem (rotations ``R``, default ``p.R``); also returns
    the per-component ``(comp, graph, eigen)``."""
    R = p.R if R is None else R
    rng = np.random.default_rng(seed)
    parts, stationarity, trace = [], 0.0, 0.0
    for comp in p.components:
        g = _Graph(len(comp), *_component_edges(p, comp))
        Y = R[comp]
        G = g.WY(Y)
        Lam = g.multipliers(Y, G)
        stationarity = max(stationarity, g.stationarity(Y, G, Lam))
        trace += float(np.trace(Lam, axis1=1, axis2=2).sum())
        parts.append((comp, g, Y, Lam))
    critical = stationarity <= stol
    lam_min, lam_c, iterations, residual, converged, hows, out = np.inf, np.inf, 0, 0.0, True, set(), []
    for comp, g, Y, Lam in parts:
        e = _eigen(g, Y, Lam, critical, tol, method, rng, max_iterations)
        lam_min, lam_c = min(lam_min, e.lam_min), min(lam_c, e.lam_complement)
        iterations += e.iterations
        residual = max(residual, e.residual)
        converged &= e.converged
        hows.add(e.how)
        out.append((comp, g, e))
    if not critical:
        lam_c = float("nan")
    mu = max(0.0, -lam_min)
    primal = sum(g.cost(R[comp]) for comp, g, _ in out)
    dual = 6.0 * float(p.w.sum()) - trace - 3.0 * p.n * mu
    gap = primal - dual
    if not critical:
        certified = False
        reason = (f"not critical: stationarity {stationarity:.3g} > {stol:.3g}, not a first-order critical point of "
                  f"the chordal cost (lambda_min {lam_min:.3g}); refine it first: on the command line 'rotgraph solve "
                  "INPUT -o OUTPUT --certify' (refines, then certifies), in Python rotgraph.refine_chordal")
    elif lam_min < -tol:
        certified = False
        reason = (f"negative eigenvalue: lambda_min {lam_min:.3g} < -{tol:.3g} at a critical point, not certified "
                  f"(a local minimum or saddle, or the relaxation is not tight); duality gap {gap:.3g}")
    elif not converged:
        certified = False
        reason = (f"undecided: LOBPCG did not converge in {max_iterations} iterations (smallest Ritz value "
                  f"{lam_c:.3g}, residual {residual:.3g}): no negative eigenvalue found, none ruled out")
    else:
        certified = True
        reason = (f"certified: a global minimum of the chordal cost (lambda_min {lam_min:.3g} >= -{tol:.3g}, "
                  f"duality gap {gap:.3g}, smallest eigenvalue beyond the gauge {lam_c:.3g})")
    cert = Certificate(
        certified=bool(certified),
        lambda_min=float(lam_min),
        tolerance=tol,
        duality_gap=float(gap),
        primal_cost=float(primal),
        dual_bound=float(dual),
        stationarity=float(stationarity),
        stationarity_tolerance=stol,
        lambda_complement=float(lam_c),
        seconds=time.perf_counter() - t0,
        method=" + ".join(sorted(hows)),
        reason=reason,
        n_nodes=p.n,
        n_edges=len(p.i),
        n_components=len(p.components),
        weight_scale=p.weight_scale,
        eigen_iterations=int(iterations),
        eigen_residual=float(residual),
    )
    return cert, out


def certify_graph(graph, cam_from_world, *, inliers=None, use_weights: bool = False, **kwargs) -> Certificate:
    """:func:`certify` on a :class:`~rotgraph.viewgraph.ViewGraph`: its edges and relative
    rotations, its weights when ``use_weights`` (as ``SolveOptions.use_weights``), else unit
    weights; ``inliers`` e.g. ``AveragingResult.inliers``. Information matrices are ignored."""
    return certify(cam_from_world, graph.edges, graph.cam2_from_cam1, graph.weights if use_weights else None,
                   inliers=inliers, **kwargs)


# --------------------------------------------------------------------------- local solvers


def refine_chordal(
    cam_from_world,
    edges,
    cam2_from_cam1,
    weights=None,
    *,
    inliers=None,
    method: str = "trust-region",
    max_iterations: int = 200,
    stationarity_tol: float = 1e-10,
) -> tuple[np.ndarray, int, float]:
    """A critical point of the weighted chordal cost near ``cam_from_world`` (rotgraph has no
    other local solver of it: ``method="chordal"`` is the linear relaxation, ``l2`` the
    geodesic cost). Returns ``(cam_from_world, iterations, stationarity)``.

    ``method="trust-region"`` (default): :func:`_trust_region`, Riemannian trust-region
    Newton on SO(3)^n. ``"irls"``: rotgraph's IRLS (:func:`~.irls.solve_weighted`, one
    anchored graph-Laplacian solve an iteration, ``R_i <- R_i exp(x_i)``) with the edge
    weights ``w_e sin(theta_e) / theta_e``: the chordal term of an edge is ``4 (1 - cos
    theta_e)`` of its residual angle, whose IRLS weight ``rho'(theta) / theta`` that is (up
    to the factor 4), so its fixed point is a critical point of the chordal cost (the
    Lie-algebraic gradient of ``theta^2 / 2`` is the residual vector itself). Both run until
    the stationarity of :func:`certify` is below ``stationarity_tol``, or ``max_iterations``.

    Measured from rotgraph's ``l2`` answer (stationarity 1e-10): up to 30 degrees of noise
    both take 5-15 iterations, IRLS 0.2 s and trust-region 0.2 s at 2000 cameras / 40k
    edges; at 60 degrees (2000 cameras, degree 10) IRLS had not converged after 500
    iterations (83 s, stationarity 1.5e-2), trust-region converged in 136 (3.6 s); on
    synthetic pose graphs (2000 cameras, degree 4, 10 degrees) IRLS 215 iterations / 3.4 s,
    trust-region 13 / 1.1 s.

    Rows with NaN stay NaN; edges masked out (``inliers``) or touching them are ignored.
    The gauge stays near the input's (trust-region) or the highest-degree node of each
    component stays fixed (IRLS).

    Parameters
    ----------
    cam_from_world : (N, 3, 3) array_like
        The starting absolute rotations (world-to-camera), NaN rows for unsolved cameras.
    edges : (E, 2) array_like of int
        Node indices ``(i, j)`` of each edge.
    cam2_from_cam1 : (E, 3, 3) array_like
        The relative rotation of each edge, ``R_ij = R_j R_i^T``.
    weights : (E,) array_like, optional
        Scalar edge weights (default 1).
    inliers : (E,) bool array_like, optional
        Use these edges only.
    method : {"trust-region", "irls"}, default "trust-region"
        The local solver.
    max_iterations : int, default 200
        Iteration cap.
    stationarity_tol : float, default 1e-10
        Stop when the stationarity of :func:`certify` is below this.

    Returns
    -------
    cam_from_world : (N, 3, 3) float64 ndarray
        The refined rotations (NaN rows kept).
    iterations : int
        Iterations run.
    stationarity : float
        The final stationarity.
    """
    if method not in ("trust-region", "irls"):
        raise OptionError(f"method must be trust-region or irls, got {method!r}")
    p = _problem(cam_from_world, edges, cam2_from_cam1, weights, inliers)
    out = np.asarray(cam_from_world, dtype=np.float64).copy()
    total, worst = 0, 0.0
    for comp in p.components:
        g = _Graph(len(comp), *_component_edges(p, comp))
        if method == "irls":
            R, it, s = _irls_chordal(g, p.R[comp], max_iterations, stationarity_tol)
        else:
            R, it, s = _trust_region(g, p.R[comp].copy(), max_iterations, stationarity_tol)
        out[p.nodes[comp]] = R
        total, worst = max(total, it), max(worst, s)
    return out, total, worst


def _stationarity_of(g: _Graph, Y: np.ndarray) -> float:
    G = g.WY(Y)
    return g.stationarity(Y, G, g.multipliers(Y, G))


def _irls_chordal(g: _Graph, R: np.ndarray, max_iterations: int, stationarity_tol: float):
    """:func:`refine_chordal` on one component: ``(R, iterations, stationarity)``."""
    from .irls import solve_weighted
    from .laplacian import make_laplacian
    from .residuals import EdgeSystem

    s = _stationarity_of(g, R)
    if s <= stationarity_tol or max_iterations <= 0:
        return R, 0, s
    e = np.stack([g.i, g.j], axis=1)
    anchor = int(np.argmax(g.degree))
    q = so3.quaternion_rows_from_matrices(R)
    system = EdgeSystem(g.n, e, so3.quaternion_rows_from_matrices(g.rel), anchor)
    lap = make_laplacian(g.n, e, anchor)
    w = g.w

    def weight(theta: np.ndarray) -> np.ndarray:
        return w * np.sinc(theta / np.pi)  # sin(theta) / theta

    it = 0
    while s > stationarity_tol and it < max_iterations:
        q, k, _ = solve_weighted(q, system, lap, weight, min(5, max_iterations - it), 0.0)
        it += k
        R = so3.matrices_from_quaternion_rows(q)
        s = _stationarity_of(g, R)
    return R, it, s


def _project_tangent(Y: np.ndarray, Z: np.ndarray) -> np.ndarray:
    """Orthogonal projection onto the tangent space at ``Y`` (rows of each block orthonormal):
    ``Z_i - sym(Z_i Y_i^T) Y_i``."""
    S = Z @ np.swapaxes(Y, 1, 2)
    return Z - 0.5 * (S + np.swapaxes(S, 1, 2)) @ Y


def _retract(Y: np.ndarray, eta: np.ndarray) -> np.ndarray:
    """Polar retraction: the nearest block with orthonormal rows to each ``Y_i + eta_i``."""
    U, _, Vt = np.linalg.svd(Y + eta, full_matrices=False)
    return U @ Vt


def _trust_region(g: _Graph, Y: np.ndarray, max_iterations: int = 200, stationarity_tol: float = 1e-10,
                  max_inner: int = 500) -> tuple[np.ndarray, int, float]:
    """Riemannian trust-region Newton (Absil, Baker & Gallivan 2007; truncated CG of
    Steihaug-Toint, preconditioned by the inverse weighted degrees) for the chordal cost
    ``sum_e w |Y_j - R_ij Y_i|^2 = 6 sum w - tr(Y^T W Y)`` over blocks ``Y_i`` (3 x p) with
    orthonormal rows: ``p = 3`` rotations (O(3); the determinant stays that of the start),
    ``p > 3`` the rank-lifted problem of Shonan averaging. Riemannian gradient ``2 M Y``,
    Hessian ``eta -> Proj(2 M eta)``, ``M = blkdiag(Lambda(Y)) - W`` (module docstring).
    Returns ``(Y, iterations, stationarity)``."""
    dinv = (1.0 / g.degree)[:, None, None]

    def inner(a, b):
        return float(np.einsum("ijk,ijk->", a, b))

    f = g.cost(Y)
    G = g.WY(Y)
    Lam = g.multipliers(Y, G)
    grad = 2.0 * g.gradient_residual(Y, G, Lam)
    delta_max = np.sqrt(3.0 * float(g.degree.sum()))  # a radian at every node, in the preconditioned norm
    delta = delta_max / 8.0
    it = 0
    s = g.stationarity(Y, G, Lam)
    while s > stationarity_tol and it < max_iterations:
        it += 1

        def hess(eta, Y=Y, Lam=Lam):
            return _project_tangent(Y, 2.0 * (Lam @ eta - g.WY(eta)))

        # Truncated CG (Manopt's tCG with a preconditioner: norms in the P^-1 metric).
        eta = np.zeros_like(Y)
        Heta = np.zeros_like(Y)
        r = grad.copy()
        r0 = np.sqrt(inner(r, r))
        z = _project_tangent(Y, r * dinv)
        z_r = inner(z, r)
        d_Pd = z_r
        d = -z
        e_Pd = e_Pe = 0.0
        hit = False
        for _ in range(max_inner):
            Hd = hess(d)
            d_Hd = inner(d, Hd)
            alpha = z_r / d_Hd if d_Hd != 0 else np.inf
            e_Pe_new = e_Pe + 2.0 * alpha * e_Pd + alpha * alpha * d_Pd
            if d_Hd <= 0 or e_Pe_new >= delta * delta:
                tau = (-e_Pd + np.sqrt(max(e_Pd * e_Pd + d_Pd * (delta * delta - e_Pe), 0.0))) / d_Pd
                eta += tau * d
                Heta += tau * Hd
                hit = True
                break
            e_Pe = e_Pe_new
            eta += alpha * d
            Heta += alpha * Hd
            r += alpha * Hd
            r = _project_tangent(Y, r)
            rn = np.sqrt(inner(r, r))
            if rn <= r0 * min(r0, 0.1):  # superlinear: kappa 0.1, theta 1
                break
            z = _project_tangent(Y, r * dinv)
            z_r_old, z_r = z_r, inner(z, r)
            beta = z_r / z_r_old
            e_Pd = beta * (e_Pd + alpha * d_Pd)
            d_Pd = z_r + beta * beta * d_Pd
            d = -z + beta * d
        Y_new = _retract(Y, eta)
        f_new = g.cost(Y_new)
        model = -(inner(grad, eta) + 0.5 * inner(eta, Heta))
        reg = 1e3 * np.finfo(float).eps * max(1.0, abs(f))
        rho = (f - f_new + reg) / (model + reg) if model + reg > 0 else -1.0
        if rho < 0.25:
            delta *= 0.25
        elif rho > 0.75 and hit:
            delta = min(2.0 * delta, delta_max)
        if rho > 0.1:
            Y, f = Y_new, f_new
            G = g.WY(Y)
            Lam = g.multipliers(Y, G)
            grad = 2.0 * g.gradient_residual(Y, G, Lam)
            s = g.stationarity(Y, G, Lam)
        if delta < 1e-14 * delta_max:
            break
    return Y, it, s


# --------------------------------------------------------------------------- item 2: escape


@dataclass(frozen=True)
class CertifiedSolution:
    """The outcome of :func:`certified_chordal`.

    ``cam_from_world`` (N, 3, 3) the rotations returned (NaN rows as the input's),
    ``certificate`` their :class:`Certificate`; ``start_cost`` and ``cost`` the chordal cost
    (weights divided by ``certificate.weight_scale``) of the input and of the answer;
    ``lower_bound`` the best lower bound of the global minimum found (the largest dual
    bound of the points visited, at any rank: when a lifted solution is certified it is the
    relaxation's optimum, and ``relaxation_solved`` is True); ``max_rank`` the highest rank
    used (3: no lift); ``history`` one dict per stage (``stage``: ``local`` / ``lift`` /
    ``round``, ``rank``, ``cost``, ``lambda_min``, ``stationarity``, ``iterations``,
    ``seconds``); ``summary`` one sentence. ``relative_gap``: ``(cost - lower_bound) /
    cost``, what the answer is proven to be within of the global minimum even when the
    eigenvalue test fails (a relaxation solved at rank 4 and rounded can leave 1e-8).
    """

    cam_from_world: np.ndarray
    certificate: Certificate
    start_cost: float
    cost: float
    lower_bound: float
    max_rank: int
    relaxation_solved: bool
    history: list
    summary: str
    seconds: float

    @property
    def relative_gap(self) -> float:
        return max(self.cost - self.lower_bound, 0.0) / self.cost if self.cost > 0 else 0.0

    def to_dict(self) -> dict:
        return {"certificate": self.certificate.to_dict(), "start_cost": float(self.start_cost), "cost": float(self.cost),
                "lower_bound": float(self.lower_bound), "relative_gap": float(self.relative_gap),
                "max_rank": int(self.max_rank), "relaxation_solved": bool(self.relaxation_solved),
                "history": self.history, "summary": self.summary, "seconds": float(self.seconds)}


def _round(Y: np.ndarray) -> np.ndarray:
    """Rotations from a rank-lifted ``Y`` (n, 3, p): its 3 leading right singular directions
    (``Y V_3``, the best rank-3 approximation of ``Y Y^T``), the reflection that gives most
    blocks a positive determinant, each block projected onto SO(3)."""
    n, _, p = Y.shape
    _, _, Vt = np.linalg.svd(Y.reshape(3 * n, p), full_matrices=False)
    Y3 = Y @ Vt[:3].T
    if np.count_nonzero(np.linalg.det(Y3) < 0) > n / 2:
        Y3[:, :, 2] *= -1.0
    return so3.project_to_so3(Y3)


def _escape(g: _Graph, Y: np.ndarray, v: np.ndarray, lam: float) -> np.ndarray | None:
    """From a critical point ``Y`` (n, 3, p) whose ``M`` has the eigenvector ``v`` (3n,) of the
    negative eigenvalue ``lam``: lift to rank p + 1 (``[Y, 0]``) and step along the tangent
    direction ``[0, v]``, where the cost falls like ``lam alpha^2``; backtracking from a
    step of about a radian a node. None when no step lowers the cost."""
    n, _, p = Y.shape
    Yl = np.concatenate([Y, np.zeros((n, 3, 1))], axis=2)
    eta = np.zeros_like(Yl)
    eta[:, :, p] = (v / np.linalg.norm(v)).reshape(n, 3)
    f = g.cost(Yl)
    alpha = np.sqrt(n)
    for _ in range(40):
        Yn = _retract(Yl, alpha * eta)
        if g.cost(Yn) < f - 1e-12 * max(f, 1.0):
            return Yn
        alpha *= 0.5
    return None


def certified_chordal(
    cam_from_world,
    edges,
    cam2_from_cam1,
    weights=None,
    *,
    inliers=None,
    max_rank: int = 10,
    tol: float | None = None,
    method: str = "auto",
    seed: int = 0,
    max_iterations: int = 500,
) -> CertifiedSolution:
    """A certified global minimum of the weighted chordal cost, started from ``cam_from_world``
    (the Riemannian staircase of Boumal's Burer-Monteiro analysis, as GTSAM's Shonan
    averaging; Rosen et al.'s SE-Sync).

    1. Local: :func:`_trust_region` (Riemannian trust-region Newton) to a critical point of
       the chordal cost on SO(3)^n; :func:`certify`. Certified: done.
    2. Lift: otherwise the eigenvector of ``M``'s negative eigenvalue is a descent direction
       of the problem lifted to rank ``p + 1`` (blocks 3 x (p+1) with orthonormal rows):
       step along it, trust-region to a critical point there, certify the lifted point
       (same ``M``). Repeat up to ``max_rank`` until ``M >= 0``: the lifted point is then
       a global minimum of the semidefinite relaxation, its cost a lower bound.
    3. Round: the 3 leading directions of the lifted solution, projected onto SO(3), a
       local solve, :func:`certify`. If the relaxation is tight (its solution has rank 3)
       this is the global minimum, certified; otherwise no rotations can be certified and
       the rounded answer comes with the relaxation's bound. The answer is the better of
       the local and the rounded solutions.

    Per connected component; rows with NaN and masked edges as in :func:`certify`.
    Returns a :class:`CertifiedSolution`.
    """
    t0 = time.perf_counter()
    tol = DEFAULT_TOL if tol is None else float(tol)
    if max_rank < 3:
        raise OptionError("max_rank must be >= 3")
    p = _problem(cam_from_world, edges, cam2_from_cam1, weights, inliers)
    rng = np.random.default_rng(seed)
    R_out = p.R.copy()
    history: list = []
    start_cost, lower, top = 0.0, 0.0, 3
    lifted_any, solved, stuck = False, True, []

    def log(stage, rank, cost, lam, stat, it, t):
        history.append({"stage": stage, "rank": int(rank), "cost": float(cost), "lambda_min": float(lam),
                        "stationarity": float(stat), "iterations": int(it), "seconds": time.perf_counter() - t})

    def examine(g, Y, s):
        """(eigen, dual bound) at a point the trust region reached with stationarity s; a
        point that is not critical is not deflated (and ends the staircase)."""
        G = g.WY(Y)
        Lam = g.multipliers(Y, G)
        e = _eigen(g, Y, Lam, s <= STATIONARITY_TOL, tol, method, rng, _MAX_ITERATIONS)
        bound = 6.0 * g.total_weight - float(np.trace(Lam, axis1=1, axis2=2).sum()) - 3.0 * g.n * max(0.0, -e.lam_min)
        return e, bound

    for comp in p.components:
        g = _Graph(len(comp), *_component_edges(p, comp))
        R0 = p.R[comp]
        start_cost += g.cost(R0)
        t = time.perf_counter()
        R, it, s = _trust_region(g, R0.copy(), max_iterations)
        e, bound = examine(g, R, s)
        f_local = g.cost(R)
        log("local", 3, f_local, e.lam_min, s, it, t)
        best, f_best = R, f_local
        Y, rank = R, 3
        while e.lam_min < -tol and rank < max_rank and s <= STATIONARITY_TOL:
            t = time.perf_counter()
            Yn = _escape(g, Y, e.vector, e.lam_min)
            if Yn is None:
                break
            Y, it, s = _trust_region(g, Yn, max_iterations)
            rank += 1
            lifted_any = True
            e, b = examine(g, Y, s)
            bound = max(bound, b)  # weak duality holds at any rank
            log("lift", rank, g.cost(Y), e.lam_min, s, it, t)
        if s > STATIONARITY_TOL:
            stuck.append(rank)
        solved &= bool(e.lam_min >= -tol and s <= STATIONARITY_TOL)
        top = max(top, rank)
        if rank > 3:
            t = time.perf_counter()
            Rr, it, s = _trust_region(g, _round(Y), max_iterations)
            f_r = g.cost(Rr)
            er, b = examine(g, Rr, s)
            bound = max(bound, b)
            log("round", 3, f_r, er.lam_min, s, it, t)
            if f_r < f_best:
                best, f_best = Rr, f_r
        R_out[comp] = best
        lower += bound
    cert = _certify_problem(p, tol, STATIONARITY_TOL, method, seed, _MAX_ITERATIONS, time.perf_counter(), R=R_out)[0]
    cost = cert.primal_cost
    lower = max(lower, cert.dual_bound)
    out = np.asarray(cam_from_world, dtype=np.float64).copy()
    out[p.nodes] = R_out
    if cert.certified:
        summary = ("certified at the local solution" if not lifted_any else
                   f"certified after lifting to rank {top} and rounding")
    else:
        how = ("the relaxation solved at rank " + str(top) if solved else
               f"the trust region did not converge at rank {stuck[0]}" if stuck else
               f"the relaxation not solved by rank {top}")
        gap = max(cost - lower, 0.0) / cost if cost > 0 else 0.0
        summary = (f"not certified ({cert.reason.split(':')[0]}; {how}): cost {cost:.8g}, within {gap:.2g} "
                   f"(relative) of the lower bound {lower:.8g}")
    return CertifiedSolution(out, cert, start_cost, cost, lower, top, solved and lifted_any, history, summary,
                             time.perf_counter() - t0)
