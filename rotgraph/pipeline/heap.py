"""Where a solve's large arrays live: glibc's heap, not fresh ``mmap`` regions.

glibc serves every allocation above its mmap threshold (128 KiB to 32 MiB) with a fresh
``mmap`` and unmaps it when freed. A solve of 10^7 edges allocates and frees arrays of
hundreds of MB every iteration, and each new one is page-faulted in again. On a virtual
machine whose balloon driver hands free guest memory back to the host (free page
reporting: this project's machines), a page touched again after a few seconds is faulted in
by the host too: measured 1.3-1.4 s per 720 MB re-touched, 0.03 s when the memory stayed in
the process. ``rotgraph solve`` at 10^7 edges: 91.7 s whole with mmap, 68.5 s on the heap.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading

__all__ = ["heap_for_large_arrays"]

# glibc mallopt parameters and defaults
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
_M_MMAP_MAX = -4
_MMAP_THRESHOLD_DEFAULT = 128 * 1024
_TRIM_THRESHOLD_DEFAULT = 128 * 1024
_MMAP_THRESHOLD_MAX = 32 * 1024 * 1024  # glibc's upper bound on 64-bit
_MMAP_MAX_DEFAULT = 65536
_INT_MAX = 2**31 - 1


def _glibc():
    if not sys.platform.startswith("linux"):
        return None
    try:
        import ctypes

        libc = ctypes.CDLL("libc.so.6")
        libc.mallopt, libc.malloc_trim  # noqa: B018 - glibc, not another C library
        return libc
    except (OSError, AttributeError):
        return None


@contextlib.contextmanager
def heap_for_large_arrays():
    """Keep the block's large arrays on glibc's heap; give the memory back when it ends.

    * In the main thread (``rotgraph solve``, a script): no ``mmap`` for any size
      (``M_MMAP_MAX`` 0; glibc still falls back to it if the heap cannot grow) and no trim of
      the heap's top while the block runs: freed arrays are reused without page faults.
    * In another thread (a Dask worker's task) only the main arena can grow without
      ``mmap``: there, if Dask's nanny set ``MALLOC_TRIM_THRESHOLD_`` (which freezes glibc's
      mmap threshold at 128 KiB: every larger temporary a fresh mapping, solves ~2x slower),
      the threshold is raised to its 32 MiB maximum for the block.

    When the block ends the settings are put back (the trim threshold to
    ``MALLOC_TRIM_THRESHOLD_`` or glibc's default) and the free memory is returned with
    ``malloc_trim``. A no-op where glibc is not the C library, or ``MALLOC_MMAP_THRESHOLD_``
    or ``MALLOC_MMAP_MAX_`` were set by the user (their choice stands)."""
    libc = None if os.environ.get("MALLOC_MMAP_THRESHOLD_") or os.environ.get("MALLOC_MMAP_MAX_") else _glibc()
    mode = None
    if libc is not None:
        if threading.current_thread() is threading.main_thread():
            if libc.mallopt(_M_MMAP_MAX, 0) == 1:
                mode = "heap"
                libc.mallopt(_M_TRIM_THRESHOLD, _INT_MAX)
        elif os.environ.get("MALLOC_TRIM_THRESHOLD_") and libc.mallopt(_M_MMAP_THRESHOLD, _MMAP_THRESHOLD_MAX) == 1:
            mode = "threshold"
    try:
        yield
    finally:
        if mode == "heap":
            libc.mallopt(_M_MMAP_MAX, _MMAP_MAX_DEFAULT)
            try:
                trim = int(os.environ.get("MALLOC_TRIM_THRESHOLD_", _TRIM_THRESHOLD_DEFAULT))
            except ValueError:
                trim = _TRIM_THRESHOLD_DEFAULT
            libc.mallopt(_M_TRIM_THRESHOLD, min(max(trim, 0), _INT_MAX))
            libc.malloc_trim(0)
        elif mode == "threshold":
            libc.mallopt(_M_MMAP_THRESHOLD, _MMAP_THRESHOLD_DEFAULT)
            libc.malloc_trim(0)
