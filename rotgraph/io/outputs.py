"""The output rule (docs/outputs.md), enforced once: :func:`check_outputs` refuses, before
any work, outputs that cannot be written or would destroy something - an input is never an
output, and an existing file is replaced only when it is rotgraph's own output from an
earlier run (:func:`is_rotgraph_output`) or when the user says so (``overwrite``,
``--overwrite``). The writing itself is :mod:`rotgraph.io.atomic`.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import stat
import tempfile
from pathlib import Path

from ..errors import InputError
from .atomic import cannot_write_error, output_folder, output_target, own_fd, special_file, writes_to_stdout
from .parts import parquet_parts

__all__ = ["OWN_SIGNATURES", "PLOT_CREATOR", "check_outputs", "check_replaceable", "input_datasets", "is_rotgraph_output",
           "probe_folder", "refuse_input_dataset"]


#: The first bytes of each kind of text file rotgraph writes (:mod:`rotgraph.io.writers`,
#: the batch's manifest and summary, synth's files): an existing file that starts with one
#: of them is rotgraph's own output from an earlier run, which a new run may replace
#: (:func:`is_rotgraph_output`). Plots name rotgraph in their metadata and binary edge
#: files are told by their arrays. tests/test_overwrite.py writes a file with every writer
#: and checks that it is recognised, so this table follows the writers.
OWN_SIGNATURES: tuple[bytes, ...] = (
    b"id,name,qw,qx,qy,qz",  # write_rotations: solve's CSV, batch's per-problem CSVs
    b"i,j,residual_deg,inlier",  # write_edges_csv: --edges-out
    b"id,name,error_deg",  # write_camera_errors: eval --per-camera
    b"sensor_id,status,qw,qx,qy,qz",  # write_extrinsics: --extrinsics-out
    b"frame_id,qw,qx,qy,qz",  # write_frames: --frames-out
    b"sensor_id,qw,qx,qy,qz",  # synth's gt_extrinsics.csv
    b"input,output,status,error",  # batch's summary.csv
    b"# id qw qx qy qz (cam_from_world)",  # write_absolute_rotations_text: synth's gt.txt
    b"# IMAGE_NAME QW QX QY QZ (cam_from_world)",  # write_rotations_text: -o x.txt
    b"# i j qw qx qy qz weight",  # write_edges, write_edges_text_blocks: synth's edges.txt
    b"# image_id frame_id sensor_id",  # write_rigs: synth's rigs.txt
    b"# image_id gx gy gz: the gravity direction",  # synth's gravity.txt
    b'{\n "convention": "cam_from_world quaternions',  # write_rotations_json: -o x.json
    b'{\n  "n": ',  # synth's meta.json
    b'[\n  {\n    "input": ',  # batch's manifest.json
    b"[]",  # a batch manifest without entries
)
#: The metadata rotgraph's plots carry (``Software`` of a PNG, ``Creator`` of a PDF or SVG).
PLOT_CREATOR = "rotgraph"
#: How that metadata reads in the file matplotlib writes (PNG tEXt chunk, PDF Info, SVG Dublin Core).
_PLOT_MARK = re.compile(b"tEXtSoftware\x00" + PLOT_CREATOR.encode() + b"|/Creator \\(" + PLOT_CREATOR.encode() + b"\\)"
                        b"|<dc:creator>\\s*<cc:Agent>\\s*<dc:title>" + PLOT_CREATOR.encode() + b"</dc:title>")
#: Files of an input project that are read as part of it (COLMAP database and model files, 1DSfM's).
_PROJECT_FILE = re.compile(r"(?i)^(.*\.db|(cameras|images|points3D|rigs|frames)\.(bin|txt)|EGs\.txt|coords\.txt|"
                           r"list\.txt|gt_bundle\.out|tracks\.txt)$")
#: The arrays every binary edge file of rotgraph holds (:func:`~rotgraph.io.writers.write_edges_npz`).
_NPZ_ARRAYS = {"i.npy", "j.npy", "qw.npy", "qx.npy", "qy.npy", "qz.npy"}


def is_rotgraph_output(path) -> bool:
    """Whether the existing file ``path`` is one rotgraph writes, so that a new run may
    replace it: empty (or blank), starting with one of :data:`OWN_SIGNATURES` (after a UTF-8
    byte-order mark), a binary edge file (a ``.npz`` of rotgraph's arrays) or a plot whose
    metadata names rotgraph. Anything else, or a file that cannot be read, is not."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(1 << 16)
            size = os.fstat(fh.fileno()).st_size
            tail = b""
            if size > len(head):
                fh.seek(max(len(head), size - (1 << 16)))
                tail = fh.read()
    except OSError:
        return False
    if not head.strip():
        return True
    text = head[3:] if head.startswith(b"\xef\xbb\xbf") else head
    if text.startswith(OWN_SIGNATURES):
        return True
    if head.startswith(b"PK\x03\x04"):
        import zipfile

        try:
            with zipfile.ZipFile(path) as z:
                return _NPZ_ARRAYS <= set(z.namelist())
        except (OSError, zipfile.BadZipFile):
            return False
    if head.startswith((b"\x89PNG", b"%PDF", b"<?xml", b"<svg")):
        return _PLOT_MARK.search(head) is not None or _PLOT_MARK.search(tail) is not None
    return False


def check_replaceable(path, shown=None, overwrite: bool = False) -> None:
    """The output rule for an existing file at an output: an :class:`InputError` (exit 3,
    before any work) unless ``overwrite`` or the file is rotgraph's own output from an earlier
    run (:func:`is_rotgraph_output`) and not read-only. Missing paths, folders, devices and
    FIFOs (written through) pass."""
    if overwrite:
        return
    try:
        st = os.stat(path)
    except OSError:
        return
    if not stat.S_ISREG(st.st_mode):
        return
    shown = os.fspath(path if shown is None else shown)
    if not st.st_mode & 0o222:
        raise InputError("exists and is read-only (--overwrite replaces it)", path=shown)
    if not is_rotgraph_output(path):
        raise InputError("exists and is not a rotgraph output (--overwrite replaces it)", path=shown)


_NO_TMPFILE = {errno.EOPNOTSUPP, errno.EISDIR, errno.EINVAL, getattr(errno, "ENOTSUP", errno.EOPNOTSUPP)}


def probe_folder(folder: Path, shown) -> None:
    """Whether a file can be created in ``folder`` (where ``atomic_write`` puts its
    temporary file): an InputError naming the output ``shown`` when not, before any work.

    Permission bits alone do not tell (root writes anywhere they allow, yet /sys, /proc and
    read-only mounts refuse), so a file is created: an unnamed one (``O_TMPFILE``, Linux),
    which leaves the folder untouched; where the file system does not support that (sysfs,
    procfs, NFS), a named temporary file, removed at once, and the folder's times restored.
    """
    if not os.access(folder, os.W_OK | os.X_OK):
        raise cannot_write_error(PermissionError(errno.EACCES, os.strerror(errno.EACCES)), shown, folder)
    if hasattr(os, "O_TMPFILE"):
        try:
            os.close(os.open(folder, os.O_TMPFILE | os.O_WRONLY, 0o600))
            return
        except OSError as exc:
            if exc.errno not in _NO_TMPFILE:
                raise cannot_write_error(exc, shown, folder) from None
    before = os.stat(folder)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{Path(shown).name}.", suffix=".tmp", dir=folder)
    except OSError as exc:
        raise cannot_write_error(exc, shown, folder) from None
    os.close(fd)
    with contextlib.suppress(OSError):
        os.unlink(tmp)
    with contextlib.suppress(OSError):  # nothing outside the named output touched, not even the folder's mtime
        os.utime(folder, ns=(before.st_atime_ns, before.st_mtime_ns))


def input_datasets(inputs) -> list[tuple[str, Path]]:
    """``(as named, resolved)`` of each input (of ``inputs``) that is a folder of Parquet
    parts (:func:`rotgraph.io.parts.parquet_parts`): the output rule writes nothing there
    (:func:`refuse_input_dataset`), since any new file would be read as a part."""
    named = [os.fsdecode(os.fspath(i)) for i in inputs if i is not None]
    return [(i, Path(os.path.realpath(i))) for i in named if parquet_parts(i)]


def refuse_input_dataset(target, datasets, shown=None) -> None:
    """An :class:`InputError` naming the output ``shown`` (default ``target``) when one of
    the input ``datasets`` (:func:`input_datasets`) holds or is ``target``."""
    key = Path(os.path.realpath(target))
    for inp, folder in datasets:
        if folder == key or folder in key.parents:
            raise InputError(f"output would be written into the input Parquet dataset {inp} (a file there would be read "
                             "as a part of it): choose another folder", path=os.fspath(target if shown is None else shown))


def check_outputs(outputs, inputs=(), overwrite: bool = False) -> None:
    """Refuse, before any work, outputs that cannot be written or would destroy something:
    a missing output folder, a folder that refuses new files (``cannot write here``; /sys,
    a read-only mount, no permission), an output that is a folder, the same file named
    twice (standard output too: ``-`` and ``/dev/stdout`` are one), an output that is
    one of the inputs (or a file inside an input folder; ``overwrite`` or not; any file in an
    input folder of Parquet parts, :func:`refuse_input_dataset`), or an
    existing file that is not rotgraph's own output or is read-only, unless ``overwrite``
    (:func:`check_replaceable`). Symlinks are judged by the file they point to; ``-`` and
    existing devices or FIFOs (written through) are fine."""
    seen: dict[object, str] = {}
    probed: set[Path] = set()
    datasets = input_datasets(inputs)
    for o in outputs:
        if o is None:
            continue
        shown = os.fspath(o)
        if writes_to_stdout(o):
            key: object = "<stdout>"
        elif own_fd(o) is not None:
            key = f"<fd {own_fd(o)}>"
        else:
            key = None
        if key is not None:  # an open file of this process (stdout, /dev/fd/N): written through
            if key in seen:
                also = "" if seen[key] == shown else f" (also as {seen[key]})"
                raise InputError(f"named twice as an output{also}", path=shown)
            seen[key] = shown
            continue
        out = Path(o)
        target = output_target(out)
        special = special_file(target)
        if special is not None:  # a device or FIFO: written through, never replaced
            if not os.access(target, os.W_OK):
                raise InputError("cannot write here: permission denied", path=shown)
            if stat.S_ISFIFO(special.st_mode):  # two writers of one FIFO would interleave
                key = ("fifo", special.st_dev, special.st_ino)
                if key in seen:
                    raise InputError(f"named twice as an output (also as {seen[key]})", path=shown)
                seen[key] = shown
            continue
        folder = output_folder(target)
        if target.is_dir():
            raise InputError("output is a folder, expected a file name", path=shown)
        key = target.resolve()
        if key in seen:
            also = "" if seen[key] == shown else f" (also as {seen[key]})"
            raise InputError(f"named twice as an output{also}", path=shown)
        seen[key] = shown
        refuse_input_dataset(key, datasets, shown)
        if target.exists():
            for inp in inputs:
                ip = Path(inp)
                if not ip.exists():
                    continue
                if ip.is_file() and os.path.samefile(ip, target):
                    raise InputError("output would overwrite the input", path=shown)
                # An input folder (a COLMAP project, a 1DSfM scene; a database's folder holds the
                # sparse model read beside it): nothing in it but rotgraph's own kinds of output, or
                # its own earlier outputs (never a database or a model file, which the input reads).
                ifolder = ip if ip.is_dir() else (ip.parent if ip.name == "database.db" else None)
                if ifolder is not None and ifolder.resolve() in key.parents and (
                        _PROJECT_FILE.match(target.name) or (target.suffix.lower() not in (".csv", ".json", ".png")
                                                             and not is_rotgraph_output(target))):
                    raise InputError(f"output would overwrite a file of the input folder {ifolder}", path=shown)
            check_replaceable(target, shown, overwrite)
        if folder.resolve() not in probed:
            probe_folder(folder, shown)
            probed.add(folder.resolve())
