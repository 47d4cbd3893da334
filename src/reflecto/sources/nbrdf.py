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

import io
import math
from pathlib import Path
from typing import Any

import h5py
import numpy as np
from numpy.typing import ArrayLike, NDArray

from .. import geometry
from ..brdf import BRDFSource, Reader, check_plausible, register_reader
from ..errors import FileFormatError, short_repr
from ..io import MAX_BRDF_BYTES, MAX_DESCRIPTION_BYTES, parse_json, read_input

Array = NDArray[np.float64]

LAYERS = (("dense_1", 6, 21), ("dense_2", 21, 21), ("dense_3", 21, 3))


def _dataset(path: Path, f: Any, name: str, shape: tuple[int, ...]) -> Array:
    """Dataset ``name`` of the open file ``f`` as float64, checked before it is read.

    Only hard links to plain float datasets stored in the file itself: an external
    or soft link, external raw storage or a virtual dataset would read other files,
    and the shape is checked before reading, so that a huge (even lazily allocated)
    dataset is refused without allocating it.
    """

    link = f.get(name, getlink=True)
    if link is None:
        raise KeyError(name)
    if not isinstance(link, h5py.HardLink):
        raise FileFormatError(path, f"{name!r} is a {type(link).__name__}: only data stored in the file itself is read")
    ds = f[name]
    if not isinstance(ds, h5py.Dataset):
        raise FileFormatError(path, f"{name!r} is not a dataset")
    if ds.is_virtual or ds.id.get_create_plist().get_external_count() > 0:
        raise FileFormatError(path, f"{name!r} refers to data in other files")
    if ds.dtype.kind != "f":
        raise FileFormatError(path, f"{name!r} holds {ds.dtype} values, expected floating point")
    if ds.shape != shape:
        raise FileFormatError(path, f"{name!r} has shape {ds.shape}, expected {shape}")
    return np.asarray(ds[()], dtype=np.float64)


def _read_weights(path: Path) -> list[tuple[Array, Array]]:
    raw = read_input(path, MAX_BRDF_BYTES, "an NBRDF weights file")
    try:
        f = h5py.File(io.BytesIO(raw), "r")
    except MemoryError:
        raise
    except Exception as e:  # noqa: BLE001 — h5py raises OSError, ValueError, ... on damaged files
        raise FileFormatError(path, f"not a readable HDF5 file ({type(e).__name__}: {e})") from None
    layers = []
    try:
        with f:
            for name, n_in, n_out in LAYERS:
                if f.get(name, getlink=True) is None:
                    raise FileFormatError(path, f"missing layer {name!r} (expected layers {[n for n, _, _ in LAYERS]})")
                base = f"{name}/{name}" if f.get(f"{name}/{name}", getlink=True) is not None else name
                try:
                    kernel = _dataset(path, f, f"{base}/kernel:0", (n_in, n_out))
                    bias = _dataset(path, f, f"{base}/bias:0", (n_out,))
                except KeyError:
                    raise FileFormatError(path, f"layer {name!r} lacks kernel:0 or bias:0") from None
                if not (np.all(np.isfinite(kernel)) and np.all(np.isfinite(bias))):
                    raise FileFormatError(path, f"layer {name!r} contains NaN or infinite weights")
                layers.append((kernel, bias))
    except (FileFormatError, MemoryError):
        raise
    except Exception as e:  # noqa: BLE001 — damaged object headers surface as many h5py error types
        raise FileFormatError(path, f"damaged HDF5 file ({type(e).__name__}: {e})") from None
    return layers


def _check_architecture(path: Path) -> None:
    if not path.exists() and not path.is_symlink():
        return
    d = parse_json(read_input(path, MAX_DESCRIPTION_BYTES, "an NBRDF architecture file"), path)
    try:
        layers = d["config"]["layers"]
        dense = [(l["config"]["units"], l["config"]["activation"]) for l in layers if l["class_name"] == "Dense"]
    except (KeyError, TypeError, AttributeError) as e:
        raise FileFormatError(path, f"not a Keras architecture file (missing or invalid {e})") from None
    if dense != [(21, "relu"), (21, "relu"), (3, "linear")]:
        raise FileFormatError(path, f"unexpected NBRDF architecture {short_repr(dense)}; "
                                    "expected 6→21 relu→21 relu→3 linear")


class NBRDF(BRDFSource):
    """A neural BRDF (NBRDF) fit of a MERL material, evaluated in NumPy."""

    kind = "nbrdf"

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        _check_architecture(self.path.with_suffix(".json"))
        self.layers = _read_weights(self.path)
        self.reciprocal = True
        self.isotropic = True
        check_plausible(self, self.path)

    def eval(self, i: ArrayLike, o: ArrayLike) -> Array:
        """The neural BRDF: a 6-21-21-3 ReLU network of ``(h, d)`` (Rusinkiewicz half and
        difference vectors, ``φ_d`` mod π), output ``max(0, exp(y) − 1)``, sr⁻¹.

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
        """The network's shape and number of weights, for ``reflecto info``.

        Returns
        -------
        dict
            ``network`` (the architecture in words) and ``weights`` (their number).
        """
        return {"network": "6-21-21-3 (ReLU, exp(x)-1)", "weights": sum(k.size + b.size for k, b in self.layers)}


register_reader(Reader("nbrdf", "an NBRDF fit (.h5)", (".h5",), (b"\x89HDF",), NBRDF))
