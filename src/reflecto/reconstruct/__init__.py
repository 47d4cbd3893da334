"""The §5 reconstruction: six BRDF slices → generalized microfacet BRDF."""

from .pipeline import ReconstructionResult, reconstruct

__all__ = ["ReconstructionResult", "reconstruct"]
