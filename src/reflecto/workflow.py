"""The one capture→model path: a capture and a calibration choice in, a model out.

Every caller that turns a capture into a BRDF — the CLI (``reconstruct``, ``watch``),
the §6 studies (``sweep``, ``design``, ``gallery``, ``report``) and the Python API —
goes through this module, so that a change to the path is made once::

    calibration_for(device, calibration, missing=)   which calibration reads the capture
    measure(capture, calibration)                   HDR merge, radiometry → Slices   (§4.3)
    capture_to_model(capture, calibration, options) … → reconstruct (§5) → CaptureModel
    save_model(result, output, capture_dir)         model file + JSON summary, atomically
    reconstruct_folder(capture_dir, output, ...)    all of the above for one capture folder
    rotations_to_model(captures, calibration, ...)  captures at several rotations (§5.5)

**Which calibration.** A capture is read with (1) the calibration given (a
:class:`~reflecto.instrument.calibrate.Calibration` or its file, checked against the
capture's device design), else (2) the nominal calibration when the device's nominal
description is exact (``ideal``, ``earlier``), else (3) what the caller's ``missing``
says: ``"refuse"`` (the CLI's default: a real or as-built device differs from its
nominal optics, LEDs and vignetting in ways only a calibration recovers), ``"nominal"``
(the CLI's ``--nominal``, and studies that simulate with a device whose nominal
description is exact, e.g. ``wide``), or ``"simulate"`` (studies of a simulated
device with hidden imperfections: the virtual calibration procedure, §4.2, is run).
A device that needs its calibration, read with the nominal one, gets a note
(:data:`NOMINAL_NOTE`): its directions may be off by degrees, which the normal's
estimate and the motion cues read as a tilt or a turn.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import tempfile
import time
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from . import geometry
from .errors import OutputError, ParameterError, ReflectoError, ReflectoWarning, short_repr
from .instrument.calibrate import Calibration, calibrate, load_calibration, needs_calibration, nominal_calibration
from .instrument.capture import Capture, CaptureError, read_capture
from .instrument.device import BUILTINS, Device, load_device
from .instrument.simulate import simulate_calibration
from .instrument.slices import Slices, extract_slices
from .io import atomic_write, check_output, read_json, sha256
from .kinds import is_summary
from .reconstruct import Options, Reconstruction, reconstruct
from .reconstruct.asymmetric import AsymmetricReconstruction, RotatedCapture, reconstruct_rotations, sample_frames
from .reconstruct.eq3 import SymmetryTest, symmetry_test_slices
from .reconstruct.preview import preview as preview_reconstruction

__all__ = ["CaptureModel", "Missing", "StageSeconds", "calibration_file", "calibration_for", "capture_to_model",
           "measure", "reconstruct_folder", "rotations_to_model", "save_model", "save_rotations_model"]

#: What :func:`calibration_for` does for a device that needs a measured calibration and has none.
Missing = Literal["refuse", "nominal", "simulate"]
MISSING: tuple[str, ...] = ("refuse", "nominal", "simulate")


# ------------------------------------------------------------------ calibration
def calibration_for(device: Device, calibration: str | Path | Calibration | None = None, *,
                    missing: Missing = "refuse", seed: int = 1, where: str | Path = "<capture>") -> Calibration:
    """The calibration that reads captures of ``device`` (module docstring, *Which calibration*).

    Parameters
    ----------
    device
        The capture's device: its manifest's nominal description, or a simulated device
        (which, for ``missing="simulate"``, carries the hidden truth the virtual
        calibration measures).
    calibration
        A calibration or its ``.npz`` file; ``None`` for none.
    missing
        ``"refuse"``, ``"nominal"`` or ``"simulate"``, for a device that needs a measured
        calibration when none is given.
    seed
        Seed of the simulated calibration captures (``missing="simulate"``).
    where
        The capture, for the refusal's message.

    Returns
    -------
    Calibration
        ``calibration`` itself, or loaded from its file (checked against the device's
        nominal design); else the nominal calibration (a device whose nominal description
        is exact, or ``missing="nominal"``); else (``missing="simulate"``) the calibration
        measured from simulated calibration captures in a temporary folder.

    Raises
    ------
    CaptureError
        ``missing="refuse"`` and the device needs a measured calibration; ``missing="simulate"``
        for a device without its truth (a capture's, read from its manifest).
    FileFormatError
        The calibration file is damaged or made for another device design.
    ParameterError
        ``missing`` is none of :data:`MISSING`.
    """
    if missing not in MISSING:
        raise ParameterError(f"calibration: missing must be one of {', '.join(MISSING)}, got {missing!r}")
    nominal = device.nominal()
    if isinstance(calibration, Calibration):
        return calibration
    if calibration is not None:
        return load_calibration(calibration, nominal)
    if not needs_calibration(nominal) or missing == "nominal":
        return nominal_calibration(device)
    if missing == "refuse":
        raise CaptureError(where, f"captured with device {device.name!r}, whose optics, LEDs and vignetting "
                           "differ from its nominal design: pass --calibration FILE (from `reflecto calibrate`), "
                           "or --nominal to use the nominal calibration anyway")
    if device.truth is None:  # a capture's device is its manifest's nominal design: nothing to simulate from
        raise CaptureError(where, f"device {device.name!r} carries no truth to simulate its calibration from (a "
                           "capture records only the nominal design): pass the calibration of the simulated "
                           "device, e.g. calibration_for(load_device(NAME), missing=\"simulate\")")
    with tempfile.TemporaryDirectory(prefix="reflecto-calibration-") as tmp:
        return calibrate(simulate_calibration(device, Path(tmp) / "calib", seed=seed))


def device_key(device: str | Path) -> str:
    """A name for what ``device`` is, for the files and records kept per device: a built-in
    device's name, or a device file's name and the digest of its contents (two files of one
    name, or one file edited, are two devices: their calibrations and results differ).

    Parameters
    ----------
    device
        A built-in device name or a device file.

    Returns
    -------
    str
        ``"as-built"``, or e.g. ``"mydev-3f2a9c1b04d7"``.
    """
    if str(device) in BUILTINS:
        return str(device)
    return f"{Path(device).stem}-{sha256(Path(device).read_bytes())[:12]}"


def calibration_file(device: str | Path, folder: Path, seed: int = 1) -> str | None:
    """The calibration file of a simulated device with hidden imperfections (``as-built``,
    ``wide-as-built``), made once by the virtual calibration procedure and kept in
    ``folder``; ``None`` for a device whose nominal description is exact (``ideal``,
    ``wide``), which the nominal calibration reads.

    Batches pass the file's path (not the calibration) to their workers. A kept file that
    does not load is made again (with a warning).

    Parameters
    ----------
    device
        A built-in device name or a device file (:func:`reflecto.instrument.device.load_device`).
    folder
        Where the file ``calibration-<device>.npz`` (and the simulated calibration captures,
        ``calibration-<device>/``) are kept, ``<device>`` its :func:`device_key`.
    seed
        Seed of the simulated calibration captures.

    Returns
    -------
    str or None
        The path of the ``.npz`` file, or ``None`` for a device without hidden imperfections.
    """
    dev = load_device(device)
    if dev.truth is None:
        return None
    key = device_key(device)
    cal_path = folder / f"calibration-{key}.npz"
    if cal_path.exists():
        try:
            Calibration.load(cal_path)
        except ReflectoError as e:
            warnings.warn(f"{e}; calibrating again", ReflectoWarning, stacklevel=2)
            cal_path.unlink()
    if not cal_path.is_file():
        calib_dir = folder / f"calibration-{key}"
        if not calib_dir.is_dir():
            simulate_calibration(dev, calib_dir, seed=seed)
        calibrate(calib_dir).save(cal_path)
    return str(cal_path)


# ------------------------------------------------------------------ one capture
@dataclasses.dataclass(frozen=True)
class StageSeconds:
    """Wall time (s) of each stage of :func:`capture_to_model` and :func:`reconstruct_folder`."""

    read: float = 0.0
    slices: float = 0.0
    reconstruct: float = 0.0
    symmetry: float = 0.0
    write: float = 0.0

    @property
    def total(self) -> float:
        """Sum of the stages (s)."""
        return self.read + self.slices + self.reconstruct + self.symmetry + self.write


@dataclasses.dataclass(frozen=True)
class CaptureModel:
    """The result of :func:`capture_to_model`.

    Attributes
    ----------
    reconstruction
        The §5 reconstruction (model, η, normal, tests, notes).
    slices
        The capture's BRDF slices: in the device frame, turned by the capture's
        ``rotation_deg`` when it has one (the sample's tangent, §5.5).
    symmetry
        The eq. 3 test of the capture, in the sample frame, against the model.
    calibration
        Which calibration read it: ``"nominal"``, ``"nominal (--nominal)"``,
        ``"simulated"`` or the file's path.
    seconds, cpu_seconds
        Wall and CPU time (this process) of each stage.
    provenance
        What the capture's manifest says of its origin: the device's name and, for a
        simulated capture, its material (kept in the model's metadata, for exports).
    """

    reconstruction: Reconstruction
    slices: Slices
    symmetry: SymmetryTest
    calibration: str
    seconds: StageSeconds
    cpu_seconds: StageSeconds
    provenance: dict[str, str] = dataclasses.field(default_factory=dict)

    @property
    def model(self):
        """The reconstructed BRDF."""
        return self.reconstruction.model

    def summary(self) -> dict[str, Any]:
        """JSON-ready summary: :meth:`Reconstruction.summary`, the symmetry test and the calibration.

        Returns
        -------
        dict
            :meth:`reflecto.reconstruct.Reconstruction.summary`'s fields (``normal`` in device
            coordinates, also for a capture turned by its ``rotation_deg``), ``symmetry_test``
            (the eq. 3 test's ``to_dict()``) and, unless the calibration was ``"nominal"``,
            ``calibration`` (:attr:`calibration`).
        """
        out = {**self.reconstruction.summary(), "symmetry_test": self.symmetry.to_dict()}
        if not np.array_equal(self.slices.frame, np.eye(3)):  # turned by the capture's rotation: device coordinates
            out["normal"] = geometry.to_world(self.reconstruction.frame[2], self.slices.frame).tolist()
        if self.calibration != "nominal":
            out["calibration"] = self.calibration
        return out


def measure(capture: Capture, calibration: Calibration | str | Path, where: str | Path | None = None) -> Slices:
    """The capture's BRDF slices (HDR merge and radiometry, §4.3); errors name ``where``.

    Parameters
    ----------
    capture
        The capture (its frames and manifest).
    calibration
        The calibration that reads it (:func:`calibration_for`), or its ``.npz`` file.
    where
        The capture's folder, for the message of an error; ``None``: errors as raised.

    Returns
    -------
    Slices
        The BRDF slices in the device frame: ``light`` ``(L, 3)``, ``view`` ``(P, 3)``,
        ``values`` ``(L, P, 3)`` in sr⁻¹, ``valid`` ``(L, P)``.

    Raises
    ------
    CaptureError
        The capture gives no slices (naming ``where`` when given).
    """
    if not isinstance(capture, Capture):
        raise ParameterError(f"measure: the capture must be a Capture (read_capture(FOLDER)), got "
                             f"{short_repr(capture)}")
    if not isinstance(calibration, Calibration):
        calibration = calibration_for(capture.device, calibration, where=where or "<capture>")
    try:
        return extract_slices(capture, calibration)
    except CaptureError:
        raise
    except ReflectoError as e:
        if where is None:
            raise
        raise CaptureError(where, str(e).removeprefix("capture: ")) from None


#: The eq. 3 test of a preview, which does not run it: no pairs, undecided.
NOT_TESTED = SymmetryTest(0.0, 0.0, 0.0, 0, 0)


def _symmetry(slices: Slices, res: Reconstruction) -> SymmetryTest:
    """The eq. 3 test (:mod:`reflecto.reconstruct.eq3`) of one capture in its sample frame.

    Where the device axis was kept over an estimated tilt the data do not tell from it
    (:attr:`~reflecto.reconstruct.normal.NormalEstimate.alternative`), the data are
    tested in that frame too, and eq. 3 holds if it holds in either: a tilt the fit
    could not rule out is no evidence of an asymmetric material (ideal device,
    red-specular-plastic tilted 1.5° read in the device frame: BROKEN).
    """
    def in_frame(frame: NDArray[np.float64]) -> SymmetryTest:
        sl = slices if np.array_equal(frame, np.eye(3)) else slices.reframe(frame)
        return symmetry_test_slices(sl, slices.valid & sl.valid, res.model)

    test = in_frame(res.frame)
    alt = None if res.normal_estimate is None else res.normal_estimate.alternative
    if test.decided and not test.symmetric and alt is not None:
        other = in_frame(geometry.frame_from_normal(alt, np.array([1.0, 0.0, 0.0])))
        if other.symmetric:
            return other
    return test


#: The note of a capture read with the nominal calibration of a device that needs its own.
NOMINAL_NOTE = ("read with the nominal calibration of a device that needs its own (--nominal): its LED and view "
                "directions may be off by degrees, which the normal's estimate and the motion cues read as a tilt "
                "or a turn")


def _calibration_label(calibration: str | Path | Calibration | None, missing: Missing, device: Device) -> str:
    if isinstance(calibration, Calibration):
        return "given"
    if calibration is not None:
        return str(calibration)
    if not needs_calibration(device.nominal()):
        return "nominal"
    return {"nominal": "nominal (--nominal)", "simulate": "simulated"}.get(missing, "nominal")


def capture_to_model(capture: Capture | str | Path, calibration: str | Path | Calibration | None = None,
                     options: Options | None = None, *, missing: Missing = "refuse", seed: int = 1,
                     preview: bool = False) -> CaptureModel:
    """Turn one capture into a model: calibration, slices (§4.3), reconstruction (§5), eq. 3 test.

    Parameters
    ----------
    capture
        A :class:`~reflecto.instrument.capture.Capture`, or its folder.
    calibration, missing, seed
        The calibration choice (:func:`calibration_for`).
    options
        Reconstruction settings (:class:`~reflecto.reconstruct.Options`).
    preview
        Make the first model of :func:`reflecto.reconstruct.preview.preview` instead of the
        full reconstruction (with the ``options`` it follows; the eq. 3 test is not run and
        reads undecided).

    Returns
    -------
    CaptureModel
        The reconstruction, the slices (turned into the sample frame by the capture's
        ``rotation_deg`` when it is not a multiple of 360°), the eq. 3 symmetry test, the
        calibration's label, wall and CPU seconds per stage, and the provenance.

    Raises
    ------
    CaptureError
        Naming the capture folder (or ``<capture>``), for a capture that gives no model.
    """
    if not isinstance(preview, (bool, np.bool_)):
        raise ParameterError(f"preview must be True or False, got {short_repr(preview)}")
    t0, c0 = time.perf_counter(), time.process_time()
    where: str | Path = "<capture>"
    if not isinstance(capture, Capture):
        where = capture
        capture = read_capture(capture)
    t1, c1 = time.perf_counter(), time.process_time()
    cal = calibration_for(capture.device, calibration, missing=missing, seed=seed, where=where)
    slices = measure(capture, cal, where)
    if capture.rotation_deg % 360.0:  # the model lives in the sample's frame, turned by the manifest's rotation
        turn = sample_frames([capture.rotation_deg])[0]
        slices = slices.reframe(turn)
        options = _given_normal_in(options, turn)
    t2, c2 = time.perf_counter(), time.process_time()
    try:
        res = preview_reconstruction(slices, options) if preview else reconstruct(slices, options)
    except CaptureError:
        raise
    except ReflectoError as e:  # the reconstruction's own errors do not know the capture's folder
        cal_note = f" (calibration {calibration})" if isinstance(calibration, (str, Path)) else ""
        raise CaptureError(where, str(e).removeprefix("capture: ") + cal_note) from None
    t3, c3 = time.perf_counter(), time.process_time()
    sym = NOT_TESTED if preview else _symmetry(slices, res)
    t4, c4 = time.perf_counter(), time.process_time()
    label = _calibration_label(calibration, missing, capture.device)
    if label == "nominal (--nominal)":
        res.notes.append(NOMINAL_NOTE)
    return CaptureModel(res, slices, sym, label,
                        StageSeconds(read=t1 - t0, slices=t2 - t1, reconstruct=t3 - t2, symmetry=t4 - t3),
                        StageSeconds(read=c1 - c0, slices=c2 - c1, reconstruct=c3 - c2, symmetry=c4 - c3),
                        provenance(capture))


def _given_normal_in(options: Options | None, frame: NDArray[np.float64]) -> Options | None:
    """``options`` with a given normal (device coordinates, as ``--normal X,Y,Z`` gives it)
    expressed in ``frame``'s coordinates, those of the slices turned into it; other options as they are."""
    if not isinstance(options, Options) or isinstance(options.normal, str):  # reconstruct refuses a wrong type
        return options
    return dataclasses.replace(options, normal=geometry.to_local(np.asarray(options.normal, dtype=np.float64), frame))


def provenance(capture: Capture) -> dict[str, str]:
    """The device's name and, for a simulated capture, its material, from the capture's manifest."""
    out = {"device": capture.device.name}
    sim = capture.extra.get("simulation")
    if isinstance(sim, dict) and isinstance(sim.get("source"), str) and sim["source"]:
        out["material"] = Path(sim["source"]).stem + " (simulated capture)"
    return out


#: The summary's keys of the sample normal that a saved model's metadata carries (``reflecto info`` shows them).
NORMAL_KEYS = ("normal", "normal_tilt_deg", "normal_uncertainty_deg", "normal_source")


def _folder_of(output: Path) -> Path:
    """The real folder the file ``output`` is written into (the write replaces a link named
    ``output``, so the link itself is not followed: a dangling or looping one is no error)."""
    return Path(os.path.abspath(output)).parent.resolve()


def save_model(result: CaptureModel, output: str | Path, capture_dir: str | Path | None = None,
               calibration: str | Path | None = None) -> dict[str, Any]:
    """Write the model file and its ``.json`` summary beside it (each atomically); returns the summary.

    The model names its capture folder and its calibration file (when one was given)
    relative to its own folder, where readers (``reflecto report``) look for them.

    Parameters
    ----------
    result
        The result of :func:`capture_to_model`; its model's metadata gains the capture,
        calibration, provenance, ``model_error`` and the sample normal used
        (:data:`NORMAL_KEYS`: the normal in device coordinates, its tilt and uncertainty in
        degrees, and whether it was estimated, §5.4).
    output
        The model file to write; the summary goes to the same path with suffix ``.json``.
    capture_dir
        The capture's folder, recorded in the summary (``capture``) and, relative to the
        model's folder, in the model's metadata; ``None``: not recorded.
    calibration
        The calibration file used, recorded relative to the model's folder; ``None``: none.

    Returns
    -------
    dict
        The summary written: :meth:`CaptureModel.summary`, preceded by ``capture`` when
        ``capture_dir`` is given.
    """
    out = Path(output)
    summary = result.summary()
    if capture_dir is not None:
        summary = {"capture": str(capture_dir), **summary}
        rel = os.path.relpath(Path(capture_dir).resolve(), _folder_of(out))
        result.model.metadata.update({"capture": rel})
    if isinstance(calibration, (str, Path)):
        rel_cal = os.path.relpath(Path(calibration).resolve(), _folder_of(out))
        result.model.metadata.update({"calibration": rel_cal})
    result.model.metadata.update({**result.provenance, "model_error": summary["model_error"],
                                  **{k: summary[k] for k in NORMAL_KEYS}})
    if result.reconstruction.preview:  # `reflecto info` and the report say so
        result.model.metadata["preview"] = True
    _write_model_and_summary(result.model, out, summary)
    return summary


def _check_replaceable_summary(path: Path, model: Path) -> None:
    """Refuse to write a summary over a file that is not an earlier summary (``NAME.json`` is
    often the BRDF description or device file the capture came from). Beside an earlier
    model file ``model`` the JSON file is that model's summary, damaged or not."""
    if not path.exists() and not path.is_symlink() or model.exists() or model.is_symlink():
        return
    try:
        data = read_json(path, limit=MAX_SUMMARY_BYTES)
    except ReflectoError:
        data = None
    if not (isinstance(data, dict) and is_summary(data)):
        raise OutputError(path, "is not the summary of an earlier model, and the model's summary would replace "
                                "it: name the model otherwise (-o NEW.reflecto)")


#: The largest file read to tell an earlier summary from another JSON file (bytes).
MAX_SUMMARY_BYTES = 64 << 20


def _write_model_and_summary(model: Any, out: Path, summary: dict[str, Any]) -> None:
    """The model file ``out``, then its ``.json`` summary, each atomically. The summary's path
    is checked before the model is written, and a summary that cannot be written (or an
    interrupt between the two) takes the model just written with it: no model is left
    without its summary."""
    summary_path = out.with_suffix(".json")
    check_output(summary_path)
    _check_replaceable_summary(summary_path, out)
    model.save(out)
    try:
        with atomic_write(summary_path, "w") as fh:
            fh.write(json.dumps(summary, indent=1))
    except BaseException:
        out.unlink(missing_ok=True)
        raise


def reconstruct_folder(capture_dir: str | Path, output: str | Path, calibration: str | Path | None = None,
                       options: Options | None = None, missing: Missing = "refuse",
                       preview: bool = False) -> dict[str, Any]:
    """A capture folder → its model file and ``.json`` summary (:func:`capture_to_model`, :func:`save_model`).

    Returns the summary, with the motion cues described (``motion``) and the stages'
    wall and CPU times (``stage_seconds``, ``stage_cpu_seconds``). A module-level function of plain arguments, so
    that batches run it in worker processes.

    Parameters
    ----------
    capture_dir
        The capture folder.
    output
        The model file to write (and its ``.json`` summary beside it).
    calibration
        A calibration ``.npz`` file, or ``None`` (:func:`calibration_for`).
    options
        Reconstruction settings (:class:`~reflecto.reconstruct.Options`).
    missing
        What to do for a device that needs a calibration and has none (:data:`Missing`).
    preview
        Write the first model (:func:`reflecto.reconstruct.preview.preview`) instead of the
        full reconstruction; its summary says ``"preview": true``.

    Returns
    -------
    dict
        :func:`save_model`'s summary, with ``motion`` (one line, ``""`` when no cue fired),
        ``stage_seconds`` and ``stage_cpu_seconds`` (``read``, ``slices``, ``reconstruct``,
        ``symmetry``, ``write`` and ``total``, in seconds), and ``fit_cpu_seconds``: the
        reconstruction's CPU seconds per part (:class:`~reflecto.reconstruct.FitSeconds`).
    """
    return folder_to_model(capture_dir, output, calibration, options, missing, preview)[0]


def folder_to_model(capture_dir: str | Path, output: str | Path, calibration: str | Path | None = None,
                    options: Options | None = None, missing: Missing = "refuse",
                    preview: bool = False) -> tuple[dict[str, Any], CaptureModel]:
    """:func:`reconstruct_folder`'s summary and the :class:`CaptureModel` whose model it wrote
    (a caller that shows the model, as ``reflecto watch``'s thumbnail, need not read it back).

    Parameters
    ----------
    capture_dir, output, calibration, options, missing, preview
        As for :func:`reconstruct_folder`.

    Returns
    -------
    tuple of (dict, CaptureModel)
        The summary :func:`reconstruct_folder` returns, and the result behind it.
    """
    result = capture_to_model(capture_dir, calibration, options, missing=missing, preview=preview)
    t0, c0 = time.perf_counter(), time.process_time()
    summary = save_model(result, output, capture_dir, calibration if isinstance(calibration, (str, Path)) else None)
    wall = dataclasses.replace(result.seconds, write=time.perf_counter() - t0)
    cpu = dataclasses.replace(result.cpu_seconds, write=time.process_time() - c0)
    return {**summary, "motion": result.reconstruction.motion.describe(),
            "stage_seconds": {**dataclasses.asdict(wall), "total": wall.total},
            "stage_cpu_seconds": {**dataclasses.asdict(cpu), "total": cpu.total},
            "fit_cpu_seconds": dataclasses.asdict(result.reconstruction.cpu_seconds)}, result


# ------------------------------------------------------------------ several rotations (§5.5)
def rotated_captures(captures: Sequence[Capture | str | Path], calibration: str | Path | Calibration | None = None,
                     *, missing: Missing = "refuse", seed: int = 1,
                     rotations_deg: Sequence[float] | None = None,
                     names: Sequence[str] | None = None) -> list[RotatedCapture]:
    """The captures of a §5.5 set as :class:`~reflecto.reconstruct.asymmetric.RotatedCapture`:
    one device for all (refused otherwise), one calibration.

    ``rotations_deg`` overrides the captures' own rotations (their manifests' ``rotation_deg``);
    ``names`` name the captures in messages (default: their folders).
    """
    if names is None:
        names = [str(c) if not isinstance(c, Capture) else f"capture {k + 1}" for k, c in enumerate(captures)]
    for what, given in (("rotations_deg", rotations_deg), ("names", names)):  # one per capture: none dropped
        if given is not None and len(given) != len(captures):
            raise ParameterError(f"{what}: one per capture, got {len(given)} for {len(captures)} captures")
    if rotations_deg is not None:
        for r in rotations_deg:
            if isinstance(r, bool) or not isinstance(r, (int, float, np.integer, np.floating)) or not math.isfinite(r):
                raise ParameterError(f"rotations_deg: each a finite number of degrees, got {r!r}")
    caps = [c if isinstance(c, Capture) else read_capture(c) for c in captures]
    if not caps:
        raise ReflectoError("<no capture>: the asymmetric reconstruction (§5.5) needs captures")
    first = caps[0]
    for c, name in zip(caps[1:], names[1:]):
        if c.device.to_dict() != first.device.to_dict():
            raise CaptureError(name, f"captured with device {c.device.name!r}, {names[0]} with "
                               f"{first.device.name!r} (or the same name with other optics, LEDs or camera): the "
                               "captures of one §5.5 set must come from one device")
    cal = calibration_for(first.device, calibration, missing=missing, seed=seed, where=names[0])
    rots = [c.rotation_deg for c in caps] if rotations_deg is None else list(rotations_deg)
    return [RotatedCapture(measure(c, cal, name), float(r), name) for c, r, name in zip(caps, rots, names)]


def rotations_to_model(captures: Sequence[Capture | str | Path], calibration: str | Path | Calibration | None = None,
                       options: Options | None = None, *, missing: Missing = "refuse",
                       seed: int = 1) -> AsymmetricReconstruction:
    """One model from captures of the same point at several rotations (§5.5,
    :func:`~reflecto.reconstruct.asymmetric.reconstruct_rotations`).

    Parameters
    ----------
    captures
        The captures (:class:`~reflecto.instrument.capture.Capture` objects or folders),
        all from one device, each with its manifest's ``rotation_deg``.
    calibration, missing, seed
        The calibration choice (:func:`calibration_for`), one for all captures.
    options
        Reconstruction settings (:class:`~reflecto.reconstruct.Options`).

    Returns
    -------
    AsymmetricReconstruction
        The §5.5 reconstruction of the set.

    Raises
    ------
    CaptureError
        The captures come from different devices, or one gives no slices.
    """
    return reconstruct_rotations(rotated_captures(captures, calibration, missing=missing, seed=seed), options)


def save_rotations_model(result: AsymmetricReconstruction, output: str | Path, capture_dirs: Sequence[str | Path],
                         calibration_note: str | None = None) -> dict[str, Any]:
    """Write a §5.5 model and its ``.json`` summary (each atomically); returns the summary.

    Parameters
    ----------
    result
        The result of :func:`rotations_to_model`; its model's metadata gains the captures
        (relative to the model's folder), ``rotations_deg`` and ``asymmetric``.
    output
        The model file to write; the summary goes to the same path with suffix ``.json``.
    capture_dirs
        The captures' folders, recorded in the summary (``captures``).
    calibration_note
        A description of the calibration used, recorded as ``calibration``; ``None`` or
        ``""``: not recorded.

    Returns
    -------
    dict
        The summary written: ``captures`` followed by :meth:`AsymmetricReconstruction.summary`'s
        fields (and ``calibration``).
    """
    out = Path(output)
    summary = {"captures": [str(c) for c in capture_dirs], **result.summary()}
    if calibration_note:
        summary["calibration"] = calibration_note
    result.model.metadata.update({"captures": [os.path.relpath(Path(c).resolve(), _folder_of(out))
                                               for c in capture_dirs],
                                  "rotations_deg": result.rotations_deg, "asymmetric": True})
    _write_model_and_summary(result.model, out, summary)
    return summary
