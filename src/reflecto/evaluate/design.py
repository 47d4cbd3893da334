"""Condenser design study: which cone, tilt and LED set make instant reflectometry match a dense fit?

The paper's view cone (48.2° about an axis tilted 20°) ends at θ_o = 68.2°, so the
specular peak is never seen at θ_d > 68°, where measured materials carry most of
eq. 10's error (docs/design-study.md). The instrument here is virtual, so the geometry
is a design variable. For every design of a grid — cone half-angle ``c``, axis tilt
``t``, number of LEDs ``L`` — this module

1. places the LEDs with :func:`reflecto.instrument.layout.optimize_layout` under the
   §4.1 rules (``l0`` 5° above the horizon, no LED below 5°, none within the cone +
   5° tube margin), weighted by :data:`~reflecto.instrument.layout.DESIGN_WEIGHTS`;
2. reports its coverage after eq. 3, the θ_d at which it sees the specular peak
   (:func:`~reflecto.instrument.layout.peak_theta_d`), the capture time and what the
   condenser must be (:func:`condenser`);
3. simulates a capture of every material on the design's ideal device, reconstructs it
   with the sweep's pipeline (§5, default options) and scores it by eq. 10 against the
   dense Cook–Torrance fit, which is fitted once per material and cached.

Everything is cached and resumable like the sweep (:mod:`.sweep`): ``designs/<key>.json``
per design (its layout and geometry), ``ct/<material>.json`` per material,
``runs/<key>/<material>.json`` per (design, material), each written atomically; a rerun
does only what is missing, and every seed derives from the material's name, so a
restarted study ends with identical results. Work runs in local processes, or on a
Dask cluster (``scheduler``, :func:`reflecto.batch.run_batch`). At the end ``design.csv`` (one
row per design) and ``design.png`` (fidelity and coverage against cone and tilt) are
written.

Nothing renders spheres and no earlier-device capture is made here: the grid's cost is
one simulated capture, one reconstruction and one evaluation of eq. 10 per (design,
material), ≈ 1 s.
"""

from __future__ import annotations

import csv
import dataclasses
import functools
import io
import json
import math
import os
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .. import workflow
from ..batch import Progress, run_batch
from ..errors import BatchError, ReflectoError
from ..fresnel import eta_to_json
from ..hemicube import hemicube
from ..instrument import layout
from ..instrument.device import Device
from ..instrument.optics import Optics
from ..instrument.simulate import simulate_capture
from ..io import atomic_write, make_parents, read_json
from ..load import load_source
from ..plotting import pyplot, save_figure
from .cooktorrance import fit_cook_torrance
from .metrics import brdf_error, evaluate_on_grid, max_albedo, metric_grid
from .sweep import METRIC_STRIDE, find_materials, material_seed

#: The grid of ``reflecto design`` by default (degrees, degrees, LEDs).
DEFAULT_CONES = (48.2, 55.0, 60.0, 65.0)
DEFAULT_TILTS = (10.0, 15.0, 20.0, 25.0, 35.0)
DEFAULT_LED_COUNTS = (6, 10)

#: Clear-aperture diameter of the paper's condenser (Anchor Optics, 47 mm; mm): the
#: housing (a 50 mm cylinder) fixes it, so a wider cone needs a shorter focal length.
LENS_DIAMETER_MM = 47.0
#: The largest numerical aperture taken as a catalogue part: moulded and polished
#: aspheric condensers are sold up to NA ≈ 0.9 (docs/design-study.md).
MAX_CATALOGUE_NA = 0.90
#: The condenser's rim must stay at least this far above the sample plane (degrees):
#: the mount needs the clearance the lowest LED gets (§4.1's 5°).
MIN_RIM_ELEVATION_DEG = 5.0
#: Frame rate of the paper's camera at 320 × 240 in trigger mode (Hz): 12 frames per
#: capture and "about 10 BRDFs per second" (§4.3).
PAPER_FRAME_RATE_HZ = 120.0
#: The paper's device, evaluated alongside the grid as its reference row.
PAPER_KEY = "paper"


#: Decimals of a design's angles, as its key (``c60.0-t20.0-l6``) and records hold them: the
#: study refuses finer values rather than giving two designs one record.
DESIGN_DECIMALS = 1


def design_value(value: float) -> float:
    """``value`` (degrees, or an LED count) as a design's key holds it: rounded to
    :data:`DESIGN_DECIMALS` decimals.

    Parameters
    ----------
    value
        A cone half-angle or axis tilt (degrees), or a number of LEDs.

    Returns
    -------
    float
        The rounded value.
    """
    return round(float(value), DESIGN_DECIMALS)


@dataclasses.dataclass(frozen=True)
class Design:
    """One optical design: cone half-angle and axis tilt (degrees), number of LEDs."""

    cone_half_angle_deg: float
    axis_tilt_deg: float
    n_leds: int

    @property
    def key(self) -> str:
        """File-name key, e.g. ``c60.0-t20.0-l6``."""
        return f"c{self.cone_half_angle_deg:.1f}-t{self.axis_tilt_deg:.1f}-l{self.n_leds}"

    def optics(self) -> Any:
        """The design's nominal :class:`~reflecto.instrument.optics.Optics` (paper's sensor and law).

        Returns
        -------
        Optics
            ``Optics(cone_half_angle_deg, axis_tilt_deg)``, every other field at its default.
        """

        return Optics(cone_half_angle_deg=self.cone_half_angle_deg, axis_tilt_deg=self.axis_tilt_deg)

    @property
    def possible(self) -> str | None:
        """Why the design cannot be built at all (``None`` if it can be laid out)."""
        if self.axis_tilt_deg + self.cone_half_angle_deg >= 90.0:
            return "the view cone reaches below the sample plane"
        return None


@dataclasses.dataclass(frozen=True)
class Condenser:
    """What a design asks of its condenser (aplanatic, sine law ``r = f sin θ``).

    Attributes
    ----------
    na
        Object-space numerical aperture in air, ``sin c``.
    focal_mm
        Focal length that puts the cone's marginal ray at the rim of a
        :data:`LENS_DIAMETER_MM` lens: ``f = (D/2) / NA`` (mm).
    rim_elevation_deg
        Elevation of the cone's lowest ray above the sample plane, ``90° − (t + c)``.
    realisable
        ``na ≤`` :data:`MAX_CATALOGUE_NA` and the rim at least
        :data:`MIN_RIM_ELEVATION_DEG` above the sample plane.
    limit
        What stops it otherwise (``""`` when realisable).
    """

    na: float
    focal_mm: float
    rim_elevation_deg: float
    realisable: bool
    limit: str


def condenser(design: Design) -> Condenser:
    """The condenser a design needs, and whether it is a catalogue part (:class:`Condenser`).

    ``NA = sin c``, ``f = (D/2)/NA`` with ``D =`` :data:`LENS_DIAMETER_MM`, rim elevation
    ``90° − (t + c)``.

    Parameters
    ----------
    design
        The design (cone half-angle ``c`` and axis tilt ``t``, degrees).

    Returns
    -------
    Condenser
        NA, focal length (mm), rim elevation (degrees), whether it is realisable
        (NA ≤ :data:`MAX_CATALOGUE_NA`, rim ≥ :data:`MIN_RIM_ELEVATION_DEG`) and, if not, why.
    """
    na = math.sin(math.radians(design.cone_half_angle_deg))
    rim = 90.0 - design.axis_tilt_deg - design.cone_half_angle_deg
    limits = []
    if na > MAX_CATALOGUE_NA + 1e-9:
        limits.append(f"NA {na:.3f} > {MAX_CATALOGUE_NA}")
    if rim < MIN_RIM_ELEVATION_DEG - 1e-9:
        limits.append(f"rim {rim:.1f}° above the sample plane < {MIN_RIM_ELEVATION_DEG}°")
    return Condenser(na=na, focal_mm=0.5 * LENS_DIAMETER_MM / na, rim_elevation_deg=rim,
                     realisable=not limits, limit="; ".join(limits))


def capture_frames(n_leds: int, n_check: int = 1, n_exposures: int = 2) -> int:
    """Frames of one capture: every LED and check LED at every exposure.

    Parameters
    ----------
    n_leds
        Number of LEDs.
    n_check
        Number of check LEDs (fired a second time to detect motion).
    n_exposures
        Exposures per LED (the HDR pair).

    Returns
    -------
    int
        ``(n_leds + n_check) · n_exposures``.
    """
    return (n_leds + n_check) * n_exposures


def capture_seconds(frames: int) -> float:
    """Capture time (s) of ``frames`` at the paper's camera (:data:`PAPER_FRAME_RATE_HZ`).

    Parameters
    ----------
    frames
        Number of frames (:func:`capture_frames`).

    Returns
    -------
    float
        ``frames / 120 Hz``, seconds.
    """
    return frames / PAPER_FRAME_RATE_HZ


# ------------------------------------------------------------------ layouts
def lay_out(design: Design, seed: int = 0, maxiter: int = 80) -> dict[str, Any]:
    """Place the design's LEDs and measure its geometry; the design's JSON record.

    The LED angles are rounded to 10⁻⁴° (kept unrounded if rounding broke a §4.1 rule).
    Keys: ``key, cone_half_angle_deg, axis_tilt_deg, n_leds, leds`` ([elevation,
    azimuth] pairs), ``coverage_after_tau, coverage_bound`` (fractions of the θ_h ≤ 80°
    cap, N = 64), ``peak_theta_d_deg`` (θ_d at which h = n is seen), ``theta_d_reach_deg``,
    ``tilt_margin_deg`` (the smallest hand tilt that takes one of those peaks out of view,
    :func:`~reflecto.instrument.layout.tilt_margin_deg`), ``objective_terms``,
    ``frames, capture_s``, the :class:`Condenser` fields, ``seconds``.

    Parameters
    ----------
    design
        The design; its LEDs are placed by
        :func:`reflecto.instrument.layout.optimize_layout` with
        :data:`~reflecto.instrument.layout.DESIGN_WEIGHTS`.
    seed
        Seed of the layout optimizer.
    maxiter
        Iteration limit of the layout optimizer.

    Returns
    -------
    dict
        The record (:func:`geometry_record`; ``seconds`` the layout's wall time).
    """

    t0 = time.perf_counter()
    optics = design.optics()
    leds = layout.optimize_layout(optics, n_leds=design.n_leds, seed=seed, maxiter=maxiter,
                                  weights=layout.DESIGN_WEIGHTS)
    angles = layout.led_angles(leds)
    rounded = np.round(angles, 4)
    if not layout.layout_violations(optics, layout.led_direction(rounded[:, 0], rounded[:, 1])):
        angles = rounded
    return geometry_record(design.key, optics, angles, seconds=time.perf_counter() - t0,
                           terms=layout.objective_terms(optics, layout.led_direction(angles[:, 0], angles[:, 1]),
                                                        hemicube(64)))


def geometry_record(key: str, optics: Any, angles: Any, seconds: float = 0.0, occluder_deg: float = 0.0,
                    terms: Sequence[float] | None = None, n_check: int = 1) -> dict[str, Any]:
    """The geometry of a layout (see :func:`lay_out`) for given optics and LED angles ``(L, 2)``.

    Parameters
    ----------
    key
        The record's key (:attr:`Design.key`, or :data:`PAPER_KEY`).
    optics
        The design's :class:`~reflecto.instrument.optics.Optics`.
    angles
        LED ``(elevation, azimuth)`` pairs in degrees, shape ``(L, 2)``.
    seconds
        Wall time to record (s).
    occluder_deg
        Half angle of a central occluder for the peak θ_d (degrees; 0: none).
    terms
        The layout objective's terms to record; ``None``: recorded as ``None``.
    n_check
        Number of check LEDs (for the frame count).

    Returns
    -------
    dict
        The keys listed in :func:`lay_out`, angles in degrees, coverages as fractions,
        ``capture_s`` in seconds.
    """

    angles = np.asarray(angles, dtype=np.float64)
    leds = layout.led_direction(angles[:, 0], angles[:, 1])
    cov = layout.coverage(optics, leds, resolution=64)
    peak = layout.peak_theta_d(optics, leds, occluder_deg)
    design = Design(optics.cone_half_angle_deg, optics.axis_tilt_deg, len(angles))
    frames = capture_frames(len(angles), n_check)
    return {"key": key, "cone_half_angle_deg": optics.cone_half_angle_deg, "axis_tilt_deg": optics.axis_tilt_deg,
            "n_leds": len(angles), "leds": angles.tolist(), "coverage_after_tau": cov.after_tau,
            "coverage_bound": cov.upper_bound_after_tau, "peak_theta_d_deg": [round(float(x), 2) for x in peak],
            "theta_d_reach_deg": float(peak.max()) if len(peak) else 0.0,
            "tilt_margin_deg": round(layout.tilt_margin_deg(optics, leds, occluder_deg), 3),
            "objective_terms": list(terms) if terms is not None else None,
            "frames": frames, "capture_s": capture_seconds(frames),
            **dataclasses.asdict(condenser(design)), "seconds": seconds}


@functools.lru_cache(maxsize=1)
def _paper_record() -> str:
    dev = Device.builtin("ideal")
    return json.dumps(geometry_record(PAPER_KEY, dev.optics, np.asarray(dev.led_angles),
                                      terms=layout.objective_terms(dev.optics, dev.leds, hemicube(64)),
                                      n_check=len(dev.check_leds)))


def paper_record() -> dict[str, Any]:
    """The geometry record of the paper's device (``ideal``), the study's reference row.

    Returns
    -------
    dict
        :func:`geometry_record` of the ``ideal`` device (key :data:`PAPER_KEY`); a fresh
        copy on every call.
    """
    return json.loads(_paper_record())


def design_device(rec: dict[str, Any]) -> Any:
    """The ideal :class:`~reflecto.instrument.device.Device` of a design record.

    Parameters
    ----------
    rec
        A design record (:func:`lay_out`, :func:`paper_record`): ``key``,
        ``cone_half_angle_deg``, ``axis_tilt_deg``, ``leds``.

    Returns
    -------
    Device
        The built-in ``ideal`` device for :data:`PAPER_KEY`, else
        ``Device.design(key, optics, leds, ideal=True)``.
    """

    if rec["key"] == PAPER_KEY:
        return Device.builtin("ideal")
    optics = Optics(cone_half_angle_deg=rec["cone_half_angle_deg"], axis_tilt_deg=rec["axis_tilt_deg"])
    return Device.design(rec["key"], optics, rec["leds"], ideal=True)


def _layout_task(cone: float, tilt: float, n_leds: int, out_dir: str) -> dict[str, Any]:
    rec = lay_out(Design(cone, tilt, n_leds))
    with atomic_write(Path(out_dir) / "designs" / f"{rec['key']}.json", "w") as fh:
        fh.write(json.dumps(rec))
    return rec


# ---------------------------------------------------------------- materials
def cook_torrance_record(src: Any, ref_values: Any, albedo: float) -> dict[str, Any]:
    """The dense Cook–Torrance fit of a material and its eq. 10 error (the sweep's baseline).

    Parameters
    ----------
    src
        The material (reference BRDF).
    ref_values
        ``src`` on ``metric_grid(METRIC_STRIDE)``, shape ``(K, 3)``, sr⁻¹.
    albedo
        The normalizing albedo (:func:`~reflecto.evaluate.metrics.max_albedo` of ``src``).

    Returns
    -------
    dict
        ``error`` (normalized eq. 10), ``log_rmse``, the fitted ``rho_d``, ``rho_s``, ``F0``,
        ``m``, and ``seconds`` (fit and evaluation).
    """

    t0 = time.perf_counter()
    ct = fit_cook_torrance(src)
    err = brdf_error(src, ct, stride=METRIC_STRIDE, albedo_ref=albedo, reference_values=ref_values)
    return {"error": err.normalized, "log_rmse": err.log_rmse, **ct.parameters(), "seconds": time.perf_counter() - t0}


def evaluate_design(src: Any, device: Any, seed: int, ref_values: Any, albedo: float) -> dict[str, Any]:
    """One (design, material) record: the sweep's capture→model path on the design's ideal device.

    Parameters
    ----------
    src
        The material (reference BRDF).
    device
        The design's device (:func:`design_device`).
    seed
        Seed of the simulated capture (:func:`~reflecto.evaluate.sweep.material_seed`).
    ref_values
        ``src`` on ``metric_grid(METRIC_STRIDE)``, shape ``(K, 3)``, sr⁻¹.
    albedo
        The normalizing albedo of eq. 10's normalized error.

    Returns
    -------
    dict
        ``error`` (normalized eq. 10), ``log_rmse``, the model's ``fresnel``/``eta``,
        ``kd``, ``ks``, ``isotropic``, ``shake_detected``, ``albedo_max``,
        ``energy_scale``, ``model_error`` and ``seconds``.
    """
    t0 = time.perf_counter()
    res = workflow.capture_to_model(simulate_capture(src, device, seed=seed), missing="nominal").reconstruction
    err = brdf_error(src, res.model, stride=METRIC_STRIDE, albedo_ref=albedo, reference_values=ref_values)
    m = res.model
    return {"error": err.normalized, "log_rmse": err.log_rmse, **eta_to_json(m.eta), "kd": m.kd.tolist(),
            "ks": m.ks.tolist(), "isotropic": bool(res.isotropic), "shake_detected": bool(res.shake_detected),
            "albedo_max": float(res.albedo_max), "energy_scale": float(res.energy_scale),
            "model_error": float(res.model_error), "seconds": time.perf_counter() - t0}


def _read(path: Path) -> dict[str, Any] | None:
    """A finished record, or None (absent or unreadable: done again)."""
    if not path.is_file():
        return None
    try:
        rec = read_json(path)
    except ReflectoError:
        return None
    return rec if isinstance(rec, dict) and all(_finite_number(rec.get(k)) for k in ("error", "log_rmse")) else None


def _finite_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _material_task(path: str, out_dir: str, designs: list[dict[str, Any]]) -> dict[str, Any]:
    """Every missing (design, material) record of one material, and its CT record.

    The reference on eq. 10's grid and its albedo are computed once for all designs.
    Returns ``{"ct": record, "runs": {key: record}}`` (also the ones already on disk).
    """

    p, out = Path(path), Path(out_dir)
    name = p.stem
    ct_path = out / "ct" / f"{name}.json"
    ct = _read(ct_path)
    runs = {d["key"]: r for d in designs if (r := _read(out / "runs" / d["key"] / f"{name}.json")) is not None}
    todo = [d for d in designs if d["key"] not in runs]
    if ct is not None and not todo:
        return {"ct": ct, "runs": runs}
    src = load_source(p)
    ref = evaluate_on_grid(src, metric_grid(METRIC_STRIDE))
    alb = max_albedo(src)
    if ct is None:
        ct = {"name": name, **cook_torrance_record(src, ref, alb)}
        make_parents(ct_path.parent)
        with atomic_write(ct_path, "w") as fh:
            fh.write(json.dumps(ct))
    seed = material_seed(name)
    for d in todo:
        rec = {"name": name, "design": d["key"], "seed": seed, **evaluate_design(src, design_device(d), seed, ref, alb)}
        rp = out / "runs" / d["key"] / f"{name}.json"
        make_parents(rp.parent)
        with atomic_write(rp, "w") as fh:
            fh.write(json.dumps(rec))
        runs[d["key"]] = rec
    return {"ct": ct, "runs": runs}


# -------------------------------------------------------------------- study
def design_grid(cones: Sequence[float], tilts: Sequence[float], led_counts: Sequence[int]) -> list[Design]:
    """Every combination, cones outermost (the table's order).

    Parameters
    ----------
    cones
        Cone half-angles, degrees.
    tilts
        Axis tilts, degrees.
    led_counts
        Numbers of LEDs.

    Returns
    -------
    list of Design
        ``len(cones) · len(tilts) · len(led_counts)`` designs, LED count innermost.
    """
    return [Design(float(c), float(t), int(n)) for c in cones for t in tilts for n in led_counts]


def design_study(folders: Sequence[str | Path], out_dir: str | Path, cones: Sequence[float] = DEFAULT_CONES,
                 tilts: Sequence[float] = DEFAULT_TILTS, led_counts: Sequence[int] = DEFAULT_LED_COUNTS,
                 jobs: int = 0, scheduler: str | None = None, progress: bool = True,
                 materials: bool = True) -> list[dict[str, Any]]:
    """Run the design study (module docstring); returns the table's rows.

    ``materials=False`` lays out the designs only (geometry columns, no fidelity).

    Parameters
    ----------
    folders
        Folders of material files, or the files (:func:`~reflecto.evaluate.sweep.find_materials`).
    out_dir
        The study's folder (``designs/``, ``ct/``, ``runs/``, ``design.csv``, ``design.png``).
    cones, tilts, led_counts
        The grid (:func:`design_grid`): cone half-angles and axis tilts in degrees, LED counts.
    jobs
        Number of worker processes; 0: one per CPU.
    scheduler
        Dask scheduler address, or ``None`` for local processes.
    progress
        Draw the progress on stderr.
    materials
        Whether to evaluate the materials on every design.

    Returns
    -------
    list of dict
        The rows of :func:`table_row`, the paper's device first, then the grid's order;
        designs that cannot be built (:attr:`Design.possible`) get a short row with
        ``realisable`` false and the ``limit``.

    Raises
    ------
    ReflectoError
        ``materials`` and no material file in ``folders``.
    BatchError
        After writing the table of what finished, if some designs or materials failed.
    """


    out = Path(out_dir)
    make_parents(out / "designs")
    grid = design_grid(cones, tilts, led_counts)
    jobs = jobs or os.cpu_count() or 1
    failures: list[tuple[str, str]] = []
    recs: dict[str, dict[str, Any]] = {}
    for d in grid:
        try:
            r = read_json(out / "designs" / f"{d.key}.json") if (out / "designs" / f"{d.key}.json").is_file() else None
        except ReflectoError:
            r = None  # unreadable: laid out again
        if isinstance(r, dict) and r.get("key") == d.key and all(
                _finite_number(r.get(k)) for k in ("coverage_after_tau", "na", "theta_d_reach_deg", "capture_s")):
            recs[d.key] = r
    todo = [d for d in grid if d.possible is None and d.key not in recs]
    bar = Progress(len(todo), "design layouts", progress)

    def laid(k: int, ok: bool, value: Any, seconds: float) -> None:
        if ok:
            recs[todo[k].key] = value
        else:
            failures.append((todo[k].key, value))
        bar.update(todo[k].key, ok, seconds)

    try:
        # absolute paths: a Dask worker resolves a relative one against its own working folder
        run_batch(_layout_task, [(d.cone_half_angle_deg, d.axis_tilt_deg, d.n_leds, os.path.abspath(out))
                                 for d in todo],
                  [d.key for d in todo], jobs, laid, scheduler=scheduler)
    finally:
        bar.close()
    paper = paper_record()
    laid_out = [paper] + [recs[d.key] for d in grid if d.key in recs]
    results: dict[str, dict[str, Any]] = {}
    cts: dict[str, dict[str, Any]] = {}
    n_mats = 0
    if materials:
        mats = find_materials(folders)
        if not mats:
            raise ReflectoError(f"no material files in {', '.join(map(str, folders))}")
        n_mats = len(mats)
        mbar = Progress(len(mats), "design materials", progress)

        def evaluated(k: int, ok: bool, value: Any, seconds: float) -> None:
            if ok:
                cts[mats[k].stem] = value["ct"]
                for key, r in value["runs"].items():
                    results.setdefault(key, {})[mats[k].stem] = r
            else:
                failures.append((str(mats[k]), value))
            mbar.update(mats[k].stem, ok, seconds)

        try:
            run_batch(_material_task, [(os.path.abspath(p), os.path.abspath(out), laid_out) for p in mats],
                      [str(p) for p in mats], jobs,
                      evaluated, scheduler=scheduler)
        finally:
            mbar.close()
    rows = [table_row(r, results.get(r["key"], {}), cts) for r in laid_out]
    rows += [{"key": d.key, "cone_half_angle_deg": d.cone_half_angle_deg, "axis_tilt_deg": d.axis_tilt_deg,
              "n_leds": d.n_leds, "realisable": False, "limit": d.possible} for d in grid if d.possible is not None]
    order = {d.key: k for k, d in enumerate(grid)}
    rows.sort(key=lambda r: -1 if r["key"] == PAPER_KEY else order.get(r["key"], len(order)))
    write_design_table(rows, out / "design.csv")
    plot_design(rows, out / "design.png")
    if failures:
        err = BatchError(sorted(failures), len(todo) + n_mats)
        err.records = rows
        raise err
    return rows


def table_row(geo: dict[str, Any], runs: dict[str, dict[str, Any]], cts: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """One design's row: its geometry and, over the materials with both records, the fidelity.

    Parameters
    ----------
    geo
        The design's geometry record (:func:`geometry_record`).
    runs
        Material name → its (design, material) record (:func:`evaluate_design`).
    cts
        Material name → its Cook–Torrance record (:func:`cook_torrance_record`).

    Returns
    -------
    dict
        The geometry columns and ``materials``; with at least one material also
        ``ours_below_ct``, ``fraction_below_ct``, ``median_ratio`` (ours / CT),
        ``median_error``, ``median_ct_error``, ``shaken``, ``anisotropic``, ``max_albedo``,
        ``max_eta`` (NaN if every Fresnel lobe is constant), ``constant_fresnel`` and
        ``seconds``.
    """
    names = sorted(n for n in runs if n in cts)
    row = {k: geo[k] for k in ("key", "cone_half_angle_deg", "axis_tilt_deg", "n_leds", "na", "focal_mm",
                               "rim_elevation_deg", "realisable", "limit", "coverage_after_tau", "coverage_bound",
                               "theta_d_reach_deg", "peak_theta_d_deg", "frames", "capture_s")}
    if "tilt_margin_deg" in geo:
        row["tilt_margin_deg"] = geo["tilt_margin_deg"]
    else:  # a layout recorded before the margin was: from its optics and LEDs
        dev = design_device(geo)
        row["tilt_margin_deg"] = round(layout.tilt_margin_deg(dev.optics, dev.leds), 3)
    row["leds"] = geo["leds"]
    row["materials"] = len(names)
    if names:
        ours = np.array([runs[n]["error"] for n in names])
        ct = np.array([cts[n]["error"] for n in names])
        ratio = ours / np.maximum(ct, 1e-300)
        row.update({"ours_below_ct": int(np.sum(ours < ct)), "fraction_below_ct": float(np.mean(ours < ct)),
                    "median_ratio": float(np.median(ratio)), "median_error": float(np.median(ours)),
                    "median_ct_error": float(np.median(ct)),
                    "shaken": int(sum(runs[n]["shake_detected"] for n in names)),
                    "anisotropic": int(sum(not runs[n]["isotropic"] for n in names)),
                    "max_albedo": float(max(runs[n]["albedo_max"] for n in names)),
                    "max_eta": float(max((max(runs[n]["eta"]) for n in names if runs[n]["eta"] is not None),
                                         default=math.nan)),
                    "constant_fresnel": int(sum(runs[n]["eta"] is None for n in names)),
                    "seconds": float(sum(runs[n]["seconds"] for n in names))})
    return row


TABLE_COLUMNS = ("key", "cone_half_angle_deg", "axis_tilt_deg", "n_leds", "na", "focal_mm", "rim_elevation_deg",
                 "realisable", "limit", "coverage_after_tau", "coverage_bound", "theta_d_reach_deg",
                 "peak_theta_d_deg", "tilt_margin_deg", "frames", "capture_s", "materials", "ours_below_ct",
                 "fraction_below_ct", "median_ratio", "median_error", "median_ct_error", "shaken", "anisotropic",
                 "max_albedo", "max_eta", "constant_fresnel", "seconds", "leds")


def write_design_table(rows: list[dict[str, Any]], path: Path) -> Path:
    """``design.csv``: one row per design (the paper's device first), :data:`TABLE_COLUMNS`.

    Parameters
    ----------
    rows
        Rows of :func:`table_row` (a missing column is an empty cell; lists as JSON).
    path
        The CSV file to write (atomically; parents created).

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    def cell(v: Any) -> str:
        if v is None:
            return ""
        if isinstance(v, bool):
            return str(v)
        if isinstance(v, float):
            return f"{v:.6g}"
        if isinstance(v, list):
            return json.dumps(v)
        return str(v)

    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(TABLE_COLUMNS)
    for r in rows:
        w.writerow([cell(r.get(c)) for c in TABLE_COLUMNS])
    make_parents(path.parent)
    with atomic_write(path, "w") as fh:
        fh.write(buf.getvalue())
    return path


def plot_design(rows: list[dict[str, Any]], path: Path) -> Path:
    """``design.png``: per LED count, the share of materials below CT, the median ratio to
    CT and the coverage after eq. 3 against the cone half-angle, one line per tilt; open
    markers are designs that are not realisable (:func:`condenser`), the dashed line the
    paper's device.

    Parameters
    ----------
    rows
        Rows of :func:`design_study`.
    path
        The PNG file to write (atomically; parents created).

    Returns
    -------
    pathlib.Path
        ``path``.
    """

    plt = pyplot()
    grid = [r for r in rows if r["key"] != PAPER_KEY and "coverage_after_tau" in r]
    paper = next((r for r in rows if r["key"] == PAPER_KEY), None)
    counts = sorted({r["n_leds"] for r in grid}) or [6]
    tilts = sorted({r["axis_tilt_deg"] for r in grid})
    panels = [("fraction_below_ct", "ours < dense CT (share)"), ("median_ratio", "median ours / CT"),
              ("coverage_after_tau", "coverage after eq. 3")]
    fig, axes = plt.subplots(len(panels), len(counts), figsize=(4.6 * len(counts), 3.1 * len(panels)), squeeze=False)
    colours = plt.cm.viridis(np.linspace(0.0, 0.9, max(len(tilts), 1)))
    for j, n in enumerate(counts):
        for i, (col, label) in enumerate(panels):
            ax = axes[i, j]
            for tilt, colour in zip(tilts, colours):
                sel = sorted((r for r in grid if r["n_leds"] == n and r["axis_tilt_deg"] == tilt and col in r),
                             key=lambda r: r["cone_half_angle_deg"])
                if not sel:
                    continue
                x = [r["cone_half_angle_deg"] for r in sel]
                ax.plot(x, [r[col] for r in sel], "-", color=colour, label=f"tilt {tilt:g}°")
                for r in sel:
                    ax.plot(r["cone_half_angle_deg"], r[col], "o", color=colour,
                            mfc=colour if r["realisable"] else "white")
            if paper is not None and col in paper:
                ax.axhline(paper[col], color="grey", ls="--", lw=1, label="paper's device")
            if col == "fraction_below_ct":
                ax.axhline(0.8, color="red", ls=":", lw=1)
            if col == "median_ratio":
                ax.axhline(0.8, color="red", ls=":", lw=1)
            ax.set_ylabel(label)
            ax.set_xlabel("cone half-angle (°)")
            if i == 0:
                ax.set_title(f"{n} LEDs")
            ax.grid(alpha=0.3)
    if axes[0, 0].get_legend_handles_labels()[0]:  # a grid of only unrealisable designs draws no labelled line
        axes[0, 0].legend(fontsize=7)
    fig.tight_layout()
    make_parents(path.parent)
    return save_figure(fig, path, dpi=110)


def best_design(rows: list[dict[str, Any]]) -> dict[str, Any] | None:
    """The realisable design with the most materials below CT (then the lowest median ratio,
    then the fewest LEDs); ``None`` when no realisable design was evaluated.

    Parameters
    ----------
    rows
        Rows of :func:`design_study` (the paper's row is left out).

    Returns
    -------
    dict or None
        The chosen row.
    """
    ok = [r for r in rows if r.get("realisable") and r.get("materials") and r["key"] != PAPER_KEY]
    if not ok:
        return None
    return min(ok, key=lambda r: (-r["ours_below_ct"], r["median_ratio"], r["n_leds"]))
