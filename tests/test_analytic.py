import json

import numpy as np
import pytest

from conftest import random_directions
from reflecto import geometry as g
from reflecto.errors import FileFormatError, ParameterError
from reflecto.hemicube import hemicube
from reflecto.load import load_source
from reflecto.sources.analytic import AnalyticBRDF

MODELS = [
    dict(distribution="ggx", alpha=0.05, kd=0.0, ks=1.0, eta=50.0),
    dict(distribution="ggx", alpha=0.4, kd=[0.5, 0.3, 0.1], ks=0.5, eta=1.5),
    dict(distribution="beckmann", alpha=0.2, kd=0.3, ks=0.7, eta=1.5),
    dict(distribution="beckmann", alpha=(0.1, 0.4), rotation_deg=35, kd=0.1, ks=0.9, eta=2.0),
    dict(distribution="ggx", alpha=(0.4, 0.1), rotation_deg=-20, kd=0.0, ks=1.0, eta=[3.0, 2.0, 1.4]),
    dict(distribution="ggx", alpha=(0.3, 0.15), asymmetry=(0.3, 0.1, 0.3), kd=0.2, ks=0.8, eta=1.6),
    dict(distribution="ggx", alpha=1.0, kd=0.0, ks=1.0, eta=100.0),
]


@pytest.mark.parametrize("kw", MODELS)
def test_reciprocal_and_energy_conserving(kw, rng):
    src = AnalyticBRDF(**kw)
    i, o = random_directions(rng, 20000), random_directions(rng, 20000)
    a, b = src.eval(i, o), src.eval(o, i)
    assert np.all(np.isfinite(a)) and np.all(a >= 0)
    assert np.allclose(a, b, rtol=1e-6, atol=0)
    alb = src.albedo([0, 30, 60, 75, 85, 89])
    assert alb.max() <= 1.0 + 1e-3, alb
    assert np.all(alb >= 0)


def test_white_furnace_of_diffuse_term():
    src = AnalyticBRDF(kd=[1.0, 0.5, 0.25], ks=0.0)
    assert np.allclose(src.albedo([0, 45, 80]), [[1.0, 0.5, 0.25]] * 3, atol=2e-3)


def test_ndf_normalized_and_asymmetric_variant_breaks_eq3():
    c = hemicube(256)
    sym = AnalyticBRDF(distribution="ggx", alpha=(0.3, 0.15), rotation_deg=30)
    asym = AnalyticBRDF(distribution="ggx", alpha=(0.3, 0.15), rotation_deg=30, asymmetry=(0.3, 0.1, 0.3))
    tau = c.permutation(g.TAU)
    for src in (sym, asym):
        d = src.ndf(c.directions)
        assert abs(np.sum(d * c.cos_theta * c.solid_angles) - 1) < 1e-4
        centroid = (d * c.solid_angles) @ c.directions  # identity 1.5: ∫ h D dω = n
        assert np.allclose(centroid, [0, 0, 1], atol=1e-4)
    ds, da = sym.ndf(c.directions), asym.ndf(c.directions)
    assert np.allclose(ds[tau], ds, rtol=1e-9)
    assert np.abs(da[tau] - da).max() > 0.2 * da.max()


def test_invalid_parameters():
    with pytest.raises(ParameterError):
        AnalyticBRDF(alpha=-0.1)
    with pytest.raises(ParameterError):
        AnalyticBRDF(kd=0.6, ks=0.6)
    with pytest.raises(ParameterError):
        AnalyticBRDF(eta=float("nan"))
    with pytest.raises(ParameterError):
        AnalyticBRDF(distribution="phong")
    with pytest.raises(ParameterError):
        AnalyticBRDF(asymmetry=(0.1, 0.0, 1.5))


def test_description_files(tmp_path):
    p = tmp_path / "m.json"
    p.write_text(json.dumps({"type": "analytic", "distribution": "beckmann", "alpha": [0.2, 0.1], "kd": 0.1,
                             "ks": 0.5}))
    src = load_source(p)
    assert isinstance(src, AnalyticBRDF) and src.distribution == "beckmann"
    t = tmp_path / "m.toml"
    t.write_text('type = "analytic"\ndistribution = "ggx"\nalpha = 0.3\n'
                 'asymmetry = { shift = [0.2, 0.0], weight = 0.4 }\n')
    src = load_source(t)
    assert src.asymmetry == (0.2, 0.0, 0.4)
    bad = tmp_path / "bad.json"
    bad.write_text('{"type": "analytic", "alpha": 0.2, "roughness": 3}')
    with pytest.raises(FileFormatError, match="bad.json.*unknown keys"):
        load_source(bad)
    bad.write_text('{"type": "analytic", "alpha": NaN}')
    with pytest.raises(FileFormatError, match="bad.json"):
        load_source(bad)
    bad.write_text("{not json")
    with pytest.raises(FileFormatError, match="not valid JSON"):
        load_source(bad)
