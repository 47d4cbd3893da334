"""The isotropic model (polar NDF table) and the 1-D reconstruction's stages and kernels."""

import math

import numpy as np
import pytest

from reflecto.errors import FileFormatError, ParameterError
from reflecto.evaluate.metrics import brdf_error
from reflecto.instrument.calibrate import nominal_calibration
from reflecto.instrument.device import Device
from reflecto.instrument.simulate import simulate_capture
from reflecto.instrument.slices import extract_slices
from reflecto.model import IsotropicMicrofacetBRDF, load_model
from reflecto.polar import IsotropicNDF, azimuthal_kernel, cell_table, polar_nodes
from reflecto.reconstruct import _polar_kernels, isotropic
from reflecto.sources.analytic import AnalyticBRDF


def _ggx(alpha=0.2, **kw):
    return AnalyticBRDF(distribution="ggx", alpha=alpha, **{"kd": 0.2, "ks": 0.8, "eta": 1.5, **kw})


def _tabulated(src):
    th = polar_nodes()
    return IsotropicMicrofacetBRDF((th, src.ndf(np.stack([np.sin(th), 0 * th, np.cos(th)], 1))), src.kd, src.ks,
                                   src.eta)


def test_polar_nodes_are_fine_at_the_pole_and_end_at_the_horizon():
    th = polar_nodes()
    assert th[0] == 0.0 and th[-1] == 0.5 * math.pi and np.all(np.diff(th) > 0)
    assert abs(math.degrees(th[1]) / 0.1 - 1) < 0.03 and math.degrees(np.diff(th).max()) < 4.0


def test_azimuthal_kernel_matches_a_quadrature():
    rng = np.random.default_rng(0)
    tk, th = rng.uniform(0, 0.5 * math.pi, 7), rng.uniform(0, 0.5 * math.pi, 9)
    phi = (np.arange(20000) + 0.5) * (2 * math.pi / 20000)
    brute = (np.maximum(0.0, np.cos(tk)[:, None, None] * np.cos(th)[None, :, None]
                        + np.sin(tk)[:, None, None] * np.sin(th)[None, :, None] * np.cos(phi)).sum(-1)
             * (2 * math.pi / 20000))
    assert np.allclose(azimuthal_kernel(tk, th), brute, atol=1e-6)


@pytest.mark.parametrize("alpha", [0.05, 0.2, 0.5])
def test_polar_ndf_normalization_and_shadowing_equal_smith(alpha):
    """Eq. 1.2 on the polar quadrature, and S = cos/σ (eq. 8) against the closed-form Smith G1."""
    src = _ggx(alpha)
    m = _tabulated(src)
    assert abs(m.ndf_table.normalization - 1.0) < 1e-6
    for deg in (0.0, 40.0, 70.0, 85.0):
        k = np.array([math.sin(math.radians(deg)), 0.0, math.cos(math.radians(deg))])
        assert abs(float(m.shadowing(k)) - float(src.g1(k))) < 2e-3, (alpha, deg)
    assert brdf_error(src, m, stride=3).normalized < 2e-3


def test_isotropic_model_file_round_trip_and_damage(tmp_path):
    m = _tabulated(_ggx(0.15))
    path = m.save(tmp_path / "m.reflecto")
    back = load_model(path)
    assert isinstance(back, IsotropicMicrofacetBRDF) and back.isotropic
    assert np.array_equal(back.ndf_table.values, m.ndf_table.values)
    i = np.array([[0.3, 0.1, 0.95]]) / np.linalg.norm([0.3, 0.1, 0.95])
    assert np.array_equal(back.eval(i, i[:, [1, 0, 2]]), m.eval(i, i[:, [1, 0, 2]]))
    raw = bytearray(path.read_bytes())
    raw[len(raw) // 2] ^= 0xFF
    (tmp_path / "bad.reflecto").write_bytes(bytes(raw))
    with pytest.raises(FileFormatError):
        load_model(tmp_path / "bad.reflecto")


def test_isotropic_ndf_refuses_impossible_tables():
    th = polar_nodes()
    for nodes, values in ((th, -np.ones_like(th)), (th, np.zeros_like(th)), (th[::-1], np.ones_like(th)),
                          (th[:-1], np.ones(len(th) - 1)), (th, np.full_like(th, np.nan))):
        with pytest.raises(ParameterError):
            IsotropicNDF(nodes, values)


def _slices(src, **kw):
    dev = Device.builtin("ideal")
    return extract_slices(simulate_capture(src, dev, seed=1, **kw), nominal_calibration(dev))


def test_compiled_polar_binning_matches_numpy():
    sl = _slices(_ggx(0.1))
    nodes = polar_nodes()
    edges = np.interp(np.arange((len(nodes) - 1) * 2 + 1) / 2, np.arange(len(nodes)), nodes)
    mask = sl.valid & ~sl.censored
    n_td = int(math.ceil(0.5 * math.pi / isotropic.TD_STEP)) + 1
    n_keys = sl.n_leds * (len(edges) - 1) * n_td
    count, sums, fs = np.zeros(n_keys), np.zeros((n_keys, 5)), np.zeros((n_keys, 3))
    bound = np.ascontiguousarray(sl.limit)
    _polar_kernels.bin_polar(mask, sl.light, sl.view, sl.values, sl.noise, bound, edges, cell_table(edges.tobytes()),
                             isotropic.TD_STEP, n_td, *isotropic.theta_d_tables(n_td), count, sums, fs)
    ref = isotropic.bin_polar_numpy(mask, sl.light, sl.view, sl.values, sl.noise, bound, edges, n_td)
    assert np.array_equal(count, ref[0]) and count.sum() == mask.sum()
    assert np.allclose(sums, ref[1], rtol=1e-10, atol=1e-12) and np.allclose(fs, ref[2], rtol=1e-10, atol=1e-14)


def test_compiled_normal_equations_match_numpy():
    rng = np.random.default_rng(2)
    k, n = 30, 5000
    j = rng.integers(0, k - 1, n)
    t, spec, r = rng.random(n), rng.random(n), rng.standard_normal(n)
    w = np.where(rng.random(n) < 0.2, 0.0, rng.random(n))
    dcols = np.ascontiguousarray(rng.standard_normal((n, 3)))
    out = [np.empty(k), np.empty(k - 1), np.empty((k, 3)), np.empty((3, 3)), np.empty(k), np.empty(3)]
    _polar_kernels.normal_equations(j.astype(np.int64), t, spec, dcols, r, w, k, *out)
    for a, b in zip(out, isotropic.normal_equations_numpy(j, t, spec, dcols, r, w, k)):
        assert np.allclose(a, b, rtol=1e-10, atol=1e-12)


def test_normal_equations_are_the_gradient_of_the_cost():
    """JᵀWr + Hz − β (assembled, with the k_s tie too) against finite differences of the cost."""
    sl = _slices(_ggx(0.2))
    nodes = polar_nodes()
    bins = isotropic.bin_polar(sl, nodes, sl.valid)
    p = isotropic.LuminanceProblem(bins, nodes)
    s = isotropic.initial_state(p, 1.6)
    isotropic.set_weights(p)
    isotropic.prior(p, s)
    k = len(nodes)
    for tie in (False, True):
        st = s.copy()
        if tie:  # on the bound k_s = 1: the NDF normalized, g = 1
            st.z, st.g = st.z - math.log(isotropic.normalization(nodes, st.z)[0]), 1.0
        _, grad = isotropic._normal_equations(p, st, tie)
        c0 = p.cost(st)
        for q in (5, 20, 40, k, k + 2) + (() if tie else (k + 1,)):
            h = 1e-6
            step = np.zeros(k + 3)
            step[q] = h
            num = (p.cost(isotropic._apply(p, st, step, tie)) - c0) / h / 2.0
            assert abs(num - grad[q]) <= 1e-3 * abs(grad).max() + 1e-3 * abs(grad[q]), (tie, q, num, grad[q])


def test_censored_samples_bound_the_fit_from_above():
    """GGX α = 0.05 without diffuse: 85 % of the samples read 0–1 DN. As bounds they hold the
    NDF's tail (measured nowhere) to the truth within 10 % out to 60°."""
    src = _ggx(0.05, kd=0.0)
    sl = _slices(src)
    fit = isotropic.fit_isotropic(sl, sl.valid)
    th = np.radians([20.0, 40.0, 60.0])
    h = np.stack([np.sin(th), 0 * th, np.cos(th)], 1)
    assert np.allclose(fit.model.ndf(h), src.ndf(h), rtol=0.1)
    assert fit.bins[1] > fit.bins[0]  # more censored bins than measured ones


def test_lobe_log_recovers_ggx_and_beckmann_shapes():
    nodes = polar_nodes()
    h = np.stack([np.sin(nodes), 0 * nodes, np.cos(nodes)], 1)
    seen = nodes < math.radians(40)
    for dist in ("ggx", "beckmann"):
        d = AnalyticBRDF(distribution=dist, alpha=0.15).ndf(h)
        lobe = isotropic.lobe_log(nodes, np.log(np.maximum(d, 1e-300)), seen)
        far = (nodes > math.radians(40)) & (nodes < math.radians(80)) & (d > 1e-20 * d.max())
        assert np.allclose(lobe[far], np.log(d[far]), atol=0.02), dist


def test_an_ndf_from_a_fits_log_state_is_the_constructors():
    """``IsotropicNDF.from_log`` (the fit's rounds, checking only the state's finiteness) gives
    the constructor's table, values and σ bit for bit, the state's scale removed."""
    nodes = polar_nodes()
    z = -np.tan(nodes) ** 2 / 0.04 + 3.7 - 4.0 * np.log(np.cos(np.minimum(nodes, 1.5)))
    a, b = IsotropicNDF.from_log(nodes, z), IsotropicNDF(nodes, np.exp(z - z.max()))
    for x, y in ((a.log_values, b.log_values), (a.values, b.values), (a.sigma, b.sigma)):
        assert np.array_equal(x, y) and not x.flags.writeable
    assert a.normalization == pytest.approx(1.0, rel=1e-12)
    with pytest.raises(ParameterError, match="finite"):
        IsotropicNDF.from_log(nodes, np.where(nodes > 1.0, np.nan, z))


def test_difference_gram_scaled_equals_the_scaled_rows_product():
    """The priors' first-difference Gram matrix, cached and scaled afterwards, equals the
    product of the scaled difference rows bit for bit (its entries are 0, ±1 and 2), so the
    prior's matrices do not depend on which way they are assembled."""
    rng = np.random.default_rng(3)
    k = len(polar_nodes())
    for rows in ((k - 2,), tuple(range(40, k - 1)), tuple(sorted(rng.choice(k - 1, 12, replace=False).tolist())),
                 (5, 6, 7, 30, 31)):
        p = np.zeros((len(rows), k))
        p[np.arange(len(rows)), np.asarray(rows) + 1] = 1.0
        p[np.arange(len(rows)), np.asarray(rows)] = -1.0
        for scale in (1.0, 0.1 * math.pi, rng.lognormal(0.0, 5.0)):
            assert np.array_equal(scale * isotropic._difference_gram(k, rows), scale * p.T @ p)
    assert not isotropic._difference_gram(k, (3,)).flags.writeable


def test_fresnel_tint_interpolates_holds_and_refuses_impossible_tables():
    from reflecto.fresnel import FresnelTint

    t = FresnelTint(np.radians([30.0, 60.0]), [[1.0, 0.5, 0.0], [0.5, 1.0, 1.0]])
    c = np.cos(np.radians([0.0, 30.0, 45.0, 60.0, 89.0]))
    assert np.allclose(t(c)[:, 0], [1.0, 1.0, 0.75, 0.5, 0.5])  # constant beyond the nodes, linear between
    assert t(c).shape == (5, 3)
    for theta, values in (([0.1], [[1, 1, 1]]), ([0.5, 0.2], np.ones((2, 3))), ([0.1, 2.0], np.ones((2, 3))),
                          ([0.1, 0.2], [[1, 1, -0.5], [1, 1, 1]]), ([0.1, 0.2], [[1, 1, np.nan], [1, 1, 1]])):
        with pytest.raises(ParameterError):
            FresnelTint(theta, values)


def test_fresnel_tint_continues_the_trend_of_its_nodes_beyond_the_last():
    from reflecto.fresnel import MAX_TINT, FresnelTint

    values = [[1.0, 0.5, 0.0], [0.5, 1.0, 1.0]]
    nodes = np.radians([30.0, 60.0])
    held, trend = FresnelTint(nodes, values), FresnelTint(nodes, values, "trend")
    inside = np.cos(np.radians([0.0, 30.0, 45.0, 60.0]))
    assert np.allclose(trend(inside), held(inside), rtol=1e-12)  # the nodes and below: unchanged
    td = np.radians([70.0, 80.0, 89.0])
    u = np.minimum((math.cos(nodes[1]) - np.cos(td)) / (math.cos(nodes[0]) - math.cos(nodes[1])), 1.0)
    assert 0 < u[0] < u[1] < 1 and u[2] == 1  # no further than the nodes' own span (0.37 in cos θ_d)
    # τ_K r^u with r = τ_K/τ_1 per channel: R falls by half per unit of u, G doubles; B starts at 0, held
    assert np.allclose(trend(np.cos(td)), np.stack([0.5 * 0.5 ** u, 2.0 ** u, np.ones(3)], 1), rtol=1e-12)
    assert np.allclose(held(np.cos(td)), [[0.5, 1.0, 1.0]] * 3)
    extreme = FresnelTint(np.radians([0.0, 1e-7]), [[1e-310, 1, 1], [4e6, 1, 1]], "trend")  # no span, huge ratio
    assert np.all(np.isfinite(extreme(np.cos(np.radians([0.0, 45.0, 89.0])))))
    steep = FresnelTint(nodes, [[1e-6, 1, 1], [MAX_TINT, 1, 1]], "trend")
    assert steep(np.cos(np.radians(89.0)))[0] == MAX_TINT  # bounded
    with pytest.raises(ParameterError, match="continuation"):
        FresnelTint(nodes, values, "linear")
    later = FresnelTint(nodes, values, "trend", trend_from=np.radians(75.0))  # held to 75°, the trend from there
    assert np.allclose(later(np.cos(np.radians([60.0, 70.0, 75.0]))), [[0.5, 1.0, 1.0]] * 3)
    u89 = (math.cos(np.radians(75.0)) - math.cos(np.radians(89.0))) / (math.cos(nodes[0]) - math.cos(nodes[1]))
    assert np.allclose(later(math.cos(np.radians(89.0)))[1], 2.0 ** u89)
    for bad in (dict(beyond="trend", trend_from=np.radians(50.0)), dict(trend_from=np.radians(70.0))):
        with pytest.raises(ParameterError, match="trend_from"):
            FresnelTint(nodes, values, **bad)


def test_a_tint_that_continues_its_trend_round_trips_and_a_bad_form_is_refused(tmp_path):
    import json
    import zipfile

    from reflecto.fresnel import FresnelTint
    from reflecto.io import content_digest

    src = _ggx(0.15)
    th = polar_nodes()
    ndf = (th, src.ndf(np.stack([np.sin(th), 0 * th, np.cos(th)], 1)))
    tint = (np.radians([37.0, 67.0]), [[1.0, 0.6, 0.2], [0.5, 1.0, 1.0]])
    m = IsotropicMicrofacetBRDF(ndf, 0.1, 0.8, 1.5, tint=FresnelTint(*tint, beyond="trend", trend_from=tint[0][-1]))
    held = IsotropicMicrofacetBRDF(m.ndf_table, 0.1, 0.8, 1.5, tint=tint)
    td = np.radians(80.0)
    i, o = np.array([np.sin(td), 0.0, np.cos(td)]), np.array([-np.sin(td), 0.0, np.cos(td)])
    ratio = (m.eval(i, o) - 0.1 / math.pi) / (held.eval(i, o) - 0.1 / math.pi)
    u = (math.cos(np.radians(67.0)) - math.cos(td)) / (math.cos(np.radians(37.0)) - math.cos(np.radians(67.0)))
    assert np.allclose(ratio, [0.5 ** u, (1 / 0.6) ** u, 5.0 ** u], rtol=1e-3)
    path = m.save(tmp_path / "m.reflecto")
    with zipfile.ZipFile(path) as z:
        meta = json.loads(z.read("meta.json"))
    assert meta["version"] == 6 and meta["tint_beyond"] == "trend"  # a version-5 reader refuses it
    back = load_model(path)
    assert back.tint.beyond == "trend" and back.tint.trend_from == m.tint.trend_from
    assert np.array_equal(back.eval(i, o), m.eval(i, o))
    assert back.parameters()["fresnel_tint"]["beyond the last node"] == "trend from 67.0°"
    with zipfile.ZipFile(held.save(tmp_path / "h.reflecto")) as z:
        assert "tint_beyond" not in json.loads(z.read("meta.json"))  # constant: the version-4 file as before
    for bad, message in (("sideways", "invalid tint_beyond"), (None, None), (5, "needs model format version 6"),
                         ({"tint_trend_from": "far"}, "invalid tint_trend_from"),
                         ({"tint_trend_from": 0.1}, "between its last node")):
        members = {n: zipfile.ZipFile(path).read(n) for n in zipfile.ZipFile(path).namelist()}
        meta = json.loads(members["meta.json"])
        if bad is None:  # a continuation without a tint
            for name in ("tint", "tint_theta"):
                members.pop(f"{name}.npy")
                meta["arrays"].pop(name)
            message = "without a Fresnel tint"
        elif isinstance(bad, int):  # an older version that a version-5 reader would read without it
            meta["version"] = bad
        elif isinstance(bad, dict):
            meta.update(bad)
        else:
            meta["tint_beyond"] = bad
        meta.pop("sha256")
        meta["sha256"] = content_digest(meta)
        members["meta.json"] = json.dumps(meta).encode()
        out = tmp_path / "bad.reflecto"
        with zipfile.ZipFile(out, "w") as z:
            for n, data in members.items():
                z.writestr(n, data)
        with pytest.raises(FileFormatError, match=message):
            load_model(out)


def test_tinted_model_evaluates_file_round_trips_and_refuses_a_damaged_tint(tmp_path):

    from reflecto.fresnel import fresnel

    src = _ggx(0.15)
    th = polar_nodes()
    tint = (np.radians([37.0, 67.0]), [[1.0, 0.6, 0.2], [0.5, 1.0, 1.0]])
    m = IsotropicMicrofacetBRDF((th, src.ndf(np.stack([np.sin(th), 0 * th, np.cos(th)], 1))), 0.1, 0.8, 1.5,
                                tint=tint)
    plain = IsotropicMicrofacetBRDF(m.ndf_table, 0.1, 0.8, 1.5)
    td = np.radians(50.0)
    i = np.array([np.sin(td), 0.0, np.cos(td)])
    o = np.array([-np.sin(td), 0.0, np.cos(td)])
    spec, spec_plain = m.eval(i, o) - 0.1 / math.pi, plain.eval(i, o) - 0.1 / math.pi
    assert np.allclose(spec / spec_plain, [0.78333, 0.77333, 0.54667], rtol=1e-3)  # τ at 50°: 13/30 of the way
    assert np.allclose(m.fresnel(np.cos(td)), fresnel(np.cos(td), 1.5) * np.array([0.78333, 0.77333, 0.54667]),
                       rtol=1e-4)
    back = load_model(m.save(tmp_path / "m.reflecto"))
    assert np.array_equal(back.tint.values, m.tint.values) and np.array_equal(back.tint.theta, m.tint.theta)
    assert np.array_equal(back.eval(i, o), m.eval(i, o))
    assert "fresnel_tint" in back.parameters()
    assert np.allclose(back.to_hemicube(32).fresnel(np.cos(td)), m.fresnel(np.cos(td)))
    # a negative tint, with consistent checksums, is refused by name
    bad = np.array([[1.0, 1.0, 1.0], [1.0, 1.0, -2.0]], "<f8")
    with pytest.raises(FileFormatError, match="Fresnel tint"):
        load_model(_with_array(tmp_path / "m.reflecto", "tint", bad, tmp_path / "bad.reflecto"))


def test_reconstruction_recovers_a_colour_that_changes_with_angle():
    """A GGX lobe with η 1.2 / 2 / 6 in R / G / B: its specular colour changes with θ_d as no
    single η's curve does. The tint holds it where the device measures it (the two LEDs that
    see the mirror direction, θ_d ≈ 38° and 67°)."""
    from reflecto.fresnel import fresnel
    from reflecto.reconstruct.pipeline import reconstruct, usable_samples

    src = AnalyticBRDF(distribution="ggx", alpha=0.12, kd=0.05, ks=0.8, eta=[1.2, 2.0, 6.0])
    slices = _slices(src)
    model = reconstruct(slices).model
    assert model.tint is not None and len(model.tint.theta) == 2
    assert np.allclose(np.degrees(model.tint.theta), [38.0, 66.0], atol=3.0)
    for td in model.tint.theta:  # k_s F_c at the nodes: the truth within 5 % (0.002 on red's F0 of 0.008)
        truth = 0.8 * fresnel(np.cos(td), np.array([1.2, 2.0, 6.0]))
        assert np.allclose(model.ks * model.fresnel(np.cos(td)), truth, rtol=0.05, atol=0.002)
    lum = isotropic.fit_luminance(isotropic.bin_polar(slices, polar_nodes(), usable_samples(slices)), polar_nodes())
    one_eta = IsotropicMicrofacetBRDF(model.ndf_table, *isotropic.channel_scalars(lum), model.eta)
    assert brdf_error(src, model, stride=3).normalized < 0.75 * brdf_error(src, one_eta, stride=3).normalized


def test_tint_nodes_stand_where_a_slice_holds_the_mirror_direction():
    rng = np.random.default_rng(3)
    td = np.radians(np.r_[rng.normal(38, 0.3, 50), rng.normal(67, 0.3, 50), rng.uniform(10, 70, 100)])
    th = np.radians(np.r_[rng.uniform(0, 3, 100), rng.uniform(20, 40, 100)])
    led = np.r_[np.zeros(50, int), np.ones(50, int), np.full(100, 2)]
    info = np.r_[np.ones(100), np.full(100, 1e-3)]
    assert np.allclose(np.degrees(isotropic.tint_nodes(td, th, info, led)), [38, 67], atol=0.2)
    # LED 2 sees only the flank (θ_h ≥ 20°): no node of its own, whatever its θ_d
    # a broad lobe: the spreads overlap, but the two LEDs still measure the scale's slope
    broad = np.radians(np.r_[rng.normal(40, 15, 50), rng.normal(50, 15, 50)])
    assert np.allclose(np.degrees(isotropic.tint_nodes(broad, th[:100], np.ones(100), led[:100])),
                       np.degrees([broad[:50].mean(), broad[50:].mean()]))
    same = np.radians(np.r_[rng.normal(50, 15, 50), rng.normal(50.5, 15, 50)])
    same[50:] += same[:50].mean() - same[50:].mean() + np.radians(0.5)  # means 0.5° apart: one θ_d cell
    assert len(isotropic.tint_nodes(same, th[:100], np.ones(100), led[:100])) == 1
    # five LEDs whose spreads overlap pairwise chain across 24°: pooled into two nodes, not one
    means, spreads = [49.1, 56.2, 57.5, 65.9, 73.3], [9.7, 8.8, 8.7, 7.6, 6.6]
    chain = np.radians(np.concatenate([m + s * rng.standard_normal(200) for m, s in zip(means, spreads)]))
    nodes = np.degrees(isotropic.tint_nodes(chain, np.zeros(1000), np.ones(1000), np.repeat(np.arange(5), 200)))
    assert len(nodes) == 2 and nodes[0] < 57 < 65 < nodes[1]
    assert len(isotropic.tint_nodes(td[100:], th[100:], info[100:], led[100:])) == 0  # no mirror direction


def test_a_tint_peak_between_fixed_angles_is_held_to_albedo_one(tmp_path):
    """A tint can make the specular level peak at one θ_d; the energy limit and the file
    check look at the tint's nodes and midpoints, not only at fixed incidence angles."""
    import json
    import zipfile

    from reflecto.fresnel import fresnel
    from reflecto.reconstruct.pipeline import limit_energy

    src = _ggx(0.05)
    th = polar_nodes()
    nodes = np.radians([35.0, 45.0, 55.0])
    tint = (nodes, np.outer([0.0, 1.0 / float(fresnel(np.cos(nodes[1]), 1.5)), 0.0], np.ones(3)))
    m = IsotropicMicrofacetBRDF((th, src.ndf(np.stack([np.sin(th), 0 * th, np.cos(th)], 1))), 0.45, 0.9, 1.5,
                                tint=tint)
    assert m.albedo(np.array([45.0])).max() > 1.1
    with pytest.raises(ParameterError):
        m.save(tmp_path / "bright.reflecto")
    limited, scale, albedo = limit_energy(m)
    assert scale < 0.95 and limited.albedo(np.array([45.0])).max() <= 1.0 + 1e-3 and limited.tint is m.tint
    path = limited.save(tmp_path / "m.reflecto")
    with zipfile.ZipFile(path) as z:
        assert json.loads(z.read("meta.json"))["version"] == 4  # a version-3 reader refuses it


def test_a_rising_trend_that_would_create_energy_is_held_instead_of_scaling_the_model():
    """Continuing a rising tint toward grazing can push the albedo above 1; the trend is an
    extrapolation, so it gives way (the tint held at its last node) rather than scaling the
    model at every angle."""
    from reflecto.fresnel import FresnelTint
    from reflecto.reconstruct.pipeline import limit_energy, limit_energy_of_the_trend

    th = polar_nodes()
    ndf = (th, _ggx(0.1).ndf(np.stack([np.sin(th), 0 * th, np.cos(th)], 1)))
    nodes, values = np.radians([38.0, 67.0]), [[0.3] * 3, [1.0] * 3]
    rising = IsotropicMicrofacetBRDF(ndf, 0.5, 1.0, 1.5, tint=FresnelTint(nodes, values, "trend"))
    assert rising.albedo(np.array([89.0])).max() > 1.05
    assert limit_energy(rising)[1] < 0.95  # scaling would lower it everywhere
    model, scale, albedo = limit_energy_of_the_trend(rising)
    assert model.tint.beyond == "constant" and scale == 1.0 and albedo < 0.9
    assert np.array_equal(model.tint.values, rising.tint.values) and model.kd[0] == 0.5
    falling = IsotropicMicrofacetBRDF(ndf, 0.5, 1.0, 1.5, tint=FresnelTint(nodes, values[::-1], "trend"))
    assert limit_energy_of_the_trend(falling)[0] is falling  # within 1: kept as it is


def _ggx_lobe(alpha):
    th = polar_nodes()
    return _ggx(alpha).ndf(np.stack([np.sin(th), 0 * th, np.cos(th)], 1))


def _changing_lobe(alphas=(0.05, 0.15), at_deg=(38.0, 67.0), **kw):
    """A BRDF whose lobe widens with θ_d: GGX α 0.05 up to 38°, 0.15 from 67°, mixed between."""
    th = polar_nodes()
    return IsotropicMicrofacetBRDF((th, _ggx_lobe(alphas[1])), **{"kd": 0.05, "ks": 0.8, "eta": 1.5, **kw},
                                   lobes=(np.radians(at_deg), [_ggx_lobe(a) for a in alphas]))


def test_the_energy_limit_scales_a_model_with_an_ndf_per_node_and_keeps_everything_else():
    """``limit_energy`` scales ``k_d`` and ``k_s`` and nothing else: the NDF per θ_d node,
    the tint, the shadowing form and the metadata stay, so the limited model's albedo is
    the scaled model's (≤ 1), not that of a model without its node lobes."""
    from reflecto.reconstruct.pipeline import limit_energy

    nodes = np.radians([38.0, 67.0])
    m = _changing_lobe(kd=0.95, ks=1.0, correlated=True, metadata={"name": "bright"},
                       tint=(nodes, np.ones((2, 3))))
    angles = np.array([0.0, 30.0, 60.0, 75.0, 85.0])
    assert m.albedo(angles).max() > 1.05
    limited, scale, albedo = limit_energy(m)
    assert 0.5 < scale < 0.95 and albedo == 1.0
    assert limited.lobes is m.lobes and limited.tint is m.tint and limited.ndf_table is m.ndf_table
    assert limited.correlated and limited.metadata == {"name": "bright"}
    assert np.allclose(limited.kd, scale * m.kd) and np.allclose(limited.ks, scale * m.ks)
    rng = np.random.default_rng(3)
    i, o = (v / np.linalg.norm(v, axis=1, keepdims=True) for v in np.abs(rng.normal(size=(2, 400, 3))))
    assert np.allclose(limited.eval(i, o), scale * m.eval(i, o), rtol=1e-12)
    assert limited.albedo(angles).max() <= 1.0 + 1e-3


def test_an_ndf_per_theta_d_node_interpolates_stays_normalized_reciprocal_and_round_trips(tmp_path):

    from reflecto.polar import NodeNDFs

    m = _changing_lobe()
    narrow, wide = (IsotropicNDF(polar_nodes(), _ggx_lobe(a)) for a in (0.05, 0.15))
    th = np.radians([0.0, 1.0, 5.0, 20.0])
    for td, u in ((20.0, 0.0), (38.0, 0.0), (52.5, 0.5), (67.0, 1.0), (80.0, 1.0)):
        expect = (1 - u) * narrow.at_theta(th) + u * wide.at_theta(th)
        assert np.allclose(m.lobes.at(th, np.radians(td)), expect, rtol=2e-6)  # float32 tables
    q = isotropic._quadrature(polar_nodes().tobytes())  # ∫ D cos dω = 1 at every θ_d
    for td in (10.0, 50.0, 75.0):
        d = m.lobes.at(0.5 * np.pi * ((np.arange(2048) + 0.5) / 2048) ** 2, np.radians(td))
        assert abs(float(q.norm_weights @ d) - 1.0) < 1e-4
    rng = np.random.default_rng(0)
    i, o = (v / np.linalg.norm(v, axis=1, keepdims=True) for v in np.abs(rng.normal(size=(2, 500, 3))))
    assert np.allclose(m.eval(i, o), m.eval(o, i), rtol=1e-12)
    # at a node's θ_d the lobe is that node's microfacet lobe, its own S included: at θ_d ≤ 38°
    # the model is the α 0.05 model, at θ_d ≥ 67° the α 0.15 one
    for alpha, sel in ((0.05, np.degrees(np.arccos(np.abs(np.einsum("ij,ij->i", i, (i + o) / np.linalg.norm(
            i + o, axis=1, keepdims=True))))) <= 38.0), (0.15, None)):
        plain = IsotropicMicrofacetBRDF((polar_nodes(), _ggx_lobe(alpha)), 0.05, 0.8, 1.5)
        if sel is None:
            td = np.radians(np.linspace(67.0, 89.0, 12))
            i1 = np.stack([np.sin(td), 0 * td, np.cos(td)], 1)
            o1 = np.stack([-np.sin(td), 0 * td, np.cos(td)], 1)
            assert np.allclose(m.eval(i1, o1), plain.eval(i1, o1), rtol=1e-6)
        else:
            assert sel.sum() > 50 and np.allclose(m.eval(i[sel], o[sel]), plain.eval(i[sel], o[sel]), rtol=1e-6)
    back = load_model(m.save(tmp_path / "m.reflecto"))
    assert np.array_equal(back.lobes.values, m.lobes.values) and np.array_equal(back.eval(i, o), m.eval(i, o))
    assert set(back.parameters()["ndf_per_theta_d"]) == {"38.0°", "67.0°"}
    with pytest.raises(ParameterError, match="increase"):
        NodeNDFs(np.radians([67.0, 38.0]), [narrow, wide])
    with pytest.raises(ParameterError, match="one NDF each"):
        NodeNDFs(np.radians([38.0, 50.0, 67.0]), [narrow, wide])
    # an unnormalized node table, with consistent checksums, is refused by name
    bad = (back.lobes.values * np.array([[1.0], [3.0]])).astype("<f4")
    with pytest.raises(FileFormatError, match="θ_d node 67.0° is not normalized"):
        load_model(_with_array(tmp_path / "m.reflecto", "lobes", bad, tmp_path / "bad.reflecto"))


def test_reconstruction_recovers_a_lobe_that_changes_with_theta_d():
    """GGX α 0.05 at θ_d ≤ 38°, α 0.15 at θ_d ≥ 67°: the NDF per node holds both widths where
    the two LEDs that see the mirror direction measure them, and the error falls below the
    one-NDF fit's, whose compromise is neither."""
    import functools

    from reflecto.reconstruct.pipeline import usable_samples

    src = _changing_lobe()
    slices = _slices(src)
    fit = isotropic.fit_isotropic(slices, usable_samples(slices) & slices.valid)
    model = fit.model
    assert model.lobes is not None and np.allclose(np.degrees(model.lobes.theta_d), [38.0, 67.0], atol=2.0)
    theta = np.radians(np.linspace(0.0, 30.0, 30001))

    def half_width(ndf):
        v = ndf.at_theta(theta)
        return np.degrees(theta[np.argmax(v < 0.5 * v[0])])

    truth = [half_width(d) for d in src.lobes.ndfs]  # 1.85° and 5.6°
    got = [half_width(d) for d in model.lobes.ndfs]
    # the grazing node's slice (LED 2) reaches below 67°, where the truth mixes in the
    # narrow lobe, so its lobe comes out narrower than the truth at 67° (4.6°)
    assert abs(got[0] - truth[0]) < 0.05 * truth[0] and 0.75 * truth[1] < got[1] < truth[1], (got, truth)
    one = functools.partial(isotropic.tinted_scalars, per_node=False)(fit.luminance, fit.ceiling())
    one_ndf = IsotropicMicrofacetBRDF(model.ndf_table, one[0], one[1], model.eta, tint=one[2])
    assert half_width(model.ndf_table) < 0.5 * truth[1]  # the one NDF: the narrow node's, for every θ_d
    # 0.20 against 0.24: the error lies at grazing θ_d, where the node's lobe is the narrower above
    assert brdf_error(src, model, stride=3).normalized < 0.88 * brdf_error(src, one_ndf, stride=3).normalized


def test_a_model_file_with_a_damaged_array_table_or_sample_normal_is_refused_by_name(tmp_path):
    import json
    import zipfile

    from reflecto.io import content_digest

    m = _changing_lobe()
    m.metadata.update({"normal": [0.0, 0.0, 1.0], "normal_tilt_deg": 0.0, "normal_uncertainty_deg": None,
                       "normal_source": "device"})
    good = m.save(tmp_path / "m.reflecto")
    assert load_model(good).metadata["normal_tilt_deg"] == 0.0
    with zipfile.ZipFile(good) as z:
        members = {n: z.read(n) for n in z.namelist()}

    def damaged(edit):
        meta = json.loads(members["meta.json"])
        edit(meta)
        meta.pop("sha256")
        meta["sha256"] = content_digest(meta)
        out = tmp_path / "bad.reflecto"
        with zipfile.ZipFile(out, "w") as z:
            for name, data in {**members, "meta.json": json.dumps(meta).encode()}.items():
                z.writestr(name, data)
        return out

    with pytest.raises(FileFormatError, match="member name must be a string"):
        load_model(damaged(lambda meta: meta["arrays"]["ndf"].update(file=["ndf.npy"])))
    for key, value in (("normal_tilt_deg", "abc"), ("normal_tilt_deg", float("nan")), ("normal", [0, 0, 2]),
                       ("normal_uncertainty_deg", [1])):
        with pytest.raises(FileFormatError, match=f"metadata '{key}' is not a valid sample normal entry"):
            load_model(damaged(lambda meta, key=key, value=value: meta["metadata"].update({key: value})))
    with pytest.raises(FileFormatError, match="lobes.npy. needs model format version 5, the file says 4"):
        load_model(damaged(lambda meta: meta.update(version=4)))


def test_saving_refuses_unnormalized_node_lobes_and_info_reports_a_lobe_that_never_halves(tmp_path):
    th = polar_nodes()
    lobe = IsotropicNDF(th, _ggx_lobe(0.1)).values
    bad = IsotropicMicrofacetBRDF((th, lobe), kd=0.05, ks=0.8, eta=1.5, normalize=False,
                                  lobes=(np.radians([38.0, 67.0]), [lobe, 3.0 * lobe]))
    with pytest.raises(ParameterError, match="not saved.*NDF of θ_d node 67.0° is not normalized"):
        bad.save(tmp_path / "bad.reflecto")
    assert not (tmp_path / "bad.reflecto").exists()
    flat = IsotropicMicrofacetBRDF((th, lobe), kd=0.05, ks=0.8, eta=1.5, lobes=(np.radians([38.0, 67.0]),
                                                                                 [lobe, np.ones_like(lobe)]))
    widths = flat.parameters()["ndf_per_theta_d"]
    assert widths["67.0°"] == "half width 90.00°"
    assert 1.0 < float(widths["38.0°"].split()[-1].rstrip("°")) < 10.0


def _with_array(path, name, array, out):
    """A copy of the model file ``path`` with array ``name`` replaced and every checksum
    consistent: what the loader must refuse by its content, not by a checksum."""
    import json
    import zipfile

    from reflecto.io import content_digest, npy_bytes, sha256

    with zipfile.ZipFile(path) as z:
        members = {n: z.read(n) for n in z.namelist()}
    meta = json.loads(members["meta.json"])
    members[f"{name}.npy"] = npy_bytes(array)
    meta["arrays"][name]["sha256"] = sha256(members[f"{name}.npy"])
    meta.pop("sha256")
    meta["sha256"] = content_digest(meta)
    members["meta.json"] = json.dumps(meta).encode()
    with zipfile.ZipFile(out, "w") as z:
        for n, data in members.items():
            z.writestr(n, data)
    return out


def test_a_diffuse_ceiling_of_zero_gives_k_d_zero_exactly():
    """Where the data put k_d's ceiling at 0, the channel's k_d is 0, not the 1e-300 the bounded
    solver's open box needed: the note "k_d = 0 in channels …" and the summary's k_d agree."""
    from reflecto.reconstruct.isotropic import _bounded_scalars

    rng = np.random.default_rng(0)
    a = np.column_stack([np.full(50, 1 / np.pi), rng.uniform(0.1, 1.0, 50)])
    f = np.column_stack([a @ [0.3, 0.5], a @ [0.2, 0.4], a @ [0.0, 0.6]])
    x = _bounded_scalars(a, np.ones(50), f, np.array([0.4, 0.0, 0.0]), np.array([1.0]))
    assert x[0, 1] == 0.0 and x[0, 2] == 0.0 and abs(x[0, 0] - 0.3) < 1e-9


def test_a_model_file_with_more_lobes_than_a_device_can_make_is_refused(tmp_path, monkeypatch):
    """Each θ_d node's lobe is a table with its own shadowing: a file of 1,024 of them (12.7 KB)
    took 20 s and 1.4 GB to read. At most MAX_LOBE_NODES (64) are saved and loaded; a file of
    65 (written past the check) is refused, one line."""
    import reflecto.model as model_module
    from reflecto.model import MAX_LOBE_NODES

    th = polar_nodes()
    lobe = IsotropicNDF(th, _ggx_lobe(0.1)).values

    def with_lobes(n):
        return IsotropicMicrofacetBRDF((th, lobe), kd=0.05, ks=0.8, eta=1.5,
                                       lobes=(np.radians(np.linspace(10.0, 80.0, n)), [lobe] * n))

    path = with_lobes(MAX_LOBE_NODES).save(tmp_path / "m64.reflecto")
    assert len(load_model(path).lobes.ndfs) == MAX_LOBE_NODES
    with pytest.raises(ParameterError, match="65 lobes_theta_d nodes, more than 64"):
        with_lobes(MAX_LOBE_NODES + 1).save(tmp_path / "m65.reflecto")
    monkeypatch.setattr(model_module, "MAX_LOBE_NODES", 10_000)
    path = with_lobes(MAX_LOBE_NODES + 1).save(tmp_path / "m65.reflecto")
    monkeypatch.undo()
    with pytest.raises(FileFormatError, match="65 lobes_theta_d nodes, more than 64|needs 2 to 64 float64 nodes"):
        load_model(path)
