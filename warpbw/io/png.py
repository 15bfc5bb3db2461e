"""A PNG reader of our own for the images Pillow cannot read at full precision: 16-bit RGB, grey + alpha and RGBA
(Pillow has no 16-bit colour mode and gives them 8 bits per channel).  Greyscale, grey + alpha, RGB and RGBA at 8 or
16 bits per channel, Adam7-interlaced or not (PNG specification, 2nd edition, W3C 2003: sections 5-7 and 9-11);
palette images and bit depths below 8 are Pillow's (``precompute.gmm_mipmap`` reads those).

Public:
    ``read_png(path) -> PngImage``   the samples as stored (uint8 or uint16, (H, W, channels)), alpha included
    ``png_header(path)``             (width, height, bit depth, colour type, interlace) from IHDR, or None

Average and Paeth rows are rebuilt along the image's anti-diagonals (one numpy step per diagonal, W + H of them): about
0.75 s for 1024 x 1024 16-bit RGB of Paeth rows on one core, 2.9 s for 2048 x 2048 (Pillow's 8-bit reading: 0.5 s);
rows of None, Sub and Up only take one step per row.

Every problem (not a PNG, a chunk cut short or with a wrong CRC, image data that does not inflate to the size the
header gives, an unknown filter type) is a one-line :class:`~warpbw.errors.WarpbwError` naming the file.  Ancillary
chunks (gAMA, iCCP, sBIT, tRNS, text) are skipped: the values are read as stored.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from warpbw.errors import WarpbwError, check_input_file, check_path

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"                          # section 5.2
CHANNELS = {0: 1, 2: 3, 4: 2, 6: 4}                           # colour type -> samples per pixel (section 6.1)
COLOUR_NAMES = {0: "greyscale", 2: "RGB", 3: "palette", 4: "grey + alpha", 6: "RGBA"}
# Adam7 passes: first row, first column, row step, column step (section 8.2)
ADAM7 = ((0, 0, 8, 8), (0, 4, 8, 8), (4, 0, 8, 4), (0, 2, 4, 4), (2, 0, 4, 2), (0, 1, 2, 2), (1, 0, 2, 1))
FILTER_NAMES = ("None", "Sub", "Up", "Average", "Paeth")      # filter types 0-4 (section 9.2)


@dataclass
class PngImage:
    pixels: np.ndarray      # (H, W, channels) uint8 or uint16, the samples as stored
    bit_depth: int          # 8 or 16
    colour_type: int        # 0 grey, 2 RGB, 4 grey + alpha, 6 RGBA


def png_header(path) -> tuple[int, int, int, int, int] | None:
    """(width, height, bit depth, colour type, interlace method) from a PNG's IHDR, or None where the file does not
    begin with a PNG signature and an IHDR chunk."""
    p = check_input_file(check_path(path, "png_header: path"), "a PNG image")   # an int: open()'s descriptor
    try:
        with open(p, "rb") as f:
            head = f.read(33)
    except OSError as exc:
        raise WarpbwError(f"{p}: cannot read this file ({exc.strerror})") from None
    if len(head) < 33 or not head.startswith(PNG_SIGNATURE) or head[12:16] != b"IHDR":
        return None
    w, h, depth, colour, _, _, interlace = struct.unpack(">IIBBBBB", head[16:29])
    return w, h, depth, colour, interlace


def _chunks(p: Path, data: bytes):
    """(type, body) of each chunk up to IEND, each CRC checked (section 5.3)."""
    pos = len(PNG_SIGNATURE)
    while True:
        if pos + 8 > len(data):
            raise WarpbwError(f"{p}: cannot decode this PNG (truncated: the file ends before its IEND chunk)")
        length, kind = struct.unpack(">I4s", data[pos:pos + 8])
        end = pos + 8 + length + 4
        if end > len(data):
            raise WarpbwError(f"{p}: cannot decode this PNG (truncated: its {kind.decode('latin-1')!r} chunk holds "
                              f"{length} bytes, the file ends {end - len(data)} bytes short of them)")
        body = data[pos + 8:pos + 8 + length]
        (crc,) = struct.unpack(">I", data[end - 4:end])
        if zlib.crc32(kind + body) != crc:
            raise WarpbwError(f"{p}: cannot decode this PNG (corrupt: the CRC of its {kind.decode('latin-1')!r} "
                              f"chunk at byte {pos} does not match)")
        yield kind, body
        if kind == b"IEND":
            return
        pos = end


def _unfilter(p: Path, raw: np.ndarray, height: int, row_bytes: int, bpp: int) -> np.ndarray:
    """The (height, row_bytes) uint8 scan lines of one (sub-)image from its filtered bytes (section 9.2), each row a
    filter-type byte and row_bytes bytes.  Rows of None, Sub and Up only: one row at a time, whole (Sub as a running
    sum of each byte lane).  Average and Paeth depend on the byte to the left, already reconstructed: the image is
    swept along its anti-diagonals of pixels (a pixel needs its left, upper and upper-left neighbours, all on
    earlier diagonals), one diagonal at a time, each row's filter picked per pixel."""
    lines = raw.reshape(height, row_bytes + 1)
    types = lines[:, 0]
    if types.max(initial=0) > 4:
        r = int(np.argmax(types > 4))
        raise WarpbwError(f"{p}: cannot decode this PNG (corrupt: scan line {r} has filter type {types[r]}, expected "
                          f"0-4: {', '.join(FILTER_NAMES)})")
    filt = lines[:, 1:]
    width = row_bytes // bpp
    if not np.isin(types, (3, 4)).any():
        out = np.empty((height, row_bytes), np.uint8)
        prev = np.zeros(row_bytes, np.uint8)
        for r in range(height):
            t = types[r]
            if t == 1:   # Sub: x = f + x(left), a running sum along each byte lane
                out[r] = np.cumsum(filt[r].reshape(width, bpp), axis=0, dtype=np.uint8).reshape(-1)
            elif t == 2:   # Up
                out[r] = filt[r] + prev
            else:
                out[r] = filt[r]
            prev = out[r]
        return out
    # padded by one pixel of zeros on the left and one row above: the neighbours outside the image are 0
    x = np.zeros((height + 1, (width + 1) * bpp), np.int16)
    stride = x.shape[1]
    flat = x.reshape(-1)
    f = filt.astype(np.int16).reshape(-1)
    lane = np.arange(bpp)
    for s in range(width + height - 1):
        ys = np.arange(max(0, s - width + 1), min(height - 1, s) + 1)
        xs = s - ys
        at = ((ys + 1) * stride + (xs + 1) * bpp)[:, None] + lane        # the pixels' bytes in x
        a, b, c = flat[at - bpp], flat[at - stride], flat[at - stride - bpp]   # left, up, upper left
        t = types[ys][:, None]
        pa, pb, pc = np.abs(b - c), np.abs(a - c), np.abs(a + b - 2 * c)   # |p - a|, |p - b|, |p - c|, p = a + b - c
        paeth = np.where((pa <= pb) & (pa <= pc), a, np.where(pb <= pc, b, c))
        pred = np.select([t == 1, t == 2, t == 3, t == 4], [a, b, (a + b) >> 1, paeth], 0)
        flat[at] = (f[(ys * row_bytes)[:, None] + xs[:, None] * bpp + lane] + pred) & 0xFF
    return x[1:, bpp:].astype(np.uint8)


def read_png(path) -> PngImage:
    """A PNG of 8 or 16 bits per sample, greyscale, grey + alpha, RGB or RGBA (palette images and smaller depths
    are refused, naming them), as stored."""
    p = check_input_file(check_path(path, "read_png: path"), "a PNG image")
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise WarpbwError(f"{p}: cannot read this file ({exc.strerror})") from None
    if not data.startswith(PNG_SIGNATURE):
        raise WarpbwError(f"{p}: not a PNG file (no PNG signature)")
    header, idat = None, []
    for kind, body in _chunks(p, data):
        if header is None and kind != b"IHDR":
            raise WarpbwError(f"{p}: cannot decode this PNG (corrupt: its first chunk is {kind.decode('latin-1')!r}, "
                              "expected IHDR)")
        if kind == b"IHDR":
            if header is not None or len(body) != 13:
                what = "a second IHDR chunk" if header is not None else f"an IHDR chunk of {len(body)} bytes, not 13"
                raise WarpbwError(f"{p}: cannot decode this PNG (corrupt: {what})")
            header = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat.append(body)
        elif kind[0] & 0x20 == 0 and kind not in (b"PLTE", b"IEND"):   # an unknown critical chunk (section 5.4)
            raise WarpbwError(f"{p}: cannot decode this PNG (a critical chunk {kind.decode('latin-1')!r} that this "
                              "reader does not know)")
    width, height, depth, colour, compression, filter_method, interlace = header
    if colour not in CHANNELS or depth not in (8, 16):
        raise WarpbwError(f"{p}: a {COLOUR_NAMES.get(colour, f'colour type {colour}')} PNG of {depth} bits per "
                          "sample: this reader takes 8 or 16, greyscale, grey + alpha, RGB or RGBA")
    if width == 0 or height == 0 or compression != 0 or filter_method != 0 or interlace > 1:
        raise WarpbwError(f"{p}: cannot decode this PNG (corrupt IHDR: {width} x {height}, compression method "
                          f"{compression}, filter method {filter_method}, interlace method {interlace}; expected "
                          "a size of at least 1 x 1 and methods 0, 0 and 0 or 1)")
    channels = CHANNELS[colour]
    bpp = channels * depth // 8
    passes = ADAM7 if interlace else ((0, 0, 1, 1),)
    sizes = [(-(-(height - r0) // dr), -(-(width - c0) // dc)) for r0, c0, dr, dc in passes]
    sizes = [(h, w) if h > 0 and w > 0 else (0, 0) for h, w in sizes]   # an empty pass has no scan lines at all
    need = sum(h * (w * bpp + 1) for h, w in sizes)
    inflate = zlib.decompressobj()
    try:
        raw = inflate.decompress(b"".join(idat), need + 1)   # at most one byte past the image: no bomb inflated
    except zlib.error as exc:
        raise WarpbwError(f"{p}: cannot decode this PNG (corrupt image data: zlib: {exc})") from None
    if len(raw) != need:
        raise WarpbwError(f"{p}: cannot decode this PNG ({'truncated' if len(raw) < need else 'corrupt'}: its image "
                          f"data inflate to {len(raw)}{'' if len(raw) <= need else '+'} bytes, expected {need} for "
                          f"{width} x {height} {depth}-bit {COLOUR_NAMES[colour]}"
                          f"{', interlaced' if interlace else ''})")
    dtype = np.dtype(">u2") if depth == 16 else np.dtype(np.uint8)
    pixels = np.empty((height, width, channels), np.uint16 if depth == 16 else np.uint8)
    buf = np.frombuffer(raw, np.uint8)
    at = 0
    for (r0, c0, dr, dc), (h, w) in zip(passes, sizes):
        if h == 0:
            continue
        n = h * (w * bpp + 1)
        lines = _unfilter(p, buf[at:at + n], h, w * bpp, bpp)
        pixels[r0::dr, c0::dc] = lines.reshape(-1).view(dtype).reshape(h, w, channels)
        at += n
    return PngImage(pixels, depth, colour)
