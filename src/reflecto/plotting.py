"""Matplotlib helpers shared by the figure writers (headless backend, atomic PNG output)."""

from __future__ import annotations

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


def save_figure(fig: Any, path: str | Path, dpi: int = 90) -> Path:
    """Write ``fig`` as PNG atomically (temporary name, then rename) and close it."""
    path = Path(path)
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    pyplot().close(fig)
    return path
