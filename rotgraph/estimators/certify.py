"""A certificate of global optimality for chordal multiple rotation averaging.

The chordal cost of absolute rotations ``R_i`` (cam_from_world, rotgraph's convention,
``R_ij = R_j R_i^T`` on the edge ``(i, j)``) is

    f(R) = sum_e w_e |R_j - R_ij R_i|_F^2 .

It is not convex, and a local solver can stop at a critical point that is not the global
minimum. Lagrangian duality (Eriksson, Olsson, Kahl & Chin, "Rotation averaging and strong
duality", CVPR 2018 / TPAMI 2019; Rosen et al.'s SE-Sync; GTSAM's Shonan averaging) gives
a test of one candidate: if one symmetric matrix is positive semidefinite, no rotations
have a lower cost, whatever the noise.

Derivation, in rotgraph's convention
------------------------------------
Stack the rotations ``Y = [R_1; R_2; ...; R_n]`` (3n x 3, block row ``i`` is ``R_i``).
Each edge's term expands to ``|R_j|^2 + |R_ij R_i|^2 - 2 tr(R_j^T R_ij R_i)
= 6 - 2 tr(R_j^T R_ij R_i)``. Let ``W`` be the symmetric 3n x 3n matrix with

    block (j, i) = w_e R_ij,      block (i, j) = w_e R_ij^T      (summed over the edges),

zero diagonal blocks. Then ``tr(Y^T W Y) = sum_(a,b) tr(R_a^T W_ab R_b)`` holds each
edge twice, ``tr(R_j^T w R_ij R_i) + tr(R_i^T w R_ij^T R_j) = 2 w tr(R_j^T R_ij R_i)``, so

    f(Y) = 6 sum_e w_e - tr(Y^T W Y),

and minimising ``f`` is maximising ``tr(Y^T W Y)`` subject to ``R_i R_i^T = I`` (and
``det R_i = 1``). The Lagrangian with symmetric multipliers ``Lambda_i`` for
``R_i R_i^T = I`` is ``tr(Y^T W Y) + sum_i tr(Lambda_i (I - R_i R_i^T))``; its gradient in
block row ``i`` vanishes when ``(W Y)_i = Lambda_i R_i``, so (``R_i^T`` on the *right* for
this ``W``)

    Lambda_i = sym((W Y)_i R_i^T),     M = blkdiag(Lambda_1, ..., Lambda_n) - W .

``Y`` is a first-order critical point of ``f`` on SO(3)^n iff every ``(W Y)_i R_i^T`` is
symmetric, i.e. iff ``M Y = 0`` (block row ``i`` of ``M Y`` is ``-skew((W Y)_i R_i^T) R_i``).
For every ``Y``, ``Y^T M Y = 0`` and ``sum_i tr(Lambda_i) = tr(Y^T W Y)``.

Weak duality: for any symmetric ``Lambda'_i`` with ``blkdiag(Lambda') - W >= 0`` and any
rotations ``Y'``, ``tr(Y'^T W Y') <= tr(Y'^T blkdiag(Lambda') Y') = sum_i tr(Lambda'_i)``.
``Lambda'_i = Lambda_i + mu I`` with ``mu = max(0, -lambda_min(M))`` is always feasible, so

    f* >= dual_bound = 6 sum_e w_e - sum_i tr(Lambda_i) - 3 n mu ,

and ``duality_gap = f(Y) - dual_bound = 3 n mu`` (to rounding): when ``M`` is positive
semidefinite (``mu = 0``) the candidate is a global minimum. If ``M >= 0`` then
``tr(Y^T M Y) = 0`` forces ``M Y = 0``, so a candidate that is not critical always has a
negative eigenvalue (its direction mixes span(Y) and the gradient ``M Y``): the ground truth
of a noisy problem is never certified. At a critical point span(Y) is an invariant
subspace of ``M`` with the eigenvalue 0 (three times: the gauge), and ``lambda_min(M) =
min(0, lambda_complement)``, the smallest eigenvalue of ``M`` on the orthogonal complement
of span(Y). ``lambda_complement > 0`` is a strict certificate: the optimum is then also
unique up to the gauge (the semidefinite relaxation has the rank-3 solution ``Y Y^T`` only).

This is GTSAM's matrix: ``ShonanAveraging3`` with measurements ``wRi^T wRj = R_ij^T`` on
keys ``(i, j)``, its ``Stiefel`` element ``S = [wR_1 ... wR_n] = Y^T`` (``wR_i = R_i^T``),
builds ``Q_`` with block ``(i, j) = kappa R_ij^T`` (``= W``, ``kappa = 1 / sigma^2`` of an
isotropic noise model), ``Lambda_j = sym((Q S^T)_j S_j)`` (``= sym((W Y)_j R_j^T)``) and
``A = Lambda - Q`` (``= M``); ``checkOptimality`` is ``lambda_min(A) > -1e-4`` (its
``optimalityThreshold``), computed by Lanczos to an absolute precision of 1e-3. Checked
entry by entry in ``tests/test_certify.py``.

Normalisation
-------------
The weights are divided by their median (over the edges certified): with unit weights
``M`` is GTSAM's ``A`` for ``sigma = 1`` exactly, and the tolerance (default 1e-4, GTSAM's)
means the same in both; with weights, it is GTSAM's for ``kappa_e = w_e / median(w)``.
``primal_cost``, ``dual_bound`` and ``duality_gap`` are in the same normalisation
(``Certificate.weight_scale`` is the median divided out). The verdict is the bound's:
``lambda_min(M) >= -tol``, i.e. ``duality_gap <= 3 n tol``: the rotations are within that of
the global minimum, whatever they are (GTSAM's ``checkOptimality`` on the same matrix). The
reason says whether they are also a first-order critical point:
``stationarity = max_i |vee(skew((W Y)_i R_i^T))| / d_i = max_i |(M Y)_i|_F / (sqrt(2)
d_i)`` (``d_i`` the node's weighted degree) below ``stationarity_tol`` (default 1e-6; for
a node whose neighbours agree that it is rotated by ``theta``, that is ``sin(theta)``: a
scale-free measure, in radians for small values), and then "a global minimum". (Until
2026-12 a point above it was refused: GTSAM Shonan's own optima at its default tolerances,
stationarity 1e-5 - 2e-2, within 1e-9 - 2e-2 relative of the bound. A relative gap does
not tell GTSAM's verdict: on 216 candidates of a sweep, Shonan's optima, ground truths and
perturbed optima of n = 50-800, GTSAM certified relative gaps up to 1.9e-2 and refused some
of 3e-4, where ``gap / n`` separates them, 3.1e-4 against 1.2e-3 and above.)

Computing lambda_min
--------------------
Dense (LAPACK) for small problems, otherwise a lean LOBPCG on the matrix-free ``M``,
deflated of span(Y) at a critical point: :mod:`rotgraph.estimators.certify_eigen`, whose
docstring tells how and what it costs.

What is certified: the weighted chordal L2 problem on the edges given (``inliers``: on
those only, e.g. the fixed point of a robust solve). Per-edge information matrices have no
place in it (only scalar weights); rotations with NaN entries (unsolved cameras) and their
edges are left out. Several connected components are certified one by one (each has its
own gauge); the verdict is that of all.

Elsewhere: :mod:`rotgraph.estimators.staircase`, the local solver of the chordal cost
(:func:`~rotgraph.estimators.staircase.refine_chordal`, which turns the answer of any other
method into a critical point that can be certified) and the Riemannian staircase
(:func:`~rotgraph.estimators.staircase.certified_chordal`, which escapes a failed
certificate). Besides the API of ``__all__``, this module's :class:`ChordalProblem`,
:func:`chordal_problem`, :func:`component_edges`, :class:`ChordalGraph` and
:func:`certify_problem` are public for that module.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field

import numpy as np

from .. import so3_checks
from ..options import Options, check_choice, check_fields, resolve_options
from ..graph_analysis import connected_components
from .certify_eigen import DENSE_MAX, MAX_ITERATIONS, smallest_eigen

__all__ = [
    "DEFAULT_TOL",
    "DENSE_MAX",
    "STATIONARITY_TOL",
    "Certificate",
    "CertifyOptions",
    "certify",
    "certify_graph",
    "chordal_cost",
]

#: GTSAM's ``ShonanAveragingParameters::optimalityThreshold`` is -1e-4: ``lambda_min(M) >= -DEFAULT_TOL``.
DEFAULT_TOL = 1e-4
#: A candidate is a critical point when its stationarity (module docstring) is below this.
STATIONARITY_TOL = 1e-6


@dataclass(frozen=True)
class CertifyOptions(Options):
    """The tolerances and eigen-solver of :func:`certify` (global optimality of the chordal
    cost); frozen, :meth:`~rotgraph.options.Options.validated` by :func:`certify`. The
    tolerances are on the eigenvalues and gradients of the chordal cost with weights divided
    by their median: dimensionless, no angles.

    Parameters
    ----------
    tol : float or None, default None
        The eigenvalue tolerance (>= 0): certified when ``lambda_min >= -tol``. None:
        :data:`DEFAULT_TOL` (GTSAM's).
    stationarity_tol : float or None, default None
        The first-order tolerance (>= 0): a critical point when the stationarity is below
        it. None: :data:`STATIONARITY_TOL`.
    method : str, default "auto"
        The eigen-solver: ``"auto"`` (dense up to :data:`DENSE_MAX` unknowns, else LOBPCG),
        ``"dense"`` or ``"lobpcg"``.
    seed : int, default 0
        Seed of LOBPCG's random start.
    max_iterations : int, default 1000
        Cap of LOBPCG's iterations (>= 0).
    gap_tol : float or None, default None
        Also certify rotations whose duality gap is at most this fraction of their cost
        (``relative_gap <= gap_tol``, >= 0: proven that close to the global minimum) when
        the eigenvalue test fails. None: the eigenvalue test alone (GTSAM's verdict; a
        relative gap does not tell it, see the module docstring).
    """

    tol: float | None = None  # eigenvalue tolerance; None: DEFAULT_TOL
    stationarity_tol: float | None = None  # first-order tolerance; None: STATIONARITY_TOL
    method: str = "auto"  # auto, dense or lobpcg
    seed: int = 0  # LOBPCG's random start
    max_iterations: int = MAX_ITERATIONS  # of LOBPCG
    gap_tol: float | None = None  # certify within this relative duality gap too; None: never

    def check(self) -> None:
        """An unknown method, a negative tolerance or ``max_iterations``:
        :class:`~rotgraph.errors.OptionError`."""
        check_choice("method", self.method, ("auto", "dense", "lobpcg"))
        check_fields(self, ("tol", "stationarity_tol", "gap_tol", "max_iterations"), lambda v: v >= 0, ">= 0")


@dataclass(frozen=True)
class Certificate:
    """The verdict of :func:`certify` on one candidate (see the module docstring).

    ``certified``: globally optimal for the weighted chordal cost (``lambda_min >=
    -tolerance`` at a critical point). ``lambda_min``: the smallest eigenvalue of ``M``
    (GTSAM's ``computeMinEigenValue``; ~0 when certified: the gauge). ``lambda_complement``:
    the smallest on the complement of span(Y) (only at a critical point, else NaN); > 0 a
    strict certificate. ``primal_cost`` the chordal cost of the candidate, ``dual_bound`` a
    lower bound of every rotations' cost (valid whatever the verdict), ``duality_gap`` their
    difference (``3 n max(0, -lambda_min)``), all with the weights divided by
    ``weight_scale``. ``stationarity``: the first-order residual (sine of the largest
    rotation a node's neighbours ask for). ``reason``: one sentence, starting with
    ``certified``, ``not critical``, ``negative eigenvalue`` or (LOBPCG did not converge)
    ``undecided``. ``method``: ``dense eigvalsh``, ``lobpcg`` or ``lobpcg (graph-Laplacian
    preconditioner)`` (several, joined by ``+``, over components); ``eigen_iterations`` and
    ``eigen_residual`` those of LOBPCG (summed / the largest over components).

    Attributes
    ----------
    certified : bool
        Globally optimal for the weighted chordal cost.
    lambda_min : float
        The smallest eigenvalue of the certificate matrix ``M``.
    tolerance : float
        The eigenvalue tolerance used.
    duality_gap : float
        ``primal_cost - dual_bound`` (``3 n max(0, -lambda_min)``).
    primal_cost : float
        The chordal cost of the candidate.
    dual_bound : float
        A lower bound of every rotations' chordal cost.
    stationarity : float
        The first-order residual (sine of the largest rotation a node's neighbours ask for).
    stationarity_tolerance : float
        The stationarity tolerance used.
    lambda_complement : float
        The smallest eigenvalue on the complement of span(Y) (NaN unless critical).
    seconds : float
        Wall time.
    method : str
        The eigen-solver(s) used.
    reason : str
        One sentence: why the verdict.
    n_nodes, n_edges, n_components : int
        Size of the problem certified (cameras, edges and components used).
    weight_scale : float
        The median weight divided out of the costs.
    eigen_iterations : int
        LOBPCG iterations (summed over components).
    eigen_residual : float
        LOBPCG's residual (the largest over components).
    gap_tolerance : float
        The relative-gap tolerance asked for (``certify(gap_tol=...)``), NaN when none.
    """

    certified: bool
    lambda_min: float
    tolerance: float
    duality_gap: float
    primal_cost: float
    dual_bound: float
    stationarity: float
    stationarity_tolerance: float
    lambda_complement: float
    seconds: float
    method: str
    reason: str
    n_nodes: int
    n_edges: int
    n_components: int
    weight_scale: float
    eigen_iterations: int = 0
    eigen_residual: float = 0.0
    gap_tolerance: float = float("nan")

    @property
    def relative_gap(self) -> float:
        """``duality_gap / primal_cost`` (0 when both are 0)."""
        return self.duality_gap / self.primal_cost if self.primal_cost > 0 else 0.0

    def to_dict(self) -> dict:
        """Plain JSON types (NaN becomes None)."""
        out = {}
        for k, v in asdict(self).items():
            if isinstance(v, (bool, np.bool_)):
                out[k] = bool(v)
            elif isinstance(v, (int, np.integer)):
                out[k] = int(v)
            elif isinstance(v, (float, np.floating)):
                out[k] = float(v) if np.isfinite(v) else None
            else:
                out[k] = v
        out["relative_gap"] = float(self.relative_gap)
        return out


# --------------------------------------------------------------------------- the problem


@dataclass
class ChordalProblem:
    """The edges certified, nodes renumbered 0..n-1 (only those with an edge), unit-median weights."""

    n: int
    i: np.ndarray
    j: np.ndarray
    rel: np.ndarray
    w: np.ndarray
    R: np.ndarray
    nodes: np.ndarray  # original index of each node
    edge_index: np.ndarray  # original index of each edge
    weight_scale: float
    components: list = field(default_factory=list)  # node index arrays, one per connected component


def chordal_problem(cam_from_world, edges, cam2_from_cam1, weights, inliers) -> ChordalProblem:
    """The :class:`ChordalProblem` of :func:`certify`'s arguments: the shapes checked, edges of
    weight 0 or NaN, self-loops, masked out by ``inliers`` or touching a NaN row left out,
    rows not orthonormal to 1e-9 projected onto SO(3), its connected components found."""
    R = np.asarray(cam_from_world, dtype=np.float64)
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    rel = np.asarray(cam2_from_cam1, dtype=np.float64)
    E = len(edges)
    if R.ndim != 3 or R.shape[1:] != (3, 3):
        raise ValueError(f"cam_from_world must be (N, 3, 3), got {R.shape}")
    if rel.shape != (E, 3, 3):
        raise ValueError(f"cam2_from_cam1 must be ({E}, 3, 3), got {rel.shape}")
    if E and (edges.min() < 0 or edges.max() >= len(R)):
        raise ValueError("edges refer to nodes outside cam_from_world")
    if weights is not None and np.ndim(weights) != 1:
        raise ValueError("the certificate takes scalar edge weights (E,) only: per-edge information "
                         "matrices have no place in the chordal cost")
    w = np.ones(E) if weights is None else np.asarray(weights, dtype=np.float64)
    if w.shape != (E,):
        raise ValueError(f"weights must be ({E},), got {w.shape}")
    keep = np.isfinite(w) & (w > 0) & (edges[:, 0] != edges[:, 1])
    if inliers is not None:
        inl = np.asarray(inliers, dtype=bool).reshape(-1)
        if inl.shape != (E,):
            raise ValueError(f"inliers must be ({E},), got {inl.shape}")
        keep &= inl
    solved = np.isfinite(R).all(axis=(1, 2))
    keep &= solved[edges[:, 0]] & solved[edges[:, 1]]
    keep &= np.isfinite(rel).all(axis=(1, 2))
    eidx = np.flatnonzero(keep)
    if len(eidx) == 0:
        raise ValueError("no edge to certify (every edge is masked out, or touches an unsolved camera)")
    used = np.zeros(len(R), dtype=bool)
    used[edges[eidx].ravel()] = True
    nodes = np.flatnonzero(used)
    index = np.cumsum(used) - 1
    i, j = index[edges[eidx, 0]], index[edges[eidx, 1]]
    w = w[eidx]
    scale = float(np.median(w))
    Rn = R[nodes]
    if not so3_checks.is_rotation(Rn, 1e-9).all():
        Rn = so3_checks.project_to_so3(Rn)
    n = len(nodes)
    k, labels = connected_components(n, np.stack([i, j], axis=1))
    order = np.argsort(labels, kind="stable")
    comps = np.split(order, np.cumsum(np.bincount(labels, minlength=k))[:-1])
    return ChordalProblem(n, i, j, rel[eidx], w / scale, Rn, nodes, eidx, scale, comps)


def component_edges(p: ChordalProblem, comp: np.ndarray):
    """``(i, j, rel, w)`` of the edges of one component, its nodes renumbered 0..len(comp)-1."""
    if len(p.components) == 1:
        return p.i, p.j, p.rel, p.w
    index = np.full(p.n, -1)
    index[comp] = np.arange(len(comp))
    mask = index[p.i] >= 0
    return index[p.i[mask]], index[p.j[mask]], p.rel[mask], p.w[mask]


class ChordalGraph:
    """One connected component: ``W`` (block-sparse, 3x3 blocks: one index per block, a
    quarter faster to multiply than CSR here; parallel edges are repeated blocks, which the
    product adds up), the weighted degrees, and the maps of the derivation on stacked
    rotations ``Y`` (n, 3, p) (``p = 3``: rotations; ``p > 3``: the rank-lifted problem,
    rows of each block orthonormal)."""

    def __init__(self, n: int, i: np.ndarray, j: np.ndarray, rel: np.ndarray, w: np.ndarray):
        import scipy.sparse as sp

        self.n, self.i, self.j, self.rel, self.w = n, i, j, rel, w
        E = len(i)
        rows = np.concatenate([j, i])
        cols = np.concatenate([i, j])
        order = np.argsort(rows)  # any order within a row: quicksort, 2-3x faster than stable
        data = np.empty((2 * E, 3, 3))
        np.multiply(w[:, None, None], rel, out=data[:E])
        data[E:] = np.swapaxes(data[:E], 1, 2)
        indptr = np.zeros(n + 1, dtype=np.int64)
        np.cumsum(np.bincount(rows, minlength=n), out=indptr[1:])
        self.W = sp.bsr_matrix((data[order], cols[order], indptr), shape=(3 * n, 3 * n))
        self.degree = np.bincount(i, w, n) + np.bincount(j, w, n)
        self.total_weight = float(w.sum())

    def WY(self, Y: np.ndarray) -> np.ndarray:
        """``W Y`` (n, 3, p)."""
        p = Y.shape[2]
        return (self.W @ Y.reshape(3 * self.n, p)).reshape(self.n, 3, p)

    @staticmethod
    def multipliers(Y: np.ndarray, G: np.ndarray) -> np.ndarray:
        """``Lambda_i = sym(G_i Y_i^T)`` (n, 3, 3), ``G = W Y``."""
        GY = G @ np.swapaxes(Y, 1, 2)
        return 0.5 * (GY + np.swapaxes(GY, 1, 2))

    def M_times(self, Lam: np.ndarray, X: np.ndarray) -> np.ndarray:
        """``M X = blkdiag(Lambda) X - W X`` for X (3n, k)."""
        k = X.shape[1]
        return (Lam @ X.reshape(self.n, 3, k)).reshape(3 * self.n, k) - self.W @ X

    def M_dense(self, Lam: np.ndarray) -> np.ndarray:
        A = -self.W.toarray()
        for a in range(3):
            for b in range(3):
                A[3 * np.arange(self.n) + a, 3 * np.arange(self.n) + b] += Lam[:, a, b]
        return A

    def gradient_residual(self, Y: np.ndarray, G: np.ndarray, Lam: np.ndarray) -> np.ndarray:
        """``(M Y)_i = Lambda_i Y_i - G_i`` (n, 3, p): minus half the Riemannian gradient of
        ``tr(Y^T W Y)``; for ``p = 3`` it is ``-skew(G_i R_i^T) R_i``."""
        return Lam @ Y - G

    def stationarity(self, Y: np.ndarray, G: np.ndarray, Lam: np.ndarray) -> float:
        """``max_i |(M Y)_i|_F / (sqrt(2) d_i)`` (= ``|vee(skew(G_i R_i^T))| / d_i`` at p = 3)."""
        r = self.gradient_residual(Y, G, Lam).reshape(self.n, -1)
        return float((np.sqrt(np.einsum("ij,ij->i", r, r)) / (np.sqrt(2.0) * self.degree)).max())

    def cost(self, Y: np.ndarray) -> float:
        """``sum_e w_e |Y_j - R_ij Y_i|_F^2``."""
        D = Y[self.j] - self.rel @ Y[self.i]
        return float(self.w @ np.einsum("eab,eab->e", D, D))


def chordal_cost(cam_from_world, edges, cam2_from_cam1, weights=None) -> float:
    """``sum_e w_e |R_j - R_ij R_i|_F^2`` (edges with an unsolved end left out; weights as given)."""
    R = np.asarray(cam_from_world, dtype=np.float64)
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    D = R[edges[:, 1]] - np.asarray(cam2_from_cam1, dtype=np.float64) @ R[edges[:, 0]]
    v = np.einsum("eab,eab->e", D, D)
    w = np.ones(len(edges)) if weights is None else np.asarray(weights, dtype=np.float64)
    ok = np.isfinite(v)
    return float(w[ok] @ v[ok])


# --------------------------------------------------------------------------- certify


def certify(
    cam_from_world,
    edges,
    cam2_from_cam1,
    weights=None,
    options: CertifyOptions | None = None,
    *,
    inliers=None,
    **overrides,
) -> Certificate:
    """Whether ``cam_from_world`` (N, 3, 3) is a global minimum of the weighted chordal cost
    ``sum_e w_e |R_j - R_ij R_i|_F^2`` on ``edges`` (E, 2) with ``cam2_from_cam1`` (E, 3, 3).

    ``weights`` (E,) scalar (default 1; divided by their median; edges of weight 0 left
    out); ``inliers`` (E,) bool: certify the problem on those edges only. Rows of
    ``cam_from_world`` with NaN (unsolved cameras) and their edges are left out; rows not
    orthonormal to 1e-9 are projected onto SO(3) first. ``options`` (or keyword overrides
    of its fields, as ``average_rotations(graph, options, **overrides)`` takes them): the
    tolerances and the eigen-solver, :class:`CertifyOptions`. See the module docstring for
    the mathematics and :class:`Certificate` for the result.

    Parameters
    ----------
    cam_from_world : (N, 3, 3) float64 array_like
        The candidate absolute rotations (world-to-camera), NaN rows for unsolved cameras.
    edges : (E, 2) array_like of int
        Node indices ``(i, j)`` of each edge.
    cam2_from_cam1 : (E, 3, 3) float64 array_like
        The relative rotation of each edge, ``R_ij = R_j R_i^T``.
    weights : (E,) float64 array_like, optional
        Scalar edge weights (default 1; divided by their median; 0: edge left out).
    options : CertifyOptions, optional
        Tolerances and eigen-solver; default ``CertifyOptions()``.
    inliers : (E,) bool array_like, optional
        Certify the problem on these edges only.
    **overrides
        Fields of :class:`CertifyOptions` that replace those of ``options`` (``tol=``,
        ``stationarity_tol=``, ``method=``, ``seed=``, ``max_iterations=``, ``gap_tol=``).

    Returns
    -------
    Certificate
        The verdict and its numbers.

    Raises
    ------
    OptionError
        A bad ``method`` or a negative tolerance (also a ``ValueError``);
        :class:`~rotgraph.errors.UnknownOptionError` (also a ``TypeError``) for a keyword
        that is no field of :class:`CertifyOptions`.
    ValueError
        Arrays of the wrong shapes, or no edge left to certify.
    """
    t0 = time.perf_counter()
    opts = resolve_options(CertifyOptions, options, overrides)
    tol = DEFAULT_TOL if opts.tol is None else float(opts.tol)
    stol = STATIONARITY_TOL if opts.stationarity_tol is None else float(opts.stationarity_tol)
    p = chordal_problem(cam_from_world, edges, cam2_from_cam1, weights, inliers)
    return certify_problem(p, tol, stol, opts.method, opts.seed, opts.max_iterations, t0, gap_tol=opts.gap_tol)[0]


def certify_problem(p: ChordalProblem, tol, stol, method, seed, max_iterations, t0, R=None, gap_tol=None):
    """:func:`certify` of a prepared problem (rotations ``R``, default ``p.R``); also returns
    the per-component ``(comp, graph, eigen)``."""
    R = p.R if R is None else R
    rng = np.random.default_rng(seed)
    parts, stationarity, trace = [], 0.0, 0.0
    for comp in p.components:
        g = ChordalGraph(len(comp), *component_edges(p, comp))
        Y = R[comp]
        G = g.WY(Y)
        Lam = g.multipliers(Y, G)
        stationarity = max(stationarity, g.stationarity(Y, G, Lam))
        trace += float(np.trace(Lam, axis1=1, axis2=2).sum())
        parts.append((comp, g, Y, Lam))
    critical = stationarity <= stol
    lam_min, lam_c, iterations, residual, converged, hows, out = np.inf, np.inf, 0, 0.0, True, set(), []
    for comp, g, Y, Lam in parts:
        e = smallest_eigen(g, Y, Lam, critical, tol, method, rng, max_iterations)
        lam_min, lam_c = min(lam_min, e.lam_min), min(lam_c, e.lam_complement)
        iterations += e.iterations
        residual = max(residual, e.residual)
        converged &= e.converged
        hows.add(e.how)
        out.append((comp, g, e))
    if not critical:
        lam_c = float("nan")
    mu = max(0.0, -lam_min)
    primal = sum(g.cost(R[comp]) for comp, g, _ in out)
    dual = 6.0 * float(p.w.sum()) - trace - 3.0 * p.n * mu
    gap = primal - dual
    relative = gap / primal if primal > 0 else 0.0
    if lam_min < -tol and converged and gap_tol is not None and relative <= gap_tol:
        certified = True
        reason = (f"certified: within {gap:.3g} ({relative:.3g} relative <= gap tolerance {gap_tol:.3g}) of the global "
                  f"minimum of the chordal cost (lambda_min {lam_min:.3g} < -{tol:.3g}: not by the eigenvalue test)")
    elif not critical and lam_min < -tol:
        certified = False
        reason = (f"not critical: stationarity {stationarity:.3g} > {stol:.3g}, not a first-order critical point of "
                  f"the chordal cost, and lambda_min {lam_min:.3g} < -{tol:.3g}: up to {gap:.3g} ({relative:.3g} relative) "
                  "above the global minimum; refine it first: on the command line 'rotgraph solve INPUT -o OUTPUT "
                  "--certify' (refines, then certifies), in Python rotgraph.refine_chordal")
    elif not critical and converged:
        # The bound holds for any rotations: lambda_min >= -tol puts them within 3 n tol of the global minimum,
        # GTSAM's checkOptimality verdict on the same matrix (a solution another solver returned at its own
        # tolerance is near-critical: certified by the bound, not refused for its gradient)
        certified = True
        reason = (f"certified: within {gap:.3g} ({relative:.3g} relative) of the global minimum of the chordal cost "
                  f"(lambda_min {lam_min:.3g} >= -{tol:.3g}); not a critical point (stationarity {stationarity:.3g} > "
                  f"{stol:.3g}): rotgraph.refine_chordal takes it to one")
    elif lam_min < -tol:
        certified = False
        reason = (f"negative eigenvalue: lambda_min {lam_min:.3g} < -{tol:.3g} at a critical point, not certified "
                  f"(a local minimum or saddle, or the relaxation is not tight); duality gap {gap:.3g}")
    elif not converged:
        certified = False
        reason = (f"undecided: LOBPCG did not converge in {max_iterations} iterations (smallest Ritz value "
                  f"{lam_c:.3g}, residual {residual:.3g}): no negative eigenvalue found, none ruled out")
    else:
        certified = True
        reason = (f"certified: a global minimum of the chordal cost (lambda_min {lam_min:.3g} >= -{tol:.3g}, "
                  f"duality gap {gap:.3g}, smallest eigenvalue beyond the gauge {lam_c:.3g})")
    cert = Certificate(
        certified=bool(certified),
        lambda_min=float(lam_min),
        tolerance=tol,
        duality_gap=float(gap),
        primal_cost=float(primal),
        dual_bound=float(dual),
        stationarity=float(stationarity),
        stationarity_tolerance=stol,
        lambda_complement=float(lam_c),
        seconds=time.perf_counter() - t0,
        method=" + ".join(sorted(hows)),
        reason=reason,
        n_nodes=p.n,
        n_edges=len(p.i),
        n_components=len(p.components),
        weight_scale=p.weight_scale,
        eigen_iterations=int(iterations),
        eigen_residual=float(residual),
        gap_tolerance=float("nan") if gap_tol is None else float(gap_tol),
    )
    return cert, out


def certify_graph(graph, cam_from_world, *, inliers=None, use_weights: bool = False, **kwargs) -> Certificate:
    """:func:`certify` on a :class:`~rotgraph.viewgraph.ViewGraph`: its edges and relative
    rotations, its weights when ``use_weights`` (as ``SolveOptions.use_weights``), else unit
    weights; ``inliers`` e.g. ``AveragingResult.inliers``. Information matrices are ignored."""
    return certify(cam_from_world, graph.edges, graph.cam2_from_cam1, graph.weights if use_weights else None,
                   inliers=inliers, **kwargs)
