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
  sample's BRDF is then ``f = L / s`` (algorithm-reference eq. 7.3). The field is
  smoothed by normalized convolution to average out photon noise.
"""

from __future__ import annotations

import dataclasses
import io
import json
import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy import ndimage
from scipy.optimize import least_squares

from .. import geometry
from ..errors import FileFormatError
from ..io import atomic_write
from .capture import CaptureError, read_capture, read_image
from .device import Device
from .hdr import merge_debevec, merge_linear, recover_response
from .optics import Optics

Array = NDArray[np.float64]

CALIBRATION_FORMAT = "reflecto-calibration"
CALIBRATION_VERSION = 1
#: σ (pixels) of the smoothing applied to the radiometric field.
FIELD_SMOOTHING_PX = 3.0


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
        """Pixel directions ``(H, W, 3)``, cone mask, its ``rows, cols`` and the scale
        at those pixels ``(L, P, 3)`` (cached: computed once per calibration)."""
        cached = self.__dict__.get("_geom")
        if cached is None:
            dirs, mask = self.optics.pixel_directions()
            rows, cols = np.nonzero(mask)
            cached = (dirs, mask, rows, cols, self.scale[:, rows, cols].astype(np.float64))
            self.__dict__["_geom"] = cached
        return cached

    def save(self, path: str | Path) -> Path:
        """Write an ``.npz`` calibration file atomically."""
        meta = {
            "format": CALIBRATION_FORMAT,
            "version": CALIBRATION_VERSION,
            "device": self.device.to_dict(),
            "optics": self.optics.to_dict(),
            "leds": self.leds.tolist(),
            "report": self.report,
        }
        arrays = {"scale": self.scale.astype(np.float32), "meta": np.frombuffer(json.dumps(meta).encode(), np.uint8)}
        if self.response is not None:
            arrays["response"] = self.response
        buf = io.BytesIO()
        np.savez_compressed(buf, **arrays)
        with atomic_write(path) as fh:
            fh.write(buf.getvalue())
        return Path(path)

    @classmethod
    def load(cls, path: str | Path) -> Calibration:
        path = Path(path)
        try:
            with np.load(path, allow_pickle=False) as z:
                meta = json.loads(bytes(z["meta"]).decode("utf-8"))
                scale = z["scale"]
                response = z["response"] if "response" in z.files else None
        except FileNotFoundError:
            raise FileFormatError(path, "no such calibration file") from None
        except (OSError, ValueError, KeyError, UnicodeDecodeError, EOFError) as e:
            raise FileFormatError(path, f"not a reflecto calibration file or damaged ({e})") from None
        if meta.get("format") != CALIBRATION_FORMAT:
            raise FileFormatError(path, "not a reflecto calibration file")
        if not isinstance(meta.get("version"), int) or meta["version"] > CALIBRATION_VERSION:
            raise FileFormatError(path, f"calibration format version {meta.get('version')!r} not supported")
        try:
            device = Device.from_dict(meta["device"])
            optics = Optics(**meta["optics"])
            leds = np.asarray(meta["leds"], dtype=np.float64)
        except Exception as e:  # noqa: BLE001 — any inconsistency is a damaged file
            raise FileFormatError(path, f"invalid calibration contents ({e})") from None
        expect = (device.n_leds, optics.height, optics.width, 3)
        if scale.shape != expect or leds.shape != (device.n_leds, 3):
            raise FileFormatError(path, f"scale field has shape {scale.shape}, expected {expect}")
        if not np.all(np.isfinite(scale)):
            raise FileFormatError(path, "scale field contains NaN or infinity")
        return cls(device, optics, leds, scale, response, meta.get("report", {}))


def nominal_calibration(device: Device) -> Calibration:
    """The calibration implied by the nominal device (no measurement): ideal optics,
    nominal LEDs, scale ``sensitivity/gain · E_l cos θ_l = sensitivity/gain`` everywhere."""
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


# ------------------------------------------------------------------ geometry
def detect_spots(img: NDArray[np.integer], black: float, min_peak: float) -> Array:
    """Intensity-weighted centroids ``(u, v)`` of bright spots in a raw image."""
    lum = img.astype(np.float64).mean(axis=-1) - black
    mask = lum > 0.2 * max(float(lum.max()), min_peak)
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


def fit_optics(nominal: Optics, directions: Array, spots: list[Array]) -> tuple[Optics, dict[str, float]]:
    """Fit f, principal point, k1, k2 and roll to spot centroids of known directions.

    ``directions[k]`` (shape ``(M_k, 3)``) are the rays of image ``k``, ``spots[k]``
    the detected centroids (any order). Spots are matched to rays by nearest predicted
    position, first in the central part of the image (where distortion is small) and
    then everywhere, refitting in between.
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
        pairs_d, pairs_s = np.concatenate(pd), np.concatenate(ps)
        if len(pairs_d) < 12:
            raise CaptureError(Path("<grid>"), f"only {len(pairs_d)} pinhole spots matched; cannot calibrate geometry")

        def resid(q: Array) -> Array:
            return (_optics_with(nominal, q).direction_to_pixel(pairs_d) - pairs_s).ravel()

        p = least_squares(resid, p, method="lm", x_scale=[10.0, 1.0, 1.0, 0.01, 0.01, 0.1]).x
    r = _optics_with(nominal, p).direction_to_pixel(pairs_d) - pairs_s
    rms = float(np.sqrt(np.mean(np.sum(r * r, axis=1))))
    return _optics_with(nominal, p), {"spots_used": int(len(pairs_d)), "reprojection_rms_px": rms}


# --------------------------------------------------------------- the whole job
def calibrate(calib_dir: str | Path, progress: bool = False) -> Calibration:
    """Run geometric, LED and radiometric calibration on a calibration folder."""
    calib_dir = Path(calib_dir)
    mpath = calib_dir / "calibration.json"
    if not mpath.exists():
        raise CaptureError(mpath, "calibration.json is missing (not a calibration folder)")
    try:
        meta = json.loads(mpath.read_text(encoding="utf-8"))
        device = Device.from_dict(meta["device"], where=str(mpath))
        grid, mirror = list(meta["grid"]), list(meta["mirror"])
    except (json.JSONDecodeError, UnicodeDecodeError, KeyError, TypeError) as e:
        raise FileFormatError(mpath, f"invalid calibration manifest ({e})") from None
    cam, nominal = device.camera, device.optics
    shape = (nominal.height, nominal.width)
    dtype = np.uint8 if cam.bits == 8 else np.uint16
    black = 0.0 if cam.response == "gamma" else cam.black_level
    min_peak = 0.05 * (cam.max_value - black)
    # geometry
    dirs, spots = [], []
    for g in grid:
        img = read_image(calib_dir / g["file"], shape, dtype)
        dirs.append(np.asarray(g["directions"], dtype=np.float64))
        spots.append(detect_spots(img, black, min_peak))
    optics, geo_report = fit_optics(nominal, dirs, spots)
    # LED directions from the mirror
    leds = device.leds.copy()
    for m in mirror:
        img = read_image(calib_dir / m["file"], shape, dtype)
        s = detect_spots(img, black, min_peak)
        if len(s) != 1:
            raise CaptureError(calib_dir / m["file"], f"expected one mirror spot, found {len(s)}")
        o = optics.pixel_to_direction(s[0])
        leds[int(m["led"])] = geometry.reflect(o, np.asarray(m["mirror_normal"], dtype=np.float64))
    # radiometry
    white = read_capture(calib_dir / "white")
    albedo = float(white.extra.get("white", {}).get("albedo", 0.0))
    if not 0 < albedo <= 1:
        raise FileFormatError(calib_dir / "white" / "manifest.json", "white target albedo missing or not in (0, 1]")
    response = None
    if cam.response == "gamma":
        sweep = meta.get("response") or []
        if len(sweep) < 3:
            raise FileFormatError(mpath, "a gamma camera needs an exposure sweep ('response', >= 3 frames)")
        frames = np.stack([read_image(calib_dir / f["file"], shape, dtype) for f in sweep])[None]
        cx, cy = optics.principal_point
        half = int(0.7 * optics.f * np.sin(np.radians(optics.cone_half_angle_deg)))
        win = (slice(max(int(cy) - half, 0), int(cy) + half), slice(max(int(cx) - half, 0), int(cx) + half))
        response = recover_response(frames, np.array([f["exposure_ms"] for f in sweep]), window=win)
        rad, valid = merge_debevec(white.raw, white.exposures_ms, response)
    else:
        rad, valid = merge_linear(white.raw, white.exposures_ms, cam)
    _, mask = optics.pixel_directions()
    scale = np.empty(rad.shape, dtype=np.float32)
    for k in range(device.n_leds):
        ok = (valid[k] & mask).astype(np.float64)
        sm_w = ndimage.gaussian_filter(ok, FIELD_SMOOTHING_PX, mode="nearest")
        for c in range(3):
            sm = ndimage.gaussian_filter(rad[k, ..., c] * ok, FIELD_SMOOTHING_PX, mode="nearest")
            field = np.divide(sm, sm_w, out=np.zeros_like(sm), where=sm_w > 1e-3)
            scale[k, ..., c] = field / (albedo / math.pi)
    led_err = np.degrees(np.arccos(np.clip(np.sum(leds * device.leds, axis=1), -1, 1)))
    report = {"kind": "measured", **geo_report, "led_offset_from_nominal_deg": np.round(led_err, 3).tolist(),
              "white_albedo": albedo}
    return Calibration(device.nominal(), optics, leds, scale, response, report)


def load_calibration(path: str | Path | None, device: Device) -> Calibration:
    """A calibration file, or the nominal calibration of ``device`` when ``path`` is None.

    Refuses a calibration made for a different device design.
    """
    if path is None:
        return nominal_calibration(device)
    cal = Calibration.load(path)
    if cal.device.n_leds != device.n_leds or cal.device.camera != device.camera:
        raise FileFormatError(path, f"calibration is for device {cal.device.name!r}, which does not match "
                              f"the capture's device {device.name!r}")
    return cal
