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

import dataclasses
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
MIN_PLANES = SYMMETRY.min_planes
HUBER_K = SYMMETRY.huber_k
MIN_LOBE_TEXELS = SYMMETRY.min_lobe_texels
PLANE_FLOOR_DEG = SYMMETRY.plane_floor_deg
MIN_PIXELS = SYMMETRY.min_pixels


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
        if light[k, 2] < min_z or np.count_nonzero(ok) < MIN_PIXELS:
            out.append(None)
            continue
        r = plane_offset(light[k], view, values[k] @ LUM, ok.astype(np.float64))
        out.append(None if r is None or r[1] < MIN_CURVATURE else r[0])
    return out


@dataclasses.dataclass(frozen=True)
class PlaneNormal:
    """The normal that the slices' symmetry planes share (:func:`plane_normal`).

    ``offset`` ``(2,)`` are its tangent coordinates ``(δ_t, δ_b)`` in the frame it was
    measured in (the normal ``∝ n + δ_t t + δ_b b``), ``covariance`` ``(2, 2)`` their
    covariance (rad²), ``planes`` the LEDs that located a plane and ``inliers`` those
    that kept their full weight."""

    offset: Array
    covariance: Array
    planes: int
    inliers: int


def resolves_lobe(half_width_deg: float) -> bool:
    """Whether the view hemicube's texels (``90°/CUBE_N`` each) resolve a lobe of this
    half width at half maximum (degrees) well enough to place its symmetry planes:
    at least :data:`MIN_LOBE_TEXELS` texels."""
    return half_width_deg >= MIN_LOBE_TEXELS * 90.0 / CUBE_N


def plane_normal(light: Array, view: Array, values: Array, valid: NDArray[np.bool_]) -> PlaneNormal | None:
    """The normal through which every LED's symmetry plane passes, from the planes alone.

    For an isotropic BRDF LED ``l``'s slice is mirror-symmetric about the plane through
    ``l`` and the true normal ``n*`` (module docstring), whatever the BRDF's shape: a cue
    to the normal that needs no model. Measured about the current normal ``z`` of the
    frame (:func:`plane_offset`), the plane through ``l`` turned by ``ψ`` has the normal
    ``m = cos ψ e₂ + sin ψ e₁`` and holds ``n*``: ``m · (δ_t, δ_b, 1) = 0``, one linear
    equation per LED in the two tangent coordinates of ``n*``. They are solved by least
    squares weighted by each plane's precision, the symmetry distance's curvature ``c``
    over ``sin² ∠(l, z)`` (a turn ``ψ`` of the plane moves it by ``ψ sin ∠(l, z)`` at the
    normal), with Huber's weights (:data:`HUBER_K`) iterated against planes that a cut
    or a rim biases; each plane's variance is then its share of the planes' own scatter
    (so a cue whose planes disagree says so) plus :data:`PLANE_FLOOR_DEG`², the bias a
    plane located on the texel grid carries, and the system is solved again with those
    (:func:`solve_planes`).

    ``light`` (L, 3) and ``view`` (P, 3) in the frame of the current normal, ``values``
    (L, P, 3) in sr⁻¹, ``valid`` (L, P). Every LED enters (grazing ones too: their planes
    constrain the normal most). ``None`` when fewer than :data:`MIN_PLANES` planes are
    located or keep their weight, or when those that do fix only one of the two angles.
    """
    rows, prec = [], []
    z = np.array([0.0, 0.0, 1.0])
    y = values @ LUM
    for k in range(light.shape[0]):
        ok = valid[k]
        if np.count_nonzero(ok) < MIN_PIXELS:
            continue
        l = light[k]
        r = plane_offset(l, view, y[k], ok.astype(np.float64))
        sin2 = 1.0 - float(l[2]) ** 2
        if r is None or r[1] <= 0.0 or sin2 < 1e-6:
            continue
        e1 = z - l[2] * l
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(l, e1)
        psi = math.radians(r[0])
        rows.append(math.cos(psi) * e2 + math.sin(psi) * e1)
        prec.append(r[1] / sin2)
    if len(rows) < MIN_PLANES:
        return None
    solved = solve_planes(np.array(rows), np.array(prec))
    if solved is None:
        return None
    offset, cov, n_in = solved
    return PlaneNormal(offset, cov, len(rows), n_in)


def solve_planes(m: Array, precision: Array) -> tuple[Array, Array, int] | None:
    """The normal's tangent offset ``δ`` that planes of unit normals ``m`` (N, 3) share,
    ``m · (δ_t, δ_b, 1) = 0``, with its covariance (rad²) and the number of inliers.

    Rows are weighted by their relative ``precision`` (N,) (the symmetry distance's
    curvature over ``sin² ∠(l, z)``) times Huber's weights (:data:`HUBER_K`), iterated;
    ``s²`` is the weighted residual variance on ``n_in − 2`` degrees of freedom. Each
    plane's variance is then its share of that scatter plus the floor every plane located
    on the texel grid carries, ``v_k = s²/w_k + PLANE_FLOOR_DEG²``, and ``δ`` is solved
    again with weights ``1/v_k`` (generalized least squares), covariance
    ``(Aᵀ V⁻¹ A)⁻¹``. The floor is added to the scatter, not taken out of it: where the
    planes' scatter already holds their independent errors this counts them twice (a
    conservative covariance), but part of the floor is a bias the planes share. On 69
    analytic captures (GGX and Beckmann α 0.1–0.5, ideal device) the planes' normal about
    the true one has a mean Mahalanobis² of 1.9, 5.8 % beyond the 95 % ellipse, this way;
    2.4 and 8.7 % with the floor taken out of the scatter.
    The floor enters per plane, not per axis: where two precise planes
    nearly coincide (the paper's layout: the two LEDs that see the mirror direction lie
    on the far side of the camera, their planes ≈ 10° apart), the scatter of the others
    cannot show how little they fix the normal along their common direction, and the
    floor propagated through their geometry does (`PLANE_FLOOR_DEG` / sin 10° ≈ 0.17°).

    Parameters
    ----------
    m : ndarray, shape (N, 3)
        The planes' unit normals in the frame of the current normal.
    precision : ndarray, shape (N,)
        Their relative precisions (0: the plane takes no part).

    Returns
    -------
    tuple or None
        The offset ``(δ_t, δ_b)`` (radians, shape (2,)), its covariance (rad², shape
        (2, 2)) and the number of inliers; ``None`` with fewer than :data:`MIN_PLANES`
        inliers or planes that fix one angle only.
    """
    keep = precision > 0.0  # a plane of no precision carries no information
    if np.count_nonzero(keep) < MIN_PLANES:
        return None
    a, b = m[keep, :2], -m[keep, 2]
    c = precision[keep] / float(np.mean(precision[keep]))
    w = c.copy()
    for _ in range(50):
        offset = _weighted_lstsq(a, b, w)
        res = a @ offset - b
        inliers = w > 0.5 * c
        scale = math.sqrt(float(np.sum(w * res**2)) / max(int(np.count_nonzero(inliers)) - 2, 1))
        new = c * np.minimum(1.0, HUBER_K * max(scale, 1e-9) / np.maximum(np.abs(res) * np.sqrt(c), 1e-300))
        if np.allclose(new, w, rtol=1e-9, atol=0.0):
            break
        w = new
    inliers = w > 0.5 * c
    n_in = int(np.count_nonzero(inliers))
    if n_in < MIN_PLANES:
        return None
    weighted = a.T @ (a * w[:, None])
    if not np.all(np.isfinite(weighted)) or np.linalg.cond(weighted) > 1e10:
        return None  # the weighted planes are (nearly) parallel: they fix one of the two angles only
    var = float(np.sum(w * res**2)) / (n_in - 2)
    gls = 1.0 / (var / w + math.radians(PLANE_FLOOR_DEG) ** 2)
    offset = _weighted_lstsq(a, b, gls)
    return offset, np.asarray(np.linalg.inv((a * gls[:, None]).T @ a), dtype=np.float64), n_in


def _weighted_lstsq(a: Array, b: Array, w: Array) -> Array:
    sw = np.sqrt(w)
    return np.asarray(np.linalg.lstsq(a * sw[:, None], b * sw, rcond=None)[0], dtype=np.float64)
