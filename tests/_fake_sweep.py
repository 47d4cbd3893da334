"""A stand-in for the sweep's minutes-long per-material evaluation, shared by the batch
tests and the fuzz campaign: the real loader, then a synthetic record.

Module-level, so that worker processes unpickle it by name.
"""

from __future__ import annotations

import importlib
import json
from pathlib import Path

import numpy as np


def fake_run_material(path: str, out_dir: str, device: str = "ideal", calibration: str | None = None) -> dict:
    """Load ``path`` as the sweep would and write a synthetic record of it into ``out_dir``."""
    from reflecto.evaluate.split import half
    from reflecto.io import atomic_write
    from reflecto.load import load_source

    sw = importlib.import_module("reflecto.evaluate.sweep")  # the module, not the re-exported function
    src = load_source(path)
    name = Path(path).stem
    a = float(np.clip(src.albedo([0.0])[0, 1], 1e-3, 1.0))
    img = np.full((sw.SPHERE_RES, sw.SPHERE_RES, 3), 0.1).tolist()
    from reflecto.workflow import device_key

    rec = {"name": name, "file": path, "material_digest": sw.material_digest(path), "device": device,
           "device_key": device_key(device), "seed": sw.material_seed(name),
           "timings": {"total_s": 0.01, "ours_reconstruct_s": 0.01, "cook_torrance_fit_s": 0.01},
           "ours": {"error": a, "log_rmse": 0.1, "eta": [1.5, 1.5, 1.5], "ks": [0.5, 0.5, 0.5], "albedo_max": a,
                    "finite": True, "isotropic": True},
           "earlier": {"error": 2 * a, "log_rmse": 0.2}, "cook_torrance": {"error": 1.5 * a, "log_rmse": 0.1},
           "same_data_ct": {"error": 1.2 * a, "log_rmse": 0.1}, "half": half(name),
           "renders": {k: img for k in ("reference", "ours", "earlier", "cook_torrance")}, "albedo_ref": a}
    with atomic_write(Path(out_dir) / "materials" / f"{name}.json", "w") as fh:
        fh.write(json.dumps(rec))
    return rec
