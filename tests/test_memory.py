"""Freed memory goes back to the system after a job (daemon/service/memory.py)."""

from __future__ import annotations

import os
import subprocess
import sys
import threading

from daemon.service.memory import (
    M_ARENA_MAX,
    M_MMAP_THRESHOLD,
    M_TRIM_THRESHOLD,
    heap_settings,
    release_free_memory,
)
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
    tune_heap caps them, as the daemon does at its start: then two (glibc's
    malloc_stats counts them)."""
    script = (
        "import ctypes, sys, threading\n"
        "from daemon.service.memory import M_ARENA_MAX, tune_heap\n"
        "if sys.argv[1] == 'limit':\n"
        "    assert tune_heap({M_ARENA_MAX: 2})\n"
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


def test_the_heap_settings_leave_what_the_environment_chose() -> None:
    """All three by default; an arena count from the environment is kept; either
    threshold from the environment keeps both (glibc fixes them together)."""
    assert heap_settings({}, 2, 4096, 8192) == {
        M_ARENA_MAX: 2, M_MMAP_THRESHOLD: 4096, M_TRIM_THRESHOLD: 8192}
    assert heap_settings({"MALLOC_ARENA_MAX": "4"}, 2, 4096, 8192) == {
        M_MMAP_THRESHOLD: 4096, M_TRIM_THRESHOLD: 8192}
    assert heap_settings({"MALLOC_MMAP_THRESHOLD_": "65536"}, 2, 4096, 8192) == {
        M_ARENA_MAX: 2}
    assert heap_settings({"MALLOC_TRIM_THRESHOLD_": "0", "MALLOC_ARENA_MAX": "1"}) == {}


def test_large_temporaries_after_a_larger_one_are_handed_back() -> None:
    """A 24 MB block freed raises glibc's own mmap threshold to 24 MB, so eight 6 MB
    temporaries after it are carved from the heap, and the small blocks allocated between
    them (kept, as a frame's results are) keep those 48 MB resident once they are freed.
    With the daemon's fixed thresholds (tune_heap, as at its start) they are mapped and
    handed back whole."""
    script = (
        "import os, sys\n"
        "from daemon.service.memory import tune_heap\n"
        "from tools.daemon_process import usage\n"
        "if sys.argv[1] == 'tuned':\n"
        "    assert tune_heap()\n"
        "big = bytearray(24 << 20)\n"
        "del big\n"
        "before = usage(os.getpid()).rss_mb\n"
        "temporaries, kept = [], []\n"
        "for _ in range(8):\n"
        "    temporaries.append(bytearray(6 << 20))\n"
        "    kept.append(bytes(4000))\n"
        "del temporaries\n"
        "print(usage(os.getpid()).rss_mb - before)\n")
    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}

    def held_mb(how: str) -> float:
        done = subprocess.run([sys.executable, "-c", script, how], capture_output=True,
                              text=True, env=env, cwd=REPO, check=True)
        return float(done.stdout.split()[-1])

    assert held_mb("tuned") < 8.0
    assert held_mb("glibc") > 40.0  # what the fixed thresholds prevent
