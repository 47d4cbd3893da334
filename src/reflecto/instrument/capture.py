"""The capture folder: raw frames plus a manifest (format in docs/capture-format.md).

A capture is what the device's software writes for one measurement: for every LED
and exposure one raw image (16-bit PNG, RGB, ``height × width``), and
``manifest.json``::

    {"format": "reflecto-capture", "version": 1, "kind": "sample",
     "device": {... nominal device description ...},
     "image": {"width": 320, "height": 240, "channels": 3, "encoding": "png16"},
     "frames": [{"file": "led0_t1.png", "led": 0, "exposure_ms": 1.0}, ...,
                {"file": "led0_t1ms_check.png", "led": 0, "exposure_ms": 1.0, "check": true}],
     "simulation": {...}}          # provenance only; the pipeline never reads it

A sample capture of a device with ``check_leds`` also holds their check frames: the
same LED fired again after the whole sequence, at the same exposures, to detect motion.
Reading validates everything before any value is used: every frame present and of the
right size, one frame per (LED, exposure) of the device and per (check LED, exposure),
no frame saturated everywhere.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from ..errors import FileFormatError, ReflectoError
from .device import Device

CAPTURE_FORMAT = "reflecto-capture"
CAPTURE_VERSION = 1
MANIFEST = "manifest.json"


class CaptureError(ReflectoError):
    """A capture cannot give a valid BRDF (missing frames, saturation, mismatch)."""

    def __init__(self, path: str | Path, problem: str) -> None:
        self.path = Path(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


@dataclasses.dataclass
class Capture:
    """Raw frames of one measurement.

    Attributes
    ----------
    device
        The nominal device (from the manifest).
    raw
        Raw images, shape ``(L, E, height, width, 3)``, uint16 (uint8 for gamma cameras).
    exposures_ms
        Exposure time of each exposure slot, shape ``(E,)``.
    kind
        ``"sample"`` or a calibration kind.
    check
        Check frames of ``device.check_leds`` (sample captures), shape
        ``(C, E, height, width, 3)``, or ``None`` when the device takes none.
    extra
        Further manifest entries (``simulation`` provenance, calibration targets).
    """

    device: Device
    raw: NDArray[np.integer]
    exposures_ms: NDArray[np.float64]
    kind: str = "sample"
    extra: dict[str, Any] = dataclasses.field(default_factory=dict)
    path: Path | None = None
    check: NDArray[np.integer] | None = None

    @property
    def n_leds(self) -> int:
        return self.raw.shape[0]


def frame_name(led: int, exposure_ms: float, check: bool = False) -> str:
    return f"led{led}_t{exposure_ms:g}ms{'_check' if check else ''}.png"


def expects_check_frames(device: Device, kind: str) -> bool:
    """Check frames belong to sample captures of a device that takes them."""
    return kind == "sample" and bool(device.check_leds)


def _write_png(path: Path, img: NDArray[np.integer]) -> None:
    # OpenCV stores BGR; our arrays are RGB
    if not cv2.imwrite(str(path), np.ascontiguousarray(img[..., ::-1])):
        raise ReflectoError(f"{path}: could not write image")


def read_image(path: Path, shape: tuple[int, int], dtype: type) -> NDArray[np.integer]:
    """Read a 16- or 8-bit RGB PNG/TIFF; refuse missing, unreadable or wrong-size files."""
    if not path.exists():
        raise CaptureError(path, "frame is missing")
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise CaptureError(path, "not a readable image")
    if img.ndim != 3 or img.shape[2] != 3:
        raise CaptureError(path, f"expected an RGB image, got shape {img.shape}")
    if img.shape[:2] != shape:
        raise CaptureError(path, f"image is {img.shape[1]}×{img.shape[0]}, the manifest says {shape[1]}×{shape[0]}")
    if img.dtype != dtype:
        raise CaptureError(path, f"image has {img.dtype} pixels, expected {np.dtype(dtype)}")
    return img[..., ::-1]


@contextlib.contextmanager
def atomic_dir(path: str | Path):  # type: ignore[no-untyped-def]
    """Yield a temporary folder beside ``path``; it replaces ``path`` on success."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".part", dir=path.parent))
    try:
        yield tmp
        if path.exists():
            old = path.with_name(f".{path.name}.old")
            shutil.rmtree(old, ignore_errors=True)
            os.replace(path, old)
            os.replace(tmp, path)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, path)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def write_capture(capture: Capture, out_dir: str | Path) -> Path:
    """Write frames and manifest into ``out_dir`` atomically (all or nothing)."""
    out_dir = Path(out_dir)
    dev = capture.device
    h, w = capture.raw.shape[2:4]
    if expects_check_frames(dev, capture.kind):
        shape = (len(dev.check_leds),) + capture.raw.shape[1:]
        if capture.check is None or capture.check.shape != shape:
            got = None if capture.check is None else capture.check.shape
            raise ReflectoError(f"{out_dir}: the device takes check frames of LEDs {list(dev.check_leds)}: "
                                f"expected check frames of shape {shape}, got {got}")
    frames = []
    with atomic_dir(out_dir) as tmp:
        for led in range(capture.raw.shape[0]):
            for e, t in enumerate(capture.exposures_ms):
                name = frame_name(led, float(t))
                _write_png(tmp / name, capture.raw[led, e])
                frames.append({"file": name, "led": led, "exposure_ms": float(t)})
        if expects_check_frames(dev, capture.kind):  # shape checked above
            for c, led in enumerate(dev.check_leds):
                for e, t in enumerate(capture.exposures_ms):
                    name = frame_name(led, float(t), check=True)
                    _write_png(tmp / name, capture.check[c, e])
                    frames.append({"file": name, "led": led, "exposure_ms": float(t), "check": True})
        manifest = {
            "format": CAPTURE_FORMAT,
            "version": CAPTURE_VERSION,
            "kind": capture.kind,
            "device": dev.nominal().to_dict(),
            "image": {"width": int(w), "height": int(h), "channels": 3, "encoding": f"png{8 * capture.raw.itemsize}"},
            "frames": frames,
            **capture.extra,
        }
        (tmp / MANIFEST).write_text(json.dumps(manifest, indent=1))
    return out_dir


def read_manifest(cap_dir: Path) -> dict[str, Any]:
    mpath = cap_dir / MANIFEST
    if not cap_dir.is_dir():
        raise CaptureError(cap_dir, "not a capture folder (no such directory)")
    if not mpath.exists():
        raise CaptureError(mpath, "manifest is missing")
    try:
        m = json.loads(mpath.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise FileFormatError(mpath, f"not valid JSON ({e})") from None
    if not isinstance(m, dict) or m.get("format") != CAPTURE_FORMAT:
        raise FileFormatError(mpath, "not a reflecto capture manifest")
    if not isinstance(m.get("version"), int) or m["version"] > CAPTURE_VERSION:
        raise FileFormatError(mpath, f"capture format version {m.get('version')!r} is not supported (<= {CAPTURE_VERSION})")
    return m


def read_capture(cap_dir: str | Path) -> Capture:
    """Read and validate a capture folder (see the module docstring)."""
    cap_dir = Path(cap_dir)
    m = read_manifest(cap_dir)
    mpath = cap_dir / MANIFEST
    try:
        device = Device.from_dict(m["device"], where=f"{mpath}: device")
        img = m["image"]
        width, height = int(img["width"]), int(img["height"])
        frames = list(m["frames"])
    except (KeyError, TypeError, ValueError) as e:
        raise FileFormatError(mpath, f"manifest entry missing or invalid ({e})") from None
    if (width, height) != (device.optics.width, device.optics.height):
        raise CaptureError(mpath, f"image size {width}×{height} does not match the device's sensor "
                           f"{device.optics.width}×{device.optics.height}")
    times = np.array(device.camera.exposures_ms)
    if device.camera.auto_exposure:
        # the capture's own times (auto-exposure), as many as the camera takes
        try:
            own = sorted({float(f["exposure_ms"]) for f in frames})
        except (KeyError, TypeError, ValueError):
            raise FileFormatError(mpath, "invalid frame entry (exposure_ms)") from None
        if len(own) != len(times) or any(not (t > 0 and np.isfinite(t)) for t in own):
            raise CaptureError(mpath, f"expected {len(times)} positive exposure times per LED, found {own}")
        times = np.array(own)
    kind = str(m.get("kind", "sample"))
    check_leds = device.check_leds if expects_check_frames(device, kind) else ()
    expected = {(led, float(t), False) for led in range(device.n_leds) for t in times}
    expected |= {(led, float(t), True) for led in check_leds for t in times}
    got: dict[tuple[int, float, bool], str] = {}
    for f in frames:
        try:
            key = (int(f["led"]), float(f["exposure_ms"]), bool(f.get("check", False)))
            name = str(f["file"])
        except (AttributeError, KeyError, TypeError, ValueError):
            raise FileFormatError(mpath, f"invalid frame entry {f!r}") from None
        what = f"{'check frame' if key[2] else 'frame'} for LED {key[0]} at {key[1]:g} ms"
        if key not in expected:
            raise CaptureError(mpath, f"{name}: {what} is not part of the device "
                               f"({device.n_leds} LEDs × exposures {list(times)}, check LEDs {list(check_leds)})")
        if key in got:
            raise CaptureError(mpath, f"{what} listed twice")
        if Path(name).name != name:
            raise CaptureError(mpath, f"frame file {name!r} must be a plain name inside the capture folder")
        got[key] = name
    missing = sorted(expected - set(got))
    if missing:
        led, t, chk = missing[0]
        raise CaptureError(mpath, f"{len(missing)} frame(s) missing from the manifest, e.g. "
                           f"{'the check frame of ' if chk else ''}LED {led} at {t:g} ms")
    dtype = np.uint8 if device.camera.bits == 8 else np.uint16
    raw = np.empty((device.n_leds, len(times), height, width, 3), dtype=dtype)
    check = np.empty((len(check_leds), len(times), height, width, 3), dtype=dtype) if check_leds else None
    for (led, t, chk), name in got.items():
        e = int(np.flatnonzero(times == t)[0])
        img = read_image(cap_dir / name, (height, width), dtype)
        if chk:
            check[check_leds.index(led), e] = img  # type: ignore[index]
        else:
            raw[led, e] = img
    cap = Capture(device, raw, times, kind=kind,
                  extra={k: v for k, v in m.items() if k not in
                         {"format", "version", "kind", "device", "image", "frames"}}, path=cap_dir, check=check)
    check_saturation(cap)
    return cap


def check_saturation(cap: Capture) -> None:
    """Refuse a capture whose every exposure of some LED is saturated over the view disc."""
    cam = cap.device.camera
    sat = 0.95 * cam.max_value
    dirs_mask = cap.device.optics.pixel_directions()[1]
    for led in range(cap.n_leds):
        frac = [(cap.raw[led, e][dirs_mask].max(axis=-1) >= sat).mean() for e in range(cap.raw.shape[1])]
        if min(frac) > 0.99:
            where = cap.path if cap.path is not None else Path("<capture>")
            raise CaptureError(where, f"LED {led}: every exposure is saturated over the whole view disc "
                               f"({100 * min(frac):.0f} % of pixels); no BRDF can be measured")
