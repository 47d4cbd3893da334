"""Analytic microfacet BRDFs: GGX and Beckmann, isotropic or anisotropic, optionally
with a deliberately asymmetric NDF.

``f(i, o) = k_d/π + k_s · D(h) G1(i) G1(o) F(i·h; η) / (4 (i·n)(o·n))``

with Smith's separable masking–shadowing ``G1 = 1/(1 + Λ)`` — the same product form
as eq. 2 of Lan et al. 2010, so reconstructions can be compared term by term — and
the Cook–Torrance Fresnel of eq. 4 (per-channel η).

**Slope-space lobes.** The NDF is a mixture of elliptical lobes in slope space
``p = (h_x, h_y)/h_z`` (in a tangent frame rotated by ``rotation_deg`` about n)::

    D(h) = Σ_j w_j P22(p − c_j) / cos⁴θ_h

with ``P22`` the GGX or Beckmann slope density of roughness (α_x, α_y). A single lobe
at ``c = 0`` is the usual model. The *asymmetric* variant has two lobes,
``(w, s)`` and ``(1 − w, −s·w/(1 − w))``: the mean slope is zero (so it is still a
valid height-field NDF, ∫ h D dω = n and S(n) = 1), but ``D(τh) ≠ D(h)`` — it violates
the symmetry of eq. 3 on purpose. Smith's Λ of a mixture is exact and closed-form:
``Λ(k) = Σ_j w_j E[(q_j − μ)⁺]/μ`` with ``μ = cot θ_k`` and ``q_j`` the slope along
k's azimuth (algorithm-reference §1.2, AR 1.4).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import erfc

from .. import geometry
from ..brdf import BRDFSource, Reader, register_reader
from ..brdf import rgb_triplet as _rgb
from ..errors import FileFormatError, ParameterError, short_repr
from ..fresnel import fresnel
from ..io import read_description

if TYPE_CHECKING:
    from ..brdf import ArrayField

Array = NDArray[np.float64]

DISTRIBUTIONS = ("ggx", "beckmann")
#: Roughness range. Below 10⁻³ (a 0.06° lobe, sharper than any texel of the
#: reconstruction) the lobe's density overflows double precision at its peak.
ALPHA_MIN, ALPHA_MAX = 1e-3, 4.0


@dataclass(frozen=True)
class Lobe:
    """One slope-space lobe: mixture weight and centre (slope units)."""

    weight: float
    centre: tuple[float, float] = (0.0, 0.0)


#: Largest facet tilt (degrees) at which an asymmetric description may centre either of
#: its two lobes: the slope of each centre is at most tan 60° ≈ 1.73. Beyond it most of
#: a lobe's facets face past 60°, where its mass lies outside the NDF the condenser
#: measures and the mean-zero mixture needs an opposite lobe steeper still.
ASYMMETRY_MAX_TILT_DEG = 60.0


@dataclass
class AnalyticBRDF(BRDFSource):
    """GGX or Beckmann microfacet BRDF with Smith shadowing and dielectric Fresnel.

    Parameters
    ----------
    distribution
        ``"ggx"`` or ``"beckmann"``.
    alpha
        Roughness α (isotropic) or ``(α_x, α_y)`` along the rotated tangent/bitangent.
        Beckmann α is the RMS slope times √2, as in Walter et al. 2007.
    rotation_deg
        Rotation of the anisotropy axes about n, in degrees.
    kd
        Diffuse albedo ρ_d per channel (diffuse term ρ_d/π).
    ks
        Specular scale per channel.
    eta
        Relative index of refraction per channel (≥ 1).
    asymmetry
        ``None`` (symmetric) or ``(shift_x, shift_y, weight)``: the two-lobe asymmetric
        NDF described in the module docstring.
    correlated
        Smith's height-correlated masking–shadowing ``G2 = 1/(1 + Λ(i) + Λ(o))`` instead
        of the separable product ``G1(i) G1(o)`` (Heitz 2014; the albedo bound holds: ``G2 ≤ G1``).

    Energy: ``k_d + k_s ≤ 1`` per channel is required, which bounds the albedo by 1
    (Smith-masked microfacet reflection with F ≤ 1 never exceeds 1).
    """

    distribution: str = "ggx"
    alpha: float | Sequence[float] = 0.2
    rotation_deg: float = 0.0
    kd: ArrayField = cast("ArrayField", 0.0)
    ks: ArrayField = cast("ArrayField", 1.0)
    eta: ArrayField = cast("ArrayField", 1.5)
    asymmetry: tuple[float, float, float] | None = None
    path: Path | None = None
    correlated: bool = False
    lobes: tuple[Lobe, ...] = field(init=False)

    kind = "analytic"

    def __post_init__(self) -> None:
        if self.distribution not in DISTRIBUTIONS:
            raise ParameterError(f"distribution must be one of {DISTRIBUTIONS}, got {self.distribution!r}")
        a = np.asarray(self.alpha, dtype=np.float64)
        a = np.array([float(a), float(a)]) if a.ndim == 0 else a
        if a.shape != (2,) or not np.all(np.isfinite(a)) or np.any(a < ALPHA_MIN) or np.any(a > ALPHA_MAX):
            raise ParameterError(f"alpha must be one or two numbers in [{ALPHA_MIN:g}, {ALPHA_MAX:g}], "
                                 f"got {self.alpha!r}")
        self.alpha_xy = a
        if not math.isfinite(float(self.rotation_deg)):
            raise ParameterError("rotation_deg must be finite")
        self.kd = _rgb(self.kd, "kd")
        self.ks = _rgb(self.ks, "ks")
        self.eta = _rgb(self.eta, "eta")
        if np.any(self.kd < 0) or np.any(self.ks < 0):
            raise ParameterError("kd and ks must be >= 0")
        if np.any(self.kd + self.ks > 1.0 + 1e-12):
            raise ParameterError("kd + ks must be <= 1 per channel (energy conservation), "
                                 f"got {_plain(self.kd + self.ks)}")
        if np.any(self.eta < 1.0) or np.any(self.eta > 100.0):
            raise ParameterError(f"eta must lie in [1, 100], got {_plain(self.eta)}")
        if self.asymmetry is None:
            self.lobes = (Lobe(1.0),)
        else:
            sx, sy, w = (float(v) for v in self.asymmetry)
            if not (0.0 < w < 1.0) or not (math.isfinite(sx) and math.isfinite(sy)):
                raise ParameterError(f"asymmetry needs a finite shift and a weight in (0, 1), got shift "
                                     f"{[sx, sy]}, weight {w:g}")
            r = w / (1.0 - w)
            tilt = math.degrees(math.atan(max(math.hypot(sx, sy), math.hypot(sx, sy) * r)))
            if tilt > ASYMMETRY_MAX_TILT_DEG:
                raise ParameterError(f"asymmetry shift {[sx, sy]} with weight {w:g} centres a lobe at a "
                                     f"facet tilt of {tilt:.3g}°, more than {ASYMMETRY_MAX_TILT_DEG:g}° (the shift and "
                                     "shift·weight/(1 − weight) must be slopes of at most "
                                     f"tan {ASYMMETRY_MAX_TILT_DEG:g}° = "
                                     f"{math.tan(math.radians(ASYMMETRY_MAX_TILT_DEG)):.3g})")
            self.lobes = (Lobe(w, (sx, sy)), Lobe(1.0 - w, (-sx * r, -sy * r)))
        self.isotropic = bool(self.alpha_xy[0] == self.alpha_xy[1] and self.asymmetry is None)
        self.reciprocal = True
        self._rot = math.radians(float(self.rotation_deg))

    # ------------------------------------------------------------------ pieces
    def _to_lobe_frame(self, v: Array) -> Array:
        return geometry.rotate_z(v, -self._rot) if self._rot else v

    def ndf(self, h: ArrayLike) -> Array:
        """Normalized NDF ``D(h) = Σ_j w_j P22(p − c_j) / cos⁴θ_h`` (module docstring).

        Parameters
        ----------
        h : array_like, shape (..., 3)
            Unit half vectors in the local frame.

        Returns
        -------
        ndarray, shape ``h.shape[:-1]``
            D in sr⁻¹ (``∫ D cos θ dω = 1``); 0 where ``h_z ≤ 0``.
        """
        h = self._to_lobe_frame(np.asarray(h, dtype=np.float64))
        z = h[..., 2]
        pos = z > 0
        zs = np.where(pos, z, 1.0)
        px, py = h[..., 0] / zs, h[..., 1] / zs
        ax, ay = self.alpha_xy
        cos4 = zs**4
        d = np.zeros(np.shape(z))
        for lobe in self.lobes:
            qx = (px - lobe.centre[0]) / ax
            qy = (py - lobe.centre[1]) / ay
            r2 = qx * qx + qy * qy
            if self.distribution == "ggx":
                p22 = 1.0 / (math.pi * ax * ay * (1.0 + r2) ** 2)
            else:
                p22 = np.exp(-r2) / (math.pi * ax * ay)
            d = d + lobe.weight * p22
        return np.where(pos, d / cos4, 0.0)

    def smith_lambda(self, k: ArrayLike) -> Array:
        """Smith ``Λ(k) = Σ_j w_j E[(q_j − μ)⁺]/μ``, ``μ = cot θ_k`` (AR 1.4), closed form per lobe.

        Parameters
        ----------
        k : array_like, shape (..., 3)
            Unit directions in the local frame.

        Returns
        -------
        ndarray, shape ``k.shape[:-1]``
            Λ ≥ 0 (dimensionless); 0 at the normal.
        """
        k = self._to_lobe_frame(np.asarray(k, dtype=np.float64))
        z = np.clip(k[..., 2], 1e-12, 1.0)
        sxy = np.hypot(k[..., 0], k[..., 1])
        mu = np.minimum(z / np.maximum(sxy, 1e-300), 1e12)  # Λ → 0 as k → n
        ex = np.where(sxy > 0, k[..., 0] / np.maximum(sxy, 1e-300), 1.0)
        ey = np.where(sxy > 0, k[..., 1] / np.maximum(sxy, 1e-300), 0.0)
        ax, ay = self.alpha_xy
        alpha_k = np.sqrt((ax * ex) ** 2 + (ay * ey) ** 2)
        lam = np.zeros(np.shape(z))
        for lobe in self.lobes:
            nu = mu + lobe.centre[0] * ex + lobe.centre[1] * ey
            if self.distribution == "ggx":
                # E[(αY − ν)+] = (√(α² + ν²) − ν)/2, written stably for large ν
                big = nu > 0
                root = np.sqrt(alpha_k**2 + nu**2)
                e = np.where(big, 0.5 * alpha_k**2 / np.where(big, root + nu, 1.0), 0.5 * (root - nu))
            else:
                s = alpha_k / math.sqrt(2.0)
                t = nu / s
                e = s * np.exp(-0.5 * t * t) / math.sqrt(2.0 * math.pi) - nu * 0.5 * erfc(t / math.sqrt(2.0))
            lam = lam + lobe.weight * e
        return np.where(sxy > 0, lam / mu, 0.0)

    def g1(self, k: ArrayLike) -> Array:
        """Smith masking ``G1(k) = 1/(1 + Λ(k))``, equal to the APS ``S(k)`` of eq. 8.

        Parameters
        ----------
        k : array_like, shape (..., 3)
            Unit directions in the local frame.

        Returns
        -------
        ndarray, shape ``k.shape[:-1]``
            G1 in [0, 1]; 0 below the horizon.
        """
        k = np.asarray(k, dtype=np.float64)
        return np.where(k[..., 2] > 0, 1.0 / (1.0 + self.smith_lambda(k)), 0.0)

    def sigma(self, k: ArrayLike) -> Array:
        """Projected area ``σ(k) = cos θ_k (1 + Λ(k))`` (AR 1.3; the denominator of eq. 8).

        Parameters
        ----------
        k : array_like, shape (..., 3)
            Unit directions in the local frame.

        Returns
        -------
        ndarray, shape ``k.shape[:-1]``
            σ (dimensionless); 0 below the horizon.
        """
        k = np.asarray(k, dtype=np.float64)
        return np.maximum(k[..., 2], 0.0) * (1.0 + self.smith_lambda(k))

    # -------------------------------------------------------------------- eval
    def eval(self, i: ArrayLike, o: ArrayLike) -> Array:
        """Microfacet BRDF ``f = k_d/π + k_s D(h) F(i·h; η) / (4 σ(i) σ(o))`` (eqs. 1–2 in the
        form of AR 1.6, ``σ`` the projected area of eq. 8), sr⁻¹.

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
        ok = (i[..., 2] > 0) & (o[..., 2] > 0)
        h = geometry.half_vector(i, o)
        c = np.sum(i * h, axis=-1)
        d = self.ndf(h)
        if self.correlated:
            # G2 = 1/(1 + Λi + Λo), σ = cos (1 + Λ): D G2 / (4 cos cos) = D / (4 (σi cos_o + σo cos_i − cos_i cos_o))
            ci, co = i[..., 2], o[..., 2]
            denom = 4.0 * (self.sigma(i) * co + self.sigma(o) * ci - ci * co)
        else:
            # AR 1.6: D F / (4 σ(i) σ(o)) equals D G1 G1 F / (4 cos cos)
            denom = 4.0 * self.sigma(i) * self.sigma(o)
        spec = np.divide(d, denom, out=np.zeros_like(d), where=ok & (denom > 0))
        f = self.kd / math.pi + self.ks * spec[..., None] * fresnel(c[..., None], self.eta)
        return np.where(ok[..., None], f, 0.0)

    def parameters(self) -> dict[str, Any]:
        """The description's parameters, for ``reflecto info``.

        Returns
        -------
        dict
            ``distribution``, ``alpha`` (α_x, α_y), ``rotation_deg``, ``kd``, ``ks``, ``eta``
            (RGB lists) and ``asymmetry`` ``(shift_x, shift_y, weight)`` where set.
        """
        p: dict[str, Any] = {
            "distribution": self.distribution,
            "alpha": self.alpha_xy.tolist(),
            "rotation_deg": float(self.rotation_deg),
            "kd": self.kd.tolist(),
            "ks": self.ks.tolist(),
            "eta": self.eta.tolist(),
        }
        if self.asymmetry is not None:
            p["asymmetry"] = list(self.asymmetry)
        if self.correlated:
            p["shadowing"] = "height-correlated"
        return p

    def to_dict(self) -> dict[str, Any]:
        """The description-file form (see :func:`load_analytic`).

        Returns
        -------
        dict
            ``{"type": "analytic", **self.parameters()}``; :func:`analytic_from_dict` reads it back.
        """
        return {"type": "analytic", **self.parameters()}


_KEYS = {"type", "distribution", "alpha", "rotation_deg", "kd", "ks", "eta", "asymmetry", "name", "shadowing"}
#: The ``shadowing`` values of a description: Smith's separable product or its height-correlated form.
SHADOWING_FORMS = ("separable", "height-correlated")


def _plain(values: Any) -> str:
    """Numbers for a message as a user writes them, ``[101, 101, 101]``, not numpy's ``[101. 101. 101.]``."""
    return "[" + ", ".join(f"{float(v):g}" for v in np.ravel(values)) + "]"


def _numbers(value: Any, key: str, counts: tuple[int, ...], where: str) -> Any:
    """``value`` if it is a finite number (count 1 allowed) or a list of ``counts`` finite numbers."""
    def number(v: Any) -> bool:
        return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)

    if 1 in counts and number(value):
        return value
    if isinstance(value, list) and len(value) in counts and all(number(v) for v in value):
        return value
    shapes = " or ".join("one number" if n == 1 else f"a list of {n} numbers" for n in counts)
    raise FileFormatError(where, f"{key!r} must be {shapes} (finite), got {short_repr(value)}")


def _asymmetry(value: Any, where: str) -> tuple[float, float, float] | None:
    if value is None:
        return None
    if isinstance(value, dict):
        unknown = set(value) - {"shift", "weight"}
        if unknown:
            raise FileFormatError(where, f"'asymmetry' has unknown keys {sorted(unknown)}; "
                                         "allowed: ['shift', 'weight']")
        shift = _numbers(value.get("shift", [0.0, 0.0]), "asymmetry.shift", (2,), where)
        weight = _numbers(value.get("weight", 0.5), "asymmetry.weight", (1,), where)
        return float(shift[0]), float(shift[1]), float(weight)
    if not (isinstance(value, list) and len(value) == 3):  # name the documented table form, not only the list
        raise FileFormatError(where, "'asymmetry' must be a table {\"shift\": [x, y], \"weight\": w} "
                                     f"(or a list [shift_x, shift_y, weight]), got {short_repr(value)}")
    sx, sy, w = _numbers(value, "asymmetry", (3,), where)
    return float(sx), float(sy), float(w)


def analytic_from_dict(d: dict[str, Any], path: Path | None = None) -> AnalyticBRDF:
    """Build an :class:`AnalyticBRDF` from its description dictionary.

    Every key is type-checked (numbers finite, lists of the right length) before the
    parameters' ranges are (:class:`AnalyticBRDF`); errors name ``path``.

    Parameters
    ----------
    d
        ``{"type": "analytic", ...}`` with optional ``distribution`` (``"ggx"``, ``"beckmann"``),
        ``alpha`` (one or two numbers), ``rotation_deg`` (degrees), ``kd``, ``ks``, ``eta``
        (one or three numbers), ``asymmetry``, ``shadowing`` (``"separable"``, the default, or
        ``"height-correlated"``) and ``name``.
    path
        The file it was read from, for messages and :attr:`~reflecto.brdf.BRDFSource.path`.

    Returns
    -------
    AnalyticBRDF
        The BRDF.

    Raises
    ------
    FileFormatError
        For a missing ``type``, unknown keys, or values of the wrong type or range.
    """
    where = str(path) if path else "analytic description"
    if not isinstance(d, dict) or d.get("type") != "analytic":
        raise FileFormatError(where, "not an analytic BRDF description (needs \"type\": \"analytic\")")
    unknown = set(d) - _KEYS
    if unknown:
        raise FileFormatError(where, f"unknown keys {sorted(map(str, unknown))}; allowed: {sorted(_KEYS)}")
    distribution = d.get("distribution", "ggx")
    if not isinstance(distribution, str):
        raise FileFormatError(where, f"'distribution' must be one of {DISTRIBUTIONS}, got {short_repr(distribution)}")
    if "name" in d and not isinstance(d["name"], str):
        raise FileFormatError(where, f"'name' must be a string, got {short_repr(d['name'])}")
    alpha = _numbers(d.get("alpha", 0.2), "alpha", (1, 2), where)
    rotation = _numbers(d.get("rotation_deg", 0.0), "rotation_deg", (1,), where)
    kd = _numbers(d.get("kd", 0.0), "kd", (1, 3), where)
    ks = _numbers(d.get("ks", 1.0), "ks", (1, 3), where)
    eta = _numbers(d.get("eta", 1.5), "eta", (1, 3), where)
    asym = _asymmetry(d.get("asymmetry"), where)
    shadowing = d.get("shadowing", "separable")
    if shadowing not in SHADOWING_FORMS:
        raise FileFormatError(where, f"'shadowing' must be one of {list(SHADOWING_FORMS)}, got {short_repr(shadowing)}")
    try:
        return AnalyticBRDF(
            distribution=distribution.lower(),
            alpha=alpha,
            rotation_deg=float(rotation),
            kd=kd,
            ks=ks,
            eta=eta,
            asymmetry=asym,
            path=path,
            correlated=shadowing == "height-correlated",
        )
    except (ParameterError, TypeError, ValueError) as e:
        raise FileFormatError(where, str(e)) from None


def load_analytic(path: str | Path) -> AnalyticBRDF:
    """Read an analytic BRDF description (``.json`` or ``.toml``).

    Example (JSON)::

        {"type": "analytic", "distribution": "ggx", "alpha": [0.3, 0.1],
         "rotation_deg": 30, "kd": [0.2, 0.1, 0.05], "ks": 0.6, "eta": 1.5,
         "asymmetry": {"shift": [0.25, 0.0], "weight": 0.3}}

    Parameters
    ----------
    path
        The description file.

    Returns
    -------
    AnalyticBRDF
        The BRDF (:func:`analytic_from_dict`).

    Raises
    ------
    FileFormatError
        Naming the file, for unreadable or invalid descriptions.
    """
    path = Path(path)
    return analytic_from_dict(read_description(path), path)


register_reader(Reader("analytic", "a JSON/TOML description", (".json", ".toml"), (b"{",), load_analytic))
