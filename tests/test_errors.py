"""Every bad input is a clean error naming the file — one test per kind of case
(loaders, calibration, captures, paths, permissions, outputs)."""

from __future__ import annotations

import io
import json
import os
import pickle
import re
import stat
import struct
import warnings
import zipfile
from pathlib import Path

import h5py
import numpy as np
import pytest

from reflecto import io as rio
from reflecto.cli import main
from reflecto.errors import (
    BatchError,
    FileFormatError,
    LimitError,
    OutputError,
    ParameterError,
    ReflectoError,
    ReflectoWarning,
)
from reflecto.instrument.calibrate import Calibration, calibrate
from reflecto.instrument.capture import CaptureError, read_capture
from reflecto.instrument.device import Device
from reflecto.instrument.simulate import simulate_calibration
from reflecto.load import load_source
from reflecto.model import MicrofacetBRDF
from reflecto.sources.analytic import AnalyticBRDF

ROOT = Path(__file__).resolve().parents[1]
PLASTIC = ROOT / "examples" / "ggx-plastic.json"
SRC = AnalyticBRDF(distribution="ggx", alpha=0.2, kd=0.3, ks=0.6, eta=1.5)


def _err(capsys) -> str:
    """The one stderr line of a failed command (and that there is exactly one)."""
    lines = [l for l in capsys.readouterr().err.splitlines() if l.strip()]
    assert len(lines) == 1 and lines[0].startswith("reflecto: error: "), lines
    return lines[0]


# ------------------------------------------------------------ crafted files
def _members(path: Path) -> dict[str, bytes]:
    with zipfile.ZipFile(path) as z:
        return {n: z.read(n) for n in z.namelist()}


def _zip(path: Path, members: dict[str, bytes]) -> Path:
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as z:
        for n, d in members.items():
            z.writestr(n, d)
    return path


def _npy(a: np.ndarray) -> bytes:
    return rio.npy_bytes(a)


def _craft_model(good: Path, out: Path, meta_edit=None, ndf=None) -> Path:
    """A model file as a writer that knows the format would make it: edited, checksums recomputed."""
    m = _members(good)
    meta = json.loads(m["meta.json"])
    if meta_edit:
        meta_edit(meta)
    if ndf is not None:
        m["ndf.npy"] = _npy(ndf.astype("<f4"))
        meta["arrays"]["ndf"].update(shape=list(ndf.shape), sha256=rio.sha256(m["ndf.npy"]))
    meta["sha256"] = rio.content_digest(meta)
    m["meta.json"] = json.dumps(meta).encode()
    return _zip(out, m)


def _craft_calibration(good: Path, out: Path, meta_edit=None, scale=None) -> Path:
    m = _members(good)
    meta = json.loads(bytes(rio.npy_array(m["meta.npy"], good, "meta.npy")))
    if meta_edit:
        meta_edit(meta)
    if scale is not None:
        m["scale.npy"] = _npy(scale)
        meta["arrays"]["scale"]["sha256"] = rio.sha256(m["scale.npy"])
    meta["sha256"] = rio.content_digest(meta)
    m["meta.npy"] = _npy(np.frombuffer(json.dumps(meta).encode(), np.uint8))
    return _zip(out, m)


def _npy_header(shape: tuple[int, ...], dtype: str = "<f4") -> bytes:
    """A .npy file's header claiming ``shape``, with a few bytes of data."""
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": dtype, "fortran_order": False, "shape": shape})
    return buf.getvalue() + b"\0" * 64


@pytest.fixture(scope="module")
def model_file(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("model")
    m = MicrofacetBRDF.from_ndf_function(SRC.ndf, resolution=32, kd=0.3, ks=0.6, eta=1.5)
    m.metadata["note"] = "test"
    return m.save(d / "m.reflecto")


@pytest.fixture(scope="module")
def calib(tmp_path_factory) -> tuple[Path, Path]:
    """A calibration folder of the as-built device and its calibration file."""
    d = tmp_path_factory.mktemp("calib")
    simulate_calibration(Device.builtin("as-built"), d / "calib", seed=3, white_repeats=1)
    return d / "calib", calibrate(d / "calib").save(d / "cal.npz")


# ------------------------------------------------------------------ pickling
@pytest.mark.parametrize("err", [FileFormatError("a/b.bsdf", "bad"), LimitError("x", "big"), OutputError("o", "no"),
                                 ParameterError("eta must be > 1"), ReflectoError("plain"),
                                 CaptureError("cap", "frame is missing"), BatchError([("a", "a: bad")], 5)])
def test_every_error_pickles_to_an_equal_one(err):
    back = pickle.loads(pickle.dumps(err))
    assert type(back) is type(err) and str(back) == str(err) and back.__dict__ == err.__dict__


# ---------------------------------------------------------------- model file
def test_damaged_model_member_is_a_clean_error(model_file, tmp_path):
    raw = bytearray(model_file.read_bytes())
    with zipfile.ZipFile(model_file) as z:
        info = z.getinfo("ndf.npy")
    data_start = info.header_offset + 30 + len(info.filename) + len(info.extra)
    raw[data_start + info.compress_size // 2] ^= 0x55  # inside the deflate stream: zlib.error before
    bad = tmp_path / "zlib.reflecto"
    bad.write_bytes(bytes(raw))
    with pytest.raises(FileFormatError, match="zlib.reflecto: damaged archive member 'ndf.npy'"):
        load_source(bad)


def test_model_meta_that_is_not_an_object(model_file, tmp_path):
    m = _members(model_file)
    m["meta.json"] = b"[]"
    with pytest.raises(FileFormatError, match="not a reflecto model file"):
        MicrofacetBRDF.load(_zip(tmp_path / "list.reflecto", m))


@pytest.mark.parametrize("edit, message", [
    (lambda meta: meta.update(kd=[1e6, 0.3, 0.3]), "kd must be three finite numbers in \\[0, 1\\]"),
    (lambda meta: meta.update(eta=[0.5, 1.5, 1.5]), "eta must be three finite numbers in \\[1, 100\\]"),
    (lambda meta: meta.update(ks=[500.0, 500.0, 500.0]), "directional albedo"),
    (lambda meta: meta.update(resolution=30), "NDF array is"),
    (lambda meta: meta.update(correlated="yes"), "'correlated' must be true or false"),
    (lambda meta: meta.update(metadata=[1, 2]), "'metadata' must be an object"),
])
def test_model_parameters_are_range_checked_even_with_valid_checksums(model_file, tmp_path, edit, message):
    with pytest.raises(FileFormatError, match=message):
        MicrofacetBRDF.load(_craft_model(model_file, tmp_path / "c.reflecto", edit))


def test_model_with_an_all_zero_or_unnormalized_ndf_is_refused(model_file, tmp_path):
    n = 3 * 32 * 32
    with pytest.raises(FileFormatError, match="not normalized"):
        MicrofacetBRDF.load(_craft_model(model_file, tmp_path / "z.reflecto", ndf=np.zeros(n)))
    good = MicrofacetBRDF.load(model_file).ndf_values
    with pytest.raises(FileFormatError, match="not normalized"):
        MicrofacetBRDF.load(_craft_model(model_file, tmp_path / "u.reflecto", ndf=2 * good))


def test_model_checksum_covers_parameters_and_metadata(model_file, tmp_path):
    """Version 1 checksummed the NDF only: an edited k_d, η or metadata passed."""
    for key, value in (("kd", [0.5, 0.3, 0.3]), ("eta", [1.6, 1.5, 1.5]), ("metadata", {"note": "edited"})):
        m = _members(model_file)
        meta = json.loads(m["meta.json"])
        meta[key] = value
        m["meta.json"] = json.dumps(meta).encode()
        with pytest.raises(FileFormatError, match="metadata checksum mismatch"):
            MicrofacetBRDF.load(_zip(tmp_path / f"{key}.reflecto", m))
    m = _members(model_file)  # an extra member is not silently ignored
    m["extra.npy"] = _npy(np.zeros(3))
    with pytest.raises(FileFormatError, match="do not match the metadata"):
        MicrofacetBRDF.load(_zip(tmp_path / "extra.reflecto", m))


def test_model_save_load_round_trip_is_exact_and_version_3(model_file):
    meta = json.loads(_members(model_file)["meta.json"])
    assert meta["version"] == 3 and set(meta["arrays"]) == {"ndf"} and len(meta["sha256"]) == 64
    back = MicrofacetBRDF.load(model_file)
    assert back.metadata == {"note": "test"} and back.kd.tolist() == [0.3] * 3


def _isotropic_model(tmp_path: Path) -> Path:
    from reflecto.model import IsotropicMicrofacetBRDF
    from reflecto.polar import polar_nodes

    nodes = polar_nodes()
    d = SRC.ndf(np.stack([np.sin(nodes), 0 * nodes, np.cos(nodes)], -1))
    return IsotropicMicrofacetBRDF((nodes, d), 0.3, 0.6, 1.5, metadata={"note": "iso"}).save(tmp_path / "iso.reflecto")


def test_isotropic_model_files_are_checksummed_over_nodes_values_and_metadata(tmp_path):
    from reflecto.model import IsotropicMicrofacetBRDF

    good = _isotropic_model(tmp_path)
    meta = json.loads(_members(good)["meta.json"])
    assert meta["ndf_kind"] == "isotropic" and set(meta["arrays"]) == {"ndf", "ndf_theta"}
    back = load_source(good)
    assert isinstance(back, IsotropicMicrofacetBRDF) and back.metadata == {"note": "iso"}
    m = _members(good)
    nodes = rio.npy_array(m["ndf_theta.npy"], good, "ndf_theta.npy")
    m["ndf_theta.npy"] = _npy(nodes * 0.99)  # the nodes are covered too
    with pytest.raises(FileFormatError, match="array 'ndf_theta' checksum mismatch"):
        MicrofacetBRDF.load(_zip(tmp_path / "nodes.reflecto", m))
    bad = _craft_model(good, tmp_path / "kd.reflecto", lambda meta: meta.update(kd=[2.0, 0, 0]))
    with pytest.raises(FileFormatError, match="kd must be three finite numbers in \\[0, 1\\]"):
        MicrofacetBRDF.load(bad)


def test_version_2_files_of_either_kind_read_with_a_warning(model_file, tmp_path):
    """Format version 2 (ndf_kind, ndf_sha256 over the NDF and its nodes) is read, range-checked, with a warning."""
    for good in (model_file, _isotropic_model(tmp_path)):
        m = _members(good)
        meta = json.loads(m["meta.json"])
        covered = rio.npy_array(m["ndf.npy"], good, "ndf.npy").tobytes()
        if "ndf_theta.npy" in m:
            covered += rio.npy_array(m["ndf_theta.npy"], good, "ndf_theta.npy").tobytes()
        v2 = {k: v for k, v in meta.items() if k not in ("arrays", "sha256")}
        v2.update(version=2, ndf_sha256=rio.sha256(covered))
        m["meta.json"] = json.dumps(v2).encode()
        with pytest.warns(ReflectoWarning, match="version 2 checksums only the NDF"):
            back = MicrofacetBRDF.load(_zip(tmp_path / f"v2-{good.name}", m))
        assert back.kd.tolist() == meta["kd"]


def test_version_1_model_reads_with_a_warning(model_file, tmp_path):
    m = _members(model_file)
    meta = json.loads(m["meta.json"])
    ndf = rio.npy_array(m["ndf.npy"], model_file, "ndf.npy")
    v1 = {k: meta[k] for k in ("format", "resolution", "kd", "ks", "eta", "correlated", "metadata")}
    v1.update(version=1, ndf_sha256=rio.sha256(ndf.astype("<f4").tobytes()))
    old = _zip(tmp_path / "v1.reflecto", {"meta.json": json.dumps(v1).encode(), "ndf.npy": m["ndf.npy"]})
    with pytest.warns(ReflectoWarning, match="version 1 checksums only the NDF"):
        assert np.array_equal(MicrofacetBRDF.load(old).ndf_values, ndf)
    v1["kd"] = [1e6, 0, 0]  # ranges are still checked, and a file that fails one gets its error alone
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(FileFormatError, match="kd must be"):
            MicrofacetBRDF.load(_zip(tmp_path / "v1b.reflecto",
                                     {"meta.json": json.dumps(v1).encode(), "ndf.npy": m["ndf.npy"]}))


def test_save_refuses_what_load_would_refuse(tmp_path):
    m = MicrofacetBRDF.from_ndf_function(SRC.ndf, resolution=16, kd=0.9, ks=50.0, eta=1.5)
    with pytest.raises(ParameterError, match="not saved"):
        m.save(tmp_path / "hot.reflecto")
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("member", ["ndf.npy", "scale.npy"])
def test_npy_header_claiming_a_huge_shape_is_refused_without_allocating(model_file, calib, tmp_path, member):
    if member == "ndf.npy":
        m = _members(model_file)
        m["ndf.npy"] = _npy_header((10**12,))
        meta = json.loads(m["meta.json"])
        meta["arrays"]["ndf"].update(shape=[10**12], sha256=rio.sha256(m["ndf.npy"]))
        meta["sha256"] = rio.content_digest(meta)
        m["meta.json"] = json.dumps(meta).encode()
        with pytest.raises(FileFormatError, match="header says"):
            MicrofacetBRDF.load(_zip(tmp_path / "huge.reflecto", m))
    else:
        m = _members(calib[1])
        m["scale.npy"] = _npy_header((6, 10**6, 10**6, 3))
        with pytest.raises(FileFormatError):
            Calibration.load(_zip(tmp_path / "huge.npz", m))


def test_zip_bomb_is_refused_before_inflating(model_file, tmp_path):
    """A member that unpacks to 9 GiB (declared in the central directory) is refused at once."""
    raw = bytearray(model_file.read_bytes())
    with zipfile.ZipFile(model_file) as z:
        info = z.getinfo("ndf.npy")
    # the ndf.npy central-directory entry's uncompressed size (offset 24): 4 GiB, the most without ZIP64
    pos = raw.find(b"PK\x01\x02")
    while pos >= 0:
        name_len = struct.unpack_from("<H", raw, pos + 28)[0]
        if raw[pos + 46: pos + 46 + name_len] == info.filename.encode():
            struct.pack_into("<I", raw, pos + 24, 0xFFFFFFF0)
            break
        pos = raw.find(b"PK\x01\x02", pos + 4)
    assert pos >= 0
    bomb = tmp_path / "bomb.reflecto"
    bomb.write_bytes(bytes(raw))
    with pytest.raises(LimitError, match="unpacks to 42949.* bytes, more than"):
        MicrofacetBRDF.load(bomb)


def test_real_zip_bomb_over_the_unpacked_limit(tmp_path):
    bomb = tmp_path / "bomb.npz"
    with zipfile.ZipFile(bomb, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=1) as z:
        with z.open("scale.npy", "w", force_zip64=True) as fh:
            zeros = bytes(1 << 24)
            for _ in range((rio.MAX_UNPACKED_BYTES >> 24) + 1):
                fh.write(zeros)
    assert bomb.stat().st_size < 4 << 20
    with pytest.raises(LimitError, match="bomb.npz: archive unpacks to"):
        Calibration.load(bomb)


# ----------------------------------------------------------------- sources
def test_deeply_nested_json_is_a_clean_error(tmp_path, capsys):
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 100_000 + "]" * 100_000)
    assert main(["info", str(deep)]) == 1
    assert "deep.json: JSON nested deeper than 64 levels" in _err(capsys)
    t = tmp_path / "deep.toml"
    t.write_text("a = " + "[" * 5000 + "]" * 5000 + "\n")
    with pytest.raises(LimitError, match="TOML nested deeper"):
        load_source(t)


@pytest.mark.parametrize("desc, message", [
    ({"asymmetry": {"shift": "ab"}}, "'asymmetry.shift' must be a list of 2 numbers"),
    ({"asymmetry": {"shift": [0.1, 0.0], "weight": "x"}}, "'asymmetry.weight' must be one number"),
    ({"alpha": 1e-300}, "alpha must be one or two numbers in \\[0.001, 4\\]"),
    ({"alpha": True}, "'alpha' must be one number"),
    ({"kd": [0.1, 0.2]}, "'kd' must be one number or a list of 3 numbers"),
    ({"distribution": 3}, "'distribution' must be one of"),
    ({"name": ["x"]}, "'name' must be a string"),
])
def test_analytic_fields_are_type_checked(tmp_path, desc, message):
    p = tmp_path / "a.json"
    p.write_text(json.dumps({"type": "analytic", **desc}))
    with pytest.raises(FileFormatError, match=f"a.json: {message}"):
        load_source(p)


def _tensor_file(fields: list[tuple[str, int, tuple[int, ...], bytes]]) -> bytes:
    """A tensor file from (name, dtype code, shape, data) with the header as written by hand."""
    head = bytearray(b"tensor_file\x00" + bytes([1, 0]) + struct.pack("<I", len(fields)))
    table = sum(2 + len(n) + 11 + 8 * len(s) for n, _, s, _ in fields)
    offset = len(head) + table
    body = b""
    for name, code, shape, data in fields:
        head += struct.pack("<H", len(name)) + name.encode() + struct.pack("<HBQ", len(shape), code, offset + len(body))
        head += struct.pack(f"<{len(shape)}Q", *shape)
        body += data
    return bytes(head) + body


def test_rgl_shape_product_overflow_is_a_clean_error(tmp_path):
    p = tmp_path / "overflow.bsdf"
    p.write_bytes(_tensor_file([("ndf", 10, (2**40, 2**40), b"\0" * 16)]))
    with pytest.raises(FileFormatError, match="overflow.bsdf: truncated: field 'ndf' needs bytes"):
        load_source(p)


@pytest.fixture(scope="module")
def rgl_fields(shared) -> dict[str, np.ndarray]:
    from reflecto.sources.rgl import read_tensor_file

    return {k: np.array(v) for k, v in read_tensor_file(shared / "rgl" / "paper_white_rgb.bsdf").items()}


@pytest.mark.parametrize("field, change, message", [
    ("vndf", lambda a: a * 0, "'vndf' is zero everywhere"),
    ("ndf", lambda a: -a, "'ndf' must be non-negative"),
    ("rgb", lambda a: -a, "its tables give a directional albedo of -1\\.03"),
    ("sigma", lambda a: a * 0, "'sigma' .* must be positive"),
    ("theta_i", lambda a: a[::-1].copy(), "theta_i must increase"),
    ("jacobian", lambda a: a + 5, "'jacobian' must be 0 or 1"),
])
def test_rgl_tables_are_range_checked(rgl_fields, tmp_path, field, change, message):
    from reflecto.export.rgl import write_tensor_file

    fields = dict(rgl_fields)
    fields[field] = change(fields[field])
    fields = {k: v for k, v in fields.items() if v.dtype in (np.dtype("u1"), np.dtype("<u4"), np.dtype("<f4"))}
    p = write_tensor_file(tmp_path / "bad.bsdf", fields)
    with pytest.raises(FileFormatError, match=f"bad.bsdf: .*{message}"):
        load_source(p)


def test_merl_values_of_1e200_are_refused(tmp_path):
    from reflecto.sources import merl

    t = np.full(merl.SHAPE + (3,), 0.1)
    t[40:50] = 1e200
    with pytest.raises(FileFormatError, match="hot.binary: the table to write: f·cos θ_i·cos θ_o reaches"):
        merl.write_merl_table(tmp_path / "hot.binary", t)  # reflecto writes only what it reads
    p = tmp_path / "hot.binary"
    p.write_bytes(np.array(merl.SHAPE, "<i4").tobytes()
                  + np.ascontiguousarray((t.reshape(merl.N_BINS, 3) / merl.SCALE).T, "<f8").tobytes())
    with pytest.raises(FileFormatError, match="hot.binary: its table: f·cos θ_i·cos θ_o reaches 9.02e\\+199 sr⁻¹"):
        load_source(p)


def test_merl_spike_between_quadrature_nodes_is_refused_by_its_hemispherical_albedo(tmp_path):
    """6667 sr⁻¹ in one θ_h bin (15°) at θ_d 62–72°: the directional-albedo quadrature's
    rings step over the bin (albedo < 0.5), its exact per-bin integral does not (found by
    the fuzz campaign)."""
    from reflecto.brdf import directional_albedo
    from reflecto.sources import merl

    t = np.full(merl.SHAPE + (3,), 0.1)
    t[37, 62:73, :, 0] = 6666.7
    src = merl.MerlBRDF.from_table(t)
    assert directional_albedo(src, [0.0, 20.0, 40.0, 60.0, 75.0], n_u=48, n_phi=64).max() < 1.5
    assert merl.hemispherical_albedo(np.full(merl.SHAPE + (3,), 1 / np.pi)) == pytest.approx(1.0, abs=1e-3)
    p = merl.write_merl_table(tmp_path / "spike.binary", t)
    with pytest.raises(FileFormatError,
                       match="spike.binary: hemispherical albedo \\[[0-9.]+, 0.3\\d+, 0.3\\d+\\] above"):
        load_source(p)


def _nbrdf(path: Path, shared: Path, edit=None, extra=None) -> Path:
    """Copy pvc.h5's layers into a new file, changing them with ``edit(name, array)``."""
    with h5py.File(shared / "merl-nbrdf" / "pvc.h5", "r") as src, h5py.File(path, "w") as dst:
        for layer in ("dense_1", "dense_2", "dense_3"):
            for part in ("kernel:0", "bias:0"):
                a = np.asarray(src[f"{layer}/{layer}/{part}"])
                dst.create_dataset(f"{layer}/{layer}/{part}", data=edit(f"{layer}/{part}", a) if edit else a)
        if extra:
            extra(dst)
    return path


def test_nbrdf_bias_of_1000_is_refused(shared, tmp_path):
    p = _nbrdf(tmp_path / "hot.h5", shared, lambda n, a: a + 1000.0 if n == "dense_3/bias:0" else a)
    with pytest.raises(FileFormatError, match="hot.h5: the BRDF evaluates to NaN or infinity"):
        load_source(p)


def test_lazily_allocated_huge_hdf5_dataset_is_refused_without_reading(shared, tmp_path):
    def huge(f):
        del f["dense_2/dense_2/kernel:0"]
        f.create_dataset("dense_2/dense_2/kernel:0", shape=(10**6, 10**6), dtype="f8", chunks=(1000, 1000))

    p = _nbrdf(tmp_path / "lazy.h5", shared, extra=huge)
    with pytest.raises(FileFormatError, match="lazy.h5: 'dense_2/dense_2/kernel:0' has shape \\(1000000, 1000000\\)"):
        load_source(p)


def test_hdf5_links_to_other_files_are_not_followed(shared, tmp_path):
    def external(f):
        del f["dense_1/dense_1/bias:0"]
        f["dense_1/dense_1/bias:0"] = h5py.ExternalLink(str(shared / "merl-nbrdf" / "pvc.h5"),
                                                        "/dense_1/dense_1/bias:0")

    p = _nbrdf(tmp_path / "ext.h5", shared, extra=external)
    with pytest.raises(FileFormatError, match="ext.h5: .* is a ExternalLink"):
        load_source(p)


@pytest.mark.parametrize("command", [["info"], ["tabulate", "-o", "OUT.binary"], ["simulate", "-o", "OUT"]])
def test_special_files_are_refused_without_blocking(tmp_path, capsys, command):
    fifo = tmp_path / "pipe.json"
    os.mkfifo(fifo)
    dev = tmp_path / "zero.json"
    dev.symlink_to("/dev/zero")
    for src, kind in ((fifo, "a FIFO"), (dev, "a device"), (tmp_path, "a directory")):
        argv = [command[0], str(src)] + [a.replace("OUT", str(tmp_path / "out")) for a in command[1:]]
        assert main(argv) == 1
        assert f"is {kind}, not a regular file" in _err(capsys)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pipe.json", "zero.json"]


# ------------------------------------------------------------------ captures
@pytest.fixture
def capture(tmp_path) -> Path:
    assert main(["simulate", str(PLASTIC), "-o", str(tmp_path / "cap"), "-q"]) == 0
    return tmp_path / "cap"


def _manifest(cap: Path, fn) -> None:
    m = json.loads((cap / "manifest.json").read_text())
    fn(m)
    (cap / "manifest.json").write_text(json.dumps(m))


def test_huge_sensor_in_a_manifest_is_refused_before_allocating(capture):
    def huge(m):
        m["device"]["optics"].update(width=100_000, height=100_000)
        m["image"].update(width=100_000, height=100_000)

    _manifest(capture, huge)
    with pytest.raises(FileFormatError, match="width must be an integer in \\[8, 4096\\]"):
        read_capture(capture)
    _manifest(capture, lambda m: (m["device"]["optics"].update(width=4096, height=4096),
                                  m["image"].update(width=4096, height=4096)))
    with pytest.raises(FileFormatError, match="more than the 4194304 pixels allowed"):
        read_capture(capture)


def test_manifest_missing_key_and_wrong_types(capture):
    _manifest(capture, lambda m: m.pop("image"))
    with pytest.raises(FileFormatError, match="manifest entry missing: 'image'"):
        read_capture(capture)


def test_symlinked_frame_outside_the_capture_is_refused(capture, tmp_path):
    outside = tmp_path / "outside.png"
    (capture / "led1_t1ms.png").rename(outside)
    (capture / "led1_t1ms.png").symlink_to(outside)
    with pytest.raises(FileFormatError, match="manifest.json: frame file 'led1_t1ms.png' leads outside"):
        read_capture(capture)
    # a link that stays inside the folder is fine
    (capture / "led1_t1ms.png").unlink()
    (capture / "frames").mkdir()
    outside.rename(capture / "frames" / "led1.png")
    (capture / "led1_t1ms.png").symlink_to(Path("frames") / "led1.png")
    assert read_capture(capture).raw.shape[0] == 6


def test_traversal_frame_names_are_still_refused(capture):
    _manifest(capture, lambda m: m["frames"][0].update(file="../led0_t1ms.png"))
    with pytest.raises(CaptureError, match="must be a plain name inside the capture folder"):
        read_capture(capture)


def test_fifo_frame_is_refused_without_blocking(capture):
    (capture / "led2_t8ms.png").unlink()
    os.mkfifo(capture / "led2_t8ms.png")
    with pytest.raises(FileFormatError, match="led2_t8ms.png: is a FIFO"):
        read_capture(capture)


def test_png_header_claiming_a_huge_image_is_refused_before_decoding(capture):
    f = capture / "led3_t1ms.png"
    raw = bytearray(f.read_bytes())
    struct.pack_into(">II", raw, 16, 100_000, 100_000)
    f.write_bytes(bytes(raw))
    with pytest.raises(CaptureError, match="image is 100000×100000, the manifest says 320×240"):
        read_capture(capture)


# --------------------------------------------------------------- calibration
def _calib_json(folder: Path, fn) -> None:
    p = folder / "calibration.json"
    m = json.loads(p.read_text())
    fn(m)
    p.write_text(json.dumps(m))


@pytest.fixture
def calib_copy(calib, tmp_path) -> Path:
    import shutil

    return Path(shutil.copytree(calib[0], tmp_path / "calib"))


@pytest.mark.parametrize("edit, message", [
    (lambda m: m.update(grid=[]), "'grid' must be a list of 1 to 64 objects"),
    (lambda m: m.pop("mirror"), "'mirror' must be a list"),
    (lambda m: m["mirror"][2].update(mirror_normal=[float("nan")] * 3),
     "mirror_normal of 'mirror_led2.png' must be finite unit"),
    (lambda m: m["mirror"][2].update(mirror_normal=[0.0, 0.0, 0.0]), "must be finite unit vectors"),
    (lambda m: m["mirror"][1].update(led=-1), "led must be a distinct LED index in \\[0, 6\\), got -1"),
    (lambda m: m["mirror"][1].update(led=0), "led must be a distinct LED index"),
    (lambda m: m["grid"][0].update(directions=[[0, 0, 1], [1, 2]]), "directions of 'grid_0.png' must be"),
    # no overflow warning
    (lambda m: m["grid"][0]["directions"][0].__setitem__(1, 1e308), "must be finite unit vectors"),
    (lambda m: m["grid"][0].update(file="../../outside/x.png"),
     "grid image '../../outside/x.png' must be a relative name"),
    (lambda m: m["grid"][0].update(file="/dev/zero"), "grid image '/dev/zero' must be a relative name"),
    (lambda m: m["mirror"][0].update(file=None), "mirror image name must be a non-empty string"),
])
def test_calibration_manifest_entries_are_checked(calib_copy, edit, message, capsys, tmp_path):
    _calib_json(calib_copy, edit)
    out = tmp_path / "out" / "cal.npz"
    assert main(["calibrate", str(calib_copy), "-o", str(out)]) == 1
    line = _err(capsys)
    assert "calibration.json: " in line and re.search(message, line), line
    assert not (tmp_path / "out").exists()


def test_calibration_symlinked_image_leading_outside_and_a_device_file(calib_copy, tmp_path):
    (calib_copy / "grid_1.png").unlink()
    (calib_copy / "grid_1.png").symlink_to("/dev/zero")
    with pytest.raises(FileFormatError, match="grid image 'grid_1.png' leads outside"):
        calibrate(calib_copy)


def test_calibration_mirror_normal_that_moves_an_led_far_is_refused(calib_copy):
    # a unit normal, but not the mirror's: the LED would move by tens of degrees
    _calib_json(calib_copy, lambda m: m["mirror"][3].update(mirror_normal=[0.0, 0.0, 1.0]))
    with pytest.raises(CaptureError, match="mirror_led3.png: LED 3 lies .*° from its nominal direction, more than 5°"):
        calibrate(calib_copy)


def test_calibration_mirror_image_of_noise_is_refused(calib_copy):
    """A mirror image of uniform noise made one spot of the whole frame, whose centroid moved
    LED 0 by 1.66° without a word: a pinhole's image covers a few pixels."""
    import cv2

    path = calib_copy / "mirror_led0.png"
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    noise = np.random.default_rng(0).integers(0, np.iinfo(img.dtype).max, img.shape, dtype=img.dtype)
    cv2.imwrite(str(path), noise)
    with pytest.raises(CaptureError, match=r"mirror_led0.png: not a mirror spot: 9\d\.\d % of the frame"):
        calibrate(calib_copy)


@pytest.mark.parametrize("leds, message", [
    ([[float("nan")] * 3] * 6, "NaN or infinity"),
    ([[0.0, 0.0, 0.0]] * 6, "unit vectors"),
    ([[0.0, 0.0, -1.0]] * 6, "below the sample's horizon"),
])
def test_calibration_file_with_impossible_leds_is_refused(calib, tmp_path, capsys, leds, message):
    """A NaN LED direction reached the compiled binning kernel and crashed it (rc 139)."""
    bad = _craft_calibration(calib[1], tmp_path / "bad.npz", lambda meta: meta.update(leds=leds))
    with pytest.raises(FileFormatError, match=message):
        Calibration.load(bad)
    cap = tmp_path / "cap"
    assert main(["simulate", str(PLASTIC), "--device", "as-built", "-o", str(cap), "-q"]) == 0
    assert main(["reconstruct", str(cap), "--calibration", str(bad), "-o", str(tmp_path / "m.reflecto")]) == 1
    assert message.split()[0] in _err(capsys)


def test_calibration_checksum_and_truncation(calib, tmp_path):
    raw = calib[1].read_bytes()
    (tmp_path / "t.npz").write_bytes(raw[: len(raw) // 2])
    with pytest.raises(FileFormatError, match="t.npz: not a zip archive or damaged"):
        Calibration.load(tmp_path / "t.npz")
    m = _members(calib[1])
    meta = json.loads(bytes(rio.npy_array(m["meta.npy"], calib[1], "meta.npy")))
    meta["leds"][0][0] += 1e-3
    m["meta.npy"] = _npy(np.frombuffer(json.dumps(meta).encode(), np.uint8))
    with pytest.raises(FileFormatError, match="metadata checksum mismatch"):
        Calibration.load(_zip(tmp_path / "edited.npz", m))
    scale = rio.npy_array(m["scale.npy"], calib[1], "scale.npy")
    bad = _craft_calibration(calib[1], tmp_path / "neg.npz", scale=-scale)
    with pytest.raises(FileFormatError, match="negative"):
        Calibration.load(bad)
    dark = scale.copy()
    dark[2] = 0.0  # an LED with no radiometric calibration: every sample of its slice would be dropped
    with pytest.raises(FileFormatError, match="LED 2: the scale field is zero on 100 % of the view disc"):
        Calibration.load(_craft_calibration(calib[1], tmp_path / "dark.npz", scale=dark))
    assert np.array_equal(Calibration.load(calib[1]).scale, np.load(calib[1])["scale"])  # numpy still reads it


# ----------------------------------------------------------------- outputs
def test_output_under_an_existing_file(tmp_path, capsys):
    (tmp_path / "file").write_text("x")
    assert main(["tabulate", str(PLASTIC), "-o", str(tmp_path / "file" / "x.binary")]) == 1
    assert "file: cannot create the folder: a file of that name is in the way" in _err(capsys)
    assert main(["simulate", str(PLASTIC), "-o", str(tmp_path / "file" / "sub" / "cap")]) == 1
    assert "file: cannot create the folder: a file of that name is in the way" in _err(capsys)
    os.mkfifo(tmp_path / "pipe.binary")  # a rename would replace a device or FIFO with the output
    assert main(["tabulate", str(PLASTIC), "-o", str(tmp_path / "pipe.binary")]) == 1
    assert "pipe.binary: is a device, FIFO or socket; refusing to replace it" in _err(capsys)
    assert stat.S_ISFIFO(os.lstat(tmp_path / "pipe.binary").st_mode)
    (tmp_path / "dir.binary").mkdir()
    assert main(["tabulate", str(PLASTIC), "-o", str(tmp_path / "dir.binary")]) == 1
    assert "dir.binary: is a folder; cannot write a file there" in _err(capsys)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dir.binary", "file", "pipe.binary"]


def test_failed_runs_leave_no_output_folders(tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text('{"type": "analytic", "alpha": -1}')
    runs = [["tabulate", str(bad), "-o", str(tmp_path / "a" / "b" / "t.binary")],
            ["simulate", str(bad), "-o", str(tmp_path / "c" / "d")],
            ["export", str(bad), "-o", str(tmp_path / "e" / "x.bsdf")],
            ["report", str(bad), "-o", str(tmp_path / "f" / "g")],
            ["calibrate", str(tmp_path / "nothing"), "-o", str(tmp_path / "h" / "c.npz")],
            ["reconstruct", str(tmp_path / "no1"), str(tmp_path / "no2"), "-o", str(tmp_path / "i" / "models")],
            ["sweep", str(tmp_path / "no-such-folder"), "-o", str(tmp_path / "j" / "k")]]
    for argv in runs:
        assert main(argv) == 1, argv
        capsys.readouterr()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.json"]
    # a batch whose items failed keeps its record of the failure, and nothing empty
    assert main(["sweep", str(bad), "-o", str(tmp_path / "s"), "-q"]) == 1
    assert "bad.json: alpha must be" in _err(capsys)
    assert sorted(p.name for p in (tmp_path / "s").iterdir()) == ["failures.json", "results.csv"]
    assert json.loads((tmp_path / "s" / "failures.json").read_text())[0]["file"] == str(bad)


def _modes(root: Path) -> set[tuple[str, int]]:
    return {("dir" if p.is_dir() else "file", stat.S_IMODE(p.stat().st_mode)) for p in [root, *root.rglob("*")]}


@pytest.mark.parametrize("umask, file_mode, dir_mode", [(0o022, 0o644, 0o755), (0o077, 0o600, 0o700)])
def test_outputs_respect_the_umask(tmp_path, capsys, umask, file_mode, dir_mode):
    old = os.umask(umask)
    try:
        m = MicrofacetBRDF.from_ndf_function(SRC.ndf, resolution=16, kd=0.3, ks=0.6, eta=1.5)
        m.save(tmp_path / "models" / "m.reflecto")  # atomic_write, with a folder made for it
        assert main(["simulate", str(PLASTIC), "-o", str(tmp_path / "caps" / "cap"), "-q"]) == 0  # atomic_folder
        with rio.atomic_path(tmp_path / "plots" / "x.png", suffix=".png") as tmp:  # as matplotlib/imageio write
            tmp.unlink()
            tmp.write_bytes(b"png")
        if umask == 0o022:  # a report folder (mkdir) of images (atomic_path) and a page (atomic_write)
            assert main(["report", str(tmp_path / "models" / "m.reflecto"), "--no-render",
                         "-o", str(tmp_path / "rep")]) == 0
    finally:
        os.umask(old)
    capsys.readouterr()
    modes = set()
    for sub in ("models", "caps", "plots", "rep"):
        if (tmp_path / sub).exists():
            modes |= _modes(tmp_path / sub)
    assert modes == {("file", file_mode), ("dir", dir_mode)}, modes


def test_export_suffix_and_format_must_agree(model_file, tmp_path, capsys):
    assert main(["export", str(model_file), "--format", "merl", "-o", str(tmp_path / "a.bsdf")]) == 1
    assert "a.bsdf is a .bsdf file name; export --format merl writes a MERL table (.binary)" in _err(capsys)
    assert main(["export", str(model_file), "--format", "rgl", "-o", str(tmp_path / "a.binary")]) == 1
    assert "use -o" in _err(capsys)
    assert main(["export", str(model_file), "-o", str(tmp_path / "a.json")]) == 1
    assert "a.json is a .json file; export writes an RGL .bsdf or a MERL .binary file" in _err(capsys)
    assert not list(tmp_path.iterdir())
    # the suffix chooses: MERL, read back as such
    assert main(["export", str(model_file), "--isotropic", "yes", "-o", str(tmp_path / "a.binary"), "-q"]) == 0
    assert load_source(tmp_path / "a.binary").kind == "merl"
    assert main(["tabulate", str(PLASTIC), "-o", str(tmp_path / "t.bsdf")]) == 1
    assert "t.bsdf is a .bsdf file; tabulate writes a MERL table (.binary)" in _err(capsys)
    assert main(["reconstruct", str(tmp_path), "-o", str(tmp_path / "m.json")]) == 1
    assert "m.json is a .json file; reconstruct writes a model file (.reflecto)" in _err(capsys)


def test_capture_named_in_model_metadata_resolves_only_inside_its_folder(tmp_path):
    m = MicrofacetBRDF.from_ndf_function(SRC.ndf, resolution=16, kd=0.3, ks=0.6, eta=1.5)
    (tmp_path / "cap").mkdir()
    for cap, kept in (("cap", True), ("../cap", False), ("/etc", False), (str(tmp_path / "cap"), False),
                      ("missing", False), (3, False)):
        m.metadata = {"capture": cap}
        back = MicrofacetBRDF.load(m.save(tmp_path / "m.reflecto"))
        assert back.metadata.get("capture") == (str(tmp_path / "cap") if kept else None), cap
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "link").symlink_to(tmp_path / "cap")  # a link out of the model's folder
    m.metadata = {"capture": "link"}
    assert "capture" not in MicrofacetBRDF.load(m.save(tmp_path / "sub" / "m.reflecto")).metadata


def test_folder_output_refuses_a_file_or_a_capture_folder(model_file, capture, tmp_path, capsys):
    """A folder output is not written over a file, nor into a capture folder, whose
    reader would then find the report's files among its frames; ``simulate`` may
    replace its own kind of folder."""
    blocker = tmp_path / "page.html"
    blocker.write_text("mine")
    assert main(["report", str(model_file), "-o", str(blocker), "--no-render"]) == 1
    assert "page.html: exists and is not a folder; report writes a report folder" in _err(capsys)
    assert blocker.read_text() == "mine"
    dangling = tmp_path / "gone"
    dangling.symlink_to(tmp_path / "nowhere")
    assert main(["report", str(model_file), "-o", str(dangling), "--no-render"]) == 1
    assert "gone: exists and is not a folder; report writes a report folder" in _err(capsys)
    assert dangling.is_symlink() and not (tmp_path / "nowhere").exists()
    before = sorted(p.name for p in capture.iterdir())
    assert main(["report", str(model_file), "-o", str(capture), "--no-render"]) == 1
    assert "is a capture folder (manifest.json and frames); report writes a report folder" in _err(capsys)
    assert sorted(p.name for p in capture.iterdir()) == before
    assert main(["simulate", str(PLASTIC), "-o", str(capture), "-q"]) == 0
    link = tmp_path / "cap-link"
    link.symlink_to(capture)
    assert main(["simulate", str(PLASTIC), "-o", str(link), "-q"]) == 1
    assert "cap-link: is a link; this output folder is replaced as a whole: name the folder itself" in _err(capsys)
    assert link.is_symlink() and sorted(p.name for p in capture.iterdir()) == before
