"""Finding and configuring Mitsuba 3 (reference reader of ``.bsdf`` files, renderer).

Mitsuba's ``llvm_ad_rgb`` variant needs LLVM ≥ 16 (``DRJIT_LIBLLVM_PATH``); where none is
found we fall back to ``scalar_rgb``, which works everywhere.
"""

from __future__ import annotations

import glob
import os
import re
from types import ModuleType

_LLVM_GLOBS = (
    "/usr/lib/*/libLLVM-[0-9]*.so*",
    "/usr/lib/*/libLLVM.so.[0-9]*",
    "/usr/lib/llvm-*/lib/libLLVM*.so*",
    "/usr/local/lib/libLLVM*.so*",
)


def find_libllvm(min_major: int = 16) -> str | None:
    """Path of the newest ``libLLVM`` shared library with major version ≥ ``min_major``."""
    env = os.environ.get("DRJIT_LIBLLVM_PATH")
    if env and os.path.exists(env):
        return env
    best: tuple[int, str] | None = None
    for pattern in _LLVM_GLOBS:
        for path in glob.glob(pattern):
            m = re.search(r"(?:LLVM-|LLVM\.so\.|llvm-)(\d+)", path)
            if m and int(m.group(1)) >= min_major and (best is None or int(m.group(1)) > best[0]):
                best = (int(m.group(1)), path)
    return best[1] if best else None


def import_mitsuba(prefer: str = "llvm_ad_rgb") -> tuple[ModuleType, str]:
    """Import Mitsuba and set a variant: ``prefer`` if usable, else ``scalar_rgb``.

    Raises ``ImportError`` if Mitsuba is not installed.
    """
    if prefer.startswith("llvm"):
        lib = find_libllvm()
        if lib:
            os.environ.setdefault("DRJIT_LIBLLVM_PATH", lib)
    import mitsuba as mi

    for variant in (prefer, "scalar_rgb"):
        if variant.startswith("llvm") and not os.environ.get("DRJIT_LIBLLVM_PATH"):
            continue
        try:
            mi.set_variant(variant)
            if variant.startswith("llvm"):
                import drjit as dr

                dr.zeros(mi.Float, 4)  # force the JIT to load LLVM now
            return mi, variant
        except Exception:  # noqa: BLE001 - any failure means: try the next variant
            continue
    raise ImportError("no usable Mitsuba variant (tried llvm_ad_rgb and scalar_rgb)")
