"""Figures of the instrument: the analogue of the paper's Fig. 2(c)(d)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from .. import geometry
from ..hemicube import hemicube
from ..plotting import pyplot, save_figure
from .layout import coverage_masks, led_angles
from .optics import Optics


def plot_coverage(optics: Optics, leds: ArrayLike, path: str | Path, resolution: int = 128,
                  theta_max_deg: float = 80.0, occluder_deg: float = 0.0) -> Path:
    """Half-vector coverage per LED (left) and after completion by eq. 3 (right).

    Half vectors are drawn in the orthographic projection ``(h_x, h_y)`` of the NDF
    hemisphere (the view down the normal); rings every 20° of θ_h.

    Parameters
    ----------
    optics
        The condenser optics.
    leds : array_like, shape (L, 3)
        LED directions in the device frame.
    path
        The image file to write.
    resolution
        Hemicube resolution of the masks.
    theta_max_deg
        θ_max of the coverage cap, degrees.
    occluder_deg
        Half angle of the device's central occluder about the view axis (degrees; 0: none),
        whose views see nothing (:func:`~reflecto.instrument.layout.coverage_masks`).

    Returns
    -------
    Path
        ``path``.
    """
    plt = pyplot()
    cube = hemicube(resolution)
    leds = geometry.normalize(np.atleast_2d(leds))
    masks = coverage_masks(optics, leds, cube, occluder_deg)
    tau = cube.permutation(geometry.TAU)
    h = cube.directions
    cap = h[:, 2] >= math.cos(math.radians(theta_max_deg))
    colors = plt.get_cmap("tab10")(np.arange(len(leds)))
    fig, axes = plt.subplots(1, 2, figsize=(9.5, 4.8))
    size = 1.2 * (128 / resolution) ** 2
    for ax, completed in zip(axes, (False, True)):
        union = masks.any(axis=0)
        assert isinstance(union, np.ndarray)  # masks is (leds, texels): any over axis 0 is an array
        if completed:
            extra = union[tau] & ~union & cap
            ax.scatter(h[extra, 0], h[extra, 1], s=size, c="0.6", marker="s", linewidths=0, label="by symmetry (eq. 3)")
            miss = cap & ~(union | union[tau])
        else:
            miss = cap & ~union
        for k in range(len(leds)):
            m = masks[k] & cap
            ax.scatter(h[m, 0], h[m, 1], s=size, color=colors[k], marker="s", linewidths=0, alpha=0.55,
                       label=f"l{k}" if not completed else None)
        ax.scatter(h[miss, 0], h[miss, 1], s=size, c="black", marker="s", linewidths=0, alpha=0.15)
        for t in (20, 40, 60, 80):
            a = np.linspace(0, 2 * np.pi, 200)
            ax.plot(np.sin(np.radians(t)) * np.cos(a), np.sin(np.radians(t)) * np.sin(a), lw=0.5, c="0.3")
        # LEDs and the view cone's axis, as seen from above
        for k, (el, az) in enumerate(led_angles(leds)):
            r = math.cos(math.radians(el))
            ax.plot(r * math.cos(math.radians(az)), r * math.sin(math.radians(az)), "*", ms=9, color=colors[k],
                    mec="black", mew=0.5)
        a = optics.axis
        ax.plot(a[0], a[1], "k+", ms=10)
        ax.set_aspect("equal")
        ax.set_xlim(-1.05, 1.05)
        ax.set_ylim(-1.05, 1.05)
        ax.set_xlabel("h_x (tangent)")
        ax.set_ylabel("h_y (bitangent)")
        ax.set_title("(d) completed by symmetry" if completed else "(c) partial NDF per LED")
        ax.legend(loc="lower left", fontsize=7, markerscale=4, ncol=2, frameon=False)
    fig.suptitle(f"Half-vector coverage, θ_h ≤ {theta_max_deg:g}° "
                 "(★ LED directions, + optical axis; grey dots: uncovered)",
                 fontsize=10)
    fig.tight_layout()
    return save_figure(fig, path, dpi=90)
