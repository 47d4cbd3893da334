"""Command-line interface: ``reflecto SUBCOMMAND``, one of ``info``, ``tabulate``, ``layout``, ``simulate``,
``simulate-calibration``, ``calibrate``, ``reconstruct``, ``watch``, ``export``, ``render``, ``compare``,
``report``, ``fit-ct``, ``sweep``, ``gallery``, ``design``.

Each subcommand is one ``cmd_*`` handler: it takes the parsed arguments of its
subcommand (:func:`build_parser`) and returns the exit status (0, or 1 when a batch
item failed); a failure raises :class:`~reflecto.errors.ReflectoError`, which
:func:`main` prints as one line. Every failure prints one line, ``reflecto: error: FILE: problem``, on stderr and
exits with status 1, leaving no output file and no folder it created; ``--json``
makes stdout exactly one JSON document. Batches (several captures, ``sweep``)
finish every item they can, report each failed one, and exit 1 if any failed.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import sys
import time
import unicodedata
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NoReturn

import imageio.v3 as iio
import numpy as np
from tqdm import tqdm

from . import __version__, kinds, workflow
from .batch import Progress, check_scheduler_address, interactive, run_batch
from .errors import (
    BatchError,
    FileFormatError,
    OutputError,
    ParameterError,
    ReflectoError,
    ReflectoWarning,
    interrupted,
    one_line,
    shown_path,
)
from .evaluate.cooktorrance import fit_cook_torrance
from .evaluate.design import (
    DEFAULT_CONES,
    DEFAULT_LED_COUNTS,
    DEFAULT_TILTS,
    DESIGN_DECIMALS,
    best_design,
    design_study,
    design_value,
)
from .evaluate.gallery import GALLERY_MARKER, GallerySettings, gallery
from .evaluate.metrics import ALBEDO_AZIMUTHS, comparison_error
from .evaluate.report import write_report
from .evaluate.sweep import find_materials, summarize, sweep
from .export.merl import export_merl, holds_isotropic
from .export.rgl import export_rgl
from .fresnel import eta_from_json, format_eta
from .instrument import layout
from .instrument.calibrate import calibrate, read_calibration
from .instrument.capture import CALIBRATION_MANIFEST, MANIFEST, write_capture
from .instrument.device import BUILTINS as DEVICE_BUILTINS
from .instrument.device import load_device
from .instrument.plots import plot_coverage
from .instrument.simulate import simulate_calibration, simulate_capture
from .io import atomic_path, check_output, make_parents, read_json
from .load import load_source
from .reconstruct import Options
from .reconstruct.asymmetric import MIN_CAPTURES
from .reconstruct.eq3 import SymmetryTest
from .reconstruct.pipeline import BOUND_NOTE, PEAK_BEYOND_NOTE
from .reconstruct.preview import UNPLACED
from .render.mitsuba import (
    DEFAULT_SPP,
    SCENES,
    check_envmap,
    compare,
    comparison_image,
    render,
    save_image,
    titled,
    to_srgb8,
    utf8_name,
)
from .render.mitsuba import MAX_SEED as RENDER_MAX_SEED
from .sources import merl
from .watch import Entry, Watcher, default_previewer, default_reconstructor

_SHOW_WARNING = warnings.showwarning


def _interactive() -> bool:
    return interactive()


def _progress(total: int, desc: str, enabled: bool):
    return tqdm(total=total, desc=desc, unit="bin", unit_scale=True, disable=not enabled, leave=False)


def _emit(args: argparse.Namespace, info: dict, lines: list[str]) -> int:
    """Print ``info`` as JSON with ``--json``, else the human-readable ``lines`` (none with ``-q``)."""
    if args.json:  # strict JSON: a non-finite number (a file's own metadata) is written as null
        print(json.dumps(_finite_json(info), indent=1, allow_nan=False))
    elif lines and not getattr(args, "quiet", False):  # a name's control characters escaped: one line each
        print("\n".join(shown_path(line) for line in lines))
    return 0


def _finite_json(value: Any) -> Any:
    """``value`` with every non-finite float (NaN, ±inf) replaced by ``None`` (JSON's null)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite_json(v) for v in value]
    return value


#: What reflecto reads a file of each suffix as (``load_source`` goes by suffix first).
_SUFFIX_KINDS = {".binary": "merl", ".bsdf": "rgl", ".reflecto": "model", ".h5": "nbrdf", ".json": "description",
                 ".toml": "description"}
_KIND_WORDS = {"merl": "a MERL table (.binary)", "rgl": "an RGL tensor file (.bsdf)",
               "model": "a model file (.reflecto)", "nbrdf": "an NBRDF fit (.h5)",
               "description": "a JSON/TOML description"}


def _check_suffix(output: str | Path, kind: str, hint: str = "") -> None:
    """Refuse an output whose suffix reflecto would read as another kind of file than ``kind``."""
    suffix = Path(output).suffix.lower()
    other = _SUFFIX_KINDS.get(suffix)
    if other is not None and other != kind:
        raise OutputError(output, f"this writes {_KIND_WORDS[kind]}, "
                                  f"but a {suffix} file is read as {_KIND_WORDS[other]}"
                          + (f": {hint}" if hint else ""))


_BRDF = "a BRDF file (.binary, .bsdf, .h5, .json/.toml) or a model (.reflecto)"
_DEVICE = "a device: ideal, as-built, earlier, wide, wide-as-built, or a device file (.json/.toml)"
_FILE_SUFFIXES = (".reflecto", ".binary", ".bsdf", ".h5", ".npz", ".json", ".toml", ".png", ".exr", ".hdr")

#: Per command: (argument, what it reads, its kinds) for every input (kinds.KINDS).
_INPUTS: dict[str, list[tuple[str, str, tuple[str, ...]]]] = {
    "info": [("source", _BRDF, kinds.BRDF_KINDS)],
    "tabulate": [("source", _BRDF, kinds.BRDF_KINDS)],
    "simulate": [("source", _BRDF, kinds.BRDF_KINDS), ("device", _DEVICE, ("device",))],
    "simulate-calibration": [("device", _DEVICE, ("device",))],
    "layout": [("device", _DEVICE, ("device",))],
    "calibrate": [("calib_dir", kinds.KINDS["calibration-folder"], ("calibration-folder", "folder"))],
    "reconstruct": [("captures", kinds.KINDS["capture"], ("capture",)),
                    ("calibration", kinds.KINDS["calibration"], ("calibration",))],
    "export": [("source", _BRDF, kinds.BRDF_KINDS)],
    "render": [("source", _BRDF, kinds.BRDF_KINDS), ("compare", _BRDF, kinds.BRDF_KINDS)],
    "compare": [("reference", _BRDF, kinds.BRDF_KINDS), ("test", _BRDF, kinds.BRDF_KINDS)],
    "report": [("model", kinds.KINDS["model"], ("model",)), ("ref", _BRDF, kinds.BRDF_KINDS)],
    "fit-ct": [("source", _BRDF, kinds.BRDF_KINDS)],
    "gallery": [("materials", _BRDF, kinds.BRDF_KINDS), ("device", _DEVICE, ("device",)),
                ("calibration", kinds.KINDS["calibration"], ("calibration",))],
    "sweep": [("folders", "folders or files of materials (BRDF files)", ("folder", *kinds.BRDF_KINDS)),
              ("device", _DEVICE, ("device",))],
    "design": [("folders", "folders or files of materials (BRDF files)", ("folder", *kinds.BRDF_KINDS))],
}

#: Per command: (output argument, suffixes it may have, what it writes); ``None``: a folder.
_OUTPUTS: dict[str, tuple[str, tuple[str, ...] | None, str]] = {
    "tabulate": ("output", (".binary",), "a MERL table (.binary)"),
    "calibrate": ("output", (".npz",), "a calibration file (.npz)"),
    "render": ("output", (".png", ".exr", ".hdr"), "an image (.png, .exr or .hdr)"),
    "layout": ("plot", (".png",), "a plot (.png)"),
    "simulate": ("output", None, "a capture folder"),
    "simulate-calibration": ("output", None, "a calibration folder"),
    "report": ("output", None, "a report folder (index.html and images)"),
    "gallery": ("output", None, "a gallery folder (index.html and renders)"),
    "sweep": ("output", None, "a results folder"),
    "design": ("output", None, "a results folder"),
}


#: The list options and the type of their values: one syntax, values separated by spaces or commas.
_LIST_OPTIONS = {"rotations": float, "cones": float, "tilts": float, "leds": int}


def _lists(args: argparse.Namespace) -> None:
    """Turn every list option's words (``0 90`` or ``0,90``) into numbers; one line naming the option otherwise."""
    for name, typ in _LIST_OPTIONS.items():
        words = getattr(args, name, None)
        if words is None:
            continue
        items = [w for word in words for w in str(word).split(",") if w.strip()]
        try:
            values = [typ(w) for w in items]
        except ValueError:
            raise ReflectoError(f"--{name}: expected {'integers' if typ is int else 'numbers'} separated by spaces, "
                                f"got {' '.join(map(str, words))!r}") from None
        if not values:
            raise ReflectoError(f"--{name}: expected at least one value")
        setattr(args, name, values)


def check_inputs(args: argparse.Namespace) -> None:
    """Refuse at once an input or output of the wrong kind (:mod:`reflecto.kinds`).

    Each input named on the command line is identified (model, capture folder,
    calibration, BRDF file, device, ...); one of another kind than the command reads
    gives ``FILE is KIND; COMMAND needs KIND (what to run instead)``. Output suffixes
    are checked against what the command writes.

    Raises
    ------
    reflecto.kinds.KindError
    """
    command = args.command
    if getattr(args, "scheduler", None):  # before any folder is made for the results
        check_scheduler_address(args.scheduler)
    for name, need, accept in _INPUTS.get(command, []):
        value = getattr(args, name, None)
        values = value if isinstance(value, list) else [value]
        for v in values:
            if v is None or (name == "device" and str(v) in DEVICE_BUILTINS):
                continue
            label = command if name in ("source", "model", "captures", "calib_dir", "materials", "folders",
                                        "reference", "test") else f"{command} --{name.replace('_', '-')}"
            if not str(v).strip():  # Path("") is ".": the message would name the current folder
                raise ReflectoError(f"{label}: the argument is empty; expected {need}")
            kinds.require(v, label, accept, need)
    spec = _OUTPUTS.get(command)
    if spec is None:
        out = getattr(args, "output", None)
        if out is not None and not str(out).strip():  # Path("") is ".": it would write into the current folder
            raise ReflectoError(f"{command} -o: the argument is empty; expected an output path")
        return
    name, suffixes, what = spec
    out = getattr(args, name, None)
    if out is None:
        return
    if not str(out).strip():
        raise ReflectoError(f"{command} {'--plot' if name == 'plot' else '-o'}: the argument is empty; "
                            f"expected {what}")
    if command == "render" and getattr(args, "compare", None):
        suffixes, what = (".png",), "a comparison image (.png)"
    if suffixes is not None:
        kinds.require_output_suffix(out, command, suffixes, what, "--plot" if name == "plot" else "-o")
    elif Path(out).suffix.lower() in _FILE_SUFFIXES and not Path(out).is_dir():
        raise kinds.KindError(out, f"a {Path(out).suffix} file name", command, what,
                              f"use -o {Path(out).with_suffix('')}", verb="writes")
    else:
        _refuse_other_folder(out, command, what)


#: Folders an output folder must not be written into (their readers would take the
#: output's files for their own) unless the command writes that kind of folder.
_INPUT_FOLDER_KINDS = {"capture": "simulate", "calibration-folder": "simulate-calibration"}


def _refuse_other_folder(out: str | Path, command: str, what: str) -> None:
    """Refuse a folder output (``what``) where a file is in the way, or into a capture or
    calibration folder (the report's images beside a capture's frames would make it
    another capture's folder for ``watch``, and a sweep's results inside one a damaged one)."""
    path = Path(out)
    if _exists(path) and not path.is_dir():
        raise OutputError(out, f"exists and is not a folder; {command} writes {what}: name a folder")
    kind = kinds.identify(path).name if path.is_dir() else "folder"
    if kind in _INPUT_FOLDER_KINDS and _INPUT_FOLDER_KINDS[kind] != command:
        raise OutputError(out, f"is {kinds.KINDS[kind]}; {command} writes {what}: name another folder")


def _within(path: str | Path, folder: str | Path) -> bool:
    """Whether ``path`` is ``folder`` or lies inside it (links followed; ``path`` need not exist)."""
    try:
        p, f = Path(path).resolve(), Path(folder).resolve()
    except (OSError, RuntimeError):  # RuntimeError: a link loop, which the readers name
        return False
    return p == f or f in p.parents


def _refuse_inside(output: str | Path, inputs: Sequence[str | Path], what: str) -> None:
    """Refuse an output in an input folder: it would change the input (and be read as part of it later)."""
    for folder in inputs:
        if _within(output, folder):
            raise OutputError(output, f"is or lies in the {what} {folder}, an input of this command; "
                                      "write the output outside it")


def _refuse_holding(output: str | Path, inputs: Sequence[str | Path | None]) -> None:
    """Refuse an output folder that holds an input file: replacing the folder would delete the input."""
    for f in inputs:
        if f is not None and str(f) not in DEVICE_BUILTINS and _within(f, output):
            raise OutputError(output, f"holds the input {f}; writing the output there would delete it: "
                                      "choose another folder")


def cmd_info(args: argparse.Namespace) -> int:
    """``reflecto info SOURCE``: kind, parameters and directional albedo (0–80°) of a BRDF file.
    """

    src = load_source(args.source)
    theta = np.array([0.0, 20.0, 40.0, 60.0, 80.0])
    alb = src.albedo(theta)
    # an anisotropic BRDF's albedo changes with the incidence azimuth: its range is over 12 of them
    # (as compare normalizes by), the table at φ_i = 0
    azimuths = 1 if src.isotropic else ALBEDO_AZIMUTHS
    span = alb if azimuths == 1 else np.stack([alb] + [src.albedo(theta, 360.0 * k / azimuths)
                                                       for k in range(1, azimuths)])
    info: dict[str, Any] = {
        "file": str(src.path),
        "kind": src.kind,
        "isotropic": bool(src.isotropic),
        "reciprocal": bool(src.reciprocal),
        "parameters": src.parameters(),
        "albedo": {f"{t:g}deg": [round(float(v), 5) for v in a] for t, a in zip(theta, alb)},
        "albedo_range": [round(float(span.min()), 5), round(float(span.max()), 5)],
        "albedo_range_azimuths": azimuths,
    }
    lines = [shown_path(info["file"]),
             f"  kind        {info['kind']}  (isotropic: {info['isotropic']}, reciprocal: {info['reciprocal']})"]
    # a file's own text (an RGL description) with its newlines and terminal escapes written as escapes
    lines += [f"  {shown_path(k):<11} {shown_path(str(v))}" for k, v in info["parameters"].items()]
    meta = getattr(src, "metadata", None) or {}
    if "normal_tilt_deg" in meta:  # a reconstruction: the sample normal it used (§5.4)
        unc = meta.get("normal_uncertainty_deg")
        info["normal"] = {k: meta.get(k) for k in workflow.NORMAL_KEYS}
        detail = f"±{unc:.2f}°, " if isinstance(unc, (int, float)) and unc > 0 else ""
        if meta.get("normal_source") == UNPLACED:
            lines.append("  normal      not placed: a preview, read in the device frame (the full model places it)")
        else:
            lines.append(f"  normal      tilted {meta['normal_tilt_deg']:.2f}° from the device axis "
                         f"({detail}{shown_path(str(meta.get('normal_source')))})")
        if meta.get("preview") is True:
            lines.append("  preview     a first model (reflecto watch); reflecto reconstruct makes the full one")
    lines.append("  directional albedo (RGB) at θ_i" + ("" if azimuths == 1 else ", φ_i = 0") + ":")
    lines += [f"    {k:>6}  {v[0]:.4f} {v[1]:.4f} {v[2]:.4f}" for k, v in info["albedo"].items()]
    lines.append(f"  albedo range [{info['albedo_range'][0]:.4f}, {info['albedo_range'][1]:.4f}]"
                 + ("" if azimuths == 1 else f" over θ_i 0–80° and {azimuths} incidence azimuths"))
    return _emit(args, info, lines)


def cmd_tabulate(args: argparse.Namespace) -> int:
    """``reflecto tabulate SOURCE -o F.binary``: a MERL table of any source, evaluated at the bin centres.
    """

    out = Path(args.output)
    _check_suffix(out, "merl", f"use -o {out.with_suffix('.binary')}")
    check_output(out)
    if _same_file(out, args.source):
        raise OutputError(out, "is the file being tabulated; tabulate writes a new file: name another")
    src = load_source(args.source)
    if not holds_isotropic(src):  # as `export`: a MERL table of an anisotropic source is its φ_h = 0 slice only
        raise ReflectoError(f"{shown_path(args.source)} is anisotropic; a MERL table holds an isotropic BRDF: "
                            f"reflecto export {shown_path(args.source)} -o {shown_path(out)} --isotropic yes writes "
                            "its φ_h = 0 slice, or write an RGL .bsdf")
    _write_merl(args, src, out, allow_anisotropic=False)
    size = out.stat().st_size
    return _emit(args, {"source": str(args.source), "output": str(out), "format": "merl", "bytes": size},
                 [f"wrote {out} ({size} bytes, MERL 90x90x180, bin centres)"])


def cmd_layout(args: argparse.Namespace) -> int:
    """``reflecto layout``: coverage of a device's LED layout (§4.1, Fig. 2), optionally re-optimised and plotted.
    """

    dev = load_device(args.device)
    leds = dev.leds
    if args.seed is not None and not args.optimize:
        raise ReflectoError("--seed is the layout optimizer's: give it with --optimize")
    if args.optimize:
        leds = layout.optimize_layout(dev.optics, n_leds=dev.n_leds, theta_max_deg=args.theta_max,
                                      seed=args.seed or 0)
    cov = layout.coverage(dev.optics, leds, resolution=args.resolution, theta_max_deg=args.theta_max,
                          occluder_deg=dev.occluder_deg)
    info = {"device": dev.name, "leds_elevation_azimuth_deg": np.round(layout.led_angles(leds), 2).tolist(),
            "coverage": cov.to_dict()}
    if args.plot:

        plot_coverage(dev.optics, leds, args.plot, resolution=max(args.resolution, 128), theta_max_deg=args.theta_max,
                      occluder_deg=dev.occluder_deg)
        info["plot"] = str(args.plot)
    if args.json:
        print(json.dumps(_finite_json(info), indent=1, allow_nan=False))
        return 0
    print(f"LED layout of device {dev.name!r} (elevation, azimuth in degrees):")
    for k, (el, az) in enumerate(info["leds_elevation_azimuth_deg"]):
        print(f"  l{k}  {el:6.2f}  {az:7.2f}   covers {100 * cov.per_led[k]:5.1f} %")
    print(f"coverage of the NDF cap θ_h ≤ {args.theta_max:g}° (solid-angle fraction):")
    print(f"  union of slices          {100 * cov.union:6.2f} %")
    print(f"  after symmetry (eq. 3)   {100 * cov.after_tau:6.2f} %   "
          f"(any layout: at most {100 * cov.upper_bound_after_tau:.2f} %)")
    print(f"  after both mirror planes {100 * cov.after_mirrors:6.2f} %")
    print(f"  every slice overlaps another: {cov.every_led_overlaps}")
    if args.plot:
        print(f"wrote {shown_path(args.plot)}")
    return 0


def cmd_simulate(args: argparse.Namespace) -> int:
    """``reflecto simulate SOURCE -o CAP``: write the raw frames and manifest of a virtual capture
    (tilt, rotation, shake, camera noise).
    """

    _refuse_holding(args.output, [args.source, args.device])  # the more telling refusal first
    check_output(args.output, folder=True, marker=MANIFEST)
    parent = Path(os.path.abspath(args.output)).parent
    if kinds.identify(parent).name == "calibration-folder":  # its white/ is a capture too: not a sample's place
        raise OutputError(args.output, f"lies in the calibration folder {shown_path(parent)}; simulate writes a "
                                       "sample capture: name a folder outside it")
    src = load_source(args.source)
    dev = load_device(args.device)
    cap = simulate_capture(src, dev, tilt_deg=args.tilt, tilt_azimuth_deg=args.tilt_azimuth,
                           rotation_deg=args.rotation, shake=args.shake, seed=args.seed,
                           source_name=str(args.source))
    write_capture(cap, args.output)
    info = {"source": str(args.source), "output": str(args.output), "device": dev.name, "leds": int(cap.raw.shape[0]),
            "exposures_ms": [float(t) for t in cap.exposures_ms],
            "check_frames": 0 if cap.check is None else int(cap.check.shape[0] * cap.check.shape[1]),
            "simulation": cap.extra.get("simulation", {})}
    return _emit(args, info, [f"wrote {args.output}: {cap.raw.shape[0]} LEDs × {cap.raw.shape[1]} exposures, "
                              f"device {dev.name}"])


def cmd_simulate_calibration(args: argparse.Namespace) -> int:
    """``reflecto simulate-calibration -o DIR``: virtual calibration captures (white standard,
    pinhole grid, mirror) of a device.
    """

    _refuse_holding(args.output, [args.device])  # the more telling refusal first
    check_output(args.output, folder=True, marker=CALIBRATION_MANIFEST)
    dev = load_device(args.device)
    out = simulate_calibration(dev, args.output, seed=args.seed)
    files = sorted(str(p.relative_to(out)) for p in Path(out).rglob("*") if p.is_file())
    return _emit(args, {"device": dev.name, "output": str(args.output), "seed": args.seed, "files": files},
                 [f"wrote calibration captures of device {dev.name} to {args.output}"])


def cmd_calibrate(args: argparse.Namespace) -> int:
    """``reflecto calibrate DIR -o CAL.npz``: geometric, LED and radiometric calibration from a
    calibration folder.
    """

    check_output(args.output)
    _refuse_inside(args.output, [args.calib_dir], "calibration folder")
    cal = calibrate(args.calib_dir)
    cal.save(args.output)
    r = cal.report
    return _emit(args, {"calibration_folder": str(args.calib_dir), "output": str(args.output),
                        "device": cal.device.name, "report": r},
                 [f"wrote {args.output}: {r['spots_used']} grid spots, "
                  f"reprojection RMS {r['reprojection_rms_px']:.3f} px; "
                  "LEDs moved by [" + ", ".join("not measured" if e is None else f"{e}"
                                                for e in r["led_offset_from_nominal_deg"]) + "]° from nominal"])


def _symmetry_hint(test: SymmetryTest, summary: dict[str, Any], max_tilt: float) -> str | None:
    """The eq. 3 test's advice, or, where the search's bound held the normal (the summary's notes
    say so), that the frame comes first: a normal held short of the sample's breaks eq. 3 as well."""
    notes = summary.get("notes") or []
    if any(isinstance(n, str) and n.startswith((BOUND_NOTE, PEAK_BEYOND_NOTE)) for n in notes):
        return (f"the search's bound --max-tilt {max_tilt:g}° held the normal, and a normal short of the sample's "
                "breaks eq. 3 too: raise --max-tilt (or give the normal) before capturing rotations")
    return test.hint()


def _normal_arg(text: str) -> str | tuple[float, ...]:
    """``--normal``: ``auto``, ``device`` or ``X,Y,Z`` (a unit vector, checked by
    :class:`~reflecto.reconstruct.Options`).
    """
    if text in ("auto", "device", "search"):
        return text
    try:
        v = tuple(float(x) for x in text.split(","))
    except ValueError:
        v = ()
    if len(v) != 3:
        raise argparse.ArgumentTypeError(f"expected auto, device or X,Y,Z, got {text!r}")
    return v


def _checked(convert: Callable[[str], Any], ok: Callable[[Any], bool], expect: str) -> Callable[[str], Any]:
    """An argparse ``type``: the word ``convert``-ed, refused unless ``ok`` (``argument --X: must be EXPECT``)."""

    def parse(text: str) -> Any:
        try:
            value = convert(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be {expect}, got {text!r}") from None
        if not ok(value):
            raise argparse.ArgumentTypeError(f"must be {expect}, got {text}")
        return value

    return parse


#: The checked number options: what numpy, scipy and Mitsuba would refuse with a
#: traceback, or take silently (NaN angles, negative counts), is one line naming the option.
#: Seeds of the simulations: they are written into the manifest, whose reader refuses integers no float holds.
_SEED = _checked(int, lambda v: 0 <= v <= 2**63 - 1, f"an integer in [0, {2**63 - 1}]")
_LAYOUT_SEED = _checked(int, lambda v: 0 <= v <= layout.MAX_SEED, f"an integer in [0, {layout.MAX_SEED}]")
_RENDER_SEED = _checked(int, lambda v: 0 <= v <= RENDER_MAX_SEED, f"an integer in [0, {RENDER_MAX_SEED}] "
                        "(the reference renders use the seed + 1 and + 2)")
#: The gallery renders the reference again with the seed + 3.
_GALLERY_SEED = _checked(int, lambda v: 0 <= v <= RENDER_MAX_SEED - 3, f"an integer in [0, {RENDER_MAX_SEED - 3}]")
_JOBS = _checked(int, lambda v: v >= 0, "0 (one per core) or a positive number of processes")
_SECONDS = _checked(float, lambda v: math.isfinite(v) and v >= 0, "a finite number of seconds >= 0")
_ANGLE = _checked(float, math.isfinite, "a finite angle in degrees")
_CAP_ANGLE = _checked(float, lambda v: 0 < v <= 90, "an angle in (0, 90] degrees")
_MAX_TILT = _checked(float, lambda v: 0 < v < 60, "an angle in (0, 60) degrees")
#: The layout analysis's hemicube: 256 takes about a minute, 512 several on one core.
_LAYOUT_RESOLUTION = _checked(int, lambda v: 8 <= v <= 256 and v % 2 == 0, "an even integer in [8, 256]")


def _options(args: argparse.Namespace) -> Options:
    """The reconstruction settings of ``reconstruct``'s (and ``watch``'s) flags."""
    return Options(normal=args.normal, fixed_eta=args.eta, isotropic=args.isotropic, shadowing=args.shadowing,
                   max_tilt_deg=args.max_tilt)


def _missing(args: argparse.Namespace) -> workflow.Missing:
    """``--nominal`` reads a capture without a calibration by the nominal one; else it is refused."""
    return "nominal" if args.nominal else "refuse"


def _reconstruct_asymmetric(args: argparse.Namespace) -> int:
    """``reconstruct CAP... --asymmetric -o MODEL``: one model from captures at several rotations (§5.5)."""
    caps = list(args.captures)
    if len(caps) < MIN_CAPTURES:
        raise ReflectoError(f"{caps[0]}: --asymmetric reconstructs one model from captures of the same point at "
                            f"{MIN_CAPTURES} or more rotations (paper §5.5); got one capture — reconstruct it "
                            "without --asymmetric")
    if args.shadowing != "auto":  # the §5.5 path's isotropic branch keeps eq. 8's product; the option would be ignored
        raise ReflectoError(f"--shadowing {args.shadowing}: the §5.5 path (--asymmetric) fits eq. 8's product "
                            "shadowing; --shadowing chooses the form of one capture's model (leave it out here)")
    out = Path(args.output)
    _check_suffix(out, "model", f"use -o {out.with_suffix('.reflecto')}")
    if out.suffix.lower() != ".reflecto":
        raise OutputError(out, "with --asymmetric the captures make one model: -o must name a .reflecto file")
    check_output(out)
    _refuse_inside(out, caps, "capture folder")
    res = workflow.rotations_to_model(caps, args.calibration, _options(args), missing=_missing(args))
    note = "nominal (--nominal)" if args.calibration is None and args.nominal else None
    summary = workflow.save_rotations_model(res, out, caps, note)
    info = {"models": [{"captures": caps, "output": str(out), "summary": summary}], "failed": []}
    kind = "isotropic (1-D, all captures)" if res.isotropic else "hemicube, §5.5 merge and synthesis"
    rots = "/".join(f"{r:g}" for r in res.rotations_deg)
    lines = [f"{out}: {kind} from {len(caps)} captures at {rots}°, eta {format_eta(res.eta)}, "
             f"kd {np.round(res.model.kd, 3).tolist()}, ks {np.round(res.model.ks, 3).tolist()}, "
             f"tilt {res.normal_tilt_deg:.2f}°, {res.seconds * 1000:.0f} ms"
             + ("  SHAKE DETECTED" if res.shake_detected else ""),
             f"  {res.symmetry.describe()}" + ("; the §5.5 model above holds it (hemicube NDF, no eq. 3)"
                                               if res.symmetry.decided and not res.symmetry.symmetric
                                               and not res.isotropic else "")]
    lines += [f"  note: {note}" for note in res.notes]
    if args.json:
        print(json.dumps(info, indent=1))
    elif not args.quiet:
        print("\n".join(lines))
    return 0


def _report_failures(failures: list[tuple[str, str]]) -> None:
    for _, msg in failures:
        print(f"reflecto: error: {one_line(msg)}", file=sys.stderr)


def _capture_name(capture: str) -> str:
    """The name of a capture folder's model in an output folder: the folder's own name, also
    where it is given as ``.``, ``..`` or with a trailing slash."""
    name = Path(os.path.abspath(capture)).name  # "." and ".." by the path, a link keeps its own name
    if not name:
        raise OutputError(capture, "has no name to give its model (the file system's root): "
                                   "name the model file with -o FILE.reflecto")
    return name


def cmd_reconstruct(args: argparse.Namespace) -> int:
    """``reflecto reconstruct CAP... -o OUT``: the §5 reconstruction of one capture, or of several
    in parallel worker processes (a model file and its ``.json`` summary each).
    """
    if args.asymmetric:
        return _reconstruct_asymmetric(args)
    caps = list(args.captures)
    if len(caps) > 1 and not Path(args.output).suffix == "":
        raise OutputError(args.output, "with several captures, -o must be a folder")
    folder = not (len(caps) == 1 and Path(args.output).suffix)  # -o names a folder of models
    if not folder:
        kinds.require_output_suffix(args.output, "reconstruct", (".reflecto",), "a model file (.reflecto)")
        check_output(args.output)
        outs = [args.output]
    else:
        outs = [str(Path(args.output) / (_capture_name(c) + ".reflecto")) for c in caps]
        seen: dict[str, str] = {}
        for c, o in zip(caps, outs):
            if o in seen:
                raise OutputError(o, f"captures {seen[o]} and {c} have the same name; "
                                     "their models would overwrite each other")
            seen[o] = c
    for o in outs:  # before any folder is made: nothing goes into a capture
        _refuse_inside(o, caps, "capture folder")
    if args.calibration:  # one line for a bad file, not one per capture
        read_calibration(args.calibration)
    if folder:
        make_parents(Path(args.output))
    options, missing = _options(args), _missing(args)
    jobs = [(c, o, args.calibration, options, missing) for c, o in zip(caps, outs)]
    results: dict[int, dict] = {}
    failures: list[tuple[str, str]] = []
    bar = Progress(len(jobs), "reconstruct", (len(jobs) > 1 or args.progress) and not args.quiet)

    def finished(k: int, ok: bool, value: object, seconds: float) -> None:
        if ok:
            results[k] = value  # type: ignore[assignment]
        else:
            failures.append((caps[k], str(value)))
        bar.update(Path(caps[k]).name, ok, seconds)

    try:
        if len(jobs) == 1:
            # one capture: its error is the command's error (nothing else to finish)
            t0 = time.perf_counter()
            summary = workflow.reconstruct_folder(*jobs[0])
            finished(0, True, summary, time.perf_counter() - t0)
        else:
            run_batch(workflow.reconstruct_folder, jobs, caps, args.jobs or os.cpu_count() or 1, finished)
    finally:
        bar.close()
    models = [{"capture": caps[k], "output": outs[k], "summary": results[k]} for k in sorted(results)]
    info = {"models": models, "failed": [{"capture": c, "error": m} for c, m in failures]}
    lines = []
    for k, r in sorted(results.items()):
        flag = f"  SHAKE DETECTED ({r['motion']})" if r["shake_detected"] else ""
        kind = "isotropic" if r["isotropic"] else "anisotropic"
        lines.append(f"{outs[k]}: {kind}, eta {format_eta(eta_from_json(r))}, kd {np.round(r['kd'], 3).tolist()}, "
                     f"ks {np.round(r['ks'], 3).tolist()}, tilt {_tilt_text(r)}, "
                     f"{r['seconds'] * 1000:.0f} ms{flag}")
        lines += [f"  note: {note}" for note in r["notes"]]
        sym = r.get("symmetry_test", {})
        if sym.get("decided") and not sym.get("symmetric"):
            test = SymmetryTest(*(sym[k] for k in ("asymmetry", "tau_rms", "direct_rms", "tau_pairs", "direct_pairs")))
            lines += [f"  {test.describe()}", f"  hint: {_symmetry_hint(test, r, args.max_tilt)}"]
    if args.json:
        print(json.dumps(info, indent=1))
    elif lines:
        print("\n".join(lines))
    if failures:
        _report_failures(failures)
        return 1
    return 0


def cmd_watch(args: argparse.Namespace) -> int:
    """``reflecto watch ROOT -o MODELS``: reconstruct each capture folder as it lands in ROOT
    (:mod:`reflecto.watch`); with ``--once``, what is there, then exit (1 if any was skipped)."""
    if not Path(args.root).is_dir():
        raise ReflectoError(f"{shown_path(args.root)}: no such folder to watch")
    if kinds.identify(args.root).name == "capture":
        raise ReflectoError(f"{shown_path(args.root)}: is a capture folder; watch the folder the captures land in "
                            f"(here {shown_path(Path(args.root).resolve().parent)})")
    check_output(args.output, folder=True)
    # the watcher would take its own output folder (or a capture's) for a capture landing in ROOT
    _refuse_inside(args.output, [args.root], "watched folder")
    if args.calibration:  # one line for a bad file, before the output folder is made
        read_calibration(args.calibration)
    options = _options(args)
    recon = default_reconstructor(args.calibration, options, _missing(args))
    # a preview is an isotropic light fit: not for a material declared anisotropic
    previews = not args.no_preview and options.isotropic != "no"
    watcher = Watcher(args.root, args.output, recon, settle_s=args.settle,
                      announce=None if args.quiet and not args.json else _watch_announcer(args),
                      preview_one=default_previewer(args.calibration, options, _missing(args)) if previews else None,
                      jobs=args.jobs or os.cpu_count() or 1)
    watcher.run(once=args.once)
    return 1 if args.once and watcher.failed else 0


def _tilt_text(summary: dict[str, Any]) -> str:
    """The tilt found and its uncertainty, as a summary gives them (``"2.00° ± 0.21°"``)."""
    tilt, unc = summary.get("normal_tilt_deg"), summary.get("normal_uncertainty_deg")
    if summary.get("normal_source") == UNPLACED:
        return "not placed yet"
    if not isinstance(tilt, (int, float)):
        return "?"
    return f"{tilt:.2f}°" + (f" ± {unc:.2f}°" if isinstance(unc, (int, float)) and unc > 0 else "")


def _watch_announcer(args: argparse.Namespace) -> Callable[[Entry, dict[str, Any], float], None]:
    """One line per model written (a capture's preview, then its full model) on stdout: a JSON
    object with ``--json`` (JSON Lines), else name, preview or full, tilt, η, the model's
    misfit, latency and warnings."""
    def announce(entry: Entry, summary: dict[str, Any], latency_s: float) -> None:
        if args.json:
            keys = ("normal_tilt_deg", "normal_uncertainty_deg", "normal_source", "eta", "model_error")
            print(json.dumps({"capture": entry.name, "model": str(Path(args.output) / f"{entry.name}.reflecto"),
                              "preview": entry.preview, **{k: summary.get(k) for k in keys}, "warnings": entry.warnings,
                              "notes": entry.notes,
                              "latency_s": round(latency_s, 3)}), flush=True)
            return
        shown = _tilt_text(summary)
        warn = f", {len(entry.warnings)} warning(s)" if entry.warnings else ""
        kind = "preview" if entry.preview else "full"
        eps = summary.get("model_error", float("nan"))
        print(f"{shown_path(entry.name)} ({kind}): tilt {shown}, η {entry.eta}, ε {eps:.4f}, "
              f"{1000 * latency_s:.0f} ms{warn}", flush=True)
    return announce


def _export_format(args: argparse.Namespace) -> str:
    """``--format``, or the one the ``-o`` suffix names; the two must agree."""
    kinds.require_file_name(args.output, "export", "an RGL .bsdf or a MERL .binary file",
                            ".binary" if args.format == "merl" else ".bsdf")
    suffix = Path(args.output).suffix.lower()
    by_suffix = {".bsdf": "rgl", ".binary": "merl"}.get(suffix)
    if args.format is None and by_suffix is None:
        kinds.require_output_suffix(args.output, "export", (".bsdf", ".binary"),
                                    "an RGL .bsdf or a MERL .binary file (or name one with --format rgl|merl)")
    fmt = args.format or by_suffix or "rgl"
    if suffix in kinds._SUFFIX and kinds._SUFFIX[suffix] not in (None, fmt):
        raise kinds.KindError(args.output, f"a {suffix} file name", f"export --format {fmt}",
                              f"{kinds.KINDS[fmt]}",
                              f"use -o {Path(args.output).with_suffix('.bsdf' if fmt == 'rgl' else '.binary')}",
                              verb="writes")
    right = {"rgl": ".bsdf", "merl": ".binary"}[fmt]
    _check_suffix(args.output, fmt, f"use -o {Path(args.output).with_suffix(right)}, or --format "
                  f"{by_suffix or ('merl' if fmt == 'rgl' else 'rgl')}")
    return fmt


def cmd_export(args: argparse.Namespace) -> int:
    """``reflecto export MODEL -o F.bsdf|F.binary``: an RGL tensor file or a MERL table (the suffix
    or ``--format`` chooses).
    """

    out = Path(args.output)
    fmt = _export_format(args)
    check_output(out)
    if _same_file(out, args.source):
        raise OutputError(out, "is the file being exported; export writes a new file: name another")
    src = load_source(args.source)
    if fmt == "rgl":

        iso = {"auto": None, "yes": True, "no": False}[args.isotropic]
        export_rgl(src, out, isotropic=iso)
    else:
        allow = args.isotropic == "yes"
        if not allow and not holds_isotropic(src):
            rgl = out.with_suffix(".bsdf")
            if _same_file(rgl, args.source):  # the hint must not name the input
                rgl = out.with_name(f"{out.stem}-anisotropic.bsdf")
            raise ReflectoError(f"{args.source} is anisotropic; a MERL table holds an isotropic BRDF: add "
                                f"--isotropic yes to write its φ_h = 0 slice, or write -o {rgl} "
                                "(RGL, anisotropic)")
        _write_merl(args, src, out, allow_anisotropic=allow)
    size = out.stat().st_size
    return _emit(args, {"source": str(args.source), "output": str(out), "format": fmt, "bytes": size},
                 [f"wrote {out} ({size} bytes, {fmt})"])


def _write_merl(args: argparse.Namespace, src, out: Path, allow_anisotropic: bool) -> None:
    """:func:`export_merl` of ``src`` (the file ``args.source``) to ``out``, with a progress bar;
    a table that is no BRDF (negative or not finite on the grid) is refused naming the file."""
    try:
        shown = not args.quiet and not args.json and _interactive()
        with _progress(merl_bins(), f"tabulating {src.name}", shown) as bar:
            export_merl(src, out, allow_anisotropic=allow_anisotropic, progress=bar.update)
    except ParameterError as e:
        raise ReflectoError(f"{shown_path(args.source)}: {str(e).removeprefix(f'{src.name}: ')}") from None


def _same_file(a: str | Path, b: str | Path) -> bool:
    """Whether ``a`` and ``b`` are one existing file (links followed)."""
    try:
        return os.path.samefile(a, b)
    except (OSError, ValueError):
        return False


def merl_bins() -> int:
    """Number of bins of a MERL table (90 × 90 × 180), the length of a tabulation's progress bar."""

    return merl.N_BINS


def cmd_render(args: argparse.Namespace) -> int:
    """``reflecto render SOURCE -o IMG``: a Mitsuba 3 render; with ``--compare``, the mean image
    difference against a reference and its noise floor (docs/mitsuba.md).
    """

    out = Path(args.output)
    if args.envmap and not args.scene.endswith("-env"):
        raise ReflectoError(f"--envmap lights the *-env scenes; {args.scene} is lit by its point lights: drop "
                            "--envmap or choose sphere-env or teapot-env")
    if args.envmap:  # before the BRDF's export, which can take seconds
        check_envmap(args.envmap)
    if args.envmap and _same_file(out, args.envmap):
        raise ReflectoError(f"{shown_path(out)}: is the environment map being rendered with; write the render "
                            "elsewhere")
    if out.suffix.lower() in (".exr", ".hdr") and not utf8_name(out):
        raise ReflectoError(f"{shown_path(out)}: the name is not valid UTF-8, which the {out.suffix.lower()} writer "
                            "cannot take: rename it (or write a .png)")
    if args.title and any(unicodedata.category(ch) == "Cc" for ch in args.title):  # Matplotlib warns on them
        raise ReflectoError(f"render --title: {args.title!r} holds control characters; a title is drawn as text")
    if args.title and out.suffix.lower() != ".png":  # before the render: a title is drawn on 8-bit pixels
        raise ReflectoError(f"{shown_path(out)}: --title is drawn on a .png image; a .exr or .hdr keeps its "
                            "linear values untouched: drop --title or write a .png")
    src = load_source(args.source)
    if not args.compare:
        r = render(src, args.scene, envmap=args.envmap, resolution=args.resolution, spp=args.spp, seed=args.seed)
        # a linear EXR keeps the object's alpha; PNG and HDR get the grey background
        if args.title and out.suffix.lower() == ".png":
            with atomic_path(out, suffix=".png") as tmp:
                iio.imwrite(tmp, titled(to_srgb8(r.image()), args.title))
        else:
            save_image(np.dstack([r.radiance, r.alpha]) if out.suffix.lower() == ".exr" else r.image(), out)
        return _emit(args, {"source": str(args.source), "scene": args.scene, "resolution": args.resolution,
                            "spp": r.spp, "variant": r.variant, "seconds": r.seconds, "output": str(out)},
                     [f"rendered {src.name} ({args.scene}, {args.resolution}², {r.spp} spp, {r.variant}) in "
                      f"{r.seconds:.1f} s; wrote {out}"])
    if out.suffix.lower() != ".png":
        raise ReflectoError(f"{out}: a comparison image must be .png")
    ref = load_source(args.compare)
    c = compare(ref, src, args.scene, envmap=args.envmap, resolution=args.resolution, spp=args.spp, seed=args.seed)


    image = comparison_image(c.reference.radiance, c.test.radiance, (f"reference\n{ref.name}", f"test\n{src.name}"),
                             alpha=c.reference.alpha, alpha_test=c.test.alpha, difference=c.difference)
    with atomic_path(out, suffix=".png") as tmp:
        iio.imwrite(tmp, titled(image, args.title) if args.title else image)
    seconds = c.test.seconds + c.reference.seconds + c.reference_repeat.seconds
    lines = [f"rendered {src.name} and {ref.name} twice ({args.scene}, {args.resolution}², {c.test.spp} spp, "
             f"{c.test.variant}) in {seconds:.1f} s; {c.summary()}; wrote {out} (reference | {src.name} | difference)"]
    if c.within_noise:
        lines.append("note: the difference is within the noise floor: at this spp the two renders look alike")
    elif not c.resolved:
        lines.append(f"note: the noise floor is more than a third of the difference; about --spp {c.spp_to_resolve()} "
                     "would bring it there")
    return _emit(args, {"source": str(args.source), "reference": str(args.compare), "scene": args.scene,
                        "resolution": args.resolution, "spp": c.test.spp, "variant": c.test.variant, "seconds": seconds,
                        "difference": c.difference, "noise_floor": c.noise_floor, "corrected": c.corrected,
                        "output": str(out)}, lines)


def cmd_compare(args: argparse.Namespace) -> int:
    """``reflecto compare REF TEST``: eq. 10 error (normalized by the reference's albedo) and
    log-RMSE of TEST against REF (over every φ_h when either source is anisotropic).
    """

    ref, test = load_source(args.reference), load_source(args.test)
    err = comparison_error(ref, test)
    return _emit(args, {"reference": str(args.reference), "test": str(args.test), **err.to_dict()}, [
        f"{args.test} against {args.reference} ({err.describe()}):",
        f"  RMSE (R, G, B)      {err.rmse[0]:.5f} {err.rmse[1]:.5f} {err.rmse[2]:.5f} sr⁻¹",
        f"  normalized error    {100 * err.normalized:.3f} %  (RMSE averaged over R, G, B, divided by the reference's "
        f"largest channel-mean directional albedo over θ_i ≤ 80°, {err.albedo_ref:.4f})",
        f"  log-RMSE            {err.log_rmse:.5f}"])


def cmd_report(args: argparse.Namespace) -> int:
    """``reflecto report MODEL -o DIR``: the HTML report of a model (renders, NDF, slices, numbers).
    """

    summary = Path(args.model).with_suffix(".json")
    if summary.exists() or summary.is_symlink():
        # the report reads the reconstruction summary beside the model: refuse a bad one here
        if not isinstance(read_json(summary), dict):

            raise FileFormatError(summary, "a reconstruction summary must be a JSON object")
    page = write_report(args.model, args.output, reference=args.ref, spp=args.spp, render=not args.no_render)
    return _emit(args, {"model": str(args.model), "output": str(page), "folder": str(args.output)}, [f"wrote {page}"])


def cmd_fit_ct(args: argparse.Namespace) -> int:
    """``reflecto fit-ct SOURCE``: the dense Cook–Torrance baseline fit (algorithm reference
    §6.3) and its eq. 10 error.
    """

    src = load_source(args.source)
    ct = fit_cook_torrance(src)
    err = comparison_error(src, ct)  # as `compare`: every half-vector azimuth where the source is anisotropic
    info = {"source": str(args.source), **ct.parameters(), "error_normalized": err.normalized, "log_rmse": err.log_rmse,
            "error_form": err.describe()}
    return _emit(args, info, [
        f"Cook–Torrance fit of {args.source} (Beckmann D, V-groove G, Schlick F; eq. 10 weights):",
        f"  rho_d  {np.round(ct.rho_d, 5).tolist()}",
        f"  rho_s  {np.round(ct.rho_s, 5).tolist()}",
        f"  F0     {ct.f0:.4f}    m  {ct.m:.5f}",
        f"  normalized error  {100 * err.normalized:.3f} % ({err.describe()}), log-RMSE {err.log_rmse:.5f}"])


def cmd_sweep(args: argparse.Namespace) -> int:
    """``reflecto sweep DIR... -o RESULTS``: the §6 validation over materials, resumable, in parallel.
    """

    failures: list[tuple[str, str]] = []
    try:
        recs = sweep(args.folders, args.output, device=args.device, jobs=args.jobs, progress=not args.quiet,
                     scheduler=args.scheduler)
    except BatchError as e:
        recs, failures = getattr(e, "records", []), e.failures
    s = summarize(recs)
    a = s["all"]
    out = Path(args.output)
    files = [str(out / f) for f in ("results.csv", "fig5_errors.png", "fig4_spheres.png", "failures.json")
             if (out / f).is_file()]
    info = {**s, "output": str(out), "files": files, "failed": [{"file": f, "error": m} for f, m in failures]}
    if args.json:
        print(json.dumps(info, indent=1))
    elif not args.quiet:
        lines = [f"{a['materials']} materials in {out}" + (f", {len(failures)} failed" if failures else "")]
        n = a["materials"]
        if n:
            lines += [f"  ours < Cook–Torrance            {a['ours_better_than_ct']}/{n}",
                      f"  ours < same-data Cook–Torrance  {a['ours_better_than_same_data_ct']}/{n}",
                      f"  ours < earlier device           {a['ours_better_than_earlier']}/{n}",
                      f"  median ours / CT                {a['median_ratio_ours_over_ct']:.3g}",
                      "  median error                    ours {ours:.4g} · CT {cook_torrance:.4g} · same-data CT "
                      "{same_data_ct:.4g} · earlier {earlier:.4g}".format(**a["median_error"]),
                      f"  all finite: {a['all_finite']}, max albedo {a['max_albedo']:.4g}"]
        lines.append("wrote " + ", ".join(files))
        print("\n".join(lines))
    if failures:
        _report_failures(failures)
        return 1
    return 0


def cmd_design(args: argparse.Namespace) -> int:
    """``reflecto design DIR... -o OUT``: the condenser design study (:func:`reflecto.evaluate.design.design_study`);
    returns exit status 0, 1 when a material failed."""

    failures: list[tuple[str, str]] = []
    for flag, values, lo, hi in (("--cones", args.cones, 1.0, 88.0), ("--tilts", args.tilts, 0.0, 59.0),
                                 ("--leds", args.leds, 3, 32)):
        if not values or any(not lo <= v <= hi for v in values):
            raise ReflectoError(f"{flag}: each value must be in [{lo:g}, {hi:g}], got {values}")
        if any(abs(v - design_value(v)) > 1e-9 for v in values):  # a design's key holds 0.1°
            raise ReflectoError(f"{flag}: values to {DESIGN_DECIMALS} decimal(s), got {values}")
        if len({design_value(v) for v in values}) != len(values):  # one design twice: one record, two rows
            raise ReflectoError(f"{flag}: each value once, got {values}")
    _refuse_inside(args.output, [f for f in args.folders if Path(f).is_dir()], "materials folder")
    _refuse_holding(args.output, list(args.folders))
    if not args.layout_only and not find_materials(list(args.folders)):  # known before any design is laid out
        raise ReflectoError(f"no material files in {', '.join(map(shown_path, args.folders))} (or pass --layout-only)")
    try:
        rows = design_study(args.folders, args.output, cones=args.cones, tilts=args.tilts, led_counts=args.leds,
                            jobs=args.jobs, scheduler=args.scheduler, progress=not args.quiet,
                            materials=not args.layout_only)
    except BatchError as e:
        rows, failures = getattr(e, "records", []), e.failures
    out = Path(args.output)
    best = best_design(rows)
    info: dict[str, Any] = {"output": str(out), "files": [str(out / "design.csv"), str(out / "design.png")],
                            "designs": rows, "best_realisable": best["key"] if best else None,
                            "failed": [{"item": f, "error": m} for f, m in failures]}
    if args.json:
        print(json.dumps(info, indent=1))
    elif not args.quiet:
        lines = [f"{'design':18s} {'NA':>5s} {'cover':>6s} {'reach':>6s} {'time':>6s} {'< CT':>8s} {'ratio':>6s}"]
        for r in rows:
            if "coverage_after_tau" not in r:
                lines.append(f"{r['key']:18s} not possible: {r.get('limit', '')}")
                continue
            fid = (f"{r['ours_below_ct']:>3d}/{r['materials']:<4d} {r['median_ratio']:6.3f}" if r.get("materials")
                   else "")
            lines.append(f"{r['key']:18s} {r['na']:5.3f} {100 * r['coverage_after_tau']:5.1f}% "
                         f"{r['theta_d_reach_deg']:5.1f}° {1000 * r['capture_s']:4.0f}ms {fid}"
                         + ("" if r["realisable"] else f"  (not realisable: {r['limit']})"))
        if best:
            lines.append(f"best realisable design: {best['key']}")
        lines.append("wrote " + ", ".join(info["files"]))
        print("\n".join(lines))
    if failures:
        _report_failures(failures)
        return 1
    return 0


class _HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows "(default: …)" after every option's help that has a default worth stating."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        d = action.default
        if ("%(default)" in text or d is None or d is argparse.SUPPRESS or isinstance(d, bool)
                or not action.option_strings):
            return text
        if isinstance(d, list):
            return text + " (default: " + " ".join(map(str, d)).replace("%", "%%") + ")"
        return text + " (default: %(default)s)"


class _Parser(argparse.ArgumentParser):
    """The parser of reflecto and of each subcommand: defaults shown in ``--help``, errors in one line."""

    def __init__(self, *args, **kwargs) -> None:
        kwargs.setdefault("formatter_class", _HelpFormatter)
        super().__init__(*args, **kwargs)

    def error(self, message: str) -> NoReturn:
        """A command-line mistake is an error like any other: one line, exit status 1 (argparse's
        own is the usage text and status 2); ``--help`` still shows the usage."""
        self.exit(1, f"reflecto: error: {one_line(message)} (see {self.prog} --help)\n")


_JSON_HELP = "print one JSON document on stdout instead of text"
_DEVICE_HELP = ("the device: ideal (the paper's design, nominal optics, noiseless camera), as-built (the same "
                "design with seeded LED, optics and vignetting errors and camera noise: needs a calibration), "
                "earlier (the [DWT*10] baseline: condenser on the normal, sparse LEDs), wide (the design study's "
                "60° cone about a 20° axis, ten LEDs, ideal optics), wide-as-built (wide with as-built errors), "
                "or a device file (.json/.toml, docs/instrument.md)")
_LIST_HELP = "; values separated by spaces (commas also accepted)"
_SCHEDULER_HELP = ("run the work on the Dask cluster of this scheduler (tcp://host:8786; needs reflecto[dask]) "
                   "instead of local processes; the output folder must be a path every worker sees")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``reflecto`` and its subcommands (``--help`` shows defaults).

    Returns
    -------
    argparse.ArgumentParser
        The parser; each subcommand's namespace carries its handler as ``func``.
    """
    p = _Parser(
        prog="reflecto",
        description="Condenser-based instant reflectometry (Lan et al. 2010): BRDF model, sources and tools.",
    )
    p.add_argument("--version", action="version", version=f"reflecto {__version__}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    q = sub.add_parser("info", help="kind, parameters and albedo range of a BRDF file")
    q.add_argument("source", help="BRDF file: .binary, .bsdf, .h5, .json/.toml, .reflecto")
    q.add_argument("--json", action="store_true", help=_JSON_HELP)
    q.set_defaults(func=cmd_info)

    q = sub.add_parser("tabulate", help="write a MERL-format table of any BRDF source")
    q.add_argument("source", help="BRDF file")
    q.add_argument("-o", "--output", required=True, help="output .binary file")
    q.add_argument("-q", "--quiet", action="store_true", help="no progress or summary")
    q.add_argument("--json", action="store_true", help=_JSON_HELP)
    q.set_defaults(func=cmd_tabulate)

    q = sub.add_parser("layout", help="coverage of a device's LED layout (paper §4.1); optionally re-optimise it")
    q.add_argument("--device", default="ideal", help=_DEVICE_HELP)
    q.add_argument("--optimize", action="store_true",
                   help="run the layout optimizer instead of using the device's LEDs")
    q.add_argument("--seed", type=_LAYOUT_SEED, default=None, help="random seed of the layout optimizer (default 0)")
    q.add_argument("--resolution", type=_LAYOUT_RESOLUTION, default=64, help="hemicube resolution of the analysis: "
                   "cells along each edge of a hemicube face, even, 8 to 256 (the NDF's texels; the plot uses at "
                   "least 128)")
    q.add_argument("--theta-max", type=_CAP_ANGLE, default=80.0, help="NDF cap θ_h ≤ this (degrees)")
    q.add_argument("--plot", help="write the Fig. 2(c)(d) analogue to this PNG (default: no plot)")
    q.add_argument("--json", action="store_true", help=_JSON_HELP)
    q.set_defaults(func=cmd_layout)

    q = sub.add_parser("simulate", help="raw frames of a virtual capture of a BRDF source")
    q.add_argument("source", help="BRDF file")
    q.add_argument("--device", default="ideal", help=_DEVICE_HELP)
    q.add_argument("--tilt", type=float, default=0.0, help="hand tilt of the sample normal, degrees (≤ 30)")
    q.add_argument("--tilt-azimuth", type=_ANGLE, default=None,
                   help="azimuth of the tilt, degrees (default: from the seed)")
    q.add_argument("--rotation", type=_ANGLE, default=0.0, help="rotation of the sample about its normal, degrees")
    q.add_argument("--shake", action="store_true", help="move the sample between two LEDs' frames")
    q.add_argument("--seed", type=_SEED, default=0, help="random seed of the camera noise, tilt azimuth and shake")
    q.add_argument("-o", "--output", required=True, help="capture folder to write")
    q.add_argument("-q", "--quiet", action="store_true", help="no summary line")
    q.add_argument("--json", action="store_true", help=_JSON_HELP)
    q.set_defaults(func=cmd_simulate)

    q = sub.add_parser("simulate-calibration", help="virtual calibration captures (white target, pinhole grid, mirror)")
    q.add_argument("--device", default="as-built", help=_DEVICE_HELP)
    q.add_argument("--seed", type=_SEED, default=0, help="random seed of the camera noise")
    q.add_argument("-o", "--output", required=True, help="calibration folder to write")
    q.add_argument("-q", "--quiet", action="store_true", help="no summary line")
    q.add_argument("--json", action="store_true", help=_JSON_HELP)
    q.set_defaults(func=cmd_simulate_calibration)

    q = sub.add_parser("calibrate", help="geometric, LED and radiometric calibration from calibration captures")
    q.add_argument("calib_dir", help="calibration folder")
    q.add_argument("-o", "--output", required=True, help="calibration file to write (.npz)")
    q.add_argument("-q", "--quiet", action="store_true", help="no summary line")
    q.add_argument("--json", action="store_true", help=_JSON_HELP)
    q.set_defaults(func=cmd_calibrate)

    q = sub.add_parser("reconstruct", help="captures → microfacet BRDF model files (paper §5)")
    q.add_argument("captures", nargs="+", help="capture folder(s)")
    how = q.add_mutually_exclusive_group()
    how.add_argument("--calibration", help="calibration file from `reflecto calibrate`; needed for captures of any "
                     "device but the built-in ideal and earlier ones "
                     "(default: those two use their nominal calibration)")
    how.add_argument("--nominal", action="store_true",
                     help="use the device's nominal calibration even where it needs a measured one")
    q.add_argument("-o", "--output", required=True, help="model file (.reflecto) or, for several captures, a folder")
    q.add_argument("--normal", type=_normal_arg, default="auto", metavar="auto|device|search|X,Y,Z",
                   help="the sample normal (§5.4): estimated from the capture (auto, default), the device axis "
                        "(device), or a known unit vector in device coordinates; with --asymmetric, auto takes the "
                        "device axis unless the captures disagree in it (a tilted set), then the set's own normal "
                        "search (seconds per set), which search always runs")
    q.add_argument("--eta", type=float, help="use this η instead of fitting it (default: fitted, eqs. 5–6)")
    q.add_argument("--max-tilt", type=_MAX_TILT, default=16.0, metavar="DEG",
                   help="largest tilt of the sample normal the estimate searches, degrees (above 0, below 60)")
    q.add_argument("--isotropic", choices=("auto", "yes", "no"), default="auto",
                   help="reconstruct a 1-D isotropic NDF (yes), a hemicube NDF for an anisotropic material (no), "
                        "or decide from the capture (auto)")
    q.add_argument("--shadowing", choices=("auto", "separable", "correlated"), default="auto",
                   help="the isotropic model's shadowing form beyond the angles the device sees: eq. 8's product "
                        "(separable), height-correlated Smith (correlated), or the one that fits the capture better "
                        "(auto)")
    q.add_argument("--asymmetric", action="store_true",
                   help="the captures are of one point at several rotations (their manifests' rotation_deg): "
                        "reconstruct one model without the symmetry of eq. 3, completed by microfacet synthesis "
                        "(paper §5.5); -o names the model file")
    q.add_argument("--jobs", type=_JOBS, default=0, help="worker processes for several captures (0: all cores)")
    q.add_argument("--progress", action="store_true",
                   help="show progress also for one capture (several captures show it unless -q): "
                        "a bar on a terminal, plain lines on stderr otherwise or under CI=true")
    q.add_argument("-q", "--quiet", action="store_true", help="no progress")
    q.add_argument("--json", action="store_true", help=_JSON_HELP)
    q.set_defaults(func=cmd_reconstruct)

    q = sub.add_parser("watch", help="reconstruct each capture folder as it lands in ROOT; keep MODELS/index.html")
    q.add_argument("root", help="folder the capture folders land in")
    q.add_argument("-o", "--output", required=True, help="folder of the models, their summaries and index.html")
    how = q.add_mutually_exclusive_group()
    how.add_argument("--calibration", help="calibration file from `reflecto calibrate` (as for reconstruct)")
    how.add_argument("--nominal", action="store_true", help="use the device's nominal calibration (as for reconstruct)")
    q.add_argument("--normal", type=_normal_arg, default="auto", metavar="auto|device|X,Y,Z",
                   help="the sample normal (§5.4), as for reconstruct: estimated from each capture (auto), the "
                        "device axis (device), or a known unit vector")
    q.add_argument("--eta", type=float, help="use this η instead of fitting it")
    q.add_argument("--max-tilt", type=_MAX_TILT, default=16.0, metavar="DEG", help="as for reconstruct")
    q.add_argument("--isotropic", choices=("auto", "yes", "no"), default="auto", help="as for reconstruct")
    q.add_argument("--shadowing", choices=("auto", "separable", "correlated"), default="auto",
                   help="as for reconstruct")
    q.add_argument("--settle", type=_SECONDS, default=5.0,
                   help="seconds an incomplete capture folder may stay unchanged before it is reported and skipped")
    q.add_argument("--once", action="store_true", help="process the capture folders there now and exit")
    q.add_argument("--no-preview", action="store_true",
                   help="make each capture's full model at once instead of a preview first (the full models then "
                        "fall behind a sweep at the device's rate)")
    q.add_argument("--jobs", type=_JOBS, default=1,
                   help="worker processes that replace the previews by full models, several at once, when the "
                        "sweep pauses (default 1: one at a time in the watcher; 0: one per core)")
    q.add_argument("-q", "--quiet", action="store_true",
                   help="no line per modelled capture (problems are still reported)")
    q.add_argument("--json", action="store_true", help="one JSON object per modelled capture (JSON Lines) on stdout")
    q.set_defaults(func=cmd_watch)

    q = sub.add_parser("export",
                       help="write a BRDF as an RGL .bsdf (RGB, Mitsuba 3's measured plugin) or MERL .binary file",
                       description="Write a BRDF as an RGL .bsdf tensor file in the RGB variant that Mitsuba 3's "
                                   "`measured` plugin reads (see docs/mitsuba.md), or as a MERL .binary table.")
    q.add_argument("source", help="model (.reflecto) or any BRDF file")
    q.add_argument("--format", choices=("rgl", "merl"),
                   help="file format (default: from the -o suffix, .bsdf or .binary; rgl for other suffixes); "
                        "must agree with the suffix")
    q.add_argument("--isotropic", choices=("auto", "yes", "no"), default="auto",
                   help="write an isotropic file (RGL: one φ_i; MERL: the φ_h = 0 slice of an anisotropic "
                        "source) or an anisotropic RGL file (auto: as the source says it is, or isotropic if "
                        "its NDF is within 2 %% of its mean around every ring)")
    q.add_argument("-o", "--output", required=True, help="output file")
    q.add_argument("-q", "--quiet", action="store_true", help="no progress or summary")
    q.add_argument("--json", action="store_true", help=_JSON_HELP)
    q.set_defaults(func=cmd_export)


    q = sub.add_parser("render", help="render a BRDF with Mitsuba 3 (sphere or teapot, point lights or envmap)",
                       description="Render a BRDF with Mitsuba 3. With --compare, render the source once and the "
                                   "reference twice (three seeds) and print the mean image difference over the "
                                   "object's pixels, the same number between the two reference renders (the noise "
                                   "floor) and the difference corrected for it; see docs/mitsuba.md.")
    q.add_argument("source", help="model (.reflecto) or any BRDF file")
    q.add_argument("--scene", choices=SCENES, default="sphere-env", help="scene to render (docs/mitsuba.md)")
    q.add_argument("--envmap", help="environment map (.hdr/.exr; default: the shared studio map)")
    q.add_argument("--spp", type=int, help="samples per pixel (default: per scene, "
                   + ", ".join(f"{k} {v}" for k, v in DEFAULT_SPP.items()) + ")")
    q.add_argument("--resolution", type=int, default=256, help="image width and height in pixels")
    q.add_argument("--seed", type=_RENDER_SEED, default=0,
                   help="seed of the source's render (the reference's: +1, +2)")
    q.add_argument("--compare", metavar="REFERENCE",
                   help="also render REFERENCE; write reference | source | difference")
    q.add_argument("--title", help="write this title above the image, or above the comparison (.png only; "
                                   "default: no title)")
    q.add_argument("-o", "--output", required=True,
                   help="image: .png (sRGB, grey background), .exr (linear RGBA) or .hdr (linear, grey background)")
    q.add_argument("--json", action="store_true", help=_JSON_HELP)
    q.set_defaults(func=cmd_render)

    q = sub.add_parser("compare", help="error of TEST against REFERENCE (Ngan et al. metric, eq. 10; every half-vector "
                       "azimuth when either is anisotropic)")
    q.add_argument("reference", help="reference BRDF file")
    q.add_argument("test", help="BRDF file to evaluate")
    q.add_argument("--json", action="store_true", help=_JSON_HELP)
    q.set_defaults(func=cmd_compare)

    q = sub.add_parser("report", help="static HTML report of a model: renders, NDF, coverage, slices, numbers")
    q.add_argument("model", help="model file (.reflecto)")
    q.add_argument("--ref", help="reference BRDF file to compare with (default: none, no comparison)")
    q.add_argument("--spp", type=int, default=64, help="samples per pixel of the renders")
    q.add_argument("--no-render", action="store_true", help="skip the Mitsuba renders")
    q.add_argument("-o", "--output", required=True, help="folder to write index.html and images into")
    q.add_argument("--json", action="store_true", help=_JSON_HELP)
    q.set_defaults(func=cmd_report)

    q = sub.add_parser("fit-ct", help="fit the Cook–Torrance baseline to a dense BRDF (as Ngan et al. 2005)")
    q.add_argument("source", help="BRDF file")
    q.add_argument("--json", action="store_true", help=_JSON_HELP)
    q.set_defaults(func=cmd_fit_ct)

    q = sub.add_parser("gallery", help="the paper's Fig. 6 analogue: teapots of anisotropic/asymmetric materials, "
                       "reference | symmetric path | §5.5 path, with errors (HTML)",
                       description="For every material: simulated captures at the given rotations, the symmetric "
                                   "path (the first capture, eq. 3 mirror) and the §5.5 path (all captures), their "
                                   "BRDF errors, and Mitsuba teapot renders under the environment map; writes "
                                   "index.html into the output folder.")
    q.add_argument("materials", nargs="+", help="material files (.json/.toml analytic descriptions or any BRDF file)")
    q.add_argument("-o", "--output", required=True, help="folder to write index.html and the renders into")
    q.add_argument("--device", default="ideal", help=_DEVICE_HELP)
    q.add_argument("--calibration", help="calibration file for a device that needs one (default: simulated)")
    q.add_argument("--rotations", nargs="+", default=["0", "90", "180", "270"],
                   help="rotations of the §5.5 captures, degrees" + _LIST_HELP)
    q.add_argument("--spp", type=int, default=64, help="samples per pixel of the renders")
    q.add_argument("--resolution", type=int, default=256, help="image width and height of the renders, pixels")
    q.add_argument("--seed", type=_GALLERY_SEED, default=1, help="seed of the first capture and render")
    q.add_argument("-q", "--quiet", action="store_true", help="no progress or summary")
    q.add_argument("--json", action="store_true", help=_JSON_HELP)
    q.set_defaults(func=cmd_gallery)

    q = sub.add_parser("sweep", help="validation (paper §6): simulate → reconstruct → evaluate, ours vs baselines")
    q.add_argument("folders", nargs="+", help="folders (or files) of materials: .binary .bsdf .h5 .json .toml")
    q.add_argument("-o", "--output", required=True, help="results folder (resumable: finished materials are skipped)")
    q.add_argument("--device", default="ideal", help="our device: " + _DEVICE_HELP[len("the device: "):])
    _batch_options(q)
    q.set_defaults(func=cmd_sweep)


    q = sub.add_parser("design", help="condenser design study: cone, tilt and LED count against coverage and fidelity",
                       description="For every design of the grid, place the LEDs (layout optimizer, §4.1 rules), "
                                   "measure coverage, θ_d reach at the peak and capture time, and run the sweep's "
                                   "pipeline on the design's ideal device against the dense Cook–Torrance fit. "
                                   "Writes design.csv and design.png; resumable. See docs/design-study.md.")
    q.add_argument("folders", nargs="+", help="folders (or files) of materials")
    q.add_argument("-o", "--output", required=True, help="results folder (resumable: finished work is skipped)")
    q.add_argument("--cones", nargs="+", default=[str(v) for v in DEFAULT_CONES],
                   help="cone half-angles (degrees)" + _LIST_HELP)
    q.add_argument("--tilts", nargs="+", default=[str(v) for v in DEFAULT_TILTS],
                   help="axis tilts (degrees)" + _LIST_HELP)
    q.add_argument("--leds", nargs="+", default=[str(v) for v in DEFAULT_LED_COUNTS],
                   help="LED counts" + _LIST_HELP)
    q.add_argument("--layout-only", action="store_true", help="lay out the designs only (no materials)")
    _batch_options(q)
    q.set_defaults(func=cmd_design)
    return p


def _batch_options(q: argparse.ArgumentParser) -> None:
    """The options of the batch commands (``sweep``, ``design``): workers, scheduler, quiet, JSON."""
    q.add_argument("--jobs", type=_JOBS, default=0, help="worker processes (0: all cores)")
    q.add_argument("--scheduler", metavar="ADDRESS", help=_SCHEDULER_HELP)
    q.add_argument("-q", "--quiet", action="store_true",
                   help="no progress (else a bar on a terminal, plain lines on stderr otherwise or under CI=true) "
                        "and no summary")
    q.add_argument("--json", action="store_true", help=_JSON_HELP)


def cmd_gallery(args: argparse.Namespace) -> int:
    """``reflecto gallery SOURCE... -o DIR``: teapots of reference, symmetric path and §5.5 path
    (:func:`reflecto.evaluate.gallery.gallery`, the paper's Fig. 6); returns exit status 0."""

    check_output(args.output, folder=True, marker=GALLERY_MARKER)
    _refuse_holding(args.output, [*args.materials, args.device, args.calibration])
    rotations = tuple(args.rotations)
    settings = GallerySettings(args.device, args.calibration, rotations, args.spp, args.resolution, args.seed)

    def progress(name: str, seconds: float) -> None:
        if not args.quiet and not args.json:
            print(f"{name}: {seconds:.0f} s", file=sys.stderr)

    page, rows = gallery(args.materials, args.output, settings, progress)
    info = {"output": str(page), "rows": [r.to_dict() for r in rows]}
    lines = [f"{r.name}: BRDF error symmetric path {100 * r.symmetric_error:.2f} %, "
             f"§5.5 {100 * r.asymmetric_error:.2f} %; "
             f"image difference {100 * r.symmetric_image_difference:.2f} % / "
             f"{100 * r.asymmetric_image_difference:.2f} % "
             f"(noise floor {100 * r.noise_floor:.2f} %)" for r in rows] + [f"wrote {page}"]
    return _emit(args, info, lines)


def _new_paths(path: str | Path | None) -> list[Path]:
    """``path`` and those of its parents that do not exist yet, outermost first."""
    if path is None:
        return []
    out: list[Path] = []
    p = Path(path)
    while not _exists(p) and p != p.parent:
        out.append(p)
        p = p.parent
    return out[::-1]


def _exists(path: Path) -> bool:
    """Whether ``path`` names something (a dangling link too). A name the system cannot
    look up (longer than it allows) counts as existing: nothing is created there, and
    the command's own write reports the name in one line."""
    try:
        return path.exists() or path.is_symlink()
    except OSError:
        return True


def _clean_up(new: list[Path], command: str) -> None:
    """After a failed command: remove what it created of its output's path.

    A report folder that did not exist is removed with its partial contents (a
    report is all or nothing); any other folder created for the output only if it
    is empty (a batch keeps what its finished items wrote).
    """
    if not new:
        return
    if command == "report" and new[-1].is_dir() and not new[-1].is_symlink():
        shutil.rmtree(new[-1], ignore_errors=True)
    if new[-1].is_dir() and not new[-1].is_symlink():  # the empty folders made inside it (a sweep's materials/)
        for root, subs, _ in os.walk(new[-1], topdown=False):
            for sub in subs:
                try:
                    (Path(root) / sub).rmdir()
                except OSError:  # not empty (a finished item's record), or a link: kept
                    pass
    for d in reversed(new):
        try:
            d.rmdir()
        except OSError:
            pass


def _show_warning(message, category, filename, lineno, file=None, line=None):
    if issubclass(category, ReflectoWarning):
        print(f"reflecto: warning: {one_line(message)}", file=sys.stderr)
    else:
        _SHOW_WARNING(message, category, filename, lineno, file, line)


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``reflecto`` with ``argv`` (default: ``sys.argv[1:]``).

    Parameters
    ----------
    argv
        Command-line arguments without the program name.

    Returns
    -------
    int
        Exit status: 0 on success; 1 on an error (one line ``reflecto: error: FILE: problem``
        on stderr; outputs and folders the command created are removed); 130 when
        interrupted; 141 when stdout's reader went away.
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    new = _new_paths(getattr(args, "output", None))
    rc = 1
    with warnings.catch_warnings():
        warnings.simplefilter("always", ReflectoWarning)
        # numpy's floating-point warnings (overflow in a hostile file's numbers, ...) are not
        # messages for the user: the loaders check every value and name the file at fault
        warnings.simplefilter("ignore", RuntimeWarning)
        warnings.showwarning = _show_warning
        try:
            _lists(args)
            check_inputs(args)
            rc = int(args.func(args))
            sys.stdout.flush()
        except BrokenPipeError:
            # the reader of stdout went away (`| head`): the work is done, say nothing more

            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            rc = 141
        except ReflectoError as e:
            print(f"reflecto: error: {one_line(e)}", file=sys.stderr)
        except ImportError as e:  # Mitsuba 3 (render, report, gallery) is optional
            if e.name != "mitsuba":
                raise
            print(f"reflecto: error: {args.command} needs Mitsuba 3, which does not load here ({one_line(e)}): "
                  "pip install 'reflecto[render]'", file=sys.stderr)
        except OSError as e:
            where = f"{e.filename}: " if e.filename else ""
            print(f"reflecto: error: {where}{one_line(e.strerror or e)}", file=sys.stderr)
        except MemoryError:
            print("reflecto: error: out of memory (see docs/limits.md for the input limits)", file=sys.stderr)
        except OverflowError as e:  # a number beyond a float's range that no check caught: still one line
            print(f"reflecto: error: a number is out of range ({one_line(e)})", file=sys.stderr)
        except KeyboardInterrupt:
            print("reflecto: interrupted", file=sys.stderr)
            rc = 130
        except SystemError as e:
            if not interrupted(e):  # Ctrl-C inside a compiled kernel comes back as a SystemError
                raise
            print("reflecto: interrupted", file=sys.stderr)
            rc = 130
        finally:
            if rc in (1, 130):
                _clean_up(new, args.command)
    return rc


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
