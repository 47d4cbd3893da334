"""Benchmark of the BRDF model at the paper's resolution (N = 512), on one core.

Reports the median of several runs of:
  * model eval of 1M direction pairs            (target ≤ 0.5 s)
  * splat of 460,800 samples into the hemicube   (target ≤ 50 ms; 6 LEDs × 320×240 pixels)
  * σ/S table computation from the NDF (eq. 8)  (target ≤ 100 ms)

Run: ``make bench`` or ``.venv/bin/python benchmarks/bench_model.py``.
"""

from __future__ import annotations

import _bench  # pins to one core before NumPy loads

# isort: split
import numpy as np  # noqa: E402

from reflecto import geometry  # noqa: E402
from reflecto.hemicube import hemicube  # noqa: E402
from reflecto.model import MicrofacetBRDF  # noqa: E402
from reflecto.shadowing import sigma_table  # noqa: E402
from reflecto.sources.analytic import AnalyticBRDF  # noqa: E402


def main() -> None:
    rng = np.random.default_rng(0)
    ref = AnalyticBRDF(distribution="ggx", alpha=(0.25, 0.1), rotation_deg=20, kd=[0.3, 0.2, 0.1], ks=0.6,
                       eta=[1.5, 1.6, 2.0])
    cube = hemicube(512)
    model = MicrofacetBRDF(ref.ndf(cube.directions), ref.kd, ref.ks, ref.eta)
    _ = model.sigma_table

    def dirs(n: int) -> np.ndarray:
        d = geometry.normalize(rng.normal(size=(n, 3)))
        d[:, 2] = np.abs(d[:, 2])
        return d

    i, o = dirs(1_000_000), dirs(1_000_000)
    t_eval = _bench.timed(lambda: model.eval(i, o))
    h, vals, w = dirs(460_800), rng.random(460_800), rng.random(460_800)
    t_splat = _bench.timed(lambda: cube.splat(h, vals, w), repeat=9)
    t_sigma = _bench.timed(lambda: sigma_table(cube, model.ndf_values), repeat=9)

    rows = [
        ("model eval, 1M direction pairs", t_eval, 0.5),
        ("splat, 460,800 samples", t_splat, 0.05),
        ("S table from NDF (eq. 8)", t_sigma, 0.1),
    ]
    print(f"reflecto model benchmark, N=512, one core (cpu affinity {_bench.cpus()})")
    for name, t, target in rows:
        status = "ok" if t <= target else "OVER TARGET"
        print(f"  {name:<34} {t * 1000:8.1f} ms   target {target * 1000:6.0f} ms   {status}")


if __name__ == "__main__":
    main()
