"""Compiled (Numba) kernels for the hot loops that NumPy cannot fuse.

Each kernel is a per-sample loop over exactly the arithmetic of the NumPy reference
implementation it replaces (named in its docstring); tests compare the two. Added
because ``benchmarks/bench_model.py`` showed the NumPy model evaluation at
0.51–0.59 s per 1M pairs (target 0.5 s): the time went into temporaries of the
hemicube and σ lookups, which a fused loop does not allocate.

All kernels are single-threaded (``parallel`` is left off so results and timings do
not depend on the core count); batch-level parallelism lives in the CLI.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit

_OPTS: dict[str, Any] = dict(cache=True, nogil=True, fastmath=False, error_model="numpy")


@njit(inline="always", **_OPTS)
def _unit(x, y, z):
    """``(x, y, z) / |(x, y, z)|``, or zeros for the zero vector."""
    n = math.sqrt(x * x + y * y + z * z)
    if n > 0.0:
        return x / n, y / n, z / n
    return 0.0, 0.0, 0.0


@njit(inline="always", **_OPTS)
def _face_coords(x: float, y: float, z: float, n: int) -> tuple[int, float, float]:
    """Face and continuous texel coordinates: :meth:`Hemicube._face_coords_xyz`."""
    if z < 0.0:
        z = 0.0
    ax, ay = abs(x), abs(y)
    m = max(ax, ay)
    half_n = 0.5 * n - 0.5
    if z >= m:
        inv = 0.5 * n / (z if z > 0.0 else 1.0)
        return 0, x * inv + half_n, y * inv + half_n
    inv = 0.5 * n / (m if m > 0.0 else 1.0)
    if ax >= ay:
        return (2 if x < 0.0 else 1), y * inv + half_n, z * inv - 0.5
    return (4 if y < 0.0 else 3), x * inv + half_n, z * inv - 0.5


@njit(inline="always", **_OPTS)
def _cube_lookup(padded, pad_offsets, n: int, x: float, y: float, z: float) -> float:
    """Bilinear lookup in padded faces: :meth:`Hemicube.lookup` for one direction."""
    face, col, row = _face_coords(x, y, z, n)
    col += 1.0
    row += 1.0
    ci = int(col)
    ri = int(row)
    fc = col - ci
    fr = row - ri
    if ci > n:
        ci = n
    width = n + 2
    return _bilinear(padded, ri * width + ci + pad_offsets[face], width, fc, fr)


@njit(inline="always", **_OPTS)
def _bilinear(padded, base: int, width: int, fc: float, fr: float) -> float:
    """Bilinear blend of the 2×2 padded texels from ``base`` (row stride ``width``)."""
    v00 = padded[base]
    v01 = padded[base + 1]
    v10 = padded[base + width]
    v11 = padded[base + width + 1]
    a = v00 + (v01 - v00) * fc
    b = v10 + (v11 - v10) * fc
    return a + (b - a) * fr


@njit(inline="always", **_OPTS)
def _sigma_lookup(flat, nt: int, nphi: int, x: float, y: float, z: float) -> float:
    """Bilinear σ(θ, φ): :meth:`SigmaTable.eval_sigma` for one direction."""
    zc = min(max(z, 0.0), 1.0)
    t = math.acos(zc) * ((nt - 1) / (0.5 * math.pi))
    p = math.atan2(y, x) * (nphi / (2.0 * math.pi)) + nphi
    t0 = min(int(t), nt - 2)
    p0 = int(p)
    ft = t - t0
    fp = p - p0
    p0 %= nphi
    w = nphi + 1
    idx = t0 * w + p0
    s00 = flat[idx]
    s01 = flat[idx + 1]
    s10 = flat[idx + w]
    s11 = flat[idx + w + 1]
    s00 += fp * (s01 - s00)
    s10 += fp * (s11 - s10)
    return s00 + ft * (s10 - s00)


@njit(**_OPTS)
def shadowing_at(flat, w, idx, ft, fp, cos, out):
    """``S = cos/max(σ, cos)`` from precomputed σ-grid cells: :meth:`SigmaTable.eval_at`."""
    for k in range(idx.shape[0]):
        j = idx[k]
        s00 = flat[j]
        s10 = flat[j + w]
        s00 += fp[k] * (flat[j + 1] - s00)
        s10 += fp[k] * (flat[j + w + 1] - s10)
        s00 += ft[k] * (s10 - s00)
        s = max(s00, cos[k])
        out[k] = cos[k] / s if s > 0.0 else 0.0


@njit(inline="always", **_OPTS)
def _polar_shadowing(sigma, theta_s, cell: int, offset: float, c: float) -> float:
    """``S = c/max(σ(θ), c)`` with ``σ(θ)`` as ``np.interp(θ, theta_s, sigma)`` takes it at
    ``θ = theta_s[cell] + offset`` (the node itself where ``offset`` is 0, as NumPy avoids a
    non-finite slope there, or where ``cell`` is the last; else ``slope · offset + σ[cell]``,
    the slope ``(σ[j+1] − σ[j])/(θ[j+1] − θ[j])``)."""
    if cell == sigma.shape[0] - 1 or offset == 0.0:
        sig = sigma[cell]
    else:
        sig = (sigma[cell + 1] - sigma[cell]) / (theta_s[cell + 1] - theta_s[cell]) * offset + sigma[cell]
    s = sig if (sig >= c or sig != sig) else c  # np.maximum's: a NaN σ propagates (then S is 0)
    return c / s if s > 0.0 else 0.0


@njit(**_OPTS)
def pair_shadowing(sigma, theta_s, cell_i, offset_i, cos_i, cell_o, offset_o, cos_o, correlated, geometry,
                   out, out_geometry):
    """The pair's shadowing ``S_i S_o`` (or with ``correlated`` ``S_i S_o/(S_i + S_o − S_i S_o)``,
    0 where either is 0) and its product with ``geometry``: :meth:`reflecto.polar.IsotropicNDF.pair_shadowing`
    (the NumPy reference: ``IsotropicNDF.shadowing`` of each direction)."""
    for k in range(cell_i.shape[0]):
        si = _polar_shadowing(sigma, theta_s, cell_i[k], offset_i[k], cos_i[k])
        so = _polar_shadowing(sigma, theta_s, cell_o[k], offset_o[k], cos_o[k])
        if correlated:
            v = si * so / (si + so - si * so) if (si > 0.0 and so > 0.0) else 0.0
        else:
            v = si * so
        out[k] = v
        out_geometry[k] = v * geometry[k]


@njit(**_OPTS)
def cube_lookup(padded, pad_offsets, n, dirs, out):
    """``out[k] = lookup(dirs[k])`` for directions of shape ``(M, 3)``."""
    for k in range(dirs.shape[0]):
        out[k] = _cube_lookup(padded, pad_offsets, n, dirs[k, 0], dirs[k, 1], dirs[k, 2])


@njit(**_OPTS)
def upsample(padded, pad_offsets, n, m, out):
    """Bilinear lookup of an ``n``-hemicube at every texel centre of the ``m·n`` one.

    On each face the fine texel centres sit at coarse texel coordinates
    ``(k + ½)/m − ½``, so this is :meth:`Hemicube.lookup` at ``hemicube(m·n).directions``
    without the per-direction projection.
    """
    _upsample(padded, pad_offsets, n, m, out, out, out, -1.0)


@njit(**_OPTS)
def pull(padded, pad_offsets, n, w_fine, v_fine, min_weight, out):
    """One push–pull step up: ``v/w`` where ``w > min_weight``, else the 2× upsampled coarse estimate."""
    _upsample(padded, pad_offsets, n, 2, w_fine, v_fine, out, min_weight)


@njit(inline="always", **_OPTS)
def _upsample(padded, pad_offsets, n, m, w_fine, v_fine, out, min_weight):
    """:func:`upsample`; with ``min_weight ≥ 0``, texels with ``w_fine > min_weight`` take ``v/w``."""
    nf = m * n
    width = n + 2
    cell = np.empty(nf, dtype=np.int64)  # padded coarse index and weight of fine index k
    frac = np.empty(nf)
    for k in range(nf):
        x = (k + 0.5) / m - 0.5 + 1.0
        cell[k] = min(int(x), n)
        frac[k] = x - int(x)
    t = 0
    for face in range(5):
        rows = nf if face == 0 else nf // 2
        base_face = pad_offsets[face]
        for r in range(rows):
            row_base = base_face + cell[r] * width
            fr = frac[r]
            for c in range(nf):
                if min_weight >= 0.0 and w_fine[t] > min_weight:
                    out[t] = v_fine[t] / w_fine[t]
                    t += 1
                    continue
                out[t] = _bilinear(padded, row_base + cell[c], width, frac[c], fr)
                t += 1


@njit(**_OPTS)
def mirror_distances(t, vt, e1, e2, psis, pad_v, pad_has, pad_offsets, n, out):
    """Symmetry distance of a slice per plane angle: :func:`reconstruct.symmetry.plane_offset`.

    Texel directions ``t`` (M, 3) with values ``vt`` are mirrored across the plane with
    normal ``cos ψ e2 + sin ψ e1`` for every ψ; only texels whose mirror image lands on
    data (``pad_has`` ≥ 0.999) for every ψ count. ``out[j]`` = mean squared difference
    over them divided by the mean of ``vt²`` over them; all ``inf`` if fewer than 50.
    """
    m, n_psi = t.shape[0], psis.shape[0]
    keep = np.ones(m, dtype=np.bool_)
    mirrored = np.empty((n_psi, m, 3))
    for j in range(n_psi):
        c, s = math.cos(psis[j]), math.sin(psis[j])
        ux, uy, uz = c * e2[0] + s * e1[0], c * e2[1] + s * e1[1], c * e2[2] + s * e1[2]
        for k in range(m):
            d = 2.0 * (t[k, 0] * ux + t[k, 1] * uy + t[k, 2] * uz)
            x, y, z = t[k, 0] - d * ux, t[k, 1] - d * uy, max(t[k, 2] - d * uz, 1e-9)
            mirrored[j, k, 0], mirrored[j, k, 1], mirrored[j, k, 2] = x, y, z
            if keep[k] and _cube_lookup(pad_has, pad_offsets, n, x, y, z) <= 0.999:
                keep[k] = False
    count = 0
    scale = 0.0
    for k in range(m):
        if keep[k]:
            count += 1
            scale += vt[k] * vt[k]
    if count < 50 or scale <= 0.0:
        for j in range(n_psi):
            out[j] = np.inf
        return
    for j in range(n_psi):
        acc = 0.0
        for k in range(m):
            if keep[k]:
                r = vt[k] - _cube_lookup(pad_v, pad_offsets, n, mirrored[j, k, 0], mirrored[j, k, 1], mirrored[j, k, 2])
                acc += r * r
        out[j] = acc / scale


@njit(**_OPTS)
def pad_border(values, border, src, w, out):
    """The border texels of :meth:`Hemicube.pad`: ``out[b] = Σ_j values[src[b, j]] w[b, j]``."""
    for k in range(border.shape[0]):
        b = border[k]
        acc = 0.0
        for j in range(src.shape[1]):
            acc += values[src[b, j]] * w[b, j]
        out[b] = acc


@njit(**_OPTS)
def scatter_add(values, index, out):
    """``out[index[k], c] += values[k, c]``: :meth:`Hemicube.block_reduce`'s block sums."""
    for k in range(values.shape[0]):
        t = index[k]
        for c in range(values.shape[1]):
            out[t, c] += values[k, c]


@njit(inline="always", **_OPTS)
def _texel(n: int, x: float, y: float, z: float) -> int:
    """Nearest-texel flat index of one direction (need not be unit): :meth:`Hemicube.index`."""
    face, col, row = _face_coords(x, y, z, n)
    c = min(int(col + 0.5), n - 1)
    if face == 0:
        return min(int(row + 0.5), n - 1) * n + c
    half = n // 2
    return n * n + (face - 1) * n * half + min(int(row + 0.5), half - 1) * n + c


@njit(**_OPTS)
def cube_index(n, dirs, out):
    """Nearest-texel flat index: :meth:`Hemicube.index`."""
    for k in range(dirs.shape[0]):
        out[k] = _texel(n, dirs[k, 0], dirs[k, 1], dirs[k, 2])


@njit(**_OPTS)
def bin_accumulate(light, view, values, valid, n, sq):
    """Per (LED, texel of i + o) sums of the valid samples: :func:`reconstruct.samples.bin_samples`.

    Samples are visited LED by LED, pixel by pixel (the order of ``np.nonzero``), so
    the sums equal ``np.bincount``'s bit for bit. Returns the used keys
    ``led·size + texel`` (ascending), their counts, ``Σf`` (K, 3), ``Σo`` (K, 3) and
    ``Σ sq`` (K,) when ``sq`` has the shape of ``valid`` (zeros otherwise).
    """
    size = 3 * n * n
    n_l, n_p = valid.shape
    n_keys = n_l * size
    key = np.empty(n_l * n_p, dtype=np.int64)
    count = np.zeros(n_keys, dtype=np.int32)
    m = 0
    for l in range(n_l):
        lx, ly, lz = light[l, 0], light[l, 1], light[l, 2]
        for p in range(n_p):
            if valid[l, p]:
                k = l * size + _texel(n, lx + view[p, 0], ly + view[p, 1], lz + view[p, 2])
                key[m] = k
                count[k] += 1
                m += 1
    # one ascending scan numbers the used keys; count[k] becomes the slot of key k
    used = np.empty(m, dtype=np.int64)
    cnt = np.empty(m, dtype=np.float64)
    nb = 0
    for k in range(n_keys):
        c = count[k]
        if c > 0:
            used[nb] = k
            cnt[nb] = c
            count[k] = nb
            nb += 1
    used = used[:nb]
    cnt = cnt[:nb]
    slot = count
    fsum = np.zeros((nb, 3))
    osum = np.zeros((nb, 3))
    qsum = np.zeros(nb)
    with_sq = sq.shape[0] == n_l and sq.shape[1] == n_p
    m = 0
    for l in range(n_l):
        for p in range(n_p):
            if valid[l, p]:
                b = slot[key[m]]
                m += 1
                for ch in range(3):
                    fsum[b, ch] += values[l, p, ch]
                    osum[b, ch] += view[p, ch]
                if with_sq:
                    qsum[b] += sq[l, p]
    return used, cnt, fsum, osum, qsum


@njit(**_OPTS)
def bin_finish(light, used, cnt, fsum, osum, size):
    """Means of :func:`bin_accumulate`'s sums: :func:`reconstruct.samples._finish` per bin.

    Returns LED, texel, i, mean o (unit), h = (i + o)/|i + o|, mean f and cos θ_d.
    """
    nb = used.shape[0]
    led = np.empty(nb, dtype=np.intp)
    texel = np.empty(nb, dtype=np.intp)
    i = np.empty((nb, 3))
    o = np.empty((nb, 3))
    h = np.empty((nb, 3))
    f = np.empty((nb, 3))
    cos_d = np.empty(nb)
    for b in range(nb):
        l = used[b] // size
        led[b] = l
        texel[b] = used[b] % size
        ox, oy, oz = osum[b, 0], osum[b, 1], osum[b, 2]
        ox, oy, oz = _unit(ox, oy, oz)
        ix, iy, iz = light[l, 0], light[l, 1], light[l, 2]
        hx, hy, hz = _unit(ix + ox, iy + oy, iz + oz)
        i[b, 0], i[b, 1], i[b, 2] = ix, iy, iz
        o[b, 0], o[b, 1], o[b, 2] = ox, oy, oz
        h[b, 0], h[b, 1], h[b, 2] = hx, hy, hz
        for ch in range(3):
            f[b, ch] = fsum[b, ch] / cnt[b]
        cos_d[b] = min(max(ix * hx + iy * hy + iz * hz, 0.0), 1.0)
    return led, texel, i, o, h, f, cos_d


@njit(**_OPTS)
def overlap_pairs(led, texel, n_leds, size, tau, symmetric):
    """Direct and τ-symmetric bin pairs: :func:`reconstruct.fresnel_fit.overlap_pairs`.

    ``led``, ``texel`` of the bins, sorted by ``(led, texel)``. Pairs come out in the
    reference's order: LED pairs ``a ≤ b`` in turn, texels ascending within each.
    """
    slot = np.full((n_leds, size), -1, dtype=np.int64)
    start = np.zeros(n_leds + 1, dtype=np.int64)
    for k in range(led.shape[0]):
        slot[led[k], texel[k]] = k
        start[led[k] + 1] = k + 1
    for a in range(1, n_leds + 1):
        start[a] = max(start[a], start[a - 1])
    cap = 0
    for a in range(n_leds):
        cap += (start[a + 1] - start[a]) * (n_leds - a) * (2 if symmetric else 1)
    p = np.empty(cap, dtype=np.int64)
    q = np.empty(cap, dtype=np.int64)
    sym = np.empty(cap, dtype=np.bool_)
    m = 0
    for a in range(n_leds):
        for b in range(a, n_leds):
            if b > a:
                for k in range(start[a], start[a + 1]):
                    j = slot[b, texel[k]]
                    if j >= 0:
                        p[m] = k
                        q[m] = j
                        sym[m] = False
                        m += 1
            if symmetric:
                for k in range(start[a], start[a + 1]):
                    t = texel[k]
                    j = slot[b, tau[t]]
                    if j >= 0 and (a != b or t < tau[t]):
                        p[m] = k
                        q[m] = j
                        sym[m] = True
                        m += 1
    return p[:m], q[:m], sym[:m]


@njit(**_OPTS)
def splat(n, dirs, values, weights, wsum, wvsum):
    """Accumulate ``Σw`` and ``Σw·v`` (values shape ``(M, C)``) per nearest texel."""
    nc = values.shape[1]
    for k in range(dirs.shape[0]):
        w = weights[k]
        if w == 0.0:
            continue
        t = _texel(n, dirs[k, 0], dirs[k, 1], dirs[k, 2])
        wsum[t] += w
        for ch in range(nc):
            wvsum[t, ch] += w * values[k, ch]


@njit(**_OPTS)
def model_eval(i, o, padded, pad_offsets, n, sig_flat, nt, nphi, ftable, kd, ks, correlated, out):
    """:meth:`MicrofacetBRDF.eval` fused per pair (eqs. 1–2 in the form of AR 1.6).

    ``ftable`` is :class:`FresnelTable`'s table (rows uniform in √c, one guard row).
    """
    nf = ftable.shape[0] - 2  # index of c = 1
    inv_pi = 1.0 / math.pi
    for k in range(i.shape[0]):
        ix, iy, iz = i[k, 0], i[k, 1], i[k, 2]
        ox, oy, oz = o[k, 0], o[k, 1], o[k, 2]
        if iz <= 0.0 or oz <= 0.0:
            for ch in range(3):
                out[k, ch] = 0.0
            continue
        hx, hy, hz = ix + ox, iy + oy, iz + oz
        norm = math.sqrt(hx * hx + hy * hy + hz * hz)
        hx /= norm
        hy /= norm
        hz /= norm
        c = abs(ix * hx + iy * hy + iz * hz)
        d = _cube_lookup(padded, pad_offsets, n, hx, hy, hz)
        si = max(_sigma_lookup(sig_flat, nt, nphi, ix, iy, iz), iz)
        so = max(_sigma_lookup(sig_flat, nt, nphi, ox, oy, oz), oz)
        if correlated:
            denom = 4.0 * (si * oz + so * iz - iz * oz)
        else:
            denom = 4.0 * si * so
        spec = d / denom if denom > 0.0 else 0.0
        x = math.sqrt(min(c, 1.0)) * nf
        j = int(x)
        w = x - j
        for ch in range(3):
            f = ftable[j, ch] + w * (ftable[j + 1, ch] - ftable[j, ch])
            out[k, ch] = f * ks[ch] * spec + kd[ch] * inv_pi


@njit(inline="always", **_OPTS)
def _fresnel(c: float, eta: float) -> float:
    """One value of :func:`reflecto.fresnel.fresnel` (same arithmetic)."""
    c = abs(c)
    g2 = eta * eta + c * c - 1.0
    if g2 <= 0.0:
        return 1.0
    g = math.sqrt(g2)
    gpc = g + c
    gmc = g - c
    a = gmc * gmc / (2.0 * gpc * gpc)
    num = c * gpc - 1.0
    den = c * gmc + 1.0
    f = a * (1.0 + num * num / (den * den))
    if not math.isfinite(f):
        return 1.0
    return min(max(f, 0.0), 1.0)


@njit(**_OPTS)
def fresnel_flat(c, eta, out):
    """``out[k] = F(c[k]; η[k])``: :func:`reflecto.fresnel.fresnel` on flat arrays."""
    for k in range(c.shape[0]):
        out[k] = _fresnel(c[k], eta[k])


@njit(**_OPTS)
def pair_residuals(cp, cq, fp, fq, ap, aq, w, eta, kd_over_pi, level, out):
    """Weighted relative residuals of eq. 6 per bin pair: ``fresnel_fit.fit_fresnel``'s ``r``."""
    for k in range(cp.shape[0]):
        fpp = max(_fresnel(cp[k], eta), 1e-12)
        fqq = max(_fresnel(cq[k], eta), 1e-12)
        yp = (fp[k] - kd_over_pi) * ap[k] / fpp
        yq = (fq[k] - kd_over_pi) * aq[k] / fqq
        mean = 0.5 * (fp[k] * ap[k] / fpp + fq[k] * aq[k] / fqq)
        out[k] = w[k] * (yp - yq) / max(mean, level)


@njit(inline="always", **_OPTS)
def _fresnel_dlog(c: float, eta: float) -> tuple[float, float]:
    """``F(c; η)`` (as :func:`_fresnel`, up to rounding) and ``∂ log F/∂η``; F floored at 1e-12.

    With ``g = √(η² + c² − 1)``, ``F = a (1 + B²)``, ``a = (g−c)²/(2(g+c)²)``,
    ``B = (c(g+c) − 1)/(c(g−c) + 1)``: ``∂a/∂g = 2c(g−c)/(g+c)³``,
    ``∂B/∂g = 2c(1 − c²)/(c(g−c) + 1)²``, ``∂g/∂η = η/g``. The derivative is 0 under
    total internal reflection and where F is clamped.
    """
    c = abs(c)
    g2 = eta * eta + c * c - 1.0
    if g2 <= 0.0:
        return 1.0, 0.0
    g = math.sqrt(g2)
    gpc = g + c
    gmc = g - c
    ig = 1.0 / gpc
    a = 0.5 * gmc * gmc * ig * ig
    iden = 1.0 / (c * gmc + 1.0)
    b = (c * gpc - 1.0) * iden
    f = a * (1.0 + b * b)
    if not math.isfinite(f):
        return 1.0, 0.0
    if f <= 1e-12 or f >= 1.0:
        return min(max(f, 1e-12), 1.0), 0.0
    da = 2.0 * c * gmc * ig * ig * ig
    db = 2.0 * c * (1.0 - c * c) * iden * iden
    return f, (da * (1.0 + b * b) + 2.0 * a * b * db) * eta / (g * f)


@njit(**_OPTS)
def pair_residuals_jac(cp, cq, fp, fq, ap, aq, w, eta, kd_over_pi, level, jac):
    """Derivatives of :func:`pair_residuals`: ``jac[0] = ∂r/∂η``, ``jac[1] = ∂r/∂(k_d/π)``.

    ``r = w (y_p − y_q)/M`` with ``y = (f − k_d/π) a/F``, ``M = max(½(m_p + m_q), level)``,
    ``m = f a/F``; ``∂y/∂η = −y ∂log F/∂η``, ``∂m/∂η = −m ∂log F/∂η``,
    ``∂y/∂(k_d/π) = −a/F``.
    """
    for k in range(cp.shape[0]):
        fpp, lp = _fresnel_dlog(cp[k], eta)
        fqq, lq = _fresnel_dlog(cq[k], eta)
        up = ap[k] / fpp
        uq = aq[k] / fqq
        yp = (fp[k] - kd_over_pi) * up
        yq = (fq[k] - kd_over_pi) * uq
        mp = fp[k] * up
        mq = fq[k] * uq
        mean = 0.5 * (mp + mq)
        im = 1.0 / max(mean, level)
        wm = w[k] * im
        dm = -0.5 * (mp * lp + mq * lq) if mean > level else 0.0
        jac[0, k] = wm * ((yq * lq - yp * lp) - (yp - yq) * dm * im)
        jac[1, k] = wm * (uq - up)


def as_dirs(a) -> np.ndarray:
    """C-contiguous float64 view/copy of shape ``(M, 3)``."""
    return np.ascontiguousarray(np.asarray(a, dtype=np.float64).reshape(-1, 3))


@njit(**_OPTS)
def merge_linear(raw, rows, cols, t, black, sat, dark, black_limit, out, valid, near_black, t_sum, n_used):
    """Linear HDR merge at pixels ``(rows, cols)``: :func:`reflecto.instrument.hdr.merge_linear`.

    ``near_black`` (L, P) is set where the value rests on one exposure whose signal is
    below ``black_limit`` DN in every channel; ``t_sum`` (L, P) is the summed time of the
    exposures used (ms) and ``n_used`` (L, P) their number (the noise model's inputs).

    ``raw`` (L, E, H, W, 3); ``t`` exposure times sorted by slot; writes ``out`` (L, P, 3)
    in DN/ms and ``valid`` (L, P).
    """
    n_l, n_e = raw.shape[0], raw.shape[1]
    order = np.argsort(t)
    for l in range(n_l):
        for p in range(rows.shape[0]):
            r, c = rows[p], cols[p]
            wsum = 0.0
            a0 = a1 = a2 = 0.0
            longest_done = False
            only_dark = False
            used = 0
            for q in range(n_e - 1, -1, -1):
                e = order[q]
                z0 = float(raw[l, e, r, c, 0])
                z1 = float(raw[l, e, r, c, 1])
                z2 = float(raw[l, e, r, c, 2])
                if max(z0, z1, z2) >= sat:
                    continue
                s0, s1, s2 = z0 - black, z1 - black, z2 - black
                top = max(s0, s1, s2)
                if top < dark and longest_done:
                    continue
                only_dark = top < black_limit and not longest_done
                longest_done = True
                w = t[e]
                wsum += w
                used += 1
                a0 += s0
                a1 += s1
                a2 += s2
            if wsum > 0.0:
                out[l, p, 0] = a0 / wsum
                out[l, p, 1] = a1 / wsum
                out[l, p, 2] = a2 / wsum
                valid[l, p] = True
                near_black[l, p] = only_dark
            else:
                out[l, p, 0] = out[l, p, 1] = out[l, p, 2] = 0.0
                valid[l, p] = False
                near_black[l, p] = False
            t_sum[l, p] = wsum
            n_used[l, p] = used


@njit(**_OPTS)
def expose(signal, t_ms, z, pois, full_well, read_noise, shot, gauss_above, gamma, gain, black, max_value, out):
    """Camera exposure of electron rates ``signal`` (flat): :func:`reflecto.instrument.simulate.expose`.

    ``z``: standard normals (or empty for no noise); ``pois``: Poisson draws used where
    the mean is below ``gauss_above``. ``gamma > 0`` encodes 8-bit
    ``255 (e/full_well)^(1/gamma)``; otherwise ``black + e/gain`` rounded and clipped.
    """
    noisy = z.shape[0] > 0
    rn2 = read_noise * read_noise
    for k in range(signal.shape[0]):
        e = min(max(signal[k], 0.0) * t_ms, 4.0 * full_well)
        if noisy:
            if shot and e < gauss_above:
                e = pois[k] + read_noise * z[k]
            elif shot:
                e += math.sqrt(e + rn2) * z[k]
            else:
                e += read_noise * z[k]
        e = min(e, full_well)
        if gamma > 0.0:
            out[k] = min(max(round(255.0 * max(e / full_well, 0.0) ** (1.0 / gamma)), 0.0), 255.0)
        else:
            out[k] = min(max(round(black + e / gain), 0.0), max_value)


@njit(**_OPTS)
def quantize_ndf(d, psa, normalize, out):
    """:class:`reflecto.model.MicrofacetBRDF`'s NDF: float32-rounded, normalized by AR 1.2.

    ``out[k] = f32(d[k])`` and ``total = Σ out[k] psa[k]``; with ``normalize`` (and
    ``total > 0``) then ``out[k] = f32(out[k] / total)``. Returns ``total``, or −1 if
    some ``d[k]`` is negative, NaN or infinite (``out`` is then unspecified). A NaN or
    ±inf shows in ``total`` (NaN·0 and inf·0 are NaN), so the loop needs no branch.
    """
    total = 0.0
    lo = 0.0
    for k in range(d.shape[0]):
        v = d[k]
        lo = min(lo, v)
        q = np.float64(np.float32(v))
        out[k] = q
        total += q * psa[k]
    if not (lo >= 0.0) or not math.isfinite(total):
        return -1.0
    if normalize and total > 0.0:
        for k in range(d.shape[0]):
            out[k] = np.float64(np.float32(out[k] / total))
    return total


@njit(**_OPTS)
def gather_below(values, valid, thresholds, out):
    """Per channel ``c``, the valid ``values[k, c] < thresholds[c]`` into ``out[c, :count[c]]``.

    :func:`reflecto.reconstruct.samples.kd_upper_bound`; ``values`` (M, 3), ``valid``
    (M,), ``out`` (3, ≥ count). Returns the counts and the numbers of valid values
    equal to the thresholds, each of shape ``(3,)``.
    """
    counts = np.zeros(3, dtype=np.int64)
    equal = np.zeros(3, dtype=np.int64)
    for k in range(values.shape[0]):
        if valid[k]:
            for c in range(3):
                v = values[k, c]
                if v < thresholds[c]:
                    out[c, counts[c]] = v
                    counts[c] += 1
                elif v == thresholds[c]:
                    equal[c] += 1
    return counts, equal


@njit(**_OPTS)
def partial_ndf(f, kd_over_pi, cos_io, s_led, led, s_o, fres, lum, dh, d_lum):
    """Eq. 7 per bin and channel: :func:`reflecto.reconstruct.pipeline.reconstruct`'s inner loop.

    ``a = cos_io / max(S(i) S(o), 1e-12)``, ``dh[k, c] = (f[k, c] − k_d,c/π) · 4a / F[k, c]``
    (``fres`` has 3 columns, or 1 shared by the channels) and ``d_lum = dh @ lum``.
    The same arithmetic as the NumPy expressions, without their (B, 3) temporaries.
    """
    shared = fres.shape[1] == 1
    for k in range(f.shape[0]):
        a4 = 4.0 * (cos_io[k] / max(s_led[led[k]] * s_o[k], 1e-12))
        acc = 0.0
        for c in range(3):
            v = (f[k, c] - kd_over_pi[c]) * a4 / fres[k, 0 if shared else c]
            dh[k, c] = v
            acc += v * lum[c]
        d_lum[k] = acc


@njit(**_OPTS)
def ct_lobe(i, o, scale, f0, m, out):
    """``scale · D G F / (π cos θ_i cos θ_o)`` per pair: :func:`reflecto.evaluate.cooktorrance._lobe`.

    The same arithmetic as the NumPy reference (Beckmann D, V-groove G, Schlick F),
    times ``scale`` (the fit's √w cos θ_i), without its temporaries.
    """
    m2 = m * m
    for k in range(i.shape[0]):
        ix, iy, iz = i[k, 0], i[k, 1], i[k, 2]
        ox, oy, oz = o[k, 0], o[k, 1], o[k, 2]
        if not (iz > 0.0 and oz > 0.0):
            out[k] = 0.0
            continue
        hx, hy, hz = _unit(ix + ox, iy + oy, iz + oz)
        ch = min(max(hz, 1e-9), 1.0)
        c = min(max(ix * hx + iy * hy + iz * hz, 1e-9), 1.0)
        t2 = (1.0 - ch * ch) / (ch * ch)
        d = math.exp(-t2 / m2) / (math.pi * m2 * ch**4)
        g = min(1.0, min(2 * ch * iz / c, 2 * ch * oz / c))
        f = f0 + (1 - f0) * (1 - c) ** 5
        den = math.pi * max(iz, 1e-9) * max(oz, 1e-9)
        out[k] = d * max(g, 0.0) * f / den * scale[k]


@njit(**_OPTS)
def ct_residual(diff, lobe, y, rd, rs, out):
    """``out[k, c] = rd[c] diff[k] + rs[c] lobe[k] − y[k, c]``: the Cook–Torrance fit's residual."""
    for k in range(y.shape[0]):
        for c in range(3):
            out[k, c] = rd[c] * diff[k] + rs[c] * lobe[k] - y[k, c]


@njit(**_OPTS)
def box_mean(values, valid, rows, cols, h, w, radius, out):
    """Mean of the valid samples in a ``(2 radius + 1)²`` pixel box per LED:
    :func:`reflecto.reconstruct.samples.box_mean_numpy` (sums instead of SciPy's means).

    ``values`` (L, P, 3), ``valid`` (L, P), ``rows``/``cols`` (P,) inside an ``h × w``
    image; ``out`` (L, P, 3) gets 0 at invalid samples. Separable running sums: one
    pass along the rows, one along the columns.
    """
    n_l, n_p = valid.shape
    img = np.zeros((h, w, 4))
    tmp = np.zeros((h, w, 4))
    for k in range(n_l):
        img[:] = 0.0
        for p in range(n_p):
            if valid[k, p]:
                r, c = rows[p], cols[p]
                for ch in range(3):
                    img[r, c, ch] = values[k, p, ch]
                img[r, c, 3] = 1.0
        s = np.zeros(4)
        for r in range(h):  # along each row: tmp[r, c] = Σ img[r, c-radius..c+radius]
            s[:] = 0.0
            for c in range(min(radius, w)):
                for ch in range(4):
                    s[ch] += img[r, c, ch]
            for c in range(w):
                for ch in range(4):
                    if c + radius < w:
                        s[ch] += img[r, c + radius, ch]
                    tmp[r, c, ch] = s[ch]
                    if c - radius >= 0:
                        s[ch] -= img[r, c - radius, ch]
        s2 = np.zeros((w, 4))  # along each column, all columns at once (row-major order)
        for r in range(min(radius, h)):
            for c in range(w):
                for ch in range(4):
                    s2[c, ch] += tmp[r, c, ch]
        for r in range(h):
            for c in range(w):
                for ch in range(4):
                    if r + radius < h:
                        s2[c, ch] += tmp[r + radius, c, ch]
                    img[r, c, ch] = s2[c, ch]
                    if r - radius >= 0:
                        s2[c, ch] -= tmp[r - radius, c, ch]
        for p in range(n_p):
            r, c = rows[p], cols[p]
            cnt = img[r, c, 3]
            for ch in range(3):
                out[k, p, ch] = img[r, c, ch] / cnt if valid[k, p] and cnt > 0.0 else 0.0


@njit(**_OPTS)
def png_unfilter(data, height, rowbytes, bpp, out):
    """Undo the PNG row filters (PNG spec §9.2) of a non-interlaced image.

    ``data`` (uint8, ``height · (1 + rowbytes)``): the inflated image data, each row
    its filter type byte (0 None, 1 Sub, 2 Up, 3 Average, 4 Paeth) then ``rowbytes``
    filtered bytes; ``bpp`` bytes per pixel (6 for 16-bit RGB, 3 for 8-bit). Writes
    the raw bytes into ``out`` (uint8, ``(height, rowbytes)``), exactly as libpng's
    ``png_read_filter_row`` does. Returns the first row whose filter type is not 0–4,
    or -1 when every row's is valid (that row and later ones are then not written).
    """
    for y in range(height):
        base = y * (rowbytes + 1)
        ft = data[base]
        src = base + 1
        if ft == 0:
            for x in range(rowbytes):
                out[y, x] = data[src + x]
        elif ft == 1:
            for x in range(rowbytes):
                a = out[y, x - bpp] if x >= bpp else 0
                out[y, x] = (data[src + x] + a) & 0xFF
        elif ft == 2:
            for x in range(rowbytes):
                b = out[y - 1, x] if y > 0 else 0
                out[y, x] = (data[src + x] + b) & 0xFF
        elif ft == 3:
            for x in range(rowbytes):
                a = np.int32(out[y, x - bpp]) if x >= bpp else np.int32(0)
                b = np.int32(out[y - 1, x]) if y > 0 else np.int32(0)
                out[y, x] = (np.int32(data[src + x]) + ((a + b) >> 1)) & 0xFF
        elif ft == 4:
            for x in range(rowbytes):
                a = np.int32(out[y, x - bpp]) if x >= bpp else np.int32(0)
                b = np.int32(out[y - 1, x]) if y > 0 else np.int32(0)
                c = np.int32(out[y - 1, x - bpp]) if (y > 0 and x >= bpp) else np.int32(0)
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                if pa <= pb and pa <= pc:
                    pred = a
                elif pb <= pc:
                    pred = b
                else:
                    pred = c
                out[y, x] = (np.int32(data[src + x]) + pred) & 0xFF
        else:
            return y
    return -1


@njit(**_OPTS)
def count_saturated(img, rows, cols, sat):
    """Pixels ``(rows[p], cols[p])`` of ``img`` (H, W, 3) whose largest channel is ≥ ``sat``:
    ``(img[rows, cols].max(axis=-1) >= sat).sum()`` without the gathered copy."""
    n = 0
    for p in range(rows.shape[0]):
        r, c = rows[p], cols[p]
        if max(img[r, c, 0], img[r, c, 1], img[r, c, 2]) >= sat:
            n += 1
    return n


@njit(**_OPTS)
def merge_noise_sd(lum, t_sum, n_used, per_exposure_var, gain, shot, out):
    """Noise model of a merged luminance: :func:`reflecto.instrument.hdr.merge_noise`.

    ``out = √(n (r² + 1/12) + L Σt / g) / max(Σt, 1e-300)`` elementwise over (L, P),
    ``per_exposure_var = r² + 1/12`` (DN²), the shot term only with ``shot``; ``lum``
    is the clipped luminance ``max(radiance · LUM, 0)`` (DN/ms). Same operations in
    the same order as the NumPy expression (bit-identical).
    """
    for l in range(lum.shape[0]):
        for p in range(lum.shape[1]):
            var = n_used[l, p] * per_exposure_var
            if shot:
                var = var + lum[l, p] * t_sum[l, p] / gain
            out[l, p] = math.sqrt(var) / max(t_sum[l, p], 1e-300)


@njit(**_OPTS)
def slice_values(rad, valid, scl, scl_pos, s_lum, sigma, t_sum, black_dn, values, ok, noise, limit):
    """Radiometric correction of merged radiance: the BRDF slices of
    :func:`reflecto.instrument.slices.extract_slices` in one pass over (L, P).

    ``ok = valid & scl_pos``; ``values = rad / scl`` (sr⁻¹, (L, P, 3)) where ok, else 0;
    ``noise = sigma / s_lum`` and ``limit = black_dn / max(t_sum, 1e-300) / s_lum``
    (sr⁻¹, (L, P)) where ok, else 0; ``s_lum`` is the scale's luminance ``scl · LUM``,
    ``scl_pos`` whether every channel of ``scl`` is > 0. Same operations in the same
    order as the NumPy expressions it replaces (bit-identical).
    """
    for l in range(rad.shape[0]):
        for p in range(rad.shape[1]):
            good = valid[l, p] and scl_pos[l, p]
            ok[l, p] = good
            if good:
                values[l, p, 0] = rad[l, p, 0] / scl[l, p, 0]
                values[l, p, 1] = rad[l, p, 1] / scl[l, p, 1]
                values[l, p, 2] = rad[l, p, 2] / scl[l, p, 2]
                noise[l, p] = sigma[l, p] / s_lum[l, p]
                limit[l, p] = black_dn / max(t_sum[l, p], 1e-300) / s_lum[l, p]
            else:
                values[l, p, 0] = 0.0
                values[l, p, 1] = 0.0
                values[l, p, 2] = 0.0
                noise[l, p] = 0.0
                limit[l, p] = 0.0
