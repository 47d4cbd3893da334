"""Benchmark of ``reflecto watch``: 100 captures landing at the device's rate, one core.

The captures of :mod:`bench_capture_to_model` (measured materials, as-built device,
calibrated, tilted 3–8°) are copied into a watched folder from a thread at 8.6 per
second (the device's rate), 100 in all: most renamed into place whole, every fourth
written frame by frame with the manifest last after a pause (half-written while the
watcher looks), and one damaged (a frame's CRC fails). The watcher
(:class:`reflecto.watch.Watcher`, as ``reflecto watch`` runs it: a preview of each capture
first, the full reconstructions once the captures stop landing; ``--no-preview``: the
full reconstruction of each capture at once; thumbnails and index page) runs in the
main thread.

Prints the latency per capture (from the folder landed to its first model, summary and
index written: median, p90, max), whether the damaged capture was reported, the rate
kept (captures per second until every capture has its first model) and the process's
CPU time per capture (on a shared machine the wall-clock figures also count the other
processes' turns; the CPU time says whether one core of its own keeps up); with
previews also the time from the last capture landed to the last full model, and the
full models' CPU time. Target: latency ≤ 200 ms, keeping up with 8.6 captures/s.

With ``--jobs N`` the full models are made N at a time in worker processes (``reflecto watch
--jobs``), on every core (the process is not pinned then); their CPU time is the workers',
not counted in the process's.

Run: ``.venv/bin/python benchmarks/bench_watch.py [--work DIR] [--count N] [--no-preview] [--jobs N]``.
"""

from __future__ import annotations

import _bench  # noqa: F401  (pins to one core before NumPy loads)

# isort: split
import argparse  # noqa: E402
import json  # noqa: E402
import os  # noqa: E402
import shutil  # noqa: E402
import tempfile  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from bench_capture_to_model import ROOT, prepare  # noqa: E402
from reflecto.watch import Watcher, default_previewer, default_reconstructor  # noqa: E402

RATE = 8.6


def land(src: Path, dst: Path, how: str) -> None:
    """Write one capture folder into the watched folder (``whole``, ``manifest-last`` or ``damaged``)."""
    if how == "whole":
        tmp = dst.with_name(f".{dst.name}.part")
        shutil.copytree(src, tmp)
        os.replace(tmp, dst)
        return
    dst.mkdir()
    frames = [f["file"] for f in json.loads((src / "manifest.json").read_text())["frames"]]
    for k, name in enumerate(frames):
        data = (src / name).read_bytes()
        if how == "damaged" and k == 2:
            data = data[:200] + bytes([data[200] ^ 0x55]) + data[201:]
        (dst / name).write_bytes(data)
    time.sleep(0.02)
    shutil.copyfile(src / "manifest.json", dst / "manifest.json")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", type=Path, default=ROOT / "out" / "bench-capture-to-model")
    ap.add_argument("--count", type=int, default=100)
    ap.add_argument("--no-preview", action="store_true", help="the full reconstruction of each capture at once")
    ap.add_argument("--jobs", type=int, default=1,
                    help="worker processes for the full models that replace the previews (watch --jobs)")
    args = ap.parse_args()
    caps, cal = prepare(args.work)
    if args.jobs > 1:  # the workers inherit the process's affinity: give them every core (the watcher too)
        os.sched_setaffinity(0, range(os.cpu_count() or 1))
    with tempfile.TemporaryDirectory() as tmp:
        root, models = Path(tmp) / "root", Path(tmp) / "models"
        root.mkdir()
        recon = default_reconstructor(str(cal))
        previewer = None if args.no_preview else default_previewer(str(cal))
        # warm-up (compiled kernels, the calibration's caches) outside the timed run
        warm = Watcher(caps[0].parent, Path(tmp) / "warm", recon, report=lambda _: None)
        warm.run(once=True)
        if previewer is not None:
            previewer(caps[0], Path(tmp) / "warm" / "preview.reflecto")
        landed: dict[str, float] = {}
        plan = [(f"c{k:03d}", caps[k % len(caps)], "damaged" if k == args.count // 2 else
                 "manifest-last" if k % 4 == 3 else "whole") for k in range(args.count)]
        done = threading.Event()

        def device() -> None:
            t0 = time.monotonic()
            for k, (name, src, how) in enumerate(plan):
                time.sleep(max(0.0, t0 + k / RATE - time.monotonic()))
                land(src, root / name, how)
                landed[name] = time.monotonic()
            done.set()

        reported: list[str] = []
        full_at: dict[str, float] = {}

        def on_model(entry, summary, latency) -> None:
            if not entry.preview:
                full_at[entry.name] = time.monotonic()

        watcher = Watcher(root, models, recon, settle_s=2.0, report=reported.append, preview_one=previewer,
                          announce=on_model, jobs=args.jobs)
        writer = threading.Thread(target=device)
        t0, c0 = time.monotonic(), time.process_time()
        writer.start()
        n_good = args.count - 1
        watcher.run(stop=lambda: done.is_set() and len(watcher.finished_at) + len(watcher.failed) >= args.count)
        span, cpu = time.monotonic() - t0, time.process_time() - c0
        writer.join()
        lat = 1000 * np.array([watcher.finished_at[n] - landed[n] for n in watcher.finished_at])
        if previewer is not None:  # the full models, once the captures stopped landing
            watcher.run(stop=lambda: not watcher.previews)
            last = max(landed.values())
            full_span, full_cpu = time.monotonic() - last, time.process_time() - c0 - cpu
            n_full = len(full_at)
    print(f"reflecto watch: {args.count} captures landing at {RATE} per second ({len(caps)} measured materials, "
          f"as-built, calibrated, tilted 3–8°), one core" + (f"; full models in {args.jobs} worker processes"
                                                             if args.jobs > 1 else ""))
    print(f"  modelled {len(lat)}/{n_good} good captures; damaged reported: {len(reported)} line(s)"
          + (f" ({reported[0][-80:]})" if reported else ""))
    first = "preview" if previewer is not None else "model"
    print(f"  latency (landed → {first}, summary, index written): median {np.median(lat):.0f} ms, "
          f"p90 {np.percentile(lat, 90):.0f} ms, max {lat.max():.0f} ms")
    print(f"  rate kept: {args.count / span:.2f} captures/s over {span:.1f} s (device: {RATE}/s); the process's CPU "
          f"time {1000 * cpu / args.count:.0f} ms per capture (watcher and copying thread; {1000 / RATE:.0f} ms "
          "keeps up on one core of its own)")
    if previewer is not None:
        print(f"  full models: {n_full}/{n_good}, the last {full_span:.1f} s after the last capture landed "
              f"(the watcher waits {watcher.refine_idle_s:g} s for the sweep to pause); CPU "
              f"{1000 * full_cpu / max(n_full, 1):.0f} ms per full model")


if __name__ == "__main__":
    main()
