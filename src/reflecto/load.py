"""Open any BRDF file reflecto reads, by its suffix or, failing that, its first bytes.

================  =====================================  ==========================================
suffix            kind                                   class
================  =====================================  ==========================================
``.binary``       MERL table                             :class:`~reflecto.sources.MerlBRDF`
``.bsdf``         RGL tensor file (RGB)                  :class:`~reflecto.sources.RGLBRDF`
``.h5``           NBRDF neural fit (+ sibling ``.json``)  :class:`~reflecto.sources.NBRDF`
``.json/.toml``   analytic description                   :class:`~reflecto.sources.AnalyticBRDF`
``.reflecto``     reflecto model file                    :class:`~reflecto.model.MicrofacetBRDF`
================  =====================================  ==========================================

Each reader registers itself in :data:`reflecto.brdf.READERS` where it is defined;
this module imports the readers (so that they are registered) and chooses among them.
"""

from __future__ import annotations

from pathlib import Path

from . import model as _model  # noqa: F401 — registers the .reflecto reader
from . import sources as _sources  # noqa: F401 — registers the measured and analytic readers
from .brdf import READERS, BRDFSource, Reader
from .errors import FileFormatError
from .io import check_regular, read_head

__all__ = ["load_source", "reader_for"]


def _sniff(path: Path) -> Reader:
    """The reader whose leading bytes start the file (JSON descriptions: the first non-blank byte)."""
    head = read_head(path, 16)
    for reader in dict.fromkeys(READERS.values()):
        if any(head.startswith(m) or head.lstrip().startswith(m) for m in reader.magic):
            return reader
    known = ", ".join(sorted(READERS))
    raise FileFormatError(path, f"unrecognised BRDF file (expected {known})")


def reader_for(path: str | Path) -> Reader:
    """The reader of ``path``: by its suffix, else by its first bytes.

    Parameters
    ----------
    path
        A BRDF file (see the table in the module docstring for the kinds).

    Returns
    -------
    reflecto.brdf.Reader
        The registered reader of the suffix (lower-cased), or the one whose magic bytes
        start the file.

    Raises
    ------
    FileFormatError
        Naming the file, when no reader knows it.
    """
    path = Path(path)
    reader = READERS.get(path.suffix.lower())
    return reader if reader is not None else _sniff(path)


def load_source(path: str | Path) -> BRDFSource:
    """Open any supported BRDF file as a :class:`~reflecto.brdf.BRDFSource`.

    Every reader checks sizes against the file before allocating, the type and range
    of every field, and the plausibility of the BRDF it describes (docs/limits.md).

    Parameters
    ----------
    path
        A ``.binary`` (MERL), ``.bsdf`` (RGL), ``.h5`` (NBRDF), ``.json``/``.toml``
        (analytic) or ``.reflecto`` (model) file; other suffixes are recognised by their
        first bytes.

    Returns
    -------
    BRDFSource
        The BRDF; ``eval(i, o)`` gives linear RGB values in sr⁻¹, shape ``(N, 3)``.

    Raises
    ------
    FileFormatError
        Naming the file and the problem, for missing, truncated, damaged,
        implausible or unrecognised files, and for anything but a regular file.
    """
    path = Path(path)
    check_regular(path)
    return reader_for(path).open(path)
