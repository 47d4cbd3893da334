"""A NumPy twin for every compiled (Numba) kernel.

Each test below runs one kernel on random inputs (fixed seeds), including empty and
boundary inputs, and compares it with a NumPy reference: the package's own ``*_numpy``
reference where it has one, otherwise one written here from the kernel's documented
formula (vectorized, not a transcription of its loops). ``@twin(...)`` registers the
test as the twin of the kernels it checks; :func:`test_every_compiled_kernel_has_a_twin`
finds every ``@njit`` function in the package (by reading the source) and fails if one
has no twin here. Helpers compiled with ``inline="always"`` are checked through the
kernels they are inlined into (:data:`INLINED_INTO`).

The inputs use the dtypes and memory layouts of the package's own calls, so that the
kernels' cached compilations are reused (a new signature would compile for seconds).
"""

from __future__ import annotations

import ast
import importlib
import math
from pathlib import Path

import numpy as np
import pytest

import reflecto
from conftest import random_directions
from reflecto import _kernels
from reflecto.colour import LUM
from reflecto.hemicube import hemicube
from reflecto.polar import cell_table
from reflecto.reconstruct import _polar_kernels

PACKAGE = Path(reflecto.__file__).resolve().parent

#: kernel qualname → names of the tests that compare it with NumPy
TWINS: dict[str, list[str]] = {}


def twin(*kernels: str):
    """Register the decorated test as the NumPy twin of ``kernels`` (``module.function``)."""

    def register(test):
        for k in kernels:
            TWINS.setdefault(k, []).append(test.__name__)
        return test

    return register


#: Helpers compiled with ``inline="always"`` → the twin-tested kernels that inline them.
INLINED_INTO = {
    "reflecto._kernels._unit": ("bin_finish", "ct_lobe"),
    "reflecto._kernels._face_coords": ("_cube_lookup", "_texel"),
    "reflecto._kernels._cube_lookup": ("cube_lookup", "mirror_distances", "model_eval"),
    "reflecto._kernels._bilinear": ("_cube_lookup", "_upsample"),
    "reflecto._kernels._sigma_lookup": ("model_eval",),
    "reflecto._kernels._polar_shadowing": ("pair_shadowing",),
    "reflecto._kernels._upsample": ("upsample", "pull"),
    "reflecto._kernels._texel": ("cube_index", "bin_accumulate", "splat"),
    "reflecto._kernels._fresnel": ("fresnel_flat", "pair_residuals"),
    "reflecto._kernels._fresnel_dlog": ("pair_residuals_jac",),
    "reflecto.reconstruct._polar_kernels._bin_model": ("luminance_pass",),
    "reflecto.reconstruct._polar_kernels._eta_column": ("pass_normal_equations",),
    "reflecto.reconstruct._polar_kernels._accumulate_bin": ("normal_equations", "pass_normal_equations"),
    "reflecto.reconstruct._polar_kernels._zero": ("normal_equations", "pass_normal_equations"),
    "reflecto.reconstruct._polar_kernels._theta_d_cell": ("bin_polar",),
    "reflecto.reconstruct._polar_kernels._mirror_dense": ("normal_equations", "pass_normal_equations"),
    "reflecto.reconstruct._polar_kernels._ndf_integral": ("luminance_lm",),
    "reflecto.reconstruct._polar_kernels._lm_cost": ("luminance_lm",),
    "reflecto.reconstruct._polar_kernels._lm_system": ("luminance_lm",),
    "reflecto.reconstruct._normal_kernels._projected_area": ("_cosines",),
    "reflecto.reconstruct._normal_kernels._cosines": ("tilt_pass",),
    "reflecto.sources._rgl_kernels._solve_quadratic": ("warp_sample",),
}


# ----------------------------------------------------------------------------- discovery
def _is_compiled(decorator: ast.expr) -> tuple[bool, bool]:
    """(a Numba decorator?, with ``inline="always"``?)"""
    call = decorator if isinstance(decorator, ast.Call) else None
    target = call.func if call else decorator
    name = target.attr if isinstance(target, ast.Attribute) else getattr(target, "id", "")
    if name not in ("njit", "jit", "vectorize", "guvectorize", "cfunc", "generated_jit"):
        return False, False
    inline = any(k.arg == "inline" and isinstance(k.value, ast.Constant) and k.value.value == "always"
                 for k in (call.keywords if call else []))
    return True, inline


def compiled_functions() -> dict[str, bool]:
    """Every Numba-compiled function of the package: ``module.name`` → inlined helper?"""
    found = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        text = path.read_text(encoding="utf-8")
        if "numba" not in text:
            continue
        module = ".".join(("reflecto",) + path.relative_to(PACKAGE).with_suffix("").parts).removesuffix(".__init__")
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, ast.FunctionDef):
                for d in node.decorator_list:
                    compiled, inline = _is_compiled(d)
                    if compiled:
                        found[f"{module}.{node.name}"] = inline
    return found


def test_every_compiled_kernel_has_a_twin():
    from numba.core.registry import CPUDispatcher

    found = compiled_functions()
    # the source scan misses nothing the modules compile (e.g. an ``njit(f)`` call form)
    for module in {k.rsplit(".", 1)[0] for k in found}:
        mod = importlib.import_module(module)
        dispatchers = {f"{module}.{name}" for name, obj in vars(mod).items()
                       if isinstance(obj, CPUDispatcher) and obj.py_func.__module__ == module}
        assert dispatchers == {k for k in found if k.startswith(module + ".")}, module
    kernels = sorted(k for k, inline in found.items() if not inline)
    helpers = sorted(k for k, inline in found.items() if inline)
    assert len(kernels) >= 28, kernels  # issue 40 counted 28
    assert not [k for k in kernels if k not in TWINS], "compiled kernels without a NumPy twin test"
    assert not [k for k in TWINS if k not in found], "twins of kernels that no longer exist"
    assert sorted(INLINED_INTO) == helpers, "inlined helpers: name the kernels that test them"
    for helper, users in INLINED_INTO.items():
        module, name = helper.rsplit(".", 1)
        src = (PACKAGE / Path(*module.split(".")[1:])).with_suffix(".py").read_text(encoding="utf-8")
        tree = {n.name: ast.get_source_segment(src, n) for n in ast.walk(ast.parse(src))
                if isinstance(n, ast.FunctionDef)}
        for user in users:
            assert f"{name}(" in tree[user], (helper, user)
            # the user is a twin-tested kernel, or itself a helper inlined into one
            assert f"{module}.{user}" in TWINS or f"{module}.{user}" in INLINED_INTO, (helper, user)


# ----------------------------------------------------------------------------- instrument
@twin("reflecto._kernels.expose")
@pytest.mark.parametrize("gamma", [0.0, 2.2])
@pytest.mark.parametrize("noise", ["none", "read", "shot"])
def test_expose(noise, gamma):
    """Electrons ``e = clip(signal, 0) t`` (at most 4 wells), plus read noise ``r z`` or, with
    shot noise, Poisson below ``gauss_above`` and ``√(e + r²) z`` above; clipped to the well;
    then 8-bit gamma ``255 (e/well)^(1/γ)`` or linear ``black + e/gain``, rounded (half to
    even) and clipped to the ADC range."""
    rng = np.random.default_rng(11)
    n = 5000
    # negative, zero, far over the well, and half-DN ties (e = 1, 3 electrons: 64.5, 65.5 DN)
    signal = np.concatenate([rng.exponential(40.0, n), rng.uniform(0, 20, 200), [-5.0, 0.0, 1e9, 0.5, 1.5]])
    t, well, rn, gain, black, top, above = 2.0, 3000.0, 3.0, 2.0, 64.0, 4095.0, 30.0
    shot = noise == "shot"
    z = rng.standard_normal(len(signal), dtype=np.float32) if noise != "none" else np.empty(0)
    pois = rng.poisson(np.clip(signal * t, 0, above)).astype(np.float64) if shot else np.zeros(len(signal))
    out = np.empty(len(signal), dtype=np.uint8 if gamma > 0 else np.uint16)
    _kernels.expose(signal, t, z, pois, well, rn, shot, above, gamma, gain, black, top, out)

    e = np.minimum(np.maximum(signal, 0.0) * t, 4.0 * well)
    z64 = z.astype(np.float64)
    if noise == "read":
        e = e + rn * z64
    elif shot:
        e = np.where(e < above, pois + rn * z64, e + np.sqrt(e + rn * rn) * z64)
    e = np.minimum(e, well)
    if gamma > 0:
        ref = np.clip(np.rint(255.0 * np.maximum(e / well, 0.0) ** (1.0 / gamma)), 0, 255)
    else:
        ref = np.clip(np.rint(black + e / gain), 0, top)
    assert np.array_equal(out, ref.astype(out.dtype))
    if noise == "none" and gamma == 0:
        assert out[-3:].tolist() == [int(black + well / gain), 64, 66]  # a full well; half-DN ties round to even
    empty = np.empty(0, dtype=out.dtype)
    _kernels.expose(np.empty(0), t, np.empty(0), np.empty(0), well, rn, shot, above, gamma, gain, black, top, empty)


def _merge_linear_numpy(raw, rows, cols, t, black, sat, dark, black_limit):
    """The linear HDR merge from its definition: per pixel, the exposures not saturated in
    any channel; the longest of them always counts, a shorter one only if its largest
    channel reaches ``dark`` DN above black; radiance ``Σ (z − black) / Σ t`` over those used;
    near-black where only the longest counts and it reads below ``black_limit``."""
    z = raw[:, :, rows, cols, :].astype(np.float64)  # (L, E, P, 3)
    s = z - black
    ok = z.max(axis=-1) < sat  # (L, E, P)
    top = s.max(axis=-1)
    order = np.argsort(-t, kind="stable")  # longest first
    ok_sorted = ok[:, order]
    first = np.argmax(ok_sorted, axis=1)  # index (in order) of the longest usable exposure
    longest = np.zeros_like(ok)
    has_any = ok_sorted.any(axis=1)
    li, pi = np.nonzero(has_any)
    longest[li, order[first[li, pi]], pi] = True
    used = ok & (longest | (top >= dark))
    t_sum = np.einsum("lep,e->lp", used, t)
    n_used = used.sum(axis=1).astype(np.float64)
    acc = np.einsum("lepc,lep->lpc", s, used)
    valid = t_sum > 0
    out = np.where(valid[..., None], acc / np.where(valid, t_sum, 1.0)[..., None], 0.0)
    top_longest = np.where(longest, top, np.inf).min(axis=1)
    near_black = valid & (n_used == 1) & (top_longest < black_limit)
    return out, valid, near_black, t_sum, n_used


@twin("reflecto._kernels.merge_linear")
def test_merge_linear():
    from reflecto.instrument import hdr

    rng = np.random.default_rng(5)
    n_l, n_e, h, w = 3, 3, 9, 11
    top = 4095
    raw = rng.integers(60, 200, (n_l, n_e, h, w, 3)).astype(np.uint16)
    raw[rng.random((n_l, n_e, h, w)) < 0.2] = top  # saturated
    raw[:, :, 0, :, :] = rng.integers(64, 66, (n_l, n_e, w, 3))  # near black: 0-1 DN
    raw[:, :, 1, :2, :] = top  # saturated in every exposure: invalid
    raw[0, :, 2, 3, 1] = top  # one channel saturates the whole pixel
    t = np.array([4.0, 1.0, 16.0])  # exposures out of order
    rows, cols = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    rows, cols = rows.ravel().astype(np.intp), cols.ravel().astype(np.intp)
    black, sat = 64.0, hdr.SATURATION * top
    shape = (n_l, len(rows))
    out, valid, near, t_sum, n_used = (np.empty(shape + (3,)), np.empty(shape, bool), np.empty(shape, bool),
                                       np.empty(shape), np.empty(shape))
    _kernels.merge_linear(raw, rows, cols, t, black, sat, hdr.DARK_DN, hdr.BLACK_DN, out, valid, near, t_sum, n_used)
    ref = _merge_linear_numpy(raw, rows, cols, t, black, sat, hdr.DARK_DN, hdr.BLACK_DN)
    assert np.allclose(out, ref[0], rtol=1e-14, atol=0)
    for a, b in zip((valid, near, t_sum, n_used), ref[1:]):
        assert np.array_equal(a, b)
    assert (~valid).any() and near.any() and (n_used >= 2).any()  # every branch was taken
    empty = np.empty(0, np.intp)
    e_out = np.empty((n_l, 0, 3))
    _kernels.merge_linear(raw, empty, empty, t, black, sat, hdr.DARK_DN, hdr.BLACK_DN, e_out, np.empty((n_l, 0), bool),
                          np.empty((n_l, 0), bool), np.empty((n_l, 0)), np.empty((n_l, 0)))


# ----------------------------------------------------------------------------- hemicube
@twin("reflecto._kernels.cube_lookup")
@pytest.mark.parametrize("n", [4, 8, 16])
def test_cube_lookup(n):
    """Bilinear lookup: equal to :meth:`Hemicube.lookup_numpy`; the texel value at a texel
    centre; exact on a function linear in the top face's (u, v) = (x/z, y/z) inside it."""
    c = hemicube(n)
    rng = np.random.default_rng(n)
    values = rng.random(c.size)
    padded = c.pad_numpy(values)
    seams = np.array([[1, 1, 1], [-1, 1, 1], [1, 0, 1], [1, 1, 0], [0, 0, 1], [1, 0, 0], [0, -1, 0], [1, 1, -0.3]])
    seams /= np.linalg.norm(seams, axis=1)[:, None]
    dirs = np.concatenate([random_directions(rng, 3000), rng.normal(size=(300, 3)), seams])
    out = np.empty(len(dirs))
    _kernels.cube_lookup(padded, c._pad_offsets, c.n, _kernels.as_dirs(dirs), out)
    assert np.allclose(out, c.lookup_numpy(values, dirs, padded), rtol=1e-13, atol=1e-15)
    centres = np.empty(c.size)
    _kernels.cube_lookup(padded, c._pad_offsets, c.n, np.ascontiguousarray(c.directions), centres)
    assert np.allclose(centres, values, rtol=1e-12, atol=1e-13)
    # linear in (u, v) on the top face: exact between the texel centres
    top = c.directions[: n * n]
    u, v = top[:, 0] / top[:, 2], top[:, 1] / top[:, 2]
    lin = np.zeros(c.size)
    lin[: n * n] = 1.0 + 2.0 * u - 3.0 * v
    inner = 1.0 - 1.0 / n  # the outermost texel centres
    uu, vv = rng.uniform(-inner, inner, (2, 500))
    d = np.stack([uu, vv, np.ones(500)], axis=1)
    d /= np.linalg.norm(d, axis=1)[:, None]
    got = np.empty(500)
    _kernels.cube_lookup(c.pad_numpy(lin), c._pad_offsets, c.n, d, got)
    assert np.allclose(got, 1.0 + 2.0 * uu - 3.0 * vv, rtol=0, atol=1e-12)
    _kernels.cube_lookup(padded, c._pad_offsets, c.n, np.empty((0, 3)), np.empty(0))


@twin("reflecto._kernels.pad_border")
@pytest.mark.parametrize("n", [4, 16])
def test_pad_border(n):
    """The padded copy: ``Σ_j values[src_j] w_j`` at every padded texel (:meth:`Hemicube.pad_numpy`)."""
    c = hemicube(n)
    values = np.random.default_rng(1).random(c.size)
    assert np.allclose(c.pad(values), c.pad_numpy(values), rtol=1e-14, atol=1e-15)
    out = np.full(len(c._pad_src), -7.0)
    _kernels.pad_border(values, c._pad_border, c._pad_src, c._pad_w, out)
    ref = np.sum(values[c._pad_src] * c._pad_w, axis=1)
    assert np.allclose(out[c._pad_border], ref[c._pad_border], rtol=1e-14, atol=1e-15)
    inner = np.ones(len(out), bool)
    inner[c._pad_border] = False
    assert np.all(out[inner] == -7.0)  # only the border is written


@twin("reflecto._kernels.scatter_add")
def test_scatter_add():
    """``out[index[k]] += values[k]`` row by row: ``np.add.at``."""
    rng = np.random.default_rng(2)
    values = rng.normal(size=(4000, 2))
    index = rng.integers(0, 50, 4000).astype(np.intp)
    out = rng.normal(size=(50, 2))
    ref = out.copy()
    np.add.at(ref, index, values)
    _kernels.scatter_add(values, index, out)
    assert np.allclose(out, ref, rtol=1e-12, atol=1e-12)
    _kernels.scatter_add(np.empty((0, 2)), np.empty(0, np.intp), out)
    assert np.allclose(out, ref, rtol=1e-12, atol=1e-12)
    c = hemicube(16)  # the block sums of Hemicube.block_reduce
    v = rng.random((c.size, 2))
    assert np.allclose(c.block_reduce(v, 4), c.block_reduce_numpy(v, 4), rtol=1e-13, atol=0)


@twin("reflecto._kernels.cube_index")
@pytest.mark.parametrize("n", [4, 8, 64])
def test_cube_index(n):
    """Nearest texel: :meth:`Hemicube.index_numpy`; each texel centre is its own texel; the
    index does not depend on the length of the direction."""
    c = hemicube(n)
    rng = np.random.default_rng(3)
    dirs = np.concatenate([random_directions(rng, 5000), rng.normal(size=(500, 3)), [[0, 0, 1], [1, 1, 1], [1, 0, 0]]])
    out = np.empty(len(dirs), np.intp)
    _kernels.cube_index(n, _kernels.as_dirs(dirs), out)
    assert np.array_equal(out, c.index_numpy(dirs))
    _kernels.cube_index(n, _kernels.as_dirs(3.7 * dirs), out)
    assert np.array_equal(out, c.index_numpy(dirs))
    centres = np.empty(c.size, np.intp)
    _kernels.cube_index(n, np.ascontiguousarray(c.directions), centres)
    assert np.array_equal(centres, np.arange(c.size))
    _kernels.cube_index(n, np.empty((0, 3)), np.empty(0, np.intp))


@twin("reflecto._kernels.splat")
def test_splat():
    """``Σw`` and ``Σw v`` per nearest texel: ``np.bincount`` (:meth:`Hemicube.splat_numpy`)."""
    c = hemicube(16)
    rng = np.random.default_rng(4)
    d = random_directions(rng, 6000)
    v = rng.random((6000, 3))
    w = np.where(rng.random(6000) < 0.1, 0.0, rng.random(6000))
    ws, wv = c.splat(d, v, w)
    ws0, wv0 = c.splat_numpy(d, v, w)
    assert np.allclose(ws, ws0, rtol=1e-12, atol=1e-14) and np.allclose(wv, wv0, rtol=1e-12, atol=1e-14)
    idx = c.index_numpy(d)
    assert np.allclose(ws, np.bincount(idx, w, c.size), rtol=1e-12, atol=1e-14)
    ws, wv = np.zeros(c.size), np.zeros((c.size, 3))
    _kernels.splat(c.n, np.empty((0, 3)), np.empty((0, 3)), np.empty(0), ws, wv)
    assert not ws.any() and not wv.any()


def test_splat_of_no_samples_is_empty():
    ws, wv = hemicube(8).splat(np.empty((0, 3)), np.empty((0, 3)))
    assert not ws.any() and not wv.any()


def _lookup_at_fine_centres(coarse, values, m):
    """Reference of :func:`upsample`: :meth:`Hemicube.lookup_numpy` at the directions of
    the ``m·n`` hemicube's texel centres."""
    return coarse.lookup_numpy(values, hemicube(m * coarse.n).directions, coarse.pad_numpy(values))


@twin("reflecto._kernels.upsample")
@pytest.mark.parametrize("n, m", [(4, 1), (4, 2), (8, 3), (8, 4), (16, 2)])
def test_upsample(n, m):
    c = hemicube(n)
    values = np.random.default_rng(n * m).random(c.size)
    out = np.empty(hemicube(m * n).size)
    _kernels.upsample(c.pad_numpy(values), c._pad_offsets, n, m, out)
    assert np.allclose(out, _lookup_at_fine_centres(c, values, m), rtol=1e-12, atol=1e-13)
    if m == 1:
        assert np.allclose(out, values, rtol=1e-13, atol=0)  # the same texels
    const = np.empty_like(out)
    _kernels.upsample(c.pad_numpy(np.full(c.size, 2.5)), c._pad_offsets, n, m, const)
    assert np.allclose(const, 2.5, rtol=1e-14, atol=0)


@twin("reflecto._kernels.pull")
@pytest.mark.parametrize("min_weight", [1e-12, 0.5])
def test_pull(min_weight):
    """One push–pull step up: ``v/w`` where ``w > min_weight``, else the coarse estimate
    interpolated bilinearly at the fine texel's centre."""
    coarse, fine = hemicube(8), hemicube(16)
    rng = np.random.default_rng(6)
    est = rng.random(coarse.size)
    w = np.where(rng.random(fine.size) < 0.4, 0.0, rng.random(fine.size))
    w[:5] = min_weight  # on the threshold: a hole
    levels = np.stack([w, rng.random(fine.size) * w], axis=1)  # as push_pull passes them: column views
    ws, vs = levels[:, 0], levels[:, 1]
    out = np.empty(fine.size)
    _kernels.pull(coarse.pad_numpy(est), coarse._pad_offsets, coarse.n, ws, vs, min_weight, out)
    measured = ws > min_weight
    ref = np.where(measured, vs / np.where(measured, ws, 1.0), _lookup_at_fine_centres(coarse, est, 2))
    assert np.allclose(out, ref, rtol=1e-12, atol=1e-13)
    assert np.array_equal(out[measured], vs[measured] / ws[measured])  # measured texels are never changed
    assert 0 < measured.sum() < fine.size


@twin("reflecto._kernels.mirror_distances")
def test_mirror_distances():
    """Mirror the texels ``t`` across the plane with normal ``u = cos ψ e2 + sin ψ e1``
    (``t − 2(t·u)u``, z floored at 1e-9); keep the texels whose mirror lands on data
    (bilinear ``has`` > 0.999) for every ψ; ``out[ψ] = Σ (v − v(mirror))² / Σ v²`` over them,
    ``inf`` for fewer than 50 kept texels or a zero slice."""
    c = hemicube(16)
    rng = np.random.default_rng(8)
    has = (c.directions[:, 2] > math.cos(math.radians(70))).astype(np.float64)
    light = np.array([math.sin(0.6), 0.0, math.cos(0.6)])
    x = c.directions
    v = np.where(has > 0, np.exp(-8 * (x[:, 0] - 0.3) ** 2 - 5 * x[:, 1] ** 2) + 0.05 * rng.random(c.size), 0.0)
    e1 = np.array([0.0, 0.0, 1.0]) - light[2] * light
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(light, e1)
    psis = np.radians(np.arange(-12.0, 12.5, 1.0))

    def reference(t, vt, pad_v, pad_has):
        u = np.cos(psis)[:, None] * e2 + np.sin(psis)[:, None] * e1  # (Ψ, 3)
        mir = t[None] - 2.0 * np.einsum("kc,jc->jk", t, u)[..., None] * u[:, None, :]
        mir[..., 2] = np.maximum(mir[..., 2], 1e-9)
        keep = np.all(c.lookup_numpy(None, mir, pad_has) > 0.999, axis=0)
        scale = np.sum(vt[keep] ** 2)
        if keep.sum() < 50 or scale <= 0:
            return np.full(len(psis), np.inf), keep
        diff = vt[None, keep] - c.lookup_numpy(None, mir[:, keep], pad_v)
        return np.sum(diff**2, axis=1) / scale, keep

    def run(mask, values):
        t, vt = np.ascontiguousarray(c.directions[mask > 0]), np.ascontiguousarray(values[mask > 0])
        pad_v, pad_has = c.pad_numpy(values), c.pad_numpy(mask)
        out = np.empty(len(psis))
        _kernels.mirror_distances(t, vt, e1, e2, psis, pad_v, pad_has, c._pad_offsets, c.n, out)
        return out, reference(t, vt, pad_v, pad_has)

    out, (ref, keep) = run(has, v)
    assert keep.sum() >= 50 and np.all(np.isfinite(ref))
    assert np.allclose(out, ref, rtol=1e-12, atol=1e-15)
    assert abs(np.argmin(out) - len(psis) // 2) <= 1  # this slice is mirror-symmetric about ψ = 0 up to its noise
    few = np.zeros(c.size)
    few[np.argsort(-c.directions[:, 2])[:40]] = 1.0  # 40 texels with data: too few
    out, (ref, _) = run(few, v * few)
    assert np.all(np.isinf(out)) and np.all(np.isinf(ref))
    out, (ref, _) = run(has, np.zeros(c.size))  # a zero slice
    assert np.all(np.isinf(out)) and np.all(np.isinf(ref))


# ----------------------------------------------------------------------------- model
@twin("reflecto._kernels.quantize_ndf")
@pytest.mark.parametrize("normalize", [True, False])
def test_quantize_ndf(normalize):
    """``q = f32(d)``, ``total = Σ q psa``; normalized: ``f32(q / total)``; −1 for a negative,
    NaN or infinite value."""
    c = hemicube(8)
    psa = c.projected_solid_angles
    rng = np.random.default_rng(9)
    d = rng.gamma(0.5, 3.0, c.size)
    out = np.empty_like(d)
    total = _kernels.quantize_ndf(d, psa, normalize, out)
    q = d.astype(np.float32).astype(np.float64)
    assert total == pytest.approx(math.fsum(q * psa), rel=1e-13)
    ref = (q / total).astype(np.float32).astype(np.float64) if normalize else q
    assert np.array_equal(out, ref)
    assert not normalize or math.fsum(out * psa) == pytest.approx(1.0, rel=1e-6)
    for bad in (-1e-30, np.nan, np.inf, -np.inf):
        dd = d.copy()
        dd[17] = bad
        assert _kernels.quantize_ndf(dd, psa, normalize, np.empty_like(d)) == -1.0, bad
    zeros = np.zeros(c.size)
    out = np.full(c.size, 9.0)
    assert _kernels.quantize_ndf(zeros, psa, normalize, out) == 0.0 and not out.any()
    assert _kernels.quantize_ndf(np.empty(0), np.empty(0), normalize, np.empty(0)) == 0.0


@twin("reflecto._kernels.shadowing_at")
def test_shadowing_at():
    """``S = cos θ / max(σ, cos θ)`` (0 where that is 0) with σ bilinear in (θ, φ):
    :meth:`SigmaTable.eval` (NumPy) at the stencil's directions."""
    from reflecto.shadowing import SigmaTable, grid_stencil

    rng = np.random.default_rng(10)
    table = SigmaTable(0.7 + 0.6 * rng.random((19, 32)))
    dirs = np.concatenate([random_directions(rng, 4000), [[0, 0, 1], [1, 0, 0], [0, -1, 0], [0.6, 0, -0.8]]])
    st = grid_stencil(dirs, 19, 32)
    out = np.empty(len(dirs))
    _kernels.shadowing_at(table._flat(), table.n_phi + 1, st.idx, st.ft, st.fp, st.cos, out)
    cos = np.maximum(dirs[:, 2], 0.0)
    sigma = np.maximum(table.eval_sigma(dirs), cos)
    assert np.allclose(out, np.divide(cos, sigma, out=np.zeros_like(cos), where=sigma > 0), rtol=1e-14, atol=1e-15)
    assert np.allclose(table.eval_at(st), table.eval(dirs), rtol=1e-14, atol=1e-15)
    assert out[-1] == 0.0  # below the horizon


@twin("reflecto._kernels.pair_shadowing")
@pytest.mark.parametrize("correlated", [False, True])
def test_pair_shadowing(correlated):
    """The pair's shadowing from prepared cells equals :func:`isotropic.pair_shadowing` (the
    NumPy reference: :meth:`IsotropicNDF.shadowing`'s ``np.interp`` on σ's table) at random
    cosines, at the σ table's own angles, at grazing (cos 0, θ = π/2: the last node), at the
    pole and below the horizon (clipped to 0): bit for bit where NumPy's interpolation is
    built without a fused multiply–add (its x86-64 wheels), else within an ulp; a σ that is
    NaN gives S = 0 as ``np.maximum`` does; mismatched lengths are refused."""
    import platform

    from reflecto.errors import ParameterError
    from reflecto.polar import SIGMA_NODES, IsotropicNDF, polar_nodes, shadowing_cells
    from reflecto.reconstruct.isotropic import pair_shadowing

    rng = np.random.default_rng(11)
    nodes = polar_nodes()
    grid = np.linspace(0.0, 0.5 * math.pi, SIGMA_NODES)
    special = np.concatenate([np.cos(grid), [0.0, 1.0, -0.3, 1.2, 1e-300]])
    exact = platform.machine().lower() in ("x86_64", "amd64")
    for alpha in (0.02, 0.3, 0.9):  # sharp to broad: S from 1 down to ≈ 0 at grazing
        ndf = IsotropicNDF(nodes, np.exp(-np.tan(nodes) ** 2 / alpha**2) / np.cos(nodes) ** 4)
        cos_i = np.concatenate([rng.random(3000), special, rng.random(len(special))])
        cos_o = np.concatenate([rng.random(3000), rng.random(len(special)), special])
        geometry = 1.0 / (4.0 * np.maximum(cos_i, 0.05) * np.maximum(cos_o, 0.05))
        shadow, shadow_geometry = ndf.pair_shadowing(shadowing_cells(cos_i), shadowing_cells(cos_o), correlated,
                                                     geometry)
        want = pair_shadowing(ndf, cos_i, cos_o, correlated)
        if exact:
            assert np.array_equal(shadow, want) and np.array_equal(shadow_geometry, want * geometry)
        else:
            np.testing.assert_array_max_ulp(shadow, want, maxulp=2)
        assert shadow.min() >= 0.0 and shadow.max() <= 1.0
    assert shadow[3000 + SIGMA_NODES] == 0.0 and shadow[3000 + SIGMA_NODES + 2] == 0.0  # grazing, below
    nan_sigma = IsotropicNDF(nodes, np.ones(len(nodes)))
    object.__setattr__(nan_sigma, "sigma", np.full(SIGMA_NODES, np.nan))
    cells = shadowing_cells(np.array([0.2, 0.7, 1.0]))
    assert not nan_sigma.pair_shadowing(cells, cells, correlated)[0].any()
    with pytest.raises(ParameterError, match="pair shadowing"):
        ndf.pair_shadowing(cells, shadowing_cells(np.array([0.5])), correlated)


@twin("reflecto._kernels.model_eval")
@pytest.mark.parametrize("correlated", [False, True])
def test_model_eval(correlated):
    """:meth:`MicrofacetBRDF.eval` (the fused kernel) against :meth:`eval_numpy`, with
    directions below the horizon (0) and a coloured η."""
    from reflecto.model import MicrofacetBRDF

    rng = np.random.default_rng(12)
    c = hemicube(8)
    m = MicrofacetBRDF(np.exp(-4 * (1 - c.directions[:, 2])) + 0.1 * rng.random(c.size), kd=(0.2, 0.1, 0.05),
                       ks=(0.5, 0.6, 0.7), eta=(1.3, 1.5, 2.5), correlated=correlated)
    i = np.concatenate([random_directions(rng, 2000), [[0.6, 0, -0.8], [0, 0, 1]]])
    o = np.concatenate([random_directions(rng, 2000), [[0, 0, 1], [0, 0.6, -0.8]]])
    fast, slow = m.eval(i, o), m.eval_numpy(i, o)
    assert np.allclose(fast, slow, rtol=1e-12, atol=1e-15)
    assert np.all(fast[-2:] == 0.0)
    assert m.eval(np.empty((0, 3)), np.empty((0, 3))).shape == (0, 3)


# ----------------------------------------------------------------------------- Fresnel
@twin("reflecto._kernels.fresnel_flat")
def test_fresnel_flat():
    """Eq. 4, ``F = ½ (g−c)²/(g+c)² (1 + ((c(g+c)−1)/(c(g−c)+1))²)``, ``g = √(η² + c² − 1)``;
    1 under total internal reflection and for η = ∞; at normal incidence ((η−1)/(η+1))²."""
    from reflecto.fresnel import fresnel, fresnel_numpy

    rng = np.random.default_rng(13)
    c = np.concatenate([rng.random(3000), [0.0, 1.0, -0.5]])
    eta = np.concatenate([rng.uniform(0.5, 4.0, 3000), [1.5, 1.5, 1.5]])
    out = np.empty(len(c))
    _kernels.fresnel_flat(c, eta, out)
    ac = np.abs(c)
    g = np.sqrt(np.maximum(eta**2 + ac**2 - 1.0, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        ref = 0.5 * (g - ac) ** 2 / (g + ac) ** 2 * (1 + ((ac * (g + ac) - 1) / (ac * (g - ac) + 1)) ** 2)
    ref = np.where(eta**2 + ac**2 - 1.0 <= 0, 1.0, np.clip(np.nan_to_num(ref, nan=1.0), 0.0, 1.0))
    assert np.allclose(out, ref, rtol=1e-13, atol=1e-15)
    assert np.array_equal(out, fresnel_numpy(c, eta))
    assert out[-2] == pytest.approx((0.5 / 2.5) ** 2, rel=1e-14) and out[-3] == 1.0
    assert np.array_equal(fresnel(c[:10], np.inf), np.ones(10))


def _pair_inputs(rng, n):
    cp, cq = rng.uniform(0.05, 1.0, n), rng.uniform(0.05, 1.0, n)
    fp, fq = rng.uniform(0.0, 2.0, n), rng.uniform(0.0, 2.0, n)
    ap, aq = rng.uniform(0.1, 1.0, n), rng.uniform(0.1, 1.0, n)
    return cp, cq, fp, fq, ap, aq, rng.uniform(0.5, 1.5, n)


@twin("reflecto._kernels.pair_residuals")
def test_pair_residuals():
    """Eq. 6 per bin pair: :func:`fresnel_fit.pair_residuals_numpy`."""
    from reflecto.reconstruct.fresnel_fit import pair_residuals_numpy

    rng = np.random.default_rng(14)
    args = _pair_inputs(rng, 3000)
    for eta, kd, level in ((1.2, 0.0, 1e-3), (1.5, 0.1, 1e-3), (3.0, 0.3, 0.5)):
        out = np.empty(3000)
        _kernels.pair_residuals(*args, eta, kd / np.pi, level, out)
        assert np.allclose(out, pair_residuals_numpy(*args, eta, kd, level), rtol=1e-12, atol=1e-15)
    _kernels.pair_residuals(*(np.empty(0),) * 7, 1.5, 0.0, 1e-3, np.empty(0))


@twin("reflecto._kernels.pair_residuals_jac")
def test_pair_residuals_jac():
    """``∂r/∂η`` and ``∂r/∂(k_d/π)`` against central differences of the NumPy residual."""
    from reflecto.reconstruct.fresnel_fit import pair_residuals_numpy

    rng = np.random.default_rng(15)
    n = 2000
    args = _pair_inputs(rng, n)
    for eta, kd, level in ((1.2, 0.05, 1e-3), (1.8, 0.1, 1e-3), (2.5, 0.02, 0.8)):
        jac = np.empty((2, n))
        _kernels.pair_residuals_jac(*args, eta, kd / np.pi, level, jac)
        h = 1e-6
        d_eta = (pair_residuals_numpy(*args, eta + h, kd, level)
                 - pair_residuals_numpy(*args, eta - h, kd, level)) / (2 * h)
        hk = 1e-7  # in k_d/π
        d_kd = (pair_residuals_numpy(*args, eta, (kd / np.pi + hk) * np.pi, level)
                - pair_residuals_numpy(*args, eta, (kd / np.pi - hk) * np.pi, level)) / (2 * hk)
        assert np.allclose(jac[0], d_eta, rtol=1e-5, atol=1e-6)
        assert np.allclose(jac[1], d_kd, rtol=1e-6, atol=1e-6)


@twin("reflecto._kernels.overlap_pairs")
def test_overlap_pairs():
    """Direct and τ-symmetric bin pairs: :func:`fresnel_fit.overlap_pairs_numpy` (same order)."""
    from reflecto.reconstruct.fresnel_fit import overlap_pairs, overlap_pairs_numpy

    bins = _bins(hemicube(16))
    for symmetric in (True, False):
        a, b = overlap_pairs(bins, 4, symmetric), overlap_pairs_numpy(bins, 4, symmetric)
        assert len(a) > 100
        assert np.array_equal(a.p, b.p) and np.array_equal(a.q, b.q) and np.array_equal(a.symmetric, b.symmetric)


# ----------------------------------------------------------------------------- samples
def _slices(rng, n_l=4, n_p=3000):
    light = random_directions(rng, n_l, 60)
    view = random_directions(rng, n_p, 70)
    values = rng.random((n_l, n_p, 3))
    valid = rng.random((n_l, n_p)) < 0.8
    return light, view, values, valid


def _bins(cube):
    from reflecto.reconstruct.samples import bin_samples

    light, view, values, valid = _slices(np.random.default_rng(16))
    return bin_samples(light, view, values, valid, cube)


@twin("reflecto._kernels.bin_accumulate", "reflecto._kernels.bin_finish")
def test_bin_accumulate_and_finish():
    """Per (LED, texel of i + o): count, mean f, mean o (unit), h = (i + o)/|i + o|,
    cos θ_d = i·h; from ``np.unique`` and ``np.bincount`` over the valid samples, and
    :func:`samples.bin_samples_numpy`."""
    from reflecto.reconstruct.samples import bin_samples, bin_samples_numpy

    rng = np.random.default_rng(17)
    light, view, values, valid = _slices(rng)
    cube = hemicube(16)
    noise = rng.random(valid.shape)
    a = bin_samples(light, view, values, valid, cube, noise)
    b = bin_samples_numpy(light, view, values, valid, cube, noise)
    for name in ("led", "texel", "count", "i", "o", "h", "f", "variance"):
        assert np.allclose(getattr(a, name), getattr(b, name), rtol=1e-13, atol=1e-15), name
    li, pi = np.nonzero(valid)
    key = li * cube.size + cube.index_numpy(light[li] + view[pi])
    used, slot, count = np.unique(key, return_inverse=True, return_counts=True)
    assert np.array_equal(a.led, used // cube.size) and np.array_equal(a.texel, used % cube.size)
    assert np.array_equal(a.count, count)
    f = np.stack([np.bincount(slot, values[li, pi, ch]) for ch in range(3)], axis=1) / count[:, None]
    o = np.stack([np.bincount(slot, view[pi, ch]) for ch in range(3)], axis=1)
    o /= np.linalg.norm(o, axis=1)[:, None]
    h = light[a.led] + o
    h /= np.linalg.norm(h, axis=1)[:, None]
    assert np.allclose(a.f, f, rtol=1e-12) and np.allclose(a.o, o, rtol=1e-12, atol=1e-15)
    assert np.allclose(a.h, h, rtol=1e-12, atol=1e-15)
    assert np.allclose(a.cos_d, np.clip(np.sum(light[a.led] * h, axis=1), 0, 1), rtol=1e-12, atol=1e-15)
    # the kernels directly, with no valid sample
    none = np.zeros_like(valid)
    used, cnt, fsum, osum, qsum = _kernels.bin_accumulate(_kernels.as_dirs(light), _kernels.as_dirs(view), values,
                                                         none, cube.n, np.empty((0, 0)))
    assert len(used) == len(cnt) == len(fsum) == 0
    out = _kernels.bin_finish(_kernels.as_dirs(light), used, cnt, fsum, osum, cube.size)
    assert all(len(x) == 0 for x in out)


@twin("reflecto._kernels.gather_below")
def test_gather_below():
    """Per channel, the valid values below the threshold in their order, their count, and
    the count of valid values equal to it (NaN is neither)."""
    rng = np.random.default_rng(18)
    m = 5000
    values = np.round(rng.random((m, 3)) * 50) / 50  # quantized: ties at the thresholds
    values[::97, 1] = np.nan
    valid = rng.random(m) < 0.9
    for thresholds in (np.array([0.1, 0.5, 0.9]), np.array([np.inf, -np.inf, 0.0]), values[3].copy()):
        out = np.full((3, m), -1.0)
        counts, equal = _kernels.gather_below(values, valid, thresholds, out)
        for c in range(3):
            col = values[valid, c]
            below = col[col < thresholds[c]]
            assert counts[c] == len(below) and np.array_equal(out[c, : counts[c]], below), (thresholds, c)
            assert equal[c] == np.count_nonzero(col == thresholds[c])
    counts, equal = _kernels.gather_below(values, np.zeros(m, bool), np.full(3, np.inf), np.empty((3, 0)))
    assert counts.tolist() == equal.tolist() == [0, 0, 0]
    counts, equal = _kernels.gather_below(np.empty((0, 3)), np.empty(0, bool), np.full(3, np.inf), np.empty((3, 0)))
    assert counts.tolist() == [0, 0, 0]


@twin("reflecto._kernels.partial_ndf")
@pytest.mark.parametrize("channels", [3, 1])
def test_partial_ndf(channels):
    """Eq. 7: ``a = cos_io / max(S(i) S(o), 1e-12)``, ``dh = (f − k_d/π) 4a / F``, ``d_lum = dh · LUM``."""
    rng = np.random.default_rng(19)
    b, n_l = 3000, 6
    f = rng.random((b, 3))
    kd_over_pi = np.array([0.05, 0.1, 0.02])
    cos_io = rng.random(b)
    s_led = rng.uniform(0.5, 1.0, n_l)
    s_led[2] = 0.0  # S(i) S(o) = 0: the 1e-12 floor
    led = rng.integers(0, n_l, b).astype(np.intp)
    s_o = rng.uniform(0.3, 1.0, b)
    fres = rng.uniform(0.04, 1.0, (b, channels))
    dh, d_lum = np.empty((b, 3)), np.empty(b)
    _kernels.partial_ndf(f, kd_over_pi, cos_io, s_led, led, s_o, fres, LUM, dh, d_lum)
    a = cos_io / np.maximum(s_led[led] * s_o, 1e-12)
    ref = (f - kd_over_pi) * (4.0 * a)[:, None] / fres
    assert np.allclose(dh, ref, rtol=1e-14, atol=0) and np.allclose(d_lum, ref @ LUM, rtol=1e-13, atol=1e-300)
    assert np.any(led == 2)
    _kernels.partial_ndf(np.empty((0, 3)), kd_over_pi, np.empty(0), s_led, np.empty(0, np.intp), np.empty(0),
                         np.empty((0, channels)), LUM, np.empty((0, 3)), np.empty(0))


@twin("reflecto._kernels.box_mean")
def test_box_mean():
    """Mean of the valid samples in a ``(2r + 1)²`` pixel box: :func:`samples.box_mean_numpy`
    (SciPy's ``uniform_filter``), with holes and the image border."""
    from reflecto.reconstruct.samples import box_mean, box_mean_numpy

    rng = np.random.default_rng(20)
    rows, cols = np.meshgrid(np.arange(23), np.arange(31), indexing="ij")
    keep = rng.random(rows.size) < 0.7
    pixels = np.stack([rows.ravel()[keep], cols.ravel()[keep]], axis=1)
    values = rng.random((2, len(pixels), 3))
    valid = rng.random((2, len(pixels))) < 0.8
    valid[1] = False  # an LED with no valid sample: zeros
    for radius in (1, 3, 40):  # 40: the box covers the whole image
        got = box_mean(values, valid, pixels, radius)
        assert np.allclose(got, box_mean_numpy(values, valid, pixels, radius), rtol=1e-12, atol=1e-14)
        assert not got[1].any()
    full = box_mean(values, valid, pixels, 40)[0]
    assert np.allclose(full[valid[0]], values[0][valid[0]].mean(axis=0), rtol=1e-12)


# ----------------------------------------------------------------------------- Cook–Torrance
@twin("reflecto._kernels.ct_lobe")
def test_ct_lobe():
    """The Cook–Torrance lobe (Beckmann D, V-groove G, Schlick F): ``cooktorrance._lobe``;
    0 below the horizon."""
    from reflecto.evaluate.cooktorrance import _lobe

    rng = np.random.default_rng(21)
    i = np.concatenate([random_directions(rng, 3000), [[0.6, 0, -0.8]]])
    o = np.concatenate([random_directions(rng, 3000), [[0, 0, 1]]])
    scale = rng.random(len(i)) + 0.5
    for f0, m in ((0.04, 0.05), (0.9, 0.4), (0.3, 1.5)):
        out = np.empty(len(i))
        _kernels.ct_lobe(i, o, scale, f0, m, out)
        assert np.allclose(out, np.nan_to_num(_lobe(i, o, f0, m)) * scale, rtol=1e-12, atol=0)
        assert out[-1] == 0.0


@twin("reflecto._kernels.ct_residual")
def test_ct_residual():
    """``out[k, c] = ρ_d,c diff[k] + ρ_s,c lobe[k] − y[k, c]``."""
    rng = np.random.default_rng(22)
    diff, lobe, y = rng.random(1000), rng.random(1000), rng.random((1000, 3))
    rd, rs = np.array([0.1, 0.2, 0.3]), np.array([0.5, 0.0, 2.0])
    out = np.empty((1000, 3))
    _kernels.ct_residual(diff, lobe, y, rd, rs, out)
    assert np.allclose(out, np.outer(diff, rd) + np.outer(lobe, rs) - y, rtol=1e-14, atol=1e-15)
    _kernels.ct_residual(np.empty(0), np.empty(0), np.empty((0, 3)), rd, rs, np.empty((0, 3)))


# ----------------------------------------------------------------------------- isotropic fit
@twin("reflecto.reconstruct._polar_kernels.bin_polar")
@pytest.mark.parametrize("step_deg", [1.0, 3.0])  # the model's θ_d cells, the normal's light fits'
def test_bin_polar(step_deg):
    """(LED, θ_h cell, θ_d cell) bins: :func:`isotropic.bin_polar_numpy` (bisection =
    ``searchsorted``), including θ_h beyond the last edge."""
    from reflecto.polar import polar_nodes
    from reflecto.reconstruct import isotropic

    rng = np.random.default_rng(23)
    light, view, values, mask = _slices(rng, 3, 2000)
    noise, bound = rng.random(mask.shape), rng.random(mask.shape)
    nodes = polar_nodes()
    edges = np.interp(np.arange((len(nodes) - 1) * 2 + 1) / 2, np.arange(len(nodes)), nodes)
    step = math.radians(step_deg)
    n_td = int(math.ceil(0.5 * math.pi / step)) + 1
    n_keys = len(light) * (len(edges) - 1) * n_td
    count, sums, fs = np.zeros(n_keys), np.zeros((n_keys, 5)), np.zeros((n_keys, 3))
    _polar_kernels.bin_polar(mask, light, view, values, noise, bound, edges, cell_table(edges.tobytes()),
                             step, n_td, *isotropic.theta_d_tables(n_td, step), count, sums, fs)
    ref = isotropic.bin_polar_numpy(mask, light, view, values, noise, bound, edges, n_td, step)
    assert np.array_equal(count, ref[0]) and count.sum() == mask.sum()
    assert np.allclose(sums, ref[1], rtol=1e-12, atol=1e-13) and np.allclose(fs, ref[2], rtol=1e-12, atol=1e-13)


@pytest.mark.parametrize("step_deg", [1.0, 3.0])
def test_theta_d_cell_is_the_arccos_cell_at_and_beside_every_edge(step_deg):
    """The binning's θ_d cell without the arccos equals ``min(⌊arccos(c)/step⌋, n_td − 1)``
    on random cosines and on each cell edge, a few ulps and 10⁻¹³–10⁻⁹ either side of it."""
    from reflecto.reconstruct import _polar_kernels, isotropic

    step = math.radians(step_deg)
    n_td = int(math.ceil(0.5 * math.pi / step)) + 1
    td_cos, table = isotropic.theta_d_tables(n_td, step)
    cs = [0.0, 1.0, *np.random.default_rng(25).random(20000)]
    for edge in td_cos[:n_td]:
        near = [edge]
        for direction in (-1.0, 2.0):
            x = float(edge)
            for _ in range(4):
                x = float(np.nextafter(x, direction))
                near.append(x)
        near += [edge + s * d for d in (1e-13, 1e-12, 2e-12, 1e-9) for s in (-1.0, 1.0)]
        cs += [float(x) for x in near if 0.0 <= x <= 1.0]
    got = [_polar_kernels._theta_d_cell(c, step, n_td, td_cos, table) for c in cs]
    assert got == [min(int(math.acos(c) / step), n_td - 1) for c in cs]


@twin("reflecto.reconstruct._polar_kernels.normal_equations")
def test_normal_equations():
    """``JᵀWJ`` and ``JᵀWr``: :func:`isotropic.normal_equations_numpy`, and the dense Jacobian's products."""
    from reflecto.reconstruct import isotropic

    rng = np.random.default_rng(24)
    k, n = 12, 3000
    j = rng.integers(0, k - 1, n).astype(np.intp)
    t, spec, r = rng.random(n), rng.random(n), rng.standard_normal(n)
    w = np.where(rng.random(n) < 0.2, 0.0, rng.random(n))
    dcols = rng.standard_normal((n, 3))
    out = [np.empty(k), np.empty(k - 1), np.empty((k, 3)), np.empty((3, 3)), np.empty(k), np.empty(3)]
    _polar_kernels.normal_equations(j, t, spec, dcols, r, w, k, *out)
    for a, b in zip(out, isotropic.normal_equations_numpy(j, t, spec, dcols, r, w, k)):
        assert np.allclose(a, b, rtol=1e-11, atol=1e-12)
    jz = np.zeros((n, k))  # the full Jacobian: JᵀWJ's blocks
    jz[np.arange(n), j] = spec * (1 - t)
    jz[np.arange(n), j + 1] += spec * t
    full = np.concatenate([jz, dcols], axis=1)
    jtj, jtr = full.T @ (w[:, None] * full), full.T @ (w * r)
    assert np.allclose(out[0], np.diag(jtj)[:k], rtol=1e-11)
    assert np.allclose(out[1], np.diag(jtj, 1)[: k - 1], rtol=1e-11)
    assert np.allclose(out[2], jtj[:k, k:], rtol=1e-11, atol=1e-12) and np.allclose(out[3], jtj[k:, k:], rtol=1e-11)
    assert np.allclose(out[4], jtr[:k], rtol=1e-11, atol=1e-12) and np.allclose(out[5], jtr[k:], rtol=1e-11)


def _luminance_problem(seed: int = 25, b: int = 3000, k: int = 10):
    """A random luminance problem: cells, weights, log nodes (one overflowing), geometry, …"""
    rng = np.random.default_rng(seed)
    j = rng.integers(0, k - 1, b).astype(np.intp)
    t = rng.random(b)
    z = rng.normal(0, 2, k)
    z[4] = 800.0  # overflow guard: e^{min(z, 700)}
    return (j, t, z, rng.uniform(0.25, 3.0, b), rng.random(b), rng.random(b) * 3, rng.random(b),
            rng.random(b) < 0.7, 0.3, 0.02)


def _luminance_reference(j, t, z, geo, cos_d, f, measured, kd, g, eta):
    """NumPy: the specular part, the residual (0 where a bound is not active), and activity."""
    from reflecto.fresnel import fresnel_numpy

    lz = np.minimum((1 - t) * z[j] + t * z[j + 1], 700.0)
    fr = fresnel_numpy(cos_d, eta)
    with np.errstate(over="ignore", invalid="ignore"):
        s = g * fr * np.exp(lz) * geo
        r0 = kd / np.pi + s - f
    active = measured | (r0 > 0)
    return s, np.where(active, r0, 0.0), active, fr


@twin("reflecto.reconstruct._polar_kernels.luminance_pass")
@pytest.mark.parametrize("eta", [1.5, 3.0, np.inf])
def test_luminance_pass(eta):
    """``m = k_d/π + g F(c; η) e^{z(θ)} G``, ``z`` linear between nodes (its exponent capped
    at 700), ``r = m − f`` (one-sided where not measured), cost ``Σ w r²``."""
    j, t, z, geo, cos_d, f, w, measured, kd, g = _luminance_problem()
    b = len(j)
    r, spec, fr_out, act = np.empty(b), np.empty(b), np.empty(b), np.empty(b, dtype=bool)
    out = (r, spec, fr_out, act)
    cost = _polar_kernels.luminance_pass(j, t, z, geo, cos_d, f, w, measured, kd, g, eta, *out)
    s, r_ref, active, fr = _luminance_reference(j, t, z, geo, cos_d, f, measured, kd, g, eta)
    finite = np.isfinite(r_ref)
    assert np.array_equal(np.isfinite(r), finite) and np.allclose(r[finite], r_ref[finite], rtol=1e-13, atol=1e-15)
    assert np.array_equal(act[finite], active[finite]) and np.allclose(fr_out, fr, rtol=1e-13)
    ok = np.isfinite(s)
    assert np.allclose(spec[ok], s[ok], rtol=1e-13, atol=0.0)
    assert np.any(~measured & ~active) and np.any(~measured & active)  # both sides of the bound
    if not math.isfinite(eta):
        assert np.all(fr == 1.0)
    with np.errstate(over="ignore", invalid="ignore"):
        assert cost == pytest.approx(np.sum(w * r_ref**2), rel=1e-12) or not math.isfinite(cost)
    # without the overflowing node the cost is finite and equals the sum
    z[4] = 1.0
    cost = _polar_kernels.luminance_pass(j, t, z, geo, cos_d, f, w, measured, kd, g, eta, *out)
    _, r_ref, _, _ = _luminance_reference(j, t, z, geo, cos_d, f, measured, kd, g, eta)
    assert np.allclose(r, r_ref, rtol=1e-13, atol=1e-15) and cost == pytest.approx(np.sum(w * r_ref**2), rel=1e-12)
    assert _polar_kernels.luminance_pass(j[:0], t[:0], z, geo[:0], cos_d[:0], f[:0], w[:0], measured[:0], kd, g, eta,
                                         *(a[:0] for a in out)) == 0.0


@twin("reflecto.reconstruct._polar_kernels.pass_normal_equations")
@pytest.mark.parametrize("eta", [1.5, 3.0, np.inf])
def test_pass_normal_equations(eta):
    """From the values a :func:`luminance_pass` stored, the normal equations of the columns
    ``[1/π, spec, ∂r/∂ log(η − 1)]`` (``spec (∂F/∂η)/F (η − 1)``, 0 for η = ∞ and on
    inactive bins) with the weight where the bin is active: NumPy's
    :func:`normal_equations_numpy` of the reference columns; the η column also against a
    central difference."""
    from reflecto.fresnel import fresnel_numpy
    from reflecto.reconstruct.isotropic import normal_equations_numpy

    j, t, z, geo, cos_d, f, w, measured, kd, g = _luminance_problem(seed=27)
    z[4] = 1.0
    k, b = len(z), len(j)
    s, r_ref, active, fr = _luminance_reference(j, t, z, geo, cos_d, f, measured, kd, g, eta)
    assert np.any(~active) and np.any(active)
    if math.isfinite(eta):
        de = 1e-6 * eta  # the kernel's forward difference
        d_eta = s * (fresnel_numpy(cos_d, eta + de) - fr) / de / fr * (eta - 1.0)
        h = 1e-5
        d_central = s * (fresnel_numpy(cos_d, eta + h) - fresnel_numpy(cos_d, eta - h)) / (2 * h) / fr * (eta - 1.0)
        assert np.allclose(d_eta[active], d_central[active], rtol=1e-4, atol=1e-9 * np.abs(s).max())
    else:
        d_eta = np.zeros(len(j))
    w_act = np.where(active, w, 0.0)
    cols = np.stack([np.full(len(j), 1 / np.pi), s, d_eta], axis=1)
    ref = normal_equations_numpy(j, t, s, cols, r_ref, w_act, k)
    kept = (np.empty(b), np.empty(b), np.empty(b), np.empty(b, dtype=bool))
    _polar_kernels.luminance_pass(j, t, z, geo, cos_d, f, w, measured, kd, g, eta, *kept)
    out = (np.empty(k), np.empty(k - 1), np.empty((k, 3)), np.empty((3, 3)), np.empty(k), np.empty(3))
    _polar_kernels.pass_normal_equations(j, t, cos_d, *kept, w, eta, k, *out)
    for got, want in zip(out, ref):
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12 * np.abs(want).max())


# ----------------------------------------------------------------------------- layout
@twin("reflecto.instrument.layout._terms_kernel")
def test_layout_terms_kernel():
    """The first three layout goals in one pass: :func:`layout.layout_terms` (NumPy)."""
    from reflecto.instrument import layout
    from reflecto.instrument.optics import Optics

    rng = np.random.default_rng(26)
    for cone, tilt in ((48.2, 20.0), (65.0, 10.0)):
        o = Optics(cone_half_angle_deg=cone, axis_tilt_deg=tilt)
        cube = hemicube(32)
        goals = layout.LayoutObjective(o, cube)
        for _ in range(3):
            leds = layout.led_direction(rng.uniform(5, 80, 6), rng.uniform(0, 360, 6))
            assert np.allclose(goals.terms(leds)[:3], layout.layout_terms(o, leds, cube), rtol=0, atol=1e-12)
        assert goals.terms(layout.led_direction([89.9], [0.0]))[0] == pytest.approx(
            layout.layout_terms(o, layout.led_direction([89.9], [0.0]), cube)[0], abs=1e-12)


# ----------------------------------------------------------------------------- capture → slices kernels
@twin("reflecto._kernels.count_saturated")
def test_count_saturated_counts_the_listed_pixels_at_or_above_the_level():
    rng = np.random.default_rng(11)
    img = rng.integers(0, 65536, (24, 32, 3), dtype=np.uint16)
    rows = rng.integers(0, 24, 300).astype(np.int64)
    cols = rng.integers(0, 32, 300).astype(np.int64)
    for sat in (0, 40000, 65535, 65536):
        want = int((img[rows, cols].max(axis=-1) >= sat).sum())
        assert _kernels.count_saturated(img, rows, cols, sat) == want
    assert _kernels.count_saturated(img, rows[:0], cols[:0], 1) == 0


@twin("reflecto._kernels.merge_noise_sd")
@pytest.mark.parametrize("shot", [True, False])
def test_merge_noise_sd_is_the_noise_model_of_the_merge(shot):
    rng = np.random.default_rng(12)
    lum = np.maximum(rng.normal(50.0, 40.0, (6, 500)), 0.0)
    t_sum = rng.uniform(0.0, 9.0, (6, 500))
    t_sum[0, :5] = 0.0  # no exposure used: the 1e-300 floor
    n_used = rng.integers(0, 3, (6, 500)).astype(np.float64)
    per_var, gain = 2.5**2 + 1.0 / 12.0, 4.0
    out = np.empty_like(lum)
    _kernels.merge_noise_sd(lum, t_sum, n_used, per_var, gain, shot, out)
    var = n_used * per_var + (lum * t_sum / gain if shot else 0.0)
    np.testing.assert_array_equal(out, np.sqrt(var) / np.maximum(t_sum, 1e-300))


@twin("reflecto._kernels.slice_values")
def test_slice_values_divides_by_the_scale_where_valid():
    rng = np.random.default_rng(13)
    L, P = 6, 400
    rad = rng.uniform(0.0, 100.0, (L, P, 3))
    scl = rng.uniform(-0.1, 2.0, (L, P, 3))
    scl_pos = np.all(scl > 0, axis=-1)
    valid = rng.uniform(size=(L, P)) > 0.2
    s_lum = np.abs(scl @ LUM) + 1e-3
    sigma = rng.uniform(0.0, 1.0, (L, P))
    t_sum = rng.uniform(0.0, 5.0, (L, P))
    black_dn = 2.0
    values, noise, limit = np.empty_like(rad), np.empty((L, P)), np.empty((L, P))
    ok = np.empty((L, P), dtype=np.bool_)
    _kernels.slice_values(rad, valid, scl, scl_pos, s_lum, sigma, t_sum, black_dn, values, ok, noise, limit)
    want_ok = valid & scl_pos
    np.testing.assert_array_equal(ok, want_ok)
    np.testing.assert_array_equal(values, np.where(want_ok[..., None], rad / np.where(want_ok[..., None], scl, 1.0),
                                                   0.0))
    np.testing.assert_array_equal(noise, np.where(want_ok, sigma / s_lum, 0.0))
    np.testing.assert_array_equal(limit, np.where(want_ok, black_dn / np.maximum(t_sum, 1e-300) / s_lum, 0.0))


def _png_filter(raw: np.ndarray, kinds: np.ndarray, bpp: int) -> np.ndarray:
    """The PNG spec's forward row filters (§9.2), vectorized over each row: filtered bytes
    with each row's filter type byte in front (what ``png_unfilter`` undoes)."""
    h, n = raw.shape
    x = raw.astype(np.int32)
    a = np.zeros_like(x)
    a[:, bpp:] = x[:, :-bpp]  # left
    b = np.zeros_like(x)
    b[1:] = x[:-1]  # up
    c = np.zeros_like(x)
    c[1:, bpp:] = x[:-1, :-bpp]  # up-left
    p = a + b - c
    pa, pb, pc = np.abs(p - a), np.abs(p - b), np.abs(p - c)
    paeth = np.where((pa <= pb) & (pa <= pc), a, np.where(pb <= pc, b, c))
    pred = np.stack([np.zeros_like(x), a, b, (a + b) >> 1, paeth])[kinds, np.arange(h)]
    filtered = ((x - pred) & 0xFF).astype(np.uint8)
    return np.concatenate([kinds[:, None].astype(np.uint8), filtered], axis=1).ravel()


@twin("reflecto._kernels.png_unfilter")
@pytest.mark.parametrize("bpp", [3, 6])
def test_png_unfilter_inverts_every_row_filter(bpp):
    rng = np.random.default_rng(14)
    h, n = 40, 8 * bpp
    raw = rng.integers(0, 256, (h, n), dtype=np.uint8)
    kinds = np.resize(np.arange(5), h)  # every filter type, also on the first row (no row above)
    rng.shuffle(kinds)
    data = _png_filter(raw, kinds, bpp)
    out = np.zeros((h, n), dtype=np.uint8)
    assert _kernels.png_unfilter(data, h, n, bpp, out) == -1
    np.testing.assert_array_equal(out, raw)
    bad = data.copy()
    bad[7 * (n + 1)] = 5  # row 7's filter type is not 0–4
    assert _kernels.png_unfilter(bad, h, n, bpp, np.zeros((h, n), dtype=np.uint8)) == 7


@twin("reflecto.reconstruct._normal_kernels.tilt_pass", "reflecto.reconstruct._normal_kernels.theta_cells")
def test_tilt_pass_matches_its_numpy_reference_and_finite_differences():
    """The compiled pass of the tilt's least squares gives the NumPy reference's residuals,
    θ_h cells and samples, and its analytic tilt columns are the residuals' central
    differences (away from the NDF's nodes, where log D has a kink)."""
    from reflecto import geometry
    from reflecto.instrument.calibrate import nominal_calibration
    from reflecto.instrument.device import Device
    from reflecto.instrument.simulate import simulate_capture
    from reflecto.instrument.slices import extract_slices
    from reflecto.reconstruct.normal import TiltProblem, _light_model, _tilt_normal, light_fit
    from reflecto.reconstruct.pipeline import usable_samples
    from reflecto.sources.analytic import AnalyticBRDF

    dev = Device.builtin("ideal")
    cap = simulate_capture(AnalyticBRDF(distribution="ggx", alpha=0.2, kd=0.1, ks=0.6, eta=1.5), dev,
                           tilt_deg=4.0, tilt_azimuth_deg=130.0, seed=3)
    sl, truth = extract_slices(cap, nominal_calibration(dev)), np.array(cap.extra["simulation"]["normal"])
    valid = usable_samples(sl)
    problem = TiltProblem(sl, valid)
    model = _light_model(light_fit(sl, valid, geometry.frame_from_normal(truth, np.array([1.0, 0, 0])), None))
    ndf = model.ndf_table
    z = ndf.log_values + math.log(float(model.ks @ LUM))
    kd, fresnel = float(model.kd @ LUM), problem.fresnel(model)
    xy = truth[:2] / truth[2] + np.array([0.004, -0.003])
    ev = problem.evaluate(ndf, xy, z, kd, fresnel, jacobian=True)
    r, spec, j, t, use = problem.residuals_numpy(ndf, _tilt_normal(xy)[0], z, kd, fresnel)
    np.testing.assert_allclose(ev.r, r, rtol=1e-9, atol=1e-12 * np.abs(r).max())
    np.testing.assert_array_equal(ev.j, j)
    np.testing.assert_allclose(ev.t, t, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(ev.use, use)
    assert 0 < np.count_nonzero(use) < len(use) or np.all(use)
    np.testing.assert_allclose(ev.cost, float(np.sum(ev.w * ev.r ** 2)), rtol=1e-12)
    eps = 1e-6
    for q in range(2):
        e = np.zeros(2)
        e[q] = eps
        up = problem.residuals_numpy(ndf, _tilt_normal(xy + e)[0], z, kd, fresnel)
        down = problem.residuals_numpy(ndf, _tilt_normal(xy - e)[0], z, kd, fresnel)
        smooth = use & (up[2] == j) & (down[2] == j)  # the same θ_h cell on both sides
        fd = (up[0] - down[0]) / (2 * eps)
        scale = np.abs(fd[smooth]).max()
        assert scale > 0
        close = np.abs(ev.dr[smooth, q] - fd[smooth]) <= 1e-4 * np.abs(fd[smooth]) + 1e-6 * scale
        # all but the few samples on a kink of σ's table (a node of its θ grid, or where σ meets cos θ)
        assert np.count_nonzero(~close) <= 1e-3 * len(close), np.count_nonzero(~close)


@twin("reflecto.reconstruct._polar_kernels.luminance_lm")
@pytest.mark.parametrize("case", ["free", "tied", "fixed_eta", "constant"])
def test_luminance_lm_is_the_numpy_solve(case):
    """The compiled Levenberg–Marquardt loop of the luminance fit takes the steps of
    :func:`isotropic.solve_numpy` (its NumPy reference) on a capture's bins: a GGX α 0.2,
    η 1.6 lobe with a diffuse floor (free η; ``k_s`` tied to 1; η held; the constant
    Fresnel lobe), from the data's initial state with the priors set, to the same state
    and cost within rounding."""
    from reflecto.instrument.calibrate import nominal_calibration
    from reflecto.instrument.device import Device
    from reflecto.instrument.simulate import simulate_capture
    from reflecto.instrument.slices import extract_slices
    from reflecto.reconstruct import isotropic
    from reflecto.reconstruct.pipeline import usable_samples
    from reflecto.sources.analytic import AnalyticBRDF

    dev = Device.builtin("ideal")
    src = AnalyticBRDF(distribution="ggx", alpha=0.2, eta=1.6, kd=(0.2, 0.15, 0.1), ks=0.5)
    sl = extract_slices(simulate_capture(src, dev, seed=4), nominal_calibration(dev))
    nodes = isotropic.polar_nodes()
    bins = isotropic.bin_polar(sl, nodes, usable_samples(sl) & sl.valid)
    eta = {"fixed_eta": 1.9, "constant": math.inf}.get(case, 1.5)
    problems = []
    for _ in range(2):
        p = isotropic.LuminanceProblem(bins, nodes)
        isotropic.set_weights(p)
        s = isotropic.initial_state(p, eta)
        isotropic.update_shadowing(p, s)
        isotropic.prior(p, s)
        problems.append((p, s))
    kw = dict(fix_eta=case in ("fixed_eta", "constant"), tie_ks=case == "tied")
    (pa, sa), (pb, sb) = problems
    fast, cost = isotropic.solve(pa, sa, **kw)
    ref, cost_ref = isotropic.solve_numpy(pb, sb, **kw)
    assert cost < 0.5 * pa.cost(sa)  # the loop moved
    assert cost == pytest.approx(cost_ref, rel=1e-7)  # rounding: BLAS products in another order
    np.testing.assert_allclose(fast.z, ref.z, rtol=0, atol=1e-7)
    assert fast.kd == pytest.approx(ref.kd, rel=1e-7, abs=1e-12)
    assert fast.g == pytest.approx(ref.g, rel=1e-7)
    assert fast.eta == pytest.approx(ref.eta, rel=1e-9) or fast.eta == ref.eta
    if kw["fix_eta"]:
        assert fast.eta == eta
    if case == "tied":
        assert fast.g == 1.0
    # the pass buffers hold a pass the normal equations can start from, as the reference's do
    assert np.all(np.isfinite(pa._r))


# ----------------------------------------------------------------------------- RGL reader
@twin("reflecto.sources._rgl_kernels.warp_sample", "reflecto.sources._rgl_kernels.bilinear_one_slice")
def test_rgl_warp_and_one_slice_lookup(shared, rng):
    """The compiled warp (:meth:`Marginal2D.sample`) equals its NumPy reference
    (:meth:`Marginal2D.sample_numpy`) bit for bit, on a shared file's ``vndf`` (every
    incident slice) and on a table with flat stretches, rows of no mass, corners and
    clipped samples; the compiled lookup of a one-slice table equals the interpolation
    between two slices at the first one's parameter."""
    from reflecto.sources.rgl import Marginal2D

    u = np.concatenate([rng.random((20000, 2)), [[0, 0], [1, 1], [0, 1], [1, 0], [-0.5, 0.3], [0.4, 1.5]]])
    from reflecto.load import load_source

    vndf = load_source(sorted((shared / "rgl").glob("*.bsdf"))[0])._vndf
    k = rng.integers(0, vndf.norm_data.shape[0], len(u))
    assert np.array_equal(vndf.sample(u, k), vndf.sample_numpy(u, k))
    data = rng.random((1, 2, 9, 13))
    data[0, 0, :, 3:7] = 0.0
    data[0, 1, 2:5, :] = 0.0
    m = Marginal2D(data, np.zeros(1), np.array([0.1, 0.6]))
    for k in (0, 1):
        assert np.array_equal(m.sample(u, k), m.sample_numpy(u, k))
    nodes = rng.random((40, 2))
    both = np.array([[0], [1]])
    assert np.array_equal(m.sample(nodes[None], both), m.sample_numpy(nodes[None], both))
    for bad in (2, -3, 10**8):  # the compiled loop reads only inside the tables
        with pytest.raises(IndexError):
            m.sample(u[:3], bad)
    assert np.array_equal(m.sample(u, -1), m.sample_numpy(u, -1))
    table = rng.random((7, 11))
    one = Marginal2D(table[None, None], np.zeros(1), np.zeros(1), build_cdf=False)
    two = Marginal2D(np.stack([table, rng.random((7, 11))])[None], np.zeros(1), np.array([0.0, 1.0]), build_cdf=False)
    zero = np.zeros(len(u))
    assert np.array_equal(one.eval(u, zero, zero), two.eval(u, zero, zero))
    assert one.eval(u.reshape(2, -1, 2), zero.reshape(2, -1), zero.reshape(2, -1)).shape == (2, len(u) // 2)
