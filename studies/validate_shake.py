"""Shake detection on the shared materials (ideal device by default).

For every shared material (10 RGL, 40 MERL/NBRDF; material k uses seed k) one
shaken capture (``simulate_capture(..., shake=True)``: from a random LED on, in the
device's firing order, the sample turns by 3–8° about a random horizontal axis) and
one clean capture are reconstructed with the default options. Prints per material,
for both captures, E(η) where the shake test reads it, the largest offset of a steep
LED's symmetry plane from the normal (:mod:`reflecto.reconstruct.symmetry`), the
isotropy and reciprocity log ratios between LED pairs
(:mod:`reflecto.reconstruct.consistency`), the check frames' |log ratio| against their
LEDs' slices (:mod:`reflecto.reconstruct.repeat`), the largest angle between the slices'
compact specular peaks (:func:`reflecto.reconstruct.motion.peak_agreement`), whether the
capture was flagged, and the moved LEDs and the angle; then the detection rate and the
number of false alarms, for the cues together and each alone, and the
detection rate by the firing position of the first moved LED.

Run: ``.venv/bin/python studies/validate_shake.py [--jobs N] [--device as-built]
[--firing-order 0,1,2,3,4,5] [--check-leds 0|4,0|none]`` (≈ 2 minutes on 2 cores);
``--firing-order`` tries another order of the same LEDs and ``--check-leds`` other
check frames (the defaults are the device's).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from conftest import SHARED  # noqa: E402
from reflecto.reconstruct.consistency import THRESHOLD as PAIR_THRESHOLD  # noqa: E402
from reflecto.reconstruct.motion import PEAK_AGREEMENT_DEG  # noqa: E402
from reflecto.reconstruct.symmetry import PLANE_THRESHOLD_DEG  # noqa: E402


def one(args: tuple[int, str, str, str | None, tuple[int, ...] | None, tuple[int, ...] | None]) -> dict:
    from reflecto import workflow
    from reflecto.instrument.device import load_device
    from reflecto.instrument.simulate import simulate_capture
    from reflecto.load import load_source
    from reflecto.reconstruct import reconstruct

    k, path, device, cal_path, order, check = args
    dev = load_device(device)
    if order is not None:
        dev = dataclasses.replace(dev, firing_order=order)
    if check is not None:
        dev = dataclasses.replace(dev, check_leds=check)
    cal = workflow.calibration_for(dev, cal_path, missing="nominal")
    src = load_source(path)
    out = {"name": Path(path).stem}
    for shake in (False, True):
        cap = simulate_capture(src, dev, seed=k, shake=shake)
        res = reconstruct(workflow.measure(cap, cal))
        s = res.summary()
        key = "shaken" if shake else "clean"
        planes = [x for x in s["symmetry_plane_offsets_deg"] if x is not None]
        out[key] = {"eps": res.model_error, "isotropic": res.isotropic, "flagged": s["shake_detected"],
                    "excluded": s["excluded_leds"],
                    "plane": max((abs(x) for x in planes), default=None),
                    "pairs": {f"{c['kind'][:3]} {c['a']}-{c['b']}": c["log_ratio"] for c in s["consistency_checks"]},
                    "pair_flag": any(abs(c["log_ratio"]) > PAIR_THRESHOLD[c["kind"]] for c in s["consistency_checks"]),
                    "repeat": max((abs(c["log_ratio"]) if c["log_ratio"] is not None else float("inf")
                                   for c in s["repeat_checks"]), default=None),
                    "repeat_flag": any(c["moved"] for c in s["repeat_checks"]),
                    "peaks": s["peak_spread_deg"],
                    "peak_flag": s["peak_spread_deg"] is not None and s["peak_spread_deg"] > PEAK_AGREEMENT_DEG}
        if shake:
            info = cap.extra["simulation"]["shake"]
            out["from_led"], out["angle_deg"] = info["from_led"], info["angle_deg"]
            out["from_position"], out["moved"] = info["from_position"], info["moved_leds"]
    return out


def main() -> None:
    from reflecto import workflow
    from reflecto.evaluate.sweep import find_materials

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--device", default="ideal", help="ideal or as-built (virtual calibration, kept in out/)")
    ap.add_argument("--firing-order", help="LED indices in firing order, e.g. 0,1,2,3,4,5 (default: the device's)")
    ap.add_argument("--check-leds", help="LEDs fired again after the sequence, e.g. 0 or 4,0; 'none' for no "
                    "check frames (default: the device's)")
    args = ap.parse_args()
    order = tuple(int(x) for x in args.firing_order.split(",")) if args.firing_order else None
    check = None if args.check_leds is None else (
        () if args.check_leds == "none" else tuple(int(x) for x in args.check_leds.split(",")))
    cal_path = workflow.calibration_file(args.device, ROOT / "out")
    paths = find_materials([SHARED / "rgl", SHARED / "merl-nbrdf"])
    with ProcessPoolExecutor(args.jobs) as pool:
        rows = list(pool.map(one, [(k, str(p), args.device, cal_path, order, check) for k, p in enumerate(paths)]))
    by_led: dict[int, list[bool]] = {}
    for r in rows:
        c, s = r["clean"], r["shaken"]
        by_led.setdefault(r["from_position"], []).append(s["flagged"])
        def plane(x: dict) -> str:
            return "  –  " if x["plane"] is None else f"{x['plane']:4.1f}°"

        def pairs(x: dict) -> str:
            return " ".join(f"{k} {v:+.2f}" for k, v in x["pairs"].items()).ljust(26)

        def rep(x: dict) -> str:
            return " –   " if x["repeat"] is None else f"{x['repeat']:5.3f}"

        def peaks(x: dict) -> str:
            return "  –  " if x["peaks"] is None else f"{x['peaks']:4.1f}°"

        def kind(x: dict) -> str:
            return "iso  " if x["isotropic"] else "ANISO"

        print(f"{r['name']:30s} clean {kind(c)} check {rep(c)} plane {plane(c)} peaks {peaks(c)} {pairs(c)} "
              f"{'FLAG' if c['flagged'] else '    '}   "
              f"shaken (LEDs {','.join(map(str, r['moved']))}, {r['angle_deg']:.1f}°) {kind(s)} "
              f"check {rep(s)} plane {plane(s)} peaks {peaks(s)} {pairs(s)} "
              f"{'FLAG' if s['flagged'] else '    '}{'  excluded ' + str(s['excluded']) if s['excluded'] else ''}")
    n = len(rows)
    print(f"detected {sum(r['shaken']['flagged'] for r in rows)}/{n} shaken; "
          f"false alarms {sum(r['clean']['flagged'] for r in rows)}/{n} clean")
    for cue, key in (("check frames alone", "repeat_flag"),
                     ("symmetry plane alone", "plane"), ("isotropy/reciprocity alone", "pair_flag"),
                     ("peaks' agreement alone", "peak_flag")):
        def hit(x: dict, key: str = key) -> bool:
            if key == "plane":
                return x[key] is not None and x[key] > PLANE_THRESHOLD_DEG
            return bool(x[key])
        print(f"  {cue}: detected {sum(hit(r['shaken']) for r in rows)}/{n}, "
              f"false alarms {sum(hit(r['clean']) for r in rows)}/{n}")
    print("detection by firing position of the first moved LED: " + ", ".join(
        f"{k}: {sum(v)}/{len(v)}" for k, v in sorted(by_led.items())))
    print(f"clean captures found isotropic: {sum(r['clean']['isotropic'] for r in rows)}/{n}; "
          f"shaken ones: {sum(r['shaken']['isotropic'] for r in rows)}/{n}")


if __name__ == "__main__":
    main()
