"""Isotropy and reciprocity across slices: a model-free shake cue (§5.1).

An isotropic BRDF depends on ``(θ_i, θ_o, φ_o − φ_i)`` only, and every BRDF is
reciprocal, ``f(i, o) = f(o, i)``. Between the slices of two LEDs this gives exact
equalities that need no microfacet model:

- **Isotropy.** Two LEDs at the same elevation see the same function of the view
  once the view is turned about the normal by the difference of their azimuths.
- **Reciprocity.** LED ``b``'s sample viewed from ``u = (θ_a, φ_b + Δ)`` equals LED
  ``a``'s sample viewed from ``u* = (θ_b, φ_a − Δ)`` for every Δ (rotate the reciprocal
  pair about the normal), which pairs two steep LEDs
  (:data:`~reflecto.instrument.device.STEEP_ELEVATION_DEG`) whose polar angles both lie
  within the view cone's range of polar angles, along a curve. A grazing LED would put
  its partner's view at grazing exitance, where measured data are not reciprocal.

Which LEDs pair up is derived from the capture, not from an LED numbering: the LED
directions in the sample frame (equal elevation within :data:`ISOTROPY_MAX_DEG`) and
the polar angles its view directions span. (The default layout gives one pair of
each kind: LEDs 1 and 3 at θ_i = 82.7° and 83.0°, LEDs 2 and 4 at 67.1° and 37.8°;
a layout with more LEDs near one elevation, or inside a wider cone, gives more.)

When the sample turns between two LEDs (a shake), the later slices are measured in a
turned frame: their θ_i, and with them ``cos θ_i`` in the conversion from radiance to
BRDF, are wrong. The equalities then fail by a factor the microfacet fit of §5.1 need
not notice: on matte materials E(η) hardly rises (the specular peak is too broad to
reveal the turn), and the mirror planes of :mod:`.symmetry` cannot be located. The
cue is the median ``|log|`` ratio of each comparable pair, on the slices averaged onto a
coarse hemicube of view directions (:data:`CUBE_N`) and looked up bilinearly at the
paired directions, where all four texels hold data.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numpy.typing import NDArray

from ..colour import LUM
from ..hemicube import hemicube
from ..instrument.device import STEEP_ELEVATION_DEG
from .tuning import CONSISTENCY

Array = NDArray[np.float64]

# Tuned numbers: what, units and provenance are in :mod:`.tuning` (consistency stage).
CUBE_N = CONSISTENCY.cube_n
ISOTROPY_MAX_DEG = CONSISTENCY.isotropy_max_deg
MIN_PAIRS = {"isotropy": CONSISTENCY.min_pairs_isotropy, "reciprocity": CONSISTENCY.min_pairs_reciprocity}
RECIPROCITY_STEP_DEG = CONSISTENCY.reciprocity_step_deg
THRESHOLD = {"isotropy": CONSISTENCY.threshold_isotropy, "reciprocity": CONSISTENCY.threshold_reciprocity}
STEP_DEG = CONSISTENCY.step_deg
MAX_STEP = CONSISTENCY.max_step
FLOOR = CONSISTENCY.floor
MAX_NOISE = CONSISTENCY.max_noise


@dataclasses.dataclass(frozen=True)
class PairCheck:
    """One comparison between the slices of LEDs ``a`` and ``b``.

    ``kind`` is ``"isotropy"`` or ``"reciprocity"``; ``log_ratio`` the median of
    ``log(f_a / f_b)`` over the ``count`` paired directions (0 for a consistent pair);
    ``allowance`` what the normal's uncertainty adds to the kind's :data:`THRESHOLD`
    (:func:`normal_allowance`; 0 for a known normal).
    """

    a: int
    b: int
    kind: str
    log_ratio: float
    count: int
    allowance: float = 0.0

    @property
    def inconsistent(self) -> bool:
        """Whether the ratio exceeds the kind's :data:`THRESHOLD` plus the allowance."""
        return abs(self.log_ratio) > THRESHOLD[self.kind] + self.allowance


def normal_allowance(light: Array, a: int, b: int, normal_uncertainty_deg: float, sigmas: float = 2.0) -> float:
    """What an error of the normal does to a pair's log ratio: each LED's value is
    divided by its ``cos θ_i`` in the sample frame, and a normal off by ``δ`` changes
    ``log cos θ_i`` by up to ``δ tan θ_i``; both LEDs' at ``sigmas`` standard
    uncertainties: ``sigmas · δ · (tan θ_a + tan θ_b)`` (δ in radians)."""
    if normal_uncertainty_deg <= 0:
        return 0.0
    tan = lambda k: math.sqrt(max(1.0 - light[k, 2] ** 2, 0.0)) / max(float(light[k, 2]), 1e-6)  # noqa: E731
    return sigmas * math.radians(normal_uncertainty_deg) * (tan(a) + tan(b))


class _SliceTable:
    """One slice's luminance averaged onto a hemicube of view directions."""

    def __init__(self, view: Array, values: Array, ok: NDArray[np.bool_]) -> None:
        self.cube = cube = hemicube(CUBE_N)
        wsum, wv = cube.splat(view, np.where(ok, values, 0.0), ok.astype(np.float64))
        has = wsum > 0
        self.centres = cube.directions[has]  # texels with data
        self.value = cube.pad(np.where(has, wv / np.where(has, wsum, 1.0), 0.0))
        self.has = cube.pad(has.astype(np.float64))

    def at(self, dirs: Array) -> tuple[Array, NDArray[np.bool_]]:
        """Bilinear values at ``dirs`` (N, 3), and where they are usable: all four
        texels hold data, and the value changes by less than :data:`MAX_STEP` in log
        within :data:`STEP_DEG` (so that a direction error of the calibration, or of the
        normal, does not read as an inconsistency)."""
        h = self.cube.lookup(None, dirs, padded=self.has)
        v = self.cube.lookup(None, dirs, padded=self.value)
        ok = (h > 1.0 - 1e-9) & (v > 0.0)
        t1 = np.cross(dirs, [0.0, 0.0, 1.0])
        t1 /= np.maximum(np.linalg.norm(t1, axis=-1, keepdims=True), 1e-12)
        t2 = np.cross(dirs, t1)
        step = math.radians(STEP_DEG)
        logv = np.log(np.where(ok, v, 1.0))
        for t in (t1, -t1, t2, -t2):
            d = dirs + step * t
            d /= np.linalg.norm(d, axis=-1, keepdims=True)
            vn = self.cube.lookup(None, d, padded=self.value)
            hn = self.cube.lookup(None, d, padded=self.has)
            near = (hn > 1.0 - 1e-9) & (vn > 0.0)  # a neighbour off the data is not judged
            ok &= ~near | (np.abs(np.log(np.where(near, vn, 1.0)) - logv) < MAX_STEP)
        return v, ok


def _spherical(theta: Array | float, phi: Array) -> Array:
    st = np.sin(theta)
    return np.stack([st * np.cos(phi), st * np.sin(phi), np.broadcast_to(np.cos(theta), np.shape(phi))], axis=-1)


def _median_log_ratio(fa: Array, fb: Array, ok: NDArray[np.bool_], kind: str) -> tuple[float, int]:
    if np.count_nonzero(ok) < MIN_PAIRS[kind]:
        return math.nan, 0
    floor = FLOOR * float(np.percentile(np.concatenate([fa[ok], fb[ok]]), 99.0))
    ok = ok & (fa > floor) & (fb > floor)
    n = int(np.count_nonzero(ok))
    if n < MIN_PAIRS[kind]:
        return math.nan, 0
    return float(np.median(np.log(fa[ok] / fb[ok]))), n


def pair_checks(light: Array, view: Array, values: Array, valid: NDArray[np.bool_],
                noise: Array | None = None) -> list[PairCheck]:
    """Every isotropy and reciprocity comparison the layout allows.

    Samples whose camera noise exceeds :data:`MAX_NOISE` of their luminance take no part:
    a slice read a few DN above the black level is rounded and censored into a biased
    ratio (a tilted capture's grazing LEDs), which no turn of the sample caused.

    Parameters
    ----------
    light
        LED directions in the sample frame, shape ``(L, 3)``.
    view
        View directions of the pixels in the sample frame, shape ``(P, 3)``.
    values
        BRDF values (sr⁻¹), shape ``(L, P, 3)``.
    valid
        Usable samples (not saturated, not censored), shape ``(L, P)``.
    noise
        Standard deviation of one channel's reading (sr⁻¹, :attr:`Slices.noise`), shape
        ``(L, P)``, or ``None`` (a camera without a noise model: every valid sample).

    Returns the pairs that have at least :data:`MIN_PAIRS` paired directions above the
    floor; LEDs below the horizon take no part.
    """
    view = np.asarray(view, dtype=np.float64)
    above = view[:, 2] > 1e-6
    n_led = light.shape[0]
    theta = np.arccos(np.clip(light[:, 2], -1.0, 1.0))
    phi = np.arctan2(light[:, 1], light[:, 0])
    lum = values @ LUM
    if noise is not None:
        valid = valid & (noise <= MAX_NOISE * lum)
    tables: dict[int, _SliceTable] = {}

    def table(k: int) -> _SliceTable:
        if k not in tables:
            tables[k] = _SliceTable(view, lum[k], valid[k] & above & np.isfinite(lum[k]))
        return tables[k]

    # the polar angles the view cone spans: reciprocity needs both LEDs' polar angles within
    theta_views = np.arccos(np.clip(view[above, 2], -1.0, 1.0))
    theta_lo, theta_view = (float(theta_views.min()), float(theta_views.max())) if len(theta_views) else (0.0, 0.0)
    # reciprocity pairs only steep LEDs: a grazing one puts its partner's view at grazing
    # exitance, where measured data are not reciprocal (RGL: |log ratio| 0.47–0.54 on
    # clean captures through a 60° cone)
    steep = math.radians(90.0 - STEEP_ELEVATION_DEG)
    out: list[PairCheck] = []
    for a in range(n_led):
        for b in range(a + 1, n_led):
            if light[a, 2] <= 0.0 or light[b, 2] <= 0.0:
                continue
            if abs(theta[a] - theta[b]) <= math.radians(ISOTROPY_MAX_DEG):
                dirs_a = table(a).centres  # one point per texel of LED a's data
                dirs_b = _rotate_z(dirs_a, phi[b] - phi[a])
                fa, ha = table(a).at(dirs_a)
                fb, hb = table(b).at(dirs_b)
                r, n = _median_log_ratio(fa, fb, ha & hb & (dirs_b[:, 2] > 1e-6), "isotropy")
                if n:
                    out.append(PairCheck(a, b, "isotropy", r, n))
            elif theta_lo < min(theta[a], theta[b]) and max(theta[a], theta[b]) < min(theta_view, steep):
                delta = np.radians(np.arange(0.0, 360.0, RECIPROCITY_STEP_DEG))
                u = _spherical(theta[a], phi[b] + delta)  # LED b's view
                u_star = _spherical(theta[b], phi[a] - delta)  # LED a's view
                fb, hb = table(b).at(u)
                fa, ha = table(a).at(u_star)
                r, n = _median_log_ratio(fa, fb, ha & hb, "reciprocity")
                if n:
                    out.append(PairCheck(a, b, "reciprocity", r, n))
    return out


def _rotate_z(dirs: Array, angle: float) -> Array:
    c, s = math.cos(angle), math.sin(angle)
    return np.stack([c * dirs[:, 0] - s * dirs[:, 1], s * dirs[:, 0] + c * dirs[:, 1], dirs[:, 2]], axis=-1)
