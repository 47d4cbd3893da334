"""README.md's commands and Python blocks run as written.

Every ```sh and ```python block of the README is run from a work folder that behaves
like the project root: it holds a link ``examples`` to the project's examples, and
``../shared`` beside it links to the project's shared data; the commands write under
``out/qs/`` there. In a ```sh block each non-empty line that is not a comment is one
command (a trailing ``# comment`` is dropped); a leading ``reflecto`` runs this
interpreter's ``reflecto`` script. A ```python block runs in a fresh interpreter.

Skipped, and only these: ``make …`` lines (the set-up, which ``make test`` itself
is) and ``export PATH=…`` (the test puts the virtual environment's ``bin`` first on
the ``PATH`` of every command instead).

The blocks run concurrently, the lines of a block in order: each block of the README
starts from shipped files only (examples and shared data), never from another
block's outputs.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
BLOCK = re.compile(r"^```(sh|python)[ \t]*\n(.*?)^```[ \t]*$", re.S | re.M)
SKIPPED = ("make", "export PATH=")


def _reflecto() -> list[str]:
    script = Path(sys.executable).with_name("reflecto")
    return [str(script)] if script.is_file() else [sys.executable, "-m", "reflecto.cli"]


def readme_blocks(text: str) -> tuple[list[tuple[str, list]], list[str]]:
    """The README's runnable blocks (``("sh", [argv, ...])`` or ``("python", [source])``)
    and the lines skipped."""
    blocks, skipped = [], []
    for kind, body in BLOCK.findall(text):
        if kind == "python":
            blocks.append(("python", [body]))
            continue
        commands = []
        for line in body.splitlines():
            argv = shlex.split(line, comments=True)
            if not argv:
                continue
            if argv[0] == "make" or line.strip().startswith("export PATH="):
                skipped.append(line.strip())
                continue
            if argv[0] == "reflecto":
                argv = _reflecto() + argv[1:]
            commands.append(argv)
        if commands:
            blocks.append(("sh", commands))
    return blocks, skipped


def _run_block(kind: str, items: list, cwd: Path, env: dict[str, str]) -> list[tuple[str, float]]:
    """Run one block's commands in order; returns (command, seconds) per command."""
    times = []
    for k, item in enumerate(items):
        if kind == "python":
            script = cwd / f"readme_block_{id(item)}.py"
            script.write_text(item)
            argv, shown = [sys.executable, str(script)], "python block:\n" + item
        else:
            argv, shown = item, shlex.join(item)
        t0 = time.perf_counter()
        r = subprocess.run(argv, cwd=cwd, env=env, capture_output=True, text=True, timeout=300)
        times.append((shown.splitlines()[0] if kind == "sh" else "python block", time.perf_counter() - t0))
        assert r.returncode == 0, f"README {kind} command failed (exit {r.returncode}):\n{shown}\n--- stderr:\n{r.stderr[-3000:]}"
        if kind == "sh" and "-o" in item:  # the output it names exists
            out = cwd / item[item.index("-o") + 1]
            assert out.exists(), f"README command wrote no {out.relative_to(cwd)}:\n{shown}"
    return times


def test_readme_commands_and_python_run_as_written(tmp_path, capsys):
    blocks, skipped = readme_blocks(README.read_text(encoding="utf-8"))
    assert all(line.startswith(SKIPPED) for line in skipped), skipped
    assert sum(kind == "sh" for kind, _ in blocks) >= 2 and any(kind == "python" for kind, _ in blocks)
    assert sum(len(items) for kind, items in blocks if kind == "sh") >= 8

    work = tmp_path / "project"
    work.mkdir()
    (work / "examples").symlink_to(ROOT / "examples", target_is_directory=True)
    shared = ROOT.parent / "shared"
    if shared.exists():
        (tmp_path / "shared").symlink_to(shared.resolve(), target_is_directory=True)
    env = dict(os.environ)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    env.setdefault("MPLBACKEND", "Agg")

    t0 = time.perf_counter()
    with ThreadPoolExecutor(max_workers=len(blocks)) as pool:
        futures = [pool.submit(_run_block, kind, items, work, env) for kind, items in blocks]
        times = [f.result() for f in futures]
    total = time.perf_counter() - t0
    with capsys.disabled():
        slowest = max((t for block in times for t in block), key=lambda t: t[1])
        print(f"\n  README: {sum(map(len, times))} commands/blocks in {total:.1f} s "
              f"(slowest {slowest[1]:.1f} s: {slowest[0][:70]})")
