"""Compiled loop of the tilt's least squares (:class:`reflecto.reconstruct.normal.TiltProblem`).

Its NumPy reference is :meth:`TiltProblem.residuals_numpy` (finite differences for the
tilt's derivatives), which the tests compare it with.
"""

from __future__ import annotations

import math
from typing import Any

from numba import njit

_OPTS: dict[str, Any] = dict(cache=True, nogil=True, fastmath=False, error_model="numpy")


@njit(inline="always", **_OPTS)
def _projected_area(c, sig_step, sig_vals):  # pragma: no cover - compiled
    """``σ = max(σ_D(θ), cos θ)`` at ``c = max(l·n, 1e-6)`` (:meth:`IsotropicNDF.projected_area`:
    ``σ_D`` linear in θ on a uniform grid of step ``sig_step`` from 0) and ``dσ/dc``."""
    cc = min(max(c, 0.0), 1.0)
    th = math.acos(cc)
    n = sig_vals.shape[0]
    u = th / sig_step
    k = min(int(u), n - 2)
    f = min(max(u - k, 0.0), 1.0)
    sig = (1.0 - f) * sig_vals[k] + f * sig_vals[k + 1]
    if sig > cc:
        s = math.sqrt(max(1.0 - cc * cc, 1e-300))
        return sig, -(sig_vals[k + 1] - sig_vals[k]) / sig_step / s
    return cc, 1.0


@njit(inline="always", **_OPTS)
def _cosines(dirs, n, dn, sig_step, sig_vals, jacobian):  # pragma: no cover - compiled
    """Per direction ``d`` (rows of ``dirs``): ``c = max(d·n, 10⁻⁶)``, ``σ(c)``
    (:func:`_projected_area`), and with ``jacobian`` ``∂c/∂t_q = d·dn[q]`` and
    ``∂σ/∂t_q`` (0 where ``d·n`` is clamped), shapes ``(M,)``, ``(M,)``, ``(M, 2)``, ``(M, 2)``."""
    m = dirs.shape[0]
    c_out = dirs[:, 0] * 0.0
    s_out = c_out.copy()
    dc_out = dirs[:, :2] * 0.0
    ds_out = dirs[:, :2] * 0.0
    for a in range(m):
        c = dirs[a, 0] * n[0] + dirs[a, 1] * n[1] + dirs[a, 2] * n[2]
        c_out[a] = max(c, 1e-6)
        sig, dsig = _projected_area(c_out[a], sig_step, sig_vals)
        s_out[a] = sig
        if jacobian and c > 1e-6:
            for q in range(2):
                d = dirs[a, 0] * dn[q, 0] + dirs[a, 1] * dn[q, 1] + dirs[a, 2] * dn[q, 2]
                dc_out[a, q] = d
                ds_out[a, q] = dsig * d
    return c_out, s_out, dc_out, ds_out


@njit(**_OPTS)
def theta_cells(theta_h, nodes, cell_table, z, j_out, t_out, log_d_out):  # pragma: no cover - compiled
    """The cell ``j`` (``nodes[j] ≤ θ < nodes[j+1]``) and weight ``t`` of each ``θ_h``,
    and ``log D = (1 − t) z[j] + t z[j + 1]`` (capped at 700). ``cell_table`` holds the
    cell of equal steps of ``[0, nodes[-1])``, a first guess moved up node by node."""
    n_cells = nodes.shape[0] - 1
    n_table = cell_table.shape[0]
    scale = n_table / nodes[n_cells]
    for b in range(theta_h.shape[0]):
        th = theta_h[b]
        lo = cell_table[min(max(int(th * scale), 0), n_table - 1)]
        while lo + 1 < n_cells and nodes[lo + 1] <= th:
            lo += 1
        t = min(max((th - nodes[lo]) / (nodes[lo + 1] - nodes[lo]), 0.0), 1.0)
        j_out[b] = lo
        t_out[b] = t
        log_d_out[b] = min((1.0 - t) * z[lo] + t * z[lo + 1], 700.0)


@njit(**_OPTS)
def tilt_pass(lights, views, led, pix, half, cos_h, theta_h, d_h, f_dev, fresnel, weight, nodes, z, kd,
              sig_step, sig_vals, n, dn, cos_power, min_light_cos, min_view_cos, fix_use, use, jacobian,
              j_out, r_out, spec_out, w_out, dr_out):  # pragma: no cover - compiled
    """Residuals of the tilt's least squares at the normal ``n`` and their weighted cost.

    For sample ``b`` (LED ``l = led[b]``, view ``v = views[pix[b]]``, half vector
    ``h = half[b]``) with ``c_i = max(l·n, 10⁻⁶)``, ``c_o = max(v·n, 10⁻⁶)``:

    ``r_b = k_d/π + F_b D_b / (4 σ(c_i) σ(c_o)) − f_b / c_i``

    where ``cos_h = h·n``, ``theta_h = arccos(h·n)``, ``d_h = e^{z(θ_h)}`` and its cell
    ``j_out`` come from :func:`theta_cells` (the arccos and the exponential are taken
    vectorized by NumPy), and ``σ`` is :func:`_projected_area` of the NDF's table
    ``sig_vals`` (step ``sig_step``). The weight is ``w_b = weight_b (l·n)^cos_power``
    where the sample takes part (``c_i > min_light_cos`` and ``c_o > min_view_cos``;
    with ``fix_use`` the given ``use`` mask instead, else written to it), 0 elsewhere.
    Writes ``r_out``, ``spec_out`` (the specular part) and ``w_out``; with
    ``jacobian`` also ``dr_out[b, q] = ∂r_b/∂t_q`` for the tilt offsets ``t_q`` along
    ``dn[q] = ∂n/∂t_q`` (analytic, ``log D`` linear in θ_h within its cell). Returns
    ``Σ w r²``.
    """
    ci_l, si_l, dci_l, dsi_l = _cosines(lights, n, dn, sig_step, sig_vals, True)
    co_p, so_p, _, dso_p = _cosines(views, n, dn, sig_step, sig_vals, jacobian)
    n_cells = nodes.shape[0] - 1
    kd_pi = kd / math.pi
    cost = 0.0
    for b in range(r_out.shape[0]):
        a = led[b]
        p = pix[b]
        lo = j_out[b]
        spec = fresnel[b] * d_h[b] / (4.0 * si_l[a] * so_p[p])
        ci = ci_l[a]
        r = kd_pi + spec - f_dev[b] / ci
        if fix_use:
            ok = use[b]
        else:
            ok = ci > min_light_cos and co_p[p] > min_view_cos
            use[b] = ok
        w = 0.0
        if ok:
            lc = lights[a, 0] * n[0] + lights[a, 1] * n[1] + lights[a, 2] * n[2]
            w = weight[b] * (lc * lc if cos_power == 2.0 else (1.0 if cos_power == 0.0 else lc ** cos_power))
        r_out[b] = r
        spec_out[b] = spec
        w_out[b] = w
        cost += w * r * r
        if jacobian:
            th = theta_h[b]
            slope = (z[lo + 1] - z[lo]) / (nodes[lo + 1] - nodes[lo]) if th <= nodes[n_cells] else 0.0
            sh = math.sqrt(max(1.0 - cos_h[b] * cos_h[b], 0.0))
            for q in range(2):
                hd = half[b, 0] * dn[q, 0] + half[b, 1] * dn[q, 1] + half[b, 2] * dn[q, 2]
                dth = -hd / sh if sh > 0.0 else 0.0
                dr_out[b, q] = (spec * (slope * dth - dsi_l[a, q] / si_l[a] - dso_p[p, q] / so_p[p])
                                + f_dev[b] * dci_l[a, q] / (ci * ci))
    return cost
