"""BRDF sources read from files: measured tables, neural fits and analytic lobes.

Each reader registers its suffixes in :data:`reflecto.brdf.READERS`;
:func:`reflecto.load.load_source` opens any file by them.
"""

from __future__ import annotations

from .analytic import AnalyticBRDF, load_analytic
from .merl import MerlBRDF
from .nbrdf import NBRDF
from .rgl import RGLBRDF

__all__ = ["AnalyticBRDF", "MerlBRDF", "NBRDF", "RGLBRDF", "load_analytic"]


def __dir__() -> list[str]:
    """The public names (:data:`__all__`) and the reader modules."""
    return sorted([*__all__, "analytic", "merl", "nbrdf", "rgl"])
