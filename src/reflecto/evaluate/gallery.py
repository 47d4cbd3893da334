"""The paper's Fig. 6 analogue: teapots of anisotropic and asymmetric materials, three ways.

For every material file: captures of the virtual device at the given rotations
(capture ``k`` with seed ``seed + k``), then

* the **symmetric path**: the first capture alone, reconstructed on the hemicube and
  completed by eq. 3's τ mirror (``reflecto reconstruct CAP --isotropic no``; ``auto``
  for an isotropic source);
* the **§5.5 path**: all captures together (``reflecto reconstruct CAP... --asymmetric``);

and a teapot under the environment map (Mitsuba 3, ``teapot-env``) of the reference,
of each reconstruction, and of the reference again with another seed (the renders'
noise floor). The page (``index.html``) shows reference | symmetric path | §5.5 path
per material with the BRDF error of each reconstruction (``reflecto compare``'s form:
eq. 10 over every half-vector azimuth for anisotropic sources), the mean image
difference of its teapot to the reference's, the noise floor, and the single
capture's symmetry test. The folder is written all at once (atomically).
"""

from __future__ import annotations

import dataclasses
import html
import json
import math
import os
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any
from urllib.parse import quote as url_quote

from .. import workflow
from ..errors import ParameterError, shown_path
from ..instrument.device import load_device
from ..instrument.simulate import simulate_capture
from ..io import atomic_folder, atomic_write
from ..load import load_source
from ..reconstruct import Options, reconstruct_rotations
from ..render.mitsuba import SMOOTHING_PX, check_render_settings, image_difference, object_mask, render, save_image
from .metrics import brdf_error_all_azimuths, comparison_error

__all__ = ["GALLERY_MARKER", "GallerySettings", "GalleryRow", "check_distinct_names", "gallery_row", "write_gallery",
           "gallery"]


@dataclasses.dataclass(frozen=True)
class GallerySettings:
    """What the gallery simulates and renders.

    ``device`` a built-in device or a device file; ``calibration`` a calibration file
    for a device that needs one (else one is simulated and computed once);
    ``rotations_deg`` the §5.5 set (the first is the symmetric path's capture);
    ``spp``, ``resolution`` the teapot renders'; ``seed`` the first capture's.
    """

    device: str = "ideal"
    calibration: str | None = None
    rotations_deg: tuple[float, ...] = (0.0, 90.0, 180.0, 270.0)
    spp: int = 64
    resolution: int = 256
    seed: int = 1

    def __post_init__(self) -> None:
        if len(self.rotations_deg) < 2:
            raise ParameterError("the gallery's §5.5 path needs at least two rotations, "
                                 f"got {list(self.rotations_deg)}")
        # the renders' settings, checked before the captures and reconstructions that precede them
        check_render_settings("teapot-env", self.resolution, self.spp, self.seed)


@dataclasses.dataclass
class GalleryRow:
    """One material of the gallery: errors, image differences, image files (in the folder)."""

    name: str
    source: str
    parameters: dict[str, Any]
    error_form: str
    symmetric_error: float
    asymmetric_error: float
    symmetric_image_difference: float
    asymmetric_image_difference: float
    noise_floor: float
    symmetry_ratio: float
    symmetry_broken: bool
    images: dict[str, str]
    seconds: float

    def to_dict(self) -> dict[str, Any]:
        """The row as JSON-ready values.

        Returns
        -------
        dict
            Every field (``dataclasses.asdict``): name, source, parameters, the error form,
            the normalized eq. 10 errors and image differences of both paths, the noise floor,
            the symmetry test's ratio and verdict, the image file names and the seconds.
        """
        return dataclasses.asdict(self)


def _reconstructions(src, device, cal, settings: GallerySettings):
    """The symmetric path's model, the §5.5 model, and the first capture's symmetry test."""
    caps = [simulate_capture(src, device, seed=settings.seed + k, rotation_deg=r)
            for k, r in enumerate(settings.rotations_deg)]
    first = workflow.capture_to_model(caps[0], cal, Options(isotropic="auto" if src.isotropic else "no"))
    rotated = workflow.rotated_captures(caps, cal, names=[f"rotation {r:g}°" for r in settings.rotations_deg])
    return first.model, reconstruct_rotations(rotated).model, first.symmetry


def _render_png(source, out: Path, name: str, settings: GallerySettings, seed: int):
    r = render(source, "teapot-env", resolution=settings.resolution, spp=settings.spp, seed=seed)
    save_image(r.image(), out / name)
    return r


def gallery_row(path: str | Path, out: Path, settings: GallerySettings, device=None, cal=None) -> GalleryRow:
    """Reconstruct, compare and render one material into the folder ``out`` (module docstring).

    Parameters
    ----------
    path
        The material file.
    out
        The folder the three teapot PNGs (``<name>_reference.png``, ``_symmetric.png``,
        ``_asymmetric.png``) are written to.
    settings
        Device, calibration, rotations, renders and seed.
    device
        The device already loaded from ``settings.device``; ``None``: load it.
    cal
        The calibration already made for it; ``None``: :func:`reflecto.workflow.calibration_for`
        (``missing="simulate"``).

    Returns
    -------
    GalleryRow
        The errors (:func:`~reflecto.evaluate.metrics.comparison_error`, normalized), the
        mean image differences to the reference's teapot and their noise floor (smoothed by
        :data:`~reflecto.render.mitsuba.SMOOTHING_PX`), the first capture's symmetry test,
        the image file names and the wall time (s).
    """

    t0 = time.perf_counter()
    p = Path(path)
    src = load_source(p)
    device = device or load_device(settings.device)
    cal = cal or workflow.calibration_for(device, settings.calibration, missing="simulate", seed=settings.seed)
    sym, asym, test = _reconstructions(src, device, cal, settings)
    e_asym = comparison_error(src, asym)  # the §5.5 model is anisotropic: over every half-vector azimuth
    # the symmetric path's over the same azimuths, so that a row's two errors compare (comparison_error
    # alone takes the MERL bins where the reference and that model are both isotropic)
    e_sym = brdf_error_all_azimuths(src, sym) if e_asym.form != "merl" else comparison_error(src, sym)
    stem = p.stem
    images = {k: f"{stem}_{k}.png" for k in ("reference", "symmetric", "asymmetric")}
    renders = {k: _render_png(s, out, images[k], settings, settings.seed + j)
               for j, (k, s) in enumerate((("reference", src), ("symmetric", sym), ("asymmetric", asym)))}
    repeat = _render_png(src, out, f"{stem}_reference_seed2.png", settings, settings.seed + 3)
    (out / f"{stem}_reference_seed2.png").unlink()
    mask = object_mask(*renders.values(), repeat)
    ref = renders["reference"].radiance
    diff = {k: image_difference(ref, renders[k].radiance, mask, SMOOTHING_PX) for k in ("symmetric", "asymmetric")}
    return GalleryRow(stem, str(p), src.parameters(), e_asym.describe(), e_sym.normalized, e_asym.normalized,
                      diff["symmetric"], diff["asymmetric"], image_difference(ref, repeat.radiance, mask, SMOOTHING_PX),
                      test.ratio, not test.symmetric, images, time.perf_counter() - t0)


_STYLE = """<style>
body { font-family: system-ui, sans-serif; margin: 2em; color: #222; }
table { border-collapse: collapse; } td, th { padding: 0.4em 0.8em; text-align: left; vertical-align: top;
border-bottom: 1px solid #eee; } img { width: 256px; } .num { font-size: 0.85em; color: #444; }
</style>"""


def _cell(row: GalleryRow, kind: str) -> str:
    src = html.escape(url_quote(os.fsencode(row.images[kind])))  # a name's "#", "?" or "%" is not part of a URL
    img = f'<img src="{src}" alt="{html.escape(shown_path(row.name))} {kind}">'
    if kind == "reference":
        return f"<td>{img}<div class='num'>noise floor of the renders {100 * row.noise_floor:.2f} %</div></td>"
    err = row.symmetric_error if kind == "symmetric" else row.asymmetric_error
    dif = row.symmetric_image_difference if kind == "symmetric" else row.asymmetric_image_difference
    corrected = math.sqrt(max(dif * dif - row.noise_floor * row.noise_floor, 0.0))
    return (f"<td>{img}<div class='num'>BRDF error {100 * err:.2f} %<br>image difference {100 * dif:.2f} % "
            f"(noise-corrected {100 * corrected:.2f} %)</div></td>")


def write_gallery(rows: Sequence[GalleryRow], out: Path, settings: GallerySettings) -> Path:
    """``index.html`` (and ``gallery.json``) of the rows in the folder ``out``.

    Parameters
    ----------
    rows
        The materials' rows (:func:`gallery_row`).
    out
        The folder (the rows' images are already there).
    settings
        The settings, stated on the page and stored in ``gallery.json``.

    Returns
    -------
    pathlib.Path
        ``out / "index.html"``.
    """

    rots = "/".join(f"{r:g}" for r in settings.rotations_deg)
    head = ("<tr><th>material</th><th>reference</th><th>symmetric path (one capture, eq. 3 mirror)</th>"
            f"<th>§5.5 path ({len(settings.rotations_deg)} captures at {rots}°)</th></tr>")
    forms = sorted({r.error_form for r in rows})
    form = forms[0] if len(forms) == 1 else "as each row's material states"  # rows may differ: say so
    body = []
    for r in rows:
        params = ", ".join(f"{k} {v}" for k, v in r.parameters.items())
        verdict = "broken" if r.symmetry_broken else "kept"
        name, shown_params = html.escape(shown_path(r.name)), html.escape(shown_path(params))
        own_form = f"BRDF error: {html.escape(r.error_form)}<br>" if len(forms) > 1 else ""
        body.append(f"<tr><td><b>{name}</b><div class='num'>{shown_params}<br>{own_form}"
                    f"eq. 3 in one capture: {verdict} ({r.symmetry_ratio:.1f}×)</div></td>"
                    + "".join(_cell(r, k) for k in ("reference", "symmetric", "asymmetric")) + "</tr>")
    page = ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>reflecto gallery: §5.5</title>"
            f"{_STYLE}</head>\n<body>\n<h1>Anisotropic and asymmetric materials: reference, symmetric path, §5.5 path"
            f"</h1>\n<p>Device {html.escape(shown_path(settings.device))}; teapot under the environment map, "
            f"{settings.spp} spp, "
            f"{settings.resolution}²; BRDF error: {html.escape(form)}, normalized; image difference: mean |Δ| over "
            "the teapot's pixels relative to the reference's mean (both smoothed by 1 px), beside the same between "
            f"two renders of the reference (noise floor) and √(difference² − floor²) (noise-corrected).</p>\n"
            f"<table>\n{head}\n" + "\n".join(body) + "\n</table>\n"
            "</body></html>\n")
    with atomic_write(out / "gallery.json", "w") as fh:
        fh.write(json.dumps({"settings": dataclasses.asdict(settings), "rows": [r.to_dict() for r in rows]}, indent=1))
    index = out / "index.html"
    with atomic_write(index, "w") as fh:
        fh.write(page)
    return index


#: The file every gallery folder holds: a folder with it is an earlier gallery, which a new one replaces
#: as a whole (a folder with only an ``index.html`` may be a report or a watch's models).
GALLERY_MARKER = "gallery.json"


def check_distinct_names(paths: Sequence[str | Path]) -> None:
    """Refuse materials of the same file name: their images (``NAME_reference.png``, …) would
    overwrite each other in the gallery's folder.

    Parameters
    ----------
    paths
        The material files.

    Raises
    ------
    ParameterError
        Two of them have the same name (stem).
    """
    seen: dict[str, str] = {}
    for p in paths:
        stem = Path(p).stem
        if stem in seen:
            raise ParameterError(f"materials {shown_path(seen[stem])} and {shown_path(p)} have the same name "
                                 f"{shown_path(stem)!r}; their images would overwrite each other: rename one")
        seen[stem] = str(p)


def gallery(paths: Sequence[str | Path], out_dir: str | Path, settings: GallerySettings | None = None,
            progress: Callable[[str, float], None] | None = None) -> tuple[Path, list[GalleryRow]]:
    """The gallery of the material files ``paths`` in the folder ``out_dir`` (module docstring).

    The folder appears complete or not at all; ``progress(name, seconds)`` is called
    after each material. Returns the page and the rows.

    Parameters
    ----------
    paths
        The material files, in page order.
    out_dir
        The gallery's folder (replaced as a whole, :func:`reflecto.io.atomic_folder`).
    settings
        Device, calibration, rotations, renders and seed; ``None``: ``GallerySettings()``.
    progress
        Called with each material's name and wall time (s); ``None``: nothing.

    Returns
    -------
    tuple of (pathlib.Path, list of GalleryRow)
        ``out_dir / "index.html"`` and the rows.
    """

    settings = settings or GallerySettings()
    check_distinct_names(paths)
    device = load_device(settings.device)
    cal = workflow.calibration_for(device, settings.calibration, missing="simulate", seed=settings.seed)
    rows = []
    with atomic_folder(out_dir, marker=GALLERY_MARKER) as tmp:
        for p in paths:
            row = gallery_row(p, tmp, settings, device, cal)
            rows.append(row)
            if progress:
                progress(row.name, row.seconds)
        write_gallery(rows, tmp, settings)
    return Path(out_dir) / "index.html", rows
