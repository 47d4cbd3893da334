"""The open choices of microfacet synthesis (docs/design/asymmetric.md), measured.

On the cases of ``validate_asymmetric.py --part fill`` where synthesis fills texels
(the eight example materials and twelve random ones at 0/90° and 0/120/240°, ideal
device), the §5.5 reconstruction with one option changed at a time against the
defaults: on the texels the defaults synthesized, the Ω-weighted RMS of log(D/D_true)
and the mass error (as part ``fill``), each case's value over the defaults', summarized
as the geometric mean and the worst over the cases, and the synthesis's time.

Run: ``.venv/bin/python studies/synthesis_choices.py [--jobs N]`` (≈ 5 min on 2 busy
cores); results in ``out/validate_asymmetric/choices.json``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "studies"))
sys.path.insert(0, str(ROOT / "tests"))

#: One option changed at a time (SynthesisOptions field → value).
VARIANTS = {"default": {}, "step 2.5°": {"rotation_step_deg": 2.5}, "step 10°": {"rotation_step_deg": 10.0},
            "window 5°": {"window_deg": 5.0}, "window 12°": {"window_deg": 12.0}, "overlap 0.15": {"min_overlap": 0.15},
            "overlap 0.5": {"min_overlap": 0.5}, "blend 1": {"blend": 1}, "blend 5": {"blend": 5},
            "gain penalty 0": {"gain_penalty": 0.0}, "no held-out blend": {"validate": False}}


def one(args: tuple[str, tuple[float, ...]]) -> dict:
    import numpy as np

    import validate_asymmetric as v
    from reflecto.load import load_source
    from reflecto.reconstruct.asymmetric import reconstruct_rotations
    from reflecto.reconstruct.synthesis import SynthesisOptions

    name, rotations = args
    src = v.random_asymmetric(int(name.removeprefix("random-"))) if name.startswith("random-") else load_source(name)
    dev, cal = v._device_and_calibration("ideal")
    caps = v._captures(src, dev, cal, rotations)
    out: dict = {"name": Path(name).stem, "rotations": list(rotations)}
    mask = cube = None
    for label, kw in VARIANTS.items():
        t0 = time.perf_counter()
        res = reconstruct_rotations(caps, synthesis=SynthesisOptions(**kw))
        dt = time.perf_counter() - t0
        if label == "default":
            f = res.fill
            if f is None or f.synthesized_work is None or not f.synthesized_work.any():
                return out
            mask, cube = f.synthesized_work, f.cube
        m = v._on_texels(src, res.model, cube, mask)
        out[label] = {"log_rms": m["log_rms"], "mass": m["mass"], "seconds": dt}
    out["texels"] = int(np.count_nonzero(mask))
    return out


def main() -> None:
    import validate_asymmetric as v

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1))
    args = ap.parse_args()
    names = [str(p) for p in v.asymmetric_files()] + [f"random-{k}" for k in range(v.N_RANDOM)]
    items = [(n, rs) for rs in v.ROTATION_SETS_FILL for n in names]
    with ProcessPoolExecutor(max_workers=args.jobs) as ex:
        rows = [r for r in ex.map(one, items) if "texels" in r]
    print(f"{len(rows)} cases with synthesized texels; each variant's error over the default's (geometric mean, worst)")
    for label in VARIANTS:
        if label == "default":
            continue
        line = [f"{label:18s}"]
        for key in ("log_rms", "mass"):
            q = [r[label][key] / r["default"][key] for r in rows if r["default"][key] > 0]
            gm = math.exp(sum(math.log(max(x, 1e-12)) for x in q) / len(q))
            line.append(f"{key} {gm:.3f} (worst {max(q):.2f}, better on {sum(x < 1 for x in q)}/{len(q)})")
        t = sum(r[label]["seconds"] for r in rows) / sum(r["default"]["seconds"] for r in rows)
        line.append(f"time {t:.2f}×")
        print("  ".join(line), flush=True)
    v.OUT.mkdir(parents=True, exist_ok=True)
    (v.OUT / "choices.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
