"""Capture + calibration → BRDF slices, the input of the reconstruction (§4.3, §5).

For LED ``l`` and pixel ``p`` inside the view cone: ``f_l(p) = L_l(p) / s_l(p)`` (RGB,
sr⁻¹), with ``L`` the HDR radiance and ``s`` the radiometric scale of the calibration.
The value assumes the sample normal is the device's +z: for a tilted sample it is
``f(i, o) · cos θ_i(sample) / cos θ_i(device)``, which the reconstruction undoes once
it has estimated the normal (:func:`Slices.reframe`).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numpy.typing import NDArray

from .. import _kernels, geometry
from ..errors import ParameterError
from .calibrate import Calibration
from .capture import Capture, CaptureError
from .hdr import BLACK_DN, dithered, merge_debevec, merge_linear_pixels

Array = NDArray[np.float64]

#: Smallest cos θ_i of an LED in the sample frame after :meth:`Slices.reframe`.
MIN_LIGHT_COS = 0.05


@dataclasses.dataclass
class Slices:
    """Six (L) BRDF slices sharing one set of view directions.

    Attributes
    ----------
    light
        LED directions, shape ``(L, 3)``.
    view
        View direction of every pixel used, shape ``(P, 3)``.
    values
        BRDF values (sr⁻¹), shape ``(L, P, 3)``.
    valid
        False where a pixel is saturated in every exposure or otherwise unusable,
        shape ``(L, P)``.
    pixels
        ``(row, col)`` of each view direction, shape ``(P, 2)``.
    frame
        Rows ``(t, b, n)`` of the frame the directions are expressed in, in device
        coordinates (identity: the device's own). The values are the BRDF for a sample
        whose normal is this frame's ``n``.
    censored
        Valid samples below the camera's detection limit, shape ``(L, P)``, or ``None``:
        0 or 1 DN in the longest exposure of a camera without dithering read noise,
        whose quantizer rounds a signal under half a DN to 0 and one up to 1.5 DN to 1
        every time (:data:`reflecto.instrument.hdr.BLACK_DN`). Their values are
        bounds, not measurements: the reconstruction uses them to bound k_d, not as
        NDF or Fresnel data.
    noise
        Standard deviation (sr⁻¹) of one channel's reading at each sample's luminance,
        from the camera's noise model (read, shot and quantization noise of the exposures merged,
        :func:`reflecto.instrument.hdr.merge_noise`), shape ``(L, P)``, or ``None`` when
        the camera has no noise model (gamma-encoded).
    limit
        The detection limit of each sample (sr⁻¹): the luminance that
        :data:`reflecto.instrument.hdr.BLACK_DN` represents in its longest exposure;
        a censored sample's value lies below it. Shape ``(L, P)`` or ``None``.
    check_leds, check_values, check_valid
        The device's check frames (the LEDs ``check_leds`` fired again after the
        sequence), merged like the slices: values ``(C, P, 3)`` and validity ``(C, P)``
        for the same view directions; ``()`` and ``None`` when there are none. They are
        no data for the BRDF: a clean capture repeats the slice of the same LED, and a
        difference is motion (:mod:`reflecto.reconstruct.repeat`).
    """

    light: Array
    view: Array
    values: Array
    valid: NDArray[np.bool_]
    pixels: NDArray[np.intp]
    frame: Array = dataclasses.field(default_factory=lambda: np.eye(3))
    censored: NDArray[np.bool_] | None = None
    noise: Array | None = None
    limit: Array | None = None
    check_leds: tuple[int, ...] = ()
    check_values: Array | None = None
    check_valid: NDArray[np.bool_] | None = None

    @property
    def n_leds(self) -> int:
        """Number of LEDs ``L`` (first axis of ``light``)."""
        return self.light.shape[0]

    def reframe(self, frame: Array) -> Slices:
        """Express the slices in a new sample frame (rows t, b, n in the slices' coordinates).

        Directions are rotated; values are corrected for the changed ``cos θ_i``
        (see the module docstring). Views at or below the new horizon become invalid.

        Parameters
        ----------
        frame : ndarray, shape (3, 3)
            Rows ``t, b, n`` of the new sample frame, in the coordinates these slices'
            directions are expressed in: the device's for a capture's slices (e.g.
            :func:`reflecto.geometry.frame_from_normal` of an estimated normal, §5.4).

        Returns
        -------
        Slices
            Light ``(L, 3)`` and view ``(P, 3)`` directions in the new frame, values in
            sr⁻¹ scaled by ``cos θ_i,old / cos θ_i,new`` (``cos θ_i,old`` about the normal
            the values are for, this frame's ``n``); LEDs within ~3° of the new horizon
            become invalid too. Its :attr:`frame` is the new frame in device coordinates
            (``frame @ self.frame``): a second reframe turns from this one.
        """
        frame = np.asarray(frame, dtype=np.float64)
        light = geometry.to_local(self.light, frame)
        view = geometry.to_local(self.view, frame)
        old = self.light[:, 2]  # the values are the BRDF about this frame's normal, z here
        new = light[:, 2]
        ratio = np.divide(old, new, out=np.zeros_like(new), where=new > 1e-6)
        values = self.values * ratio[:, None, None]
        # LEDs within ~3° of the new horizon: cos θ_i is too uncertain to correct by
        valid = self.valid & (view[None, :, 2] > 0) & (new[:, None] > MIN_LIGHT_COS)
        check_values = check_valid = None
        if self.check_values is not None and self.check_valid is not None:
            k = list(self.check_leds)
            check_values = self.check_values * ratio[k, None, None]
            check_valid = self.check_valid & valid[k]
        rescale = (lambda a: None if a is None else a * ratio[:, None])
        return Slices(light, view, values, valid, self.pixels, frame @ self.frame, self.censored, rescale(self.noise),
                      rescale(self.limit), self.check_leds, check_values, check_valid)


#: Directions further from unit length than this are refused (:func:`check_slices`).
UNIT_TOLERANCE = 1e-6


def finite_rgb(values: NDArray[np.floating]) -> NDArray[np.bool_]:
    """Where every channel of ``values`` (shape ``(..., 3)``, RGB) is finite: shape ``(...)``.

    ``np.all(np.isfinite(values), axis=-1)``, with the three channels' flags combined by
    hand (a reduction over a last axis of 3 takes four times as long).

    Parameters
    ----------
    values
        RGB values, shape ``(..., 3)``.

    Returns
    -------
    numpy.ndarray of bool, shape (...)
        No NaN or ±inf in any channel.
    """
    finite = np.isfinite(values)
    return finite[..., 0] & finite[..., 1] & finite[..., 2]


def check_slices(slices: Slices, where: str = "slices") -> None:
    """Refuse slices the reconstruction cannot read: ``light`` ``(L, 3)`` and ``view``
    ``(P, 3)`` finite unit vectors (``L, P ≥ 1``), ``values`` ``(L, P, 3)`` finite on the
    valid samples, ``valid`` ``(L, P)``, ``frame`` a finite ``(3, 3)``. The compiled kernels
    index their tables by the directions' angles, which a NaN would send out of bounds.

    Parameters
    ----------
    slices
        The slices to check (any frame).
    where
        The name that leads the message.

    Raises
    ------
    ParameterError
        One line naming the first array that does not hold.
    """
    def bad(what: str) -> ParameterError:
        return ParameterError(f"{where}: {what}")

    light, view = np.asarray(slices.light), np.asarray(slices.view)
    for name, d in (("light", light), ("view", view)):
        if d.ndim != 2 or d.shape[1] != 3 or len(d) == 0:
            raise bad(f"{name} directions must have shape (N ≥ 1, 3), got {d.shape}")
        if not np.all(np.isfinite(d)):
            raise bad(f"{name} directions hold NaN or infinite values")
        if np.any(np.abs(np.einsum("ij,ij->i", d, d) - 1.0) > 2 * UNIT_TOLERANCE):
            raise bad(f"{name} directions must be unit vectors")
    shape = (len(light), len(view))
    values, valid = np.asarray(slices.values), np.asarray(slices.valid)
    if values.shape != (*shape, 3) or valid.shape != shape:
        raise bad(f"values {values.shape} and valid {valid.shape} must have shapes {(*shape, 3)} and {shape}")
    # a finite sum has no NaN or infinite term (one would make it NaN or infinite): the usual
    # case costs one pass without gathering the valid samples; a sum that overflows is looked at closely
    with np.errstate(over="ignore", invalid="ignore"):
        total = np.sum(values)
    if not np.isfinite(total) and not np.all(np.isfinite(values[valid])):
        raise bad("values hold NaN or infinite values where valid")
    frame = np.asarray(slices.frame)
    if frame.shape != (3, 3) or not np.all(np.isfinite(frame)):
        raise bad(f"frame must be a finite (3, 3) array, got {frame.shape}")


def _check_inputs(capture: Capture, calibration: Calibration) -> None:
    where = capture.path or "<capture>"
    design, ours = calibration.device, capture.device
    if (design.n_leds != ours.n_leds or design.camera != ours.camera
            or not np.allclose(np.asarray(design.leds), np.asarray(ours.leds), atol=1e-6)):
        raise CaptureError(where, f"the calibration is for device {design.name!r}, whose design (LEDs, camera) "
                                  f"is not that of the capture's device {ours.name!r}")
    leds = np.asarray(calibration.leds, dtype=np.float64)
    if leds.shape != (capture.device.n_leds, 3):
        raise CaptureError(where, f"calibration has {leds.shape} LED directions, "
                                  f"the capture {capture.device.n_leds} LEDs")
    if (not np.all(np.abs(leds) <= 1.0 + 1e-5) or np.any(np.abs(np.linalg.norm(leds, axis=1) - 1.0) > 1e-5)
            or np.any(leds[:, 2] <= 0)):
        raise CaptureError(where, "the calibration's LED directions are not finite unit vectors above the horizon")
    o = calibration.optics
    scale = calibration.scale
    if scale.shape != (capture.device.n_leds, o.height, o.width, 3):
        raise CaptureError(where, f"the calibration's scale field has shape {scale.shape}")
    # a read-only scale field (a calibration loaded by load_calibration) is checked once
    if calibration.__dict__.get("_scale_checked") is not scale:
        if not np.all(np.isfinite(scale)) or np.any(scale < 0):
            raise CaptureError(where, "the calibration's scale field has NaN, infinite or negative values")
        if not scale.flags.writeable:
            calibration.__dict__["_scale_checked"] = scale
    raw = capture.raw
    if (not isinstance(raw, np.ndarray) or raw.dtype.kind != "u" or raw.ndim != 5
            or raw.shape[0] != capture.device.n_leds or raw.shape[2:] != (o.height, o.width, 3)):
        raise CaptureError(where, f"raw frames must be unsigned integers of shape (LEDs {capture.device.n_leds}, "
                                  f"exposures, {o.height}, {o.width}, 3), got "
                                  f"{getattr(raw, 'dtype', type(raw).__name__)} {getattr(raw, 'shape', '')}")
    t = np.asarray(capture.exposures_ms, dtype=np.float64)
    if t.shape != (capture.raw.shape[1],) or not np.all(np.isfinite(t)) or np.any(t <= 0):
        raise CaptureError(where, "exposure times must be positive and one per exposure slot")
    r = capture.rotation_deg
    if isinstance(r, bool) or not isinstance(r, (int, float, np.number)) or not math.isfinite(r):
        raise CaptureError(where, f"rotation_deg must be a finite number of degrees, got {r!r}")


def extract_slices(capture: Capture, calibration: Calibration) -> Slices:
    """HDR merge, radiometric correction and pixel directions (see the module docstring).

    Refuses (before any compiled kernel sees them) LED directions that are not finite
    unit vectors above the horizon, a radiometric scale of the wrong shape or with
    NaN, infinite or negative values, and exposure times that are not positive.

    Parameters
    ----------
    capture
        Raw frames of one measurement (:func:`reflecto.instrument.read_capture`).
    calibration
        The device's calibration (optics, LED directions, radiometric scale).

    Returns
    -------
    Slices
        ``L`` BRDF slices: light ``(L, 3)``, view ``(P, 3)`` directions (device frame)
        and values ``(L, P, 3)`` in sr⁻¹ (HDR radiance / scale), with validity masks.

    Raises
    ------
    CaptureError
        When capture and calibration do not fit each other, or the inputs are invalid.
    """
    dev = capture.device
    _check_inputs(capture, calibration)
    if calibration.device.n_leds != dev.n_leds:
        raise CaptureError(capture.path or "<capture>", "calibration and capture have different LED counts")
    if capture.raw.shape[2:4] != (calibration.optics.height, calibration.optics.width):
        raise CaptureError(capture.path or "<capture>", "image size differs from the calibration's sensor")
    if dev.camera.response == "gamma":
        if calibration.response is None:
            raise CaptureError(capture.path or "<capture>", "gamma camera: the calibration has no response curve")
    dirs, mask, rows, cols, scale = calibration.pixel_geometry()

    def merge(raw: NDArray[np.integer], scl: Array, scl_pos: NDArray[np.bool_], s_lum: Array
              ) -> tuple[Array, NDArray[np.bool_], NDArray[np.bool_] | None, Array | None, Array | None]:
        if dev.camera.response == "gamma":
            assert calibration.response is not None  # refused above for a gamma camera
            rad, valid = merge_debevec(raw, capture.exposures_ms, calibration.response)
            rad, valid = rad[:, rows, cols], valid[:, rows, cols]
            ok = valid & scl_pos
            return np.divide(rad, scl, out=np.zeros_like(rad), where=ok[..., None]), ok, None, None, None
        rad, valid, near_black, sigma, t_sum = merge_linear_pixels(raw, capture.exposures_ms, dev.camera, rows, cols,
                                                                    noise=True)
        # one compiled pass: ok = valid & scale > 0; where ok, values = rad / scale and, in BRDF units (sr⁻¹),
        # the noise σ / s_lum and the detection limit BLACK_DN / max(Σt, 1e-300) / s_lum; 0 elsewhere
        values, ok = np.empty_like(rad), np.empty(valid.shape, dtype=bool)
        noise, limit = np.empty(valid.shape), np.empty(valid.shape)
        _kernels.slice_values(rad, valid, scl, scl_pos, s_lum, sigma, t_sum, BLACK_DN, values, ok, noise, limit)
        return values, ok, near_black, noise, limit

    scale_pos, scale_lum = calibration.scale_luminance()
    values, ok, near_black, noise, limit = merge(capture.raw, scale, scale_pos, scale_lum)
    censored = None if near_black is None or dithered(dev.camera) else near_black & ok
    check_leds: tuple[int, ...] = ()
    check_values = check_valid = None
    if capture.check is not None and dev.check_leds:
        check_leds = dev.check_leds
        k = list(check_leds)
        check_values, check_valid, *_ = merge(capture.check, scale[k], scale_pos[k], scale_lum[k])
    return Slices(calibration.leds.copy(), dirs[rows, cols], values, ok, np.stack([rows, cols], -1), censored=censored,
                  noise=noise, limit=limit, check_leds=check_leds, check_values=check_values, check_valid=check_valid)
