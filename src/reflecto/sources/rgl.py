r"""RGL material database ``.bsdf`` tensor files (Dupuy & Jakob 2018), evaluated as
Mitsuba 3's ``measured`` plugin does.

**Container** ("tensor file"): 12-byte magic ``tensor_file\0``, version bytes (1, 0),
uint32 field count; per field: uint16 name length, name, uint16 ndim, uint8 dtype
(Mitsuba ``Struct`` codes), uint64 data offset, ``ndim`` × uint64 shape; little endian.

**Evaluation** (docs/ecosystem.md §2.4): with ``m = normalize(ω_i + ω_o)``, unit
coordinates ``u_θ = √(2θ/π)``, ``u_φ = (φ + π)/2π`` (φ_m relative to φ_i for isotropic
files), invert the VNDF warp (a continuous ``Marginal2D`` conditioned on (φ_i, θ_i)) at
``u_m``, look up the RGB residual table bilinearly at the warped position, and multiply
by ``D(m)/(4 σ(ω_i))`` if the ``jacobian`` flag is set. The result is the cosine-weighted
BSDF ``f · cos θ_o``; :meth:`RGLBRDF.eval` divides by ``cos θ_o`` to return ``f`` in sr⁻¹.

Direction roles: reflecto's ``i`` (toward the light) is the table's incident direction
(Mitsuba's ``si.wi``) and ``o`` is Mitsuba's ``wo``. Measured tables are not exactly
reciprocal, so ``reciprocal`` is False.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..brdf import (
    ALBEDO_RANGE,
    MAX_PROJECTED_BRDF,
    BRDFSource,
    Reader,
    check_plausible,
    check_projected,
    read_file_bytes,
    register_reader,
)
from ..errors import FileFormatError
from . import _rgl_kernels

Array = NDArray[np.float64]

MAGIC = b"tensor_file\x00"
#: Mitsuba Struct type codes → NumPy dtypes
DTYPES = {
    1: "u1", 2: "i1", 3: "<u2", 4: "<i2", 5: "<u4", 6: "<i4", 7: "<u8", 8: "<i8",
    9: "<f2", 10: "<f4", 11: "<f8",
}


#: Limits of tensor files (docs/limits.md): fields, dimensions per field, name length.
MAX_FIELDS = 64
MAX_NDIM = 8
MAX_NAME_BYTES = 256
#: The most ``ndf`` nodes the damage check visits (:meth:`RGLBRDF._ndf_nodes_at_risk`; 8
#: incident directions each): a table whose values could exceed the projected bound almost
#: everywhere is judged by its largest nodes, in bounded memory.
MAX_NODES_AT_RISK = 1 << 14


def read_tensor_file(path: str | Path) -> dict[str, np.ndarray]:
    """Parse a tensor file into ``{name: array}``; clear errors for damaged files.

    Every field's byte range is checked against the file length with exact integer
    arithmetic before an array is made (a hostile shape cannot overflow or allocate);
    arrays are read-only views of the file's bytes.

    Parameters
    ----------
    path
        A tensor file (container layout in the module docstring).

    Returns
    -------
    dict of str to ndarray
        Every field by name, with its stored dtype and shape.

    Raises
    ------
    FileFormatError
        For a wrong magic or version, a damaged field table or a truncated field.
    """
    path = Path(path)
    raw = read_file_bytes(path, what="an RGL tensor file")
    if raw[:12] != MAGIC:
        raise FileFormatError(path, "not an RGL tensor file (wrong magic; expected 'tensor_file\\0')")
    if len(raw) < 18:
        raise FileFormatError(path, "truncated tensor file header")
    major, minor = raw[12], raw[13]
    if (major, minor) != (1, 0):
        raise FileFormatError(path, f"unsupported tensor file version {major}.{minor} (expected 1.0)")
    (count,) = struct.unpack_from("<I", raw, 14)
    if count > MAX_FIELDS:
        raise FileFormatError(path, f"{count} fields, more than {MAX_FIELDS}: damaged field table")
    pos = 18
    fields: dict[str, np.ndarray] = {}
    try:
        for _ in range(count):
            (nlen,) = struct.unpack_from("<H", raw, pos)
            pos += 2
            if nlen > MAX_NAME_BYTES or pos + nlen > len(raw):
                raise FileFormatError(path, "truncated or damaged field table (field name)")
            name = raw[pos : pos + nlen].decode("utf-8")
            pos += nlen
            ndim, dtype_code, offset = struct.unpack_from("<HBQ", raw, pos)
            pos += 11
            if ndim > MAX_NDIM:
                raise FileFormatError(path, f"field {name!r} has {ndim} dimensions, more than {MAX_NDIM}")
            shape = struct.unpack_from(f"<{ndim}Q", raw, pos)
            pos += 8 * ndim
            if dtype_code not in DTYPES:
                raise FileFormatError(path, f"field {name!r} has unknown dtype code {dtype_code}")
            if name in fields:
                raise FileFormatError(path, f"field {name!r} is listed twice")
            dt = np.dtype(DTYPES[dtype_code])
            count_items = math.prod(shape)  # Python integers: exact for any shape
            nbytes = count_items * dt.itemsize
            if offset + nbytes > len(raw):
                raise FileFormatError(path, f"truncated: field {name!r} needs bytes {offset}..{offset + nbytes}, "
                                            f"file has {len(raw)}")
            fields[name] = np.frombuffer(raw, dtype=dt, count=count_items, offset=offset).reshape(shape)
    except (struct.error, UnicodeDecodeError):
        raise FileFormatError(path, "truncated or damaged field table") from None
    return fields


def _require(path: Path, f: dict[str, np.ndarray], name: str, ndim: int, dtype: str) -> np.ndarray:
    if name not in f:
        raise FileFormatError(path, f"missing field {name!r}")
    a = f[name]
    if a.ndim != ndim or a.dtype != np.dtype(dtype):
        raise FileFormatError(path, f"field {name!r} has shape {a.shape} and type {a.dtype}, "
                                    f"expected {ndim}-D {np.dtype(dtype)}")
    return a


def _check_tables(path: Path, theta_i: Array, phi_i: Array, ndf: np.ndarray, sigma: np.ndarray,
                  vndf: np.ndarray, lum: np.ndarray, rgb: np.ndarray, jac: np.ndarray) -> None:
    """Ranges of the tables that the evaluation divides by or integrates (see :class:`RGLBRDF`)."""
    for name, arr in (("theta_i", theta_i), ("phi_i", phi_i), ("ndf", ndf), ("sigma", sigma), ("vndf", vndf),
                      ("luminance", lum), ("rgb", rgb)):
        if not np.all(np.isfinite(arr)):
            raise FileFormatError(path, f"field {name!r} contains NaN or infinite values")
    if len(theta_i) < 1 or len(phi_i) < 1:
        raise FileFormatError(path, "theta_i and phi_i need at least one value each")
    if np.any(np.diff(theta_i) <= 0) or theta_i[0] < 0 or theta_i[-1] > 0.5 * math.pi + 1e-4:
        raise FileFormatError(path, "theta_i must increase strictly within [0, π/2]")
    if np.any(np.diff(phi_i) <= 0) or phi_i[0] < -math.pi - 1e-4 or phi_i[-1] > math.pi + 1e-4:
        raise FileFormatError(path, "phi_i must increase strictly within [−π, π]")
    if np.any(ndf < 0) or not np.any(ndf > 0):
        raise FileFormatError(path, "field 'ndf' must be non-negative and not zero everywhere")
    if np.any(sigma <= 0):
        raise FileFormatError(path, "field 'sigma' (projected area) must be positive everywhere")
    if np.any(vndf < 0):
        raise FileFormatError(path, "field 'vndf' must be non-negative")
    empty = ~np.any(vndf.reshape(vndf.shape[0] * vndf.shape[1], -1) > 0, axis=1)
    if np.any(empty):
        raise FileFormatError(path, f"field 'vndf' is zero everywhere in {int(empty.sum())} incident slice(s): "
                              "its warp is undefined")
    if np.any(lum < 0):
        raise FileFormatError(path, "field 'luminance' must be non-negative")
    dark = ~np.any(lum.reshape(lum.shape[0] * lum.shape[1], -1) > 0, axis=1)
    if np.any(dark):  # the sampling warp of such a slice divides by zero (Mitsuba's pdf is NaN there)
        raise FileFormatError(path, f"field 'luminance' is zero everywhere in {int(dark.sum())} incident slice(s): "
                              "its warp is undefined")
    if jac[0] not in (0, 1):
        raise FileFormatError(path, f"field 'jacobian' must be 0 or 1, got {int(jac[0])}")


def _param_weights(values: Array, p: Array) -> tuple[NDArray[np.intp], Array]:
    """Interval index and upper weight of ``p`` in the parameter grid (clamped)."""
    if len(values) == 1:
        return np.zeros(p.shape, dtype=np.intp), np.zeros(p.shape)
    idx = np.clip(np.searchsorted(values, p, side="left") - 1, 0, len(values) - 2)
    p0, p1 = values[idx], values[idx + 1]
    return idx, np.clip((p - p0) / (p1 - p0), 0.0, 1.0)


@dataclass
class Marginal2D:
    """NumPy version of Mitsuba's continuous ``Marginal2D`` warp, conditioned on
    ``(φ_i, θ_i)`` by linear interpolation between slices.

    ``data`` has shape ``(n_phi, n_theta, H, W)`` (slices × rows × columns).
    """

    data: Array
    phi: Array
    theta: Array
    build_cdf: bool = True

    def __post_init__(self) -> None:
        d = np.asarray(self.data, dtype=np.float64)
        self.h, self.w = d.shape[-2:]
        slices = d.reshape(-1, self.h, self.w)
        if self.build_cdf:
            cond = np.zeros_like(slices)
            cond[:, :, 1:] = np.cumsum(0.5 * (slices[:, :, 1:] + slices[:, :, :-1]), axis=2)
            row_tot = cond[:, :, -1]
            marg = np.zeros((len(slices), self.h))
            marg[:, 1:] = np.cumsum(0.5 * (row_tot[:, 1:] + row_tot[:, :-1]), axis=1)
            norm = 1.0 / marg[:, -1]
            self.cond = cond * norm[:, None, None]
            self.marg = marg * norm[:, None]
            self.norm_data = slices * norm[:, None, None]
        else:
            self.norm_data = slices
        self.n_theta = len(self.theta)

    def _slices(self, phi_i: Array, theta_i: Array) -> list[tuple[NDArray[np.intp], Array]]:
        pi_, pw = _param_weights(np.asarray(self.phi, dtype=np.float64), phi_i)
        ti, tw = _param_weights(np.asarray(self.theta, dtype=np.float64), theta_i)
        out = []
        nphi = len(self.phi)
        for dp, wp in ((0, 1.0 - pw), (1, pw)):
            if nphi == 1 and dp == 1:
                continue
            for dt, wt in ((0, 1.0 - tw), (1, tw)):
                if self.n_theta == 1 and dt == 1:
                    continue
                out.append(((pi_ + dp) * self.n_theta + ti + dt, wp * wt))
        return out

    def eval(self, pos: Array, phi_i: Array, theta_i: Array) -> Array:
        """Bilinear interpolation of the (unnormalized, if ``build_cdf`` is False) data.

        Parameters
        ----------
        pos : ndarray, shape (..., 2)
            Positions in [0, 1]² (x: column, y: row), clipped.
        phi_i, theta_i : ndarray, shape (...)
            The conditioning parameters (radians), interpolated linearly between slices.

        Returns
        -------
        ndarray, shape (...)
            The interpolated data.
        """
        if self.norm_data.shape[0] == 1:  # one parameter slice (the ndf and sigma tables): one compiled loop
            shape = np.broadcast_shapes(pos.shape[:-1], np.shape(phi_i), np.shape(theta_i))
            px = np.ascontiguousarray(np.broadcast_to(pos[..., 0], shape), dtype=np.float64).reshape(-1)
            py = np.ascontiguousarray(np.broadcast_to(pos[..., 1], shape), dtype=np.float64).reshape(-1)
            flat = np.empty(px.shape)
            _rgl_kernels.bilinear_one_slice(np.ascontiguousarray(self.norm_data).reshape(-1), self.h, self.w,
                                            px, py, flat)
            return flat.reshape(shape)
        x = np.clip(pos[..., 0], 0.0, 1.0) * (self.w - 1)
        y = np.clip(pos[..., 1], 0.0, 1.0) * (self.h - 1)
        x0 = np.minimum(x.astype(np.intp), self.w - 2)
        y0 = np.minimum(y.astype(np.intp), self.h - 2)
        fx, fy = x - x0, y - y0
        out = np.zeros(x.shape)
        for sl, wt in self._slices(phi_i, theta_i):
            d = self.norm_data
            v = (1 - fy) * ((1 - fx) * d[sl, y0, x0] + fx * d[sl, y0, x0 + 1]) + fy * (
                (1 - fx) * d[sl, y0 + 1, x0] + fx * d[sl, y0 + 1, x0 + 1]
            )
            out += wt * v
        return out

    def invert(self, sample: Array, phi_i: Array, theta_i: Array) -> Array:
        """Inverse of the continuous sample warp: point in [0,1]² → uniform sample.

        Parameters
        ----------
        sample : ndarray, shape (..., 2)
            Warped points in [0, 1]².
        phi_i, theta_i : ndarray, shape (...)
            The conditioning parameters (radians).

        Returns
        -------
        ndarray, shape (..., 2)
            The uniform samples that the warp maps to ``sample``.
        """
        s = np.clip(sample, 0.0, 1.0)
        x = s[..., 0] * (self.w - 1)
        y = s[..., 1] * (self.h - 1)
        px = np.minimum(x.astype(np.intp), self.w - 2)
        py = np.minimum(y.astype(np.intp), self.h - 2)
        sx, sy = x - px, y - py
        v00 = v10 = v01 = v11 = c0v = c1v = r0 = r1 = m0 = 0.0
        for sl, wt in self._slices(phi_i, theta_i):
            d, c = self.norm_data, self.cond
            v00 = v00 + wt * d[sl, py, px]
            v10 = v10 + wt * d[sl, py, px + 1]
            v01 = v01 + wt * d[sl, py + 1, px]
            v11 = v11 + wt * d[sl, py + 1, px + 1]
            c0v = c0v + wt * c[sl, py, px]
            c1v = c1v + wt * c[sl, py + 1, px]
            r0 = r0 + wt * c[sl, py, self.w - 1]
            r1 = r1 + wt * c[sl, py + 1, self.w - 1]
            m0 = m0 + wt * self.marg[sl, py]
        c0 = (1 - sy) * v00 + sy * v01
        c1 = (1 - sy) * v10 + sy * v11
        ux = sx * (c0 + 0.5 * sx * (c1 - c0))
        ux = ux + (1 - sy) * c0v + sy * c1v
        row = (1 - sy) * r0 + sy * r1
        # a row of no mass (zeros in the table): its conditional warp is undefined; the point's
        # own position along the row stands in (uniform), as its limit from rows of equal mass does
        ux = np.divide(ux, row, out=np.asarray(sx, dtype=np.float64).copy(), where=row > 0)
        uy = sy * (r0 + 0.5 * sy * (r1 - r0)) + m0
        return np.stack([ux, uy], axis=-1)


    def sample(self, u: Array, slice_index: int | NDArray[np.intp]) -> Array:
        """Forward continuous warp of parameter slices: uniform ``u`` → point in [0,1]².

        The exact inverse of :meth:`invert` (at a grid node of the parameters): the
        marginal and conditional CDFs are piecewise quadratic, each solved in closed form.
        One compiled loop over the samples (:func:`._rgl_kernels.warp_sample`), equal to
        :meth:`sample_numpy` bit for bit.

        Parameters
        ----------
        u : ndarray, shape (..., 2)
            Uniform samples in [0, 1]² (clipped).
        slice_index
            Flat parameter slice ``k·n_theta + j``: one, or one per sample (an integer
            array broadcast with ``u[..., 0]``).

        Returns
        -------
        ndarray, shape (..., 2)
            The warped points in [0, 1]².
        """
        k_b, ux_b, uy_b = _warp_inputs(u, slice_index)
        shape = k_b.shape
        k = np.ascontiguousarray(k_b).reshape(-1)
        ux, uy = np.ascontiguousarray(ux_b).reshape(-1), np.ascontiguousarray(uy_b).reshape(-1)
        n = self.norm_data.shape[0]
        if k.size and (int(k.min()) < -n or int(k.max()) >= n):  # the compiled loop does not check its reads
            raise IndexError(f"slice index out of range for {n} parameter slices")
        k = np.where(k < 0, k + n, k)
        out = np.empty((len(k), 2))
        _rgl_kernels.warp_sample(np.ascontiguousarray(self.norm_data).reshape(-1),
                                 np.ascontiguousarray(self.cond).reshape(-1),
                                 np.ascontiguousarray(self.marg).reshape(-1), self.h, self.w, k, ux, uy, out)
        return out.reshape(shape + (2,))

    def sample_numpy(self, u: Array, slice_index: int | NDArray[np.intp]) -> Array:
        """NumPy reference of :meth:`sample`, vectorized over the samples: each bisection
        step gathers every sample's node at once.

        Parameters
        ----------
        u : ndarray, shape (..., 2)
            Uniform samples in [0, 1]² (clipped).
        slice_index
            Flat parameter slice ``k·n_theta + j``: one, or one per sample.

        Returns
        -------
        ndarray, shape (..., 2)
            The warped points in [0, 1]².
        """
        k, ux, uy = _warp_inputs(u, slice_index)
        h, w = self.h, self.w
        # flat indices into the (slice, row, column) tables: one gather each (np.take)
        d, c, marg = self.norm_data.reshape(-1), self.cond.reshape(-1), self.marg.reshape(-1)
        # the row: the last node of the (nondecreasing) marginal CDF at or below uy, by bisection
        py = np.clip(_last_at_or_below(lambda row: marg.take(k * h + row), h, uy), 0, h - 2)
        row0 = (k * h + py) * w
        row1 = row0 + w
        r0, r1 = c.take(row0 + (w - 1)), c.take(row1 + (w - 1))
        sy = _solve_quadratic(r0, r1, uy - marg.take(k * h + py))
        # the conditional CDF of the row interpolated at sy: the last column at or below the
        # target (the interpolated row is nondecreasing, as both rows are)
        total = (1 - sy) * r0 + sy * r1
        target = ux * total

        def cond(col: NDArray[np.intp]) -> Array:
            return (1 - sy) * c.take(row0 + col) + sy * c.take(row1 + col)

        px = np.clip(_last_at_or_below(cond, w, target), 0, w - 2)
        c0 = (1 - sy) * d.take(row0 + px) + sy * d.take(row1 + px)
        c1 = (1 - sy) * d.take(row0 + px + 1) + sy * d.take(row1 + px + 1)
        base = cond(px)
        sx = _solve_quadratic(c0, c1, target - base)
        return np.stack([(px + sx) / (w - 1), (py + sy) / (h - 1)], axis=-1)


def _warp_inputs(u: Array, slice_index: int | NDArray[np.intp]) -> tuple[NDArray[np.intp], Array, Array]:
    """The slice index and the two uniform coordinates (clipped to [0, 1], float64) of
    :meth:`Marginal2D.sample`, broadcast to one shape (read-only views)."""
    ux = np.clip(np.asarray(u[..., 0], dtype=np.float64), 0.0, 1.0)
    uy = np.clip(np.asarray(u[..., 1], dtype=np.float64), 0.0, 1.0)
    shape = np.broadcast_shapes(ux.shape, np.shape(slice_index))
    k = np.broadcast_to(np.asarray(slice_index, dtype=np.intp), shape)
    return k, np.broadcast_to(ux, shape), np.broadcast_to(uy, shape)


def _last_at_or_below(values: Callable[[NDArray[np.intp]], Array], n: int, target: Array) -> NDArray[np.intp]:
    """Per element, the last index ``i < n`` of a nondecreasing sequence with
    ``values(i) ≤ target`` (−1 where there is none), by bisection over all elements at once."""
    lo = np.full(np.shape(target), -1, dtype=np.intp)  # values(lo) <= target (-1: none)
    hi = np.full(np.shape(target), n, dtype=np.intp)  # values(hi) > target (n: none)
    while np.any(hi - lo > 1):
        mid = (lo + hi) // 2
        below = values(np.clip(mid, 0, n - 1)) <= target
        lo = np.where(below, mid, lo)
        hi = np.where(below, hi, mid)
    return lo


def _bilinear(table: Array, pos: Array) -> Array:
    """Bilinear interpolation of ``table`` (rows × columns, or a stack ``(S, rows, columns)``)
    at ``pos`` in [0,1]² (x: column, y: row), shape ``(N,)`` or ``(S, N)``."""
    h, w = table.shape[-2:]
    x = np.clip(pos[:, 0], 0.0, 1.0) * (w - 1)
    y = np.clip(pos[:, 1], 0.0, 1.0) * (h - 1)
    x0 = np.clip(np.floor(x).astype(np.intp), 0, w - 2)
    y0 = np.clip(np.floor(y).astype(np.intp), 0, h - 2)
    fx, fy = x - x0, y - y0
    t = np.asarray(table, dtype=np.float64)
    return ((1 - fy) * ((1 - fx) * t[..., y0, x0] + fx * t[..., y0, x0 + 1])
            + fy * ((1 - fx) * t[..., y0 + 1, x0] + fx * t[..., y0 + 1, x0 + 1]))


def _solve_quadratic(v0: Array, v1: Array, y: Array) -> Array:
    """``t ∈ [0, 1]`` with ``t v0 + ½ t² (v1 − v0) = y`` (the integral of a linear density)."""
    a = 0.5 * (v1 - v0)
    disc = np.sqrt(np.maximum(v0 * v0 + 4.0 * a * np.maximum(y, 0.0), 0.0))
    lin = np.divide(y, v0, out=np.zeros_like(y), where=v0 > 0)
    quad = np.divide(2.0 * np.maximum(y, 0.0), v0 + disc, out=np.zeros_like(y), where=(v0 + disc) > 0)
    t = np.where(np.abs(a) < 1e-9 * np.maximum(np.abs(v0), 1e-300), lin, quad)
    return np.clip(t, 0.0, 1.0)


#: The incident slices up to this θ_i are checked by their albedo (:meth:`RGLBRDF.slice_albedo`;
#: nearer grazing, cells that cross the horizon make the trapezoid rule overestimate it).
SLICE_ALBEDO_MAX_THETA_DEG = 80.0


class RGLBRDF(BRDFSource):
    """An RGL ``.bsdf`` tensor file (RGB version), evaluated like Mitsuba 3's ``measured``."""

    kind = "rgl"
    path: Path  # always read from a file

    def __init__(self, path: str | Path) -> None:
        self.path = path = Path(path)
        f = read_tensor_file(path)
        desc = _require(path, f, "description", 1, "u1")
        theta_i = _require(path, f, "theta_i", 1, "<f4").astype(np.float64)
        phi_i = _require(path, f, "phi_i", 1, "<f4").astype(np.float64)
        ndf = _require(path, f, "ndf", 2, "<f4")
        sigma = _require(path, f, "sigma", 2, "<f4")
        vndf = _require(path, f, "vndf", 4, "<f4")
        lum = _require(path, f, "luminance", 4, "<f4")
        jac = _require(path, f, "jacobian", 1, "u1")
        if "rgb" not in f:
            raise FileFormatError(path, "missing field 'rgb' (only RGB tensor files are supported; "
                                        "this may be a spectral file)")
        rgb = _require(path, f, "rgb", 5, "<f4")
        nphi, nth = len(phi_i), len(theta_i)
        if vndf.shape[:2] != (nphi, nth) or lum.shape[:2] != (nphi, nth) or rgb.shape[:3] != (nphi, nth, 3):
            raise FileFormatError(path, f"inconsistent shapes: vndf {vndf.shape}, luminance {lum.shape}, "
                                        f"rgb {rgb.shape} for {nphi} φ_i × {nth} θ_i")
        if rgb.shape[3] != rgb.shape[4] or jac.shape != (1,):
            raise FileFormatError(path, f"rgb slices must be square and jacobian one byte; "
                                        f"got rgb {rgb.shape}, jacobian {jac.shape}")
        if lum.shape[2:] != rgb.shape[3:]:  # Mitsuba's plugin samples rgb's grid through the luminance's warp
            raise FileFormatError(path, f"luminance slices {lum.shape[2:]} must match the rgb slices "
                                        f"{rgb.shape[3:]} (square, the same size)")
        if min(ndf.shape) < 2 or min(sigma.shape) < 2 or min(vndf.shape[2:]) < 2 or min(rgb.shape[3:]) < 2:
            raise FileFormatError(path, "tables must be at least 2×2")
        _check_tables(path, theta_i, phi_i, ndf, sigma, vndf, lum, rgb, jac)
        self.description = bytes(desc).decode("utf-8", "replace")
        self.theta_i, self.phi_i = theta_i, phi_i
        self.isotropic = nphi <= 2
        self.reduction = 0 if self.isotropic else int(round(2 * math.pi / (phi_i[-1] - phi_i[0])))
        if self.reduction not in (0, 1, 2, 4):
            raise FileFormatError(path, f"phi_i spans {np.degrees(phi_i[-1] - phi_i[0]):.4g}°: "
                                  "an anisotropic file must cover 360°, 180° or 90° (symmetry reduction 1, 2 or 4)")
        self.jacobian = bool(jac[0])
        one = np.zeros(1)
        self._ndf = Marginal2D(ndf[None, None].astype(np.float64), one, one, build_cdf=False)
        self._sigma = Marginal2D(sigma[None, None].astype(np.float64), one, one, build_cdf=False)
        self._vndf = Marginal2D(vndf.astype(np.float64), phi_i, theta_i)
        rgb64 = rgb.astype(np.float64)
        self._rgb = [Marginal2D(rgb64[:, :, c], phi_i, theta_i, build_cdf=False) for c in range(3)]
        self.reciprocal = False
        check_projected(self.projected_at_nodes(), path, "its tables")
        steep = self.theta_i <= math.radians(SLICE_ALBEDO_MAX_THETA_DEG)
        albedo = self.slice_albedo().reshape(len(phi_i), len(theta_i), 3)[:, steep]
        lo, hi = ALBEDO_RANGE
        if not np.all(np.isfinite(albedo)) or albedo.min() < lo or albedo.max() > hi:
            raise FileFormatError(path, f"its tables give a directional albedo of {albedo.min():.4g} to "
                                  f"{albedo.max():.4g} (θ_i ≤ {SLICE_ALBEDO_MAX_THETA_DEG:g}°), outside the plausible "
                                  f"[{lo:g}, {hi:g}]: damaged, or not a BRDF in sr⁻¹")
        check_plausible(self, path)

    def slice_albedo(self, refine: int = 2) -> Array:
        """Directional albedo ``∫ f cos θ_o dω_o`` of every incident slice, from the tables
        themselves, shape ``(n_φi · n_θi, 3)``.

        The ``rgb`` grid, refined ``refine`` times (bilinear, as the plugin interpolates),
        is warped to outgoing directions (``vndf``); each cell counts with the solid
        angle of its four warped corners and the mean of the values there (trapezoid
        rule). Every node of the tables is a corner, so a damaged value anywhere is
        counted with its measure.

        Parameters
        ----------
        refine
            Subdivisions of each ``rgb`` grid cell per axis.

        Returns
        -------
        ndarray, shape (n_φi · n_θi, 3)
            RGB albedo (dimensionless) per incident slice, φ_i-major.
        """
        h, w = self._rgb[0].h, self._rgb[0].w
        hr, wr = refine * (h - 1) + 1, refine * (w - 1) + 1
        yy, xx = np.meshgrid(np.linspace(0, 1, hr), np.linspace(0, 1, wr), indexing="ij")
        nodes = np.stack([xx.ravel(), yy.ravel()], -1)
        out = []
        for k, j in self._slice_batches(len(nodes)):
            o, g = self._slice_values(k, j, nodes)
            o = o.reshape(len(k), hr, wr, 3)
            g = g.reshape(len(k), hr, wr, 3)
            d1 = o[:, 1:, 1:] - o[:, :-1, :-1]
            d2 = o[:, 1:, :-1] - o[:, :-1, 1:]
            area = 0.5 * np.linalg.norm(np.cross(d1, d2), axis=-1)
            mean = 0.25 * (g[:, 1:, 1:] + g[:, :-1, :-1] + g[:, 1:, :-1] + g[:, :-1, 1:])
            out.extend(np.sum(area[..., None] * mean, axis=(1, 2)))
        return np.array(out)

    def _slice_values(self, k: NDArray[np.intp], j: NDArray[np.intp], nodes: Array) -> tuple[Array, Array]:
        """Outgoing directions and ``f·cos θ_o`` at sample positions ``nodes`` (shape ``(N, 2)``)
        of the slices ``(k, j)`` (shape ``(S,)`` each), shapes ``(S, N, 3)``: values bilinear in
        the ``rgb`` grid (exact at its nodes); 0 below the horizon."""
        nth = len(self.theta_i)
        u_m = self._vndf.sample(nodes[None], (k * nth + j)[:, None])
        theta_m = u_m[..., 0] ** 2 * (0.5 * math.pi)
        phi_m = u_m[..., 1] * (2 * math.pi) - math.pi + (self.phi_i[k][:, None] if self.isotropic else 0.0)
        angles = [(float(self.theta_i[b]), float(self.phi_i[a])) for a, b in zip(k, j)]
        i = np.array([[math.sin(ti) * math.cos(pi_), math.sin(ti) * math.sin(pi_), math.cos(ti)] for ti, pi_ in angles])
        m = np.stack([np.sin(theta_m) * np.cos(phi_m), np.sin(theta_m) * np.sin(phi_m), np.cos(theta_m)], -1)
        o = 2.0 * np.stack([m_s @ i_s for m_s, i_s in zip(m, i)])[..., None] * m - i[:, None]
        spec = np.stack([_bilinear(t.data[k, j], nodes) for t in self._rgb], -1)
        if self.jacobian:
            zero = np.zeros(theta_m.shape)
            u_wi = np.array([[math.sqrt(ti * 2 / math.pi), (pi_ + math.pi) / (2 * math.pi)] for ti, pi_ in angles])
            ndf = self._ndf.eval(u_m, zero, zero)
            sig = self._sigma.eval(np.broadcast_to(u_wi[:, None], u_m.shape), zero, zero)
            spec = spec * (ndf / (4.0 * sig))[..., None]
        return o, np.where((o[..., 2] > 0)[..., None], spec, 0.0)

    def _slice_batches(self, n_nodes: int) -> Iterator[tuple[NDArray[np.intp], NDArray[np.intp]]]:
        """The incident slices ``(k, j)`` (φ_i-major), in batches of about 2¹⁸ samples at ``n_nodes`` each."""
        nth = len(self.theta_i)
        flat = np.arange(len(self.phi_i) * nth)
        step = max(1, (1 << 18) // max(n_nodes, 1))
        for s in range(0, len(flat), step):
            k, j = np.divmod(flat[s : s + step], nth)
            yield k, j

    def projected_at_nodes(self) -> Array:
        """``f·cos θ_i·cos θ_o`` (sr⁻¹) at every node of the ``rgb`` tables, shape ``(N, 3)``.

        Each node of a slice's ``rgb`` table is one outgoing direction of that slice's
        incident direction (the node's sample position, warped by the ``vndf`` table);
        the value there is the node's value exactly (bilinear interpolation at a node).
        A damaged value between the directions a quadrature visits is seen here.

        Returns
        -------
        ndarray, shape (N, 3)
            RGB values in sr⁻¹: every ``rgb`` node of every slice, then direction pairs at
            the nodes of the ``ndf`` and ``sigma`` tables.
        """
        h, w = self._rgb[0].h, self._rgb[0].w
        yy, xx = np.meshgrid(np.linspace(0, 1, h), np.linspace(0, 1, w), indexing="ij")
        nodes = np.stack([xx.ravel(), yy.ravel()], -1)
        out: list[Array] = []
        for k, j in self._slice_batches(len(nodes)):
            _, g = self._slice_values(k, j, nodes)
            out.extend(g * np.cos(self.theta_i[j])[:, None, None])
        i, o = self._ndf_sigma_pairs()
        out.append(self.eval_cosine(i, o) * i[:, 2:3])
        return np.concatenate(out)

    def _ndf_sigma_pairs(self) -> tuple[Array, Array]:
        """Direction pairs at every node of the ``sigma`` (incident) and ``ndf`` (half-vector)
        tables, each with each: where a damaged node of those tables shows.

        Where that is more than 2¹⁶ pairs, each ``sigma`` node meets the 32 densest half
        vectors, and an ``ndf`` node meets 8 incident directions only where its value could
        exceed :data:`~reflecto.brdf.MAX_PROJECTED_BRDF` (:meth:`_ndf_nodes_at_risk`): an
        anisotropic export's 2048² ``ndf`` table then costs a few pairs, not 33 million.
        """

        def directions(table: Marginal2D, nodes: NDArray[np.intp] | None = None) -> Array:
            """Directions of the table's nodes (all, or the flat indices ``nodes``)."""
            h, w = table.h, table.w
            flat = np.arange(h * w) if nodes is None else nodes
            theta = (flat % w / (w - 1)) ** 2 * (0.5 * math.pi)
            phi = (flat // w / (h - 1)) * (2 * math.pi) - math.pi
            return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1)

        wi = directions(self._sigma)
        if len(wi) * self._ndf.h * self._ndf.w > 1 << 16:
            ndf_values = np.asarray(self._ndf.data, dtype=np.float64).reshape(-1)
            top_m = directions(self._ndf, np.argpartition(ndf_values, max(len(ndf_values) - 32, 0))[-32:])
            m = directions(self._ndf, self._ndf_nodes_at_risk())
            some_wi = wi[np.linspace(0, len(wi) - 1, 8).astype(np.intp)]
            i = np.concatenate([np.repeat(some_wi, len(m), 0), np.repeat(wi, len(top_m), 0)])
            mm = np.concatenate([np.tile(m, (len(some_wi), 1)), np.tile(top_m, (len(wi), 1))])
        else:
            m = directions(self._ndf)
            i = np.repeat(wi, len(m), 0)
            mm = np.tile(m, (len(wi), 1))
        o = 2.0 * np.sum(i * mm, -1)[:, None] * mm - i
        keep = (i[:, 2] > 1e-4) & (o[:, 2] > 1e-4)
        return i[keep], o[keep]

    def _ndf_nodes_at_risk(self) -> NDArray[np.intp]:
        """Flat indices of the ``ndf`` nodes through which a value could exceed the projected bound.

        The plugin's value is ``f·cos θ_i·cos θ_o = rgb · D(m) / (4 σ(i)) · cos θ_i``, each
        table read by bilinear interpolation between its nodes (and between slices, with
        weights in [0, 1] that sum to 1), so ``|f·cos θ_i·cos θ_o| ≤ max|rgb| · D_k / (4 min σ)``
        with ``D_k`` the largest of the four ``ndf`` nodes around ``m``. Where no node reaches
        :data:`~reflecto.brdf.MAX_PROJECTED_BRDF` by this bound, no pair of directions can:
        the nodes that do are the ones to visit.
        """
        ndf_values = np.asarray(self._ndf.data, dtype=np.float64).reshape(-1)
        rgb_max = max(float(np.max(np.abs(t.data))) for t in self._rgb)
        bound = rgb_max * ndf_values / (4.0 * float(np.min(self._sigma.data)))
        risky = np.flatnonzero(bound > MAX_PROJECTED_BRDF)
        if len(risky) > MAX_NODES_AT_RISK:  # a table of huge values: its largest nodes are what to visit
            risky = np.sort(risky[np.argpartition(bound[risky], -MAX_NODES_AT_RISK)[-MAX_NODES_AT_RISK:]])
        return risky

    def eval_cosine(self, i: ArrayLike, o: ArrayLike) -> Array:
        """The plugin's value ``f(i, o)·cos θ_o`` (what Mitsuba's ``eval`` returns).

        Parameters
        ----------
        i, o : array_like, shape (..., 3)
            Unit light (Mitsuba's ``wi``) and view (``wo``) directions in the local frame.

        Returns
        -------
        ndarray, shape (..., 3)
            RGB ``f·cos θ_o`` in sr⁻¹; 0 where either direction is below the horizon.
        """
        wi = np.array(i, dtype=np.float64)
        wo = np.array(o, dtype=np.float64)
        active = (wi[..., 2] > 0) & (wo[..., 2] > 0)
        if self.reduction >= 2:
            sy = wi[..., 1]
            sx = wi[..., 0] if self.reduction == 4 else sy
            # mulsign_neg(v, s) = v * (−sign(s)): flip so the incident direction lies in the stored wedge
            fx = np.where(sx >= 0, -1.0, 1.0)
            fy = np.where(sy >= 0, -1.0, 1.0)
            wi[..., 0] *= fx
            wi[..., 1] *= fy
            wo[..., 0] *= fx
            wo[..., 1] *= fy
        m = wi + wo
        m /= np.linalg.norm(m, axis=-1, keepdims=True).clip(1e-300)

        def elevation(d: Array) -> Array:
            dist = np.sqrt(d[..., 0] ** 2 + d[..., 1] ** 2 + (d[..., 2] - 1.0) ** 2)
            return 2.0 * np.arcsin(np.clip(0.5 * dist, 0.0, 1.0))

        theta_i = elevation(wi)
        phi_i = np.arctan2(wi[..., 1], wi[..., 0])
        theta_m = elevation(m)
        phi_m = np.arctan2(m[..., 1], m[..., 0])
        u_wi = np.stack([np.sqrt(theta_i * (2 / math.pi)), (phi_i + math.pi) / (2 * math.pi)], -1)
        u_m1 = ((phi_m - phi_i) if self.isotropic else phi_m) + math.pi
        u_m1 = u_m1 / (2 * math.pi)
        u_m1 = u_m1 - np.floor(u_m1)
        u_m = np.stack([np.sqrt(theta_m * (2 / math.pi)), u_m1], -1)
        sample = self._vndf.invert(u_m, phi_i, theta_i)
        spec = np.stack([t.eval(sample, phi_i, theta_i) for t in self._rgb], -1)
        if self.jacobian:
            zero = np.zeros(theta_i.shape)
            ndf = self._ndf.eval(u_m, zero, zero)
            sig = self._sigma.eval(u_wi, zero, zero)
            spec = spec * (ndf / (4.0 * sig))[..., None]
        return np.where(active[..., None], spec, 0.0)

    def eval(self, i: ArrayLike, o: ArrayLike) -> Array:
        """The BRDF ``f = eval_cosine(i, o) / cos θ_o`` of the tensor file, evaluated like Mitsuba 3's
        ``measured`` plugin, sr⁻¹.

        Parameters
        ----------
        i, o : array_like, shape (..., 3)
            Unit light and view directions in the local frame.

        Returns
        -------
        ndarray, shape (..., 3)
            Linear RGB BRDF in sr⁻¹; 0 where either direction is below the horizon.
        """
        o = np.asarray(o, dtype=np.float64)
        v = self.eval_cosine(i, o)
        cos_o = o[..., 2]
        return np.divide(v, cos_o[..., None], out=np.zeros_like(v), where=cos_o[..., None] > 0)

    def parameters(self) -> dict[str, Any]:
        """The file's summary, for ``reflecto info``.

        Returns
        -------
        dict
            ``description`` (the file's own), ``theta_i_deg`` (incidence angles, degrees),
            ``isotropic`` and ``table`` (the ``rgb`` table size).
        """
        return {
            "description": self.description,
            "theta_i_deg": np.degrees(self.theta_i).round(2).tolist(),
            "isotropic": self.isotropic,
            "table": f"{self._rgb[0].h}x{self._rgb[0].w} RGB per incident direction",
        }


register_reader(Reader("rgl", "an RGL tensor file (.bsdf)", (".bsdf",), (b"tensor_file\x00",), RGLBRDF))
