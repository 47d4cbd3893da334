"""Commands that would lose the user's files, or print what a terminal runs, refuse instead:
one error line, a non-zero exit, and the user's files as they were (from a fuzz campaign of
the CLI; each case was reproduced before its fix)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from reflecto.cli import main

ROOT = Path(__file__).resolve().parents[1]
PLASTIC = ROOT / "examples" / "ggx-plastic.json"


def _err(capsys) -> str:
    lines = [l for l in capsys.readouterr().err.splitlines() if l.strip()]
    assert len(lines) == 1 and lines[0].startswith("reflecto: error: "), lines
    return lines[0]


def test_a_folder_is_replaced_only_when_it_holds_nothing_but_an_earlier_output(tmp_path, capsys):
    """A folder with someone else's manifest.json, or an earlier capture with the user's notes in
    it, was replaced as a whole by simulate (its files deleted)."""
    ext = tmp_path / "ext"
    (ext / "src").mkdir(parents=True)
    (ext / "manifest.json").write_text('{"manifest_version": 3}')
    (ext / "index.html").write_text("x")
    assert main(["simulate", str(PLASTIC), "-o", str(ext), "-q"]) == 1
    assert "of no reflecto format" in _err(capsys)
    assert sorted(p.name for p in ext.iterdir()) == ["index.html", "manifest.json", "src"]
    cap = tmp_path / "cap"
    assert main(["simulate", str(PLASTIC), "-o", str(cap), "-q"]) == 0
    (cap / "notes.txt").write_text("mine")
    assert main(["simulate", str(PLASTIC), "-o", str(cap), "-q"]) == 1
    assert "holds 'notes.txt'" in _err(capsys) and (cap / "notes.txt").read_text() == "mine"
    (cap / "notes.txt").unlink()
    assert main(["simulate", str(PLASTIC), "-o", str(cap), "-q", "--seed", "2"]) == 0  # an earlier capture: replaced


def test_a_models_summary_replaces_only_an_earlier_summary(tmp_path, capsys):
    """``reconstruct CAP -o mat.reflecto`` wrote its summary over ``mat.json``, the material
    description the capture came from."""
    desc = tmp_path / "mat.json"
    desc.write_text(PLASTIC.read_text())
    cap = tmp_path / "cap"
    assert main(["simulate", str(desc), "-o", str(cap), "-q"]) == 0
    assert main(["reconstruct", str(cap), "-o", str(tmp_path / "mat.reflecto"), "-q"]) == 1
    assert "is not the summary of an earlier model" in _err(capsys)
    assert desc.read_text() == PLASTIC.read_text() and not (tmp_path / "mat.reflecto").exists()
    out = tmp_path / "m.reflecto"
    for _ in range(2):  # an earlier summary is replaced
        assert main(["reconstruct", str(cap), "-o", str(out), "-q", "--max-tilt", "10"]) == 0
    assert json.loads(out.with_suffix(".json").read_text())["normal_source"] == "device"  # untilted


def test_tabulate_does_not_replace_its_own_source(tmp_path, capsys):
    table = tmp_path / "t.binary"
    assert main(["tabulate", str(PLASTIC), "-o", str(table), "-q"]) == 0
    before = table.read_bytes()
    assert main(["tabulate", str(table), "-o", str(table), "-q"]) == 1
    assert "is the file being tabulated" in _err(capsys) and table.read_bytes() == before


def test_layout_refuses_an_empty_cap_and_an_unbounded_resolution(capsys):
    """``--theta-max 1`` divided by an empty cap (NaN, and JSON no parser reads); ``--resolution``
    had no upper bound (512 ran for minutes, 10⁵ ran out of memory)."""
    assert main(["layout", "--theta-max", "1", "--json"]) == 1
    assert "holds no texel centre" in _err(capsys)
    with pytest.raises(SystemExit):
        main(["layout", "--resolution", "100000"])
    assert "must be an even integer in [8, 256]" in capsys.readouterr().err


def test_design_writes_outside_its_materials(tmp_path, capsys):
    mats = tmp_path / "mats"
    mats.mkdir()
    (mats / "p.json").write_text(PLASTIC.read_text())
    assert main(["design", str(mats), "-o", str(mats), "--cones", "48.2", "--tilts", "20", "--leds", "6"]) == 1
    assert "an input of this command" in _err(capsys)
    assert main(["design", str(mats / "p.json"), "-o", str(mats), "--cones", "48.2", "--tilts", "20",
                 "--leds", "6"]) == 1
    assert "holds the input" in _err(capsys)
    assert sorted(p.name for p in mats.iterdir()) == ["p.json"]


def test_a_written_name_is_printed_on_one_line_without_control_characters(tmp_path, capsys):
    out = tmp_path / "a\x1b[2Jb\nFAKE"
    assert main(["simulate", str(PLASTIC), "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    assert printed.count("\n") == 1 and "\x1b" not in printed and "\\x1b[2Jb\\nFAKE" in printed


def test_device_cameras_write_what_they_read(tmp_path, capsys):
    """An 8-bit linear camera wrote 16-bit frames its reader refused; a gamma camera with the
    default black level wrote frames read as below black."""
    dev8 = tmp_path / "b8.json"
    dev8.write_text(json.dumps({"name": "b8", "camera": {"bits": 8}}))
    cap = tmp_path / "c8"
    assert main(["simulate", str(PLASTIC), "--device", str(dev8), "-o", str(cap), "-q"]) == 0
    assert main(["reconstruct", str(cap), "--nominal", "-o", str(tmp_path / "m8.reflecto"), "-q"]) == 0
    gamma = tmp_path / "g8.json"
    gamma.write_text(json.dumps({"name": "g8", "camera": {"bits": 8, "response": "gamma"}}))
    assert main(["simulate", str(PLASTIC), "--device", str(gamma), "-o", str(tmp_path / "cg"), "-q"]) == 1
    assert "a gamma-encoded camera has no black level" in _err(capsys)


def test_layout_counts_no_view_the_occluder_blocks(tmp_path, capsys):
    """A device whose occluder covers nearly the whole cone reported the coverage of a device
    without one (81 %); its views carry no data."""
    from reflecto.instrument.device import Device

    d = Device.builtin("ideal").to_dict()
    d.update(name="occluded", occluder_deg=47.0)
    dev = tmp_path / "occluded.json"
    dev.write_text(json.dumps(d))
    assert main(["layout", "--json"]) == 0
    plain = json.loads(capsys.readouterr().out)["coverage"]
    assert main(["layout", "--device", str(dev), "--json"]) == 0
    occluded = json.loads(capsys.readouterr().out)["coverage"]
    assert occluded["after_tau"] < 0.1 * plain["after_tau"], (occluded, plain)


def test_layout_plots_what_it_counts_behind_an_occluder(tmp_path, capsys, monkeypatch):
    """`layout --plot` drew the coverage of the device without its occluder while printing
    the occluded numbers (the earlier device: 42.6 % drawn, 40.7 % printed)."""
    import reflecto.instrument.plots as plots

    seen = []
    real = plots.coverage_masks

    def recorded(optics, leds, cube, occluder_deg=0.0):
        seen.append(occluder_deg)
        return real(optics, leds, cube, occluder_deg)

    monkeypatch.setattr(plots, "coverage_masks", recorded)
    assert main(["layout", "--device", "earlier", "--plot", str(tmp_path / "c.png"), "--resolution", "32"]) == 0
    from reflecto.instrument.device import Device

    assert seen == [Device.builtin("earlier").occluder_deg] and seen[0] > 0


def test_log_axes_are_labelled_in_plain_text():
    r"""With every text plain (a name's ``$`` is no maths markup), matplotlib's own log labels
    showed as ``$\mathdefault{10^{1}}$``: the log axes carry plain powers of ten."""
    from reflecto.plotting import plain_log_axis, power_of_ten, pyplot

    assert [power_of_ten(v) for v in (0.01, 1.0, 10.0, 2.0, 0.0)] == ["10⁻²", "10⁰", "10¹", "", ""]
    plt = pyplot()
    fig, ax = plt.subplots()
    ax.semilogy([1, 2, 3], [0.01, 1.0, 30.0])
    plain_log_axis(ax)
    fig.canvas.draw()
    labels = [t.get_text() for t in ax.get_yticklabels() if t.get_text()]
    plt.close(fig)
    assert labels and all("$" not in t and t.startswith("10") for t in labels), labels


@pytest.mark.parametrize("device, message", [
    ({"camera": {"full_well": 1e-300}}, "must hold at least one electron"),
    ({"camera": {"read_noise": 1e12}}, "reads noise only"),
    ({"occluder_deg": 48.0}, "pixels see the sample"),
    ({"camera": {"exposures_ms": [1e-9]}}, r"exposures_ms\[0\] must be"),
])
def test_a_device_file_that_cannot_measure_is_refused_when_read(tmp_path, capsys, device, message):
    """Such files simulated without a word and failed later with a misleading message (a NaN
    scale field, a negative radiometric scale, a black model)."""
    path = tmp_path / "dev.json"
    path.write_text(json.dumps({"name": "d", **device}))
    assert main(["simulate", str(PLASTIC), "--device", str(path), "-o", str(tmp_path / "cap"), "-q"]) == 1
    assert re.search(message, _err(capsys))
    assert not (tmp_path / "cap").exists()


def test_a_truth_led_below_the_sample_plane_is_refused():
    from reflecto.errors import ParameterError
    from reflecto.instrument.device import Device

    d = Device.builtin("as-built").to_dict(with_truth=True)
    d["truth"]["led_angles"][0] = [-10.0, d["truth"]["led_angles"][0][1]]
    with pytest.raises(ParameterError, match="at or below the sample plane"):
        Device.from_dict(d)


def test_watch_and_reconstruct_take_the_largest_tilt_to_search(tmp_path):
    """``--max-tilt`` reaches the reconstruction from ``watch`` and ``reconstruct``: a capture
    tilted 12° is held at a bound of 8° (the default 16° finds it), and the summary says so."""
    root, models = tmp_path / "root", tmp_path / "models"
    root.mkdir()
    assert main(["simulate", str(PLASTIC), "--tilt", "12", "--seed", "2", "-o", str(root / "t12"), "-q"]) == 0
    assert main(["watch", str(root), "-o", str(models), "--once", "--max-tilt", "8"]) == 0
    out = tmp_path / "r.reflecto"
    assert main(["reconstruct", str(root / "t12"), "-o", str(out), "-q", "--max-tilt", "8"]) == 0
    for summary in (json.loads((models / "t12.json").read_text()), json.loads(out.with_suffix(".json").read_text())):
        assert abs(summary["normal_tilt_deg"] - 8.0) < 0.05, summary["normal_tilt_deg"]
        assert any("reached the search's bound max_tilt_deg 8°" in n for n in summary["notes"]), summary["notes"]
    assert main(["reconstruct", str(root / "t12"), "-o", str(out), "-q"]) == 0
    assert abs(json.loads(out.with_suffix(".json").read_text())["normal_tilt_deg"] - 12.0) < 0.5


def test_a_merl_table_that_is_no_brdf_is_refused_for_what_it_is(tmp_path, capsys, shared):
    """An isotropic RGL file whose values on the MERL grid go negative (chm_mint: down to
    −7.4·10⁶ sr⁻¹ at grazing) was told by ``export`` that it is anisotropic (add
    ``--isotropic yes``, which failed the same way), and ``tabulate`` wrote it, a fifth of
    its bins read as unmeasured. Both refuse it naming the file and the problem."""
    src = shared / "rgl" / "chm_mint_rgb.bsdf"
    for argv in (["export", str(src), "-o", str(tmp_path / "e.binary"), "-q"],
                 ["export", str(src), "-o", str(tmp_path / "e.binary"), "-q", "--isotropic", "yes"],
                 ["tabulate", str(src), "-o", str(tmp_path / "t.binary"), "-q"]):
        assert main(argv) == 1
        err = _err(capsys)
        assert f"{src}: negative on the MERL grid" in err and "anisotropic" not in err, err
    assert list(tmp_path.iterdir()) == []


def test_options_that_would_be_ignored_are_refused(tmp_path, capsys):
    """`layout --seed` without `--optimize`, and `render --envmap` with the point-lit scene,
    were accepted and ignored; each is one line, before any work."""
    assert main(["layout", "--seed", "3"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--seed is the layout optimizer's" in err[0]
    ex = str(Path(__file__).resolve().parents[1] / "examples" / "ggx-plastic.json")
    assert main(["render", ex, "--scene", "sphere-point", "--envmap", str(tmp_path / "none.hdr"),
                 "-o", str(tmp_path / "x.png")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--envmap lights the *-env scenes" in err[0] and not (tmp_path / "x.png").exists()


def test_the_eq3_advice_puts_a_tilt_held_at_its_bound_first():
    """A capture whose estimated tilt stopped at --max-tilt breaks eq. 3 in that frame as well:
    the advice was to capture rotations for §5.5; it names the bound. The ratio is shown to two
    decimals (2.04× read "2.0×" against "broken from 2×")."""
    from reflecto.cli import _symmetry_hint
    from reflecto.reconstruct.eq3 import SymmetryTest

    test = SymmetryTest(0.5, 1.0, 0.49, 40, 40)
    assert test.ratio > 2.0 and f"{test.ratio:.2f}×" in test.describe()
    from reflecto.reconstruct.pipeline import BOUND_NOTE, PEAK_BEYOND_NOTE

    for note in (BOUND_NOTE, PEAK_BEYOND_NOTE):
        held = {"normal_source": "estimated", "normal_tilt_deg": 8.0, "notes": [f"{note} …"]}
        assert "bound --max-tilt 8° held the normal" in _symmetry_hint(test, held, 8.0)
    free = {"normal_source": "estimated", "normal_tilt_deg": 5.2, "notes": ["sample normal tilted 5.20°"]}
    assert _symmetry_hint(test, free, 8.0) == test.hint() and "rotations" in test.hint()
