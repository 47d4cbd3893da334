"""Matplotlib helpers shared by the figure writers (headless backend, atomic PNG output)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from .io import atomic_path


def pyplot() -> Any:
    """``matplotlib.pyplot`` with the non-interactive Agg backend and plain text (no mathtext)."""
    import matplotlib.pyplot as plt  # deferred: matplotlib is ~0.4 s of every command's start-up; only plots need it

    plt.switch_backend("Agg")
    # every text is plain: a material or file name with "$…$" in it is not maths markup (mathtext
    # would fail to parse "\foo"), and reflecto's labels write their symbols in Unicode
    plt.rcParams["text.parse_math"] = False
    return plt


_SUPERSCRIPT = str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹")


def power_of_ten(value: float, _position: Any = None) -> str:
    """A log axis's tick label in plain text: ``10⁻²`` at a power of ten, empty elsewhere
    (matplotlib's own labels are maths markup, which plain text shows as written).

    Parameters
    ----------
    value
        The tick's value (> 0).

    Returns
    -------
    str
        The label.
    """
    if not value > 0:
        return ""
    exponent = math.log10(value)
    if abs(exponent - round(exponent)) > 1e-9:
        return ""
    return "10" + str(int(round(exponent))).translate(_SUPERSCRIPT)


def plain_log_axis(ax: Any, which: str = "y") -> None:
    """Label a log-scaled axis of ``ax`` with :func:`power_of_ten` (major ticks) and no minor labels.

    Parameters
    ----------
    ax
        A matplotlib axes whose ``which`` axis (``"x"`` or ``"y"``) is log-scaled.
    """
    axis = ax.yaxis if which == "y" else ax.xaxis
    axis.set_major_formatter(power_of_ten)  # matplotlib wraps a function in a FuncFormatter
    axis.set_minor_formatter(lambda value, position: "")


def save_figure(fig: Any, path: str | Path, dpi: int = 90) -> Path:
    """Write ``fig`` as PNG atomically (temporary name, then rename) and close it."""
    path = Path(path)
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    pyplot().close(fig)
    return path
