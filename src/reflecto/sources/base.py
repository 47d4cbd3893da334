"""The common interface of every BRDF source, and quantities derived from it."""

from __future__ import annotations

import abc
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .. import geometry
from ..errors import FileFormatError, ParameterError

Array = NDArray[np.float64]


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
            Unit directions, shape ``(N, 3)`` (or broadcastable ``(..., 3)``).

        Returns
        -------
        ndarray, shape ``(N, 3)``
            Linear RGB BRDF; 0 where either direction is below the horizon.
        """

    def parameters(self) -> dict[str, Any]:
        """Human-readable parameters for ``reflecto info``."""
        return {}

    @property
    def name(self) -> str:
        return self.path.stem if self.path is not None else self.kind

    def albedo(self, theta_i_deg: ArrayLike, phi_i_deg: float = 0.0, **kw: Any) -> Array:
        """Directional albedo ``a(i) = ∫ f(i, o) cos θ_o dω_o`` (dimensionless), shape ``(K, 3)``."""
        return directional_albedo(self, theta_i_deg, phi_i_deg, **kw)


def _eval_chunked(source: BRDFSource, i: Array, o: Array, chunk: int = 1 << 18) -> Array:
    out = np.empty(i.shape[:-1] + (3,))
    fi, fo, fout = i.reshape(-1, 3), o.reshape(-1, 3), out.reshape(-1, 3)
    for s in range(0, len(fi), chunk):
        fout[s : s + chunk] = source.eval(fi[s : s + chunk], fo[s : s + chunk])
    return out


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
    theta_i_deg
        Incident polar angles in degrees, shape ``(K,)``.
    phi_i_deg
        Incident azimuth in degrees.

    Returns
    -------
    ndarray, shape ``(K, 3)``
    """
    theta_i = np.radians(np.atleast_1d(np.asarray(theta_i_deg, dtype=np.float64)))
    u = (np.arange(n_u) + 0.5) / n_u
    th = u * u * (0.5 * np.pi)
    ph = (np.arange(n_phi) + 0.5) * (2.0 * np.pi / n_phi)
    h = geometry.spherical_to_cartesian(th[:, None], ph[None, :]).reshape(-1, 3)
    dw = (np.sin(th) * (np.pi * u / n_u))[:, None] * np.full(n_phi, 2.0 * np.pi / n_phi)[None, :]
    dw = dw.ravel()
    out = np.empty((len(theta_i), 3))
    for k, t in enumerate(theta_i):
        i = geometry.spherical_to_cartesian(t, np.radians(phi_i_deg))
        idoth = h @ i
        o = 2.0 * idoth[:, None] * h - i
        ok = (idoth > 0) & (o[:, 2] > 0)
        f = _eval_chunked(source, np.broadcast_to(i, o[ok].shape).copy(), o[ok])
        w = (o[ok, 2] * 4.0 * idoth[ok] * dw[ok])[:, None]
        out[k] = np.sum(f * w, axis=0)
    return out


def valid_pairs(i: Array, o: Array) -> NDArray[np.bool_]:
    """Mask of pairs with both directions strictly above the horizon."""
    return (i[..., 2] > 0) & (o[..., 2] > 0)


def rgb_triplet(value: Any, name: str) -> Array:
    """One number or three (RGB) → finite array of shape ``(3,)``; ParameterError otherwise."""
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim == 0:
        arr = np.full(3, float(arr))
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise ParameterError(f"{name} must be one or three finite numbers (RGB), got {value!r}")
    return arr


def read_file_bytes(path: Path) -> bytes:
    """Whole file contents; FileFormatError naming the file if it cannot be read."""
    try:
        return path.read_bytes()
    except FileNotFoundError:
        raise FileFormatError(path, "no such file") from None
    except OSError as e:
        raise FileFormatError(path, f"cannot read: {e.strerror}") from None
