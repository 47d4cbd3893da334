"""The reconstruction of paper §5: slices → generalized microfacet BRDF.

::

    estimate the altered normal (§5.4)                       normal.py
    repeat (≤ 5, Fresnel loop):
        fit η to overlapping slices (§5.1, eqs. 5–6)          fresnel_fit.py
        repeat (≤ 6, NDF/shadowing loop):
            partial NDFs (eq. 7), merged (eq. 9) and
            completed by symmetry (eq. 3)                     ndf.py
            S from the NDF (eq. 8)                            shadowing.py
            k_d, k_s per channel (linear least squares)
    resample the NDF to the output hemicube (512² top, 512×256 sides)

Colour: one NDF shared by R, G, B (built from the luminance-weighted per-channel
partial NDFs); k_d, k_s and η per channel (algorithm-reference §4.3 [R]). This keeps
the NDF's shape from the best-exposed data and puts colour in the scalars, which is
what the model can represent; coloured metals get their tint from k_s and η.

Shake (§5.1): when E(η) exceeds :data:`SHAKE_THRESHOLD`, the LED whose exclusion
lowers E(η) most is dropped and the fit is repeated; the summary flags it.
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .. import geometry
from ..fresnel import fresnel
from ..hemicube import hemicube
from ..model import MicrofacetBRDF
from ..shadowing import sigma_table
from ..instrument.slices import Slices
from . import ndf as ndf_mod
from .fresnel_fit import FresnelFit, fit_eta, texel_means
from .normal import SymmetryDistance, estimate_normal

Array = NDArray[np.float64]
LUM = np.array([0.2126, 0.7152, 0.0722])

#: E(η) above this marks a shaken capture (set from clean and shaken simulations).
SHAKE_THRESHOLD = 0.12


@dataclasses.dataclass
class Options:
    """Reconstruction settings.

    Attributes
    ----------
    resolution
        Output NDF hemicube N (paper: 512).
    work_resolution
        Hemicube N on which samples are merged (≈ 5 samples per texel per slice at 256).
    estimate_normal
        Run §5.4. Off by default: on untilted analytic captures it still finds a
        3–6° tilt (work in progress, issue 4), so it is opt-in.
    fixed_eta
        Use this η instead of fitting it (for layouts whose overlaps miss the lobe).
    outer_iterations, inner_iterations
        Fresnel and NDF/shadowing loops (paper: ≤ 5 and ≤ 6).
    """

    resolution: int = 512
    work_resolution: int = 128
    estimate_normal: bool = False
    max_tilt_deg: float = 16.0
    outer_iterations: int = 3
    inner_iterations: int = 3
    detect_shake: bool = True
    fixed_eta: float | None = None


@dataclasses.dataclass
class ReconstructionResult:
    model: MicrofacetBRDF
    summary: dict[str, Any]


def _nnls2(a: Array, b: Array, y: Array) -> tuple[float, float]:
    """``min |x0 a + x1 b − y|²`` with x ≥ 0 (two unknowns)."""
    m = np.array([[a @ a, a @ b], [a @ b, b @ b]])
    r = np.array([a @ y, b @ y])
    try:
        x = np.linalg.solve(m, r)
    except np.linalg.LinAlgError:
        x = np.array([-1.0, -1.0])
    if x[0] >= 0 and x[1] >= 0:
        return float(x[0]), float(x[1])
    c0 = max(float(a @ y) / max(float(a @ a), 1e-300), 0.0)
    c1 = max(float(b @ y) / max(float(b @ b), 1e-300), 0.0)
    e0 = np.sum((c0 * a - y) ** 2)
    e1 = np.sum((c1 * b - y) ** 2)
    return (c0, 0.0) if e0 <= e1 else (0.0, c1)


def reconstruct(slices: Slices, options: Options | None = None) -> ReconstructionResult:
    """Reconstruct the microfacet BRDF from six slices (see the module docstring)."""
    opt = options or Options()
    t0 = time.perf_counter()
    n_leds = slices.n_leds
    valid = slices.valid & np.all(np.isfinite(slices.values), axis=-1)
    f_all = slices.values
    if valid.sum() < 100:
        raise ValueError("fewer than 100 valid samples in the capture")
    kd_pi = np.array([np.percentile(f_all[..., c][valid], 1.0) for c in range(3)])  # ρ_d/π ≤ min f

    # §5.4 altered normal
    frame = np.eye(3)
    sym_dist = float("nan")
    if opt.estimate_normal:
        y = (f_all @ LUM) - kd_pi @ LUM
        cos_dev = np.maximum(slices.light[:, 2], 1e-6)
        val = np.where(valid, np.maximum(y, 0.0) * cos_dev[:, None], np.nan)
        step = max(1, int(valid.shape[1] // 12000))
        dist = SymmetryDistance(slices.light, slices.view[::step], val[:, ::step])
        normal, sym_dist = estimate_normal(dist, opt.max_tilt_deg)
        frame = geometry.frame_from_normal(normal, np.array([1.0, 0.0, 0.0]))
    sl = slices.reframe(frame) if opt.estimate_normal else slices
    ok = sl.valid & valid
    li, pi = np.nonzero(ok)
    i = sl.light[li]
    o = sl.view[pi]
    f = sl.values[li, pi]
    led = li
    h = geometry.normalize(i + o)
    c = np.clip(np.sum(i * h, axis=1), 0.0, 1.0)
    w_merge = ndf_mod.merge_weights(o)

    work = hemicube(opt.work_resolution)
    eta = np.full(3, 1.5 if opt.fixed_eta is None else float(opt.fixed_eta))
    kd = kd_pi * math.pi
    ks = np.ones(3)
    s_i = np.ones(len(f))
    s_o = np.ones(len(f))
    excluded: set[int] = set()
    fit: FresnelFit | None = None
    d_work = None
    shake = False
    history = []
    for outer in range(opt.outer_iterations):
        f_s = f - kd / math.pi
        g = f_s * (i[:, 2] * o[:, 2] / np.maximum(s_i * s_o, 1e-12))[:, None]
        counts, cm, gm = texel_means(h, c, g, led, n_leds)
        fit = fit_eta(counts, cm, gm, excluded, eta0=float(np.median(eta)))
        # S ≡ 1 in the first pass (§5.1): grazing LEDs' S(i) differ by tens of percent,
        # so the first η is not used; it is refitted once S is known (outer > 0).
        if opt.detect_shake and outer == min(1, opt.outer_iterations - 1) and np.isfinite(fit.error) and fit.error > SHAKE_THRESHOLD:
            shake = True
            best = (fit.error, None)
            for k in range(n_leds):
                trial = fit_eta(counts, cm, gm, {k}, eta0=1.5)
                if np.isfinite(trial.error) and trial.error < best[0]:
                    best = (trial.error, k)
            if best[1] is not None:
                excluded.add(best[1])
                fit = fit_eta(counts, cm, gm, excluded, eta0=1.5)
        if opt.fixed_eta is None and outer > 0 and np.all(np.isfinite(fit.eta)) and fit.n_pairs > 0:
            eta = fit.eta
        use = ~np.isin(led, list(excluded)) if excluded else np.ones(len(f), bool)
        fres = fresnel(c[:, None], eta[None, :])  # (M, 3); η is fixed within the inner loop
        for inner in range(opt.inner_iterations):
            f_s = f - kd / math.pi
            d_ch = ndf_mod.partial_ndf(f_s, i[:, None, :], o[:, None, :], s_i[:, None], s_o[:, None], fres)  # eq. 7
            d_hat = np.maximum(d_ch / np.maximum(ks, 1e-12), 0.0) @ LUM
            wsum, wv = ndf_mod.splat_completed(work, h[use], d_hat[use], w_merge[use])
            d_work = np.maximum(ndf_mod.push_pull(work, wsum, wv), 0.0)
            norm = float(np.sum(d_work * work.cos_theta * work.solid_angles))
            d_work /= max(norm, 1e-300)
            table = sigma_table(work, d_work)
            s_i = table.eval(i)
            s_o = table.eval(o)
            # k_d, k_s per channel: f = k_d/π + k_s · D S S F / (4 cos cos)
            d_at = work.lookup(d_work, h)
            lobe = d_at * s_i * s_o / np.maximum(4.0 * i[:, 2] * o[:, 2], 1e-12)
            one = np.full(int(use.sum()), 1.0 / math.pi)
            for ch in range(3):
                kd[ch], ks[ch] = _nnls2(one, (lobe * fres[:, ch])[use], f[use, ch])
        history.append({"eta": eta.tolist(), "E": fit.error, "kd": kd.tolist(), "ks": ks.tolist()})
    assert d_work is not None
    out_cube = hemicube(opt.resolution)
    d_out = np.maximum(ndf_mod.resample(work, d_work, out_cube), 0.0)
    model = MicrofacetBRDF(d_out, kd, ks, eta)
    # residual of the final model on the used samples (relative, luminance)
    pred = model.eval(i[use], o[use]) @ LUM
    meas = f[use] @ LUM
    rel = np.abs(pred - meas) / np.maximum(np.abs(meas), 1e-6)
    tilt = float(np.degrees(math.acos(min(1.0, frame[2, 2]))))
    summary = {
        "eta": eta.tolist(),
        "kd": kd.tolist(),
        "ks": ks.tolist(),
        "normal": frame[2].tolist(),
        "normal_tilt_deg": tilt,
        "symmetry_distance": sym_dist,
        "fresnel_error": None if fit is None else fit.error,
        "fresnel_pairs": 0 if fit is None else fit.n_pairs,
        "shake_detected": shake,
        "excluded_leds": sorted(excluded),
        "iterations": history,
        "samples": int(use.sum()),
        "residual_median_rel": float(np.median(rel)),
        "albedo_max": float(model.albedo(np.array([0.0, 30.0, 60.0, 80.0])).max()),
        "seconds": time.perf_counter() - t0,
    }
    return ReconstructionResult(model, summary)
