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

A material that fails (a damaged file, an error in its evaluation, a worker process
that dies) is recorded in ``failures.json`` with its message, and the others finish;
:func:`sweep` then raises :class:`~reflecto.errors.BatchError`. A rerun tries the
failed ones again. A finished record that cannot be read back or lacks a field is
done again (with a warning). Workers end when the parent process dies, even by
SIGKILL (:func:`run_batch`).
"""

from __future__ import annotations

import json
import math
import os
import signal
import sys
import threading
import time
import warnings
import zlib
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import BatchError, FileFormatError, ReflectoError, ReflectoWarning, one_line
from ..fresnel import eta_from_json, eta_to_json, is_constant
from ..io import atomic_write, make_parents, read_description, read_json, remove_empty

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
                      **eta_to_json(m.eta), "kd": m.kd.tolist(), "ks": m.ks.tolist(), "isotropic": res.isotropic,
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


def record_problem(rec: Any, name: str) -> str | None:
    """What a material record lacks for the table, the summary and the figures (None if complete)."""
    def number(v: Any) -> bool:
        return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)

    if not isinstance(rec, dict):
        return "not a record (a JSON object)"
    if rec.get("name") != name or not isinstance(rec.get("device"), str):
        return "name or device missing or wrong"
    tm = rec.get("timings")
    if not isinstance(tm, dict) or not all(number(tm.get(k)) for k in ("total_s", "ours_reconstruct_s", "cook_torrance_fit_s")):
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


def prepare_calibration(out_dir: Path, device: str) -> str | None:
    """For a device with hidden imperfections (``as-built``, ``wide-as-built``): run the
    virtual calibration once (kept in ``out_dir``); ``None`` for one without.

    A kept calibration file that does not load is made again (with a warning).
    """
    from ..instrument.calibrate import Calibration, calibrate
    from ..instrument.device import load_device
    from ..instrument.simulate import simulate_calibration

    dev = load_device(device)
    if dev.truth is None:  # nominal optics (ideal, wide): the nominal calibration is exact
        return None
    cal_path = out_dir / f"calibration-{Path(device).stem}.npz"
    if cal_path.exists():
        try:
            Calibration.load(cal_path)
        except ReflectoError as e:
            warnings.warn(f"{e}; calibrating again", ReflectoWarning, stacklevel=2)
            cal_path.unlink()
    if not cal_path.is_file():
        folder = out_dir / f"calibration-{Path(device).stem}"
        if not folder.is_dir():
            simulate_calibration(dev, folder, seed=1)
        calibrate(folder).save(cal_path)
    return str(cal_path)


# ------------------------------------------------------------------ batches
def interactive() -> bool:
    """Whether progress may be drawn as a bar: stderr is a terminal and ``CI`` is not set."""
    ci = os.environ.get("CI", "").strip().lower() not in ("", "0", "false", "no")
    try:
        return sys.stderr.isatty() and not ci
    except (AttributeError, ValueError):
        return False


class Progress:
    """Progress of a batch on stderr: a tqdm bar on a terminal, else one plain line per item.

    A line reads ``sweep: 12/50 done (pvc, 8.1 s)`` or ``sweep: 13/50 failed (pvc)``.
    """

    def __init__(self, total: int, desc: str, enabled: bool = True, initial: int = 0) -> None:
        self.total, self.desc, self.enabled, self.done = total, desc, enabled, initial
        self.bar = None
        if enabled and interactive():
            from tqdm import tqdm

            self.bar = tqdm(total=total, initial=initial, desc=desc, unit="item", leave=False)

    def update(self, name: str, ok: bool, seconds: float) -> None:
        """Count one finished item: advance the bar, or print ``desc: k/n done (name, s)`` /
        ``desc: k/n failed (name)``.

        Parameters
        ----------
        name
            The item's name.
        ok
            Whether it succeeded.
        seconds
            Its wall time (s).
        """
        self.done += 1
        if self.bar is not None:
            self.bar.update()
        elif self.enabled:
            what = f"done ({name}, {seconds:.1f} s)" if ok else f"failed ({name})"
            print(f"{self.desc}: {self.done}/{self.total} {what}", file=sys.stderr, flush=True)

    def close(self) -> None:
        """Remove the bar (nothing to do for plain lines)."""
        if self.bar is not None:
            self.bar.close()


def _watch_parent(parent: int) -> None:
    """Pool initializer: end this worker as soon as its parent process is gone.

    Linux kills the worker when its parent dies (``PR_SET_PDEATHSIG``, SIGKILL, set
    by ``prctl``); elsewhere, and as a fallback, a thread polls ``os.getppid()``
    twice a second. Without this a SIGKILLed parent leaves its workers waiting on
    their task queue for ever.
    """
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, int(signal.SIGKILL), 0, 0, 0)  # 1 = PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass
    if os.getppid() != parent:  # the parent died before prctl took effect
        os._exit(1)

    def poll() -> None:
        while True:
            time.sleep(0.5)
            if os.getppid() != parent:
                os.kill(os.getpid(), signal.SIGKILL)

    threading.Thread(target=poll, name="reflecto-parent-watch", daemon=True).start()


def _guarded(fn: Callable[..., Any], args: tuple[Any, ...], label: str) -> tuple[bool, Any, float]:
    """``(True, fn(*args), seconds)``, or ``(False, message, seconds)`` if it raised.

    The message is one line naming the item: a ReflectoError's own, anything else as
    an internal error with its type (no exception object crosses the process boundary).
    """
    t0 = time.perf_counter()
    try:
        return True, fn(*args), time.perf_counter() - t0
    except ReflectoError as e:
        msg = one_line(e)
    except MemoryError:
        msg = f"{label}: out of memory"
    except Exception as e:  # noqa: BLE001 — one item's bug must not end the batch
        msg = f"{label}: internal error ({type(e).__name__}: {one_line(e, 300)})"
    return False, msg, time.perf_counter() - t0


def run_batch(fn: Callable[..., Any], items: Sequence[tuple[Any, ...]], labels: Sequence[str], jobs: int,
              on_result: Callable[[int, bool, Any, float], None], scheduler: str | None = None) -> None:
    """Run ``fn(*items[k])`` for every ``k``, in ``jobs`` worker processes (1: in this one),
    or on the Dask cluster whose scheduler listens at ``scheduler`` (:func:`run_on_dask`).

    ``on_result(k, ok, value_or_message, seconds)`` is called in this process as each
    item ends, in completion order; a failed item never stops the others. Workers
    die with this process (:func:`_watch_parent`). If a worker process itself dies
    (a signal, the out-of-memory killer), the pool is lost: every item that had not
    finished is run again, each in a process of its own, so that only the item that
    kills its process is reported failed ("worker process died").
    """
    if scheduler:
        run_on_dask(fn, items, labels, scheduler, on_result)
        return
    if jobs <= 1 or len(items) <= 1:
        for k, args in enumerate(items):
            on_result(k, *_guarded(fn, args, labels[k]))
        return
    unfinished: list[int] = []
    with ProcessPoolExecutor(max_workers=min(jobs, len(items)), initializer=_watch_parent,
                             initargs=(os.getpid(),)) as ex:
        futs = {ex.submit(_guarded, fn, args, labels[k]): k for k, args in enumerate(items)}
        pending = set(futs)
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for f in done:
                try:
                    res = f.result()
                except BrokenProcessPool:
                    unfinished.append(futs[f])
                    continue
                on_result(futs[f], *res)
    _run_isolated(fn, items, labels, sorted(unfinished), jobs, on_result)


#: How long (s) to try to reach a Dask scheduler before giving up.
DASK_CONNECT_TIMEOUT_S = 30.0


def run_on_dask(fn: Callable[..., Any], items: Sequence[tuple[Any, ...]], labels: Sequence[str], scheduler: str,
                on_result: Callable[[int, bool, Any, float], None]) -> None:
    """Run ``fn(*items[k])`` on a Dask cluster (``dask.distributed``, the ``dask`` extra).

    ``scheduler`` is the scheduler's address (``tcp://host:8786``). Each item is one
    task, wrapped as locally (:func:`_guarded`), so a failed item arrives as its message;
    ``on_result`` runs in this process as tasks end. The items write their results
    themselves (atomically, to a folder every worker must see under the same path),
    and every seed derives from the item, so the results equal a local run's. A worker
    that dies is the scheduler's to handle: it reruns the task elsewhere, and a task
    that kills workers repeatedly ends as failed ("worker process died"). Tasks are
    submitted with ``pure=False`` (a rerun of the batch recomputes what its records lack).
    """
    try:
        from distributed import Client, as_completed
        from distributed.client import FutureCancelledError
        from distributed.scheduler import KilledWorker
    except ImportError:
        raise ReflectoError("--scheduler needs dask.distributed: pip install 'reflecto[dask]'") from None
    if not items:
        return
    try:
        client = Client(scheduler, timeout=DASK_CONNECT_TIMEOUT_S, set_as_default=False)
    except (OSError, TimeoutError) as e:
        raise ReflectoError(f"{scheduler}: cannot reach the Dask scheduler ({one_line(e)})") from None
    try:
        futs = {client.submit(_guarded, fn, args, labels[k], pure=False, key=f"reflecto-{k}-{labels[k]}"): k
                for k, args in enumerate(items)}
        for f in as_completed(list(futs), loop=client.loop):
            k = futs[f]
            try:
                res = f.result()
            except (KilledWorker, FutureCancelledError):
                res = (False, f"{labels[k]}: worker process died (killed by a signal, or out of memory)", 0.0)
            on_result(k, *res)
    finally:
        client.close()


def _run_isolated(fn: Callable[..., Any], items: Sequence[tuple[Any, ...]], labels: Sequence[str], which: list[int],
                  jobs: int, on_result: Callable[[int, bool, Any, float], None]) -> None:
    """Run the items ``which`` each in a worker process of its own, ``jobs`` at a time."""
    queue = list(which)
    active: dict[Any, tuple[int, ProcessPoolExecutor, float]] = {}
    while queue or active:
        while queue and len(active) < jobs:
            k = queue.pop(0)
            ex = ProcessPoolExecutor(max_workers=1, initializer=_watch_parent, initargs=(os.getpid(),))
            active[ex.submit(_guarded, fn, items[k], labels[k])] = (k, ex, time.perf_counter())
        done, _ = wait(set(active), return_when=FIRST_COMPLETED)
        for f in done:
            k, ex, t0 = active.pop(f)
            try:
                res = f.result()
            except BrokenProcessPool:
                res = (False, f"{labels[k]}: worker process died (killed by a signal, or out of memory)",
                       time.perf_counter() - t0)
            ex.shutdown(wait=False)
            on_result(k, *res)


def sweep(folders: Sequence[str | Path], out_dir: str | Path, device: str = "ideal", jobs: int = 0,
          progress: bool = True, scheduler: str | None = None) -> list[dict[str, Any]]:
    """Run the sweep (resumable); returns every material's record, sorted by name.

    ``scheduler``: the address of a Dask scheduler to run the materials on instead of
    local processes (:func:`run_on_dask`); ``out_dir`` must then be a path every worker
    sees.

    Raises
    ------
    BatchError
        After writing the results of the others, if some materials failed; its
        ``failures`` list ``(file, message)``, its ``records`` the finished records.
    """
    out = Path(out_dir)
    mats = find_materials(folders)
    if not mats:
        raise ReflectoError(f"no material files in {', '.join(map(str, folders))}")
    make_parents(out / "materials")
    cal = prepare_calibration(out, device)
    records = {p.stem: r for p in mats if (r := _done(out, p.stem)) is not None and r.get("device") == device}
    todo = [p for p in mats if p.stem not in records]
    failures: list[tuple[str, str]] = []
    bar = Progress(len(mats), "sweep", progress, initial=len(mats) - len(todo))

    def finished(k: int, ok: bool, value: Any, seconds: float) -> None:
        if ok:
            records[todo[k].stem] = value
        else:
            failures.append((str(todo[k]), value))
        bar.update(todo[k].stem, ok, seconds)

    try:
        run_batch(run_material, [(str(p), str(out), device, cal) for p in todo], [str(p) for p in todo],
                  jobs or os.cpu_count() or 1, finished, scheduler=scheduler)
    finally:
        bar.close()
    recs = [records[k] for k in sorted(records)]
    remove_empty([out / "materials"])  # nothing finished, ever: no empty folder left behind
    write_failures(out / "failures.json", failures)
    write_table(recs, out / "results.csv")
    if recs:
        from .plots import plot_errors, plot_spheres

        plot_errors(recs, out / "fig5_errors.png")
        plot_spheres(recs, out / "fig4_spheres.png")
    if failures:
        err = BatchError(sorted(failures), len(mats))
        err.records = recs
        raise err
    return recs


def write_failures(path: Path, failures: list[tuple[str, str]]) -> None:
    """``failures.json``: ``[{"file", "error"}, ...]`` of the last run; removed when none failed."""
    if failures:
        with atomic_write(path, "w") as fh:
            fh.write(json.dumps([{"file": f, "error": m} for f, m in sorted(failures)], indent=1))
    elif path.exists():
        path.unlink()


COLUMNS = ("name", "half", "device", "ours", "earlier", "cook_torrance", "same_data_ct", "ours_over_ct",
           "ours_over_same_data_ct", "ours_log_rmse", "ct_log_rmse", "eta", "ks_max", "isotropic", "ours_albedo_max",
           "ours_finite", "seconds_total", "seconds_reconstruct", "seconds_ct_fit")


def _eta_cell(result: dict[str, Any]) -> str:
    """The table's η of a result: the relative index, or ``constant`` for the constant Fresnel lobe."""
    eta = eta_from_json(result)
    return "constant" if eta is None or is_constant(eta) else f"{eta[0]:.4g}"


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
                    _eta_cell(r["ours"]), f"{max(r['ours']['ks']):.4g}", r["ours"].get("isotropic"),
                    f"{r['ours']['albedo_max']:.4g}", r["ours"]["finite"],
                    f"{tm['total_s']:.2f}", f"{tm['ours_reconstruct_s']:.3f}", f"{tm['cook_torrance_fit_s']:.2f}"])
    with atomic_write(path, "w") as fh:
        fh.write(buf.getvalue())
    return path


def summarize(records: list[dict[str, Any]]) -> dict[str, Any]:
    """The validation numbers: over all materials and per half of the protocol (:mod:`.split`);
    ``{"all": {"materials": 0}}`` for no records (every material failed)."""
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
