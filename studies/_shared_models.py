"""The 50 shared reconstructions (ideal device), cached under ``out/`` for the export and render studies.

Every material of ``shared/data/rgl`` and ``shared/data/merl-nbrdf`` is simulated on the
ideal device with the sweep's seed (:func:`reflecto.evaluate.sweep.material_seed`) and
reconstructed, as the validation sweep does. The models are kept in
``out/shared-models/<key>/``, where the key is a hash of every source file the
reconstruction depends on (all of ``src/reflecto`` but the exports, the renderers, the
report and the CLI), so a changed reconstruction is redone and an unchanged one is read.
"""

from __future__ import annotations

import hashlib
import sys
import time
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from conftest import SHARED  # noqa: E402

#: Source files that do not change a reconstruction.
_NOT_RECONSTRUCTION = ("export/", "render/", "evaluate/report.py", "evaluate/plots.py", "mitsuba_support.py", "cli.py")


def reconstruction_key() -> str:
    """Hash of the reconstruction's source files (see the module docstring)."""
    h = hashlib.sha256()
    src = ROOT / "src" / "reflecto"
    for p in sorted(src.rglob("*.py")):
        rel = p.relative_to(src).as_posix()
        if not rel.startswith(_NOT_RECONSTRUCTION):
            h.update(rel.encode() + b"\0" + p.read_bytes())
    return h.hexdigest()[:12]


def material_files() -> list[Path]:
    """The 50 shared materials (10 RGL, 40 NBRDF), sorted by name."""
    from reflecto.evaluate.sweep import find_materials

    return sorted(find_materials([SHARED / "rgl", SHARED / "merl-nbrdf"]), key=lambda p: p.stem)


def shared_models(names: list[str] | None = None, quiet: bool = False) -> Iterator[tuple[Path, Path]]:
    """``(material file, model file)`` for each shared material (or those named), reconstructing when not cached."""
    from reflecto import workflow
    from reflecto.evaluate.sweep import material_seed
    from reflecto.instrument.device import Device
    from reflecto.instrument.simulate import simulate_capture
    from reflecto.load import load_source
    from reflecto.reconstruct.pipeline import reconstruct

    folder = ROOT / "out" / "shared-models" / reconstruction_key()
    folder.mkdir(parents=True, exist_ok=True)
    dev = Device.builtin("ideal")
    cal = workflow.calibration_for(dev, missing="nominal")
    for p in material_files():
        if names and p.stem not in names:
            continue
        out = folder / f"{p.stem}.reflecto"
        if not out.is_file():
            t0 = time.perf_counter()
            cap = simulate_capture(load_source(p), dev, seed=material_seed(p.stem))
            res = reconstruct(workflow.measure(cap, cal))
            res.model.metadata.update({"material": p.stem, "device": "ideal (simulated)"})
            res.model.save(out)
            if not quiet:
                print(f"  reconstructed {p.stem} in {time.perf_counter() - t0:.1f} s -> {out}", file=sys.stderr,
                      flush=True)
        yield p, out
