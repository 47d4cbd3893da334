import numpy as np
import pytest

from reflecto import geometry as g
from reflecto.hemicube import hemicube
from reflecto.shadowing import sigma_direct, sigma_table
from reflecto.sources.analytic import AnalyticBRDF

# algorithm-reference §1.2: Smith–Beckmann G1 (= APS S) at θ_k = 60, 75, 85°
BECKMANN_TABLE = {0.1: [1.00000, 1.00000, 0.95971], 0.3: [0.99964, 0.96250, 0.64582], 0.6: [0.97148, 0.79769, 0.40394]}


def _tabulated(dist, alpha, n=512, **kw):
    src = AnalyticBRDF(distribution=dist, alpha=alpha, **kw)
    c = hemicube(n)
    d = src.ndf(c.directions)
    d /= np.sum(d * c.cos_theta * c.solid_angles)
    return src, c, d


@pytest.mark.parametrize("alpha", [0.1, 0.3, 0.6])
@pytest.mark.parametrize("dist", ["beckmann", "ggx"])
def test_aps_matches_smith_closed_form(dist, alpha):
    src, c, d = _tabulated(dist, alpha)
    table = sigma_table(c, d)
    theta = np.radians([0, 30, 60, 75, 85])
    phi = np.radians([0, 17, 45, 123, 290])
    k = g.spherical_to_cartesian(theta[:, None], phi[None, :])
    s = table.eval(k)
    assert np.abs(s - src.g1(k)).max() < 1e-3
    assert np.allclose(s[0], 1.0, atol=1e-12)  # S(n) = 1
    if dist == "beckmann":
        assert np.allclose(s[2:, 0], BECKMANN_TABLE[alpha], atol=1e-3)


def test_table_agrees_with_brute_force_integral(rng):
    src, c, d = _tabulated("ggx", (0.4, 0.15), n=64, rotation_deg=25)
    table = sigma_table(c, d)
    k = g.normalize(rng.normal(size=(300, 3)))
    k[:, 2] = np.abs(k[:, 2]) + 0.05
    k = g.normalize(k)
    assert np.allclose(table.eval_sigma(k), sigma_direct(c, d, k), rtol=0, atol=3e-3)


def test_s_is_clamped_and_azimuthal_min():
    c = hemicube(64)
    d = np.zeros(c.size)
    d[c.index(g.normalize([[0.3, 0.0, 1.0]]))] = 1.0  # a single tilted facet: centroid ≠ 0
    d /= np.sum(d * c.cos_theta * c.solid_angles)
    table = sigma_table(c, d)
    k = g.spherical_to_cartesian(np.radians(np.linspace(0, 89, 50))[:, None], np.radians(np.arange(0, 360, 30))[None])
    s = table.eval(k)
    assert s.max() <= 1.0 and s.min() >= 0.0
    iso = table.azimuthal_min()
    assert np.all(iso.eval(k) <= s + 1e-12)
    assert np.allclose(iso.sigma, iso.sigma[:, :1])


@pytest.mark.parametrize(
    "kw",
    [
        dict(distribution="ggx", alpha=(0.3, 0.1), rotation_deg=30),
        dict(distribution="beckmann", alpha=(0.2, 0.35), rotation_deg=-60),
        dict(distribution="ggx", alpha=0.25, asymmetry=(0.3, 0.1, 0.3)),
        dict(distribution="beckmann", alpha=(0.25, 0.2), asymmetry=(-0.2, 0.15, 0.4)),
    ],
)
def test_closed_form_lambda_of_anisotropic_and_asymmetric_models(kw, rng):
    # The analytic sources' Smith Λ is closed-form; the APS integral of their NDF must agree.
    src = AnalyticBRDF(**kw)
    c = hemicube(256)
    d = src.ndf(c.directions)
    assert abs(np.sum(d * c.cos_theta * c.solid_angles) - 1) < 1e-4
    table = sigma_table(c, d / np.sum(d * c.cos_theta * c.solid_angles))
    k = random_k = g.normalize(rng.normal(size=(2000, 3)))
    random_k[:, 2] = np.abs(random_k[:, 2])
    k = random_k[random_k[:, 2] > np.cos(np.radians(85))]
    assert np.abs(table.eval(k) - src.g1(k)).max() < 2e-3


def test_eval_at_a_stencil_equals_eval(rng):
    from reflecto.shadowing import grid_stencil

    c = hemicube(64)
    t = sigma_table(c, AnalyticBRDF(distribution="ggx", alpha=0.3).ndf(c.directions), n_theta=46, n_phi=64, n_u=64)
    d = g.normalize(rng.normal(size=(5000, 3)))
    d = np.concatenate([d, [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]])
    st = grid_stencil(d, 46, 64)
    s = t.eval_at(st)
    assert np.array_equal(s, t.eval(d))
    assert s[-2] == pytest.approx(1.0, abs=1e-12) and s[-1] == 0.0 and np.all(s[d[:, 2] <= 0] == 0.0)
    with pytest.raises(ValueError):
        sigma_table(c, np.ones(c.size), n_theta=91, n_phi=128).eval_at(st)
