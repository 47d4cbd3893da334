"""What kind of input a path is, so that a command given the wrong kind says so first.

:func:`identify` looks at a path's suffix, its first bytes, the member names of a zip
archive, the top-level keys of a JSON/TOML file, or the manifest of a folder, and names
its kind (:data:`KINDS`). It never reads more than a description file's
:data:`~reflecto.io.MAX_DESCRIPTION_BYTES` and never fails: a path it cannot place is
``"unknown"`` (the command's own reader then names the problem), a missing one
``"missing"``.

:func:`require` refuses a path of another kind with one line,
``FILE is KIND; COMMAND needs KIND`` and the command that uses such a file.
"""

from __future__ import annotations

import dataclasses
import json
import os
import tomllib
import zipfile
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from .errors import ReflectoError, one_line

__all__ = ["KINDS", "BRDF_KINDS", "Kind", "KindError", "identify", "is_summary", "require", "require_output_suffix",
           "require_file_name", "is_model_file"]

#: Every kind :func:`identify` names, with the words used in messages.
KINDS: dict[str, str] = {
    "model": "a reflecto model file (.reflecto)",
    "merl": "a MERL table (.binary)",
    "rgl": "an RGL tensor file (.bsdf)",
    "nbrdf": "an NBRDF fit (.h5)",
    "analytic": "an analytic BRDF description (.json/.toml)",
    "capture": "a capture folder (manifest.json and frames)",
    "calibration-folder": "a calibration folder (calibration captures, calibration.json)",
    "calibration": "a calibration file (.npz, from `reflecto calibrate`)",
    "device": "a device file (.json/.toml)",
    "summary": "a reconstruction summary (.json)",
    "manifest": "a capture manifest (manifest.json)",
    "calibration-manifest": "a calibration folder's manifest (calibration.json)",
    "nbrdf-architecture": "an NBRDF architecture file (the .json beside its .h5 weights)",
    "results": "a results folder (of `reflecto sweep` or `design`)",
    "image": "an image",
    "folder": "a folder",
    "missing": "missing",
    "unknown": "unknown",
}
#: The kinds every command that reads a BRDF accepts.
BRDF_KINDS = ("model", "merl", "rgl", "nbrdf", "analytic")

_SUFFIX = {".reflecto": "model", ".binary": "merl", ".bsdf": "rgl", ".h5": "nbrdf", ".npz": "calibration",
           ".png": "image", ".exr": "image", ".hdr": "image", ".jpg": "image", ".jpeg": "image"}
_DEVICE_KEYS = {"name", "optics", "leds", "camera", "truth", "occluder_deg", "firing_order", "check_leds"}
_SUMMARY_KEYS = {"kd", "ks", "shake_detected", "model_error"}
#: A §5.5 set's summary (``reconstruct --asymmetric``): no single capture's model error.
_SET_SUMMARY_KEYS = {"kd", "ks", "shake_detected", "asymmetric", "rotations_deg"}
_MAX_DESCRIPTION = 16 << 20


def is_summary(data: dict[str, Any]) -> bool:
    """Whether a JSON object is a reconstruction's summary: one capture's, or a §5.5 set's.

    Parameters
    ----------
    data
        A JSON object.

    Returns
    -------
    bool
        Whether it holds a summary's keys.
    """
    keys = set(data)
    return _SUMMARY_KEYS <= keys or _SET_SUMMARY_KEYS <= keys


#: What to run with a file of each kind instead (``{path}`` is the file).
_USE = {
    "model": "to look at it: reflecto info {path}, or reflecto report {path} -o REPORT",
    "merl": "to model it: reflecto simulate {path} -o CAPTURE, then reflecto reconstruct CAPTURE -o MODEL.reflecto",
    "rgl": "to model it: reflecto simulate {path} -o CAPTURE, then reflecto reconstruct CAPTURE -o MODEL.reflecto",
    "nbrdf": "to model it: reflecto simulate {path} -o CAPTURE, then reflecto reconstruct CAPTURE -o MODEL.reflecto",
    "analytic": "to model it: reflecto simulate {path} -o CAPTURE, then reflecto reconstruct CAPTURE -o MODEL.reflecto",
    "capture": "to make a model of it: reflecto reconstruct {path} -o MODEL.reflecto",
    "calibration-folder": "to make a calibration file of it: reflecto calibrate {path} -o CAL.npz",
    "calibration": "it reads captures: reflecto reconstruct CAPTURE --calibration {path} -o MODEL.reflecto",
    "device": "it describes a device: reflecto simulate BRDF --device {path} -o CAPTURE",
    "summary": "it describes a model: reflecto info {model}",
    "manifest": "it belongs to its folder: reflecto reconstruct {parent} -o MODEL.reflecto",
    "calibration-manifest": "it belongs to its folder: reflecto calibrate {parent} -o CAL.npz",
    "nbrdf-architecture": "open the fit by its weights: reflecto info {h5}",
    "results": "its page and tables are inside it",
    "image": "",
    "folder": "",
}


@dataclasses.dataclass(frozen=True)
class Kind:
    """The kind of a path: ``name`` (a key of :data:`KINDS`) and the reason it was recognised."""

    name: str
    why: str = ""

    @property
    def words(self) -> str:
        """The kind in words (``"a MERL table (.binary)"``)."""
        return KINDS[self.name]


class KindError(ReflectoError):
    """A command was given a file or folder of another kind than it reads.

    Parameters
    ----------
    path
        The input.
    got
        Its kind (:class:`Kind`).
    command
        The command (``"report"``).
    need
        What the command reads, in words.
    hint
        What to run instead (may be empty).
    """

    def __init__(self, path: str | Path, got: str, command: str, need: str, hint: str = "",
                 verb: str = "needs") -> None:
        self.path = Path(path)
        text = f"{path} is {got}; {command} {verb} {need}" + (f" ({hint})" if hint else "")
        super().__init__(one_line(text))


def _json_kind(data: object) -> str:
    if not isinstance(data, dict):
        return "unknown"
    if data.get("type") == "analytic":
        return "analytic"
    if data.get("format") == "reflecto-capture":
        return "manifest"
    if data.get("format") == "reflecto-calibration-capture":
        return "calibration-manifest"
    if is_summary(data):
        return "summary"
    if data and set(data) <= _DEVICE_KEYS:
        return "device"
    return "unknown"


def _description_kind(path: Path) -> str:
    try:
        if path.stat().st_size > _MAX_DESCRIPTION:
            return "unknown"
        raw = path.read_bytes()
        data = tomllib.loads(raw.decode()) if path.suffix.lower() == ".toml" else json.loads(raw)
    except (OSError, ValueError, RecursionError):
        return "unknown"
    if path.suffix.lower() == ".json" and path.with_suffix(".h5").is_file() and isinstance(data, dict) \
            and "type" not in data and not is_summary(data):
        return "nbrdf-architecture"  # an NBRDF's architecture file beside its weights
    return _json_kind(data)


def _zip_kind(path: Path) -> str:
    try:
        with zipfile.ZipFile(path) as z:
            names = set(z.namelist()[:64])
    except (OSError, zipfile.BadZipFile, ValueError):
        return "unknown"
    if "meta.json" in names:
        return "model"
    if {"meta.npy", "scale.npy"} <= names:
        return "calibration"
    return "unknown"


def is_model_file(path: str | Path) -> bool:
    """Whether ``path`` is a readable zip holding a model's ``meta.json`` (a cheap check of
    its structure, not of its contents: :func:`reflecto.model.load_model` does that).

    Parameters
    ----------
    path
        A file (it need not exist).

    Returns
    -------
    bool
        ``True`` for a model file's structure; ``False`` for a missing, empty, truncated or other file.
    """
    return _zip_kind(Path(path)) == "model"


def _folder_kind(path: Path) -> str:
    if (path / "manifest.json").is_file():
        return "capture"
    if (path / "calibration.json").is_file():
        return "calibration-folder"
    if any((path / f).is_file() for f in ("results.csv", "design.csv", "records")) or (path / "records").is_dir():
        return "results"
    return "folder"


def identify(path: str | Path) -> Kind:
    """The kind of ``path`` (module docstring); never raises.

    Parameters
    ----------
    path
        A file or folder (it need not exist).

    Returns
    -------
    Kind
        ``"missing"`` for a path that does not exist, ``"unknown"`` for one that could
        not be placed (not readable, damaged, or of no kind reflecto knows).
    """
    p = Path(path)
    try:
        if p.is_dir():
            return Kind(_folder_kind(p), "folder")
        if not p.exists():
            return Kind("missing")
        if not p.is_file():
            return Kind("unknown", "not a regular file")
        suffix = p.suffix.lower()
        if suffix in (".json", ".toml"):
            return Kind(_description_kind(p), "contents")
        if suffix in (".reflecto", ".npz"):
            kind = _zip_kind(p)
            return Kind(kind if kind != "unknown" else _SUFFIX[suffix], "suffix")
        if suffix in _SUFFIX:
            return Kind(_SUFFIX[suffix], "suffix")
        with p.open("rb") as fh:
            head = fh.read(16)
    except OSError:
        return Kind("unknown")
    if head.startswith(b"PK\x03\x04"):
        return Kind(_zip_kind(p), "contents")
    if head.startswith(b"tensor_file"):
        return Kind("rgl", "contents")
    if head.startswith(b"\x89HDF\r\n\x1a\n"):
        return Kind("nbrdf", "contents")
    if head.startswith(b"\x89PNG"):
        return Kind("image", "contents")
    if head.lstrip().startswith(b"{"):
        return Kind(_json_kind_of(p), "contents")
    return Kind("unknown")


def _json_kind_of(path: Path) -> str:
    try:
        if path.stat().st_size > _MAX_DESCRIPTION:
            return "unknown"
        return _json_kind(json.loads(path.read_bytes()))
    except (OSError, ValueError, RecursionError):
        return "unknown"


def hint_for(path: str | Path, kind: str) -> str:
    """What to run with a file of ``kind`` (empty when nothing fits)."""
    p = Path(path)
    return _USE.get(kind, "").format(path=path, model=p.with_suffix(".reflecto"), parent=p.parent,
                                     h5=p.with_suffix(".h5"))


def require(path: str | Path | None, command: str, accept: Iterable[str], need: str, hint: str = "") -> None:
    """Refuse ``path`` unless its kind is one of ``accept`` (or cannot be told: missing or unknown).

    Parameters
    ----------
    path
        The input (``None``: nothing to check).
    command
        The command, for the message (``"report"``, ``"reconstruct --calibration"``).
    accept
        Kinds (keys of :data:`KINDS`) the command reads.
    need
        What the command reads, in words.
    hint
        What to run instead; default: what a file of the given kind is for.

    Raises
    ------
    KindError
        ``FILE is KIND; COMMAND needs KIND (hint)``.
    """
    if path is None:
        return
    kind = identify(path)
    accept = tuple(accept)
    if kind.name in accept or kind.name in ("missing", "unknown", "folder"):
        return  # what cannot be told (a plain folder among them) is left to the command's reader to name
    raise KindError(path, kind.words, command, need, hint or hint_for(path, kind.name))


def require_file_name(path: str | Path, command: str, what: str, suffix: str, flag: str = "-o") -> None:
    """Refuse an output that ends with a path separator (``m.bsdf/``) where the command
    writes one file: the user named a folder, and :class:`~pathlib.Path` would drop the
    separator and write a file of that name.

    Parameters
    ----------
    path
        The output path the user gave.
    command
        The CLI command, for the message.
    what
        What the command writes, in words.
    suffix
        The suffix the message suggests (lower case, with the dot).
    flag
        The option that names the output, for the message.

    Returns
    -------
    None

    Raises
    ------
    KindError
        ``PATH is a folder; COMMAND writes WHAT (use -o NAME.SUFFIX)``.
    """
    if str(path).endswith(("/", os.sep)):
        raise KindError(path, "a folder", command, what, f"use {flag} NAME{suffix}", verb="writes")


def require_output_suffix(path: str | Path, command: str, suffixes: Iterable[str], what: str,
                          flag: str = "-o") -> None:
    """Refuse an output whose suffix is not one of ``suffixes`` (lower case, with the dot).

    Parameters
    ----------
    path
        The output path the user gave.
    command
        The CLI command, for the message.
    suffixes
        Accepted suffixes, lower case with the dot (the first is suggested).
    what
        What the command writes, in words.
    flag
        The option that names the output, for the message.

    Raises
    ------
    KindError
        ``FILE is a .X file; COMMAND writes WHAT (use -o NAME.SUFFIX)``.
    """
    suffixes = tuple(suffixes)
    if not str(path).strip():  # Path("") is ".": the message would name the current folder
        raise ReflectoError(f"{command} {flag}: the argument is empty; expected {what}")
    require_file_name(path, command, what, suffixes[0], flag)
    p = Path(path)
    if p.suffix.lower() in suffixes:
        return
    if not p.name.strip() or p.name == "..":  # ".", "/", "..": a folder, which has no file name to suffix
        raise KindError(path, "a folder", command, what, f"use {flag} NAME{suffixes[0]}", verb="writes")
    got = f"a {p.suffix} file" if p.suffix else "a name without a suffix"
    alternatives = " or ".join(f"{flag} {p.with_suffix(s)}" for s in suffixes)
    raise KindError(path, got, command, what, f"use {alternatives}", verb="writes")
