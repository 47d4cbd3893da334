"""Benchmark of the whole capture → model path, per stage, on measured materials.

Captures: :data:`MATERIALS` (measured, from ``../shared/data``) through the as-built
device, calibrated (``simulate_calibration`` + ``calibrate``), each tilted by
``3 + 5 u`` degrees (``u`` uniform from the material's seed, :func:`material_seed`) at
an azimuth drawn from the same seed, written as capture folders (16-bit PNG frames +
manifest) into ``--work`` (made once, reused).

Timed per capture, after one warm-up round, :data:`REPEATS` rounds, one core:

* ``read``        the frames decoded and validated, saturation checked (:func:`read_capture`),
* ``hdr+slices``  the calibration (read once per file identity) and :func:`measure` (HDR, radiometry),
* ``fit``         the §5 reconstruction with the default options, incl. the normal, isotropy and motion,
* ``eq3 test``    the capture's symmetry test against its model,
* ``write``       the model file and its JSON summary (atomic, fsync'ed),
* ``total``       :func:`reflecto.workflow.reconstruct_folder` end to end, the path ``reflecto
  reconstruct`` and ``reflecto watch`` run; the stages are its own measurements.

Below ``fit``, its parts (CPU, :class:`reflecto.reconstruct.FitSeconds`): the normal, the
isotropic fit(s) with the device frame's check, the isotropy test, the shadowing form's
choice, the model (``k_d``'s ceiling, tint, NDF per node, energy limit), the motion cues.
Then the same path for the preview ``reflecto watch`` writes first
(``reconstruct_folder(..., preview=True)``, :mod:`reflecto.reconstruct.preview`), timed in
the same rounds, capture by capture beside the full one.

Prints per stage the median and p90 over all captures × rounds of the process's CPU
time (the benchmark runs single-threaded on one core; on a shared machine the wall
time also counts the other processes' turns) and the wall time beside it; then the
first-call time of ``reflecto reconstruct`` in a fresh process (wall, median of
``--first`` runs). The device captures 8.6 BRDFs per second (117 ms each); the
target is ≤ 100 ms median, ≤ 150 ms p90 marginal per capture (``total``).

With ``--normal true`` (or ``device``) the normal is given instead (the capture's simulated
normal, or the device axis): the same path without the altered normal's estimate.

Run: ``.venv/bin/python benchmarks/bench_capture_to_model.py [--work DIR] [--repeats N] [--normal auto|true|device]``.
"""

from __future__ import annotations

import _bench  # noqa: F401  (pins to one core before NumPy loads)

# isort: split
import argparse  # noqa: E402
import json  # noqa: E402
import os  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from reflecto import load_source, workflow  # noqa: E402
from reflecto.evaluate.sweep import material_seed  # noqa: E402
from reflecto.instrument.calibrate import calibrate  # noqa: E402
from reflecto.instrument.capture import write_capture  # noqa: E402
from reflecto.instrument.device import Device  # noqa: E402
from reflecto.instrument.simulate import simulate_calibration, simulate_capture  # noqa: E402
from reflecto.reconstruct import Options  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
#: The source tree of the reflecto this process runs (the fresh process runs the same one).
SRC = Path(workflow.__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"
#: Measured materials (NBRDF fits of MERL materials and RGL measurements): metals, paints,
#: plastics, phenolic, fabric.
MATERIALS = ("merl-nbrdf/alum-bronze.h5", "merl-nbrdf/blue-metallic-paint.h5", "merl-nbrdf/delrin.h5",
             "merl-nbrdf/pink-felt.h5", "merl-nbrdf/red-specular-plastic.h5",
             "merl-nbrdf/specular-maroon-phenolic.h5", "merl-nbrdf/steel.h5", "merl-nbrdf/orange-paint.h5",
             "rgl/acrylic_felt_green_rgb.bsdf", "rgl/chm_mint_rgb.bsdf")
REPEATS = 3
#: Stage names of the report and the keys of ``reconstruct_folder``'s stage times: read (decode,
#: validation, saturation check), hdr+slices (calibration choice, HDR merge, radiometry), fit (§5,
#: the normal, isotropy and motion tests), eq3 test, write (model + summary).
STAGE_KEYS = {"read": "read", "hdr+slices": "slices", "fit": "reconstruct", "eq3 test": "symmetry", "write": "write"}
STAGES = (*STAGE_KEYS, "total")


def tilt_of(name: str) -> float:
    """The capture's tilt (degrees) in [3, 8): ``3 + 5 u``, ``u`` uniform from the material's seed."""
    return 3.0 + 5.0 * float(np.random.default_rng(material_seed(name)).uniform())


def prepare(work: Path) -> tuple[list[Path], Path]:
    """Capture folders of :data:`MATERIALS` and the calibration file in ``work`` (made if absent)."""
    dev = Device.builtin("as-built")
    cal_path = work / "as-built.npz"
    if not cal_path.exists():
        calibrate(simulate_calibration(dev, work / "calib", seed=0)).save(cal_path)
    caps = []
    for rel in MATERIALS:
        src = SHARED / rel
        name = Path(rel).stem
        out = work / "captures" / name
        if not (out / "manifest.json").exists():
            cap = simulate_capture(load_source(src), dev, tilt_deg=tilt_of(name), seed=material_seed(name),
                                   source_name=str(src))
            write_capture(cap, out)
        caps.append(out)
    return caps, cal_path


def true_normal(cap_dir: Path) -> tuple[float, float, float]:
    """The sample normal the capture was simulated with (device coordinates)."""
    x, y, z = json.loads((cap_dir / "manifest.json").read_text())["simulation"]["normal"]
    return float(x), float(y), float(z)


def stages_once(cap_dir: Path, cal_path: Path, out: Path, preview: bool = False,
                normal: str = "auto") -> dict[str, tuple[float, float]]:
    """(CPU s, wall s) of each stage for one capture, as :func:`reflecto.workflow.reconstruct_folder`
    (the path of ``reflecto reconstruct`` and ``reflecto watch``) measures them; ``preview``:
    the preview's path; ``normal``: ``auto`` or ``device`` (:attr:`reflecto.reconstruct.Options.normal`),
    or ``true``: the simulated capture's own normal (its manifest's ``simulation`` record), given."""
    given = true_normal(cap_dir) if normal == "true" else normal
    c0, t0 = time.process_time(), time.perf_counter()
    summary = workflow.reconstruct_folder(cap_dir, out, str(cal_path), options=Options(normal=given),
                                          preview=preview)
    total = (time.process_time() - c0, time.perf_counter() - t0)
    cpu, wall = summary["stage_cpu_seconds"], summary["stage_seconds"]
    res = {name: (cpu[key], wall[key]) for name, key in STAGE_KEYS.items()}
    res["total"] = total
    for part, seconds in summary["fit_cpu_seconds"].items():
        res[f"  {part}"] = (seconds, seconds)  # CPU only: the parts are not timed on the wall clock
    return res


def first_call(cap_dir: Path, cal_path: Path, runs: int) -> list[float]:
    """Wall seconds of ``reflecto reconstruct CAP --calibration CAL -o M`` in fresh processes."""
    times = []
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(runs):
            t = time.perf_counter()
            subprocess.run([sys.executable, "-m", "reflecto.cli", "reconstruct", str(cap_dir), "--calibration",
                            str(cal_path), "-o", str(Path(tmp) / f"m{k}.reflecto"), "-q"], check=True,
                           stdout=subprocess.DEVNULL, env={**os.environ, "PYTHONPATH": str(SRC)})
            times.append(time.perf_counter() - t)
    return times


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", type=Path, default=ROOT / "out" / "bench-capture-to-model",
                    help="folder of the captures and calibration (made once, reused)")
    ap.add_argument("--repeats", type=int, default=REPEATS, help="rounds over all captures")
    ap.add_argument("--first", type=int, default=3, help="fresh-process runs of the first call (0: skip)")
    ap.add_argument("--normal", choices=("auto", "device", "true"), default="auto",
                    help="auto: the default path (the altered normal estimated); device or true: the normal "
                         "given (the device axis, or the capture's simulated normal), the path without the estimate")
    args = ap.parse_args()
    caps, cal_path = prepare(args.work)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "m.reflecto"
        for c in caps:  # warm-up: compiled kernels, caches, page cache
            stages_once(c, cal_path, out, normal=args.normal)
            stages_once(c, cal_path, out, preview=True)
        rows: dict[str, list[tuple[float, float]]] = {}
        previews: dict[str, list[tuple[float, float]]] = {}
        for _ in range(args.repeats):
            for c in caps:
                for k, v in stages_once(c, cal_path, out, normal=args.normal).items():
                    rows.setdefault(k, []).append(v)
                for k, v in stages_once(c, cal_path, out, preview=True).items():
                    previews.setdefault(k, []).append(v)
    print(f"capture → model, {len(caps)} measured materials × {args.repeats}, as-built device, calibrated, "
          f"tilted 3–8°, normal {args.normal}, one core (ms per capture, marginal)")
    print(f"  {'stage':12s} {'cpu median':>10s} {'cpu p90':>8s} {'wall median':>11s} {'wall p90':>8s}")
    parts = [k for k in rows if k.startswith("  ")]
    for s in STAGES:
        for name in [s] + (parts if s == "fit" else []):
            cpu = 1000 * np.array([v[0] for v in rows[name]])
            wall = "" if name in parts else (f" {np.median(1000 * np.array([v[1] for v in rows[name]])):11.1f} "
                                             f"{np.percentile(1000 * np.array([v[1] for v in rows[name]]), 90):8.1f}")
            print(f"  {name:12s} {np.median(cpu):10.1f} {np.percentile(cpu, 90):8.1f}{wall}")
    pv = 1000 * np.array([v[0] for v in previews["total"]])
    full = 1000 * np.array([v[0] for v in rows["total"]])
    print(f"  preview (`watch` writes it first; same rounds): total CPU median {np.median(pv):.1f}, p90 "
          f"{np.percentile(pv, 90):.1f}; per capture {np.median(pv / full):.3f}x the full path's "
          f"({np.min(pv / full):.3f}-{np.max(pv / full):.3f}); its fit "
          f"{np.median(1000 * np.array([v[0] for v in previews['fit']])):.1f} ms median")
    if args.first:
        t = first_call(caps[0], cal_path, args.first)
        print(f"first call (fresh process, `reflecto reconstruct`): median {np.median(t):.2f} s, "
              f"max {max(t):.2f} s over {len(t)} runs")


if __name__ == "__main__":
    main()
