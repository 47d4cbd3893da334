"""The point-lit sphere of each shared reconstruction against its reference.

For each of the 50 shared materials, the reconstruction (ideal device, cached by
``_shared_models.py``) is exported to ``.bsdf`` and compared with the reference file as
``reflecto render MODEL.bsdf --scene sphere-point --compare REFERENCE`` does
(:func:`reflecto.render.mitsuba.compare`): both through Mitsuba's ``measured`` plugin
(an NBRDF reference is exported the same way, by its back-scattering NDF estimate),
the model's render once and the reference's twice, and the mean image difference over
the sphere's pixels with the noise floor beside it. Also, for each reference that had
to be exported (the NBRDFs), the difference between its Mitsuba render and the direct
evaluation of the reference itself (:func:`reflecto.render.sphere.render_sphere`, same
camera and lights): how much of the difference the reference's own export could
explain; and the same for the model's export against the model, which shows whether
the export adds anything (a seam, rings) to what the model itself looks like. (An RGL file
is rendered as it is; its direct evaluation would differ by its non-reciprocity, since Mitsuba looks its
table up from the camera's side.)

Prints one line per material and median / p90 / max of the difference (target:
median ≤ 10 %, none above 25 %), for all materials and for the tuning and validation
halves (:mod:`reflecto.evaluate.split`), and of the noise floor, and writes
reference | model | difference images of the best, the median, the worst materials and
of ``--show`` ones to ``--out`` (default ``out/validate-renders``), to look for seams
at the parameterization's pole (the highlight's centre) or rings.

Run: ``.venv/bin/python studies/validate_renders.py`` (≈ 6 minutes on 2 cores;
``--names a,b`` for some materials, ``--scene sphere-env`` for the environment map).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from _shared_models import ROOT, shared_models  # noqa: E402
from reflecto.evaluate.split import half  # noqa: E402
from reflecto.export.rgl import export_rgl  # noqa: E402
from reflecto.load import load_source  # noqa: E402
from reflecto.model import load_model  # noqa: E402
from reflecto.render.mitsuba import SMOOTHING_PX, compare, comparison_image, image_difference, object_mask  # noqa: E402
from reflecto.render.sphere import render_sphere  # noqa: E402
from reflecto.sources.rgl import RGLBRDF  # noqa: E402

SHOW = ("chrome-steel", "irid_flake_paint1_rgb", "pvc", "paper_white_rgb")


def _pair(c) -> np.ndarray:  # type: ignore[no-untyped-def]
    """Reference | model | difference, at the exposure that puts the reference's 99th percentile at 0.9."""
    from reflecto.render.mitsuba import exposure_for

    return comparison_image(c.reference.radiance, c.test.radiance, alpha=c.reference.alpha, alpha_test=c.test.alpha,
                            exposure=exposure_for(c.reference.radiance))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--names", help="comma-separated material names (default: all 50)")
    ap.add_argument("--scene", default="sphere-point", choices=("sphere-point", "sphere-env", "teapot-env"))
    ap.add_argument("--spp", type=int, help="samples per pixel (default: the scene's)")
    ap.add_argument("--show", default=",".join(SHOW), help="materials whose image pairs are always written")
    ap.add_argument("--out", default=str(ROOT / "out" / "validate-renders"), help="folder for the image pairs")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    show = set(args.show.split(",")) if args.show else set()
    rows = []
    pairs: dict[str, np.ndarray] = {}
    print(f"{args.scene}: reconstruction's .bsdf against the reference, both through Mitsuba "
          f"(mean image difference over the sphere, Gaussian σ = {SMOOTHING_PX:g} px)")
    with tempfile.TemporaryDirectory() as tmp:
        for p, model_file in shared_models(args.names.split(",") if args.names else None):
            t0 = time.perf_counter()
            model = load_model(model_file)
            test = RGLBRDF(export_rgl(model, Path(tmp) / f"{p.stem}.bsdf"))
            ref = load_source(p)
            c = compare(ref, test, args.scene, spp=args.spp)
            line = (f"{p.stem:28s} difference {100 * c.difference:6.2f} %  floor {100 * c.noise_floor:5.2f} %  "
                    f"corrected {100 * c.corrected:6.2f} %")
            model_export = ref_export = float("nan")
            if args.scene == "sphere-point":
                res = c.reference.radiance.shape[0]
                model_export = image_difference(render_sphere(model, res), c.test.radiance, object_mask(c.test),
                                                SMOOTHING_PX)
                line += f"  model's export vs the model {100 * model_export:5.2f} %"
                if not isinstance(ref, RGLBRDF):
                    ref_export = image_difference(render_sphere(ref, res), c.reference.radiance,
                                                  object_mask(c.reference), SMOOTHING_PX)
                    line += f"  reference's export vs the reference {100 * ref_export:5.2f} %"
            print(line + f"  ({time.perf_counter() - t0:.0f} s)", flush=True)
            rows.append((p.stem, c.difference, c.noise_floor, c.corrected, ref_export, model_export))
            pairs[p.stem] = _pair(c)
    import imageio.v3 as iio

    order = sorted(rows, key=lambda r: r[1])
    chosen = {f"best-{order[0][0]}": order[0][0], f"median-{order[len(order) // 2][0]}": order[len(order) // 2][0],
              f"worst-{order[-1][0]}": order[-1][0]}
    if len(order) > 1:
        chosen[f"second-worst-{order[-2][0]}"] = order[-2][0]
    chosen.update({name: name for name in show if name in pairs})
    for label, name in chosen.items():
        iio.imwrite(out / f"{args.scene}-{label}.png", pairs[name])
    f = np.array([r[2] for r in rows])
    print(f"{len(rows)} materials, {args.scene}:")
    for label, part in (("all", rows), *((h, [r for r in rows if half(r[0]) == h]) for h in ("tuning", "validation"))):
        if not part:
            continue
        dh = np.array([r[1] for r in part])
        worst = max(part, key=lambda r: r[1])[0]
        print(f"  mean image difference, {label} ({len(part)}): median {100 * np.median(dh):.2f} %, "
              f"p90 {100 * np.percentile(dh, 90):.2f} %, max {100 * dh.max():.2f} % ({worst}); "
              f"above 10 %: {int(np.sum(dh > 0.10))}, above 25 %: {int(np.sum(dh > 0.25))}")
    print(f"  noise floor:           median {100 * np.median(f):.2f} %, max {100 * f.max():.2f} %")
    e = np.array([r[5] for r in rows])
    if np.any(np.isfinite(e)):
        k = int(np.nanargmax(e))
        print(f"  the model's export vs the model (direct evaluation): median {100 * np.nanmedian(e):.2f} %, "
              f"max {100 * e[k]:.2f} % ({rows[k][0]})")
    e = np.array([r[4] for r in rows])
    if np.any(np.isfinite(e)):
        k = int(np.nanargmax(e))
        print(f"  exported references' render vs their direct evaluation ({int(np.sum(np.isfinite(e)))}): median "
              f"{100 * np.nanmedian(e):.2f} %, max {100 * e[k]:.2f} % ({rows[k][0]})")
    print(f"  image pairs (reference | model | difference, % of the mean reference radiance): {out}")


if __name__ == "__main__":
    main()
