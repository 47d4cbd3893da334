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
    (lambda s: {"values": np.zeros_like(s.values)}, "no signal above the camera's noise"),
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


@pytest.mark.parametrize("kwargs, words", [
    ({"max_tilt_deg": "16"}, "max_tilt_deg must be a number"),
    ({"kd_bound_max_deg": None}, "kd_bound_max_deg must be a number"),
    ({"fixed_eta": 1.0000001}, "a fixed η must be a finite relative index in [1.001"),
    ({"fixed_eta": np.complex128(1.5)}, "a fixed η must be a real number"),
    ({"estimate_normal": "no"}, "estimate_normal must be True, False or None"),
    ({"detect_shake": "no"}, "detect_shake must be True or False"),
])
def test_options_of_the_wrong_type_are_refused(kwargs, words):
    """Options of another type than they hold are refused naming them (a string tilt raised a
    TypeError, a complex η warned in the fit, "no" counted as True)."""
    with pytest.raises(ParameterError, match=words.replace("[", r"\[").replace("(", r"\(")):
        Options(**kwargs)


def test_rotation_sets_whose_lists_disagree_are_refused(capture):
    """``rotated_captures`` with fewer or more rotations (or names) than captures, or a rotation
    that is not a number, is refused (zip dropped captures silently); the §5.5 set refuses a
    shadowing form it would not use."""
    from reflecto.reconstruct import reconstruct_rotations
    from reflecto.workflow import rotated_captures

    caps = [capture, dataclasses.replace(capture, rotation_deg=90.0), dataclasses.replace(capture, rotation_deg=180.0)]
    with pytest.raises(ParameterError, match="rotations_deg: one per capture, got 2 for 3"):
        rotated_captures(caps, rotations_deg=[0, 90])
    with pytest.raises(ParameterError, match="names: one per capture, got 1 for 3"):
        rotated_captures(caps, names=["a"])
    with pytest.raises(ParameterError, match="rotations_deg: each a finite number of degrees, got 'ninety'"):
        rotated_captures(caps[:2], rotations_deg=[0, "ninety"])
    with pytest.raises(ParameterError, match="the §5.5 set fits eq. 8's product shadowing"):
        reconstruct_rotations(rotated_captures(caps[:2]), Options(shadowing="correlated"))


def test_a_tilt_at_the_search_bound_says_so_and_the_isotropy_verdict_is_the_models():
    """A 22° tilt with the default max_tilt_deg (16°) is held at the bound, and the summary says
    so; a 30° tilt whose estimated frame reads anisotropic falls back to the device frame,
    where the verdict, the model and the notes agree."""
    from reflecto.model import IsotropicMicrofacetBRDF

    sl = extract_slices(simulate_capture(SRC, IDEAL, tilt_deg=22.0, seed=1), nominal_calibration(IDEAL))
    r = reconstruct(sl)
    assert r.normal_tilt_deg == pytest.approx(16.0, abs=0.02)
    assert any("reached the search's bound max_tilt_deg 16°" in n for n in r.notes), r.notes
    sl = extract_slices(simulate_capture(SRC, IDEAL, tilt_deg=30.0, tilt_azimuth_deg=30.0, seed=1),
                        nominal_calibration(IDEAL))
    r = reconstruct(sl, Options(max_tilt_deg=40.0))
    assert isinstance(r.model, IsotropicMicrofacetBRDF) == r.isotropy.isotropic
    assert r.normal_source == "device" and r.normal_tilt_deg == 0.0
    note = "read in the device frame, not at the tilt the isotropic fit places (29."
    assert any(n.startswith(note) for n in r.notes), r.notes


def test_options_compare_by_value():
    """Two Options with the same given normal are equal (the generated comparison raised on the
    normal's array), and a different normal or value makes them differ."""
    assert Options(normal=[0, 0, 1]) == Options(normal=(0.0, 0.0, 1.0))
    assert Options(normal=[0, 0, 1]) != Options(normal=[0, 0.6, 0.8])
    assert Options() == Options() and Options() != Options(normal=[0, 0, 1])
    assert Options(fixed_eta=1.5) != Options()


def test_a_simulated_calibration_needs_the_devices_truth():
    """A capture's device is its manifest's nominal design: ``missing="simulate"`` has no truth
    to measure there, and calibrating the nominal design instead would label a nominal
    reading "simulated" (pvc as-built: eq. 10 3.5× the calibrated one). Refused, as is a
    ``missing`` that names no choice."""
    from reflecto import workflow

    cap = simulate_capture(SRC, Device.builtin("as-built"), seed=1)
    with pytest.raises(CaptureError, match="carries no truth to simulate its calibration"):
        workflow.capture_to_model(cap, missing="simulate")
    with pytest.raises(ParameterError, match="missing must be one of"):
        workflow.capture_to_model(cap, missing="bogus")  # type: ignore[arg-type]
    # the device named by its file, with its truth: the calibration measures the as-built LEDs
    from reflecto.instrument import layout

    dev = Device.builtin("as-built")
    cal = workflow.calibration_for(dev, missing="simulate", seed=1)
    truth = layout.led_direction(*np.array(dev.truth.led_angles).T)
    offsets = np.degrees(np.arccos(np.clip(np.sum(truth * dev.leds, axis=1), -1.0, 1.0)))
    assert offsets.max() > 0.1  # the as-built LEDs are off their nominal places
    np.testing.assert_allclose(cal.report["led_offset_from_nominal_deg"], offsets, atol=0.005)


@pytest.mark.parametrize("name", ["m.json", "m.bsdf", "m.binary", "m"])
def test_a_model_is_saved_only_under_its_own_suffix(tmp_path, slices, name):
    """The readers tell files apart by their suffix: a model written as ``.bsdf`` would be read as an
    RGL file, and ``save_model`` to ``m.json`` would replace the model by its own summary."""
    from reflecto import workflow

    result = workflow.capture_to_model(simulate_capture(SRC, IDEAL, seed=1))
    with pytest.raises(ParameterError, match=r"not saved, a model file's name must end in \.reflecto"):
        workflow.save_model(result, tmp_path / name)
    with pytest.raises(ParameterError, match=r"must end in \.reflecto"):
        reconstruct(slices).model.save(tmp_path / name)
    assert list(tmp_path.iterdir()) == []
    workflow.save_model(result, tmp_path / "m.REFLECTO")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.REFLECTO", "m.json"]


def test_a_cook_torrance_fit_needs_usable_samples(slices):
    """No finite sample (a NaN or negative reference, a capture without a valid sample) is an
    error, not the start values returned as a black model."""
    from reflecto.evaluate.cooktorrance import fit_cook_torrance, fit_cook_torrance_capture

    @dataclasses.dataclass
    class Nan(AnalyticBRDF):
        def eval(self, i, o):
            return np.full(np.shape(i)[:-1] + (3,), np.nan)

    with pytest.raises(ParameterError, match="0 of 0 samples usable"):
        fit_cook_torrance(Nan())
    with pytest.raises(ParameterError, match="0 of 0 samples usable"):
        fit_cook_torrance_capture(dataclasses.replace(slices, valid=np.zeros_like(slices.valid)))
    with pytest.raises(ParameterError, match="reference_values must have shape"):
        fit_cook_torrance(SRC, reference_values=np.zeros((5, 3)))


@pytest.mark.parametrize("field, value, message", [("fixed_eta", -3.0, "a fixed η must be"),
                                                   ("isotropic", "maybe", "isotropic must be"),
                                                   ("max_tilt_deg", float("nan"), "max_tilt_deg must lie"),
                                                   ("normal", [0.0, 0.0, 2.0], "a given normal must be")])
def test_options_set_after_they_were_made_are_checked_by_the_stage(slices, field, value, message):
    """An :class:`Options` is checked when made; a field set afterwards is checked when a stage
    reads it (a fixed η of −3 was clamped to 1.001 without a word, ``isotropic="maybe"`` took
    the hemicube path)."""
    from reflecto.reconstruct.asymmetric import RotatedCapture, reconstruct_rotations
    from reflecto.reconstruct.preview import preview

    opt = Options()
    setattr(opt, field, value)
    with pytest.raises(ParameterError, match=message):
        reconstruct(slices, opt)
    with pytest.raises(ParameterError, match=message):
        preview(slices, opt)
    with pytest.raises(ParameterError, match=message):
        reconstruct_rotations([RotatedCapture(slices, 0.0), RotatedCapture(slices, 90.0)], opt)
    with pytest.raises(ParameterError, match="must be an Options"):
        reconstruct(slices, {"normal": "device"})  # type: ignore[arg-type]


def test_types_and_flags_are_checked_where_a_string_would_pass_as_true(capture, tmp_path):
    """A string where a flag belongs is refused, not read as True (``shake="no"`` simulated a
    shake); a source or device that is not one is named, not an AttributeError."""
    from reflecto import workflow
    from reflecto.export import export_merl, export_rgl

    for call, message in [(lambda: simulate_capture(SRC, IDEAL, shake="no"), "shake must be True or False"),
                          (lambda: simulate_capture(SRC, IDEAL, shake_deg=5.0), "a shake angle needs shake=True"),
                          (lambda: simulate_capture("x.json", IDEAL), "the source must be a BRDF"),
                          (lambda: simulate_capture(SRC, "ideal"), "the device must be a Device"),
                          (lambda: workflow.capture_to_model(capture, preview="no"), "preview must be True or False"),
                          (lambda: workflow.measure("cap", None), "the capture must be a Capture"),
                          (lambda: export_rgl(SRC, tmp_path / "a.bsdf", isotropic="no"), "isotropic must be"),
                          (lambda: export_rgl(SRC, tmp_path / "a.binary"), r"name must end in \.bsdf"),
                          (lambda: export_merl(SRC, tmp_path / "a.bsdf"), r"name must end in \.binary")]:
        with pytest.raises(ParameterError, match=message):
            call()
    assert list(tmp_path.iterdir()) == []
    slices = workflow.measure(capture, None)  # the nominal calibration reads the ideal device
    assert slices.values.shape[0] == IDEAL.n_leds


def test_a_merl_export_writes_only_what_the_reader_reads(tmp_path):
    """A negative source is refused (it was clamped to a black table), and one whose albedo the
    MERL reader refuses is not written (it was, and then could not be read)."""
    from reflecto.errors import FileFormatError
    from reflecto.export import export_merl

    @dataclasses.dataclass
    class Negative(AnalyticBRDF):
        def eval(self, i, o):
            return -np.ones(np.shape(i)[:-1] + (3,))

    @dataclasses.dataclass
    class Bright(AnalyticBRDF):
        def eval(self, i, o):
            return 50.0 * super().eval(i, o)

    with pytest.raises(ParameterError, match="negative on the MERL grid"):
        export_merl(Negative(), tmp_path / "n.binary")
    with pytest.raises(FileFormatError, match="not written: the file would be refused on reading"):
        export_merl(Bright(alpha=0.3, kd=0.5, ks=0.5), tmp_path / "b.binary")
    assert list(tmp_path.iterdir()) == []


def test_metrics_refuse_what_gives_no_number():
    """A reference with no valid bin gave a NaN error with only a warning; an NDF floor of NaN
    a NaN; an ``eval`` of the wrong shape NumPy's broadcast message."""
    from reflecto.evaluate.metrics import metric_grid, ndf_error

    g = metric_grid(4)
    with pytest.raises(ParameterError, match="no valid bin"):
        brdf_error(SRC, SRC, stride=4, reference_values=np.full((len(g.i), 3), np.nan))
    with pytest.raises(ParameterError, match="floor must be a fraction"):
        ndf_error(SRC, SRC, resolution=16, floor=float("nan"))

    @dataclasses.dataclass
    class Grey(AnalyticBRDF):
        def eval(self, i, o):
            return super().eval(i, o).mean(axis=-1)

    with pytest.raises(ParameterError, match=r"must return shape \(N, 3\)"):
        brdf_error(SRC, Grey(), stride=4)


@pytest.mark.parametrize("kwargs, message", [({"resolution": 0}, "resolution must be an integer"),
                                             ({"resolution": 10**6}, "resolution must be an integer"),
                                             ({"supersample": 0}, "supersample must be"),
                                             ({"lights": (((np.nan, 0.0, 1.0), 1.0),)}, "a light needs"),
                                             ({"lights": (((0.0, 0.0, 3.0), -1.0),)}, "a light needs")])
def test_a_sphere_render_refuses_sizes_and_lights_that_give_no_image(kwargs, message):
    """An empty image (resolution 0), an all-NaN one (supersample 0) or a black one (a NaN or
    negative light) was returned without a word; a huge size asked for terabytes."""
    from reflecto.hemicube import hemicube
    from reflecto.render.sphere import render_sphere

    with pytest.raises(ParameterError, match=message):
        render_sphere(SRC, **kwargs)
    with pytest.raises(ParameterError, match="hemicube resolution must be an even integer"):
        hemicube(10**6)


def test_a_capture_is_written_only_as_it_reads(capture, tmp_path):
    """Float frames were written as 8-bit PNGs that the reader then refused for a 12-bit camera,
    a NaN rotation or exposure into the manifest: refused before any file is written."""
    from reflecto.instrument.capture import write_capture

    for bad, message in [(dataclasses.replace(capture, raw=capture.raw.astype(np.float64)), "must be uint16"),
                         (dataclasses.replace(capture, rotation_deg=float("nan")), "rotation must be a finite"),
                         (dataclasses.replace(capture, exposures_ms=np.array([np.nan, 8.0])), "exposure times"),
                         (dataclasses.replace(capture, raw=capture.raw[:, :1]), "must have shape"),
                         (dataclasses.replace(capture, raw=capture.raw | np.uint16(0xF000)), "exceed the camera")]:
        with pytest.raises(ReflectoError, match=message):
            write_capture(bad, tmp_path / "cap")
        assert not (tmp_path / "cap").exists()


def test_a_simulated_calibration_needs_a_white_exposure(tmp_path):
    """``white_repeats=0`` averaged no frame (an IndexError after NumPy's empty-mean warning)."""
    from reflecto.instrument.simulate import simulate_calibration

    with pytest.raises(ParameterError, match="white_repeats must be an integer"):
        simulate_calibration(Device.builtin("as-built"), tmp_path / "cal", white_repeats=0)
    assert not (tmp_path / "cal").exists()


def test_a_capture_of_nothing_but_noise_gives_no_model():
    """A black target on a noisy camera (the as-built one) gave a 'metal-like' model of albedo
    5·10⁻⁶ and a shake flag: its samples are noise, and it says so."""
    dev = Device.builtin("as-built")
    black = AnalyticBRDF(alpha=0.2, kd=0.0, ks=0.0, eta=1.5)
    slices = extract_slices(simulate_capture(black, dev, seed=3), nominal_calibration(dev))
    with pytest.raises(ReflectoError, match="no signal above the camera's noise"):
        reconstruct(slices)
    dark = AnalyticBRDF(alpha=0.2, kd=0.02, ks=0.02, eta=1.5)  # dark, but there: its body is measured
    r = reconstruct(extract_slices(simulate_capture(dark, dev, seed=3), nominal_calibration(dev)))
    assert np.all(np.abs(r.model.kd - 0.02) < 0.006) and not r.shake_detected  # 0.0152 (nominal calibration)
    assert brdf_error(dark, r.model, stride=3).normalized < 0.1  # 0.051
