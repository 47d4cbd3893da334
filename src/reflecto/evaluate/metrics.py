"""Error metrics between two BRDFs (paper §6, eq. 10; AR 6.2).

The Ngan–Durand–Matusik error is a cosine-weighted RMS over the MERL bin grid
(``φ_h = 0``, bin centres, AR 6.1):

``E = √( Σ w (R cos θ_i − M cos θ_i)² / Σ w )``                    (eq. 10 / AR 6.1)

with the 4-D solid-angle weight of a bin ``w ∝ cos θ_d sin θ_d sin θ_h · u_h``
(AR 6.3, ``u_h = (k + ½)/90``), over bins with ``θ_i, θ_o ≤ 80°`` where the
reference is valid (≥ 0). Reported per channel, and as their mean divided by the
reference's largest directional albedo over ``θ_i ≤ 80°`` (*normalized error*), so
that dark and bright materials are comparable. Also the log-RMSE
``√(Σ w (log(1 + R cos) − log(1 + M cos))² / Σ w)`` (channel mean).

**Every half-vector azimuth.** The MERL grid fixes ``φ_h = 0``: for an isotropic
BRDF that loses nothing, but of an anisotropic or asymmetric lobe it sees one
azimuthal cut only (an NDF that breaks eq. 3 differs between ``φ_h`` and
``φ_h + π``, which the cut never compares). :func:`comparison_error` therefore uses,
when either source is anisotropic, the same sum over :data:`AZIMUTHS` copies of the
grid turned about ``n`` by ``φ_h = 2πk/K`` (every :data:`AZIMUTH_STRIDE`-th θ_d and
φ_d bin, the sub-grid offset staggered with ``k`` so that any
``AZIMUTH_STRIDE²`` consecutive azimuths together visit every bin):

``E² = Σ_k Σ w (R cos θ_i − M cos θ_i)² / (K Σ w)``

— eq. 10 with ``φ_h`` integrated too (the measure ``dω_i dω_o`` is uniform in
``φ_h``, AR 6.2). On isotropic sources both forms estimate the same integral. Its
normalization takes the largest albedo over :data:`ALBEDO_AZIMUTHS` incidence
azimuths as well, so that turning both sources about ``n`` leaves the number as it is.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np
from numpy.typing import NDArray

from .. import geometry
from ..brdf import BRDFSource, HasNDF
from ..errors import ParameterError
from ..hemicube import hemicube
from ..sources import merl

Array = NDArray[np.float64]

#: Grazing cut of Ngan et al. (degrees).
THETA_MAX_DEG = 80.0


@dataclasses.dataclass(frozen=True)
class Grid:
    """MERL bin-centre directions kept by the metric, with their weights.

    ``i, o`` shape ``(K, 3)``; ``w`` shape ``(K,)`` (AR 6.3); ``flat`` the MERL linear
    index of each kept bin (to skip a MERL reference's invalid bins).
    """

    i: Array
    o: Array
    w: Array
    flat: NDArray[np.intp]


@functools.lru_cache(maxsize=16)
def metric_grid(stride: int = 1, theta_max_deg: float = THETA_MAX_DEG, offset: tuple[int, int] = (0, 0)) -> Grid:
    """The bins of eq. 10 (every ``stride``-th bin along θ_d and φ_d, for quick checks,
    starting at bin ``offset`` = (θ_d, φ_d)); ``stride`` an integer in ``[1, 90]``, the angle
    in ``(0°, 90°]``."""
    if isinstance(stride, bool) or not isinstance(stride, (int, np.integer)) or not 1 <= stride <= merl.N_THETA_D:
        raise ParameterError(f"eq. 10 grid: stride must be an integer in [1, {merl.N_THETA_D}], got {stride!r}")
    if not (isinstance(theta_max_deg, (int, float, np.number)) and 0.0 < theta_max_deg <= 90.0):
        raise ParameterError(f"eq. 10 grid: the largest angle must lie in (0°, 90°], got {theta_max_deg!r}")
    th, td, pd = merl.bin_centres()
    kh = np.arange(merl.N_THETA_H)
    kd = np.arange(offset[0] % stride, merl.N_THETA_D, stride)
    kp = np.arange(offset[1] % stride, merl.N_PHI_D, stride)
    KH, KD, KP = np.meshgrid(kh, kd, kp, indexing="ij")

    i, o = geometry.hd_to_io(th[KH], np.zeros(KH.shape), td[KD], pd[KP])
    u = (KH + 0.5) / merl.N_THETA_H
    w = np.cos(td[KD]) * np.sin(td[KD]) * np.sin(th[KH]) * u
    cz = math.cos(math.radians(theta_max_deg))
    keep = (i[..., 2] >= cz) & (o[..., 2] >= cz)
    flat = KP + merl.N_PHI_D * (KD + merl.N_THETA_D * KH)
    g = Grid(np.ascontiguousarray(i[keep]), np.ascontiguousarray(o[keep]), w[keep], flat[keep])
    for a in (g.i, g.o, g.w, g.flat):
        a.setflags(write=False)
    return g


@dataclasses.dataclass
class Error:
    """Eq. 10 between a reference and a test BRDF.

    Attributes
    ----------
    rmse
        Cosine-weighted RMS difference per channel (sr⁻¹), shape ``(3,)``.
    normalized
        Channel mean of ``rmse`` over the reference's max directional albedo.
    log_rmse
        Channel-mean log-RMSE (dimensionless).
    albedo_ref
        The normalizing albedo.
    form
        Which form of eq. 10: ``"merl"`` (the MERL bins, ``φ_h = 0``) or
        ``"all-azimuths"`` (:data:`AZIMUTHS` half-vector azimuths, module docstring).
    azimuths
        Number of half-vector azimuths summed (1 for ``"merl"``).
    """

    rmse: Array
    normalized: float
    log_rmse: float
    albedo_ref: float
    form: str = "merl"
    azimuths: int = 1

    def to_dict(self) -> dict[str, float | int | str | list[float]]:
        """The error as JSON-ready numbers.

        Returns
        -------
        dict
            ``rmse`` (list of 3 floats, sr⁻¹), ``normalized``, ``log_rmse``, ``albedo_ref``
            (floats), and the metric's ``form`` (str) and ``azimuths`` (int).
        """
        return {"rmse": self.rmse.tolist(), "normalized": self.normalized, "log_rmse": self.log_rmse,
                "albedo_ref": self.albedo_ref, "form": self.form, "azimuths": self.azimuths}

    def describe(self) -> str:
        """The form in words, for a command's output.

        Returns
        -------
        str
            ``"Ngan et al. eq. 10, MERL bins (φ_h = 0), θ ≤ 80°"`` for the ``"merl"`` form, else
            a line naming the number of half-vector azimuths and their spacing.
        """
        if self.form == "merl":
            return "Ngan et al. eq. 10, MERL bins (φ_h = 0), θ ≤ 80°"
        return (f"Ngan et al. eq. 10 over every half-vector azimuth ({self.azimuths} φ_h, "
                f"{360 / self.azimuths:g}° apart; an anisotropic source), θ ≤ 80°")


def max_albedo(source: BRDFSource, theta_max_deg: float = THETA_MAX_DEG, azimuths: int = 1) -> float:
    """Largest channel-mean directional albedo over ``θ_i ∈ [0, θ_max]`` (5° steps) and
    ``φ_i = 2πk/azimuths`` (the incidence plane ``φ_i = 0`` alone by default).

    Parameters
    ----------
    source
        The BRDF whose albedo is taken (its ``albedo(theta_i_deg, phi_i_deg)`` method).
    theta_max_deg
        Largest incidence polar angle θ_max, degrees (default the 80° cut of eq. 10).
    azimuths
        Number ``K`` of incidence azimuths ``φ_i = 360° k/K``, ``k = 0 … K−1``.

    Returns
    -------
    float
        ``max over θ_i, φ_i`` of the mean over R, G, B of ``a(i) = ∫ f(i, o) cos θ_o dω_o``
        (dimensionless).
    """
    theta = np.arange(0.0, theta_max_deg + 1e-9, 5.0)
    return max(float(np.max(source.albedo(theta, 360.0 * k / azimuths).mean(axis=1))) for k in range(azimuths))


def evaluate_on_grid(source: BRDFSource, grid: Grid, chunk: int = 1 << 18) -> Array:
    """``source`` at the grid's direction pairs; a MERL table is read directly.

    Parameters
    ----------
    source
        The BRDF. One with a ``table`` attribute of the MERL shape ``(90, 90, 180, 3)``
        is indexed at ``grid.flat`` (invalid bins stay negative); any other is
        evaluated with ``source.eval(i, o)``.
    grid
        The direction pairs (:func:`metric_grid` or :func:`turned_grid`).
    chunk
        Number of direction pairs evaluated per ``eval`` call (bounds the memory).

    Returns
    -------
    numpy.ndarray, shape (K, 3)
        BRDF values in sr⁻¹, one row per bin of ``grid`` (``K = len(grid.w)``), R, G, B.
    """
    table = getattr(source, "table", None)
    if table is not None and np.shape(table) == merl.SHAPE + (3,):
        return np.asarray(table).reshape(-1, 3)[grid.flat]
    out = np.empty((len(grid.w), 3))
    for s in range(0, len(grid.w), chunk):
        f = np.asarray(source.eval(grid.i[s : s + chunk], grid.o[s : s + chunk]))
        if f.shape != (len(grid.i[s : s + chunk]), 3):
            raise ParameterError(f"{getattr(source, 'name', 'the source')}: eval(i, o) of {len(grid.i[s : s + chunk])} "
                                 f"direction pairs must return shape (N, 3) (R, G, B), got {f.shape}")
        out[s : s + chunk] = f
    return out


@dataclasses.dataclass
class _Sums:
    """``Σ w``, ``Σ w Δ²`` and ``Σ w Δ_log²`` of eq. 10 over some bins (per channel)."""

    w: float = 0.0
    sq: Array = dataclasses.field(default_factory=lambda: np.zeros(3))
    log_sq: Array = dataclasses.field(default_factory=lambda: np.zeros(3))


def _accumulate(sums: _Sums, grid: Grid, r: Array, m: Array, name: str) -> None:
    """Add the bins of ``grid`` (reference values ``r``, test values ``m``, (K, 3)) to ``sums``."""
    ok = np.all(r >= 0, axis=1) & np.all(np.isfinite(r), axis=1)
    if not np.all(np.isfinite(m[ok])):
        bad = int(np.count_nonzero(~np.isfinite(m[ok])))
        raise ParameterError(f"{name}: {bad} non-finite values on the metric grid")
    cos_i = grid.i[ok, 2][:, None]
    w = grid.w[ok][:, None]
    rc, mc = r[ok] * cos_i, m[ok] * cos_i
    sums.w += float(np.sum(w))
    sums.sq += np.sum(w * (rc - mc) ** 2, axis=0)
    sums.log_sq += np.sum(w * (np.log1p(rc) - np.log1p(np.maximum(mc, 0.0))) ** 2, axis=0)


#: Incidence azimuths of the all-azimuths form's albedo normalization (30° apart): the
#: albedo of an anisotropic lobe varies with φ_i, so that the φ_i = 0 plane alone would
#: make the normalized error depend on how the reference is turned about n.
ALBEDO_AZIMUTHS = 12
#: The smallest largest-albedo of a reference that eq. 10's normalized error divides by:
#: below it the reference is black (10⁻⁶ is far below any measured material's, ≳ 10⁻²).
MIN_ALBEDO_REF = 1e-6


def _error(sums: _Sums, reference: BRDFSource, albedo_ref: float | None, form: str, azimuths: int) -> Error:
    if not sums.w > 0:
        raise ParameterError(f"eq. 10: the reference {reference.name} has no valid bin on the grid (every value "
                             "negative or not finite)")
    rmse = np.sqrt(sums.sq / sums.w)
    log_rmse = np.sqrt(sums.log_sq / sums.w)
    if albedo_ref is not None:
        a = albedo_ref
    elif azimuths > 1 and not getattr(reference, "isotropic", True):
        a = max_albedo(reference, azimuths=ALBEDO_AZIMUTHS)
    else:
        a = max_albedo(reference)
    if not a > MIN_ALBEDO_REF:  # a black reference: the error relative to what it reflects has no meaning
        raise ParameterError(f"eq. 10: the reference {reference.name} reflects (almost) nothing (largest directional "
                             f"albedo {a:.3g}), so the error normalized by it is undefined")
    return Error(rmse, float(rmse.mean() / a), float(log_rmse.mean()), a, form, azimuths)


def brdf_error(reference: BRDFSource, test: BRDFSource, stride: int = 1, albedo_ref: float | None = None,
               reference_values: Array | None = None) -> Error:
    """Eq. 10 (and log-RMSE) of ``test`` against ``reference`` on the MERL bins
    (``φ_h = 0``, module docstring).

    ``E_c = √( Σ w (R_c cos θ_i − M_c cos θ_i)² / Σ w )`` per channel ``c`` (paper eq. 10,
    Ngan–Durand–Matusik; AR 6.1), with ``w ∝ cos θ_d sin θ_d sin θ_h · u_h`` (AR 6.3),
    over the bins with ``θ_i, θ_o ≤ 80°`` where the reference is valid (all three
    channels ≥ 0 and finite).

    Parameters
    ----------
    reference
        The reference BRDF ``R`` (e.g. a MERL material).
    test
        The BRDF ``M`` under test (e.g. a reconstruction); its ``name`` labels the
        error raised on a non-finite value.
    stride
        Keep every ``stride``-th bin along θ_d and φ_d (1: every bin; larger for quick
        checks).
    albedo_ref
        Normalizing albedo; ``None``: :func:`max_albedo` of ``reference`` (``φ_i = 0``).
    reference_values
        ``reference`` already evaluated on ``metric_grid(stride)``, shape ``(K, 3)``, sr⁻¹
        (saves evaluating it again across several tests); ``None``: evaluate it.

    Returns
    -------
    Error
        ``rmse`` (sr⁻¹, per channel), ``normalized = mean(rmse)/albedo_ref``,
        ``log_rmse``, ``albedo_ref``; ``form == "merl"``, ``azimuths == 1``.

    Raises
    ------
    ParameterError
        (a ``ValueError``) ``test`` is non-finite on a bin where the reference is valid; a
        reference without a valid bin; a source whose ``eval`` does not return ``(N, 3)``.
    """
    g = metric_grid(stride)
    r = evaluate_on_grid(reference, g) if reference_values is None else reference_values
    if np.shape(r) != (len(g.i), 3):
        raise ParameterError(f"eq. 10: reference_values must have shape ({len(g.i)}, 3) (the grid of stride "
                             f"{stride}), got {np.shape(r)}")
    if albedo_ref is not None and not (isinstance(albedo_ref, (int, float, np.number))
                                       and math.isfinite(albedo_ref) and albedo_ref > 0):
        raise ParameterError(f"eq. 10: albedo_ref must be a finite number > 0, got {albedo_ref!r}")
    sums = _Sums()
    _accumulate(sums, g, r, evaluate_on_grid(test, g), test.name)
    return _error(sums, reference, albedo_ref, "merl", 1)


#: Half-vector azimuths of the anisotropy-aware form (15° apart: an anisotropic lobe
#: varies with 2 φ_h, an asymmetric one with φ_h; a 15° step resolves both).
AZIMUTHS = 24
#: θ_d and φ_d stride of each azimuth's grid in that form (3: within 1.5 % of a 48-azimuth full
#: grid's error on the analytic lobes, and ``AZIMUTHS`` grids cost 2.7× one full grid).
AZIMUTH_STRIDE = 3


def turned_grid(grid: Grid, phi_h: float) -> Grid:
    """``grid`` with every direction turned about ``n`` by ``phi_h`` (radians): the same
    bins at half-vector azimuth ``phi_h``.

    Parameters
    ----------
    grid
        The bins to turn.
    phi_h
        Rotation angle about ``n`` (the local ``z`` axis), radians.

    Returns
    -------
    Grid
        ``i`` and ``o`` turned (shape ``(K, 3)`` each); ``w`` and ``flat`` shared with ``grid``.
    """

    return Grid(geometry.rotate_z(grid.i, phi_h), geometry.rotate_z(grid.o, phi_h), grid.w, grid.flat)


def brdf_error_all_azimuths(reference: BRDFSource, test: BRDFSource, azimuths: int = AZIMUTHS,
                            stride: int = AZIMUTH_STRIDE, albedo_ref: float | None = None) -> Error:
    """Eq. 10 of ``test`` against ``reference`` summed over ``azimuths`` half-vector
    azimuths (module docstring); shape and units as :func:`brdf_error`.

    ``E_c² = Σ_k Σ w (R_c cos θ_i − M_c cos θ_i)² / (K Σ w)`` over ``φ_h = 2πk/K``,
    ``k = 0 … K−1``; azimuth ``k`` uses every ``stride``-th θ_d and φ_d bin starting at
    offset ``(k mod stride, (k div stride) mod stride)``.

    Parameters
    ----------
    reference
        The reference BRDF ``R``.
    test
        The BRDF ``M`` under test.
    azimuths
        Number ``K`` of half-vector azimuths (default :data:`AZIMUTHS`, 15° apart).
    stride
        θ_d and φ_d stride of each azimuth's grid (default :data:`AZIMUTH_STRIDE`).
    albedo_ref
        Normalizing albedo; ``None``: :func:`max_albedo` of ``reference`` over
        :data:`ALBEDO_AZIMUTHS` incidence azimuths when the reference is anisotropic
        (``isotropic`` false), over ``φ_i = 0`` alone otherwise.

    Returns
    -------
    Error
        As :func:`brdf_error`, with ``form == "all-azimuths"`` and ``azimuths == K``.

    Raises
    ------
    ParameterError
        (a ``ValueError``) ``test`` is non-finite on a bin where the reference is valid.
    """
    sums = _Sums()
    for k in range(azimuths):
        base = metric_grid(stride, THETA_MAX_DEG, (k % stride, (k // stride) % stride))
        g = turned_grid(base, 2.0 * math.pi * k / azimuths)
        _accumulate(sums, g, evaluate_on_grid(reference, g), evaluate_on_grid(test, g), test.name)
    return _error(sums, reference, albedo_ref, "all-azimuths", azimuths)


def comparison_error(reference: BRDFSource, test: BRDFSource) -> Error:
    """The error ``reflecto compare`` reports: eq. 10 on the MERL bins when both sources
    are isotropic, over every half-vector azimuth when either is not (module docstring).

    Parameters
    ----------
    reference
        The reference BRDF; a source without an ``isotropic`` attribute counts as isotropic.
    test
        The BRDF under test; likewise.

    Returns
    -------
    Error
        :func:`brdf_error` (``form == "merl"``) when both are isotropic, else
        :func:`brdf_error_all_azimuths` with its defaults (``form == "all-azimuths"``).
    """
    if getattr(reference, "isotropic", True) and getattr(test, "isotropic", True):
        return brdf_error(reference, test)
    return brdf_error_all_azimuths(reference, test)


def ndf_error(reference: HasNDF, model: HasNDF, resolution: int = 256, floor: float = 0.01) -> float:
    """Mean relative error of ``model``'s NDF against ``reference``'s where the reference's
    ``D`` exceeds ``floor`` of its peak, over the texel directions of a hemicube of the
    given resolution (dimensionless). Both must have an ``ndf(h)`` method.

    ``mean over {h : D_ref(h) > floor · max D_ref} of |D_model(h)/D_ref(h) − 1|``.

    Parameters
    ----------
    reference
        The reference NDF ``D_ref`` (``ndf(h)`` on unit half vectors, local frame).
    model
        The NDF ``D_model`` under test.
    resolution
        Top-face resolution of the hemicube whose texel centres are the half vectors ``h``.
    floor
        Fraction of the reference's peak below which texels are left out (0.01: 1 %).

    Returns
    -------
    float
        The mean relative error (0 for identical NDFs).

    Raises
    ------
    ParameterError
        A floor outside ``[0, 1)``, or a reference NDF with no finite positive texel.
    """
    if isinstance(floor, bool) or not isinstance(floor, (int, float, np.number)) or not 0.0 <= floor < 1.0:
        raise ParameterError(f"NDF error: floor must be a fraction in [0, 1), got {floor!r}")
    h = hemicube(resolution).directions
    d = reference.ndf(h)
    m = model.ndf(h)
    if not (np.all(np.isfinite(d)) and d.max() > 0):
        raise ParameterError("NDF error: the reference NDF must be finite with a positive peak")
    peak = d > floor * d.max()
    return float(np.mean(np.abs(m[peak] / d[peak] - 1.0)))
