"""Did the sample move during the capture? The shake cues of §5.1, gathered.

* The check frames (:mod:`.repeat`): the device fires its first LED again at the end;
  a changed slice is motion. Model-free, valid for any BRDF.
* Mirror planes (:mod:`.symmetry`): an isotropic material's steep slices are
  symmetric about the plane through their LED and the normal; after a turn, about
  the turned normal.
* Isotropy and reciprocity between LEDs (:mod:`.consistency`).
* The peaks' agreement (:func:`peak_agreement`): a sharp lobe's slices peak at one
  half vector, the lobe's mode; after a turn, the slices fired later peak at the
  turned one. Where the lobe is sharper than the view hemicube's texel, its mirror
  planes are not located, and on a dark floor the check frame and the pairs see little:
  there the peaks tell. The peaks' half vectors need no normal.

The last three hold for isotropic materials only, so they are consulted only when the
material was found (or declared) isotropic; and they judge the slices in the sample
frame, against the sample's normal: the estimated one (§5.4) for a tilted capture.
An error ``δ`` of that normal turns an LED's mirror plane by up to ``δ / sin θ_l``
and changes a pair's log ratio by up to ``δ (tan θ_a + tan θ_b)`` (the ``cos θ_i``
of both slices); each cue's threshold is widened by that at two standard
uncertainties of the normal (:attr:`MotionReport.plane_allowance_deg`,
:func:`.consistency.normal_allowance`), so a steady tilted capture whose normal is
known to ``δ`` is not read as motion. The check frames need no normal and judge
every capture. ``E(η)`` of the hemicube path's Fresnel
fit (§5.1's own cue) enters through :class:`~.hemicube_fit.HemicubeFit`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..instrument.slices import Slices
from .consistency import THRESHOLD as PAIR_THRESHOLD
from .consistency import PairCheck, normal_allowance, pair_checks
from .normal import SlicePeak, slice_peaks
from .repeat import RepeatCheck, repeat_checks
from .symmetry import PLANE_THRESHOLD_DEG, plane_offsets
from .tuning import MOTION

Array = NDArray[np.float64]

__all__ = ["MotionReport", "PeakAgreement", "detect_motion", "peak_agreement", "PEAK_RADIUS_DEG",
           "PEAK_AGREEMENT_DEG"]

#: A slice's peak is compact when its pixels above half its height lie within this of its half vector (degrees) …
PEAK_RADIUS_DEG = MOTION.peak_radius_deg
#: … and two compact peaks further apart than this (degrees) flag a shake.
PEAK_AGREEMENT_DEG = MOTION.peak_agreement_deg


@dataclasses.dataclass(frozen=True)
class PeakAgreement:
    """Whether the slices' compact peaks share one half vector (:func:`peak_agreement`).

    Attributes
    ----------
    leds
        The LEDs whose slice has a compact peak (:data:`PEAK_RADIUS_DEG`).
    spread_deg
        The largest angle between two of their peaks' half vectors (degrees; 0 with
        fewer than two).
    pair
        The two LEDs of that angle, or ``None``.
    """

    leds: tuple[int, ...] = ()
    spread_deg: float = 0.0
    pair: tuple[int, int] | None = None

    @property
    def moved(self) -> bool:
        """The peaks lie further apart than :data:`PEAK_AGREEMENT_DEG`."""
        return self.spread_deg > PEAK_AGREEMENT_DEG


def peak_agreement(peaks: Sequence[SlicePeak]) -> PeakAgreement:
    """The largest angle between the compact peaks' half vectors (:class:`PeakAgreement`).

    A sharp lobe's slice that holds the mirror direction peaks where ``D`` does: at
    ``h = m``, the lobe's mode (the normal, for an isotropic lobe), within the camera's
    half-vector sampling and the lobe's small off-specular shift. Every such slice of
    a steady capture peaks at the same ``m``, whatever the frame; a sample turned by
    ``δ`` between two LEDs' firings moves the later peaks by ``δ``. Only compact peaks
    count (their pixels above half height within :data:`PEAK_RADIUS_DEG` of their
    centroid, :attr:`.normal.SlicePeak.radius_deg`): a slice that misses the mirror
    direction has its maximum on a ridge of the lobe's flank, placed by the slice's
    path, not by ``m``. Broad lobes have no compact peak and the cue is silent.
    """
    compact = [p for p in peaks if p.radius_deg <= PEAK_RADIUS_DEG]
    spread, pair = 0.0, None
    for a in range(len(compact)):
        for b in range(a + 1, len(compact)):
            d = math.degrees(math.acos(min(1.0, max(-1.0, float(compact[a].normal @ compact[b].normal)))))
            if d > spread:
                spread, pair = d, (compact[a].led, compact[b].led)
    return PeakAgreement(tuple(p.led for p in compact), spread, pair)


def agreeing_normals(peaks: Sequence[SlicePeak], agreement: PeakAgreement) -> list[Array]:
    """The half vectors of the compact peaks where they agree: each places the lobe's mode
    (:func:`peak_agreement`) without a model.

    Parameters
    ----------
    peaks
        The slices' peaks (:func:`.normal.slice_peaks`).
    agreement
        Their agreement, :func:`peak_agreement` of ``peaks``.

    Returns
    -------
    list of numpy.ndarray
        Unit vectors (shape ``(3,)``, the peaks' frame), one per compact peak; empty where
        there is none or where they lie further apart than :data:`PEAK_AGREEMENT_DEG` (a turn).
    """
    if not agreement.leds or agreement.moved:
        return []
    return [p.normal for p in peaks if p.led in agreement.leds]


@dataclasses.dataclass
class MotionReport:
    """The shake cues of one capture and their verdict.

    Attributes
    ----------
    repeat_checks
        One per check LED (:class:`.repeat.RepeatCheck`).
    plane_offsets_deg
        Per LED the angle between its slice's mirror plane and the normal, or ``None``
        (not steep enough, plane not located, or the test did not apply).
    pair_checks
        Isotropy and reciprocity comparisons (:class:`.consistency.PairCheck`).
    excluded_leds
        LEDs left out of the fit because they alone explained an inconsistency.
    plane_allowance_deg
        Per LED what the normal's uncertainty adds to :data:`PLANE_THRESHOLD_DEG`
        (module docstring; empty: nothing).
    peaks
        Whether the slices' compact peaks agree (:func:`peak_agreement`), or ``None``
        where the cue did not apply (a material not judged isotropic).
    """

    repeat_checks: list[RepeatCheck] = dataclasses.field(default_factory=list)
    plane_offsets_deg: list[float | None] = dataclasses.field(default_factory=list)
    pair_checks: list[PairCheck] = dataclasses.field(default_factory=list)
    excluded_leds: list[int] = dataclasses.field(default_factory=list)
    plane_allowance_deg: list[float] = dataclasses.field(default_factory=list)
    peaks: PeakAgreement | None = None

    @property
    def moved_leds(self) -> list[int]:
        """Check LEDs whose repeated frame says the sample moved (:class:`.repeat.RepeatCheck`)."""
        return [r.led for r in self.repeat_checks if r.moved]

    @property
    def tilted_planes(self) -> list[int]:
        """LEDs whose slice's mirror plane is off the normal by more than :data:`PLANE_THRESHOLD_DEG`
        (plus the allowance for the normal's uncertainty)."""
        allow = self.plane_allowance_deg or [0.0] * len(self.plane_offsets_deg)
        return [k for k, x in enumerate(self.plane_offsets_deg)
                if x is not None and abs(x) > PLANE_THRESHOLD_DEG + allow[k]]

    @property
    def inconsistent_pairs(self) -> list[PairCheck]:
        """The isotropy and reciprocity comparisons that failed."""
        return [c for c in self.pair_checks if c.inconsistent]

    @property
    def shake_detected(self) -> bool:
        """Whether any cue fired: a moved check LED, a tilted mirror plane, an inconsistent
        pair, peaks that disagree, or an LED excluded from the fit.
        """
        return bool(self.moved_leds or self.tilted_planes or self.inconsistent_pairs
                    or (self.peaks is not None and self.peaks.moved) or self.excluded_leds)

    def describe(self) -> str:
        """One line naming the cues that fired.

        Returns
        -------
        str
            The moved repeat checks, tilted symmetry planes, inconsistent pairs and
            excluded LEDs, ``"; "``-separated; ``""`` when none fired.
        """
        parts = [f"LED {c.led} " + (f"×{math.exp(c.log_ratio):.2f}" if math.isfinite(c.log_ratio) else "lit once")
                 + " between its two firings" for c in self.repeat_checks if c.moved]
        if self.tilted_planes:
            parts.append(f"LEDs {self.tilted_planes} not symmetric about the normal")
        parts += [f"{c.kind} {c.a}-{c.b} ×{math.exp(c.log_ratio):.2f}" for c in self.inconsistent_pairs]
        if self.peaks is not None and self.peaks.moved and self.peaks.pair is not None:
            a, b = self.peaks.pair
            parts.append(f"LEDs {a} and {b} peak {self.peaks.spread_deg:.1f}° apart")
        if self.excluded_leds:
            parts.append(f"LEDs {self.excluded_leds} excluded")
        return "; ".join(parts)

    def to_dict(self) -> dict[str, Any]:
        """The cues and the verdict as JSON-ready data (non-finite numbers as ``None``).

        Returns
        -------
        dict
            ``shake_detected``, ``repeat_checks``, ``symmetry_plane_offsets_deg``,
            ``symmetry_plane_allowance_deg``, ``consistency_checks``, ``peak_spread_deg``
            (with ``peak_leds``, the LEDs with a compact peak, and ``peak_pair``; ``None``
            where the cue did not apply) and ``excluded_leds``.
        """
        def finite(d: dict[str, Any]) -> dict[str, Any]:
            return {k: (v if not isinstance(v, float) or math.isfinite(v) else None) for k, v in d.items()}

        return {"shake_detected": self.shake_detected,
                "repeat_checks": [finite(dataclasses.asdict(r)) for r in self.repeat_checks],
                "symmetry_plane_offsets_deg": self.plane_offsets_deg,
                "symmetry_plane_allowance_deg": self.plane_allowance_deg,
                "consistency_checks": [dataclasses.asdict(c) for c in self.pair_checks],
                "peak_spread_deg": None if self.peaks is None else self.peaks.spread_deg,
                "peak_leds": None if self.peaks is None else list(self.peaks.leds),
                "peak_pair": None if self.peaks is None or self.peaks.pair is None else list(self.peaks.pair),
                "excluded_leds": self.excluded_leds}


#: The cues' thresholds are widened by the normal's error at this many standard uncertainties.
NORMAL_SIGMAS = MOTION.normal_sigmas


def detect_motion(device_frame: Slices, sample_frame: Slices, valid: NDArray[np.bool_],
                  isotropic: bool, normal_uncertainty_deg: float = 0.0,
                  flank_only: Sequence[int] = (), peaks: Sequence[SlicePeak] | None = None) -> MotionReport:
    """Run the cues that apply (see the module docstring).

    ``device_frame`` carries the check frames (compared where they were taken);
    ``sample_frame`` is the same capture in the sample's (estimated) frame, where the
    mirror planes and the pairs are judged; ``valid`` marks the usable samples;
    ``normal_uncertainty_deg`` the standard uncertainty of that frame's normal (0 for
    a known one), which widens the mirror-plane and pair thresholds (module docstring).
    ``flank_only``: LEDs whose slice holds no sample of the peak, only its flank or tail
    (:func:`.normal.peakless_leds`, the peaks a tilt hid among them); their mirror planes
    are not judged. A
    plane located on a flank several half widths from the peak moves by degrees with
    hundredths of a degree of the normal (ideal steel tilted 0.5°, LED 2's nearest view
    3.4 half widths from its mirror direction: 1.6° from the plane through the normal
    0.05° off the truth, 4.0° from the one 0.01° off). ``peaks``: the device frame's
    slice peaks where already found (:func:`.normal.slice_peaks` of ``device_frame``; the
    reconstruction passes those of its usable samples in the device frame, which the
    normal's first estimate took); ``None``: those of ``valid``.

    The peaks' agreement assumes calibrated directions (an LED or view direction off by
    ``δ`` moves its peak's half vector by about ``δ/2``: a device read with its nominal
    calibration where it needs its own can read that as a turn) and a lobe with one sharp
    mode (an NDF with two, judged isotropic, puts different slices' peaks on different
    modes).
    """
    report = MotionReport(repeat_checks=repeat_checks(device_frame))
    if isotropic:
        u = float(normal_uncertainty_deg) if math.isfinite(normal_uncertainty_deg) else 90.0
        light = sample_frame.light
        ok = valid & sample_frame.valid
        meas = ok if sample_frame.censored is None else ok & ~sample_frame.censored
        report.plane_offsets_deg = [None if k in flank_only else x for k, x in
                                    enumerate(plane_offsets(light, sample_frame.view, sample_frame.values, ok))]
        report.plane_allowance_deg = [NORMAL_SIGMAS * u / max(math.sqrt(max(1.0 - float(l[2]) ** 2, 0.0)), 1e-3)
                                      for l in light]
        report.pair_checks = [dataclasses.replace(c, allowance=normal_allowance(light, c.a, c.b, u, NORMAL_SIGMAS))
                              for c in pair_checks(light, sample_frame.view, sample_frame.values, meas,
                                                  sample_frame.noise)]
        report.peaks = peak_agreement(slice_peaks(device_frame, valid) if peaks is None else peaks)
    return report


__all__ += ["PAIR_THRESHOLD", "PLANE_THRESHOLD_DEG"]
