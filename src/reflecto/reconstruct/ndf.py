"""Partial NDFs (eq. 7), their weighted merge and symmetry completion (eqs. 3, 9).

Eq. 7 with the constant 4 and ``∫D cos = 1`` (algorithm-reference §3.3; the paper's
"4π" only rescales k_s):

``D̂(h) = 4 f_s(i, o_h) (i·n)(o_h·n) / (S(i) S(o_h) F(i·h))``

Binned samples (:mod:`.samples`) are merged into a hemicube at a working resolution
(each texel the W-weighted mean of the bins that fall in it, eq. 9 with
``W = √(o_h·n)`` per pixel); completion by eq. 3 adds every bin a second time at ``τh``; texels that no
sample reaches are filled (:func:`fill_holes`): an anisotropic GGX or Beckmann lobe
fitted to the measured texels gives the shape, and push–pull (normalized convolution
over the texel pyramid) carries the measured-to-lobe ratio into the holes; below the
peak the table is smoothed (:func:`smooth_tails`), then resampled bilinearly to the
output resolution.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import spline_filter

from .. import _kernels
from ..hemicube import Hemicube, hemicube
from .tuning import NDF

Array = NDArray[np.float64]


def partial_ndf(f_s: Array, i: Array, o: Array, s_i: Array, s_o: Array, fres: Array) -> Array:
    """Eq. 7 per sample: ``4 f_s (i·n)(o·n) / (S(i) S(o) F)`` (sr⁻¹ × k_s); broadcasts."""
    den = s_i * s_o * fres
    num = 4.0 * f_s * i[..., 2] * o[..., 2]
    return np.divide(num, den, out=np.zeros(np.broadcast_shapes(num.shape, den.shape)), where=den > 0)


def merge_weights(o: Array) -> Array:
    """Eq. 9: ``W = √⟨o_h·n⟩`` (o_h is the pixel's view direction)."""
    return np.sqrt(np.maximum(o[..., 2], 0.0))


def merge_sums(cube: Hemicube, texel: NDArray[np.intp], texel_tau: NDArray[np.intp], x: Array,
               symmetric: bool = True) -> Array:
    """``Σ x`` per texel over the values at ``h`` and, if ``symmetric``, at ``τh`` (eqs. 3, 9)."""
    out = np.bincount(texel, weights=x, minlength=cube.size)
    if symmetric:
        out += np.bincount(texel_tau, weights=x, minlength=cube.size)
    return out  # type: ignore[return-value]  # numpy stub: weighted bincount is float64, not intp


def bin_offsets(cube: Hemicube, h: Array) -> tuple[Array, Array]:
    """Offset of each half vector ``h`` (B, 3) from its top-face texel's centre, in
    texels: ``(Δcol, Δrow)``, each shape ``(B,)``; 0 off the top face."""
    face, col, row = cube._face_coords(h)
    top = face == 0
    return np.where(top, col - np.floor(col + 0.5), 0.0), np.where(top, row - np.floor(row + 0.5), 0.0)


def top_offsets(cube: Hemicube, offsets: tuple[Array, Array], texel: NDArray[np.intp], texel_tau: NDArray[np.intp],
                w: Array, wsum: Array, symmetric: bool = True) -> tuple[Array, Array]:
    """Mean position of the merged samples within each top-face texel, in texels.

    A texel's merged value is the weighted mean of its samples, which sit at ``h``
    (and, mirrored by eq. 3's τ, at ``τh``), not at the texel's centre; the camera
    samples the half vector along sparse curves, so the mean offset of a texel is up
    to half a texel and varies from texel to texel. ``offsets`` are the bins' own
    (:func:`bin_offsets`). Returns ``(Δcol, Δrow)``, shape ``(N, N)`` each,
    ``Σ w·Δ / Σ w`` per texel (0 where nothing was merged); without ``symmetric``
    (§5.5: no τ images in the merge) the samples count at ``h`` only.
    """
    n = cube.n
    inv = np.divide(1.0, wsum[: n * n], out=np.zeros(n * n), where=wsum[: n * n] > 0)
    out = []
    for d in offsets:  # τ = diag(−1, −1, 1) mirrors a top-face offset to its negative
        wd = w * d
        s = np.bincount(texel, weights=wd, minlength=cube.size)[: n * n]
        if symmetric:
            s -= np.bincount(texel_tau, weights=wd, minlength=cube.size)[: n * n]
        out.append((s * inv).reshape(n, n))
    return out[0], out[1]  # type: ignore[return-value]  # numpy stub: weighted bincount is float64, not intp


# Tuned numbers: what, units and provenance are in :mod:`.tuning` (ndf stage).
POSITION_CORRECTION_CLIP = NDF.position_correction_clip


def position_correction(cube: Hemicube, d: Array, offsets: tuple[Array, Array]) -> Array:
    """Factor that moves each top-face texel's merged value to the texel's centre.

    First order: ``D(centre) ≈ D(mean sample) · exp(−∇log D · Δ)``, with the gradient
    of ``log d`` (an earlier estimate of the NDF on the same cube) by central
    differences and ``Δ`` from :func:`top_offsets`. A steep lobe (GGX α = 0.05: log D
    falls ≈ 0.1 per 0.18° texel at 1.5° from the peak) otherwise shows the sampling
    curves as ±3–5 % streaks. Returns factors for all texels, shape ``(cube.size,)``
    (1 off the top face and at its border).
    """
    n = cube.n
    lg = np.log(np.maximum(d[: n * n], 1e-300)).reshape(n, n)
    gc = np.zeros((n, n))
    gr = np.zeros((n, n))
    gc[:, 1:-1] = 0.5 * (lg[:, 2:] - lg[:, :-2])
    gr[1:-1, :] = 0.5 * (lg[2:, :] - lg[:-2, :])
    corr = np.ones(cube.size)
    corr[: n * n] = np.exp(np.clip(-(gc * offsets[0] + gr * offsets[1]), *np.log(POSITION_CORRECTION_CLIP))).ravel()
    return corr


def push_pull(cube: Hemicube, wsum: Array, wvsum: Array, min_weight: float = 1e-12) -> Array:
    """Fill texels without samples from coarser levels of the texel pyramid.

    Each level sums ``Σw`` and ``Σw·v`` over 2×2 blocks; going back up, a hole takes
    the coarser level's estimate interpolated bilinearly at its direction (so the fill
    is continuous, not blocky). Measured texels are never changed.
    """
    cubes = [cube]
    # Σw and Σw·v side by side: one block reduction per level sums both
    levels = [np.stack([np.asarray(wsum, dtype=np.float64), np.asarray(wvsum, dtype=np.float64)], axis=1)]
    while cubes[-1].n > 4:
        levels.append(cubes[-1].block_reduce(levels[-1], 2))
        cubes.append(cubes[-1]._coarse(2))
    ws, vs = [x[:, 0] for x in levels], [x[:, 1] for x in levels]
    # coarsest level: fill any remaining hole with the global mean
    w, v = ws[-1], vs[-1]
    total_w = max(float(w.sum()), min_weight)
    est = np.where(w > min_weight, v / np.maximum(w, min_weight), float(v.sum()) / total_w)
    for k in range(len(ws) - 2, -1, -1):
        # holes take the coarser estimate interpolated bilinearly (continuous fill)
        fine = np.empty(cubes[k].size)
        _kernels.pull(cubes[k + 1].pad(est), cubes[k + 1]._pad_offsets, cubes[k + 1].n, ws[k], vs[k], min_weight, fine)
        est = fine
    return est


LOBE_FLOOR = NDF.lobe_floor


@functools.lru_cache(maxsize=8)
def _slope_terms(n: int) -> tuple[Array, Array]:
    """Per texel of ``hemicube(n)``: ``[1, s_x², 2 s_x s_y, s_y²]`` (s = slope) and ``log cos⁴θ``."""
    h = hemicube(n).directions
    sx, sy = h[:, 0] / h[:, 2], h[:, 1] / h[:, 2]
    x = np.stack([np.ones_like(sx), sx * sx, 2.0 * sx * sy, sy * sy], axis=1)
    log_c4 = 4.0 * np.log(h[:, 2])
    x.setflags(write=False)
    log_c4.setflags(write=False)
    return x, log_c4


def fit_lobe(cube: Hemicube, wsum: Array, wvsum: Array) -> Array | None:
    """Log of an anisotropic GGX or Beckmann lobe fitted to the measured NDF texels, or ``None``.

    Both families are linear in the slopes' quadratic form ``sᵀBs`` after a transform
    (``s = (h_x, h_y)/h_z``; Walter et al. 2007)::

        GGX:       (D cos⁴θ)^(−½) = a + sᵀBs        (D ∝ 1 / (cos⁴θ (1 + sᵀAs)²))
        Beckmann:  log(D cos⁴θ)   = a − sᵀBs        (D ∝ exp(−sᵀAs) / cos⁴θ)

    so each is one weighted linear least-squares fit, done on 2×2 texel blocks (the
    lobe only guides :func:`fill_holes`; weights: the merge weights, scaled so that the
    residual is a relative error of D; texels below :data:`LOBE_FLOOR` of the peak are
    left out). Returns ``log D`` of the family with the smaller weighted log-RMS
    misfit at every texel of ``cube`` (same scale as the data; in log because grazing
    tails underflow); ``None`` if neither gives a positive-definite ``B``.

    Parameters
    ----------
    wsum, wvsum
        ``Σw`` and ``Σw·D`` per texel (0 where unmeasured), shape ``(cube.size,)``.
    """
    n_fit = cube.n // 2 if cube.n >= 32 else cube.n
    w = cube.block_reduce(wsum, 2) if n_fit != cube.n else wsum
    wv = cube.block_reduce(wvsum, 2) if n_fit != cube.n else wvsum
    v = np.where(w > 0, wv / np.where(w > 0, w, 1.0), 0.0)
    obs = (w > 0) & (v > LOBE_FLOOR * max(float(v.max()), 1e-300))
    if np.count_nonzero(obs) < 20:
        return None
    x_fit, log_c4_fit = _slope_terms(n_fit)
    x, wo = x_fit[obs], w[obs]
    log_vc4 = np.log(v[obs]) + log_c4_fit[obs]
    best: tuple[float, str, NDArray[np.floating]] | None = None
    for family in ("ggx", "beckmann"):
        if family == "ggx":
            y, ww = np.exp(-0.5 * log_vc4), wo * np.exp(log_vc4)  # δD/D = −2 δy/y
        else:
            y, ww = log_vc4, wo
        # normal equations of the 4-parameter weighted fit (an SVD of the (M, 4) system
        # costs ≈ 10× more); lstsq where they are singular
        xw = x * ww[:, None]
        try:
            coef = np.linalg.solve(xw.T @ x, xw.T @ y)
        except np.linalg.LinAlgError:
            sw = np.sqrt(ww)
            coef = np.linalg.lstsq(x * sw[:, None], y * sw, rcond=None)[0]
        b = np.array([[coef[1], coef[2]], [coef[2], coef[3]]])
        if np.any(np.linalg.eigvalsh(b if family == "ggx" else -b) <= 0) or (family == "ggx" and coef[0] <= 0):
            continue
        q = x @ coef
        log_fit = -2.0 * np.log(q) if family == "ggx" else q  # log(lobe · cos⁴θ) at the fitted blocks
        misfit = float(np.sqrt(np.sum(wo * (log_vc4 - log_fit) ** 2) / np.sum(wo)))
        if np.isfinite(misfit) and (best is None or misfit < best[0]):
            best = (misfit, family, coef)
    if best is None:
        return None
    _, family, coef = best
    x_all, log_c4 = _slope_terms(cube.n)
    q = x_all @ coef
    return (-2.0 * np.log(q) if family == "ggx" else q) - log_c4


def fill_holes(cube: Hemicube, wsum: Array, wvsum: Array, min_weight: float = 1e-12) -> Array:
    """Merged NDF with the texels that no sample reaches filled (measured texels unchanged).

    See :func:`fill_holes_and_lobe`, which also returns the fitted lobe.
    """
    return fill_holes_and_lobe(cube, wsum, wvsum, min_weight)[0]


def fill_holes_and_lobe(cube: Hemicube, wsum: Array, wvsum: Array,
                        min_weight: float = 1e-12) -> tuple[Array, Array | None]:
    """Merged NDF with the texels that no sample reaches filled, and ``log`` of the guiding lobe.

    Plain push–pull fills a hole with a smooth average of its measured neighbours, so
    beyond the measured region (grazing θ_h, where the layout sees nothing) the NDF
    would stay flat at its last measured level. Here the hole takes the shape of a lobe
    fitted to the measured texels (:func:`fit_lobe`) times the push–pulled ratio
    ``D/lobe`` (in log), so it decays as a microfacet NDF does and joins the measured
    texels continuously; it is capped by the plain push–pull value. Falls back to
    plain push–pull when no lobe fits.
    """
    obs = wsum > min_weight
    log_lobe = fit_lobe(cube, np.where(obs, wsum, 0.0), np.where(obs, wvsum, 0.0))
    if log_lobe is None:
        return push_pull(cube, wsum, wvsum, min_weight), None
    plain = push_pull(cube, wsum, wvsum, min_weight)
    v = np.where(obs, wvsum / np.maximum(wsum, min_weight), 0.0)
    # the ratio is taken where the lobe was fitted: in the deep tail the measured
    # values are noise and diffuse residue, orders of magnitude off any lobe
    pos = obs & (v > LOBE_FLOOR * max(float(v.max()), 1e-300))
    if not np.any(pos):
        return plain, log_lobe
    w = np.where(pos, wsum, 0.0)
    ratio = np.zeros(cube.size)
    ratio[pos] = np.log(v[pos]) - log_lobe[pos]
    guided = np.exp(np.minimum(log_lobe + push_pull(cube, w, w * ratio, min_weight), 700.0))
    # a hole never exceeds the flat fill: the lobe only makes tails decay
    return np.where(obs, v, np.minimum(guided, plain)), log_lobe


WIDE_SMOOTH_FRACTION = NDF.wide_smooth_fraction
WIDE_SMOOTH_START = NDF.wide_smooth_start
WIDE_SMOOTH_FULL = NDF.wide_smooth_full
WIDE_SMOOTH_FLOOR = NDF.wide_smooth_floor
WIDE_SMOOTH_FADE = NDF.wide_smooth_fade
WIDE_SMOOTH_MISFIT = NDF.wide_smooth_misfit
WIDE_SMOOTH_N = NDF.wide_smooth_n
WIDE_SMOOTH_MAX_PASSES = NDF.wide_smooth_max_passes


def half_width(cube: Hemicube, d: Array) -> float:
    """Narrowest half width at half maximum of the NDF's peak (radians).

    From the texels where ``D ≥ max D / 2``: the covariance of their slopes
    ``(h_x, h_y)/h_z`` (projected-solid-angle weights) has eigenvalues ``a²/4`` for an
    elliptical region of slope semi-axes ``a``; returns ``atan(2 √λ_min)``.
    """
    peak = float(d.max()) if d.size else 0.0
    if not peak > 0:
        return 0.0
    sel = d >= 0.5 * peak
    h = cube.directions[sel]
    w = cube.projected_solid_angles[sel]
    s = h[:, :2] / h[:, 2:3]
    mean = (w @ s) / w.sum()
    c = ((s - mean) * w[:, None]).T @ (s - mean) / w.sum()
    return math.atan(2.0 * math.sqrt(max(float(np.linalg.eigvalsh(c)[0]), 0.0)))


def smooth_wide(cube: Hemicube, d: Array, log_lobe: Array | None) -> Array:
    """Smooth a wide lobe's flanks at a fifth of its half width, relative to its fitted lobe.

    Away from the peak a texel is reached by few of the camera's sparse sampling curves,
    and the merged NDF of a wide lobe (GGX α = 0.4) shows them as arcs ±10 % off the
    truth, a few texels apart, while the NDF itself varies over tens of degrees. So
    ``log D' = L + (1 − w) r + w·S(r)``, where ``L`` is the fitted lobe
    (:func:`fit_lobe`), ``r = log D − L`` and ``S`` a binomial filter of σ =
    :data:`WIDE_SMOOTH_FRACTION` × the narrowest half width (:func:`half_width`, at
    :data:`WIDE_SMOOTH_N`, at most :data:`WIDE_SMOOTH_MAX_PASSES` passes, over the
    texels above :data:`WIDE_SMOOTH_FLOOR` of the maximum); ``w`` is 0 above
    :data:`WIDE_SMOOTH_START` of the maximum (the peak keeps its data), 1 from
    :data:`WIDE_SMOOTH_FULL` down to :data:`WIDE_SMOOTH_FADE`, and 0 again below
    :data:`WIDE_SMOOTH_FLOOR` (deep tails are :func:`smooth_tails`' business).
    Filtering ``r`` rather than ``log D`` keeps the lobe's curvature: filtering
    ``log D`` lowered Beckmann α = 0.2 flanks by 1–2 % (the filtered mean of a concave
    function); for the same reason the NDF is left unchanged where the lobe misses it
    by more than :data:`WIDE_SMOOTH_MISFIT` (log-RMS), as it is for a peak narrower
    than ≈ 3.5° (σ under half a filter texel) and for an NDF without a lobe. The mass
    is kept. The levels are those of ``D`` itself, relative to its maximum.
    """
    hw = half_width(cube, d)
    passes = int(round(2.0 * (WIDE_SMOOTH_FRACTION * hw / (0.5 * math.pi / WIDE_SMOOTH_N)) ** 2))
    passes = min(passes, WIDE_SMOOTH_MAX_PASSES)
    if passes < 1 or log_lobe is None or cube.n < WIDE_SMOOTH_N:
        return d
    peak = float(d.max())
    lobe = np.maximum(log_lobe, math.log(1e-12 * peak))
    log_d = np.log(np.maximum(d, 1e-12 * peak))
    r = log_d - lobe
    level = log_d - math.log(peak)
    inside = (level >= math.log(WIDE_SMOOTH_FLOOR)).astype(np.float64)
    # a lobe that does not follow the NDF (a diffuse residue in the tail pulled the fit)
    # would put its curvature into r: then leave the NDF as it is
    om = cube.projected_solid_angles
    wm = om * (level >= math.log(WIDE_SMOOTH_FADE))
    r_mean = float(wm @ r) / float(wm.sum())
    if math.sqrt(float(wm @ (r - r_mean) ** 2) / float(wm.sum())) > WIDE_SMOOTH_MISFIT:
        return d
    # normalized convolution over the texels above the floor: the deep tail's r stays out
    f = cube.n // WIDE_SMOOTH_N
    coarse, low_w = cube.downsample(inside, f)
    _, low_r = cube.downsample(inside * r, f)
    num = resample(coarse, coarse.smooth(low_r, passes), cube)
    den = resample(coarse, coarse.smooth(low_w, passes), cube)
    smoothed = np.where(den > 1e-3, num / np.maximum(den, 1e-3), r)
    w = _ramp(-level, -math.log(WIDE_SMOOTH_START), -math.log(WIDE_SMOOTH_FULL))
    w *= _ramp(level, math.log(WIDE_SMOOTH_FLOOR), math.log(WIDE_SMOOTH_FADE))
    out = np.exp(np.minimum(lobe + r + w * (smoothed - r), 700.0))
    return out * (float(d @ om) / max(float(out @ om), 1e-300))


TAIL_KEEP = NDF.tail_keep
TAIL_FULL = NDF.tail_full
DEEP_FULL = NDF.deep_full
TAIL_PASSES_512 = NDF.tail_passes_512


def smooth_tails(cube: Hemicube, d: Array, passes: int | None = None) -> Array:
    """Smooth the NDF where it is weak, keep the peak.

    Away from the peak a texel's value rests on few, dim pixels from one or two LEDs,
    and neighbouring texels disagree by more than the NDF varies: texel-scale noise
    that no renderer's table can follow and that no real surface has. So
    ``log D' = w log D + (1 − w) log(k S)``, where ``S`` is ``log D`` filtered by a
    binomial filter of σ ≈ 0.45° (:data:`TAIL_PASSES_512` passes at N = 512, scaled
    by ``(N/512)²``) and, below :data:`DEEP_FULL` … :data:`TAIL_FULL` of the peak, at
    the 128-texel scale (σ ≈ 1.3°), exponentiated; ``w`` goes from 0 at
    :data:`TAIL_FULL` of the peak to 1 at :data:`TAIL_KEEP` of it, linearly in
    ``log D``; and ``k`` rescales the smoothed part to the mass it replaces, locally at
    the wide filter's scale. Nothing happens at N = 128, whose texels are wider.

    Why log D: a linear filter raised a Beckmann α = 0.05 tail by 6 % at 5°; a filter
    of log D (a geometric mean) leaves fast-falling tails nearly unbiased. Why ``k``:
    where texels scatter, a geometric mean sits below the arithmetic one; without
    ``k`` the tail of specular-maroon-phenolic lost 20 % of its mass, normalization
    lifted the peak, and its eq. 10 error rose by 50 %. With both, the analytic grid
    and the eq. 10 errors of the shared materials stay within ±2 % of the unsmoothed
    reconstruction, and the exported ``.bsdf`` files follow the model.
    """
    peak = float(d.max()) if d.size else 0.0
    if cube.n < 256 or not peak > 0:
        return d
    if passes is None:
        passes = int(TAIL_PASSES_512 * (cube.n / 512) ** 2)
    log_d = np.log(np.maximum(d, 1e-12 * peak))
    level = log_d / math.log(10.0) - math.log10(peak)  # log10(D / peak)
    narrow = cube.smooth(log_d, passes) if passes > 0 else log_d
    # deep tails (≲ 10⁻⁴ of the peak, a few photons per pixel): the 128-texel scale
    coarse, low = cube.downsample(log_d, cube.n // 128)
    wide = resample(coarse, coarse.smooth(low, 2), cube)
    w2 = _ramp(level, math.log10(DEEP_FULL), math.log10(TAIL_FULL))
    smoothed = np.exp(w2 * narrow + (1.0 - w2) * wide)
    w = _ramp(level, math.log10(TAIL_FULL), math.log10(TAIL_KEEP))
    # a geometric mean sits below the arithmetic one where texels scatter: rescale the
    # smoothed part to the mass it replaces, locally (at the wide filter's scale), so
    # that no mass moves between regions and normalization does not lift the peak
    wc = (1.0 - w) * cube.projected_solid_angles
    f = cube.n // 128
    num = resample(coarse, coarse.smooth(cube.block_reduce(wc * d, f), 2), cube)
    den = resample(coarse, coarse.smooth(cube.block_reduce(wc * smoothed, f), 2), cube)
    k = np.where(den > 0, num / np.maximum(den, 1e-300), 1.0)
    return np.where(w >= 1.0, d, np.exp(w * log_d) * (k * smoothed) ** (1.0 - w))


def _ramp(x: Array, lo: float, hi: float) -> Array:
    """0 below ``lo``, 1 above ``hi``, linear between."""
    return np.clip((x - lo) / (hi - lo), 0.0, 1.0)


CUBIC_OVERSHOOT = NDF.cubic_overshoot
CUBIC_FLOOR = NDF.cubic_floor


def resample(src: Hemicube, values: Array, dst: Hemicube) -> Array:
    """Resample a hemicube table to another resolution.

    Refinement by an integer factor (the reconstruction's working NDF to the output
    one): the top face by cubic spline interpolation of ``log D``, the side faces
    bilinearly. Bilinear interpolation of ``D`` cuts a lobe's peak: with N even the
    normal lies between four texel centres, 0.45° from each at N = 128, where GGX
    α = 0.1 is 2.3 % below its peak; a quadratic ``log D`` near the peak is what a
    cubic reproduces (GGX α = 0.1: BRDF error 0.47 → 0.32 %). Only texels above
    :data:`CUBIC_FLOOR` of the peak take the cubic (blended in across it), and its
    overshoot is clipped to :data:`CUBIC_OVERSHOOT` times the coarse maximum.
    Otherwise bilinear lookup.
    """
    if src.n == dst.n:
        return values.copy()
    if dst.n % src.n == 0 and np.ndim(values) == 1:  # refinement: texel centres on a fixed grid
        out = np.empty(dst.size)
        _kernels.upsample(src.pad(values), src._pad_offsets, src.n, dst.n // src.n, out)
        n, m = src.n, dst.n // src.n
        top = np.asarray(values[: n * n], dtype=np.float64).reshape(n, n)
        peak = float(top.max())
        if peak > 0.0 and np.all(np.isfinite(top)):
            k = dst.n * dst.n
            cub = _log_cubic_refine(np.log(np.maximum(top, CUBIC_FLOOR[0] * peak)), m, CUBIC_OVERSHOOT * peak)
            # the cubic only within the lobe: blended in from CUBIC_FLOOR (bilinear below)
            lo, hi = np.log(CUBIC_FLOOR[0]), np.log(CUBIC_FLOOR[1])
            t = np.clip((np.log(np.maximum(out[:k], 1e-300) / peak) - lo) / (hi - lo), 0.0, 1.0)
            out[:k] += t * (cub - out[:k])
        return out
    return src.lookup(values, dst.directions)


_CUBIC_PAD = NDF.cubic_pad


@functools.lru_cache(maxsize=8)
def _cubic_weights(n: int, m: int) -> Array:
    """Cubic B-spline weights, shape ``(n m, n + 2 pad)``: row ``j`` evaluates the spline
    of the padded coefficients at the centre of fine texel ``j`` (a fixed grid, so the
    2-D evaluation is two matrix products)."""
    x = (np.arange(n * m) + 0.5) / m - 0.5 + _CUBIC_PAD  # in padded coarse coordinates
    k0 = np.floor(x).astype(int) - 1
    w = np.zeros((n * m, n + 2 * _CUBIC_PAD))
    for t in range(4):
        k = k0 + t
        d = np.abs(x - k)
        b = np.where(d < 1.0, 2.0 / 3.0 - d * d + 0.5 * d**3, np.where(d < 2.0, (2.0 - d) ** 3 / 6.0, 0.0))
        w[np.arange(n * m), k] += b
    w.setflags(write=False)
    return w


def _log_cubic_refine(log_top: Array, m: int, cap: float) -> Array:
    """``exp`` of the cubic spline of ``log_top`` (n × n) at the centres of an m-times
    finer grid, clipped to ``cap``; flattened, shape ``((n m)²,)``."""

    n = log_top.shape[0]
    coef = spline_filter(np.pad(log_top, _CUBIC_PAD, mode="edge"), order=3, mode="mirror")
    w = _cubic_weights(n, m)
    v = w @ coef @ w.T
    return np.minimum(np.exp(v, out=v), cap).ravel()
