"""How far do the data break the symmetry of eq. 3? A model-light test on τ-paired texels.

Eq. 3 says ``D(h) = D(τh)``, ``τ`` the half turn about ``n``. Where the slices
observe a half vector and its τ image both, their partial NDFs (eq. 7, with the
reconstruction's ``S``, ``F`` and ``k_d`` divided out) must agree; an asymmetric NDF
makes them differ. How much two partial NDFs of the same NDF can differ anyway
(``S`` and ``F`` a little off, the texel's extent, noise) shows where two LEDs see
the *same* texel: the direct overlaps of §5.1.

Samples are binned per LED and texel (:mod:`.samples`); in the lobe (partial NDF
above :data:`LEVEL` of its 99.5th percentile, specular part at least
:data:`MIN_SPECULAR_FRACTION` of the value) every τ pair of bins (``h`` from one
LED, ``τh`` from one) and every direct pair (one texel, two LEDs) gives a log ratio
``ℓ = log D̂_p − log D̂_q``. With ``ρ_τ`` and ``ρ_d`` their pixel-count-weighted RMS,
the data break eq. 3 when

``ρ_τ / max(ρ_d, ρ_min) ≥`` :data:`THRESHOLD`

(``ρ_min`` = :data:`DIRECT_FLOOR`; with fewer than :data:`MIN_PAIRS` direct pairs
``max(ρ_d, UNPAIRED_SPREAD)``), and how far they break it is the excess
``asymmetry = √max(0, ρ_τ² − ρ_d²)`` (log units: 0.1 is a 10 % difference between
``D(h)`` and ``D(τh)`` beyond what equal NDFs show). A ratio rather than an absolute
level: on measured materials the model's ``S`` and ``F`` miss the data by 20–60 %
(log RMS) in both kinds of pair alike, while an asymmetric lobe adds to the τ pairs
only. On the 50 shared materials and four analytic symmetric lobes (one capture, ideal
device) the ratios stay ≤ 1.60, on the eight analytic asymmetric lobes they are
≥ 3.2 (3.1 on the as-built device; docs/design/asymmetric.md). For several
captures (§5.5) the bins of all captures, each in the sample frame, enter together:
the direct pairs then include those of two captures.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numpy.typing import NDArray

from ..colour import LUM
from ..hemicube import hemicube
from ..instrument.slices import Slices
from .fresnel_fit import Pairs, overlap_pairs
from .samples import Bins, bin_samples
from .tuning import SYMMETRY_TEST

Array = NDArray[np.float64]

__all__ = ["SymmetryTest", "symmetry_test", "symmetry_test_slices", "THRESHOLD", "PairRatios", "pair_ratios",
           "symmetry_from_ratios"]

#: Bins enter where their partial NDF is above this fraction of its 99.5th percentile …
LEVEL = SYMMETRY_TEST.level
#: … and the specular part is at least this fraction of the measured BRDF (where the
#: partial NDF is measured, not the diffuse floor and the model's account of it).
MIN_SPECULAR_FRACTION = SYMMETRY_TEST.min_specular_fraction
#: τ pairs needed for a verdict, and direct pairs needed to measure their spread.
MIN_PAIRS = SYMMETRY_TEST.min_pairs
#: The least spread of the direct pairs assumed when fewer than :data:`MIN_PAIRS` of them
#: are in the lobe (a sharp lobe that τ pairs reach and direct ones hardly do; log units): the
#: model's S and F miss measured materials by 20–60 %, so 0.3. Without direct pairs
#: the τ pairs of blue-rubber and light-red-paint differ by 0.13–0.18 (kept), those of
#: the asymmetric satin of the examples by 0.91 (broken).
UNPAIRED_SPREAD = SYMMETRY_TEST.unpaired_spread
#: Ratio of the τ pairs' RMS log ratio to the direct pairs' at and above which the data break eq. 3.
THRESHOLD = SYMMETRY_TEST.threshold
#: Floor of the direct pairs' RMS in that ratio (log units): below ≈ 1 % two partial
#: NDFs are equal to within the texel's extent.
DIRECT_FLOOR = SYMMETRY_TEST.direct_floor
#: Working resolution of the test's bins (texels ≈ 0.9° at the pole).
TEST_RESOLUTION = SYMMETRY_TEST.test_resolution


@dataclasses.dataclass(frozen=True)
class SymmetryTest:
    """The eq. 3 test (module docstring).

    Attributes
    ----------
    asymmetry
        Excess RMS log ratio of τ-paired partial NDFs over direct pairs (log units).
    tau_rms, direct_rms
        Pixel-weighted RMS log ratio of the τ pairs and of the direct pairs.
    tau_pairs, direct_pairs
        Pairs that entered.
    captures
        Captures whose bins entered (1, or the §5.5 set).
    """

    asymmetry: float
    tau_rms: float
    direct_rms: float
    tau_pairs: int
    direct_pairs: int
    captures: int = 1

    @property
    def decided(self) -> bool:
        """Whether enough τ pairs were observed for a verdict (``MIN_PAIRS``)."""
        return self.tau_pairs >= MIN_PAIRS

    @property
    def spread(self) -> float:
        """The direct pairs' spread in the statistic: ``max(ρ_d, ρ_min)``, or with fewer
        than :data:`MIN_PAIRS` direct pairs ``max(ρ_d, UNPAIRED_SPREAD)``: so few pairs
        cannot show that the model misses the data by less than the assumed spread, but
        they can show it misses by more (a red plastic tilted 1.5°: 29 direct pairs at
        1.33 log units, τ pairs at 0.68, read as broken against 0.3)."""
        if self.direct_pairs >= MIN_PAIRS:
            return max(self.direct_rms, DIRECT_FLOOR)
        return max(self.direct_rms, UNPAIRED_SPREAD)  # no pairs: ρ_d = 0

    @property
    def ratio(self) -> float:
        """``ρ_τ / spread``: the test's statistic."""
        return self.tau_rms / self.spread

    @property
    def symmetric(self) -> bool:
        """The data keep eq. 3 (or hold too few τ pairs to tell)."""
        return not self.decided or self.ratio < THRESHOLD

    def to_dict(self) -> dict[str, float | int | bool]:
        """The test as JSON-ready numbers."""
        return {"asymmetry": self.asymmetry, "ratio": self.ratio, "tau_rms": self.tau_rms,
                "direct_rms": self.direct_rms,
                "tau_pairs": self.tau_pairs, "direct_pairs": self.direct_pairs, "captures": self.captures,
                "threshold": THRESHOLD, "decided": self.decided, "symmetric": self.symmetric}

    def describe(self) -> str:
        """One line: the statistic and the verdict."""
        if not self.decided:
            return f"symmetry of eq. 3 not tested ({self.tau_pairs} τ-paired texels in the lobe, {MIN_PAIRS} needed)"
        verdict = "kept" if self.symmetric else "BROKEN"
        return (f"symmetry of eq. 3 {verdict}: partial NDFs at h and τh differ by {self.tau_rms:.3f} (log RMS, "
                f"{self.tau_pairs} pairs), {self.ratio:.2f}× what two LEDs at one texel differ by "
                f"({self.spread:.3f}{'' if self.direct_pairs >= MIN_PAIRS else ', assumed: too few direct pairs'}; "
                f"broken from {THRESHOLD:g}×): an excess of {self.asymmetry:.3f}")

    def hint(self) -> str | None:
        """Advice when a single capture breaks eq. 3, else ``None``."""
        if self.symmetric or self.captures > 1:
            return None
        return ("the BRDF breaks the symmetry of eq. 3, which this reconstruction assumes: capture the same point "
                "at several rotations (e.g. 0/90/180/270°; the manifest's rotation_deg) and reconstruct them "
                "together with `reflecto reconstruct CAP... --asymmetric -o MODEL.reflecto` (paper §5.5)")


def partial_ndf_luminance(bins: Bins, model) -> tuple[Array, Array]:
    """Eq. 7 per bin with the model's ``S``, ``F``, ``k_d`` and ``k_s``: luminance
    ``D̂ = (f − k_d/π)·LUM / ((k_s F)·LUM · S(i) S(o) / (4 cos θ_i cos θ_o))`` (sr⁻¹),
    shape ``(B,)``, 0 where the model's specular factor vanishes; and the specular
    fraction ``(f − k_d/π)·LUM / f·LUM`` of each bin."""
    f_lum = bins.f @ LUM
    f_s = f_lum - float(model.kd @ LUM) / math.pi
    spec = (model.fresnel(bins.cos_d) * model.ks[None, :]) @ LUM
    s = model.shadowing(bins.i) * model.shadowing(bins.o)
    g = spec * s / np.maximum(4.0 * bins.i[:, 2] * bins.o[:, 2], 1e-12)
    frac = np.divide(f_s, f_lum, out=np.zeros(len(bins)), where=f_lum > 0)
    return np.divide(f_s, g, out=np.zeros(len(bins)), where=g > 0), frac


def _weighted_rms(x: Array, w: Array) -> float:
    return float(math.sqrt(np.sum(w * x * x) / np.sum(w))) if len(x) and np.sum(w) > 0 else 0.0


@dataclasses.dataclass(frozen=True)
class PairRatios:
    """Log ratios ``ℓ = log D̂_p − log D̂_q`` of the lobe's overlapping bins (module docstring).

    ``p, q`` bin indices, ``symmetric`` whether the pair is a τ pair, ``w`` its weight
    (the smaller pixel count), all shape ``(K,)``.
    """

    p: NDArray[np.intp]
    q: NDArray[np.intp]
    symmetric: NDArray[np.bool_]
    ell: Array
    w: Array


def pair_ratios(bins: Bins, n_leds: int, model, pairs: Pairs | None = None) -> PairRatios:
    """The lobe's τ and direct pairs of ``bins`` (sample frame, sorted by LED and texel)
    with their log ratios against ``model``'s S, F, k_d; ``pairs`` from
    :func:`.fresnel_fit.overlap_pairs` (symmetric) when already at hand."""
    d, frac = partial_ndf_luminance(bins, model)
    pos = d > 0
    empty = np.zeros(0, dtype=np.intp)
    if np.count_nonzero(pos) < MIN_PAIRS:
        return PairRatios(empty, empty, np.zeros(0, dtype=bool), np.zeros(0), np.zeros(0))
    level = LEVEL * float(np.percentile(d[pos], 99.5))
    lobe = (d > level) & (frac >= MIN_SPECULAR_FRACTION)
    pairs = overlap_pairs(bins, n_leds, symmetric=True) if pairs is None else pairs
    keep = lobe[pairs.p] & lobe[pairs.q]
    p, q = pairs.p[keep], pairs.q[keep]
    return PairRatios(p, q, pairs.symmetric[keep], np.log(d[p]) - np.log(d[q]),
                      np.minimum(bins.count[p], bins.count[q]))


def symmetry_from_ratios(r: PairRatios, captures: int = 1) -> SymmetryTest:
    """:class:`SymmetryTest` of the pairs' log ratios (module docstring)."""
    sym = r.symmetric
    tau_rms = _weighted_rms(r.ell[sym], r.w[sym])
    direct_rms = _weighted_rms(r.ell[~sym], r.w[~sym])
    excess = math.sqrt(max(tau_rms * tau_rms - direct_rms * direct_rms, 0.0))
    return SymmetryTest(excess, tau_rms, direct_rms, int(np.count_nonzero(sym)), int(np.count_nonzero(~sym)), captures)


def symmetry_test(bins: Bins, n_leds: int, model, captures: int = 1) -> SymmetryTest:
    """:class:`SymmetryTest` of bins in the sample frame against ``model``'s S, F, k_d (module docstring).

    ``bins`` sorted by LED and texel (:func:`.samples.bin_samples`; several captures'
    bins concatenated with their LED indices offset); ``n_leds`` the LED indices' range.
    """
    return symmetry_from_ratios(pair_ratios(bins, n_leds, model), captures)


def symmetry_test_slices(slices: Slices, valid: NDArray[np.bool_], model) -> SymmetryTest:
    """:func:`symmetry_test` of one capture's slices, already in the sample frame."""
    ok = valid & slices.valid
    if slices.censored is not None:
        ok = ok & ~slices.censored
    bins = bin_samples(slices.light, slices.view, slices.values, ok, hemicube(TEST_RESOLUTION))
    return symmetry_test(bins, slices.n_leds, model)
