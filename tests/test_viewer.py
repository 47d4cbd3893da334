"""The report's BRDF viewer (reflecto.evaluate.viewer) in headless Chromium: it loads from
file:// with no console message, its sphere under the point lights matches Mitsuba's
sphere-point render of the same BRDF, and a light change changes the picture."""

import json
import math
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from reflecto.evaluate.viewer import tabulate_projected, write_viewer
from reflecto.load import load_source
from reflecto.sources.analytic import AnalyticBRDF

RES = 64


def _chromium() -> str:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        if shutil.which(name):
            return shutil.which(name)
    pytest.skip("no Chromium here (CI installs Debian's chromium via `make sysdeps`)")


def _run(page: Path, fragment: str) -> tuple[dict, list[str]]:
    """The page's test output (#test=RES) and its console lines."""
    r = subprocess.run([_chromium(), "--headless=new", "--no-sandbox", "--disable-gpu", "--virtual-time-budget=60000",
                        "--enable-logging=stderr", "--v=0", "--dump-dom", page.as_uri() + "#" + fragment],
                       capture_output=True, text=True, timeout=300)
    console = [line for line in r.stderr.splitlines() if ":CONSOLE" in line]
    m = re.search(r'<pre id="test-output">(.*?)</pre>', r.stdout, re.S)
    assert m and m.group(1), r.stdout[-500:] + r.stderr[-2000:]
    return json.loads(m.group(1)), console


def _materials(shared):
    return [("ggx-plastic", AnalyticBRDF(distribution="ggx", alpha=0.15, kd=(0.45, 0.12, 0.08), ks=0.5, eta=1.5)),
            ("beckmann-rough", AnalyticBRDF(distribution="beckmann", alpha=0.4, kd=0.1, ks=0.8, eta=2.5)),
            ("ggx-shiny", AnalyticBRDF(distribution="ggx", alpha=0.05, kd=0.2, ks=0.6, eta=1.6)),
            ("pvc", load_source(shared / "merl-nbrdf" / "pvc.h5")),
            ("paper_white", load_source(shared / "rgl" / "paper_white_rgb.bsdf"))]


def test_tables_are_the_projected_brdf(shared):
    a = AnalyticBRDF(distribution="ggx", alpha=0.3, kd=0.2, ks=0.5)
    t = tabulate_projected(a)
    assert t.shape == (64, 48, 32, 3) and t.dtype == np.float32
    # θ_h = θ_d = 0: normal incidence and view, f·1·1
    assert t[0, 0, 0] == pytest.approx(a.eval(np.array([[0, 0, 1.0]]), np.array([[0, 0, 1.0]]))[0], rel=1e-6)
    assert np.all(t[:, -1] == 0)  # θ_d = 90°: grazing
    # off the pole: the BRDF times both cosines, at the nodes θ_h = (π/2) u², θ_d, φ_d uniform
    from reflecto import geometry

    for a_, b_, c_ in ((20, 30, 10), (40, 12, 25), (9, 40, 0)):
        th, td, pd = (math.pi / 2) * (a_ / 63) ** 2, (math.pi / 2) * b_ / 47, math.pi * c_ / 31
        i, o = (np.asarray(v, dtype=np.float64).reshape(1, 3) for v in geometry.hd_to_io(th, 0.0, td, pd))
        assert i[0, 2] > 0.05 and o[0, 2] > 0.05 and i[0, 2] * o[0, 2] < 0.95  # both cosines count
        want = a.eval(i, o)[0] * i[0, 2] * o[0, 2]
        np.testing.assert_allclose(t[a_, b_, c_], want, rtol=1e-5)


@pytest.mark.slow
def test_viewer_sphere_matches_mitsuba_and_follows_the_light(shared, tmp_path):
    from reflecto.render.mitsuba import image_difference, render

    mats = _materials(shared)
    page = write_viewer(mats, tmp_path / "viewer.html", envmap=shared / "envmaps" / "pmndrs_studio.hdr")
    out, console = _run(page, f"test={RES}")
    assert console == [], console
    diffs = {}
    for (name, src), sphere in zip(mats, out["spheres"]):
        mi = render(src, "sphere-point", resolution=RES, spp=64, seed=0)
        ours = np.array(sphere["radiance"]).reshape(RES, RES, 3)
        mask = (np.array(sphere["coverage"]).reshape(RES, RES) >= 1) & (mi.alpha >= 1 - 1e-6)
        diffs[name] = image_difference(mi.radiance, ours, mask)
    assert max(diffs.values()) < 0.05, diffs  # measured: 0.2–1.4 %
    # moving the key light changes the picture
    moved, console = _run(page, f"test={RES}&light=60,10")
    assert console == []
    assert moved["key_light"] != out["key_light"]
    a = np.array(out["spheres"][0]["radiance"])
    b = np.array(moved["spheres"][0]["radiance"])
    assert np.abs(a - b).sum() / np.abs(a).sum() > 0.2
    # a pointer press on the sphere (what dragging does) moves the light and the picture
    dragged, console = _run(page, f"test={RES}&drag=0.85,0.5")
    assert console == [] and dragged["key_light"] != out["key_light"]
    c = np.array(dragged["spheres"][0]["radiance"])
    assert np.abs(a - c).sum() / np.abs(a).sum() > 0.2


def test_viewer_loads_from_file_with_no_console_message(tmp_path):
    a = AnalyticBRDF(distribution="ggx", alpha=0.2, kd=0.3, ks=0.5)
    page = write_viewer([("model", a)], tmp_path / "viewer.html")
    out, console = _run(page, "test=16")
    assert console == [] and len(out["spheres"]) == 1 and len(out["spheres"][0]["radiance"]) == 16 * 16 * 3
    assert max(out["spheres"][0]["radiance"]) > 0.05


def test_the_slice_reads_the_brdf_near_grazing(tmp_path):
    """The θ_h–θ_d slice and its read-out give f itself, within the table's interpolation, up to
    grazing: the projected value's interpolation over nodes below the horizon, divided by the
    point's cosines, read a PVC's f at θ_h 85°, θ_d 60° as 0.0021 against 0.0106."""
    from reflecto import geometry

    a = AnalyticBRDF(distribution="ggx", alpha=0.3, kd=(0.3, 0.2, 0.1), ks=0.5, eta=1.5)
    page = write_viewer([("model", a)], tmp_path / "viewer.html")
    points = [(85.0, 60.0, 90.0), (83.0, 60.0, 90.0), (75.0, 60.0, 88.0), (70.0, 20.0, 100.0), (20.0, 40.0, 90.0)]
    out, console = _run(page, "test=8&at=" + ";".join(",".join(f"{x:g}" for x in p) for p in points))
    assert console == []
    for (th, td, pd), got in zip(points, out["slice"]):
        i, o = (np.asarray(v, dtype=np.float64).reshape(1, 3)
                for v in geometry.hd_to_io(math.radians(th), 0.0, math.radians(td), math.radians(pd)))
        assert i[0, 2] > 0 and o[0, 2] > 0
        np.testing.assert_allclose(got, a.eval(i, o)[0], rtol=0.1, err_msg=f"{(th, td, pd)}")
    # a point whose table nodes all lie below the horizon is not in the table: no value, not 0
    out, _ = _run(page, "test=8&at=88,60,90")
    assert out["slice"][0] == [None, None, None]  # NaN in JSON
