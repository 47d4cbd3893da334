"""The numbers the README and the docs quote, written from the result files by one command.

Every number below comes from the sweep tables ``docs/sweep-<device>.csv`` (one row per
material: errors of ours, the dense Cook–Torrance fit, the same-data fit and the earlier
device; the material's half; the reconstruction's seconds) and from the exports' tables
``docs/exports.csv`` and ``docs/exports-analytic.csv`` (``studies/validate_exports.py``:
each exported file, evaluated by Mitsuba, against its model). Each is written into a
marker-delimited block of a Markdown file::

    <!-- numbers:NAME -->
    ...generated text...
    <!-- /numbers:NAME -->

``make docs`` (``python studies/docs_numbers.py``) rewrites the blocks;
``--check`` exits 1 and names each block that differs from what the tables give
(``tests/test_docs.py`` runs it), so the README, docs/validation.md and the other
pages cannot disagree with the tables or with each other.
"""

from __future__ import annotations

import argparse
import csv
import re
import statistics
import sys
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
DEVICES = ("ideal", "as-built", "wide", "wide-as-built")
README_DEVICE_LABELS = {
    "ideal": "ideal (the paper's geometry)",
    "as-built": "as-built, calibrated",
    "wide": "`wide` (60° cone, 10 LEDs; [design study](docs/design-study.md))",
    "wide-as-built": "`wide-as-built`",
}


def rows(device: str) -> list[dict[str, str]]:
    """The sweep table of ``device`` (``docs/sweep-<device>.csv``)."""
    with (DOCS / f"sweep-{device}.csv").open(newline="") as fh:
        return list(csv.DictReader(fh))


def _below(rs: list[dict[str, str]], other: str) -> int:
    return sum(float(r["ours"]) < float(r[other]) for r in rs)


def _median(rs: list[dict[str, str]], key: str) -> float:
    return statistics.median(float(r[key]) for r in rs)


def _quantile(values: list[float], q: float) -> float:
    v = sorted(values)
    pos = q * (len(v) - 1)
    lo = int(pos)
    hi = min(lo + 1, len(v) - 1)
    return v[lo] + (pos - lo) * (v[hi] - v[lo])


def readme_sweep_table() -> str:
    """README: per device, ours < CT (tuning · validation), < same-data CT, < earlier, median ours/CT."""
    out = ["| device | ours < dense CT (tuning · validation) | ours < same-data CT | ours < earlier device | "
           "median ours / CT |", "|---|---|---|---|---|"]
    for dev in DEVICES:
        rs = rows(dev)
        n = len(rs)
        halves = [_below([r for r in rs if r["half"] == h], "cook_torrance") for h in ("tuning", "validation")]
        out.append(f"| {README_DEVICE_LABELS[dev]} | {_below(rs, 'cook_torrance')}/{n} ({halves[0]} · {halves[1]}) | "
                   f"{_below(rs, 'same_data_ct')}/{n} | {_below(rs, 'earlier')}/{n} | "
                   f"{_median(rs, 'ours_over_ct'):.2f} |")
    return "\n".join(out)


def validation_sweep_table() -> str:
    """docs/validation.md: the full table, per device and half."""
    out = ["| device | materials | ours < CT | ours < same-data CT | ours < earlier | median ours/CT | "
           "median ours/same-data CT | median error ours · CT · same-data CT · earlier |",
           "|---|---|---|---|---|---|---|---|"]
    for dev in DEVICES:
        rs_all = rows(dev)
        for label, rs in (("tuning", [r for r in rs_all if r["half"] == "tuning"]),
                          ("validation", [r for r in rs_all if r["half"] == "validation"]), ("all", rs_all)):
            n = len(rs)
            errs = " · ".join(f"{_median(rs, k):.3f}" for k in ("ours", "cook_torrance", "same_data_ct", "earlier"))
            out.append(f"| {dev} | {label} {n} | {_below(rs, 'cook_torrance')}/{n} | "
                       f"{_below(rs, 'same_data_ct')}/{n} | "
                       f"{_below(rs, 'earlier')}/{n} | {_median(rs, 'ours_over_ct'):.3f} | "
                       f"{_median(rs, 'ours_over_same_data_ct'):.3f} | {errs} |")
    return "\n".join(out)


def ours_below() -> str:
    """docs/validation.md, model ceiling table: how often ours beats CT (ideal device)."""
    rs = rows("ideal")
    n, below = len(rs), _below(rs, "cook_torrance")
    return f"{round(100 * below / n)} % ({below}/{n})"


def ours_count() -> str:
    """How many materials ours beats CT on, in words (ideal device)."""
    rs = rows("ideal")
    return f"{_below(rs, 'cook_torrance')} of {len(rs)}"


def ours_ratio() -> str:
    """The median of ours/CT on the ideal device, two decimals."""
    return f"{_median(rows('ideal'), 'ours_over_ct'):.2f}"


def ours_median() -> str:
    """The median error of ours on the ideal device."""
    return f"{_median(rows('ideal'), 'ours'):.3f}"


def speed() -> str:
    """The reconstruction's time per BRDF in the ideal sweep (wall clock, ``seconds_reconstruct``)."""
    s = [1000 * float(r["seconds_reconstruct"]) for r in rows("ideal")]
    return (f"median {statistics.median(s):.0f} ms, p90 {_quantile(s, 0.9):.0f} ms per BRDF "
            f"(the ideal sweep's `seconds_reconstruct`, {len(s)} materials)")


def _table(name: str) -> list[dict[str, str]]:
    with (DOCS / name).open(newline="") as fh:
        return list(csv.DictReader(fh))


def exports() -> str:
    """The 50 shared reconstructions' ``.bsdf`` exports read by Mitsuba against the models (eq. 10)."""
    rs = _table("exports.csv")
    err = [100 * float(r["error"]) for r in rs]
    sec = [float(r["export_seconds"]) for r in rs]
    mb = [float(r["size_mb"]) for r in rs]
    worst = max(rs, key=lambda r: float(r["error"]))
    layouts = sorted({r["layout"] for r in rs})
    return (f"eq. 10 error median {statistics.median(err):.3f} %, p90 {_quantile(err, 0.9):.3f} %, max "
            f"{max(err):.3f} % ({worst['name']}), {sum(e <= 2.0 for e in err)}/{len(rs)} within 2 %; export "
            f"median {statistics.median(sec):.2f} s, max {max(sec):.2f} s on one core; "
            f"{statistics.median(mb):.1f} MB per file ({' and '.join(layouts)} tables)")


def exports_analytic() -> str:
    """Analytic sources and their hemicube models, exported and read by Mitsuba."""
    rs = _table("exports-analytic.csv")
    err = [100 * float(r["error"]) for r in rs]
    med = [100 * float(r["pair_median"]) for r in rs]
    p95 = [100 * float(r["pair_p95"]) for r in rs]
    names = ", ".join(dict.fromkeys(r["name"] for r in rs))
    return (f"{names}, each analytic and as a 512² hemicube model: eq. 10 error ≤ {max(err):.2f} %, per-pair "
            f"relative difference median ≤ {max(med):.2f} %, p95 ≤ {max(p95):.2f} %")


#: (file, block name) → generator.
BLOCKS: dict[tuple[str, str], Callable[[], str]] = {
    ("README.md", "sweep-table"): readme_sweep_table,
    ("README.md", "speed"): speed,
    ("README.md", "ours-count"): ours_count,
    ("docs/validation.md", "sweep-table"): validation_sweep_table,
    ("docs/validation.md", "ours-below"): ours_below,
    ("docs/validation.md", "ours-ratio"): ours_ratio,
    ("docs/validation.md", "ours-median"): ours_median,
    ("docs/validation.md", "speed"): speed,
    ("docs/validation.md", "exports"): exports,
    ("docs/mitsuba.md", "exports"): exports,
    ("docs/mitsuba.md", "exports-analytic"): exports_analytic,
}


def _pattern(name: str) -> re.Pattern[str]:
    return re.compile(rf"(<!-- numbers:{re.escape(name)} -->)(.*?)(<!-- /numbers:{re.escape(name)} -->)", re.S)


def render(text: str, name: str, body: str) -> str:
    """``text`` with the block ``name`` holding ``body``; ValueError when the markers are missing."""
    pat = _pattern(name)
    if not pat.search(text):
        raise ValueError(f"no <!-- numbers:{name} --> block")
    inline = "\n" not in body
    return pat.sub(lambda m: m.group(1) + (body if inline else "\n" + body + "\n") + m.group(3), text, count=1)


def run(check: bool) -> list[str]:
    """Write (or, with ``check``, compare) every block; returns the blocks that differ or are missing."""
    stale = []
    files: dict[str, str] = {}
    for (rel, name), make in BLOCKS.items():
        text = files.get(rel) or (ROOT / rel).read_text()
        try:
            new = render(text, name, make())
        except ValueError as e:
            stale.append(f"{rel}: {e}")
            continue
        if new != text:
            stale.append(f"{rel}: block {name} differs from the tables")
        files[rel] = new
    if not check:
        for rel, text in files.items():
            if (ROOT / rel).read_text() != text:
                (ROOT / rel).write_text(text)
    return stale


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--check", action="store_true", help="change nothing; exit 1 if a block differs")
    args = ap.parse_args()
    stale = run(args.check)
    for line in stale:
        print(line)
    if args.check:
        return 1 if stale else 0
    print(f"wrote {len(BLOCKS)} blocks" + (f" ({len(stale)} changed)" if stale else " (unchanged)"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
