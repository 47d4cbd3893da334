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

Each is scored as ``reflecto compare`` scores it (:func:`.metrics.comparison_error`): on the
MERL bins at ``φ_h = 0`` where the material and the model are isotropic, over every
half-vector azimuth where either is not (the Cook–Torrance fits are isotropic, fitted on
the MERL bins).

Each material also records its half of the generalization protocol (:mod:`.split`).

Each material's result (errors, parameters, timings per stage, sphere renders for the
Fig. 4 analogue) is written atomically to ``RESULTS/materials/<name>.json`` as soon
as it is finished; a rerun skips finished materials, so an interrupted sweep loses
nothing and a restarted one ends with identical results (every seed derives from the
material's name). Work is spread over processes; at the end the CSV table
(``results.csv``) and the figures (``fig5_errors.png``, ``fig4_spheres.png``) are
written.

A material that fails (a damaged file, an error in its evaluation, a worker process
that dies) is recorded in ``failures.json`` with its message, and the others finish;
:func:`sweep` then raises :class:`~reflecto.errors.BatchError`. A rerun tries the
failed ones again. A finished record that cannot be read back or lacks a field is
done again (with a warning). Workers end when the parent process dies, even by
SIGKILL (:func:`reflecto.batch.run_batch`).
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import time
import warnings
import zlib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .. import workflow
from ..batch import Progress, run_batch
from ..errors import BatchError, FileFormatError, ReflectoError, ReflectoWarning
from ..fresnel import eta_from_json, eta_to_json, is_constant
from ..instrument.device import load_device
from ..instrument.simulate import simulate_capture
from ..io import atomic_write, make_parents, read_description, read_json, remove_empty, sha256
from ..load import load_source
from ..render.sphere import render_sphere
from .cooktorrance import fit_cook_torrance, fit_cook_torrance_capture
from .metrics import brdf_error, comparison_error, evaluate_on_grid, max_albedo, metric_grid
from .plots import plot_errors, plot_spheres
from .split import half

MATERIAL_SUFFIXES = (".binary", ".bsdf", ".h5", ".json", ".toml")
#: Resolution of the sphere renders kept per material (Fig. 4).
SPHERE_RES = 96
#: Every k-th θ_d/φ_d bin for the reported errors (1 = the full MERL grid).
METRIC_STRIDE = 1


def find_materials(folders: Sequence[str | Path]) -> list[Path]:
    """Material files in ``folders`` (sorted; NBRDF architecture sidecars skipped).

    Parameters
    ----------
    folders
        Folders to list (their files with a suffix of :data:`MATERIAL_SUFFIXES`, hidden
        files skipped; a ``.json``/``.toml`` only when it describes an analytic BRDF and has
        no ``.h5`` beside it), or material files taken as they are.

    Returns
    -------
    list of pathlib.Path
        The material files, folder by folder, each folder's sorted by name.

    Raises
    ------
    FileFormatError
        An entry is neither a folder nor a file.
    ReflectoError
        Two materials have the same name (file stem) in different folders.
    """
    out: list[Path] = []
    for folder in folders:
        folder = Path(folder)
        if folder.is_file():
            out.append(folder)
            continue
        if not folder.is_dir():
            raise FileFormatError(folder, "not a folder or material file" if folder.exists() else "no such folder")
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
    """The simulation seed of a material: ``crc32(name) mod 2³¹``, the same on every run and machine.

    Parameters
    ----------
    name
        The material's name (its file's stem).

    Returns
    -------
    int
        A seed in ``[0, 2³¹)``.
    """
    return zlib.crc32(name.encode()) % (2**31)


def _reconstruct(src: Any, device_name: str, calibration: str | None, seed: int) -> tuple[Any, dict[str, float], Any]:
    """A simulated capture of ``src`` with the device, through the capture→model path
    (:func:`reflecto.workflow.capture_to_model`); its reconstruction, stage times and slices.

    ``calibration`` is :func:`reflecto.workflow.calibration_file`'s: a file, or ``None``
    for a device whose nominal description is exact."""
    dev = load_device(device_name)
    t0 = time.perf_counter()
    cap = simulate_capture(src, dev, seed=seed)
    simulate_s = time.perf_counter() - t0
    result = workflow.capture_to_model(cap, calibration, missing="nominal")
    t = {"simulate_s": simulate_s, "slices_s": result.seconds.slices, "reconstruct_s": result.seconds.reconstruct}
    return result.reconstruction, t, result.slices


def material_digest(path: str | Path) -> str:
    """The digest of a material file's contents (SHA-256, 16 hex digits): a sweep's record of a
    material is kept only while its file is what was evaluated.

    Parameters
    ----------
    path
        The material file.

    Returns
    -------
    str
        16 hexadecimal digits.
    """
    return sha256(Path(path).read_bytes())[:16]


def run_material(path: str, out_dir: str, device: str = "ideal", calibration: str | None = None) -> dict[str, Any]:
    """Evaluate one material (see the module docstring); writes and returns its record.

    Parameters
    ----------
    path
        The material file.
    out_dir
        The sweep's results folder; the record goes to ``out_dir/materials/<name>.json``
        (atomically).
    device
        The device ``ours`` simulates with (a built-in name or a device file).
    calibration
        :func:`reflecto.workflow.calibration_file` of ``device``: its calibration file, or
        ``None`` for a device whose nominal description is exact.

    Returns
    -------
    dict
        The record: ``name``, ``file``, ``device``, ``seed``, ``half``, ``albedo_ref``;
        ``ours``, ``earlier`` (normalized ``error`` of eq. 10, ``log_rmse``, ``rmse``
        per channel in sr⁻¹, ``error_form``, and the model's η, ``kd``, ``ks``, notes and checks),
        ``cook_torrance`` and ``same_data_ct`` (errors and fitted parameters);
        ``renders`` (``SPHERE_RES × SPHERE_RES × 3`` linear RGB lists of the reference and
        the models); ``timings`` (seconds per stage, and ``total_s``).
    """

    p = Path(path)
    src = load_source(p)
    name = p.stem
    seed = material_seed(name)
    rec: dict[str, Any] = {"name": name, "file": str(p), "material_digest": material_digest(p), "device": device,
                           "device_key": workflow.device_key(device), "seed": seed, "half": half(name), "timings": {}}
    tm = rec["timings"]
    t0 = time.perf_counter()
    grid = metric_grid(METRIC_STRIDE)
    ref_vals = evaluate_on_grid(src, grid)
    alb = max_albedo(src)
    tm["reference_s"] = time.perf_counter() - t0

    def score(model):  # as `reflecto compare`: every half-vector azimuth where either side is anisotropic
        if getattr(src, "isotropic", True) and getattr(model, "isotropic", True):
            return brdf_error(src, model, stride=METRIC_STRIDE, albedo_ref=alb, reference_values=ref_vals)
        return comparison_error(src, model)

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
        err = score(res.model)
        tm[f"{label}_metric_s"] = time.perf_counter() - t0
        m = res.model
        rec[label] = {"error": err.normalized, "log_rmse": err.log_rmse, "rmse": err.rmse.tolist(),
                      **eta_to_json(m.eta), "kd": m.kd.tolist(), "ks": m.ks.tolist(), "isotropic": res.isotropic,
                      "model_error": res.model_error, "shake_detected": res.shake_detected,
                      "albedo_max": res.albedo_max, "energy_scale": res.energy_scale, "notes": res.notes,
                      "finite": bool(np.isfinite(err.normalized)), "error_form": err.describe(),
                      "tint_nodes_deg": [] if getattr(m, "tint", None) is None else
                      np.degrees(m.tint.theta).round(2).tolist(),
                      "shadowing": None if res.shadowing is None else res.shadowing.form}
        renders[label] = render_sphere(res.model, SPHERE_RES, supersample=2)
    t0 = time.perf_counter()
    ct = fit_cook_torrance(src)
    tm["cook_torrance_fit_s"] = time.perf_counter() - t0
    err = score(ct)
    rec["cook_torrance"] = {"error": err.normalized, "log_rmse": err.log_rmse, "rmse": err.rmse.tolist(),
                            **ct.parameters()}
    renders["cook_torrance"] = render_sphere(ct, SPHERE_RES, supersample=2)
    t0 = time.perf_counter()
    sdct = fit_cook_torrance_capture(ours_slices)
    tm["same_data_ct_fit_s"] = time.perf_counter() - t0
    err = score(sdct)
    rec["same_data_ct"] = {"error": err.normalized, "log_rmse": err.log_rmse, "rmse": err.rmse.tolist(),
                           **sdct.parameters()}
    rec["albedo_ref"] = alb
    rec["renders"] = {k: np.round(v, 5).tolist() for k, v in renders.items()}
    rec["timings"]["total_s"] = sum(v for k, v in tm.items() if k.endswith("_s"))
    out = Path(out_dir) / "materials" / f"{name}.json"
    with atomic_write(out, "w") as fh:
        fh.write(json.dumps(rec))
    return rec


def record_problem(rec: Any, name: str) -> str | None:
    """What a material record lacks for the table, the summary and the figures (None if complete).

    Parameters
    ----------
    rec
        The record as read back from its JSON file (any JSON value).
    name
        The material's name, which ``rec["name"]`` must equal.

    Returns
    -------
    str or None
        A short description of the first problem found, or ``None`` for a usable record.
    """
    def number(v: Any) -> bool:
        return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)

    if not isinstance(rec, dict):
        return "not a record (a JSON object)"
    if rec.get("name") != name or not isinstance(rec.get("device"), str):
        return "name or device missing or wrong"
    tm = rec.get("timings")
    if not isinstance(tm, dict) or not all(number(tm.get(k))
                                           for k in ("total_s", "ours_reconstruct_s", "cook_torrance_fit_s")):
        return "timings missing or invalid"
    for key in ("ours", "earlier", "cook_torrance", "same_data_ct"):
        r = rec.get(key)
        if not isinstance(r, dict) or not number(r.get("error")) or r["error"] < 0 or not number(r.get("log_rmse")):
            return f"{key}: error or log_rmse missing or invalid"
    ours = rec["ours"]

    def triple(v: Any) -> bool:
        return isinstance(v, list) and len(v) == 3 and all(number(e) for e in v)

    if eta_from_json(ours) is None or not triple(ours.get("ks")) or not number(ours.get("albedo_max")) \
            or not isinstance(ours.get("finite"), bool):
        return "ours: eta, ks, albedo_max or finite missing or invalid"
    renders = rec.get("renders")
    if not isinstance(renders, dict):
        return "renders missing"
    for key in ("reference", "ours", "earlier", "cook_torrance"):
        try:
            img = np.asarray(renders.get(key))  # as the figures read it: no object arrays
        except (TypeError, ValueError):
            return f"render {key!r} invalid"
        if img.shape != (SPHERE_RES, SPHERE_RES, 3) or img.dtype.kind not in "fiu" or not np.all(np.isfinite(img)):
            return f"render {key!r} missing or invalid"
    return None


def _done(out_dir: Path, name: str) -> dict[str, Any] | None:
    """The finished record of ``name``, or None (to do it again) if absent or unusable."""
    p = out_dir / "materials" / f"{name}.json"
    if not p.exists() and not p.is_symlink():
        return None
    try:
        rec = read_json(p)
    except ReflectoError as e:
        warnings.warn(f"{e}; the material is evaluated again", ReflectoWarning, stacklevel=2)
        return None
    problem = record_problem(rec, name)
    if problem:
        warnings.warn(f"{p}: damaged result record ({problem}); the material is evaluated again", ReflectoWarning,
                      stacklevel=2)
        return None
    return rec


def sweep(folders: Sequence[str | Path], out_dir: str | Path, device: str = "ideal", jobs: int = 0,
          progress: bool = True, scheduler: str | None = None) -> list[dict[str, Any]]:
    """Run the sweep (resumable); returns every material's record, sorted by name.

    ``scheduler``: the address of a Dask scheduler to run the materials on instead of
    local processes (:func:`reflecto.batch.run_on_dask`); ``out_dir`` must then be a path every worker
    sees.

    Parameters
    ----------
    folders
        Folders of material files, or the files (:func:`find_materials`).
    out_dir
        The results folder: ``materials/<name>.json``, ``failures.json``, ``results.csv``,
        ``fig5_errors.png``, ``fig4_spheres.png`` and, for a device with hidden
        imperfections, its calibration.
    device
        The device ``ours`` simulates with; records of another device are evaluated again.
    jobs
        Number of worker processes; 0: one per CPU.
    progress
        Draw the progress (:class:`reflecto.batch.Progress`) on stderr.
    scheduler
        Dask scheduler address, or ``None`` for local processes.

    Returns
    -------
    list of dict
        The records of :func:`run_material` (finished ones read back), sorted by name.

    Raises
    ------
    ReflectoError
        No material file in ``folders``, or a device that does not load (before any
        folder is made).
    BatchError
        After writing the results of the others, if some materials failed; its
        ``failures`` list ``(file, message)``, its ``records`` the finished records.
    """
    out = Path(out_dir)
    mats = find_materials(folders)
    if not mats:
        raise ReflectoError(f"no material files in {', '.join(map(str, folders))}")
    load_device(device)  # a bad device is refused before any folder is made for the results
    make_parents(out / "materials")
    cal = workflow.calibration_file(device, out)
    failures: list[tuple[str, str]] = []
    blocked = [p for p in mats if (out / "materials" / f"{p.stem}.json").is_dir()]
    for p in blocked:  # no record can be written there: name the material and the folder in the way
        failures.append((str(p), f"{p}: its result record {out / 'materials' / (p.stem + '.json')} is a folder; "
                                 "remove it (or choose another -o) to evaluate this material"))
    mats_left = [p for p in mats if p not in blocked]
    # a record is kept for the same device (by its contents: a device file edited since, or another
    # of the same name, is another device) and the same material file's contents
    key = workflow.device_key(device)
    records = {p.stem: r for p in mats_left if (r := _done(out, p.stem)) is not None
               and r.get("device_key", r.get("device")) == key and r.get("material_digest") == material_digest(p)}
    todo = [p for p in mats_left if p.stem not in records]
    bar = Progress(len(mats), "sweep", progress, initial=len(mats) - len(todo))

    def finished(k: int, ok: bool, value: Any, seconds: float) -> None:
        if ok:
            records[todo[k].stem] = value
        else:
            failures.append((str(todo[k]), value))
        bar.update(todo[k].stem, ok, seconds)

    # absolute paths: a Dask worker resolves a relative one against its own working folder (the
    # device as given: the records and the table name it so)
    try:
        run_batch(run_material, [(os.path.abspath(p), os.path.abspath(out), device,
                                  None if cal is None else os.path.abspath(cal)) for p in todo],
                  [str(p) for p in todo], jobs or os.cpu_count() or 1, finished, scheduler=scheduler)
    finally:
        bar.close()
    recs = [records[k] for k in sorted(records)]
    remove_empty([out / "materials"])  # nothing finished, ever: no empty folder left behind
    write_failures(out / "failures.json", failures)
    write_table(recs, out / "results.csv")
    if recs:

        plot_errors(recs, out / "fig5_errors.png")
        plot_spheres(recs, out / "fig4_spheres.png")
    if failures:
        err = BatchError(sorted(failures), len(mats))
        err.records = recs
        raise err
    return recs


def write_failures(path: Path, failures: list[tuple[str, str]]) -> None:
    """``failures.json``: ``[{"file", "error"}, ...]`` of the last run; removed when none failed.

    Parameters
    ----------
    path
        The file to write (atomically) or remove.
    failures
        ``(material file, message)`` pairs; written sorted.
    """
    if failures:
        with atomic_write(path, "w") as fh:
            fh.write(json.dumps([{"file": f, "error": m} for f, m in sorted(failures)], indent=1))
    elif path.exists():
        path.unlink()


COLUMNS = ("name", "half", "device", "ours", "earlier", "cook_torrance", "same_data_ct", "ours_over_ct",
           "ours_over_same_data_ct", "ours_log_rmse", "ct_log_rmse", "eta", "ks_max", "isotropic", "ours_albedo_max",
           "ours_finite", "tint_nodes_deg", "shadowing", "seconds_total", "seconds_reconstruct", "seconds_ct_fit")


def _eta_cell(result: dict[str, Any]) -> str:
    """The table's η of a result: the relative index, or ``constant`` for the constant Fresnel lobe."""
    eta = eta_from_json(result)
    return "constant" if eta is None or is_constant(eta) else f"{eta[0]:.4g}"


def write_table(records: list[dict[str, Any]], path: Path) -> Path:
    """The CSV table of a sweep (one row per material).

    Columns :data:`COLUMNS`: the normalized errors of eq. 10 (``ours``, ``earlier``,
    ``cook_torrance``, ``same_data_ct``), the ratios ``ours/ct`` and ``ours/same_data_ct``,
    log-RMSEs, the model's η, largest ``ks``, isotropy, largest albedo and finiteness, the
    θ_d nodes of the Fresnel tint (degrees, space-separated; empty without a tint), the
    shadowing form (:mod:`reflecto.reconstruct.extrapolation`; empty on the anisotropic
    path), and seconds (total, reconstruction, Cook–Torrance fit).

    Parameters
    ----------
    records
        Records of :func:`run_material`.
    path
        The CSV file to write (atomically).

    Returns
    -------
    pathlib.Path
        ``path``.
    """

    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(COLUMNS)
    for r in records:
        tm = r["timings"]
        o, ct, sd = r["ours"]["error"], r["cook_torrance"]["error"], r["same_data_ct"]["error"]
        w.writerow([r["name"], r.get("half", "other"), r["device"], f"{o:.6g}", f"{r['earlier']['error']:.6g}",
                    f"{ct:.6g}", f"{sd:.6g}", f"{o / max(ct, 1e-300):.4g}", f"{o / max(sd, 1e-300):.4g}",
                    f"{r['ours']['log_rmse']:.6g}", f"{r['cook_torrance']['log_rmse']:.6g}",
                    _eta_cell(r["ours"]), f"{max(r['ours']['ks']):.4g}", r["ours"].get("isotropic"),
                    f"{r['ours']['albedo_max']:.4g}", r["ours"]["finite"],
                    " ".join(f"{t:.1f}" for t in r["ours"].get("tint_nodes_deg", [])), r["ours"].get("shadowing") or "",
                    f"{tm['total_s']:.2f}", f"{tm['ours_reconstruct_s']:.3f}", f"{tm['cook_torrance_fit_s']:.2f}"])
    with atomic_write(path, "w") as fh:
        fh.write(buf.getvalue())
    return path


def summarize(records: list[dict[str, Any]]) -> dict[str, Any]:
    """The validation numbers: over all materials and per half of the protocol (:mod:`.split`);
    ``{"all": {"materials": 0}}`` for no records (every material failed).

    Parameters
    ----------
    records
        Records of :func:`run_material`.

    Returns
    -------
    dict
        ``all`` (and ``tuning``, ``validation`` for halves with records): ``materials``,
        the counts ``ours_better_than_ct``, ``ours_better_than_same_data_ct``,
        ``ours_better_than_earlier`` (lower normalized error of eq. 10), the median ratios
        ``median_ratio_ours_over_ct`` and ``median_ratio_ours_over_same_data_ct``,
        ``median_error`` per method, ``isotropic`` (count), ``all_finite`` and
        ``max_albedo``; plus ``seconds_total_cpu``, the sum of the records' ``total_s``.
    """
    if not records:
        return {"all": {"materials": 0}, "seconds_total_cpu": 0.0}
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
