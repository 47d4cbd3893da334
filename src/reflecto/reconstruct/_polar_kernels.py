"""Compiled loops of the isotropic fit (:mod:`reflecto.reconstruct.isotropic`).

Each has a NumPy reference in that module (``*_numpy``) that the tests compare it with.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit

from .._kernels import _fresnel

_OPTS: dict[str, Any] = dict(cache=True, nogil=True, fastmath=False, error_model="numpy")


@njit(**_OPTS)
def bin_polar(mask, light, view, values, noise, bound, edges, cell_table, td_step, n_td, td_cos, td_table,
              count, sums, out_f):  # pragma: no cover
    """Accumulate the samples where ``mask`` (L, P) holds into (LED, θ_h cell, θ_d cell) bins.

    For LED ``l`` and pixel ``p``: ``h = normalize(i + o)``, its θ_h cell ``j``
    (``edges[j] ≤ θ_h < edges[j+1]``: ``cell_table``'s first guess, :func:`reflecto.polar.cell_table`,
    moved up to it) and θ_d cell ``min(⌊arccos(c) / td_step⌋, n_td − 1)`` (:func:`_theta_d_cell`); the
    bin is ``(l · (len(edges) − 1) + j) · n_td + k``. ``count`` (keys,) receives the
    pixel count, ``sums`` (keys, 5) the sums of θ_h, ``c = cos θ_d``, ``cos θ_o``, the
    noise variance ``noise²`` and ``bound``, ``out_f`` (keys, 3) the sums of ``f``.
    ``noise`` and ``bound`` are (L, P) (zeros where the slices carry none).
    """
    n_cells = edges.shape[0] - 1
    n_table = cell_table.shape[0]
    table_scale = n_table / edges[n_cells]
    for l in range(mask.shape[0]):
        ix, iy, iz = light[l, 0], light[l, 1], light[l, 2]
        for p in range(mask.shape[1]):
            if not mask[l, p]:
                continue
            hx = ix + view[p, 0]
            hy = iy + view[p, 1]
            hz = iz + view[p, 2]
            nrm = math.sqrt(hx * hx + hy * hy + hz * hz)
            hz /= nrm
            th = math.acos(min(max(hz, -1.0), 1.0))
            c = min(max((ix * hx + iy * hy) / nrm + iz * hz, 0.0), 1.0)
            lo = cell_table[min(int(th * table_scale), n_table - 1)]
            while lo + 1 < n_cells and edges[lo + 1] <= th:
                lo += 1
            k = _theta_d_cell(c, td_step, n_td, td_cos, td_table)
            key = (l * n_cells + lo) * n_td + k
            count[key] += 1.0
            sums[key, 0] += th
            sums[key, 1] += c
            sums[key, 2] += view[p, 2]
            sums[key, 3] += noise[l, p] * noise[l, p]
            sums[key, 4] += bound[l, p]
            out_f[key, 0] += values[l, p, 0]
            out_f[key, 1] += values[l, p, 1]
            out_f[key, 2] += values[l, p, 2]


#: Distance in ``cos θ_d`` from a θ_d cell's edge within which :func:`_theta_d_cell` takes
#: the arccos: ≥ 10⁻¹² rad of angle, ten thousand times arccos's and the division's
#: rounding (≈ 10⁻¹⁶), so outside it the comparison decides exactly as the arccos would.
TD_EDGE_MARGIN = 1e-12


@njit(inline="always", **_OPTS)
def _theta_d_cell(c, td_step, n_td, td_cos, td_table):  # pragma: no cover - compiled
    """``min(⌊arccos(c) / td_step⌋, n_td − 1)`` for ``c ∈ [0, 1]``, mostly without the arccos.

    ``td_cos[j] = cos(j · td_step)`` (``j = 0 … n_td``) are the cells' edges in ``c``: cell
    ``j`` holds ``td_cos[j + 1] < c ≤ td_cos[j]``. ``td_table[i]`` is the cell of
    ``c = i / len(td_table)``, a step finer than the narrowest cell, so ``c``'s cell is
    that or the one below. Where ``c`` lies within :data:`TD_EDGE_MARGIN` of an edge the
    arccos decides: the cells are those of the arccos everywhere.
    """
    n_tab = td_table.shape[0]
    k = td_table[min(int(c * n_tab), n_tab - 1)]
    if k > 0 and c > td_cos[k]:
        k -= 1
    if abs(c - td_cos[k]) < TD_EDGE_MARGIN or abs(c - td_cos[k + 1]) < TD_EDGE_MARGIN:
        return min(int(math.acos(c) / td_step), n_td - 1)
    return min(k, n_td - 1)


@njit(inline="always", **_OPTS)
def _accumulate_bin(k, tb, spec, cols, wb, r, diag, off, cross, dense, grad_z, grad_d):  # pragma: no cover
    """Add one residual ``r`` (weight ``wb``) to the normal equations: its z columns
    ``spec (1 − tb)``, ``spec tb`` at nodes ``k``, ``k + 1`` and its dense columns
    ``cols`` (D,); the dense block's upper triangle only (mirrored at the end)."""
    a0 = spec * (1.0 - tb)
    a1 = spec * tb
    wr = wb * r
    diag[k] += wb * a0 * a0
    diag[k + 1] += wb * a1 * a1
    off[k] += wb * a0 * a1
    grad_z[k] += a0 * wr
    grad_z[k + 1] += a1 * wr
    n_d = cols.shape[0]
    for q in range(n_d):
        cq = cols[q] * wb
        cross[k, q] += a0 * cq
        cross[k + 1, q] += a1 * cq
        grad_d[q] += cols[q] * wr
        for u in range(q, n_d):
            dense[q, u] += cq * cols[u]


@njit(inline="always", **_OPTS)
def _zero(diag, off, cross, dense, grad_z, grad_d):  # pragma: no cover - compiled
    """Zero the normal equations' blocks and gradients before they are accumulated."""
    diag[:] = 0.0
    off[:] = 0.0
    cross[:, :] = 0.0
    dense[:, :] = 0.0
    grad_z[:] = 0.0
    grad_d[:] = 0.0


@njit(inline="always", **_OPTS)
def _mirror_dense(dense):  # pragma: no cover - compiled
    """Fill the dense block's lower triangle from its upper one."""
    for q in range(dense.shape[0]):
        for u in range(q):
            dense[q, u] = dense[u, q]


@njit(**_OPTS)
def normal_equations(j, t, spec, dcols, r, w, n_nodes, diag, off, cross, dense, grad_z, grad_d):  # pragma: no cover
    """Gauss–Newton normal equations of the luminance fit, ``JᵀWJ`` and ``JᵀWr``.

    Residual ``b`` depends on the log-NDF nodes ``j[b]``, ``j[b] + 1`` through
    ``∂r/∂z = spec[b] (1 − t[b])``, ``spec[b] t[b]`` and on the dense parameters
    through ``dcols[b, :]``. Writes the tridiagonal z block (``diag`` (K,), ``off``
    (K − 1,)), the z–dense block ``cross`` (K, D), the dense block ``dense`` (D, D)
    and the gradients ``grad_z`` (K,), ``grad_d`` (D,). ``w`` is 0 for inactive residuals.
    """
    _zero(diag, off, cross, dense, grad_z, grad_d)
    for b in range(r.shape[0]):
        wb = w[b]
        if wb == 0.0:
            continue
        _accumulate_bin(j[b], t[b], spec[b], dcols[b], wb, r[b], diag, off, cross, dense, grad_z, grad_d)
    _mirror_dense(dense)


@njit(inline="always", **_OPTS)
def _bin_model(k, tb, z, geometry_b, cos_d_b, f_b, measured_b, kd, g, eta):  # pragma: no cover - compiled
    """One bin of the luminance fit: ``(r, spec, F, active)`` with ``spec = g F(c; η) e^{z(θ)} G``
    (``z`` interpolated in cell ``k`` at weight ``tb``, its exponent capped at 700),
    ``r = k_d/π + spec − f`` and ``active`` unless the bin is a bound the model stays under."""
    lz = (1.0 - tb) * z[k] + tb * z[k + 1]
    if lz > 700.0:
        lz = 700.0
    fr = _fresnel(cos_d_b, eta)
    spec = g * fr * math.exp(lz) * geometry_b
    r = kd / math.pi + spec - f_b
    return r, spec, fr, measured_b or r > 0.0


@njit(**_OPTS)
def luminance_pass(j, t, z, shadow_geometry, cos_d, f, w, measured, kd, g, eta, r_out, spec_out, fr_out,
                   active_out):  # pragma: no cover - compiled
    """One pass of the luminance fit over the bins: residuals and the weighted cost.

    ``m_b = k_d/π + g F(c_b; η) e^{z(θ_b)} G_b`` with ``z`` interpolated at ``(j, t)`` and
    ``G_b = S_b / (4 cos θ_i cos θ_o)`` (``shadow_geometry``); ``r_b = m_b − f_b``,
    one-sided (``max(0, r_b)``) where ``measured[b]`` is False. Writes ``r_out`` (0 where
    inactive), the specular part ``spec_out``, ``F`` (``fr_out``) and ``active_out``, which
    :func:`pass_normal_equations` takes at the same state; returns ``Σ w r²``.
    """
    cost = 0.0
    for b in range(r_out.shape[0]):
        r, spec, fr, active = _bin_model(j[b], t[b], z, shadow_geometry[b], cos_d[b], f[b], measured[b], kd, g, eta)
        if not active:
            r = 0.0
        r_out[b] = r
        spec_out[b] = spec
        fr_out[b] = fr
        active_out[b] = active
        cost += w[b] * r * r
    return cost


@njit(inline="always", **_OPTS)
def _eta_column(cos_d_b, eta, de, finite_eta, spec, fr):  # pragma: no cover - compiled
    """``∂r/∂ log(η − 1) = spec (∂F/∂η)/F (η − 1)``, ``∂F/∂η`` a forward difference of step ``de``."""
    if not finite_eta:
        return 0.0
    dfr = (_fresnel(cos_d_b, eta + de) - fr) / de
    return spec * dfr / (fr if fr > 0.0 else 1e-300) * (eta - 1.0)


@njit(**_OPTS)
def pass_normal_equations(j, t, cos_d, r, spec, fr, active, w, eta, n_nodes, diag, off, cross, dense, grad_z,
                          grad_d):  # pragma: no cover - compiled
    """The Gauss–Newton normal equations of the luminance fit at the state of the last
    :func:`luminance_pass`, from the values it stored (``r``, ``spec``, ``F``, ``active``):
    each active bin's η column ``∂r/∂ log(η − 1) = spec (∂F/∂η)/F (η − 1)`` (a forward
    difference of step ``10⁻⁶ η``; 0 for the constant Fresnel ``η = ∞``), accumulated as
    :func:`normal_equations` does for the columns ``[1/π, spec, η]`` with the weight ``w``
    (inactive bins: 0)."""
    _zero(diag, off, cross, dense, grad_z, grad_d)
    de = 1e-6 * eta
    finite_eta = math.isfinite(eta)
    col = np.empty(3)
    col[0] = 1.0 / math.pi
    for b in range(j.shape[0]):
        if not active[b]:
            continue
        deta = _eta_column(cos_d[b], eta, de, finite_eta, spec[b], fr[b])
        wb = w[b]
        if wb == 0.0:
            continue
        col[1] = spec[b]
        col[2] = deta
        _accumulate_bin(j[b], t[b], spec[b], col, wb, r[b], diag, off, cross, dense, grad_z, grad_d)
    _mirror_dense(dense)
