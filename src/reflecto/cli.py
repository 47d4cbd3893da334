"""Command-line interface: ``reflecto info|tabulate|layout|simulate|simulate-calibration|calibrate|reconstruct|export|render|compare|report|fit-ct|sweep``."""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from . import __version__
from .errors import ReflectoError


def _progress(total: int, desc: str, enabled: bool):  # type: ignore[no-untyped-def]
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit="bin", unit_scale=True, disable=not enabled, leave=False)


def _emit(args: argparse.Namespace, info: dict, lines: list[str]) -> int:
    """Print ``info`` as JSON with ``--json``, else the human-readable ``lines``."""
    print(json.dumps(info, indent=1) if args.json else "\n".join(lines))
    return 0


def cmd_info(args: argparse.Namespace) -> int:
    from .sources import load_source

    src = load_source(args.source)
    theta = np.array([0.0, 20.0, 40.0, 60.0, 80.0])
    alb = src.albedo(theta)
    info = {
        "file": str(src.path),
        "kind": src.kind,
        "isotropic": bool(src.isotropic),
        "reciprocal": bool(src.reciprocal),
        "parameters": src.parameters(),
        "albedo": {f"{t:g}deg": [round(float(v), 5) for v in a] for t, a in zip(theta, alb)},
        "albedo_range": [round(float(alb.min()), 5), round(float(alb.max()), 5)],
    }
    lines = [str(info["file"]),
             f"  kind        {info['kind']}  (isotropic: {info['isotropic']}, reciprocal: {info['reciprocal']})"]
    lines += [f"  {k:<11} {v}" for k, v in info["parameters"].items()]
    lines.append("  directional albedo (RGB) at θ_i:")
    lines += [f"    {k:>6}  {v[0]:.4f} {v[1]:.4f} {v[2]:.4f}" for k, v in info["albedo"].items()]
    lines.append(f"  albedo range [{info['albedo_range'][0]:.4f}, {info['albedo_range'][1]:.4f}]")
    return _emit(args, info, lines)


def cmd_tabulate(args: argparse.Namespace) -> int:
    from .sources import load_source
    from .sources import merl

    src = load_source(args.source)
    out = Path(args.output)
    with _progress(merl.N_BINS, f"tabulating {src.name}", not args.quiet and sys.stderr.isatty()) as bar:
        table = merl.tabulate(src, progress=bar.update)
    merl.write_merl_table(out, table)
    if not args.quiet:
        print(f"wrote {out} ({out.stat().st_size} bytes, MERL 90x90x180, bin centres)")
    return 0


def cmd_layout(args: argparse.Namespace) -> int:
    from .instrument import layout
    from .instrument.device import load_device

    dev = load_device(args.device)
    leds = dev.leds
    if args.optimize:
        leds = layout.optimize_layout(dev.optics, n_leds=dev.n_leds, seed=args.seed)
    cov = layout.coverage(dev.optics, leds, resolution=args.resolution, theta_max_deg=args.theta_max)
    info = {"device": dev.name, "leds_elevation_azimuth_deg": np.round(layout.led_angles(leds), 2).tolist(),
            "coverage": cov.to_dict()}
    if args.plot:
        from .instrument.plots import plot_coverage

        plot_coverage(dev.optics, leds, args.plot, resolution=max(args.resolution, 128))
        info["plot"] = str(args.plot)
    if args.json:
        print(json.dumps(info, indent=1))
        return 0
    print(f"LED layout of device {dev.name!r} (elevation, azimuth in degrees):")
    for k, (el, az) in enumerate(info["leds_elevation_azimuth_deg"]):
        print(f"  l{k}  {el:6.2f}  {az:7.2f}   covers {100 * cov.per_led[k]:5.1f} %")
    print(f"coverage of the NDF cap θ_h ≤ {args.theta_max:g}° (solid-angle fraction):")
    print(f"  union of slices          {100 * cov.union:6.2f} %")
    print(f"  after symmetry (eq. 3)   {100 * cov.after_tau:6.2f} %   (any layout: at most {100 * cov.upper_bound_after_tau:.2f} %)")
    print(f"  after both mirror planes {100 * cov.after_mirrors:6.2f} %")
    print(f"  every slice overlaps another: {cov.every_led_overlaps}")
    if args.plot:
        print(f"wrote {args.plot}")
    return 0


def cmd_simulate(args: argparse.Namespace) -> int:
    from .instrument.capture import write_capture
    from .instrument.device import load_device
    from .instrument.simulate import simulate_capture
    from .sources import load_source

    src = load_source(args.source)
    dev = load_device(args.device)
    cap = simulate_capture(src, dev, tilt_deg=args.tilt, tilt_azimuth_deg=args.tilt_azimuth,
                           rotation_deg=args.rotation, shake=args.shake, seed=args.seed,
                           source_name=str(args.source))
    write_capture(cap, args.output)
    if not args.quiet:
        print(f"wrote {args.output}: {cap.raw.shape[0]} LEDs × {cap.raw.shape[1]} exposures, device {dev.name}")
    return 0


def cmd_simulate_calibration(args: argparse.Namespace) -> int:
    from .instrument.device import load_device
    from .instrument.simulate import simulate_calibration

    dev = load_device(args.device)
    simulate_calibration(dev, args.output, seed=args.seed)
    if not args.quiet:
        print(f"wrote calibration captures of device {dev.name} to {args.output}")
    return 0


def cmd_calibrate(args: argparse.Namespace) -> int:
    from .instrument.calibrate import calibrate

    cal = calibrate(args.calib_dir)
    cal.save(args.output)
    if not args.quiet:
        r = cal.report
        print(f"wrote {args.output}: {r['spots_used']} grid spots, reprojection RMS {r['reprojection_rms_px']:.3f} px; "
              f"LEDs moved by {r['led_offset_from_nominal_deg']}° from nominal")
    return 0


def _reconstruct_one(job: tuple[str, str | None, str, bool, float | None, bool]) -> dict:
    from .instrument.calibrate import load_calibration
    from .instrument.capture import read_capture
    from .instrument.slices import extract_slices
    from .io import atomic_write
    from .reconstruct.pipeline import Options, reconstruct

    cap_dir, cal_path, out, normal, eta, anisotropic = job
    cap = read_capture(cap_dir)
    cal = load_calibration(cal_path, cap.device)
    res = reconstruct(extract_slices(cap, cal), Options(estimate_normal=normal, fixed_eta=eta, anisotropic=anisotropic))
    res.summary["capture"] = str(cap_dir)
    res.model.metadata.update({"capture": str(cap_dir), "eta_fit_error": res.summary["fresnel_error"]})
    res.model.save(out)
    with atomic_write(Path(out).with_suffix(".json"), "w") as fh:
        fh.write(json.dumps(res.summary, indent=1))
    return res.summary


def cmd_reconstruct(args: argparse.Namespace) -> int:
    from concurrent.futures import ProcessPoolExecutor

    from tqdm import tqdm

    from .reconstruct.consistency import THRESHOLD as PAIR_THRESHOLD
    from .reconstruct.symmetry import PLANE_THRESHOLD_DEG

    caps = list(args.captures)
    if len(caps) > 1 and not Path(args.output).suffix == "":
        raise ReflectoError(f"{args.output}: with several captures, -o must be a folder")
    if len(caps) == 1 and Path(args.output).suffix:
        outs = [args.output]
    else:
        Path(args.output).mkdir(parents=True, exist_ok=True)
        outs = [str(Path(args.output) / (Path(c).name + ".reflecto")) for c in caps]
    jobs = [(c, args.calibration, o, args.estimate_normal, args.eta, args.anisotropic) for c, o in zip(caps, outs)]
    show = args.progress or (len(jobs) > 1 and sys.stderr.isatty())
    if len(jobs) == 1:
        results = [_reconstruct_one(jobs[0])]
    else:
        import os

        with ProcessPoolExecutor(max_workers=args.jobs or os.cpu_count()) as ex:
            results = list(tqdm(ex.map(_reconstruct_one, jobs), total=len(jobs), disable=not show, desc="reconstruct"))
    for out, r in zip(outs, results):
        flag = ""
        if r["shake_detected"]:
            planes = [k for k, x in enumerate(r["symmetry_plane_offsets_deg"]) if x is not None and abs(x) > PLANE_THRESHOLD_DEG]
            pairs = [f"{c['kind']} {c['a']}-{c['b']} ×{math.exp(c['log_ratio']):.2f}" for c in r["consistency_checks"]
                     if abs(c["log_ratio"]) > PAIR_THRESHOLD[c["kind"]]]
            moved = [f"LED {c['led']}" + (f" ×{math.exp(c['log_ratio']):.2f}" if c["log_ratio"] is not None else " lit once")
                     for c in r["repeat_checks"] if c["moved"]]
            flag = (f"  SHAKE DETECTED (E(η) {r['fresnel_error_at_check']:.2f}"
                    + (f"; {', '.join(moved)} changed between its two firings" if moved else "")
                    + (f"; LEDs {planes} not symmetric about the normal" if planes else "")
                    + (f"; {', '.join(pairs)}" if pairs else "")
                    + (f"; LEDs {r['excluded_leds']} excluded" if r["excluded_leds"] else "")
                    + ("; an anisotropic material reads like this too: --anisotropic" if planes or pairs else "") + ")")
        print(f"{out}: eta {np.round(r['eta'], 3).tolist()}, kd {np.round(r['kd'], 3).tolist()}, "
              f"ks {np.round(r['ks'], 3).tolist()}, tilt {r['normal_tilt_deg']:.2f}°, {r['seconds'] * 1000:.0f} ms{flag}")
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    from .sources import load_source

    src = load_source(args.source)
    out = Path(args.output)
    if args.format == "rgl":
        from .export.rgl import export_rgl

        iso = {"auto": None, "yes": True, "no": False}[args.isotropic]
        export_rgl(src, out, isotropic=iso)
    else:
        from .export.merl import export_merl

        with _progress(merl_bins(), f"tabulating {src.name}", not args.quiet and sys.stderr.isatty()) as bar:
            export_merl(src, out, allow_anisotropic=args.isotropic == "yes", progress=bar.update)
    if not args.quiet:
        print(f"wrote {out} ({out.stat().st_size} bytes, {args.format})")
    return 0


def merl_bins() -> int:
    from .sources import merl

    return merl.N_BINS


def cmd_render(args: argparse.Namespace) -> int:
    from .render.mitsuba import compare, comparison_image, render, save_image
    from .sources import load_source

    src = load_source(args.source)
    out = Path(args.output)
    if not args.compare:
        r = render(src, args.scene, envmap=args.envmap, resolution=args.resolution, spp=args.spp, seed=args.seed)
        # a linear EXR keeps the object's alpha; PNG and HDR get the grey background
        save_image(np.dstack([r.radiance, r.alpha]) if out.suffix.lower() == ".exr" else r.image(), out)
        print(f"rendered {src.name} ({args.scene}, {args.resolution}², {r.spp} spp, {r.variant}) in {r.seconds:.1f} s; "
              f"wrote {out}")
        return 0
    if out.suffix.lower() != ".png":
        raise ReflectoError(f"{out}: a comparison image must be .png")
    ref = load_source(args.compare)
    c = compare(src, ref, args.scene, envmap=args.envmap, resolution=args.resolution, spp=args.spp, seed=args.seed)
    from .io import atomic_path

    import imageio.v3 as iio

    with atomic_path(out, suffix=".png") as tmp:
        iio.imwrite(tmp, comparison_image(c.reference.radiance, c.test.radiance, alpha=c.reference.alpha,
                                          alpha_test=c.test.alpha))
    seconds = c.test.seconds + c.reference.seconds + c.reference_repeat.seconds
    print(f"rendered {src.name} and {ref.name} twice ({args.scene}, {args.resolution}², {c.test.spp} spp, "
          f"{c.test.variant}) in {seconds:.1f} s; {c.summary()}; wrote {out} (reference | {src.name} | difference)")
    if c.within_noise:
        print("note: the difference is within the noise floor: at this spp the two render alike")
    elif not c.resolved:
        print(f"note: the noise floor is more than a third of the difference; about --spp {c.spp_to_resolve()} "
              "would bring it there")
    return 0


def cmd_compare(args: argparse.Namespace) -> int:
    from .evaluate.metrics import brdf_error
    from .sources import load_source

    ref, test = load_source(args.reference), load_source(args.test)
    err = brdf_error(ref, test)
    return _emit(args, {"reference": str(args.reference), "test": str(args.test), **err.to_dict()}, [
        f"{args.test} against {args.reference} (Ngan et al. eq. 10, MERL bins, θ ≤ 80°):",
        f"  RMSE (R, G, B)      {err.rmse[0]:.5f} {err.rmse[1]:.5f} {err.rmse[2]:.5f} sr⁻¹",
        f"  normalized error    {err.normalized:.5f}  (channel mean / max albedo {err.albedo_ref:.4f})",
        f"  log-RMSE            {err.log_rmse:.5f}"])


def cmd_report(args: argparse.Namespace) -> int:
    from .evaluate.report import write_report

    page = write_report(args.model, args.output, reference=args.ref, spp=args.spp, render=not args.no_render)
    print(f"wrote {page}")
    return 0


def cmd_fit_ct(args: argparse.Namespace) -> int:
    from .evaluate.cooktorrance import fit_cook_torrance
    from .evaluate.metrics import brdf_error
    from .sources import load_source

    src = load_source(args.source)
    ct = fit_cook_torrance(src)
    err = brdf_error(src, ct)
    info = {"source": str(args.source), **ct.parameters(), "error_normalized": err.normalized, "log_rmse": err.log_rmse}
    return _emit(args, info, [
        f"Cook–Torrance fit of {args.source} (Beckmann D, V-groove G, Schlick F; eq. 10 weights):",
        f"  rho_d  {np.round(ct.rho_d, 5).tolist()}",
        f"  rho_s  {np.round(ct.rho_s, 5).tolist()}",
        f"  F0     {ct.f0:.4f}    m  {ct.m:.5f}",
        f"  error  {err.normalized:.5f} (normalized), log-RMSE {err.log_rmse:.5f}"])


def cmd_sweep(args: argparse.Namespace) -> int:
    from .evaluate.sweep import summarize, sweep

    recs = sweep(args.folders, args.output, device=args.device, jobs=args.jobs, progress=not args.quiet and sys.stderr.isatty())
    s = summarize(recs)
    print(json.dumps(s, indent=1))
    print(f"wrote {Path(args.output) / 'results.csv'}, fig5_errors.png, fig4_spheres.png")
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="reflecto",
        description="Condenser-based instant reflectometry (Lan et al. 2010): BRDF model, sources and tools.",
    )
    p.add_argument("--version", action="version", version=f"reflecto {__version__}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    q = sub.add_parser("info", help="kind, parameters and albedo range of a BRDF file")
    q.add_argument("source", help="BRDF file: .binary, .bsdf, .h5, .json/.toml, .reflecto")
    q.add_argument("--json", action="store_true", help="print machine-readable JSON")
    q.set_defaults(func=cmd_info)

    q = sub.add_parser("tabulate", help="write a MERL-format table of any BRDF source")
    q.add_argument("source", help="BRDF file")
    q.add_argument("-o", "--output", required=True, help="output .binary file")
    q.add_argument("-q", "--quiet", action="store_true", help="no progress or summary")
    q.set_defaults(func=cmd_tabulate)

    q = sub.add_parser("layout", help="coverage of a device's LED layout (paper §4.1); optionally re-optimise it")
    q.add_argument("--device", default="ideal", help="ideal | as-built | device file (JSON/TOML)")
    q.add_argument("--optimize", action="store_true", help="run the layout optimizer instead of using the device's LEDs")
    q.add_argument("--seed", type=int, default=0)
    q.add_argument("--resolution", type=int, default=64, help="hemicube resolution of the analysis")
    q.add_argument("--theta-max", type=float, default=80.0, help="NDF cap θ_h ≤ this (degrees)")
    q.add_argument("--plot", type=Path, help="write the Fig. 2(c)(d) analogue to this PNG")
    q.add_argument("--json", action="store_true")
    q.set_defaults(func=cmd_layout)

    q = sub.add_parser("simulate", help="raw frames of a virtual capture of a BRDF source")
    q.add_argument("source", help="BRDF file")
    q.add_argument("--device", default="ideal", help="ideal | as-built | device file (JSON/TOML)")
    q.add_argument("--tilt", type=float, default=0.0, help="hand tilt of the sample normal, degrees (≤ 30)")
    q.add_argument("--tilt-azimuth", type=float, default=None, help="azimuth of the tilt (default: from the seed)")
    q.add_argument("--rotation", type=float, default=0.0, help="rotation of the sample about its normal, degrees")
    q.add_argument("--shake", action="store_true", help="move the sample between two LEDs' frames")
    q.add_argument("--seed", type=int, default=0)
    q.add_argument("-o", "--output", required=True, help="capture folder to write")
    q.add_argument("-q", "--quiet", action="store_true")
    q.set_defaults(func=cmd_simulate)

    q = sub.add_parser("simulate-calibration", help="virtual calibration captures (white target, pinhole grid, mirror)")
    q.add_argument("--device", default="as-built")
    q.add_argument("--seed", type=int, default=0)
    q.add_argument("-o", "--output", required=True, help="calibration folder to write")
    q.add_argument("-q", "--quiet", action="store_true")
    q.set_defaults(func=cmd_simulate_calibration)

    q = sub.add_parser("calibrate", help="geometric, LED and radiometric calibration from calibration captures")
    q.add_argument("calib_dir", help="calibration folder")
    q.add_argument("-o", "--output", required=True, help="calibration file to write (.npz)")
    q.add_argument("-q", "--quiet", action="store_true")
    q.set_defaults(func=cmd_calibrate)

    q = sub.add_parser("reconstruct", help="captures → microfacet BRDF model files (paper §5)")
    q.add_argument("captures", nargs="+", help="capture folder(s)")
    q.add_argument("--calibration", help="calibration file from `reflecto calibrate` (default: the nominal device)")
    q.add_argument("-o", "--output", required=True, help="model file (.reflecto) or, for several captures, a folder")
    q.add_argument("--estimate-normal", action="store_true", help="estimate the altered normal (§5.4; experimental)")
    q.add_argument("--eta", type=float, help="use this η instead of fitting it")
    q.add_argument("--anisotropic", action="store_true",
                   help="the material may be anisotropic: skip the shake cues that assume isotropy (E(η) remains)")
    q.add_argument("--jobs", type=int, default=0, help="worker processes for several captures (default: all cores)")
    q.add_argument("--progress", action="store_true", help="progress bar")
    q.set_defaults(func=cmd_reconstruct)

    q = sub.add_parser("export", help="write a BRDF as an RGL .bsdf (RGB, Mitsuba 3's measured plugin) or MERL .binary file",
                       description="Write a BRDF as an RGL .bsdf tensor file in the RGB variant that Mitsuba 3's "
                                   "`measured` plugin reads (see docs/mitsuba.md), or as a MERL .binary table.")
    q.add_argument("source", help="model (.reflecto) or any BRDF file")
    q.add_argument("--format", choices=("rgl", "merl"), default="rgl")
    q.add_argument("--isotropic", choices=("auto", "yes", "no"), default="auto",
                   help="write an isotropic file (RGL: one φ_i; MERL: the φ_h = 0 slice of an anisotropic "
                        "source) or an anisotropic RGL file (default: as the source says it is, or isotropic if "
                        "its NDF is within 2 %% of its mean around every ring)")
    q.add_argument("-o", "--output", required=True, help="output file")
    q.add_argument("-q", "--quiet", action="store_true")
    q.set_defaults(func=cmd_export)

    from .render.mitsuba import DEFAULT_SPP, SCENES

    q = sub.add_parser("render", help="render a BRDF with Mitsuba 3 (sphere or teapot, point lights or envmap)",
                       description="Render a BRDF with Mitsuba 3. With --compare, render the source once and the "
                                   "reference twice (three seeds) and print the mean image difference over the "
                                   "object's pixels, the same number between the two reference renders (the noise "
                                   "floor) and the difference corrected for it; see docs/mitsuba.md.")
    q.add_argument("source", help="model (.reflecto) or any BRDF file")
    q.add_argument("--scene", choices=SCENES, default="sphere-env")
    q.add_argument("--envmap", help="environment map (.hdr/.exr; default: the shared studio map)")
    q.add_argument("--spp", type=int, help="samples per pixel (default: per scene, "
                   + ", ".join(f"{k} {v}" for k, v in DEFAULT_SPP.items()) + ")")
    q.add_argument("--resolution", type=int, default=256)
    q.add_argument("--seed", type=int, default=0, help="seed of the source's render (the reference's: +1, +2)")
    q.add_argument("--compare", metavar="REFERENCE", help="also render REFERENCE; write reference | source | difference")
    q.add_argument("-o", "--output", required=True,
                   help="image: .png (sRGB, grey background), .exr (linear RGBA) or .hdr (linear, grey background)")
    q.set_defaults(func=cmd_render)

    q = sub.add_parser("compare", help="error of TEST against REFERENCE (Ngan et al. metric, eq. 10)")
    q.add_argument("reference", help="reference BRDF file")
    q.add_argument("test", help="BRDF file to evaluate")
    q.add_argument("--json", action="store_true")
    q.set_defaults(func=cmd_compare)

    q = sub.add_parser("report", help="static HTML report of a model: renders, NDF, coverage, slices, numbers")
    q.add_argument("model", help="model file (.reflecto)")
    q.add_argument("--ref", help="reference BRDF file to compare with")
    q.add_argument("--spp", type=int, default=64)
    q.add_argument("--no-render", action="store_true", help="skip the Mitsuba renders")
    q.add_argument("-o", "--output", required=True, help="folder to write index.html and images into")
    q.set_defaults(func=cmd_report)

    q = sub.add_parser("fit-ct", help="fit the Cook–Torrance baseline to a dense BRDF (as Ngan et al. 2005)")
    q.add_argument("source", help="BRDF file")
    q.add_argument("--json", action="store_true")
    q.set_defaults(func=cmd_fit_ct)

    q = sub.add_parser("sweep", help="validation (paper §6): simulate → reconstruct → evaluate, ours vs baselines")
    q.add_argument("folders", nargs="+", help="folders (or files) of materials: .binary .bsdf .h5 .json .toml")
    q.add_argument("-o", "--output", required=True, help="results folder (resumable: finished materials are skipped)")
    q.add_argument("--device", default="ideal", help="our device: ideal | as-built | device file")
    q.add_argument("--jobs", type=int, default=0, help="worker processes (default: all cores)")
    q.add_argument("-q", "--quiet", action="store_true")
    q.set_defaults(func=cmd_sweep)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except ReflectoError as e:
        print(f"reflecto: error: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("reflecto: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
