"""The §5 reconstruction: BRDF slices → generalized microfacet BRDF (:mod:`.pipeline`);
captures at several rotations → one BRDF that may break eq. 3 (§5.5, :mod:`.asymmetric`)."""

from .asymmetric import AsymmetricReconstruction, RotatedCapture, reconstruct_rotations
from .isotropy import IsotropyTest
from .motion import MotionReport
from .pipeline import FitSeconds, Options, Reconstruction, reconstruct
from .synthesis import SynthesisOptions

__all__ = ["AsymmetricReconstruction", "FitSeconds", "IsotropyTest", "MotionReport", "Options", "Reconstruction",
           "RotatedCapture", "SynthesisOptions", "reconstruct", "reconstruct_rotations"]
