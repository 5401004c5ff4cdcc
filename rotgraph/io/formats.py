"""Format detection: which reader a path needs, decided in one place.

* :func:`detect_format` - the edge format of a view-graph input (:data:`EDGE_FORMATS`,
  named as in CLI.md), by the path's kind, extension and first data line;
* :func:`detect_rotation_format` - the format of an absolute-rotation file
  (:data:`ROTATION_FORMATS`);
* :func:`detect_table_format` - ``csv`` or ``text`` for the ``mean`` and ``handeye`` inputs;
* :func:`looks_like_rotations` - files that are positively not view graphs (absolute
  rotations, rotgraph's own outputs), which ``rotgraph batch`` skips in a folder.

Detection reads at most the first 64 KiB of a file; the first data line is the first
line that is neither blank nor a ``#`` comment (:func:`rotgraph.io.table_lines.first_data_line`).
It sees through compression (:mod:`rotgraph.io.compressed`): a gzip, bzip2 or xz file is
judged by the data it holds and by its name without the compression extension
(``edges.txt.gz`` as ``edges.txt``, ``garage.g2o.xz`` as ``garage.g2o``).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..choices import EDGE_FORMATS, ROTATION_FORMATS, TABLE_FORMATS
from ..errors import InputError
from .compressed import uncompressed_name
from .parts import parquet_parts
from .table_lines import first_data_line
from .text import is_float, read_head

__all__ = [
    "EDGE_FORMATS",
    "ROTATION_FORMATS",
    "TABLE_FORMATS",
    "G2O_EDGE",
    "G2O_VERTEX",
    "G2O_SKIPPED",
    "PARQUET_PARTS",
    "binary_edge_format",
    "detect_format",
    "detect_rotation_format",
    "detect_table_format",
    "head_data_line",
    "looks_like_rotations",
]

#: The ``mean`` and ``handeye`` inputs (EDGE_FORMATS, ROTATION_FORMATS: :mod:`rotgraph.choices`).

# g2o tags (rotgraph.io.g2o): the two it reads, and those whose lines it skips (with one
# warning); any other tag is an error.
G2O_EDGE = "EDGE_SE3:QUAT"
G2O_VERTEX = "VERTEX_SE3:QUAT"
G2O_SKIPPED = ("FIX", "VERTEX_TRACKXYZ", "VERTEX_XYZ", "EDGE_SE3_TRACKXYZ", "PARAMS_SE3OFFSET")

_BINARY_MAGIC = (b"MATLAB", b"\x89HDF", b"SQLite format 3\x00")
# rotgraph's binary edge files (rotgraph.io.edges): .npz is a zip archive.
_ZIP_MAGIC, _PARQUET_MAGIC = b"PK\x03\x04", b"PAR1"


def _binary_edge_kind(ext: str, head: bytes) -> str | None:
    if ext == ".npz":
        return "npz"
    if ext in (".parquet", ".pq"):
        return "parquet"
    return "npz" if head.startswith(_ZIP_MAGIC) else "parquet" if head.startswith(_PARQUET_MAGIC) else None


#: The binary edge kind of a folder of Parquet parts (a partitioned dataset: Dask, Spark, Arrow).
PARQUET_PARTS = "parquet-parts"


def _folder_format(p: Path) -> str | None:
    """The edge format of a folder: ``1dsfm`` (``EGs.txt``), ``colmap``, ``rotgraph`` (a
    Parquet dataset, :func:`~rotgraph.io.parts.parquet_parts`), in this order; None for any other folder."""
    if (p / "EGs.txt").is_file():
        return "1dsfm"
    if _is_colmap(p):
        return "colmap"
    return "rotgraph" if parquet_parts(p) else None


def binary_edge_format(path) -> str | None:
    """``npz`` or ``parquet`` for a binary edge file (by its extension, or its zip / Parquet
    magic bytes), :data:`PARQUET_PARTS` for a folder of Parquet parts (:func:`~rotgraph.io.parts.parquet_parts`;
    not a 1DSfM scene or COLMAP project), else None: the binary encoding of the ``rotgraph``
    edge format, which :func:`detect_format` calls ``rotgraph`` (and
    :func:`rotgraph.io.edges.read_edge_file` reads as binary whatever format it is told, but ``mat``)."""
    p = Path(path)
    if p.is_dir():
        return PARQUET_PARTS if _folder_format(p) == "rotgraph" else None
    if not p.is_file():
        return None
    return _binary_edge_kind(Path(uncompressed_name(p)).suffix.lower(), read_head(p, 4))


def _head_line(head: bytes) -> str | None:
    first = first_data_line(head.decode("utf-8-sig", errors="replace"))
    return None if first is None else first[2]


def head_data_line(path) -> str | None:
    """The first data line of a file's first 64 KiB (stripped), or None; a missing or
    unreadable file is an :class:`~rotgraph.errors.InputError`."""
    return _head_line(read_head(path))


def _is_colmap(p: Path) -> bool:
    from .colmap_project import is_colmap_project

    return is_colmap_project(p)


def detect_format(path) -> str:
    """The edge format of ``path`` (see :data:`EDGE_FORMATS`), by extension and content.

    Folder with ``EGs.txt`` -> ``1dsfm``; a COLMAP folder (``database.db`` or a sparse
    model) or ``.db`` file -> ``colmap``; ``.mat`` or a MATLAB header -> ``mat``; ``.g2o``
    or a first tag ``VERTEX_...``/``EDGE_...`` -> ``g2o``; a file named ``EGs.txt``, or 14
    numeric fields a line -> ``1dsfm``; ``.npz``, ``.parquet``, ``.pq`` or a zip / Parquet
    magic, or a folder of Parquet parts (:func:`binary_edge_format`) -> ``rotgraph`` (its
    binary encoding); ``.csv`` or a
    comma in the first data line -> ``csv``; exactly 9 fields whose 3rd..6th form a unit quaternion -> ``glomap``;
    otherwise ``rotgraph``. A folder holding none of these is an
    :class:`~rotgraph.errors.InputError`.
    """
    p = Path(path)
    if p.is_dir():
        fmt = _folder_format(p)
        if fmt is not None:
            return fmt
        raise InputError(
            "folder holds no input rotgraph can read (expected EGs.txt of a 1DSfM scene, a COLMAP "
            "database.db / sparse model, or Parquet parts of an edge table)",
            path=str(path),
        )
    if not p.exists():
        raise InputError("no such file", path=str(path))
    name = uncompressed_name(p).lower()  # a compressed file: the name of what it holds (edges.txt.gz -> edges.txt)
    ext = Path(name).suffix
    head = read_head(p)
    if ext == ".mat" or head.startswith(_BINARY_MAGIC[:2]):
        return "mat"
    if ext == ".db" or head.startswith(_BINARY_MAGIC[2]):
        return "colmap"
    if ext == ".g2o":
        return "g2o"
    if name == "egs.txt":
        return "1dsfm"
    if _binary_edge_kind(ext, head) is not None:
        return "rotgraph"  # its binary encoding (.npz, Parquet)
    line = _head_line(head)
    tokens = line.split() if line else []
    if tokens and (tokens[0].startswith(("VERTEX_", "EDGE_")) or tokens[0] in G2O_SKIPPED):
        return "g2o"
    if ext == ".csv" or detect_table_format(line) == "csv":
        return "csv"
    if len(tokens) == 9 and all(is_float(t) for t in tokens[2:9]):
        q = np.array([float(t) for t in tokens[2:6]])
        if abs(np.linalg.norm(q) - 1.0) < 1e-2:
            return "glomap"
    if len(tokens) == 14 and tokens[0].isdigit() and tokens[1].isdigit() and all(is_float(t) for t in tokens[2:]):
        return "1dsfm"
    return "rotgraph"


def detect_rotation_format(path) -> str:
    """The format of an absolute-rotation file (see :data:`ROTATION_FORMATS`).

    A folder, ``.mat``, ``.g2o``, ``.db``, ``EGs.txt`` or a binary MATLAB/HDF5/SQLite file
    -> as :func:`detect_format` (the ground truth inside that input); a file of a COLMAP
    sparse model (``images.bin`` ...) -> ``colmap`` (the model); ``# Bundle file`` ->
    ``bundler``; a first tag ``VERTEX_...``/``EDGE_...`` -> ``g2o``; ``.csv`` or a comma in
    the first data line -> ``csv``; ``.json`` or a first ``{`` -> ``json`` (``rotgraph solve
    -o X.json``); otherwise ``text``.
    """
    p = Path(path)
    if p.is_dir():
        return detect_format(p)
    if p.parent.is_dir() and p.suffix.lower() in (".bin", ".txt") and p.stem in ("cameras", "images", "points3D", "rigs", "frames"):
        if _is_colmap(p.parent):
            return "colmap"  # a file inside a sparse model: the model
    if not p.exists():
        raise InputError("no such file", path=str(p))
    name = uncompressed_name(p).lower()
    ext = Path(name).suffix
    head = read_head(p)
    if ext in (".mat", ".g2o", ".db") or name == "egs.txt" or head.startswith(_BINARY_MAGIC):
        return detect_format(p)
    if head.lstrip().startswith(b"# Bundle file"):
        return "bundler"
    line = _head_line(head)
    if line is not None and line.split()[0].startswith(("VERTEX_", "EDGE_")):
        return "g2o"
    if ext == ".json" or head.lstrip().startswith(b"{"):
        return "json"
    if ext == ".csv" or detect_table_format(line) == "csv":
        return "csv"
    return "text"


def detect_table_format(first_line: str | None) -> str:
    """``csv`` when the first data line (see :func:`~rotgraph.io.table_lines.first_data_line`)
    has a comma, else ``text``: how the ``mean`` and ``handeye`` inputs are told apart."""
    return "csv" if first_line is not None and "," in first_line else "text"


def looks_like_rotations(path) -> bool:
    """Whether a file is positively absolute rotations or one of rotgraph's outputs, not a
    view graph: ``id,name,qw,...`` or ``name,qw,...`` CSVs (``rotgraph solve``'s output),
    ``i,j,residual_deg,inlier`` CSVs (``--edges-out``) and ``id qw qx qy qz`` lines with a
    unit quaternion (e.g. ``rotgraph synth``'s ``gt.txt``; a cut edge line is not one).
    False for anything else, including unreadable files."""
    try:
        line = head_data_line(path)
    except InputError:
        return False
    if line is None:
        return False
    if "," in line:
        header = [f.strip().lower() for f in line.split(",")]
        return (header[0] in ("id", "name") and "qw" in header) or header[:3] == ["i", "j", "residual_deg"]
    fields = line.split()
    if len(fields) != 5 or not all(is_float(f) for f in fields[1:]):
        return False
    return abs(math.sqrt(sum(float(f) ** 2 for f in fields[1:])) - 1.0) < 1e-3
