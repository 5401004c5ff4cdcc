"""Linear multiple rotation averaging: chordal (Martinec & Pajdla 2007) and quaternion
(Govindu 2001) least squares on the sparse block system, one node anchored."""

from __future__ import annotations

import numpy as np

from .. import so3, so3_checks, so3_rows
from ..graph_analysis import connected_components
from .laplacian import block_pcg, direct_is_cheap, rcm_widths

__all__ = ["chordal_start", "solve_chordal", "solve_quaternion"]


def _block_system(n: int, edges: np.ndarray, blocks: np.ndarray, weights: np.ndarray, k: int, solver: str = "auto"):
    """Normal matrix of ``sum w |x_j - B_e x_i|^2`` over k-vectors x: blocks (E, k, k); a
    dense array for small systems (and, unless ``solver`` asks for CG, for wide graphs of up
    to :data:`DENSE_LINEAR_MAX` unknowns), else sparse."""
    i, j = edges[:, 0], edges[:, 1]
    a, b = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
    a, b = a.ravel(), b.ravel()
    # Off-diagonal blocks: M_ji = -w B, M_ij = -w B^T.
    rows_ji = (k * j[:, None] + a[None]).ravel()
    cols_ji = (k * i[:, None] + b[None]).ravel()
    vals = (-weights[:, None, None] * blocks).reshape(len(edges), -1).ravel()
    deg = np.bincount(i, weights=weights, minlength=n) + np.bincount(j, weights=weights, minlength=n)
    diag = np.repeat(deg, k)
    rows = np.concatenate([rows_ji, cols_ji, np.arange(k * n)])
    cols = np.concatenate([cols_ji, rows_ji, np.arange(k * n)])
    data = np.concatenate([vals, vals, diag])
    # Small systems: dense, solved by numpy (:func:`_anchored_solve`; BLAS on one thread, as
    # in every public solver: the same bits in a batch worker as in `rotgraph solve`); a
    # sparse matrix, its slicing and the envelope test cost more than the dense solve there
    # (2 ms at 120 unknowns); so do they on a wide graph, whose sparse LU fills in.
    N = k * n
    if N <= DENSE_DIRECT_MAX or (solver in ("auto", "direct") and N <= DENSE_LINEAR_MAX and _wide(n, edges)):
        return np.bincount(rows * N + cols, weights=data, minlength=N * N).reshape(N, N)
    import scipy.sparse as sp

    return sp.coo_matrix((data, (rows, cols)), shape=(N, N)).tocsr()


#: Up to this many unknowns a linear system is built and solved dense whatever the graph:
#: at most ~1 ms (measured: 0.27 ms at 150 unknowns, 0.96 ms at 297).
DENSE_DIRECT_MAX = 300
#: Up to this many unknowns, a linear start on a *wide* graph (its envelope in reverse
#: Cuthill-McKee order a good part of the dense matrix: random SfM graphs, a rig's frames)
#: is solved densely: measured on random sparse systems of 150 / 297 / 600 unknowns, sparse
#: LU 1.1 / 4.4 / 19.8 ms, dense 0.27 / 0.96 / 5.5 ms (one BLAS thread); a rig's round-0
#: image graph of 240 cameras (720 unknowns, degree 36): LU 36 ms, block CG 11.5 ms, dense
#: 6.7 ms (900 unknowns: 12 ms). Thin graphs (trajectories, pose graphs: narrow envelopes)
#: keep the sparse LU.
DENSE_LINEAR_MAX = 900


def _wide(n: int, edges: np.ndarray) -> bool:
    """Whether the graph's mean RCM envelope width is at least a quarter of its size."""
    return float(rcm_widths(n, edges[:, 0], edges[:, 1]).mean()) >= 0.25 * n


def _anchored_solve(M, k: int, anchor: int, x_anchor: np.ndarray, solver: str = "auto", edges=None) -> np.ndarray:
    """Minimise the quadratic form of ``M`` with the anchor's k-block fixed to x_anchor (k, c)
    (``edges``: the graph's, to tell whether a sparse LU would fill in)."""
    N = M.shape[0]
    free = np.ones(N, dtype=bool)
    free[k * anchor : k * anchor + k] = False
    Mff = M[free][:, free]
    rhs = -np.asarray(M[free][:, ~free] @ x_anchor)
    if isinstance(M, np.ndarray):  # dense: small graphs
        xf = np.linalg.solve(Mff, rhs)
    else:
        if solver == "auto":
            thin = M.nnz / N < 12 * k or N < 300 * k
            solver = "direct" if thin and (N < 300 * k or direct_is_cheap(N // k, edges, k)) else "cg"
        if solver == "direct":  # a thin graph (wide ones of up to DENSE_LINEAR_MAX unknowns came dense)
            import scipy.sparse.linalg as spla

            xf = spla.splu(Mff.tocsc(), permc_spec="MMD_AT_PLUS_A").solve(rhs)
        else:
            xf = block_pcg(Mff.tocsr(), rhs)[0]
    X = np.zeros((N, x_anchor.shape[1]))
    X[free] = xf
    X[~free] = x_anchor
    return X


def _rotation_entry(q: np.ndarray, a: int, b: int) -> np.ndarray:
    """Entry ``(a, b)`` (E,) of the rotation matrices of unit quaternion rows ``q`` (4, E)."""
    w, v = q[0], q[1:]
    if a == b:
        c, d = [k for k in range(3) if k != a]
        return 1.0 - 2.0 * (v[c] * v[c] + v[d] * v[d])
    c = 3 - a - b  # the third axis; (a, b, c) cyclic: +, else -
    sign = 1.0 if (b - a) % 3 == 1 else -1.0
    return 2.0 * (v[a] * v[b] - sign * w * v[c])


def _chordal_bsr(n: int, edges: np.ndarray, qrel: np.ndarray, weights: np.ndarray, anchor: int):
    """The anchored chordal normal matrix as a BSR matrix of 3x3 blocks and its right-hand
    side (3n, 3): built from the edges' quaternions entry by entry (no (E, 3, 3) array, no
    COO triplets, no sort of the entries but one argsort of the block rows). The
    anchor's block row and column hold the identity (its unknowns come out zero: ``R_anchor
    = I`` is set after); its edges' blocks go to the right-hand side. Parallel edges are
    repeated blocks of one row (a BSR matrix-vector product sums them)."""
    import scipy.sparse as sp

    i, j = edges[:, 0], edges[:, 1]
    deg = np.bincount(i, weights=weights, minlength=n) + np.bincount(j, weights=weights, minlength=n)
    at_i, at_j = i == anchor, j == anchor
    ke = np.flatnonzero(~(at_i | at_j))
    K = len(ke)
    itype = np.int32 if 2 * K + n < 2**31 else np.int64
    rows = np.concatenate([j[ke], i[ke]]).astype(itype)
    counts = np.bincount(rows, minlength=n) + 1  # + the diagonal block, first in its row
    indptr = np.zeros(n + 1, dtype=itype)
    np.cumsum(counts, out=indptr[1:])
    order = np.argsort(rows)  # any order within a row (a CSR product sums it): quicksort, 2-3x faster than stable
    pos = np.empty(2 * K, dtype=itype)
    pos[order] = np.arange(2 * K, dtype=itype) + rows[order] + 1
    del order
    indices = np.empty(indptr[-1], dtype=itype)
    indices[indptr[:-1]] = np.arange(n, dtype=itype)
    indices[pos[:K]] = i[ke]
    indices[pos[K:]] = j[ke]
    data = np.empty((len(indices), 3, 3))
    d = indptr[:-1]
    data[d] = 0.0
    for a in range(3):
        data[d, a, a] = deg
    # The edges' blocks, a cache-sized chunk of edges at a time: M_ji = -w B_e, M_ij = -w B_e^T.
    blk = np.empty((min(K, BSR_CHUNK), 3, 3))
    for c in range(0, K, BSR_CHUNK):
        kc = ke[c : c + BSR_CHUNK]
        qk, bk = qrel[:, kc], blk[: len(kc)]
        for a in range(3):
            for b in range(3):
                bk[:, a, b] = _rotation_entry(qk, a, b)
        bk *= -weights[kc][:, None, None]
        data[pos[c : c + len(kc)]] = bk
        data[pos[K + c : K + c + len(kc)]] = bk.transpose(0, 2, 1)
    # The edges of the anchor (x_anchor = I): rhs_j += w B_e, rhs_i += w B_e^T.
    B = np.zeros((n, 3, 3))
    e_i, e_j = np.flatnonzero(at_i & ~at_j), np.flatnonzero(at_j & ~at_i)
    for a in range(3):
        for b in range(3):
            np.add.at(B[:, a, b], j[e_i], weights[e_i] * _rotation_entry(qrel[:, e_i], a, b))
            np.add.at(B[:, b, a], i[e_j], weights[e_j] * _rotation_entry(qrel[:, e_j], a, b))
    data[indptr[anchor]] = np.eye(3)  # the anchor's diagonal block (first block of its row)
    B[anchor] = 0.0
    M = sp.bsr_matrix((data, indices, indptr), shape=(3 * n, 3 * n))
    return M, B.reshape(3 * n, 3)


#: :func:`_chordal_bsr` writes the edges' blocks this many edges at a time.
BSR_CHUNK = 1 << 14
#: PCG tolerance of the chordal start on the BSR path: it is only a start (projected onto
#: SO(3), then refined by IRLS). Measured (20k cameras / 10^6 edges): 14 PCG iterations at
#: 1e-8, 9 at 1e-5, the start's rotations within 0.0013 deg of the 1e-8 ones.
CHORDAL_RTOL = 1e-5

#: From this average degree (and 300 cameras), the chordal system is solved by conjugate
#: gradients on a BSR matrix built in place (:func:`_chordal_bsr`): where the generic
#: path's ``auto`` choice would take CG too (its thin-graph test: 1 + 3 degree nonzeros a row,
#: the diagonal blocks' diagonals and the neighbours' blocks, below 36), the BSR matrix costs
#: less to build and CG stops at CHORDAL_RTOL (measured: a rig's round-0 image graph, 400
#: cameras of degree 16: 8.3 -> 5.8 ms).
CHORDAL_BSR_MIN_DEGREE = 12.0


def solve_chordal(n: int, edges: np.ndarray, qrel: np.ndarray, weights: np.ndarray, anchor: int, solver: str = "auto") -> np.ndarray:
    """Linear chordal averaging (Martinec & Pajdla): ``min sum w |R_j - R_ij R_i|_F^2`` with
    ``R_anchor = I`` over unconstrained 3x3 blocks, then each block projected onto SO(3)."""
    if solver in ("auto", "cg") and n >= 300 and (solver == "cg" or 2.0 * len(edges) / n >= CHORDAL_BSR_MIN_DEGREE):
        M, B = _chordal_bsr(n, edges, qrel, weights, anchor)
        X = block_pcg(M, B, rtol=CHORDAL_RTOL)[0]
        del M
        X[3 * anchor : 3 * anchor + 3] = np.eye(3)
        return so3_rows.quaternion_rows_from_matrices(so3_checks.project_to_so3(X.reshape(n, 3, 3)))
    Rrel = so3_rows.matrices_from_quaternion_rows(qrel)
    M = _block_system(n, edges, Rrel, weights, 3, solver)
    X = _anchored_solve(M, 3, anchor, np.eye(3), solver, edges)
    R = so3_checks.project_to_so3(X.reshape(n, 3, 3))
    return so3_rows.quaternion_rows_from_matrices(R)


#: The chordal *start* of the adaptive solver keeps about this many edges per camera (a
#: random subset, below). Its value is to put IRLS in the inliers' basin: its error falls as
#: 1/sqrt(degree) while its cost (building and solving a 3n x 3n block system) grows with
#: the edges. Measured on the synthetic 10^7-edge problem (degree 100, sigma 2 deg, 10 %
#: outliers): the whole chordal start was a third of the solve.
START_DEGREE = 32
#: ... on graphs of at least this many edges: below, the whole start costs milliseconds and
#: drawing the subset (and testing it connected) would be most of it.
START_MIN_EDGES = 100_000


def start_edges(n: int, edges: np.ndarray, weights: np.ndarray, degree: float | None = None, seed: int = 0):
    """``(index, weights)`` of a random subset of the edges with about ``degree`` edges per
    camera, or ``None`` when the graph is not denser than that, has fewer than
    :data:`START_MIN_EDGES` edges, or the subset would not be connected. Edge ``(i, j)`` is
    kept with probability ``p = min(1, degree / min(d_i, d_j))`` (``d``: the cameras'
    degrees; so every edge of a camera of degree at most ``degree`` is kept) and weighted
    ``w / p``: the expected normal matrix is the whole graph's.
    ``degree``: :data:`START_DEGREE` by default."""
    degree = START_DEGREE if degree is None else degree
    E = len(edges)
    if E < START_MIN_EDGES or 2.0 * E <= degree * n * 1.5:
        return None
    d = np.bincount(edges.ravel(), minlength=n).astype(np.float64)
    p = np.minimum(1.0, degree / np.minimum(d[edges[:, 0]], d[edges[:, 1]]))
    keep = np.flatnonzero(np.random.default_rng(seed).random(E) < p)
    if connected_components(n, edges[keep])[0] > 1:
        return None
    return keep, weights[keep] / p[keep]


def chordal_start(n: int, edges: np.ndarray, qrel: np.ndarray, weights: np.ndarray, anchor: int, solver: str = "auto",
                  seed: int = 0) -> np.ndarray:
    """A start for iterative averaging: :func:`solve_chordal` on :func:`start_edges` of a
    dense graph (on all edges otherwise); quaternion rows (4, n)."""
    sub = start_edges(n, edges, weights, seed=seed)
    if sub is None:
        return solve_chordal(n, edges, qrel, weights, anchor, solver)
    keep, w = sub
    return solve_chordal(n, edges[keep], qrel[:, keep], w, anchor, solver)


def solve_quaternion(
    n: int, edges: np.ndarray, qrel: np.ndarray, weights: np.ndarray, anchor: int, q_ref: np.ndarray, solver: str = "auto"
) -> np.ndarray:
    """Linear quaternion averaging (Govindu 2001): ``min sum w |q_j - s_ij q_ij q_i|^2`` with
    ``q_anchor`` fixed, the signs ``s_ij`` chosen to agree with the estimate ``q_ref``."""
    pred = so3_rows.qmul_rows(qrel, q_ref[:, edges[:, 0]])
    s = np.where((pred * q_ref[:, edges[:, 1]]).sum(axis=0) < 0, -1.0, 1.0)
    Lq = so3.quaternion_left_matrices((qrel * s).T)  # q * p = L(q) p
    M = _block_system(n, edges, Lq, weights, 4, solver)
    X = _anchored_solve(M, 4, anchor, q_ref[:, anchor : anchor + 1], solver, edges)
    Q = X.reshape(n, 4).T
    Q /= np.sqrt((Q * Q).sum(axis=0))
    return so3_rows.positive_w_rows(Q)
