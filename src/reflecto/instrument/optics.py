"""Condenser optics: view direction ↔ camera pixel (paper §4.1, algorithm-reference §10).

The sample point sits at the front focal point of the condenser pair, so every ray
leaving it at angle θ' from the optical axis reaches the sensor at a radius that
depends only on θ' (the *radial law*), at the ray's own azimuth about the axis:

* ``sine``        r = f sin θ'   (Abbe sine condition, aplanatic condenser; default)
* ``tan``         r = f tan θ'   (paraxial thin lens)
* ``equidistant`` r = f θ'

followed by radial distortion of the normalized radius ρ = r/f,
``ρ_d = ρ (1 + k1 ρ² + k2 ρ⁴)``, and the principal point ``(cx, cy)``:
``u = cx + f ρ_d cos φ'``, ``v = cy + f ρ_d sin φ'``.

Frames: the sample normal is +z of the *device* frame. The optical axis is tilted by
``axis_tilt_deg`` from +z towards azimuth ``axis_azimuth_deg``; ``roll_deg`` turns
the sensor about the axis. Pixel centres are at integer coordinates (u = column,
v = row), the sensor is ``width × height``.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import ParameterError

Array = NDArray[np.float64]

LAWS = ("sine", "tan", "equidistant")


def _law(name: str, theta: Array) -> Array:
    if name == "sine":
        return np.sin(theta)
    if name == "tan":
        return np.tan(theta)
    return theta


def _law_inverse(name: str, rho: Array) -> Array:
    if name == "sine":  # ρ = sin θ: beyond 1 (+ rounding) no direction maps there
        return np.where(np.abs(rho) <= 1.0 + 1e-12, np.arcsin(np.clip(rho, -1.0, 1.0)), np.nan)
    if name == "tan":
        return np.arctan(rho)
    return rho


@dataclasses.dataclass(frozen=True)
class Optics:
    """Geometry of the condenser + camera (all angles in degrees, lengths in pixels).

    Parameters
    ----------
    axis_tilt_deg, axis_azimuth_deg
        Direction of the condenser's optical axis in the device frame (paper: 20°, 0°).
    cone_half_angle_deg
        Half-angle of the usable view cone about the axis (atan(23.5/21) = 48.2° for
        the paper's 47 mm / 21 mm condenser).
    law
        Radial law, one of :data:`LAWS`.
    focal_px
        ``f`` of the radial law in pixels; ``None`` puts the cone's rim at
        ``disc_radius_px`` from the principal point.
    disc_radius_px
        Image radius of the cone's rim when ``focal_px`` is not given.
    cx, cy
        Principal point (pixels); ``None`` is the sensor centre.
    k1, k2
        Radial distortion of the normalized radius.
    roll_deg
        Rotation of the sensor about the optical axis.
    width, height
        Sensor size in pixels (paper: 320 × 240).
    """

    axis_tilt_deg: float = 20.0
    axis_azimuth_deg: float = 0.0
    cone_half_angle_deg: float = math.degrees(math.atan2(23.5, 21.0))
    law: str = "sine"
    focal_px: float | None = None
    disc_radius_px: float = 112.0
    cx: float | None = None
    cy: float | None = None
    k1: float = 0.0
    k2: float = 0.0
    roll_deg: float = 0.0
    width: int = 320
    height: int = 240

    def __post_init__(self) -> None:
        if self.law not in LAWS:
            raise ParameterError(f"optics: unknown radial law {self.law!r} (expected one of {', '.join(LAWS)})")
        if not 0 < self.cone_half_angle_deg < 89:
            raise ParameterError(f"optics: cone half-angle must be in (0°, 89°), got {self.cone_half_angle_deg}")
        if not 0 <= self.axis_tilt_deg < 60:
            raise ParameterError(f"optics: axis tilt must be in [0°, 60°), got {self.axis_tilt_deg}")
        if self.axis_tilt_deg + self.cone_half_angle_deg >= 90:
            raise ParameterError("optics: the view cone reaches below the sample's horizon")
        if self.width < 8 or self.height < 8:
            raise ParameterError("optics: sensor too small")
        for name in ("focal_px", "cx", "cy"):
            v = getattr(self, name)
            if v is not None and not math.isfinite(v):
                raise ParameterError(f"optics: {name} must be finite")
        if self.focal_px is not None and self.focal_px <= 0:
            raise ParameterError("optics: focal_px must be > 0")

    # ----------------------------------------------------------- derived values
    @property
    def f(self) -> float:
        """Radial-law scale in pixels."""
        if self.focal_px is not None:
            return float(self.focal_px)
        rim = float(_law(self.law, np.radians(self.cone_half_angle_deg)))
        return self.disc_radius_px / rim

    @property
    def principal_point(self) -> tuple[float, float]:
        """Principal point ``(c_x, c_y)`` in pixels; the image centre where ``cx``/``cy`` are unset."""
        cx = (self.width - 1) / 2 if self.cx is None else float(self.cx)
        cy = (self.height - 1) / 2 if self.cy is None else float(self.cy)
        return cx, cy

    @functools.cached_property
    def axis_frame(self) -> Array:
        """Rows ``(x', y', a)``: sensor axes and optical axis in the device frame (read-only;
        computed once per optics, since the layout optimizer asks for it per LED and layout)."""
        t, p, r = (math.radians(v) for v in (self.axis_tilt_deg, self.axis_azimuth_deg, self.roll_deg))
        a = np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])
        # x' lies in the plane of the axis and +z, pointing away from the normal's side
        x0 = np.array([math.cos(t) * math.cos(p), math.cos(t) * math.sin(p), -math.sin(t)])
        y0 = np.cross(a, x0)
        x = math.cos(r) * x0 + math.sin(r) * y0
        y = np.cross(a, x)
        frame = np.stack([x, y, a])
        frame.setflags(write=False)
        return frame

    @property
    def axis(self) -> Array:
        """Unit optical axis in the device frame."""
        return self.axis_frame[2]

    def to_dict(self) -> dict[str, Any]:
        """The optics' fields as a dict (what a device file's ``optics`` table holds).

        Returns
        -------
        dict
            Field name → value (``dataclasses.asdict``).
        """
        return dataclasses.asdict(self)

    def replace(self, **changes: Any) -> Optics:
        """The same optics with some fields replaced (``dataclasses.replace``).

        Parameters
        ----------
        **changes
            Field names and their new values.

        Returns
        -------
        Optics
            A new instance; this one is unchanged.
        """
        return dataclasses.replace(self, **changes)

    # -------------------------------------------------------------- mappings
    def _distort(self, rho: Array) -> Array:
        r2 = rho * rho
        return rho * (1.0 + self.k1 * r2 + self.k2 * r2 * r2)

    def _monotonic_r2(self) -> float:
        """``ρ²`` up to which the distortion ``ρ(1 + k1ρ² + k2ρ⁴)`` rises: the smallest positive
        root of its derivative ``1 + 3k1 x + 5k2 x²`` (``x = ρ²``; infinite where it has none)."""
        roots = np.roots([5.0 * self.k2, 3.0 * self.k1, 1.0]) if (self.k1 or self.k2) else np.array([])
        real = [float(r.real) for r in np.atleast_1d(roots) if abs(r.imag) < 1e-12 and r.real > 0]
        return min(real) if real else math.inf

    def _undistort(self, rho_d: Array) -> Array:
        """The undistorted ``ρ`` of image radii ``ρ_d`` (focal lengths): the root of
        ``ρ(1 + k1ρ² + k2ρ⁴) = ρ_d`` on the distortion's rising branch; NaN where there is none
        (a strong barrel distortion folds back: past its maximum no ray reaches the pixel)."""
        rho = rho_d.copy()
        for _ in range(30):  # Newton on ρ(1 + k1ρ² + k2ρ⁴) = ρ_d
            r2 = rho * rho
            g = rho * (1.0 + self.k1 * r2 + self.k2 * r2 * r2) - rho_d
            dg = 1.0 + 3.0 * self.k1 * r2 + 5.0 * self.k2 * r2 * r2
            step = g / dg
            rho -= step
            if np.all(np.abs(step) < 1e-15):
                break
        r2 = rho * rho
        g = rho * (1.0 + self.k1 * r2 + self.k2 * r2 * r2) - rho_d
        ok = (np.abs(g) <= 1e-9 * (1.0 + np.abs(rho_d))) & (rho >= 0.0) & (r2 < self._monotonic_r2())
        return np.where(ok, rho, np.nan)

    def direction_to_pixel(self, dirs: ArrayLike) -> Array:
        """Image position of view directions: ``r = f·ρ(θ)(1 + k1 ρ² + k2 ρ⁴)`` from the principal point.

        ``θ`` is the angle from the optical axis, ``ρ`` the mapping law (sine law for
        the condenser, algorithm-reference §10.1). Directions at more than 90° from the
        optical axis give NaN.

        Parameters
        ----------
        dirs : array_like, shape (..., 3)
            Unit view directions in the device frame.

        Returns
        -------
        ndarray, shape (..., 2)
            ``(u, v)`` in pixels (column, row).
        """
        d = np.asarray(dirs, dtype=np.float64)
        loc = d @ self.axis_frame.T
        theta = np.arccos(np.clip(loc[..., 2], -1.0, 1.0))
        phi = np.arctan2(loc[..., 1], loc[..., 0])
        rho = _law(self.law, theta)
        rho = np.where(theta <= 0.5 * np.pi, rho, np.nan)
        r = self.f * self._distort(rho)
        cx, cy = self.principal_point
        return np.stack([cx + r * np.cos(phi), cy + r * np.sin(phi)], axis=-1)

    def pixel_to_direction(self, uv: ArrayLike) -> Array:
        """Unit view direction (device frame) seen at image position ``(u, v)``; inverse of :meth:`direction_to_pixel`.

        Parameters
        ----------
        uv : array_like, shape (..., 2)
            Image positions, pixels.

        Returns
        -------
        ndarray, shape (..., 3)
            Unit directions in the device frame.
        """
        uv = np.asarray(uv, dtype=np.float64)
        cx, cy = self.principal_point
        du, dv = uv[..., 0] - cx, uv[..., 1] - cy
        rho = self._undistort(np.hypot(du, dv) / self.f)
        theta = _law_inverse(self.law, rho)
        phi = np.arctan2(dv, du)
        st = np.sin(theta)
        loc = np.stack([st * np.cos(phi), st * np.sin(phi), np.cos(theta)], axis=-1)
        return loc @ self.axis_frame

    def pixel_grid(self) -> Array:
        """Pixel-centre coordinates.

        Returns
        -------
        ndarray, shape (height, width, 2)
            ``(u, v)`` = (column, row) of every pixel.
        """
        v, u = np.mgrid[0 : self.height, 0 : self.width].astype(np.float64)
        return np.stack([u, v], axis=-1)

    def pixel_directions(self) -> tuple[Array, NDArray[np.bool_]]:
        """View direction of every pixel and the mask of pixels inside the view cone.

        Read-only arrays, computed once per optics (the optics are immutable;
        :func:`_pixel_directions` keeps the last few).

        Returns
        -------
        dirs : ndarray, shape (height, width, 3)
            Unit view directions in the device frame.
        mask : ndarray of bool, shape (height, width)
            Inside the view cone and above the sample plane.
        """
        return _pixel_directions(self)[:2]

    def view_pixels(self) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        """The pixels inside the view cone (read-only, cached like :meth:`pixel_directions`).

        Returns
        -------
        rows, cols : ndarray of intp, shape (P,)
            ``np.nonzero(mask)`` of :meth:`pixel_directions`.
        """
        return _pixel_directions(self)[2:]

    def pixel_solid_angles(self) -> Array:
        """Solid angle of each pixel, from the numerical Jacobian of the map.

        Returns
        -------
        ndarray, shape (height, width)
            sr per pixel (``|∂d/∂u × ∂d/∂v|``).
        """
        uv = self.pixel_grid()
        eps = 0.25
        du = self.pixel_to_direction(uv + [eps, 0]) - self.pixel_to_direction(uv - [eps, 0])
        dv = self.pixel_to_direction(uv + [0, eps]) - self.pixel_to_direction(uv - [0, eps])
        return np.linalg.norm(np.cross(du, dv), axis=-1) / (4 * eps * eps)


@functools.lru_cache(maxsize=8)
def _pixel_directions(optics: Optics) -> tuple[Array, NDArray[np.bool_], NDArray[np.intp], NDArray[np.intp]]:
    """``(dirs, mask, rows, cols)`` of :meth:`Optics.pixel_directions` and
    :meth:`Optics.view_pixels`, made read-only so that the cached arrays stay as computed."""
    dirs = optics.pixel_to_direction(optics.pixel_grid())
    cos_axis = dirs @ optics.axis
    mask = (cos_axis >= math.cos(math.radians(optics.cone_half_angle_deg))) & (dirs[..., 2] > 0)
    rows, cols = np.nonzero(mask)
    for a in (dirs, mask, rows, cols):
        a.flags.writeable = False
    return dirs, mask, rows, cols


def optics_from_dict(d: dict[str, Any], where: str = "optics") -> Optics:
    """Build :class:`Optics` from a description dict; unknown keys are an error.

    Parameters
    ----------
    d
        Field name → value.
    where
        Where it came from, for messages.

    Returns
    -------
    Optics
        The optics (its own ``__post_init__`` checks the values).

    Raises
    ------
    ParameterError
        For unknown keys.
    """
    fields = {f.name for f in dataclasses.fields(Optics)}
    unknown = set(d) - fields
    if unknown:
        raise ParameterError(f"{where}: unknown keys {sorted(unknown)} (known: {sorted(fields)})")
    return Optics(**d)
