"""Step 3 of the rig calibration (:mod:`.rig_calibration`): the joint Gauss-Newton
refinement of frames and extrinsics in one sparse system (:func:`joint_refine`), with every
image pair at the weight the frame solve gave it.

An image's world-frame update is ``w_a = delta_f + R_a^T sigma_k`` for
``F_f <- F_f exp(delta_f)``, ``S_k <- exp(sigma_k) S_k``, so the image-level Gauss-Newton
rows ``w_a - w_b`` become rows over (frames, sensors): normal equations dense Cholesky up to
:data:`DENSE_MAX` unknowns, else block-Jacobi CG; factorised once while the steps shrink
fast (:data:`REFACTOR_RATIO`), stopped when the predicted distance to the fixed point is
below :data:`REFINE_TOL`.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .. import so3, so3_rows
from ..viewgraph import ViewGraph
from .residuals import EdgeSystem

__all__ = ["joint_refine", "DENSE_MAX", "NORMAL_RTOL", "REFACTOR_RATIO", "REFINE_ITERATIONS", "REFINE_TOL"]

REFINE_ITERATIONS = 20
REFINE_TOL = 1e-10  # radians: the Gauss-Newton step at which the joint refinement stops
#: Normal equations of the joint refinement up to this many unknowns are solved dense
#: (Cholesky); larger ones by block-Jacobi CG: a sparse LU fills in on random frame graphs
#: (3000 unknowns: 0.24 s a factorisation, measured). Measured (one BLAS thread, the whole
#: refinement): r4x100 (309 unknowns) 6.6 ms dense, 18.8 ms CG; about even at 1500 (r2x500:
#: 45 ms dense, 38 ms CG; r6x500: 65 ms dense, 84 ms CG).
DENSE_MAX = 1000
#: CG's relative residual in the joint refinement: each Gauss-Newton step to ~1e-10 of its
#: size, far below the linear convergence of the iteration itself (~1e-3 a step); the
#: extrinsics agree with a dense solve's to 1e-16 (r2x500).
NORMAL_RTOL = 1e-10


def _normal_solver(N, n: int):
    """``solve(g) = (N + damping)^-1 g`` for the normal matrix ``N`` (n x n: dense
    array up to :data:`DENSE_MAX` unknowns, else sparse), with 1e-12 relative damping:
    factorised (dense Cholesky) or preconditioned (block-Jacobi CG) once, for several
    right-hand sides."""
    from .laplacian import block_pcg, cholesky_factor, cholesky_solve

    damp = 1e-12 * max(float(N.diagonal().max()), 1.0)
    if n <= DENSE_MAX:
        N[np.diag_indices(n)] += damp
        factor = cholesky_factor(N)
        return lambda g: cholesky_solve(factor, g)
    N = (N + sp.identity(n, format="csr") * damp).tobsr(blocksize=(3, 3))
    N.sort_indices()
    rows = np.repeat(np.arange(n // 3), np.diff(N.indptr))
    on_diag = N.indices == rows  # every row has its diagonal block (damping)
    inv = np.linalg.inv(N.data[on_diag][np.argsort(rows[on_diag])])

    def precondition(R: np.ndarray) -> np.ndarray:
        return np.einsum("kab,kbc->kac", inv, R.reshape(-1, 3, R.shape[1])).reshape(R.shape)

    return lambda g: block_pcg(N, g[:, None], rtol=NORMAL_RTOL, maxiter=2000, precondition=precondition)[0][:, 0]


def _unknowns(group: np.ndarray, sensor: np.ndarray, free_img: np.ndarray, a: np.ndarray, b: np.ndarray, anchor: int,
              n_frames: int, n_sensors: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`joint_refine`'s unknowns: the frames touched by the edges ``a-b`` (not the
    anchor), then the free sensors touched. Returns ``(frames_used, fcol, sens_used, scol)``:
    ``fcol``/``scol`` each frame's/sensor's unknown (-1: none)."""
    frames_used = np.unique(np.concatenate([group[a], group[b]]))
    frames_used = frames_used[frames_used != anchor]
    fcol = np.full(n_frames, -1)
    fcol[frames_used] = np.arange(len(frames_used))
    sens_used = np.unique(sensor[np.concatenate([a, b])][free_img[np.concatenate([a, b])]])
    scol = np.full(n_sensors, -1)
    scol[sens_used] = len(frames_used) + np.arange(len(sens_used))
    return frames_used, fcol, sens_used, scol


def _scatter_indices(cols: list, E: int, n3: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(gidx, gpos, nidx, npos)``: where :func:`joint_refine`'s per-edge gradient terms and
    normal-matrix blocks go, for the edges' four unknowns ``cols`` (each (E,), -1: none) and
    ``n3`` scalar unknowns."""
    i3 = np.arange(3)
    # gradient: term (k, entry i) of edge e at the flat index (3 k + i) E + e of the (4, 3, E)
    # rows of terms, summed into entry 3 C_k + i
    used = [np.flatnonzero(c >= 0) for c in cols]
    gidx = np.concatenate([((3 * k + i3)[:, None] * E + used[k]).ravel() for k in range(4)])
    gpos = np.concatenate([(3 * cols[k][used[k]] + i3[:, None]).ravel() for k in range(4)])
    # normal matrix: block (k, l) entry (i, j) of edge e at the flat index ((4 k + l) 9 + 3 i + j) E
    # + e of the (4, 4, 3, 3, E) rows of blocks, summed into (3 C_k + i, 3 C_l + j)
    nidx, npos, ij = [], [], np.arange(9)
    for k in range(4):
        for l in range(4):
            both = np.flatnonzero((cols[k] >= 0) & (cols[l] >= 0))
            nidx.append((((4 * k + l) * 9 + ij)[:, None] * E + both).ravel())
            npos.append(((3 * cols[k][both] + ij[:, None] // 3) * n3 + 3 * cols[l][both] + ij[:, None] % 3).ravel())
    return gidx, gpos, np.concatenate(nidx), np.concatenate(npos)


#: The signs of the four unknowns' C_k in :func:`joint_refine` (frame of a, sensor of a, frame
#: of b, sensor of b).
_SIGN = np.array([1.0, 1.0, -1.0, -1.0])


def _normal_blocks(M: np.ndarray, Ra: np.ndarray, Rb: np.ndarray, E: int) -> np.ndarray:
    """The (4, 4, 3, 3, E) blocks ``C_k^T M C_l`` of :func:`joint_refine`'s normal matrix
    from the edges' Gauss-Newton blocks ``M`` and the end rotations ``Ra``, ``Rb`` (as rows)."""
    RaT, RbT = Ra.transpose(1, 0, 2), Rb.transpose(1, 0, 2)
    MRaT, MRbT = so3_rows.matmul_rows(M, RaT), so3_rows.matmul_rows(M, RbT)
    RaM, RbM = MRaT.transpose(1, 0, 2), MRbT.transpose(1, 0, 2)  # M symmetric
    RaMRbT = so3_rows.matmul_rows(Ra, MRbT)
    MC = [None, MRaT, None, MRbT]  # M C_l for the sensors' columns
    T = np.empty((4, 4, 3, 3, E))
    for k, left in enumerate((M, RaM, M, RbM)):  # C_k^T M up to sign
        for l in range(4):
            if l in (0, 2):
                T[k, l] = left
            elif k in (0, 2):
                T[k, l] = MC[l]
            elif k == l:
                T[k, l] = so3_rows.matmul_rows(Ra if k == 1 else Rb, MC[l])
            else:
                T[k, l] = RaMRbT if k == 1 else RaMRbT.transpose(1, 0, 2)
    T *= (_SIGN[:, None] * _SIGN[None, :])[:, :, None, None, None]
    return T


#: The joint refinement keeps its normal equations' factorisation while each Gauss-Newton
#: step is at most this fraction of the one before (its linear convergence: the Jacobian
#: hardly changes at steps of 1e-4 rad, so the old factorisation converges as fast as a new
#: one, to the same fixed point); a slower step gets a new factorisation.
REFACTOR_RATIO = 0.1


def joint_refine(graph: ViewGraph, group: np.ndarray, F: np.ndarray, S_image: np.ndarray, sensor: np.ndarray,
                 S: np.ndarray, free: np.ndarray, u: np.ndarray, anchor: int, information: np.ndarray | None = None,
                 iterations: int = REFINE_ITERATIONS, tol: float = REFINE_TOL) -> tuple[np.ndarray, np.ndarray, int]:
    """Gauss-Newton (exact Jacobians: its fixed point is the cost's minimum) on frames ``F``
    (G, 3, 3) and the ``free`` sensors' ``S`` (K, 3, 3) for the weighted cost
    ``sum u_e |log(R_b^T R_ab R_a)|^2`` (whitened by the world-frame information
    ``R_b^T H R_b`` when ``information`` is given) over every image edge with
    ``u_e > 0`` and both frames solved, ``R_a = S_a F_group(a)``; ``S_a`` the free sensor's
    current ``S`` or, for other images, ``S_image[a]``. Frame ``anchor`` fixed. Returns
    ``(F, S, iterations)``."""
    F, S = F.copy(), S.copy()
    a, b = graph.edges[:, 0], graph.edges[:, 1]
    solved_frame = np.isfinite(F).all(axis=(1, 2))
    keep = (u > 0) & solved_frame[group[a]] & solved_frame[group[b]]
    if not keep.any():
        return F, S, 0
    e = np.flatnonzero(keep)
    a, b, w = a[e], b[e], u[e]
    n = graph.n_nodes
    # The edges' Gauss-Newton blocks at the image rotations (EdgeSystem: the whitened residual
    # r = log(R_b^T R_ab R_a), world-frame information G = R_b^T H R_b, the identity without,
    # and the exact Jacobian J = J_r^-1(r) of both ends' world-frame updates), as rows. Its
    # anchor is unused here (only its right-hand side needs one).
    H = np.broadcast_to(np.eye(3), (len(e), 3, 3)) if information is None else information[e]
    system = EdgeSystem(n, np.stack([a, b], axis=1), graph.relative_quaternion_rows(e), 0, information=H)
    free_img = (sensor >= 0) & free[np.maximum(sensor, 0)]
    frames_used, fcol, sens_used, scol = _unknowns(group, sensor, free_img, a, b, anchor, len(F), len(S))
    m = len(frames_used) + len(sens_used)
    if m == 0:
        return F, S, 0
    # Each edge's residual moves by J C_k x_k for the update x_k of each of its (up to four)
    # unknowns: C = I (frame of a), R_a^T (sensor of a), -I (frame of b), -R_b^T (sensor of
    # b), the images' world-frame updates. With M = u J^T G J and z = u J^T G r (EdgeSystem's
    # block and twice its half gradient), the gradient is C_k^T z and the normal matrix has
    # the blocks C_k^T M C_l.
    cols = [fcol[group[a]], np.where(free_img[a], scol[np.maximum(sensor[a], 0)], -1),
            fcol[group[b]], np.where(free_img[b], scol[np.maximum(sensor[b], 0)], -1)]
    E, n3 = len(e), 3 * m
    gidx, gpos, nidx, npos = _scatter_indices(cols, E, n3)
    it, solve, last_step = 0, None, np.inf
    for it in range(1, iterations + 1):
        Simg = np.where(free_img[:, None, None], S[np.maximum(sensor, 0)], S_image)
        R = Simg @ F[group]  # the images' rotations
        M, y = system.gauss_newton_blocks(so3_rows.quaternion_rows_from_matrices(R), w)
        z = 2.0 * y
        R = np.moveaxis(R, 0, -1)  # as rows (3, 3, n)
        Ra, Rb = np.take(R, a, axis=2), np.take(R, b, axis=2)
        # gradient terms C_k^T z: z, R_a z, -z, -R_b z
        gt = np.stack([z, (Ra * z).sum(axis=1), -z, -(Rb * z).sum(axis=1)])
        g = np.bincount(gpos, weights=gt.ravel()[gidx], minlength=n3)
        if solve is None:
            vals = _normal_blocks(M, Ra, Rb, E).ravel()[nidx]
            if n3 <= DENSE_MAX:
                N = np.bincount(npos, weights=vals, minlength=n3 * n3).reshape(n3, n3)
            else:
                N = sp.csr_matrix((vals, (npos // n3, npos % n3)), shape=(n3, n3))
            solve = _normal_solver(N, n3)
        y = -solve(g).reshape(m, 3)
        step = float(np.abs(y).max())
        if step > REFACTOR_RATIO * last_step:  # slow: factorise at the next iterate
            solve = None
        # Linear convergence (rate step / last_step, ~1e-3 here): the iterate is within about
        # step^2 / last_step of the fixed point; stop when that is below tol.
        done = step < tol or (step < REFACTOR_RATIO * last_step < np.inf and step * step < tol * last_step)
        last_step = step
        df = y[: len(frames_used)]
        ds = y[len(frames_used):]
        F[frames_used] = F[frames_used] @ so3.exp(df)
        S[sens_used] = so3.exp(ds) @ S[sens_used]
        if done:
            break
    return F, S, it
