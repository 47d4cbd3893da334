"""The altered normal (paper §5.4): the sample's normal in device coordinates.

A hand-held capture is tilted: the sample's normal ``n`` is not the device axis. The
slices store ``f`` computed with the device normal (:mod:`reflecto.instrument.slices`),
so in the sample frame each LED's values carry the factor ``(n₀·l)/(n·l)`` and every
direction is rotated (:meth:`~reflecto.instrument.slices.Slices.reframe`).

**The mechanism of every reconstruction** (:func:`estimate_normal`, docs/design/normal.md):

1. A first estimate from the specular peak (:func:`peak_normal`): in the steepest LED
   slice whose peak stands clear of its floor and lies inside the view cone, the
   half vector of the peak ``h = normalize(l + v_peak)`` is the normal (the mirror
   direction of a lobe centred on ``n``); otherwise the device axis.
2. The two tilt angles refined inside the isotropic fit's least squares
   (:class:`TiltProblem`): with ``D``, ``S`` and ``η`` of an isotropic fit in the
   current frame, Gauss–Newton on ``(t_x, t_y, k_d, k_s)`` of the residuals per sample,
   weighted by eq. 10's ``cos² θ_i`` (the weights the fit itself uses) over the sample's
   noise variance (:func:`inverse_variance`), where
   ``n = normalize(t_x, t_y, 1)``; the fit is repeated in the new frame until the
   step is below :data:`CONVERGED_DEG`. The samples: every pixel of the specular
   peaks (a sharp peak covers a few pixels, and there the residuals move most with
   the tilt) and a regular grid of the rest.
3. Its uncertainty: the cluster-robust (sandwich) covariance of that last step with
   the LEDs as clusters (:meth:`TiltProblem.step`): the errors that do not average
   out within a slice (a calibration error of one LED, the model's misfit at one
   incidence) are correlated within the slice, not between slices (where fewer than
   three LEDs hold data, as for a sharp metal on a noiseless camera, the samples are
   the clusters: two LEDs' spread is no estimate); combined in
   quadrature with the shift of the optimum when the samples are weighted alike
   instead of by ``cos² θ_i`` (:func:`weighting_shift_deg`): a misfit every LED shares
   pulls the tilt by an amount that depends on where the weight lies, a bias the
   sandwich cannot see. The larger standard deviation of the two tilt angles is
   reported, and never less than the camera's sampling of the half vector
   (:func:`half_vector_pitch_deg`, ≈ 0.2°).

The old §5.4 search (HLHZ08's consistency criterion on a grid of tilts, Nelder–Mead;
:class:`ConsistencyDistance`, :class:`IsotropicDistance`,
:func:`estimate_normal_consistency`) is kept for the several captures of §5.5.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import minimize

from .. import geometry
from ..colour import LUM
from ..errors import ReflectoError
from ..hemicube import hemicube
from ..instrument.slices import MIN_LIGHT_COS, Slices
from ..model import IsotropicMicrofacetBRDF
from ..polar import cell_table, interpolation_cells, lobe_half_width_deg, polar_nodes
from . import _normal_kernels, _polar_kernels, isotropic, symmetry
from .fresnel_fit import fit_fresnel, overlap_pairs
from .samples import bin_samples, kd_bound
from .tuning import NORMAL

Array = NDArray[np.float64]


class NormalDistance(Protocol):
    """A distance of the slices from consistency in the frame of the candidate normal
    ``normalize(tx, ty, 1)``: :class:`ConsistencyDistance`, :class:`IsotropicDistance`,
    :class:`.asymmetric.SetDistance`."""

    def __call__(self, normal_xy: Array) -> float:
        """The distance at the tangent offset ``normal_xy = (tx, ty)``; ``inf`` where it cannot be judged."""
        ...


#: LEDs less than this far above a candidate frame's horizon (degrees) take no part in
#: its :class:`IsotropicDistance`: a frame that sank the worst-fitting grazing LEDs
#: would otherwise win by fitting fewer data (specular maroon phenolic tilted 5°:
#: 7.8° off), and counting their samples as lost biases the tilt of captures whose
#: LEDs truly sink (GGX α = 0.1 at 10°: found 8.97°).
LED_MARGIN_DEG = NORMAL.led_margin_deg
#: Minimum number of texel pairs for a candidate to count.
MIN_PAIRS = NORMAL.min_pairs


def tilt_frame(tx: float, ty: float) -> Array:
    """Frame (rows t, b, n) whose normal is ``normalize(tx, ty, 1)``; t follows device x."""
    return geometry.frame_from_normal(np.array([tx, ty, 1.0]), np.array([1.0, 0.0, 0.0]))


class ConsistencyDistance:
    """E(η) of the slices re-expressed in a candidate frame (see the module docstring).

    Parameters
    ----------
    slices
        :class:`~reflecto.instrument.slices.Slices` in the device frame.
    valid
        Usable samples, shape ``(L, P)``.
    shadowing
        ``S(k)`` for local directions (a first reconstruction's), callable on ``(M, 3)``.
    n
        Working hemicube resolution of the bins.
    stride
        Use every ``stride``-th pixel (speed).
    kd_bound_max_deg
        The reconstruction's :attr:`~.pipeline.Options.kd_bound_max_deg` (same k_d bound).
    """

    def __init__(self, slices, valid: NDArray[np.bool_], shadowing, n: int = 64, stride: int = 1,
                 kd_bound_max_deg: float = 75.0) -> None:
        px = np.arange(0, slices.view.shape[0], stride)
        self.slices = type(slices)(slices.light, slices.view[px], slices.values[:, px],
                                   slices.valid[:, px] & valid[:, px], slices.pixels[px], slices.frame)
        self.shadowing = shadowing
        self.cube = hemicube(n)
        self.n_leds = slices.n_leds
        self.kd_bound_max_deg = kd_bound_max_deg

    def __call__(self, normal_xy: Array) -> float:
        """E(η) in the frame of the candidate normal ``normalize(tx, ty, 1)``, ``normal_xy = (tx, ty)``.

        ``inf`` with too few samples or overlap pairs.
        """
        sl = self.slices.reframe(tilt_frame(float(normal_xy[0]), float(normal_xy[1])))
        ok = sl.valid
        if ok.sum() < 1000:
            return float("inf")
        kd_max = kd_bound(sl.light, sl.view, sl.values, ok, sl.pixels, self.kd_bound_max_deg)
        bins = bin_samples(sl.light, sl.view, sl.values, ok, self.cube)
        pairs = overlap_pairs(bins, self.n_leds)
        a = bins.i[:, 2] * bins.o[:, 2] / np.maximum(self.shadowing(bins.i) * self.shadowing(bins.o), 1e-6)
        fit = fit_fresnel(bins, pairs, a, self.n_leds, 0.5 * kd_max, np.full(3, 1.5), kd_max, per_channel=False,
                          diagnostics=False)
        return float(fit.error) if np.isfinite(fit.error) and fit.n_pairs >= MIN_PAIRS else float("inf")


class IsotropicDistance:
    """The misfit of an isotropic 1-D fit to the slices re-expressed in a candidate frame.

    An isotropic BRDF depends on ``θ_h`` (through D), ``θ_d``, ``θ_i`` and ``θ_o`` only in
    the sample's own frame; in a frame tilted away from it, samples on one ring of half
    vectors see different parts of the lobe and the 1-D model of :mod:`.isotropic`
    cannot follow them. The distance is that fit's relative model error ``ε``
    (:func:`.isotropic.model_error`), which falls to the material's own misfit at the
    true normal (chrome steel tilted 5°: 0.35 there, 0.37–0.39 at 1°, 0.41–0.44 at 3°),
    over the LEDs at least :data:`LED_MARGIN_DEG` above the candidate's horizon.

    Parameters
    ----------
    slices
        :class:`~reflecto.instrument.slices.Slices` in the device frame.
    valid
        Usable samples, shape ``(L, P)``.
    stride
        Use every ``stride``-th pixel (speed).
    outer_iterations
        Outer iterations (S from D) of each fit.
    """

    def __init__(self, slices, valid: NDArray[np.bool_], stride: int = 1, outer_iterations: int = 2) -> None:
        px = np.arange(0, slices.view.shape[0], stride)
        keep = slices.valid[:, px] & valid[:, px]
        self.slices = dataclasses.replace(slices, view=slices.view[px], values=slices.values[:, px], valid=keep,
                                          pixels=slices.pixels[px],
                                          censored=None if slices.censored is None else slices.censored[:, px],
                                          noise=None if slices.noise is None else slices.noise[:, px],
                                          limit=None if slices.limit is None else slices.limit[:, px],
                                          check_leds=(), check_values=None, check_valid=None)
        self.nodes = polar_nodes()
        self.outer_iterations = outer_iterations

    def __call__(self, normal_xy: Array) -> float:
        """The isotropic fit's ``ε`` in the frame of the candidate normal ``normalize(tx, ty, 1)``.

        ``normal_xy = (tx, ty)``; ``inf`` with too few samples or where the fit fails.
        """
        sl = self.slices.reframe(tilt_frame(float(normal_xy[0]), float(normal_xy[1])))
        # LEDs near the candidate's horizon take no part (their cos θ_i correction, and
        # the model's fit at grazing incidence, are least certain there)
        low = sl.light[:, 2] < math.sin(math.radians(LED_MARGIN_DEG))
        sl = dataclasses.replace(sl, valid=sl.valid & ~low[:, None])
        if int(sl.valid.sum()) < 1000:
            return float("inf")
        try:
            bins = isotropic.bin_polar(sl, self.nodes, sl.valid)
            fit = isotropic.fit_luminance(bins, self.nodes, outer_iterations=self.outer_iterations)
        except ReflectoError:
            return float("inf")
        if not math.isfinite(fit.eps):
            return float("inf")
        return float(fit.eps)


def _tilt_grid(max_tilt_deg: float, step_deg: float) -> Array:
    """Candidate normals as tangent-plane offsets ``(tx, ty)``: the untilted normal and
    rings every ``step_deg`` up to ``max_tilt_deg``, ≈ ``step_deg`` apart along each ring."""
    pts = [np.zeros(2)]
    for t in np.arange(step_deg, max_tilt_deg + 1e-9, step_deg):
        k = max(6, int(round(2 * math.pi * t / step_deg)))
        a = np.arange(k) * (2 * math.pi / k)
        pts.extend(math.tan(math.radians(t)) * np.stack([np.cos(a), np.sin(a)], axis=1))
    return np.array(pts)


def _grid_minima(xy: Array, e: Array, radius_deg: float) -> NDArray[np.intp]:
    """Indices of the grid's local minima (no finite neighbour within ``radius_deg`` is
    lower), lowest first."""
    n = np.column_stack([xy, np.ones(len(xy))])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    near = n @ n.T > math.cos(math.radians(radius_deg))
    e_near = np.where(near, e[None, :], np.inf)
    is_min = np.isfinite(e) & (e <= e_near.min(axis=1))
    idx = np.flatnonzero(is_min)
    return idx[np.argsort(e[idx])]


#: At most this many local minima of the coarse grid are refined (multi-start).
N_STARTS = NORMAL.n_starts


def estimate_normal_consistency(
    coarse: NormalDistance, fine: NormalDistance, max_tilt_deg: float = 16.0, step_deg: float = 3.0,
    n_starts: int = N_STARTS,
) -> tuple[Array, float]:
    """Grid search of ``coarse`` over tilts ≤ ``max_tilt_deg``, multi-start refinement,
    Nelder–Mead on ``fine``.

    The distance's basin at the true normal is narrow where an LED sits near the
    sample's horizon (≈ 1° for a Beckmann α = 0.2 lobe: a candidate that keeps that
    LED sees its near-zero slice as inconsistent), so the grid's best point can lie in
    a wide, shallow basin elsewhere (tilts of 10°: the grid point 1° from the truth
    ranked fourth). The ``n_starts`` lowest local minima of the grid are therefore
    refined on ``coarse`` (Nelder–Mead, steps of ``step_deg / 2``), compared on
    ``fine``, and the best refined by Nelder–Mead on ``fine``. Candidates beyond ``max_tilt_deg + step_deg`` count
    as infinitely far.

    Returns the unit normal (device frame) and the distance at it.
    """
    limit = math.tan(math.radians(min(max_tilt_deg + step_deg, 89.0)))

    def bounded(dist: NormalDistance):
        return lambda xy: dist(xy) if float(np.hypot(xy[0], xy[1])) <= limit else float("inf")

    grid = _tilt_grid(max_tilt_deg, step_deg)
    e = np.array([coarse(xy) for xy in grid])
    starts = _grid_minima(grid, e, 1.6 * step_deg)[:n_starts]
    if len(starts) == 0:
        starts = np.array([0])
    d = math.tan(math.radians(0.5 * step_deg))
    simplex = np.array([[0, 0], [d, 0], [0, d]])
    best = (math.inf, grid[starts[0]])
    for i in starts:
        xy = grid[i]
        if len(starts) > 1:  # each basin's bottom, compared on the fine distance
            xy = minimize(bounded(coarse), xy, method="Nelder-Mead",
                          options={"xatol": 2e-3, "fatol": 1e-5, "maxfev": 30, "initial_simplex": xy + simplex}).x
        e_fine = fine(xy) if len(starts) > 1 else 0.0
        if e_fine < best[0]:
            best = (e_fine, xy)
    return refine_normal(fine, tilt_frame(float(best[1][0]), float(best[1][1]))[2], 0.5 * step_deg, limit)


def refine_normal(dist: NormalDistance, normal: Array, step_deg: float = 1.0,
                  limit: float = math.inf, maxfev: int = 80, probe_deg: float = 0.0,
                  n_probe: int = 12) -> tuple[Array, float]:
    """Nelder–Mead on ``dist`` from ``normal`` (initial steps ``step_deg``); candidates
    whose tangent offset exceeds ``limit`` count as infinitely far.

    With ``probe_deg > 0`` the start is the best of ``normal`` and ``n_probe`` normals
    on each of two rings, ``probe_deg / 2`` and ``probe_deg`` around it: a shallow dip of the distance a degree or two
    from the true normal (a ridge between them) otherwise holds the search.

    Returns the unit normal (device frame) and the distance at it.
    """
    xy0 = np.asarray(normal[:2], dtype=np.float64) / float(normal[2])
    if probe_deg > 0:
        a = np.arange(n_probe) * (2 * math.pi / n_probe)
        unit = np.stack([np.cos(a), np.sin(a)], axis=1)
        cands = np.vstack([xy0] + [xy0 + math.tan(math.radians(r)) * unit for r in (0.5 * probe_deg, probe_deg)])
        xy0 = cands[int(np.argmin([dist(xy) for xy in cands]))]
    d = math.tan(math.radians(step_deg))
    res = minimize(lambda xy: dist(xy) if float(np.hypot(xy[0], xy[1])) <= limit else float("inf"), xy0,
                   method="Nelder-Mead", options={"xatol": 5e-4, "fatol": 1e-6, "maxfev": maxfev,
                                                  "initial_simplex": xy0 + np.array([[0, 0], [d, 0], [0, d]])})
    xy = res.x
    return tilt_frame(float(xy[0]), float(xy[1]))[2], float(res.fun)


# ------------------------------------------------------------------ the altered normal of every reconstruction

#: Every ``SAMPLE_STRIDE``-th pixel off the specular peaks enters the tilt's least squares
#: (≈ 5 300 views of the default optics, ×6 LEDs), with weight ``SAMPLE_STRIDE``.
SAMPLE_STRIDE = NORMAL.sample_stride
#: In a slice with a peak, samples above this share of the capture's peak (over the slice's
#: median) enter the tilt's step all (:func:`_lobe_mask`).
LOBE_LEVEL = NORMAL.lobe_level
#: Every ``FIT_STRIDE``-th pixel enters the isotropic fits inside the estimate (the
#: final fit in the estimated frame uses all).
FIT_STRIDE = NORMAL.fit_stride
#: Outer iterations (S from D) of those fits.
FIT_OUTER_ITERATIONS = NORMAL.fit_outer_iterations
#: Width of those fits' θ_d cells (radians; the model's fits: :data:`.isotropic.TD_STEP`).
FIT_TD_STEP = NORMAL.fit_td_step
#: The estimate has converged when a refit moves the normal by less than this (degrees)
#: or by less than :data:`CONVERGED_SHARE` of its uncertainty.
CONVERGED_DEG = NORMAL.converged_deg
CONVERGED_SHARE = NORMAL.converged_share
#: At most this many refits.
MAX_REFITS = NORMAL.max_refits
#: The refits' sequence of normals is extrapolated to its limit (vector Aitken) when it
#: shrinks by a ratio below this from one refit to the next (the limit then lies at most
#: 3× the last move further) …
AITKEN_MAX_RATIO = NORMAL.aitken_max_ratio
#: … and the move before was below this (degrees): far from the limit the moves are
#: set by the trust region (:data:`MAX_STEP_DEG`), not by a geometric convergence.
AITKEN_MAX_STEP_DEG = NORMAL.aitken_max_step_deg
#: Gauss–Newton steps with the model held fixed after each refit.
INNER_STEPS = NORMAL.inner_steps
#: Largest step of one Gauss–Newton iteration (degrees; a trust region).
MAX_STEP_DEG = NORMAL.max_step_deg
#: Samples whose view is within this of the candidate's horizon (degrees) take no part in the tilt's step.
MIN_VIEW_DEG = NORMAL.min_view_deg
MIN_VIEW_COS = math.sin(math.radians(MIN_VIEW_DEG))
#: A peak stands clear of its slice's floor when its luminance is this many times
#: the slice's median …
PEAK_CONTRAST = NORMAL.peak_contrast
#: … and lies at least this far (degrees) inside the view cone's rim.
PEAK_RIM_DEG = NORMAL.peak_rim_deg


@dataclasses.dataclass(frozen=True)
class NormalEstimate:
    """The sample normal in device coordinates and how well it is known.

    Attributes
    ----------
    normal
        Unit normal, shape ``(3,)``.
    uncertainty_deg
        Standard uncertainty of its direction (degrees): the larger principal standard
        deviation of the cluster-robust covariance (LEDs as clusters) for an estimated
        normal; 0 for a normal imposed by the options.
    source
        ``"estimated"`` (§5.4 from the data), ``"device"`` (the device axis: imposed,
        or the estimate did not differ from it significantly) or ``"given"``.
    refits
        Isotropic fits the estimate took.
    tilt_estimate_deg
        The estimated tilt before the decision for the device axis (degrees; NaN when
        nothing was estimated).
    alternative
        A normal the data allow as well, shape ``(3,)`` (the eq. 3 test looks in its frame
        too), else ``None``: where the device axis was kept over an estimate (one within
        two uncertainties of it, or one that fitted no better), that estimate; where the
        symmetry planes moved the fit's normal (``planes`` > 0), the fit's normal.
    half_vector_pitch_deg
        The camera's sampling of the half vector (:func:`half_vector_pitch_deg`) where the
        estimate measured it (the floor of its uncertainty); else NaN.
    planes
        The slices' symmetry planes that entered the estimate (:func:`with_symmetry_planes`;
        0 where they gave none).
    fit_uncertainty_deg
        The estimate's uncertainty before the floor of the half vector's sampling: what
        the fit's residuals and the symmetry planes tell (degrees; NaN when nothing was
        estimated).
    lobe_half_width_deg
        Half width at half maximum of the last light fit's NDF (degrees; NaN when nothing
        was estimated).
    misfit
        ``ε`` of the last light fit (:attr:`.isotropic.LuminanceFit.eps`: the RMS relative
        residual beyond the camera noise) in the frame the tilt was refined from; NaN when
        nothing was estimated.
    peak_tilt_deg
        The tilt of the first estimate, the steepest peaked slice's half vector
        (:func:`peak_normal`), degrees; NaN where no slice peaks. Beyond the search's bound it
        is not used.
    """

    normal: Array
    uncertainty_deg: float
    source: str
    refits: int = 0
    tilt_estimate_deg: float = math.nan
    alternative: Array | None = None
    half_vector_pitch_deg: float = math.nan
    planes: int = 0
    fit_uncertainty_deg: float = math.nan
    lobe_half_width_deg: float = math.nan
    misfit: float = math.nan
    peak_tilt_deg: float = math.nan

    @property
    def tilt_deg(self) -> float:
        """Angle between the normal and the device axis, ``acos(n_z)`` (degrees)."""
        return geometry.tilt_deg(self.normal)

    @property
    def frame(self) -> Array:
        """Rows ``(t, b, n)`` of the sample frame; ``t`` follows device x."""
        if self.normal[2] >= 1.0:
            return np.eye(3)
        return geometry.frame_from_normal(self.normal, np.array([1.0, 0.0, 0.0]))


def _angle_deg(a: Array, b: Array) -> float:
    return math.degrees(math.acos(min(1.0, max(-1.0, float(np.dot(a, b))))))


@dataclasses.dataclass(frozen=True)
class SlicePeak:
    """The specular peak of one LED's slice (:func:`slice_peaks`).

    Attributes
    ----------
    led
        The LED.
    normal
        The half vector of the peak's centroid, ``normalize(Σ w h)`` over the pixels above
        half the peak's height (``w`` their height above that level, ``h = (l + v)/|l + v|``),
        in the slices' frame, shape ``(3,)``: the normal of a lobe centred on it.
    cos_light
        ``l_z``, the LED's direction cosine to the frame's axis (the steepest LED's peak
        has the smallest off-specular shift).
    radius_deg
        The largest angle between a pixel's half vector above that level and ``normal``
        (degrees): a lobe's peak a few pixels across, or a ridge or plateau degrees wide
        where the slice only grazes a lobe's flank.
    """

    led: int
    normal: Array
    cos_light: float
    radius_deg: float


def slice_peaks(slices, valid: NDArray[np.bool_]) -> list[SlicePeak]:
    """The slices' specular peaks (:class:`SlicePeak`), by LED.

    An LED's slice (luminance ``Y`` of its ``valid`` samples, at least 100) has a peak
    where its largest value is at least :data:`PEAK_CONTRAST` times its median and lies
    at least :data:`PEAK_RIM_DEG` inside the rim of the view cone (a peak the rim cuts
    is placed by the rim). The peak's pixels are those above ``½(Y_max + median)``. A
    slice with a non-finite value among its ``valid`` samples has none.
    ``slices`` in any frame (the peaks' half vectors are in it), ``valid`` shape ``(L, P)``.
    """
    view = slices.view
    axis = geometry.normalize(view.mean(axis=0))
    cos_axis = view @ axis

    def angle_deg(i: int) -> float:  # the angle of pixel i from the axis: taken where a peak asks for it
        return float(np.degrees(np.arccos(np.clip(cos_axis[i:i + 1], -1.0, 1.0)))[0])

    rim = angle_deg(int(np.argmin(cos_axis))) - PEAK_RIM_DEG  # the widest view (arccos decreases)
    out = []
    for k in range(slices.n_leds):
        # the valid samples' pixels, gathered once (not as masked copies), and not at all where all are valid
        n_valid = int(np.count_nonzero(valid[k]))
        if n_valid < 100:
            continue
        idx = None if n_valid == len(view) else np.flatnonzero(valid[k])
        # C order, as a gathered copy is: the product then runs the same code whatever the layout
        y = (np.ascontiguousarray(slices.values[k]) if idx is None else slices.values[k, idx]) @ LUM
        if not np.all(np.isfinite(y)):  # a value the usable samples would not hold: no peak to place
            continue
        med = float(np.median(y))
        j = int(np.argmax(y))
        if not (y[j] > PEAK_CONTRAST * max(med, 1e-300) and angle_deg(j if idx is None else int(idx[j])) < rim):
            continue
        level = 0.5 * (y[j] + med)
        top = y > level
        h = slices.light[k] + view[top if idx is None else idx[top]]
        h /= np.linalg.norm(h, axis=1, keepdims=True)
        n = geometry.normalize(((y[top] - level)[:, None] * h).sum(axis=0))
        if not np.all(np.isfinite(n)):
            continue
        radius = math.degrees(math.acos(min(1.0, float(np.min(h @ n)))))
        out.append(SlicePeak(k, n, float(slices.light[k, 2]), radius))
    return out


def peak_normal(slices, valid: NDArray[np.bool_], peaks: list[SlicePeak] | None = None) -> Array | None:
    """First estimate of the normal from the specular peak (module docstring, step 1):
    of the slices' peaks (:func:`slice_peaks`; ``peaks`` where already found in the
    device frame), the steepest LED's (its lobe's off-specular shift is the smallest).
    ``None`` when no slice has a peak.
    """
    peaks = slice_peaks(slices, valid) if peaks is None else peaks
    best: SlicePeak | None = None
    for p in peaks:
        if best is None or p.cos_light > best.cos_light:
            best = p
    return None if best is None else best.normal


def _lobe_mask(y: Array, ok: NDArray[np.bool_], level: float, stride: int) -> NDArray[np.bool_]:
    """The samples on the capture's specular peaks, shape ``(L, P)``: in each LED slice
    whose peak stands clear of its floor (maximum above :data:`PEAK_CONTRAST` times its
    median, as in :func:`peak_normal`), the samples above ``median + level · (Y_max −
    median)``, ``Y_max`` the brightest usable sample of the capture; not where these are
    more than one in ``stride`` of the slice's samples (a broad lobe, which the stride's
    grid samples as finely as the rest).

    The tilt moves a lobe across the pixels; the residuals' derivative with respect to
    it is largest on the lobe's flanks, and a sharp lobe covers only a few pixels, which
    a regular stride can miss (module docstring, step 2)."""
    out = np.zeros(ok.shape, dtype=bool)
    stats = []
    for k in range(ok.shape[0]):
        v = y[k, ok[k]]
        stats.append((float(np.median(v)), float(v.max())) if v.size >= 100 else None)
    tops = [t for st in stats if st is not None for t in st[1:]]
    if not tops:
        return out
    y_max = max(tops)
    for k, st in enumerate(stats):
        if st is not None and st[1] > PEAK_CONTRAST * max(st[0], 1e-300):
            lobe = ok[k] & (y[k] > st[0] + level * (y_max - st[0]))
            if np.count_nonzero(lobe) * stride <= np.count_nonzero(ok[k]):  # a broad lobe: the grid holds it
                out[k] = lobe
    return out


def inverse_variance(sd: Array) -> Array:
    """``1/σ²`` per sample, scaled to a median of 1: the factor that makes the tilt's
    least squares heteroscedastic. ``σ`` (any unit, shape ``(N,)``) is the camera noise
    of each sample's reading (:attr:`~reflecto.instrument.slices.Slices.noise`),
    floored at 10⁻³ of its median so that a noiseless sample cannot take all the
    weight; all ones where no sample has a noise.

    The tilt is a geometric parameter, not the BRDF that eq. 10 judges: how well it is
    located depends on how noisy each sample is. With shot noise the bright pixels of
    a sharp peak are the noisiest in absolute terms, and under eq. 10's weights alone a
    few of them place the normal. A sample weighs eq. 10's ``cos² θ_i`` times ``1/σ²``
    (:meth:`TiltProblem.evaluate`): the cosine is kept because it holds down the
    grazing LEDs, where the microfacet model misfits more than the noise. Measured on
    the hand-held study's 100 steady as-built captures (docs/design/normal.md): within
    0.5° 93 → 96 of 100 (hematite 0.025° → 0.006° off, violet-rubber 0.54° → 0.11°,
    cm_military_green 0.38° → 0.02°); the full inverse variance of ``r`` (without the
    cosine, the grazing LEDs' misfit weighted up about 70×) 86 of 100. The tuning half
    alone rejects the latter (43 against 49 of 50) but ties the cosine alone with this
    (49 and 49); the validation half's 44 → 47 informed the choice.
    """
    sd = np.asarray(sd, dtype=np.float64)
    positive = sd[sd > 0]
    if not len(positive):
        return np.ones(len(sd))
    floor = 1e-3 * float(np.median(positive))
    inv = 1.0 / np.maximum(sd, floor) ** 2
    return inv / float(np.median(inv))


class TiltProblem:
    """The tilt's least squares with an isotropic model held fixed (module docstring, step 2).

    Samples ``s`` (LED ``l``, view ``v``): every pixel on a specular peak
    (:func:`_lobe_mask`) with weight 1, and every :data:`SAMPLE_STRIDE`-th pixel off them
    with weight ``SAMPLE_STRIDE`` (each stands for the pixels it skips), in device
    coordinates with their luminance ``f`` as stored (device normal ``z``). For a
    candidate normal ``n`` the model is

    ``m = k_d/π + k_s F(l·h; η) D(θ_h) / (4 σ(l·n) σ(v·n))``,  ``cos θ_h = h·n``

    (eqs. 1–2, 8; ``F`` and ``l·h`` do not depend on ``n``), the datum
    ``f_n = f (l·z)/(l·n)`` (:meth:`~reflecto.instrument.slices.Slices.reframe`), and the
    residual ``r = m − f_n`` with weight ``w = (l·n)²/σ²`` (eq. 10's cosine weight, as in
    :func:`.isotropic.set_weights`, over the sample's noise variance, :func:`inverse_variance`;
    the cosine alone where the slices carry no noise). Samples whose LED has ``l·n`` below
    :data:`~reflecto.instrument.slices.MIN_LIGHT_COS` (≈ 3° above the candidate's
    horizon: the limit below which :meth:`Slices.reframe` does not correct ``cos θ_i``
    either), or whose view is within 1° of the horizon, take no part.

    Parameters
    ----------
    slices
        :class:`~reflecto.instrument.slices.Slices` in the device frame.
    valid
        Usable samples, shape ``(L, P)``.
    """

    def __init__(self, slices, valid: NDArray[np.bool_], stride: int = SAMPLE_STRIDE,
                 lobe_level: float = LOBE_LEVEL) -> None:
        ok = valid & slices.valid
        if slices.censored is not None:
            ok &= ~slices.censored
        y = slices.values @ LUM  # (L, P) luminance as stored
        lobe = _lobe_mask(y, ok, lobe_level, stride)
        grid = np.zeros(ok.shape[1], dtype=bool)
        grid[::stride] = True
        keep = ok & (lobe | grid[None, :])
        li, pj = np.nonzero(keep)
        # Horvitz–Thompson: a lobe sample stands for itself, a grid sample off the lobe for ``stride``
        self.weight = np.where(lobe[li, pj], 1.0, float(stride))
        used, pi = np.unique(pj, return_inverse=True)
        self.led = li
        self.pix = pi
        self.lights = np.ascontiguousarray(slices.light)
        self.views = np.ascontiguousarray(slices.view[used])
        self.light = slices.light[li]
        self.view = self.views[pi]
        h = self.light + self.view
        self.half = h / np.linalg.norm(h, axis=1, keepdims=True)
        self.cos_d = np.clip(np.einsum("ij,ij->i", self.light, self.half), 0.0, 1.0)
        z_dev = slices.light[:, 2]  # cos θ_i about the normal the values are for (the slices' own z)
        self.f_dev = y[li, pj] * z_dev[li]
        if slices.noise is not None:  # eq. 10's weights made heteroscedastic (inverse_variance)
            self.weight = self.weight * inverse_variance(slices.noise[li, pj])
        self.n_leds = slices.n_leds
        # the samples are sorted by LED (row-major nonzero): each LED's segment
        self.starts = np.searchsorted(li, np.arange(slices.n_leds + 1))
        self._fresnel: tuple[object, Array] | None = None

    def fresnel(self, model) -> Array:
        """``F(l·h; η)`` per sample, luminance-weighted over the channels' ``k_s`` (cached per model)."""

        if self._fresnel is None or self._fresnel[0] is not model:
            ks = float(model.ks @ LUM)
            self._fresnel = (model, (model._fresnel_table(self.cos_d) * model.ks) @ LUM / max(ks, 1e-300))
        return self._fresnel[1]

    def residuals_numpy(self, ndf, normal: Array, z: Array, kd: float, fresnel: Array
                        ) -> tuple[Array, Array, NDArray[np.intp], Array, NDArray[np.bool_]]:
        """NumPy reference of :func:`._normal_kernels.tilt_pass` without the Jacobian:
        residuals ``r`` (N,), the specular part (N,), the cells ``j, t`` of θ_h and the
        samples that take part, at ``normal`` for log nodes ``z`` (``log(k_s D)``)."""
        sigma = ndf.projected_area
        ci_l = np.maximum(self.lights @ normal, 1e-6)
        co_p = np.maximum(self.views @ normal, 1e-6)
        ci, co = ci_l[self.led], co_p[self.pix]
        use = (ci > MIN_LIGHT_COS) & (co > MIN_VIEW_COS)
        j, t = interpolation_cells(ndf.nodes, np.arccos(np.clip(self.half @ normal, -1.0, 1.0)))
        log_d = (1.0 - t) * z[j] + t * z[j + 1]
        spec = fresnel * np.exp(np.minimum(log_d, 700.0)) / (4.0 * sigma(ci_l)[self.led] * sigma(co_p)[self.pix])
        r = kd / math.pi + spec - self.f_dev / ci
        return r, spec, j, t, use

    def evaluate(self, ndf, xy: Array, z: Array, kd: float, fresnel: Array, cos_power: float = 2.0,
                 jacobian: bool = False, use: NDArray[np.bool_] | None = None) -> _TiltPass:
        """The residuals at the tangent offset ``xy`` (:func:`._normal_kernels.tilt_pass`):
        with ``use`` given, only those samples take part (a trial step is judged on the
        samples of its base); with ``jacobian`` the tilt's columns of the Jacobian."""
        normal, dn = _tilt_normal(xy)
        out = _TiltPass.empty(len(self.led), use)
        cos_h = np.clip(self.half @ normal, -1.0, 1.0)
        theta_h = np.arccos(cos_h)
        d_h = np.empty(len(cos_h))
        _normal_kernels.theta_cells(theta_h, ndf.nodes, cell_table(ndf.nodes.tobytes()), z, out.j, out.t, d_h)
        np.exp(d_h, out=d_h)
        out.cost = _normal_kernels.tilt_pass(
            self.lights, self.views, self.led, self.pix, self.half, cos_h, theta_h, d_h, self.f_dev, fresnel,
            self.weight, ndf.nodes, z, kd, ndf._quad.sigma_theta[1], ndf.sigma, normal, dn, cos_power,
            MIN_LIGHT_COS, MIN_VIEW_COS, use is not None, out.use, jacobian, out.j, out.r, out.spec, out.w, out.dr)
        out.normal = normal
        return out

    def _normal_matrix(self, ev: _TiltPass, k: int, lam: float, curv: Array, z: Array) -> tuple[Array, Array]:
        """``JᵀWJ + λC`` over ``(t_x, t_y, k_d, z)`` and the gradient ``JᵀWr + λCz``
        (:func:`._polar_kernels.normal_equations`)."""
        dense_cols = np.empty((len(ev.r), 3))
        dense_cols[:, :2] = ev.dr
        dense_cols[:, 2] = 1.0 / math.pi
        diag, off, cross = np.empty(k), np.empty(k - 1), np.empty((k, 3))
        dense, grad_z, grad_d = np.empty((3, 3)), np.empty(k), np.empty(3)
        _polar_kernels.normal_equations(ev.j, ev.t, ev.spec, dense_cols, ev.r, ev.w, k, diag, off, cross, dense,
                                        grad_z, grad_d)
        a_mat = np.zeros((k + 3, k + 3))
        a_mat[:3, :3] = dense
        a_mat[:3, 3:] = cross.T
        a_mat[3:, :3] = cross
        iz = np.arange(k)
        a_mat[3 + iz, 3 + iz] += diag
        a_mat[3 + iz[:-1], 4 + iz[:-1]] += off
        a_mat[4 + iz[:-1], 3 + iz[:-1]] += off
        a_mat[3:, 3:] += lam * curv
        return a_mat, np.concatenate([grad_d, grad_z + lam * curv @ z])

    def _scores(self, ev: _TiltPass, k: int) -> tuple[Array, Array]:
        """Per-sample score columns for the covariance: each sample's ``J_b w_b r_b`` as
        its dense part (N, 3) and its z part's two entries ``(w r a₀, w r a₁)`` at ``j, j + 1``."""
        wr = ev.w * ev.r
        dense = np.empty((len(ev.r), 3))
        dense[:, :2] = ev.dr * wr[:, None]
        dense[:, 2] = wr / math.pi
        return dense, np.stack([wr * ev.spec * (1.0 - ev.t), wr * ev.spec * ev.t], axis=1)

    def _covariance_sd(self, ev: _TiltPass, a_mat: Array, k: int) -> float:
        """The tilt's standard uncertainty (degrees): the cluster-robust (sandwich)
        covariance with the LEDs as clusters, or the samples where fewer than three LEDs
        hold data (module docstring, step 3); ``inf`` where it cannot be formed."""
        wd, wz = self._scores(ev, k)
        g_d_led = np.stack([np.bincount(self.led, wd[:, q], self.n_leds) for q in range(3)], axis=1)
        lk = self.led * k
        g_z_led = (np.bincount(lk + ev.j, wz[:, 0], self.n_leds * k)
                   + np.bincount(lk + ev.j + 1, wz[:, 1], self.n_leds * k)).reshape(self.n_leds, k)
        scores = np.concatenate([g_d_led, g_z_led], axis=1)  # (L, K + 3)
        leds = [q for q in range(self.n_leds) if np.any(scores[q] != 0)]
        if not leds:
            return math.inf
        try:
            b = np.linalg.solve(a_mat, np.eye(k + 3)[:, :2])  # the tilt's columns of A⁻¹
        except np.linalg.LinAlgError:
            return math.inf
        if len(leds) >= 3:
            u = scores[leds] @ b  # (L', 2)
            cov = u.T @ u * len(leds) / (len(leds) - 1)
        else:
            # one or two LEDs hold data (a sharp metal on a noiseless camera: the others
            # read 0): too few clusters for their spread; the samples are the clusters
            u = wd @ b[:3] + wz[:, :1] * b[3 + ev.j] + wz[:, 1:] * b[4 + ev.j]
            cov = u.T @ u
        return math.degrees(math.atan(math.sqrt(max(float(np.linalg.eigvalsh(cov).max()), 0.0))))

    def solve(self, model, normal: Array, steps: int | None = None, cos_power: float = 2.0
              ) -> tuple[Array, float, float]:
        """Gauss–Newton (Levenberg–Marquardt) on ``(t_x, t_y, k_d, z)`` with ``S``, ``F``
        and ``η`` of ``model`` held fixed, from ``normal``; ``z`` the log of ``k_s D`` at
        the NDF's nodes (luminance), under the fit's curvature prior on ``log D``
        (:func:`.isotropic.prior`). The Jacobian is analytic
        (:func:`._normal_kernels.tilt_pass`). A sample weighs ``(n·l)^cos_power`` times its
        sampling weight: ``cos_power`` = 2 is eq. 10's cosine weight (the estimate), 0
        weighs the samples alike (:func:`weighting_shift_deg`).

        Returns the normal, its uncertainty (degrees; module docstring, step 3) and the
        weighted RMS residual.
        """

        steps = INNER_STEPS if steps is None else steps
        ndf = model.ndf_table
        k = len(ndf.nodes)
        fresnel = self.fresnel(model)
        z = ndf.log_values + math.log(max(float(model.ks @ LUM), 1e-300))
        kd = float(model.kd @ LUM)
        xy = np.asarray(normal[:2], dtype=np.float64) / float(normal[2])
        curv = isotropic._curvature_matrix(ndf.nodes.tobytes())
        lam = math.nan
        mu = 1e-3
        lim = math.tan(math.radians(MAX_STEP_DEG))
        a_mat = None
        ev = self.evaluate(ndf, xy, z, kd, fresnel, cos_power, jacobian=True)
        for it in range(steps + 1):
            if np.count_nonzero(ev.w) < 100:
                return ev.normal, math.inf, math.nan
            if math.isnan(lam):  # the fit's curvature prior: ρ ℓ⁴ with ρ the data's weight per radian
                m = ev.r + self.f_dev / np.maximum(self.lights[self.led] @ ev.normal, 1e-6)
                span = max(float(np.ptp(np.arccos(np.clip(self.half[ev.use] @ ev.normal, -1, 1)))), 1e-3)
                lam = float(np.sum(ev.w * m * m)) / span * isotropic.SMOOTH_LENGTH ** 4
            if it == steps:
                break
            a_mat, grad = self._normal_matrix(ev, k, lam, curv, z)
            dg = np.diag(a_mat).copy()
            dg += 1e-12 * dg.max()
            cost0 = ev.cost + lam * z @ curv @ z
            improved = False
            while mu < 1e8:
                try:
                    step = -np.linalg.solve(a_mat + mu * np.diag(dg), grad)
                except np.linalg.LinAlgError:
                    mu *= 10.0
                    continue
                length = float(np.hypot(*step[:2]))
                if length > lim:
                    step = step * (lim / length)
                trial = (xy + step[:2], z + step[3:], max(kd + float(step[2]), 0.0))
                with np.errstate(over="ignore", invalid="ignore"):  # an NDF that overflows costs inf: rejected
                    c = self.evaluate(ndf, trial[0], trial[1], trial[2], fresnel, cos_power, use=ev.use).cost
                    c += lam * trial[1] @ curv @ trial[1]
                if math.isfinite(c) and c < cost0:
                    xy, z, kd = trial
                    mu = max(mu / 10.0, 1e-9)
                    improved = True
                    break
                mu *= 10.0
            if improved:
                ev = self.evaluate(ndf, xy, z, kd, fresnel, cos_power, jacobian=True)
            if not improved or float(np.hypot(*step[:2])) < math.tan(math.radians(0.2 * CONVERGED_DEG)):
                break
        sd = self._covariance_sd(ev, a_mat, k) if a_mat is not None else math.inf
        rms = float(np.sqrt(np.sum(ev.w * ev.r ** 2) / max(np.sum(ev.w), 1e-300)))
        return ev.normal, sd, rms


@dataclasses.dataclass
class _TiltPass:
    """One pass of :func:`._normal_kernels.tilt_pass`: per sample the residual, the
    specular part, the θ_h cell and weight, the sample weight (0: not taking part),
    whether it takes part and the tilt's two Jacobian columns; the weighted cost."""

    r: Array
    spec: Array
    j: NDArray[np.intp]
    t: Array
    w: Array
    use: NDArray[np.bool_]
    dr: Array
    cost: float = math.nan
    normal: Array = dataclasses.field(default_factory=lambda: np.zeros(3))

    @classmethod
    def empty(cls, n: int, use: NDArray[np.bool_] | None) -> _TiltPass:
        return cls(np.empty(n), np.empty(n), np.empty(n, dtype=np.intp), np.empty(n), np.empty(n),
                   np.empty(n, dtype=bool) if use is None else use, np.empty((n, 2)))


def _tilt_normal(xy: Array) -> tuple[Array, Array]:
    """``n = normalize(t_x, t_y, 1)`` and ``∂n/∂t_q = (I − n nᵀ) e_q / |(t_x, t_y, 1)|``, shape (2, 3)."""
    u = np.array([float(xy[0]), float(xy[1]), 1.0])
    length = float(np.linalg.norm(u))
    n = u / length
    dn = (np.eye(3)[:2] - n[:2, None] * n[None, :]) / length
    return n, np.ascontiguousarray(dn)


def light_fit(slices, valid: NDArray[np.bool_], frame: Array, fixed_eta: float | None) -> isotropic.LuminanceFit:
    """A light isotropic luminance fit (every :data:`FIT_STRIDE`-th pixel, θ_d cells of
    :data:`FIT_TD_STEP`, :data:`FIT_OUTER_ITERATIONS` rounds of ``S`` from ``D``) in ``frame``, from the
    data's initial state each time: a start from the previous refit's state was
    measured worse (untilted captures given tilts of 0.5–2.4°, a rubber's normal off by
    2.1° instead of 0.15°) and no faster."""
    return _light_fit_of(*light_subset(slices, valid), frame, fixed_eta)


def light_subset(slices: Slices, valid: NDArray[np.bool_]) -> tuple[Slices, NDArray[np.bool_]]:
    """Every :data:`FIT_STRIDE`-th pixel of the slices (device frame) and of ``valid``,
    the samples of :func:`light_fit` (taken once per estimate, refitted in each frame)."""
    px = slice(0, None, FIT_STRIDE)  # a strided view, copied once (a gather of index arrays is 4× slower)

    def columns(a: NDArray[Any]) -> NDArray[Any]:
        # in C order once here: the compiled binning of every refit takes them so, not as copies of its own
        return np.ascontiguousarray(a[:, px])

    sub = dataclasses.replace(slices, view=np.ascontiguousarray(slices.view[px]), values=columns(slices.values),
                              valid=columns(slices.valid), pixels=np.ascontiguousarray(slices.pixels[px]),
                              censored=None if slices.censored is None else columns(slices.censored),
                              noise=None if slices.noise is None else columns(slices.noise),
                              limit=None if slices.limit is None else columns(slices.limit),
                              check_leds=(), check_values=None, check_valid=None)
    return sub, columns(valid)


def _light_fit_of(sub: Slices, valid_sub: NDArray[np.bool_], frame: Array,
                  fixed_eta: float | None) -> isotropic.LuminanceFit:
    """:func:`light_fit` on the samples :func:`light_subset` took."""
    sl = sub.reframe(frame)
    ok = valid_sub & sl.valid
    nodes = polar_nodes()
    bins = isotropic.bin_polar(sl, nodes, ok, FIT_TD_STEP)
    return isotropic.fit_luminance(bins, nodes, fixed_eta, outer_iterations=FIT_OUTER_ITERATIONS)


def _light_model(lum: isotropic.LuminanceFit) -> IsotropicMicrofacetBRDF:
    """The luminance model of a light fit: the ``D``, ``S``, ``η``, ``k_d``, ``k_s`` the tilt's steps hold."""
    nodes = lum.problem.nodes
    d = np.exp(lum.state.z - lum.state.z.max())
    return IsotropicMicrofacetBRDF((nodes, d), lum.state.kd, lum.ks, lum.state.eta)


@dataclasses.dataclass(frozen=True)
class HiddenPeak:
    """An LED whose specular peak the tilt hides: its slice reaches its mirror direction
    about the device axis, but in the sample frame its nearest half vector lies
    ``nearest_deg`` from the normal, beyond the fitted lobe's half width ``half_width_deg``
    (degrees); ``theta_d_deg`` is the peak's θ_d (the LED's incidence in the sample frame)."""

    led: int
    theta_d_deg: float
    nearest_deg: float
    half_width_deg: float


def hidden_peaks(slices: Slices, valid: NDArray[np.bool_], normal: Array, nodes: Array, values: Array,
                 pitch_deg: float | None = None) -> list[HiddenPeak]:
    """The LEDs whose specular peak the tilt to ``normal`` hides (:class:`HiddenPeak`).

    A hand-held tilt of a few tenths of a degree toward the view cone's rim moves a
    grazing LED's mirror direction out of view (the paper's layout: LED 2, θ_d ≈ 67°,
    within a degree of the rim; docs/design/normal.md). For a lobe narrower than the
    distance, the slice then holds no sample of the peak, and the lobe at that θ_d is
    extrapolated from the others. An LED counts when some usable sample's half vector
    ``h = (l + v)/|l + v|`` lies within the half-vector pitch of the device axis, and
    none within the lobe's half width (or the pitch) of ``normal``. ``slices`` and
    ``normal`` in the device frame, ``valid`` the usable samples ``(L, P)``, the fitted
    NDF's ``nodes`` (radians) and ``values``; ``pitch_deg`` the camera's half-vector
    pitch where known (:attr:`NormalEstimate.half_vector_pitch_deg`).
    """
    return peaks_out_of_reach(slices, valid, normal, nodes, values, pitch_deg)[0]


def peaks_out_of_reach(slices: Slices, valid: NDArray[np.bool_], normal: Array, nodes: Array, values: Array,
                       pitch_deg: float | None = None) -> tuple[list[HiddenPeak], list[int]]:
    """:func:`hidden_peaks` and :func:`peakless_leds` from one pass over the slices (arguments as there).

    Returns
    -------
    (list of HiddenPeak, list of int)
        The peaks the tilt hides, and the LEDs whose slice holds no sample of the peak.
    """
    pitch = half_vector_pitch_deg(slices) if pitch_deg is None or not math.isfinite(pitch_deg) else pitch_deg
    width = lobe_half_width_deg(nodes, values)
    reach = math.cos(math.radians(max(width, pitch)))
    seen = math.cos(math.radians(pitch))
    near, near_axis = _nearest_half_vectors(slices, valid, normal)
    peakless = [k for k in range(slices.n_leds) if valid[k].any() and near[k] < reach]
    # hidden: the untilted slice reached its mirror direction, the tilted one does not
    hidden = [HiddenPeak(k, math.degrees(math.acos(min(1.0, float(slices.light[k] @ normal)))),
                         math.degrees(math.acos(min(1.0, float(near[k])))), width)
              for k in peakless if near_axis[k] >= seen]
    return hidden, peakless


def _nearest_half_vectors(slices: Slices, valid: NDArray[np.bool_], normal: Array) -> tuple[Array, Array]:
    """Per LED, the largest cosine between a usable sample's half vector ``(l + v)/|l + v|`` and
    ``normal``, and the same about the device axis; −1 for an LED without a usable sample."""
    view = slices.view
    v_z, v_n = view[:, 2], view @ normal
    near, near_axis = np.full(slices.n_leds, -1.0), np.full(slices.n_leds, -1.0)
    for k in range(slices.n_leds):
        ok = valid[k]
        if not ok.any():
            continue
        light = slices.light[k]
        inv_length = 1.0 / np.sqrt(np.maximum(2.0 + 2.0 * (view @ light), 1e-300))  # |l + v| of unit vectors
        near_axis[k] = float(np.max(np.where(ok, (light[2] + v_z) * inv_length, -1.0)))
        near[k] = float(np.max(np.where(ok, (float(light @ normal) + v_n) * inv_length, -1.0)))
    return near, near_axis


def peakless_leds(slices: Slices, valid: NDArray[np.bool_], normal: Array, nodes: Array, values: Array,
                  pitch_deg: float | None = None) -> list[int]:
    """The LEDs whose slice holds no sample of the specular peak about ``normal``: no usable
    sample's half vector ``h = (l + v)/|l + v|`` lies within the fitted lobe's half width (or
    the half-vector pitch, where larger) of ``normal``. Such a slice sees only the lobe's
    flank or tail, where a mirror plane located from the data moves by degrees with
    hundredths of a degree of the normal (:func:`.motion.detect_motion`, ``flank_only``).
    A superset of :func:`hidden_peaks`' LEDs; arguments as there.

    Returns
    -------
    list of int
        The LEDs, in order.
    """
    return peaks_out_of_reach(slices, valid, normal, nodes, values, pitch_deg)[1]


def half_vector_pitch_deg(slices) -> float:
    """Half the median angle between horizontally adjacent pixels' view directions
    (degrees): how finely the camera samples the half vector of one LED's slice
    (≈ 0.21° on the default optics). The tilt is reported no better than this."""
    rows, cols, view = slices.pixels[:, 0], slices.pixels[:, 1], slices.view
    # the pixels of a capture's slices come in row-major order: sorted again (and gathered) only where not
    if not np.all((rows[1:] > rows[:-1]) | ((rows[1:] == rows[:-1]) & (cols[1:] > cols[:-1]))):
        order = np.lexsort((cols, rows))
        rows, cols, view = rows[order], cols[order], view[order]
    nxt = (rows[1:] == rows[:-1]) & (cols[1:] == cols[:-1] + 1)
    if not nxt.any():
        return 0.0
    # every neighbour's dot product, then the horizontal ones: no gathered copies of the directions
    cos = np.clip(np.einsum("ij,ij->i", view[:-1], view[1:])[nxt], -1.0, 1.0)
    return 0.5 * math.degrees(float(np.median(np.arccos(cos))))


def estimate_normal(slices, valid: NDArray[np.bool_], max_tilt_deg: float = 16.0,
                    fixed_eta: float | None = None, peaks: list[SlicePeak] | None = None) -> NormalEstimate:
    """The altered normal of one capture (module docstring): peak, then the tilt refined
    in the isotropic fit's least squares, with its cluster-robust (sandwich) uncertainty.

    ``slices`` in the device frame, ``valid`` the usable samples ``(L, P)``; tilts are
    held within ``max_tilt_deg`` of the device axis; ``peaks`` the slices' peaks where
    already found (:func:`slice_peaks`).
    """
    z = np.array([0.0, 0.0, 1.0])
    n0 = peak_normal(slices, valid, peaks)
    peak_tilt = math.nan if n0 is None else _angle_deg(n0, z)
    # a peak beyond the searched cone is not a start: a felt's or a paint's grazing sheen passes
    # for a peak 50–56° off (docs/design/normal.md); a start on the cone's edge lost such a
    # felt's normal (acrylic felt tilted 7.8°: 7.8° off)
    normal = z if n0 is None or peak_tilt > max_tilt_deg else n0
    limit = math.tan(math.radians(max_tilt_deg))
    problem = TiltProblem(slices, valid)
    sd = math.inf
    refits = 0
    moving = 0.0  # the last refit's move while the estimate has not converged (degrees)
    history: list[Array] = []  # tangent offsets of the normal before each refit
    subset = light_subset(slices, valid)
    for _ in range(MAX_REFITS):
        frame = geometry.frame_from_normal(normal, np.array([1.0, 0.0, 0.0]))
        try:
            lum = _light_fit_of(*subset, frame, fixed_eta)
        except ReflectoError:
            break
        model = _light_model(lum)
        refits += 1
        start = normal
        new, sd_new, _ = problem.solve(model, normal)
        if not (np.all(np.isfinite(new)) and new[2] > 0):  # a degenerate step: keep what we have
            break
        sd = sd_new if math.isfinite(sd_new) else math.inf
        xy = new[:2] / new[2]
        history.append(start[:2] / start[2])
        if _angle_deg(new, start) >= CONVERGED_DEG and len(history) >= 2:
            # the refits converge geometrically (the fit's D follows the frame it is fitted in):
            # extrapolate the sequence to its limit (vector Aitken) when its ratio is clear
            d1, d0 = xy - history[-1], history[-1] - history[-2]
            rho = float(d1 @ d0) / max(float(d0 @ d0), 1e-30)
            if (0.05 < rho < AITKEN_MAX_RATIO and float(np.hypot(*d1)) <= 1.5 * rho * float(np.hypot(*d0))
                    and float(np.hypot(*d0)) < math.tan(math.radians(AITKEN_MAX_STEP_DEG))):
                xy = xy + d1 * rho / (1.0 - rho)
        if float(np.hypot(*xy)) > limit:  # held within the searched cone
            xy = xy * limit / float(np.hypot(*xy))
        normal = tilt_frame(*xy)[2]
        moving = _angle_deg(normal, start)
        if moving < max(CONVERGED_DEG, CONVERGED_SHARE * sd):
            moving = 0.0
            break
    if refits and math.isfinite(sd) and np.all(np.isfinite(new)):
        # an estimate still moving after MAX_REFITS is not known better than its last move
        sd = math.hypot(sd, weighting_shift_deg(problem, model, new), moving)
    planes, fitted = 0, None
    width = lobe_half_width_deg(lum.problem.nodes, np.exp(lum.state.z)) if refits else math.nan
    if refits and symmetry.resolves_lobe(width):
        # not on a sharp lobe: there the fit's peak places the normal, the planes cannot (MIN_LOBE_TEXELS)
        fitted = normal
        normal, sd, planes = with_symmetry_planes(slices, valid, normal, sd, limit)
    pitch = half_vector_pitch_deg(slices)
    return NormalEstimate(normal, max(sd, pitch), "estimated", refits, _angle_deg(normal, z),
                          half_vector_pitch_deg=pitch, planes=planes, alternative=fitted if planes else None,
                          fit_uncertainty_deg=sd, lobe_half_width_deg=width,
                          misfit=lum.eps if refits else math.nan, peak_tilt_deg=peak_tilt)


def with_symmetry_planes(slices: Slices, valid: NDArray[np.bool_], normal: Array, sd_deg: float,
                         limit: float = math.inf) -> tuple[Array, float, int]:
    """The fit's normal combined with the one the slices' symmetry planes share.

    The fit's estimate assumes the 1-D microfacet model; where the model misfits (felts,
    fabrics, matte plastics) the misfit biases it. The symmetry planes
    (:func:`.symmetry.plane_normal`) assume only isotropy. Measured about ``normal``,
    their estimate ``δ_p`` (covariance ``C_p``) and the fit's (``0``, ``σ² I`` with
    ``σ`` = ``sd_deg``) are combined by their precisions,
    ``δ = (I/σ² + C_p⁻¹)⁻¹ C_p⁻¹ δ_p``, with the combined uncertainty the larger principal
    standard deviation of ``(I/σ² + C_p⁻¹)⁻¹``. :func:`estimate_normal` asks for it only
    where the view hemicube resolves the fitted lobe (:func:`.symmetry.resolves_lobe`):
    on a sharp lobe the fit's peak places the normal to hundredths of a degree, which
    the planes cannot. Returns the normal (device frame), its uncertainty
    (degrees) and how many planes entered (0: the planes gave no estimate).
    ``slices`` and ``normal`` in the device frame, ``valid`` (L, P); the tangent offset
    is held within ``limit`` (the tangent of the largest tilt searched).
    """
    frame = geometry.frame_from_normal(normal, np.array([1.0, 0.0, 0.0]))
    turned = slices.reframe(frame)
    planes = symmetry.plane_normal(turned.light, turned.view, turned.values, valid & turned.valid)
    if planes is None or not (sd_deg > 0.0):
        return normal, sd_deg, 0
    cue = np.linalg.inv(planes.covariance)
    info = cue + (np.eye(2) / math.radians(sd_deg) ** 2 if math.isfinite(sd_deg) else 0.0)
    cov = np.linalg.inv(info)
    d = cov @ cue @ planes.offset
    moved = normal + d[0] * frame[0] + d[1] * frame[1]
    moved /= np.linalg.norm(moved)
    xy = moved[:2] / moved[2]
    if not (moved[2] > 0 and np.all(np.isfinite(moved))):
        return normal, sd_deg, 0
    if float(np.hypot(*xy)) > limit:
        xy = xy * limit / float(np.hypot(*xy))
        moved = tilt_frame(*xy)[2]
    return moved, math.degrees(math.sqrt(float(np.linalg.eigvalsh(cov).max()))), planes.planes


def weighting_shift_deg(problem: TiltProblem, model, normal: Array) -> float:
    """How far the tilt's optimum moves when the samples are weighted alike instead of by
    eq. 10's ``(n·l)²`` (degrees, from ``normal``, the ``(n·l)²`` optimum, with the same model).

    Were the model right, any weighting would find the same normal up to the noise. On a
    material the 1-D model misfits (felts, fabrics, matte plastics) the misfit pulls the
    optimum, and by how much depends on where the weight lies: that shift is a bias the
    cluster-robust covariance does not see (all LEDs share it). Measured on the hand-held
    study's 100 steady as-built captures (the estimate before the device-axis decision):
    0.00–0.03° on the sharp lobes (their normals 0.00–0.08° off); 0.7–1.5° on acrylic felt
    and black-soft-plastic (0.4–3.2° off), 1.2° on green-fabric tilted (0.75° off); but
    0.2–0.3° on pink-felt (2.0–2.1° off) and 0.06° on ipswich-pine untilted (0.70° off):
    not every bias shows as a shift.
    """
    alt, _, _ = problem.solve(model, normal, cos_power=0.0)
    return _angle_deg(alt, normal) if np.all(np.isfinite(alt)) and alt[2] > 0 else 0.0
