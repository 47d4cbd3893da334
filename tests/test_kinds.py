"""Every command checks the kind of each input and the suffix of its output first
(reflecto.kinds): one line ``FILE is KIND; COMMAND needs KIND (what to run)``, exit 1,
no output."""

import json
import zipfile
from pathlib import Path

import numpy as np
import pytest

from reflecto import kinds
from reflecto.cli import main
from reflecto.model import MicrofacetBRDF

ROOT = Path(__file__).resolve().parents[1]
PLASTIC = ROOT / "examples" / "ggx-plastic.json"
BRUSHED = ROOT / "examples" / "brushed-asymmetric.toml"

BRDF = "needs a BRDF file (.binary, .bsdf, .h5, .json/.toml) or a model (.reflecto)"


@pytest.fixture(scope="module")
def files(tmp_path_factory, shared) -> dict[str, Path]:
    """One input of every kind (folders and a calibration file by their marks alone)."""
    d = tmp_path_factory.mktemp("kinds")
    model = MicrofacetBRDF.from_ndf_function(lambda h: np.ones(len(h)) / np.pi, resolution=8, kd=0.2, ks=0.3)
    model.save(d / "m.reflecto")
    (d / "m.json").write_text(json.dumps({"kd": [0.2] * 3, "ks": [0.3] * 3, "shake_detected": False,
                                          "model_error": 0.0}))
    (d / "cap").mkdir()
    (d / "cap" / "manifest.json").write_text(json.dumps({"format": "reflecto-capture", "version": 1}))
    (d / "calib").mkdir()
    (d / "calib" / "calibration.json").write_text(json.dumps({"format": "reflecto-calibration-capture"}))
    with zipfile.ZipFile(d / "cal.npz", "w") as z:
        z.writestr("meta.npy", b"")
        z.writestr("scale.npy", b"")
    (d / "dev.json").write_text(json.dumps({"name": "mine", "optics": {}}))
    (d / "materials").mkdir()
    return {"model": d / "m.reflecto", "summary": d / "m.json", "capture": d / "cap", "calib-dir": d / "calib",
            "cal": d / "cal.npz", "device": d / "dev.json", "bsdf": shared / "rgl" / "chm_mint_rgb.bsdf",
            "h5": shared / "merl-nbrdf" / "pvc.h5", "h5json": shared / "merl-nbrdf" / "pvc.json", "analytic": PLASTIC,
            "aniso": BRUSHED, "out": d / "out"}


# (argv with {kind} placeholders, what the message must say)
CASES = [
    ("report {bsdf} -o {out}/r", "chm_mint_rgb.bsdf is an RGL tensor file (.bsdf); report needs a reflecto model "
                                 "file (.reflecto) (to model it: reflecto simulate"),
    ("report {capture} -o {out}/r", "cap is a capture folder (manifest.json and frames); report needs a reflecto "
                                    "model file (.reflecto) (to make a model of it: reflecto reconstruct"),
    ("reconstruct {model} -o {out}/x.reflecto", "m.reflecto is a reflecto model file (.reflecto); reconstruct needs "
                                                "a capture folder (manifest.json and frames) "
                                                "(to look at it: reflecto info"),
    ("reconstruct {bsdf} -o {out}/x.reflecto", "is an RGL tensor file (.bsdf); reconstruct needs a capture folder"),
    ("reconstruct {capture} --calibration {calib-dir} -o {out}/x.reflecto",
     "calib is a calibration folder (calibration captures, calibration.json); reconstruct --calibration needs a "
     "calibration file (.npz, from `reflecto calibrate`) (to make a calibration file of it: reflecto calibrate"),
    ("reconstruct {capture} --calibration {model} -o {out}/x.reflecto",
     "m.reflecto is a reflecto model file (.reflecto); reconstruct --calibration needs a calibration file (.npz"),
    ("info {cal}", f"cal.npz is a calibration file (.npz, from `reflecto calibrate`); info {BRDF} (it reads "
                   "captures: reflecto reconstruct CAPTURE --calibration"),
    ("info {summary}", f"m.json is a reconstruction summary (.json); info {BRDF} (it describes a model: reflecto "
                       "info"),
    ("info {capture}", f"cap is a capture folder (manifest.json and frames); info {BRDF}"),
    ("info {device}", f"dev.json is a device file (.json/.toml); info {BRDF} (it describes a device: reflecto "
                      "simulate BRDF --device"),
    ("tabulate {cal} -o {out}/t.binary",
     f"cal.npz is a calibration file (.npz, from `reflecto calibrate`); tabulate {BRDF}"),
    ("compare {capture} {model}", f"cap is a capture folder (manifest.json and frames); compare {BRDF}"),
    ("compare {model} {calib-dir}",
     f"calib is a calibration folder (calibration captures, calibration.json); compare {BRDF}"),
    ("fit-ct {summary}", f"m.json is a reconstruction summary (.json); fit-ct {BRDF}"),
    ("calibrate {capture} -o {out}/c.npz", "cap is a capture folder (manifest.json and frames); calibrate needs a "
                                           "calibration folder (calibration captures, calibration.json)"),
    ("simulate {analytic} --device {bsdf} -o {out}/cap", "chm_mint_rgb.bsdf is an RGL tensor file (.bsdf); simulate "
     "--device needs a device: ideal, as-built, earlier, wide, wide-as-built, or a device file (.json/.toml)"),
    ("simulate {analytic} --device {analytic} -o {out}/cap", "ggx-plastic.json is an analytic BRDF description "
                                                              "(.json/.toml); simulate --device needs a device"),
    ("layout --device {model}", "m.reflecto is a reflecto model file (.reflecto); layout --device needs a device"),
    ("simulate {capture} -o {out}/cap", f"cap is a capture folder (manifest.json and frames); simulate {BRDF}"),
    ("render {capture} -o {out}/x.png", f"cap is a capture folder (manifest.json and frames); render {BRDF}"),
    ("render {analytic} --compare {cal} -o {out}/x.png", f"cal.npz is a calibration file (.npz, from `reflecto "
                                                         f"calibrate`); render --compare {BRDF}"),
    ("sweep {capture} -o {out}/s", "cap is a capture folder (manifest.json and frames); sweep needs folders or files "
                                   "of materials (BRDF files)"),
    ("gallery {analytic} --calibration {calib-dir} -o {out}/g", "calib is a calibration folder (calibration captures, "
     "calibration.json); gallery --calibration needs a calibration file (.npz"),
    ("info {h5json}", f"pvc.json is an NBRDF architecture file (the .json beside its .h5 weights); info {BRDF} "
                      "(open the fit by its weights: reflecto info"),
    ("reconstruct {capture} --calibration {calib-dir}/calibration.json -o {out}/x.reflecto",
     "calibration.json is a calibration folder's manifest (calibration.json); reconstruct --calibration needs a "
     "calibration file (.npz, from `reflecto calibrate`) (it belongs to its folder: reflecto calibrate"),
    # outputs
    ("export {model} -o {out}/x.png", "x.png is a .png file; export writes an RGL .bsdf or a MERL .binary file (or "
                                      "name one with --format rgl|merl) (use -o"),
    ("export {model} --format merl -o {out}/x.bsdf", "x.bsdf is a .bsdf file name; export --format merl writes a "
                                                     "MERL table (.binary) (use -o"),
    ("export {model} -o {out}/x.reflecto", "x.reflecto is a .reflecto file; export writes an RGL .bsdf or a MERL "
                                           ".binary file"),
    ("tabulate {analytic} -o {out}/t.bsdf", "t.bsdf is a .bsdf file; tabulate writes a MERL table (.binary) (use -o"),
    ("reconstruct {capture} -o {out}/x.png", "x.png is a .png file; reconstruct writes a model file (.reflecto) (use "
                                             "-o"),
    ("calibrate {calib-dir} -o {out}/x.reflecto", "x.reflecto is a .reflecto file; calibrate writes a calibration "
                                                  "file (.npz) (use -o"),
    ("render {analytic} -o {out}/x.bsdf", "x.bsdf is a .bsdf file; render writes an image (.png, .exr or .hdr)"),
    ("render {analytic} --compare {analytic} -o {out}/x.exr", "x.exr is a .exr file; render writes a comparison "
                                                               "image (.png)"),
    ("layout --plot {out}/x.pdf", "x.pdf is a .pdf file; layout writes a plot (.png) (use --plot"),
    ("simulate {analytic} -o {out}/x.reflecto", "x.reflecto is a .reflecto file name; simulate writes a capture "
                                                "folder (use -o"),
    ("report {model} -o {out}/r.png", "r.png is a .png file name; report writes a report folder"),
]


@pytest.mark.parametrize("argv, message", CASES, ids=[c[0].split()[0] + "-" + str(k) for k, c in enumerate(CASES)])
def test_wrong_kind_or_suffix_is_one_line_exit_1_no_output(files, argv, message, capsys):
    args = [a.format(**{k.replace("-", "_"): v for k, v in files.items()})
            for a in argv.replace("calib-dir", "calib_dir").split()]
    assert main(args) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("reflecto: error: ")
    assert message in err, err
    assert not files["out"].exists()


def test_anisotropic_merl_export_names_the_cli_option(files, capsys, tmp_path):
    assert main(["export", str(files["aniso"]), "-o", str(tmp_path / "x.binary")]) == 1
    err = capsys.readouterr().err
    assert "add --isotropic yes to write its φ_h = 0 slice" in err and "allow_anisotropic" not in err
    assert not (tmp_path / "x.binary").exists()


def test_identify_every_kind(files, tmp_path):
    assert {k: kinds.identify(files[k]).name for k in ("model", "summary", "capture", "calib-dir", "cal", "device",
                                                        "bsdf", "h5", "analytic")} == {
        "model": "model", "summary": "summary", "capture": "capture", "calib-dir": "calibration-folder",
        "cal": "calibration", "device": "device", "bsdf": "rgl", "h5": "nbrdf", "analytic": "analytic"}
    # by contents when the suffix says nothing
    renamed = tmp_path / "model-without-suffix"
    renamed.write_bytes(files["model"].read_bytes())
    assert kinds.identify(renamed).name == "model"
    assert kinds.identify(tmp_path / "nothing").name == "missing"
    (tmp_path / "junk.json").write_text("{not json")
    assert kinds.identify(tmp_path / "junk.json").name == "unknown"  # the reader names the problem


def test_right_kinds_pass_the_check(files, capsys):
    """The check does not get in the way of a correct invocation."""
    assert main(["info", str(files["analytic"]), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["kind"] == "analytic"
    assert main(["info", str(files["model"]), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["kind"] == "model"


# ------------------------------------------------------------------ choices, units, order, public names
def test_device_help_lists_every_builtin_and_options_state_units(capsys):
    from reflecto.cli import build_parser
    from reflecto.instrument.device import BUILTINS

    helps = {}
    for command in ("simulate", "layout", "gallery"):
        with pytest.raises(SystemExit):
            main([command, "--help"])
        helps[command] = " ".join(capsys.readouterr().out.split())
    for text in helps.values():
        assert all(f"{name} (" in text for name in BUILTINS), text
    assert "azimuth of the tilt, degrees" in helps["simulate"]
    assert "cells along each edge of a hemicube face" in helps["layout"]
    assert "rotations of the §5.5 captures, degrees; values separated by spaces" in helps["gallery"]
    assert "(default: 0 90 180 270)" in helps["gallery"]
    args = build_parser().parse_args(["gallery", "x.json", "-o", "g", "--rotations", "0,120", "240"])
    from reflecto.cli import _lists

    _lists(args)
    assert args.rotations == [0.0, 120.0, 240.0]


def test_reference_first_everywhere():
    import inspect

    from reflecto.evaluate.metrics import brdf_error
    from reflecto.render.mitsuba import compare

    assert list(inspect.signature(compare).parameters)[:2] == ["reference", "test"]
    assert list(inspect.signature(brdf_error).parameters)[:2] == ["reference", "test"]


def test_public_names_albedo_shape_and_help():
    import pydoc

    import reflecto.sources
    from reflecto.reconstruct import reconstruct
    from reflecto.sources.analytic import AnalyticBRDF

    assert dir(reflecto.sources) == ["AnalyticBRDF", "MerlBRDF", "NBRDF", "RGLBRDF", "analytic", "load_analytic",
                                     "merl", "nbrdf", "rgl"]
    a = AnalyticBRDF(kd=0.5, ks=0.0)
    assert a.albedo(0).shape == (3,) and a.albedo([0, 30]).shape == (2, 3)
    assert a.albedo(0) == pytest.approx([0.5] * 3, abs=2e-3)
    text = pydoc.render_doc(reconstruct, renderer=pydoc.plaintext)
    assert "Parameters" in text and "options" in text and "Returns" in text and "Reconstruction" in text


def test_wide_capture_reconstructs_without_nominal(tmp_path, capsys):
    assert main(["simulate", str(PLASTIC), "--device", "wide", "-o", str(tmp_path / "cap"), "-q"]) == 0
    assert main(["reconstruct", str(tmp_path / "cap"), "--eta", "1.5", "-o", str(tmp_path / "m.reflecto"),
                 "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["models"][0]["summary"]["kd"][0] == pytest.approx(0.45, abs=0.03)
    assert main(["simulate", str(PLASTIC), "--device", "wide-as-built", "-o", str(tmp_path / "cab"), "-q"]) == 0
    assert main(["reconstruct", str(tmp_path / "cab"), "-o", str(tmp_path / "n.reflecto")]) == 1
    assert "captured with device 'wide-as-built'" in capsys.readouterr().err


def test_teapot_is_welded_and_smooth(shared, tmp_path, monkeypatch):
    """The welded copy's vertex normals are its triangles' mean normals: unit, on the side
    the triangles face, and agreeing with every triangle around them to within its
    curvature. The copy lies in the process's own private folder: a file planted or damaged
    under the name a shared temporary folder's cache used is not served (it was, and a damaged
    one broke every teapot render with a traceback)."""
    import hashlib
    import os
    import stat
    import tempfile

    import reflecto.render.mitsuba as rm

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    monkeypatch.setattr(rm, "_MESH_FOLDER", [])
    raw = (shared / "meshes" / "teapot.obj").read_bytes()
    planted = tmp_path / f"reflecto-smooth-{hashlib.sha256(raw).hexdigest()[:16]}.obj"
    planted.write_text("garbage\n")
    path = rm.smooth_mesh(shared / "meshes" / "teapot.obj")
    assert path.parent.parent == tmp_path and path.parent.name.startswith("reflecto-mesh-")
    assert stat.S_IMODE(os.stat(path.parent).st_mode) == 0o700
    text = path.read_text().splitlines()
    v = np.array([[float(x) for x in l.split()[1:]] for l in text if l.startswith("v ")])
    vn = np.array([[float(x) for x in l.split()[1:]] for l in text if l.startswith("vn ")])
    f = np.array([[int(w.split("//")[0]) - 1 for w in l.split()[1:]] for l in text if l.startswith("f ")])
    assert len(v) == len(vn) < 6320  # the seam's repeated vertices merged
    assert len(np.unique(np.round(v, 5), axis=0)) == len(v)
    assert np.allclose(np.linalg.norm(vn, axis=1), 1.0, atol=1e-5)
    tri = v[f]
    face_n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    face_n /= np.linalg.norm(face_n, axis=1, keepdims=True)
    agree = np.einsum("fkj,fj->fk", vn[f], face_n)  # each corner's normal against its triangle's
    assert np.mean(agree > 0.9) > 0.97 and np.mean(agree > 0.0) > 0.995, (np.mean(agree > 0.9), agree.min())


def test_model_names_its_calibration_and_the_report_reads_the_slices_with_it(tmp_path, capsys):
    """As-built capture + its calibration: the model records both; the report's slices use the
    calibration, and a moved model says that its capture is not found."""
    import shutil

    assert main(["simulate", str(PLASTIC), "--device", "as-built", "-o", str(tmp_path / "cap"), "-q"]) == 0
    assert main(["simulate-calibration", "--device", "as-built", "-o", str(tmp_path / "calib"), "-q"]) == 0
    assert main(["calibrate", str(tmp_path / "calib"), "-o", str(tmp_path / "cal.npz"), "-q"]) == 0
    assert main(["reconstruct", str(tmp_path / "cap"), "--calibration", str(tmp_path / "cal.npz"), "--eta", "1.5",
                 "-o", str(tmp_path / "m.reflecto"), "-q"]) == 0
    from reflecto.model import load_model

    meta = load_model(tmp_path / "m.reflecto").metadata
    assert meta["calibration"] == str(tmp_path / "cal.npz") and meta["capture"] == str(tmp_path / "cap")
    assert main(["report", str(tmp_path / "m.reflecto"), "--no-render", "-o", str(tmp_path / "rep")]) == 0
    assert "The slices of" in (tmp_path / "rep" / "index.html").read_text()
    assert "(calibration cal.npz)" in (tmp_path / "rep" / "index.html").read_text()
    (tmp_path / "moved").mkdir()
    shutil.copy(tmp_path / "m.reflecto", tmp_path / "moved")
    assert main(["report", str(tmp_path / "moved" / "m.reflecto"), "--no-render", "-o", str(tmp_path / "rep2")]) == 0
    assert ("not shown: the model names the capture cap, which is not a capture folder"
            in (tmp_path / "rep2" / "index.html").read_text())
    frame = tmp_path / "cap" / "led2_t8ms.png"  # a damaged frame: the page names it
    frame.write_bytes(frame.read_bytes()[:500])
    assert main(["report", str(tmp_path / "m.reflecto"), "--no-render", "-o", str(tmp_path / "rep3")]) == 0
    page = (tmp_path / "rep3" / "index.html").read_text()
    assert "not shown: the capture cannot be read" in page and "led2_t8ms.png" in page and "truncated" in page
    capsys.readouterr()


def test_a_mesh_that_is_not_an_obj_is_one_line(tmp_path):
    """A damaged teapot mesh (the shared data's, or one under REFLECTO_SHARED) is named with
    its problem; it raised numpy's ValueError."""
    from reflecto.errors import FileFormatError
    from reflecto.render.mitsuba import smooth_mesh

    for k, text in enumerate(("garbage\n", "v 0 0 0\nv 1 0 0\nf 1 2 9\n", "v 0 0 nan\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")):
        bad = tmp_path / f"bad{k}.obj"
        bad.write_text(text)
        with pytest.raises(FileFormatError, match=f"bad{k}.obj: not an OBJ mesh"):
            smooth_mesh(bad)
