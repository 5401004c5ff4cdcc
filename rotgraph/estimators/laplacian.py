"""The weighted graph Laplacian solves of Lie-algebraic rotation averaging.

Every L1/L2/IRLS iteration solves ``A^T diag(u) A x = A^T v`` on the view graph with the
anchor's unknowns fixed (three right-hand sides: the axes of the update). One class,
:class:`AnchoredLaplacian`, behind one ``solve`` call, chooses between a dense Cholesky
factorisation (small graphs), a sparse LU (thin graphs) and Jacobi-preconditioned
conjugate gradients (well-connected graphs), by size and degree or by timing both.
"""

from __future__ import annotations

import functools
import sys
import threading

import time

import numpy as np

from ..choices import LINEAR_SOLVERS
from .residuals import FLOAT32_MIN_EDGES

__all__ = ["AnchoredLaplacian", "AnchoredBlockLaplacian", "make_laplacian", "LINEAR_SOLVERS", "block_pcg", "block_jacobi", "single_threaded_blas",
           "one_blas_thread"]

# Up to DENSE_MAX cameras, Laplacian solves use a dense Cholesky factorisation; up to
# DENSE_MAX_CONNECTED when the graph is not thin (average degree >= DENSE_MIN_DEGREE).
# Measured (single-threaded BLAS, per solve): n = 500, degree 12: dense 2.9 ms, sparse LU
# 14.6, CG 9.2; n = 800: dense 20, CG 14; trajectories of degree 4 at n = 300: LU 1.6, dense 2.0.
DENSE_MAX = 100
DENSE_MAX_CONNECTED = 500
DENSE_MIN_DEGREE = 8.0
# Up to this many cameras a sparse LU is cheap whatever the density: auto tries both.
DIRECT_MAX = 600
TRIAL_AT = 5
# Relative residual at which the conjugate-gradient Laplacian solves stop. Each solve is
# one IRLS step (an inexact Newton step), corrected by the next one; the fixed point does
# not depend on it. Measured, CG products / IRLS iterations / median error, 1e-6 -> 1e-4:
# er 20k degree 100: 142 / 8 -> 118 / 9, same; er 20k degree 8 (10 % outliers): 937 / 14
# -> 694 / 15, 1.2874 -> 1.2873 deg; er 50k degree 5 (20 %): 7516 / 35 -> 4431 / 34,
# 5.113 -> 5.117; trajectory 20k: 1489 / 15 -> 1038 / 14, 1.4369 -> 1.4372. (1e-3 cut
# more products but took up to 11 IRLS iterations on the first.)
RTOL = 1e-4


def rcm_widths(n: int, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """Each row's width in the envelope (profile) of the graph Laplacian in reverse
    Cuthill-McKee order (the sum bounds the fill of a Cholesky factor, the sum of squares
    its flops), computed in O(E)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import reverse_cuthill_mckee

    A = coo_matrix((np.ones(2 * len(i)), (np.r_[i, j], np.r_[j, i])), shape=(n, n)).tocsr()
    inv = np.empty(n, dtype=np.int64)
    inv[reverse_cuthill_mckee(A, symmetric_mode=True)] = np.arange(n)
    a, b = inv[i], inv[j]
    first = np.arange(n)
    np.minimum.at(first, np.maximum(a, b), np.minimum(a, b))
    return (np.arange(n) - first).astype(np.float64)


# A sparse LU is chosen for a thin graph only when the envelope estimate of its
# factorisation (the sum of squared RCM row widths, times 27 for 3x3 blocks) is below this:
# thin graphs with long-range edges (random thin SfM graphs, a rig's images before its
# frames are known) fill in. Measured: Erdos-Renyi n = 20,000, degree 8: estimate 1.1e12,
# scalar LU 208 s (CG: well conditioned); 3,000 rig images, degree 10: 4.5e9 (x 27), block
# LU 100 s per solve; parking-garage 6e5 and cubicle 4.8e8 (x 27): LU in a second or less.
DIRECT_FLOPS_MAX = 2e10


def direct_is_cheap(n: int, edges, k: int = 1) -> bool:
    """Whether a sparse LU of the Laplacian of ``edges`` with ``k x k`` blocks stays cheap
    (:data:`DIRECT_FLOPS_MAX`); True when ``edges`` is None."""
    if edges is None:
        return True
    w = rcm_widths(n, edges[:, 0], edges[:, 1])
    return float(np.dot(w, w)) * float(k) ** 3 <= DIRECT_FLOPS_MAX


def _choose_solver(n: int, n_edges: int, solver: str, edges=None, k: int = 1) -> tuple[str, list]:
    """The Laplacian solver for ``solver="auto"`` and the ones to time against each other."""
    if solver != "auto":
        return solver, []
    degree = 2.0 * n_edges / max(n, 1)
    # Small graphs: a dense Cholesky beats any sparse machinery. Direct sparse LU has
    # little fill on sparse graphs (trajectories, thin SfM graphs); well-connected
    # graphs fill in, and are well conditioned for CG instead.
    if n <= DENSE_MAX or (n <= DENSE_MAX_CONNECTED and degree >= DENSE_MIN_DEGREE):
        return "dense", []
    solver = "direct" if degree < 12 and direct_is_cheap(n, edges, k) else "cg"
    # Below DIRECT_MAX cameras neither CG nor sparse LU wins everywhere (CG: synthetic
    # graphs, Ellis; LU: Madrid, whose many down-weighted edges slow CG): time one
    # solve of each and keep the faster.
    return solver, (["cg", "direct"] if n <= DIRECT_MAX and solver == "cg" else [])


def _reduced_pattern(n: int, edges: np.ndarray, anchor: int):
    """The sparsity pattern of a Laplacian without the anchor's row and column, one entry (or
    3x3 block) per edge and end, no sort of the 4E entries: ``(keep, indptr, indices, pos_ij,
    pos_ji, ke)``. In each row the diagonal comes first (at ``indptr[:-1]``), then one entry
    per edge (parallel edges are repeated entries, which a CSR or BSR product sums);
    ``pos_ij`` / ``pos_ji`` are where edge ``ke[k]``'s (i, j) and (j, i) entries go; ``ke`` the
    edges not at the anchor (None: all). int32 indices where they fit."""
    i, j = edges[:, 0], edges[:, 1]
    keep = np.ones(n, dtype=bool)
    keep[anchor] = False
    m = n - 1
    ke = np.flatnonzero((i != anchor) & (j != anchor))
    K = len(ke)
    itype = np.int32 if 2 * K + n < 2**31 else np.int64
    index = (np.cumsum(keep) - 1).astype(itype)  # node -> reduced index (anchor: unused)
    ri, rj = index[i[ke]], index[j[ke]]
    rows = np.concatenate([ri, rj])
    indptr = np.zeros(m + 1, dtype=itype)
    np.cumsum(np.bincount(rows, minlength=m) + 1, out=indptr[1:])
    order = np.argsort(rows)  # any order within a row (a CSR product sums it): quicksort, 2-3x faster than stable
    pos = np.empty(2 * K, dtype=itype)
    pos[order] = np.arange(2 * K, dtype=itype) + rows[order] + 1
    del order, rows
    indices = np.empty(indptr[-1], dtype=itype)
    indices[indptr[:-1]] = np.arange(m, dtype=itype)
    indices[pos[:K]] = rj
    indices[pos[K:]] = ri
    return keep, indptr, indices, pos[:K], pos[K:], (ke if K < len(i) else None)


class AnchoredLaplacian:
    """Weighted graph Laplacian ``A^T diag(u) A`` with the anchor's unknowns fixed to zero.

    The sparsity pattern is fixed; each solve scatters new edge weights into it (no
    re-assembly), then solves with a dense Cholesky factorisation (``dense``: the anchor's
    row and column replaced by the identity's), a sparse LU (``direct``) or
    Jacobi-preconditioned conjugate gradients on the three right-hand sides at once
    (``cg``; these two on the matrix without the anchor's row and column).
    """

    def __init__(self, n: int, edges: np.ndarray, anchor: int, solver: str = "auto", pattern: tuple | None = None):
        self.n, self.anchor = n, anchor
        self.solver, self.trial = _choose_solver(n, len(edges), solver, edges)
        self.timings: dict[str, float] = {}
        self.n_solves = 0
        self.rtol = RTOL
        i, j = edges[:, 0], edges[:, 1]
        if self.solver == "dense":
            rows = np.concatenate([i, j, i, j])
            cols = np.concatenate([i, j, j, i])
            ok = (rows != anchor) & (cols != anchor)
            # Each entry of the matrix: its source edge and sign; flat positions in the
            # n x n matrix (bincount adds up the repeated ones).
            self.src = np.tile(np.arange(len(i)), 4)[ok]
            self.sign = np.concatenate([np.ones(2 * len(i)), -np.ones(2 * len(i))])[ok]
            self.pos = (rows * n + cols)[ok]
            return
        # Sparse solvers: the reduced matrix (anchor's row and column removed) in CSR with
        # a fixed pattern (:func:`_reduced_pattern`): each solve writes -u_e into the two
        # entries of edge e and the weighted degrees into the diagonal.
        self.edges = edges
        self.pattern = pattern or _reduced_pattern(n, edges, anchor)  # ``pattern``: another Laplacian's of these edges
        self.keep, self.indptr, self.indices, self.pos_ij, self.pos_ji, self.ke = self.pattern
        # One buffer for every solve's values (the matrix of a solve is dropped before the
        # next): a fresh 2E array each time cost 0.2 s of page faults at 10^7 edges.
        self._data = np.empty(len(self.indices))

    def _values(self, u: np.ndarray, size: int) -> np.ndarray:
        """The dense path's flat n x n matrix."""
        return np.bincount(self.pos, weights=u[self.src] * self.sign, minlength=size)

    def matrix(self, u: np.ndarray):
        """The reduced matrix (anchor's row and column removed) as CSR (sparse solvers); its
        values live in a buffer that the next call overwrites."""
        import scipy.sparse as sp

        m = self.n - 1
        i, j = self.edges[:, 0], self.edges[:, 1]
        data = self._data
        deg = np.bincount(i, weights=u, minlength=self.n)
        deg += np.bincount(j, weights=u, minlength=self.n)
        data[self.indptr[:-1]] = deg[self.keep]
        uk = -(u if self.ke is None else u[self.ke])
        data[self.pos_ij] = uk
        data[self.pos_ji] = uk
        return sp.csr_matrix((data, self.indices, self.indptr), shape=(m, m))

    def solve(self, u: np.ndarray, rhs: np.ndarray, rtol: float | None = None) -> np.ndarray:
        """Solve ``L x = rhs`` (rhs (3, n) with a zero anchor column); returns x (n, 3),
        zero at the anchor. ``rtol``: conjugate gradients' relative residual for this solve
        (default :attr:`rtol`; direct solvers ignore it)."""
        self.n_solves += 1
        rtol = self.rtol if rtol is None else rtol
        if self.trial and self.n_solves >= TRIAL_AT:  # the first L1 solves are atypical
            self.solver = self.trial.pop(0)
            t0 = time.perf_counter()
            out = self._solve(u, rhs, rtol)
            self.timings[self.solver] = time.perf_counter() - t0
            if not self.trial:
                self.solver = min(self.timings, key=self.timings.get)
            return out
        return self._solve(u, rhs, rtol)

    def _solve(self, u: np.ndarray, rhs: np.ndarray, rtol: float) -> np.ndarray:
        n = self.n
        if self.solver == "dense":
            L = self._values(u, n * n)
            L[self.anchor * (n + 1)] = 1.0
            return cholesky_solve(cholesky_factor(L.reshape(n, n)), rhs.T)
        keep = self.keep
        b = rhs.T[keep]
        L = self.matrix(u)
        if self.solver == "direct":
            import scipy.sparse.linalg as spla

            Lc = L.tocsc()
            Lc.sum_duplicates()  # parallel edges: repeated entries
            x = spla.splu(Lc, permc_spec="MMD_AT_PLUS_A").solve(b)
        else:
            x = block_pcg(L, b, rtol=rtol)[0]
        out = np.zeros((n, 3))
        out[keep] = x
        return out


def cholesky_factor(A: np.ndarray) -> np.ndarray:
    """The Cholesky factor of a symmetric positive definite C-ordered ``A`` (overwritten), by
    LAPACK directly (the scipy.linalg wrappers cost more than the work at these sizes). ``A``
    is symmetric: its transpose, the same matrix, is the Fortran-ordered array LAPACK wants
    (``A`` itself would be copied first: 3x slower at 300 unknowns). Raises
    ``numpy.linalg.LinAlgError`` when ``A`` is not positive definite."""
    from scipy.linalg.lapack import dpotrf

    c, info = dpotrf(A.T, lower=False, clean=False, overwrite_a=True)
    if info != 0:
        raise np.linalg.LinAlgError(f"Cholesky factorisation failed: the matrix is not positive definite (LAPACK info {info})")
    return c


def cholesky_solve(c: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``A^-1 b`` from :func:`cholesky_factor`'s factor ``c`` of ``A``."""
    from scipy.linalg.lapack import dpotrs

    x, info = dpotrs(c, b, lower=False)
    if info != 0:
        raise np.linalg.LinAlgError(f"Cholesky solve failed (LAPACK info {info})")
    return x


# Up to this many cameras the 3n x 3n block Laplacian (per-edge information matrices) is
# factorised densely. Measured (n = 300, degree 12, per solve): dense 14 ms, block-Jacobi
# CG 9 ms; n = 150: dense 2.6, CG 5.
BLOCK_DENSE_MAX = 200


def _assembly_operator(target: np.ndarray, src: np.ndarray, sign: np.ndarray, E: int, size: int):
    """The block Laplacian's assembly, which is linear in the edges' blocks: a sparse operator
    (``size`` x 9E) taking ``U`` as rows (3, 3, E) flattened to the values ``sum sign U_src``
    at ``target`` (9, n_blocks: where entry (k, l) of each block goes). One product instead of
    gathering the blocks and nine bincounts (3-5x faster). Built as CSC, column (3 k + l) E + e
    (entry (k, l) of U_e) holding that edge's blocks: one sort of the blocks by edge, no sort of
    the 36 E entries."""
    import scipy.sparse as sp

    order = np.argsort(src, kind="stable")
    indptr = np.zeros(9 * E + 1, dtype=np.int64)
    np.cumsum(np.tile(np.bincount(src, minlength=E), 9), out=indptr[1:])
    return sp.csc_matrix((np.tile(sign[order], 9), target[:, order].ravel(), indptr), shape=(size, 9 * E))


class AnchoredBlockLaplacian:
    """The block Laplacian ``sum_e A_e^T U_e A_e`` of per-edge 3x3 weights ``U_e`` (IRLS
    weight times the edge's world-frame information matrix), the anchor's unknowns fixed
    to zero: the normal equations of the whitened residuals, 3(n - 1) unknowns (node-major).

    Same interface and solver choice as :class:`AnchoredLaplacian` (``solve(U, rhs)`` with
    ``U`` the blocks as rows (3, 3, E)), one right-hand side: a dense Cholesky factorisation up to
    :data:`BLOCK_DENSE_MAX` cameras, above it a sparse LU on thin graphs and conjugate
    gradients preconditioned by the inverse 3x3 diagonal blocks on well-connected ones.
    """

    def __init__(self, n: int, edges: np.ndarray, anchor: int, solver: str = "auto", pattern: tuple | None = None):
        self.n, self.anchor = n, anchor
        self.solver = _choose_solver(n, len(edges), solver, edges, k=3)[0]
        if solver == "auto" and self.solver == "dense" and n > BLOCK_DENSE_MAX:
            thin = 2.0 * len(edges) / max(n, 1) < 12
            self.solver = "direct" if thin and direct_is_cheap(n, edges, k=3) else "cg"
        self.n_solves = 0
        self.rtol = RTOL
        i, j = edges[:, 0], edges[:, 1]
        self.n_edges = E = len(i)
        self.nb = nb = n - 1
        self.m = 3 * nb
        if self.solver == "dense":
            # The four 3x3 blocks of each edge: (i, i) and (j, j) with +U_e, (i, j) and (j, i)
            # with -U_e; the matrix's flat position of entry (k, l) of each block.
            br, bc = np.concatenate([i, j, i, j]), np.concatenate([i, j, j, i])
            ok = (br != anchor) & (bc != anchor)
            src = np.tile(np.arange(E), 4)[ok]  # each block's edge
            sign = np.concatenate([np.ones(2 * E), -np.ones(2 * E)])[ok]
            self.keep = keep = np.ones(n, dtype=bool)
            keep[anchor] = False
            index = np.cumsum(keep) - 1
            r, c = index[br[ok]], index[bc[ok]]
            k, l = np.repeat(np.arange(3), 3), np.tile(np.arange(3), 3)
            self.assemble = _assembly_operator((3 * r + k[:, None]) * self.m + 3 * c + l[:, None], src, sign, E, self.m * self.m)
            return
        # Sparse solvers: a BSR matrix of 3x3 blocks on the scalar Laplacian's pattern (the
        # diagonal block first in each block row, then one block per edge: no sort of the 4E
        # blocks, no assembly operator; 4.5x faster to build and fill at 10^6 edges).
        self.edges = edges
        self.pattern = pattern or _reduced_pattern(n, edges, anchor)
        self.keep, self.indptr, self.indices, pos_ij, pos_ji, ke = self.pattern
        self.diag = self.indptr[:-1]  # the diagonal blocks, in node order
        # Where each edge's two blocks go, for every edge: those at the anchor (no block of their
        # own) to a spare block past the matrix's, so the values are written straight from the
        # Gauss-Newton blocks' rows with no copy of them.
        nnz = len(self.indices)
        if ke is None:
            self.pos = (pos_ij, pos_ji)
        else:
            self.pos = tuple(np.full(E, nnz, dtype=pos_ij.dtype) for _ in range(2))
            self.pos[0][ke], self.pos[1][ke] = pos_ij, pos_ji
        # reused by every solve, as AnchoredLaplacian's; + the spare block. Single precision on huge
        # graphs (conjugate gradients then run in it): half the memory and traffic of the products,
        # and the solve's relative residual (RTOL, 1e-4) is far above its rounding.
        single = self.solver == "cg" and E >= FLOAT32_MIN_EDGES  # (the edge errors' and Gauss-Newton blocks' threshold)
        self._data = np.empty((nnz + 1, 3, 3), dtype=np.float32 if single else np.float64)
        # The edges at the anchor (their blocks go to the spare one) count on their other end's
        # diagonal: their blocks are kept aside as they are written (:meth:`write_blocks`).
        at_anchor = np.flatnonzero((i == anchor) | (j == anchor))
        self._anchor_edges = at_anchor
        self._anchor_rows = (np.cumsum(self.keep) - 1)[np.where(i[at_anchor] == anchor, j[at_anchor], i[at_anchor])]
        self._anchor_blocks = np.zeros((len(at_anchor), 9), dtype=self._data.dtype)

    @property
    def writes_blocks(self) -> bool:
        """Whether :meth:`write_blocks` takes the edges' blocks (the sparse solvers)."""
        return self.solver != "dense"

    def write_blocks(self, b: slice, U: np.ndarray) -> None:
        """Write the blocks ``U`` (3, 3, len) of the edges ``b`` (a slice of the edges, in
        order) into the matrix: ``+U_e`` at each edge's two off-diagonal blocks of ``-L``. The
        diagonal is made by :meth:`solve`. The Gauss-Newton blocks come here chunk by chunk as
        they are made (:meth:`~.residuals.EdgeSystem.gauss_newton_blocks`): no array of all of
        them."""
        # each block one item of nine values (a void scalar): np.put of whole items is 2x faster
        # than a fancy-indexed write of rows of nine (10^7 edges in single precision: ~1.2 s
        # against ~2.5 s a solve, the writes' random access to 720 MB being the rest)
        item = np.dtype((np.void, 9 * self._data.itemsize))
        rows = np.ascontiguousarray(U.reshape(9, -1).T, dtype=self._data.dtype)
        lo = b.start or 0
        blocks, src = self._data.reshape(-1).view(item), rows.reshape(-1).view(item)
        np.put(blocks, self.pos[0][b], src)
        np.put(blocks, self.pos[1][b], src)
        ka = self._anchor_edges
        a, z = np.searchsorted(ka, (lo, lo + rows.shape[0]))
        if z > a:
            self._anchor_blocks[a:z] = rows[ka[a:z] - lo]

    def _diagonal(self) -> np.ndarray:
        """The (n_blocks, 3, 3) values of ``-L`` once every edge's blocks are written: minus the
        sum of the blocks at each node in its diagonal block, from the sums of the rows' blocks
        (one sequential pass over the values; the diagonal comes first in each row, zeroed) and
        the blocks of the edges at the anchor. (Nine bincounts of the blocks by either end had
        cost 0.2 s each at 10^7 edges in single precision, 3.6 s a solve.)"""
        flat = self._data.reshape(-1, 9)
        flat[self.diag] = 0.0
        sums = np.add.reduceat(flat[:-1], self.indptr[:-1], axis=0)
        if len(self._anchor_rows):
            np.add.at(sums, self._anchor_rows, self._anchor_blocks)
        np.negative(sums, out=sums)
        flat[self.diag] = sums
        return self._data[:-1]

    def matrix(self, U: np.ndarray | None = None):
        """``(N, D)``: ``N = -L`` as a BSR matrix of 3x3 blocks (sparse solvers; its values in
        a buffer the next call overwrites) of the blocks given to :meth:`write_blocks` since the
        last call, or of ``U`` (3, 3, E); ``D`` (n - 1, 3, 3) the diagonal blocks of ``L``."""
        import scipy.sparse as sp

        if U is not None:
            self.write_blocks(slice(0, self.n_edges), U)
        blocks = self._diagonal()
        return sp.bsr_matrix((blocks, self.indices, self.indptr), shape=(self.m, self.m)), -blocks[self.diag]

    def solve(self, U: np.ndarray | None, rhs: np.ndarray, rtol: float | None = None) -> np.ndarray:
        """Solve for ``x`` (n, 3), zero at the anchor; ``U`` the edges' blocks as rows
        (3, 3, E) (``U[a, b, e]``, as :meth:`~.residuals.EdgeSystem.gauss_newton_blocks`
        gives them), or None: the blocks given to :meth:`write_blocks` since the last solve
        (sparse solvers); ``rhs`` (3, n); ``rtol`` as :meth:`AnchoredLaplacian.solve`."""
        if U is None and not self.writes_blocks:
            raise ValueError("the dense block Laplacian takes the blocks in solve(), not write_blocks()")
        if U is not None and U.shape != (3, 3, self.n_edges):
            raise ValueError(f"expected the edges' blocks as rows (3, 3, {self.n_edges}), got {U.shape}")
        self.n_solves += 1
        n, m = self.n, self.m
        b = np.ascontiguousarray(rhs.T[self.keep]).ravel()
        out = np.zeros((n, 3))
        if m == 0:
            return out
        if self.solver == "dense":
            x = cholesky_solve(cholesky_factor((self.assemble @ U.ravel()).reshape(m, m)), b)
        else:
            import scipy.sparse as sp

            N, D = self.matrix(U)
            if self.solver == "direct":
                import scipy.sparse.linalg as spla

                Nc = N.tocsc()
                Nc.sum_duplicates()  # parallel edges: repeated blocks
                x = -spla.splu(Nc, permc_spec="MMD_AT_PLUS_A").solve(b)
            else:
                L = _Negated(N)
                b = b.astype(N.dtype, copy=False)
                x = block_pcg(L, b[:, None], rtol=self.rtol if rtol is None else rtol, precondition=block_jacobi(D))[0][:, 0]
                x = x.astype(np.float64, copy=False)
        out[self.keep] = x.reshape(-1, 3)
        return out


def block_jacobi(D: np.ndarray):
    """The preconditioner of conjugate gradients on a block Laplacian (:func:`block_pcg`'s
    ``precondition``): the inverses of its 3x3 diagonal blocks ``D`` (k, 3, 3), applied to the
    node-major unknowns (3k, columns)."""
    Dinv = np.linalg.inv(D)

    def precondition(R: np.ndarray) -> np.ndarray:
        return np.einsum("kab,kb->ka", Dinv, R.reshape(-1, 3)).reshape(R.shape)

    return precondition


class _Negated:
    """``-N`` for a sparse matrix ``N``, as far as :func:`block_pcg` uses it (``@``)."""

    def __init__(self, N):
        self.N = N

    def __matmul__(self, P: np.ndarray) -> np.ndarray:
        out = self.N @ P
        return np.negative(out, out=out)


def make_laplacian(n: int, edges: np.ndarray, anchor: int, solver: str = "auto", blocks: bool = False, like=None):
    """The anchored Laplacian of the IRLS solves: scalar edge weights, or 3x3 blocks (per-edge
    information matrices, ``blocks=True``). ``like``: a Laplacian of the same edges and
    anchor whose sparsity pattern to share (the pattern is the costly part to build)."""
    pattern = getattr(like, "pattern", None)
    cls = AnchoredBlockLaplacian if blocks else AnchoredLaplacian
    return cls(n, edges, anchor, solver, pattern)


def block_pcg(L, B: np.ndarray, x0=None, rtol: float = 1e-8, maxiter: int = 1000, precondition=None) -> tuple[np.ndarray, int]:
    """Preconditioned CG on each column of ``B`` at once (one sparse matmul a step);
    ``precondition(R) -> Z`` (default: Jacobi, the inverse diagonal).

    Returns the solution and the number of iterations."""
    if precondition is None:
        d = L.diagonal()
        dinv = np.where(d > 0, 1.0 / np.where(d > 0, d, 1.0), 0.0)[:, None]

        def precondition(R: np.ndarray) -> np.ndarray:
            return dinv * R

    X = np.zeros_like(B) if x0 is None or x0.shape != B.shape else x0.copy()
    R = B - L @ X
    Z = precondition(R)
    P = Z.copy()
    rz = (R * Z).sum(axis=0)
    bnorm = np.maximum(np.linalg.norm(B, axis=0), 1e-300)
    it = 0
    for it in range(maxiter):
        if (np.linalg.norm(R, axis=0) <= rtol * bnorm).all():
            break
        LP = L @ P
        pLp = (P * LP).sum(axis=0)
        alpha = np.where(pLp > 0, rz / np.where(pLp > 0, pLp, 1.0), 0.0)
        X += alpha * P
        R -= alpha * LP
        Z = precondition(R)
        rz_new = (R * Z).sum(axis=0)
        beta = np.where(rz > 0, rz_new / np.where(rz > 0, rz, 1.0), 0.0)
        P = Z + beta * P
        rz = rz_new
    return X, it


_BLAS: tuple | None = None  # (threadpoolctl controller, len(sys.modules) when it was made)


def one_blas_thread(fn):
    """Decorator of the public solvers: ``fn`` runs with BLAS on one thread
    (:func:`single_threaded_blas`). Their BLAS calls are small (the noise-model fits' dots,
    matrix-vector products, dense solves of at most a few thousand unknowns): a second
    thread only adds hand-offs, which on a loaded machine cost up to milliseconds each
    (measured: the rig solve of 3000 images in 500 frames 221 -> 74 ms CPU, load 2.5 on 2
    cores; the EM fits of its noise model had been 80 % of it). The limit is process-wide
    while the call lasts (a callback runs under it too) and is only set from the main
    thread: threadpoolctl changes OpenBLAS's thread count from one controlling thread only,
    and overlapping calls from several threads would restore each other's settings. A
    program that runs solvers in threads limits BLAS itself (as Dask workers do)."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        if threading.current_thread() is not threading.main_thread():
            return fn(*args, **kwargs)
        with single_threaded_blas():
            return fn(*args, **kwargs)

    return wrapper


def single_threaded_blas():
    """Context limiting BLAS to one thread (threadpoolctl), process-wide while it lasts.

    The controller lists the libraries loaded when it is made, so it is made again when
    modules were imported since (a library loaded later, e.g. by a new extension module,
    would otherwise keep its threads): scipy.linalg, whose OpenBLAS is not numpy's, is
    imported first (measured: a 100-frame rig solve 230 ms with scipy's LAPACK left
    threaded, 21 ms without)."""
    global _BLAS
    if _BLAS is None or _BLAS[1] != len(sys.modules):
        import scipy.linalg  # noqa: F401
        from threadpoolctl import ThreadpoolController

        _BLAS = (ThreadpoolController(), len(sys.modules))
    return _BLAS[0].limit(limits=1, user_api="blas")
