"""Benchmark of the virtual instrument, on one core.

Reports the median of several runs of:
  * simulating one capture (6 LEDs × 2 exposures, as-built device, noise)  (target ≤ 0.3 s)
  * raw frames → slices (HDR merge, radiometric correction, directions)    (target ≤ 50 ms)
  * the same, including reading the 12 PNG frames from disk

Run: ``make bench`` or ``.venv/bin/python benchmarks/bench_instrument.py``.
"""

from __future__ import annotations

import _bench  # pins to one core before NumPy loads

# isort: split
import tempfile  # noqa: E402

import cv2  # noqa: E402

cv2.setNumThreads(1)

from reflecto import workflow
from reflecto.instrument.capture import read_capture, write_capture  # noqa: E402
from reflecto.instrument.device import Device  # noqa: E402
from reflecto.instrument.simulate import simulate_capture  # noqa: E402
from reflecto.sources.analytic import AnalyticBRDF  # noqa: E402


def main() -> None:
    src = AnalyticBRDF(distribution="ggx", alpha=0.15, kd=[0.3, 0.2, 0.1], ks=0.6, eta=1.5)
    dev = Device.builtin("as-built")
    cal = workflow.calibration_for(dev, missing="nominal")
    cap = simulate_capture(src, dev, seed=0)
    t_sim = _bench.timed(lambda: simulate_capture(src, dev, seed=1))
    t_slices = _bench.timed(lambda: workflow.measure(cap, cal), repeat=15)
    with tempfile.TemporaryDirectory() as d:
        write_capture(cap, f"{d}/cap")
        t_read = _bench.timed(lambda: workflow.measure(read_capture(f"{d}/cap"), cal), repeat=15)
    rows = [
        ("simulate one capture (as-built)", t_sim, 0.3),
        ("raw frames → slices", t_slices, 0.05),
        ("read PNGs + raw → slices", t_read, None),
    ]
    print(f"reflecto instrument benchmark, one core (cpu affinity {_bench.cpus()})")
    for name, t, target in rows:
        status = "" if target is None else ("ok" if t <= target else "OVER TARGET")
        tgt = "" if target is None else f"target {target * 1000:6.0f} ms"
        print(f"  {name:<34} {t * 1000:8.1f} ms   {tgt}   {status}")


if __name__ == "__main__":
    main()
