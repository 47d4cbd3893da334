"""Safe file input and atomic file output.

**Input.** Every file reflecto reads goes through :func:`read_input` (or
:func:`read_head`): it refuses anything but a regular file (a FIFO, a device or a
socket would block or never end) and files larger than the limit of their kind,
before reading a byte. Structured inputs then go through one checker per container:
:func:`parse_json` (nesting depth), :func:`zip_members` (member count and unpacked
bytes, from the central directory, before inflating anything) and :func:`npy_array`
(the ``.npy`` header's dtype and shape against the bytes present, before allocating).
Files named inside other files resolve only inside their folder (:func:`inside`).
The limits are in ``docs/limits.md``; each failure is a
:class:`~reflecto.errors.FileFormatError` naming the file.

**Output.** Files are written to a temporary name beside the target and renamed
(:func:`atomic_write`, :func:`atomic_path`, :func:`atomic_folder`), so an interrupted
or failed write never leaves a partial file under the requested name. Outputs get the
permissions of an ordinary file or folder under the process's umask
(``0o666 & ~umask``, ``0o777 & ~umask``), and folders created for an output that then
failed are removed again.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import io
import json
import math
import os
import re
import shutil
import stat
import sys
import tempfile
import tomllib
import zipfile
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import IO, Any

import numpy as np

from .errors import FileFormatError, LimitError, OutputError, short_repr

MiB = 1 << 20
#: Largest JSON/TOML description (analytic BRDF, device, capture manifest,
#: calibration.json, NBRDF architecture, sweep record, reconstruction summary).
MAX_DESCRIPTION_BYTES = 16 * MiB
#: Deepest nesting of arrays/objects in a JSON or TOML description.
MAX_JSON_DEPTH = 64
#: Largest zip archive (``.reflecto`` model, ``.npz`` calibration) on disk.
MAX_ARCHIVE_BYTES = 512 * MiB
#: Most bytes all members of one archive may unpack to, and most members.
MAX_UNPACKED_BYTES = 512 * MiB
MAX_ARCHIVE_MEMBERS = 64
#: Largest BRDF file of a kind without a fixed size (RGL ``.bsdf``, NBRDF ``.h5``).
MAX_BRDF_BYTES = 128 * MiB


# ---------------------------------------------------------------------- input
def _open_regular(path: Path, missing: str) -> tuple[int, os.stat_result]:
    """An open descriptor of ``path`` (following links) and its status; regular files only.

    The file is opened without blocking (a FIFO would otherwise wait for a writer)
    and checked on the descriptor, so what is checked is what is read.
    """
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(path, flags)
    except FileNotFoundError:
        raise FileFormatError(path, missing) from None
    except OSError as e:
        raise FileFormatError(path, f"cannot read: {e.strerror or e}") from None
    try:
        st = os.fstat(fd)
    except OSError as e:
        os.close(fd)
        raise FileFormatError(path, f"cannot read: {e.strerror or e}") from None
    if not stat.S_ISREG(st.st_mode):
        os.close(fd)
        kind = ("a directory" if stat.S_ISDIR(st.st_mode) else "a FIFO" if stat.S_ISFIFO(st.st_mode)
                else "a device" if stat.S_ISCHR(st.st_mode) or stat.S_ISBLK(st.st_mode) else "a special file")
        raise FileFormatError(path, f"is {kind}, not a regular file")
    return fd, st


def read_input(path: str | Path, limit: int, what: str = "this kind of file", missing: str = "no such file") -> bytes:
    """The whole contents of a regular file of at most ``limit`` bytes.

    Parameters
    ----------
    path
        The file (symbolic links are followed).
    limit
        Largest size allowed, bytes (e.g. :data:`MAX_DESCRIPTION_BYTES`).
    what
        The kind of file, for the message of a :class:`LimitError`.
    missing
        The message when the file does not exist.

    Returns
    -------
    bytes
        The file's contents.

    Raises
    ------
    FileFormatError
        Missing (message ``missing``), unreadable, not a regular file.
    LimitError
        Larger than ``limit`` (checked before reading, and again while reading).
    """
    path = Path(path)
    fd, st = _open_regular(path, missing)
    try:
        if st.st_size > limit:
            raise LimitError(path, f"{st.st_size} bytes, more than the {limit} bytes allowed for {what} "
                                   "(docs/limits.md)")
        chunks, total = [], 0
        while True:
            chunk = os.read(fd, min(1 << 24, limit + 1 - total))
            if not chunk:
                break
            chunks.append(chunk)
            total += len(chunk)
            if total > limit:
                raise LimitError(path, f"more than the {limit} bytes allowed for {what} (docs/limits.md)")
        return b"".join(chunks)
    except OSError as e:
        raise FileFormatError(path, f"cannot read: {e.strerror or e}") from None
    finally:
        os.close(fd)


def read_head(path: str | Path, n: int, missing: str = "no such file") -> bytes:
    """The first ``n`` bytes of a regular file (fewer if it is shorter).

    Parameters
    ----------
    path
        The file (symbolic links are followed).
    n
        Number of bytes to read (one ``read`` call).
    missing
        The message when the file does not exist.

    Returns
    -------
    bytes
        At most ``n`` bytes from the start of the file.

    Raises
    ------
    FileFormatError
        Missing, unreadable, or not a regular file.
    """
    path = Path(path)
    fd, _ = _open_regular(path, missing)
    try:
        return os.read(fd, n)
    except OSError as e:
        raise FileFormatError(path, f"cannot read: {e.strerror or e}") from None
    finally:
        os.close(fd)


def check_regular(path: str | Path, missing: str = "no such file") -> int:
    """Refuse ``path`` unless it is a regular file (following links); returns its size.

    Parameters
    ----------
    path
        The file.
    missing
        The message when the file does not exist.

    Returns
    -------
    int
        The file's size, bytes.

    Raises
    ------
    FileFormatError
        Missing, unreadable, or not a regular file.
    """
    path = Path(path)
    fd, st = _open_regular(path, missing)
    os.close(fd)
    return int(st.st_size)


def _depth_at_most(obj: Any, limit: int) -> bool:
    """Whether no array/object in ``obj`` is nested deeper than ``limit`` (iterative)."""
    stack = [(obj, 1)]
    while stack:
        o, d = stack.pop()
        vals: Iterable[Any]
        if isinstance(o, dict):
            vals = o.values()
        elif isinstance(o, list):
            vals = o
        else:
            continue
        if d > limit:
            return False
        stack.extend((v, d + 1) for v in vals if isinstance(v, (dict, list)))
    return True


class _HugeInt(Exception):
    """An integer literal beyond the range of a float (raised out of the JSON parser)."""


def _float_range_int(text: str) -> int:
    """``int(text)`` for the JSON parser, refusing integers no float can hold.

    Every reader converts numbers to floats; ``float(10**400)`` raises OverflowError
    deep inside it, so such a number is refused here, where the file is known.
    """
    if len(text.lstrip("-")) > _MAX_INT_DIGITS:  # cheap: no int() of thousands of digits
        raise _HugeInt(text)
    n = int(text)
    if abs(n) > sys.float_info.max:  # int/float comparison is exact, never overflows
        raise _HugeInt(text)
    return n


#: Digits of the largest integer a float holds (≈ 1.8·10³⁰⁸).
_MAX_INT_DIGITS = 309


def _huge_int(obj: Any) -> int | None:
    """The first integer in ``obj`` beyond the range of a float, or None (iterative; for TOML)."""
    stack = [obj]
    while stack:
        o = stack.pop()
        if isinstance(o, dict):
            stack.extend(o.values())
        elif isinstance(o, list):
            stack.extend(o)
        elif isinstance(o, int) and not isinstance(o, bool) and abs(o) > sys.float_info.max:
            return o
    return None


def _huge_int_problem(text: str) -> str:
    digits = len(text.lstrip("-"))
    return f"the integer {text[:12]}… ({digits} digits) is out of range: numbers must be within ±1.8e308"


def parse_json(raw: bytes | str, path: str | Path, kind: str = "JSON") -> Any:
    """Parse JSON (or TOML with ``kind="TOML"``) text read from ``path``.

    Refuses invalid UTF-8 and syntax, integers beyond the range of a float (no reader
    could use them) and nesting deeper than :data:`MAX_JSON_DEPTH`.

    Parameters
    ----------
    raw
        The text, as UTF-8 bytes or a str.
    path
        The file it was read from, for messages.
    kind
        ``"JSON"`` or ``"TOML"``.

    Returns
    -------
    Any
        The parsed value (dict, list, str, number, bool or None; a dict for TOML).

    Raises
    ------
    FileFormatError
        Not valid UTF-8 or not valid ``kind``.
    LimitError
        Nested deeper than :data:`MAX_JSON_DEPTH`.
    """

    try:
        text = raw.decode("utf-8") if isinstance(raw, bytes) else raw
        d = tomllib.loads(text) if kind == "TOML" else json.loads(text, parse_int=_float_range_int)
    except RecursionError:
        d = None
        deep = True
    except _HugeInt as e:
        raise FileFormatError(path, _huge_int_problem(str(e))) from None
    except (UnicodeDecodeError, ValueError, tomllib.TOMLDecodeError) as e:  # JSONDecodeError is a ValueError
        raise FileFormatError(path, f"not valid {kind}: {e}") from None
    else:
        deep = not _depth_at_most(d, MAX_JSON_DEPTH)
    if deep:
        raise LimitError(path, f"{kind} nested deeper than {MAX_JSON_DEPTH} levels (docs/limits.md)")
    huge = _huge_int(d) if kind == "TOML" else None  # tomllib has no integer hook: look afterwards
    if huge is not None:
        raise FileFormatError(path, _huge_int_problem(str(huge)))
    return d


def read_json(path: str | Path, limit: int = MAX_DESCRIPTION_BYTES, missing: str = "no such file") -> Any:
    """A JSON file (size- and depth-limited) as Python objects.

    Parameters
    ----------
    path
        The JSON file.
    limit
        Largest size allowed, bytes.
    missing
        The message when the file does not exist.

    Returns
    -------
    Any
        The parsed value (:func:`parse_json`).

    Raises
    ------
    FileFormatError
        As :func:`read_input` and :func:`parse_json`.
    """
    return parse_json(read_input(path, limit, "a JSON file", missing), path)


def read_description(path: str | Path, missing: str = "no such file") -> dict[str, Any]:
    """A JSON or TOML description file (by suffix) as a dict.

    Raises :class:`FileFormatError` naming the file if it is missing (with ``missing``
    as the message), unreadable, not a regular file, larger than
    :data:`MAX_DESCRIPTION_BYTES`, not valid JSON/TOML, nested too deep, or not a
    table at the top level.

    Parameters
    ----------
    path
        The file; suffix ``.toml`` (any case) is read as TOML, anything else as JSON.
    missing
        The message when the file does not exist.

    Returns
    -------
    dict
        The top-level table/object.
    """
    path = Path(path)
    kind = "TOML" if path.suffix.lower() == ".toml" else "JSON"
    d = parse_json(read_input(path, MAX_DESCRIPTION_BYTES, f"a {kind} description", missing), path, kind)
    if not isinstance(d, dict):
        raise FileFormatError(path, "top level must be a table/object")
    return d


def inside(folder: str | Path, name: Any, where: str | Path, what: str = "file") -> Path:
    """The path of ``name``, a file named inside ``where``, which must lie in ``folder``.

    ``name`` must be a relative path without ``..``; after following symbolic links
    it must still lie inside ``folder`` (a link within the folder is fine, one that
    leads out of it is not).

    Parameters
    ----------
    folder
        The folder the named file must lie in.
    name
        The name as read from ``where`` (anything; only a non-empty str without NUL passes).
    where
        The file that names ``name``, for messages.
    what
        What ``name`` names, for messages.

    Returns
    -------
    pathlib.Path
        ``folder / name`` (not resolved; it need not exist).

    Raises
    ------
    FileFormatError
        Naming ``where`` (the file that names ``name``).
    """
    folder = Path(folder)
    if not isinstance(name, str) or not name or "\x00" in name:
        raise FileFormatError(where, f"{what} name must be a non-empty string, got {_short(name)}")
    rel = Path(name)
    if rel.is_absolute() or ".." in rel.parts:
        raise FileFormatError(where, f"{what} {name!r} must be a relative name inside {folder}")
    target = folder / rel
    try:
        real_folder = os.path.realpath(folder)
        real = os.path.realpath(target)
    except (OSError, ValueError) as e:
        raise FileFormatError(where, f"{what} {name!r}: cannot resolve ({e})") from None
    if os.path.commonpath([real_folder, real]) != real_folder:
        raise FileFormatError(where, f"{what} {name!r} leads outside {folder} (to {real})")
    return target


def _short(v: Any) -> str:
    return short_repr(v)


# ------------------------------------------------------------------- archives
def zip_members(raw: bytes, path: str | Path, max_unpacked: int = MAX_UNPACKED_BYTES,
                max_members: int = MAX_ARCHIVE_MEMBERS) -> dict[str, bytes]:
    """Every member of a zip archive (its bytes ``raw``), checked before inflating.

    The member count and the unpacked sizes of the central directory are checked
    against the limits before anything is inflated; a member whose data inflates to
    more than its recorded size, or fails its CRC, is refused by ``zipfile`` itself.
    Duplicate names, encryption and compression other than stored/deflate are refused.

    Parameters
    ----------
    raw
        The archive's bytes.
    path
        The archive's file, for messages.
    max_unpacked
        Most bytes all members together may unpack to.
    max_members
        Most members.

    Returns
    -------
    dict of str to bytes
        Member name → its inflated bytes.

    Raises
    ------
    FileFormatError
        Not a zip archive, damaged, a duplicate name, an encrypted member or an
        unsupported compression.
    LimitError
        More members or more unpacked bytes than allowed.
    """
    try:
        z = zipfile.ZipFile(io.BytesIO(raw))
    except MemoryError:
        raise
    except Exception as e:  # noqa: BLE001 — zipfile raises many types on damaged data
        raise FileFormatError(path, f"not a zip archive or damaged ({type(e).__name__}: {e})") from None
    with z:
        infos = z.infolist()
        if len(infos) > max_members:
            raise LimitError(path, f"{len(infos)} archive members, more than {max_members} (docs/limits.md)")
        names = [i.filename for i in infos]
        if len(set(names)) != len(names):
            raise FileFormatError(path, "archive lists a member twice")
        total = sum(i.file_size for i in infos)
        if total > max_unpacked:
            raise LimitError(path, f"archive unpacks to {total} bytes, more than {max_unpacked} (docs/limits.md)")
        out = {}
        for i in infos:
            if i.flag_bits & 0x1:
                raise FileFormatError(path, f"archive member {i.filename!r} is encrypted")
            if i.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
                raise FileFormatError(path, f"archive member {i.filename!r} uses unsupported compression "
                                            f"{i.compress_type}")
            try:
                data = z.read(i)
            except MemoryError:
                raise
            except Exception as e:  # noqa: BLE001 — BadZipFile, zlib.error, EOFError, ...
                raise FileFormatError(path, f"damaged archive member {i.filename!r} "
                                            f"({type(e).__name__}: {e})") from None
            if len(data) != i.file_size:
                raise FileFormatError(path, f"damaged archive member {i.filename!r} "
                                            "(size differs from the directory's)")
            out[i.filename] = data
    return out


#: The date every member of a file reflecto zips carries (the zip format's earliest), so
#: that the same content gives the same bytes.
ZIP_DATE = (1980, 1, 1, 0, 0, 0)


def write_zip(fh: IO[bytes], members: dict[str, bytes]) -> None:
    """``members`` (name → bytes) deflated into a zip written to ``fh``, in their order,
    each dated :data:`ZIP_DATE` with permissions 0644: equal members, equal bytes.

    Parameters
    ----------
    fh
        A binary file open for writing.
    members
        The members' names and contents.
    """
    with zipfile.ZipFile(fh, "w", compression=zipfile.ZIP_DEFLATED) as z:
        for name, data in members.items():
            info = zipfile.ZipInfo(name, date_time=ZIP_DATE)
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            z.writestr(info, data)


def npy_bytes(array: np.ndarray) -> bytes:
    """``array`` in ``.npy`` format (no pickles).

    Parameters
    ----------
    array
        The array (written C-contiguous).

    Returns
    -------
    bytes
        The ``.npy`` file's bytes.
    """
    buf = io.BytesIO()
    np.save(buf, np.ascontiguousarray(array), allow_pickle=False)
    return buf.getvalue()


def npy_array(raw: bytes, path: str | Path, member: str, dtype: Any = None,
              shape: tuple[int, ...] | None = None) -> np.ndarray:
    """The numeric array in ``.npy`` bytes ``raw``; its header is checked before allocating.

    ``dtype`` and ``shape``, when given, are required exactly; in any case the bytes
    after the header must be exactly what the header's dtype and shape need.

    Parameters
    ----------
    raw
        The ``.npy`` bytes (format version 1.0 or 2.0).
    path
        The file holding them, for messages.
    member
        The archive member they came from, for messages.
    dtype
        The required dtype; ``None``: any boolean, integer or float dtype.
    shape
        The required shape; ``None``: any.

    Returns
    -------
    numpy.ndarray
        A C-ordered copy of the array.

    Raises
    ------
    FileFormatError
        A damaged header, a non-numeric or structured dtype, another dtype or shape than
        required, or data of the wrong length.
    """
    fmt = np.lib.format
    bio = io.BytesIO(raw)
    try:
        version = fmt.read_magic(bio)
        if version == (1, 0):
            shp, fortran, dt = fmt.read_array_header_1_0(bio)
        elif version == (2, 0):
            shp, fortran, dt = fmt.read_array_header_2_0(bio)
        else:
            raise ValueError(f"unsupported .npy version {version}")
    except MemoryError:
        raise
    except Exception as e:  # noqa: BLE001 — ValueError, SyntaxError, TypeError on damaged headers
        raise FileFormatError(path, f"{member}: damaged .npy header ({type(e).__name__}: {e})") from None
    if dt.hasobject or dt.kind not in "biuf" or dt.subdtype is not None:
        raise FileFormatError(path, f"{member}: not a plain numeric array (dtype {dt})")
    if dtype is not None and dt != np.dtype(dtype):
        raise FileFormatError(path, f"{member}: dtype {dt}, expected {np.dtype(dtype)}")
    if shape is not None and tuple(shp) != tuple(shape):
        raise FileFormatError(path, f"{member}: shape {tuple(shp)}, expected {tuple(shape)}")
    if any(int(n) < 0 for n in shp):
        raise FileFormatError(path, f"{member}: damaged .npy header (shape {tuple(shp)} has a negative length)")
    count = math.prod(int(s) for s in shp)  # exact: no overflow on a hostile shape
    need = count * dt.itemsize
    have = len(raw) - bio.tell()
    if need != have:
        raise FileFormatError(path, f"{member}: header says {tuple(shp)} {dt} ({need} bytes), "
                                    f"the data has {have} bytes")
    arr = np.frombuffer(raw, dtype=dt, count=count, offset=bio.tell())
    return np.array(arr.reshape(shp, order="F" if fortran else "C"), order="C")


def canonical_json(obj: Any) -> bytes:
    """The one text of ``obj`` that checksums are taken over (sorted keys, no blanks).

    Parameters
    ----------
    obj
        A JSON-ready value (NaN and infinities are written as ``NaN``/``Infinity``).

    Returns
    -------
    bytes
        ASCII JSON with sorted keys and ``,``/``:`` separators.
    """
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=True).encode()


def content_digest(meta: dict[str, Any]) -> str:
    """SHA-256 of the canonical JSON of ``meta`` without its ``sha256`` entry.

    Parameters
    ----------
    meta
        A metadata dict (its ``sha256`` key, if any, is left out).

    Returns
    -------
    str
        64 lowercase hex digits.
    """
    return hashlib.sha256(canonical_json({k: v for k, v in meta.items() if k != "sha256"})).hexdigest()


def sha256(data: bytes) -> str:
    """SHA-256 of ``data`` as 64 lowercase hex digits (the checksums of model and calibration files).

    Parameters
    ----------
    data
        The bytes to hash.

    Returns
    -------
    str
        64 lowercase hex digits.
    """
    return hashlib.sha256(data).hexdigest()


# --------------------------------------------------------------------- output
def _umask() -> int:
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    old = os.umask(0o022)  # no /proc: read it by setting it (and back at once)
    os.umask(old)
    return old


def file_mode() -> int:
    """Mode of a new output file: ``0o666 & ~umask`` (what ``open()`` would give).

    Returns
    -------
    int
        The permission bits.
    """
    return 0o666 & ~_umask()


def folder_mode() -> int:
    """Mode of a new output folder: ``0o777 & ~umask`` (what ``mkdir`` would give).

    Returns
    -------
    int
        The permission bits.
    """
    return 0o777 & ~_umask()


def make_parents(folder: Path) -> list[Path]:
    """Create ``folder`` and its missing parents; returns the ones created, outermost first.

    Parameters
    ----------
    folder
        The folder to create.

    Returns
    -------
    list of pathlib.Path
        The folders created, outermost first (empty if ``folder`` existed); on an error the
        ones created so far are removed again.

    Raises
    ------
    OutputError
        A file is in the way, or no permission.
    """
    missing = []
    p = folder
    while not p.exists() and not p.is_symlink():
        missing.append(p)
        if p.parent == p:
            break
        p = p.parent
    if p.exists() and not p.is_dir():
        raise OutputError(p, "cannot create the folder: a file of that name is in the way")
    created: list[Path] = []
    for d in reversed(missing):
        try:
            d.mkdir()
        except FileExistsError:
            if not d.is_dir():
                remove_empty(created)
                raise OutputError(d, "cannot create the folder: a file of that name is in the way") from None
            continue
        except OSError as e:
            remove_empty(created)
            problem = "a file is in the way" if isinstance(e, NotADirectoryError) else (e.strerror or str(e))
            raise OutputError(d, f"cannot create the folder: {problem}") from None
        created.append(d)
    if not folder.is_dir():
        raise OutputError(folder, "cannot create the folder: a file of that name is in the way")
    return created


def remove_empty(folders: list[Path]) -> None:
    """Remove those of ``folders`` (outermost first) that are empty, innermost first.

    Parameters
    ----------
    folders
        Folders as :func:`make_parents` returns them; a folder that is not empty, or
        cannot be removed, stays.
    """
    for d in reversed(folders):
        with contextlib.suppress(OSError):
            d.rmdir()


def _replaceable(path: Path, folder: bool = False) -> None:
    """Refuse an output path that holds something a rename must not replace (a device, a FIFO, ...)."""
    try:
        st = os.lstat(path)
    except (FileNotFoundError, NotADirectoryError):
        return  # a missing parent, or a file in its place: make_parents says which
    except OSError as e:
        raise OutputError(path, f"cannot write: {e.strerror or e}") from None
    if stat.S_ISLNK(st.st_mode) or (stat.S_ISDIR(st.st_mode) if folder else stat.S_ISREG(st.st_mode)):
        return
    if stat.S_ISDIR(st.st_mode):
        raise OutputError(path, "is a folder; cannot write a file there")
    if folder and stat.S_ISREG(st.st_mode):
        raise OutputError(path, "a file of that name is in the way")
    raise OutputError(path, "is a device, FIFO or socket; refusing to replace it with an output")




def _replaceable_folder(path: Path, marker: str) -> None:
    """Refuse to replace ``path`` as a whole unless that loses nothing of the user's.

    The current folder and its parents cannot be renamed away (and hold the user's
    work); an existing folder may be replaced only when it is empty or holds
    ``marker``, the file every output of this kind has (a capture's ``manifest.json``):
    a folder of other files is the user's, not an earlier output.
    """
    try:
        real, cwd = path.resolve(), Path.cwd().resolve()
    except (OSError, RuntimeError) as e:  # RuntimeError: a symbolic-link loop
        raise OutputError(path, f"cannot write: {e}") from None
    if real == cwd or real in cwd.parents:
        raise OutputError(path, "is the current folder or one of its parents; name a new folder for the output")
    if path.is_symlink() or not path.is_dir():
        return  # nothing there, or a link or file that _replaceable and the rename refuse
    try:
        with os.scandir(path) as it:
            empty = next(it, None) is None
    except OSError as e:
        raise OutputError(path, f"cannot write: {e.strerror or e}") from None
    if not empty and not (path / marker).is_file():
        raise OutputError(path, f"is a folder of other files (no {marker}), not an earlier output of this "
                                "kind; refusing to replace it: name a new or empty folder")
    if not empty and marker in FRAME_FOLDER_MARKERS:
        foreign = _foreign_entry(path, marker)
        if foreign is not None:
            raise OutputError(path, f"holds {foreign}, which no earlier output of this kind writes; refusing to "
                                    "replace it: name a new or empty folder")


#: The markers of the folders of frames (a capture's ``manifest.json``, a calibration's
#: ``calibration.json``): such a folder holds its marker, a JSON file of a reflecto format,
#: PNG frames and (a calibration) captures of the same kind, nothing else.
FRAME_FOLDER_MARKERS = ("manifest.json", "calibration.json")


def _foreign_entry(path: Path, marker: str, depth: int = 0) -> str | None:
    """The first entry of the frame folder ``path`` that its kind of output does not write
    (``marker`` not a reflecto format's JSON, a file that is no PNG frame, a folder that is
    no capture), or ``None`` where the folder holds only what an earlier output writes."""
    try:
        text = (path / marker).read_text(encoding="utf-8", errors="replace")[:4096]
    except OSError as err:
        return f"an unreadable {marker} ({err.strerror or err})"
    if not re.search(r'"format"\s*:\s*"reflecto-', text):
        return f"a {marker} of no reflecto format"
    try:
        entries = list(os.scandir(path))
    except OSError as err:
        return f"entries it cannot list ({err.strerror or err})"
    for entry in entries:
        if entry.name == marker or (entry.name.lower().endswith(".png") and entry.is_file(follow_symlinks=False)):
            continue
        sub = Path(entry.path)
        if depth == 0 and entry.is_dir(follow_symlinks=False) and (sub / "manifest.json").is_file():
            inner = _foreign_entry(sub, "manifest.json", depth + 1)
            if inner is None:
                continue
            return f"{entry.name}/ (a capture folder holding {inner})"
        return repr(entry.name)
    return None


def check_output(path: str | Path, folder: bool = False, marker: str | None = None) -> None:
    """Refuse at once an output that cannot be written (before the work that makes it).

    The path must not hold something a rename must not replace, nor a file where a
    folder goes (or the reverse), and its nearest existing parent must be a folder.
    Nothing is created.

    Parameters
    ----------
    path
        The output's path.
    folder
        Whether the output is a folder (else a file).
    marker
        For a folder that the output replaces as a whole (:func:`atomic_folder`): the
        file that marks an earlier output of its kind; the checks of
        :func:`atomic_folder` are made now. ``None``: a folder written into.

    Raises
    ------
    OutputError
        The output could not be written there.
    """
    path = Path(path)
    _replaceable(path, folder)
    if folder and marker is not None:
        _replaceable_folder(path, marker)
    p = path.parent
    while not p.exists() and not p.is_symlink() and p != p.parent:
        p = p.parent
    if p.exists() and not p.is_dir():
        raise OutputError(p, "cannot create the folder: a file of that name is in the way")


#: Longest temporary file name made next to an output (bytes): the usual file systems' limit.
TEMP_NAME_MAX = 255


def _temp_file(path: Path, suffix: str) -> tuple[int, str, list[Path]]:
    _replaceable(path)
    created = make_parents(path.parent)
    # the temporary name adds a dot, 8 random characters and the suffix to the final one: a
    # final name near the file system's limit (255 bytes) keeps only the head of its own
    name = os.fsencode(path.name)
    room = TEMP_NAME_MAX - len(os.fsencode(suffix)) - 10
    head = path.name
    if len(name) > room:  # cut on a character's boundary where the name is UTF-8 (writers that take text)
        try:
            head = name.decode("utf-8") and name[:room].decode("utf-8", "ignore")
        except UnicodeDecodeError:
            head = os.fsdecode(name[:room])
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{head}.", suffix=suffix, dir=path.parent)
    except OSError as e:
        remove_empty(created)
        raise OutputError(path, f"cannot write: {e.strerror or e}") from None
    os.fchmod(fd, file_mode())  # mkstemp makes 0600 whatever the umask
    return fd, tmp, created


#: Errors of writing that are the output's, whatever code raised them: a full disk, a quota, a file too large.
_WRITE_ERRNOS = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)


def _name_the_output(e: BaseException, path: Path, tmp: str | Path) -> None:
    """Raise an :class:`OutputError` naming ``path`` for a write error of the disk's
    (:data:`_WRITE_ERRNOS`), which names no file ("No space left on device"), or for one
    that names the temporary file or folder ``tmp`` or a file inside it (a writer that
    writes atomically in turn): named by its place in ``path``. Other exceptions go on as
    they are."""
    if isinstance(e, OSError) and e.errno in _WRITE_ERRNOS:
        raise OutputError(path, f"cannot write: {e.strerror or e}") from None
    if isinstance(e, OutputError) and e.path.is_relative_to(tmp):
        raise OutputError(path / e.path.relative_to(tmp), e.problem) from None


def _rename(tmp: str, path: Path) -> None:
    try:
        os.replace(tmp, path)
    except IsADirectoryError:
        raise OutputError(path, "is a folder; cannot write a file there") from None
    except OSError as e:
        raise OutputError(path, f"cannot write: {e.strerror or e}") from None


@contextlib.contextmanager
def atomic_write(path: str | Path, mode: str = "wb") -> Iterator[IO[Any]]:
    """Open a temporary file next to ``path``; rename it onto ``path`` on success.

    On any exception the temporary file (and any folder created for it) is removed
    and ``path`` is untouched. The file gets mode ``0o666 & ~umask``.

    Parameters
    ----------
    path
        The file to write; missing parent folders are created.
    mode
        The ``open`` mode: ``"wb"`` (bytes) or ``"w"`` (text).

    Yields
    ------
    file object
        The temporary file, open for writing; flushed and fsynced before the rename.

    Raises
    ------
    OutputError
        ``path`` cannot be written (a folder, device or FIFO there, no permission).
    """
    path = Path(path)
    fd, tmp, created = _temp_file(path, ".part")
    try:
        with os.fdopen(fd, mode) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        _rename(tmp, path)
    except BaseException as e:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        remove_empty(created)
        _name_the_output(e, path, tmp)
        raise


@contextlib.contextmanager
def atomic_path(path: str | Path, suffix: str = "") -> Iterator[Path]:
    """Yield a temporary path next to ``path`` for libraries that want a filename.

    The caller writes to the yielded path; it is renamed onto ``path`` on success
    and removed on failure (with any folder created for it).

    Parameters
    ----------
    path
        The file to write; missing parent folders are created.
    suffix
        Suffix of the temporary name (a library may choose the format by it);
        ``""``: ``.part``.

    Yields
    ------
    pathlib.Path
        The temporary file (created empty, mode ``0o666 & ~umask``).

    Raises
    ------
    OutputError
        ``path`` cannot be written.
    """
    path = Path(path)
    fd, tmp, created = _temp_file(path, suffix or ".part")
    os.close(fd)
    try:
        yield Path(tmp)
        with contextlib.suppress(OSError):
            os.chmod(tmp, file_mode())  # a library may have replaced the file
        _rename(tmp, path)
    except BaseException as e:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        remove_empty(created)
        _name_the_output(e, path, tmp)
        raise


@contextlib.contextmanager
def atomic_folder(path: str | Path, marker: str) -> Iterator[Path]:
    """Yield a temporary folder beside ``path``; it replaces ``path`` on success.

    The folder gets mode ``0o777 & ~umask``; on failure it is removed, with any
    parent created for it. Only an empty folder or an earlier output of the same kind
    (one holding ``marker``) is replaced, never the current folder or a parent of it.

    Parameters
    ----------
    path
        The folder to write; an existing folder there is replaced as a whole.
    marker
        The file every output of this kind holds, and no other kind (a capture's
        ``manifest.json``, a calibration folder's ``calibration.json``, a gallery's
        ``gallery.json``, a report's ``viewer.html``; an ``index.html`` alone would also
        mark a watch's models folder).

    Yields
    ------
    pathlib.Path
        The temporary folder to fill.

    Raises
    ------
    OutputError
        A file (or a link) is in the way, ``path`` is a folder of other files, the
        current folder or a parent of it, or it cannot be written.
    """
    path = Path(path)
    if path.is_symlink():  # refused before the work, not after it: the rename would replace the link, not its target
        raise OutputError(path, "is a link; this output folder is replaced as a whole: name the folder itself")
    _replaceable(path, folder=True)
    _replaceable_folder(path, marker)
    created = make_parents(path.parent)
    try:
        tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".part", dir=path.parent))
    except OSError as e:
        remove_empty(created)
        raise OutputError(path, f"cannot write: {e.strerror or e}") from None
    os.chmod(tmp, folder_mode())  # mkdtemp makes 0700 whatever the umask
    try:
        yield tmp
        if path.is_symlink() or (path.exists() and not path.is_dir()):
            raise OutputError(path, "a file of that name is in the way")
        if path.exists():
            _replaceable_folder(path, marker)  # again: it may have changed during the work
            # a fresh name for the old folder: a fixed one could be a folder of the user's
            old = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".old", dir=path.parent))
            try:
                os.replace(path, old)  # onto the empty folder just made: POSIX allows it
            except OSError:
                old.rmdir()
                raise
            try:
                os.replace(tmp, path)
            except OSError:
                os.replace(old, path)  # put the earlier output back
                raise
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, path)
    except BaseException as e:
        shutil.rmtree(tmp, ignore_errors=True)
        remove_empty(created)
        _name_the_output(e, path, tmp)
        raise
