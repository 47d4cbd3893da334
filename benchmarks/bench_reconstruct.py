"""Benchmark of the §5 reconstruction on the real workload: the 50 shared measured materials.

Each material of ``../shared/data/rgl`` and ``../shared/data/merl-nbrdf`` is captured
with the ideal device (the sweep's seed), its slices extracted once; then every
capture is reconstructed with the default options, :data:`REPEATS` rounds, one core.
Prints the per-material median times, the distribution (median, p90, max) and, as the
last line, ``ms_per_brdf: X`` (the median). Times are the process's CPU time (the
benchmark runs on one core, single-threaded): on a shared machine the wall time also
counts the other processes' turns; the wall-time median is printed beside it. The device captures 8.6 BRDFs per second
(117 ms each); the paper's reconstruction took 30 s.

Run: ``make bench`` or ``.venv/bin/python benchmarks/bench_reconstruct.py [--quick]``
(``--quick``: every fifth material).
"""

from __future__ import annotations

import _bench  # noqa: F401  (pins to one core before NumPy loads)

# isort: split
import argparse  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from reflecto.reconstruct import reconstruct  # noqa: E402

#: Rounds over all captures (a slow spell of the machine then hits every capture alike).
REPEATS = 3


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="every fifth material")
    args = ap.parse_args()
    captured = _bench.shared_ideal_slices(args.quick)
    files, slices = [p for p, _ in captured], [sl for _, sl in captured]
    reconstruct(slices[0])  # compile kernels, fill caches
    times: dict[str, list[float]] = {p.stem: [] for p in files}
    walls: list[float] = []
    for _ in range(REPEATS):
        for p, sl in zip(files, slices):
            t, w = time.process_time(), time.perf_counter()
            reconstruct(sl)
            times[p.stem].append(time.process_time() - t)
            walls.append(time.perf_counter() - w)
    per = {k: 1000 * statistics.median(v) for k, v in times.items()}
    for k, v in sorted(per.items(), key=lambda kv: -kv[1]):
        print(f"  {k:28s} {v:7.1f} ms")
    ms = np.array(list(per.values()))
    print(f"reflecto reconstruction benchmark, {len(files)} measured materials × {REPEATS}, ideal device, one core "
          f"{_bench.cpus()}: CPU time median {np.median(ms):.1f} ms, p90 {np.percentile(ms, 90):.1f} ms, "
          f"max {ms.max():.1f} ms (wall-time median {1000 * statistics.median(walls):.1f} ms)")
    print(f"ms_per_brdf: {np.median(ms):.1f}")


if __name__ == "__main__":
    main()
