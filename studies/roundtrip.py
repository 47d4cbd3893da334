"""Everything reflecto writes, reflecto reads: the 50 shared reconstructions, each as its
model file, RGL ``.bsdf`` export, MERL ``.binary`` tabulation and reconstruction summary,
and a calibration file, each read back by reflecto's own readers.

For every file: read back (``load_source``, ``Calibration.load``, ``read_json``), its
kind as :func:`reflecto.kinds.identify` names it, and for the BRDF files the largest
``f`` and ``f·cos θ_i·cos θ_o`` over the MERL bins (the physical bound,
:data:`reflecto.brdf.MAX_PROJECTED_BRDF`, docs/limits.md). Prints one line per
material and the totals; exit status 1 if any file was refused.

Run: ``.venv/bin/python studies/roundtrip.py [--names a,b]`` (≈ 20 s per material on one
core: the MERL tabulation dominates; the first run also reconstructs the 50 materials).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _shared_models import shared_models  # noqa: E402
from reflecto import (  # noqa: E402
    brdf,
    kinds,
    workflow,  # noqa: E402
)
from reflecto.errors import ReflectoError  # noqa: E402
from reflecto.export.merl import export_merl  # noqa: E402
from reflecto.export.rgl import export_rgl  # noqa: E402
from reflecto.instrument.calibrate import Calibration, calibrate  # noqa: E402
from reflecto.instrument.device import Device  # noqa: E402
from reflecto.instrument.simulate import simulate_calibration  # noqa: E402
from reflecto.io import read_json  # noqa: E402
from reflecto.load import load_source  # noqa: E402
from reflecto.sources import merl  # noqa: E402


def roundtrip_model(model_path: Path, folder: Path) -> dict:
    """Write the model's ``.bsdf``, ``.binary`` and summary into ``folder`` and read each back."""
    out: dict = {"material": model_path.stem, "refused": []}
    model = load_source(model_path)
    files = {"model": model_path}
    files["rgl"] = export_rgl(model, folder / f"{model_path.stem}.bsdf")
    export_merl(model, folder / f"{model_path.stem}.binary", allow_anisotropic=True)
    files["merl"] = folder / f"{model_path.stem}.binary"
    summary = folder / f"{model_path.stem}.json"
    summary.write_text(json.dumps({"kd": model.kd.tolist(), "ks": model.ks.tolist(), "shake_detected": False,
                                   "model_error": float(model.metadata.get("model_error", 0.0))}))
    files["summary"] = summary
    for kind, path in files.items():
        try:
            if kind == "summary":
                assert isinstance(read_json(path), dict)
            else:
                load_source(path)
            got = kinds.identify(path).name
            if got != kind:
                out["refused"].append(f"{path.name}: identified as {got}")
        except ReflectoError as e:
            out["refused"].append(str(e))
    table = merl.read_merl_table(files["merl"]) if (folder / f"{model_path.stem}.binary").is_file() else None
    if table is not None:
        out["max_f"] = float(table.max())
        out["max_projected"] = float((np.maximum(table, 0) * merl._cos_cos()[..., None]).max())
    return out


def roundtrip_calibrations(folder: Path) -> list[str]:
    """A measured (as-built) and a nominal (ideal) calibration file, written and read back."""
    refused = []
    simulate_calibration(Device.builtin("as-built"), folder / "calib", seed=3, white_repeats=1)
    for name, cal in (("as-built", calibrate(folder / "calib")),
                      ("ideal", workflow.calibration_for(Device.builtin("ideal"), missing="nominal"))):
        p = cal.save(folder / f"{name}.npz")
        try:
            Calibration.load(p)
            if kinds.identify(p).name != "calibration":
                refused.append(f"{p.name}: identified as {kinds.identify(p).name}")
        except ReflectoError as e:
            refused.append(str(e))
    return refused


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--names", help="comma-separated material names (default: all 50)")
    args = ap.parse_args()
    names = args.names.split(",") if args.names else None
    rows, refused = [], []
    with tempfile.TemporaryDirectory(prefix="reflecto-roundtrip-") as tmp:
        for _, model_path in shared_models(names):
            t0 = time.perf_counter()
            r = roundtrip_model(model_path, Path(tmp))
            rows.append(r)
            refused += r["refused"]
            print(f"{r['material']:28s} max f {r.get('max_f', float('nan')):9.3g} sr⁻¹  max f·cosθi·cosθo "
                  f"{r.get('max_projected', float('nan')):8.3g} sr⁻¹  "
                  f"{'refused: ' + '; '.join(r['refused']) if r['refused'] else 'read back'}"
                  f"  ({time.perf_counter() - t0:.0f} s)", flush=True)
        cal_refused = roundtrip_calibrations(Path(tmp))
        refused += cal_refused
    n_files = 4 * len(rows) + 2
    print(f"{len(rows)} reconstructions × (model, .bsdf, .binary, summary) + 2 calibration files = {n_files} files; "
          f"refused {len(refused)}")
    if rows:
        print(f"max f over all MERL tabulations {max(r['max_f'] for r in rows):.3g} sr⁻¹; max f·cosθi·cosθo "
              f"{max(r['max_projected'] for r in rows):.3g} sr⁻¹ (bound {brdf.MAX_PROJECTED_BRDF:.3g})")
    for line in refused:
        print("refused:", line)
    return 1 if refused else 0


if __name__ == "__main__":
    sys.exit(main())
