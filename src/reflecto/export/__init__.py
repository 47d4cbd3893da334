"""Exchange formats: RGL .bsdf (RGB, as Mitsuba 3's ``measured`` plugin reads it) and MERL .binary.

::

    export_rgl(brdf, "m.bsdf")         tensor file for Mitsuba 3 (docs/mitsuba.md)   rgl.py
    export_merl(brdf, "m.binary")      MERL 90 × 90 × 180 table                      merl.py
"""

from .merl import export_merl
from .rgl import export_rgl

__all__ = ["export_merl", "export_rgl"]
