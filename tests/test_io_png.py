"""warpbw.io.png, the PNG reader of our own (16-bit colour PNGs, which Pillow reads with 8 bits): against an
encoder written here (zlib and each of the five scan-line filters chosen by the test, per row; Adam7 interlacing by
its pass table), against Pillow's reading of the 8-bit files Pillow writes (adaptive Sub and Paeth rows) and of
16-bit greyscale, and on damaged files (a one-line error naming the file).  PNG specification, 2nd edition (W3C
2003): 5 (chunks, CRC), 7-8 (scan lines, Adam7), 9 (filters), 11.2.2 (IHDR)."""
from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest

from warpbw.errors import WarpbwError
from warpbw.io.png import png_header, read_png

PASSES = ((0, 0, 8, 8), (0, 4, 8, 8), (4, 0, 8, 4), (0, 2, 4, 4), (2, 0, 4, 2), (0, 1, 2, 2), (1, 0, 2, 1))
CHANNELS = {0: 1, 2: 3, 4: 2, 6: 4}


def _predict(kind: int, a: int, b: int, c: int) -> int:
    """The predictor of filter type ``kind`` from the bytes left (a), up (b) and upper left (c): spec 9.2-9.4."""
    if kind == 0:
        return 0
    if kind == 1:
        return a
    if kind == 2:
        return b
    if kind == 3:
        return (a + b) // 2
    p = a + b - c
    pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
    return a if pa <= pb and pa <= pc else b if pb <= pc else c


def _filtered(rows: list, bpp: int, kinds) -> bytes:
    """Each row's filter-type byte and its bytes filtered (byte by byte, in plain Python), row r by kinds[r % n]."""
    out, prev = bytearray(), bytes(len(rows[0]))
    for r, row in enumerate(rows):
        kind = kinds[r % len(kinds)]
        out.append(kind)
        for i, x in enumerate(row):
            a = row[i - bpp] if i >= bpp else 0
            c = prev[i - bpp] if i >= bpp else 0
            out.append((x - _predict(kind, a, prev[i], c)) % 256)
        prev = row
    return bytes(out)


def _chunk(kind: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))


def encode(pixels: np.ndarray, colour: int, kinds=(0,), interlace: bool = False, extra: bytes = b"") -> bytes:
    """A PNG of ``pixels`` (H, W, C) uint8 or uint16; ``extra`` chunks go before the image data."""
    h, w, ch = pixels.shape
    depth = 16 if pixels.dtype == np.uint16 else 8
    raw = b""
    for r0, c0, dr, dc in (PASSES if interlace else ((0, 0, 1, 1),)):
        sub = pixels[r0::dr, c0::dc]
        if sub.size:   # an empty pass has no scan lines
            raw += _filtered([sub[r].astype(">u2" if depth == 16 else "u1").tobytes() for r in range(sub.shape[0])],
                             ch * depth // 8, kinds)
    return (b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, depth, colour, 0, 0, int(interlace)))
            + extra + _chunk(b"IDAT", zlib.compress(raw)) + _chunk(b"IEND", b""))


@pytest.mark.parametrize("depth", [8, 16])
@pytest.mark.parametrize("colour", [0, 2, 4, 6])
def test_each_filter_type_alone_and_mixed_and_interlaced_reads_back_what_was_written(tmp_path, colour, depth):
    """Every filter type on every row, then all five in turn, then rows of Paeth, Sub and Average (the rows a
    predictor of the left byte rebuilds), each plain and Adam7-interlaced, at sizes whose passes are empty (1 x 1,
    3 x 2) or partial (13 x 9).  Truth: the random samples encoded, to the bit."""
    rng = np.random.default_rng(10 * colour + depth)
    dtype = np.uint16 if depth == 16 else np.uint8
    for h, w in ((1, 1), (3, 2), (9, 13)):
        pixels = rng.integers(0, 2 ** depth, (h, w, CHANNELS[colour])).astype(dtype)
        for kinds in ((0,), (1,), (2,), (3,), (4,), (0, 1, 2, 3, 4), (4, 1, 3)):
            for interlace in (False, True):
                (tmp_path / "p.png").write_bytes(encode(pixels, colour, kinds, interlace))
                got = read_png(tmp_path / "p.png")
                assert got.pixels.dtype == dtype and (got.bit_depth, got.colour_type) == (depth, colour)
                assert np.array_equal(got.pixels, pixels), (h, w, kinds, interlace)


def test_pillows_8_bit_files_and_16_bit_greyscale_read_as_pillow_reads_them(tmp_path):
    """Pillow writes adaptive filters (Sub and Paeth rows here) and reads 8-bit files and 16-bit greyscale whole:
    our reading of a smooth noisy image in L, LA, RGB and RGBA, and in I;16, is Pillow's, value for value.  And an
    interlaced file of our encoder reads as Pillow reads it (an Adam7 check that is not ours alone)."""
    from PIL import Image

    rng = np.random.default_rng(7)
    x = np.linspace(0.0, 6.0, 37)
    smooth = np.sin(x[:, None] + 0.7 * x[None, :])[..., None] * [90, 60, 30, 20] + 128
    img = np.clip(smooth + rng.normal(0, 3, (37, 37, 4)), 0, 255).astype(np.uint8)
    for mode, ch in (("L", 1), ("LA", 2), ("RGB", 3), ("RGBA", 4)):
        Image.fromarray(img[..., 0] if ch == 1 else img[..., :ch], mode).save(tmp_path / f"{mode}.png")
        with Image.open(tmp_path / f"{mode}.png") as im:
            want = np.asarray(im)
        got = read_png(tmp_path / f"{mode}.png").pixels
        assert np.array_equal(got, want.reshape(got.shape)), mode
    grey16 = (img[..., 0].astype(np.uint16) * 251 + rng.integers(0, 250, (37, 37))).astype(np.uint16)
    Image.fromarray(grey16).save(tmp_path / "i16.png")
    assert png_header(tmp_path / "i16.png")[2:4] == (16, 0)
    with Image.open(tmp_path / "i16.png") as im:
        assert np.array_equal(read_png(tmp_path / "i16.png").pixels[..., 0], np.asarray(im).astype(np.uint16))
    (tmp_path / "adam7.png").write_bytes(encode(img[:, :, :3], 2, (4, 3, 1, 2, 0), interlace=True))
    with Image.open(tmp_path / "adam7.png") as im:
        assert np.array_equal(read_png(tmp_path / "adam7.png").pixels, np.asarray(im))


def test_ancillary_chunks_are_skipped_and_the_image_data_may_come_in_several_chunks(tmp_path):
    """gAMA and a text chunk before the data, the data split over three IDAT chunks (as encoders write large
    images): the values as stored."""
    pixels = np.random.default_rng(3).integers(0, 65536, (6, 5, 3)).astype(np.uint16)
    data = encode(pixels, 2, (4, 1))
    start = data.index(b"IDAT") - 4
    (length,) = struct.unpack(">I", data[start:start + 4])
    body = data[start + 8:start + 8 + length]
    cut = [body[:3], body[3:10], body[10:]]
    data = (data[:start] + _chunk(b"gAMA", struct.pack(">I", 45455)) + _chunk(b"tEXt", b"Software\0test")
            + b"".join(_chunk(b"IDAT", part) for part in cut) + data[start + 12 + length:])
    (tmp_path / "s.png").write_bytes(data)
    assert np.array_equal(read_png(tmp_path / "s.png").pixels, pixels)


def _damaged(good: bytes) -> dict:
    """Damaged versions of ``good`` (a 16-bit RGB PNG of 4 x 3 pixels with one IDAT) and what the error says."""
    idat = good.index(b"IDAT") - 4
    (n,) = struct.unpack(">I", good[idat:idat + 4])
    body = good[idat + 8:idat + 8 + n]
    raw = zlib.decompress(body)

    def with_idat(new_body):
        return good[:idat] + _chunk(b"IDAT", new_body) + good[idat + 12 + n:]

    bad_filter = bytearray(raw)
    bad_filter[25] = 5   # row 1's filter byte (each row: 1 + 4 pixels x 6 bytes)
    flipped = bytearray(good)
    flipped[idat + 10] ^= 0x01
    ihdr = struct.unpack(">IIBBBBB", good[16:29])
    return {
        "truncated in IDAT": (good[:idat + 20], r"truncated: its 'IDAT' chunk holds \d+ bytes, the file ends "
                                                r"\d+ bytes"),
        "no IEND": (good[:-12], "truncated: the file ends before its IEND chunk"),
        "a CRC": (bytes(flipped), r"corrupt: the CRC of its 'IDAT' chunk at byte \d+ does not match"),
        "not zlib": (with_idat(b"\x00" * 20), "corrupt image data: zlib: "),
        "short data": (with_idat(zlib.compress(raw[:-7])), "truncated: its image data inflate to 68 bytes, expected 75 "
                                                            "for 4 x 3 16-bit RGB"),
        "long data": (with_idat(zlib.compress(raw + b"\0" * 9)), r"corrupt: its image data inflate to 76\+ bytes"),
        "filter type 5": (with_idat(zlib.compress(bytes(bad_filter))), "corrupt: scan line 1 has filter type 5, "
                                                                        "expected 0-4"),
        "IHDR not first": (good[:8] + _chunk(b"gAMA", b"\0\0\0\1") + good[8:], "its first chunk is 'gAMA', expected"),
        "an unknown critical chunk": (good[:idat] + _chunk(b"ABCD", b"") + good[idat:], "a critical chunk 'ABCD'"),
        "interlace method 2": (good[:8] + _chunk(b"IHDR", struct.pack(">IIBBBBB", *ihdr[:6], 2)) + good[33:],
                               "corrupt IHDR: 4 x 3, compression method 0, filter method 0, interlace method 2"),
        "width 0": (good[:8] + _chunk(b"IHDR", struct.pack(">IIBBBBB", 0, *ihdr[1:])) + good[33:],
                    "corrupt IHDR: 0 x 3"),
        "palette": (good[:8] + _chunk(b"IHDR", struct.pack(">IIBBBBB", 4, 3, 8, 3, 0, 0, 0)) + good[33:],
                    "a palette PNG of 8 bits per sample: this reader takes 8 or 16"),
        "4-bit grey": (good[:8] + _chunk(b"IHDR", struct.pack(">IIBBBBB", 4, 3, 4, 0, 0, 0, 0)) + good[33:],
                       "a greyscale PNG of 4 bits per sample: this reader takes"),
        "not a PNG": (b"GIF89a" + good[6:], r"not a PNG file \(no PNG signature\)"),
    }


def test_a_damaged_png_is_one_line_naming_the_file_and_what_is_wrong(tmp_path):
    """Each damage (cut short, a bad CRC, image data that does not inflate or to the wrong size, an unknown filter
    type or critical chunk, an IHDR out of place or out of range, a colour type or depth this reader leaves to
    Pillow) is a WarpbwError naming the file; the good file reads."""
    pixels = np.random.default_rng(5).integers(0, 65536, (3, 4, 3)).astype(np.uint16)
    good = encode(pixels, 2, (4,))
    (tmp_path / "good.png").write_bytes(good)
    assert np.array_equal(read_png(tmp_path / "good.png").pixels, pixels)
    for name, (data, said) in _damaged(good).items():
        path = tmp_path / f"{name.replace(' ', '_')}.png"
        path.write_bytes(data)
        with pytest.raises(WarpbwError, match=f"^{path}: .*{said}") as exc:
            read_png(path)
        assert "\n" not in str(exc.value), name


def test_a_missing_file_or_a_folder_is_named_and_a_number_is_not_read_as_a_descriptor(tmp_path):
    """As the other readers: a missing file, a folder, and a number (open(1) would read stdout's descriptor and close
    it) are one line each, naming the path or the parameter."""
    for call in (read_png, png_header):
        with pytest.raises(WarpbwError, match=f"^{tmp_path / 'no.png'}: file not found \\(expected a PNG image\\)$"):
            call(tmp_path / "no.png")
        with pytest.raises(WarpbwError, match=f"^{tmp_path}: a directory, not a file"):
            call(tmp_path)
        with pytest.raises(WarpbwError, match=f"^{call.__name__}: path: expected a file name"):
            call(1)


def test_a_damaged_16_bit_normal_map_is_refused_by_load_map_naming_the_file(tmp_path):
    """Through the map reader (warpbw-precompute gmm, a scene's normal_map): a 16-bit RGB normal map cut short is
    the reader's one line, not Pillow's 8-bit reading of what is left."""
    from precompute.gmm_mipmap import load_map

    flat = np.broadcast_to(np.array([32768, 32768, 65535], np.uint16), (4, 4, 3)).copy()
    data = encode(flat, 2, (1,))
    (tmp_path / "n.png").write_bytes(data[:-20])
    with pytest.raises(WarpbwError, match=f"^{tmp_path / 'n.png'}: cannot decode this PNG \\(truncated"):
        load_map(tmp_path / "n.png", "normal")
    (tmp_path / "n.png").write_bytes(data)
    np.testing.assert_allclose(load_map(tmp_path / "n.png", "normal")[..., 2], 1.0, atol=1e-4)


def test_an_image_of_many_rows_and_columns_reads_back_whatever_its_filters(tmp_path):
    """A larger image (the anti-diagonal sweep over 200 x 150 pixels, rows of every filter in turn) read back whole;
    its filtered rows made with numpy here (Up and Sub are whole-row operations), the Paeth and Average rows of the
    small tests above standing for the rest.  Truth: the samples."""
    rng = np.random.default_rng(11)
    pixels = rng.integers(0, 65536, (150, 200, 4)).astype(np.uint16)
    rows = pixels.reshape(150, -1).astype(">u2").view(np.uint8).reshape(150, -1)
    filtered = []
    for r in range(150):
        kind = r % 3
        prev = rows[r - 1] if r else np.zeros_like(rows[0])
        left = np.concatenate([np.zeros(8, np.uint8), rows[r][:-8]])
        pred = (np.zeros_like(rows[r]), left, prev)[kind]
        filtered.append(bytes([kind]) + (rows[r] - pred).astype(np.uint8).tobytes())
    data = (b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", struct.pack(">IIBBBBB", 200, 150, 16, 6, 0, 0, 0))
            + _chunk(b"IDAT", zlib.compress(b"".join(filtered))) + _chunk(b"IEND", b""))
    (tmp_path / "big.png").write_bytes(data)
    assert np.array_equal(read_png(tmp_path / "big.png").pixels, pixels)
    # one Paeth row among them: the sweep along anti-diagonals
    small = pixels[:40, :60]
    (tmp_path / "mixed.png").write_bytes(encode(small, 6, (1, 4, 2, 3)))
    assert np.array_equal(read_png(tmp_path / "mixed.png").pixels, small)
