"""Finding and configuring Mitsuba 3 (reference reader of ``.bsdf`` files, renderer).

:class:`MitsubaMeasured` evaluates a ``.bsdf`` file through Mitsuba's own ``measured``
plugin, as a BRDF source. Mitsuba's ``llvm_ad_rgb`` variant needs LLVM ≥ 16 (``DRJIT_LIBLLVM_PATH``); where none is
found we fall back to ``scalar_rgb``, which works everywhere.
"""

from __future__ import annotations

import glob
import math
import os
import re
from pathlib import Path
from types import ModuleType

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .brdf import BRDFSource

_LLVM_GLOBS = (
    "/usr/lib/*/libLLVM-[0-9]*.so*",
    "/usr/lib/*/libLLVM.so.[0-9]*",
    "/usr/lib/llvm-*/lib/libLLVM*.so*",
    "/usr/local/lib/libLLVM*.so*",
)


def find_libllvm(min_major: int = 16) -> str | None:
    """Path of the newest ``libLLVM`` shared library with major version ≥ ``min_major``."""
    env = os.environ.get("DRJIT_LIBLLVM_PATH")
    if env and os.path.exists(env):
        return env
    best: tuple[int, str] | None = None
    for pattern in _LLVM_GLOBS:
        for path in glob.glob(pattern):
            m = re.search(r"(?:LLVM-|LLVM\.so\.|llvm-)(\d+)", path)
            if m and int(m.group(1)) >= min_major and (best is None or int(m.group(1)) > best[0]):
                best = (int(m.group(1)), path)
    return best[1] if best else None


def import_mitsuba(prefer: str = "llvm_ad_rgb") -> tuple[ModuleType, str]:
    """Import Mitsuba and set a variant: ``prefer`` if usable, else ``scalar_rgb``.

    Raises ``ImportError`` if Mitsuba is not installed.
    """
    if prefer.startswith("llvm"):
        lib = find_libllvm()
        if lib:  # find_libllvm passes over a DRJIT_LIBLLVM_PATH naming no file: that one would not load
            os.environ["DRJIT_LIBLLVM_PATH"] = lib
    try:
        import mitsuba as mi  # deferred: DRJIT_LIBLLVM_PATH must be set before the import, and Mitsuba is optional
    except ImportError as e:  # not installed, or installed and broken: named so that callers can tell
        raise ImportError(str(e) or "mitsuba", name="mitsuba") from None

    for variant in (prefer, "scalar_rgb"):
        if variant.startswith("llvm") and not os.environ.get("DRJIT_LIBLLVM_PATH"):
            continue
        try:
            mi.set_variant(variant)
            if variant.startswith("llvm"):
                import drjit as dr  # deferred: with Mitsuba, after its variant is set

                dr.zeros(mi.Float, 4)  # force the JIT to load LLVM now
            return mi, variant
        except Exception:  # noqa: BLE001 - any failure means: try the next variant
            continue
    raise ImportError("no usable Mitsuba variant (tried llvm_ad_rgb and scalar_rgb)", name="mitsuba")


class MitsubaMeasured(BRDFSource):
    """An RGL ``.bsdf`` file evaluated by Mitsuba 3's own ``measured`` plugin.

    ``eval(i, o)`` in sr⁻¹, ``(N, 3)``, so that reflecto's metrics can compare what
    Mitsuba renders with a model: ``i`` is
    Mitsuba's ``si.wi``, ``o`` its ``wo``, and the plugin's ``f·cos θ_o`` is divided by
    ``cos θ_o``. Vectorised with an LLVM variant; one pair at a time with ``scalar_rgb``
    (slow: keep such inputs to a few thousand pairs).
    """

    kind = "mitsuba-measured"
    reciprocal = False

    def __init__(self, path: str | Path, prefer: str = "llvm_ad_rgb") -> None:
        self.mi, self.variant = import_mitsuba(prefer)
        self.path = Path(path)
        self.bsdf = self.mi.load_dict({"type": "measured", "filename": str(self.path)})
        # isotropic as the plugin evaluates the file: an anisotropic file's error is taken over
        # every half-vector azimuth (metrics.comparison_error), not at φ_h = 0 alone
        self.isotropic = self._turns_alike()

    def _turns_alike(self, pairs: int = 64) -> bool:
        """Whether ``f`` is unchanged when both directions turn about the normal (37° and 113°,
        ``pairs`` random direction pairs up to 80° from it; within 10⁻⁴ of the largest value):
        what an isotropic file's plugin gives exactly, its φ relative to the incidence's."""
        rng = np.random.default_rng(0)
        th = np.radians(rng.uniform(5.0, 80.0, (2, pairs)))
        ph = rng.uniform(0.0, 2 * np.pi, (2, pairs))

        def dirs(turn: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
            p = ph + math.radians(turn)
            d = np.stack([np.sin(th) * np.cos(p), np.sin(th) * np.sin(p), np.cos(th)], axis=-1)
            return d[0], d[1]

        base = self.eval(*dirs(0.0))
        scale = max(float(np.max(np.abs(base))), 1e-30)
        return all(float(np.max(np.abs(self.eval(*dirs(t)) - base))) <= 1e-4 * scale for t in (37.0, 113.0))

    def eval_cosine(self, i: ArrayLike, o: ArrayLike) -> NDArray[np.float64]:
        """Mitsuba's ``eval``: ``f(i, o)·cos θ_o``, shape ``(N, 3)``."""
        mi = self.mi
        i = np.ascontiguousarray(np.asarray(i, dtype=np.float64).reshape(-1, 3))
        o = np.ascontiguousarray(np.asarray(o, dtype=np.float64).reshape(-1, 3))
        ctx = mi.BSDFContext()
        if not self.variant.startswith("scalar"):
            si = mi.SurfaceInteraction3f()
            si.wi = mi.Vector3f(i[:, 0], i[:, 1], i[:, 2])
            v = self.bsdf.eval(ctx, si, mi.Vector3f(o[:, 0], o[:, 1], o[:, 2]))
            return np.array(v, dtype=np.float64).reshape(3, -1).T
        out = np.empty((len(i), 3))
        for k in range(len(i)):
            si = mi.SurfaceInteraction3f()
            si.wi = mi.Vector3f(*i[k])
            out[k] = np.array(self.bsdf.eval(ctx, si, mi.Vector3f(*o[k])), dtype=np.float64)
        return out

    def eval(self, i: ArrayLike, o: ArrayLike) -> NDArray[np.float64]:
        """BRDF in sr⁻¹, ``(N, 3)``; 0 where either direction is below the horizon."""
        o2 = np.asarray(o, dtype=np.float64).reshape(-1, 3)
        v = self.eval_cosine(i, o2)
        cos_o = o2[:, 2:3]
        return np.divide(v, cos_o, out=np.zeros_like(v), where=cos_o > 0)
