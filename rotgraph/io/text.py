"""Reading text tables with line numbers, and writing files atomically.

Every reader in :mod:`rotgraph.io` goes through :func:`read_rows`, so every malformed
input gives the same :class:`~rotgraph.errors.InputError` naming the file and the
1-based line; every writer goes through :func:`atomic_write`, so no output is ever
half-written: the data goes to a temporary file in the target folder, which is renamed
over the target only once complete.
"""

from __future__ import annotations

import contextlib
import os
import stat
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError

__all__ = ["Rows", "read_text", "read_rows", "read_csv_table", "parse_floats", "atomic_write"]


@dataclass
class Rows:
    """The data lines of a text file: their 1-based line numbers and their fields."""

    path: str
    line_numbers: list[int]
    fields: list[list[str]]

    def __len__(self) -> int:
        return len(self.fields)


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


def read_text(path) -> str:
    """The whole file as text, with clear errors for missing, binary, UTF-16/32 or otherwise
    non-UTF-8 files (a UTF-8 byte-order mark is fine)."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except FileNotFoundError:
        raise InputError("no such file", path=str(path)) from None
    except IsADirectoryError:
        raise InputError("is a folder, expected a file", path=str(path)) from None
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror or exc}", path=str(path)) from None
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


def read_rows(path, *, sep: str | None = None, comment: str = "#") -> Rows:
    """Split a text file into fields, skipping blank lines and ``comment`` lines.

    ``sep=None`` splits on white space; ``sep=","`` splits CSV (fields stripped).
    """
    text = read_text(path)
    numbers: list[int] = []
    fields: list[list[str]] = []
    for k, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if not s or s.startswith(comment):
            continue
        numbers.append(k)
        fields.append(s.split() if sep is None else [f.strip() for f in s.split(sep)])
    return Rows(str(path), numbers, fields)


def read_csv_table(path, required: list[str], expected: str, noun: str) -> tuple[list[str], Rows]:
    """A CSV file with a header naming at least ``required``: ``(lower-case header, data rows)``.

    Empty file, missing columns, no data rows and rows whose field count differs from the
    header are :class:`InputError` at their line; ``expected`` describes the header for the
    empty-file message and ``noun`` names the data rows ("rotations", "poses").
    """
    rows = read_rows(path, sep=",")
    if len(rows) == 0:
        raise InputError(f"the file is empty, expected a header {expected}", str(path), 1)
    header = [h.lower() for h in rows.fields[0]]
    missing = [c for c in required if c not in header]
    if missing:
        raise InputError(f"CSV header lacks column(s) {', '.join(missing)}", rows.path, rows.line_numbers[0])
    data = Rows(rows.path, rows.line_numbers[1:], rows.fields[1:])
    if len(data) == 0:
        raise InputError(f"no {noun} after the header", rows.path, rows.line_numbers[0])
    for ln, f in zip(data.line_numbers, data.fields):
        if len(f) != len(header):
            raise InputError(f"expected {len(header)} fields as in the header, got {len(f)}", data.path, ln)
    return header, data


def parse_floats(rows: Rows, columns: list[int], names: list[str] | None = None, finite: bool = True) -> np.ndarray:
    """The given columns of every row as a float64 array ``(len(rows), len(columns))``.

    Raises :class:`InputError` at the first row with a missing, non-numeric or (with
    ``finite``) NaN/infinite field.
    """
    names = names or [f"field {c + 1}" for c in columns]
    try:
        out = np.array([[f[c] for c in columns] for f in rows.fields], dtype=np.float64)
    except (ValueError, IndexError):
        out = None
    if out is None:  # find the first bad row, for the message
        for ln, f in zip(rows.line_numbers, rows.fields):
            for c, name in zip(columns, names):
                if c >= len(f):
                    raise InputError(f"missing {name} (expected at least {max(columns) + 1} fields, got {len(f)})", rows.path, ln)
                try:
                    float(f[c])
                except ValueError:
                    raise InputError(f"{name} is not a number: {f[c][:40]!r}", rows.path, ln) from None
        raise AssertionError("unreachable")  # pragma: no cover
    out = out.reshape(len(rows), len(columns))
    if finite and not np.isfinite(out).all():
        r, c = np.argwhere(~np.isfinite(out))[0]
        raise InputError(f"{names[c]} is not finite ({rows.fields[r][columns[c]]})", rows.path, rows.line_numbers[r])
    return out


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
