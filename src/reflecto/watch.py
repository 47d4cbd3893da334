"""``reflecto watch ROOT -o MODELS``: reconstruct each capture folder as it lands (the paper's
"instant": the operator sweeps the device from sample to sample).

The watcher polls ``ROOT`` (every :data:`POLL_S` seconds while idle) for capture folders
(docs/capture-format.md). A folder counts once it is complete: ``manifest.json``
parses as JSON and every frame it names exists and ends with the PNG end chunk
(:func:`capture_state`). ``reflecto simulate`` and :func:`~reflecto.instrument.capture.write_capture`
make a folder appear complete at once (written beside it under a hidden ``.NAME.*.part``
name, then renamed); a writer that copies files in one by one (frames first,
manifest last, or frames still growing) is waited for. A folder that stays incomplete
and unchanged for ``settle_s`` seconds, or that the reader refuses (a damaged frame,
a manifest that does not fit the device, a saturated capture), is reported once
(one line naming the folder and the problem) and skipped; if it changes later it is
looked at again, and one that leaves ``ROOT`` (removed, or renamed by its writer) is
forgotten. A modelled capture that leaves ``ROOT`` leaves the page with one line (its
files stay in ``MODELS``); one replaced or rewritten after its model (another folder
renamed into place, its manifest written again; looked at once a second,
:data:`IDENTITY_CHECK_S`) is modelled again. A folder whose name the models cannot carry
(not valid UTF-8, or too long for the file names made from it) is reported and skipped the
same way. A folder rewritten while its model was made is made again from what it holds then.

Each good capture is reconstructed by the function given as ``reconstruct_one``
(capture folder, model path → summary dict; default :func:`default_reconstructor`,
the code path of ``reflecto reconstruct``), into ``MODELS/<name>.reflecto`` and its
``.json`` summary, both written atomically (:func:`reflecto.io.atomic_write`). After
each model a thumbnail (``MODELS/thumbs/<name>.png``, a lit sphere,
:func:`thumbnail`) and the index page ``MODELS/index.html`` (name, tilt, η, thumbnail,
warnings and notes; the skipped folders with their problem) are rewritten atomically.
While the watch runs the page reloads itself every :data:`PAGE_REFRESH_S` seconds in a
browser; the page a finished or interrupted watch leaves does not.

**Previews first.** The full reconstruction takes about twice the device's 117 ms per
capture on one core, so a watcher that made only full models would fall further behind
with every capture of a sweep. With ``preview_one`` (:func:`default_previewer`,
:func:`reflecto.reconstruct.preview.preview`: the normal from the compact specular peaks,
one light fit, the motion cues that need no frame; about a third of the full path's
CPU) each capture first gets a preview model, summary (``"preview": true``) and index
row; the full reconstruction replaces each preview, oldest first, once no capture has
landed for ``refine_idle_s`` seconds (:data:`REFINE_IDLE_S`: the operator has stopped
sweeping, and a full model started then delays the next capture's preview by at most its
own time; with ``jobs`` worker processes, ``watch --jobs N``, N full models at a time, each
renamed into place here as its worker ends). A preview that fails gives way to the full
reconstruction; a full model that
fails leaves the preview, says why on the page, and is tried again when the folder
changes (one that failed after its file had replaced the preview's takes the preview
with it: the capture is listed as skipped, and made again by the next watch).

A capture whose ``.json`` summary exists in ``MODELS`` counts as done (a restarted watcher
carries on; a preview's summary queues its full reconstruction, ``--once`` too); a model
without its summary, or with one that does not read as a summary, is redone.

Ctrl-C (SIGINT), or SIGTERM, stops the watcher between two files: every file in
``MODELS`` is complete, and a model whose summary was not yet written is removed (with
the preview's summary and thumbnail where it replaced a preview: the capture is made
again).
"""

from __future__ import annotations

import dataclasses
import glob
import html
import math
import os
import pickle
import signal
import stat
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any
from urllib.parse import quote as url_quote

import cv2
import numpy as np

from . import workflow
from .batch import run_batch
from .brdf import BRDFSource
from .errors import FileFormatError, LimitError, ParameterError, ReflectoError, interrupted, one_line, shown_path
from .fresnel import eta_from_json, format_eta
from .instrument.capture import MANIFEST
from .io import MAX_DESCRIPTION_BYTES, atomic_write, make_parents, parse_json, read_input, read_json
from .kinds import is_model_file
from .model import load_model
from .reconstruct import Options
from .reconstruct.preview import PREVIEW_NOTE, UNPLACED
from .render.sphere import composite, render_sphere, sphere_coverage

#: Seconds between two looks at ROOT while nothing is ready.
POLL_S = 0.02
#: Seconds between two reloads of the index page in a browser while the watch runs.
PAGE_REFRESH_S = 2
#: A folder incomplete and unchanged for this long (seconds) is reported as damaged.
SETTLE_S = 5.0
#: Seconds between two looks at the modelled capture folders for a replaced or rewritten one.
IDENTITY_CHECK_S = 1.0
#: Side of the index page's thumbnails (pixels).
THUMB_PX = 48
#: Seconds without a new capture after which the previews are replaced by full models: ten
#: of the device's capture periods (117 ms), a pause in the sweep rather than a gap in it.
REFINE_IDLE_S = 1.0
#: The last 12 bytes of every complete PNG file: the empty IEND chunk with its CRC.
PNG_END = b"\x00\x00\x00\x00IEND\xaeB`\x82"

READY, WAITING = "ready", "waiting"

#: Bytes the longest file name the watcher makes for a capture adds to the capture's name:
#: a worker's hidden model ``..NAME.full.reflecto.XXXXXXXX`` (:func:`reflecto.io.atomic_write`'s
#: temporary file beside ``.NAME.full.reflecto``), with a margin.
NAME_OVERHEAD_BYTES = 32

#: (capture folder, model path) → the summary written beside the model.
Reconstructor = Callable[[Path, Path], dict]


class FolderReconstructor:
    """Capture folder, model path → summary: :func:`reflecto.workflow.reconstruct_folder` with
    fixed settings, which writes the model and its ``.json`` summary; it keeps the model it
    wrote last (:attr:`last`), so that the watcher's thumbnail need not read the file back.

    Parameters
    ----------
    calibration, options, missing, preview
        As for :func:`reflecto.workflow.reconstruct_folder`.
    """

    def __init__(self, calibration: str | None = None, options: Options | None = None,
                 missing: workflow.Missing = "refuse", preview: bool = False) -> None:
        self.calibration, self.options, self.missing, self.preview = calibration, options, missing, preview
        #: The model file written last and its model (``None`` before the first).
        self.last: tuple[Path, BRDFSource] | None = None

    def __call__(self, cap_dir: Path, out: Path) -> dict:
        """Reconstruct one capture folder into a model file and its ``.json`` summary.

        Parameters
        ----------
        cap_dir
            The capture folder.
        out
            The model file to write (the summary goes beside it).

        Returns
        -------
        dict
            The summary (:func:`reflecto.workflow.reconstruct_folder`); the model is kept in
            :attr:`last`.
        """
        self.last = None
        summary, result = workflow.folder_to_model(cap_dir, out, self.calibration, self.options, self.missing,
                                                   self.preview)
        self.last = (Path(out), result.model)
        return summary

    def __getstate__(self) -> dict[str, Any]:
        # sent to a worker process (``watch --jobs``) without the model it kept
        return {**self.__dict__, "last": None}


def _full_model(reconstruct_one: Reconstructor, cap_dir: Path, out: Path) -> dict:
    """One full model in a worker process (:meth:`Watcher.refine` with ``jobs > 1``): the
    model and its summary written to ``out`` (a hidden name the watcher renames)."""
    return reconstruct_one(cap_dir, out)


def default_reconstructor(calibration: str | None = None, options: Options | None = None,
                          missing: workflow.Missing = "refuse") -> FolderReconstructor:
    """The per-capture reconstruction of ``reflecto reconstruct`` with these settings.

    Parameters
    ----------
    calibration
        A calibration file for every capture, or None (then ``missing`` decides;
        :func:`reflecto.workflow.calibration_for`).
    options
        Reconstruction options (defaults if None).
    missing
        What to do without a calibration: ``"refuse"``, ``"nominal"`` or ``"simulate"``.

    Returns
    -------
    FolderReconstructor
        ``run(cap_dir, out) -> summary``: :func:`reflecto.workflow.reconstruct_folder`,
        which writes the model and its ``.json`` summary.
    """
    return FolderReconstructor(calibration, options, missing)


def default_previewer(calibration: str | None = None, options: Options | None = None,
                      missing: workflow.Missing = "refuse") -> FolderReconstructor:
    """The preview of each capture (:func:`reflecto.reconstruct.preview.preview`) with these settings.

    Parameters
    ----------
    calibration, options, missing
        As for :func:`default_reconstructor`.

    Returns
    -------
    FolderReconstructor
        ``run(cap_dir, out) -> summary``: :func:`reflecto.workflow.reconstruct_folder` with
        ``preview=True``, which writes the preview model and its ``.json`` summary.
    """
    return FolderReconstructor(calibration, options, missing, preview=True)


def _regular(path: Path) -> bool | None:
    """Whether ``path`` is a regular file (``None``: nothing there yet). Something else that
    is there (a FIFO, a device, a folder, a link loop) is not waited for: opening a FIFO
    would block the watch, and the reader refuses all of them with a line naming them."""
    try:
        return stat.S_ISREG(os.stat(path).st_mode)
    except FileNotFoundError:
        return None
    except (OSError, ValueError):  # ValueError: a NUL in a name the manifest gives
        return False


def _png_complete(path: Path) -> bool:
    """Whether the file ends with the PNG end chunk (a frame still being written does not)."""
    try:
        with open(path, "rb") as fh:
            fh.seek(0, os.SEEK_END)
            if fh.tell() < 45:  # signature + IHDR + IEND
                return False
            fh.seek(-12, os.SEEK_END)
            return fh.read(12) == PNG_END
    except OSError:
        return False


def capture_state(folder: Path) -> tuple[str, str]:
    """``(READY, "")`` when the capture folder is complete, else ``(WAITING, reason)``.

    Complete: ``manifest.json`` exists and parses as a JSON object, and every frame its
    ``frames`` list names (as a plain file name) exists and ends with the PNG end chunk.
    Whatever else is wrong with the folder (a damaged frame, a manifest that does not
    fit its device, a manifest or frame that is not a regular file) is the reader's to
    say: such a folder is ready, and refused there.

    Parameters
    ----------
    folder
        A capture folder, possibly still being written.

    Returns
    -------
    state : str
        :data:`READY` or :data:`WAITING`.
    reason : str
        Why it is waiting (empty when ready).
    """

    mpath = folder / MANIFEST
    regular = _regular(mpath)
    if regular is None:
        return WAITING, f"no {MANIFEST} yet"
    if not regular:
        return READY, ""
    try:  # the reader's limits: a manifest too large or nested too deep is the reader's to refuse
        manifest = parse_json(read_input(mpath, MAX_DESCRIPTION_BYTES, "a manifest"), mpath)
    except LimitError:
        return READY, ""
    except FileFormatError as e:  # gone meanwhile, unreadable, or not (yet) valid JSON
        if _regular(mpath) is None:
            return WAITING, f"no {MANIFEST} yet"
        return WAITING, f"{MANIFEST}: {e.problem}"
    frames = manifest.get("frames") if isinstance(manifest, dict) else None
    if not isinstance(frames, list):
        return READY, ""
    for f in frames:
        name = f.get("file") if isinstance(f, dict) else None
        if not isinstance(name, str) or not name or Path(name).name != name:
            continue
        p = folder / name
        regular = _regular(p)
        if regular is None:
            return WAITING, f"frame {name} is missing"
        if not regular:
            return READY, ""
        if not _png_complete(p):
            return WAITING, f"frame {name} is incomplete (no PNG end chunk)"
    return READY, ""


def _stat(path: Path) -> tuple[int, int, int] | None:
    """Inode, size and modification time of a file (``None`` where there is none): a change means it was rewritten."""
    try:
        st = path.stat()
    except OSError:
        return None
    return st.st_ino, st.st_size, st.st_mtime_ns


def _identity(folder: Path) -> tuple:
    """A folder's inode and modification time and its manifest's status: cheap to look at
    again, and changed by a capture renamed into place or a manifest written again."""
    return _stat(folder), _stat(folder / MANIFEST)


def _signature(folder: Path) -> tuple:
    """Names, sizes and modification times of a folder's files: a change means a writer is at work."""
    def entry(e: os.DirEntry) -> tuple[str, int, int]:
        try:
            st = e.stat()
        except OSError:  # a dangling link: its own status, so that the rest still counts
            try:
                st = e.stat(follow_symlinks=False)
            except OSError:
                return e.name, -1, -1
        return e.name, st.st_size, st.st_mtime_ns

    try:
        with os.scandir(folder) as it:
            return tuple(sorted(entry(e) for e in it))
    except OSError:
        return ()


def thumbnail(model: BRDFSource, size: int = THUMB_PX) -> bytes:
    """A lit sphere of ``model`` as a PNG (:func:`reflecto.render.sphere.render_sphere`: key and fill point lights).

    Parameters
    ----------
    model
        Any BRDF.
    size
        Image side, pixels.

    Returns
    -------
    bytes
        PNG of ``size × size`` sRGB-encoded 8-bit RGB pixels on the renders' grey
        background, exposure 1.
    """


    rad = render_sphere(model, resolution=size, supersample=1)
    img = np.clip(composite(rad, sphere_coverage(size, 1)), 0.0, 1.0)
    srgb = np.where(img <= 0.0031308, 12.92 * img, 1.055 * np.power(img, 1 / 2.4) - 0.055)
    ok, buf = cv2.imencode(".png", np.ascontiguousarray((255 * srgb + 0.5).astype(np.uint8)[..., ::-1]))
    if not ok:  # pragma: no cover - OpenCV encodes any uint8 image
        raise ReflectoError("could not encode a thumbnail")
    return buf.tobytes()


def warnings_of(summary: dict[str, Any]) -> list[str]:
    """The warnings a summary carries, as plain lines: what asks the operator to capture
    again or differently.

    Parameters
    ----------
    summary
        A reconstruction summary (the model's ``.json``).

    Returns
    -------
    list of str
        Shake detected, symmetry of eq. 3 broken.
    """
    out = []
    if summary.get("shake_detected") is True:
        motion = summary.get("motion")
        out.append("shake detected" + (f" ({motion})" if isinstance(motion, str) and motion else ""))
    sym = summary.get("symmetry_test")
    if isinstance(sym, dict) and sym.get("decided") is True and sym.get("symmetric") is False:
        out.append("symmetry of eq. 3 broken (capture rotations for §5.5)")
    return out


def notes_of(summary: dict[str, Any]) -> list[str]:
    """The summary's notes (the tilt found, parameters at a bound, a hidden peak, ...), as plain lines.

    Parameters
    ----------
    summary
        A reconstruction summary (the model's ``.json``).

    Returns
    -------
    list of str
        Its ``notes``; none where they are not a list.
    """
    notes = summary.get("notes")
    # a summary written by another program, or damaged, may hold anything: only a list of notes is read
    return [str(n) for n in notes] if isinstance(notes, list) else []


def _number(value: Any, default: float = math.nan) -> float:
    """``value`` as a float where it is a finite JSON number, else ``default``."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        return default
    return float(value)


@dataclasses.dataclass
class Entry:
    """One modelled capture on the index page.

    Attributes
    ----------
    name
        The capture folder's name.
    tilt_deg
        The sample normal's tilt from the device axis (degrees; NaN where not known yet).
    eta
        η as the page shows it.
    warnings, notes
        :func:`warnings_of` and :func:`notes_of` of its summary (a preview's without the
        note that says it is one).
    seconds
        The reconstruction's wall time.
    preview
        Whether the model is a preview (module docstring).
    """

    name: str
    tilt_deg: float
    eta: str
    warnings: list[str]
    seconds: float
    notes: list[str] = dataclasses.field(default_factory=list)
    preview: bool = False


class Watcher:
    """Polls ``root`` and reconstructs each complete capture folder into ``models`` (module docstring).

    Parameters
    ----------
    root, models
        The folder the captures land in, the folder the models are written to.
    reconstruct_one
        Capture folder, model path → summary (writes the model and its ``.json``);
        default :func:`default_reconstructor`.
    settle_s
        An incomplete folder unchanged for this long is reported (seconds).
    report
        Receives each one-line problem (default: ``reflecto: watch: …`` on stderr).
    thumbnails
        Render the index page's thumbnails.
    announce
        Receives each capture's entry, summary and latency (seconds) once its model,
        summary and index are written, the preview's and then the full model's (default:
        nothing).
    preview_one
        Capture folder, model path → summary of a preview (module docstring, *Previews
        first*); ``None``: every capture gets its full model at once.
    refine_idle_s
        Seconds without a new capture before previews are replaced by full models.
    jobs
        Worker processes that make the full models replacing the previews, several at once
        (``reconstruct_one`` must then be picklable, as :class:`FolderReconstructor` is);
        1: one at a time in this process.
    """

    def __init__(self, root: str | Path, models: str | Path, reconstruct_one: Reconstructor | None = None,
                 settle_s: float = SETTLE_S, report: Callable[[str], None] | None = None,
                 thumbnails: bool = True,
                 announce: Callable[[Entry, dict[str, Any], float], None] | None = None,
                 preview_one: Reconstructor | None = None, refine_idle_s: float = REFINE_IDLE_S,
                 jobs: int = 1) -> None:
        if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
            raise ParameterError(f"watch: jobs must be a positive number of processes, got {jobs!r}")
        self.jobs = jobs
        self.root = Path(root)
        self.reconstruct_one = reconstruct_one or default_reconstructor()
        if jobs > 1:  # sent to the worker processes
            try:
                pickle.dumps(self.reconstruct_one)
            except Exception as e:  # noqa: BLE001 — any pickling failure says the same
                raise ParameterError(f"watch: with jobs > 1 the reconstruction must be picklable (a module-level "
                                     f"function or a FolderReconstructor), not {self.reconstruct_one!r} "
                                     f"({type(e).__name__})") from None
        self.models = Path(models)
        self.preview_one = preview_one
        self.refine_idle_s = refine_idle_s
        self.settle_s = settle_s
        self.report = report or (lambda line: print(f"reflecto: watch: {line}", file=sys.stderr, flush=True))
        self.thumbnails = thumbnails
        self.announce = announce
        self._interrupted = False  # a Ctrl-C or SIGTERM arrived (run)
        # the models folder's name where it lies directly in the watched folder: never a capture
        try:
            self._models_here = self.models.name if self.models.resolve().parent == self.root.resolve() else None
        except OSError:
            self._models_here = None
        self.entries: dict[str, Entry] = {}
        self.failed: dict[str, str] = {}
        self._failed_sig: dict[str, tuple] = {}
        self._waiting: dict[str, tuple[tuple, float, str]] = {}
        #: Seconds from a capture found complete to its first model (the preview, or the
        #: full model without previews), summary and index written.
        self.latency: dict[str, float] = {}
        #: ``time.monotonic()`` at which each capture's first model, summary and index were written.
        self.finished_at: dict[str, float] = {}
        #: Seconds from a capture found complete to its full model (after its preview), summary and index.
        self.full_latency: dict[str, float] = {}
        #: Captures whose model is a preview, oldest first, with ``time.monotonic()`` when found complete.
        self.previews: dict[str, float] = {}
        self._busy_at = time.monotonic()  # when the last capture was found complete
        self._rows: dict[str, tuple[tuple, str]] = {}  # the page's rows by capture: (their content, HTML)
        self._live = False  # the watch loop runs: the page reloads itself
        self._name_max: int | None = None  # the file system's longest file name (bytes), once asked
        #: Each modelled capture's folder as its model was made from it (:func:`_identity`):
        #: a folder replaced or rewritten since is modelled again.
        self._made_from: dict[str, tuple] = {}
        self._stale: set[str] = set()  # modelled captures whose folder changed: made again, not adopted
        self._identity_checked = -math.inf  # time.monotonic() of the last look at the modelled folders

    # ------------------------------------------------------------------ scanning
    def _candidates(self) -> list[Path]:
        try:
            with os.scandir(self.root) as it:  # hidden names: a writer's folder before its rename
                names = sorted(e.name for e in it if e.is_dir() and not e.name.startswith("."))
        except FileNotFoundError:
            names = []
        except OSError as e:
            raise ReflectoError(f"{shown_path(self.root)}: cannot list the folder ({e.strerror or e})") from None
        self._forget_gone(set(names))
        self._find_rewritten()
        # a capture with a model is looked at again where its full model failed (a preview
        # stays), once its folder changes, and where its folder was replaced or rewritten
        return [self.root / n for n in names
                if (n not in self.entries or n in self.failed or n in self._stale) and n != self._models_here]

    def _find_rewritten(self) -> None:
        """Mark the modelled captures whose folder was replaced or rewritten since (a new
        folder renamed into place, or its manifest written again): their model is of other
        data, and is made again. Two file statuses per capture, looked at once per
        :data:`IDENTITY_CHECK_S` (a sweep's thousand captures would otherwise cost 10⁵
        statuses a second)."""
        now = time.monotonic()
        if now - self._identity_checked < IDENTITY_CHECK_S:
            return
        self._identity_checked = now
        changed = [name for name, made in self._made_from.items()
                   if name not in self._stale and name in self.entries and _identity(self.root / name) != made]
        for name in changed:
            self._stale.add(name)
            self.previews.pop(name, None)  # its full model is of the new data, made afresh
            self.entries[name].warnings.append("the capture folder changed since: being modelled again")
        if changed:
            self._write_index()

    def _forget_gone(self, present: set[str]) -> None:
        """Forget the folders waited for or refused that have left ``root`` (removed, or
        renamed by their writer): their state would grow with every folder a sweep leaves behind,
        and the page would list them as skipped for good."""
        gone = [n for n in self._waiting if n not in present]
        for n in gone:
            del self._waiting[n]
        dropped = [n for n in self.failed if n not in present]
        for n in dropped:
            del self.failed[n]
            self._failed_sig.pop(n, None)
        # a modelled capture that left: its files stay in MODELS, its row (and a preview's
        # pending full model) goes, as a new watch of ROOT would not list it either
        left = [n for n in self.entries if n not in present and n != self._models_here]
        for n in left:
            preview = self.entries.pop(n).preview
            self._rows.pop(n, None)
            self.previews.pop(n, None)
            self._made_from.pop(n, None)
            self._stale.discard(n)
            self.report(f"{shown_path(self.root / n)}: the capture folder left the watched folder; its "
                        f"{'preview' if preview else 'model'} stays in {shown_path(self.models)}, off the page")
        if dropped or left:
            self._write_index()

    def _name_problem(self, name: str) -> str | None:
        """Why a folder of this name cannot be modelled (``None``: it can): the models' file
        names are the capture's name with a suffix, so it must be valid UTF-8 (the page and the
        summaries are) and leave room for the suffixes within the file system's limit."""
        raw = os.fsencode(name)
        try:
            raw.decode("utf-8")
        except UnicodeDecodeError:
            return "the folder's name is not valid UTF-8: rename it"
        if self._name_max is None:
            try:
                self._name_max = os.pathconf(self.models if self.models.is_dir() else self.root, "PC_NAME_MAX")
            except (OSError, ValueError):
                self._name_max = 255
        limit = self._name_max
        if len(raw) + NAME_OVERHEAD_BYTES > limit:
            return (f"the folder's name is {len(raw)} bytes; its models' file names need at most "
                    f"{limit - NAME_OVERHEAD_BYTES} (the file system allows {limit} per name): rename it")
        return None

    def _done(self, name: str) -> bool:
        """A model of ``name`` is in ``models``: its summary, and a model file whose structure
        reads (an empty or truncated one, left by a crash or another program, is made again)."""
        return (self.models / f"{name}.json").exists() and is_model_file(self.models / f"{name}.reflecto")

    def scan(self, final: bool = False) -> int:
        """Look at ``root`` once: model every complete folder not yet done, report the damaged ones.

        Parameters
        ----------
        final
            Report an incomplete folder at once instead of waiting for it (``--once``).

        Returns
        -------
        int
            The number of models written.
        """
        made = adopted = 0
        for folder in self._candidates():
            name = folder.name
            if name in self.failed:
                sig = _signature(folder)
                if sig == self._failed_sig.get(name):
                    continue
                del self.failed[name]  # changed since it was reported: look again
            problem = self._name_problem(name)
            if problem is not None:
                self._fail(folder, problem)
                continue
            if (self._done(name) and name not in self._waiting and name not in self._stale
                    and self._adopt(name, now=time.monotonic())):
                adopted += 1
                continue
            state, why = capture_state(folder)
            now = time.monotonic()
            if state == WAITING:
                self._still_incomplete(folder, why, _signature(folder), final)
                continue
            self._waiting.pop(name, None)
            self._busy_at = now
            # the folder as it was found complete: a refusal is looked at again once it differs
            # (a writer that finishes while the reader refuses its half-written frame)
            sig = _signature(folder)
            if self._model(folder, now, preview=self.preview_one is not None and not final, sig=sig):
                made += 1
            if self._interrupted:  # a Ctrl-C that something on the way swallowed: stop between captures
                raise KeyboardInterrupt
        if adopted and not made:  # an earlier watch's models: the page lists them as they are now
            self._write_index()
        return made

    def _still_incomplete(self, folder: Path, why: str, sig: tuple, final: bool) -> bool:
        """An incomplete folder (``why``, its signature ``sig``): waited for while it changes,
        reported once unchanged for ``settle_s`` seconds (at once with ``final``). Returns
        whether it is still waited for."""
        name, now = folder.name, time.monotonic()
        seen = self._waiting.get(name)
        if seen is None or seen[0] != sig:
            self._waiting[name] = (sig, now, why)
        if final or now - self._waiting[name][1] >= self.settle_s:
            held = "" if final else f" for {self.settle_s:g} s"
            self._fail(folder, f"incomplete capture: {why} (unchanged{held})", sig)
            return False
        return True

    def _fail(self, folder: Path, problem: str, sig: tuple | None = None) -> None:
        name = folder.name
        self._waiting.pop(name, None)
        self.failed[name] = problem
        self._failed_sig[name] = _signature(folder) if sig is None else sig
        if name in self.entries:  # its preview stays, and says why no full model follows
            self.entries[name].warnings.append(f"no full model: {one_line(problem)}")
        self.report(one_line(f"{shown_path(folder)}: {problem}" if not problem.startswith(str(folder))
                             else shown_path(problem)))
        self._write_index()

    def _adopt(self, name: str, now: float) -> bool:
        """A model made before this watcher started: listed on the page, not redone (a
        preview is queued for its full model). Returns whether it was adopted: a summary that
        the checking reader refuses (huge numbers, not an object) does not count, and the
        capture is made again, as one without its summary is."""
        try:
            summary = read_json(self.models / f"{name}.json")
        except ReflectoError:
            return False
        if not isinstance(summary, dict):
            return False
        self.entries[name] = self._entry(name, summary)
        self._made_from[name] = _identity(self.root / name)
        if self.entries[name].preview:
            self.previews[name] = now
        if self.thumbnails:
            self._refresh_thumbnail(name)
        return True

    def _refresh_thumbnail(self, name: str) -> None:
        """Render the thumbnail of an earlier model where it is missing or older than the
        summary (a watch stopped between a full model's summary and its thumbnail)."""
        thumb, summary = self.models / "thumbs" / f"{name}.png", self.models / f"{name}.json"
        try:
            if thumb.exists() and thumb.stat().st_mtime_ns >= summary.stat().st_mtime_ns:
                return
            png = thumbnail(load_model(self.models / f"{name}.reflecto"))
            with atomic_write(thumb) as fh:
                fh.write(png)
        except (ReflectoError, OSError) as e:
            self.entries[name].warnings.append(f"no thumbnail ({one_line(e)})")

    def _entry(self, name: str, summary: dict[str, Any]) -> Entry:
        eta = eta_from_json(summary)
        preview = summary.get("preview") is True
        notes = notes_of(summary)
        tilt = _number(summary.get("normal_tilt_deg"))
        if preview:  # the page's model column says it is a preview; a tilt no peak placed is not known yet
            notes = [n for n in notes if n != PREVIEW_NOTE]
            if summary.get("normal_source") == UNPLACED:
                tilt = math.nan
        return Entry(name, tilt, "?" if eta is None else format_eta(eta), warnings_of(summary),
                     _number(summary.get("seconds"), 0.0), notes, preview)

    def refine(self, final: bool = False) -> bool:
        """Replace the oldest preview by the capture's full model (module docstring).

        A capture folder being rewritten since its preview waits at the end of the queue,
        and is reported (its preview stays) once incomplete and unchanged for ``settle_s``
        seconds, or at once with ``final``. A refused capture is reported and keeps its
        preview, with the reason among its warnings; it is looked at again when its folder
        changes.

        Parameters
        ----------
        final
            Report a folder that is incomplete now instead of waiting for it (``--once``).

        Returns
        -------
        bool
            Whether a full model was written (``False``: no preview waits, the capture waits
            for its writer, or it was refused and reported).
        """
        batch = self._ready_previews(final)
        if self.jobs == 1 or len(batch) == 1:
            return any([self._model(self.root / name, found, preview=False, refining=True, sig=sig)
                        for name, found, sig in batch])
        return self._refine_in_workers(batch)

    def _ready_previews(self, final: bool) -> list[tuple[str, float, tuple]]:
        """The oldest previews whose folders are complete, at most :attr:`jobs` (name, when found,
        the folder's signature); a folder being rewritten goes back to the end of the queue or,
        incomplete and unchanged for ``settle_s`` (or at once with ``final``), is reported."""
        batch: list[tuple[str, float, tuple]] = []
        back: list[tuple[str, float]] = []
        while self.previews and len(batch) < self.jobs:
            name = next(iter(self.previews))
            found = self.previews.pop(name)
            folder = self.root / name
            state, why = capture_state(folder)
            sig = _signature(folder)
            if state == WAITING:
                if self._still_incomplete(folder, why, sig, final):
                    back.append((name, found))
                continue
            self._waiting.pop(name, None)
            batch.append((name, found, sig))
        self.previews.update(back)  # behind the others
        return batch

    def _refine_in_workers(self, batch: list[tuple[str, float, tuple]]) -> bool:
        """The full models of ``batch`` made in :attr:`jobs` worker processes
        (:func:`reflecto.batch.run_batch`), each written under a hidden name and renamed into
        place here, model first, as its worker ends (an interrupt between the two renames is
        handled as in :meth:`_model`); the hidden files are removed whatever happens."""
        hidden = [self.models / f".{name}.full.reflecto" for name, _, _ in batch]
        made, handled = [], set()
        make_parents(self.models)

        def arrived(k: int, ok: bool, value: Any, seconds: float) -> None:
            name, found, sig = batch[k]
            folder = self.root / name
            handled.add(name)
            if not ok:  # the worker's one-line message (a refusal, or an internal error)
                self._fail(folder, str(value), sig)
            elif _signature(folder) != sig:  # rewritten meanwhile: made again from what is there now
                self.previews[name] = found
            else:
                made.append(self._install(name, found, value, hidden[k]))

        try:
            items = [(self.reconstruct_one, self.root / name, h) for (name, _, _), h in zip(batch, hidden)]
            run_batch(_full_model, items, [str(self.root / name) for name, _, _ in batch], self.jobs, arrived,
                      ignore_interrupt=True)
        finally:
            for name, found, _ in batch:  # the workers are gone: their hidden files, whole or not, go too
                stem = glob.escape(f".{name}.full.")
                for h in [*self.models.glob(stem + "*"), *self.models.glob("." + stem + "*")]:
                    h.unlink(missing_ok=True)
                if name not in handled and name not in self.failed:  # not made: still a preview
                    self.previews.setdefault(name, found)
        return any(made)

    def _install(self, name: str, found: float, summary: dict, hidden: Path) -> bool:
        """Rename a full model made by a worker (``hidden`` and its summary) into place, then
        thumbnail, page and announcement as :meth:`_model` does."""
        out = self.models / f"{name}.reflecto"
        summary_path = out.with_suffix(".json")
        before = (_stat(out), _stat(summary_path))
        try:
            os.replace(hidden, out)
            os.replace(hidden.with_suffix(".json"), summary_path)
        except OSError as e:  # as a reconstruction in this process that cannot write its files
            self._discard_half_written(name, True, before)
            self._fail(self.root / name, f"{e.filename or out}: {one_line(e.strerror or e)}")
            return False
        except BaseException:
            self._discard_half_written(name, True, before)
            raise
        self._finish(name, summary, out, found, True, None)
        return True

    def _model(self, folder: Path, found: float, preview: bool = False, refining: bool = False,
               sig: tuple | None = None) -> bool:
        """Reconstruct one capture (its preview, or its full model; ``refining``: the full
        model that replaces its preview); a refused one is reported and remembered with the
        folder's signature ``sig`` as it was found complete. A preview that fails gives way
        to the full reconstruction at once."""

        name = folder.name
        out = self.models / f"{name}.reflecto"
        summary_path = out.with_suffix(".json")
        had_summary = summary_path.exists()  # a preview's, which the full model replaces
        before = (_stat(out), _stat(summary_path))
        make_parents(self.models)
        make = self.preview_one if preview and self.preview_one is not None else self.reconstruct_one

        try:
            summary = make(folder, out)
        except ReflectoError as e:
            self._discard_half_written(name, had_summary, before)
            if make is not self.reconstruct_one:  # the preview failed: the full reconstruction may not
                return self._model(folder, found, sig=sig)
            self._fail(folder, one_line(e), sig)
            return False
        except MemoryError:
            self._discard_half_written(name, had_summary, before)
            self._fail(folder, "out of memory (see docs/limits.md for the input limits)", sig)
            return False
        except OSError as e:
            self._discard_half_written(name, had_summary, before)
            self._fail(folder, f"{e.filename or folder}: {one_line(e.strerror or e)}", sig)
            return False
        except Exception as e:  # a fault of one capture's reconstruction must not stop the watch
            self._discard_half_written(name, had_summary, before)
            if interrupted(e):  # Ctrl-C inside a compiled kernel: an interrupt, not the capture's fault
                raise KeyboardInterrupt from e
            self._fail(folder, f"reconstruction failed ({type(e).__name__}: {one_line(e)})", sig)
            return False
        except BaseException:  # interrupted, possibly between the model and its summary
            self._discard_half_written(name, had_summary, before)
            raise
        kept = getattr(make, "last", None)  # a FolderReconstructor's model: not read back
        self._stale.discard(name)
        if sig is not None:
            self._made_from[name] = _identity(folder)
        self._finish(name, summary, out, found, refining, kept[1] if isinstance(kept, tuple) and kept[0] == out
                     else None)
        if sig is not None and _signature(folder) != sig:  # rewritten meanwhile: made again from what is there now
            self.previews[name] = found
        return True

    def _discard_half_written(self, name: str, had_summary: bool, before: tuple) -> None:
        """After a failed or interrupted model of ``name``: a model written without its summary
        is removed; where it replaced a preview whose summary (``before``: the model's and the
        summary's stat) is still there, the preview's summary, model and thumbnail go too (they
        would contradict each other), and its row: the capture is made again once its folder
        changes, or by the next watch."""
        out = self.models / f"{name}.reflecto"
        summary_path = out.with_suffix(".json")
        if not had_summary:
            if not summary_path.exists():
                out.unlink(missing_ok=True)
        elif _stat(out) != before[0] and _stat(summary_path) == before[1]:
            for p in (out, summary_path, self.models / "thumbs" / f"{name}.png"):
                p.unlink(missing_ok=True)
            self.entries.pop(name, None)
            self._rows.pop(name, None)
            self.previews.pop(name, None)

    def _finish(self, name: str, summary: dict, out: Path, found: float, refining: bool,
                model: BRDFSource | None) -> None:
        """A model and its summary written: the page's row, the thumbnail (of ``model``, or of the
        file read back), the page, the latency and the announcement; a preview joins the queue."""
        self.entries[name] = self._entry(name, summary)
        if self.thumbnails:
            try:
                png = thumbnail(model if model is not None else load_model(out))
                with atomic_write(self.models / "thumbs" / f"{name}.png") as fh:
                    fh.write(png)
            except ReflectoError as e:
                self.entries[name].warnings.append(f"no thumbnail ({one_line(e)})")
            except OSError as e:  # a full disk: the model stands, without its sphere
                self.entries[name].warnings.append(f"no thumbnail ({one_line(e.strerror or e)})")
            except Exception as e:  # a fault of the renderer must not stop the watch either
                if interrupted(e):
                    raise KeyboardInterrupt from e
                self.entries[name].warnings.append(f"no thumbnail ({type(e).__name__}: {one_line(e)})")
        self._write_index()
        done = time.monotonic()
        if refining:  # the full model after its preview
            self.full_latency[name] = done - found
        else:
            self.finished_at[name] = done
            self.latency[name] = done - found
        if self.entries[name].preview:
            self.previews[name] = found
        if self.announce is not None:
            self.announce(self.entries[name], summary, done - found)

    # ------------------------------------------------------------------ the page
    def _row(self, e: Entry, thumb: bool) -> str:
        """One capture's row of the page, remembered by its content: a sweep of many captures
        rewrites the page after each, and formats only the rows that changed."""
        tilt = "–" if not math.isfinite(e.tilt_deg) else f"{e.tilt_deg:.2f}°"
        key = (e.name, tilt, e.eta, tuple(e.warnings), tuple(e.notes), e.preview, thumb)
        row = self._rows.get(e.name)
        if row is not None and row[0] == key:
            return row[1]
        esc = html.escape
        img = (f'<img src="thumbs/{esc(url_quote(os.fsencode(e.name)))}.png" width="{THUMB_PX}" '
               f'height="{THUMB_PX}" alt="">' if thumb else "")
        model = "preview" if e.preview else "full"
        warn = "<br>".join([f"<strong>{esc(w)}</strong>" for w in e.warnings] + [esc(n) for n in e.notes]) or "–"
        text = (f'<tr><td><a href="{esc(url_quote(os.fsencode(e.name)))}.json">{esc(shown_path(e.name))}</a></td>'
                f'<td>{model}</td>'
                f"<td>{tilt}</td><td>{esc(e.eta)}</td><td>{img}</td><td>{warn}</td></tr>")
        self._rows[e.name] = (key, text)
        return text

    def _write_index(self) -> None:
        """Rewrite ``MODELS/index.html`` atomically: one row per model, then the skipped folders."""

        try:  # the thumbnails there are: one listing, not a look-up per row
            with os.scandir(self.models / "thumbs") as it:
                thumbs = {d.name for d in it}
        except OSError:
            thumbs = set()
        rows = [self._row(e, f"{e.name}.png" in thumbs) for e in sorted(self.entries.values(), key=lambda e: e.name)]
        esc = html.escape
        skipped = "".join(f"<li>{esc(shown_path(n))}: {esc(shown_path(p))}</li>"
                          for n, p in sorted(self.failed.items()))
        waiting = sum(e.preview and e.name not in self.failed for e in self.entries.values())
        pending = f" ({waiting} previews, their full models to follow)" if waiting else ""
        reload = f'<meta http-equiv="refresh" content="{PAGE_REFRESH_S}">' if self._live else ""
        page = (f"<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\">{reload}<title>reflecto watch: "
                f"{esc(shown_path(self.root))}</title>\n<style>body{{font-family:sans-serif}}td{{padding:2px 8px;"
                "vertical-align:middle}</style></head><body>\n"
                f"<h1>Models of {esc(shown_path(self.root))}</h1>\n<p>{len(self.entries)} models{pending}, "
                f"{len(self.failed)} skipped.</p>\n<table>\n<tr><th>capture</th><th>model</th><th>tilt</th>"
                "<th>η</th><th>sphere</th>"
                "<th>warnings and notes</th></tr>\n" + "\n".join(rows) + "\n</table>\n"
                + (f"<h2>Skipped</h2>\n<ul>{skipped}</ul>\n" if skipped else "") + "</body></html>\n")
        make_parents(self.models)
        with atomic_write(self.models / "index.html", "w") as fh:
            fh.write(page)

    # ------------------------------------------------------------------ the loop
    def run(self, once: bool = False, stop: Callable[[], bool] | None = None, poll_s: float = POLL_S) -> None:
        """Scan until interrupted (Ctrl-C, SIGTERM) or ``stop()`` is true.

        Parameters
        ----------
        once
            One scan that reports the incomplete folders instead of waiting for them, and
            makes full models only (the previews waiting from an earlier watch are replaced).
        stop
            Checked between scans; the watch ends when it returns True.
        poll_s
            Seconds between scans.
        """
        def interrupt(signum: int, frame: object) -> None:
            # remembered as well as raised: a compiled kernel that catches errors can swallow the
            # KeyboardInterrupt raised inside it, and the watch then stops after that capture
            self._interrupted = True
            raise KeyboardInterrupt

        # a service manager's SIGTERM stops the watch as Ctrl-C does: between two files (--once too)
        main = threading.current_thread() is threading.main_thread()
        previous = {sig: signal.signal(sig, interrupt) for sig in (signal.SIGINT, signal.SIGTERM)} if main else {}
        self._live = not once
        try:
            if once:
                self.scan(final=True)
                while self.previews:
                    self.refine(final=True)
                return
            while stop is None or not stop():
                if self.scan():
                    continue
                if self.previews and time.monotonic() - self._busy_at >= self.refine_idle_s:
                    refined = self.refine()
                    if self._interrupted:  # swallowed on the way (scan's comment)
                        raise KeyboardInterrupt
                    if refined:
                        continue
                time.sleep(poll_s)
        finally:
            self._live = False
            try:  # the page left behind: every model there is (an earlier watch's too), and no reload
                if self.entries or self.failed:
                    self._write_index()
            except (ReflectoError, OSError):  # a page that cannot be written now keeps its reload, nothing worse
                pass
            finally:
                for sig, handler in previous.items():
                    signal.signal(sig, handler)
