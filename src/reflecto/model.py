"""The generalized microfacet BRDF of Lan et al. 2010, §3.1 (eqs. 1, 2, 4, 8).

``f(i, o) = k_d/π + k_s · D(h) S(i) S(o) F(i·h; η) / (4 (i·n)(o·n))``          (eqs. 1–2)

* ``D`` — tabulated on a hemicube (§9 of algorithm-reference), normalized so that
  ``∫ D(h)(h·n) dω_h = 1`` (eq. 1.2); one NDF shared by the three colour channels;
* ``S`` — APS shadowing derived from D (eq. 8), tabulated as σ and clamped so S ≤ 1;
* ``F`` — Cook–Torrance Fresnel (eq. 4) with a per-channel real index η;
* ``k_d`` (diffuse albedo ρ_d), ``k_s`` — per channel.

Two tabulations of ``D``: :class:`MicrofacetBRDF` holds any NDF on a hemicube
(anisotropic materials, §5.5); :class:`IsotropicMicrofacetBRDF` holds an isotropic
``D(θ_h)`` on polar nodes (:mod:`reflecto.polar`), which is what an isotropic
material's reconstruction determines, at a fraction of the storage and cost.

Evaluation uses the cancelled form ``k_s D F / (4 σ(i) σ(o))`` (algorithm-reference
eq. 1.6), which is finite at grazing angles. The physical unit is sr⁻¹ throughout; the
paper's "4π" constant is *not* used (algorithm-reference §3.2–§3.3).
"""

from __future__ import annotations

import hashlib
import io
import json
import math
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import _kernels
from .errors import FileFormatError, ParameterError
from .fresnel import FresnelTable, fresnel
from .hemicube import Hemicube, hemicube
from .io import atomic_write
from .polar import IsotropicNDF
from .shadowing import SigmaTable, sigma_table
from .sources.base import BRDFSource
from .sources.base import rgb_triplet as _rgb

Array = NDArray[np.float64]

#: Format identifier and version of reflecto model files.
MODEL_FORMAT = "reflecto-model"
MODEL_VERSION = 2
MODEL_SUFFIX = ".reflecto"

__all__ = ["MicrofacetBRDF", "IsotropicMicrofacetBRDF", "load_model", "MODEL_SUFFIX"]


class MicrofacetBRDF(BRDFSource):
    """Generalized microfacet BRDF with a tabulated hemicube NDF.

    Parameters
    ----------
    ndf
        D on the hemicube texels, shape ``(3 N²,)``; non-negative, finite. It is
        normalized here (eq. 1.2) unless ``normalize=False``; the scale removed is
        *not* moved into ``ks`` — pass ``ks`` for the intended level.
    kd, ks, eta
        Per-channel diffuse albedo, specular scale and relative index (3 numbers or one).
    correlated
        Use the height-correlated Smith form ``S(i)S(o)/(S(i)+S(o)−S(i)S(o))`` instead
        of the paper's separable product (algorithm-reference §1.3).
    metadata
        Free JSON-serializable information kept in the model file.
    """

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
        self.kd = _rgb(kd, "kd")
        self.ks = _rgb(ks, "ks")
        self.eta = _rgb(eta, "eta")
        if np.any(self.kd < 0) or np.any(self.ks < 0):
            raise ParameterError("kd and ks must be >= 0")
        if np.any(self.eta <= 0):
            raise ParameterError("eta must be > 0")
        self.correlated = bool(correlated)
        self.metadata = dict(metadata or {})
        self.path = path
        self.reciprocal = True
        self.isotropic = False
        self._padded = self.cube.pad(self.ndf_values)
        self._sigma: SigmaTable | None = None
        self._fresnel_table = FresnelTable(self.eta)

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
        """``D(h)`` in sr⁻¹ by bilinear hemicube lookup; 0 below the horizon."""
        h = np.asarray(h, dtype=np.float64)
        return np.where(h[..., 2] > 0, self.cube.lookup(self.ndf_values, h, self._padded), 0.0)

    def shadowing(self, k: ArrayLike) -> Array:
        """APS shadowing ``S(k) = (k·n)/σ(k)`` in [0, 1] (eq. 8)."""
        return self.sigma_table.eval(k)

    def fresnel(self, c: ArrayLike) -> Array:
        """Per-channel ``F(c; η)`` (eq. 4), shape ``c.shape + (3,)``."""
        return fresnel(np.asarray(c)[..., None], self.eta)

    def specular_lobe(self, i: ArrayLike, o: ArrayLike) -> Array:
        """``D S(i) S(o) / (4 cos θ_i cos θ_o)`` without k_s and F (sr⁻¹), shape ``(N,)``."""
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
            denom = 4.0 * si * so  # eq. 1.6
        spec = np.divide(d, denom, out=np.zeros_like(d), where=ok & (denom > 0))
        return spec, c

    def eval(self, i: ArrayLike, o: ArrayLike) -> Array:
        """BRDF in sr⁻¹ (eqs. 1–2), shape ``(N, 3)``; 0 below the horizon.

        A compiled loop (:func:`reflecto._kernels.model_eval`) that computes exactly
        what :meth:`eval_numpy` computes, without its temporaries.
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
        """Reference NumPy implementation of :meth:`eval` (same values, slower)."""
        i = np.asarray(i, dtype=np.float64)
        o = np.asarray(o, dtype=np.float64)
        spec, c = self._parts(i, o)
        f = self._fresnel_table(c)
        f *= self.ks
        f *= spec[..., None]
        f += self.kd / math.pi
        f[~((i[..., 2] > 0) & (o[..., 2] > 0))] = 0.0
        return f

    def parameters(self) -> dict[str, Any]:
        return {
            "resolution": f"{self.cube.n}x{self.cube.n} top, {self.cube.n}x{self.cube.half} sides",
            "kd": self.kd.tolist(),
            "ks": self.ks.tolist(),
            "eta": self.eta.tolist(),
            "shadowing": "height-correlated Smith" if self.correlated else "separable APS (eq. 8)",
            **({"metadata": self.metadata} if self.metadata else {}),
        }

    # -------------------------------------------------------------- factories
    @classmethod
    def from_ndf_function(
        cls, ndf_fn: Any, resolution: int = 512, **kw: Any
    ) -> MicrofacetBRDF:
        """Tabulate ``ndf_fn(h) → D`` (vectorised, shape ``(M, 3) → (M,)``) on a hemicube."""
        cube = hemicube(resolution)
        return cls(ndf_fn(cube.directions), **kw)

    # ------------------------------------------------------------------- files
    def save(self, path: str | Path) -> Path:
        """Write the model file atomically (a zip of ``meta.json`` and ``ndf.npy``).

        ``meta.json`` holds the format name and version, the scalars, and the SHA-256
        of the NDF bytes, so that damaged files are refused on load.
        """
        path = Path(path)
        ndf32 = self.ndf_values.astype("<f4")
        buf = io.BytesIO()
        np.save(buf, ndf32, allow_pickle=False)
        meta = {
            "format": MODEL_FORMAT,
            "version": MODEL_VERSION,
            "ndf_kind": "hemicube",
            "resolution": self.cube.n,
            "kd": self.kd.tolist(),
            "ks": self.ks.tolist(),
            "eta": self.eta.tolist(),
            "correlated": self.correlated,
            "ndf_sha256": hashlib.sha256(ndf32.tobytes()).hexdigest(),
            "metadata": self.metadata,
        }
        with atomic_write(path) as fh:
            with zipfile.ZipFile(fh, "w", compression=zipfile.ZIP_DEFLATED) as z:
                z.writestr("meta.json", json.dumps(meta, indent=1))
                z.writestr("ndf.npy", buf.getvalue())
        return path

    @classmethod
    def load(cls, path: str | Path) -> MicrofacetBRDF:
        """Read a model file written by :meth:`save`; refuse foreign or damaged files."""
        path = Path(path)
        try:
            with zipfile.ZipFile(path) as z:
                names = set(z.namelist())
                if "meta.json" not in names or "ndf.npy" not in names:
                    raise FileFormatError(path, "not a reflecto model file (meta.json or ndf.npy missing)")
                meta = json.loads(z.read("meta.json").decode("utf-8"))
                raw = z.read("ndf.npy")
                theta_raw = z.read("ndf_theta.npy") if "ndf_theta.npy" in names else None
        except FileNotFoundError:
            raise FileFormatError(path, "no such file") from None
        except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError) as e:
            raise FileFormatError(path, f"not a reflecto model file or damaged ({e})") from None
        except (UnicodeDecodeError, json.JSONDecodeError) as e:
            raise FileFormatError(path, f"damaged model metadata ({e})") from None
        if not isinstance(meta, dict) or meta.get("format") != MODEL_FORMAT:
            raise FileFormatError(path, f"not a reflecto model file (format is {meta.get('format')!r})")
        version = meta.get("version")
        if not isinstance(version, int) or version < 1:
            raise FileFormatError(path, f"invalid model format version {version!r}")
        if version > MODEL_VERSION:
            raise FileFormatError(
                path,
                f"written by a newer reflecto (model format version {version}; this version reads <= {MODEL_VERSION})",
            )
        if meta.get("ndf_kind", "hemicube") == "isotropic":
            return IsotropicMicrofacetBRDF._from_file(path, meta, raw, theta_raw)
        try:
            ndf = np.load(io.BytesIO(raw), allow_pickle=False)
        except ValueError as e:
            raise FileFormatError(path, f"damaged NDF array ({e})") from None
        if hashlib.sha256(np.ascontiguousarray(ndf, dtype="<f4").tobytes()).hexdigest() != meta.get("ndf_sha256"):
            raise FileFormatError(path, "NDF checksum mismatch: the file is damaged")
        n = meta.get("resolution")
        if not isinstance(n, int) or ndf.shape != (3 * n * n,):
            raise FileFormatError(path, f"NDF has shape {ndf.shape}, expected (3·{n}²,)")
        try:
            return cls(
                ndf,
                meta["kd"],
                meta["ks"],
                meta["eta"],
                normalize=False,
                correlated=bool(meta.get("correlated", False)),
                metadata=meta.get("metadata") or {},
                path=path,
            )
        except (KeyError, ParameterError) as e:
            raise FileFormatError(path, f"invalid model parameters ({e})") from None


def load_model(path: str | Path) -> MicrofacetBRDF | IsotropicMicrofacetBRDF:
    """Read a reflecto model file, hemicube or isotropic (see :meth:`MicrofacetBRDF.load`)."""
    return MicrofacetBRDF.load(path)


class IsotropicMicrofacetBRDF(BRDFSource):
    """Generalized microfacet BRDF (eqs. 1–2) with an isotropic NDF ``D(θ_h)``.

    ``f(i, o) = k_d/π + k_s D(θ_h) F(i·h; η) / (4 σ(i) σ(o))`` (the cancelled form of
    eq. 1.6), with ``D`` and ``σ`` from :class:`reflecto.polar.IsotropicNDF`.

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
    """

    kind = "model"

    def __init__(self, ndf: IsotropicNDF | tuple[ArrayLike, ArrayLike], kd: ArrayLike = 0.0, ks: ArrayLike = 1.0,
                 eta: ArrayLike = 1.5, *, normalize: bool = True, correlated: bool = False,
                 metadata: dict[str, Any] | None = None, path: Path | None = None) -> None:
        if not isinstance(ndf, IsotropicNDF):
            nodes, values = ndf
            # stored as float32 in model files: round now so that save/load is exact
            values = np.asarray(values, dtype=np.float64)
            if normalize:
                values = IsotropicNDF(nodes, values).values
            ndf = IsotropicNDF(np.asarray(nodes, np.float64), np.asarray(values, "<f4").astype(np.float64),
                               normalize=False)
        self.ndf_table = ndf
        self.kd = _rgb(kd, "kd")
        self.ks = _rgb(ks, "ks")
        self.eta = _rgb(eta, "eta")
        if np.any(self.kd < 0) or np.any(self.ks < 0):
            raise ParameterError("kd and ks must be >= 0")
        if np.any(self.eta <= 0):
            raise ParameterError("eta must be > 0")
        self.correlated = bool(correlated)
        self.metadata = dict(metadata or {})
        self.path = path
        self.reciprocal = True
        self.isotropic = True
        self._fresnel_table = FresnelTable(self.eta)
        self._hemicube: dict[int, MicrofacetBRDF] = {}

    @property
    def resolution(self) -> int:
        """Number of polar nodes of the NDF."""
        return len(self.ndf_table.nodes)

    def ndf(self, h: ArrayLike) -> Array:
        """``D(h)`` in sr⁻¹; 0 below the horizon."""
        return self.ndf_table(h)

    def shadowing(self, k: ArrayLike) -> Array:
        """APS shadowing ``S(k) = (k·n)/σ(k)`` in [0, 1] (eq. 8)."""
        k = np.asarray(k, dtype=np.float64)
        return self.ndf_table.shadowing(k[..., 2] / np.maximum(np.linalg.norm(k, axis=-1), 1e-300))

    def fresnel(self, c: ArrayLike) -> Array:
        """Per-channel ``F(c; η)`` (eq. 4), shape ``c.shape + (3,)``."""
        return fresnel(np.asarray(c)[..., None], self.eta)

    def eval(self, i: ArrayLike, o: ArrayLike) -> Array:
        """BRDF in sr⁻¹ (eqs. 1–2), shape ``(..., 3)``; 0 below the horizon."""
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
        d = self.ndf_table.at_theta(np.arccos(np.clip(ch, -1.0, 1.0)))
        si = self.ndf_table.projected_area(ci)
        so = self.ndf_table.projected_area(co)
        if self.correlated:
            denom = 4.0 * (si * np.maximum(co, 0) + so * np.maximum(ci, 0) - np.maximum(ci, 0) * np.maximum(co, 0))
        else:
            denom = 4.0 * si * so
        spec = np.divide(d, denom, out=np.zeros_like(d), where=ok & (denom > 0) & (ch > 0))
        f = self._fresnel_table(c)
        f *= self.ks
        f *= spec[..., None]
        f += self.kd / math.pi
        f[~ok] = 0.0
        return f

    def to_hemicube(self, resolution: int = 128) -> MicrofacetBRDF:
        """The same BRDF with its NDF tabulated on a hemicube (for plots and the §5.5 merge)."""
        if resolution not in self._hemicube:
            cube = hemicube(resolution)
            self._hemicube[resolution] = MicrofacetBRDF(self.ndf(cube.directions), self.kd, self.ks, self.eta,
                                                        correlated=self.correlated, metadata=self.metadata)
        return self._hemicube[resolution]

    def parameters(self) -> dict[str, Any]:
        return {
            "resolution": f"isotropic, {self.resolution} polar nodes",
            "kd": self.kd.tolist(),
            "ks": self.ks.tolist(),
            "eta": self.eta.tolist(),
            "shadowing": "height-correlated Smith" if self.correlated else "separable APS (eq. 8)",
            **({"metadata": self.metadata} if self.metadata else {}),
        }

    def save(self, path: str | Path) -> Path:
        """Write the model file atomically (a zip of ``meta.json``, ``ndf.npy``, ``ndf_theta.npy``)."""
        path = Path(path)
        values = self.ndf_table.values.astype("<f4")
        nodes = self.ndf_table.nodes.astype("<f8")
        arrays = {}
        for name, a in (("ndf.npy", values), ("ndf_theta.npy", nodes)):
            buf = io.BytesIO()
            np.save(buf, a, allow_pickle=False)
            arrays[name] = buf.getvalue()
        meta = {
            "format": MODEL_FORMAT,
            "version": MODEL_VERSION,
            "ndf_kind": "isotropic",
            "resolution": len(nodes),
            "kd": self.kd.tolist(),
            "ks": self.ks.tolist(),
            "eta": self.eta.tolist(),
            "correlated": self.correlated,
            "ndf_sha256": hashlib.sha256(values.tobytes() + nodes.tobytes()).hexdigest(),
            "metadata": self.metadata,
        }
        with atomic_write(path) as fh:
            with zipfile.ZipFile(fh, "w", compression=zipfile.ZIP_DEFLATED) as z:
                z.writestr("meta.json", json.dumps(meta, indent=1))
                for name, raw in arrays.items():
                    z.writestr(name, raw)
        return path

    @classmethod
    def _from_file(cls, path: Path, meta: dict[str, Any], raw: bytes, theta_raw: bytes | None) -> IsotropicMicrofacetBRDF:
        if theta_raw is None:
            raise FileFormatError(path, "isotropic model without its polar nodes (ndf_theta.npy)")
        try:
            values = np.load(io.BytesIO(raw), allow_pickle=False)
            nodes = np.load(io.BytesIO(theta_raw), allow_pickle=False)
        except ValueError as e:
            raise FileFormatError(path, f"damaged NDF array ({e})") from None
        values = np.ascontiguousarray(values, dtype="<f4")
        nodes = np.ascontiguousarray(nodes, dtype="<f8")
        if hashlib.sha256(values.tobytes() + nodes.tobytes()).hexdigest() != meta.get("ndf_sha256"):
            raise FileFormatError(path, "NDF checksum mismatch: the file is damaged")
        try:
            ndf = IsotropicNDF(nodes, values.astype(np.float64), normalize=False)
            return cls(ndf, meta["kd"], meta["ks"], meta["eta"], correlated=bool(meta.get("correlated", False)),
                       metadata=meta.get("metadata") or {}, path=path)
        except (KeyError, ParameterError) as e:
            raise FileFormatError(path, f"invalid model parameters ({e})") from None
