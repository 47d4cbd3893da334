"""The slices' specular peaks: the first estimate of the normal and the peaks' agreement as a shake cue."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from reflecto.instrument.calibrate import nominal_calibration
from reflecto.instrument.device import Device
from reflecto.instrument.simulate import simulate_capture
from reflecto.instrument.slices import extract_slices
from reflecto.reconstruct import reconstruct
from reflecto.reconstruct.motion import PEAK_AGREEMENT_DEG, PEAK_RADIUS_DEG, peak_agreement
from reflecto.reconstruct.normal import SlicePeak, peak_normal, slice_peaks
from reflecto.reconstruct.pipeline import usable_samples
from reflecto.sources.analytic import AnalyticBRDF


def _turned(deg: float, azimuth_deg: float = 0.0) -> np.ndarray:
    t, a = math.radians(deg), math.radians(azimuth_deg)
    return np.array([math.sin(t) * math.cos(a), math.sin(t) * math.sin(a), math.cos(t)])


def test_peak_agreement_takes_the_compact_peaks_only():
    steady = [SlicePeak(2, _turned(0.1), 0.9, 0.2), SlicePeak(5, _turned(0.15, 90), 0.7, 0.3),
              SlicePeak(0, _turned(40.0), 0.1, 25.0)]  # a plateau on a flank: not a peak of the lobe
    agree = peak_agreement(steady)
    assert agree.leds == (2, 5) and not agree.moved
    assert agree.spread_deg == pytest.approx(math.degrees(math.acos(float(_turned(0.1) @ _turned(0.15, 90)))))
    turned = steady + [SlicePeak(8, _turned(3.0, 200.0), 0.5, 0.2)]
    moved = peak_agreement(turned)
    assert moved.moved and 8 in moved.pair and moved.spread_deg > 3.0
    assert not peak_agreement([SlicePeak(2, _turned(0.0), 0.9, PEAK_RADIUS_DEG + 0.1),
                               SlicePeak(5, _turned(5.0), 0.7, 0.2)]).moved  # one compact peak: nothing to compare
    assert peak_agreement([]).spread_deg == 0.0


def test_peak_normal_is_the_steepest_peak():
    src = AnalyticBRDF(distribution="ggx", alpha=0.05, kd=0.05, ks=0.8)
    dev = Device.builtin("wide")
    cap = simulate_capture(src, dev, seed=2, tilt_deg=3.0)
    sl = extract_slices(cap, nominal_calibration(dev))
    peaks = slice_peaks(sl, usable_samples(sl))
    assert len(peaks) >= 2
    steepest = max(peaks, key=lambda p: p.cos_light)
    assert np.array_equal(peak_normal(sl, usable_samples(sl)), steepest.normal)
    truth = np.array(cap.extra["simulation"]["normal"])
    assert math.degrees(math.acos(min(1.0, float(steepest.normal @ truth)))) < 0.5


def test_a_turn_between_the_firings_moves_the_later_peaks():
    """A sharp lobe on a dark floor (GGX α 0.01, k_d 0) tilted 4° on the `wide` device: its
    mirror planes are finer than the view hemicube's texel and its check frame and pairs
    see little. A steady capture's compact peaks agree within a tenth of a degree; a turn
    of 5° after some of the firings puts the later peaks 5° from the earlier ones."""
    dev = Device.builtin("wide")
    cal = nominal_calibration(dev)
    src = AnalyticBRDF(distribution="ggx", alpha=0.01, kd=0.0, ks=0.8)
    steady = reconstruct(extract_slices(simulate_capture(src, dev, seed=3, tilt_deg=4.0), cal))
    assert not steady.shake_detected
    assert len(steady.motion.peaks.leds) >= 2 and steady.motion.peaks.spread_deg < 0.2
    for seed in (0, 1):
        cap = simulate_capture(src, dev, seed=seed, tilt_deg=4.0, shake=True, shake_deg=5.0)
        moved = set(cap.extra["simulation"]["shake"]["moved_leds"])
        res = reconstruct(extract_slices(cap, cal))
        peaks = res.motion.peaks
        assert peaks.moved and res.shake_detected and peaks.spread_deg > PEAK_AGREEMENT_DEG
        assert abs(peaks.spread_deg - 5.0) < 0.5, peaks
        a, b = peaks.pair
        assert (a in moved) != (b in moved), (peaks.pair, moved)  # one fired before the turn, one after
        assert f"LEDs {a} and {b} peak" in res.motion.describe()
        summary = res.motion.to_dict()
        assert summary["peak_spread_deg"] == peaks.spread_deg and summary["peak_pair"] == [a, b]


def test_a_broad_lobe_has_no_compact_peak():
    """GGX α 0.1 on `wide`, tilted 4°: three slices peak, each over 4° across at half
    height, so none is compact and the cue is silent."""
    dev = Device.builtin("wide")
    src = AnalyticBRDF(distribution="ggx", alpha=0.1, kd=0.02, ks=0.8)
    sl = extract_slices(simulate_capture(src, dev, seed=3, tilt_deg=4.0), nominal_calibration(dev))
    peaks = slice_peaks(sl, usable_samples(sl))
    assert len(peaks) >= 2 and all(p.radius_deg > 2.0 * PEAK_RADIUS_DEG for p in peaks)
    res = reconstruct(sl)
    assert res.motion.peaks is not None and res.motion.peaks.leds == () and not res.motion.peaks.moved
    assert not res.shake_detected


def test_the_cue_applies_to_isotropic_materials_only():
    dev = Device.builtin("ideal")
    aniso = AnalyticBRDF(distribution="ggx", alpha=(0.2, 0.05), rotation_deg=120, kd=0.1, ks=0.7, eta=1.5)
    res = reconstruct(extract_slices(simulate_capture(aniso, dev, seed=1), nominal_calibration(dev)))
    assert not res.isotropic and res.motion.peaks is None
    summary = res.motion.to_dict()
    assert summary["peak_spread_deg"] is None and summary["peak_leds"] is None


def test_a_slice_with_a_non_finite_value_has_no_peak():
    dev = Device.builtin("wide")
    src = AnalyticBRDF(distribution="ggx", alpha=0.01, kd=0.0, ks=0.8)
    sl = extract_slices(simulate_capture(src, dev, seed=3, tilt_deg=4.0), nominal_calibration(dev))
    valid = usable_samples(sl)
    leds = [p.led for p in slice_peaks(sl, valid)]
    values = sl.values.copy()
    values[leds[0], np.flatnonzero(valid[leds[0]])[0]] = np.inf
    broken = dataclasses.replace(sl, values=values)
    assert [p.led for p in slice_peaks(broken, valid)] == leds[1:]


def test_the_peaks_are_the_same_whether_or_not_every_sample_is_valid():
    """An LED whose samples are all valid is read without gathering them; masking a fifth
    of the samples far from every peak (below each peak's level) gathers the rest, and the
    peaks stay where they were (the median of the floor moves their level a little)."""
    src = AnalyticBRDF(distribution="ggx", alpha=0.05, kd=0.05, ks=0.8)
    dev = Device.builtin("ideal")
    sl = extract_slices(simulate_capture(src, dev, seed=3, tilt_deg=2.0), nominal_calibration(dev))
    valid = usable_samples(sl)
    whole = slice_peaks(sl, valid)
    assert whole and any(valid[p.led].all() for p in whole)
    far = np.ones(len(sl.view), dtype=bool)
    for p in whole:  # keep every pixel within 10° of a peak's mirror direction
        mirror = 2.0 * (sl.light[p.led] @ p.normal) * p.normal - sl.light[p.led]
        far &= sl.view @ mirror < math.cos(math.radians(10.0))
    drop = far & (np.arange(len(sl.view)) % 5 == 0)
    masked = slice_peaks(sl, valid & ~drop[None, :])
    assert [p.led for p in masked] == [p.led for p in whole]
    for a, b in zip(whole, masked):
        assert math.degrees(math.acos(min(1.0, float(a.normal @ b.normal)))) < 0.01
        assert b.radius_deg == pytest.approx(a.radius_deg, abs=0.05)
