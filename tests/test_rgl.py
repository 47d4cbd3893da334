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


def test_marginal_warp_bisection_equals_the_column_count(rng):
    """:meth:`Marginal2D.sample` finds the conditional CDF's column by bisection; it must be
    the column the definition counts (the last whose interpolated CDF is ≤ the target),
    also on rows with flat stretches (zero density: ties) and at the corners."""
    from reflecto.sources.rgl import Marginal2D, _solve_quadratic

    data = rng.random((1, 2, 9, 13))
    data[0, 0, :, 3:7] = 0.0  # flat stretches of the CDF
    data[0, 1, 2:5, :] = 0.0  # rows of no mass
    m = Marginal2D(data, np.zeros(1), np.array([0.1, 0.6]))
    u = np.concatenate([rng.random((5000, 2)), [[0, 0], [1, 1], [0, 1], [1, 0]]])
    for k in range(2):
        d, c, marg = m.norm_data[k], m.cond[k], m.marg[k]
        uy = u[:, 1]
        py = np.clip(np.searchsorted(marg, uy, side="right") - 1, 0, m.h - 2)
        r0, r1 = c[py, -1], c[py + 1, -1]
        sy = _solve_quadratic(r0, r1, uy - marg[py])
        rows = (1 - sy)[:, None] * c[py] + sy[:, None] * c[py + 1]
        target = u[:, 0] * ((1 - sy) * r0 + sy * r1)
        px = np.clip(np.sum(rows <= target[:, None], axis=1) - 1, 0, m.w - 2)
        c0 = (1 - sy) * d[py, px] + sy * d[py + 1, px]
        c1 = (1 - sy) * d[py, px + 1] + sy * d[py + 1, px + 1]
        sx = _solve_quadratic(c0, c1, target - rows[np.arange(len(u)), px])
        expected = np.stack([(px + sx) / (m.w - 1), (py + sy) / (m.h - 1)], axis=-1)
        assert np.array_equal(m.sample(u, k), expected)


def _paper_white_fields(shared) -> dict:
    return {k: np.array(v) for k, v in read_tensor_file(shared / "rgl" / "paper_white_rgb.bsdf").items()}


@pytest.mark.parametrize("damage", ["small", "nonsquare", "zero", "negative"])
def test_a_luminance_table_mitsuba_cannot_sample_is_refused(shared, tmp_path, damage):
    """The luminance slices must be rgb's (square, the same size), non-negative and not zero in
    any incident slice: Mitsuba's plugin refuses the first two and samples a NaN pdf from the others."""
    from reflecto.export.rgl import write_tensor_file

    f = _paper_white_fields(shared)
    lum = f["luminance"]
    f["luminance"] = {"small": np.ascontiguousarray(lum[:, :, :16, :16]),
                      "nonsquare": np.ascontiguousarray(lum[:, :, :16, :]),
                      "zero": np.zeros_like(lum), "negative": -lum}[damage]
    p = write_tensor_file(tmp_path / f"{damage}.bsdf", f)
    expected = {"small": "must match the rgb slices", "nonsquare": "must match the rgb slices",
                "zero": "'luminance' is zero everywhere", "negative": "'luminance' must be non-negative"}[damage]
    with pytest.raises(FileFormatError, match=expected):
        RGLBRDF(p)


def test_rows_of_no_visible_normals_read_without_a_division_by_zero(shared, tmp_path):
    """A band of ``vndf`` rows of zeros (no mass: the conditional warp is undefined there) is
    read, and the inverse warp stays within [0, 1]² instead of giving NaN indices."""
    from reflecto.export.rgl import write_tensor_file

    f = _paper_white_fields(shared)
    f["vndf"][:, :, 60:70, :] = 0
    src = RGLBRDF(write_tensor_file(tmp_path / "rows.bsdf", f))
    table = src._vndf
    y = np.full(50, 64.5 / (table.h - 1))  # between two rows of zeros
    u = table.invert(np.stack([np.linspace(0, 1, 50), y], -1), np.zeros(50), np.full(50, 0.3))
    assert np.all(np.isfinite(u)) and np.all((u >= 0) & (u <= 1))
    rng = np.random.default_rng(0)
    assert np.all(np.isfinite(src.eval(random_directions(rng, 200, 80.0), random_directions(rng, 200, 80.0))))


def test_a_table_of_huge_ndf_values_is_judged_by_its_largest_nodes(shared, tmp_path):
    """Every ``ndf`` node of a 512² table could exceed the projected bound: the damage check visits
    at most MAX_NODES_AT_RISK of them (bounded memory) and still refuses the file."""
    from reflecto.export.rgl import write_tensor_file
    from reflecto.sources import rgl

    f = _paper_white_fields(shared)
    f["ndf"] = np.full((512, 512), 1e6, np.float32)
    f["ndf"][7, 11] = 2e6
    p = write_tensor_file(tmp_path / "bomb.bsdf", f)
    with pytest.raises(FileFormatError, match="more than any BRDF reflecto represents"):
        RGLBRDF(p)
    obj = RGLBRDF.__new__(RGLBRDF)
    obj._ndf = rgl.Marginal2D.__new__(rgl.Marginal2D)
    obj._ndf.data = f["ndf"]
    obj._rgb = [type("T", (), {"data": np.ones(4)})()]
    obj._sigma = type("T", (), {"data": np.ones(4)})()
    nodes = obj._ndf_nodes_at_risk()
    assert len(nodes) == rgl.MAX_NODES_AT_RISK and 7 * 512 + 11 in nodes and np.all(np.diff(nodes) > 0)
