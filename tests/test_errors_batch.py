"""Batches: a bad item is reported and the others finish; no worker outlives its parent."""

from __future__ import annotations

import importlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from reflecto.cli import main
from reflecto.errors import BatchError, ReflectoWarning

sweep_mod = importlib.import_module("reflecto.evaluate.sweep")  # the module, not the re-exported function
batch = importlib.import_module("reflecto.batch")

from _fake_sweep import fake_run_material  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
PLASTIC = ROOT / "examples" / "ggx-plastic.json"


def _materials(folder: Path, n_good: int, bad: bool = True) -> Path:
    folder.mkdir()
    for k in range(n_good):
        (folder / f"m{k}.json").write_text(json.dumps(
            {"type": "analytic", "distribution": "ggx", "alpha": 0.1 + 0.1 * k, "kd": 0.2, "ks": 0.5}))
    if bad:
        (folder / "m2-bad.bsdf").write_bytes(b"tensor_file\x00\x01\x00" + b"\xff" * 40)
    return folder


@pytest.fixture
def fake_sweep(monkeypatch):
    monkeypatch.setattr(sweep_mod, "run_material", fake_run_material)


def test_sweep_with_one_bad_material_of_five_finishes_the_four(tmp_path, fake_sweep, capsys):
    mats = _materials(tmp_path / "mats", 4)
    out = tmp_path / "res"
    assert main(["sweep", str(mats), "-o", str(out), "--jobs", "2", "--json"]) == 1
    captured = capsys.readouterr()
    info = json.loads(captured.out)  # one JSON document, nothing after it
    assert info["all"]["materials"] == 4 and [f["file"] for f in info["failed"]] == [str(mats / "m2-bad.bsdf")]
    errors = [l for l in captured.err.splitlines() if l.startswith("reflecto: error:")]
    assert len(errors) == 1 and "m2-bad.bsdf: 4294967295 fields, more than 64" in errors[0]
    assert sorted(p.name for p in (out / "materials").iterdir()) == [f"m{k}.json" for k in range(4)]
    assert len((out / "results.csv").read_text().splitlines()) == 5
    assert json.loads((out / "failures.json").read_text())[0]["file"] == str(mats / "m2-bad.bsdf")
    # a rerun retries the failed one only; once it is gone, failures.json goes too
    (mats / "m2-bad.bsdf").unlink()
    assert sweep_mod.sweep([mats], out, jobs=1, progress=False)[0]["name"] == "m0"
    assert not (out / "failures.json").exists()


def test_batch_runner_survives_a_worker_that_dies():
    """A worker killed by a signal takes only its own item with it."""
    results = {}
    items = [("ok", 0.0), ("die", 0.0), ("ok", 0.2), ("ok", 0.0), ("ok", 0.1)]
    batch.run_batch(_maybe_die, items, [f"item{k}" for k in range(5)], 2,
                        lambda k, ok, v, s: results.__setitem__(k, (ok, v)))
    assert results[1] == (False, "item1: worker process died (killed by a signal, or out of memory)")
    assert all(results[k] == (True, "ok") for k in (0, 2, 3, 4))


def _maybe_die(what: str, delay: float) -> str:
    time.sleep(delay)
    if what == "die":
        os.kill(os.getpid(), signal.SIGKILL)
    return what


def test_reconstruct_batch_reports_the_bad_capture_and_finishes_the_others(tmp_path, capsys):
    caps = []
    for k in range(5):
        c = tmp_path / f"c{k}"
        assert main(["simulate", str(PLASTIC), "--seed", str(k), "-o", str(c), "-q"]) == 0
        caps.append(str(c))
    (tmp_path / "c2" / "led3_t8ms.png").unlink()
    env_ci = os.environ.get("CI")
    os.environ["CI"] = "true"
    try:
        rc = main(["reconstruct", *caps, "-o", str(tmp_path / "models"), "--jobs", "2", "--eta", "1.5"])
    finally:
        if env_ci is None:
            del os.environ["CI"]
        else:
            os.environ["CI"] = env_ci
    captured = capsys.readouterr()
    assert rc == 1
    assert sorted(p.name for p in (tmp_path / "models").glob("*.reflecto")) == ["c0.reflecto", "c1.reflecto",
                                                                                "c3.reflecto", "c4.reflecto"]
    assert len(captured.out.strip().splitlines()) == 4
    errors = [l for l in captured.err.splitlines() if l.startswith("reflecto: error:")]
    assert errors == [f"reflecto: error: {tmp_path / 'c2' / 'led3_t8ms.png'}: frame is missing"]
    progress = [l for l in captured.err.splitlines() if l.startswith("reconstruct: ")]
    assert len(progress) == 5 and progress[-1].startswith("reconstruct: 5/5 ")
    assert sum("failed (c2)" in l for l in progress) == 1


def test_resuming_a_sweep_with_a_damaged_record_redoes_it(tmp_path, fake_sweep):
    mats = _materials(tmp_path / "mats", 2, bad=False)
    out = tmp_path / "res"
    first = sweep_mod.sweep([mats], out, jobs=1, progress=False)
    rec = out / "materials" / "m1.json"
    damaged = json.loads(rec.read_text())
    del damaged["timings"]  # was KeyError: 'timings' in the table
    rec.write_text(json.dumps(damaged))
    (out / "materials" / "m0.json").write_text("[]")
    with pytest.warns(ReflectoWarning, match="damaged result record"):
        again = sweep_mod.sweep([mats], out, jobs=1, progress=False)
    assert [r["name"] for r in again] == ["m0", "m1"] and again == first
    assert "timings" in json.loads(rec.read_text())
    # a number numpy can only hold as an object (2**64) in a render: the figures failed on it
    damaged = json.loads(rec.read_text())
    damaged["renders"]["ours"][0][0][0] = 2**64
    rec.write_text(json.dumps(damaged))
    with pytest.warns(ReflectoWarning, match="render 'ours' missing or invalid"):
        assert sweep_mod.sweep([mats], out, jobs=1, progress=False) == first


def test_sweep_raises_batch_error_with_records(tmp_path, fake_sweep):
    mats = _materials(tmp_path / "mats", 1)
    with pytest.raises(BatchError, match="1 of 2 items failed") as e:
        sweep_mod.sweep([mats], tmp_path / "res", jobs=1, progress=False)
    assert [r["name"] for r in e.value.records] == ["m0"]


def _children(pid: int) -> list[int]:
    out = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                fields = (d / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == pid:
                out.append(int(d.name))
    return out


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state not in ("Z", "X")  # a zombie is dead, waiting for its reaper


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc (Linux)")
def test_sigkill_of_the_parent_leaves_no_worker_behind(tmp_path):
    mats = _materials(tmp_path / "mats", 2, bad=False)
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    parent = subprocess.Popen([sys.executable, "-m", "reflecto.cli", "sweep", str(mats), "-o", str(tmp_path / "res"),
                               "--jobs", "2", "-q"], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    workers: list[int] = []
    try:
        deadline = time.monotonic() + 60
        while len(workers) < 2 and time.monotonic() < deadline and parent.poll() is None:
            time.sleep(0.1)
            workers = _children(parent.pid)
        assert len(workers) >= 2, "the sweep did not start its workers"
        time.sleep(0.5)  # inside their first material
        os.kill(parent.pid, signal.SIGKILL)
        parent.wait()
        deadline = time.monotonic() + 10
        while any(_alive(w) for w in workers) and time.monotonic() < deadline:
            time.sleep(0.1)
        left = [w for w in workers if _alive(w)]
        assert not left, f"workers {left} outlived their SIGKILLed parent"
    finally:
        for w in workers + _children(parent.pid) + ([parent.pid] if parent.poll() is None else []):
            try:
                os.kill(w, signal.SIGKILL)
            except ProcessLookupError:
                pass
