"""The geometry of gravity priors (issue #17, item 3): COLMAP's conventions, gravity-aligned
rotations, the swing-twist split about gravity, tilt residuals.

A gravity direction ``g_i`` is a unit vector in camera ``i``'s frame, the direction "down"
as the camera sees it; the world's down is ``d`` (:data:`~rotgraph.priors.GRAVITY_WORLD`,
``(0, 1, 0)``), and a perfect prior is ``g_i = R_i d`` (``R_i`` cam_from_world). ``A_i``
with ``A_i e_y = g_i`` (COLMAP's ``GravityAlignedRotation``) and ``C`` with ``C e_y = d``
write every rotation that respects its gravity as ``R_i = A_i Y(theta_i) C^T`` (``Y``: a
rotation about ``e_y``, the image's yaw).
"""

from __future__ import annotations

import numpy as np

from .. import so3, so3_rows
from ..priors import GRAVITY_WORLD

__all__ = ["GRAVITY_WORLD", "unit_rows", "gravity_aligned_rotations", "gravity_of", "perturb_gravity", "yaw_quaternion_rows",
           "yaw_rotations", "yaw_angle", "yaw_of", "wrap_angle", "swing_twist", "tilt_residuals", "gravity_frame"]

#: The yaw axis of the gravity-aligned frames.
E_Y = np.array([0.0, 1.0, 0.0])


def unit_rows(v: np.ndarray) -> np.ndarray:
    """The rows of ``v`` (..., 3) normalised."""
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def gravity_aligned_rotations(gravity: np.ndarray) -> np.ndarray:
    """Rotations ``A`` (n, 3, 3) with ``A e_y = g`` (second column the unit gravity ``g``), as
    COLMAP's ``GravityAlignedRotation`` (which completes the basis by a Householder QR; the
    yaw about ``g`` chosen here differs, which changes no solution: it is absorbed by the
    yaw unknowns)."""
    g = unit_rows(np.atleast_2d(np.asarray(gravity, dtype=np.float64)))
    helper = np.zeros_like(g)
    use_z = np.abs(g[:, 0]) > 0.9
    helper[~use_z, 0] = 1.0
    helper[use_z, 2] = 1.0
    x = unit_rows(helper - (helper * g).sum(axis=1, keepdims=True) * g)
    z = np.cross(x, g)
    return np.stack([x, g, z], axis=2)


def gravity_of(cam_from_world: np.ndarray, gravity_world=GRAVITY_WORLD) -> np.ndarray:
    """The exact gravity directions ``R_i d`` (n, 3) of rotations ``R_i`` (cam_from_world)."""
    return np.asarray(cam_from_world, dtype=np.float64) @ unit_rows(np.asarray(gravity_world, dtype=np.float64))


def perturb_gravity(gravity: np.ndarray, sigma_deg, rng=None) -> np.ndarray:
    """Noisy gravity directions under the tilt model of :mod:`.gravity`: each ``g`` turned
    about an axis perpendicular to it by a 2-D Gaussian vector, ``sigma_deg`` per axis
    (scalar or (n,))."""
    rng = np.random.default_rng(rng)
    g = unit_rows(np.asarray(gravity, dtype=np.float64))
    A = gravity_aligned_rotations(g)
    z = rng.standard_normal((len(g), 2)) * np.deg2rad(np.broadcast_to(np.asarray(sigma_deg, float), (len(g),)))[:, None]
    v = A[:, :, 0] * z[:, :1] + A[:, :, 2] * z[:, 1:]  # perpendicular to g
    return unit_rows(np.einsum("nab,nb->na", so3.exp(v), g))


def yaw_quaternion_rows(phi: np.ndarray) -> np.ndarray:
    """Quaternion rows (4, K) of rotations by ``phi`` about ``e_y``."""
    z = np.zeros_like(phi)
    return np.stack([np.cos(0.5 * phi), z, np.sin(0.5 * phi), z])


def yaw_rotations(A: np.ndarray, theta: np.ndarray, C: np.ndarray) -> np.ndarray:
    """``A_i Y(theta_i) C^T`` (K, 3, 3): the rotations of yaws ``theta`` (K,) that respect the
    gravities of their aligned frames ``A`` (K, 3, 3)."""
    return A @ so3.exp(theta[:, None] * E_Y) @ C.T


def yaw_angle(q: np.ndarray) -> np.ndarray:
    """The twist angles (K,) about ``e_y`` of quaternion rows ``q`` (4, K), wrapped."""
    return wrap_angle(2.0 * np.arctan2(q[2], q[0]))


def yaw_of(A: np.ndarray, R: np.ndarray, C: np.ndarray) -> np.ndarray:
    """The yaws (K,) of rotations ``R`` in their aligned frames ``A``: the twist of
    ``A^T R C`` about ``e_y`` (``R`` projected onto its gravity keeps it)."""
    return yaw_angle(so3_rows.quaternion_rows_from_matrices(np.swapaxes(A, 1, 2) @ R @ C))


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Angles wrapped to ``[-pi, pi)``."""
    return (a + np.pi) % (2.0 * np.pi) - np.pi


def swing_twist(q: np.ndarray, axis: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Swing-twist decomposition of quaternion rows ``q`` (4, K) about the unit ``axis``:
    ``(twist angle in (-pi, pi], swing angle in [0, pi], total angle)``."""
    p = axis @ q[1:]  # the vector part along the axis
    twist = wrap_angle(2.0 * np.arctan2(p, q[0]))
    wp = np.sqrt(q[0] ** 2 + p**2)
    swing = 2.0 * np.arctan2(np.sqrt(np.maximum(1.0 - wp * wp, 0.0)), wp)
    v = np.sqrt((q[1:] ** 2).sum(axis=0))
    total = 2.0 * np.arctan2(v, np.abs(q[0]))
    return twist, swing, total


def tilt_residuals(R: np.ndarray, g: np.ndarray, d: np.ndarray) -> np.ndarray:
    """``t_i`` (n, 3): the rotation vector (perpendicular to ``d``) taking ``d`` to ``R_i^T g_i``."""
    h = np.einsum("nba,nb->na", R, g)  # R^T g
    c = np.cross(d, h)
    s = np.linalg.norm(c, axis=1)
    ang = np.arctan2(s, h @ d)
    with np.errstate(invalid="ignore", divide="ignore"):
        f = np.where(s > 1e-15, ang / np.where(s > 1e-15, s, 1.0), 1.0)
    return c * f[:, None]


def gravity_frame(R: np.ndarray, g: np.ndarray, d: np.ndarray) -> np.ndarray:
    """A rotation ``W`` with ``R_i W d ~ g_i`` on average: ``W^T`` takes ``R_i^T g_i`` to ``d``
    (the rotation of least angle taking their normalised mean to ``d``)."""
    h = np.einsum("nba,nb->na", R, g).mean(axis=0)
    h /= np.linalg.norm(h)
    c = np.cross(h, d)
    s = np.linalg.norm(c)
    ang = np.arctan2(s, h @ d)
    if s < 1e-15:
        Wt = np.eye(3) if ang < 1 else so3.exp(np.pi * gravity_aligned_rotations(d[None])[0][:, 0])
    else:
        Wt = so3.exp(c / s * ang)
    return Wt.T
