"""The capture folder: raw frames plus a manifest (format in docs/capture-format.md).

A capture is what the device's software writes for one measurement: for every LED
and exposure one raw image (16-bit PNG, RGB, ``height × width``), and
``manifest.json``::

    {"format": "reflecto-capture", "version": 1, "kind": "sample",
     "device": {... nominal device description ...},
     "image": {"width": 320, "height": 240, "channels": 3, "encoding": "png16"},
     "rotation_deg": 0.0,          # the sample's tangent in the device frame (optional)
     "frames": [{"file": "led0_t1.png", "led": 0, "exposure_ms": 1.0}, ...,
                {"file": "led0_t1ms_check.png", "led": 0, "exposure_ms": 1.0, "check": true}],
     "simulation": {...}}          # provenance only; the pipeline never reads it

A sample capture of a device with ``check_leds`` also holds their check frames: the
same LED fired again after the whole sequence, at the same exposures, to detect motion.
``rotation_deg`` is the rotation of the sample about the device's axis, relative to
the device: the azimuth of the sample's tangent in the device frame (degrees,
counter-clockwise seen from above the sample; a device turned by ψ over a fixed
sample records −ψ). Captures of one point at several rotations are reconstructed
together (paper §5.5); absent means 0.

Reading validates everything before any value is used: every frame present and of the
right size, one frame per (LED, exposure) of the device and per (check LED, exposure),
no frame saturated everywhere.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import os
import struct
import sys
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any, NoReturn

import cv2
import numpy as np
from numpy.typing import NDArray

from .. import _kernels
from ..errors import FileFormatError, LimitError, ReflectoError, short_repr, shown_path
from ..io import atomic_folder, inside, read_input, read_json
from .device import MAX_EXPOSURE_MS, Device
from .hdr import SATURATION

_decompressobj: Any = zlib.decompressobj
_crc32: Any = zlib.crc32
_INFLATE_ERRORS: Any = (zlib.error,)
try:  # ISA-L's inflate and CRC: zlib's stream semantics, ≈ 1.5× faster (docs/design/speed.md)
    from isal import isal_zlib

    _decompressobj, _crc32 = isal_zlib.decompressobj, isal_zlib.crc32
    _INFLATE_ERRORS = (isal_zlib.error, zlib.error)
except ImportError:  # pragma: no cover - a platform without its wheels keeps zlib
    pass

CAPTURE_FORMAT = "reflecto-capture"
CAPTURE_VERSION = 1
MANIFEST = "manifest.json"
#: The manifest of a calibration folder (:mod:`reflecto.instrument.calibrate`).
CALIBRATION_MANIFEST = "calibration.json"
#: Largest |rotation_deg| a manifest may state (a few turns; beyond it the number is noise).
MAX_ROTATION_DEG = 3600.0


class CaptureError(ReflectoError):
    """A capture cannot give a valid BRDF (missing frames, saturation, mismatch)."""

    def __init__(self, path: str | Path, problem: str) -> None:
        self.path = Path(path)
        self.problem = problem
        super().__init__(f"{shown_path(self.path)}: {problem}")


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
    rotation_deg
        Rotation of the sample about the device's axis: the azimuth of its tangent in
        the device frame, degrees in ``[0, 360)`` (module docstring).
    """

    device: Device
    raw: NDArray[np.integer]
    exposures_ms: NDArray[np.float64]
    kind: str = "sample"
    extra: dict[str, Any] = dataclasses.field(default_factory=dict)
    path: Path | None = None
    check: NDArray[np.integer] | None = None
    rotation_deg: float = 0.0

    @property
    def n_leds(self) -> int:
        """Number of LEDs ``L`` (first axis of ``raw``)."""
        return self.raw.shape[0]


def frame_name(led: int, exposure_ms: float, check: bool = False, exact: bool = False) -> str:
    """File name a capture gives a frame: ``led{led}_t{exposure}ms[_check].png``.

    Parameters
    ----------
    led
        LED index.
    exposure_ms
        Exposure time (ms), written with ``%g`` (six significant digits), or with
        ``exact`` in full (the shortest text that reads back as the same number): for
        times that ``%g`` writes alike.
    check
        Whether it is a check frame (the LED fired again after the sequence).
    exact
        Write the time in full.

    Returns
    -------
    str
        E.g. ``"led0_t8ms.png"``, ``"led2_t1ms_check.png"``.
    """
    t = _ms(exposure_ms) if exact else f"{exposure_ms:g}"
    return f"led{led}_t{t}ms{'_check' if check else ''}.png"


def expects_check_frames(device: Device, kind: str) -> bool:
    """Whether a capture of ``kind`` by ``device`` has check frames.

    Parameters
    ----------
    device
        The capture's device.
    kind
        ``"sample"`` or a calibration kind.

    Returns
    -------
    bool
        True for sample captures of a device with ``check_leds``.
    """
    return kind == "sample" and bool(device.check_leds)


def _write_png(path: Path, img: NDArray[np.integer]) -> None:
    # OpenCV stores BGR; our arrays are RGB. Encoded in memory and written by Python: OpenCV's
    # own writer takes the name as UTF-8 text (a name of other bytes crashes the process)
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(img[..., ::-1]))
    if not ok:
        raise ReflectoError(f"{shown_path(path)}: could not encode the image")
    Path(path).write_bytes(buf.tobytes())


PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: Largest capture (all frames' pixels, as stored) that is read: docs/limits.md.
MAX_CAPTURE_BYTES = 1 << 30


#: The critical chunks an RGB PNG may hold (PNG spec §4.3; PLTE: a suggested palette).
_CRITICAL_CHUNKS = (b"IHDR", b"PLTE", b"IDAT", b"IEND")


def _png_image_data(data: bytes, path: Path) -> list[bytes]:
    """The IDAT chunks' contents of a PNG whose signature and header were read, after
    checking its chunk structure (PNG spec §5.3, §5.6): every chunk's length and CRC;
    one header (13 bytes), first; no unknown critical chunk (a reader must refuse one);
    the IDAT chunks consecutive; the end chunk present and nothing after it."""
    pos, idat, end, idat_closed = 8, [], False, False
    while pos + 12 <= len(data):
        (length,) = struct.unpack_from(">I", data, pos)
        if length > len(data) - pos - 12:
            break
        (crc,) = struct.unpack_from(">I", data, pos + 8 + length)
        kind = data[pos + 4 : pos + 8]
        if _crc32(data[pos + 4 : pos + 8 + length]) != crc:
            raise CaptureError(path, f"damaged PNG: chunk {kind!r} at byte {pos} fails its CRC")
        if kind == b"IHDR" and (pos != 8 or length != 13):
            raise CaptureError(path, f"damaged PNG: a header chunk at byte {pos} of length {length} "
                               "(one of 13 bytes, first)")
        if not kind[0] & 0x20 and kind not in _CRITICAL_CHUNKS:
            raise CaptureError(path, f"damaged PNG: unknown critical chunk {kind!r} at byte {pos}")
        if kind == b"IDAT":
            if idat_closed:
                raise CaptureError(path, f"damaged PNG: image data chunks not consecutive (byte {pos})")
            idat.append(data[pos + 8 : pos + 8 + length])
        elif idat:
            idat_closed = True
        pos += 12 + length
        if kind == b"IEND":
            end = True
            break
    if not end:
        raise CaptureError(path, "damaged PNG: truncated (no end chunk)")
    if pos != len(data):
        raise CaptureError(path, f"damaged PNG: {len(data) - pos} bytes after the end chunk")
    if not idat:
        raise CaptureError(path, "damaged PNG: no image data")
    return idat


def _adam7_bytes(width: int, height: int, pixel_bytes: int) -> int:
    """The inflated size of an Adam7-interlaced image (PNG spec §8.2): each of the seven
    passes' rows, each one filter byte and its pixels."""
    total = 0
    for x0, y0, dx, dy in ((0, 0, 8, 8), (4, 0, 8, 8), (0, 4, 4, 8), (2, 0, 4, 4), (0, 2, 2, 4), (1, 0, 2, 2),
                           (0, 1, 1, 2)):
        w, h = (width - x0 + dx - 1) // dx, (height - y0 + dy - 1) // dy
        if w > 0 and h > 0:
            total += h * (1 + w * pixel_bytes)
    return total


def _decode_png(data: bytes, path: Path, shape: tuple[int, int], depth_bits: int) -> NDArray[np.integer] | None:
    """Validate and decode an RGB PNG in one pass: the pixels ``(height, width, 3)`` (RGB,
    native uint16 or uint8), or ``None`` for an interlaced file (the caller decodes that).

    Checks, before anything is allocated for the pixels: the header against ``shape``
    and the bit depth (colour type 2, compression and filter method 0), the chunks'
    structure (:func:`_png_image_data`: lengths, CRCs, order, the end chunk last). Then
    the image data is inflated once, bounded to the size of its rows plus one byte (no
    decompression bomb), must hold exactly ``height · (1 + 3 · width · depth/8)`` bytes
    (an interlaced file: its seven passes', :func:`_adam7_bytes`) and nothing after
    its stream's end, and its row filters (types 0–4) are
    undone (:func:`reflecto._kernels.png_unfilter`, the arithmetic of the PNG spec
    §9.2; the 16-bit samples are big-endian). The result is bit-identical to
    OpenCV's ``imdecode(…, IMREAD_UNCHANGED)`` (BGR flipped to RGB), which decodes at
    about the cost of this inflation on top of it.

    A damaged frame is refused naming the file (:class:`CaptureError`).
    """
    if len(data) < 33 or data[:8] != PNG_SIGNATURE or data[12:16] != b"IHDR":
        raise CaptureError(path, "not a readable image (frames are PNG files)")
    width, height, depth, colour, method, filt, interlace = struct.unpack(">IIBBBBB", data[16:29])
    if (height, width) != shape:
        raise CaptureError(path, f"image is {width}×{height}, the manifest says {shape[1]}×{shape[0]}")
    if colour != 2:
        raise CaptureError(path, f"expected an RGB image, got PNG colour type {colour}")
    if depth != depth_bits:
        raise CaptureError(path, f"image has {depth}-bit pixels, expected {depth_bits}-bit")
    if method != 0 or filt != 0 or interlace > 1:
        raise CaptureError(path, f"damaged PNG: unknown compression, filter or interlace method "
                           f"({method}, {filt}, {interlace})")
    idat = _png_image_data(data, path)
    rowbytes = width * 3 * depth // 8
    need = (1 + rowbytes) * height if interlace == 0 else _adam7_bytes(width, height, 3 * depth // 8)
    z = _decompressobj()
    try:
        rows = z.decompress(idat[0] if len(idat) == 1 else b"".join(idat), need + 1)
    except _INFLATE_ERRORS as e:
        raise CaptureError(path, f"damaged PNG: image data does not inflate ({e})") from None
    if len(rows) != need or not z.eof:
        raise CaptureError(path, f"damaged PNG: image data holds {len(rows)}{'+' if not z.eof else ''} bytes, "
                           f"{need} expected")
    if z.unused_data:
        raise CaptureError(path, f"damaged PNG: {len(z.unused_data)} bytes after the end of the image data stream")
    if interlace != 0:
        return None  # Adam7 passes: its size is checked, OpenCV undoes the passes and their filters
    out = np.empty((height, rowbytes), dtype=np.uint8)
    if _kernels.png_unfilter(np.frombuffer(rows, np.uint8), height, rowbytes, 3 * depth // 8, out) >= 0:
        raise CaptureError(path, "damaged PNG: invalid row filter type")
    if depth == 8:
        return out.reshape(height, width, 3)
    return out.view(">u2").reshape(height, width, 3).astype(np.uint16)


@contextlib.contextmanager
def _fd2_silenced() -> Iterator[None]:
    """Send file descriptor 2 to the null device for the block, and restore it after.

    libpng prints ``libpng error: …`` straight to fd 2, past OpenCV's log level and
    Python's ``sys.stderr``; the damaged frame is reflecto's to report, in one line.
    """
    try:
        sys.stderr.flush()
        saved: int | None = os.dup(2)
    except (AttributeError, OSError, ValueError):  # no fd 2 to silence (no, a closed or a replaced stderr)
        saved = None
    if saved is None:
        yield
        return
    try:
        null = os.open(os.devnull, os.O_WRONLY)
        try:
            os.dup2(null, 2)
        finally:
            os.close(null)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def _decode_quietly(data: bytes) -> NDArray[Any] | None:
    """``cv2.imdecode`` without OpenCV's or libpng's own messages on stderr (a damaged file
    is our error to report)."""
    cv_log = getattr(getattr(cv2, "utils", None), "logging", None)
    level = None if cv_log is None else cv_log.getLogLevel()  # None: older OpenCV builds
    if cv_log is not None:
        cv_log.setLogLevel(cv_log.LOG_LEVEL_SILENT)
    try:
        with _fd2_silenced():
            return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    finally:
        if cv_log is not None:
            cv_log.setLogLevel(level)


def read_image(path: Path, shape: tuple[int, int], dtype: type) -> NDArray[np.integer]:
    """Read a 16- or 8-bit RGB PNG; refuse missing, unreadable, special or wrong-size files.

    Returns the pixels, shape ``(height, width, 3)``, RGB, ``dtype``. The PNG header
    (size, bit depth, colour type) is checked against ``shape`` and ``dtype`` before
    the image is decoded, so a header claiming a huge image costs nothing; the file
    itself may be at most twice the size of its pixels plus 1 MiB. Decoded by
    :func:`_decode_png` (interlaced files by OpenCV).

    Parameters
    ----------
    path
        The PNG file.
    shape
        Expected ``(height, width)``.
    dtype
        Expected pixel type: ``np.uint16`` or ``np.uint8``.

    Returns
    -------
    ndarray, shape (height, width, 3)
        The pixels, RGB order, ``dtype``.

    Raises
    ------
    CaptureError
        Naming the file, for a missing, unreadable or mismatched image.
    """

    if not path.exists() and not path.is_symlink():
        raise CaptureError(path, "frame is missing")
    itemsize = np.dtype(dtype).itemsize
    limit = 2 * shape[0] * shape[1] * 3 * itemsize + (1 << 20)
    data = read_input(path, limit, "a frame of this size", missing="frame is missing")
    img = _decode_png(data, path, shape, 8 * itemsize)
    if img is not None:
        return img
    img = _decode_quietly(data)
    if img is None:
        raise CaptureError(path, "not a readable image (damaged PNG)")
    if img.ndim != 3 or img.shape[2] != 3:
        raise CaptureError(path, f"expected an RGB image, got shape {img.shape}")
    if img.shape[:2] != shape:
        raise CaptureError(path, f"image is {img.shape[1]}×{img.shape[0]}, the manifest says {shape[1]}×{shape[0]}")
    if img.dtype != dtype:
        raise CaptureError(path, f"image has {img.dtype} pixels, expected {np.dtype(dtype)}")
    return img[..., ::-1]


def atomic_dir(path: str | Path, marker: str = MANIFEST):
    """Yield a temporary folder beside ``path``; it replaces ``path`` on success.

    See :func:`reflecto.io.atomic_folder`: umask permissions, no folder left on failure,
    and only an empty folder or an earlier output holding ``marker`` is replaced.

    Parameters
    ----------
    path
        The folder to create or replace.
    marker
        The file of an earlier output of the same kind: :data:`MANIFEST` (a capture) or
        :data:`CALIBRATION_MANIFEST` (a calibration folder).

    Returns
    -------
    contextmanager
        Entered, it gives the temporary folder's path.
    """

    return atomic_folder(path, marker)


def _check_writable_capture(capture: Capture, out_dir: Path) -> None:
    """Refuse, before writing, a capture that :func:`read_capture` would refuse for its frames'
    type, shape or range, its exposure times or its rotation."""
    def refuse(problem: str) -> NoReturn:
        raise ReflectoError(f"{shown_path(out_dir)}: not written: {problem}")

    dev, raw = capture.device, np.asarray(capture.raw)
    want = dev.camera.raw_dtype
    if raw.dtype != want:
        refuse(f"the frames must be {np.dtype(want).name} (the camera's {dev.camera.bits}-bit raw values), "
               f"got {raw.dtype}")
    times = np.asarray(capture.exposures_ms, dtype=np.float64)
    if times.ndim != 1 or len(times) == 0 or not np.all(np.isfinite(times)) or not np.all(times > 0):
        refuse(f"exposure times must be finite and > 0 ms, got {short_repr(capture.exposures_ms)}")
    shape = (dev.n_leds, len(times))
    if raw.ndim != 5 or raw.shape[:2] != shape or raw.shape[4] != 3:
        refuse(f"the frames must have shape (LEDs, exposures, height, width, 3) = {shape + ('H', 'W', 3)}, "
               f"got {raw.shape}")
    if raw.size and int(raw.max()) > dev.camera.max_value:
        refuse(f"raw values up to {int(raw.max())} exceed the camera's {dev.camera.max_value}")
    if not (isinstance(capture.rotation_deg, (int, float, np.number)) and math.isfinite(capture.rotation_deg)):
        refuse(f"the rotation must be a finite angle, got {short_repr(capture.rotation_deg)}")


def write_capture(capture: Capture, out_dir: str | Path) -> Path:
    """Write frames and manifest into ``out_dir`` atomically (all or nothing).

    One PNG per LED and exposure (:func:`frame_name`), check frames where the device
    takes them, and ``manifest.json`` (docs/capture-format.md).

    Parameters
    ----------
    capture
        The capture (e.g. from :func:`reflecto.instrument.simulate_capture`).
    out_dir
        The capture folder to create or replace.

    Returns
    -------
    Path
        ``out_dir``.
    """
    out_dir = Path(out_dir)
    dev = capture.device
    _check_writable_capture(capture, out_dir)
    h, w = capture.raw.shape[2:4]
    if expects_check_frames(dev, capture.kind):
        shape = (len(dev.check_leds),) + capture.raw.shape[1:]
        if capture.check is None or capture.check.shape != shape:
            got = None if capture.check is None else capture.check.shape
            raise ReflectoError(f"{out_dir}: the device takes check frames of LEDs {list(dev.check_leds)}: "
                                f"expected check frames of shape {shape}, got {got}")
    frames = []
    # times that %g writes alike (1 and 1.0000001 ms) are named in full: one file per frame
    exact = len({f"{float(t):g}" for t in capture.exposures_ms}) < len(capture.exposures_ms)
    with atomic_dir(out_dir) as tmp:
        for led in range(capture.raw.shape[0]):
            for e, t in enumerate(capture.exposures_ms):
                name = frame_name(led, float(t), exact=exact)
                _write_png(tmp / name, capture.raw[led, e])
                frames.append({"file": name, "led": led, "exposure_ms": float(t)})
        if expects_check_frames(dev, capture.kind):  # shape checked above
            assert capture.check is not None
            for c, led in enumerate(dev.check_leds):
                for e, t in enumerate(capture.exposures_ms):
                    name = frame_name(led, float(t), check=True, exact=exact)
                    _write_png(tmp / name, capture.check[c, e])
                    frames.append({"file": name, "led": led, "exposure_ms": float(t), "check": True})
        manifest = {
            "format": CAPTURE_FORMAT,
            "version": CAPTURE_VERSION,
            "kind": capture.kind,
            "device": dev.nominal().to_dict(),
            "image": {"width": int(w), "height": int(h), "channels": 3, "encoding": f"png{8 * capture.raw.itemsize}"},
            "rotation_deg": float(capture.rotation_deg) % 360.0,
            "frames": frames,
            **capture.extra,
        }
        (tmp / MANIFEST).write_text(json.dumps(manifest, indent=1))
    return out_dir


def read_manifest(cap_dir: Path) -> dict[str, Any]:
    """The manifest of a capture folder, read by the validating JSON loader (docs/capture-format.md).

    Parameters
    ----------
    cap_dir
        The capture folder.

    Returns
    -------
    dict
        The manifest, its ``format`` and ``version`` checked (the rest is checked by
        :func:`read_capture`).

    Raises
    ------
    CaptureError, FileFormatError
        Naming the folder or ``manifest.json``: no folder, no manifest, not a reflecto
        capture manifest, an unsupported version.
    """

    mpath = cap_dir / MANIFEST
    if not cap_dir.is_dir():
        there = cap_dir.exists() or cap_dir.is_symlink()
        raise CaptureError(cap_dir, "not a capture folder (" + ("a file, not a folder" if there
                                                                else "no such directory") + ")")
    if not mpath.exists() and not mpath.is_symlink():
        raise CaptureError(mpath, "manifest is missing")
    m = read_json(inside(cap_dir, MANIFEST, cap_dir, "manifest"), missing="manifest is missing")
    if not isinstance(m, dict) or m.get("format") != CAPTURE_FORMAT:
        raise FileFormatError(mpath, "not a reflecto capture manifest")
    v = m.get("version")
    if not isinstance(v, int) or isinstance(v, bool) or not 1 <= v <= CAPTURE_VERSION:
        raise FileFormatError(mpath, f"capture format version {short_repr(v)} is not supported "
                                     f"(1 to {CAPTURE_VERSION})")
    return m


def _numbers(values: Any) -> str:
    """Numbers for a message, as a user writes them: ``[1, 8]``, not numpy's reprs."""
    return "[" + ", ".join(f"{float(v):g}" for v in values) + "]"


def _frame_key(f: Any, mpath: Path) -> tuple[tuple[int, float, bool], str]:
    """(LED, exposure, check) and file name of one manifest frame entry, types checked."""
    ok = (isinstance(f, dict) and isinstance(f.get("led"), int) and not isinstance(f.get("led"), bool)
          and isinstance(f.get("exposure_ms"), (int, float)) and not isinstance(f.get("exposure_ms"), bool)
          and math.isfinite(f["exposure_ms"]) and isinstance(f.get("check", False), bool)
          and isinstance(f.get("file"), str))
    if not ok:
        raise FileFormatError(mpath, f"invalid frame entry {short_repr(f)} "
                                     "(needs file, led, exposure_ms; check true/false)")
    return (f["led"], float(f["exposure_ms"]), f.get("check", False)), f["file"]


def read_capture(cap_dir: str | Path) -> Capture:
    """Read and validate a capture folder (see the module docstring).

    Everything is checked before pixels are allocated: the manifest's types and
    ranges, the device (:meth:`Device.from_dict`), the frame list against the
    device, every frame name (a plain name inside the folder, also after following
    links), the capture's size (:data:`MAX_CAPTURE_BYTES`) and each PNG header.

    Parameters
    ----------
    cap_dir
        A capture folder (``manifest.json`` and its PNG frames).

    Returns
    -------
    Capture
        Raw frames ``(L, E, H, W, 3)``, exposures (ms), device, kind, rotation and check frames.

    Raises
    ------
    CaptureError, FileFormatError
        Naming the file and the problem.
    """
    cap_dir = Path(cap_dir)
    m = read_manifest(cap_dir)
    mpath = cap_dir / MANIFEST
    try:
        device = Device.from_dict(m["device"], where="device")  # the message below names the file
        img = m["image"]
        if not isinstance(img, dict):
            raise TypeError("'image' must be an object")
        width, height = img["width"], img["height"]
        if not all(isinstance(v, int) and not isinstance(v, bool) for v in (width, height)):
            raise TypeError(f"image width and height must be integers, got {short_repr([width, height])}")
        frames = m["frames"]
        if not isinstance(frames, list):
            raise TypeError("'frames' must be a list")
    except KeyError as e:
        raise FileFormatError(mpath, f"manifest entry missing: {e}") from None
    except (TypeError, ValueError) as e:
        raise FileFormatError(mpath, f"manifest entry invalid ({e})") from None
    if (width, height) != (device.optics.width, device.optics.height):
        raise CaptureError(mpath, f"image size {width}×{height} does not match the device's sensor "
                           f"{device.optics.width}×{device.optics.height}")
    if img.get("channels", 3) != 3:
        raise CaptureError(mpath, f"image channels must be 3 (RGB), got {short_repr(img.get('channels'))}")
    encoding = "png8" if device.camera.bits == 8 else "png16"
    if img.get("encoding", encoding) != encoding:
        raise CaptureError(mpath, f"image encoding {short_repr(img.get('encoding'))} does not fit a "
                           f"{device.camera.bits}-bit camera ({encoding!r})")
    entries = [_frame_key(f, mpath) for f in frames]
    times = np.array(device.camera.exposures_ms)
    if device.camera.auto_exposure:
        # the capture's own times (auto-exposure), as many as the camera takes: the camera's
        # times shortened by one factor (auto-exposure keeps their ratios and never lengthens them)
        own = sorted({t for (_, t, _), _ in entries})
        if len(own) != len(times) or any(not (0 < t <= MAX_EXPOSURE_MS) for t in own):
            raise CaptureError(mpath, f"expected {len(times)} positive exposure times per LED, "
                               f"found {_numbers(own[:10])}")
        factor = np.asarray(own) / times
        if not (np.all(np.abs(factor / factor[0] - 1.0) <= AUTO_EXPOSURE_RATIO_TOLERANCE)
                and factor[0] <= 1.0 + AUTO_EXPOSURE_RATIO_TOLERANCE):
            raise CaptureError(mpath, f"exposure times {_numbers(own)} ms are not the camera's "
                               f"{_numbers(list(times))} ms shortened by one factor (auto-exposure keeps their "
                               "ratios and never lengthens them)")
        times = np.array(own)
    rotation = m.get("rotation_deg", 0.0)
    if (not isinstance(rotation, (int, float)) or isinstance(rotation, bool) or not math.isfinite(rotation)
            or abs(rotation) > MAX_ROTATION_DEG):
        raise FileFormatError(mpath, f"'rotation_deg' must be a finite number of degrees (|r| ≤ {MAX_ROTATION_DEG:g}), "
                              f"got {short_repr(rotation)}")
    kind = m.get("kind", "sample")
    if kind not in CAPTURE_KINDS:  # another kind would pass without the check frames a sample capture has
        raise FileFormatError(mpath, f"'kind' must be one of {', '.join(map(repr, CAPTURE_KINDS))}, "
                              f"got {short_repr(kind)}")
    check_leds = device.check_leds if expects_check_frames(device, kind) else ()
    expected = {(led, float(t), False) for led in range(device.n_leds) for t in times}
    expected |= {(led, float(t), True) for led in check_leds for t in times}
    got: dict[tuple[int, float, bool], str] = {}
    named: dict[str, str] = {}
    for key, name in entries:
        what = f"{'check frame' if key[2] else 'frame'} for LED {key[0]} at {key[1]:g} ms"
        if key not in expected:
            raise CaptureError(mpath, f"{short_repr(name)}: {what} is not part of the device "
                               f"({device.n_leds} LEDs × exposures {_numbers(times)} ms, "
                               f"check LEDs {list(check_leds)})")
        if key in got:
            raise CaptureError(mpath, f"{what} listed twice")
        if Path(name).name != name or name in ("", ".", ".."):
            raise CaptureError(mpath, f"frame file {short_repr(name)} must be a plain name inside the capture folder")
        if name in named:  # one image cannot be two exposures: a copy-paste slip in the manifest
            raise CaptureError(mpath, f"frame file {short_repr(name)} is named for two frames "
                               f"({named[name]} and {what})")
        got[key] = name
        named[name] = what
    missing = sorted(expected - set(got))
    if missing:
        led, t, chk = missing[0]
        raise CaptureError(mpath, f"{len(missing)} frame(s) missing from the manifest, e.g. "
                           f"{'the check frame of ' if chk else ''}LED {led} at {t:g} ms")
    dtype = np.uint8 if device.camera.bits == 8 else np.uint16
    nbytes = len(got) * height * width * 3 * np.dtype(dtype).itemsize
    if nbytes > MAX_CAPTURE_BYTES:
        raise LimitError(mpath, f"the capture's frames hold {nbytes} bytes, more than {MAX_CAPTURE_BYTES} "
                                "(docs/limits.md)")
    paths = {key: inside(cap_dir, name, mpath, "frame file") for key, name in got.items()}
    raw = np.empty((device.n_leds, len(times), height, width, 3), dtype=dtype)
    check = np.empty((len(check_leds), len(times), height, width, 3), dtype=dtype) if check_leds else None
    for (led, t, chk), fpath in paths.items():
        slot = int(np.flatnonzero(times == t)[0])
        img_ = read_image(fpath, (height, width), dtype)
        top = int(img_.max())
        if top > device.camera.max_value:  # a frame of another camera, or one scaled to 16 bits
            raise CaptureError(fpath, f"pixel values up to {top}, above the {device.camera.bits}-bit camera's "
                               f"{device.camera.max_value}")
        if chk:
            check[check_leds.index(led), slot] = img_  # type: ignore[index]
        else:
            raw[led, slot] = img_
    cap = Capture(device, raw, times, kind=kind,
                  extra={k: v for k, v in m.items() if k not in
                         {"format", "version", "kind", "device", "image", "frames", "rotation_deg"}}, path=cap_dir,
                  check=check, rotation_deg=float(rotation) % 360.0)
    check_saturation(cap)
    check_exposures(cap)
    return cap


#: The kinds of capture folder: a sample's (with check frames where the device has check
#: LEDs) and a white standard's (a calibration's radiometry).
CAPTURE_KINDS = ("sample", "white")
#: Relative tolerance of an auto-exposed capture's times against the camera's times times one
#: factor (the simulator rounds them to float32, 6·10⁻⁸; a camera may round to its line time).
AUTO_EXPOSURE_RATIO_TOLERANCE = 1e-3
#: Largest share of a frame's checked view pixels (every :data:`EXPOSURE_CHECK_STRIDE` th) that
#: may read below the black level by more than 8 read-noise standard deviations (at least
#: 4 DN; :func:`check_exposures`): the read noise (≈ 0.6 DN on the default camera) puts none
#: there; a blank frame puts all.
BELOW_BLACK_MAX_FRACTION = 0.05


#: Smallest black-subtracted reading (DN, every channel) of the shorter exposure that
#: :func:`check_exposures` compares: from 32 DN the read noise (≈ 0.6 DN on the
#: default camera) and the quantization move a ratio by under 2 %.
EXPOSURE_CHECK_MIN_DN = 32.0
#: Pixels of an LED (every :data:`EXPOSURE_CHECK_STRIDE` th of the view disc) that
#: :func:`check_exposures` needs before the LED's exposures decide.
EXPOSURE_CHECK_MIN_PIXELS = 50
#: Every 16th pixel: ≈ 2 ms a capture (every 4th: ≈ 5.5 ms, no closer to the ratio).
EXPOSURE_CHECK_STRIDE = 16
#: Largest factor between the frames' brightness ratio and the manifest's exposure
#: ratio: the simulated ideal, as-built and wide-as-built captures of 17 measured
#: materials, steady and shaken, stay within 5.1 % (the selection at the DN floor
#: biases the median low); a factor of 1.5 is 8× that.
EXPOSURE_RATIO_TOLERANCE = 1.5


def check_exposures(cap: Capture) -> None:
    """Refuse a capture whose frames contradict its manifest's exposure times.

    The merge (:mod:`.hdr`) divides each frame by its exposure time, so the times set
    the radiance scale: a time written wrongly gives a wrong model without any other
    sign. On a linear camera the longer of two consecutive exposures reads
    ``t_b / t_a`` times the shorter one where neither is saturated or dark: over every
    :data:`EXPOSURE_CHECK_STRIDE` th pixel of the view disc whose shorter exposure
    reads ≥ :data:`EXPOSURE_CHECK_MIN_DN` in every channel and whose longer one is
    unsaturated, the median of the per-pixel ratio of the channel sums must lie within a
    factor :data:`EXPOSURE_RATIO_TOLERANCE` of ``t_b / t_a``. Every LED's pair of frames
    is compared, and every check LED's, where it has at least
    :data:`EXPOSURE_CHECK_MIN_PIXELS` such pixels (a sharp lobe's dark slices cannot
    tell); and two exposures of an LED that read the same image where it is lit (a frame
    copied over the other, or one file standing for both) are refused whatever their
    brightness. A frame whose checked pixels read below the black level (by more than
    8 read-noise deviations) on more than :data:`BELOW_BLACK_MAX_FRACTION` of them is
    another camera's or damaged. A gamma-encoded camera's response is the merge's to
    recover.

    Parameters
    ----------
    cap
        The capture.

    Raises
    ------
    CaptureError
        Naming the LED, the two exposures and both ratios (or that they are one image).
    """
    cam = cap.device.camera
    t = np.asarray(cap.exposures_ms, dtype=np.float64)
    rows, cols = cap.device.optics.view_pixels()
    rows, cols = rows[::EXPOSURE_CHECK_STRIDE], cols[::EXPOSURE_CHECK_STRIDE]
    # every frame's checked pixels in one gather: (frames of an LED, exposures, pixels, RGB)
    sub = cap.raw[:, :, rows, cols]
    names = [f"LED {led}" for led in range(cap.n_leds)]
    if cap.check is not None:
        sub = np.concatenate([sub, cap.check[:, :, rows, cols]])
        names += [f"LED {led}'s check" for led in cap.device.check_leds]
    # per pixel over the channels by hand: NumPy's reductions over a last axis of 3 are slow
    darkest = np.minimum(np.minimum(sub[..., 0], sub[..., 1]), sub[..., 2])
    if cam.black_level > 0 and len(rows):
        noise_dn = cam.read_noise / cam.gain if cam.response == "linear" else 0.0
        low = (darkest < cam.black_level - max(8.0 * noise_dn, 4.0)).mean(axis=-1)
        k, e = np.unravel_index(int(np.argmax(low)), low.shape)
        if low[k, e] > BELOW_BLACK_MAX_FRACTION:  # a blank or foreign frame: it would merge to negative values
            raise CaptureError(_where(cap), f"{names[k]}: its {_ms(t[e])} ms frame reads below the camera's black "
                               f"level {cam.black_level:g} DN (less its noise) on {100 * low[k, e]:.0f} % of the view "
                               "disc: a frame of another camera, or a damaged one")
    order = np.argsort(t)
    for a, b in zip(order[:-1], order[1:]):
        flat_a, flat_b = sub[:, a].reshape(len(sub), -1), sub[:, b].reshape(len(sub), -1)
        same = (flat_a == flat_b).all(axis=1) & (flat_a.max(axis=1) > cam.black_level)
        if same.any():  # no two exposures of a lit scene read alike, on any camera
            raise CaptureError(_where(cap), f"{names[int(np.argmax(same))]}: its {_ms(t[a])} ms and {_ms(t[b])} ms "
                               "frames are the same image (one file copied over, or standing for, the other)")
    if cam.response != "linear" or len(t) < 2:
        return
    sat = SATURATION * cam.max_value - cam.black_level
    low_z = darkest.astype(np.float64) - cam.black_level
    high_z = np.maximum(np.maximum(sub[..., 0], sub[..., 1]), sub[..., 2]).astype(np.float64) - cam.black_level
    total = sub[..., 0].astype(np.float64) + sub[..., 1] + sub[..., 2] - 3.0 * cam.black_level
    for a, b in zip(order[:-1], order[1:]):
        said = float(t[b] / t[a])
        for j, what in enumerate(names):
            ok = (low_z[j, a] >= EXPOSURE_CHECK_MIN_DN) & (high_z[j, b] < sat)
            if np.count_nonzero(ok) < EXPOSURE_CHECK_MIN_PIXELS:
                continue
            seen = float(np.median(total[j, b][ok] / total[j, a][ok]))
            if not 1.0 / EXPOSURE_RATIO_TOLERANCE <= seen / said <= EXPOSURE_RATIO_TOLERANCE:
                raise CaptureError(_where(cap), f"{what}: its {_ms(t[b])} ms frame reads {seen:.3g}× its "
                                   f"{_ms(t[a])} ms frame (median of {np.count_nonzero(ok)} pixels), but the "
                                   f"manifest's exposure times say {said:.3g}×: the times or the frames are wrong")


def _where(cap: Capture) -> Path:
    """The capture's folder for a message (``<capture>`` for one made in memory)."""
    return cap.path if cap.path is not None else Path("<capture>")


def _ms(t: float) -> str:
    """An exposure time as written (shortest round trip): 8, 1e-300, 1.0000000000000002."""
    text = repr(float(t))
    return text[:-2] if text.endswith(".0") else text


def check_saturation(cap: Capture) -> None:
    """Refuse a capture whose every exposure of some LED is saturated over the view disc.

    A pixel of the nominal optics' view disc (:meth:`Optics.view_pixels`) is saturated
    when its largest channel reads ≥ 0.95 of the ADC range; an LED fails when more than
    99 % of the disc is saturated in each of its exposures.

    Parameters
    ----------
    cap
        The capture.

    Raises
    ------
    CaptureError
        Naming the LED.
    """
    cam = cap.device.camera
    sat = SATURATION * cam.max_value
    rows, cols = cap.device.optics.view_pixels()
    n = max(len(rows), 1)
    for led in range(cap.n_leds):
        frac = [_kernels.count_saturated(cap.raw[led, e], rows, cols, sat) / n for e in range(cap.raw.shape[1])]
        if min(frac) > 0.99:
            raise CaptureError(_where(cap), f"LED {led}: every exposure is saturated over the whole view disc "
                               f"({100 * min(frac):.0f} % of pixels); no BRDF can be measured")
