"""Bad input through the Python API: one :class:`~reflecto.errors.ReflectoError` naming the
argument or file, before any compiled kernel or long loop sees it; and equal inputs give
equal bytes."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from reflecto import AnalyticBRDF
from reflecto.errors import ParameterError, ReflectoError
from reflecto.evaluate import brdf_error
from reflecto.evaluate.cooktorrance import CookTorrance
from reflecto.instrument import Device, simulate_capture
from reflecto.instrument.calibrate import nominal_calibration
from reflecto.instrument.capture import CaptureError
from reflecto.instrument.slices import extract_slices
from reflecto.reconstruct import Options, reconstruct
from reflecto.watch import Watcher

SRC = AnalyticBRDF(alpha=0.2, kd=0.3, ks=0.6, eta=1.5)
IDEAL = Device.builtin("ideal")


@pytest.fixture(scope="module")
def capture():
    return simulate_capture(SRC, IDEAL, seed=1)


@pytest.fixture(scope="module")
def slices(capture):
    return extract_slices(capture, nominal_calibration(IDEAL))


def _with(array: np.ndarray, index, value) -> np.ndarray:
    out = array.copy()
    out[index] = value
    return out


@pytest.mark.parametrize("change, words", [
    (lambda s: {"view": _with(s.view, 100, np.nan)}, "view directions hold NaN"),  # was a segmentation fault
    (lambda s: {"light": np.full_like(s.light, np.inf)}, "light directions hold NaN"),
    (lambda s: {"light": np.zeros_like(s.light)}, "light directions must be unit vectors"),
    (lambda s: {"view": s.view[:0]}, "view directions must have shape"),
    (lambda s: {"values": _with(s.values, (0, 5), np.nan)}, "values hold NaN"),
    (lambda s: {"values": np.zeros_like(s.values)}, "every usable sample reads 0"),
    (lambda s: {"light": -s.light}, "valid samples"),
])
def test_slices_the_kernels_cannot_read_are_refused(slices, change, words):
    with pytest.raises(ReflectoError, match=words):
        reconstruct(dataclasses.replace(slices, **change(slices)))


def test_slices_check_reads_the_valid_samples_only(slices):
    """A NaN where a sample is not valid is no error, nor are finite values whose sum
    overflows; a NaN or an infinity where one is valid is."""
    from reflecto.instrument.slices import check_slices

    hidden = _with(slices.valid, (1, 7), False)
    check_slices(dataclasses.replace(slices, valid=hidden, values=_with(slices.values, (1, 7), np.nan)))
    check_slices(dataclasses.replace(slices, values=_with(slices.values, (0, 5), 1e308)))
    seen = tuple(np.argwhere(slices.valid)[-1])
    for bad in (np.nan, np.inf, -np.inf):
        with pytest.raises(ParameterError, match="values hold NaN or infinite values where valid"):
            check_slices(dataclasses.replace(slices, values=_with(slices.values, seen + (2,), bad)))


@pytest.mark.parametrize("change, words", [
    ({"raw": "short"}, "raw frames must be unsigned integers"),
    ({"raw": "bool"}, "raw frames must be unsigned integers"),
    ({"rotation_deg": float("nan")}, "rotation_deg must be a finite number"),
])
def test_captures_the_slices_cannot_read_are_refused(capture, change, words):
    raw = {"short": capture.raw[:3], "bool": capture.raw.astype(bool)}
    kw = {k: raw.get(v, v) if k == "raw" else v for k, v in change.items()}
    with pytest.raises(CaptureError, match=words):
        extract_slices(dataclasses.replace(capture, **kw), nominal_calibration(IDEAL))


def test_a_calibration_of_another_design_is_refused():
    earlier = simulate_capture(SRC, Device.builtin("earlier"), seed=1)
    with pytest.raises(CaptureError, match="calibration is for device 'ideal'"):
        extract_slices(earlier, nominal_calibration(IDEAL))


@pytest.mark.parametrize("theta", [90.0, 120.0, -10.0, float("nan"), float("inf"), None])
def test_albedo_outside_the_hemisphere_is_refused(theta):
    """At 90° the analytic lobe divided by cos θ_i and read 2173; beyond, the angle wrapped."""
    with pytest.raises(ParameterError, match="incidence angles"):
        SRC.albedo(theta)
    assert 0.43 < float(np.ravel(SRC.albedo(89.99))[0]) < 0.44


@pytest.mark.parametrize("kw", [{"n_u": 0}, {"n_phi": -5}, {"n_u": 10**9}, {"n_u": 2.5}])
def test_albedo_quadrature_sizes_are_bounded(kw):
    with pytest.raises(ParameterError, match="quadrature sizes"):
        SRC.albedo(30.0, **kw)


@pytest.mark.parametrize("make", [
    lambda: Options(resolution=float("nan")), lambda: Options(work_resolution=10**6),
    lambda: Options(resolution="512"), lambda: Options(fixed_eta="1.5"),
    lambda: simulate_capture(SRC, IDEAL, shake=True, shake_deg=float("inf")),
    lambda: simulate_capture(SRC, IDEAL, shake=True, shake_deg=-1.0),
    lambda: simulate_capture(SRC, IDEAL, tilt_deg="5"),
    lambda: IDEAL.with_camera(full_well=float("nan")), lambda: IDEAL.with_camera(exposures_ms=(8.0, 1.0)),
    lambda: CookTorrance(m=0.0), lambda: CookTorrance(f0=float("nan")), lambda: CookTorrance(rho_s=(-1, 0, 0)),
    lambda: brdf_error(SRC, SRC, stride=0), lambda: brdf_error(SRC, SRC, stride=3, albedo_ref=float("nan")),
])
def test_impossible_parameters_are_refused(make):
    with pytest.raises(ParameterError):
        make()


def test_equal_models_are_equal_files(slices, tmp_path):
    """The model file's zip members carry a fixed date: the same model, the same bytes."""
    model = reconstruct(slices, Options(normal="device")).model
    a, b = model.save(tmp_path / "a.reflecto"), model.save(tmp_path / "b.reflecto")
    assert a.read_bytes() == b.read_bytes()


def test_watch_names_with_odd_characters(tmp_path):
    """A capture whose name holds a newline is reported on one line; one with URL syntax
    (``#``, ``?``, ``%``) gets links that reach its files; a models folder inside the
    watched one is not taken for a capture."""
    root = tmp_path / "root"
    for name in ("bad\nname", "a#b?c%41"):
        (root / name).mkdir(parents=True)
    (root / "a#b?c%41" / "manifest.json").write_text("{}")

    def fake(cap_dir: Path, out: Path) -> dict:
        out.write_bytes(b"model")
        summary = {"normal_tilt_deg": 1.0, "eta": [1.5, 1.5, 1.5], "notes": []}
        out.with_suffix(".json").write_text(json.dumps(summary))
        return summary

    lines: list[str] = []
    models = root / "models"
    w = Watcher(root, models, fake, report=lines.append, thumbnails=False)
    w._model(root / "a#b?c%41", 0.0)
    w._fail(root / "bad\nname", "incomplete capture: no manifest.json yet")
    w.scan(final=True)
    assert lines and all("\n" not in line for line in lines)
    assert not any("models" in line for line in lines)
    page = (models / "index.html").read_text()
    assert 'href="a%23b%3Fc%2541.json"' in page
