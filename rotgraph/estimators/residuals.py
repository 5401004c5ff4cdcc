"""Edge residuals of multiple rotation averaging, in the quaternion row layout.

Absolute rotations are quaternion rows ``q`` (4, n) and relative rotations rows ``qrel``
(4, E): each component a contiguous array, which makes elementwise work over 10^6 edges
several times faster than (E, 4). The residual of edge ``(i, j)`` is
``log(R_j^T R_ij R_i)``.
"""

from __future__ import annotations

import copy

import numpy as np

from .. import so3_rows

__all__ = ["edge_errors", "error_quaternions", "EdgeSystem", "unit_quaternions", "update_rotations"]


def error_quaternions(qi: np.ndarray, qj: np.ndarray, qrel: np.ndarray) -> np.ndarray:
    """Each edge's residual rotation ``R_j^T R_ij R_i`` as quaternion rows (4, E),
    ``conj(q_j) qrel q_i``, from the rotations of its tail ``qi`` and head ``qj`` (4, E, gathered
    by the caller: the layout of the gather decides the rounding of the small products, which
    each caller keeps as it was) and its relative rotation ``qrel`` (4, E)."""
    return so3_rows.qmul_rows(so3_rows.qconj_rows(qj), so3_rows.qmul_rows(qrel, qi))


def edge_errors(q: np.ndarray, edges: np.ndarray, qrel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Residual rotation vectors ``log(R_j^T R_ij R_i)`` (3, E) and their angles (E,)."""
    return so3_rows.qlog_rows(error_quaternions(q[:, edges[:, 0]], q[:, edges[:, 1]], qrel))


# conj(a) * b = _QMUL_CONJ @ outer(a, b).ravel(), for the small-graph products (up to
# so3_rows.OUTER_MAX edges).
_QMUL_CONJ = so3_rows.QMUL_TABLE * np.repeat([1.0, -1.0, -1.0, -1.0], 4)


#: :meth:`EdgeSystem.errors` works through the edges in blocks of this many.
ERRORS_CHUNK = 1 << 16
#: From this many edges on, :meth:`EdgeSystem.errors` multiplies the quaternions in single
#: precision (results stored in double): about twice as fast, and each residual carries a
#: rounding error of ~1e-7 rad (~1e-5 deg; up to ~1e-4 rad for outliers near 180 deg, where
#: asin is ill-conditioned), a hundredth of the step tolerance and far below the noise of
#: any real graph this large. Below, everything is double (noise-free problems are solved
#: to ~1e-12).
FLOAT32_MIN_EDGES = 2_000_000


def unit_quaternions(q: np.ndarray) -> np.ndarray:
    """``q`` (4, K) itself when its columns are unit quaternions (to 1e-12), else normalised
    (the errors' half angle ``asin(|v|)`` assumes unit norm)."""
    if not q.shape[-1]:
        return q
    norm2 = np.einsum("ij,ij->j", q, q)
    return q / np.sqrt(norm2) if float(np.abs(norm2 - 1.0).max()) > 1e-12 else q


class EdgeSystem:
    """What every IRLS iteration needs of the graph: the edge errors, the right-hand side
    ``A^T v`` of the Laplacian system, the update of the rotations.

    With per-edge rotation information matrices ``information`` (E, 3, 3) (rotgraph's
    convention: an error ``d`` in camera j's frame, ``R_ij,meas = exp(d) R_ij``), an edge's
    residual size is its Mahalanobis norm ``sqrt(d^T H d)`` (:meth:`angles`), ``d = R_j r``
    the camera-frame error of the world-frame residual ``r`` (whose information is
    ``G = R_j^T H R_j``; never formed: :meth:`gauss_newton_blocks`). ``information_scale``
    normalises ``information`` (the caller's choice: its median isotropic precision 1, the norm
    then an angle for an edge of median precision); the matrices are the caller's array, not
    copied (the scale is applied chunk by chunk where they are used).

    Everything is in half-angle form: the error quaternion ``e`` of an edge has vector part
    ``v`` and half angle ``t``; its rotation vector is ``2 f v``. The Laplacian system is
    solved for half the update, ``x = w / 2``, so that ``exp(w)`` is ``[cos|x|, sin|x| x/|x|]``.
    """

    def __init__(self, n: int, edges: np.ndarray, qrel: np.ndarray, anchor: int, information: np.ndarray | None = None,
                 information_scale: float = 1.0):
        qrel = unit_quaternions(qrel)
        self.n, self.n_edges, self.qrel = n, len(edges), qrel
        self.precision = None  # (E,) isotropic precisions of an :meth:`isotropic` view
        self._blocks_buffer = None  # :meth:`gauss_newton_blocks`' output, reused
        # The information matrices (E, 3, 3) as given (the graph's own array: no copy, 720 MB at
        # 10^7 edges) and the factor that normalises them, applied chunk by chunk where they
        # are used (:meth:`_information_rows`).
        self._information = information
        self.information_scale = float(information_scale)
        # The last errors (:meth:`errors`), in a holder shared with the :meth:`isotropic` views (the
        # errors do not depend on the information: one result alive, not one per view).
        self._last = [None, None]
        self.last_camera: tuple = (None, None)
        self.last_angles: tuple = (None, None)
        # (qrel * p)_k = sum_b left[k, b] p_b, for the small-graph products.
        self.left = so3_rows.left_matrix_rows(qrel) if len(edges) <= so3_rows.OUTER_MAX else None
        i, j = edges[:, 0], edges[:, 1]
        self.head_node = j
        self.ij = np.concatenate([i, j])
        # single-precision copies for the products of huge graphs (FLOAT32_MIN_EDGES)
        self.single = None
        if len(edges) >= FLOAT32_MIN_EDGES and self.left is None and n < 2**31:
            self.single = (self.ij.astype(np.int32), qrel.astype(np.float32))
        self.anchor = anchor

    def errors(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(v (3, E), f (E,), t (E,))``: residual rotation vector ``2 f v``, angle ``2 t``.

        The last result is kept: the solvers never modify a rotation array in place, so the
        same array (one stage's result, the next stage's start) has the same errors."""
        last = self._last
        if q is last[0]:
            return last[1]
        E = self.n_edges
        if self.left is None and E > ERRORS_CHUNK:
            out = self._errors_chunked(q)
        else:
            out = self._errors(q, self.ij[:E], self.ij[E:], self.qrel)
        last[:] = (q, out)
        return out

    def _errors(self, q, i, j, qrel, out=None):
        """:meth:`errors` of the edges ``i -> j`` (relative rotations ``qrel``), into ``out``
        ``(v, f, t)`` when given."""
        E = len(i)
        if self.left is not None:
            qq = np.take(q, np.concatenate([i, j]), axis=1)
            p = np.einsum("kbe,be->ke", self.left, qq[:, :E])  # qrel * q_i
            e = _QMUL_CONJ @ (qq[:, None, E:] * p[None]).reshape(16, E)
        else:
            e = error_quaternions(np.take(q, i, axis=1), np.take(q, j, axis=1), qrel)
        v = e[1:] if out is None else out[0]
        if out is not None:
            v[...] = e[1:]
        s = np.sqrt(np.einsum("ke,ke->e", e[1:], e[1:]))  # in e's precision
        # Half angle, the short way round: atan2(s, |w|) = asin(s) for a unit quaternion
        # (asin is 3x faster; exact but for angles within ~1e-8 rad of 180 deg).
        t = np.arcsin(np.minimum(s, 1.0), out=None if out is None else out[2])
        # s = 0 only where v = 0: any finite f gives the zero vector there.
        f = np.copysign(t / np.maximum(s, np.finfo(s.dtype).tiny), e[0], out=None if out is None else out[1])
        return v, f, t

    def _errors_chunked(self, q):
        """:meth:`errors` over blocks of :data:`ERRORS_CHUNK` edges: the same numbers, with
        temporaries that stay in cache instead of a dozen fresh (4, E) arrays (at 10^7 edges
        each product of fresh arrays cost 0.6 s, mostly page faults)."""
        E = self.n_edges
        ij, qrel = (self.ij, self.qrel) if self.single is None else self.single
        if self.single is not None:
            q = q.astype(np.float32)
        v, f, t = np.empty((3, E)), np.empty(E), np.empty(E)
        for a in range(0, E, ERRORS_CHUNK):
            b = min(a + ERRORS_CHUNK, E)
            self._errors(q, ij[a:b], ij[E + a : E + b], qrel[:, a:b], (v[:, a:b], f[a:b], t[a:b]))
        return v, f, t

    @property
    def information(self) -> np.ndarray | None:
        """The information matrices (E, 3, 3) as given, before :attr:`information_scale`
        (the graph's own array), or None."""
        return self._information

    def scaled_information(self) -> np.ndarray | None:
        """The information matrices times :attr:`information_scale` (E, 3, 3): a new array."""
        return None if self._information is None else self._information * self.information_scale

    def _information_rows(self, b: slice) -> np.ndarray:
        """The scaled information matrices of the edges ``b`` as rows (3, 3, len): a chunk of
        the layout of :func:`~rotgraph.so3.matmul_rows`, in double precision."""
        return np.multiply(np.moveaxis(self._information[b], 0, -1), self.information_scale)

    def isotropic(self, cap: bool = True) -> "EdgeSystem":
        """This system with each edge's information replaced by its isotropic part, ``p``
        times the identity (``p`` = trace / 3, :attr:`precision`), and (``cap``) ``p`` no larger
        than the median edge's: residual sizes ``sqrt(p) |r|`` and scalar weights ``p u`` in the
        Laplacian (:func:`~.irls.solve_weighted`). A view sharing the graph's arrays and the
        last errors; the robust stages that find the basin and the inliers run on it with the
        scalar Laplacian (one third of the unknowns' coupling, a tenth of the fill), the final
        ones on the 3x3 blocks. The cap: an edge's claim of more than typical precision is
        not trusted before the fit has told inliers from outliers (wrong edges of high
        information would set the basin; an edge of low precision weighs less, as it says:
        it cannot mislead)."""
        H, s = self._information, self.information_scale
        p = (H[:, 0, 0] * s + H[:, 1, 1] * s + H[:, 2, 2] * s) / 3.0
        view = copy.copy(self)
        view._information, view.precision = None, np.minimum(p, np.median(p), out=p) if cap else p
        view.last_angles = view.last_camera = (None, None)
        return view

    def forget(self) -> None:
        """Drop the residual sizes and camera-frame errors kept for the last rotations (a
        view whose stages are over: 320 MB at 10^7 edges)."""
        self.last_angles = self.last_camera = (None, None)

    def camera_errors(self, q: np.ndarray) -> np.ndarray:
        """``d = R_j r`` (3, E): each edge's residual rotation vector in camera j's frame, the
        frame of its information (kept for the last ``q``, as :meth:`errors`). ``r`` turned
        by ``q_j``: ``d = r + w c + u x c`` with ``c = 2 u x r``."""
        if q is self.last_camera[0]:
            return self.last_camera[1]
        v, f, t = self.errors(q)
        d = np.empty_like(v)
        for a in range(0, self.n_edges, ERRORS_CHUNK):  # temporaries that stay in cache, as _errors_chunked
            b = slice(a, a + ERRORS_CHUNK)
            r = v[:, b] * (2.0 * f[b])
            w, x, y, z = np.take(q, self.head_node[b], axis=1)
            c0, c1, c2 = 2.0 * (y * r[2] - z * r[1]), 2.0 * (z * r[0] - x * r[2]), 2.0 * (x * r[1] - y * r[0])
            d[0, b] = r[0] + w * c0 + (y * c2 - z * c1)
            d[1, b] = r[1] + w * c1 + (z * c0 - x * c2)
            d[2, b] = r[2] + w * c2 + (x * c1 - y * c0)
        self.last_camera = (q, d)
        return d

    def rotation_angles(self, q: np.ndarray) -> np.ndarray:
        """Each edge's residual rotation angle (E,) in radians, ``2 t`` of :meth:`errors`."""
        return 2.0 * self.errors(q)[2]

    def angles(self, q: np.ndarray) -> np.ndarray:
        """Each edge's residual size (E,) in radians: its rotation angle
        (:meth:`rotation_angles`), or, with information matrices, the Mahalanobis norm of the
        residual rotation vector (kept for the last ``q``, as :meth:`errors`: a stage's final
        sizes are the next stage's and the result's)."""
        if q is self.last_angles[0]:
            return self.last_angles[1]
        if self.information is None:
            out = self.rotation_angles(q)
            if self.precision is not None:
                out = out * np.sqrt(self.precision)
        else:
            d_all, out = self.camera_errors(q), np.empty(self.n_edges)
            for a in range(0, self.n_edges, ERRORS_CHUNK):
                b = slice(a, a + ERRORS_CHUNK)
                d, H = d_all[:, b], self._information_rows(b)
                quad = H[0, 0] * d[0] ** 2 + H[1, 1] * d[1] ** 2 + H[2, 2] * d[2] ** 2
                quad += 2.0 * (H[0, 1] * d[0] * d[1] + H[0, 2] * d[0] * d[2] + H[1, 2] * d[1] * d[2])
                np.sqrt(np.maximum(quad, 0.0), out=out[b])
        self.last_angles = (q, out)
        return out

    def rhs(self, v: np.ndarray) -> np.ndarray:
        """``A^T v`` (3, n): +v_e at the head of each edge, -v_e at its tail, 0 at the anchor."""
        # a bincount of each component by head and by tail (the index arrays of the errors: no
        # (3E,) index arrays of their own, 480 MB at 10^7 edges), the anchor's row zeroed
        E, n = self.n_edges, self.n
        out = np.empty((3, n))
        for k in range(3):
            np.subtract(np.bincount(self.ij[E:], v[k], n), np.bincount(self.ij[:E], v[k], n), out=out[k])
        out[:, self.anchor] = 0.0
        return out

    def gauss_newton_blocks(self, q: np.ndarray, u: np.ndarray, laplacian=None) -> tuple[np.ndarray | None, np.ndarray]:
        """``(U (3, 3, E) rows, y (3, E))``: each edge's Gauss-Newton block and half gradient for
        the whitened cost ``sum u_e d^T H d / 2`` at ``q`` (``U`` is overwritten by the next call). The camera-frame error is ``d = R_j r``
        (``r = log(R_j^T R_ij R_i)``) and ``R_i exp(w_i)``, ``R_j exp(w_j)`` move it by
        ``R_j J_r^-1(r) (w_i - w_j)``: in the world frame both ends see the same Jacobian
        ``M = R_j J``, ``J = J_r^-1(r)``, so ``U = u M^T H M`` and ``y = u M^T H d / 2``
        (``M r = R_j r = d``). That is ``u J^T G J`` with ``G = R_j^T H R_j`` the world-frame
        information, three 3x3 products an edge instead of four; the identity in place of ``J``
        would miss that ``G`` turns with ``R_j``, biasing the fixed point by ``O(|r|^2)`` and
        making it depend on each edge's direction.

        ``laplacian``: an :class:`~.laplacian.AnchoredBlockLaplacian` that takes the blocks as
        they are made (``write_blocks``, its sparse solvers): each chunk of blocks goes straight
        into its matrix, no ``U`` is kept (360 MB at 10^7 edges) and ``U`` is None (its
        ``solve(None, ...)`` solves with them)."""
        v, f, t = self.errors(q)
        d = self.camera_errors(q)
        # the rotations as rows of nine (n, 9): one gather of a row an edge, not nine strided ones
        R9 = so3_rows.matrix_rows(q).reshape(9, -1).T.copy()
        sink = laplacian if getattr(laplacian, "writes_blocks", False) else None
        U = None
        if sink is None:
            # one buffer for every call's blocks (the caller solves with them before the next
            # call): a fresh (3, 3, E) array is 720 MB of page faults a call at 10^7 edges;
            # single precision with the single-precision block Laplacian's (FLOAT32_MIN_EDGES)
            if self._blocks_buffer is None:
                dtype = np.float32 if self.n_edges >= FLOAT32_MIN_EDGES else np.float64
                self._blocks_buffer = np.empty((3, 3, self.n_edges), dtype=dtype)
            U = self._blocks_buffer
        y = np.empty((3, self.n_edges))
        # in blocks of edges whose 3x3 temporaries stay in cache (whole-array ones: five fresh
        # (3, 3, E) arrays a call, 3.6 GB and their page faults at 10^7 edges)
        for s in range(0, self.n_edges, so3_rows.MATMUL_ROWS_BLOCK):
            b = slice(s, s + so3_rows.MATMUL_ROWS_BLOCK)
            Rj = np.take(R9, self.head_node[b], axis=0).T.reshape(3, 3, -1)
            M = so3_rows.matmul_rows(Rj, so3_rows.right_jacobian_inverse_rows(v[:, b] * (2.0 * f[b])))
            HM = so3_rows.matmul_rows(self._information_rows(b), M)
            Ub = so3_rows.matmul_rows(M.transpose(1, 0, 2), HM)
            Ub *= u[b]
            if sink is None:
                U[:, :, b] = Ub
            else:
                sink.write_blocks(b, Ub)
            np.multiply((HM * d[:, None, b]).sum(axis=0), 0.5 * u[b], out=y[:, b])
        return U, y

    def update(self, q: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(q exp(2 x), |x|)`` for the half-updates ``x`` (n, 3): :func:`update_rotations`."""
        return update_rotations(q, x)


def update_rotations(q: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(q exp(2 x), |x|)``: the rotations ``q`` (4, n) after the half-updates ``x`` (n, 3) of
    a Laplacian solve (:class:`EdgeSystem`'s half-angle form), and each update's size."""
    h = np.sqrt(np.einsum("ek,ek->e", x, x))
    d = np.empty((4, len(h)))
    np.cos(h, out=d[0])
    np.multiply(x.T, np.sin(h) / np.maximum(h, 1e-300), out=d[1:])
    return so3_rows.qmul_rows(q, d), h
