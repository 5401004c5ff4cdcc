"""The names rotgraph accepts for its options: one home for each list, importable without
numpy, so that the command line builds its choices from them at start-up.

The modules that implement each choice import their list from here.
"""

#: Multiple rotation averaging (:class:`~rotgraph.estimators.types.SolveOptions`).
METHODS = ("adaptive", "irls", "l1", "l2", "chordal", "quaternion", "nodewise", "spanning_tree")
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
