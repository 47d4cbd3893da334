"""BRDF sources: one interface (:class:`BRDFSource`), chosen by file type.

================  =====================================  ==========================
suffix            kind                                   class
================  =====================================  ==========================
``.binary``       MERL table                             :class:`MerlBRDF`
``.bsdf``         RGL tensor file (RGB)                  :class:`RGLBRDF`
``.h5``           NBRDF neural fit (+ sibling ``.json``)  :class:`NBRDF`
``.json/.toml``   analytic description                   :class:`AnalyticBRDF`
``.reflecto``     reflecto model file                    :class:`MicrofacetBRDF`
================  =====================================  ==========================

Files with another suffix are identified by their first bytes.
"""

from __future__ import annotations

from pathlib import Path

from ..errors import FileFormatError
from ..io import check_regular, read_head
from .analytic import AnalyticBRDF, load_analytic
from .base import BRDFSource, directional_albedo
from .merl import MerlBRDF
from .nbrdf import NBRDF
from .rgl import RGLBRDF

__all__ = [
    "BRDFSource",
    "AnalyticBRDF",
    "MerlBRDF",
    "NBRDF",
    "RGLBRDF",
    "directional_albedo",
    "load_analytic",
    "load_source",
]


def _sniff(path: Path) -> str:
    head = read_head(path, 16)
    if head.startswith(b"tensor_file\x00"):
        return ".bsdf"
    if head.startswith(b"PK"):
        return ".reflecto"
    if head.startswith(b"\x89HDF"):
        return ".h5"
    if head[:12] == b"\x5a\x00\x00\x00\x5a\x00\x00\x00\xb4\x00\x00\x00":
        return ".binary"
    if head.lstrip()[:1] in (b"{",):
        return ".json"
    raise FileFormatError(path, "unrecognised BRDF file (expected .binary, .bsdf, .h5, .json, .toml or .reflecto)")


def load_source(path: str | Path) -> BRDFSource:
    """Open any supported BRDF file as a :class:`BRDFSource`.

    Every loader checks sizes against the file before allocating, the type and range
    of every field, and the plausibility of the BRDF it describes (docs/limits.md).

    Raises
    ------
    FileFormatError
        Naming the file and the problem, for missing, truncated, damaged,
        implausible or unrecognised files, and for anything but a regular file.
    """
    path = Path(path)
    check_regular(path)
    suffix = path.suffix.lower()
    if suffix not in (".binary", ".bsdf", ".h5", ".json", ".toml", ".reflecto"):
        suffix = _sniff(path)
    if suffix == ".binary":
        return MerlBRDF(path)
    if suffix == ".bsdf":
        return RGLBRDF(path)
    if suffix == ".h5":
        return NBRDF(path)
    if suffix in (".json", ".toml"):
        return load_analytic(path)
    from ..model import MicrofacetBRDF

    return MicrofacetBRDF.load(path)
