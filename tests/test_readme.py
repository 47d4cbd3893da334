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

import numpy as np
import pytest

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


#: (kind, README command without the ``reflecto`` prefix or Python source, stdout) of every command run
OUTPUTS: list[tuple[str, object, str]] = []


def _run_block(kind: str, items: list, cwd: Path, env: dict[str, str]) -> list[tuple[str, float]]:
    """Run one block's commands in order; returns (command, seconds) per command and records
    each command's stdout in :data:`OUTPUTS`."""
    times = []
    for item in items:
        if kind == "python":
            script = cwd / f"readme_block_{id(item)}.py"
            script.write_text(item)
            argv, shown = [sys.executable, str(script)], "python block:\n" + item
        else:
            argv, shown = item, shlex.join(item)
        t0 = time.perf_counter()
        r = subprocess.run(argv, cwd=cwd, env=env, capture_output=True, text=True, timeout=300)
        times.append((shown.splitlines()[0] if kind == "sh" else "python block", time.perf_counter() - t0))
        assert r.returncode == 0, (f"README {kind} command failed (exit {r.returncode}):\n{shown}\n"
                                   f"--- stderr:\n{r.stderr[-3000:]}")
        readme_argv = item[len(_reflecto()):] if kind == "sh" and item[0] == _reflecto()[0] else item
        OUTPUTS.append((kind, readme_argv, r.stdout))
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

    OUTPUTS.clear()
    t0 = time.perf_counter()
    with ThreadPoolExecutor(max_workers=len(blocks)) as pool:
        futures = [pool.submit(_run_block, kind, items, work, env) for kind, items in blocks]
        times = [f.result() for f in futures]
    total = time.perf_counter() - t0
    with capsys.disabled():
        slowest = max((t for block in times for t in block), key=lambda t: t[1])
        print(f"\n  README: {sum(map(len, times))} commands/blocks in {total:.1f} s "
              f"(slowest {slowest[1]:.1f} s: {slowest[0][:70]})")
    _check_printed_numbers(work)


# ------------------------------------------------------------------ what the tour prints
FLOAT = r"[-+]?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?"


def _numbers(text: str) -> list[float]:
    return [float(x) for x in re.findall(FLOAT, text)]


def _output(*prefix: str) -> str:
    """The stdout of the README's sh command that starts with ``prefix`` (after ``reflecto``)."""
    hits = [out for kind, argv, out in OUTPUTS if kind == "sh" and tuple(argv[: len(prefix)]) == prefix]
    assert len(hits) == 1, (prefix, len(hits))
    return hits[0]


def _summary(line_start: str, text: str) -> dict[str, list[float]]:
    """``eta 1.497, kd [..], ks [..], tilt 0.00°`` of a reconstruct summary line."""
    line = next(x for x in text.splitlines() if x.startswith(line_start))
    return {key: _numbers(m) for key, m in re.findall(r"(eta|kd|ks|tilt) (\[[^]]*\]|\S+?)(?:,|°)", line)}


def _check_printed_numbers(work: Path) -> None:
    """The numbers the README's commands and Python tour print, against ground truth: the
    analytic sources' own parameters and albedo, and bounds on the reconstruction's accuracy."""
    import ast
    import json

    from reflecto import load_source
    from reflecto.evaluate.metrics import max_albedo

    plastic = json.loads((ROOT / "examples" / "ggx-plastic.json").read_text())
    src = load_source(ROOT / "examples" / "ggx-plastic.json")
    # reflecto info: the file's parameters and the source's directional albedo
    info = _output("info", "examples/ggx-plastic.json")
    rows = {line.split()[0]: line for line in info.splitlines() if line.strip()}
    assert _numbers(rows["kd"]) == plastic["kd"] and _numbers(rows["ks"]) == [plastic["ks"]] * 3
    assert _numbers(rows["eta"]) == [plastic["eta"]] * 3 and _numbers(rows["alpha"]) == [plastic["alpha"]] * 2
    for theta in (0, 20, 40, 60, 80):
        printed = _numbers(next(x for x in info.splitlines() if x.strip().startswith(f"{theta}deg")))[1:]
        assert np.allclose(printed, src.albedo([theta])[0], atol=6e-5), (theta, printed)
    # reflecto reconstruct (ideal device, flat): η, k_d, k_s of the source
    got = _summary("out/qs/plastic.reflecto", _output("reconstruct", "out/qs/capture"))
    assert abs(got["eta"][0] - plastic["eta"]) <= 0.01, got
    assert np.allclose(got["kd"], plastic["kd"], atol=0.005) and np.allclose(got["ks"], plastic["ks"], rtol=0.03), got
    assert got["tilt"] == [0.0]
    # reflecto compare: eq. 10 normalized by the reference's max albedo (measured 0.033 % for this pair)
    cmp = _output("compare", "examples/ggx-plastic.json", "out/qs/plastic.reflecto")
    line = next(x for x in cmp.splitlines() if "normalized error" in x)
    err_percent, albedo = _numbers(line)[0], _numbers(line)[-1]  # "normalized error 0.033 % (… albedo …, 0.3166)"
    assert 0.0 < err_percent <= 0.2 and albedo == pytest.approx(max_albedo(src), abs=6e-5), line
    # the hand-held capture (as-built device, 5° tilt): the tilt is recovered
    got = _summary("out/qs/tilted.reflecto", _output("reconstruct", "out/qs/tilted"))
    assert abs(got["tilt"][0] - 5.0) <= 0.5 and abs(got["eta"][0] - plastic["eta"]) <= 0.1, got

    # the Python tour: its truth (parsed from the block), a 5° tilt, printed η, k_d, k_s, tilt, isotropy,
    # eq. 10 and the Cook–Torrance fit
    source, out = next((item, out) for kind, item, out in OUTPUTS if kind == "python" and "simulate_capture" in item)
    call = next(n for n in ast.walk(ast.parse(source))
                if isinstance(n, ast.Call) and getattr(n.func, "id", "") == "AnalyticBRDF")
    truth = {k.arg: ast.literal_eval(k.value) for k in call.keywords}
    tilt = next(ast.literal_eval(k.value) for n in ast.walk(ast.parse(source)) if isinstance(n, ast.Call)
                for k in n.keywords if k.arg == "tilt_deg")
    first, second, third = out.strip().splitlines()
    nums = _numbers(first)
    assert first.rstrip().endswith("True")  # isotropic
    eta, kd, ks, normal_tilt = nums[0], nums[1:4], nums[4:7], nums[7]
    assert abs(eta - truth["eta"]) <= 0.01 and np.allclose(kd, truth["kd"], atol=0.005), first
    # k_s within 3 %: normals within 0.02° of the true one give 0.599–0.613 on this capture (the true one 0.609)
    assert np.allclose(ks, truth["ks"], rtol=0.03) and abs(normal_tilt - tilt) <= 0.1, first
    assert 0.0 < float(second) <= 0.002, second  # eq. 10 normalized
    ct = ast.literal_eval(third)
    # the dense Cook–Torrance fit: its diffuse albedo is the source's k_d, its Beckmann m near GGX's α
    assert np.allclose(ct["rho_d"], truth["kd"], rtol=0.05) and abs(ct["m"] - truth["alpha"]) <= 0.05, ct
    assert 0.0 < ct["F0"] < 0.2 and np.all(np.array(ct["rho_s"]) > 0), ct
