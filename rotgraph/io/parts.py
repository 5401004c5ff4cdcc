"""The part files of a Parquet dataset folder: :func:`parquet_parts`.

A table written by Dask, Spark or Arrow is a folder of Parquet parts (``part.0.parquet``,
``part.1.parquet``, or hive-style ``key=value/`` sub-folders), beside bookkeeping files
(``_metadata``, ``_SUCCESS``, hidden ``.crc`` files). Such a folder is an edge input
(:mod:`rotgraph.io.formats` tells it, :mod:`rotgraph.io.edges` reads it) and never an output
place (:func:`rotgraph.io.outputs.check_outputs`). This module depends on nothing of rotgraph's,
so both can ask it.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

__all__ = ["parquet_parts"]


def _natural_key(rel: str) -> list:
    """Sort key of a part's path in its dataset: runs of digits as numbers (part.2 before part.10)."""
    return [(int(t), t) if k % 2 else t for k, t in enumerate(re.split(r"(\d+)", rel))]


def parquet_parts(folder) -> list[Path]:
    """The part files of a Parquet dataset folder (Dask's ``part.0.parquet ...``, Spark's and
    Arrow's), in natural order of their paths in the folder (``part.2`` before ``part.10``):
    every file in ``folder`` and, recursively, in its hive-style ``key=value`` sub-folders
    (``x=1/part-0.parquet``; other sub-folders are not looked into: a folder holding a
    dataset folder is no dataset) whose name starts with neither ``.`` nor ``_``
    (``_metadata``, ``_SUCCESS``, ``.crc`` files are not parts). Empty when ``folder`` is no
    folder or none of these files is named ``*.parquet`` or ``*.pq`` (not a Parquet
    dataset); otherwise every one is a part, whatever its name (the reader checks that it
    is Parquet)."""
    root = Path(folder)
    if not root.is_dir():
        return []
    found: list[str] = []
    for top, dirs, files in os.walk(root):
        dirs[:] = [d for d in dirs if "=" in d and not d.startswith((".", "_", "="))]
        rel = os.path.relpath(top, root)
        found += [f if rel == "." else os.path.join(rel, f) for f in files
                  if not f.startswith((".", "_")) and os.path.isfile(os.path.join(top, f))]
    if not any(Path(f).suffix.lower() in (".parquet", ".pq") for f in found):
        return []
    return [root / f for f in sorted(found, key=_natural_key)]
