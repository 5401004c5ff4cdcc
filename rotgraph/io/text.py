"""Reading text files with clear errors.

:func:`read_text` is how every reader of :mod:`rotgraph.io` opens a text file (missing,
folder, binary, UTF-16/32 and non-UTF-8 files are :class:`~rotgraph.errors.InputError`
naming the file and, where there is one, the 1-based line); :func:`read_head` reads the
first bytes of a file for format detection (:mod:`rotgraph.io.formats`); the tables in
the files are parsed by :mod:`rotgraph.io.tables`.

Writing has two modules of its own, whose public names are names of this one too (it held
them once): :mod:`rotgraph.io.atomic` (every writer goes through :func:`atomic_write`: no
output is ever half-written; :func:`output_group`: the outputs of one run appear together or
not at all) and :mod:`rotgraph.io.outputs` (:func:`check_outputs`, the one enforcement of the
output rule of docs/outputs.md).
"""

from __future__ import annotations

from ..errors import InputError
from .atomic import STDOUT, atomic_write, output_group, write_error, writes_to_stdout  # noqa: F401
from .compressed import input_bytes, input_head
from .outputs import (  # noqa: F401
    OWN_SIGNATURES, PLOT_CREATOR, check_outputs, check_replaceable, input_datasets, is_rotgraph_output, probe_folder,
    refuse_input_dataset,
)

__all__ = ["read_text", "read_head", "is_float", "check_outputs", "probe_folder", "atomic_write", "writes_to_stdout", "STDOUT",
           "is_rotgraph_output", "check_replaceable", "output_group", "OWN_SIGNATURES", "write_error",
           "input_datasets", "refuse_input_dataset"]


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
