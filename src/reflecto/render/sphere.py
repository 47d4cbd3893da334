"""A direct NumPy renderer: a sphere under point lights, any BRDF evaluated exactly.

Same camera, lights and sphere as Mitsuba's ``sphere-point`` scene
(:mod:`reflecto.render.mitsuba`), so the two can be compared pixel by pixel: this one
calls ``source.eval`` itself (no tables, no Monte Carlo), which makes it the reference
for checking an exported ``.bsdf`` and a quick way to make the sphere figures of the
validation (paper Fig. 4) without a renderer.

Lighting: a key light up and to the left of the camera (:data:`LIGHT`) lights 87 % of the
visible cap; a fill light at a quarter of its irradiance on the other side of the view
axis (:data:`FILL`, 40° off the axis) lights the rest, so that no visible point of the
sphere is black and its shape reads against the grey background (:data:`BACKGROUND`,
composited by :func:`composite`, never part of the radiance).

Radiance of a visible point ``p`` with normal ``n``: ``L = Σ_l f(ω_l, ω_v) (ω_l·n) I_l / r_l²``
(point lights of intensity ``I_l`` W/sr at distance ``r_l``, no shadowing on a convex
sphere). Pixels average ``supersample²`` stratified positions (a box filter).
Shading frame as Mitsuba's sphere: ``n`` outward, ``t`` along ``∂p/∂φ`` about world z.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from ..brdf import BRDFSource
from ..errors import ParameterError, short_repr

Array = NDArray[np.float64]

CAMERA = (0.0, 0.8, 4.2)
TARGET = (0.0, 0.0, 0.0)
UP = (0.0, 1.0, 0.0)
FOV_DEG = 30.0
#: Key light: position and intensity (W/sr).
LIGHT = (-3.0, 4.0, 4.0)
INTENSITY = 80.0
#: Fill light: 40° from the view axis, opposite the key; a quarter of the key's
#: irradiance at the sphere's centre (80/41 · 35.4 / 4 ≈ 17 W/sr).
FILL = (2.6, -1.9, 5.0)
FILL_INTENSITY = 17.0
#: ``((position, intensity), ...)`` of the point-lit scene.
LIGHTS = ((LIGHT, INTENSITY), (FILL, FILL_INTENSITY))
#: Display-space grey behind the object (linear; 0.18 is sRGB 118/255).
BACKGROUND = 0.18


def camera_rays(resolution: int, supersample: int = 3, origin=CAMERA, target=TARGET, up=UP,
                fov_deg: float = FOV_DEG) -> tuple[Array, Array]:
    """Ray directions ``(res, res, s², 3)`` of a perspective camera (horizontal fov, like Mitsuba).

    Parameters
    ----------
    resolution
        Image width and height, pixels.
    supersample
        ``s``: stratified sub-pixel positions per pixel axis (``s²`` rays per pixel, at the
        centres of an ``s × s`` grid).
    origin, target, up
        Camera position, the point it looks at and its up vector (world coordinates);
        default the scene's :data:`CAMERA`, :data:`TARGET`, :data:`UP`.
    fov_deg
        Field of view, degrees.

    Returns
    -------
    origin : numpy.ndarray, shape (3,)
        The camera position.
    directions : numpy.ndarray, shape (res, res, s², 3)
        Unit ray directions; row 0 is the top of the image, column 0 its left.
    """
    o = np.asarray(origin, float)
    d = np.asarray(target, float) - o
    d /= np.linalg.norm(d)
    left = np.cross(np.asarray(up, float), d)
    left /= np.linalg.norm(left)
    up2 = np.cross(d, left)
    t = math.tan(math.radians(fov_deg) / 2)
    k = (np.arange(supersample) + 0.5) / supersample
    px = (np.arange(resolution)[:, None] + k[None, :]).ravel() / resolution  # sub-pixel u
    u = px.reshape(resolution, supersample)
    uu = u[None, :, None, :] * np.ones((resolution, 1, supersample, 1))  # (row, col, sy, sx)
    vv = u[:, None, :, None] * np.ones((1, resolution, 1, supersample))
    x = (0.5 - uu) * 2 * t  # camera +x is "left" (Mitsuba's look_at)
    y = (0.5 - vv) * 2 * t
    dirs = x[..., None] * left + y[..., None] * up2 + d
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
    return o, dirs.reshape(resolution, resolution, supersample * supersample, 3)


def _hits(resolution: int, supersample: int) -> tuple[Array, Array, NDArray[np.bool_]]:
    """Camera rays, their first intersections with the unit sphere and which ones hit."""
    o, d = camera_rays(resolution, supersample)
    b = d @ o
    c = float(o @ o) - 1.0
    disc = b * b - c
    hit = disc > 0
    tt = -b - np.sqrt(np.where(hit, disc, 0.0))
    hit &= tt > 0
    return d, o + tt[..., None] * d, hit


def sphere_coverage(resolution: int, supersample: int = 8) -> Array:
    """Fraction of each pixel covered by the sphere, ``(res, res)`` (the renders' alpha).

    Parameters
    ----------
    resolution
        Image width and height, pixels.
    supersample
        Sub-pixel positions per pixel axis (``supersample²`` rays per pixel).

    Returns
    -------
    numpy.ndarray, shape (res, res)
        Coverage in ``[0, 1]``: the fraction of a pixel's rays that hit the unit sphere.
    """
    _, _, hit = _hits(resolution, supersample)
    return hit.mean(axis=2)


#: The image sizes :func:`render_sphere` draws (pixels per side), and its sub-pixel rays per axis.
RESOLUTION_RANGE = (8, 4096)
MAX_SUPERSAMPLE = 16


def _check_render(resolution: int, supersample: int, lights) -> None:
    """Refuse sizes and lights that give no image (an empty or NaN one)."""
    def integer(x: object) -> bool:
        return isinstance(x, (int, np.integer)) and not isinstance(x, bool)

    lo, hi = RESOLUTION_RANGE
    if not (integer(resolution) and lo <= resolution <= hi):
        raise ParameterError(f"render: resolution must be an integer in [{lo}, {hi}] pixels, got {resolution!r}")
    if not (integer(supersample) and 1 <= supersample <= MAX_SUPERSAMPLE):
        raise ParameterError(f"render: supersample must be an integer in [1, {MAX_SUPERSAMPLE}], got {supersample!r}")
    for position, intensity in lights:
        pos, power = np.asarray(position, dtype=np.float64), np.asarray(intensity, dtype=np.float64)
        if pos.shape != (3,) or not np.all(np.isfinite(pos)) or not (np.all(np.isfinite(power))
                                                                    and np.all(power >= 0)):
            raise ParameterError(f"render: a light needs a finite position (3-vector) and a finite intensity ≥ 0, "
                                 f"got {short_repr(position)} and {short_repr(intensity)}")


def render_sphere(source: BRDFSource, resolution: int = 256, supersample: int = 3, lights=LIGHTS) -> Array:
    """Linear RGB radiance ``(res, res, 3)`` of a unit sphere at the origin (see module docstring).

    0 off the sphere; ``lights`` is ``((position, intensity W/sr), ...)``.

    ``L = Σ_l f(ω_l, ω_v) (ω_l·n) I_l / r_l²`` at each ray's hit, averaged over the
    pixel's ``supersample²`` rays.

    Parameters
    ----------
    source
        The BRDF (sr⁻¹), evaluated in the sphere's shading frame (``n`` outward, ``t``
        along ``∂p/∂φ`` about world z).
    resolution
        Image width and height, pixels.
    supersample
        Sub-pixel positions per pixel axis.
    lights
        Point lights: world positions and intensities (W/sr); default :data:`LIGHTS`.

    Returns
    -------
    numpy.ndarray, shape (res, res, 3)
        Radiance (W m⁻² sr⁻¹, scene lengths in metres), box-filtered with 0 off the sphere.

    Raises
    ------
    ParameterError
        A resolution outside ``[8, 4096]``, a supersampling outside ``[1, 16]``, or a light
        whose position is not a finite 3-vector or whose intensity is not finite and ≥ 0.
    """
    _check_render(resolution, supersample, lights)
    d, p, hit = _hits(resolution, supersample)
    n = p  # unit sphere
    tang = np.stack([-p[..., 1], p[..., 0], np.zeros(p.shape[:-1])], -1)
    tn = np.linalg.norm(tang, axis=-1, keepdims=True)
    tang = np.where(tn > 1e-9, tang / np.maximum(tn, 1e-12), np.array([1.0, 0.0, 0.0]))
    bit = np.cross(n, tang)

    def local(v: Array) -> Array:
        return np.stack([np.sum(v * tang, -1), np.sum(v * bit, -1), np.sum(v * n, -1)], -1)

    lo = local(-d)
    rad = np.zeros(d.shape[:-1] + (3,))
    for position, intensity in lights:
        lvec = np.asarray(position, float) - p
        r2 = np.sum(lvec * lvec, -1)
        li = local(lvec / np.sqrt(r2)[..., None])
        ok = hit & (li[..., 2] > 0) & (lo[..., 2] > 0)
        if ok.any():
            f = source.eval(li[ok], lo[ok])
            rad[ok] += f * (li[ok][:, 2] * intensity / r2[ok])[:, None]
    return rad.mean(axis=2)


def composite(radiance: Array, alpha: Array, exposure: float = 1.0, background: float = BACKGROUND) -> Array:
    """``exposure·radiance + (1 − α)·background``: the display image of a render (linear).

    ``radiance`` is box-filtered with the background at 0, so an edge pixel already
    holds ``α`` times the object's radiance; the grey does not depend on the exposure.

    Parameters
    ----------
    radiance
        Linear RGB radiance, shape ``(H, W, 3)``.
    alpha
        Coverage of each pixel by the object, shape ``(H, W)`` (:func:`sphere_coverage`).
    exposure
        Factor applied to the radiance.
    background
        Linear grey behind the object.

    Returns
    -------
    numpy.ndarray, shape (H, W, 3)
        The linear display image.
    """
    return exposure * np.asarray(radiance) + (1.0 - np.asarray(alpha))[..., None] * background
