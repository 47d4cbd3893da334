"""RGL ``.bsdf`` tensor files from any BRDF (Dupuy & Jakob 2018; Mitsuba 3 ``measured``).

The format stores, per incident direction ``(φ_i, θ_i)`` on a grid, a 2-D table over a
*warped* domain ``s ∈ [0, 1]²``; Mitsuba evaluates (see :mod:`reflecto.sources.rgl`)::

    u_m = (√(2θ_m/π), (φ_m [− φ_i] + π)/2π)      half vector in unit coordinates
    s   = VNDF⁻¹(u_m; φ_i, θ_i)                  inverse of the vndf warp
    f·cos θ_o = rgb(s; φ_i, θ_i) · N(u_m) / (4 Σ(u_i))

and interpolates every table linearly (``rgb`` bilinearly in ``s`` and linearly between
incident slices). Only the product has to equal the BRDF; ``N`` (field ``ndf``), ``Σ``
(``sigma``) and the warp are a parameterization, chosen here so that ``rgb`` is smooth
and nearly linear where Mitsuba interpolates it:

* ``N = D + c``: the source's NDF (a model's own ``ndf(h)``; for any other source the
  back-scattering estimate ``f(m, m) cos²θ_m`` of Dupuy & Jakob), normalized, plus a
  floor ``c`` near the NDF level where the diffuse term equals the specular one
  (:func:`_floor`). For a microfacet BRDF the ratio is then
  ``rgb ∝ (k_s F S(o) D + 4 k_d cos θ_o σ(i)/π) / (D + c)``: bounded, and with no
  trace of the lobe's shape where either term dominates; the lobe's detail is in
  ``N``, a fine table Mitsuba looks up directly at ``u_m``.
* ``Σ = σ_D(θ_i) / F(θ_i)``: the projected area ``∫ D ⟨i·m⟩ dω`` of the NDF without the
  floor (so that ``Σ S(i)/cos θ_i = 1``: no ``1/cos θ_i`` is left in ``rgb``), divided
  by the Fresnel factor at ``θ_d = θ_i`` relative to normal incidence (so that at the
  specular peak, where ``i·h ≈ cos θ_i``, ``rgb ≈ k_s S(o)`` does not bend between
  incident elevations). Both from the azimuthal mean of D, for anisotropic files too.
* One warp for every incident direction, uniform in ``u₁`` (:func:`_warp`): a node ``s``
  is the same half vector ``m`` in every slice, so Mitsuba's interpolation between
  slices is an interpolation of ``rgb(m; θ_i, φ_i)`` at fixed ``m``. Its columns follow
  the lobe, the lobe's flank (where ``rgb`` turns from the specular to the diffuse
  ratio) and, for a share, solid angle.
* Incident elevations are somewhat denser toward grazing incidence (:func:`theta_i_nodes`).

``rgb`` is evaluated at the forward-warped nodes with the float32 ``N`` and ``Σ`` values
Mitsuba will interpolate, so the file reproduces the source exactly at every node.
``luminance`` (only used for sampling) is the luminance of ``f cos θ_o`` times the warp's
Jacobian over its density, so that a sampled direction's density follows ``f cos θ_o``.

Isotropic sources are written with one ``φ_i`` (relative ``φ_m``), anisotropic ones with
``φ_i`` over ``[−π, π]`` and absolute ``φ_m``. Only the public interface of a source is
used: ``eval``, and where present ``ndf``, ``isotropic``, ``kd``, ``ks``, ``eta`` and
``metadata`` (for the description).
"""

from __future__ import annotations

import dataclasses
import math
import struct
from collections.abc import Callable
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from .. import __version__
from ..brdf import BRDFSource
from ..colour import LUM
from ..errors import FileFormatError, ParameterError, short_repr, shown_path
from ..fresnel import fresnel, is_constant
from ..io import atomic_path, atomic_write
from ..polar import NodeNDFs
from ..sources.rgl import MAGIC, RGLBRDF, Marginal2D

Array = NDArray[np.float64]
NDFFunction = Callable[[Array], Array]
_CODES = {np.dtype("u1"): 1, np.dtype("<u4"): 5, np.dtype("<f4"): 10}


@dataclasses.dataclass(frozen=True)
class RGLGrid:
    """Table resolutions and warp settings of an exported file.

    Attributes
    ----------
    n_theta_i, n_theta_i_aniso
        Incident elevations of isotropic and anisotropic files, denser toward grazing
        incidence by ``theta_i_grazing`` (see :func:`theta_i_nodes`). A model's lobe
        that changes with ``θ_d`` (an NDF per ``θ_d`` node) changes along ``θ_i`` too:
        chrome-steel's reconstruction is read back by Mitsuba within 2.2 % (eq. 10) with
        32 elevations, 0.73 % with 48, 0.49 % with 64 (3.3 MB per file at 48).
    n_phi_i
        Incident azimuths of anisotropic files, over ``[−π, π]``.
    ndf_iso, ndf
        Columns (``u₀``) of the isotropic ``ndf`` table; ``(φ rows, u₀ columns)`` of the
        anisotropic one. Both resolve the kinks of a bilinearly interpolated tabulated
        NDF near the pole (0.01° steps in θ at θ = 0.3°), which a sharp lobe's peak
        value depends on; the anisotropic one also the texel-scale structure of a
        reconstructed NDF's tails (0.18° in φ).
    sigma
        Columns (``u₀``) of the ``sigma`` table (two equal rows: see the module docstring).
    warp
        Columns of the warp (it is uniform in ``u₁``, so two rows).
    rgb, rgb_aniso
        Side of the square ``rgb``/``luminance`` slices (isotropic, anisotropic).
    uniform, flank, flank_floor, temper, lobe_measure
        The warp's three shares (see :func:`_warp`).
    floor_scale
        The NDF floor is this times ``4 k_d/(π k_s F(0))`` (see :func:`_floor`).
    fresnel_sigma
        Divide Σ by the Fresnel factor at ``θ_d = θ_i`` (see :func:`_fresnel_ratio`).
    """

    n_theta_i: int = 48
    n_theta_i_aniso: int = 24
    theta_i_grazing: float = 0.3
    n_phi_i: int = 37
    ndf_iso: int = 4096
    ndf: tuple[int, int] = (2048, 2048)
    sigma: int = 256
    warp: int = 256
    rgb: int = 64
    rgb_aniso: int = 32
    uniform: float = 0.2
    flank: float = 0.4
    flank_floor: float = 0.01
    temper: float = 0.5
    lobe_measure: float = 0.2
    floor_scale: float = 0.5
    fresnel_sigma: bool = True


def write_tensor_file(path: str | Path, fields: dict[str, np.ndarray]) -> Path:
    """Write ``{name: array}`` as a tensor file (format of :func:`reflecto.sources.rgl.read_tensor_file`), atomically.

    Parameters
    ----------
    path
        The file to write.
    fields
        Field name → array of dtype ``uint8``, little-endian ``uint32`` or little-endian
        ``float32`` (the ones Mitsuba's reader of these files uses), any shape.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ValueError
        A field of another dtype (convert it first, e.g. ``a.astype("<f4")``).
    """
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


# ------------------------------------------------------------------ geometry
def _unit_dirs(u0: Array, u1: Array, phi_offset: Array | float = 0.0) -> Array:
    """Directions at unit coordinates (θ = π/2·u0², φ = (2u1 − 1)π + offset), broadcast, ``(..., 3)``."""
    th, ph = np.broadcast_arrays(0.5 * math.pi * u0 * u0, (2.0 * u1 - 1.0) * math.pi + phi_offset)
    st = np.sin(th)
    return np.stack([st * np.cos(ph), st * np.sin(ph), np.cos(th)], axis=-1)


def _grid_dirs(u0: Array, u1: Array) -> Array:
    """Directions on the grid ``(len(u1) rows, len(u0) columns)`` of unit coordinates, ``(rows, cols, 3)``.

    The trigonometry is done on the two axes only (the NDF table's grid has 4M nodes).
    """
    th = 0.5 * math.pi * u0 * u0
    ph = (2.0 * u1 - 1.0) * math.pi
    out = np.empty((len(u1), len(u0), 3))
    np.multiply(np.cos(ph)[:, None], np.sin(th)[None, :], out=out[..., 0])
    np.multiply(np.sin(ph)[:, None], np.sin(th)[None, :], out=out[..., 1])
    out[..., 2] = np.cos(th)[None, :]
    return out


def _jacobian(u0: Array) -> Array:
    """``dω/du₀du₁ = 2π² u₀ sin θ`` of the unit coordinates (θ = π/2·u₀²)."""
    return 2.0 * math.pi**2 * u0 * np.sin(0.5 * math.pi * u0 * u0)


def theta_i_nodes(n: int, grazing: float) -> Array:
    """Incident elevations ``θ(t) = π/2·(t + a sin(πt)/π)`` at ``t = k/(n − 1)`` (radians).

    The spacing is ``∝ 1 + a cos(πt)``: ``(1 − a)/(1 + a)`` of the normal-incidence
    spacing at grazing incidence, where ``F(θ_d ≈ θ_i)`` and ``S`` bend fastest.

    Parameters
    ----------
    n
        Number of nodes.
    grazing
        The densification ``a`` (0: uniform).

    Returns
    -------
    ndarray, shape (n,)
        θ_i from 0 to π/2, radians.
    """
    t = np.linspace(0.0, 1.0, n)
    return 0.5 * math.pi * (t + grazing * np.sin(math.pi * t) / math.pi)


# ------------------------------------------------------------------ the NDF
def ndf_function(source: BRDFSource) -> tuple[NDFFunction, bool]:
    """The NDF the export builds its warp from.

    Parameters
    ----------
    source
        Any BRDF.

    Returns
    -------
    d_fn : callable
        ``D(m)`` for unit half vectors of shape ``(..., 3)``: the source's own ``ndf(h)``
        (sr⁻¹) if it has one (for a model with an NDF per ``θ_d`` node, the nodes' mean,
        so that the warp resolves the narrowest node's peak and the widest node's tail),
        else the back-scattering estimate ``f(m, m)·cos²θ_m`` (luminance, unnormalized).
    is_model_ndf : bool
        Whether ``d_fn`` is the source's own NDF.
    """
    lobes = getattr(source, "lobes", None)
    if isinstance(lobes, NodeNDFs):
        return (lambda m: np.mean([np.asarray(d(m), dtype=np.float64) for d in lobes.ndfs], axis=0)), True
    own = getattr(source, "ndf", None)
    if callable(own):
        return (lambda m: np.asarray(own(m), dtype=np.float64)), True

    def backscatter(m: Array) -> Array:
        flat = m.reshape(-1, 3)
        k = flat.copy()
        k[:, 2] = np.maximum(k[:, 2], 1e-3)
        k /= np.linalg.norm(k, axis=1, keepdims=True)
        v = np.maximum(source.eval(k, k) @ LUM, 0.0) * k[:, 2] ** 2
        return v.reshape(m.shape[:-1])

    return backscatter, False


def proxy_ndf(source: BRDFSource) -> tuple[NDFFunction, bool]:
    """:func:`ndf_function`'s D and whether the export treats the source as isotropic.

    Parameters
    ----------
    source
        Any BRDF.

    Returns
    -------
    d_fn : callable
        ``D(m)``, as :func:`ndf_function` returns it.
    isotropic : bool
        The source's ``isotropic`` flag, or D varying by < 2 % around every ring.
    """
    d_fn, _ = ndf_function(source)
    return d_fn, bool(getattr(source, "isotropic", False)) or _looks_isotropic(d_fn)


def _looks_isotropic(d_fn: NDFFunction, tol: float = 0.02) -> bool:
    """Whether D varies by less than ``tol`` (relative) around every ring above 10⁻³ of its peak."""
    u0 = np.linspace(0.05, 0.95, 19)
    u1 = np.linspace(0.0, 1.0, 64, endpoint=False)
    d = d_fn(_grid_dirs(u0, u1))
    mean = d.mean(axis=0)
    ok = mean > 1e-3 * mean.max()
    return bool(np.all(np.abs(d[:, ok] / mean[ok] - 1.0) < tol))


def _ring_means(d_fn: NDFFunction, u0: Array, n_az: int = 64) -> Array:
    """Azimuthal mean of ``max(D, 0)`` on the rings ``θ = π/2·u₀²`` (midpoint rule, ``n_az`` azimuths)."""
    az = (np.arange(n_az) + 0.5) / n_az
    return np.maximum(d_fn(_grid_dirs(u0, az)), 0.0).mean(axis=0)


def _trapezoid_weights(x: Array) -> Array:
    w = np.zeros_like(x)
    dx = np.diff(x)
    w[:-1] += 0.5 * dx
    w[1:] += 0.5 * dx
    return w


def _floor(source: BRDFSource, ring: Array, u0: Array, scale: float, min_floor: float = 1e-6) -> float:
    """NDF floor ``c = scale · 4 k_d/(π k_s F(0))`` (luminance) of a source with those parameters.

    Where ``D = 4 k_d/(π k_s F(0))`` the diffuse term of a microfacet BRDF equals the
    specular one at normal incidence. Away from it the balance moves (at θ_d = 60° the
    specular term is ≈ 2–3× larger relative to the diffuse one), so the floor sits
    below it: ``scale = 0.5`` gives the lowest eq. 10 error over the 50 shared
    reconstructions (1.1 % worst, against 1.6 % with 1 and 1.3 % with 0.3).

    A source without ``kd``/``ks``/``eta`` has the back-scattering estimate for D
    (``ring``, normalized, at ``u0``), which already holds the diffuse term as
    ``∝ cos²θ_m``; its level at the normal, ``min_θ D(θ)/cos²θ`` over θ ≤ 80°, stands
    for the same balance. Clipped to ``[min_floor, 10]``·peak.
    """
    peak = float(ring.max())
    kd, ks, eta = (getattr(source, k, None) for k in ("kd", "ks", "eta"))
    if kd is not None and ks is not None and eta is not None:
        f0 = float(_fresnel_luminance(source, np.ones(1))[0])
        kdl, ksl = float(np.asarray(kd) @ LUM), float(np.asarray(ks) @ LUM)
        c = 4.0 * kdl / (math.pi * max(ksl * f0, 1e-6))
    else:
        th = 0.5 * math.pi * u0 * u0
        keep = th <= math.radians(80.0)
        c = float(np.min(ring[keep] / np.cos(th[keep]) ** 2))
    return float(np.clip(scale * c, min_floor * peak, 10.0 * peak))


# ------------------------------------------------------------------ σ
def _ring_kernel(theta_k: Array, theta_m: Array) -> Array:
    """``∫₀^{2π} max(cos θ_k cos θ_m + sin θ_k sin θ_m cos φ, 0) dφ``, shape ``(K, M)``."""
    a = np.cos(theta_k)[:, None] * np.cos(theta_m)[None, :]
    b = np.sin(theta_k)[:, None] * np.sin(theta_m)[None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        phi0 = np.arccos(np.clip(-a / np.where(b > 0, b, 1.0), -1.0, 1.0))
    part = 2.0 * (a * phi0 + b * np.sin(phi0))
    return np.where(a >= b, 2.0 * math.pi * a, np.where(a <= -b, 0.0, part))


def _sigma_isotropic(d_norm: Array, u: Array, theta_k: Array) -> Array:
    """``σ(θ_k) = ∫ D(θ) ⟨k·m⟩ dω`` of an isotropic NDF sampled at ``u`` (trapezoid in u)."""
    th = 0.5 * math.pi * u * u
    w = _trapezoid_weights(u) * math.pi * u * np.sin(th) * d_norm  # dθ = π u du
    return _ring_kernel(theta_k, th) @ w


def _fresnel_ratio(source: BRDFSource, u: Array, grid: RGLGrid) -> Array:
    """``F(cos θ)/F(1)`` (luminance of the per-channel eq. 4, and of the model's Fresnel
    tint where it has one) at ``θ = π/2·u²``; 1 without ``eta``.

    Dividing Σ by it leaves ``rgb ≈ k_s S(o) F(i·h)/F(θ_i) ≈ k_s`` at the specular
    peak (h ≈ n, so i·h ≈ cos θ_i), which linear interpolation in θ_i reproduces.
    """
    eta = getattr(source, "eta", None)
    if eta is None or not grid.fresnel_sigma:
        return np.ones_like(u)

    th = 0.5 * math.pi * u * u
    normal = float(_fresnel_luminance(source, np.ones(1))[0])
    if not normal > 0:  # η = 1: no interface, F ≡ 0 at every angle; nothing to take out of rgb
        return np.ones_like(u)
    return _fresnel_luminance(source, np.cos(th)) / normal


def _fresnel_luminance(source: BRDFSource, c: Array) -> Array:
    """The luminance of the source's per-channel Fresnel term at ``c = cos θ_d``: its own
    ``fresnel`` where it has one (a model's includes its tint), else eq. 4 with its ``eta``."""
    own = getattr(source, "fresnel", None)
    if callable(own):
        return np.asarray(own(c), dtype=np.float64) @ LUM
    eta = np.asarray(source.eta, dtype=np.float64)  # type: ignore[attr-defined]  # callers check it
    return fresnel(c[:, None], eta[None, :]) @ LUM


# ------------------------------------------------------------------ tables
@dataclasses.dataclass
class _Tables:
    """The incident-independent tables: N, Σ, the warp and its forward-warped nodes."""

    ndf: Array        # float32-exact values, (rows, cols)
    sigma: Array
    warp: Array       # warp density on its own grid (Mitsuba normalizes it)
    nodes_u: Array    # (n, n, 2) unit coordinates of the rgb nodes
    n_at_nodes: Array  # N interpolated at the nodes (as Mitsuba does)
    g_at_nodes: Array  # the warp's density over the Jacobian at the nodes (for the luminance)
    sigma_interp: Marginal2D


def _f32(a: Array) -> Array:
    return np.asarray(a, dtype=np.float32).astype(np.float64)


def _table(values: Array) -> Marginal2D:
    return Marginal2D(values[None, None], np.zeros(1), np.zeros(1), build_cdf=False)


def _build_tables(source: BRDFSource, d_fn: NDFFunction, iso: bool, grid: RGLGrid) -> _Tables:
    """N, Σ and the warp (see the module docstring), and the warp's image of the rgb nodes."""
    if iso:
        u0 = np.linspace(0.0, 1.0, grid.ndf_iso)
        # a source that declares itself isotropic has D(θ) alone; any other one
        # (a hemicube model of an isotropic material) is averaged around each ring
        d = _ring_means(d_fn, u0, 1 if getattr(source, "isotropic", False) else 64)[None, :]
    else:
        rows, cols = grid.ndf
        u0 = np.linspace(0.0, 1.0, cols)
        d = np.maximum(d_fn(_grid_dirs(u0, np.linspace(0.0, 1.0, rows))), 0.0)
    th = 0.5 * math.pi * u0 * u0
    ring = d[:-1].mean(axis=0) if not iso else d[0]  # the last row repeats the first azimuth
    norm = float(np.sum(_trapezoid_weights(u0) * math.pi * u0 * np.sin(th) * np.cos(th) * ring) * 2 * math.pi)
    if not (norm > 0 and np.isfinite(norm)):
        raise ParameterError(f"{shown_path(source.path or source.name)}: no positive NDF or back-scattering "
                             "(f(m, m) at θ_d = 0, unmeasured or zero) to build the RGL tables from")
    d, ring = d / norm, ring / norm
    c = _floor(source, ring, u0, grid.floor_scale)
    n_vals = (d + c) / (1.0 + math.pi * c)  # ∫ N cos dω = 1
    ndf_tab = _f32(np.concatenate([n_vals, n_vals]) if iso else n_vals)
    # Σ from the azimuthal mean of D, also for anisotropic files: it only has to take
    # the 1/cos θ_i out of rgb, and what it leaves (σ's azimuthal variation) is smooth
    us = np.linspace(0.0, 1.0, grid.sigma)
    s = _sigma_isotropic(ring, u0, 0.5 * math.pi * us * us) / _fresnel_ratio(source, us, grid)
    s = np.maximum(s, 1e-6 * s.max())
    sig_tab = _f32(np.stack([s, s]))
    warp, g = _warp(ndf_tab, c / (1.0 + math.pi * c), grid)
    n = grid.rgb if iso else grid.rgb_aniso
    lin = np.linspace(0.0, 1.0, n)
    s_nodes = np.stack(np.meshgrid(lin, lin, indexing="xy"), axis=-1)  # (row, col, 2): x = column
    wm = Marginal2D(warp[None, None], np.zeros(1), np.zeros(1))
    nodes_u = wm.sample(s_nodes, 0)
    zero = np.zeros(nodes_u.shape[:-1])
    n_at = _table(ndf_tab).eval(nodes_u, zero, zero)
    g_at = _table(g).eval(nodes_u, zero, zero)
    return _Tables(ndf_tab, sig_tab, warp.astype(np.float32), nodes_u, n_at, g_at, _table(sig_tab))


def _warp(ndf_tab: Array, floor: float, grid: RGLGrid) -> tuple[Array, Array]:
    """The warp density on its grid (float32-exact, 2 rows × ``warp`` columns) and
    ``g = density/Jacobian`` there.

    The warp is uniform in ``u₁`` (so a node's azimuth is the same in every row and
    slice) and its column density is the sum of three shares, each normalized:
    ``uniform``, uniform in solid angle; ``flank``, ``∝ |∂ log(N + κ c)/∂u₀|`` (the
    azimuthal mean), which puts nodes where the lobe falls to the floor and ``rgb``
    turns from the specular to the diffuse ratio; the rest ``∝ ⟨(N/N_max)^temper⟩``
    times the Jacobian to the power ``lobe_measure`` (the lobe itself, in a measure
    between the unit coordinates and solid angle).
    """
    u0 = np.linspace(0.0, 1.0, grid.warp)
    src_u0 = np.linspace(0.0, 1.0, ndf_tab.shape[1])
    rows = np.stack([np.interp(u0, src_u0, r) for r in ndf_tab])
    jac = _jacobian(u0)
    w = _trapezoid_weights(u0)
    with np.errstate(divide="ignore"):
        lobe = ((rows / rows.max()) ** grid.temper).mean(axis=0)
        lobe = lobe * np.where(jac > 0, jac / jac.max(), 1.0) ** grid.lobe_measure
    log_n = np.log(rows + grid.flank_floor * floor + 1e-30 * rows.max())
    slope = ndimage.uniform_filter1d(np.abs(np.gradient(log_n, u0, axis=1)).mean(axis=0), 3, mode="nearest")
    dens = (1.0 - grid.uniform - grid.flank) * lobe / np.sum(lobe * w) + grid.uniform * jac / np.sum(jac * w)
    if grid.flank > 0 and np.sum(slope * w) > 0:
        dens = dens + grid.flank * slope / np.sum(slope * w)
    dens = _f32(np.maximum(dens, 1e-7 * float(dens.max())))
    g = dens / np.maximum(jac, 1e-12 * jac.max())
    return np.stack([dens, dens]), np.stack([g, g])


#: The grazing slice (θ_i = 90°) is evaluated this far above the horizon: a source
#: evaluated at cos θ_i ≈ 6·10⁻¹⁷ may return anything (an analytic GGX's Smith
#: term, clipped at 10⁻¹², gave f·cos θ_o ≈ 2000 and fireflies in every render).
GRAZING_EVAL = 1e-3


def _incident_dirs(iso: bool, grid: RGLGrid) -> tuple[Array, Array, Array]:
    """``(phi_i, theta_i, wi)`` of the incident grid; ``wi`` shape ``(n_phi, n_theta, 3)``.

    ``wi`` of the last elevation (90°) lies :data:`GRAZING_EVAL` above the horizon.
    """
    theta_i = theta_i_nodes(grid.n_theta_i if iso else grid.n_theta_i_aniso, grid.theta_i_grazing)
    phi_i = np.zeros(1) if iso else np.linspace(-math.pi, math.pi, grid.n_phi_i)
    th, ph = np.meshgrid(np.minimum(theta_i, 0.5 * math.pi - GRAZING_EVAL), phi_i)
    wi = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1)
    return phi_i, theta_i, wi


def _slices(source: BRDFSource, tabs: _Tables, wi: Array, phi_i: Array,
            theta_i: Array) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """``rgb`` ``(n_phi, n_theta, 3, n, n)`` and ``luminance`` ``(n_phi, n_theta, n, n)`` of every incident node."""
    n = tabs.nodes_u.shape[0]
    u = tabs.nodes_u.reshape(-1, 2)
    zero = np.zeros(len(theta_i))
    u_wi = np.stack([np.sqrt(theta_i * 2 / math.pi), np.zeros_like(theta_i)], -1)
    rgb = np.empty((len(phi_i), len(theta_i), 3, n, n), np.float32)
    lum = np.empty((len(phi_i), len(theta_i), n, n), np.float32)
    n_at = tabs.n_at_nodes.reshape(-1)
    g_at = tabs.g_at_nodes.reshape(-1)
    # the nodes' half vectors: relative to φ_i = 0 (the one slice) in an isotropic
    # file, absolute in an anisotropic one; the same in every slice either way
    m_nodes = _unit_dirs(u[:, 0], u[:, 1])
    for a, ph in enumerate(phi_i):
        u_wi[:, 1] = (ph + math.pi) / (2 * math.pi)
        sig = tabs.sigma_interp.eval(u_wi, zero, zero)  # (n_theta,)
        w = wi[a][:, None, :]  # (n_theta, 1, 3)
        m = np.broadcast_to(m_nodes[None], (len(theta_i),) + m_nodes.shape)
        im = np.sum(w * m, -1)
        wo = 2.0 * im[..., None] * m - w
        valid = (im > 1e-6) & (wo[..., 2] > 1e-6)
        f = np.zeros(valid.shape + (3,))
        if valid.any():
            wi_v = np.broadcast_to(w, wo.shape)[valid]
            f[valid] = source.eval(wi_v, wo[valid])
        cos_o = np.maximum(wo[..., 2], 0.0)
        fc = np.maximum(f, 0.0) * cos_o[..., None]
        val = fc * (4.0 * sig[:, None] / np.maximum(n_at, 1e-30)[None, :])[..., None]
        # sampling: density of ω_o ∝ f cos θ_o needs luminance ∝ f cos θ_o · 4(i·m) / g
        lv = (fc @ LUM) * np.maximum(im, 0.0) / np.maximum(g_at, 1e-30)[None, :]
        val = _fill_invalid(val.reshape(len(theta_i), n, n, 3), valid.reshape(len(theta_i), n, n))
        rgb[a] = np.moveaxis(val, -1, 1)
        lv = np.where(valid, lv, 0.0).reshape(len(theta_i), n, n)
        lum[a] = np.maximum(lv, 1e-5 * np.maximum(lv.max(axis=(1, 2), keepdims=True), 1e-30))
    return rgb, lum


def _fill_invalid(val: Array, valid: NDArray[np.bool_]) -> Array:
    """Nodes whose ω_o is below the horizon (or ``i·m ≤ 0``) get the mean of their valid 8-neighbours.

    Mitsuba never evaluates such a node's own half vector (it masks ω_o below the
    horizon) but interpolates it into the cells it shares with valid nodes; only the
    nodes next to a valid one matter, and the rest stay 0. ``val`` ``(S, n, n, 3)``,
    ``valid`` ``(S, n, n)``.
    """
    w = valid.astype(np.float64)
    pv = np.pad(val * w[..., None], ((0, 0), (1, 1), (1, 1), (0, 0)))
    pw = np.pad(w, ((0, 0), (1, 1), (1, 1)))
    n = val.shape[1]
    total = np.zeros_like(val)
    count = np.zeros(w.shape)
    for dy in (0, 1, 2):
        for dx in (0, 1, 2):
            if dy == dx == 1:
                continue
            total += pv[:, dy:dy + n, dx:dx + n]
            count += pw[:, dy:dy + n, dx:dx + n]
    fill = np.divide(total, count[..., None], out=np.zeros_like(total), where=count[..., None] > 0)
    return np.where(valid[..., None], val, fill)


def rgl_tables(source: BRDFSource, grid: RGLGrid = RGLGrid(), isotropic: bool | None = None,
               description: str | None = None) -> dict[str, np.ndarray]:
    """The fields of an RGL ``.bsdf`` file reproducing ``source`` (see the module docstring).

    ``isotropic=None`` follows the source (its ``isotropic`` attribute, or an NDF that
    varies by < 2 % around every ring).

    Parameters
    ----------
    source
        Any BRDF (sr⁻¹).
    grid
        Table resolutions and warp settings.
    isotropic
        Write an isotropic file (True), an anisotropic one (False) or follow the source (None).
    description
        The file's description line; :func:`export_description` if None.

    Returns
    -------
    dict of str to ndarray
        The fields ``description``, ``phi_i``, ``theta_i``, ``ndf``, ``sigma``, ``vndf``,
        ``luminance``, ``rgb`` and ``jacobian``, in the dtypes of Mitsuba's reader.

    Raises
    ------
    ParameterError
        (a ``ValueError``) When the source gives non-finite values, or no positive NDF
        or back-scattering to build the tables from.
    """
    d_fn, iso_guess = proxy_ndf(source)
    iso = iso_guess if isotropic is None else bool(isotropic)
    tabs = _build_tables(source, d_fn, iso, grid)
    phi_i, theta_i, wi = _incident_dirs(iso, grid)
    rgb, lum = _slices(source, tabs, wi, phi_i, theta_i)
    if not (np.all(np.isfinite(rgb)) and np.all(np.isfinite(lum))):
        raise ParameterError(f"{shown_path(source.path or source.name)}: non-finite values while building "
                             "the RGL tables")
    vndf = np.broadcast_to(tabs.warp, (len(phi_i), len(theta_i)) + tabs.warp.shape)
    # a file name that is not valid UTF-8 (surrogate escapes) is written with backslash escapes
    desc = (description if description is not None else export_description(source, iso)).encode(
        "utf-8", "backslashreplace")
    return {
        "description": np.frombuffer(desc, dtype=np.uint8).copy(),
        "phi_i": phi_i.astype(np.float32),
        "theta_i": theta_i.astype(np.float32),
        "ndf": tabs.ndf.astype(np.float32),
        "sigma": tabs.sigma.astype(np.float32),
        "vndf": np.ascontiguousarray(vndf, dtype=np.float32),
        "luminance": lum,
        "rgb": rgb,
        "jacobian": np.array([1], np.uint8),
    }


# ------------------------------------------------------------------ description
def _capture_info(source: BRDFSource) -> dict[str, str]:
    """Material, device and capture of a model, as its metadata records them
    (:func:`reflecto.workflow.save_model` writes them from the capture's manifest); the
    capture by its folder's name, which does not depend on how the model's path was typed."""
    meta = getattr(source, "metadata", None) or {}
    info = {k: str(meta[k]) for k in ("material", "device", "capture") if meta.get(k)}
    if "capture" in info:
        info["capture"] = Path(info["capture"]).name or info["capture"]
    return info


def export_description(source: BRDFSource, isotropic: bool) -> str:
    """One line naming the material, its capture, its parameters and the reflecto version.

    Parameters
    ----------
    source
        The exported BRDF.
    isotropic
        Whether the file is written isotropic.

    Returns
    -------
    str
        The description stored in the file.
    """

    info = _capture_info(source)
    parts = [f"reflecto {__version__} export of {source.name}"]
    if "material" in info:
        parts.append(f"material {info['material']}")
    if "capture" in info:
        parts.append(f"capture {info['capture']}" + (f" (device {info['device']})" if "device" in info else ""))
    elif "device" in info:
        parts.append(f"device {info['device']}")
    parts.append(f"source kind {source.kind}")
    for key, label in (("kd", "k_d"), ("ks", "k_s"), ("eta", "eta")):
        v = getattr(source, key, None)
        if key == "eta" and v is not None and is_constant(v):
            parts.append("constant Fresnel (F = 1)")
        elif v is not None:
            parts.append(f"{label} (R,G,B) " + " ".join(f"{float(x):.4g}" for x in np.ravel(v)))
    params = source.parameters()
    for key in ("resolution", "shadowing"):
        if key in params:
            parts.append(f"{key} {params[key]}")
    parts.append("isotropic table (one phi_i)" if isotropic else "anisotropic table")
    return "; ".join(parts)


def export_rgl(source: BRDFSource, path: str | Path, grid: RGLGrid = RGLGrid(), isotropic: bool | None = None,
               description: str | None = None) -> Path:
    """Write ``source`` as an RGL ``.bsdf`` file (atomically); returns the path.

    The file is read back by reflecto's own reader (:class:`reflecto.sources.rgl.RGLBRDF`,
    with the checks of docs/limits.md) before it takes its name: reflecto writes only
    what it reads.

    Parameters
    ----------
    source
        Any BRDF (sr⁻¹); a model's own NDF shapes the file's warp.
    path
        The ``.bsdf`` file to write (Mitsuba 3's ``measured`` plugin reads it; docs/mitsuba.md).
    grid
        Table resolutions and warp settings.
    isotropic
        Write an isotropic file (True), an anisotropic one (False) or follow the source (None).
    description
        The file's description line; :func:`export_description` if None.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    FileFormatError
        Naming ``path``, when the tables would not pass the reader's checks.
    ParameterError
        For a path whose name does not end in ``.bsdf``, or ``isotropic`` none of True,
        False, None.
    """
    path = Path(path)
    if path.suffix.lower() != ".bsdf":
        raise ParameterError(f"{shown_path(path)}: not written, an RGL file's name must end in .bsdf")
    if isotropic is not None and not isinstance(isotropic, (bool, np.bool_)):
        raise ParameterError(f"isotropic must be True, False or None, got {short_repr(isotropic)}")
    tables = rgl_tables(source, grid, isotropic, description)
    with atomic_path(path, suffix=".bsdf") as tmp:
        write_tensor_file(tmp, tables)
        try:
            RGLBRDF(tmp)
        except FileFormatError as e:
            raise FileFormatError(path, f"not written: the file would be refused on reading ({e.problem})") from None
    return path
