import numpy as np
import pytest

from conftest import random_directions
from reflecto import geometry as g
from reflecto.errors import FileFormatError
from reflecto.load import load_source
from reflecto.sources import merl
from reflecto.sources.analytic import AnalyticBRDF


@pytest.fixture(scope="module")
def table():
    src = AnalyticBRDF(distribution="beckmann", alpha=0.25, kd=[0.3, 0.2, 0.1], ks=0.6, eta=1.6)
    return src, merl.tabulate(src)


def test_round_trip_and_bin_centre_values(table, tmp_path):
    src, t = table
    p = merl.write_merl_table(tmp_path / "a.binary", t)
    assert p.stat().st_size == merl.FILE_BYTES
    back = merl.read_merl_table(p)
    ulp = np.spacing(np.abs(t))
    assert np.all(np.abs(back - t) <= ulp)  # within one ulp for arbitrary float64 values
    # bitwise exact for everything the encoding can represent: read → write → read
    p2 = merl.write_merl_table(tmp_path / "b.binary", back)
    assert p2.read_bytes() == p.read_bytes()
    assert np.array_equal(merl.read_merl_table(p2), back)
    # eval at the bin centres returns the tabulated values
    b = load_source(p)
    i, o = merl.bin_directions()
    sel = (slice(None, None, 7), slice(None, None, 5), slice(None, None, 11))
    ii, oo = i[sel].reshape(-1, 3), o[sel].reshape(-1, 3)
    ok = (ii[:, 2] > 0) & (oo[:, 2] > 0)
    assert np.array_equal(b.eval(ii[ok], oo[ok]), back[sel].reshape(-1, 3)[ok])
    assert np.allclose(b.eval(ii[ok], oo[ok]), src.eval(ii[ok], oo[ok]), rtol=1e-12)


def test_indices_at_bin_edges():
    k = np.arange(90)
    assert np.array_equal(merl.theta_h_index(merl.theta_h_edge(k)), k)
    assert np.array_equal(merl.theta_h_index(np.nextafter(merl.theta_h_edge(k[1:]), 0)), k[:-1])
    assert np.array_equal(merl.theta_d_index(np.radians(k)), k)
    assert np.array_equal(merl.theta_d_index(np.nextafter(np.radians(k[1:]), 0)), k[:-1])
    kp = np.arange(180)
    assert np.array_equal(merl.phi_d_index(np.radians(kp)), kp)
    assert merl.theta_h_index(np.pi / 2) == 89 and merl.theta_h_index(-0.1) == 0
    th, td, pd = merl.bin_centres()
    assert np.array_equal(merl.theta_h_index(th), k)
    assert np.array_equal(merl.theta_d_index(td), k)
    assert np.array_equal(merl.phi_d_index(pd), kp)
    assert np.array_equal(merl.phi_d_index(pd - np.pi), kp)  # reciprocity fold of φ_d < 0
    # φ_d = π (an in-plane pair: atan2's (−π, π]) floors to 180 and is clamped into the last bin,
    # as readBRDF.cpp does; folding it to bin 0 read another bin than MERL's reader
    assert merl.phi_d_index(np.pi) == 179 and merl.phi_d_index(np.nextafter(np.pi, 0)) == 179
    assert merl.phi_d_index(0.0) == 0 and merl.phi_d_index(-1e-300) == 179  # −0 + π rounds to π
    # index formula of the spec
    i, o = g.hd_to_io(th[3], 0.0, td[40], pd[100])
    assert merl.bin_index(i, o) == 100 + 180 * 40 + 180 * 90 * 3


def test_reciprocal_lookup(table, rng):
    _, t = table
    b = merl.MerlBRDF.from_table(t)
    i, o = random_directions(rng, 20000), random_directions(rng, 20000)
    assert np.array_equal(b.eval(i, o), b.eval(o, i))


def test_invalid_bins_and_bad_files(table, tmp_path):
    _, t = table
    t = t.copy()
    t[10:20] = -1.0 * merl.SCALE
    p = merl.write_merl_table(tmp_path / "inv.binary", t)
    b = merl.MerlBRDF(p)
    assert b.parameters()["invalid_bins"] == 10 * 90 * 180
    raw = p.read_bytes()
    (tmp_path / "trunc.binary").write_bytes(raw[:-8])
    with pytest.raises(FileFormatError, match="trunc.binary: truncated"):
        load_source(tmp_path / "trunc.binary")
    (tmp_path / "short.binary").write_bytes(raw[:6])
    with pytest.raises(FileFormatError, match="short.binary"):
        load_source(tmp_path / "short.binary")
    wrong = np.array([90, 90, 360], "<i4").tobytes() + raw[12:]
    (tmp_path / "dims.binary").write_bytes(wrong)
    with pytest.raises(FileFormatError, match="dimensions"):
        load_source(tmp_path / "dims.binary")
    nan = bytearray(raw)
    nan[12 + 8 * 1000 : 12 + 8 * 1001] = np.array([np.nan], "<f8").tobytes()
    (tmp_path / "nan.binary").write_bytes(bytes(nan))
    with pytest.raises(FileFormatError, match="NaN"):
        load_source(tmp_path / "nan.binary")


def test_a_source_with_non_finite_values_is_a_parameter_error_naming_it():
    """A source that gives NaN at some MERL bins (a model that passes the plausibility sample but
    overflows elsewhere) is one ParameterError naming it, which the CLI prints as one line."""
    from reflecto.brdf import BRDFSource
    from reflecto.errors import ParameterError
    from reflecto.sources import merl

    class NaNAt(BRDFSource):
        kind, isotropic, path = "test", True, None

        def eval(self, i, o):
            v = np.full((len(i), 3), 0.1)
            v[::997] = np.nan
            return v

    with pytest.raises(ParameterError, match="test: the source produced NaN or infinite values"):
        merl.tabulate(NaNAt())
