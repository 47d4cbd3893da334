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
