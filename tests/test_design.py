"""The condenser design study (issue 27): layout rules, design geometry, the wide device, Dask runs."""

import json
import math

import numpy as np
import pytest

from conftest import require
from reflecto import geometry
from reflecto.evaluate import design as ds
from reflecto.hemicube import hemicube
from reflecto.instrument import layout
from reflecto.instrument.device import (
    DEFAULT_FIRING_ORDER,
    DEFAULT_LED_ANGLES,
    WIDE_LED_ANGLES,
    WIDE_OPTICS,
    Device,
    steep_last_order,
)
from reflecto.instrument.optics import Optics


def test_first_led_is_the_papers_where_legal_and_clears_the_cone_elsewhere():
    assert np.allclose(layout.led_angles(layout.first_led(Optics())), [5.0, 0.0])
    for cone, tilt in ((60.0, 20.0), (65.0, 20.0), (55.0, 30.0), (48.2, 35.0)):
        o = Optics(cone_half_angle_deg=cone, axis_tilt_deg=tilt)
        l0 = layout.first_led(o)
        el, az = layout.led_angles(l0)
        assert abs(el - 5.0) < 1e-9 and not layout.layout_violations(o, l0[None])
        gap = math.degrees(math.acos(l0 @ o.axis)) - (cone + layout.TUBE_MARGIN_DEG)
        if cone + tilt <= 80.0:
            assert az == 0.0 and gap >= 0.0
        else:  # the nearest legal azimuth: on the tube margin's edge
            assert 0.0 < az < 180.0 and 0.0 <= gap < 1e-4


def test_compiled_layout_goals_equal_layout_terms():
    rng = np.random.default_rng(3)
    for cone, tilt in ((48.2, 20.0), (60.0, 20.0), (65.0, 10.0)):
        o = Optics(cone_half_angle_deg=cone, axis_tilt_deg=tilt)
        for n in (32, 64):
            cube = hemicube(n)
            goals = layout.LayoutObjective(o, cube)
            for _ in range(5):
                leds = layout.led_direction(rng.uniform(5, 80, 6), rng.uniform(0, 360, 6))
                assert np.allclose(goals.terms(leds)[:3], layout.layout_terms(o, leds, cube), rtol=0, atol=1e-12)


def test_peak_reach_of_the_papers_device_is_its_two_steep_leds():
    dev = Device.builtin("ideal")
    assert np.allclose(layout.peak_theta_d(dev.optics, dev.leds), [37.8, 67.1])
    # the earlier device's axial LED is in its occluder: it sees h = n at θ_d = 0 only through the hole
    e = Device.builtin("earlier")
    assert len(layout.peak_theta_d(e.optics, e.leds, e.occluder_deg)) == 0
    # goal 4 of the design objective: reach / 80°
    assert layout.objective_terms(dev.optics, dev.leds, hemicube(32))[3] == pytest.approx(67.1 / 80.0)


def test_tilt_margin_is_the_smallest_tilt_that_hides_a_seen_peak():
    """The paper's layout sees LED 2's peak (θ_d 67.1°) within a degree of the cone's rim:
    a hand tilt of ≈ 0.28° toward the rim hides it, while LED 4's (37.8°) stays in view
    to 13.9°. At the margin the mirror view leaves the cone in some direction; 0.01° less
    keeps it in view in every direction; a layout that sees no peak has no margin."""
    dev = Device.builtin("ideal")
    leds = geometry.normalize(np.asarray(dev.leds))
    margin = layout.tilt_margin_deg(dev.optics, leds)
    assert 0.2 < margin < 0.4
    steep = leds[np.isclose(np.degrees(np.arccos(leds[:, 2])), 37.8, atol=0.1)]
    assert 13.0 < layout.tilt_margin_deg(dev.optics, steep) < 15.0

    def in_view(tilt_deg: float) -> np.ndarray:
        psi = np.radians(np.arange(3600) / 10.0)
        t = math.radians(tilt_deg)
        normals = np.stack([np.sin(t) * np.cos(psi), np.sin(t) * np.sin(psi), np.full(len(psi), np.cos(t))], axis=1)
        ln = normals @ leds.T
        o = 2.0 * ln[..., None] * normals[:, None, :] - leds[None]
        return (o @ dev.optics.axis >= math.cos(math.radians(dev.optics.cone_half_angle_deg))) & (ln > 0.05)

    seen = in_view(0.0)[0]
    assert seen.sum() == 2
    assert np.all(in_view(margin - 0.01)[:, seen])
    assert not np.all(in_view(margin + 0.01)[:, seen])
    e = Device.builtin("earlier")
    assert layout.tilt_margin_deg(e.optics, e.leds, e.occluder_deg) == math.inf


def test_a_layout_for_hand_held_use_keeps_its_peaks_in_view_under_the_margin():
    """``min_tilt_margin_deg`` holds every peak the layout sees in view for tilts up to it
    (the bound of ``peak_margins_deg`` below the exact margin); raising the paper's LED 2
    by 4° buys 2° of margin for 4° of reach."""
    optics = Optics()
    leds = layout.optimize_layout(optics, 6, maxiter=15, min_tilt_margin_deg=2.0)
    bound = layout.peak_margins_deg(optics, leds)
    assert len(bound) and np.all(bound >= 2.0)
    assert layout.tilt_margin_deg(optics, leds) >= bound.min() - 1e-3
    dev = Device.builtin("ideal")
    angles = np.array(dev.led_angles, dtype=float)
    k = int(np.argmin(np.abs(angles[:, 0] - 22.9)))
    angles[k, 0] += 4.0
    raised = layout.led_direction(angles[:, 0], angles[:, 1])
    assert np.allclose(layout.peak_theta_d(optics, raised), [37.8, 63.1], atol=0.05)
    assert layout.tilt_margin_deg(optics, raised) == pytest.approx(2.28, abs=0.02)
    assert not layout.layout_violations(optics, raised)


def test_firing_order_is_derived_from_the_layout():
    assert steep_last_order(DEFAULT_LED_ANGLES) == DEFAULT_FIRING_ORDER
    assert steep_last_order([(5, 0), (30, 10), (6, 90), (60, 200)]) == (2, 0, 3, 1)
    assert steep_last_order([(40, 0), (30, 10)]) == (0, 1)  # no grazing LED: the steep ones, steepest first
    dev = Device.design("x", WIDE_OPTICS, WIDE_LED_ANGLES)
    assert dev.check_leds == (dev.order[0],) and dev.camera.noiseless


def test_as_built_device_is_unchanged():
    t = Device.builtin("as-built").truth
    assert t.led_angles[0] == (4.7435, 0.2523)
    assert t.led_intensity == (0.9217, 1.1024, 0.8796, 0.8789, 1.0996, 0.9632)
    assert t.optics == Optics(cx=163.2, cy=116.9, k1=-0.06, k2=0.015, roll_deg=0.7)


def test_wide_device_sees_the_peak_up_to_the_metrics_cut():
    wide, built = Device.builtin("wide"), Device.builtin("wide-as-built")
    assert wide.optics == WIDE_OPTICS and not layout.layout_violations(wide.optics, wide.leds)
    assert wide.optics.axis_tilt_deg + wide.optics.cone_half_angle_deg >= 78.0
    assert layout.peak_theta_d(wide.optics, wide.leds).max() > 75.0
    assert layout.coverage(wide.optics, wide.leds).after_tau > 0.92
    assert ds.condenser(ds.Design(wide.optics.cone_half_angle_deg, wide.optics.axis_tilt_deg, wide.n_leds)).realisable
    # the as-built variant: same nominal design, hidden errors of the as-built kind
    assert built.nominal() == Device.design("wide-as-built", WIDE_OPTICS, WIDE_LED_ANGLES, ideal=False).nominal()
    assert built.truth is not None and built.truth.optics.cone_half_angle_deg == wide.optics.cone_half_angle_deg
    errs = np.abs(np.array(built.truth.led_angles)[:, 0] - np.array(wide.led_angles)[:, 0])
    assert 0 < errs.max() <= 0.5 + 1e-9


def test_condenser_requirements_and_capture_time():
    paper = ds.condenser(ds.Design(48.2, 20.0, 6))
    assert paper.na == pytest.approx(0.7455, abs=1e-4) and paper.realisable
    c60 = ds.condenser(ds.Design(60.0, 20.0, 6))
    assert c60.na == pytest.approx(0.8660, abs=1e-4) and c60.focal_mm == pytest.approx(27.14, abs=0.01)
    assert c60.rim_elevation_deg == pytest.approx(10.0) and c60.realisable
    assert not ds.condenser(ds.Design(65.0, 15.0, 6)).realisable  # NA 0.906
    assert "rim" in ds.condenser(ds.Design(55.0, 32.0, 6)).limit
    assert ds.Design(65.0, 25.0, 6).possible is not None and ds.Design(65.0, 20.0, 6).possible is None
    # the paper's 12 frames at 10 captures per second; ours add the two check frames
    assert ds.capture_seconds(ds.capture_frames(6, n_check=0)) == pytest.approx(0.1)
    assert ds.capture_frames(10) == 22


def _analytic(folder):
    folder.mkdir()
    (folder / "plastic.json").write_text(json.dumps(
        {"type": "analytic", "distribution": "ggx", "alpha": 0.25, "kd": 0.3, "ks": 0.5, "eta": 1.5}))
    return folder


def _seed_layout(out, key_design):
    """A design record written as the layout step would, to skip its optimizer in a test."""
    rec = ds.geometry_record(key_design.key, key_design.optics(), np.asarray(WIDE_LED_ANGLES))
    (out / "designs").mkdir(parents=True)
    (out / "designs" / f"{key_design.key}.json").write_text(json.dumps(rec))


def test_design_study_is_resumable_and_its_paper_row_is_the_sweeps_device(tmp_path):
    mats = _analytic(tmp_path / "mats")
    out = tmp_path / "study"
    d = ds.Design(WIDE_OPTICS.cone_half_angle_deg, WIDE_OPTICS.axis_tilt_deg, len(WIDE_LED_ANGLES))
    _seed_layout(out, d)
    rows = ds.design_study([mats], out, cones=[d.cone_half_angle_deg, 70.0], tilts=[d.axis_tilt_deg],
                           led_counts=[d.n_leds], jobs=1, progress=False)
    assert [r["key"] for r in rows] == ["paper", d.key, f"c70.0-t20.0-l{d.n_leds}"]
    paper, wide, impossible = rows
    assert impossible["limit"] == "the view cone reaches below the sample plane" and not impossible["realisable"]
    assert paper["materials"] == wide["materials"] == 1
    # an analytic microfacet material: both devices far below the dense Cook–Torrance fit
    assert paper["median_ratio"] < 0.3 and wide["median_ratio"] < 0.3
    assert wide["theta_d_reach_deg"] > paper["theta_d_reach_deg"] == pytest.approx(67.1)
    table = (out / "design.csv").read_text()
    assert (out / "design.png").stat().st_size > 5000
    # a rerun does nothing and writes the same table; a lost record is redone identically
    run = out / "runs" / d.key / "plastic.json"
    stamp = run.stat().st_mtime_ns
    ds.design_study([mats], out, cones=[d.cone_half_angle_deg, 70.0], tilts=[d.axis_tilt_deg], led_counts=[d.n_leds],
                    jobs=1, progress=False)
    assert run.stat().st_mtime_ns == stamp and (out / "design.csv").read_text() == table
    first = json.loads(run.read_text())
    run.unlink()
    ds.design_study([mats], out, cones=[d.cone_half_angle_deg, 70.0], tilts=[d.axis_tilt_deg], led_counts=[d.n_leds],
                    jobs=1, progress=False)
    again = json.loads(run.read_text())
    assert {k: v for k, v in again.items() if k != "seconds"} == {k: v for k, v in first.items() if k != "seconds"}


@pytest.fixture(scope="module")
def cluster():
    distributed = require("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as c:
        yield c


def test_run_batch_on_a_local_dask_cluster_equals_the_local_run(cluster):
    from reflecto.batch import run_batch

    o = Optics(cone_half_angle_deg=60.0)
    items = [(o, layout.led_direction([5.0, 40.0, 10.0], [0.0, 180.0, 170.0])), (o, "not directions"),
             (Optics(), Device.builtin("ideal").leds)]
    labels = ["a", "b", "c"]

    def collect(scheduler):
        got = {}
        run_batch(layout.peak_theta_d, items, labels, 2, lambda k, ok, v, s: got.__setitem__(k, (ok, v)),
                  scheduler=scheduler)
        return got

    local, remote = collect(None), collect(cluster.scheduler_address)
    assert local.keys() == remote.keys() == {0, 1, 2}
    for k in (0, 2):
        assert local[k][0] and remote[k][0] and np.array_equal(local[k][1], remote[k][1])
    assert not local[1][0] and not remote[1][0] and local[1][1] == remote[1][1]
    assert np.allclose(remote[2][1], [37.8, 67.1])


def test_two_batches_on_one_cluster_get_their_own_results(cluster):
    """Two batches with the same positions and labels (one material swept on two devices) at
    once on one cluster: each gets its own results (their task keys were equal, and Dask gave
    the second batch the first's)."""
    import threading

    from reflecto.batch import run_batch

    got: dict[str, list] = {"ideal": [], "wide": []}

    def batch(name):
        leds = Device.builtin(name).leds
        run_batch(layout.peak_theta_d, [(Device.builtin(name).optics, leds)], ["same-material"], 1,
                  lambda k, ok, v, s: got[name].append((ok, np.asarray(v).tolist())),
                  scheduler=cluster.scheduler_address)

    threads = [threading.Thread(target=batch, args=(n,)) for n in got]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    want = {n: np.asarray(layout.peak_theta_d(Device.builtin(n).optics, Device.builtin(n).leds)).tolist()
            for n in got}
    assert got["ideal"] == [(True, want["ideal"])] and got["wide"] == [(True, want["wide"])]
    assert want["ideal"] != want["wide"]


def test_an_unreachable_scheduler_is_one_error(monkeypatch):
    import importlib

    from reflecto.errors import ReflectoError

    batch = importlib.import_module("reflecto.batch")
    from reflecto.batch import run_batch

    require("distributed")
    monkeypatch.setattr(batch, "DASK_CONNECT_TIMEOUT_S", 1.0)
    with pytest.raises(ReflectoError, match="cannot reach the Dask scheduler"):
        run_batch(abs, [(1,)], ["x"], 1, lambda *a: None, scheduler="tcp://127.0.0.1:9")


def _without_timings(csv_text):
    rows = [line.split(",") for line in csv_text.strip().splitlines()]
    keep = [k for k, name in enumerate(rows[0]) if not name.startswith("seconds")]
    return [[r[k] for k in keep] for r in rows]


@pytest.mark.slow
def test_sweep_on_a_local_dask_cluster_writes_the_local_table(tmp_path, cluster):
    from reflecto.cli import main

    mats = _analytic(tmp_path / "mats")
    (mats / "metal.json").write_text(json.dumps(
        {"type": "analytic", "distribution": "beckmann", "alpha": 0.15, "kd": 0.02, "ks": 0.9, "eta": 3.0}))
    assert main(["sweep", str(mats), "-o", str(tmp_path / "local"), "--jobs", "1", "-q"]) == 0
    assert main(["sweep", str(mats), "-o", str(tmp_path / "dask"), "-q", "--scheduler", cluster.scheduler_address]) == 0
    local = _without_timings((tmp_path / "local" / "results.csv").read_text())
    assert _without_timings((tmp_path / "dask" / "results.csv").read_text()) == local and len(local) == 3
