"""Paper §5.5: one BRDF from captures of the same point at several rotations.

For a BRDF that breaks the symmetry of eq. 3 the device is rotated about the sample's
normal and the point captured again at each position (any set of rotations, e.g.
0/90/180/270° or 0/120/240°; each capture's manifest records its ``rotation_deg``).
Then::

    every capture in the sample frame (its rotation; one normal for the set, §5.4)
    bins of all captures on one working hemicube                     samples.py
    partial NDFs at shared texels, against a 1-D fit of capture 1:   eq3.py
        captures consistent with one material?                       capture_consistency
        eq. 3 kept by the captures' own pairs, pooled?               within_captures
    isotropic? (eq. 3 kept and every capture's azimuthal test)       isotropy.py
      yes: the 1-D fit on all captures' samples together             isotropic.py
      no:  the hemicube loop on all captures' bins:                  hemicube_fit.py
           η and k_d from direct overlaps only (no τ pairs, §5.1)
           partial NDFs (eq. 7) merged by eq. 9 without eq. 3's τ mirror
           S from the NDF (eq. 8), k_s ≤ 1 per channel
           the holes no rotation covered: microfacet synthesis       synthesis.py
    the symmetry test of eq. 3 on the merged data, with the model's S, F
    albedo ≤ 1                                                       pipeline.limit_energy_of_the_trend

η, k_d, k_s and S are fitted jointly over all captures: the bins of capture ``c``
carry LED indices ``c·L … c·L + L − 1`` of one set of ``C·L`` lights in the sample
frame, and the loop of :mod:`.hemicube_fit` runs on them unchanged but for the
missing τ.

**Why the 1-D fit for isotropic data.** An isotropic BRDF does not change when the
sample turns about its normal: the captures at several rotations are then repeated
captures of one configuration, and the 1-D NDF of :mod:`.isotropic` fits their
samples together (stacked as ``C·L`` LEDs in one frame). The hemicube path would
throw away what isotropy gives: every ring of half vectors seen from every LED.
So ``Options(isotropic="auto")`` takes the 1-D fit when every capture's azimuthal
test (:mod:`.isotropy`) finds no second harmonic (its conditional fraction,
:func:`_isotropic_for_set`) and the captures' own pairs, pooled, keep eq. 3
(:mod:`.eq3` against the 1-D fit, :func:`within_captures`: an asymmetric
lobe can hide from the second harmonic); ``"no"`` always takes the hemicube.

**The normal of the set.** The rotations turn the sample about its own normal while
the hand holds the device's tilt (as ``reflecto simulate --tilt T --rotation R``):
one device-frame normal for all captures. With ``Options(normal="search")`` it is the normal
in which the captures agree best with each other where they see the same half vector
in the sample frame (:class:`SetDistance`: E(η) of the direct overlaps of all
captures' bins, §5.1 without τ, so an asymmetric NDF does not bias it), searched as
§5.4 does (:func:`.normal.estimate_normal_consistency`). It costs seconds per set, so
under the default ``"auto"`` the set takes the device axis first and runs the search only
where the captures, seen about that axis, do not measure one material
(:class:`CaptureConsistency`): a tilted set turns the sample about a normal that is not
the axis, and its captures then disagree as different samples would (``"device"`` keeps
the axis, a given vector is taken as it is).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .. import geometry
from ..colour import LUM
from ..errors import ParameterError, ReflectoError
from ..fresnel import eta_to_json
from ..hemicube import Hemicube, hemicube
from ..instrument.slices import Slices, check_slices
from ..model import IsotropicMicrofacetBRDF, MicrofacetBRDF
from . import hemicube_fit as hf
from .eq3 import PairRatios, SymmetryTest, pair_ratios, symmetry_from_ratios
from .fresnel_fit import Pairs, fit_fresnel, overlap_pairs
from .isotropic import fit_isotropic
from .isotropy import CONDITIONAL_EXPLAINED, IsotropyTest, azimuthal_test
from .motion import MotionReport, detect_motion
from .normal import MIN_PAIRS, estimate_normal_consistency, tilt_frame
from .pipeline import (
    Options,
    bound_notes,
    checked_options,
    held_tint_notes,
    limit_energy_of_the_trend,
    resolve_normal,
    usable_samples,
)
from .samples import Bins, bin_samples, kd_bound
from .synthesis import SynthesisFill, SynthesisOptions
from .tuning import ASYMMETRIC

Array = NDArray[np.float64]

__all__ = ["RotatedCapture", "AsymmetricReconstruction", "CaptureConsistency", "reconstruct_rotations",
           "check_rotations", "sample_frames", "capture_consistency", "SetDistance"]

# Tuned numbers: what, units and provenance are in :mod:`.tuning` (asymmetric stage).
DUPLICATE_DEG = ASYMMETRIC.duplicate_deg
MIN_CAPTURES = ASYMMETRIC.min_captures
INCONSISTENT_LEVEL = ASYMMETRIC.inconsistent_level
INCONSISTENT_RATIO = ASYMMETRIC.inconsistent_ratio
INCONSISTENT_MIN = ASYMMETRIC.inconsistent_min
INCONSISTENT_LEVEL_WITH_SHAPE = ASYMMETRIC.inconsistent_level_with_shape
MIN_CROSS_PAIRS = ASYMMETRIC.min_cross_pairs


@dataclasses.dataclass(frozen=True)
class RotatedCapture:
    """One capture of the set: its slices (device frame), its rotation and a name for messages."""

    slices: Slices
    rotation_deg: float
    name: str = "<capture>"


def check_rotations(captures: Sequence[RotatedCapture]) -> None:
    """Refuse a set that §5.5 cannot use: fewer than :data:`MIN_CAPTURES`, two captures
    at the same rotation (within :data:`DUPLICATE_DEG`), or captures of different LED
    counts or view sets. Raises :class:`~reflecto.errors.ReflectoError` naming the capture."""
    if len(captures) < MIN_CAPTURES:
        where = captures[0].name if captures else "<no capture>"
        raise ReflectoError(f"{where}: the asymmetric reconstruction (§5.5) needs captures of the same point at "
                            f"{MIN_CAPTURES} or more rotations; got {len(captures)}")
    first = captures[0]
    for k, c in enumerate(captures):
        if not math.isfinite(c.rotation_deg):
            raise ReflectoError(f"{c.name}: rotation {c.rotation_deg} is not a finite angle")
        check_slices(c.slices, c.name)
        if c.slices.n_leds != first.slices.n_leds or c.slices.view.shape != first.slices.view.shape:
            raise ReflectoError(f"{c.name}: captured with another device than {first.name} "
                                f"({c.slices.n_leds} LEDs, {len(c.slices.view)} views against "
                                f"{first.slices.n_leds}, {len(first.slices.view)})")
        for other in captures[:k]:
            gap = abs((c.rotation_deg - other.rotation_deg + 180.0) % 360.0 - 180.0)
            if gap < DUPLICATE_DEG:
                raise ReflectoError(f"{c.name}: rotation {c.rotation_deg:g}° duplicates that of {other.name} "
                                    f"({other.rotation_deg:g}°); each capture of the set needs its own rotation")


def sample_frames(rotations_deg: Sequence[float], normal: Array | None = None) -> Array:
    """Rows ``(t, b, n)`` of each capture's sample frame in device coordinates, shape ``(C, 3, 3)``:
    the normal (device ``+z`` by default) and the tangent at azimuth ``rotation_deg``."""
    n = np.array([0.0, 0.0, 1.0]) if normal is None else np.asarray(normal, dtype=np.float64)
    return np.stack([geometry.frame_from_normal(
                         n, np.array([math.cos(math.radians(r)), math.sin(math.radians(r)), 0.0]))
                     for r in rotations_deg])


@dataclasses.dataclass
class _SetBins:
    """All captures' bins on one working hemicube, in the sample frame, LED indices offset per capture."""

    cube: Hemicube
    bins: Bins
    light: Array
    per_led: Array
    censored_fraction: float
    n_leds: int


def _measured(sl: Slices, ok: NDArray[np.bool_]) -> NDArray[np.bool_]:
    return ok if sl.censored is None else ok & ~sl.censored


def _concatenate(parts: list[Bins], cube: Hemicube, leds_per_capture: int) -> Bins:
    """One :class:`Bins` of several captures' bins, capture ``c``'s LEDs offset by ``c·L`` (sorted by LED, texel)."""
    cat = (lambda name: np.concatenate([getattr(b, name) for b in parts]))
    led = np.concatenate([b.led + c * leds_per_capture for c, b in enumerate(parts)])
    variance = cat("variance") if all(b.variance is not None for b in parts) else None
    return Bins(cube, led, cat("texel"), cat("texel_tau"), cat("count"), cat("i"), cat("o"), cat("h"), cat("f"),
                cat("cos_d"), variance)


def set_bins(sls: Sequence[Slices], oks: Sequence[NDArray[np.bool_]], work_resolution: int | None) -> _SetBins:
    """Bins of the captures (each already in the sample frame) at the working resolution
    (:func:`.hemicube_fit.auto_work_resolution` on the set when not given)."""
    n_l = sls[0].n_leds
    cube = hemicube(work_resolution or 128)

    def binned(c: Hemicube) -> Bins:
        return _concatenate([bin_samples(s.light, s.view, s.values, _measured(s, ok), c, s.noise)
                             for s, ok in zip(sls, oks)],
                            c, n_l)

    bins = binned(cube)
    if work_resolution is None:
        n = hf.auto_work_resolution(bins)
        if n != cube.n:
            cube = hemicube(n)
            bins = binned(cube)
    per_led = np.concatenate([_measured(s, ok).sum(axis=1) for s, ok in zip(sls, oks)]).astype(np.float64)
    n_ok = sum(float(ok.sum()) for ok in oks)
    censored = 1.0 - float(per_led.sum()) / max(n_ok, 1.0)
    return _SetBins(cube, bins, np.concatenate([s.light for s in sls]), per_led, censored, n_l)


@dataclasses.dataclass(frozen=True)
class CaptureConsistency:
    """Do the captures measure one material? Partial NDFs compared at shared sample-frame texels.

    ``cross_rms[a, b]`` is the pixel-weighted RMS log ratio ``log D̂_a − log D̂_b`` of the
    partial NDFs (eq. 7) of captures ``a`` and ``b`` at the texels both see, and
    ``cross_mean[a, b]`` its weighted mean (antisymmetric; NaN with fewer than
    :data:`MIN_CROSS_PAIRS` pairs); ``within_rms`` the RMS between LEDs of one capture,
    the least over the captures (NaN when no capture has :data:`MIN_CROSS_PAIRS` such
    pairs). ``worst`` is the pair of captures that differ most (level first, then shape).
    Inconsistent when some pair differs in level by :data:`INCONSISTENT_LEVEL`, or in
    shape as :data:`INCONSISTENT_RATIO` says (with a smaller level offset as well).
    """

    cross_rms: Array
    cross_mean: Array
    within_rms: float
    worst: tuple[int, int] | None

    def ratio(self, a: int, b: int) -> float:
        """``cross_rms[a, b]`` over the within-capture RMS (NaN without one)."""
        if not math.isfinite(self.within_rms):
            return math.nan
        return float(self.cross_rms[a, b]) / max(self.within_rms, 0.01)

    def breaks(self, a: int, b: int) -> bool:
        """Do captures ``a`` and ``b`` measure different materials (class docstring)?"""
        level = abs(float(self.cross_mean[a, b]))
        if not math.isfinite(level):
            return False
        if level >= INCONSISTENT_LEVEL:
            return True
        q = self.ratio(a, b)
        return (math.isfinite(q) and q >= INCONSISTENT_RATIO and self.cross_rms[a, b] >= INCONSISTENT_MIN
                and level >= INCONSISTENT_LEVEL_WITH_SHAPE)

    @property
    def worst_ratio(self) -> float:
        """Shape difference of the worst pair of captures over the within-capture spread (0 without one)."""
        if self.worst is None:
            return 0.0
        q = self.ratio(*self.worst)
        return q if math.isfinite(q) else 0.0

    @property
    def worst_level(self) -> float:
        """|mean log offset| of the worst pair's partial NDFs at shared half vectors (0 without one)."""
        return 0.0 if self.worst is None else abs(float(self.cross_mean[self.worst]))

    @property
    def consistent(self) -> bool:
        """Whether the captures can show one sample (no pair breaks the level or shape test)."""
        return self.worst is None or not self.breaks(*self.worst)

    def to_dict(self) -> dict[str, Any]:
        """The test as JSON-ready numbers (non-finite entries as ``None``).

        Returns
        -------
        dict
            ``cross_rms``, ``cross_mean`` (matrices over capture pairs), ``within_rms``,
            ``worst_pair``, ``worst_ratio``, ``worst_level`` and ``consistent``.
        """
        fin = (lambda m: [[None if not math.isfinite(x) else float(x) for x in row] for row in m])
        return {"cross_rms": fin(self.cross_rms), "cross_mean": fin(self.cross_mean),
                "within_rms": self.within_rms if math.isfinite(self.within_rms) else None,
                "worst_pair": list(self.worst) if self.worst else None, "worst_ratio": self.worst_ratio,
                "worst_level": self.worst_level, "consistent": self.consistent}


def capture_consistency(sb: _SetBins, ratios: PairRatios) -> CaptureConsistency:
    """:class:`CaptureConsistency` of the set's bins from their lobe's pair log ratios
    (:func:`.eq3.pair_ratios`; direct overlaps only)."""
    n_c = len(sb.per_led) // sb.n_leds
    cross, mean = np.full((n_c, n_c), np.nan), np.full((n_c, n_c), np.nan)
    direct = ~ratios.symmetric
    ell, w = ratios.ell[direct], ratios.w[direct]
    ca, cb = sb.bins.led[ratios.p[direct]] // sb.n_leds, sb.bins.led[ratios.q[direct]] // sb.n_leds
    # the least spread of one capture's own pairs: a capture of another material has a
    # large one against the reference (a 1-D fit of the first capture), which a pooled
    # value would let hide the difference between captures
    own = [float(math.sqrt(np.sum(w[m] * ell[m] ** 2) / np.sum(w[m])))
           for m in ((ca == c) & (cb == c) for c in range(n_c))
           if np.count_nonzero(m) >= MIN_CROSS_PAIRS]
    within = min(own) if own else math.nan
    for a in range(n_c):
        for b in range(a + 1, n_c):
            m = ((ca == a) & (cb == b)) | ((ca == b) & (cb == a))
            if np.count_nonzero(m) < MIN_CROSS_PAIRS:
                continue
            sign = np.where(ca[m] == a, 1.0, -1.0)  # ℓ as log D̂_a − log D̂_b
            cross[a, b] = cross[b, a] = math.sqrt(float(np.sum(w[m] * ell[m] ** 2) / np.sum(w[m])))
            mean[a, b] = float(np.sum(w[m] * sign * ell[m]) / np.sum(w[m]))
            mean[b, a] = -mean[a, b]
    out = CaptureConsistency(cross, mean, within, None)
    pairs = [(a, b) for a in range(n_c) for b in range(a + 1, n_c) if math.isfinite(cross[a, b])]
    if not pairs:
        return out
    worst = max(pairs, key=lambda ab: (out.breaks(*ab), abs(mean[ab]), cross[ab]))
    return dataclasses.replace(out, worst=worst)


def within_captures(ratios: PairRatios, sb: _SetBins) -> PairRatios:
    """The pairs of ``ratios`` whose two bins come from one capture: the set's eq. 3 test
    pools the captures' own τ and direct pairs. Pairs across captures also differ by
    what differs between the captures (the as-built device's optics, a normal a little
    off), which enters the direct pairs as much as the τ pairs and would hide an
    asymmetry behind it; a capture's own pairs share its errors."""
    same = sb.bins.led[ratios.p] // sb.n_leds == sb.bins.led[ratios.q] // sb.n_leds
    return PairRatios(ratios.p[same], ratios.q[same], ratios.symmetric[same], ratios.ell[same], ratios.w[same])


def stack_isotropic(sls: Sequence[Slices], oks: Sequence[NDArray[np.bool_]]) -> tuple[Slices, NDArray[np.bool_]]:
    """The captures as one capture of ``C·L`` LEDs (same views): exact for an isotropic
    BRDF, which a rotation about the normal does not change. The slices must share
    one frame (the set's normal, any tangent)."""
    first = sls[0]
    cat = (lambda xs: None if any(x is None for x in xs) else np.concatenate(xs))
    light = np.concatenate([s.light for s in sls])
    st = Slices(light, first.view, np.concatenate([s.values for s in sls]), np.concatenate([s.valid for s in sls]),
                first.pixels, first.frame, cat([s.censored for s in sls]), cat([s.noise for s in sls]),
                cat([s.limit for s in sls]))
    return st, np.concatenate(list(oks))


class SetDistance:
    """E(η) of all captures' direct overlaps in the sample frames a candidate normal gives.

    For a candidate device-frame normal ``normalize(tx, ty, 1)`` every capture is turned
    into its sample frame (the normal, its rotation's tangent), binned on one hemicube
    and fitted by §5.1's consistency without τ pairs (:func:`.fresnel_fit.fit_fresnel`);
    at the true normal the captures see one NDF at every shared half vector, away from
    it each capture's frame is off in another direction. ``shadowing`` (callable on
    ``(M, 3)``) divides S out; ``stride`` thins the pixels.
    """

    def __init__(self, captures: Sequence[RotatedCapture], valids: Sequence[NDArray[np.bool_]], shadowing,
                 n: int = 64, stride: int = 1, kd_bound_max_deg: float = 75.0) -> None:
        self.captures = []
        for c, ok in zip(captures, valids):
            s = c.slices
            px = np.arange(0, s.view.shape[0], stride)
            self.captures.append((Slices(s.light, s.view[px], s.values[:, px], s.valid[:, px] & ok[:, px], s.pixels[px],
                                         s.frame), c.rotation_deg))
        self.shadowing = shadowing
        self.cube = hemicube(n)
        self.kd_bound_max_deg = kd_bound_max_deg

    def __call__(self, normal_xy: Array) -> float:
        """The distance at the candidate normal ``normalize(tx, ty, 1)``, ``normal_xy = (tx, ty)``.

        ``inf`` with too few samples or overlap pairs.
        """
        normal = tilt_frame(float(normal_xy[0]), float(normal_xy[1]))[2]
        frames = sample_frames([r for _, r in self.captures], normal)
        sls = [s.reframe(f) for (s, _), f in zip(self.captures, frames)]
        if sum(int(s.valid.sum()) for s in sls) < 1000:
            return float("inf")
        n_l = sls[0].n_leds
        bins = _concatenate([bin_samples(s.light, s.view, s.values, s.valid, self.cube) for s in sls], self.cube, n_l)
        # the plain bound (these slices carry no noise model): the same for every candidate normal
        kd_max = np.min([kd_bound(s.light, s.view, s.values, s.valid, s.pixels, self.kd_bound_max_deg) for s in sls],
                        axis=0)
        n_all = n_l * len(sls)
        pairs = overlap_pairs(bins, n_all, symmetric=False)
        a = bins.i[:, 2] * bins.o[:, 2] / np.maximum(self.shadowing(bins.i) * self.shadowing(bins.o), 1e-6)
        fit = fit_fresnel(bins, pairs, a, n_all, 0.5 * kd_max, np.full(3, 1.5), kd_max, per_channel=False,
                          diagnostics=False)
        return float(fit.error) if np.isfinite(fit.error) and fit.n_pairs >= MIN_PAIRS else float("inf")


@dataclasses.dataclass
class AsymmetricReconstruction:
    """The result of :func:`reconstruct_rotations`.

    Attributes
    ----------
    model
        The BRDF (:class:`~reflecto.model.MicrofacetBRDF`, or the isotropic model when
        the merged data are isotropic).
    eta
        The relative index, one for R, G, B.
    rotations_deg
        The captures' rotations.
    normal
        The set's normal in device coordinates.
    isotropy
        The captures' azimuthal tests (each in its own sample frame), in capture order
        up to the first anisotropic one; empty when not run (the data break eq. 3, or
        ``Options(isotropic="no")``).
    symmetry
        The eq. 3 test on the merged data (:mod:`.eq3`).
    consistency
        The captures compared with each other (:class:`CaptureConsistency`).
    motion
        Each capture's shake cues (check frames; model-free).
    synthesized_fraction
        Solid-angle fraction of the working hemicube's cap (θ_h ≤ 80°) filled by
        synthesis; ``hole_fraction`` the fraction no capture covered.
    fresnel_error
        E(η) of the set's Fresnel fit (NaN on the isotropic path).
    energy_scale, albedo_max
        As :class:`~.pipeline.Reconstruction`.
    notes, seconds
        Plain statements about bounds and choices; wall time.
    fill
        The hole fill used (its last synthesis, for the validation), ``None`` on the
        isotropic path.
    """

    model: IsotropicMicrofacetBRDF | MicrofacetBRDF
    eta: float
    rotations_deg: list[float]
    normal: Array
    isotropy: list[IsotropyTest]
    symmetry: SymmetryTest
    consistency: CaptureConsistency
    motion: list[MotionReport]
    synthesized_fraction: float
    hole_fraction: float
    fresnel_error: float
    energy_scale: float
    albedo_max: float
    notes: list[str]
    seconds: float
    fill: SynthesisFill | None = None
    excluded_leds: list[tuple[int, int]] = dataclasses.field(default_factory=list)

    @property
    def isotropic(self) -> bool:
        """Whether the set took the 1-D isotropic shortcut (an isotropic model)."""
        return isinstance(self.model, IsotropicMicrofacetBRDF)

    @property
    def shake_detected(self) -> bool:
        """Whether any capture of the set was flagged as shaken (§5.1)."""
        return any(m.shake_detected for m in self.motion)

    @property
    def normal_tilt_deg(self) -> float:
        """Angle between the set's estimated normal and the device's axis normal (degrees)."""
        return geometry.tilt_deg(self.normal)

    def summary(self) -> dict[str, Any]:
        """JSON-ready summary (the ``.json`` written beside the model file).

        Returns
        -------
        dict
            ``asymmetric``, ``isotropic``, ``rotations_deg``, the model's η (or constant
            Fresnel), ``kd``, ``ks``, the normal and its tilt (degrees), the isotropy,
            symmetry and consistency tests, shake and motion cues, excluded LEDs, the
            synthesized and hole fractions, the Fresnel error, energy scale, largest
            albedo, notes and seconds (non-finite numbers as ``None``).
        """
        nan = (lambda x: x if math.isfinite(x) else None)
        return {"asymmetric": True, "isotropic": self.isotropic, "rotations_deg": self.rotations_deg,
                **eta_to_json(self.model.eta), "kd": self.model.kd.tolist(), "ks": self.model.ks.tolist(),
                "normal": self.normal.tolist(), "normal_tilt_deg": self.normal_tilt_deg,
                "isotropy_tests": [t.to_dict() for t in self.isotropy], "symmetry_test": self.symmetry.to_dict(),
                "capture_consistency": self.consistency.to_dict(),
                "shake_detected": self.shake_detected, "motion": [m.to_dict() for m in self.motion],
                "excluded_leds": [list(x) for x in self.excluded_leds],
                "synthesized_fraction": self.synthesized_fraction, "hole_fraction": self.hole_fraction,
                "fresnel_error": nan(self.fresnel_error), "energy_scale": self.energy_scale,
                "albedo_max": self.albedo_max, "notes": self.notes, "seconds": self.seconds}


CAP_DEG = ASYMMETRIC.cap_deg


def _cap_fraction(cube: Hemicube, mask: NDArray[np.bool_] | None) -> float:
    if mask is None:
        return 0.0
    cap = cube.directions[:, 2] >= math.cos(math.radians(CAP_DEG))
    om = cube.solid_angles
    return float(om[mask & cap].sum() / om[cap].sum())


def _notes(model, isotropic: bool, ks_at_bound: bool, eta: float, symmetry: SymmetryTest, energy_scale: float,
           synthesized: float, holes: float, kd_ceiling: Array | None = None) -> list[str]:
    notes = []
    if isotropic:
        notes.append("isotropic: no capture shows a second azimuthal harmonic and the merged data keep eq. 3; "
                     "one 1-D NDF fitted to all captures")
    else:
        notes.append(f"§5.5: eq. 9 merge without the τ mirror; {100 * holes:.1f} % of the θ_h ≤ {CAP_DEG:g}° cap "
                     f"seen by no capture, {100 * synthesized:.1f} % synthesized, the rest lobe-filled")
    if symmetry.decided and symmetry.symmetric:
        notes.append("the merged data keep the symmetry of eq. 3: a single capture would have done")
    return notes + bound_notes(ks_at_bound, eta, model, energy_scale, kd_ceiling)


def _set_normal(captures: Sequence[RotatedCapture], valids: list[NDArray[np.bool_]], max_tilt_deg: float) -> Array:
    """The set's device-frame normal (module docstring), S from an isotropic fit in the device frame."""
    stacked, ok = stack_isotropic([c.slices for c in captures], valids)
    shadow = fit_isotropic(stacked, ok).least_squares.shadowing
    coarse = SetDistance(captures, valids, shadow, n=32, stride=3)
    fine = SetDistance(captures, valids, shadow, n=64, stride=1)
    normal, _ = estimate_normal_consistency(coarse, fine, max_tilt_deg)
    return geometry.normalize(np.asarray(normal, dtype=np.float64))


def _fit_hemicube_set(sb: _SetBins, sls: Sequence[Slices], oks: Sequence[NDArray[np.bool_]], opt: Options,
                      synthesis: SynthesisOptions, pairs: Pairs
                      ) -> tuple[hf.LoopResult, hf.Merge, SynthesisFill, Array]:
    """The hemicube loop on all captures' bins without τ (``pairs``: their direct overlaps), completed by
    synthesis; with ``k_d``'s ceiling per channel (the lowest of the captures')."""
    mg = hf.merge_bins(sb.cube, sb.bins, len(sb.light), sb.per_led, sb.censored_fraction, symmetric=False,
                       pairs=pairs)
    kd_max = np.min([kd_bound(s.light, s.view, s.values, ok, s.pixels, opt.kd_bound_max_deg, s.noise)
                     for s, ok in zip(sls, oks)], axis=0)
    fill = SynthesisFill(synthesis)
    result = hf.run_loop(mg, kd_max, sb.light, fixed_eta=opt.fixed_eta, fill=fill)
    return result, mg, fill, kd_max


@dataclasses.dataclass
class _SetView:
    """A set's captures in the sample frames of one normal: their slices and usable samples, the
    set's bins, the first capture's 1-D fit, the overlaps' ratios and whether they measure one material."""

    frames: list[Array]
    slices: list[Slices]
    valid: list[NDArray[np.bool_]]
    bins: _SetBins
    reference: Any
    pairs: Pairs
    ratios: PairRatios
    consistency: CaptureConsistency


def _set_view(captures: Sequence[RotatedCapture], valids: list[NDArray[np.bool_]], normal: Array,
              opt: Options) -> _SetView:
    """The set seen with the device-frame ``normal`` (:class:`_SetView`)."""
    frames = sample_frames([c.rotation_deg for c in captures], normal)
    sls = [c.slices.reframe(f) for c, f in zip(captures, frames)]
    oks = [ok & s.valid for ok, s in zip(valids, sls)]
    sb = set_bins(sls, oks, opt.work_resolution)
    # a 1-D fit of the first capture gives S, F and k_d for comparing partial NDFs:
    # are the captures of one material, and do they keep eq. 3?
    reference = fit_isotropic(sls[0], oks[0], opt.fixed_eta).least_squares
    pairs = overlap_pairs(sb.bins, len(sb.light), symmetric=True)
    ratios = pair_ratios(sb.bins, len(sb.light), reference, pairs)
    return _SetView(list(frames), sls, oks, sb, reference, pairs, ratios, capture_consistency(sb, ratios))


def _refuse_mixed(captures: Sequence[RotatedCapture], consistency: CaptureConsistency, normal: Array,
                  searched: bool) -> None:
    """Refuse a set whose captures do not measure one material about ``normal``; the message
    says whether that normal was the set's own (``searched``) or imposed, where a tilted set
    reads as different samples do."""
    if consistency.consistent:
        return
    assert consistency.worst is not None  # inconsistent: there is a worst pair
    a, b = consistency.worst
    q = consistency.ratio(a, b)
    spread = f", {q:.1f}× what two LEDs of one capture differ by" if math.isfinite(q) else ""
    tilt = geometry.tilt_deg(normal)
    why = (f" (about the set's own normal, searched: tilted {tilt:.2f}°)" if searched
           else f", or a set tilted from the normal given ({tilt:.2f}° from the device axis; --normal search finds "
                "the set's own)")
    raise ReflectoError(f"{captures[b].name}: does not measure the same material as {captures[a].name} (at shared "
                        f"half vectors their partial NDFs differ in level by {abs(consistency.cross_mean[a, b]):.2f} "
                        f"and by {consistency.cross_rms[a, b]:.2f} in log RMS{spread}): captures of different "
                        "samples or points, or a wrong rotation_deg" + why)


def _set_symmetry(view: _SetView) -> SymmetryTest:
    """Eq. 3's test of the set's merged data (within each capture's pairs) in the view's frames."""
    return symmetry_from_ratios(within_captures(view.ratios, view.bins), captures=len(view.frames))


def _tilt_that_keeps_eq3(captures: Sequence[RotatedCapture], valids: list[NDArray[np.bool_]], opt: Options,
                         normal: Array, view: _SetView, symmetry: SymmetryTest
                         ) -> tuple[Array, _SetView, SymmetryTest]:
    """Where a set consistent about the device axis reads eq. 3 broken there: the first
    capture's own altered normal (:func:`.pipeline.resolve_normal`, §5.4), with the set's
    view and eq. 3 test about it, if the set keeps eq. 3 and stays consistent about it;
    else ``normal``, ``view`` and ``symmetry`` unchanged.

    A set whose captures share one tilt in the device frame (the sample turned about its
    own normal on a tilted stage) agrees with itself about the device axis, but a tilt
    breaks eq. 3's mirror symmetry there as an asymmetric BRDF would: aurora_white tilted
    3° read 2.8× broken and got a hemicube model. One capture's estimate costs a fraction
    of a second against the set search's seconds, and is tried only where the captures
    are alike in the device frame (:func:`_alike_in_the_device_frame`): a BRDF that does
    not change when the sample turns about its normal is isotropic, and keeps eq. 3 in
    its own frame. An asymmetric material changes with the turn and keeps the device axis.
    """
    if opt.isotropic == "no" or not _alike_in_the_device_frame(captures, valids):
        return normal, view, symmetry
    est = resolve_normal(captures[0].slices, valids[0], opt)
    if est.source != "estimated":
        return normal, view, symmetry
    other = _set_view(captures, valids, est.normal, opt)
    kept = _set_symmetry(other)
    if other.consistency.consistent and kept.symmetric:
        return est.normal, other, kept
    return normal, view, symmetry


#: Captures whose device-frame values differ by at most this RMS of their noise are alike.
ALIKE_NOISE_RMS = ASYMMETRIC.alike_noise_rms


def _alike_in_the_device_frame(captures: Sequence[RotatedCapture], valids: list[NDArray[np.bool_]]) -> bool:
    """Whether every capture's luminance equals the first's within the camera's noise, pixel
    by pixel in the device frame: the RMS of ``(y_k − y_0) / √(σ_k² + σ_0²)`` over the
    samples usable in both is at most :data:`ALIKE_NOISE_RMS` (1 for noise alone). Turning
    an isotropic sample about its tilted normal changes nothing the device sees; turning an
    asymmetric one does. Captures without a noise model (``Slices.noise``) are not judged alike."""
    first = captures[0].slices
    if first.noise is None:
        return False
    y0 = first.values @ LUM
    for c, ok in zip(captures[1:], valids[1:]):
        sl = c.slices
        if sl.noise is None or sl.values.shape != first.values.shape:
            return False
        var = sl.noise ** 2 + first.noise ** 2
        use = ok & valids[0] & (var > 0)
        if np.count_nonzero(use) < MIN_PAIRS:
            return False
        z = ((sl.values @ LUM) - y0)[use] / np.sqrt(var[use])
        if not float(np.sqrt(np.mean(z * z))) <= ALIKE_NOISE_RMS:
            return False
    return True


def _isotropic_for_set(t: IsotropyTest) -> bool:
    """Is one capture of the set isotropic? The conditional fraction alone decides
    (below :data:`.isotropy.CONDITIONAL_EXPLAINED`, or too few rings): the plain fraction
    of :attr:`.IsotropyTest.isotropic` is diluted by a first harmonic, which an
    asymmetric lobe — what §5.5 is for — adds (the brushed GGX of the examples on the
    as-built device: plain 0.74–0.80, below its 0.8, conditional 0.75, amplitude 1.0),
    while the conditional fraction already discounts an isotropic BRDF's own misfit."""
    return not t.decided or t.conditional < CONDITIONAL_EXPLAINED


def _choose_isotropic(option: str, sls: Sequence[Slices], oks: Sequence[NDArray[np.bool_]], reference,
                      symmetry: SymmetryTest) -> tuple[bool, list[IsotropyTest]]:
    """The 1-D path? ``"auto"``: when every capture's azimuthal test (against the
    ``reference`` isotropic model) is isotropic (:func:`_isotropic_for_set`) and the
    merged data keep eq. 3 — an NDF that breaks eq. 3 is not isotropic, whatever its
    second harmonic says. The tests run in capture order and, under ``"auto"``, stop at
    the first anisotropic one: it decides the set."""
    if option == "no" or (option == "auto" and not symmetry.symmetric):
        return False, []
    tests: list[IsotropyTest] = []
    for s, ok in zip(sls, oks):
        tests.append(azimuthal_test(s, ok, reference))
        if option == "auto" and not _isotropic_for_set(tests[-1]):
            return False, tests
    return True, tests


def reconstruct_rotations(captures: Sequence[RotatedCapture], options: Options | None = None,
                          synthesis: SynthesisOptions | None = None) -> AsymmetricReconstruction:
    """Reconstruct one BRDF from captures of the same point at several rotations (module docstring).

    Isotropic data get the 1-D fit on all captures' samples; otherwise the partial NDFs
    (eq. 7) of all captures are merged by eq. 9 without the τ mirror of eq. 3, and what
    no rotation measured is filled by microfacet synthesis (§5.5, after Wang et al. 2008).

    Parameters
    ----------
    captures
        The captures of one point, each with its slices and rotation (:class:`RotatedCapture`).
    options
        Reconstruction options (defaults if None).
    synthesis
        Microfacet-synthesis options (defaults if None).

    Returns
    -------
    AsymmetricReconstruction
        The model (BRDF in sr⁻¹; isotropic or hemicube NDF) and the tests and
        diagnostics of :meth:`AsymmetricReconstruction.summary`.

    Raises
    ------
    ReflectoError
        Naming the capture, for a set that :func:`check_rotations` refuses and for
        captures that do not measure one material (:class:`CaptureConsistency`).
    """
    opt = checked_options(options)
    if opt.shadowing != "auto":  # the set's isotropic branch fits eq. 8's product: the choice would be ignored
        raise ParameterError(f"shadowing {opt.shadowing!r}: the §5.5 set fits eq. 8's product shadowing; the "
                             "shadowing form is chosen for one capture's model (leave it 'auto')")
    syn_opt = synthesis or SynthesisOptions()
    t0 = time.perf_counter()
    check_rotations(captures)
    valids = []
    for c in captures:
        try:
            valids.append(usable_samples(c.slices))
        except ReflectoError as e:
            raise ReflectoError(f"{c.name}: {str(e).removeprefix('capture: ')}") from None
    searched = isinstance(opt.normal, str) and opt.normal == "search"
    if isinstance(opt.normal, str):
        # "auto" takes the device axis first: the set's search costs seconds; "search" runs it
        normal = (_set_normal(captures, valids, opt.max_tilt_deg) if searched else np.array([0.0, 0.0, 1.0]))
    else:
        normal = np.asarray(opt.normal, dtype=np.float64)
    view = _set_view(captures, valids, normal, opt)
    symmetry = _set_symmetry(view)
    if not view.consistency.consistent and opt.normal == "auto":
        # a tilted set's captures disagree in the device frame as different samples would: search its normal
        normal, searched = _set_normal(captures, valids, opt.max_tilt_deg), True
        view = _set_view(captures, valids, normal, opt)
        symmetry = _set_symmetry(view)
    elif opt.normal == "auto" and not symmetry.symmetric:
        normal, view, symmetry = _tilt_that_keeps_eq3(captures, valids, opt, normal, view, symmetry)
    _refuse_mixed(captures, view.consistency, normal, searched)
    frames, sls, oks, sb, reference, pairs, _, consistency = (
        view.frames, view.slices, view.valid, view.bins, view.reference, view.pairs, view.ratios, view.consistency)
    isotropic, tests = _choose_isotropic(opt.isotropic, sls, oks, reference, symmetry)
    fill: SynthesisFill | None = None
    excluded: list[tuple[int, int]] = []
    model: IsotropicMicrofacetBRDF | MicrofacetBRDF
    if isotropic:
        stacked, ok_st = stack_isotropic([c.slices.reframe(frames[0]) for c in captures], valids)
        iso = fit_isotropic(stacked, ok_st & stacked.valid, opt.fixed_eta, opt.kd_bound_max_deg)
        model, eta, ks_bound, fresnel_error = iso.model, iso.eta, iso.ks_at_bound, math.nan
        kd_ceiling: Array | None = iso.kd_ceiling
    else:
        loop, mg, fill, kd_ceiling = _fit_hemicube_set(sb, sls, oks, opt, syn_opt, pairs.select(~pairs.symmetric))
        st = loop.state
        model = hf.output_model(mg, st, opt.resolution)
        eta, ks_bound, fresnel_error = float(st.eta[0]), bool(np.any(st.ks >= 1.0)), loop.fresnel_error
        excluded = [(k // sb.n_leds, k % sb.n_leds) for k in loop.excluded_leds]
        # reported against the reconstruction's own S and F, which fit the anisotropic lobe
        symmetry = symmetry_from_ratios(within_captures(pair_ratios(sb.bins, len(sb.light), model, pairs), sb),
                                        captures=len(captures))
    motion = ([detect_motion(c.slices, s, ok, False) for c, s, ok in zip(captures, sls, oks)]
              if opt.detect_shake else [MotionReport() for _ in captures])
    built = model
    model, scale, albedo = limit_energy_of_the_trend(model, opt.energy_clamp)
    synthesized = _cap_fraction(sb.cube, fill.synthesized_work) if fill else 0.0
    holes = _cap_fraction(sb.cube, fill.holes_work) if fill else 0.0
    return AsymmetricReconstruction(
        model, eta, [float(c.rotation_deg) for c in captures], normal, tests, symmetry, consistency, motion,
        synthesized, holes, fresnel_error, scale, albedo,
        _notes(model, isotropic, ks_bound, eta, symmetry, scale, synthesized, holes, kd_ceiling)
        + held_tint_notes(built, model),
        time.perf_counter() - t0,
        fill, excluded)
