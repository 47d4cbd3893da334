"""Static HTML report of a model (and of a sweep): renders, NDF, coverage, slices, numbers.

``write_report(model_path, out_dir, reference=None)`` writes ``out_dir/index.html``
and its PNGs:

* renders: the model on a sphere under an environment map and under point lights
  (Mitsuba 3), and — with a reference — reference | model | difference for both, each
  with its mean image difference, noise floor and noise-corrected difference;
* the NDF: the hemicube unfolded (log scale) and a polar plot ``D(θ_h, φ_h)``;
* the LED coverage of the capture's device (paper Fig. 2(c)(d));
* the six slices of the capture, when the model's metadata names a capture folder
  that still exists (calibration: the nominal one of its device);
* a ``θ_h``–``θ_d`` image at ``φ_d = 90°`` as BRDF Explorer shows it (log scale);
* the numbers: η, k_d, k_s, normal tilt, E(η), and with a reference the eq. 10 error.

The folder is written whole or not at all (an earlier report there is replaced); the page checks on load
that each image decoded and records the count in ``<body data-images>`` — the
headless-Chromium test reads it (``tests/test_report.py``).
"""

from __future__ import annotations

import html
import math
import tempfile
from pathlib import Path
from typing import Any
from urllib.parse import quote as url_quote

import imageio.v3 as iio
import numpy as np
from numpy.typing import NDArray

from .. import geometry, workflow
from ..brdf import BRDFSource, HasNDF, albedo_angles
from ..colour import LUM
from ..errors import FileFormatError, ReflectoError, one_line, shown_path
from ..fresnel import is_constant
from ..instrument.capture import read_capture
from ..instrument.device import BUILTINS as DEVICE_BUILTINS
from ..instrument.device import Device, load_device
from ..instrument.plots import plot_coverage
from ..io import atomic_folder, atomic_path, atomic_write, read_json
from ..load import load_source
from ..model import IsotropicMicrofacetBRDF, MicrofacetBRDF, load_model
from ..plotting import plain_log_axis, pyplot, save_figure
from ..reconstruct.pipeline import ALBEDO_ANGLES
from ..reconstruct.preview import UNPLACED
from ..render.mitsuba import bsdf_file, compare_files, comparison_image, default_envmap, render_file, titled, to_srgb8
from .metrics import comparison_error
from .viewer import write_viewer

Array = NDArray[np.float64]

_CHECK_SCRIPT = """<script>
window.addEventListener('load', function () {
  var imgs = Array.prototype.slice.call(document.images);
  var bad = imgs.filter(function (im) { return !(im.complete && im.naturalWidth > 0); });
  document.body.setAttribute('data-images', (imgs.length - bad.length) + '/' + imgs.length);
  bad.forEach(function (im) { console.error('image failed to load: ' + im.getAttribute('src')); });
});
</script>"""

_STYLE = """<style>
body { font-family: system-ui, sans-serif; margin: 2em; color: #222; max-width: 1100px; }
h1 { font-size: 1.5em; } h2 { font-size: 1.15em; margin-top: 1.6em; border-bottom: 1px solid #ddd; }
table { border-collapse: collapse; } td, th { padding: 0.2em 0.8em; text-align: left; border-bottom: 1px solid #eee; }
figure { display: inline-block; margin: 0.5em 1em 0.5em 0; vertical-align: top; }
figcaption { font-size: 0.85em; color: #555; max-width: 520px; }
img { max-width: 100%; image-rendering: auto; }
</style>"""


def _save_png(fig_or_array: Any, path: Path) -> str:
    """Save a matplotlib figure or an 8-bit image atomically; returns the file name."""
    if isinstance(fig_or_array, np.ndarray):

        with atomic_path(path, suffix=".png") as tmp:
            iio.imwrite(tmp, fig_or_array)
    else:
        save_figure(fig_or_array, path, dpi=90)
    return path.name



def ndf_figures(model: HasNDF, out: Path) -> list[tuple[str, str]]:
    """Plots of a model's NDF from ``model.ndf(h)``; returns ``[(file, caption)]``.

    A polar plot ``D(θ_h, φ_h)`` and the profile ``D(θ_h)`` (azimuthal mean, min and
    max) for any model; the unfolded hemicube as well where the model has one.

    Parameters
    ----------
    model
        A model with ``ndf(h)`` (``D`` in sr⁻¹ on unit half vectors ``(N, 3)``); one with
        ``cube`` and ``ndf_values`` also gets the unfolded hemicube.
    out
        The folder the PNGs are written to (``ndf_unfolded.png``, ``ndf_polar.png``,
        ``ndf_profile.png``).

    Returns
    -------
    list of (str, str)
        ``(file name, caption)`` of each figure written.
    """
    plt = pyplot()
    items = []
    cube = getattr(model, "cube", None)
    values = getattr(model, "ndf_values", None)
    if cube is not None and values is not None:
        d = np.maximum(values, 1e-6 * values.max())
        fig, ax = plt.subplots(figsize=(5.2, 4.6))
        im = ax.imshow(np.log10(cube.unfold(d)), origin="lower", cmap="magma")
        fig.colorbar(im, ax=ax, label="log₁₀ D (sr⁻¹)")
        ax.set_title("NDF, hemicube unfolded (top face in the middle)")
        ax.set_xticks([])
        ax.set_yticks([])
        items.append((_save_png(fig, out / "ndf_unfolded.png"), "NDF on the hemicube, unfolded (log scale)."))
    th = np.radians(np.linspace(0, 89, 90))
    ph = np.radians(np.linspace(0, 360, 181))
    T, P = np.meshgrid(th, ph, indexing="ij")
    h = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1)
    dv = model.ndf(h.reshape(-1, 3)).reshape(T.shape)
    fig = plt.figure(figsize=(5, 4.6))
    ax = fig.add_subplot(projection="polar")
    pc = ax.pcolormesh(P, np.degrees(T), np.log10(np.maximum(dv, 1e-6 * dv.max())), cmap="magma", shading="auto")
    fig.colorbar(pc, ax=ax, label="log₁₀ D (sr⁻¹)", pad=0.12)
    ax.set_rticks([30, 60, 90])
    ax.set_yticklabels(["θ_h 30°", "60°", "90°"], color="white", fontsize=8)
    ax.set_rlabel_position(112.5)
    ax.set_xticks(np.radians(np.arange(0, 360, 45)))
    ax.set_xticklabels([f"φ_h {v}°" if v == 0 else f"{v}°" for v in range(0, 360, 45)], fontsize=8)
    ax.tick_params(axis="x", pad=6)
    ax.set_title("NDF D(θ_h, φ_h); radius θ_h", pad=14)
    items.append((_save_png(fig, out / "ndf_polar.png"), "NDF in polar coordinates (log scale)."))
    # the profile on rings dense near the pole, where sharp lobes are
    th = 0.5 * math.pi * np.linspace(0.0, 1.0, 400) ** 2
    az = np.radians(np.arange(0.0, 360.0, 5.0))
    h = np.stack(np.broadcast_arrays(np.sin(th)[:, None] * np.cos(az), np.sin(th)[:, None] * np.sin(az),
                                     np.cos(th)[:, None]), -1)
    ring = model.ndf(h.reshape(-1, 3)).reshape(h.shape[:-1])
    fig, ax = plt.subplots(figsize=(5, 3.6))
    floor = 1e-6 * float(ring.max())
    ax.fill_between(np.degrees(th), np.maximum(ring.min(axis=1), floor), np.maximum(ring.max(axis=1), floor),
                    color="0.8", label="min–max over φ_h")
    ax.semilogy(np.degrees(th), np.maximum(ring.mean(axis=1), floor), "k-", lw=1, label="mean over φ_h")
    lobes = getattr(model, "lobes", None)
    caption = "NDF against θ_h (log scale): mean, min and max over φ_h."
    if lobes is not None:  # the lobe at each θ_d node (docs/design/reconstruction.md)
        for t, d in zip(lobes.theta_d, lobes.ndfs):
            ax.semilogy(np.degrees(th), np.maximum(d.at_theta(th), floor), lw=1, ls="--",
                        label=f"lobe at θ_d = {math.degrees(t):.0f}°")
        caption = ("NDF against θ_h (log scale): the fit's one D (black; S of the plots) "
                   "and the lobe the model uses at each θ_d node (dashed), mixed between the nodes; the "
                   "export samples by the nodes' mean.")
    plain_log_axis(ax)
    ax.set_xlabel("θ_h (deg)")
    ax.set_ylabel("D (sr⁻¹)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    items.append((_save_png(fig, out / "ndf_profile.png"), caption))
    return items


def theta_h_theta_d_image(source: BRDFSource, out: Path, name: str = "thd.png", title: str = "") -> str:
    """BRDF Explorer's θ_h–θ_d image at φ_d = 90° (luminance, log scale).

    ``log₁₀ max(f·LUM, 10⁻⁴)`` on a 180 × 180 grid of θ_h, θ_d ∈ [0.25°, 89.75°] (``φ_h = 0``).

    Parameters
    ----------
    source
        The BRDF (sr⁻¹).
    out
        The folder the PNG is written to.
    name
        The PNG's file name.
    title
        The plot's title; ``""``: ``"θ_h–θ_d slice at φ_d = 90°"``.

    Returns
    -------
    str
        The file name written (``name``).
    """

    plt = pyplot()
    th = np.radians(np.linspace(0.25, 89.75, 180))
    td = np.radians(np.linspace(0.25, 89.75, 180))
    TH, TD = np.meshgrid(th, td, indexing="ij")
    i, o = geometry.hd_to_io(TH, np.zeros_like(TH), TD, np.full_like(TH, 0.5 * math.pi))
    ok = (i[..., 2] > 0) & (o[..., 2] > 0)
    f = np.zeros(TH.shape)
    f[ok] = source.eval(i[ok], o[ok]) @ LUM
    fig, ax = plt.subplots(figsize=(5, 4.4))
    im = ax.imshow(np.log10(np.maximum(f, 1e-4)).T, origin="lower", extent=(0, 90, 0, 90), cmap="viridis",
                   aspect="equal")
    fig.colorbar(im, ax=ax, label="log₁₀ f (sr⁻¹), luminance")
    ax.set_xlabel("θ_h (deg)")
    ax.set_ylabel("θ_d (deg)")
    ax.set_title(title or "θ_h–θ_d slice at φ_d = 90°")
    return _save_png(fig, out / name)


def slice_figure(capture_dir: Path, out: Path, calibration: str | Path | None = None):
    """The slices of a capture (luminance, log scale, with its colour bar) on the sensor, read
    with ``calibration`` (the capture's own; default: the device's nominal one).

    Returns ``(file, device, calibration words)``, or the reason the capture cannot be read
    (one line naming the file at fault).

    Parameters
    ----------
    capture_dir
        The capture folder.
    out
        The folder ``slices.png`` is written to.
    calibration
        The calibration file the model names; ``None``, or a file that does not load: the
        device's nominal calibration (and the words say so).

    Returns
    -------
    tuple of (str, Device, str) or str
        The file name, the capture's device and how it was calibrated; where the capture
        cannot be read, why (one line).
    """
    try:
        cap = read_capture(capture_dir)
    except Exception as e:  # noqa: BLE001 - the capture may be gone or damaged: the report says why
        return one_line(e)
    try:
        cal = workflow.calibration_for(cap.device, calibration, missing="nominal")
        words = f"calibration {Path(calibration).name}" if calibration is not None else "nominal calibration"
    except ReflectoError as e:
        cal = workflow.calibration_for(cap.device, missing="nominal")
        words = f"nominal calibration: the model's calibration file could not be read ({e})"
    sl = workflow.measure(cap, cal, capture_dir)
    plt = pyplot()
    h, w = cal.optics.height, cal.optics.width
    fig, axes = plt.subplots(2, (sl.n_leds + 1) // 2, figsize=(3.2 * ((sl.n_leds + 1) // 2), 5.2))
    vals = np.where(sl.valid, sl.values @ LUM, np.nan)
    vmax = np.nanpercentile(vals, 99.5)
    im = None
    for k, ax in enumerate(np.ravel(axes)):
        ax.axis("off")
        if k >= sl.n_leds:
            continue
        img = np.full((h, w), np.nan)
        img[sl.pixels[:, 0], sl.pixels[:, 1]] = vals[k]
        im = ax.imshow(np.log10(np.maximum(img, 1e-4 * vmax)), cmap="inferno", vmin=np.log10(1e-3 * vmax),
                       vmax=np.log10(vmax))
        ax.set_title(f"slice l{k}", fontsize=9)
    fig.suptitle(f"BRDF slices on the sensor (log luminance, one per LED; white: not measured; {words.split(':')[0]})",
                 fontsize=10)
    fig.tight_layout(rect=(0, 0, 0.9, 1))
    if im is not None:
        bar = fig.colorbar(im, cax=fig.add_axes((0.91, 0.15, 0.015, 0.7)))
        bar.set_label("log₁₀ luminance of f (sr⁻¹)", fontsize=8)
    return _save_png(fig, out / "slices.png"), cap.device, words


def render_figures(model: MicrofacetBRDF | IsotropicMicrofacetBRDF, ref: BRDFSource | None, out: Path,
                   spp: int | None) -> tuple[list[tuple[str, str]], dict[str, Any]]:
    """The model's renders and, with a reference, the two comparisons.

    Returns ``[(file, caption)]`` and ``{scene: Comparison}``.

    Each comparison renders the model once and the reference twice with different
    seeds, and states the mean image difference beside the noise floor (the same
    measure between the two reference renders) and the difference corrected for it
    (:class:`reflecto.render.mitsuba.Comparison`).

    Parameters
    ----------
    model
        The model to render.
    ref
        The reference BRDF, or ``None`` for the model's renders alone.
    out
        The folder the PNGs are written to (``render_<scene>.png``, ``compare_<scene>.png``).
    spp
        Samples per pixel; ``None``: each scene's default.

    Returns
    -------
    tuple of (list of (str, str), dict of str to Comparison)
        ``(file name, caption)`` of each figure, and the comparison of each scene
        (``sphere-env``, ``sphere-point``; empty without a reference).
    """

    with tempfile.TemporaryDirectory(prefix="reflecto-report-") as tmp:  # each BRDF exported once for both scenes
        folder = Path(tmp)
        (folder / "model").mkdir()
        (folder / "ref").mkdir()
        model_file = bsdf_file(model, folder / "model")
        ref_file = None if ref is None else (ref.name, bsdf_file(ref, folder / "ref"))
        return _render_figures(model, model_file, ref_file, out, spp)


def _render_figures(model: MicrofacetBRDF | IsotropicMicrofacetBRDF, model_file: Path,
                    ref_file: tuple[str, Path] | None, out: Path, spp: int | None
                    ) -> tuple[list[tuple[str, str]], dict[str, Any]]:
    items, comparisons = [], {}
    for scene, what in (("sphere-env", "Sphere under the studio map"),
                        ("sphere-point", "Sphere under a key and a fill point light")):
        if ref_file is None:
            r = render_file(model_file, scene, spp=spp)
            items.append((_save_png(titled(to_srgb8(r.image()), f"model {model.name}: {what.lower()}"),
                                    out / f"render_{scene}.png"),
                          f"{what} (Mitsuba 3, {r.variant}, {r.spp} spp)."))
            continue
        ref_name, ref_path = ref_file
        c = comparisons[scene] = compare_files(ref_path, model_file, scene, spp=spp)
        items.append((_save_png(titled(to_srgb8(c.test.image()), f"model {model.name}: {what.lower()}"),
                                out / f"render_{scene}.png"),
                      f"{what} (Mitsuba 3, {c.test.variant}, {c.test.spp} spp)."))
        note = ("" if c.resolved else " The difference is within the noise floor: "
                "the two renders look alike at this spp."
                if c.within_noise else " The noise floor is more than a third of the difference: render with more "
                f"samples (about {c.spp_to_resolve()} spp) to resolve it.")
        items.append((_save_png(comparison_image(c.reference.radiance, c.test.radiance,
                                                 ("reference\n" + ref_name, "model\n" + model.name),
                                                 alpha=c.reference.alpha, alpha_test=c.test.alpha,
                                                 difference=c.difference),
                                out / f"compare_{scene}.png"),
                      f"{what}: reference | model | relative difference (scale from 0 to 20 %, or to the 99th "
                      "percentile where that is higher, as its bar says). Mean image difference "
                      f"{100 * c.difference:.2f} % over the object's pixels; noise floor {100 * c.noise_floor:.2f} % "
                      f"(two renders of the reference with different seeds); corrected for it "
                      f"{100 * c.corrected:.2f} %.{note}"))
    return items, comparisons


#: The file every report folder holds: a folder with it is an earlier report, which a new one
#: replaces as a whole; another non-empty folder is refused.
REPORT_MARKER = "viewer.html"


def write_report(model_path: str | Path, out_dir: str | Path, reference: str | Path | None = None,
                 spp: int | None = None, render: bool = True) -> Path:
    """Write the HTML report of one model (see the module docstring); returns the page.

    Parameters
    ----------
    model_path
        The model file; its ``.json`` summary beside it, when present, adds the normal tilt,
        the model error, the shake verdict and isotropy.
    out_dir
        The report's folder, written whole or not at all (:func:`reflecto.io.atomic_folder`):
        an earlier report there (one holding :data:`REPORT_MARKER`) is replaced, a folder of
        other files refused.
    reference
        A reference BRDF file: adds the comparisons, its θ_h–θ_d image and the normalized
        eq. 10 error and log-RMSE as ``reflecto compare`` gives them
        (:func:`~reflecto.evaluate.metrics.comparison_error`: every half-vector azimuth where
        either BRDF is anisotropic).
    spp
        Samples per pixel of the renders; ``None``: each scene's default.
    render
        Whether to render with Mitsuba (``False``: no render section).

    Returns
    -------
    pathlib.Path
        ``out_dir / "index.html"``.

    Raises
    ------
    FileFormatError
        The model's summary is not a JSON object.
    """

    model_path = Path(model_path)
    model = load_model(model_path)
    ref = load_source(reference) if reference is not None else None
    with atomic_folder(out_dir, marker=REPORT_MARKER) as tmp:
        _write_report_into(tmp, model_path, model, ref, reference, spp, render)
    return Path(out_dir) / "index.html"


def _model_device(model: Any) -> Device | None:
    """The device the model's capture was taken with, by its name in the model's metadata
    (a built-in device; the ideal one where the metadata name none, as for analytic and
    external BRDFs); ``None`` for a device the name does not identify."""
    name = model.metadata.get("device") if isinstance(getattr(model, "metadata", None), dict) else None
    if not name:
        return load_device("ideal")
    if not isinstance(name, str) or name not in DEVICE_BUILTINS:
        return None
    return load_device(name)


def _write_report_into(out: Path, model_path: Path, model: Any, ref: BRDFSource | None,
                       reference: str | Path | None, spp: int | None, render: bool) -> None:
    """:func:`write_report`'s files, written into the (temporary) folder ``out``."""
    figs: list[tuple[str, list[tuple[str, str]]]] = []
    numbers: dict[str, Any] = {
        "η (R, G, B)": "∞: constant Fresnel, F ≡ 1" if is_constant(model.eta) else np.round(model.eta, 4).tolist(),
        "k_d (R, G, B)": np.round(model.kd, 4).tolist(),
        "k_s (R, G, B)": np.round(model.ks, 4).tolist(),
        **({} if model.tint is None else {
            "specular colour k_s·τ (R, G, B) at θ_d": "; ".join(
                f"{np.degrees(t):.1f}°: {np.round(model.ks * v, 4).tolist()}"
                for t, v in zip(model.tint.theta, model.tint.values))
            + ("" if model.tint.beyond == "constant" else
               f"; beyond {np.degrees(model.tint.trend_from or model.tint.theta[-1]):.1f}°: "
               "the nodes' trend continued")}),
        "NDF": model.parameters().get("resolution", "isotropic" if model.isotropic else "anisotropic"),
        # the angles the reconstruction's energy limit checks, as the summary's albedo_max
        f"max directional albedo (θ_i {ALBEDO_ANGLES[0]:g}–{ALBEDO_ANGLES[-1]:g}°)": round(float(model.albedo(np.array(
            albedo_angles(model, ALBEDO_ANGLES))).max()), 4),
    }
    summary_path = model_path.with_suffix(".json")
    summary = read_json(summary_path) if summary_path.is_file() else {}
    if not isinstance(summary, dict):
        raise FileFormatError(summary_path, "a model summary must be a JSON object")
    if summary.get("preview") is True:
        numbers["preview"] = ("yes: the first look `watch` writes (one light fit; no tint, lobe per node or eq. 3 "
                              "test); its full model replaces it")
    unplaced = summary.get("normal_source") == UNPLACED  # a preview whose peaks placed no normal: tilt unknown
    if unplaced:
        numbers["normal tilt (deg)"] = "not placed (no compact specular peak; the model is in the device frame)"
    for key, label in (("normal_tilt_deg", "normal tilt (deg)"), ("normal_uncertainty_deg", "its uncertainty (deg)"),
                       ("model_error", "relative model error ε of the fit"),
                       ("shake_detected", "shake detected"), ("isotropic", "isotropic")):
        if key in summary and summary[key] is not None and not (unplaced and key.startswith("normal_")):
            v = summary[key]
            numbers[label] = round(v, 4) if isinstance(v, float) else v
    if render:
        items, comparisons = render_figures(model, ref, out, spp)
        figs.append(("Renders", items))
        for scene, c in comparisons.items():
            numbers[f"mean image difference, {scene} (noise floor; corrected)"] = (
                f"{100 * c.difference:.2f} % ({100 * c.noise_floor:.2f} %; {100 * c.corrected:.2f} %)")
    figs.append(("Normal distribution", ndf_figures(model, out)))
    items = [(theta_h_theta_d_image(model, out, "thd_model.png", "model: θ_h–θ_d at φ_d = 90°"),
              "Model, BRDF Explorer's θ_h–θ_d view.")]
    if ref is not None:

        items.append((theta_h_theta_d_image(ref, out, "thd_reference.png", "reference: θ_h–θ_d at φ_d = 90°"),
                      "Reference."))
        err = comparison_error(ref, model)  # as `reflecto compare`: every half-vector azimuth where one is anisotropic
        numbers[f"eq. 10 error vs reference ({err.describe()}, normalized, %)"] = round(100 * err.normalized, 3)
        numbers["log-RMSE vs reference"] = round(err.log_rmse, 5)
    figs.append(("θ_h–θ_d slice", items))
    cap_dir = model.metadata.get("capture")
    dev = _model_device(model)  # the capture's own device where its folder is read below
    items = []
    got = (slice_figure(Path(cap_dir), out, model.metadata.get("calibration"))
           if cap_dir and Path(cap_dir).is_dir() else None)
    if isinstance(got, tuple):
        items.append((got[0], f"The slices of {html.escape(shown_path(cap_dir))} ({html.escape(shown_path(got[2]))})."))
        dev = got[1]
    elif isinstance(got, str):
        numbers["capture slices"] = f"not shown: the capture cannot be read ({got})"
    elif cap_dir or model.metadata.get("capture_not_found"):
        numbers["capture slices"] = ("not shown: the model names the capture "
                                     f"{cap_dir or model.metadata['capture_not_found']}, "
                                     "which is not a capture folder inside the model's folder")
    if dev is not None:
        cov = plot_coverage(dev.optics, dev.leds, out / "coverage.png", occluder_deg=dev.occluder_deg)
        items.insert(0, (cov.name, f"Half-vector coverage per LED of device {html.escape(dev.name)} "
                                   "(paper Fig. 2(c)(d))."))
    else:
        numbers["half-vector coverage"] = (f"not shown: the model's device {model.metadata.get('device')!s} is not a "
                                           "built-in one and its capture folder is not found")
    figs.append(("Capture", items))

    viewer_sources = [("model: " + shown_path(model_path.stem), model)] + (
        [("reference: " + shown_path(ref.name), ref)] if ref is not None else [])
    write_viewer(viewer_sources, out / "viewer.html", envmap=default_envmap())
    rows = "\n".join(f"<tr><th>{html.escape(k)}</th><td>{html.escape(str(v))}</td></tr>" for k, v in numbers.items())
    sections = []
    for title, its in figs:
        body = "\n".join(f'<figure><img src="{html.escape(url_quote(f))}" alt="{html.escape(html.unescape(c))}">'
                         f'<figcaption>{c}</figcaption></figure>'
                         for f, c in its)
        sections.append(f"<h2>{html.escape(title)}</h2>\n{body}")
    title = f"reflecto report: {html.escape(shown_path(model_path.name))}"
    page = (f"<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{title}</title>{_STYLE}</head>\n"
            f"<body data-images=\"pending\">\n<h1>{title}</h1>\n"
            f"<p>Model file <code>{html.escape(shown_path(model_path))}</code>"
            + (f", reference <code>{html.escape(shown_path(reference))}</code>" if reference else "") + "</p>\n"
            "<p><a href=\"viewer.html\">Interactive BRDF viewer</a>: lit sphere with a draggable light, θ_h–θ_d "
            "slice with read-outs, incidence-plane plots"
            + (", model and reference side by side" if ref is not None else "")
            + " (a static page; works from file://).</p>\n"
            f"<h2>Numbers</h2>\n<table>\n{rows}\n</table>\n" + "\n".join(sections)
            + f"\n{_CHECK_SCRIPT}\n</body></html>\n")
    with atomic_write(out / "index.html", "w") as fh:
        fh.write(page)


def write_index(entries: list[dict[str, Any]], out_dir: str | Path, title: str = "reflecto sweep") -> Path:
    """An index page linking per-material reports: ``entries`` of ``{name, href, numbers...}``.

    Parameters
    ----------
    entries
        One dict per material: ``name``, ``href`` (the report's link; empty or missing: no
        link) and further columns, taken from the first entry's keys (floats to 4
        significant digits).
    out_dir
        The folder ``index.html`` is written to.
    title
        The page's title.

    Returns
    -------
    pathlib.Path
        ``out_dir / "index.html"``.
    """
    out = Path(out_dir)
    keys = [k for k in entries[0] if k not in ("name", "href")] if entries else []
    head = "".join(f"<th>{html.escape(k)}</th>" for k in ["material", *keys])
    rows = []
    for e in entries:
        link = (f'<a href="{html.escape(url_quote(e["href"]))}">{html.escape(shown_path(e["name"]))}</a>'
                if e.get("href") else html.escape(shown_path(e["name"])))
        cells = "".join(f"<td>{html.escape(_fmt(e.get(k)))}</td>" for k in keys)
        rows.append(f"<tr><td>{link}</td>{cells}</tr>")
    page = ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>{html.escape(title)}</title>{_STYLE}"
            f"</head>\n<body data-images=\"pending\">\n<h1>{html.escape(title)}</h1>\n<table>\n<tr>{head}</tr>\n"
            + "\n".join(rows) + f"\n</table>\n{_CHECK_SCRIPT}\n</body></html>\n")
    index = out / "index.html"
    with atomic_write(index, "w") as fh:
        fh.write(page)
    return index


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return "" if v is None else str(v)
