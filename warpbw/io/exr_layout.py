"""The OpenEXR file layout, read to say which part of a file OpenEXR refused is damaged.

Public functions:

- ``first_header_declares(path, name, typ) -> bool | None``: whether the first header holds that attribute (OpenEXR
  gives a missing dataWindow its default instead of refusing the file).
- ``exr_damage(path) -> str | None``: the first damaged part of an EXR file's version field, headers, offset tables
  or chunk leaders that the layout shows, in words naming its byte (None where none shows: damage in the pixel data,
  or beyond what is checked).  ``warpbw.io.exr`` calls it once OpenEXR has refused a file; OpenEXR alone decides
  whether a file reads, so a file is never refused for what this module alone finds.

Checked: the version field and its flags; every header's attributes (names and type names NUL-terminated and of the
allowed length, sizes of the fixed-size types, values with a closed set: compression, line order, channel pixel
types, tile modes, windows, strings as UTF-8), the attributes every header or part needs, channel sampling; the
offset table of a single-part file (as many entries as the data window and compression or tiling make chunks,
each chunk's leader and data size) and the offset tables of a multi-part or deep file (part numbers).  Not checked:
the tiles' order in mipmapped and ripmapped files, the chunks of multi-part and deep files beyond their part number,
and the pixel data.
"""
from __future__ import annotations

import difflib
import mmap
import struct

from warpbw.errors import check_path

# What the diagnosis of a file OpenEXR has refused checks (``exr_damage``), from the OpenEXR file layout
# (openexr.com/en/latest/OpenEXRFileLayout.html; section names in quotes).  "Version Field": the low byte is the format
# version, 2; bit 9 marks a single-part tiled file (then bits 11 and 12 are 0), bit 10 names of up to 255 bytes, bit 11
# deep ("non-image") data, bit 12 a multi-part file; no other bit is defined.
_EXR_VERSION = 2
_TILED_FLAG, _LONG_NAMES_FLAG, _NON_IMAGE_FLAG, _MULTI_PART_FLAG = 0x200, 0x400, 0x800, 0x1000
# "Attribute Layout": an attribute is its name, NUL, its type name, NUL, the value's size (int32), then the value; names
# and type names are 1 to 31 bytes (1 to 255 with the long-names bit).  A header ends with an empty name (a NUL byte).
_NAME_MAX, _LONG_NAME_MAX = 31, 255
# "Header Attributes (All Files)": in every header, with their types; "Tile Header Attribute": tiles in a tiled part;
# "Multi-Part and Deep Data Header Attributes": name, type and chunkCount in every part of a multi-part or deep file.
_REQUIRED_ATTRIBUTES = {"channels": "chlist", "compression": "compression", "dataWindow": "box2i",
                        "displayWindow": "box2i", "lineOrder": "lineOrder", "pixelAspectRatio": "float",
                        "screenWindowCenter": "v2f", "screenWindowWidth": "float"}
_TILED_ATTRIBUTES = {"tiles": "tiledesc"}
_MULTI_PART_ATTRIBUTES = {"name": "string", "type": "string", "chunkCount": "int"}
# Attributes that every part of a multi-part file shares (OpenEXR's multi-part reader checks them against part 0).
_SHARED_ATTRIBUTES = ("displayWindow", "pixelAspectRatio", "timeCode", "chromaticities")
# "Predefined Attribute Types": bytes of the value of each fixed-size type.
_TYPE_SIZES = {"box2i": 16, "box2f": 16, "chromaticities": 32, "compression": 1, "double": 8, "envmap": 1, "float": 4,
               "int": 4, "keycode": 28, "lineOrder": 1, "m33f": 36, "m33d": 72, "m44f": 64, "m44d": 128,
               "rational": 8, "tiledesc": 9, "timecode": 8, "v2i": 8, "v2f": 8, "v2d": 16, "v3i": 12, "v3f": 12,
               "v3d": 24, "deepImageState": 1}
# "Predefined Attribute Types", compression, and "Offset Tables": scan lines in one chunk of a scan-line part, by
# compression method: NONE, RLE, ZIPS 1; ZIP, PXR24 16; PIZ, B44, B44A, DWAA 32; DWAB 256.  Methods 10 to 13 (HTJ2K256,
# HTJ2K32, LJ2K, ZSTD) are newer than the document: what the bundled OpenEXR (3.5) writes for them.
_COMPRESSIONS = ("NONE", "RLE", "ZIPS", "ZIP", "PIZ", "PXR24", "B44", "B44A", "DWAA", "DWAB",
                 "HTJ2K256", "HTJ2K32", "LJ2K", "ZSTD")
_LINES_PER_CHUNK = (1, 1, 1, 16, 32, 16, 32, 32, 32, 256, 256, 32, 256, 1)
# "Predefined Attribute Types": lineOrder INCREASING_Y, DECREASING_Y, RANDOM_Y; chlist pixel types UINT, HALF, FLOAT;
# tiledesc level modes ONE_LEVEL, MIPMAP_LEVELS, RIPMAP_LEVELS (low 4 bits) and rounding ROUND_DOWN, ROUND_UP (bit 4).
_LINE_ORDERS = ("INCREASING_Y", "DECREASING_Y", "RANDOM_Y")
_PIXEL_TYPES = ("UINT", "HALF", "FLOAT")
_LEVEL_MODES = ("ONE_LEVEL", "MIPMAP_LEVELS", "RIPMAP_LEVELS")
_ROUNDING_MODES = ("ROUND_DOWN", "ROUND_UP")
# "Header Attributes (All Files)", type: the kinds of part.
_PART_TYPES = ("scanlineimage", "tiledimage", "deepscanline", "deeptile")
# The bundled OpenEXR's own header checks, beyond the layout (which says the library decides): window coordinates
# strictly between -(2^31 - 1) / 2 and (2^31 - 1) / 2, a pixelAspectRatio from 1e-6 to 1e6, a screenWindowWidth of 0 or
# more, a channel's pLinear 0 or 1 and its sampling dividing the data window's origin and size (measured on 3.5).
_WINDOW_LIMIT = (2**31 - 1) // 2
_PIXEL_ASPECT_RANGE = (1e-6, 1e6)
# "Predefined Attribute Types", chlist: bytes a pixel of each pixel type takes (UINT, HALF, FLOAT), unpacked.
_PIXEL_BYTES = (4, 2, 4)
# "Chunk Layout": a scan-line chunk starts with its first scan line's y and the data's size (int32 each), a tile with
# its tile x, y, level x, y and the data's size; in a multi-part file each chunk starts with its part number (int32).
_SCANLINE_LEADER, _TILE_LEADER, _PART_NUMBER = 8, 20, 4

class _Damage(Exception):
    """The first damaged part of an EXR file that ``exr_damage`` finds, in words (raised and caught inside it)."""


# Attributes whose type the layout fixes: a 'dataWindow' of another type is damage, not a user's attribute.
_KNOWN_TYPES = {**_REQUIRED_ATTRIBUTES, **_TILED_ATTRIBUTES, **_MULTI_PART_ATTRIBUTES}


def _int32(data, at: int) -> int:
    return struct.unpack_from("<i", data, at)[0]


def _text(data, at: int, stop: int, limit: int, what: str, where: str) -> tuple[str, int]:
    """The NUL-terminated text of 1 to ``limit`` bytes at byte ``at`` that ends before byte ``stop`` (``what`` it is,
    in the ``where`` part of the file), and the byte after its NUL."""
    end = data.find(b"\0", at, min(stop, at + limit + 1))
    if end < 0:
        if at + limit + 1 <= stop:
            longer = data.find(b"\0", at, min(stop, at + _LONG_NAME_MAX + 1))
            if limit == _NAME_MAX and longer > 0:
                raise _Damage(f"{where} damaged at byte {at}: {what} is {longer - at} bytes long, more than {limit} "
                              "(the version field's long-names flag 0x400 is not set)")
            raise _Damage(f"{where} damaged at byte {at}: {what} has no NUL byte within {limit + 1} bytes")
        if stop < len(data):
            raise _Damage(f"{where} damaged at byte {at}: {what} runs past the end of its attribute (byte {stop})")
        raise _Damage(f"the file ends after {len(data)} bytes, inside {what} (from byte {at}) in the {where}")
    if end == at:
        raise _Damage(f"{where} damaged at byte {at}: {what} is empty")
    raw = bytes(data[at:end])
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise _Damage(f"{where} damaged at byte {at + exc.start}: {what} (from byte {at}) is not UTF-8 text "
                      f"(byte 0x{raw[exc.start]:02x})") from None
    if not text.isprintable():
        raise _Damage(f"{where} damaged at byte {at}: {what} holds control characters ({text!r})")
    return text, end + 1


def _channel_list(data, at: int, size: int, name_max: int, where: str) -> list[tuple]:
    """The channels of a chlist value ("Predefined Attribute Types": per channel its name, NUL, pixel type (int32),
    pLinear (1 byte), 3 reserved bytes, x and y sampling (int32 each); a NUL after the last one) of ``size`` bytes at
    byte ``at``, as ``[(name, byte of its pixel type, pixel type, x sampling, y sampling)]``."""
    def bad(pos: int, text: str) -> _Damage:
        return _Damage(f"{where} damaged at byte {pos}: attribute 'channels' (chlist): {text}")

    p, end, channels = at, at + size, []
    while True:
        if p >= end:
            raise bad(p, "it ends without the NUL byte that closes the channel list")
        if data[p] == 0:
            if p + 1 != end:
                raise bad(p + 1, f"{end - p - 1} bytes follow the NUL byte that closes the channel list")
            return channels
        try:
            name, q = _text(data, p, end, name_max, "a channel name", where)
        except _Damage as exc:
            raise bad(p, str(exc).split(": ", 1)[-1]) from None
        if q + 16 > end:
            raise bad(q, f"it ends inside channel {name!r} ({end - q} of its 16 bytes after the name)")
        pixel_type, linear, x_sampling, y_sampling = struct.unpack_from("<iB3xii", data, q)
        if not 0 <= pixel_type < len(_PIXEL_TYPES):
            raise bad(q, f"channel {name!r} has pixel type {pixel_type} (expected 0 UINT, 1 HALF or 2 FLOAT)")
        if linear > 1:
            raise bad(q + 4, f"channel {name!r} has pLinear {linear} (expected 0 or 1)")
        if x_sampling < 1 or y_sampling < 1:
            raise bad(q + 8, f"channel {name!r} has sampling {x_sampling} x {y_sampling} (expected 1 or more)")
        channels.append((name, q, pixel_type, x_sampling, y_sampling))
        p = q + 16


def _check_value(data, name: str, typ: str, at: int, size: int, name_max: int, where: str) -> None:
    """The value (``size`` bytes from byte ``at``) of attribute ``name`` of type ``typ``, where the layout ("Predefined
    Attribute Types") or OpenEXR's own checks say what it may hold."""
    def bad(pos: int, text: str) -> _Damage:
        return _Damage(f"{where} damaged at byte {pos}: attribute {name!r} ({typ}): {text}")

    if typ == "compression" and data[at] >= len(_COMPRESSIONS):
        raise bad(at, f"compression method {data[at]}, not one of the {len(_COMPRESSIONS)} that OpenEXR defines "
                      f"(0 to {len(_COMPRESSIONS) - 1})")
    if typ == "lineOrder" and data[at] >= len(_LINE_ORDERS):
        raise bad(at, f"line order {data[at]} (expected 0 to {len(_LINE_ORDERS) - 1})")
    if typ == "int" and name == "chunkCount" and _int32(data, at) < 0:
        raise bad(at, f"{_int32(data, at)} chunks")
    if typ == "box2i" and name in ("dataWindow", "displayWindow"):
        x0, y0, x1, y1 = struct.unpack_from("<4i", data, at)
        if x1 < x0 or y1 < y0:
            raise bad(at, f"reversed, from ({x0}, {y0}) to ({x1}, {y1}): a maximum below its minimum")
        if max(abs(x0), abs(y0), abs(x1), abs(y1)) >= _WINDOW_LIMIT:
            raise bad(at, f"from ({x0}, {y0}) to ({x1}, {y1}), beyond the coordinates of +-{_WINDOW_LIMIT - 1} that "
                      "OpenEXR reads")
    if typ == "float" and name in ("pixelAspectRatio", "screenWindowWidth"):
        value = struct.unpack_from("<f", data, at)[0]
        if name == "pixelAspectRatio" and not _PIXEL_ASPECT_RANGE[0] <= value <= _PIXEL_ASPECT_RANGE[1]:
            raise bad(at, f"{value:g} (expected {_PIXEL_ASPECT_RANGE[0]:g} to {_PIXEL_ASPECT_RANGE[1]:g})")
        if name == "screenWindowWidth" and value < 0:
            raise bad(at, f"{value:g} (expected 0 or more)")
    if typ == "tiledesc":
        x_size, y_size, mode = struct.unpack_from("<IIB", data, at)
        if x_size < 1 or y_size < 1:
            raise bad(at, f"tiles of {x_size} x {y_size} pixels")
        if mode & 0xF >= len(_LEVEL_MODES) or mode >> 4 >= len(_ROUNDING_MODES):
            raise bad(at + 8, f"level mode {mode & 0xF} and rounding mode {mode >> 4} (expected 0 to 2, and 0 or 1)")
    if typ == "chlist":
        _channel_list(data, at, size, name_max, where)
    if typ == "string":
        raw = bytes(data[at:at + size])
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise bad(at + exc.start, f"not UTF-8 text (byte 0x{raw[exc.start]:02x})") from None
        if name == "type" and text not in _PART_TYPES:
            raise bad(at, f"{text!r}, not a kind of part ({', '.join(_PART_TYPES)})")
    if typ == "stringvector":
        p = at
        while p < at + size:
            length = _int32(data, p) if p + 4 <= at + size else -1
            if length < 0 or p + 4 + length > at + size:
                raise bad(p, f"a string of {length} bytes that does not fit in the value's {size} bytes" if length >= 0
                          else "it ends inside the length of a string")
            try:
                bytes(data[p + 4:p + 4 + length]).decode("utf-8")
            except UnicodeDecodeError as exc:
                raise bad(p + 4 + exc.start, "a string that is not UTF-8 text") from None
            p += 4 + length
    if typ == "floatvector" and size % 4:
        raise bad(at, f"{size} bytes, not a whole number of floats")
    if typ == "preview":
        w, h = struct.unpack_from("<II", data, at) if size >= 8 else (0, 0)
        if size != 8 + 4 * w * h:
            raise bad(at, f"{size} bytes, not those of a preview image of {w} x {h} RGBA pixels")


def _header_attributes(data, at: int, name_max: int, where: str) -> tuple[dict, int]:
    """``{name: (type, first byte, value's first byte, value's size)}`` of the header from byte ``at`` to the NUL that
    ends it ("Attribute Layout"), each value checked, and the byte after that NUL."""
    attrs: dict = {}
    n, blame = len(data), ""
    while True:
        after = f"the attribute after {next(reversed(attrs))!r}" if attrs else "the first attribute"
        if at >= n:
            raise _Damage(f"the file ends after {n} bytes, inside the {where}, before the NUL byte that ends it")
        if data[at] == 0:
            return attrs, at + 1
        start = at
        try:
            name, at = _text(data, at, n, name_max, f"the name of {after}", where)
            typ, at = _text(data, at, n, name_max, f"the type name of attribute {name!r}", where)
        except _Damage as exc:      # a name cut off by the end of the file is the file's end, not a size's
            raise _Damage(f"{exc}{'' if str(exc).startswith('the file ends') else blame}") from None
        if at + 4 > n:
            raise _Damage(f"the file ends after {n} bytes, inside the size of attribute {name!r} (from byte {start}) "
                          f"in the {where}")
        size = _int32(data, at)
        known = _KNOWN_TYPES.get(name)
        if known is not None and typ != known:
            raise _Damage(f"{where} damaged at byte {start}: attribute {name!r} has type {typ!r} (expected {known!r})")
        want = _TYPE_SIZES.get(typ)
        if size < 0 or (want is not None and size != want):
            raise _Damage(f"{where} damaged at byte {at}: attribute {name!r} has type {typ!r} but size {size}"
                          f"{f' (expected {want})' if want is not None else ''}")
        if at + 4 + size > n:
            raise _Damage(f"the file ends after {n} bytes, inside attribute {name!r} ({typ}, from byte {start}) in the "
                          f"{where}: its value would take bytes {at + 4} to {at + 3 + size}"
                          f"{'' if want is not None else f' (or its size, at byte {at}, is damaged)'}")
        _check_value(data, name, typ, at + 4, size, name_max, where)
        attrs[name] = (typ, start, at + 4, size)
        # a wrong size of a value the layout does not delimit shows as damage in the name after it
        blame = "" if want is not None or typ == "chlist" else \
            f" (or the size of attribute {name!r}, at byte {at}, is damaged)"
        at += 4 + size


def _string_value(data, attrs: dict, name: str) -> str | None:
    if name not in attrs or attrs[name][0] != "string":
        return None
    _, _, at, size = attrs[name]
    return bytes(data[at:at + size]).decode("utf-8")   # checked by _check_value


def _check_required(attrs: dict, start: int, end: int, where: str, need: dict, why: str) -> None:
    """Each attribute of ``need`` (name: type) in the header from byte ``start`` to ``end``, which ``why`` needs."""
    for name, typ in need.items():
        if name not in attrs:
            near = difflib.get_close_matches(name, list(attrs), n=1, cutoff=0.75)
            hint = f"; it has {near[0]!r} at byte {attrs[near[0]][1]}: a damaged name?" if near else ""
            raise _Damage(f"{where} (bytes {start} to {end - 1}) damaged: it has no attribute {name!r} ({typ}), which "
                          f"{why}{hint}")


def _channels(data, attrs: dict, name_max: int, where: str) -> list[tuple]:
    _, _, at, size = attrs["channels"]
    return _channel_list(data, at, size, name_max, where)    # checked on the walk: raises nothing here


def _check_sampling(data, attrs: dict, name_max: int, where: str, tiled: bool) -> None:
    """Each channel's sampling divides the data window's origin and size, and is 1 in a tiled part."""
    x0, y0, x1, y1 = struct.unpack_from("<4i", data, attrs["dataWindow"][2])
    for name, at, _, xs, ys in _channels(data, attrs, name_max, where):
        for axis, s, lo, size, pos in (("x", xs, x0, x1 - x0 + 1, at + 8), ("y", ys, y0, y1 - y0 + 1, at + 12)):
            if lo % s or size % s or (tiled and s != 1):
                need = "1 in a tiled part" if tiled else f"a divisor of {lo} and {size}"
                raise _Damage(f"{where} damaged at byte {pos}: attribute 'channels' (chlist): channel {name!r} has "
                              f"{axis} sampling {s}, but the dataWindow's {axis} starts at {lo} and spans {size} "
                              f"pixels (expected {need})")


def _tile_levels(width: int, height: int, data, tiles_at: int) -> tuple[list, str]:
    """``[(tiles across, tiles down)]`` of each level of a tiled part in the order of its offset table ("Offset
    Tables", "Tiles": level by level), and the tiling in words."""
    x_size, y_size, mode = struct.unpack_from("<IIB", data, tiles_at)
    level_mode, round_up = mode & 0xF, mode >> 4

    def levels(v: int) -> int:     # 1 + log2(v), rounded down or up as the part says
        return (v - 1).bit_length() + 1 if round_up else v.bit_length()

    def level_size(v: int, level: int) -> int:
        return max(1, (v + ((1 << level) - 1 if round_up else 0)) >> level)

    if level_mode == 0:
        pairs = [(0, 0)]
    elif level_mode == 1:
        pairs = [(lv, lv) for lv in range(levels(max(width, height)))]
    else:
        pairs = [(lx, ly) for ly in range(levels(height)) for lx in range(levels(width))]
    out = [(-(-level_size(width, lx) // x_size), -(-level_size(height, ly) // y_size)) for lx, ly in pairs]
    return out, f"tiles of {x_size} x {y_size}, {_LEVEL_MODES[level_mode]}"


def _check_chunks(data, table: int, attrs: dict, tiled: bool, name_max: int) -> None:
    """The offset table of a single-part scan-line or tiled file, from byte ``table`` ("Offset Tables"): as many
    entries as the data window and compression (or tiling) make chunks, each pointing past the table to a chunk whose
    leader ("Chunk Layout") names the place it is for, and whose data lie inside the file and are no more than its
    pixels unpacked (OpenEXR stores a chunk unpacked when packing does not make it smaller)."""
    n = len(data)
    channels = _channels(data, attrs, name_max, "header")
    pixel_bytes = sum(_PIXEL_BYTES[t] for _, _, t, _, _ in channels)     # sampling 1 in a tiled part
    x0, y0, x1, y1 = struct.unpack_from("<4i", data, attrs["dataWindow"][2])
    width, height = x1 - x0 + 1, y1 - y0 + 1

    def scan_line_bytes(first: int, last: int) -> int:    # unpacked, each channel's samples on its own grid
        return sum(_PIXEL_BYTES[t] * (width // xs) * (last // ys - (first - 1) // ys) for _, _, t, xs, ys in channels)
    if tiled:
        levels, how = _tile_levels(width, height, data, attrs["tiles"][2])
        count = sum(nx * ny for nx, ny in levels)
        x_size, y_size = struct.unpack_from("<II", data, attrs["tiles"][2])
        sources = "dataWindow or tiles"
    else:
        method = data[attrs["compression"][2]]
        lines = _LINES_PER_CHUNK[method]
        count = -(-height // lines)
        how = f"{lines} scan lines a chunk for {_COMPRESSIONS[method]} compression"
        sources = "dataWindow or compression"
    end = table + 8 * count
    if end > n:
        raise _Damage(f"the file ends after {n} bytes, inside the offset table: a data window of {width} x {height} "
                      f"pixels ({how}) makes {count} chunk{'s' if count != 1 else ''}, whose offsets take bytes "
                      f"{table} to {end - 1}")
    leader = _TILE_LEADER if tiled else _SCANLINE_LEADER
    one_level = tiled and len(levels) == 1      # the tiles' order in the other level modes is not checked
    for k in range(count):        # read an entry at a time: a damaged count can be in the millions
        entry, which = table + 8 * k, f"chunk {k + 1} of {count}"
        at = struct.unpack_from("<Q", data, entry)[0]
        blame = f"(or the offset table entry at byte {entry}, or the header's {sources}, is damaged)"
        if at < end:
            raise _Damage(f"offset table damaged at byte {entry}: it puts {which} at byte {at}, inside the header and "
                          f"offset table (bytes 0 to {end - 1}; or the header's {sources}, which make {count} chunks, "
                          "is damaged)")
        if at + leader > n:
            raise _Damage(f"the file ends after {n} bytes, {'before' if at >= n else 'inside the leader of'} {which}, "
                          f"which the offset table (entry at byte {entry}) puts at byte {at}")
        if not tiled and _int32(data, at) != y0 + k * lines:
            raise _Damage(f"{which} damaged at byte {at}: it says it starts at scan line {_int32(data, at)}, expected "
                          f"{y0 + k * lines} {blame}")
        tile = (k % levels[0][0], k // levels[0][0], 0, 0) if one_level else None
        if one_level and struct.unpack_from("<4i", data, at) != tile:
            raise _Damage(f"{which} damaged at byte {at}: it says it is tile {struct.unpack_from('<4i', data, at)} "
                          f"(x, y, level x, level y), expected {tile} {blame}")
        if not tiled:
            unpacked = scan_line_bytes(y0 + k * lines, min(y1, y0 + k * lines + lines - 1))
        elif one_level:      # a tile on the right or bottom edge holds only the pixels inside the data window
            unpacked = pixel_bytes * min(x_size, width - tile[0] * x_size) * min(y_size, height - tile[1] * y_size)
        else:
            unpacked = pixel_bytes * x_size * y_size
        size = _int32(data, at + leader - 4)
        if size < 0 or (size == 0 and unpacked > 0):
            raise _Damage(f"{which} damaged at byte {at + leader - 4}: its data size is {size}")
        if at + leader + size > n:
            raise _Damage(f"the file ends after {n} bytes, inside {which} (from byte {at}, with {size} bytes of data)")
        if size > unpacked:
            raise _Damage(f"{which} damaged at byte {at + leader - 4}: its data size is {size} bytes, more than the "
                          f"{unpacked} its pixels take unpacked (or the header's dataWindow or channels are damaged)")


def _check_part_offsets(data, table: int, counts: list[int], multi: bool) -> None:
    """The offset tables of a multi-part or deep file, one after another from byte ``table``, as many entries as each
    part's chunkCount: each pointing past the tables, to a chunk that starts with its part number in a multi-part
    file."""
    n, end = len(data), table + 8 * sum(counts)
    if end > n:
        raise _Damage(f"the file ends after {n} bytes, inside the offset tables: the parts' chunkCount attributes "
                      f"({', '.join(map(str, counts))}) make offsets take bytes {table} to {end - 1}")
    entry = table
    for part, count in enumerate(counts):
        for k in range(count):
            which, at = f"chunk {k + 1} of {count} of part {part}", struct.unpack_from("<Q", data, entry + 8 * k)[0]
            if at < end or at + _PART_NUMBER > n:
                raise _Damage(f"offset table damaged at byte {entry + 8 * k}: it puts {which} at byte {at}, outside "
                              f"the pixel data (bytes {end} to {n - 1})")
            if multi and _int32(data, at) != part:
                raise _Damage(f"{which} damaged at byte {at}: it says it belongs to part {_int32(data, at)} (or the "
                              f"offset table entry at byte {entry + 8 * k} is damaged)")
        entry += 8 * count


def _check_shared(data, first: dict, attrs: dict, where: str) -> None:
    """The attributes of a later part of a multi-part file that it shares with the first part, equal to them."""
    for name in _SHARED_ATTRIBUTES:
        if name in first and name in attrs:
            _, _, at0, size0 = first[name]
            typ, _, at, size = attrs[name]
            if bytes(data[at:at + size]) != bytes(data[at0:at0 + size0]):
                raise _Damage(f"part headers damaged at byte {at0} or {at}: attribute {name!r} ({typ}) of part 0 "
                              f"differs from that of {where.replace('header of ', '')}, and every part of a "
                              "multi-part file shares it")


def _check_version(data) -> int:
    """The flags of the version field ("Version Field"), checked."""
    if len(data) < 8:
        raise _Damage(f"the file ends after {len(data)} bytes, inside the version field (bytes 4 to 7)")
    version = struct.unpack_from("<I", data, 4)[0]
    flags = version & ~0xFF
    if version & 0xFF != _EXR_VERSION:
        raise _Damage(f"version field damaged at byte 4: format version {version & 0xFF} (expected {_EXR_VERSION})")
    unknown = flags & ~(_TILED_FLAG | _LONG_NAMES_FLAG | _NON_IMAGE_FLAG | _MULTI_PART_FLAG)
    if unknown:
        raise _Damage(f"version field damaged at byte 5: unknown flag bits 0x{unknown:x} (known: 0x200 tiled, 0x400 "
                      "long names, 0x800 deep data, 0x1000 multi-part)")
    if flags & _TILED_FLAG and flags & (_NON_IMAGE_FLAG | _MULTI_PART_FLAG):
        raise _Damage("version field damaged at byte 5: the single-part tiled flag 0x200 is set with the deep-data or "
                      "multi-part flag")
    return flags


def _check_layout(data) -> None:
    """Raise ``_Damage`` for the first thing in the version field, the headers or the offset tables of ``data`` (an
    EXR file whose magic number is right) that the file layout says cannot be."""
    flags = _check_version(data)
    name_max = _LONG_NAME_MAX if flags & _LONG_NAMES_FLAG else _NAME_MAX
    multi, deep = bool(flags & _MULTI_PART_FLAG), bool(flags & _NON_IMAGE_FLAG)
    at, counts, n, first = 8, [], len(data), {}
    while True:      # one header, or a multi-part file's headers up to the NUL byte that ends them
        where = f"header of part {len(counts)}" if multi else "header"
        if multi and counts:
            if at >= n:
                raise _Damage(f"the file ends after {n} bytes, after the headers of {len(counts)} parts, before the "
                              "NUL byte that ends them")
            if data[at] == 0:
                at += 1
                break
        attrs, end = _header_attributes(data, at, name_max, where)
        kind = _string_value(data, attrs, "type")
        if not multi and kind is not None and (kind in ("tiledimage", "deeptile")) != bool(flags & _TILED_FLAG):
            raise _Damage(f"{where} damaged at byte {attrs['type'][1]}: attribute 'type' says {kind!r}, but the "
                          f"version field's tiled flag 0x200 is {'' if flags & _TILED_FLAG else 'not '}set")
        tiled = kind in ("tiledimage", "deeptile") if multi or kind else bool(flags & _TILED_FLAG)
        _check_required(attrs, at, end, where, _REQUIRED_ATTRIBUTES, "every header needs")
        if tiled:
            _check_required(attrs, at, end, where, _TILED_ATTRIBUTES, "a tiled part needs" if multi or kind else
                            "a tiled part needs (the version field's flag 0x200 says the file is tiled)")
        if multi or deep:
            _check_required(attrs, at, end, where, _MULTI_PART_ATTRIBUTES, "every part of a multi-part or deep file "
                            f"needs (the version field's flag 0x{flags & (_MULTI_PART_FLAG | _NON_IMAGE_FLAG):x} says "
                            "the file is one)")
        _check_sampling(data, attrs, name_max, where, tiled)
        first = first or attrs
        _check_shared(data, first, attrs, where)       # nothing to compare in the first (or only) part
        counts.append(_int32(data, attrs["chunkCount"][2]) if "chunkCount" in attrs else None)
        at = end
        if not multi:
            break
    if not (multi or deep):
        _check_chunks(data, at, attrs, tiled, name_max)
    elif None not in counts:
        _check_part_offsets(data, at, counts, multi)


def exr_damage(path) -> str | None:
    """After OpenEXR has refused ``path`` (whose magic number is right): the first damaged part of its version field,
    headers or offset tables that the file layout shows, in words naming the byte, or None where none shows (damage in
    the pixel data, or beyond what is checked).  Only what is checked is read (the file is mapped, not loaded)."""
    path = check_path(path, "exr_damage: path")   # an int was open()'s file descriptor, closed after reading it
    try:
        with open(path, "rb") as fh, mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as data:
            try:
                _check_layout(data)
            except _Damage as found:
                return str(found)
    except (OSError, ValueError):    # unreadable now, or emptied since the magic number was read
        return None
    return None


def first_header_declares(path, name: str, typ: str) -> bool | None:
    """Whether the first header of EXR file ``path`` holds attribute ``name`` of type ``typ``; None where the
    version field or that header is damaged (``exr_damage`` says how) or the file does not read.  OpenEXR gives a
    header without a dataWindow its default, 64 x 64 pixels, instead of refusing it."""
    path = check_path(path, "first_header_declares: path")   # an int: a file descriptor, read and closed
    try:
        with open(path, "rb") as fh, mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as data:
            try:
                flags = _check_version(data)
                attrs, _ = _header_attributes(data, 8, _LONG_NAME_MAX if flags & _LONG_NAMES_FLAG else _NAME_MAX,
                                              "header")
            except (_Damage, struct.error):
                return None
    except (OSError, ValueError):
        return None
    return attrs.get(name, (None,))[0] == typ
