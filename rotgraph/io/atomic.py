"""Writing files atomically: every writer of rotgraph goes through :func:`atomic_write`,
so no output is ever half-written: the data goes to a temporary file in the target folder,
which is renamed over the target only once complete; ``-`` is standard output, an existing
device or FIFO is written through (never replaced) and a symlink's target is replaced (the
link stays). :func:`output_group` makes the outputs of one run appear together or not at
all. What an output path is (standard output, an open file of this process, a device, a
symlink) and the errors of a write that fails are worded here once, for the output rule of
:mod:`rotgraph.io.outputs` too.
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

__all__ = ["STDOUT", "atomic_write", "output_group", "writes_to_stdout", "write_error", "cannot_write_error", "own_fd",
           "output_target", "special_file", "output_folder"]

#: The output name that means standard output (``-o -``).
STDOUT = "-"


def _output_mode(path: Path) -> int:
    """The permission bits an output file should get: the existing target's, else those of
    a newly created file (0666 less the umask), as a plain ``open(path, "w")`` would."""
    try:
        return stat.S_IMODE(os.stat(path).st_mode)
    except OSError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask


def output_folder(path: Path) -> Path:
    """The folder an output goes to; an InputError naming it when it does not exist."""
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise InputError("output folder does not exist", path=str(folder))
    return folder


# /dev/stdout, /dev/fd/N, /proc/self/fd/N: names of this process's open files.
_FD_NAME = re.compile(r"^/(?:dev/fd|proc/(self|\d+)/fd)/(\d+)$")


def own_fd(path) -> int | None:
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
    return path is not None and (os.fspath(path) == STDOUT or own_fd(path) == 1)


def output_target(path: Path) -> Path:
    """What writing ``path`` replaces: the file a symlink (chain) ends at, else ``path``."""
    return Path(os.path.realpath(path)) if path.is_symlink() else path


def special_file(path: Path) -> os.stat_result | None:
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
    return cannot_write_error(exc, path, folder)


def cannot_write_error(exc: OSError, path, folder=None) -> InputError:
    """``cannot write here: <reason>`` naming the output."""
    if isinstance(exc, FileNotFoundError) and folder is not None and Path(folder).is_dir():
        reason = f"the folder {folder} does not accept new files"  # /proc, some FUSE mounts
    elif exc.errno in (errno.EACCES, errno.EPERM):
        reason = "permission denied" + (f" in the folder {folder}" if folder is not None else "")
    else:
        reason = exc.strerror or str(exc)
        reason = reason[:1].lower() + reason[1:]
    return InputError(f"cannot write here: {reason}", path=str(path))



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
        raise cannot_write_error(exc, path) from None
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
    fd = own_fd(path)
    if fd is not None:
        with _write_through(path, mode, newline, fd=fd) as fh:
            yield fh
        return
    shown = path
    path = output_target(Path(path))
    if special_file(path) is not None:
        with _write_through(path, mode, newline) as fh:
            yield fh
        return
    folder = output_folder(path)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=folder)
    except OSError as exc:
        raise cannot_write_error(exc, shown, folder) from None
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
