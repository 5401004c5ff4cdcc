"""Rotation information (inverse covariance) of two-view relative poses, from their inlier
correspondences: the Gauss-Newton Hessian of the epipolar error at the estimated pose,
with the translation marginalised out (Zhang, Larsson, Olsson et al., "Revisiting Rotation
Averaging: Uncertainties and Robust Losses", CVPR 2023).

All pairs at once, vectorised: per-correspondence residuals and Jacobians in numpy,
per-pair sums by segment; no Python loop over pairs or correspondences. Pure numpy: no
pycolmap, no files (:func:`rotgraph.pipeline.colmap.read_colmap_project` normalises the
keypoints with the cameras and calls :func:`rotation_information`).

Inputs
------
Correspondence ``m`` of pair ``p = seg[m]`` is ``x1[m]``, ``x2[m]``: *normalised* image
points ``(u, v)`` (the point ``(u, v, 1)`` on the plane ``z = 1`` of the camera: COLMAP's
``Camera.cam_from_img``). Pixel noise is isotropic Gaussian with standard deviation
``sigma`` pixels (:data:`PIXEL_SIGMA` by default) in both images, i.e. ``sigma * scale1[p]``
and ``sigma * scale2[p]`` in normalised units, ``scale`` = the pixel-to-normalised scale of
the camera (``1 / focal length``). The relative pose of pair ``p`` is ``R[p]`` =
``cam2_from_cam1`` and the translation direction ``t[p]`` (any length; its sign does not
matter), ``x2 ~ R x1 + t / depth``. The global scale of the noise is refitted by the solver
anyway: only the relative information between edges and axes matters there.

Parameters (rotgraph's perturbation convention, :mod:`rotgraph.viewgraph`)
--------------------------------------------------------------------------
``d`` (3): ``R -> exp([d]x) R`` (an error in camera 2's frame, as the view graph's
``information`` expects); ``dt`` (2): ``t -> normalise(t + B dt)``, ``B = (b1, b2)`` an
orthonormal basis of the tangent plane of the unit sphere at ``t`` (:func:`tangent_basis`).

Epipolar residual (one per correspondence): the Sampson error, whitened
----------------------------------------------------------------------------
With ``E = [t]x R``, ``y = R x1``, ``a = E x1 = t x y``, ``w = x2 x t``,
``b = E^T x2 = R^T w``, ``e = x2^T E x1 = x2 . a``::

    r = e / sqrt(D),   D = s2^2 (a_0^2 + a_1^2) + s1^2 (b_0^2 + b_1^2)

(``s1``, ``s2`` = the noise in normalised units of each image): the first-order
standard deviation of ``e`` under the pixel noise, so ``r ~ N(0, 1)``. Its exact Jacobian
(checked against finite differences in the tests), with ``g = (a_0, a_1, 0)``,
``h = (b_0, b_1, 0)``::

    de/dd  = y x w                     de/ddt = B^T (y x x2)
    dD/dd  = 2 s2^2 y x (g x t) + 2 s1^2 (R h) x w
    dD/ddt = 2 s2^2 B^T (y x g) + 2 s1^2 B^T ((R h) x x2)
    dr     = (de - r dD / (2 sqrt(D))) / sqrt(D)

Hessian ``N = sum_m J_m^T J_m`` (5 x 5) per pair ``= [[A, B], [B^T, C]]`` (A: rotation
3 x 3, C: translation 2 x 2); the marginal rotation information is the Schur complement
``A - B C^-1 B^T`` (C with a ridge of 1e-12 of its trace, against a singular block).

Rotation-only residual (pure rotation: ``rotation_only``, or ``t`` zero / not finite)
-------------------------------------------------------------------------------------
``rho = pi(R x1) - x2`` (2 per correspondence), ``pi(y) = (y_0 / y_2, y_1 / y_2)``,
``p = pi(R x1)``::

    drho/dd = [[-p_0 p_1, 1 + p_0^2, -p_1], [-(1 + p_1^2), p_0 p_1, p_0]]

with covariance ``C = s2^2 I + s1^2 A A^T``, ``A = d pi(R x1) / d(u1, v1)`` (the noise of
both images); information ``sum_m J_m^T C_m^-1 J_m`` (3 x 3), nothing to marginalise.

Degeneracies
------------
Correspondences that are not finite, at an epipole (``D = 0``) or behind camera 2 (the
rotation-only model) are dropped. A pair with fewer than :data:`MIN_CORRESPONDENCES`
usable correspondences (5 for the epipolar model, 2 for the rotation-only one), or whose
information is not finite or has no positive trace, gets the weak isotropic
:data:`EMPTY_INFORMATION`. Every other pair gets ``H + MIN_EIGENVALUE_RATIO * trace(H) * I``
(eigenvalues clamped to that floor should rounding leave one below it): always symmetric
positive definite, never NaN.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "EMPTY_INFORMATION",
    "MIN_CORRESPONDENCES",
    "MIN_EIGENVALUE_RATIO",
    "PIXEL_SIGMA",
    "rotation_information",
    "sampson_residuals",
    "tangent_basis",
    "transfer_residuals",
    "translation_directions",
]

#: Default keypoint noise, pixels (standard deviation per coordinate, both images).
PIXEL_SIGMA = 1.0
#: Eigenvalue floor of every information matrix, relative to its trace (``H + ratio *
#: trace(H) * I``).
MIN_EIGENVALUE_RATIO = 1e-6
#: Information (rad^-2, isotropic: a standard deviation of 1 rad per axis) of a pair
#: without enough usable correspondences: positive definite, but next to nothing.
EMPTY_INFORMATION = 1.0
#: Usable correspondences a pair needs: ``(epipolar, rotation-only)`` (5 and 3 unknowns).
MIN_CORRESPONDENCES = (5, 2)
#: Correspondences processed at once (memory: a few dozen float64 arrays of this size).
CHUNK = 1 << 18

# Ridge of the translation block before the Schur complement, relative to its trace: only
# keeps a singular block invertible (a direction of t the data do not fix then takes the
# rotation direction it is coupled to with it).
_SCHUR_RIDGE = 1e-12

# Upper triangle of a 5 x 5 (epipolar) and a 3 x 3 (rotation-only) matrix.
_IU5 = np.triu_indices(5)
_IU3 = np.triu_indices(3)


# =========================================================================== small helpers


def _cross(a, b):
    """``a x b`` of vectors given as 3 arrays (or scalars) each."""
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def tangent_basis(t: np.ndarray) -> np.ndarray:
    """``(P, 3, 2)``: two orthonormal vectors perpendicular to each unit ``t`` ``(P, 3)``
    (``b1 = t x e / |t x e|`` with ``e`` the axis least aligned with ``t``, ``b2 = t x b1``)."""
    t = np.asarray(t, dtype=np.float64).reshape(-1, 3)
    e = np.zeros_like(t)
    e[np.arange(len(t)), np.argmin(np.abs(t), axis=1)] = 1.0
    b1 = np.cross(t, e)
    b1 /= np.maximum(np.linalg.norm(b1, axis=1, keepdims=True), 1e-300)
    b2 = np.cross(t, b1)
    return np.stack([b1, b2], axis=2)


def _segment_sums(values: np.ndarray, seg: np.ndarray, n: int) -> np.ndarray:
    """Row sums of ``values`` (K, m) per segment (``seg`` sorted, values in ``[0, n)``): (n, K)."""
    out = np.zeros((n, values.shape[0]))
    if values.shape[1] == 0:
        return out
    counts = np.bincount(seg, minlength=n)
    filled = counts > 0
    starts = (np.cumsum(counts) - counts)[filled]
    out[filled] = np.add.reduceat(values, starts, axis=1).T
    return out


def _as_pairs(x, P: int, name: str) -> np.ndarray:
    v = np.asarray(x, dtype=np.float64)
    if v.ndim == 0:
        return np.full(P, float(v))
    if v.shape != (P,):
        raise ValueError(f"{name} must be a scalar or ({P},), got {v.shape}")
    return v


def _prepare(x1, x2, seg, R):
    x1 = np.asarray(x1, dtype=np.float64)
    x2 = np.asarray(x2, dtype=np.float64)
    seg = np.asarray(seg)
    R = np.asarray(R, dtype=np.float64).reshape(-1, 3, 3)
    M = len(seg)
    if x1.shape != (M, 2) or x2.shape != (M, 2) or seg.ndim != 1:
        raise ValueError(f"expected (M, 2) points x1, x2 and (M,) seg, got {x1.shape}, {x2.shape}, {seg.shape}")
    if M and not np.issubdtype(seg.dtype, np.integer):
        raise ValueError("seg must hold integer pair indices")
    seg = seg.astype(np.int64)
    if M and (seg.min() < 0 or seg.max() >= len(R)):
        raise ValueError(f"seg must index the {len(R)} pairs")
    if M > 1 and (np.diff(seg) < 0).any():  # group the correspondences by pair
        order = np.argsort(seg, kind="stable")
        x1, x2, seg = x1[order], x2[order], seg[order]
    return x1, x2, seg, R


def _chunks(seg: np.ndarray, size: int = CHUNK):
    """Slices of the (sorted) correspondences, cut at pair boundaries, ~``size`` each."""
    M = len(seg)
    lo = 0
    while lo < M:
        hi = min(lo + size, M)
        if hi < M:  # extend to the end of the pair at hi - 1
            hi = int(np.searchsorted(seg, seg[hi - 1], side="right"))
        yield slice(lo, hi)
        lo = hi


def _rows(a: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Per-pair (P, K) values gathered per correspondence as (K, m) rows."""
    return np.ascontiguousarray(a[idx].T)


# =========================================================================== residuals


def _sampson(u1, v1, u2, v2, Rm, t, B, s1sq, s2sq, jacobian: bool = True):
    """Whitened Sampson residuals ``r`` (m,), ``D`` (m,) and, with ``jacobian``, ``J``
    (5, m): rows ``d`` (3) then ``dt`` (2). All inputs per correspondence (module docstring)."""
    y = (Rm[0] * u1 + Rm[1] * v1 + Rm[2], Rm[3] * u1 + Rm[4] * v1 + Rm[5], Rm[6] * u1 + Rm[7] * v1 + Rm[8])
    x2 = (u2, v2, 1.0)
    a = _cross(t, y)
    e = a[0] * u2 + a[1] * v2 + a[2]
    w = _cross(x2, t)
    b0 = Rm[0] * w[0] + Rm[3] * w[1] + Rm[6] * w[2]
    b1 = Rm[1] * w[0] + Rm[4] * w[1] + Rm[7] * w[2]
    D = s2sq * (a[0] * a[0] + a[1] * a[1]) + s1sq * (b0 * b0 + b1 * b1)
    sq = np.sqrt(np.maximum(D, 1e-300))
    r = e / sq
    if not jacobian:
        return r, D, None
    de_d = _cross(y, w)
    yx2 = _cross(y, x2)
    Bc1, Bc2 = (B[0], B[1], B[2]), (B[3], B[4], B[5])
    gxt = (a[1] * t[2], -a[0] * t[2], a[0] * t[1] - a[1] * t[0])  # g x t, g = (a0, a1, 0)
    Rh = (Rm[0] * b0 + Rm[1] * b1, Rm[3] * b0 + Rm[4] * b1, Rm[6] * b0 + Rm[7] * b1)
    p, q = 2.0 * s2sq, 2.0 * s1sq
    ygt = _cross(y, gxt)
    Rhw = _cross(Rh, w)
    dD_d = tuple(p * ygt[k] + q * Rhw[k] for k in range(3))
    yg = (-y[2] * a[1], y[2] * a[0], y[0] * a[1] - y[1] * a[0])  # y x g
    Rhx2 = _cross(Rh, x2)
    v = tuple(p * yg[k] + q * Rhx2[k] for k in range(3))
    de_t = (_dot(Bc1, yx2), _dot(Bc2, yx2))
    dD_t = (_dot(Bc1, v), _dot(Bc2, v))
    c = 0.5 * r / sq
    inv = 1.0 / sq
    J = np.stack([(de_d[0] - c * dD_d[0]) * inv, (de_d[1] - c * dD_d[1]) * inv, (de_d[2] - c * dD_d[2]) * inv,
                  (de_t[0] - c * dD_t[0]) * inv, (de_t[1] - c * dD_t[1]) * inv])
    return r, D, J


def _transfer(u1, v1, u2, v2, Rm, s1sq, s2sq):
    """Rotation-only model: ``rho`` (2, m), ``J`` (2, 3, m), ``W = C^-1`` as ``(W00, W01,
    W11)`` and the depth ``y_2`` (m,) of ``R x1`` (module docstring)."""
    y0 = Rm[0] * u1 + Rm[1] * v1 + Rm[2]
    y1 = Rm[3] * u1 + Rm[4] * v1 + Rm[5]
    y2 = Rm[6] * u1 + Rm[7] * v1 + Rm[8]
    iz = 1.0 / np.where(y2 > 0, y2, 1.0)
    p0, p1 = y0 * iz, y1 * iz
    rho = np.stack([p0 - u2, p1 - v2])
    J = np.stack([np.stack([-p0 * p1, 1.0 + p0 * p0, -p1]), np.stack([-(1.0 + p1 * p1), p0 * p1, p0])])
    A00, A01 = (Rm[0] - p0 * Rm[6]) * iz, (Rm[1] - p0 * Rm[7]) * iz
    A10, A11 = (Rm[3] - p1 * Rm[6]) * iz, (Rm[4] - p1 * Rm[7]) * iz
    C00 = s2sq + s1sq * (A00 * A00 + A01 * A01)
    C01 = s1sq * (A00 * A10 + A01 * A11)
    C11 = s2sq + s1sq * (A10 * A10 + A11 * A11)
    det = C00 * C11 - C01 * C01
    idet = 1.0 / np.where(det > 0, det, 1.0)
    return rho, J, (C11 * idet, -C01 * idet, C00 * idet), y2, np.stack([np.stack([C00, C01]), np.stack([C01, C11])])


def _per_correspondence(seg, R, scale1, scale2, sigma):
    P = len(R)
    s1 = sigma * _as_pairs(scale1, P, "scale1")
    s2 = sigma * _as_pairs(scale2, P, "scale2")
    Rm = _rows(R.reshape(P, 9), seg)
    sq = (_rows((s1 * s1)[:, None], seg)[0], _rows((s2 * s2)[:, None], seg)[0])
    return Rm, sq


def sampson_residuals(x1, x2, seg, R, t, *, scale1=1.0, scale2=1.0, sigma: float = PIXEL_SIGMA):
    """The whitened Sampson residuals ``r`` (M,) of every correspondence and their
    Jacobian ``J`` (M, 5) w.r.t. ``(d, dt)`` (module docstring; ``dt`` in
    :func:`tangent_basis` of the normalised ``t``), in the order given."""
    x1 = np.asarray(x1, dtype=np.float64)
    x2 = np.asarray(x2, dtype=np.float64)
    seg = np.asarray(seg, dtype=np.int64)
    R = np.asarray(R, dtype=np.float64).reshape(-1, 3, 3)
    t = np.asarray(t, dtype=np.float64).reshape(-1, 3)
    t = t / np.linalg.norm(t, axis=1, keepdims=True)
    Rm, (s1sq, s2sq) = _per_correspondence(seg, R, scale1, scale2, sigma)
    tt = _rows(t, seg)
    B = _rows(np.swapaxes(tangent_basis(t), 1, 2).reshape(-1, 6), seg)
    r, _, J = _sampson(x1[:, 0], x1[:, 1], x2[:, 0], x2[:, 1], Rm, tt, B, s1sq, s2sq)
    return r, J.T


def transfer_residuals(x1, x2, seg, R, *, scale1=1.0, scale2=1.0, sigma: float = PIXEL_SIGMA):
    """The rotation-only model: transfer residuals ``rho`` (M, 2) (normalised units), their
    Jacobian (M, 2, 3) w.r.t. ``d`` and their covariance ``C`` (M, 2, 2) (module
    docstring), in the order given."""
    x1 = np.asarray(x1, dtype=np.float64)
    x2 = np.asarray(x2, dtype=np.float64)
    seg = np.asarray(seg, dtype=np.int64)
    R = np.asarray(R, dtype=np.float64).reshape(-1, 3, 3)
    Rm, (s1sq, s2sq) = _per_correspondence(seg, R, scale1, scale2, sigma)
    rho, J, _, _, C = _transfer(x1[:, 0], x1[:, 1], x2[:, 0], x2[:, 1], Rm, s1sq, s2sq)
    return rho.T, np.moveaxis(J, -1, 0), np.moveaxis(C, -1, 0)


# =========================================================================== information


def _schur(N: np.ndarray) -> np.ndarray:
    """Rotation block of the 5 x 5 Hessians ``N`` (P, 5, 5) with the translation
    marginalised: ``A - B C^-1 B^T`` (C regularised)."""
    A, Bm, C = N[:, :3, :3], N[:, :3, 3:], N[:, 3:, 3:]
    tr = C[:, 0, 0] + C[:, 1, 1]
    reg = _SCHUR_RIDGE * np.maximum(tr, 0.0)
    c00, c01, c11 = C[:, 0, 0] + reg, C[:, 0, 1], C[:, 1, 1] + reg
    det = c00 * c11 - c01 * c01
    det = np.where(det > 0, det, np.inf)  # no translation block at all (nor coupling): no correction
    Ci = np.stack([np.stack([c11, -c01], -1), np.stack([-c01, c00], -1)], -2) / det[:, None, None]
    return A - Bm @ Ci @ np.swapaxes(Bm, 1, 2)


def _floor(H: np.ndarray, enough: np.ndarray) -> np.ndarray:
    """Symmetric positive definite information (module docstring, "Degeneracies")."""
    H = 0.5 * (H + np.swapaxes(H, 1, 2))
    tr = np.trace(H, axis1=1, axis2=2)
    ok = enough & np.isfinite(H).all(axis=(1, 2)) & (tr > 0) & np.isfinite(tr)
    floor = MIN_EIGENVALUE_RATIO * np.where(ok, tr, 0.0)
    H = np.where(ok[:, None, None], H + floor[:, None, None] * np.eye(3), EMPTY_INFORMATION * np.eye(3))
    m2 = H[:, 0, 0] * H[:, 1, 1] - H[:, 0, 1] ** 2
    bad = ~((H[:, 0, 0] > 0) & (m2 > 0) & (np.linalg.det(H) > 0))
    if bad.any():  # rounding left an eigenvalue below the floor: clamp it
        lam, V = np.linalg.eigh(H[bad])
        lam = np.maximum(lam, floor[bad][:, None])
        H[bad] = (V * lam[:, None, :]) @ np.swapaxes(V, 1, 2)
    return H


def rotation_information(x1, x2, seg, R, t=None, *, scale1=1.0, scale2=1.0, sigma: float = PIXEL_SIGMA,
                         rotation_only=None) -> np.ndarray:
    """Rotation information matrices ``(P, 3, 3)`` of ``P`` relative poses from their
    correspondences (module docstring: inputs, model, formulas, degeneracies).

    ``x1``, ``x2`` (M, 2): normalised image points; ``seg`` (M,): the pair of each
    correspondence (any order); ``R`` (P, 3, 3): ``cam2_from_cam1``; ``t`` (P, 3): the
    translation directions (None: every pair rotation-only); ``scale1``, ``scale2``: the
    pixel-to-normalised scale of each pair's cameras (scalar or (P,), e.g. ``1 / focal``);
    ``sigma``: the pixel noise; ``rotation_only`` (P,) bool: pairs to treat as pure
    rotations (COLMAP's PANORAMIC), as are those whose ``t`` is zero or not finite.

    The information is in rotgraph's convention: ``R_measured = exp([d]x) R`` with
    ``d ~ N(0, H^-1)`` (camera 2's frame, radians). Symmetric positive definite, finite.
    """
    x1, x2, seg, R = _prepare(x1, x2, seg, R)
    P = len(R)
    if not sigma > 0:
        raise ValueError("sigma must be positive")
    if t is None:
        t = np.zeros((P, 3))
    t = np.asarray(t, dtype=np.float64).reshape(-1, 3)
    if len(t) != P:
        raise ValueError(f"t must be ({P}, 3), got {t.shape}")
    norm = np.linalg.norm(t, axis=1)
    rot_only = ~(np.isfinite(norm) & (norm > 1e-12))
    if rotation_only is not None:
        rot_only |= np.broadcast_to(np.asarray(rotation_only, dtype=bool), (P,))
    t = np.where(rot_only[:, None], np.array([0.0, 0.0, 1.0]), t / np.where(rot_only, 1.0, norm)[:, None])
    s1 = sigma * _as_pairs(scale1, P, "scale1")
    s2 = sigma * _as_pairs(scale2, P, "scale2")
    if not (np.isfinite(s1).all() and np.isfinite(s2).all()):
        raise ValueError("scale1 and scale2 must be finite")
    R9 = R.reshape(P, 9)
    Bt = np.swapaxes(tangent_basis(t), 1, 2).reshape(P, 6)
    var1, var2 = s1 * s1, s2 * s2

    N = np.zeros((P, 15))  # epipolar Hessians (upper triangle)
    G = np.zeros((P, 6))  # rotation-only information (upper triangle)
    count = np.zeros(P, dtype=np.int64)
    finite = np.isfinite(x1).all(axis=1) & np.isfinite(x2).all(axis=1)
    for sl in _chunks(seg):
        sg = seg[sl]
        use = finite[sl]
        ro = rot_only[sg]
        ep = use & ~ro
        if ep.any():
            idx = sg[ep]
            a, b = x1[sl][ep], x2[sl][ep]
            _, D, J = _sampson(a[:, 0], a[:, 1], b[:, 0], b[:, 1], _rows(R9, idx), _rows(t, idx), _rows(Bt, idx),
                               var1[idx], var2[idx])
            good = (D > 0) & np.isfinite(J).all(axis=0)
            J = J[:, good]
            N += _segment_sums(J[_IU5[0]] * J[_IU5[1]], idx[good], P)
            count += np.bincount(idx[good], minlength=P)
        rt = use & ro
        if rt.any():
            idx = sg[rt]
            a, b = x1[sl][rt], x2[sl][rt]
            _, J, W, depth, _ = _transfer(a[:, 0], a[:, 1], b[:, 0], b[:, 1], _rows(R9, idx), var1[idx], var2[idx])
            WJ0 = W[0] * J[0] + W[1] * J[1]  # (C^-1 J) rows, (3, m) each
            WJ1 = W[1] * J[0] + W[2] * J[1]
            vals = J[0][_IU3[0]] * WJ0[_IU3[1]] + J[1][_IU3[0]] * WJ1[_IU3[1]]
            good = (depth > 0) & np.isfinite(vals).all(axis=0)
            G += _segment_sums(vals[:, good], idx[good], P)
            count += np.bincount(idx[good], minlength=P)

    full5 = np.zeros((P, 5, 5))
    full5[:, _IU5[0], _IU5[1]] = N
    full5[:, _IU5[1], _IU5[0]] = N
    full3 = np.zeros((P, 3, 3))
    full3[:, _IU3[0], _IU3[1]] = G
    full3[:, _IU3[1], _IU3[0]] = G
    H = np.where(rot_only[:, None, None], full3, _schur(full5))
    enough = count >= np.where(rot_only, MIN_CORRESPONDENCES[1], MIN_CORRESPONDENCES[0])
    return _floor(H, enough)


def translation_directions(x1, x2, seg, R, *, scale1=1.0, scale2=1.0, sigma: float = PIXEL_SIGMA,
                           iterations: int = 2) -> np.ndarray:
    """Unit translation directions ``(P, 3)`` of pairs whose rotation ``R`` (P, 3, 3) is
    known (up to sign, which the information does not depend on): the ``t`` minimising
    ``sum (t . (R x1 x x2))^2 / D`` (the epipolar error ``e = t . (y x x2)``, weighted by
    the Sampson denominator ``D`` of the previous iterate; the first is unweighted), the
    smallest eigenvector of a 3 x 3 scatter matrix per pair. Zero rows for pairs with fewer
    than 2 finite correspondences (their ``t`` is undefined)."""
    x1, x2, seg, R = _prepare(x1, x2, seg, R)
    P = len(R)
    var1 = (sigma * _as_pairs(scale1, P, "scale1")) ** 2
    var2 = (sigma * _as_pairs(scale2, P, "scale2")) ** 2
    finite = np.isfinite(x1).all(axis=1) & np.isfinite(x2).all(axis=1)
    x1, x2, seg = x1[finite], x2[finite], seg[finite]
    count = np.bincount(seg, minlength=P)
    R9 = R.reshape(P, 9)
    t = None
    for it in range(iterations + 1):
        S = np.zeros((P, 6))
        for sl in _chunks(seg):
            idx = seg[sl]
            u1, v1, u2, v2 = x1[sl, 0], x1[sl, 1], x2[sl, 0], x2[sl, 1]
            Rm = _rows(R9, idx)
            y = (Rm[0] * u1 + Rm[1] * v1 + Rm[2], Rm[3] * u1 + Rm[4] * v1 + Rm[5], Rm[6] * u1 + Rm[7] * v1 + Rm[8])
            n = np.stack(_cross(y, (u2, v2, 1.0)))
            if t is None:
                wgt = 1.0 / (var1[idx] + var2[idx])
            else:
                zeros = np.zeros((6, len(idx)))
                _, D, _ = _sampson(u1, v1, u2, v2, Rm, _rows(t, idx), zeros, var1[idx], var2[idx], jacobian=False)
                wgt = 1.0 / np.maximum(D, 1e-300)
            S += _segment_sums(wgt * n[_IU3[0]] * n[_IU3[1]], idx, P)
        full = np.zeros((P, 3, 3))
        full[:, _IU3[0], _IU3[1]] = S
        full[:, _IU3[1], _IU3[0]] = S
        full /= np.maximum(np.trace(full, axis1=1, axis2=2), 1e-300)[:, None, None]
        _, V = np.linalg.eigh(full)
        t = V[:, :, 0]
    return np.where((count >= 2)[:, None] & np.isfinite(t), t, 0.0)
