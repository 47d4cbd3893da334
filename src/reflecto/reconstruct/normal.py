"""Altered-normal estimation (paper §5.4, after HLHZ08; algorithm-reference §5.2–5.3).

:class:`ConsistencyDistance` is the symmetry criterion of HLHZ08 with the full model: for a candidate normal the slices are
re-expressed in its frame and binned, and the distance is E(η) of §5.1 — how badly
partial NDFs of overlapping and τ-mirrored bins disagree once S, F and k_d are
divided out (η and k_d fitted per candidate). The sample's true frame is the only
one in which the τ-symmetry of the NDF and the direct overlaps hold at once. It is
sharp (on an ideal capture E falls from ≈ 0.6 at 6° off to ≈ 0.01 at the truth).

HLHZ08's plain form — ``log D̂`` with ``S = F = 1`` compared between ``h`` and ``τh`` —
finds 3–6° tilts on untilted captures: the unequal S and F of the
two samples (different θ_i, θ_d) bias it, which the full-model form divides out. As
the paper says, only the reflection across the normal (τ) is used, applied through
the dense views.

The minimum is found on a grid of tilts (every ``step_deg`` up to ``max_tilt_deg``) of
a cheap coarse distance; its lowest local minima are refined on the coarse distance
and the best of them by Nelder–Mead on the fine one.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import minimize

from .. import geometry
from ..errors import ReflectoError
from ..hemicube import hemicube
from .fresnel_fit import fit_fresnel, overlap_pairs
from .samples import bin_samples, kd_bound

Array = NDArray[np.float64]

#: LEDs less than this far above a candidate frame's horizon (degrees) take no part in
#: its :class:`IsotropicDistance`: a frame that sank the worst-fitting grazing LEDs
#: would otherwise win by fitting fewer data (specular maroon phenolic tilted 5°:
#: 7.8° off), and counting their samples as lost biases the tilt of captures whose
#: LEDs truly sink (GGX α = 0.1 at 10°: found 8.97°).
LED_MARGIN_DEG = 10.0
#: Minimum number of texel pairs for a candidate to count.
MIN_PAIRS = 40


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
        self.slices = type(slices)(slices.light, slices.view[px], slices.values[:, px], slices.valid[:, px] & valid[:, px],
                                   slices.pixels[px], slices.frame)
        self.shadowing = shadowing
        self.cube = hemicube(n)
        self.n_leds = slices.n_leds
        self.kd_bound_max_deg = kd_bound_max_deg

    def __call__(self, normal_xy: Array) -> float:
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
        from ..polar import polar_nodes

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
        from . import isotropic

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


def _grid_minima(xy: Array, e: Array, radius_deg: float) -> Array:
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
N_STARTS = 6


def estimate_normal_consistency(
    coarse: ConsistencyDistance, fine: ConsistencyDistance, max_tilt_deg: float = 16.0, step_deg: float = 3.0,
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

    def bounded(dist: ConsistencyDistance):
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


def refine_normal(dist: ConsistencyDistance, normal: Array, step_deg: float = 1.0,
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
