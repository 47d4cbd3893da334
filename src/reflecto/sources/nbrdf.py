"""Neural BRDF fits (Sztrajman et al. 2021) of MERL materials: ``.h5`` weights + ``.json``.

Network (``../shared/data/merl-nbrdf/PROVENANCE.md``): Dense 6→21 (ReLU) → 21 (ReLU)
→ 3 (linear), then ``exp(x) − 1``; kernels stored (in, out). Input
``(h_x, h_y, h_z, d_x, d_y, d_z)``: the half vector with φ_h = 0,
``(sin θ_h, 0, cos θ_h)``, and the difference vector
``(sin θ_d cos φ_d, sin θ_d sin φ_d, cos θ_d)``. Output: RGB BRDF in sr⁻¹.

φ_d is folded into [0, π) as in MERL's tables (which the networks were fitted to);
this also makes the evaluation exactly reciprocal.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .. import geometry
from ..errors import FileFormatError
from .base import BRDFSource

Array = NDArray[np.float64]

LAYERS = (("dense_1", 6, 21), ("dense_2", 21, 21), ("dense_3", 21, 3))


def _read_weights(path: Path) -> list[tuple[Array, Array]]:
    import h5py

    try:
        f = h5py.File(path, "r")
    except FileNotFoundError:
        raise FileFormatError(path, "no such file") from None
    except OSError as e:
        raise FileFormatError(path, f"not a readable HDF5 file ({e})") from None
    layers = []
    with f:
        for name, n_in, n_out in LAYERS:
            grp = f.get(name)
            if grp is None:
                raise FileFormatError(path, f"missing layer {name!r} (expected layers {[n for n, _, _ in LAYERS]})")
            sub = grp.get(name, grp)
            try:
                kernel = np.asarray(sub["kernel:0"], dtype=np.float64)
                bias = np.asarray(sub["bias:0"], dtype=np.float64)
            except KeyError:
                raise FileFormatError(path, f"layer {name!r} lacks kernel:0 or bias:0") from None
            if kernel.shape != (n_in, n_out) or bias.shape != (n_out,):
                raise FileFormatError(
                    path, f"layer {name!r} has kernel {kernel.shape} and bias {bias.shape}, expected ({n_in}, {n_out}) and ({n_out},)"
                )
            if not (np.all(np.isfinite(kernel)) and np.all(np.isfinite(bias))):
                raise FileFormatError(path, f"layer {name!r} contains NaN or infinite weights")
            layers.append((kernel, bias))
    return layers


def _check_architecture(path: Path) -> None:
    try:
        d = json.loads(path.read_text(encoding="utf-8"))
        layers = d["config"]["layers"]
        dense = [(l["config"]["units"], l["config"]["activation"]) for l in layers if l["class_name"] == "Dense"]
    except FileNotFoundError:
        return
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, KeyError, TypeError) as e:
        raise FileFormatError(path, f"not a Keras architecture file ({e})") from None
    if dense != [(21, "relu"), (21, "relu"), (3, "linear")]:
        raise FileFormatError(path, f"unexpected NBRDF architecture {dense}; expected 6→21 relu→21 relu→3 linear")


class NBRDF(BRDFSource):
    """A neural BRDF (NBRDF) fit of a MERL material, evaluated in NumPy."""

    kind = "nbrdf"

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        _check_architecture(self.path.with_suffix(".json"))
        self.layers = _read_weights(self.path)
        self.reciprocal = True
        self.isotropic = True

    def eval(self, i: ArrayLike, o: ArrayLike) -> Array:
        i = np.asarray(i, dtype=np.float64)
        o = np.asarray(o, dtype=np.float64)
        th, _, td, pd = geometry.io_to_hd(i, o)
        pd = np.mod(pd, math.pi)
        std = np.sin(td)
        x = np.stack([np.sin(th), np.zeros_like(th), np.cos(th), std * np.cos(pd), std * np.sin(pd), np.cos(td)], -1)
        (k1, b1), (k2, b2), (k3, b3) = self.layers
        x = np.maximum(x @ k1 + b1, 0.0)
        x = np.maximum(x @ k2 + b2, 0.0)
        y = np.expm1(x @ k3 + b3)
        ok = (i[..., 2] > 0) & (o[..., 2] > 0)
        return np.where(ok[..., None], np.maximum(y, 0.0), 0.0)

    def parameters(self) -> dict[str, Any]:
        return {"network": "6-21-21-3 (ReLU, exp(x)-1)", "weights": sum(k.size + b.size for k, b in self.layers)}
