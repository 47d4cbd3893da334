"""The reconstruction of paper §5, as named stages: slices → generalized microfacet BRDF.

::

    usable_samples        finite, unsaturated samples                       (§4.3)
    resolve_normal        the altered normal (§5.4), by default              normal.py
    fit_isotropic         a 1-D NDF D(θ_h), η, k_d, k_s (§5.1–5.3)          isotropic.py
    azimuthal_test        isotropic? symmetric under eq. 3?                  isotropy.py
    choose_shadowing      S's form beyond the observed θ_d (isotropic)       extrapolation.py
    fit_hemicube          a hemicube NDF, for an anisotropic material        hemicube_fit.py
    detect_motion         check frames, mirror planes, LED pairs (§5.1)      motion.py
    limit_energy          albedo ≤ 1 up to 89°

:func:`reconstruct` runs them and returns a :class:`Reconstruction`. With
``Options(isotropic="auto")`` (the default) the capture decides: the isotropic fit
always runs (it is cheap and it is the reference of the test); when the slices carry
a significant second azimuthal harmonic the hemicube path reconstructs the
anisotropic NDF instead. ``"yes"``/``"no"`` impose the choice.

Physical bounds hold for every output: one ``η`` for R, G, B in ``(1, 50)``,
``0 ≤ k_s ≤ 1`` and ``k_d ≥ 0`` per channel, albedo ≤ 1 at every incidence up to
89°; where a bound binds, :attr:`Reconstruction.notes` says so.
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .. import geometry
from ..brdf import albedo_angles
from ..colour import LUM
from ..errors import ParameterError, ReflectoError
from ..fresnel import FresnelTint, eta_to_json, is_constant
from ..instrument.slices import Slices, check_slices, finite_rgb
from ..model import IsotropicMicrofacetBRDF, MicrofacetBRDF
from .extrapolation import ShadowingChoice, choose_shadowing
from .hemicube_fit import HemicubeFit, fit_hemicube
from .isotropic import (
    ETA_MAX,
    ETA_MIN,
    OUTER_ITERATIONS,
    IsotropicFit,
    finish_isotropic,
    fit_isotropic,
    start_isotropic,
)
from .isotropy import IsotropyTest, azimuthal_test
from .motion import PEAK_AGREEMENT_DEG, MotionReport, agreeing_normals, detect_motion, peak_agreement
from .normal import (
    ConsistencyDistance,
    HiddenPeak,
    IsotropicDistance,
    NormalDistance,
    NormalEstimate,
    SlicePeak,
    estimate_normal,
    estimate_normal_consistency,
    peaks_out_of_reach,
    refine_normal,
    slice_peaks,
)
from .symmetry import PLANE_FLOOR_DEG
from .tuning import PIPELINE

Array = NDArray[np.float64]

__all__ = ["Options", "Reconstruction", "FitSeconds", "reconstruct", "usable_samples", "estimate_frame",
           "limit_energy", "limit_energy_of_the_trend", "checked_options"]

#: Incidence angles (degrees) at which the albedo is checked against 1.
ALBEDO_ANGLES = PIPELINE.albedo_angles
#: Rings and azimuths of the half-vector quadrature of that check: 48 × 48 is within
#: 1e-3 of a 400 × 512 quadrature on GGX and Beckmann lobes of α = 0.05–0.8.
ALBEDO_QUAD = PIPELINE.albedo_quad
#: Where that check reads above this, it is repeated on a 128 × 128 quadrature and the
#: larger value counts: on a tabulated NDF with structure toward grazing the 48 × 48
#: quadrature misses up to 2e-3 at 89° (aurora_white: 1.0000 against 1.0015–1.0022 at
#: 96–256 rings).
ALBEDO_REFINE_ABOVE = PIPELINE.albedo_refine_above
ALBEDO_QUAD_FINE = PIPELINE.albedo_quad_fine
#: An anisotropic model's albedo is checked at this many incidence azimuths, then refined about the largest.
ALBEDO_AZIMUTHS = PIPELINE.albedo_azimuths
#: Fewer valid samples than this make no capture.
MIN_SAMPLES = PIPELINE.min_samples


@dataclasses.dataclass
class Options:
    """Reconstruction settings.

    Attributes
    ----------
    isotropic
        ``"auto"`` (decide from the capture, :mod:`.isotropy`), ``"yes"`` (a 1-D NDF
        whatever the data) or ``"no"`` (a hemicube NDF; the shake cues that assume
        isotropy are skipped).
    normal
        The sample normal (§5.4): ``"auto"`` (estimate it, :func:`.normal.estimate_normal`,
        and keep the device axis where the estimate does not differ from it by more than
        :data:`DEVICE_AXIS_SIGMAS` of its uncertainty), ``"device"`` (the device axis
        ``(0, 0, 1)``), ``"search"`` (for a §5.5 set: the set's own normal search,
        :func:`.asymmetric.reconstruct_rotations`; one capture: as ``"auto"``) or a unit
        3-vector (a known normal) in the coordinates of the slices reconstructed: the
        device's for a capture's slices (:func:`reflecto.workflow.capture_to_model` turns it
        with a capture whose manifest turns the sample). A §5.5 set takes the device axis
        under ``"auto"`` unless its captures disagree there (a tilted set), then its search
        (seconds per set).
    estimate_normal
        An alias of ``normal``: ``True`` is ``normal="auto"``,
        ``False`` ``normal="device"``; ``None`` (default) leaves ``normal`` as given.
    max_tilt_deg
        Largest tilt searched by the normal estimate (degrees).
    fixed_eta
        Use this η instead of fitting it.
    detect_shake
        Run the shake cues (:mod:`.motion`).
    energy_clamp
        Scale k_d, k_s down where the directional albedo exceeds 1.
    resolution, work_resolution
        Output and working hemicube resolutions of the anisotropic path (``None``:
        chosen from the peak's sharpness).
    kd_bound_max_deg
        The anisotropic path bounds k_d by the samples with θ_i, θ_o at most this.
    shadowing
        The isotropic model's shadowing form beyond the observed ``θ_d``: ``"auto"``
        (the one the capture fits better, :func:`.extrapolation.choose_shadowing`), ``"separable"``
        (eq. 8's product) or ``"correlated"`` (height-correlated Smith).
    """

    isotropic: str = "auto"
    normal: Any = "auto"
    estimate_normal: bool | None = None
    max_tilt_deg: float = 16.0
    fixed_eta: float | None = None
    detect_shake: bool = True
    energy_clamp: bool = True
    resolution: int = 512
    work_resolution: int | None = None
    kd_bound_max_deg: float = 75.0
    shadowing: str = "auto"

    def __eq__(self, other: object) -> bool:
        """Field by field, a given normal (an array) by its values: a generated comparison fails
        on the array's ambiguous truth value."""
        if not isinstance(other, Options):
            return NotImplemented
        for f in dataclasses.fields(self):
            a, b = getattr(self, f.name), getattr(other, f.name)
            if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
                if not (isinstance(a, np.ndarray) and isinstance(b, np.ndarray) and np.array_equal(a, b)):
                    return False
            elif a != b:
                return False
        return True

    __hash__ = None  # type: ignore[assignment]  # mutable, as the generated class is

    def __post_init__(self) -> None:
        def bad(what: str) -> ParameterError:
            return ParameterError(f"reconstruction options: {what}")

        if self.isotropic not in ("auto", "yes", "no"):
            raise bad(f"isotropic must be 'auto', 'yes' or 'no', got {self.isotropic!r}")
        if self.shadowing not in ("auto", "separable", "correlated"):
            raise bad(f"shadowing must be 'auto', 'separable' or 'correlated', got {self.shadowing!r}")
        if self.estimate_normal is not None:
            if not isinstance(self.estimate_normal, (bool, np.bool_)):
                raise bad(f"estimate_normal must be True, False or None, got {self.estimate_normal!r}")
            self.normal = "auto" if self.estimate_normal else "device"
            self.estimate_normal = None
        if isinstance(self.normal, str):
            if self.normal not in ("auto", "device", "search"):
                raise bad(f"normal must be 'auto', 'device', 'search' or a unit 3-vector, got {self.normal!r}")
        else:
            try:
                n = np.asarray(self.normal, dtype=np.float64)
            except (TypeError, ValueError):
                raise bad(f"normal must be 'auto', 'device' or a unit 3-vector, got {self.normal!r}") from None
            norm = float(np.linalg.norm(n)) if n.shape == (3,) else math.nan
            if not (n.shape == (3,) and np.all(np.isfinite(n)) and norm > 0 and abs(norm - 1.0) < 1e-3):
                raise bad(f"a given normal must be a finite unit 3-vector, got {self.normal!r}")
            if n[2] / norm < math.cos(math.radians(60.0)):
                raise bad(f"a given normal must lie within 60° of the device axis, got {self.normal!r}")
            self.normal = n / norm
        for name, cells in (("resolution", self.resolution), ("work_resolution", self.work_resolution)):
            if cells is not None and not (isinstance(cells, (int, np.integer)) and not isinstance(cells, bool)
                                          and 8 <= cells <= MAX_RESOLUTION):
                raise bad(f"{name} must be an integer in [8, {MAX_RESOLUTION}] (hemicube cells per face side), "
                          f"got {cells!r}")
        real = (lambda x: isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, bool))
        if self.fixed_eta is not None and not real(self.fixed_eta):
            raise bad(f"a fixed η must be a real number, got {self.fixed_eta!r}")
        if self.fixed_eta is not None and not (math.isfinite(self.fixed_eta) and ETA_MIN <= self.fixed_eta <= ETA_MAX):
            raise bad(f"a fixed η must be a finite relative index in [{ETA_MIN:g}, {ETA_MAX:g}] (the fit's range), "
                      f"got {self.fixed_eta}")
        for name in ("max_tilt_deg", "kd_bound_max_deg"):
            if not real(getattr(self, name)):
                raise bad(f"{name} must be a number of degrees, got {getattr(self, name)!r}")
        if not (math.isfinite(self.max_tilt_deg) and 0.0 < self.max_tilt_deg < 60.0):
            raise bad(f"max_tilt_deg must lie in (0°, 60°), got {self.max_tilt_deg}")
        if not (math.isfinite(self.kd_bound_max_deg) and 0.0 < self.kd_bound_max_deg <= 90.0):
            raise bad(f"kd_bound_max_deg must lie in (0°, 90°], got {self.kd_bound_max_deg}")
        for name in ("detect_shake", "energy_clamp"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise bad(f"{name} must be True or False, got {getattr(self, name)!r}")


def checked_options(options: Options | None) -> Options:
    """The options a stage runs with: the defaults for ``None``, else a copy of ``options``
    checked again (an :class:`Options` is checked when made; a field set afterwards is
    checked here, before the stage reads it).

    Parameters
    ----------
    options
        The caller's options, or ``None``.

    Returns
    -------
    Options
        A checked copy (the defaults for ``None``).

    Raises
    ------
    ParameterError
        ``options`` is no :class:`Options`, or one of its fields is invalid.
    """
    if options is None:
        return Options()
    if not isinstance(options, Options):
        raise ParameterError(f"reconstruction options must be an Options, got {type(options).__name__}")
    return dataclasses.replace(options)


#: A tilt estimated within this of ``Options.max_tilt_deg`` (degrees) is said to be held by the bound.
MAX_TILT_MARGIN_DEG = 0.01
#: The largest hemicube resolution the options take (the paper's is 512; 2048² cells per face
#: are 100 MB of NDF).
MAX_RESOLUTION = 2048


@dataclasses.dataclass
class FitSeconds:
    """CPU seconds of :func:`reconstruct`'s parts (the process's time, all threads), in order.

    Attributes
    ----------
    normal
        The sample normal (§5.4): the estimate, its refits and uncertainty, after the
        slices' checks and the usable samples.
    fit
        The isotropic fit in the frame kept (eqs. 5–8), the device frame's check of an
        estimated tilt, and the hemicube fit of an anisotropic material (with the
        device frame's fit and isotropy test where an estimated frame's lobe turns out
        anisotropic).
    isotropy
        The azimuthal (isotropy) test.
    form
        The shadowing form's choice (:func:`.extrapolation.choose_shadowing`).
    model
        The model itself: ``k_d``'s ceiling, the Fresnel tint and the NDF per θ_d node, and
        the energy limit.
    motion
        The hidden peaks and the motion cues (§5.1).
    """

    normal: float = 0.0
    fit: float = 0.0
    isotropy: float = 0.0
    form: float = 0.0
    model: float = 0.0
    motion: float = 0.0


@dataclasses.dataclass
class Reconstruction:
    """The result of :func:`reconstruct`.

    Attributes
    ----------
    model
        The BRDF: :class:`~reflecto.model.IsotropicMicrofacetBRDF` or, for an
        anisotropic material, :class:`~reflecto.model.MicrofacetBRDF`.
    eta
        The relative index, one for R, G, B.
    isotropy
        The azimuthal test of the capture against the isotropic fit.
    motion
        The shake cues and their verdict.
    frame
        Rows ``(t, b, n)`` of the sample frame in the coordinates of the slices reconstructed
        (the device's for a capture's slices; :meth:`reflecto.workflow.CaptureModel.summary`
        gives the normal in device coordinates for a capture turned by its rotation).
    model_error
        RMS relative misfit of the isotropic fit beyond the camera noise (``ε``).
    fresnel_error
        E(η) of the anisotropic path's Fresnel fit (§5.1), NaN on the isotropic path.
    energy_scale
        Factor applied to k_d, k_s so that the albedo stays ≤ 1 (1: none needed).
    albedo_max
        Largest directional albedo over :data:`ALBEDO_ANGLES` after that.
    notes
        Plain statements about parameters at a bound and choices the data forced.
    seconds
        Wall time of the reconstruction.
    normal_uncertainty_deg
        Standard uncertainty of the normal (degrees; :class:`.normal.NormalEstimate`;
        0 for a normal imposed by the options).
    normal_source
        ``"estimated"``, ``"device"`` (imposed, or the estimate did not differ from the
        device axis significantly) or ``"given"``.
    normal_estimate
        The estimate behind :attr:`frame`, or ``None`` when the options imposed it.
    shadowing
        The isotropic model's shadowing form and why (:class:`.extrapolation.ShadowingChoice`);
        ``None`` on the anisotropic path (eq. 8's product).
    cpu_seconds
        CPU seconds per part (:class:`FitSeconds`).
    preview
        Whether this is :func:`.preview.preview`'s first model rather than the full reconstruction.
    """

    model: IsotropicMicrofacetBRDF | MicrofacetBRDF
    eta: float
    isotropy: IsotropyTest
    motion: MotionReport
    frame: Array
    model_error: float
    fresnel_error: float
    energy_scale: float
    albedo_max: float
    notes: list[str]
    seconds: float
    normal_uncertainty_deg: float = 0.0
    normal_source: str = "device"
    normal_estimate: NormalEstimate | None = None
    shadowing: ShadowingChoice | None = None
    cpu_seconds: FitSeconds = dataclasses.field(default_factory=FitSeconds)
    preview: bool = False

    @property
    def isotropic(self) -> bool:
        """Whether the model is the isotropic one (1-D NDF ``D(θ_h)``) rather than a hemicube."""
        return isinstance(self.model, IsotropicMicrofacetBRDF)

    @property
    def shake_detected(self) -> bool:
        """Whether the motion checks found a shaken capture (:attr:`MotionReport.shake_detected`)."""
        return self.motion.shake_detected

    @property
    def normal_tilt_deg(self) -> float:
        """Angle between the estimated sample normal and the device axis, ``acos(n_z)`` (degrees)."""
        return geometry.tilt_deg(self.frame[2])

    def summary(self) -> dict[str, Any]:
        """JSON-ready summary (the ``material.json`` written beside a model file).

        Returns
        -------
        dict
            ``isotropic``; ``fresnel`` and ``eta`` (:func:`reflecto.fresnel.eta_to_json`);
            ``kd``, ``ks`` (RGB lists); ``fresnel_tint`` (``theta_d_deg``, the nodes, ``tau``,
            one RGB row per node, ``beyond``, its continuation past the last node, and
            ``trend_from_deg``, :class:`reflecto.fresnel.FresnelTint`; ``None`` without a tint);
            ``normal`` (unit vector, in the slices' coordinates: :attr:`frame`),
            ``normal_tilt_deg``, ``normal_uncertainty_deg`` (degrees), ``normal_source``;
            ``isotropy_test`` (:meth:`IsotropyTest.to_dict`); the motion cues
            (:meth:`MotionReport.to_dict`: ``shake_detected``, …); ``shadowing``
            (:meth:`.extrapolation.ShadowingChoice.to_dict`, ``None`` on the anisotropic path); ``model_error``,
            ``fresnel_error``, ``energy_scale``, ``albedo_max``, ``notes``, ``seconds`` and
            ``preview`` (:attr:`preview`). Non-finite ``normal_uncertainty_deg``, ``model_error``
            and ``fresnel_error`` are ``None``.
        """
        nan = (lambda x: x if math.isfinite(x) else None)
        tint = self.model.tint
        return {"isotropic": self.isotropic, **eta_to_json(self.model.eta), "kd": self.model.kd.tolist(),
                "ks": self.model.ks.tolist(),
                "fresnel_tint": None if tint is None else {"theta_d_deg": np.degrees(tint.theta).tolist(),
                                                           "tau": tint.values.tolist(), "beyond": tint.beyond,
                                                           "trend_from_deg": None if tint.trend_from is None
                                                           else math.degrees(tint.trend_from)},
                "normal": self.frame[2].tolist(), "normal_tilt_deg": self.normal_tilt_deg,
                "normal_uncertainty_deg": nan(self.normal_uncertainty_deg), "normal_source": self.normal_source,
                "isotropy_test": self.isotropy.to_dict(), **self.motion.to_dict(),
                "model_error": nan(self.model_error), "fresnel_error": nan(self.fresnel_error),
                "shadowing": None if self.shadowing is None else self.shadowing.to_dict(),
                "energy_scale": self.energy_scale, "albedo_max": self.albedo_max, "notes": self.notes,
                "seconds": self.seconds, "preview": self.preview}


def usable_samples(slices: Slices) -> NDArray[np.bool_]:
    """Valid samples with finite values in every channel, shape ``(L, P)``; too few is an error.

    Parameters
    ----------
    slices
        The capture's BRDF slices (``valid`` ``(L, P)``, ``values`` ``(L, P, 3)`` in sr⁻¹).

    Returns
    -------
    numpy.ndarray of bool, shape (L, P)
        ``slices.valid``, every channel finite, the LED and the view above the sample plane.

    Raises
    ------
    ReflectoError
        Fewer than :data:`MIN_SAMPLES` samples are usable, or (where the slices carry a noise
        model) fewer than that many read above :data:`SIGNAL_SIGMAS` noise deviations.
    """
    ok = slices.valid & finite_rgb(slices.values)  # a NaN or ±inf channel poisons the sum
    ok &= (slices.light[:, 2] > 0)[:, None] & (slices.view[:, 2] > 0)[None, :]
    if int(ok.sum()) < MIN_SAMPLES:
        raise ReflectoError(f"capture: fewer than {MIN_SAMPLES} valid samples "
                            "(saturated, dark or outside the view cone)")
    if slices.noise is not None:  # a target that reflects nothing still reads the camera's noise
        signal = np.count_nonzero(ok & (slices.values @ LUM > SIGNAL_SIGMAS * slices.noise))
        if signal < MIN_SAMPLES:
            raise ReflectoError(f"capture: no signal above the camera's noise ({signal} samples above "
                                f"{SIGNAL_SIGMAS:g} noise deviations, fewer than {MIN_SAMPLES}): an empty or black "
                                "target, or LEDs that did not light")
    return ok


#: A sample reads signal where its luminance exceeds this many of the noise model's standard
#: deviations (:attr:`.Slices.noise`): noise alone passes it on 3·10⁻⁷ of the samples.
SIGNAL_SIGMAS = 5.0


def estimate_frame(slices: Slices, valid: NDArray[np.bool_], max_tilt_deg: float, isotropic: bool = True) -> Array:
    """The sample frame of §5.4: the normal in which the slices are most consistent.

    For a material that may be isotropic the distance is the misfit of the isotropic
    fit in the candidate frame (:class:`.normal.IsotropicDistance`: every ring of half
    vectors must see one NDF); otherwise HLHZ08's symmetry criterion with the full
    model (:class:`.normal.ConsistencyDistance`: partial NDFs at ``h`` and ``τh``), with
    ``S`` from an isotropic fit in the device frame. Both are searched on a grid of
    tilts, their local minima refined (:func:`.normal.estimate_normal_consistency`).

    Parameters
    ----------
    slices
        The capture's BRDF slices, device frame.
    valid
        Usable samples, shape ``(L, P)`` (:func:`usable_samples`).
    max_tilt_deg
        Largest tilt of the normal from the device axis searched (degrees).
    isotropic
        Whether the material may be isotropic (the isotropic-misfit distance) or not (the
        symmetry criterion, refined once more with ``S`` from the fit in the found frame).

    Returns
    -------
    numpy.ndarray, shape (3, 3)
        Rows ``(t, b, n)`` of the sample frame in device coordinates (``t`` follows device x).
    """
    coarse: NormalDistance
    fine: NormalDistance
    if isotropic:
        coarse, fine = IsotropicDistance(slices, valid, stride=3), IsotropicDistance(slices, valid, stride=1)
        normal, _ = estimate_normal_consistency(coarse, fine, max_tilt_deg)
        return geometry.frame_from_normal(normal, np.array([1.0, 0.0, 0.0]))
    shadow = fit_isotropic(slices, valid).least_squares.shadowing
    coarse = ConsistencyDistance(slices, valid, shadow, n=32, stride=3)
    fine = ConsistencyDistance(slices, valid, shadow, n=64, stride=1)
    normal, _ = estimate_normal_consistency(coarse, fine, max_tilt_deg)
    frame = geometry.frame_from_normal(normal, np.array([1.0, 0.0, 0.0]))
    turned = slices.reframe(frame)
    shadow = fit_isotropic(turned, valid & turned.valid).least_squares.shadowing
    normal, _ = refine_normal(ConsistencyDistance(slices, valid, shadow, n=64, stride=1), normal, 0.5, maxfev=50,
                              probe_deg=1.5)
    return geometry.frame_from_normal(normal, np.array([1.0, 0.0, 0.0]))


#: ``normal="auto"`` keeps the device axis when the estimated tilt is at most this many
#: standard uncertainties (a two-sided 95 % test that the data tell the normal from it).
DEVICE_AXIS_SIGMAS = PIPELINE.device_axis_sigmas


def resolve_normal(slices: Slices, valid: NDArray[np.bool_], opt: Options,
                   peaks: list[SlicePeak] | None = None) -> NormalEstimate:
    """The sample normal the options ask for: estimated (``"auto"``, :func:`.normal.estimate_normal`,
    the device axis where the tilt is within :data:`DEVICE_AXIS_SIGMAS` uncertainties of 0),
    the device axis (``"device"``) or the given vector.

    Parameters
    ----------
    slices
        The capture's BRDF slices, device frame.
    valid
        Usable samples, shape ``(L, P)``.
    opt
        The reconstruction options (``normal``, ``isotropic``, ``max_tilt_deg``, ``fixed_eta``);
        with ``isotropic="no"`` the device axis is kept.
    peaks
        The slices' specular peaks where already found (:func:`.normal.slice_peaks` of
        ``slices`` and ``valid``); ``None``: found here where needed.

    Returns
    -------
    NormalEstimate
        The normal (unit vector, device frame), its standard uncertainty (degrees; 0 when
        imposed) and its ``source`` (``"estimated"``, ``"device"`` or ``"given"``).
    """
    z = np.array([0.0, 0.0, 1.0])
    if isinstance(opt.normal, str) and opt.normal == "device":
        return NormalEstimate(z, 0.0, "device")
    if not isinstance(opt.normal, str):
        return NormalEstimate(np.asarray(opt.normal, dtype=np.float64), 0.0, "given")
    if opt.isotropic == "no":  # the estimate fits an isotropic lobe: not for a declared anisotropic one
        return NormalEstimate(z, 0.0, "device")
    est = estimate_normal(slices, valid, opt.max_tilt_deg, opt.fixed_eta, peaks)
    if not (est.tilt_deg > DEVICE_AXIS_SIGMAS * _decision_uncertainty(est)):
        return dataclasses.replace(est, normal=z, source="device", alternative=est.normal)  # not told apart
    return est


#: A lobe at most this many half-vector pitches wide (half width at half maximum) has its
#: tilt tested against the fit's own uncertainty (:func:`_decision_uncertainty`) …
SHARP_LOBE_PITCHES = PIPELINE.sharp_lobe_pitches
#: … but never less than this many pitches: the bias of a peak placed between pixels.
SUBPIXEL_BIAS = PIPELINE.subpixel_bias
#: A sharp lobe's tilt beyond this many of its own uncertainties is not checked against the device frame.
SHARP_TILT_SIGMAS = PIPELINE.sharp_tilt_sigmas
#: … as has a lobe of any width whose light fit's misfit ``ε`` is at most this.
EXACT_MODEL_MISFIT = PIPELINE.exact_model_misfit


def _sharp(est: NormalEstimate) -> bool:
    """Whether the estimate's lobe is at most :data:`SHARP_LOBE_PITCHES` half-vector pitches wide
    (half width at half maximum): its peak lies in a few pixels."""
    return est.lobe_half_width_deg <= SHARP_LOBE_PITCHES * est.half_vector_pitch_deg


def _decision_uncertainty(est: NormalEstimate) -> float:
    """The uncertainty the device-axis test of :func:`resolve_normal` uses.

    The reported uncertainty has the half vector's sampling (≈ 0.2°) as its floor. On a
    sharp lobe, at most :data:`SHARP_LOBE_PITCHES` pitches wide, the peak covers a few
    pixels whose values place the normal to hundredths of a degree (steel on the ideal
    device tilted 0.03–0.20°: found within 0.015°, ±0.004–0.010°), and there a tenth of
    a degree of frame costs eq. 10 a factor of 2–2.7: the test uses the fit's own
    uncertainty (:attr:`.normal.NormalEstimate.fit_uncertainty_deg`), but at least
    :data:`SUBPIXEL_BIAS` pitches, the bias of a peak placed between pixels (so a tilt
    is told from none from ≈ 0.04° on). A broader lobe's tilt comes from many pixels,
    where the 1-D model's misfit biases it by more than the fit's scatter (untilted
    paints and fabrics: 0.1–0.4°): the pitch's floor stays, unless the light fit misfits the
    capture by no more than its own discretization (``misfit`` ≤ :data:`EXACT_MODEL_MISFIT`):
    there no misfit biases the tilt, and a glossy lobe tilted 0.1–0.4° left on the device
    axis has up to 27× the true normal's eq. 10 error."""
    sd, pitch = est.fit_uncertainty_deg, est.half_vector_pitch_deg
    if math.isfinite(sd) and (_sharp(est) or est.misfit <= EXACT_MODEL_MISFIT):
        # where the symmetry planes moved the normal, the texel grid they are all located on
        # biases them alike (symmetry.PLANE_FLOOR_DEG), which their combination cannot average away
        return max(sd, SUBPIXEL_BIAS * pitch, PLANE_FLOOR_DEG if est.planes else 0.0)
    return est.uncertainty_deg


def _within_sampling(est: NormalEstimate) -> bool:
    """Whether an estimated tilt lies within the half vector's sampling (≤
    :data:`DEVICE_AXIS_SIGMAS` times the reported uncertainty, whose floor is the
    sampling): there both frames put the peak in the same pixels, and the isotropic
    fits' misfit ε does not tell them apart (steel on the ideal device tilted 0.06° and
    0.12°: ε 0.219 and 0.234 in the device frame against 0.254 and 0.250 in the
    estimated one, whose eq. 10 error is 2.2× and 2.5× lower). The tilt's own
    significance (:func:`_decision_uncertainty`) decides there, without the device
    frame's check (:func:`_tilt_explains_nothing`)."""
    return est.tilt_deg <= DEVICE_AXIS_SIGMAS * est.uncertainty_deg


def _device_frame_fit(slices: Slices, valid: NDArray[np.bool_], opt: Options) -> IsotropicFit:
    """The isotropic fit in the device frame."""
    return fit_isotropic(slices, valid & slices.valid, opt.fixed_eta, opt.kd_bound_max_deg)


#: The device frame's check looks at its fit's ``ε`` after this many outer rounds …
DEVICE_CHECK_ROUNDS = PIPELINE.device_check_rounds
#: … and stops it where that ``ε`` is at least this many times the estimated frame's …
DEVICE_CHECK_MARGIN = PIPELINE.device_check_margin
#: … and its η is at most this.
DEVICE_CHECK_ETA = PIPELINE.device_check_eta


def device_frame_check(slices: Slices, valid: NDArray[np.bool_], opt: Options,
                       estimated: IsotropicFit) -> IsotropicFit | None:
    """The device frame's isotropic fit that checks an estimated tilt
    (:func:`_tilt_explains_nothing`), or ``None`` where its first rounds already answer:
    the tilt explains the data better.

    The check compares the fits' final ``ε``; the device frame's fit is the model only
    where the device axis wins (or where the estimated frame's lobe turns out
    anisotropic, and then :func:`reconstruct` fits it again). After
    :data:`DEVICE_CHECK_ROUNDS` outer rounds its ``ε`` lies within 0.99–1.41× of its
    final value on the hand-held study's captures; where it is still at least
    :data:`DEVICE_CHECK_MARGIN` times the estimated frame's, the check stops there, and
    the rest of the fit (its other rounds, ``k_d``'s ceiling) is not run. That is a
    measured margin, not a bound: ``ε`` is not monotone in the rounds. Not where a
    free η after those rounds exceeds :data:`DEVICE_CHECK_ETA`: it may still climb to
    the search bound, where :func:`.isotropic.with_constant_fresnel` can replace the fit
    by one of lower ``ε`` (a held η, ``opt.fixed_eta``, never is). Otherwise the fit
    runs on to the end: the same fit as :func:`_device_frame_fit`, bit for bit.
    """
    ok = valid & slices.valid
    run = start_isotropic(slices, ok, opt.fixed_eta)
    run.rounds(min(DEVICE_CHECK_ROUNDS, OUTER_ITERATIONS))
    settled = opt.fixed_eta is not None or run.state.eta <= DEVICE_CHECK_ETA  # a held η is never replaced
    if settled and run.model_error() >= DEVICE_CHECK_MARGIN * estimated.model_error:
        return None
    return finish_isotropic(run, slices, ok, opt.kd_bound_max_deg)


def _peaks_place_tilt(est: NormalEstimate, peaks: list[SlicePeak]) -> bool:
    """Whether the slices' compact peaks place the estimated tilt without a model: at
    least one, agreeing (:func:`.motion.peak_agreement`), each within
    :data:`.motion.PEAK_AGREEMENT_DEG` of the estimated normal and further than that from
    the device axis. A sharp lobe's slices that hold the mirror direction peak at its
    mode, the sample's normal, whatever its shape (:mod:`.motion`); where they put it
    away from the device axis and at the estimate, the device frame's fit
    (:func:`device_frame_check`) cannot show that the tilt explains nothing."""
    compact = agreeing_normals(peaks, peak_agreement(peaks))
    limit = math.cos(math.radians(PEAK_AGREEMENT_DEG))
    return bool(compact) and all(float(n @ est.normal) >= limit and float(n[2]) < limit for n in compact)


def _sharp_tilt_beyond_doubt(est: NormalEstimate) -> bool:
    """Whether a sharp lobe's tilt lies beyond :data:`SHARP_TILT_SIGMAS` of its own
    uncertainty (:func:`_decision_uncertainty`, the peak's pixels placing it to hundredths of a
    degree): no misfit of the 1-D model puts it there (untilted sharp lobes read 0.010–0.022°),
    and the device frame's ε is no judge of it where the tilt hides a peak the device frame
    sees (hematite tilted 0.7° toward the rim: found 0.001° off, ±0.02°, but the device
    frame's ε was lower, and its model had 2.1× the true normal's eq. 10 error)."""
    return (math.isfinite(est.fit_uncertainty_deg) and _sharp(est)
            and est.tilt_deg > SHARP_TILT_SIGMAS * _decision_uncertainty(est))


def _needs_device_check(opt: Options) -> bool:
    """Whether an estimated tilt is checked against the device frame's fit
    (:func:`_tilt_explains_nothing`): under ``normal="auto"``, isotropy not imposed as "no"."""
    return isinstance(opt.normal, str) and opt.normal == "auto" and opt.isotropic != "no"


def _tilt_explains_nothing(device_fit: IsotropicFit, estimated: IsotropicFit) -> bool:
    """Whether the estimated tilt fails to explain the data better than the device axis.

    The estimate fits an isotropic lobe, so on an anisotropic one it finds a tilt too.
    A tilt that is the sample's explains the data: in its frame the isotropic misfit ε
    falls (GGX α 0.15 tilted 8°: 0.35 → 0.0025, the second harmonic's share 0.85 →
    0.01); a tilt found on an anisotropic lobe does not (α ratios 2–4: ε 0.19–0.22 →
    0.21–0.27), nor one the estimate finds on an untilted lobe it misfits (GGX α 0.4,
    η 2: 0.009 → 0.033). Where the estimated frame fits no better, the device axis holds.
    """
    return estimated.model_error >= device_fit.model_error


def _fit_frame_explains(slices: Slices, valid: NDArray[np.bool_], opt: Options, est: NormalEstimate,
                        device_fit: IsotropicFit) -> bool:
    """Where the symmetry planes moved the fit's normal (:func:`.normal.with_symmetry_planes`)
    and the moved frame fits no better than the device axis: whether the fit's own frame
    (:attr:`NormalEstimate.alternative`) does. The device frame's check asks the 1-D model
    whether a tilt explains the data, and the model answers best in its own optimum: off
    it, on a material it misfits, ε can read lower in the device frame (`wide`,
    green-fabric tilted 5.2°: the device axis kept, 5.2° off). A tilt the model confirms
    in its own frame is kept, in the direction the planes refined. One more fit, only
    where the check would otherwise reject the tilt."""
    if not est.planes or est.alternative is None:
        return False
    own = slices.reframe(geometry.frame_from_normal(est.alternative, np.array([1.0, 0.0, 0.0])))
    fit = fit_isotropic(own, valid & own.valid, opt.fixed_eta, opt.kd_bound_max_deg)
    return not _tilt_explains_nothing(device_fit, fit)


def limit_energy(model: IsotropicMicrofacetBRDF | MicrofacetBRDF, clamp: bool = True
                 ) -> tuple[IsotropicMicrofacetBRDF | MicrofacetBRDF, float, float]:
    """Scale ``k_d, k_s`` so that the directional albedo is ≤ 1 at :data:`ALBEDO_ANGLES`
    (and, with a Fresnel tint, at its nodes and their midpoints, :func:`reflecto.brdf.albedo_angles`;
    for an anisotropic model at every incidence azimuth, :func:`_largest_albedo`).

    A passive surface reflects at most what it receives. Returns the model, the scale
    (1 when nothing was needed) and the largest albedo after it.

    Parameters
    ----------
    model
        The fitted BRDF.
    clamp
        Whether to scale; ``False`` only measures the largest albedo.

    Returns
    -------
    tuple of (model, float, float)
        The model (a new one with ``k_d, k_s`` times ``1/albedo`` when the largest albedo
        exceeds 1, else ``model``), the scale applied, and the largest directional albedo
        (dimensionless) after it.
    """
    angles = np.array(albedo_angles(model, ALBEDO_ANGLES))
    albedo = _largest_albedo(model, angles, ALBEDO_QUAD)
    if albedo > ALBEDO_REFINE_ABOVE and model.isotropic:
        fine = model.albedo(angles, n_u=ALBEDO_QUAD_FINE, n_phi=ALBEDO_QUAD_FINE)
        albedo = max(albedo, float(fine.max()))
    elif albedo > ALBEDO_REFINE_ABOVE:
        # a lobe sharp in one direction is read ≈ 3 % high at grazing by the coarse quadrature (GGX α
        # 0.5 × 0.05 at 89°: 1.000 against 0.9668 on 128 rings, 0.9655 on 256): the fine one decides
        albedo = _largest_albedo(model, angles, ALBEDO_QUAD_FINE)
    if not clamp or albedo <= 1.0:
        return model, 1.0, albedo
    scale = 1.0 / albedo
    return model.scaled(scale), scale, 1.0


def _largest_albedo(model: IsotropicMicrofacetBRDF | MicrofacetBRDF, angles: Array, quad: int) -> float:
    """The largest directional albedo over the incidence angles ``angles`` (degrees) and
    the incidence azimuths, on a ``quad × quad`` quadrature.

    An isotropic model's albedo does not depend on the azimuth (``φ_i = 0``). An
    anisotropic one's does: it is taken at :data:`ALBEDO_AZIMUTHS` azimuths, then at the
    midpoints of the steps on either side of the largest, twice (the step halved each
    time), so that a maximum between the first azimuths is found to within 7.5°.
    """
    def at(phi: float) -> float:
        return float(model.albedo(angles, phi, n_u=quad, n_phi=quad).max())

    if model.isotropic:
        return at(0.0)
    step = 360.0 / ALBEDO_AZIMUTHS
    best = max((at(p), p) for p in step * np.arange(ALBEDO_AZIMUTHS))
    for _ in range(2):
        step /= 2.0
        best = max(best, *((at(best[1] + d), best[1] + d) for d in (-step, step)))
    return best[0]


def limit_energy_of_the_trend(model: IsotropicMicrofacetBRDF | MicrofacetBRDF, clamp: bool = True
                              ) -> tuple[IsotropicMicrofacetBRDF | MicrofacetBRDF, float, float]:
    """:func:`limit_energy`, holding the Fresnel tint beyond its last node where continuing
    its trend (:class:`reflecto.fresnel.FresnelTint`, ``"trend"``) alone is what would make
    the surface reflect more than it receives.

    The trend is an extrapolation into the grazing band the device does not observe; a
    scale that it alone forces would lower the model at every angle, the observed ones
    included. So where :func:`limit_energy` must scale a model whose tint continues its
    trend and the same model with the tint held at its last node's value (``"constant"``)
    needs no scaling, the held one is kept; otherwise the trend is kept and scaled.

    Parameters
    ----------
    model
        The fitted BRDF.
    clamp
        Whether to scale (:func:`limit_energy`).

    Returns
    -------
    tuple of (model, float, float)
        As :func:`limit_energy`.
    """
    limited = limit_energy(model, clamp)
    tint = model.tint
    if limited[1] >= 1.0 or tint is None or tint.beyond == "constant" or not isinstance(model, IsotropicMicrofacetBRDF):
        return limited
    held = IsotropicMicrofacetBRDF(model.ndf_table, model.kd, model.ks, model.eta, normalize=False,
                                   correlated=model.correlated, metadata=model.metadata,
                                   tint=FresnelTint(tint.theta, tint.values), lobes=model.lobes)
    other = limit_energy(held, clamp)
    return other if other[1] == 1.0 else limited


def held_tint_notes(built, model) -> list[str]:
    """A note where :func:`limit_energy_of_the_trend` held the Fresnel tint beyond its last node.

    Parameters
    ----------
    built
        The model before the energy limit.
    model
        The model after it.

    Returns
    -------
    list of str
        One note, or none.
    """
    if built.tint is None or model.tint is None or built.tint.beyond == model.tint.beyond:
        return []
    return [f"Fresnel tint held beyond its last node (θ_d {math.degrees(model.tint.theta[-1]):.1f}°): "
            "continuing its trend toward grazing would reflect more light than the surface receives"]


def _choose_isotropic(option: str, test: IsotropyTest) -> bool:
    return option == "yes" or (option == "auto" and test.isotropic)


def _notes(fit: IsotropicFit | HemicubeFit, model, isotropic: bool, test: IsotropyTest,
           energy_scale: float, declared: bool = False) -> list[str]:
    notes = []
    if not isotropic:
        # declared anisotropic (isotropic="no"): the test's numbers are reported, not the reason
        notes.append(("anisotropic as declared (isotropic: no); " if declared else "anisotropic: ")
                     + f"a second azimuthal harmonic explains {100 * test.anisotropy:.0f} % of the "
                     f"partial NDF's ring-wise variance ({100 * test.conditional:.0f} % of what θ_d and φ_d "
                     "leave); hemicube NDF")
    return notes + bound_notes(fit.ks_at_bound, fit.eta, model, energy_scale, fit.kd_ceiling)


def bound_notes(ks_at_bound: bool, eta: float, model, energy_scale: float,
                kd_ceiling: Array | None = None) -> list[str]:
    """Plain notes on every parameter the data held at a physical or search bound (``k_s = 1``,
    η at :data:`~.isotropic.ETA_MIN` or :data:`~.isotropic.ETA_MAX`, ``k_d = 0``, ``k_d`` at
    its ceiling), on the constant Fresnel lobe that replaces an η beyond that bound, and on
    the energy limit, for a summary.

    Parameters
    ----------
    ks_at_bound
        Whether the fit held ``k_s`` at 1 (the note is also made where the model's ``k_s``
        before the energy limit reaches 1 in some channel).
    eta
        The fitted relative index (or :data:`reflecto.fresnel.CONSTANT`).
    model
        The final model (its ``kd`` is checked for zero channels).
    energy_scale
        The scale of :func:`limit_energy` (< 1: the albedo was limited).
    kd_ceiling
        ``k_d``'s upper bound per channel in the fit (:func:`.samples.kd_median_bound`:
        ``k_d/π`` at most the samples' median), or ``None`` where the fit had none.

    Returns
    -------
    list of str
        One sentence per bound met (empty when none).
    """
    notes = []
    # the bound binds in the fit, or in a channel's scalars after it (the tint's bounded least
    # squares): the model before the energy limit (``model.ks / energy_scale``) reaches 1
    ks = np.asarray(model.ks)
    if bool(np.any(ks >= (1.0 - 1e-9) * energy_scale)):
        notes.append("k_s at its physical bound 1 (a microfacet reflects at most F): the specular level fixes η")
    elif ks_at_bound:  # the channels' scalars, fitted after the luminance fit, came out below it
        notes.append("the luminance fit held k_s at its physical bound 1 (a microfacet reflects at most F), so the "
                     f"specular level fixes η; the channels' k_s, fitted after it, stay below (largest "
                     f"{float(ks.max()) / energy_scale:.3f})")
    if is_constant(eta):
        notes.append(f"constant Fresnel (F ≡ 1, the η → ∞ limit of eq. 4): the data ask for a flatter curve than "
                     f"any dielectric up to η = {ETA_MAX:g} gives (a metal-like or sheen lobe); the channels' k_s "
                     "carry its level and colour")
    elif eta >= ETA_MAX * (1 - 1e-6):
        notes.append(f"η at its bound {ETA_MAX:g}: a metal-like flat Fresnel curve; the channels' k_s carry its colour")
    elif eta <= ETA_MIN * (1 + 1e-6):
        notes.append(f"η at its bound {ETA_MIN:g}: the steepest Fresnel rise toward grazing the fit allows")
    # the hemicube fit's logistic map of k_d reaches 0 only to ≈ 4e-18 (its argument's clip at −40)
    zero = np.asarray(model.kd) <= 1e-12
    if np.any(zero):
        notes.append("k_d = 0 in channels " + str(np.flatnonzero(zero).tolist()) + ": no diffuse floor measured")
    if kd_ceiling is not None:
        # the energy limit scales k_d after the fit: compare the fitted value with its bound
        ceiling = np.asarray(kd_ceiling, dtype=np.float64)
        at = np.flatnonzero((ceiling > 0) & ~zero & (np.asarray(model.kd) >= (1.0 - 1e-7) * energy_scale * ceiling))
        if at.size:
            notes.append(f"k_d at its ceiling in channels {at.tolist()} (k_d/π at most the samples' median, "
                         "which a diffuse floor cannot exceed): the least squares wanted more, the specular "
                         "terms carry the rest")
    if energy_scale < 1:
        notes.append(f"k_d and k_s scaled by {energy_scale:.3f} so that the albedo stays ≤ 1")
    return notes


def reconstruct(slices: Slices, options: Options | None = None) -> Reconstruction:
    """Reconstruct the generalized microfacet BRDF of one capture's slices (paper §5).

    The stages, in order: the usable samples; the altered normal (§5.4, with
    ``options.estimate_normal``); the isotropic fit of η, k_d, k_s and a 1-D NDF
    (eqs. 5–6); the azimuthal test that decides isotropy (``options.isotropic``); for
    an anisotropic material the hemicube NDF under the symmetry of eq. 3; the motion
    cues; the energy limit (albedo ≤ 1).

    Parameters
    ----------
    slices
        The capture's BRDF slices (:func:`reflecto.workflow.measure`).
    options
        Reconstruction settings (:class:`Options`; default: ``Options()``).

    Returns
    -------
    Reconstruction
        The model (:class:`reflecto.model.IsotropicMicrofacetBRDF`, or for an anisotropic
        material :class:`reflecto.model.MicrofacetBRDF`), η, the isotropy test, the
        motion report, the normal frame, the model error, the energy scale, the albedo,
        notes and the seconds taken.
    """
    opt = checked_options(options)
    if isinstance(opt.normal, str) and opt.normal == "search":  # the §5.5 set search; one capture: as "auto"
        opt = dataclasses.replace(opt, normal="auto")
    t0 = time.perf_counter()
    cpu = FitSeconds()
    clock = time.process_time()

    def lap() -> float:
        """CPU seconds since the last lap."""
        nonlocal clock
        now = time.process_time()
        spent, clock = now - clock, now
        return spent

    check_slices(slices)
    valid = usable_samples(slices)
    # the first estimate of the normal, the device frame's check and a motion cue take them
    peaks = slice_peaks(slices, valid) if _needs_device_check(opt) or opt.detect_shake else None
    est = resolve_normal(slices, valid, opt, peaks)
    cpu.normal = lap()
    frame = est.frame
    sl = slices if est.source == "device" else slices.reframe(frame)
    ok = valid & sl.valid
    device_fit: IsotropicFit | None = None
    if est.source == "device":
        iso = device_fit = _device_frame_fit(slices, valid, opt)
    else:
        iso = fit_isotropic(sl, ok, opt.fixed_eta, opt.kd_bound_max_deg)
        if (_needs_device_check(opt) and not _within_sampling(est) and not _sharp_tilt_beyond_doubt(est)
                and not (peaks is not None and _peaks_place_tilt(est, peaks))):
            device_fit = device_frame_check(slices, valid, opt, iso)
        if (device_fit is not None and _tilt_explains_nothing(device_fit, iso)
                and not _fit_frame_explains(slices, valid, opt, est, device_fit)):
            # the device axis fits as well as the estimated tilt: the data tell the normal only to
            # within the candidates (the fit's own normal too, where the planes moved it), so that is
            # its uncertainty (the motion cues must not read it as a turn)
            spread = max(est.tilt_deg, 0.0 if est.alternative is None
                         else geometry.tilt_deg(est.alternative))
            est = NormalEstimate(np.array([0.0, 0.0, 1.0]), max(est.uncertainty_deg, spread), "device",
                                 est.refits, est.tilt_estimate_deg, alternative=est.normal, planes=est.planes,
                                 peak_tilt_deg=est.peak_tilt_deg)
            frame, sl = est.frame, slices
            ok = valid & sl.valid
            iso = device_fit
    cpu.fit = lap()
    test = azimuthal_test(sl, ok, iso.least_squares)  # in the frame kept: the device frame's only when it is
    isotropic = _choose_isotropic(opt.isotropic, test)
    cpu.isotropy = lap()
    anisotropic_frame_note = None
    if not isotropic and est.source == "estimated":
        # an anisotropic lobe: the estimate's isotropic fit does not hold; the device axis
        dropped = est
        est = dataclasses.replace(est, normal=np.array([0.0, 0.0, 1.0]), uncertainty_deg=0.0, source="device")
        frame, sl = est.frame, slices
        ok = valid & sl.valid
        iso = device_fit if device_fit is not None else _device_frame_fit(slices, valid, opt)
        test = azimuthal_test(sl, ok, iso.least_squares)
        isotropic = _choose_isotropic(opt.isotropic, test)  # the verdict of the frame kept, as the model is
        anisotropic_frame_note = (f"read in the device frame, not at the tilt the isotropic fit places "
                                  f"({dropped.tilt_deg:.2f}° ± {dropped.uncertainty_deg:.2f}°): the lobe reads "
                                  "anisotropic in that frame, where the isotropic fit does not hold (a tilted "
                                  "anisotropic capture needs a given normal)")
        cpu.fit += lap()  # the device frame's fit (and its test) after all
    fit: IsotropicFit | HemicubeFit = iso
    shadowing = None
    if isotropic:
        iso, shadowing = choose_shadowing(iso, opt.fixed_eta, opt.shadowing)
        fit = iso
        cpu.form = lap()
    else:
        fit = fit_hemicube(sl, ok, fixed_eta=opt.fixed_eta, work_resolution=opt.work_resolution,
                           resolution=opt.resolution, kd_bound_max_deg=opt.kd_bound_max_deg)
        cpu.fit += lap()
    built = fit.model  # the ceiling, tint and lobes per node of an isotropic fit are made on first use
    cpu.model = lap()
    hidden, flank_only = _peaks_out_of_reach(slices, ok, est, built)
    motion = (detect_motion(slices, sl, ok, isotropic, est.uncertainty_deg, flank_only, peaks)
              if opt.detect_shake else MotionReport())
    if isinstance(fit, HemicubeFit):
        motion.excluded_leds = fit.excluded_leds
    cpu.motion = lap()
    model, scale, albedo = limit_energy_of_the_trend(built, opt.energy_clamp)
    notes = _normal_notes(est, opt, isotropic) + ([anisotropic_frame_note] if anisotropic_frame_note else [])
    if motion.shake_detected and est.source == "estimated":  # the tilt reads as confidently as a steady one's
        notes.append(f"the sample moved during the capture: the normal found ({est.tilt_deg:.2f}°) and the model "
                     "mix its positions, whatever their uncertainty says; capture again holding the device still")
    notes += _hidden_peak_notes(hidden)
    notes += _notes(fit, model, isotropic, test, scale, opt.isotropic == "no") + held_tint_notes(built, model)
    shadowing_note = None if shadowing is None else shadowing.note()
    if shadowing_note:
        notes.append(shadowing_note)
    cpu.model += lap()  # the energy limit
    return Reconstruction(model, fit.eta, test, motion, frame, iso.model_error,
                          fit.fresnel_error if isinstance(fit, HemicubeFit) else math.nan, scale, albedo,
                          notes, time.perf_counter() - t0, est.uncertainty_deg, est.source,
                          est if isinstance(opt.normal, str) and opt.normal == "auto" else None, shadowing, cpu)


def _peaks_out_of_reach(slices: Slices, valid: NDArray[np.bool_], est: NormalEstimate, model
                        ) -> tuple[list[HiddenPeak], list[int]]:
    """For an isotropic model (none otherwise): the LEDs whose specular peak the tilt hid
    (:func:`.normal.hidden_peaks`; none in the device frame), and those whose mirror planes the
    motion cue does not judge, the slices that hold no sample of the peak about the normal used
    (:func:`.normal.peakless_leds`; a steel tilted 8° has LED 5's nearest view 8.5° from its
    mirror direction, 70 half widths, and its plane 8.6° off a normal 0.01° from the truth)."""
    table = getattr(model, "ndf_table", None)
    if table is None:
        return [], []
    hidden, peakless = peaks_out_of_reach(slices, valid, est.normal, table.nodes, table.values,
                                          est.half_vector_pitch_deg)
    return ([] if est.source == "device" else hidden), peakless


def _hidden_peak_notes(hidden: list[HiddenPeak]) -> list[str]:
    """A note per hidden peak (:func:`_peaks_out_of_reach`)."""
    return [f"the tilt hides LED {p.led}'s specular peak (θ_d {p.theta_d_deg:.0f}°; its nearest view "
            f"{p.nearest_deg:.2f}° off the mirror direction, the lobe's half width {p.half_width_deg:.2f}°): "
            "the lobe there is extrapolated; a capture with the device flatter on the sample sees it"
            for p in hidden]


#: The notes that say the search's bound held the normal (:func:`_normal_notes`): the frame may be
#: off, which breaks eq. 3 and the mirror planes as well.
BOUND_NOTE = "the tilt reached the search's bound"
PEAK_BEYOND_NOTE = "a specular peak places the normal"


def _peak_beyond_notes(est: NormalEstimate, opt: Options) -> list[str]:
    """A note where the slices' specular peak placed the normal beyond a bound set below the
    default search's (a felt's grazing sheen passes for a peak 50° off: beyond that search, no note)."""
    peak, default = est.peak_tilt_deg, Options().max_tilt_deg
    if not (math.isfinite(peak) and opt.max_tilt_deg < peak <= default):
        return []
    return [f"{PEAK_BEYOND_NOTE} {peak:.2f}° from the device axis, beyond the search's bound max_tilt_deg "
            f"{opt.max_tilt_deg:g}°, which held the normal short of it: raise the bound (--max-tilt, "
            "Options.max_tilt_deg) or give the normal"]


def _normal_notes(est: NormalEstimate, opt: Options, isotropic: bool) -> list[str]:
    """A plain statement of the normal used (§5.4) when the options left it to the data."""
    if not (isinstance(opt.normal, str) and opt.normal == "auto"):
        return []
    if est.source == "estimated":
        how = f"estimated with {est.planes} symmetry planes" if est.planes else "estimated"
        notes = [f"sample normal tilted {est.tilt_deg:.2f}° from the device axis (±{est.uncertainty_deg:.2f}°, "
                 f"{how}, §5.4)"]
        if est.tilt_deg >= opt.max_tilt_deg - MAX_TILT_MARGIN_DEG:  # held by the search's bound: beyond it, maybe
            notes.append(f"{BOUND_NOTE} max_tilt_deg {opt.max_tilt_deg:g}°: the normal may "
                         "lie beyond it (raise it: --max-tilt, Options.max_tilt_deg; or give the normal)")
        return notes + _peak_beyond_notes(est, opt)
    if not isotropic or opt.isotropic == "no":
        return ["sample normal: the device axis (the tilt estimate assumes an isotropic lobe; give a known "
                "normal for a tilted capture of an anisotropic material)"] + _peak_beyond_notes(est, opt)
    return _peak_beyond_notes(est, opt)  # the device axis holds (summary: normal_source "device")
