"""Benchmark of what the Fresnel tint, the NDF per θ_d node and the shadowing form's choice add to a
reconstruction, on the 50 shared measured materials.

Each material is captured with the ideal device (the sweep's seed) and its luminance fit
done once (:func:`reflecto.reconstruct.isotropic.fit_luminance`); then the channel scalars
are timed both ways, :data:`REPEATS` rounds, one core, CPU time: the tint's fit
(:func:`~reflecto.reconstruct.isotropic.tinted_scalars`: its nodes, the NDF per node where
there are two or more, :func:`~reflecto.reconstruct.isotropic.node_ndfs`, the bounded least
squares per channel) and one scale per channel
(:func:`~reflecto.reconstruct.isotropic.channel_scalars`); and the choice of the shadowing
form beyond the observed θ_d (:func:`~reflecto.reconstruct.extrapolation.choose_shadowing`:
its gate, and where the gate passes one more luminance fit). Prints the median, p90 and
maximum of each and of their sum per capture (issue 42's budget: 20 ms per capture) and,
as the last line, ``ms_tint_extra: X`` (the median of the sum).

Run: ``.venv/bin/python benchmarks/bench_tint.py [--quick]`` (``--quick``: every fifth material).
"""

from __future__ import annotations

import _bench  # noqa: F401  (pins to one core before NumPy loads)

# isort: split
import argparse  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from reflecto.polar import polar_nodes  # noqa: E402
from reflecto.reconstruct import extrapolation, isotropic  # noqa: E402
from reflecto.reconstruct.pipeline import usable_samples  # noqa: E402
from reflecto.reconstruct.samples import kd_median_bound  # noqa: E402

#: Rounds over all captures.
REPEATS = 5


def _cpu_ms(fn, *args) -> float:  # type: ignore[no-untyped-def]
    t = time.process_time()
    fn(*args)
    return 1000.0 * (time.process_time() - t)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="every fifth material")
    args = ap.parse_args()
    nodes = polar_nodes()
    fits = []
    for _, sl in _bench.shared_ideal_slices(args.quick):
        ok = usable_samples(sl) & sl.valid
        lum = isotropic.fit_luminance(isotropic.bin_polar(sl, nodes, ok), nodes)
        fits.append((lum, kd_median_bound(sl.light, sl.view, sl.values, ok, 75.0)))
    isotropic.tinted_scalars(*fits[0])  # warm caches
    tints, choices = [], []
    for lum, ceiling in fits:
        tint = [_cpu_ms(isotropic.tinted_scalars, lum, ceiling) for _ in range(REPEATS)]
        plain = [_cpu_ms(isotropic.channel_scalars, lum, ceiling) for _ in range(REPEATS)]
        tints.append(statistics.median(tint) - statistics.median(plain))
        fit = isotropic.isotropic_fit(lum, lambda c=ceiling: c)
        choices.append(statistics.median(_cpu_ms(extrapolation.choose_shadowing, fit) for _ in range(REPEATS)))
    total = np.array(tints) + np.array(choices)
    print(f"{len(fits)} measured materials × {REPEATS}, ideal device, one core {_bench.cpus()}, extra CPU time "
          "per capture (budget 20 ms):")
    for label, ms in (("Fresnel tint and NDF per node", np.array(tints)),
                      ("shadowing form's choice", np.array(choices)), ("both", total)):
        print(f"  {label:30s} median {np.median(ms):6.2f} ms, p90 {np.percentile(ms, 90):6.2f} ms, "
              f"max {ms.max():6.2f} ms")
    print(f"ms_tint_extra: {np.median(total):.2f}")


if __name__ == "__main__":
    main()
