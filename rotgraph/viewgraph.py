"""The view graph: cameras (nodes) and relative rotations (edges).

A :class:`ViewGraph` holds plain arrays, the layout the solvers use:

* ``node_ids`` (n,): the external id of each camera (int or str), row ``i`` is node ``i``;
* ``names`` (n,) or None: image names, when the input has them;
* ``edges`` (E, 2) int64: node indices ``(i, j)``;
* ``cam2_from_cam1`` (E, 3, 3): ``R_ij = R_j R_i^T`` (readers of quaternions hold them as
  :class:`QuaternionRotations`; the matrices are made on first access,
  :meth:`ViewGraph.relative_quaternion_rows` gives the quaternions either way);
* ``weights`` (E,) float: confidence (e.g. inlier count), 1 when unknown;
* ``gt_cam_from_world`` (n, 3, 3) or None: ground truth, when the input carries it;
* ``initial_cam_from_world`` (n, 3, 3) or None: an initial guess carried by the input
  (g2o ``VERTEX_SE3:QUAT`` lines: dead-reckoned odometry), never ground truth; the
  iterative solvers start from it with ``init="vertices"``;
* ``information`` (E, 3, 3) or None: each edge's rotation information (precision) matrix
  ``H_ij``, symmetric positive definite, in the **perturbation convention of rotgraph**:
  ``R_ij,measured = exp([d]x) R_ij`` with ``d ~ N(0, H_ij^-1)`` (radians), i.e. ``d`` is
  an error in the frame of camera ``j``. None: isotropic, every edge equal up to its weight;
* ``gravity`` or None: per-image gravity priors (:class:`~rotgraph.priors.GravityPriors`),
  which the solve then uses (:meth:`ViewGraph.with_gravity`).

The per-camera arrays have NaN rows for cameras without a value, and follow the nodes
through :meth:`ViewGraph.subgraph` and the duplicate policies.

Users who want graph analysis get a networkx graph from :meth:`ViewGraph.to_networkx`;
the hot paths (components, degrees, spanning trees) use ``scipy.sparse.csgraph``.

Duplicates and self-loops are never silently resolved: ``duplicates="error"`` (the
default) raises; ``"merge"`` replaces the edges of one unordered pair by one edge whose
rotation is their weighted chordal L2 mean and whose weight is their sum; ``"keep"`` keeps
parallel edges (legitimate in pose graphs: each is one more measurement).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from . import so3
from .choices import DUPLICATE_POLICIES
from .errors import InputError, OptionError
from .priors import GravityPriors

__all__ = ["ViewGraph", "Rigs", "QuaternionRotations", "check_information", "connected_components", "cycle_errors",
           "cycle_statistics"]

logger = logging.getLogger(__name__)



def connected_components(n: int, edges) -> tuple[int, np.ndarray]:
    """The connected components of the undirected graph on nodes ``0..n-1`` with ``edges``
    ``(E, 2)`` (parallel edges and self-loops allowed): ``(k, labels)``, ``labels`` (n,) in
    ``0..k-1`` numbered in the order of each component's smallest node (scipy's numbering).

    The one home of this computation: the view graph's components, the estimators' (rows of
    a problem, the gravity edges, a sparsified start graph), the rig file's rigs and the
    pose graph of ``reconstruct`` all call it.
    """
    e = np.asarray(edges).reshape(-1, 2)
    if n == 0:
        return 0, np.zeros(0, dtype=np.int64)
    if n <= 64:
        # Small graphs: reachability by squaring the reflexive adjacency matrix (cheaper
        # than building a sparse matrix); components numbered by their smallest node.
        A = np.eye(n)
        A[e[:, 0], e[:, 1]] = 1.0
        A[e[:, 1], e[:, 0]] = 1.0
        while True:
            B = np.minimum(A @ A, 1.0)
            if (B == A).all():
                break
            A = B
        first = A.argmax(axis=1)  # the smallest node reached
        root = first == np.arange(n)
        return int(root.sum()), (np.cumsum(root) - 1)[first]
    # One triangle is enough: undirected search follows stored entries both ways.
    import scipy.sparse as sp
    from scipy.sparse import csgraph

    A = sp.csr_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    k, labels = csgraph.connected_components(A, directed=False)
    return int(k), labels


def _plural(k: int, word: str) -> str:
    return f"{k} {word}" + ("" if k == 1 else "s")


def _show(x) -> str:
    """An id for a message: ``7`` or ``'img.jpg'``, not ``np.int64(7)`` (numpy 2 reprs)."""
    return repr(x.item() if isinstance(x, np.generic) else x)


@dataclass
class Rigs:
    """Which images were taken together by one rig (COLMAP 4's rigs and frames).

    Per node: ``frame_ids`` (n,) int64, the frame (one capture of the rig) the image belongs
    to, and ``cam_from_rig`` (n, 3, 3), the rotation of its sensor in the rig (identity for
    the rig's reference sensor, NaN rows when unknown). An image's rotation is
    ``cam_from_world = cam_from_rig @ rig_from_world`` of its frame.

    Optional, for the solve of unknown extrinsics (``estimators/rig_calibration.py``):
    ``sensor_ids`` (n,) int64, the sensor that took the image (a key unique across rigs:
    every image of one sensor shares its ``cam_from_rig``; -1: none), and ``is_reference``
    (n,) bool, the image's sensor is its rig's reference (``cam_from_rig`` the identity by
    definition). Without ``sensor_ids``, an image with unknown ``cam_from_rig`` is a frame of
    its own.
    """

    frame_ids: np.ndarray
    cam_from_rig: np.ndarray
    sensor_ids: np.ndarray | None = None
    is_reference: np.ndarray | None = None

    def __post_init__(self):
        self.frame_ids = np.asarray(self.frame_ids, dtype=np.int64)
        self.cam_from_rig = np.asarray(self.cam_from_rig, dtype=np.float64)
        n = len(self.frame_ids)
        if self.frame_ids.shape != (n,) or self.cam_from_rig.shape != (n, 3, 3):
            raise ValueError(f"expected (n,) frame ids and (n,3,3) cam_from_rig, got {self.frame_ids.shape} and {self.cam_from_rig.shape}")
        if self.sensor_ids is not None:
            self.sensor_ids = np.asarray(self.sensor_ids, dtype=np.int64)
            ref = np.zeros(n, dtype=bool) if self.is_reference is None else np.asarray(self.is_reference, dtype=bool)
            self.is_reference = ref
            if self.sensor_ids.shape != (n,) or ref.shape != (n,):
                raise ValueError(f"expected (n,) sensor ids and reference flags, got {self.sensor_ids.shape} and {ref.shape}")
        elif self.is_reference is not None:
            raise ValueError("is_reference needs sensor_ids")

    def subset(self, nodes: np.ndarray) -> "Rigs":
        if self.sensor_ids is None:
            return Rigs(self.frame_ids[nodes], self.cam_from_rig[nodes])
        return Rigs(self.frame_ids[nodes], self.cam_from_rig[nodes], self.sensor_ids[nodes], self.is_reference[nodes])


class QuaternionRotations:
    """Relative rotations held as unit quaternion rows ``(4, E)`` (``w >= 0``) until someone
    asks for the matrices: a reader of quaternions (10^7 edges) hands them to the solver
    without making, page-faulting and converting back 720 MB of matrices. ``rows`` must be
    unit quaternions (the reader checked and normalised them); the object takes them over
    (their signs are made ``w >= 0`` in place: no second (4, E) array)."""

    __slots__ = ("rows",)

    def __init__(self, rows: np.ndarray):
        rows = np.asarray(rows, dtype=np.float64)
        so3.positive_w_rows(rows, out=rows)
        self.rows = rows

    @property
    def shape(self) -> tuple:
        return (self.rows.shape[1], 3, 3)

    def matrices(self) -> np.ndarray:
        return so3.matrices_from_quaternion_rows(self.rows)


class _RotationsOnDemand:
    """``ViewGraph.cam2_from_cam1``: an (E, 3, 3) array, made from :class:`QuaternionRotations`
    on first access (and kept: from then on the matrices are the graph's rotations)."""

    def __set_name__(self, owner, name):
        self.slot = "_" + name

    def __get__(self, obj, owner=None):
        if obj is None:  # no class-level default: the dataclass field stays required
            raise AttributeError(self.slot[1:])
        value = obj.__dict__[self.slot]
        if isinstance(value, QuaternionRotations):
            value = obj.__dict__[self.slot] = value.matrices()
        return value

    def __set__(self, obj, value):
        obj.__dict__[self.slot] = value


@dataclass
class ViewGraph:
    """Cameras and the relative rotations between them (see the module docstring).

    Build it with :meth:`from_edges` (which checks and canonicalises the input) rather than
    the constructor.

    Parameters
    ----------
    node_ids : (n,) ndarray
        The external id of each camera (int or str); node ``i`` is row ``i``.
    edges : (E, 2) int64 ndarray
        Node indices ``(i, j)`` of each edge.
    cam2_from_cam1 : (E, 3, 3) float64 ndarray or QuaternionRotations
        The relative rotation of each edge, ``R_ij = R_j R_i^T`` (COLMAP's
        ``cam2_from_cam1``), so ``R_j ~ R_ij R_i`` for absolute ``cam_from_world`` ``R``.
    weights : (E,) float64 ndarray
        Positive confidence of each edge (e.g. an inlier count), 1 when unknown.
    names : (n,) ndarray or None
        Image names, when the input has them.
    source_lines : (E,) ndarray or None
        The file line of each edge, for error messages.
    source_path : str or None
        The file the edges came from, for error messages.
    gt_cam_from_world : (n, 3, 3) float64 ndarray or None
        Ground-truth absolute rotations (world-to-camera), NaN rows for cameras without.
    meta : dict
        What the reader knew about the input (counts, paths), for reports; no solver reads it.
    rigs : Rigs or None
        Rig structure (frames, ``cam_from_rig``), when the input has rigs.
    format : str or None
        The file format read (e.g. ``"colmap"``); the pipeline chooses default options by it.
    initial_cam_from_world : (n, 3, 3) float64 ndarray or None
        An initial guess carried by the input (g2o vertices), NaN rows for cameras without
        one; never ground truth. Used by ``init="vertices"`` only.
    information : (E, 3, 3) float64 ndarray or None
        Each edge's rotation information matrix ``H_ij`` (radians^-2) in rotgraph's
        perturbation convention ``R_ij,measured = exp([d]x) R_ij``, ``d ~ N(0, H_ij^-1)``;
        None: isotropic.
    gravity : GravityPriors or None
        Per-image gravity priors (:meth:`with_gravity`); the solve uses them when present.
    """

    node_ids: np.ndarray
    edges: np.ndarray
    cam2_from_cam1: np.ndarray = _RotationsOnDemand()  # (E, 3, 3); may be given as QuaternionRotations
    weights: np.ndarray
    names: np.ndarray | None = None
    # Where each edge came from (file line numbers), for error messages; optional.
    source_lines: np.ndarray | None = None
    source_path: str | None = None
    # Ground-truth cam_from_world for some nodes, when the input carries it: (n, 3, 3) with
    # NaN rows for nodes without ground truth.
    gt_cam_from_world: np.ndarray | None = None
    # What the reader knew about the input, for reports (counts, paths); never read by a solver.
    meta: dict = field(default_factory=dict)
    # Rig structure (frames, cam_from_rig), when the input has rigs: the solver averages frames.
    rigs: Rigs | None = None
    # The file format read (e.g. "colmap"): the pipeline chooses its default options by it.
    format: str | None = None
    # An initial guess of cam_from_world carried by the input (g2o vertices: odometry), NOT
    # ground truth: (n, 3, 3), NaN rows for nodes without one. Used by init="vertices" only.
    initial_cam_from_world: np.ndarray | None = None
    # Per-edge rotation information matrices (E, 3, 3) (module docstring), or None.
    information: np.ndarray | None = None
    # Per-image gravity priors, or None: the solve is then its gravity variant.
    gravity: GravityPriors | None = None

    # ----------------------------------------------------------------- construction

    @classmethod
    def from_edges(
        cls,
        ids_i,
        ids_j,
        cam2_from_cam1,
        weights=None,
        *,
        node_ids=None,
        codes: bool = False,
        names=None,
        duplicates: str = "error",
        source_lines=None,
        source_path: str | None = None,
        information=None,
    ) -> "ViewGraph":
        """Build a graph from edge endpoint ids and relative rotations ``R_ij = R_j R_i^T``.

        ``ids_i``/``ids_j`` are external ids (ints or strings). ``node_ids`` fixes the node
        order (and may include cameras without edges); by default the sorted distinct ids.
        ``information`` (E, 3, 3): each edge's rotation information matrix (module docstring).

        The fast path of the readers (10^7 edges: ~1 s instead of ~12 s): with ``codes``,
        ``ids_i``/``ids_j`` are the edges' positions in ``node_ids`` (e.g. the inverse of
        ``np.unique``), so there are no ids to search (messages still name the ids); and
        ``cam2_from_cam1`` may be :class:`QuaternionRotations` (unit quaternions a reader
        checked, :func:`rotgraph.so3.check_quaternion_rows`), which the graph keeps as they
        are. The checks are the same on every path: positive finite weights, no self-loop,
        rotations, information, then ``duplicates``.
        """
        if duplicates not in DUPLICATE_POLICIES:
            raise OptionError(f"duplicates must be one of {DUPLICATE_POLICIES}, got {duplicates!r}")
        ids_i = np.asarray(ids_i)
        ids_j = np.asarray(ids_j)
        checked = isinstance(cam2_from_cam1, QuaternionRotations)
        rel = cam2_from_cam1 if checked else np.asarray(cam2_from_cam1, dtype=np.float64)
        m = len(ids_i)
        if ids_j.shape != (m,) or rel.shape != (m, 3, 3):
            raise InputError(f"expected (E,) ids and (E,3,3) rotations, got {ids_i.shape}, {ids_j.shape}, {rel.shape}")
        w = np.ones(m) if weights is None else np.asarray(weights, dtype=np.float64)
        lines = None if source_lines is None else np.asarray(source_lines)

        def where(k: int) -> dict:
            return {"path": source_path, "line": None if lines is None else int(lines[k])}

        if w.shape != (m,):
            raise InputError(f"expected ({m},) weights, got {w.shape}")
        bad = ~(np.isfinite(w) & (w > 0))
        if bad.any():
            k = int(np.argmax(bad))
            raise InputError(f"edge weight must be positive and finite, got {w[k]}", **where(k))
        if node_ids is None:
            if codes:
                raise OptionError("codes need the node_ids they are positions in")
            node_ids = np.unique(np.concatenate([ids_i, ids_j])) if m else np.array([], dtype=np.int64)
        node_ids = np.asarray(node_ids)
        if len(node_ids) > 1 and not (node_ids[1:] > node_ids[:-1]).all():  # not sorted distinct ids
            order = np.argsort(node_ids, kind="stable")
            sorted_ids = node_ids[order]
            if (sorted_ids[1:] == sorted_ids[:-1]).any():
                raise InputError("node ids are not unique")
        else:
            order, sorted_ids = None, node_ids
        if not m:
            edges = np.zeros((0, 2), np.int64)
        elif codes:
            edges = np.stack([ids_i, ids_j], axis=1).astype(np.int64, copy=False)
            if edges.min() < 0 or edges.max() >= len(node_ids):
                raise ValueError(f"codes must be positions in the {len(node_ids)} node_ids")
        else:
            pos_i = np.searchsorted(sorted_ids, ids_i)
            pos_j = np.searchsorted(sorted_ids, ids_j)
            for pos, ids in ((pos_i, ids_i), (pos_j, ids_j)):
                pos_c = np.minimum(pos, max(len(sorted_ids) - 1, 0))
                miss = (len(sorted_ids) == 0) | (sorted_ids[pos_c] != ids)
                if np.any(miss):
                    k = int(np.argmax(miss))
                    raise InputError(f"edge refers to unknown camera id {_show(ids[k])}", **where(k))
            edges = np.stack([pos_i, pos_j] if order is None else [order[pos_i], order[pos_j]], axis=1).astype(np.int64)

        loops = edges[:, 0] == edges[:, 1]
        if loops.any():
            k = int(np.argmax(loops))
            raise InputError(f"self-loop: edge from camera {_show(node_ids[ids_i[k]] if codes else ids_i[k])} to itself",
                             **where(k))
        if m and not checked:
            rel = so3.check_rotations(rel, path=source_path, lines=lines, label=lambda k: "relative rotation")

        info = None if information is None else check_information(information, m, source_path, lines)
        graph = cls(node_ids, edges, rel, w, None if names is None else np.asarray(names), lines, source_path, information=info)
        return graph._resolve_duplicates(duplicates)

    def _resolve_duplicates(self, policy: str) -> "ViewGraph":
        if self.n_edges == 0:
            return self
        key = np.minimum(self.edges[:, 0], self.edges[:, 1])
        key *= self.n_nodes
        key += np.maximum(self.edges[:, 0], self.edges[:, 1])
        sorted_key = np.sort(key)
        if not (sorted_key[1:] == sorted_key[:-1]).any():  # no pair twice: the common case, one sort
            return self
        del sorted_key
        uniq, first, inverse, counts = np.unique(key, return_index=True, return_inverse=True, return_counts=True)
        if policy == "keep":
            logger.info("kept %d parallel edges (%d distinct pairs)", self.n_edges - len(uniq), len(uniq))
            return self
        if policy == "error":
            dup = counts[inverse] > 1
            # the first edge whose pair came before (the first repeat, not a first occurrence)
            k = int(np.argmax(np.arange(self.n_edges) != first[inverse.ravel()]))
            a, b = self.node_ids[self.edges[k, 0]], self.node_ids[self.edges[k, 1]]
            raise InputError(
                f"duplicate pair ({_show(a)}, {_show(b)}): {_plural(int(dup.sum()), 'edge')} on "
                f"{_plural(int((counts > 1).sum()), 'repeated pair')} "
                "(use --duplicates merge or keep)",
                path=self.source_path,
                line=None if self.source_lines is None else int(self.source_lines[k]),
            )
        # merge: orient every edge as (lo, hi), then average per pair (weighted chordal L2).
        lo, hi = np.minimum(self.edges[:, 0], self.edges[:, 1]), np.maximum(self.edges[:, 0], self.edges[:, 1])
        flip = self.edges[:, 0] > self.edges[:, 1]
        rel = np.where(flip[:, None, None], np.swapaxes(self.cam2_from_cam1, 1, 2), self.cam2_from_cam1)
        acc = np.zeros((len(uniq), 3, 3))
        np.add.at(acc, inverse, rel * self.weights[:, None, None])
        wsum = np.bincount(inverse, weights=self.weights, minlength=len(uniq))
        info = None
        if self.information is not None:
            # A reversed edge R_ji = R_ij^T has the error -R_ij^T d: information R_ij^T H R_ij.
            # Independent measurements of one pair: their informations add up.
            H = np.where(flip[:, None, None], np.swapaxes(self.cam2_from_cam1, 1, 2) @ self.information @ self.cam2_from_cam1,
                         self.information)
            info = np.zeros((len(uniq), 3, 3))
            np.add.at(info, inverse, H)
        logger.info("merged %d parallel edges into %d pairs", self.n_edges, len(uniq))
        return ViewGraph(
            self.node_ids,
            np.stack([lo[first], hi[first]], axis=1),
            so3.project_to_so3(acc),
            wsum,
            self.names,
            None if self.source_lines is None else self.source_lines[first],
            self.source_path,
            self.gt_cam_from_world,
            dict(self.meta),
            self.rigs,
            self.format,
            self.initial_cam_from_world,
            info,
            self.gravity,
        )

    def with_gravity(self, gravity, sigma_deg=None, world=None) -> "ViewGraph":
        """This graph with per-image gravity priors (a shallow copy: the arrays are shared).

        Parameters
        ----------
        gravity : (n, 3) array_like or None
            Each image's gravity direction in its camera frame (NaN rows: none); None: a
            copy without priors.
        sigma_deg : float, (n,) array_like or None
            Their noise, degrees per tilt axis (see :class:`~rotgraph.priors.GravityPriors`).
        world : (3,) array_like, optional
            The world's down direction (default :data:`~rotgraph.priors.GRAVITY_WORLD`).

        Returns
        -------
        ViewGraph
            The copy, with :attr:`gravity` set.
        """
        import copy

        out = copy.copy(self)  # (dataclasses.replace would make quaternion rotations matrices)
        if gravity is None:
            out.gravity = None
            return out
        g = np.asarray(gravity, dtype=np.float64)
        if g.shape != (self.n_nodes, 3):
            raise ValueError(f"gravity must be ({self.n_nodes}, 3) (NaN rows for images without gravity), got {g.shape}")
        out.gravity = GravityPriors(g, sigma_deg) if world is None else GravityPriors(g, sigma_deg, world)
        return out

    # ----------------------------------------------------------------- basic facts

    def relative_quaternion_rows(self, edges: np.ndarray | None = None) -> np.ndarray:
        """The relative rotations as unit quaternion rows (4, E), ``w >= 0``: the reader's own
        quaternions while the matrices were never asked for, else converted from them
        (``edges``: of those edges only, converting no others)."""
        value = self.__dict__["_cam2_from_cam1"]
        if isinstance(value, QuaternionRotations):
            return value.rows if edges is None else value.rows[:, edges]
        return so3.quaternion_rows_from_matrices(value if edges is None else value[edges])

    @property
    def n_nodes(self) -> int:
        return len(self.node_ids)

    @property
    def n_edges(self) -> int:
        return len(self.edges)

    def adjacency(self, weighted: bool = False):
        """Symmetric n x n adjacency (edge weights summed over parallel edges, or counts)."""
        n, e = self.n_nodes, self.edges
        data = self.weights if weighted else np.ones(self.n_edges)
        import scipy.sparse as sp

        A = sp.coo_matrix((np.concatenate([data, data]), (np.concatenate([e[:, 0], e[:, 1]]), np.concatenate([e[:, 1], e[:, 0]]))), shape=(n, n))
        return A.tocsr()

    def degrees(self) -> np.ndarray:
        """Number of edges at each node (parallel edges counted)."""
        return np.bincount(self.edges.ravel(), minlength=self.n_nodes)

    def components(self) -> np.ndarray:
        """Connected-component label of each node, 0 = the largest component."""
        ncomp, labels = connected_components(self.n_nodes, self.edges)
        if ncomp <= 1:
            return labels.astype(np.int64, copy=False)
        sizes = np.bincount(labels, minlength=ncomp)
        rank = np.empty(ncomp, dtype=np.int64)
        rank[np.argsort(-sizes, kind="stable")] = np.arange(ncomp)
        return rank[labels]

    def subgraph(self, nodes: np.ndarray, edge_mask: np.ndarray | None = None) -> tuple["ViewGraph", np.ndarray]:
        """The graph on ``nodes`` (indices) with the edges between them (and in ``edge_mask``).

        Returns ``(subgraph, edge_index)``: the original index of each kept edge.
        """
        nodes = np.asarray(nodes, dtype=np.int64)
        remap = np.full(self.n_nodes, -1, dtype=np.int64)
        remap[nodes] = np.arange(len(nodes))
        keep = (remap[self.edges[:, 0]] >= 0) & (remap[self.edges[:, 1]] >= 0)
        if edge_mask is not None:
            keep &= edge_mask
        idx = np.flatnonzero(keep)
        sub = ViewGraph(
            self.node_ids[nodes],
            remap[self.edges[idx]],
            self._relative_subset(idx),
            self.weights[idx],
            None if self.names is None else self.names[nodes],
            None if self.source_lines is None else self.source_lines[idx],
            self.source_path,
            None if self.gt_cam_from_world is None else self.gt_cam_from_world[nodes],
            dict(self.meta),
            None if self.rigs is None else self.rigs.subset(nodes),
            self.format,
            None if self.initial_cam_from_world is None else self.initial_cam_from_world[nodes],
            None if self.information is None else self.information[idx],
            None if self.gravity is None else self.gravity.subset(nodes),
        )
        return sub, idx

    def _relative_subset(self, idx: np.ndarray):
        """``cam2_from_cam1[idx]``, kept as quaternions when the graph holds quaternions."""
        value = self.__dict__["_cam2_from_cam1"]
        if isinstance(value, QuaternionRotations):
            return QuaternionRotations(value.rows[:, idx])
        return value[idx]

    def largest_component(self, labels: np.ndarray | None = None) -> tuple["ViewGraph", np.ndarray, np.ndarray]:
        """The largest connected component: ``(subgraph, node_index, edge_index)``; the graph
        itself (no copy) when it is connected. ``labels``: :meth:`components`, when at hand."""
        labels = self.components() if labels is None else labels
        if not self.n_nodes or labels.max() == 0:
            return self, np.arange(self.n_nodes), np.arange(self.n_edges)
        nodes = np.flatnonzero(labels == 0)
        sub, eidx = self.subgraph(nodes)
        return sub, nodes, eidx

    # ----------------------------------------------------------------- interop

    def to_networkx(self):
        """A ``networkx.MultiGraph`` (or ``Graph`` when there are no parallel edges).

        Nodes are the external ids with attributes ``index`` and ``name``; edges carry
        ``rotation`` (``R_ij`` oriented from ``source`` to the other end), ``source``,
        ``weight``, ``index`` (the row in :attr:`edges`) and, when the graph has them,
        ``information`` (the 3x3 matrix of :attr:`information`, for ``rotation``).
        """
        import networkx as nx

        lo = np.minimum(self.edges[:, 0], self.edges[:, 1])
        hi = np.maximum(self.edges[:, 0], self.edges[:, 1])
        parallel = len(np.unique(lo * max(self.n_nodes, 1) + hi)) < self.n_edges
        G = nx.MultiGraph() if parallel else nx.Graph()
        for k, nid in enumerate(self.node_ids.tolist()):
            G.add_node(nid, index=k, name=None if self.names is None else str(self.names[k]))
        ids = self.node_ids.tolist()
        for k, (i, j) in enumerate(self.edges.tolist()):
            G.add_edge(ids[i], ids[j], rotation=self.cam2_from_cam1[k], source=ids[i], weight=float(self.weights[k]), index=k,
                       **({} if self.information is None else {"information": self.information[k]}))
        return G

    @classmethod
    def from_networkx(cls, G, rotation: str = "rotation", weight: str = "weight", duplicates: str = "error") -> "ViewGraph":
        """Build from a networkx graph whose edges carry ``R_ij`` under ``rotation``.

        For an undirected graph, an edge attribute ``source`` names the node ``i`` that
        ``R_ij`` maps from (default: the first node of the edge as networkx yields it).
        """
        ii, jj, rr, ww, hh = [], [], [], [], []
        for u, v, data in G.edges(data=True):
            src = data.get("source", u)
            R = np.asarray(data[rotation], dtype=np.float64)
            if src == v:
                u, v = v, u
            ii.append(u)
            jj.append(v)
            rr.append(R)
            ww.append(float(data.get(weight, 1.0)))
            hh.append(data.get("information"))
        ids = list(G.nodes)
        names = [G.nodes[n].get("name") for n in ids]
        node_ids = np.array(ids)
        return cls.from_edges(
            np.array(ii), np.array(jj), np.array(rr).reshape(-1, 3, 3), np.array(ww), node_ids=node_ids,
            names=np.array(names) if all(n is not None for n in names) else None, duplicates=duplicates,
            information=np.array(hh, dtype=np.float64).reshape(-1, 3, 3) if hh and all(h is not None for h in hh) else None,
        )

    def summary(self) -> dict:
        labels = self.components() if self.n_nodes else np.zeros(0, np.int64)
        deg = self.degrees()
        return {
            "n_cameras": self.n_nodes,
            "n_edges": self.n_edges,
            "n_components": int(labels.max() + 1) if len(labels) else 0,
            "largest_component": int((labels == 0).sum()) if len(labels) else 0,
            "degree_min": int(deg.min()) if len(deg) else 0,
            "degree_median": float(np.median(deg)) if len(deg) else 0.0,
            "degree_max": int(deg.max()) if len(deg) else 0,
        }


#: Relative asymmetry ``|H - H^T| / |H|`` accepted in an information matrix (text files
#: print a handful of digits); the matrix used is its symmetric part.
INFORMATION_SYMMETRY_TOL = 1e-6


#: :func:`check_information` works through the matrices in chunks of this many (temporaries in
#: cache; whole-array ones: 6 s and three 720 MB temporaries at 10^7 edges).
CHECK_CHUNK = 1 << 16


def check_information(information, n_edges: int, path=None, lines=None) -> np.ndarray:
    """The one check of per-edge rotation information matrices: (E, 3, 3), finite,
    symmetric (to :data:`INFORMATION_SYMMETRY_TOL`) and positive definite. Returns the
    symmetrised float64 array; raises :class:`InputError` naming the first bad edge (of the
    first of those three checks that fails)."""
    H = np.asarray(information, dtype=np.float64)
    if H.shape != (n_edges, 3, 3):
        raise InputError(f"expected ({n_edges}, 3, 3) information matrices, got {H.shape}", path=path)
    if not n_edges:
        return H

    def check(bad: np.ndarray, what: str) -> None:
        if bad.any():
            k = int(np.argmax(bad))
            raise InputError(f"edge information matrix {what}", path=path, line=None if lines is None else int(lines[k]))

    chunks = [slice(a, a + CHECK_CHUNK) for a in range(0, n_edges, CHECK_CHUNK)]
    for b in chunks:
        check(~np.isfinite(H[b]).all(axis=(1, 2)), "is not finite")
    out = np.empty_like(H)
    asymmetric, indefinite = np.zeros(n_edges, dtype=bool), np.zeros(n_edges, dtype=bool)
    for b in chunks:
        h = H[b]
        ht = np.swapaxes(h, 1, 2)
        size = np.abs(h).max(axis=(1, 2))
        with np.errstate(over="ignore"):  # entries near the float limit: inf, not symmetric
            asymmetric[b] = np.abs(h - ht).max(axis=(1, 2)) > INFORMATION_SYMMETRY_TOL * np.maximum(size, 1e-300)
        hs = out[b]
        np.add(0.5 * h, 0.5 * ht, out=hs)
        # Positive definite: every leading principal minor positive (Sylvester), of H scaled to a
        # largest entry of 1 (same signs; no overflow of huge entries); the 3x3 determinant by
        # cofactors (np.linalg.det's LU per matrix: 1.5 s at 10^7 edges)
        hs = hs / np.where(size > 0, size, 1.0)[:, None, None]
        with np.errstate(all="ignore"):  # entries down to 1e-320 beside 1: a zero pivot
            m1 = hs[:, 0, 0]
            m2 = hs[:, 0, 0] * hs[:, 1, 1] - hs[:, 0, 1] ** 2
            m3 = (hs[:, 0, 0] * (hs[:, 1, 1] * hs[:, 2, 2] - hs[:, 1, 2] * hs[:, 2, 1])
                  - hs[:, 0, 1] * (hs[:, 1, 0] * hs[:, 2, 2] - hs[:, 1, 2] * hs[:, 2, 0])
                  + hs[:, 0, 2] * (hs[:, 1, 0] * hs[:, 2, 1] - hs[:, 1, 1] * hs[:, 2, 0]))
            indefinite[b] = ~((m1 > 0) & (m2 > 0) & (m3 > 0))
    check(asymmetric, "is not symmetric")
    check(indefinite, "is not positive definite")
    return out

    def check(bad: np.ndarray, what: str) -> None:
        if bad.any():
            k = int(np.argmax(bad))
            raise InputError(f"edge information matrix {what}", path=path, line=None if lines is None else int(lines[k]))

    check(~np.isfinite(H).all(axis=(1, 2)), "is not finite")
    Ht = np.swapaxes(H, 1, 2)
    size = np.abs(H).max(axis=(1, 2))
    with np.errstate(over="ignore"):  # entries near the float limit: inf, not symmetric
        check(np.abs(H - Ht).max(axis=(1, 2)) > INFORMATION_SYMMETRY_TOL * np.maximum(size, 1e-300), "is not symmetric")
    H = 0.5 * H + 0.5 * Ht
    # Positive definite: every leading principal minor positive (Sylvester), vectorised, of
    # H scaled to a largest entry of 1 (same signs; no overflow of huge entries).
    Hs = H / np.where(size > 0, size, 1.0)[:, None, None]
    m1 = Hs[:, 0, 0]
    m2 = Hs[:, 0, 0] * Hs[:, 1, 1] - Hs[:, 0, 1] ** 2
    with np.errstate(all="ignore"):  # entries down to 1e-320 beside 1: a zero pivot
        m3 = np.linalg.det(Hs)
    check(~((m1 > 0) & (m2 > 0) & (m3 > 0)), "is not positive definite")
    return H


def cycle_errors(graph: ViewGraph, max_triangles: int = 100_000, seed: int = 0) -> np.ndarray:
    """Closure angles (radians) ``|log(R_ki R_jk R_ij)|`` of up to ``max_triangles`` triangles.

    Triangles are found with sparse products of adjacency rows for a random sample of the
    edges (all of them on small graphs); each triangle is counted once per sampled edge.

    Parameters
    ----------
    graph : ViewGraph
        The view graph; edge ``(i, j)`` carries ``R_ij = R_j R_i^T``.
    max_triangles : int, default 100000
        At most this many triangles are evaluated (a random sample beyond it).
    seed : int, default 0
        Seed of the random sample of edges and triangles.

    Returns
    -------
    (T,) float64 ndarray
        The closure angle of each triangle found, in radians (empty with fewer than 3 edges).
    """
    n = graph.n_nodes
    if graph.n_edges < 3:
        return np.zeros(0)
    lo = np.minimum(graph.edges[:, 0], graph.edges[:, 1])
    hi = np.maximum(graph.edges[:, 0], graph.edges[:, 1])
    key = lo * n + hi
    order = np.argsort(key, kind="stable")
    skey = key[order]
    A = graph.adjacency() > 0
    rng = np.random.default_rng(seed)
    m = graph.n_edges
    sample = np.arange(m) if m <= max_triangles // 4 else rng.choice(m, max_triangles // 4, replace=False)
    i, j = graph.edges[sample, 0], graph.edges[sample, 1]
    common = A[i].multiply(A[j]).tocoo()
    e_idx, k = common.row, common.col
    if len(k) > max_triangles:
        pick = rng.choice(len(k), max_triangles, replace=False)
        e_idx, k = e_idx[pick], k[pick]
    i, j = i[e_idx], j[e_idx]
    R_ij = graph.cam2_from_cam1[sample[e_idx]]
    R_ij = np.where((graph.edges[sample[e_idx], 0] == i)[:, None, None], R_ij, np.swapaxes(R_ij, 1, 2))

    def oriented(a, b):
        kk = np.minimum(a, b) * n + np.maximum(a, b)
        e = order[np.searchsorted(skey, kk)]
        R = graph.cam2_from_cam1[e]
        return np.where((graph.edges[e, 0] == a)[:, None, None], R, np.swapaxes(R, 1, 2))

    loop = oriented(k, i) @ oriented(j, k) @ R_ij
    return so3.angle(loop)


def cycle_statistics(cycle_deg: np.ndarray) -> dict:
    """Summary of triangle closure errors in degrees (:func:`cycle_errors`, converted):
    ``n_triangles_checked`` and, when there are any, the median, mean and 90th percentile
    and the fractions under 2 and over 10 degrees (``rotgraph info``)."""
    c = np.asarray(cycle_deg, dtype=np.float64)
    out: dict = {"n_triangles_checked": int(len(c))}
    if len(c):
        out.update(
            cycle_error_median_deg=float(np.median(c)),
            cycle_error_mean_deg=float(c.mean()),
            cycle_error_p90_deg=float(np.percentile(c, 90)),
            cycle_under_2deg=float((c < 2).mean()),
            cycle_over_10deg=float((c > 10).mean()),
        )
    return out
