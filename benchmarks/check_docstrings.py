"""List the public functions, classes and methods of ``src/reflecto`` without a docstring.

Public: a name not starting with ``_``, in a module whose path has no part starting
with ``_`` (``__init__.py`` counts as public); property setters and overloads are
skipped. Prints ``file:line: name`` per missing docstring; exits 1 if there is any.

    python benchmarks/check_docstrings.py [src/reflecto]
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path


def missing_docstrings(root: Path) -> list[str]:
    """``file:line: qualified name`` of every public definition under ``root`` without a docstring."""
    out: list[str] = []
    for f in sorted(root.rglob("*.py")):
        rel = f.relative_to(root.parent)
        if any(p.startswith("_") and p != "__init__.py" for p in rel.parts):
            continue

        def visit(node: ast.AST, prefix: str) -> None:
            for n in ast.iter_child_nodes(node):
                if not isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)) or n.name.startswith("_"):
                    continue
                decorators = [ast.unparse(d) for d in n.decorator_list]
                if any(d.endswith(".setter") or d.endswith("overload") for d in decorators):
                    continue
                if ast.get_docstring(n) is None:
                    out.append(f"{rel}:{n.lineno}: {prefix}{n.name}")
                if isinstance(n, ast.ClassDef):
                    visit(n, f"{prefix}{n.name}.")

        visit(ast.parse(f.read_text(encoding="utf-8")), "")
    return out


if __name__ == "__main__":
    root = Path(sys.argv[1] if len(sys.argv) > 1 else Path(__file__).resolve().parents[1] / "src" / "reflecto")
    missing = missing_docstrings(root)
    print("\n".join(missing) if missing else "every public definition has a docstring")
    sys.exit(1 if missing else 0)
