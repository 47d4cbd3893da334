"""Fresnel index (and diffuse albedo) from overlapping slices (paper §5.1, eqs. 4–6).

Two samples ``p, q`` with the same half vector see the same ``D(h)``, so their
partial NDFs (eq. 7) agree once the right Fresnel term is divided out:

``y_p = (f_p − k_d/π)(i_p·n)(o_p·n) / (S(i_p) S(o_p) F(i_p·h; η)) = k_s D(h) / 4``

and ``y_p / y_q = 1`` is eq. 5 rearranged. Pairs come from two sources:

* *direct* overlaps: the same working texel seen by two LEDs (the paper's pairs);
* *symmetric* overlaps: a texel ``h`` seen by LED ``a`` and ``τh`` seen by LED ``b``
  (``a = b`` allowed), since the NDF is symmetric under ``τ`` (eq. 3). These put
  pairs near the lobe centre, where the direct overlaps of a coverage-optimal layout
  are missing.

Per colour channel, ``η`` and ``k_d`` are fitted together by Levenberg–Marquardt
(MINPACK through ``scipy.optimize.leastsq``, automatic variable scaling) on the relative differences
``(y_p − y_q) / ȳ`` (eq. 6 in relative form), with ``η = 1 + e^x`` so that η > 1.
``k_d`` enters because with a free tabulated NDF the diffuse term can only be told
apart from the NDF's tail by the same consistency: a wrong ``k_d`` makes partial NDFs
of different ``(i, o)`` disagree at the same ``h``.

``E(η)`` — the RMS relative residual — is what §5.1 uses to detect shaken captures:
when the sample moves between two LEDs' frames, their slices do not share ``D(h)``
at the same texel, and the ratios stop following any Fresnel curve.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import leastsq

from .. import _kernels
from ..colour import LUM
from ..fresnel import fresnel_numpy
from .samples import Bins
from .tuning import FRESNEL_FIT, ISOTROPIC

Array = NDArray[np.float64]

# Tuned numbers: what, units and provenance are in :mod:`.tuning` (fresnel_fit stage).
MIN_LEVEL = FRESNEL_FIT.min_level
ETA_MAX = ISOTROPIC.eta_max
MIN_COUNT = FRESNEL_FIT.min_count
MAX_PAIRS = FRESNEL_FIT.max_pairs


@dataclasses.dataclass
class Pairs:
    """Overlapping bins: index arrays ``p, q`` (shape ``(K,)``), whether each is a
    symmetric overlap, and ``u`` (shape ``(K,)``), a hash of the pair's two
    ``(LED, texel)`` keys in [0, 1) that draws the fits' subsample (:func:`pair_hash`)."""

    p: NDArray[np.intp]
    q: NDArray[np.intp]
    symmetric: NDArray[np.bool_]
    u: Array

    def __len__(self) -> int:
        return len(self.p)

    def select(self, mask: NDArray[np.bool_] | NDArray[np.intp] | slice) -> Pairs:
        """The pairs at ``mask`` (boolean mask, indices or slice over the ``K`` pairs)."""
        return Pairs(self.p[mask], self.q[mask], self.symmetric[mask], self.u[mask])


def _mix64(x: NDArray[np.uint64]) -> NDArray[np.uint64]:
    """SplitMix64's finaliser: a bijection of uint64 whose output bits all depend on every input bit."""
    x = x ^ (x >> np.uint64(30))
    x = x * np.uint64(0xBF58476D1CE4E5B9)
    x = x ^ (x >> np.uint64(27))
    x = x * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


def pair_hash(bins: Bins, p: NDArray[np.intp], q: NDArray[np.intp]) -> Array:
    """A uniform pseudo-random number in [0, 1) per pair, a function of the pair's two
    ``(LED, texel)`` keys only (shape ``(K,)``).

    The fits keep the pairs with ``u < MAX_PAIRS / K``. Position-based subsampling
    (every k-th pair of the list) aliases with the texel order, and one pair more or
    less below the level threshold shifted the whole subsample: on measured materials,
    whose E(η) is flat, η or k_s then moved by 7–60 % from a 1e-12 change of the input
    (6 of the 50 shared materials).
    """
    key = bins.led.astype(np.uint64) * np.uint64(bins.cube.size) + bins.texel.astype(np.uint64)
    with np.errstate(over="ignore"):
        h = _mix64(_mix64(key[p]) ^ (key[q] + np.uint64(0x9E3779B97F4A7C15)))
    return (h >> np.uint64(11)).astype(np.float64) * 2.0**-53


@dataclasses.dataclass
class FresnelFit:
    """Result of the η (and k_d) fit.

    Attributes
    ----------
    eta
        Per-channel relative index, shape ``(3,)``.
    kd
        Per-channel diffuse albedo ρ_d, shape ``(3,)``.
    error
        E(η): weighted RMS of the relative residuals, luminance (dimensionless).
    pair_error
        RMS residual per LED pair, shape ``(L, L)`` (NaN where no overlap).
    n_pairs
        Number of bin pairs used.
    theta_d_spread_deg
        Median ``|θ_d(p) − θ_d(q)|`` over the pairs: η is weakly determined when the
        pairs see nearly the same Fresnel angle (algorithm-reference §2.3).
    """

    eta: Array
    kd: Array
    error: float
    pair_error: Array
    n_pairs: int
    theta_d_spread_deg: float
    error_median: float = float("nan")


def pair_residuals_numpy(cp: Array, cq: Array, fp: Array, fq: Array, ap: Array, aq: Array, w: Array,
                         eta: float, kd: float, level: float) -> Array:
    """Eq. 6 residual per pair, ``w (y_p − y_q) / ȳ`` (NumPy reference of the compiled kernel).

    ``y = (f − k_d/π) a / F(c; η)``; ``ȳ`` is the pair's mean of ``f a / F``, floored
    at ``level`` because noisy dim bins can average to ≈ 0.
    """
    fpp, fqq = np.maximum(fresnel_numpy(cp, eta), 1e-12), np.maximum(fresnel_numpy(cq, eta), 1e-12)
    yp = (fp - kd / math.pi) * ap / fpp
    yq = (fq - kd / math.pi) * aq / fqq
    mean = 0.5 * (fp * ap / fpp + fq * aq / fqq)
    return w * (yp - yq) / np.maximum(mean, level)


def overlap_pairs(bins: Bins, n_leds: int, symmetric: bool = True) -> Pairs:
    """All direct (same texel, two LEDs) and symmetric (``h`` and ``τh``) bin pairs.

    Bins must be sorted by ``(led, texel)``, as :func:`bin_samples` makes them.
    """
    key = bins.led.astype(np.int64) * bins.cube.size + bins.texel
    if np.any(np.diff(key) <= 0):
        raise ValueError("overlap_pairs: bins must be sorted by (led, texel), one bin per key")
    tau = bins.cube.permutation(np.diag([-1.0, -1.0, 1.0]))
    p, q, sym = _kernels.overlap_pairs(bins.led.astype(np.int64), bins.texel.astype(np.int64), n_leds,
                                       bins.cube.size, tau.astype(np.int64), symmetric)
    p, q = p.astype(np.intp), q.astype(np.intp)
    return Pairs(p, q, sym, pair_hash(bins, p, q))


def overlap_pairs_numpy(bins: Bins, n_leds: int, symmetric: bool = True) -> Pairs:
    """NumPy reference of :func:`overlap_pairs` (same pairs, same order)."""
    size = bins.cube.size
    slot = np.full((n_leds, size), -1, dtype=np.intp)
    slot[bins.led, bins.texel] = np.arange(len(bins))
    tau = bins.cube.permutation(np.diag([-1.0, -1.0, 1.0]))
    ps, qs, sym = [], [], []
    for a in range(n_leds):
        for b in range(a, n_leds):
            if b > a:
                m = (slot[a] >= 0) & (slot[b] >= 0)
                ps.append(slot[a][m])
                qs.append(slot[b][m])
                sym.append(np.zeros(int(m.sum()), bool))
            if symmetric:
                sb = slot[b][tau]
                m = (slot[a] >= 0) & (sb >= 0)
                if a == b:
                    m &= np.arange(size) < tau  # each unordered pair once, never a texel with itself
                ps.append(slot[a][m])
                qs.append(sb[m])
                sym.append(np.ones(int(m.sum()), bool))
    p, q = np.concatenate(ps), np.concatenate(qs)
    return Pairs(p, q, np.concatenate(sym), pair_hash(bins, p, q))


def _remember_last(fun: Callable[[Array], Array]) -> Callable[[Array], Array]:
    """``fun`` that returns its previous result again for the same ``x``.

    leastsq evaluates the residual and the Jacobian at the start point once to check
    their shapes and again to start: each is one pass over every pair saved.
    """
    last: list[Any] = [None, None]

    def wrapped(x: Array) -> Array:
        key = np.asarray(x, dtype=np.float64).tobytes()
        if key != last[0]:
            last[0], last[1] = key, fun(x)
        return last[1]

    return wrapped


def fit_fresnel(
    bins: Bins,
    pairs: Pairs,
    a: Array,
    n_leds: int,
    kd0: Array,
    eta0: Array,
    kd_max: Array,
    exclude: set[int] | None = None,
    fixed_eta: float | None = None,
    per_channel: bool = True,
    diagnostics: bool = True,
) -> FresnelFit:
    """Fit η and k_d per channel to the overlapping bins (eq. 6, see the module docstring).

    Parameters
    ----------
    bins, pairs
        Binned samples and their overlaps.
    a
        ``(i·n)(o·n) / (S(i) S(o))`` per bin, shape ``(B,)``.
    kd0, eta0
        Starting values, shape ``(3,)``.
    kd_max
        Upper bound of ρ_d per channel (``π · min f``), shape ``(3,)``.
    exclude
        LEDs left out (shake).
    fixed_eta
        Fit only k_d, with this η.
    per_channel
        Fit each channel; otherwise fit the luminance once and scale k_d per channel
        by ``kd_max`` (a cheaper start for the first iterations).
    diagnostics
        Also compute ``error_median``, ``pair_error`` and ``theta_d_spread_deg`` (NaN
        otherwise): the loop's intermediate fits need only E(η).
    """
    exclude = exclude or set()
    n_none = FresnelFit(np.asarray(eta0, float).copy(), np.asarray(kd0, float).copy(), float("nan"),
                        np.full((n_leds, n_leds), np.nan), 0, float("nan"))
    if not len(pairs):
        return n_none
    g = (bins.f @ LUM) * a
    level = MIN_LEVEL * float(np.max(g))
    keep = (g[pairs.p] > level) & (g[pairs.q] > level)
    keep &= (bins.count[pairs.p] >= MIN_COUNT) & (bins.count[pairs.q] >= MIN_COUNT)
    if exclude:
        bad = np.isin(bins.led, list(exclude))
        keep &= ~bad[pairs.p] & ~bad[pairs.q]
    n_keep = int(np.count_nonzero(keep))
    if n_keep > MAX_PAIRS:  # a hashed subsample: each pair's draw is its own (see pair_hash)
        keep &= pairs.u < MAX_PAIRS / n_keep
    pr = pairs.select(keep)
    if len(pr) < 3:
        return n_none
    p, q = pr.p, pr.q
    cp, cq = bins.cos_d[p], bins.cos_d[q]
    ap, aq = a[p], a[q]
    # weights: the relative residual's noise falls with the pixel count and the signal
    # (shot noise; 12-bit quantisation in the dimmest bins)
    w = np.sqrt(np.minimum(bins.count[p], bins.count[q]) * np.minimum(g[p], g[q]) / float(np.max(g)))
    eta = np.empty(3)
    kd = np.empty(3)
    resid = np.empty((len(p), 3))
    f_ch = bins.f if per_channel else (bins.f @ LUM)[:, None]
    kd_max_ch = kd_max if per_channel else np.array([kd_max @ LUM])
    kd0_ch = kd0 if per_channel else np.array([kd0 @ LUM])
    eta0_ch = eta0 if per_channel else np.array([eta0 @ LUM])
    for ch in range(f_ch.shape[1]):
        fp, fq = np.ascontiguousarray(f_ch[p, ch]), np.ascontiguousarray(f_ch[q, ch])
        hi = float(kd_max_ch[ch])

        def parts(x: Array, hi: float = hi) -> tuple[float, float]:
            # η = 1 + e^x₀ > 1; k_d = hi·sigmoid(x₁) ∈ (0, hi): no bounds needed by LM
            e = (float(fixed_eta) if fixed_eta is not None
                 else min(1.0 + max(math.exp(min(float(x[0]), 10.0)), 1e-3), ETA_MAX))
            return e, hi / (1.0 + math.exp(-float(np.clip(x[-1], -40.0, 40.0))))

        @_remember_last
        def r(x: Array, fp: Array = fp, fq: Array = fq) -> Array:
            e, k = parts(x)
            out = np.empty(len(fp))
            _kernels.pair_residuals(cp, cq, fp, fq, ap, aq, w, e, k / math.pi, level, out)
            return out

        @_remember_last
        def jac(x: Array, fp: Array = fp, fq: Array = fq, hi: float = hi) -> Array:
            # analytic ∂r/∂x (rows: x), chained through η = 1 + e^x₀ and k_d = hi·sigmoid(x₁);
            # 0 where parts() clamps. One pass instead of MINPACK's one evaluation per parameter
            e, k = parts(x)
            d = np.empty((2, len(fp)))
            _kernels.pair_residuals_jac(cp, cq, fp, fq, ap, aq, w, e, k / math.pi, level, d)
            x1 = float(x[-1])
            s = k / hi if hi > 0 else 0.0
            d[1] *= hi / math.pi * s * (1.0 - s) if abs(x1) < 40.0 else 0.0
            if fixed_eta is not None:
                return d[1:]
            x0 = float(x[0])
            d[0] *= math.exp(x0) if (x0 < 10.0 and math.exp(x0) > 1e-3 and e < ETA_MAX) else 0.0
            return d

        frac = float(np.clip(kd0_ch[ch] / hi, 1e-6, 1 - 1e-6)) if hi > 0 else 0.5
        x0 = [math.log(frac / (1.0 - frac))]
        if fixed_eta is None:
            x0 = [math.log(max(float(eta0_ch[ch]) - 1.0, 1e-3))] + x0
        x = np.asarray(x0, dtype=np.float64)
        rx = r(x)
        if np.all(np.isfinite(rx)):
            # MINPACK's lmdif directly: least_squares(method="lm") runs the same
            # algorithm but spends ≈ 4 ms per fit in Python around the Jacobian
            # full_output: a fit that runs out of evaluations (maxfev = 600, as
            # least_squares) keeps its last iterate without a warning; its fvec is
            # r at that iterate
            sol, _, info, *_ = leastsq(r, x, Dfun=jac, col_deriv=True, ftol=1e-8, xtol=1e-8, gtol=1e-8,
                                       full_output=True)
            if np.all(np.isfinite(sol)) and np.all(np.isfinite(info["fvec"])):
                x, rx = np.atleast_1d(sol), info["fvec"]
        eta[ch], kd[ch] = parts(x)
        resid[:, ch] = rx / w
    if not per_channel:
        frac = kd[0] / max(float(kd_max @ LUM), 1e-300)
        eta[:], kd[:] = eta[0], frac * kd_max
        resid[:, 1:] = resid[:, :1]
    lum_res = resid @ LUM
    error = float(np.sqrt(np.sum(w * w * lum_res**2) / np.sum(w * w)))
    if not diagnostics:
        return FresnelFit(eta, kd, error, np.full((n_leds, n_leds), np.nan), int(len(p)), float("nan"), float("nan"))
    order = np.argsort(np.abs(lum_res))
    cw = np.cumsum((w * w)[order])
    error_median = float(np.abs(lum_res[order])[np.searchsorted(cw, 0.5 * cw[-1])])
    # RMS residual per unordered LED pair
    la, lb = bins.led[p], bins.led[q]
    cell = np.minimum(la, lb) * n_leds + np.maximum(la, lb)
    n_cell = np.bincount(cell, minlength=n_leds * n_leds).reshape(n_leds, n_leds)
    ss = np.bincount(cell, weights=lum_res**2, minlength=n_leds * n_leds).reshape(n_leds, n_leds)
    with np.errstate(invalid="ignore", divide="ignore"):
        pair_error = np.where(n_cell > 0, np.sqrt(ss / n_cell), np.nan)
    pair_error = np.where(np.isnan(pair_error), pair_error.T, pair_error)
    spread = float(np.degrees(np.median(np.abs(np.arccos(cp) - np.arccos(cq)))))
    return FresnelFit(eta, kd, error, pair_error, int(len(p)), spread, error_median)
