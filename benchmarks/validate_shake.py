"""Issue 4, acceptance 4: shake detection on the shared materials (ideal device).

For every shared material (10 RGL, 40 MERL/NBRDF; material k uses seed k) one
shaken capture (``simulate_capture(..., shake=True)``: from a random LED on, the
sample turns by 3–8° about a random horizontal axis) and one clean capture are
reconstructed with the default options. Prints per material E(η) of both, whether
each was flagged, and the shake's first LED and angle; then the detection rate and
the number of false alarms, and the detection rate by the first shaken LED.

Run: ``.venv/bin/python benchmarks/validate_shake.py [--jobs N]`` (≈ 6 minutes on 2 cores).
"""

from __future__ import annotations

import argparse
import os
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from conftest import SHARED  # noqa: E402


def one(args: tuple[int, str]) -> dict:
    from reflecto.instrument.calibrate import nominal_calibration
    from reflecto.instrument.device import Device
    from reflecto.instrument.simulate import simulate_capture
    from reflecto.instrument.slices import extract_slices
    from reflecto.reconstruct.pipeline import reconstruct
    from reflecto.sources import load_source

    k, path = args
    dev = Device.builtin("ideal")
    cal = nominal_calibration(dev)
    src = load_source(path)
    out = {"name": Path(path).stem}
    for shake in (False, True):
        cap = simulate_capture(src, dev, seed=k, shake=shake)
        s = reconstruct(extract_slices(cap, cal)).summary
        key = "shaken" if shake else "clean"
        out[key] = {"E": s["fresnel_error"], "flagged": s["shake_detected"], "excluded": s["excluded_leds"]}
        if shake:
            info = cap.extra["simulation"]["shake"]
            out["from_led"], out["angle_deg"] = info["from_led"], info["angle_deg"]
    return out


def main() -> None:
    from reflecto.evaluate.sweep import find_materials

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    args = ap.parse_args()
    paths = find_materials([SHARED / "rgl", SHARED / "merl-nbrdf"])
    with ProcessPoolExecutor(args.jobs) as pool:
        rows = list(pool.map(one, [(k, str(p)) for k, p in enumerate(paths)]))
    by_led: dict[int, list[bool]] = {}
    for r in rows:
        c, s = r["clean"], r["shaken"]
        by_led.setdefault(r["from_led"], []).append(s["flagged"])
        print(f"{r['name']:30s} clean E {c['E']:.3f} {'FLAG' if c['flagged'] else '    '}   "
              f"shaken (LED {r['from_led']}+, {r['angle_deg']:.1f}°) E {s['E']:.3f} {'FLAG' if s['flagged'] else '    '}"
              f"{'  excluded ' + str(s['excluded']) if s['excluded'] else ''}")
    n = len(rows)
    print(f"detected {sum(r['shaken']['flagged'] for r in rows)}/{n} shaken; "
          f"false alarms {sum(r['clean']['flagged'] for r in rows)}/{n} clean")
    print("detection by first shaken LED: " + ", ".join(
        f"{k}: {sum(v)}/{len(v)}" for k, v in sorted(by_led.items())))
    ratio = sorted(r["shaken"]["E"] / max(r["clean"]["E"], 1e-9) for r in rows)
    print(f"E(shaken)/E(clean) per material: median {ratio[n // 2]:.2f}, "
          f"< 1.5 on {sum(x < 1.5 for x in ratio)}/{n}")


if __name__ == "__main__":
    main()
