"""Validation: the eq. 10 metric, the Cook–Torrance baseline, the resumable sweep."""

import json
import math

import numpy as np
import pytest

from reflecto.evaluate.cooktorrance import CookTorrance, fit_cook_torrance
from reflecto.evaluate.metrics import brdf_error, metric_grid
from reflecto.evaluate.sweep import find_materials, sweep
from reflecto.load import load_source
from reflecto.sources import merl
from reflecto.sources.analytic import AnalyticBRDF


def test_metric_reproduces_itself_on_a_merl_tabulation(shared):
    src = load_source(shared / "merl-nbrdf" / "blue-fabric.h5")
    tab = merl.MerlBRDF.from_table(merl.tabulate(src), name="blue-fabric")
    err = brdf_error(src, tab)
    assert err.normalized <= 1e-3 and err.log_rmse <= 1e-3
    # and a metric that returned 0 would fail: a copy offset by δ has eq. 10's error δ rms(cos θ_i)
    # on every channel (the weights of AR 6.3 only), and one scaled by 1.1 has 0.1 × the tabulation's
    # cosine-weighted RMS; both normalized by the source's largest albedo
    g = metric_grid(1)
    rms_cos = math.sqrt(np.sum(g.w * g.i[:, 2] ** 2) / np.sum(g.w))
    delta = 0.01 / math.pi
    shifted = brdf_error(src, merl.MerlBRDF.from_table(tab.table + delta, name="shifted"))
    assert np.allclose(shifted.rmse, delta * rms_cos, rtol=2e-3), (shifted.rmse, delta * rms_cos)
    assert shifted.normalized == pytest.approx(delta * rms_cos / err.albedo_ref, rel=2e-3)
    r = tab.table.reshape(-1, 3)[g.flat] * g.i[:, 2:3]  # R cos θ_i on the grid
    scaled = brdf_error(src, merl.MerlBRDF.from_table(1.1 * tab.table, name="scaled"))
    expect = 0.1 * np.sqrt(np.sum(g.w[:, None] * r**2, axis=0) / np.sum(g.w))
    assert np.allclose(scaled.rmse, expect, rtol=2e-3) and scaled.rmse.min() > 0, (scaled.rmse, expect)
    log_expect = np.sqrt(np.sum(g.w[:, None] * (np.log1p(1.1 * r) - np.log1p(r)) ** 2, axis=0) / np.sum(g.w)).mean()
    assert scaled.log_rmse == pytest.approx(log_expect, rel=2e-2) and scaled.log_rmse > 0


def test_lambertian_of_the_right_albedo_has_zero_error_and_the_wrong_one_does_not():
    diffuse = AnalyticBRDF(distribution="ggx", alpha=0.3, kd=(0.5, 0.4, 0.3), ks=0.0, eta=1.5)
    assert brdf_error(diffuse, CookTorrance(rho_d=(0.5, 0.4, 0.3))).normalized < 1e-12
    # 10 % too bright: error = 0.1 ρ/π · rms(cos θ_i) / max albedo (all weights positive)
    g = metric_grid(1)
    rms_cos = math.sqrt(np.sum(g.w * g.i[:, 2] ** 2) / np.sum(g.w))
    e = brdf_error(diffuse, CookTorrance(rho_d=(0.55, 0.44, 0.33)))
    assert np.allclose(e.rmse, 0.1 * np.array([0.5, 0.4, 0.3]) / math.pi * rms_cos, rtol=1e-9)


def test_metric_weights_are_the_4d_solid_angle():
    """Σw over the θ ≤ cut region ∝ (∫ dω)² = (2π(1 − cos cut))², eq. 6.2–6.3."""
    s80, s60 = metric_grid(1, 80.0).w.sum(), metric_grid(1, 60.0).w.sum()
    expect = ((1 - math.cos(math.radians(80))) / (1 - math.cos(math.radians(60)))) ** 2
    assert abs(s80 / s60 / expect - 1) < 0.02


def test_cook_torrance_fit_recovers_its_own_parameters():
    truth = CookTorrance(rho_d=(0.2, 0.15, 0.1), rho_s=(0.3, 0.25, 0.2), f0=0.3, m=0.15)
    ct = fit_cook_torrance(truth)
    assert abs(ct.m / 0.15 - 1) < 0.02 and abs(ct.f0 - 0.3) < 0.02
    assert np.allclose(ct.rho_d, truth.rho_d, rtol=0.02) and np.allclose(ct.rho_s, truth.rho_s, rtol=0.03)
    assert brdf_error(truth, ct).normalized < 1e-3


def test_compiled_cook_torrance_lobe_matches_numpy():
    """The fit's compiled lobe is the NumPy reference's, pair by pair (grid pairs and some below the horizon)."""
    from reflecto import _kernels
    from reflecto.evaluate.cooktorrance import _lobe

    g = metric_grid(8)
    rng = np.random.default_rng(5)
    i = np.concatenate([g.i, rng.normal(size=(500, 3))])
    o = np.concatenate([g.o, rng.normal(size=(500, 3))])
    i /= np.linalg.norm(i, axis=1, keepdims=True)
    o /= np.linalg.norm(o, axis=1, keepdims=True)
    scale = rng.random(len(i)) + 0.5
    for f0, m in ((0.04, 0.02), (0.9, 0.4), (0.3, 1.5)):
        out = np.empty(len(i))
        _kernels.ct_lobe(i, o, scale, f0, m, out)
        assert np.allclose(out, _lobe(i, o, f0, m) * scale, rtol=1e-12, atol=0)


def _without_timings(csv_text: str) -> list[list[str]]:
    rows = [line.split(",") for line in csv_text.strip().splitlines()]
    keep = [k for k, name in enumerate(rows[0]) if not name.startswith("seconds")]
    return [[r[k] for k in keep] for r in rows]


def test_sweep_is_resumable_and_deterministic(tmp_path):
    mats = tmp_path / "mats"
    mats.mkdir()
    (mats / "plastic.json").write_text(json.dumps(
        {"type": "analytic", "distribution": "ggx", "alpha": 0.2, "kd": 0.3, "ks": 0.6, "eta": 1.5}))
    (mats / "notes.json").write_text('{"not": "a brdf"}')
    assert [p.name for p in find_materials([mats])] == ["plastic.json"]
    out = tmp_path / "res"
    first = sweep([mats], out, jobs=1, progress=False)
    table = _without_timings((out / "results.csv").read_text())
    record = out / "materials" / "plastic.json"
    assert first[0]["ours"]["finite"] and record.is_file()
    # a finished material is skipped by a rerun
    stamp = record.stat().st_mtime_ns
    sweep([mats], out, jobs=1, progress=False)
    assert record.stat().st_mtime_ns == stamp
    # an interrupted sweep (the record never written) redoes it with identical results
    record.unlink()
    second = sweep([mats], out, jobs=1, progress=False)
    assert _without_timings((out / "results.csv").read_text()) == table
    assert second[0]["ours"]["error"] == first[0]["ours"]["error"]
    assert second[0]["cook_torrance"] == first[0]["cook_torrance"]
    assert (out / "fig5_errors.png").stat().st_size > 5000 and (out / "fig4_spheres.png").stat().st_size > 5000
    # on an analytic microfacet material ours beats both baselines
    r = second[0]
    assert r["ours"]["error"] < r["earlier"]["error"] and r["ours"]["error"] < r["cook_torrance"]["error"]


def test_model_ceiling_recovers_a_brdf_of_the_papers_class():
    """studies/model_ceiling.py fits the paper's model class to a dense reference; on
    an analytic GGX (its S is the APS S of its NDF, its Fresnel eq. 4) the fit must find
    the truth: η per channel within 0.5 %, k_d within 1 %, and eq. 10 below 0.1 %. Fitted
    only to the bins with θ_d ≤ 60°, the same material still comes back (it is in the
    class, so the observed range determines it; η within 1.5 %, as F changes little
    below 60°)."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "studies"))
    import model_ceiling as mc

    src = AnalyticBRDF(distribution="ggx", alpha=0.3, kd=(0.3, 0.2, 0.1), ks=0.6, eta=(1.4, 1.5, 1.7))
    for cut, eta_tol, tol in ((90.0, 5e-3, 1e-3), (60.0, 1.5e-2, 3e-3)):
        m = mc.fit_class(mc.Problem(src, max_theta_d_deg=cut), outer=3)
        assert np.allclose(m.eta, (1.4, 1.5, 1.7), rtol=eta_tol), (cut, m.eta)
        assert np.allclose(m.kd, (0.3, 0.2, 0.1), rtol=1e-2), (cut, m.kd)
        err = brdf_error(src, m, stride=2).normalized
        assert err < tol, (cut, err)


def test_same_data_cook_torrance_recovers_a_cook_torrance_capture():
    """Fitted to a capture of a Cook–Torrance BRDF, the same-data baseline finds its
    roughness and albedos again from the six slices alone."""
    from reflecto.evaluate.cooktorrance import fit_cook_torrance_capture
    from reflecto.instrument.calibrate import nominal_calibration
    from reflecto.instrument.device import Device
    from reflecto.instrument.simulate import simulate_capture
    from reflecto.instrument.slices import extract_slices

    truth = CookTorrance(rho_d=(0.3, 0.2, 0.1), rho_s=(0.5, 0.5, 0.5), f0=0.05, m=0.15)
    dev = Device.builtin("ideal")
    sl = extract_slices(simulate_capture(truth, dev, seed=1), nominal_calibration(dev))
    fit = fit_cook_torrance_capture(sl)
    assert abs(fit.m / 0.15 - 1) < 0.03
    assert np.allclose(fit.rho_d, [0.3, 0.2, 0.1], atol=0.01)
    assert np.allclose(fit.rho_s * fit.f0, 0.5 * 0.05, rtol=0.1)


def test_protocol_split_is_the_documented_draw(shared):
    """The halves are disjoint, 25 + 25, stratified (5 + 20 each) and the hash draw of evaluate/split.py."""
    from reflecto.evaluate.split import TUNING, VALIDATION, draw_split

    rgl = sorted(p.stem for p in (shared / "rgl").glob("*.bsdf"))
    merl = sorted(p.stem for p in (shared / "merl-nbrdf").glob("*.h5"))
    assert not TUNING & VALIDATION and len(TUNING) == len(VALIDATION) == 25
    assert len(TUNING & set(rgl)) == 5 and len(VALIDATION & set(merl)) == 20
    assert draw_split([rgl, merl]) == (set(TUNING), set(VALIDATION))


def test_handheld_control_makes_a_reference_mirror_symmetric():
    """studies/validate_handheld.py --mirror-symmetric: an analytic isotropic BRDF is
    mirror-symmetric (asymmetry 0, the symmetric part equal to it), a source with an odd
    part in the relative azimuth is not, and its symmetric part is again, with the odd
    part gone and the even part kept."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "studies"))
    import validate_handheld as vh
    from reflecto.brdf import BRDFSource

    src = AnalyticBRDF(distribution="ggx", alpha=0.3, kd=0.2, ks=0.5, eta=1.5)
    assert vh.mirror_asymmetry(src) < 1e-12

    class Chiral(BRDFSource):
        """``f (1 + 0.3 sin(φ_o − φ_i))``: invariant under rotation about ``n``, not under a reflection."""

        def eval(self, i, o):
            i, o = np.asarray(i, float), np.asarray(o, float)
            dphi = np.arctan2(o[:, 1], o[:, 0]) - np.arctan2(i[:, 1], i[:, 0])
            return src.eval(i, o) * (1.0 + 0.3 * np.sin(dphi))[:, None]

    chiral = Chiral()
    assert vh.mirror_asymmetry(chiral) > 0.1
    sym = vh.MirrorSymmetric(chiral)
    rng = np.random.default_rng(3)
    i = rng.normal(size=(500, 3))
    o = rng.normal(size=(500, 3))
    i[:, 2], o[:, 2] = np.abs(i[:, 2]), np.abs(o[:, 2])
    i /= np.linalg.norm(i, axis=1, keepdims=True)
    o /= np.linalg.norm(o, axis=1, keepdims=True)
    assert np.allclose(sym.eval(i, o), src.eval(i, o), rtol=1e-12, atol=1e-15)
    assert np.allclose(vh.MirrorSymmetric(src).eval(i, o), src.eval(i, o), rtol=1e-12, atol=1e-15)


@pytest.mark.slow
def test_sweep_scores_an_anisotropic_material_as_compare_does(tmp_path):
    """An anisotropic material: the sweep scored every model at φ_h = 0 alone, `compare` and
    `fit-ct` over every half-vector azimuth, and the verdict against Cook–Torrance flipped
    (ggx-brushed-30: ours 0.075 against 0.052 there, 0.044 against 0.167 over all azimuths)."""
    import shutil
    from pathlib import Path

    from reflecto.evaluate.metrics import comparison_error

    mats = tmp_path / "mats"
    mats.mkdir()
    root = Path(__file__).resolve().parents[1]
    brushed = shutil.copy(root / "examples" / "asymmetric" / "ggx-brushed-30.toml", mats)
    rec = sweep([mats], tmp_path / "res", jobs=1, progress=False)[0]
    assert "every half-vector azimuth" in rec["ours"]["error_form"]
    src = load_source(brushed)
    ct = comparison_error(src, fit_cook_torrance(src)).normalized
    assert rec["cook_torrance"]["error"] == pytest.approx(ct, rel=1e-9)
    assert rec["ours"]["error"] < rec["cook_torrance"]["error"]
