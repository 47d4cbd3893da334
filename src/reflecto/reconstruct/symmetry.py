"""Mirror symmetry of single slices: a shake cue independent of E(η) (§5.1, §5.4).

For an isotropic BRDF, reflecting the view across any plane that contains the normal
``n`` and the light ``i`` leaves ``f(i, o)`` unchanged. One LED's slice is therefore
mirror-symmetric about the plane through its direction and the normal. When the sample
turns between two LEDs (a shake), the later slices are symmetric about planes through
the *turned* normal: their planes miss the frame's normal by an angle of the order of
the shake. HLHZ08's symmetry distance, which §5.4 minimises over normals, here
minimised over the one angle ``ψ`` that turns an LED's plane about its direction.

Only LEDs well above the sample plane are used (:data:`MIN_ELEVATION_DEG`): on the
shared materials, the grazing slices of metals and coated paints put their plane
1.5–10° off the normal even without a shake (clean brass, aluminium, metallic
paints); and the slices of rough materials are too flat to place a plane at all
(:data:`MIN_CURVATURE`). So a shake that moves only grazing LEDs goes unseen here.

A tilted capture reconstructed without the §5.4 normal estimate shows the same way
(every steep plane misses the assumed normal) and is flagged too; with the estimate,
the planes are measured against the estimated normal.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from .. import _kernels
from ..colour import LUM
from ..hemicube import hemicube
from ..instrument.device import STEEP_ELEVATION_DEG
from .tuning import SYMMETRY

Array = NDArray[np.float64]

#: LEDs at least this far above the sample plane (degrees) enter the test: the device's
#: *steep* LEDs, whichever their index (the firing order fires them last,
#: :func:`reflecto.instrument.device.steep_last_order`).
MIN_ELEVATION_DEG = STEEP_ELEVATION_DEG
# Tuned numbers: what, units and provenance are in :mod:`.tuning` (symmetry stage).
SEARCH_DEG = SYMMETRY.search_deg
STEP_DEG = SYMMETRY.step_deg
MIN_CURVATURE = SYMMETRY.min_curvature
PLANE_THRESHOLD_DEG = SYMMETRY.plane_threshold_deg
CUBE_N = SYMMETRY.cube_n


def plane_offset(light: Array, view: Array, values: Array, weights: Array | None = None) -> tuple[float, float] | None:
    """Angle (degrees) between an LED's symmetry plane and the plane through ``n = z``.

    Parameters
    ----------
    light
        LED direction in the sample frame, shape ``(3,)``.
    view
        View directions of the pixels, shape ``(P, 3)``.
    values
        Luminance of the slice at those pixels (sr⁻¹), shape ``(P,)``.
    weights
        1 for valid pixels, 0 for the others (default: all valid), shape ``(P,)``.

    Returns ``(ψ, curvature)``, or ``None`` when the minimum lies on the search bound
    or too few mirrored texels land on data.
    """
    cube = hemicube(CUBE_N)
    wsum, wv = cube.splat(view, values[:, None], weights)
    has = (wsum > 0).astype(np.float64)
    v = np.where(wsum > 0, wv[:, 0] / np.where(wsum > 0, wsum, 1.0), 0.0)
    pad_v, pad_has = cube.pad(v), cube.pad(has)
    t = cube.directions[wsum > 0]
    vt = v[wsum > 0]
    z = np.array([0.0, 0.0, 1.0])
    e1 = z - (z @ light) * light
    norm = np.linalg.norm(e1)
    if norm < 1e-9:
        return None
    e1 /= norm
    e2 = np.cross(light, e1)  # the normal of the plane through the LED and z
    psis = np.radians(np.arange(-SEARCH_DEG, SEARCH_DEG + 0.5 * STEP_DEG, STEP_DEG))
    dist = np.empty(len(psis))
    _kernels.mirror_distances(np.ascontiguousarray(t), np.ascontiguousarray(vt), e1, e2, psis, pad_v, pad_has,
                              cube._pad_offsets, cube.n, dist)
    if not np.all(np.isfinite(dist)):
        return None
    j = int(np.argmin(dist))
    if j == 0 or j == len(dist) - 1:
        return None
    step = math.radians(STEP_DEG)
    curv2 = dist[j - 1] - 2.0 * dist[j] + dist[j + 1]
    off = 0.5 * (dist[j - 1] - dist[j + 1]) / curv2 if curv2 > 0 else 0.0
    return math.degrees(psis[j] + off * step), float(curv2 / step**2)


def plane_offsets(light: Array, view: Array, values: Array, valid: NDArray[np.bool_]) -> list[float | None]:
    """:func:`plane_offset` of every LED that is steep enough and locates its plane.

    ``light`` (L, 3) and ``view`` (P, 3) in the sample frame, ``values`` (L, P, 3),
    ``valid`` (L, P). ``None`` for LEDs that do not enter or do not locate a plane.
    """
    out: list[float | None] = []
    min_z = math.sin(math.radians(MIN_ELEVATION_DEG))
    for k in range(light.shape[0]):
        ok = valid[k]
        if light[k, 2] < min_z or np.count_nonzero(ok) < 1000:
            out.append(None)
            continue
        r = plane_offset(light[k], view, values[k] @ LUM, ok.astype(np.float64))
        out.append(None if r is None or r[1] < MIN_CURVATURE else r[0])
    return out
