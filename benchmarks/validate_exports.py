"""Issue 6, acceptance 1: exported ``.bsdf`` files evaluated by Mitsuba 3 vs reflecto.

For reconstructions of 5 shared materials (ideal device) and 3 analytic models (one
anisotropic): median and 95th percentile of the per-pair relative difference between
Mitsuba's ``measured`` plugin on the exported file and reflecto's own model
evaluation (100k random pairs, θ ≤ 80°; the difference is taken relative to
max(|reference|, 1 % of its mean) so that near-zero tails of sharp lobes do not
dominate), and the mean image difference between Mitsuba's ``sphere-point`` render
of the file and the direct render of the model (reflecto.render.sphere).

Run: ``.venv/bin/python benchmarks/validate_exports.py`` (≈ 3 minutes).

``--all``: additionally reconstruct every shared material (10 RGL, 40 MERL/NBRDF;
ideal device, seed 1), export it, and evaluate the file with reflecto's reader of
the format (:class:`reflecto.sources.rgl.RGLBRDF`, the same interpolation as
Mitsuba's plugin; 50k pairs); prints each and how many meet median ≤ 1 %, p95 ≤ 5 %
(≈ 8 minutes).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from conftest import SHARED, random_directions  # noqa: E402
from test_export import relative_difference  # noqa: E402
from reflecto.export.rgl import export_rgl  # noqa: E402
from reflecto.instrument.calibrate import nominal_calibration  # noqa: E402
from reflecto.instrument.device import Device  # noqa: E402
from reflecto.instrument.simulate import simulate_capture  # noqa: E402
from reflecto.instrument.slices import extract_slices  # noqa: E402
from reflecto.mitsuba_support import import_mitsuba  # noqa: E402
from reflecto.model import MicrofacetBRDF  # noqa: E402
from reflecto.reconstruct.pipeline import reconstruct  # noqa: E402
from reflecto.render.mitsuba import image_difference, render  # noqa: E402
from reflecto.render.sphere import render_sphere  # noqa: E402
from reflecto.sources import load_source  # noqa: E402
from reflecto.sources.analytic import AnalyticBRDF  # noqa: E402
from reflecto.sources.rgl import RGLBRDF  # noqa: E402


def all_shared() -> None:
    """Every shared material: reconstruct, export, read back with :class:`RGLBRDF`."""
    from reflecto.evaluate.sweep import find_materials

    dev = Device.builtin("ideal")
    cal = nominal_calibration(dev)
    rng = np.random.default_rng(7)
    i, o = random_directions(rng, 50_000, 80), random_directions(rng, 50_000, 80)
    ok = 0
    paths = find_materials([SHARED / "rgl", SHARED / "merl-nbrdf"])
    with tempfile.TemporaryDirectory() as tmp:
        for p in paths:
            m = reconstruct(extract_slices(simulate_capture(load_source(p), dev, seed=1), cal)).model
            r = RGLBRDF(export_rgl(m, Path(tmp) / "m.bsdf"))
            rel = relative_difference(r.eval_cosine(i, o), m.eval(i, o) * o[:, 2:3])
            med, p95 = np.median(rel), np.percentile(rel, 95)
            ok += med <= 0.01 and p95 <= 0.05
            print(f"{p.stem:34s} median {100 * med:.2f} %  p95 {100 * p95:.2f} %", flush=True)
    print(f"all shared materials: {ok}/{len(paths)} within median 1 %, p95 5 %")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--all", action="store_true", help="also every shared material, read back by reflecto")
    args = ap.parse_args()
    mitsuba_checks()
    if args.all:
        all_shared()


def mitsuba_checks() -> None:
    mi, variant = import_mitsuba("llvm_ad_rgb")
    dev = Device.builtin("ideal")
    cal = nominal_calibration(dev)
    models: dict[str, MicrofacetBRDF] = {}
    for p in [SHARED / "rgl" / "paper_white_rgb.bsdf", SHARED / "rgl" / "ilm_l3_37_metallic_rgb.bsdf",
              SHARED / "merl-nbrdf" / "alum-bronze.h5", SHARED / "merl-nbrdf" / "blue-metallic-paint.h5",
              SHARED / "merl-nbrdf" / "maroon-plastic.h5"]:
        src = load_source(p)
        models[f"recon {p.stem}"] = reconstruct(extract_slices(simulate_capture(src, dev, seed=1), cal)).model
    for name, a in {
        "GGX plastic": AnalyticBRDF(distribution="ggx", alpha=0.2, kd=(0.4, 0.2, 0.1), ks=0.5, eta=1.5),
        "Beckmann metal": AnalyticBRDF(distribution="beckmann", alpha=0.05, kd=0.0, ks=0.9, eta=(2.5, 2.0, 1.8)),
        "anisotropic GGX": AnalyticBRDF(distribution="ggx", alpha=(0.1, 0.4), rotation_deg=30, kd=0.1, ks=0.7, eta=1.6),
    }.items():
        models[name] = MicrofacetBRDF.from_ndf_function(a.ndf, kd=a.kd, ks=a.ks, eta=a.eta)
    rng = np.random.default_rng(2026)
    i, o = random_directions(rng, 100_000, 80), random_directions(rng, 100_000, 80)
    print(f"Mitsuba {mi.__version__}, variant {variant}")
    with tempfile.TemporaryDirectory() as tmp:
        for name, m in models.items():
            path = export_rgl(m, Path(tmp) / "m.bsdf")
            bsdf = mi.load_dict({"type": "measured", "filename": str(path)})
            si = mi.SurfaceInteraction3f()
            si.wi = mi.Vector3f(i[:, 0], i[:, 1], i[:, 2])
            got = np.array(bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(o[:, 0], o[:, 1], o[:, 2]))).reshape(3, -1).T
            ref = m.eval(i, o) * o[:, 2:3]
            rel = np.abs(got - ref).max(axis=1) / np.maximum(np.abs(ref).max(axis=1), 1e-2 * np.abs(ref).mean())
            direct = render_sphere(m, 256)
            img, _ = render(load_source(path), "sphere-point", resolution=256, spp=64)
            print(f"{name:34s} "
                  f"median {100 * np.median(rel):.2f} %  p95 {100 * np.percentile(rel, 95):.2f} %  "
                  f"render diff {100 * image_difference(direct, img):.2f} %  ({path.stat().st_size / 1e6:.1f} MB)", flush=True)


if __name__ == "__main__":
    main()
