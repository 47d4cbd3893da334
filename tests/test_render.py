"""Renders and render comparisons: lighting, seeds, noise floor, the metric."""

import numpy as np
import pytest

from conftest import require_mitsuba
from reflecto.cli import main
from reflecto.render.mitsuba import (
    DEFAULT_SPP,
    SMOOTHING_PX,
    compare,
    image_difference,
    object_mask,
    render,
    sample_count,
)
from reflecto.render.sphere import BACKGROUND, composite, render_sphere, sphere_coverage
from reflecto.sources.analytic import AnalyticBRDF

LAMBERT = AnalyticBRDF(distribution="ggx", alpha=0.5, kd=0.9, ks=0.0, eta=1.5)
#: A near-mirror (its highlight is about a pixel wide at 256²): the hardest case for the noise floor.
MIRROR = AnalyticBRDF(distribution="beckmann", alpha=0.01, kd=0.05, ks=0.9, eta=2.0)


@pytest.fixture(scope="module")
def mitsuba():
    return require_mitsuba()


def test_every_visible_point_of_the_sphere_is_lit():
    """Key and fill light: no pixel of the sphere is black (the key alone left 13 % unlit)."""
    img = render_sphere(LAMBERT, 64, supersample=2)
    inside = sphere_coverage(64, supersample=2) >= 1.0
    lum = img[inside] @ np.array([0.2126, 0.7152, 0.0722])
    assert lum.min() > 0.0
    key_only = render_sphere(LAMBERT, 64, supersample=2, lights=((( -3.0, 4.0, 4.0), 80.0),))
    assert np.mean(key_only[inside].sum(axis=1) == 0.0) > 0.10


def test_composite_puts_grey_behind_the_object_at_any_exposure():
    img = render_sphere(LAMBERT, 32, supersample=2)
    alpha = sphere_coverage(32, supersample=2)
    for exposure in (1.0, 7.0):
        out = composite(img, alpha, exposure)
        np.testing.assert_allclose(out[alpha == 0.0], BACKGROUND)
        np.testing.assert_allclose(out[alpha == 1.0], exposure * img[alpha == 1.0])


def test_mitsuba_sphere_point_matches_the_direct_renderer(mitsuba):
    """Same camera, lights and sphere: a Lambertian through its export agrees within 0.5 % (measured 0.32 %)."""
    r = render(LAMBERT, "sphere-point", resolution=128)
    assert r.spp == DEFAULT_SPP["sphere-point"]
    direct = render_sphere(LAMBERT, 128, supersample=4)
    np.testing.assert_allclose(r.alpha, sphere_coverage(128, supersample=16), atol=0.1)  # 64 samples per pixel
    assert image_difference(direct, r.radiance, object_mask(r), SMOOTHING_PX) <= 0.005


def test_self_comparison_sees_the_noise_of_different_seeds(mitsuba):
    """At 4 spp two seeds of one BRDF differ by several % (the same seed gave 0.00 %), and
    the floor, measured between two other seeds, is of the same size."""
    plastic = AnalyticBRDF(distribution="ggx", alpha=0.2, kd=(0.4, 0.2, 0.1), ks=0.5, eta=1.5)
    c = compare(plastic, plastic, "sphere-env", spp=4, resolution=128)
    assert (c.test.seed, c.reference.seed, c.reference_repeat.seed) == (0, 1, 2)
    assert c.difference > 0.01 and 0.5 < c.noise_floor / c.difference < 2.0
    assert not c.resolved and c.within_noise and c.spp_to_resolve() == 4


def test_point_lit_self_comparison_at_the_default_settings(mitsuba):
    """Sphere-point at its defaults: ≤ 1.5 % between two seeds (measured 0.24 %)."""
    c = compare(MIRROR, MIRROR, "sphere-point")
    assert c.test.spp == DEFAULT_SPP["sphere-point"]
    assert c.difference <= 0.015 and c.noise_floor <= 0.015


@pytest.mark.slow
@pytest.mark.parametrize("scene", ["sphere-env", "teapot-env"])
def test_environment_self_comparison_at_the_default_settings(mitsuba, scene):
    """The environment scenes at their defaults: ≤ 1.5 % between two seeds (measured on a
    reconstructed chrome: 0.58 % / 0.82 % floor under the studio map, 0.63 % / 1.10 % for
    the teapot)."""
    c = compare(MIRROR, MIRROR, scene)
    assert c.difference <= 0.015 and c.noise_floor <= 0.015


def test_comparison_tells_brdfs_apart_beyond_the_floor(mitsuba):
    """Two GGX plastics whose roughness differs by 20 %: the difference is many floors."""
    a = AnalyticBRDF(distribution="ggx", alpha=0.2, kd=(0.4, 0.2, 0.1), ks=0.5, eta=1.5)
    b = AnalyticBRDF(distribution="ggx", alpha=0.24, kd=(0.4, 0.2, 0.1), ks=0.5, eta=1.5)
    c = compare(a, b, "sphere-point", resolution=128)
    assert c.resolved and c.difference > 10 * c.noise_floor
    # the corrected value is the difference itself when the floor is negligible
    assert abs(c.corrected - c.difference) < 0.01 * c.difference
    assert not c.within_noise and c.spp_to_resolve() == c.test.spp


def test_ldsampler_counts():
    assert [sample_count(n) for n in (1, 4, 5, 64, 100, 256, 1000)] == [4, 4, 16, 64, 256, 256, 1024]


def test_cli_render_compare_reports_difference_and_floor(mitsuba, tmp_path, capsys):
    src = tmp_path / "mirror.json"
    import json

    src.write_text(json.dumps(MIRROR.to_dict()))
    out = tmp_path / "cmp.png"
    assert main(["render", str(src), "--scene", "sphere-point", "--resolution", "64", "--compare", str(src),
                 "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "mean image difference" in text and "noise floor" in text and "64 spp" in text
    import imageio.v3 as iio

    img = iio.imread(out)
    # three labelled panels and a colour bar: wider than three renders, titles above them
    assert img.shape[0] > 64 and img.shape[1] > 3 * 64 and img.shape[2] == 3
    # the grey background (sRGB of 0.18) of the two renders
    grey = np.all(np.abs(img.astype(int) - 118) <= 1, axis=-1)
    assert grey[:, : img.shape[1] // 3].any() and grey[:, img.shape[1] // 3 : 2 * img.shape[1] // 3].any()
    # --json: one document with the difference and its floor (a BRDF against itself: both tiny)
    assert main(["render", str(src), "--scene", "sphere-point", "--resolution", "64", "--compare", str(src),
                 "-o", str(out), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["output"] == str(out) and doc["spp"] == 64 and 0.0 <= doc["difference"] < 0.015
    assert doc["noise_floor"] >= 0.0 and doc["corrected"] <= doc["difference"]


def test_the_scene_in_docs_mitsuba_renders_an_export(mitsuba, shared, tmp_path):
    """docs/mitsuba.md's XML scene, with its file names pointed at an export and the
    shared studio map, renders a lit sphere (at 32², 16 spp)."""
    import re
    from pathlib import Path

    from reflecto.export.rgl import export_rgl

    mi, _ = mitsuba
    text = (Path(__file__).resolve().parents[1] / "docs" / "mitsuba.md").read_text()
    xml = re.search(r"```xml\n(.*?)```", text, re.S).group(1)
    path = export_rgl(LAMBERT, tmp_path / "plastic.bsdf")
    xml = (xml.replace('"plastic.bsdf"', f'"{path}"')
              .replace('"../shared/data/envmaps/pmndrs_studio.hdr"', f'"{shared / "envmaps" / "pmndrs_studio.hdr"}"')
              .replace('value="256"', 'value="32"')
              .replace('name="sample_count" value="32"', 'name="sample_count" value="16"'))
    img = np.array(mi.render(mi.load_string(xml)))
    assert img.shape == (32, 32, 4)
    centre = img[12:20, 12:20, :3]
    assert np.all(np.isfinite(img)) and centre.min() > 0.01


def test_spp_to_resolve_asks_for_a_floor_a_third_of_the_corrected_difference():
    from reflecto.render.mitsuba import Comparison, Rendering

    r = Rendering(np.zeros((2, 2, 3)), np.ones((2, 2)), "sphere-env", 64, 0, "scalar_rgb", 0.0)
    c = Comparison(0.05, 0.03, 0.04, r, r, r)  # floor 0.03 must fall to 0.04/3: ×(9/4)² ≈ 5.1 the spp
    assert not c.resolved and not c.within_noise
    assert c.spp_to_resolve() == 1024  # 64 × 5.06 = 324, rounded up to the sampler's power of 4
    assert Comparison(0.03, 0.03, 0.0, r, r, r).within_noise
    black = Comparison(0.0, 0.0, 0.0, r, r, r)  # two black renders: alike, and no spp to name
    assert black.within_noise and black.spp_to_resolve() == 64


def test_text_with_dollar_signs_is_plain_not_maths(tmp_path):
    """A title or material name with ``$…$`` in it is written as it is (matplotlib's mathtext
    raised a parse error on a backslash command inside dollar signs)."""
    from reflecto.evaluate.plots import plot_errors
    from reflecto.render.mitsuba import titled

    img = titled(np.zeros((64, 256, 3), np.uint8), r"cost $\foo$ x")
    assert img.shape[0] > 64 and img[:20].min() < 255  # a strip with dark text in it
    rec = {"name": r"a$\b$", "device": "ideal", **{k: {"error": e} for k, e in
                                                    (("ours", 0.1), ("earlier", 0.2), ("cook_torrance", 0.3),
                                                     ("same_data_ct", 0.3))}}
    assert plot_errors([rec], tmp_path / "pe.png").stat().st_size > 0


def test_environment_maps_are_read_as_mitsuba_reads_them(mitsuba, tmp_path):
    """A linear OpenEXR map (as ``render -o x.exr`` writes) is accepted and read in floating
    point; a TIFF, a valid image Mitsuba does not read, is refused in one line; the
    viewer's lighting keeps the shared map's high dynamic range."""

    from reflecto.errors import FileFormatError
    from reflecto.evaluate.viewer import _envmap_small
    from reflecto.render.mitsuba import check_envmap, default_envmap, read_envmap, save_image

    exr = save_image(np.full((16, 32, 3), 2.5), tmp_path / "ok.exr")
    assert check_envmap(exr) == exr and np.allclose(read_envmap(exr), 2.5)
    import cv2

    assert cv2.imwrite(str(tmp_path / "env.tif"), np.full((16, 32, 3), 100, np.uint8))
    assert cv2.imread(str(tmp_path / "env.tif")).shape == (16, 32, 3)  # a valid image, which Mitsuba does not read
    with pytest.raises(FileFormatError, match="env.tif: unreadable environment map"):
        check_envmap(tmp_path / "env.tif")
    env = default_envmap()
    if env.is_file():
        small = np.frombuffer(__import__("base64").b64decode(_envmap_small(env)["data"]), "<f4")
        assert small.max() > 1.5 and np.isclose(small.mean(), read_envmap(env).mean(), rtol=0.05)


def test_a_bsdf_file_whose_name_is_not_utf8_renders(mitsuba, shared, tmp_path):
    """Mitsuba takes file names as UTF-8: an RGL file of another name is rendered through a link."""
    import os
    import shutil

    bad = tmp_path / os.fsdecode(b"mint\xff.bsdf")
    shutil.copyfile(shared / "rgl" / "chm_mint_rgb.bsdf", bad)
    assert main(["render", str(bad), "--scene", "sphere-point", "--resolution", "16", "--spp", "1",
                 "-o", str(tmp_path / "u.png")]) == 0
    assert (tmp_path / "u.png").is_file()


def test_a_title_is_drawn_on_comparisons_and_refused_for_linear_images(mitsuba, tmp_path, capsys):
    """``--title`` above a ``--compare`` image too; with a ``.exr`` or ``.hdr`` output it is refused
    before the render (it was accepted and ignored)."""
    import imageio.v3 as iio

    ex = str(__import__("pathlib").Path(__file__).resolve().parents[1] / "examples" / "ggx-plastic.json")
    base = ["render", ex, "--scene", "sphere-point", "--resolution", "16", "--spp", "1", "--compare", ex]
    assert main([*base, "-o", str(tmp_path / "a.png")]) == 0
    assert main([*base, "--title", "HELLO TITLE", "-o", str(tmp_path / "b.png")]) == 0
    assert iio.imread(tmp_path / "b.png").shape[0] > iio.imread(tmp_path / "a.png").shape[0]
    capsys.readouterr()
    assert main(["render", ex, "--title", "x", "-o", str(tmp_path / "c.exr")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--title is drawn on a .png image" in err[0] and not (tmp_path / "c.exr").exists()
    # a control character (ESC) made Matplotlib warn on stderr, two more lines
    assert main(["render", ex, "--title", "a\x1bb", "-o", str(tmp_path / "d.png")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "holds control characters" in err[0] and not (tmp_path / "d.png").exists()


def test_a_render_of_days_is_refused_before_it_starts(tmp_path, capsys):
    """Pixels × spp beyond MAX_SAMPLES (a 4096² image at 2²⁰ spp asked for 1.8·10¹³ samples) is one
    line naming both, before Mitsuba is loaded."""
    ex = str(__import__("pathlib").Path(__file__).resolve().parents[1] / "examples" / "ggx-plastic.json")
    assert main(["render", ex, "--resolution", "4096", "--spp", "1048576", "-o", str(tmp_path / "x.png")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "4096² pixels × 1048576 spp" in err[0] and not (tmp_path / "x.png").exists()


def test_render_refuses_outputs_it_cannot_write_and_its_own_envmap(mitsuba, tmp_path, capsys):
    """An ``.hdr`` or ``.exr`` name that is not UTF-8 (the ``.hdr`` writer crashed the process,
    the ``.exr`` one raised a traceback) and an output that is the ``--envmap`` being rendered
    with (it was overwritten) are one line each, before the render, and nothing is written."""
    import os

    ex = str(__import__("pathlib").Path(__file__).resolve().parents[1] / "examples" / "ggx-plastic.json")
    for suffix in (".hdr", ".exr"):
        bad = tmp_path / os.fsdecode(b"out\xff" + suffix.encode())
        assert main(["render", ex, "--scene", "sphere-point", "--resolution", "16", "--spp", "1", "-o", str(bad)]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "not valid UTF-8" in err[0]
    env = tmp_path / "my.hdr"
    from reflecto.render.mitsuba import save_image

    save_image(np.full((8, 16, 3), 0.5, dtype=np.float32), env)
    before = env.read_bytes()
    assert main(["render", ex, "--envmap", str(env), "--resolution", "16", "--spp", "1", "-o", str(env)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "environment map being rendered with" in err[0] and env.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["my.hdr"]


def test_a_negative_envmap_and_a_black_reference_are_refused(mitsuba, tmp_path, capsys):
    """An environment map with negative radiance (it lit the sphere with negative light) and a
    ``--compare`` reference that renders black (the difference relative to it printed as
    3·10³⁰⁴ %) are one line each."""
    import json

    from reflecto.errors import FileFormatError
    from reflecto.render.mitsuba import check_envmap, save_image

    img = np.full((8, 16, 3), 0.5, dtype=np.float32)
    img[:4] = -1.0
    with pytest.raises(FileFormatError, match="negative values"):
        check_envmap(save_image(img, tmp_path / "neg.exr"))
    black = tmp_path / "black.json"
    black.write_text(json.dumps({"type": "analytic", "distribution": "ggx", "alpha": 0.3, "kd": 0.0, "ks": 0.0,
                                 "eta": 1.5}))
    ex = str(__import__("pathlib").Path(__file__).resolve().parents[1] / "examples" / "ggx-plastic.json")
    out = tmp_path / "c.png"
    assert main(["render", ex, "--compare", str(black), "--scene", "sphere-point", "--resolution", "16", "--spp",
                 "1", "-o", str(out)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "renders black" in err[0] and not out.exists()


def test_an_envmap_without_pixels_is_refused_before_mitsuba_sees_it(mitsuba, tmp_path, capsys):
    """A Radiance header of ``-Y 0 +X 0`` decodes to an empty image, on which Mitsuba's
    ``envmap`` crashed the process (segfault, temporary files left): one line, no output."""
    from reflecto.errors import FileFormatError
    from reflecto.render.mitsuba import check_envmap

    empty = tmp_path / "empty.hdr"
    empty.write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 0 +X 0\n")
    with pytest.raises(FileFormatError, match=r"0 × 0 pixels: at least 2 × 2"):
        check_envmap(empty)
    ex = str(__import__("pathlib").Path(__file__).resolve().parents[1] / "examples" / "ggx-plastic.json")
    out = tmp_path / "e.png"
    assert main(["render", ex, "--scene", "sphere-env", "--envmap", str(empty), "--resolution", "16", "--spp", "1",
                 "-o", str(out)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "0 × 0 pixels" in err[0] and not out.exists()


def test_the_note_on_spp_compares_the_floor_with_the_corrected_difference():
    """docs/mitsuba.md: the note appears when the floor is above a third of the corrected
    difference (difference 3.0 %, floor 0.95 %: corrected 2.85 %, a third 0.949 %)."""
    from reflecto.render.mitsuba import Comparison, Rendering

    r = Rendering(np.zeros((2, 2, 3)), np.ones((2, 2)), "sphere-env", 64, 0, "scalar_rgb", 0.0)
    c = Comparison(0.03, 0.0095, float(np.sqrt(0.03**2 - 0.0095**2)), r, r, r)
    assert not c.resolved and c.spp_to_resolve() > 64


def test_render_without_mitsuba_is_one_line(tmp_path):
    """Mitsuba 3 is an optional extra: without it ``render`` says what it needs in one line
    (it ended in a traceback)."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    fake = tmp_path / "fake" / "mitsuba"
    fake.mkdir(parents=True)
    (fake / "__init__.py").write_text('raise ImportError("no mitsuba here")\n')
    root = Path(__file__).resolve().parents[1]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path / "fake"), str(root / "src")])}
    p = subprocess.run([sys.executable, "-m", "reflecto.cli", "render", str(root / "examples" / "ggx-plastic.json"),
                        "--resolution", "16", "--spp", "1", "-o", str(tmp_path / "x.png")],
                       capture_output=True, text=True, env=env, timeout=300)
    err = p.stderr.strip().splitlines()
    assert p.returncode == 1 and len(err) == 1 and "needs Mitsuba 3" in err[0], p.stderr
    assert not (tmp_path / "x.png").exists()


def test_an_exr_the_disk_cannot_take_is_one_line_naming_it(tmp_path, monkeypatch):
    """Mitsuba's writer reports a full disk as a RuntimeError naming the temporary file (a
    traceback on the CLI): it becomes the output's error, and nothing is left."""
    from types import SimpleNamespace

    from reflecto.errors import OutputError
    from reflecto.render import mitsuba as rm

    class FullDisk:
        def __init__(self, img):
            pass

        def write(self, name):
            raise RuntimeError(f'[FileStream] "{name}": I/O error while attempting to write 226671 bytes: '
                               "No space left on device")

    monkeypatch.setattr(rm, "import_mitsuba", lambda variant: (SimpleNamespace(Bitmap=FullDisk), variant))
    with pytest.raises(OutputError, match=r"r\.exr: cannot write: No space left on device$"):
        rm.save_image(np.zeros((4, 4, 4)), tmp_path / "r.exr")
    assert list(tmp_path.iterdir()) == []
