"""The names rotgraph accepts for its options: one home for each list, importable without
numpy, so that the command line builds its choices from them at start-up.

The modules that implement each choice import their list from here.
"""

from typing import NamedTuple


class Method(NamedTuple):
    """A multiple rotation averaging method: one entry of :data:`METHOD_TABLE`. The function
    that runs its stages is registered under ``name`` in :mod:`rotgraph.estimators.methods`."""

    name: str
    #: One line of ``--method``'s help (``name: help``).
    help: str
    #: Starts from the initialisation (``SolveOptions.init``: the spanning tree, a linear
    #: solution or the input's own guess) and iterates from it. The others get the spanning
    #: tree and ignore ``init``.
    iterative: bool = False
    #: Rejects outlier edges: a camera whose every edge is one is left out (the others flag
    #: outliers too but keep every camera they solve).
    robust: bool = False
    #: A rig calibration's rounds after the first may start it from the previous round's
    #: frames (``init="vertices"`` in place of ``init="auto"``).
    warm_start: bool = False


#: Multiple rotation averaging (:class:`~rotgraph.estimators.types.SolveOptions`): every
#: method, its properties and its help; the lists below and ``--method`` are derived from it.
#: Adding a method: an entry here and its function in :mod:`rotgraph.estimators.methods`
#: (docs/algorithms.md, "Adding a method").
METHOD_TABLE = (
    Method("adaptive", "weights from the noise and outliers estimated in the data (start, L1, then the maximum-likelihood "
           "rotations of a fitted noise model)", iterative=True, robust=True, warm_start=True),
    Method("irls", "GLOMAP's L1 then robust IRLS with --loss/--loss-scale-deg", iterative=True, robust=True, warm_start=True),
    Method("l1", "L1RA", iterative=True, robust=True, warm_start=True),
    Method("l2", "Lie-algebraic L2", iterative=True, warm_start=True),
    Method("chordal", "linear chordal averaging"),
    Method("quaternion", "linear quaternion averaging"),
    Method("nodewise", "per-node averaging", iterative=True, warm_start=True),
    Method("spanning_tree", "the initialisation alone"),
)
METHODS = tuple(m.name for m in METHOD_TABLE)
METHOD_BY_NAME = {m.name: m for m in METHOD_TABLE}
#: The methods that start from an initialisation (``SolveOptions.init``).
ITERATIVE_METHODS = tuple(m.name for m in METHOD_TABLE if m.iterative)
#: The methods that reject outlier edges (and leave out cameras whose every edge is one).
ROBUST_METHODS = tuple(m.name for m in METHOD_TABLE if m.robust)
#: The methods a rig calibration warm-starts (:mod:`rotgraph.estimators.rig_calibration`).
WARM_START_METHODS = tuple(m.name for m in METHOD_TABLE if m.warm_start)
#: ``vertices``: the input's own initial guess (``ViewGraph.initial_cam_from_world``: g2o vertices).
INITS = ("auto", "mst", "chordal", "quaternion", "vertices")
#: Rig extrinsics (``SolveOptions.rig_extrinsics``, :mod:`rotgraph.estimators.rig_calibration`).
RIG_EXTRINSICS = ("auto", "fixed", "refine", "unknown")
LINEAR_SOLVERS = ("auto", "dense", "direct", "cg")
#: Robust losses (:mod:`rotgraph.losses`).
LOSSES = ("l2", "l1", "huber", "cauchy", "geman_mcclure", "half_norm", "truncated_l2")
#: Single rotation averaging (:func:`rotgraph.estimators.single.mean`).
METRICS = ("geodesic", "chordal", "quaternion")
NORMS = ("l1", "l2", "robust")
#: Conjugate rotation averaging (:func:`rotgraph.estimators.handeye.solve_handeye`).
HANDEYE_METHODS = ("robust", "quaternion", "procrustes", "l2", "l1")
HANDEYE_POSE_PAIRS = ("all", "consecutive")  # motions from every pair of poses i < j, or consecutive ones
#: Several edges between one pair of cameras (:class:`~rotgraph.viewgraph.ViewGraph`); the
#: default by input format is :func:`rotgraph.pipeline.read.default_duplicates`.
DUPLICATE_POLICIES = ("error", "merge", "keep")
#: Input formats of view graphs and of absolute rotations (:mod:`rotgraph.io`).
EDGE_FORMATS = ("auto", "rotgraph", "csv", "glomap", "1dsfm", "mat", "g2o", "colmap")
# (g2o is recognised to be refused: its vertices are initial guesses, not ground truth.)
ROTATION_FORMATS = ("auto", "csv", "text", "json", "bundler", "mat", "g2o", "1dsfm", "colmap")
#: ``rotgraph solve -o`` (by the extension of ``-o``, or ``--output-format``): see ``rotgraph.io.outputs``.
OUTPUT_FORMATS = ("auto", "csv", "text", "json", "colmap", "colmap-txt")
#: Tables of rotations or poses (``rotgraph mean``, ``rotgraph handeye``).
TABLE_FORMATS = ("auto", "text", "csv")
#: Synthetic graphs and outlier models (:func:`rotgraph.synth.random_problem`).
GRAPHS = ("er", "traj", "posegraph")
OUTLIER_MODELS = ("uniform", "flip")
