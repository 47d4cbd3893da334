"""The preview (:mod:`reflecto.reconstruct.preview`): a first model from the compact peaks'
normal and one light fit, against analytic ground truth and the full reconstruction."""

from __future__ import annotations

import math

import numpy as np
import pytest

from reflecto import geometry
from reflecto.errors import ParameterError
from reflecto.evaluate.metrics import brdf_error
from reflecto.instrument.calibrate import nominal_calibration
from reflecto.instrument.device import Device
from reflecto.instrument.simulate import simulate_capture
from reflecto.reconstruct import Options, reconstruct
from reflecto.reconstruct.preview import NO_PEAK_NOTE, PREVIEW_NOTE, UNPLACED, preview
from reflecto.sources.analytic import AnalyticBRDF
from reflecto.workflow import capture_to_model

IDEAL = Device.builtin("ideal")
SHARP = AnalyticBRDF("ggx", 0.015, kd=[0.2, 0.1, 0.05], ks=0.6, eta=1.5)
BROAD = AnalyticBRDF("beckmann", 0.3, kd=[0.1, 0.2, 0.3], ks=0.3, eta=1.6)


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(math.acos(min(1.0, float(np.dot(a, b)))))


@pytest.fixture(scope="module")
def sharp_tilted():
    cap = simulate_capture(SHARP, IDEAL, tilt_deg=4.0, seed=11)
    return cap, capture_to_model(cap, nominal_calibration(IDEAL)).slices


def test_the_compact_peaks_place_a_sharp_lobes_tilt(sharp_tilted) -> None:
    cap, slices = sharp_tilted
    truth = np.array(cap.extra["simulation"]["normal"])
    res = preview(slices)
    assert res.preview and res.notes[0] == PREVIEW_NOTE
    assert res.normal_source == "estimated"
    assert _angle_deg(res.frame[2], truth) < 0.1
    assert abs(res.normal_tilt_deg - 4.0) < 0.3
    assert res.normal_uncertainty_deg >= 0.1  # at least the camera's half-vector pitch
    assert not res.shake_detected
    assert res.isotropic and not res.isotropy.decided
    assert res.eta == pytest.approx(1.5, rel=0.1)
    assert res.albedo_max <= 1.0 and np.all(res.model.ks <= 1.0) and np.all(res.model.kd >= 0.0)


def test_the_preview_is_close_to_the_full_model(sharp_tilted) -> None:
    """On an analytic lobe both models are near the truth; the preview, a light fit, within a
    few times the full reconstruction's error."""
    _, slices = sharp_tilted
    quick, full = preview(slices), reconstruct(slices)
    e_quick = brdf_error(SHARP, quick.model, stride=4).normalized
    e_full = brdf_error(SHARP, full.model, stride=4).normalized
    assert e_full < 0.02  # 1.7 %
    assert e_quick < 0.05  # 3.9 %: 3° θ_d cells, every second pixel


def test_a_broad_lobe_keeps_the_device_axis_and_says_so() -> None:
    cap = simulate_capture(BROAD, IDEAL, tilt_deg=0.0, seed=3)
    slices = capture_to_model(cap, nominal_calibration(IDEAL)).slices
    res = preview(slices)
    assert res.normal_source == UNPLACED and np.allclose(res.frame, np.eye(3))
    assert math.isnan(res.normal_uncertainty_deg) and res.summary()["normal_uncertainty_deg"] is None
    assert NO_PEAK_NOTE in res.notes
    assert res.eta == pytest.approx(1.6, rel=0.15)
    assert brdf_error(BROAD, res.model, stride=4).normalized < 0.005


def test_the_preview_follows_the_options(sharp_tilted) -> None:
    cap, slices = sharp_tilted
    truth = np.array(cap.extra["simulation"]["normal"])
    given = preview(slices, Options(normal=truth, fixed_eta=1.5))
    assert given.normal_source == "given" and _angle_deg(given.frame[2], truth) < 1e-9
    assert given.eta == 1.5
    held = preview(slices, Options(max_tilt_deg=3.0))  # the peaks place 4°: beyond the search, not placed
    assert held.normal_source == UNPLACED and np.allclose(held.frame, np.eye(3))
    with pytest.raises(ParameterError, match="isotropic"):
        preview(slices, Options(isotropic="no"))
    device = preview(slices, Options(normal="device", detect_shake=False))
    assert device.normal_source == "device" and device.motion.repeat_checks == [] and device.motion.peaks is None
    assert np.allclose(device.frame, geometry.frame_from_normal(np.array([0.0, 0.0, 1.0]), np.array([1.0, 0, 0])))


def test_a_bound_is_noted_as_in_the_full_path() -> None:
    """A metal-like lobe with no diffuse floor: the preview's k_d is 0 in every channel,
    and its notes say so in the words of :func:`reflecto.reconstruct.pipeline.bound_notes`."""
    metal = AnalyticBRDF("ggx", 0.015, kd=0.0, ks=0.9, eta=8.0)
    cap = simulate_capture(metal, IDEAL, seed=5)
    slices = capture_to_model(cap, nominal_calibration(IDEAL)).slices
    res = preview(slices)
    assert np.all(res.model.kd == 0.0)
    assert "k_d = 0 in channels [0, 1, 2]: no diffuse floor measured" in res.notes


def test_a_shaken_capture_is_flagged_by_the_check_frames() -> None:
    cap = simulate_capture(SHARP, IDEAL, tilt_deg=4.0, seed=11, shake=True)
    slices = capture_to_model(cap, nominal_calibration(IDEAL), Options(detect_shake=False)).slices
    res = preview(slices)
    full = reconstruct(slices)
    assert full.shake_detected
    assert res.shake_detected
    assert res.motion.moved_leds or (res.motion.peaks is not None and res.motion.peaks.moved)


def test_a_preview_model_file_says_what_it_is(tmp_path, capsys) -> None:
    """``reconstruct_folder(preview=True)`` writes a model whose metadata and summary say it is a
    preview; ``reflecto info`` shows that, and a normal no peak placed as not placed."""
    from reflecto.cli import main
    from reflecto.instrument.capture import write_capture
    from reflecto.workflow import reconstruct_folder

    cap = write_capture(simulate_capture(BROAD, IDEAL, tilt_deg=4.0, seed=3), tmp_path / "cap")
    summary = reconstruct_folder(cap, tmp_path / "p.reflecto", preview=True)
    assert summary["preview"] is True and summary["normal_source"] == UNPLACED
    assert summary["normal_uncertainty_deg"] is None and summary["symmetry_test"]["decided"] is False
    assert main(["info", str(tmp_path / "p.reflecto")]) == 0
    out = capsys.readouterr().out
    assert "normal      not placed" in out and "preview     a first model" in out
    full = reconstruct_folder(cap, tmp_path / "f.reflecto")
    assert full["preview"] is False and abs(full["normal_tilt_deg"] - 4.0) < 0.5
    assert main(["info", str(tmp_path / "f.reflecto")]) == 0
    assert "  preview " not in capsys.readouterr().out
