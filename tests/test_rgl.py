import struct

import numpy as np
import pytest

from conftest import random_directions, require_mitsuba
from reflecto.errors import FileFormatError
from reflecto.load import load_source
from reflecto.sources import RGLBRDF
from reflecto.sources.rgl import read_tensor_file


def _files(shared):
    files = sorted((shared / "rgl").glob("*.bsdf"))
    assert len(files) == 10
    return files


def test_all_shared_rgl_files_load_and_evaluate(shared, rng):
    i, o = random_directions(rng, 5000, 80), random_directions(rng, 5000, 80)
    for f in _files(shared):
        src = load_source(f)
        assert isinstance(src, RGLBRDF) and src.isotropic
        v = src.eval(i, o)
        assert np.all(np.isfinite(v)), f.name
        assert not src.reciprocal  # measured tables are not exactly reciprocal
        lum = src.albedo([0, 40]) @ np.array([0.2126, 0.7152, 0.0722])
        assert np.all((lum > 0) & (lum < 1.05)), (f.name, lum)


def test_agrees_with_mitsuba_measured_plugin(shared):
    mi, variant = require_mitsuba()
    rng = np.random.default_rng(7)
    n = 100_000 if variant.startswith("llvm") else 3_000
    i, o = random_directions(rng, n, 80), random_directions(rng, n, 80)
    for f in _files(shared):
        bsdf = mi.load_dict({"type": "measured", "filename": str(f)})
        ctx = mi.BSDFContext()
        if variant.startswith("llvm"):
            si = mi.SurfaceInteraction3f()
            si.wi = mi.Vector3f(i[:, 0], i[:, 1], i[:, 2])
            ref = np.array(bsdf.eval(ctx, si, mi.Vector3f(o[:, 0], o[:, 1], o[:, 2]))).reshape(3, -1).T
        else:
            ref = np.empty((n, 3))
            for k in range(n):
                si = mi.SurfaceInteraction3f()
                si.wi = mi.Vector3f(*i[k])
                ref[k] = np.array(bsdf.eval(ctx, si, mi.Vector3f(*o[k])))
        mine = RGLBRDF(f).eval_cosine(i, o)
        rel = np.abs(mine - ref).max(axis=1) / np.maximum(np.abs(ref).max(axis=1), 1e-6)
        assert np.median(rel) <= 0.005, (f.name, variant)
        assert np.percentile(rel, 99) <= 0.02, (f.name, variant)


def _rewrite_without(raw: bytes, drop: str) -> bytes:
    """Rename one field so that it is 'missing' (same byte layout)."""
    return raw.replace(drop.encode(), b"X" * len(drop), 1)


def test_bad_tensor_files(shared, tmp_path):
    raw = (shared / "rgl" / "paper_white_rgb.bsdf").read_bytes()
    cases = {
        "magic.bsdf": (b"tensor_fil3\x00" + raw[12:], "wrong magic"),
        "missing.bsdf": (_rewrite_without(raw, "sigma"), "missing field 'sigma'"),
        "trunc.bsdf": (raw[: len(raw) // 2], "truncated"),
        "header.bsdf": (raw[:40], "truncated"),
    }
    for name, (data, msg) in cases.items():
        p = tmp_path / name
        p.write_bytes(data)
        with pytest.raises(FileFormatError, match=f"{name}.*{msg}"):
            RGLBRDF(p)
    f = read_tensor_file(shared / "rgl" / "paper_white_rgb.bsdf")
    assert f["rgb"].shape[:3] == (1, 8, 3) and f["ndf"].shape == (2, 128)
    assert struct.unpack("<I", raw[14:18])[0] == len(f)
