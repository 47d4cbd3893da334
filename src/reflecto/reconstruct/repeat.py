"""Motion check from repeated frames: the fourth shake cue (beyond the paper).

The device fires its check LEDs once more after the whole sequence (the capture's
``check_leds``, from the device: :data:`reflecto.instrument.device.DEFAULT_CHECK_LEDS`
for the default layout, the first LED fired for
:meth:`~reflecto.instrument.device.Device.design`). If the sample did not move,
a check slice repeats its LED's slice up to camera noise; if the hand turned the
device at any point of the sequence (§5.1's "shaking or moving the device"), the
LED's incidence angle and every view direction changed between the two firings.
The comparison needs no BRDF model and no symmetry, so it also holds for
anisotropic materials, and it sees the matte materials whose slices the other cues
cannot tell from a clean capture (a grazing LED's irradiance ``cos θ_i`` changes by
10 % per half degree at 85°).

For a check LED ``k``, on the pixels valid in both of its frames, with luminance
``Y`` (Rec. 709) of the slice ``a`` and the check slice ``b`` and ``δ = Y_b − Y_a``:

* the global log ratio ``g = log(Σ Y_b / Σ Y_a)`` (an irradiance change), with its
  significance ``z = Σ δ / √(Σ (δ − δ̄)²)`` (about N(0, 1) when the two frames
  differ by independent camera noise alone);
* per block of :data:`BLOCK_PX` × :data:`BLOCK_PX` pixels the same pair,
  ``g_j = log(Σ_j Y_b / Σ_j Y_a)`` and ``z_j`` (a pattern that moved on the sensor: a
  highlight, or the grazing fall-off of a turned view).

The sample moved when the whole frame changed (``|g| >`` :data:`THRESHOLD` and
``|z| >`` :data:`MIN_Z`) or at least :data:`MIN_BLOCKS` blocks did (``|g_j| >``
:data:`BLOCK_THRESHOLD`, ``|z_j| >`` :data:`MIN_Z`). The size thresholds allow for an
LED that does not repeat its output exactly (≈ 0.5 % pulse to pulse for a
current-driven LED; the simulation repeats it exactly); the significance keeps the
noise of dark slices from reading as motion. A slice lit in one firing only (its mean
:data:`MIN_Z` standard errors above 0 in one, not in the other: the LED sank below a
turned sample's horizon) counts as moved when its change exceeds :data:`MIN_Z` times
what two readings' camera noise gives (the noise model of :attr:`Slices.noise`), over
the frame or in :data:`MIN_BLOCKS` blocks, not on one firing's passing that threshold by
noise (:func:`_lit_once`).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numpy.typing import NDArray

from ..colour import LUM
from ..instrument.slices import Slices, finite_rgb
from .tuning import REPEAT

Array = NDArray[np.float64]

# Tuned numbers: what, units and provenance are in :mod:`.tuning` (repeat stage).
BLOCK_PX = REPEAT.block_px
BLOCK_MIN_FILL = REPEAT.block_min_fill
THRESHOLD = REPEAT.threshold
BLOCK_THRESHOLD = REPEAT.block_threshold
MIN_BLOCKS = REPEAT.min_blocks
MIN_Z = REPEAT.min_z


@dataclasses.dataclass(frozen=True)
class RepeatCheck:
    """One check LED's comparison (see the module docstring).

    ``log_ratio`` and ``z`` are the whole frame's ``g`` and ``z``; ``changed_blocks`` of
    ``blocks`` compared changed; ``moved`` is the verdict.
    """

    led: int
    log_ratio: float
    z: float
    changed_blocks: int
    blocks: int
    moved: bool


def _significance(total: Array, spread: Array) -> Array:
    """``Σδ / √(Σ(δ − δ̄)²)``: ∞ for a change without noise, 0 for no change at all."""
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.abs(total) / np.sqrt(spread)
    return np.where(total == 0, 0.0, np.where(spread > 0, z, np.inf))


def _lit(y: Array) -> bool:
    """Whether a slice holds light: ``Σ y > MIN_Z √(Σ (y − ȳ)²)``, its mean :data:`MIN_Z`
    standard errors above 0, so that the camera noise of an LED below the horizon
    (values scattered about 0) reads as dark, not as lit in one firing only."""
    return len(y) > 1 and float(y.sum()) > MIN_Z * math.sqrt(float(np.sum((y - y.mean()) ** 2)))


def _noise_significance(delta: Array, noise: Array) -> float:
    """``|Σ δ| / √(2 Σ σ²)``: the change against two readings' camera noise ``σ`` (one
    channel's standard deviation at each pixel, :attr:`Slices.noise`)."""
    var = 2.0 * float(np.sum(noise * noise))
    total = abs(float(delta.sum()))
    return total / math.sqrt(var) if var > 0 else (math.inf if total > 0 else 0.0)


def _block_sums(blk: NDArray[np.intp], ya: Array, yb: Array, n_blocks: int) -> tuple[Array, Array, Array]:
    """Per block of :data:`BLOCK_PX` × :data:`BLOCK_PX` pixels: pixel count and the sums of ``Y_a`` and ``Y_b``."""
    n = np.bincount(blk, minlength=n_blocks).astype(float)
    sums = (np.bincount(blk, ya, minlength=n_blocks).astype(np.float64),
            np.bincount(blk, yb, minlength=n_blocks).astype(np.float64))  # weighted: float64 (the stub says intp)
    return n, *sums


def _block_log_ratio(ba: Array, bb: Array, total: float, n_used: int) -> Array:
    """``|g_j| = |log(Σ_j Y_b / Σ_j Y_a)|`` of the blocks given, each sum floored at 0 plus
    a millionth of the mean block's share of ``total`` (so an empty block reads 0, not NaN)."""
    eps = 1e-6 * total / max(n_used, 1) + 1e-300
    return np.abs(np.log((np.maximum(bb, 0.0) + eps) / (np.maximum(ba, 0.0) + eps)))


def _lit_once(k: int, ya: Array, yb: Array, delta: Array, blk: NDArray[np.intp], n_blocks: int,
              noise: Array | None) -> RepeatCheck:
    """The check of an LED lit in one firing only: it sank below a turned sample's horizon
    (moved) if the change exceeds what two readings' camera noise ``σ`` allows
    (:attr:`Slices.noise`), over the frame (``|Σ δ| > MIN_Z √(2 Σ σ²)``) or in at least
    :data:`MIN_BLOCKS` blocks (the same per block, and ``|g_j| >`` :data:`BLOCK_THRESHOLD`).

    A slice near the lit test's threshold can pass it in one firing and not in the other
    by noise alone (a 10°-tilted chrome-steel's check LED 3° above its horizon: sums 6.5
    and 8.8 against a threshold of 7.7, the change 0.9 noise standard deviations). The
    spread of ``δ`` is no measure of the noise here: a highlight that left the slice
    changes a few pixels by much, and that is its spread. Without a noise model (a
    gamma camera) lit once counts as moved.
    """
    if noise is None:
        return RepeatCheck(k, math.inf, math.inf, 0, 0, True)
    z = _noise_significance(delta, noise)
    n, ba, bb = _block_sums(blk, ya, yb, n_blocks)
    bvar = np.bincount(blk, 2.0 * noise * noise, minlength=n_blocks)
    use = (n >= BLOCK_MIN_FILL * BLOCK_PX * BLOCK_PX) & (bvar > 0)
    gj = _block_log_ratio(ba[use], bb[use], float(np.abs(ya).sum() + np.abs(yb).sum()), int(use.sum()))
    zj = np.abs(bb[use] - ba[use]) / np.sqrt(bvar[use])
    changed = int(np.count_nonzero((gj > BLOCK_THRESHOLD) & (zj > MIN_Z)))
    moved = z > MIN_Z or changed >= MIN_BLOCKS
    return RepeatCheck(k, math.inf if moved else 0.0, z, changed, int(use.sum()), bool(moved))


def repeat_checks(slices: Slices) -> list[RepeatCheck]:
    """Compare each check slice with its LED's slice; empty when the capture has none."""
    if slices.check_values is None or slices.check_valid is None or not slices.check_leds:
        return []
    rows, cols = slices.pixels[:, 0], slices.pixels[:, 1]
    block = (rows // BLOCK_PX) * (int(cols.max()) // BLOCK_PX + 1) + cols // BLOCK_PX
    n_blocks = int(block.max()) + 1
    out = []
    for c, k in enumerate(slices.check_leds):
        both = (slices.valid[k] & slices.check_valid[c] & finite_rgb(slices.values[k])
                & finite_rgb(slices.check_values[c]))  # a NaN pixel is no evidence
        ya = (slices.values[k] @ LUM)[both]
        yb = (slices.check_values[c] @ LUM)[both]
        blk = block[both]
        sa, sb = float(ya.sum()), float(yb.sum())
        lit_a, lit_b = _lit(ya), _lit(yb)
        if not lit_a and not lit_b:  # dark in both firings (or no pixel valid in both): no evidence
            out.append(RepeatCheck(int(k), 0.0, 0.0, 0, 0, False))
            continue
        delta = yb - ya
        if not (lit_a and lit_b):
            noise = None if slices.noise is None else slices.noise[k][both]
            out.append(_lit_once(int(k), ya, yb, delta, blk, n_blocks, noise))
            continue
        g = math.log(sb / sa)
        z = float(_significance(np.array(delta.sum()), np.array(np.sum((delta - delta.mean()) ** 2))))
        # per block: sums, and the spread of δ about the block's mean
        n, ba, bb = _block_sums(blk, ya, yb, n_blocks)
        bd = bb - ba
        mean = np.divide(bd, n, out=np.zeros_like(bd), where=n > 0)
        spread = np.bincount(blk, (delta - mean[blk]) ** 2, minlength=n_blocks)
        use = (n >= BLOCK_MIN_FILL * BLOCK_PX * BLOCK_PX) & (ba + bb > 0)
        gj = _block_log_ratio(ba[use], bb[use], sa + sb, int(use.sum()))
        zj = _significance(bd[use], spread[use])  # type: ignore[arg-type]  # numpy stub: weighted bincount is float64, not intp
        changed = int(np.count_nonzero((gj > BLOCK_THRESHOLD) & (zj > MIN_Z)))
        moved = (abs(g) > THRESHOLD and z > MIN_Z) or changed >= MIN_BLOCKS
        out.append(RepeatCheck(int(k), g, z, changed, int(use.sum()), bool(moved)))
    return out
