"""LED layout design and coverage analysis (paper §4.1, Fig. 2(c)(d)).

A slice lit by LED ``l`` and seen over the view cone covers the half vectors
``h = normalize(l + o)`` for ``o`` in the cone. Equivalently, a hemicube texel ``h`` is
covered by ``l`` iff its mirror view ``o_h = R_h(l) = 2(l·h)h − l`` lies inside the
cone (and above the horizon, with a margin against grazing views). This is exact per
texel, without sampling pixels.

The symmetry of eq. 3, ``τ = diag(−1, −1, 1)``, maps the half vector of ``(i, o)`` to
that of ``(τi, τo)``; a texel is *covered after symmetry* if it or ``τh`` is covered.
The mirror planes of HLHZ08 (``M_t``, ``M_b``) are reported as well, for isotropic
and orthotropic materials.

The layout constraints (§4.1): ``l0`` at 5° elevation at the condenser's azimuth; no
LED below 5° elevation; no LED inside the view cone widened by a 5° margin for the
LED's tube (it would shadow the light path between the condensers). A cone wider or
more tilted than the paper's (``cone + tilt > 80°``) takes that azimuth into the tube
margin; ``l0`` then sits at the nearest azimuth that clears it (:func:`first_led`).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import differential_evolution

from .. import geometry
from ..errors import ParameterError
from ..hemicube import Hemicube, hemicube
from .optics import Optics

Array = NDArray[np.float64]

#: Smallest LED elevation (mechanical limit of the paper's device), degrees.
MIN_ELEVATION_DEG = 5.0
#: Margin around the view cone kept free for the LED tubes, degrees.
TUBE_MARGIN_DEG = 5.0
#: Views more grazing than this are not used (algorithm-reference §4.2: o·n ≤ 0.05).
MIN_VIEW_COS = 0.05


def led_direction(elevation_deg: ArrayLike, azimuth_deg: ArrayLike) -> Array:
    """Unit LED direction(s) ``(cos el cos az, cos el sin az, sin el)``.

    Parameters
    ----------
    elevation_deg : array_like
        Elevation above the sample plane, degrees.
    azimuth_deg : array_like
        Azimuth from +x, degrees; broadcast against ``elevation_deg``.

    Returns
    -------
    ndarray, shape (..., 3)
        Unit directions in the device frame.
    """
    el = np.radians(np.asarray(elevation_deg, dtype=np.float64))
    az = np.radians(np.asarray(azimuth_deg, dtype=np.float64))
    return np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=-1)


def led_angles(dirs: ArrayLike) -> Array:
    """Inverse of :func:`led_direction`.

    Parameters
    ----------
    dirs : array_like, shape (..., 3)
        Directions (normalized here).

    Returns
    -------
    ndarray, shape (..., 2)
        ``(elevation, azimuth)`` in degrees, azimuth in [0, 360).
    """
    d = geometry.normalize(dirs)
    el = np.degrees(np.arcsin(np.clip(d[..., 2], -1.0, 1.0)))
    az = np.degrees(np.arctan2(d[..., 1], d[..., 0])) % 360.0
    return np.stack([el, az], axis=-1)


def first_led(optics: Optics) -> Array:
    """``l0``: 5° above the horizon, at the azimuth nearest the condenser's that clears
    the view cone + tube margin, shape ``(3,)``.

    For the paper's optics (and any with ``cone + tilt ≤ 80°``) that is the condenser's
    azimuth itself (§4.1). For a wider or more tilted cone, the LED at 85° from the
    normal in the condenser's azimuth would sit in the light path; the angle ``γ`` of
    an 85° LED at azimuth offset ``φ`` from the axis obeys
    ``cos γ = sin t sin 85° cos φ + cos t cos 85°``, so ``γ ≥ cone + margin`` first holds
    at ``cos φ = (cos(cone + margin) − cos t cos 85°) / (sin t sin 85°)``.

    Parameters
    ----------
    optics
        The condenser optics (axis tilt, azimuth and cone).

    Returns
    -------
    ndarray, shape (3,)
        The unit direction of ``l0`` in the device frame.
    """
    el = math.radians(MIN_ELEVATION_DEG)
    t = math.radians(optics.axis_tilt_deg)
    limit = math.cos(math.radians(optics.cone_half_angle_deg + TUBE_MARGIN_DEG))
    offset = 0.0
    if math.sin(t) * math.cos(el) + math.cos(t) * math.sin(el) > limit and math.sin(t) > 0:
        c = (limit - math.cos(t) * math.sin(el)) / (math.sin(t) * math.cos(el))
        # a hair beyond the boundary, so that the constraint check (with its 1e-12) passes
        offset = math.degrees(math.acos(max(-1.0, min(1.0, c)))) + 1e-6
    return led_direction(MIN_ELEVATION_DEG, optics.axis_azimuth_deg + offset)


def layout_violations(optics: Optics, leds: ArrayLike, occluder_deg: float = 0.0) -> list[str]:
    """The §4.1 constraints a layout breaks, in words (empty if none).

    LEDs inside a declared central occluder (``occluder_deg`` around the axis, whose
    views the device gives up) are allowed there.

    Parameters
    ----------
    optics
        The condenser optics.
    leds : array_like, shape (L, 3)
        LED directions (normalized here).
    occluder_deg
        Half angle of a central occluder, degrees (0: none).

    Returns
    -------
    list of str
        One sentence per broken constraint (elevation below 5°, inside the view cone
        plus the tube margin).
    """
    leds = geometry.normalize(np.atleast_2d(leds))
    out = []
    limit = math.cos(math.radians(optics.cone_half_angle_deg + TUBE_MARGIN_DEG))
    in_occ = math.cos(math.radians(occluder_deg)) if occluder_deg > 0 else 2.0
    for k, (el, _az) in enumerate(led_angles(leds)):
        if leds[k] @ optics.axis >= in_occ:
            continue
        if el < MIN_ELEVATION_DEG - 1e-9:
            out.append(f"LED {k} at {el:.1f}° elevation is below {MIN_ELEVATION_DEG}°")
        if leds[k] @ optics.axis > limit + 1e-12:
            ang = math.degrees(math.acos(min(1.0, float(leds[k] @ optics.axis))))
            out.append(
                f"LED {k} is {ang:.1f}° from the optical axis, inside the view cone + "
                f"{TUBE_MARGIN_DEG}° margin ({optics.cone_half_angle_deg + TUBE_MARGIN_DEG:.1f}°)"
            )
    return out


def coverage_masks(optics: Optics, leds: ArrayLike, cube: Hemicube, occluder_deg: float = 0.0) -> NDArray[np.bool_]:
    """Texels of ``cube`` whose half vector each LED's slice observes.

    Parameters
    ----------
    optics
        The condenser optics (view cone).
    leds : array_like, shape (L, 3)
        LED directions.
    cube
        The hemicube of half vectors.
    occluder_deg
        Half angle of a central occluder about the optical axis, degrees (0: none): the
        views within it carry no data.

    Returns
    -------
    ndarray of bool, shape (L, cube.size)
        True where the mirror view ``R_h(l)`` lies in the view cone, outside the occluder,
        above the grazing limit.
    """
    leds = geometry.normalize(np.atleast_2d(leds))
    h = cube.directions
    lh = leds @ h.T  # (L, T)
    o = 2.0 * lh[..., None] * h[None] - leds[:, None, :]  # mirror views (L, T, 3)
    cos_axis = o @ optics.axis
    in_cone = cos_axis >= math.cos(math.radians(optics.cone_half_angle_deg))
    if occluder_deg > 0:
        in_cone &= cos_axis <= math.cos(math.radians(occluder_deg))
    return in_cone & (o[..., 2] > MIN_VIEW_COS) & (lh > 0)


@dataclasses.dataclass
class Coverage:
    """Coverage numbers of a layout, as solid-angle fractions of the NDF cap θ_h ≤ θ_max.

    Attributes
    ----------
    per_led
        Fraction each LED's slice covers, shape ``(L,)``.
    union
        Fraction covered by at least one slice.
    after_tau
        Fraction covered after completion by eq. 3 (h or τh covered).
    after_mirrors
        Fraction after the full group {1, M_t, M_b, τ} (orthotropic materials).
    overlap
        ``overlap[a, b]``: fraction covered by both slices a and b.
    theta_d_spread_deg
        Mean ``|θ_d(a) − θ_d(b)|`` over each overlap (degrees; NaN without overlap);
        Fresnel estimation (§5.1) needs pairs at different θ_d.
    upper_bound_after_tau
        What any number of LEDs obeying the constraints could cover after τ.
    """

    theta_max_deg: float
    per_led: Array
    union: float
    after_tau: float
    after_mirrors: float
    overlap: Array
    theta_d_spread_deg: Array
    upper_bound_after_tau: float
    masks: NDArray[np.bool_] = dataclasses.field(repr=False)

    @property
    def every_led_overlaps(self) -> bool:
        """Whether every LED's slice shares some half vectors with another LED's (needed for η, §5.1)."""
        off = self.overlap.copy()
        np.fill_diagonal(off, 0.0)
        return bool(np.all(off.max(axis=1) > 0))

    def to_dict(self) -> dict[str, Any]:
        """The coverage numbers as JSON-ready data.

        Returns
        -------
        dict
            Fractions rounded to 4 digits, the overlap matrix and the θ_d spreads (degrees,
            NaN as 0); no masks.
        """
        return {
            "theta_max_deg": self.theta_max_deg,
            "per_led": [round(float(x), 4) for x in self.per_led],
            "union": round(self.union, 4),
            "after_tau": round(self.after_tau, 4),
            "after_mirrors": round(self.after_mirrors, 4),
            "upper_bound_after_tau": round(self.upper_bound_after_tau, 4),
            "every_led_overlaps": self.every_led_overlaps,
            "overlap": np.round(self.overlap, 4).tolist(),
            "theta_d_spread_deg": np.round(np.nan_to_num(self.theta_d_spread_deg), 2).tolist(),
        }


def reachable_mask(optics: Optics, cube: Hemicube, n_views: int = 4000) -> NDArray[np.bool_]:
    """Texels that *some* LED obeying the §4.1 constraints could cover.

    ``h`` is reachable iff a view ``o`` in the cone exists whose mirror ``R_h(o)`` is a
    legal LED direction. Views are a deterministic Fibonacci set over the cone. The
    result depends on the optics' geometry alone and is cached per geometry (≈ 5 s at
    N = 64; the design study asks for it once per layout).

    Parameters
    ----------
    optics
        The condenser optics.
    cube
        The hemicube of half vectors.
    n_views
        Views sampled over the cone.

    Returns
    -------
    ndarray of bool, shape (cube.size,)
        The reachable texels (a copy of the cached mask).
    """
    key = (optics.axis_tilt_deg, optics.axis_azimuth_deg, optics.cone_half_angle_deg, optics.roll_deg)
    return _reachable(key, cube.n, n_views).copy()


@functools.lru_cache(maxsize=64)
def _reachable(key: tuple[float, float, float, float], n: int, n_views: int) -> NDArray[np.bool_]:
    tilt, azimuth, cone, roll = key
    optics = Optics(axis_tilt_deg=tilt, axis_azimuth_deg=azimuth, cone_half_angle_deg=cone, roll_deg=roll)
    cube = hemicube(n)
    k = np.arange(n_views) + 0.5
    cos_max = math.cos(math.radians(optics.cone_half_angle_deg))
    ct = 1.0 - (1.0 - cos_max) * k / n_views
    st = np.sqrt(1.0 - ct * ct)
    ph = k * math.pi * (3.0 - math.sqrt(5.0))
    o = np.stack([st * np.cos(ph), st * np.sin(ph), ct], -1) @ optics.axis_frame
    o = o[o[:, 2] > MIN_VIEW_COS]
    sin_el = math.sin(math.radians(MIN_ELEVATION_DEG))
    cos_tube = math.cos(math.radians(optics.cone_half_angle_deg + TUBE_MARGIN_DEG))
    out = np.zeros(cube.size, dtype=bool)
    h = cube.directions
    for s in range(0, cube.size, 256):
        hh = h[s : s + 256]
        i = 2.0 * (o @ hh.T)[..., None] * hh[None] - o[:, None]
        ok = (i[..., 2] >= sin_el) & (i @ optics.axis <= cos_tube)
        out[s : s + 256] = ok.any(axis=0)
    return out


#: Largest seed of the layout optimizer (scipy's differential evolution takes 32-bit seeds).
MAX_SEED = 2**32 - 1


def _check_theta_max(theta_max_deg: float) -> None:
    """Refuse an NDF cap that is empty (θ_max ≤ 0: every fraction would be 0/0) or not a cap of the
    hemisphere (beyond 90°, or NaN, which would print ``nan %``)."""
    if not 0.0 < theta_max_deg <= 90.0:  # NaN compares false: refused too
        raise ParameterError(f"theta_max must be in (0°, 90°], got {theta_max_deg}")


def coverage(optics: Optics, leds: ArrayLike, resolution: int = 64, theta_max_deg: float = 80.0,
             occluder_deg: float = 0.0) -> Coverage:
    """Coverage analysis of a layout on a ``resolution`` hemicube (§4.1, Figure 2c–d).

    Parameters
    ----------
    optics
        The condenser optics.
    leds : array_like, shape (L, 3)
        LED directions in the device frame.
    resolution
        Hemicube resolution of the analysis.
    theta_max_deg
        The NDF cap θ_h ≤ θ_max whose solid angle the fractions refer to, degrees.
    occluder_deg
        Half angle of a central occluder, degrees (0: none; :func:`coverage_masks`).

    Returns
    -------
    Coverage
        Per-LED, union, after-τ (eq. 3) and after-mirrors fractions, the pairwise
        overlaps and θ_d spreads, the reachable upper bound and the masks.

    Raises
    ------
    ParameterError
        For ``theta_max_deg`` outside (0°, 90°].
    """
    _check_theta_max(theta_max_deg)
    cube = hemicube(resolution)
    leds = geometry.normalize(np.atleast_2d(leds))
    masks = coverage_masks(optics, leds, cube, occluder_deg)
    cap = cube.directions[:, 2] >= math.cos(math.radians(theta_max_deg))
    w = np.where(cap, cube.solid_angles, 0.0)
    total = w.sum()
    if not total > 0:
        raise ParameterError(f"coverage: the cap θ_h ≤ {theta_max_deg:g}° holds no texel centre of a hemicube of "
                             f"resolution {cube.n}: a larger cap or a finer hemicube")
    frac = lambda m: float(w[m].sum() / total)  # noqa: E731
    union = masks.any(axis=0)
    assert isinstance(union, np.ndarray)  # masks is (leds, texels): any over axis 0 is an array
    tau = cube.permutation(geometry.TAU)
    after_tau = union | union[tau]
    mirrors = after_tau | union[cube.permutation(geometry.MIRROR_T)] | union[cube.permutation(geometry.MIRROR_B)]
    n = len(leds)
    overlap = np.zeros((n, n))
    spread = np.full((n, n), np.nan)
    theta_d = np.degrees(np.arccos(np.clip(leds @ cube.directions.T, -1, 1)))  # (L, T)
    for a in range(n):
        for b in range(n):
            both = masks[a] & masks[b]
            overlap[a, b] = frac(both)
            if a != b and both.any():
                ww = w[both]
                spread[a, b] = float(np.sum(np.abs(theta_d[a, both] - theta_d[b, both]) * ww) / max(ww.sum(), 1e-300))
    reach = reachable_mask(optics, cube)
    return Coverage(
        theta_max_deg=theta_max_deg,
        per_led=np.array([frac(m) for m in masks]),
        union=frac(union),
        after_tau=frac(after_tau),
        after_mirrors=frac(mirrors),
        overlap=overlap,
        theta_d_spread_deg=spread,
        upper_bound_after_tau=frac(reach | reach[tau]),
        masks=masks,
    )


def layout_terms(optics: Optics, leds: ArrayLike, cube: Hemicube,
                 theta_max_deg: float = 80.0) -> tuple[float, float, float]:
    """The three goals of the layout design, each a solid-angle fraction in [0, 1].

    * ``coverage``: the θ_h ≤ θ_max cap covered after eq. 3;
    * ``central``: the cap θ_h ≤ 10° seen (directly or through τ) by slices whose
      θ_d differ by ≥ 10° — the overlaps that make η identifiable for sharp lobes (§5.1);
    * ``small_theta_d``: the cap where some slice sees θ_d ≤ 25° — near-normal
      incidence, which carries most of the weight of the eq. 10 error and which the
      model otherwise reaches only by extrapolating F and S.

    Parameters
    ----------
    optics
        The condenser optics.
    leds : array_like, shape (L, 3)
        LED directions.
    cube
        The hemicube the fractions are computed on.
    theta_max_deg
        θ_max of the coverage cap, degrees.

    Returns
    -------
    tuple of float
        ``(coverage, central, small_theta_d)``.
    """
    leds = geometry.normalize(np.atleast_2d(leds))
    h = cube.directions
    cap = h[:, 2] >= math.cos(math.radians(theta_max_deg))
    w = np.where(cap, cube.solid_angles, 0.0)
    w /= w.sum()
    central = h[:, 2] >= math.cos(math.radians(10.0))
    wc = np.where(central, cube.solid_angles, 0.0)
    wc /= wc.sum()
    tau = cube.permutation(geometry.TAU)
    m = coverage_masks(optics, leds, cube)
    u = m.any(axis=0)
    assert isinstance(u, np.ndarray)  # m is (leds, texels): any over axis 0 is an array
    cov = float(w[u | u[tau]].sum())
    td = np.degrees(np.arccos(np.clip(leds @ h.T, -1.0, 1.0)))
    seen = m | m[:, tau]
    td_seen = np.where(m, td, td[:, tau])
    lo = np.where(seen, td_seen, np.inf).min(axis=0)
    hi = np.where(seen, td_seen, -np.inf).max(axis=0)
    return cov, float(wc[(hi - lo) >= 10.0].sum()), float(w[lo <= 25.0].sum())


#: Weights of :func:`layout_terms` in the layout objective.
LAYOUT_WEIGHTS = (1.0, 0.3, 0.3)
#: The design study's weights (:mod:`reflecto.evaluate.design`): the three goals of
#: :data:`LAYOUT_WEIGHTS` and a fourth, the θ_d reach at the specular peak
#: (:func:`objective_terms`), which the paper's cone cannot extend (its views end at
#: θ_o = 68.2°) and where measured materials carry most of eq. 10's error.
DESIGN_WEIGHTS = (1.0, 0.3, 0.3, 0.3)
#: Half-angle (degrees) of the central cap of goal 2.
CENTRAL_CAP_DEG = 10.0
#: θ_d (degrees) at which the peak's reach counts in full (goal 4): eq. 10's grazing cut.
PEAK_REACH_FULL_DEG = 80.0


@njit(cache=True, nogil=True)
def _terms_kernel(leds, h, tau, w, wc, axis, cos_cone, min_view, out):  # pragma: no cover - compiled
    """The first three goals of :func:`objective_terms` in one pass over the texels.

    ``leds`` (L, 3) unit; ``h`` (T, 3) texel directions; ``tau`` (T,) the permutation
    of eq. 3; ``w``/``wc`` (T,) the cap's and the central cap's normalized weights;
    ``out`` (3,) receives coverage, central, small θ_d (as :func:`layout_terms`).
    """
    n_led = leds.shape[0]
    n_tex = h.shape[0]
    seen = np.zeros((n_led, n_tex), dtype=np.bool_)
    td = np.empty((n_led, n_tex))
    for k in range(n_led):
        la = leds[k, 0] * axis[0] + leds[k, 1] * axis[1] + leds[k, 2] * axis[2]
        for j in range(n_tex):
            lh = leds[k, 0] * h[j, 0] + leds[k, 1] * h[j, 1] + leds[k, 2] * h[j, 2]
            td[k, j] = math.degrees(math.acos(min(1.0, max(-1.0, lh))))
            if lh <= 0.0:
                continue
            oa = 2.0 * lh * (h[j, 0] * axis[0] + h[j, 1] * axis[1] + h[j, 2] * axis[2]) - la
            oz = 2.0 * lh * h[j, 2] - leds[k, 2]
            seen[k, j] = oa >= cos_cone and oz > min_view
    cov = 0.0
    central = 0.0
    small = 0.0
    for j in range(n_tex):
        t = tau[j]
        lo = np.inf
        hi = -np.inf
        union = False
        for k in range(n_led):
            if seen[k, j] or seen[k, t]:
                union = True
                d = td[k, j] if seen[k, j] else td[k, t]
                lo = min(lo, d)
                hi = max(hi, d)
        if union:
            cov += w[j]
            if hi - lo >= 10.0:
                central += wc[j]
            if lo <= 25.0:
                small += w[j]
    out[0] = cov
    out[1] = central
    out[2] = small


class LayoutObjective:
    """The goals of a layout on one hemicube, precomputed for fast repeated evaluation.

    The optimizer evaluates tens of thousands of layouts per design; the texel
    directions, the weights and the permutation of eq. 3 are fixed, and one compiled
    pass gives all goals (≈ 0.2 ms at N = 32 for six LEDs).
    """

    def __init__(self, optics: Optics, cube: Hemicube, theta_max_deg: float = 80.0) -> None:
        h = cube.directions
        cap = h[:, 2] >= math.cos(math.radians(theta_max_deg))
        w = np.where(cap, cube.solid_angles, 0.0)
        central = h[:, 2] >= math.cos(math.radians(CENTRAL_CAP_DEG))
        wc = np.where(central, cube.solid_angles, 0.0)
        self.h = np.ascontiguousarray(h, dtype=np.float64)
        self.tau = np.ascontiguousarray(cube.permutation(geometry.TAU), dtype=np.int64)
        self.w = w / w.sum()
        self.wc = wc / wc.sum()
        self.optics = optics
        self.axis = np.ascontiguousarray(optics.axis, dtype=np.float64)
        self.cos_cone = math.cos(math.radians(optics.cone_half_angle_deg))

    def terms(self, leds: ArrayLike) -> tuple[float, float, float, float]:
        """The four goals of a layout, see :func:`objective_terms`.

        Parameters
        ----------
        leds : array_like, shape (L, 3)
            LED directions (normalized here).

        Returns
        -------
        tuple of float
            ``(coverage, central, small_theta_d, peak_reach)``, each in [0, 1].
        """
        leds = np.ascontiguousarray(geometry.normalize(np.atleast_2d(leds)), dtype=np.float64)
        out = np.empty(3)
        _terms_kernel(leds, self.h, self.tau, self.w, self.wc, self.axis, self.cos_cone, MIN_VIEW_COS, out)
        peak = peak_theta_d(self.optics, leds)
        reach = min(1.0, float(peak[-1]) / PEAK_REACH_FULL_DEG) if len(peak) else 0.0
        return float(out[0]), float(out[1]), float(out[2]), reach


def objective_terms(optics: Optics, leds: ArrayLike, cube: Hemicube,
                    theta_max_deg: float = 80.0) -> tuple[float, float, float, float]:
    """The three goals of :func:`layout_terms` and a fourth, each in [0, 1]:

    * ``peak_reach``: the largest θ_d at which some slice sees the specular peak
      ``h = n`` (:func:`peak_theta_d`) over :data:`PEAK_REACH_FULL_DEG`, at most 1.
      Beyond the reach the model extrapolates F and S, and the Fresnel and shadowing
      of measured materials depart most from any curve extrapolated from smaller θ_d.
      The term is continuous in the LED positions (unlike a share of texels).

    Parameters
    ----------
    optics
        The condenser optics.
    leds : array_like, shape (L, 3)
        LED directions.
    cube
        The hemicube the fractions are computed on.
    theta_max_deg
        θ_max of the coverage cap, degrees.

    Returns
    -------
    tuple of float
        ``(coverage, central, small_theta_d, peak_reach)``.
    """
    return LayoutObjective(optics, cube, theta_max_deg).terms(leds)


def _mirror_views_in_view(optics: Optics, leds: Array, normals: Array, occluder_deg: float) -> NDArray[np.bool_]:
    """Whether each LED's mirror view ``o = 2(l·n)n − l`` about each normal lies in the view
    cone (outside an occluder) and above the grazing limit of that normal, shape ``(M, L)``."""
    ln = normals @ leds.T  # (M, L)
    o = 2.0 * ln[..., None] * normals[:, None, :] - leds[None, :, :]
    cos_axis = o @ optics.axis
    ok = (cos_axis >= math.cos(math.radians(optics.cone_half_angle_deg))) & (ln > MIN_VIEW_COS)
    if occluder_deg > 0:
        ok &= cos_axis <= math.cos(math.radians(occluder_deg))
    return ok


def peak_theta_d(optics: Optics, leds: ArrayLike, occluder_deg: float = 0.0) -> Array:
    """θ_d (degrees, sorted) at which the slices see the half vector ``h = n``, shape ``(k,)``.

    ``h = n`` is seen by LED ``l`` where its mirror view ``(−l_x, −l_y, l_z)`` lies in
    the view cone (outside an occluder) and above the grazing limit; there
    ``θ_d = θ_l``. The largest value is the design's *θ_d reach at the specular peak*.

    Parameters
    ----------
    optics
        The condenser optics.
    leds : array_like, shape (L, 3)
        LED directions.
    occluder_deg
        Half angle of a central occluder, degrees (0: none).

    Returns
    -------
    ndarray, shape (k,)
        θ_d in degrees, ascending, for the ``k`` LEDs that see ``h = n``.
    """
    dirs = geometry.normalize(np.atleast_2d(np.asarray(leds, dtype=np.float64)))
    ok = _mirror_views_in_view(optics, dirs, np.array([[0.0, 0.0, 1.0]]), occluder_deg)[0]
    return np.sort(np.degrees(np.arccos(np.clip(dirs[ok, 2], -1.0, 1.0))))


def peak_margins_deg(optics: Optics, leds: ArrayLike) -> Array:
    """A lower bound (degrees) of the tilt that hides each specular peak the layout sees.

    LED ``l`` sees its peak where its mirror view ``o = (−l_x, −l_y, l_z)`` lies in the
    view cone and above the grazing limit (:func:`peak_theta_d`); a tilt ``δ`` of the
    normal turns ``o`` by at most ``2δ``, so the peak stays in view while ``2δ`` is below
    the angle from ``o`` to the cone's rim and to the grazing limit. Shape ``(k,)`` for the
    ``k`` LEDs that see their peak (:func:`tilt_margin_deg` gives the exact minimum).

    Parameters
    ----------
    optics
        The condenser optics.
    leds : array_like, shape (L, 3)
        LED directions.

    Returns
    -------
    ndarray, shape (k,)
        Half the angular distance of each seen mirror view to the edge of the view, degrees.
    """
    dirs = geometry.normalize(np.atleast_2d(np.asarray(leds, dtype=np.float64)))
    o = dirs * np.array([-1.0, -1.0, 1.0])
    from_axis = np.degrees(np.arccos(np.clip(o @ optics.axis, -1.0, 1.0)))
    above = np.degrees(np.arcsin(np.clip(o[:, 2], -1.0, 1.0))) - math.degrees(math.asin(MIN_VIEW_COS))
    seen = (from_axis <= optics.cone_half_angle_deg) & (above > 0)
    return 0.5 * np.minimum(optics.cone_half_angle_deg - from_axis[seen], above[seen])


def tilt_margin_deg(optics: Optics, leds: ArrayLike, occluder_deg: float = 0.0, max_tilt_deg: float = 15.0,
                    n_azimuths: int = 360) -> float:
    """The smallest hand tilt (degrees) that takes a specular peak the layout sees out of view.

    The peaks of :func:`peak_theta_d` are seen where LED ``l``'s mirror view about the
    normal, ``o = 2(l·n)n − l``, lies in the view cone; tilting ``n`` by ``δ`` turns ``o``
    by up to ``2δ`` (exactly ``2δ`` within the plane of incidence), so a peak seen near the
    rim of the cone is lost at small tilts, and the slice then holds only the lobe's flank
    (docs/design/normal.md). For each LED that sees its peak untilted, the smallest tilt
    over ``n_azimuths`` directions (bisection to 0.001°) at which its mirror view leaves
    the cone, the occluder or the grazing limit; the minimum over those LEDs.

    Parameters
    ----------
    optics
        The condenser optics.
    leds : array_like, shape (L, 3)
        LED directions.
    occluder_deg
        Half angle of a central occluder, degrees (0: none).
    max_tilt_deg
        The largest tilt searched, degrees.
    n_azimuths
        Directions of tilt searched (evenly over 360°).

    Returns
    -------
    float
        The margin in degrees; ``inf`` when no LED sees a peak, ``max_tilt_deg`` when
        none is lost below it.
    """
    dirs = geometry.normalize(np.atleast_2d(np.asarray(leds, dtype=np.float64)))
    z = np.array([[0.0, 0.0, 1.0]])
    seen = _mirror_views_in_view(optics, dirs, z, occluder_deg)[0]
    if not seen.any():
        return math.inf
    dirs = dirs[seen]
    psi = np.arange(n_azimuths) * (2.0 * math.pi / n_azimuths)

    def normals(tilt: Array) -> Array:
        t = np.radians(tilt)
        return np.stack([np.sin(t) * np.cos(psi), np.sin(t) * np.sin(psi), np.cos(t)], axis=-1)

    lo = np.zeros((n_azimuths, len(dirs)))  # in view at lo, not at hi (where hi < max)
    hi = np.full((n_azimuths, len(dirs)), float(max_tilt_deg))
    for _ in range(int(math.ceil(math.log2(max_tilt_deg / 1e-3)))):
        mid = 0.5 * (lo + hi)
        inside = np.stack([_mirror_views_in_view(optics, dirs[k:k + 1], normals(mid[:, k]), occluder_deg)[:, 0]
                           for k in range(len(dirs))], axis=1)
        lo = np.where(inside, mid, lo)
        hi = np.where(inside, hi, mid)
    return float(hi.min())


def optimize_layout(
    optics: Optics,
    n_leds: int = 6,
    resolution: int = 32,
    theta_max_deg: float = 80.0,
    min_separation_deg: float = 12.0,
    seed: int = 0,
    maxiter: int = 80,
    weights: tuple[float, ...] = LAYOUT_WEIGHTS,
    min_tilt_margin_deg: float = 0.0,
) -> Array:
    """Place the free LEDs (paper §4.1) for coverage, central overlaps and small θ_d.

    ``l0`` is fixed at 5° elevation in the condenser's azimuth (or the nearest azimuth
    that clears the view cone, :func:`first_led`). The other ``n_leds − 1``
    LEDs (elevation, azimuth) are chosen by differential evolution (deterministic for
    a seed) maximising the weighted sum of the goals of :func:`objective_terms`
    (``weights``: three for :func:`layout_terms`' goals, :data:`LAYOUT_WEIGHTS`; a
    fourth weighs the θ_d reach at the peak, :data:`DESIGN_WEIGHTS`); layouts that break the
    §4.1 constraints or put two LEDs closer than ``min_separation_deg`` are penalised
    beyond any gain.

    Pure coverage (weights 1, 0, 0) puts five LEDs near the horizon: 84.6 % after
    eq. 3, but η is then unidentifiable for sharp lobes (no central overlap) and
    near-normal incidence is never measured; the default weights trade 4 points of
    coverage for both (docs/instrument.md).

    Parameters
    ----------
    optics
        The condenser optics.
    n_leds
        Number of LEDs, ``l0`` included.
    resolution
        Hemicube resolution of the goals.
    theta_max_deg
        θ_max of the coverage cap, degrees.
    min_separation_deg
        Smallest angle between two LEDs, degrees.
    seed
        Seed of the differential evolution.
    maxiter
        Its generations.
    weights
        Three or four weights of the goals.
    min_tilt_margin_deg
        For hand-held use: every specular peak the layout sees stays in view under tilts
        up to this (degrees; :func:`tilt_margin_deg`), enforced through its lower bound
        :func:`peak_margins_deg` and penalised beyond any gain; 0: no constraint.

    Returns
    -------
    ndarray, shape (n_leds, 3)
        LED directions in the device frame, ``l0`` first.

    Raises
    ------
    ValueError
        For a ``weights`` of another length.
    ParameterError
        For ``theta_max_deg`` outside (0°, 90°] or a seed outside [0, :data:`MAX_SEED`].
    """

    if not 3 <= len(weights) <= 4:
        raise ValueError("optimize_layout: weights must list 3 or 4 numbers")
    _check_theta_max(theta_max_deg)
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= seed <= MAX_SEED:
        raise ParameterError(f"seed must be an integer in [0, {MAX_SEED}], got {seed}")
    wts = np.zeros(4)
    wts[: len(weights)] = weights
    goals = LayoutObjective(optics, hemicube(resolution), theta_max_deg)
    l0 = first_led(optics)
    cos_sep = math.cos(math.radians(min_separation_deg))

    def unpack(x: Array) -> Array:
        return np.concatenate([l0[None], led_direction(x[0::2], x[1::2])])

    def objective(x: Array) -> float:
        leds = unpack(x)
        penalty = 2.0 * len(layout_violations(optics, leds))
        g = leds @ leds.T
        np.fill_diagonal(g, -1.0)
        penalty += 2.0 * float(np.sum(g > cos_sep)) / 2
        if min_tilt_margin_deg > 0:
            penalty += 2.0 * float(np.sum(peak_margins_deg(optics, leds) < min_tilt_margin_deg))
        return -(float(wts @ np.array(goals.terms(leds))) - penalty)

    bounds = [(MIN_ELEVATION_DEG, 80.0), (0.0, 360.0)] * (n_leds - 1)
    res = differential_evolution(objective, bounds, seed=seed, maxiter=maxiter, popsize=20, tol=1e-8, polish=False)
    return unpack(res.x)
