"""HTML report: written atomically, loads in a real headless Chromium.

The page records how many of its images decoded in ``<body data-images="k/n">``;
Chromium's ``--dump-dom`` gives the DOM after the load event, and
``--enable-logging=stderr`` prints every console message (the page logs none when
all is well). A screenshot is kept in ``out/test-report/`` for people to look at.
"""

import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from conftest import require
from reflecto.cli import main
from reflecto.evaluate.report import write_index, write_report
from reflecto.model import MicrofacetBRDF, load_model
from reflecto.sources.analytic import AnalyticBRDF

ROOT = Path(__file__).resolve().parents[1]


def _chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        if shutil.which(name):
            return shutil.which(name)
    return None


def _load_in_chromium(page: Path, screenshot: Path | None = None) -> tuple[str, list[str]]:
    exe = _chromium() or require("chromium", "chromium-browser", "google-chrome")  # skips here, fails in CI
    base = [exe, "--headless=new", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", "--virtual-time-budget=8000"]
    dom = subprocess.run([*base, "--enable-logging=stderr", "--v=0", "--dump-dom", page.as_uri()],
                         capture_output=True, text=True, timeout=120)
    console = [line for line in dom.stderr.splitlines() if ":CONSOLE" in line]
    if screenshot is not None:
        screenshot.parent.mkdir(parents=True, exist_ok=True)
        subprocess.run([*base, "--window-size=1200,3200", f"--screenshot={screenshot}", page.as_uri()],
                       capture_output=True, timeout=120)
    m = re.search(r'data-images="([^"]*)"', dom.stdout)
    return (m.group(1) if m else ""), console


def test_report_page_loads_in_chromium_with_every_image(tmp_path, capsys):
    a = AnalyticBRDF(distribution="ggx", alpha=0.2, kd=(0.4, 0.2, 0.1), ks=0.5, eta=1.5)
    ref = tmp_path / "ref.json"
    ref.write_text(json.dumps(a.to_dict()))
    model = MicrofacetBRDF.from_ndf_function(a.ndf, resolution=128, kd=a.kd, ks=a.ks, eta=a.eta)
    path = model.save(tmp_path / "m.reflecto")
    page = write_report(path, tmp_path / "report", reference=ref, spp=4)
    html = page.read_text()
    n_img = html.count("<img ")
    assert n_img >= 8 and "eq. 10 error" in html
    shot = ROOT / "out" / "test-report" / "report.png"
    status, console = _load_in_chromium(page, shot)
    assert status == f"{n_img}/{n_img}", status
    assert console == [], console
    assert shot.is_file() and shot.stat().st_size > 10_000
    with capsys.disabled():
        print(f"\n  report screenshot: {shot}")
    # the sweep index page links it
    index = write_index([{"name": "ggx", "href": "report/index.html", "error": 0.001}], tmp_path)
    status, console = _load_in_chromium(index)
    assert status == "0/0" and console == []


def test_report_refuses_bad_model(tmp_path):
    bad = tmp_path / "bad.reflecto"
    bad.write_bytes(b"not a zip")
    assert main(["report", str(bad), "-o", str(tmp_path / "r")]) == 1
    assert not (tmp_path / "r" / "index.html").exists()


def test_report_refuses_a_bad_model_summary(tmp_path):
    """The model's summary (``m.json`` beside ``m.reflecto``) is read by the validating loader."""
    from reflecto.errors import FileFormatError

    a = AnalyticBRDF(distribution="ggx", alpha=0.3, kd=0.3, ks=0.5, eta=1.5)
    path = MicrofacetBRDF.from_ndf_function(a.ndf, resolution=16, kd=a.kd, ks=a.ks, eta=a.eta).save(
        tmp_path / "m.reflecto")
    summary = tmp_path / "m.json"
    for text in ("{not json", "[1, 2]"):
        summary.write_text(text)
        with pytest.raises(FileFormatError) as e:
            write_report(path, tmp_path / "r", render=False)
        assert e.value.path == summary


def test_report_shows_the_specular_colour_of_a_fresnel_tint(tmp_path):
    a = AnalyticBRDF(distribution="ggx", alpha=0.3, kd=0.3, ks=0.5, eta=1.5)
    model = MicrofacetBRDF.from_ndf_function(a.ndf, resolution=16, kd=a.kd, ks=0.5, eta=a.eta,
                                             tint=(np.radians([38.0, 67.0]), [[1.0, 0.5, 0.2], [0.5, 1.0, 1.0]]))
    page = write_report(model.save(tmp_path / "m.reflecto"), tmp_path / "r", render=False)
    text = page.read_text()
    assert "specular colour" in text and "[0.5, 0.25, 0.1]" in text and "67.0°" in text
    assert "trend" not in text  # held beyond the last node: nothing to say
    from reflecto.fresnel import FresnelTint

    trend = MicrofacetBRDF.from_ndf_function(a.ndf, resolution=16, kd=a.kd, ks=0.5, eta=a.eta,
                                             tint=FresnelTint(np.radians([38.0, 67.0]), [[1.0, 0.5, 0.2],
                                                                                         [0.5, 1.0, 1.0]], "trend"))
    back = load_model(trend.save(tmp_path / "t.reflecto"))  # a hemicube model keeps the continuation too
    assert back.tint.beyond == "trend"
    text = write_report(back.path, tmp_path / "t", render=False).read_text()
    assert "beyond 67.0°: the nodes&#x27; trend continued" in text


def _small_model(tmp_path: Path, name: str = "m.reflecto") -> Path:
    a = AnalyticBRDF(distribution="ggx", alpha=0.3, kd=0.3, ks=0.5, eta=1.5)
    return MicrofacetBRDF.from_ndf_function(a.ndf, resolution=16, kd=a.kd, ks=a.ks, eta=a.eta).save(tmp_path / name)


def test_a_report_is_written_whole_or_not_at_all(tmp_path, monkeypatch):
    """A report that fails half-way leaves the earlier report in its folder as it was; a folder
    of other files (a watch's models, with their index.html) is refused, not filled."""
    from reflecto.errors import OutputError
    from reflecto.evaluate import report

    model = _small_model(tmp_path)
    out = write_report(model, tmp_path / "r", render=False).parent
    before = {p.name: p.read_bytes() for p in out.iterdir()}

    def broken(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(report, "write_viewer", broken)
    with pytest.raises(OSError):
        write_report(model, out, render=False)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    other = tmp_path / "models"
    other.mkdir()
    (other / "index.html").write_text("a watch's page")
    (other / "precious.reflecto").write_bytes(b"x")
    monkeypatch.undo()
    with pytest.raises(OutputError, match="folder of other files"):
        write_report(model, other, render=False)
    assert sorted(p.name for p in other.iterdir()) == ["index.html", "precious.reflecto"]


def test_names_that_are_markup_or_not_utf8_stay_text(tmp_path):
    """A model file named like markup, or with a name that is not valid UTF-8, gives a page (and a
    viewer whose data block cannot open a tag or a comment) that shows the name as text."""
    import os

    from reflecto.evaluate.viewer import write_viewer

    model = _small_model(tmp_path, "<!--<script>.reflecto")
    page = write_report(model, tmp_path / "r", render=False)
    viewer = (page.parent / "viewer.html").read_text()
    assert "<!--<script>" not in viewer and "\\u003c!--\\u003cscript>" in viewer
    bad = _small_model(tmp_path, os.fsdecode(b"bad\xff.reflecto"))
    text = write_report(bad, tmp_path / "r2", render=False).read_text()
    assert "bad\\udcff.reflecto" in text
    write_viewer([("</script><!--", load_model(model))], tmp_path / "v.html")
    assert "</script><!--" not in (tmp_path / "v.html").read_text()


def test_the_report_scores_an_anisotropic_reference_as_compare_does(tmp_path):
    """The report's eq. 10 error against an anisotropic reference is ``compare``'s (every
    half-vector azimuth), not the φ_h = 0 cut alone."""
    from reflecto.evaluate.metrics import comparison_error
    from reflecto.load import load_source

    ref = ROOT / "examples" / "asymmetric" / "ggx-brushed-30.toml"
    model = _small_model(tmp_path)
    text = write_report(model, tmp_path / "r", reference=ref, render=False).read_text()
    err = comparison_error(load_source(ref), load_model(model))
    assert f"{round(100 * err.normalized, 3)}</td>" in text and err.describe() in text


def test_gallery_keeps_to_its_own_folders_and_names(tmp_path, capsys):
    """``gallery -o`` refuses a folder of other files that merely holds an ``index.html`` (a
    watch's models or a report), two materials of one name, and a resolution out of range,
    each in one line before any capture is simulated; its image links are URL-encoded."""
    from reflecto.evaluate.gallery import GalleryRow, GallerySettings, _cell

    victim = tmp_path / "victim"
    victim.mkdir()
    (victim / "index.html").write_text("x")
    (victim / "precious.reflecto").write_bytes(b"x")
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir()
    b.mkdir()
    for d in (a, b):
        (d / "x.json").write_text(json.dumps({"type": "analytic", "alpha": 0.3, "kd": 0.2, "ks": 0.3}))
    argv = ["gallery", "--rotations", "0", "180", "--resolution", "16", "--spp", "1"]
    for extra, expected in (([str(a / "x.json"), "-o", str(victim)], "folder of other files"),
                            ([str(a / "x.json"), str(b / "x.json"), "-o", str(tmp_path / "g")], "the same name"),
                            ([str(a / "x.json"), "-o", str(tmp_path / "g"), "--resolution", "4"],
                             "resolution must be in [8, 4096]")):
        assert main([*argv, *extra]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and expected in err[0], err
    assert sorted(p.name for p in victim.iterdir()) == ["index.html", "precious.reflecto"]
    assert not (tmp_path / "g").exists()
    row = GalleryRow("p#1", "p#1.json", {}, "", 0.1, 0.1, 0.1, 0.1, 0.01, 1.0, False,
                     {k: f"p#1_{k}.png" for k in ("reference", "symmetric", "asymmetric")}, 1.0)
    assert 'src="p%231_reference.png"' in _cell(row, "reference")
    assert GallerySettings().resolution == 256


def test_the_report_of_a_preview_of_a_wide_capture_in_another_folder(tmp_path):
    """A `watch` preview whose peaks placed no normal: the report says it is a preview and
    that the tilt is not placed (it showed 0.0°); the capture taken with `wide` and moved
    out of reach: the coverage is `wide`'s, named in the model (it fell back to the ideal
    device); the albedo is over the angles the reconstruction checks (it read 0–80° and
    disagreed with the summary's)."""
    from reflecto import workflow
    from reflecto.instrument.capture import write_capture
    from reflecto.instrument.device import Device
    from reflecto.instrument.simulate import simulate_capture

    src = AnalyticBRDF(distribution="ggx", alpha=0.5, kd=(0.4, 0.3, 0.2), ks=0.3, eta=1.5)
    cap = tmp_path / "cap" / "broad"
    write_capture(simulate_capture(src, Device.builtin("wide"), tilt_deg=4.0, seed=1), cap)
    model = tmp_path / "m" / "broad.reflecto"
    summary = workflow.reconstruct_folder(cap, model, preview=True)
    assert summary["normal_source"] == "unplaced" and summary["preview"] is True
    shutil.rmtree(tmp_path / "cap")
    text = write_report(model, tmp_path / "r", render=False).read_text()
    assert "not placed" in text and "<th>preview</th>" in text
    assert "normal tilt (deg)</th><td>0" not in text
    assert "coverage per LED of device wide" in text
    m = re.search(r"max directional albedo \(θ_i 0–89°\)</th><td>([0-9.]+)<", text)
    assert m and abs(float(m.group(1)) - summary["albedo_max"]) < 1e-3, (m and m.group(1), summary["albedo_max"])
