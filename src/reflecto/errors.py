"""Exception types of reflecto.

Every error raised on bad input names the offending file (when there is one) and
the problem, so that the CLI can print it and exit non-zero.
"""

from __future__ import annotations

from pathlib import Path


class ReflectoError(Exception):
    """Base class of all errors reflecto raises on purpose."""


class FileFormatError(ReflectoError):
    """A file is truncated, of the wrong format, or damaged.

    Parameters
    ----------
    path
        The file that could not be read.
    problem
        What is wrong with it, in words.
    """

    def __init__(self, path: str | Path, problem: str) -> None:
        self.path = Path(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


class ParameterError(ReflectoError, ValueError):
    """A parameter is impossible (negative roughness, NaN, energy gain, ...)."""
