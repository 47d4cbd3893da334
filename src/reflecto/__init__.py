"""reflecto — condenser-based instant reflectometry (Lan, Dong, Wang, Tong, Guo 2010).

The BRDF model of §3.1 (generalized microfacet BRDF with a tabulated hemicube NDF),
the BRDF sources it is validated against, and, in the subpackages, the virtual
instrument (:mod:`.instrument`), the §5 reconstruction (:mod:`.reconstruct`), the §6
validation (:mod:`.evaluate`), exports (:mod:`.export`) and renders (:mod:`.render`).

Units: BRDF values in sr⁻¹; angles in radians unless a name ends in ``_deg``.
Directions: unit vectors away from the surface, local frame ``x = t, y = b, z = n``.
"""

from __future__ import annotations

from .brdf import BRDFSource, directional_albedo
from .errors import FileFormatError, ParameterError, ReflectoError
from .hemicube import Hemicube, hemicube
from .load import load_source
from .model import IsotropicMicrofacetBRDF, MicrofacetBRDF, load_model
from .sources import NBRDF, RGLBRDF, AnalyticBRDF, MerlBRDF

__version__ = "0.1.0"

__all__ = [
    "AnalyticBRDF",
    "BRDFSource",
    "FileFormatError",
    "Hemicube",
    "IsotropicMicrofacetBRDF",
    "MerlBRDF",
    "MicrofacetBRDF",
    "NBRDF",
    "ParameterError",
    "RGLBRDF",
    "ReflectoError",
    "directional_albedo",
    "hemicube",
    "load_model",
    "load_source",
    "__version__",
]
