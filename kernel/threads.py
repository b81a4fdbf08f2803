"""One BLAS thread for placecell's processes (docs/design.md §13).

The method's matrices are small (a place's 16 landmark templates against a panorama's
coarse windows: 16 x 64 by 64 x 19557), and OpenBLAS's worker threads cost more than they
give: that product takes 6.9 ms with its default threads on this 2-core machine and 0.67 ms
with one, and its idle workers spin between calls (placecell-bench --only daemon: 0.48 of a
core in localisation mode with the default threads, 0.24 with one). BLAS reads the setting
when numpy first loads it, so :func:`one_blas_thread` is called before anything imports
numpy: by the daemon, the evaluator and the test suite. An environment that sets the
variables keeps its own choice."""

from __future__ import annotations

import os

BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def one_blas_thread() -> None:
    """One BLAS thread unless the environment says otherwise (module docstring)."""
    for name in BLAS_THREAD_VARIABLES:
        os.environ.setdefault(name, "1")
