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


def shared_ideal_slices(quick: bool = False) -> list[tuple[object, object]]:
    """``(material file, slices)`` of the 50 shared measured materials (every fifth with
    ``quick``), each captured once by the ideal device with the sweep's seed."""
    from pathlib import Path

    from reflecto import workflow
    from reflecto.evaluate.sweep import find_materials, material_seed
    from reflecto.instrument.device import Device
    from reflecto.instrument.simulate import simulate_capture
    from reflecto.load import load_source

    shared = Path(__file__).resolve().parents[1].parent / "shared" / "data"
    dev = Device.builtin("ideal")
    cal = workflow.calibration_for(dev, missing="nominal")
    files = find_materials([shared / "rgl", shared / "merl-nbrdf"])[:: 5 if quick else 1]
    return [(p, workflow.measure(simulate_capture(load_source(p), dev, seed=material_seed(p.stem)), cal))
            for p in files]
