"""Handing freed memory back to the system (design §13).

glibc keeps what a thread frees in that thread's arena for later use, up to the peak the
arena ever held; a learn job (a new thread each time, its Turn Back and Look and feature
search allocating tens of MB of temporaries) leaves its arena at that peak. The daemon
bench's learns on the simulated robot grew the RSS by 42 and 40 MB for the first two
learns and 2-4 MB for each after; ``malloc_trim`` returns the free pages.

With those trims, five learns in a row on the simulated robot still grew the RSS by 68
and 70 MB in two runs (288 → 357 MB): glibc gives threads that meet on the heap arenas
of their own (up to 8 per core), each holding its own free, fragmented pages. With two
arenas (``limit_arenas``, called as the daemon starts): +16 and −22 MB in two runs (274 → 290,
304 → 282), and the daemon's CPU in localisation mode unchanged (0.51 of a core against
0.48-0.50). A fixed mmap threshold (1 MB) held less still (+7 MB) but cost 50 % more CPU
per frame (each large temporary mapped, faulted in and unmapped): not used.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import os

ARENAS = 2  # glibc malloc arenas: the main thread's and one the other threads share
M_ARENA_MAX = -8  # mallopt's parameter number (glibc's malloc.h)


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


def limit_arenas(count: int = ARENAS) -> bool:
    """At most ``count`` glibc malloc arenas for the threads created from here on (call it
    before any is started); False where the C library has no such setting, or when the
    environment already chose (MALLOC_ARENA_MAX: a deployment's word wins)."""
    libc = _libc()
    if libc is None or not hasattr(libc, "mallopt") or "MALLOC_ARENA_MAX" in os.environ:
        return False
    return bool(libc.mallopt(M_ARENA_MAX, count))
