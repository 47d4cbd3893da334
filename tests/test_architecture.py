"""The package's structure: layers that import only downward, no import cycle, few deferred imports.

Every ``import`` of a ``reflecto`` module, at module level or inside a function, is read
from the source (``ast``), so the check needs no import to run and sees the imports a
deferred statement would hide.
"""

from __future__ import annotations

import ast
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src" / "reflecto"

#: Units from the bottom up: a unit imports only units of lower layers (and itself).
#: A unit is a top-level module or a subpackage (all its modules).
LAYERS: list[set[str]] = [
    {"errors", "geometry", "colour", "_kernels"},
    {"io", "batch", "kinds"},
    {"fresnel", "polar", "hemicube", "brdf", "plotting"},
    {"shadowing", "mitsuba_support"},
    {"model", "sources"},
    {"load"},
    {"instrument"},
    {"reconstruct", "export"},
    {"render"},
    {"workflow"},
    {"evaluate"},
    {"watch"},
    {"cli", "__init__", "__main__"},
]

#: Imports inside functions allowed in ``src/reflecto`` (each states its reason in a comment).
MAX_DEFERRED = 10


def _module_name(path: Path) -> str:
    rel = path.relative_to(SRC.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in sorted(SRC.rglob("*.py"))}


def _resolve(module: str, is_package: bool, node: ast.ImportFrom) -> str:
    if node.level == 0:
        return node.module or ""
    base = module.split(".") if is_package else module.split(".")[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _imports(mods: dict[str, Path]) -> list[tuple[str, str, int, bool, str]]:
    """``(importer, imported, line, deferred, source line)`` for every import of a reflecto module."""
    out = []
    for mod, path in mods.items():
        text = path.read_text()
        lines = text.splitlines()
        tree = ast.parse(text)
        deferred_nodes = {id(n) for f in ast.walk(tree) if isinstance(f, (ast.FunctionDef, ast.AsyncFunctionDef))
                          for n in ast.walk(f) if isinstance(n, (ast.Import, ast.ImportFrom))}
        for node in ast.walk(tree):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = _resolve(mod, path.name == "__init__.py", node)
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in mods else base for a in node.names]
            else:
                continue
            for t in targets:
                out.append((mod, t, node.lineno, id(node) in deferred_nodes, lines[node.lineno - 1]))
    return out


def _unit(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def _layer(unit: str) -> int:
    for k, layer in enumerate(LAYERS):
        if unit in layer:
            return k
    raise AssertionError(f"module unit {unit!r} is in no layer of tests/test_architecture.py: place it")


def test_every_import_points_down_the_layers():
    mods = _modules()
    upward = []
    for a, b, line, _, _ in _imports(mods):
        if not b.startswith("reflecto.") or not (b in mods or b.rsplit(".", 1)[0] in mods):
            continue
        ua, ub = _unit(a), _unit(b)
        if ua != ub and _layer(ub) >= _layer(ua):
            upward.append(f"{a}:{line} imports {b} ({ua} is not above {ub})")
    assert not upward, "\n".join(upward)


def test_no_import_cycle_between_modules():
    mods = _modules()
    graph: dict[str, set[str]] = {m: set() for m in mods}
    for a, b, _, _, _ in _imports(mods):
        target = b if b in mods else b.rsplit(".", 1)[0]
        if target in mods and target != a and not a.startswith(target + "."):
            graph[a].add(target)
    # Tarjan's strongly connected components
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    cycles: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                cycles.append(sorted(comp))

    for v in graph:
        if v not in index:
            visit(v)
    assert not cycles, f"import cycles: {cycles}"


def test_deferred_imports_are_few_and_say_why():
    mods = _modules()
    deferred = {}
    for mod, path in mods.items():
        text = path.read_text()
        lines = text.splitlines()
        for f in ast.walk(ast.parse(text)):
            if isinstance(f, (ast.FunctionDef, ast.AsyncFunctionDef)):
                for n in ast.walk(f):
                    if isinstance(n, (ast.Import, ast.ImportFrom)):
                        deferred[(mod, n.lineno)] = lines[n.lineno - 1]
    assert len(deferred) <= MAX_DEFERRED, f"{len(deferred)} function-level imports: {sorted(deferred)}"
    unexplained = [f"{m}:{line}" for (m, line), text in deferred.items() if "# deferred:" not in text]
    assert not unexplained, f"function-level imports without a '# deferred: reason' comment: {unexplained}"


def test_the_layer_check_sees_an_upward_import(tmp_path):
    """The check itself: a low module importing a high one is found (not a test that cannot fail)."""
    assert _layer("errors") < _layer("workflow") < _layer("cli")
    fake = ast.parse("from .workflow import capture_to_model\n").body[0]
    assert isinstance(fake, ast.ImportFrom)
    assert _resolve("reflecto.geometry", False, fake) == "reflecto.workflow"
    assert _layer(_unit("reflecto.workflow")) >= _layer(_unit("reflecto.geometry"))


def test_capture_to_model_is_written_once():
    """``extract_slices(`` and the calibration choice are called in reflecto.workflow alone."""
    calls = ("extract_slices(", "nominal_calibration(", "load_calibration(", "needs_calibration(")
    root = SRC.parents[1]
    offenders = []
    for folder in ("src", "studies", "benchmarks", "examples"):
        for path in sorted((root / folder).rglob("*.py")):
            if path.name == "workflow.py":
                continue
            for k, line in enumerate(path.read_text().splitlines(), 1):
                code = line.split("#", 1)[0]
                if any(c in code for c in calls) and not code.lstrip().startswith("def "):
                    offenders.append(f"{path.relative_to(root)}:{k}: {line.strip()}")
    # the definitions' own modules may call each other (load_calibration's default, needs_calibration's use)
    offenders = [o for o in offenders if not o.startswith(("src/reflecto/instrument/calibrate.py",
                                                           "src/reflecto/instrument/slices.py"))]
    assert not offenders, "\n".join(offenders)


def test_studies_benchmarks_and_examples_import_names_that_exist():
    """Every ``from reflecto… import NAME`` in studies/, benchmarks/ and examples/ (also inside
    functions) names something the module has: a study that rots when the package moves a
    name fails here, not on the day someone reruns it."""
    import importlib

    root = SRC.parents[1]
    missing = []
    for folder in ("studies", "benchmarks", "examples"):
        for path in sorted((root / folder).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("reflecto"):
                    module = importlib.import_module(node.module)
                    missing += [f"{path.relative_to(root)}:{node.lineno}: {node.module}.{a.name}"
                                for a in node.names
                                if not hasattr(module, a.name)
                                and importlib.util.find_spec(f"{node.module}.{a.name}") is None]
    assert not missing, "\n".join(missing)
