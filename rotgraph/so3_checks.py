"""What counts as a rotation: the distance to SO(3), the projection onto it, and the one
check of rotation matrices and of quaternions that every reader and estimator uses.

Conventions as in :mod:`rotgraph.so3`, which re-exports every public name here.
"""

from __future__ import annotations

import logging

import numpy as np

from .errors import InputError
from .so3_rows import rotation_errors

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
