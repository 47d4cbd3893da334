"""Shared set-up of the benchmarks: one core, single-threaded libraries, median timing.

Import this module before NumPy so that the thread variables take effect.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"
try:
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
except (AttributeError, OSError):
    pass

import statistics  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402


def timed(fn: Callable[[], object], repeat: int = 5) -> float:
    """Median wall time (s) of ``repeat`` calls after one warm-up call."""
    fn()  # warm-up: compiled kernels, caches, page faults
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def cpus() -> list[int]:
    """The CPUs this process is pinned to."""
    try:
        return sorted(os.sched_getaffinity(0))
    except AttributeError:
        return []
