"""Rendering with Mitsuba 3 (an RGL export of any BRDF through the ``measured`` plugin).

::

    render(brdf, "sphere-env")         an image (linear RGB) and the variant used   mitsuba.py
    compare(reference, test, scene)    mean image difference and its noise floor     mitsuba.py
    render_sphere(brdf)                a sphere by direct evaluation (no Mitsuba)    sphere.py
"""

from .mitsuba import SCENES, Comparison, compare, render, save_image
from .sphere import render_sphere

__all__ = ["SCENES", "Comparison", "compare", "render", "render_sphere", "save_image"]
