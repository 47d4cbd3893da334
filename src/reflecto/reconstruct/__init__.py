"""The §5 reconstruction: BRDF slices → generalized microfacet BRDF (:mod:`.pipeline`)."""

from .isotropy import IsotropyTest
from .motion import MotionReport
from .pipeline import Options, Reconstruction, reconstruct

__all__ = ["IsotropyTest", "MotionReport", "Options", "Reconstruction", "reconstruct"]
