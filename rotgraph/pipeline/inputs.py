"""The inputs of a batch: command-line inputs -> problems, and their output names.

:func:`expand_inputs` turns files, folders, glob patterns and ``@LIST`` files into
:class:`Problem` s (one view graph each); a folder's files are sniffed by
:mod:`rotgraph.io.formats` (scene folders, files that are positively not view graphs).
:func:`output_names` gives each problem a unique ``<stem>.csv``. Used by
:mod:`rotgraph.pipeline.batch` (``rotgraph batch``).
"""

from __future__ import annotations

import glob
import hashlib
import logging
import os
import re
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from ..errors import InputError, RotgraphError
from ..io.compressed import COMPRESSION_SUFFIXES, uncompressed_name
from ..io.formats import detect_format, looks_like_rotations
from ..io.text import read_text

__all__ = ["Problem", "expand_inputs", "output_names", "list_file"]

logger = logging.getLogger(__name__)

#: The files a batch writes into its output folder beside one CSV per problem.
MANIFEST = "manifest.json"
SUMMARY = "summary.csv"

# Files in a listed folder that are certainly not view graphs (folder expansion skips them).
_NOT_INPUT_SUFFIXES = {
    ".json", ".md", ".rst", ".yaml", ".yml", ".toml", ".ini", ".cfg", ".log", ".tmp", ".py", ".sh", ".ipynb",
    ".png", ".jpg", ".jpeg", ".gif", ".svg", ".pdf", ".html", ".htm", ".npy", ".npz", ".pkl", ".pickle",
    ".zip", ".gz", ".bz2", ".xz", ".tar", ".7z", ".ply", ".out", ".bin", ".lock",
}


@dataclass(frozen=True)
class Problem:
    """One problem: ``input`` as the user named it, ``path`` absolute; ``error`` is set
    (and ``path`` None) for an input that names nothing (a missing file, a pattern without
    matches, a folder without inputs)."""

    input: str
    path: Path | None
    error: str | None = None


def _is_scene_folder(p: Path) -> bool:
    """A folder that is one problem: a 1DSfM scene (``EGs.txt``), a COLMAP project or a
    folder of Parquet parts (``rotgraph``, :func:`~rotgraph.io.formats.parquet_parts`)."""
    try:
        return detect_format(p) in ("1dsfm", "colmap", "rotgraph")
    except (RotgraphError, OSError):
        return False


def _looks_like_other_data(p: Path) -> bool:
    """True for files of a folder that are positively something else than a view graph:
    hidden files, documents, images, archives, JSON, Bundler files, and what
    :func:`~rotgraph.io.formats.looks_like_rotations` recognises (absolute rotations such
    as ``rotgraph synth``'s ``gt.txt``, rotgraph's own output CSVs). Anything else,
    including unreadable or corrupt files, is an input (and is reported if it cannot be
    read)."""
    suffix = p.suffix.lower()
    if suffix in COMPRESSION_SUFFIXES:  # edges.txt.gz: judged by the name inside; a bare x.gz stays an archive
        suffix = Path(uncompressed_name(p)).suffix.lower() or suffix
    return p.name.startswith(".") or suffix in _NOT_INPUT_SUFFIXES or looks_like_rotations(p)


def _expand_folder(folder: Path, display: str) -> tuple[list[Problem], list[str]]:
    """The problems in a folder (not recursive): the folder itself when it is a scene, else
    its files that are not positively other data, and its sub-folders that are scenes."""
    if _is_scene_folder(folder):
        return [Problem(display, folder.resolve())], []
    found, ignored = [], []
    for child in sorted(folder.iterdir(), key=lambda c: c.name):
        shown = os.path.join(display, child.name)
        if child.is_dir():
            (found if _is_scene_folder(child) else ignored).append(shown)
        elif child.is_file():
            (ignored if _looks_like_other_data(child) else found).append(shown)
    if ignored:
        logger.info("%s: ignored %d file(s) or folder(s) that are not view graphs: %s", display, len(ignored), ", ".join(ignored[:10]))
    return [Problem(s, (folder / Path(s).name).resolve()) for s in found], ignored


def _read_list_file(spec: str) -> list[str]:
    """The entries of an ``@list.txt`` file: one path (or folder, or glob) a line; blank lines
    and ``#`` comments skipped; relative paths are relative to the list file's folder."""
    path = Path(spec[1:])
    lines = read_text(path).splitlines()
    out = []
    for line in lines:
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        s = os.path.expanduser(s)
        out.append(s if os.path.isabs(s) else os.path.normpath(os.path.join(str(path.parent), s)))
    if not out:
        raise InputError("names no input (only blank lines and # comments)", path=str(path))
    return out


def expand_inputs(inputs: Iterable, out_dir=None) -> list[Problem]:
    """Turn command-line inputs into problems.

    Each input is a file (one problem), a folder (a 1DSfM scene, COLMAP project or Parquet
    dataset folder is one problem; any other folder gives its files and scene sub-folders, not recursively,
    skipping files that are positively something else: images, JSON, documents, absolute
    rotation tables such as ``gt.txt``, rotgraph's output CSVs), a glob pattern (``*``,
    ``?``, ``[...]``, ``**``) or ``@LIST`` (a text file with one input a line, relative to
    its own folder). Paths met twice count once. Inputs that name nothing (a missing file,
    a pattern without matches, a folder without inputs) are problems with an ``error``.
    """
    problems: list[Problem] = []
    seen: set[Path] = set()
    out_resolved = Path(out_dir).resolve() if out_dir is not None else None

    def add(pr: Problem) -> None:
        if pr.path not in seen:
            seen.add(pr.path)
            problems.append(pr)

    def fail(display: str, message: str) -> None:
        problems.append(Problem(display, None, message))

    def one(item: str, from_pattern: bool = False) -> None:
        p = Path(item)
        if p.is_dir():
            if out_resolved is not None and p.resolve() == out_resolved:
                logger.warning("%s: the output folder is not an input; skipped", item)
                return
            found, _ = _expand_folder(p, item)
            if not found:
                fail(item, f"{item}: folder holds no input rotgraph can read")
            for pr in found:
                add(pr)
        elif p.exists():
            add(Problem(item, p.resolve()))
        elif not from_pattern and glob.has_magic(item):
            matches = sorted(glob.glob(item, recursive=True))
            if not matches:
                fail(item, f"{item}: no file matches this pattern")
            for m in matches:
                one(m, from_pattern=True)
        else:
            fail(item, f"{item}: no such file")

    for raw in inputs:
        item = os.fspath(raw)
        if isinstance(item, bytes):
            item = os.fsdecode(item)
        if list_file(item) is not None:
            for sub in _read_list_file(item):
                one(sub)
        else:
            one(item)
    return problems


def list_file(item) -> Path | None:
    """The list file an input names (``@LIST``, when no file is called that), else None:
    :func:`expand_inputs` reads it, and a batch counts it among its inputs (never an output)."""
    item = os.fsdecode(os.fspath(item))
    return Path(item[1:]) if item.startswith("@") and not Path(item).exists() else None


# =========================================================================== output names


def _stem(p: Path) -> str:
    """The output name of a problem: the file's stem, or the scene folder's name for a
    folder, ``EGs.txt`` or ``database.db``."""
    if p.is_dir():
        s = p.name
    elif uncompressed_name(p).lower() in ("egs.txt", "database.db"):
        s = p.parent.name
    else:
        s = Path(uncompressed_name(p)).stem  # edges.txt.gz -> edges
    s = re.sub(r"[^\w.\-]+", "_", s).strip("._") or "problem"
    return s


def output_names(problems: list[Problem]) -> list[str]:
    """Unique CSV names for the problems, independent of their order: ``<stem>.csv``; stems
    shared by several problems (or equal to ``summary``) become ``<folder>_<stem>.csv``,
    and if that still collides ``<folder>_<stem>-<hash of the path>.csv``."""
    reserved = {Path(MANIFEST).stem.lower(), Path(SUMMARY).stem.lower()}  # the batch's own files

    def clashes(cands: list[str]) -> list[bool]:
        count: dict[str, int] = {}
        for c in cands:
            count[c.lower()] = count.get(c.lower(), 0) + 1
        return [count[c.lower()] > 1 or c.lower() in reserved for c in cands]

    names = [_stem(pr.path) for pr in problems]
    for k, bad in enumerate(clashes(names)):
        if bad:
            parent = re.sub(r"[^\w.\-]+", "_", problems[k].path.parent.name).strip("._") or "root"
            names[k] = f"{parent}_{names[k]}"
    for k, bad in enumerate(clashes(names)):
        if bad:
            names[k] = f"{names[k]}-{hashlib.sha1(str(problems[k].path).encode()).hexdigest()[:8]}"
    return [n + ".csv" for n in names]
