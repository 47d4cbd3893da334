"""Per-material tables the studies write (``-o FILE``)."""

from __future__ import annotations

import csv
import os
from pathlib import Path
from typing import Any


def write_rows(path: Path, rows: list[dict[str, Any]]) -> None:
    """``rows`` as a CSV file sorted by ``name``, the first row's keys as the header;
    written to a temporary file and renamed (parents created)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    with open(tmp, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(sorted(rows, key=lambda r: r["name"]))
    os.replace(tmp, path)
