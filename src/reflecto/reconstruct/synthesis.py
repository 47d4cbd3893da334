"""Example-based microfacet synthesis (paper §5.5 after Wang et al. 2008; AR 4.4).

The captures at several rotations measure the NDF where some rotation's slices
reached; what none reached is completed from the measured NDF itself, turned about
``n``: the candidates are the measured texels rotated by ``α ∈ {Δα, 2Δα, …}``
(:data:`ROTATION_STEP_DEG`), a candidate is judged by how well it matches the known
region around the hole, the search is brute force over every rotation, and the
best candidates are blended in. Newly filled texels join the known region and the
search repeats until no rotation reaches further.

**What is synthesized.** Not ``D`` itself but its log ratio to the anisotropic GGX or
Beckmann lobe fitted to the measured texels (:func:`.ndf.fit_lobe`),
``r = log D − log lobe``: the lobe carries the level and the polar fall-off, which a
rotation about ``n`` cannot supply (it keeps ``θ_h``), and the candidates supply
the azimuthal structure the lobe misses (an asymmetric NDF's shifted components,
the measured shape of a real one). A hole texel then takes
``min(lobe · exp(r), push–pull of D)``, the cap of the plain fill, so that the
synthesis never raises a hole above its measured neighbours' level.

**The choices the paper leaves open** (Wang et al. do not state them either):

* *rotation step*: :data:`ROTATION_STEP_DEG` = 5° (71 candidates);
* *neighbourhood*: a Gaussian window of :data:`WINDOW_DEG` radius (σ half of it)
  around each hole texel, at the :data:`SYNTHESIS_RESOLUTION` hemicube (≈ 2.8°
  texels): the NDF's azimuthal structure spans tens of degrees;
* *overlap threshold*: a candidate counts where the known texels it covers hold at
  least :data:`MIN_OVERLAP` of the window's weight (Wang: 30 %);
* *distance*: the window-weighted variance of the log ratio of target to candidate
  (a log MSE after removing the mean offset ``μ``), plus :data:`GAIN_PENALTY` · μ²
  so that of two equal shapes the one at the right level wins;
* *blending*: the :data:`BLEND` best candidates, each shifted by its ``μ``, averaged
  with weights ``1 / (distance + ε)``; the result blended with the lobe-guided fill's
  ratio by the weight that predicts held-out measured texels best
  (:func:`held_out_weight`);
* *iteration*: the hole texels reached are filled at once, then the search repeats
  with them known (they are matched against, never copied from), at most
  :data:`MAX_ROUNDS` times.

Texels on rings of half vectors that no capture saw at any azimuth (the grazing rim
beyond the LEDs' reach) cannot be reached by a rotation; they keep the plain fill
(but for a band of one search texel at the measured rim: a rotated direction's
nearest texel lies up to 2° off its ring, so a rim texel can land on a measured one).
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np
from numpy.typing import NDArray
from scipy import sparse
from scipy.spatial import cKDTree

from ..errors import ParameterError
from ..geometry import rotate_z
from ..hemicube import Hemicube, hemicube
from . import ndf as ndf_mod
from .tuning import SYNTHESIS

Array = NDArray[np.float64]

__all__ = ["SynthesisOptions", "Synthesis", "synthesize_ratio", "SynthesisFill"]

# Tuned numbers: what, units and provenance are in :mod:`.tuning` (synthesis stage).
ROTATION_STEP_DEG = SYNTHESIS.rotation_step_deg
WINDOW_DEG = SYNTHESIS.window_deg
MIN_OVERLAP = SYNTHESIS.min_overlap
GAIN_PENALTY = SYNTHESIS.gain_penalty
BLEND = SYNTHESIS.blend
MAX_ROUNDS = SYNTHESIS.max_rounds
SYNTHESIS_RESOLUTION = SYNTHESIS.resolution
BLEND_EPS = SYNTHESIS.blend_eps
SYNTHESIS_FLOOR = SYNTHESIS.floor


#: How the §5.5 path completes the holes in its last passes: synthesis (the default), or
#: for comparison the plain fills — lobe-guided (:func:`.ndf.fill_holes_and_lobe`, the
#: symmetric path's) or plain push–pull (:func:`.ndf.push_pull`).
FILL_MODES = ("synthesis", "lobe", "push-pull")


@dataclasses.dataclass(frozen=True)
class SynthesisOptions:
    """The synthesis parameters (module docstring) and the fill ``mode`` (:data:`FILL_MODES`)."""

    rotation_step_deg: float = ROTATION_STEP_DEG
    window_deg: float = WINDOW_DEG
    min_overlap: float = MIN_OVERLAP
    gain_penalty: float = GAIN_PENALTY
    blend: int = BLEND
    max_rounds: int = MAX_ROUNDS
    resolution: int = SYNTHESIS_RESOLUTION
    floor: float = SYNTHESIS_FLOOR
    validate: bool = True
    mode: str = "synthesis"

    def __post_init__(self) -> None:
        if self.mode not in FILL_MODES:
            raise ParameterError(f"synthesis mode must be one of {FILL_MODES}, got {self.mode!r}")
        if not (0.0 < self.rotation_step_deg <= 90.0 and 0.0 < self.window_deg <= 45.0 and 0.0 < self.min_overlap <= 1.0
                and self.blend >= 1 and self.max_rounds >= 1 and self.resolution >= 8 and 0.0 < self.floor < 1.0):
            raise ParameterError(f"synthesis options out of range: {self}")


@dataclasses.dataclass
class Synthesis:
    """Result of :func:`synthesize_ratio` on a hemicube.

    Attributes
    ----------
    ratio
        ``r`` on every texel, shape ``(size,)``: the known values, the synthesized
        ones, 0 elsewhere.
    synthesized
        Texels filled by synthesis, shape ``(size,)``.
    rounds
        Search-and-fill rounds run.
    rotation_deg
        The best candidate's rotation at each synthesized texel (degrees), shape
        ``(synthesized.sum(),)``.
    """

    ratio: Array
    synthesized: NDArray[np.bool_]
    rounds: int
    rotation_deg: Array


@functools.lru_cache(maxsize=4)
def rotation_sources(n: int, step_deg: float) -> tuple[Array, NDArray[np.intp]]:
    """Rotations ``α_k`` (radians, shape ``(R,)``, 0 excluded) and, per rotation and
    texel ``t``, the texel of ``Rot_n(−α_k) h_t`` (shape ``(R, size)``): a candidate
    turned by ``α_k`` has at ``t`` the value measured there."""
    cube = hemicube(n)
    alphas = np.radians(np.arange(step_deg, 360.0 - 1e-9, step_deg))
    src = np.stack([cube.index(rotate_z(cube.directions, -a)) for a in alphas])
    src.setflags(write=False)
    return alphas, src


@functools.lru_cache(maxsize=4)
def window_matrix(n: int, radius_deg: float) -> sparse.csr_matrix:
    """Sparse ``(size, size)`` matrix of Gaussian window weights: row ``t`` holds
    ``exp(−½ (∠(h_t, h_u)/σ)²) Ω_u`` for texels ``u`` within ``radius_deg`` (σ half of it)."""
    cube = hemicube(n)
    d = cube.directions
    chord = 2.0 * math.sin(0.5 * math.radians(radius_deg))
    pairs = cKDTree(d).query_pairs(chord, output_type="ndarray")
    rows = np.concatenate([pairs[:, 0], pairs[:, 1], np.arange(cube.size)])
    cols = np.concatenate([pairs[:, 1], pairs[:, 0], np.arange(cube.size)])
    ang = np.arccos(np.clip(np.einsum("ij,ij->i", d[rows], d[cols]), -1.0, 1.0))
    w = np.exp(-0.5 * (ang / (0.5 * math.radians(radius_deg))) ** 2) * cube.solid_angles[cols]
    return sparse.csr_matrix((w, (rows, cols)), shape=(cube.size, cube.size))


def _best_candidates(stats: Array, w_row: Array, cand_known: NDArray[np.bool_], opt: SynthesisOptions
                     ) -> tuple[Array, Array, NDArray[np.intp]]:
    """Distance and offset per (frontier texel, rotation), and the rotations sorted by distance.

    ``stats`` (3, R, F): window sums of the overlap, of ``e = r − c`` and of ``e²``;
    ``w_row`` (F,) the window's total weight; ``cand_known`` (R, F) whether the
    candidate is measured at the texel itself.
    """
    s0, s1, s2 = stats
    with np.errstate(invalid="ignore", divide="ignore"):
        mu = np.where(s0 > 0, s1 / s0, 0.0)
        var = np.where(s0 > 0, s2 / s0 - mu * mu, np.inf)
    usable = cand_known & (s0 >= opt.min_overlap * w_row[None, :])
    dist = np.where(usable, np.maximum(var, 0.0) + opt.gain_penalty * mu * mu, np.inf)
    order = np.argsort(dist, axis=0)[: max(1, opt.blend)]
    return dist, mu, order


def synthesize_ratio(cube: Hemicube, known: NDArray[np.bool_], ratio: Array,
                     options: SynthesisOptions | None = None) -> Synthesis:
    """Fill the unknown texels of ``ratio`` from rotated copies of the known ones (module docstring).

    Parameters
    ----------
    cube
        The hemicube of ``known`` and ``ratio`` (its resolution is the search's).
    known
        Measured texels, shape ``(size,)``: the candidates' texels and the first known region.
    ratio
        ``r = log D − log lobe`` on the known texels (any value elsewhere), shape ``(size,)``.
    """
    opt = options or SynthesisOptions()
    alphas, src = rotation_sources(cube.n, float(opt.rotation_step_deg))
    win = window_matrix(cube.n, float(opt.window_deg))
    w_total = np.asarray(win.sum(axis=1)).ravel()
    measured = np.asarray(known, dtype=bool)
    r = np.where(measured, ratio, 0.0)
    cand = r[src]  # (R, size): candidates' values, fixed (copied from measured texels only)
    cand_known = measured[src]
    k_now = measured.copy()
    synth = np.zeros(cube.size, dtype=bool)
    best_rot = np.zeros(cube.size)
    rounds = 0
    for rounds in range(1, opt.max_rounds + 1):
        reach = np.flatnonzero(~k_now & (win @ k_now.astype(np.float64) > 0) & cand_known.any(axis=0))
        if not len(reach):
            rounds -= 1
            break
        # the window sums at the reached texels need the texels within a window of them only
        w_reach = win[reach]
        cols = np.unique(w_reach.indices)
        w_reach = sparse.csr_matrix((w_reach.data, np.searchsorted(cols, w_reach.indices), w_reach.indptr),
                                    shape=(len(reach), len(cols)))
        ov = k_now[None, cols] & cand_known[:, cols]
        e = np.where(ov, r[None, cols] - cand[:, cols], 0.0)
        x = np.empty((len(cols), 3 * len(alphas)))  # (texels, 3R), C order as the sparse product wants it
        r_count = len(alphas)
        x[:, :r_count] = ov.T
        x[:, r_count : 2 * r_count] = e.T
        x[:, 2 * r_count :] = (e * e).T
        stats = np.asarray(w_reach @ x).T.reshape(3, r_count, len(reach))
        dist, mu, order = _best_candidates(stats, w_total[reach], cand_known[:, reach], opt)
        d_best = np.take_along_axis(dist, order, 0)
        ok = np.isfinite(d_best[0])
        if not ok.any():
            rounds -= 1
            break
        cols = np.arange(len(reach))
        vals = np.take_along_axis(cand[:, reach] + mu, order, 0)
        wts = np.where(np.isfinite(d_best), 1.0 / (d_best + BLEND_EPS), 0.0)
        fill = reach[ok]
        r[fill] = (np.sum(wts * vals, axis=0) / np.maximum(np.sum(wts, axis=0), 1e-300))[ok]
        best_rot[fill] = np.degrees(alphas[order[0, cols[ok]]])
        k_now[fill] = True
        synth[fill] = True
    return Synthesis(np.where(k_now, r, 0.0), synth, rounds, best_rot[synth])


@dataclasses.dataclass(frozen=True)
class HeldOut:
    """How well synthesis predicts measured texels it did not see (:func:`held_out_weight`).

    ``weight`` of the synthesized ratio against the plain fill's, ``rms_synthesis`` and
    ``rms_plain`` the two predictions' Ω-weighted RMS log errors on the held-out texels,
    ``texels`` how many there were.
    """

    weight: float
    rms_synthesis: float
    rms_plain: float
    texels: int


def held_out_weight(cube: Hemicube, known: NDArray[np.bool_], ratio: Array, synthesized: NDArray[np.bool_],
                    options: SynthesisOptions) -> HeldOut:
    """Blend weight of synthesis from the measured texels next to what it filled.

    The known texels within one window of a synthesized texel are held out; synthesis
    from the remaining known texels (:func:`synthesize_ratio`) and push–pull of their
    ratio (the plain fill's interpolation) both predict them, with errors ``e_s`` and
    ``e_p``; the weight ``w ∈ [0, 1]`` minimizes ``Σ Ω (w e_s + (1 − w) e_p)²``. It is 1
    where the rotated copies continue the measured NDF better than interpolation does,
    0 where interpolation is better, and between where both err. Shapes ``(size,)``.
    """
    win = window_matrix(cube.n, float(options.window_deg))
    band = known & (win @ synthesized.astype(np.float64) > 0)
    rest = known & ~band
    if np.count_nonzero(band) < 4 or not rest.any():
        return HeldOut(1.0, math.nan, math.nan, 0)
    syn = synthesize_ratio(cube, rest, ratio, options)
    test = band & syn.synthesized
    if np.count_nonzero(test) < 4:
        return HeldOut(1.0, math.nan, math.nan, int(np.count_nonzero(test)))
    plain = ndf_mod.push_pull(cube, rest.astype(np.float64), np.where(rest, ratio, 0.0))
    om = cube.solid_angles[test]
    e_s, e_p = syn.ratio[test] - ratio[test], plain[test] - ratio[test]
    den = float(np.sum(om * (e_s - e_p) ** 2))
    w = float(np.clip(np.sum(om * e_p * (e_p - e_s)) / den, 0.0, 1.0)) if den > 0 else 1.0
    rms = (lambda e: math.sqrt(float(np.sum(om * e * e) / np.sum(om))))
    return HeldOut(w, rms(e_s), rms(e_p), int(np.count_nonzero(test)))


@dataclasses.dataclass
class SynthesisFill:
    """The hole fill of the §5.5 path (a :data:`.hemicube_fit.HoleFill`).

    In every pass the holes take the lobe-guided fill (:func:`.ndf.fill_holes_and_lobe`:
    without eq. 3's mirror the holes lie inside the NDF, not only at its rim); in the
    passes of the last outer iteration the texels a rotation reaches are synthesized
    instead (:meth:`complete`). The search runs in the first of those passes; the
    next pass, whose measured NDF differs only by the updated S, reuses its
    synthesized ratio (it costs as much as the rest of the pass). ``last_synthesis``
    keeps what the synthesis did, ``synthesized_work`` and ``holes_work`` the texels
    of the working hemicube ``cube`` it filled and that no capture covered, for the
    summary and the validation.
    """

    options: SynthesisOptions = dataclasses.field(default_factory=SynthesisOptions)
    last_synthesis: Synthesis | None = None
    synthesized_work: NDArray[np.bool_] | None = None
    holes_work: NDArray[np.bool_] | None = None
    cube: Hemicube | None = None
    held_out: HeldOut | None = None

    def __call__(self, work: Hemicube, wsum: Array, wv: Array, last: bool, inner_holes: bool
                 ) -> tuple[Array, Array | None]:
        """The pass's filled NDF on ``work`` and its log lobe (the :data:`.hemicube_fit.HoleFill` call).

        Lobe-guided fill, except in the last outer iteration's passes (``last``), where
        ``options.mode`` decides (``"push-pull"``, or the rotation synthesis of :meth:`complete`).
        """
        d, log_lobe = ndf_mod.fill_holes_and_lobe(work, wsum, wv)
        if not last or log_lobe is None:
            return d, log_lobe
        self.holes_work, self.cube = wsum <= 1e-12, work
        if self.options.mode == "lobe":
            return d, log_lobe
        if self.options.mode == "push-pull":
            return ndf_mod.push_pull(work, wsum, wv), log_lobe
        return self.complete(work, wsum, wv, d, log_lobe), log_lobe

    def complete(self, work: Hemicube, wsum: Array, wv: Array, d_plain: Array, log_lobe: Array) -> Array:
        """``d_plain`` with the holes that a rotation reaches synthesized (module docstring)."""
        obs = wsum > 1e-12
        v = np.where(obs, wv / np.maximum(wsum, 1e-300), 0.0)
        peak = max(float(v.max()), 1e-300)
        pos = obs & (v > self.options.floor * peak)
        ratio = np.where(pos, np.log(np.maximum(v, 1e-300)) - log_lobe, 0.0)
        n_s = min(work.n, self.options.resolution)
        f = work.n // n_s
        if f > 1:
            coarse, frac = work.downsample(pos.astype(np.float64), f)
            _, r_sum = work.downsample(np.where(pos, ratio, 0.0), f)
            known = frac >= 0.5
            r_coarse = np.where(known, r_sum / np.maximum(frac, 1e-300), 0.0)
        else:
            coarse, known, r_coarse = work, pos, ratio
        syn = self.last_synthesis
        if syn is None or len(syn.ratio) != coarse.size:
            syn = synthesize_ratio(coarse, known, r_coarse, self.options)
            self.last_synthesis = syn
            self.held_out = held_out_weight(coarse, known, r_coarse, syn.synthesized, self.options)
        # the working holes whose (nearest) search texel was synthesized take its ratio, interpolated
        # the deep tail (below the floor) has no reliable ratio to match against: plain fill
        hole = ~obs & (log_lobe >= math.log(self.options.floor * peak))
        at = coarse.index(work.directions)
        target = hole & syn.synthesized[at]
        self.synthesized_work = target
        if not target.any():
            return d_plain
        filled = ndf_mod.push_pull(coarse, (known | syn.synthesized).astype(np.float64),
                                   np.where(known | syn.synthesized, syn.ratio, 0.0))
        r_t = coarse.lookup(filled, work.directions[target])
        plain_cap = ndf_mod.push_pull(work, wsum, wv)
        w = self.held_out.weight if self.held_out is not None and self.options.validate else 1.0
        if w < 1.0:  # blended with the plain fill's ratio, as the held-out texels say
            r_t = w * r_t + (1.0 - w) * (np.log(np.maximum(d_plain[target], 1e-300)) - log_lobe[target])
        out = d_plain.copy()
        out[target] = np.minimum(np.exp(np.minimum(log_lobe[target] + r_t, 700.0)), plain_cap[target])
        return out
