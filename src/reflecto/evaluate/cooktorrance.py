"""Cook–Torrance baseline fitted to a dense reference, as Ngan et al. 2005 did (paper §6).

Model (algorithm-reference §6.3, BBM's re-implementation of Ngan's fit)::

    f = ρ_d/π + ρ_s · D_Beck(h; m) · G_V(i, o, h) · F_Schlick(F0, i·h) / (π cos θ_i cos θ_o)

with ``D_Beck = exp(−tan²θ_h/m²)/(π m² cos⁴θ_h)``, the V-groove
``G_V = min(1, 2 cosθ_h cosθ_i/(i·h), 2 cosθ_h cosθ_o/(o·h))`` and Schlick's
``F = F0 + (1 − F0)(1 − i·h)⁵``. Parameters: ρ_d, ρ_s (RGB), F0 and m (scalars).

Fit: weighted least squares on exactly the error of eq. 10 (the cosine-weighted
differences on the MERL bin grid, θ ≤ 80°, solid-angle weights). For fixed
``(F0, m)`` the RGB albedos enter linearly, so they are solved in closed form (two
non-negative unknowns per channel) and the optimizer only sees ``(log m, F0)``
(variable projection); bounded trust-region least squares from several starts
(Ngan restarted unsatisfactory fits by hand). The fit uses every fourth θ_d and φ_d
bin (stride 4); the reported error is on the full grid.
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Any, cast

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares

from .. import _kernels, geometry
from ..brdf import BRDFSource
from ..errors import ParameterError
from ..hemicube import hemicube
from ..instrument.slices import finite_rgb
from ..reconstruct.samples import bin_samples
from .metrics import evaluate_on_grid, metric_grid

if TYPE_CHECKING:
    from ..brdf import ArrayField

Array = NDArray[np.float64]

#: Starting roughnesses and F0 values of the multi-start.
STARTS_M = (0.02, 0.1, 0.4)
STARTS_F0 = (0.05, 0.9)


@dataclasses.dataclass
class CookTorrance(BRDFSource):
    """The Cook–Torrance model of the module docstring (sr⁻¹)."""

    #: RGB albedos, any array-like broadcast to shape ``(3,)`` (float64 arrays once constructed).
    rho_d: ArrayField = cast("ArrayField", (0.0, 0.0, 0.0))
    rho_s: ArrayField = cast("ArrayField", (0.0, 0.0, 0.0))
    f0: float = 0.04
    m: float = 0.1

    kind = "cook-torrance"

    def __post_init__(self) -> None:
        try:
            self.rho_d = np.broadcast_to(np.asarray(self.rho_d, float), (3,)).copy()
            self.rho_s = np.broadcast_to(np.asarray(self.rho_s, float), (3,)).copy()
            self.f0, self.m = float(self.f0), float(self.m)
        except (TypeError, ValueError) as e:
            raise ParameterError(f"Cook–Torrance: ρ_d, ρ_s must be 1 or 3 numbers and F0, m numbers ({e})") from None
        if not (np.all(np.isfinite(self.rho_d)) and np.all(self.rho_d >= 0)
                and np.all(np.isfinite(self.rho_s)) and np.all(self.rho_s >= 0)):
            raise ParameterError(f"Cook–Torrance: ρ_d and ρ_s must be finite and ≥ 0, got {self.rho_d.tolist()} "
                                 f"and {self.rho_s.tolist()}")
        if not (0.0 <= self.f0 <= 1.0) or not (math.isfinite(self.m) and self.m > 0.0):
            raise ParameterError(f"Cook–Torrance: F0 must lie in [0, 1] and m be finite and > 0, got {self.f0} "
                                 f"and {self.m}")
        self.isotropic = True
        self.reciprocal = True
        self.path = None

    def lobe(self, i: Array, o: Array) -> Array:
        """The specular lobe without ρ_s: ``D_Beck G_V F_Schlick / (π cos θ_i cos θ_o)``
        (sr⁻¹ per unit ρ_s; module docstring).

        Parameters
        ----------
        i, o
            Unit light and view directions in the local frame (``z = n``), shape ``(N, 3)``
            (or broadcastable ``(..., 3)``).

        Returns
        -------
        numpy.ndarray, shape (N,)
            The lobe at each pair; 0 where either direction is below the horizon.
        """
        return _lobe(i, o, self.f0, self.m)

    def eval(self, i: ArrayLike, o: ArrayLike) -> Array:
        """Cook–Torrance BRDF ``f = ρ_d/π + ρ_s D G F / (π cos θ_i cos θ_o)`` (sr⁻¹; algorithm
        reference §6.3).

        Parameters
        ----------
        i, o
            Unit directions in the local frame (``x = t, y = b, z = n``; ``i`` toward the
            light, ``o`` toward the viewer), shape ``(N, 3)`` (or broadcastable ``(..., 3)``),
            as :meth:`reflecto.brdf.BRDFSource.eval`.

        Returns
        -------
        numpy.ndarray, shape (N, 3)
            Linear RGB BRDF (sr⁻¹); 0 where either direction is below the horizon.
        """
        i = np.asarray(i, float)
        o = np.asarray(o, float)
        ok = (i[..., 2] > 0) & (o[..., 2] > 0)
        spec = _lobe(i, o, self.f0, self.m)
        f = self.rho_d / math.pi + self.rho_s * spec[..., None]
        return np.where(ok[..., None], f, 0.0)

    def parameters(self) -> dict[str, Any]:
        """The fitted parameters, for ``reflecto info`` and ``fit-ct``.

        Returns
        -------
        dict
            ``rho_d``, ``rho_s`` (RGB lists of 3 floats, dimensionless albedos), ``F0``
            (Schlick's reflectance at normal incidence) and ``m`` (Beckmann roughness), floats.
        """
        return {"rho_d": self.rho_d.tolist(), "rho_s": self.rho_s.tolist(), "F0": self.f0, "m": self.m}

    @property
    def name(self) -> str:
        """``"cook-torrance"``."""
        return "cook-torrance"


def _lobe(i: Array, o: Array, f0: float, m: float) -> Array:
    h = geometry.normalize(i + o)
    ci, co, ch = i[..., 2], o[..., 2], np.clip(h[..., 2], 1e-9, 1.0)
    c = np.clip(np.sum(i * h, axis=-1), 1e-9, 1.0)
    t2 = (1.0 - ch * ch) / (ch * ch)
    d = np.exp(-t2 / (m * m)) / (math.pi * m * m * ch**4)
    g = np.minimum(1.0, np.minimum(2 * ch * ci / c, 2 * ch * co / c))
    f = f0 + (1 - f0) * (1 - c) ** 5
    den = math.pi * np.maximum(ci, 1e-9) * np.maximum(co, 1e-9)
    return np.where((ci > 0) & (co > 0), d * np.maximum(g, 0.0) * f / den, 0.0)


def _nnls2(aa: float, ab: float, bb: float, ay: float, by: float) -> tuple[float, float]:
    """``min |x0 a + x1 b − y|²`` with x ≥ 0, from the dot products of ``a``, ``b``, ``y``."""
    det = aa * bb - ab * ab
    if det > 1e-300:
        x0 = (bb * ay - ab * by) / det
        x1 = (aa * by - ab * ay) / det
        if x0 >= 0 and x1 >= 0:
            return float(x0), float(x1)
    # one of them at 0: |c a − y|² = c² aa − 2c ay + |y|², compared without |y|²
    c0 = max(ay / aa, 0.0) if aa > 0 else 0.0
    c1 = max(by / bb, 0.0) if bb > 0 else 0.0
    e0 = c0 * c0 * aa - 2.0 * c0 * ay
    e1 = c1 * c1 * bb - 2.0 * c1 * by
    return (c0, 0.0) if e0 <= e1 else (0.0, c1)


def fit_cook_torrance(reference: BRDFSource, stride: int = 4, reference_values: Array | None = None) -> CookTorrance:
    """Fit :class:`CookTorrance` to ``reference`` on the MERL grid (see the module docstring).

    The bins of ``metric_grid(stride)`` (θ_i, θ_o ≤ 80°, ``φ_h = 0``) where the reference
    is valid (all channels ≥ 0 and finite) go to :func:`fit_cook_torrance_samples` with
    their solid-angle weights (AR 6.3), so the fit minimises the error of eq. 10.

    Parameters
    ----------
    reference
        The dense reference BRDF (e.g. a MERL material).
    stride
        Keep every ``stride``-th θ_d and φ_d bin (4 by default; 1 is every bin).
    reference_values
        ``reference`` already evaluated on ``metric_grid(stride)``, shape ``(K, 3)``, sr⁻¹;
        ``None``: evaluate it.

    Returns
    -------
    CookTorrance
        The fitted model (ρ_d, ρ_s per channel, F0, m).
    """
    g = metric_grid(stride)
    r = evaluate_on_grid(reference, g) if reference_values is None else np.asarray(reference_values, np.float64)
    if r.shape != (len(g.i), 3):
        raise ParameterError(f"Cook–Torrance fit: reference_values must have shape ({len(g.i)}, 3) (the grid of "
                             f"stride {stride}), got {r.shape}")
    ok = np.all(r >= 0, axis=1) & np.all(np.isfinite(r), axis=1)
    return fit_cook_torrance_samples(g.i[ok], g.o[ok], r[ok], g.w[ok])


#: The fewest usable samples :func:`fit_cook_torrance_samples` fits: its four parameters per
#: channel need more than four, and a fit to a handful is no baseline.
MIN_SAMPLES = 16


def fit_cook_torrance_samples(i: ArrayLike, o: ArrayLike, f: ArrayLike, w: ArrayLike) -> CookTorrance:
    """Fit :class:`CookTorrance` to BRDF samples by the residuals of eq. 10.

    Minimises ``Σ w (f − f_CT)² cos² θ_i`` over ``(ρ_d, ρ_s, F0, m)``: ``ρ_d, ρ_s`` in
    closed form (non-negative least squares per channel), ``(log m, F0)`` by bounded
    trust-region least squares (``m ∈ [0.002, 1.5]``, ``F0 ∈ [0, 1]``) from the starts
    :data:`STARTS_M` × :data:`STARTS_F0`, keeping the lowest cost.

    Parameters
    ----------
    i, o
        Light and view directions, shape ``(N, 3)``.
    f
        BRDF values (sr⁻¹), shape ``(N, 3)``.
    w
        Weight of each sample (the metric's solid-angle weight, or a pixel count), ``(N,)``.

    Returns
    -------
    CookTorrance
        The best fit over the starts.

    Raises
    ------
    ParameterError
        Shapes that do not match, or fewer than :data:`MIN_SAMPLES` usable samples (finite
        values, a positive weight, both directions above the horizon; the others are left out).
    """
    i, o = np.ascontiguousarray(i, dtype=np.float64), np.ascontiguousarray(o, dtype=np.float64)
    r = np.asarray(f, dtype=np.float64)
    w = np.asarray(w, dtype=np.float64)
    n = len(i)
    if i.shape != (n, 3) or o.shape != (n, 3) or r.shape != (n, 3) or w.shape != (n,):
        raise ParameterError(f"Cook–Torrance fit: i, o, f must have shape (N, 3) and w (N,), got {i.shape}, "
                             f"{o.shape}, {r.shape} and {w.shape}")
    usable = np.all(np.isfinite(r), axis=1) & np.isfinite(w) & (w > 0) & (i[:, 2] > 0) & (o[:, 2] > 0)
    if np.count_nonzero(usable) < MIN_SAMPLES:
        raise ParameterError(f"Cook–Torrance fit: {np.count_nonzero(usable)} of {n} samples usable (finite values, "
                             f"a positive weight, both directions above the horizon); it needs at least {MIN_SAMPLES}")
    if not np.all(usable):
        i, o, r, w = np.ascontiguousarray(i[usable]), np.ascontiguousarray(o[usable]), r[usable], w[usable]
    sw = np.sqrt(w) * i[:, 2]  # residual = √w (R − M) cos θ_i
    y = np.ascontiguousarray(r * sw[:, None])
    diff = sw / math.pi
    # fixed by the data: the diffuse column's dot products
    aa, ay = float(diff @ diff), diff @ y
    lobe = np.empty(len(sw))

    def solve(f0: float, m: float) -> tuple[Array, Array, Array]:
        # one compiled pass for the lobe; its dot products by BLAS; ρ_d, ρ_s in closed form
        _kernels.ct_lobe(i, o, sw, f0, m, lobe)
        ab, bb, by = float(diff @ lobe), float(lobe @ lobe), lobe @ y
        rd, rs = np.zeros(3), np.zeros(3)
        for ch in range(3):
            rd[ch], rs[ch] = _nnls2(aa, ab, bb, float(ay[ch]), float(by[ch]))
        res = np.empty_like(y)
        _kernels.ct_residual(diff, lobe, y, rd, rs, res)
        return rd, rs, res

    def resid(x: Array) -> Array:
        return solve(float(x[1]), math.exp(float(x[0])))[2].ravel()

    best: tuple[float, Array] | None = None
    for m0 in STARTS_M:
        for f00 in STARTS_F0:
            try:
                sol = least_squares(resid, [math.log(m0), f00], bounds=([math.log(0.002), 0.0], [math.log(1.5), 1.0]),
                                    method="trf", x_scale=[1.0, 0.3], max_nfev=60)
            except ValueError:
                continue
            if best is None or sol.cost < best[0]:
                best = (float(sol.cost), sol.x)
    assert best is not None
    x = best[1]
    f0, m = float(x[1]), math.exp(float(x[0]))
    rd, rs, _ = solve(f0, m)
    return CookTorrance(rd, rs, f0, m)


def fit_cook_torrance_capture(slices: Any) -> CookTorrance:
    """The same-data baseline: :class:`CookTorrance` fitted to exactly the samples a capture holds.

    The parametric sparse fit the paper's related work compares against: every valid
    sample of the slices (readings at the detection limit too, as they are), averaged
    per LED and texel of a 128² hemicube (each bin weighs by its pixel count), fitted
    by :func:`fit_cook_torrance_samples`.

    Parameters
    ----------
    slices
        The capture's BRDF slices (:class:`reflecto.instrument.slices.Slices`): ``light``
        ``(L, 3)``, ``view`` ``(P, 3)``, ``values`` ``(L, P, 3)`` in sr⁻¹, ``valid``
        ``(L, P)``; samples with a non-finite value are left out as well.

    Returns
    -------
    CookTorrance
        The fitted model.
    """

    ok = slices.valid & finite_rgb(slices.values)
    bins = bin_samples(slices.light, slices.view, slices.values, ok, hemicube(128))
    return fit_cook_torrance_samples(bins.i, bins.o, bins.f, bins.count)
