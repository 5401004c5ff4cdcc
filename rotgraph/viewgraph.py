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

from . import so3_rows
from .graph_analysis import connected_components, cycle_errors, cycle_statistics
from .graph_build import (
    QuaternionRotations,
    check_information,
    checked_edges,
    edges_from_networkx,
    merged_duplicates,
    networkx_graph,
)
from .priors import GravityPriors

__all__ = ["ViewGraph", "Rigs", "QuaternionRotations", "check_information", "connected_components", "cycle_errors",
           "cycle_statistics"]

logger = logging.getLogger(__name__)


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
        node_ids, edges, rel, w, lines, info = checked_edges(
            ids_i, ids_j, cam2_from_cam1, weights, node_ids=node_ids, codes=codes, duplicates=duplicates,
            source_lines=source_lines, source_path=source_path, information=information)
        graph = cls(node_ids, edges, rel, w, None if names is None else np.asarray(names), lines, source_path, information=info)
        return graph._resolve_duplicates(duplicates)

    def _resolve_duplicates(self, policy: str) -> "ViewGraph":
        """This graph under the duplicate policy ``policy`` (:func:`~rotgraph.graph_build.merged_duplicates`)."""
        merged = merged_duplicates(self, policy)
        if merged is None:
            return self
        edges, rel, weights, first, info = merged
        return ViewGraph(
            self.node_ids,
            edges,
            rel,
            weights,
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
        return so3_rows.quaternion_rows_from_matrices(value if edges is None else value[edges])

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
        return networkx_graph(self)

    @classmethod
    def from_networkx(cls, G, rotation: str = "rotation", weight: str = "weight", duplicates: str = "error") -> "ViewGraph":
        """Build from a networkx graph whose edges carry ``R_ij`` under ``rotation``.

        For an undirected graph, an edge attribute ``source`` names the node ``i`` that
        ``R_ij`` maps from (default: the first node of the edge as networkx yields it).
        """
        return cls.from_edges(**edges_from_networkx(G, rotation, weight), duplicates=duplicates)

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
