"""The rotation group in the solvers' row layout: batches kept component-major.

Quaternion rows are ``(4, K)`` (each component one contiguous array), matrix rows ``(3, 3, K)``
(entry ``[a, b, k]`` of matrix ``k``), flat matrix rows ``(9, K)`` (``F[3 i + j] = R[:, i, j]``):
the layout of the multiple-averaging hot loops, which makes elementwise work over 10^6 edges
several times faster. These functions take and give batches only; :mod:`rotgraph.so3` holds the
item-or-batch API (and re-exports every public name here), with the conventions stated once.
"""

from __future__ import annotations

import numpy as np

def quaternion_rows_from_flat(F: np.ndarray) -> np.ndarray:
    """Shepperd's method on matrices given as rows ``F[3 i + j] = R[:, i, j]``; returns (4, N)."""
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = F
    tr = r00 + r11 + r22
    with np.errstate(invalid="ignore", divide="ignore"):
        w4 = 2.0 * np.sqrt(np.maximum(1.0 + tr, 0.0))  # = 4 w
        q = np.stack([0.25 * w4, (r21 - r12) / w4, (r02 - r20) / w4, (r10 - r01) / w4])
    hard = np.flatnonzero(tr <= -0.5)
    if len(hard):
        a = F[:, hard]
        diag = a[[0, 4, 8]]
        k = np.argmax(diag, axis=0)  # largest of x^2, y^2, z^2 (w^2 < 1/8 here)
        t = tr[hard]
        # Columns: 4 q_k q for pivot k = x, y, z (unnormalised; normalised below).
        d21, d02, d10 = a[7] - a[5], a[2] - a[6], a[3] - a[1]
        s01, s02, s12 = a[1] + a[3], a[2] + a[6], a[5] + a[7]
        piv = 1.0 + 2.0 * diag[k, np.arange(len(k))] - t
        q[:, hard] = np.where(
            k == 0,
            np.stack([d21, piv, s01, s02]),
            np.where(k == 1, np.stack([d02, s01, piv, s12]), np.stack([d10, s02, s12, piv])),
        )
    q *= np.where(q[0] < 0, -1.0, 1.0) / np.sqrt(np.einsum("ij,ij->j", q, q))
    return q


def flat_matrix_rows(q: np.ndarray) -> np.ndarray:
    """Rotation matrices of quaternion rows ``q`` (4, N) as rows (9, N); normalises ``q``."""
    w, x, y, z = q
    k = 2.0 / (w * w + x * x + y * y + z * z)
    xx, yy, zz = k * x * x, k * y * y, k * z * z
    xy, xz, yz = k * x * y, k * x * z, k * y * z
    wx, wy, wz = k * w * x, k * w * y, k * w * z
    return np.stack(
        [1 - (yy + zz), xy - wz, xz + wy, xy + wz, 1 - (xx + zz), yz - wx, xz - wy, yz + wx, 1 - (xx + yy)]
    )


# Column blocks for the batch conversions: a block's temporaries stay in the CPU cache,
# which makes the elementwise work over 10^6 matrices 2-3x faster than whole-array passes
# (10^7 relative rotations: 11 s whole-array, mostly page faults of fresh temporaries).
CONVERT_BLOCK = 8192


def convert_items(fn, items: np.ndarray, width: int, rows_out: bool = False) -> np.ndarray:
    """``fn`` (rows (k, m) in, rows (width, m) out) applied to ``items`` (N, k) block by
    block: (N, width), or the rows (width, N) with ``rows_out``."""
    items = np.asarray(items, dtype=np.float64)
    n = len(items)
    if n <= CONVERT_BLOCK:
        out = fn(np.ascontiguousarray(items.T))
        return out if rows_out else np.ascontiguousarray(out.T)
    out = np.empty((width, n) if rows_out else (n, width))
    for lo in range(0, n, CONVERT_BLOCK):
        block = fn(np.ascontiguousarray(items[lo : lo + CONVERT_BLOCK].T))
        if rows_out:
            out[:, lo : lo + CONVERT_BLOCK] = block
        else:
            out[lo : lo + CONVERT_BLOCK] = block.T
    return out


def rotation_errors(R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Quaternions ``(4, N)`` (rows) of matrices ``(N, 3, 3)`` and each matrix's distance
    (max entry) to the rotation of its quaternion: 0 for a rotation, > 0 for anything else
    (a reflection, a scaled or sheared matrix). Non-finite matrices give ``inf``."""
    R = np.asarray(R, dtype=np.float64)
    R9 = R.reshape(-1, 9)
    n = len(R9)
    if n <= CONVERT_BLOCK:
        return _rotation_errors_block(np.ascontiguousarray(R9.T))
    q = np.empty((4, n))
    err = np.empty(n)
    for lo in range(0, n, CONVERT_BLOCK):
        hi = min(lo + CONVERT_BLOCK, n)
        q[:, lo:hi], err[lo:hi] = _rotation_errors_block(np.ascontiguousarray(R9[lo:hi].T))
    return q, err


def _rotation_errors_block(F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`rotation_errors` of matrices given as rows ``F`` (9, n)."""
    finite = np.isfinite(F).all(axis=0)
    all_finite = finite.all()
    if not all_finite:
        F = np.where(finite, F, 0.0)
    with np.errstate(all="ignore"):  # finite garbage (1e308, 1e-320 entries) may overflow: err NaN / inf
        q = quaternion_rows_from_flat(F)
        err = np.abs(flat_matrix_rows(q) - F).max(axis=0)
    err[np.isnan(err)] = np.inf
    if not all_finite:
        err[~finite] = np.inf
    return q, err


def right_jacobian_inverse_coefficient(theta: np.ndarray) -> np.ndarray:
    """``c(theta) = 1/theta^2 - cot(theta/2) / (2 theta)``, the coefficient of
    ``[phi]x^2`` in :func:`rotgraph.so3.right_jacobian_inverse` (series near 0; ``1/pi^2`` at pi)."""
    theta = np.asarray(theta, dtype=np.float64)
    small = theta < 1e-2
    t = np.where(small, 1.0, theta)
    return np.where(small, 1.0 / 12.0 + theta * theta / 720.0, 1.0 / (t * t) - 0.5 / (t * np.tan(0.5 * t)))



#: Edges per block of :func:`matmul_rows`: its (3, 3, 3, block) temporary stays in cache.
MATMUL_ROWS_BLOCK = 1 << 14


def matmul_rows(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Products ``A_e B_e`` of 3x3 matrices given as rows (3, 3, E): a broadcast sum over
    contiguous rows, 5-9x faster than ``np.matmul`` on (E, 3, 3) stacks (which loops over
    the tiny matrices one by one: measured 0.14 us a product at 760 and 7000 edges), in
    blocks of :data:`MATMUL_ROWS_BLOCK` edges (at 10^6 edges the whole (3, 3, 3, E)
    temporary made it 160 ms a product, 43 ms in blocks; the same numbers bit for bit)."""
    E = A.shape[-1]
    if E <= MATMUL_ROWS_BLOCK:
        return (A[:, :, None, :] * B[None, :, :, :]).sum(axis=1)
    out = np.empty((3, 3, E))
    for s in range(0, E, MATMUL_ROWS_BLOCK):
        b = slice(s, s + MATMUL_ROWS_BLOCK)
        out[:, :, b] = (A[:, :, None, b] * B[None, :, :, b]).sum(axis=1)
    return out


def congruence_rows(R: np.ndarray, H: np.ndarray) -> np.ndarray:
    """``R_e^T H_e R_e`` of 3x3 matrices given as rows (3, 3, E) (an information matrix
    carried into another frame)."""
    return matmul_rows(matmul_rows(R.transpose(1, 0, 2), H), R)


def right_jacobian_inverse_rows(r: np.ndarray) -> np.ndarray:
    """:func:`rotgraph.so3.right_jacobian_inverse` of rotation vectors given as rows (3, E),
    as rows (3, 3, E): ``I + [r]x / 2 + c [r]x^2`` with ``[r]x^2 = r r^T - |r|^2 I``."""
    c = right_jacobian_inverse_coefficient(np.sqrt((r * r).sum(axis=0)))
    cr = c * r
    J = cr[:, None, :] * r[None, :, :]
    diag = 1.0 - (cr * r).sum(axis=0)
    h = 0.5 * r
    x, y, z = h
    J[0, 0] += diag
    J[1, 1] += diag
    J[2, 2] += diag
    J[0, 1] -= z
    J[1, 0] += z
    J[0, 2] += y
    J[2, 0] -= y
    J[1, 2] -= x
    J[2, 1] += x
    return J


# --------------------------------------------------------------------------- distances




# --------------------------------------------------------------------------- row layout
# The multiple-averaging solvers keep quaternions as rows (4, K): each component is a
# contiguous array, which makes elementwise work over 10^6 edges several times faster.


def _hamilton_table() -> np.ndarray:
    """``T`` (4, 16) with ``a * b = T @ outer(a, b).ravel()`` for quaternions (w, x, y, z)."""
    basis = np.eye(4)
    return np.ascontiguousarray(np.stack([qmul_rows(basis[i], basis[j]) for i in range(4) for j in range(4)]).T)


# Up to this many columns, products of rows of the same shape are one broadcast outer
# product and one (4, 16) matrix product (4 numpy calls instead of 30: 2x faster per IRLS
# iteration on small graphs); above, the elementwise formula is as fast and needs no
# (16, K) temporaries.
OUTER_MAX = 4000


def qmul_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of quaternion rows ``(4, K)`` (or a single (4,) broadcast)."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    sa, sb = np.shape(a), np.shape(b)
    if sa == sb or len(sb) == 1:
        shape = sa
    elif len(sa) == 1:  # one quaternion (4,) against rows (4, K)
        shape = sb
    else:  # e.g. (4, 1) against (4, K)
        shape = np.broadcast_shapes(sa, sb)
    if len(shape) == 1:
        return np.array([
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ])
    if sa == sb and shape[1] <= OUTER_MAX:
        return QMUL_TABLE @ (a[:, None, :] * b[None]).reshape(16, -1)
    # Accumulate in place: 40 % faster than stacking fresh rows at 10^6 columns.
    out = np.empty(shape, dtype=np.result_type(a, b))
    w, x, y, z = out
    np.multiply(aw, bw, out=w); w -= ax * bx; w -= ay * by; w -= az * bz
    np.multiply(aw, bx, out=x); x += ax * bw; x += ay * bz; x -= az * by
    np.multiply(aw, by, out=y); y -= ax * bz; y += ay * bw; y += az * bx
    np.multiply(aw, bz, out=z); z += ax * by; z -= ay * bx; z += az * bw
    return out


QMUL_TABLE = _hamilton_table()
# Left/right multiplication matrices as one gather: L(q)[k, b] = sign * q[index] (from the
# Hamilton table: each entry of L and Q is +-one component of q).
LEFT_INDEX = np.abs(QMUL_TABLE.reshape(4, 4, 4)).argmax(axis=1).ravel()
LEFT_SIGN = QMUL_TABLE.reshape(4, 4, 4).sum(axis=1).ravel()
RIGHT_INDEX = np.abs(QMUL_TABLE.reshape(4, 4, 4)).argmax(axis=2).ravel()
RIGHT_SIGN = QMUL_TABLE.reshape(4, 4, 4).sum(axis=2).ravel()


def left_matrix_rows(q: np.ndarray) -> np.ndarray:
    """:func:`rotgraph.so3.quaternion_left_matrices` of quaternion rows ``(4, K)``, as ``(4, 4, K)``."""
    return (q[LEFT_INDEX] * LEFT_SIGN[:, None]).reshape(4, 4, -1)


def qconj_rows(q: np.ndarray) -> np.ndarray:
    out = -q
    out[0] = q[0]
    return out


def positive_w_rows(q: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """Quaternion rows ``(4, K)`` (or one ``(4,)``) with the columns of ``w < 0`` negated:
    the ``w >= 0`` representative, exactly (no normalisation, no tie-break at ``w == 0``;
    :func:`rotgraph.so3.canonical_quaternions` does both, on ``(..., 4)``). ``out=q`` flips in place and
    needs no second ``(4, K)`` array."""
    if out is None:
        out = np.array(q, dtype=np.float64)
    elif out is not q:
        out[...] = q
    return np.negative(out, out=out, where=out[0] < 0)


def qlog_rows(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation vectors ``(3, K)`` and angles ``(K,)`` of quaternion rows (short way round)."""
    c = np.abs(q[0])
    s = np.sqrt(q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    with np.errstate(divide="ignore", invalid="ignore"):
        theta = 2.0 * np.arctan(s / c)
        f = np.where(s > 0, theta / s, 2.0 / c) * np.where(q[0] < 0, -1.0, 1.0)
    return q[1:] * f, theta


def qexp_rows(v: np.ndarray) -> np.ndarray:
    """Quaternion rows ``(4, K)`` of rotation vectors ``(3, K)``."""
    theta = np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    k = 0.5 * np.sinc(theta / (2 * np.pi))
    return np.concatenate([np.cos(0.5 * theta)[None], v * k])


def quaternion_rows_from_matrices(R: np.ndarray) -> np.ndarray:
    """Unit quaternion rows ``(4, N)`` (``w >= 0``) of matrices ``(N, 3, 3)``."""
    return convert_items(quaternion_rows_from_flat, np.asarray(R, dtype=np.float64).reshape(-1, 9), 4, rows_out=True)


def matrices_from_quaternion_rows(q: np.ndarray) -> np.ndarray:
    """Matrices ``(N, 3, 3)`` of quaternion rows ``(4, N)``."""
    return convert_items(flat_matrix_rows, np.asarray(q, dtype=np.float64).T, 9).reshape(-1, 3, 3)


def matrix_rows(q: np.ndarray) -> np.ndarray:
    """Rotation matrices of unit quaternion rows ``q`` (4, N) as rows (3, 3, N): entry
    ``[a, b, k]`` of matrix k, the layout of :func:`matmul_rows`."""
    return flat_matrix_rows(q).reshape(3, 3, -1)
