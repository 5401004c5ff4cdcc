"""Chatterjee-Govindu ``.mat`` files: the edge format ``mat`` of
:func:`rotgraph.io.edges.read_edge_file`.

Chatterjee-Govindu ``.mat`` (scipy.io.loadmat; MATLAB v7.3/HDF5 files are not
supported): ``RR`` 3x3xM relative rotations, ``I`` 2xM 1-based edge indices (any
integer type; Ellis.mat stores uint8, cast before subtracting 1), optional ``Rgt``
3x3xN world -> camera ground truth (all-zero slices = no ground truth). ``RR(:,:,k) =
Rgt_j Rgt_i^T`` for ``I(:,k) = (i, j)``: used as is. Also accepted: ``I`` as Mx2,
``RR``/``Rgt`` as Mx3x3, and a single 3x3 slice. Node ids are ``0 .. N-1`` with N the
larger of ``max(I)`` and Rgt's N (but when more than half of them would have neither
an edge nor ground truth, only the ids in ``I`` and Rgt's ``0 .. N-1``: one huge index
must not allocate billions of cameras). Checked on Ellis.mat against its ``Rgt``: median
input-edge error 2.894 degrees as read, vs 33.1 degrees read as ``R_i R_j^T`` and
31.8 degrees read as ``R_j^T R_i``.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from .. import so3_checks
from ..errors import InputError
from ..viewgraph import ViewGraph
from .compressed import input_bytes, is_compressed
from .table_columns import INT64_MAX, unique

__all__ = ["read_mat"]


def read_mat(path: Path, duplicates: str) -> ViewGraph:
    """Read a Chatterjee-Govindu ``.mat`` file (module docstring); ``Rgt`` lands in ``gt_cam_from_world``."""
    import scipy.io

    if not path.is_file():
        raise InputError("no such file" if not path.exists() else "is a folder, expected a .mat file", str(path))
    source = io.BytesIO(input_bytes(path)) if is_compressed(path) else str(path)  # .mat.gz: decompressed in memory
    try:
        data = scipy.io.loadmat(source)
    except NotImplementedError:
        raise InputError("MATLAB v7.3 (HDF5) .mat files are not supported: save with -v7 instead", str(path)) from None
    except Exception as exc:  # scipy raises ValueError, TypeError, OSError ... on garbage
        raise InputError(f"not a readable MATLAB .mat file ({type(exc).__name__}: {str(exc)[:100]})", str(path)) from None
    spath = str(path)

    def var(name, required=True):
        if name not in data:
            if not required:
                return None
            have = sorted(k for k in data if not k.startswith("__"))
            raise InputError(
                f"variable {name!r} missing (the file has: {', '.join(have) or 'nothing'}); expected RR, I and optionally Rgt",
                spath,
            )
        v = data[name]
        if not isinstance(v, np.ndarray) or v.dtype.kind not in "biuf":
            raise InputError(f"variable {name!r} must be a numeric array, got {getattr(v, 'dtype', type(v))}", spath)
        return v

    RR = _mat_stack(var("RR"), "RR", spath)
    M = len(RR)
    I = var("I")
    if I.ndim != 2 or 2 not in I.shape:
        raise InputError(f"variable 'I' must be 2xM (or Mx2), got shape {I.shape}", spath)
    if I.shape != (2, M):
        if I.shape != (M, 2):
            m = I.shape[1] if I.shape[0] == 2 else I.shape[0]
            raise InputError(f"variable 'I' has {m} edges but 'RR' has {M}", spath)
        I = I.T
    if I.dtype.kind == "f":
        if not (np.isfinite(I).all() and (I == np.round(I)).all()):
            raise InputError("variable 'I' must hold integer indices", spath)
    if M == 0:
        raise InputError("no edges (RR and I are empty)", spath)
    if I.min() < 1:
        k = int(np.argmax((I < 1).any(axis=0)))
        raise InputError(f"I(:,{k + 1}) = {tuple(I[:, k].tolist())}: indices are 1-based, got < 1", spath)
    if I.max() > INT64_MAX:  # uint64 or float indices beyond int64
        k = int(np.argmax((I > INT64_MAX).any(axis=0)))
        raise InputError(f"I(:,{k + 1}) = {tuple(I[:, k].tolist())}: index too large (must fit in a signed 64-bit integer)", spath)
    I = I.astype(np.int64)  # before subtracting 1: Ellis.mat stores I as uint8
    if not np.isfinite(RR).all():
        k = int(np.argmax(~np.isfinite(RR).all(axis=(1, 2))))
        raise InputError(f"RR(:,:,{k + 1}) is not finite", spath)
    rel = so3_checks.check_rotations(RR, path=spath, label=lambda k: f"RR(:,:,{k + 1})")
    Rgt = var("Rgt", required=False)
    n_gt = 0
    if Rgt is not None:
        Rgt = _mat_stack(Rgt, "Rgt", spath)
        n_gt = len(Rgt)
    n = max(int(I.max()), n_gt)
    # Cameras 0 .. n-1, unless most of them would have neither edges nor ground truth (e.g.
    # one huge index in a small file: 0 .. n-1 could be too many to allocate); then only the
    # cameras in I and Rgt.
    known = unique(np.concatenate([np.arange(n_gt, dtype=np.int64), (I - 1).ravel()]))
    node_ids = np.arange(n, dtype=np.int64) if n <= 2 * len(known) else known
    gt = None
    if Rgt is not None:
        gt = np.full((len(node_ids), 3, 3), np.nan)
        has = np.isfinite(Rgt).all(axis=(1, 2)) & np.any(Rgt != 0, axis=(1, 2))
        idx = np.flatnonzero(has)
        gt[idx] = so3_checks.check_rotations(Rgt[idx], path=spath, label=lambda k: f"Rgt(:,:,{idx[k] + 1})")
    loops = np.flatnonzero(I[0] == I[1])
    if len(loops):
        k = int(loops[0])
        raise InputError(f"I(:,{k + 1}) = {tuple(I[:, k].tolist())}: self-loop, an edge from a camera to itself", spath)
    graph = ViewGraph.from_edges(I[0] - 1, I[1] - 1, rel, None, node_ids=node_ids, duplicates=duplicates, source_path=spath)
    graph.gt_cam_from_world = gt
    return graph


def _mat_stack(v: np.ndarray, name: str, path: str) -> np.ndarray:
    """A MATLAB 3x3xK array (or 3x3, or Kx3x3) as ``(K, 3, 3)`` float64."""
    v = np.asarray(v, dtype=np.float64)
    if v.shape == (3, 3):
        return v[None].copy()
    if v.ndim == 3 and v.shape[:2] == (3, 3):
        return np.ascontiguousarray(np.moveaxis(v, 2, 0))
    if v.ndim == 3 and v.shape[1:] == (3, 3):
        return np.ascontiguousarray(v)
    if v.size == 0:
        return np.zeros((0, 3, 3))
    raise InputError(f"variable {name!r} must be 3x3xK, got shape {v.shape}", path)
