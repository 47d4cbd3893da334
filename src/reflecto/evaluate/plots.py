"""Figures of the validation: analogues of the paper's Fig. 5 (errors) and Fig. 4 (spheres)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..plotting import plain_log_axis, save_figure
from ..plotting import pyplot as _plt
from ..render.mitsuba import exposure_for, to_srgb8
from ..render.sphere import composite, sphere_coverage


def plot_errors(records: list[dict[str, Any]], path: str | Path) -> Path:
    """Fig. 5 analogue: log normalized error per material, sorted by the Cook–Torrance error.

    Parameters
    ----------
    records
        Sweep records (:func:`~reflecto.evaluate.sweep.run_material`): the normalized eq. 10
        ``error`` of ``cook_torrance``, ``earlier`` and ``ours`` (plotted at ≥ 10⁻⁶).
    path
        The PNG file to write (atomically).

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    plt = _plt()
    recs = sorted(records, key=lambda r: r["cook_torrance"]["error"])
    x = np.arange(len(recs))
    fig, ax = plt.subplots(figsize=(max(7.0, 0.2 * len(recs) + 3), 4.2))
    for key, label, style in (("cook_torrance", "Cook–Torrance (dense fit)", "s-"),
                              ("earlier", "earlier device [DWT*10]", "^-"),
                              ("ours", "ours (this device + §5)", "o-")):
        ax.semilogy(x, [max(r[key]["error"], 1e-6) for r in recs], style, ms=4, lw=1, label=label)
    plain_log_axis(ax)
    ax.set_xticks(x)
    ax.set_xticklabels([r["name"] for r in recs], rotation=90, fontsize=6)
    ax.set_ylabel("normalized error (eq. 10), log scale")
    dev = recs[0]["device"] if recs else ""
    ax.set_title(f"Error per material, sorted by Cook–Torrance error ({len(recs)} materials, device {dev})",
                 fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return save_figure(fig, path, dpi=80)


def plot_spheres(records: list[dict[str, Any]], path: str | Path, n: int = 4) -> Path:
    """Fig. 4 analogue: spheres under point lights — reference, ours, earlier device, CT.

    Shows the ``n`` materials where ours gains most over the earlier device (the
    paper's choice of illustrating the difference), with each error in the title.
    The renders are :func:`reflecto.render.sphere.render_sphere`'s (key and fill
    light), shown at one exposure per row (the reference's) on the grey background.

    Parameters
    ----------
    records
        Sweep records with their ``renders`` (linear RGB, square).
    path
        The PNG file to write (atomically).
    n
        Number of materials (rows): the lowest ratios ours / earlier error.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    plt = _plt()
    recs = sorted(records, key=lambda r: r["ours"]["error"] / max(r["earlier"]["error"], 1e-300))[:n]
    cols = (("reference", "reference", None), ("ours", "ours", "ours"), ("earlier", "earlier device", "earlier"),
            ("cook_torrance", "Cook–Torrance", "cook_torrance"))
    fig, axes = plt.subplots(len(recs), len(cols), figsize=(2.2 * len(cols), 2.3 * len(recs)), squeeze=False)
    for row, r in zip(axes, recs):
        ref = np.asarray(r["renders"]["reference"])
        exp = exposure_for(ref)
        alpha = sphere_coverage(ref.shape[0])
        for ax, (key, label, err_key) in zip(row, cols):
            ax.imshow(to_srgb8(composite(np.asarray(r["renders"][key]), alpha, exp)))
            ax.set_xticks([])
            ax.set_yticks([])
            title = label if err_key is None else f"{label}\nerror {r[err_key]['error']:.4f}"
            ax.set_title(title, fontsize=7)
        row[0].set_ylabel(r["name"], fontsize=8)
    fig.suptitle("Spheres under a key and a fill point light (direct evaluation of each BRDF)", fontsize=9)
    fig.tight_layout()
    return save_figure(fig, path, dpi=80)
