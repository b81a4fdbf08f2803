"""Timing helpers for benchmarks: medians of repeated runs on one core."""

from __future__ import annotations

import os
import statistics
import time
from collections.abc import Callable

from kernel.threads import BLAS_THREAD_VARIABLES

_ENVIRONMENT = dict(os.environ)  # as this process was started, before pin_to_one_core


def pin_to_one_core() -> None:
    """Run the benchmark on one core (and tell OpenCV and BLAS to use one thread: BLAS
    reads its setting when numpy is first imported, so call this before that)."""
    for name in BLAS_THREAD_VARIABLES:
        os.environ[name] = "1"
    import cv2

    cv2.setNumThreads(1)
    if hasattr(os, "sched_setaffinity"):
        cpus = sorted(os.sched_getaffinity(0))
        os.sched_setaffinity(0, {cpus[0]})


def median_seconds(fn: Callable[[], object], repeats: int, inner: int = 1,
                   warmup: int = 1) -> float:
    """Median over ``repeats`` runs of the time of one call of ``fn`` (each run times
    ``inner`` calls and divides), after ``warmup`` untimed calls."""
    for _ in range(warmup):
        fn()
    samples = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(inner):
            fn()
        samples.append((time.perf_counter() - t0) / inner)
    return statistics.median(samples)


def original_environment() -> dict[str, str]:
    """The environment this process was started with: a process it starts to measure
    (the daemon) runs as it would without the benchmark's own settings."""
    return dict(_ENVIRONMENT)
