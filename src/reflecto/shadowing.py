"""APS shadowing/masking derived from a tabulated NDF (eq. 8 of Lan et al. 2010).

Ashikhmin, Premože & Shirley 2000; algorithm-reference §1.2–§1.5::

    S(k) = (k·n) / σ(k),   σ(k) = ∫_{Ω+} ⟨k, h⟩ D(h) dω_h            (eq. 8 / 1.3)

σ is the projected area of the front-facing microfacets (Dupuy & Jakob's ``sigma``);
``S`` equals the exact Smith G1 of the same NDF. We tabulate σ on a (θ, φ) grid and
interpolate it bilinearly; ``S = cos θ / max(σ, cos θ)`` is then clamped to ≤ 1
(algorithm-reference §1.2, consequence 2).

σ is integrated on a polar grid whose rings are dense near the normal (θ = u²·π/2);
for each θ_k the sum over azimuth is a circular convolution, evaluated by FFT with a
kernel spectrum that depends only on the grid (cached). Unlike a coarse box-filtered
hemicube, this stays exact where the terminator ``k·h = 0`` cuts a sharp lobe, which
is the case that matters at grazing ``k``.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import _kernels
from .hemicube import Hemicube

Array = NDArray[np.float64]

#: Default σ grid: θ from 0 to 90° in 1° steps (91 nodes), φ in 2.8125° steps (128 nodes).
N_THETA = 91
N_PHI = 128


@dataclass(frozen=True)
class SigmaTable:
    """Projected-area table ``σ(θ, φ)`` with bilinear interpolation.

    Attributes
    ----------
    sigma : ndarray, shape (n_theta, n_phi)
        σ at θ_j = j·(π/2)/(n_theta − 1) and φ_k = 2πk/n_phi (dimensionless).
    """

    sigma: Array

    @property
    def n_theta(self) -> int:
        """Number of θ nodes (first axis of ``sigma``)."""
        return self.sigma.shape[0]

    @property
    def n_phi(self) -> int:
        """Number of φ nodes (second axis of ``sigma``)."""
        return self.sigma.shape[1]

    def grid_directions(self) -> Array:
        """The directions of this table's nodes (:func:`grid_directions`).

        Returns
        -------
        ndarray, shape (n_theta, n_phi, 3)
            Unit vectors at ``(θ_j, φ_k)``.
        """
        return grid_directions(self.n_theta, self.n_phi)

    def eval_sigma(self, dirs: ArrayLike) -> Array:
        """Bilinearly interpolated σ (the denominator of eq. 8).

        Parameters
        ----------
        dirs : array_like, shape (..., 3)
            Unit directions in the local frame (θ clipped to the upper hemisphere).

        Returns
        -------
        ndarray, shape (...)
            σ (dimensionless), not clamped.
        """
        st = grid_stencil(dirs, self.n_theta, self.n_phi)
        flat = self._flat()
        w = self.n_phi + 1
        s00 = flat[st.idx]
        s01 = flat[st.idx + 1]
        s10 = flat[st.idx + w]
        s11 = flat[st.idx + w + 1]
        s00 += st.fp * (s01 - s00)
        s10 += st.fp * (s11 - s10)
        s00 += st.ft * (s10 - s00)
        return s00.reshape(st.shape)

    def _flat(self) -> Array:
        """σ with the φ = 0 column repeated at φ = 2π, flattened (cached)."""
        flat = self.__dict__.get("_flat_cache")
        if flat is None:
            flat = np.concatenate([self.sigma, self.sigma[:, :1]], axis=1).ravel()
            object.__setattr__(self, "_flat_cache", flat)
        return flat

    def eval_sigma_clamped(self, dirs: ArrayLike) -> Array:
        """``max(σ, cos θ)``: the σ that makes ``S ≤ 1`` (dj_brdf's clamp, algorithm-reference §1.2).

        Parameters
        ----------
        dirs : array_like, shape (..., 3)
            Unit directions in the local frame.

        Returns
        -------
        ndarray, shape (...)
            The clamped σ.
        """
        d = np.asarray(dirs, dtype=np.float64)
        return np.maximum(self.eval_sigma(d), np.maximum(d[..., 2], 0.0))

    def eval(self, dirs: ArrayLike) -> Array:
        """Shadowing ``S(k) = (k·n)/max(σ(k), k·n)`` (eq. 8), in [0, 1].

        Parameters
        ----------
        dirs : array_like, shape (..., 3)
            Unit directions ``k`` in the local frame.

        Returns
        -------
        ndarray, shape ``dirs.shape[:-1]``
            S; 0 below the horizon.
        """
        d = np.asarray(dirs, dtype=np.float64)
        cos = np.maximum(d[..., 2], 0.0)
        sig = self.eval_sigma_clamped(d)
        return np.divide(cos, sig, out=np.zeros_like(cos), where=sig > 0)

    def eval_at(self, stencil: GridStencil) -> Array:
        """:meth:`eval` at the directions of a precomputed :func:`grid_stencil`.

        For directions evaluated against many tables (the reconstruction's inner loop),
        where finding the cell (``acos``, ``atan2``) costs more than the interpolation.

        Parameters
        ----------
        stencil
            From :func:`grid_stencil` with this table's ``n_theta`` and ``n_phi``.

        Returns
        -------
        ndarray, shape ``stencil.shape``
            S at the stencil's directions.

        Raises
        ------
        ValueError
            When the stencil was made for another grid.
        """
        if (stencil.n_theta, stencil.n_phi) != (self.n_theta, self.n_phi):
            raise ValueError("stencil was made for a different σ grid")
        out = np.empty(len(stencil.idx))
        _kernels.shadowing_at(self._flat(), self.n_phi + 1, stencil.idx, stencil.ft, stencil.fp, stencil.cos, out)
        return out.reshape(stencil.shape)

    def azimuthal_min(self) -> SigmaTable:
        """``S(θ, φ) ← min_φ' S(θ, φ')`` (Lan et al. §5.2, after Wang et al. 2008).

        Since ``S = cos θ/σ``, the minimum of S over azimuth is the maximum of σ.

        Returns
        -------
        SigmaTable
            A table whose every row is that row's maximum σ over φ.
        """
        return SigmaTable(np.repeat(self.sigma.max(axis=1, keepdims=True), self.n_phi, axis=1))


@dataclass(frozen=True)
class GridStencil:
    """Bilinear cells of fixed directions in a (θ, φ) σ grid (see :meth:`SigmaTable.eval_at`)."""

    idx: NDArray[np.intp]
    ft: Array
    fp: Array
    cos: Array
    shape: tuple[int, ...]
    n_theta: int
    n_phi: int


def grid_stencil(dirs: ArrayLike, n_theta: int = N_THETA, n_phi: int = N_PHI) -> GridStencil:
    """Cells and weights of unit ``dirs`` (shape ``(..., 3)``) in an ``n_theta × n_phi`` σ grid.

    θ and φ map linearly to grid coordinates; truncation gives the cell (φ is shifted
    by a full turn so that it is positive), the remainders are the bilinear weights.

    Parameters
    ----------
    dirs : array_like, shape (..., 3)
        Unit directions in the local frame.
    n_theta, n_phi
        The σ grid's sizes (θ from 0 to 90°, φ over a full turn).

    Returns
    -------
    GridStencil
        Flat cell indices into the φ-wrapped table, θ and φ weights, ``cos θ`` (clipped
        at 0) and the shape ``...`` of ``dirs``.
    """
    d = np.asarray(dirs, dtype=np.float64)
    x, y, z = d.reshape(-1, 3).T.copy()
    cos = np.maximum(z, 0.0)
    np.clip(z, 0.0, 1.0, out=z)
    t = np.arccos(z, out=z)
    t *= (n_theta - 1) / (0.5 * np.pi)
    p: Array = np.arctan2(y, x)
    p *= n_phi / (2.0 * np.pi)
    p += n_phi
    t0 = np.minimum(t.astype(np.intp), n_theta - 2)
    p0 = p.astype(np.intp)
    ft = t - t0
    fp = p - p0
    p0 %= n_phi
    return GridStencil(t0 * (n_phi + 1) + p0, ft, fp, cos, d.shape[:-1], n_theta, n_phi)


def grid_directions(n_theta: int = N_THETA, n_phi: int = N_PHI) -> Array:
    """Directions of the σ grid: ``θ_j = j·(π/2)/(n_theta − 1)``, ``φ_k = 2πk/n_phi``.

    Parameters
    ----------
    n_theta, n_phi
        Numbers of θ and φ nodes.

    Returns
    -------
    ndarray, shape (n_theta, n_phi, 3)
        Unit vectors.
    """
    theta = np.linspace(0.0, 0.5 * np.pi, n_theta)
    phi = np.arange(n_phi) * (2.0 * np.pi / n_phi)
    st = np.sin(theta)[:, None]
    return np.stack(
        np.broadcast_arrays(st * np.cos(phi)[None], st * np.sin(phi)[None], np.cos(theta)[:, None]),
        axis=-1,
    )


def sigma_direct(cube: Hemicube, ndf: ArrayLike, dirs: ArrayLike, chunk: int = 256) -> Array:
    """Brute-force ``σ(k) = Σ_t max(0, k·h_t) D_t Ω_t`` over every texel (reference).

    Cost is ``O(len(dirs) · cube.size)``; use :func:`sigma_table` for whole grids.

    Parameters
    ----------
    cube
        Geometry of ``ndf``.
    ndf : array_like, shape (cube.size,)
        D on the texels, sr⁻¹.
    dirs : array_like, shape (..., 3)
        Unit directions ``k``.
    chunk
        Directions per matrix product (memory bound).

    Returns
    -------
    ndarray, shape (...)
        σ(k) (dimensionless for a normalized D).
    """
    k = np.asarray(dirs, dtype=np.float64).reshape(-1, 3)
    m = (np.asarray(ndf, dtype=np.float64) * cube.solid_angles)[:, None] * cube.directions
    out = np.empty(len(k))
    for s in range(0, len(k), chunk):
        out[s : s + chunk] = np.maximum(k[s : s + chunk] @ m.T, 0.0).sum(axis=1)
    return out.reshape(np.shape(dirs)[:-1])


#: Polar quadrature of σ: θ_h rings at u = (j + ½)/N_U with θ = u²·π/2 (dense near
#: the normal, where sharp lobes live), N_PHI_QUAD azimuths per ring.
N_U = 128
N_PHI_QUAD = 256


@functools.lru_cache(maxsize=4)
def _kernel_spectrum(n_theta: int, n_u: int, n_phi: int) -> tuple[Array, Array, Array]:
    """The rFFT over Δφ of ``K(θ_k, θ_h, Δφ) = max(0, sinθ_k sinθ_h cosΔφ + cosθ_k cosθ_h)``.

    Returns the (real) spectrum (shape ``(n_phi//2 + 1, n_theta, n_u)``), the ring polar
    angles θ_h and the ring weights ``sinθ_h dθ_h dφ`` (sr per quadrature node).
    """
    theta_k = np.linspace(0.0, 0.5 * np.pi, n_theta)
    u = (np.arange(n_u) + 0.5) / n_u
    theta_h = u * u * (0.5 * np.pi)
    weight = np.sin(theta_h) * (np.pi * u / n_u) * (2.0 * np.pi / n_phi)
    dphi = np.arange(n_phi) * (2.0 * np.pi / n_phi)
    k = (
        np.sin(theta_k)[:, None, None] * np.sin(theta_h)[None, :, None] * np.cos(dphi)[None, None, :]
        + np.cos(theta_k)[:, None, None] * np.cos(theta_h)[None, :, None]
    )
    # K is even in Δφ, so its spectrum is real (the imaginary part is rounding noise,
    # ~1e-16 of the real one): keep it real. Stored (F, n_theta, n_u): sigma_table
    # contracts u per frequency as one batched real matmul.
    spec = np.ascontiguousarray(np.fft.rfft(np.maximum(k, 0.0), axis=-1).real.transpose(2, 0, 1))
    spec.setflags(write=False)
    return spec, theta_h, weight


@functools.lru_cache(maxsize=8)
def polar_directions(n_u: int = N_U, n_phi: int = N_PHI_QUAD) -> Array:
    """Quadrature nodes of :func:`sigma_table`, shape ``(n_u, n_phi, 3)`` (cached, read-only)."""
    u = (np.arange(n_u) + 0.5) / n_u
    theta = u * u * (0.5 * np.pi)
    phi = np.arange(n_phi) * (2.0 * np.pi / n_phi)
    st = np.sin(theta)[:, None]
    out = np.stack(
        np.broadcast_arrays(st * np.cos(phi)[None], st * np.sin(phi)[None], np.cos(theta)[:, None]),
        axis=-1,
    )
    out.setflags(write=False)
    return out


def sigma_table(
    cube: Hemicube,
    ndf: ArrayLike,
    n_theta: int = N_THETA,
    n_phi: int = N_PHI,
    n_u: int = N_U,
    padded: Array | None = None,
    n_phi_quad: int = N_PHI_QUAD,
) -> SigmaTable:
    """Tabulate σ of a hemicube NDF (the denominator of eq. 8) on the (θ, φ) grid.

    D is resampled (bilinearly) on a polar grid; for each θ_k the azimuthal sum is a
    circular convolution, done by FFT against a cached kernel spectrum. The result
    is divided by the same quadrature's ``∫ D cos θ dω`` so that ``σ(n) = 1`` and
    ``S(n) = 1`` hold exactly for a normalized D.

    Parameters
    ----------
    cube
        Geometry of ``ndf``.
    ndf
        D on the hemicube texels, shape ``(cube.size,)`` (sr⁻¹), normalized by AR 1.2.
    n_theta, n_phi
        Output grid: θ in [0°, 90°] with ``n_theta`` nodes, ``n_phi`` azimuths
        (``n_phi`` must divide the quadrature's 256 azimuths).
    n_u
        Number of polar quadrature rings.
    padded
        ``cube.pad(ndf)`` if already at hand.
    n_phi_quad
        Quadrature azimuths per ring.

    Returns
    -------
    SigmaTable
        σ, shape ``(n_theta, n_phi)``, non-negative, with ``σ(n) = 1``.

    Raises
    ------
    ValueError
        When ``n_phi`` does not divide ``n_phi_quad``.
    """
    if n_phi_quad % n_phi:
        raise ValueError(f"n_phi must divide the quadrature's {n_phi_quad} azimuths, got {n_phi}")
    spec, theta_h, weight = _kernel_spectrum(n_theta, n_u, n_phi_quad)
    d_polar = cube.lookup(ndf, polar_directions(n_u, n_phi_quad), padded)  # (n_u, n_phi_quad)
    d_polar = np.maximum(d_polar, 0.0) * weight[:, None]
    norm = float(np.sum(d_polar * np.cos(theta_h)[:, None]))
    d_spec = np.fft.rfft(d_polar, axis=-1)  # (n_u, F)
    # circular convolution over φ: σ(θk, φk) = Σ_h D(θh, φh) K(θk, θh, φk − φh)
    # Σ_u spec[f, t, u] d[u, f] for the real and imaginary parts at once → (t, f)
    parts = np.matmul(spec, np.stack([d_spec.real.T, d_spec.imag.T], axis=-1))  # (F, t, 2)
    sig_spec = (parts[..., 0] + 1j * parts[..., 1]).T
    sigma = np.fft.irfft(sig_spec, n=n_phi_quad, axis=-1)[:, :: n_phi_quad // n_phi]
    if norm > 0:
        sigma = sigma / norm
    return SigmaTable(np.maximum(sigma, 0.0))
