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
standard deviation of ``e`` under the pixel noise, so ``r ~ N(0, 1)``. Its Gauss-Newton
Jacobian, with the denominator ``D`` held at the linearisation point (the Sampson error as
a weighted algebraic error; checked against finite differences in the tests)::

    J = (de/dd, de/ddt) / sqrt(D),   de/dd = y x w,   de/ddt = B^T (y x x2)

(``e = t . (y x x2)``, and ``d`` turns ``y`` into ``y + d x y``). The exact derivative of
``r`` adds ``-r dD / (2 D)``: proportional to the residual, so zero in expectation (the
Fisher information is the Hessian above); it changed the information by a median 5e-5,
at most 6 % (in the whitened sense) on a synthetic 50-image COLMAP project, for twice
the arithmetic.

Hessian ``N = sum_m J_m^T J_m`` (5 x 5) per pair ``= [[A, B], [B^T, C]]`` (A: rotation
3 x 3, C: translation 2 x 2); the marginal rotation information is the Schur complement
``A - B C^-1 B^T`` (C with a ridge of 1e-12 of its trace, against a singular block).

Rotation-only residual (pure rotation: ``rotation_only``, or ``t`` zero / not finite)
-------------------------------------------------------------------------------------
``rho = pi(R x1) - x2`` (2 per correspondence), ``pi(y) = (y_0 / y_2, y_1 / y_2)``,
``p = pi(R x1)``::

    drho/dd = [[-p_0 p_1, 1 + p_0^2, -p_1], [-(1 + p_1^2), p_0 p_1, p_0]]

with covariance ``C = s2^2 I + s1^2 A A^T``, ``A = d pi(R x1) / d(u1, v1)`` (the noise of
both images; held at the linearisation point, as ``D`` above); information
``sum_m J_m^T C_m^-1 J_m`` (3 x 3), nothing to marginalise.

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

from ..errors import OptionError

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
CHUNK = 1 << 16

# Ridge of the translation block before the Schur complement, relative to its trace: only
# keeps a singular block invertible (a direction of t the data do not fix then takes the
# rotation direction it is coupled to with it).
_SCHUR_RIDGE = 1e-12

# A Sampson denominator below this times (s1^2 + s2^2): the point is at an epipole in both
# images (|E x1|, |E^T x2| < 1e-6), a correspondence without a constraint.
_AT_EPIPOLE = 1e-12

# Upper triangle of a 5 x 5 (epipolar) and a 3 x 3 (rotation-only) matrix.
_IU5 = np.triu_indices(5)
_IU3 = np.triu_indices(3)


# =========================================================================== small helpers


def _cross(a, b):
    """``a x b`` of vectors given as 3 arrays (or scalars) each."""
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


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


def _prepare(x1, x2, seg, R, weights=None):
    x1 = np.asarray(x1, dtype=np.float64)
    x2 = np.asarray(x2, dtype=np.float64)
    seg = np.asarray(seg)
    R = np.asarray(R, dtype=np.float64).reshape(-1, 3, 3)
    M = len(seg)
    if x1.shape != (M, 2) or x2.shape != (M, 2) or seg.ndim != 1:
        raise ValueError(f"expected (M, 2) points x1, x2 and (M,) seg, got {x1.shape}, {x2.shape}, {seg.shape}")
    if M and not np.issubdtype(seg.dtype, np.integer):
        raise ValueError("seg must hold integer pair indices")
    seg = seg.astype(np.int64, copy=False)
    if M and (seg.min() < 0 or seg.max() >= len(R)):
        raise ValueError(f"seg must index the {len(R)} pairs")
    if weights is not None:
        weights = np.asarray(weights, dtype=np.float64)
        if weights.shape != (M,) or not (np.isfinite(weights).all() and (weights >= 0).all()):
            raise ValueError(f"weights must be ({M},), finite and >= 0")
    if M > 1 and (np.diff(seg) < 0).any():  # group the correspondences by pair
        order = np.argsort(seg, kind="stable")
        x1, x2, seg = x1[order], x2[order], seg[order]
        weights = None if weights is None else weights[order]
    return x1, x2, seg, R, weights


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


def _upper_products(J: np.ndarray, iu) -> np.ndarray:
    """The products ``J[i] * J[j]`` of the upper-triangle index pairs ``iu``: (len, m)."""
    out = np.empty((len(iu[0]), J.shape[1]))
    for r, (i, j) in enumerate(zip(*iu)):
        np.multiply(J[i], J[j], out=out[r])
    return out


def _model_sums(x1, x2, seg, weights, member, P: int, model, K: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-pair sums (P, K) of ``model``'s values over the correspondences flagged in
    ``member`` (``seg`` sorted), times their ``weights`` (None: 1), and the count of
    usable ones (P,), chunk by chunk.

    ``model(u1, v1, u2, v2, rep)`` gets a chunk's coordinates and ``rep(a)``, which turns
    per-pair values ``a`` (P, k) into per-correspondence rows (k, m); it returns the values
    (K, m) and which correspondences are usable (m,). Correspondences that are not finite
    or not usable add nothing."""
    out = np.zeros((P, K))
    count = np.zeros(P, dtype=np.int64)
    if not member.any():
        return out, count
    if not member.all():
        x1, x2, seg = x1[member], x2[member], seg[member]
        weights = None if weights is None else weights[member]
    finite = np.isfinite(x1).all(axis=1) & np.isfinite(x2).all(axis=1)
    all_finite = bool(finite.all())
    if not all_finite:
        x1 = np.where(finite[:, None], x1, 0.5)
        x2 = np.where(finite[:, None], x2, 0.5)
    u1, v1, u2, v2 = (np.ascontiguousarray(c) for c in (x1[:, 0], x1[:, 1], x2[:, 0], x2[:, 1]))
    for sl in _chunks(seg):
        sg = seg[sl]
        lo, hi = int(sg[0]), int(sg[-1]) + 1
        n = np.bincount(sg - lo, minlength=hi - lo)

        def rep(a):
            return np.repeat(a[lo:hi].T, n, axis=1)

        vals, ok = model(u1[sl], v1[sl], u2[sl], v2[sl], rep)
        if not all_finite:
            ok &= finite[sl]
        if not ok.all():
            vals = np.where(ok, vals, 0.0)
        if weights is not None:
            vals *= weights[sl]
        out[lo:hi] += _segment_sums(vals, sg - lo, hi - lo)
        count[lo:hi] += np.bincount(sg - lo, weights=ok, minlength=hi - lo).astype(np.int64)
    return out, count


# =========================================================================== residuals


def _sampson(u1, v1, u2, v2, Rm, t, B, s1sq, s2sq, jacobian: bool = True):
    """Whitened Sampson residuals ``r`` (m,), their denominators ``D`` (m,) and, with
    ``jacobian``, ``J = grad(e) / sqrt(D)`` (5, m): rows ``d`` (3) then ``dt`` (2). All
    inputs per correspondence (module docstring); written out component by component."""
    y0 = Rm[0] * u1 + Rm[1] * v1 + Rm[2]  # y = R x1
    y1 = Rm[3] * u1 + Rm[4] * v1 + Rm[5]
    y2 = Rm[6] * u1 + Rm[7] * v1 + Rm[8]
    t0, t1, t2 = t[0], t[1], t[2]
    a0 = t1 * y2 - t2 * y1  # a = E x1 = t x y
    a1 = t2 * y0 - t0 * y2
    a2 = t0 * y1 - t1 * y0
    w0 = v2 * t2 - t1  # w = x2 x t
    w1 = t0 - u2 * t2
    w2 = u2 * t1 - v2 * t0
    b0 = Rm[0] * w0 + Rm[3] * w1 + Rm[6] * w2  # b = E^T x2 = R^T w
    b1 = Rm[1] * w0 + Rm[4] * w1 + Rm[7] * w2
    D = s2sq * (a0 * a0 + a1 * a1) + s1sq * (b0 * b0 + b1 * b1)
    inv = 1.0 / np.sqrt(np.maximum(D, 1e-300))
    r = (a0 * u2 + a1 * v2 + a2) * inv
    if not jacobian:
        return r, D, None
    c0 = y1 - y2 * v2  # y x x2
    c1 = y2 * u2 - y0
    c2 = y0 * v2 - y1 * u2
    J = np.stack([
        (y1 * w2 - y2 * w1) * inv,  # de/dd = y x w
        (y2 * w0 - y0 * w2) * inv,
        (y0 * w1 - y1 * w0) * inv,
        (B[0] * c0 + B[1] * c1 + B[2] * c2) * inv,  # de/ddt = B^T (y x x2)
        (B[3] * c0 + B[4] * c1 + B[5] * c2) * inv,
    ])
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
    """The whitened Sampson residuals ``r`` (M,) of every correspondence, their
    Gauss-Newton Jacobian ``J`` (M, 5) w.r.t. ``(d, dt)`` (module docstring; ``dt`` in
    :func:`tangent_basis` of the normalised ``t``) and their denominators ``D`` (M,)
    (``J`` is the derivative of ``e / sqrt(D)`` with ``D`` fixed), in the order given."""
    x1 = np.asarray(x1, dtype=np.float64)
    x2 = np.asarray(x2, dtype=np.float64)
    seg = np.asarray(seg, dtype=np.int64)
    R = np.asarray(R, dtype=np.float64).reshape(-1, 3, 3)
    t = np.asarray(t, dtype=np.float64).reshape(-1, 3)
    t = t / np.linalg.norm(t, axis=1, keepdims=True)
    Rm, (s1sq, s2sq) = _per_correspondence(seg, R, scale1, scale2, sigma)
    tt = _rows(t, seg)
    B = _rows(np.swapaxes(tangent_basis(t), 1, 2).reshape(-1, 6), seg)
    r, D, J = _sampson(x1[:, 0], x1[:, 1], x2[:, 0], x2[:, 1], Rm, tt, B, s1sq, s2sq)
    return r, J.T, D


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
                         rotation_only=None, weights=None) -> np.ndarray:
    """Rotation information matrices ``(P, 3, 3)`` of ``P`` relative poses from their
    correspondences (module docstring: inputs, model, formulas, degeneracies).

    ``x1``, ``x2`` (M, 2): normalised image points; ``seg`` (M,): the pair of each
    correspondence (any order); ``R`` (P, 3, 3): ``cam2_from_cam1``; ``t`` (P, 3): the
    translation directions (None: every pair rotation-only); ``scale1``, ``scale2``: the
    pixel-to-normalised scale of each pair's cameras (scalar or (P,), e.g. ``1 / focal``);
    ``sigma``: the pixel noise; ``rotation_only`` (P,) bool: pairs to treat as pure
    rotations (COLMAP's PANORAMIC), as are those whose ``t`` is zero or not finite;
    ``weights`` (M,): each correspondence counts this many times (e.g. ``n / k`` for a
    sample of ``k`` of a pair's ``n`` matches), None = 1.

    The information is in rotgraph's convention: ``R_measured = exp([d]x) R`` with
    ``d ~ N(0, H^-1)`` (camera 2's frame, radians). Symmetric positive definite, finite.
    """
    x1, x2, seg, R, w = _prepare(x1, x2, seg, R, weights)
    P = len(R)
    if not sigma > 0:
        raise OptionError("sigma must be positive")
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
    var = np.stack([s1 * s1, s2 * s2], axis=1)

    def epipolar(u1, v1, u2, v2, rep):
        Rm, tt, B, vv = rep(R9), rep(t), rep(Bt), rep(var)
        _, D, J = _sampson(u1, v1, u2, v2, Rm, tt, B, vv[0], vv[1])
        # D ~ 0: the point at an epipole in both images (no constraint; 1 / sqrt(D) blows up)
        return _upper_products(J, _IU5), D > _AT_EPIPOLE * (vv[0] + vv[1])

    def rotation(u1, v1, u2, v2, rep):
        vv = rep(var)
        _, J, W, depth, _ = _transfer(u1, v1, u2, v2, rep(R9), vv[0], vv[1])
        WJ0 = W[0] * J[0] + W[1] * J[1]  # (C^-1 J) rows, (3, m) each
        WJ1 = W[1] * J[0] + W[2] * J[1]
        return J[0][_IU3[0]] * WJ0[_IU3[1]] + J[1][_IU3[0]] * WJ1[_IU3[1]], depth > 0

    on_rot = rot_only[seg]
    N, n_ep = _model_sums(x1, x2, seg, w, ~on_rot, P, epipolar, 15)  # epipolar Hessians (upper triangle)
    G, n_rot = _model_sums(x1, x2, seg, w, on_rot, P, rotation, 6)  # rotation-only information (upper triangle)
    count = n_ep + n_rot

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
    x1, x2, seg, R, _ = _prepare(x1, x2, seg, R)
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
