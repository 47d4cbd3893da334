"""Hemicube tabulation of functions on the upper hemisphere (algorithm-reference §9).

Layout in the local frame (``x = t, y = b, z = n``), resolution ``N`` (even):

* face 0, **top** (plane z = 1): ``N × N`` texels over ``u, v ∈ [−1, 1]``, direction
  ``∝ (u, v, 1)``; row index from ``v``, column index from ``u``;
* faces 1–4, **+X, −X, +Y, −Y** half faces: ``N/2 × N`` texels, column from
  ``a ∈ [−1, 1]``, row from ``b = z ∈ [0, 1]``; directions ``∝ (±1, a, b)`` and
  ``(a, ±1, b)``.

Values are stored in one flat array of ``3 N²`` texels (top first, then +X, −X, +Y, −Y,
each row-major), optionally with trailing channel axes. The paper uses ``N = 512``
(Lan et al. 2010, §6: "512×512 pixels on top face and 512×256 pixels on each side").
"""

from __future__ import annotations

import functools
import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import _kernels, geometry
from .errors import ParameterError

Array = NDArray[np.float64]

FACE_NAMES = ("top", "+x", "-x", "+y", "-y")


def _face_antiderivative(u: Array, v: Array) -> Array:
    """``A(u, v) = atan2(uv, √(1 + u² + v²))``, antiderivative of ``(1+u²+v²)^−3/2``.

    (AR 9.2)
    """
    return np.arctan2(u * v, np.sqrt(1.0 + u * u + v * v))


def _rect_solid_angle(u0: Array, u1: Array, v0: Array, v1: Array) -> Array:
    """Exact solid angle of the face rectangle ``[u0,u1] × [v0,v1]`` at unit distance."""
    a = _face_antiderivative
    return a(u0, v0) - a(u0, v1) - a(u1, v0) + a(u1, v1)


#: The largest top-face resolution (texels per side): 3·4096² texels of directions, solid
#: angles and lookups are ≈ 2 GB; a model file holds at most 2048.
MAX_RESOLUTION = 4096


class Hemicube:
    """Geometry of an ``N``-resolution hemicube: texel directions, solid angles, lookups.

    Parameters
    ----------
    n
        Top-face resolution ``N`` (even, in ``[4, MAX_RESOLUTION]``). Side faces are ``N/2 × N``.

    Attributes
    ----------
    size : int
        Number of texels, ``3 N²``.
    directions : ndarray, shape (size, 3)
        Unit direction through each texel centre.
    solid_angles : ndarray, shape (size,)
        Exact texel solid angles in sr; they sum to 2π.
    """

    def __init__(self, n: int = 512) -> None:
        if (isinstance(n, bool) or not isinstance(n, (int, float, np.integer, np.floating)) or not math.isfinite(n)
                or int(n) != n or n < 4 or n % 2 or n > MAX_RESOLUTION):
            raise ParameterError(f"hemicube resolution must be an even integer in [4, {MAX_RESOLUTION}], got {n!r}")
        self.n = int(n)
        self.half = self.n // 2
        self.top_size = self.n * self.n
        self.side_size = self.half * self.n
        self.size = self.top_size + 4 * self.side_size
        self.offsets = np.array([0] + [self.top_size + k * self.side_size for k in range(4)])
        self._max_row = np.array([self.n - 1] + [self.half - 1] * 4)
        self.directions, self.solid_angles = self._texel_geometry()
        self.cos_theta = np.ascontiguousarray(self.directions[:, 2])
        #: ``cos θ · Ω`` per texel: the weights of the NDF normalization ∫ D cos θ dω = 1
        self.projected_solid_angles = self.cos_theta * self.solid_angles
        self._pad_src, self._pad_w, self._pad_offsets = self._padding()
        self._pad_border = self._padding_border()

    # ------------------------------------------------------------------ geometry
    def face_shape(self, face: int) -> tuple[int, int]:
        """The texel grid of one face.

        Parameters
        ----------
        face
            0 = top, 1..4 = +X, −X, +Y, −Y.

        Returns
        -------
        tuple of int
            ``(N, N)`` for the top, ``(N/2, N)`` for a side face.
        """
        return (self.n, self.n) if face == 0 else (self.half, self.n)

    def face_values(self, values: ArrayLike, face: int) -> Array:
        """View of one face of a flat texel array.

        Parameters
        ----------
        values : array_like, shape (size,) or (size, ...)
            Texel values (any trailing channel axes).
        face
            0 = top, 1..4 = +X, −X, +Y, −Y.

        Returns
        -------
        ndarray, shape ``face_shape(face) + values.shape[1:]``
            A view (not a copy) of that face, rows and columns as in the module docstring.
        """
        values = np.asarray(values)
        start = self.offsets[face]
        rows, cols = self.face_shape(face)
        return values[start : start + rows * cols].reshape((rows, cols) + values.shape[1:])

    def _texel_geometry(self) -> tuple[Array, Array]:
        n, half = self.n, self.half
        edges = np.linspace(-1.0, 1.0, n + 1)
        centres = 0.5 * (edges[:-1] + edges[1:])
        bedges = np.linspace(0.0, 1.0, half + 1)
        bcentres = 0.5 * (bedges[:-1] + bedges[1:])

        dirs, omegas = [], []
        # top: rows = v, cols = u
        v, u = np.meshgrid(centres, centres, indexing="ij")
        dirs.append(np.stack([u, v, np.ones_like(u)], axis=-1).reshape(-1, 3))
        v0, u0 = np.meshgrid(edges[:-1], edges[:-1], indexing="ij")
        v1, u1 = np.meshgrid(edges[1:], edges[1:], indexing="ij")
        omegas.append(_rect_solid_angle(u0, u1, v0, v1).ravel())
        # sides: rows = b (z), cols = a
        b, a = np.meshgrid(bcentres, centres, indexing="ij")
        b0, a0 = np.meshgrid(bedges[:-1], edges[:-1], indexing="ij")
        b1, a1 = np.meshgrid(bedges[1:], edges[1:], indexing="ij")
        side_omega = _rect_solid_angle(a0, a1, b0, b1).ravel()
        one = np.ones_like(a)
        for d in (
            np.stack([one, a, b], -1),
            np.stack([-one, a, b], -1),
            np.stack([a, one, b], -1),
            np.stack([a, -one, b], -1),
        ):
            dirs.append(d.reshape(-1, 3))
            omegas.append(side_omega)
        return geometry.normalize(np.concatenate(dirs)), np.concatenate(omegas)

    # ------------------------------------------------------------- coordinates
    def _face_coords(self, dirs: ArrayLike) -> tuple[NDArray[np.intp], Array, Array]:
        """Face id and continuous texel coordinates (col, row); texel centres at integers."""
        d = np.asarray(dirs, dtype=np.float64)
        shape = d.shape[:-1]
        x, y, z = d.reshape(-1, 3).T.copy()  # contiguous copies: faster ufuncs, and safe to modify
        face, col, row = self._face_coords_xyz(x, y, z)
        return face.reshape(shape), col.reshape(shape), row.reshape(shape)

    def _face_coords_xyz(self, x: Array, y: Array, z: Array) -> tuple[NDArray[np.intp], Array, Array]:
        np.maximum(z, 0.0, out=z)
        ax, ay = np.abs(x), np.abs(y)
        m = np.maximum(ax, ay)
        top = z >= m
        xdom = ax >= ay
        face = np.where(top, 0, np.where(xdom, 1 + (x < 0), 3 + (y < 0)))
        denom = np.where(top, z, m)
        denom[denom <= 0] = 1.0
        inv = np.divide(0.5 * self.n, denom, out=denom)
        half_n = 0.5 * self.n - 0.5
        # column coordinate a = x/z (top), y/|x| (±X), x/|y| (±Y); row b = y/z (top), z/m (sides)
        col = np.where(xdom & ~top, y, x)
        col *= inv
        col += half_n
        row = np.where(top, y, z)
        row *= inv
        row += np.where(top, half_n, -0.5)
        return face, col, row

    def index(self, dirs: ArrayLike) -> NDArray[np.intp]:
        """Flat index of the texel containing each direction (nearest texel).

        Directions below the horizon are clamped to it. ``dirs`` need not be unit
        length (only ratios of components enter).

        Parameters
        ----------
        dirs : array_like, shape (..., 3)
            Directions in the local frame.

        Returns
        -------
        ndarray of intp, shape ``dirs.shape[:-1]``
            Indices into the flat ``(size,)`` texel array.
        """
        d = _kernels.as_dirs(dirs)
        out = np.empty(len(d), dtype=np.intp)
        _kernels.cube_index(self.n, d, out)
        return out.reshape(np.shape(dirs)[:-1])

    def index_numpy(self, dirs: ArrayLike) -> NDArray[np.intp]:
        """NumPy reference of :meth:`index`.

        Parameters
        ----------
        dirs : array_like, shape (..., 3)
            Directions in the local frame.

        Returns
        -------
        ndarray of intp, shape ``dirs.shape[:-1]``
            Flat texel indices (the same as :meth:`index`).
        """
        face, col, row = self._face_coords(dirs)
        # col, row ≥ −0.5, so truncation of (x + 0.5) is the floor
        col += 0.5
        row += 0.5
        c = col.astype(np.intp)
        np.minimum(c, self.n - 1, out=c)
        r = row.astype(np.intp)
        np.minimum(r, self._max_row[face], out=r)
        r *= self.n
        r += c
        r += self.offsets[face]
        return r

    # ------------------------------------------------------------ interpolation
    def _padding(self) -> tuple[NDArray[np.intp], Array, NDArray[np.intp]]:
        """Sources and weights of every texel of the 1-texel-padded faces.

        A border texel takes the bilinear interpolation, on the neighbouring face, at
        the border texel's own direction; so a bilinear lookup in the padded faces is
        continuous across seams and second-order accurate there. Below the horizon
        the border mirrors the bottom row.
        """
        n, half = self.n, self.half
        dirs, offs, start = [], [], 0
        for face in range(5):
            rows, cols = self.face_shape(face)
            rr, cc = np.meshgrid(np.arange(-1, rows + 1), np.arange(-1, cols + 1), indexing="ij")
            a = -1.0 + (cc + 0.5) * 2.0 / n
            if face == 0:
                d = np.stack([a, -1.0 + (rr + 0.5) * 2.0 / n, np.ones_like(a)], -1)
            else:
                b = np.abs((rr + 0.5) / half)
                one = np.ones_like(a)
                d = {
                    1: np.stack([one, a, b], -1),
                    2: np.stack([-one, a, b], -1),
                    3: np.stack([a, one, b], -1),
                    4: np.stack([a, -one, b], -1),
                }[face]
            dirs.append(geometry.normalize(d).reshape(-1, 3))
            offs.append(start)
            start += (rows + 2) * (cols + 2)
        fface, col, row = self._face_coords(np.concatenate(dirs))
        rows_f = np.where(fface == 0, n, half)
        c0 = np.clip(np.floor(col).astype(np.intp), 0, n - 2)
        r0 = np.clip(np.floor(row).astype(np.intp), 0, rows_f - 2)
        fc = np.clip(col - c0, 0.0, 1.0)
        fr = np.clip(row - r0, 0.0, 1.0)
        base = self.offsets[fface] + r0 * n + c0
        src = np.stack([base, base + 1, base + n, base + n + 1], axis=1)
        w = np.stack([(1 - fr) * (1 - fc), (1 - fr) * fc, fr * (1 - fc), fr * fc], axis=1)
        return src, w, np.array(offs)

    def _padding_border(self) -> NDArray[np.intp]:
        """Padded indices of the 1-texel border of every face (the rest copies the face)."""
        out = []
        for face in range(5):
            rows, cols = self.face_shape(face)
            m = np.ones((rows + 2, cols + 2), bool)
            m[1:-1, 1:-1] = False
            out.append(self._pad_offsets[face] + np.flatnonzero(m))
        return np.concatenate(out)

    def pad(self, values: ArrayLike) -> Array:
        """Padded-face copy of ``values`` for repeated :meth:`lookup` calls.

        Each face gains a 1-texel border interpolated from its neighbours, so that
        bilinear lookups are continuous across seams.

        Parameters
        ----------
        values : array_like, shape (size,) or (size, C)
            Texel values.

        Returns
        -------
        ndarray
            The padded faces, one after the other, each ``(rows + 2) × (cols + 2)``
            (flattened), plus the channel axis if ``values`` has one.
        """
        values = np.asarray(values, dtype=np.float64)
        if values.ndim == 1:
            # inside each face the padded copy is the face itself (interpolation weight 1
            # at the texel): copy it; only the 1-texel border is interpolated
            out = np.empty(len(self._pad_src))
            for face in range(5):
                rows, cols = self.face_shape(face)
                o = self._pad_offsets[face]
                inner = out[o : o + (rows + 2) * (cols + 2)].reshape(rows + 2, cols + 2)[1:-1, 1:-1]
                inner[...] = self.face_values(values, face)
            _kernels.pad_border(np.ascontiguousarray(values), self._pad_border, self._pad_src, self._pad_w, out)
            return out
        return self.pad_numpy(values)

    def pad_numpy(self, values: ArrayLike) -> Array:
        """NumPy reference of :meth:`pad` (every padded texel by its interpolation weights).

        Parameters
        ----------
        values : array_like, shape (size,) or (size, C)
            Texel values.

        Returns
        -------
        ndarray
            The padded faces, as :meth:`pad` returns them.
        """
        values = np.asarray(values, dtype=np.float64)
        w = self._pad_w if values.ndim == 1 else self._pad_w[..., None]
        return np.sum(values[self._pad_src] * w, axis=1)

    def lookup(self, values: ArrayLike | None, dirs: ArrayLike, padded: Array | None = None) -> Array:
        """Bilinear interpolation of texel ``values`` at directions ``dirs``.

        Continuous across face seams (the faces are padded from their neighbours).

        Parameters
        ----------
        values
            Shape ``(size,)`` or ``(size, C)``.
        dirs
            Unit directions, shape ``(..., 3)``; below-horizon ones are clamped.
        padded
            ``self.pad(values)``, to skip recomputing it on repeated lookups (``values`` may then be
            ``None``).

        Returns
        -------
        ndarray, shape ``dirs.shape[:-1]`` (+ ``(C,)``)
            The interpolated values, in the units of ``values``.
        """
        values = np.asarray(values)
        padded = self.pad(values) if padded is None else padded
        if padded.ndim == 1:  # the common case: one fused compiled loop, same arithmetic
            d = _kernels.as_dirs(dirs)
            out = np.empty(len(d))
            _kernels.cube_lookup(padded, self._pad_offsets, self.n, d, out)
            return out.reshape(np.shape(dirs)[:-1])
        return self.lookup_numpy(values, dirs, padded)

    def lookup_numpy(self, values: ArrayLike | None, dirs: ArrayLike, padded: Array | None = None) -> Array:
        """NumPy reference of :meth:`lookup` (any number of channels).

        Parameters
        ----------
        values : array_like, shape (size,) or (size, C), or None
            Texel values (``None`` when ``padded`` is given).
        dirs : array_like, shape (..., 3)
            Directions; below-horizon ones are clamped.
        padded
            ``self.pad(values)``, if already at hand.

        Returns
        -------
        ndarray, shape ``dirs.shape[:-1]`` (+ ``(C,)``)
            The bilinearly interpolated values.
        """
        values = np.asarray(values)
        padded = self.pad(values) if padded is None else padded
        face, col, row = self._face_coords(dirs)
        # shift into padded coordinates: col + 1 ∈ [0.5, n + 0.5], row + 1 ∈ [0.5, rows + 0.5],
        # so truncation is the floor and the 2×2 stencil stays inside the padded face
        col += 1.0
        row += 1.0
        ci = col.astype(np.intp)
        ri = row.astype(np.intp)
        fc = col - ci
        fr = row - ri
        np.minimum(ci, self.n, out=ci)
        width = self.n + 2
        ri *= width
        ri += ci
        ri += self._pad_offsets[face]
        base = ri
        if padded.ndim > 1:
            fc = fc[..., None]
            fr = fr[..., None]
        v00 = padded[base]
        v01 = padded[base + 1]
        base += width
        v10 = padded[base]
        v11 = padded[base + 1]
        v01 -= v00
        v01 *= fc
        v00 += v01
        v11 -= v10
        v11 *= fc
        v10 += v11
        v10 -= v00
        v10 *= fr
        v00 += v10
        return v00

    # ----------------------------------------------------------------- splatting
    def splat(
        self, dirs: ArrayLike, values: ArrayLike, weights: ArrayLike | None = None
    ) -> tuple[Array, Array]:
        """Accumulate weighted point samples into their nearest texels.

        Returns ``(Σ w, Σ w·value)`` per texel (algorithm-reference §9.4: an average,
        not a histogram, so no Jacobian enters). Divide the second by the first where
        it is positive to get the texel estimate.

        Parameters
        ----------
        dirs
            Sample directions, shape ``(M, 3)``.
        values
            Sample values, shape ``(M,)`` or ``(M, C)``.
        weights
            Sample weights, shape ``(M,)``; ones if omitted.

        Returns
        -------
        wsum : ndarray, shape (size,)
        wvsum : ndarray, shape (size,) or (size, C)
        """
        values = np.asarray(values, dtype=np.float64)
        d = _kernels.as_dirs(dirs)
        w = np.ones(len(d)) if weights is None else np.ascontiguousarray(weights, dtype=np.float64).ravel()
        if len(w) != len(d) or values.shape[0] != len(d):
            raise ValueError(f"splat: {len(d)} directions, {values.shape[0]} values, {len(w)} weights")
        channels = 1 if values.ndim == 1 else int(np.prod(values.shape[1:]))  # also for M = 0
        v2 = np.ascontiguousarray(values.reshape(len(d), channels))
        wsum = np.zeros(self.size)
        wvsum = np.zeros((self.size, v2.shape[1]))
        _kernels.splat(self.n, d, v2, w, wsum, wvsum)
        return wsum, (wvsum[:, 0] if values.ndim == 1 else wvsum)

    def splat_numpy(
        self, dirs: ArrayLike, values: ArrayLike, weights: ArrayLike | None = None
    ) -> tuple[Array, Array]:
        """Reference NumPy implementation of :meth:`splat` (``np.bincount``).

        Parameters
        ----------
        dirs : array_like, shape (M, 3)
            Sample directions.
        values : array_like, shape (M,) or (M, C)
            Sample values.
        weights : array_like, shape (M,), optional
            Sample weights; ones if omitted.

        Returns
        -------
        wsum : ndarray, shape (size,)
            ``Σ w`` per texel.
        wvsum : ndarray, shape (size,) or (size, C)
            ``Σ w·value`` per texel.
        """
        idx = self.index(dirs).ravel()
        values = np.asarray(values, dtype=np.float64)
        w = np.ones(idx.shape) if weights is None else np.asarray(weights, dtype=np.float64).ravel()
        wsum = np.bincount(idx, weights=w, minlength=self.size)
        if values.ndim == 1:
            wvsum = np.bincount(idx, weights=w * values, minlength=self.size)
        else:
            wvsum = np.stack(
                [np.bincount(idx, weights=w * values[:, k], minlength=self.size) for k in range(values.shape[1])],
                axis=1,
            )
        return wsum, wvsum  # type: ignore[return-value]  # numpy stub: weighted bincount is float64, not intp

    def smooth(self, values: ArrayLike, passes: int = 1) -> Array:
        """Binomial ``[1 2 1]ᵀ[1 2 1]/16`` filter applied ``passes`` times, face by face.

        The faces are padded from their neighbours (:meth:`pad`), so the filter runs
        across seams; ``passes`` filters have a standard deviation of ``√(passes/2)``
        texels.

        Parameters
        ----------
        values : array_like, shape (size,)
            Texel values.
        passes
            Number of filter passes (0 returns the values as float64).

        Returns
        -------
        ndarray, shape (size,)
            The filtered values.
        """
        v = np.asarray(values, dtype=np.float64)
        for _ in range(passes):
            padded = self.pad(v)
            out = np.empty_like(v)
            for face in range(5):
                rows, cols = self.face_shape(face)
                start = self._pad_offsets[face]
                a = padded[start : start + (rows + 2) * (cols + 2)].reshape(rows + 2, cols + 2)
                h = a[:, :-2] + 2.0 * a[:, 1:-1] + a[:, 2:]
                out[self.offsets[face] : self.offsets[face] + rows * cols] = (
                    (h[:-2] + 2.0 * h[1:-1] + h[2:]) / 16.0).ravel()
            v = out
        return v

    # -------------------------------------------------------------- resampling
    def block_reduce(self, values: ArrayLike, factor: int) -> Array:
        """Sum over ``factor × factor`` texel blocks, face by face.

        Parameters
        ----------
        values : array_like, shape (size,) or (size, C)
            Texel values.
        factor
            Block size; ``N/factor`` must be an even integer.

        Returns
        -------
        ndarray, shape (3 (N/factor)², ...)
            Block sums, laid out as the coarse hemicube's texels.

        Raises
        ------
        ParameterError
            For a factor that does not divide the hemicube into an even resolution.
        """
        self._check_factor(factor)
        values = np.ascontiguousarray(values, dtype=np.float64)
        parent = _block_parents(self.n, factor)
        m = 3 * (self.n // factor) ** 2
        flat = values.reshape(len(values), -1)
        out = np.zeros((m, flat.shape[1]))
        _kernels.scatter_add(flat, parent, out)
        return out.reshape((m,) + values.shape[1:])

    def block_reduce_numpy(self, values: ArrayLike, factor: int) -> Array:
        """NumPy reference of :meth:`block_reduce`.

        Parameters
        ----------
        values : array_like, shape (size,) or (size, C)
            Texel values.
        factor
            Block size.

        Returns
        -------
        ndarray, shape (3 (N/factor)², ...)
            Block sums (not checked: call :meth:`block_reduce` for the checked version).
        """
        out = []
        for face in range(5):
            rows, cols = self.face_shape(face)
            v = self.face_values(values, face)
            tail = v.shape[2:]
            v = v.reshape((rows // factor, factor, cols // factor, factor) + tail).sum(axis=(1, 3))
            out.append(v.reshape((-1,) + tail))
        return np.concatenate(out)

    def downsample(self, values: ArrayLike, factor: int) -> tuple[Hemicube, Array]:
        """Solid-angle-weighted box filter to resolution ``N/factor``.

        ``D_coarse = Σ D_t Ω_t / Σ Ω_t`` over the fine texels of each coarse texel
        (algorithm-reference §1.4).

        Parameters
        ----------
        values : array_like, shape (size,) or (size, C)
            Texel values (e.g. D in sr⁻¹).
        factor
            Reduction factor; ``N/factor`` must be an even integer.

        Returns
        -------
        coarse : Hemicube
            The hemicube of resolution ``N/factor``.
        values : ndarray, shape (coarse.size,) or (coarse.size, C)
            The solid-angle-weighted block means, in the units of ``values``.
        """
        coarse = self._coarse(factor)
        values = np.asarray(values, dtype=np.float64)
        om = self.solid_angles if values.ndim == 1 else self.solid_angles[:, None]
        num = self.block_reduce(values * om, factor)
        den = self.block_reduce(self.solid_angles, factor)
        return coarse, num / (den if values.ndim == 1 else den[:, None])

    def moments(self, values: ArrayLike, factor: int) -> tuple[Array, Array]:
        """Zeroth and first moments of ``values`` over coarse blocks.

        Integrals of a linear function of ``h`` against ``v`` are exact on these moments.

        Parameters
        ----------
        values : array_like, shape (size,)
            Texel values.
        factor
            Block size; ``N/factor`` must be an even integer.

        Returns
        -------
        mass : ndarray, shape (size_c,)
            ``mass_T = Σ_t v_t Ω_t`` over the fine texels ``t`` of each coarse texel ``T``.
        first : ndarray, shape (size_c, 3)
            ``first_T = Σ_t v_t Ω_t h_t``.
        """
        self._check_factor(factor)
        w = np.asarray(values, dtype=np.float64) * self.solid_angles
        mass = self.block_reduce(w, factor)
        first = self.block_reduce(w[:, None] * self.directions, factor)
        return mass, first

    def _check_factor(self, factor: int) -> None:
        if factor < 1 or self.n % factor or (self.n // factor) % 2:
            raise ParameterError(f"cannot downsample a {self.n}-hemicube by {factor}")

    def _coarse(self, factor: int) -> Hemicube:
        self._check_factor(factor)
        return hemicube(self.n // factor)

    # --------------------------------------------------------------- symmetry
    def permutation(self, matrix: ArrayLike) -> NDArray[np.intp]:
        """Texel permutation ``p`` with ``values[p]`` = values under the map ``h → M h``.

        ``M`` must be one of the hemicube's symmetries (τ = R_n, M_t, M_b, or a
        rotation by a multiple of 90° about n). ``new[t] = old[p[t]]`` is the value of
        ``old`` at ``M·h_t``. Exact: raises if ``M`` does not map texels onto texels.

        Parameters
        ----------
        matrix : array_like, shape (3, 3)
            The symmetry ``M`` (e.g. :data:`reflecto.geometry.TAU`).

        Returns
        -------
        ndarray of intp, shape (size,)
            The permutation (cached, read-only).

        Raises
        ------
        ParameterError
            When ``M`` maps texels below the horizon or not exactly onto texels.
        """
        key = tuple(np.round(np.asarray(matrix, dtype=np.float64), 12).ravel())
        return _permutation(self.n, key)

    def symmetrize(self, values: ArrayLike, matrix: ArrayLike) -> Array:
        """Values at the mirrored directions: ``out[t] = values(M h_t)`` (exact).

        Parameters
        ----------
        values : array_like, shape (size,) or (size, C)
            Texel values.
        matrix : array_like, shape (3, 3)
            A hemicube symmetry (see :meth:`permutation`).

        Returns
        -------
        ndarray
            The permuted values, same shape as ``values``.
        """
        return np.asarray(values)[self.permutation(matrix)]

    # --------------------------------------------------------------- integrals
    def integrate(self, values: ArrayLike, weight: ArrayLike | None = None) -> Array:
        """``Σ_t values_t · weight_t · Ω_t`` (≈ ∫ values·weight dω).

        Parameters
        ----------
        values : array_like, shape (size,) or (size, ...)
            Texel values.
        weight : array_like, shape (size,), optional
            Per-texel weight (e.g. :attr:`cos_theta` for ``∫ D cos θ dω``); 1 if omitted.

        Returns
        -------
        ndarray
            The integral, shape ``values.shape[1:]`` (a 0-d array for flat ``values``).
        """
        values = np.asarray(values, dtype=np.float64)
        w = self.solid_angles if weight is None else self.solid_angles * np.asarray(weight)
        return np.tensordot(w, values, axes=(0, 0))

    # ------------------------------------------------------------------ images
    def unfold(self, values: ArrayLike, fill: float = np.nan) -> Array:
        """Unfolded cross image, shape ``(2N, 2N)`` (+ channels), top face in the middle.

        Image rows follow +y, columns +x; each side face is folded out from the top
        face's edge it touches, horizon on the outside.

        Parameters
        ----------
        values : array_like, shape (size,) or (size, C)
            Texel values.
        fill
            Value of the four corner squares outside the cross.

        Returns
        -------
        ndarray, shape (2N, 2N) or (2N, 2N, C)
            The image.
        """
        values = np.asarray(values, dtype=np.float64)
        n, h = self.n, self.half
        img = np.full((2 * n, 2 * n) + values.shape[1:], fill)
        img[h : h + n, h : h + n] = self.face_values(values, 0)
        px = self.face_values(values, 1)  # rows b, cols a (= y)
        img[h : h + n, n + h :] = np.swapaxes(px[::-1], 0, 1)
        mx = self.face_values(values, 2)
        img[h : h + n, :h] = np.swapaxes(mx, 0, 1)
        py = self.face_values(values, 3)  # rows b, cols a (= x)
        img[n + h :, h : h + n] = py[::-1]
        my = self.face_values(values, 4)
        img[:h, h : h + n] = my
        return img


@functools.lru_cache(maxsize=8)
def hemicube(n: int = 512) -> Hemicube:
    """Cached :class:`Hemicube` of resolution ``n`` (geometry is immutable).

    Parameters
    ----------
    n
        Top-face resolution ``N`` (even, ≥ 4); the paper's is 512 (§6).

    Returns
    -------
    Hemicube
        The shared instance for ``n`` (an LRU cache keeps the last eight).
    """
    return Hemicube(n)


@functools.lru_cache(maxsize=16)
def _block_parents(n: int, factor: int) -> NDArray[np.intp]:
    """Coarse texel (resolution ``n/factor``) of every texel of an ``n``-hemicube."""
    fine, nc = hemicube(n), n // factor
    coarse_offsets = [0] + [nc * nc + k * nc * (nc // 2) for k in range(4)]
    parent = np.empty(fine.size, dtype=np.intp)
    for face in range(5):
        rows, cols = fine.face_shape(face)
        r, c = np.meshgrid(np.arange(rows) // factor, np.arange(cols) // factor, indexing="ij")
        start = fine.offsets[face]
        parent[start : start + rows * cols] = (coarse_offsets[face] + r * (cols // factor) + c).ravel()
    parent.setflags(write=False)
    return parent


@functools.lru_cache(maxsize=32)
def _permutation(n: int, key: tuple[float, ...]) -> NDArray[np.intp]:
    cube = hemicube(n)
    m = np.asarray(key).reshape(3, 3)
    mapped = geometry.apply(m, cube.directions)
    if np.any(mapped[:, 2] < 0):
        raise ParameterError("symmetry must keep the normal: it maps texels below the horizon")
    perm = cube.index(mapped)
    if not np.array_equal(np.sort(perm), np.arange(cube.size)) or not np.allclose(
        cube.directions[perm], mapped, atol=1e-12
    ):
        raise ParameterError("matrix does not map hemicube texels exactly onto texels")
    perm.setflags(write=False)
    return perm
