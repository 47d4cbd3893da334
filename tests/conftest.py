from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"


@pytest.fixture(scope="session")
def shared() -> Path:
    if not SHARED.is_dir():
        pytest.fail(f"shared data not found at {SHARED}: clone the project with ../shared beside it")
    return SHARED


def random_directions(rng: np.random.Generator, n: int, max_theta_deg: float = 90.0) -> np.ndarray:
    """Uniform directions on the spherical cap θ ≤ max_theta_deg."""
    ct = rng.uniform(np.cos(np.radians(max_theta_deg)), 1.0, n)
    ph = rng.uniform(0.0, 2 * np.pi, n)
    st = np.sqrt(1 - ct * ct)
    return np.stack([st * np.cos(ph), st * np.sin(ph), ct], -1)


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)


# ------------------------------------------------------------ dependencies
import importlib  # noqa: E402
import os  # noqa: E402
import shutil  # noqa: E402


def in_ci() -> bool:
    """True when the ``CI`` environment variable says so (``CI=true``, as GitHub Actions and most CIs set it)."""
    return os.environ.get("CI", "").strip().lower() in ("true", "1", "yes")


def missing(reason: str) -> None:
    """A dependency that ``make test`` installs is absent: skip here, fail under ``CI=true``.

    ``make test`` installs Mitsuba, ``distributed``, LLVM and Chromium (Makefile), so in CI
    their absence is a broken install, not a reason to leave the suite green.
    """
    if in_ci():
        pytest.fail(f"{reason} (CI=true: `make test` installs this dependency, so its absence fails)", pytrace=False)
    pytest.skip(reason)


def require(*names: str):
    """The first of ``names`` that is available: an importable module (returned imported) or
    an executable on the PATH (its path returned). Otherwise :func:`missing` (skip; fail in CI).
    """
    for name in names:
        try:
            return importlib.import_module(name)
        except ImportError:
            pass
        if shutil.which(name):
            return shutil.which(name)
    missing(f"none of {', '.join(names)} is available")


def require_mitsuba(llvm: bool = False):
    """``(mitsuba, variant)`` from :func:`reflecto.mitsuba_support.import_mitsuba`; with ``llvm``
    the vectorised ``llvm_ad_rgb`` variant is required (it needs LLVM >= 16, ``make sysdeps``)."""
    try:
        from reflecto.mitsuba_support import import_mitsuba

        mi, variant = import_mitsuba("llvm_ad_rgb")
    except ImportError as e:
        missing(f"Mitsuba 3 cannot be imported here ({e}); install with `pip install mitsuba`")
    if llvm and not variant.startswith("llvm"):
        missing("needs Mitsuba's vectorised llvm_ad_rgb variant (LLVM >= 16; `make sysdeps` installs libllvm19)")
    return mi, variant


def json_out(capsys) -> dict:
    """The stdout of the last command: exactly one JSON document, nothing around it."""
    out = capsys.readouterr().out
    doc, end = json.JSONDecoder().raw_decode(out)
    assert out[end:].strip() == "", out[end:]
    return doc
