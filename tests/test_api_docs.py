"""What a user sees: ``help()`` of every public name of the API documents it.

The public API is every name in ``__all__`` of the modules below (or, for a module
without ``__all__``, every function and class it defines whose name has no leading
underscore), with the public methods of those classes. Every public callable has a
docstring. In the modules of :data:`COVERED`, every public function or method that
takes parameters has a numpydoc ``Parameters`` section, and one that returns a value
(return annotation not ``None``) a ``Returns`` (or ``Yields``) section.
"""

from __future__ import annotations

import importlib
import inspect
import re
from collections.abc import Callable, Iterator
from typing import Any

import pytest

#: The modules whose public names make the API (``reflecto.reconstruct``: its package ``__all__`` only).
PUBLIC_MODULES = [
    "reflecto",
    "reflecto.batch",
    "reflecto.brdf",
    "reflecto.colour",
    "reflecto.evaluate",
    "reflecto.evaluate.cooktorrance",
    "reflecto.evaluate.design",
    "reflecto.evaluate.gallery",
    "reflecto.evaluate.metrics",
    "reflecto.evaluate.plots",
    "reflecto.evaluate.report",
    "reflecto.evaluate.split",
    "reflecto.evaluate.sweep",
    "reflecto.evaluate.viewer",
    "reflecto.export",
    "reflecto.export.merl",
    "reflecto.export.rgl",
    "reflecto.fresnel",
    "reflecto.geometry",
    "reflecto.hemicube",
    "reflecto.instrument",
    "reflecto.instrument.calibrate",
    "reflecto.instrument.capture",
    "reflecto.instrument.device",
    "reflecto.instrument.hdr",
    "reflecto.instrument.layout",
    "reflecto.instrument.optics",
    "reflecto.instrument.plots",
    "reflecto.instrument.simulate",
    "reflecto.instrument.slices",
    "reflecto.io",
    "reflecto.kinds",
    "reflecto.load",
    "reflecto.model",
    "reflecto.reconstruct",
    "reflecto.render",
    "reflecto.render.mitsuba",
    "reflecto.render.sphere",
    "reflecto.shadowing",
    "reflecto.sources",
    "reflecto.sources.analytic",
    "reflecto.sources.merl",
    "reflecto.sources.nbrdf",
    "reflecto.sources.rgl",
    "reflecto.watch",
    "reflecto.workflow",
]

#: Packages among :data:`PUBLIC_MODULES`: their names come from the modules that define them.
PACKAGES = {"reflecto", "reflecto.evaluate", "reflecto.export", "reflecto.instrument", "reflecto.reconstruct",
            "reflecto.render", "reflecto.sources"}
#: Defining modules whose public functions and methods must have ``Parameters`` and ``Returns`` sections:
#: every public module but the packages and ``reflecto.colour`` (its public names are constants), and the
#: modules behind ``reflecto.reconstruct``'s ``__all__``.
#: A name of :data:`PUBLIC_MODULES` is checked by the module that defines it (``obj.__module__``).
COVERED = (set(PUBLIC_MODULES) - PACKAGES - {"reflecto.colour"}) | {
    "reflecto.reconstruct.asymmetric", "reflecto.reconstruct.isotropy", "reflecto.reconstruct.motion",
    "reflecto.reconstruct.pipeline"}

_PARAMETERS = re.compile(r"^\s*Parameters\n\s*-{3,}\s*$", re.M)
_RETURNS = re.compile(r"^\s*(Returns|Yields)\n\s*-{3,}\s*$", re.M)


def _public_names(module: Any) -> list[str]:
    names = getattr(module, "__all__", None)
    if names is not None:
        return list(names)
    return [n for n, obj in vars(module).items()
            if not n.startswith("_") and (inspect.isfunction(obj) or inspect.isclass(obj))
            and getattr(obj, "__module__", None) == module.__name__]


def _function(obj: Any) -> Callable[..., Any] | None:
    """The plain function behind ``obj`` (unwrapping caches and class/static methods), or None."""
    if isinstance(obj, (classmethod, staticmethod)):
        obj = obj.__func__
    obj = inspect.unwrap(obj) if callable(obj) else obj
    return obj if inspect.isfunction(obj) else None


def _api() -> Iterator[tuple[str, str, Any]]:
    """``(qualified name, defining module, object)`` of every public function, class, method and property."""
    seen: set[int] = set()
    for module_name in PUBLIC_MODULES:
        module = importlib.import_module(module_name)
        for name in _public_names(module):
            obj = getattr(module, name)
            if id(obj) in seen or not (callable(obj) and (inspect.isclass(obj) or _function(obj))):
                continue
            seen.add(id(obj))
            owner = getattr(obj, "__module__", module_name)
            yield f"{owner}.{name}", owner, obj
            if inspect.isclass(obj):
                for attr, member in vars(obj).items():
                    if attr.startswith("_") and attr != "__call__":
                        continue
                    if isinstance(member, property) or _function(member) is not None:
                        yield f"{owner}.{name}.{attr}", owner, member


def _doc(obj: Any) -> str:
    return inspect.getdoc(obj.fget if isinstance(obj, property) else (_function(obj) or obj)) or ""


def missing_sections(func: Callable[..., Any]) -> list[str]:
    """The sections ``func``'s docstring lacks: ``Parameters`` if it takes any, ``Returns`` if it returns a value."""
    doc = inspect.getdoc(func) or ""
    sig = inspect.signature(func)
    params = [p for p in sig.parameters if p not in ("self", "cls")]
    out = []
    if params and not _PARAMETERS.search(doc):
        out.append("Parameters")
    ret = sig.return_annotation
    if ret is not inspect.Signature.empty and ret not in (None, "None") and not _RETURNS.search(doc):
        out.append("Returns")
    return out


def test_every_name_in_all_is_defined():
    missing = [f"{m}.{n}" for m in PUBLIC_MODULES for n in getattr(importlib.import_module(m), "__all__", [])
               if not hasattr(importlib.import_module(m), n)]
    assert not missing, missing


def test_the_api_is_found():
    names = {q for q, _, _ in _api()}
    assert "reflecto.model.load_model" in names
    assert "reflecto.model.MicrofacetBRDF.eval" in names
    assert "reflecto.hemicube.hemicube" in names  # an lru_cache'd function
    assert len(names) > 300


def test_every_public_callable_has_a_docstring():
    bare = [q for q, _, obj in _api() if not _doc(obj).strip()]
    assert not bare, "\n".join(bare)


def test_covered_functions_have_parameters_and_returns_sections():
    assert COVERED <= {owner for _, owner, _ in _api()}, "a covered module no public name comes from"
    problems = []
    for qualname, owner, obj in _api():
        func = _function(obj)
        if owner in COVERED and func is not None and not inspect.isclass(obj):
            lacks = missing_sections(func)
            if lacks:
                problems.append(f"{qualname}: no {' or '.join(lacks)} section")
    assert not problems, "\n".join(problems)


def _undocumented(x: float) -> float:
    """Twice ``x``."""
    return 2 * x


def _documented(x: float) -> None:
    """Nothing.

    Parameters
    ----------
    x
        Ignored.
    """


@pytest.mark.parametrize(("func", "expected"), [(_undocumented, ["Parameters", "Returns"]), (_documented, [])])
def test_the_section_check_sees_a_missing_section(func, expected):
    assert missing_sections(func) == expected
