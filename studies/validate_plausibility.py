"""Every output a plausible, isotropy-correct BRDF: the 50 shared materials, ideal and as-built, flat and tilted.

For each material of ``../shared/data/rgl`` and ``../shared/data/merl-nbrdf``, a clean
capture (the sweep's seed) on the ideal device and on the as-built device (with its
virtual calibration) is reconstructed with the default options; every fifth material
also tilted by 5°, 10° and 15° (as-built, the estimated normal). Checked per model:

* η below its search bound (50) and one η for R, G, B (spread 0);
* ``0 ≤ k_s ≤ 1`` and ``k_d ≥ 0`` per channel;
* directional albedo ≤ 1 at 0°, 30°, 60°, 75°, 85° and 89° (a 96 × 96 quadrature);
* found isotropic (``isotropic="auto"``);
* not flagged as shaken (the captures are clean).

Prints one line per capture with any violation, then the counts.

Run: ``.venv/bin/python studies/validate_plausibility.py [--jobs 2] [--no-tilt] [--device wide]``
(≈ 5 minutes on 2 cores). ``--device NAME`` checks the built-in pair NAME (ideal) and
NAME-as-built (``wide``, ``wide-as-built``) instead of ``ideal`` and ``as-built``.
"""

from __future__ import annotations

import argparse
import math
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"
TILTS = (5.0, 10.0, 15.0)
ANGLES = np.array([0.0, 30.0, 60.0, 75.0, 85.0, 89.0])


def one(job: tuple[str, str, str | None, float]) -> dict:
    from reflecto import workflow
    from reflecto.evaluate.sweep import material_seed
    from reflecto.fresnel import is_constant
    from reflecto.instrument.device import load_device
    from reflecto.instrument.simulate import simulate_capture
    from reflecto.load import load_source
    from reflecto.reconstruct import Options, reconstruct
    from reflecto.reconstruct.isotropic import ETA_MAX

    path, device, cal_path, tilt = job
    dev = load_device(device)
    cal = workflow.calibration_for(dev, cal_path, missing="nominal")
    name = Path(path).stem
    cap = simulate_capture(load_source(path), dev, seed=material_seed(name), tilt_deg=tilt)
    try:
        res = reconstruct(workflow.measure(cap, cal), Options(normal="auto" if tilt > 0 else "device"))
    except Exception as e:  # noqa: BLE001 - reported, the run goes on
        return {"name": name, "device": device, "tilt": tilt, "bad": [f"FAILED {type(e).__name__}: {e}"],
                "eta": float("nan"), "albedo": float("nan"), "notes": [], "seconds": 0.0}
    m = res.model
    albedo = float(m.albedo(ANGLES, n_u=96, n_phi=96).max())
    bad = []
    constant = is_constant(m.eta)  # the constant Fresnel lobe: an explicit model, not η at its bound
    if not (constant or (res.eta < ETA_MAX and np.ptp(m.eta) == 0)):
        bad.append(f"η {m.eta.tolist()}")
    if np.any(m.ks > 1.0) or np.any(m.ks < 0) or np.any(m.kd < 0):
        bad.append(f"k_s {m.ks.round(3).tolist()} k_d {m.kd.round(3).tolist()}")
    if albedo > 1.0 + 1e-3:
        bad.append(f"albedo {albedo:.4f}")
    if not res.isotropic:
        bad.append(f"anisotropic ({100 * res.isotropy.anisotropy:.0f} %)")
    if res.shake_detected:
        bad.append("shake: " + res.motion.describe())
    return {"name": name, "device": device, "tilt": tilt, "bad": bad, "eta": math.nan if constant else res.eta,
            "constant_fresnel": constant, "albedo": albedo,
            "notes": res.notes, "seconds": res.seconds}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--no-tilt", action="store_true", help="skip the tilted captures")
    ap.add_argument("--device", default="ideal", help="ideal device (its as-built twin is NAME-as-built, or as-built)")
    args = ap.parse_args()
    ideal = args.device
    built = "as-built" if ideal == "ideal" else f"{ideal}-as-built"
    from reflecto import workflow
    from reflecto.evaluate.sweep import find_materials

    files = find_materials([SHARED / "rgl", SHARED / "merl-nbrdf"])
    with tempfile.TemporaryDirectory() as tmp:
        cal = workflow.calibration_file(built, Path(tmp))
        jobs = [(str(p), d, cal if d == built else None, 0.0) for d in (ideal, built) for p in files]
        if not args.no_tilt:
            jobs += [(str(p), built, cal, t) for p in files[::5] for t in TILTS]
        with ProcessPoolExecutor(args.jobs) as ex:
            rows = list(ex.map(one, jobs))
    for r in rows:
        if r["bad"]:
            print(f"{r['name']:28s} {r['device']:8s} tilt {r['tilt']:4.1f}°: " + "; ".join(r["bad"]))
    for label, sel in ((ideal, lambda r: r["device"] == ideal),
                       (built, lambda r: r["device"] == built and r["tilt"] == 0),
                       (f"{built} tilted", lambda r: r["tilt"] > 0)):
        group = [r for r in rows if sel(r)]
        if not group:
            continue
        ok = sum(not r["bad"] for r in group)
        iso = sum(not any(b.startswith("anisotropic") for b in r["bad"]) for r in group)
        shake = sum(any(b.startswith("shake") for b in r["bad"]) for r in group)
        print(f"{label}: {ok}/{len(group)} plausible and clean; isotropic {iso}/{len(group)}; flagged as shaken "
              f"{shake}/{len(group)}; max albedo {np.nanmax([r['albedo'] for r in group]):.4f}; "
              f"η range {np.nanmin([r['eta'] for r in group]):.3f}–{np.nanmax([r['eta'] for r in group]):.3f}; "
              f"constant Fresnel {sum(r.get('constant_fresnel', False) for r in group)}/{len(group)}")
        for r in group:
            if r.get("constant_fresnel"):
                print(f"  constant Fresnel: {r['name']} (tilt {r['tilt']:g}°)")


if __name__ == "__main__":
    main()
