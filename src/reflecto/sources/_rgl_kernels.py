"""Compiled loop of the continuous ``Marginal2D`` warp (:meth:`reflecto.sources.rgl.Marginal2D.sample`).

Its NumPy reference is :meth:`Marginal2D.sample_numpy`, which the tests compare it with
bit for bit: the same bisections, the same closed-form quadratics, the operations in
the same order (no fast-math). Reading an RGL file checks its tables by warping every
incident slice (:meth:`RGLBRDF.slice_albedo`), millions of samples for an anisotropic
file; vectorized over all samples, the bisections' gathers dominated the read.
"""

from __future__ import annotations

import math
from typing import Any

from numba import njit

_OPTS: dict[str, Any] = dict(cache=True, nogil=True, fastmath=False, error_model="numpy")


@njit(inline="always", **_OPTS)
def _solve_quadratic(v0, v1, y):  # pragma: no cover - compiled
    """``t ∈ [0, 1]`` with ``t v0 + ½ t² (v1 − v0) = y``: :func:`reflecto.sources.rgl._solve_quadratic`."""
    a = 0.5 * (v1 - v0)
    ym = max(y, 0.0)
    disc = math.sqrt(max(v0 * v0 + 4.0 * a * ym, 0.0))
    lin = y / v0 if v0 > 0 else 0.0
    quad = 2.0 * ym / (v0 + disc) if (v0 + disc) > 0 else 0.0
    t = lin if abs(a) < 1e-9 * max(abs(v0), 1e-300) else quad
    return min(max(t, 0.0), 1.0)


@njit(**_OPTS)
def warp_sample(data, cond, marg, h, w, k, ux, uy, out):  # pragma: no cover - compiled
    """Per sample ``s``: the warp of ``(ux[s], uy[s])`` (clipped to [0, 1]) in slice
    ``k[s]`` of the flat tables ``data``, ``cond`` (slice × row × column) and ``marg``
    (slice × row) into ``out[s] = (x, y)`` in [0, 1]²."""
    for s in range(k.shape[0]):
        base_m = k[s] * h
        target_y = uy[s]
        lo, hi = -1, h  # the last row of the marginal CDF at or below uy (bisection)
        while hi - lo > 1:
            mid = (lo + hi) // 2
            if marg[base_m + min(max(mid, 0), h - 1)] <= target_y:
                lo = mid
            else:
                hi = mid
        py = min(max(lo, 0), h - 2)
        row0 = (base_m + py) * w
        row1 = row0 + w
        r0 = cond[row0 + (w - 1)]
        r1 = cond[row1 + (w - 1)]
        sy = _solve_quadratic(r0, r1, target_y - marg[base_m + py])
        total = (1 - sy) * r0 + sy * r1
        target = ux[s] * total
        lo, hi = -1, w  # the last column of the interpolated conditional CDF at or below the target
        while hi - lo > 1:
            mid = (lo + hi) // 2
            col = min(max(mid, 0), w - 1)
            if (1 - sy) * cond[row0 + col] + sy * cond[row1 + col] <= target:
                lo = mid
            else:
                hi = mid
        px = min(max(lo, 0), w - 2)
        c0 = (1 - sy) * data[row0 + px] + sy * data[row1 + px]
        c1 = (1 - sy) * data[row0 + px + 1] + sy * data[row1 + px + 1]
        base = (1 - sy) * cond[row0 + px] + sy * cond[row1 + px]
        sx = _solve_quadratic(c0, c1, target - base)
        out[s, 0] = (px + sx) / (w - 1)
        out[s, 1] = (py + sy) / (h - 1)


@njit(**_OPTS)
def bilinear_one_slice(table, h, w, px, py, out):  # pragma: no cover - compiled
    """Bilinear lookup of one ``h × w`` table (flat, row-major) at ``(px[s], py[s])`` in
    [0, 1]² (x: column, y: row; clipped): :meth:`reflecto.sources.rgl.Marginal2D.eval`
    of a table with one parameter slice, the same arithmetic in the same order."""
    for s in range(px.shape[0]):
        x = min(max(px[s], 0.0), 1.0) * (w - 1)
        y = min(max(py[s], 0.0), 1.0) * (h - 1)
        x0 = min(int(x), w - 2)
        y0 = min(int(y), h - 2)
        fx = x - x0
        fy = y - y0
        r0 = y0 * w + x0
        r1 = r0 + w
        out[s] = (1 - fy) * ((1 - fx) * table[r0] + fx * table[r0 + 1]) + fy * (
            (1 - fx) * table[r1] + fx * table[r1 + 1])
