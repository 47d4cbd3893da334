"""The virtual instrument: raw frames a real device would record (paper §4).

Image formation for LED ``l``, exposure ``t`` and pixel ``p`` (view direction ``o_p``
through the *true* optics):

``electrons = sensitivity · t · E_l · T(p) · f(i_loc, o_loc) · cos θ_i``  (RGB)

with ``E_l`` the nominal design irradiance (``E_l cos θ_l = 1`` on the device's sample
plane) times the LED's real intensity factor,

``T`` the optical transmission/vignetting field,
``f`` the BRDF in sr⁻¹ evaluated in the sample's local frame (``i_loc``, ``o_loc``;
the sample may be tilted, rotated, or move between frames) at the pixel's centre
direction (by default; or averaged over the pixel's area and blurred by a Gaussian
spread, :func:`simulate_capture`'s ``footprint`` and ``blur_px``), then Poisson photon
noise, clipping at the full well, Gaussian read noise, conversion to DN with the
black level, rounding and clipping to the ADC range. A gamma camera encodes
``255 (e/full_well)^(1/γ)`` in 8 bits instead. Pixels outside the condenser's view
cone receive no light.

Calibration targets (§4.2) are simulated by the same camera: a Lambertian white
standard under every LED, images of a pinhole-grid occluder in front of a point
source at the focal point, and a mirror on a tilt stage that reflects each LED into
the camera.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from .. import _kernels, geometry
from ..brdf import BRDFSource
from ..errors import ParameterError, short_repr
from ..sources.analytic import AnalyticBRDF
from .capture import CALIBRATION_MANIFEST, MAX_ROTATION_DEG, Capture, _write_png, atomic_dir, write_capture
from .device import Camera, Device
from .optics import Optics

Array = NDArray[np.float64]

#: Largest hand tilt the simulator accepts (hand-held use reaches about 15°).
MAX_TILT_DEG = 30.0


@dataclasses.dataclass(frozen=True)
class Pose:
    """Orientation of the sample in the device frame: rows ``(t, b, n)``."""

    frame: Array

    @classmethod
    def from_angles(cls, tilt_deg: float = 0.0, tilt_azimuth_deg: float = 0.0, rotation_deg: float = 0.0) -> Pose:
        """Normal tilted by ``tilt_deg`` towards ``tilt_azimuth_deg``; tangent turned by ``rotation_deg``.

        Parameters
        ----------
        tilt_deg
            Angle between the sample normal and the device's +z, degrees.
        tilt_azimuth_deg
            Azimuth of the tilt in the device frame, degrees.
        rotation_deg
            Azimuth of the tangent hint (projected ⟂ n), degrees.

        Returns
        -------
        Pose
            The pose.
        """
        t, a, r = (math.radians(v) for v in (tilt_deg, tilt_azimuth_deg, rotation_deg))
        n = np.array([math.sin(t) * math.cos(a), math.sin(t) * math.sin(a), math.cos(t)])
        t0 = np.array([math.cos(r), math.sin(r), 0.0])
        return cls(geometry.frame_from_normal(n, t0))

    def rotated(self, axis: ArrayLike, angle_deg: float) -> Pose:
        """The pose after rotating the sample by ``angle_deg`` about ``axis`` (device frame).

        Parameters
        ----------
        axis : array_like, shape (3,)
            Rotation axis in device coordinates (normalized here).
        angle_deg
            Rotation angle, degrees (right-hand rule; Rodrigues' formula).

        Returns
        -------
        Pose
            The rotated pose.
        """
        k = geometry.normalize(axis)
        a = math.radians(angle_deg)
        kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        rot = np.eye(3) + math.sin(a) * kx + (1 - math.cos(a)) * kx @ kx
        return Pose(self.frame @ rot.T)

    @property
    def normal(self) -> Array:
        """The sample normal ``n`` in the device frame (third row of ``frame``), shape ``(3,)``."""
        return self.frame[2]

    def to_local(self, v: ArrayLike) -> Array:
        """Device-frame vectors in the sample frame: ``(v·t, v·b, v·n)``.

        Parameters
        ----------
        v
            Vectors in device coordinates, shape ``(..., 3)``.

        Returns
        -------
        ndarray, shape ``(..., 3)``
            The same vectors in the sample's ``(t, b, n)`` frame.
        """
        return geometry.to_local(v, self.frame)


#: Above this many electrons, photon noise is drawn from its Gaussian limit N(λ, λ)
#: (same mean and variance; skewness ≤ 0.18); below it, exactly from Poisson(λ).
GAUSSIAN_PHOTONS = 30.0


def expose(signal: Array, t_ms: float, camera: Camera, rng: np.random.Generator | None) -> NDArray[np.integer]:
    """Raw image of an electron rate ``signal`` (e⁻/ms, any shape) for ``t_ms`` ms.

    Photon and read noise are drawn from ``rng`` (a seeded generator gives identical
    frames); ``rng=None`` or a noiseless camera gives the noiseless image.

    Parameters
    ----------
    signal : ndarray
        Electron rate per pixel and channel, e⁻/ms.
    t_ms
        Exposure time, ms.
    camera
        Full well, noise, gain, black level, response and ADC range.
    rng
        Noise source, or None.

    Returns
    -------
    ndarray, shape of ``signal``
        Raw DN: uint16, or uint8 for an 8-bit camera (:attr:`Camera.raw_dtype`).
    """
    sig = np.ascontiguousarray(signal, dtype=np.float64).ravel()
    gamma = camera.gamma if camera.response == "gamma" else 0.0
    out = np.empty(sig.shape, dtype=camera.raw_dtype)
    z: NDArray[np.float32] | Array  # the normal deviates, float32 when drawn
    z = pois = np.empty(0)
    if rng is not None and not camera.noiseless:
        z = rng.standard_normal(sig.shape, dtype=np.float32)
        pois = np.zeros(sig.shape)
        if camera.shot_noise:
            lam = np.minimum(np.maximum(sig, 0.0) * t_ms, GAUSSIAN_PHOTONS)
            idx = np.flatnonzero((lam > 0) & (lam < GAUSSIAN_PHOTONS))
            pois[idx] = rng.poisson(lam[idx])
    _kernels.expose(
        sig, float(t_ms), z, pois, camera.full_well, camera.read_noise, camera.shot_noise, GAUSSIAN_PHOTONS,
        gamma, camera.gain, camera.black_level, float(camera.max_value), out,
    )  # fmt: skip
    return out.reshape(np.shape(signal))


def exposure_times(camera: Camera, peak_rate: float, headroom: float = 0.8) -> tuple[float, ...]:
    """The camera's exposures, shortened (ratios kept) so the peak fills ``headroom`` of the well.

    Without auto-exposure, or when nothing saturates, the nominal times.

    Parameters
    ----------
    camera
        The camera (its ``exposures_ms`` and ``full_well``).
    peak_rate
        The brightest pixel's electron rate, e⁻/ms.
    headroom
        Fraction of the full well the peak may fill in the shortest exposure.

    Returns
    -------
    tuple of float
        Exposure times, ms.
    """
    times = camera.exposures_ms
    if not camera.auto_exposure or peak_rate <= 0:
        return times
    t_max = headroom * camera.full_well / peak_rate
    shortest = min(times)
    if shortest <= t_max:
        return times
    k = max(t_max, 1e-4) / shortest
    return tuple(float(np.float32(t * k)) for t in times)


def _truth(device: Device) -> tuple[Optics, Array, Array, Array]:
    """True optics, LED directions, LED intensities and transmission field."""
    if device.truth is None:
        h, w = device.optics.height, device.optics.width
        return device.optics, device.leds, np.ones(device.n_leds), np.ones((h, w))
    t = device.truth
    return t.optics, t.leds, np.asarray(t.led_intensity), t.transmission_field()


#: The largest turn of a simulated shake (degrees): a hand moves the device a few degrees.
MAX_SHAKE_DEG = 30.0


def _check_angle(what: str, deg: float) -> None:
    """Refuse an angle that is not finite or beyond a few turns (its sine and cosine would be noise,
    and NaN would reach the manifest and the frames)."""
    if not (math.isfinite(deg) and abs(deg) <= MAX_ROTATION_DEG):
        raise ParameterError(f"{what} must be a finite angle of at most {MAX_ROTATION_DEG:g}° in magnitude, "
                             f"got {deg:g}")


def _check_seed(seed: int) -> None:
    """Refuse a seed numpy's generator does not take (it needs an integer >= 0)."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ParameterError(f"seed must be an integer >= 0, got {seed}")


def simulate_capture(
    source: BRDFSource,
    device: Device,
    *,
    tilt_deg: float = 0.0,
    tilt_azimuth_deg: float | None = None,
    rotation_deg: float = 0.0,
    shake: bool = False,
    shake_deg: float | None = None,
    seed: int = 0,
    source_name: str | None = None,
    footprint: int = 1,
    blur_px: float = 0.0,
) -> Capture:
    """Raw frames of one capture of ``source`` (see the module docstring).

    Parameters
    ----------
    tilt_deg, tilt_azimuth_deg
        Hand tilt of the sample normal (≤ 30°); the azimuth is drawn from ``seed`` when
        not given.
    rotation_deg
        Rotation of the sample's tangent about its normal (for anisotropic sources).
    shake
        The device moves during the capture: from a random LED on (in the device's
        firing order, never the first), the sample is turned by ``shake_deg`` (drawn in
        [3°, 8°] when not given) about a random horizontal axis — the failure §5.1 must
        detect. The manifest records the first moved LED, its firing position and all
        moved LEDs.
    seed
        Seeds noise, tilt azimuth and shake; equal seeds give identical frames.
    source
        The BRDF to measure (sr⁻¹).
    device
        The device; its ``truth`` (as-built imperfections), if any, is simulated.
    source_name
        Name recorded in the manifest (default: the source's name).
    footprint, blur_px
        How a pixel sees the BRDF: at its centre's direction (``footprint`` 1, ``blur_px``
        0, the default), or as the mean over ``footprint × footprint`` sub-pixel
        directions of the BRDF's image blurred by a Gaussian of ``blur_px`` pixels
        (standard deviation; the spread of a real device's pinhole and LED beam). A lobe
        narrower than a pixel is read high or low by where the pixel centres fall; the
        footprint and the blur make the reading a smooth function of the pose, at
        ``footprint²`` times the BRDF evaluations (docs/design/normal.md, Limits).

    Returns
    -------
    Capture
        Raw frames ``(L, E, H, W, 3)``, exposures (ms), check frames, and the simulation's
        provenance (pose, shake) in ``extra``.

    Raises
    ------
    ParameterError
        For a tilt outside [0°, :data:`MAX_TILT_DEG`], a tilt azimuth or rotation that is
        not a finite angle of at most :data:`MAX_ROTATION_DEG`, or a negative seed.
    """
    if not callable(getattr(source, "eval", None)):
        raise ParameterError(f"simulate: the source must be a BRDF (load_source(PATH)), got {short_repr(source)}")
    if not isinstance(device, Device):
        raise ParameterError(f"simulate: the device must be a Device (load_device(NAME)), got {short_repr(device)}")
    if not isinstance(shake, (bool, np.bool_)):
        raise ParameterError(f"shake must be True or False, got {short_repr(shake)}")
    if shake_deg is not None and not shake:
        raise ParameterError("a shake angle needs shake=True")
    for name, v in (("tilt", tilt_deg), ("rotation", rotation_deg), ("tilt azimuth", tilt_azimuth_deg),
                    ("shake angle", shake_deg)):
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float, np.number))):
            raise ParameterError(f"{name} must be a number of degrees, got {v!r}")
    if not (math.isfinite(tilt_deg) and 0.0 <= tilt_deg <= MAX_TILT_DEG):
        raise ParameterError(f"tilt must be in [0°, {MAX_TILT_DEG}°], got {tilt_deg}")
    if shake_deg is not None and not (math.isfinite(shake_deg) and 0.0 < shake_deg <= MAX_SHAKE_DEG):
        raise ParameterError(f"shake angle must be in (0°, {MAX_SHAKE_DEG:g}°], got {shake_deg}")
    _check_angle("rotation", rotation_deg)
    if tilt_azimuth_deg is not None:
        _check_angle("tilt azimuth", tilt_azimuth_deg)
    _check_seed(seed)
    if isinstance(footprint, bool) or not isinstance(footprint, (int, np.integer)) or not 1 <= footprint <= 8:
        raise ParameterError(f"footprint must be an integer in [1, 8] (sub-pixel directions per side), "
                             f"got {footprint!r}")
    if isinstance(blur_px, bool) or not isinstance(blur_px, (int, float)) or not 0.0 <= blur_px <= 8.0:
        raise ParameterError(f"blur_px must be a number of pixels in [0, 8], got {blur_px!r}")
    rng = np.random.default_rng(seed)
    optics, leds, intensity, trans = _truth(device)
    cam = device.camera
    if tilt_azimuth_deg is None:
        tilt_azimuth_deg = float(rng.uniform(0.0, 360.0))
    pose = Pose.from_angles(tilt_deg, tilt_azimuth_deg, rotation_deg)
    poses = [pose] * device.n_leds
    shake_info: dict[str, Any] | None = None
    if shake:
        start = int(rng.integers(1, device.n_leds))  # position in the firing order
        ang = float(rng.uniform(3.0, 8.0)) if shake_deg is None else float(shake_deg)
        az = rng.uniform(0.0, 2.0 * math.pi)
        axis = np.array([math.cos(az), math.sin(az), 0.0])
        moved = pose.rotated(axis, ang)
        later = set(device.order[start:])
        poses = [moved if k in later else pose for k in range(device.n_leds)]
        shake_info = {"from_led": device.order[start], "from_position": start, "moved_leds": sorted(later),
                      "angle_deg": ang, "axis": axis.tolist()}

    dirs, mask = optics.pixel_directions()
    o = dirs[mask]
    h, w = mask.shape
    raw_dtype = cam.raw_dtype
    # an occluder in the light path (earlier device) blocks the central views
    scale = cam.sensitivity * trans[mask][:, None] * ~device.occluded(o)[:, None]
    power = device.led_irradiance * intensity

    fine = _fine_views(optics, mask, footprint, blur_px) if footprint > 1 or blur_px > 0 else None

    def brdf(i_loc: Array, o_loc: Array) -> Array:
        ok = (o_loc[:, 2] > 0) & (i_loc[2] > 0)
        f = np.zeros((len(o_loc), 3))
        if ok.any():
            f[ok] = source.eval(np.broadcast_to(i_loc, (int(ok.sum()), 3)), o_loc[ok])
        if not np.all(np.isfinite(f)):
            raise ParameterError(f"source {source_name or source.name} returned non-finite values")
        return f

    def rate(k: int, p: Pose) -> Array:
        i_loc = p.to_local(leds[k])
        f = brdf(i_loc, p.to_local(o)) if fine is None else fine.pixel_means(brdf(i_loc, p.to_local(fine.views)))
        r = np.zeros((h, w, 3))
        r[mask] = f * (max(i_loc[2], 0.0) * power[k]) * scale
        return r

    rates = np.stack([rate(k, poses[k]) for k in range(device.n_leds)])
    times = exposure_times(cam, float(rates.max()))
    raw = np.empty((device.n_leds, len(times), h, w, 3), dtype=raw_dtype)
    for k in range(device.n_leds):
        for e, t in enumerate(times):
            raw[k, e] = expose(rates[k], t, cam, rng)
    # check frames: fired after the whole sequence, in the pose of its last LED; their
    # noise is drawn after the sequence's, which stays as without them
    check = None
    if device.check_leds:
        final = poses[device.order[-1]]
        check = np.empty((len(device.check_leds), len(times), h, w, 3), dtype=raw_dtype)
        for c, k in enumerate(device.check_leds):
            r = rates[k] if final is poses[k] else rate(k, final)
            for e, t in enumerate(times):
                check[c, e] = expose(r, t, cam, rng)
    sim = {
        "source": source_name or source.name,
        "seed": seed,
        "tilt_deg": tilt_deg,
        "tilt_azimuth_deg": tilt_azimuth_deg,
        "rotation_deg": rotation_deg,
        "normal": pose.normal.tolist(),
        "shake": shake_info,
        "device_truth": device.name if device.truth is not None else None,
    }
    return Capture(device.nominal(), raw, np.array(times), "sample", {"simulation": sim}, check=check,
                   rotation_deg=float(rotation_deg) % 360.0)


# --------------------------------------------------------------- calibration
#: Albedo of the simulated Lambertian white standard.
WHITE_ALBEDO = 0.99
#: Spacing of the pinhole grid in the sine-law image plane (normalized radius).
GRID_SPACING = 0.1
#: Angular radius (degrees) of a spot: pinhole diffraction / LED size blur.
SPOT_BLUR_PX = 0.8


@dataclasses.dataclass(frozen=True)
class _FineViews:
    """The sub-pixel view directions of :func:`simulate_capture`'s ``footprint`` and
    ``blur_px``, and how their BRDF values become the view-cone pixels' means."""

    views: Array  # (M, 3) device-frame directions on the fine grid near the view cone
    near: NDArray[np.bool_]  # (H·n, W·n): where ``views`` lie on the fine grid
    mask: NDArray[np.bool_]  # (H, W): the view cone's pixels
    footprint: int
    blur_px: float

    def pixel_means(self, f: Array) -> Array:
        """Per view-cone pixel (``mask`` order), the mean of the blurred fine image, shape ``(P, 3)``."""
        n = self.footprint
        h, w = self.mask.shape
        img = np.zeros((h * n, w * n, 3))
        img[self.near] = f
        if self.blur_px > 0:
            img = cv2.GaussianBlur(img, (0, 0), self.blur_px * n, borderType=cv2.BORDER_CONSTANT)
        return img.reshape(h, n, w, n, 3).mean(axis=(1, 3))[self.mask]


def _fine_views(optics: Optics, mask: NDArray[np.bool_], footprint: int, blur_px: float) -> _FineViews:
    """``footprint²`` directions per pixel at the centres of its sub-pixels, over the view
    cone's pixels and a margin of three blur widths (the blur carries light in from there)."""
    n = footprint
    h, w = mask.shape
    v, u = np.mgrid[0:h * n, 0:w * n].astype(np.float64)
    uv = np.stack([(u + 0.5) / n - 0.5, (v + 0.5) / n - 0.5], axis=-1)
    reach = 1 + int(math.ceil(3.0 * blur_px))
    grown = cv2.dilate(mask.astype(np.uint8), np.ones((2 * reach + 1, 2 * reach + 1), np.uint8)) > 0
    near = np.repeat(np.repeat(grown, n, axis=0), n, axis=1)
    return _FineViews(optics.pixel_to_direction(uv[near]), near, mask, n, float(blur_px))


def grid_directions(optics: Optics, offset: tuple[float, float]) -> Array:
    """Known ray directions through one occluder position's pinholes (device frame).

    The pinholes are laid out so that the rays are evenly spaced in the sine-law image
    (spacing :data:`GRID_SPACING`), shifted by ``offset``; the occluder is mounted on
    the optical axis of the nominal design.

    Parameters
    ----------
    optics
        The optics (cone and axis).
    offset
        Shift of the grid in sine-law units ``(x, y)``.

    Returns
    -------
    ndarray, shape (M, 3)
        Unit ray directions in the device frame, within 1° of the cone's rim.
    """
    rim = math.sin(math.radians(optics.cone_half_angle_deg - 1.0))
    g = np.arange(-1.0, 1.0 + 1e-9, GRID_SPACING)
    sx, sy = np.meshgrid(g + offset[0], g + offset[1])
    s2 = sx * sx + sy * sy
    keep = s2 <= rim * rim
    loc = np.stack([sx[keep], sy[keep], np.sqrt(1.0 - s2[keep])], -1)
    return loc @ optics.axis_frame


def _spots(optics: Optics, dirs: Array, amplitude: float) -> Array:
    """Electron rate image of Gaussian spots at the pixels of ``dirs`` (true optics)."""
    uv = optics.direction_to_pixel(dirs)
    v, u = np.mgrid[0 : optics.height, 0 : optics.width].astype(np.float64)
    img = np.zeros((optics.height, optics.width))
    r = int(math.ceil(4 * SPOT_BLUR_PX))
    for cu, cv in uv:
        if not (np.isfinite(cu) and -r < cu < optics.width + r and -r < cv < optics.height + r):
            continue
        u0, v0 = max(int(cu) - r, 0), max(int(cv) - r, 0)
        u1, v1 = min(int(cu) + r + 2, optics.width), min(int(cv) + r + 2, optics.height)
        du, dv = u[v0:v1, u0:u1] - cu, v[v0:v1, u0:u1] - cv
        img[v0:v1, u0:u1] += amplitude * np.exp(-(du * du + dv * dv) / (2 * SPOT_BLUR_PX**2))
    return np.repeat(img[..., None], 3, axis=-1)


#: Exposure sweep (ms) of the white target for gamma cameras' response recovery.
RESPONSE_SWEEP_MS = tuple(0.25 * 2.0**k for k in range(9))

GRID_OFFSETS = tuple((a, b) for a in (0.0, 0.033, 0.066) for b in (0.0, 0.033, 0.066))


#: The most white-standard exposures :func:`simulate_calibration` averages per frame.
MAX_WHITE_REPEATS = 256


def simulate_calibration(device: Device, out_dir: str | Path, seed: int = 0, white_repeats: int = 8) -> Path:
    """Write the calibration captures of ``device`` into ``out_dir`` (atomically).

    * ``white/``: a capture of a Lambertian standard (albedo :data:`WHITE_ALBEDO`),
      every LED and exposure; each frame is the mean of ``white_repeats`` exposures,
      rounded to the ADC range (frame averaging against photon noise);
    * ``grid_*.png``: pinhole-grid images, one per occluder position, with the known
      ray directions in ``calibration.json``;
    * ``mirror_led*.png``: a mirror whose known normal sends each LED into the camera;
    * ``response_t*.png`` (gamma cameras only): an exposure sweep of the white target.

    Parameters
    ----------
    device
        The device (its truth, if any, is what the captures show).
    out_dir
        The calibration folder to create or replace.
    seed
        Seeds the noise.
    white_repeats
        Exposures averaged per white frame.

    Returns
    -------
    Path
        ``out_dir``, ready for :func:`reflecto.instrument.calibrate`.

    Raises
    ------
    ParameterError
        For a negative seed, or ``white_repeats`` not an integer in ``[1, MAX_WHITE_REPEATS]``.
    """
    _check_seed(seed)
    if isinstance(white_repeats, bool) or not isinstance(white_repeats, (int, np.integer)) \
            or not 1 <= white_repeats <= MAX_WHITE_REPEATS:
        raise ParameterError(f"white_repeats must be an integer in [1, {MAX_WHITE_REPEATS}], got "
                             f"{short_repr(white_repeats)}")
    rng = np.random.default_rng(seed)
    optics, leds, intensity, trans = _truth(device)
    cam = device.camera
    lamb = AnalyticBRDF(distribution="ggx", alpha=0.5, kd=WHITE_ALBEDO, ks=0.0)
    shots = [simulate_capture(lamb, device, seed=seed * 1000 + r, tilt_azimuth_deg=0.0) for r in range(white_repeats)]
    mean = np.mean([c.raw.astype(np.float64) for c in shots], axis=0)
    # the times the frames were taken with: auto-exposure may have shortened the camera's (the
    # same for every repeat: one target, one brightest pixel)
    times = np.asarray(shots[0].exposures_ms, dtype=np.float64)
    white = Capture(device.nominal(), np.rint(mean).astype(cam.raw_dtype),
                    times, "white", {"white": {"albedo": WHITE_ALBEDO, "repeats": white_repeats}})
    t_spot = cam.exposures_ms[0]
    amp = 0.6 * cam.full_well / t_spot
    nominal = device.optics
    meta: dict[str, Any] = {"format": "reflecto-calibration-capture", "version": 1,
                            "device": device.nominal().to_dict(), "grid": [], "mirror": []}
    with atomic_dir(out_dir, CALIBRATION_MANIFEST) as tmp:
        write_capture(white, tmp / "white")
        for k, off in enumerate(GRID_OFFSETS):
            d = grid_directions(nominal, off)
            img = expose(_spots(optics, d, amp), t_spot, cam, rng)
            name = f"grid_{k}.png"
            _write_png(tmp / name, img)
            meta["grid"].append({"file": name, "exposure_ms": t_spot, "directions": np.round(d, 12).tolist()})
        for k in range(device.n_leds):
            # the tilt stage turns the mirror so that the nominal LED reflects onto the axis
            m = geometry.normalize(device.leds[k] + nominal.axis)
            r = geometry.reflect(leds[k], m)
            img = expose(_spots(optics, r[None], amp), t_spot, cam, rng)
            name = f"mirror_led{k}.png"
            _write_png(tmp / name, img)
            meta["mirror"].append({"file": name, "led": k, "exposure_ms": t_spot, "mirror_normal": m.tolist()})
        if cam.response == "gamma":
            # exposure sweep of the white target under LED 0 for Debevec–Malik response recovery
            rate = np.zeros((optics.height, optics.width, 3))
            dirs, mask = optics.pixel_directions()
            rate[mask] = cam.sensitivity * (WHITE_ALBEDO / math.pi) * trans[mask][:, None] * intensity[0]
            meta["response"] = []
            for t in RESPONSE_SWEEP_MS:
                name = f"response_t{t:g}ms.png"
                _write_png(tmp / name, expose(rate, t, cam, rng))
                meta["response"].append({"file": name, "exposure_ms": t})
        (tmp / CALIBRATION_MANIFEST).write_text(json.dumps(meta, indent=1))
    return Path(out_dir)
