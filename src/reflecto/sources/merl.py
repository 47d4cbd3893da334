"""MERL BRDF database ``.binary`` files: reader, writer, tabulation (algorithm-reference §6.1).

File layout: three little-endian int32 dimensions ``(90, 90, 180)`` = (θ_h, θ_d, φ_d)
bins, then ``3·90·90·180`` little-endian float64 values as three consecutive colour
blocks R, G, B. Linear index ``i_φd + 180·i_θd + 180·90·i_θh``. Stored values times
``(1/1500, 1.15/1500, 1.66/1500)`` give the BRDF in sr⁻¹. Negative values (−1) mark
bins that were not measured.

Bin indices (floor, clamped): ``i_θh = ⌊90·√(θ_h/(π/2))⌋``; ``i_θd = ⌊θ_d/(π/2)·90⌋``;
``φ_d < 0`` moved by ``π`` (reciprocity), ``i_φd = ⌊φ_d/π·180⌋`` (``φ_d = π`` clamped into the
last bin, as MERL's ``readBRDF.cpp`` does). Indices are
corrected so that a value exactly on a bin edge falls in the bin that *starts* there,
as the spec's half-open intervals say, regardless of floating-point rounding.

Bin centres (tabulation): ``θ_h = ((k+½)/90)²·π/2``, ``θ_d = (k+½)°``, ``φ_d = (k+½)°``,
``φ_h = 0``.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .. import geometry
from ..brdf import ALBEDO_RANGE, BRDFSource, Reader, check_plausible, check_projected, read_file_bytes, register_reader
from ..errors import FileFormatError, ParameterError, shown_path
from ..io import atomic_write

Array = NDArray[np.float64]

N_THETA_H, N_THETA_D, N_PHI_D = 90, 90, 180
SHAPE = (N_THETA_H, N_THETA_D, N_PHI_D)
N_BINS = N_THETA_H * N_THETA_D * N_PHI_D
#: Factors from stored values to sr⁻¹ (R, G, B), as in MERL's readBRDF.cpp.
SCALE = np.array([1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0])
HEADER_BYTES = 12
FILE_BYTES = HEADER_BYTES + 8 * 3 * N_BINS


def theta_h_edge(k: ArrayLike) -> Array:
    """Lower edge of θ_h bin ``k``: ``(k/90)²·π/2`` (MERL's square-root mapping, algorithm-reference §6.1).

    Parameters
    ----------
    k : array_like
        Bin indices (0..90; 90 gives the upper edge of the last bin).

    Returns
    -------
    ndarray
        θ_h in radians, shape of ``k``.
    """
    k = np.asarray(k, dtype=np.float64)
    return (k / N_THETA_H) ** 2 * (0.5 * math.pi)


def _fix_edges(idx: NDArray[np.intp], value: Array, edge: Callable[[NDArray[np.intp]], Array],
               n: int) -> NDArray[np.intp]:
    """Move ``idx`` by ±1 where rounding put ``value`` on the wrong side of a bin edge."""
    idx = np.clip(idx, 0, n - 1)
    up = (idx < n - 1) & (value >= edge(idx + 1))
    idx = idx + up
    down = (idx > 0) & (value < edge(idx))
    return idx - down


def theta_h_index(theta_h: ArrayLike) -> NDArray[np.intp]:
    """MERL θ_h bin index ``⌊√(θ_h/(π/2))·90⌋`` (square-root mapping), edge-exact.

    Parameters
    ----------
    theta_h : array_like
        Half-vector polar angle, radians (negative values count as 0).

    Returns
    -------
    ndarray of intp
        Index in [0, 89], shape of ``theta_h``, consistent with :func:`theta_h_edge`.
    """
    t = np.asarray(theta_h, dtype=np.float64)
    raw = np.floor(np.sqrt(np.maximum(t, 0.0) / (0.5 * math.pi)) * N_THETA_H).astype(np.intp)
    return _fix_edges(raw, t, theta_h_edge, N_THETA_H)


def theta_d_index(theta_d: ArrayLike) -> NDArray[np.intp]:
    """MERL θ_d bin index (1° bins), edge-exact.

    Parameters
    ----------
    theta_d : array_like
        Difference polar angle, radians.

    Returns
    -------
    ndarray of intp
        Index in [0, 89], shape of ``theta_d``.
    """
    t = np.asarray(theta_d, dtype=np.float64)
    raw = np.floor(t / (0.5 * math.pi) * N_THETA_D).astype(np.intp)
    return _fix_edges(raw, t, np.radians, N_THETA_D)


def phi_d_index(phi_d: ArrayLike) -> NDArray[np.intp]:
    """MERL φ_d bin index: add π where negative, 1° bins, edge-exact, clamped (``φ_d = π``: 179, as
    MERL's ``readBRDF.cpp``; algorithm-reference §6.1).

    Parameters
    ----------
    phi_d : array_like
        Difference azimuth, radians, in (−π, π].

    Returns
    -------
    ndarray of intp
        Index in [0, 179], shape of ``phi_d``.
    """
    p = np.asarray(phi_d, dtype=np.float64)
    p = np.where(p < 0, p + math.pi, p)
    raw = np.floor(p / math.pi * N_PHI_D).astype(np.intp)
    return _fix_edges(raw, p, np.radians, N_PHI_D)


def bin_index(i: ArrayLike, o: ArrayLike) -> NDArray[np.intp]:
    """Linear MERL bin index of direction pairs (``i`` is MERL's "in" vector).

    Parameters
    ----------
    i, o : array_like, shape (..., 3)
        Unit directions in the local frame.

    Returns
    -------
    ndarray of intp, shape (...)
        ``φ_d-index + 180·(θ_d-index + 90·θ_h-index)``, an index into the flat
        ``(90·90·180,)`` table.
    """
    th, _, td, pd = geometry.io_to_hd(i, o)
    return phi_d_index(pd) + N_PHI_D * (theta_d_index(td) + N_THETA_D * theta_h_index(th))


def bin_centres() -> tuple[Array, Array, Array]:
    """The bin centres of the MERL grid.

    Returns
    -------
    theta_h : ndarray, shape (90,)
        ``((k + ½)/90)²·π/2``, radians.
    theta_d : ndarray, shape (90,)
        ``k + ½`` degrees, in radians.
    phi_d : ndarray, shape (180,)
        ``k + ½`` degrees, in radians.
    """
    th = ((np.arange(N_THETA_H) + 0.5) / N_THETA_H) ** 2 * (0.5 * math.pi)
    td = np.radians(np.arange(N_THETA_D) + 0.5)
    pd = np.radians(np.arange(N_PHI_D) + 0.5)
    return th, td, pd


def bin_directions() -> tuple[Array, Array]:
    """Direction pairs at every bin centre, with ``φ_h = 0`` (:func:`reflecto.geometry.hd_to_io`).

    Returns
    -------
    i, o : ndarray, shape (90, 90, 180, 3)
        Unit directions in the local frame; some lie below the horizon.
    """
    th, td, pd = bin_centres()
    TH, TD, PD = np.meshgrid(th, td, pd, indexing="ij")
    return geometry.hd_to_io(TH, np.zeros_like(TH), TD, PD)


def read_merl_table(path: str | Path) -> Array:
    """Read a MERL file; returns the stored values scaled to sr⁻¹, shape ``(90, 90, 180, 3)``.

    Unmeasured bins keep their negative value (times the channel scale). Refuses
    files of the wrong size or dimensions, NaN or infinite values, values above
    :func:`~reflecto.brdf.check_projected` (``f·cos θ_i·cos θ_o`` at the bin centres at most
    :data:`~reflecto.brdf.MAX_PROJECTED_BRDF`) and tables without a measured bin.

    Parameters
    ----------
    path
        A MERL ``.binary`` file: 3 int32 dimensions (90, 90, 180), then 3 × 1 458 000
        float64 (R, G, B blocks).

    Returns
    -------
    ndarray, shape (90, 90, 180, 3)
        The BRDF in sr⁻¹ (stored values times :data:`SCALE`), axes θ_h, θ_d, φ_d, RGB.

    Raises
    ------
    FileFormatError
        Naming the file and the problem.
    """
    path = Path(path)
    raw = read_file_bytes(path, FILE_BYTES, f"a MERL file ({FILE_BYTES} bytes)")
    if len(raw) < HEADER_BYTES:
        raise FileFormatError(path, f"truncated MERL file: {len(raw)} bytes, no complete header")
    dims = tuple(int(v) for v in np.frombuffer(raw[:HEADER_BYTES], dtype="<i4"))
    if dims != SHAPE:
        raise FileFormatError(path, f"not a MERL BRDF: dimensions {dims}, expected {SHAPE}")
    if len(raw) != FILE_BYTES:
        what = "truncated" if len(raw) < FILE_BYTES else "oversized"
        raise FileFormatError(path, f"{what} MERL file: {len(raw)} bytes, expected {FILE_BYTES}")
    vals = np.frombuffer(raw, dtype="<f8", offset=HEADER_BYTES).reshape(3, N_BINS)
    if not np.all(np.isfinite(vals)):
        bad = int(np.count_nonzero(~np.isfinite(vals)))
        raise FileFormatError(path, f"{bad} values are NaN or infinite")
    table = (vals * SCALE[:, None]).T.reshape(SHAPE + (3,))
    check_projected(np.maximum(table, 0.0) * _cos_cos()[..., None], path, "its table")
    if not np.any(np.all(table >= 0, axis=-1)):
        raise FileFormatError(path, "no bin holds a measured value (all are negative, MERL's 'unmeasured')")
    return table


def write_merl_table(path: str | Path, table: ArrayLike) -> Path:
    """Write a table in sr⁻¹ (shape ``(90, 90, 180, 3)``) as a MERL file, atomically.

    Stored values are chosen so that reading back reproduces ``table`` bit for bit
    wherever the MERL encoding can represent it (every value that was itself read
    from a MERL file, for example); elsewhere the difference is at most 1 ulp
    (relative 1.1e-16). No exactness is possible beyond that: multiplying by the
    channel scale (not a power of two) reaches only ~86–91 % of float64 values.
    Negative entries are written unchanged as "unmeasured" markers.

    Parameters
    ----------
    path
        The file to write.
    table : array_like, shape (90, 90, 180, 3)
        The BRDF in sr⁻¹ (as :func:`read_merl_table` returns it).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ParameterError
        (a ``ValueError``) For a table of another shape or with NaN or infinite values.
    FileFormatError
        For values above :data:`~reflecto.brdf.MAX_PROJECTED_BRDF` (projected).
    """
    path = Path(path)
    t = np.asarray(table, dtype=np.float64)
    if t.shape != SHAPE + (3,):
        raise ParameterError(f"MERL table must have shape {SHAPE + (3,)}, got {t.shape}")
    if not np.all(np.isfinite(t)):
        raise ParameterError("MERL table contains NaN or infinite values")
    check_projected(np.maximum(t, 0.0) * _cos_cos()[..., None], path, "the table to write")
    flat = t.reshape(N_BINS, 3).T  # (3, N)
    stored = flat / SCALE[:, None]
    for _ in range(2):  # exact round trip where possible: fix products that miss by an ulp
        back = stored * SCALE[:, None]
        miss = back != flat
        if not miss.any():
            break
        stored = np.where(miss, np.nextafter(stored, np.where(back < flat, np.inf, -np.inf)), stored)
    header = np.array(SHAPE, dtype="<i4").tobytes()
    with atomic_write(path) as fh:
        fh.write(header)
        fh.write(np.ascontiguousarray(stored, dtype="<f8").tobytes())
    return path


def tabulate(source: BRDFSource, chunk: int = 1 << 17, progress: Callable[[int], None] | None = None) -> Array:
    """Evaluate ``source`` at every MERL bin centre; shape ``(90, 90, 180, 3)`` in sr⁻¹.

    Bins with a direction below the horizon get 0 (the BRDF of a surface there).

    Parameters
    ----------
    source
        Any BRDF.
    chunk
        Bins evaluated per call of ``source.eval``.
    progress
        Called with the number of bins done after each chunk.

    Returns
    -------
    ndarray, shape (90, 90, 180, 3)
        The table in sr⁻¹.

    Raises
    ------
    ParameterError
        (a ``ValueError``) When the source gives NaN or infinite values.
    """
    i, o = bin_directions()
    i = i.reshape(-1, 3)
    o = o.reshape(-1, 3)
    out = np.zeros((N_BINS, 3))
    for s in range(0, N_BINS, chunk):
        ii, oo = i[s : s + chunk], o[s : s + chunk]
        ok = (ii[:, 2] > 0) & (oo[:, 2] > 0)
        vals = np.zeros((len(ii), 3))
        if ok.any():
            vals[ok] = source.eval(ii[ok], oo[ok])
        out[s : s + chunk] = vals
        if progress is not None:
            progress(len(ii))
    if not np.all(np.isfinite(out)):
        raise ParameterError(f"{shown_path(source.path or source.name)}: the source produced NaN or infinite values")
    return out.reshape(SHAPE + (3,))


@functools.lru_cache(maxsize=1)
def _hh_weights() -> Array:
    """Per-bin weights ``w`` of the hemispherical–hemispherical albedo, shape ``(90, 90, 180)``.

    ``ρ_hh = (1/π) ∫∫ f cos θ_i cos θ_o dω_i dω_o = Σ_bins f w`` (1 for a white Lambertian
    surface; the mean of the directional albedo over cosine-weighted incidence), with
    ``dω_i dω_o = 4 cos θ_d dω_h dω_d``, ``φ_h`` over 2π and ``φ_d`` folded into [0, π)
    (×2): every bin's measure is integrated exactly over its edges; ``cos θ_i cos θ_o =
    (cos θ_h cos θ_d)² − (sin θ_h sin θ_d cos φ_d)²`` (both above the horizon) at its centre.
    """
    th_e = theta_h_edge(np.arange(N_THETA_H + 1))
    td_e = np.radians(np.arange(N_THETA_D + 1.0))
    th, td, pd = bin_centres()
    measure = (4.0 * 2.0 * math.pi * 2.0 * (np.cos(th_e[:-1]) - np.cos(th_e[1:]))[:, None, None]
               * (0.5 * (np.sin(td_e[1:]) ** 2 - np.sin(td_e[:-1]) ** 2))[None, :, None] * math.radians(1.0))
    a = np.cos(th)[:, None, None] * np.cos(td)[None, :, None]
    b = np.sin(th)[:, None, None] * np.sin(td)[None, :, None] * np.cos(pd)[None, None, :]
    w = np.where(a > np.abs(b), measure * (a * a - b * b), 0.0) / math.pi
    w.setflags(write=False)
    return w


@functools.lru_cache(maxsize=1)
def _cos_cos() -> Array:
    """``cos θ_i cos θ_o`` at every bin centre, shape ``(90, 90, 180)``; bins whose centre
    lies below the horizon get the smallest value of the others (a value stored there
    is still read by lookups of directions inside the bin above the horizon)."""
    th, td, pd = bin_centres()
    a = np.cos(th)[:, None, None] * np.cos(td)[None, :, None]
    b = np.sin(th)[:, None, None] * np.sin(td)[None, :, None] * np.cos(pd)[None, None, :]
    c = np.where(a > np.abs(b), a * a - b * b, 0.0)
    c = np.maximum(c, c[c > 0].min())
    c.setflags(write=False)
    return c


def hemispherical_albedo(table: ArrayLike) -> Array:
    """``ρ_hh`` per channel of a MERL table in sr⁻¹ (unmeasured bins count 0), shape ``(3,)``.

    ``ρ_hh = (1/π) ∫∫ f cos θ_i cos θ_o dω_i dω_o`` (1 for a white Lambertian surface).
    Every bin counts with its exact measure, so a damaged bin anywhere raises it (a
    quadrature of the directional albedo can step over a spike between its nodes).

    Parameters
    ----------
    table : array_like, shape (90, 90, 180, 3)
        A MERL table in sr⁻¹; negative (unmeasured) bins count 0.

    Returns
    -------
    ndarray, shape (3,)
        ρ_hh per channel (dimensionless).
    """
    t = np.asarray(table, dtype=np.float64).reshape(N_BINS, 3)
    return np.maximum(t, 0.0).T @ _hh_weights().ravel()


def check_table(source: MerlBRDF, path: Path) -> None:
    """The checks a MERL file's table passes on reading: a finite hemispherical albedo of at
    most ``ALBEDO_RANGE[1]`` per channel, and :func:`reflecto.brdf.check_plausible`.

    Parameters
    ----------
    source
        The table as a source (:meth:`MerlBRDF.from_table` or a file's).
    path
        The file, for the message.

    Raises
    ------
    FileFormatError
        Naming ``path`` and the check that failed.
    """
    rho = hemispherical_albedo(source.table)
    if not np.all(np.isfinite(rho)) or rho.max() > ALBEDO_RANGE[1]:
        raise FileFormatError(path, f"hemispherical albedo {np.round(rho, 4).tolist()} above the plausible "
                              f"{ALBEDO_RANGE[1]:g}: damaged, or not a BRDF in sr⁻¹")
    check_plausible(source, path)


class MerlBRDF(BRDFSource):
    """A MERL ``.binary`` BRDF, looked up bin by bin (no interpolation, as MERL's reader).

    ``eval`` returns 0 for unmeasured (negative) bins and below the horizon; use
    :meth:`valid` to tell them apart.
    """

    kind = "merl"
    #: the ``name`` given to :meth:`from_table` (set there only)
    _name: str

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.table = read_merl_table(self.path)
        self._flat = self.table.reshape(N_BINS, 3)
        self.reciprocal = True  # φ_d folding makes lookups reciprocal by construction
        self.isotropic = True
        check_table(self, self.path)

    @classmethod
    def from_table(cls, table: ArrayLike, name: str = "merl") -> MerlBRDF:
        """Wrap an in-memory table (no file, no plausibility check).

        Parameters
        ----------
        table : array_like, shape (90, 90, 180, 3)
            The BRDF in sr⁻¹, MERL bin order; negative entries are unmeasured.
        name
            The :attr:`name` of the source.

        Returns
        -------
        MerlBRDF
            A source looking up ``table``.
        """
        obj = cls.__new__(cls)
        obj.path = None
        obj.table = np.asarray(table, dtype=np.float64).reshape(SHAPE + (3,))
        obj._flat = obj.table.reshape(N_BINS, 3)
        obj.reciprocal = True
        obj.isotropic = True
        obj._name = name
        return obj

    @property
    def name(self) -> str:
        """The file's stem, or the name given to :meth:`from_table`."""
        return self.path.stem if self.path is not None else getattr(self, "_name", self.kind)

    def eval(self, i: ArrayLike, o: ArrayLike) -> Array:
        """The table's value in the MERL bin of ``(i, o)`` (MERL's bin lookup, no interpolation), sr⁻¹.

        Parameters
        ----------
        i, o
            Unit directions in the local frame, shape ``(N, 3)`` (or broadcastable ``(..., 3)``).

        Returns
        -------
        ndarray, shape ``(N, 3)``
            Linear RGB BRDF; 0 below the horizon and in unmeasured (negative) bins.
        """
        i = np.asarray(i, dtype=np.float64)
        o = np.asarray(o, dtype=np.float64)
        vals = self._flat[bin_index(i, o)]
        ok = (i[..., 2] > 0) & (o[..., 2] > 0)
        return np.where(ok[..., None] & (vals >= 0), vals, 0.0)

    def valid(self, i: ArrayLike, o: ArrayLike) -> NDArray[np.bool_]:
        """Whether the bin of each pair holds a measured (non-negative) value.

        Parameters
        ----------
        i, o : array_like, shape (..., 3)
            Unit directions in the local frame.

        Returns
        -------
        ndarray of bool, shape (...)
            True where all three channels of the bin are ≥ 0 (the horizon is not checked).
        """
        return np.all(self._flat[bin_index(i, o)] >= 0, axis=-1)

    def parameters(self) -> dict[str, Any]:
        """The table's summary, for ``reflecto info``.

        Returns
        -------
        dict
            ``bins`` (the grid), ``valid_bins``, ``invalid_bins`` (unmeasured) and
            ``max_value_sr-1`` (largest measured value per channel, or None).
        """
        valid = np.all(self._flat >= 0, axis=1)
        return {
            "bins": f"{N_THETA_H} x {N_THETA_D} x {N_PHI_D}",
            "valid_bins": int(valid.sum()),
            "invalid_bins": int((~valid).sum()),
            "max_value_sr-1": self._flat[valid].max(axis=0).tolist() if valid.any() else None,
        }


register_reader(Reader("merl", "a MERL table (.binary)", (".binary",),
                       (b"\x5a\x00\x00\x00\x5a\x00\x00\x00\xb4\x00\x00\x00",), MerlBRDF))
