"""``reflecto watch``: captures copied in at the device's rate, some half-written, one damaged.

Every good capture is modelled once, with the summary ``reflecto reconstruct`` gives it
(same numbers), the damaged one reported once, and an interrupt leaves no partial file.
Timing (latency, keeping up with 8.6 captures/s) lives in benchmarks/bench_watch.py.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from reflecto import load_source
from reflecto.errors import ReflectoError
from reflecto.instrument.capture import MANIFEST, read_capture, write_capture
from reflecto.instrument.device import Device
from reflecto.instrument.simulate import simulate_capture
from reflecto.model import load_model
from reflecto.watch import READY, WAITING, Entry, Watcher, capture_state, default_previewer
from reflecto.workflow import reconstruct_folder

ROOT = Path(__file__).resolve().parents[1]
#: The device's rate: one capture every 1/8.6 s.
INTERVAL_S = 1 / 8.6
#: Summary entries that differ between two runs of the same reconstruction.
VOLATILE = ("seconds", "capture")


@pytest.fixture(scope="module")
def sources(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    """Two ideal-device captures of analytic materials (a plastic untilted, a rougher one tilted 4°)."""
    base = tmp_path_factory.mktemp("sources")
    dev = Device.builtin("ideal")
    plastic = load_source(ROOT / "examples" / "ggx-plastic.json")
    (base / "rough.json").write_text(json.dumps({"type": "analytic", "distribution": "beckmann", "alpha": 0.3,
                                                 "kd": [0.1, 0.2, 0.3], "ks": 0.3, "eta": 1.6}))
    rough = load_source(base / "rough.json")
    out = []
    for k, (src, tilt) in enumerate([(plastic, 0.0), (rough, 4.0)]):
        out.append(write_capture(simulate_capture(src, dev, tilt_deg=tilt, seed=k + 1), base / f"src{k}"))
    return out


@pytest.fixture(scope="module")
def reference(sources: list[Path], tmp_path_factory: pytest.TempPathFactory) -> list[dict]:
    """The summaries ``reflecto reconstruct`` writes for the source captures."""
    base = tmp_path_factory.mktemp("reference")
    refs = []
    for s in sources:
        reconstruct_folder(s, base / f"{s.name}.reflecto")
        refs.append(json.loads((base / f"{s.name}.json").read_text()))
    return refs


def _frames(src: Path) -> list[str]:
    return [f["file"] for f in json.loads((src / MANIFEST).read_text())["frames"]]


def _copy_in(src: Path, dst: Path, how: str, pause: float) -> None:
    """Write a capture folder the way a device's software might (``how``):
    ``atomic`` (renamed into place), ``manifest-last`` (frames one by one, a pause, then the
    manifest), ``truncated`` (manifest first, one frame cut short for a while, then completed),
    ``damaged`` (one frame's pixel data altered: its CRC fails, for good)."""
    if how == "atomic":
        tmp = dst.with_name(f".{dst.name}.copy.part")
        shutil.copytree(src, tmp)
        os.replace(tmp, dst)
        return
    dst.mkdir()
    frames = _frames(src)
    if how == "manifest-last":
        for name in frames:
            shutil.copyfile(src / name, dst / name)
        time.sleep(pause)
        shutil.copyfile(src / MANIFEST, dst / MANIFEST)
    elif how == "truncated":
        shutil.copyfile(src / MANIFEST, dst / MANIFEST)
        for name in frames[1:]:
            shutil.copyfile(src / name, dst / name)
        data = (src / frames[0]).read_bytes()
        (dst / frames[0]).write_bytes(data[: len(data) // 2])
        time.sleep(pause)
        (dst / frames[0]).write_bytes(data)
    elif how == "damaged":
        for name in frames:
            shutil.copyfile(src / name, dst / name)
        data = bytearray((src / frames[2]).read_bytes())
        data[200] ^= 0x55  # inside the image data: the chunk's CRC no longer matches
        (dst / frames[2]).write_bytes(bytes(data))
        shutil.copyfile(src / MANIFEST, dst / MANIFEST)


def test_capture_state_waits_for_manifest_and_whole_frames(sources: list[Path], tmp_path: Path) -> None:
    src = sources[0]
    dst = tmp_path / "cap"
    dst.mkdir()
    assert capture_state(dst)[0] == WAITING
    text = (src / MANIFEST).read_text()
    (dst / MANIFEST).write_text(text[: len(text) // 2])
    state, why = capture_state(dst)  # waited for, with the parser's own words
    assert state == WAITING and why.startswith("manifest.json: not valid JSON: ") and "line " in why
    (dst / MANIFEST).write_text(text)
    assert capture_state(dst)[0] == WAITING  # no frame yet
    for name in _frames(src):
        shutil.copyfile(src / name, dst / name)
    first = _frames(src)[0]
    data = (src / first).read_bytes()
    (dst / first).write_bytes(data[:-5])
    assert capture_state(dst) == (WAITING, f"frame {first} is incomplete (no PNG end chunk)")
    (dst / first).write_bytes(data)
    assert capture_state(dst) == (READY, "")
    assert np.array_equal(read_capture(dst).raw, read_capture(src).raw)


def test_a_fifo_or_folder_in_a_capture_is_the_readers_to_refuse_not_waited_on(sources: list[Path],
                                                                             tmp_path: Path) -> None:
    """Opening a FIFO blocks: the state never opens one, and reports such a folder ready
    (the reader then refuses it in one line naming the file)."""
    src = sources[0]
    first = _frames(src)[0]
    for what, name in (("fifo", first), ("fifo", MANIFEST), ("folder", first)):
        dst = tmp_path / f"{what}-{name}"
        shutil.copytree(src, dst)
        (dst / name).unlink()
        os.mkfifo(dst / name) if what == "fifo" else (dst / name).mkdir()
        assert capture_state(dst) == (READY, "")
        with pytest.raises(ReflectoError, match="not a regular file|a folder|directory"):
            read_capture(dst)


def test_watch_models_every_good_capture_once(sources: list[Path], reference: list[dict], tmp_path: Path) -> None:
    root, models = tmp_path / "root", tmp_path / "models"
    root.mkdir()
    ways = ["atomic", "manifest-last", "atomic", "truncated", "atomic", "damaged", "manifest-last", "atomic",
            "truncated", "atomic"]
    plan = [(f"cap{k:02d}", k % 2, how) for k, how in enumerate(ways)]
    done = threading.Event()

    def device() -> None:
        try:
            for name, which, how in plan:
                t = time.monotonic()
                _copy_in(sources[which], root / name, how, pause=0.3)
                time.sleep(max(0.0, INTERVAL_S - (time.monotonic() - t)))
        finally:
            done.set()

    reported: list[str] = []
    calls: list[str] = []
    default = Watcher(root, models).reconstruct_one

    def counting(cap: Path, out: Path) -> dict:
        calls.append(cap.name)
        return default(cap, out)

    watcher = Watcher(root, models, counting, settle_s=2.0, report=reported.append)
    good = {n for n, _, how in plan if how != "damaged"}
    writer = threading.Thread(target=device)
    writer.start()
    deadline = time.monotonic() + 25.0
    watcher.run(stop=lambda: (done.is_set() and good <= set(watcher.entries) and watcher.failed)
                or time.monotonic() > deadline)
    writer.join()
    assert sorted(calls) == sorted(good | {"cap05"}), "each capture reconstructed once (the damaged one tried once)"
    assert set(watcher.entries) == good
    assert len(reported) == 1 and "cap05" in reported[0] and "CRC" in reported[0] and "\n" not in reported[0]
    assert watcher.failed.keys() == {"cap05"}
    for name, which, how in plan:
        if how == "damaged":
            assert not (models / f"{name}.reflecto").exists() and not (models / f"{name}.json").exists()
            continue
        summary = json.loads((models / f"{name}.json").read_text())
        ref = reference[which]
        assert {k: v for k, v in summary.items() if k not in VOLATILE} == \
            {k: v for k, v in ref.items() if k not in VOLATILE}
        if which == 0:  # the untilted plastic against its ground truth (examples/ggx-plastic.json)
            assert np.allclose(summary["kd"], [0.45, 0.12, 0.08], rtol=0.02)
            assert np.allclose(summary["ks"], 0.5, rtol=0.03) and np.allclose(summary["eta"], 1.5, rtol=0.01)
        model = load_model(models / f"{name}.reflecto")
        assert np.allclose(model.kd, summary["kd"]) and np.allclose(model.ks, summary["ks"])
        assert (models / "thumbs" / f"{name}.png").stat().st_size > 100
    page = (models / "index.html").read_text()
    assert all(f">{n}</a>" in page for n in good) and "cap05" in page and "CRC" in page
    assert not list(models.rglob("*.part")) and not [p for p in models.iterdir() if p.name.startswith(".")]
    # a second watcher over the same folders redoes nothing and reports the damaged one again (a new process)
    again: list[str] = []
    w2 = Watcher(root, models, lambda c, o: default(c, o) if c.name == "cap05" else pytest.fail(f"{c} redone"),
                 report=again.append)
    w2.run(once=True)
    assert set(w2.entries) == good and len(again) == 1


def test_previews_land_first_and_full_models_replace_them(sources: list[Path], reference: list[dict],
                                                         tmp_path: Path) -> None:
    """With previews, each capture copied in at the device's rate gets its preview model and
    summary first; once no capture lands for ``refine_idle_s`` the full models replace them,
    oldest first, with the summaries ``reflecto reconstruct`` writes; a restarted watcher
    finishes the previews another left."""
    root, models = tmp_path / "root", tmp_path / "models"
    root.mkdir()
    names = [f"cap{k:02d}" for k in range(4)]
    done = threading.Event()

    def device() -> None:
        try:
            for k, name in enumerate(names):
                _copy_in(sources[k % 2], root / name, "atomic", pause=0.0)
                time.sleep(INTERVAL_S)
        finally:
            done.set()

    seen: list[tuple[str, bool]] = []

    def announce(entry: Entry, summary: dict, latency: float) -> None:
        assert summary["preview"] is entry.preview
        seen.append((entry.name, entry.preview))

    watcher = Watcher(root, models, preview_one=default_previewer(), refine_idle_s=0.3, announce=announce,
                      report=lambda line: pytest.fail(line))
    writer = threading.Thread(target=device)
    writer.start()
    deadline = time.monotonic() + 30.0
    watcher.run(stop=lambda: (done.is_set() and len(watcher.full_latency) == len(names))
                or time.monotonic() > deadline)
    writer.join()
    assert [n for n, p in seen if p] == names and [n for n, p in seen if not p] == names
    assert all(seen.index((n, True)) < seen.index((n, False)) for n in names)
    assert not watcher.previews and set(watcher.latency) == set(watcher.full_latency) == set(names)
    for k, name in enumerate(names):
        summary = json.loads((models / f"{name}.json").read_text())
        ref = reference[k % 2]
        assert {k: v for k, v in summary.items() if k not in VOLATILE} == \
            {k: v for k, v in ref.items() if k not in VOLATILE}
    page = (models / "index.html").read_text()
    assert page.count("<td>full</td>") == len(names) and "<td>preview</td>" not in page
    # previews left by a watcher that stopped before its full models: a restarted one makes them
    models2 = tmp_path / "models2"
    first = Watcher(root, models2, preview_one=default_previewer(), thumbnails=False)
    first.scan()
    for name in names:
        assert json.loads((models2 / f"{name}.json").read_text())["preview"] is True
    second = Watcher(root, models2, thumbnails=False,
                     announce=lambda e, s, t: seen.append((e.name, e.preview)))
    second.run(once=True)
    for name in names:
        assert json.loads((models2 / f"{name}.json").read_text())["preview"] is False
    assert "<td>preview</td>" not in (models2 / "index.html").read_text()


def test_once_reports_an_incomplete_folder_and_exits_1(sources: list[Path], tmp_path: Path) -> None:
    root, models = tmp_path / "root", tmp_path / "models"
    root.mkdir()
    shutil.copytree(sources[0], root / "good")
    (root / "half").mkdir()
    shutil.copyfile(sources[0] / _frames(sources[0])[0], root / "half" / _frames(sources[0])[0])
    proc = subprocess.run([sys.executable, "-m", "reflecto.cli", "watch", str(root), "-o", str(models), "--once"],
                          capture_output=True, text=True, env={**os.environ, "PYTHONPATH": str(ROOT / "src")},
                          timeout=120)
    assert proc.returncode == 1
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and str(root / "half") in lines[0] and "no manifest.json" in lines[0]
    assert "Traceback" not in proc.stderr
    assert (models / "good.reflecto").exists() and (models / "good.json").exists()
    shown = proc.stdout.strip().splitlines()  # one line per modelled capture
    assert len(shown) == 1 and shown[0].startswith("good (full): tilt ") and " ms" in shown[0]


@pytest.mark.parametrize("once, signum", [(False, signal.SIGINT), (True, signal.SIGTERM)])
def test_interrupt_leaves_no_partial_model(sources: list[Path], tmp_path: Path, once: bool, signum: int) -> None:
    """Ctrl-C, or a service manager's SIGTERM (``--once`` as well), stops the watch between two files."""
    root, models = tmp_path / "root", tmp_path / "models"
    root.mkdir()
    for k in range(12):
        shutil.copytree(sources[k % 2], root / f"cap{k:02d}")
    proc = subprocess.Popen([sys.executable, "-m", "reflecto.cli", "watch", str(root), "-o", str(models),
                             *(["--once"] if once else [])],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": str(ROOT / "src")})
    try:
        deadline = time.monotonic() + 60
        while not list(models.glob("*.json")) and time.monotonic() < deadline:
            time.sleep(0.01)
        time.sleep(0.05)  # mid-way through a later capture
        proc.send_signal(signum)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 130 and "Traceback" not in err
    made = sorted(p.stem for p in models.glob("*.reflecto"))
    assert made and len(made) < 12
    assert made == sorted(p.stem for p in models.glob("*.json"))
    for name in made:
        load_model(models / f"{name}.reflecto")
        json.loads((models / f"{name}.json").read_text())
    leftovers = [p for p in models.rglob("*") if p.name.startswith(".") or p.name.endswith(".part")]
    assert not leftovers


def test_a_full_model_that_fails_keeps_the_preview_until_the_folder_changes(sources: list[Path],
                                                                            tmp_path: Path) -> None:
    root, models = tmp_path / "root", tmp_path / "models"
    root.mkdir()
    shutil.copytree(sources[1], root / "a")
    lines: list[str] = []
    w = Watcher(root, models, preview_one=default_previewer(), thumbnails=False, report=lines.append)
    assert w.scan() == 1 and list(w.previews) == ["a"]
    frame = root / "a" / _frames(sources[1])[2]
    good = frame.read_bytes()
    bad = bytearray(good)
    bad[200] ^= 0x55
    frame.write_bytes(bytes(bad))
    assert w.refine() is False
    assert len(lines) == 1 and "CRC" in lines[0]
    assert json.loads((models / "a.json").read_text())["preview"] is True
    assert any(x.startswith("no full model:") and "CRC" in x for x in w.entries["a"].warnings)
    page = (models / "index.html").read_text()
    assert "<td>preview</td>" in page and "full models to follow" not in page
    assert w.scan() == 0 and not w.previews  # unchanged: not tried again
    frame.write_bytes(good)  # the folder changes: looked at again
    w.scan()
    assert list(w.previews) == ["a"] and w.refine() is True
    assert json.loads((models / "a.json").read_text())["preview"] is False and not w.entries["a"].warnings


def test_an_interrupt_between_a_full_model_and_its_summary_removes_the_preview(sources: list[Path],
                                                                               tmp_path: Path) -> None:
    """The model file written, its summary not: the preview's summary and thumbnail would
    describe another model, so all three go and the next watch makes the capture again; an
    interrupt before the model file leaves the preview whole."""
    root, models = tmp_path / "root", tmp_path / "models"
    root.mkdir()
    shutil.copytree(sources[0], root / "a")

    def before_model(cap: Path, out: Path) -> dict:
        raise KeyboardInterrupt

    def after_model(cap: Path, out: Path) -> dict:
        out.write_bytes(b"the full model")
        raise KeyboardInterrupt

    w = Watcher(root, models, before_model, preview_one=default_previewer())
    w.scan()
    kept = {p.name: p.read_bytes() for p in [models / "a.reflecto", models / "a.json", models / "thumbs" / "a.png"]}
    with pytest.raises(KeyboardInterrupt):
        w.refine()
    assert {p.name: p.read_bytes() for p in [models / "a.reflecto", models / "a.json",
                                            models / "thumbs" / "a.png"]} == kept
    w.reconstruct_one = after_model
    w.previews["a"] = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        w.refine()
    assert not (models / "a.reflecto").exists() and not (models / "a.json").exists()
    assert not (models / "thumbs" / "a.png").exists()
    again = Watcher(root, models, thumbnails=False)
    again.run(once=True)
    assert json.loads((models / "a.json").read_text())["preview"] is False


def test_a_preview_that_fails_gives_way_to_the_full_model(sources: list[Path], reference: list[dict],
                                                          tmp_path: Path) -> None:
    root, models = tmp_path / "root", tmp_path / "models"
    root.mkdir()
    shutil.copytree(sources[0], root / "a")

    def failing(cap: Path, out: Path) -> dict:
        raise ReflectoError("capture: the light fit found no usable bins")

    w = Watcher(root, models, preview_one=failing, thumbnails=False, report=lambda line: pytest.fail(line))
    assert w.scan() == 1 and not w.previews
    summary = json.loads((models / "a.json").read_text())
    assert {k: v for k, v in summary.items() if k not in VOLATILE} == \
        {k: v for k, v in reference[0].items() if k not in VOLATILE}


def test_the_cli_previews_first_unless_told_not_to(sources: list[Path], tmp_path: Path) -> None:
    """``reflecto watch`` (until Ctrl-C) writes a preview, then the full model once the captures
    stop landing; ``--no-preview`` the full model at once. One JSON line per model written."""
    root = tmp_path / "root"
    root.mkdir()
    shutil.copytree(sources[1], root / "rough")

    def lines_until(argv: list[str], n: int) -> list[dict]:
        proc = subprocess.Popen([sys.executable, "-m", "reflecto.cli", *argv], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True, env={**os.environ, "PYTHONPATH": str(ROOT / "src")})
        out: list[dict] = []
        try:
            assert proc.stdout is not None
            while len(out) < n:
                line = proc.stdout.readline()
                assert line, proc.stderr.read() if proc.stderr else "no output"
                out.append(json.loads(line))
            proc.send_signal(signal.SIGINT)
            proc.communicate(timeout=60)
        finally:
            proc.kill()
        assert proc.returncode == 130
        return out

    first, full = lines_until(["watch", str(root), "-o", str(tmp_path / "m1"), "--nominal", "--json"], 2)
    assert first["capture"] == full["capture"] == "rough"
    assert first["preview"] is True and full["preview"] is False
    assert json.loads((tmp_path / "m1" / "rough.json").read_text())["preview"] is False
    assert abs(full["normal_tilt_deg"] - 4.0) < 0.5
    (only,) = lines_until(["watch", str(root), "-o", str(tmp_path / "m2"), "--nominal", "--json", "--no-preview"], 1)
    assert only["preview"] is False and only["eta"] == full["eta"]


def test_watch_options_reach_the_reconstruction(sources: list[Path], tmp_path: Path, capsys) -> None:
    """``--isotropic``, ``--eta``, ``--normal``, ``--shadowing``, ``--nominal`` and ``--settle`` of ``watch`` are
    the reconstruction's and the watcher's: a fixed η is the model's, the tilted capture's
    tilt is found, and a calibration file that is not one is one line naming it."""
    from reflecto.cli import main

    root = tmp_path / "root"
    root.mkdir()
    shutil.copytree(sources[1], root / "rough")
    models = tmp_path / "models"
    assert main(["watch", str(root), "--output", str(models), "--once", "--settle", "0.5", "--isotropic", "yes",
                 "--eta", "1.6", "--normal", "auto", "--nominal", "--shadowing", "correlated", "--json"]) == 0
    summary = json.loads((models / "rough.json").read_text())
    line = json.loads(capsys.readouterr().out)  # JSON Lines: one object per modelled capture
    assert line["capture"] == "rough" and line["model"] == str(models / "rough.reflecto")
    assert line["normal_tilt_deg"] == summary["normal_tilt_deg"] and line["eta"] == summary["eta"]
    assert main(["watch", str(root), "-o", str(tmp_path / "m3"), "--once", "--quiet", "--nominal"]) == 0
    assert capsys.readouterr().out == "" and (tmp_path / "m3" / "rough.reflecto").exists()
    assert summary["isotropic"] is True and summary["eta"] == pytest.approx([1.6] * 3)
    assert summary["shadowing"]["form"] == "height-correlated" and summary["shadowing"]["reason"] == "option"
    assert abs(summary["normal_tilt_deg"] - 4.0) < 0.5
    bad = tmp_path / "cal.npz"
    bad.write_bytes(b"not a calibration")
    argv = ["watch", str(root), "-o", str(tmp_path / "m2"), "--once", "--calibration", str(bad)]
    proc = subprocess.run([sys.executable, "-m", "reflecto.cli", *argv], capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(ROOT / "src")}, timeout=120)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    assert str(bad) in proc.stderr and len(proc.stderr.strip().splitlines()) == 1


def test_an_interrupt_inside_a_compiled_kernel_stops_the_watch(sources: list[Path], tmp_path: Path) -> None:
    """A Ctrl-C that lands inside a compiled kernel comes back as a ``SystemError`` whose
    cause is the interrupt: the watcher stops as for any Ctrl-C, the capture is not
    reported as bad and no partial model is left."""
    from reflecto.errors import interrupted

    root, models = tmp_path / "root", tmp_path / "models"
    root.mkdir()
    shutil.copytree(sources[0], root / "good")

    def kernel_interrupted(cap_dir: Path, out: Path) -> dict:
        out.write_bytes(b"half a model")
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as e:
            raise SystemError("CPUDispatcher(<function luminance_lm>) returned a result with an exception set") from e

    problems: list[str] = []
    watcher = Watcher(root, models, kernel_interrupted, report=problems.append, thumbnails=False)
    with pytest.raises(KeyboardInterrupt):
        watcher.run(once=True)
    assert not problems and not watcher.failed
    assert not (models / "good.reflecto").exists()
    assert interrupted(SystemError("x")) is False


@pytest.fixture(scope="module")
def first_model(sources: list[Path], tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The model file ``reflecto reconstruct`` writes for the first source capture."""
    out = tmp_path_factory.mktemp("first") / f"{sources[0].name}.reflecto"
    reconstruct_folder(sources[0], out)
    return out


def test_the_path_reports_its_stages_and_the_fits_parts(sources: list[Path], tmp_path: Path) -> None:
    """``reconstruct_folder`` gives each stage's wall and CPU seconds and the reconstruction's
    CPU seconds per part (the benchmark's per-stage output): each ≥ 0, the parts within the
    reconstruct stage's CPU time, the stages within the total."""
    got = reconstruct_folder(sources[1], tmp_path / "m.reflecto")  # tilted 4°: the normal is estimated
    cpu, wall, parts = got["stage_cpu_seconds"], got["stage_seconds"], got["fit_cpu_seconds"]
    assert set(cpu) == set(wall) == {"read", "slices", "reconstruct", "symmetry", "write", "total"}
    assert set(parts) == {"normal", "fit", "isotropy", "form", "model", "motion"}
    assert all(v >= 0 for v in (*cpu.values(), *wall.values(), *parts.values()))
    assert sum(parts.values()) <= cpu["reconstruct"] + 1e-3 and parts["normal"] > 0 and parts["fit"] > 0
    assert sum(v for k, v in cpu.items() if k != "total") == pytest.approx(cpu["total"])
    saved = json.loads((tmp_path / "m.json").read_text())  # the file keeps the reconstruction's seconds only
    assert not {"stage_seconds", "stage_cpu_seconds", "fit_cpu_seconds"} & set(saved)


@pytest.mark.parametrize("fields", [{"notes": 5}, {"notes": None}, {"seconds": "abc"}, {"seconds": [1]},
                                    {"symmetry_test": "broken"}, {"symmetry_test": [1]}, {"normal_tilt_deg": "x"},
                                    {"shake_detected": True, "motion": 3}])
def test_a_damaged_summary_of_an_earlier_model_is_listed_not_fatal(sources: list[Path], reference: list[dict],
                                                                   first_model: Path, tmp_path: Path,
                                                                   fields: dict) -> None:
    """A model made before the watcher started is taken over from its summary; a summary
    whose fields have the wrong types (another program's, or damaged) neither stops the
    watch nor keeps the other captures from being modelled."""
    root, models = tmp_path / "root", tmp_path / "models"
    root.mkdir()
    models.mkdir()
    for s in sources:
        shutil.copytree(s, root / s.name)
    first = sources[0].name
    shutil.copyfile(first_model, models / f"{first}.reflecto")
    (models / f"{first}.json").write_text(json.dumps({**reference[0], **fields}))
    lines: list[str] = []
    w = Watcher(root, models, report=lines.append, thumbnails=False)
    w.run(once=True)
    assert sorted(w.entries) == sorted(s.name for s in sources) and not w.failed, lines
    assert (models / f"{first}.json").read_text() == json.dumps({**reference[0], **fields})  # taken over, not redone
    assert (models / f"{sources[1].name}.reflecto").exists() and (models / "index.html").exists()


@pytest.mark.parametrize("damage", ["empty", "truncated"])
def test_an_earlier_model_file_that_does_not_read_is_made_again(sources: list[Path], reference: list[dict],
                                                                  first_model: Path, tmp_path: Path,
                                                                  damage: str) -> None:
    """An empty or truncated model file beside a summary (a crash, another program) does
    not count as done: the capture is modelled again and the file replaced."""
    root, models = tmp_path / "root", tmp_path / "models"
    root.mkdir()
    models.mkdir()
    shutil.copytree(sources[0], root / sources[0].name)
    name = sources[0].name
    data = first_model.read_bytes()
    (models / f"{name}.reflecto").write_bytes(b"" if damage == "empty" else data[: len(data) // 2])
    (models / f"{name}.json").write_text(json.dumps(reference[0]))
    w = Watcher(root, models, report=lambda line: None, thumbnails=False)
    w.run(once=True)
    assert list(w.entries) == [name] and not w.failed
    assert load_model(models / f"{name}.reflecto").kd.shape == (3,)


def test_warnings_are_what_asks_for_another_capture_and_notes_the_rest():
    from reflecto.watch import notes_of, warnings_of

    steady = {"shake_detected": False, "notes": ["sample normal tilted 4.00° from the device axis (±0.20°, §5.4)"],
              "symmetry_test": {"decided": True, "symmetric": True}}
    assert warnings_of(steady) == [] and notes_of(steady) == steady["notes"]
    shaken = {"shake_detected": True, "motion": "LEDs 2 and 8 peak 7.8° apart",
              "symmetry_test": {"decided": True, "symmetric": False}, "notes": "damaged"}
    assert warnings_of(shaken) == ["shake detected (LEDs 2 and 8 peak 7.8° apart)",
                                   "symmetry of eq. 3 broken (capture rotations for §5.5)"]
    assert notes_of(shaken) == []


def test_the_page_shows_each_change_of_a_row(tmp_path: Path) -> None:
    """The page's rows are formatted once and remembered; a row whose entry changes (a warning,
    the full model after the preview, a thumbnail written) is formatted again."""
    models = tmp_path / "models"
    w = Watcher(tmp_path / "root", models, lambda c, o: {}, thumbnails=False)
    for k in range(3):
        w.entries[f"c{k}"] = Entry(f"c{k}", float("nan") if k == 0 else 2.0 + k, "1.5", [], 0.1, ["a note"], True)
    w._write_index()
    first = (models / "index.html").read_text()
    assert first.count("<td>preview</td>") == 3 and "<td>–</td>" in first and "<td>3.00°</td>" in first
    assert "<img" not in first
    w._write_index()
    assert (models / "index.html").read_text() == first  # the same rows, from memory
    w.entries["c1"].warnings.append("no full model: <damaged>")
    w.entries["c2"] = Entry("c2", 4.5, "2.1", [], 0.2, [], False)
    (models / "thumbs").mkdir()
    (models / "thumbs" / "c0.png").write_bytes(b"png")
    w._write_index()
    page = (models / "index.html").read_text()
    assert "<strong>no full model: &lt;damaged&gt;</strong>" in page
    assert page.count("<td>preview</td>") == 2 and "<td>full</td><td>4.50°</td><td>2.1</td>" in page
    assert page.count("<img") == 1 and 'src="thumbs/c0.png"' in page


def test_the_page_reloads_itself_while_the_watch_runs(tmp_path: Path, sources: list[Path]) -> None:
    """A browser showing the page follows the sweep; the page a stopped watch leaves is still."""
    root, models = tmp_path / "root", tmp_path / "models"
    root.mkdir()
    shutil.copytree(sources[0], root / "a")
    pages: list[str] = []
    w = Watcher(root, models, thumbnails=False,
                announce=lambda entry, summary, latency: pages.append((models / "index.html").read_text()))
    w.run(stop=lambda: bool(pages), poll_s=0.01)
    assert pages and '<meta http-equiv="refresh"' in pages[0]
    assert '<meta http-equiv="refresh"' not in (models / "index.html").read_text()
    assert ">a</a>" in (models / "index.html").read_text()
    w.run(once=True)  # --once: no reload at any time
    assert '<meta http-equiv="refresh"' not in (models / "index.html").read_text()


def test_a_full_model_that_crashes_after_writing_its_file_is_listed_as_skipped(sources: list[Path],
                                                                              tmp_path: Path) -> None:
    """A fault of the full reconstruction after its model file replaced the preview's: the
    preview's summary and thumbnail go with it, its row leaves the page, the capture is listed
    as skipped with the fault, and a later watch makes it again."""
    root, models = tmp_path / "root", tmp_path / "models"
    root.mkdir()
    shutil.copytree(sources[0], root / "a")

    def crashes(cap: Path, out: Path) -> dict:
        out.write_bytes(b"half a full model")
        raise RuntimeError("a bug")

    lines: list[str] = []
    w = Watcher(root, models, crashes, preview_one=default_previewer(), report=lines.append)
    assert w.scan() == 1 and w.refine() is False
    assert not (models / "a.reflecto").exists() and not (models / "a.json").exists()
    assert "a" not in w.entries and not w.previews and len(lines) == 1 and "a bug" in lines[0]
    page = (models / "index.html").read_text()
    assert ">a</a>" not in page and "<li>a: reconstruction failed (RuntimeError: a bug)</li>" in page
    Watcher(root, models, thumbnails=False).run(once=True)
    assert json.loads((models / "a.json").read_text())["preview"] is False


def test_a_thumbnail_that_cannot_be_written_leaves_the_model_and_a_warning(sources: list[Path], tmp_path: Path,
                                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    import reflecto.watch as watch

    def full_disk(model: object) -> bytes:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(watch, "thumbnail", full_disk)
    root, models = tmp_path / "root", tmp_path / "models"
    root.mkdir()
    shutil.copytree(sources[0], root / "a")
    w = Watcher(root, models, preview_one=default_previewer())
    assert w.scan() == 1
    assert (models / "a.json").exists() and not (models / "thumbs" / "a.png").exists()
    assert w.entries["a"].warnings == ["no thumbnail (No space left on device)"]
    assert "no thumbnail (No space left on device)" in (models / "index.html").read_text()


def test_a_folder_finished_while_its_reading_failed_is_looked_at_again(sources: list[Path],
                                                                      tmp_path: Path) -> None:
    """The folder's writer finishes while the reader refuses its half-rewritten frame: the
    refusal remembers the folder as it was found, so the finished folder is read again."""
    root, models = tmp_path / "root", tmp_path / "models"
    root.mkdir()
    shutil.copytree(sources[0], root / "a")
    frame = root / "a" / _frames(sources[0])[1]
    good = frame.read_bytes()
    frame.write_bytes(good[:-40] + bytes(28) + good[-12:])  # whole in form, damaged inside (a CRC fails)
    calls: list[int] = []

    def read_while_written(cap: Path, out: Path) -> dict:
        calls.append(1)
        if len(calls) == 1:
            try:
                return reconstruct_folder(cap, out)
            finally:
                frame.write_bytes(good)  # the writer ends its rewrite meanwhile
        return reconstruct_folder(cap, out)

    lines: list[str] = []
    w = Watcher(root, models, read_while_written, thumbnails=False, report=lines.append)
    assert w.scan() == 0 and len(lines) == 1 and "a" in w.failed
    assert w.scan() == 1 and len(calls) == 2 and "a" not in w.failed
    assert json.loads((models / "a.json").read_text())["preview"] is False


def _copies(sources: list[Path], root: Path, n: int) -> list[str]:
    root.mkdir()
    names = [f"c{k}" for k in range(n)]
    for k, name in enumerate(names):
        shutil.copytree(sources[k % 2], root / name)
    return names


def test_full_models_made_in_worker_processes_are_the_same(sources: list[Path], reference: list[dict],
                                                           tmp_path: Path) -> None:
    """``jobs=2``: the previews are replaced two at a time by full models made in worker
    processes, renamed into place here: the summaries ``reflecto reconstruct`` writes, the
    thumbnails, no hidden file left."""
    root, models = tmp_path / "root", tmp_path / "models"
    names = _copies(sources, root, 3)
    w = Watcher(root, models, preview_one=default_previewer(), jobs=2)
    assert w.scan() == 3 and list(w.previews) == names
    assert w.refine() is True and list(w.previews) == ["c2"]  # two at once
    assert w.refine() is True and not w.previews
    for k, name in enumerate(names):
        summary = json.loads((models / f"{name}.json").read_text())
        assert {a: b for a, b in summary.items() if a not in VOLATILE} == \
            {a: b for a, b in reference[k % 2].items() if a not in VOLATILE}
        load_model(models / f"{name}.reflecto")
        assert (models / "thumbs" / f"{name}.png").stat().st_size > 100 and name in w.full_latency
    assert "<td>preview</td>" not in (models / "index.html").read_text()
    assert not [p for p in models.iterdir() if p.name.startswith(".")]


def test_a_worker_that_refuses_a_capture_leaves_its_preview(sources: list[Path], tmp_path: Path) -> None:
    root, models = tmp_path / "root", tmp_path / "models"
    _copies(sources, root, 2)
    lines: list[str] = []
    w = Watcher(root, models, preview_one=default_previewer(), thumbnails=False, report=lines.append, jobs=2)
    assert w.scan() == 2
    frame = root / "c1" / _frames(sources[1])[2]
    bad = bytearray(frame.read_bytes())
    bad[200] ^= 0x55
    frame.write_bytes(bytes(bad))
    assert w.refine() is True  # c0's full model
    assert len(lines) == 1 and "c1" in lines[0] and "CRC" in lines[0]
    assert json.loads((models / "c0.json").read_text())["preview"] is False
    assert json.loads((models / "c1.json").read_text())["preview"] is True
    assert any(x.startswith("no full model:") for x in w.entries["c1"].warnings)
    assert not [p for p in models.iterdir() if p.name.startswith(".")]


def test_an_interrupt_while_a_workers_model_is_renamed_into_place(sources: list[Path], tmp_path: Path,
                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    """Between the model's rename and its summary's: the preview's files go (they would
    describe another model), the hidden files too; the other capture keeps its preview."""
    import reflecto.watch as watch

    root, models = tmp_path / "root", tmp_path / "models"
    _copies(sources, root, 2)
    w = Watcher(root, models, preview_one=default_previewer(), thumbnails=False, jobs=2)
    assert w.scan() == 2
    rename, here = os.replace, os.getpid()

    def interrupted_rename(a: Path, b: Path) -> None:
        # this process's rename of a summary into place (the workers inherit the patch: they write as usual)
        if os.getpid() == here and Path(b).parent == models and Path(b).suffix == ".json":
            raise KeyboardInterrupt
        rename(a, b)

    monkeypatch.setattr(watch.os, "replace", interrupted_rename)
    with pytest.raises(KeyboardInterrupt):
        w.refine()
    monkeypatch.setattr(watch.os, "replace", rename)
    done = {p.name for p in models.iterdir() if p.is_file()}
    assert "index.html" in done and not [n for n in done if n.startswith(".")]
    first = sorted(n for n in ("c0", "c1") if f"{n}.reflecto" not in done)
    assert len(first) == 1 and f"{first[0]}.json" not in done  # the one interrupted: made again later
    other = ({"c0", "c1"} - set(first)).pop()
    assert json.loads((models / f"{other}.json").read_text())["preview"] is True
    Watcher(root, models, thumbnails=False, jobs=2).run(once=True)
    assert all(json.loads((models / f"{n}.json").read_text())["preview"] is False for n in ("c0", "c1"))


def test_jobs_must_be_a_positive_number(tmp_path: Path) -> None:
    with pytest.raises(ReflectoError, match="jobs must be a positive number"):
        Watcher(tmp_path, tmp_path / "m", jobs=0)


def test_the_cli_replaces_previews_in_worker_processes(sources: list[Path], tmp_path: Path, capsys) -> None:
    """``watch --once --jobs 2`` over an earlier watch's previews: full models made two at a time."""
    from reflecto.cli import main

    root, models = tmp_path / "root", tmp_path / "models"
    _copies(sources, root, 2)
    assert Watcher(root, models, preview_one=default_previewer(), thumbnails=False).scan() == 2
    assert main(["watch", str(root), "-o", str(models), "--once", "--jobs", "2", "-q"]) == 0
    assert all(json.loads((models / f"c{k}.json").read_text())["preview"] is False for k in range(2))
    capsys.readouterr()
    with pytest.raises(SystemExit) as e:
        main(["watch", str(root), "-o", str(models), "--once", "--jobs", "-1", "-q"])
    assert e.value.code == 1
    assert capsys.readouterr().err.strip().startswith("reflecto: error: argument --jobs: must be 0")


def test_ctrl_c_to_the_process_group_stops_the_workers_quietly(sources: list[Path], tmp_path: Path) -> None:
    """A terminal's Ctrl-C reaches the watcher and its worker processes: the workers ignore it,
    the watcher stops them after the models running (exit 130, one line, no traceback), and
    every capture keeps a model and its summary that agree, with no hidden file left."""
    root, models = tmp_path / "root", tmp_path / "models"
    names = _copies(sources, root, 6)
    assert Watcher(root, models, preview_one=default_previewer(), thumbnails=False).scan() == 6
    proc = subprocess.Popen([sys.executable, "-m", "reflecto.cli", "watch", str(root), "-o", str(models), "--once",
                             "--jobs", "2"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, env={**os.environ, "PYTHONPATH": str(ROOT / "src")})
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and all(json.loads((models / f"{n}.json").read_text())["preview"]
                                                  for n in names):
            time.sleep(0.01)
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 130 and "Traceback" not in err and err.strip().endswith("reflecto: interrupted")
    previews = [json.loads((models / f"{n}.json").read_text())["preview"] for n in names]
    assert False in previews and True in previews
    for n in names:
        load_model(models / f"{n}.reflecto")
    assert not [p for p in models.iterdir() if p.name.startswith(".")]


def test_jobs_need_a_reconstruction_the_workers_can_take(tmp_path: Path) -> None:
    with pytest.raises(ReflectoError, match="must be picklable"):
        Watcher(tmp_path, tmp_path / "m", lambda c, o: {}, jobs=2)
    Watcher(tmp_path, tmp_path / "m", lambda c, o: {}, jobs=1)  # in this process: anything callable


def test_a_workers_model_that_cannot_be_renamed_into_place_is_reported(sources: list[Path], tmp_path: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """A rename refused by the file system (a full or read-only disk) is that capture's failure,
    reported in one line as in the watcher's own process; the watch goes on."""
    import reflecto.watch as watch

    root, models = tmp_path / "root", tmp_path / "models"
    _copies(sources, root, 2)
    lines: list[str] = []
    w = Watcher(root, models, preview_one=default_previewer(), thumbnails=False, report=lines.append, jobs=2)
    assert w.scan() == 2
    rename, here = os.replace, os.getpid()

    def refused(a: Path, b: Path) -> None:
        if os.getpid() == here and Path(b) == models / "c0.reflecto":
            raise OSError(30, "Read-only file system", str(b))
        rename(a, b)

    monkeypatch.setattr(watch.os, "replace", refused)
    assert w.refine() is True  # c1
    monkeypatch.setattr(watch.os, "replace", rename)
    assert len(lines) == 1 and "c0.reflecto: Read-only file system" in lines[0]
    assert json.loads((models / "c0.json").read_text())["preview"] is True
    assert json.loads((models / "c1.json").read_text())["preview"] is False
    assert not [p for p in models.iterdir() if p.name.startswith(".")]


def _fake_model(cap: Path, out: Path) -> dict:
    """A stand-in reconstruction that reads the capture as ``reconstruct`` does (its refusals)
    and writes a model file and its summary without fitting (the real model of the plastic,
    copied): the watcher's bookkeeping is what is tested."""
    read_capture(cap)
    shutil.copyfile(_fake_model.model, out)  # type: ignore[attr-defined]
    summary = {"capture": str(cap), "eta": 1.5, "normal_tilt_deg": 0.0, "notes": [], "seconds": 0.0,
               "manifest": json.loads((cap / MANIFEST).read_text()).get("note", "")}
    out.with_suffix(".json").write_text(json.dumps(summary))
    return summary


@pytest.fixture()
def fake(first_model: Path):
    _fake_model.model = first_model  # type: ignore[attr-defined]
    return _fake_model


def test_names_the_models_cannot_carry_are_reported_and_skipped(sources: list[Path], tmp_path: Path,
                                                                  fake) -> None:
    """A folder name that is not valid UTF-8, or too long for the models' file names beside it,
    is reported in one line and skipped; the page lists it (escaped) and the other captures
    are modelled."""
    root, models = tmp_path / "root", tmp_path / "models"
    root.mkdir()
    shutil.copytree(sources[0], root / "good")
    bad = os.fsdecode(b"bad\xff")
    shutil.copytree(sources[0], root / bad)
    long = "c" * 240
    shutil.copytree(sources[0], root / long)
    lines: list[str] = []
    w = Watcher(root, models, fake, thumbnails=False, report=lines.append)
    w.run(once=True)
    assert list(w.entries) == ["good"] and sorted(w.failed) == sorted([bad, long])
    assert len(lines) == 2 and all("\n" not in x and x.isprintable() for x in lines)
    assert any("bad\\udcff" in x and "not valid UTF-8" in x for x in lines)
    assert any("240 bytes" in x for x in lines)
    page = (models / "index.html").read_text()
    assert "bad\\udcff" in page and "not valid UTF-8" in page


@pytest.mark.parametrize("manifest", ["deep", "nul", "huge", "syntax"])
def test_a_damaged_manifest_is_reported_in_one_line(sources: list[Path], tmp_path: Path, fake,
                                                    manifest: str) -> None:
    """A manifest nested too deep, naming a frame with a NUL, larger than the reader's limit
    or with a syntax error is reported in the reader's words (the syntax error once it stays
    unchanged), and the watch carries on with the other captures."""
    root, models = tmp_path / "root", tmp_path / "models"
    root.mkdir()
    shutil.copytree(sources[0], root / "good")
    bad = root / "bad"
    shutil.copytree(sources[0], bad)
    text = (bad / MANIFEST).read_text()
    if manifest == "deep":
        (bad / MANIFEST).write_text("[" * 100_000 + "]" * 100_000)
    elif manifest == "nul":
        (bad / MANIFEST).write_text(json.dumps({**json.loads(text), "frames": [{"file": "a\u0000b.png"}]}))
    elif manifest == "huge":
        with open(bad / MANIFEST, "wb") as fh:  # sparse: no disk used
            fh.truncate(17 << 20)
    else:
        (bad / MANIFEST).write_text(text.replace(",", ",,", 1))
    lines: list[str] = []
    w = Watcher(root, models, fake, thumbnails=False, report=lines.append)
    w.run(once=True)
    assert list(w.entries) == ["good"] and list(w.failed) == ["bad"] and len(lines) == 1
    expected = {"deep": "nested deeper", "nul": "a\\x00b.png", "huge": "bytes allowed", "syntax": "not valid JSON"}
    assert expected[manifest] in lines[0], lines


def test_a_summary_that_is_not_an_object_is_made_again_not_adopted_over_and_over(
        sources: list[Path], tmp_path: Path, fake) -> None:
    """An earlier model whose summary the checking reader refuses (not an object) does not
    count as done: the capture is modelled again, once, and the watcher does not rewrite
    its page on every look."""
    root, models = tmp_path / "root", tmp_path / "models"
    root.mkdir()
    models.mkdir()
    shutil.copytree(sources[0], root / "a")
    shutil.copyfile(fake.model, models / "a.reflecto")
    (models / "a.json").write_text("[1]")
    w = Watcher(root, models, fake, thumbnails=False, report=lambda line: None)
    assert w.scan() == 1
    assert isinstance(json.loads((models / "a.json").read_text()), dict)
    page = (models / "index.html").stat().st_mtime_ns
    for _ in range(3):
        assert w.scan() == 0
    assert (models / "index.html").stat().st_mtime_ns == page


@pytest.mark.parametrize("preview", [False, True])
def test_a_folder_rewritten_while_its_model_is_made_is_made_again(sources: list[Path], tmp_path: Path,
                                                                   first_model: Path, preview: bool) -> None:
    """The folder is replaced by another capture while its model is made (one process, with
    or without a preview first): the model is made again from what the folder holds now."""
    root, models = tmp_path / "root", tmp_path / "models"
    root.mkdir()
    shutil.copytree(sources[0], root / "a")
    made: list[str] = []

    def swapped(cap: Path, out: Path) -> dict:
        made.append(json.loads((cap / MANIFEST).read_text())["simulation"]["source"])
        summary = reconstruct_folder(cap, out, preview=preview and len(made) == 1)
        if len(made) == 1:
            tmp = root / ".a.part"
            shutil.copytree(sources[1], tmp)
            shutil.rmtree(root / "a")
            os.replace(tmp, root / "a")
        return summary

    w = Watcher(root, models, swapped, thumbnails=False, report=lambda line: None, refine_idle_s=0.0)
    w.run(once=True)
    assert len(made) == 2 and made[0] != made[1]
    summary = json.loads((models / "a.json").read_text())
    assert summary["preview"] is False and abs(summary["normal_tilt_deg"] - 4.0) < 0.5  # the rough one, tilted


def test_folders_that_are_gone_are_forgotten(sources: list[Path], tmp_path: Path, fake) -> None:
    """A folder reported (or waited for) and then removed or renamed by its writer leaves the
    watcher's state and the page's skipped list."""
    root, models = tmp_path / "root", tmp_path / "models"
    root.mkdir()
    (root / "incoming").mkdir()  # a writer's folder, no manifest yet
    w = Watcher(root, models, fake, thumbnails=False, report=lambda line: None, settle_s=0.0)
    w.scan()
    assert "incoming" in w.failed and "incoming" in (models / "index.html").read_text()
    shutil.copytree(sources[0], root / "incoming-done")
    shutil.rmtree(root / "incoming")
    w.scan()
    assert not w.failed and not w._waiting and list(w.entries) == ["incoming-done"]
    assert "Skipped" not in (models / "index.html").read_text()


def test_a_dangling_link_in_a_refused_folder_does_not_hide_its_repair(sources: list[Path], tmp_path: Path,
                                                                        fake) -> None:
    """A refused folder holding a dangling link is looked at again once its manifest is fixed
    (the folder's signature still sees the other files change)."""
    root, models = tmp_path / "root", tmp_path / "models"
    root.mkdir()
    cap = root / "a"
    shutil.copytree(sources[0], cap)
    good = (cap / MANIFEST).read_text()
    (cap / MANIFEST).write_text(good.replace(",", ",,", 1))
    os.symlink(tmp_path / "nowhere.jpg", cap / "preview.jpg")
    w = Watcher(root, models, fake, thumbnails=False, report=lambda line: None, settle_s=0.0)
    w.scan()
    assert "a" in w.failed
    time.sleep(0.01)
    (cap / MANIFEST).write_text(good)
    w.scan()
    assert list(w.entries) == ["a"] and not w.failed


def test_a_folder_named_like_a_part_file_is_a_capture(sources: list[Path], tmp_path: Path, fake) -> None:
    """Only hidden names are a writer's unfinished folders; ``spare.part`` is modelled."""
    root, models = tmp_path / "root", tmp_path / "models"
    root.mkdir()
    shutil.copytree(sources[0], root / "spare.part")
    shutil.copytree(sources[0], root / ".a.copy.part")
    w = Watcher(root, models, fake, thumbnails=False, report=lambda line: None)
    w.run(once=True)
    assert list(w.entries) == ["spare.part"] and not w.failed


def test_the_cli_prints_one_line_per_model_whatever_the_name(sources: list[Path], tmp_path: Path, capsys) -> None:
    """A newline in a capture's name is written escaped in the CLI's line for its model; a
    capture folder given as the folder to watch is refused in one line."""
    from reflecto.cli import main

    root = tmp_path / "root"
    root.mkdir()
    shutil.copytree(sources[0], root / "x\nfake (full): forged")
    assert main(["watch", str(root), "-o", str(tmp_path / "m"), "--nominal", "--once", "--no-preview"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert len(out) == 1 and out[0].startswith("x\\nfake (full): forged (full): tilt")
    assert main(["watch", str(root / "x\nfake (full): forged"), "-o", str(tmp_path / "m2"), "--once"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is a capture folder; watch the folder the captures land in" in err[0]
    assert not (tmp_path / "m2").exists()


def test_a_capture_that_leaves_or_is_replaced_after_its_model(sources: list[Path], tmp_path: Path,
                                                                monkeypatch) -> None:
    """A capture removed after its preview leaves the page (it stayed as "full model to follow"
    for good) with one line, its files kept in MODELS; a capture replaced by another after its
    full model is modelled again from the new data (the page kept the old material's tilt)."""
    import reflecto.watch as watch_mod

    monkeypatch.setattr(watch_mod, "IDENTITY_CHECK_S", 0.0, raising=False)
    root, models = tmp_path / "root", tmp_path / "models"
    root.mkdir()
    shutil.copytree(sources[0], root / "gone")
    shutil.copytree(sources[0], root / "swapped")  # the untilted plastic
    lines: list[str] = []
    w = Watcher(root, models, thumbnails=False, report=lines.append, preview_one=default_previewer(),
                refine_idle_s=3600.0)
    w.scan()
    assert sorted(w.entries) == ["gone", "swapped"] and all(e.preview for e in w.entries.values())
    shutil.rmtree(root / "gone")
    w.scan()
    assert list(w.entries) == ["swapped"] and "gone" not in w.previews
    assert len(lines) == 1 and "left the watched folder" in lines[0] and (models / "gone.json").is_file()
    assert ">gone<" not in (models / "index.html").read_text()
    w.refine_idle_s = 0.0
    assert w.refine(final=True)
    assert not w.entries["swapped"].preview and abs(w.entries["swapped"].tilt_deg) < 0.5
    tmp = root / ".swapped.part"
    shutil.copytree(sources[1], tmp)  # the rough material tilted 4°, renamed into place
    shutil.rmtree(root / "swapped")
    os.replace(tmp, root / "swapped")
    w.run(once=True)
    summary = json.loads((models / "swapped.json").read_text())
    assert summary["preview"] is False and abs(summary["normal_tilt_deg"] - 4.0) < 0.5
    assert abs(w.entries["swapped"].tilt_deg - 4.0) < 0.5
