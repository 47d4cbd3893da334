"""How a pixel sees the BRDF, and what that does to the tilted captures of sharp lobes.

The virtual camera samples the BRDF at each pixel's centre direction; a lobe narrower than
a pixel (steel: a half width of 0.11° in ``h``, a pixel 0.2°) is then read high or low by
where the centres fall, and eq. 10 moves by several times with hundredths of a degree of
frame (docs/design/normal.md, Limits). This study captures each material (as-built device,
calibrated, the hand-held study's tilt and seed) three ways with
:func:`reflecto.instrument.simulate.simulate_capture`: at the pixel centres (``point``), as
the mean over 4 × 4 sub-pixel directions (``footprint``), and as that mean of the image
blurred by a Gaussian of 0.8 px (``blur``, the spot blur the calibration simulation gives
its pinholes). Per material and way: eq. 10 of the untilted capture, and of the tilted one
over the true normal's (the hand-held issue's 1.1× bar) and over the untilted one's.

Run: ``.venv/bin/python studies/pixel_footprint.py [NAME ...] [-o out/pixel-footprint]``
(default: the 13 materials docs/design/normal.md quotes; ≈ 20 s per footprint capture).
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

from reflecto import load_source, workflow
from reflecto.evaluate.metrics import brdf_error, evaluate_on_grid, max_albedo, metric_grid
from reflecto.evaluate.sweep import material_seed
from reflecto.instrument.device import load_device
from reflecto.instrument.simulate import SPOT_BLUR_PX, simulate_capture
from reflecto.reconstruct import Options, reconstruct

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"
MATERIALS = ("steel", "chrome-steel", "alum-bronze", "red-metallic-paint", "specular-blue-phenolic", "maroon-plastic",
             "orange-paint", "blue-metallic-paint", "aventurnine", "pink-felt", "delrin", "irid_flake_paint1_rgb",
             "vch_golden_yellow_rgb")
#: The three ways a pixel reads the BRDF: (footprint, blur in pixels).
WAYS = {"point": (1, 0.0), "footprint": (4, 0.0), "blur": (4, SPOT_BLUR_PX)}


def run(name: str, cal, stride: int = 2) -> dict:
    """One material's three ways (module docstring)."""
    path = next(p for p in sorted(SHARED.glob(f"*/{name}.*")) if p.suffix in (".h5", ".bsdf"))
    seed = material_seed(path.stem)
    tilt = float(np.random.default_rng(seed).uniform(0.0, 10.0))  # the hand-held study's
    src, dev = load_source(path), load_device("as-built")
    grid = metric_grid(stride)
    ref, alb = evaluate_on_grid(src, grid), max_albedo(src)
    err = (lambda m: float(brdf_error(src, m, stride=stride, albedo_ref=alb, reference_values=ref).normalized))
    out: dict = {"name": name, "tilt_deg": tilt}
    for way, (footprint, blur) in WAYS.items():
        e = {}
        for label, t in (("flat", 0.0), ("tilted", tilt)):
            cap = simulate_capture(src, dev, tilt_deg=t, seed=seed, footprint=footprint, blur_px=blur)
            truth = np.array(cap.extra["simulation"]["normal"])
            result = workflow.capture_to_model(cap, cal)
            e[label] = err(result.reconstruction.model)
            if label == "tilted":
                e["true_normal"] = err(reconstruct(result.slices, Options(normal=truth)).model)
        out[way] = {"flat": e["flat"], "tilted": e["tilted"], "vs_true_normal": e["tilted"] / e["true_normal"],
                    "vs_untilted": e["tilted"] / e["flat"]}
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("names", nargs="*", default=list(MATERIALS), help="material names (default: 13)")
    ap.add_argument("-o", "--out", default=str(ROOT / "out" / "pixel-footprint"), help="output folder")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    cal = workflow.calibration_for(load_device("as-built"), workflow.calibration_file("as-built", out),
                                   missing="nominal")
    rows = []
    print(f"{'material':24s} " + "  ".join(f"{w:>24s}" for w in WAYS) + "   (untilted eq. 10, tilted / true normal)")
    for name in args.names:
        r = run(name, cal)
        rows.append(r)
        cells = (f"{r[w]['flat']:9.4f} {r[w]['vs_true_normal']:6.3f}× {r[w]['vs_untilted']:5.2f}×" for w in WAYS)
        print(f"{name:24s} " + "  ".join(cells), flush=True)
    (out / "records.json").write_text(json.dumps(rows, indent=1))
    for w in WAYS:
        ratios = [r[w]["vs_true_normal"] for r in rows]
        print(f"{w}: tilted within 1.1× of the true normal on {sum(x <= 1.1 for x in ratios)}/{len(rows)}, "
              f"median {float(np.median(ratios)):.3f}; untilted eq. 10 geometric mean over point's "
              f"{math.exp(float(np.mean([math.log(r[w]['flat'] / r['point']['flat']) for r in rows]))):.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
