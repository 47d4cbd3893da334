"""Fresnel reflectance of an unpolarized wave at a dielectric interface.

Eq. 4 of Lan et al. 2010, after Cook & Torrance 1982 (algorithm-reference §2.1)::

    F(c; η) = (g − c)² / (2 (g + c)²) · [1 + (c(g + c) − 1)² / (c(g − c) + 1)²],
    g = √(η² + c² − 1),   c = |o·h| = cos θ_d.

``F(1) = ((η − 1)/(η + 1))² = F0``, ``F(0) = 1``. Where ``g²`` would be negative
(η < 1, total internal reflection) ``F = 1``.

``η = ∞`` (:data:`CONSTANT`) is the limit of eq. 4 for a perfect conductor, ``F ≡ 1``:
the *constant Fresnel* lobe, the reconstruction's explicit answer for data whose
specular level does not rise toward grazing as any dielectric's does (metallic paints,
the sheen of fabrics). Files and JSON carry it as ``"fresnel": "constant"`` with no η
(:func:`eta_to_json`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import _kernels
from .errors import ParameterError

Array = NDArray[np.float64]


def fresnel(c: ArrayLike, eta: ArrayLike) -> Array:
    """Unpolarized dielectric Fresnel reflectance, eq. 4 (dimensionless, in [0, 1]).

    Parameters
    ----------
    c
        ``cos θ_d = |i·h|``; its absolute value is used. Any shape.
    eta
        Relative index of refraction η > 0; broadcast against ``c`` (e.g. shape ``(3,)``
        against ``c[..., None]`` for per-channel η).

    Returns
    -------
    ndarray
        ``F(c; η)`` in [0, 1], of the broadcast shape of ``c`` and ``eta`` (a NumPy scalar
        for scalar input); 1 under total internal reflection (``g² ≤ 0``) and for ``η = ∞``.
    """
    c = np.asarray(c, dtype=np.float64)
    eta = np.asarray(eta, dtype=np.float64)
    shape = np.broadcast_shapes(c.shape, eta.shape)
    cb = np.ascontiguousarray(np.broadcast_to(c, shape)).ravel()
    eb = np.ascontiguousarray(np.broadcast_to(eta, shape)).ravel()
    out = np.empty(cb.size)
    _kernels.fresnel_flat(cb, eb, out)
    return out.reshape(shape)[()]  # a NumPy scalar for scalar input, as NumPy's ufuncs give


def fresnel_numpy(c: ArrayLike, eta: ArrayLike) -> Array:
    """NumPy reference of :func:`fresnel` (the compiled loop does the same arithmetic).

    Parameters
    ----------
    c : array_like
        ``cos θ_d``; its absolute value is used.
    eta : array_like
        Relative index η; broadcast against ``c``.

    Returns
    -------
    ndarray
        Eq. 4's ``F(c; η)`` clipped to [0, 1]; 1 where ``g² ≤ 0`` or the formula is not finite.
    """
    c = np.abs(np.asarray(c, dtype=np.float64))
    eta = np.asarray(eta, dtype=np.float64)
    g2 = eta * eta + c * c - 1.0
    tir = g2 <= 0.0
    g = np.sqrt(np.maximum(g2, 0.0))
    gpc = g + c
    gmc = g - c
    with np.errstate(divide="ignore", invalid="ignore"):
        a = gmc * gmc / (2.0 * gpc * gpc)
        num = c * gpc - 1.0
        den = c * gmc + 1.0
        f = a * (1.0 + num * num / (den * den))
    f = np.where(tir | ~np.isfinite(f), 1.0, f)
    return np.clip(f, 0.0, 1.0)


#: The relative index of the constant Fresnel lobe, ``F ≡ 1`` (module docstring).
CONSTANT = math.inf


def is_constant(eta: ArrayLike | None) -> bool:
    """Whether ``eta`` is the constant Fresnel lobe ``η = ∞`` (:data:`CONSTANT`).

    Parameters
    ----------
    eta
        A scalar or an RGB triplet; ``None`` (no η) is not constant.

    Returns
    -------
    bool
        True when every entry is +∞.
    """
    return bool(np.all(np.isposinf(np.asarray(eta, dtype=np.float64))))


def eta_to_json(eta: ArrayLike) -> dict[str, Any]:
    """η as JSON fields (JSON has no infinity).

    Parameters
    ----------
    eta
        One η or an RGB triplet, or :data:`CONSTANT`.

    Returns
    -------
    dict
        ``{"fresnel": "dielectric", "eta": [R, G, B]}``, or ``{"fresnel": "constant",
        "eta": None}`` for :data:`CONSTANT`.
    """
    if is_constant(eta):
        return {"fresnel": "constant", "eta": None}
    return {"fresnel": "dielectric", "eta": np.broadcast_to(np.asarray(eta, dtype=np.float64), (3,)).tolist()}


def eta_from_json(record: dict[str, Any]) -> Array | None:
    """Inverse of :func:`eta_to_json`.

    Parameters
    ----------
    record
        A JSON object with ``"fresnel"`` and ``"eta"`` fields.

    Returns
    -------
    ndarray, shape (3,), or None
        η as three floats (∞ for the constant lobe); ``None`` when the record holds
        neither form (``eta`` not three finite numbers).
    """
    if record.get("fresnel") == "constant" and record.get("eta") is None:
        return np.full(3, CONSTANT)
    v = record.get("eta")
    ok = isinstance(v, list) and len(v) == 3 and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                      and math.isfinite(x) for x in v)
    return np.asarray(v, dtype=np.float64) if ok else None


def format_eta(eta: ArrayLike | None) -> str:
    """η for a summary line.

    Parameters
    ----------
    eta
        One η or an RGB triplet; ``None`` for a record without η (:func:`eta_from_json`).

    Returns
    -------
    str
        ``"1.500"`` (one η serves R, G, B: the first channel's), ``"∞ (constant Fresnel)"``,
        or ``"nan"`` for ``None``.
    """
    if is_constant(eta):
        return "∞ (constant Fresnel)"
    return f"{float(np.ravel(np.asarray(eta, dtype=np.float64))[0]):.3f}"


def f0_from_eta(eta: ArrayLike) -> Array:
    """Normal-incidence reflectance ``F0 = F(1; η) = ((η − 1)/(η + 1))²`` (algorithm-reference §2.1).

    Parameters
    ----------
    eta : array_like
        Relative index η.

    Returns
    -------
    ndarray
        F0 (dimensionless), of the shape of ``eta``; 1 for ``η = ∞``.
    """
    eta = np.asarray(eta, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        return np.where(np.isposinf(eta), 1.0, ((eta - 1.0) / (eta + 1.0)) ** 2)[()]


def eta_from_f0(f0: ArrayLike) -> Array:
    """Inverse of :func:`f0_from_eta` on η ≥ 1: ``η = (1 + √F0)/(1 − √F0)``.

    Parameters
    ----------
    f0 : array_like
        Normal-incidence reflectance, clipped to ``[0, 1 − 10⁻¹²]``.

    Returns
    -------
    ndarray
        η ≥ 1, of the shape of ``f0``.
    """
    s = np.sqrt(np.clip(np.asarray(f0, dtype=np.float64), 0.0, 1.0 - 1e-12))
    return (1.0 + s) / (1.0 - s)


def schlick(c: ArrayLike, f0: ArrayLike) -> Array:
    """Schlick's approximation ``F0 + (1 − F0)(1 − c)⁵`` (used by the Cook–Torrance baseline).

    Parameters
    ----------
    c : array_like
        ``cos θ_d``; its absolute value is used.
    f0 : array_like
        Normal-incidence reflectance; broadcast against ``c``.

    Returns
    -------
    ndarray
        F (dimensionless), of the broadcast shape.
    """
    c = np.abs(np.asarray(c, dtype=np.float64))
    f0 = np.asarray(f0, dtype=np.float64)
    return f0 + (1.0 - f0) * (1.0 - c) ** 5


#: Largest factor of a :class:`FresnelTint`: above ``1/F0`` of η = 1.001 (4.004·10⁶), the smallest η fitted.
MAX_TINT = 4.1e6


class FresnelTint:
    """A per-channel factor ``τ_c(θ_d) ≥ 0`` on the Fresnel term: ``F_c = min(1, τ_c(θ_d) F(cos θ_d; η))``.

    The colour of a specular reflection that changes with angle in a way one η's curve
    cannot (a metallic or colour-shifting paint, a coloured metal). ``τ`` is linear in
    ``θ_d`` between its nodes and constant below the first. Beyond the last node
    (``θ_K``, the largest ``θ_d`` at which the device saw the mirror direction) it is

    - ``"constant"``: ``τ_K``, so the Fresnel curve keeps η's shape (eq. 4);
    - ``"trend"``: ``τ_K`` up to ``θ_T = trend_from`` (≥ ``θ_K``: where the data that
      fitted the tint end), then the departure from η's curve that the nodes measure,
      continued log-linearly in ``cos θ_d``: ``τ_c(θ_d) = τ_{c,K} r_c^u`` with
      ``r_c = τ_{c,K}/τ_{c,1}`` (1 where either is 0) and
      ``u = min(1, (cos θ_T − cos θ_d)/(cos θ_1 − cos θ_K))``: no further than the nodes'
      own span, so at most the change from the first node to the last once more (at
      ``θ_d = 90°`` on the paper's layout, nodes ≈ 38° and 67°: ``u`` ≈ 0.97); at most
      :data:`MAX_TINT`.

    The product is clipped at 1 (:class:`FresnelTable`): a reflectance.

    Parameters
    ----------
    theta
        The nodes ``θ_d`` (radians), increasing, in ``[0, π/2]``; shape ``(K,)``, ``K ≥ 2``.
    values
        ``τ`` at the nodes, shape ``(K, 3)``, each ≥ 0.
    beyond
        ``"constant"`` or ``"trend"`` (above).
    trend_from
        ``θ_T`` (radians) in ``[θ_K, π/2]``; ``None``: ``θ_K``. Only with ``"trend"``.
    """

    #: How ``τ`` continues beyond the last node.
    BEYOND = ("constant", "trend")

    def __init__(self, theta: ArrayLike, values: ArrayLike, beyond: str = "constant",
                 trend_from: float | None = None) -> None:
        self.theta = np.asarray(theta, dtype=np.float64)
        self.values = np.asarray(values, dtype=np.float64)
        if beyond not in self.BEYOND:
            raise ParameterError(f"the Fresnel tint's continuation must be one of {self.BEYOND}, got {beyond!r}")
        self.beyond = beyond
        if trend_from is not None and beyond != "trend":
            raise ParameterError("a Fresnel tint's trend_from needs beyond='trend'")
        self.trend_from = None if trend_from is None else float(trend_from)
        if (self.theta.ndim != 1 or len(self.theta) < 2 or self.values.shape != (len(self.theta), 3)
                or not np.all(np.isfinite(self.theta)) or not np.all(np.isfinite(self.values))):
            raise ParameterError("a Fresnel tint needs K >= 2 finite nodes and a (K, 3) table of finite values")
        if np.any(np.diff(self.theta) <= 0) or self.theta[0] < 0 or self.theta[-1] > math.pi / 2 + 1e-12:
            raise ParameterError("the Fresnel tint's nodes must increase within [0, pi/2]")
        if np.any(self.values < 0) or np.any(self.values > MAX_TINT):
            raise ParameterError(f"the Fresnel tint's values must lie in [0, {MAX_TINT:g}]")
        if self.trend_from is not None and not self.theta[-1] <= self.trend_from <= math.pi / 2 + 1e-12:
            raise ParameterError("the Fresnel tint's trend_from must lie between its last node and pi/2")

    def angles_deg(self) -> list[float]:
        """The nodes and the midpoints between them: where the tinted specular level can peak.

        Returns
        -------
        list of float
            The angles ``θ_d`` in degrees, sorted.
        """
        t = np.degrees(self.theta)
        return sorted({*t.tolist(), *(0.5 * (t[1:] + t[:-1])).tolist()})

    def __call__(self, c: ArrayLike) -> Array:
        """``τ`` at ``θ_d = arccos |c|``.

        Parameters
        ----------
        c : array_like
            ``cos θ_d``; any shape.

        Returns
        -------
        ndarray, shape ``c.shape + (3,)``
            The tint per RGB channel.
        """
        c = np.minimum(np.abs(np.asarray(c, dtype=np.float64)), 1.0)
        th = np.arccos(c)
        tau = np.stack([np.interp(th, self.theta, self.values[:, k]) for k in range(3)], axis=-1)
        if self.beyond == "trend":
            tau = np.minimum(tau * self._trend(c), MAX_TINT)
        return tau

    def _trend(self, c: Array) -> Array:
        """``r_c^u`` beyond ``θ_T`` (``u`` at most 1), 1 elsewhere; shape ``c.shape + (3,)``."""
        first, last = self.values[0], self.values[-1]
        ok = (first > 0) & (last > 0)
        log_r = np.where(ok, np.log(np.where(ok, last, 1.0)) - np.log(np.where(ok, first, 1.0)), 0.0)
        span = math.cos(self.theta[0]) - math.cos(self.theta[-1])
        if not span > 1e-9:  # nodes too close to measure a trend between them
            return np.ones(np.shape(c) + (3,))
        start = math.cos(self.theta[-1] if self.trend_from is None else self.trend_from)
        u = np.minimum(np.maximum(start - c, 0.0) / span, 1.0)
        return np.where(u[..., None] > 0, np.exp(u[..., None] * log_r), 1.0)


class FresnelTable:
    """Per-channel ``F(c; η)`` (times a :class:`FresnelTint` when given) tabulated on
    ``c ∈ [0, 1]`` for fast repeated evaluation.

    Linear interpolation on 4097 nodes spaced uniformly in √c (dense near grazing,
    where F rises steeply for large η); the error against :func:`fresnel` is below
    1e-5 for η ∈ [1.01, 100] (tested). A tint is resolved to the table's cells: 0.04° at
    θ_d = 38°, 1.8° at normal incidence (a tint varying within 2° of θ_d = 0 is smoothed).
    """

    def __init__(self, eta: ArrayLike, n: int = 4097, tint: FresnelTint | None = None) -> None:
        self.eta = np.atleast_1d(np.asarray(eta, dtype=np.float64))
        self.n = n
        c = np.linspace(0.0, 1.0, n) ** 2
        table = fresnel(c[:, None], self.eta[None, :])
        if tint is not None:
            table = np.minimum(table * tint(c), 1.0)
        self.table = np.concatenate([table, table[-1:]], axis=0)  # guard row for c = 1

    def __call__(self, c: ArrayLike) -> Array:
        """``F`` at ``|c|`` by linear interpolation in the table.

        Parameters
        ----------
        c : array_like
            ``cos θ_d``; absolute value used, clipped to 1.

        Returns
        -------
        ndarray, shape ``c.shape + (channels,)``
            F per channel of ``eta``.
        """
        x = np.sqrt(np.minimum(np.abs(np.asarray(c, dtype=np.float64)), 1.0)) * (self.n - 1)
        k = x.astype(np.intp)
        w = (x - k)[..., None]
        lo = self.table[k]
        return lo + w * (self.table[k + 1] - lo)
