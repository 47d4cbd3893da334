from __future__ import annotations

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
