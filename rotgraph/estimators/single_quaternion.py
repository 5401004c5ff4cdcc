"""Closed forms of the L2 means on unit quaternions (:func:`rotgraph.estimators.single.mean`).

* chordal L2: the dominant eigenvector of ``sum w_i q_i q_i^T`` (Markley et al. 2007),
  equal to the projection of ``sum w_i R_i`` onto SO(3);
* quaternion L2 (Hartley et al. 2013, section 5.7): choose each ``q_i``'s sign in the
  hemisphere of the estimate, average, normalise, until the signs stop changing. Up to
  :data:`_EXHAUSTIVE_MAX` rotations every sign vector is tried (exact); up to a few hundred
  the sign iterations run from several starts at once; beyond, only the data near the
  hemisphere boundary are revisited.

The data are ``x`` (N, 4) quaternions, not necessarily unit: ``u = w / |q|^2`` normalises
``q q^T`` and ``v = w / |q|`` normalises ``q`` (``inv = 1 / |q|``, None for unit data).
"""

from __future__ import annotations

import numpy as np


def _eigenvectors(K: np.ndarray) -> np.ndarray:
    """Eigenvectors (columns, ascending eigenvalues) of a symmetric 4x4 matrix. numpy's
    ``eigh`` (LAPACK's syevd too) costs ~4 us more per call than scipy's raw LAPACK wrapper,
    but needs no scipy import: a one-shot command (e.g. the gauge alignment of ``rotgraph
    solve``'s evaluation) starts 0.25 s sooner."""
    return np.linalg.eigh(K)[1]


def dominant_eigenvector(K: np.ndarray) -> np.ndarray:
    return _eigenvectors(K)[:, -1]


def chordal_l2(Q: np.ndarray, w: np.ndarray) -> np.ndarray:
    return dominant_eigenvector((Q * w) @ Q.T)


_COS_QUARTER_PI = float(np.cos(np.pi / 4))


def quaternion_l2_small(x, u, v, inv, w, wpos, max_iterations, W=None):
    """Quaternion L2 mean of few rotations: the sign iterations of paper section 5.7 (choose
    each ``q_i``'s sign in the hemisphere of ``m``, average, normalise, until the signs stop
    changing) run from several starts at once, as one (N, starts) problem.

    The first start is the chordal L2 mean. When some datum of positive weight ends beyond
    pi/2 of its fixed point (``|q_i . m| < cos(pi/4)``) the cost can have other local minima,
    and the best fixed point of all the starts is kept: for N <= 64 the 4 data points of
    highest support ``sum_j w_j |q_i . q_j|`` and the second eigenvector of ``sum w q q^T``,
    beyond that the datum of highest chordal support ``sum_j w_j (q_i . q_j)^2``.
    The columns are not normalised during the iterations (signs do not depend on scale);
    at a fixed point ``T = sum v_i sign_i q_i`` the support ``sum v |q_i . m|`` is ``|T|``.
    Returns ``(m, sum v |q_i . m|, iterations, converged, spread)``.
    """
    n = len(x)
    if n <= _EXHAUSTIVE_MAX:
        return _quaternion_l2_exhaustive(x, v, inv, w, wpos)
    xn = x if inv is None else x * inv[:, None]
    K = x.T @ (x * u[:, None])
    V = _eigenvectors(K)
    if n > 64:
        # The datum of highest chordal support sum_j w_j (q_i . q_j)^2 = q_i^T K q_i (O(N)
        # instead of the O(N^2) support of every datum).
        M = np.empty((4, 2))
        M[:, 1] = xn[int(np.argmax(np.einsum("ij,ij->i", xn @ K, xn)))]
    else:
        score = np.abs(xn @ xn.T) @ w
        top = np.argsort(score)[:-5:-1]  # the 4 highest
        M = np.empty((4, len(top) + 2))
        M[:, 1:-1] = xn[top].T
        M[:, -1] = V[:, -2]
    M[:, 0] = V[:, -1]
    vc = v[:, None]
    sg = np.copysign(vc, x @ M)  # v_i sign(q_i . m) per start
    T = x.T @ sg
    it = 0
    converged = False
    for it in range(1, max_iterations + 1):
        S = x @ T
        new = np.copysign(vc, S)
        if not (new != sg).any():
            converged = True
            break
        sg = new
        T = x.T @ sg
    norms = np.sqrt((T * T).sum(axis=0))
    if converged:
        support = norms.tolist()
        changed = [False] * len(support)
    else:
        changed = (np.copysign(vc, x @ T) != sg).any(axis=0)
        S = x @ T  # at the normalised T / |T| below
        support = ((v @ np.abs(S)) / norms).tolist()
    c0 = np.abs(S[:, 0])
    if inv is not None:
        c0 *= inv
    spread = float(c0.min() if wpos else c0[w > 0].min()) < _COS_QUARTER_PI * float(norms[0])
    best = 0
    if spread:
        # Beyond a ball of radius pi/2 the sign iterations may stop in a local minimum: keep
        # the lowest cost (the chordal start unless another is lower beyond rounding).
        W = float(w.sum()) if W is None else W
        for j in range(1, M.shape[1]):
            if 2.0 * support[j] > 2.0 * support[best] + 1e-12 * W:
                best = j
    return T[:, best] / norms[best], support[best], it, not bool(changed[best]), spread


# Up to this many rotations the quaternion L2 mean is found by trying every sign choice.
_EXHAUSTIVE_MAX = 12
_SIGN_TABLES: dict = {}


def _quaternion_l2_exhaustive(x, v, inv, w, wpos):
    """Quaternion L2 mean of at most :data:`_EXHAUSTIVE_MAX` rotations, exactly: the cost
    ``sum w_i (2 - 2 |q . q_i|)`` is minimal where ``sum w_i |q . q_i|`` is maximal, and
    ``max_q sum w_i |q . q_i| = max_s |sum_i s_i w_i q_i|`` over the sign vectors ``s``
    (with ``q`` the normalised sum): one matrix product over all ``2^(N-1)`` of them.
    Returns what :func:`quaternion_l2_small` returns."""
    n = len(x)
    S = _SIGN_TABLES.get(n)
    if S is None:  # rows: every sign vector with s_0 = +1
        bits = (np.arange(2 ** (n - 1))[:, None] >> np.arange(n - 1)) & 1
        S = _SIGN_TABLES[n] = np.hstack([np.ones((len(bits), 1)), 1.0 - 2.0 * bits])
    T = S @ (x * v[:, None])  # (2^(N-1), 4): sum s_i v_i q_i, v_i = w_i / |q_i|
    norms = np.einsum("ij,ij->i", T, T)
    best = int(np.argmax(norms))
    support = float(np.sqrt(norms[best]))
    m = T[best] / support if support > 0 else np.array([1.0, 0.0, 0.0, 0.0])
    c = np.abs(x @ m)
    if inv is not None:
        c *= inv
    spread = float(c.min() if wpos else c[w > 0].min()) < _COS_QUARTER_PI
    return m, support, 0, True, spread


def quaternion_l2_large(m, x, v, inv, max_iterations):
    """Sign iterations of the quaternion L2 mean (paper section 5.7) from ``m`` for many data.

    One pass fixes the signs at the start and the weighted sum; then only the data within a
    band of the hemisphere boundary (``|q_i . m| / |q_i| < margin``) can change sign while
    the iterate stays within ``margin`` of the start, so the iterations touch those alone
    (a new band is taken if the iterate moves farther).
    Returns ``(m, sum v |q_i . m|, iterations, converged)``.
    """
    margin = 0.1
    it = 0
    total = None
    while True:
        s = x @ m
        c = np.abs(s)
        if inv is not None:
            c *= inv
        neg = s < 0
        total = x.T @ np.where(neg, -v, v)
        band = np.flatnonzero(c < margin)
        xb, vb, negb = x[band], v[band], neg[band]
        m_ref = m
        while it < max_iterations:
            it += 1
            m = total / np.sqrt(total @ total)
            dm = m - m_ref
            if dm @ dm >= 0.25 * margin * margin:
                break  # left the band's region of validity: take a new one
            new_neg = xb @ m < 0
            flip = np.flatnonzero(new_neg != negb)
            if len(flip) == 0:
                return m, float(m @ total), it, True
            total = total - 2.0 * (xb[flip].T @ np.where(negb[flip], -vb[flip], vb[flip]))
            negb[flip] = ~negb[flip]
        else:
            m = total / np.sqrt(total @ total)
            return m, float(v @ np.abs(x @ m)), it, False

