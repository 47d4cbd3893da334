"""The reconstruction of an anisotropic material: a hemicube NDF from the slices (§5.1–5.3).

::

    bin samples per LED and working texel                     samples.py
    repeat (3 to 5 times, until η moves < 1 %; Fresnel loop):
        fit η and k_d to overlapping bins (§5.1, eqs. 5–6)    fresnel_fit.py
        repeat (NDF/shadowing loop):
            partial NDFs (eq. 7), merged (eq. 9, each bin by
            its inverse variance under the camera's noise
            model) and completed by symmetry (eq. 3)          ndf.py
            S from the NDF (eq. 8)                            shadowing.py
            k_s per channel (linear least squares)
    smooth a wide lobe's flanks and the weak tails            ndf.py
    resample the NDF to the output hemicube (512² top, 512×256 sides)

An isotropic material is reconstructed by :mod:`.isotropic` instead, whose 1-D NDF
sees every ring of half vectors from all six LEDs; this path keeps the azimuthal
structure an anisotropic NDF has, which the slices sample only where they cross.

Colour: one NDF shared by R, G, B (built from the luminance-weighted partial NDFs);
``k_d`` and ``k_s`` per channel. One ``η`` (the luminance fit) for the three channels,
as in :mod:`.isotropic`; ``k_s ≤ 1`` per channel.

η and k_d come from the consistency of overlapping bins (direct and τ-symmetric
pairs, :mod:`.fresnel_fit`); k_d is bounded above by the Lambertian bound
``ρ_d ≤ π f`` over the samples with θ_i, θ_o ≤ ``kd_bound_max_deg``
(:func:`.samples.kd_bound`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from .. import _kernels
from ..colour import LUM
from ..fresnel import fresnel
from ..hemicube import Hemicube, hemicube
from ..instrument.slices import Slices
from ..model import MicrofacetBRDF
from ..shadowing import GridStencil, grid_stencil, sigma_table
from . import ndf as ndf_mod
from .fresnel_fit import FresnelFit, Pairs, fit_fresnel, overlap_pairs
from .samples import Bins, bin_samples, kd_bound
from .tuning import HEMICUBE_FIT

Array = NDArray[np.float64]

__all__ = ["HemicubeFit", "fit_hemicube", "auto_work_resolution", "Merge", "LoopState", "LoopResult", "merge_bins",
           "noise_weights", "symmetric_fill", "run_loop", "output_model"]

# Tuned numbers: what, units and provenance are in :mod:`.tuning` (hemicube_fit stage).
SHAKE_THRESHOLD = HEMICUBE_FIT.shake_threshold
WORK_SIGMA = HEMICUBE_FIT.work_sigma
WORK_QUAD = HEMICUBE_FIT.work_quad
LOST_LED_FRACTION = HEMICUBE_FIT.lost_led_fraction
CENSORED_FRACTION = HEMICUBE_FIT.censored_fraction


def auto_work_resolution(bins: Bins) -> int:
    """128, 256 or 512: finer where the specular peak spans few 128-texels.

    At N = 128 a texel near the normal is ≈ 0.9° wide while the camera samples the
    half vector every ≈ 0.2°, so peaks narrower than a few texels (α ≲ 0.07) are
    merged at a finer resolution. 512 is taken when the brightest LED's peak has
    fewer than 20 bins above half its maximum, 256 below 24.
    """
    g = (bins.f @ LUM) * bins.i[:, 2] * bins.o[:, 2]
    top = int(bins.led[int(np.argmax(g))])
    mine = g[bins.led == top]
    n_half = int(np.count_nonzero(mine > 0.5 * mine.max()))
    return 512 if n_half < 20 else 256 if n_half < 24 else 128


@dataclasses.dataclass
class HemicubeFit:
    """Result of :func:`fit_hemicube`.

    ``fresnel_error`` is E(η) of the last Fresnel fit and ``fresnel_error_at_check``
    at outer iteration 1 (§5.1); ``excluded_leds`` the LEDs left out because their
    exclusion explained E(η); ``lost_leds`` those with too few samples;
    ``ks_at_bound`` whether ``k_s ≤ 1`` binds in some channel.
    """

    model: MicrofacetBRDF
    eta: float
    fresnel_error: float
    fresnel_error_at_check: float
    excluded_leds: list[int]
    lost_leds: list[int]
    ks_at_bound: bool
    iterations: int
    #: ``k_d``'s ceiling per channel (:func:`.samples.kd_bound`), the box of the scalars' fit.
    kd_ceiling: Array | None = None


#: A hole fill: ``(cube, Σw, Σw·D, last, inner_holes) → (D, log lobe or None)``, where
#: ``last`` marks the passes of the final outer iteration and ``inner_holes`` a merge
#: whose holes lie inside the NDF (:attr:`Merge.inner_holes`).
HoleFill = Callable[[Hemicube, Array, Array, bool, bool], "tuple[Array, Array | None]"]


@dataclasses.dataclass
class Merge:
    """The bins of a working hemicube and what the NDF loop keeps fixed about them.

    ``symmetric``: eq. 9 adds every bin at ``h`` and at ``τh`` (eq. 3) and the Fresnel
    fit uses the τ-symmetric overlaps; without it (§5.5) each bin counts at ``h`` only.
    Bins with a noise model (:attr:`.samples.Bins.variance`) make the loop weigh the
    partial NDFs by their inverse variance (:func:`noise_weights`) instead of eq. 9's ``W``.
    """

    cube: Hemicube
    bins: Bins
    pairs: Pairs
    w_merge: Array
    o_cells: GridStencil
    bin_offsets: tuple[Array, Array]
    inner_holes: bool
    lost_leds: list[int]
    symmetric: bool = True


def merge_bins(work: Hemicube, bins: Bins, n_leds: int, per_led: Array, censored_fraction: float,
               symmetric: bool = True, pairs: Pairs | None = None) -> Merge:
    """A :class:`Merge` of ``bins`` (sorted by LED and texel) of ``n_leds`` LEDs.

    ``per_led`` (shape ``(n_leds,)``) counts each LED's measured samples. A tilt that
    sinks LEDs below the horizon (an LED with fewer than :data:`LOST_LED_FRACTION` of
    the median's samples is lost), or a slice below the detection limit (a
    ``censored_fraction`` above :data:`CENSORED_FRACTION`), leaves holes inside the
    NDF, not only at its grazing rim: they are filled lobe-guided in every iteration.
    ``pairs``: the overlaps (:func:`.fresnel_fit.overlap_pairs` with ``symmetric``)
    when already at hand.
    """
    lost = np.flatnonzero(per_led < LOST_LED_FRACTION * np.median(per_led)).tolist()
    pairs = overlap_pairs(bins, n_leds, symmetric=symmetric) if pairs is None else pairs
    return Merge(work, bins, pairs, bins.count * ndf_mod.merge_weights(bins.o),
                 grid_stencil(bins.o, *WORK_SIGMA), ndf_mod.bin_offsets(work, bins.h),
                 bool(lost) or censored_fraction > CENSORED_FRACTION, lost, symmetric)


def noise_weights(mg: Merge, st: LoopState) -> Array:
    """Inverse-variance merge weights of the bins' partial NDFs, shape ``(B,)``, median 1.

    Eq. 7 turns a bin's mean ``f`` into ``D̂ = (f − k_d/π) · 4 cos θ_i cos θ_o /
    (k_s F(θ_d) S(i) S(o))``, so its variance is ``Var f · (cos θ_i cos θ_o / (F S(i)
    S(o)))²`` up to the common ``(4/k_s)²``; ``Var f`` is the camera's noise model
    (:attr:`.samples.Bins.variance`). Weighing each bin by the inverse is the
    minimum-variance merge of a texel's estimates; eq. 9's ``W = √cos θ_o`` is the paper's
    choice for a camera whose noise it does not model. ``F`` and ``S`` are the state's.
    """
    b = mg.bins
    fres = np.maximum(fresnel(b.cos_d, float(st.eta @ LUM)), 1e-6)
    gain = b.i[:, 2] * b.o[:, 2] / (fres * np.maximum(st.s_led[b.led] * st.s_o, 1e-6))
    var = np.asarray(b.variance) * gain * gain
    w = np.divide(1.0, var, out=np.zeros_like(var), where=var > 0.0)
    if not np.any(w > 0.0):
        return mg.w_merge
    w[var <= 0.0] = w[w > 0.0].max()  # a noiseless bin (none on a camera with a noise model): the best weight
    return w / float(np.median(w))


def _prepare(sl: Slices, ok: NDArray[np.bool_], work_resolution: int | None) -> Merge:
    """Bins on the working hemicube (resolution chosen by :func:`auto_work_resolution`)."""
    meas = ok if sl.censored is None else ok & ~sl.censored
    work = hemicube(work_resolution or 128)
    bins = bin_samples(sl.light, sl.view, sl.values, meas, work, sl.noise)
    if work_resolution is None:
        n = auto_work_resolution(bins)
        if n != work.n:
            work = hemicube(n)
            bins = bin_samples(sl.light, sl.view, sl.values, meas, work, sl.noise)
    censored_fraction = 1.0 - float(meas.sum()) / max(float(ok.sum()), 1.0)
    return merge_bins(work, bins, sl.n_leds, meas.sum(axis=1), censored_fraction)


@dataclasses.dataclass
class LoopState:
    """What the NDF and Fresnel loops update: η, k_d, k_s, S at the LEDs and bins, the working NDF."""

    eta: Array
    kd: Array
    ks: Array
    s_led: Array
    s_o: Array
    d_work: Array
    log_lobe: Array | None = None
    norm: float = 1.0


def symmetric_fill(work: Hemicube, wsum: Array, wv: Array, last: bool, inner_holes: bool) -> tuple[Array, Array | None]:
    """The hole fill of the symmetric path: lobe-guided (:func:`.ndf.fill_holes_and_lobe`)
    in the last passes or where the holes lie inside the NDF, plain push–pull before."""
    if last or inner_holes:
        return ndf_mod.fill_holes_and_lobe(work, wsum, wv)
    return ndf_mod.push_pull(work, wsum, wv), None


def _ndf_pass(mg: Merge, st: LoopState, use, merged, fres: Array, last: bool, light: Array,
              fill: HoleFill = symmetric_fill) -> None:
    """One pass of the NDF/shadowing loop: eq. 7, eq. 9 (+ eq. 3 if symmetric), hole fill, S (eq. 8), k_s."""
    bins, work = mg.bins, mg.cube
    wsum, offsets = merged
    dh, d_lum = np.empty((len(bins), 3)), np.empty(len(bins))
    cos_io = bins.i[:, 2] * bins.o[:, 2]
    _kernels.partial_ndf(bins.f, st.kd / math.pi, cos_io, st.s_led, bins.led, st.s_o, fres, LUM, dh, d_lum)
    tex, tex_tau, wb = bins.texel[use], bins.texel_tau[use], mg.w_merge[use]
    wv = ndf_mod.merge_sums(work, tex, tex_tau, wb * d_lum[use], symmetric=mg.symmetric)
    if st.d_work.any():  # each texel's value moved to its centre (first order, previous NDF's slope)
        wv *= ndf_mod.position_correction(work, st.d_work, offsets)
    d, st.log_lobe = fill(work, wsum, wv, last, mg.inner_holes)
    d = np.maximum(d, 0.0)
    st.norm = float(d @ work.projected_solid_angles)
    if st.norm > 0.0:
        d /= st.norm
    else:  # no specular anywhere (a pure diffuse): any normalized NDF, k_s comes out 0
        d[:] = 1.0 / math.pi
        st.norm, st.log_lobe = 1.0, None
    st.d_work = d
    table = sigma_table(work, d, n_theta=WORK_SIGMA[0], n_phi=WORK_SIGMA[1], n_u=WORK_QUAD[0], n_phi_quad=WORK_QUAD[1])
    st.s_led = table.eval(light)
    st.s_o = table.eval_at(mg.o_cells)
    d_b = d[tex]
    den = float(np.sum(wb * d_b * d_b))
    st.ks = np.clip((wb * d_b) @ dh[use] / max(den, 1e-300), 0.0, 1.0)


def _fresnel_step(mg: Merge, st: LoopState, kd_max: Array, excluded: set[int], fixed_eta: float | None,
                  check: bool) -> FresnelFit:
    """η and k_d from the overlaps (§5.1, one η); at the check iteration an LED whose
    exclusion at least halves an E(η) above :data:`SHAKE_THRESHOLD` is excluded."""
    bins = mg.bins
    a = bins.i[:, 2] * bins.o[:, 2] / np.maximum(st.s_led[bins.led] * st.s_o, 1e-12)
    fit = fit_fresnel(bins, mg.pairs, a, len(st.s_led), st.kd, st.eta, kd_max, excluded, fixed_eta,
                      per_channel=False, diagnostics=False)
    if check and fit.error > SHAKE_THRESHOLD:
        trials = [(fit_fresnel(bins, mg.pairs, a, len(st.s_led), st.kd, st.eta, kd_max, {k}, fixed_eta,
                               per_channel=False, diagnostics=False).error, k) for k in range(len(st.s_led))]
        err, k = min(((e, k) for e, k in trials if np.isfinite(e)), default=(math.inf, None))
        if k is not None and err < 0.5 * fit.error:
            excluded.add(k)
            fit = fit_fresnel(bins, mg.pairs, a, len(st.s_led), st.kd, st.eta, kd_max, excluded, fixed_eta,
                              per_channel=False, diagnostics=False)
    return fit


@dataclasses.dataclass
class LoopResult:
    """The state after :func:`run_loop`, with E(η) last and at the check iteration, the
    LEDs excluded for inconsistency and the outer iterations run."""

    state: LoopState
    fresnel_error: float
    fresnel_error_at_check: float
    excluded_leds: list[int]
    iterations: int


def run_loop(mg: Merge, kd_max: Array, light: Array, *, fixed_eta: float | None = None, outer_iterations: int = 5,
             min_outer_iterations: int = 3, eta_tolerance: float = 0.01, inner_iterations: int = 2,
             fill: HoleFill = symmetric_fill) -> LoopResult:
    """The Fresnel loop around the NDF/shadowing loop (module docstring) on a :class:`Merge`.

    ``kd_max`` (3,) bounds ρ_d; ``light`` (L, 3) are the LED directions in the sample
    frame, one per LED index of the bins; ``fill`` completes the merged NDF.
    """
    n_leds = len(light)
    eta0 = 1.5 if fixed_eta is None else float(fixed_eta)
    st = LoopState(np.full(3, eta0), 0.5 * kd_max, np.ones(3), np.ones(n_leds), np.ones(len(mg.bins)),
                   np.zeros(mg.cube.size))
    excluded: set[int] = set()
    merged_for, merged = None, None
    e_check = fit_error = math.nan
    outer = 0
    for outer in range(outer_iterations):
        eta_before = float(st.eta @ LUM)
        fit = _fresnel_step(mg, st, kd_max, excluded, fixed_eta, check=outer == min(1, outer_iterations - 1))
        if outer == min(1, outer_iterations - 1):
            e_check = float(fit.error)
        fit_error = float(fit.error)
        if fit.n_pairs > 0 and np.all(np.isfinite(fit.eta)):
            st.eta, st.kd = fit.eta, fit.kd
        converged = abs(float(st.eta @ LUM) - eta_before) <= eta_tolerance * eta_before
        last = outer == outer_iterations - 1 or (outer >= min_outer_iterations - 1 and converged)
        use = ~np.isin(mg.bins.led, list(excluded)) if excluded else slice(None)
        if mg.bins.variance is not None:  # the weights follow η and S: merge anew each outer iteration
            mg = dataclasses.replace(mg, w_merge=noise_weights(mg, st))
            merged_for = None
        if merged_for != excluded:  # eq. 9's Σw and the samples' mean texel offsets, fixed while the bins are
            wsum = ndf_mod.merge_sums(mg.cube, mg.bins.texel[use], mg.bins.texel_tau[use], mg.w_merge[use],
                                      symmetric=mg.symmetric)
            offsets = ndf_mod.top_offsets(mg.cube, (mg.bin_offsets[0][use], mg.bin_offsets[1][use]),
                                          mg.bins.texel[use], mg.bins.texel_tau[use], mg.w_merge[use], wsum,
                                          symmetric=mg.symmetric)
            merged_for, merged = set(excluded), (wsum, offsets)
        fres = np.maximum(fresnel(mg.bins.cos_d[:, None], st.eta[None, :1]), 1e-6)
        for _ in range(inner_iterations):
            _ndf_pass(mg, st, use, merged, fres, last, light, fill)
        if last:
            break
    return LoopResult(st, fit_error, e_check, sorted(excluded), outer + 1)


def fit_hemicube(sl: Slices, ok: NDArray[np.bool_], *, fixed_eta: float | None = None,
                 work_resolution: int | None = None, resolution: int = 512, outer_iterations: int = 5,
                 min_outer_iterations: int = 3, eta_tolerance: float = 0.01, inner_iterations: int = 2,
                 kd_bound_max_deg: float = 75.0) -> HemicubeFit:
    """Reconstruct a hemicube NDF and the scalars from slices in the sample frame (module docstring)."""
    mg = _prepare(sl, ok, work_resolution)
    kd_max = kd_bound(sl.light, sl.view, sl.values, ok, sl.pixels, kd_bound_max_deg, sl.noise)
    r = run_loop(mg, kd_max, sl.light, fixed_eta=fixed_eta, outer_iterations=outer_iterations,
                 min_outer_iterations=min_outer_iterations, eta_tolerance=eta_tolerance,
                 inner_iterations=inner_iterations)
    st = r.state
    return HemicubeFit(output_model(mg, st, resolution), float(st.eta[0]), r.fresnel_error, r.fresnel_error_at_check,
                       r.excluded_leds, mg.lost_leds, bool(np.any(st.ks >= 1.0)), r.iterations, kd_max)


def output_model(mg: Merge, st: LoopState, resolution: int) -> MicrofacetBRDF:
    """Smooth the working NDF's flanks and tails, refine it to the output hemicube."""
    lobe = st.log_lobe - math.log(max(st.norm, 1e-300)) if st.log_lobe is not None else None
    d = ndf_mod.smooth_wide(mg.cube, st.d_work, lobe)
    d = ndf_mod.smooth_tails(mg.cube, d)
    d_out = ndf_mod.resample(mg.cube, np.maximum(d, 0.0), hemicube(resolution))
    return MicrofacetBRDF(d_out, st.kd, st.ks, st.eta)
