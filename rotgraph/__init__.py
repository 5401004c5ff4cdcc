"""rotgraph: rotation averaging for Structure-from-Motion.

Conventions, stated once for the whole package
----------------------------------------------
* Rotations are float64 arrays of shape ``(N, 3, 3)``; node ``i`` is row ``i``.
* Quaternions are scalar-first ``(w, x, y, z)``, unit norm; rotgraph writes ``w >= 0``.
  (scipy and pycolmap are scalar-last; :mod:`rotgraph.so3` converts at the boundary.)
* Absolute rotations are world-to-camera, COLMAP's ``cam_from_world``.
* The relative rotation on edge ``(i, j)`` is ``R_ij = R_j R_i^T`` (COLMAP's
  ``cam2_from_cam1``), so ``R_j ~ R_ij R_i``.
* The gauge is one global rotation acting on the right: ``R_i -> R_i W^T`` leaves every
  ``R_ij`` unchanged. Errors are reported in degrees after aligning it.
* Angles are radians in the library unless a name says ``_deg``.
"""

import importlib
import logging

from .errors import InputError, OptionError, RotgraphError, UnknownOptionError, UnsolvableError

__version__ = "0.1.0"

# The numerical modules (numpy, scipy) load on first use: ``rotgraph --help`` and the
# error paths of the command line stay fast, and ``import rotgraph`` costs little.
_LAZY = {
    # modules
    "so3": ("so3", None),
    "losses": ("losses", None),
    # the view graph
    "ViewGraph": ("viewgraph", "ViewGraph"),
    "cycle_errors": ("graph_analysis", "cycle_errors"),
    # multiple rotation averaging
    "average_rotations": ("estimators.rotation_averaging", "average_rotations"),
    "SolveOptions": ("estimators.rotation_averaging", "SolveOptions"),
    "AveragingResult": ("estimators.rotation_averaging", "AveragingResult"),
    # global optimality (chordal cost)
    "certify": ("estimators.certify", "certify"),
    "Certificate": ("estimators.certify", "Certificate"),
    "CertifyOptions": ("estimators.certify", "CertifyOptions"),
    "refine_chordal": ("estimators.staircase", "refine_chordal"),
    "RefineOptions": ("estimators.staircase", "RefineOptions"),
    # single rotation averaging
    "mean": ("estimators.single", "mean"),
    "MeanOptions": ("estimators.single", "MeanOptions"),
    "MeanResult": ("estimators.single", "MeanResult"),
    # conjugate rotation averaging (hand-eye)
    "solve_handeye": ("estimators.handeye", "solve_handeye"),
    "motions_from_poses": ("estimators.handeye", "motions_from_poses"),
    "HandEyeOptions": ("estimators.handeye", "HandEyeOptions"),
    "HandEyeResult": ("estimators.handeye", "HandEyeResult"),
    # evaluation against ground truth
    "compare_rotations": ("evaluate", "compare_rotations"),
    "EvalResult": ("evaluate", "EvalResult"),
    # files
    "read_view_graph": ("pipeline.read", "read_view_graph"),
    "read_absolute_rotations": ("io.rotations", "read_absolute_rotations"),
    "write_rotations": ("io.writers", "write_rotations"),
    "write_edges": ("io.writers", "write_edges"),
    "solve_file": ("pipeline.solve", "solve_file"),
    "solve_distributed": ("pipeline.distributed", "solve_distributed"),
    "default_options": ("pipeline.solve", "default_options"),
    # synthetic problems
    "random_problem": ("synth", "random_problem"),
    "ProblemOptions": ("synth", "ProblemOptions"),
}


def __getattr__(name: str):
    if name not in _LAZY:
        raise AttributeError(f"module 'rotgraph' has no attribute {name!r}")
    module, attr = _LAZY[name]
    mod = importlib.import_module(f".{module}", __name__)
    value = mod if attr is None else getattr(mod, attr)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_LAZY))

__all__ = [*_LAZY, "RotgraphError", "InputError", "UnsolvableError", "OptionError", "UnknownOptionError"]

logging.getLogger(__name__).addHandler(logging.NullHandler())
