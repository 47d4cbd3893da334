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


@njit(inline="always", **_OPTS)
def _ndf_integral(q_cells, q_t, q_weights, z):  # pragma: no cover - compiled
    """``N = Σ_q w_q e^{z(θ_q)}`` over the polar quadrature (the exponent capped at 700)."""
    n = 0.0
    for q in range(q_cells.shape[0]):
        lz = (1.0 - q_t[q]) * z[q_cells[q]] + q_t[q] * z[q_cells[q] + 1]
        n += q_weights[q] * math.exp(min(lz, 700.0))
    return n


@njit(inline="always", **_OPTS)
def _lm_cost(j, t, z, shadow_geometry, cos_d, f, w, measured, kd, g, eta, h, beta, prior_constant, r, spec, fr,
             active):  # pragma: no cover - compiled
    """The luminance fit's cost ``Σ w r² + zᵀHz − 2βᵀz + c`` (one :func:`luminance_pass`); ``inf`` if not finite."""
    c = luminance_pass(j, t, z, shadow_geometry, cos_d, f, w, measured, kd, g, eta, r, spec, fr, active)
    c += np.dot(np.dot(z, h), z) - 2.0 * np.dot(beta, z) + prior_constant
    return c if math.isfinite(c) else math.inf


@njit(inline="always", **_OPTS)
def _lm_system(j, t, cos_d, r, spec, fr, active, w, eta, z, h, beta, q_cells, q_t, q_weights, tie_ks):
    # pragma: no cover - compiled
    """``JᵀWJ + H`` and ``JᵀWr + Hz − β`` over ``(z, k_d, log g, log(η − 1))`` from the last
    pass's values; with ``tie_ks`` the ``log g`` column folded into ``z`` through ``∂ log N/∂z``."""
    k = z.shape[0]
    diag, off = np.empty(k), np.empty(k - 1)
    cross, dense = np.empty((k, 3)), np.empty((3, 3))
    gz, gd = np.empty(k), np.empty(3)
    pass_normal_equations(j, t, cos_d, r, spec, fr, active, w, eta, k, diag, off, cross, dense, gz, gd)
    a = np.zeros((k + 3, k + 3))
    for i in range(k):
        a[i, i] = diag[i]
    for i in range(k - 1):
        a[i, i + 1] = off[i]
        a[i + 1, i] = off[i]
    for i in range(k):
        for q in range(3):
            a[i, k + q] = cross[i, q]
            a[k + q, i] = cross[i, q]
    for q in range(3):
        for u in range(3):
            a[k + q, k + u] = dense[q, u]
    grad = np.empty(k + 3)
    grad[:k] = gz
    grad[k:] = gd
    if tie_ks:
        n_total = _ndf_integral(q_cells, q_t, q_weights, z)
        dn = np.zeros(k)
        if math.isfinite(n_total) and n_total > 0.0:
            for q in range(q_cells.shape[0]):
                lz = (1.0 - q_t[q]) * z[q_cells[q]] + q_t[q] * z[q_cells[q] + 1]
                wd = q_weights[q] * math.exp(min(lz, 700.0))
                dn[q_cells[q]] += wd * (1.0 - q_t[q])
                dn[q_cells[q] + 1] += wd * q_t[q]
            dn /= n_total
        cg = a[:k, k + 1].copy()
        agg = a[k + 1, k + 1]
        for i in range(k):
            for u in range(k):
                a[i, u] += -dn[i] * cg[u] - cg[i] * dn[u] + agg * dn[i] * dn[u]
        for i in range(k):
            a[i, k] -= dn[i] * a[k + 1, k]
            a[i, k + 2] -= dn[i] * a[k + 1, k + 2]
            a[k, i] = a[i, k]
            a[k + 2, i] = a[i, k + 2]
            grad[i] -= dn[i] * grad[k + 1]
    hz = np.dot(h, z)
    ridge = 1e-12 * max(diag.max(), 1e-300)  # the z level and g are one degree of freedom
    for i in range(k):
        grad[i] += hz[i] - beta[i]
        for u in range(k):
            a[i, u] += h[i, u] + ridge
    return a, grad


@njit(**_OPTS)
def luminance_lm(j, t, shadow_geometry, cos_d, f, w, measured, h, beta, prior_constant, q_cells, q_t, q_weights,
                 z0, kd, g, eta, fix_eta, tie_ks, fix_kd, eta_min, eta_max, max_iterations, tolerance, r, spec, fr,
                 active):  # pragma: no cover - compiled
    """Levenberg–Marquardt of the luminance fit on ``(z, k_d, log g, log(η − 1))``, the
    loop of :func:`reflecto.reconstruct.isotropic.solve_numpy` (its reference) in one call.

    Each iteration: the normal equations at the state (:func:`_lm_system`), the frozen
    parameters (η held or at a bound it is pushed past, ``k_d`` at 0 pushed below, the
    ``log g`` column under ``tie_ks``) as identity rows, then trial steps
    ``(A + μ diag A) δ = −g`` with μ ×8 until the cost falls (μ /5 on success); the step
    is renormalized so that ``∫ e^z cos = 1`` (``g`` absorbs the level), ``η`` moves by
    ``e^{clip(δ, ±2)}`` on ``η − 1`` within ``[eta_min, eta_max]``, ``g`` by
    ``e^{clip(δ, ±3)}``. Ends when no step lowers the cost or the relative decrease
    is below ``tolerance``. Returns ``(z, k_d, g, η, cost)``; ``r``, ``spec``, ``fr``,
    ``active`` hold the last pass's values.
    """
    k = z0.shape[0]
    z = z0.copy()
    if tie_ks:
        n0 = _ndf_integral(q_cells, q_t, q_weights, z)
        z = z - math.log(n0)
        g = 1.0
    cost = _lm_cost(j, t, z, shadow_geometry, cos_d, f, w, measured, kd, g, eta, h, beta, prior_constant, r, spec,
                    fr, active)
    mu = 1e-3
    for _ in range(max_iterations):
        a, grad = _lm_system(j, t, cos_d, r, spec, fr, active, w, eta, z, h, beta, q_cells, q_t, q_weights, tie_ks)
        frozen = np.zeros(k + 3, dtype=np.bool_)
        frozen[k + 2] = fix_eta or (eta >= eta_max and grad[k + 2] < 0) or (eta <= eta_min and grad[k + 2] > 0)
        frozen[k] = fix_kd or (kd <= 0.0 and grad[k] > 0)
        frozen[k + 1] = tie_ks
        for q in range(k, k + 3):
            if frozen[q]:
                a[q, :] = 0.0
                a[:, q] = 0.0
                a[q, q] = 1.0
                grad[q] = 0.0
        dg = np.empty(k + 3)
        for i in range(k + 3):
            dg[i] = a[i, i]
        dg += 1e-12 * dg.max()
        improved = False
        rel = 0.0
        while mu < 1e10:
            m = a.copy()
            for i in range(k + 3):
                m[i, i] += mu * dg[i]
            try:
                step = -np.linalg.solve(m, grad)
            except Exception:  # singular or not finite: a larger damping
                mu *= 8.0
                continue
            zt = z + step[:k]
            n = _ndf_integral(q_cells, q_t, q_weights, zt)
            c = math.inf
            if math.isfinite(n) and n > 0.0:
                zt -= math.log(n)
                et = eta
                if math.isfinite(eta):
                    et = min(max(1.0 + (eta - 1.0) * math.exp(min(max(step[k + 2], -2.0), 2.0)), eta_min), eta_max)
                gt = 1.0 if tie_ks else g * n * math.exp(min(max(step[k + 1], -3.0), 3.0))
                kt = max(kd + step[k], 0.0)
                c = _lm_cost(j, t, zt, shadow_geometry, cos_d, f, w, measured, kt, gt, et, h, beta, prior_constant,
                             r, spec, fr, active)
            if math.isfinite(c) and c < cost:
                rel = (cost - c) / cost
                z, kd, g, eta, cost = zt, kt, gt, et, c
                mu = max(mu / 5.0, 1e-9)
                improved = True
                break
            mu *= 8.0
        if not improved or rel < tolerance:
            break
    return z, kd, g, eta, cost
