import h5py
import numpy as np
import pytest

from conftest import random_directions
from reflecto.errors import FileFormatError
from reflecto.load import load_source
from reflecto.sources import NBRDF


def test_all_shared_nbrdf_materials(shared, rng):
    files = sorted((shared / "merl-nbrdf").glob("*.h5"))
    assert len(files) == 40
    i, o = random_directions(rng, 5000, 85), random_directions(rng, 5000, 85)
    for f in files:
        src = load_source(f)
        assert isinstance(src, NBRDF)
        a = src.eval(i, o)
        assert np.all(np.isfinite(a)) and np.all(a >= 0), f.name
        assert np.allclose(a, src.eval(o, i), rtol=1e-6, atol=1e-12), f.name


def test_known_material_is_plausible(shared):
    # white-acrylic is neutral and diffuse-dominated (MERL's absolute scale: albedo ≈ 0.3);
    # chrome-steel is a sharp metal
    wa = load_source(shared / "merl-nbrdf" / "white-acrylic.h5").albedo([0, 30])
    assert np.all(wa > 0.2) and np.all(wa < 1.05)
    assert wa.max() / wa.min() < 1.3
    cs = load_source(shared / "merl-nbrdf" / "chrome-steel.h5")
    n = np.array([[0.0, 0.0, 1.0]])
    off = np.array([[np.sin(0.5), 0.0, np.cos(0.5)]])
    assert cs.eval(n, n).min() > 100 * cs.eval(n, off).max()


def test_bad_h5(tmp_path):
    p = tmp_path / "bad.h5"
    with h5py.File(p, "w") as f:
        f.create_dataset("dense_1/dense_1/kernel:0", data=np.zeros((6, 21), "f4"))
        f.create_dataset("dense_1/dense_1/bias:0", data=np.zeros(21, "f4"))
    with pytest.raises(FileFormatError, match="bad.h5: missing layer 'dense_2'"):
        load_source(p)
    p.write_bytes(b"not hdf5 at all")
    with pytest.raises(FileFormatError, match="bad.h5"):
        NBRDF(p)
