"""Fuzzing every loader and every file-reading command with malformed inputs.

Each case copies valid inputs into a folder of its own, damages one of them (bytes,
JSON fields, format-aware edits, special files, paths) with a seeded generator, and
runs a ``reflecto`` command on it in a forked child process with a memory limit and
a timeout. The outcome is one of:

* ``refused``: exit 1, exactly one line ``reflecto: error: FILE: problem`` naming a
  file of the case, and no output left;
* ``accepted-same``: exit 0 and the input reads back identical to the valid one (a
  change the format does not carry, such as a zip header's timestamp);
* ``accepted-changed``: exit 0, the content differs and passes every range check;
  allowed only for formats without a checksum;
* ``recovered``: exit 0 after a warning that the damaged input was redone (a sweep
  record);

or a failure: ``corrupt-accepted`` (a checksummed file's content changed, or a
mutation that must be refused, accepted), ``bad-message``, ``output-left``,
``traceback``, ``crash`` (a signal), ``hang`` (the timeout), ``memory`` (an
allocation beyond the limit, or a peak RSS above :data:`MEMORY_LIMIT`).

The default test run draws a small campaign (a few cases per input kind, < 30 s);
``make fuzz`` runs ``python tests/test_fuzz.py --cases 600`` and prints the table of
input kind × outcome. The sweep cases replace the minutes-long evaluation of a
material by a stand-in that loads it with the real loader and returns a synthetic
record, so the sweep's own reading (materials, records, failures) is what is fuzzed.
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import hashlib
import json
import os
import random
import resource
import shutil
import signal
import socket
import struct
import sys
import tempfile
import time
import traceback
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from _fake_sweep import fake_run_material  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"
#: A case whose child process peaks above this resident size is a memory blow-up
#: (the valid inputs need at most ~0.6 GiB; docs/limits.md).
MEMORY_LIMIT = 3 << 30
#: Address-space limit of a case's child above what the parent already maps.
ADDRESS_HEADROOM = 6 << 30
FAILURES = ("corrupt-accepted", "bad-message", "output-left", "traceback", "crash", "hang", "memory")
OUTCOMES = ("refused", "accepted-same", "accepted-changed", "recovered") + FAILURES


# ------------------------------------------------------------------ base inputs
def build_base(folder: Path) -> Path:
    """Valid inputs of every kind, in ``folder`` (about 60 MB; 10–20 s)."""
    import importlib

    from reflecto.cli import main
    sw = importlib.import_module("reflecto.evaluate.sweep")
    from reflecto.load import load_source
    from reflecto.model import MicrofacetBRDF

    folder.mkdir(parents=True, exist_ok=True)
    q = ["-q"]
    shutil.copy(ROOT / "examples" / "ggx-plastic.json", folder / "analytic.json")
    (folder / "analytic.toml").write_text('type = "analytic"\ndistribution = "beckmann"\nalpha = [0.2, 0.1]\n'
                                          'rotation_deg = 30\nkd = [0.2, 0.1, 0.05]\nks = 0.6\neta = 1.5\n'
                                          'asymmetry = { shift = [0.25, 0.0], weight = 0.3 }\n')
    assert main(["tabulate", str(folder / "analytic.json"), "-o", str(folder / "merl.binary"), *q]) == 0
    shutil.copy(SHARED / "rgl" / "paper_white_rgb.bsdf", folder / "rgl.bsdf")
    shutil.copy(SHARED / "merl-nbrdf" / "pvc.h5", folder / "nbrdf.h5")
    shutil.copy(SHARED / "merl-nbrdf" / "pvc.json", folder / "nbrdf.json")
    mdir = folder / "model"
    mdir.mkdir()
    assert main(["simulate", str(folder / "analytic.json"), "-o", str(mdir / "cap"), *q]) == 0
    src = load_source(folder / "analytic.json")
    MicrofacetBRDF.from_ndf_function(src.ndf, resolution=32, kd=0.2, ks=0.5, eta=1.5,
                                     metadata={"capture": "cap", "note": "fuzz base"}).save(mdir / "model.reflecto")
    from reflecto.model import IsotropicMicrofacetBRDF
    from reflecto.polar import polar_nodes

    nodes = polar_nodes()
    d = src.ndf(np.stack([np.sin(nodes), 0 * nodes, np.cos(nodes)], -1))
    IsotropicMicrofacetBRDF((nodes, d), 0.2, 0.5, 1.5, metadata={"capture": "cap"}).save(mdir / "iso.reflecto")
    (mdir / "model.json").write_text(json.dumps({"normal_tilt_deg": 0.1, "fresnel_error": 0.2, "shake_detected": False,
                                                 "residual_median_rel": 0.01}))
    dev = {"name": "fuzz-device", "leds": [[5.0, 0.0], [7.34, 305.77], [22.9, 167.71], [6.99, 75.82],
                                           [52.2, 155.42], [12.71, 272.66]],
           "optics": {"axis_tilt_deg": 20.0, "width": 320, "height": 240},
           "camera": {"bits": 12, "exposures_ms": [1.0, 8.0], "read_noise": 0.0, "shot_noise": False},
           "firing_order": [0, 1, 3, 5, 4, 2], "check_leds": [0]}
    (folder / "device.json").write_text(json.dumps(dev, indent=1))
    (folder / "device.toml").write_text('name = "fuzz"\nleds = [[5.0, 0.0], [10.0, 120.0], [10.0, 240.0]]\n'
                                        '[optics]\naxis_tilt_deg = 15.0\n'
                                        '[camera]\nbits = 14\nexposures_ms = [0.5, 4.0]\n')
    assert main(["simulate", str(folder / "analytic.json"), "-o", str(folder / "cap"), *q]) == 0
    assert main(["simulate", str(folder / "analytic.json"), "--device", "as-built", "-o", str(folder / "cap-ab"),
                 *q]) == 0
    from reflecto.instrument.device import Device
    from reflecto.instrument.simulate import simulate_calibration

    simulate_calibration(Device.builtin("as-built"), folder / "calib", seed=2, white_repeats=1)
    assert main(["calibrate", str(folder / "calib"), "-o", str(folder / "cal.npz"), *q]) == 0
    mats = folder / "mats"
    mats.mkdir()
    shutil.copy(folder / "analytic.json", mats / "plastic.json")
    fake_run_material(str(mats / "plastic.json"), str(folder / "res"))
    sw.write_table([json.loads((folder / "res" / "materials" / "plastic.json").read_text())],
                   folder / "res" / "results.csv")
    (folder / ".complete").write_text("")
    return folder


# -------------------------------------------------------------------- mutations
HOSTILE = [float("nan"), float("inf"), float("-inf"), -1, 0, 1e308, -1e308, 1e-300, 1e200, "ab", "", [], {}, None,
           True, [1, 2, 3, 4, 5], 2**64, -(2**63), 0.5, 100000, [[0.0, 0.0, 0.0]], [float("nan")] * 3,
           "../../outside/x.png", "/dev/zero", "/etc/passwd"]
PATHS = ["../x.png", "../../outside/x.png", "/dev/zero", "/etc/hostname", "sub/../../x.png", "", ".", "..",
         "white", "nonexistent.png", "a\u0000b", "calibration.json", "manifest.json"]


def _leaves(obj, path=()):  # type: ignore[no-untyped-def]
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _leaves(v, path + (k,))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from _leaves(v, path + (i,))
    yield path, obj


def _set(obj, path, value):  # type: ignore[no-untyped-def]
    if not path:
        return value
    parent = obj
    for k in path[:-1]:
        parent = parent[k]
    parent[path[-1]] = value
    return obj


def _dump(obj) -> str:  # type: ignore[no-untyped-def]
    return json.dumps(obj, indent=1)


def mutate_json(rng: random.Random, text: str, prefer: str | None = None) -> tuple[str, str]:
    """One structural change of a JSON document; returns (new text, mutation name)."""
    obj = json.loads(text)
    leaves = list(_leaves(obj))
    op = rng.choice(["hostile", "hostile", "hostile", "drop", "add", "swap", "deep", "bigint", "path", "dup"])
    if prefer and rng.random() < 0.5:
        named = [(p, v) for p, v in leaves if p and p[-1] == prefer]
        if named:
            p, _ = rng.choice(named)
            return _dump(_set(obj, p, rng.choice(HOSTILE))), f"{prefer}:hostile"
    path, _ = rng.choice(leaves)
    if op == "hostile":
        return _dump(_set(obj, path, rng.choice(HOSTILE))), "json:hostile"
    if op == "drop":
        dicts = [(p, v) for p, v in leaves if isinstance(v, dict) and v]
        if dicts:
            p, d = rng.choice(dicts)
            del d[rng.choice(list(d))]
            return _dump(obj), "json:drop-key"
    if op == "add":
        dicts = [(p, v) for p, v in leaves if isinstance(v, dict)]
        p, d = rng.choice(dicts) if dicts else ((), {})
        d["zz_unknown"] = rng.choice(HOSTILE)
        return _dump(obj), "json:add-key"
    if op == "swap":
        conts = [(p, v) for p, v in leaves if isinstance(v, (dict, list))]
        p, v = rng.choice(conts)
        return _dump(_set(obj, p, list(v.values()) if isinstance(v, dict) else {str(i): x for i, x in enumerate(v)})), \
            "json:swap-container"
    if op == "deep":
        marker = "\"@@DEEP@@\""
        return _dump(_set(obj, path, "@@DEEP@@")).replace(marker, "[" * 100_000 + "]" * 100_000), "json:deep"
    if op == "bigint":
        marker = "\"@@BIG@@\""
        return _dump(_set(obj, path, "@@BIG@@")).replace(marker, "9" * 5000), "json:5000-digit-int"
    if op == "path":
        files = [(p, v) for p, v in leaves if p and p[-1] == "file"]
        if files:
            p, _ = rng.choice(files)
            return _dump(_set(obj, p, rng.choice(PATHS))), "json:file-path"
    lists = [(p, v) for p, v in leaves if isinstance(v, list) and v]
    if lists:
        p, v = rng.choice(lists)
        v.append(json.loads(json.dumps(v[rng.randrange(len(v))])))
        return _dump(obj), "json:dup-entry"
    return _dump(_set(obj, path, None)), "json:null"


def mutate_toml(rng: random.Random, text: str) -> tuple[str, str]:
    """A TOML value token replaced by a hostile one (text level: no TOML writer needed)."""
    lines = text.splitlines()
    k = rng.choice([i for i, l in enumerate(lines) if "=" in l])
    key = lines[k].split("=", 1)[0]
    bad = rng.choice(["nan", "inf", "-inf", "-1", "0", "1e400", '"ab"', "[]", "{}", "true", "[1, 2, 3, 4, 5]",
                      "[" * 5000 + "]" * 5000, "9" * 5000, "{ shift = \"ab\" }", "1e-300"])
    lines[k] = f"{key}= {bad}"
    return "\n".join(lines) + "\n", "toml:hostile"


def mutate_bytes(rng: random.Random, raw: bytes) -> tuple[bytes, str]:
    n = len(raw)
    op = rng.choice(["truncate", "truncate", "flip", "flip", "flip", "zero", "tail", "insert", "dup", "empty",
                     "random"])
    if op == "truncate" and n:
        return raw[: rng.randrange(n)], "bytes:truncate"
    if op == "flip" and n:
        b = bytearray(raw)
        for _ in range(rng.randint(1, 8)):
            b[rng.randrange(n)] ^= rng.randint(1, 255)
        return bytes(b), "bytes:flip"
    if op == "zero" and n:
        s = rng.randrange(n)
        return (raw[:s] + bytes(min(rng.randint(1, 4096), n - s)) + raw[s + rng.randint(1, 4096):][: max(0, n - s)],
                "bytes:zero-block")
    if op == "tail":
        return raw + rng.randbytes(rng.randint(1, 4096)), "bytes:garbage-tail"
    if op == "insert" and n:
        s = rng.randrange(n)
        return raw[:s] + rng.randbytes(rng.randint(1, 64)) + raw[s:], "bytes:insert"
    if op == "dup" and n:
        s = rng.randrange(n)
        return raw[:s] + raw[s: s + 4096] + raw[s:], "bytes:dup-chunk"
    if op == "random":
        return rng.randbytes(min(n, 1 << 16) or 64), "bytes:random"
    return b"", "bytes:empty"


def make_special(rng: random.Random, target: Path, outside: Path) -> str:
    """Replace ``target`` by a special file or an odd link; returns the mutation name."""
    if target.is_dir() and not target.is_symlink():
        shutil.rmtree(target)
    elif target.exists() or target.is_symlink():
        target.unlink()
    op = rng.choice(["fifo", "dev-zero", "dir", "broken-link", "loop", "outside-link", "socket"])
    if op == "fifo":
        os.mkfifo(target)
    elif op == "dev-zero":
        target.symlink_to("/dev/zero")
    elif op == "dir":
        target.mkdir()
    elif op == "broken-link":
        target.symlink_to(target.parent / "no-such-file")
    elif op == "loop":
        target.symlink_to(target.name)
    elif op == "outside-link":
        outside.write_bytes(b"{}")
        target.symlink_to(outside)
    else:
        s = socket.socket(socket.AF_UNIX)
        try:
            s.bind(str(target))
        except OSError:  # path too long for a socket: a FIFO instead
            os.mkfifo(target)
            op = "fifo"
        finally:
            s.close()
    return f"special:{op}"


# format-aware edits -----------------------------------------------------------
def mutate_merl(rng: random.Random, raw: bytes) -> tuple[bytes, str]:
    vals = np.frombuffer(raw, "<f8", offset=12).copy()
    op = rng.choice(["values", "values", "scale", "header"])
    if op == "header":
        return struct.pack("<3i", *(rng.choice([90, 180, 0, -1, 2**30]) for _ in range(3))) + raw[12:], "merl:header"
    if op == "scale":
        f = rng.choice([1e6, 1e10, -1.0, 0.0, float("nan")])
        return raw[:12] + (vals * f).tobytes(), f"merl:scale×{f:g}"
    v = rng.choice([float("nan"), float("inf"), 1e200, -1e200, 1e7, 0.0, -1.0])
    s = rng.randrange(len(vals))
    vals[s: s + rng.randint(1, 100000)] = v
    return raw[:12] + vals.tobytes(), f"merl:values={v:g}"


def mutate_rgl(rng: random.Random, path: Path) -> str:
    from reflecto.export.rgl import write_tensor_file
    from reflecto.sources.rgl import read_tensor_file

    raw = path.read_bytes()
    op = rng.choice(["field", "field", "field", "shape", "count"])
    if op == "count":
        b = bytearray(raw)
        struct.pack_into("<I", b, 14, rng.choice([0, 5, 1000, 2**32 - 1]))
        path.write_bytes(bytes(b))
        return "rgl:field-count"
    if op == "shape":
        b = bytearray(raw)
        pos = 18  # first field's shape entries follow name, ndim, dtype, offset
        (nlen,) = struct.unpack_from("<H", b, pos)
        (ndim,) = struct.unpack_from("<H", b, pos + 2 + nlen)
        if ndim:
            struct.pack_into("<Q", b, pos + 2 + nlen + 11 + 8 * rng.randrange(ndim), rng.choice([2**40, 2**63, 0, 3]))
        path.write_bytes(bytes(b))
        return "rgl:shape"
    fields = {k: np.array(v) for k, v in read_tensor_file(path).items()}
    name = rng.choice([k for k in fields if k not in ("version", "valid")])
    a = fields[name]
    how = rng.choice(["negate", "zero", "nan", "reverse", "huge", "drop", "reshape"])
    if how == "drop":
        del fields[name]
    elif how == "reshape":
        fields[name] = a.reshape(-1)
    elif a.dtype.kind == "f":
        fields[name] = {"negate": -a, "zero": a * 0, "nan": np.where(np.arange(a.size).reshape(a.shape) % 7 == 0,
                                                                          np.float32("nan"), a),
                        "reverse": a[::-1].copy(), "huge": a * np.float32(1e30)}[how].astype(a.dtype)
    else:
        fields[name] = (a + 7).astype(a.dtype)
    fields = {k: v for k, v in fields.items() if v.dtype in (np.dtype("u1"), np.dtype("<u4"), np.dtype("<f4"))}
    write_tensor_file(path, fields)
    return f"rgl:{name}:{how}"


def mutate_h5(rng: random.Random, path: Path) -> str:
    import h5py

    op = rng.choice(["nan", "bias", "shape", "drop", "lazy", "external", "soft", "string", "extstore", "group"])
    with h5py.File(path, "r+") as f:
        layer = rng.choice(["dense_1", "dense_2", "dense_3"])
        name = f"{layer}/{layer}/{rng.choice(['kernel:0', 'bias:0'])}"
        a = np.asarray(f[name])
        del f[name]
        if op == "nan":
            a = a.copy()
            a.flat[0] = np.nan
            f[name] = a
        elif op == "bias":
            f[name] = a + 1000.0
        elif op == "shape":
            f[name] = np.zeros(a.shape[::-1] + (2,), a.dtype)
        elif op == "lazy":
            f.create_dataset(name, shape=(10**6, 10**6), dtype="f8", chunks=(1000, 1000))
        elif op == "external":
            f[name] = h5py.ExternalLink("/etc/passwd", "/x")
        elif op == "soft":
            f[name] = h5py.SoftLink("/nowhere")
        elif op == "string":
            f[name] = np.array([b"ab"] * a.size)
        elif op == "extstore":
            f.create_dataset(name, shape=a.shape, dtype=a.dtype, external=[("/dev/zero", 0, a.nbytes)])
        elif op == "group":
            f.create_group(name)
    return f"h5:{op}"


def _zip_members(path: Path) -> dict[str, bytes]:
    with zipfile.ZipFile(path) as z:
        return {n: z.read(n) for n in z.namelist()}


def _write_zip(path: Path, members: dict[str, bytes] | list[tuple[str, bytes]]) -> None:
    import warnings

    items = members.items() if isinstance(members, dict) else members
    with warnings.catch_warnings(), zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as z:
        warnings.simplefilter("ignore")  # zipfile's own "Duplicate name" when the harness means it
        for n, d in items:
            z.writestr(n, d)


def _npy(a: np.ndarray) -> bytes:
    from reflecto.io import npy_bytes

    return npy_bytes(a)


def _huge_npy(shape, dtype="<f4") -> bytes:  # type: ignore[no-untyped-def]
    import io as _io

    buf = _io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": dtype, "fortran_order": False, "shape": shape})
    return buf.getvalue() + b"\0" * 32


def mutate_archive(rng: random.Random, path: Path, kind: str) -> str:
    """Edits of a model (.reflecto) or calibration (.npz) archive, with checksums recomputed or not."""
    from reflecto.io import content_digest, npy_array, sha256

    m = _zip_members(path)
    meta_name = "meta.json" if kind == "model" else "meta.npy"

    def get_meta() -> dict:
        raw = m[meta_name] if kind == "model" else npy_array(m[meta_name], path, meta_name).tobytes()
        return json.loads(raw)

    def put_meta(meta: dict, recompute: bool) -> None:
        if recompute:
            meta["sha256"] = content_digest(meta)
        text = json.dumps(meta).encode()
        m[meta_name] = text if kind == "model" else _npy(np.frombuffer(text, np.uint8))

    op = rng.choice(["meta", "meta", "meta-crafted", "meta-crafted", "array", "array-crafted", "bomb", "dup",
                     "extra", "drop", "huge-npy", "directory"])
    arr_name = "ndf" if kind == "model" else "scale"
    if op in ("meta", "meta-crafted"):
        meta = get_meta()
        text, what = mutate_json(rng, json.dumps(meta), prefer=rng.choice(["kd", "eta", "ks", "leds", "resolution",
                                                                            "width", "version", None]))
        try:
            meta = json.loads(text)
        except (ValueError, RecursionError):
            m[meta_name] = text.encode() if kind == "model" else _npy(np.frombuffer(text.encode(), np.uint8))
            _write_zip(path, m)
            return f"{kind}:meta-unparsable"
        if not isinstance(meta, dict):
            meta = {"format": meta}
        put_meta(meta, op == "meta-crafted")
        _write_zip(path, m)
        return f"{kind}:{op}:{what}"
    if op in ("array", "array-crafted"):
        a = npy_array(m[f"{arr_name}.npy"], path, arr_name)
        how = rng.choice(["zero", "nan", "negate", "scale", "shape", "dtype"])
        b = {"zero": a * 0, "nan": np.where(np.arange(a.size).reshape(a.shape) % 5 == 0, np.nan, a).astype(a.dtype),
             "negate": -a, "scale": a * 1e6, "shape": a.reshape(-1)[: a.size // 2],
             "dtype": a.astype(np.float64)}[how]
        m[f"{arr_name}.npy"] = _npy(b)
        if op == "array-crafted":
            meta = get_meta()
            meta["arrays"][arr_name].update(sha256=sha256(m[f"{arr_name}.npy"]), shape=list(b.shape), dtype=b.dtype.str)
            put_meta(meta, True)
        _write_zip(path, m)
        return f"{kind}:{op}:{how}"
    if op == "bomb":
        with zipfile.ZipFile(path, "a", compression=zipfile.ZIP_DEFLATED, compresslevel=1) as z:
            with z.open("bomb.npy", "w", force_zip64=True) as fh:
                zeros = bytes(1 << 24)
                for _ in range(33):
                    fh.write(zeros)
        return f"{kind}:zip-bomb-528MiB"
    if op == "dup":
        _write_zip(path, list(m.items()) + [(meta_name, m[meta_name])])
        return f"{kind}:duplicate-member"
    if op == "extra":
        m["extra.npy"] = _npy(np.zeros(4))
        _write_zip(path, m)
        return f"{kind}:extra-member"
    if op == "drop":
        del m[rng.choice(list(m))]
        _write_zip(path, m)
        return f"{kind}:missing-member"
    if op == "huge-npy":
        m[f"{arr_name}.npy"] = _huge_npy((10**12,))
        meta = get_meta()
        if "arrays" in meta:
            meta["arrays"][arr_name].update(sha256=sha256(m[f"{arr_name}.npy"]), shape=[10**12])
        put_meta(meta, True)
        _write_zip(path, m)
        return f"{kind}:npy-header-10^12"
    b = bytearray(path.read_bytes())  # central directory / local header bytes
    pos = b.rfind(b"PK\x01\x02")
    for _ in range(rng.randint(1, 4)):
        b[pos + rng.randrange(46)] ^= rng.randint(1, 255)
    path.write_bytes(bytes(b))
    return f"{kind}:zip-directory-flip"


def mutate_png(rng: random.Random, path: Path) -> str:
    import cv2

    op = rng.choice(["bytes", "bytes", "8bit", "gray", "rgba", "size", "ihdr", "jpeg"])
    if op == "bytes":
        raw, what = mutate_bytes(rng, path.read_bytes())
        path.write_bytes(raw)
        return f"png:{what}"
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if op == "8bit":
        cv2.imwrite(str(path), (img >> 8).astype(np.uint8))
    elif op == "gray":
        cv2.imwrite(str(path), img[..., 0])
    elif op == "rgba":
        cv2.imwrite(str(path), np.concatenate([img, img[..., :1]], axis=-1))
    elif op == "size":
        cv2.imwrite(str(path), img[: img.shape[0] // 2])
    elif op == "ihdr":
        b = bytearray(path.read_bytes())
        struct.pack_into(">II", b, 16, rng.choice([100000, 2**31 - 1, 0, 1]), rng.choice([100000, 240, 0]))
        path.write_bytes(bytes(b))
    else:
        path.unlink()
        cv2.imwrite(str(path.with_suffix(".jpg")), (img >> 8).astype(np.uint8))
        path.with_suffix(".jpg").rename(path)
    return f"png:{op}"


# ------------------------------------------------------------------- the cases
@dataclasses.dataclass(frozen=True)
class Case:
    kind: str       # input kind (row of the table)
    command: str    # the reflecto subcommand
    seed: int


#: input kind → (commands that read it, the base paths a case copies, its checksummed flag)
KINDS: dict[str, tuple[tuple[str, ...], tuple[str, ...], bool]] = {
    "analytic .json": (("info", "tabulate", "simulate", "compare", "export", "sweep", "fit-ct", "render"),
                       ("analytic.json",), False),
    "analytic .toml": (("info", "simulate"), ("analytic.toml",), False),
    "MERL .binary": (("info", "compare", "tabulate"), ("merl.binary",), False),
    "RGL .bsdf": (("info", "simulate", "sweep"), ("rgl.bsdf",), False),
    "NBRDF .h5": (("info", "tabulate"), ("nbrdf.h5", "nbrdf.json"), False),
    "NBRDF .json": (("info",), ("nbrdf.h5", "nbrdf.json"), False),
    "model .reflecto": (("info", "export", "report", "tabulate"), ("model",), True),
    "device file": (("layout", "simulate", "simulate-calibration"), ("device.json", "device.toml", "analytic.json"),
                    False),
    "capture manifest": (("reconstruct",), ("cap",), False),
    "capture frame": (("reconstruct",), ("cap",), False),
    "calibration .npz": (("reconstruct",), ("cap-ab", "cal.npz"), True),
    "calibration.json": (("calibrate",), ("calib",), False),
    "calibration image": (("calibrate",), ("calib",), False),
    "white capture": (("calibrate",), ("calib",), False),
    "summary .json": (("report",), ("model",), False),
    "sweep record": (("sweep",), ("mats", "res"), False),
    "special file": (("info", "tabulate", "reconstruct", "calibrate", "layout", "sweep", "report"),
                     ("analytic.json", "cap", "calib", "model", "mats"), False),
}
#: Commands too slow for every case: drawn rarely (fit-ct fits for ~10 s, render starts Mitsuba).
RARE = {"fit-ct": 0.25, "render": 0.25}


def base_choice(case: Case) -> str | None:
    """For kinds with several valid files, the one a case damages (its seed's first draw)."""
    choices = {"device file": ["device.json", "device.toml"], "model .reflecto": ["model.reflecto", "iso.reflecto"]}
    if case.kind not in choices:
        return None
    return choices[case.kind][int(random.Random(case.seed).random() * 2)]


def draw_cases(n: int, seed: int) -> list[Case]:
    """``n`` cases: every (kind, command) pair first, then random ones (deterministic in ``seed``)."""
    rng = random.Random(seed)
    pairs = [(k, c) for k, (cmds, _, _) in KINDS.items() for c in cmds]
    out = [Case(k, c, rng.randrange(2**31)) for k, c in pairs][:n]
    kinds = list(KINDS)
    while len(out) < n:
        k = rng.choice(kinds)
        c = rng.choice(KINDS[k][0])
        if c in RARE and rng.random() > RARE[c]:
            continue
        out.append(Case(k, c, rng.randrange(2**31)))
    return out


def prepare(case: Case, base: Path, d: Path, mutate: bool = True) -> tuple[list[str], Path, str, bool]:
    """Copy the inputs of ``case`` into ``d`` and damage one; returns (argv, the input read back
    for the oracle, the mutation's name, whether it must be refused)."""
    rng = random.Random(case.seed)
    for name in KINDS[case.kind][1]:
        src = base / name
        (shutil.copytree(src, d / name, symlinks=True) if src.is_dir() else shutil.copy(src, d / name))
    out = d / "out"
    kind, what, must_refuse = case.kind, "none", False

    def file_mutation(p: Path, structured: Callable[[], str] | None = None) -> str:
        if structured is not None and rng.random() < 0.6:
            return structured()
        raw, w = mutate_bytes(rng, p.read_bytes())
        p.write_bytes(raw)
        return w

    def json_mutation(p: Path, prefer: str | None = None) -> str:
        text, w = mutate_json(rng, p.read_text(), prefer)
        p.write_text(text)
        return w

    # which file is damaged, and the input the command reads
    if kind.startswith("analytic") or kind in ("MERL .binary", "RGL .bsdf", "NBRDF .h5", "NBRDF .json"):
        src = d / {"analytic .json": "analytic.json", "analytic .toml": "analytic.toml", "MERL .binary": "merl.binary",
                   "RGL .bsdf": "rgl.bsdf", "NBRDF .h5": "nbrdf.h5", "NBRDF .json": "nbrdf.h5"}[kind]
        target = d / "nbrdf.json" if kind == "NBRDF .json" else src
        if mutate:
            if kind == "analytic .json" or kind == "NBRDF .json":
                what = file_mutation(target, lambda: json_mutation(target))
            elif kind == "analytic .toml":
                what = file_mutation(target, lambda: (target.write_text(mutate_toml(rng, target.read_text())[0]),
                                                      "toml:hostile")[1])
            elif kind == "MERL .binary":
                what = file_mutation(target, lambda: (target.write_bytes(mutate_merl(rng, target.read_bytes())[0]),
                                                      "merl:edit")[1])
            elif kind == "RGL .bsdf":
                what = file_mutation(target, lambda: mutate_rgl(rng, target))
            else:
                what = file_mutation(target, lambda: mutate_h5(rng, target))
        read_back = src
    elif kind == "model .reflecto" or kind == "summary .json":
        src = d / "model" / (base_choice(case) or "model.reflecto")
        rng.random()  # the draw base_choice made
        target = src if kind == "model .reflecto" else d / "model" / "model.json"
        if mutate:
            if kind == "model .reflecto":
                what = file_mutation(target, lambda: mutate_archive(rng, target, "model"))
            else:
                what = file_mutation(target, lambda: json_mutation(target))
        read_back = target
    elif kind == "device file":
        target = d / base_choice(case)
        rng.random()  # the draw base_choice made
        if mutate:
            if target.suffix == ".json":
                what = file_mutation(target, lambda: json_mutation(target))
            else:
                what = file_mutation(target, lambda: (target.write_text(mutate_toml(rng, target.read_text())[0]),
                                                      "toml:hostile")[1])
        src = read_back = target
    elif kind.startswith("capture"):
        cap = d / "cap"
        if kind == "capture manifest":
            target = cap / "manifest.json"
            if mutate:
                r = rng.random()
                if r < 0.1:
                    what = make_special(rng, target, d / "outside.json")
                    must_refuse = True
                elif r < 0.2:
                    m = json.loads(target.read_text())
                    m["device"]["optics"].update(width=100_000, height=100_000)
                    m["image"].update(width=100_000, height=100_000)
                    target.write_text(json.dumps(m))
                    what, must_refuse = "manifest:sensor-100000²", True
                else:
                    what = file_mutation(target, lambda: json_mutation(target, rng.choice(["file", "led", "exposure_ms",
                                                                                          "width", None])))
        else:
            target = rng.choice(sorted(cap.glob("*.png")))
            if mutate:
                if rng.random() < 0.25:
                    what = make_special(rng, target, d / "outside.png")
                    must_refuse = True
                else:
                    what = mutate_png(rng, target)
        src = read_back = cap
    elif kind == "calibration .npz":
        target = d / "cal.npz"
        if mutate:
            what = file_mutation(target, lambda: mutate_archive(rng, target, "calibration"))
        src, read_back = d / "cap-ab", target
    elif kind in ("calibration.json", "calibration image", "white capture"):
        calib = d / "calib"
        if kind == "calibration.json":
            target = calib / "calibration.json"
            if mutate:
                what = file_mutation(target, lambda: json_mutation(target, rng.choice(
                    ["mirror_normal", "led", "file", "directions", "grid", None])))
        elif kind == "calibration image":
            target = rng.choice(sorted(calib.glob("*.png")))
            if mutate:
                if rng.random() < 0.2:
                    what = make_special(rng, target, d / "outside.png")
                    must_refuse = True
                else:
                    what = mutate_png(rng, target)
        else:
            target = rng.choice([calib / "white" / "manifest.json", *sorted((calib / "white").glob("*.png"))])
            if mutate:
                what = (file_mutation(target, lambda: json_mutation(target, rng.choice(["albedo", "file", None])))
                        if target.suffix == ".json" else mutate_png(rng, target))
        src, read_back = calib, calib
    elif kind == "sweep record":
        target = d / "res" / "materials" / "plastic.json"
        if mutate:
            what = file_mutation(target, lambda: json_mutation(target, rng.choice(["timings", "error", "eta", None])))
        src, read_back = d / "mats", target
    else:  # special file in place of a command's input
        target = {"info": d / "analytic.json", "tabulate": d / "analytic.json", "reconstruct": d / "cap",
                  "calibrate": d / "calib" / rng.choice(["calibration.json", "grid_0.png", "mirror_led1.png", "white"]),
                  "layout": d / "dev.json", "sweep": d / "mats" / "plastic.json",
                  "report": d / "model" / "model.reflecto"}[case.command]
        if mutate:
            what = make_special(rng, target, d / "outside.json")
            # a link the user names on the command line is followed wherever it leads
            must_refuse = not (what == "special:outside-link" and case.command in ("info", "tabulate", "layout"))
        src = {"calibrate": d / "calib", "sweep": d / "mats"}.get(case.command, target)
        read_back = None
    argv = command_argv(case.command, src, d, out, rng)
    return argv, read_back, what, must_refuse


def command_argv(command: str, src: Path, d: Path, out: Path, rng: random.Random) -> list[str]:
    if command == "info":
        return ["info", str(src), "--json"]
    if command == "tabulate":
        return ["tabulate", str(src), "-o", str(out / "t.binary"), "-q"]
    if command == "simulate":
        if src.name.startswith("device"):
            return ["simulate", str(d / "analytic.json"), "--device", str(src), "-o", str(out / "cap"), "-q"]
        return ["simulate", str(src), "-o", str(out / "cap"), "-q"]
    if command == "simulate-calibration":
        return ["simulate-calibration", "--device", str(src), "-o", str(out / "calib"), "-q"]
    if command == "layout":
        return ["layout", "--device", str(src), "--json", "--resolution", "16"]
    if command == "compare":
        ref = d / "analytic.json"
        if not ref.exists():
            shutil.copy(ROOT / "examples" / "ggx-plastic.json", ref)
        return ["compare", str(ref), str(src), "--json"]
    if command == "export":
        return ["export", str(src), "-o", str(out / rng.choice(["x.bsdf", "x.binary"])), "--isotropic", "yes", "-q"]
    if command == "report":
        return ["report", str(src), "--no-render", "-o", str(out / "rep")]
    if command == "fit-ct":
        return ["fit-ct", str(src), "--json"]
    if command == "render":
        return ["render", str(src), "--scene", "sphere-point", "--spp", "4", "--resolution", "32",
                "-o", str(out / "r.png")]
    if command == "reconstruct":
        if (d / "cal.npz").exists() or src.name == "cap-ab":
            return ["reconstruct", str(src), "--calibration", str(d / "cal.npz"), "--eta", "1.5",
                    "-o", str(out / "m.reflecto")]
        return ["reconstruct", str(src), "--eta", "1.5", "-o", str(out / "m.reflecto")]
    if command == "calibrate":
        return ["calibrate", str(src), "-o", str(out / "cal.npz"), "-q"]
    if command == "sweep":
        res = d / "res" if (d / "res").exists() else out / "res"
        return ["sweep", str(src), "-o", str(res), "-q", "--jobs", rng.choice(["1", "1", "2"])]
    raise ValueError(command)


def fingerprint(kind: str, path: Path | None, root: Path) -> str | None:
    """A digest of what reflecto reads from ``path`` (None: nothing to compare); paths inside
    the case folder ``root`` count as equal between cases."""
    if path is None:
        return None
    h = hashlib.sha256()

    def text(obj: object) -> bytes:
        return json.dumps(obj, sort_keys=True, default=str).replace(str(root), "<case>").encode()

    if kind in ("capture manifest", "capture frame"):
        from reflecto.instrument.capture import read_capture

        cap = read_capture(path)
        for a in (cap.raw, cap.check if cap.check is not None else np.zeros(0), cap.exposures_ms):
            h.update(np.ascontiguousarray(a).tobytes())
        h.update(text(cap.device.to_dict(with_truth=True)) + cap.kind.encode())
    elif kind in ("calibration .npz", "calibration.json", "calibration image", "white capture"):
        from reflecto.instrument.calibrate import Calibration, calibrate

        cal = Calibration.load(path) if path.suffix == ".npz" else calibrate(path)
        for a in (cal.scale, cal.leds, cal.response if cal.response is not None else np.zeros(0)):
            h.update(np.ascontiguousarray(a).tobytes())
        h.update(text([cal.device.to_dict(), cal.optics.to_dict()]))
    elif kind == "device file":
        from reflecto.instrument.device import load_device

        h.update(text(load_device(path).to_dict(with_truth=True)))
    elif kind in ("summary .json", "sweep record"):
        h.update(text(json.loads(path.read_text())))
    else:
        from reflecto.load import load_source

        src = load_source(path)
        rng = np.random.default_rng(7)
        ct, ph = rng.uniform(0.05, 1, (2, 512)), rng.uniform(0, 2 * np.pi, (2, 512))
        st = np.sqrt(1 - ct * ct)
        dirs = np.stack([st * np.cos(ph), st * np.sin(ph), ct], -1)
        h.update(np.round(src.eval(dirs[0], dirs[1]), 10).tobytes() + src.kind.encode())
        h.update(text(src.parameters()))
    return h.hexdigest()


def sanity(kind: str, path: Path | None) -> str | None:
    """An independent check of an accepted input: why it is implausible (None if it is not).

    Sources: finite values and a directional albedo in [−0.05, 1.5] (1.0 for the
    analytic model, whose k_d + k_s ≤ 1); calibrations: LED directions finite unit
    vectors within 5° of the design and a finite, non-negative scale.
    """
    if path is None:
        return None
    if kind in ("calibration .npz", "calibration.json", "calibration image", "white capture"):
        from reflecto.instrument.calibrate import Calibration, calibrate

        cal = Calibration.load(path) if path.suffix == ".npz" else calibrate(path)
        cos = np.sum(cal.leds * cal.device.leds, axis=1) / np.linalg.norm(cal.leds, axis=1)
        if not np.all(np.isfinite(cal.leds)) or np.degrees(np.arccos(np.clip(cos, -1, 1))).max() > 5.0:
            return "LED directions off the design by more than 5° or not finite"
        if not np.all(np.isfinite(cal.scale)) or np.any(cal.scale < 0):
            return "scale field not finite or negative"
        return None
    if kind in ("capture manifest", "capture frame", "device file", "summary .json", "sweep record"):
        return None
    from reflecto.brdf import directional_albedo
    from reflecto.load import load_source

    src = load_source(path)
    with np.errstate(all="ignore"):
        a = directional_albedo(src, [0.0, 30.0, 60.0, 75.0], n_u=64, n_phi=96)
    hi = 1.0 + 1e-3 if src.kind == "analytic" else 1.5
    if not np.all(np.isfinite(a)) or a.min() < -0.05 or a.max() > hi:
        return f"directional albedo {a.min():.3g}..{a.max():.3g}"
    return None


# -------------------------------------------------------------------- running
def _run_child(case: Case, base: Path, d: Path, result_file: Path) -> None:
    """In the forked child: build the case, run the command, write the result; never returns."""
    code = 0
    try:
        os.setsid()
        out_fd = os.open(d / ".stdout", os.O_WRONLY | os.O_CREAT, 0o644)
        err_fd = os.open(d / ".stderr", os.O_WRONLY | os.O_CREAT, 0o644)
        os.dup2(out_fd, 1)
        os.dup2(err_fd, 2)
        sys.stdout = open(1, "w", closefd=False, buffering=1)
        sys.stderr = open(2, "w", closefd=False, buffering=1)
        with open("/proc/self/status") as fh:
            vm = next(int(l.split()[1]) * 1024 for l in fh if l.startswith("VmSize:"))
        resource.setrlimit(resource.RLIMIT_AS, (vm + ADDRESS_HEADROOM, vm + ADDRESS_HEADROOM))
        argv, read_back, what, must_refuse = prepare(case, base, d)
        res = {"argv": argv, "mutation": what, "must_refuse": must_refuse}
        result_file.write_text(json.dumps(res))
        from reflecto.cli import main

        if case.command in ("sweep",) or case.kind == "special file":
            import importlib
            sw = importlib.import_module("reflecto.evaluate.sweep")

            sw.run_material = fake_run_material
        try:
            rc = main(argv)
            res["rc"] = rc
        except SystemExit as e:
            res["rc"] = e.code if isinstance(e.code, int) else 2
        except BaseException as e:  # noqa: BLE001 — what the user would see as a traceback
            res["traceback"] = f"{type(e).__name__}: {e}"[:500]
            res["tb"] = traceback.format_exc()[-2000:]
        sys.stdout.flush()
        sys.stderr.flush()
        if res.get("rc") == 0 and read_back is not None:
            try:
                res["fingerprint"] = fingerprint(case.kind, read_back, d)
                res["insane"] = sanity(case.kind, read_back)
            except Exception as e:  # noqa: BLE001 — accepted by the command, refused by a reader: note it
                res["fingerprint_error"] = f"{type(e).__name__}: {e}"[:300]
        result_file.write_text(json.dumps(res))
    except BaseException:  # noqa: BLE001
        try:
            result_file.write_text(json.dumps({"harness_error": traceback.format_exc()[-2000:]}))
        except BaseException:  # noqa: BLE001
            pass
        code = 3
    os._exit(code)


@dataclasses.dataclass
class _Running:
    case: Case
    d: Path
    result_file: Path
    t0: float
    timeout: float
    pid: int | None = None
    popen: object = None


def _start(case: Case, base: Path, work: Path, timeout: float) -> _Running:
    d = Path(tempfile.mkdtemp(prefix="case-", dir=work))
    r = _Running(case, d, work / f".{d.name}.json", time.monotonic(), timeout)
    if case.command == "render":
        r.popen = _start_render(case, base, d, r.result_file)
    else:
        pid = os.fork()
        if pid == 0:
            _run_child(case, base, d, r.result_file)
        r.pid = pid
    return r


def _poll(r: _Running) -> dict | None:
    """The finished case's record, or None while it runs (killed at its timeout)."""
    hang = time.monotonic() - r.t0 > r.timeout
    if r.popen is not None:
        return _poll_render(r, hang)
    wpid, status, usage = os.wait4(r.pid, os.WNOHANG)
    if not wpid:
        if not hang:
            return None
        _kill_group(r.pid)
        _, status, usage = os.wait4(r.pid, 0)
    rec = json.loads(r.result_file.read_text()) if r.result_file.exists() else {}
    rec["hang"] = bool(hang and not wpid)
    rec["signal"] = os.WTERMSIG(status) if os.WIFSIGNALED(status) else None
    rec["peak_rss"] = usage.ru_maxrss * 1024
    return rec


def _finish(r: _Running, rec: dict, base_prints: dict[str, str | None]) -> dict:
    rec["seconds"] = round(time.monotonic() - r.t0, 2)
    rec["stdout"] = _read(r.d / ".stdout")
    rec["stderr"] = _read(r.d / ".stderr")
    rec.update(kind=r.case.kind, command=r.case.command, seed=r.case.seed)
    rec["outcome"] = classify(rec, r.case, r.d, base_prints)
    shutil.rmtree(r.d, ignore_errors=True)
    r.result_file.unlink(missing_ok=True)
    return rec


def _kill_group(pid: int) -> None:
    for target in (-pid, pid):
        try:
            os.kill(target, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass


def _start_render(case: Case, base: Path, d: Path, result_file: Path):  # type: ignore[no-untyped-def]
    """The render command loads Mitsuba, which does not survive a fork: a fresh interpreter instead."""
    import subprocess

    argv, read_back, what, must_refuse = prepare(case, base, d)
    result_file.write_text(json.dumps({"argv": argv, "mutation": what, "must_refuse": must_refuse,
                                       "read_back": str(read_back) if read_back else None}))
    so, se = open(d / ".stdout", "w"), open(d / ".stderr", "w")
    p = subprocess.Popen([sys.executable, "-m", "reflecto.cli", *argv], stdout=so, stderr=se, start_new_session=True,
                         env={**os.environ, "PYTHONPATH": str(ROOT / "src")})
    so.close()
    se.close()
    return p


def _poll_render(r: _Running, hang: bool) -> dict | None:
    p = r.popen
    if p.poll() is None:  # type: ignore[union-attr]
        if not hang:
            return None
        _kill_group(p.pid)  # type: ignore[union-attr]
        p.wait()  # type: ignore[union-attr]
    rec = json.loads(r.result_file.read_text())
    rc = p.returncode  # type: ignore[union-attr]
    rec.update(hang=hang and rc is not None and rc < 0, rc=rc if rc >= 0 else None, signal=-rc if rc < 0 else None,
               peak_rss=0)
    err = _read(r.d / ".stderr")
    if "Traceback (most recent call last)" in err:
        rec["traceback"] = err.strip().splitlines()[-1][:500]
    if rc == 0 and rec.get("read_back"):
        try:
            rec["fingerprint"] = fingerprint(r.case.kind, Path(rec["read_back"]), r.d)
            rec["insane"] = sanity(r.case.kind, Path(rec["read_back"]))
        except Exception as e:  # noqa: BLE001
            rec["fingerprint_error"] = f"{type(e).__name__}: {e}"[:300]
    return rec


def _read(p: Path) -> str:
    try:
        return p.read_text(errors="replace")
    except OSError:
        return ""


def classify(rec: dict, case: Case, d: Path, base_prints: dict[str, str | None]) -> str:
    if "harness_error" in rec:
        raise RuntimeError(f"fuzz harness failed on {case}: {rec['harness_error']}")
    err = rec.get("stderr", "")
    if rec.get("hang"):
        return "hang"
    if ("out of memory" in err or "MemoryError" in str(rec.get("traceback", ""))
            or rec.get("peak_rss", 0) > MEMORY_LIMIT):
        return "memory"
    if rec.get("signal"):
        return "crash"
    if "traceback" in rec or "Traceback (most recent call last)" in err:
        return "traceback"
    rc = rec.get("rc")
    lines = [l for l in err.splitlines() if l.strip() and not l.startswith(("reflecto: warning:", "sweep: ",
                                                                            "reconstruct: "))]
    if rc == 0:
        if rec.get("must_refuse"):
            return "corrupt-accepted"
        if "fingerprint_error" in rec or rec.get("insane"):
            return "corrupt-accepted"  # implausible, or refused by reflecto's own reader
        same = rec.get("fingerprint") is not None and rec.get("fingerprint") == base_prints.get(case.kind)
        # a file edited as a writer would (checksums recomputed) can only be told by its ranges
        crafted = "crafted" in str(rec.get("mutation"))
        if "damaged result record" in err or "evaluated again" in err:
            return "recovered"
        if same or rec.get("fingerprint") is None:
            return "accepted-same"
        return "corrupt-accepted" if KINDS[case.kind][2] and not crafted else "accepted-changed"
    errors = [l for l in lines if l.startswith("reflecto: error: ")]
    batch = rec.get("argv", [""])[0] == "sweep"
    if rc != 1 or not errors or (len(lines) != len(errors)) or (not batch and len(errors) != 1):
        return "bad-message"
    for line in errors:
        if str(d) not in line:
            return "bad-message"
    if not batch and (d / "out").exists():
        return "output-left"
    return "refused"


def base_fingerprints(base: Path, work: Path) -> dict[str, str | None]:
    """The fingerprint of each kind's valid input, read from a case folder as the cases are."""
    out = {}
    for kind, (cmds, _, _) in KINDS.items():
        d = Path(tempfile.mkdtemp(prefix="base-", dir=work))
        _, read_back, _, _ = prepare(Case(kind, cmds[0], 0), base, d, mutate=False)
        if base_choice(Case(kind, cmds[0], 0)) is not None:  # drawn per case: no single base
            out[kind] = None
        else:
            out[kind] = fingerprint(kind, read_back, d)
        shutil.rmtree(d, ignore_errors=True)
    return out


def campaign(cases: list[Case], base: Path, work: Path, jobs: int = 2, timeout: float = 120.0,
             log: Callable[[dict], None] | None = None) -> list[dict]:
    """Run ``cases``, ``jobs`` at a time, each in a child forked from this (main) thread."""
    prints = base_fingerprints(base, work)
    pending = list(cases)
    running: list[_Running] = []
    results: list[dict] = []
    while pending or running:
        while pending and len(running) < jobs:
            case = pending.pop(0)
            running.append(_start(case, base, work, timeout * (3 if case.command in RARE else 1)))
        time.sleep(0.02)
        for r in list(running):
            rec = _poll(r)
            if rec is None:
                continue
            running.remove(r)
            p = dict(prints)
            name = base_choice(r.case)
            if name is not None:  # compared with whichever valid file the case drew
                p[r.case.kind] = fingerprint(r.case.kind,
                                             base / ("model" if r.case.kind.startswith("model") else "") / name, base)
            results.append(_finish(r, rec, p))
            if log:
                log(results[-1])
    return results


def table(results: list[dict]) -> str:
    """Markdown table: input kind × outcome counts (only outcomes that occur, plus the failures)."""
    counts = collections.Counter((r["kind"], r["outcome"]) for r in results)
    cols = [o for o in OUTCOMES if any(k[1] == o for k in counts) or o in FAILURES]
    kinds = list(dict.fromkeys(r["kind"] for r in results))
    head = "| input kind | cases | " + " | ".join(cols) + " |"
    rows = [head, "|" + "---|" * (len(cols) + 2)]
    for k in kinds:
        n = sum(v for (kk, _), v in counts.items() if kk == k)
        rows.append(f"| {k} | {n} | " + " | ".join(str(counts.get((k, c), 0)) for c in cols) + " |")
    tot = collections.Counter(r["outcome"] for r in results)
    rows.append(f"| **all** | {len(results)} | " + " | ".join(str(tot.get(c, 0)) for c in cols) + " |")
    cmds = collections.Counter(r["command"] for r in results)
    return "\n".join(rows) + "\n\ncommands: " + ", ".join(f"{c} {n}" for c, n in sorted(cmds.items()))


def failures_of(results: list[dict]) -> list[dict]:
    return [r for r in results if r["outcome"] in FAILURES]


def _describe(r: dict) -> str:
    return (f"{r['outcome']}: {r['kind']} / {r['command']} seed {r['seed']} ({r.get('mutation')}): "
            f"rc {r.get('rc')} {r.get('traceback', '')} {r.get('insane') or ''} stderr {r.get('stderr', '')[-400:]!r}")


# ---------------------------------------------------------------- pytest entry
@pytest.fixture(scope="module")
def fuzz_base(tmp_path_factory, shared) -> Path:
    return build_base(tmp_path_factory.mktemp("fuzz") / "base")


#: The default run: every (kind, command) pair but the slow ones, then more cases of
#: the cheap kinds, each with a seed of its own; < 30 s on 2 cores.
DEFAULT_CASES = 48


def test_fuzz_campaign_small(fuzz_base, tmp_path):
    cases = [c for c in draw_cases(DEFAULT_CASES + 20, seed=23) if c.command not in RARE][:DEFAULT_CASES]
    results = campaign(cases, fuzz_base, tmp_path, jobs=2, timeout=60.0)
    bad = failures_of(results)
    assert not bad, "\n".join(_describe(r) for r in bad) + "\n" + table(results)
    outcomes = collections.Counter(r["outcome"] for r in results)
    assert outcomes["refused"] >= len(results) // 2, table(results)


@pytest.mark.slow
def test_fuzz_campaign_full(fuzz_base, tmp_path):
    results = campaign(draw_cases(600, seed=1), fuzz_base, tmp_path, jobs=2)
    bad = failures_of(results)
    print("\n" + table(results))
    assert not bad, "\n".join(_describe(r) for r in bad)


# ---------------------------------------------------------------- script entry
def _cli() -> int:
    ap = argparse.ArgumentParser(description="reflecto fuzz campaign: prints the input kind × outcome table")
    ap.add_argument("--cases", type=int, default=600, help="number of cases")
    ap.add_argument("--seed", type=int, default=1, help="master seed of the campaign")
    ap.add_argument("--jobs", type=int, default=2, help="cases run at once")
    ap.add_argument("--work", type=Path, default=ROOT / "out" / "fuzz", help="scratch folder (base inputs kept)")
    ap.add_argument("--log", type=Path, help="write every case's record here (JSON lines)")
    a = ap.parse_args()
    base = a.work / "base"
    if not (base / ".complete").exists():
        shutil.rmtree(base, ignore_errors=True)
        print(f"building valid base inputs in {base} ...", file=sys.stderr)
        build_base(base)
    work = a.work / "cases"
    work.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    logf = open(a.log, "w") if a.log else None
    done = [0]

    def log(rec: dict) -> None:
        done[0] += 1
        if logf:
            logf.write(json.dumps({k: v for k, v in rec.items() if k not in ("tb",)}) + "\n")
            logf.flush()
        if rec["outcome"] in FAILURES:
            print(_describe(rec), file=sys.stderr)
        if done[0] % 50 == 0:
            print(f"fuzz: {done[0]}/{a.cases} cases ({time.monotonic() - t0:.0f} s)", file=sys.stderr)

    results = campaign(draw_cases(a.cases, a.seed), base, work, jobs=a.jobs, log=log)
    peak = max((r.get("peak_rss", 0) for r in results), default=0)
    print(table(results))
    print(f"\n{len(results)} cases in {time.monotonic() - t0:.0f} s; largest peak RSS {peak / 2**20:.0f} MiB; "
          f"failures: {len(failures_of(results))}")
    return 1 if failures_of(results) else 0


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT / "src"))
    sys.exit(_cli())
