"""Fresnel index from overlapping slices (paper §5.1, eqs. 4–6).

Two samples from LEDs a and b with the same half vector see the same D(h), so the
ratio of their ``g = f_s (i·n)(o·n) / (S(i) S(o)) = k_s D F / 4`` is the ratio of
Fresnel terms (eq. 5). Samples are averaged per hemicube texel and per LED; every
texel seen by two LEDs gives one measured ratio. η is fitted per colour channel by
Levenberg–Marquardt (``scipy.optimize.least_squares(method="lm")``) on eq. 6 in log
form, ``log(g_a/g_b) − log(F(c_a; η)/F(c_b; η))`` (symmetric in a, b), with
``η = 1 + e^x`` so that η > 1 without bounds.

``E(η)`` — the RMS residual — is what §5.1 uses to detect shaken captures: when the
sample moves between two LEDs' frames, their slices no longer share D(h) at the same
texel, and the ratios stop following any Fresnel curve.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from ..fresnel import fresnel
from ..hemicube import hemicube

Array = NDArray[np.float64]

#: Working resolution of the per-texel ratios.
RATIO_N = 64
#: Only texels whose g is above this fraction of the capture's maximum take part.
MIN_LEVEL = 0.005
ETA_MAX = 50.0


@dataclasses.dataclass
class FresnelFit:
    """Result of the η fit.

    Attributes
    ----------
    eta
        Per-channel relative index, shape ``(3,)``.
    error
        E(η): RMS of the log-ratio residuals (dimensionless).
    pair_error
        RMS residual per LED pair, shape ``(L, L)`` (NaN where no overlap).
    n_pairs
        Number of texel ratios used.
    theta_d_max_deg
        Largest θ_d among the ratios (η is weakly determined below 45°, §2.3).
    """

    eta: Array
    error: float
    pair_error: Array
    n_pairs: int
    theta_d_max_deg: float


def texel_means(h: Array, c: Array, g: Array, led: NDArray[np.intp], n_leds: int, n: int = RATIO_N):
    """Per LED and texel: sample count, mean ``c`` and mean ``g`` (RGB)."""
    cube = hemicube(n)
    counts = np.zeros((n_leds, cube.size))
    cm = np.zeros((n_leds, cube.size))
    gm = np.zeros((n_leds, cube.size, 3))
    for l in range(n_leds):
        m = led == l
        if not m.any():
            continue
        w, v = cube.splat(h[m], np.column_stack([c[m], g[m]]))
        counts[l] = w
        have = w > 0
        cm[l, have] = v[have, 0] / w[have]
        gm[l, have] = v[have, 1:] / w[have, None]
    return counts, cm, gm


def _pairs(counts: Array, cm: Array, gm: Array, exclude: set[int]):
    n_leds = counts.shape[0]
    out = []
    lum = gm @ np.array([0.2126, 0.7152, 0.0722])
    peak = [max(float(lum.max()), 1e-300)] * n_leds
    for a in range(n_leds):
        for b in range(a + 1, n_leds):
            if a in exclude or b in exclude:
                continue
            both = (counts[a] >= 2) & (counts[b] >= 2)
            both &= (lum[a] > MIN_LEVEL * peak[a]) & (lum[b] > MIN_LEVEL * peak[b])
            both &= np.all(gm[a] > 0, axis=1) & np.all(gm[b] > 0, axis=1)
            t = np.flatnonzero(both)
            if len(t):
                out.append((a, b, t))
    return out


def fit_eta(counts: Array, cm: Array, gm: Array, exclude: set[int] | None = None, eta0: float = 1.5) -> FresnelFit:
    """LM fit of per-channel η to all overlapping texel ratios (eq. 6)."""
    exclude = exclude or set()
    pairs = _pairs(counts, cm, gm, exclude)
    n_leds = counts.shape[0]
    if not pairs:
        return FresnelFit(np.full(3, eta0), float("nan"), np.full((n_leds, n_leds), np.nan), 0, float("nan"))
    ca = np.concatenate([cm[a, t] for a, b, t in pairs])
    cb = np.concatenate([cm[b, t] for a, b, t in pairs])
    la = np.concatenate([np.log(gm[a, t]) for a, b, t in pairs])
    lb = np.concatenate([np.log(gm[b, t]) for a, b, t in pairs])
    w = np.sqrt(np.concatenate([np.sqrt(np.minimum(counts[a, t], counts[b, t])) for a, b, t in pairs]))
    meas = la - lb  # (M, 3)
    eta = np.empty(3)
    resid = np.empty_like(meas)
    for ch in range(3):
        def r(x: Array, ch: int = ch) -> Array:
            e = min(1.0 + math.exp(float(x[0])), ETA_MAX)
            return w * (meas[:, ch] - np.log(fresnel(ca, e) / fresnel(cb, e)))

        x0 = math.log(eta0 - 1.0)
        try:
            sol = least_squares(r, [x0], method="lm")
            x = float(sol.x[0])
        except ValueError:
            x = x0
        eta[ch] = min(1.0 + math.exp(x), ETA_MAX)
        resid[:, ch] = meas[:, ch] - np.log(fresnel(ca, eta[ch]) / fresnel(cb, eta[ch]))
    lum_res = resid @ np.array([0.2126, 0.7152, 0.0722])
    error = float(np.sqrt(np.sum(w * w * lum_res**2) / np.sum(w * w)))
    pair_error = np.full((n_leds, n_leds), np.nan)
    k = 0
    for a, b, t in pairs:
        seg = lum_res[k : k + len(t)]
        pair_error[a, b] = pair_error[b, a] = float(np.sqrt(np.mean(seg**2)))
        k += len(t)
    theta_d = float(np.degrees(np.arccos(np.clip(min(ca.min(), cb.min()), 0, 1))))
    return FresnelFit(eta, error, pair_error, int(len(ca)), theta_d)
