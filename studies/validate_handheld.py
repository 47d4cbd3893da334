"""Hand-held validation (issue 41): the 50 shared materials through a calibrated device, tilted and shaken.

For every material (its seed ``crc32(name)``, :func:`reflecto.evaluate.sweep.material_seed`):

* a tilt drawn from the seed, uniform in [0°, ``--max-tilt``] (default 10°), at the
  azimuth the simulator draws from the same seed;
* four captures on the device (``--device``, default ``as-built``, with the virtual
  calibration of :func:`reflecto.workflow.calibration_file`): untilted
  steady, tilted steady, tilted shaken (``simulate_capture(..., shake=True)``) and,
  for the normal's share of the tilt range, the untilted one counted as a 0° tilt;
* reconstructed with the default options (``normal="auto"``); the steady ones also
  with the true normal (``Options(normal=truth)``).

Reported per half of the generalization split (:mod:`reflecto.evaluate.split`):

* normal error of the steady captures (tilted and untilted): share within 0.5°, max;
* false shake flags on steady captures; share of shaken captures detected;
* false "eq. 3 BROKEN" (:attr:`reflecto.workflow.CaptureModel.symmetry`, the eq. 3 test
  as ``reflecto reconstruct`` reports it) on the steady captures (all 50 materials are
  isotropic, so symmetric);
* eq. 10 error (:func:`reflecto.evaluate.metrics.brdf_error`, every ``--metric-stride``-th
  θ_d/φ_d bin) with the estimated normal over that with the true normal (share ≤ 1.1)
  and over the untilted capture's (share ≤ 1.25); and with the true normal over the
  untilted capture's: the tilt's cost that no normal estimate can remove (the
  reconstruction's resampling and the geometry of what the tilted cone sees), split by
  whether the tilt took a slice's specular peak out of view (:func:`peaks_lost`: an LED
  whose untilted slice reaches its mirror direction sees, tilted, no half vector within
  the fitted lobe's half width);
* the reconstruction's own reproducibility at the true normal: eq. 10 of the tilted
  capture reconstructed with the true normal turned by :data:`NEAR_DEG` (0.02°, a tenth of
  the camera's half-vector pitch) toward six azimuths. Where these errors spread by more
  than 1.1× (the true normal's included), the ratio to the true normal's error is decided
  below the camera's resolution, not by the estimate; reported: the share of materials
  whose errors stay within 1.1×, the estimate's ratio on those, and the share whose
  estimated-normal error is within 1.1× of the largest of them;
* of the misses (normal beyond 0.5°; eq. 10 beyond 1.1× the true normal's), the share
  where the capture itself fits the estimated frame at least as well as the true one
  (the model error ``ε`` of :func:`reflecto.reconstruct.isotropic.model_error`, the
  capture's own misfit, not the reference's): there the data, not the estimate, put the
  normal elsewhere;
* time per default reconstruction (median, p90), one process;
* the preview of each capture (:func:`reflecto.reconstruct.preview.preview`, what ``reflecto
  watch`` shows first): where its compact peaks place the normal, its error; the shaken
  captures it flags and the steady ones it flags falsely; its eq. 10 error over the full
  reconstruction's (median, p90).

With ``--mirror-symmetric`` every reference is replaced by its mirror-symmetric part,
``f_s(i, o) = ½ (f(i, o) + f(M i, M o))`` with ``M`` the reflection ``y → −y``
(:class:`MirrorSymmetric`): the symmetry about every plane through the normal that a
physical isotropic BRDF has, and that the estimate's model and the symmetry planes assume.
The neural fits of the MERL materials are invariant under rotation about ``n`` but not
exactly under that reflection; each record carries the reference's departure from it
(:func:`mirror_asymmetry`). A control, not the user's path: it separates what the
references' asymmetry does to the normal from what the estimate does.

Records go to ``OUT/records.jsonl`` as each material finishes (a rerun skips finished
ones), the summary to ``OUT/summary.json`` and stdout.

Run::

    PYTHONPATH=src .venv/bin/python studies/validate_handheld.py --materials 6   # quick subset
    PYTHONPATH=src .venv/bin/python studies/validate_handheld.py                 # all 50 (≈ 15 min)
    PYTHONPATH=src .venv/bin/python studies/validate_handheld.py --mirror-symmetric     # out/handheld-mirror
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from reflecto import geometry, load_source, workflow
from reflecto.brdf import BRDFSource
from reflecto.colour import LUM
from reflecto.evaluate.metrics import brdf_error, evaluate_on_grid, max_albedo, metric_grid
from reflecto.evaluate.split import half
from reflecto.evaluate.sweep import find_materials, material_seed
from reflecto.instrument.device import load_device
from reflecto.instrument.simulate import simulate_capture
from reflecto.polar import lobe_half_width_deg
from reflecto.reconstruct import Options, reconstruct
from reflecto.reconstruct.normal import half_vector_pitch_deg
from reflecto.reconstruct.pipeline import usable_samples
from reflecto.reconstruct.preview import preview

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"
#: The turn of the true normal (degrees) at which the reconstruction's reproducibility is measured.
NEAR_DEG = 0.02
#: Azimuths of those turns (evenly spaced).
NEAR_AZIMUTHS = 6


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(math.acos(min(1.0, max(-1.0, float(np.dot(a, b))))))


def pick(materials: list[Path], n: int | None) -> list[Path]:
    """``n`` materials spread evenly over the sorted list, alternating the halves; all when ``n`` is None."""
    if n is None or n >= len(materials):
        return materials
    by = {h: [m for m in materials if half(m.stem) == h] for h in ("tuning", "validation", "other")}
    out: list[Path] = []
    for k in range(n):
        group = by["tuning"] if k % 2 == 0 else by["validation"]
        group = group or by["tuning"] or by["validation"]
        idx = int(round((k // 2) * len(group) / max(1, math.ceil(n / 2))))
        cand = group[min(idx, len(group) - 1)]
        if cand not in out:
            out.append(cand)
    return out


def nearest_half_deg(slices, valid: np.ndarray, normal: np.ndarray) -> list[float]:
    """Per LED, the angle (degrees) between ``normal`` and the nearest half vector any
    usable sample of its slice has: how close to its mirror direction the slice looks."""
    out = []
    for k in range(slices.n_leds):
        h = slices.light[k][None, :] + slices.view[valid[k]]
        if not len(h):
            out.append(90.0)
            continue
        c = (h @ normal) / np.linalg.norm(h, axis=1)
        out.append(math.degrees(math.acos(min(1.0, float(c.max())))))
    return out


def lobe_hwhm_deg(model) -> float:
    """Half width at half maximum (degrees) of a fitted isotropic NDF; NaN for another model."""
    table = getattr(model, "ndf_table", None)
    return math.nan if table is None else lobe_half_width_deg(table.nodes, table.values)


def peaks_lost(rec: dict) -> bool:
    """Whether the tilt took a slice's specular peak out of view: an LED whose untilted
    slice reaches its mirror direction (within the camera's half-vector pitch) sees, tilted
    (in the true frame), no half vector within the fitted lobe's half width (or the pitch)."""
    pitch = rec["half_vector_pitch_deg"]
    reach = max(rec["flat"]["lobe_hwhm_deg"], pitch)
    return any(u <= pitch and t > reach
               for u, t in zip(rec["flat"]["nearest_half_deg"], rec["tilted"]["nearest_half_deg"]))


#: The reflection ``y → −y`` about the plane through the normal and ``x``.
MIRROR = np.array([1.0, -1.0, 1.0])


class MirrorSymmetric(BRDFSource):
    """A reference's mirror-symmetric part, ``f_s(i, o) = ½ (f(i, o) + f(M i, M o))`` (sr⁻¹),
    ``M`` the reflection :data:`MIRROR`. For a source invariant under rotation about
    ``n`` this is symmetric about every plane through ``n``."""

    def __init__(self, source: BRDFSource) -> None:
        self.source = source
        self.kind = source.kind
        self.path = source.path

    def eval(self, i, o) -> np.ndarray:
        i, o = np.asarray(i, dtype=np.float64), np.asarray(o, dtype=np.float64)
        return 0.5 * (self.source.eval(i, o) + self.source.eval(i * MIRROR, o * MIRROR))


def mirror_asymmetry(source: BRDFSource, n: int = 20000, seed: int = 0) -> float:
    """Relative RMS of ``(f(i, o) − f(M i, M o)) cos θ_i cos θ_o`` over that of
    ``f cos θ_i cos θ_o`` (luminance; ``n`` random direction pairs of the upper
    hemisphere, ``θ`` below ≈ 87°): 0 for a mirror-symmetric BRDF."""
    rng = np.random.default_rng(seed)

    def directions() -> np.ndarray:
        v = rng.normal(size=(n, 3))
        v[:, 2] = np.abs(v[:, 2]) + 0.05
        return v / np.linalg.norm(v, axis=1, keepdims=True)

    i, o = directions(), directions()
    w = i[:, 2] * o[:, 2]
    f = source.eval(i, o) @ LUM * w
    fm = source.eval(i * MIRROR, o * MIRROR) @ LUM * w
    return float(np.sqrt(np.sum((f - fm) ** 2) / max(float(np.sum(f**2)), 1e-300)))


def run_material(path: Path, device: str, cal, max_tilt: float, stride: int, mirror_symmetric: bool = False) -> dict:
    name = path.stem
    seed = material_seed(name)
    tilt = float(np.random.default_rng(seed).uniform(0.0, max_tilt))
    src: BRDFSource = load_source(path)
    asymmetry = mirror_asymmetry(src)
    if mirror_symmetric:
        src = MirrorSymmetric(src)
    dev = load_device(device)
    grid = metric_grid(stride)
    ref = evaluate_on_grid(src, grid)
    alb = max_albedo(src)

    def error(model) -> float:
        return float(brdf_error(src, model, stride=stride, albedo_ref=alb, reference_values=ref).normalized)

    rec: dict = {"name": name, "half": half(name), "device": device, "seed": seed, "tilt_deg": tilt,
                 "reference_mirror_asymmetry": asymmetry, "mirror_symmetric": mirror_symmetric}
    for label, t, shake in (("flat", 0.0, False), ("tilted", tilt, False), ("shaken", tilt, True)):
        cap = simulate_capture(src, dev, tilt_deg=t, shake=shake, seed=seed)
        truth = np.array(cap.extra["simulation"]["normal"])
        result = workflow.capture_to_model(cap, cal)
        sl, res = result.slices, result.reconstruction
        r = {"normal_error_deg": angle_deg(res.frame[2], truth), "tilt_found_deg": res.normal_tilt_deg,
             "uncertainty_deg": res.normal_uncertainty_deg, "normal_source": res.normal_source,
             "shake_detected": bool(res.shake_detected), "motion": res.motion.describe(), "seconds": res.seconds}
        t0 = time.perf_counter()
        pv = preview(sl)
        r["preview"] = {"seconds": time.perf_counter() - t0, "normal_source": pv.normal_source,
                        "normal_error_deg": angle_deg(pv.frame[2], truth), "shake_detected": bool(pv.shake_detected)}
        if not shake:
            r["symmetric"] = bool(result.symmetry.symmetric)  # as `reflecto reconstruct` reports it
            r["error"] = error(res.model)
            r["preview"]["error"] = error(pv.model)
        if not shake:
            usable = usable_samples(sl)
            true_frame = sl.reframe(geometry.frame_from_normal(truth, np.array([1.0, 0.0, 0.0])))
            r["nearest_half_deg"] = nearest_half_deg(true_frame, usable & true_frame.valid, np.array([0.0, 0.0, 1.0]))
        if label == "flat":
            r["lobe_hwhm_deg"] = lobe_hwhm_deg(res.model)
            rec["half_vector_pitch_deg"] = half_vector_pitch_deg(sl)
        if not shake:
            # the capture's own misfit (eq. 10's relative ε) in the estimated and the true frame:
            # which frame the capture itself prefers
            t0 = time.perf_counter()
            known = reconstruct(sl, Options(normal=truth))
            r["seconds_true_normal"] = time.perf_counter() - t0
            r["error_true_normal"] = error(known.model)
            r["shake_detected_true_normal"] = bool(known.shake_detected)
            r["model_error"] = float(res.model_error)
            r["model_error_true_normal"] = float(known.model_error)
        if label == "tilted":
            r["error_near_true_normal"] = near_true_normal_errors(sl, truth, error)
        rec[label] = r
    return rec


def near_true_normal_errors(sl, truth: np.ndarray, error) -> list[float]:
    """Eq. 10 (``error(model)``) of ``sl`` reconstructed with ``truth`` turned by :data:`NEAR_DEG`
    toward :data:`NEAR_AZIMUTHS` evenly spaced azimuths."""
    frame = geometry.frame_from_normal(truth, np.array([1.0, 0.0, 0.0]))
    out = []
    for k in range(NEAR_AZIMUTHS):
        a = 2 * math.pi * k / NEAR_AZIMUTHS
        n = truth + math.radians(NEAR_DEG) * (math.cos(a) * frame[0] + math.sin(a) * frame[1])
        out.append(error(reconstruct(sl, Options(normal=n / np.linalg.norm(n))).model))
    return out


def share(x: list[bool]) -> str:
    return f"{sum(x)}/{len(x)}" if x else "-"


def summarize(records: list[dict]) -> dict:
    out = {}
    for h in ("tuning", "validation", "all"):
        rs = [r for r in records if h == "all" or r["half"] == h]
        if not rs:
            continue
        steady = [r[k] for r in rs for k in ("flat", "tilted")]
        nerr = [s["normal_error_deg"] for s in steady]
        tilted = [r["tilted"] for r in rs]
        ratio_true = [t["error"] / max(t["error_true_normal"], 1e-12) for t in tilted]
        ratio_flat = [r["tilted"]["error"] / max(r["flat"]["error"], 1e-12) for r in rs]
        # the tilt's cost with the normal known: the reconstruction's and the geometry's share
        ratio_known = [r["tilted"]["error_true_normal"] / max(r["flat"]["error"], 1e-12) for r in rs]
        lost = [peaks_lost(r) for r in rs if "nearest_half_deg" in r["flat"]]
        known_lost = [x for x, q in zip(ratio_known, lost) if q]
        known_seen = [x for x, q in zip(ratio_known, lost) if not q]
        secs = [s["seconds"] for s in steady]
        # misses the capture itself prefers: its misfit ε in the estimated frame ≤ in the true one
        prefers = [s for s in steady if "model_error_true_normal" in s]
        normal_misses = [s["model_error"] <= s["model_error_true_normal"] for s in prefers
                         if s["normal_error_deg"] > 0.5]
        ratio_misses = [t["model_error"] <= t["model_error_true_normal"] for t in tilted
                        if "model_error_true_normal" in t and t["error"] > 1.1 * t["error_true_normal"]]
        near = [(t["error"], t["error_true_normal"], t["error_near_true_normal"]) for t in tilted
                if "error_near_true_normal" in t]
        spread = [max(b, *c) / max(min(b, *c), 1e-12) for _, b, c in near]
        steady_ratio = [a / max(b, 1e-12) for (a, b, _), sp in zip(near, spread) if sp <= 1.1]
        near_extra = {} if not near else {
            f"true_normal_reproducible_within_1.1_at_{NEAR_DEG:g}deg": share([x <= 1.1 for x in spread]),
            "error_vs_true_normal_within_1.1_where_reproducible": share([x <= 1.1 for x in steady_ratio]),
            f"error_within_1.1_of_the_worst_within_{NEAR_DEG:g}deg_of_the_true_normal":
                share([a <= 1.1 * max(b, *c) for a, b, c in near]),
        }
        pv_steady = [s["preview"] for s in steady if "preview" in s]
        placed = [p["normal_error_deg"] for p in pv_steady if p["normal_source"] == "estimated"]
        pv_ratio = [s["preview"]["error"] / max(s["error"], 1e-12) for s in steady if "preview" in s]
        pv_extra = {} if not pv_steady else {
            "preview_normal_placed_by_peaks": share([p["normal_source"] == "estimated" for p in pv_steady]),
            "preview_placed_normal_within_0.5": share([e <= 0.5 for e in placed]),
            "preview_placed_normal_error_max_deg": float(max(placed)) if placed else None,
            "preview_false_shake_steady": share([p["shake_detected"] for p in pv_steady]),
            "preview_shaken_detected": share([r["shaken"]["preview"]["shake_detected"] for r in rs]),
            "preview_error_vs_full_median": float(np.median(pv_ratio)),
            "preview_error_vs_full_p90": float(np.percentile(pv_ratio, 90)),
            "preview_error_vs_full_within_1.25": share([x <= 1.25 for x in pv_ratio]),
            "preview_seconds_median": float(np.median([p["seconds"] for p in pv_steady])),
        }
        out[h] = {
            "materials": len(rs),
            "normal_within_0.5": share([e <= 0.5 for e in nerr]),
            "normal_within_1": share([e <= 1.0 for e in nerr]),
            "normal_error_median_deg": float(np.median(nerr)), "normal_error_max_deg": float(np.max(nerr)),
            "normal_error_tilted_within_0.5": share([t["normal_error_deg"] <= 0.5 for t in tilted]),
            "false_shake_steady": share([s["shake_detected"] for s in steady]),
            "shaken_detected": share([r["shaken"]["shake_detected"] for r in rs]),
            "false_broken_steady": share([not s["symmetric"] for s in steady]),
            "error_vs_true_normal_within_1.1": share([x <= 1.1 for x in ratio_true]),
            "error_vs_true_normal_median": float(np.median(ratio_true)),
            "error_vs_untilted_within_1.25": share([x <= 1.25 for x in ratio_flat]),
            "error_vs_untilted_median": float(np.median(ratio_flat)),
            "true_normal_error_vs_untilted_within_1.25": share([x <= 1.25 for x in ratio_known]),
            "true_normal_error_vs_untilted_median": float(np.median(ratio_known)),
            "tilt_took_a_peak_out_of_view": share(lost),
            "true_normal_within_1.25_peak_lost": share([x <= 1.25 for x in known_lost]),
            "true_normal_within_1.25_peak_seen": share([x <= 1.25 for x in known_seen]),
            "normal_misses_fitting_the_capture_better": share(normal_misses),
            "error_vs_true_misses_fitting_the_capture_better": share(ratio_misses),
            "untilted_normal_source_device": share([r["flat"]["normal_source"] == "device" for r in rs]),
            "seconds_median": float(np.median(secs)), "seconds_p90": float(np.percentile(secs, 90)),
            **near_extra,
            **pv_extra,
        }
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--materials", type=int, help="a subset of N materials (both halves), for quick checks")
    ap.add_argument("--device", default="as-built", help="built-in device (default as-built, calibrated)")
    ap.add_argument("--max-tilt", type=float, default=10.0, help="tilts are drawn in [0, MAX] degrees")
    ap.add_argument("--metric-stride", type=int, default=2, help="θ_d/φ_d stride of the eq. 10 grid")
    ap.add_argument("-o", "--out",
                    help="output folder (default out/handheld; with --mirror-symmetric out/handheld-mirror)")
    ap.add_argument("--data", default=str(SHARED), help="the shared data folder")
    ap.add_argument("--mirror-symmetric", action="store_true",
                    help="replace each reference by its mirror-symmetric part (a control; MirrorSymmetric)")
    args = ap.parse_args(argv)
    if args.out is None:
        args.out = str(ROOT / "out" / ("handheld-mirror" if args.mirror_symmetric else "handheld"))
    out = Path(args.out) / args.device
    out.mkdir(parents=True, exist_ok=True)
    materials = pick(find_materials([Path(args.data) / "rgl", Path(args.data) / "merl-nbrdf"]), args.materials)
    dev = load_device(args.device)
    cal = workflow.calibration_for(dev, workflow.calibration_file(args.device, Path(args.out)), missing="nominal")
    rec_file = out / "records.jsonl"
    done = {}
    if rec_file.exists():
        for line in rec_file.read_text().splitlines():
            try:
                r = json.loads(line)
                # the other control's records, and those of a study that did not yet measure the
                # reproducibility, are redone
                if bool(r.get("mirror_symmetric", False)) == args.mirror_symmetric \
                        and "error_near_true_normal" in r.get("tilted", {}):
                    done[r["name"]] = r
            except (json.JSONDecodeError, KeyError):
                continue
    records = []
    for k, p in enumerate(materials):
        if p.stem in done:
            records.append(done[p.stem])
            continue
        t0 = time.perf_counter()
        r = run_material(p, args.device, cal, args.max_tilt, args.metric_stride, args.mirror_symmetric)
        records.append(r)
        with rec_file.open("a") as fh:
            fh.write(json.dumps(r) + "\n")
        t, f, s = r["tilted"], r["flat"], r["shaken"]
        print(f"{k + 1}/{len(materials)} {p.stem:28s} {r['half'][:3]} tilt {r['tilt_deg']:4.1f}° "
              f"normal off {t['normal_error_deg']:.2f}° (±{t['uncertainty_deg']:.2f}, {t['normal_source'][:3]}; "
              f"flat {f['normal_error_deg']:.2f}°) shake {int(f['shake_detected'])}{int(t['shake_detected'])}"
              f"/{int(s['shake_detected'])} sym {int(f['symmetric'])}{int(t['symmetric'])} "
              f"err ×{t['error'] / max(t['error_true_normal'], 1e-12):.2f} true, "
              f"×{t['error'] / max(f['error'], 1e-12):.2f} flat; {1000 * t['seconds']:.0f} ms "
              f"({time.perf_counter() - t0:.0f} s)", flush=True)
    summary = summarize(records)
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    print(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
