"""The malformed inputs of issue 39, each refused with one line (or, for a legitimate
capture, a result without an internal error), and the physical bound every reader and
writer applies (reflecto.brdf.MAX_PROJECTED_BRDF)."""

import json
import shutil
import struct
import sys
from pathlib import Path

import numpy as np
import pytest

from reflecto import brdf
from reflecto.cli import main
from reflecto.errors import FileFormatError, ParameterError
from reflecto.sources import merl
from reflecto.sources.analytic import AnalyticBRDF

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from _fake_sweep import fake_run_material  # noqa: E402

PLASTIC = ROOT / "examples" / "ggx-plastic.json"


def _err(capsys) -> str:
    err = capsys.readouterr().err
    lines = [l for l in err.splitlines() if l.startswith("reflecto: error:")]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def test_projected_bound_is_one_over_4_pi_alpha_squared():
    assert brdf.MAX_PROJECTED_BRDF == pytest.approx(1 / (4 * np.pi * 1e-6))
    assert round(brdf.MAX_PROJECTED_BRDF) == 79577


# ------------------------------------------------------------------ RGL: one damaged value
def _field_offsets(raw: bytes) -> dict[str, int]:
    pos, offs = 18, {}
    for _ in range(struct.unpack_from("<I", raw, 14)[0]):
        (n,) = struct.unpack_from("<H", raw, pos)
        name = raw[pos + 2 : pos + 2 + n].decode()
        pos += 2 + n
        nd, _, off = struct.unpack_from("<HBQ", raw, pos)
        pos += 11 + 8 * nd
        offs[name] = off
    return offs


@pytest.mark.parametrize("field, cell, bit, peak", [("sigma", 108, 4, "5.45e+08"), ("ndf", 5, 6, "5.62e+37")])
def test_rgl_with_one_flipped_byte_is_refused_by_tabulate_export_and_info(shared, tmp_path, capsys, field, cell, bit,
                                                                          peak):
    """One flipped exponent bit in a table the plugin divides by or multiplies with: the
    4096 plausibility pairs miss it, the table's own nodes do not."""
    raw = bytearray((shared / "rgl" / "paper_white_rgb.bsdf").read_bytes())
    raw[_field_offsets(bytes(raw))[field] + 4 * cell + 3] ^= 1 << bit
    bad = tmp_path / "flipped.bsdf"
    bad.write_bytes(bytes(raw))
    for argv in (["tabulate", str(bad), "-o", str(tmp_path / "t.binary")],
                 ["export", str(bad), "-o", str(tmp_path / "e.bsdf")], ["info", str(bad)]):
        assert main(argv) == 1
        err = _err(capsys)
        assert f"flipped.bsdf: its tables: f·cos θ_i·cos θ_o reaches {peak} sr⁻¹, more than any BRDF reflecto " \
               "represents (7.96e+04 = 1/(4π α²) at α = 0.001" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["flipped.bsdf"]


@pytest.mark.parametrize("value, refused", [(1e9, True), (100.0, False)])
def test_a_damaged_node_of_a_large_ndf_table_is_found_by_its_bound(tmp_path, value, refused):
    """Tables of more than 2¹⁶ (sigma, ndf) node pairs: an ``ndf`` node is evaluated where
    ``max|rgb| · D / (4 min σ)`` could exceed the bound; a node below it is not, and cannot."""
    from reflecto.export.rgl import export_rgl, write_tensor_file
    from reflecto.sources.rgl import RGLBRDF, Marginal2D, read_tensor_file

    good = export_rgl(AnalyticBRDF(distribution="ggx", alpha=0.2, kd=0.3, ks=0.5, eta=1.5), tmp_path / "good.bsdf")
    fields = {k: np.array(v) for k, v in read_tensor_file(good).items()}
    assert fields["sigma"].size * fields["ndf"].size > 1 << 16
    node = (1, 1500)  # a half vector 12° from the normal
    fields["ndf"][node] = value
    # the nodes the check visits under 8 incident directions: the damaged one only where it could exceed the bound
    src = RGLBRDF(good)
    assert len(src._ndf_nodes_at_risk()) == 0
    one = np.zeros(1)
    src._ndf = Marginal2D(fields["ndf"][None, None].astype(np.float64), one, one, build_cdf=False)
    assert list(src._ndf_nodes_at_risk()) == ([node[0] * fields["ndf"].shape[1] + node[1]] if refused else [])
    bad = write_tensor_file(tmp_path / "node.bsdf", fields)
    if refused:
        with pytest.raises(FileFormatError, match=r"node\.bsdf: its tables: f·cos θ_i·cos θ_o reaches"):
            RGLBRDF(bad)
    else:
        assert RGLBRDF(bad).projected_at_nodes().max() < brdf.MAX_PROJECTED_BRDF


def test_a_small_ndf_table_beside_a_large_sigma_table_is_read(tmp_path):
    """Fewer than 32 ``ndf`` nodes in a table of more than 2¹⁶ node pairs: all are the densest."""
    from reflecto.export.rgl import export_rgl, write_tensor_file
    from reflecto.sources.rgl import RGLBRDF, read_tensor_file

    good = export_rgl(AnalyticBRDF(distribution="ggx", alpha=0.2, kd=0.3, ks=0.5, eta=1.5), tmp_path / "good.bsdf")
    fields = {k: np.array(v) for k, v in read_tensor_file(good).items()}
    fields["ndf"] = np.full((3, 3), fields["ndf"].mean(), dtype=np.float32)
    fields["sigma"] = np.repeat(fields["sigma"], 16, axis=1)  # 2 × 4096: 9 × 8192 pairs
    src = RGLBRDF(write_tensor_file(tmp_path / "small.bsdf", fields))
    rng = np.random.default_rng(0)
    d = rng.normal(size=(2, 64, 3))
    d[..., 2] = np.abs(d[..., 2]) + 0.2
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    f = src.eval(d[0], d[1])
    assert f.shape == (64, 3) and np.all(np.isfinite(f)) and np.all(f >= 0) and f.max() > 0


def test_every_shared_rgl_file_passes_its_table_checks(shared):
    from reflecto.sources.rgl import RGLBRDF

    files = sorted((shared / "rgl").glob("*.bsdf"))
    assert len(files) >= 10
    for p in files:
        s = RGLBRDF(p)
        assert s.projected_at_nodes().max() < 600  # chm_mint 560: two decades under the bound
        steep = s.theta_i <= np.radians(60)
        # the tables' own albedo agrees with the half-vector quadrature within 0.08 up to 60° (chm_mint: 0.063)
        assert np.abs(s.slice_albedo()[steep] - s.albedo(np.degrees(s.theta_i[steep]))).max() < 0.08


# ------------------------------------------------------------------ MERL: grazing values are physics
def test_merl_grazing_values_of_reconstructions_read_and_a_spike_does_not(tmp_path):
    table = np.full(merl.SHAPE + (3,), 0.1)
    table[0, 89, 90] = 6.23e6  # θ_h ≈ 0, θ_d = 89.5°: f·cosθ_i·cosθ_o ≈ 474 sr⁻¹
    merl.write_merl_table(tmp_path / "grazing.binary", table)
    assert merl.read_merl_table(tmp_path / "grazing.binary")[0, 89, 90, 0] == 6.23e6
    table[0, 0, 90] = 1e6  # at normal incidence: f·cosθ_i·cosθ_o ≈ 10⁶
    with pytest.raises(FileFormatError, match="the table to write: f·cos θ_i·cos θ_o reaches 1e\\+06"):
        merl.write_merl_table(tmp_path / "spike.binary", table)
    assert not (tmp_path / "spike.binary").exists()


# ------------------------------------------------------------------ analytic asymmetry shift
def test_asymmetry_shift_out_of_range_is_refused_by_info(tmp_path, capsys):
    bad = tmp_path / "asym.toml"
    bad.write_text('type = "analytic"\ndistribution = "ggx"\nalpha = 0.2\nkd = 0.2\nks = 0.5\n'
                   "asymmetry = { shift = [40.0, 0.0], weight = 0.3 }\n")
    assert main(["info", str(bad)]) == 1
    assert "asym.toml: asymmetry shift [40.0, 0.0] with weight 0.3 centres a lobe at a facet tilt of 88.6°, more " \
           "than 60°" in _err(capsys)
    # the opposite lobe counts too: shift 0.8 at weight 0.75 puts it at slope 2.4 (67°)
    with pytest.raises(ParameterError, match="facet tilt of 67.4°"):
        AnalyticBRDF(asymmetry=(0.8, 0.0, 0.75))
    AnalyticBRDF(asymmetry=(0.25, 0.0, 0.3))  # the examples' shifts read


# ------------------------------------------------------------------ calibration with dark grid frames
@pytest.mark.slow
def test_calibration_with_all_black_grid_frames_is_one_line(tmp_path, capsys):
    from reflecto.instrument.capture import _write_png
    from reflecto.instrument.device import Device
    from reflecto.instrument.simulate import simulate_calibration

    simulate_calibration(Device.builtin("as-built"), tmp_path / "calib", seed=3, white_repeats=1)
    for p in (tmp_path / "calib").glob("grid_*.png"):
        _write_png(p, np.zeros((240, 320, 3), np.uint16))
    assert main(["calibrate", str(tmp_path / "calib"), "-o", str(tmp_path / "cal.npz")]) == 1
    assert "calibration.json: geometric calibration failed: no pinhole spot in any grid image" in _err(capsys)
    assert not (tmp_path / "cal.npz").exists()


# ------------------------------------------------------------------ a capture of pure noise
def test_capture_of_pure_noise_is_refused_by_its_exposures_without_an_internal_error(tmp_path, capsys):
    """Frames of uniform noise read the same in both exposures: they contradict the
    manifest's 8:1 exposure times, which is one line naming the capture, no model."""
    from reflecto.instrument.capture import _write_png

    assert main(["simulate", str(PLASTIC), "-o", str(tmp_path / "cap"), "-q"]) == 0
    rng = np.random.default_rng(0)
    for p in (tmp_path / "cap").glob("*.png"):
        _write_png(p, rng.integers(100, 4000, (240, 320, 3)).astype(np.uint16))  # above the black level
    rc = main(["reconstruct", str(tmp_path / "cap"), "-o", str(tmp_path / "m.reflecto"), "--json"])
    lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert rc == 1 and len(lines) == 1, lines
    assert "cap: LED 0: its 8 ms frame reads 0.9" in lines[0] and "say 8×" in lines[0], lines
    assert not (tmp_path / "m.reflecto").exists()


# ------------------------------------------------------------------ sweep records
@pytest.fixture
def fake_sweep(monkeypatch):
    import importlib

    sweep_mod = importlib.import_module("reflecto.evaluate.sweep")  # the module, not the re-exported function
    monkeypatch.setattr(sweep_mod, "run_material", fake_run_material)


@pytest.mark.parametrize("record", ["{}", "[]", '{"name": "m0"}'])
def test_sweep_resume_records_that_are_not_results_are_redone(tmp_path, fake_sweep, capsys, record):
    (tmp_path / "mats").mkdir()
    (tmp_path / "mats" / "m0.json").write_text(json.dumps({"type": "analytic", "alpha": 0.2, "kd": 0.2, "ks": 0.5}))
    out = tmp_path / "res"
    assert main(["sweep", str(tmp_path / "mats"), "-o", str(out), "--jobs", "1", "-q"]) == 0
    (out / "materials" / "m0.json").write_text(record)
    assert main(["sweep", str(tmp_path / "mats"), "-o", str(out), "--jobs", "1", "--json"]) == 0
    captured = capsys.readouterr()
    assert "damaged result record" in captured.err and "the material is evaluated again" in captured.err
    assert json.loads(captured.out)["all"]["materials"] == 1
    assert json.loads((out / "materials" / "m0.json").read_text())["name"] == "m0"


def test_sweep_record_path_that_is_a_folder_names_the_material(tmp_path, fake_sweep, capsys):
    (tmp_path / "mats").mkdir()
    for k in range(2):
        (tmp_path / "mats" / f"m{k}.json").write_text(json.dumps({"type": "analytic", "alpha": 0.2 + 0.1 * k,
                                                                  "kd": 0.2, "ks": 0.5}))
    out = tmp_path / "res"
    (out / "materials" / "m0.json").mkdir(parents=True)
    assert main(["sweep", str(tmp_path / "mats"), "-o", str(out), "--jobs", "1", "-q"]) == 1
    err = _err(capsys)
    assert err == (f"reflecto: error: {tmp_path / 'mats' / 'm0.json'}: "
                   f"its result record {out / 'materials' / 'm0.json'} "
                   "is a folder; remove it (or choose another -o) to evaluate this material")
    assert (out / "materials" / "m1.json").is_file()  # the other material finished
    shutil.rmtree(out)


# ------------------------------------------------------------------ what reflecto writes, reflecto reads
@pytest.mark.slow
@pytest.mark.parametrize("material", ["examples/ggx-plastic.json", "rgl/chm_mint_rgb.bsdf"])
def test_round_trip_of_a_reconstruction(tmp_path, capsys, shared, material):
    """Capture → model + summary → .bsdf and .binary → each read back by `info`; a
    calibration file read back by `reconstruct` (studies/roundtrip.py: all 50)."""
    src = ROOT / material if material.startswith("examples") else shared / material
    assert main(["simulate", str(src), "-o", str(tmp_path / "cap"), "-q"]) == 0
    assert main(["simulate-calibration", "--device", "ideal", "-o", str(tmp_path / "calib"), "-q"]) == 0
    assert main(["calibrate", str(tmp_path / "calib"), "-o", str(tmp_path / "cal.npz"), "-q"]) == 0
    assert main(["reconstruct", str(tmp_path / "cap"), "--calibration", str(tmp_path / "cal.npz"),
                 "-o", str(tmp_path / "m.reflecto"), "-q"]) == 0
    assert main(["export", str(tmp_path / "m.reflecto"), "-o", str(tmp_path / "m.bsdf"), "-q"]) == 0
    assert main(["export", str(tmp_path / "m.reflecto"), "--isotropic", "yes", "-o", str(tmp_path / "m.binary"),
                 "-q"]) == 0
    capsys.readouterr()
    kinds_read = {}
    for name in ("m.reflecto", "m.bsdf", "m.binary"):
        assert main(["info", str(tmp_path / name), "--json"]) == 0, capsys.readouterr().err
        kinds_read[name] = json.loads(capsys.readouterr().out)["kind"]
    assert kinds_read == {"m.reflecto": "model", "m.bsdf": "rgl", "m.binary": "merl"}
    summary = json.loads((tmp_path / "m.json").read_text())
    assert summary["calibration"].endswith("cal.npz") and summary["kd"]
    t = merl.read_merl_table(tmp_path / "m.binary")
    assert (np.maximum(t, 0) * merl._cos_cos()[..., None]).max() < brdf.MAX_PROJECTED_BRDF / 100


def test_a_black_reference_has_no_normalized_error(tmp_path, capsys):
    """Eq. 10's error is normalized by the reference's largest albedo: a black reference gets one
    line, not a number of 10¹⁰ %."""
    black = tmp_path / "black.json"
    black.write_text(json.dumps({"type": "analytic", "distribution": "ggx", "alpha": 0.15, "kd": [0, 0, 0],
                                 "ks": 0, "eta": 1.5}))
    assert main(["compare", str(black), str(PLASTIC)]) == 1
    assert "the reference black reflects (almost) nothing" in _err(capsys)
    assert main(["compare", str(PLASTIC), str(black)]) == 0  # a black test against a real reference: its error


def test_a_resumed_sweep_redoes_an_edited_material_and_keeps_a_device_spelled_otherwise(tmp_path, fake_sweep,
                                                                                         capsys, monkeypatch):
    """A record is kept for the same material file contents and the same device contents: an
    edited material is evaluated again, and ``./dev.json`` for ``dev.json`` keeps the records."""
    (tmp_path / "mats").mkdir()
    mat = tmp_path / "mats" / "m0.json"
    mat.write_text(json.dumps({"type": "analytic", "alpha": 0.2, "kd": 0.45, "ks": 0.5}))
    (tmp_path / "dev.json").write_text(json.dumps({"name": "dev"}))
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "res"
    argv = ["sweep", "mats", "-o", str(out), "--jobs", "1", "--json"]
    assert main([*argv, "--device", "dev.json"]) == 0
    first = json.loads((out / "materials" / "m0.json").read_text())
    capsys.readouterr()
    assert main([*argv, "--device", "./dev.json"]) == 0
    assert json.loads((out / "materials" / "m0.json").read_text()) == first  # kept, not evaluated again
    mat.write_text(json.dumps({"type": "analytic", "alpha": 0.5, "kd": 0.05, "ks": 0.1}))
    assert main([*argv, "--device", "dev.json"]) == 0
    again = json.loads((out / "materials" / "m0.json").read_text())
    assert again["material_digest"] != first["material_digest"] and again["ours"]["error"] < first["ours"]["error"]


def test_batch_commands_refuse_before_they_start(tmp_path, capsys):
    """A malformed --scheduler (it hung after a traceback), a design folder without materials
    (found after every layout), a design value twice or finer than its key, --shadowing with
    --asymmetric (ignored) and a MERL table of an anisotropic source (its φ_h = 0 slice,
    silently) are one line each, before any output is made."""
    (tmp_path / "mats").mkdir()
    (tmp_path / "mats" / "m0.json").write_text(json.dumps({"type": "analytic", "alpha": 0.2, "kd": 0.2, "ks": 0.5}))
    (tmp_path / "empty").mkdir()
    aniso = ROOT / "examples" / "asymmetric" / "ggx-brushed-30.toml"
    cases = [
        (["sweep", str(tmp_path / "mats"), "-o", str(tmp_path / "s"), "--scheduler", "tcp://127.0.0.1:notaport"],
         "not a scheduler address"),
        (["sweep", str(tmp_path / "mats"), "-o", str(tmp_path / "s"), "--scheduler", "foo://bar:1"],
         "unknown scheme 'foo'"),
        (["design", str(tmp_path / "empty"), "-o", str(tmp_path / "d"), "--cones", "40", "--tilts", "20",
          "--leds", "6"], "no material files in"),
        (["design", str(tmp_path / "mats"), "-o", str(tmp_path / "d"), "--cones", "40", "40", "--tilts", "20",
          "--leds", "6", "--layout-only"], "--cones: each value once"),
        (["design", str(tmp_path / "mats"), "-o", str(tmp_path / "d"), "--cones", "40.04", "--tilts", "20",
          "--leds", "6", "--layout-only"], "--cones: values to 1 decimal"),
        (["reconstruct", str(tmp_path / "mats"), str(tmp_path / "empty"), "--asymmetric", "--shadowing",
          "correlated", "-o", str(tmp_path / "a.reflecto")], "--shadowing correlated: the §5.5 path"),
        (["tabulate", str(aniso), "-o", str(tmp_path / "t.binary")], "is anisotropic; a MERL table holds"),
    ]
    for argv, expected in cases:
        assert main(argv) == 1, argv
        err = _err(capsys)
        assert expected in err, (argv, err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty", "mats"]


def test_fit_ct_scores_an_anisotropic_source_as_compare_does(capsys):
    """``fit-ct`` of an anisotropic source reports eq. 10 over every half-vector azimuth (the
    φ_h = 0 cut alone understated it 3×), and says which form."""
    from reflecto.evaluate.cooktorrance import CookTorrance
    from reflecto.evaluate.metrics import comparison_error
    from reflecto.load import load_source

    aniso = ROOT / "examples" / "asymmetric" / "ggx-brushed-30.toml"
    assert main(["fit-ct", str(aniso), "--json"]) == 0
    got = json.loads(capsys.readouterr().out)
    fitted = CookTorrance(got["rho_d"], got["rho_s"], got["F0"], got["m"])  # the fit it printed
    err = comparison_error(load_source(aniso), fitted)
    assert got["error_normalized"] == pytest.approx(err.normalized) and "every half-vector azimuth" in got["error_form"]


def test_a_failed_batch_leaves_no_empty_folder_it_made(tmp_path):
    """After a failed command the empty folders made inside its new output folder go (a sweep's
    ``materials/``), a folder with a finished item's record stays."""
    from reflecto.cli import _clean_up

    out = tmp_path / "res"
    (out / "materials").mkdir(parents=True)
    _clean_up([out], "sweep")
    assert not out.exists()
    (out / "materials").mkdir(parents=True)
    (out / "materials" / "m0.json").write_text("{}")
    (out / "designs").mkdir()
    _clean_up([out], "design")
    assert sorted(p.name for p in out.iterdir()) == ["materials"]
