"""The shadowing form beyond the observed ``θ_d``: the one the capture's data fit better.

The device sees the specular lobe up to the largest ``θ_d`` of its slices (≈ 67° on the
paper's layout: its view cone ends at ``θ_o`` = 68°); eq. 10 judges the model up to
``θ_d`` = 80° (``θ_i, θ_o ≤ 80°``). Beyond what is observed the model is an
extrapolation, and on matte materials most of eq. 10's error lies there
(docs/validation.md). Two shadowing forms follow from the same fitted NDF and its ``S``
(eq. 8) and differ exactly there, where both directions are far from the normal
(:func:`.isotropic.pair_shadowing`):

- the paper's separable product ``S(θ_i) S(θ_o)``;
- the height-correlated Smith form ``S_i S_o / (S_i + S_o − S_i S_o)`` (Heitz 2014): a
  microfacet that lies low hides from both directions at once, which the product counts
  twice. It is never below the product; the two agree where either ``S`` is 1.

Neither is right for every material, so the capture chooses (:func:`choose_shadowing`):

1. **Where the data can tell the forms apart.** With the product's fit, the correlated
   form changes a bin's model value by ``s_b (1/(1 − q_b) − 1) / m_b`` (``s_b`` its
   specular part, ``m_b`` its value, ``q_b = (1 − S_i)(1 − S_o)``). Where no measured
   bin changes by :data:`MIN_DIFFERENCE` (sharp lobes, ``S`` ≈ 1 wherever the device
   looks; or a layout without grazing light, as the earlier device's), the data cannot
   choose and the product is kept without another fit.
2. **Both forms fitted to every bin.** The luminance fit (:func:`.isotropic.fit_luminance`)
   is continued from the product's optimum and its active set (on ``k_s = 1`` where the
   product's fit ended there) with the correlated form; the two fits have
   the same parameters (the NDF's nodes, ``k_d``, ``g``, η) and the same priors, so their
   final costs (eq. 10's weighted squares plus the NDF's curvature prior) compare
   directly, as likelihoods of models of equal size do. The grazing slices (θ_i ≈ 83°,
   views to θ_o = 68°) are where the two forms differ within the data.
3. **The correlated form must fit clearly better, on the same branch**: its cost below
   ``1 −`` :data:`MIN_COST_GAIN` of the product's, and its lobe's half width within a
   factor :data:`MAX_WIDTH_CHANGE` of the product's (the forms differ only where both
   directions are far from the normal; a continuation that moves the lobe's core has
   found another branch of the fit, and the costs then compare two lobes, not two
   forms); otherwise the paper's product stays.

Choosing on a held-out band instead (both forms fitted below ``θ_d = θ_obs − 13°``, the
band's weighted misfit compared) picks the wrong form for two of four separable GGX
lobes whose form is known (the correlated form's band misfit 0.23× and 0.41× the true
form's): fitted below the band, η and ``k_s`` extrapolate as much as ``S`` does, and the
band measures them. The full fits' costs pick the true form for those lobes
(docs/design/reconstruction.md).

The cost is one more luminance fit, on broad lobes only (docs/design/speed.md).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from ..fresnel import CONSTANT, is_constant
from ..polar import IsotropicNDF, lobe_half_width_deg
from .isotropic import IsotropicFit, LuminanceFit, fit_luminance, isotropic_fit
from .tuning import EXTRAPOLATION

__all__ = ["ShadowingChoice", "choose_shadowing", "form_difference", "SEPARABLE", "CORRELATED",
           "MIN_DIFFERENCE", "MIN_COST_GAIN", "MAX_WIDTH_CHANGE"]

# Tuned numbers: what, units and provenance are in :mod:`.tuning` (extrapolation stage).
MIN_DIFFERENCE = EXTRAPOLATION.min_difference
MIN_COST_GAIN = EXTRAPOLATION.min_cost_gain
MAX_WIDTH_CHANGE = EXTRAPOLATION.max_width_change

#: The shadowing forms' names, as the summary and the model file's description give them.
SEPARABLE = "separable"
CORRELATED = "height-correlated"


@dataclasses.dataclass(frozen=True)
class ShadowingChoice:
    """Which shadowing form the model uses, and why.

    Attributes
    ----------
    form
        :data:`SEPARABLE` (eq. 8's product) or :data:`CORRELATED`.
    reason
        ``"option"`` (imposed by the options), ``"indistinct"`` (the forms differ by less
        than :data:`MIN_DIFFERENCE` on every measured bin), ``"branch"`` (the correlated
        form's fit moved the lobe's core by more than :data:`MAX_WIDTH_CHANGE`: another
        branch, not compared) or ``"fit"`` (compared by cost).
    difference
        The largest relative change of a measured bin's model value from the product to
        the correlated form (:func:`form_difference`); NaN where not computed.
    scores
        The final costs of the luminance fits with the separable and the correlated form
        (eq. 10's weighted squares and the NDF's prior), or ``None``.
    """

    form: str
    reason: str
    difference: float = math.nan
    scores: tuple[float, float] | None = None

    @property
    def correlated(self) -> bool:
        """Whether the form is the height-correlated one."""
        return self.form == CORRELATED

    @property
    def cost_ratio(self) -> float:
        """The correlated form's cost over the separable form's (NaN without scores)."""
        if self.scores is None or not self.scores[0] > 0:
            return math.nan
        return self.scores[1] / self.scores[0]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: ``form``, ``reason``, ``difference``, ``cost_ratio`` (correlated over
        separable; ``None`` where not computed)."""
        nan = (lambda x: x if math.isfinite(x) else None)
        return {"form": self.form, "reason": self.reason, "difference": nan(self.difference),
                "cost_ratio": nan(self.cost_ratio)}

    def note(self) -> str | None:
        """A plain sentence for the summary where the data chose the correlated form."""
        if not (self.correlated and self.reason == "fit"):
            return None
        return (f"shadowing: height-correlated Smith instead of eq. 8's product (it fits the capture at "
                f"{self.cost_ratio:.3f}× the product's cost; the two differ by up to {100 * self.difference:.0f} % "
                "on the measured bins)")


def form_difference(fit: LuminanceFit) -> float:
    """The largest relative change ``s_b (1/(1 − q_b) − 1) / m_b`` of a measured bin's
    model value when the product ``S_i S_o`` of ``fit`` (its state, separable) is replaced
    by the correlated form, ``q_b = (1 − S_i)(1 − S_o)`` (module docstring, step 1)."""
    p, state = fit.problem, fit.state
    ndf = IsotropicNDF(p.nodes, np.exp(state.z - state.z.max()))
    si, so = ndf.shadowing(p.bins.cos_i), ndf.shadowing(p.bins.cos_o)
    spec, _ = p.specular(state)
    value = state.kd / math.pi + spec
    seen = p.measured & (value > 0) & (si > 0) & (so > 0)
    if not seen.any():
        return 0.0
    si, so = si[seen], so[seen]
    # correlated / product = 1/(S_i + S_o − S_i S_o) = 1/(1 − q)
    change = spec[seen] * (1.0 / (si + so - si * so) - 1.0) / value[seen]
    return float(change.max())


def choose_shadowing(fit: IsotropicFit, fixed_eta: float | None = None, option: str = "auto"
                     ) -> tuple[IsotropicFit, ShadowingChoice]:
    """The isotropic fit with the shadowing form the data choose (module docstring).

    Parameters
    ----------
    fit
        The converged isotropic fit with eq. 8's product (:func:`.isotropic.fit_isotropic`).
    fixed_eta
        η held in the correlated form's fit (as in ``fit``), or ``None``.
    option
        ``"auto"`` (choose), ``"separable"`` (keep ``fit``) or ``"correlated"`` (refit with
        the correlated form without a choice).

    Returns
    -------
    (IsotropicFit, ShadowingChoice)
        ``fit`` itself where the product is kept, else the correlated form's fit on its bins.
    """
    if option == "separable":
        return fit, ShadowingChoice(SEPARABLE, "option")
    if option == "correlated":
        return isotropic_fit(_correlated_fit(fit.luminance, fixed_eta), fit.ceiling), ShadowingChoice(CORRELATED,
                                                                                                      "option")
    lum = fit.luminance
    difference = form_difference(lum)
    if not difference >= MIN_DIFFERENCE:
        return fit, ShadowingChoice(SEPARABLE, "indistinct", difference)
    alt = _correlated_fit(lum, fixed_eta)
    scores = (lum.cost, alt.cost)
    if not _same_branch(lum, alt):
        return fit, ShadowingChoice(SEPARABLE, "branch", difference, scores)
    if not scores[1] < (1.0 - MIN_COST_GAIN) * scores[0]:
        return fit, ShadowingChoice(SEPARABLE, "fit", difference, scores)
    return isotropic_fit(alt, fit.ceiling), ShadowingChoice(CORRELATED, "fit", difference, scores)


def _same_branch(lum: LuminanceFit, alt: LuminanceFit) -> bool:
    """Whether the correlated form's fit ``alt`` stayed on the product's branch ``lum``: its
    lobe's half width at half maximum within :data:`MAX_WIDTH_CHANGE` of ``lum``'s (module
    docstring, step 3)."""
    w0 = lobe_half_width_deg(lum.problem.nodes, np.exp(lum.state.z))
    w1 = lobe_half_width_deg(alt.problem.nodes, np.exp(alt.state.z))
    return w1 <= MAX_WIDTH_CHANGE * w0 and w0 <= MAX_WIDTH_CHANGE * w1


def _correlated_fit(lum: LuminanceFit, fixed_eta: float | None) -> LuminanceFit:
    """``lum`` continued on the same bins with the correlated form, from its converged state
    and its active set (on the bound ``k_s = 1`` where ``lum`` ended on it; η held where
    ``lum`` holds it, or took the constant Fresnel lobe)."""
    hold = fixed_eta if fixed_eta is not None else (CONSTANT if is_constant(lum.state.eta) else None)
    return fit_luminance(lum.problem.bins, lum.problem.nodes, hold, correlated=True, start=lum.state,
                         tied=lum.ks_bound)
