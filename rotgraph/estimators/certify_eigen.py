"""The smallest eigenvalue of the certificate matrix ``M`` of
:mod:`rotgraph.estimators.certify` (whose docstring derives ``M``, ``W`` and the verdict),
on one connected component: LAPACK's dense solver for small problems, a lean LOBPCG for
larger ones, with its preconditioners. ``g`` below is a component's
:class:`~rotgraph.estimators.certify.ChordalGraph` (its ``n``, ``i``, ``j``, ``w``,
``degree``, ``M_times`` and ``M_dense``).

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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .laplacian import single_threaded_blas

__all__ = ["DENSE_MAX", "MAX_ITERATIONS", "smallest_eigen"]

#: Up to this many unknowns (3 n) the eigenvalues come from LAPACK's dense solver.
DENSE_MAX = 300
#: LOBPCG's iteration cap (the default ``max_iterations`` of :func:`~rotgraph.estimators.certify.certify`).
MAX_ITERATIONS = 1000
# LOBPCG: block size.
_BLOCK = 4
# LOBPCG stops when the smallest Ritz pair's residual is below max(tol / 4, _RELATIVE_RESIDUAL |theta|).
_RELATIVE_RESIDUAL = 1e-2
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


def smallest_eigen(g, Y: np.ndarray, Lam: np.ndarray, critical: bool, tol: float, method: str,
                   rng, max_iterations: int) -> _Eigen:
    """The smallest eigenvalue of ``M`` (module docstring, 'Computing lambda_min') of the
    component ``g`` at ``Y`` with the multipliers ``Lam``; on the complement of span(Y) too
    when ``critical``. Returns ``lam_min``, ``lam_complement``, ``vector``, ``iterations``,
    ``residual``, ``converged`` and ``how`` (the method's name)."""
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


def _laplacian_preconditioner(g, R: np.ndarray):
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
