"""Issue 24 (paper §5.5): asymmetric BRDFs from rotated captures, completed by microfacet synthesis.

Parts (``--part``, default all):

* ``asym`` — acceptance 1 and the asymmetric half of 3: the eight analytic asymmetric
  materials of ``examples/asymmetric/`` captured at 0/90/180/270° (capture ``k`` with
  seed ``k + 1``). Per material: ``reflecto compare``'s error (eq. 10 over every
  half-vector azimuth) of the symmetric path (the 0° capture alone, ``--isotropic
  no``) and of the §5.5 path, their ratio (target ≤ 1/3), the §5.5 NDF's mean
  relative error where D > 1 % of its peak (target ≤ 8 %), and the symmetry test on
  the single capture and on the merged set (target: broken on every one).
* ``fill`` — acceptance 2: the same materials and twelve seeded random asymmetric ones
  at 2 (0/90) and 3 (0/120/240) rotations, reconstructed with synthesis and with the
  plain fills (lobe-guided, as the symmetric path's; plain push–pull). On the
  working texels synthesis filled, each model's NDF against the truth: mean relative
  error where D > 1 % of the peak, the solid-angle-weighted RMS of log(D/D_true),
  and the mass error Σ|ΔD| cos θ Ω / Σ D cos θ Ω (what the BRDF feels).
* ``sym`` — acceptance 3, symmetric half: the 50 shared materials (10 RGL, 40 NBRDF;
  seed from the sweep) and four analytic symmetric ones (isotropic GGX/Beckmann,
  anisotropic GGX/Beckmann). §5.5 at 0/90/180/270° against the symmetric path
  (``auto``, and ``--isotropic no`` for the anisotropic ones): ratio ≤ 1.25; the
  symmetry test must say symmetric on the single capture and on the set.
* ``asbuilt`` — acceptance 4: the eight asymmetric materials on the as-built device
  (noise, hidden optics errors) with its simulated calibration; §5.5 error against
  the ideal device's (target ≤ 1.25×).
  ``--part fill-summary`` prints the verdict again from ``fill.json``.
* ``noise`` — what sets acceptance 4's as-built error: §5.5 on the ideal device, on the
  ideal optics with the as-built camera's noise, on the as-built optics with a noiseless
  camera (calibrated), and on the as-built device.
* ``photons`` — whether the noise's share is variance or bias: the ideal optics with the
  as-built camera collecting 1, 4, 16 and 64 times its electrons; and the as-built
  optics with the 64× camera, calibrated (the calibration's residuals almost alone).
* ``mixed`` — acceptance 5's mixed samples: sets whose captures are of two materials
  must be refused.
* ``timing`` — acceptance 6: one §5.5 reconstruction from 4 captures against one
  symmetric (``--isotropic no``) reconstruction of one capture, median of 3 after a
  warm-up, one core (target ≤ 4×).

Run: ``.venv/bin/python studies/validate_asymmetric.py [--part P] [--jobs N]``
(asym ≈ 1 min, fill ≈ 3 min, sym ≈ 4 min, asbuilt ≈ 1 min, mixed ≈ 15 s,
timing ≈ 20 s on 2 busy cores). Results go to ``out/validate_asymmetric/<part>.json``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "studies"))
sys.path.insert(0, str(ROOT / "benchmarks"))

from reflecto import workflow  # noqa: E402

OUT = ROOT / "out" / "validate_asymmetric"
ROTATIONS_4 = (0.0, 90.0, 180.0, 270.0)
ROTATION_SETS_FILL = ((0.0, 90.0), (0.0, 120.0, 240.0))

#: The analytic symmetric materials of part ``sym`` (name → AnalyticBRDF keywords).
SYMMETRIC_ANALYTIC = {
    "ggx-iso-0.1": dict(distribution="ggx", alpha=0.1, kd=0.2, ks=0.8, eta=1.5),
    "beckmann-iso-0.3": dict(distribution="beckmann", alpha=0.3, kd=0.0, ks=0.8, eta=1.3),
    "ggx-aniso-30": dict(distribution="ggx", alpha=[0.3, 0.1], rotation_deg=30, kd=0.05, ks=0.9, eta=2.2),
    "beckmann-aniso-75": dict(distribution="beckmann", alpha=[0.05, 0.2], rotation_deg=75, kd=0.1, ks=0.7, eta=1.5),
}


def asymmetric_files() -> list[Path]:
    return sorted((ROOT / "examples" / "asymmetric").glob("*.toml"))


def _device_and_calibration(device: str):  # type: ignore[no-untyped-def]
    from reflecto.instrument.calibrate import calibrate
    from reflecto.instrument.device import load_device
    from reflecto.instrument.simulate import simulate_calibration

    dev = load_device(device)
    if device == "ideal":
        return dev, workflow.calibration_for(dev, missing="nominal")
    cal_dir = OUT / f"calib-{device}"
    if not (cal_dir / "calibration.json").is_file():
        simulate_calibration(dev, cal_dir, seed=11)
    return dev, calibrate(cal_dir)


def _captures(src, dev, cal, rotations, seed0: int = 1):  # type: ignore[no-untyped-def]
    from reflecto import workflow
    from reflecto.instrument.simulate import simulate_capture

    return workflow.rotated_captures([simulate_capture(src, dev, seed=seed0 + k, rotation_deg=r)
                                      for k, r in enumerate(rotations)], cal, rotations_deg=rotations,
                                     names=[f"rotation {r:g}°" for r in rotations])


def _symmetric_path(caps, isotropic: str):  # type: ignore[no-untyped-def]
    from reflecto.reconstruct import Options, reconstruct
    from reflecto.reconstruct.eq3 import symmetry_test_slices

    res = reconstruct(caps[0].slices, Options(isotropic=isotropic))
    return res, symmetry_test_slices(caps[0].slices, caps[0].slices.valid, res.model)


def one_asym(args: tuple[str, str]) -> dict:
    """Part ``asym`` (and ``asbuilt``) for one material file on one device."""
    from reflecto.evaluate.metrics import comparison_error, ndf_error
    from reflecto.load import load_source
    from reflecto.reconstruct.asymmetric import reconstruct_rotations

    path, device = args
    src = load_source(path)
    dev, cal = _device_and_calibration(device)
    caps = _captures(src, dev, cal, ROTATIONS_4)
    sym, test1 = _symmetric_path(caps, "no")
    res = reconstruct_rotations(caps)
    e_sym, e_asym = comparison_error(src, sym.model).normalized, comparison_error(src, res.model).normalized
    return {"name": Path(path).stem, "device": device, "error_symmetric": e_sym, "error_asymmetric": e_asym,
            "ratio": e_asym / e_sym, "ndf_symmetric": ndf_error(src, sym.model),
            "ndf_asymmetric": ndf_error(src, res.model),
            "single_symmetry_ratio": test1.ratio, "single_broken": not test1.symmetric,
            "set_symmetry_ratio": res.symmetry.ratio, "set_broken": not res.symmetry.symmetric,
            "isotropic_path": res.isotropic, "consistency_level": res.consistency.worst_level,
            "consistency_ratio": res.consistency.worst_ratio, "synthesized_fraction": res.synthesized_fraction,
            "hole_fraction": res.hole_fraction, "eta": res.eta, "seconds": res.seconds}


def _on_texels(src, model, cube, mask) -> dict:  # type: ignore[no-untyped-def]
    """The model's NDF against the truth on the texels of ``mask``: mean relative error
    where D > 1 % of the peak, Ω-weighted RMS of log(D/D_true), and the mass error
    Σ|D − D_true| cos θ Ω / Σ D_true cos θ Ω."""
    import numpy as np

    h = cube.directions[mask]
    d, m = src.ndf(h), model.ndf(h)
    peak = float(src.ndf(cube.directions).max())
    sel = d > 0.01 * peak
    om, pom = cube.solid_angles[mask], cube.projected_solid_angles[mask]
    return {"rel_1pc": float(np.mean(np.abs(m[sel] / d[sel] - 1.0))) if sel.any() else math.nan,
            "log_rms": float(np.sqrt(np.sum(om * np.log(np.maximum(m, 1e-300) / d) ** 2) / np.sum(om))),
            "mass": float(np.sum(np.abs(m - d) * pom) / np.sum(d * pom)), "texels_1pc": int(sel.sum())}


def random_asymmetric(k: int):  # type: ignore[no-untyped-def]
    """The ``k``-th of part ``fill``'s seeded random asymmetric materials (GGX or Beckmann,
    α 0.1–0.4 per axis, any tangent, shifts up to 0.3, weights 0.15–0.4)."""
    import numpy as np

    from reflecto.sources.analytic import AnalyticBRDF

    rng = np.random.default_rng(1000 + k)
    return AnalyticBRDF(distribution=str(rng.choice(["ggx", "beckmann"])),
                        alpha=[float(rng.uniform(0.1, 0.4)), float(rng.uniform(0.1, 0.4))],
                        rotation_deg=float(rng.uniform(0, 180)), kd=float(rng.uniform(0, 0.1)), ks=0.8,
                        eta=float(rng.uniform(1.4, 2.2)),
                        asymmetry=(float(rng.uniform(-0.3, 0.3)), float(rng.uniform(-0.3, 0.3)),
                                   float(rng.uniform(0.15, 0.4))))


#: Random materials of part ``fill`` beside the eight examples.
N_RANDOM = 12


def one_fill(args: tuple[str, tuple[float, ...]]) -> dict:
    """Part ``fill`` for one material and rotation set."""
    from reflecto.load import load_source
    from reflecto.reconstruct.asymmetric import reconstruct_rotations
    from reflecto.reconstruct.synthesis import SynthesisOptions

    path, rotations = args
    src = random_asymmetric(int(path.removeprefix("random-"))) if path.startswith("random-") else load_source(path)
    dev, cal = _device_and_calibration("ideal")
    caps = _captures(src, dev, cal, rotations)
    runs = {mode: reconstruct_rotations(caps, synthesis=SynthesisOptions(mode=mode))
            for mode in ("synthesis", "lobe", "push-pull")}
    fill = runs["synthesis"].fill
    mask = fill.synthesized_work if fill is not None and fill.synthesized_work is not None else None
    out = {"name": Path(path).stem, "rotations": list(rotations)}
    if mask is None or not mask.any():
        out["synthesized_texels"] = 0
        return out
    cube = fill.cube
    out["synthesized_texels"] = int(mask.sum())
    out["synthesized_fraction"] = runs["synthesis"].synthesized_fraction
    for mode, res in runs.items():
        out[mode] = _on_texels(src, res.model, cube, mask)
    return out


def one_sym(args: tuple[str, str | dict, int]) -> dict:
    """Part ``sym`` for one symmetric material (a file, or analytic keywords)."""
    from reflecto.errors import ReflectoError
    from reflecto.evaluate.metrics import comparison_error
    from reflecto.load import load_source
    from reflecto.reconstruct.asymmetric import reconstruct_rotations
    from reflecto.sources.analytic import AnalyticBRDF

    name, spec, seed = args
    src = AnalyticBRDF(**spec) if isinstance(spec, dict) else load_source(spec)
    dev, cal = _device_and_calibration("ideal")
    caps = _captures(src, dev, cal, ROTATIONS_4, seed0=seed)
    sym, test1 = _symmetric_path(caps, "auto" if src.isotropic else "no")
    try:
        res = reconstruct_rotations(caps)
    except ReflectoError as e:  # a refused set of one material: a failure of the test, recorded
        return {"name": name, "refused": str(e), "ratio": math.inf, "single_broken": not test1.symmetric,
                "set_broken": True, "single_symmetry_ratio": test1.ratio}
    e_sym, e_asym = comparison_error(src, sym.model).normalized, comparison_error(src, res.model).normalized
    return {"name": name, "refused": "", "error_symmetric": e_sym, "error_asymmetric": e_asym,
            "ratio": e_asym / max(e_sym, 1e-12),
            "single_symmetry_ratio": test1.ratio, "single_broken": not test1.symmetric,
            "set_symmetry_ratio": res.symmetry.ratio, "set_broken": not res.symmetry.symmetric,
            "isotropic_path": res.isotropic, "consistency_ratio": res.consistency.worst_ratio,
            "consistency_level": res.consistency.worst_level}


def one_mixed(args: tuple[str, str]) -> dict:
    """Part ``mixed``: captures 0/90° of one material, 180/270° of another; must be refused."""
    from reflecto.errors import ReflectoError
    from reflecto.load import load_source
    from reflecto.reconstruct.asymmetric import reconstruct_rotations

    a, b = args
    dev, cal = _device_and_calibration("ideal")
    caps = _captures(load_source(a), dev, cal, (0.0, 90.0)) + _captures(load_source(b), dev, cal, (180.0, 270.0), 3)
    try:
        reconstruct_rotations(caps)
    except ReflectoError as e:
        return {"a": Path(a).stem, "b": Path(b).stem, "refused": True, "message": str(e)}
    return {"a": Path(a).stem, "b": Path(b).stem, "refused": False, "message": ""}


def _map(fn, items, jobs: int) -> list:  # type: ignore[no-untyped-def]
    if jobs <= 1:
        return [fn(x) for x in items]
    with ProcessPoolExecutor(max_workers=jobs) as ex:
        return list(ex.map(fn, items))


def _save(part: str, rows: list[dict]) -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / f"{part}.json").write_text(json.dumps(rows, indent=1))


def part_asym(jobs: int, device: str = "ideal") -> list[dict]:
    rows = _map(one_asym, [(str(p), device) for p in asymmetric_files()], jobs)
    for r in rows:
        print(f"{r['name']:20s} {device:8s} compare: symmetric {100 * r['error_symmetric']:6.3f} %  §5.5 "
              f"{100 * r['error_asymmetric']:6.3f} %  ratio {r['ratio']:.3f}   NDF symmetric "
              f"{100 * r['ndf_symmetric']:5.1f} %  §5.5 {100 * r['ndf_asymmetric']:5.1f} %   eq. 3: single "
              f"{r['single_symmetry_ratio']:5.1f}× {'broken' if r['single_broken'] else 'KEPT'}, set "
              f"{r['set_symmetry_ratio']:5.1f}× {'broken' if r['set_broken'] else 'KEPT'}   synthesized "
              f"{100 * r['synthesized_fraction']:.1f} % of the cap   captures agree: level "
              f"{r['consistency_level']:.3f}   {r['seconds']:.1f} s", flush=True)
    ok1 = sum(r["ratio"] <= 1 / 3 and r["ndf_asymmetric"] <= 0.08 for r in rows)
    ok3 = sum(r["single_broken"] and r["set_broken"] for r in rows)
    print(f"acceptance 1: {ok1}/{len(rows)} with ratio ≤ 1/3 and NDF ≤ 8 %; symmetry test broken on single capture "
          f"and set: {ok3}/{len(rows)}")
    _save("asym" if device == "ideal" else f"asym-{device}", rows)
    return rows


def part_fill(jobs: int) -> list[dict]:
    names = [str(p) for p in asymmetric_files()] + [f"random-{k}" for k in range(N_RANDOM)]
    rows = _map(one_fill, [(n, rs) for rs in ROTATION_SETS_FILL for n in names], jobs)
    for r in rows:
        rots = "/".join(f"{x:g}" for x in r["rotations"])
        if not r.get("synthesized_texels"):
            print(f"{Path(r['name']).stem:20s} {rots:10s} nothing synthesized")
            continue
        line = [f"{Path(r['name']).stem:20s} {rots:10s} {r['synthesized_texels']:5d} texels "
                f"({r['synthesis']['texels_1pc']:4d} with D > 1 %):"]
        for mode in ("synthesis", "lobe", "push-pull"):
            m = r[mode]
            rel = "   –  " if math.isnan(m["rel_1pc"]) else f"{100 * m['rel_1pc']:5.1f} %"
            line.append(f"{mode} {rel} / log {m['log_rms']:.3f} / mass {100 * m['mass']:5.1f} %")
        print("  ".join(line), flush=True)
    fill_summary(rows)
    _save("fill", rows)
    return rows


def fill_summary(rows: list[dict]) -> None:
    """Part ``fill``'s verdict: per rotation count and plain fill, on how many cases synthesis
    has the smaller error, and the geometric mean and worst of (synthesis error / plain fill's)."""
    for n_rot in (2, 3):
        done = [r for r in rows if r.get("synthesized_texels") and len(r["rotations"]) == n_rot]
        for mode in ("lobe", "push-pull"):
            counts = []
            for key in ("rel_1pc", "log_rms", "mass"):
                pairs = [(r["synthesis"][key], r[mode][key]) for r in done if not math.isnan(r["synthesis"][key])]
                q = [a / b for a, b in pairs if b > 0]
                gm = math.exp(sum(math.log(max(x, 1e-12)) for x in q) / len(q)) if q else math.nan
                counts.append(f"{key} {sum(a < b for a, b in pairs)}/{len(pairs)} (ratio geo-mean {gm:.2f}, "
                              f"worst {max(q, default=math.nan):.2f})")
            print(f"acceptance 2, {n_rot} rotations: synthesis better than the {mode} fill on the synthesized "
                  f"texels: {', '.join(counts)}")


def part_sym(jobs: int) -> list[dict]:
    from _shared_models import material_files
    from reflecto.evaluate.sweep import material_seed

    items = [(k, v, 1) for k, v in SYMMETRIC_ANALYTIC.items()]
    items += [(p.stem, str(p), material_seed(p.stem)) for p in material_files()]
    rows = _map(one_sym, items, jobs)
    for r in rows:
        if r["refused"]:
            print(f"{r['name']:28s} REFUSED: {r['refused']}", flush=True)
            continue
        print(f"{r['name']:28s} compare: symmetric {100 * r['error_symmetric']:7.3f} %  §5.5 "
              f"{100 * r['error_asymmetric']:7.3f} %  ratio {r['ratio']:.3f}  "
              f"({'1-D' if r['isotropic_path'] else 'hemicube'})"
              f"   eq. 3: single {r['single_symmetry_ratio']:4.2f}× {'BROKEN' if r['single_broken'] else 'kept'}, set "
              f"{r['set_symmetry_ratio']:4.2f}× {'BROKEN' if r['set_broken'] else 'kept'}   captures agree "
              f"{r['consistency_ratio']:.2f}×, level {r['consistency_level']:.3f}", flush=True)
    ok = sum(r["ratio"] <= 1.25 for r in rows)
    kept = sum(not r["single_broken"] and not r["set_broken"] for r in rows)
    print(f"acceptance 3: §5.5 ≤ 1.25 × symmetric path on {ok}/{len(rows)}; symmetry test kept on single capture and "
          f"set: {kept}/{len(rows)}; worst ratio {max(r['ratio'] for r in rows):.3f}")
    _save("sym", rows)
    return rows


def part_asbuilt(jobs: int) -> None:
    ideal_file = OUT / "asym.json"
    ideal = {r["name"]: r for r in json.loads(ideal_file.read_text())} if ideal_file.is_file() else {
        r["name"]: r for r in part_asym(jobs)}
    rows = part_asym(jobs, "as-built")
    ok = 0
    for r in rows:
        q = r["error_asymmetric"] / ideal[r["name"]]["error_asymmetric"]
        ok += q <= 1.25
        print(f"{r['name']:20s} §5.5 as-built {100 * r['error_asymmetric']:6.3f} % / ideal "
              f"{100 * ideal[r['name']]['error_asymmetric']:6.3f} % = {q:.2f}")
    print(f"acceptance 4: as-built within 25 % of the ideal device's error on {ok}/{len(rows)}")


#: Part ``noise``'s devices: the ideal one, the ideal optics with the as-built camera
#: (read and shot noise), the as-built optics with a noiseless camera (calibrated), and
#: the as-built device (calibrated).
NOISE_VARIANTS = ("ideal", "ideal optics + noise", "as-built, no noise", "as-built")


def _noise_variant(label: str):  # type: ignore[no-untyped-def]
    import dataclasses

    from reflecto.instrument.calibrate import calibrate
    from reflecto.instrument.device import load_device
    from reflecto.instrument.simulate import simulate_calibration

    ideal, built = load_device("ideal"), load_device("as-built")
    if label == "ideal":
        return ideal, workflow.calibration_for(ideal, missing="nominal")
    if label == "ideal optics + noise":
        dev = dataclasses.replace(ideal, camera=built.camera)
        return dev, workflow.calibration_for(dev, missing="nominal")
    dev = built if label == "as-built" else dataclasses.replace(
        built, camera=dataclasses.replace(built.camera, read_noise=0.0, shot_noise=False))
    cal_dir = OUT / ("calib-as-built" if label == "as-built" else "calib-as-built-noiseless")
    if not (cal_dir / "calibration.json").is_file():
        simulate_calibration(dev, cal_dir, seed=11)
    return dev, calibrate(cal_dir)


def one_noise(path: str) -> dict:
    """Part ``noise`` for one material: the §5.5 error on each of :data:`NOISE_VARIANTS`."""
    from reflecto.evaluate.metrics import comparison_error
    from reflecto.load import load_source
    from reflecto.reconstruct.asymmetric import reconstruct_rotations

    src = load_source(path)
    out = {"name": Path(path).stem}
    for label in NOISE_VARIANTS:
        dev, cal = _noise_variant(label)
        out[label] = comparison_error(
            src, reconstruct_rotations(_captures(src, dev, cal, ROTATIONS_4)).model).normalized
    return out


def part_noise(jobs: int) -> None:
    """What sets acceptance 4's as-built error: the camera's noise, the optics' hidden
    errors through the calibration, or both (§5.5 at 0/90/180/270° on each variant)."""
    rows = _map(one_noise, [str(p) for p in asymmetric_files()], jobs)
    for r in rows:
        print(f"{r['name']:20s} " + " | ".join(f"{k} {100 * r[k]:.3f} %" for k in NOISE_VARIANTS)
              + f"   noise alone {r['ideal optics + noise'] / r['ideal']:.2f}×, calibration alone "
              f"{r['as-built, no noise'] / r['ideal']:.2f}×")
    _save("noise", rows)


#: Part ``photons``: the as-built camera on the ideal optics, collecting this many times
#: its electrons (full well, sensitivity and read noise scaled alike: the same DN and
#: saturation, relative noise 1/√k).
PHOTON_FACTORS = (1, 4, 16, 64)


def one_photons(path: str) -> dict:
    """Part ``photons`` for one material: the §5.5 error at each of :data:`PHOTON_FACTORS`."""
    import dataclasses

    from reflecto.evaluate.metrics import comparison_error
    from reflecto.instrument.device import load_device
    from reflecto.load import load_source
    from reflecto.reconstruct.asymmetric import reconstruct_rotations

    src = load_source(path)
    ideal, built = load_device("ideal"), load_device("as-built")
    cam = built.camera
    out = {"name": Path(path).stem}
    for k in PHOTON_FACTORS:
        dev = dataclasses.replace(ideal, camera=_brighter(cam, k))
        out[str(k)] = comparison_error(src, reconstruct_rotations(
            _captures(src, dev, workflow.calibration_for(dev, missing="nominal"), ROTATIONS_4)).model).normalized
    dev, cal = _as_built_bright()
    out["as-built ×64"] = comparison_error(
        src, reconstruct_rotations(_captures(src, dev, cal, ROTATIONS_4)).model).normalized
    return out


def _brighter(camera, k: float):  # type: ignore[no-untyped-def]
    """``camera`` collecting ``k``× the electrons at the same DN (full well, sensitivity and read noise × k)."""
    import dataclasses

    return dataclasses.replace(camera, full_well=k * camera.full_well, sensitivity=k * camera.sensitivity,
                               read_noise=k * camera.read_noise)


def _as_built_bright():  # type: ignore[no-untyped-def]
    """The as-built optics with its camera at 64× the electrons (noise 1/8, still dithered), calibrated:
    the calibration's residuals without the noiseless camera's undithered rounding."""
    import dataclasses

    from reflecto.instrument.calibrate import calibrate
    from reflecto.instrument.device import load_device
    from reflecto.instrument.simulate import simulate_calibration

    built = load_device("as-built")
    dev = dataclasses.replace(built, camera=_brighter(built.camera, PHOTON_FACTORS[-1]))
    cal_dir = OUT / "calib-as-built-x64"
    if not (cal_dir / "calibration.json").is_file():
        simulate_calibration(dev, cal_dir, seed=11)
    return dev, calibrate(cal_dir)


def part_photons(jobs: int) -> None:
    """Whether the noise's share of acceptance 4 is variance (falls as 1/√k with k× the
    light) or a bias (stays): the §5.5 error on the ideal optics with the as-built
    camera at :data:`PHOTON_FACTORS` × its electrons, against the noiseless ideal device."""
    ideal_file = OUT / "asym.json"
    ideal = ({r["name"]: r["error_asymmetric"] for r in json.loads(ideal_file.read_text())} if ideal_file.is_file()
             else {r["name"]: r["error_asymmetric"] for r in part_asym(jobs)})
    _as_built_bright()  # its calibration, once, before the workers read it
    rows = _map(one_photons, [str(p) for p in asymmetric_files()], jobs)
    for r in rows:
        e0 = ideal[r["name"]]
        print(f"{r['name']:20s} ideal {100 * e0:.3f} % | " + " | ".join(
            f"×{k} {100 * r[str(k)]:.3f} % ({r[str(k)] / e0:.2f}×)" for k in PHOTON_FACTORS)
              + f" | as-built optics ×64 {100 * r['as-built ×64']:.3f} % ({r['as-built ×64'] / e0:.2f}×)", flush=True)
        r["ideal"] = e0
    _save("photons", rows)


def part_mixed(jobs: int) -> None:
    from _shared_models import material_files

    files = asymmetric_files()
    shared = material_files()
    rgl = [p for p in shared if p.suffix == ".bsdf"]
    nb = [p for p in shared if p.suffix == ".h5"]
    pairs = [(files[0], files[5]), (files[1], files[4]), (files[2], files[6]), (files[3], files[7]),
             (rgl[0], nb[0]), (nb[1], nb[2]), (files[0], nb[3]), (rgl[1], rgl[2])]
    rows = _map(one_mixed, [(str(a), str(b)) for a, b in pairs], jobs)
    for r in rows:
        print(f"{r['a']:22s} + {r['b']:22s} {'refused' if r['refused'] else 'ACCEPTED'}  {r['message'][:140]}")
    print(f"acceptance 5 (mixed samples): {sum(r['refused'] for r in rows)}/{len(rows)} refused")
    _save("mixed", rows)


def part_timing() -> None:
    import _bench  # noqa: F401  (one core, single-threaded libraries; before NumPy)
    from reflecto.load import load_source
    from reflecto.reconstruct import Options, reconstruct
    from reflecto.reconstruct.asymmetric import reconstruct_rotations

    dev, cal = _device_and_calibration("ideal")
    ratios = []
    for p in asymmetric_files():
        caps = _captures(load_source(p), dev, cal, ROTATIONS_4)
        t_sym = _bench.timed(lambda caps=caps: reconstruct(caps[0].slices, Options(isotropic="no")), repeat=3)
        t_asym = _bench.timed(lambda caps=caps: reconstruct_rotations(caps), repeat=3)
        ratios.append(t_asym / t_sym)
        print(f"{p.stem:20s} symmetric {1000 * t_sym:6.0f} ms   §5.5 from 4 captures {1000 * t_asym:6.0f} ms   "
              f"ratio {t_asym / t_sym:.2f}", flush=True)
    print(f"acceptance 6: ratio median {statistics.median(ratios):.2f}, worst {max(ratios):.2f} (target ≤ 4)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--part", default="all",
                    choices=("all", "asym", "fill", "fill-summary", "sym", "asbuilt", "noise", "photons", "mixed",
                             "timing"))
    ap.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1))
    args = ap.parse_args()
    t0 = time.perf_counter()
    parts = ["asym", "fill", "sym", "asbuilt", "mixed", "timing"] if args.part == "all" else [args.part]
    for part in parts:
        print(f"== {part}", flush=True)
        if part == "timing":
            part_timing()
        elif part == "fill-summary":  # the verdict of a finished part fill, from its JSON
            fill_summary(json.loads((OUT / "fill.json").read_text()))
        else:
            {"asym": part_asym, "fill": part_fill, "sym": part_sym, "asbuilt": part_asbuilt, "noise": part_noise,
             "photons": part_photons, "mixed": part_mixed}[part](
                args.jobs)
    print(f"({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
