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

Per ring (:data:`RING_WIDTH_DEG`), ``r`` is regressed on ``[1, cos 2φ_h, sin 2φ_h]`` and on
``[1, cos 2φ_h, sin 2φ_h, cos φ_h, sin φ_h]``; the statistics are the fractions of the
ring-wise variance of ``r`` that the second harmonic explains (anisotropy) and that
the first harmonic explains beyond it (asymmetry), pooled over the rings.

An isotropic BRDF that is not exactly microfacet leaves a misfit that varies with
``θ_d`` and ``φ_d``, and on a ring the device's LEDs tie ``θ_d`` to ``φ_h``: that
misfit can read as a harmonic. The conditional statistic therefore regresses ``r``
per ring on a null basis ``[1, z, z² − 1, cos 2φ_d, sin 2φ_d]`` (``z`` the ring's
standardized ``θ_d``) and reports the fraction of what is left that the second
harmonic explains. A material is anisotropic when both statistics are large.
The thresholds are chosen on the tuning half of the shared materials and
checked on the validation half (isotropic ground truth, see
``docs/design/reconstruction.md``) and on anisotropic GGX/Beckmann lobes with
``α_x/α_y`` from 1.5 to 4: plain fraction ≤ 0.70 on the tuning half except one
material at 0.90, ≥ 0.93 on the lobes (:data:`ANISOTROPY_EXPLAINED` 0.8);
conditional fraction ≤ 0.42 on the tuning half, ≥ 0.52 on the lobes
(:data:`CONDITIONAL_EXPLAINED` their midpoint).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numpy.typing import NDArray

from ..colour import LUM
from ..geometry import io_to_hd
from ..instrument.slices import Slices
from .tuning import ISOTROPY

Array = NDArray[np.float64]

__all__ = ["IsotropyTest", "azimuthal_test"]

# Tuned numbers: what, units and provenance are in :mod:`.tuning` (isotropy stage).
RING_WIDTH_DEG = ISOTROPY.ring_width_deg
RING_START_DEG = ISOTROPY.ring_start_deg
RING_END_DEG = ISOTROPY.ring_end_deg
MIN_RING_SAMPLES = ISOTROPY.min_ring_samples
MAX_CONDITION = ISOTROPY.max_condition
MIN_SPECULAR_FRACTION = ISOTROPY.min_specular_fraction
ANISOTROPY_EXPLAINED = ISOTROPY.anisotropy_explained
MAX_CONDITION_CONDITIONAL = ISOTROPY.max_condition_conditional
CONDITIONAL_EXPLAINED = ISOTROPY.conditional_explained
MIN_RINGS = ISOTROPY.min_rings


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
        explain (0 … 1), reported only: it does not tell a break of eq. 3 (isotropic
        materials read up to 0.5, anisotropic lobes that keep eq. 3 up to 0.7); eq. 3 is
        :mod:`.eq3`'s decision.
    amplitude
        Sample-weighted mean amplitude of the second harmonic (in log D).
    rings
        Rings that entered.
    conditional
        Fraction of the ring-wise variance left by a smooth function of ``θ_d`` and
        ``φ_d`` (the misfit an isotropic BRDF can have) that ``cos 2φ_h, sin 2φ_h``
        explain (0 … 1).
    """

    anisotropy: float
    asymmetry: float
    amplitude: float
    rings: int
    conditional: float

    @property
    def decided(self) -> bool:
        """Whether enough rings entered for a verdict (at least :data:`MIN_RINGS`)."""
        return self.rings >= MIN_RINGS

    @property
    def isotropic(self) -> bool:
        """No significant second harmonic (or too few rings to tell).

        Anisotropic needs both: the harmonic explains most of the ring-wise variance
        and it still explains a large part once the residual may vary with ``θ_d`` and
        ``φ_d`` (an isotropic BRDF's own departure from the microfacet model).
        """
        return (not self.decided or self.anisotropy < ANISOTROPY_EXPLAINED
                or self.conditional < CONDITIONAL_EXPLAINED)

    def to_dict(self) -> dict[str, float | int | bool]:
        """The test as JSON-ready data.

        Returns
        -------
        dict
            ``anisotropy``, ``asymmetry``, ``amplitude``, ``rings``, ``conditional`` and the
            verdict ``isotropic``.
        """
        return {"anisotropy": self.anisotropy, "asymmetry": self.asymmetry, "amplitude": self.amplitude,
                "rings": self.rings, "conditional": self.conditional, "isotropic": self.isotropic}


def azimuthal_test(slices: Slices, valid: NDArray[np.bool_], model) -> IsotropyTest:
    """:class:`IsotropyTest` of the slices (sample frame) against an isotropic ``model``.

    Every :data:`PIXEL_STRIDE`-th pixel enters (the rings hold thousands of samples).
    """
    r, phi, theta_d, phi_d, ring = _log_ratios(slices, valid, model)
    n_rings = int(math.ceil((RING_END_DEG - RING_START_DEG) / RING_WIDTH_DEG))
    if len(r) < MIN_RING_SAMPLES:
        return IsotropyTest(0.0, 0.0, 0.0, 0, 0.0)
    z = _standardized_per_ring(theta_d, ring, n_rings)
    harmonic2 = [np.cos(2 * phi), np.sin(2 * phi)]
    harmonic1 = [np.cos(phi), np.sin(phi)]
    ones = [np.ones(len(r))]
    isotropic_misfit = ones + [z, z * z - 1.0, np.cos(2 * phi_d), np.sin(2 * phi_d)]
    plain = _RingRegression(r, ring, n_rings, ones + harmonic2 + harmonic1)
    conditional = _RingRegression(r, ring, n_rings, isotropic_misfit + harmonic2)
    use = plain.usable(3, MAX_CONDITION)
    if not np.any(use):
        return IsotropyTest(0.0, 0.0, 0.0, 0, 0.0)
    v_total = plain.residual(use, 1)
    v_even = plain.residual(use, 3)
    v_all = plain.residual(use, 5)
    if v_total <= 0:
        return IsotropyTest(0.0, 0.0, 0.0, int(use.sum()), 0.0)
    use_c = conditional.usable(7, MAX_CONDITION_CONDITIONAL)
    v_null = conditional.residual(use_c, 5) if np.any(use_c) else 0.0
    beyond = 1.0 - conditional.residual(use_c, 7) / v_null if v_null > 0 else 0.0
    return IsotropyTest(1.0 - v_even / v_total, 1.0 - v_all / max(v_even, 1e-300), plain.amplitude(use),
                        int(use.sum()), beyond)


def _standardized_per_ring(x: Array, ring: NDArray[np.intp], n_rings: int) -> Array:
    """``(x − mean) / std`` within each ring (keeps the rings' regressions conditioned)."""
    n = np.maximum(np.bincount(ring, minlength=n_rings), 1)
    mean = np.bincount(ring, x, n_rings) / n
    var = np.bincount(ring, x * x, n_rings) / n - mean ** 2
    return (x - mean[ring]) / np.sqrt(np.maximum(var, 1e-12))[ring]


class _RingRegression:
    """Per-ring least squares of ``r`` on nested column sets (the first k columns)."""

    def __init__(self, r: Array, ring: NDArray[np.intp], n_rings: int, columns: list[Array]):
        x = np.stack(columns, axis=1)
        m = x.shape[1]
        # per ring: XᵀX, Xᵀr and rᵀr, accumulated in one pass; XᵀX is symmetric (x_a x_b = x_b x_a
        # exactly), so the upper triangle is accumulated and mirrored
        self.xtx = np.empty((n_rings, m, m))
        for a in range(m):
            for b in range(a, m):
                self.xtx[:, a, b] = np.bincount(ring, x[:, a] * x[:, b], n_rings)
                self.xtx[:, b, a] = self.xtx[:, a, b]
        self.xtr = np.stack([np.bincount(ring, x[:, a] * r, n_rings) for a in range(m)], axis=1)
        self.rtr = np.bincount(ring, r * r, n_rings)
        self.n = self.xtx[:, 0, 0]

    def usable(self, k: int, max_condition: float) -> NDArray[np.bool_]:
        """Rings with enough samples whose first ``k`` columns are conditioned (XᵀX below ``max_condition``)."""
        use = self.n >= MIN_RING_SAMPLES
        block = np.where(use[:, None, None], self.xtx[:, :k, :k], np.eye(k))
        return use & (np.linalg.cond(block) <= max_condition)

    def coefficients(self, use: NDArray[np.bool_], k: int) -> NDArray[np.floating]:
        xtx, xtr = self.xtx[use, :k, :k], self.xtr[use, :k]
        return np.linalg.solve(xtx + 1e-12 * np.eye(k), xtr[..., None])[..., 0]

    def residual(self, use: NDArray[np.bool_], k: int) -> float:
        """Σ over the rings of the residual sum of squares on the first ``k`` columns."""
        c = self.coefficients(use, k)
        return float(np.sum(self.rtr[use] - np.einsum("ka,ka->k", c, self.xtr[use, :k])))

    def amplitude(self, use: NDArray[np.bool_]) -> float:
        """Sample-weighted mean amplitude of columns 1 and 2 (the second harmonic)."""
        c = self.coefficients(use, 3)
        return float(np.average(np.hypot(c[:, 1], c[:, 2]), weights=self.n[use]))


PIXEL_STRIDE = ISOTROPY.pixel_stride


def _log_ratios(slices: Slices, valid: NDArray[np.bool_],
                model) -> tuple[Array, Array, Array, Array, NDArray[np.intp]]:
    """Log ratio of each usable sample's specular part to the model's; its ``φ_h``, ``θ_d``, ``φ_d`` and ring."""
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
    _, phi, theta_d, phi_d = io_to_hd(i[use], o[use])
    ring = ((theta[use] - RING_START_DEG) // RING_WIDTH_DEG).astype(np.intp)
    return r, phi, theta_d, phi_d, ring
