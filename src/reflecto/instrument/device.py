"""Device descriptions: optics, LEDs and camera, nominal and as built.

A :class:`Device` is what the software *believes* about the instrument (nominal
values). The built-in ``as-built`` device also carries a :class:`DeviceTruth` — the
real distortion, principal point, LED directions and intensities and the optical
transmission field — which only the capture simulator reads. The pipeline gets the
nominal device from the capture's manifest and corrects it with what calibration
recovers (:mod:`reflecto.instrument.calibrate`).

Description files are JSON or TOML with the keys of :meth:`Device.to_dict`::

    name = "my-device"
    leds = [[5.0, 0.0], [6.0, 293.3], ...]     # [elevation, azimuth] in degrees
    [optics]   axis_tilt_deg = 20.0 ...         # see Optics
    [camera]   bits = 12 ...                    # see Camera
    [truth]    ...                              # optional, simulation only
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import FileFormatError, ParameterError, short_repr
from ..io import read_description
from .layout import layout_violations, led_direction
from .optics import Optics, optics_from_dict

Array = NDArray[np.float64]

#: The default LED layout ([elevation, azimuth] in degrees): l0 is fixed by §4.1; the
#: other five are the result of :func:`reflecto.instrument.layout.optimize_layout`
#: (seed 0, N=32 grid) for the default optics: coverage after eq. 3, overlaps at
#: different θ_d in the central cap (η of sharp lobes) and near-normal incidence. Its
#: numbers are in docs/instrument.md (81.2 % of the θ_h ≤ 80° cap after eq. 3; the
#: constraints allow at most 87.7 % for any number of LEDs).
DEFAULT_LED_ANGLES = (
    (5.0, 0.0),
    (7.34, 305.77),
    (22.9, 167.71),
    (6.99, 75.82),
    (52.2, 155.42),
    (12.71, 272.66),
)

#: Firing order of the default layout: the highest grazing LED (12.7° elevation) first,
#: the other grazing ones, then the two steep LEDs (52.2° and 22.9°) last
#: (:func:`steep_last_order`). The steep LEDs' slices are the ones whose mirror-symmetry
#: plane can be located (:mod:`reflecto.reconstruct.symmetry`), so a hand shake at any
#: point of the capture turns at least one of them and shows as a plane off the normal
#: (in index order a shake after the 52.2° LED went unseen: 0/11 in
#: studies/validate_shake.py). The first LED is the one fired again as the check frame.
DEFAULT_FIRING_ORDER = (5, 0, 1, 3, 4, 2)

#: LEDs fired once more after the whole sequence: a check frame (both exposures) of the
#: first LED. A clean capture repeats it exactly (up to camera noise); after a shake
#: at any point of the sequence the sample has turned, and the grazing LED's slice
#: changes with its irradiance ``cos θ_i`` (``tan θ_i`` = 4.4 per radian of turn at
#: 77.3° from the normal) and with every view direction (:mod:`reflecto.reconstruct.repeat`:
#: no model needed, anisotropic materials too). Of the grazing LEDs it is the highest:
#: a hand tilt of ``t`` toward the far side lowers an LED by up to ``t``, and the 5–7°
#: LEDs sink below a tilted sample's horizon from 5–7° of tilt on (then both firings
#: are dark and the check tells nothing), the 12.7° LED only beyond 12.7°. It costs two
#: frames: 14 instead of 12, 8.6 instead of 10 captures per second (docs/instrument.md).
DEFAULT_CHECK_LEDS = (DEFAULT_FIRING_ORDER[0],)

#: LEDs at least this high above the sample plane (degrees) count as *steep*: their
#: slices are the ones whose mirror-symmetry plane the shake test can locate
#: (:data:`reflecto.reconstruct.symmetry.MIN_ELEVATION_DEG`).
STEEP_ELEVATION_DEG = 20.0


def steep_last_order(led_angles: Sequence[Sequence[float]]) -> tuple[int, ...]:
    """A firing order derived from the layout: the highest LED below
    :data:`STEEP_ELEVATION_DEG` first (the check frame's LED), the other LEDs below it in
    index order, then the steep ones, the steepest first.

    A hand shake moves the sample for every LED fired after it; with the steep LEDs last,
    any shake turns at least one slice whose mirror plane can be located. The first LED
    is fired again after the sequence (:data:`DEFAULT_CHECK_LEDS`): of the grazing LEDs,
    the highest stays above the horizon of the largest hand tilt (a tilt ``t`` lowers an
    LED by up to ``t``) while its irradiance still changes by ``tan θ_i`` per radian of
    turn. For the default layout this is :data:`DEFAULT_FIRING_ORDER`.

    Parameters
    ----------
    led_angles
        Per LED, ``(elevation, azimuth)`` in degrees.

    Returns
    -------
    tuple of int
        LED indices in firing order.
    """
    el = [float(a[0]) for a in led_angles]
    flat = [k for k in range(len(el)) if el[k] < STEEP_ELEVATION_DEG]
    steep = sorted((k for k in range(len(el)) if el[k] >= STEEP_ELEVATION_DEG), key=lambda k: (-el[k], k))
    if flat:
        first = max(flat, key=lambda k: (el[k], -k))
        flat = [first] + [k for k in flat if k != first]
    return tuple(flat + steep)


#: Limits of device descriptions (docs/limits.md): sensor size, LEDs, exposures.
MAX_SENSOR_SIDE = 4096
MAX_SENSOR_PIXELS = 1 << 22
MAX_LEDS = 32
MAX_EXPOSURES = 8
MAX_EXPOSURE_MS = 1e6


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _number(v: Any, where: str, lo: float = -math.inf, hi: float = math.inf) -> float:
    """``v`` as a float if it is a finite number in [lo, hi]; ParameterError naming ``where``."""
    if not _is_number(v) or not math.isfinite(v) or not lo <= v <= hi:
        rng = "" if (lo, hi) == (-math.inf, math.inf) else f" in [{lo:g}, {hi:g}]"
        raise ParameterError(f"{where} must be a finite number{rng}, got {short_repr(v)}")
    return float(v)


def _integer(v: Any, where: str, lo: int, hi: int) -> int:
    if not isinstance(v, int) or isinstance(v, bool) or not lo <= v <= hi:
        raise ParameterError(f"{where} must be an integer in [{lo}, {hi}], got {short_repr(v)}")
    return v


def _index_list(value: Any, where: str, what: str) -> tuple[int, ...] | None:
    if value is None:
        return None
    if not isinstance(value, (list, tuple)) or len(value) > MAX_LEDS or not all(
            isinstance(k, int) and not isinstance(k, bool) for k in value):
        raise ParameterError(f"{where}: {what} must be a list of LED indices, got {short_repr(value)}")
    return tuple(value)


def _firing_order(value: Any, where: str) -> tuple[int, ...] | None:
    return _index_list(value, where, "firing_order")


def _check_leds(value: Any, where: str) -> tuple[int, ...]:
    return _index_list(value, where, "check_leds") or ()


def _led_angles(value: Any, where: str) -> tuple[tuple[float, float], ...]:
    if not isinstance(value, (list, tuple)) or not 2 <= len(value) <= MAX_LEDS:
        raise ParameterError(f"{where} must be a list of 2 to {MAX_LEDS} [elevation, azimuth] pairs, "
                             f"got {short_repr(value)}")
    out = []
    for k, a in enumerate(value):
        if not isinstance(a, (list, tuple)) or len(a) != 2:
            raise ParameterError(f"{where}[{k}] must be an [elevation, azimuth] pair, got {short_repr(a)}")
        out.append((_number(a[0], f"{where}[{k}] elevation", -90.0, 90.0),
                    _number(a[1], f"{where}[{k}] azimuth", -720.0, 720.0)))
    return tuple(out)


#: Number-valued optics fields and their ranges (the dataclass checks the geometry).
_OPTICS_NUMBERS = {"axis_tilt_deg": (-90.0, 90.0), "axis_azimuth_deg": (-720.0, 720.0),
                   "cone_half_angle_deg": (0.0, 90.0), "disc_radius_px": (1e-3, 1e5), "k1": (-1.0, 1.0),
                   "k2": (-1.0, 1.0), "roll_deg": (-720.0, 720.0)}


def validate_optics_dict(d: Any, where: str) -> Optics:
    """:class:`Optics` from a description dict, every value's type and range checked first.

    Sensor sides must be integers in [8, :data:`MAX_SENSOR_SIDE`] with at most
    :data:`MAX_SENSOR_PIXELS` pixels in all, so that no image allocation follows from
    a hostile size.

    Parameters
    ----------
    d
        The optics description (the keys of :meth:`Optics.to_dict`).
    where
        Where it came from, for messages (``"device.optics"``).

    Returns
    -------
    Optics
        The optics.

    Raises
    ------
    ParameterError
        Naming ``where`` and the key.
    """
    if not isinstance(d, dict):
        raise ParameterError(f"{where} must be a table/object, got {short_repr(d)}")
    for key, (lo, hi) in _OPTICS_NUMBERS.items():
        if key in d:
            _number(d[key], f"{where}.{key}", lo, hi)
    for key in ("focal_px", "cx", "cy"):
        if d.get(key) is not None:
            _number(d[key], f"{where}.{key}", -1e5, 1e5)
    if "law" in d and not isinstance(d["law"], str):
        raise ParameterError(f"{where}.law must be a string, got {short_repr(d['law'])}")
    w = _integer(d.get("width", 320), f"{where}.width", 8, MAX_SENSOR_SIDE)
    h = _integer(d.get("height", 240), f"{where}.height", 8, MAX_SENSOR_SIDE)
    if w * h > MAX_SENSOR_PIXELS:
        raise ParameterError(f"{where}: a {w}×{h} sensor has more than the {MAX_SENSOR_PIXELS} pixels allowed "
                             "(docs/limits.md)")
    return optics_from_dict(dict(d), where)


#: The fewest pixels of a device file's view disc (outside an occluder) that it may have: a
#: slice's mirror plane is located on 1 000 usable pixels, the calibration's grid needs its spots.
MIN_VIEW_PIXELS = 1000
#: The shortest exposure a device file may give (ms): 1 µs.
MIN_EXPOSURE_MS = 1e-3


def _camera(d: Any, where: str) -> Camera:
    if not isinstance(d, dict):
        raise ParameterError(f"{where} must be a table/object, got {short_repr(d)}")
    cfields = {f.name for f in dataclasses.fields(Camera)}
    if set(d) - cfields:
        raise ParameterError(f"{where}: unknown keys {sorted(map(str, set(d) - cfields))}")
    if "bits" in d:
        _integer(d["bits"], f"{where}.bits", 8, 16)
    for key in ("black_level", "full_well", "read_noise", "sensitivity", "gamma"):
        if key in d:
            _number(d[key], f"{where}.{key}", 0.0, 1e12)
    for key in ("shot_noise", "auto_exposure"):
        if key in d and not isinstance(d[key], bool):
            raise ParameterError(f"{where}.{key} must be true or false, got {short_repr(d[key])}")
    if "response" in d and not isinstance(d["response"], str):
        raise ParameterError(f"{where}.response must be a string, got {short_repr(d['response'])}")
    if "exposures_ms" in d:
        t = d["exposures_ms"]
        if not isinstance(t, (list, tuple)) or not 1 <= len(t) <= MAX_EXPOSURES:
            raise ParameterError(f"{where}.exposures_ms must be a list of 1 to {MAX_EXPOSURES} times, "
                                 f"got {short_repr(t)}")
        for k, v in enumerate(t):
            _number(v, f"{where}.exposures_ms[{k}]", MIN_EXPOSURE_MS, MAX_EXPOSURE_MS)
    if d.get("gamma", 1.0) <= 0:
        raise ParameterError(f"{where}.gamma must be > 0")
    if "full_well" in d and d["full_well"] < 1.0:
        raise ParameterError(f"{where}.full_well must hold at least one electron, got {d['full_well']}")
    cam = Camera(**d)
    if cam.read_noise >= cam.full_well:
        raise ParameterError(f"{where}: read_noise {cam.read_noise:g} e⁻ is not below full_well {cam.full_well:g} "
                             "e⁻: such a camera reads noise only")
    return cam


def _truth(t: Any, where: str, n_leds: int) -> DeviceTruth:
    if not isinstance(t, dict) or set(t) != {"optics", "led_angles", "led_intensity", "transmission"}:
        raise ParameterError(f"{where} must have the keys optics, led_angles, led_intensity, transmission")
    angles = _led_angles(t["led_angles"], f"{where}.led_angles")
    if any(el <= 0.0 for el, _ in angles):
        raise ParameterError(f"{where}.led_angles: an LED at or below the sample plane (elevation "
                             f"{min(el for el, _ in angles):g}°) lights nothing")
    inten = t["led_intensity"]
    if not isinstance(inten, (list, tuple)) or len(inten) != n_leds:
        raise ParameterError(f"{where}.led_intensity must list {n_leds} numbers, got {short_repr(inten)}")
    trans = t["transmission"]
    if not isinstance(trans, dict) or set(trans) != {"floor", "u0", "v0", "su", "sv"}:
        raise ParameterError(f"{where}.transmission must have the keys floor, u0, v0, su, sv")
    tr = {k: _number(v, f"{where}.transmission.{k}", -1e5, 1e5) for k, v in trans.items()}
    if not 0 <= tr["floor"] <= 1 or tr["su"] == 0 or tr["sv"] == 0:
        raise ParameterError(f"{where}.transmission: floor must be in [0, 1] and su, sv non-zero")
    return DeviceTruth(optics=validate_optics_dict(t["optics"], f"{where}.optics"), led_angles=angles,
                       led_intensity=tuple(_number(v, f"{where}.led_intensity", 1e-6, 1e6) for v in inten),
                       transmission=tr)


@dataclasses.dataclass(frozen=True)
class Camera:
    """A linear (machine-vision) or gamma-encoded camera.

    Parameters
    ----------
    bits
        ADC bit depth of the raw values (stored in 16-bit images); 8 for ``gamma``.
    black_level
        Raw value of zero light (DN).
    full_well
        Electrons at which a pixel saturates.
    read_noise
        Read noise (electrons RMS); 0 and ``shot_noise=False`` make a noiseless camera.
    shot_noise
        Poisson photon noise on or off.
    exposures_ms
        The exposure times taken per LED (paper §4.3: two, the longest 8 ms).
    sensitivity
        Electrons per millisecond produced by a BRDF value of 1 sr⁻¹ under a unit
        irradiance on the sample plane (transmission 1). With the defaults the short
        exposure saturates at f = 20 sr⁻¹ and the long one at 2.5 sr⁻¹; a diffuse
        f = 0.03 sr⁻¹ still collects 240 e⁻ in the long exposure.
    response
        ``"linear"`` (raw) or ``"gamma"`` (8-bit, ``Z = 255 (x/x_sat)^(1/gamma)``,
        merged by Debevec–Malik).
    auto_exposure
        Shorten the exposures of a capture (keeping their ratios) when its brightest
        pixel would saturate the shortest one, as a camera's auto-exposure from the
        preview stream does: sharp metallic peaks reach f ≈ 10³–10⁴ sr⁻¹. The
        times used are recorded in the capture's manifest.
    """

    bits: int = 12
    black_level: float = 64.0
    full_well: float = 20000.0
    read_noise: float = 3.0
    shot_noise: bool = True
    exposures_ms: tuple[float, ...] = (1.0, 8.0)
    sensitivity: float = 1000.0
    response: str = "linear"
    gamma: float = 2.2
    auto_exposure: bool = True

    def __post_init__(self) -> None:
        object.__setattr__(self, "exposures_ms", tuple(float(t) for t in self.exposures_ms))
        if self.response not in ("linear", "gamma"):
            raise ParameterError(f"camera: response must be 'linear' or 'gamma', got {self.response!r}")
        if not 8 <= self.bits <= 16:
            raise ParameterError(f"camera: bits must be in [8, 16], got {self.bits}")
        if self.response == "gamma" and self.bits != 8:
            raise ParameterError("camera: a gamma-encoded camera has 8 bits")
        if self.response == "gamma" and self.black_level != 0:
            raise ParameterError(f"camera: a gamma-encoded camera has no black level (set black_level 0), got "
                                 f"{self.black_level}")
        if not 0 <= self.black_level < self.max_value / 2:
            raise ParameterError("camera: black level out of range")
        finite = (lambda x: isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x))
        if not (finite(self.full_well) and self.full_well > 0 and finite(self.sensitivity) and self.sensitivity > 0
                and finite(self.read_noise) and self.read_noise >= 0):
            raise ParameterError(f"camera: full_well and sensitivity must be finite and > 0, read_noise finite and "
                                 f">= 0, got {self.full_well}, {self.sensitivity} and {self.read_noise}")
        if self.response == "gamma" and not (finite(self.gamma) and self.gamma > 0):
            raise ParameterError(f"camera: gamma must be finite and > 0, got {self.gamma}")
        if not self.exposures_ms or any(not (t > 0 and math.isfinite(t)) for t in self.exposures_ms):
            raise ParameterError("camera: exposure times must be positive")
        if any(b <= a for a, b in zip(self.exposures_ms, self.exposures_ms[1:])):
            raise ParameterError(f"camera: exposure times must increase, got {list(self.exposures_ms)}")

    @property
    def max_value(self) -> int:
        """Largest raw value, ``2^bits − 1`` (DN)."""
        return (1 << self.bits) - 1

    @property
    def raw_dtype(self) -> type[np.unsignedinteger]:
        """The raw frames' type: ``uint8`` for an 8-bit camera (its PNG frames are 8-bit,
        docs/capture-format.md), ``uint16`` otherwise."""
        return np.uint8 if self.bits == 8 else np.uint16

    @property
    def gain(self) -> float:
        """Electrons per DN (linear camera)."""
        return self.full_well / (self.max_value - self.black_level)

    @property
    def noiseless(self) -> bool:
        """Whether the camera adds no noise (no shot noise and zero read noise)."""
        return not self.shot_noise and self.read_noise == 0


@dataclasses.dataclass(frozen=True)
class DeviceTruth:
    """What the as-built device really is (simulation only; never read by the pipeline).

    Parameters
    ----------
    optics
        Real optics (distortion, principal point, roll).
    led_angles
        Real LED [elevation, azimuth] in degrees, shape ``(L, 2)``.
    led_intensity
        Real LED irradiance relative to nominal, shape ``(L,)``.
    transmission
        Smooth transmission/vignetting field: ``T = floor + (1 − floor)·exp(−((u−u0)/su)²
        − ((v−v0)/sv)²)``, keys ``floor, u0, v0, su, sv``.
    """

    optics: Optics
    led_angles: tuple[tuple[float, float], ...]
    led_intensity: tuple[float, ...]
    transmission: dict[str, float]

    def transmission_field(self) -> Array:
        """The transmission field at every pixel centre.

        Returns
        -------
        ndarray, shape (height, width)
            ``T = floor + (1 − floor)·exp(−((u−u0)/su)² − ((v−v0)/sv)²)``, in [floor, 1].
        """
        t = self.transmission
        v, u = np.mgrid[0 : self.optics.height, 0 : self.optics.width].astype(np.float64)
        g = np.exp(-(((u - t["u0"]) / t["su"]) ** 2) - ((v - t["v0"]) / t["sv"]) ** 2)
        return t["floor"] + (1.0 - t["floor"]) * g

    @property
    def leds(self) -> Array:
        """Real LED directions (unit vectors, device frame), shape ``(L, 3)``."""
        return led_direction(*np.asarray(self.led_angles, dtype=np.float64).T)

    def to_dict(self) -> dict[str, Any]:
        """The truth as JSON-ready data.

        Returns
        -------
        dict
            Keys ``optics``, ``led_angles``, ``led_intensity``, ``transmission``.
        """
        return {
            "optics": self.optics.to_dict(),
            "led_angles": [list(a) for a in self.led_angles],
            "led_intensity": list(self.led_intensity),
            "transmission": dict(self.transmission),
        }


@dataclasses.dataclass(frozen=True)
class Device:
    """A condenser reflectometer: optics, LEDs, camera (nominal) and optional truth."""

    name: str
    optics: Optics
    led_angles: tuple[tuple[float, float], ...]
    camera: Camera
    truth: DeviceTruth | None = None
    #: Views within this angle of the optical axis are blocked (an LED in the light
    #: path, as in the earlier device of Dong et al. 2010); LEDs there are allowed.
    occluder_deg: float = 0.0
    #: The order in which the LEDs fire (LED indices); ``None``: index order. Only a
    #: capture's timing depends on it: a hand shake moves the sample for the LEDs
    #: fired after it (see :data:`DEFAULT_FIRING_ORDER`).
    firing_order: tuple[int, ...] | None = None
    #: LEDs fired again after the whole sequence (check frames, see
    #: :data:`DEFAULT_CHECK_LEDS`); a sample capture holds one frame per check LED and
    #: exposure besides the sequence's.
    check_leds: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        angles = tuple(tuple(float(x) for x in a) for a in self.led_angles)
        object.__setattr__(self, "led_angles", angles)
        if len(angles) < 2 or any(len(a) != 2 for a in angles):
            raise ParameterError("device: leds must be a list of at least two [elevation, azimuth] pairs")
        if not all(math.isfinite(x) for a in angles for x in a):
            raise ParameterError("device: LED angles must be finite")
        if not (math.isfinite(self.occluder_deg) and 0.0 <= self.occluder_deg < self.optics.cone_half_angle_deg):
            raise ParameterError(f"device: occluder_deg must be in [0, cone half-angle), got {self.occluder_deg}")
        bad = layout_violations(self.optics, self.leds, self.occluder_deg)
        if bad:
            raise ParameterError("device: " + "; ".join(bad))
        if self.truth is not None and len(self.truth.led_angles) != len(angles):
            raise ParameterError("device: truth has a different number of LEDs")
        if self.firing_order is not None:
            order = tuple(int(k) for k in self.firing_order)
            if sorted(order) != list(range(len(angles))):
                raise ParameterError(f"device: firing_order must list each of the {len(angles)} LED indices once, "
                                     f"got {list(order)}")
            object.__setattr__(self, "firing_order", order)
        check = tuple(int(k) for k in self.check_leds)
        if any(not 0 <= k < len(angles) for k in check) or len(set(check)) != len(check):
            raise ParameterError(f"device: check_leds must list distinct LED indices in [0, {len(angles)}), "
                                 f"got {list(check)}")
        object.__setattr__(self, "check_leds", check)

    @property
    def order(self) -> tuple[int, ...]:
        """LED indices in firing order."""
        return self.firing_order if self.firing_order is not None else tuple(range(self.n_leds))

    @property
    def leds(self) -> Array:
        """Nominal LED directions, shape ``(L, 3)``."""
        return led_direction(*np.asarray(self.led_angles, dtype=np.float64).T)

    @property
    def n_leds(self) -> int:
        """Number of LEDs ``L``."""
        return len(self.led_angles)

    @property
    def led_irradiance(self) -> Array:
        """Nominal LED irradiance normal to each beam, shape ``(L,)``.

        The LED drive currents are designed so that every LED gives the same unit
        irradiance on the sample plane (``E_l cos θ_l = 1``): grazing LEDs are driven
        harder, so all slices use the camera's range alike.
        """
        return 1.0 / np.sin(np.radians([a[0] for a in self.led_angles]))

    def occluded(self, view_dirs: Array) -> NDArray[np.bool_]:
        """Views blocked by the occluder (within :attr:`occluder_deg` of the optical axis).

        Parameters
        ----------
        view_dirs : ndarray, shape (..., 3)
            Unit view directions in the device frame.

        Returns
        -------
        ndarray of bool, shape (...)
            True where the view is blocked (all False without an occluder).
        """
        if self.occluder_deg <= 0:
            return np.zeros(np.shape(view_dirs)[:-1], bool)
        return view_dirs @ self.optics.axis > math.cos(math.radians(self.occluder_deg))

    def nominal(self) -> Device:
        """This device without its truth: what the pipeline may know.

        Returns
        -------
        Device
            A copy with ``truth=None``.
        """
        return dataclasses.replace(self, truth=None)

    def to_dict(self, with_truth: bool = False) -> dict[str, Any]:
        """The device description as JSON-ready data (the keys of a device file; docs/instrument.md).

        Parameters
        ----------
        with_truth
            Also write the hidden imperfections (``truth``) of an as-built device.

        Returns
        -------
        dict
            ``name``, ``optics``, ``leds`` ([elevation, azimuth] in degrees), ``camera``, and
            ``occluder_deg``, ``firing_order``, ``check_leds`` where set; what
            ``Device.from_dict`` reads back.
        """
        d: dict[str, Any] = {
            "name": self.name,
            "optics": self.optics.to_dict(),
            "leds": [list(a) for a in self.led_angles],
            "camera": dataclasses.asdict(self.camera),
        }
        d["camera"]["exposures_ms"] = list(self.camera.exposures_ms)
        if self.occluder_deg > 0:
            d["occluder_deg"] = self.occluder_deg
        if self.firing_order is not None:
            d["firing_order"] = list(self.firing_order)
        if self.check_leds:
            d["check_leds"] = list(self.check_leds)
        if with_truth and self.truth is not None:
            d["truth"] = self.truth.to_dict()
        return d

    # ------------------------------------------------------------- factories
    @classmethod
    def from_dict(cls, d: dict[str, Any], where: str = "device") -> Device:
        """A device from its description dict; every entry's type and range is checked.

        See :func:`validate_optics_dict` and the limits in docs/limits.md.

        Parameters
        ----------
        d
            The keys of :meth:`to_dict` (each optional: defaults are the ``ideal`` device's).
        where
            Where it came from, for messages.

        Returns
        -------
        Device
            The device.

        Raises
        ------
        ParameterError
            Naming ``where`` and the entry.
        """
        known = {"name", "optics", "leds", "camera", "truth", "occluder_deg", "firing_order", "check_leds"}
        if not isinstance(d, dict):
            raise ParameterError(f"{where}: expected a table/object")
        if set(d) - known:
            raise ParameterError(f"{where}: unknown keys {sorted(map(str, set(d) - known))}")
        name = d.get("name", "custom")
        if not isinstance(name, str) or len(name) > 200:
            raise ParameterError(f"{where}.name must be a string of at most 200 characters, got {short_repr(name)}")
        optics = validate_optics_dict(d.get("optics", {}), f"{where}.optics")
        camera = _camera(d.get("camera", {}), f"{where}.camera")
        angles = _led_angles(d.get("leds", DEFAULT_LED_ANGLES), f"{where}.leds")
        truth = _truth(d["truth"], f"{where}.truth", len(angles)) if "truth" in d else None
        if truth is not None and (truth.optics.width, truth.optics.height) != (optics.width, optics.height):
            raise ParameterError(f"{where}.truth.optics: the sensor is {truth.optics.width}×{truth.optics.height}, "
                                 f"the device's {optics.width}×{optics.height}: a device's imperfections do not "
                                 "change its sensor")
        sensors = [(optics, f"{where}.optics")] + ([(truth.optics, f"{where}.truth.optics")] if truth else [])
        occluder = _number(d.get("occluder_deg", 0.0), f"{where}.occluder_deg", 0.0, 90.0)
        for o, w in sensors:
            if not len(o.view_pixels()[0]):
                raise ParameterError(f"{w}: no pixel of the sensor lies in the view cone (check disc_radius_px, "
                                     "cx, cy): such a device sees nothing")
            dirs, mask = o.pixel_directions()
            seen = int(np.count_nonzero(dirs[mask] @ o.axis <= math.cos(math.radians(occluder))) if occluder > 0
                       else np.count_nonzero(mask))
            if seen < MIN_VIEW_PIXELS:
                raise ParameterError(f"{w}: {seen} pixels see the sample (the view cone, outside the occluder), "
                                     f"fewer than {MIN_VIEW_PIXELS}: too few views to calibrate or reconstruct")
        return cls(
            name=name,
            optics=optics,
            led_angles=angles,
            camera=camera,
            truth=truth,
            occluder_deg=occluder,
            firing_order=_firing_order(d.get("firing_order"), where),
            check_leds=_check_leds(d.get("check_leds"), where),
        )

    @classmethod
    def builtin(cls, name: str) -> Device:
        """A built-in device by name (:data:`BUILTINS`); a device file is read by :func:`load_device`.

        Parameters
        ----------
        name
            ``"ideal"`` (the paper's design, nominal optics, noiseless camera),
            ``"as-built"`` (the same design with seeded LED, optics and vignetting errors
            and camera noise), ``"earlier"`` (the [DWT*10] baseline layout), ``"wide"``
            (the design study's 60° cone about a 20° axis, ideal optics) or
            ``"wide-as-built"`` (``wide`` with the as-built errors).

        Returns
        -------
        Device

        Raises
        ------
        ParameterError
            For another name (a file's path among them: use :func:`load_device`).
        """
        if name == "ideal":
            return cls("ideal", Optics(), DEFAULT_LED_ANGLES, Camera(read_noise=0.0, shot_noise=False),
                       firing_order=DEFAULT_FIRING_ORDER, check_leds=DEFAULT_CHECK_LEDS)
        if name == "as-built":
            return cls("as-built", Optics(), DEFAULT_LED_ANGLES, Camera(), truth=_as_built_truth(),
                       firing_order=DEFAULT_FIRING_ORDER, check_leds=DEFAULT_CHECK_LEDS)
        if name == "earlier":
            return cls("earlier", Optics(axis_tilt_deg=0.0), EARLIER_LED_ANGLES,
                       Camera(read_noise=0.0, shot_noise=False), occluder_deg=EARLIER_OCCLUDER_DEG)
        if name in ("wide", "wide-as-built"):
            return cls.design(name, WIDE_OPTICS, WIDE_LED_ANGLES, ideal=name == "wide")
        raise ParameterError(f"unknown built-in device {name!r} (expected one of {', '.join(BUILTINS)}; "
                             "read a device file with load_device(path))")

    @classmethod
    def design(cls, name: str, optics: Optics, led_angles: Sequence[Sequence[float]], ideal: bool = True) -> Device:
        """A device of another optical design with the built-in devices' conventions.

        The firing order is :func:`steep_last_order`; the first LED fired is fired once
        more as the check frame. ``ideal``: nominal optics and a noiseless camera, as
        ``ideal``; otherwise the as-built imperfections of ``as-built`` (the same seeded
        draws of LED, optics and vignetting errors), scaled to these optics.

        Parameters
        ----------
        name
            The device's name.
        optics
            The optical design.
        led_angles
            Per LED, ``(elevation, azimuth)`` in degrees.
        ideal
            Nominal optics and a noiseless camera (else as-built imperfections).

        Returns
        -------
        Device
            The device.
        """
        angles = tuple((float(a[0]), float(a[1])) for a in led_angles)
        order = steep_last_order(angles)
        camera = Camera(read_noise=0.0, shot_noise=False) if ideal else Camera()
        truth = None if ideal else _as_built_truth(angles, optics)
        return cls(name, optics, angles, camera, truth=truth, firing_order=order, check_leds=(order[0],))

    def with_camera(self, **changes: Any) -> Device:
        """The same device with some camera fields replaced.

        Parameters
        ----------
        **changes
            :class:`Camera` fields and their new values (e.g. ``read_noise=0``).

        Returns
        -------
        Device
            A new device; this one is unchanged.
        """
        return dataclasses.replace(self, camera=dataclasses.replace(self.camera, **changes))


def _as_built_truth(led_angles: Sequence[Sequence[float]] = DEFAULT_LED_ANGLES,
                    optics: Optics | None = None) -> DeviceTruth:
    """Fixed imperfections of an as-built device (seeded, so every run agrees).

    The defaults are the ``as-built`` device's; another layout and optics (``wide``) get
    the same draws: LED direction errors up to ±0.5°, intensities in [0.85, 1.15], the
    principal point, distortion, roll and vignetting of ``as-built``.
    """
    rng = np.random.default_rng(2010)
    n = len(led_angles)
    # direction errors of up to ±0.5° in elevation and azimuth (azimuth scaled to arc)
    d_el = rng.uniform(-0.5, 0.5, n)
    d_az = rng.uniform(-0.5, 0.5, n)
    angles = []
    for (el, az), a, b in zip(led_angles, d_el, d_az):
        el2 = max(el + a, 4.6)
        angles.append((round(el2, 4), round(az + b / math.cos(math.radians(el2)), 4)))
    intensity = tuple(np.round(rng.uniform(0.85, 1.15, n), 4))
    real = (optics or Optics()).replace(cx=163.2, cy=116.9, k1=-0.06, k2=0.015, roll_deg=0.7, disc_radius_px=112.0)
    return DeviceTruth(
        optics=real,
        led_angles=tuple(angles),
        led_intensity=intensity,
        transmission={"floor": 0.5, "u0": 150.0, "v0": 128.0, "su": 170.0, "sv": 150.0},
    )


#: The earlier device (Dong et al. 2010, "[DWT*10]"), reconstructed from Lan et al.'s
#: description (§1, §6.2): the condenser on the normal; one LED in the light path on the
#: axis, which blocks the central views; sparse LEDs just outside the view cone, so
#: that the slices see only the central NDF region (θ_h ≲ 50°). See docs/validation.md.
EARLIER_LED_ANGLES = ((90.0, 0.0), (35.0, 0.0), (35.0, 72.0), (35.0, 144.0), (35.0, 216.0), (35.0, 288.0))
EARLIER_OCCLUDER_DEG = 8.0
#: The ``wide`` device: the best realisable design of the condenser design study
#: (docs/design-study.md, ``reflecto design``; chosen on the tuning half, the design
#: ``c60.0-t20.0-l10``): a 60° cone (NA 0.87) about an axis tilted 20°, whose views reach
#: θ_o = 80°, so that the specular peak is seen up to θ_d = 79° (eq. 10's grazing cut is
#: 80°); ten LEDs placed by :func:`reflecto.instrument.layout.optimize_layout` with the
#: study's weights (22 frames, 0.18 s per capture).
WIDE_OPTICS = Optics(cone_half_angle_deg=60.0, axis_tilt_deg=20.0)
WIDE_LED_ANGLES = (
    (5.0, 0.0),
    (6.7657, 87.142),
    (32.9653, 212.9443),
    (10.7112, 173.0997),
    (7.2392, 308.7996),
    (42.8177, 202.2664),
    (13.6589, 217.2527),
    (10.8129, 297.0548),
    (19.3728, 146.0542),
    (29.0568, 131.7786),
)
BUILTINS = ("ideal", "as-built", "earlier", "wide", "wide-as-built")


def load_device(spec: str | Path) -> Device:
    """A built-in device by name or a JSON/TOML description file.

    Parameters
    ----------
    spec
        One of :data:`BUILTINS` (``ideal``, ``as-built``, ``earlier``, ``wide``,
        ``wide-as-built``) or the path of a device file (docs/instrument.md).

    Returns
    -------
    Device
        The device.

    Raises
    ------
    FileFormatError
        For a missing or invalid device file.
    ParameterError
        For an empty ``spec``.
    """
    if str(spec) in BUILTINS:
        return Device.builtin(str(spec))
    if not str(spec).strip():  # Path("") is "." (the current folder): name the empty argument instead
        raise ParameterError(f"the device is empty; give one of {', '.join(BUILTINS)} or a device file")
    path = Path(spec)
    d = read_description(path, missing=f"no such device file (built-ins: {', '.join(BUILTINS)})")
    try:
        return Device.from_dict(d, where="device")  # the FileFormatError below names the file
    except (ParameterError, TypeError, ValueError) as e:
        raise FileFormatError(path, str(e)) from None

