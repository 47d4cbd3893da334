"""Slice samples binned per LED and hemicube texel of their half vector.

The reconstruction works on bins, not pixels: every (LED, texel of ``h``) pair
holds the mean BRDF value, the mean view direction and half vector, and the number
of pixels. Eq. 9 merges samples per texel anyway, so binning first changes only
how the within-texel average is taken (of ``f`` instead of ``D̂``; second order in
the texel size), and it divides the per-iteration work by the number of pixels per
texel (≈ 4 at the default working resolution). Every bin also knows the texel of
``τh`` (eq. 3), for completion and for the symmetric overlaps of §5.1.
"""

from __future__ import annotations

import dataclasses
import math
from statistics import NormalDist

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import uniform_filter

from .. import _kernels, geometry
from ..colour import LUM
from ..errors import ParameterError
from ..hemicube import Hemicube
from .tuning import SAMPLES

Array = NDArray[np.float64]


@dataclasses.dataclass
class Bins:
    """Samples averaged per (LED, texel).

    Attributes
    ----------
    cube
        Working hemicube the texels refer to.
    led
        LED index of each bin, shape ``(B,)``.
    texel, texel_tau
        Texel of ``h`` and of ``τh``, shape ``(B,)``.
    count
        Pixels in the bin, shape ``(B,)``.
    i, o, h
        Light, mean view and mean half vector (unit), shape ``(B, 3)``.
    f
        Mean BRDF value (sr⁻¹), shape ``(B, 3)``.
    cos_d
        ``c = i·h`` (cos θ_d), shape ``(B,)``.
    variance
        Variance of the bin's mean luminance (sr⁻²), ``Σ σ² / n²`` over its ``n`` samples
        (independent pixel noise ``σ``, :attr:`~reflecto.instrument.slices.Slices.noise`),
        shape ``(B,)``; ``None`` when binned without a noise model.
    """

    cube: Hemicube
    led: NDArray[np.intp]
    texel: NDArray[np.intp]
    texel_tau: NDArray[np.intp]
    count: Array
    i: Array
    o: Array
    h: Array
    f: Array
    cos_d: Array
    variance: Array | None = None

    def __len__(self) -> int:
        return len(self.led)

    def select(self, mask: NDArray[np.bool_]) -> Bins:
        """The bins where ``mask`` holds."""
        return Bins(self.cube, self.led[mask], self.texel[mask], self.texel_tau[mask], self.count[mask],
                    self.i[mask], self.o[mask], self.h[mask], self.f[mask], self.cos_d[mask],
                    None if self.variance is None else self.variance[mask])


def bin_samples(light: Array, view: Array, values: Array, valid: NDArray[np.bool_], cube: Hemicube,
                noise: Array | None = None) -> Bins:
    """Average the valid samples of ``(L, P)`` slices per LED and texel of ``h``.

    Parameters
    ----------
    light
        LED directions in the sample frame, shape ``(L, 3)``.
    view
        Pixel view directions in the sample frame, shape ``(P, 3)``.
    values
        BRDF values (sr⁻¹), shape ``(L, P, 3)``.
    valid
        Usable samples, shape ``(L, P)``.
    cube
        Working hemicube.
    noise
        Standard deviation of each sample's luminance (sr⁻¹), shape ``(L, P)``
        (:attr:`~reflecto.instrument.slices.Slices.noise`); with it the bins carry
        :attr:`Bins.variance`.
    """
    light = _kernels.as_dirs(light)
    view = _kernels.as_dirs(view)
    vals = np.ascontiguousarray(values, dtype=np.float64)
    sq = np.zeros((0, 0)) if noise is None else np.ascontiguousarray(noise, dtype=np.float64) ** 2
    used, cnt, fsum, osum, qsum = _kernels.bin_accumulate(light, view, vals,
                                                          np.ascontiguousarray(valid, dtype=np.bool_), cube.n, sq)
    led, texel, i, o, h, f, cos_d = _kernels.bin_finish(light, used, cnt, fsum, osum, cube.size)
    tau = cube.permutation(geometry.TAU)
    return Bins(cube, led, texel, tau[texel], cnt, i, o, h, f, cos_d, None if noise is None else qsum / (cnt * cnt))


def bin_samples_numpy(light: Array, view: Array, values: Array, valid: NDArray[np.bool_], cube: Hemicube,
                      noise: Array | None = None) -> Bins:
    """NumPy reference of :func:`bin_samples` (same sums in the same order)."""
    li, pi = np.nonzero(valid)
    o = view[pi]
    key = li * cube.size + cube.index(light[li] + o)  # the texel of h = (i + o)/|i + o|
    n_keys = light.shape[0] * cube.size
    count = np.bincount(key, minlength=n_keys)
    used = np.flatnonzero(count)
    slot = np.full(n_keys, -1, dtype=np.intp)
    slot[used] = np.arange(len(used))
    b = slot[key]
    nb = len(used)

    def total(x: Array) -> Array:
        return np.column_stack([np.bincount(b, weights=x[:, k], minlength=nb) for k in range(x.shape[1])])

    cnt = count[used].astype(np.float64)
    bins = _finish(cube, light, used, cnt, total(values[li, pi]), total(o))
    if noise is not None:
        bins.variance = np.bincount(b, weights=noise[li, pi] ** 2, minlength=nb) / (cnt * cnt)
    return bins


def _finish(cube: Hemicube, light: Array, used: NDArray[np.intp], cnt: Array, fsum: Array, osum: Array) -> Bins:
    """Bins from the per-key sums (keys ``led·size + texel``, ascending)."""
    f = fsum / cnt[:, None]
    o_mean = geometry.normalize(osum)
    led = (used // cube.size).astype(np.intp)
    i = light[led]
    h_mean = geometry.normalize(i + o_mean)
    texel = (used % cube.size).astype(np.intp)
    tau = cube.permutation(geometry.TAU)
    cos_d = np.clip(np.einsum("ij,ij->i", i, h_mean), 0.0, 1.0)
    return Bins(cube, led, texel, tau[texel], cnt, i, o_mean, h_mean, f, cos_d)


def _percentile_ranks(n: int, q: float) -> tuple[int, int, float]:
    """Ranks ``lo ≤ hi`` and weight ``t`` of ``np.percentile``'s linear method."""
    virt = (q / 100.0) * (n - 1)
    lo = int(math.floor(virt))
    return lo, min(lo + 1, n - 1), virt - lo


def _interpolate(a: float, b: float, t: float) -> float:
    """``np.percentile``'s linear interpolation between order statistics (same arithmetic)."""
    return b - (b - a) * (1.0 - t) if t >= 0.5 else a + (b - a) * t


# Tuned numbers: what, units and provenance are in :mod:`.tuning` (samples stage).
KD_BOUND_PERCENTILE = SAMPLES.kd_bound_percentile
#: Subsampling stride of the threshold that pre-selects the low values (kd_upper_bound).
_SUBSAMPLE = 16


BOX_RADIUS = SAMPLES.box_radius


def box_mean(values: Array, valid: NDArray[np.bool_], pixels: NDArray[np.intp], radius: int = BOX_RADIUS) -> Array:
    """Each valid sample replaced by the mean of the valid samples of its LED within a
    ``(2 radius + 1)²`` pixel box, shape ``(L, P, 3)`` (invalid samples: 0).

    A low percentile of noisy samples sits ≈ 3σ below their level; averaged over 25
    pixels, σ falls 5×, while the smooth diffuse floor that the percentile looks
    for keeps its level. ``values`` (L, P, 3), ``valid`` (L, P), ``pixels`` (P, 2) rows
    and columns. Compiled running sums (:func:`box_mean_numpy` is the reference).
    """
    rows = np.ascontiguousarray(pixels[:, 0], dtype=np.intp)
    cols = np.ascontiguousarray(pixels[:, 1], dtype=np.intp)
    out = np.empty(np.shape(values), dtype=np.float64)
    if out.size == 0:
        return out
    _kernels.box_mean(np.ascontiguousarray(values, dtype=np.float64), np.ascontiguousarray(valid, dtype=np.bool_),
                      rows, cols, int(rows.max()) + 1, int(cols.max()) + 1, int(radius), out)
    return out


def box_mean_numpy(values: Array, valid: NDArray[np.bool_], pixels: NDArray[np.intp],
                   radius: int = BOX_RADIUS) -> Array:
    """NumPy/SciPy reference of :func:`box_mean` (``scipy.ndimage.uniform_filter``)."""

    n_l = values.shape[0]
    rows, cols = pixels[:, 0], pixels[:, 1]
    img = np.zeros((n_l, int(rows.max()) + 1, int(cols.max()) + 1, 4))
    img[:, rows, cols, :3] = np.where(valid[..., None], values, 0.0)
    img[:, rows, cols, 3] = valid
    size = (1, 2 * radius + 1, 2 * radius + 1, 1)
    img = uniform_filter(img, size=size, mode="constant")
    out = img[:, rows, cols]
    return np.divide(out[..., :3], out[..., 3:], out=np.zeros_like(values), where=valid[..., None] & (out[..., 3:] > 0))


#: A low percentile of noisy samples lies this many standard deviations below their
#: level: ``z = Φ⁻¹(1 − q/100)`` for :data:`KD_BOUND_PERCENTILE` ``q`` (2.88 at 0.2 %).
KD_BOUND_Z = float(NormalDist().inv_cdf(1.0 - KD_BOUND_PERCENTILE / 100.0))


def box_noise(noise: Array, valid: NDArray[np.bool_], pixels: NDArray[np.intp], radius: int = BOX_RADIUS) -> Array:
    """Standard deviation of :func:`box_mean`'s means, shape ``(L, P)``: ``√(Σ σ²)/n`` over
    the ``n`` valid samples of each box (independent pixel noise ``σ``, ``noise`` (L, P);
    0 at invalid samples)."""

    rows, cols = pixels[:, 0], pixels[:, 1]
    img = np.zeros((noise.shape[0], int(rows.max()) + 1, int(cols.max()) + 1, 2))
    img[:, rows, cols, 0] = np.where(valid, noise, 0.0) ** 2
    img[:, rows, cols, 1] = valid
    img = uniform_filter(img, size=(1, 2 * radius + 1, 2 * radius + 1, 1), mode="constant") * (2 * radius + 1) ** 2
    var, n = img[:, rows, cols, 0], img[:, rows, cols, 1]
    return np.sqrt(np.divide(np.maximum(var, 0.0), n * n, out=np.zeros_like(var), where=valid & (n > 0.5)))


def kd_bound(light: Array, view: Array, values: Array, valid: NDArray[np.bool_], pixels: NDArray[np.intp],
             max_deg: float, noise: Array | None = None) -> Array:
    """Upper bound of ρ_d per channel (shape ``(3,)``): :func:`kd_upper_bound` of the
    box-averaged slices (:func:`box_mean`) over the samples with θ_i, θ_o ≤ ``max_deg``,
    each raised by :data:`KD_BOUND_Z` times its noise.

    Real diffuse darkens at grazing incidence (the shared materials: down to 1/20 at
    85°), so grazing LEDs would hold the bound below ρ_d. Noise pulls a low percentile
    down: ≈ 3σ on the raw samples, and still ``z σ_box`` after the box mean (the
    as-built camera's shot noise: 1.5–4.5 % below ρ_d on the analytic lobes, and k_d
    then sits at that bound, its deficit divided by F into a floor under the whole NDF).
    With the camera's noise model (``noise``: per sample, shape (L, P), the standard
    deviation of a channel reading at the sample's luminance,
    :attr:`~reflecto.instrument.slices.Slices.noise`) each box mean is raised by
    ``z σ_box`` (:func:`box_noise`; for a channel ``v`` above the luminance by
    ``√(v/lum)`` more, as its shot noise grows), so that the percentile estimates the
    floor's level rather than its noise's lower tail. ``light`` (L, 3), ``view`` (P, 3), ``values`` (L, P, 3),
    ``valid`` (L, P), ``pixels`` (P, 2); directions in the sample frame. Without a
    valid sample within ``max_deg`` every valid sample bounds; without any, 0.
    """
    c_lim = math.cos(math.radians(max_deg))
    near = valid & (light[:, 2] >= c_lim)[:, None] & (view[:, 2] >= c_lim)[None, :]
    if not near.any():  # no sample that steep (a small max_deg, or the steep slices saturated): all of them
        near = valid
    if not near.any():
        return np.zeros(3)
    leds = np.flatnonzero(near.any(axis=1))  # box_mean costs per LED: only those that bound
    boxed = box_mean(values[leds], valid[leds], pixels)
    if noise is not None:
        lum = np.maximum(boxed @ LUM, 1e-300)
        # a channel's σ: ≤ σ(lum) below the luminance (read and shot noise both fall or
        # stay), ≤ σ(lum) √(v/lum) above it (shot noise grows as √v): the envelope, so
        # that the bound is never under-corrected
        grow = np.sqrt(np.maximum(boxed, 0.0) / lum[..., None])
        boxed = boxed + KD_BOUND_Z * box_noise(noise[leds], valid[leds], pixels)[..., None] * np.maximum(grow, 1.0)
    return np.maximum(kd_upper_bound(boxed, near[leds]), 0.0)


def kd_median_bound(light: Array, view: Array, values: Array, valid: NDArray[np.bool_], max_deg: float) -> Array:
    """``π ·`` the median of f per channel over the valid samples with θ_i, θ_o ≤ ``max_deg``
    (shape ``(3,)``; without such a sample, every valid one; without any, ``inf``).

    The bound of ρ_d that the isotropic path applies. ``f = ρ_d/π + specular ≥ ρ_d/π``
    holds at every sample for a Lambertian diffuse; a real diffuse term varies with
    angle (it darkens toward grazing), so the lowest samples (:func:`kd_bound`) sit
    below the level that fits the bulk of them. The median tolerates that variation on
    up to half the samples and still caps a ρ_d that a channel's misfit of the peak
    would otherwise raise far above everything measured. ``light`` (L, 3), ``view``
    (P, 3), ``values`` (L, P, 3), ``valid`` (L, P); directions in the sample frame.
    """
    c_lim = math.cos(math.radians(max_deg))
    near = valid & (light[:, 2] >= c_lim)[:, None] & (view[:, 2] >= c_lim)[None, :]
    if not near.any():
        near = valid
    if not near.any():
        return np.full(3, np.inf)
    # channel by channel (each gathered contiguous): the same order statistics as the median
    # over axis 0 of the (N, 3) gather, in less than half its time
    medians = np.array([np.median(values[..., c][near]) for c in range(values.shape[-1])])
    return math.pi * np.maximum(medians, 0.0)


def kd_upper_bound(values: Array, valid: NDArray[np.bool_]) -> Array:
    """``π · f_low`` per channel: ρ_d/π ≤ f everywhere, so ρ_d ≤ π min f (shape ``(3,)``).

    ``values`` (L, P, 3) in sr⁻¹, ``valid`` (L, P); ``f_low`` is the
    :data:`KD_BOUND_PERCENTILE` percentile of the valid samples, exactly as
    ``np.percentile(values[valid], q, axis=0)``.

    Only the order statistics near the bottom matter, so only values below a
    threshold are partitioned: an order statistic of a strided subsample, taken with a
    margin, bounds them from above whenever more than ``hi`` values lie below it
    (counted; otherwise that channel is gathered whole). One compiled pass gathers the
    values below the thresholds.
    """
    flat = values.reshape(-1, 3)
    ok = valid.ravel()
    n = int(np.count_nonzero(ok))
    if n == 0:
        raise ParameterError("kd_upper_bound: no valid sample")
    lo, hi, t = _percentile_ranks(n, KD_BOUND_PERCENTILE)
    thresholds = np.full(3, np.inf)
    sub = flat[::_SUBSAMPLE][ok[::_SUBSAMPLE]]
    m = 2 * (hi // _SUBSAMPLE) + 32
    if len(sub) > 4 * m:
        thresholds = np.partition(sub, m, axis=0)[m]
    low = np.empty((3, n))
    counts, equal = _kernels.gather_below(flat, ok, thresholds, low)
    out = np.empty(3)
    for ch in range(3):
        if counts[ch] + equal[ch] <= hi:  # the subsample's threshold kept too few: all values of the channel
            thresholds[ch] = np.inf
            counts, equal = _kernels.gather_below(flat, ok, thresholds, low)
        # ranks below counts[ch] are among the gathered values; the others up to hi
        # equal the threshold (quantized data tie there by the thousand: no partition)
        c = int(counts[ch])
        need = [r for r in sorted({lo, hi}) if r < c]
        part = np.partition(low[ch, :c], need) if need else low[ch, :0]
        a = float(part[lo]) if lo < c else float(thresholds[ch])
        b = float(part[hi]) if hi < c else float(thresholds[ch])
        out[ch] = _interpolate(a, b, t)
    return out * math.pi
