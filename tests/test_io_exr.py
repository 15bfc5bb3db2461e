"""EXR in and out, PNG previews (warpbw.io.exr).

Truth: the arrays written (bit-exact round trips), the sRGB formula of IEC 61966-2-1 written out
here, the published ends of matplotlib's viridis map (#440154, #fde725), and the real light probes.
"""
from __future__ import annotations

import math
import re
import shutil
import struct

import numpy as np
import pytest
from conftest import SHARED_DATA, exr_claiming_size, shared_file
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from warpbw.errors import WarpbwError
from warpbw.io.exr import (
    EXR_MAGIC,
    REC709_CHROMATICITIES,
    colour_conversion,
    exr_size,
    linear_to_srgb,
    read_exr,
    read_rgb,
    rec709_transform,
    rgb_of,
    write_exr,
    write_false_colour_png,
    write_png,
)


def srgb_reference(x: float) -> float:
    """IEC 61966-2-1 encoding, scalar, written independently."""
    return 12.92 * x if x <= 0.0031308 else 1.055 * x ** (1 / 2.4) - 0.055


def awkward_floats(rng, shape):
    v = rng.standard_normal(shape).astype(np.float32) * 10
    flat = v.reshape(-1)
    flat[:6] = [0.0, -0.0, 3.0e38, 1.0e-40, -1.0e-30, 65504.0 * 2]  # huge, subnormal, beyond half range
    return v


def test_round_trip_rgba_exact(tmp_path):
    rng = np.random.default_rng(0)
    px = awkward_floats(rng, (37, 53, 4))
    path = write_exr(tmp_path / "rgba.exr", px)
    img = read_exr(path)
    assert img.channels == ["R", "G", "B", "A"]
    assert img.pixels.dtype == np.float32 and img.pixels.shape == (37, 53, 4)
    assert np.array_equal(img.pixels.view(np.uint32), px.view(np.uint32))  # bit-exact, signed zero too
    assert img.path == str(path)
    assert np.array_equal(read_rgb(path), px[..., :3])


def test_round_trip_single_channel_y(tmp_path):
    rng = np.random.default_rng(1)
    px = awkward_floats(rng, (16, 9))
    write_exr(tmp_path / "y.exr", px)
    img = read_exr(tmp_path / "y.exr")
    assert img.channels == ["Y"] and img.pixels.shape == (16, 9, 1)
    assert np.array_equal(img.pixels[..., 0], px)
    rgb = read_rgb(tmp_path / "y.exr")
    assert rgb.shape == (16, 9, 3) and all(np.array_equal(rgb[..., c], px) for c in range(3))



def test_a_lone_channel_other_than_y_is_read_as_grey_with_a_warning(tmp_path):
    """A depth-only EXR (channel Z) was read as a grey light probe without a word (scene fuzzing, session 63): it
    still reads as grey, but says so in one warning naming the file and the channel; a lone Y says nothing."""
    import warnings

    px = np.random.default_rng(4).random((4, 8), dtype=np.float32)
    write_exr(tmp_path / "z.exr", px[..., None], channels=["Z"])
    with pytest.warns(RuntimeWarning, match=r"z\.exr: its one channel 'Z' is read as grey radiance") as record:
        rgb = read_rgb(tmp_path / "z.exr")
    assert len(record) == 1 and all(np.array_equal(rgb[..., c], px) for c in range(3))
    write_exr(tmp_path / "y.exr", px)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_rgb(tmp_path / "y.exr")


def test_a_luminance_chroma_image_is_refused_not_read_as_its_grey_luminance(tmp_path):
    """OpenEXR's luminance / chroma images store Y, RY = (R - Y) / Y and BY = (B - Y) / Y (ImfRgbaYca); read as a
    lone Y, a probe of Y 1, RY 0.5, BY -0.5 (R 1.5, B 0.5) was white without a word.  Refused, by its channels, at
    full resolution as when OpenEXR subsamples the chroma (its own writer does, 2 x 2).  Written by OpenEXR."""
    import OpenEXR

    y = np.ones((4, 8), np.float32)
    OpenEXR.File({}, {"Y": y, "RY": 0.5 * y, "BY": -0.5 * y}).write(str(tmp_path / "yc.exr"))
    with pytest.raises(WarpbwError, match=r"yc\.exr: channels \['Y', 'BY', 'RY'\] are luminance and chroma"):
        read_rgb(tmp_path / "yc.exr")


def test_notes_round_trip_through_the_header_and_a_file_without_them_has_none(tmp_path):
    """write_exr's notes (the bench's chunk digest) come back from read_exr as written, str for str; a file written
    without notes, or by another writer (OpenEXR's own, with only its standard attributes), reads back with none."""
    import OpenEXR

    px = np.ones((3, 4, 3), np.float32)
    notes = {"rgb_blake2b": "0f" * 16, "a b": "é ß, 1"}
    write_exr(tmp_path / "n.exr", px, notes=notes)
    assert read_exr(tmp_path / "n.exr").notes == notes
    write_exr(tmp_path / "plain.exr", px)
    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage},
                 {"R": px[..., 0], "G": px[..., 1], "B": px[..., 2]}).write(str(tmp_path / "other.exr"))
    assert read_exr(tmp_path / "plain.exr").notes == {} == read_exr(tmp_path / "other.exr").notes

def test_custom_channel_names_and_order_kept(tmp_path):
    rng = np.random.default_rng(2)
    px = rng.random((8, 8, 3), dtype=np.float32)
    write_exr(tmp_path / "aov.exr", px, channels=["depth", "Z", "alpha.mask"])
    img = read_exr(tmp_path / "aov.exr")
    assert img.channels == ["depth", "Z", "alpha.mask"]
    assert np.array_equal(img.pixels, px)
    with pytest.raises(WarpbwError, match="aov.exr.*no colour"):
        read_rgb(tmp_path / "aov.exr")


def test_rgb_order_of_foreign_file(tmp_path):
    """A file written without warpbw's order attribute (EXR sorts channels B, G, R) still reads as R, G, B."""
    import OpenEXR

    r, g, b = (np.full((4, 4), v, np.float32) for v in (1.0, 2.0, 3.0))
    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION}, {"R": r, "G": g, "B": b}).write(str(tmp_path / "f.exr"))
    img = read_exr(tmp_path / "f.exr")
    assert img.channels == ["R", "G", "B"]
    assert img.pixels[0, 0].tolist() == [1.0, 2.0, 3.0]


def test_half_channels_read_as_float32(tmp_path):
    import OpenEXR

    y = np.array([[0.5, 1.0], [2.0, 65504.0]], dtype=np.float16)
    OpenEXR.File({}, {"Y": y}).write(str(tmp_path / "half.exr"))
    img = read_exr(tmp_path / "half.exr")
    assert img.pixels.dtype == np.float32 and img.pixels[..., 0].tolist() == [[0.5, 1.0], [2.0, 65504.0]]


def test_png_renamed_exr_is_refused(tmp_path):
    png = tmp_path / "pic.png"
    Image.fromarray(np.zeros((4, 4, 3), np.uint8)).save(png)
    fake = tmp_path / "pic.exr"
    shutil.copy(png, fake)
    with pytest.raises(WarpbwError) as ei:
        read_exr(fake)
    msg = str(ei.value)
    assert str(fake) in msg and "0x762f3101" in msg and "PNG" in msg and "\n" not in msg


def test_missing_and_truncated_files(tmp_path):
    with pytest.raises(WarpbwError, match="nothere.exr.*not found"):
        read_exr(tmp_path / "nothere.exr")
    write_exr(tmp_path / "ok.exr", np.ones((64, 64, 3), np.float32))
    (tmp_path / "cut.exr").write_bytes((tmp_path / "ok.exr").read_bytes()[:300])
    with pytest.raises(WarpbwError, match="cut.exr"):
        read_exr(tmp_path / "cut.exr")
    (tmp_path / "tiny.exr").write_bytes(b"\x76\x2f")
    with pytest.raises(WarpbwError, match="tiny.exr"):
        read_exr(tmp_path / "tiny.exr")


def test_exr_size_reads_the_header_alone(tmp_path):
    """exr_size gives the data window's (width, height) without decoding a pixel: a file of a few hundred bytes
    that claims 20000 x 20000 texels is sized, while a full read of it fails."""
    write_exr(tmp_path / "wide.exr", np.zeros((3, 5, 1), np.float32), ["Y"])
    assert exr_size(tmp_path / "wide.exr") == (5, 3)
    big = exr_claiming_size(tmp_path / "big.exr", 20000, 20000)
    assert big.stat().st_size < 1000 and exr_size(big) == (20000, 20000)
    with pytest.raises(WarpbwError, match="big.exr: unreadable OpenEXR file"):
        read_exr(big)
    with pytest.raises(WarpbwError, match="nothere.exr.*not found"):
        exr_size(tmp_path / "nothere.exr")
    (tmp_path / "tiny.exr").write_bytes(b"\x76\x2f\x31\x01\x02")
    with pytest.raises(WarpbwError, match="tiny.exr: unreadable OpenEXR file"):
        exr_size(tmp_path / "tiny.exr")


# ---- damaged headers: the one line names the damaged part and its byte (OpenEXR file layout), not OpenEXR's words
# ("file has 0 parts", "Unable to open 'x' for read", "'utf-8' codec can't decode ...").  Images of 48 x 40: not the
# 64 x 64 that OpenEXR assumes for a header without a dataWindow, which would read as if whole.

def _valid_exr(tmp_path) -> bytes:
    return write_exr(tmp_path / "ok.exr", np.random.default_rng(5).random((40, 48, 3)).astype(np.float32)).read_bytes()


def _attribute(data: bytes, name: str, typ: str) -> tuple[int, int, int]:
    """(first byte, byte of the size, first byte of the value) of attribute ``name`` of type ``typ`` (OpenEXR file
    layout, "Attribute Layout": name, NUL, type name, NUL, int32 size, value)."""
    start = data.index(name.encode() + b"\0" + typ.encode() + b"\0")
    size_at = start + len(name) + len(typ) + 2
    return start, size_at, size_at + 4


def _header_end(data: bytes) -> int:
    """The byte after the NUL that ends the header of a write_exr file (its last attribute is warpbw_channels)."""
    _, size_at, value_at = _attribute(data, "warpbw_channels", "string")
    end = value_at + struct.unpack_from("<i", data, size_at)[0]
    assert data[end] == 0
    return end + 1


def _refusal(path, read=read_exr) -> str:
    with pytest.raises(WarpbwError) as ei:
        read(path)
    msg = str(ei.value)
    assert msg.startswith(f"{path}: unreadable OpenEXR file, truncated or corrupt: ") and "\n" not in msg, msg
    return msg


def test_a_header_cut_short_names_the_attribute_it_ends_in(tmp_path):
    data = _valid_exr(tmp_path)
    start, _, value_at = _attribute(data, "dataWindow", "box2i")
    (tmp_path / "cut.exr").write_bytes(data[:value_at + 5])
    for read in (read_exr, exr_size):
        assert _refusal(tmp_path / "cut.exr", read).endswith(
            f"the file ends after {value_at + 5} bytes, inside attribute 'dataWindow' (box2i, from byte {start}) in "
            f"the header: its value would take bytes {value_at} to {value_at + 15}")


def test_an_attribute_of_the_wrong_size_or_type_is_named_with_its_byte(tmp_path):
    data = _valid_exr(tmp_path)
    start, size_at, _ = _attribute(data, "dataWindow", "box2i")
    bad = bytearray(data)
    struct.pack_into("<i", bad, size_at, 9)
    (tmp_path / "size.exr").write_bytes(bad)
    with pytest.raises(WarpbwError, match=rf"size\.exr: unreadable OpenEXR file, truncated or corrupt: header damaged "
                                          rf"at byte {size_at}: attribute 'dataWindow' has type 'box2i' but size 9 "
                                          r"\(expected 16\)$"):
        read_exr(tmp_path / "size.exr")
    bad = bytearray(data)
    bad[start + len("dataWindow") + 1] = ord("B")
    (tmp_path / "type.exr").write_bytes(bad)
    with pytest.raises(WarpbwError, match=rf"type\.exr: .*: header damaged at byte {start}: attribute 'dataWindow' has "
                                          r"type 'Box2i' \(expected 'box2i'\)$"):
        read_exr(tmp_path / "type.exr")


def test_a_missing_required_attribute_is_named(tmp_path):
    """A header rewritten without 'channels' (the offset table moved with it), and one whose 'channels' lost a letter
    to a flipped byte: the second says which name it found instead."""
    data = _valid_exr(tmp_path)
    start, size_at, value_at = _attribute(data, "channels", "chlist")
    end = value_at + struct.unpack_from("<i", data, size_at)[0]
    cut = end - start
    table = _header_end(data)
    offsets = struct.unpack_from("<3Q", data, table)       # 40 rows, 16 a chunk (ZIP): 3 chunks
    rest = bytearray(data[table:])
    struct.pack_into("<3Q", rest, 0, *(o - cut for o in offsets))
    (tmp_path / "drop.exr").write_bytes(data[:start] + data[end:table] + bytes(rest))
    msg = _refusal(tmp_path / "drop.exr")
    assert msg.endswith(f"header (bytes 8 to {table - cut - 1}) damaged: it has no attribute 'channels' (chlist), "
                        "which every header needs"), msg
    bad = bytearray(data)
    bad[start + 2] = ord("x")
    (tmp_path / "name.exr").write_bytes(bad)
    assert _refusal(tmp_path / "name.exr", exr_size).endswith(
        "it has no attribute 'channels' (chlist), which every header needs; it has 'chxnnels' at byte 8: a damaged "
        "name?")


def test_bad_values_of_known_attributes_are_named(tmp_path):
    data = _valid_exr(tmp_path)
    _, _, window = _attribute(data, "dataWindow", "box2i")
    _, _, channels = _attribute(data, "channels", "chlist")
    cases = {
        "reversed": (window, struct.pack("<4i", 10, 0, 0, 39),
                     rf"byte {window}: attribute 'dataWindow' \(box2i\): reversed, from \(10, 0\) to \(0, 39\)"),
        "pixtype": (channels + 2, struct.pack("<i", 7),
                    rf"byte {channels + 2}: attribute 'channels' \(chlist\): channel 'B' has pixel type 7 "
                    r"\(expected 0 UINT, 1 HALF or 2 FLOAT\)"),
        "sampling": (channels + 10, struct.pack("<i", 7),
                     rf"byte {channels + 10}: attribute 'channels' \(chlist\): channel 'B' has x sampling 7, but "
                     r"the dataWindow's x starts at 0 and spans 48 pixels"),
        "version": (4, struct.pack("<I", 99), r"version field damaged at byte 4: format version 99 \(expected 2\)"),
    }
    for name, (at, new, says) in cases.items():
        bad = bytearray(data)
        bad[at:at + len(new)] = new
        (tmp_path / f"{name}.exr").write_bytes(bad)
        for read in (read_exr, exr_size):
            with pytest.raises(WarpbwError, match=rf"{name}\.exr: unreadable OpenEXR file, truncated or corrupt: .*{says}"):
                read(tmp_path / f"{name}.exr")


def test_text_that_is_not_utf8_is_named_not_left_to_the_codec(tmp_path):
    """The Python binding decodes attribute names and strings as UTF-8: a flipped byte there came out as "'utf-8'
    codec can't decode byte 0xff in position 0"."""
    data = _valid_exr(tmp_path)
    start, _, _ = _attribute(data, "compression", "compression")
    _, _, order = _attribute(data, "warpbw_channels", "string")
    for name, at, says in (("name", start, rf"header damaged at byte {start}: the name of the attribute after "
                                           rf"'channels' \(from byte {start}\) is not UTF-8 text \(byte 0xff\)$"),
                           ("string", order, rf"header damaged at byte {order}: attribute 'warpbw_channels' "
                                             r"\(string\): not UTF-8 text \(byte 0xff\)$")):
        bad = bytearray(data)
        bad[at] = 0xFF
        (tmp_path / f"{name}.exr").write_bytes(bad)
        for read in (read_exr, exr_size):
            msg = _refusal(tmp_path / f"{name}.exr", read)
            assert re.search(says, msg) and "codec" not in msg, msg


def test_a_file_cut_in_its_pixels_names_the_chunk_the_offset_table_points_past_the_end(tmp_path):
    data = _valid_exr(tmp_path)
    table = _header_end(data)
    offsets = struct.unpack_from("<3Q", data, table)
    (tmp_path / "before.exr").write_bytes(data[:offsets[2]])
    assert _refusal(tmp_path / "before.exr").endswith(
        f"the file ends after {offsets[2]} bytes, before chunk 3 of 3, which the offset table (entry at byte "
        f"{table + 16}) puts at byte {offsets[2]}")
    (tmp_path / "inside.exr").write_bytes(data[:offsets[1] + 100])
    size = struct.unpack_from("<i", data, offsets[1] + 4)[0]
    assert _refusal(tmp_path / "inside.exr").endswith(
        f"the file ends after {offsets[1] + 100} bytes, inside chunk 2 of 3 (from byte {offsets[1]}, with {size} "
        "bytes of data)")


def test_a_compression_that_makes_more_chunks_than_the_table_holds_is_named(tmp_path):
    """ZIP (16 scan lines a chunk) rewritten as NONE (1): 40 chunks, whose offsets would run into the pixel data; the
    message names the table entry and the header attributes it follows from."""
    data = _valid_exr(tmp_path)
    _, _, method = _attribute(data, "compression", "compression")
    bad = bytearray(data)
    bad[method] = 0
    (tmp_path / "none.exr").write_bytes(bad)
    table = _header_end(data)
    first = struct.unpack_from("<Q", data, table)[0]
    assert _refusal(tmp_path / "none.exr").endswith(
        f"offset table damaged at byte {table}: it puts chunk 1 of 40 at byte {first}, inside the header and offset "
        f"table (bytes 0 to {table + 8 * 40 - 1}; or the header's dataWindow or compression, which make 40 chunks, is "
        "damaged)")


def test_a_chunk_larger_than_its_pixels_blames_the_chunk_or_the_window(tmp_path):
    """A dataWindow shrunk to one row (the table still has its first entry): the first chunk holds 16 rows' data."""
    data = _valid_exr(tmp_path)
    _, _, window = _attribute(data, "dataWindow", "box2i")
    bad = bytearray(data)
    struct.pack_into("<4i", bad, window, 0, 0, 47, 0)
    (tmp_path / "row.exr").write_bytes(bad)
    first = struct.unpack_from("<Q", data, _header_end(data))[0]
    size = struct.unpack_from("<i", data, first + 4)[0]
    assert _refusal(tmp_path / "row.exr").endswith(
        f"chunk 1 of 1 damaged at byte {first + 4}: its data size is {size} bytes, more than the {48 * 12} its pixels "
        "take unpacked (or the header's dataWindow or channels are damaged)")


def test_parts_of_a_multi_part_file_that_disagree_on_a_shared_attribute_are_named(tmp_path):
    import OpenEXR

    px = np.ones((8, 6), np.float32)
    OpenEXR.File([OpenEXR.Part({}, {"Y": px}, "left"), OpenEXR.Part({}, {"Z": px}, "right")]).write(
        str(tmp_path / "two.exr"))
    data = (tmp_path / "two.exr").read_bytes()
    key = b"displayWindow\0box2i\0\x10\0\0\0"
    first = data.index(key) + len(key)
    second = data.index(key, first) + len(key)
    bad = bytearray(data)
    struct.pack_into("<4i", bad, second, 0, 0, 99, 99)
    (tmp_path / "two.exr").write_bytes(bad)
    for read in (read_exr, exr_size):
        assert _refusal(tmp_path / "two.exr", read).endswith(
            f"part headers damaged at byte {first} or {second}: attribute 'displayWindow' (box2i) of part 0 differs "
            "from that of part 1, and every part of a multi-part file shares it")


@settings(max_examples=80, deadline=None)
@given(st.data())
def test_every_cut_inside_the_header_or_table_is_refused_saying_where_the_file_ends(tmp_path_factory, draw):
    """A file cut anywhere from its version field to the end of its offset table: read_exr and exr_size (up to the
    header's end, beyond which it needs no more) refuse it with a WarpbwError that names the file and where it ends,
    never another exception or OpenEXR's words."""
    tmp = tmp_path_factory.mktemp("cut")
    data = _valid_exr(tmp)
    header_end = _header_end(data)
    cut = draw.draw(st.integers(4, header_end + 3 * 8 - 1), label="cut")
    (tmp / "cut.exr").write_bytes(data[:cut])
    for read in (read_exr, exr_size) if cut < header_end else (read_exr,):
        msg = _refusal(tmp / "cut.exr", read)
        assert f"truncated or corrupt: the file ends after {cut} bytes, inside " in msg, msg


def _subsampled_exr(path):
    """An uncompressed scan-line EXR of 48 x 40 pixels from y = -4 with Y full and BY, RY sampled 2 x 2, written byte
    by byte (OpenEXR file layout: channels sorted by name; a chunk a scan line, holding the samples of the channels
    sampled on it), which OpenEXR's Python binding cannot write."""
    def attr(name, typ, value):
        return name.encode() + b"\0" + typ.encode() + b"\0" + struct.pack("<i", len(value)) + value

    chans, box = (("BY", 2), ("RY", 2), ("Y", 1)), struct.pack("<4i", 0, -4, 47, 35)
    chlist = b"".join(n.encode() + b"\0" + struct.pack("<iB3xii", 2, 0, s, s) for n, s in chans) + b"\0"
    head = EXR_MAGIC + struct.pack("<I", 2) + b"".join((
        attr("channels", "chlist", chlist), attr("compression", "compression", b"\0"), attr("dataWindow", "box2i", box),
        attr("displayWindow", "box2i", box), attr("lineOrder", "lineOrder", b"\0"),
        attr("pixelAspectRatio", "float", struct.pack("<f", 1)),
        attr("screenWindowCenter", "v2f", struct.pack("<2f", 0, 0)),
        attr("screenWindowWidth", "float", struct.pack("<f", 1)), b"\0"))
    rng = np.random.default_rng(7)
    chunks = [struct.pack("<i", y) for y in range(-4, 36)]
    for i, y in enumerate(range(-4, 36)):
        line = b"".join(rng.random(48 // s, dtype=np.float32).tobytes() for _, s in chans if y % s == 0)
        chunks[i] += struct.pack("<i", len(line)) + line
    starts = len(head) + 8 * 40 + np.cumsum([0] + [len(c) for c in chunks[:-1]])
    path.write_bytes(head + struct.pack("<40Q", *starts) + b"".join(chunks))
    return path


def _valid_files(tmp_path) -> list:
    """EXR files of many kinds that OpenEXR reads: write_exr's; OpenEXR's own in every compression it writes, in both
    line orders, with half and uint channels; tiled, offset, multi-part, subsampled and long-named ones."""
    import OpenEXR

    px = np.random.default_rng(6).random((37, 53, 3), dtype=np.float32)
    files = [write_exr(tmp_path / "w.exr", px, notes={"digest": "0f" * 16, "é": "ß"})]
    chans = {"R": px[..., 0], "G": px[..., 1].astype(np.float16), "B": (px[..., 2] * 100).astype(np.uint32)}
    for method in range(OpenEXR.NUM_COMPRESSION_METHODS):
        for order in (OpenEXR.INCREASING_Y, OpenEXR.DECREASING_Y):
            files.append(tmp_path / f"c{method}_{int(order)}.exr")
            OpenEXR.File({"compression": OpenEXR.Compression(method), "lineOrder": order}, chans).write(str(files[-1]))
    tiles = OpenEXR.TileDescription()
    tiles.xSize, tiles.ySize, tiles.mode, tiles.roundingMode = 8, 16, OpenEXR.ONE_LEVEL, OpenEXR.ROUND_DOWN
    for method in (OpenEXR.NO_COMPRESSION, OpenEXR.ZIP_COMPRESSION, OpenEXR.PIZ_COMPRESSION):
        files.append(tmp_path / f"tiled{int(method)}.exr")
        OpenEXR.File({"compression": method, "type": OpenEXR.tiledimage, "tiles": tiles}, chans).write(str(files[-1]))
    files.append(tmp_path / "offset.exr")
    OpenEXR.File({"dataWindow": (np.array([-5, 7], np.int32), np.array([47, 43], np.int32))},
                 {"Y": px[..., 0]}).write(str(files[-1]))
    files.append(tmp_path / "multi.exr")
    OpenEXR.File([OpenEXR.Part({}, {"Y": px[..., 0]}, "left"),
                  OpenEXR.Part({"compression": OpenEXR.PIZ_COMPRESSION}, {"Z": px[..., 1]}, "right")]).write(str(files[-1]))
    files.append(_subsampled_exr(tmp_path / "subsampled.exr"))
    files.append(tmp_path / "long.exr")
    OpenEXR.File({"an_attribute_name_longer_than_31_bytes": "x"},
                 {"a_channel_name_longer_than_31_bytes": px[..., 0]}).write(str(files[-1]))
    return files


def _multilevel_exr(path, px, mode, round_up=False):
    """An uncompressed tiled EXR of ``px`` (H, W, 3) at level 0, with MIPMAP_LEVELS (``mode`` 1) or RIPMAP_LEVELS
    (2) rounded down, every coarser level (lx, ly) filled with lx + 10 ly + 1 (not what the level holds), written byte
    by byte (OpenEXR file layout: tiledesc's mode byte; the offset table and chunks level by level, x fastest, tile
    rows within a level; a chunk's tile and level coordinates), since OpenEXR's Python binding leaves every level
    past the first unwritten (its offsets 0, a file OpenEXR itself then refuses)."""
    def attr(name, typ, value):
        return name.encode() + b"\0" + typ.encode() + b"\0" + struct.pack("<i", len(value)) + value

    h, w, _ = px.shape
    tile, box = 16, struct.pack("<4i", 0, 0, w - 1, h - 1)
    chlist = b"".join(n.encode() + b"\0" + struct.pack("<iB3xii", 2, 0, 1, 1) for n in "BGR") + b"\0"
    head = EXR_MAGIC + struct.pack("<I", 2 | 0x200) + b"".join((
        attr("channels", "chlist", chlist), attr("compression", "compression", b"\0"), attr("dataWindow", "box2i", box),
        attr("displayWindow", "box2i", box), attr("lineOrder", "lineOrder", b"\0"),
        attr("pixelAspectRatio", "float", struct.pack("<f", 1)),
        attr("screenWindowCenter", "v2f", struct.pack("<2f", 0, 0)),
        attr("screenWindowWidth", "float", struct.pack("<f", 1)),
        attr("tiles", "tiledesc", struct.pack("<IIB", tile, tile, mode | (0x10 if round_up else 0))), b"\0"))
    nx, ny = w.bit_length(), h.bit_length()                     # floor(log2(size)) + 1 levels per axis
    if round_up:                                                # ceil(log2(size)) + 1, sizes rounded up
        nx, ny = (w - 1).bit_length() + 1, (h - 1).bit_length() + 1
    if mode == 1:
        levels = [(i, i) for i in range(max(nx, ny))]
    else:
        levels = [(lx, ly) for ly in range(ny) for lx in range(nx)]
    chunks = []
    for lx, ly in levels:
        lw, lh = (max(1, -(-w >> lx)), max(1, -(-h >> ly))) if round_up else (max(1, w >> lx), max(1, h >> ly))
        img = px[..., ::-1] if (lx, ly) == (0, 0) else np.full((lh, lw, 3), lx + 10 * ly + 1, np.float32)
        for ty in range(-(-lh // tile)):
            for tx in range(-(-lw // tile)):
                rows = img[ty * tile:(ty + 1) * tile, tx * tile:(tx + 1) * tile]
                data = b"".join(np.ascontiguousarray(row.T).astype("<f4").tobytes() for row in rows)
                chunks.append(struct.pack("<5i", tx, ty, lx, ly, len(data)) + data)
    starts = len(head) + 8 * len(chunks) + np.cumsum([0] + [len(c) for c in chunks[:-1]])
    path.write_bytes(head + struct.pack(f"<{len(chunks)}Q", *starts) + b"".join(chunks))
    return path


@pytest.mark.parametrize("mode", [1, 2], ids=["mipmap", "ripmap"])
def test_a_mipmapped_or_ripmapped_tiled_exr_reads_its_full_resolution_level(tmp_path, mode):
    """A probe or map saved with MIP or RIP levels (exrmaketiled's, a texture pipeline's) reads as its level 0: the
    pixels written there bit for bit, not a coarser level's constants; its size is level 0's, and the layout checks
    find nothing wrong in it.  Cut inside a coarser level's chunk, it is refused in one line naming that chunk."""
    from warpbw.io.exr_layout import exr_damage

    px = np.random.default_rng(8).random((37, 53, 3), dtype=np.float32)
    path = _multilevel_exr(tmp_path / f"levels{mode}.exr", px, mode)
    assert np.array_equal(read_rgb(path), px)
    assert exr_size(path) == (53, 37)
    assert exr_damage(path) is None
    data = path.read_bytes()
    (tmp_path / "cut.exr").write_bytes(data[:-100])
    msg = _refusal(tmp_path / "cut.exr")
    assert "truncated or corrupt: the file ends after" in msg and "inside chunk" in msg, msg


def test_the_diagnosis_finds_nothing_wrong_in_files_openexr_reads(tmp_path):
    """The layout checks run only once OpenEXR has refused a file; run on files it reads, they must find nothing, or
    a message could blame a part that is whole."""
    from warpbw.io.exr_layout import exr_damage, first_header_declares

    import OpenEXR

    files = _valid_files(tmp_path)
    assert len(files) > 30
    for path in files:
        OpenEXR.File(str(path), separate_channels=True).channels()     # read_exr refuses the subsampled one
        assert exr_damage(path) is None, path
        assert first_header_declares(path, "dataWindow", "box2i") is True, path
        assert first_header_declares(path, "dataWindow", "box2f") is False, path


@pytest.mark.parametrize("edit", [(b"dataWindow\0", b"dataWindoX\0"), (b"dataWindow\0box2i", b"dataWindow\0box2f")])
def test_exr_size_refuses_a_header_without_its_data_window_instead_of_reading_64_by_64(tmp_path, edit):
    """OpenEXR gives a header whose dataWindow is missing (a damaged name) or of another type its default, 64 x 64
    pixels: exr_size (warpbw info's probe memory, the probe's size checks) returned that without a word, while
    read_exr refused the file (session 64's EXR audit)."""
    path = write_exr(tmp_path / "p.exr", np.ones((20, 30, 3), np.float32))
    assert exr_size(path) == (30, 20)
    data = path.read_bytes()
    assert data.count(edit[0]) == 1
    path.write_bytes(data.replace(*edit))
    with pytest.raises(WarpbwError, match=r"p\.exr: unreadable OpenEXR file, truncated or corrupt: header .*damaged.*"
                                          r"'dataWindow'"):
        exr_size(path)


@pytest.mark.parametrize("edit", [(b"displayWindow\0", b"displayWindoX\0"),
                                  (b"displayWindow\0box2i", b"displayWindow\0box2f")])
def test_a_header_without_its_display_window_is_refused_not_framed_in_64_by_64(tmp_path, edit):
    """OpenEXR gives a header without a displayWindow (a damaged name, or another type) the default 64 x 64 frame
    and reads the file; the probe and compare place the pixels in that frame (``in_display_window``), so a 30 x 20
    probe became 64 x 64.  Refused, naming the attribute, by read_exr and exr_size alike."""
    path = write_exr(tmp_path / "p.exr", np.ones((20, 30, 3), np.float32))
    data = path.read_bytes()
    assert data.count(edit[0]) == 1
    path.write_bytes(data.replace(*edit))
    for read in (read_exr, read_rgb, lambda p: exr_size(p, window="display")):
        with pytest.raises(WarpbwError, match=r"p\.exr: unreadable OpenEXR file, truncated or corrupt: header .*damaged"
                                              r".*'displayWindow'"):
            read(path)


def test_the_diagnosis_finds_nothing_wrong_in_the_real_probes():
    from warpbw.io.exr_layout import exr_damage

    probes = sorted(SHARED_DATA.glob("**/*.exr"))
    if not probes:
        pytest.skip(f"real test data {SHARED_DATA} is absent or holds no EXR (clone ../shared beside the repository "
                    "or set $WARPBW_SHARED_DATA)")
    for path in probes:
        read_exr(path)
        assert exr_damage(path) is None, path


def test_write_exr_bad_channel_count(tmp_path):
    """Names that do not give each channel its own name are refused by write_exr's own check, nothing written.
    (Session 80: the test matched the file name alone, which OpenEXR's own refusal of a nameless image, "Invalid
    display window", also gives; and it left out a name short, which wrote the image without its last channel.)"""
    said = r"x\.exr: channel names .* do not match {} channels \(expected that many distinct, non-empty names"
    for pixels, channels in ((np.zeros((4, 4, 2), np.float32), None),       # no default names for 2 channels
                             (np.zeros((4, 4, 3), np.float32), ["R", "R", "B"]),
                             (np.zeros((4, 4, 3), np.float32), ["R", "G"])):
        with pytest.raises(WarpbwError, match=said.format(pixels.shape[2])):
            write_exr(tmp_path / "x.exr", pixels, channels=channels)
        assert not (tmp_path / "x.exr").exists()


def test_linear_to_srgb_formula():
    xs = [0.0, 0.001, 0.0031308, 0.004, 0.05, 0.18, 0.2140411, 0.5, 1.0, 4.0]
    np.testing.assert_allclose(linear_to_srgb(np.array(xs)), [srgb_reference(x) for x in xs], rtol=1e-12, atol=1e-15)
    assert linear_to_srgb(0.2140411) == pytest.approx(0.5, abs=1e-6)  # inverse of 0.5 under sRGB
    assert linear_to_srgb(1.0) == pytest.approx(1.0, abs=1e-12)


def test_write_png_exposure_and_srgb(tmp_path):
    lin = np.array([0.0, 0.0005, 0.002, 0.01, 0.1, 0.25, 0.45, 0.6, np.nan, -1.0, np.inf], dtype=np.float32)
    rgb = np.stack([lin, lin * 0.5, lin * 0.25], -1)[None]  # (1, N, 3)
    for exposure in (0.0, 1.0, -2.0):
        path = write_png(tmp_path / f"e{exposure}.png", rgb, exposure=exposure)
        got = np.asarray(Image.open(path))
        assert got.shape == (1, len(lin), 3) and got.dtype == np.uint8
        scale = 2.0**exposure
        for c, f in enumerate((1.0, 0.5, 0.25)):
            for n, x in enumerate(lin):
                v = float(x) * f * scale
                v = 0.0 if math.isnan(v) else min(max(v, 0.0), 1.0)
                assert got[0, n, c] == round(255 * srgb_reference(v)), (exposure, c, n)
    # one stop brighter = twice the radiance
    a = np.asarray(Image.open(write_png(tmp_path / "a.png", np.full((2, 2, 3), 0.2), exposure=1.0)))
    b = np.asarray(Image.open(write_png(tmp_path / "b.png", np.full((2, 2, 3), 0.4))))
    assert np.array_equal(a, b)


def test_false_colour_png(tmp_path):
    vals = np.tile(np.linspace(0.0, 10.0, 11), (3, 1))
    mask = np.ones_like(vals, bool)
    mask[1, 5] = False
    vals[2, 7] = np.nan
    lo, hi = write_false_colour_png(tmp_path / "fc.png", vals, mask=mask, vmin=2.0, vmax=8.0)
    assert (lo, hi) == (2.0, 8.0)
    img = np.asarray(Image.open(tmp_path / "fc.png"))
    assert img.shape == (3, 11, 3)
    viridis_lo, viridis_hi, viridis_mid = (0x44, 0x01, 0x54), (0xFD, 0xE7, 0x25), (0x21, 0x91, 0x8C)
    assert np.all(np.abs(img[0, 0].astype(int) - viridis_lo) <= 1)  # below vmin -> first colour
    assert np.all(np.abs(img[0, 10].astype(int) - viridis_hi) <= 1)  # above vmax -> last colour
    assert img[1, 5].tolist() == [0, 0, 0] and img[2, 7].tolist() == [0, 0, 0]
    assert np.all(np.abs(img[0, 5].astype(int) - viridis_mid) <= 2)  # 5, halfway from 2 to 8
    # log scale: the default range comes from the positive values
    lo, hi = write_false_colour_png(tmp_path / "log.png", np.array([[0.01, 0.1, 1.0, 0.0]]), log=True)
    assert (lo, hi) == (0.01, 1.0)
    img = np.asarray(Image.open(tmp_path / "log.png")).astype(int)
    assert np.all(np.abs(img[0, 0] - viridis_lo) <= 1) and np.all(np.abs(img[0, 2] - viridis_hi) <= 1)
    # 0.1 lies halfway in log10 between 0.01 and 1 (a linear map would put it at 0.09): viridis(0.5)
    assert np.all(np.abs(img[0, 1] - viridis_mid) <= 2), img[0, 1]
    # each PNG says its own scale, so that the picture can be read without the command's output
    assert Image.open(tmp_path / "log.png").text["Description"] == \
        "viridis colour scale, log10, from 0.01 (dark blue) to 1 (yellow); black: not shown"
    assert "linear, from 2 (dark blue) to 8 (yellow)" in Image.open(tmp_path / "fc.png").text["Description"]
    # a log scale over values none of which is above 0 (b_p under a constant light): said so, not "1 to 1"
    assert write_false_colour_png(tmp_path / "zero.png", np.zeros((2, 3)), log=True) == (0.0, 0.0)
    assert Image.open(tmp_path / "zero.png").text["Description"].startswith(
        "viridis colour scale, log10: no shown value is above 0")
    assert np.all(np.abs(np.asarray(Image.open(tmp_path / "zero.png")).astype(int) - viridis_lo) <= 1)
    # ... and over no shown pixel at all: the command line's log AOVs mask their non-positive values out, so an
    # adaptive frame that sees nothing, or a black one, draws every PNG black; its text once said "dark blue"
    hidden = np.zeros((2, 3), bool)
    assert write_false_colour_png(tmp_path / "none.png", np.zeros((2, 3)), mask=hidden, log=True) == (0.0, 0.0)
    assert not np.asarray(Image.open(tmp_path / "none.png")).any()
    assert Image.open(tmp_path / "none.png").text["Description"] == \
        "viridis colour scale, log10: no value shown; black: not shown"




def test_previews_are_encoded_a_block_of_rows_at_a_time(tmp_path, monkeypatch):
    """The sRGB preview's float64 temporaries of the whole image took 144 bytes per pixel at the peak, a false-colour
    AOV's 80: more than the frame itself (a 2048 x 2048 reference render peaked at 1.19 GB, 0.66 GB with blocks;
    session 79).  Encoded a block of rows at a time, numpy's peak stays near the PNG's 3 bytes per pixel, and the
    pixels are those of the whole image's encoding (numpy's sRGB formula and matplotlib's viridis over it all)."""
    import tracemalloc

    from matplotlib import colormaps

    import warpbw.io.exr as exr

    monkeypatch.setattr(exr, "PREVIEW_BLOCK_PIXELS", 1000, raising=False)  # 3 rows of 256: 86 blocks, one short
    rng = np.random.default_rng(5)
    lin = rng.lognormal(-1.5, 1.5, (256, 256, 3)).astype(np.float32)
    lin[0, :5] = np.array([np.nan, np.inf, -1.0, 0.0, 1.0])[:, None]
    tracemalloc.start()
    try:
        tracemalloc.reset_peak()
        write_png(tmp_path / "p.png", lin, exposure=0.5)
        peak_png = tracemalloc.get_traced_memory()[1]
        tracemalloc.reset_peak()
        lo, hi = write_false_colour_png(tmp_path / "f.png", lin[..., 0], mask=lin[..., 1] < 1.0, log=True)
        peak_fc = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    pixels = 256 * 256
    assert peak_png < 12 * pixels and peak_fc < 32 * pixels, (peak_png / pixels, peak_fc / pixels)
    v = np.clip(np.nan_to_num(lin.astype(np.float64) * 2.0 ** 0.5, nan=0.0, posinf=1.0), 0.0, 1.0)
    srgb = np.where(v <= 0.0031308, 12.92 * v, 1.055 * np.maximum(v, 0.0031308) ** (1 / 2.4) - 0.055)
    assert np.array_equal(np.asarray(Image.open(tmp_path / "p.png")), np.round(srgb * 255).astype(np.uint8))
    shown = (lin[..., 1] < 1.0) & np.isfinite(lin[..., 0]) & (lin[..., 0] > 0)
    assert (lo, hi) == (float(lin[..., 0][shown].min()), float(lin[..., 0][shown].max()))
    t = np.clip((np.log10(np.where(shown, lin[..., 0], lo).astype(np.float64)) - np.log10(lo))
                / (np.log10(hi) - np.log10(lo)), 0.0, 1.0)
    want = np.round(colormaps["viridis"](t)[..., :3] * 255.0).astype(np.uint8)
    shown_any = (lin[..., 1] < 1.0) & np.isfinite(lin[..., 0])   # drawn (a value <= 0 at the bottom colour)
    want[~shown_any] = 0
    assert np.array_equal(np.asarray(Image.open(tmp_path / "f.png")), want)


@pytest.mark.parametrize("shape", [(5, 300), (5, 300, 1)])
def test_a_grey_preview_wider_than_a_block_is_encoded_a_row_at_a_time(tmp_path, monkeypatch, shape):
    """Mutation round 12: a row wider than ``PREVIEW_BLOCK_PIXELS`` is a block of its own (one row at least, never
    none), and a grey image ((H, W) or (H, W, 1)) is the same value in all three channels.  Truth: IEC 61966-2-1's
    sRGB formula (numpy) over the whole image, and viridis over the linear scale of the values shown."""
    from matplotlib import colormaps

    import warpbw.io.exr as exr

    monkeypatch.setattr(exr, "PREVIEW_BLOCK_PIXELS", 100)
    grey = np.linspace(0.0, 1.2, 5 * 300).reshape(5, 300).astype(np.float32)
    write_png(tmp_path / "p.png", grey.reshape(shape))
    v = np.clip(grey.astype(np.float64), 0.0, 1.0)
    srgb = np.where(v <= 0.0031308, 12.92 * v, 1.055 * np.maximum(v, 0.0031308) ** (1 / 2.4) - 0.055)
    want = np.repeat(np.round(srgb * 255).astype(np.uint8)[..., None], 3, axis=-1)
    assert np.array_equal(np.asarray(Image.open(tmp_path / "p.png")), want)
    mask = np.ones((5, 300), bool)
    mask[2] = False
    lo, hi = write_false_colour_png(tmp_path / "f.png", grey, mask=mask)
    assert (lo, hi) == (float(grey[mask].min()), float(grey[mask].max()))
    t = np.clip((grey.astype(np.float64) - lo) / (hi - lo), 0.0, 1.0)
    want = np.round(colormaps["viridis"](t)[..., :3] * 255.0).astype(np.uint8)
    want[~mask] = 0
    assert np.array_equal(np.asarray(Image.open(tmp_path / "f.png")), want)


def test_a_preview_at_the_default_block_size_peaks_at_tens_of_mb_not_the_images_temporaries(tmp_path):
    """Mutation round 12: ``PREVIEW_BLOCK_PIXELS`` keeps a preview's float64 temporaries to "a few tens of MB whatever
    the image's size" (its comment); at 2^30 the whole image was one block.  A 1024 x 640 image (2.5 blocks of 2^18
    pixels) peaks, under tracemalloc, below 110 bytes per pixel (72 here), where the whole image's temporaries took
    144."""
    import tracemalloc

    lin = np.random.default_rng(1).random((640, 1024, 3), dtype=np.float32)
    tracemalloc.start()
    try:
        tracemalloc.reset_peak()
        write_png(tmp_path / "p.png", lin)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 110 * lin.shape[0] * lin.shape[1], peak / (lin.shape[0] * lin.shape[1])


@pytest.mark.parametrize("shape", [(4, 5, 2), (4, 5, 4), (4, 5, 3, 1), (5,)])
def test_write_png_refuses_an_array_that_is_no_image_in_one_line(tmp_path, shape):
    """Mutation round 12: a preview is (H, W), (H, W, 1) or (H, W, 3); two or four channels (an RGBA frame), or
    another number of axes, are refused naming the shape, before any block is encoded (they broke in numpy's
    broadcasting)."""
    with pytest.raises(WarpbwError, match=re.escape(f"cannot write a preview of shape {shape} (expected (H, W, 3))")):
        write_png(tmp_path / "x.png", np.zeros(shape, np.float32))
    assert not (tmp_path / "x.png").exists()


@pytest.mark.parametrize("vmin, vmax, says", [(float("nan"), 1.0, "vmin of the colour scale: expected a finite"),
                                              (0.0, float("inf"), "vmax of the colour scale: expected a finite"),
                                              (8.0, 2.0, "expected vmin <= vmax")])
def test_false_colour_png_refuses_a_colour_scale_it_cannot_draw(tmp_path, vmin, vmax, says):
    """A NaN or reversed range once drew every pixel in viridis' first colour, silently."""
    with pytest.raises(WarpbwError, match=says):
        write_false_colour_png(tmp_path / "fc.png", np.ones((2, 3)), vmin=vmin, vmax=vmax)
    assert not (tmp_path / "fc.png").exists()


def test_false_colour_png_with_one_end_beyond_every_value_draws_a_scale_that_reads_upwards(tmp_path):
    """vmin 5 over values <= 1 returned (5, 1) and the PNG said "from 5 (dark blue) to 1 (yellow)"; on a log scale
    vmin -1 became 2.2e-308, a scale of 300 decades."""
    v = np.array([[0.25, 0.5, 1.0]])
    assert write_false_colour_png(tmp_path / "a.png", v, vmin=5.0) == (5.0, 5.0)
    assert write_false_colour_png(tmp_path / "b.png", v, vmax=0.1) == (0.1, 0.1)
    assert "from 5 (dark blue) to 5 (yellow)" in Image.open(tmp_path / "a.png").text["Description"]
    for opt in ("vmin", "vmax"):
        with pytest.raises(WarpbwError, match=rf"{opt} -1 of a log colour scale: expected a number > 0"):
            write_false_colour_png(tmp_path / "c.png", v, log=True, **{opt: -1.0})
    assert not (tmp_path / "c.png").exists()


def test_real_probe_reads():
    path = shared_file("envmaps/studio.exr")
    img = read_exr(path)
    assert img.channels == ["R", "G", "B"] and img.pixels.shape == (512, 1024, 3)
    rgb = read_rgb(path)
    assert rgb.dtype == np.float32 and np.all(np.isfinite(rgb))
    assert rgb.max() > 10.0 * np.median(rgb)  # high dynamic range survives (not clipped to 1)


# ACES2065-1 (AP0 primaries, the ACES white near D60; SMPTE ST 2065-1) and its matrix to linear Rec. 709 / sRGB with
# Bradford's adaptation as colour-science and the ACES / OCIO configurations publish it (not computed here).
AP0_CHROMATICITIES = (0.7347, 0.2653, 0.0, 1.0, 0.0001, -0.0770, 0.32168, 0.33767)
AP0_TO_REC709 = np.array([[2.52168619, -1.13413099, -0.38755520],
                          [-0.27647991, 1.37271909, -0.09623917],
                          [-0.01537801, -0.15297534, 1.16835335]])


def _exr_with_chromaticities(path, rgb, chromaticities):
    import OpenEXR

    OpenEXR.File({"chromaticities": tuple(chromaticities)},
                 {c: np.ascontiguousarray(rgb[..., i]) for i, c in enumerate("RGB")}).write(str(path))


def test_an_exr_in_aces2065_1_primaries_is_read_in_rec709s_as_published(tmp_path):
    """An EXR declaring ACES2065-1's chromaticities was read as Rec. 709 RGB: its stored (1, 0, 0) is (2.52, -0.28,
    -0.02) in the primaries the renderer computes in.  Truth: the published AP0 -> Rec. 709 (Bradford) matrix; the
    file's white stays white (each row of the matrix sums to 1)."""
    rgb = np.random.default_rng(7).uniform(0.0, 4.0, (3, 5, 3)).astype(np.float32)
    rgb[0, 0] = 1.0
    _exr_with_chromaticities(tmp_path / "aces.exr", rgb, AP0_CHROMATICITIES)
    got = read_rgb(tmp_path / "aces.exr")
    np.testing.assert_allclose(got, rgb.astype(np.float64) @ AP0_TO_REC709.T, rtol=2e-5, atol=2e-5)
    np.testing.assert_allclose(got[0, 0], 1.0, atol=2e-5)   # white in, white out
    # compare reads it alike: rgb_of of the image read
    np.testing.assert_array_equal(rgb_of(read_exr(tmp_path / "aces.exr")), got)


def test_an_exr_in_cie_xyz_is_read_in_rec709s_as_published(tmp_path):
    """CIE XYZ stored as R, G, B under OpenEXR's chromaticities for XYZ (red (1, 0), green (0, 1), blue (0, 0), white
    (1/3, 1/3): ImfChromaticities.h's convention) is converted, not read as Rec. 709 RGB.  Truth: Lindbloom's
    published XYZ -> sRGB matrix times his Bradford adaptation from illuminant E to D65 (his D65 white, (0.95047, 1,
    1.08883), is xy (0.31273, 0.32902) where Rec. 709's is (0.3127, 0.3290): 4e-4 apart)."""
    xyz_to_srgb = np.array([[3.2404542, -1.5371385, -0.4985314], [-0.9692660, 1.8760108, 0.0415560],
                            [0.0556434, -0.2040259, 1.0572252]])
    e_to_d65 = np.array([[0.9531874, -0.0265906, 0.0238731], [-0.0382467, 1.0288406, 0.0094060],
                         [0.0026068, -0.0030332, 1.0892565]])
    xyz = np.random.default_rng(10).uniform(0.0, 2.0, (3, 4, 3)).astype(np.float32)
    xyz[0, 0] = 1.0   # illuminant E's white, X = Y = Z
    _exr_with_chromaticities(tmp_path / "xyz.exr", xyz, (1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0 / 3.0, 1.0 / 3.0))
    got = read_rgb(tmp_path / "xyz.exr")
    np.testing.assert_allclose(got, xyz.astype(np.float64) @ (xyz_to_srgb @ e_to_d65).T, atol=2e-3)
    np.testing.assert_allclose(got[0, 0], 1.0, atol=1e-5)   # the file's white is white


def test_every_luminance_weight_is_rec709s_y_row():
    """RGB is reduced to one number by the bandwidth pass (its chi), the BRDF sampling tables (Y(f) cos) and the
    probe's sampling distribution: each weighs it by Rec. 709's luminance, the Y row of the RGB -> XYZ matrix of
    BT.709's primaries and D65 white, derived here from their xy (0.21264, 0.71517, 0.07219), not another standard's
    (Rec. 601's 0.299, 0.587, 0.114; a channel mean).  The bandwidth pass and the tables take one constant,
    REC709_LUMINANCE; the probe's distribution keeps Mitsuba's rounding of the same row."""
    import warpbw.bandwidth as wb
    import warpbw.envmap as we
    import warpbw.sampling as ws
    from warpbw.io.exr import REC709_LUMINANCE

    xy = np.array([[0.64, 0.33], [0.30, 0.60], [0.15, 0.06]])
    prim = np.stack([xy[:, 0] / xy[:, 1], np.ones(3), (1.0 - xy.sum(axis=1)) / xy[:, 1]])   # columns: XYZ at Y = 1
    white = np.array([0.3127 / 0.3290, 1.0, (1.0 - 0.3127 - 0.3290) / 0.3290])
    y_row = np.linalg.solve(prim, white)   # each primary's Y in the white
    assert ws.LUMINANCE is REC709_LUMINANCE and wb.LUMINANCE is REC709_LUMINANCE
    for weights in (REC709_LUMINANCE, we.LUMINANCE_RGB, tuple(wb._LUM)):
        np.testing.assert_allclose(weights, y_row, atol=1e-4)
        assert sum(weights) == pytest.approx(1.0, abs=1e-6)


def test_an_exr_declaring_rec709_or_its_d50_adaptation_is_read_bit_for_bit(tmp_path):
    """Rec. 709's own chromaticities, and city.exr's (sRGB's primaries adapted to D50, which Bradford's transform
    brings back to the identity within 2e-4), are read as stored: no conversion, no rounding."""
    rgb = np.random.default_rng(8).uniform(0.0, 4.0, (3, 5, 3)).astype(np.float32)
    city = (0.6484473943710327, 0.3308766186237335, 0.3211871385574341, 0.5978942513465881, 0.15590143203735352,
            0.06605630367994308, 0.3457084000110626, 0.35854125022888184)
    for name, c in (("rec709", REC709_CHROMATICITIES), ("city", city)):
        _exr_with_chromaticities(tmp_path / f"{name}.exr", rgb, c)
        assert colour_conversion(tmp_path / f"{name}.exr") is None
        np.testing.assert_array_equal(read_rgb(tmp_path / f"{name}.exr"), rgb)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(0.05, 0.75), min_size=8, max_size=8))
def test_rec709_transform_keeps_the_declared_white_white_or_refuses_by_name(c):
    """For any chromaticities, either the file's white (1, 1, 1) maps to Rec. 709's white (Bradford's adaptation
    takes white to white, whatever the primaries), or they are refused in one line: never a non-finite matrix."""
    try:
        m = rec709_transform(c, "probe.exr")
    except WarpbwError as e:
        assert str(e).startswith("probe.exr: chromaticities") and "\n" not in str(e)
        return
    if m is not None:
        assert np.isfinite(m).all()
        np.testing.assert_allclose(m @ np.ones(3), np.ones(3), atol=1e-6)


@pytest.mark.parametrize("bad", [(0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.0),      # white of y = 0
                                 (0.1, 0.1, 0.2, 0.2, 0.3, 0.3, 0.3127, 0.3290),        # primaries on one line
                                 (0.64, 0.33, 0.30, 0.60, 0.15, 0.06, math.nan, 0.3290),
                                 (0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.30, 0.60)])    # white on green
def test_chromaticities_that_define_no_colour_space_are_refused_by_name(tmp_path, bad):
    """Read as colour they are refused in one line; read as data (a height field's channel, say) they do not
    matter, and the pixels read as stored."""
    rgb = np.random.default_rng(9).uniform(0.0, 1.0, (2, 2, 3)).astype(np.float32)
    _exr_with_chromaticities(tmp_path / "odd.exr", rgb, bad)
    with pytest.raises(WarpbwError, match=r"odd\.exr: chromaticities .* define no RGB colour space"):
        read_rgb(tmp_path / "odd.exr")
    np.testing.assert_array_equal(read_exr(tmp_path / "odd.exr").pixels, rgb)
    assert colour_conversion(tmp_path / "odd.exr") is None   # loading it says what is wrong


def test_a_scene_whose_probe_is_converted_hashes_apart_from_what_earlier_code_rendered(tmp_path, monkeypatch):
    """Ground truths are cached under the scene's content hash, which holds the probe's bytes: a probe that is now
    read converted must not find a ground truth rendered from it unconverted.  The hash of a scene whose probe
    declares ACES2065-1 changes with the conversion (here: with it taken away); one of a Rec. 709 probe does not.
    ``warpbw info`` says which probe is converted."""
    import warpbw.io.exr as exr
    from warpbw.pipeline import scene_summary
    from warpbw.scene import load_scene

    rgb = np.full((4, 8, 3), 0.5, np.float32)
    _exr_with_chromaticities(tmp_path / "aces.exr", rgb, AP0_CHROMATICITIES)
    _exr_with_chromaticities(tmp_path / "srgb.exr", rgb, REC709_CHROMATICITIES)
    hashes = {}
    for probe in ("aces", "srgb"):
        (tmp_path / f"{probe}.toml").write_text(
            f'[camera]\nposition = [0.0, 0.0, 4.0]\nlook_at = [0.0, 0.0, 0.0]\nfov = 30.0\nresolution = [8, 8]\n'
            f'[environment]\nfile = "{probe}.exr"\n[[object]]\nshape = "sphere"\ncenter = [0.0, 0.0, 0.0]\n'
            f'radius = 1.0\nmaterial = "m"\n[material.m]\ntype = "lambert"\nalbedo = [0.5, 0.5, 0.5]\n')
        hashes[probe] = load_scene(tmp_path / f"{probe}.toml").content_hash()
        said = scene_summary(load_scene(tmp_path / f"{probe}.toml"), "reference")["environment"]   # warpbw info
        assert ("converted to Rec. 709" in said) == (probe == "aces"), said
    monkeypatch.setattr(exr, "colour_conversion", lambda path: None)
    assert load_scene(tmp_path / "aces.toml").content_hash() != hashes["aces"]
    assert load_scene(tmp_path / "srgb.toml").content_hash() == hashes["srgb"]


def _offset_table(data: bytes) -> int:
    """The byte at which a single-part EXR's offset table starts: past the header's attributes (name\\0 type\\0
    size value, to the NUL byte that ends them; OpenEXR file layout), read here by hand."""
    at = 8
    while data[at] != 0:
        at = data.index(b"\0", data.index(b"\0", at) + 1) + 1
        at += 4 + struct.unpack_from("<i", data, at)[0]
    return at + 1


@pytest.mark.parametrize("kind", ["edge tile", "subsampled line"])
def test_a_chunk_claiming_more_data_than_its_pixels_unpacked_is_found_at_the_edge_and_with_subsampling(tmp_path,
                                                                                                       kind):
    """Round 11: an uncompressed chunk's data are its pixels unpacked (OpenEXR stores them so), so one whose data size
    says 4 bytes more is damaged: a tile on the right edge of a ONE_LEVEL tiled file (53 columns in tiles of 8: 5 of
    them), a scan line of a file with channels sampled 2 x 2 (on even lines they add their samples).  Truth: the
    chunk's own size field before the edit.  Bounds taken from whole tiles, or from every channel on every line,
    were larger and saw nothing."""
    from warpbw.io.exr_layout import exr_damage

    import OpenEXR

    if kind == "edge tile":
        px = np.random.default_rng(6).random((37, 53, 3), dtype=np.float32)
        tiles = OpenEXR.TileDescription()
        tiles.xSize, tiles.ySize, tiles.mode, tiles.roundingMode = 8, 16, OpenEXR.ONE_LEVEL, OpenEXR.ROUND_DOWN
        path = tmp_path / "tiled.exr"
        OpenEXR.File({"compression": OpenEXR.NO_COMPRESSION, "type": OpenEXR.tiledimage, "tiles": tiles},
                     {"R": px[..., 0], "G": px[..., 1]}).write(str(path))
        k, leader = 6, 20   # tile (6, 0): 5 x 16 pixels
    else:
        path, k, leader = _subsampled_exr(tmp_path / "sub.exr"), 4, 8   # line y = 0: Y and the 2 x 2 channels
    assert exr_damage(path) is None
    data = bytearray(path.read_bytes())
    at = struct.unpack_from("<Q", data, _offset_table(bytes(data)) + 8 * k)[0]
    size = struct.unpack_from("<i", data, at + leader - 4)[0]
    struct.pack_into("<i", data, at + leader - 4, size + 4)
    (tmp_path / "bad.exr").write_bytes(bytes(data))
    msg = exr_damage(tmp_path / "bad.exr")
    assert msg is not None and f"its data size is {size + 4} bytes, more than the {size} its pixels take" in msg, msg


def test_a_chunk_of_no_data_and_a_tiled_flag_beside_the_deep_flag_are_damage(tmp_path):
    """Round 11: a chunk whose data size is 0 holds none of its pixels (OpenEXR writes no empty chunk), and the
    single-part tiled flag 0x200 set beside the deep-data flag 0x800 is no layout the file format allows ("Version
    Field"); each edit of a whole file is found.  Truth: the edits, made here by hand."""
    from warpbw.io.exr_layout import exr_damage

    path = _subsampled_exr(tmp_path / "sub.exr")
    data = bytearray(path.read_bytes())
    at = struct.unpack_from("<Q", data, _offset_table(bytes(data)) + 8 * 4)[0]
    struct.pack_into("<i", data, at + 4, 0)
    (tmp_path / "empty.exr").write_bytes(bytes(data))
    msg = exr_damage(tmp_path / "empty.exr")
    assert msg is not None and "its data size is 0" in msg, msg
    data = bytearray(path.read_bytes())
    struct.pack_into("<I", data, 4, struct.unpack_from("<I", data, 4)[0] | 0x200 | 0x800)
    (tmp_path / "flags.exr").write_bytes(bytes(data))
    msg = exr_damage(tmp_path / "flags.exr")
    assert msg is not None and "the single-part tiled flag 0x200 is set with the deep-data or multi-part flag" in msg, \
        msg


@pytest.mark.parametrize("mode", [1, 2], ids=["mipmap", "ripmap"])
def test_a_tiled_exr_whose_levels_round_up_reads_and_a_cut_in_its_last_level_is_found(tmp_path, mode):
    """Round 11: with ROUND_UP (tiledesc's mode bit 0x10) a part has ceil(log2(size)) + 1 levels per axis, of sizes
    rounded up (OpenEXR file layout, "Tiles"): a 33 x 37 map has 7 levels per axis, not 6, and level 1 is 17 x 19
    (2 x 2 tiles of 16), not 16 x 18 (1 x 2).
    Written so byte by byte, it reads as its level 0 and the layout checks find nothing; cut inside its last chunk
    (the coarsest level's), that chunk is named.  Counted or sized rounded down, the checks stopped before it."""
    from warpbw.io.exr_layout import exr_damage

    px = np.random.default_rng(9).random((37, 33, 3), dtype=np.float32)
    path = _multilevel_exr(tmp_path / f"up{mode}.exr", px, mode, round_up=True)
    assert np.array_equal(read_rgb(path), px)
    assert exr_damage(path) is None
    (tmp_path / "cut.exr").write_bytes(path.read_bytes()[:-10])
    msg = exr_damage(tmp_path / "cut.exr")
    pairs = [(lv, lv) for lv in range(7)] if mode == 1 else [(lx, ly) for ly in range(7) for lx in range(7)]
    n = sum(-(-math.ceil(33 / 2 ** lx) // 16) * -(-math.ceil(37 / 2 ** ly) // 16) for lx, ly in pairs)   # tiles
    assert msg is not None and f"inside chunk {n} of {n}" in msg, msg


def test_an_exr_whose_name_is_not_utf8_is_written_and_read(tmp_path):
    """OpenEXR's Python binding takes a file name as UTF-8 text: a name holding other bytes (a Latin-1 name, b"\\xff",
    which Python holds as the surrogate escape "\\udcff") it could not take.  read_exr said such a file was "unreadable
    OpenEXR file, truncated or corrupt", and write_exr failed, so that ``warpbw render -o`` such a name failed once
    its frame was rendered, where every other output (PNG, JSON, tables, mipmaps) is written under any name the file
    system takes (command-line audit, session 81).  Truth: the pixels written, and the bytes of the file written under
    a UTF-8 name, which the binding takes."""
    import os

    from warpbw.io.exr import exr_size, read_exr, write_exr

    name = tmp_path / os.fsdecode(b"probe-\xff.exr")
    try:
        name.write_bytes(b"")
    except (OSError, UnicodeError):
        pytest.skip("this file system takes no name that is not UTF-8")
    name.unlink()
    pixels = np.arange(2 * 3 * 4, dtype=np.float32).reshape(2, 3, 4)
    write_exr(name, pixels, channels=["R", "G", "B", "A"])
    write_exr(tmp_path / "plain.exr", pixels, channels=["R", "G", "B", "A"])
    assert name.read_bytes() == (tmp_path / "plain.exr").read_bytes()
    img = read_exr(name)
    assert img.channels == ["R", "G", "B", "A"] and np.array_equal(img.pixels, pixels)
    assert exr_size(name) == (3, 2)
