"""The rotation group SO(3): batched maps, conversions and distances.

Conventions (stated once for the whole package):

* a batch of rotations is a float64 array of shape ``(N, 3, 3)``;
* quaternions are scalar-first ``(w, x, y, z)`` and unit norm, shape ``(N, 4)``;
  ``q`` and ``-q`` are the same rotation; functions that return quaternions return
  the representative with ``w >= 0``;
* axis-angle (rotation) vectors have shape ``(N, 3)``: ``exp(hat(v))`` rotates by
  ``|v|`` radians about ``v / |v|``.

The solvers' hot loops keep batches component-major instead ("rows": each component one
contiguous array): quaternion rows ``(4, K)`` and matrix rows ``(3, 3, K)`` (entry ``[a, b, k]``
of matrix ``k``), with their own functions (``qmul_rows``, ``matrix_rows``, ``matmul_rows``, ...),
which take and give batches only.

Every other function accepts a single item (``(3, 3)``, ``(4,)``, ``(3,)``) as well as a
batch, and returns the same kind. All are vectorised: no Python loop over items.

Accuracy: ``log`` goes through Shepperd's quaternion extraction and ``atan2``, so it is
accurate to machine precision at every angle in ``[0, pi]``, including near 0 (no
``arccos`` of a trace) and near ``pi`` (the axis comes from the largest diagonal
entry, not from ``R - R^T``).
"""

from __future__ import annotations

import logging

import numpy as np

from .errors import InputError

__all__ = [
    "hat",
    "vee",
    "exp",
    "log",
    "matrices_from_quaternions",
    "quaternions_from_matrices",
    "quaternion_multiply",
    "quaternion_conjugate",
    "quaternion_log",
    "quaternion_exp",
    "canonical_quaternions",
    "project_to_so3",
    "angle_between",
    "angle",
    "chordal_distance",
    "quaternion_distance",
    "chordal_from_angle",
    "quaternion_distance_from_angle",
    "random_rotations",
    "perturb",
    "is_rotation",
    "check_rotations",
    "check_quaternions",
    "check_quaternion_rows",
    "quaternion_left_matrices",
    "quaternion_right_matrices",
    "right_jacobian_inverse",
    "ROTATION_TOL",
    "to_scipy",
    "from_scipy",
    "wxyz_from_xyzw",
    "xyzw_from_wxyz",
    "from_pycolmap",
]


def _batch(x: np.ndarray, item_ndim: int) -> tuple[np.ndarray, bool]:
    """Return ``x`` as a float64 batch and whether it was a single item."""
    x = np.asarray(x, dtype=np.float64)
    if x.ndim == item_ndim:
        return x[None], True
    return x, False


def _unbatch(x: np.ndarray, single: bool) -> np.ndarray:
    return x[0] if single else x


def hat(v: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrix ``[v]x`` of ``v`` (``(..., 3)`` -> ``(..., 3, 3)``)."""
    v = np.asarray(v, dtype=np.float64)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1] = -v[..., 2]
    out[..., 0, 2] = v[..., 1]
    out[..., 1, 0] = v[..., 2]
    out[..., 1, 2] = -v[..., 0]
    out[..., 2, 0] = -v[..., 1]
    out[..., 2, 1] = v[..., 0]
    return out


def vee(m: np.ndarray) -> np.ndarray:
    """Inverse of :func:`hat` on the skew part of ``m`` (``(..., 3, 3)`` -> ``(..., 3)``)."""
    m = np.asarray(m, dtype=np.float64)
    return 0.5 * np.stack(
        [m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]],
        axis=-1,
    )


# --------------------------------------------------------------------------- quaternions


_CONJ_SIGNS = np.array([1.0, -1.0, -1.0, -1.0])


def quaternion_conjugate(q: np.ndarray) -> np.ndarray:
    """``(w, -x, -y, -z)``: the inverse rotation."""
    q = np.asarray(q, dtype=np.float64)
    if q.shape == (4,):
        return q * _CONJ_SIGNS
    return np.moveaxis(qconj_rows(np.moveaxis(q, -1, 0)), 0, -1)


def _as_rows(*qs: np.ndarray) -> tuple[list[np.ndarray], tuple]:
    """Quaternions ``(..., 4)`` broadcast to one shape, as rows ``(4, K)``, and that shape."""
    qs = [np.asarray(q, dtype=np.float64) for q in qs]
    if all(q.shape == (4,) for q in qs):  # single quaternions (the iterations of single averaging)
        return [q.reshape(4, 1) for q in qs], ()
    qs = np.broadcast_arrays(*qs)
    shape = qs[0].shape[:-1]
    return [np.ascontiguousarray(q.reshape(-1, 4).T) for q in qs], shape


def _from_rows(rows: np.ndarray, shape: tuple) -> np.ndarray:
    if shape == ():  # one item
        return rows[:, 0].copy()
    return np.ascontiguousarray(rows.T).reshape(shape + (rows.shape[0],))


def quaternion_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a * b`` (the rotation ``R(a) @ R(b)``), broadcasting over batches."""
    (ra, rb), shape = _as_rows(a, b)
    return _from_rows(qmul_rows(ra, rb), shape)


def canonical_quaternions(q: np.ndarray) -> np.ndarray:
    """Normalise and flip to ``w >= 0`` (ties at ``w == 0`` broken on the first nonzero entry)."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    # Sign of the first nonzero component, so that q and -q map to one representative.
    first = np.argmax(np.abs(q) > 1e-15, axis=-1)
    sign = np.sign(np.take_along_axis(q, first[..., None], axis=-1))
    sign[sign == 0] = 1.0
    return q * sign


def matrices_from_quaternions(q: np.ndarray) -> np.ndarray:
    """Rotation matrices of unit quaternions ``(w, x, y, z)``: ``(..., 4)`` -> ``(..., 3, 3)``.

    The quaternion is normalised first, so any nonzero ``q`` is accepted.
    """
    q = np.asarray(q, dtype=np.float64)
    shape = q.shape[:-1]
    return _convert_items(_matrix_rows, q.reshape(-1, 4), 9).reshape(shape + (3, 3))


def quaternions_from_matrices(R: np.ndarray) -> np.ndarray:
    """Unit quaternions ``(w, x, y, z)`` with ``w >= 0`` of rotation matrices (Shepperd's method).

    Of the four algebraically equivalent formulas, each item uses one whose pivot
    (``1 + trace`` or ``1 + 2 R_kk - trace``) is large, which keeps the result accurate at
    every angle: the ``w`` pivot wherever ``trace > -1/2`` (angles below ~104 degrees, the
    cheap common case), the largest diagonal pivot elsewhere.
    """
    R = np.asarray(R, dtype=np.float64)
    shape = R.shape[:-2]
    return _convert_items(_quaternion_rows, R.reshape(-1, 9), 4).reshape(shape + (4,))


def _quaternion_rows(F: np.ndarray) -> np.ndarray:
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


def _matrix_rows(q: np.ndarray) -> np.ndarray:
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
_BLOCK = 8192


def _convert_items(fn, items: np.ndarray, width: int, rows_out: bool = False) -> np.ndarray:
    """``fn`` (rows (k, m) in, rows (width, m) out) applied to ``items`` (N, k) block by
    block: (N, width), or the rows (width, N) with ``rows_out``."""
    items = np.asarray(items, dtype=np.float64)
    n = len(items)
    if n <= _BLOCK:
        out = fn(np.ascontiguousarray(items.T))
        return out if rows_out else np.ascontiguousarray(out.T)
    out = np.empty((width, n) if rows_out else (n, width))
    for lo in range(0, n, _BLOCK):
        block = fn(np.ascontiguousarray(items[lo : lo + _BLOCK].T))
        if rows_out:
            out[:, lo : lo + _BLOCK] = block
        else:
            out[lo : lo + _BLOCK] = block.T
    return out


def rotation_errors(R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Quaternions ``(4, N)`` (rows) of matrices ``(N, 3, 3)`` and each matrix's distance
    (max entry) to the rotation of its quaternion: 0 for a rotation, > 0 for anything else
    (a reflection, a scaled or sheared matrix). Non-finite matrices give ``inf``."""
    R = np.asarray(R, dtype=np.float64)
    R9 = R.reshape(-1, 9)
    n = len(R9)
    if n <= _BLOCK:
        return _rotation_errors_block(np.ascontiguousarray(R9.T))
    q = np.empty((4, n))
    err = np.empty(n)
    for lo in range(0, n, _BLOCK):
        hi = min(lo + _BLOCK, n)
        q[:, lo:hi], err[lo:hi] = _rotation_errors_block(np.ascontiguousarray(R9[lo:hi].T))
    return q, err


def _rotation_errors_block(F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`rotation_errors` of matrices given as rows ``F`` (9, n)."""
    finite = np.isfinite(F).all(axis=0)
    all_finite = finite.all()
    if not all_finite:
        F = np.where(finite, F, 0.0)
    with np.errstate(all="ignore"):  # finite garbage (1e308, 1e-320 entries) may overflow: err NaN / inf
        q = _quaternion_rows(F)
        err = np.abs(_matrix_rows(q) - F).max(axis=0)
    err[np.isnan(err)] = np.inf
    if not all_finite:
        err[~finite] = np.inf
    return q, err


def quaternion_log(q: np.ndarray) -> np.ndarray:
    """Axis-angle vector of unit quaternions (``(..., 4)`` -> ``(..., 3)``), angle in ``[0, pi]``.

    ``q`` and ``-q`` give the same result (the short way round).
    """
    (rows,), shape = _as_rows(q)
    return _from_rows(qlog_rows(rows)[0], shape)


def quaternion_exp(v: np.ndarray) -> np.ndarray:
    """Unit quaternion of axis-angle vectors (``(..., 3)`` -> ``(..., 4)``)."""
    v = np.asarray(v, dtype=np.float64)
    shape = v.shape[:-1]
    return _from_rows(qexp_rows(np.ascontiguousarray(v.reshape(-1, 3).T)), shape)


# --------------------------------------------------------------------------- exp / log


def exp(v: np.ndarray) -> np.ndarray:
    """Rotation matrices ``exp(hat(v))`` of axis-angle vectors (``(..., 3)`` -> ``(..., 3, 3)``)."""
    return matrices_from_quaternions(quaternion_exp(v))


def log(R: np.ndarray) -> np.ndarray:
    """Axis-angle vectors of rotation matrices (``(..., 3, 3)`` -> ``(..., 3)``), angle in ``[0, pi]``."""
    return quaternion_log(quaternions_from_matrices(R))


def project_to_so3(M: np.ndarray) -> np.ndarray:
    """Nearest rotation in the Frobenius norm (``(..., 3, 3)``): ``U diag(1, 1, det(U V^T)) V^T``."""
    M = np.asarray(M, dtype=np.float64)
    U, _, Vt = np.linalg.svd(M)
    d = np.sign(np.linalg.det(U @ Vt))
    d = np.where(d == 0, 1.0, d)
    U = U.copy()
    U[..., :, 2] *= d[..., None]
    return U @ Vt


def is_rotation(R: np.ndarray, tol: float = 1e-6) -> np.ndarray:
    """Whether each ``(3, 3)`` block is within ``tol`` (max entry) of a rotation matrix."""
    R = np.asarray(R, dtype=np.float64)
    return (rotation_errors(R)[1] <= tol).reshape(R.shape[:-2])


#: A 3x3 matrix within this distance (max entry) of a rotation is accepted as one and
#: projected onto SO(3): files that print matrices with a few significant digits pass;
#: scaled, sheared or reflected matrices do not.
ROTATION_TOL = 1e-3
#: Quaternions with a norm below this are zero (no rotation at all).
QUATERNION_ZERO = 1e-9
#: Non-unit quaternions are accepted as scaled ones (normalised); beyond this deviation of
#: the norm from 1 they are worth a warning.
QUATERNION_UNIT_TOL = 1e-3


def _locate(k: int, path, lines, label) -> tuple[str, dict]:
    where = "" if label is None else f"{label(k)}: "
    return where, {"path": None if path is None else str(path), "line": None if lines is None else int(lines[k])}


def check_rotations(M, *, path=None, lines=None, label=None, quaternion_rows: bool = False, project: bool = True):
    """Validate a batch of rotation matrices ``(K, 3, 3)``: the one check of rotgraph.

    Each matrix must be finite and within :data:`ROTATION_TOL` of a rotation; the batch is
    returned projected onto SO(3) (unchanged when already exact). Otherwise an
    :class:`~rotgraph.errors.InputError` names the first bad matrix: by ``path`` and
    ``lines[k]`` (its file line) and/or ``label(k)`` (e.g. ``"RR(:,:,5)"``), and says
    whether it is not finite, a reflection or not orthonormal. With ``quaternion_rows``
    the result is ``(rotations, quaternion rows (4, K) with w >= 0)``; ``project=False``
    skips the projection (for callers that only need the quaternions).
    """
    R = np.asarray(M, dtype=np.float64)
    if R.ndim != 3 or R.shape[1:] != (3, 3):
        raise InputError(f"expected rotations of shape (K,3,3), got {R.shape}", None if path is None else str(path))
    q, err = rotation_errors(R)
    bad = ~(err <= ROTATION_TOL)
    if bad.any():
        k = int(np.argmax(bad))
        with np.errstate(all="ignore"):
            det = np.linalg.det(R[k])
        if not np.isfinite(R[k]).all():
            what = "not finite"
        elif np.isfinite(det) and det <= 0:
            what = "a reflection (det <= 0)"
        else:
            what = f"not orthonormal (max entry {err[k]:.3g} from the nearest rotation)"
        where, loc = _locate(k, path, lines, label)
        raise InputError(f"{where}not a rotation matrix: {what}", **loc)
    if project and len(R) and float(err.max()) > 1e-12:
        R = project_to_so3(R)
    return (R, q) if quaternion_rows else R


def check_quaternions(q, *, path=None, lines=None, label=None) -> np.ndarray:
    """Validate quaternions ``(K, 4)`` (w, x, y, z) and return them normalised: the one
    quaternion check of rotgraph (:func:`check_quaternion_rows` for rows ``(4, K)``).

    Non-finite or zero (norm < :data:`QUATERNION_ZERO`) quaternions are an
    :class:`~rotgraph.errors.InputError` located as in :func:`check_rotations` (a
    non-finite one first, wherever it is); non-unit ones are scaled quaternions,
    normalised, with one warning (their count) when some norm is off by more than
    :data:`QUATERNION_UNIT_TOL`.
    """
    q = np.asarray(q, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != 4:
        raise InputError(f"expected quaternions of shape (K,4), got {q.shape}", None if path is None else str(path))
    return _check_quaternion_blocks(q.T, path, lines, label, rows_out=False)


def check_quaternion_rows(q, *, path=None, lines=None, label=None) -> np.ndarray:
    """:func:`check_quaternions` of quaternion rows: ``q`` is ``(4, K)`` or four ``(K,)``
    columns (w, x, y, z; any numeric dtype); returns the normalised rows ``(4, K)``
    float64. Checked in blocks of :data:`QUATERNION_BLOCK`: besides the result, memory
    is one block (10^7 edges of a reader's columns), errors and warning as
    :func:`check_quaternions`."""
    if len(q) != 4 or any(np.ndim(c) != 1 or len(c) != len(q[0]) for c in q):
        raise InputError(f"expected quaternion rows of shape (4,K), got {np.shape(q)}", None if path is None else str(path))
    return _check_quaternion_blocks(q, path, lines, label, rows_out=True)


#: Quaternions per block of :func:`check_quaternion_rows`.
QUATERNION_BLOCK = 1 << 16


def _check_quaternion_blocks(cols, path, lines, label, rows_out: bool) -> np.ndarray:
    """The check of :func:`check_quaternions`: ``cols`` the four components (w, x, y, z),
    block by block; the result as rows (4, K) or items (K, 4)."""
    m = len(cols[0])
    out = np.empty((4, m) if rows_out else (m, 4))
    first_zero, n_off, first_off, worst = None, 0, None, 0.0
    for s in range(0, m, QUATERNION_BLOCK):
        qb = np.stack([c[s:s + QUATERNION_BLOCK] for c in cols], axis=1).astype(np.float64, copy=False)
        if not np.isfinite(qb).all():
            where, loc = _locate(s + int(np.argmax(~np.isfinite(qb).all(axis=1))), path, lines, label)
            raise InputError(f"{where}quaternion is not finite", **loc)
        big = np.abs(qb).max(axis=1)
        if big.size and not float(big.max()) < 1e150:  # |q|^2 would overflow: scale those first
            qb /= np.where(big > 1.0, big, 1.0)[:, None]
            unit = np.sqrt(np.einsum("ij,ij->i", qb, qb))  # the norm of the scaled quaternion
            with np.errstate(over="ignore"):
                norm = np.where(big > 1.0, big, 1.0) * unit  # inf for the largest: far from unit
        else:
            norm = unit = np.sqrt(np.einsum("ij,ij->i", qb, qb))
        zero = ~(norm >= QUATERNION_ZERO)
        if first_zero is not None or zero.any():  # reported after the whole pass: a non-finite one goes first
            first_zero = s + int(np.argmax(zero)) if first_zero is None else first_zero
            continue
        dev = np.abs(norm - 1.0)
        off = dev > QUATERNION_UNIT_TOL
        if off.any():
            n_off += int(off.sum())
            first_off = s + int(np.argmax(off)) if first_off is None else first_off
            worst = max(worst, float(dev.max()))
        qb /= unit[:, None]  # qb is the block's own copy (np.stack)
        if rows_out:
            out[:, s:s + QUATERNION_BLOCK] = qb.T
        else:
            out[s:s + QUATERNION_BLOCK] = qb
    if first_zero is not None:
        where, loc = _locate(first_zero, path, lines, label)
        raise InputError(f"{where}zero quaternion (all four components 0)", **loc)
    if n_off:
        at = "" if lines is None else f" (the first at line {int(lines[first_off])})"
        logging.getLogger("rotgraph").warning(
            "%s%d of %d quaternions are not unit length%s; | |q| - 1 | up to %.3g; normalised",
            "" if path is None else f"{path}: ", n_off, m, at, worst,
        )
    return out


def quaternion_left_matrices(q: np.ndarray) -> np.ndarray:
    """``L(q)`` with ``q * p = L(q) p``: ``(..., 4)`` -> ``(..., 4, 4)``."""
    q = np.asarray(q, dtype=np.float64)
    return (q[..., _LEFT_INDEX] * _LEFT_SIGN).reshape(q.shape[:-1] + (4, 4))


def quaternion_right_matrices(q: np.ndarray) -> np.ndarray:
    """``Q(q)`` with ``p * q = Q(q) p``: ``(..., 4)`` -> ``(..., 4, 4)``."""
    q = np.asarray(q, dtype=np.float64)
    return (q[..., _RIGHT_INDEX] * _RIGHT_SIGN).reshape(q.shape[:-1] + (4, 4))


def right_jacobian_inverse_coefficient(theta: np.ndarray) -> np.ndarray:
    """``c(theta) = 1/theta^2 - cot(theta/2) / (2 theta)``, the coefficient of
    ``[phi]x^2`` in :func:`right_jacobian_inverse` (series near 0; ``1/pi^2`` at pi)."""
    theta = np.asarray(theta, dtype=np.float64)
    small = theta < 1e-2
    t = np.where(small, 1.0, theta)
    return np.where(small, 1.0 / 12.0 + theta * theta / 720.0, 1.0 / (t * t) - 0.5 / (t * np.tan(0.5 * t)))


def right_jacobian_inverse(phi: np.ndarray) -> np.ndarray:
    """``J_r^{-1}(phi) = I + [phi]x / 2 + c(|phi|) [phi]x^2`` of rotation vectors
    ``(..., 3)`` -> ``(..., 3, 3)``: ``log(exp(phi) exp(d)) ~ phi + J_r^{-1}(phi) d``.
    Accurate at 0 (series) and up to pi (:func:`right_jacobian_inverse_rows`, the formula's
    one home)."""
    phi = np.asarray(phi, dtype=np.float64)
    J = right_jacobian_inverse_rows(phi.reshape(-1, 3).T)
    return np.moveaxis(J, -1, 0).reshape(phi.shape[:-1] + (3, 3))


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
    """:func:`right_jacobian_inverse` of rotation vectors given as rows (3, E),
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


def angle(R: np.ndarray) -> np.ndarray:
    """Rotation angle in ``[0, pi]`` radians of each matrix (accurate at 0 and pi)."""
    q = quaternions_from_matrices(R)
    return 2.0 * np.arctan2(np.linalg.norm(q[..., 1:], axis=-1), np.abs(q[..., 0]))


def angle_between(R: np.ndarray, S: np.ndarray) -> np.ndarray:
    """Geodesic (angle) distance ``|log(R S^T)|`` in radians, broadcasting over batches."""
    R = np.asarray(R, dtype=np.float64)
    S = np.asarray(S, dtype=np.float64)
    return angle(R @ np.swapaxes(S, -1, -2))


def chordal_distance(R: np.ndarray, S: np.ndarray) -> np.ndarray:
    """Chordal distance ``|R - S|_F`` (= ``2 sqrt(2) sin(theta / 2)``)."""
    R = np.asarray(R, dtype=np.float64)
    S = np.asarray(S, dtype=np.float64)
    return np.sqrt(((R - S) ** 2).sum(axis=(-1, -2)))


def quaternion_distance(q: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Quaternion distance ``min(|q - p|, |q + p|)`` (= ``2 sin(theta / 4)``)."""
    q = np.asarray(q, dtype=np.float64)
    p = np.asarray(p, dtype=np.float64)
    return np.minimum(np.linalg.norm(q - p, axis=-1), np.linalg.norm(q + p, axis=-1))


def chordal_from_angle(theta: np.ndarray) -> np.ndarray:
    """Chordal distance of rotations ``theta`` radians apart: ``2 sqrt(2) sin(theta / 2)``."""
    return 2.0 * np.sqrt(2.0) * np.sin(0.5 * np.asarray(theta, dtype=np.float64))


def quaternion_distance_from_angle(theta: np.ndarray) -> np.ndarray:
    """Quaternion distance of rotations ``theta`` radians apart: ``2 sin(theta / 4)``."""
    return 2.0 * np.sin(0.25 * np.asarray(theta, dtype=np.float64))


# --------------------------------------------------------------------------- random


def random_rotations(n: int | None = None, rng=None) -> np.ndarray:
    """Rotations drawn uniformly (Haar measure): ``(n, 3, 3)``, or ``(3, 3)`` when ``n`` is None."""
    rng = np.random.default_rng(rng)
    q = rng.standard_normal((1 if n is None else n, 4))
    R = matrices_from_quaternions(q)
    return R[0] if n is None else R


def perturb(R: np.ndarray, sigma: float, rng=None) -> np.ndarray:
    """``R exp(hat(e))`` with ``e ~ N(0, sigma^2 I_3)`` per item (``sigma`` in radians)."""
    rng = np.random.default_rng(rng)
    R = np.asarray(R, dtype=np.float64)
    e = sigma * rng.standard_normal(R.shape[:-2] + (3,))
    return R @ exp(e)


# --------------------------------------------------------------------------- boundaries


def wxyz_from_xyzw(q: np.ndarray) -> np.ndarray:
    """Scalar-last quaternions ``(..., 4)`` ``(x, y, z, w)`` (scipy, pycolmap, g2o files) in
    rotgraph's scalar-first order ``(w, x, y, z)``: a new array, the values as they are."""
    return np.asarray(q)[..., [3, 0, 1, 2]]


def xyzw_from_wxyz(q: np.ndarray) -> np.ndarray:
    """Scalar-first quaternions ``(..., 4)`` ``(w, x, y, z)`` in the scalar-last order
    ``(x, y, z, w)`` of scipy and pycolmap: a new array, the values as they are."""
    return np.asarray(q)[..., [1, 2, 3, 0]]


def to_scipy(R: np.ndarray):
    """A ``scipy.spatial.transform.Rotation`` holding the matrices ``R``."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(np.asarray(R, dtype=np.float64))


def from_scipy(rotation) -> np.ndarray:
    """Matrices ``(N, 3, 3)`` (or ``(3, 3)``) of a scipy ``Rotation``."""
    return np.asarray(rotation.as_matrix(), dtype=np.float64)


def from_pycolmap(rotation) -> np.ndarray:
    """Matrix ``(3, 3)`` of a ``pycolmap.Rotation3d``, or ``(N, 3, 3)`` of a sequence of them
    (anything with a ``matrix()`` method: pycolmap itself is not imported here; the other
    direction, which makes pycolmap objects, is :func:`rotgraph.io.colmap_project.to_pycolmap`)."""
    if hasattr(rotation, "matrix"):
        return np.asarray(rotation.matrix(), dtype=np.float64)
    return np.stack([np.asarray(r.matrix(), dtype=np.float64) for r in rotation])


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
_LEFT_INDEX = np.abs(QMUL_TABLE.reshape(4, 4, 4)).argmax(axis=1).ravel()
_LEFT_SIGN = QMUL_TABLE.reshape(4, 4, 4).sum(axis=1).ravel()
_RIGHT_INDEX = np.abs(QMUL_TABLE.reshape(4, 4, 4)).argmax(axis=2).ravel()
_RIGHT_SIGN = QMUL_TABLE.reshape(4, 4, 4).sum(axis=2).ravel()


def left_matrix_rows(q: np.ndarray) -> np.ndarray:
    """:func:`quaternion_left_matrices` of quaternion rows ``(4, K)``, as ``(4, 4, K)``."""
    return (q[_LEFT_INDEX] * _LEFT_SIGN[:, None]).reshape(4, 4, -1)


def qconj_rows(q: np.ndarray) -> np.ndarray:
    out = -q
    out[0] = q[0]
    return out


def positive_w_rows(q: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """Quaternion rows ``(4, K)`` (or one ``(4,)``) with the columns of ``w < 0`` negated:
    the ``w >= 0`` representative, exactly (no normalisation, no tie-break at ``w == 0``;
    :func:`canonical_quaternions` does both, on ``(..., 4)``). ``out=q`` flips in place and
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
    return _convert_items(_quaternion_rows, np.asarray(R, dtype=np.float64).reshape(-1, 9), 4, rows_out=True)


def matrices_from_quaternion_rows(q: np.ndarray) -> np.ndarray:
    """Matrices ``(N, 3, 3)`` of quaternion rows ``(4, N)``."""
    return _convert_items(_matrix_rows, np.asarray(q, dtype=np.float64).T, 9).reshape(-1, 3, 3)


def matrix_rows(q: np.ndarray) -> np.ndarray:
    """Rotation matrices of unit quaternion rows ``q`` (4, N) as rows (3, 3, N): entry
    ``[a, b, k]`` of matrix k, the layout of :func:`matmul_rows`."""
    return _matrix_rows(q).reshape(3, 3, -1)
