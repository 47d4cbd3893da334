"""Benchmark of ``reflecto render``: each scene at its default samples per pixel, 256×256.

Target: ≤ 60 s per image on this 2-core machine (all cores allowed: Mitsuba's
LLVM backend is multi-threaded). The sphere is rendered under each shared environment
map (``sphere-env``), under the point lights (``sphere-point``) and the teapot under the
studio map (``teapot-env``), each including the export of the analytic source to
``.bsdf``; ``render --compare`` takes three renders. Prints one line per image and
the variant used; the last line is ``max_seconds_per_render: X``. On a machine shared
with other jobs the times vary by 2-4×.

Run: ``make bench`` or ``.venv/bin/python benchmarks/bench_render.py``.
"""

from __future__ import annotations

import sys
from pathlib import Path

from reflecto.load import load_source
from reflecto.render.mitsuba import SHARED, default_envmap, render


def main() -> None:
    src = load_source(Path(__file__).resolve().parents[1] / "examples" / "ggx-plastic.json")
    maps = sorted((SHARED / "envmaps").glob("*.hdr"))
    if not maps:
        sys.exit(f"no environment maps under {SHARED / 'envmaps'}")
    jobs = [("sphere-env", m) for m in maps] + [("sphere-point", None), ("teapot-env", default_envmap())]
    worst = 0.0
    for scene, envmap in jobs:
        r = render(src, scene, envmap=envmap, resolution=256)
        worst = max(worst, r.seconds)
        where = f" {envmap.name}" if envmap is not None and scene != "sphere-point" else ""
        print(f"{scene}{where}: {r.seconds:.1f} s ({r.variant}, 256x256, {r.spp} spp, includes the .bsdf export)",
              flush=True)
    print(f"max_seconds_per_render: {worst:.1f}")


if __name__ == "__main__":
    main()
