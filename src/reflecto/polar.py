"""Isotropic NDFs tabulated over the polar angle, ``D(θ_h)``, and their shadowing (eqs. 1, 8).

An isotropic material's NDF depends on ``θ_h`` only. It is stored on polar nodes
``θ_k`` whose spacing grows with the angle (:func:`polar_nodes`: fine at the pole,
where sharp specular peaks live, coarse at grazing angles) and interpolated
linearly in ``log D`` between them, so that a lobe falling over decades stays
positive and smooth.

Two integrals of ``D`` follow from its azimuthal symmetry in closed form over the
azimuth (algorithm-reference §1.2, §1.4):

* the normalization of AR 1.2, ``∫ D(h)(h·n) dω_h = 2π ∫ D(θ) cos θ sin θ dθ = 1``;
* the projected area of AR 1.3 (the denominator of eq. 8),
  ``σ(θ_k) = ∫ ⟨k, h⟩ D(h) dω_h = ∫ D(θ) A(θ_k, θ) sin θ dθ`` with
  ``A(θ_k, θ) = ∫₀^{2π} max(0, cos θ_k cos θ + sin θ_k sin θ cos φ) dφ``
  (:func:`azimuthal_kernel`), so ``S(k) = cos θ_k / max(σ(k), cos θ_k)`` (eq. 8).

Both are sums over a fixed polar quadrature (:data:`QUADRATURE_RINGS` rings,
``θ = u² π/2``, dense at the pole), i.e. one matrix–vector product each.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import _kernels
from .errors import ParameterError

Array = NDArray[np.float64]

__all__ = ["IsotropicNDF", "NodeNDFs", "ShadowingCells", "azimuthal_kernel", "polar_nodes", "interpolation_cells",
           "shadowing_cells"]

#: Node spacing at the pole (radians): 0.1°, half the camera's angular sampling of
#: the half vector (a pixel moves h by ≈ 0.2°), so that the sharpest peaks it can
#: resolve are resolved by the table too.
POLE_SPACING = math.radians(0.1)
#: The node spacing grows by this fraction of the polar angle (relative resolution
#: 4 %: 0.5° at 10°, 2° at 45°), as a lobe's structure scales with its width.
SPACING_GROWTH = 0.04
#: Rings of the polar quadrature of the normalization and of σ.
QUADRATURE_RINGS = 2048
#: Polar angles of the σ table (1° steps would miss the grazing fall of S of sharp lobes: 0.5°).
SIGMA_NODES = 181


def polar_nodes(pole_spacing: float = POLE_SPACING, growth: float = SPACING_GROWTH) -> Array:
    """Polar nodes ``θ_k`` (radians) from 0 to π/2 with ``dθ/ds = pole_spacing + growth θ``.

    ``θ(s) = (pole_spacing / growth)(e^{growth s} − 1)``, ``s`` uniform; the last node is
    exactly π/2. With the defaults, 92 nodes.
    """
    s_max = math.log1p(0.5 * math.pi * growth / pole_spacing) / growth
    n = int(math.ceil(s_max)) + 1
    nodes = (pole_spacing / growth) * np.expm1(growth * np.linspace(0.0, s_max, n))
    nodes[-1] = 0.5 * math.pi
    return nodes


def interpolation_cells(nodes: Array, theta: ArrayLike) -> tuple[NDArray[np.intp], Array]:
    """Cell index ``j`` (``nodes[j] ≤ θ ≤ nodes[j+1]``) and weight ``t ∈ [0, 1]`` of each θ.

    Linear interpolation of a nodal quantity ``z`` is ``(1 − t) z[j] + t z[j + 1]``.
    """
    theta = np.asarray(theta, dtype=np.float64)
    j = np.clip(np.searchsorted(nodes, theta, side="right") - 1, 0, len(nodes) - 2)
    t = np.clip((theta - nodes[j]) / (nodes[j + 1] - nodes[j]), 0.0, 1.0)
    return j, t


@functools.lru_cache(maxsize=8)
def cell_table(edges_key: bytes, steps: int = 2048) -> NDArray[np.intp]:
    """The cell of ``steps`` equal steps of ``[0, edges[-1])`` (``edges`` increasing from 0,
    as bytes): ``c[i]`` with ``edges[c] ≤ i · edges[-1]/steps < edges[c + 1]``, read-only.

    A compiled loop's first guess of an angle's cell (:mod:`reflecto.reconstruct._polar_kernels`,
    :mod:`~reflecto.reconstruct._normal_kernels`), which it moves up edge by edge to the
    exact cell (the one bisection finds): one table read and a step or two instead of a
    bisection's ≈ 8 branches.
    """
    edges = np.frombuffer(edges_key, dtype=np.float64)
    theta = np.arange(steps) * (edges[-1] / steps)
    out = np.clip(np.searchsorted(edges, theta, side="right") - 1, 0, len(edges) - 2).astype(np.intp)
    out.setflags(write=False)
    return out


def azimuthal_kernel(theta_k: Array, theta_h: Array) -> Array:
    """``A(θ_k, θ_h) = ∫₀^{2π} max(0, cos θ_k cos θ_h + sin θ_k sin θ_h cos φ) dφ``.

    With ``a = cos θ_k cos θ_h`` and ``b = sin θ_k sin θ_h``: ``2π a`` where ``a ≥ b``,
    0 where ``a ≤ −b``, else ``2 (a φ₀ + b sin φ₀)`` with ``φ₀ = arccos(−a/b)``.
    Shape ``(len(theta_k), len(theta_h))``.
    """
    a = np.cos(theta_k)[:, None] * np.cos(theta_h)[None, :]
    b = np.sin(theta_k)[:, None] * np.sin(theta_h)[None, :]
    partial = np.abs(a) < b
    phi0 = np.arccos(np.clip(-a / np.where(partial, b, 1.0), -1.0, 1.0))
    return np.where(partial, 2.0 * (a * phi0 + b * np.sin(phi0)), np.where(a >= b, 2.0 * math.pi * a, 0.0))


@dataclasses.dataclass(frozen=True)
class _Quadrature:
    """The polar quadrature of a node grid: interpolation cells, weights and the σ matrix."""

    cells: NDArray[np.intp]
    t: Array
    norm_weights: Array  # ∫ D cos dω = norm_weights @ D(θ_q)
    sigma_matrix: Array  # σ(θ_s) = sigma_matrix @ D(θ_q)
    sigma_theta: Array


@functools.lru_cache(maxsize=8)
def _quadrature(nodes_key: bytes) -> _Quadrature:
    nodes = np.frombuffer(nodes_key, dtype=np.float64)
    u = (np.arange(QUADRATURE_RINGS) + 0.5) / QUADRATURE_RINGS
    theta = 0.5 * math.pi * u * u
    ring = np.sin(theta) * (math.pi * u / QUADRATURE_RINGS)  # sin θ dθ of each ring
    j, t = interpolation_cells(nodes, theta)
    theta_s = _sigma_grid()
    q = _Quadrature(j, t, 2.0 * math.pi * np.cos(theta) * ring, azimuthal_kernel(theta_s, theta) * ring[None, :],
                    theta_s)
    for a in (q.cells, q.t, q.norm_weights, q.sigma_matrix, q.sigma_theta):
        a.setflags(write=False)
    return q


def lobe_half_width_deg(nodes: Array, values: Array) -> float:
    """Half width at half maximum (degrees) of a tabulated isotropic NDF ``D(θ_h)``
    (``nodes`` in radians), linear between the nodes; 90 where it never halves."""
    theta = np.linspace(0.0, float(nodes[-1]), 9001)
    d = np.interp(theta, nodes, values)
    below = np.flatnonzero(d < 0.5 * d[0])
    return math.degrees(float(theta[below[0]])) if len(below) else 90.0


@dataclasses.dataclass(frozen=True)
class ShadowingCells:
    """Fixed directions prepared once for their ``S`` under many NDFs (a fit's bins).

    Attributes
    ----------
    cos
        ``cos θ`` clipped to [0, 1], shape ``(B,)``.
    cell
        The σ table's cell of ``θ = arccos(cos)``: ``θ_s[cell] ≤ θ < θ_s[cell + 1]``, the last
        node where ``θ`` is π/2 (as ``np.interp`` finds it), shape ``(B,)``.
    offset
        ``θ − θ_s[cell]`` (radians), shape ``(B,)``.
    """

    cos: Array
    cell: NDArray[np.intp]
    offset: Array


def shadowing_cells(cos_theta: ArrayLike) -> ShadowingCells:
    """:class:`ShadowingCells` of the cosines ``cos_theta`` (shape ``(B,)``) on the σ table's
    polar angles (:data:`SIGMA_NODES` from 0 to π/2, the same for every node grid)."""
    c = np.clip(np.asarray(cos_theta, dtype=np.float64), 0.0, 1.0)
    theta = np.arccos(c)
    grid = _sigma_grid()
    cell = np.clip(np.searchsorted(grid, theta, side="right") - 1, 0, len(grid) - 1)
    out = ShadowingCells(c, cell.astype(np.intp), theta - grid[cell])
    for a in (out.cos, out.cell, out.offset):
        a.setflags(write=False)
    return out


@functools.lru_cache(maxsize=1)
def _sigma_grid() -> Array:
    grid = np.linspace(0.0, 0.5 * math.pi, SIGMA_NODES)
    grid.setflags(write=False)
    return grid


class IsotropicNDF:
    """A normalized isotropic NDF ``D(θ_h)`` on polar nodes, with its σ (eq. 8).

    Parameters
    ----------
    nodes
        Increasing polar angles (radians) from 0 to π/2, shape ``(K,)``.
    values
        ``D`` at the nodes (sr⁻¹), finite and ≥ 0, not all 0, shape ``(K,)``. Normalized
        here (AR 1.2) unless ``normalize=False``. Zeros are kept as a floor of
        ``1e-300`` relative to the peak so that ``log D`` interpolates.
    """

    def __init__(self, nodes: ArrayLike, values: ArrayLike, normalize: bool = True) -> None:
        nodes = np.ascontiguousarray(nodes, dtype=np.float64)
        values = np.ascontiguousarray(values, dtype=np.float64)
        if nodes.ndim != 1 or values.shape != nodes.shape or len(nodes) < 3:
            raise ParameterError(f"isotropic NDF: nodes and values must be 1-D of one length ≥ 3, got "
                                 f"{nodes.shape} and {values.shape}")
        if not (np.all(np.isfinite(nodes)) and abs(nodes[0]) < 1e-12 and abs(nodes[-1] - 0.5 * math.pi) < 1e-9
                and np.all(np.diff(nodes) > 0)):
            raise ParameterError("isotropic NDF: nodes must increase from 0 to π/2")
        if not np.all(np.isfinite(values)) or np.any(values < 0) or not np.any(values > 0):
            raise ParameterError("isotropic NDF: values must be finite, ≥ 0 and not all 0")
        self._tabulate(nodes, values, normalize)

    @classmethod
    def from_log(cls, nodes: Array, z: Array) -> IsotropicNDF:
        """The normalized NDF ``∝ e^z`` at ``nodes`` (a fit's state; ``nodes`` a node grid
        already checked, so only ``z``'s finiteness is): the values ``e^{z − max z}`` and
        their table are exactly the constructor's."""
        if not np.all(np.isfinite(z)):
            raise ParameterError("isotropic NDF: the log values must be finite")
        ndf = cls.__new__(cls)
        ndf._tabulate(nodes, np.exp(z - z.max()), True)
        return ndf

    def _tabulate(self, nodes: Array, values: Array, normalize: bool) -> None:
        self.nodes = nodes
        self._quad = _quadrature(nodes.tobytes())
        log_d = np.log(np.maximum(values, values.max() * 1e-300))
        if normalize:
            log_d -= math.log(self._norm(log_d))
        self.log_values = log_d
        self.values = np.exp(log_d)
        d_q = self._at_quadrature(log_d)
        # σ is normalized by the same quadrature's ∫ D cos, so that σ(n) = 1 and S(n) = 1 exactly
        self.sigma = np.maximum(self._quad.sigma_matrix @ d_q, 0.0) / float(self._quad.norm_weights @ d_q)
        for a in (self.nodes, self.log_values, self.values, self.sigma):
            a.setflags(write=False)

    def _at_quadrature(self, log_d: Array) -> Array:
        q = self._quad
        return np.exp((1.0 - q.t) * log_d[q.cells] + q.t * log_d[q.cells + 1])

    def _norm(self, log_d: Array) -> float:
        return float(self._quad.norm_weights @ self._at_quadrature(log_d))

    @property
    def normalization(self) -> float:
        """``∫ D cos θ dω`` of the stored table (1 after normalization)."""
        return self._norm(self.log_values)

    def at_theta(self, theta: ArrayLike) -> Array:
        """``D`` (sr⁻¹) at polar angles ``theta`` (radians), any shape."""
        j, t = interpolation_cells(self.nodes, theta)
        return np.exp((1.0 - t) * self.log_values[j] + t * self.log_values[j + 1])

    def __call__(self, h: ArrayLike) -> Array:
        """``D(h)`` (sr⁻¹) at unit half vectors ``h`` (shape ``(..., 3)``); 0 below the horizon."""
        h = np.asarray(h, dtype=np.float64)
        cz = h[..., 2] / np.maximum(np.linalg.norm(h, axis=-1), 1e-300)
        return np.where(cz > 0, self.at_theta(np.arccos(np.clip(cz, -1.0, 1.0))), 0.0)

    def projected_area(self, cos_theta: ArrayLike) -> Array:
        """``max(σ(θ), cos θ)`` (the σ that makes S ≤ 1) at ``cos θ``, any shape."""
        c = np.clip(np.asarray(cos_theta, dtype=np.float64), 0.0, 1.0)
        sig = np.interp(np.arccos(c), self._quad.sigma_theta, self.sigma)
        return np.maximum(sig, c)

    def pair_shadowing(self, cells_i: ShadowingCells, cells_o: ShadowingCells, correlated: bool = False,
                       geometry: Array | None = None) -> tuple[Array, Array]:
        """The shadowing of direction pairs, ``S(θ_i) S(θ_o)`` (eq. 8), or with ``correlated``
        the height-correlated ``S_i S_o / (S_i + S_o − S_i S_o)`` (0 where either is 0), at
        prepared directions (:func:`shadowing_cells`, shape ``(B,)`` each) in one compiled
        pass; each ``S`` equals :meth:`shadowing`'s bit for bit. Returns the shadowing and
        its product with ``geometry`` (shape ``(B,)``; ones where ``None``)."""
        n = len(cells_i.cos)
        geometry = np.ones(n) if geometry is None else np.ascontiguousarray(geometry, dtype=np.float64)
        if len(cells_o.cos) != n or geometry.shape != (n,):
            raise ParameterError(f"pair shadowing: {n} light directions, {len(cells_o.cos)} view directions and "
                                 f"geometry of shape {geometry.shape}")
        out, out_geometry = np.empty(n), np.empty(n)
        # the cells index the σ table's angles (shadowing_cells), which every node grid's quadrature shares
        _kernels.pair_shadowing(self.sigma, self._quad.sigma_theta, cells_i.cell, cells_i.offset, cells_i.cos,
                                cells_o.cell, cells_o.offset, cells_o.cos, bool(correlated), geometry, out,
                                out_geometry)
        return out, out_geometry

    def shadowing(self, cos_theta: ArrayLike) -> Array:
        """APS shadowing ``S = cos θ / σ`` in [0, 1] (eq. 8) at ``cos θ``, any shape."""
        c = np.clip(np.asarray(cos_theta, dtype=np.float64), 0.0, 1.0)
        sig = self.projected_area(c)
        return np.divide(c, sig, out=np.zeros_like(c), where=sig > 0)


class NodeNDFs:
    """An isotropic NDF that changes with ``θ_d``: one normalized ``D_j(θ_h)`` per ``θ_d`` node.

    ``D(θ_h; θ_d) = Σ_j H_j(θ_d) D_j(θ_h)`` with ``H_j`` the hat functions of the
    nodes, constant beyond the first and the last (the Fresnel tint's interpolation
    between its nodes, :class:`reflecto.fresnel.FresnelTint`). Each ``D_j`` is normalized (AR 1.2) and the
    weights sum to 1, so ``∫ D(h; θ_d) cos θ_h dω_h = 1`` at every ``θ_d``; ``D`` is
    symmetric in ``i`` and ``o`` (``θ_h`` and ``θ_d`` are), so a BRDF built on it stays
    reciprocal.

    Parameters
    ----------
    theta_d
        The nodes (radians), strictly increasing, in ``[0, π/2]``, shape ``(J,)``, ``J ≥ 2``.
    ndfs
        One :class:`IsotropicNDF` per node, all on the same polar nodes.
    """

    def __init__(self, theta_d: ArrayLike, ndfs: list[IsotropicNDF] | tuple[IsotropicNDF, ...]) -> None:
        theta_d = np.ascontiguousarray(theta_d, dtype=np.float64)
        if theta_d.ndim != 1 or len(theta_d) < 2 or len(ndfs) != len(theta_d):
            raise ParameterError(f"NDF per θ_d node: need ≥ 2 nodes and one NDF each, got {theta_d.shape} "
                                 f"and {len(ndfs)}")
        if not (np.all(np.isfinite(theta_d)) and np.all(np.diff(theta_d) > 0) and theta_d[0] >= 0
                and theta_d[-1] <= 0.5 * math.pi + 1e-12):
            raise ParameterError("NDF per θ_d node: nodes must increase within [0, π/2]")
        if any(not np.array_equal(d.nodes, ndfs[0].nodes) for d in ndfs):
            raise ParameterError("NDF per θ_d node: the NDFs must share their polar nodes")
        self.theta_d = theta_d
        self.theta_d.setflags(write=False)
        self.ndfs = tuple(ndfs)

    @property
    def values(self) -> Array:
        """``D_j`` at the polar nodes (sr⁻¹), shape ``(J, K)``."""
        return np.stack([d.values for d in self.ndfs])

    def weights(self, theta_d: ArrayLike) -> tuple[NDArray[np.intp], Array]:
        """The lower node ``j`` and the weight ``u`` of node ``j + 1`` at each ``θ_d`` (radians)."""
        theta_d = np.asarray(theta_d, dtype=np.float64)
        nodes = self.theta_d
        j = np.clip(np.searchsorted(nodes, theta_d) - 1, 0, len(nodes) - 2)
        u = np.clip((theta_d - nodes[j]) / (nodes[j + 1] - nodes[j]), 0.0, 1.0)
        return j, u

    def hats(self, theta_d: ArrayLike) -> list[Array]:
        """Each node's weight ``H_j(θ_d)`` at ``θ_d`` (radians; the weights sum to 1), one array per node."""
        j, u = self.weights(theta_d)
        return [np.where(j == q, 1.0 - u, 0.0) + np.where(j + 1 == q, u, 0.0) for q in range(len(self.ndfs))]

    def at(self, theta_h: ArrayLike, theta_d: ArrayLike) -> Array:
        """``D(θ_h; θ_d)`` (sr⁻¹), broadcast over the two angle arrays (radians)."""
        theta_h, theta_d = np.broadcast_arrays(np.asarray(theta_h, np.float64), np.asarray(theta_d, np.float64))
        out = np.zeros(theta_h.shape)
        for w, d in zip(self.hats(theta_d), self.ndfs):
            if np.any(w > 0):
                out += w * d.at_theta(theta_h)
        return out
