"""Matplotlib helpers shared by the figure writers (headless backend, atomic PNG output)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

from .io import atomic_path


def pyplot() -> Any:
    """``matplotlib.pyplot`` with the non-interactive Agg backend."""
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # deferred: pyplot costs ~0.4 s of start-up, and only plots need it

    return plt


def save_figure(fig: Any, path: str | Path, dpi: int = 90) -> Path:
    """Write ``fig`` as PNG atomically (temporary name, then rename) and close it."""
    path = Path(path)
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    pyplot().close(fig)
    return path
