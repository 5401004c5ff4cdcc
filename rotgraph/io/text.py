"""Reading text files with clear errors, and writing files atomically.

:func:`read_text` is how every reader of :mod:`rotgraph.io` opens a text file (missing,
folder, binary, UTF-16/32 and non-UTF-8 files are :class:`~rotgraph.errors.InputError`
naming the file and, where there is one, the 1-based line); :func:`read_head` reads the
first bytes of a file for format detection (:mod:`rotgraph.io.formats`); the tables in
the files are parsed by :mod:`rotgraph.io.tables`. Every writer goes through
:func:`atomic_write`, so no output is ever half-written: the data goes to a temporary
file in the target folder, which is renamed over the target only once complete; ``-``
is standard output, an existing device or FIFO is written through (never replaced) and
a symlink's target is replaced (the link stays). :func:`check_outputs` refuses, before
any work, outputs that cannot be written or would destroy something: it is the one
enforcement of the output rule (docs/outputs.md) - an input is never an output, and an
existing file is replaced only when it is rotgraph's own output from an earlier run
(:func:`is_rotgraph_output`) or when the user says so (``overwrite``, ``--overwrite``).
:func:`output_group` makes the outputs of one run appear together or not at all.
"""

from __future__ import annotations

import contextlib
import contextvars
import errno
import io
import os
import re
import stat
import sys
import tempfile
from pathlib import Path

from ..errors import InputError
from .compressed import input_bytes, input_head
from .parts import parquet_parts

__all__ = ["read_text", "read_head", "is_float", "check_outputs", "probe_folder", "atomic_write", "writes_to_stdout", "STDOUT",
           "is_rotgraph_output", "check_replaceable", "output_group", "OWN_SIGNATURES", "write_error",
           "input_datasets", "refuse_input_dataset"]

#: The output name that means standard output (``-o -``).
STDOUT = "-"


def _wide_encoding(data: bytes) -> str | None:
    """The encoding ("UTF-16" or "UTF-32") when ``data`` is text in one of those (Windows
    editors and PowerShell's ``>`` write UTF-16), told by its byte-order mark or, without
    one, by the NUL bytes of ASCII characters; else None."""
    if data.startswith((b"\xff\xfe\x00\x00", b"\x00\x00\xfe\xff")):
        return "UTF-32"
    if data.startswith((b"\xff\xfe", b"\xfe\xff")):
        return "UTF-16"
    head = data[:512]
    if len(head) >= 4 and len(head) % 2 == 0:
        even, odd = head[0::2], head[1::2]
        for text, zeros in ((even, odd), (odd, even)):  # UTF-16 LE / BE of ASCII text
            if zeros.count(0) == len(zeros) and 0 not in text:
                return "UTF-16"
    return None


def is_float(s: str) -> bool:
    """Whether ``float(s)`` accepts the string."""
    try:
        float(s)
    except ValueError:
        return False
    return True


def _read_error(path, exc: OSError) -> InputError:
    if isinstance(exc, FileNotFoundError):
        return InputError("no such file", path=str(path))
    if isinstance(exc, IsADirectoryError):
        return InputError("is a folder, expected a file", path=str(path))
    return InputError(f"cannot read: {exc.strerror or exc}", path=str(path))


def read_head(path, n: int = 65536) -> bytes:
    """The first ``n`` bytes of a file (for format detection; of the data it holds when it
    is compressed, as in :func:`read_text`); a missing or unreadable file is an
    :class:`InputError` as in :func:`read_text`."""
    try:
        return input_head(path, n)  # decompressed when gzip, bzip2 or xz (rotgraph.io.compressed)
    except OSError as exc:
        raise _read_error(path, exc) from None


def read_text(path) -> str:
    """The whole file as text, with clear errors for missing, binary, UTF-16/32 or otherwise
    non-UTF-8 files (a UTF-8 byte-order mark is fine). A gzip, bzip2 or xz file (told by its
    magic bytes) is the text it holds (:mod:`rotgraph.io.compressed`: a corrupt or truncated
    one is an :class:`InputError` naming the file; line numbers count the decompressed text)."""
    try:
        data = input_bytes(path)  # decompressed when gzip, bzip2 or xz (rotgraph.io.compressed)
    except OSError as exc:
        raise _read_error(path, exc) from None
    wide = _wide_encoding(data)
    if wide:
        raise InputError(f"{wide} text, expected UTF-8 (save the file as UTF-8)", path=str(path), line=1)
    if b"\x00" in data:
        line = data[: data.index(b"\x00")].count(b"\n") + 1
        raise InputError("binary data (NUL byte), expected text", path=str(path), line=line)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise InputError("not valid UTF-8 text", path=str(path), line=line) from None


def _output_mode(path: Path) -> int:
    """The permission bits an output file should get: the existing target's, else those of
    a newly created file (0666 less the umask), as a plain ``open(path, "w")`` would."""
    try:
        return stat.S_IMODE(os.stat(path).st_mode)
    except OSError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask


def _output_folder(path: Path) -> Path:
    """The folder an output goes to; an InputError naming it when it does not exist."""
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise InputError("output folder does not exist", path=str(folder))
    return folder


# /dev/stdout, /dev/fd/N, /proc/self/fd/N: names of this process's open files.
_FD_NAME = re.compile(r"^/(?:dev/fd|proc/(self|\d+)/fd)/(\d+)$")


def _own_fd(path) -> int | None:
    """The file descriptor of this process that ``path`` names (``/dev/stdout`` ->
    ``/proc/self/fd/1``, ``/dev/fd/N``, ``/proc/self/fd/N``), following symlinks; else None."""
    p = os.path.abspath(os.fspath(path))
    for _ in range(40):  # the kernel's own limit on a symlink chain
        m = _FD_NAME.match(p)
        if m:
            pid = m.group(1)
            return int(m.group(2)) if pid in (None, "self") or int(pid) == os.getpid() else None
        try:
            link = os.readlink(p)
        except OSError:  # not a symlink (or missing)
            return None
        p = os.path.normpath(os.path.join(os.path.dirname(p), link))
    return None


def writes_to_stdout(path) -> bool:
    """Whether writing ``path`` writes this process's standard output: ``-`` (``-o -``),
    ``/dev/stdout`` or ``/dev/fd/1``. Commands print their summary to stderr then."""
    return path is not None and (os.fspath(path) == STDOUT or _own_fd(path) == 1)


def _target(path: Path) -> Path:
    """What writing ``path`` replaces: the file a symlink (chain) ends at, else ``path``."""
    return Path(os.path.realpath(path)) if path.is_symlink() else path


def _special(path: Path) -> os.stat_result | None:
    """The status of an existing output that is not a regular file or a folder (a
    character or block device such as /dev/null, a FIFO, a socket): written through."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return None if stat.S_ISREG(st.st_mode) or stat.S_ISDIR(st.st_mode) else st


#: OS errors of a write that ran out of room: the message is the reason alone
#: (``FILE: no space left on device``), not ``cannot write here``.
_FULL = {errno.ENOSPC, errno.EFBIG, getattr(errno, "EDQUOT", errno.ENOSPC)}


def write_error(exc: OSError, path, folder=None) -> InputError:
    """The :class:`InputError` (exit 3) of an OS error writing the output ``path``: the reason
    alone when the disk is full (``no space left on device``, a quota, a file too large),
    else ``cannot write here: <reason>``."""
    if exc.errno in _FULL:
        reason = exc.strerror or str(exc)
        return InputError(reason[:1].lower() + reason[1:], path=str(path))
    return _write_error(exc, path, folder)


def _write_error(exc: OSError, path, folder=None) -> InputError:
    """``cannot write here: <reason>`` naming the output."""
    if isinstance(exc, FileNotFoundError) and folder is not None and Path(folder).is_dir():
        reason = f"the folder {folder} does not accept new files"  # /proc, some FUSE mounts
    elif exc.errno in (errno.EACCES, errno.EPERM):
        reason = "permission denied" + (f" in the folder {folder}" if folder is not None else "")
    else:
        reason = exc.strerror or str(exc)
        reason = reason[:1].lower() + reason[1:]
    return InputError(f"cannot write here: {reason}", path=str(path))


# =========================================================================== whose file is it

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
        raise _write_error(PermissionError(errno.EACCES, os.strerror(errno.EACCES)), shown, folder)
    if hasattr(os, "O_TMPFILE"):
        try:
            os.close(os.open(folder, os.O_TMPFILE | os.O_WRONLY, 0o600))
            return
        except OSError as exc:
            if exc.errno not in _NO_TMPFILE:
                raise _write_error(exc, shown, folder) from None
    before = os.stat(folder)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{Path(shown).name}.", suffix=".tmp", dir=folder)
    except OSError as exc:
        raise _write_error(exc, shown, folder) from None
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
        elif _own_fd(o) is not None:
            key = f"<fd {_own_fd(o)}>"
        else:
            key = None
        if key is not None:  # an open file of this process (stdout, /dev/fd/N): written through
            if key in seen:
                also = "" if seen[key] == shown else f" (also as {seen[key]})"
                raise InputError(f"named twice as an output{also}", path=shown)
            seen[key] = shown
            continue
        out = Path(o)
        target = _target(out)
        special = _special(target)
        if special is not None:  # a device or FIFO: written through, never replaced
            if not os.access(target, os.W_OK):
                raise InputError("cannot write here: permission denied", path=shown)
            if stat.S_ISFIFO(special.st_mode):  # two writers of one FIFO would interleave
                key = ("fifo", special.st_dev, special.st_ino)
                if key in seen:
                    raise InputError(f"named twice as an output (also as {seen[key]})", path=shown)
                seen[key] = shown
            continue
        folder = _output_folder(target)
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


def _text_kwargs(mode: str, newline) -> dict:
    return {} if "b" in mode else {"encoding": "utf-8", "newline": newline}


@contextlib.contextmanager
def _write_stdout(mode: str, newline):
    """Collect the output, then write it to standard output at once (nothing on an error)."""
    binary = "b" in mode
    buf = io.BytesIO() if binary else io.StringIO(newline=newline)
    yield buf
    data = buf.getvalue()
    stream = getattr(sys.stdout, "buffer", None)
    if stream is None:  # a text-only stdout (an embedding application's)
        if binary:
            raise InputError("standard output does not take binary data", path=STDOUT)
        sys.stdout.write(data)
        sys.stdout.flush()
        return
    sys.stdout.flush()  # what was printed before comes first
    stream.write(data if binary else data.encode("utf-8"))
    stream.flush()


@contextlib.contextmanager
def _write_through(path, mode: str, newline, fd: int | None = None):
    """Write an existing device or FIFO (or an open file of this process, ``fd``) in place,
    as a plain ``open(path, "w")`` would: no temporary file, no rename."""
    try:
        if fd is not None:
            for s in (sys.stdout, sys.stderr):
                with contextlib.suppress(Exception):
                    s.flush()
            fh = os.fdopen(os.dup(fd), mode, **_text_kwargs(mode, newline))
        else:
            fh = open(path, mode, **_text_kwargs(mode, newline))
    except OSError as exc:
        raise _write_error(exc, path) from None
    try:
        with fh:
            yield fh
            fh.flush()
    except OSError as exc:  # a full device (/dev/full), a broken FIFO: the output's error
        if isinstance(exc, BrokenPipeError):
            raise
        raise write_error(exc, path) from None


@contextlib.contextmanager
def atomic_write(path, mode: str = "w", newline: str | None = ""):
    """Open a temporary file beside ``path`` for writing; rename it over ``path`` on success.

    On any exception (KeyboardInterrupt included) the target is left as it was and the
    temporary file is removed (a kill can leave a ``.tmp`` file behind, never a
    half-written target). The new file gets the mode bits of the file it replaces.

    What is at ``path`` is never destroyed: ``-`` writes standard output (the data is
    collected and written at once, nothing on an error); an existing device or FIFO
    (``/dev/null``, a named pipe) and ``/dev/stdout``, ``/dev/fd/N`` are opened and written
    through; a symlink is followed and the file it points to replaced (temporary file in
    that file's folder), the link itself stays. A folder that refuses the temporary file is
    an :class:`InputError` ``cannot write here`` naming ``path``.
    """
    if os.fspath(path) == STDOUT:
        with _write_stdout(mode, newline) as fh:
            yield fh
        return
    fd = _own_fd(path)
    if fd is not None:
        with _write_through(path, mode, newline, fd=fd) as fh:
            yield fh
        return
    shown = path
    path = _target(Path(path))
    if _special(path) is not None:
        with _write_through(path, mode, newline) as fh:
            yield fh
        return
    folder = _output_folder(path)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=folder)
    except OSError as exc:
        raise _write_error(exc, shown, folder) from None
    try:
        fh = os.fdopen(fd, mode, **_text_kwargs(mode, newline))
        try:
            try:
                yield fh
            except OSError as exc:  # the writes of the block: a full disk is the output's error
                if exc.errno in _FULL:
                    raise write_error(exc, shown) from None
                raise
            try:  # what is still buffered goes out here, and may not fit
                fh.flush()
                os.fsync(fh.fileno())
                fh.close()
            except OSError as exc:
                raise write_error(exc, shown, folder) from None
        finally:
            if not fh.closed:  # an error above: close without a second error over the first
                with contextlib.suppress(OSError):
                    fh.close()
        with contextlib.suppress(OSError):  # mkstemp makes 0600 files: give the usual mode
            os.chmod(tmp, _output_mode(path))
        group = _GROUP.get()
        if group is not None:  # renamed with the other outputs of the run (output_group)
            group.add(tmp, path)
        else:
            try:
                os.replace(tmp, path)
            except OSError as exc:
                raise write_error(exc, shown, folder) from None
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


class _Group:
    """The outputs of one :func:`output_group`: temporary files to rename over their targets
    and files to remove, all at the end."""

    def __init__(self):
        self.renames: dict[Path, str] = {}
        self.removals: list[Path] = []

    def add(self, tmp: str, path: Path) -> None:
        old = self.renames.pop(path, None)
        if old is not None:  # written twice in the group: the last one counts
            with contextlib.suppress(OSError):
                os.unlink(old)
        self.renames[path] = tmp

    def discard(self, keep: dict | None = None) -> None:
        """Remove the temporary files (those not in ``keep``: an inner group's failure keeps
        the outer group's files)."""
        for path, tmp in list(self.renames.items()):
            if keep is None or keep.get(path) != tmp:
                with contextlib.suppress(OSError):
                    os.unlink(tmp)
                del self.renames[path]

    def commit(self) -> None:
        with _sigint_held():  # a Ctrl-C now waits until every file is in place
            try:
                while self.renames:
                    path, tmp = next(iter(self.renames.items()))
                    try:
                        os.replace(tmp, path)
                    except OSError as exc:
                        raise write_error(exc, path) from None
                    del self.renames[path]
            finally:
                self.discard()
            for p in self.removals:
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(p)


@contextlib.contextmanager
def _sigint_held():
    """Hold a Ctrl-C back while the block runs (in the main thread; elsewhere signals are not
    delivered to Python code anyway) and raise it as KeyboardInterrupt when the block ends."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []
    try:
        old = signal.signal(signal.SIGINT, lambda signum, frame: caught.append(signum))
    except (ValueError, OSError):  # no signals here (an embedding application)
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)
    if caught:
        if callable(old):
            old(signal.SIGINT, None)
        elif old == signal.SIG_DFL:
            raise KeyboardInterrupt


_GROUP: contextvars.ContextVar[_Group | None] = contextvars.ContextVar("rotgraph_output_group", default=None)


@contextlib.contextmanager
def output_group(remove=()):
    """The files :func:`atomic_write` writes inside the block are renamed into place together
    when the block ends without an error (a Ctrl-C meanwhile waits for the last rename), and
    the files in ``remove`` (e.g. a replaced model's files of the other format) removed then;
    on an error none is, their temporary files are removed and every earlier output stays as
    it was. A group inside a group is part of the outer one: its files are renamed with the
    outer group's, or dropped (with its ``remove`` list) when the inner block fails.
    Devices, FIFOs and standard output are written at once."""
    outer = _GROUP.get()
    if outer is not None:
        before = dict(outer.renames)
        try:
            yield
        except BaseException:
            outer.discard(keep=before)
            raise
        outer.removals.extend(Path(p) for p in remove)
        return
    group = _Group()
    token = _GROUP.set(group)
    try:
        yield
    except BaseException:
        group.discard()
        raise
    finally:
        _GROUP.reset(token)
    group.removals.extend(Path(p) for p in remove)
    group.commit()
