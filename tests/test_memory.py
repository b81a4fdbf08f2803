"""Freed memory goes back to the system after a job (daemon/service/memory.py)."""

from __future__ import annotations

import os
import threading

from daemon.service.memory import release_free_memory
from tools.daemon_process import usage


def test_what_a_finished_thread_freed_is_handed_back() -> None:
    """A thread that allocated 60 MB in malloc'd chunks and freed them (the top of its
    heap still in use, so nothing is trimmed on its own) leaves the RSS up until
    release_free_memory (Debian's glibc has malloc_trim)."""
    pinned: list[bytes] = []

    def churn() -> None:
        held = [bytes(2000) for _ in range(30_000)]
        pinned.append(bytes(2000))  # allocated last: the top chunk stays in use
        del held

    worker = threading.Thread(target=churn)
    worker.start()
    worker.join()
    before = usage(os.getpid()).rss_mb
    assert release_free_memory()
    after = usage(os.getpid()).rss_mb
    assert before - after > 30.0, (before, after)
