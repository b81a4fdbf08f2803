"""Handing freed memory back to the system (design §13).

glibc keeps what a thread frees in that thread's arena for later use, up to the peak the
arena ever held; a learn job (a new thread each time, its Turn Back and Look and feature
search allocating tens of MB of temporaries) leaves its arena at that peak. The daemon
bench's learns on the simulated robot grew the RSS by 42 and 40 MB for the first two
learns and 2-4 MB for each after; ``malloc_trim`` returns the free pages.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools


@functools.cache
def _libc() -> ctypes.CDLL | None:
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name) if name else None
    except OSError:
        return None
    return libc if libc is not None and hasattr(libc, "malloc_trim") else None


def release_free_memory() -> bool:
    """Return the C heap's free pages to the system (glibc's malloc_trim); False where
    the C library has no such call (musl, macOS): nothing is done there."""
    libc = _libc()
    if libc is None:
        return False
    libc.malloc_trim(0)
    return True
