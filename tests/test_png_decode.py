"""The capture reader's PNG decoder (:func:`reflecto.instrument.capture._decode_png`):
bit-identical to OpenCV on every row filter type, refuses damaged files naming them."""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from reflecto.instrument.capture import CaptureError, _decode_png, read_image


def _chunk(kind: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))


def _filter_rows(raw: np.ndarray, types: list[int], bpp: int) -> bytes:
    """PNG spec §9.2 forward filters of each row of ``raw`` (uint8, (H, rowbytes))."""
    out = []
    prev = np.zeros(raw.shape[1], dtype=np.int32)
    for y, ft in enumerate(types):
        x = raw[y].astype(np.int32)
        a = np.concatenate([np.zeros(bpp, np.int32), x[:-bpp]])
        c = np.concatenate([np.zeros(bpp, np.int32), prev[:-bpp]])
        b = prev
        if ft == 0:
            f = x
        elif ft == 1:
            f = x - a
        elif ft == 2:
            f = x - b
        elif ft == 3:
            f = x - (a + b) // 2
        else:
            p = a + b - c
            pa, pb, pc = np.abs(p - a), np.abs(p - b), np.abs(p - c)
            f = x - np.where((pa <= pb) & (pa <= pc), a, np.where(pb <= pc, b, c))
        out.append(bytes([ft]) + (f & 0xFF).astype(np.uint8).tobytes())
        prev = x
    return b"".join(out)


def _png(img: np.ndarray, types: list[int]) -> bytes:
    """An RGB PNG of ``img`` (H, W, 3; uint8 or uint16) with the given row filter types."""
    h, w, _ = img.shape
    depth = 8 * img.itemsize
    raw = img.astype(">u2" if depth == 16 else np.uint8).view(np.uint8).reshape(h, -1)
    body = zlib.compress(_filter_rows(raw, types, 3 * img.itemsize), 6)
    ihdr = struct.pack(">IIBBBBB", w, h, depth, 2, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", ihdr) + _chunk(b"IDAT", body[:50]) + _chunk(b"IDAT", body[50:]) \
        + _chunk(b"IEND", b"")


@pytest.mark.parametrize("dtype", [np.uint16, np.uint8])
def test_every_filter_type_decodes_exactly(dtype: type) -> None:
    rng = np.random.default_rng(3)
    top = np.iinfo(dtype).max
    img = rng.integers(0, top + 1, size=(23, 17, 3)).astype(dtype)
    img[5:9] = top  # wrap-around of the byte arithmetic
    types = [int(t) for t in rng.integers(0, 5, size=23)]
    types[:5] = [4, 3, 2, 1, 0]  # first row: the filters without a previous row
    data = _png(img, types)
    got = _decode_png(data, Path("f.png"), (23, 17), 8 * img.itemsize)
    assert got.dtype == dtype and got.shape == (23, 17, 3)
    assert np.array_equal(got, img)
    ref = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)[..., ::-1]
    assert np.array_equal(got, ref)


def test_opencv_written_frame_round_trips(tmp_path: Path) -> None:
    img = np.random.default_rng(1).integers(0, 4096, size=(31, 40, 3)).astype(np.uint16)
    path = tmp_path / "f.png"
    assert cv2.imwrite(str(path), np.ascontiguousarray(img[..., ::-1]))
    assert np.array_equal(read_image(path, (31, 40), np.uint16), img)


@pytest.mark.parametrize("damage, problem", [
    (lambda d: d[:-30], "truncated"),
    (lambda d: d[:60] + bytes([d[60] ^ 1]) + d[61:], "CRC"),
])
def test_damaged_frame_is_refused_naming_it(tmp_path: Path, damage, problem: str) -> None:  # type: ignore[no-untyped-def]
    img = np.full((8, 8, 3), 700, dtype=np.uint16)
    path = tmp_path / "led0_t1ms.png"
    path.write_bytes(damage(_png(img, [1] * 8)))
    with pytest.raises(CaptureError, match=problem) as e:
        read_image(path, (8, 8), np.uint16)
    assert str(path) in str(e.value)


def test_invalid_filter_type_is_refused() -> None:
    img = np.zeros((4, 4, 3), dtype=np.uint16)
    h, w = 4, 4
    raw = bytearray(_filter_rows(img.astype(">u2").view(np.uint8).reshape(h, -1), [0] * 4, 6))
    raw[(1 + w * 6) * 2] = 5
    ihdr = struct.pack(">IIBBBBB", w, h, 16, 2, 0, 0, 0)
    bad = (b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", ihdr) + _chunk(b"IDAT", zlib.compress(bytes(raw)))
           + _chunk(b"IEND", b""))
    with pytest.raises(CaptureError, match="filter type"):
        _decode_png(bad, Path("f.png"), (4, 4), 16)


def _chunks(img: np.ndarray, body: bytes | None = None) -> tuple[bytes, bytes, bytes, bytes]:
    """Signature + IHDR, the image data (one IDAT's body), ``tEXt``, IEND of ``img`` (filter 0)."""
    h, w, _ = img.shape
    raw = _filter_rows(img.astype(">u2").view(np.uint8).reshape(h, -1), [0] * h, 6)
    head = b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 16, 2, 0, 0, 0))
    return head, zlib.compress(raw) if body is None else body, _chunk(b"tEXt", b"k\x00v"), _chunk(b"IEND", b"")


@pytest.mark.parametrize("build, problem", [
    (lambda head, data, text, end: head + head[8:] + _chunk(b"IDAT", data) + end, "header chunk"),
    (lambda head, data, text, end: head + _chunk(b"ABCD", b"x") + _chunk(b"IDAT", data) + end, "unknown critical"),
    (lambda head, data, text, end: head + _chunk(b"IDAT", data) + end + text, "after the end chunk"),
    (lambda head, data, text, end: head + _chunk(b"IDAT", data[:9]) + text + _chunk(b"IDAT", data[9:]) + end,
     "not consecutive"),
    (lambda head, data, text, end: head + _chunk(b"IDAT", data + bytes(64)) + end, "after the end of the image"),
    (lambda head, data, text, end: head + _chunk(b"IDAT", data + zlib.compress(b"x")) + end,
     "after the end of the image"),
    (lambda head, data, text, end: head + text + end, "no image data"),
])
def test_a_png_whose_chunks_break_the_spec_is_refused(build, problem: str) -> None:  # type: ignore[no-untyped-def]
    """PNG spec §5.6: one header, first; no unknown critical chunk; the image data chunks
    consecutive; nothing after the end chunk; nothing after the image data's stream. Each
    damage is refused naming it; the same parts put together rightly decode (and an
    ancillary chunk before the image data is no damage)."""
    img = np.arange(4 * 4 * 3, dtype=np.uint16).reshape(4, 4, 3) * 97
    head, data, text, end = _chunks(img)
    with pytest.raises(CaptureError, match=problem):
        _decode_png(build(head, data, text, end), Path("f.png"), (4, 4), 16)
    fine = head + text + _chunk(b"IDAT", data[:9]) + _chunk(b"IDAT", data[9:]) + end
    assert np.array_equal(_decode_png(fine, Path("f.png"), (4, 4), 16), img)


def test_an_interlaced_frame_is_refused_when_its_data_outgrow_its_passes(tmp_path: Path) -> None:
    """An Adam7 frame goes to OpenCV only after its inflated size matches its seven passes
    (PNG spec §8.2); OpenCV alone accepts 5 000 bytes too many."""
    img = np.random.default_rng(2).integers(0, 4096, size=(13, 11, 3)).astype(np.uint16)
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(img[..., ::-1]))
    assert ok
    plain = buf.tobytes()
    # re-encode the same pixels interlaced, by hand: seven passes, filter type 0
    passes = []
    for x0, y0, dx, dy in ((0, 0, 8, 8), (4, 0, 8, 8), (0, 4, 4, 8), (2, 0, 4, 4), (0, 2, 2, 4), (1, 0, 2, 2),
                           (0, 1, 1, 2)):
        sub = img[y0::dy, x0::dx]
        if sub.size:
            passes.append(b"".join(b"\x00" + row.astype(">u2").tobytes() for row in sub))
    raw = b"".join(passes)
    ihdr = struct.pack(">IIBBBBB", 11, 13, 16, 2, 0, 0, 1)
    good = plain[:8] + _chunk(b"IHDR", ihdr) + _chunk(b"IDAT", zlib.compress(raw)) + _chunk(b"IEND", b"")
    path = tmp_path / "led0_t1ms.png"
    path.write_bytes(good)
    assert np.array_equal(read_image(path, (13, 11), np.uint16), img)
    path.write_bytes(good.replace(good[33:], _chunk(b"IDAT", zlib.compress(raw + bytes(5000))) + _chunk(b"IEND", b"")))
    with pytest.raises(CaptureError, match="image data holds") as e:
        read_image(path, (13, 11), np.uint16)
    assert str(path) in str(e.value)
