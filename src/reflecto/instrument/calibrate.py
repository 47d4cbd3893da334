"""Calibration of the instrument (paper §4.2, algorithm-reference §7.2–§7.3, §10.3).

From a calibration folder (written by a device, or by
:func:`reflecto.instrument.simulate.simulate_calibration`):

* **geometric** — spots of a pinhole-grid occluder in front of a point source at the
  focal point, several occluder positions, each ray's direction known. A direct
  Levenberg–Marquardt fit (``scipy.optimize.least_squares``) of the condenser model of
  :class:`~reflecto.instrument.optics.Optics` — radial-law scale ``f``, principal point,
  distortion ``k1, k2`` and sensor roll — to the spot centroids. (Zhang's method
  calibrates a pinhole camera from planar targets; here the targets are directions,
  so the condenser law is fitted directly, as algorithm-reference §10.3 recommends.)
* **LED directions** — a mirror with a known normal ``m`` reflects LED ``l`` into view
  direction ``o``; ``l = R_m(o)``.
* **radiometric** — a Lambertian standard of albedo ρ under every LED gives the
  per-LED, per-pixel, per-channel scale ``s = L_ref / (ρ/π)`` (DN/ms per sr⁻¹), which
  contains LED intensity, LED cosine, transmission/vignetting and camera gain; a
  sample's BRDF is then ``f = L / s`` (AR 7.3). The field is smoothed to average
  out photon noise by a local linear fit under a Gaussian window
  (:func:`smooth_field`), which, unlike a local mean, stays unbiased at the view
  disc's rim.
"""

from __future__ import annotations

import dataclasses
import io
import json
import math
import os
import warnings
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy import ndimage
from scipy.optimize import least_squares

from .. import geometry
from ..colour import LUM
from ..errors import FileFormatError, ParameterError, ReflectoWarning, short_repr
from ..io import (
    MAX_ARCHIVE_BYTES,
    atomic_write,
    content_digest,
    inside,
    npy_array,
    npy_bytes,
    parse_json,
    read_input,
    read_json,
    sha256,
    write_zip,
    zip_members,
)
from .capture import CaptureError, read_capture, read_image
from .device import Device, validate_optics_dict
from .hdr import merge_debevec, merge_linear, recover_response
from .optics import Optics

Array = NDArray[np.float64]

CALIBRATION_FORMAT = "reflecto-calibration"
CALIBRATION_VERSION = 2
#: σ (pixels) of the smoothing applied to the radiometric field.
FIELD_SMOOTHING_PX = 3.0
#: A view-disc pixel whose white reading is below this fraction of the LED's median over
#: the disc is cut off by the real aperture, an obstruction or a misplaced axis: it gets no
#: radiometric scale (its samples are invalid). Vignetting leaves the as-built device's
#: darkest disc pixel at 0.84 of the median; a pixel half covered reads about 0.5.
DARK_WHITE_FRACTION = 0.5


@dataclasses.dataclass
class Calibration:
    """What the pipeline knows about a device after calibration.

    Attributes
    ----------
    device
        The nominal device.
    optics
        Calibrated optics (pixel ↔ direction).
    leds
        Calibrated LED directions, shape ``(L, 3)``.
    scale
        Radiometric scale ``s`` (DN/ms per sr⁻¹), shape ``(L, H, W, 3)``: BRDF = radiance / s.
    response
        Inverse camera response ``(256, 3)`` for gamma cameras, else ``None``.
    report
        Residuals of the fits, for the user.
    """

    device: Device
    optics: Optics
    leds: Array
    scale: NDArray[np.float32]
    response: Array | None = None
    report: dict[str, Any] = dataclasses.field(default_factory=dict)

    def pixel_geometry(self) -> tuple[Array, NDArray[np.bool_], NDArray[np.intp], NDArray[np.intp], Array]:
        """The calibrated pixel geometry (cached: computed once per calibration).

        Returns
        -------
        dirs : ndarray, shape (H, W, 3)
            Unit view direction of every pixel (local frame).
        mask : ndarray of bool, shape (H, W)
            Pixels inside the view cone.
        rows, cols : ndarray of intp, shape (P,)
            The indices of the ``P`` pixels of ``mask``.
        scale : ndarray, shape (L, P, 3)
            The radiometric scale at those pixels (DN/ms per sr⁻¹), float64.
        """
        cached = self.__dict__.get("_geom")
        if cached is None:
            dirs, mask = self.optics.pixel_directions()
            rows, cols = np.nonzero(mask)
            cached = (dirs, mask, rows, cols, self.scale[:, rows, cols].astype(np.float64))
            self.__dict__["_geom"] = cached
        return cached

    def scale_luminance(self) -> tuple[NDArray[np.bool_], Array]:
        """The scale's validity and luminance at the view-cone pixels of :meth:`pixel_geometry` (cached).

        Returns
        -------
        positive : ndarray of bool, shape (L, P)
            Whether the scale is > 0 in every channel.
        luminance : ndarray, shape (L, P)
            ``scale · LUM`` (DN/ms per sr⁻¹), :data:`reflecto.colour.LUM` weights.
        """
        cached = self.__dict__.get("_scale_lum")
        if cached is None:

            scl = self.pixel_geometry()[4]
            cached = (np.all(scl > 0, axis=-1), scl @ LUM)
            self.__dict__["_scale_lum"] = cached
        return cached

    def save(self, path: str | Path) -> Path:
        """Write an ``.npz`` calibration file atomically (readable by ``numpy.load``).

        Members ``meta.npy`` (the JSON below, as uint8), ``scale.npy`` and, for gamma
        cameras, ``response.npy``. The JSON holds the format and version, the device,
        the calibrated optics and LED directions, the report, each array's dtype,
        shape and SHA-256 (``arrays``) and the SHA-256 of its own canonical form
        without that entry (``sha256``): a damaged byte anywhere is refused on load.

        Parameters
        ----------
        path
            The file to write (conventionally ``.npz``).

        Returns
        -------
        Path
            ``path``.
        """

        arrays = {"scale": self.scale.astype(np.float32)}
        if self.response is not None:
            arrays["response"] = np.asarray(self.response, dtype=np.float64)
        members = {f"{k}.npy": npy_bytes(a) for k, a in arrays.items()}
        meta = json.loads(json.dumps({
            "format": CALIBRATION_FORMAT,
            "version": CALIBRATION_VERSION,
            "device": self.device.to_dict(),
            "optics": self.optics.to_dict(),
            "leds": self.leds.tolist(),
            "report": self.report,
        }))
        meta["arrays"] = {k: {"dtype": a.dtype.str, "shape": list(a.shape), "sha256": sha256(members[f"{k}.npy"])}
                          for k, a in arrays.items()}
        meta["sha256"] = content_digest(meta)
        members["meta.npy"] = npy_bytes(np.frombuffer(json.dumps(meta).encode(), np.uint8))
        buf = io.BytesIO()
        write_zip(buf, members)
        with atomic_write(path) as fh:
            fh.write(buf.getvalue())
        return Path(path)

    @classmethod
    def load(cls, path: str | Path) -> Calibration:
        """Read a calibration file; refuse foreign, damaged or implausible ones.

        Checks the file and archive limits, the format and version, the checksums
        (version 2; version 1 is read with a warning), the device and optics
        descriptions, the LED directions (finite unit vectors above the horizon,
        within :data:`MAX_LED_OFFSET_DEG` of the nominal design), and the scale and
        response arrays' headers, shapes and values.

        Parameters
        ----------
        path
            A calibration file written by :meth:`save`.

        Returns
        -------
        Calibration
            The calibration.

        Raises
        ------
        FileFormatError
            Naming the file and the first check that failed.
        """

        path = Path(path)
        members = zip_members(read_input(path, MAX_ARCHIVE_BYTES, "a calibration file",
                                         missing="no such calibration file"), path)
        if "meta.npy" not in members or "scale.npy" not in members:
            raise FileFormatError(path, "not a reflecto calibration file (meta or scale missing)")
        meta_raw = npy_array(members["meta.npy"], path, "meta.npy", dtype=np.uint8)
        meta = parse_json(meta_raw.tobytes(), path)
        if not isinstance(meta, dict) or meta.get("format") != CALIBRATION_FORMAT:
            raise FileFormatError(path, "not a reflecto calibration file")
        version = meta.get("version")
        if not isinstance(version, int) or isinstance(version, bool) or not 1 <= version <= CALIBRATION_VERSION:
            raise FileFormatError(path, f"calibration format version {short_repr(version)} not supported "
                                  f"(1 to {CALIBRATION_VERSION})")
        if version >= 2:
            _verify_checksums(path, meta, members)
        try:
            device = Device.from_dict(meta["device"], where="device")
            optics = validate_optics_dict(meta["optics"], "optics")
        except KeyError as e:
            raise FileFormatError(path, f"invalid calibration contents (missing {e})") from None
        except ParameterError as e:
            raise FileFormatError(path, f"invalid calibration contents ({e})") from None
        if (optics.width, optics.height) != (device.optics.width, device.optics.height):
            raise FileFormatError(path, "calibrated optics and device have different sensor sizes")
        leds = _checked_leds(path, meta.get("leds"), device)
        expect = (device.n_leds, optics.height, optics.width, 3)
        scale = npy_array(members["scale.npy"], path, "scale.npy", dtype="<f4", shape=expect)
        if not np.all(np.isfinite(scale)):
            raise FileFormatError(path, "scale field contains NaN or infinity")
        if np.any(scale < 0):
            raise FileFormatError(path, "scale field has negative values")
        dark = _dark_led(device, optics, scale)
        if dark is not None:
            raise FileFormatError(path, f"LED {dark[0]}: the scale field is zero on {100 * (1 - dark[1]):.0f} % of "
                                  "the view disc (a calibration has it on at least half)")
        response = None
        if "response.npy" in members:
            response = npy_array(members["response.npy"], path, "response.npy", dtype="<f8", shape=(256, 3))
            if not np.all(np.isfinite(response)):
                raise FileFormatError(path, "response curve contains NaN or infinity")
        too_bright = _implausible_scale(device, scale, response)
        if too_bright is not None:
            raise FileFormatError(path, too_bright)
        extra = sorted(set(members) - {"meta.npy", "scale.npy", "response.npy"})
        if extra:
            raise FileFormatError(path, f"unexpected archive members {extra}")
        report = meta.get("report", {})
        if not isinstance(report, dict):
            raise FileFormatError(path, "'report' must be an object")
        if version < 2:  # once every check has passed: a damaged file gets its error alone, one line
            warnings.warn(f"{path}: calibration format version 1 has no checksum; its contents are range-checked "
                          "only (calibrate again to get version 2)", ReflectoWarning, stacklevel=2)
        return cls(device, optics, leds, scale, response, report)


#: Calibrated LED directions may differ from the nominal design by at most this angle
#: (degrees): the as-built device's errors are ±0.5°; more means a wrong mirror normal
#: or spot. docs/limits.md.
MAX_LED_OFFSET_DEG = 5.0


#: Largest ratio of a calibrated radiometric scale to its reference value (below), either way. The
#: scale is the nominal one times the LED's intensity factor and the optics' transmission
#: (≤ 1): the as-built devices read at most 1.12× nominal (LEDs within ±15 %). Two orders
#: of magnitude leave room for a device file whose camera sensitivity is only roughly
#: known, and still refuse a scale that would make every measured BRDF a hundred times
#: (or, for a damaged file's 3e38, 10³⁶ times) too dark: an all-black model; or, a hundred
#: times too small, a hundred times too bright (a diffuse white read as k_d ≈ 1 whatever the sample).
MAX_SCALE_RATIO = 100.0


def _reference_scale(device: Device, response: Array | None) -> Array:
    """Per LED, the scale (DN/ms per sr⁻¹) a calibration of ``device`` cannot far exceed.

    Linear camera: the nominal scale ``sensitivity/gain · E_l cos θ_l``
    (:func:`nominal_calibration`). Gamma camera: the scale is in the response curve's
    relative units, so its reference is the brightest level the camera records
    (``max(response)`` per ms of the shortest exposure), read as a white standard of
    albedo 1 (``· π``).
    """
    cam = device.camera
    if cam.response == "gamma" and response is not None:
        top = float(np.max(response)) / min(cam.exposures_ms) * math.pi
        return np.full(device.n_leds, top)
    return cam.sensitivity / cam.gain * np.maximum(device.leds[:, 2], 0.0) * device.led_irradiance


def _implausible_scale(device: Device, scale: NDArray[np.float32], response: Array | None) -> str | None:
    """Why the scale field is too large or too small to be a calibration of ``device``
    (None if it is neither): beyond :data:`MAX_SCALE_RATIO` times its reference either way.
    An LED whose scale is 0 everywhere is :func:`_dark_led`'s to name."""
    ref = _reference_scale(device, response)
    peak = scale.reshape(len(scale), -1).max(axis=1)
    high = np.flatnonzero(peak > MAX_SCALE_RATIO * ref)
    if len(high):
        k = int(high[0])
        return (f"LED {k}: the scale field reaches {float(peak[k]):.3g} DN/ms per sr⁻¹, more than "
                f"{MAX_SCALE_RATIO:g}× the device's reference {float(ref[k]):.3g}; every BRDF read with it would be "
                "far too dark")
    low = np.flatnonzero((peak > 0) & (peak < ref / MAX_SCALE_RATIO))
    if len(low):
        k = int(low[0])
        return (f"LED {k}: the scale field reaches only {float(peak[k]):.3g} DN/ms per sr⁻¹, less than 1/"
                f"{MAX_SCALE_RATIO:g} of the device's reference {float(ref[k]):.3g}; every BRDF read with it would "
                "be far too bright")
    return None


def _dark_led(device: Device, optics: Optics, scale: NDArray[np.float32]) -> tuple[int, float] | None:
    """The first LED whose scale is positive on less than half of the unblocked view disc,
    with that fraction (None if every LED is calibrated over most of it)."""
    dirs, mask = optics.pixel_directions()
    view = mask & ~device.occluded(dirs)
    if not view.any():
        return 0, 0.0
    for k in range(len(scale)):
        lit = float(np.all(scale[k][view] > 0, axis=-1).mean())
        if lit < 0.5:
            return k, lit
    return None


def _verify_checksums(path: Path, meta: dict[str, Any], members: dict[str, bytes]) -> None:
    if meta.get("sha256") != content_digest(meta):
        raise FileFormatError(path, "metadata checksum mismatch: the file is damaged")
    spec = meta.get("arrays")
    if not isinstance(spec, dict):
        raise FileFormatError(path, "metadata lacks a valid 'arrays' table")
    listed = {f"{k}.npy" for k in spec}
    if listed != set(members) - {"meta.npy"}:
        raise FileFormatError(path, f"archive members {sorted(members)} do not match the metadata's {sorted(listed)}")
    for k, v in spec.items():
        if not isinstance(v, dict) or sha256(members[f"{k}.npy"]) != v.get("sha256"):
            raise FileFormatError(path, f"array {k!r} checksum mismatch: the file is damaged")


def _checked_leds(path: Path, value: Any, device: Device) -> Array:
    """Calibrated LED directions: ``(L, 3)`` finite unit vectors above the horizon, near nominal."""
    try:
        leds = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        leds = np.zeros(0)
    if leds.shape != (device.n_leds, 3):
        raise FileFormatError(path, f"LED directions must be {device.n_leds} [x, y, z] vectors, "
                                    f"got {short_repr(value)}")
    problem = led_problem(leds, device.leds)
    if problem:
        raise FileFormatError(path, problem)
    return leds


def led_problem(leds: Array, nominal: Array, index: list[int] | None = None) -> str | None:
    """Why calibrated LED directions cannot be right (None if they can).

    Parameters
    ----------
    leds : ndarray, shape (K, 3)
        Calibrated directions.
    nominal : ndarray, shape (K, 3)
        The design's directions of the same LEDs.
    index
        The LEDs' numbers, for the message; ``0..K−1`` if omitted.

    Returns
    -------
    str or None
        The first problem (not finite, not unit, at or below the horizon, more than
        :data:`MAX_LED_OFFSET_DEG` from nominal), or None.
    """
    index = list(range(len(leds))) if index is None else index
    if not np.all(np.isfinite(leds)):
        return "LED directions contain NaN or infinity"
    if np.any(np.abs(leds) > 1.0 + 1e-5):
        return "LED directions must be unit vectors"
    if np.any(np.abs(np.linalg.norm(leds, axis=1) - 1.0) > 1e-5):
        return "LED directions must be unit vectors"
    if np.any(leds[:, 2] <= 0):
        return "an LED direction lies at or below the sample's horizon"
    off = np.degrees(np.arccos(np.clip(np.sum(leds * nominal, axis=1), -1.0, 1.0)))
    if off.max() > MAX_LED_OFFSET_DEG:
        k = int(np.argmax(off))
        return (f"LED {index[k]} lies {off[k]:.1f}° from its nominal direction, more than {MAX_LED_OFFSET_DEG:g}° "
                "(wrong mirror normal or spot?)")
    return None


def needs_calibration(device: Device) -> bool:
    """Whether captures of ``device`` need a measured calibration to be read correctly.

    Only the built-in simulated devices whose nominal description is exactly what
    they are (:data:`NOMINAL_DEVICES`: ``ideal``, ``earlier``, ``wide``) can use the
    nominal calibration; ``as-built``, ``wide-as-built``, device files and real devices
    differ from their nominal optics, LEDs and vignetting in ways only a calibration
    recovers.

    Parameters
    ----------
    device
        The capture's device.

    Returns
    -------
    bool
        False only for a device whose nominal form is that of a built-in nominal device.
    """
    nominal = device.nominal()
    return all(nominal != Device.builtin(name).nominal() for name in NOMINAL_DEVICES)


#: The built-in devices whose optics are ideal: their captures are read with the nominal calibration.
NOMINAL_DEVICES = ("ideal", "earlier", "wide")


def nominal_calibration(device: Device) -> Calibration:
    """The calibration implied by the nominal device (no measurement).

    Ideal optics, nominal LEDs, scale ``sensitivity/gain · E_l cos θ_l`` everywhere in
    the view disc, 0 at views the device occludes.

    Parameters
    ----------
    device
        The device (its nominal form is used).

    Returns
    -------
    Calibration
        With ``report = {"kind": "nominal"}`` and no response curve.

    Raises
    ------
    CaptureError
        For a gamma-encoded camera, which needs a measured calibration.
    """
    device = device.nominal()
    cam = device.camera
    if cam.response != "linear":
        raise CaptureError(Path("<device>"), "a gamma-encoded camera needs a measured calibration (--calibration)")
    h, w = device.optics.height, device.optics.width
    cos_l = np.maximum(device.leds[:, 2], 0.0) * device.led_irradiance
    scale = np.broadcast_to((cam.sensitivity / cam.gain * cos_l)[:, None, None, None], (device.n_leds, h, w, 3)).copy()
    dirs, mask = device.optics.pixel_directions()
    scale[:, mask & device.occluded(dirs)] = 0.0  # blocked views carry no data
    return Calibration(device, device.optics, device.leds, scale.astype(np.float32), None, {"kind": "nominal"})


# ------------------------------------------------------------------ radiometry
def _gaussian_moments(sigma: float) -> tuple[Array, Array, Array]:
    """1-D Gaussian taps ``g(x)``, ``x g(x)``, ``x² g(x)`` for ``|x| ≤ 4σ`` (pixels)."""
    x = np.arange(-int(math.ceil(4.0 * sigma)), int(math.ceil(4.0 * sigma)) + 1, dtype=np.float64)
    g = np.exp(-0.5 * (x / sigma) ** 2)
    g /= g.sum()
    return g, x * g, x * x * g


def white_lit(white: Array, ok: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """The pixels of ``ok`` where the white standard is seen: its reading (channel mean) at
    least :data:`DARK_WHITE_FRACTION` of its median over ``ok``.

    The view disc comes from the calibrated geometry; where the real aperture is a little
    narrower, or the axis a little off, a ring of the disc reads dark. Smoothed with the
    rest, those pixels would pull the field down at the rim (and the local plane below
    zero just outside it), and a sample there would read ``f ≈ 0``.

    Parameters
    ----------
    white : ndarray, shape (H, W, C)
        One LED's merged white frame (DN/ms).
    ok : ndarray of bool, shape (H, W)
        The view disc's pixels with a valid reading.

    Returns
    -------
    ndarray of bool, shape (H, W)
        The pixels that get a radiometric scale.
    """
    y = white.mean(axis=-1)
    if not ok.any():
        return ok
    return ok & (y >= DARK_WHITE_FRACTION * float(np.median(y[ok])))


def smooth_field(values: Array, ok: NDArray[np.bool_], sigma: float) -> Array:
    """The radiometric field's local linear fit under a Gaussian window, shape of ``values``.

    At each pixel ``t`` the plane ``a + b·(u − u_t) + c·(v − v_t)`` minimizing
    ``Σ_j G_σ(j − t) ok_j (values_j − plane_j)²`` gives the field ``a`` (per channel);
    ``values``: ``(H, W, C)``, ``ok``: ``(H, W)``. A local *mean* (normalized
    convolution) is biased where its window is one-sided: at the view disc's rim it
    reads the field ``σ``-ish pixels inward, 0.25 % high on average over the outer
    10 px of the as-built device's vignetting (0.5 % at p95). The local plane is exact
    for any linear field, so what remains is the field's curvature times ``σ²``
    (≈ 3·10⁻⁴ there) and the photon noise it averages out. Pixels whose window is too
    one-sided for a plane (less than a tenth of a full window's weight, or a 3×3
    system with a condition number above 10⁶) take the local mean; pixels with less
    than 10⁻³ of it, 0.

    Parameters
    ----------
    values : ndarray, shape (H, W, C)
        The raw field (e.g. DN/ms per sr⁻¹ per pixel).
    ok : ndarray of bool, shape (H, W)
        Pixels that carry data.
    sigma
        Gaussian σ in pixels (:data:`FIELD_SMOOTHING_PX`).

    Returns
    -------
    ndarray, shape (H, W, C)
        The smoothed field.
    """
    g, gx, gxx = _gaussian_moments(sigma)

    def corr(img: Array, ku: Array, kv: Array) -> Array:  # Σ_j ku(Δu) kv(Δv) img_j, Δ = j − t
        return ndimage.correlate1d(ndimage.correlate1d(img, ku, axis=1, mode="constant"), kv, axis=0, mode="constant")

    w = ok.astype(np.float64)
    s0, su, sv = corr(w, g, g), corr(w, gx, g), corr(w, g, gx)
    suu, suv, svv = corr(w, gxx, g), corr(w, gx, gx), corr(w, g, gxx)
    m = np.stack([np.stack([s0, su, sv], -1), np.stack([su, suu, suv], -1), np.stack([sv, suv, svv], -1)], -2)
    usable = s0 > 1e-3
    plane = s0 > 0.1
    plane[plane] = np.linalg.cond(m[plane]) < 1e6
    out = np.zeros(values.shape, dtype=np.float64)
    for c in range(values.shape[-1]):
        y = values[..., c] * w
        r0 = corr(y, g, g)
        out[..., c] = np.divide(r0, s0, out=np.zeros_like(r0), where=usable)
        if plane.any():
            rhs = np.stack([r0, corr(y, gx, g), corr(y, g, gx)], -1)[plane]
            out[plane, c] = np.linalg.solve(m[plane], rhs[..., None])[:, 0, 0]
    return out


# ------------------------------------------------------------------ geometry
def _spot_pixels(img: NDArray[np.integer], black: float, min_peak: float) -> tuple[Array, NDArray[np.bool_]]:
    """The image's luminance above black and its spot pixels: brighter than 20 % of the
    peak (at least ``min_peak``), as :func:`detect_spots` takes them."""
    lum = img.astype(np.float64).mean(axis=-1) - black
    return lum, lum > 0.2 * max(float(lum.max()), min_peak)


#: A mirror image's one spot covers at most this share of the frame: a pinhole's image is a
#: few pixels (4–7 of 76,800 on the as-built device); a frame of noise or light covers most of it.
MAX_MIRROR_SPOT_FRACTION = 0.01


def detect_spots(img: NDArray[np.integer], black: float, min_peak: float) -> Array:
    """Intensity-weighted centroids of bright spots in a raw image.

    Pixels brighter than 20 % of the peak (at least ``min_peak``) above black form the
    spots (8-connected); each centroid is refined on a 7 × 7 window.

    Parameters
    ----------
    img : ndarray, shape (H, W, 3)
        Raw frame (DN).
    black
        Black level (DN).
    min_peak
        Smallest peak (DN above black) the threshold is taken from.

    Returns
    -------
    ndarray, shape (K, 2)
        ``(u, v)`` pixel coordinates (column, row) of the ``K`` spots.
    """
    lum, mask = _spot_pixels(img, black, min_peak)
    n, labels = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
    if n <= 1:
        return np.zeros((0, 2))
    weights = np.maximum(lum, 0.0)
    com = ndimage.center_of_mass(weights, labels, np.arange(1, n))
    # refine on a window around each centre (the threshold cuts the spot's tails)
    v, u = np.mgrid[0 : img.shape[0], 0 : img.shape[1]]
    out = []
    for cv_, cu in com:
        r = 3
        u0, v0 = max(int(round(cu)) - r, 0), max(int(round(cv_)) - r, 0)
        win = weights[v0 : v0 + 2 * r + 1, u0 : u0 + 2 * r + 1]
        s = win.sum()
        if s <= 0:
            continue
        out.append(((win * u[v0 : v0 + 2 * r + 1, u0 : u0 + 2 * r + 1]).sum() / s,
                    (win * v[v0 : v0 + 2 * r + 1, u0 : u0 + 2 * r + 1]).sum() / s))
    return np.array(out).reshape(-1, 2)


def _optics_with(nominal: Optics, p: Array) -> Optics:
    return nominal.replace(focal_px=float(p[0]), cx=float(p[1]), cy=float(p[2]), k1=float(p[3]),
                           k2=float(p[4]), roll_deg=float(p[5]))


def fit_optics(nominal: Optics, directions: list[Array], spots: list[Array]) -> tuple[Optics, dict[str, float]]:
    """Fit f, principal point, k1, k2 and roll to spot centroids of known directions.

    ``directions[k]`` (shape ``(M_k, 3)``) are the rays of image ``k``, ``spots[k]``
    the detected centroids (any order). Spots are matched to rays by nearest predicted
    position, first in the central part of the image (where distortion is small) and
    then everywhere, refitting in between.

    Parameters
    ----------
    nominal
        The design optics: the start of the fit and the fixed parameters.
    directions
        Per image, the known ray directions, shape ``(M_k, 3)``.
    spots
        Per image, the detected centroids ``(u, v)``, shape ``(K_k, 2)``.

    Returns
    -------
    optics : Optics
        The fitted optics.
    report : dict
        ``spots_used`` and ``reprojection_rms_px`` (pixels).
    """
    cx, cy = nominal.principal_point
    p = np.array([nominal.f, cx, cy, nominal.k1, nominal.k2, nominal.roll_deg])
    rim = nominal.f * math.sin(math.radians(nominal.cone_half_angle_deg))
    pairs_d: Array = np.zeros((0, 3))
    pairs_s: Array = np.zeros((0, 2))
    for radius_frac, gate in ((0.6, 6.0), (1.1, 3.0), (1.1, 1.5)):
        opt = _optics_with(nominal, p)
        pd, ps = [], []
        for d, s in zip(directions, spots):
            if len(s) == 0:
                continue
            pred = opt.direction_to_pixel(d)
            ccx, ccy = opt.principal_point
            central = np.hypot(pred[:, 0] - ccx, pred[:, 1] - ccy) <= radius_frac * rim
            dist = np.linalg.norm(pred[:, None, :] - s[None, :, :], axis=-1)
            j = np.argmin(dist, axis=1)
            ok = central & (dist[np.arange(len(d)), j] <= gate)
            # one spot per ray
            _, first = np.unique(j[ok], return_index=True)
            idx = np.flatnonzero(ok)[first]
            pd.append(d[idx])
            ps.append(s[j[idx]])
        if not pd:
            raise CaptureError(Path("<grid>"), "no pinhole spot in any grid image (are the grid frames dark?); "
                               "cannot calibrate geometry")
        pairs_d, pairs_s = np.concatenate(pd), np.concatenate(ps)
        if len(pairs_d) < 12:
            raise CaptureError(Path("<grid>"), f"only {len(pairs_d)} pinhole spots matched; cannot calibrate geometry")

        # called by least_squares within this iteration; the defaults bind this iteration's pairs
        def resid(q: Array, pairs_d: Array = pairs_d, pairs_s: Array = pairs_s) -> Array:
            return (_optics_with(nominal, q).direction_to_pixel(pairs_d) - pairs_s).ravel()

        p = least_squares(resid, p, method="lm", x_scale=[10.0, 1.0, 1.0, 0.01, 0.01, 0.1]).x
    r = _optics_with(nominal, p).direction_to_pixel(pairs_d) - pairs_s
    rms = float(np.sqrt(np.mean(np.sum(r * r, axis=1))))
    return _optics_with(nominal, p), {"spots_used": int(len(pairs_d)), "reprojection_rms_px": rms}


# --------------------------------------------------------------- the whole job
#: calibration.json limits (docs/limits.md): grid images, rays per image, sweep frames.
MAX_GRID_IMAGES = 64
MAX_GRID_RAYS = 10000
MAX_RESPONSE_FRAMES = 64
#: A geometric fit worse than this (RMS, pixels) is refused: the spots do not fit the optics model.
MAX_REPROJECTION_RMS_PX = 2.0


def _unit_vectors(value: Any, where: Path, what: str, max_count: int) -> Array:
    try:
        v = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        v = np.zeros(0)
    if v.ndim == 1 and v.shape == (3,) and max_count == 1:
        v = v[None]
    if v.ndim != 2 or v.shape[1] != 3 or not 1 <= len(v) <= max_count:
        raise FileFormatError(where, f"{what} must be "
                              f"{'an [x, y, z] vector' if max_count == 1 else f'1 to {max_count} [x, y, z] vectors'}, "
                              f"got {short_repr(value)}")
    if not np.all(np.abs(v) <= 1.0 + 1e-6) or np.any(np.abs(np.linalg.norm(v, axis=1) - 1.0) > 1e-6):
        raise FileFormatError(where, f"{what} must be finite unit vectors, got {short_repr(value)}")
    if np.any(v[:, 2] <= 0):
        raise FileFormatError(where, f"{what} must point above the sample plane (z > 0)")
    return v


def _entries(meta: dict[str, Any], key: str, mpath: Path, lo: int, hi: int,
             timed: bool = False) -> list[dict[str, Any]]:
    """The ``key`` list of the calibration manifest: ``lo`` to ``hi`` objects, each ``exposure_ms``
    a positive number (with ``timed``, required and distinct: the response sweep's times are its data)."""
    v = meta.get(key)
    if not isinstance(v, list) or not lo <= len(v) <= hi or not all(isinstance(e, dict) for e in v):
        raise FileFormatError(mpath, f"'{key}' must be a list of {lo} to {hi} objects, got {short_repr(v)}")
    for e in v:
        if timed and "exposure_ms" not in e:
            raise FileFormatError(mpath, f"'{key}' entry {short_repr(e)}: exposure_ms is missing (the sweep's "
                                  "times are what recovers the camera's response)")
        t = e.get("exposure_ms", 1.0)
        if not isinstance(t, (int, float)) or isinstance(t, bool) or not (math.isfinite(t) and t > 0):
            raise FileFormatError(mpath, f"'{key}' entry {short_repr(e)}: exposure_ms must be a positive number")
    if timed and len({float(e["exposure_ms"]) for e in v}) != len(v):
        raise FileFormatError(mpath, f"'{key}': every frame needs its own exposure time, got "
                              f"{short_repr([e['exposure_ms'] for e in v])}")
    return v


def read_calibration_manifest(calib_dir: Path) -> tuple[dict[str, Any], Device]:
    """calibration.json of a calibration folder and its device, every entry checked.

    Files named in it must be plain names inside the folder (also after following
    links); ray and mirror-normal directions finite unit vectors above the sample
    plane; mirror LED indices distinct and within the device's LEDs.

    Parameters
    ----------
    calib_dir
        The calibration folder.

    Returns
    -------
    meta : dict
        The manifest, each entry completed with its checked paths and directions
        (keys ``_path``, ``_dirs``, ``_normal``).
    device : Device
        The device it describes.

    Raises
    ------
    CaptureError, FileFormatError
        Naming the manifest and the problem.
    """

    mpath = calib_dir / "calibration.json"
    if not calib_dir.is_dir() or (not mpath.exists() and not mpath.is_symlink()):
        raise CaptureError(mpath, "calibration.json is missing (not a calibration folder)")
    meta = read_json(inside(calib_dir, "calibration.json", calib_dir, "manifest"))
    if (not isinstance(meta, dict)
            or meta.get("format", "reflecto-calibration-capture") != "reflecto-calibration-capture"):
        raise FileFormatError(mpath, "not a reflecto calibration manifest (format 'reflecto-calibration-capture')")
    v = meta.get("version", 1)
    if not isinstance(v, int) or isinstance(v, bool) or v != 1:
        raise FileFormatError(mpath, f"calibration manifest version {short_repr(v)} is not supported (1)")
    if "device" not in meta:
        raise FileFormatError(mpath, "invalid calibration manifest (missing 'device')")
    try:
        device = Device.from_dict(meta["device"], where="device")  # the FileFormatError below names the file
    except (ParameterError, TypeError, ValueError) as e:
        raise FileFormatError(mpath, str(e)) from None
    grid = _entries(meta, "grid", mpath, 1, MAX_GRID_IMAGES)
    mirror = _entries(meta, "mirror", mpath, 0, device.n_leds)
    for g in grid:
        g["_path"] = inside(calib_dir, g.get("file"), mpath, "grid image")
        g["_dirs"] = _unit_vectors(g.get("directions"), mpath, f"directions of {g.get('file')!r}", MAX_GRID_RAYS)
    seen = set()
    for m in mirror:
        m["_path"] = inside(calib_dir, m.get("file"), mpath, "mirror image")
        led = m.get("led")
        if not isinstance(led, int) or isinstance(led, bool) or not 0 <= led < device.n_leds or led in seen:
            raise FileFormatError(mpath, f"mirror entry {short_repr(m.get('file'))}: led must be a distinct LED index "
                                  f"in [0, {device.n_leds}), got {short_repr(led)}")
        seen.add(led)
        m["_normal"] = _unit_vectors(m.get("mirror_normal"), mpath, f"mirror_normal of {m.get('file')!r}", 1)[0]
    if device.camera.response == "gamma":
        if len(meta.get("response") or []) < 3:
            raise FileFormatError(mpath, "a gamma camera needs an exposure sweep ('response', >= 3 frames)")
        for f in _entries(meta, "response", mpath, 3, MAX_RESPONSE_FRAMES, timed=True):
            f["_path"] = inside(calib_dir, f.get("file"), mpath, "response frame")
    named: dict[Path, str] = {}  # one image cannot be two exposures or two positions: a copy-paste slip
    for key in ("grid", "mirror", "response"):
        for entry in meta.get(key) or []:
            if "_path" not in entry:
                continue
            what = f"{key} image {short_repr(entry.get('file'))}"
            if entry["_path"] in named:
                raise FileFormatError(mpath, f"file {short_repr(entry.get('file'))} is named for two images "
                                      f"({named[entry['_path']]} and {what})")
            named[entry["_path"]] = what
    white = inside(calib_dir, "white", mpath, "white capture folder")
    if (white.exists() or white.is_symlink()) and not white.is_dir():
        raise CaptureError(white, "the white capture must be a folder (a capture of the white standard), "
                                  "not a file")
    return meta, device


def calibrate(calib_dir: str | Path, progress: bool = False) -> Calibration:
    """Run geometric, LED and radiometric calibration on a calibration folder.

    Refuses (naming the file) a folder whose manifest, images or white capture are
    invalid, and a result that cannot be right: a geometric fit worse than
    :data:`MAX_REPROJECTION_RMS_PX`, an LED moved more than :data:`MAX_LED_OFFSET_DEG`
    from its nominal direction, a white standard that reads no signal over most of
    the view disc under some LED.

    Parameters
    ----------
    calib_dir
        A calibration folder (``calibration.json``, grid and mirror images, a ``white``
        capture of a Lambertian standard).
    progress
        Show progress bars.

    Returns
    -------
    Calibration
        Fitted optics, LED directions and the radiometric scale (DN/ms per sr⁻¹), with
        the fits' residuals in ``report``.
    """
    calib_dir = Path(calib_dir)
    mpath = calib_dir / "calibration.json"
    meta, device = read_calibration_manifest(calib_dir)
    grid, mirror = meta["grid"], meta["mirror"]
    cam, nominal = device.camera, device.optics
    shape = (nominal.height, nominal.width)
    dtype = np.uint8 if cam.bits == 8 else np.uint16
    black = 0.0 if cam.response == "gamma" else cam.black_level
    min_peak = 0.05 * (cam.max_value - black)
    # geometry
    dirs, spots = [], []
    for g in grid:
        img = read_image(g["_path"], shape, dtype)
        dirs.append(g["_dirs"])
        spots.append(detect_spots(img, black, min_peak))
        if not len(spots[-1]) and len(grid) > 1:  # a grid frame whose source did not light: the others calibrate
            warnings.warn(f"{g['_path']}: no pinhole spot above {min_peak:g} DN (a dark frame?); the geometry is "
                          "fitted to the other grid images", ReflectoWarning, stacklevel=2)
    try:
        optics, geo_report = fit_optics(nominal, dirs, spots)
    except (CaptureError, ParameterError) as e:
        raise CaptureError(mpath, f"geometric calibration failed: {getattr(e, 'problem', e)}") from None
    if not geo_report["reprojection_rms_px"] <= MAX_REPROJECTION_RMS_PX:
        raise CaptureError(mpath, f"geometric calibration failed: the grid spots fit the optics to "
                           f"{geo_report['reprojection_rms_px']:.3g} px RMS (at most {MAX_REPROJECTION_RMS_PX:g})")
    # LED directions from the mirror
    leds = device.leds.copy()
    for m in mirror:
        img = read_image(m["_path"], shape, dtype)
        lit = float(_spot_pixels(img, black, min_peak)[1].mean())
        if lit > MAX_MIRROR_SPOT_FRACTION:  # its centroid would be the frame's: an LED moved by degrees
            raise CaptureError(m["_path"], f"not a mirror spot: {100 * lit:.1f} % of the frame is above a fifth of "
                               "its peak, where a pinhole's image covers a few pixels (noise, or a frame of light)")
        s = detect_spots(img, black, min_peak)
        if len(s) != 1:
            raise CaptureError(m["_path"], f"expected one mirror spot, found {len(s)}")
        o = optics.pixel_to_direction(s[0])
        leds[m["led"]] = geometry.reflect(o, m["_normal"])
        problem = led_problem(leds[m["led"]][None], device.leds[m["led"]][None], [m["led"]])
        if problem:
            raise CaptureError(m["_path"], problem)
    # radiometry
    white = read_capture(calib_dir / "white")
    if white.device.to_dict() != device.to_dict():  # another device's white standard: a wrong radiometry
        raise CaptureError(calib_dir / "white", "the white capture's device is not calibration.json's (another "
                           "device's white standard, or another design of this one)")
    if white.kind != "white":
        raise CaptureError(calib_dir / "white", f"a calibration's white capture has kind 'white', got {white.kind!r}")
    wmeta = white.extra.get("white")
    albedo = wmeta.get("albedo", 0.0) if isinstance(wmeta, dict) else 0.0
    if not isinstance(albedo, (int, float)) or isinstance(albedo, bool) or not 0 < albedo <= 1:
        raise FileFormatError(calib_dir / "white" / "manifest.json", "white target albedo missing or not in (0, 1]")
    albedo = float(albedo)
    response = None
    if cam.response == "gamma":
        sweep = meta["response"]
        frames = np.stack([read_image(f["_path"], shape, dtype) for f in sweep])[None]
        cx, cy = optics.principal_point
        half = int(0.7 * optics.f * np.sin(np.radians(optics.cone_half_angle_deg)))
        win = (slice(max(int(cy) - half, 0), int(cy) + half), slice(max(int(cx) - half, 0), int(cx) + half))
        response = recover_response(frames, np.array([f.get("exposure_ms", 1.0) for f in sweep], dtype=np.float64),
                                    window=win)
        if not np.all(np.isfinite(response)):
            raise CaptureError(mpath, "the exposure sweep gives no usable camera response curve")
        rad, valid = merge_debevec(white.raw, white.exposures_ms, response)
    else:
        rad, valid = merge_linear(white.raw, white.exposures_ms, cam)
    _, mask = optics.pixel_directions()
    scale = np.zeros(rad.shape, dtype=np.float32)
    for k in range(device.n_leds):
        seen = white_lit(rad[k], valid[k] & mask)
        scale[k][seen] = (smooth_field(rad[k], seen, FIELD_SMOOTHING_PX) / (albedo / math.pi))[seen]
    dark = _dark_led(device, optics, scale)
    if dark is not None or not np.all(np.isfinite(scale)):
        k, lit = dark if dark is not None else (0, 0.0)
        raise CaptureError(calib_dir / "white", f"LED {k}: the white standard reads a signal on only "
                           f"{100 * lit:.0f} % of the view disc; no radiometric calibration")
    too_bright = _implausible_scale(device, scale, response)  # what Calibration.load would refuse
    if too_bright is not None:
        raise CaptureError(calib_dir / "white", too_bright)
    if np.any(scale < 0):  # Calibration.load refuses it too: the white frames read below their black level
        k = int(np.flatnonzero((scale < 0).reshape(len(scale), -1).any(axis=1))[0])
        raise CaptureError(calib_dir / "white", f"LED {k}: the white standard reads below the black level "
                           "(negative radiometric scale); no radiometric calibration")
    led_err = np.degrees(np.arccos(np.clip(np.sum(leds * device.leds, axis=1), -1, 1)))
    measured = {int(m["led"]) for m in mirror}
    unmeasured = [k for k in range(device.n_leds) if k not in measured]
    if unmeasured:  # a real LED sits ±0.5° from its design: say which ones were not measured
        warnings.warn(ReflectoWarning(f"{mpath}: LEDs {unmeasured} have no mirror image: they keep their design's "
                                      "directions (a real device's are off by up to 0.5°)"), stacklevel=2)
    report = {"kind": "measured", **geo_report,
              "led_offset_from_nominal_deg": [round(float(e), 3) if k in measured else None
                                              for k, e in enumerate(led_err)],
              "leds_nominal": unmeasured, "white_albedo": albedo}
    return Calibration(device.nominal(), optics, leds, scale, response, report)


#: Calibrations read by :func:`load_calibration`, by file identity (at most :data:`_CACHE_SIZE`).
_LOADED: dict[tuple[Any, ...], Calibration] = {}
_CACHE_SIZE = 4


def _load_cached(path: Path) -> Calibration:
    """:meth:`Calibration.load`, once per file identity (real path, inode, size, modification
    and change times in ns): a batch or ``reflecto watch`` reads and checks its calibration
    file once, not once per capture. A file replaced or rewritten is read again. The
    cached calibration's arrays are read-only, so that no caller changes what the next
    one gets."""
    try:
        st = os.stat(path)
        key = (os.path.realpath(path), st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns)
    except (OSError, ValueError):
        return Calibration.load(path)  # it names the problem
    cal = _LOADED.get(key)
    if cal is None:
        cal = Calibration.load(path)
        for a in (cal.leds, cal.scale, cal.response):
            if a is not None:
                a.flags.writeable = False
        while len(_LOADED) >= _CACHE_SIZE:
            _LOADED.pop(next(iter(_LOADED)))
        _LOADED[key] = cal
    return cal


def read_calibration(path: str | Path) -> Calibration:
    """A calibration file, read and checked once per process while it stays unchanged
    (:func:`load_calibration` without a device to match: a command checks its
    ``--calibration`` once, before its first capture).

    Parameters
    ----------
    path
        A calibration file (:meth:`Calibration.save`).

    Returns
    -------
    Calibration
        The calibration (its arrays read-only).

    Raises
    ------
    FileFormatError
        For a missing or damaged file.
    """
    return _load_cached(Path(path))


def load_calibration(path: str | Path, device: Device) -> Calibration:
    """A calibration file, checked against the capture's ``device`` design.

    Refuses a calibration made for a different device design (LED count, camera). A
    file is read and checked once per process while it stays unchanged (:func:`_load_cached`).

    Parameters
    ----------
    path
        A calibration file (:meth:`Calibration.save`).
    device
        The device of the capture it is for.

    Returns
    -------
    Calibration
        The calibration.

    Raises
    ------
    FileFormatError
        For a damaged file or one made for another device design.
    """
    cal = _load_cached(Path(path))
    if cal.device.n_leds != device.n_leds or cal.device.camera != device.camera:
        raise FileFormatError(path, f"calibration is for device {cal.device.name!r}, which does not match "
                              f"the capture's device {device.name!r}")
    return cal
