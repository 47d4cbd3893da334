"""Bad command-line input is one line naming the file or the argument, exit status 1,
no traceback and no output left behind — one test per defect of the fuzz campaign
(outputs that replace the user's folders, huge integers, unchecked angles, seeds and
counts, outputs inside inputs, argparse's usage text, libpng's own stderr line, an
implausible calibration scale, untidy messages)."""

from __future__ import annotations

import json
import os
import shutil
import struct
import zipfile
import zlib
from pathlib import Path

import numpy as np
import pytest

from reflecto import io as rio
from reflecto.cli import main
from reflecto.errors import FileFormatError, OutputError, ParameterError
from reflecto.instrument import layout
from reflecto.instrument.calibrate import Calibration, calibrate
from reflecto.instrument.device import Device
from reflecto.instrument.simulate import simulate_calibration, simulate_capture
from reflecto.render import mitsuba
from reflecto.sources.analytic import AnalyticBRDF

ROOT = Path(__file__).resolve().parents[1]
PLASTIC = ROOT / "examples" / "ggx-plastic.json"
HUGE = "1" + "0" * 400  # 10**400: a valid JSON/TOML integer that no float holds


def _run(argv: list[str], capsys) -> tuple[int, str]:
    """Exit status and the one stderr line of a failed command (argparse's errors exit by SystemExit)."""
    try:
        rc = main(argv)
    except SystemExit as e:
        rc = e.code if isinstance(e.code, int) else 1
    lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert rc == 1, (rc, lines)
    assert len(lines) == 1 and lines[0].startswith("reflecto: error: "), lines
    assert "Traceback" not in lines[0]
    return rc, lines[0]


@pytest.fixture(scope="module")
def cap(tmp_path_factory) -> Path:
    """A capture of the ideal device (≈ 1 s)."""
    out = tmp_path_factory.mktemp("cap") / "cap"
    assert main(["simulate", str(PLASTIC), "-o", str(out), "-q"]) == 0
    return out


@pytest.fixture(scope="module")
def model(cap, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("model") / "m.reflecto"
    assert main(["reconstruct", str(cap), "-o", str(out), "-q"]) == 0
    return out


@pytest.fixture(scope="module")
def calib(tmp_path_factory) -> tuple[Path, Path, Path]:
    """A calibration folder of the as-built device, its calibration file and a capture it reads."""
    d = tmp_path_factory.mktemp("calib")
    simulate_calibration(Device.builtin("as-built"), d / "calib", seed=3, white_repeats=1)
    cal = calibrate(d / "calib").save(d / "cal.npz")
    assert main(["simulate", str(PLASTIC), "--device", "as-built", "-o", str(d / "capab"), "-q"]) == 0
    return d / "calib", cal, d / "capab"


def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


def _edit_json(path: Path, fn) -> None:
    d = json.loads(path.read_text())
    fn(d)
    path.write_text(json.dumps(d))


# ------------------------------------------------------------ D1: replacing folders
@pytest.mark.parametrize("command", [["simulate", str(PLASTIC)], ["simulate-calibration", "--device", "ideal"]])
def test_a_folder_of_other_files_is_not_replaced(tmp_path, capsys, command):
    victim = tmp_path / "victim"
    victim.mkdir()
    (victim / "thesis.txt").write_text("years of work")
    _, line = _run([*command, "-o", str(victim), "-q"], capsys)
    assert str(victim) in line and "refusing to replace" in line
    assert sorted(p.name for p in victim.iterdir()) == ["thesis.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["victim"]  # no temporary folder left


def test_an_earlier_output_of_the_same_kind_and_an_empty_folder_are_replaced(tmp_path, cap, capsys):
    again = _copy(cap, tmp_path / "again")
    (again / "stale.png").write_bytes(b"x")  # an earlier capture: replaced as a whole
    assert main(["simulate", str(PLASTIC), "-o", str(again), "-q"]) == 0
    assert (again / "manifest.json").is_file() and not (again / "stale.png").exists()
    (tmp_path / "empty").mkdir()
    assert main(["simulate", str(PLASTIC), "-o", str(tmp_path / "empty"), "-q"]) == 0
    # a capture folder is not a calibration folder: not replaced by one
    _, line = _run(["simulate-calibration", "--device", "ideal", "-o", str(again), "-q"], capsys)
    assert "is a capture folder" in line and "simulate-calibration writes a calibration folder" in line
    assert (again / "manifest.json").is_file()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


@pytest.mark.parametrize("output", [".", ".."])
def test_the_current_folder_and_its_parent_are_refused(tmp_path, capsys, monkeypatch, output):
    work = tmp_path / "work"
    work.mkdir()
    (work / "notes.txt").write_text("keep")
    monkeypatch.chdir(work)
    _, line = _run(["simulate", str(PLASTIC), "-o", output, "-q"], capsys)
    assert "current folder or one of its parents" in line
    assert sorted(p.name for p in work.iterdir()) == ["notes.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["work"]


def test_atomic_folder_refuses_before_and_leaves_the_folder_as_it_was(tmp_path):
    victim = tmp_path / "victim"
    victim.mkdir()
    (victim / "a.txt").write_text("a")
    with pytest.raises(OutputError, match="no manifest.json"), rio.atomic_folder(victim, "manifest.json") as tmp:
        (tmp / "manifest.json").write_text("{}")
    with pytest.raises(OutputError, match="no manifest.json"):
        rio.check_output(victim, folder=True, marker="manifest.json")
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["a.txt", "victim"]


# ------------------------------------------------------------ D2: huge integers
def test_parse_json_refuses_integers_beyond_a_float_and_keeps_large_ones(tmp_path):
    for text, kind in ((f'{{"a": {HUGE}}}', "JSON"), (f'{{"a": [-{HUGE}]}}', "JSON"), (f"a = {HUGE}\n", "TOML"),
                       (f"[t]\na = [1, -{HUGE}]\n", "TOML")):
        with pytest.raises(FileFormatError, match=r"f\.x: the integer .* out of range"):
            rio.parse_json(text, tmp_path / "f.x", kind)
    assert rio.parse_json(f'{{"a": {10**300}, "b": {2**64}}}', "f.json") == {"a": 10**300, "b": 2**64}
    assert rio.parse_json(f"a = {2**63 - 1}\n", "f.toml", "TOML") == {"a": 2**63 - 1}


def _huge_model(model: Path, out: Path) -> Path:
    with zipfile.ZipFile(model) as z:
        members = {n: z.read(n) for n in z.namelist()}
    members["meta.json"] = members["meta.json"].replace(b"{", b'{"huge": ' + HUGE.encode() + b",", 1)
    with zipfile.ZipFile(out, "w", compression=zipfile.ZIP_DEFLATED) as z:
        for n, d in members.items():
            z.writestr(n, d)
    return out


def _huge_calibration(cal: Path, out: Path) -> Path:
    with zipfile.ZipFile(cal) as z:
        members = {n: z.read(n) for n in z.namelist()}
    meta = rio.npy_array(members["meta.npy"], cal, "meta.npy").tobytes()
    meta = meta.replace(b"{", b'{"huge": ' + HUGE.encode() + b",", 1)
    members["meta.npy"] = rio.npy_bytes(np.frombuffer(meta, np.uint8))
    with zipfile.ZipFile(out, "w", compression=zipfile.ZIP_DEFLATED) as z:
        for n, d in members.items():
            z.writestr(n, d)
    return out


def test_huge_integers_in_every_description_are_one_line_naming_the_file(tmp_path, cap, model, calib, capsys):
    calib_dir, cal, capab = calib
    (tmp_path / "a.json").write_text(f'{{"type": "analytic", "alpha": 0.2, "kd": {HUGE}}}')
    (tmp_path / "a.toml").write_text(f'type = "analytic"\nalpha = 0.2\nks = {HUGE}\n')
    (tmp_path / "dev.json").write_text(f'{{"name": "d", "occluder_deg": {HUGE}}}')
    capbig = _copy(cap, tmp_path / "capbig")
    (capbig / "manifest.json").write_text((cap / "manifest.json").read_text().replace(
        '"rotation_deg": 0.0', f'"rotation_deg": {HUGE}'))
    calbig = _copy(calib_dir, tmp_path / "calbig")
    _edit_json(calbig / "calibration.json", lambda m: m.update(version="HUGE"))
    (calbig / "calibration.json").write_text((calbig / "calibration.json").read_text().replace('"HUGE"', HUGE))
    cases = [
        (["info", str(tmp_path / "a.json")], tmp_path / "a.json"),
        (["info", str(tmp_path / "a.toml")], tmp_path / "a.toml"),
        (["layout", "--device", str(tmp_path / "dev.json"), "--resolution", "8"], tmp_path / "dev.json"),
        (["reconstruct", str(capbig), "-o", str(tmp_path / "x.reflecto")], capbig / "manifest.json"),
        (["info", str(_huge_model(model, tmp_path / "h.reflecto"))], tmp_path / "h.reflecto"),
        (["calibrate", str(calbig), "-o", str(tmp_path / "c.npz")], calbig / "calibration.json"),
        (["reconstruct", str(capab), "--calibration", str(_huge_calibration(cal, tmp_path / "h.npz")),
          "-o", str(tmp_path / "y.reflecto")], tmp_path / "h.npz"),
    ]
    for argv, named in cases:
        _, line = _run(argv, capsys)
        assert line.startswith(f"reflecto: error: {named}: the integer 1000"), (argv, line)
        assert "out of range" in line
    assert not (tmp_path / "c.npz").exists() and not (tmp_path / "x.reflecto").exists()


def test_sweep_and_watch_name_the_huge_integer_not_an_internal_error(tmp_path, cap, capsys):
    (tmp_path / "huge.json").write_text(f'{{"type": "analytic", "alpha": 0.2, "kd": {HUGE}}}')
    assert main(["sweep", str(tmp_path / "huge.json"), "-o", str(tmp_path / "sw"), "-q", "--jobs", "1"]) == 1
    err = capsys.readouterr().err
    assert "out of range" in err and "internal error" not in err and "OverflowError" not in err
    root = tmp_path / "root"
    root.mkdir()
    capbig = _copy(cap, root / "capbig")
    (capbig / "manifest.json").write_text((cap / "manifest.json").read_text().replace(
        '"rotation_deg": 0.0', f'"rotation_deg": {HUGE}'))
    assert main(["watch", str(root), "-o", str(tmp_path / "models"), "--once"]) == 1
    err = capsys.readouterr().err
    assert "out of range" in err and "reconstruction failed" not in err and "OverflowError" not in err


def test_an_overflow_no_check_caught_is_still_one_line(tmp_path, capsys, monkeypatch):
    import reflecto.cli as cli

    def overflow(_):
        raise OverflowError("int too large to convert to float")

    monkeypatch.setattr(cli, "load_source", overflow)
    _, line = _run(["info", str(PLASTIC)], capsys)
    assert "out of range" in line and "int too large" in line


# ------------------------------------------------------------ D5–D7, D13: numbers on the command line
@pytest.mark.parametrize("argv, option", [
    (["simulate", str(PLASTIC), "--rotation", "inf"], "--rotation"),
    (["simulate", str(PLASTIC), "--rotation", "nan"], "--rotation"),
    (["simulate", str(PLASTIC), "--tilt", "3", "--tilt-azimuth", "inf"], "--tilt-azimuth"),
    (["simulate", str(PLASTIC), "--tilt", "3", "--tilt-azimuth", "nan"], "--tilt-azimuth"),
    (["simulate", str(PLASTIC), "--seed", "-1"], "--seed"),
    (["simulate-calibration", "--seed", "-1"], "--seed"),
    (["reconstruct", "CAP", "CAP2", "--jobs", "-1"], "--jobs"),
    (["design", "MATS", "--jobs", "-2"], "--jobs"),
    (["gallery", str(PLASTIC), "--seed", "-1"], "--seed"),
])
def test_impossible_numbers_are_refused_naming_the_option(tmp_path, capsys, argv, option):
    out = tmp_path / "out"
    _, line = _run([*argv, "-o", str(out)], capsys)
    assert f"argument {option}" in line and "must be" in line
    assert not out.exists()


@pytest.mark.parametrize("argv, option", [
    (["layout", "--theta-max", "nan"], "--theta-max"),
    (["layout", "--theta-max", "-10"], "--theta-max"),
    (["layout", "--theta-max", "100"], "--theta-max"),
    (["layout", "--theta-max", "inf"], "--theta-max"),
    (["layout", "--optimize", "--seed", "-1"], "--seed"),
    (["watch", "ROOT", "-o", "MODELS", "--settle", "-5"], "--settle"),
    (["render", str(PLASTIC), "--seed", "-1", "-o", "r.png"], "--seed"),
    (["render", str(PLASTIC), "--seed", str(2**32 - 2), "-o", "r.png"], "--seed"),
])
def test_layout_watch_and_render_numbers_are_checked(capsys, argv, option):
    _, line = _run(argv, capsys)
    assert f"argument {option}" in line and "must be" in line


def test_the_library_checks_the_same_numbers(tmp_path):
    src, dev = AnalyticBRDF(), Device.builtin("ideal")
    for kw in (dict(rotation_deg=float("nan")), dict(rotation_deg=float("inf")),
               dict(tilt_deg=3.0, tilt_azimuth_deg=float("nan")), dict(tilt_deg=3.0, tilt_azimuth_deg=float("inf")),
               dict(seed=-1)):
        with pytest.raises(ParameterError):
            simulate_capture(src, dev, **kw)
    with pytest.raises(ParameterError, match="seed"):
        simulate_calibration(dev, tmp_path / "c", seed=-1)
    assert not (tmp_path / "c").exists()
    for theta in (float("nan"), 0.0, -10.0, 100.0, float("inf")):
        with pytest.raises(ParameterError, match="theta_max"):
            layout.coverage(dev.optics, dev.leds, resolution=8, theta_max_deg=theta)
    with pytest.raises(ParameterError, match="seed"):
        layout.optimize_layout(dev.optics, seed=-1)
    for seed in (-1, mitsuba.MAX_SEED + 1):  # compare renders the reference with seed + 1 and + 2
        with pytest.raises(ParameterError, match="seed"):
            mitsuba.compare(src, src, seed=seed)
        with pytest.raises(ParameterError, match="seed"):
            mitsuba.render(src, seed=seed)


# ------------------------------------------------------------ D8: libpng's own message
def test_a_damaged_interlaced_frame_is_reflectos_one_line_only(tmp_path, cap, capfd):
    bad = _copy(cap, tmp_path / "cap_il")

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    from reflecto.instrument.capture import _adam7_bytes

    ihdr = struct.pack(">IIBBBBB", 320, 240, 16, 2, 0, 0, 1)  # 16-bit RGB, Adam7-interlaced
    # the passes' size is right (reflecto's check), their filter bytes are not (libpng's, with its own message)
    data = bytes([9]) * _adam7_bytes(320, 240, 6)
    (bad / "led2_t8ms.png").write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr)
                                        + chunk(b"IDAT", zlib.compress(data)) + chunk(b"IEND", b""))
    assert main(["reconstruct", str(bad), "-o", str(tmp_path / "il.reflecto")]) == 1
    lines = [line for line in capfd.readouterr().err.splitlines() if line.strip()]  # fd 2, not only sys.stderr
    assert lines == [f"reflecto: error: {bad / 'led2_t8ms.png'}: not a readable image (damaged PNG)"], lines
    assert not (tmp_path / "il.reflecto").exists()
    os.write(2, b"after\n")  # fd 2 is restored after the decode
    assert "after" in capfd.readouterr().err


# ------------------------------------------------------------ D9: calibration scale
@pytest.mark.parametrize("factor, words", [(None, "scale field reaches 3e"), (1e-30, "reaches only")])
def test_a_calibration_scale_of_3e38_is_refused_naming_the_file(tmp_path, calib, capsys, factor, words):
    """A scale 10³⁶ times too large (every BRDF black) or 10³⁰ times too small (every BRDF
    a hundred-fold-plus white: k_d 0.999 and tilts of ±43° on a plastic) is refused."""
    _, cal, capab = calib
    with zipfile.ZipFile(cal) as z:
        members = {n: z.read(n) for n in z.namelist()}
    meta = json.loads(rio.npy_array(members["meta.npy"], cal, "meta.npy").tobytes())
    scale = rio.npy_array(members["scale.npy"], cal, "scale.npy")
    members["scale.npy"] = rio.npy_bytes(np.full_like(scale, 3e38) if factor is None else scale * np.float32(factor))
    meta["arrays"]["scale"]["sha256"] = rio.sha256(members["scale.npy"])
    meta["sha256"] = rio.content_digest(meta)  # checksums right: only the values are wrong
    members["meta.npy"] = rio.npy_bytes(np.frombuffer(json.dumps(meta).encode(), np.uint8))
    bright = tmp_path / "bright.npz"
    with zipfile.ZipFile(bright, "w", compression=zipfile.ZIP_DEFLATED) as z:
        for n, d in members.items():
            z.writestr(n, d)
    with pytest.raises(FileFormatError, match=words):
        Calibration.load(bright)
    out = tmp_path / "m.reflecto"
    _, line = _run(["reconstruct", str(capab), "--calibration", str(bright), "-o", str(out)], capsys)
    assert line.startswith(f"reflecto: error: {bright}: LED 0: the scale field") and not out.exists()
    Calibration.load(cal)  # the genuine one is far inside the bound


def test_a_damaged_version_1_calibration_gets_its_error_alone(tmp_path, calib, capsys):
    """A version-1 calibration (no checksum) is read with a warning; one that fails a check
    gets the error alone, one line on the CLI, not the warning first."""
    _, cal, capab = calib
    with zipfile.ZipFile(cal) as z:
        members = {n: z.read(n) for n in z.namelist()}
    meta = json.loads(rio.npy_array(members["meta.npy"], cal, "meta.npy").tobytes())
    v1 = {k: v for k, v in meta.items() if k not in ("arrays", "sha256")}
    v1["version"] = 1

    def written(name: str, scale_factor: float) -> Path:
        m = dict(members, **{"meta.npy": rio.npy_bytes(np.frombuffer(json.dumps(v1).encode(), np.uint8))})
        scale = rio.npy_array(members["scale.npy"], cal, "scale.npy")
        m["scale.npy"] = rio.npy_bytes(scale * np.float32(scale_factor))
        path = tmp_path / name
        with zipfile.ZipFile(path, "w") as z:
            for n, d in m.items():
                z.writestr(n, d)
        return path

    with pytest.warns(UserWarning, match="version 1 has no checksum"):
        Calibration.load(written("v1.npz", 1.0))
    bad = written("v1-nan.npz", float("nan"))
    out = tmp_path / "m.reflecto"
    assert main(["reconstruct", str(capab), "--calibration", str(bad), "-o", str(out)]) == 1
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1 and err[0].startswith(f"reflecto: error: {bad}: ") and not out.exists(), err


# ------------------------------------------------------------ D10–D12: outputs and inputs
def test_sweep_with_a_bad_device_leaves_no_folder(tmp_path, capsys):
    out = tmp_path / "sw"
    _, line = _run(["sweep", str(PLASTIC), "-o", str(out), "--device", "junk", "-q"], capsys)
    assert "junk" in line and not out.exists()


def test_watch_output_inside_the_watched_folder_is_refused(tmp_path, cap, capsys):
    root = tmp_path / "root"
    root.mkdir()
    _copy(cap, root / "cap")
    for models in (root, root / "models", root / "cap" / "models"):
        _, line = _run(["watch", str(root), "-o", str(models), "--once"], capsys)
        assert f"watched folder {root}" in line
    assert sorted(p.name for p in root.iterdir()) == ["cap"] and not (root / "cap" / "models").exists()


def test_outputs_inside_an_input_folder_are_refused(tmp_path, cap, calib, capsys):
    calib_dir = calib[0]
    mine = _copy(cap, tmp_path / "mine")
    before = sorted(p.name for p in mine.iterdir())
    for out in (mine, mine / "m.reflecto"):
        _, line = _run(["reconstruct", str(mine), "-o", str(out)], capsys)
        assert f"capture folder {mine}" in line
    _, line = _run(["reconstruct", str(mine), str(cap), "-o", str(mine)], capsys)
    assert f"capture folder {mine}" in line
    assert sorted(p.name for p in mine.iterdir()) == before
    cal_copy = _copy(calib_dir, tmp_path / "calib")
    _, line = _run(["calibrate", str(cal_copy), "-o", str(cal_copy / "c.npz")], capsys)
    assert f"calibration folder {cal_copy}" in line and not (cal_copy / "c.npz").exists()
    # an output folder that would be replaced must not hold an input
    src = mine / "plastic.json"
    src.write_text(PLASTIC.read_text())
    _, line = _run(["simulate", str(src), "-o", str(mine), "-q"], capsys)
    assert "holds the input" in line and src.is_file()


# ------------------------------------------------------------ D14: argparse
@pytest.mark.parametrize("argv, words", [
    (["reconstruct", "cap", "--normal", "0,0,1,1", "-o", "m.reflecto"], "argument --normal"),
    (["reconstruct", "cap", "-o"], "argument -o/--output: expected one argument"),
    (["simulate"], "required"),
    ([], "required: COMMAND"),
    (["nosuchcommand"], "invalid choice"),
])
def test_argparse_errors_are_one_line_and_status_1(capsys, argv, words):
    _, line = _run(argv, capsys)
    assert words in line and "usage:" not in line and "--help" in line


def test_help_still_shows_the_usage(capsys):
    with pytest.raises(SystemExit) as e:
        main(["simulate", "--help"])
    assert e.value.code == 0 and "usage: reflecto simulate" in capsys.readouterr().out


# ------------------------------------------------------------ D15: tidy messages
def test_an_empty_argument_is_named_not_the_current_folder(tmp_path, capsys):
    for argv, words in ((["simulate", str(PLASTIC), "--device", "", "-o", str(tmp_path / "c")], "simulate --device"),
                        (["layout", "--device", ""], "layout --device"),
                        (["simulate", str(PLASTIC), "-o", ""], "simulate -o"),
                        (["info", ""], "info")):
        _, line = _run(argv, capsys)
        assert line.startswith(f"reflecto: error: {words}: the argument is empty"), line
    assert not (tmp_path / "c").exists()


def test_messages_show_plain_numbers_and_each_path_once(tmp_path, cap, calib, capsys):
    bad = _copy(cap, tmp_path / "led9")
    _edit_json(bad / "manifest.json", lambda m: m["frames"][0].update(led=9))
    _, line = _run(["reconstruct", str(bad), "-o", str(tmp_path / "a.reflecto")], capsys)
    assert "exposures [1, 8] ms" in line and "np." not in line
    (tmp_path / "eta.json").write_text('{"type": "analytic", "eta": 101}')
    _, line = _run(["info", str(tmp_path / "eta.json")], capsys)
    assert line.endswith("eta must lie in [1, 100], got [101, 101, 101]")
    bits = _copy(cap, tmp_path / "bits")
    _edit_json(bits / "manifest.json", lambda m: m["device"]["camera"].update(bits=99))
    _, line = _run(["reconstruct", str(bits), "-o", str(tmp_path / "b.reflecto")], capsys)
    assert line.count("manifest.json") == 1 and "device.camera.bits" in line
    cal_bits = _copy(calib[0], tmp_path / "calbits")
    _edit_json(cal_bits / "calibration.json", lambda m: m["device"]["camera"].update(bits=99))
    _, line = _run(["calibrate", str(cal_bits), "-o", str(tmp_path / "c.npz")], capsys)
    assert line.count("calibration.json") == 1 and "device.camera.bits" in line
    (tmp_path / "dev.toml").write_text('name = "d"\n[camera]\nbits = 99\n')
    _, line = _run(["layout", "--device", str(tmp_path / "dev.toml")], capsys)
    assert line.count("dev.toml") == 1 and "device.camera.bits" in line


def test_a_white_capture_that_is_a_file_and_a_list_asymmetry_are_described_as_they_are(tmp_path, calib, capsys):
    white = _copy(calib[0], tmp_path / "calib")
    shutil.rmtree(white / "white")
    (white / "white").write_text("not a capture")
    _, line = _run(["calibrate", str(white), "-o", str(tmp_path / "c.npz")], capsys)
    assert "must be a folder" in line and "no such directory" not in line
    (tmp_path / "asym.json").write_text('{"type": "analytic", "asymmetry": [0.25, 0.0]}')
    _, line = _run(["info", str(tmp_path / "asym.json")], capsys)
    assert '{"shift": [x, y], "weight": w}' in line


def test_watch_skips_a_damaged_summary_of_an_earlier_model(tmp_path, cap, capsys):
    root, models = tmp_path / "root", tmp_path / "models"
    root.mkdir()
    models.mkdir()
    for name, summary in (("a", "[]"), ("b", f'{{"normal_tilt_deg": {HUGE}}}')):
        _copy(cap, root / name)
        (models / f"{name}.json").write_text(summary)  # a model "done" before, its summary damaged
        (models / f"{name}.reflecto").write_bytes(b"")
    assert main(["watch", str(root), "-o", str(models), "--once"]) == 0
    assert capsys.readouterr().err == ""


# ------------------------------------------------------------ second campaign
def test_an_output_that_names_a_folder_or_nothing_is_refused_before_anything_is_written(tmp_path, cap, model,
                                                                                        capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    for argv, words in ((["export", str(model), "-o", "."], ". is a folder; export writes"),
                        (["export", str(model), "-o", "/"], "/ is a folder; export writes"),
                        (["tabulate", str(PLASTIC), "-o", ".."], ".. is a folder; tabulate writes"),
                        (["render", str(model), "-o", "."], ". is a folder; render writes"),
                        (["export", str(model), "-o", " "], "export -o: the argument is empty"),
                        (["reconstruct", str(cap), "-o", ""], "reconstruct -o: the argument is empty"),
                        (["watch", str(cap.parent), "-o", "", "--once"], "watch -o: the argument is empty"),
                        (["layout", "--plot", ""], "layout --plot: the argument is empty")):
        _, line = _run(argv, capsys)
        assert line.startswith(f"reflecto: error: {words}"), line
    assert list(tmp_path.iterdir()) == []


def test_a_samples_count_beyond_the_renderers_range_is_refused(tmp_path, model, capsys):
    for argv in (["render", str(model), "--spp", "4294967295", "--resolution", "8", "-o", str(tmp_path / "s.png")],
                 ["report", str(model), "-o", str(tmp_path / "rep"), "--spp", "1000000000000"]):
        _, line = _run(argv, capsys)
        assert f"spp must be in [1, {mitsuba.MAX_SPP}]" in line
    assert list(tmp_path.iterdir()) == []


def test_an_unreadable_environment_map_is_one_line_without_decoder_noise(tmp_path, model, capfd):
    (tmp_path / "e.hdr").write_bytes(b"#?RADIANCE\ngarbage\n")
    rc = main(["render", str(model), "--spp", "4", "--resolution", "32", "--envmap", str(tmp_path / "e.hdr"),
               "-o", str(tmp_path / "e.png")])
    lines = [line for line in capfd.readouterr().err.splitlines() if line.strip()]
    assert rc == 1 and len(lines) == 1, lines
    assert "e.hdr: unreadable environment map" in lines[0] and not (tmp_path / "e.png").exists()


def test_a_bad_calibration_is_named_once_before_any_capture_or_output(tmp_path, cap, capsys):
    root = tmp_path / "root"
    for name in ("a", "b"):
        _copy(cap, root / name)
    (tmp_path / "bad.npz").write_text("x")
    for argv in (["watch", str(root), "-o", str(tmp_path / "models"), "--once", "--calibration",
                  str(tmp_path / "bad.npz")],
                 ["reconstruct", str(root / "a"), str(root / "b"), "--calibration", str(tmp_path / "bad.npz"),
                  "-o", str(tmp_path / "multi"), "--jobs", "1", "-q"]):
        _, line = _run(argv, capsys)
        assert "bad.npz: not a zip archive" in line
    assert not (tmp_path / "models").exists() and not (tmp_path / "multi").exists()


def test_a_model_file_with_an_unknown_fresnel_form_is_refused(tmp_path, model, capsys):
    with zipfile.ZipFile(model) as z:
        members = {n: z.read(n) for n in z.namelist()}
    for form, words in (("foo", "'fresnel' must be \"dielectric\" or \"constant\""),
                        ("constant", "a constant Fresnel lobe has no η")):
        meta = json.loads(members["meta.json"])
        meta["fresnel"] = form
        meta.pop("sha256")
        meta["sha256"] = rio.content_digest(meta)
        bad = tmp_path / f"{form}.reflecto"
        with zipfile.ZipFile(bad, "w") as z:
            for n, b in members.items():
                z.writestr(n, json.dumps(meta).encode() if n == "meta.json" else b)
        _, line = _run(["info", str(bad)], capsys)
        assert line.startswith(f"reflecto: error: {bad}: invalid model parameters") and words in line, line


def test_exposure_times_the_frames_contradict_are_refused(tmp_path, cap, capsys):
    """A manifest's exposure time sets the radiance scale: one written wrongly (1e-300 ms,
    or both exposures labelled ≈ 1 ms) is not the camera's times shortened by one factor;
    frames swapped between the exposures are caught by their own brightness ratio."""
    for name, new in (("tiny", "1e-300"), ("same", "1.0000000000000002")):
        bad = _copy(cap, tmp_path / name)
        text = (bad / "manifest.json").read_text()
        assert '"exposure_ms": 8.0' in text
        (bad / "manifest.json").write_text(text.replace('"exposure_ms": 8.0', f'"exposure_ms": {new}'))
        _, line = _run(["reconstruct", str(bad), "-o", str(tmp_path / f"{name}.reflecto")], capsys)
        assert "manifest.json: exposure times" in line and "shortened by one factor" in line, line
        assert not (tmp_path / f"{name}.reflecto").exists()
    bad = _copy(cap, tmp_path / "swapped")
    frames = json.loads((bad / "manifest.json").read_text())["frames"]
    short, long_ = (next(f["file"] for f in frames if f["led"] == 2 and f["exposure_ms"] == t and not f.get("check"))
                    for t in (1.0, 8.0))
    os.replace(bad / short, bad / "tmp.png")
    os.replace(bad / long_, bad / short)
    os.replace(bad / "tmp.png", bad / long_)
    _, line = _run(["reconstruct", str(bad), "-o", str(tmp_path / "swapped.reflecto")], capsys)
    assert f"{bad}: LED 2: its 8 ms frame reads" in line and "the manifest's exposure times say 8×" in line, line


@pytest.mark.parametrize("suffix", [".bsdf", ".reflecto"])
def test_an_output_name_longer_than_the_system_allows_is_one_line(tmp_path, model, cap, capsys, suffix):
    """A 300-byte file name in an existing folder: one line naming it, nothing created."""
    out = tmp_path / ("a" * 300 + suffix)
    argv = (["export", str(model), "-o", str(out), "-q"] if suffix == ".bsdf"
            else ["reconstruct", str(cap), "-o", str(out), "-q"])
    _, line = _run(argv, capsys)
    assert "a" * 300 in line and "too long" in line.lower()
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("suffix", [".bsdf", ".reflecto", ".npz"])
def test_a_file_output_named_as_a_folder_is_refused(tmp_path, model, cap, calib, capsys, suffix):
    """``-o m.bsdf/`` names a folder (the separator is the user's), where the command writes one file."""
    out = str(tmp_path / f"m{suffix}") + "/"
    argv = {".bsdf": ["export", str(model), "-o", out, "-q"],
            ".reflecto": ["reconstruct", str(cap), "-o", out, "-q"],
            ".npz": ["calibrate", str(calib[0]), "-o", out, "-q"]}[suffix]
    _, line = _run(argv, capsys)
    assert "a folder" in line and f"m{suffix}" in line
    assert list(tmp_path.iterdir()) == []


def test_a_summary_that_cannot_be_written_leaves_no_model(tmp_path, cap, capsys):
    """``reconstruct -o m.reflecto`` where ``m.json`` is a folder: refused in one line before the
    work, and no model file left without its summary."""
    (tmp_path / "m.json").mkdir()
    _, line = _run(["reconstruct", str(cap), "-o", str(tmp_path / "m.reflecto"), "-q"], capsys)
    assert "m.json: is a folder" in line
    assert not (tmp_path / "m.reflecto").exists()


def test_a_capture_given_as_dot_names_its_model_after_the_folder(tmp_path, cap, capsys, monkeypatch):
    """``reconstruct . -o FOLDER`` from inside a capture writes ``FOLDER/<capture>.reflecto``, not a hidden
    ``.reflecto``; the file system's root has no name to give and is refused in one line."""
    monkeypatch.chdir(cap)
    assert main(["reconstruct", ".", "-o", str(tmp_path / "models"), "-q"]) == 0
    assert sorted(p.name for p in (tmp_path / "models").iterdir()) == [f"{cap.name}.json", f"{cap.name}.reflecto"]
    _, line = _run(["reconstruct", "/", str(cap), "-o", str(tmp_path / "more"), "-q"], capsys)
    assert "has no name to give its model" in line


def test_a_negative_length_in_an_npy_header_is_a_damaged_file(tmp_path):
    """An ``.npy`` header whose shape has a negative length (with the same element count as its
    data) is refused as damaged, naming the file and the member, not by NumPy's reshape."""
    good = rio.npy_bytes(np.zeros((2, 4)))
    bad = good.replace(b"(2, 4), }", b"(-2,-4),}")  # the header keeps its length
    assert len(bad) == len(good) and bad != good
    with pytest.raises(FileFormatError, match=r"x\.npz: meta\.npy: damaged \.npy header \(shape \(-2, -4\)"):
        rio.npy_array(bad, tmp_path / "x.npz", "meta.npy")


def test_an_rgl_export_of_eta_one_has_no_specular_part(tmp_path, capsys):
    """η = 1 (no interface: F ≡ 0) is inside the model's range: the export is written, and what
    it holds is the diffuse term alone."""
    src = tmp_path / "eta1.json"
    src.write_text(json.dumps({"type": "analytic", "alpha": 0.2, "kd": 0.5, "ks": 0.5, "eta": 1}))
    out = tmp_path / "eta1.bsdf"
    assert main(["export", str(src), "-o", str(out), "-q"]) == 0
    from reflecto.sources import RGLBRDF

    i = np.array([[0.3, 0.1, np.sqrt(0.9)], [0.0, 0.0, 1.0]])
    o = np.array([[-0.3, -0.1, np.sqrt(0.9)], [0.5, 0.0, np.sqrt(0.75)]])
    assert np.allclose(RGLBRDF(out).eval(i, o), 0.5 / np.pi, rtol=0.02)


def test_a_merl_table_without_back_scattering_is_one_line_for_the_rgl_export(tmp_path, capsys):
    """A MERL table whose θ_d = 0 bins are unmeasured (−1) has no back-scattering to estimate the
    RGL tables' NDF from: one line naming the file, no output."""
    from reflecto.sources import merl

    lamb = tmp_path / "lamb.json"
    lamb.write_text(json.dumps({"type": "analytic", "alpha": 0.3, "kd": 0.5, "ks": 0.2}))
    table = tmp_path / "t.binary"
    assert main(["export", str(lamb), "-o", str(table), "-q"]) == 0
    t = merl.read_merl_table(table).copy()
    t[:, 0, :, :] = -1.0  # every φ_d of the θ_d = 0 bins
    merl.write_merl_table(tmp_path / "retro.binary", t)
    _, line = _run(["export", str(tmp_path / "retro.binary"), "-o", str(tmp_path / "r.bsdf")], capsys)
    assert "retro.binary: no positive NDF or back-scattering" in line
    assert not (tmp_path / "r.bsdf").exists()


def test_export_refuses_to_replace_its_input_and_never_hints_at_it(tmp_path, capsys):
    """``export X.bsdf -o X.bsdf`` would replace the file being read with a resampled copy; a
    MERL export of an anisotropic ``X.bsdf`` hints at another RGL name than ``X.bsdf``."""
    model = tmp_path / "an.json"
    model.write_text(json.dumps({"type": "analytic", "alpha": [0.3, 0.08], "kd": 0.2, "ks": 0.5}))
    rgl = tmp_path / "an.bsdf"
    assert main(["export", str(model), "-o", str(rgl), "-q"]) == 0
    before = rgl.read_bytes()
    _, line = _run(["export", str(rgl), "-o", str(rgl)], capsys)
    assert "is the file being exported" in line and rgl.read_bytes() == before
    _, line = _run(["export", str(rgl), "-o", str(tmp_path / "an.binary")], capsys)
    assert "an-anisotropic.bsdf" in line and f"-o {rgl} " not in line


def test_a_file_name_that_is_not_utf8_and_a_description_with_escapes(tmp_path, capsys):
    """A source whose name is not valid UTF-8 exports (its name escaped in the file's description),
    and ``info`` writes the description's newlines and terminal escapes as escapes."""
    name = os.fsdecode(b"bad\xffname.json")
    (tmp_path / name).write_text(json.dumps({"type": "analytic", "alpha": 0.2, "kd": 0.3, "ks": 0.4}))
    out = tmp_path / "bn.bsdf"
    assert main(["export", str(tmp_path / name), "-o", str(out), "-q"]) == 0
    from reflecto.export.rgl import write_tensor_file
    from reflecto.sources.rgl import read_tensor_file

    f = {k: np.array(v) for k, v in read_tensor_file(out).items()}
    assert b"bad\\udcffname" in f["description"].tobytes()
    f["description"] = np.frombuffer(b"paper\n  kind        merl\x1b[31m", np.uint8).copy()
    write_tensor_file(tmp_path / "desc.bsdf", f)
    capsys.readouterr()
    assert main(["info", str(tmp_path / "desc.bsdf")]) == 0
    out_lines = capsys.readouterr().out.splitlines()
    assert any(x.startswith("  description paper\\n  kind        merl\\x1b[31m") for x in out_lines)
    assert not any(x.startswith("  kind        merl") for x in out_lines) and "\x1b" not in "".join(out_lines)


def test_output_names_that_are_not_utf8_and_unreadable_seeds(tmp_path, capsys):
    """``simulate -o`` with a name of bytes that are not UTF-8 writes its capture (OpenCV's writer
    crashed the process on it), and a seed no manifest could hold is refused up front."""
    out = tmp_path / os.fsdecode(b"cap\xff")
    assert main(["simulate", str(PLASTIC), "-o", str(out), "-q"]) == 0
    from reflecto.instrument.capture import read_capture

    assert read_capture(out).raw.shape[0] == 6
    assert [p.name for p in tmp_path.iterdir()] == [out.name]  # no temporary folder left
    _, line = _run(["simulate", str(PLASTIC), "--seed", str(10**400), "-o", str(tmp_path / "big")], capsys)
    assert "--seed" in line and not (tmp_path / "big").exists()


def test_model_files_save_only_what_load_reads(tmp_path):
    """``save`` refuses a model that ``load`` would refuse (too many tint nodes, a sample-normal
    entry out of range, metadata nested too deep or with an integer no float holds), and a
    hostile dtype in a model's array table is one line naming the file."""
    import zipfile

    from reflecto.io import content_digest
    from reflecto.model import IsotropicMicrofacetBRDF, load_model

    nodes = np.radians(np.linspace(0, 90, 92))
    d = np.exp(-(np.tan(np.minimum(nodes, 1.5)) / 0.2) ** 2)
    for kwargs, words in (({"tint": (np.linspace(0.1, 1.4, 1100), np.ones((1100, 3)))}, "tint_theta nodes"),
                          ({"metadata": {"normal_tilt_deg": 95}}, "not a valid sample normal entry"),
                          ({"metadata": {"deep": json.loads("[" * 70 + "]" * 70)}}, "nested deeper"),
                          ({"metadata": {"big": 10**400}}, "out of range")):
        m = IsotropicMicrofacetBRDF((nodes, d), kd=0.2, ks=0.5, eta=1.5, **kwargs)
        with pytest.raises(ParameterError, match=words):
            m.save(tmp_path / "m.reflecto")
        assert not (tmp_path / "m.reflecto").exists()
    good = IsotropicMicrofacetBRDF((nodes, d), kd=0.2, ks=0.5, eta=1.5).save(tmp_path / "g.reflecto")
    with zipfile.ZipFile(good) as z:
        members = {n: z.read(n) for n in z.namelist()}
    meta = json.loads(members["meta.json"])
    meta["arrays"]["ndf"]["dtype"] = "f4,f4,,"
    meta.pop("sha256")
    meta["sha256"] = content_digest(meta)
    members["meta.json"] = json.dumps(meta).encode()
    with zipfile.ZipFile(tmp_path / "d.reflecto", "w") as z:
        for n, b in members.items():
            z.writestr(n, b)
    with pytest.raises(FileFormatError, match="invalid dtype"):
        load_model(tmp_path / "d.reflecto")


def test_info_json_is_strict_and_a_set_summary_is_named(tmp_path, capsys):
    """``info --json`` writes a model's non-finite metadata as null (strict JSON), and names the
    summary of a §5.5 set as a summary, not as a broken analytic description."""
    from reflecto.model import IsotropicMicrofacetBRDF

    nodes = np.radians(np.linspace(0, 90, 92))
    m = IsotropicMicrofacetBRDF((nodes, np.exp(-(np.tan(np.minimum(nodes, 1.5)) / 0.2) ** 2)), kd=0.2, ks=0.5, eta=1.5,
                                metadata={"score": float("nan")})
    path = m.save(tmp_path / "m.reflecto")
    assert main(["info", str(path), "--json"]) == 0
    out = capsys.readouterr().out
    assert json.loads(out, parse_constant=lambda c: pytest.fail(f"non-standard JSON {c}")) is not None
    (tmp_path / "set.json").write_text(json.dumps({"asymmetric": True, "rotations_deg": [0, 90], "kd": [0.1] * 3,
                                                   "ks": [0.5] * 3, "shake_detected": False}))
    from reflecto.kinds import identify

    assert identify(tmp_path / "set.json").name == "summary"


def test_simulate_does_not_write_into_a_calibration_folder(tmp_path, calib, capsys):
    """``simulate -o CAL/white`` would replace a calibration folder's white-standard capture with a
    sample capture (a folder with a manifest counts as replaceable): refused in one line, the
    white capture untouched."""
    calib_dir = calib[0]
    before = (calib_dir / "white" / "manifest.json").read_bytes()
    _, line = _run(["simulate", str(PLASTIC), "-o", str(calib_dir / "white")], capsys)
    assert "lies in the calibration folder" in line
    assert (calib_dir / "white" / "manifest.json").read_bytes() == before


def test_an_output_name_near_the_file_systems_limit_is_written(tmp_path):
    """A 250-byte output name fits the file system's 255, but its temporary name (a dot, 8
    random characters and the suffix added) did not: "File name too long". Multi-byte names
    are cut on a character's boundary, so that writers taking text accept the temporary name."""
    import os

    from reflecto.io import atomic_path, atomic_write

    for name in ("x" * 250 + ".png", "é" * 124 + ".png"):
        with atomic_write(tmp_path / name) as fh:
            fh.write(b"data")
        assert (tmp_path / name).read_bytes() == b"data"
    with atomic_path(tmp_path / ("é" * 124 + ".exr"), suffix=".exr") as tmp:
        os.fsencode(tmp.name).decode("utf-8")  # a name of whole characters
        assert len(os.fsencode(tmp.name)) <= 255
        tmp.write_bytes(b"x")
    assert sorted(len(os.fsencode(p.name)) for p in tmp_path.iterdir()) == [252, 252, 254]


def test_a_full_disk_names_the_output_it_could_not_write(tmp_path):
    """A full disk (ENOSPC) while an output is written said only "No space left on device":
    the error names the output, and nothing is left behind. An OSError of another kind raised
    by the writer's own code goes on as it is."""
    import errno

    from reflecto.io import atomic_folder, atomic_path, atomic_write

    out = tmp_path / "sub" / "m.bin"
    with pytest.raises(OutputError, match=r"m\.bin: cannot write: No space left on device"):
        with atomic_write(out) as fh:
            fh.write(b"data")
            raise OSError(errno.ENOSPC, "No space left on device")
    with pytest.raises(OutputError, match=r"m\.bin: cannot write: Disk quota exceeded"):
        with atomic_path(out):
            raise OSError(errno.EDQUOT, "Disk quota exceeded")
    with pytest.raises(FileNotFoundError):
        with atomic_write(out):
            raise FileNotFoundError(errno.ENOENT, "an input the writer reads")
    folder = tmp_path / "rep"
    # the final name, not the temporary folder's
    with pytest.raises(OutputError, match=r"rep/a\.png: cannot write: No space left"):
        with atomic_folder(folder, "index.html") as d, atomic_write(d / "a.png"):
            raise OSError(errno.ENOSPC, "No space left on device")
    with pytest.raises(OutputError, match=r"rep: cannot write: No space left"):  # a writer of its own
        with atomic_folder(folder, "index.html"):
            raise OSError(errno.ENOSPC, "No space left on device")
    assert list(tmp_path.iterdir()) == []
