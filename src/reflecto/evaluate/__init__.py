"""Validation (paper §6): the error metric, the baselines, sweeps, figures and reports.

::

    brdf_error(reference, test)        eq. 10 (Ngan et al.), normalized       metrics.py
    comparison_error(reference, test)  eq. 10, every φ_h if either anisotropic metrics.py
    fit_cook_torrance(reference)       the dense Cook–Torrance baseline       cooktorrance.py
    fit_cook_torrance_capture(slices)  the same-data baseline                 cooktorrance.py
    sweep(folders, out)                simulate → reconstruct → evaluate      sweep.py
    write_report(model, out)           an HTML page of one model              report.py
"""

from .cooktorrance import CookTorrance, fit_cook_torrance, fit_cook_torrance_capture
from .metrics import Error, brdf_error, comparison_error, ndf_error
from .report import write_report
from .split import TUNING, VALIDATION
from .sweep import summarize, sweep

__all__ = ["CookTorrance", "Error", "TUNING", "VALIDATION", "brdf_error", "comparison_error", "fit_cook_torrance",
           "fit_cook_torrance_capture", "ndf_error", "summarize", "sweep", "write_report"]
