import json
import zipfile

import numpy as np
import pytest

from conftest import random_directions
from reflecto import geometry as g
from reflecto.errors import FileFormatError, ParameterError
from reflecto.load import load_source
from reflecto.model import MicrofacetBRDF
from reflecto.sources.analytic import AnalyticBRDF


@pytest.fixture(scope="module")
def pair():
    ref = AnalyticBRDF(distribution="beckmann", alpha=0.2, kd=[0.3, 0.2, 0.1], ks=0.7, eta=[1.5, 1.7, 2.2])
    model = MicrofacetBRDF.from_ndf_function(ref.ndf, 512, kd=ref.kd, ks=ref.ks, eta=ref.eta)
    return ref, model


def test_model_reproduces_analytic_brdf(pair, rng):
    ref, model = pair
    i, o = random_directions(rng, 100_000, 80), random_directions(rng, 100_000, 80)
    rel = np.abs(model.eval(i, o) - ref.eval(i, o)) / ref.eval(i, o)
    assert np.median(rel) < 1e-4
    assert np.percentile(rel, 99.9) < 5e-3
    # no π slip: the specular peak is right (algorithm-reference §3.2)
    n = np.array([[0.0, 0.0, 1.0]])
    assert np.allclose(model.eval(n, n), ref.eval(n, n), rtol=1e-3)


def test_model_terms(pair):
    ref, model = pair
    c = model.cube
    assert np.isclose(np.sum(model.ndf_values * c.cos_theta * c.solid_angles), 1.0, rtol=1e-6)
    assert np.isclose(model.shadowing(np.array([0.0, 0.0, 1.0])), 1.0)
    k = g.spherical_to_cartesian(np.radians([30, 60, 75, 85]), 0.0)
    assert np.allclose(model.shadowing(k), ref.g1(k), atol=1e-3)


def test_reciprocity_energy_and_correlated(pair, rng):
    _, model = pair
    i, o = random_directions(rng, 20000), random_directions(rng, 20000)
    assert np.allclose(model.eval(i, o), model.eval(o, i), rtol=1e-6)
    assert model.albedo([0, 45, 80, 89]).max() <= 1.0
    corr = MicrofacetBRDF(model.ndf_values, model.kd, model.ks, model.eta, correlated=True)
    a, b = corr.eval(i, o), model.eval(i, o)
    assert np.all(a >= b - 1e-12)  # G2_correlated ≥ G1·G1
    assert np.allclose(corr.eval(i, o), corr.eval(o, i), rtol=1e-6)


def test_save_load_exact(pair, tmp_path, rng):
    _, model = pair
    model.metadata["material"] = "test"
    p = model.save(tmp_path / "m.reflecto")
    back = load_source(p)
    assert isinstance(back, MicrofacetBRDF)
    assert np.array_equal(back.ndf_values, model.ndf_values)
    assert back.metadata["material"] == "test"
    i, o = random_directions(rng, 1000), random_directions(rng, 1000)
    assert np.array_equal(back.eval(i, o), model.eval(i, o))
    assert not list(tmp_path.glob("*.part"))


def test_damaged_and_foreign_files(pair, tmp_path):
    _, model = pair
    good = model.save(tmp_path / "good.reflecto").read_bytes()
    trunc = tmp_path / "trunc.reflecto"
    trunc.write_bytes(good[: len(good) // 2])
    with pytest.raises(FileFormatError, match="trunc.reflecto"):
        MicrofacetBRDF.load(trunc)
    flipped = bytearray(good)
    flipped[len(good) // 3] ^= 0xFF
    (tmp_path / "flip.reflecto").write_bytes(bytes(flipped))
    with pytest.raises(FileFormatError, match="flip.reflecto"):
        MicrofacetBRDF.load(tmp_path / "flip.reflecto")
    foreign = tmp_path / "foreign.reflecto"
    with zipfile.ZipFile(foreign, "w") as z:
        z.writestr("hello.txt", "hi")
    with pytest.raises(FileFormatError, match="not a reflecto model"):
        MicrofacetBRDF.load(foreign)
    newer = tmp_path / "newer.reflecto"
    with zipfile.ZipFile(tmp_path / "good.reflecto") as zin, zipfile.ZipFile(newer, "w") as zout:
        meta = json.loads(zin.read("meta.json"))
        meta["version"] = 99
        zout.writestr("meta.json", json.dumps(meta))
        zout.writestr("ndf.npy", zin.read("ndf.npy"))
    with pytest.raises(FileFormatError, match="newer reflecto"):
        MicrofacetBRDF.load(newer)


def test_invalid_model_parameters():
    with pytest.raises(ParameterError):
        MicrofacetBRDF(np.ones(100))
    with pytest.raises(ParameterError):
        MicrofacetBRDF(np.full(3 * 16 * 16, np.nan))
    with pytest.raises(ParameterError):
        MicrofacetBRDF(np.ones(3 * 16 * 16), kd=[0.1, 0.2])
    for bad in (np.nan, np.inf, -1e-9):
        d = np.ones(3 * 16 * 16)
        d[100] = bad
        with pytest.raises(ParameterError, match="finite and non-negative"):
            MicrofacetBRDF(d)
    with pytest.raises(ParameterError, match="zero everywhere"):
        MicrofacetBRDF(np.zeros(3 * 16 * 16))


def test_ndf_is_float32_rounded_and_normalized(rng):
    # the compiled pass against the NumPy formula it replaces: round, integrate (eq. 1.2), scale, round
    d = rng.random(3 * 64 * 64) ** 4 * 7.0
    m = MicrofacetBRDF(d)
    q = d.astype(np.float32).astype(np.float64)
    total = q @ m.cube.projected_solid_angles
    ref = (q / total).astype(np.float32).astype(np.float64)
    np.testing.assert_allclose(m.ndf_values, ref, rtol=1.2e-7, atol=0)  # within one float32 ulp
    assert np.array_equal(m.ndf_values, m.ndf_values.astype(np.float32))
    assert abs(m.ndf_values @ m.cube.projected_solid_angles - 1.0) < 1e-6
    raw = MicrofacetBRDF(d, normalize=False)
    assert np.array_equal(raw.ndf_values, q)


@pytest.mark.parametrize("correlated", [False, True])
def test_compiled_eval_matches_numpy_reference(pair, rng, correlated):
    ref, model = pair
    m = MicrofacetBRDF(model.ndf_values, ref.kd, ref.ks, ref.eta, normalize=False, correlated=correlated)
    i, o = random_directions(rng, 50_000, 90), random_directions(rng, 50_000, 90)
    i[:10, 2] *= -1  # below the horizon: zero in both
    fast, slow = m.eval(i, o), m.eval_numpy(i, o)
    assert np.all(fast[:10] == 0)
    np.testing.assert_allclose(fast, slow, rtol=1e-12, atol=1e-14)
    # broadcasting a single light against many views, as the instrument does
    np.testing.assert_allclose(m.eval(i[20], o[:100]), m.eval_numpy(np.broadcast_to(i[20], (100, 3)), o[:100]),
                               rtol=1e-12)
