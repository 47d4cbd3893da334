"""HDR merge of the exposures of each LED (paper §4.3, algorithm-reference §7.1).

* Linear (raw) camera — black-subtracted, exposure-normalised average
  ``E = Σ_j w_j (Z_j − Z_black)/t_j / Σ_j w_j`` with ``w_j = t_j`` (photon-noise
  optimal) and zero weight for saturated (``Z ≥ 0.95 Z_max``) or near-black pixels
  (``Z − Z_black`` below :data:`DARK_DN`), except that the longest unsaturated exposure
  always keeps its weight, so dark-but-valid pixels measure ≈ 0 instead of a hole.
  Pixels that read 0 or 1 DN in that exposure are also reported (``black``): on a
  camera whose read noise does not dither its quantization (below :data:`DITHER_DN`
  DN RMS) a signal under half a DN rounds to 0 every time and one up to 1.5 DN to 1,
  so their values are bounds, not measurements
  (:attr:`~reflecto.instrument.slices.Slices.censored`; :data:`BLACK_DN`). Rounded
  values of 2 DN or more stay: their rounding errors average out over pixels.
* Gamma-encoded 8-bit camera — Debevec–Malik response recovery and merge (OpenCV's
  ``CalibrateDebevec`` / ``MergeDebevec``), the response kept in the calibration.

Output: radiance in DN/ms (linear) or response units/ms (gamma), shape
``(L, H, W, 3)``, and the validity mask ``(L, H, W)`` (False where every exposure is
saturated).
"""

from __future__ import annotations

from typing import Literal, overload

import cv2
import numpy as np
from numpy.typing import NDArray

from .. import _kernels
from ..colour import LUM
from .device import Camera

Array = NDArray[np.float64]

#: Raw values this close to the black level (DN) count as near-black.
DARK_DN = 4.0
#: Read noise (DN) from which the quantization counts as dithered (near-black values
#: unbiased on average, so kept).
DITHER_DN = 0.5
#: A reading below this (DN, black-subtracted) in every channel — 0 or 1 DN — is no
#: measurement on an undithered quantizer, only a bound: 0 means a signal under half a
#: DN, 1 anything in [0.5, 1.5), and once the zeros are set aside the ones that remain
#: are biased high (in the tail of a k_d = 0 lobe, where the signal fades through a
#: DN, they read ≈ 2× the signal). From 2 DN on the rounding error is ≤ 25 % and the
#: selection bias small.
BLACK_DN = 1.5
#: Fraction of the ADC range above which a raw value counts as saturated.
SATURATION = 0.95


@overload
def merge_linear_pixels(
    raw: NDArray[np.integer], exposures_ms: Array, camera: Camera, rows: NDArray[np.intp], cols: NDArray[np.intp],
    noise: Literal[False] = False,
) -> tuple[Array, NDArray[np.bool_], NDArray[np.bool_]]: ...
@overload
def merge_linear_pixels(
    raw: NDArray[np.integer], exposures_ms: Array, camera: Camera, rows: NDArray[np.intp], cols: NDArray[np.intp],
    noise: Literal[True],
) -> tuple[Array, NDArray[np.bool_], NDArray[np.bool_], Array, Array]: ...
def merge_linear_pixels(
    raw: NDArray[np.integer], exposures_ms: Array, camera: Camera, rows: NDArray[np.intp], cols: NDArray[np.intp],
    noise: bool = False,
) -> (tuple[Array, NDArray[np.bool_], NDArray[np.bool_]]
      | tuple[Array, NDArray[np.bool_], NDArray[np.bool_], Array, Array]):
    """Linear merge at the pixels ``(rows, cols)`` only: radiance ``(L, P, 3)``, valid
    and black masks ``(L, P)`` (black: the value rests on the longest usable exposure
    alone, which read below :data:`BLACK_DN` — 0 or 1 DN — in every channel); with
    ``noise``, also the noise model's standard deviation of the merged luminance
    (:func:`merge_noise`, DN/ms, ``(L, P)``) and the summed exposure time (ms, ``(L, P)``).

    A pixel is saturated if any channel is, so colour ratios stay unbiased.
    (Weights ``w_j = t_j`` make the merge ``Σ_j signal_j / Σ_j t_j`` over the used
    exposures.)

    Parameters
    ----------
    raw : ndarray, shape (L, E, H, W, 3)
        Raw frames (DN).
    exposures_ms : ndarray, shape (E,)
        Exposure times, ms.
    camera
        Black level and ADC range (saturation), noise model.
    rows, cols : ndarray of intp, shape (P,)
        The pixels to merge.
    noise
        Also return the noise model's standard deviation and the summed exposure time.

    Returns
    -------
    radiance : ndarray, shape (L, P, 3)
        DN/ms above black.
    valid : ndarray of bool, shape (L, P)
        Some exposure of the pixel is usable (unsaturated in every channel).
    black : ndarray of bool, shape (L, P)
        The value rests on a near-black longest exposure.
    noise_sd : ndarray, shape (L, P)
        Only with ``noise``: standard deviation of the merged luminance, DN/ms.
    t_sum : ndarray, shape (L, P)
        Only with ``noise``: summed exposure time of the used exposures, ms.
    """
    if raw.ndim != 5 or raw.shape[-1] != 3:
        raise ValueError(f"raw frames must have shape (L, E, H, W, 3), got {raw.shape}")
    t = np.ascontiguousarray(exposures_ms, dtype=np.float64)
    n = len(rows)
    out = np.empty((raw.shape[0], n, 3))
    valid = np.empty((raw.shape[0], n), dtype=bool)
    near_black = np.empty((raw.shape[0], n), dtype=bool)
    t_sum = np.empty((raw.shape[0], n))
    n_used = np.empty((raw.shape[0], n))
    _kernels.merge_linear(
        np.ascontiguousarray(raw), np.ascontiguousarray(rows, dtype=np.intp), np.ascontiguousarray(cols, dtype=np.intp),
        t, float(camera.black_level), SATURATION * camera.max_value, DARK_DN, BLACK_DN, out, valid, near_black,
        t_sum, n_used,
    )  # fmt: skip
    if not noise:
        return out, valid, near_black
    return out, valid, near_black, merge_noise(out, t_sum, n_used, camera), t_sum


def merge_noise(radiance: Array, t_sum: Array, n_used: Array, camera: Camera) -> Array:
    """Standard deviation (DN/ms) of a merged luminance, from the camera's noise model.

    ``Σ_j s_j / Σ_j t_j`` over ``n`` used exposures has the variance
    ``(n (r² + 1/12) + L Σt / g) / (Σt)²``: read noise ``r`` (DN RMS, per exposure),
    the uniform quantization error of 1 DN (1/12 DN², also on a noiseless camera) and
    the photon shot noise of the ``L Σt`` collected DN (variance ``DN / g`` for ``g``
    electrons per DN).

    Parameters
    ----------
    radiance : ndarray, shape (L, P, 3)
        Merged radiance, DN/ms.
    t_sum : ndarray, shape (L, P)
        Summed exposure time of the used exposures, ms.
    n_used : ndarray, shape (L, P)
        Number of used exposures.
    camera
        Read noise, gain and whether shot noise is simulated.

    Returns
    -------
    ndarray, shape (L, P)
        Standard deviation of the merged luminance, DN/ms.
    """

    read_dn = camera.read_noise / camera.gain
    lum = np.maximum(radiance @ LUM, 0.0)
    t_sum = np.asarray(t_sum, dtype=np.float64)
    n_used = np.asarray(n_used, dtype=np.float64)
    if lum.ndim != 2 or t_sum.shape != lum.shape or n_used.shape != lum.shape:
        var = n_used * (read_dn * read_dn + 1.0 / 12.0)
        if camera.shot_noise:
            var = var + lum * t_sum / camera.gain
        return np.sqrt(var) / np.maximum(t_sum, 1e-300)
    out = np.empty(lum.shape)  # the expression above in one compiled pass
    _kernels.merge_noise_sd(lum, t_sum, n_used, read_dn * read_dn + 1.0 / 12.0, float(camera.gain),
                            bool(camera.shot_noise), out)
    return out


def dithered(camera: Camera) -> bool:
    """Whether the camera's read noise dithers its quantization.

    Parameters
    ----------
    camera
        The camera.

    Returns
    -------
    bool
        Read noise ≥ :data:`DITHER_DN` DN RMS.
    """
    return camera.read_noise / camera.gain >= DITHER_DN


def merge_linear(raw: NDArray[np.integer], exposures_ms: Array, camera: Camera) -> tuple[Array, NDArray[np.bool_]]:
    """Merge raw exposures of a linear camera, every pixel (:func:`merge_linear_pixels`).

    Parameters
    ----------
    raw : ndarray, shape (L, E, H, W, 3)
        Raw frames (DN).
    exposures_ms : ndarray, shape (E,)
        Exposure times, ms.
    camera
        The camera.

    Returns
    -------
    radiance : ndarray, shape (L, H, W, 3)
        DN/ms above black.
    valid : ndarray of bool, shape (L, H, W)
        Pixels with a usable exposure.
    """
    h, w = raw.shape[2:4]
    rows, cols = np.divmod(np.arange(h * w), w)
    out, valid, _ = merge_linear_pixels(raw, exposures_ms, camera, rows, cols)
    return out.reshape(raw.shape[0], h, w, 3), valid.reshape(raw.shape[0], h, w)


def recover_response(
    raw: NDArray[np.uint8], exposures_ms: Array, samples: int = 150, window: tuple[slice, slice] | None = None
) -> Array:
    """Debevec–Malik inverse response (linear units per 8-bit level), shape ``(256, 3)``.

    ``raw`` has shape ``(N, E, H, W, 3)``: N scenes (e.g. the white target under each
    LED) with E exposures each. OpenCV samples pixels on a regular grid, so ``window``
    (rows, cols) restricts it to the lit part of the image.

    Parameters
    ----------
    raw : ndarray of uint8, shape (N, E, H, W, 3)
        The exposure sweeps.
    exposures_ms : ndarray, shape (E,)
        Exposure times, ms.
    samples
        Pixels OpenCV samples.
    window
        ``(rows, cols)`` slices of the lit region, or None for the whole image.

    Returns
    -------
    ndarray, shape (256, 3)
        Inverse response per 8-bit level and RGB channel (relative linear units; OpenCV's
        ``CalibrateDebevec`` with the times in seconds).
    """

    cal = cv2.createCalibrateDebevec(samples=samples, lambda_=10.0, random=False)
    t = (np.asarray(exposures_ms, dtype=np.float32) / 1000.0).astype(np.float32)
    # the scenes are tiled side by side into one image per exposure: one system, and
    # OpenCV's sampling grid spans the levels of every scene
    imgs = []
    for e in range(raw.shape[1]):
        tiles = [(scene[e] if window is None else scene[e][window]) for scene in raw]
        imgs.append(np.ascontiguousarray(np.concatenate(tiles, axis=1)[..., ::-1]))
    return cal.process(imgs, t).reshape(256, 3)[:, ::-1].astype(np.float64)


def merge_debevec(raw: NDArray[np.integer], exposures_ms: Array, response: Array) -> tuple[Array, NDArray[np.bool_]]:
    """Merge 8-bit gamma exposures ``(L, E, H, W, 3)`` with a recovered response.

    Unlike OpenCV's ``MergeDebevec`` (whose hat weight is never zero, so clipped pixels
    leak in — algorithm-reference §7.1), clipped (255) and black (0) levels get zero
    weight here; the hat weight is per channel.

    Parameters
    ----------
    raw : ndarray, shape (L, E, H, W, 3)
        8-bit raw frames.
    exposures_ms : ndarray, shape (E,)
        Exposure times, ms.
    response : ndarray, shape (256, 3)
        Inverse response (:func:`recover_response`).

    Returns
    -------
    radiance : ndarray, shape (L, H, W, 3)
        Weighted mean of ``response[z]/t`` over the exposures.
    valid : ndarray of bool, shape (L, H, W)
        Pixels with weight in every channel.
    """
    z = raw.astype(np.intp)
    lev = np.arange(256, dtype=np.float64)
    hat = np.minimum(lev, 255.0 - lev)
    hat[[0, 255]] = 0.0
    t = np.asarray(exposures_ms, dtype=np.float64)
    resp = np.asarray(response, dtype=np.float64)
    lin = np.stack([resp[z[..., c], c] for c in range(3)], axis=-1)  # (L, E, H, W, 3)
    sat = z.max(axis=-1) >= 254
    w = hat[z] * (~sat)[..., None]
    num = np.sum(w * lin / t[None, :, None, None, None], axis=1)
    wsum = w.sum(axis=1)
    valid = np.all(wsum > 0, axis=-1)
    radiance = np.divide(num, wsum, out=np.zeros_like(num), where=wsum > 0)
    return radiance, valid
