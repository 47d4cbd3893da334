import numpy as np
import pytest

from conftest import random_directions
from reflecto import geometry as g
from reflecto.errors import ParameterError
from reflecto.hemicube import Hemicube, hemicube


@pytest.mark.parametrize("n", [4, 16, 64, 512])
def test_solid_angles_sum_to_2pi(n):
    c = hemicube(n)
    assert c.size == 3 * n * n
    assert abs(c.solid_angles.sum() / (2 * np.pi) - 1) < 1e-12
    assert np.all(c.solid_angles > 0)


def test_solid_angle_values():
    c = hemicube(512)
    top = c.face_values(c.solid_angles, 0)
    # centre texel ≈ (2/512)² sr; corner texel ~5.2x smaller (algorithm-reference §9.2)
    assert abs(top[256, 256] / (2 / 512) ** 2 - 1) < 1e-4
    assert 5.0 < top[256, 256] / top[0, 0] < 5.3


def test_index_of_texel_centres_is_identity():
    c = hemicube(64)
    assert np.array_equal(c.index(c.directions), np.arange(c.size))


def test_lookup_exact_at_centres_and_accurate_across_seams(rng):
    c = hemicube(128)
    vals = rng.random(c.size)
    assert np.allclose(c.lookup(vals, c.directions), vals, atol=1e-12)

    def f(d):
        return np.exp(-3 * (1 - d[..., 2])) + 0.3 * d[..., 0] * d[..., 1] + 0.2 * d[..., 1]

    tab = f(c.directions)
    d = random_directions(rng, 400_000, 89.0)
    err = np.abs(c.lookup(tab, d) - f(d))
    seam = (np.abs(np.abs(d[:, 0]) - d[:, 2]) < 0.01) | (np.abs(np.abs(d[:, 1]) - d[:, 2]) < 0.01) | (
        np.abs(np.abs(d[:, 0]) - np.abs(d[:, 1])) < 0.01
    )
    interior = err[~seam].max()
    # second-order everywhere: seam error within a small factor of the interior error
    assert interior < 1e-3
    assert err[seam].max() < 3 * interior
    # multi-channel lookup agrees with per-channel lookups
    two = np.stack([tab, 2 * tab], -1)
    assert np.allclose(c.lookup(two, d[:100]), np.stack([c.lookup(tab, d[:100]), 2 * c.lookup(tab, d[:100])], -1))


def test_splat_averages_samples():
    c = hemicube(16)
    t = np.array([5, 5, 5, 700])
    d = c.directions[t]
    wsum, wvsum = c.splat(d, np.array([1.0, 2.0, 6.0, 4.0]), np.array([1.0, 1.0, 2.0, 3.0]))
    assert wsum[5] == 4.0 and wvsum[5] == 1 + 2 + 12
    assert wsum[700] == 3.0 and wvsum[700] == 12.0
    assert wsum.sum() == 7.0
    rgb = c.splat(d, np.ones((4, 3)))[1]
    assert rgb.shape == (c.size, 3) and rgb[5, 1] == 3


def test_downsample_preserves_integral_and_moments():
    c = hemicube(64)
    d = np.exp(-((1 - c.cos_theta) / 0.05))
    coarse, dc = c.downsample(d, 4)
    assert coarse.n == 16
    assert np.isclose(np.sum(dc * coarse.solid_angles), np.sum(d * c.solid_angles), rtol=1e-12)
    mass, first = c.moments(d, 4)
    assert np.allclose(mass.sum(), np.sum(d * c.solid_angles))
    assert np.allclose(first.sum(0), (d * c.solid_angles) @ c.directions)
    with pytest.raises(ParameterError):
        c.downsample(d, 3)


@pytest.mark.parametrize("m", [g.TAU, g.MIRROR_T, g.MIRROR_B])
def test_symmetries_are_exact_permutations(m):
    c = hemicube(32)
    p = c.permutation(m)
    assert np.array_equal(np.sort(p), np.arange(c.size))
    assert np.allclose(c.directions[p], g.apply(m, c.directions), atol=1e-12)
    assert np.array_equal(p[p], np.arange(c.size))  # involution


def test_tau_is_composition_of_mirrors():
    c = hemicube(32)
    pt, pb, pn = c.permutation(g.MIRROR_T), c.permutation(g.MIRROR_B), c.permutation(g.TAU)
    assert np.array_equal(pt[pb], pn)


def test_bad_resolution():
    with pytest.raises(ParameterError):
        Hemicube(7)
    with pytest.raises(ParameterError):
        hemicube(8).permutation(np.diag([1.0, 1.0, -1.0]))


def test_lookups_do_not_modify_their_input():
    from reflecto.shadowing import sigma_table

    c = hemicube(16)
    for d in (np.array([[0.0, 0.0, 1.0]]), np.array([[0.6, 0.0, -0.8]]), np.array([0.0, 0.6, 0.8])):
        before = d.copy()
        c.lookup(np.ones(c.size), d)
        c.index(d)
        sigma_table(c, np.ones(c.size)).eval(d)
        assert np.array_equal(d, before)


def test_compiled_splat_matches_bincount(rng):
    c = hemicube(32)
    d = g.normalize(rng.normal(size=(20_000, 3)))
    d[:, 2] = np.abs(d[:, 2])
    v, w = rng.random((20_000, 3)), rng.random(20_000)
    for vals in (v, v[:, 0]):
        ws, wv = c.splat(d, vals, w)
        ws0, wv0 = c.splat_numpy(d, vals, w)
        np.testing.assert_allclose(ws, ws0, rtol=1e-12)
        np.testing.assert_allclose(wv, wv0, rtol=1e-12)


def test_smooth_keeps_constants_and_smooth_functions_and_is_continuous_across_seams():
    c = hemicube(64)
    assert np.allclose(c.smooth(np.ones(c.size), 4), 1.0, atol=1e-12)
    # a smooth function moves by about σ²/2·∇² (tiny); a texel-scale checkerboard vanishes
    d = c.directions
    f = np.exp(-((d[:, 0] - 0.3) ** 2 + (d[:, 1] + 0.2) ** 2) / 0.5)
    assert np.abs(c.smooth(f, 2) - f).max() < 5e-3
    top = c.face_values(np.arange(c.size), 0)
    checker = np.zeros(c.size)
    checker[top[::2, ::2].ravel()] = 1.0
    checker[top[1::2, 1::2].ravel()] = 1.0
    inner = c.face_values(c.smooth(checker, 1), 0)[2:-2, 2:-2]
    assert np.allclose(inner, 0.5)
    # a spike on the top face's +X edge spreads onto the +X side face
    spike = np.zeros(c.size)
    spike[c.index(np.array([1.0, 0.0, 1.0]) / np.sqrt(2))] = 1.0
    side = c.smooth(spike, 1)[c.offsets[1]:c.offsets[2]]
    assert side.max() > 0.05


def test_compiled_index_matches_numpy(rng):
    c = hemicube(64)
    d = random_directions(rng, 20_000)
    d = np.concatenate([d, c.directions, [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.3, -0.3, -0.1]]])
    assert np.array_equal(c.index(d), c.index_numpy(d))
    assert np.array_equal(c.index(3.0 * d), c.index(d))  # scale-free: only ratios enter


@pytest.mark.parametrize("n, factor", [(64, 2), (128, 8), (16, 4)])
def test_block_reduce_matches_numpy_and_conserves_sums(rng, n, factor):
    c = hemicube(n)
    v = rng.random(c.size)
    v3 = rng.random((c.size, 3))
    coarse = c.block_reduce(v, factor)
    assert coarse.shape == (3 * (n // factor) ** 2,)
    assert np.allclose(coarse, c.block_reduce_numpy(v, factor), rtol=1e-13, atol=0)
    assert np.allclose(c.block_reduce(v3, factor), c.block_reduce_numpy(v3, factor), rtol=1e-13, atol=0)
    assert np.isclose(coarse.sum(), v.sum(), rtol=1e-12)
    with pytest.raises(ParameterError):
        c.block_reduce(v, 3)


def test_pad_copies_faces_and_interpolates_the_border(rng):
    c = hemicube(32)
    v = rng.random(c.size)
    padded = c.pad(v)
    assert np.allclose(padded, c.pad_numpy(v), rtol=1e-12, atol=1e-14)
    # the interior of every padded face is the face itself, bit for bit
    for face in range(5):
        rows, cols = c.face_shape(face)
        o = c._pad_offsets[face]
        inner = padded[o : o + (rows + 2) * (cols + 2)].reshape(rows + 2, cols + 2)[1:-1, 1:-1]
        assert np.array_equal(inner, c.face_values(v, face))
