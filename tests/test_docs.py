"""The docs state the current mechanism and the current numbers: the numbers come from
one generator (studies/docs_numbers.py), and no page or docstring reads like a log."""

import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: Phrases that tell a history instead of the present mechanism (case-insensitive, whole words).
HISTORY = ["today's", "not kept", "previously", "tried first", "was tried", "no longer", "formerly", "came out",
           "used to be", "was measured", "were measured", "this was", "with a prototype", "at first", "originally",
           "was changed", "we tried", "before the fix", "now fixed"]
_PATTERN = re.compile(r"\b(" + "|".join(re.escape(p) for p in HISTORY) + r")\b", re.I)


def _texts() -> list[tuple[str, str]]:
    out = [(str(p.relative_to(ROOT)), p.read_text())
           for p in [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]]
    for p in sorted((ROOT / "src" / "reflecto").rglob("*.py")):
        tree = ast.parse(p.read_text())
        for node in ast.walk(tree):
            if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
                doc = ast.get_docstring(node)
                if doc:
                    out.append((f"{p.relative_to(ROOT)}:{getattr(node, 'lineno', 1)}", doc))
    return out


def test_no_history_phrasing_in_readme_docs_or_docstrings():
    hits = [f"{where}: {m.group(0)!r} in …{text[max(0, m.start() - 40):m.end() + 40]!r}…"
            for where, text in _texts() for m in _PATTERN.finditer(text)]
    assert not hits, "\n".join(hits)


def test_the_history_check_sees_a_hit():
    assert _PATTERN.search("Three remedies were measured (not kept).")
    assert not _PATTERN.search("The fit keeps the round with the lowest misfit.")


def test_quoted_numbers_agree_with_the_result_files():
    r = subprocess.run([sys.executable, str(ROOT / "studies" / "docs_numbers.py"), "--check"], capture_output=True,
                       text=True)
    assert r.returncode == 0, r.stdout + r.stderr


def test_the_numbers_check_sees_a_stale_block(monkeypatch):
    sys.path.insert(0, str(ROOT / "studies"))
    import docs_numbers

    text = "x <!-- numbers:speed -->median 1 ms<!-- /numbers:speed --> y"
    assert docs_numbers.render(text, "speed", docs_numbers.speed()) != text
    import csv
    import statistics

    with open(ROOT / "docs" / "sweep-ideal.csv") as fh:
        ms = [1000 * float(r["seconds_reconstruct"]) for r in csv.DictReader(fh)]
    assert f"median {statistics.median(ms):.0f} ms" in docs_numbers.speed()  # ms first, as the block: 233.5 rounds
    with pytest.raises(ValueError, match="no <!-- numbers:speed --> block"):
        docs_numbers.render("no block", "speed", "1")
