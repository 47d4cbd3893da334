"""Altered-normal estimation (paper §5.4, after HLHZ08; algorithm-reference §5.2–5.3).

For a candidate normal ``n`` the samples are expressed in its frame and turned into
partial-NDF values with ``S = F = 1`` (eq. 7 up to a constant):
``D̂ ∝ f_s (i·n)(o·n)``. The *symmetry distance* is the mean squared difference of
``log(D̂ + ε)`` between hemicube texels ``h`` and ``τh = R_n(h)`` (the reflection
through the normal, eq. 3) where both were measured. As the paper says, only the
symmetry across the normal is used; the dense views carry the transformation (the
texel of ``τh`` is filled by other pixels of the same or another slice).

The minimum is found on a grid of tilts (every ``step_deg`` up to ``max_tilt_deg``)
and refined by Nelder–Mead on the two tilt components.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import minimize

from .. import geometry
from ..hemicube import hemicube

Array = NDArray[np.float64]

#: Working resolution of the symmetry distance.
SYMMETRY_N = 32
#: Minimum number of texel pairs for a candidate to count.
MIN_PAIRS = 40


def tilt_frame(tx: float, ty: float) -> Array:
    """Frame (rows t, b, n) whose normal is ``normalize(tx, ty, 1)``; t follows device x."""
    return geometry.frame_from_normal(np.array([tx, ty, 1.0]), np.array([1.0, 0.0, 0.0]))


class SymmetryDistance:
    """Symmetry distance of a set of slice samples as a function of the candidate normal.

    Parameters
    ----------
    light
        LED directions (device frame), shape ``(L, 3)``.
    view
        View directions, shape ``(P, 3)``.
    value
        Luminance BRDF minus the diffuse estimate, times the device-frame ``cos θ_i``
        (so that only ``o·n`` depends on the candidate), shape ``(L, P)``; NaN = invalid.
    """

    def __init__(self, light: Array, view: Array, value: Array, n: int = SYMMETRY_N) -> None:
        ok = np.isfinite(value)
        li, pi = np.nonzero(ok)
        self.i = light[li]
        self.o = view[pi]
        v = value[ok]
        self.v = v
        self.eps = 1e-3 * max(float(np.percentile(v, 99.9)), 1e-12)
        self.cube = hemicube(n)
        self.tau = self.cube.permutation(geometry.TAU)

    def __call__(self, normal_xy: Array) -> float:
        frame = tilt_frame(float(normal_xy[0]), float(normal_xy[1]))
        i = self.i @ frame.T
        o = self.o @ frame.T
        ok = (i[:, 2] > 0.02) & (o[:, 2] > 0.05)
        h = geometry.normalize(i[ok] + o[ok])
        d = np.log(np.maximum(self.v[ok] * o[ok, 2], 0.0) + self.eps)
        wsum, wv = self.cube.splat(h, d)
        have = wsum > 0
        both = have & have[self.tau]
        if both.sum() < MIN_PAIRS:
            return float("inf")
        m = np.where(have, wv / np.where(have, wsum, 1.0), 0.0)
        diff = m[both] - m[self.tau][both]
        return float(np.mean(diff * diff))


def estimate_normal(dist: SymmetryDistance, max_tilt_deg: float = 16.0, step_deg: float = 4.0) -> tuple[Array, float]:
    """Normal minimising the symmetry distance; returns ``(normal, distance)``."""
    best = (float(dist(np.zeros(2))), np.zeros(2))
    for t in np.arange(step_deg, max_tilt_deg + 1e-9, step_deg):
        k = max(6, int(round(2 * math.pi * t / step_deg)))
        for a in np.arange(k) * (2 * math.pi / k):
            xy = math.tan(math.radians(t)) * np.array([math.cos(a), math.sin(a)])
            e = dist(xy)
            if e < best[0]:
                best = (e, xy)
    res = minimize(dist, best[1], method="Nelder-Mead",
                   options={"xatol": 2e-4, "fatol": 1e-9, "initial_simplex": best[1] + np.array([[0, 0], [0.03, 0], [0, 0.03]])})
    xy = res.x if res.fun <= best[0] else best[1]
    return tilt_frame(float(xy[0]), float(xy[1]))[2], float(min(res.fun, best[0]))
