"""Atomic file output: write to a temporary name beside the target, then rename.

An interrupted or failed write therefore never leaves a partial or corrupted file
under the requested name.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any, BinaryIO

from .errors import FileFormatError


@contextlib.contextmanager
def atomic_write(path: str | Path, mode: str = "wb") -> Iterator[BinaryIO]:
    """Open a temporary file next to ``path``; rename it onto ``path`` on success.

    On any exception the temporary file is removed and ``path`` is untouched.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".part", dir=path.parent)
    try:
        with os.fdopen(fd, mode) as fh:
            yield fh  # type: ignore[misc]
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


@contextlib.contextmanager
def atomic_path(path: str | Path, suffix: str = "") -> Iterator[Path]:
    """Yield a temporary path next to ``path`` for libraries that want a filename.

    The caller writes to the yielded path; it is renamed onto ``path`` on success
    and removed on failure.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix or ".part", dir=path.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def read_description(path: str | Path, missing: str = "no such file") -> dict[str, Any]:
    """A JSON or TOML description file (by suffix) as a dict.

    Raises :class:`FileFormatError` naming the file if it is missing (with ``missing``
    as the message), unreadable, not valid JSON/TOML, or not a table at the top level.
    """
    import json
    import tomllib

    path = Path(path)
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise FileFormatError(path, missing) from None
    except OSError as e:
        raise FileFormatError(path, f"cannot read: {e.strerror}") from None
    kind = "TOML" if path.suffix.lower() == ".toml" else "JSON"
    try:
        text = raw.decode("utf-8")
        d = tomllib.loads(text) if kind == "TOML" else json.loads(text)
    except (UnicodeDecodeError, json.JSONDecodeError, tomllib.TOMLDecodeError) as e:
        raise FileFormatError(path, f"not valid {kind}: {e}") from None
    if not isinstance(d, dict):
        raise FileFormatError(path, "top level must be a table/object")
    return d
