"""Is the material isotropic, and does it keep the symmetry of eq. 3? Azimuthal harmonics of the residual.

An isotropic NDF depends on ``θ_h`` alone. With the isotropic fit of
:mod:`.isotropic` as reference, each sample's specular part gives the log ratio
``r = log((f − k_d/π) / f_spec,iso)`` of its partial NDF (eq. 7) to the isotropic
``D``. On a ring of half vectors (fixed ``θ_h``) the six LEDs see ``h`` at many
azimuths ``φ_h``; an anisotropic NDF modulates ``D`` along the ring, and a
microfacet NDF ``D(sᵀAs)`` (any ellipse of slopes, Walter et al. 2007) does so
through its second harmonic ``cos 2φ_h, sin 2φ_h`` (it is symmetric under
``φ → φ + π``). An NDF that breaks eq. 3 (``D(h) ≠ D(τh)``, ``τ`` the half turn about
``n``) adds odd harmonics, led by ``cos φ_h, sin φ_h``.

Per ring (:data:`RING_WIDTH_DEG`), ``r`` is regressed on ``[1, cos 2φ, sin 2φ]`` and on
``[1, cos 2φ, sin 2φ, cos φ, sin φ]``; the statistics are the fractions of the
ring-wise variance of ``r`` that the second harmonic explains (anisotropy) and that
the first harmonic explains beyond it (asymmetry), pooled over the rings. The
misfit of an isotropic material to the model scatters over all azimuths and over
``θ_d``; an anisotropic lobe concentrates it in the harmonic. On the 25 shared
materials of the tuning half the explained fraction stays ≤ 0.71 (metals with few
samples per ring), on anisotropic GGX/Beckmann lobes with α_x/α_y ≥ 1.5 it is ≥ 0.89:
:data:`ANISOTROPY_EXPLAINED` is the midpoint.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numpy.typing import NDArray

from ..colour import LUM
from ..instrument.slices import Slices

Array = NDArray[np.float64]

__all__ = ["IsotropyTest", "azimuthal_test"]

#: Width of the rings of half vectors (degrees).
RING_WIDTH_DEG = 2.0
#: Rings from this polar angle (degrees; nearer the pole the azimuth is ill defined) …
RING_START_DEG = 1.0
#: … to this one.
RING_END_DEG = 60.0
#: A ring enters with at least this many samples …
MIN_RING_SAMPLES = 30
#: … and an azimuthal spread that conditions its regression (condition number below this).
MAX_CONDITION = 1e3
#: Samples enter where the isotropic model's specular part is at least this fraction
#: of the BRDF (where the partial NDF is measured, not the diffuse floor).
MIN_SPECULAR_FRACTION = 0.5
#: Explained fraction of the ring-wise variance above which the material is anisotropic.
ANISOTROPY_EXPLAINED = 0.8
#: Explained fraction (first harmonic, beyond the second) above which eq. 3 is broken.
ASYMMETRY_EXPLAINED = 0.5
#: At least this many rings for a verdict; fewer (a capture with almost no specular
#: signal) leave the material isotropic.
MIN_RINGS = 3


@dataclasses.dataclass(frozen=True)
class IsotropyTest:
    """Azimuthal harmonics of the partial NDF against an isotropic fit.

    Attributes
    ----------
    anisotropy
        Fraction of the ring-wise variance of the log partial NDF explained by
        ``cos 2φ_h, sin 2φ_h`` (0 … 1).
    asymmetry
        Fraction of the variance left by the second harmonic that ``cos φ_h, sin φ_h``
        explain (0 … 1): a break of eq. 3.
    amplitude
        Sample-weighted mean amplitude of the second harmonic (in log D).
    rings
        Rings that entered.
    """

    anisotropy: float
    asymmetry: float
    amplitude: float
    rings: int

    @property
    def decided(self) -> bool:
        return self.rings >= MIN_RINGS

    @property
    def isotropic(self) -> bool:
        """No significant second harmonic (or too few rings to tell)."""
        return not self.decided or self.anisotropy < ANISOTROPY_EXPLAINED

    @property
    def symmetric(self) -> bool:
        """No significant first harmonic: the data keep eq. 3's symmetry."""
        return not self.decided or self.asymmetry < ASYMMETRY_EXPLAINED

    def to_dict(self) -> dict[str, float | int | bool]:
        return {"anisotropy": self.anisotropy, "asymmetry": self.asymmetry, "amplitude": self.amplitude,
                "rings": self.rings, "isotropic": self.isotropic, "symmetric": self.symmetric}


def azimuthal_test(slices: Slices, valid: NDArray[np.bool_], model) -> IsotropyTest:
    """:class:`IsotropyTest` of the slices (sample frame) against an isotropic ``model``.

    Every :data:`PIXEL_STRIDE`-th pixel enters (the rings hold thousands of samples).
    """
    r, phi, ring = _log_ratios(slices, valid, model)
    if len(r) < MIN_RING_SAMPLES:
        return IsotropyTest(0.0, 0.0, 0.0, 0)
    n_rings = int(math.ceil((RING_END_DEG - RING_START_DEG) / RING_WIDTH_DEG))
    x = np.stack([np.ones(len(r)), np.cos(2 * phi), np.sin(2 * phi), np.cos(phi), np.sin(phi)], axis=1)
    # per ring: XᵀX (5 × 5), Xᵀr and rᵀr, accumulated in one pass
    xtx = np.stack([np.bincount(ring, x[:, a] * x[:, b], n_rings) for a in range(5) for b in range(5)], axis=1)
    xtx = xtx.reshape(n_rings, 5, 5)
    xtr = np.stack([np.bincount(ring, x[:, a] * r, n_rings) for a in range(5)], axis=1)
    rtr = np.bincount(ring, r * r, n_rings)
    n = xtx[:, 0, 0]
    use = n >= MIN_RING_SAMPLES
    even = xtx[:, :3, :3]
    use &= np.linalg.cond(np.where(use[:, None, None], even, np.eye(3))) <= MAX_CONDITION
    if not np.any(use):
        return IsotropyTest(0.0, 0.0, 0.0, 0)
    xtx, xtr, rtr, n = xtx[use], xtr[use], rtr[use], n[use]
    c3 = np.linalg.solve(xtx[:, :3, :3], xtr[:, :3, None])[..., 0]
    c5 = np.linalg.solve(xtx + 1e-12 * np.eye(5), xtr[..., None])[..., 0]
    v_total = float(np.sum(rtr - xtr[:, 0] ** 2 / n))  # Σ (r − r̄)² per ring
    v_even = float(np.sum(rtr - np.einsum("ka,ka->k", c3, xtr[:, :3])))  # residual of the normal equations' fit
    v_all = float(np.sum(rtr - np.einsum("ka,ka->k", c5, xtr)))
    if v_total <= 0:
        return IsotropyTest(0.0, 0.0, 0.0, int(use.sum()))
    amp = float(np.average(np.hypot(c3[:, 1], c3[:, 2]), weights=n))
    return IsotropyTest(1.0 - v_even / v_total, 1.0 - v_all / max(v_even, 1e-300), amp, int(use.sum()))


#: Every this many pixels enters the test.
PIXEL_STRIDE = 3


def _log_ratios(slices: Slices, valid: NDArray[np.bool_], model) -> tuple[Array, Array, NDArray[np.intp]]:
    """Log ratio of each usable sample's specular part to the model's, its ``φ_h`` and ring."""
    px = np.arange(0, slices.view.shape[0], PIXEL_STRIDE)
    values = slices.values[:, px]
    lum = values @ LUM
    ok = valid[:, px] & np.isfinite(lum)
    if slices.censored is not None:
        ok &= ~slices.censored[:, px]
    diffuse = float(model.kd @ LUM) / math.pi
    # a sample whose specular part is at least MIN_SPECULAR_FRACTION of the model's value
    # reads at least diffuse / (1 − fraction) unless the model is far off: the others
    # need no model evaluation
    ok &= lum > diffuse / (1.0 + MIN_SPECULAR_FRACTION)
    li, pj = np.nonzero(ok)
    i, o = slices.light[li], slices.view[px[pj]]
    f = lum[li, pj]
    pred = model.eval(i, o) @ LUM
    spec = pred - diffuse
    h = i + o
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    theta = np.degrees(np.arccos(np.clip(h[:, 2], -1.0, 1.0)))
    use = ((spec >= MIN_SPECULAR_FRACTION * pred) & (f > diffuse) & (spec > 0) & (theta >= RING_START_DEG)
           & (theta < RING_END_DEG))
    r = np.log((f[use] - diffuse) / spec[use])
    phi = np.arctan2(h[use, 1], h[use, 0])
    ring = ((theta[use] - RING_START_DEG) // RING_WIDTH_DEG).astype(np.intp)
    return r, phi, ring
