"""Benchmark of ``reflecto render``: a sphere under each shared environment map, 256×256.

Issue 6 target: ≤ 60 s per image on this 2-core machine (all cores allowed: Mitsuba's
LLVM backend is multi-threaded). Prints one line per map and the variant used; the
last line is ``max_seconds_per_render: X``.

Run: ``make bench`` or ``.venv/bin/python benchmarks/bench_render.py``.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from reflecto.render.mitsuba import SHARED, render
from reflecto.sources import load_source


def main() -> None:
    src = load_source(Path(__file__).resolve().parents[1] / "examples" / "ggx-plastic.json")
    maps = sorted((SHARED / "envmaps").glob("*.hdr"))
    if not maps:
        sys.exit(f"no environment maps under {SHARED / 'envmaps'}")
    worst = 0.0
    for m in maps:
        t = time.perf_counter()
        _, variant = render(src, "sphere-env", envmap=m, resolution=256, spp=64)
        dt = time.perf_counter() - t
        worst = max(worst, dt)
        print(f"sphere-env {m.name}: {dt:.1f} s ({variant}, 256x256, 64 spp, includes the .bsdf export)")
    print(f"max_seconds_per_render: {worst:.1f}")


if __name__ == "__main__":
    main()
