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

from .errors import InputError, RotgraphError, UnsolvableError

__version__ = "0.1.0"

# The numerical modules (numpy, scipy) load on first use: ``rotgraph --help`` and the
# error paths of the command line stay fast, and ``import rotgraph`` costs little.
_LAZY = {
    "so3": ("so3", None),
    "losses": ("losses", None),
    "mean": ("single", "mean"),
    "MeanResult": ("single", "MeanResult"),
    "solve_handeye": ("handeye", "solve_handeye"),
    "motions_from_poses": ("handeye", "motions_from_poses"),
    "HandEyeResult": ("handeye", "HandEyeResult"),
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

__all__ = [
    "so3",
    "losses",
    "mean",
    "MeanResult",
    "solve_handeye",
    "motions_from_poses",
    "HandEyeResult",
    "RotgraphError",
    "InputError",
    "UnsolvableError",
]

logging.getLogger(__name__).addHandler(logging.NullHandler())
