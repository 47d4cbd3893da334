r"""`reflecto sweep --scheduler` on a Dask LocalCluster writes the local run's table (issue 27, item 4).

Runs the sweep twice on the same materials, once in local processes and once on a
``distributed.LocalCluster`` of ``--jobs`` single-threaded worker processes, and compares
the two ``results.csv`` in every column but the ``seconds_*`` ones (timings), and every
material record but its ``timings`` (and the temporary path it was read from). Prints the verdict and both wall times.

    .venv/bin/python studies/validate_dask.py ../shared/data/rgl ../shared/data/merl-nbrdf \
        --device wide --only pvc yellow-paint cm_military_green_rgb -o out/dask-check

Resumable like the sweep: a rerun into the same folder reuses finished records.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path


def _table(path: Path) -> list[list[str]]:
    rows = [line.split(",") for line in path.read_text().strip().splitlines()]
    keep = [k for k, name in enumerate(rows[0]) if not name.startswith("seconds")]
    return [[r[k] for k in keep] for r in rows]


def _records(folder: Path) -> dict[str, dict]:
    out = {}
    for p in sorted((folder / "materials").glob("*.json")):
        rec = json.loads(p.read_text())
        rec.pop("timings", None)
        rec.pop("file", None)  # the temporary folder of links the run read
        out[p.stem] = rec
    return out


def main(argv: list[str] | None = None) -> int:
    from distributed import LocalCluster

    from reflecto.evaluate.sweep import find_materials, sweep

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folders", nargs="+")
    ap.add_argument("--device", default="ideal")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--only", nargs="*", help="material names (default: all)")
    ap.add_argument("-o", "--output", required=True)
    a = ap.parse_args(argv)
    mats = [p for p in find_materials(a.folders) if not a.only or p.stem in a.only]
    out = Path(a.output)
    with tempfile.TemporaryDirectory() as tmp:
        sel = Path(tmp) / "materials"
        sel.mkdir()
        for p in mats:  # the chosen materials, by link, so that both runs see the same list
            (sel / p.name).symlink_to(p.resolve())
            if p.suffix == ".h5" and p.with_suffix(".json").exists():
                (sel / p.with_suffix(".json").name).symlink_to(p.with_suffix(".json").resolve())
        t0 = time.perf_counter()
        sweep([sel], out / "local", device=a.device, jobs=a.jobs, progress=False)
        t_local = time.perf_counter() - t0
        with LocalCluster(n_workers=a.jobs, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
            t0 = time.perf_counter()
            sweep([sel], out / "dask", device=a.device, progress=False, scheduler=cluster.scheduler_address)
            t_dask = time.perf_counter() - t0
    same_table = _table(out / "local" / "results.csv") == _table(out / "dask" / "results.csv")
    same_records = _records(out / "local") == _records(out / "dask")
    print(f"{len(mats)} materials, device {a.device}: local {t_local:.0f} s, LocalCluster of {a.jobs} workers "
          f"{t_dask:.0f} s")
    print(f"tables identical (but for seconds_*): {same_table}; records identical (but for timings): {same_records}")
    return 0 if same_table and same_records else 1


if __name__ == "__main__":
    sys.exit(main())
