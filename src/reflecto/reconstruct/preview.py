"""A first model of one capture in a few tens of milliseconds: what ``reflecto watch`` shows
while the operator is still at the sample, before the full reconstruction replaces it.

The full reconstruction (:func:`.pipeline.reconstruct`) costs ≈ 250 ms of one core on a
tilted capture, twice the device's 117 ms per capture, most of it the altered normal's
estimate (§5.4) and the checks around it. The preview keeps the parts that need no
model and no estimated frame, and one light fit:

* **the normal**: where the slices' compact specular peaks agree
  (:func:`.motion.peak_agreement`), their mean direction: a sharp lobe's slices that
  hold the mirror direction peak at the lobe's mode, the sample normal, with no model
  (on the hand-held study's 400 steady captures every compact peak lies within 0.30° of
  the true normal); otherwise (or beyond ``max_tilt_deg``) the device axis, with
  ``normal_source`` :data:`UNPLACED` and no uncertainty: the tilt is not known until the
  full reconstruction;
* **the fit**: the normal estimate's light isotropic fit (:func:`.normal.light_fit`:
  every second pixel, θ_d cells of 3°) in that frame, its ``D``, ``S`` and ``η``, with
  ``k_d`` and ``k_s`` per channel by :func:`.isotropic.channel_scalars` under the
  median ceiling of ``k_d``; no Fresnel tint, no lobe per θ_d node, the separable
  shadowing; the energy limit (albedo ≤ 1) as in the full path;
* **the motion cues that need no frame**: the check frames (:mod:`.repeat`, the LED
  fired twice) and the peaks' agreement: a shaken capture is flagged at once. The
  cues that read the sample frame (mirror planes, isotropy and reciprocity pairs)
  wait for the full reconstruction, whose estimated frame keeps a tilt from reading as
  a turn;
* no isotropy or eq. 3 test: both are reported undecided (the model is isotropic; a
  material declared anisotropic, ``isotropic="no"``, gets no preview).

:attr:`.pipeline.Reconstruction.notes` starts with :data:`PREVIEW_NOTE`; the parameters
at a bound are noted as in the full path (:func:`.pipeline.bound_notes`).
"""

from __future__ import annotations

import math
import time

import numpy as np

from .. import geometry
from ..errors import ParameterError
from ..instrument.slices import Slices, check_slices
from ..model import IsotropicMicrofacetBRDF
from .isotropic import channel_scalars
from .isotropy import IsotropyTest
from .motion import MotionReport, PeakAgreement, agreeing_normals, peak_agreement
from .normal import SlicePeak, half_vector_pitch_deg, light_fit, slice_peaks
from .pipeline import FitSeconds, Options, Reconstruction, bound_notes, checked_options, limit_energy, usable_samples
from .repeat import repeat_checks
from .samples import kd_median_bound

__all__ = ["NO_PEAK_NOTE", "PREVIEW_NOTE", "UNPLACED", "preview"]

#: The first note of every preview's summary.
PREVIEW_NOTE = ("preview: a light fit with the normal from the specular peaks or the device axis; "
                "the full reconstruction replaces it")
#: ``normal_source`` of a preview whose normal no compact peak places: read in the device
#: frame, the tilt not known.
UNPLACED = "unplaced"
#: The note of a preview whose normal no compact peak places (read in the device frame).
NO_PEAK_NOTE = "preview: the tilt is left to the full reconstruction (no compact specular peak places the normal)"
def peaks_normal(peaks: list[SlicePeak], agreement: PeakAgreement) -> tuple[np.ndarray | None, float]:
    """The normal the compact peaks place: the normalized sum of the agreeing compact peaks'
    half vectors.

    Parameters
    ----------
    peaks
        The slices' peaks (:func:`.normal.slice_peaks`), device frame.
    agreement
        Their agreement (:func:`.motion.peak_agreement`): which peaks are compact.

    Returns
    -------
    normal : numpy.ndarray of shape (3,) or None
        Unit vector, device frame; ``None`` where no compact peak was found or the compact
        peaks disagree (a turn between the LEDs' firings).
    spread_deg : float
        The largest angle of one compact peak from it (degrees; NaN without a normal).
    """
    compact = agreeing_normals(peaks, agreement)
    if not compact:
        return None, math.nan
    normals = np.array(compact)
    n = normals.sum(axis=0)
    n = n / np.linalg.norm(n)
    spread = max(math.degrees(math.acos(min(1.0, float(m @ n)))) for m in normals)
    return n, spread


def preview(slices: Slices, options: Options | None = None) -> Reconstruction:
    """A first model of one capture's slices (module docstring).

    Parameters
    ----------
    slices
        The capture's BRDF slices, device frame (:func:`reflecto.workflow.measure`).
    options
        The reconstruction's settings that the preview follows: ``normal`` (``"device"``
        or a known vector replaces the peaks' normal), ``max_tilt_deg``, ``fixed_eta``,
        ``kd_bound_max_deg``, ``energy_clamp`` and ``detect_shake``; the others are the full
        reconstruction's.

    Returns
    -------
    Reconstruction
        An isotropic model (:class:`reflecto.model.IsotropicMicrofacetBRDF`, sr⁻¹), its η,
        the frame (the compact peaks' normal, ``normal_source`` ``"estimated"`` with the
        uncertainty ``max(pitch, spread)``; the device axis, :data:`UNPLACED` with a NaN
        uncertainty; or as the options impose, ``"device"`` or ``"given"``), the
        frame-free motion cues, the light fit's model error ``ε``, the energy limit, and
        notes (:data:`PREVIEW_NOTE` first). The isotropy test is undecided (no rings).

    Raises
    ------
    reflecto.errors.ParameterError
        With ``isotropic="no"``: the preview is an isotropic fit.
    reflecto.errors.ReflectoError
        For slices with too few usable samples to fit.
    """
    opt = checked_options(options)
    if opt.isotropic == "no":
        raise ParameterError("preview: the preview is an isotropic fit, not for a material declared anisotropic "
                             "(isotropic='no')")
    t0, c0 = time.perf_counter(), time.process_time()
    check_slices(slices)
    valid = usable_samples(slices)
    peaks = slice_peaks(slices, valid)
    agreement = peak_agreement(peaks)
    notes = [PREVIEW_NOTE]
    if not isinstance(opt.normal, str):
        normal, source, sd = np.asarray(opt.normal, dtype=np.float64), "given", 0.0
    elif opt.normal == "device":
        normal, source, sd = np.array([0.0, 0.0, 1.0]), "device", 0.0
    else:
        found, spread = peaks_normal(peaks, agreement)
        if found is None or geometry.tilt_deg(found) > opt.max_tilt_deg:
            normal, source, sd = np.array([0.0, 0.0, 1.0]), UNPLACED, math.nan
            notes.append(NO_PEAK_NOTE)
        else:
            normal, source, sd = found, "estimated", max(half_vector_pitch_deg(slices), spread)
    frame = geometry.frame_from_normal(normal, np.array([1.0, 0.0, 0.0]))
    c1 = time.process_time()
    lum = light_fit(slices, valid, frame, opt.fixed_eta)
    sl = slices.reframe(frame)
    ok = valid & sl.valid
    ceiling = kd_median_bound(sl.light, sl.view, sl.values, ok, opt.kd_bound_max_deg)
    kd, ks = channel_scalars(lum, ceiling)
    fitted = IsotropicMicrofacetBRDF((lum.problem.nodes, np.exp(lum.state.z - lum.state.z.max())), kd, ks,
                                     lum.state.eta)
    model, scale, albedo = limit_energy(fitted, opt.energy_clamp)
    notes += bound_notes(bool(np.any(ks >= 1.0)), float(lum.state.eta), model, scale, ceiling)
    c2 = time.process_time()
    motion = MotionReport()
    if opt.detect_shake:
        motion.repeat_checks = repeat_checks(slices)
        motion.peaks = agreement
    c3 = time.process_time()
    cpu = FitSeconds(normal=c1 - c0, fit=c2 - c1, motion=c3 - c2)
    undecided = IsotropyTest(0.0, 0.0, 0.0, 0, 0.0)
    return Reconstruction(model, float(lum.state.eta), undecided, motion, frame, float(lum.eps), math.nan, scale,
                          albedo, notes, time.perf_counter() - t0, sd, source, None, None, cpu, preview=True)
