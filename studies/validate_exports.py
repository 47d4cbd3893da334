"""Exported ``.bsdf`` files, evaluated by Mitsuba 3, against reflecto's model.

Default: every one of the 50 shared reconstructions (ideal device, cached by
``_shared_models.py``) is exported with :func:`reflecto.export.rgl.export_rgl` on one
core (single-threaded libraries, pinned, CPU time of the export alone), and the file
is evaluated by Mitsuba's ``measured`` plugin
(:class:`reflecto.mitsuba_support.MitsubaMeasured`) on the bins of eq. 10, with the
model as the reference (:func:`reflecto.evaluate.metrics.brdf_error`). Prints per
material the eq. 10 error, the export time and the file size, then median / p90 / max
of each. Target: error ≤ 0.02 on all 50, ≤ 1 s per export.

``--isotropic-proxy``: the same for the models' 1-D versions (the NDF averaged around
each ring, :class:`isotropic_model.TabulatedIsotropic`), the form the reconstruction
gives isotropic materials: isotropic files. ``--analytic``: also analytic models
(one anisotropic), with the per-pair relative difference (median, p95).
``--names a,b``: only those materials. ``--reader numpy``: evaluate with reflecto's
reader of the format instead (the same interpolation, float64; Mitsuba agrees to
≤ 2·10⁻⁵).

Results go to ``--csv`` (default ``docs/exports.csv`` for the full default run: one row
per material) and, with ``--analytic``, ``docs/exports-analytic.csv``; ``make docs``
(``studies/docs_numbers.py``) writes the numbers the docs quote from them.

Run: ``.venv/bin/python studies/validate_exports.py --analytic`` (≈ 6 minutes on one
core; the first run also reconstructs the 50 materials, ≈ 30 s). Timings on a shared
machine are noisy: compare paired runs.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import _bench  # noqa: E402, F401  (one core, single-threaded libraries: before NumPy)

# isort: split
import argparse  # noqa: E402
import csv
import tempfile
import time

import numpy as np

from _shared_models import ROOT, shared_models  # noqa: E402

sys.path.insert(0, str(ROOT / "tests"))

from conftest import random_directions  # noqa: E402
from isotropic_model import TabulatedIsotropic  # noqa: E402
from reflecto.evaluate.metrics import brdf_error  # noqa: E402
from reflecto.export.rgl import export_rgl  # noqa: E402
from reflecto.model import MicrofacetBRDF, load_model  # noqa: E402
from reflecto.sources.analytic import AnalyticBRDF  # noqa: E402
from reflecto.sources.rgl import RGLBRDF  # noqa: E402
from test_export import relative_difference  # noqa: E402


def _reader(kind: str):  # type: ignore[no-untyped-def]
    if kind == "numpy":
        return RGLBRDF, "reflecto's reader"
    from reflecto.mitsuba_support import MitsubaMeasured, import_mitsuba

    mi, variant = import_mitsuba("llvm_ad_rgb")
    if not variant.startswith("llvm"):
        sys.exit("Mitsuba's scalar_rgb variant evaluates pair by pair: too slow for the 1M bins of eq. 10; "
                 "install LLVM >= 16 or use --reader numpy")
    return MitsubaMeasured, f"Mitsuba {mi.__version__} {variant}"


def _stats(values: list[float]) -> str:
    v = np.asarray(values)
    return f"median {np.median(v):.4g}, p90 {np.percentile(v, 90):.4g}, max {v.max():.4g}"


def exports(names: list[str] | None, proxy: bool, reader: str, out_csv: Path | None) -> None:
    read, label = _reader(reader)
    print(f"exported file ({label}) against the model, eq. 10 normalized error; export CPU time on one core")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for p, model_file in shared_models(names):
            m = load_model(model_file)
            src = TabulatedIsotropic.ring_mean_of(m) if proxy else m
            src.eval(np.array([[0.0, 0.0, 1.0]]), np.array([[0.0, 0.0, 1.0]]))  # compile, σ table: not export time
            t0 = time.process_time()
            path = export_rgl(src, Path(tmp) / f"{p.stem}.bsdf")
            seconds = time.process_time() - t0
            err = brdf_error(src, read(path)).normalized
            layout = "isotropic" if len(RGLBRDF(path).phi_i) == 1 else "anisotropic"
            rows.append((p.stem, err, seconds, path.stat().st_size / 1e6, layout))
            print(f"{p.stem:28s} error {err:.4f}  export {seconds:.2f} s  {rows[-1][3]:.2f} MB  {layout}", flush=True)
            path.unlink()
    if out_csv is not None:
        with out_csv.open("w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["name", "error", "export_seconds", "size_mb", "layout"])
            w.writerows([(n, f"{e:.6g}", f"{t:.4f}", f"{mb:.3f}", lay) for n, e, t, mb, lay in rows])
    errs, secs, sizes = zip(*[r[1:4] for r in rows])
    worst = max(rows, key=lambda r: r[1])
    print(f"{len(rows)} materials{' (1-D NDF versions)' if proxy else ''}:")
    print(f"  eq. 10 error: {_stats(errs)} ({worst[0]}); within 0.02: {sum(e <= 0.02 for e in errs)}/{len(rows)}")
    print(f"  export time:  {_stats(secs)} s; within 1 s: {sum(s <= 1.0 for s in secs)}/{len(rows)}")
    print(f"  file size:    {_stats(sizes)} MB")


def analytic(reader: str, out_csv: Path | None) -> None:
    read, label = _reader(reader)
    models = {
        "GGX plastic": AnalyticBRDF(distribution="ggx", alpha=0.2, kd=(0.4, 0.2, 0.1), ks=0.5, eta=1.5),
        "Beckmann metal": AnalyticBRDF(distribution="beckmann", alpha=0.05, kd=0.0, ks=0.9, eta=(2.5, 2.0, 1.8)),
        "Beckmann mirror-like (α 0.01)": AnalyticBRDF(distribution="beckmann", alpha=0.01, kd=0.05, ks=0.9, eta=2.0),
        "anisotropic GGX": AnalyticBRDF(distribution="ggx", alpha=(0.1, 0.4), rotation_deg=30, kd=0.1, ks=0.7, eta=1.6),
    }
    rng = np.random.default_rng(2026)
    i, o = random_directions(rng, 100_000, 80), random_directions(rng, 100_000, 80)
    print(f"analytic sources and their 512 hemicube models ({label}): eq. 10; per-pair relative difference, θ ≤ 80°")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, a in models.items():
            for kind, src in (("analytic", a),
                              ("hemicube", MicrofacetBRDF.from_ndf_function(a.ndf, kd=a.kd, ks=a.ks, eta=a.eta))):
                path = export_rgl(src, Path(tmp) / "m.bsdf")
                r = read(path)
                rel = relative_difference(r.eval(i, o) * o[:, 2:3], src.eval(i, o) * o[:, 2:3])
                rows.append((name, kind, brdf_error(src, r).normalized, float(np.median(rel)),
                             float(np.percentile(rel, 95)), path.stat().st_size / 1e6))
                print(f"{name:30s} {kind:8s} eq. 10 {brdf_error(src, r).normalized:.4f}  pairs: median "
                      f"{100 * np.median(rel):.2f} %, p95 {100 * np.percentile(rel, 95):.2f} %  "
                      f"({path.stat().st_size / 1e6:.1f} MB)", flush=True)
    if out_csv is not None:
        with out_csv.open("w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["name", "kind", "error", "pair_median", "pair_p95", "size_mb"])
            w.writerows([(n, k, f"{e:.6g}", f"{a:.6g}", f"{b:.6g}", f"{mb:.2f}") for n, k, e, a, b, mb in rows])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--names", help="comma-separated material names (default: all 50)")
    ap.add_argument("--isotropic-proxy", action="store_true", help="the models' 1-D (ring-averaged) versions")
    ap.add_argument("--analytic", action="store_true", help="also analytic models")
    ap.add_argument("--reader", choices=("mitsuba", "numpy"), default="mitsuba")
    ap.add_argument("--csv", type=Path, help="per-material results (default: docs/exports.csv for the full "
                    "default run with Mitsuba's reader, else none); --analytic writes NAME-analytic.csv beside it")
    args = ap.parse_args()
    full = not args.names and not args.isotropic_proxy and args.reader == "mitsuba"
    out_csv = args.csv or (ROOT / "docs" / "exports.csv" if full else None)
    exports(args.names.split(",") if args.names else None, args.isotropic_proxy, args.reader, out_csv)
    if args.analytic:
        analytic(args.reader, None if out_csv is None else out_csv.with_name(out_csv.stem + "-analytic.csv"))


if __name__ == "__main__":
    main()
