"""The validation sweep of paper §6: simulate → reconstruct → evaluate, for many materials.

For every material file found in the given folders (MERL ``.binary``, RGL ``.bsdf``,
NBRDF ``.h5``, analytic ``.json``/``.toml``), three BRDFs are compared with the
reference by the error of eq. 10 (:mod:`.metrics`):

* **ours**: a capture with our device (``ideal``, or ``as-built`` with noise and a
  calibration made by the virtual calibration procedure), reconstructed by §5;
* **earlier**: the same with the earlier device's layout (``Device.builtin("earlier")``,
  Dong et al. 2010 as described in Lan et al. §1/§6.2) and the same reconstruction;
* **Cook–Torrance**: fitted to the dense reference (:mod:`.cooktorrance`);
* **same-data Cook–Torrance**: fitted to exactly the samples our capture holds
  (:func:`.cooktorrance.fit_cook_torrance_capture`), the parametric sparse fit.

Each material also records its half of the generalization protocol (:mod:`.split`).

Each material's result (errors, parameters, timings per stage, sphere renders for the
Fig. 4 analogue) is written atomically to ``RESULTS/materials/<name>.json`` as soon
as it is finished; a rerun skips finished materials, so an interrupted sweep loses
nothing and a restarted one ends with identical results (every seed derives from the
material's name). Work is spread over processes; at the end the CSV table
(``results.csv``) and the figures (``fig5_errors.png``, ``fig4_spheres.png``) are
written.
"""

from __future__ import annotations

import json
import os
import time
import zlib
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import FileFormatError, ReflectoError
from ..io import atomic_write, read_description

MATERIAL_SUFFIXES = (".binary", ".bsdf", ".h5", ".json", ".toml")
#: Resolution of the sphere renders kept per material (Fig. 4).
SPHERE_RES = 96
#: Every k-th θ_d/φ_d bin for the reported errors (1 = the full MERL grid).
METRIC_STRIDE = 1


def find_materials(folders: Sequence[str | Path]) -> list[Path]:
    """Material files in ``folders`` (sorted; NBRDF architecture sidecars skipped)."""
    out: list[Path] = []
    for folder in folders:
        folder = Path(folder)
        if folder.is_file():
            out.append(folder)
            continue
        if not folder.is_dir():
            raise FileFormatError(folder, "no such folder")
        for p in sorted(folder.iterdir()):
            if p.suffix.lower() not in MATERIAL_SUFFIXES or p.name.startswith("."):
                continue
            if p.suffix.lower() in (".json", ".toml"):
                if p.with_suffix(".h5").exists():
                    continue  # the Keras architecture of an NBRDF
                try:
                    if read_description(p).get("type") != "analytic":
                        continue
                except ReflectoError:
                    continue
            out.append(p)
    names = [p.stem for p in out]
    dup = {n for n in names if names.count(n) > 1}
    if dup:
        raise ReflectoError(f"materials with the same name in different folders: {sorted(dup)}")
    return out


def material_seed(name: str) -> int:
    return zlib.crc32(name.encode()) % (2**31)


def _reconstruct(src: Any, device_name: str, calibration: str | None, seed: int) -> tuple[Any, dict[str, float]]:
    from ..instrument.calibrate import load_calibration, nominal_calibration
    from ..instrument.device import load_device
    from ..instrument.simulate import simulate_capture
    from ..instrument.slices import extract_slices
    from ..reconstruct import reconstruct

    t = {}
    dev = load_device(device_name)
    t0 = time.perf_counter()
    cap = simulate_capture(src, dev, seed=seed)
    t["simulate_s"] = time.perf_counter() - t0
    cal = load_calibration(calibration, dev.nominal()) if calibration else nominal_calibration(dev)
    t0 = time.perf_counter()
    sl = extract_slices(cap, cal)
    t["slices_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    res = reconstruct(sl)
    t["reconstruct_s"] = time.perf_counter() - t0
    return res, t, sl


def run_material(path: str, out_dir: str, device: str = "ideal", calibration: str | None = None) -> dict[str, Any]:
    """Evaluate one material (see the module docstring); writes and returns its record."""
    from ..render.sphere import render_sphere
    from ..sources import load_source
    from .cooktorrance import fit_cook_torrance, fit_cook_torrance_capture
    from .metrics import brdf_error, evaluate_on_grid, max_albedo, metric_grid
    from .split import half

    p = Path(path)
    src = load_source(p)
    name = p.stem
    seed = material_seed(name)
    rec: dict[str, Any] = {"name": name, "file": str(p), "device": device, "seed": seed, "half": half(name),
                           "timings": {}}
    tm = rec["timings"]
    t0 = time.perf_counter()
    grid = metric_grid(METRIC_STRIDE)
    ref_vals = evaluate_on_grid(src, grid)
    alb = max_albedo(src)
    tm["reference_s"] = time.perf_counter() - t0
    renders = {}
    t0 = time.perf_counter()
    renders["reference"] = render_sphere(src, SPHERE_RES, supersample=2)
    tm["render_s"] = time.perf_counter() - t0
    ours_slices = None
    for label, dev, cal in (("ours", device, calibration), ("earlier", "earlier", None)):
        res, t, sl = _reconstruct(src, dev, cal, seed)
        if label == "ours":
            ours_slices = sl
        for k, v in t.items():
            tm[f"{label}_{k}"] = v
        t0 = time.perf_counter()
        err = brdf_error(src, res.model, stride=METRIC_STRIDE, albedo_ref=alb, reference_values=ref_vals)
        tm[f"{label}_metric_s"] = time.perf_counter() - t0
        m = res.model
        rec[label] = {"error": err.normalized, "log_rmse": err.log_rmse, "rmse": err.rmse.tolist(),
                      "eta": m.eta.tolist(), "kd": m.kd.tolist(), "ks": m.ks.tolist(), "isotropic": res.isotropic,
                      "model_error": res.model_error, "shake_detected": res.shake_detected,
                      "albedo_max": res.albedo_max, "energy_scale": res.energy_scale, "notes": res.notes,
                      "finite": bool(np.isfinite(err.normalized))}
        renders[label] = render_sphere(res.model, SPHERE_RES, supersample=2)
    t0 = time.perf_counter()
    ct = fit_cook_torrance(src)
    tm["cook_torrance_fit_s"] = time.perf_counter() - t0
    err = brdf_error(src, ct, stride=METRIC_STRIDE, albedo_ref=alb, reference_values=ref_vals)
    rec["cook_torrance"] = {"error": err.normalized, "log_rmse": err.log_rmse, "rmse": err.rmse.tolist(), **ct.parameters()}
    renders["cook_torrance"] = render_sphere(ct, SPHERE_RES, supersample=2)
    t0 = time.perf_counter()
    sdct = fit_cook_torrance_capture(ours_slices)
    tm["same_data_ct_fit_s"] = time.perf_counter() - t0
    err = brdf_error(src, sdct, stride=METRIC_STRIDE, albedo_ref=alb, reference_values=ref_vals)
    rec["same_data_ct"] = {"error": err.normalized, "log_rmse": err.log_rmse, "rmse": err.rmse.tolist(),
                           **sdct.parameters()}
    rec["albedo_ref"] = alb
    rec["renders"] = {k: np.round(v, 5).tolist() for k, v in renders.items()}
    rec["timings"]["total_s"] = sum(v for k, v in tm.items() if k.endswith("_s"))
    out = Path(out_dir) / "materials" / f"{name}.json"
    with atomic_write(out, "w") as fh:
        fh.write(json.dumps(rec))
    return rec


def _done(out_dir: Path, name: str) -> dict[str, Any] | None:
    p = out_dir / "materials" / f"{name}.json"
    if not p.is_file():
        return None
    try:
        return json.loads(p.read_text())
    except (OSError, json.JSONDecodeError):
        return None  # damaged (cannot happen with atomic writes, but be safe): redo


def prepare_calibration(out_dir: Path, device: str) -> str | None:
    """For ``as-built``: run the virtual calibration once (kept in ``out_dir``)."""
    if device == "ideal":
        return None
    from ..instrument.calibrate import calibrate
    from ..instrument.device import load_device
    from ..instrument.simulate import simulate_calibration

    cal_path = out_dir / f"calibration-{Path(device).stem}.npz"
    if not cal_path.is_file():
        folder = out_dir / f"calibration-{Path(device).stem}"
        if not folder.is_dir():
            simulate_calibration(load_device(device), folder, seed=1)
        calibrate(folder).save(cal_path)
    return str(cal_path)


def sweep(folders: Sequence[str | Path], out_dir: str | Path, device: str = "ideal", jobs: int = 0,
          progress: bool = True) -> list[dict[str, Any]]:
    """Run the sweep (resumable); returns every material's record, sorted by name."""
    from tqdm import tqdm

    out = Path(out_dir)
    (out / "materials").mkdir(parents=True, exist_ok=True)
    mats = find_materials(folders)
    if not mats:
        raise ReflectoError(f"no material files in {', '.join(map(str, folders))}")
    cal = prepare_calibration(out, device)
    records = {p.stem: r for p in mats if (r := _done(out, p.stem)) is not None and r.get("device") == device}
    todo = [p for p in mats if p.stem not in records]
    jobs = jobs or os.cpu_count() or 1
    with tqdm(total=len(mats), initial=len(mats) - len(todo), desc="sweep", unit="material", disable=not progress) as bar:
        if jobs == 1:
            for p in todo:
                records[p.stem] = run_material(str(p), str(out), device, cal)
                bar.update()
        else:
            with ProcessPoolExecutor(max_workers=jobs) as ex:
                futs = {ex.submit(run_material, str(p), str(out), device, cal): p for p in todo}
                for f in as_completed(futs):
                    records[futs[f].stem] = f.result()
                    bar.update()
    recs = [records[k] for k in sorted(records)]
    write_table(recs, out / "results.csv")
    from .plots import plot_errors, plot_spheres

    plot_errors(recs, out / "fig5_errors.png")
    plot_spheres(recs, out / "fig4_spheres.png")
    return recs


COLUMNS = ("name", "half", "device", "ours", "earlier", "cook_torrance", "same_data_ct", "ours_over_ct",
           "ours_over_same_data_ct", "ours_log_rmse", "ct_log_rmse", "eta", "ks_max", "isotropic", "ours_albedo_max",
           "ours_finite", "seconds_total", "seconds_reconstruct", "seconds_ct_fit")


def write_table(records: list[dict[str, Any]], path: Path) -> Path:
    """The CSV table of a sweep (one row per material)."""
    import csv
    import io

    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(COLUMNS)
    for r in records:
        tm = r["timings"]
        o, ct, sd = r["ours"]["error"], r["cook_torrance"]["error"], r["same_data_ct"]["error"]
        w.writerow([r["name"], r.get("half", "other"), r["device"], f"{o:.6g}", f"{r['earlier']['error']:.6g}",
                    f"{ct:.6g}", f"{sd:.6g}", f"{o / max(ct, 1e-300):.4g}", f"{o / max(sd, 1e-300):.4g}",
                    f"{r['ours']['log_rmse']:.6g}", f"{r['cook_torrance']['log_rmse']:.6g}",
                    f"{r['ours']['eta'][0]:.4g}", f"{max(r['ours']['ks']):.4g}", r["ours"].get("isotropic"),
                    f"{r['ours']['albedo_max']:.4g}", r["ours"]["finite"],
                    f"{tm['total_s']:.2f}", f"{tm['ours_reconstruct_s']:.3f}", f"{tm['cook_torrance_fit_s']:.2f}"])
    with atomic_write(path, "w") as fh:
        fh.write(buf.getvalue())
    return path


def summarize(records: list[dict[str, Any]]) -> dict[str, Any]:
    """The validation numbers: over all materials and per half of the protocol (:mod:`.split`)."""
    def numbers(recs: list[dict[str, Any]]) -> dict[str, Any]:
        ours = np.array([r["ours"]["error"] for r in recs])
        ct = np.array([r["cook_torrance"]["error"] for r in recs])
        sd = np.array([r["same_data_ct"]["error"] for r in recs])
        earlier = np.array([r["earlier"]["error"] for r in recs])
        return {
            "materials": len(recs),
            "ours_better_than_ct": int(np.sum(ours < ct)),
            "ours_better_than_same_data_ct": int(np.sum(ours < sd)),
            "ours_better_than_earlier": int(np.sum(ours < earlier)),
            "median_ratio_ours_over_ct": float(np.median(ours / np.maximum(ct, 1e-300))),
            "median_ratio_ours_over_same_data_ct": float(np.median(ours / np.maximum(sd, 1e-300))),
            "median_error": {"ours": float(np.median(ours)), "earlier": float(np.median(earlier)),
                             "cook_torrance": float(np.median(ct)), "same_data_ct": float(np.median(sd))},
            "isotropic": int(sum(bool(r["ours"].get("isotropic")) for r in recs)),
            "all_finite": bool(all(r["ours"]["finite"] for r in recs)),
            "max_albedo": float(max(r["ours"]["albedo_max"] for r in recs)),
        }

    out = {"all": numbers(records), "seconds_total_cpu": float(sum(r["timings"]["total_s"] for r in records))}
    for name in ("tuning", "validation"):
        group = [r for r in records if r.get("half") == name]
        if group:
            out[name] = numbers(group)
    return out
