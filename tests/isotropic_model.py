"""A microfacet BRDF with a 1-D NDF ``D(θ_h)``, as the reconstruction writes for isotropic
materials: a test source that has only the public interface (``eval``, ``ndf``,
``isotropic``, ``kd``, ``ks``, ``eta``), no hemicube.

``f = k_d/π + k_s D(θ_h) F(i·h; η) / (4 σ(i) σ(o))`` (eqs. 1–2 in the cancelled form of
algorithm-reference eq. 1.6), with ``D`` interpolated linearly in θ_h between table
nodes (so it has kinks at the nodes, like any tabulated NDF) and
``σ(k) = max(∫ D ⟨k·h⟩ dω, cos θ_k)`` integrated numerically (eq. 8).
"""

from __future__ import annotations

import math

import numpy as np

from reflecto.brdf import BRDFSource
from reflecto.fresnel import fresnel


class TabulatedIsotropic(BRDFSource):
    """Isotropic microfacet BRDF with ``D`` tabulated at ``theta`` (radians, increasing from 0).

    ``d`` is normalized here (``∫ D cos θ dω = 1``); ``kd``, ``ks``, ``eta`` are RGB.
    """

    kind = "model"

    def __init__(self, theta, d, kd, ks, eta, name: str = "tabulated") -> None:
        self.theta = np.asarray(theta, dtype=np.float64)
        d = np.maximum(np.asarray(d, dtype=np.float64), 0.0)
        self.kd, self.ks, self.eta = (np.broadcast_to(np.asarray(v, dtype=np.float64), (3,)).copy()
                                      for v in (kd, ks, eta))
        # normalization and σ on a fine polar grid (midpoint rule in u, θ = π/2·u²)
        u = (np.arange(2048) + 0.5) / 2048
        th = 0.5 * math.pi * u * u
        dw = np.sin(th) * math.pi * u / 2048 * 2 * math.pi  # dω per ring
        dd = np.interp(th, self.theta, d, right=0.0)
        self.d = d / float(np.sum(dd * np.cos(th) * dw))
        dd = np.interp(th, self.theta, self.d, right=0.0)
        self.sigma_theta = np.linspace(0.0, 0.5 * math.pi, 181)
        az = (np.arange(128) + 0.5) / 128 * 2 * math.pi
        sig = []
        for t in self.sigma_theta:
            # ring integral of max(k·h, 0) over azimuth, per ring, times D and dω
            kh = np.cos(t) * np.cos(th)[:, None] + np.sin(t) * np.sin(th)[:, None] * np.cos(az)[None, :]
            sig.append(float(np.sum(np.maximum(kh, 0.0).mean(axis=1) * dd * dw)))
        self.sigma = np.maximum(np.array(sig), np.cos(self.sigma_theta))
        self.isotropic = True
        self.reciprocal = True
        self._name = name

    @classmethod
    def ring_mean_of(cls, model, n: int = 2048) -> TabulatedIsotropic:
        """The azimuthal mean of a model's NDF on ``n`` θ_h nodes (denser near the pole), with its k_d, k_s, η."""
        theta = 0.5 * math.pi * np.linspace(0.0, 1.0, n) ** 2
        az = (np.arange(64) + 0.5) / 64 * 2 * math.pi
        h = np.stack(np.broadcast_arrays(np.sin(theta)[None] * np.cos(az)[:, None],
                                         np.sin(theta)[None] * np.sin(az)[:, None], np.cos(theta)[None]), -1)
        d = model.ndf(h.reshape(-1, 3)).reshape(64, n).mean(axis=0)
        return cls(theta, d, model.kd, model.ks, model.eta, name=model.name)

    @property
    def name(self) -> str:
        return self._name

    def ndf(self, h) -> np.ndarray:
        h = np.asarray(h, dtype=np.float64)
        z = np.clip(h[..., 2], -1.0, 1.0)
        return np.where(z > 0, np.interp(np.arccos(z), self.theta, self.d, right=0.0), 0.0)

    def _sigma(self, k: np.ndarray) -> np.ndarray:
        return np.interp(np.arccos(np.clip(k[..., 2], -1.0, 1.0)), self.sigma_theta, self.sigma)

    def eval(self, i, o) -> np.ndarray:
        i = np.asarray(i, dtype=np.float64)
        o = np.asarray(o, dtype=np.float64)
        hs = i + o
        h = hs / np.maximum(np.linalg.norm(hs, axis=-1, keepdims=True), 1e-300)
        c = np.abs(np.sum(i * h, axis=-1))
        spec = self.ndf(h) / (4.0 * self._sigma(i) * self._sigma(o))
        f = self.kd / math.pi + self.ks * fresnel(c[..., None], self.eta) * spec[..., None]
        ok = (i[..., 2] > 0) & (o[..., 2] > 0)
        return np.where(ok[..., None], f, 0.0)
