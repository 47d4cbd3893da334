"""The common interface of every BRDF (:class:`BRDFSource`), quantities derived from it, and
the register of file readers.

Every BRDF in reflecto — a measured table, an analytic lobe, a reconstructed model —
is a :class:`BRDFSource`; the model (:mod:`reflecto.model`) and the readers
(:mod:`reflecto.sources`) both build on this module, which depends on neither.
Each reader registers the suffixes and leading bytes it reads (:func:`register_reader`);
:func:`reflecto.load.load_source` picks one by suffix, else by the file's first bytes.
"""

from __future__ import annotations

import abc
import dataclasses
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, overload

import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import geometry
from .errors import FileFormatError, ParameterError
from .io import MAX_BRDF_BYTES, read_input

Array = NDArray[np.float64]

if TYPE_CHECKING:

    class ArrayField:
        """For the type checker only: the type of a dataclass field given as any array-like and
        held as a float64 array, converted by the class's ``__post_init__``.

        The generated ``__init__`` takes an ``ArrayLike`` (the ``__set__`` value); an instance's
        attribute reads as ``Array``. A field's default is written ``cast("ArrayField", value)``.
        Nothing of this exists at run time: there the field is a plain dataclass field.
        """

        @overload
        def __get__(self, obj: None, owner: type) -> ArrayField: ...
        @overload
        def __get__(self, obj: object, owner: type) -> Array: ...
        def __get__(self, obj: object, owner: type) -> ArrayField | Array: ...
        def __set__(self, obj: object, value: ArrayLike) -> None: ...


class BRDFSource(abc.ABC):
    """A BRDF that can be evaluated at direction pairs.

    Directions are unit vectors in the local frame (``n = +z``), pointing away from the
    surface: ``i`` toward the light, ``o`` toward the viewer (algorithm-reference §0).
    """

    #: short name of the source kind ("analytic", "merl", "rgl", "nbrdf", "model")
    kind: str = "source"
    #: the file it came from, if any
    path: Path | None = None
    #: whether ``f(i, o) = f(o, i)`` holds exactly for this representation
    reciprocal: bool = True
    #: whether the BRDF is invariant under rotation about the normal
    isotropic: bool = True

    @abc.abstractmethod
    def eval(self, i: ArrayLike, o: ArrayLike) -> Array:
        """BRDF values in sr⁻¹.

        Parameters
        ----------
        i, o
            Unit directions in the local frame (``x = t, y = b, z = n``; ``i`` toward the
            light, ``o`` toward the viewer), shape ``(N, 3)`` (or broadcastable ``(..., 3)``).

        Returns
        -------
        ndarray, shape ``(N, 3)``
            Linear RGB BRDF; 0 where either direction is below the horizon.
        """

    def parameters(self) -> dict[str, Any]:
        """Human-readable parameters for ``reflecto info``.

        Returns
        -------
        dict
            Parameter name → value (numbers, strings, short lists); empty for a source
            with nothing to report.
        """
        return {}

    @property
    def name(self) -> str:
        """Short name: the file's stem, or the kind for a source not read from a file."""
        return self.path.stem if self.path is not None else self.kind

    def albedo(self, theta_i_deg: ArrayLike, phi_i_deg: float = 0.0, **kw: Any) -> Array:
        """Directional albedo ``a(i) = ∫ f(i, o) cos θ_o dω_o`` (dimensionless).

        Parameters
        ----------
        theta_i_deg
            Incident polar angle(s), degrees: one number or a sequence of ``K``.
        phi_i_deg
            Incident azimuth, degrees.
        **kw
            Quadrature sizes ``n_u``, ``n_phi`` (:func:`directional_albedo`).

        Returns
        -------
        ndarray
            Shape ``(3,)`` (RGB) for one angle, ``(K, 3)`` for a sequence.
        """
        a = directional_albedo(self, theta_i_deg, phi_i_deg, **kw)
        return a[0] if np.ndim(theta_i_deg) == 0 else a


class HasNDF(Protocol):
    """Anything with a normal distribution ``D(h)``: the analytic BRDFs and the models."""

    def ndf(self, h: ArrayLike) -> Array:
        """The normal distribution ``D(h)``.

        Parameters
        ----------
        h : array_like, shape (..., 3)
            Unit half vectors in the local frame.

        Returns
        -------
        ndarray, shape (...)
            ``D(h)`` in sr⁻¹ (normalized so that ``∫ D(h) (h·n) dω_h = 1``).
        """
        ...


def _eval_chunked(source: BRDFSource, i: Array, o: Array, chunk: int = 1 << 18) -> Array:
    out = np.empty(i.shape[:-1] + (3,))
    fi, fo, fout = i.reshape(-1, 3), o.reshape(-1, 3), out.reshape(-1, 3)
    for s in range(0, len(fi), chunk):
        fout[s : s + chunk] = source.eval(fi[s : s + chunk], fo[s : s + chunk])
    return out


#: The most half vectors :func:`directional_albedo` integrates over (``n_u · n_phi``).
MAX_QUADRATURE = 10_000_000


def directional_albedo(
    source: BRDFSource,
    theta_i_deg: ArrayLike,
    phi_i_deg: float = 0.0,
    n_u: int = 160,
    n_phi: int = 256,
) -> Array:
    """Directional albedo by quadrature over the half vector.

    ``a(i) = ∫ f(i, o) cos θ_o dω_o = ∫ f(i, R_h(i)) cos θ_o · 4 (i·h) dω_h``
    (the Jacobian ``dω_o/dω_h = 4 (i·h)``). The half vectors lie on rings
    ``θ_h = u²·π/2`` that are dense near the normal, where specular lobes are, so
    sharp lobes are integrated accurately.

    Parameters
    ----------
    source
        The BRDF (sr⁻¹).
    theta_i_deg
        Incident polar angles in degrees, one number or shape ``(K,)``.
    phi_i_deg
        Incident azimuth in degrees.
    n_u, n_phi
        Quadrature rings in ``u = sqrt(2 θ_h/π)`` and azimuths per ring.

    Returns
    -------
    ndarray, shape ``(K, 3)``
        Linear RGB albedo (dimensionless) per incident angle; ``K = 1`` for one number.

    Raises
    ------
    ParameterError
        An angle outside ``[0°, 90°)`` (at 90° the light grazes the surface: no
        irradiance, and ``f`` divides by ``cos θ_i``) or not finite; quadrature sizes
        below 1 or above :data:`MAX_QUADRATURE` points in all.
    """
    try:
        deg = np.asarray(theta_i_deg, dtype=np.float64)
        phi = float(phi_i_deg)
    except (TypeError, ValueError) as e:
        raise ParameterError(f"albedo: incidence angles must be numbers ({e})") from None
    if deg.ndim > 1 or not (np.all(np.isfinite(deg)) and np.all(deg >= 0.0) and np.all(deg < 90.0)):
        raise ParameterError("albedo: incidence angles must be finite, in [0°, 90°), one number or a sequence")
    if not math.isfinite(phi):
        raise ParameterError(f"albedo: incidence azimuth must be finite, got {phi}")
    if not (isinstance(n_u, (int, np.integer)) and isinstance(n_phi, (int, np.integer)) and n_u >= 1
            and n_phi >= 1 and n_u * n_phi <= MAX_QUADRATURE):
        raise ParameterError(f"albedo: quadrature sizes n_u, n_phi must be integers ≥ 1 with at most "
                             f"{MAX_QUADRATURE} points in all, got {n_u} and {n_phi}")
    theta_i = np.radians(np.atleast_1d(deg))
    u = (np.arange(n_u) + 0.5) / n_u
    th = u * u * (0.5 * np.pi)
    ph = (np.arange(n_phi) + 0.5) * (2.0 * np.pi / n_phi)
    h = geometry.spherical_to_cartesian(th[:, None], ph[None, :]).reshape(-1, 3)
    dw = (np.sin(th) * (np.pi * u / n_u))[:, None] * np.full(n_phi, 2.0 * np.pi / n_phi)[None, :]
    dw = dw.ravel()
    out = np.empty((len(theta_i), 3))
    group = max(1, ALBEDO_BATCH // len(h))  # angles per call of the source: few calls, bounded memory
    for k0 in range(0, len(theta_i), group):
        out[k0 : k0 + group] = _albedo_sums(source, theta_i[k0 : k0 + group], float(np.radians(phi)), h, dw)
    return out


#: The most quadrature points :func:`directional_albedo` evaluates in one call of the source.
ALBEDO_BATCH = 1 << 18


def _albedo_sums(source: BRDFSource, theta_i: Array, phi_i: float, h: Array, dw: Array) -> Array:
    """``Σ f(i, o) cos θ_o 4 (i·h) dω_h`` over the half vectors ``h`` (weights ``dw``) for each
    incidence ``θ_i`` (radians, shape ``(K,)``) at azimuth ``φ_i``; shape ``(K, 3)``. All the
    incidences' pairs go to the source at once; each sum runs over its own pairs in ``h``'s order."""
    i = geometry.spherical_to_cartesian(theta_i, np.full(theta_i.shape, phi_i))
    idoth = np.stack([h @ ik for ik in i])  # (K, H)
    o = 2.0 * idoth[..., None] * h - i[:, None, :]
    ok = (idoth > 0) & (o[..., 2] > 0)
    f = _eval_chunked(source, np.broadcast_to(i[:, None, :], o.shape)[ok], o[ok])
    w = (o[ok][:, 2] * 4.0 * idoth[ok] * np.broadcast_to(dw, ok.shape)[ok])[:, None]
    ends = np.cumsum(np.count_nonzero(ok, axis=1))
    starts = ends - np.count_nonzero(ok, axis=1)
    return np.array([np.sum(f[a:b] * w[a:b], axis=0) for a, b in zip(starts, ends)]).reshape(len(theta_i), 3)


def valid_pairs(i: Array, o: Array) -> NDArray[np.bool_]:
    """Mask of pairs with both directions strictly above the horizon.

    Parameters
    ----------
    i, o : ndarray, shape (..., 3)
        Local-frame directions (``n = +z``).

    Returns
    -------
    ndarray of bool, shape (...)
        ``i_z > 0 and o_z > 0``.
    """
    return (i[..., 2] > 0) & (o[..., 2] > 0)


def rgb_triplet(value: Any, name: str) -> Array:
    """One number or three (RGB) → finite array of shape ``(3,)``.

    Parameters
    ----------
    value
        A number (repeated to R, G, B) or a sequence of three numbers.
    name
        The parameter's name, for the message.

    Returns
    -------
    ndarray, shape (3,)
        Float64 RGB values.

    Raises
    ------
    ParameterError
        For any other shape, or values that are not finite.
    """
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim == 0:
        arr = np.full(3, float(arr))
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise ParameterError(f"{name} must be one or three finite numbers (RGB), got {value!r}")
    return arr


def read_file_bytes(path: Path, limit: int | None = None, what: str = "a BRDF file") -> bytes:
    """Whole contents of a regular file of at most ``limit`` bytes.

    Parameters
    ----------
    path
        The file.
    limit
        Largest size accepted, bytes; default :data:`reflecto.io.MAX_BRDF_BYTES`.
    what
        What the file is, for messages.

    Returns
    -------
    bytes
        The contents.

    Raises
    ------
    FileFormatError
        Naming the file, when it is missing, not a regular file, or larger than ``limit``.
    """
    return read_input(path, MAX_BRDF_BYTES if limit is None else limit, what)


#: Narrowest lobe reflecto represents: the smallest roughness α of an analytic
#: description (below it the lobe's density overflows).
MIN_ALPHA = 1e-3
#: Largest projected BRDF ``f·cos θ_i·cos θ_o`` (sr⁻¹) any file may hold, from physics:
#: for a microfacet BRDF ``f·cos θ_i·cos θ_o = F·D·G / 4 ≤ D_max / 4`` (F, G ≤ 1), and
#: the densest normal distribution reflecto represents, GGX or Beckmann of
#: α = :data:`MIN_ALPHA`, peaks at ``D_max = 1/(π α²)``: the bound is
#: ``1/(4π α²) ≈ 7.96·10⁴`` sr⁻¹. The bound is on the projected BRDF, not on ``f``:
#: ``f`` itself grows without bound toward grazing (``1/(cos θ_i cos θ_o)``), where
#: tabulations of measured materials and of reconstructions legitimately reach
#: 10⁶–10⁷ sr⁻¹ at θ_d ≈ 89.5°.
MAX_PROJECTED_BRDF = 1.0 / (4.0 * np.pi * MIN_ALPHA**2)


def check_projected(projected: ArrayLike, path: Path, where: str = "the BRDF") -> None:
    """Refuse projected BRDF values ``f·cos θ_i·cos θ_o`` that are not finite or exceed
    :data:`MAX_PROJECTED_BRDF`; every reader and writer applies this one bound.

    Parameters
    ----------
    projected
        Values of ``f·cos θ_i·cos θ_o`` (any shape), sr⁻¹.
    path
        The file, for the message.
    where
        What was evaluated, for the message (``"its tables"``).

    Raises
    ------
    FileFormatError
        Naming ``path``.
    """
    v = np.asarray(projected, dtype=np.float64)
    if not np.all(np.isfinite(v)):
        raise FileFormatError(path, f"{where}: NaN or infinite values: the file is damaged")
    peak = float(np.max(np.abs(v))) if v.size else 0.0
    if peak > MAX_PROJECTED_BRDF:
        raise FileFormatError(path, f"{where}: f·cos θ_i·cos θ_o reaches {peak:.3g} sr⁻¹, more than any "
                              f"BRDF reflecto represents ({MAX_PROJECTED_BRDF:.3g} = 1/(4π α²) at α = {MIN_ALPHA:g}; "
                              "docs/limits.md): damaged, or not a BRDF in sr⁻¹")
#: Directional albedo a loaded measured or tabulated BRDF may have at the incidence
#: angles :data:`PLAUSIBILITY_ANGLES_DEG`. Below 0 by a little is measurement noise
#: (RGL's chm_mint: −0.006 at grazing); above 1 is noise or calibration error up to a
#: point; outside this range the file is damaged or not a BRDF in sr⁻¹.
ALBEDO_RANGE = (-0.05, 1.5)
PLAUSIBILITY_ANGLES_DEG = (0.0, 20.0, 40.0, 60.0, 75.0)


def albedo_angles(source: BRDFSource, angles_deg: Sequence[float]) -> list[float]:
    """``angles_deg`` and, for a model with a Fresnel tint, its nodes and their midpoints
    (degrees): the tint can make the specular level peak between fixed angles.

    Parameters
    ----------
    source
        The BRDF.
    angles_deg
        The incidence angles to check in any case (degrees).

    Returns
    -------
    list of float
        The angles, sorted, in degrees.
    """
    tint = getattr(source, "tint", None)
    return sorted({*map(float, angles_deg), *(tint.angles_deg() if tint is not None else [])})


def check_plausible(source: BRDFSource, path: Path, albedo_range: tuple[float, float] = ALBEDO_RANGE) -> None:
    """Refuse a loaded BRDF whose values or directional albedo are impossible.

    Evaluates the source at 4096 fixed direction pairs (values must be finite and
    ``f·cos θ_i·cos θ_o`` at most :data:`MAX_PROJECTED_BRDF`, :func:`check_projected`) and its directional albedo at
    :data:`PLAUSIBILITY_ANGLES_DEG` (a 48 × 64 half-vector quadrature; it must be
    finite and lie in ``albedo_range``). Costs 5–60 ms.

    Parameters
    ----------
    source
        The loaded BRDF.
    path
        Its file, for the message.
    albedo_range
        ``(lowest, highest)`` directional albedo accepted (dimensionless).

    Raises
    ------
    FileFormatError
        Naming ``path``.
    """
    rng = np.random.default_rng(20100919)
    ct = rng.uniform(0.0, 1.0, (2, 4096))
    ph = rng.uniform(0.0, 2.0 * np.pi, (2, 4096))
    st = np.sqrt(1.0 - ct * ct)
    d = np.stack([st * np.cos(ph), st * np.sin(ph), ct], -1)
    with np.errstate(all="ignore"):
        f = source.eval(d[0], d[1])
        if not np.all(np.isfinite(f)):
            raise FileFormatError(path, "the BRDF evaluates to NaN or infinity: the file is damaged")
        check_projected(f * (d[0, :, 2] * d[1, :, 2])[:, None], path)
        a = directional_albedo(source, albedo_angles(source, PLAUSIBILITY_ANGLES_DEG), n_u=48, n_phi=64)
    if not np.all(np.isfinite(a)):
        raise FileFormatError(path, "its directional albedo is NaN or infinite: the file is damaged")
    lo, hi = albedo_range
    if a.min() < lo or a.max() > hi:
        raise FileFormatError(path, f"directional albedo {a.min():.4g} to {a.max():.4g}, outside the plausible "
                              f"[{lo:g}, {hi:g}]: damaged, or not a BRDF in sr⁻¹")


# ------------------------------------------------------------------ readers
@dataclasses.dataclass(frozen=True)
class Reader:
    """How one kind of BRDF file is read.

    Attributes
    ----------
    kind
        Short name of the kind (``"merl"``, ``"rgl"``, ``"nbrdf"``, ``"analytic"``, ``"model"``).
    description
        The kind in words, for messages (``"a MERL table (.binary)"``).
    suffixes
        Lower-case suffixes read as this kind (``(".binary",)``).
    magic
        Leading bytes that identify the kind when the suffix does not (may be empty).
    open
        ``open(path) -> BRDFSource``.
    """

    kind: str
    description: str
    suffixes: tuple[str, ...]
    magic: tuple[bytes, ...]
    open: Callable[[Path], BRDFSource]


READERS: dict[str, Reader] = {}


def register_reader(reader: Reader) -> Reader:
    """Add ``reader`` to :data:`READERS` (each suffix is read by one reader).

    Parameters
    ----------
    reader
        The reader; each of its suffixes maps to it.

    Returns
    -------
    Reader
        ``reader`` itself, so that a module can keep it as a constant.

    Raises
    ------
    ValueError
        When a suffix is already read by a reader of another kind.
    """
    for suffix in reader.suffixes:
        other = READERS.get(suffix)
        if other is not None and other.kind != reader.kind:
            raise ValueError(f"suffix {suffix} is already read as {other.kind}")
        READERS[suffix] = reader
    return reader
