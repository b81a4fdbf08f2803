"""Handing freed memory back to the system (design §13).

glibc keeps what a thread frees in that thread's arena for later use, up to the peak the
arena ever held; a learn job (a new thread each time, its Turn Back and Look and feature
search allocating tens of MB of temporaries) leaves its arena at that peak. The daemon
bench's learns on the simulated robot grew the RSS by 42 and 40 MB for the first two
learns and 2-4 MB for each after; ``malloc_trim`` returns the free pages.

With those trims, five learns in a row on the simulated robot still grew the RSS by 68
and 70 MB in two runs (288 → 357 MB): glibc gives threads that meet on the heap arenas
of their own (up to 8 per core), each holding its own free, fragmented pages. With two
arenas (M_ARENA_MAX in ``tune_heap``, called as the daemon starts): +16 and −22 MB in two
runs (274 → 290, 304 → 282), and the daemon's CPU in localisation mode unchanged (0.51 of
a core against 0.48-0.50). A fixed mmap threshold (1 MB) held less still (+7 MB) but
cost 50 % more CPU per frame: not used then (see below for why).

Half-hour soaks still ended 31-149 MB above a fresh daemon, the main arena's heap swinging
between 50 and 137 MB: glibc raises its mmap threshold to the largest mapped block freed
(up to 32 MB), so after a learn's first large temporaries every later one up to that size
is carved from the heap, and a small block allocated after them pins the pages below it.
A fixed threshold keeps blocks of ``MMAP_THRESHOLD`` and more out of the heaps (mapped and
returned whole); fixing it also fixes glibc's trim threshold, which at its 128 kB default
hands the heap's top back after nearly every frame and faults it in again, so that is
raised to ``TRIM_THRESHOLD`` (``tune_heap``; numbers in docs/design.md §13).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import os
from collections.abc import Mapping

ARENAS = 2  # glibc malloc arenas: the main thread's and one the other threads share
MMAP_THRESHOLD = 4 * 1024 * 1024  # bytes: a block this large or larger is mapped on its own
TRIM_THRESHOLD = 32 * 1024 * 1024  # bytes free at a heap's top before they are handed back

# mallopt's parameter numbers (glibc's malloc.h), each with the environment variable that
# sets it at the process's start (a deployment's word wins over ours).
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD, M_ARENA_MAX = -1, -3, -8
ENVIRONMENT_NAME = {M_TRIM_THRESHOLD: "MALLOC_TRIM_THRESHOLD_",
                    M_MMAP_THRESHOLD: "MALLOC_MMAP_THRESHOLD_", M_ARENA_MAX: "MALLOC_ARENA_MAX"}


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


def heap_settings(environ: Mapping[str, str], arenas: int = ARENAS,
                  mmap_threshold: int = MMAP_THRESHOLD,
                  trim_threshold: int = TRIM_THRESHOLD) -> dict[int, int]:
    """The mallopt settings the daemon makes, parameter → value, leaving out those the
    environment already chose. glibc fixes both thresholds when either is set (no
    dynamic mmap threshold after that), so the two are made together or not at all."""
    wanted = {M_ARENA_MAX: arenas}
    if not {ENVIRONMENT_NAME[M_MMAP_THRESHOLD], ENVIRONMENT_NAME[M_TRIM_THRESHOLD]} & set(environ):
        wanted |= {M_MMAP_THRESHOLD: mmap_threshold, M_TRIM_THRESHOLD: trim_threshold}
    return {param: value for param, value in wanted.items()
            if ENVIRONMENT_NAME[param] not in environ}


def tune_heap(settings: dict[int, int] | None = None) -> bool:
    """Apply ``settings`` (``heap_settings`` of this process's environment by default);
    call it before any thread starts. False where the C library has no mallopt (musl,
    macOS: nothing is done there) or refused one."""
    libc = _libc()
    if libc is None or not hasattr(libc, "mallopt"):
        return False
    chosen = heap_settings(os.environ) if settings is None else settings
    return all([bool(libc.mallopt(param, value)) for param, value in chosen.items()])
