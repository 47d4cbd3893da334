"""RGL ``.bsdf`` tensor files from any BRDF (Dupuy & Jakob 2018; Mitsuba 3 ``measured``).

The format stores, per incident direction ``(φ_i, θ_i)`` on a grid, a 2-D table over a
*warped* domain ``s ∈ [0, 1]²``; Mitsuba evaluates (see :mod:`reflecto.sources.rgl`)::

    u_m = (√(2θ_m/π), (φ_m [− φ_i] + π)/2π)      half vector in unit coordinates
    s   = VNDF⁻¹(u_m; φ_i, θ_i)                  inverse of the vndf warp
    f·cos θ_o = rgb(s; φ_i, θ_i) · ndf(u_m) / (4 σ(u_wi))

Only this product has to equal the BRDF; the tables are a parameterization. ``ndf``
holds the source's NDF itself, ``D + c`` (a reflecto model's NDF or, for any other
source, the estimate from its back-scattering ``f(m, m) cos²θ_m``, Dupuy & Jakob's),
with a floor ``c`` where the diffuse level meets the specular one; so the NDF's detail
sits in a table Mitsuba looks up directly and ``rgb = f cos θ_o · 4σ/D`` varies slowly.
``sigma`` is that NDF's projected area. The ``vndf`` warp, which only places the rgb
nodes (and drives sampling), is built from a *tempered* NDF (raised to the power
:data:`TEMPER`, heavier tails, floored) so that the tails of a sharp lobe keep nodes;
``vndf ∝ D' ⟨ω_i·m⟩ u₀ sin θ_m`` in unit coordinates. ``rgb`` is evaluated at the
forward-warped nodes of a regular ``s`` grid with the exact ``ndf``/``sigma`` values
Mitsuba will interpolate, so the file reproduces the source exactly at every node;
``luminance`` (Mitsuba's first sampling stage) is the luminance of ``rgb``.

Isotropic sources are written with one ``φ_i`` (relative ``φ_m``), anisotropic
ones with ``φ_i`` over ``[−π, π]`` and absolute ``φ_m``.
"""

from __future__ import annotations

import dataclasses
import math
import struct
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from ..colour import LUM
from ..io import atomic_write
from ..sources.base import BRDFSource
from ..sources.rgl import MAGIC, Marginal2D

Array = NDArray[np.float64]
#: The vndf warp uses the source's NDF raised to this power (then normalized): heavier
#: tails than D itself, so that the warped domain keeps resolution where f is small but
#: not zero (see the module docstring).
TEMPER = 0.65
_CODES = {np.dtype("u1"): 1, np.dtype("<u4"): 5, np.dtype("<f4"): 10}


@dataclasses.dataclass(frozen=True)
class RGLGrid:
    """Table resolutions of an exported file.

    ``n_theta_i``/``n_phi_i``: incident grid (``n_phi_i`` only for anisotropic files);
    ``ndf``, ``sigma``: (φ rows, θ columns) of those tables (the ndf table is fine,
    0.35° in φ and ≤ 0.35° in θ, so that reconstructed NDFs stay representable: with
    256 φ rows the deep tails of reconstructed metals missed p95 ≤ 5 %); ``vndf``: (rows, cols)
    of each vndf slice; ``rgb``: side of the square rgb/luminance slices.
    """

    n_theta_i: int = 24
    n_phi_i: int = 49
    ndf: tuple[int, int] = (1024, 512)
    sigma: tuple[int, int] = (64, 128)
    vndf: tuple[int, int] = (128, 128)
    vndf_anisotropic: tuple[int, int] = (64, 64)
    rgb: int = 48


def write_tensor_file(path: str | Path, fields: dict[str, np.ndarray]) -> Path:
    """Write ``{name: array}`` as a tensor file (format of :func:`reflecto.sources.rgl.read_tensor_file`), atomically."""
    arrays = {k: np.ascontiguousarray(v) for k, v in fields.items()}
    header = bytearray(MAGIC + bytes([1, 0]) + struct.pack("<I", len(arrays)))
    table_size = sum(2 + len(k.encode()) + 2 + 1 + 8 + 8 * v.ndim for k, v in arrays.items())
    offset = len(header) + table_size
    offset += -offset % 8
    layout = []
    for k, v in arrays.items():
        if v.dtype not in _CODES:
            raise ValueError(f"tensor field {k!r}: unsupported dtype {v.dtype}")
        name = k.encode()
        header += struct.pack("<H", len(name)) + name + struct.pack("<HBQ", v.ndim, _CODES[v.dtype], offset)
        header += struct.pack(f"<{v.ndim}Q", *v.shape)
        layout.append((offset, v))
        offset += v.nbytes
        offset += -offset % 8
    with atomic_write(path) as fh:
        fh.write(header)
        pos = len(header)
        for off, v in layout:
            fh.write(b"\0" * (off - pos))
            fh.write(v.tobytes())
            pos = off + v.nbytes
    return Path(path)


def _unit_dirs(u0: Array, u1: Array, phi_offset: float = 0.0) -> Array:
    """Directions at unit coordinates (θ = π/2·u0², φ = (2u1 − 1)π + offset)."""
    th, ph = np.broadcast_arrays(0.5 * math.pi * u0 * u0, (2.0 * u1 - 1.0) * math.pi + phi_offset)
    return np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=-1)


def proxy_ndf(source: BRDFSource) -> tuple[callable, bool]:
    """``(D, isotropic)``: the NDF of a microfacet model, else the back-scattering estimate.

    ``D`` maps unit directions ``(..., 3)`` to unnormalized NDF values.
    """
    from ..model import MicrofacetBRDF

    if isinstance(source, MicrofacetBRDF):
        def d_fn(m: Array) -> Array:
            return source.ndf(m)
    else:
        def d_fn(m: Array) -> Array:
            flat = m.reshape(-1, 3)
            k = flat.copy()
            k[:, 2] = np.maximum(k[:, 2], 1e-3)
            k /= np.linalg.norm(k, axis=1, keepdims=True)
            v = np.maximum(source.eval(k, k) @ LUM, 0.0) * k[:, 2] ** 2
            return v.reshape(m.shape[:-1])
    return d_fn, bool(getattr(source, "isotropic", False)) or _looks_isotropic(d_fn)


def _looks_isotropic(d_fn, tol: float = 0.02) -> bool:
    u0 = np.linspace(0.05, 0.95, 19)
    u1 = np.linspace(0.0, 1.0, 64, endpoint=False)
    d = d_fn(_unit_dirs(u0[None, :], u1[:, None]))
    mean = d.mean(axis=0)
    ok = mean > 1e-3 * mean.max()
    return bool(np.all(np.abs(d[:, ok] / mean[ok] - 1.0) < tol))


def rgl_tables(source: BRDFSource, grid: RGLGrid = RGLGrid(), isotropic: bool | None = None,
               description: str | None = None) -> dict[str, np.ndarray]:
    """The fields of an RGL ``.bsdf`` file reproducing ``source`` (see the module docstring)."""
    d_raw, iso_guess = proxy_ndf(source)
    iso = iso_guess if isotropic is None else bool(isotropic)
    n_phi_ndf, n_th_ndf = (2, grid.ndf[1]) if iso else grid.ndf
    u0 = np.linspace(0.0, 1.0, n_th_ndf)
    u1 = np.linspace(0.0, 1.0, n_phi_ndf)
    qu = (np.arange(256) + 0.5) / 256
    qphi = (np.arange(128) + 0.5) / 128
    mq = _unit_dirs(qu[None, :], qphi[:, None])
    th_q = 0.5 * math.pi * qu * qu
    w_q = (np.sin(th_q) * math.pi * qu / 256)[None, :] * (2 * math.pi / 128)  # dω per node
    cos_q = np.cos(th_q)[None, :]
    # the ndf table is the NDF itself (so that rgb = f cos·4σ/D carries no NDF detail);
    # the warp that places the rgb nodes uses the tempered NDF (heavier tails).
    # D is evaluated once per point set; both tables are derived from those values.
    raw = _RawNDF(d_raw, iso, mq, _unit_dirs(u0[None, :], u1[:, None]))
    ndf_tab, dq_exact = _floored(source, raw, 1.0, w_q, cos_q, min_floor=1e-9)
    warp_tab, _ = _floored(source, raw, TEMPER, w_q, cos_q, min_floor=1e-6)
    # σ(k) = ∫ D(m) ⟨k·m⟩ dω_m on the quadrature, at the sigma table's nodes
    wq = (dq_exact * w_q).ravel()
    mq = mq.reshape(-1, 3)
    n_phi_sig, n_th_sig = (2, grid.sigma[1]) if iso else grid.sigma
    ks = _unit_dirs(np.linspace(0.0, 1.0, n_th_sig)[None, :], np.linspace(0.0, 1.0, n_phi_sig)[:, None])
    sig_tab = np.concatenate([np.maximum(blk @ mq.T, 0.0) @ wq for blk in np.array_split(ks.reshape(-1, 3), 16)])
    sig_tab = sig_tab.reshape(ks.shape[:-1])
    warp_m = Marginal2D(warp_tab[None, None], np.zeros(1), np.zeros(1), build_cdf=False)
    ndf_m = Marginal2D(ndf_tab[None, None], np.zeros(1), np.zeros(1), build_cdf=False)
    sig_m = Marginal2D(sig_tab[None, None], np.zeros(1), np.zeros(1), build_cdf=False)

    theta_i = np.linspace(0.0, 0.5 * math.pi, grid.n_theta_i)
    phi_i = np.zeros(1) if iso else np.linspace(-math.pi, math.pi, grid.n_phi_i)
    hv, wv = grid.vndf if iso else grid.vndf_anisotropic
    vu0 = np.linspace(0.0, 1.0, wv)
    vu1 = np.linspace(0.0, 1.0, hv)
    n = grid.rgb
    s = np.stack(np.meshgrid(np.linspace(0.0, 1.0, n), np.linspace(0.0, 1.0, n), indexing="xy"), axis=-1)  # (row, col, 2)
    vndf = np.empty((len(phi_i), len(theta_i), hv, wv), np.float32)
    rgb = np.empty((len(phi_i), len(theta_i), 3, n, n), np.float32)
    lum = np.empty((len(phi_i), len(theta_i), n, n), np.float32)
    for a, ph in enumerate(phi_i):
        for b, th in enumerate(theta_i):
            wi = np.array([math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph), math.cos(th)])
            offset = ph if iso else 0.0
            m = _unit_dirs(vu0[None, :], vu1[:, None], offset)
            v = warp_m.eval(np.stack(np.broadcast_arrays(vu0[None, :], vu1[:, None]), -1), np.zeros(1), np.zeros(1))
            v = v * np.maximum(m @ wi, 0.0) * vu0[None, :] * np.sin(0.5 * math.pi * vu0 * vu0)[None, :]
            v = np.maximum(v, 1e-7 * max(float(v.max()), 1e-300))
            v /= v.sum()
            vndf[a, b] = v
            warp = Marginal2D(v[None, None].astype(np.float32).astype(np.float64), np.zeros(1), np.zeros(1))
            um = warp.sample(s, 0)  # (n, n, 2) unit coordinates of the half vector
            mm = _unit_dirs(um[..., 0], um[..., 1], offset).reshape(-1, 3)
            wo = 2.0 * (mm @ wi)[:, None] * mm - wi
            below = (wo[:, 2] <= 1e-4).reshape(n, n)
            wo[:, 2] = np.maximum(wo[:, 2], 1e-4)
            wo /= np.linalg.norm(wo, axis=1, keepdims=True)
            wi_rep = np.broadcast_to(np.array([wi[0], wi[1], max(wi[2], 1e-4)]), wo.shape).copy()
            f = source.eval(wi_rep, wo)
            uwi = np.array([[math.sqrt(th * 2 / math.pi), (ph + math.pi) / (2 * math.pi)]])
            sig = float(sig_m.eval(uwi, np.zeros(1), np.zeros(1))[0])
            dm = ndf_m.eval(um.reshape(-1, 2), np.zeros(len(mm)), np.zeros(len(mm)))
            val = f * (wo[:, 2] * 4.0 * sig / np.maximum(dm, 1e-30))[:, None]
            val = np.maximum(val, 0.0).reshape(n, n, 3)
            # nodes whose ω_o is below the horizon are never evaluated (Mitsuba masks
            # them) but enter the interpolation: extend the nearest valid node's value
            if below.any() and not below.all():
                _, (ri, ci) = ndimage.distance_transform_edt(below, return_indices=True)
                val = val[ri, ci]
            rgb[a, b] = np.moveaxis(val, -1, 0)
            lv = val @ LUM
            lum[a, b] = np.maximum(lv, 1e-4 * max(float(lv.max()), 1e-30))
    if not (np.all(np.isfinite(rgb)) and np.all(np.isfinite(vndf))):
        raise ValueError(f"{source.name}: non-finite values while building the RGL tables")
    desc = (description or f"reflecto export of {source.name}").encode("utf-8")
    return {
        "description": np.frombuffer(desc, dtype=np.uint8).copy(),
        "phi_i": phi_i.astype(np.float32),
        "theta_i": theta_i.astype(np.float32),
        "ndf": ndf_tab.astype(np.float32),
        "sigma": sig_tab.astype(np.float32),
        "vndf": vndf,
        "luminance": lum,
        "rgb": rgb,
        "jacobian": np.array([1], np.uint8),
    }


class _RawNDF:
    """``max(D, 0)`` at the quadrature (``q``) and table nodes (``nodes``), each evaluated once.

    For isotropic files D is replaced by its azimuthal average (64 azimuths on 257
    polar rings, interpolated in ``u₀``), taken after raising D to the table's power.
    """

    def __init__(self, d_raw, iso: bool, q: Array, nodes: Array) -> None:
        self.iso = iso
        if iso:
            k = (np.arange(64) + 0.5) / 64
            self._rings = np.maximum(d_raw(_unit_dirs(np.linspace(0, 1, 257)[None, :], k[:, None])), 0.0)
            self._u = [np.sqrt(np.arccos(np.clip(m[..., 2], -1.0, 1.0)) * 2 / math.pi) for m in (q, nodes)]
        else:
            self._values = [np.maximum(d_raw(m), 0.0) for m in (q, nodes)]

    def powered(self, power: float) -> tuple[Array, Array]:
        """``(D^power at q, D^power at nodes)``."""
        if self.iso:
            ring = (self._rings if power == 1.0 else self._rings**power).mean(axis=0)
            return tuple(np.interp(u, np.linspace(0, 1, 257), ring) for u in self._u)
        return tuple(v if power == 1.0 else v**power for v in self._values)


def _floored(source: BRDFSource, raw: _RawNDF, power: float, w_q: Array, cos_q: Array,
             min_floor: float) -> tuple[Array, Array]:
    """``(D^power/norm + c)·norm'`` at the table nodes and at the quadrature.

    Normalized so that ``∫ D cos = 1`` on the quadrature, with the floor ``c`` of
    :func:`_floor`.
    """
    dq, dn = raw.powered(power)
    norm = float(np.sum(dq * cos_q * w_q))
    if not (norm > 0 and np.isfinite(norm)):
        raise ValueError(f"{source.name}: no positive NDF or back-scattering to build the tables from")
    floor = _floor(source, dq / norm, min_floor)
    scale2 = 1.0 / (1.0 + floor * float(np.sum(cos_q * w_q)))
    return (dn / norm + floor) * scale2, (dq / norm + floor) * scale2


def _floor(source: BRDFSource, d_norm: Array, min_floor: float) -> float:
    """NDF floor ``c`` at which the diffuse level meets the specular one (see module docstring)."""
    peak = float(d_norm.max())
    kd = getattr(source, "kd", None)
    ks = getattr(source, "ks", None)
    eta = getattr(source, "eta", None)
    if kd is not None and ks is not None and eta is not None:
        f0 = float(((np.asarray(eta) - 1) / (np.asarray(eta) + 1)) ** 2 @ LUM)
        kdl, ksl = float(np.asarray(kd) @ LUM), float(np.asarray(ks) @ LUM)
        c = 4.0 * kdl * 0.5 / (math.pi * max(ksl * f0, 1e-6))
    else:
        c = 0.0
    return float(np.clip(c, min_floor * peak, 10.0 * peak)) if peak > 0 else 1.0


def export_rgl(source: BRDFSource, path: str | Path, grid: RGLGrid = RGLGrid(), isotropic: bool | None = None) -> Path:
    """Write ``source`` as an RGL ``.bsdf`` file (atomically); returns the path."""
    return write_tensor_file(path, rgl_tables(source, grid, isotropic))
