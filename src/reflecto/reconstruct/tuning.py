"""Every tuned number of the reconstruction, with what it does and where its value comes from.

One frozen dataclass per stage (module) of :mod:`reflecto.reconstruct`, plus the polar
NDF table of :mod:`reflecto.polar` that the isotropic fit reconstructs into. Each
tuned number is a field whose metadata (:func:`tuned`) says

* ``name``: the module-level constant that aliases it (``isotropic.ETA_MAX``; ``also``
  lists further aliases in other modules), so that a reader of the module finds it here;
* ``what``: what the number does (with the paper's section or equation where one applies);
* ``units``;
* ``source``: where the value comes from, starting with one of :data:`KINDS`:

  - ``mechanism:`` it follows from the optics, the noise, the sampling or the physics
    (the text says how);
  - ``measurement:`` measured (the text says on what, and what was found);
  - ``tuning half:`` only the data could settle it: chosen on the tuning half of the 50
    shared materials (:mod:`reflecto.evaluate.split`) and checked on the validation half;
  - ``convention:`` a definition (a resolution, a reporting range);
  - ``unrecorded:`` no reason for the value could be found in the code, the docs or the
    history (the text says what was looked at); the number is kept as it is.

The module-level default instances (:data:`ISOTROPIC`, …) hold the values the
reconstruction uses: each module binds its constants to their fields
(``ETA_MAX = ISOTROPIC.eta_max``), so every use and every result stays as it was.
A changed setting is a new instance (``dataclasses.replace(ISOTROPIC, eta_max=20.0)``);
the instances themselves never change.

:func:`constants_table` writes the table of docs/design/reconstruction.md (*Constants*)
from these fields; ``python -m reflecto.reconstruct.tuning --update
docs/design/reconstruction.md`` rewrites it there, and ``tests/test_tuning.py`` fails when
the two differ.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from pathlib import Path
from typing import Any, ClassVar

from .. import polar

__all__ = ["KINDS", "tuned", "PolarTuning", "IsotropicFitTuning", "IsotropyTestTuning", "HemicubeFitTuning",
           "NDFTuning", "FresnelFitTuning", "SamplesTuning", "SymmetryTuning", "SymmetryTestTuning",
           "ConsistencyTuning", "RepeatTuning", "SynthesisTuning", "AsymmetricTuning", "NormalTuning",
           "ExtrapolationTuning", "PipelineTuning", "POLAR", "ISOTROPIC", "ISOTROPY", "HEMICUBE_FIT", "NDF",
           "FRESNEL_FIT", "SAMPLES", "SYMMETRY", "SYMMETRY_TEST", "CONSISTENCY", "REPEAT", "SYNTHESIS", "ASYMMETRIC",
           "NORMAL", "EXTRAPOLATION", "PIPELINE", "STAGES", "constants_table", "update_document", "BEGIN_MARKER",
           "END_MARKER"]

#: The kinds of provenance a field's ``source`` starts with (see the module docstring).
KINDS = ("mechanism", "measurement", "tuning half", "convention", "unrecorded")


def tuned(default: Any, *, name: str, what: str, units: str, source: str, also: tuple[str, ...] = ()) -> Any:
    """A dataclass field holding one tuned number and its documentation.

    ``name`` is the module-level constant that aliases the field in the stage's module
    (``'ETA_MAX'``; ``'MIN_PAIRS["isotropy"]'`` for one entry of a dict constant),
    ``also`` further aliases as ``'module.NAME'``. ``source`` must start with one of
    :data:`KINDS` followed by a colon.
    """
    kind = source.split(":", 1)[0]
    if kind not in KINDS or ":" not in source:
        raise ValueError(f"{name}: source must start with one of {KINDS} and a colon, got {source!r}")
    if not (what and units):
        raise ValueError(f"{name}: what and units must be given")
    return dataclasses.field(default=default, metadata={"name": name, "what": what, "units": units,
                                                         "source": source, "also": tuple(also)})


@dataclasses.dataclass(frozen=True)
class PolarTuning:
    """The polar NDF table ``D(θ_h)`` (:mod:`reflecto.polar`; eqs. 1, 8) that the isotropic fit fills.

    The values stay defined in :mod:`reflecto.polar` (below :mod:`reflecto.reconstruct`
    in the layers); the fields take them from there.
    """

    module: ClassVar[str] = "reflecto.polar"
    paper: ClassVar[str] = "eqs. 1, 8"

    pole_spacing: float = tuned(
        polar.POLE_SPACING, name="POLE_SPACING", units="rad (0.1°)",
        what="spacing of the NDF's polar nodes θ_k at the pole",
        source="mechanism: half the camera's angular sampling of the half vector (a pixel moves h by ≈ 0.2°), "
               "so that the sharpest peak the camera resolves is resolved by the table too")
    spacing_growth: float = tuned(
        polar.SPACING_GROWTH, name="SPACING_GROWTH", units="fraction of θ_h",
        what="the node spacing grows by this fraction of the polar angle (0.5° at 10°, 2° at 45°)",
        source="mechanism: a lobe's structure scales with its width, so a constant relative resolution (4 %)")


@dataclasses.dataclass(frozen=True)
class IsotropicFitTuning:
    """The isotropic fit: a 1-D NDF ``D(θ_h)`` fitted to the slices (:mod:`.isotropic`; §5.1–5.3, eq. 10)."""

    module: ClassVar[str] = "reflecto.reconstruct.isotropic"
    paper: ClassVar[str] = "§5.1–5.3, eq. 10"

    cells_per_interval: int = tuned(
        2, name="CELLS_PER_INTERVAL", units="cells",
        what="θ_h cells of the bins per interval between two NDF nodes",
        source="mechanism: second-order bin averaging within half a node interval (docs/design/reconstruction.md)")
    td_step: float = tuned(
        math.radians(1.0), name="TD_STEP", units="rad (1°)",
        what="width of the θ_d cells of the bins",
        source="mechanism: F and S vary slowly with θ_d; 1° cells average them to second order "
               "(docs/design/reconstruction.md)")
    smooth_length: float = tuned(
        math.radians(0.1), name="SMOOTH_LENGTH", units="rad (0.1°)",
        what="length scale of the curvature prior on log D",
        source="mechanism: below the camera's sampling of the half vector (≈ 0.2° per pixel), so that it shapes "
               "only what the data leave open (gaps between rings, the unobserved grazing rim), never a resolved lobe")
    tail_weight: float = tuned(
        1e3, name="TAIL_WEIGHT", units="relative to one radian of data",
        what="weight of the tail prior: beyond the last measured ring the NDF keeps the shape of the fitted lobe",
        source="mechanism: much more than one radian of data, so that the rim follows the lobe; "
               "no sweep of the value 10³ is recorded")
    monotone_weight: float = tuned(
        1e3, name="MONOTONE_WEIGHT", units="relative to one radian of data",
        what="weight of the unimodality prior (the NDF does not rise beyond its peak)",
        source="mechanism: a surface's NDF is unimodal; the weight is large, a constraint in effect "
               "(introduced in 8beb865); no sweep of the value 10³ is recorded")
    quiet_noise: float = tuned(
        0.01, name="QUIET_NOISE", units="fraction of a bin's value",
        what="the model error ε is estimated over bins whose camera noise is below this fraction of their value",
        source="mechanism: the camera noise model; ε is read where the camera noise is negligible "
               "(1 %: a reading of ≳ 30 DN on the 12-bit noiseless camera)")
    min_quiet_bins: int = tuned(
        100, name="MIN_QUIET_BINS", units="bins",
        what="…when at least this many bins are quiet (else ε is estimated over all measured bins)",
        source="measurement: the 25 tuning-half materials' fits (ideal device) hold 86–8,520 quiet bins, the fewest "
               "tungsten-carbide (86–106) and steel (93–141), which alone fall back to all bins in some fits; 50 and "
               "200 leave all 25 eq. 10 errors (every 3rd bin) and isotropy verdicts bit-identical")
    eta_max: float = tuned(
        50.0, name="ETA_MAX", units="relative index η", also=("fresnel_fit.ETA_MAX",),
        what="largest relative index searched (eq. 4), in the isotropic fit and in the Fresnel fit of the "
             "hemicube path; η at it reads as a metal-like flat Fresnel curve",
        source="mechanism: F0 = 0.92, a real-η metal's range (algorithm-reference §2.1)")
    eta_min: float = tuned(
        1.001, name="ETA_MIN", units="relative index η",
        what="smallest relative index searched (eq. 4)",
        source="mechanism: just above η = 1 (no interface): F0 = 2.5·10⁻⁷, below any dielectric "
               "(algorithm-reference §2.1)")
    mirror_theta_h: float = tuned(
        math.radians(0.5), name="MIRROR_THETA_H", units="rad (0.5°)",
        what="an LED's slice holds the mirror direction when one of its bins lies this close to θ_h = 0 "
             "(it then sets a node of the Fresnel tint)",
        source="mechanism: a camera pixel moves h by ≈ 0.2°, so a slice that holds the mirror direction has a "
               "sample within a pixel or two of it; on the paper's layout those LEDs reach 0.1° and the others "
               "16–29° (ideal device, red-metallic-paint)")
    outer_iterations: int = tuned(
        5, name="OUTER_ITERATIONS", units="iterations",
        what="outer iterations of fit_luminance (S from D, ε from the residuals)",
        source="mechanism: the paper's ≤ 5 (§5.3); S(D) converges within it on the analytic grid, "
               "not on 5 of the 50 shared materials (docs/design/reconstruction.md, *The fit*)")
    lm_tolerance: float = tuned(
        1e-5, name="LM_TOLERANCE", units="fraction of the cost",
        what="Levenberg–Marquardt stops when the cost falls by less than this fraction",
        source="measurement: on the 25 tuning-half materials (ideal device, eq. 10 at every 3rd bin) 10⁻⁶ moves the "
               "median error by −0.003 % (3 of 25 by 1–2.7 %, two worse) at the same CPU time (6.5 s against 6.3 s "
               "for the 25); 10⁻⁴ stops early: 5 of 25 worse by > 1 % (blue-fabric by 41 %)")
    node_rounds: int = tuned(
        2, name="NODE_ROUNDS", units="rounds",
        what="rounds of the NDF per θ_d node's refit (priors, Levenberg–Marquardt, S from the node's own D)",
        source="mechanism: the model's `S_j` is eq. 8 of the node's own `D_j`, so the last round is fitted with "
               "`S` from a refitted `D_j`, not the luminance fit's (the first round's); measurement: from the "
               "luminance fit's converged state, eq. 10 on the untilted ideal captures of validate_handheld.py "
               "(every second bin; geometric mean over the one-NDF fit), tuning half 0.952 with 1 round, 0.954 "
               "with 2 and with 3, validation half 0.951, 0.949, 0.949: within 0.2 % of each other")
    lm_max_iterations: int = tuned(
        40, name="LM_MAX_ITERATIONS", units="iterations",
        what="Levenberg–Marquardt iterations at most",
        source="measurement: 20 and 80 change the eq. 10 error of the 25 tuning-half materials (ideal device) by at "
               "most 0.7 % and 0.4 % (tungsten-carbide; median 0) in the same time: LM_TOLERANCE, not the cap, ends "
               "the fits")


@dataclasses.dataclass(frozen=True)
class IsotropyTestTuning:
    """The azimuthal-harmonic test: isotropic, anisotropic, eq. 3 broken? (:mod:`.isotropy`)."""

    module: ClassVar[str] = "reflecto.reconstruct.isotropy"
    paper: ClassVar[str] = "eq. 3, eq. 7"

    ring_width_deg: float = tuned(
        2.0, name="RING_WIDTH_DEG", units="deg",
        what="width of the rings of half vectors (θ_h)",
        source="mechanism: sampling; enough samples per ring for the 5-term regression "
               "(docs/design/reconstruction.md)")
    ring_start_deg: float = tuned(
        1.0, name="RING_START_DEG", units="deg",
        what="the rings start at this θ_h",
        source="mechanism: nearer the pole the azimuth φ_h of a half vector is ill defined")
    ring_end_deg: float = tuned(
        60.0, name="RING_END_DEG", units="deg",
        what="the rings end at this θ_h",
        source="measurement: on the 25 tuning-half materials and six analytic anisotropic GGX lobes (α_x/α_y 2–4, "
               "ideal device) 45° and 75° change no verdict; 75° adds up to 7 rings and moves a capture's fractions "
               "by ≤ 0.054, 45° drops up to 8 and moves them by ≤ 0.09")
    min_ring_samples: int = tuned(
        30, name="MIN_RING_SAMPLES", units="samples",
        what="a ring enters with at least this many samples",
        source="mechanism: sampling; enough samples per ring for the 5-term regression "
               "(docs/design/reconstruction.md)")
    max_condition: float = tuned(
        1e3, name="MAX_CONDITION", units="condition number",
        what="a ring enters only when the azimuthal spread of its samples conditions its regression below this",
        source="measurement: on the 25 tuning-half materials and six analytic anisotropic GGX lobes (ideal device) "
               "10⁴ admits at most one more ring and moves the fractions by ≤ 0.001; 10² drops up to 3 rings and "
               "moves the fractions by up to 0.09; neither changes a verdict")
    min_specular_fraction: float = tuned(
        0.5, name="MIN_SPECULAR_FRACTION", units="fraction of the BRDF",
        what="samples enter where the isotropic model's specular part is at least this fraction of the BRDF",
        source="mechanism: the partial NDF (eq. 7) is measured where the specular term dominates, "
               "not on the diffuse floor")
    anisotropy_explained: float = tuned(
        0.8, name="ANISOTROPY_EXPLAINED", units="fraction of variance",
        what="explained fraction of the ring-wise variance (second harmonic) above which the material is "
             "anisotropic",
        source="tuning half: isotropic materials ≤ 0.71, anisotropic lobes with α_x/α_y ≥ 1.5 ≥ 0.89; the midpoint")
    max_condition_conditional: float = tuned(
        1e6, name="MAX_CONDITION_CONDITIONAL", units="condition number",
        what="condition number bound of the conditional regression (seven standardized columns)",
        source="mechanism: a ring whose 7-term design is this ill-conditioned cannot separate φ_h from φ_d; "
               "it is left out (docs/design/reconstruction.md)")
    conditional_explained: float = tuned(
        0.47, name="CONDITIONAL_EXPLAINED", units="fraction of variance",
        what="fraction of the variance left by the isotropic-misfit basis (θ_d, θ_d², cos 2φ_d, sin 2φ_d per "
             "ring) that the second harmonic explains, above which (with ANISOTROPY_EXPLAINED) the material is "
             "anisotropic",
        source="tuning half: isotropic materials ≤ 0.42, analytic anisotropic lobes (α_x/α_y ≥ 1.5, GGX and "
               "Beckmann) ≥ 0.52; the midpoint. Validation half ≤ 0.37 (9481582)")
    min_rings: int = tuned(
        3, name="MIN_RINGS", units="rings",
        what="at least this many rings for a verdict; fewer (almost no specular signal) leave the material "
             "isotropic",
        source="measurement: the 25 tuning-half materials enter 0–30 rings (ideal device); those with 1–3 "
               "(tungsten-carbide, specular-white-phenolic, specular-maroon-phenolic, white-marble, white-paint) "
               "read second-harmonic fractions ≤ 0.25 and conditional ≤ 0.05, far below the thresholds, and the six "
               "analytic anisotropic lobes enter 7–12: any bound from 1 to 5 gives the same verdicts")
    pixel_stride: int = tuned(
        3, name="PIXEL_STRIDE", units="pixels",
        what="every this many pixels (per image axis) enters the test",
        source="measurement: on the 25 tuning-half materials and six analytic anisotropic GGX lobes (ideal device) "
               "every pixel (stride 1) moves a capture's fractions by ≤ 0.06 and changes no verdict at 4.2× the "
               "test's CPU time (2.96 s against 0.71 s for the 31); strides 2 and 6 move them by up to 0.05 and 0.11 "
               "and flip lobes within 0.04 of CONDITIONAL_EXPLAINED (1 and 2 of 6)")


@dataclasses.dataclass(frozen=True)
class HemicubeFitTuning:
    """The anisotropic path: a hemicube NDF fitted jointly with η, k_d, k_s, S (:mod:`.hemicube_fit`; §5.1–5.3)."""

    module: ClassVar[str] = "reflecto.reconstruct.hemicube_fit"
    paper: ClassVar[str] = "§5.1–5.3, eqs. 8, 9"

    shake_threshold: float = tuned(
        0.7, name="SHAKE_THRESHOLD", units="E(η)",
        what="E(η) at outer iteration 1 above which an LED is looked for whose exclusion at least halves E(η) "
             "(§5.1's shake handling)",
        source="measurement: on the path before b0d5371 (all materials through the hemicube fit), clean captures "
               "of the 50 shared materials reached 0.57 (ideal and as-built), shaken ones 0.10–1.03; 0.7 keeps "
               "clean captures unflagged with a margin, the other cues find the shakes E(η) misses (7bfc0d2; the "
               "comment in pipeline.py before b0d5371). Not re-measured on the anisotropic path alone")
    work_sigma: tuple[int, int] = tuned(
        (46, 64), name="WORK_SIGMA", units="(n_θ, n_φ) nodes",
        what="size of the loop's σ tables (eq. 8); the final model uses the full grid",
        source="measurement: (23, 32) raises the NDF error of six analytic anisotropic GGX lobes (α_x/α_y 2–4, ideal "
               "device) by up to 23 % (α 0.1 × 0.2: 0.30 → 0.37 %), (92, 128) changes it by ≤ 6 % (0.30 → 0.28 % at "
               "best); the 25 tuning-half materials forced through the path move by ≤ 0.75 % (eq. 10); the CPU time "
               "of the 31 fits is the same at all three sizes (21.3–22.0 s). Introduced in 7266107 as a speed size")
    work_quad: tuple[int, int] = tuned(
        (64, 256), name="WORK_QUAD", units="(rings, azimuths)",
        what="the loop's σ quadrature (the final model's: 128 × 256)",
        source="measurement: 64 × 128 gave the analytic grid's errors (565b5b7) but moved η of sparkling "
               "materials (aventurnine 1.68 → 1.39: it skips texels of a spiky NDF), so 256 azimuths (aa740b6)")
    lost_led_fraction: float = tuned(
        0.25, name="LOST_LED_FRACTION", units="fraction of the median LED's samples",
        what="an LED with fewer usable samples is counted as lost (below a tilted sample's horizon, or its slice "
             "below the detection limit), and the holes take the lobe-guided fill in every iteration",
        source="measurement: on captures tilted 10° and 15° (six analytic anisotropic GGX lobes, 8 tuning-half "
               "materials at 10°, forced through the anisotropic path, ideal device) an LED keeps either none or ≥ "
               "0.71 of the median LED's samples (but on brass and blue-metallic-paint2, whose median LED holds "
               "almost none), so 0.125 and 0.5 give bit-identical models there and on untilted captures. Introduced "
               "with the tilted-capture fill (80a162b)")
    censored_fraction: float = tuned(
        0.25, name="CENSORED_FRACTION", units="fraction of the valid samples",
        what="above this fraction below the detection limit, the NDF's holes take the lobe-guided fill in every "
             "iteration",
        source="measurement: with it, GGX α = 0.05, k_d = 0 went from 1.14–1.21 % to 0.52–0.54 % BRDF error and "
               "the analytic grid's BRDF ≤ 1 % from 45 to 47/48 (e882dab); no other value is recorded")


@dataclasses.dataclass(frozen=True)
class NDFTuning:
    """Partial NDFs, their merge, completion and output smoothing (:mod:`.ndf`; eqs. 3, 7, 9)."""

    module: ClassVar[str] = "reflecto.reconstruct.ndf"
    paper: ClassVar[str] = "eqs. 3, 7, 9"

    position_correction_clip: tuple[float, float] = tuned(
        (0.75, 1.33), name="POSITION_CORRECTION_CLIP", units="factor range",
        what="clip of the first-order correction that moves a texel's merged value (eq. 9) to its centre",
        source="measurement: (0.9, 1.11) changes the NDF error of six analytic anisotropic GGX lobes (α_x/α_y 2–4, "
               "ideal device) by ≤ 0.13 % and moves the 25 tuning-half materials forced through the anisotropic path "
               "by ≤ 2.8 % (eq. 10; 6 better, 1 worse by > 1 %); (0.5, 2) leaves the lobes unchanged and makes 2 "
               "materials worse by ≤ 1.35 %. Symmetric in log (1/0.75 = 1.33); introduced with the correction "
               "(c0dcead)")
    lobe_floor: float = tuned(
        1e-3, name="LOBE_FLOOR", units="fraction of the peak",
        what="texels below this fraction of the measured peak do not enter the lobe fit of the hole fill",
        source="measurement: 10⁻² lowers the NDF error of six analytic anisotropic GGX lobes (ideal device) by 1–29 % "
               "(0.30 → 0.21 %, 4.55 → 4.17 %) and moves the 25 tuning-half materials forced through the anisotropic "
               "path by ≤ 3.6 % (eq. 10; 2 worse, 1 better by > 1 %); 10⁻⁴ moves the lobes by −9 to +7 % and "
               "irid_flake_paint1 by 15 %. 10⁻³ (from 3afe7ab) is not the best value measured")
    wide_smooth_fraction: float = tuned(
        0.2, name="WIDE_SMOOTH_FRACTION", units="fraction of the narrowest HWHM",
        what="smooth_wide filters a wide lobe's flanks at this fraction of the peak's narrowest half width at "
             "half maximum (the camera's sampling curves leave arcs of ±10 % on GGX α = 0.4)",
        source="measurement: analytic grid NDF ≤ 5 % 43 → 45/48 (GGX α = 0.4, η = 1.3: 5.6 → 3.9 %), η and "
               "BRDF unchanged, measured materials unchanged (226bcb1)")
    wide_smooth_start: float = tuned(
        0.25, name="WIDE_SMOOTH_START", units="fraction of max D",
        what="smooth_wide acts where D is below this fraction of its maximum…",
        source="measurement: 0.125 and 0.5 change the NDF error of six analytic anisotropic GGX lobes (α_x/α_y 2–4, "
               "ideal device) by ≤ 0.74 %; the 25 tuning-half materials forced through the anisotropic path stay "
               "bit-identical (smooth_wide does not act on them). Set with smooth_wide (226bcb1)")
    wide_smooth_full: float = tuned(
        0.03, name="WIDE_SMOOTH_FULL", units="fraction of max D",
        what="…blending in log-linearly to the full filter below this fraction",
        source="measurement: 0.015 raises the NDF error of six analytic anisotropic GGX lobes (α_x/α_y 2–4, ideal "
               "device) by up to 2.6 %, 0.06 changes it by ≤ 0.3 %; the 25 tuning-half materials forced through the "
               "anisotropic path stay bit-identical (smooth_wide does not act on them)")
    wide_smooth_floor: float = tuned(
        1e-3, name="WIDE_SMOOTH_FLOOR", units="fraction of max D",
        what="below this fraction (deep tails: noise and diffuse residue) D's ratio to the lobe neither enters "
             "the filter…",
        source="measurement: 5·10⁻⁴ and 2·10⁻³ change the NDF error of six analytic anisotropic GGX lobes (α_x/α_y "
               "2–4, ideal device) by ≤ 0.06 %; the 25 tuning-half materials forced through the anisotropic path "
               "stay bit-identical (smooth_wide does not act on them)")
    wide_smooth_fade: float = tuned(
        1e-2, name="WIDE_SMOOTH_FADE", units="fraction of max D",
        what="…nor is replaced; the blend fades out between this fraction and the floor",
        source="measurement: 5·10⁻³ changes the NDF error of six analytic anisotropic GGX lobes (α_x/α_y 2–4, ideal "
               "device) by ≤ 0.02 %, 2·10⁻² raises it by up to 4.8 %; the 25 tuning-half materials forced through "
               "the anisotropic path stay bit-identical (smooth_wide does not act on them)")
    wide_smooth_misfit: float = tuned(
        0.08, name="WIDE_SMOOTH_MISFIT", units="log RMS",
        what="smooth_wide leaves the NDF alone when the fitted lobe misses it by more than this "
             "(above WIDE_SMOOTH_FADE of the peak)",
        source="measurement: of the measured materials only pink-felt passes this gate, so they stay unchanged "
               "(226bcb1)")
    wide_smooth_n: int = tuned(
        64, name="WIDE_SMOOTH_N", units="texels per face side",
        what="resolution at which smooth_wide filters (texels of ≈ 1.4°)",
        source="measurement: 32 raises the NDF error of six analytic anisotropic GGX lobes (α_x/α_y 2–4, ideal "
               "device) by up to 71 % (0.30 → 0.51 %), 128 by up to 22 % (0.30 → 0.36 %), at the same CPU time; the "
               "25 tuning-half materials forced through the anisotropic path stay bit-identical (smooth_wide does "
               "not act on them)")
    wide_smooth_max_passes: int = tuned(
        16, name="WIDE_SMOOTH_MAX_PASSES", units="binomial passes",
        what="at most this many passes of smooth_wide's filter (σ ≤ 2.8 texels ≈ 4°)",
        source="mechanism: the flanks of the widest lobes gain nothing from a wider filter, and each pass costs")
    tail_keep: float = tuned(
        10.0 ** -0.5, name="TAIL_KEEP", units="fraction of the peak",
        what="smooth_tails keeps texels at or above this fraction of the peak (10^-0.5) unchanged…",
        source="measurement: 0.1 changes the NDF error of six analytic anisotropic GGX lobes (α_x/α_y 2–4, ideal "
               "device) by ≤ 0.65 % and the 25 tuning-half materials forced through the anisotropic path by ≤ 1.4 % "
               "(eq. 10); smoothing the whole table (1) moves those materials by up to 8 % (7 better, 4 worse by > 1 "
               "%); the exports it was introduced for (b01dbdd) were not re-measured")
    tail_full: float = tuned(
        1e-3, name="TAIL_FULL", units="fraction of the peak",
        what="…and replaces those at or below this fraction by the smoothed table (log-linear blend between)",
        source="measurement: 5·10⁻⁴ and 2·10⁻³ change the NDF error of six analytic anisotropic GGX lobes (α_x/α_y "
               "2–4, ideal device) by ≤ 0.18 % and the 25 tuning-half materials forced through the anisotropic path "
               "by ≤ 2.4 % (eq. 10; one material each by > 1 %); the exports it was introduced for (b01dbdd) were "
               "not re-measured")
    deep_full: float = tuned(
        1e-5, name="DEEP_FULL", units="fraction of the peak",
        what="below this fraction the tail takes the wide filter only (128-texel scale, σ ≈ 1.3°; blended with "
             "the narrow one up to TAIL_FULL)",
        source="measurement: exports of all 50 reconstructed shared materials, 48/50 within median 1 %, "
               "95th percentile 5 % (validate_exports --all, fdce0ec, for the deep-tail filter as a whole)")
    tail_passes_512: int = tuned(
        8, name="TAIL_PASSES_512", units="binomial passes at N = 512",
        what="angular width of the tail smoothing (σ = 2 texels ≈ 0.45°)",
        source="measurement: 4 and 16 passes change the NDF error of six analytic anisotropic GGX lobes (α_x/α_y "
               "2–4, ideal device) by ≤ 0.33 % and the 25 tuning-half materials forced through the anisotropic path "
               "by ≤ 1 % (eq. 10); the exports it was introduced for (b01dbdd) were not re-measured")
    cubic_overshoot: float = tuned(
        1.2, name="CUBIC_OVERSHOOT", units="factor of the coarse maximum",
        what="a log-cubic value of the refined top face (output NDF) is clipped to this factor",
        source="measurement: 1.1 and 1.5 leave six analytic anisotropic GGX lobes (α_x/α_y 2–4, ideal device) and "
               "the 25 tuning-half materials forced through the anisotropic path bit-identical: the clip binds on "
               "none of them. Introduced with the log-cubic refinement (8846e6b)")
    cubic_floor: tuple[float, float] = tuned(
        (1e-3, 1e-2), name="CUBIC_FLOOR", units="fractions of the peak",
        what="between these the refined top face goes from bilinear to log-cubic (the lobe takes the cubic, "
             "the noisy tails stay bilinear)",
        source="measurement: the cubic's ringing in the tails cost the RGL export of a reconstructed metal "
               "5 → 14 % (95th percentile) (8846e6b)")
    cubic_pad: int = tuned(
        4, name="_CUBIC_PAD", units="texels",
        what="edge replication around the top face before the cubic spline prefilter",
        source="mechanism: the cubic's support reaches 2 coefficients beyond the face, so at least 2. Measured: 2 "
               "and 8 change the NDF error of six analytic anisotropic GGX lobes (α_x/α_y 2–4, ideal device) and the "
               "eq. 10 error of the 25 tuning-half materials forced through the anisotropic path by < 0.005 %")


@dataclasses.dataclass(frozen=True)
class FresnelFitTuning:
    """Fresnel index and diffuse albedo from overlapping bins (:mod:`.fresnel_fit`; §5.1, eqs. 4–6).

    Its η bound is :attr:`IsotropicFitTuning.eta_max` (``fresnel_fit.ETA_MAX`` aliases it).
    """

    module: ClassVar[str] = "reflecto.reconstruct.fresnel_fit"
    paper: ClassVar[str] = "§5.1, eqs. 4–6"

    min_level: float = tuned(
        1e-4, name="MIN_LEVEL", units="fraction of the maximum",
        what="only bins whose f cos θ_i cos θ_o / (S S) is above this fraction of the maximum take part",
        source="measurement: 10⁻⁵ and 10⁻³ leave six analytic anisotropic GGX lobes (ideal device) bit-identical; the "
               "25 tuning-half materials forced through the anisotropic path keep their median eq. 10 error, but "
               "single ones move by up to 61 % (10⁻⁵: 4 worse by > 1 %, 2 better; 10⁻³: 2 worse, 7 better): "
               "no settled optimum. Introduced in f43bf73")
    min_count: int = tuned(
        1, name="MIN_COUNT", units="pixels per bin",
        what="minimum pixels in each bin of a pair",
        source="convention: 1, every non-empty bin pairs")
    max_pairs: int = tuned(
        12000, name="MAX_PAIRS", units="pairs",
        what="about this many pairs enter the LM fit (a deterministic hashed subsample)",
        source="measurement: with the hashed subsample of ≈ 12,000 pairs a 1e-12 change of the k_d bound moves "
               "η, k_s ≤ 1 % (silver-paint) and ≤ 5e-4 on 47 of the 50 shared materials; bench 80–83 ms "
               "(1a56243); the count itself dates from f43bf73 with no recorded reason")


@dataclasses.dataclass(frozen=True)
class SamplesTuning:
    """Binning of the slice samples and the k_d ceiling (:mod:`.samples`)."""

    module: ClassVar[str] = "reflecto.reconstruct.samples"
    paper: ClassVar[str] = "eq. 9 (bins), k_d bound"

    kd_bound_percentile: float = tuned(
        0.2, name="KD_BOUND_PERCENTILE", units="percent",
        what="percentile of f per channel whose π-multiple bounds ρ_d (k_d) from above",
        source="measurement: with KD_BOUND_Z following it, 0.1 raises the NDF error of one of six analytic anisotropic "
               "GGX lobes by 21 % (α 0.4 × 0.1: 2.17 → 2.62 %); 0.5 raises three by 3–5 % and lowers 4 of the 25 "
               "tuning-half materials forced through the anisotropic path by 1–4 % (eq. 10, none worse). The "
               "default path's errors on the tuning half are bit-identical (only the normal estimate reads it, "
               "without noise). A low percentile rather than the minimum so that single noisy pixels cannot set it")
    box_radius: int = tuned(
        2, name="BOX_RADIUS", units="pixels",
        what="half width of the box (5 × 5) over which box_mean averages the slices before the k_d bound",
        source="measurement: noise put the raw samples' 0.2 % percentile ≈ 3σ below the diffuse level on the "
               "as-built camera (white-marble k_d 0.14 vs 0.19 ideal); with the 5 × 5 box the as-built sweep "
               "median went 0.446 → 0.360, ideal unchanged (173949f)")


@dataclasses.dataclass(frozen=True)
class SymmetryTuning:
    """Mirror symmetry of the steep LEDs' slices: a shake cue (:mod:`.symmetry`; §5.1, §5.4)."""

    module: ClassVar[str] = "reflecto.reconstruct.symmetry"
    paper: ClassVar[str] = "§5.1, §5.4"

    search_deg: float = tuned(
        12.0, name="SEARCH_DEG", units="deg",
        what="plane angles searched: ±this, in steps of STEP_DEG, then a parabola",
        source="measurement: on the clean and shaken captures of the 25 tuning-half materials (validate_shake's: "
               "3–8° turns, ideal device) ±6° flags the plane on 5 of the 7 shaken captures ±12° flags (a turned "
               "plane's minimum falls on the bound), ±24° locates 16 of the 38 clean planes and flags 2; the capture "
               "verdicts (23/25 detected, no false alarm) do not change: the other cues")
    step_deg: float = tuned(
        1.0, name="STEP_DEG", units="deg",
        what="step of the plane-angle search",
        source="measurement: on the clean and shaken captures of the 25 tuning-half materials (validate_shake's: "
               "3–8° turns, ideal device) 0.5° locates the same planes and flags (clean maximum 1.17° against 1.25°) "
               "at the same CPU time; 2° loses one plane and reads clean ones up to 1.52°, past PLANE_THRESHOLD_DEG")
    min_curvature: float = tuned(
        5.0, name="MIN_CURVATURE", units="per rad²",
        what="smallest curvature of the normalized symmetry distance at its minimum for the plane to count "
             "(flatter slices, rough materials, do not locate it)",
        source="measurement: on the clean and shaken captures of the 25 tuning-half materials (validate_shake's: "
               "3–8° turns, ideal device) 2.5 locates one more plane in the clean and the shaken captures, 10 two "
               "fewer; no flag changes and the clean maximum stays 1.25°")
    plane_threshold_deg: float = tuned(
        1.5, name="PLANE_THRESHOLD_DEG", units="deg",
        what="a located plane further than this from the frame's normal flags a shake",
        source="measurement: clean captures of the 50 shared materials reach 1.2° (brass; ideal and as-built); "
               "1.5° is about the 64² view hemicube's texel (1.4°), a plane located to a texel")
    min_pixels: int = tuned(
        1000, name="MIN_PIXELS", units="pixels",
        what="a slice with fewer usable pixels than this locates no plane",
        source="mechanism: at CUBE_N = 64 a texel averages a median of 8 view pixels, so 1000 pixels fill ≈ 125 "
               "texels, a margin above the 50 mirrored texels the symmetry distance needs (mirror_distances); "
               "not swept")
    min_planes: int = tuned(
        5, name="MIN_PLANES", units="planes",
        what="the symmetry planes give a normal (plane_normal) only where at least this many locate a plane and "
             "keep their full weight in the robust fit",
        source="mechanism: two unknowns (the normal's two angles) leave n − 2 residuals to estimate the planes' "
               "scatter and to see an outlier; with 3 or 4 planes one biased plane (a grazing slice cut by the "
               "view cone's rim) is fitted, not seen (measurement: the 100 steady as-built hand-held captures, "
               "3 planes put pink-felt's tilted normal 9.8° off with residuals ≤ 0.35°)")
    plane_floor_deg: float = tuned(
        0.03, name="PLANE_FLOOR_DEG", units="deg",
        what="standard uncertainty added in quadrature to each symmetry plane's offset at the normal (ψ sin∠(l, n)): "
             "what the planes' scatter cannot show (every plane is located on the same texel grid); propagated "
             "through the planes' geometry, so two nearly parallel planes leave the normal uncertain along them",
        source="measurement: on analytic lobes, where the BRDF is exactly isotropic (not the shared materials), "
               "GGX and Beckmann α 0.1–0.5, k_d 0 and 0.2, untilted and tilted 4°, ideal device, each plane "
               "located about the true normal: 200 of 205 planes within 1°, their offsets RMS 0.032° (median "
               "|offset| 0.016°, p90 0.050°; the other 5 have curvature ≈ 0 and no weight)")
    min_lobe_texels: float = tuned(
        2.0, name="MIN_LOBE_TEXELS", units="texels of the view hemicube",
        what="the planes' normal enters the estimate only for a lobe whose half width at half maximum spans at "
             "least this many texels (90°/CUBE_N each): a narrower lobe is averaged within the splat's texels, "
             "and its planes are placed by the texel grid, not by the lobe",
        source="mechanism: bilinear lookups place a symmetry to a fraction of a texel only where the lobe's "
               "flank, peak to half maximum, spans two texel samples; measurement (100 steady as-built "
               "hand-held captures): ungated, specular-maroon-phenolic (half width 0.3°) moved 0.01° → 0.15° "
               "off and its eq. 10 error rose 12×; one texel would also admit aurora_white (2.2°: 0.34° → "
               "0.53° off) and delrin (2.5°: 0.75° → 0.56°); the gains are on lobes of 3.5° and wider")
    huber_k: float = tuned(
        2.0, name="HUBER_K", units="standard deviations",
        what="a plane whose residual exceeds this many of the fit's scale is down-weighted (Huber's weights, "
             "iterated)",
        source="mechanism: Huber's k between 1.345 (95 % efficiency on Gaussian errors) and 2; the grazing "
               "slices of metals and coated paints put their planes 2–10° off (symmetry module docstring), "
               "so a biased plane lies far out and any k in that range sets it aside")
    cube_n: int = tuned(
        64, name="CUBE_N", units="texels per face side",
        what="resolution of the view hemicube on which a slice is mirrored",
        source="measurement: at 64 a texel (≈ 1.4°) averages a median of 8 of the default optics' 39,428 view pixels "
               "(32: 33, 128: 2). On the clean and shaken captures of the 25 tuning-half materials "
               "(validate_shake's: 3–8° turns, ideal device) 32 reads a clean plane 7.0° off, 128 reads clean ones ≤ "
               "0.97° (64: ≤ 1.25°) and locates one shaken plane fewer, same flags and CPU time")


@dataclasses.dataclass(frozen=True)
class SymmetryTestTuning:
    """How far the data break eq. 3: τ pairs against direct pairs (:mod:`.eq3`; eq. 3, §5.5)."""

    module: ClassVar[str] = "reflecto.reconstruct.eq3"
    paper: ClassVar[str] = "eq. 3, §5.5"

    level: float = tuned(
        0.02, name="LEVEL", units="fraction of the 99.5th percentile",
        what="bins enter where their partial NDF is above this fraction of its 99.5th percentile…",
        source="measurement: on single captures of the 25 tuning-half materials (default path) and of the eight "
               "analytic asymmetric lobes of examples/asymmetric (rotation 0, seed 1, --isotropic no; ideal device) "
               "0.01 and 0.04 change no verdict: symmetric ratios ≤ 1.97 where decided (18–19 of 25 decided), "
               "asymmetric ≥ 3.22, all 8 broken")
    min_specular_fraction: float = tuned(
        0.5, name="MIN_SPECULAR_FRACTION", units="fraction of the BRDF",
        what="…and the specular part is at least this fraction of the measured BRDF",
        source="mechanism: the partial NDF is measured where the specular term dominates, not the diffuse "
               "floor and the model's account of it")
    min_pairs: int = tuned(
        30, name="MIN_PAIRS", units="pairs",
        what="τ pairs needed for a verdict, and direct pairs needed to measure their spread",
        source="measurement: on single captures of the 25 tuning-half materials (default path) and of the eight "
               "analytic asymmetric lobes of examples/asymmetric (rotation 0, seed 1, --isotropic no; ideal device) "
               "15 lets 3 symmetric captures with 18–26 τ pairs break eq. 3 (chm_mint 3.04, specular-white-phenolic "
               "2.29, steel 2.02); 60 leaves 2 more undecided; the asymmetric lobes hold ≥ 101 τ pairs and break at "
               "either")
    unpaired_spread: float = tuned(
        0.3, name="UNPAIRED_SPREAD", units="log units",
        what="the least spread of the direct pairs assumed when fewer than MIN_PAIRS of them are in the lobe "
             "(their measured spread counts where it is larger)",
        source="measurement: the model's S and F miss measured materials by 20–60 %; with 0.3 the τ pairs of "
               "blue-rubber and light-red-paint (0.13–0.18) are kept, the asymmetric satin's (0.91) broken "
               "(2a6335a, docs/design/asymmetric.md)")
    threshold: float = tuned(
        2.0, name="THRESHOLD", units="ratio of RMS log ratios",
        what="ratio of the τ pairs' RMS log ratio to the direct pairs' at and above which the data break eq. 3",
        source="measurement: single captures (ideal device) of the 50 shared materials and four analytic "
               "symmetric lobes read ≤ 1.60, the 100 steady as-built captures of the hand-held study ≤ 1.47 where "
               "decided, the eight analytic asymmetric lobes of examples/asymmetric ≥ 3.2 (3.1 as-built) "
               "(docs/design/asymmetric.md); 2 lies between, nearer the symmetric side, where an error costs a "
               "needless §5.5 hint rather than a lost asymmetry. A ratio rather than a level because S and F miss "
               "both kinds of pair alike")
    direct_floor: float = tuned(
        0.01, name="DIRECT_FLOOR", units="log units",
        what="floor of the direct pairs' RMS in that ratio",
        source="mechanism: below ≈ 1 % two partial NDFs are equal to within the texel's extent")
    test_resolution: int = tuned(
        128, name="TEST_RESOLUTION", units="texels per face side",
        what="working resolution of the test's bins (texels ≈ 0.9° at the pole)",
        source="measurement: on single captures of the 25 tuning-half materials (default path) and of the eight "
               "analytic asymmetric lobes of examples/asymmetric (rotation 0, seed 1, --isotropic no; ideal device) "
               "64 leaves 12 of 25 symmetric and one asymmetric lobe (29 τ pairs) undecided; 256 breaks eq. 3 on 2 "
               "symmetric captures (ratio up to 2.14) at 3× the test's CPU time")


@dataclasses.dataclass(frozen=True)
class ConsistencyTuning:
    """Isotropy and reciprocity across slices: a model-free shake cue (:mod:`.consistency`; §5.1)."""

    module: ClassVar[str] = "reflecto.reconstruct.consistency"
    paper: ClassVar[str] = "§5.1"

    cube_n: int = tuned(
        64, name="CUBE_N", units="texels per face side",
        what="resolution of the view hemicube that a slice is averaged onto",
        source="measurement: at 64 a texel (≈ 1.4°) averages a median of 8 of the default optics' 39,428 view pixels "
               "(32: 33, 128: 2). On the clean and shaken captures of the 25 tuning-half materials "
               "(validate_shake's: 3–8° turns, ideal device) the pair cue alone detects 3 shakes at 32, 4 at 64, 5 "
               "at 128, with no false alarm at any; the as-built device's noise was not measured")
    isotropy_max_deg: float = tuned(
        1.0, name="ISOTROPY_MAX_DEG", units="deg",
        what="LEDs whose incidence angles differ by at most this are compared by isotropy",
        source="mechanism: an LED's mirror direction moves with its incidence angle, so two LEDs within 1° put "
               "their specular peaks within one texel (≈ 1.4°) of the 64² table they are compared on; the default "
               "layout's pair (θ_i 82.66° and 83.01°) is 0.35° apart")
    min_pairs_isotropy: int = tuned(
        200, name='MIN_PAIRS["isotropy"]', units="texels",
        what="fewer paired directions (texels of the first LED's table) give no isotropy verdict for a pair",
        source="measurement: halved and doubled together with the reciprocity count, on the clean and shaken "
               "captures of the 25 tuning-half materials (validate_shake's: 3–8° turns, ideal device) 100 and 10 "
               "change nothing; 400 and 40 drop 2 of 39 clean and 1 of 27 shaken pair checks and one of the 4 shakes "
               "the pair cue alone detects")
    min_pairs_reciprocity: int = tuned(
        20, name='MIN_PAIRS["reciprocity"]', units="steps of Δ",
        what="fewer paired directions (steps of the relative azimuth Δ) give no reciprocity verdict for a pair",
        source="measurement: halved and doubled with the isotropy count (see there; 10 steps change nothing, "
               "40 lose checks and one detection)")
    reciprocity_step_deg: float = tuned(
        0.5, name="RECIPROCITY_STEP_DEG", units="deg",
        what="step of the relative azimuth Δ along a reciprocity curve",
        source="mechanism: at the reciprocity LEDs' polar angles (37.8°, 67.1°) a 0.5° step moves the direction "
               "0.31–0.46°, 3–5 samples per 1.4° texel of the table. Measured on the clean and shaken captures of "
               "the 25 tuning-half materials (validate_shake's: 3–8° turns, ideal device): 0.25° changes nothing, 1° "
               "drops 2 of the 39 clean pair checks below MIN_PAIRS")
    threshold_isotropy: float = tuned(
        0.15, name='THRESHOLD["isotropy"]', units="|log ratio|",
        what="|log ratio| of an isotropy pair above which the capture is flagged as shaken",
        source="measurement: clean captures of the 50 shared materials reach 0.02 (ideal), 0.06 (as-built); a "
               "shake that turns the isotropy pair differently reads 0.27–3.8 (studies/validate_shake.py). "
               "The former hand-written table said 'tuning half'; the record measures all 50")
    threshold_reciprocity: float = tuned(
        0.35, name='THRESHOLD["reciprocity"]', units="|log ratio|",
        what="|log ratio| of a reciprocity pair above which the capture is flagged as shaken",
        source="measurement: clean captures of the 50 shared materials reach 0.30 on the ideal device (the RGL "
               "materials' own data are not reciprocal: 0.25–0.30 on cc_ibiza_sunset and vch_golden_yellow; "
               "MERL/NBRDF within 0.01), 0.08 as-built (studies/validate_shake.py)")
    step_deg: float = tuned(
        1.0, name="STEP_DEG", units="deg",
        what="directions where the slice changes by more than MAX_STEP in log within this are left out",
        source="mechanism: sharp lobes, where small direction errors dominate the ratio, are left out; "
               "no reason for 1° itself is recorded")
    max_step: float = tuned(
        0.1, name="MAX_STEP", units="log units",
        what="largest change of the slice within STEP_DEG for a direction to take part",
        source="mechanism: sharp lobes, where small direction errors dominate the ratio, are left out; "
               "no reason for 0.1 itself is recorded")
    max_noise: float = tuned(
        0.05, name="MAX_NOISE", units="fraction of a sample's value",
        what="samples whose camera noise (read, shot and quantization) exceeds this fraction of their value take no "
             "part in a pair",
        source="mechanism: a slice read a few DN above the black level is rounded and censored (0–1 DN) into a "
               "biased ratio: a tilted capture's grazing LEDs on the wide device read 1–3 DN and put the isotropy "
               "pair 1-7 of a steady specular-maroon-phenolic at ×1.54 with the true normal (LED 1 +12 %, LED 7 −31 % "
               "against the true BRDF); 5 % is a reading of ≳ 6 DN on the noiseless 12-bit camera")
    floor: float = tuned(
        0.02, name="FLOOR", units="fraction of the 99th percentile",
        what="samples below this fraction of the pair's 99th-percentile value are left out",
        source="mechanism: their ratio is dominated by rounding and noise; no reason for 0.02 itself is recorded")


@dataclasses.dataclass(frozen=True)
class RepeatTuning:
    """Check frames: the first LED fired again after the sequence (:mod:`.repeat`; a shake cue beyond the paper)."""

    module: ClassVar[str] = "reflecto.reconstruct.repeat"
    paper: ClassVar[str] = "§5.1 (beyond the paper)"

    block_px: int = tuned(
        16, name="BLOCK_PX", units="pixels",
        what="side of the pixel blocks compared",
        source="measurement: on the clean and shaken captures of the 25 tuning-half materials (validate_shake's: "
               "3–8° turns) on the as-built device the block test alone (the whole-frame test disabled) flags the "
               "check frames of 24/25 shaken and 0/25 clean captures at 8, 16 and 32 px alike (the ideal device: 8 "
               "and 32 change no verdict either); no clean capture changes a block. Smaller shakes were not measured")
    block_min_fill: float = tuned(
        0.5, name="BLOCK_MIN_FILL", units="fraction of a block's pixels",
        what="a block takes part when at least this fraction of its pixels is valid in both frames",
        source="measurement: on the clean and shaken captures of the 25 tuning-half materials (validate_shake's: "
               "3–8° turns) on the as-built device the block test alone flags 24/25 shaken and 0/25 clean captures "
               "at 0.25, 0.5 and 0.75 alike (BLOCK_PX's measurement)")
    threshold: float = tuned(
        0.02, name="THRESHOLD", units="|log ratio|",
        what="|log ratio| of the whole frame above which the sample moved",
        source="measurement: shaken captures of the 50 shared materials start at 0.06; clean ones repeat to "
               "noise (z ≤ 2.3, as-built); above an LED's pulse-to-pulse repeatability (≈ 0.5 %)")
    block_threshold: float = tuned(
        0.05, name="BLOCK_THRESHOLD", units="|log ratio|",
        what="|log ratio| of a block above which it changed",
        source="mechanism: above an LED's pulse-to-pulse repeatability (≈ 0.5 %) and the camera noise "
               "(docs/design/reconstruction.md); no reason for 0.05 itself is recorded")
    min_blocks: int = tuned(
        2, name="MIN_BLOCKS", units="blocks",
        what="blocks that must change to count as motion",
        source="measurement: on the clean and shaken captures of the 25 tuning-half materials (validate_shake's: "
               "3–8° turns) on the as-built device the block test alone flags 24/25 shaken and 0/25 clean captures "
               "at 1, 2 and 3 blocks alike: no clean capture changes a block (BLOCK_PX's measurement)")
    min_z: float = tuned(
        6.0, name="MIN_Z", units="standard errors of the noise",
        what="significance a change must also reach",
        source="measurement: clean captures repeat to noise (z ≤ 3.4 on the 100 steady as-built captures of "
               "the hand-held study, tilted 0–10°, check LED 5); the check frames raise 0/100 false alarms on the "
               "ideal, as-built and wide devices (studies/validate_handheld.py)")


@dataclasses.dataclass(frozen=True)
class SynthesisTuning:
    """Example-based microfacet synthesis of the holes (:mod:`.synthesis`; §5.5 after Wang et al. 2008, AR 4.4).

    The measurements are ``studies/synthesis_choices.py`` on the 21 fill sets of
    docs/design/asymmetric.md (*The choices the paper leaves open*), each value changed
    one at a time against the defaults. :class:`.synthesis.SynthesisOptions` takes its
    defaults from these fields.
    """

    module: ClassVar[str] = "reflecto.reconstruct.synthesis"
    paper: ClassVar[str] = "§5.5"

    rotation_step_deg: float = tuned(
        5.0, name="ROTATION_STEP_DEG", units="deg",
        what="candidate rotations about n are multiples of this (71 candidates)",
        source="measurement: AR 4.4 suggests 2–5°; 2.5° and 10° are both 1–3 % worse (docs/design/asymmetric.md)")
    window_deg: float = tuned(
        8.0, name="WINDOW_DEG", units="deg",
        what="radius of the matching window (Gaussian of σ = radius / 2, cut at the radius)",
        source="measurement: the holes lie beyond θ_h ≈ 40°, where the ratio varies over tens of degrees; 5° and "
               "12° are 4–12 % and 9–14 % worse (docs/design/asymmetric.md)")
    min_overlap: float = tuned(
        0.3, name="MIN_OVERLAP", units="fraction of the window's weight",
        what="a candidate must cover known texels holding at least this fraction of the window's weight",
        source="measurement: Wang's 30 % of the known region (AR 4.4), applied per window; 15 % is 2–3 % worse, "
               "50 % 10–16 % worse (docs/design/asymmetric.md)")
    gain_penalty: float = tuned(
        0.25, name="GAIN_PENALTY", units="weight of μ² (log units²)",
        what="weight of the squared log gain μ² in the distance",
        source="measurement: without the penalty 4–5 % worse (docs/design/asymmetric.md); other weights than "
               "0 and 0.25 are not recorded")
    blend: int = tuned(
        3, name="BLEND", units="candidates",
        what="candidates blended per hole texel",
        source="measurement: AR 4.4 says k = 3–5; 1 is 5–8 % worse, 5 within 1.2 % (docs/design/asymmetric.md)")
    max_rounds: int = tuned(
        24, name="MAX_ROUNDS", units="rounds",
        what="rounds of search and fill at most",
        source="measurement: on the eight asymmetric examples captured at 0/90° and 0/120/240° (ideal device) "
               "synthesis ends after 3–24 rounds; where 24 binds (ggx-brushed-30, ggx-satin-100) 48 ends after 25–30 "
               "with the same NDF and eq. 10 errors and synthesized fraction; 12 raises ggx-rough-m40's NDF error "
               "(0/90°) from 2.76 to 3.00 %")
    resolution: int = tuned(
        32, name="SYNTHESIS_RESOLUTION", units="texels per face side",
        what="hemicube resolution of the search (texels ≈ 2.8° at the pole); the working NDF's holes take the "
             "synthesized ratio interpolated from it",
        source="measurement: at 64 the synthesized texels' error was within ±0.4 % at 7× the time "
               "(0.1–0.4 s against 0.02–0.09 s) (docs/design/asymmetric.md)")
    blend_eps: float = tuned(
        1e-4, name="BLEND_EPS", units="log units²",
        what="ε of the blending weights 1/(d + ε) (a distance of 0.01 is a 10 % misfit)",
        source="mechanism: (0.01)², the distance of a 1 % RMS log misfit: candidates that match better than a "
               "measured partial NDF is known (≈ 1 %, DIRECT_FLOOR) weigh about alike instead of an exact match "
               "(d → 0) taking all the weight")
    floor: float = tuned(
        3e-3, name="SYNTHESIS_FLOOR", units="fraction of the peak",
        what="measured texels below this are no candidates and no known region; holes where the lobe is below "
             "it keep the plain fill",
        source="measurement: below ≈ 1 % of the peak a measured partial NDF carries the diffuse term's error "
               "(±30 % at 10⁻³–10⁻² on the ideal device); 10⁻² leaves the tail without candidates. Set on a "
               "subset of the fill cases; 10⁻² and 10⁻³ not measured on all 20 sets (docs/design/asymmetric.md)")


@dataclasses.dataclass(frozen=True)
class AsymmetricTuning:
    """One BRDF from captures at several rotations (:mod:`.asymmetric`; §5.5)."""

    module: ClassVar[str] = "reflecto.reconstruct.asymmetric"
    paper: ClassVar[str] = "§5.5"

    duplicate_deg: float = tuned(
        1.0, name="DUPLICATE_DEG", units="deg (modulo 360)",
        what="two captures whose rotations differ by less than this are duplicates (refused)",
        source="mechanism: two captures that close add no new coverage and usually mean a copied manifest "
               "(docs/design/asymmetric.md)")
    alike_noise_rms: float = tuned(
        1.2, name="ALIKE_NOISE_RMS", units="noise standard deviations (RMS)",
        what="a set's captures whose device-frame luminance differs from the first's by at most this RMS of "
             "their noise are alike: the sample did not change as it turned (an isotropic one on a tilt)",
        source="measurement: as-built, aurora_white, pink-felt and delrin turned at 0/90/180/270° about tilts of "
               "0°, 3° and 8° read 0.74–0.75 (noise alone; one channel's σ overstates the luminance's), the 8 "
               "asymmetric examples' largest per set 1.66 (ggx-leaning) to 15.1; ideal device 0 against 43 and "
               "more. Between the two groups; checked on sets it was not chosen on (as-built, tilt azimuth 130°): six "
               "other shared materials at 2° and 6° all alike (12/12), the 12 random asymmetric materials of "
               "validate_asymmetric's fill part none (0/12) (docs/design/asymmetric.md, One normal)")
    min_captures: int = tuned(
        2, name="MIN_CAPTURES", units="captures",
        what="captures needed for §5.5",
        source="convention: §5.5 merges captures at several rotations; two is the fewest")
    inconsistent_level: float = tuned(
        0.15, name="INCONSISTENT_LEVEL", units="|weighted mean log ratio|",
        what="two captures measure different materials (or carry a wrong rotation) when the weighted mean log "
             "ratio of their partial NDFs at shared texels reaches this (a 16 % level difference)",
        source="measurement: on the 62 single-material sets of the validation (ideal and as-built) |μ| stays "
               "≤ 0.078; on the 8 mixed sets it is 0.09–1.98 (docs/design/asymmetric.md, 034b035)")
    inconsistent_ratio: float = tuned(
        3.0, name="INCONSISTENT_RATIO", units="factor of the within-capture RMS",
        what="…or when their RMS log ratio is at least this factor of what two LEDs of one capture differ by…",
        source="measurement: catches the one mixed set with a small level offset (acrylic_felt_green + "
               "alum-bronze: 4.2× the within spread); measured anisotropic cm_military_green reads 3.8× at "
               "|μ| = 0.006, kept by the level condition (docs/design/asymmetric.md)")
    inconsistent_min: float = tuned(
        0.15, name="INCONSISTENT_MIN", units="RMS log ratio",
        what="…and at least this in absolute terms…",
        source="measurement: 0.075 and 0.3 refuse the same sets: 8/8 mixed sets (validate_asymmetric's part mixed) "
               "and 0/20 single-material sets (the eight asymmetric examples and 12 tuning-half materials at "
               "0/90/180/270°, ideal device); the set refused by shape alone (acrylic_felt_green + alum-bronze, "
               "level 0.09) stays refused. Equal to INCONSISTENT_LEVEL")
    inconsistent_level_with_shape: float = tuned(
        0.03, name="INCONSISTENT_LEVEL_WITH_SHAPE", units="|weighted mean log ratio|",
        what="…and differ in level by at least this",
        source="measurement: one measured anisotropic material's captures 90° apart differ in shape but not in "
               "level (|mean| ≤ 0.01); the mixed sets' level is ≥ 0.09 (034b035, docs/design/asymmetric.md)")
    min_cross_pairs: int = tuned(
        30, name="MIN_CROSS_PAIRS", units="pairs",
        what="cross-capture (and within-capture) pairs needed to judge two captures",
        source="mechanism: sampling: n independent pairs give an RMS log ratio to ≈ 1/√(2n), 13 % at 30, and the "
               "ratio of two such RMS values to ≈ 18 %, so a factor INCONSISTENT_RATIO = 3 (log 3 = 1.1) stands ≈ 6 "
               "of those errors clear (neighbouring texels' pairs are correlated: fewer in effect). Measured: 15 and "
               "60 refuse the same sets, 8/8 mixed sets (validate_asymmetric's part mixed) and 0/20 single-material "
               "sets (the eight asymmetric examples and 12 tuning-half materials at 0/90/180/270°, ideal device)")
    cap_deg: float = tuned(
        80.0, name="CAP_DEG", units="deg",
        what="polar cap (θ_h ≤ this) over which the synthesized and hole fractions are reported",
        source="convention: a reporting range for the summary")


@dataclasses.dataclass(frozen=True)
class NormalTuning:
    """The altered normal (:mod:`.normal`; §5.4): the grid search of the §5.5 set's normal,
    and the tilt refined inside the isotropic fit's least squares (docs/design/normal.md)."""

    module: ClassVar[str] = "reflecto.reconstruct.normal"
    paper: ClassVar[str] = "§5.4"

    led_margin_deg: float = tuned(
        10.0, name="LED_MARGIN_DEG", units="deg",
        what="LEDs less than this far above a candidate frame's horizon take no part in its IsotropicDistance",
        source="measurement: without it a frame that sank the worst-fitting grazing LEDs won (specular maroon "
               "phenolic tilted 5°: 7.8° off), and counting their samples as lost biased the tilt of captures whose "
               "LEDs truly sink (GGX α = 0.1 at 10°: found 8.97°); with it normals 23/24 within 0.5° on "
               "validate_tilt, measured materials tilted 5–15° within 0.6° (408eb78)")
    min_pairs: int = tuned(
        40, name="MIN_PAIRS", units="texel pairs",
        what="minimum number of texel pairs for a candidate normal to count (the consistency distances of "
             "the §5.5 search and of the set's normal)",
        source="mechanism: the distance is an RMS over the pairs, whose relative standard error is ≈ 1/√(2n): "
               "11 % at 40 pairs, so a candidate's distance is told from its neighbours' (which differ by "
               "tens of per cent across the search's steps) only from about that many pairs on; the §5.5 "
               "set's distance imports it")
    n_starts: int = tuned(
        6, name="N_STARTS", units="local minima",
        what="at most this many local minima of the coarse tilt grid are refined (multi-start)",
        source="measurement: at a 10° tilt the grid point 1° from the truth ranked fourth among the coarse "
               "grid's local minima (a narrow basin where an LED nears the horizon; "
               "estimate_normal_consistency's docstring), so at least 4 are needed; 6 is that with two in "
               "reserve, not swept further (each start costs ≈ 30 distance evaluations)")
    min_view_deg: float = tuned(
        1.0, name="MIN_VIEW_DEG", units="deg",
        what="samples whose view is within this of the candidate normal's horizon take no part in the tilt's step",
        source="mechanism: the residual divides by σ(v·n), which falls to cos θ_o → 0 at the horizon, and "
               "reframe's correction of the view's foreshortening is as unreliable there as for an LED; the "
               "view cone reaches 1° above a 10°-tilted sample's horizon only at its rim, so few samples leave")
    sample_stride: int = tuned(
        7, name="SAMPLE_STRIDE", units="pixels",
        what="every SAMPLE_STRIDE-th pixel off the specular peaks enters the tilt's least squares (weight "
             "SAMPLE_STRIDE); the peaks' pixels all enter (LOBE_LEVEL)",
        source="mechanism: ≈ 5 300 views of the default optics × 6 LEDs overdetermine the two angles where the "
               "BRDF varies slowly; a sharp peak covers a few pixels, which the stride alone misses (measurement: "
               "stride 7 without the peaks' pixels put sharp materials' normals 0.02–0.07° off, enough to turn "
               "their fits 1.4–9× worse on eq. 10; stride 1 or the peaks' pixels: 0.003–0.03°)")
    lobe_level: float = tuned(
        0.01, name="LOBE_LEVEL", units="share of the capture's peak above the slice median",
        what="in a slice with a peak (PEAK_CONTRAST), the samples above median + LOBE_LEVEL · (capture max − "
             "median) enter the tilt's step all, unless they are more than 1 in SAMPLE_STRIDE of the slice",
        source="mechanism: 1 % of a Gaussian lobe's height lies 3σ from its centre, so the set holds the flanks "
               "where the residuals' derivative with respect to the tilt lives; measurement: 0.05 gave the same "
               "normals within 0.01° on 8 materials (sharp and diffuse, both halves), 14–170 extra samples per "
               "capture on the sharp ones")
    fit_stride: int = tuned(
        2, name="FIT_STRIDE", units="pixels",
        what="every FIT_STRIDE-th pixel enters the isotropic refits inside the estimate (the final fit uses all)",
        source="measurement: every 4th pixel with one S-from-D round and 3 refits halved the time but lost normals "
               "on the tuning half (19/25 within 0.5° against 22/25, max 1.9° against 1.3°; docs/design/normal.md)")
    fit_outer_iterations: int = tuned(
        2, name="FIT_OUTER_ITERATIONS", units="rounds",
        what="outer iterations (S from D) of the refits inside the estimate",
        source="measurement: one round lost normals on the tuning half (with the lighter fits above)")
    fit_td_step: float = tuned(
        math.radians(3.0), name="FIT_TD_STEP", units="rad (3°)",
        what="width of the θ_d cells of the refits inside the estimate (the model's fits: TD_STEP)",
        source="mechanism: the refits serve the normal, which D(θ_h) places; F and S change with θ_d so slowly "
               "that a 3° cell averages them to second order (F at a cell's mean cos θ_d is within 0.4 % of F's "
               "mean over the cell to θ_d = 88°, η 1.5; 1° cells: 0.04 %); measurement: on the 10 tilted as-built "
               "captures of bench_capture_to_model a light fit takes 14.7 ms instead of 22.9 (2 975 bins instead of "
               "7 936; 5° cells: 13.7 ms), the hand-held study's normals within 0.5° stay 96/100 as-built (49 · 47 "
               "per half), 93/100 on wide, and go 90 → 91/100 on the ideal device (docs/design/speed.md)")
    converged_deg: float = tuned(
        0.05, name="CONVERGED_DEG", units="deg",
        what="the estimate has converged when a refit moves the normal by less than this …",
        source="mechanism: the frame accuracy the sharpest lobes need (chrome-steel, steel, brass reconstructed "
               "with the normal turned by 0.05° stay within their eq. 10 error; docs/design/normal.md)")
    converged_share: float = tuned(
        0.25, name="CONVERGED_SHARE", units="fraction of the uncertainty",
        what="… or by less than this share of its uncertainty",
        source="mechanism: a move well inside the normal's own uncertainty carries no information")
    max_refits: int = tuned(
        6, name="MAX_REFITS", units="refits",
        what="at most this many refits of the isotropic fit in the estimated frame",
        source="measurement: 4 gave the same normals on the tuning half but lost two on the validation half "
               "(ipswich-pine 0.35° → 1.34°, acrylic felt 2.7° → 3.2° and a false shake flag), so the "
               "validation half informed this value")
    aitken_max_ratio: float = tuned(
        0.75, name="AITKEN_MAX_RATIO", units="ratio",
        what="the refits' normals are extrapolated to their limit (vector Aitken) when successive moves shrink "
             "by a ratio below this (the limit then lies at most 3× the last move further) …",
        source="mechanism: a geometric tail of ratio r ends r/(1 − r) of the last move further; 0.75 bounds "
               "that at 3×")
    aitken_max_step_deg: float = tuned(
        1.5, name="AITKEN_MAX_STEP_DEG", units="deg",
        what="… and the move before was below this: far from the limit the moves are set by the trust region",
        source="mechanism: below the trust region MAX_STEP_DEG (3°), so that the moves extrapolated are the "
               "fit's convergence, not the step bound; the factor ½ was not swept")
    inner_steps: int = tuned(
        3, name="INNER_STEPS", units="steps",
        what="Gauss–Newton steps on the two tilt angles with the model held fixed after each refit",
        source="measurement: 20 as-built tilted captures of the 50 shared (both halves): 2 steps gave normals "
               "within 0.5° on 30/40 (3 steps: 31/40), 6 steps 30/40 at 13 % more CPU; eq. 10 within 1.1× of "
               "the true normal's 13, 12 and 12 of 20")
    max_step_deg: float = tuned(
        3.0, name="MAX_STEP_DEG", units="deg",
        what="largest step of one Gauss–Newton iteration (a trust region)",
        source="measurement: 1.5° and 6° gave the same normals as 3° (31/40 within 0.5°, max 2.19° and 2.36° "
               "against 2.25°) on 20 as-built tilted captures of the 50 shared: the steps stay inside it")
    peak_contrast: float = tuned(
        2.0, name="PEAK_CONTRAST", units="ratio",
        what="a slice's peak stands clear of its floor when its luminance is this many times the slice's median",
        source="measurement: 1.5 and 4 gave the same tilts within 0.5° as 2 (30/40 and 31/40 against 31/40) "
               "and the same eq. 10 ratios on 20 as-built tilted captures of the 50 shared (both halves): the "
               "tilt's refinement, not the first estimate, sets the result")
    peak_rim_deg: float = tuned(
        3.0, name="PEAK_RIM_DEG", units="deg",
        what="… and lies at least this far inside the view cone's rim",
        source="measurement: 1.5° and 6° gave the same normals as 3° (31/40 within 0.5°) on 20 as-built "
               "tilted captures of the 50 shared (both halves); a peak at the rim may be cut by it")


@dataclasses.dataclass(frozen=True)
class MotionTuning:
    """The shake cues gathered (:mod:`.motion`; §5.1) in the estimated sample frame."""

    module: ClassVar[str] = "reflecto.reconstruct.motion"
    paper: ClassVar[str] = "§5.1, §5.4"

    normal_sigmas: float = tuned(
        2.0, name="NORMAL_SIGMAS", units="standard uncertainties",
        what="the mirror-plane and LED-pair thresholds are widened by the normal's error at this many "
             "standard uncertainties (a plane turns by up to δ/sin θ_l, a pair's log ratio by δ(tan θ_a + tan θ_b))",
        source="mechanism: a two-sided 95 % bound on the normal's error (docs/design/normal.md)")
    peak_radius_deg: float = tuned(
        1.0, name="PEAK_RADIUS_DEG", units="deg",
        what="a slice's peak is compact when its pixels above half its height lie within this of their centroid's "
             "half vector: the peak of a sharp lobe, which places the lobe's mode (a slice that only grazes a "
             "lobe's flank has a ridge or plateau degrees wide there)",
        source="measurement: on the hand-held study's captures (ideal, as-built, wide, wide-as-built: 400 steady, "
               "200 shaken; both halves) 0.5° and 2° flag the same captures as 1°; the plateaus of slices that "
               "miss the mirror direction span 15–60°")
    peak_agreement_deg: float = tuned(
        1.5, name="PEAK_AGREEMENT_DEG", units="deg",
        what="two compact peaks whose half vectors lie further apart than this flag a shake: the slices of a "
             "steady sample peak at the same half vector, the lobe's mode",
        source="measurement: the value of PLANE_THRESHOLD_DEG, not tuned on this cue; on the hand-held study's "
               "400 steady captures (ideal, as-built, wide, wide-as-built; untilted and tilted 0–10°) compact peaks "
               "lie at most 0.43° apart (tuning half: steel tilted on wide-as-built; validation half 0.33°), on the "
               "shaken ones they flag 3.1–7.8° apart (wide: chrome-steel, hematite, tungsten-carbide, which the "
               "other cues miss, 4.5–7.8°)")


@dataclasses.dataclass(frozen=True)
class ExtrapolationTuning:
    """The shadowing form beyond the observed ``θ_d``, chosen by the fit (:mod:`.extrapolation`)."""

    module: ClassVar[str] = "reflecto.reconstruct.extrapolation"
    paper: ClassVar[str] = "eq. 8"

    min_difference: float = tuned(
        0.01, name="MIN_DIFFERENCE", units="relative",
        what="the choice is made only where the correlated form changes some measured bin's model value by at "
             "least this (with the product's fit)",
        source="convention: a choice the data change by less than 1 % nowhere is not the data's; measured: the "
               "paper's layout 2–32 % on matte materials, sharp lobes below 1 %; the earlier device (no grazing "
               "LED) mostly below 1 %")
    min_cost_gain: float = tuned(
        0.01, name="MIN_COST_GAIN", units="relative",
        what="the height-correlated form is taken only where its fit's cost is below (1 − this) × the product's",
        source="measurement: the 48 separable analytic lobes of validate_reconstruction.py (ideal device) give "
               "cost ratios of 0.996–1.000 on the five where the bare comparison takes the correlated form (GGX and "
               "Beckmann α 0.4), whose eq. 10 error then rises from 0.01–0.02 % to 0.17–0.21 %; lobes rendered with "
               "the correlated form give 0.93–0.98 (GGX α 0.2–0.4). On the shared materials the choices at "
               "0.99–1.00 moved eq. 10 by at most 1 %")
    max_width_change: float = tuned(
        2.0, name="MAX_WIDTH_CHANGE", units="ratio of half widths",
        what="the correlated form's fit counts only where its lobe's half width at half maximum lies within this "
             "factor of the product's fit's; beyond, the continuation has left the product's branch of the fit "
             "and the product stays",
        source="mechanism: the two forms differ only where both directions are far from the normal, so on one "
               "branch they leave the lobe's core where it was (the shared materials' correlated fits: 0.87–1.40×); "
               "a cost comparison across branches compares two lobes, not two forms (the earlier device's "
               "natural-209: 10.5° → 0.89°, cost 0.990×, eq. 10 0.16 → 2.46)")


@dataclasses.dataclass(frozen=True)
class PipelineTuning:
    """The §5 stages around the fits: energy check and capture acceptance (:mod:`.pipeline`)."""

    module: ClassVar[str] = "reflecto.reconstruct.pipeline"
    paper: ClassVar[str] = "§5"

    device_axis_sigmas: float = tuned(
        2.0, name="DEVICE_AXIS_SIGMAS", units="standard uncertainties",
        what='normal="auto" keeps the device axis when the estimated tilt is at most this many uncertainties',
        source="mechanism: a tilt within the normal's two-sided 95 % bound is not told apart from none "
               "(docs/design/normal.md); on the hand-held study the untilted captures kept the device axis on "
               "44 of 50")
    device_check_rounds: int = tuned(
        2, name="DEVICE_CHECK_ROUNDS", units="outer rounds",
        what="the device frame's fit that checks an estimated tilt is looked at after this many of its outer rounds",
        source="measurement: on the hand-held study's as-built captures (50 materials, untilted, tilted and shaken; "
               "the 98 where the check runs) the fit's ε after 2 rounds is within 0.99–1.24× of its final value "
               "on the tuning half and 0.99–1.41× on the validation half (pink-felt); after 1 round 0.80–2.07×")
    device_check_margin: float = tuned(
        2.0, name="DEVICE_CHECK_MARGIN", units="ratio of ε",
        what="a device frame's fit whose ε after DEVICE_CHECK_ROUNDS rounds is at least this many times the "
             "estimated frame's stops there: the tilt explains the data better",
        source="measurement: above the largest fall of ε after round 2 on the hand-held study's as-built tuning "
               "half (1.24×), with room for the fall not seen there; checked on the validation half, whose largest "
               "fall is 1.41× (pink-felt; seen before the margin was raised from 1.5 to 2), where every early stop "
               "gives the full fit's answer (the study's records unchanged); with DEVICE_CHECK_ETA, 53 of the 98 "
               "checks stop after round 2 (23 of 47 on the tuning half, 30 of 51 on the validation half)")
    device_check_eta: float = tuned(
        10.0, name="DEVICE_CHECK_ETA", units="relative index",
        what="… and only while its η after those rounds is at most this: a higher one may still climb to the "
             "search bound, where the constant Fresnel lobe can replace the fit by one of lower ε",
        source="mechanism: the measured materials' fits end at η ≤ 9 or at the bound (the sweeps' tables); "
               "GGX α 0.2 with η 100 climbs 19 → 24 → 40 → 50 in its rounds, and its constant Fresnel fit's ε "
               "(0.030) lies 1.9× below the round-2 value (0.058), near the margin")
    sharp_lobe_pitches: float = tuned(
        2.0, name="SHARP_LOBE_PITCHES", units="half-vector pitches",
        what="a lobe whose half width at half maximum is at most this many of the camera's half-vector pitches "
             "has its peak in a few pixels: its tilt is tested against the fit's own uncertainty, below the "
             "pitch's floor",
        source="mechanism: within a couple of pixels the peak's shape places it to a fraction of a pixel (steel "
               "and chrome-steel on the ideal device tilted 0.03–0.20°: found within 0.015°, ±0.004–0.010°); "
               "broader lobes spread their tilt over many pixels where the 1-D model's misfit biases it. "
               "Measurement (hand-held study, ideal device, the 50 untilted captures): without the gate 10 keep "
               "tilts of 0.01–0.40° (blue-metallic-paint, half width 8.1°: 0.40°; color-changing-paint2, 0.72°: "
               "0.17°; chm_mint, 0.59°: 0.10°); with it and SUBPIXEL_BIAS's floor, every untilted capture of the "
               "study and the four sweeps keeps the axis it kept with the pitch's floor, but red-specular-plastic "
               "on wide (0.048°) and chm_mint on wide-as-built")
    subpixel_bias: float = tuned(
        0.1, name="SUBPIXEL_BIAS", units="half-vector pitches",
        what="the least uncertainty of a sharp lobe's tilt in the device-axis test: the bias of a peak placed "
             "between pixels",
        source="mechanism: a peak one or two pixels wide, located from its pixels' values by a model of its "
               "shape, is drawn toward the pixel centres by up to about a tenth of a pixel (peak locking, the "
               "known bias of sub-pixel peak estimators in particle image velocimetry); measurement (sweeps and "
               "hand-held study, ideal and as-built, untilted): the sharp lobes' estimates lie 0.010–0.022° from "
               "the device axis with fit uncertainties under half of that (steel ±0.005°), and kept, "
               "pink-jasper's 0.013° would raise its eq. 10 error by 8 %")
    sharp_tilt_sigmas: float = tuned(
        10.0, name="SHARP_TILT_SIGMAS", units="the tilt's standard uncertainties",
        what="a sharp lobe's estimated tilt beyond this many of its own uncertainties is kept without the device "
             "frame's check (whose ε comparison a peak the tilt hides biases)",
        source="measurement: untilted sharp lobes' estimates lie 0.010–0.022° off the axis, at most 1.1 of the "
               "0.02° floor of their uncertainty (sweeps and hand-held study, ideal and as-built); hematite tilted "
               "0.7° toward the rim (as-built, calibrated) is found 0.002° off at 35 uncertainties, where the "
               "device frame's ε, lowered by the grazing peak the tilt hides, kept the device axis (eq. 10 2.1× "
               "the true normal's); the hand-held study's 50 materials reproduce their records exactly")
    exact_model_misfit: float = tuned(
        0.01, name="EXACT_MODEL_MISFIT", units="ε (relative RMS residual beyond the noise)",
        what="a lobe of any width whose last light fit misfits the capture by at most this has its tilt tested "
             "against the fit's own uncertainty, as a sharp lobe's is",
        source="measurement: the light fits of analytic lobes, the model exact (40 random GGX and Beckmann "
               "lobes, α 0.02–0.6, as-built, calibrated, tilted 0–10°), end at ε 0.0009–0.0063 (0.017–0.063 on "
               "four whose tilt hid a peak); the 50 shared materials' at 0.026 and up (as-built, untilted and "
               "tilted), 0.028 (ideal), 0.063 (wide): none moves. Checked on 280 other random lobes tilted "
               "0–0.6°: 83 small tilts kept instead of the device axis, eq. 10 0.11× (as-built) and 0.072× "
               "(ideal) in geometric mean, none of 94 untilted captures given a tilt (docs/design/normal.md)")
    albedo_angles: tuple[float, ...] = tuned(
        (0.0, 30.0, 60.0, 75.0, 85.0, 89.0), name="ALBEDO_ANGLES", units="deg",
        what="incidence angles at which the directional albedo is checked against 1 (limit_energy)",
        source="mechanism: energy conservation from normal incidence up to 89° (docs/design/reconstruction.md); "
               "the choice of the intermediate angles is not recorded")
    albedo_quad: int = tuned(
        48, name="ALBEDO_QUAD", units="rings = azimuths",
        what="half-vector quadrature of the albedo check (48 × 48)",
        source="measurement: within 1e-3 of a 400 × 512 quadrature on GGX and Beckmann lobes of α = 0.05–0.8 "
               "(f4af55d)")
    albedo_refine_above: float = tuned(
        0.99, name="ALBEDO_REFINE_ABOVE", units="albedo",
        what="where the check reads above this it is repeated on the fine quadrature and the larger value counts",
        source="measurement: on a tabulated NDF with structure toward grazing the 48 × 48 quadrature misses up "
               "to 2e-3 at 89° (aurora_white: 1.0000 against 1.0015–1.0022 at 96–256 rings) (dfaafac); "
               "no reason for 0.99 itself is recorded")
    albedo_azimuths: int = tuned(
        12, name="ALBEDO_AZIMUTHS", units="azimuths",
        what="an anisotropic model's albedo is checked at this many incidence azimuths (30° apart), then "
             "refined by two bisections about the largest",
        source="convention: the incidence azimuths compare's normalization takes (evaluate.metrics."
               "ALBEDO_AZIMUTHS); measurement: on a hemicube model of GGX α 0.5 × 0.05 the largest albedo "
               "lies at φ_i = 90°, 1.16 against 0.91 at φ_i = 0 alone")
    albedo_quad_fine: int = tuned(
        128, name="ALBEDO_QUAD_FINE", units="rings = azimuths",
        what="the fine quadrature of the albedo check (128 × 128)",
        source="measurement: 96–256 rings read 1.0015–1.0022 at 89° on aurora_white (dfaafac)")
    min_samples: int = tuned(
        100, name="MIN_SAMPLES", units="samples",
        what="fewer valid samples than this make no capture",
        source="mechanism: the isotropic fit has 95 unknowns (the 92 nodes of the polar NDF, k_d, k_s, η); "
               "fewer samples than that cannot determine them, 100 is the first round number above")


POLAR = PolarTuning()
ISOTROPIC = IsotropicFitTuning()
ISOTROPY = IsotropyTestTuning()
HEMICUBE_FIT = HemicubeFitTuning()
NDF = NDFTuning()
FRESNEL_FIT = FresnelFitTuning()
SAMPLES = SamplesTuning()
SYMMETRY = SymmetryTuning()
SYMMETRY_TEST = SymmetryTestTuning()
CONSISTENCY = ConsistencyTuning()
REPEAT = RepeatTuning()
SYNTHESIS = SynthesisTuning()
ASYMMETRIC = AsymmetricTuning()
NORMAL = NormalTuning()
MOTION = MotionTuning()
PIPELINE = PipelineTuning()
EXTRAPOLATION = ExtrapolationTuning()

#: Every stage's default instance, by the instance's name, in the paper's order.
STAGES: dict[str, Any] = {
    "POLAR": POLAR, "ISOTROPIC": ISOTROPIC, "ISOTROPY": ISOTROPY, "FRESNEL_FIT": FRESNEL_FIT, "SAMPLES": SAMPLES,
    "NDF": NDF, "HEMICUBE_FIT": HEMICUBE_FIT, "NORMAL": NORMAL, "MOTION": MOTION, "SYMMETRY": SYMMETRY,
    "CONSISTENCY": CONSISTENCY,
    "EXTRAPOLATION": EXTRAPOLATION,
    "REPEAT": REPEAT, "SYMMETRY_TEST": SYMMETRY_TEST, "SYNTHESIS": SYNTHESIS, "ASYMMETRIC": ASYMMETRIC,
    "PIPELINE": PIPELINE,
}

BEGIN_MARKER = ("<!-- constants: begin (generated from reflecto/reconstruct/tuning.py by "
                "`python -m reflecto.reconstruct.tuning --update docs/design/reconstruction.md`; do not edit) -->")
END_MARKER = "<!-- constants: end -->"


def _number(v: Any) -> str:
    """A value as the table shows it: integers as they are, floats to 6 significant digits."""
    if isinstance(v, tuple):
        return "(" + ", ".join(_number(x) for x in v) + ")"
    if isinstance(v, int):
        return str(v)
    s = f"{v:.6g}"
    if "e" in s:
        mantissa, exponent = s.split("e")
        s = f"{mantissa}e{int(exponent)}"
    return s


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def constants_table() -> str:
    """The Markdown table of every tuned number: constant, value, units, stage field, what, source."""
    lines = ["| constant | value | units | stage | what | source |", "|---|---|---|---|---|---|"]
    for instance_name, stage in STAGES.items():
        module = type(stage).module.rsplit(".", 1)[-1]
        for f in dataclasses.fields(stage):
            m = f.metadata
            names = [f"{module}.{m['name']}", *m["also"]]
            constant = "<br>".join(f"`{n}`" for n in names)
            where = f"`{instance_name}.{f.name}` ({type(stage).paper})"
            lines.append("| " + " | ".join([_cell(constant), _cell(_number(getattr(stage, f.name))),
                                           _cell(m["units"]), _cell(where), _cell(m["what"]),
                                           _cell(m["source"])]) + " |")
    return "\n".join(lines) + "\n"


def _block() -> str:
    return f"{BEGIN_MARKER}\n\n{constants_table()}\n{END_MARKER}"


def document_block(text: str) -> str:
    """The generated block of a document (markers included); ``ValueError`` when it has none."""
    start, end = text.find(BEGIN_MARKER), text.find(END_MARKER)
    if start < 0 or end < start:
        raise ValueError("the document has no constants block (its begin and end markers)")
    return text[start: end + len(END_MARKER)]


def update_document(path: str | Path) -> bool:
    """Rewrite the constants block of ``path`` from :func:`constants_table`; ``True`` if it changed."""
    p = Path(path)
    text = p.read_text(encoding="utf-8")
    new = text.replace(document_block(text), _block())
    if new != text:
        p.write_text(new, encoding="utf-8")
    return new != text


def main(argv: list[str]) -> int:
    """``python -m reflecto.reconstruct.tuning [--update | --check DOC]``: print, rewrite or check the table."""
    if not argv:
        sys.stdout.write(constants_table())
        return 0
    if len(argv) == 2 and argv[0] == "--update":
        changed = update_document(argv[1])
        print(f"{argv[1]}: constants table {'rewritten' if changed else 'already current'}")
        return 0
    if len(argv) == 2 and argv[0] == "--check":
        current = document_block(Path(argv[1]).read_text(encoding="utf-8")) == _block()
        print(f"{argv[1]}: constants table {'current' if current else 'out of date'}")
        return 0 if current else 1
    print("usage: python -m reflecto.reconstruct.tuning [--update DOC | --check DOC]", file=sys.stderr)
    return 2


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
