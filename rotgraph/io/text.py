"""Reading text files with clear errors, and writing files atomically.

:func:`read_text` is how every reader of :mod:`rotgraph.io` opens a text file (missing,
folder, binary, UTF-16/32 and non-UTF-8 files are :class:`~rotgraph.errors.InputError`
naming the file and, where there is one, the 1-based line); :func:`read_head` reads the
first bytes of a file for format detection (:mod:`rotgraph.io.formats`); the tables in
the files are parsed by :mod:`rotgraph.io.tables`. Every writer goes through
:func:`atomic_write`, so no output is ever half-written: the data goes to a temporary
file in the target folder, which is renamed over the target only once complete.
"""

from __future__ import annotations

import contextlib
import os
import stat
import tempfile
from pathlib import Path

from ..errors import InputError

__all__ = ["read_text", "read_head", "is_float", "check_outputs", "atomic_write"]


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
    """The first ``n`` bytes of a file (for format detection); a missing or unreadable file
    is an :class:`InputError` as in :func:`read_text`."""
    try:
        with open(path, "rb") as fh:
            return fh.read(n)
    except OSError as exc:
        raise _read_error(path, exc) from None


def read_text(path) -> str:
    """The whole file as text, with clear errors for missing, binary, UTF-16/32 or otherwise
    non-UTF-8 files (a UTF-8 byte-order mark is fine)."""
    try:
        data = Path(path).read_bytes()
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


def check_outputs(outputs, inputs=()) -> None:
    """Refuse, before any work, outputs that cannot be written or would destroy something:
    a missing output folder, an output that is a folder, the same file named twice, or an
    output that is one of the inputs (or a file inside an input folder)."""
    outs = [Path(o) for o in outputs if o is not None]
    seen: dict[Path, Path] = {}
    for out in outs:
        _output_folder(out)
        if out.is_dir():
            raise InputError("output is a folder, expected a file name", path=str(out))
        key = out.resolve()
        if key in seen:
            also = "" if str(seen[key]) == str(out) else f" (also as {seen[key]})"
            raise InputError(f"named twice as an output{also}", path=str(out))
        seen[key] = out
        if not out.exists():
            continue  # a new file destroys nothing
        for inp in inputs:
            ip = Path(inp)
            if not ip.exists():
                continue
            if ip.is_file() and os.path.samefile(ip, out):
                raise InputError("output would overwrite the input", path=str(out))
            # An input folder (a COLMAP project, a 1DSfM scene; a database's folder holds the
            # sparse model read beside it): nothing in it but rotgraph's own kinds of output.
            folder = ip if ip.is_dir() else (ip.parent if ip.name == "database.db" else None)
            if folder is not None and folder.resolve() in key.parents and out.suffix.lower() not in (".csv", ".json", ".png"):
                raise InputError(f"output would overwrite a file of the input folder {folder}", path=str(out))


@contextlib.contextmanager
def atomic_write(path, mode: str = "w", newline: str | None = ""):
    """Open a temporary file beside ``path`` for writing; rename it over ``path`` on success.

    On any exception (or a kill) the target is left as it was and the temporary file is
    removed (a kill can leave a ``.tmp`` file behind, never a half-written target).
    """
    path = Path(path)
    folder = _output_folder(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=folder)
    try:
        kwargs = {} if "b" in mode else {"encoding": "utf-8", "newline": newline}
        with os.fdopen(fd, mode, **kwargs) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        with contextlib.suppress(OSError):  # mkstemp makes 0600 files: give the usual mode
            os.chmod(tmp, _output_mode(path))
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
