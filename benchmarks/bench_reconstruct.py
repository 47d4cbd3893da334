"""Benchmark of the §5 reconstruction at full resolution (N = 512), on one core.

Median wall time per BRDF over analytic captures (ideal device), slices already
extracted, each reconstructed :data:`REPEATS` times. The last line is
``ms_per_brdf: X``. Target ≤ 100 ms (the device captures 10 BRDFs/s); the paper
took 30 s.

Run: ``make bench`` or ``.venv/bin/python benchmarks/bench_reconstruct.py``.
"""

from __future__ import annotations

import _bench  # noqa: F401  (pins to one core before NumPy loads)
import statistics  # noqa: E402
import time  # noqa: E402

from reflecto.instrument.calibrate import nominal_calibration  # noqa: E402
from reflecto.instrument.device import Device  # noqa: E402
from reflecto.instrument.simulate import simulate_capture  # noqa: E402
from reflecto.instrument.slices import extract_slices  # noqa: E402
from reflecto.reconstruct.pipeline import reconstruct  # noqa: E402
from reflecto.sources.analytic import AnalyticBRDF  # noqa: E402


#: Each capture is reconstructed this many times; the median is over all runs.
REPEATS = 3


def main() -> None:
    dev = Device.builtin("ideal")
    cal = nominal_calibration(dev)
    srcs = [AnalyticBRDF(distribution=d, alpha=a, kd=0.2, ks=0.7, eta=1.5) for d in ("ggx", "beckmann") for a in (0.1, 0.3)]
    slices = [extract_slices(simulate_capture(s, dev, seed=k), cal) for k, s in enumerate(srcs)]
    reconstruct(slices[0])  # compile kernels, fill caches
    times = []
    for _ in range(REPEATS):  # rounds over all captures: a slow spell of the machine hits every capture alike
        for sl in slices:
            t = time.perf_counter()
            reconstruct(sl)
            times.append(time.perf_counter() - t)
    ms = 1000 * statistics.median(times)
    print(f"reflecto reconstruction benchmark, N=512, one core {_bench.cpus()}, {len(slices)} BRDFs × {REPEATS}: "
          f"{', '.join(f'{1000 * t:.0f}' for t in times)} ms")
    print(f"ms_per_brdf: {ms:.1f}")


if __name__ == "__main__":
    main()
