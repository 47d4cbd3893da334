"""Rendering any BRDF source with Mitsuba 3 (``measured`` plugin on an RGL tensor file),
and comparing two BRDFs by their renders.

A source that is not already an RGL ``.bsdf`` file is exported to one first
(:func:`reflecto.export.rgl.export_rgl`, into a temporary folder), so reference
BRDFs (MERL, NBRDF, analytic) and reconstructions render through the same plugin and
the same tables. Scenes (256×256 by default, low-discrepancy sampler, seeded):

* ``sphere-point``: a unit sphere under the key and fill point lights of
  :mod:`reflecto.render.sphere` (which evaluates the BRDF directly), rendered with
  Mitsuba's ``direct`` integrator from light samples alone: with point lights only
  the pixel footprint is sampled, so the image is free of noise but for antialiasing
  (two seeds differ by ~0.1 %);
* ``sphere-env``: the sphere under an environment map, ``direct`` integrator with one
  light and one BSDF sample per path (multiple importance sampling); exact for a
  convex object, which sees nothing but the environment;
* ``teapot-env``: the Utah teapot (``shared/data/meshes/teapot.obj``) under an
  environment map, path tracer to depth 4 (it reflects itself); the BSDF is two-sided
  since the mesh's winding is not ours.

The environment itself is hidden: every render has an alpha channel (the object's
coverage) and is composited onto a grey background for display
(:meth:`Rendering.image`); comparisons use the object's pixels only.

Samples per pixel default to :data:`DEFAULT_SPP`: the spp at which two renders of one
BRDF with different seeds differ by ≤ 1.5 % (:func:`image_difference`; measured on a
reconstructed chrome and a GGX plastic, see docs/mitsuba.md).

The variant is ``llvm_ad_rgb`` where LLVM ≥ 16 is found, else ``scalar_rgb``
(:mod:`reflecto.mitsuba_support`).
"""

from __future__ import annotations

import atexit
import contextlib
import dataclasses
import hashlib
import math
import os
import shutil
import tempfile
import textwrap
import time
from collections.abc import Iterator
from pathlib import Path

import cv2
import imageio.v3 as iio
import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from ..brdf import BRDFSource
from ..colour import LUM
from ..errors import FileFormatError, OutputError, ParameterError, one_line
from ..export.rgl import export_rgl
from ..io import atomic_path
from ..mitsuba_support import import_mitsuba
from ..plotting import pyplot
from ..sources.rgl import RGLBRDF
from .sphere import BACKGROUND, CAMERA, FOV_DEG, LIGHTS, TARGET, UP, composite

Array = NDArray[np.float64]

SCENES = ("sphere-point", "sphere-env", "teapot-env")
#: Samples per pixel of each scene when none is given (see the module docstring).
DEFAULT_SPP = {"sphere-point": 64, "sphere-env": 256, "teapot-env": 1024}
#: Shared data folder: ``$REFLECTO_SHARED`` or ``../shared/data`` beside the project checkout.
SHARED = Path(os.environ.get("REFLECTO_SHARED", Path(__file__).resolve().parents[3].parent / "shared" / "data"))


def default_envmap() -> Path:
    """The shared studio environment map, ``SHARED/envmaps/pmndrs_studio.hdr`` (``SHARED``: the
    ``REFLECTO_SHARED`` environment variable, else ``../shared/data`` beside the project).

    Returns
    -------
    pathlib.Path
        The map's path (not checked; :func:`check_envmap` does).
    """
    return SHARED / "envmaps" / "pmndrs_studio.hdr"


@contextlib.contextmanager
def _opencv_quiet() -> Iterator[None]:
    """OpenCV's log silenced within the block (restored after)."""
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
    try:
        yield
    finally:
        cv2.utils.logging.setLogLevel(level)


def utf8_name(path: Path) -> bool:
    """Whether ``path`` can be handed to Mitsuba or the image writers, which take file names
    as UTF-8 text.

    Parameters
    ----------
    path
        A file name.

    Returns
    -------
    bool
        False for a name of bytes that are not UTF-8 (read by Python as surrogate escapes).
    """
    try:
        str(path).encode("utf-8")
    except UnicodeEncodeError:  # a name of bytes that are not UTF-8 (surrogate escapes)
        return False
    return True


#: The fewest pixels along either side of an environment map (Mitsuba's ``envmap`` interpolates between pixels).
MIN_ENVMAP_PIXELS = 2


def read_envmap(path: str | Path) -> NDArray[np.float64]:
    """An environment map as Mitsuba's ``envmap`` emitter reads it: linear RGB, ``(H, W, 3)``.

    Read by Mitsuba's own image reader (Radiance ``.hdr``, OpenEXR, PFM, PNG, JPEG, …; 8-bit
    sRGB images linearized), so that what is accepted here is what renders; without
    Mitsuba by OpenCV (which reads ``.hdr`` as floating point, not clipped to 8 bits).

    Parameters
    ----------
    path
        The environment map.

    Returns
    -------
    numpy.ndarray of shape (H, W, 3)
        Linear RGB radiance (the map's own scale).

    Raises
    ------
    FileFormatError
        Missing, a name Mitsuba cannot take (not valid UTF-8), unreadable, not RGB, or
        with a non-finite or negative pixel.
    """
    path = Path(path)
    if not path.is_file():
        raise FileFormatError(path, "environment map not found")
    if not utf8_name(path):
        raise FileFormatError(path, "the file's name is not valid UTF-8, which Mitsuba cannot open: rename it")
    unreadable = ("unreadable environment map: no decoder reads it as an image (damaged, truncated, or not a "
                  "Radiance .hdr, OpenEXR or other image file Mitsuba reads)")
    try:
        mi, _ = import_mitsuba("llvm_ad_rgb")
    except ImportError:
        mi = None
    try:
        if mi is not None:
            bmp = mi.Bitmap(str(path)).convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.Float32, srgb_gamma=False)
            img = np.array(bmp, dtype=np.float64)
        else:
            with _opencv_quiet():
                raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
            if raw is None or raw.ndim != 3 or raw.shape[2] < 3:
                raise ValueError(unreadable)
            img = raw[..., 2::-1].astype(np.float64)  # BGR → RGB
            if raw.dtype.kind in "ui":  # an 8- or 16-bit image: sRGB-encoded
                img = img / (255.0 if raw.dtype == np.uint8 else 65535.0)
                img = np.where(img <= 0.04045, img / 12.92, ((img + 0.055) / 1.055) ** 2.4)
    except Exception:  # noqa: BLE001 - any decoder failure is "unreadable"
        raise FileFormatError(path, unreadable) from None
    if img.ndim != 3 or img.shape[2] < 3 or not np.all(np.isfinite(img)):
        raise FileFormatError(path, f"environment map must be a finite RGB image, got shape {img.shape}")
    if min(img.shape[:2]) < MIN_ENVMAP_PIXELS:  # a header of 0 × 0 decodes to an empty image that crashes Mitsuba
        raise FileFormatError(path, f"environment map of {img.shape[1]} × {img.shape[0]} pixels: at least "
                              f"{MIN_ENVMAP_PIXELS} × {MIN_ENVMAP_PIXELS} needed")
    if np.any(img[..., :3] < 0):  # radiance is not negative: such a map would light with negative light
        raise FileFormatError(path, f"environment map has negative values (down to {float(img[..., :3].min()):.3g}); "
                              "radiance is at least 0")
    return img[..., :3]


def check_envmap(path: str | Path) -> Path:
    """Refuse a missing or unreadable environment map with a clear error (:func:`read_envmap`).

    Parameters
    ----------
    path
        The environment map (any image Mitsuba's ``envmap`` reads, e.g. ``.hdr``, ``.exr``).

    Returns
    -------
    pathlib.Path
        ``path``, once it is read as a finite RGB image.

    Raises
    ------
    FileFormatError
        As :func:`read_envmap`.
    """
    read_envmap(path)
    return Path(path)


def bsdf_file(source: BRDFSource, folder: Path) -> Path:
    """An RGL file for ``source``: its own file if it is one (through a link in ``folder`` where
    its name is not valid UTF-8, which Mitsuba cannot open), else a fresh export in ``folder``.

    Parameters
    ----------
    source
        The BRDF.
    folder
        Where the export (or the link) goes, as ``source.bsdf``.

    Returns
    -------
    pathlib.Path
        The ``.bsdf`` file to render.
    """

    if isinstance(source, RGLBRDF):
        if utf8_name(Path(source.path)):
            return Path(source.path)
        link = folder / "source.bsdf"  # Mitsuba takes UTF-8 names: a link of such a name to the file
        os.symlink(os.path.abspath(source.path), link)
        return link

    return export_rgl(source, folder / "source.bsdf")


def _teapot_transform(mi, mesh: Path):
    v = np.array([list(map(float, line.split()[1:4]))
                  for line in mesh.read_text().splitlines() if line.startswith("v ")])
    lo, hi = v.min(axis=0), v.max(axis=0)
    centre = 0.5 * (lo + hi)
    s = 2.0 / float(np.max(hi - lo))
    return mi.ScalarTransform4f().scale(s) @ mi.ScalarTransform4f().translate((-centre).tolist())


_MESH_FOLDER: list[Path] = []  # this process's private folder of smoothed meshes, made on first use


def _mesh_folder() -> Path:
    """This process's private folder for :func:`smooth_mesh`'s copies (removed at exit)."""
    if not _MESH_FOLDER:
        folder = Path(tempfile.mkdtemp(prefix="reflecto-mesh-"))
        atexit.register(shutil.rmtree, folder, True)
        _MESH_FOLDER.append(folder)
    return _MESH_FOLDER[0]


def smooth_mesh(mesh: Path) -> Path:
    """A welded, smooth-shaded copy of an OBJ triangle mesh (the shared data is never edited).

    The shared ``teapot.obj`` has no normals and repeats the vertices of its patch
    seams, so a renderer shades it faceted with a seam. Vertices at the same position
    (to 10⁻⁵ of the mesh size) are merged, triangles that collapse are dropped, and
    each vertex gets the angle-weighted mean of its triangles' normals (≈ 0.1 s for the
    teapot). The copy is made once per process, in a folder of its own (created private by
    :func:`tempfile.mkdtemp`, removed at exit): a copy in a shared temporary folder under a
    name anyone can predict could be damaged or planted by another program or user.

    Parameters
    ----------
    mesh
        The OBJ file (``v`` and ``f`` lines; polygons are split into fans of triangles).

    Returns
    -------
    pathlib.Path
        The copy, ``<private tmp>/smooth-<hash of the mesh>.obj``, with ``vn`` normals.
    """
    raw = mesh.read_bytes()
    key = hashlib.sha256(raw).hexdigest()[:16]
    cached = _mesh_folder() / f"smooth-{key}.obj"
    if cached.is_file():
        return cached
    v, faces = [], []
    try:
        for line in raw.decode().splitlines():
            if line.startswith("v "):
                v.append([float(x) for x in line.split()[1:4]])
            elif line.startswith("f "):
                idx = [int(w.split("/")[0]) for w in line.split()[1:]]
                faces += [(idx[0], idx[k], idx[k + 1]) for k in range(1, len(idx) - 1)]
        pos = np.array(v, dtype=np.float64)
        f = np.array(faces, dtype=np.int64) - 1
        if pos.ndim != 2 or pos.shape[1] != 3 or len(f) == 0 or not np.all(np.isfinite(pos)) or f.min() < 0 \
                or f.max() >= len(pos):
            raise ValueError("no triangles over its vertices")
    except (ValueError, UnicodeDecodeError) as e:
        raise FileFormatError(mesh, f"not an OBJ mesh of 'v x y z' and 'f i j k' lines ({one_line(e)})") from None
    scale = float(np.max(pos.max(0) - pos.min(0)))
    _, weld, inverse = np.unique(np.round(pos / (1e-5 * scale)).astype(np.int64), axis=0, return_index=True,
                                 return_inverse=True)
    pos = pos[weld]
    f = inverse.reshape(-1)[f]
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    tri = pos[f]
    normals = np.zeros_like(pos)
    face_n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    face_n /= np.maximum(np.linalg.norm(face_n, axis=1, keepdims=True), 1e-300)
    for k in range(3):
        a = tri[:, (k + 1) % 3] - tri[:, k]
        b = tri[:, (k + 2) % 3] - tri[:, k]
        cosang = np.sum(a * b, 1) / np.maximum(np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1), 1e-300)
        np.add.at(normals, f[:, k], face_n * np.arccos(np.clip(cosang, -1, 1))[:, None])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in pos] + [f"vn {x:.6f} {y:.6f} {z:.6f}" for x, y, z in normals]
    lines += [f"f {a}//{a} {b}//{b} {c}//{c}" for a, b, c in f + 1]
    with atomic_path(cached, suffix=".obj") as tmp:
        Path(tmp).write_text("\n".join(lines) + "\n")
    return cached


def scene_dict(mi, scene: str, bsdf_path: Path, envmap: Path | None, resolution: int, spp: int, seed: int = 0,
               lights: tuple = LIGHTS) -> dict:
    """The Mitsuba scene description of one of :data:`SCENES` (``sphere-point``: with ``lights``).

    Parameters
    ----------
    mi
        The imported ``mitsuba`` module (variant set).
    scene
        One of :data:`SCENES`.
    bsdf_path
        The RGL ``.bsdf`` file of the ``measured`` BSDF.
    envmap
        Environment map of the ``*-env`` scenes; ``None``: :func:`default_envmap`.
    resolution
        Image width and height, pixels.
    spp
        Samples per pixel of the ``ldsampler``.
    seed
        Seed of the sampler.
    lights
        Point lights of ``sphere-point``: ``((position, intensity W/sr), ...)``.

    Returns
    -------
    dict
        The scene for ``mi.load_dict``: perspective sensor (RGBA film, box filter), the
        integrator, the lights and the shape.

    Raises
    ------
    ParameterError
        An unknown scene.
    FileFormatError
        A missing or unreadable environment map or teapot mesh.
    """
    if scene not in SCENES:
        raise ParameterError(f"unknown scene {scene!r}; choose one of {', '.join(SCENES)}")
    T = mi.ScalarTransform4f
    bsdf = {"type": "measured", "filename": str(bsdf_path)}
    d: dict = {
        "type": "scene",
        "sensor": {
            "type": "perspective",
            "fov": FOV_DEG,
            "to_world": T().look_at(origin=list(CAMERA), target=list(TARGET), up=list(UP)),
            "film": {"type": "hdrfilm", "width": resolution, "height": resolution, "pixel_format": "rgba",
                     "rfilter": {"type": "box"}},
            # stratified across a pixel's samples: 4-12× less noise than independent
            # samples at the same spp (sphere-env, 64 spp: 2.9 % vs 12.4 %)
            "sampler": {"type": "ldsampler", "sample_count": spp, "seed": seed},
        },
    }
    if scene == "sphere-point":
        # the lights of the direct renderer (reflecto.render.sphere), to compare with it
        d["integrator"] = {"type": "direct", "emitter_samples": 1, "bsdf_samples": 0, "hide_emitters": True}
        for k, (position, intensity) in enumerate(lights):
            d[f"light{k}"] = {"type": "point", "position": list(position),
                              "intensity": {"type": "rgb", "value": intensity}}
    else:
        env = check_envmap(envmap or default_envmap())
        d["light"] = {"type": "envmap", "filename": str(env), "scale": 1.0}
        if scene == "sphere-env":
            d["integrator"] = {"type": "direct", "emitter_samples": 1, "bsdf_samples": 1, "hide_emitters": True}
        else:
            d["integrator"] = {"type": "path", "max_depth": 4, "hide_emitters": True}
    if scene == "teapot-env":
        mesh = SHARED / "meshes" / "teapot.obj"
        if not mesh.is_file():
            raise FileFormatError(mesh, "teapot mesh not found (shared data missing)")
        d["shape"] = {"type": "obj", "filename": str(smooth_mesh(mesh)), "to_world": _teapot_transform(mi, mesh),
                      "bsdf": {"type": "twosided", "material": bsdf}}
    else:
        d["shape"] = {"type": "sphere", "bsdf": bsdf}
    return d


@dataclasses.dataclass
class Rendering:
    """One render.

    Attributes
    ----------
    radiance
        Linear RGB, ``(H, W, 3)``: the object's radiance times its pixel coverage
        (0 where only the background is).
    alpha
        The object's pixel coverage in [0, 1], ``(H, W)``.
    scene, spp, seed, variant
        What was rendered, how.
    seconds
        Wall time, including the export of a non-RGL source.
    """

    radiance: Array
    alpha: Array
    scene: str
    spp: int
    seed: int
    variant: str
    seconds: float

    def image(self, exposure: float = 1.0, background: float = BACKGROUND) -> Array:
        """The display image: the render composited onto a grey background (linear RGB).

        Parameters
        ----------
        exposure
            Factor applied to the radiance.
        background
            Linear grey behind the object.

        Returns
        -------
        numpy.ndarray, shape (H, W, 3)
            ``exposure·radiance + (1 − α)·background`` (:func:`reflecto.render.sphere.composite`).
        """
        return composite(self.radiance, self.alpha, exposure, background)


def sample_count(spp: int) -> int:
    """The samples per pixel the ``ldsampler`` takes for ``spp``: the next power of 4 (≥ 4).

    Mitsuba rounds up to a square power of two itself (128 renders as 256); doing it
    here keeps the count that a :class:`Rendering` reports the count it used.

    Parameters
    ----------
    spp
        Samples per pixel asked for.

    Returns
    -------
    int
        The smallest ``4^k ≥ spp`` (``k ≥ 1``).
    """
    n = 4
    while n < spp:
        n *= 4
    return n


#: Largest seed Mitsuba's samplers take (32-bit).
SAMPLER_MAX_SEED = 2**32 - 1
#: Largest seed of :func:`render` and :func:`compare`: the reference renders of a
#: comparison use ``seed + 1`` and ``seed + 2``, which must still be sampler seeds.
MAX_SEED = SAMPLER_MAX_SEED - 2


#: Most samples per pixel: Mitsuba's samplers count samples in 32 bits (a larger count is
#: refused by its scene parser), and 2²⁰ is far beyond a converged render of these scenes.
MAX_SPP = 2**20
#: The most samples one render may take (pixels × spp): a 4096² image at 512 spp, hours on a
#: workstation's CPU; beyond it a request is a typo rather than a render.
MAX_SAMPLES = 4096 * 4096 * 512


def check_render_settings(scene: str, resolution: int, spp: int | None, seed: int = 0,
                          max_seed: int = MAX_SEED) -> int:
    """Refuse render settings out of range before any work; returns the sample count to render with.

    Parameters
    ----------
    scene
        One of :data:`SCENES`.
    resolution
        Image side in pixels, in [8, 4096].
    spp
        Samples per pixel in [1, :data:`MAX_SPP`]; ``None``: the scene's default.
    seed, max_seed
        The sampler's seed, in [0, ``max_seed``].

    Returns
    -------
    int
        The samples per pixel rendered (:func:`sample_count`).

    Raises
    ------
    ParameterError
        A value out of range, naming it.
    """
    return _check(scene, resolution, spp, seed, max_seed)


def _check(scene: str, resolution: int, spp: int | None, seed: int = 0, max_seed: int = MAX_SEED) -> int:
    """Validated arguments; returns the sample count to render with."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= seed <= max_seed:
        raise ParameterError(f"seed must be an integer in [0, {max_seed}], got {seed}")
    if resolution < 8 or resolution > 4096:
        raise ParameterError(f"resolution must be in [8, 4096], got {resolution}")
    if scene not in SCENES:
        raise ParameterError(f"unknown scene {scene!r}; choose one of {', '.join(SCENES)}")
    spp = DEFAULT_SPP[scene] if spp is None else int(spp)
    if not 1 <= spp <= MAX_SPP:
        raise ParameterError(f"spp must be in [1, {MAX_SPP}], got {spp}")
    count = sample_count(spp)
    if resolution * resolution * count > MAX_SAMPLES:
        raise ParameterError(f"{resolution}² pixels × {count} spp is {resolution * resolution * count:.3g} samples, "
                             f"more than {MAX_SAMPLES:.3g} (days of rendering): lower --resolution or --spp")
    return count


def render_file(bsdf_path: Path, scene: str = "sphere-env", envmap: str | Path | None = None, resolution: int = 256,
                spp: int | None = None, seed: int = 0) -> Rendering:
    """Render an RGL ``.bsdf`` file (see :func:`render`).

    ``sphere-point`` is rendered once per point light and the images summed.

    Parameters
    ----------
    bsdf_path
        The RGL ``.bsdf`` file.
    scene
        One of :data:`SCENES`.
    envmap
        Environment map of the ``*-env`` scenes (default: :func:`default_envmap`); not
        used by ``sphere-point``.
    resolution
        Image width and height, pixels (8 to 4096).
    spp
        Samples per pixel, rounded up to a power of 4 (:func:`sample_count`); ``None``:
        the scene's :data:`DEFAULT_SPP`.
    seed
        Seed of the sampler.

    Returns
    -------
    Rendering
        Radiance ``(H, W, 3)`` and alpha ``(H, W)``, with the scene, spp, seed, Mitsuba
        variant and wall time.

    Raises
    ------
    ParameterError
        An unknown scene, a resolution outside [8, 4096], ``spp`` outside [1, :data:`MAX_SPP`] or a seed outside
        [0, :data:`SAMPLER_MAX_SEED`].
    FileFormatError
        A missing or unreadable environment map.
    """
    spp = _check(scene, resolution, spp, seed, SAMPLER_MAX_SEED)
    if envmap is not None:
        check_envmap(envmap)

    mi, variant = import_mitsuba("llvm_ad_rgb")
    t0 = time.perf_counter()
    env = Path(envmap) if envmap else None
    # one render per point light, summed: with both in one scene each sample picks one
    # light at random, and that choice alone put 9 % of noise on a sharp highlight
    groups = [(light,) for light in LIGHTS] if scene == "sphere-point" else [LIGHTS]
    img = None
    for lights in groups:
        sc = mi.load_dict(scene_dict(mi, scene, Path(bsdf_path), env, resolution, spp, seed, lights))
        part = np.array(mi.render(sc, spp=spp, seed=seed), dtype=np.float64)
        if img is None:
            img = part
        else:
            img[..., :3] += part[..., :3]
    assert img is not None  # groups is never empty
    return Rendering(img[..., :3], np.clip(img[..., 3], 0.0, 1.0), scene, spp, seed, variant, time.perf_counter() - t0)


def render(source: BRDFSource, scene: str = "sphere-env", envmap: str | Path | None = None,
           resolution: int = 256, spp: int | None = None, seed: int = 0) -> Rendering:
    """Render ``source`` in one of :data:`SCENES`; ``spp=None`` takes :data:`DEFAULT_SPP`.

    Parameters
    ----------
    source
        The BRDF; exported to a temporary RGL file unless it is one (:func:`bsdf_file`).
    scene
        One of :data:`SCENES`.
    envmap
        Environment map of the ``*-env`` scenes (default: :func:`default_envmap`); not
        used by ``sphere-point``.
    resolution
        Image width and height, pixels (8 to 4096).
    spp
        Samples per pixel, rounded up to a power of 4 (:func:`sample_count`); ``None``:
        the scene's :data:`DEFAULT_SPP`.
    seed
        Seed of the sampler.

    Returns
    -------
    Rendering
        As :func:`render_file`, its ``seconds`` including the export.

    Raises
    ------
    ParameterError
        An unknown scene, a resolution outside [8, 4096], ``spp`` outside [1, :data:`MAX_SPP`] or a seed outside
        [0, :data:`MAX_SEED`].
    """
    _check(scene, resolution, spp, seed)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="reflecto-render-") as tmp:
        r = render_file(bsdf_file(source, Path(tmp)), scene, envmap, resolution, spp, seed)
    r.seconds = time.perf_counter() - t0
    return r


# ---------------------------------------------------------------- comparison
def object_mask(*renders: Rendering) -> NDArray[np.bool_]:
    """Pixels that the object covers fully in every one of ``renders``.

    Parameters
    ----------
    *renders
        Renders of the same scene and resolution.

    Returns
    -------
    numpy.ndarray of bool, shape (H, W)
        ``alpha ≥ 1 − 10⁻⁶`` in all of them.
    """
    return np.logical_and.reduce([r.alpha >= 1.0 - 1e-6 for r in renders])


#: Standard deviation (pixels) of the Gaussian both renders are smoothed with before
#: they are compared: it averages out the pixel-scale, sign-alternating part of the
#: sampling noise (at 256 spp a reconstructed chrome under the studio map reads 2.3 %
#: between two seeds unsmoothed, 0.8 % smoothed) and keeps any difference that spans
#: more than a pixel, a one-pixel seam included (a line of one sign keeps its sum).
SMOOTHING_PX = 1.0


def image_difference(reference: Array, test: Array, mask: NDArray[np.bool_] | None = None,
                     smoothing: float = 0.0) -> float:
    """Mean image difference ``Σ|t − r| / Σ r`` over the pixels of ``mask`` and the three channels.

    The mean absolute difference relative to the mean reference radiance, on the
    object's pixels (all pixels without a mask); 0.05 reads "the renders differ by 5 %
    of the object's brightness, on average". With ``smoothing > 0`` both images are
    first convolved with a Gaussian of that standard deviation (pixels).

    Parameters
    ----------
    reference, test
        Linear RGB images, shape ``(H, W, 3)``.
    mask
        Pixels to compare, shape ``(H, W)`` (:func:`object_mask`); ``None``: all.
    smoothing
        Standard deviation of the Gaussian (pixels, over the two image axes, zero
        outside the image); 0: none.

    Returns
    -------
    float
        ``Σ|t − r| / Σ|r|`` (dimensionless; 0 for identical images).
    """
    r, t = np.asarray(reference, dtype=np.float64), np.asarray(test, dtype=np.float64)
    if smoothing > 0:

        sigma = (smoothing, smoothing) + (0,) * (r.ndim - 2)
        r, t = ndimage.gaussian_filter(r, sigma, mode="constant"), ndimage.gaussian_filter(t, sigma, mode="constant")
    if mask is not None:
        r, t = r[mask], t[mask]
    return float(np.sum(np.abs(t - r)) / max(float(np.sum(np.abs(r))), 1e-300))


@dataclasses.dataclass
class Comparison:
    """A test BRDF's render against a reference's, with the renders' own noise beside it.

    Attributes
    ----------
    difference
        :func:`image_difference` of the test render against the reference render
        (different seeds), on the pixels the object covers in all three renders, both
        smoothed by :data:`SMOOTHING_PX`.
    noise_floor
        The same between two renders of the reference with different seeds: what
        ``difference`` reads for two identical BRDFs.
    corrected
        ``√max(difference² − noise_floor², 0)``: an estimate of the difference without
        the noise, exact when the per-pixel differences and the noise add in
        quadrature; it reads low by up to ~15 % where they are of the same size.
    reference, reference_repeat, test
        The three renders.
    """

    difference: float
    noise_floor: float
    corrected: float
    reference: Rendering
    reference_repeat: Rendering
    test: Rendering

    @property
    def resolved(self) -> bool:
        """Whether the noise floor is below a third of the difference without the noise
        (``corrected``)."""
        return self.noise_floor < self.corrected / 3.0

    @property
    def within_noise(self) -> bool:
        """Whether the difference is no larger than two independent noisy renders would give
        (``corrected ≤ floor``; two black renders, both 0, are alike)."""
        return self.corrected <= self.noise_floor

    def spp_to_resolve(self) -> int:
        """The spp at which the floor would be a third of the corrected difference.

        The floor falls at least as ``spp^-½``; the current spp if it is resolved or the
        difference is within the noise (then no spp can be named).

        Returns
        -------
        int
            ``sample_count(⌈spp · (3 · noise_floor / corrected)²⌉)``, or the test render's spp.
        """
        if self.resolved or self.within_noise:
            return self.test.spp
        ratio = 3.0 * self.noise_floor / self.corrected
        return sample_count(int(math.ceil(self.test.spp * ratio * ratio)))

    def summary(self) -> str:
        """One line: the difference, the noise floor and the corrected estimate, in %.

        Returns
        -------
        str
            ``"mean image difference … % (noise floor … %, noise-corrected … %; scene, spp)"``.
        """
        return (f"mean image difference {100 * self.difference:.2f} % (noise floor {100 * self.noise_floor:.2f} %, "
                f"noise-corrected {100 * self.corrected:.2f} %; {self.test.scene}, {self.test.spp} spp)")


def compare(reference: BRDFSource, test: BRDFSource, scene: str = "sphere-env", envmap: str | Path | None = None,
            resolution: int = 256, spp: int | None = None, seed: int = 0,
            smoothing: float = SMOOTHING_PX) -> Comparison:
    """Render ``test`` (seed ``seed``) and ``reference`` twice (seeds ``seed + 1``, ``seed + 2``).

    The reference comes first, as in :func:`reflecto.evaluate.metrics.brdf_error` and
    ``reflecto compare REF TEST``.

    Parameters
    ----------
    reference, test
        The BRDFs to render.
    scene
        One of :data:`SCENES`.
    envmap
        Environment map of the ``*-env`` scenes (default: the shared studio map).
    resolution
        Image width and height, pixels.
    spp
        Samples per pixel (default: the scene's, :data:`DEFAULT_SPP`).
    seed
        Seed of the test's render (the reference's: ``seed + 1``, ``seed + 2``).
    smoothing
        Gaussian smoothing (pixels) before the difference; 0 compares pixel by pixel.

    Returns
    -------
    Comparison
        The mean image difference, its noise floor and the three renders.

    Raises
    ------
    ParameterError
        As :func:`render` (the seed at most :data:`MAX_SEED`, so that ``seed + 2`` is a sampler seed).
    """
    _check(scene, resolution, spp, seed)
    with tempfile.TemporaryDirectory(prefix="reflecto-compare-") as tmp:
        folder = Path(tmp)
        (folder / "t").mkdir()
        (folder / "r").mkdir()
        return compare_files(bsdf_file(reference, folder / "r"), bsdf_file(test, folder / "t"), scene, envmap,
                             resolution, spp, seed, smoothing)


def compare_files(reference: Path, test: Path, scene: str = "sphere-env", envmap: str | Path | None = None,
                  resolution: int = 256, spp: int | None = None, seed: int = 0,
                  smoothing: float = SMOOTHING_PX) -> Comparison:
    """:func:`compare` of two RGL files (:func:`bsdf_file`): several scenes of the same pair
    need each file written once.

    Parameters
    ----------
    reference, test
        The ``.bsdf`` files to render.
    scene, envmap, resolution, spp, seed, smoothing
        As :func:`compare`.

    Returns
    -------
    Comparison
        As :func:`compare`.

    Raises
    ------
    ParameterError
        As :func:`compare`.
    """
    _check(scene, resolution, spp, seed)
    r = render_file(reference, scene, envmap, resolution, spp, seed + 1)
    if not np.sum(np.abs(r.radiance)) > 0:  # the difference is relative to what the reference reflects
        raise ParameterError(f"{reference}: the reference renders black in scene {scene!r} (it reflects nothing "
                             "there), so the image difference relative to it is undefined")
    t = render_file(test, scene, envmap, resolution, spp, seed)
    r2 = render_file(reference, scene, envmap, resolution, spp, seed + 2)
    mask = object_mask(t, r, r2)
    diff = image_difference(r.radiance, t.radiance, mask, smoothing)
    floor = image_difference(r.radiance, r2.radiance, mask, smoothing)
    return Comparison(diff, floor, math.sqrt(max(diff * diff - floor * floor, 0.0)), r, r2, t)


# ------------------------------------------------------------------- images
def to_srgb8(img: Array, exposure: float = 1.0) -> NDArray[np.uint8]:
    """Linear RGB → 8-bit sRGB (clipped), for PNG output.

    Parameters
    ----------
    img
        Linear image, shape ``(H, W, 3)`` (NaN read as 0).
    exposure
        Factor applied before the clip to [0, 1].

    Returns
    -------
    numpy.ndarray of uint8, same shape
        The sRGB transfer function (``12.92 x`` up to 0.0031308, else
        ``1.055 x^(1/2.4) − 0.055``), times 255, rounded.
    """
    x = np.clip(np.nan_to_num(img * exposure), 0.0, 1.0)
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.round(s * 255).astype(np.uint8)


def save_image(img: Array, path: str | Path) -> Path:
    """Write a linear image as ``.exr``/``.hdr`` (float) or ``.png`` (sRGB), atomically.

    Parameters
    ----------
    img
        Linear RGB image, shape ``(H, W, 3)`` (a ``.png`` is converted by :func:`to_srgb8`).
    path
        The file; its suffix (``.png``, ``.exr`` or ``.hdr``, any case) chooses the format.

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    ParameterError
        Another suffix.
    """


    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".png", ".exr", ".hdr"):
        raise ParameterError(f"{path}: image format must be .png, .exr or .hdr")
    with atomic_path(path, suffix=suffix) as tmp:
        if suffix == ".png":
            iio.imwrite(tmp, to_srgb8(img))
        elif suffix == ".exr":

            mi, _ = import_mitsuba("llvm_ad_rgb")
            try:
                mi.Bitmap(np.ascontiguousarray(img, dtype=np.float32)).write(str(tmp))
            except RuntimeError as e:  # Mitsuba's FileStream: "…: I/O error while attempting to write N bytes: why"
                raise OutputError(path, f"cannot write: {str(e).rsplit(': ', 1)[-1]}") from None
        else:
            iio.imwrite(tmp, np.ascontiguousarray(img, dtype=np.float32), extension=".hdr")
    return path


def comparison_image(reference: Array, test: Array, labels: tuple[str, str] = ("reference", "ours"),
                     alpha: Array | None = None, alpha_test: Array | None = None,
                     exposure: float = 1.0, difference: float | None = None,
                     max_relative: float = 0.2) -> NDArray[np.uint8]:
    """Labelled side by side, 8-bit sRGB: reference | test | false-colour relative difference.

    The third panel is ``Σ_c |t − r|`` per pixel over the object's mean ``Σ_c r`` (its
    mean over the object is :func:`image_difference` without smoothing), from 0 to
    ``max_relative`` (raised to the 99th percentile where that is higher), with its
    colour bar; off the object it is white. Each panel is titled (``labels``); with
    ``difference`` (the mean image difference, :func:`image_difference`) the third
    panel's title states it.

    With ``alpha`` (the reference's coverage; ``alpha_test`` the test's, default the
    same) both renders are composited onto the grey background.

    Parameters
    ----------
    reference, test
        Linear RGB renders, shape ``(H, W, 3)``.
    labels
        Titles of the first two panels.
    alpha, alpha_test
        Coverage of the object in each, shape ``(H, W)``; ``None``: every pixel is the object.
    exposure
        Factor applied to both renders for display.
    difference
        The mean image difference to state in the third title; ``None``: not stated.
    max_relative
        Top of the colour scale (a fraction; 0.2 is 20 %).

    Returns
    -------
    numpy.ndarray of uint8, shape (H', W', 3)
        The figure as an RGB image (about ``H + 45`` by ``3W + 140`` pixels).
    """
    plt = pyplot()

    on = np.ones(reference.shape[:2], bool)
    if alpha is not None:
        a_test = alpha if alpha_test is None else alpha_test
        on = (alpha >= 1.0 - 1e-6) & (a_test >= 1.0 - 1e-6)
    # per pixel Σ_c |t − r| over the object's mean Σ_c r: its mean over the object is image_difference
    rel = np.abs(test - reference).sum(-1) / max(float(np.abs(reference[on]).sum(-1).mean()) if on.any() else 0.0,
                                                 1e-300)
    if alpha is not None:
        reference, test = composite(reference, alpha, exposure), composite(test, a_test, exposure)
        exposure = 1.0
    if on.any():
        p99 = float(np.percentile(rel[on], 99))
        if p99 > max_relative:
            max_relative = float(np.ceil(p99 * 10) / 10)
    shown = np.ma.masked_where(~on, rel * 100.0)
    cmap = plt.colormaps["inferno"].with_extremes(bad="white")
    h, w = rel.shape
    fig_w = 3 * w / 100 + 1.4
    fig_h = h / 100 + 0.45
    fig = plt.figure(figsize=(fig_w, fig_h), dpi=100)
    pw = (w / 100) / fig_w
    axes = [fig.add_axes((0.005 + k * (pw + 0.005), 0.01, pw, (h / 100) / fig_h)) for k in range(3)]
    axes[0].imshow(to_srgb8(reference, exposure))
    axes[1].imshow(to_srgb8(test, exposure))
    im = axes[2].imshow(shown, cmap=cmap, vmin=0.0, vmax=100.0 * max_relative)
    title = "difference" + (f"\nmean {100 * difference:.2f} %" if difference is not None else "")
    for ax, t in zip(axes, (labels[0], labels[1], title)):
        ax.set_title(t, fontsize=8, pad=2)
        ax.set_axis_off()
    cax = fig.add_axes((3 * (pw + 0.005) + 0.02, 0.1, 0.02, 0.7))
    bar = fig.colorbar(im, cax=cax)
    bar.set_label("|test − ref| / mean ref, %", fontsize=8)
    bar.ax.tick_params(labelsize=7)
    fig.canvas.draw()
    img = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
    plt.close(fig)
    return img


def titled(image: NDArray[np.uint8], title: str) -> NDArray[np.uint8]:
    """An 8-bit RGB image with ``title`` written in a white strip above it.

    Parameters
    ----------
    image
        The image, shape ``(H, W, 3)``, uint8.
    title
        The text, centred in the strip and wrapped at word boundaries into lines of at
        most ``W / 6.5`` characters (8-point text at 100 dpi is up to about 6 pixels a
        character), so that it fits the image's width.

    Returns
    -------
    numpy.ndarray of uint8, shape (H + 24 + 12 (n − 1), W, 3)
        The titled image, ``n`` the number of lines.
    """
    plt = pyplot()

    h, w = image.shape[:2]
    lines = textwrap.wrap(title, width=max(1, int(w / 6.5)), break_on_hyphens=False) or [""]
    strip = 24 + 12 * (len(lines) - 1)
    fig = plt.figure(figsize=(w / 100, (h + strip) / 100), dpi=100)
    ax = fig.add_axes((0, 0, 1, h / (h + strip)))
    ax.imshow(image)
    ax.set_axis_off()
    fig.text(0.5, 1 - 0.5 * strip / (h + strip), "\n".join(lines), ha="center", va="center", fontsize=8,
             linespacing=1.2)
    fig.canvas.draw()
    out = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
    plt.close(fig)
    return out


def exposure_for(img: Array) -> float:
    """Exposure mapping the 99th luminance percentile to 0.9 (for previews).

    Parameters
    ----------
    img
        Linear RGB image, shape ``(..., 3)``.

    Returns
    -------
    float
        ``0.9 / p99(luminance)``; 1 when that percentile is 0 or not finite.
    """
    p = float(np.percentile(img @ LUM, 99))
    return 0.9 / p if p > 0 and math.isfinite(p) else 1.0
