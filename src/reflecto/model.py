"""The generalized microfacet BRDF of Lan et al. 2010, §3.1 (eqs. 1, 2, 4, 8).

``f(i, o) = k_d/π + k_s · D(h) S(i) S(o) F(i·h; η) / (4 (i·n)(o·n))``          (eqs. 1–2)

* ``D`` — tabulated on a hemicube (§9 of algorithm-reference), normalized so that
  ``∫ D(h)(h·n) dω_h = 1`` (AR 1.2); one NDF shared by the three colour channels;
* ``S`` — APS shadowing derived from D (eq. 8), tabulated as σ and clamped so S ≤ 1;
* ``F`` — Cook–Torrance Fresnel (eq. 4) with a per-channel real index η, optionally
  times a per-channel tint ``τ_c(θ_d) ≥ 0`` (:class:`reflecto.fresnel.FresnelTint`,
  the product clipped at 1): the specular colour where it changes with angle as no
  single η's curve does;
* ``k_d`` (diffuse albedo ρ_d), ``k_s`` — per channel.

Two tabulations of ``D``: :class:`MicrofacetBRDF` holds any NDF on a hemicube
(anisotropic materials, §5.5); :class:`IsotropicMicrofacetBRDF` holds an isotropic
``D(θ_h)`` on polar nodes (:mod:`reflecto.polar`), which is what an isotropic
material's reconstruction determines, at a fraction of the storage and cost.

Evaluation uses the cancelled form ``k_s D F / (4 σ(i) σ(o))`` (algorithm-reference
AR 1.6), which is finite at grazing angles. The physical unit is sr⁻¹ throughout; the
paper's "4π" constant is *not* used (algorithm-reference §3.2–§3.3).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import warnings
from pathlib import Path
from typing import Any, NoReturn

import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import _kernels
from .brdf import BRDFSource, Reader, check_plausible, register_reader
from .brdf import rgb_triplet as _rgb
from .errors import FileFormatError, ParameterError, ReflectoWarning, one_line, short_repr, shown_path
from .fresnel import FresnelTable, FresnelTint, eta_to_json, fresnel, is_constant
from .hemicube import Hemicube, hemicube
from .io import (
    MAX_ARCHIVE_BYTES,
    atomic_write,
    content_digest,
    npy_array,
    npy_bytes,
    parse_json,
    read_input,
    sha256,
    write_zip,
    zip_members,
)
from .polar import IsotropicNDF, NodeNDFs
from .shadowing import SigmaTable, sigma_table

Array = NDArray[np.float64]

#: Format identifier and version of reflecto model files.
MODEL_FORMAT = "reflecto-model"
#: The newest format version read; a model whose Fresnel tint continues its trend
#: beyond the last node is written as version 6, an isotropic model with an NDF per
#: θ_d node as version 5, one with a Fresnel tint as version 4 (a reader of an older
#: version would ignore their arrays or keys), any other as version 3.
MODEL_VERSION = 6
MODEL_SUFFIX = ".reflecto"

__all__ = ["MicrofacetBRDF", "IsotropicMicrofacetBRDF", "load_model", "MODEL_SUFFIX"]



def _common_scalars(model, kd, ks, eta, correlated, metadata, path, tint=None) -> None:
    """Set and check what both microfacet models share: ``kd``, ``ks`` (≥ 0) and ``eta``
    (> 0, or ∞ for the constant Fresnel lobe, :data:`reflecto.fresnel.CONSTANT`) as RGB
    triplets, the Fresnel tint (or ``None``), the shadowing form, the metadata and the
    file path; and the Fresnel table evaluation uses."""
    model.kd = _rgb(kd, "kd")
    model.ks = _rgb(ks, "ks")
    model.eta = np.full(3, math.inf) if is_constant(eta) else _rgb(eta, "eta")  # ∞: the constant Fresnel lobe
    if np.any(model.kd < 0) or np.any(model.ks < 0):
        raise ParameterError("kd and ks must be >= 0")
    if np.any(model.eta <= 0):
        raise ParameterError("eta must be > 0")
    if tint is not None and not isinstance(tint, FresnelTint):
        tint = FresnelTint(*tint)
    model.tint = tint
    model.correlated = bool(correlated)
    model.metadata = dict(metadata or {})
    model.path = path
    model.reciprocal = True
    model._fresnel_table = FresnelTable(model.eta, tint=tint)


def _tinted_fresnel(model, c: ArrayLike) -> Array:
    """``min(1, τ_c(θ_d) F(c; η_c))`` per RGB channel (eq. 4 and the tint), shape ``c.shape + (3,)``."""
    f = fresnel(np.asarray(c)[..., None], model.eta)
    return f if model.tint is None else np.minimum(f * model.tint(c), 1.0)


def _tint_meta(model) -> dict[str, Any]:
    """The Fresnel tint's continuation beyond its last node for ``meta.json`` (none for ``"constant"``)."""
    if model.tint is None or model.tint.beyond == "constant":
        return {}
    return {"tint_beyond": model.tint.beyond, **({} if model.tint.trend_from is None else
                                                 {"tint_trend_from": model.tint.trend_from})}


def _tint_version(model, version: int) -> int:
    """The file version: 6 where the tint continues its trend (:func:`_tint_meta`), else ``version``."""
    return 6 if _tint_meta(model) else version


def _tint_arrays(model) -> dict[str, NDArray[Any]]:
    """The Fresnel tint's arrays of a model file (none without a tint)."""
    if model.tint is None:
        return {}
    return {"tint": model.tint.values.astype("<f8"), "tint_theta": model.tint.theta.astype("<f8")}


def _tint_from_arrays(path: Path, arrays: dict[str, NDArray[Any]], meta: dict[str, Any]) -> FresnelTint | None:
    """The Fresnel tint of a model file's arrays and its continuation in ``meta``, checked
    (``None`` when it has none)."""
    values, theta = arrays.get("tint"), arrays.get("tint_theta")
    beyond = meta.get("tint_beyond", "constant")
    if beyond not in FresnelTint.BEYOND:
        raise FileFormatError(path, f"invalid tint_beyond {short_repr(beyond)} "
                                    f"(one of {', '.join(FresnelTint.BEYOND)})")
    if "tint_beyond" in meta and meta.get("version", 0) < 6:
        raise FileFormatError(path, f"a Fresnel tint's continuation (tint_beyond) needs model format version 6, "
                                    f"the file says {meta.get('version')}")
    trend_from = meta.get("tint_trend_from")
    if trend_from is not None and (beyond != "trend" or not isinstance(trend_from, (int, float))
                                   or isinstance(trend_from, bool) or not math.isfinite(trend_from)):
        raise FileFormatError(path, f"invalid tint_trend_from {short_repr(trend_from)} (a number of radians, "
                                    "with tint_beyond \"trend\")")
    if values is None and theta is None:
        if "tint_beyond" in meta:
            raise FileFormatError(path, "tint_beyond without a Fresnel tint (tint.npy, tint_theta.npy)")
        return None
    if values is None or theta is None or values.dtype != np.dtype("<f8") or theta.dtype != np.dtype("<f8") \
            or theta.ndim != 1 or not 2 <= len(theta) <= MAX_TINT_NODES:
        raise FileFormatError(path, f"a Fresnel tint needs 2 to {MAX_TINT_NODES} float64 nodes (tint_theta.npy) "
                                    "and a table of as many RGB float64 rows (tint.npy)")
    try:
        return FresnelTint(theta, values, beyond, trend_from)
    except ParameterError as e:
        raise FileFormatError(path, f"invalid Fresnel tint ({e})") from None

class MicrofacetBRDF(BRDFSource):
    """Generalized microfacet BRDF with a tabulated hemicube NDF.

    Parameters
    ----------
    ndf
        D on the hemicube texels, shape ``(3 N²,)``; non-negative, finite. It is
        normalized here (AR 1.2) unless ``normalize=False``; the scale removed is
        *not* moved into ``ks`` — pass ``ks`` for the intended level.
    kd, ks, eta
        Per-channel diffuse albedo, specular scale and relative index (3 numbers or one).
    correlated
        Use the height-correlated Smith form ``S(i)S(o)/(S(i)+S(o)−S(i)S(o))`` instead
        of the paper's separable product (algorithm-reference §1.3).
    metadata
        Free JSON-serializable information kept in the model file.
    tint
        Per-channel Fresnel tint ``τ_c(θ_d)`` (:class:`~reflecto.fresnel.FresnelTint`, or
        ``(nodes, values)``): ``F_c = min(1, τ_c F(c; η_c))``; ``None``: eq. 4 alone.
    """

    #: Diffuse and specular albedos and the relative index, RGB, shape ``(3,)`` (set by the constructor).
    kd: Array
    ks: Array
    eta: Array
    #: The per-channel Fresnel tint, or ``None`` (set by the constructor).
    tint: FresnelTint | None
    _fresnel_table: FresnelTable
    #: Height-correlated Smith shadowing (else separable), and free-form metadata.
    correlated: bool
    metadata: dict[str, Any]


    kind = "model"

    def __init__(
        self,
        ndf: ArrayLike,
        kd: ArrayLike = 0.0,
        ks: ArrayLike = 1.0,
        eta: ArrayLike = 1.5,
        *,
        normalize: bool = True,
        correlated: bool = False,
        metadata: dict[str, Any] | None = None,
        path: Path | None = None,
        tint: FresnelTint | tuple[ArrayLike, ArrayLike] | None = None,
    ) -> None:
        d = np.asarray(ndf, dtype=np.float64).ravel()
        n = int(round(math.sqrt(d.size / 3)))
        if 3 * n * n != d.size or n < 4 or n % 2:
            raise ParameterError(f"ndf must have 3·N² texels for an even N >= 4, got {d.size}")
        self.cube: Hemicube = hemicube(n)
        # stored as float32 in model files: round now so save/load is exact (one
        # compiled pass checks, rounds and integrates; a second normalizes and rounds)
        q = np.empty_like(d)
        total = _kernels.quantize_ndf(d, self.cube.projected_solid_angles, normalize, q)
        if total < 0:
            raise ParameterError("ndf must be finite and non-negative")
        if normalize and total <= 0:
            raise ParameterError("ndf is zero everywhere")
        self.ndf_values = q
        _common_scalars(self, kd, ks, eta, correlated, metadata, path, tint)
        self.isotropic = False
        self._padded = self.cube.pad(self.ndf_values)
        self._sigma: SigmaTable | None = None

    # ------------------------------------------------------------------ pieces
    @property
    def resolution(self) -> int:
        """Top-face resolution N of the NDF hemicube."""
        return self.cube.n

    @property
    def sigma_table(self) -> SigmaTable:
        """σ(θ, φ) of the NDF (eq. 8 denominator), computed on first use."""
        if self._sigma is None:
            self._sigma = sigma_table(self.cube, self.ndf_values, padded=self._padded)
        return self._sigma

    def ndf(self, h: ArrayLike) -> Array:
        """The tabulated NDF by bilinear hemicube lookup.

        Parameters
        ----------
        h : array_like, shape (..., 3)
            Unit half vectors in the local frame.

        Returns
        -------
        ndarray, shape (...)
            ``D(h)`` in sr⁻¹ (``∫ D(h)(h·n) dω_h = 1``, AR 1.2); 0 where ``h_z ≤ 0``.
        """
        h = np.asarray(h, dtype=np.float64)
        return np.where(h[..., 2] > 0, self.cube.lookup(self.ndf_values, h, self._padded), 0.0)

    def shadowing(self, k: ArrayLike) -> Array:
        """APS shadowing ``S(k) = (k·n)/σ(k)`` (eq. 8), σ clamped to ``≥ k·n`` so that S ≤ 1.

        Parameters
        ----------
        k : array_like, shape (..., 3)
            Unit directions in the local frame.

        Returns
        -------
        ndarray, shape (...)
            ``S(k)`` in [0, 1]; 0 for directions below the horizon.
        """
        return self.sigma_table.eval(k)

    def fresnel(self, c: ArrayLike) -> Array:
        """Per-channel Fresnel ``τ_c(θ_d) F(c; η)`` (eq. 4, times the tint when there is one).

        Parameters
        ----------
        c : array_like
            ``c = |i·h| = cos θ_d``, in [0, 1].

        Returns
        -------
        ndarray, shape ``c.shape + (3,)``
            F per RGB channel (dimensionless, in [0, 1]); 1 for the constant lobe (η = ∞) without a tint.
        """
        return _tinted_fresnel(self, c)

    def specular_lobe(self, i: ArrayLike, o: ArrayLike) -> Array:
        """The specular lobe of eq. 2 without ``k_s`` and ``F``: ``D(h) S(i) S(o) / (4 cos θ_i cos θ_o)``.

        Evaluated in the cancelled form ``D / (4 σ(i) σ(o))`` (AR 1.6), or the
        height-correlated one when :attr:`correlated`.

        Parameters
        ----------
        i, o : array_like, shape (..., 3)
            Unit light and view directions in the local frame.

        Returns
        -------
        ndarray, shape (...)
            The lobe in sr⁻¹; 0 where either direction is below the horizon.
        """
        return self._parts(np.asarray(i, dtype=np.float64), np.asarray(o, dtype=np.float64))[0]

    def _parts(self, i: Array, o: Array) -> tuple[Array, Array]:
        """Specular lobe (as :meth:`specular_lobe`) and ``c = |i·h|``."""
        ci, co = i[..., 2], o[..., 2]
        ok = (ci > 0) & (co > 0)
        hs = i + o
        norm = np.sqrt(np.einsum("...k,...k->...", hs, hs))
        norm[norm == 0] = 1.0
        h = hs / norm[..., None]
        c = np.abs(np.einsum("...k,...k->...", i, h))
        d = self.cube.lookup(self.ndf_values, h, self._padded)
        table = self.sigma_table
        si = np.maximum(table.eval_sigma(i), np.maximum(ci, 0.0))
        so = np.maximum(table.eval_sigma(o), np.maximum(co, 0.0))
        if self.correlated:
            # G2 = 1/(1 + Λi + Λo), Λ = σ/cos − 1  ⇒  D G2/(4 cos cos) = D/(4(σi cos_o + σo cos_i − cos_i cos_o))
            denom = 4.0 * (si * co + so * ci - ci * co)
        else:
            denom = 4.0 * si * so  # AR 1.6
        spec = np.divide(d, denom, out=np.zeros_like(d), where=ok & (denom > 0))
        return spec, c

    def eval(self, i: ArrayLike, o: ArrayLike) -> Array:
        """The BRDF ``f = k_d/π + k_s D(h) F(c; η) / (4 σ(i) σ(o))`` (eqs. 1–2, AR 1.6).

        A compiled loop (:func:`reflecto._kernels.model_eval`) that computes exactly
        what :meth:`eval_numpy` computes, without its temporaries.

        Parameters
        ----------
        i, o : array_like, shape (..., 3)
            Unit light and view directions in the local frame; broadcast.

        Returns
        -------
        ndarray, shape (..., 3)
            Linear RGB BRDF in sr⁻¹; 0 where either direction is below the horizon.
        """
        i = np.asarray(i, dtype=np.float64)
        o = np.asarray(o, dtype=np.float64)
        shape = np.broadcast_shapes(i.shape, o.shape)
        ii = _kernels.as_dirs(np.broadcast_to(i, shape))
        oo = _kernels.as_dirs(np.broadcast_to(o, shape))
        table = self.sigma_table
        out = np.empty((ii.shape[0], 3))
        _kernels.model_eval(
            ii, oo, self._padded, self.cube._pad_offsets, self.cube.n,
            table._flat(), table.n_theta, table.n_phi,
            self._fresnel_table.table, self.kd, self.ks, self.correlated, out,
        )  # fmt: skip
        return out.reshape(shape[:-1] + (3,))

    def eval_numpy(self, i: ArrayLike, o: ArrayLike) -> Array:
        """Reference NumPy implementation of :meth:`eval` (same values, slower).

        Parameters
        ----------
        i, o : array_like, shape (..., 3)
            Unit light and view directions in the local frame.

        Returns
        -------
        ndarray, shape (..., 3)
            Linear RGB BRDF in sr⁻¹; 0 where either direction is below the horizon.
        """
        i = np.asarray(i, dtype=np.float64)
        o = np.asarray(o, dtype=np.float64)
        spec, c = self._parts(i, o)
        f = self._fresnel_table(c)
        f *= self.ks
        f *= spec[..., None]
        f += self.kd / math.pi
        f[~((i[..., 2] > 0) & (o[..., 2] > 0))] = 0.0
        return f

    def scaled(self, factor: float) -> MicrofacetBRDF:
        """The same BRDF times ``factor``: ``k_d`` and ``k_s`` scaled, the NDF, η, tint,
        shadowing form and metadata kept (``f`` is linear in ``k_d, k_s``, eq. 1).

        Parameters
        ----------
        factor
            The scale (dimensionless, ≥ 0).

        Returns
        -------
        MicrofacetBRDF
            A new model with ``factor · f``.
        """
        return MicrofacetBRDF(self.ndf_values, self.kd * factor, self.ks * factor, self.eta, normalize=False,
                              correlated=self.correlated, metadata=self.metadata, tint=self.tint)

    def parameters(self) -> dict[str, Any]:
        """The model's parameters, for ``reflecto info``.

        Returns
        -------
        dict
            ``resolution`` (hemicube sizes), ``kd``, ``ks`` and ``eta`` (RGB lists; a
            constant Fresnel lobe is named instead of η), ``shadowing`` (eq. 8 or
            height-correlated Smith) and ``metadata`` when there is any.
        """
        return {
            "resolution": f"{self.cube.n}x{self.cube.n} top, {self.cube.n}x{self.cube.half} sides",
            "kd": self.kd.tolist(),
            "ks": self.ks.tolist(),
            **eta_to_json(self.eta),
            **_tint_parameters(self),
            "shadowing": "height-correlated Smith" if self.correlated else "separable APS (eq. 8)",
            **({"metadata": self.metadata} if self.metadata else {}),
        }

    # -------------------------------------------------------------- factories
    @classmethod
    def from_ndf_function(
        cls, ndf_fn: Any, resolution: int = 512, **kw: Any
    ) -> MicrofacetBRDF:
        """A model whose NDF is ``ndf_fn`` tabulated at the texel centres of a hemicube.

        Parameters
        ----------
        ndf_fn
            Vectorised ``D(h)``: unit half vectors, shape ``(M, 3)`` → values in sr⁻¹, shape ``(M,)``.
        resolution
            Top-face resolution N of the hemicube (``3 N²`` texels).
        **kw
            Passed to the constructor (``kd``, ``ks``, ``eta``, ``normalize``, ``correlated``, ``metadata``).

        Returns
        -------
        MicrofacetBRDF
            The model (NDF normalized unless ``normalize=False``).
        """
        cube = hemicube(resolution)
        return cls(ndf_fn(cube.directions), **kw)

    # ------------------------------------------------------------------- files
    def save(self, path: str | Path) -> Path:
        """Write the model file atomically: a zip of ``meta.json`` and one ``.npy`` per array.

        ``meta.json`` holds the format name and version, the scalars, the metadata,
        each array's file, dtype, shape and SHA-256 (``arrays``), and the SHA-256 of
        its own canonical JSON without that entry (``sha256``): a damaged byte in any
        array or any metadata is refused on load. A model that :meth:`load` would
        refuse (parameters out of range, NDF not normalized, albedo above
        :data:`MODEL_ALBEDO_MAX`) is refused here with :class:`ParameterError`.

        Parameters
        ----------
        path
            The file to write; its name ends in :data:`MODEL_SUFFIX` (the readers tell a model
            file from the other kinds by it).

        Returns
        -------
        Path
            ``path``.
        """
        path = _model_path(path)
        meta = {
            "format": MODEL_FORMAT,
            "version": _tint_version(self, 4 if self.tint is not None else 3),
            "ndf_kind": "hemicube",
            "resolution": self.cube.n,
            "kd": self.kd.tolist(),
            "ks": self.ks.tolist(),
            **eta_to_json(self.eta),
            "correlated": self.correlated,
            "metadata": self.metadata,
            **_tint_meta(self),
        }
        arrays = {"ndf": self.ndf_values.astype("<f4"), **_tint_arrays(self)}
        try:
            _check_model(path, self)
        except FileFormatError as e:
            raise ParameterError(f"{path}: not saved, the model is invalid: {e.problem}") from None
        _write_model_file(path, meta, arrays)
        return path

    @classmethod
    def load(cls, path: str | Path) -> MicrofacetBRDF | IsotropicMicrofacetBRDF:
        """Read a model file written by :meth:`save`; refuse foreign, damaged or implausible files.

        Checks, in this order: the file (regular, at most
        :data:`~reflecto.io.MAX_ARCHIVE_BYTES`), the archive (members and unpacked
        sizes before inflating), the format and version, the checksums of the
        metadata and of every array, each array's header against its bytes, the
        parameters' types and ranges, the NDF's normalization and the albedo.
        Files of format versions 1 and 2 (only the NDF checksummed) are read with a
        :class:`~reflecto.errors.ReflectoWarning`. A capture folder named in the
        metadata (``capture``) is kept only if it lies inside the model's folder.
        Returns an :class:`IsotropicMicrofacetBRDF` for a file of ``ndf_kind``
        ``"isotropic"``.

        Parameters
        ----------
        path
            A ``.reflecto`` model file.

        Returns
        -------
        MicrofacetBRDF or IsotropicMicrofacetBRDF
            The model, with ``path`` set.

        Raises
        ------
        FileFormatError
            Naming the file and the first check that failed.
        """
        path = Path(path)
        meta, arrays = _read_model_file(path)
        kd, ks, eta, correlated, metadata = _model_parameters(path, meta)
        metadata = _local_metadata(path, metadata)
        kind = meta.get("ndf_kind", "hemicube")
        if kind == "isotropic":
            iso = IsotropicMicrofacetBRDF._from_file(path, meta, arrays, (kd, ks, eta, correlated, metadata))
            _warn_if_legacy(path, meta)
            return iso
        if kind != "hemicube":
            raise FileFormatError(path, f"unknown NDF kind {short_repr(kind)} (expected 'hemicube' or 'isotropic')")
        n = meta.get("resolution")
        if not isinstance(n, int) or isinstance(n, bool) or n < 4 or n % 2 or n > MAX_MODEL_RESOLUTION:
            raise FileFormatError(path, f"invalid NDF resolution {short_repr(n)} "
                                        f"(an even number in [4, {MAX_MODEL_RESOLUTION}])")
        ndf = arrays.get("ndf")
        if ndf is None or ndf.dtype != np.dtype("<f4") or ndf.shape != (3 * n * n,):
            got = None if ndf is None else f"{ndf.shape} {ndf.dtype}"
            raise FileFormatError(path, f"NDF array is {got}, expected (3·{n}²,) float32")
        try:
            model = cls(ndf, kd, ks, eta, normalize=False, correlated=correlated, metadata=metadata, path=path,
                        tint=_tint_from_arrays(path, arrays, meta))
        except ParameterError as e:
            raise FileFormatError(path, f"invalid model parameters ({e})") from None
        _check_model(path, model)
        _warn_if_legacy(path, meta)
        return model


#: Limits and ranges of model files (docs/limits.md).
MAX_MODEL_RESOLUTION = 2048
MAX_POLAR_NODES = 1 << 16
MAX_TINT_NODES = 1024
#: An NDF per θ_d node is one tabulated lobe (and its shadowing table) each: the reconstruction
#: makes one per cluster of LEDs that see the mirror direction (two on the paper's layout), and
#: a device has at most 32 LEDs (:data:`reflecto.instrument.device.MAX_LEDS`); 64 leave room for a
#: set's stacked captures while a file of 1,024 took 20 s and 1.4 GB to read.
MAX_LOBE_NODES = 64
MAX_MODEL_META_BYTES = 16 << 20
ETA_RANGE = (1.0, 100.0)
#: Largest directional albedo of a model file: the reconstruction clamps it to 1
#: (on its own quadrature, which this one may differ from by a percent or so).
MODEL_ALBEDO_MAX = 1.05
#: How far ``∫ D cos θ dω`` of a stored NDF may be from 1 (float32 rounding: 1e-7).
NDF_NORM_TOLERANCE = 1e-4


def _tint_parameters(model) -> dict[str, Any]:
    """``fresnel_tint`` for ``reflecto info``: ``τ`` per channel at each node (keyed by its
    angle in degrees) and ``"beyond the last node"``, the continuation, when there is a tint."""
    if model.tint is None:
        return {}
    tint = model.tint
    beyond = tint.beyond if tint.trend_from is None else f"{tint.beyond} from {math.degrees(tint.trend_from):.1f}°"
    return {"fresnel_tint": {**{f"{math.degrees(t):.1f}°": np.round(v, 3).tolist()
                                for t, v in zip(tint.theta, tint.values)},
                             "beyond the last node": beyond}}


def _lobe_term(ndf: IsotropicNDF, theta_h: Array, ci: Array, co: Array, correlated: bool, keep: NDArray[np.bool_]
               ) -> Array:
    """``D(θ_h) / (4 σ(i) σ(o))`` (AR 1.6; the height-correlated form when ``correlated``), 0 off ``keep``."""
    d = ndf.at_theta(theta_h)
    si, so = ndf.projected_area(ci), ndf.projected_area(co)
    if correlated:
        denom = 4.0 * (si * np.maximum(co, 0) + so * np.maximum(ci, 0) - np.maximum(ci, 0) * np.maximum(co, 0))
    else:
        denom = 4.0 * si * so
    return np.divide(d, denom, out=np.zeros_like(d), where=keep & (denom > 0))


def _lobe_parameters(model) -> dict[str, Any]:
    """``ndf_per_theta_d`` for ``reflecto info``: each θ_d node's lobe half width at half
    maximum (degrees), when the model has an NDF per node."""
    if getattr(model, "lobes", None) is None:
        return {}
    theta = np.radians(np.linspace(0.0, 90.0, 18001))
    out = {}
    for t, d in zip(model.lobes.theta_d, model.lobes.ndfs):
        v = d.at_theta(theta)
        below = np.flatnonzero(v < 0.5 * v[0])  # a lobe that never halves: 90°
        half = theta[below[0]] if len(below) else 0.5 * math.pi
        out[f"{math.degrees(t):.1f}°"] = f"half width {math.degrees(half):.2f}°"
    return {"ndf_per_theta_d": out}


def _lobes_from_arrays(path: Path, arrays: dict[str, NDArray[Any]], ndf: IsotropicNDF) -> NodeNDFs | None:
    """The NDF per θ_d node of a model file's arrays, checked (``None`` when it has none)."""
    values, theta = arrays.get("lobes"), arrays.get("lobes_theta_d")
    if values is None and theta is None:
        return None
    if values is None or theta is None or values.dtype != np.dtype("<f4") or theta.dtype != np.dtype("<f8") \
            or theta.ndim != 1 or not 2 <= len(theta) <= MAX_LOBE_NODES or values.shape != (len(theta), len(ndf.nodes)):
        raise FileFormatError(path, f"an NDF per θ_d node needs 2 to {MAX_LOBE_NODES} float64 nodes "
                                    "(lobes_theta_d.npy) and as many float32 rows on the NDF's polar nodes (lobes.npy)")
    try:
        lobes = NodeNDFs(theta, [IsotropicNDF(ndf.nodes, r.astype(np.float64), normalize=False) for r in values])
    except ParameterError as e:
        raise FileFormatError(path, f"invalid NDF per θ_d node ({e})") from None
    for t, d in zip(theta, lobes.ndfs):
        if not abs(d.normalization - 1.0) <= NDF_NORM_TOLERANCE:
            raise FileFormatError(path, f"the NDF of θ_d node {math.degrees(t):.1f}° is not normalized "
                                        f"(∫ D cos θ dω = {d.normalization:.6g}, AR 1.2 needs 1)")
    return lobes


def _model_path(path: str | Path) -> Path:
    """``path``, refused (:class:`ParameterError`) unless its name ends in :data:`MODEL_SUFFIX`:
    ``load_source`` and the CLI read a file by its suffix, so a model written as ``.bsdf`` or
    ``.json`` would be refused as that kind (and a summary written beside it would replace it)."""
    path = Path(path)
    if path.suffix.lower() != MODEL_SUFFIX:
        raise ParameterError(f"{shown_path(path)}: not saved, a model file's name must end in {MODEL_SUFFIX}")
    return path


def _write_model_file(path: Path, meta: dict[str, Any], arrays: dict[str, NDArray[Any]]) -> None:
    """Zip ``meta`` (plus array specs and checksums) and ``arrays`` atomically."""

    text = _check_writable(path, meta, arrays)
    members = {f"{name}.npy": npy_bytes(a) for name, a in arrays.items()}
    meta = json.loads(text)  # what load() will see: string keys, lists, no tuples
    meta["arrays"] = {name: {"file": f"{name}.npy", "dtype": a.dtype.str, "shape": list(a.shape),
                             "sha256": sha256(members[f"{name}.npy"])} for name, a in arrays.items()}
    meta["sha256"] = content_digest(meta)
    with atomic_write(path) as fh:
        write_zip(fh, {"meta.json": json.dumps(meta, indent=1).encode(), **members})


def _check_writable(path: Path, meta: dict[str, Any], arrays: dict[str, NDArray[Any]]) -> str:
    """Refuse, before writing, a model file that :meth:`MicrofacetBRDF.load` would refuse for
    its metadata (JSON: its nesting, integers no float holds; size; the
    sample normal's entries) or its node counts (:data:`MAX_POLAR_NODES`, :data:`MAX_TINT_NODES`).

    Returns
    -------
    str
        The metadata as JSON text (what the file holds).

    Raises
    ------
    ParameterError
        ``PATH: not saved, …``, naming the problem.
    """
    def refuse(problem: str) -> NoReturn:
        raise ParameterError(f"{shown_path(path)}: not saved, the model is invalid: {problem}")

    try:
        text = json.dumps(meta)
    except (TypeError, ValueError) as e:  # a value JSON does not hold (np.int64, a set)
        refuse(f"its metadata is not plain JSON ({one_line(e)})")
    if len(text) > MAX_MODEL_META_BYTES:
        refuse(f"its metadata is {len(text)} bytes, more than {MAX_MODEL_META_BYTES}")
    try:
        metadata = parse_json(text, path).get("metadata") or {}
        _check_normal_metadata(path, metadata if isinstance(metadata, dict) else {})
    except FileFormatError as e:
        refuse(e.problem)
    for name, limit in (("tint_theta", MAX_TINT_NODES), ("lobes_theta_d", MAX_LOBE_NODES),
                        ("ndf_theta", MAX_POLAR_NODES)):
        if name in arrays and len(arrays[name]) > limit:
            refuse(f"{len(arrays[name])} {name} nodes, more than {limit}")
    return text


def _read_model_file(path: Path) -> tuple[dict[str, Any], dict[str, NDArray[Any]]]:
    """Metadata and arrays of a model file, with every check up to the arrays' headers."""

    members = zip_members(read_input(path, MAX_ARCHIVE_BYTES, "a model file"), path)
    if "meta.json" not in members or "ndf.npy" not in members:
        raise FileFormatError(path, "not a reflecto model file (meta.json or ndf.npy missing)")
    if len(members["meta.json"]) > MAX_MODEL_META_BYTES:
        raise FileFormatError(path, f"meta.json is {len(members['meta.json'])} bytes, more than {MAX_MODEL_META_BYTES}")
    meta = parse_json(members["meta.json"], path)
    if not isinstance(meta, dict) or meta.get("format") != MODEL_FORMAT:
        got = meta.get("format") if isinstance(meta, dict) else type(meta).__name__
        raise FileFormatError(path, f"not a reflecto model file (format is {short_repr(got)})")
    version = meta.get("version")
    if not isinstance(version, int) or isinstance(version, bool) or version < 1:
        raise FileFormatError(path, f"invalid model format version {short_repr(version)}")
    if version > MODEL_VERSION:
        raise FileFormatError(
            path,
            f"written by a newer reflecto (model format version {version}; this version reads <= {MODEL_VERSION})",
        )
    if version < 3:
        return meta, _legacy_arrays(path, meta, members)
    return meta, _checked_arrays(path, meta, members)


def _checked_arrays(path: Path, meta: dict[str, Any], members: dict[str, bytes]) -> dict[str, NDArray[Any]]:
    """The arrays of a version-3 file, after its metadata and array checksums (any array names)."""

    if meta.get("sha256") != content_digest(meta):
        raise FileFormatError(path, "metadata checksum mismatch: the file is damaged")
    spec = meta.get("arrays")
    if not isinstance(spec, dict) or not all(isinstance(v, dict) for v in spec.values()):
        raise FileFormatError(path, "metadata lacks a valid 'arrays' table")
    for name, v in spec.items():
        if not isinstance(v.get("file"), str):
            raise FileFormatError(path, f"array {short_repr(name)}: its member name must be a string, "
                                        f"got {short_repr(v.get('file'))}")
    files = {v["file"] for v in spec.values()}
    extra = sorted(set(members) - files - {"meta.json"})
    if extra or len(files) != len(spec):
        raise FileFormatError(path, f"archive members {extra or sorted(map(str, files))} do not match the metadata")
    arrays = {}
    for name, v in spec.items():
        f, dtype, shape = v.get("file"), v.get("dtype"), v.get("shape")
        if f not in members:
            raise FileFormatError(path, f"array {name!r}: member {short_repr(f)} is missing")
        if sha256(members[f]) != v.get("sha256"):
            raise FileFormatError(path, f"array {name!r} checksum mismatch: the file is damaged")
        if not isinstance(shape, list) or not all(isinstance(k, int) and not isinstance(k, bool) and k >= 0
                                                  for k in shape):
            raise FileFormatError(path, f"array {name!r}: invalid shape {short_repr(shape)}")
        try:
            dt = np.dtype(dtype)
        except Exception:  # noqa: BLE001 - TypeError, ValueError, SyntaxError: NumPy's parser of a hostile spec
            raise FileFormatError(path, f"array {name!r}: invalid dtype {short_repr(dtype)}") from None
        arrays[name] = npy_array(members[f], path, f, dtype=dt, shape=tuple(shape))
    return arrays


def _legacy_arrays(path: Path, meta: dict[str, Any], members: dict[str, bytes]) -> dict[str, NDArray[Any]]:
    """The NDF (and polar nodes) of a version-1 or -2 file, whose checksum covers only
    those, with a warning."""


    arrays = {"ndf": npy_array(members["ndf.npy"], path, "ndf.npy", dtype="<f4")}
    covered = arrays["ndf"].tobytes()
    if "ndf_theta.npy" in members:
        arrays["ndf_theta"] = npy_array(members["ndf_theta.npy"], path, "ndf_theta.npy", dtype="<f8")
        covered += arrays["ndf_theta"].tobytes()
    if hashlib.sha256(covered).hexdigest() != meta.get("ndf_sha256"):
        raise FileFormatError(path, "NDF checksum mismatch: the file is damaged")
    return arrays


def _warn_if_legacy(path: Path, meta: dict[str, Any]) -> None:
    """The warning on a version-1 or -2 file, once it has passed every check (a file that
    fails one gets its error alone, one line)."""
    if meta["version"] < 3:
        warnings.warn(f"{path}: model format version {meta['version']} checksums only the NDF; its parameters are "
                      "range-checked but not verified (save it again to get version 3)", ReflectoWarning, stacklevel=4)


def _model_parameters(path: Path, meta: dict[str, Any]) -> tuple[Array, Array, Array, bool, dict[str, Any]]:
    """k_d, k_s, η, correlated and metadata of a model file, types and ranges checked."""
    def triple(key: str, lo: float, hi: float) -> Array:
        v = meta.get(key)
        ok = isinstance(v, list) and len(v) == 3 and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                         for x in v)
        arr = np.asarray(v, dtype=np.float64) if ok else np.zeros(0)
        if not ok or not np.all(np.isfinite(arr)) or np.any(arr < lo) or np.any(arr > hi):
            raise FileFormatError(path, f"invalid model parameters ({key} must be three finite numbers in "
                                  f"[{lo:g}, {hi:g}], got {short_repr(v)})")
        return arr

    kd = triple("kd", 0.0, 1.0)
    ks = triple("ks", 0.0, math.inf)
    form = meta.get("fresnel", "dielectric")  # a file without the field holds a dielectric η
    if form not in ("dielectric", "constant"):
        raise FileFormatError(path, f"invalid model parameters ('fresnel' must be \"dielectric\" or "
                                    f"\"constant\", got {short_repr(form)})")
    if form == "constant" and meta.get("eta") is not None:
        raise FileFormatError(path, "invalid model parameters (a constant Fresnel lobe has no η, got "
                                    f"{short_repr(meta.get('eta'))})")
    eta = np.full(3, math.inf) if form == "constant" else triple("eta", *ETA_RANGE)
    correlated = meta.get("correlated", False)
    if not isinstance(correlated, bool):
        raise FileFormatError(path, "invalid model parameters "
                                    f"('correlated' must be true or false, got {short_repr(correlated)})")
    metadata = meta.get("metadata") or {}
    if not isinstance(metadata, dict):
        raise FileFormatError(path, f"'metadata' must be an object, got {short_repr(metadata)}")
    return kd, ks, eta, correlated, metadata


def _check_normal_metadata(path: Path, metadata: dict[str, Any]) -> None:
    """The sample normal a reconstruction records (``reflecto info`` shows it): a unit-length
    3-vector, angles in [0°, 90°] (the uncertainty may be ``null``: not finite), a source
    name; anything else is a damaged file."""
    def angle(v: Any) -> bool:
        return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and 0.0 <= v <= 90.0

    checks = {"normal_tilt_deg": angle, "normal_uncertainty_deg": lambda v: v is None or angle(v),
              "normal_source": lambda v: isinstance(v, str) and len(v) <= 64,
              "normal": lambda v: isinstance(v, list) and len(v) == 3 and all(
                  isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v)
              and abs(math.hypot(*v) - 1.0) < 1e-3}
    for key, ok in checks.items():
        if key in metadata and not ok(metadata[key]):
            raise FileFormatError(path, f"metadata {key!r} is not a valid sample normal entry: "
                                        f"{short_repr(metadata[key])}")


def _local_metadata(path: Path, metadata: dict[str, Any]) -> dict[str, Any]:
    """``metadata`` with its ``capture`` folder and ``calibration`` file resolved against the model's folder.

    Each is kept (as that path) only if it exists and lies inside the model's folder;
    a model file cannot make a reader open files elsewhere. One that fails the rule is
    named under ``capture_not_found`` / ``calibration_not_found`` (for messages only).
    """

    out = dict(metadata)
    _check_normal_metadata(path, out)
    for key, is_kind in (("capture", os.path.isdir), ("calibration", os.path.isfile)):
        name = out.pop(key, None)
        if name is None:
            continue
        if (not isinstance(name, str) or not name or "\x00" in name or Path(name).is_absolute()
                or ".." in Path(name).parts):
            out[f"{key}_not_found"] = str(name)[:200]
            continue
        folder = path.parent
        target = folder / name
        real_folder, real = os.path.realpath(folder), os.path.realpath(target)
        if os.path.commonpath([real_folder, real]) == real_folder and is_kind(real):
            out[key] = str(target)
        else:
            out[f"{key}_not_found"] = name
    return out


def _check_model(path: Path, model: MicrofacetBRDF | IsotropicMicrofacetBRDF) -> None:
    """Ranges, NDF normalization (AR 1.2) and albedo of a model (as loaded or about to be saved)."""
    if not (np.all(model.kd >= 0) and np.all(model.kd <= 1)):
        raise FileFormatError(path, f"k_d {model.kd.tolist()} outside [0, 1]")
    if not is_constant(model.eta) and not (np.all(model.eta >= ETA_RANGE[0]) and np.all(model.eta <= ETA_RANGE[1])):
        raise FileFormatError(path, f"η {model.eta.tolist()} outside [{ETA_RANGE[0]:g}, {ETA_RANGE[1]:g}]")
    if isinstance(model, IsotropicMicrofacetBRDF):
        total = model.ndf_table.normalization
    else:
        total = float(model.ndf_values @ model.cube.projected_solid_angles)
    if not abs(total - 1.0) <= NDF_NORM_TOLERANCE:
        raise FileFormatError(path, f"the NDF is not normalized (∫ D cos θ dω = {total:.6g}, AR 1.2 needs 1)")
    lobes = model.lobes if isinstance(model, IsotropicMicrofacetBRDF) else None
    if lobes is not None:
        for t, d in zip(lobes.theta_d, lobes.ndfs):
            if not abs(d.normalization - 1.0) <= NDF_NORM_TOLERANCE:
                raise FileFormatError(path, f"the NDF of θ_d node {math.degrees(t):.1f}° is not normalized "
                                            f"(∫ D cos θ dω = {d.normalization:.6g}, AR 1.2 needs 1)")
    check_plausible(model, path, albedo_range=(0.0, MODEL_ALBEDO_MAX))


def load_model(path: str | Path) -> MicrofacetBRDF | IsotropicMicrofacetBRDF:
    """Read a reflecto model file, hemicube or isotropic (the checks are :meth:`MicrofacetBRDF.load`'s).

    Parameters
    ----------
    path
        A ``.reflecto`` model file, as :func:`reflecto.workflow.save_model` or a model's ``save`` writes it.

    Returns
    -------
    MicrofacetBRDF or IsotropicMicrofacetBRDF
        The model ``f = k_d/π + k_s D S S F / (4 cos θ_i cos θ_o)`` (eqs. 1–2), evaluated in sr⁻¹.

    Raises
    ------
    FileFormatError
        For a missing, foreign, damaged or implausible file.
    """
    return MicrofacetBRDF.load(path)


class IsotropicMicrofacetBRDF(BRDFSource):
    """Generalized microfacet BRDF (eqs. 1–2) with an isotropic NDF ``D(θ_h)``.

    ``f(i, o) = k_d/π + k_s D(θ_h) F(i·h; η) / (4 σ(i) σ(o))`` (the cancelled form of
    AR 1.6), with ``D`` and ``σ`` from :class:`reflecto.polar.IsotropicNDF`.

    Parameters
    ----------
    ndf
        The NDF: an :class:`~reflecto.polar.IsotropicNDF`, or ``(nodes, values)``
        (radians, sr⁻¹; normalized here unless ``normalize=False``).
    kd, ks, eta
        Per-channel diffuse albedo, specular scale and relative index (3 numbers or one).
    correlated
        Height-correlated Smith form instead of the separable product (§1.3).
    metadata
        Free JSON-serializable information kept in the model file.
    tint
        Per-channel Fresnel tint ``τ_c(θ_d)`` (:class:`~reflecto.fresnel.FresnelTint`, or
        ``(nodes, values)``): ``F_c = min(1, τ_c F(c; η_c))``; ``None``: eq. 4 alone.
    lobes
        The specular lobe's NDF per ``θ_d`` node (:class:`~reflecto.polar.NodeNDFs`, or
        ``(theta_d, values)`` with ``values`` of shape ``(J, K)`` on ``ndf``'s polar
        nodes, normalized here): the lobe term is then node ``j``'s microfacet lobe
        ``D_j S_j S_j / (4 cos θ_i cos θ_o)`` (``S_j`` from ``D_j``, eq. 8) at its node's
        ``θ_d``, interpolated between the nodes as the tint is; ``ndf`` stays the NDF of
        :meth:`ndf`, :meth:`shadowing` and :meth:`to_hemicube`. ``None``: ``ndf`` everywhere.
    """

    #: Diffuse and specular albedos and the relative index, RGB, shape ``(3,)`` (set by the constructor).
    kd: Array
    ks: Array
    eta: Array
    #: The per-channel Fresnel tint, or ``None`` (set by the constructor).
    tint: FresnelTint | None
    #: The lobe's NDF per θ_d node, or ``None`` (set by the constructor).
    lobes: NodeNDFs | None
    _fresnel_table: FresnelTable
    #: Height-correlated Smith shadowing (else separable), and free-form metadata.
    correlated: bool
    metadata: dict[str, Any]


    kind = "model"

    def __init__(self, ndf: IsotropicNDF | tuple[ArrayLike, ArrayLike], kd: ArrayLike = 0.0, ks: ArrayLike = 1.0,
                 eta: ArrayLike = 1.5, *, normalize: bool = True, correlated: bool = False,
                 metadata: dict[str, Any] | None = None, path: Path | None = None,
                 tint: FresnelTint | tuple[ArrayLike, ArrayLike] | None = None,
                 lobes: NodeNDFs | tuple[ArrayLike, ArrayLike] | None = None) -> None:
        if not isinstance(ndf, IsotropicNDF):
            nodes, values = ndf
            # stored as float32 in model files: round now so that save/load is exact
            values = np.asarray(values, dtype=np.float64)
            if normalize:
                values = IsotropicNDF(nodes, values).values
            ndf = IsotropicNDF(np.asarray(nodes, np.float64), np.asarray(values, "<f4").astype(np.float64),
                               normalize=False)
        self.ndf_table = ndf
        if lobes is not None and not isinstance(lobes, NodeNDFs):
            theta_d, rows = lobes
            rows = np.asarray(rows, dtype=np.float64)
            if rows.ndim != 2:
                raise ParameterError(f"NDF per θ_d node: values must be (nodes, {len(ndf.nodes)}), got {rows.shape}")
            # stored as float32: normalize, round, and keep the rounded table (save/load is exact)
            lobes = NodeNDFs(theta_d, [IsotropicNDF(ndf.nodes, np.asarray(
                IsotropicNDF(ndf.nodes, r).values if normalize else r, "<f4").astype(np.float64), normalize=False)
                for r in rows])
        elif lobes is not None and not np.array_equal(lobes.ndfs[0].nodes, ndf.nodes):
            raise ParameterError("NDF per θ_d node: the NDFs must share the model NDF's polar nodes")
        self.lobes = lobes
        _common_scalars(self, kd, ks, eta, correlated, metadata, path, tint)
        self.isotropic = True
        self._hemicube: dict[int, MicrofacetBRDF] = {}

    @property
    def resolution(self) -> int:
        """Number of polar nodes of the NDF."""
        return len(self.ndf_table.nodes)

    def ndf(self, h: ArrayLike) -> Array:
        """The isotropic NDF ``D(θ_h)``, interpolated between the polar nodes.

        Parameters
        ----------
        h : array_like, shape (..., 3)
            Unit half vectors in the local frame.

        Returns
        -------
        ndarray, shape (...)
            ``D`` in sr⁻¹ (AR 1.2 normalization); 0 below the horizon.
        """
        return self.ndf_table(h)

    def shadowing(self, k: ArrayLike) -> Array:
        """APS shadowing ``S(k) = (k·n)/σ(k)`` (eq. 8) of the isotropic NDF.

        Parameters
        ----------
        k : array_like, shape (..., 3)
            Directions in the local frame (need not be unit: only ``cos θ_k`` is used).

        Returns
        -------
        ndarray, shape (...)
            ``S(k)`` in [0, 1].
        """
        k = np.asarray(k, dtype=np.float64)
        return self.ndf_table.shadowing(k[..., 2] / np.maximum(np.linalg.norm(k, axis=-1), 1e-300))

    def fresnel(self, c: ArrayLike) -> Array:
        """Per-channel Fresnel ``τ_c(θ_d) F(c; η)`` (eq. 4, times the tint when there is one).

        Parameters
        ----------
        c : array_like
            ``c = |i·h| = cos θ_d``, in [0, 1].

        Returns
        -------
        ndarray, shape ``c.shape + (3,)``
            F per RGB channel (dimensionless); 1 for the constant lobe (η = ∞) without a tint.
        """
        return _tinted_fresnel(self, c)

    def eval(self, i: ArrayLike, o: ArrayLike) -> Array:
        """The BRDF ``f = k_d/π + k_s D(θ_h) F(c; η) / (4 σ(i) σ(o))`` (eqs. 1–2, AR 1.6);
        with :attr:`lobes`, ``Σ_j H_j(θ_d) D_j(θ_h) / (4 σ_j(i) σ_j(o))`` in place of the lobe.

        Parameters
        ----------
        i, o : array_like, shape (..., 3)
            Unit light and view directions in the local frame; broadcast.

        Returns
        -------
        ndarray, shape (..., 3)
            Linear RGB BRDF in sr⁻¹; 0 where either direction is below the horizon.
        """
        i = np.asarray(i, dtype=np.float64)
        o = np.asarray(o, dtype=np.float64)
        i, o = np.broadcast_arrays(i, o)
        ci, co = i[..., 2], o[..., 2]
        ok = (ci > 0) & (co > 0)
        hs = i + o
        norm = np.sqrt(np.einsum("...k,...k->...", hs, hs))
        norm = np.where(norm > 0, norm, 1.0)
        ch = hs[..., 2] / norm
        c = np.abs(np.einsum("...k,...k->...", i, hs)) / norm
        theta_h = np.arccos(np.clip(ch, -1.0, 1.0))
        keep = ok & (ch > 0)
        if self.lobes is None:
            spec = _lobe_term(self.ndf_table, theta_h, ci, co, self.correlated, keep)
        else:  # the microfacet lobes of the θ_d nodes, each with its own S (eq. 8), mixed by θ_d
            spec = np.zeros(theta_h.shape)
            for w, ndf in zip(self.lobes.hats(np.arccos(np.clip(c, 0.0, 1.0))), self.lobes.ndfs):
                if np.any(w > 0):
                    spec += w * _lobe_term(ndf, theta_h, ci, co, self.correlated, keep & (w > 0))
        f = self._fresnel_table(c)
        f *= self.ks
        f *= spec[..., None]
        f += self.kd / math.pi
        f[~ok] = 0.0
        return f

    def to_hemicube(self, resolution: int = 128) -> MicrofacetBRDF:
        """The BRDF with its NDF tabulated on a hemicube (for plots and the §5.5 merge). One
        hemicube NDF holds :meth:`ndf`: a model with an NDF per θ_d node (:attr:`lobes`)
        becomes the one-NDF model of the same ``ndf``, not the same BRDF.

        Parameters
        ----------
        resolution
            Top-face resolution N of the hemicube.

        Returns
        -------
        MicrofacetBRDF
            Same ``kd``, ``ks``, ``eta``, shadowing form and metadata; cached per resolution.
        """
        if resolution not in self._hemicube:
            cube = hemicube(resolution)
            self._hemicube[resolution] = MicrofacetBRDF(self.ndf(cube.directions), self.kd, self.ks, self.eta,
                                                        correlated=self.correlated, metadata=self.metadata,
                                                        tint=self.tint)
        return self._hemicube[resolution]

    def scaled(self, factor: float) -> IsotropicMicrofacetBRDF:
        """The same BRDF times ``factor``: ``k_d`` and ``k_s`` scaled, the NDF and its
        per-node lobes, η, tint, shadowing form and metadata kept (``f`` is linear in
        ``k_d, k_s``, eq. 1).

        Parameters
        ----------
        factor
            The scale (dimensionless, ≥ 0).

        Returns
        -------
        IsotropicMicrofacetBRDF
            A new model with ``factor · f``.
        """
        return IsotropicMicrofacetBRDF(self.ndf_table, self.kd * factor, self.ks * factor, self.eta,
                                       correlated=self.correlated, metadata=self.metadata, tint=self.tint,
                                       lobes=self.lobes)

    def parameters(self) -> dict[str, Any]:
        """The model's parameters, for ``reflecto info``.

        Returns
        -------
        dict
            ``resolution`` (number of polar nodes), ``kd``, ``ks`` and ``eta`` (RGB lists),
            ``shadowing`` (eq. 8 or height-correlated Smith) and ``metadata`` when there is any.
        """
        return {
            "resolution": f"isotropic, {self.resolution} polar nodes",
            "kd": self.kd.tolist(),
            "ks": self.ks.tolist(),
            **eta_to_json(self.eta),
            **_tint_parameters(self),
            **_lobe_parameters(self),
            "shadowing": "height-correlated Smith" if self.correlated else "separable APS (eq. 8)",
            **({"metadata": self.metadata} if self.metadata else {}),
        }

    def save(self, path: str | Path) -> Path:
        """Write the model file atomically: ``meta.json``, ``ndf.npy`` (D at the nodes,
        float32) and ``ndf_theta.npy`` (the nodes, radians), checksummed as
        :meth:`MicrofacetBRDF.save` describes; a model that :meth:`MicrofacetBRDF.load`
        would refuse is refused here with :class:`ParameterError`.

        Parameters
        ----------
        path
            The file to write; its name ends in :data:`MODEL_SUFFIX`.

        Returns
        -------
        Path
            ``path``.
        """
        path = _model_path(path)
        meta = {
            "format": MODEL_FORMAT,
            "version": _tint_version(self, 5 if self.lobes is not None else 4 if self.tint is not None else 3),
            "ndf_kind": "isotropic",
            "resolution": self.resolution,
            "kd": self.kd.tolist(),
            "ks": self.ks.tolist(),
            **eta_to_json(self.eta),
            "correlated": self.correlated,
            "metadata": self.metadata,
            **_tint_meta(self),
        }
        arrays = {"ndf": self.ndf_table.values.astype("<f4"), "ndf_theta": self.ndf_table.nodes.astype("<f8"),
                  **_tint_arrays(self)}
        if self.lobes is not None:
            arrays["lobes"] = self.lobes.values.astype("<f4")
            arrays["lobes_theta_d"] = self.lobes.theta_d.astype("<f8")
        try:
            _check_model(path, self)
        except FileFormatError as e:
            raise ParameterError(f"{path}: not saved, the model is invalid: {e.problem}") from None
        _write_model_file(path, meta, arrays)
        return path

    @classmethod
    def _from_file(cls, path: Path, meta: dict[str, Any], arrays: dict[str, NDArray[Any]],
                   params: tuple[Array, Array, Array, bool, dict[str, Any]]) -> IsotropicMicrofacetBRDF:
        """The model of an isotropic file whose arrays and parameters :meth:`MicrofacetBRDF.load` checked."""
        values, nodes = arrays.get("ndf"), arrays.get("ndf_theta")
        if nodes is None:
            raise FileFormatError(path, "isotropic model without its polar nodes (ndf_theta.npy)")
        n = meta.get("resolution", len(nodes))
        if (values is None or values.dtype != np.dtype("<f4") or nodes.dtype != np.dtype("<f8") or values.ndim != 1
                or values.shape != nodes.shape or n != len(nodes) or not 3 <= len(nodes) <= MAX_POLAR_NODES):
            raise FileFormatError(path, f"isotropic NDF arrays must be 3 to {MAX_POLAR_NODES} float32 values on as "
                                  "many float64 nodes, as the resolution says")
        kd, ks, eta, correlated, metadata = params
        if meta.get("version", 0) < 5 and ("lobes" in arrays or "lobes_theta_d" in arrays):
            raise FileFormatError(path, f"an NDF per θ_d node (lobes.npy) needs model format version 5, "
                                        f"the file says {meta.get('version')}")
        try:
            ndf = IsotropicNDF(nodes, values.astype(np.float64), normalize=False)
            model = cls(ndf, kd, ks, eta, correlated=correlated, metadata=metadata, path=path,
                        tint=_tint_from_arrays(path, arrays, meta), lobes=_lobes_from_arrays(path, arrays, ndf))
        except ParameterError as e:
            raise FileFormatError(path, f"invalid model parameters ({e})") from None
        _check_model(path, model)
        return model


register_reader(Reader("model", "a model file (.reflecto)", (".reflecto",), (b"PK",), load_model))
