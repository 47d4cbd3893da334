"""How low can the paper's model go on a material? Its error ceiling.

The dense Cook–Torrance baseline is fitted to the *whole* reference on the very metric
it is judged by (eq. 10). This script gives the paper's own model class the same
advantage, so that a sweep row can be read against what the class can reach at all:

``f = k_d/π + k_s D(θ_h) S(i) S(o) F(i·h; η) / (4 cos θ_i cos θ_o)``     (eqs. 1, 2, 4, 8)

with an isotropic NDF that is free on every MERL θ_h bin (90 values: the metric only
evaluates bin centres, so this is a free NDF as far as eq. 10 can tell), S derived from
that NDF by eq. 8 (the project's σ table), a real η, k_d and k_s per channel, one NDF
for R, G and B — the reconstruction's choices. The fit is weighted least squares on
eq. 10's residuals ``√w cos θ_i (M − R)`` on the stride-4 grid (as the CT fit):

* for fixed S, η: D per θ_h bin and (k_d, k_s) per channel in closed form, alternated;
* η per channel by bounded least squares over that (variable projection), from the
  best of a coarse common-η scan;
* S re-derived from the fitted NDF, a few outer rounds.

The reported error is eq. 10 on the full grid of the model as a reflecto model file
would hold it (512 hemicube, D interpolated log-linearly in θ_h between bin centres).
``--shadowing correlated`` uses the height-correlated form of S. Nothing of the device enters: this bounds
the reconstruction from below on each material, it does not measure it.

    .venv/bin/python studies/model_ceiling.py ../shared/data/rgl ../shared/data/merl-nbrdf \
        --table docs/sweep-ideal.csv -o out/ceiling.csv --jobs 2
"""

from __future__ import annotations

import argparse
import csv
import math
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares
from tqdm import tqdm

from reflecto.evaluate.cooktorrance import _nnls2
from reflecto.evaluate.metrics import brdf_error, evaluate_on_grid, metric_grid
from reflecto.evaluate.sweep import find_materials
from reflecto.fresnel import fresnel
from reflecto.load import load_source
from reflecto.model import MicrofacetBRDF
from reflecto.sources import merl

ETA_MIN, ETA_MAX = 1.01, 60.0
ETA_SCAN = (1.1, 1.3, 1.5, 2.0, 3.0, 5.0, 10.0, 25.0)
ETA_ORACLE = tuple(np.round(1.0 + np.geomspace(0.03, 30.0, 12), 4))


class Problem:
    """Eq. 10's weighted residuals on the stride grid, split by θ_h bin."""

    def __init__(self, source, stride: int = 4, max_theta_d_deg: float = 90.0,
                 coverage: np.ndarray | None = None) -> None:
        g = metric_grid(stride)
        r = evaluate_on_grid(source, g)
        ok = np.all(r >= 0, axis=1) & np.all(np.isfinite(r), axis=1)
        k_theta_d = (g.flat // merl.N_PHI_D) % merl.N_THETA_D
        k_theta_h = g.flat // (merl.N_THETA_D * merl.N_PHI_D)
        ok &= k_theta_d + 0.5 <= max_theta_d_deg  # bin centres are 1° wide
        if coverage is not None:
            ok &= coverage[k_theta_h, k_theta_d]
        self.i, self.o, self.r = g.i[ok], g.o[ok], r[ok]
        self.kh = (g.flat[ok] // (merl.N_THETA_D * merl.N_PHI_D)).astype(np.intp)
        self.sw = np.sqrt(g.w[ok]) * self.i[:, 2]  # residual = sw · (M − R)
        h = self.i + self.o
        h /= np.linalg.norm(h, axis=1, keepdims=True)
        self.c = np.clip(np.sum(self.i * h, axis=1), 0.0, 1.0)
        self.w2 = self.sw**2
        self.present = np.bincount(self.kh, minlength=merl.N_THETA_H) > 0

    def lobe_geometry(self, model: MicrofacetBRDF | None, shadowing: str) -> np.ndarray:
        """``S(i)S(o)/(4 cos cos)`` per sample (without D, k_s, F); S ≡ 1 before an NDF exists."""
        ci, co = self.i[:, 2], self.o[:, 2]
        if model is None:
            return 1.0 / (4.0 * ci * co)
        t = model.sigma_table
        si = np.maximum(t.eval_sigma(self.i), ci)
        so = np.maximum(t.eval_sigma(self.o), co)
        if shadowing == "correlated":
            return 1.0 / (4.0 * (si * co + so * ci - ci * co))
        return 1.0 / (4.0 * si * so)

    def solve_linear(self, q: np.ndarray, d: np.ndarray, kd: np.ndarray, ks: np.ndarray, rounds: int = 8):
        """Alternate D per θ_h bin and (k_d, k_s) per channel; q = geometry · F, shape (K, 3)."""
        n = merl.N_THETA_H
        for _ in range(rounds):
            # D[kh] = Σ w² ks q (r − kd/π) / Σ w² ks² q²
            a = ks[None, :] * q
            num = np.bincount(self.kh, (self.w2[:, None] * a * (self.r - kd / math.pi)).sum(axis=1), minlength=n)
            den = np.bincount(self.kh, (self.w2[:, None] * a * a).sum(axis=1), minlength=n)
            d = np.where(den > 0, np.maximum(num / np.where(den > 0, den, 1.0), 0.0), d)
            b = d[self.kh][:, None] * q * self.sw[:, None]
            col = self.sw / math.pi
            aa = float(col @ col)
            for ch in range(3):
                y = self.r[:, ch] * self.sw
                kd[ch], ks[ch] = _nnls2(aa, float(col @ b[:, ch]), float(b[:, ch] @ b[:, ch]), float(col @ y),
                                        float(b[:, ch] @ y))
            ks = np.maximum(ks, 1e-12)
        return d, kd, ks

    def residual(self, d: np.ndarray, kd: np.ndarray, ks: np.ndarray, q: np.ndarray) -> np.ndarray:
        m = kd / math.pi + ks * d[self.kh][:, None] * q
        return ((m - self.r) * self.sw[:, None]).ravel()


def ndf_function(d: np.ndarray, present: np.ndarray):
    """D(h) from its θ_h bin-centre values, log-linear in θ_h; empty bins take the neighbours'."""
    th = merl.bin_centres()[0]
    keep = present & (d > 0)
    floor = max(float(d[keep].max()) * 1e-12, 1e-300) if keep.any() else 1.0
    xs, ys = th[keep], np.log(np.maximum(d[keep], floor))

    def fn(h: np.ndarray) -> np.ndarray:
        t = np.arccos(np.clip(h[..., 2], -1.0, 1.0))
        return np.exp(np.interp(t, xs, ys))

    return fn


def normalize(d: np.ndarray, present: np.ndarray) -> float:
    """∫ D cos θ_h dω of the interpolated NDF (to move its scale into k_s)."""
    t = np.linspace(0.0, math.pi / 2, 20001)
    h = np.stack([np.sin(t), np.zeros_like(t), np.cos(t)], axis=1)
    f = ndf_function(d, present)(h) * np.cos(t) * np.sin(t)
    return float(2 * math.pi * np.sum((f[1:] + f[:-1]) / 2 * np.diff(t)))


def device_coverage(source, device: str, seed: int) -> np.ndarray:
    """(θ_h bin, θ_d bin) pairs of MERL's grid that a capture by ``device`` samples, shape (90, 90).

    Generous on purpose: any φ_d counts, so the fit sees far more of the reference
    than the six slices hold; it is an upper bound on what they can tell.
    """
    from reflecto import geometry, workflow
    from reflecto.instrument.device import load_device
    from reflecto.instrument.simulate import simulate_capture

    dev = load_device(device)
    sl = workflow.measure(simulate_capture(source, dev, seed=seed), workflow.calibration_for(dev, missing="nominal"))
    mask = np.zeros((merl.N_THETA_H, merl.N_THETA_D), bool)
    for led in range(len(sl.light)):
        o = sl.view[sl.valid[led]]
        i = np.broadcast_to(sl.light[led], o.shape)
        th, _, td, _ = geometry.io_to_hd(i, o)
        kh = np.clip(np.floor(merl.N_THETA_H * np.sqrt(np.maximum(th, 0) / (math.pi / 2))), 0, 89).astype(int)
        kd = np.clip(np.floor(td / (math.pi / 2) * merl.N_THETA_D), 0, 89).astype(int)
        mask[kh, kd] = True
    return mask


def fit_class(p: Problem, shadowing: str = "separable", eta_fixed: float | None = None,
              outer: int = 5) -> MicrofacetBRDF:
    """The model class fitted to ``p``'s bins (module docstring); η fixed if ``eta_fixed``."""
    d, kd, ks = np.ones(merl.N_THETA_H), np.zeros(3), np.ones(3)
    model = None
    eta = np.full(3, 1.5 if eta_fixed is None else eta_fixed)
    for it in range(outer):
        geom = p.lobe_geometry(model, shadowing)

        def inner(e: np.ndarray, state=(d, kd, ks), geom=geom) -> tuple:
            q = geom[:, None] * fresnel(p.c[:, None], e)
            dd, kk, ss = p.solve_linear(q, state[0].copy(), state[1].copy(), state[2].copy())
            return dd, kk, ss, q

        if eta_fixed is None:
            if it == 0:  # coarse common-η scan, then per-channel refinement
                costs = []
                for e in ETA_SCAN:
                    dd, kk, ss, q = inner(np.full(3, e))
                    costs.append(float(np.sum(p.residual(dd, kk, ss, q) ** 2)))
                eta = np.full(3, ETA_SCAN[int(np.argmin(costs))])
            x0 = np.log(np.clip(eta, ETA_MIN, ETA_MAX) - 1.0)
            sol = least_squares(lambda x: p.residual(*inner(1.0 + np.exp(x))), x0,
                                bounds=(math.log(ETA_MIN - 1), math.log(ETA_MAX - 1)), diff_step=1e-3,
                                ftol=1e-6, xtol=1e-4, max_nfev=20)
            eta = 1.0 + np.exp(sol.x)
        d, kd, ks, _ = inner(eta)
        scale = normalize(d, p.present)
        # S from the fitted NDF (eq. 8) for the next round
        model = MicrofacetBRDF.from_ndf_function(ndf_function(d / scale, p.present), resolution=128)
    scale = normalize(d, p.present)
    return MicrofacetBRDF.from_ndf_function(ndf_function(d / scale, p.present), resolution=512, kd=kd,
                                            ks=ks * scale, eta=eta, correlated=(shadowing == "correlated"))


def fit(path: str, shadowing: str = "separable", max_theta_d_deg: float = 90.0, coverage: str | None = None,
        eta_oracle: bool = False) -> dict:
    """One material's row: the class fitted to the chosen bins, its error on the whole grid."""
    t0 = time.perf_counter()
    src = load_source(path)
    cov = None
    if coverage:
        from reflecto.evaluate.sweep import material_seed

        cov = device_coverage(src, coverage, material_seed(Path(path).stem))
    p = Problem(src, max_theta_d_deg=max_theta_d_deg, coverage=cov)
    if eta_oracle:
        # η chosen with the whole reference in view (the bins fitted cannot choose it):
        # the best the fitted bins allow under any common η
        best = None
        ref2 = evaluate_on_grid(src, metric_grid(2))
        for e in ETA_ORACLE:
            m = fit_class(p, shadowing, eta_fixed=e, outer=3)
            err = brdf_error(src, m, stride=2, reference_values=ref2).normalized
            if best is None or err < best[0]:
                best = (err, m)
        model = best[1]
    else:
        model = fit_class(p, shadowing)
    err = brdf_error(src, model).normalized
    eta = model.eta
    return {"name": Path(path).stem, "ceiling": err, "eta_r": eta[0], "eta_g": eta[1], "eta_b": eta[2],
            "kd": float(np.mean(model.kd)), "ks": float(np.mean(model.ks)), "seconds": time.perf_counter() - t0}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("folders", nargs="+")
    ap.add_argument("--table", help="a sweep's CSV (docs/sweep-ideal.csv) to compare against")
    ap.add_argument("--shadowing", choices=("separable", "correlated"), default="separable")
    ap.add_argument("--max-theta-d", type=float, default=90.0,
                    help="fit only bins with θ_d ≤ this (degrees); the error is still on the whole grid")
    ap.add_argument("--coverage", metavar="DEVICE",
                    help="fit only the (θ_h, θ_d) bins this device's capture samples (any φ_d): a built-in "
                         "(ideal, earlier, wide) or a device file")
    ap.add_argument("--eta-oracle", action="store_true",
                    help="pick the common η (12 values, 1.03–31) by the error on the whole grid")
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--only", nargs="*", help="material names to run (default: all)")
    ap.add_argument("-o", "--output", required=True)
    a = ap.parse_args(argv)
    paths = [str(p) for p in find_materials(a.folders) if not a.only or p.stem in a.only]
    rows = []
    with ProcessPoolExecutor(a.jobs) as ex:
        futures = [ex.submit(fit, p, a.shadowing, a.max_theta_d, a.coverage, a.eta_oracle) for p in paths]
        for fut in tqdm(as_completed(futures), total=len(futures), desc="materials", unit="mat"):
            rows.append(fut.result())
    sweep = {}
    if a.table:
        with open(a.table) as f:
            sweep = {r["name"]: r for r in csv.DictReader(f)}
    for r in rows:
        s = sweep.get(r["name"])
        if s:
            r["ours"], r["cook_torrance"] = float(s["ours"]), float(s["cook_torrance"])
            r["ceiling_over_ct"] = r["ceiling"] / r["cook_torrance"]
    out = Path(a.output)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(out.suffix + ".tmp")
    keys = list(dict.fromkeys(k for r in rows for k in r))
    with open(tmp, "w", newline="") as f:
        wr = csv.DictWriter(f, keys)
        wr.writeheader()
        for r in sorted(rows, key=lambda r: r["name"]):
            wr.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})
    os.replace(tmp, out)
    for r in sorted(rows, key=lambda r: r.get("ceiling_over_ct", 0)):
        print(f"{r['name']:32s} ceiling {r['ceiling']:.4f}  CT {r.get('cook_torrance', float('nan')):.4f}  "
              f"ours {r.get('ours', float('nan')):.4f}  ceiling/CT {r.get('ceiling_over_ct', float('nan')):.3f}  "
              f"η {r['eta_r']:.2f},{r['eta_g']:.2f},{r['eta_b']:.2f}  {r['seconds']:.1f} s")
    with_ct = [r for r in rows if "ceiling_over_ct" in r]
    if with_ct:
        ratio = np.array([r["ceiling_over_ct"] for r in with_ct])
        print(f"ceiling < CT on {np.mean(ratio < 1):.0%} of {len(ratio)}; median ceiling/CT {np.median(ratio):.3f}")
    print(f"median ceiling {np.median([r['ceiling'] for r in rows]):.4f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
