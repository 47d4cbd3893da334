import json
import subprocess
import sys

import numpy as np

from conftest import json_out
from reflecto.cli import main
from reflecto.sources import merl


def test_info_json(capsys, shared):
    assert main(["info", str(shared / "merl-nbrdf" / "pvc.h5"), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["kind"] == "nbrdf" and info["reciprocal"]
    lo, hi = info["albedo_range"]
    assert 0 < lo <= hi < 1.05


def test_info_gives_an_anisotropic_albedo_range_over_the_incidence_azimuths(capsys):
    """An anisotropic source's albedo changes with φ_i: the range is over 12 azimuths, the
    largest what `compare` normalizes by (it read φ_i = 0 alone: 0.2228 against 0.3174)."""
    from pathlib import Path

    from reflecto.evaluate.metrics import ALBEDO_AZIMUTHS, max_albedo
    from reflecto.load import load_source

    brushed = Path(__file__).resolve().parents[1] / "examples" / "asymmetric" / "ggx-brushed-30.toml"
    assert main(["info", str(brushed), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert not info["isotropic"] and info["albedo_range_azimuths"] == ALBEDO_AZIMUTHS
    hi = max_albedo(load_source(brushed), azimuths=ALBEDO_AZIMUTHS)
    assert abs(info["albedo_range"][1] - hi) < 1e-3 and info["albedo_range"][1] > 1.2 * max(info["albedo"]["80deg"])


def test_tabulate_analytic(tmp_path, capsys):
    src = tmp_path / "g.json"
    src.write_text('{"type": "analytic", "distribution": "ggx", "alpha": 0.3, "kd": 0.2, "ks": 0.5}')
    out = tmp_path / "g.binary"
    assert main(["tabulate", str(src), "-o", str(out), "-q"]) == 0
    t = merl.read_merl_table(out)
    assert t.shape == (90, 90, 180, 3) and np.all(t >= 0)
    # the diffuse floor 0.2/π lies under every bin above the horizon; the peak is at θ_h ≈ 0
    assert t[t > 0].min() >= 0.2 / np.pi - 1e-12
    from reflecto import geometry as g
    from reflecto.load import load_source

    th, td, pd = merl.bin_centres()
    i, o = g.hd_to_io(th[0], 0.0, td[10], pd[30])
    assert np.allclose(t[0, 10, 30], load_source(src).eval(i[None], o[None])[0], rtol=1e-12)
    assert t[0, 10, 30, 0] > 1.2 * t[60, 10, 30, 0]  # specular peak above the off-specular floor


def test_bad_input_exits_nonzero_and_writes_nothing(tmp_path, capsys):
    bad = tmp_path / "bad.binary"
    bad.write_bytes(np.array([90, 90, 180], "<i4").tobytes() + b"\x00" * 800)
    out = tmp_path / "out.binary"
    assert main(["tabulate", str(bad), "-o", str(out)]) == 1
    err = capsys.readouterr().err
    assert "bad.binary" in err and "truncated" in err
    assert not out.exists() and not list(tmp_path.glob("*.part"))
    assert main(["info", str(tmp_path / "missing.bsdf")]) == 1
    assert "no such file" in capsys.readouterr().err


def test_console_script_runs():
    r = subprocess.run([sys.executable, "-m", "reflecto.cli", "--version"], capture_output=True, text=True)
    assert r.returncode == 0 and "reflecto" in r.stdout


# ------------------------------------------------------------ ergonomics
import argparse  # noqa: E402
from pathlib import Path  # noqa: E402

import pytest  # noqa: E402

from reflecto.cli import build_parser  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
PLASTIC = ROOT / "examples" / "ggx-plastic.json"



def _subparsers():
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return sub.choices


def test_every_option_has_help_and_defaults_are_shown(monkeypatch):
    monkeypatch.setenv("COLUMNS", "200")  # no line breaks inside a default
    for name, parser in _subparsers().items():
        for action in parser._actions:
            if action.option_strings and action.dest != "help":
                assert action.help, f"{name} {action.option_strings} has no help"
    def text(name):
        return " ".join(_subparsers()[name].format_help().split())

    assert "(default: ideal)" in text("sweep") and "worker processes (0: all cores) (default: 0)" in text("sweep")
    assert "samples per pixel of the renders (default: 64)" in text("report")
    assert "shake (default: 0)" in text("simulate")  # --seed
    assert "(default: sphere-env)" in text("render") and "pixels (default: 256)" in text("render")
    for name in _subparsers():  # a None default is never shown as such
        assert "(default: None)" not in text(name), name


def test_json_on_every_result_command(tmp_path, capsys):
    """--json prints exactly one JSON document on stdout (no text line after it)."""
    results = {}
    runs = {
        "simulate": ["simulate", str(PLASTIC), "-o", str(tmp_path / "cap")],
        "reconstruct": ["reconstruct", str(tmp_path / "cap"), "--eta", "1.5", "-o", str(tmp_path / "m.reflecto")],
        "export": ["export", str(tmp_path / "m.reflecto"), "-o", str(tmp_path / "m.binary"), "--isotropic", "yes"],
        "tabulate": ["tabulate", str(PLASTIC), "-o", str(tmp_path / "p.binary")],
        "info": ["info", str(tmp_path / "m.binary")],
        "compare": ["compare", str(PLASTIC), str(tmp_path / "m.binary")],
        "layout": ["layout"],
    }
    for name, argv in runs.items():
        assert main([*argv, "--json"]) == 0, name
        results[name] = json_out(capsys)
    assert results["simulate"]["leds"] == 6 and results["simulate"]["check_frames"] == 2
    assert results["reconstruct"]["failed"] == [] and results["reconstruct"]["models"][0]["summary"]["eta"] == [1.5] * 3
    assert results["export"]["format"] == "merl" and results["export"]["bytes"] == merl.FILE_BYTES
    assert results["tabulate"]["output"] == str(tmp_path / "p.binary")
    assert results["info"]["kind"] == "merl" and "reference" in results["compare"]


def test_json_of_calibration_and_report_commands(tmp_path, capsys):
    assert main(["simulate-calibration", "--device", "as-built", "-o", str(tmp_path / "calib"), "--json"]) == 0
    assert "calibration.json" in json_out(capsys)["files"]
    assert main(["calibrate", str(tmp_path / "calib"), "-o", str(tmp_path / "cal.npz"), "--json"]) == 0
    assert json_out(capsys)["report"]["reprojection_rms_px"] < 0.1
    from reflecto.load import load_source
    from reflecto.model import MicrofacetBRDF

    MicrofacetBRDF.from_ndf_function(load_source(PLASTIC).ndf, resolution=16, kd=0.1, ks=0.5).save(
        tmp_path / "m.reflecto")
    assert main(["report", str(tmp_path / "m.reflecto"), "--no-render", "-o", str(tmp_path / "rep"), "--json"]) == 0
    assert json_out(capsys)["output"] == str(tmp_path / "rep" / "index.html")


def test_reconstruct_without_the_calibration_its_device_needs(tmp_path, capsys):
    """As-built captures need --calibration (or --nominal); ideal ones do not."""
    assert main(["simulate", str(PLASTIC), "--device", "as-built", "-o", str(tmp_path / "ab"), "-q"]) == 0
    assert main(["reconstruct", str(tmp_path / "ab"), "-o", str(tmp_path / "m.reflecto")]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"reflecto: error: {tmp_path / 'ab'}: captured with device 'as-built'")
    assert "--calibration" in err and "--nominal" in err and "\n" not in err
    assert not list(tmp_path.glob("m*"))
    assert main(["reconstruct", str(tmp_path / "ab"), "--nominal", "--eta", "1.5", "-o", str(tmp_path / "m.reflecto"),
                 "--json"]) == 0
    summary = json_out(capsys)["models"][0]["summary"]
    assert summary["calibration"] == "nominal (--nominal)"
    assert any(n.startswith("read with the nominal calibration of a device that needs") for n in summary["notes"])
    assert main(["simulate", str(PLASTIC), "-o", str(tmp_path / "ideal"), "-q"]) == 0
    assert main(["reconstruct", str(tmp_path / "ideal"), "-o", str(tmp_path / "i.reflecto"), "--json"]) == 0
    summary = json_out(capsys)["models"][0]["summary"]
    assert "calibration" not in summary and not any("nominal calibration" in n for n in summary["notes"])
    with pytest.raises(SystemExit):  # one or the other
        main(["reconstruct", str(tmp_path / "ab"), "--nominal", "--calibration", "x.npz", "-o", "y.reflecto"])


def test_progress_lines_off_a_terminal_and_a_bar_on_one(monkeypatch, capsys):
    from reflecto.batch import Progress, interactive

    monkeypatch.setenv("CI", "true")
    bar = Progress(3, "sweep")
    bar.update("pvc", True, 8.1)
    bar.update("bad", False, 0.2)
    bar.close()
    assert bar.bar is None
    assert capsys.readouterr().err.splitlines() == ["sweep: 1/3 done (pvc, 8.1 s)", "sweep: 2/3 failed (bad)"]

    class Tty:
        def isatty(self):
            return True

        def write(self, s):
            return len(s)

        def flush(self):
            pass

    monkeypatch.setattr(sys, "stderr", Tty())
    assert not interactive()  # CI set: plain lines even on a terminal
    monkeypatch.delenv("CI")
    assert interactive()
    bar = Progress(3, "sweep")
    assert bar.bar is not None  # tqdm
    bar.close()
    assert Progress(3, "sweep", enabled=False).bar is None
