"""Directions, local frames, and the half/difference (Rusinkiewicz) parameterization.

Conventions (algorithm-reference §0): every direction is a unit vector pointing *away*
from the surface point; ``i`` toward the light, ``o`` toward the viewer. The local frame
is ``x = t``, ``y = b``, ``z = n``. Arrays of directions have shape ``(..., 3)``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]

#: The symmetry of eq. 3 of Lan et al. 2010: 180° rotation about the normal,
#: ``τ = diag(-1, -1, 1)``. It equals the reflection through the normal line ``R_n``.
TAU = np.diag([-1.0, -1.0, 1.0])
#: Mirror across the n–t plane, ``M_t: (x, y, z) → (x, -y, z)`` (algorithm-reference §5.1).
MIRROR_T = np.diag([1.0, -1.0, 1.0])
#: Mirror across the n–b plane, ``M_b: (x, y, z) → (-x, y, z)``.
MIRROR_B = np.diag([-1.0, 1.0, 1.0])


def normalize(v: ArrayLike) -> Array:
    """Unit vectors along ``v``; zero vectors stay zero.

    Parameters
    ----------
    v : array_like, shape (..., 3)
        Vectors to normalize.

    Returns
    -------
    ndarray, shape (..., 3)
        ``v / |v|`` (float64); rows with ``|v| = 0`` (or NaN length) are all zeros.
    """
    v = np.asarray(v, dtype=np.float64)
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    # the same sum as np.linalg.norm's (x² + y²) + z², without its generic reduction
    n = np.sqrt(x * x + y * y + z * z)[..., None]
    bad = ~(n > 0)
    if not bad.any():
        return v / n
    out = v / np.where(bad, 1.0, n)
    out[bad[..., 0]] = 0.0
    return out


def spherical_to_cartesian(theta: ArrayLike, phi: ArrayLike) -> Array:
    """Unit vector ``(sinθ cosφ, sinθ sinφ, cosθ)``.

    Parameters
    ----------
    theta : array_like
        Polar angle θ from +z, radians.
    phi : array_like
        Azimuth φ from +x toward +y, radians; broadcast against ``theta``.

    Returns
    -------
    ndarray, shape (..., 3)
        The directions, ``...`` being the broadcast shape of ``theta`` and ``phi``.
    """
    theta = np.asarray(theta, dtype=np.float64)
    phi = np.asarray(phi, dtype=np.float64)
    st = np.sin(theta)
    return np.stack(np.broadcast_arrays(st * np.cos(phi), st * np.sin(phi), np.cos(theta)), axis=-1)


def cartesian_to_spherical(v: ArrayLike) -> tuple[Array, Array]:
    """``(θ, φ)`` of unit vectors ``v``.

    θ is computed as ``2·asin(|v − z|/2)``, which stays accurate near the pole.

    Parameters
    ----------
    v : array_like, shape (..., 3)
        Unit vectors (not normalized here).

    Returns
    -------
    theta : ndarray, shape (...)
        Polar angle from +z, radians, in [0, π].
    phi : ndarray, shape (...)
        Azimuth ``atan2(y, x)``, radians, in (−π, π].
    """
    v = np.asarray(v, dtype=np.float64)
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    dist = np.sqrt(x * x + y * y + (z - 1.0) ** 2)
    theta = 2.0 * np.arcsin(np.clip(0.5 * dist, 0.0, 1.0))
    return theta, np.arctan2(y, x)


def reflect(v: ArrayLike, axis: ArrayLike) -> Array:
    """Reflection of ``v`` about the unit ``axis``: ``R_a(v) = 2(v·a)a − v``.

    Parameters
    ----------
    v : array_like, shape (..., 3)
        Directions to reflect.
    axis : array_like, shape (..., 3)
        Unit axis ``a`` (e.g. the half vector, giving ``o = R_h(i)``); broadcast against ``v``.

    Returns
    -------
    ndarray, shape (..., 3)
        The reflected directions.
    """
    v = np.asarray(v, dtype=np.float64)
    a = np.asarray(axis, dtype=np.float64)
    return 2.0 * np.sum(v * a, axis=-1, keepdims=True) * a - v


def half_vector(i: ArrayLike, o: ArrayLike) -> Array:
    """The half vector ``h = (i + o)/|i + o|``.

    Parameters
    ----------
    i, o : array_like, shape (..., 3)
        Light and view directions (unit, away from the surface); broadcast.

    Returns
    -------
    ndarray, shape (..., 3)
        ``h``; zero where ``i = −o``.
    """
    return normalize(np.asarray(i, dtype=np.float64) + np.asarray(o, dtype=np.float64))


def apply(matrix: ArrayLike, v: ArrayLike) -> Array:
    """Apply a 3×3 matrix to each direction of ``v``.

    Parameters
    ----------
    matrix : array_like, shape (3, 3)
        The linear map ``M``.
    v : array_like, shape (..., 3)
        Directions.

    Returns
    -------
    ndarray, shape (..., 3)
        ``M·v`` for every row (computed as ``v @ M.T``).
    """
    return np.asarray(v, dtype=np.float64) @ np.asarray(matrix, dtype=np.float64).T


def tau(v: ArrayLike) -> Array:
    """The symmetry τ of eq. 3: ``(x, y, z) → (−x, −y, z)``.

    Parameters
    ----------
    v : array_like, shape (..., 3)
        Local-frame directions.

    Returns
    -------
    ndarray, shape (..., 3)
        ``τ(v)``, the 180° rotation of ``v`` about the normal.
    """
    return apply(TAU, v)


def frame_from_normal(n: ArrayLike, t: ArrayLike | None = None) -> Array:
    """Rows ``(t, b, n)`` of an orthonormal frame with normal ``n``.

    If ``t`` is given it is projected onto the plane ⟂ n; otherwise the projection of
    the world x axis (or y, if x is nearly parallel to n) is used. The matrix maps world
    vectors to local ones: ``local = world @ F.T``.

    Parameters
    ----------
    n : array_like, shape (3,)
        The normal (normalized here).
    t : array_like, shape (3,), optional
        A tangent hint; need not be unit or orthogonal to ``n``.

    Returns
    -------
    ndarray, shape (3, 3)
        ``F`` with rows ``t``, ``b = n × t``, ``n``.
    """
    n = normalize(n)
    if t is None:
        t = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    t = np.asarray(t, dtype=np.float64)
    t = normalize(t - np.dot(t, n) * n)
    b = np.cross(n, t)
    return np.stack([t, b, n])


def to_local(v: ArrayLike, frame: ArrayLike) -> Array:
    """World directions → local coordinates of ``frame``.

    Parameters
    ----------
    v : array_like, shape (..., 3)
        World directions.
    frame : array_like, shape (3, 3)
        Rows ``t, b, n`` (as :func:`frame_from_normal` returns).

    Returns
    -------
    ndarray, shape (..., 3)
        ``(v·t, v·b, v·n)``.
    """
    return np.asarray(v, dtype=np.float64) @ np.asarray(frame, dtype=np.float64).T


def tilt_deg(normal: ArrayLike) -> float:
    """Angle between a unit ``normal`` and the device axis ``+z``, ``acos(n_z)`` (degrees).

    Parameters
    ----------
    normal : array_like, shape (3,)
        A unit vector (device coordinates).

    Returns
    -------
    float
        The tilt in degrees, in [0, 180].
    """
    return math.degrees(math.acos(max(-1.0, min(1.0, float(np.asarray(normal)[2])))))


def to_world(v: ArrayLike, frame: ArrayLike) -> Array:
    """Local coordinates of ``frame`` → world directions (inverse of :func:`to_local`).

    Parameters
    ----------
    v : array_like, shape (..., 3)
        Local coordinates ``(x, y, z)`` along ``t, b, n``.
    frame : array_like, shape (3, 3)
        Rows ``t, b, n``.

    Returns
    -------
    ndarray, shape (..., 3)
        ``x·t + y·b + z·n``.
    """
    return np.asarray(v, dtype=np.float64) @ np.asarray(frame, dtype=np.float64)


def rotate_z(v: Array, angle: ArrayLike) -> Array:
    """Rotate directions about +z (counter-clockwise seen from +z).

    Parameters
    ----------
    v : ndarray, shape (..., 3)
        Directions.
    angle : array_like
        Rotation angle, radians; broadcast against ``v[..., 0]``.

    Returns
    -------
    ndarray, shape (..., 3)
        ``Rot_z(angle)·v``.
    """
    c, s = np.cos(angle), np.sin(angle)
    x, y = v[..., 0], v[..., 1]
    return np.stack(np.broadcast_arrays(c * x - s * y, s * x + c * y, v[..., 2]), axis=-1)


def rotate_y(v: Array, angle: ArrayLike) -> Array:
    """Rotate directions about +y (+z toward +x for a positive angle).

    Parameters
    ----------
    v : ndarray, shape (..., 3)
        Directions.
    angle : array_like
        Rotation angle, radians; broadcast against ``v[..., 0]``.

    Returns
    -------
    ndarray, shape (..., 3)
        ``Rot_y(angle)·v``.
    """
    c, s = np.cos(angle), np.sin(angle)
    x, z = v[..., 0], v[..., 2]
    return np.stack(np.broadcast_arrays(c * x + s * z, v[..., 1], -s * x + c * z), axis=-1)


def io_to_hd(i: ArrayLike, o: ArrayLike) -> tuple[Array, Array, Array, Array]:
    """Rusinkiewicz half/difference angles of direction pairs.

    ``h = normalize(i + o)``; ``d = Rot_y(−θ_h)·Rot_z(−φ_h)·i`` (algorithm-reference §6.1).

    Parameters
    ----------
    i, o : array_like, shape (..., 3)
        Light and view directions, unit, local frame; broadcast.

    Returns
    -------
    theta_h, phi_h, theta_d, phi_d
        Radians; θ ∈ [0, π], φ ∈ (−π, π].
    """
    i = np.asarray(i, dtype=np.float64)
    h = half_vector(i, o)
    theta_h, phi_h = cartesian_to_spherical(h)
    d = rotate_y(rotate_z(i, -phi_h), -theta_h)
    d = np.clip(d, -1.0, 1.0)
    theta_d = np.arccos(d[..., 2])
    phi_d = np.arctan2(d[..., 1], d[..., 0])
    return theta_h, phi_h, theta_d, phi_d


def hd_to_io(
    theta_h: ArrayLike, phi_h: ArrayLike, theta_d: ArrayLike, phi_d: ArrayLike
) -> tuple[Array, Array]:
    """Inverse of :func:`io_to_hd`: ``i = Rot_z(φ_h)·Rot_y(θ_h)·d``, ``o = R_h(i)``.

    Parameters
    ----------
    theta_h, phi_h : array_like
        Half-vector polar angle and azimuth, radians.
    theta_d, phi_d : array_like
        Difference-vector polar angle and azimuth, radians; all four broadcast.

    Returns
    -------
    i, o : ndarray, shape (..., 3)
        Light and view directions in the local frame.
    """
    h = spherical_to_cartesian(theta_h, phi_h)
    d = spherical_to_cartesian(theta_d, phi_d)
    i = rotate_z(rotate_y(d, theta_h), phi_h)
    o = reflect(i, h)
    return i, o


def cos_theta(v: ArrayLike) -> Array:
    """``v·n`` with ``n = +z`` in the local frame.

    Parameters
    ----------
    v : array_like, shape (..., 3)
        Local-frame directions.

    Returns
    -------
    ndarray, shape (...)
        The z components, ``cos θ`` for unit ``v``.
    """
    return np.asarray(v, dtype=np.float64)[..., 2]
