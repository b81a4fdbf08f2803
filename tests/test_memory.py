"""Freed memory goes back to the system after a job (daemon/service/memory.py)."""

from __future__ import annotations

import os
import subprocess
import sys
import threading

from daemon.service.memory import release_free_memory
from tests.daemon_harness import REPO
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


def test_threads_share_the_arenas_the_daemon_allows() -> None:
    """Eight threads allocating at once get arenas of their own (seven here) unless
    limit_arenas caps them, as the daemon does at its start: then two (glibc's
    malloc_stats counts them)."""
    script = (
        "import ctypes, sys, threading\n"
        "from daemon.service.memory import limit_arenas\n"
        "if sys.argv[1] == 'limit':\n"
        "    assert limit_arenas(2)\n"
        "def work():\n"
        "    for _ in range(2000):\n"
        "        chunks = [bytearray(200) for _ in range(100)]\n"
        "        del chunks\n"
        "threads = [threading.Thread(target=work) for _ in range(8)]\n"
        "[t.start() for t in threads]\n"
        "[t.join() for t in threads]\n"
        "ctypes.CDLL(ctypes.util.find_library('c')).malloc_stats()\n")
    env = {k: v for k, v in os.environ.items() if k != "MALLOC_ARENA_MAX"}

    def arenas(how: str) -> int:
        done = subprocess.run([sys.executable, "-c", "import ctypes.util\n" + script, how],
                              capture_output=True, text=True, env=env, cwd=REPO, check=True)
        return sum(line.startswith("Arena ") for line in done.stderr.splitlines())

    assert arenas("limit") == 2
    assert arenas("free") > 2  # what the cap prevents (on 2 cores: up to 16)
