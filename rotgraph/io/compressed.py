"""Compressed inputs (gzip, bzip2, xz), and the progress of reading large input files.

Any input file rotgraph reads may be compressed (but a COLMAP database or model): the compression is told by the file's first
bytes (gzip ``1f 8b 08``; bzip2 ``BZh1`` .. ``BZh9`` then a block or end-of-stream magic;
xz ``FD 37 7A 58 5A 00``), whatever its name, and the file reads as the data it holds.
Every text reader goes through :func:`rotgraph.io.text.read_text` and format detection
through :func:`rotgraph.io.text.read_head`, which call :func:`input_bytes` and
:func:`input_head`; the streamed table reader (:func:`rotgraph.io.table_stream.read_table_file`)
opens its file with :func:`open_input`; the binary edge files (``.npz``, Parquet) and
``.mat`` files are decompressed into memory first. Format detection looks at the name
without its compression extension (:func:`uncompressed_name`: ``edges.txt.gz`` is a
``rotgraph`` text file, ``x.csv.xz`` a CSV, ``EGs.txt.bz2`` 1DSfM, ``garage.g2o.gz`` g2o).

A corrupt or truncated compressed file is an :class:`~rotgraph.errors.InputError` naming
the file (``corrupt or truncated gzip file (...)``); an error in the text it holds names
the file and the line of the decompressed text, as for any text file.

Speed (``read_view_graph`` of 46 MB of edge text, 500 000 edges, on a loaded 2-core machine):
plain 0.5 s; gzip (21 MB) 0.7-1.0 s; xz (19 MB) 2.7-4.7 s; bzip2 (19 MB) 10-18 s. The
streamed reader decompresses gzip and bzip2 through pyarrow's codecs (``fast``: 0.27 s for
that gzip file, :mod:`gzip` 0.34 s; 2.5x apart on a quieter machine).

Read progress: inside :func:`reading_progress` (``read_view_graph(..., progress=)``, which
``rotgraph solve`` gives its progress bars on a terminal), reading a file of more than
:data:`PROGRESS_MIN_BYTES` bytes on disk (:data:`PROGRESS_MIN_COMPRESSED_BYTES` when
compressed) calls ``progress(READ_STAGE, done, total)``: the bytes of the file on disk
read so far (compressed bytes for a compressed file) and the file's size. Without a
callback (the default; ``solve`` off a terminal) nothing is counted.
"""

from __future__ import annotations

import contextlib
import contextvars
import lzma
import os
import zlib
from typing import Callable

from ..errors import InputError

__all__ = [
    "COMPRESSION_SUFFIXES", "compression_of", "is_compressed", "uncompressed_name", "open_input", "input_head", "input_bytes",
    "reading_progress", "read_reporter", "READ_STAGE", "PROGRESS_MIN_BYTES", "PROGRESS_MIN_COMPRESSED_BYTES",
]

#: File-name extensions of compressed files (dropped by :func:`uncompressed_name`); the
#: compression itself is told by the magic bytes.
COMPRESSION_SUFFIXES = (".gz", ".bz2", ".xz")
#: The stage name of read progress (``progress(READ_STAGE, bytes_done, bytes_total)``).
READ_STAGE = "read"
#: Files larger than this on disk report read progress (plain text; a compressed file:
#: :data:`PROGRESS_MIN_COMPRESSED_BYTES`, decompression being slower than reading).
PROGRESS_MIN_BYTES = 8 << 20
PROGRESS_MIN_COMPRESSED_BYTES = 1 << 20

_MAGIC_BYTES = 10
_BZIP2_BLOCKS = (b"1AY&SY", b"\x17rE8P\x90")  # a compressed block (pi), the end of stream (sqrt pi)
_ARROW_CODECS = {"gzip": "gzip", "bzip2": "bz2"}
_CHUNK = 1 << 22  # bytes per read when progress is reported

_PROGRESS: contextvars.ContextVar[Callable[[str, int, int], None] | None] = contextvars.ContextVar(
    "rotgraph_read_progress", default=None)


def compression_of(head: bytes) -> str | None:
    """``gzip``, ``bzip2`` or ``xz`` when ``head`` (a file's first 10 bytes or more) starts
    with that compression's magic bytes, else None."""
    head = bytes(head[:_MAGIC_BYTES])
    if head.startswith(b"\x1f\x8b\x08"):
        return "gzip"
    if head.startswith(b"\xfd7zXZ\x00"):
        return "xz"
    if len(head) >= 10 and head.startswith(b"BZh") and 0x31 <= head[3] <= 0x39 and head[4:10] in _BZIP2_BLOCKS:
        return "bzip2"
    return None


def uncompressed_name(path) -> str:
    """The file name of ``path`` without a compression extension (``edges.txt.gz`` ->
    ``edges.txt``; any other name as it is): what format detection looks at."""
    name = os.path.basename(os.fspath(path))
    low = name.lower()
    for suffix in COMPRESSION_SUFFIXES:
        if low.endswith(suffix) and len(name) > len(suffix):
            return name[: -len(suffix)]
    return name


_ERRORS = (EOFError, OSError, ValueError, zlib.error, lzma.LZMAError)


def _stdlib_reader(kind: str, raw):
    import bz2
    import gzip

    return {"gzip": lambda r: gzip.GzipFile(fileobj=r, mode="rb"), "bzip2": bz2.BZ2File, "xz": lzma.LZMAFile}[kind](raw)


class _Decompressed:
    """A compressed file read as the data it holds (``read(n)``, ``close()``); every
    decompression error is an :class:`InputError` naming the file.

    The standard library (:mod:`gzip`, :mod:`bz2`, :mod:`lzma`) is the reference; with
    ``fast``, gzip and bzip2 go through pyarrow's codecs (~2.5x faster for gzip), and where
    pyarrow fails (a corrupt or truncated stream, or something the standard library
    accepts such as zeros after a gzip stream) the standard library takes over from the
    same point and decides: the same data or the same error either way."""

    def __init__(self, path, raw, kind: str, fast: bool):
        self.path, self.kind, self.raw = path, kind, raw
        self._done = 0  # bytes of data returned
        self._src = None  # pyarrow's own handle of the file (fast)
        self._f = None
        if fast and kind in _ARROW_CODECS and raw.seekable():
            import pyarrow as pa

            if pa.Codec.is_available(_ARROW_CODECS[kind]):
                self._src = pa.OSFile(os.fspath(path))
                self._f = pa.CompressedInputStream(self._src, _ARROW_CODECS[kind])
        if self._f is None:
            self._f = _stdlib_reader(kind, raw)

    def position(self) -> int:
        """Bytes of the compressed file consumed so far."""
        return self._src.tell() if self._src is not None else self.raw.tell()

    def read(self, n: int = -1) -> bytes:
        n = -1 if n is None else n
        if self._src is not None:
            try:
                data = self._f.read() if n < 0 else self._f.read(n)
            except _ERRORS:
                self._fall_back()
                data = self._read(n)
        else:
            data = self._read(n)
        self._done += len(data)
        return data

    def _read(self, n: int) -> bytes:
        try:
            return self._f.read() if n < 0 else self._f.read(n)
        except _ERRORS as exc:
            raise self._error(exc) from None

    def _fall_back(self) -> None:
        """pyarrow failed: the standard library reads on from the same point of the data."""
        self._close_fast()
        self.raw.seek(0)
        self._f = _stdlib_reader(self.kind, self.raw)
        skip = self._done
        while skip > 0:
            chunk = self._read(min(skip, _CHUNK))
            if not chunk:  # pragma: no cover - pyarrow returned data the standard library does not find
                raise InputError(f"corrupt {self.kind} file (decoders disagree)", path=str(self.path))
            skip -= len(chunk)

    def _close_fast(self) -> None:
        if self._src is not None:
            with contextlib.suppress(Exception):
                self._f.close()
            with contextlib.suppress(Exception):
                self._src.close()
            self._src = None

    def _error(self, exc: Exception) -> InputError:
        if isinstance(exc, OSError) and exc.errno is not None:  # the disk, not the data
            return InputError(f"cannot read: {exc.strerror or exc}", path=str(self.path))
        detail = str(exc).strip() or type(exc).__name__
        detail = detail[:1].lower() + detail[1:]
        return InputError(f"corrupt or truncated {self.kind} file ({detail[:120]})", path=str(self.path))

    def close(self) -> None:
        try:
            if self._src is not None:
                self._close_fast()
            else:
                self._f.close()
        finally:
            self.raw.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def open_input(path, fast: bool = False):
    """``path`` opened for reading bytes: the file itself (a binary file object) or, when
    compressed, a reader of the data it holds (``read(n)``, ``close()``, a context
    manager; its errors are :class:`InputError`\\ s naming the file). ``fast``: decompress
    gzip and bzip2 through pyarrow's codecs (for large files). Opening a missing or
    unreadable file raises the ``OSError``."""
    raw = open(path, "rb")
    try:
        kind = compression_of(raw.peek(_MAGIC_BYTES))
        return raw if kind is None else _Decompressed(path, raw, kind, fast)
    except BaseException:
        raw.close()
        raise


def is_compressed(path) -> bool:
    """Whether ``path`` is a gzip, bzip2 or xz file (False when it cannot be read)."""
    try:
        with open(path, "rb") as fh:
            return compression_of(fh.peek(_MAGIC_BYTES)) is not None
    except OSError:
        return False


# The decompressed head of the last compressed file asked for (format detection reads a
# file's head several times; a bzip2 block is 900 kB of work): (identity, data, complete).
_HEAD_CACHE: list = [None]
_HEAD_BYTES = 1 << 16


def input_head(path, n: int = _HEAD_BYTES) -> bytes:
    """The first ``n`` bytes of the data in ``path`` (decompressed when it is compressed);
    an ``OSError`` when it cannot be opened, an :class:`InputError` when it is corrupt."""
    with open_input(path) as fh:
        if not isinstance(fh, _Decompressed):
            return fh.read(n)
        st = os.fstat(fh.raw.fileno())
        key = (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)
        cached = _HEAD_CACHE[0]
        if cached is not None and cached[0] == key and (len(cached[1]) >= n or cached[2]):
            return cached[1][:n]
        want = max(n, _HEAD_BYTES)
        data = fh.read(want)
        _HEAD_CACHE[0] = (key, data, len(data) < want)
        return data[:n]


def input_bytes(path) -> bytes | bytearray:
    """All the data in ``path`` (decompressed when it is compressed), reporting read
    progress (see the module docstring); errors as :func:`input_head`."""
    with open_input(path) as fh:
        report = read_reporter(fh)
        if report is None:
            return fh.read()
        data = bytearray()
        while True:
            chunk = fh.read(_CHUNK)
            if not chunk:
                break
            data += chunk
            report()
        report(done=True)
        return data


@contextlib.contextmanager
def reading_progress(callback: Callable[[str, int, int], None] | None):
    """Report the progress of reading large input files to ``callback(stage, done, total)``
    (see the module docstring) inside the block; None: nothing is reported."""
    token = _PROGRESS.set(callback)
    try:
        yield
    finally:
        _PROGRESS.reset(token)


def read_reporter(fh) -> Callable[..., None] | None:
    """For a file opened by :func:`open_input` and read from its start: a function that
    reports how much of it has been read (``report()``; ``report(done=True)`` at its end),
    when a progress callback is set (:func:`reading_progress`) and the file is large; else
    None. It reports once at once (0 bytes)."""
    callback = _PROGRESS.get()
    if callback is None:
        return None
    packed = isinstance(fh, _Decompressed)
    try:
        size = os.fstat((fh.raw if packed else fh).fileno()).st_size
    except (OSError, AttributeError, ValueError):
        return None
    if size <= (PROGRESS_MIN_COMPRESSED_BYTES if packed else PROGRESS_MIN_BYTES):
        return None
    position = fh.position if packed else fh.tell

    def report(done: bool = False) -> None:
        callback(READ_STAGE, size if done else min(position(), size), size)

    report()
    return report
