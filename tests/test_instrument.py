"""The virtual instrument: optics, layout, simulation, calibration, HDR, slices."""

import dataclasses
import json
import shutil

import cv2
import numpy as np
import pytest

from reflecto import geometry as g
from reflecto.cli import main
from reflecto.errors import FileFormatError, ParameterError
from reflecto.instrument import layout
from reflecto.instrument.calibrate import Calibration, calibrate, nominal_calibration
from reflecto.instrument.capture import CaptureError, read_capture, write_capture
from reflecto.instrument.device import Device, load_device
from reflecto.instrument.hdr import merge_linear
from reflecto.instrument.optics import Optics
from reflecto.instrument.simulate import simulate_calibration, simulate_capture
from reflecto.instrument.slices import extract_slices
from reflecto.sources.analytic import AnalyticBRDF

SRC = AnalyticBRDF(distribution="ggx", alpha=0.2, kd=[0.3, 0.2, 0.1], ks=0.6, eta=1.5)


def _angle_deg(a, b):
    return np.degrees(np.arccos(np.clip(np.sum(a * b, axis=-1), -1, 1)))


def _truth_values(src, device, sl):
    """f(i, o) at the true LED and pixel directions of every slice sample."""
    truth = device.truth
    leds = device.leds if truth is None else truth.leds
    optics = device.optics if truth is None else truth.optics
    view = optics.pixel_directions()[0][sl.pixels[:, 0], sl.pixels[:, 1]]
    return np.stack([src.eval(np.broadcast_to(l, view.shape), view) for l in leds])


@pytest.mark.parametrize(
    "optics", [Optics(), Optics(law="tan"), Optics(cx=163.2, cy=116.9, k1=-0.06, k2=0.015, roll_deg=0.7)]
)
def test_pixel_direction_round_trip(optics):
    dirs, mask = optics.pixel_directions()
    uv = optics.pixel_grid()[mask]
    back = optics.direction_to_pixel(dirs[mask])
    assert np.max(np.abs(back - uv)) < 1e-6
    d2 = optics.pixel_to_direction(optics.direction_to_pixel(dirs[mask]))
    assert _angle_deg(d2, dirs[mask]).max() < 0.01
    # the cone is what the design says: axis tilted 20°, half-angle 48.2°
    assert np.isclose(g.cartesian_to_spherical(optics.axis)[0], np.radians(20.0))
    assert _angle_deg(dirs[mask], optics.axis).max() <= 48.216
    assert mask.sum() > 30_000


def test_ideal_slices_equal_the_brdf():
    dev = Device.builtin("ideal")
    cap = simulate_capture(SRC, dev, seed=3)
    sl = extract_slices(cap, nominal_calibration(dev))
    f = _truth_values(SRC, dev, sl)
    assert np.array_equal(sl.view, dev.optics.pixel_directions()[0][sl.pixels[:, 0], sl.pixels[:, 1]])
    ok = sl.valid[..., None] & (f > 0.05 * 2.5)  # above 5 % of the long exposure's full scale
    rel = np.abs(sl.values / f - 1)[ok]
    # only 12-bit quantisation remains: ≤ half a DN of a ≥ 5 %-of-range signal
    assert np.median(rel) < 2e-3 and rel.max() < 0.012
    assert sl.valid.mean() > 0.99


def test_simulation_is_deterministic_and_round_trips(tmp_path):
    dev = Device.builtin("as-built")
    a = simulate_capture(SRC, dev, seed=11, tilt_deg=7.0)
    b = simulate_capture(SRC, dev, seed=11, tilt_deg=7.0)
    c = simulate_capture(SRC, dev, seed=12, tilt_deg=7.0)
    assert np.array_equal(a.raw, b.raw) and not np.array_equal(a.raw, c.raw)
    write_capture(a, tmp_path / "cap")
    r = read_capture(tmp_path / "cap")
    assert np.array_equal(r.raw, a.raw)
    m = json.loads((tmp_path / "cap" / "manifest.json").read_text())
    assert "truth" not in m["device"]  # the pipeline never sees the as-built truth
    assert m["simulation"]["tilt_deg"] == 7.0
    assert not list(tmp_path.glob(".*part*"))


@pytest.fixture(scope="module")
def as_built(tmp_path_factory):
    d = tmp_path_factory.mktemp("calib")
    dev = Device.builtin("as-built")
    simulate_calibration(dev, d / "calib", seed=5)
    cal = calibrate(d / "calib")
    cal.save(d / "cal.npz")
    return dev, cal, d


def test_a_dark_grid_frame_is_named_and_the_others_calibrate(as_built, tmp_path):
    """A grid frame whose point source did not light (all black): a warning names it, and
    the geometry comes from the other grid images as well as before."""
    import shutil
    import warnings

    from reflecto.errors import ReflectoWarning

    dev, cal, d = as_built
    calib = tmp_path / "calib"
    shutil.copytree(d / "calib", calib)
    dark = calib / "grid_2.png"
    cv2.imwrite(str(dark), np.zeros((dev.optics.height, dev.optics.width, 3), np.uint16))
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always")
        again = calibrate(calib)
    named = [w for w in got if issubclass(w.category, ReflectoWarning) and str(dark) in str(w.message)]
    assert len(named) == 1 and "no pinhole spot" in str(named[0].message)
    dt, mt = dev.truth.optics.pixel_directions()
    dc, mc = again.optics.pixel_directions()
    m = mt & mc
    assert np.sqrt(np.mean(_angle_deg(dt[m], dc[m]) ** 2)) < 0.05


def test_an_led_without_a_mirror_image_is_named_and_reported_unmeasured(as_built, tmp_path):
    """calibration.json without LED 3's mirror entry: that LED keeps its design's direction
    (the as-built one is 0.35° off), a warning names it, and the report gives no offset for
    it (it read 0.0°, as if measured)."""
    import warnings

    from reflecto.errors import ReflectoWarning

    dev, cal, d = as_built
    calib = tmp_path / "calib"
    shutil.copytree(d / "calib", calib)
    meta = json.loads((calib / "calibration.json").read_text())
    meta["mirror"] = [m for m in meta["mirror"] if m["led"] != 3]
    (calib / "calibration.json").write_text(json.dumps(meta))
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always")
        again = calibrate(calib)
    named = [w for w in got if issubclass(w.category, ReflectoWarning) and "LEDs [3]" in str(w.message)]
    assert len(named) == 1
    assert again.report["leds_nominal"] == [3] and again.report["led_offset_from_nominal_deg"][3] is None
    assert np.array_equal(again.leds[3], dev.leds[3]) and _angle_deg(again.leds[3], dev.truth.leds[3]) > 0.2
    assert all(e is not None for k, e in enumerate(again.report["led_offset_from_nominal_deg"]) if k != 3)


@pytest.mark.parametrize("k1", [-0.15, -0.2])
def test_a_strong_barrel_distortion_maps_no_sensor_corner_into_the_view_cone(k1):
    """Past the maximum of ρ(1 + k1ρ²) no ray reaches a pixel; Newton wandered there and the
    sine law's clip gave the sensor's corners arbitrary directions inside the cone (up to
    276 px off on the way back). Every pixel of the view disc maps back onto itself."""
    optics = Device.builtin("as-built").optics.replace(k1=k1)
    dirs, mask = optics.pixel_directions()
    rows, cols = np.nonzero(mask)
    back = optics.direction_to_pixel(dirs[mask])
    assert mask.sum() > 20000 and np.abs(back - np.stack([cols, rows], axis=-1)).max() < 1e-6


def test_calibration_recovers_the_as_built_device(as_built):
    dev, cal, d = as_built
    truth = dev.truth
    dt, mt = truth.optics.pixel_directions()
    dc, mc = cal.optics.pixel_directions()
    m = mt & mc
    rms = np.sqrt(np.mean(_angle_deg(dt[m], dc[m]) ** 2))
    assert rms < 0.1, rms
    # the nominal optics would be off by far more than that
    dn, _ = dev.optics.pixel_directions()
    assert np.sqrt(np.mean(_angle_deg(dt[m], dn[m]) ** 2)) > 1.0
    assert _angle_deg(cal.leds, truth.leds).max() < 0.05
    # radiometric field: LED intensity × design irradiance × cos × transmission × gain
    cam = dev.camera
    true_scale = (cam.sensitivity / cam.gain) * (np.asarray(truth.led_intensity) * dev.led_irradiance
                                                 * truth.leds[:, 2])[:, None, None] * truth.transmission_field()[None]
    rel = cal.scale[..., 1][:, m] / true_scale[:, m] - 1
    assert np.sqrt(np.mean(rel**2)) < 0.001, np.sqrt(np.mean(rel**2))  # 0.08 %; a local mean gave 0.15 %
    # the outer 10 px of the view disc (the grazing views): a local mean read them 0.2 % high
    v, u = np.mgrid[0 : m.shape[0], 0 : m.shape[1]]
    radius = np.hypot(u - cal.optics.principal_point[0], v - cal.optics.principal_point[1])[m]
    rim = radius > radius.max() - 10.0
    assert np.abs(rel[:, rim].mean(axis=1)).max() < 5e-4, rel[:, rim].mean(axis=1)
    loaded = Calibration.load(d / "cal.npz")
    assert np.array_equal(loaded.scale, cal.scale) and loaded.optics == cal.optics


def test_a_real_aperture_narrower_than_the_calibrated_disc_calibrates(tmp_path):
    """The as-built device with its true cone 0.2° narrower than the design: a ring of the
    calibrated view disc reads the white standard dark. That ring gets no scale (its
    samples are invalid), the rest is calibrated to the noise of one white exposure, and
    nothing outside the disc makes the field negative (it was refused as a white standard
    reading below its black level)."""
    d = Device.builtin("as-built").to_dict(with_truth=True)
    d["truth"]["optics"]["cone_half_angle_deg"] -= 0.2
    path = tmp_path / "narrow.json"
    path.write_text(json.dumps(d))
    dev = load_device(path)
    simulate_calibration(dev, tmp_path / "calib", seed=5, white_repeats=1)
    cal = calibrate(tmp_path / "calib")
    assert np.all(cal.scale >= 0)
    dt, mt = dev.truth.optics.pixel_directions()
    dc, mc = cal.optics.pixel_directions()
    cut = mc & ~mt  # in the calibrated disc, outside the real aperture
    assert cut.sum() > 100 and not cal.scale[:, cut].any()
    assert not cal.scale[:, ~mc].any()
    m = mt & mc
    cam = dev.camera
    truth = dev.truth
    true_scale = (cam.sensitivity / cam.gain) * (np.asarray(truth.led_intensity) * dev.led_irradiance
                                                 * truth.leds[:, 2])[:, None, None] * truth.transmission_field()[None]
    seen = np.all(cal.scale[..., 1][:, m] > 0, axis=0)
    assert seen.mean() > 0.99
    rel = cal.scale[..., 1][:, m][:, seen] / true_scale[:, m][:, seen] - 1
    assert np.sqrt(np.mean(rel**2)) < 0.003, np.sqrt(np.mean(rel**2))  # 0.2 %: one white exposure's noise


def test_smooth_field_is_exact_for_a_linear_field_up_to_the_disc_rim():
    from scipy import ndimage

    from reflecto.instrument.calibrate import FIELD_SMOOTHING_PX, smooth_field

    v, u = np.mgrid[0:120, 0:160].astype(np.float64)
    disc = np.hypot(u - 80.0, v - 60.0) < 50.0
    field = (1.0 + 0.004 * (u - 80.0) - 0.003 * (v - 60.0))[..., None] * np.array([1.0, 0.5, 2.0])
    got = smooth_field(field, disc, FIELD_SMOOTHING_PX)
    assert np.abs(got[disc] / field[disc] - 1.0).max() < 1e-9
    # a local mean (normalized convolution) reads the rim from inside the disc
    w = disc.astype(np.float64)
    mean = ndimage.gaussian_filter(field[..., 0] * w, FIELD_SMOOTHING_PX) / np.maximum(
        ndimage.gaussian_filter(w, FIELD_SMOOTHING_PX), 1e-12)
    assert np.abs(mean[disc] / field[disc, 0] - 1.0).max() > 5e-3
    assert not got[~ndimage.binary_dilation(disc, iterations=20)].any()  # far outside the disc: 0


def test_as_built_slices_after_calibration_match_ground_truth(as_built):
    dev, cal, _ = as_built
    sl = extract_slices(simulate_capture(SRC, dev, seed=8), cal)
    f = _truth_values(SRC, dev, sl)
    ok = sl.valid[..., None] & (f > 0.05 * 2.5)
    rel = np.abs(sl.values / f - 1)[ok]
    assert np.median(rel) <= 0.02, np.median(rel)
    # without calibration the same capture is far off (vignetting alone is up to 50 %)
    sl0 = extract_slices(simulate_capture(SRC, dev, seed=8), nominal_calibration(dev))
    f0 = _truth_values(SRC, dev, sl0)
    rel0 = np.abs(sl0.values / f0 - 1)[sl0.valid[..., None] & (f0 > 0.125)]
    assert np.median(rel0) > 0.05


def test_gamma_camera_via_debevec(tmp_path):
    dev = Device.builtin("ideal").with_camera(response="gamma", bits=8, black_level=0.0, read_noise=0.0,
                                              shot_noise=False)
    simulate_calibration(dev, tmp_path / "calib", white_repeats=1)
    cal = calibrate(tmp_path / "calib")
    assert cal.response is not None and cal.response.shape == (256, 3)
    sl = extract_slices(simulate_capture(SRC, dev, seed=1), cal)
    f = _truth_values(SRC, dev, sl)
    ok = sl.valid[..., None] & (f > 0.05)
    rel = np.abs(sl.values / f - 1)[ok]
    print("gamma camera: median relative error", np.median(rel), "over", ok.sum())
    assert ok.sum() > 50_000 and np.median(rel) < 0.02


def test_linear_hdr_merge_uses_the_right_exposures():
    cam = Device.builtin("ideal").camera
    raw = np.full((1, 2, 2, 2, 3), cam.black_level, dtype=np.uint16)
    raw[0, 0, 0, 0] = cam.black_level + 100  # 1 ms: 100 DN
    raw[0, 1, 0, 0] = cam.black_level + 800  # 8 ms: 800 DN → both valid, 100 DN/ms
    raw[0, 0, 0, 1] = cam.black_level + 400
    raw[0, 1, 0, 1] = cam.max_value  # long exposure saturated → short only
    raw[0, 0, 1, 0] = cam.max_value
    raw[0, 1, 1, 0] = cam.max_value  # saturated everywhere → invalid
    raw[0, 0, 1, 1] = cam.black_level + 1  # near-black short → the long one decides
    raw[0, 1, 1, 1] = cam.black_level + 16
    rad, valid = merge_linear(raw, np.array([1.0, 8.0]), cam)
    assert np.allclose(rad[0, 0, 0], 100.0) and np.allclose(rad[0, 0, 1], 400.0)
    assert not valid[0, 1, 0] and valid[0, 1, 1] and np.allclose(rad[0, 1, 1], 2.0)


def test_zero_readings_of_an_undithered_camera_are_censored():
    """A noiseless quantizer reads 0 below half a DN and 1 up to 1.5 DN: bounds, not values."""
    from reflecto.instrument.hdr import merge_linear_pixels

    cam = Device.builtin("ideal").camera
    raw = np.full((1, 2, 1, 4, 3), cam.black_level, dtype=np.uint16)  # pixel 0: zero everywhere
    raw[0, 1, 0, 1] = cam.black_level + np.array([0, 1, 0])  # pixel 1: 1 DN in G, long exposure
    raw[0, 1, 0, 2] = cam.black_level + np.array([0, 2, 1])  # pixel 2: 2 DN in G: a measurement
    raw[0, 0, 0, 3], raw[0, 1, 0, 3] = cam.black_level + 50, cam.black_level + 400  # pixel 3: bright
    rad, valid, black = merge_linear_pixels(raw, np.array([1.0, 8.0]), cam, np.zeros(4, np.intp), np.arange(4))
    assert valid.all() and black.tolist() == [[True, True, False, False]]
    assert np.allclose(rad[0, 1], [0.0, 1 / 8, 0.0]) and np.allclose(rad[0, 2], [0.0, 2 / 8, 1 / 8])
    assert np.allclose(rad[0, 0], 0.0)
    src = AnalyticBRDF(distribution="ggx", alpha=0.05, kd=0.0, ks=0.8, eta=1.5)
    for name, censored in (("ideal", True), ("as-built", False)):  # as-built: 3 e⁻ ≈ 0.6 DN read noise dithers
        dev = Device.builtin(name)
        sl = extract_slices(simulate_capture(src, dev, seed=1), nominal_calibration(dev))
        assert (sl.censored is not None) == censored
        if censored:  # the grazing tails of a k_d = 0 lobe read 0 or 1 DN
            v = sl.values[sl.censored]
            assert 0.05 < sl.censored.mean() < 0.95 and np.any(v == 0.0) and np.any(v > 0.0)
            assert v.max() < 1e-3 * sl.values[sl.valid].max()


def test_default_layout_coverage_and_constraints():
    dev = Device.builtin("ideal")
    assert layout.layout_violations(dev.optics, dev.leds) == []
    assert np.allclose(layout.led_angles(dev.leds[0]), [5.0, 0.0])
    cov = layout.coverage(dev.optics, dev.leds)
    assert cov.every_led_overlaps
    assert cov.after_tau > 0.80 and cov.after_tau >= 0.9 * cov.upper_bound_after_tau
    # the design's other goals: overlaps at different θ_d all over the central cap
    # (η of sharp lobes) and a share of near-normal incidence (layout.layout_terms)
    from reflecto.hemicube import hemicube

    _, central, small_td = layout.layout_terms(dev.optics, dev.leds, hemicube(64))
    assert central == 1.0 and small_td > 0.2
    # the geometry's own limit: no layout reaches 97 % with a 48.2° cone tilted 20°
    assert 0.85 < cov.upper_bound_after_tau < 0.90
    # every overlap pairs samples at different θ_d (needed for Fresnel, §5.1)
    spread = cov.theta_d_spread_deg[cov.overlap > 0]
    assert np.all(np.nan_to_num(spread[~np.isnan(spread)]) > 5.0)
    # a wider (aplanatic, sine-law) cone makes 97 % reachable
    assert layout.coverage(Optics(cone_half_angle_deg=60.0), dev.leds[:1]).upper_bound_after_tau > 0.97


def test_optimizer_respects_constraints():
    o = Optics()
    leds = layout.optimize_layout(o, resolution=16, maxiter=3)
    assert layout.layout_violations(o, leds) == []
    assert np.allclose(leds[0], layout.led_direction(5.0, 0.0))
    cosines = leds @ leds.T
    np.fill_diagonal(cosines, -1.0)
    assert np.degrees(np.arccos(cosines.max())) >= 12.0  # min_separation_deg
    # it optimizes: its weighted goals beat every legal layout among 400 random draws of the
    # same free LEDs (only a few are legal; the best scored 0.99 against the optimum's 1.16),
    # and come within 3 % of the paper's hand-placed layout (1.17 at this resolution)
    from reflecto.hemicube import hemicube

    goals = layout.LayoutObjective(o, hemicube(16))
    weights = np.array(layout.LAYOUT_WEIGHTS)

    def score(x):
        return float(weights @ np.array(goals.terms(x)[:3]))

    rng = np.random.default_rng(1)
    drawn = [np.concatenate([leds[:1], layout.led_direction(rng.uniform(layout.MIN_ELEVATION_DEG, 80.0, 5),
                                                            rng.uniform(0.0, 360.0, 5))]) for _ in range(400)]
    legal = [score(x) for x in drawn if not layout.layout_violations(o, x)]
    assert legal and score(leds) >= max(legal) + 0.1, (score(leds), sorted(legal))
    assert score(leds) >= 0.97 * score(Device.builtin("ideal").leds)
    with pytest.raises(ParameterError, match="inside the view cone"):
        Device("bad", o, ((5.0, 0.0), (80.0, 0.0)), Device.builtin("ideal").camera)


# ------------------------------------------------------------------ bad input
@pytest.fixture()
def capture_dir(tmp_path):
    write_capture(simulate_capture(SRC, Device.builtin("ideal"), seed=2), tmp_path / "cap")
    return tmp_path / "cap"


def _edit_manifest(d, fn):
    m = json.loads((d / "manifest.json").read_text())
    fn(m)
    (d / "manifest.json").write_text(json.dumps(m))


@pytest.mark.parametrize(
    "damage, message",
    [
        (lambda d: (d / "led3_t8ms.png").unlink(), "frame is missing"),
        (lambda d: cv2.imwrite(str(d / "led2_t1ms.png"), np.zeros((120, 160, 3), np.uint16)), "160×120"),
        (lambda d: _edit_manifest(d, lambda m: m["frames"].pop()), "missing from the manifest"),
        (lambda d: _edit_manifest(d, lambda m: m["frames"].append(dict(m["frames"][0]))), "listed twice"),
        (lambda d: _edit_manifest(d, lambda m: m["frames"][1].update(file=m["frames"][0]["file"])),
         "is named for two frames"),
        (lambda d: cv2.imwrite(str(d / "led3_t1ms.png"), np.full((240, 320, 3), 4096, np.uint16)),
         "pixel values up to 4096, above the 12-bit camera's 4095"),
        (lambda d: _edit_manifest(d, lambda m: m["image"].update(width=640)), "does not match"),
        (lambda d: _edit_manifest(d, lambda m: (m["device"]["leds"].pop(), m["device"].pop("firing_order", None),
                                                m["device"].update(check_leds=[0]))),
         "not part of the device"),
        (lambda d: [cv2.imwrite(str(d / f"led4_t{t}ms.png"), np.full((240, 320, 3), 4095, np.uint16)) for t in (1, 8)],
         "saturated"),
        (lambda d: (d / "manifest.json").write_text("{not json"), "not valid JSON"),
        (lambda d: (d / "led5_t8ms_check.png").unlink(), "frame is missing"),
        (lambda d: _edit_manifest(d, lambda m: m["frames"].pop()), "check frame of LED 5 at 8 ms"),
        (lambda d: _edit_manifest(d, lambda m: m["frames"].append({**m["frames"][2], "check": True})),
         "check frame for LED 1 at 1 ms is not part of the device"),
        (lambda d: _edit_manifest(d, lambda m: m["device"].update(check_leds=[0, 9])), "check_leds"),
        # times the camera's auto-exposure could not have taken: longer, or another ratio
        (lambda d: _edit_manifest(d, lambda m: [f.update(exposure_ms=2 * f["exposure_ms"]) for f in m["frames"]]),
         "not the camera's"),
        (lambda d: _edit_manifest(d, lambda m: [f.update(exposure_ms=11.0) for f in m["frames"]
                                                if f["exposure_ms"] == 8.0]), "not the camera's"),
        # one LED's long exposure replaced by its short one: caught at that LED, not only at the first
        (lambda d: shutil.copyfile(d / "led3_t1ms.png", d / "led3_t8ms.png"), "LED 3: its 1 ms and 8 ms frames"),
        (lambda d: shutil.copyfile(d / "led2_t1ms.png", d / "led2_t8ms.png"), "LED 2: its 1 ms and 8 ms frames"),
        (lambda d: _edit_manifest(d, lambda m: m.update(kind="Sample")), "'kind' must be one of"),
        (lambda d: [cv2.imwrite(str(d / f"led2_t{t}ms.png"), np.zeros((240, 320, 3), np.uint16)) for t in (1, 8)],
         "reads below the camera's black level"),
    ],
)
def test_bad_captures_are_refused(capture_dir, damage, message, tmp_path, capsys):
    damage(capture_dir)
    with pytest.raises((CaptureError, FileFormatError), match=message):
        read_capture(capture_dir)


def test_cli_simulate_calibrate_and_errors(tmp_path, capsys):
    src = tmp_path / "s.json"
    src.write_text('{"type": "analytic", "distribution": "beckmann", "alpha": 0.3, "kd": 0.2, "ks": 0.5}')
    assert main(["simulate", str(src), "--device", "as-built", "--tilt", "5", "-o", str(tmp_path / "c"), "-q"]) == 0
    # 6 LEDs × 2 exposures, and the check frames of LED 5 (fired first) fired again at the end
    assert len(list((tmp_path / "c").glob("*.png"))) == 14
    assert (sorted(p.name for p in (tmp_path / "c").glob("*_check.png"))
            == ["led5_t1ms_check.png", "led5_t8ms_check.png"])
    assert main(["simulate", str(src), "--tilt", "45", "-o", str(tmp_path / "t")]) == 1
    assert "tilt" in capsys.readouterr().err and not (tmp_path / "t").exists()
    assert main(["simulate", str(src), "--device", str(tmp_path / "nodev.toml"), "-o", str(tmp_path / "u")]) == 1
    assert "no such device file" in capsys.readouterr().err
    assert main(["layout", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["coverage"]["every_led_overlaps"]
    assert main(["calibrate", str(tmp_path / "c"), "-o", str(tmp_path / "x.npz")]) == 1
    # a capture folder is not a calibration folder: the kind check says so first
    assert "c is a capture folder (manifest.json and frames); calibrate needs a calibration folder" in \
        capsys.readouterr().err and not (tmp_path / "x.npz").exists()
    assert not list(tmp_path.glob(".*part*"))


def test_device_files(tmp_path):
    p = tmp_path / "d.toml"
    p.write_text('name = "mine"\nleds = [[5.0, 0.0], [10.0, 120.0], [10.0, 240.0]]\n[optics]\naxis_tilt_deg = 15.0\n'
                 '[camera]\nbits = 14\nexposures_ms = [0.5, 4.0]\n')
    dev = load_device(p)
    assert dev.n_leds == 3 and dev.camera.exposures_ms == (0.5, 4.0) and dev.optics.axis_tilt_deg == 15.0
    p.write_text('name = "mine"\n[optics]\nfocal = 3\n')
    with pytest.raises(FileFormatError, match="unknown keys"):
        load_device(p)
    back = Device.from_dict(Device.builtin("as-built").to_dict(with_truth=True))
    assert back.truth == Device.builtin("as-built").truth
    assert back.firing_order == Device.builtin("as-built").firing_order == (5, 0, 1, 3, 4, 2)
    p.write_text('leds = [[5.0, 0.0], [10.0, 120.0], [10.0, 240.0]]\nfiring_order = [2, 0, 1]\n')
    assert load_device(p).order == (2, 0, 1)
    for bad in ("[0, 1]", "[0, 1, 1]", "[0, 1, 3]", '"abc"'):
        p.write_text(f'leds = [[5.0, 0.0], [10.0, 120.0], [10.0, 240.0]]\nfiring_order = {bad}\n')
        with pytest.raises((FileFormatError, ParameterError), match="firing_order"):
            load_device(p)
    shutil.rmtree(tmp_path)


def test_check_frames_round_trip_and_older_captures_without_them(tmp_path):
    dev = Device.builtin("as-built")
    cap = simulate_capture(SRC, dev, seed=4, shake=True)
    assert cap.check.shape == (1,) + cap.raw.shape[1:]
    back = read_capture(write_capture(cap, tmp_path / "cap"))
    assert np.array_equal(back.check, cap.check) and np.array_equal(back.raw, cap.raw)
    assert back.device.check_leds == (5,)
    # a capture written by a device without check frames reads, and gives the same
    # slices as the same sequence with them
    plain = dataclasses.replace(dev, check_leds=())
    old = simulate_capture(SRC, plain, seed=4, shake=True)
    assert old.check is None and np.array_equal(old.raw, cap.raw)  # the check frames draw their noise last
    m = tmp_path / "old" / "manifest.json"
    write_capture(old, tmp_path / "old")
    assert "check_leds" not in json.loads(m.read_text())["device"]
    assert read_capture(tmp_path / "old").check is None
    sl = extract_slices(read_capture(tmp_path / "old"), nominal_calibration(plain))
    assert sl.check_leds == () and sl.check_values is None
    # a sample capture of a device with check frames cannot be written without them
    with pytest.raises(Exception, match="check frames"):
        write_capture(dataclasses.replace(cap, check=None), tmp_path / "bad")
    assert not (tmp_path / "bad").exists()
    # reframing carries the check slice with its LED's cos θ_i correction
    s1 = extract_slices(cap, nominal_calibration(dev))
    tilted = s1.reframe(g.frame_from_normal(g.normalize(np.array([0.05, 0.0, 1.0])), np.array([1.0, 0.0, 0.0])))
    k = dev.check_leds[0]
    ratio = tilted.values[k] / np.where(s1.values[k] > 0, s1.values[k], np.nan)
    ratio_check = tilted.check_values[0] / np.where(s1.check_values[0] > 0, s1.check_values[0], np.nan)
    assert np.nanmax(np.abs(ratio - ratio_check)) < 1e-12
    with pytest.raises(ParameterError, match="check_leds"):
        dataclasses.replace(dev, check_leds=(0, 0))


def test_shake_moves_the_leds_fired_after_it():
    # the slices of the LEDs fired before the shake equal a clean capture's; the later ones do not
    for order in ((0, 1, 2, 3, 4, 5), (0, 1, 3, 5, 4, 2)):
        dev = dataclasses.replace(Device.builtin("ideal"), firing_order=order)
        for seed in (0, 1, 2):
            clean = extract_slices(simulate_capture(SRC, dev, seed=seed), nominal_calibration(dev))
            cap = simulate_capture(SRC, dev, seed=seed, shake=True)
            info = cap.extra["simulation"]["shake"]
            assert (info["moved_leds"] == sorted(order[info["from_position"]:])
                    and info["from_led"] == order[info["from_position"]])
            shaken = extract_slices(cap, nominal_calibration(dev))
            for k in range(dev.n_leds):
                same = np.array_equal(shaken.values[k], clean.values[k])
                assert same == (k not in info["moved_leds"]), (order, seed, k)


def test_a_pixel_footprint_and_blur_spread_a_sharp_peak_and_keep_its_energy():
    """``footprint`` and ``blur_px``: a Lambertian slice is the same (the mean of a constant);
    a lobe narrower than a pixel reads a lower peak, spread over more pixels, with the
    slice's sum of values (its energy on the image plane) kept within 2 %."""
    dev = Device.builtin("ideal")
    cal = nominal_calibration(dev)
    flat = AnalyticBRDF(distribution="ggx", alpha=0.5, kd=0.6, ks=0.0)
    point = extract_slices(simulate_capture(flat, dev, seed=1), cal).values
    assert np.array_equal(point, extract_slices(simulate_capture(flat, dev, seed=1, footprint=2), cal).values)
    sharp = AnalyticBRDF(distribution="ggx", alpha=0.02, kd=0.0, ks=0.8, eta=1.8)
    a = extract_slices(simulate_capture(sharp, dev, tilt_deg=0.05, tilt_azimuth_deg=40.0, seed=2), cal).values
    b = extract_slices(simulate_capture(sharp, dev, tilt_deg=0.05, tilt_azimuth_deg=40.0, seed=2, footprint=2,
                                        blur_px=1.0), cal).values
    k = int(np.argmax(a[..., 1].max(axis=1)))
    assert b[k, :, 1].max() < 0.8 * a[k, :, 1].max()
    assert abs(b[k, :, 1].sum() / a[k, :, 1].sum() - 1.0) < 0.02
    for bad in ({"footprint": 0}, {"footprint": 2.0}, {"blur_px": -1.0}, {"blur_px": float("nan")}):
        with pytest.raises(ParameterError):
            simulate_capture(flat, dev, **bad)


def test_calibration_folders_must_be_consistent(as_built, tmp_path):
    """A calibration folder whose white capture is another device's, whose grid names one image
    for several positions, or (a gamma camera) whose response sweep lacks its times is refused,
    naming the problem, instead of giving a wrong calibration."""
    dev, _, d = as_built
    other = tmp_path / "earlier"
    simulate_calibration(Device.builtin("earlier"), other, seed=5)
    mixed = tmp_path / "mixed"
    shutil.copytree(d / "calib", mixed)
    shutil.rmtree(mixed / "white")
    shutil.copytree(other / "white", mixed / "white")
    with pytest.raises(CaptureError, match="the white capture's device is not calibration.json's"):
        calibrate(mixed)
    same = tmp_path / "same"
    shutil.copytree(d / "calib", same)
    _edit_calibration = json.loads((same / "calibration.json").read_text())
    for e in _edit_calibration["grid"]:
        e["file"] = "grid_0.png"
    (same / "calibration.json").write_text(json.dumps(_edit_calibration))
    with pytest.raises(FileFormatError, match="is named for two images"):
        calibrate(same)
    gamma = Device.from_dict({"name": "g", "camera": {"bits": 8, "response": "gamma", "black_level": 0.0,
                                                    "exposures_ms": [1.0, 8.0]}})
    simulate_calibration(gamma, tmp_path / "gamma", seed=2)
    meta = json.loads((tmp_path / "gamma" / "calibration.json").read_text())
    for e in meta["response"]:
        e.pop("exposure_ms")
    (tmp_path / "gamma" / "calibration.json").write_text(json.dumps(meta))
    with pytest.raises(FileFormatError, match="exposure_ms is missing"):
        calibrate(tmp_path / "gamma")


def test_a_white_standard_auto_exposed_records_its_times(tmp_path):
    """A camera sensitive enough that auto-exposure shortens the white frames: the white
    capture's manifest gives the times the frames were taken with, and the calibration's
    scale is the nominal one (it was the shortening factor off)."""
    dev = Device.from_dict({"name": "bright", "camera": {"sensitivity": 100000.0}})
    simulate_calibration(dev, tmp_path / "calib", seed=3)
    white = read_capture(tmp_path / "calib" / "white")
    assert white.exposures_ms[0] < 0.9 * dev.camera.exposures_ms[0]
    cal = calibrate(tmp_path / "calib")
    nominal = nominal_calibration(dev)
    rows, cols = dev.optics.view_pixels()
    ratio = np.median(cal.scale[:, rows, cols] / nominal.scale[:, rows, cols])
    assert 0.9 < ratio < 1.1, ratio


def test_device_files_that_cannot_take_a_capture_are_refused(tmp_path):
    """A device whose imperfections change its sensor's size, or whose sensor has no pixel in
    the view cone, is refused; exposure times that %g writes alike still give one file per frame."""
    with pytest.raises(ParameterError, match="the sensor is 640×480"):
        Device.from_dict({**Device.builtin("as-built").to_dict(with_truth=True),
                          "truth": {**Device.builtin("as-built").to_dict(with_truth=True)["truth"],
                                    "optics": {"width": 640, "height": 480}}})
    with pytest.raises(ParameterError, match="no pixel of the sensor lies in the view cone"):
        Device.from_dict({"optics": {"disc_radius_px": 0.001}})
    dev = Device.from_dict({"name": "close", "camera": {"exposures_ms": [1.0, 1.0000001], "auto_exposure": False}})
    cap = simulate_capture(SRC, dev, seed=1)
    write_capture(cap, tmp_path / "cap")
    assert len(list((tmp_path / "cap").glob("*.png"))) == cap.raw.shape[0] * 2 + 2 * len(dev.check_leds)
    assert np.array_equal(read_capture(tmp_path / "cap").raw, cap.raw)


def test_a_device_file_is_keyed_by_its_contents(tmp_path):
    """Two device files of one name, or one file edited, are two devices: their kept calibrations
    and sweep records are not each other's."""
    from reflecto.workflow import device_key

    a, b = tmp_path / "A", tmp_path / "B"
    a.mkdir()
    b.mkdir()
    (a / "dev.json").write_text(json.dumps({"name": "dev"}))
    (b / "dev.json").write_text(json.dumps({"name": "dev", "occluder_deg": 1.0}))
    assert device_key("as-built") == "as-built"
    ka, kb = device_key(a / "dev.json"), device_key(b / "dev.json")
    assert ka.startswith("dev-") and kb.startswith("dev-") and ka != kb


def test_a_second_reframe_turns_from_the_first_and_keeps_the_values_the_brdf():
    """Slices reframed twice, F₁ then F₂ (given in F₁'s coordinates), equal the capture's
    slices reframed once into ``F₂ F₁``: directions, validity, and values corrected about the
    first frame's normal (the one they are the BRDF for), not the device axis; and those
    values are the analytic BRDF at the new directions (GGX α 0.2 tilted 6°: 0.3 % median
    on the ideal 12-bit camera, against 19 % with the correction taken about the device axis)."""
    src = AnalyticBRDF(distribution="ggx", alpha=0.2, kd=0.1, ks=0.8, eta=1.5)
    dev = Device.builtin("ideal")
    cap = simulate_capture(src, dev, tilt_deg=6.0, tilt_azimuth_deg=0.0, seed=1)
    truth = np.array(cap.extra["simulation"]["normal"])
    sl = extract_slices(cap, nominal_calibration(dev))
    f1 = g.frame_from_normal(g.normalize(np.array([0.03, -0.02, 1.0])), np.array([1.0, 0.0, 0.0]))  # every LED stays up
    # F₂ in F₁'s coordinates: the true normal's frame, as seen from F₁
    f2 = g.frame_from_normal(g.to_local(truth, f1), np.array([1.0, 0.0, 0.0]))
    twice, once = sl.reframe(f1).reframe(f2), sl.reframe(f2 @ f1)
    np.testing.assert_allclose(twice.frame, f2 @ f1, atol=1e-15)
    np.testing.assert_allclose(twice.light, once.light, atol=1e-12)
    np.testing.assert_allclose(twice.view, once.view, atol=1e-12)
    assert np.array_equal(twice.valid, once.valid)
    np.testing.assert_allclose(twice.values[twice.valid], once.values[once.valid], rtol=1e-12)
    assert abs(twice.frame[2] @ truth - 1.0) < 1e-12
    ok = twice.valid & (twice.values[..., 1] > 0.05)
    truth_values = np.stack([src.eval(np.broadcast_to(twice.light[k], twice.view.shape), twice.view)[:, 1]
                             for k in range(twice.n_leds)])
    assert np.median(np.abs(twice.values[..., 1][ok] / truth_values[ok] - 1.0)) < 0.01
