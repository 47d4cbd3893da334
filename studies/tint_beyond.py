"""How the Fresnel tint continues beyond its last node (``fresnel.FresnelTint``, ``isotropic.TINT_BEYOND``).

Beyond the last node (θ_d ≈ 67° on the paper's layout) the device never sees the mirror
direction; the model's specular level there is an extrapolation. This study scores
candidate continuations on the 50 shared ideal reconstructions (studies/_shared_models.py)
by eq. 10 against their references, each model evaluated with its fitted parameters and
only the continuation changed (a model whose tint the energy limit held keeps it held):

- ``constant``: ``τ_K`` (η's Fresnel curve keeps its shape);
- ``trend``: the nodes' departure from η's curve continued log-linearly in ``cos θ_d``
  from where the fitted bins end, no further than the nodes' span (the reconstruction's
  choice);
- ``trend-theta``: the same, log-linear in ``θ_d``;
- ``trend+smooth``: ``trend`` with, on sharp lobes (the last node's half width at most
  ``SHARP_LOBE_PITCHES`` half-vector pitches), the last node's NDF widened as the
  smooth-surface (Harvey–Shack) scattering's direction-cosine scaling says and kept
  normalized: ``D(θ_h; θ_d) = s² D_K(arcsin(s sin θ_h))``, ``s = cos θ_d / cos θ_K``.

Prints, per half, how many models beat the dense and the same-data Cook–Torrance fits
(the columns of the sweep's table given by ``--table``) and the geometric mean of the
error over ``constant``'s. ``.venv/bin/python studies/tint_beyond.py --jobs 2`` (≈ 4 min).
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
from multiprocessing import Pool
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _shared_models import ROOT, material_files, shared_models  # noqa: E402

FORMS = ("constant", "trend", "trend-theta", "trend+smooth")


class _SmoothSurfaceLobe:
    """A model whose last node's lobe widens beyond that node by the direction-cosine scaling."""

    def __init__(self, model) -> None:
        self.model, self.name, self.isotropic = model, model.name, True

    def eval(self, i, o):
        from reflecto.model import _lobe_term

        m = self.model
        f = m.eval(i, o)
        i, o = np.broadcast_arrays(np.asarray(i, np.float64), np.asarray(o, np.float64))
        hs = i + o
        norm = np.maximum(np.linalg.norm(hs, axis=-1), 1e-300)
        c = np.abs(np.einsum("...k,...k->...", i, hs)) / norm
        theta_h = np.arccos(np.clip(hs[..., 2] / norm, -1.0, 1.0))
        last = m.lobes.theta_d[-1]
        keep = (i[..., 2] > 0) & (o[..., 2] > 0) & (hs[..., 2] > 0) & (c < math.cos(last))
        s = c / math.cos(last)
        ndf = m.lobes.ndfs[-1]
        wide = s ** 2 * _lobe_term(ndf, np.arcsin(np.clip(s * np.sin(theta_h), 0.0, 1.0)), i[..., 2], o[..., 2],
                                   m.correlated, keep)
        held = _lobe_term(ndf, theta_h, i[..., 2], o[..., 2], m.correlated, keep)
        return f + (m.fresnel(c) * m.ks) * (wide - held)[..., None]


def _half_width_deg(ndf) -> float:
    theta = np.radians(np.linspace(0.0, 90.0, 90001))
    v = ndf.at_theta(theta)
    below = np.flatnonzero(v < 0.5 * v[0])
    return math.degrees(theta[below[0]]) if len(below) else 90.0


def _variant(model, form: str):
    """``model`` with the tint continued by ``form`` (the lobe too for ``trend+smooth``)."""
    from reflecto.fresnel import FresnelTint
    from reflecto.model import IsotropicMicrofacetBRDF
    from reflecto.reconstruct.pipeline import SHARP_LOBE_PITCHES

    class ThetaTrend(FresnelTint):
        def _trend(self, c):
            first, last = self.values[0], self.values[-1]
            ok = (first > 0) & (last > 0)
            log_r = np.log(np.divide(last, first, out=np.ones(3), where=ok))
            start = self.theta[-1] if self.trend_from is None else self.trend_from
            u = np.minimum(np.maximum(np.arccos(c) - start, 0.0) / (self.theta[-1] - self.theta[0]), 1.0)
            return np.exp(u[..., None] * log_r)

    if model.tint is None or model.tint.beyond != "trend":  # no tint, or held by the energy limit
        return model
    t = model.tint
    start = t.trend_from if t.beyond == "trend" else None
    tint = (FresnelTint(t.theta, t.values) if form == "constant" else
            (ThetaTrend if form == "trend-theta" else FresnelTint)(t.theta, t.values, "trend", start))
    out = IsotropicMicrofacetBRDF(model.ndf_table, model.kd, model.ks, model.eta, correlated=model.correlated,
                                  tint=tint, lobes=model.lobes)
    pitch = 0.21  # degrees: the camera's half-vector pitch (docs/design/normal.md)
    if form == "trend+smooth" and model.lobes is not None \
            and _half_width_deg(model.lobes.ndfs[-1]) <= SHARP_LOBE_PITCHES * pitch:
        return _SmoothSurfaceLobe(out)
    return out


def score(name: str) -> dict[str, float]:
    """Eq. 10 (normalized) of each continuation for one material."""
    from reflecto.evaluate.metrics import brdf_error, evaluate_on_grid, max_albedo, metric_grid
    from reflecto.load import load_source
    from reflecto.model import load_model

    path, model_path = next(shared_models([name], quiet=True))
    src = load_source(path)
    ref, alb = evaluate_on_grid(src, metric_grid(1)), max_albedo(src)
    model = load_model(model_path)
    return {form: brdf_error(src, _variant(model, form), albedo_ref=alb, reference_values=ref).normalized
            for form in FORMS}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--table", default=str(ROOT / "docs" / "sweep-ideal.csv"),
                    help="the ideal sweep's results.csv (its half, cook_torrance, same_data_ct columns)")
    ap.add_argument("--jobs", type=int, default=1)
    args = ap.parse_args()
    rows = {r["name"]: r for r in csv.DictReader(open(args.table))}
    names = [p.stem for p in material_files()]
    list(shared_models(quiet=False))  # reconstruct once, in this process, what is not cached
    with Pool(max(1, args.jobs)) as pool:
        errors = dict(zip(names, pool.map(score, names, chunksize=1)))
    for form in FORMS:
        for half in ("tuning", "validation", "all"):
            sel = [n for n in names if half == "all" or rows[n]["half"] == half]
            e = np.array([errors[n][form] for n in sel])
            base = np.array([errors[n]["constant"] for n in sel])
            ct = np.array([float(rows[n]["cook_torrance"]) for n in sel])
            sd = np.array([float(rows[n]["same_data_ct"]) for n in sel])
            print(f"{form:13s} {half:10s} < CT {int(np.sum(e < ct)):2d}/{len(sel)}  < same-data CT "
                  f"{int(np.sum(e < sd)):2d}  geometric mean over constant {math.exp(np.mean(np.log(e / base))):.3f}"
                  f"  worse by > 10 % {int(np.sum(e > 1.1 * base)):2d}  better by > 10 % "
                  f"{int(np.sum(e < base / 1.1)):2d}")
    for n in names:
        print(f"  {n:26s} " + "  ".join(f"{form} {errors[n][form]:.4g}" for form in FORMS))


if __name__ == "__main__":
    main()
