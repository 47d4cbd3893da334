import numpy as np
import pytest

from reflecto.fresnel import FresnelTable, eta_from_f0, f0_from_eta, fresnel

# algorithm-reference §2.1 table: θ_d = 0, 30, 60, 75, 85, 89.9 degrees
TABLE = {
    1.5: [0.0400, 0.0415, 0.0892, 0.2531, 0.6128, 0.9899],
    2.0: [0.1111, 0.1130, 0.1614, 0.3087, 0.6302, 0.9900],
    5.0: [0.4444, 0.4436, 0.4272, 0.4143, 0.5395, 0.9818],
}


@pytest.mark.parametrize("eta", sorted(TABLE))
def test_reference_values(eta):
    c = np.cos(np.radians([0, 30, 60, 75, 85, 89.9]))
    assert np.allclose(fresnel(c, eta), TABLE[eta], atol=6e-5)


def test_limits_and_inverse():
    eta = np.array([1.2, 1.5, 3.0, 45.9])
    assert np.allclose(fresnel(1.0, eta), f0_from_eta(eta))
    assert np.allclose(fresnel(0.0, eta), 1.0)
    assert np.allclose(eta_from_f0(f0_from_eta(eta)), eta)
    assert fresnel(0.1, 0.8) == 1.0  # total internal reflection


def test_table_matches_formula():
    c = np.linspace(0, 1, 50001)
    for eta in (1.05, 1.5, 4.0, 50.0, 100.0):
        assert np.abs(FresnelTable([eta])(c)[:, 0] - fresnel(c, eta)).max() < 1e-5


def _random_pairs(rng, n, c_min=0.0, a_min=0.0):
    """Cosines, values, a-factors and weights of n random bin pairs (eq. 6 inputs)."""
    cp, cq = rng.uniform(c_min, 1, n), rng.uniform(c_min, 1, n)
    fp, fq = rng.uniform(0, 3, n), rng.uniform(0, 3, n)
    ap, aq, w = rng.uniform(a_min, 1, n), rng.uniform(a_min, 1, n), rng.uniform(a_min, 1, n)
    return cp, cq, fp, fq, ap, aq, w


def test_compiled_pair_residuals_match_numpy():
    from reflecto import _kernels
    from reflecto.reconstruct.fresnel_fit import pair_residuals_numpy

    rng = np.random.default_rng(4)
    n = 5000
    cp, cq, fp, fq, ap, aq, w = _random_pairs(rng, n)
    for eta, kd in [(1.5, 0.2), (0.8, 0.0), (20.0, 0.5)]:
        out = np.empty(n)
        _kernels.pair_residuals(cp, cq, fp, fq, ap, aq, w, eta, kd / np.pi, 1e-3, out)
        assert np.allclose(out, pair_residuals_numpy(cp, cq, fp, fq, ap, aq, w, eta, kd, 1e-3), rtol=1e-12, atol=1e-15)


def test_compiled_fresnel_matches_numpy():
    from reflecto.fresnel import fresnel_numpy

    rng = np.random.default_rng(5)
    c = np.concatenate([rng.uniform(-1.2, 1.2, 20000), [0.0, 1.0, -1.0, np.nan]])
    eta = np.concatenate([rng.uniform(0.3, 40.0, 20000), [1.0, 1.0, 0.5, 1.5]])
    assert np.array_equal(fresnel(c, eta), fresnel_numpy(c, eta))
    # broadcasting and scalars behave as NumPy's
    per_channel = fresnel(c[:100, None], np.array([1.3, 1.5, 2.0])[None])
    assert per_channel.shape == (100, 3)
    assert np.array_equal(per_channel, fresnel_numpy(c[:100, None], np.array([1.3, 1.5, 2.0])[None]))
    assert isinstance(fresnel(0.5, 1.5), np.floating) and fresnel(1.0, 1.5) == pytest.approx(0.04)


def test_analytic_fresnel_jacobian_matches_finite_differences():
    # the LM's Jacobian (eq. 6 residuals in η and k_d/π) against central differences of the residuals
    from reflecto import _kernels

    rng = np.random.default_rng(5)
    n = 400
    cp, cq, fp, fq, ap, aq, w = _random_pairs(rng, n, c_min=0.02, a_min=0.1)
    fp[:40] = fq[:40] = 1e-4  # pairs whose mean falls below the level: M is constant there

    def r(eta, k):
        out = np.empty(n)
        _kernels.pair_residuals(cp, cq, fp, fq, ap, aq, w, eta, k, 0.01, out)
        return out

    for eta in (1.2, 1.5, 2.4, 8.0):
        jac = np.empty((2, n))
        _kernels.pair_residuals_jac(cp, cq, fp, fq, ap, aq, w, eta, 0.02, 0.01, jac)
        h = 1e-6
        num_eta = (r(eta + h, 0.02) - r(eta - h, 0.02)) / (2 * h)
        num_kd = (r(eta, 0.02 + h) - r(eta, 0.02 - h)) / (2 * h)
        np.testing.assert_allclose(jac[0], num_eta, rtol=1e-5, atol=1e-7 * np.abs(num_eta).max())
        np.testing.assert_allclose(jac[1], num_kd, rtol=1e-5, atol=1e-7 * np.abs(num_kd).max())
        assert np.abs(jac[0]).max() > 0 and np.abs(jac[1]).max() > 0


def test_constant_fresnel_is_the_conductor_limit():
    """η = ∞ is F ≡ 1 at every angle, in both implementations and the table; F0 = 1; the
    JSON form has no infinity and reads back."""
    from reflecto.fresnel import CONSTANT, eta_from_json, eta_to_json, format_eta, fresnel_numpy, is_constant

    c = np.linspace(0.0, 1.0, 11)
    assert np.array_equal(fresnel(c, CONSTANT), np.ones(11))
    assert np.array_equal(fresnel_numpy(c, CONSTANT), np.ones(11))
    assert np.allclose(FresnelTable(np.full(3, CONSTANT))(c), 1.0)
    assert f0_from_eta(CONSTANT) == 1.0 and f0_from_eta(1.5) == pytest.approx(0.04)
    # the dielectric at a large η approaches it from below
    assert 0.999 < float(fresnel(1.0, 1e4)) < 1.0
    assert eta_to_json(np.full(3, CONSTANT)) == {"fresnel": "constant", "eta": None}
    assert eta_to_json(1.5) == {"fresnel": "dielectric", "eta": [1.5, 1.5, 1.5]}
    assert is_constant(eta_from_json(eta_to_json(CONSTANT))) and not is_constant(1.5)
    assert eta_from_json({"eta": [1.5, 1.5, 1.5]}).tolist() == [1.5] * 3  # records without "fresnel"
    assert eta_from_json({"eta": None}) is None and eta_from_json({"eta": [1.5, float("inf"), 1.5]}) is None
    assert format_eta(CONSTANT).startswith("∞") and format_eta([1.5] * 3) == "1.500"
