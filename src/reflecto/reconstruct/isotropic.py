"""The reconstruction of an isotropic material: a 1-D NDF ``D(θ_h)`` fitted to the slices (§5.1–5.3).

For an isotropic BRDF the NDF depends on ``θ_h`` only, so every sample with the same
``θ_h`` sees the same ``D``, whatever its LED and view: the six slices overlap along
every ring of half vectors, not only where two slices cross (the paper's overlaps).
This module fits the paper's model (eqs. 1, 2, 4, 8) to the slices directly:

``f(i, o) = k_d/π + k_s D(θ_h) F(θ_d; η) S(θ_i) S(θ_o) / (4 cos θ_i cos θ_o)``

with ``log D`` linear between polar nodes (:mod:`reflecto.polar`) and ``S`` derived
from ``D`` (eq. 8). The stages:

1. :func:`bin_polar` — samples averaged per (LED, θ_h cell, θ_d cell); samples below
   the camera's detection limit (:attr:`Slices.censored`) become upper bounds.
2. :class:`LuminanceProblem` and :func:`solve` — weighted least squares of the
   luminance over ``(log D nodes, k_d, k_s, η)`` by Levenberg–Marquardt, with ``S``
   fixed; the residuals are those of eq. 10 (cosine-weighted absolute differences,
   :func:`set_weights`), the measure the result is judged by; bounds enter as
   one-sided residuals; priors on ``log D`` (:func:`prior`): curvature below the
   camera's resolution (:data:`SMOOTH_LENGTH`), no rise beyond the peak, and beyond
   the last measured ring the ratio to a fitted lobe held constant (:func:`lobe_log`).
   The relative misfit ``ε`` beyond the camera noise (:func:`model_error`) is reported.
3. :func:`fit_luminance` — the fixed point of the fit and ``S`` (eq. 8 from the
   current ``D``; the paper's NDF/shadowing iteration), under the physical bound
   ``k_s ≤ 1`` (a microfacet reflects at most ``F``): when the unconstrained optimum
   needs ``k_s > 1``, the fit continues with ``k_s = 1``, where the specular level
   fixes ``η``, and leaves the bound in a later round where it does not bind
   (:func:`ks_bound_binds`).
4. :func:`tinted_scalars` — ``k_d`` and the specular scale per colour channel with the
   shared ``D`` and ``η`` (bounded linear least squares); the scale is a function of
   ``θ_d`` between the nodes where LEDs see the mirror direction (:func:`tint_nodes`),
   which the model holds as ``k_s`` and a Fresnel tint (:class:`reflecto.fresnel.FresnelTint`);
   where there are two nodes or more, the lobe near the peak is refitted per node on the
   slices that set it (:func:`node_ndfs`), the model's lobe per ``θ_d`` node
   (:class:`reflecto.polar.NodeNDFs`).

One ``η`` serves the three channels: within the device's ``θ_d`` range a per-channel
real ``η`` is not identifiable from the Fresnel curve's shape (algorithm-reference
§2.2–2.3); the tint carries the specular colour and its change with ``θ_d``. Where the
data want a flatter curve than ``η = ETA_MAX`` gives, the fit takes the constant
Fresnel lobe ``F ≡ 1`` (``η = ∞``, :func:`fit_luminance`) instead of the bound.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray
from scipy import optimize

from ..colour import LUM
from ..errors import ReflectoError
from ..fresnel import CONSTANT, MAX_TINT, FresnelTint, fresnel
from ..instrument.slices import Slices
from ..model import IsotropicMicrofacetBRDF
from ..polar import (
    IsotropicNDF,
    NodeNDFs,
    ShadowingCells,
    _quadrature,
    cell_table,
    interpolation_cells,
    polar_nodes,
    shadowing_cells,
)
from . import _polar_kernels
from .samples import kd_median_bound
from .tuning import ISOTROPIC

Array = NDArray[np.float64]

__all__ = ["PolarBins", "IsotropicFit", "bin_polar", "fit_isotropic", "LuminanceProblem", "solve",
           "fit_luminance", "LuminanceRun", "with_constant_fresnel", "start_isotropic", "finish_isotropic",
           "channel_scalars", "lobe_log"]

# Tuned numbers: what, units and provenance are in :mod:`.tuning` (isotropic stage).
CELLS_PER_INTERVAL = ISOTROPIC.cells_per_interval
TD_STEP = ISOTROPIC.td_step
SMOOTH_LENGTH = ISOTROPIC.smooth_length
TAIL_WEIGHT = ISOTROPIC.tail_weight
MONOTONE_WEIGHT = ISOTROPIC.monotone_weight
QUIET_NOISE = ISOTROPIC.quiet_noise
MIN_QUIET_BINS = ISOTROPIC.min_quiet_bins
ETA_MAX = ISOTROPIC.eta_max
ETA_MIN = ISOTROPIC.eta_min
OUTER_ITERATIONS = ISOTROPIC.outer_iterations
LM_TOLERANCE = ISOTROPIC.lm_tolerance
LM_MAX_ITERATIONS = ISOTROPIC.lm_max_iterations
NODE_ROUNDS = ISOTROPIC.node_rounds
#: How the Fresnel tint continues beyond its last node (:class:`reflecto.fresnel.FresnelTint`):
#: a form, not a number; chosen on the tuning half by ``studies/tint_beyond.py``
#: (docs/design/reconstruction.md, *Beyond the last node*).
TINT_BEYOND = "trend"
MIRROR_THETA_H = ISOTROPIC.mirror_theta_h


@dataclasses.dataclass
class PolarBins:
    """Samples averaged per (LED, θ_h cell, θ_d cell), shape ``(B,)`` unless noted.

    Attributes
    ----------
    led, count
        LED index and number of pixels of each bin.
    theta_h, cos_d, cos_i, cos_o
        Mean half-vector polar angle (radians), ``cos θ_d``, ``cos θ_i``, ``cos θ_o``.
    f
        Mean BRDF (sr⁻¹), shape ``(B, 3)``; for a censored bin its detection limit.
    noise
        Standard deviation of the bin's mean luminance from the camera noise (sr⁻¹).
    censored
        The bin holds samples below the detection limit: ``f`` bounds the BRDF from above.
    """

    led: NDArray[np.intp]
    count: Array
    theta_h: Array
    cos_d: Array
    cos_i: Array
    cos_o: Array
    f: Array
    noise: Array
    censored: NDArray[np.bool_]

    def __len__(self) -> int:
        return len(self.led)

    @property
    def luminance(self) -> Array:
        """Mean BRDF luminance of each bin, ``f · LUM`` (sr⁻¹), shape ``(B,)``."""
        return self.f @ LUM


def bin_polar(slices: Slices, nodes: Array, valid: NDArray[np.bool_], td_step: float | None = None) -> PolarBins:
    """Average the ``valid`` samples of the slices per (LED, θ_h cell, θ_d cell).

    The θ_h cells halve the node intervals (:data:`CELLS_PER_INTERVAL`): a bin's mean
    BRDF then stands for its mean θ_h to second order in a half interval. The θ_d cells
    are ``td_step`` wide (radians; ``None``: :data:`TD_STEP`, the model's fits').

    Censored samples (below the detection limit) form their own bins, whose value is
    the mean detection limit (:attr:`Slices.limit`; the sample's own reading where the
    slices carry none). The noise of a bin is ``√(Σ σ²)/n`` over its ``n`` pixels
    (:attr:`Slices.noise`; 0 where the slices carry none).
    """
    td_step = TD_STEP if td_step is None else td_step
    censored = valid & slices.censored if slices.censored is not None else np.zeros_like(valid)
    edges = np.interp(np.arange((len(nodes) - 1) * CELLS_PER_INTERVAL + 1) / CELLS_PER_INTERVAL,
                      np.arange(len(nodes)), nodes)
    parts = [_bin_group(slices, edges, valid & ~censored, False, td_step),
             _bin_group(slices, edges, censored, True, td_step)]
    parts = [p for p in parts if p is not None]
    if not parts:
        raise ReflectoError("capture: no valid samples")
    return PolarBins(*(np.concatenate([getattr(p, f.name) for p in parts])
                       for f in dataclasses.fields(PolarBins)))


def _bin_group(slices: Slices, edges: Array, mask: NDArray[np.bool_], is_bound: bool,
               td_step: float) -> PolarBins | None:
    if not mask.any():
        return None
    zeros = np.zeros(mask.shape)
    noise = zeros if slices.noise is None else np.ascontiguousarray(slices.noise, dtype=np.float64)
    bound = zeros
    if is_bound:
        bound = slices.limit if slices.limit is not None else slices.values @ LUM
        bound = np.ascontiguousarray(bound, dtype=np.float64)
    n_td = int(math.ceil(0.5 * math.pi / td_step)) + 1
    n_keys = slices.n_leds * (len(edges) - 1) * n_td
    count = np.zeros(n_keys)
    sums = np.zeros((n_keys, 5))
    fsum = np.zeros((n_keys, 3))
    _polar_kernels.bin_polar(np.ascontiguousarray(mask), np.ascontiguousarray(slices.light, dtype=np.float64),
                             np.ascontiguousarray(slices.view, dtype=np.float64),
                             np.ascontiguousarray(slices.values, dtype=np.float64), noise, bound, edges,
                             cell_table(edges.tobytes()), td_step, n_td, *theta_d_tables(n_td, td_step),
                             count, sums, fsum)
    used = np.flatnonzero(count)
    n = count[used]
    led = (used // ((len(edges) - 1) * n_td)).astype(np.intp)
    f = fsum[used] / n[:, None]
    if is_bound:  # the bound: the mean detection limit, as a neutral (luminance) value
        f = np.repeat((sums[used, 4] / n)[:, None], 3, axis=1)
    return PolarBins(led, n, sums[used, 0] / n, sums[used, 1] / n, slices.light[led, 2].copy(), sums[used, 2] / n, f,
                     np.sqrt(sums[used, 3]) / n, np.full(len(used), is_bound))


@functools.cache
def theta_d_tables(n_td: int, td_step: float = TD_STEP) -> tuple[Array, NDArray[np.intp]]:
    """The θ_d cells' edges in ``c = cos θ_d`` and a table of the cell of ``c = i / m``
    (read-only), with which the binning finds a sample's θ_d cell
    (:func:`._polar_kernels._theta_d_cell`) without an arccos.

    ``td_cos[j] = cos(j · td_step)``, ``j = 0 … n_td``: cell ``j`` holds
    ``td_cos[j + 1] < c ≤ td_cos[j]``. ``m`` makes the table's step half the narrowest
    cell (``1 − cos td_step``), so a sample's cell is its table entry's or the one below.
    """
    td_cos = np.cos(np.arange(n_td + 1) * td_step)
    m = int(math.ceil(2.0 / (1.0 - math.cos(td_step))))
    c = np.arange(m) / m
    table = (np.searchsorted(-td_cos, -c, side="right") - 1).astype(np.intp)
    td_cos.setflags(write=False)
    table.setflags(write=False)
    return td_cos, table


def bin_polar_numpy(mask: NDArray[np.bool_], light: Array, view: Array, values: Array, noise: Array, bound: Array,
                    edges: Array, n_td: int, td_step: float = TD_STEP) -> tuple[Array, Array, Array]:
    """NumPy reference of the compiled binning kernel: ``(count, sums, f sums)`` per key."""
    li, pi = np.nonzero(mask)
    i, o = light[li], view[pi]
    hs = i + o
    nrm = np.linalg.norm(hs, axis=1)
    th = np.arccos(np.clip(hs[:, 2] / nrm, -1.0, 1.0))
    c = np.clip(np.einsum("ij,ij->i", i, hs) / nrm, 0.0, 1.0)
    n_cells = len(edges) - 1
    j = np.clip(np.searchsorted(edges, th, side="right") - 1, 0, n_cells - 1)
    k = np.minimum((np.arccos(c) / td_step).astype(np.intp), n_td - 1)
    key = (li * n_cells + j) * n_td + k
    n_keys = light.shape[0] * n_cells * n_td
    count = np.bincount(key, minlength=n_keys).astype(np.float64)
    cols = (th, c, o[:, 2], noise[li, pi] ** 2, bound[li, pi])
    sums = np.stack([np.bincount(key, x, n_keys) for x in cols], axis=1)
    fs = np.stack([np.bincount(key, values[li, pi, q], n_keys) for q in range(3)], axis=1)
    return count, sums, fs  # type: ignore[return-value]  # numpy stub: weighted bincount is float64, not intp


# ----------------------------------------------------------------------------- the luminance fit


@dataclasses.dataclass
class LuminanceState:
    """Parameters of the luminance fit: ``log D`` at the nodes (unnormalized), ``k_d``,
    the specular gain ``g`` (``k_s = g ∫ e^z cos``) and ``η``."""

    z: Array
    kd: float
    g: float
    eta: float

    def copy(self) -> LuminanceState:
        """A copy with its own ``z`` array."""
        return LuminanceState(self.z.copy(), self.kd, self.g, self.eta)


class LuminanceProblem:
    """The weighted least-squares problem of the luminance, with ``S`` and the weights fixed.

    Residual of bin ``b``: ``m_b − f_b`` with ``m_b = k_d/π + g F(c_b; η) e^{z(θ_b)} S_b /
    (4 cos θ_i cos θ_o)`` (``S_b = S(θ_i) S(θ_o)``); for a censored bin ``max(0, m_b − f_b)``.
    Cost ``Σ w_b r_b² + zᵀHz − 2 βᵀz + c`` (the priors of :func:`prior`; ``c`` makes the
    prior a sum of squares, so the cost is ≥ 0).
    """

    def __init__(self, bins: PolarBins, nodes: Array, correlated: bool = False) -> None:
        self.bins = bins
        self.nodes = nodes
        self.correlated = correlated  # the shadowing form (:func:`pair_shadowing`)
        self.j, self.t = interpolation_cells(nodes, bins.theta_h)
        self.f = bins.luminance
        self.geometry = 1.0 / (4.0 * bins.cos_i * bins.cos_o)
        self.measured = ~bins.censored
        self.shadow = np.ones(len(bins))
        self.shadow_geometry = self.geometry.copy()  # S · geometry, kept with the shadowing
        self.w = np.ones(len(bins))
        # the last data pass's residuals, specular parts, F and activity (pass_normal_equations)
        self._r = np.empty(len(bins))
        self._spec = np.empty(len(bins))
        self._fr = np.empty(len(bins))
        self._active = np.empty(len(bins), dtype=np.bool_)
        self.h = np.zeros((len(nodes), len(nodes)))
        self.beta = np.zeros(len(nodes))
        self.prior_constant = 0.0

    @functools.cached_property
    def direction_cells(self) -> tuple[ShadowingCells, ShadowingCells]:
        """The bins' light and view directions prepared for ``S`` (:func:`reflecto.polar.shadowing_cells`)."""
        return shadowing_cells(self.bins.cos_i), shadowing_cells(self.bins.cos_o)

    def specular(self, s: LuminanceState) -> tuple[Array, Array]:
        """``g F e^z S / (4 cos cos)`` per bin, and F."""
        z = s.z
        log_d = (1.0 - self.t) * z[self.j] + self.t * z[self.j + 1]
        fr = fresnel(self.bins.cos_d, s.eta)
        return s.g * fr * np.exp(np.minimum(log_d, 700.0)) * self.shadow * self.geometry, fr

    def values(self, s: LuminanceState) -> Array:
        """The model values ``m_b`` (sr⁻¹, shape ``(B,)``)."""
        spec, _ = self.specular(s)
        return s.kd / math.pi + spec

    def residuals(self, s: LuminanceState) -> tuple[Array, Array]:
        """Residuals (bounds one-sided) and the model values."""
        m = self.values(s)
        r = m - self.f
        return np.where(self.measured, r, np.maximum(r, 0.0)), m

    @functools.cached_property
    def measured_extent(self) -> tuple[float, int | None]:
        """The measured bins' span of ``θ_h`` (radians; 1 where none is measured) and the
        last ring they lie in (the lower node of the outermost cell; ``None`` where none)."""
        me = self.measured
        if not me.any():
            return 1.0, None
        return float(np.ptp(self.bins.theta_h[me])), int(self.j[me].max())

    def data_pass(self, s: LuminanceState) -> float:
        """``Σ w r²`` in one compiled pass (:func:`._polar_kernels.luminance_pass`); the
        pass's values at ``s`` are kept for :func:`_normal_equations` (``from_pass``)."""
        return _polar_kernels.luminance_pass(self.j, self.t, s.z, self.shadow_geometry, self.bins.cos_d, self.f,
                                             self.w, self.measured, s.kd, s.g, s.eta, self._r, self._spec, self._fr,
                                             self._active)

    def cost(self, s: LuminanceState) -> float:
        """The cost; ``inf`` for a state whose NDF overflows (a rejected trial step)."""
        with np.errstate(over="ignore", invalid="ignore"):
            c = self.data_pass(s) + float(s.z @ self.h @ s.z - 2.0 * self.beta @ s.z) + self.prior_constant
        return c if math.isfinite(c) else math.inf


def prior(problem: LuminanceProblem, s: LuminanceState, tail: Array | None = None,
          tail_from: int | None = None) -> None:
    """Set the problem's priors on ``log D`` (``H``, ``β``) for the weights in place.

    * Curvature: ``λ ∫ (∂²z/∂θ²)² dθ`` with ``λ = ρ ℓ⁴``, ``ρ`` the data's weight per
      radian of θ_h in log units (``Σ w m²`` over the measured span) and ``ℓ`` =
      :data:`SMOOTH_LENGTH`; at the pole ``z`` is mirrored (``∂z/∂θ = 0``).
    * Unimodality: beyond its peak the NDF of a surface does not rise again; where
      ``z`` rises at the current state, the rise is penalized with weight
      :data:`MONOTONE_WEIGHT` ``ρ Δθ`` (a grazing sheen that the fit would explain by
      facets at 80° extrapolates across the whole rim).
    * Tail: beyond the last ring a measured bin lies in, the first differences of
      ``z − L`` (``L`` the lobe of :func:`lobe_log`) are held at 0 with weight
      :data:`TAIL_WEIGHT` ``ρ Δθ``: the NDF continues as the lobe does, at the ratio it
      has at the last measured ring. With ``tail`` (a ``log D`` at the nodes) that shape
      instead of the lobe's, from node ``tail_from`` on where it is given (else from the
      last measured ring): the NDF continues as ``tail`` does.
    """
    nodes = problem.nodes
    k = len(nodes)
    m = problem.values(s)
    me = problem.measured
    span, last_ring = problem.measured_extent
    rho = float(np.sum((problem.w * m * m)[me])) / max(span, 1e-3)
    h = rho * SMOOTH_LENGTH**4 * _curvature_matrix(nodes.tobytes())
    beta = np.zeros(k)
    constant = 0.0
    step = _median_step(nodes.tobytes())
    # the last ring measured: the lower node of the outermost cell a measured bin lies in
    # (the node above it is touched only through interpolation weights that vanish there)
    if last_ring is not None:
        first = last_ring if tail_from is None else min(tail_from, last_ring)
        lobe = None if first >= k - 1 else tail if tail is not None else lobe_log(nodes, s.z, np.arange(k) <= first)
        if lobe is not None:
            pt = TAIL_WEIGHT * rho * step * _difference_gram(k, tuple(range(first, k - 1)))
            h = h + pt
            beta = pt @ lobe
            constant = float(lobe @ pt @ lobe)
    # unimodal: beyond its peak the NDF does not rise (rows where it rises at this state)
    peak = int(np.argmax(s.z))
    rise = np.flatnonzero(np.diff(s.z)[peak:] > 0) + peak
    if len(rise):
        h = h + MONOTONE_WEIGHT * rho * step * _difference_gram(k, tuple(rise.tolist()))
    problem.h, problem.beta, problem.prior_constant = h, beta, constant


@functools.lru_cache(maxsize=4)
def _median_step(nodes_key: bytes) -> float:
    """The median spacing of the nodes (radians)."""
    return float(np.median(np.diff(np.frombuffer(nodes_key, dtype=np.float64))))


@functools.lru_cache(maxsize=64)
def _difference_gram(k: int, rows: tuple[int, ...]) -> Array:
    """``PᵀP`` (shape ``(k, k)``, read-only) of the first differences ``(P z)_r = z[q_r + 1] − z[q_r]``
    for the indices ``q_r`` of ``rows``. Its entries are small integers, so a scale times it equals
    the scaled rows' product exactly."""
    p = np.zeros((len(rows), k))
    idx = np.asarray(rows, dtype=np.intp)
    p[np.arange(len(idx)), idx + 1] = 1.0
    p[np.arange(len(idx)), idx] = -1.0
    out = p.T @ p
    out.setflags(write=False)
    return out


@functools.lru_cache(maxsize=4)
def _curvature_matrix(nodes_key: bytes) -> Array:
    """``Pᵀ P`` with ``(P z)_k ≈ z''(θ_k) √(Δθ_k)`` (non-uniform second differences, mirror at 0)."""
    nodes = np.frombuffer(nodes_key, dtype=np.float64)
    k = len(nodes)
    p = np.zeros((k - 1, k))
    h = nodes[1] - nodes[0]
    p[0, 0], p[0, 1] = -2.0 / h**2, 2.0 / h**2
    for q in range(1, k - 1):
        h0, h1 = nodes[q] - nodes[q - 1], nodes[q + 1] - nodes[q]
        p[q, q - 1] = 2.0 / (h0 * (h0 + h1))
        p[q, q] = -2.0 / (h0 * h1)
        p[q, q + 1] = 2.0 / (h1 * (h0 + h1))
    width = 0.5 * (nodes[np.minimum(np.arange(k - 1) + 1, k - 1)] - nodes[np.maximum(np.arange(k - 1) - 1, 0)])
    p *= np.sqrt(width)[:, None]
    out = p.T @ p
    out.setflags(write=False)
    return out


def lobe_log(nodes: Array, z: Array, observed: NDArray[np.bool_]) -> Array | None:
    """``log`` of the GGX or Beckmann lobe that fits ``z`` best on the observed nodes, or ``None``.

    Both are linear in ``tan²θ`` after a transform (Walter et al. 2007):
    GGX ``(D cos⁴θ)^(−½) = a + b tan²θ``, Beckmann ``log(D cos⁴θ) = a − b tan²θ``.
    Fitted by least squares (GGX weighted to relative errors) on the observed nodes
    above 10⁻³ of the largest observed value and below 85°; the family with the smaller
    log-RMS misfit wins. The result is floored 50 (in log) below that value.
    """
    if not observed.any():
        return None
    peak = float(z[observed].max())
    sel = observed & (z > peak + math.log(1e-3)) & (nodes < math.radians(85.0))
    if np.count_nonzero(sel) < 4:
        return None
    th = nodes[sel]
    x = np.ones((len(th), 2))
    x[:, 1] = np.tan(th) ** 2
    lc4 = z[sel] + 4.0 * np.log(np.cos(th)) - peak
    best: tuple[float, str, Array] | None = None
    for family in ("ggx", "beckmann"):
        y, ww = (np.exp(-0.5 * lc4), np.exp(lc4)) if family == "ggx" else (lc4, np.ones(len(lc4)))
        sw = np.sqrt(ww)
        coef = np.linalg.lstsq(x * sw[:, None], y * sw, rcond=None)[0]
        if (family == "ggx" and (coef[0] <= 0 or coef[1] <= 0)) or (family == "beckmann" and coef[1] >= 0):
            continue
        fitted = -2.0 * np.log(x @ coef) if family == "ggx" else x @ coef
        misfit = float(np.sqrt(np.mean((fitted - lc4) ** 2)))
        if best is None or misfit < best[0]:
            best = (misfit, family, coef)
    if best is None:
        return None
    _, family, coef = best
    th = np.minimum(nodes, math.radians(89.0))
    q = coef[0] + coef[1] * np.tan(th) ** 2
    log_l = (-2.0 * np.log(q) if family == "ggx" else q) - 4.0 * np.log(np.cos(th)) + peak
    return np.maximum(log_l, peak - 50.0)


def _ndf_weights(nodes: Array, z: Array):
    """The polar quadrature of ``nodes`` and ``e^z cos θ dω`` on its rings (summing to ``N``)."""
    q = _quadrature(nodes.tobytes())
    d = np.exp(np.minimum((1.0 - q.t) * z[q.cells] + q.t * z[q.cells + 1], 700.0))
    return q, q.norm_weights * d


def ndf_integral(nodes: Array, z: Array) -> float:
    """``N = ∫ e^z cos θ dω`` (the first value of :func:`normalization`, without its gradient)."""
    return float(_ndf_weights(nodes, z)[1].sum())


def normalization(nodes: Array, z: Array) -> tuple[float, Array]:
    """``N = ∫ e^z cos θ dω`` and its gradient ``∂ log N / ∂z`` (shape ``(K,)``)."""
    q, wd = _ndf_weights(nodes, z)
    n = float(wd.sum())
    if not (math.isfinite(n) and n > 0):  # no normalizable NDF: the caller rejects the state
        return n, np.zeros(len(nodes))
    grad = (np.bincount(q.cells, wd * (1.0 - q.t), len(nodes)) + np.bincount(q.cells + 1, wd * q.t, len(nodes))) / n
    return n, grad


def solve(problem: LuminanceProblem, s: LuminanceState, fix_eta: bool = False,
          tie_ks: bool = False, fix_kd: bool = False) -> tuple[LuminanceState, float]:
    """Levenberg–Marquardt on ``(z, k_d, log g, log(η − 1))`` with ``S`` and the weights
    fixed, in one compiled call (:func:`._polar_kernels.luminance_lm`); the steps, bounds
    and ending of :func:`solve_numpy`, its NumPy reference. Returns the state and its cost."""
    q = _quadrature(problem.nodes.tobytes())
    with np.errstate(over="ignore", invalid="ignore"):
        z, kd, g, eta, cost = _polar_kernels.luminance_lm(
            problem.j, problem.t, problem.shadow_geometry, problem.bins.cos_d, problem.f, problem.w,
            problem.measured, problem.h, problem.beta, float(problem.prior_constant), q.cells, q.t, q.norm_weights,
            s.z, float(s.kd), float(s.g), float(s.eta), fix_eta, tie_ks, fix_kd, ETA_MIN, ETA_MAX,
            LM_MAX_ITERATIONS, LM_TOLERANCE, problem._r, problem._spec, problem._fr, problem._active)
    return LuminanceState(z, float(kd), float(g), float(eta)), float(cost)


def solve_numpy(problem: LuminanceProblem, s: LuminanceState, fix_eta: bool = False,
                tie_ks: bool = False, fix_kd: bool = False) -> tuple[LuminanceState, float]:
    """Levenberg–Marquardt on ``(z, k_d, log g, log(η − 1))`` with ``S`` and the weights fixed
    (the NumPy reference of :func:`solve`).

    ``tie_ks`` holds ``k_s = g N(z) = 1`` (``log g = −log N(z)``: the ``log g`` column
    folds into the ``z`` columns through ``∂ log N / ∂z``). Bounds: ``k_d ≥ 0`` and
    ``η ∈ [ETA_MIN, ETA_MAX]`` (a parameter at a bound and pushed beyond it is held for
    the step); ``fix_eta`` and ``fix_kd`` hold those. Returns the state and its cost.
    """
    k = len(problem.nodes)
    if tie_ks:  # k_s = 1 with the NDF normalized
        s = s.copy()
        s.z = s.z - math.log(ndf_integral(problem.nodes, s.z))
        s.g = 1.0
    cost = problem.cost(s)
    mu = 1e-3
    for _ in range(LM_MAX_ITERATIONS):
        # the last pass was at s: the entry's cost, or the trial step just accepted
        a, grad = _normal_equations(problem, s, tie_ks, from_pass=True)
        frozen = [k + 2] if fix_eta else []
        if (s.eta >= ETA_MAX and grad[k + 2] < 0) or (s.eta <= ETA_MIN and grad[k + 2] > 0):
            frozen.append(k + 2)
        if fix_kd or (s.kd <= 0.0 and grad[k] > 0):
            frozen.append(k)
        if tie_ks:
            frozen.append(k + 1)
        for q in frozen:
            a[q, :] = 0.0
            a[:, q] = 0.0
            a[q, q] = 1.0
            grad[q] = 0.0
        diag = np.diag(a).copy()
        diag += 1e-12 * diag.max()
        improved = False
        while mu < 1e10:
            try:
                step = -np.linalg.solve(a + mu * np.diag(diag), grad)
            except np.linalg.LinAlgError:
                mu *= 8.0
                continue
            trial = _apply(problem, s, step, tie_ks)
            c = problem.cost(trial) if trial is not None else math.inf
            if np.isfinite(c) and c < cost:
                assert trial is not None  # c is infinite for None
                improved, rel = True, (cost - c) / cost
                s, cost = trial, c
                mu = max(mu / 5.0, 1e-9)
                break
            mu *= 8.0
        if not improved or rel < LM_TOLERANCE:
            break
    return s, cost


def _apply(problem: LuminanceProblem, s: LuminanceState, step: NDArray[np.floating],
           tie_ks: bool) -> LuminanceState | None:
    """The state after an LM step, renormalized: ``z`` shifted so that ``∫ e^z cos = 1``
    and ``g`` scaled inversely (the model is unchanged: the shift is the gauge of the
    ``(z level, g)`` pair), so ``g`` is ``k_s`` and the level cannot drift. ``None`` when
    the step leaves no normalizable NDF (``e^z`` underflows or overflows everywhere):
    such a state would evaluate to the diffuse term alone, whose cost can be finite and
    lower, so it must be rejected here, not by its cost."""
    k = len(problem.nodes)
    z = s.z + step[:k]
    n = ndf_integral(problem.nodes, z)
    if not (math.isfinite(n) and n > 0):
        return None
    z = z - math.log(n)
    if math.isinf(s.eta):  # the constant Fresnel lobe: η is not a parameter
        eta = s.eta
    else:
        eta = min(max(1.0 + (s.eta - 1.0) * math.exp(float(np.clip(step[k + 2], -2.0, 2.0))), ETA_MIN), ETA_MAX)
    g = 1.0 if tie_ks else s.g * n * math.exp(float(np.clip(step[k + 1], -3.0, 3.0)))
    return LuminanceState(z, max(s.kd + float(step[k]), 0.0), g, eta)


def _normal_equations(problem: LuminanceProblem, s: LuminanceState, tie_ks: bool,
                      from_pass: bool = False) -> tuple[Array, Array]:
    """``JᵀWJ + H`` and ``JᵀWr + Hz − β`` over ``(z, k_d, log g, log(η − 1))``.

    ``from_pass``: the problem's last :meth:`~LuminanceProblem.data_pass` was at ``s``
    (as in :func:`solve`, which evaluates every state it moves to), and its stored
    values are used; otherwise the pass is made here."""
    k = len(problem.nodes)
    diag, off = np.empty(k), np.empty(k - 1)
    cross, dense = np.empty((k, 3)), np.empty((3, 3))
    gz, gd = np.empty(k), np.empty(3)
    if not from_pass:
        with np.errstate(over="ignore", invalid="ignore"):
            problem.data_pass(s)
    # the Jacobian's columns [1/π, spec, ∂/∂log(η−1)] and the normal equations in one loop
    _polar_kernels.pass_normal_equations(problem.j, problem.t, problem.bins.cos_d, problem._r, problem._spec,
                                         problem._fr, problem._active, problem.w, s.eta, k, diag, off, cross, dense,
                                         gz, gd)
    a = np.zeros((k + 3, k + 3))
    a[np.arange(k), np.arange(k)] = diag
    a[np.arange(k - 1), np.arange(1, k)] = off
    a[np.arange(1, k), np.arange(k - 1)] = off
    a[:k, k:] = cross
    a[k:, :k] = cross.T
    a[k:, k:] = dense
    grad = np.concatenate([gz, gd])
    if tie_ks:  # log g = −log N(z): the g column enters every z column through −∂log N/∂z
        _, n = normalization(problem.nodes, s.z)
        cg = a[:k, k + 1].copy()
        a[:k, :k] += -np.outer(n, cg) - np.outer(cg, n) + a[k + 1, k + 1] * np.outer(n, n)
        a[:k, k] -= n * a[k + 1, k]
        a[:k, k + 2] -= n * a[k + 1, k + 2]
        a[k, :k] = a[:k, k]
        a[k + 2, :k] = a[:k, k + 2]
        grad[:k] -= n * grad[k + 1]
    a[:k, :k] += problem.h
    grad[:k] += problem.h @ s.z - problem.beta
    # the z level and g are one degree of freedom: a vanishing ridge on the level fixes it
    a[:k, :k] += 1e-12 * max(float(diag.max()), 1e-300)
    return a, grad


def normal_equations_numpy(j: NDArray[np.intp], t: Array, spec: Array, dcols: Array, r: Array, w: Array,
                           k: int) -> tuple[Array, Array, Array, Array, Array, Array]:
    """NumPy reference of the compiled normal equations: ``(diag, off, cross, dense, grad_z, grad_d)``."""
    a0, a1 = spec * (1.0 - t), spec * t
    diag = np.bincount(j, w * a0 * a0, k) + np.bincount(j + 1, w * a1 * a1, k)
    off = np.bincount(j, w * a0 * a1, k)[: k - 1]
    wc = w[:, None] * dcols
    cross = np.stack([np.bincount(j, wc[:, q] * a0, k) + np.bincount(j + 1, wc[:, q] * a1, k)
                      for q in range(dcols.shape[1])], axis=1)
    grad_z = np.bincount(j, w * a0 * r, k) + np.bincount(j + 1, w * a1 * r, k)
    return diag, off, cross, dcols.T @ wc, grad_z, wc.T @ r  # type: ignore[return-value]  # numpy stub: weighted bincount is float64, not intp


def model_error(problem: LuminanceProblem, s: LuminanceState) -> float:
    """Relative model error ``ε``: the RMS relative residual of the measured bins beyond
    their camera noise (``ε² = mean(max(ρ² − ν², 0))`` with ``ρ = r/m``, ``ν = σ/m``),
    over the bins whose noise is below :data:`QUIET_NOISE` of their value (where the
    misfit is the model's, not a few DN's rounding and its selection at the detection
    limit), the top 2 % trimmed so that a few outlying bins do not set it."""
    r, m = problem.residuals(s)
    me = problem.measured
    level = np.maximum(np.maximum(m[me], np.abs(problem.f[me])), 1e-300)  # noise can read below 0: not m alone
    nu = problem.bins.noise[me] / level
    quiet = nu < QUIET_NOISE
    if np.count_nonzero(quiet) < MIN_QUIET_BINS:
        quiet = nu < 1.0  # too few quiet bins: every bin above its noise
    if not np.any(quiet):
        return 0.05
    excess = np.maximum((r[me][quiet] / level[quiet]) ** 2 - nu[quiet] ** 2, 0.0)
    excess = np.minimum(excess, np.percentile(excess, 98.0))
    return float(math.sqrt(max(float(excess.mean()), 1e-8)))


def set_weights(problem: LuminanceProblem) -> None:
    """The weights of eq. 10 (Ngan et al.'s error, the measure the result is judged by):
    ``w = n cos² θ_i``, the bin's pixel count (its share of view solid angle) times the
    metric's cosine weight of the residual, scaled by the brightest bin so that the
    cost is O(1). The dense Cook–Torrance baseline is fitted by the same residuals.

    Relative weights (a model error proportional to the value) let the many dim bins
    of the diffuse floor and the grazing sheen set η and the lobe's tails: fitted that
    way, the shared materials' extrapolation to the unmeasured grazing θ_d was worse
    than a dense Cook–Torrance fit's on 34 of 50 (on 20 of 50 with these weights).
    """
    f_max = float(np.max(np.abs(problem.f))) if len(problem.f) else 1.0
    if not f_max > 0.0:
        raise ReflectoError("capture: every usable sample reads 0 (no light reached the camera)")
    problem.w = problem.bins.count * problem.bins.cos_i**2 / max(f_max, 1e-300) ** 2


def pair_shadowing(ndf: IsotropicNDF, cos_i: Array, cos_o: Array, correlated: bool) -> Array:
    """The masking–shadowing of a pair of directions from the NDF's ``S`` (eq. 8):
    the separable product ``S(θ_i) S(θ_o)`` (the paper's), or with ``correlated`` the
    height-correlated Smith form ``S_i S_o / (S_i + S_o − S_i S_o)`` = ``1/(1 + Λ_i + Λ_o)``
    (``Λ = 1/S − 1``; Heitz 2014, §1.3 of the algorithm reference), which does not count
    twice the microfacets that hide from both directions because they lie low. Shapes
    ``(B,)``, values in [0, 1]; the correlated form is never below the product."""
    si, so = ndf.shadowing(cos_i), ndf.shadowing(cos_o)
    if not correlated:
        return si * so
    return np.divide(si * so, si + so - si * so, out=np.zeros_like(si), where=(si > 0) & (so > 0))


def update_shadowing(problem: LuminanceProblem, s: LuminanceState, damping: bool = False) -> None:
    """The shadowing of every bin from the current NDF (eq. 8, :func:`pair_shadowing` in
    the problem's form); with ``damping`` the geometric mean of the old and the new value
    (the fixed point ``S = S(D)`` oscillates for broad lobes when taken in full steps)."""
    ndf = IsotropicNDF.from_log(problem.nodes, s.z)
    new, new_geometry = ndf.pair_shadowing(*problem.direction_cells, problem.correlated, problem.geometry)
    if damping:
        problem.shadow = np.sqrt(problem.shadow * new)
        problem.shadow_geometry = problem.shadow * problem.geometry
    else:
        problem.shadow, problem.shadow_geometry = new, new_geometry


def initial_state(problem: LuminanceProblem, eta: float = 1.5) -> LuminanceState:
    """``k_d`` from a low percentile of the measured luminance, ``log D`` from the
    partial NDFs (eq. 7 with ``S = 1``) averaged per node and normalized, ``g`` its scale."""
    me = problem.measured
    f = problem.f
    kd = 0.5 * math.pi * max(float(np.percentile(f[me], 2.0)), 0.0) if me.any() else 0.0
    dhat = np.maximum((f - kd / math.pi) / (problem.geometry * fresnel(problem.bins.cos_d, eta)), 1e-9 * f.max())
    k = len(problem.nodes)
    w0 = problem.bins.count * me
    j, t = problem.j, problem.t
    num = np.bincount(j, w0 * (1 - t) * np.log(dhat), k) + np.bincount(j + 1, w0 * t * np.log(dhat), k)
    den = np.bincount(j, w0 * (1 - t), k) + np.bincount(j + 1, w0 * t, k)
    seen = den > 0
    if not seen.any():
        raise ReflectoError("capture: no measured sample above the detection limit")
    z = np.interp(np.arange(k), np.flatnonzero(seen), num[seen] / den[seen])
    n = ndf_integral(problem.nodes, z)
    return LuminanceState(z - math.log(n), kd, n, eta)


@dataclasses.dataclass
class LuminanceFit:
    """The converged luminance fit: state, model error ``ε``, cost, and whether ``k_s = 1`` holds."""

    state: LuminanceState
    eps: float
    cost: float
    ks_bound: bool
    problem: LuminanceProblem

    @property
    def ks(self) -> float:
        """The specular albedo ``k_s = g ∫ e^z cos θ dω`` of the fitted state (luminance)."""
        return self.state.g * ndf_integral(self.problem.nodes, self.state.z)


def fit_luminance(bins: PolarBins, nodes: Array, fixed_eta: float | None = None,
                  outer_iterations: int = OUTER_ITERATIONS, correlated: bool = False,
                  start: LuminanceState | None = None, tied: bool = False) -> LuminanceFit:
    """The luminance fit at its fixed point with ``S`` (module docstring, stage 3).

    When the free η ends at :data:`ETA_MAX` still pushed upward, the data ask for a
    Fresnel curve flatter than any dielectric's: the fit is repeated with the constant
    Fresnel lobe (``η = ∞``, ``F ≡ 1``, :data:`reflecto.fresnel.CONSTANT`) twice: from
    the initial state, and from the bound's state (its NDF, ``k_d``, ``k_s`` and ``S``;
    at η = 50 the Fresnel curve is already nearly flat, and a fresh start can end in a
    worse minimum than the bound's). The cheapest of the three fits is kept, so no η is
    left parked at the search bound unless the data fit it better than either constant
    lobe (then the notes say so). ``correlated`` chooses the shadowing form
    (:func:`pair_shadowing`); ``start`` a converged state to continue from instead of the
    data's initial state, and ``tied`` whether it starts on the bound ``k_s = 1`` (the
    active set of the fit it continues: a round leaves the bound where
    :func:`ks_bound_binds` says the optimum lies inside; a continuation that left it
    and meets it again stays on it).
    """
    run = LuminanceRun(bins, nodes, fixed_eta, start=start, correlated=correlated, tied=tied)
    run.rounds(outer_iterations)
    return with_constant_fresnel(run.fit(), fixed_eta, outer_iterations)


def with_constant_fresnel(fit: LuminanceFit, fixed_eta: float | None,
                          outer_iterations: int = OUTER_ITERATIONS) -> LuminanceFit:
    """``fit``, or where its free η ended at :data:`ETA_MAX` the cheapest of it and the two
    constant Fresnel lobes' fits (:func:`fit_luminance`)."""
    if fixed_eta is None and fit.state.eta >= ETA_MAX * (1 - 1e-9):
        bins, nodes, correlated = fit.problem.bins, fit.problem.nodes, fit.problem.correlated
        flats = (_fit_luminance(bins, nodes, CONSTANT, outer_iterations, correlated=correlated),
                 _fit_luminance(bins, nodes, CONSTANT, outer_iterations, start=fit.state, correlated=correlated))
        return min((fit, *flats), key=lambda f: f.cost)
    return fit


def _fit_luminance(bins: PolarBins, nodes: Array, fixed_eta: float | None, outer_iterations: int,
                   start: LuminanceState | None = None, correlated: bool = False, tied: bool = False
                   ) -> LuminanceFit:
    """One luminance fit, η free or held at ``fixed_eta``, from the initial state or ``start``,
    with the shadowing form ``correlated`` (:func:`pair_shadowing`)."""
    run = LuminanceRun(bins, nodes, fixed_eta, start=start, correlated=correlated, tied=tied)
    run.rounds(outer_iterations)
    return run.fit()


class LuminanceRun:
    """One luminance fit's outer rounds (``S`` from ``D``, then the Levenberg–Marquardt
    solve with ``S`` held), taken a round at a time so that a caller may look at the
    state between them (:func:`.pipeline.device_frame_check` stops a fit whose ``ε``
    already answers its question). η free or held at ``fixed_eta``, from the data's
    initial state or ``start``, with the shadowing form ``correlated``
    (:func:`pair_shadowing`) and the active set ``tied`` (:func:`fit_luminance`).
    ``rounds(n)`` then :meth:`fit` is the fit of ``n`` outer rounds (:attr:`taken`)."""

    def __init__(self, bins: PolarBins, nodes: Array, fixed_eta: float | None, start: LuminanceState | None = None,
                 correlated: bool = False, tied: bool = False) -> None:
        self.problem = problem = LuminanceProblem(bins, nodes, correlated)
        set_weights(problem)
        if start is None:
            self.state = initial_state(problem, 1.5 if fixed_eta is None else fixed_eta)
        else:
            self.state = start.copy()
            self.state.eta = self.state.eta if fixed_eta is None else fixed_eta
            update_shadowing(problem, self.state)
        self.fixed_eta = fixed_eta
        self.continuation = start is not None
        self.tie = tied
        self.left = self.held = False
        self.cost = math.inf
        self.taken = 0  # outer rounds taken

    def rounds(self, n: int) -> None:
        """Take ``n`` more outer rounds."""
        problem, s = self.problem, self.state
        fix_eta = self.fixed_eta is not None
        for _ in range(n):
            prior(problem, s)
            if self.tie and not self.held and not ks_bound_binds(problem, s):
                # the optimum lies inside the bound now: leave it (an active set's release)
                self.tie, self.left = False, True
            s, self.cost = solve(problem, s, fix_eta=fix_eta, tie_ks=self.tie)
            if not self.tie and s.g > 1.0:
                # the physical bound binds: continue on it. A continuation (``start``) that left it and
                # meets it again keeps it: its cost is compared with its start's, and a bound left and
                # met every other round makes that comparison follow the rounds' parity
                self.tie, self.held = True, self.left and self.continuation
                s, self.cost = solve(problem, s, fix_eta=fix_eta, tie_ks=True)
            update_shadowing(problem, s)
        self.state = s
        self.taken += max(n, 0)

    def model_error(self) -> float:
        """``ε`` of the current state (:func:`model_error`)."""
        return model_error(self.problem, self.state)

    def fit(self) -> LuminanceFit:
        """The fit at the current state."""
        return LuminanceFit(self.state, self.model_error(), self.cost, self.tie, self.problem)


def ks_bound_binds(problem: LuminanceProblem, s: LuminanceState) -> bool:
    """Whether the bound ``k_s ≤ 1`` holds the fit at ``s`` (a state on it): the cost's
    derivative by ``log g`` at fixed ``z``, ``Σ w_b r_b m_b,spec`` (the specular part of
    each active bin's model value times its weighted residual), is ≤ 0, so a smaller
    ``k_s`` would not lower the cost. Where it is > 0 the constraint's multiplier has
    the wrong sign: the fit's optimum lies inside the bound (Karush–Kuhn–Tucker), and a
    fit kept on it stays wherever the tie caught it."""
    r, m = problem.residuals(s)
    return float(np.sum(problem.w * r * (m - s.kd / math.pi))) <= 0.0


def channel_scalars(fit: LuminanceFit, kd_max: Array | None = None) -> tuple[Array, Array]:
    """``0 ≤ k_d ≤ k_d,max`` and ``0 ≤ k_s ≤ 1`` per channel with the fitted ``D``, ``S`` and ``η``.

    Linear least squares of ``f_c = k_{d,c}/π + k_{s,c} F D S/(4 cos cos)`` over the
    measured bins with the luminance fit's weights, on the box of the physical bounds:
    ``k_s ≤ 1`` (a microfacet reflects at most F) and ``k_d ≤ k_d,max`` (shape ``(3,)``,
    :func:`.samples.kd_median_bound`: the specular term is ≥ 0, so ``k_d/π`` cannot
    exceed what most samples measure). Without the second bound a channel whose lobe
    the luminance fit's ``D`` does not match can put its misfit into ``k_d``: a diffuse
    level hundreds of times the measured floor (a metal rendered as a coloured plastic).
    """
    return scalars_under_ceilings(fit, [kd_max])[0]


def scalars_under_ceilings(fit: LuminanceFit, ceilings: list[Array | None]) -> list[tuple[Array, Array]]:
    """:func:`channel_scalars` for each ``k_d`` ceiling of ``ceilings`` (``None``: none),
    from one pass over the bins (the normal equations do not depend on the ceiling)."""
    p = fit.problem
    s = fit.state
    n = ndf_integral(p.nodes, s.z)
    unit = LuminanceState(s.z, 0.0, 1.0 / n, s.eta)  # k_s = 1
    base, _ = p.specular(unit)
    me = p.measured
    a = np.stack([np.full(int(me.sum()), 1.0 / math.pi), base[me]], axis=1)
    w = p.w[me]
    m = a.T @ (a * w[:, None])
    m = m + 1e-12 * np.trace(m) * np.eye(2)
    vs = [a.T @ (w * p.bins.f[me, c]) for c in range(3)]
    out = []
    for kd_max in ceilings:
        upper = np.full(3, np.inf) if kd_max is None else np.asarray(kd_max, dtype=np.float64)
        kd, ks = np.zeros(3), np.zeros(3)
        for c in range(3):
            kd[c], ks[c] = _box_least_squares(m, vs[c], (0.0, float(upper[c])), (0.0, 1.0))
        out.append((kd, ks))
    return out


def tint_nodes(theta_d: Array, theta_h: Array, information: Array, led: NDArray[np.intp]) -> Array:
    """The ``θ_d`` nodes of the Fresnel tint: one per cluster of the specular information.

    An LED whose slice holds the mirror direction (a bin within :data:`MIRROR_THETA_H`
    of ``θ_h = 0``) measures the specular scale around one ``θ_d``: the
    information-weighted mean of its bins' ``θ_d`` (``information`` = the weight times the
    squared derivative of the model by the scale, per bin), with the weighted spread
    ``σ``. At the peak of a sharp lobe that is the LED's incidence angle, ``σ`` a
    fraction of a degree; a broad lobe spreads it over tens of degrees. An LED that
    sees only the lobe's flank measures the scale times a part of ``D`` the fit
    extrapolates, and sets no node (its bins still enter the fit). Clusters whose
    means lie closer than the sum of their spreads measure the same part of the
    Fresnel curve and are pooled (closest first), so nodes stand only where the data
    tell the scale at one ``θ_d`` from the scale at another. The pooling stops at two
    clusters whose means are more than a ``θ_d`` cell (:data:`TD_STEP`) apart: LEDs
    that overlap pairwise can chain across tens of degrees (a broad lobe on a layout
    with many LEDs: means 49°, 56°, 58°, 66°, 73°, spreads 7–10°), and the bins of the
    whole chain still measure the scale's slope across it, which one node would drop.

    Returns the nodes (radians, increasing; one node where every LED that holds the
    mirror direction measures the same ``θ_d`` cell, or none where no slice holds it:
    the tint is constant).
    """
    return np.array([mean for mean, _ in tint_clusters(theta_d, theta_h, information, led)])


def tint_clusters(theta_d: Array, theta_h: Array, information: Array,
                  led: NDArray[np.intp]) -> list[tuple[float, tuple[int, ...]]]:
    """:func:`tint_nodes` with the LEDs of each node: ``(θ_d node (radians), LEDs)``, increasing."""
    clusters: list[tuple[float, float, float, tuple[int, ...]]] = []  # weight, mean, mean square, LEDs
    for k in np.unique(led):
        sel = led == k
        if theta_h[sel].min() > MIRROR_THETA_H:
            continue
        w = information[sel]
        total = float(w.sum())
        if not total > 0 or not math.isfinite(total):
            continue
        mu = float(w @ theta_d[sel]) / total
        clusters.append((total, mu, float(w @ theta_d[sel] ** 2) / total, (int(k),)))
    clusters.sort(key=lambda c: c[1])
    while len(clusters) > 1:
        spread = [math.sqrt(max(c[2] - c[1] ** 2, 0.0)) for c in clusters]
        gaps = [clusters[i + 1][1] - clusters[i][1] - spread[i] - spread[i + 1] for i in range(len(clusters) - 1)]
        i = int(np.argmin(gaps))
        if gaps[i] > 0 or (len(clusters) == 2 and clusters[1][1] - clusters[0][1] > TD_STEP):
            break
        a, b = clusters[i], clusters[i + 1]
        total = a[0] + b[0]
        clusters[i:i + 2] = [(total, (a[0] * a[1] + b[0] * b[1]) / total, (a[0] * a[2] + b[0] * b[2]) / total,
                              a[3] + b[3])]
    return [(c[1], c[3]) for c in clusters]


def node_ndfs(fit: LuminanceFit, nodes: Array, leds: list[tuple[int, ...]]) -> NodeNDFs:
    """The lobe's NDF at each ``θ_d`` node, from the slices of the node's LEDs.

    A sharp lobe's shape changes with ``θ_d`` (chrome-steel's falls to 0.040 of its
    peak at ``θ_h`` = 0.5° at ``θ_d`` = 26° and to 0.089 at 65°), and the one ``D`` of
    the luminance fit is the compromise its weights make between the nodes. Near the
    peak only the nodes' slices see ``D`` (the other LEDs' half vectors stay 16–29° from
    the normal on the paper's layout); there the data tell one node's lobe from
    another's. So at each node ``log D`` is refitted to the bins of the LEDs that set
    the node (the slices that hold the mirror direction there), from the luminance
    fit's state with its ``k_d`` and ``η`` held, its priors (:func:`prior`) and ``S``
    from the node's own ``D`` (eq. 8), renewed each of :data:`NODE_ROUNDS` rounds as the
    luminance fit renews it; from the first ring that another LED's measured bins reach,
    every LED sees the lobe and the node's ``D`` continues as the luminance fit's does
    (its tail, a fraction of a percent of a diffuse sample's value, is no one slice's to
    tell). Each node's ``D`` is normalized; the specular level and colour per node are
    the tint's (:func:`tinted_scalars`).
    """
    p, base = fit.problem, fit.state
    me = p.measured
    others = me & ~np.isin(p.bins.led, [k for members in leds for k in members])
    shared_from = int(p.j[others].min()) if others.any() else None
    out = []
    for members in leds:
        sel = np.isin(p.bins.led, members)
        sub = LuminanceProblem(PolarBins(*(getattr(p.bins, f.name)[sel] for f in dataclasses.fields(PolarBins))),
                               p.nodes, p.correlated)
        set_weights(sub)
        s = base.copy()
        update_shadowing(sub, s)
        for _ in range(NODE_ROUNDS):
            prior(sub, s, tail=base.z, tail_from=shared_from)
            s, _ = solve(sub, s, fix_eta=True, fix_kd=True)
            update_shadowing(sub, s)
        out.append(IsotropicNDF(p.nodes, np.exp(s.z - s.z.max())))
    return NodeNDFs(nodes, out)


def unit_specular(fit: LuminanceFit, lobes: NodeNDFs | None = None) -> Array:
    """The specular term of every bin with ``k_s = 1``: ``F(θ_d; η) D(θ_h) S(θ_i) S(θ_o) /
    (4 cos θ_i cos θ_o)`` (sr⁻¹, shape ``(B,)``), with the fitted ``D``, ``S`` and ``η``; with
    ``lobes``, ``Σ_j H_j(θ_d) D_j S_j S_j`` of the nodes' lobes in place of ``D S S``
    (:class:`reflecto.model.IsotropicMicrofacetBRDF`'s ``lobes``)."""
    p, s = fit.problem, fit.state
    if lobes is None:
        n = ndf_integral(p.nodes, s.z)
        return p.specular(LuminanceState(s.z, 0.0, 1.0 / n, s.eta))[0]
    b = p.bins
    lobe = np.zeros(len(b))
    for w, ndf in zip(lobes.hats(np.arccos(np.clip(b.cos_d, 0.0, 1.0))), lobes.ndfs):
        lobe += w * ndf.at_theta(b.theta_h) * ndf.pair_shadowing(*p.direction_cells, p.correlated)[0]
    return fresnel(b.cos_d, s.eta) * lobe * p.geometry


def _tint_design(base: Array, theta_d: Array, nodes: Array) -> Array:
    """Columns ``[1/π, base·H_j(θ_d)]`` of the per-channel least squares (``H_j`` the hat
    functions of ``nodes``, constant beyond the ends; one node: one column ``base``)."""
    k = len(nodes)
    a = np.zeros((len(theta_d), k + 1))
    a[:, 0] = 1.0 / math.pi
    if k == 1:
        a[:, 1] = base
        return a
    j = np.clip(np.searchsorted(nodes, theta_d) - 1, 0, k - 2)
    t = np.clip((theta_d - nodes[j]) / (nodes[j + 1] - nodes[j]), 0.0, 1.0)
    rows = np.arange(len(theta_d))
    a[rows, 1 + j] = base * (1.0 - t)
    a[rows, 2 + j] += base * t
    return a


def _bounded_scalars(a: Array, w: Array, f: Array, kd_max: Array, g_max: Array) -> Array:
    """Per channel ``argmin Σ w (a x − f_c)²`` on ``0 ≤ x_0 ≤ k_d,max``, ``0 ≤ x_j ≤ g_max``;
    shape ``(K + 1, 3)``. Solved on the Cholesky factor of the normal matrix (``K + 1`` rows)."""
    m = a.T @ (a * w[:, None])
    m += 1e-12 * np.trace(m) * np.eye(len(m))
    chol = np.linalg.cholesky(m)
    x = np.zeros((len(m), 3))
    for c in range(3):
        v = a.T @ (w * f[:, c])
        x[:, c] = optimize.lsq_linear(chol.T, np.linalg.solve(chol, v),
                                      bounds=(np.zeros(len(m)), np.r_[max(kd_max[c], 1e-300), g_max]),
                                      method="bvls").x
        if not kd_max[c] > 0:  # the solver needs an open box: a ceiling of 0 is k_d = 0, not 1e-300
            x[0, c] = 0.0
    return x


def _scale_bound(nodes: Array, eta: float) -> Array:
    """``1/F(θ_j; η)`` at the nodes: the specular reflectance ``g F`` stays ≤ 1."""
    return 1.0 / np.maximum(fresnel(np.cos(nodes), eta), 1e-300)


def tinted_scalars(fit: LuminanceFit, kd_max: Array | None = None, per_node: bool = True
                   ) -> tuple[Array, Array, FresnelTint | None, NodeNDFs | None]:
    """``k_d``, ``k_s`` and the Fresnel tint per channel with the fitted ``D``, ``S`` and ``η``.

    The specular scale becomes a function of ``θ_d``, piecewise linear between the
    nodes of :func:`tint_nodes` (where the data measure it) and, in this fit, constant
    beyond the first and the last: per channel

    ``f_c = k_{d,c}/π + g_c(θ_d) F(θ_d; η) D S S / (4 cos θ_i cos θ_o)``,  ``g_c = Σ_j g_{c,j} H_j(θ_d)``

    (``H_j`` the hat functions of the nodes), fitted by linear least squares over the
    measured bins with the luminance fit's weights (eq. 10's), on the box
    ``0 ≤ g_{c,j} ≤ 1/F(θ_j; η)`` (the specular reflectance ``k_s F_c`` is at most 1)
    and ``0 ≤ k_d ≤ k_d,max`` (:func:`channel_scalars`). Past the last node the tint
    continues as :data:`TINT_BEYOND` says (:class:`~reflecto.fresnel.FresnelTint`): the
    fit's bins there are fitted with the last node's value, so a trend starts where they
    end (``trend_from``: about a degree past the last node on the paper's layout).

    Where there are two nodes or more (and ``per_node``), ``D`` is the lobe's per node
    (:func:`node_ndfs`) and interpolated between them as the tint is.

    Returns ``k_d`` (3,), ``k_s = min(1, max_j g_{c,j})`` (3,), the tint ``τ = g / k_s``
    (so ``F_c = τ F ≤ 1`` at the nodes; the model clips it at 1 between them), or ``None``
    where the data hold one node (then ``g`` is one number per channel: ``k_s``), and the
    NDF per node (or ``None``).
    """
    p = fit.problem
    me = p.measured
    base = unit_specular(fit)[me]
    td = np.arccos(np.clip(p.bins.cos_d[me], 0.0, 1.0))
    w = p.w[me]
    clusters = tint_clusters(td, p.bins.theta_h[me], w * base ** 2, p.bins.led[me])
    nodes = np.array([c[0] for c in clusters])
    lobes = None
    if len(nodes) > 1 and per_node:
        lobes = node_ndfs(fit, nodes, [c[1] for c in clusters])
        base = unit_specular(fit, lobes)[me]
    if len(nodes) == 0:  # no slice holds the mirror direction: one scale per channel
        nodes = np.zeros(1)
    upper = np.full(3, np.inf) if kd_max is None else np.asarray(kd_max, dtype=np.float64)
    g_max = _scale_bound(nodes, fit.state.eta) if len(nodes) > 1 else np.ones(1)
    x = _bounded_scalars(_tint_design(base, td, nodes), w, p.bins.f[me], upper, g_max)
    kd, g = x[0], x[1:]
    ks = np.minimum(g.max(axis=0), 1.0)
    if len(nodes) < 2:
        return kd, ks, None, None
    tau = np.divide(g, ks, out=np.ones_like(g), where=ks > 0)
    # the trend starts where the bins this fit held at the last node's value end
    trend_from = max(float(nodes[-1]), float(td.max())) if TINT_BEYOND == "trend" else None
    return kd, ks, FresnelTint(nodes, np.clip(tau, 0.0, MAX_TINT), TINT_BEYOND, trend_from), lobes


def _box_least_squares(m: Array, v: Array, xb: tuple[float, float], yb: tuple[float, float]) -> tuple[float, float]:
    """``argmin xᵀMx − 2vᵀx`` over the box ``xb × yb`` (2 × 2 SPD ``M``): the interior
    minimum if it lies in the box, else the best of the four edges' minima."""
    def cost(x: float, y: float) -> float:
        q = np.array([x, y])
        return float(q @ m @ q - 2.0 * v @ q)

    x = np.linalg.solve(m, v)
    if xb[0] <= x[0] <= xb[1] and yb[0] <= x[1] <= yb[1]:
        return float(x[0]), float(x[1])
    best = None
    for fixed in (xb[0], xb[1]):  # x on an edge: y free within its bounds
        if math.isfinite(fixed):
            y = min(max((v[1] - m[0, 1] * fixed) / m[1, 1], yb[0]), yb[1])
            best = min(best or (math.inf, 0.0, 0.0), (cost(fixed, y), fixed, y))
    for fixed in (yb[0], yb[1]):
        x0 = min(max((v[0] - m[0, 1] * fixed) / m[0, 0], xb[0]), xb[1])
        best = min(best or (math.inf, 0.0, 0.0), (cost(x0, fixed), x0, fixed))
    assert best is not None  # the loop over y's two bounds always sets it
    return best[1], best[2]


@dataclasses.dataclass
class IsotropicFit:
    """Result of :func:`fit_isotropic`.

    Attributes
    ----------
    model
        The reconstructed BRDF, built on first use: the per-channel scalars under the
        ``k_d`` ceiling, the Fresnel tint and the NDF per ``θ_d`` node
        (:func:`tinted_scalars`), which a fit used only for its ``ε`` (the device frame's
        check, :mod:`.pipeline`) never needs.
    eta
        The relative index (one for R, G, B).
    model_error
        ``ε``, the RMS relative misfit of the measured bins beyond their noise.
    ks_at_bound
        The physical bound ``k_s ≤ 1`` binds (the specular level then fixes ``η``).
    bins
        Number of bins fitted (measured, censored).
    least_squares
        The same ``D``, ``S`` and η with the channel scalars of the least-squares fit
        without the ``k_d`` ceiling: the isotropic class's best explanation of the
        samples, which the isotropy test (:func:`.isotropy.azimuthal_test`) compares
        them with (its thresholds are set on it). ``model`` is the one to use.
    """

    eta: float
    model_error: float
    ks_at_bound: bool
    bins: tuple[int, int]
    least_squares: IsotropicMicrofacetBRDF
    luminance: LuminanceFit
    #: ``k_d``'s ceiling per channel (:func:`.samples.kd_median_bound`), computed with the model.
    ceiling: Callable[[], Array]

    @functools.cached_property
    def kd_ceiling(self) -> Array:
        """``k_d``'s ceiling per channel (3,): ``π`` times the samples' median (:func:`.samples.kd_median_bound`)."""
        return np.asarray(self.ceiling(), dtype=np.float64)

    @functools.cached_property
    def model(self) -> IsotropicMicrofacetBRDF:
        """The reconstructed BRDF (see the class docstring)."""
        lum = self.luminance
        kd, ks, tint, lobes = tinted_scalars(lum, self.kd_ceiling)
        d = np.exp(lum.state.z - lum.state.z.max())
        return IsotropicMicrofacetBRDF((lum.problem.nodes, d), kd, ks, lum.state.eta, tint=tint,
                                       correlated=lum.problem.correlated,
                                       lobes=None if lobes is None else (lobes.theta_d, lobes.values))


def fit_isotropic(slices: Slices, valid: NDArray[np.bool_], fixed_eta: float | None = None,
                  kd_bound_max_deg: float = 75.0) -> IsotropicFit:
    """Reconstruct an isotropic material from its slices (see the module docstring), with
    eq. 8's product shadowing (:mod:`.extrapolation` may replace it); ``k_d`` is bounded by
    the samples with θ_i, θ_o ≤ ``kd_bound_max_deg`` (:func:`.samples.kd_median_bound`)."""
    return finish_isotropic(start_isotropic(slices, valid, fixed_eta), slices, valid, kd_bound_max_deg)


def start_isotropic(slices: Slices, valid: NDArray[np.bool_], fixed_eta: float | None = None) -> LuminanceRun:
    """:func:`fit_isotropic`'s luminance fit before its first outer round: the slices
    binned on the polar nodes (``valid`` the samples that enter), η free or held."""
    nodes = polar_nodes()
    return LuminanceRun(bin_polar(slices, nodes, valid), nodes, fixed_eta)


def finish_isotropic(run: LuminanceRun, slices: Slices, valid: NDArray[np.bool_], kd_bound_max_deg: float = 75.0,
                     outer_iterations: int = OUTER_ITERATIONS) -> IsotropicFit:
    """:func:`fit_isotropic` from a run of :func:`start_isotropic` that has taken some of
    its ``outer_iterations`` rounds: the rest, the constant Fresnel lobe's retry
    (:func:`with_constant_fresnel`), and ``k_d``'s ceiling on demand."""
    run.rounds(outer_iterations - run.taken)
    lum = with_constant_fresnel(run.fit(), run.fixed_eta, outer_iterations)
    return isotropic_fit(lum, lambda: kd_median_bound(slices.light, slices.view, slices.values, valid,
                                                      kd_bound_max_deg))


def isotropic_fit(lum: LuminanceFit, ceiling: Callable[[], Array]) -> IsotropicFit:
    """The :class:`IsotropicFit` of a converged luminance fit, with ``k_d``'s ceiling
    per channel computed on demand by ``ceiling``."""
    bins, nodes = lum.problem.bins, lum.problem.nodes
    ((kd_ls, ks_ls),) = scalars_under_ceilings(lum, [None])
    d = np.exp(lum.state.z - lum.state.z.max())
    ls = IsotropicMicrofacetBRDF((nodes, d), kd_ls, ks_ls, lum.state.eta, correlated=lum.problem.correlated)
    return IsotropicFit(lum.state.eta, lum.eps, lum.ks_bound,
                        (int(np.count_nonzero(~bins.censored)), int(np.count_nonzero(bins.censored))), ls, lum,
                        ceiling)
