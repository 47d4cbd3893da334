r"""Hand-held margin against reach: the paper's layout and the same with its grazing peak LED raised.

The paper's layout sees LED 2's specular peak at θ_d = 67.1° within a degree of the view
cone's rim (:func:`reflecto.instrument.layout.tilt_margin_deg`: 0.28°), so a hand tilt of
a few tenths of a degree toward the rim hides it. Raising that LED by ``--raise`` degrees
keeps its peak in view to larger tilts (about half a degree per degree) and lowers the
θ_d at which it is seen by as much. This study measures the trade on the 50 shared
materials: each material captured on both ideal devices (``Device.design``, the same
optics and the other five LEDs), untilted and tilted (the tilt and its azimuth drawn
from the material's seed, uniform in [0, ``--max-tilt``]), reconstructed with the true
normal (the geometry's share only, no estimate), scored on eq. 10.

Prints, per layout and half, the median eq. 10 error untilted and tilted and how many
tilted captures stay within 1.25× of the *paper's* untilted error; ``-o`` writes the
per-material table.

    PYTHONPATH=src .venv/bin/python studies/handheld_layout.py ../shared/data/rgl \
        ../shared/data/merl-nbrdf --raise 4 --jobs 2 -o out/handheld-layout.csv
"""

from __future__ import annotations

import argparse
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from _tables import write_rows
from reflecto import load_source, workflow
from reflecto.evaluate.metrics import brdf_error, evaluate_on_grid, max_albedo, metric_grid
from reflecto.evaluate.split import half
from reflecto.evaluate.sweep import find_materials, material_seed
from reflecto.instrument import layout
from reflecto.instrument.device import Device
from reflecto.instrument.simulate import simulate_capture
from reflecto.reconstruct import Options, reconstruct

#: The paper's LED that sees the grazing peak (its elevation, degrees).
GRAZING_PEAK_ELEVATION_DEG = 22.9


def devices(raise_deg: float) -> dict[str, Device]:
    """The paper's ideal device and the same with its grazing-peak LED raised by ``raise_deg``."""
    paper = Device.builtin("ideal")
    angles = np.array(paper.led_angles, dtype=float)
    k = int(np.argmin(np.abs(angles[:, 0] - GRAZING_PEAK_ELEVATION_DEG)))
    angles[k, 0] += raise_deg
    return {"paper": paper, "raised": Device.design(f"paper-led{k}+{raise_deg:g}", paper.optics, angles.tolist())}


def run(path: str, raise_deg: float, max_tilt: float) -> dict[str, Any]:
    name = Path(path).stem
    seed = material_seed(name)
    tilt = float(np.random.default_rng(seed).uniform(0.0, max_tilt))
    src = load_source(Path(path))
    grid = metric_grid(2)
    ref, albedo = evaluate_on_grid(src, grid), max_albedo(src)
    row: dict[str, Any] = {"name": name, "half": half(name), "tilt_deg": round(tilt, 3)}
    for label, dev in devices(raise_deg).items():
        cal = workflow.calibration_for(dev, missing="nominal")
        for t in (0.0, tilt):
            cap = simulate_capture(src, dev, tilt_deg=t, seed=seed)
            truth = np.array(cap.extra["simulation"]["normal"])
            res = reconstruct(workflow.measure(cap, cal), Options(normal=truth if t else "device"))
            err = brdf_error(src, res.model, stride=2, albedo_ref=albedo, reference_values=ref).normalized
            row[f"{label}_{'tilted' if t else 'untilted'}"] = float(err)
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folders", nargs="+")
    ap.add_argument("--raise", dest="raise_deg", type=float, default=4.0, help="degrees the LED is raised")
    ap.add_argument("--max-tilt", type=float, default=10.0)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("-o", "--output", type=Path)
    args = ap.parse_args()
    for label, dev in devices(args.raise_deg).items():
        print(f"{label}: peaks at θ_d {np.round(layout.peak_theta_d(dev.optics, dev.leds), 1).tolist()}, "
              f"tilt margin {layout.tilt_margin_deg(dev.optics, dev.leds):.2f}°")
    paths = [str(p) for p in find_materials(args.folders)]
    with ProcessPoolExecutor(max(args.jobs, 1)) as pool:
        rows = list(pool.map(run, paths, [args.raise_deg] * len(paths), [args.max_tilt] * len(paths)))
    for part in ("tuning", "validation", "all"):
        sel = [r for r in rows if part in ("all", r["half"])]
        for label in ("paper", "raised"):
            within = sum(r[f"{label}_tilted"] <= 1.25 * r["paper_untilted"] for r in sel)
            print(f"{part:10s} {label:6s} median eq. 10 untilted {np.median([r[f'{label}_untilted'] for r in sel]):.4f}"
                  f" tilted {np.median([r[f'{label}_tilted'] for r in sel]):.4f};"
                  f" tilted within 1.25× of the paper's untilted {within}/{len(sel)}")
    if args.output:
        write_rows(args.output, rows)


if __name__ == "__main__":
    main()
