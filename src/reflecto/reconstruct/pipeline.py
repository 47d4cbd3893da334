"""The reconstruction of paper §5: slices → generalized microfacet BRDF.

::

    estimate the altered normal (§5.4)                       normal.py
    bin samples per LED and working texel                     samples.py
    repeat (3 to 5 times, until η moves < 1 %; Fresnel loop):
        fit η and k_d to overlapping bins (§5.1, eqs. 5–6)    fresnel_fit.py
        repeat (2 ≤ 6, NDF/shadowing loop):
            partial NDFs (eq. 7), merged (eq. 9) and
            completed by symmetry (eq. 3)                     ndf.py
            S from the NDF (eq. 8)                            shadowing.py
            k_s per channel (linear least squares)
    smooth a wide lobe's flanks (ndf.smooth_wide) and the weak tails (ndf.smooth_tails)
    resample the NDF to the output hemicube (512² top, 512×256 sides)

Colour: one NDF shared by R, G, B (built from the luminance-weighted per-channel
partial NDFs); k_d, k_s and η per channel (algorithm-reference §4.3 [R]). This keeps
the NDF's shape from the best-exposed data and puts colour in the scalars, which is
what the model can represent; coloured metals get their tint from k_s and η.

η and k_d come from the consistency of overlapping bins (direct and τ-symmetric
pairs, :mod:`.fresnel_fit`); k_s per channel from the partial NDFs against the
merged one. Samples are binned per LED and working texel first (:mod:`.samples`).
k_d is bounded above by the Lambertian bound ``ρ_d ≤ π f`` (a low percentile,
:func:`.samples.kd_upper_bound`, of the slices averaged over 5×5 pixels,
:func:`.samples.box_mean`, so that noise does not pull it down: as-built sweep median
0.446 → 0.360) over the samples with θ_i, θ_o ≤ 75°
(:attr:`Options.kd_bound_max_deg`): the diffuse of real materials darkens at grazing
incidence, and the four grazing LEDs (77–85°) see it at a fraction of its near-normal
level (the shared RGL and MERL materials: down to 1/20 at 85°), which held k_d near 0
(ideal sweep: median error 0.478 → 0.357).

Shake (§5.1): when E(η) exceeds :data:`SHAKE_THRESHOLD`, the capture is flagged; if
dropping one LED at least halves E(η), that LED is excluded and the fit repeated. A
second cue (:mod:`.symmetry`): a steep LED's slice whose mirror-symmetry plane misses
the frame's normal by more than :data:`.symmetry.PLANE_THRESHOLD_DEG` flags it too.

Energy: a reconstruction whose directional albedo exceeds 1 (extrapolation beyond
the measured cap) has k_d and k_s scaled down to albedo 1; the summary reports the
factor (``energy_scale``).
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .. import _kernels, geometry
from ..colour import LUM
from ..errors import ParameterError, ReflectoError
from ..fresnel import fresnel
from ..hemicube import hemicube
from ..model import MicrofacetBRDF
from ..shadowing import grid_stencil, sigma_table
from ..instrument.slices import Slices
from . import ndf as ndf_mod
from .consistency import PairCheck, pair_checks
from .repeat import RepeatCheck, repeat_checks
from .fresnel_fit import FresnelFit, fit_fresnel, overlap_pairs
from .normal import ConsistencyDistance, estimate_normal_consistency, refine_normal
from .samples import bin_samples, kd_bound
from .symmetry import PLANE_THRESHOLD_DEG, plane_offsets

Array = NDArray[np.float64]

#: E(η) (at the shake test, outer iteration 1) above this marks a shaken capture.
#: Clean captures of the 50 shared materials reach 0.57 (model mismatch; ideal and
#: as-built device alike), shaken ones 0.10–1.03, so no threshold separates them all
#: (issue 4, open): 0.7 keeps clean captures unflagged with a margin, and the
#: symmetry cue (:mod:`.symmetry`) finds most of the shakes E(η) misses.
SHAKE_THRESHOLD = 0.7


@dataclasses.dataclass
class Options:
    """Reconstruction settings.

    Attributes
    ----------
    resolution
        Output NDF hemicube N (paper: 512).
    work_resolution
        Hemicube N on which samples are merged; ``None`` chooses 128, 256 or 512 from
        the sharpness of the measured peak (:func:`auto_work_resolution`).
    estimate_normal
        Run §5.4 (:mod:`.normal`); needed for hand-held (tilted) captures. Off by
        default because it costs a first reconstruction and ≈ 150 distance evaluations.
    fixed_eta
        Use this η instead of fitting it (for layouts whose overlaps miss the lobe).
    max_tilt_deg
        Largest tilt searched by the normal estimate (degrees).
    outer_iterations, min_outer_iterations, eta_tolerance
        The Fresnel loop runs at least ``min_outer_iterations`` and at most
        ``outer_iterations`` times (paper: ≤ 5); it stops once the fitted (luminance) η
        moves by less than ``eta_tolerance`` (relative) from one iteration to the next.
        Most captures stop at 3; rough GGX lobes take 4–5 (α = 0.4, η = 2: 2.23, 2.17,
        2.04, 2.00).
    inner_iterations
        NDF/shadowing loop per Fresnel iteration (paper: ≤ 6; 2 converge here).
    detect_shake
        Flag captures whose E(η) exceeds :data:`SHAKE_THRESHOLD` (§5.1), whose check
        frames differ from their LEDs' slices (:mod:`.repeat`), whose steep slices are
        not mirror-symmetric about the normal (:mod:`.symmetry`), or whose LED pairs
        break isotropy or reciprocity (:mod:`.consistency`).
    anisotropic
        The material may be anisotropic (brushed metal, fabrics with a weave): the two
        shake cues that assume an isotropic BRDF (mirror planes, isotropy/reciprocity)
        are skipped; E(η) and the check frames remain. With the default ``False`` a clean anisotropic
        capture is flagged as shaken (analytic GGX with α_x/α_y = 2–4: 6 of 8).
    azimuthal_min
        Apply the azimuthal-minimum constraint of Wang et al. 2008 to S (§5.2). Off by
        default: it is exact for isotropic NDFs and biases S for anisotropic ones.
    energy_clamp
        Scale k_d, k_s down when the directional albedo exceeds 1.
    kd_bound_max_deg
        Only samples with θ_i, θ_o at most this (degrees) bound k_d from above. 75°
        keeps the two steep LEDs (37.8°, 67.1°) and leaves out the grazing ones, where
        a real diffuse no longer reflects like a Lambertian (see the module docstring).
    """

    resolution: int = 512
    work_resolution: int | None = None
    estimate_normal: bool = False
    max_tilt_deg: float = 16.0
    outer_iterations: int = 5
    min_outer_iterations: int = 3
    eta_tolerance: float = 0.01
    inner_iterations: int = 2
    detect_shake: bool = True
    anisotropic: bool = False
    fixed_eta: float | None = None
    azimuthal_min: bool = False
    energy_clamp: bool = True
    kd_bound_max_deg: float = 75.0

    def __post_init__(self) -> None:
        def bad(what: str) -> ParameterError:
            return ParameterError(f"reconstruction options: {what}")

        if self.resolution < 8 or (self.work_resolution is not None and self.work_resolution < 8):
            raise bad(f"hemicube resolutions must be ≥ 8, got {self.resolution} and {self.work_resolution}")
        if min(self.outer_iterations, self.inner_iterations, self.min_outer_iterations) < 1:
            raise bad("iteration counts must be ≥ 1")
        if not (math.isfinite(self.eta_tolerance) and self.eta_tolerance >= 0):
            raise bad(f"eta_tolerance must be finite and ≥ 0, got {self.eta_tolerance}")
        if self.fixed_eta is not None and not (math.isfinite(self.fixed_eta) and self.fixed_eta > 1.0):
            raise bad(f"a fixed η must be a finite relative index > 1, got {self.fixed_eta}")
        if not (math.isfinite(self.max_tilt_deg) and 0.0 < self.max_tilt_deg < 60.0):
            raise bad(f"max_tilt_deg must lie in (0°, 60°), got {self.max_tilt_deg}")
        if not (math.isfinite(self.kd_bound_max_deg) and 0.0 < self.kd_bound_max_deg <= 90.0):
            raise bad(f"kd_bound_max_deg must lie in (0°, 90°], got {self.kd_bound_max_deg}")


@dataclasses.dataclass
class ReconstructionResult:
    model: MicrofacetBRDF
    summary: dict[str, Any]


def auto_work_resolution(bins: Any) -> int:
    """128, 256 or 512: finer where the specular peak spans few 128-texels.

    At N = 128 a texel near the normal is ≈ 0.9° wide while the camera samples the
    half vector every ≈ 0.2°, so peaks narrower than a few texels (polished metals,
    α ≲ 0.07) are merged at a finer resolution, at a higher cost. 256 blurs a
    Beckmann α = 0.05 lobe (n_half 14) by a few per cent at 6° (BRDF error 1.7–2.9 %
    against 0.2–0.5 % at 512, with :func:`.ndf.position_correction`), so 512 is taken
    below 20; GGX α = 0.1 (26) stays at 128.
    """
    g = (bins.f @ LUM) * bins.i[:, 2] * bins.o[:, 2]
    top = int(bins.led[int(np.argmax(g))])
    mine = g[bins.led == top]
    n_half = int(np.count_nonzero(mine > 0.5 * mine.max()))
    return 512 if n_half < 20 else 256 if n_half < 24 else 128


#: Rings and azimuths of the half-vector quadrature of the energy check's albedo.
ALBEDO_QUAD = 48
#: The summary's median relative residual is taken over at most this many bins (an
#: even subsample; 2048 moves the median by ≤ 5 % of itself against all bins, e.g.
#: 0.00157 for 0.00151, and costs 0.6 ms instead of 3.4 ms at 8192).
RESIDUAL_BINS = 2048

#: (n_theta, n_phi) of the loop's σ tables (eq. 8); the final model uses the full grid.
WORK_SIGMA = (46, 64)
#: (rings, azimuths) of the loop's σ quadrature (the model's: 128 × 256). 128
#: azimuths gave the same errors on the smooth lobes of the analytic grid, but moved η
#: of sparkling materials (aventurnine 1.68 → 1.39): it skips texels of a spiky NDF.
WORK_QUAD = (64, 256)
#: An LED with fewer usable samples than this fraction of the median LED's is counted
#: as lost (below the tilted sample's horizon, or its slice below the detection
#: limit), and the NDF's holes take the lobe-guided fill in every iteration.
LOST_LED_FRACTION = 0.25
#: When more than this fraction of the valid samples is below the detection limit
#: (:attr:`Slices.censored`), the NDF's holes take the lobe-guided fill in every iteration.
CENSORED_FRACTION = 0.25


def _sigma_work(cube: Any, d: Array, azimuthal_min: bool):
    """σ table of the working NDF on a coarser grid (the loop's S; eq. 8)."""
    table = sigma_table(cube, d, n_theta=WORK_SIGMA[0], n_phi=WORK_SIGMA[1], n_u=WORK_QUAD[0], n_phi_quad=WORK_QUAD[1])
    return table.azimuthal_min() if azimuthal_min else table


def reconstruct(slices: Slices, options: Options | None = None) -> ReconstructionResult:
    """Reconstruct the microfacet BRDF from six slices (see the module docstring)."""
    opt = options or Options()
    t0 = time.perf_counter()
    n_leds = slices.n_leds
    v = slices.values
    valid = slices.valid & np.isfinite(v[..., 0] + v[..., 1] + v[..., 2])  # a NaN or ±inf channel poisons the sum
    if valid.sum() < 100:
        raise ReflectoError("capture: fewer than 100 valid samples (saturated, dark or outside the view cone)")
    # §5.4 altered normal: a first reconstruction in the device frame gives S; the
    # normal minimises the consistency distance; then everything runs in its frame
    frame = np.eye(3)
    sym_dist = float("nan")
    if opt.estimate_normal:
        n_first = opt.work_resolution or 128
        quick = dataclasses.replace(opt, estimate_normal=False, resolution=n_first, work_resolution=n_first,
                                    outer_iterations=2, min_outer_iterations=2, detect_shake=False,
                                    energy_clamp=False)
        shadow = reconstruct(slices, quick).model.shadowing
        coarse = ConsistencyDistance(slices, valid, shadow, n=32, stride=3, kd_bound_max_deg=opt.kd_bound_max_deg)
        fine = ConsistencyDistance(slices, valid, shadow, n=64, stride=1, kd_bound_max_deg=opt.kd_bound_max_deg)
        normal, sym_dist = estimate_normal_consistency(coarse, fine, opt.max_tilt_deg)
        # the first S was derived in the device frame, off by the tilt; S derived in
        # the found frame sharpens the distance around the truth: refine once more
        frame = geometry.frame_from_normal(normal, np.array([1.0, 0.0, 0.0]))
        shadow = reconstruct(slices.reframe(frame), quick).model.shadowing
        normal, sym_dist = refine_normal(ConsistencyDistance(slices, valid, shadow, n=64, stride=1, kd_bound_max_deg=opt.kd_bound_max_deg), normal, 0.5,
                                         maxfev=50, probe_deg=1.5)
        frame = geometry.frame_from_normal(normal, np.array([1.0, 0.0, 0.0]))
    sl = slices.reframe(frame) if opt.estimate_normal else slices
    # ρ_d/π ≤ f away from grazing (in the sample frame): an upper bound of k_d; half of it starts the fit
    ok = sl.valid & valid
    kd_max = kd_bound(sl.light, sl.view, sl.values, ok, sl.pixels, opt.kd_bound_max_deg)
    # samples below the camera's detection limit bound k_d (above) but are no NDF data
    meas = ok if sl.censored is None else ok & ~sl.censored
    work = hemicube(opt.work_resolution or 128)
    bins = bin_samples(sl.light, sl.view, sl.values, meas, work)
    if opt.work_resolution is None:
        n = auto_work_resolution(bins)
        if n != work.n:
            work = hemicube(n)
            bins = bin_samples(sl.light, sl.view, sl.values, meas, work)
    pairs = overlap_pairs(bins, n_leds)
    # a tilt that sinks LEDs below the horizon (or a slice below the detection limit)
    # leaves holes inside the NDF, not only at its grazing rim; the plain fill's flat
    # level there biases S, and through S the η of the next fit (GGX α = 0.1 at 10°
    # tilt: η 1.34 instead of 1.5)
    per_led = meas.sum(axis=1)
    censored_fraction = 1.0 - float(meas.sum()) / max(float(ok.sum()), 1.0)
    inner_holes = bool(np.any(per_led < LOST_LED_FRACTION * np.median(per_led))) or censored_fraction > CENSORED_FRACTION
    c = bins.cos_d
    cos_io = bins.i[:, 2] * bins.o[:, 2]
    w_merge = bins.count * ndf_mod.merge_weights(bins.o)  # eq. 9 per pixel, summed over the bin
    o_cells = grid_stencil(bins.o, *WORK_SIGMA)  # S(o) of every bin, against each iteration's table
    dh, d_lum = np.empty((len(bins), 3)), np.empty(len(bins))
    bin_dc, bin_dr = ndf_mod.bin_offsets(work, bins.h)
    merged_for: set[int] | None = None

    eta = np.full(3, 1.5 if opt.fixed_eta is None else float(opt.fixed_eta))
    kd = 0.5 * kd_max
    ks = np.ones(3)
    s_led = np.ones(n_leds)
    s_o = np.ones(len(bins))
    excluded: set[int] = set()
    fit: FresnelFit | None = None
    d_work = np.zeros(work.size)
    shake = False
    e_check = float("nan")  # E(η) where the shake test looks at it
    history = []
    for outer in range(opt.outer_iterations):
        a = cos_io / np.maximum(s_led[bins.led] * s_o, 1e-12)
        # from min_outer_iterations on, any iteration may be the last: those fit per channel
        per_channel = outer >= opt.min_outer_iterations - 1 or outer == opt.outer_iterations - 1
        eta_before = float(eta @ LUM)
        fit = fit_fresnel(bins, pairs, a, n_leds, kd, eta, kd_max, excluded, opt.fixed_eta, per_channel=per_channel,
                          diagnostics=per_channel)
        # shake (§5.1): judged once S is known (outer 1); the LED whose exclusion lowers
        # E(η) most is dropped and the fit repeated
        if outer == min(1, opt.outer_iterations - 1):
            e_check = float(fit.error)
        if opt.detect_shake and outer == min(1, opt.outer_iterations - 1) and e_check > SHAKE_THRESHOLD:
            shake = True
            best = (fit.error, None)
            for k in range(n_leds):
                trial = fit_fresnel(bins, pairs, a, n_leds, kd, eta, kd_max, {k}, opt.fixed_eta, per_channel=False,
                                    diagnostics=False)
                if np.isfinite(trial.error) and trial.error < best[0]:
                    best = (trial.error, k)
            # drop an LED only if that explains the inconsistency (E at least halves);
            # otherwise the shake spans several LEDs: keep the data, flag the capture
            if best[1] is not None and best[0] < 0.5 * fit.error:
                excluded.add(best[1])
                fit = fit_fresnel(bins, pairs, a, n_leds, kd, eta, kd_max, excluded, opt.fixed_eta,
                                  per_channel=per_channel, diagnostics=per_channel)
        if fit.n_pairs > 0 and np.all(np.isfinite(fit.eta)):
            eta, kd = fit.eta, fit.kd
        # converged once (luminance) η moves by less than the tolerance; the paper stops at 5
        converged = abs(float(eta @ LUM) - eta_before) <= opt.eta_tolerance * eta_before
        last = outer == opt.outer_iterations - 1 or (outer >= opt.min_outer_iterations - 1 and converged)
        use = ~np.isin(bins.led, list(excluded)) if excluded else slice(None)  # a slice: views, no copies
        tex, tex_tau, wb = bins.texel[use], bins.texel_tau[use], w_merge[use]
        if merged_for != excluded:  # eq. 9's Σw and the samples' mean texel offsets: fixed while the bins used are
            wsum = ndf_mod.merge_sums(work, tex, tex_tau, wb)
            offsets = ndf_mod.top_offsets(work, (bin_dc[use], bin_dr[use]), tex, tex_tau, wb, wsum)
            merged_for = set(excluded)
        # (B, 3), or (B, 1) while the fit shares one η (its first iterations); fixed within the inner loop
        fres = np.maximum(fresnel(c[:, None], eta[None, :1] if np.all(eta == eta[0]) else eta[None, :]), 1e-6)
        for inner in range(opt.inner_iterations):
            # eq. 7: k_s D per channel, 4 (f − k_d/π) a / F with a = cos θi cos θo / (S(i) S(o))
            _kernels.partial_ndf(bins.f, kd / math.pi, cos_io, s_led, bins.led, s_o, fres, LUM, dh, d_lum)
            wv = ndf_mod.merge_sums(work, tex, tex_tau, wb * d_lum[use])
            if d_work.any():  # each texel's value moved to its centre (first order, previous NDF's slope)
                wv *= ndf_mod.position_correction(work, d_work, offsets)
            # holes: plain push–pull while η and S settle; the lobe-guided fill (which
            # costs a fit) for the final NDF, whose tails set its normalization and S,
            # and throughout when holes lie inside the measured region (an LED lost,
            # or much of the capture below the detection limit; GGX α = 0.1, k_d = 0:
            # η 1.14 for 1.5 with the plain fill). Otherwise the plain fill tested
            # better on the analytic grid's GGX α = 0.4 (η within 1.8 % vs 2.6 %).
            if last or inner_holes:
                d_work, log_lobe = ndf_mod.fill_holes_and_lobe(work, wsum, wv)
            else:
                d_work, log_lobe = ndf_mod.push_pull(work, wsum, wv), None
            d_work = np.maximum(d_work, 0.0)
            norm = float(d_work @ work.projected_solid_angles)
            if norm > 0.0:
                d_work /= norm
            else:  # no specular anywhere (a pure diffuse): any normalized NDF, k_s comes out 0
                d_work[:] = 1.0 / math.pi
                norm, log_lobe = 1.0, None
            if not (last and inner == opt.inner_iterations - 1):  # the final S comes from the output NDF
                table = _sigma_work(work, d_work, opt.azimuthal_min)
                s_led = table.eval(sl.light)
                s_o = table.eval_at(o_cells)
            # k_s per channel: least squares of k_s,c·D against the partial NDFs (eq. 7)
            d_b = d_work[tex]
            den = float(np.sum(wb * d_b * d_b))
            ks = np.maximum((wb * d_b) @ dh[use] / max(den, 1e-300), 0.0)
        history.append({"eta": eta.tolist(), "E": fit.error, "kd": kd.tolist(), "ks": ks.tolist()})
        if last:
            break
    # second shake cue: slices whose mirror plane misses the normal (see .symmetry)
    plane_off: list[float | None] = []
    checks: list[PairCheck] = []
    repeats: list[RepeatCheck] = []
    if opt.detect_shake:
        # fourth, model-free and valid for any BRDF: check frames repeat their LED's slice
        repeats = repeat_checks(slices)
        if any(r.moved for r in repeats):
            shake = True
    if opt.detect_shake and not opt.anisotropic:
        plane_off = plane_offsets(sl.light, sl.view, sl.values, ok)
        if any(x is not None and abs(x) > PLANE_THRESHOLD_DEG for x in plane_off):
            shake = True
        # third: isotropy and reciprocity across LEDs, model-free (see .consistency)
        checks = pair_checks(sl.light, sl.view, sl.values, meas)
        if any(c.inconsistent for c in checks):
            shake = True
    out_cube = hemicube(opt.resolution)
    d_work = ndf_mod.smooth_wide(work, d_work, log_lobe - math.log(max(norm, 1e-300)) if log_lobe is not None else None)
    d_work = ndf_mod.smooth_tails(work, d_work)
    # clamped before the upsampling (bilinear weights keep it ≥ 0): one pass over the full table fewer
    d_out = ndf_mod.resample(work, np.maximum(d_work, 0.0), out_cube)
    model = MicrofacetBRDF(d_out, kd, ks, eta)
    # residual of the final model on the used bins (relative, luminance), on an even
    # subsample of at most RESIDUAL_BINS of them: a summary statistic, not a fit
    check = np.arange(len(bins))[use]
    check = check[:: -(-len(check) // RESIDUAL_BINS)]
    pred = model.eval(bins.i[check], bins.o[check]) @ LUM
    meas = bins.f[check] @ LUM
    rel = np.abs(pred - meas) / np.maximum(np.abs(meas), 1e-6)
    # 48 × 48 half vectors per direction: within 1e-3 of a 400 × 512 quadrature on GGX
    # and Beckmann lobes of α = 0.05–0.8 (anisotropic too); the clamp needs no more
    albedo_max = float(model.albedo(np.array([0.0, 40.0, 60.0, 75.0, 85.0]), n_u=ALBEDO_QUAD, n_phi=ALBEDO_QUAD).max())
    energy_scale = 1.0
    if opt.energy_clamp and albedo_max > 1.0:
        # a passive surface reflects at most what it receives: scale k_d, k_s to albedo 1
        energy_scale = 1.0 / albedo_max
        model = MicrofacetBRDF(model.ndf_values, kd * energy_scale, ks * energy_scale, eta, normalize=False)
    tilt = float(np.degrees(math.acos(min(1.0, frame[2, 2]))))
    summary = {
        "eta": model.eta.tolist(),
        "kd": model.kd.tolist(),
        "ks": model.ks.tolist(),
        "normal": frame[2].tolist(),
        "normal_tilt_deg": tilt,
        "symmetry_distance": sym_dist,
        "fresnel_error": None if fit is None else fit.error,
        "fresnel_error_median": None if fit is None else fit.error_median,
        "fresnel_error_at_check": e_check if math.isfinite(e_check) else None,
        "fresnel_pairs": 0 if fit is None else fit.n_pairs,
        "fresnel_theta_d_spread_deg": None if fit is None else fit.theta_d_spread_deg,
        "shake_detected": shake,
        "symmetry_plane_offsets_deg": plane_off,
        "consistency_checks": [dataclasses.asdict(c) for c in checks],
        "repeat_checks": [{k: (v if not isinstance(v, float) or math.isfinite(v) else None)
                           for k, v in dataclasses.asdict(r).items()} for r in repeats],
        "excluded_leds": sorted(excluded),
        "lost_leds": np.flatnonzero(per_led < LOST_LED_FRACTION * np.median(per_led)).tolist(),
        "censored_fraction": censored_fraction,
        "pair_error": None if fit is None else np.where(np.isfinite(fit.pair_error), fit.pair_error, -1).tolist(),
        "iterations": history,
        "samples": int(bins.count[use].sum()),
        "bins": int(len(tex)),
        "residual_median_rel": float(np.median(rel)),
        "albedo_max": min(albedo_max, 1.0) if energy_scale < 1 else albedo_max,
        "energy_scale": energy_scale,
        "seconds": time.perf_counter() - t0,
    }
    return ReconstructionResult(model, summary)
