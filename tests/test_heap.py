"""Large arrays of a solve on glibc's heap (rotgraph.pipeline.heap), measured through
glibc's own accounting (mallinfo2: bytes in mmap'ed chunks vs in the heap)."""

import ctypes
import sys
import threading

import numpy as np
import pytest

from rotgraph.pipeline.heap import heap_for_large_arrays


class _Mallinfo2(ctypes.Structure):
    _fields_ = [(name, ctypes.c_size_t) for name in
                ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks", "fordblks", "keepcost")]


def _libc():
    if not sys.platform.startswith("linux"):
        pytest.skip("glibc only")
    try:
        libc = ctypes.CDLL("libc.so.6")
        libc.mallinfo2.restype = _Mallinfo2
    except (OSError, AttributeError):
        pytest.skip("no glibc mallinfo2")
    return libc


def _mapped_while_allocated(libc, nbytes=64 << 20) -> int:
    """Bytes in mmap'ed chunks while an array of ``nbytes`` is alive."""
    a = np.empty(nbytes, dtype=np.uint8)
    a[:: 4096] = 1
    mapped = libc.mallinfo2().hblkhd
    del a
    return mapped


def test_large_arrays_come_from_the_heap_in_the_block_and_from_mmap_after(monkeypatch):
    monkeypatch.delenv("MALLOC_MMAP_THRESHOLD_", raising=False)
    monkeypatch.delenv("MALLOC_MMAP_MAX_", raising=False)
    libc = _libc()
    before = libc.mallinfo2().hblkhd
    assert _mapped_while_allocated(libc) >= before + (64 << 20)  # glibc's default: a fresh mapping
    with heap_for_large_arrays():
        assert _mapped_while_allocated(libc) < before + (64 << 20)
        heap = libc.mallinfo2().arena
        assert heap >= 64 << 20  # the freed array stays in the heap, ready for the next one
        assert _mapped_while_allocated(libc) < before + (64 << 20) and libc.mallinfo2().arena == heap
    assert _mapped_while_allocated(libc) >= before + (64 << 20)  # settings put back
    assert libc.mallinfo2().arena < heap  # and the memory given back (malloc_trim)


def test_other_threads_keep_glibcs_settings_without_dasks_variable(monkeypatch):
    monkeypatch.delenv("MALLOC_TRIM_THRESHOLD_", raising=False)
    monkeypatch.delenv("MALLOC_MMAP_THRESHOLD_", raising=False)
    libc = _libc()
    seen = []

    def task():
        with heap_for_large_arrays():
            seen.append(_mapped_while_allocated(libc) - libc.mallinfo2().hblkhd)

    t = threading.Thread(target=task)
    t.start()
    t.join()
    assert seen and seen[0] >= 64 << 20  # a worker thread's arena cannot grow without mmap: untouched
