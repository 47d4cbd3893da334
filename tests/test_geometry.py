import numpy as np

from conftest import random_directions
from reflecto import geometry as g


def test_hd_io_round_trip(rng):
    i = random_directions(rng, 5000)
    o = random_directions(rng, 5000)
    th, ph, td, pd = g.io_to_hd(i, o)
    i2, o2 = g.hd_to_io(th, ph, td, pd)
    assert np.allclose(i2, i, atol=1e-10)
    assert np.allclose(o2, o, atol=1e-10)
    # θ_d is the angle between i and h, and between o and h
    h = g.half_vector(i, o)
    assert np.allclose(np.cos(td), np.sum(i * h, -1), atol=1e-12)
    assert np.allclose(np.cos(td), np.sum(o * h, -1), atol=1e-12)


def test_reflect_and_symmetries(rng):
    i = random_directions(rng, 100)
    h = random_directions(rng, 100)
    o = g.reflect(i, h)
    assert np.allclose(np.linalg.norm(o, axis=-1), 1.0)
    assert np.allclose(g.half_vector(i, o)[np.sum(i * h, -1) > 0], h[np.sum(i * h, -1) > 0])
    v = np.array([0.3, -0.4, np.sqrt(0.75)])
    assert np.allclose(g.tau(v), [-0.3, 0.4, np.sqrt(0.75)])
    assert np.allclose(g.apply(g.MIRROR_T @ g.MIRROR_B, v), g.tau(v))
    # τ is R_n, the reflection through the normal line
    assert np.allclose(g.tau(v), g.reflect(v, np.array([0.0, 0.0, 1.0])))
    # eq. 3: the half vector of (τi, τo) is the mirror of h about n
    i1, o1 = random_directions(rng, 10), random_directions(rng, 10)
    assert np.allclose(g.half_vector(g.tau(i1), g.tau(o1)), g.reflect(g.half_vector(i1, o1), np.array([0, 0, 1.0])))


def test_frames():
    n = g.normalize([0.2, -0.1, 1.0])
    f = g.frame_from_normal(n)
    assert np.allclose(f @ f.T, np.eye(3), atol=1e-12)
    assert np.allclose(g.to_local(n, f), [0, 0, 1], atol=1e-12)
    v = g.normalize([0.3, 0.5, 0.8])
    assert np.allclose(g.to_world(g.to_local(v, f), f), v)


def test_spherical_near_pole():
    v = g.spherical_to_cartesian(1e-9, 0.3)
    th, ph = g.cartesian_to_spherical(v)
    assert abs(th - 1e-9) < 1e-15


def test_tilt_deg_is_the_angle_from_the_device_axis():
    import math

    for deg, az in ((0.0, 0.0), (4.0, 60.0), (30.0, 250.0), (90.0, 10.0), (120.0, 0.0)):
        t, a = math.radians(deg), math.radians(az)
        n = np.array([math.sin(t) * math.cos(a), math.sin(t) * math.sin(a), math.cos(t)])
        assert abs(g.tilt_deg(n) - deg) < 1e-6
    assert g.tilt_deg(np.array([0.0, 0.0, 1.0 + 1e-15])) == 0.0  # round-off above 1 clamped
