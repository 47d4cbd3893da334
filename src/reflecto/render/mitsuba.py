"""Rendering any BRDF source with Mitsuba 3 (``measured`` plugin on an RGL tensor file).

A source that is not already an RGL ``.bsdf`` file is exported to one first
(:func:`reflecto.export.rgl.export_rgl`, into a temporary folder), so reference
BRDFs (MERL, NBRDF, analytic) and reconstructions render through the same plugin and
the same tables. Scenes (all 256×256 by default, path tracer, seeded):

* ``sphere-point``: a unit sphere lit by a point light up and to the left (the scene
  of :func:`reflecto.render.sphere.render_sphere`, which evaluates the BRDF directly);
* ``sphere-env``: the sphere under an environment map;
* ``teapot-env``: the Utah teapot (``shared/data/meshes/teapot.obj``) under an
  environment map; the BSDF is two-sided since the mesh's winding is not ours.

The variant is ``llvm_ad_rgb`` where LLVM ≥ 16 is found, else ``scalar_rgb``
(:mod:`reflecto.mitsuba_support`).
"""

from __future__ import annotations

import math
import os
import tempfile
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..errors import FileFormatError, ParameterError
from ..sources.base import BRDFSource
from .sphere import CAMERA, FOV_DEG, INTENSITY, LIGHT, TARGET, UP

Array = NDArray[np.float64]

SCENES = ("sphere-point", "sphere-env", "teapot-env")
#: Shared data folder: ``$REFLECTO_SHARED`` or ``../shared/data`` beside the project checkout.
SHARED = Path(os.environ.get("REFLECTO_SHARED", Path(__file__).resolve().parents[3].parent / "shared" / "data"))


def default_envmap() -> Path:
    return SHARED / "envmaps" / "pmndrs_studio.hdr"


def check_envmap(path: str | Path) -> Path:
    """Refuse a missing or unreadable environment map with a clear error."""
    path = Path(path)
    if not path.is_file():
        raise FileFormatError(path, "environment map not found")
    try:
        import imageio.v3 as iio

        img = iio.imread(path)
    except Exception as e:  # noqa: BLE001 - any decoder failure is "unreadable"
        raise FileFormatError(path, f"unreadable environment map ({e.__class__.__name__}: {e})") from None
    if img.ndim != 3 or img.shape[2] < 3 or not np.all(np.isfinite(img)):
        raise FileFormatError(path, f"environment map must be a finite RGB image, got shape {img.shape}")
    return path


def bsdf_file(source: BRDFSource, folder: Path) -> Path:
    """An RGL file for ``source``: its own file if it is one, else a fresh export in ``folder``."""
    from ..sources.rgl import RGLBRDF

    if isinstance(source, RGLBRDF):
        return Path(source.path)
    from ..export.rgl import export_rgl

    return export_rgl(source, folder / "source.bsdf")


def _teapot_transform(mi, mesh: Path):  # type: ignore[no-untyped-def]
    v = np.array([list(map(float, line.split()[1:4])) for line in mesh.read_text().splitlines() if line.startswith("v ")])
    lo, hi = v.min(axis=0), v.max(axis=0)
    centre = 0.5 * (lo + hi)
    s = 2.0 / float(np.max(hi - lo))
    return mi.ScalarTransform4f().scale(s) @ mi.ScalarTransform4f().translate((-centre).tolist())


def scene_dict(mi, scene: str, bsdf_path: Path, envmap: Path | None, resolution: int, spp: int, seed: int = 0) -> dict:  # type: ignore[no-untyped-def]
    """The Mitsuba scene description of one of :data:`SCENES`."""
    if scene not in SCENES:
        raise ParameterError(f"unknown scene {scene!r}; choose one of {', '.join(SCENES)}")
    T = mi.ScalarTransform4f
    bsdf = {"type": "measured", "filename": str(bsdf_path)}
    d: dict = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 4},
        "sensor": {
            "type": "perspective",
            "fov": FOV_DEG,
            "to_world": T().look_at(origin=list(CAMERA), target=list(TARGET), up=list(UP)),
            "film": {"type": "hdrfilm", "width": resolution, "height": resolution, "rfilter": {"type": "box"}},
            "sampler": {"type": "independent", "sample_count": spp, "seed": seed},
        },
    }
    if scene == "sphere-point":
        # the same light as the direct renderer (reflecto.render.sphere), to compare with it
        d["light"] = {"type": "point", "position": list(LIGHT), "intensity": {"type": "rgb", "value": INTENSITY}}
    else:
        env = check_envmap(envmap or default_envmap())
        d["light"] = {"type": "envmap", "filename": str(env), "scale": 1.0}
    if scene == "teapot-env":
        mesh = SHARED / "meshes" / "teapot.obj"
        if not mesh.is_file():
            raise FileFormatError(mesh, "teapot mesh not found (shared data missing)")
        d["shape"] = {"type": "obj", "filename": str(mesh), "to_world": _teapot_transform(mi, mesh),
                      "bsdf": {"type": "twosided", "material": bsdf}}
    else:
        d["shape"] = {"type": "sphere", "bsdf": bsdf}
    return d


def render(source: BRDFSource, scene: str = "sphere-env", envmap: str | Path | None = None,
           resolution: int = 256, spp: int = 64, seed: int = 0) -> tuple[Array, str]:
    """Render ``source``; returns the linear RGB image ``(resolution, resolution, 3)`` and the variant."""
    if resolution < 8 or resolution > 4096:
        raise ParameterError(f"resolution must be in [8, 4096], got {resolution}")
    if spp < 1:
        raise ParameterError(f"spp must be >= 1, got {spp}")
    if scene not in SCENES:
        raise ParameterError(f"unknown scene {scene!r}; choose one of {', '.join(SCENES)}")
    if envmap is not None:
        check_envmap(envmap)
    from ..mitsuba_support import import_mitsuba

    mi, variant = import_mitsuba("llvm_ad_rgb")
    with tempfile.TemporaryDirectory(prefix="reflecto-render-") as tmp:
        path = bsdf_file(source, Path(tmp))
        sc = mi.load_dict(scene_dict(mi, scene, path, Path(envmap) if envmap else None, resolution, spp, seed))
        img = np.array(mi.render(sc, spp=spp, seed=seed), dtype=np.float64)[..., :3]
    return img, variant


# ------------------------------------------------------------------- images
def to_srgb8(img: Array, exposure: float = 1.0) -> NDArray[np.uint8]:
    """Linear RGB → 8-bit sRGB (clipped), for PNG output."""
    x = np.clip(np.nan_to_num(img * exposure), 0.0, 1.0)
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.round(s * 255).astype(np.uint8)


def save_image(img: Array, path: str | Path) -> Path:
    """Write a linear image as ``.exr``/``.hdr`` (float) or ``.png`` (sRGB), atomically."""
    import imageio.v3 as iio

    from ..io import atomic_path

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".png", ".exr", ".hdr"):
        raise ParameterError(f"{path}: image format must be .png, .exr or .hdr")
    with atomic_path(path, suffix=suffix) as tmp:
        if suffix == ".png":
            iio.imwrite(tmp, to_srgb8(img))
        elif suffix == ".exr":
            from ..mitsuba_support import import_mitsuba

            mi, _ = import_mitsuba("llvm_ad_rgb")
            mi.Bitmap(np.ascontiguousarray(img, dtype=np.float32)).write(str(tmp))
        else:
            iio.imwrite(tmp, np.ascontiguousarray(img, dtype=np.float32), extension=".hdr")
    return path


def image_difference(reference: Array, test: Array) -> float:
    """Mean relative image difference ``mean|a − b| / mean|a|`` (over all pixels and channels)."""
    return float(np.mean(np.abs(test - reference)) / max(float(np.mean(np.abs(reference))), 1e-12))


def comparison_image(reference: Array, test: Array, labels: tuple[str, str] = ("reference", "ours")) -> NDArray[np.uint8]:
    """Side by side: reference | test | relative-difference heat map (0–20 %), 8-bit sRGB."""
    from matplotlib import colormaps

    lum = lambda a: a @ np.array([0.2126, 0.7152, 0.0722])  # noqa: E731
    rel = np.abs(lum(test) - lum(reference)) / np.maximum(lum(reference), 0.02 * max(float(lum(reference).max()), 1e-12))
    heat = (colormaps["inferno"](np.clip(rel / 0.2, 0.0, 1.0))[..., :3] * 255).astype(np.uint8)
    gap = np.full((reference.shape[0], 4, 3), 255, np.uint8)
    return np.concatenate([to_srgb8(reference), gap, to_srgb8(test), gap, heat], axis=1)


def exposure_for(img: Array) -> float:
    """Exposure mapping the 99th luminance percentile to 0.9 (for previews)."""
    p = float(np.percentile(img @ np.array([0.2126, 0.7152, 0.0722]), 99))
    return 0.9 / p if p > 0 and math.isfinite(p) else 1.0
