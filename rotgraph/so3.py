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
which take and give batches only: their home is :mod:`rotgraph.so3_rows`. What counts as a
rotation (``is_rotation``, ``project_to_so3``) and the one check of input rotations and
quaternions (``check_rotations``, ``check_quaternions``) are :mod:`rotgraph.so3_checks`. Both
modules' public names are names of this one too.

Every other function accepts a single item (``(3, 3)``, ``(4,)``, ``(3,)``) as well as a
batch, and returns the same kind. All are vectorised: no Python loop over items.

Accuracy: ``log`` goes through Shepperd's quaternion extraction and ``atan2``, so it is
accurate to machine precision at every angle in ``[0, pi]``, including near 0 (no
``arccos`` of a trace) and near ``pi`` (the axis comes from the largest diagonal
entry, not from ``R - R^T``).
"""

from __future__ import annotations

import numpy as np

# The row layout and the checks live in their own modules; every public name of theirs is
# also a name of so3 (``so3.qmul_rows``, ``so3.check_rotations``): the package's own modules
# import them from their homes.
from .so3_checks import (  # noqa: F401
    QUATERNION_BLOCK, QUATERNION_UNIT_TOL, QUATERNION_ZERO, ROTATION_TOL, check_quaternion_rows, check_quaternions,
    check_rotations, is_rotation, project_to_so3,
)
from .so3_rows import (  # noqa: F401
    CONVERT_BLOCK, LEFT_INDEX, LEFT_SIGN, MATMUL_ROWS_BLOCK, OUTER_MAX, QMUL_TABLE, RIGHT_INDEX, RIGHT_SIGN,
    congruence_rows, convert_items, flat_matrix_rows, left_matrix_rows, matmul_rows, matrices_from_quaternion_rows,
    matrix_rows, positive_w_rows, qconj_rows, qexp_rows, qlog_rows, qmul_rows, quaternion_rows_from_flat,
    quaternion_rows_from_matrices, right_jacobian_inverse_coefficient, right_jacobian_inverse_rows, rotation_errors,
)

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
    return convert_items(flat_matrix_rows, q.reshape(-1, 4), 9).reshape(shape + (3, 3))


def quaternions_from_matrices(R: np.ndarray) -> np.ndarray:
    """Unit quaternions ``(w, x, y, z)`` with ``w >= 0`` of rotation matrices (Shepperd's method).

    Of the four algebraically equivalent formulas, each item uses one whose pivot
    (``1 + trace`` or ``1 + 2 R_kk - trace``) is large, which keeps the result accurate at
    every angle: the ``w`` pivot wherever ``trace > -1/2`` (angles below ~104 degrees, the
    cheap common case), the largest diagonal pivot elsewhere.
    """
    R = np.asarray(R, dtype=np.float64)
    shape = R.shape[:-2]
    return convert_items(quaternion_rows_from_flat, R.reshape(-1, 9), 4).reshape(shape + (4,))


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



def quaternion_left_matrices(q: np.ndarray) -> np.ndarray:
    """``L(q)`` with ``q * p = L(q) p``: ``(..., 4)`` -> ``(..., 4, 4)``."""
    q = np.asarray(q, dtype=np.float64)
    return (q[..., LEFT_INDEX] * LEFT_SIGN).reshape(q.shape[:-1] + (4, 4))


def quaternion_right_matrices(q: np.ndarray) -> np.ndarray:
    """``Q(q)`` with ``p * q = Q(q) p``: ``(..., 4)`` -> ``(..., 4, 4)``."""
    q = np.asarray(q, dtype=np.float64)
    return (q[..., RIGHT_INDEX] * RIGHT_SIGN).reshape(q.shape[:-1] + (4, 4))



def right_jacobian_inverse(phi: np.ndarray) -> np.ndarray:
    """``J_r^{-1}(phi) = I + [phi]x / 2 + c(|phi|) [phi]x^2`` of rotation vectors
    ``(..., 3)`` -> ``(..., 3, 3)``: ``log(exp(phi) exp(d)) ~ phi + J_r^{-1}(phi) d``.
    Accurate at 0 (series) and up to pi (:func:`right_jacobian_inverse_rows`, the formula's
    one home)."""
    phi = np.asarray(phi, dtype=np.float64)
    J = right_jacobian_inverse_rows(phi.reshape(-1, 3).T)
    return np.moveaxis(J, -1, 0).reshape(phi.shape[:-1] + (3, 3))


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
