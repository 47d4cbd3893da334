"""Colour constants shared across reflecto.

``LUM``: Rec. 709 / sRGB luminance weights of linear R, G, B (ITU-R BT.709-6, item 3.2),
used wherever one scalar per RGB sample is needed (fit weights, tabulation, plots).
"""

from __future__ import annotations

import numpy as np

LUM = np.array([0.2126, 0.7152, 0.0722])
LUM.setflags(write=False)
