"""Exception and warning types of reflecto.

Every error raised on bad input names the offending file (when there is one) and
the problem on one line, so that the CLI can print ``reflecto: error: FILE: problem``
and exit non-zero. Every error pickles and unpickles to an equal error, so that a
worker process of a batch can report it to its parent.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any


def shown_path(path: str | Path) -> str:
    """``path`` as a message shows it: its control characters (a newline, a tab) written as
    Python's escapes, so that the message stays one line."""
    s = str(path)
    return s if s.isprintable() else "".join(c if c.isprintable() else c.encode("unicode_escape").decode("ascii")
                                             for c in s)


def one_line(text: object, max_chars: int = 600) -> str:
    """``text`` as one line (newlines and runs of blanks become one space), cut to ``max_chars``."""
    s = " ".join(str(text).split())
    return s if len(s) <= max_chars else s[: max_chars - 1] + "…"


def interrupted(error: BaseException) -> bool:
    """Whether ``error`` is, or was raised from, a :class:`KeyboardInterrupt`.

    A Ctrl-C that lands inside a compiled kernel comes back as a ``SystemError``
    ("returned a result with an exception set") whose cause is the interrupt; a caller
    that catches ``Exception`` must not take it for a fault of its input.

    Parameters
    ----------
    error
        The exception caught.

    Returns
    -------
    bool
        True where a :class:`KeyboardInterrupt` is in its chain of causes and contexts.
    """
    seen: set[int] = set()
    e: BaseException | None = error
    while e is not None and id(e) not in seen:
        if isinstance(e, KeyboardInterrupt):
            return True
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return False


def short_repr(value: Any, max_chars: int = 60) -> str:
    """``repr(value)`` cut to ``max_chars`` characters, for quoting a bad value in a message."""
    try:
        r = repr(value)
    except Exception:  # noqa: BLE001 — a message must not fail on a strange value
        r = f"<{type(value).__name__}>"
    return one_line(r, max_chars)


def _rebuild(cls: type, args: tuple[Any, ...], state: dict[str, Any]) -> BaseException:
    # BaseException.__new__ takes any arguments and does not call __init__, so
    # subclasses with their own signatures unpickle without knowing it
    err = cls.__new__(cls, *args)
    err.args = args
    err.__dict__.update(state)
    return err


class ReflectoError(Exception):
    """Base class of all errors reflecto raises on purpose."""

    def __reduce__(self) -> tuple[Any, ...]:
        return _rebuild, (type(self), self.args, dict(self.__dict__))


class FileFormatError(ReflectoError):
    """A file is missing, truncated, of the wrong format, damaged or implausible.

    Parameters
    ----------
    path
        The file that could not be read.
    problem
        What is wrong with it, in words (made one line).
    """

    def __init__(self, path: str | Path, problem: str) -> None:
        self.path = Path(path)
        self.problem = one_line(problem)
        super().__init__(f"{shown_path(self.path)}: {self.problem}")


class OutputError(ReflectoError):
    """An output cannot be written where asked (a file in the way, no permission, ...).

    Parameters
    ----------
    path
        The output (file or folder) that could not be written.
    problem
        What went wrong, in words (made one line).
    """

    def __init__(self, path: str | Path, problem: str) -> None:
        self.path = Path(path)
        self.problem = one_line(problem)
        super().__init__(f"{shown_path(self.path)}: {self.problem}")


class LimitError(FileFormatError):
    """A file exceeds one of the documented input limits (docs/limits.md)."""


class ParameterError(ReflectoError, ValueError):
    """A parameter is impossible (negative roughness, NaN, energy gain, ...)."""


class BatchError(ReflectoError):
    """Some items of a batch failed; the others finished.

    Parameters
    ----------
    failures
        ``(item, message)`` per failed item; each message names its file.
    total
        Number of items in the batch.

    Attributes
    ----------
    records
        What the batch finished (its records, for a caller that reports them), or ``[]``.
    """

    def __init__(self, failures: list[tuple[str, str]], total: int) -> None:
        self.failures = list(failures)
        self.total = total
        self.records: list = []
        super().__init__(f"{len(self.failures)} of {total} items failed")


class ReflectoWarning(UserWarning):
    """Something was read but deserves attention (an older file format, a redone result)."""
