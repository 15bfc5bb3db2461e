"""OpenEXR images in and out, and 8-bit PNG previews.

Public functions:

- ``read_exr(path) -> ExrImage``: every channel of a scan-line or tiled EXR (first part of a
  multi-part file) as float32 ``(H, W, C)``.
- ``exr_size(path, window="data") -> (width, height)``: the data window's size (the pixels stored, which
  ``read_exr`` decodes), or with ``window="display"`` the display window's (the image's frame), from the header
  alone (no pixel read).
- ``in_display_window(img) -> ExrImage``: the image over its display window: 0 where the file stores no pixel, the
  pixels stored outside it dropped (OpenEXR Technical Introduction, "Display window" and "Data window"); ``img``
  itself where the two windows are the same.
- ``read_rgb(path) -> np.ndarray``: ``(H, W, 3)`` float32 radiance over the display window (a single ``Y``
  channel is replicated, and so, with a warning, is a lone channel of another name; a luminance / chroma image,
  Y with ``CHROMA_CHANNELS``, is refused);
  ``rgb_of(img) -> np.ndarray`` the same from an ``ExrImage`` already read (over the window it holds).
  An image whose ``chromaticities`` attribute declares other primaries or another white than Rec. 709's
  (``REC709_CHROMATICITIES``, sRGB's) is converted to them (``rec709_transform``; below).
- ``rec709_transform(chromaticities, path) -> np.ndarray | None``: the 3x3 matrix taking a file's RGB to Rec. 709
  RGB, the white adapted by Bradford's transform; None where it is the identity within
  ``CHROMATICITIES_IDENTITY_TOL`` (refused in one line where they define no colour space,
  ``CHROMATICITIES_COND_MAX``).  ``colour_conversion(path) -> str | None`` says from the header alone whether
  ``read_rgb`` converts the file (a note for the cache keys of what was rendered from it, and for ``warpbw info``).
- ``write_exr(path, pixels, channels=None, notes=None)``: float32, lossless ZIP compression; channel names and
  their order survive a round trip through ``read_exr``, and so do ``notes`` (str keys and values, header
  attributes ``warpbw_note_KEY``).
- ``linear_to_srgb(x)``: the sRGB transfer function (IEC 61966-2-1) on linear values.
- ``write_png(path, rgb, exposure=0.0)``: linear radiance -> 8-bit sRGB preview, exposure in stops.
- ``write_false_colour_png(path, values, mask=None, vmin=None, vmax=None, log=False)``: a scalar
  AOV through matplotlib's viridis colour map; returns the ``(vmin, vmax)`` it used, and writes them into the
  PNG's ``Description`` (``colour_scale_text(lo, hi, log)``).

Class: ``ExrImage`` (``pixels``, ``channels``, ``path``, ``notes``, ``data_window``, ``display_window``,
``chromaticities``).

Colour: every stage of the renderer takes RGB to be linear Rec. 709 / sRGB (the primaries and D65 white of
IEC 61966-2-1).  An EXR may declare its own in the standard ``chromaticities`` attribute (CIE 1931 xy of red,
green, blue and white); a file without it is Rec. 709 by OpenEXR's definition.  Other primaries (ACES2065-1's, a
wide-gamut camera's) were read as Rec. 709's, a silently wrong light: a probe in ACES2065-1 whose stored RGB is
(1, 0, 0) is (2.52, -0.28, -0.02) in Rec. 709.  They are now converted through CIE XYZ, the white adapted to D65
with Bradford's cone matrix (ICC.1:2010 Annex E), so that the file's white stays white, as Mitsuba's and pbrt's
readers do.  A conversion within ``CHROMATICITIES_IDENTITY_TOL`` of the identity is skipped, and the pixels are
read bit for bit: city.exr declares sRGB's primaries adapted to a D50 white, which Bradford's transform brings
back to the identity within 2e-4.  Values the conversion makes negative (colours outside Rec. 709's gamut) are
kept here; the probe loader sets negative radiance to 0 with a warning, as for any probe.  A lone Y channel is
luminance, grey in any primaries.  Where RGB is reduced to one number (the bandwidth pass, the sampling tables), it
is weighed by ``REC709_LUMINANCE``.  ``write_exr`` writes no ``chromaticities``: its RGB is Rec. 709's, which is
what OpenEXR's readers take a file without the attribute to hold.

Every problem with a user's file is raised as :class:`warpbw.errors.WarpbwError` in one line that
names the file.  A file OpenEXR refuses is then read against the OpenEXR file layout
(:func:`warpbw.io.exr_layout.exr_damage`), and the message names the first damaged part and its byte where that
shows one.
"""
from __future__ import annotations

import contextlib
import io
import math
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from warpbw.errors import FLOAT32_MAX, WarpbwError, check_flag, check_input_file, check_path, one_line
from warpbw.io.exr_layout import exr_damage, first_header_declares
from warpbw.native_output import captured_native_output

# First four bytes of every OpenEXR file: the magic number 20000630 = 0x762f3101, stored
# little-endian (OpenEXR file layout, "Magic Number" section of openexr.com/en/latest/OpenEXRFileLayout.html).
EXR_MAGIC = b"\x76\x2f\x31\x01"
# Magic numbers of formats users commonly mistake for EXR, only to word the error message
# (PNG spec section 5.2; JPEG SOI marker; Radiance .hdr "#?" header; TIFF byte-order marks).
_OTHER_MAGICS = (
    (b"\x89PNG", "a PNG image"),
    (b"\xff\xd8\xff", "a JPEG image"),
    (b"#?", "a Radiance .hdr image"),
    (b"II*\x00", "a TIFF image"),
    (b"MM\x00*", "a TIFF image"),
)
# Header attribute in which write_exr records the caller's channel order (EXR itself stores
# channels sorted by name, so "R,G,B,A" would otherwise come back as "A,B,G,R").
_ORDER_ATTRIBUTE = "warpbw_channels"
_NOTE_PREFIX = "warpbw_note_"   # header attributes that hold write_exr's notes
# CIE 1931 xy of the red, green and blue primaries and of the white of ITU-R BT.709-6 (IEC 61966-2-1's sRGB, D65):
# the RGB the renderer computes in, and what OpenEXR takes a file without a chromaticities attribute to be.
REC709_CHROMATICITIES = (0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290)
# Luminance Y of linear Rec. 709 RGB, the weights of ITU-R BT.709-6 Item 3.2 (the Y row of the RGB -> XYZ matrix of
# REC709_CHROMATICITIES, 0.21264, 0.71517, 0.07219, rounded as the standard rounds it): the one set the bandwidth
# pass (warpbw.bandwidth.LUMINANCE) and the BRDF sampling tables (warpbw.sampling.LUMINANCE) weigh RGB by.  The
# probe's sampling distribution weighs it by Mitsuba's rounding of the same row (warpbw.envmap.LUMINANCE_RGB).
REC709_LUMINANCE = (0.2126, 0.7152, 0.0722)
# Bradford's cone response matrix (Lam 1985; ICC.1:2010 Annex E): the white point's adaptation.
BRADFORD = ((0.8951, 0.2664, -0.1614), (-0.7502, 1.7135, 0.0367), (0.0389, -0.0685, 1.0296))
# A file whose conversion to Rec. 709 lies within this of the identity (largest entry) is read as stored, bit for
# bit: city.exr declares sRGB's primaries adapted to D50, whose Bradford conversion is the identity within 2e-4.
CHROMATICITIES_IDENTITY_TOL = 1.0e-3
# Condition number above which a file's RGB -> XYZ matrix is taken as singular (a white its primaries cannot make):
# ACES2065-1's is 3.4, Rec. 709's 5.1.
CHROMATICITIES_COND_MAX = 1.0e6
# Chroma channels of OpenEXR's luminance / chroma images (ImfRgbaYca: RY = (R - Y) / Y, BY = (B - Y) / Y).
CHROMA_CHANNELS = ("RY", "BY")
# Order used for files without that attribute: colour first, then alpha, then the rest by name.
_CANONICAL_ORDER = ("R", "G", "B", "Y", "A")
# sRGB transfer function constants (IEC 61966-2-1:1999): linear segment below 0.0031308 with slope
# 12.92, then 1.055 * x^(1/2.4) - 0.055.
SRGB_LINEAR_THRESHOLD = 0.0031308
SRGB_LINEAR_SLOPE = 12.92
SRGB_GAMMA = 2.4
SRGB_A = 0.055


@dataclass
class ExrImage:
    """An EXR image: ``pixels`` (H, W, C) float32, ``channels`` names in ``pixels``' last-axis order; the file's
    windows as (x min, y min, x max, y max), inclusive, ``pixels`` covering the data window (None: not from a file)."""

    pixels: np.ndarray
    channels: list[str]
    path: str
    notes: dict = field(default_factory=dict)   # the write_exr notes the file holds (str -> str)
    data_window: tuple | None = None
    display_window: tuple | None = None
    chromaticities: tuple | None = None   # as the file declares them (None: Rec. 709's, OpenEXR's default)


def _check_magic(path: Path) -> None:
    with open(path, "rb") as fh:
        head = fh.read(4)
    if head == EXR_MAGIC:
        return
    what = next((name for magic, name in _OTHER_MAGICS if head.startswith(magic)), None)
    if len(head) < 4:
        what = f"a {len(head)}-byte file"
    found = f"; it looks like {what}" if what else f"; first bytes are {head.hex()}"
    raise WarpbwError(f"{path}: not an OpenEXR file (expected magic number 0x762f3101{found})")


def _order_channels(names: list[str], recorded: object) -> list[str]:
    if isinstance(recorded, str | bytes):
        if isinstance(recorded, bytes):
            recorded = recorded.decode("utf-8", "replace")
        order = recorded.split(",")
        if sorted(order) == sorted(names):
            return order
    first = [c for c in _CANONICAL_ORDER if c in names]
    return first + sorted(c for c in names if c not in first)


def _damaged(path: Path, found: str) -> WarpbwError:
    """The refusal of an EXR file whose damage the layout shows (``found``: ``exr_layout``'s words)."""
    return WarpbwError(f"{path}: unreadable OpenEXR file, truncated or corrupt: {found}")


def _utf8_name(path) -> bool:
    """Whether OpenEXR's Python binding can take ``path`` by name: it passes a name on as UTF-8, and a name holding
    bytes that are not UTF-8 (a Latin-1 name, which Python holds as surrogate escapes) it could not take: it said a
    good file was "truncated or corrupt", and a render failed to write its image once its frame was done."""
    try:
        str(path).encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def _binding_name(path: Path, stack: contextlib.ExitStack, mode: str):
    """What OpenEXR's binding is given for ``path``: its name where the binding can take it (``_utf8_name``), else the
    file opened here in ``mode`` and named by its descriptor (/proc/self/fd/N, UTF-8 whatever the file's name), or,
    where there is no /proc, the open file itself, which newer bindings take (3.5.3's; 3.4.0's takes names only)."""
    if _utf8_name(path):
        return str(path)
    f = stack.enter_context(open(path, mode))
    by_fd = f"/proc/self/fd/{f.fileno()}"
    return by_fd if os.path.exists(by_fd) else f


def _open_exr(path, header_only: bool):
    """(checked path, header, channels) of an EXR file; channels is empty when ``header_only``."""
    import OpenEXR

    path = check_input_file(path, "an OpenEXR image")
    _check_magic(path)
    try:
        # OpenEXR prints its own warnings about a damaged file to the descriptors: they go into the error; a name
        # the binding cannot take (_utf8_name) is read through the file opened here (_binding_name)
        with captured_native_output() as native, contextlib.ExitStack() as stack:
            source = _binding_name(path, stack, "rb")
            exr = OpenEXR.File(source, separate_channels=True, header_only=header_only)
            header = exr.header()
            chans = {} if header_only else {name: (ch, np.asarray(ch.pixels)) for name, ch in exr.channels().items()}
    except Exception as exc:  # OpenEXR raises RuntimeError for truncated / corrupt files
        # OpenEXR's own words ("file has 0 parts", "Unable to open ... for read") do not say what is wrong: the layout
        # of the header and offset table may
        found = exr_damage(path)
        if not found and isinstance(exc, UnicodeDecodeError):   # the binding decodes names and strings as UTF-8
            found = (f"a name or text in it is not UTF-8 text (byte 0x{exc.object[exc.start]:02x}), which OpenEXR's "
                     "Python binding cannot read")
        if found:
            raise _damaged(path, found) from None
        said = "; ".join(line.replace(f"{path}: ", "").strip() for line in native if line.strip())
        raise WarpbwError(f"{path}: unreadable OpenEXR file, truncated or corrupt ({one_line(exc)}"
                          f"{'; ' + said if said else ''})") from None
    for line in native:            # a file that read: pass on whatever the library had to say, a warning a line
        if line.strip():
            warnings.warn(f"{path}: OpenEXR: {line.replace(f'{path}: ', '').strip()}", stacklevel=2)
    return path, header, chans


def _check_declared(path: Path, name: str) -> None:
    """Refuse a file whose first header lacks window ``name`` (box2i): OpenEXR reads a header without its dataWindow
    or displayWindow as 64 x 64 pixels (the damage, where the layout shows it, is named)."""
    declared = first_header_declares(path, name, "box2i")
    if declared is not True:
        found = exr_damage(path) or (f"its header has no {name} (box2i)" if declared is False else None)
        if found:
            raise _damaged(path, found)


def _window(header, name: str) -> tuple[int, int, int, int]:
    (x0, y0), (x1, y1) = header[name]
    return int(x0), int(y0), int(x1), int(y1)


def exr_size(path, window: str = "data") -> tuple[int, int]:
    """(width, height) of an EXR file's data window (the pixels ``read_exr`` decodes) or, with ``window="display"``,
    of its display window (the frame ``read_rgb`` returns), read from its header alone: a size bound can be checked
    before the pixels are decoded."""
    if window not in ("data", "display"):
        raise WarpbwError(f"exr_size: window {window!r}: expected 'data' or 'display'")
    path, header, _ = _open_exr(path, header_only=True)
    name = "dataWindow" if window == "data" else "displayWindow"
    _check_declared(path, name)
    try:
        x0, y0, x1, y1 = _window(header, name)
        return x1 - x0 + 1, y1 - y0 + 1
    except (KeyError, TypeError, ValueError):
        raise WarpbwError(f"{path}: OpenEXR header without a valid {name}") from None


def read_exr(path) -> ExrImage:
    """Read every channel of an EXR file as float32 ``(H, W, C)`` (half and uint channels converted)."""
    path, header, both = _open_exr(path, header_only=False)
    _check_declared(path, "displayWindow")   # the frame in_display_window places the pixels in: not a 64 x 64 default
    chans = {name: ch for name, (ch, _) in both.items()}
    planes = {name: px for name, (_, px) in both.items()}
    for name, ch in chans.items():
        if getattr(ch, "xSampling", 1) != 1 or getattr(ch, "ySampling", 1) != 1:
            raise WarpbwError(f"{path}: channel {name!r} is subsampled ({ch.xSampling}x{ch.ySampling}); expected "
                              "full-resolution channels")
    if not planes:
        raise WarpbwError(f"{path}: OpenEXR file has no channels (expected R,G,B or Y)")
    names = _order_channels(list(planes), header.get(_ORDER_ATTRIBUTE))
    shapes = {planes[n].shape for n in names}
    if len(shapes) != 1 or len(next(iter(shapes))) != 2:
        raise WarpbwError(f"{path}: channels have shapes {sorted(shapes)}, expected one (H, W) shape")
    pixels = np.stack([planes[n].astype(np.float32, copy=False) for n in names], axis=-1)
    notes = {k[len(_NOTE_PREFIX):]: v for k, v in header.items() if k.startswith(_NOTE_PREFIX) and isinstance(v, str)}
    windows = {}
    for key, name in (("data_window", "dataWindow"), ("display_window", "displayWindow")):
        try:
            windows[key] = _window(header, name)
        except (KeyError, TypeError, ValueError):
            windows[key] = None
    return ExrImage(pixels=np.ascontiguousarray(pixels), channels=names, path=str(path), notes=notes, **windows,
                    chromaticities=header.get("chromaticities"))


def _primaries_to_xyz(c) -> np.ndarray:
    """The 3x3 matrix from RGB of chromaticities ``c`` (x, y of red, green, blue, white) to CIE XYZ, white at Y = 1.
    Each primary enters as (x, y, 1 - x - y) up to its scale (a y <= 0, as ACES2065-1's blue, is allowed); the
    scales are those that add up to the white."""
    xy = np.asarray(c, np.float64).reshape(4, 2)
    prim = np.stack([xy[:3, 0], xy[:3, 1], 1.0 - xy[:3, 0] - xy[:3, 1]])   # columns R, G, B
    white = np.array([xy[3, 0], xy[3, 1], 1.0 - xy[3, 0] - xy[3, 1]]) / xy[3, 1]
    return prim * np.linalg.solve(prim, white)


def rec709_transform(chromaticities, path="chromaticities") -> np.ndarray | None:
    """The 3x3 matrix M with rgb_709 = M rgb of a file whose ``chromaticities`` (8 numbers: CIE 1931 x, y of red,
    green, blue, white) are declared: to XYZ, the white adapted to D65 by Bradford's transform, to Rec. 709 RGB
    (module docstring).  None where M is the identity within ``CHROMATICITIES_IDENTITY_TOL``.  Chromaticities that
    define no colour space (not 8 finite numbers, a white of y <= 0, primaries on one line, a white on a side of
    their triangle) are a one-line error naming ``path``."""
    try:
        c = [float(v) for v in chromaticities]
    except (TypeError, ValueError):
        c = []
    prim = np.array(c[:6]).reshape(3, 2) if len(c) == 8 else None
    if prim is None or not all(math.isfinite(v) for v in c) or c[7] <= 0.0 or \
            abs(np.linalg.det(np.column_stack([prim, np.ones(3)]))) < 1.0e-9:
        raise WarpbwError(f"{path}: chromaticities {chromaticities!r} define no RGB colour space; expected the CIE xy "
                          "of red, green, blue (not on one line) and of a white with y > 0")
    src, dst = _primaries_to_xyz(c), _primaries_to_xyz(REC709_CHROMATICITIES)
    if not np.isfinite(src).all() or np.linalg.cond(src) > CHROMATICITIES_COND_MAX:
        raise WarpbwError(f"{path}: chromaticities {chromaticities!r} define no RGB colour space: their primaries "
                          "cannot add up to their white (it lies on a side of their triangle); expected a white "
                          "inside it")
    cone = np.array(BRADFORD)
    adapt = np.linalg.solve(cone, np.diag((cone @ dst.sum(axis=1)) / (cone @ src.sum(axis=1))) @ cone)
    m = np.linalg.solve(dst, adapt @ src)
    return None if np.abs(m - np.eye(3)).max() <= CHROMATICITIES_IDENTITY_TOL else m


def colour_conversion(path) -> str | None:
    """From the header alone: a note naming the conversion ``read_rgb`` applies to the EXR ``path`` (its declared
    chromaticities to Rec. 709), or None when it reads the RGB as stored, or when the file does not read (loading
    it refuses it by name)."""
    check_path(path, "colour_conversion: path")   # None or a number read as "no conversion"
    try:
        path, header, _ = _open_exr(path, header_only=True)
        declared = header.get("chromaticities")
        m = None if declared is None else rec709_transform(declared, path)
    except WarpbwError:
        return None
    return None if m is None else "rec709 from chromaticities " + ",".join(f"{v:.9g}" for v in m.ravel())


def in_display_window(img: ExrImage) -> ExrImage:
    """``img`` over its display window, the image's frame: 0 in every channel where the file stores no pixel,
    the pixels stored outside the frame dropped (OpenEXR Technical Introduction: a file "may not have pixel data for
    all the pixels in the display window, or ... may have pixel data beyond" it); ``img`` itself where the windows
    are the same (or not known).  A probe auto-cropped to its non-black texels was stretched over the sphere."""
    if not isinstance(img, ExrImage):
        raise WarpbwError(f"in_display_window: expected an ExrImage (read_exr's), got {type(img).__name__}")
    data, frame = img.data_window, img.display_window
    if data is None or frame is None or data == frame:
        return img
    h, w = frame[3] - frame[1] + 1, frame[2] - frame[0] + 1
    out = np.zeros((h, w, img.pixels.shape[2]), np.float32)
    x0, y0 = max(data[0], frame[0]), max(data[1], frame[1])     # the windows' overlap, in pixel space
    x1, y1 = min(data[2], frame[2]), min(data[3], frame[3])
    if x0 <= x1 and y0 <= y1:
        out[y0 - frame[1]:y1 - frame[1] + 1, x0 - frame[0]:x1 - frame[0] + 1] = \
            img.pixels[y0 - data[1]:y1 - data[1] + 1, x0 - data[0]:x1 - data[0] + 1]
    return ExrImage(pixels=out, channels=list(img.channels), path=img.path, notes=dict(img.notes),
                    data_window=frame, display_window=frame, chromaticities=img.chromaticities)


def read_rgb(path) -> np.ndarray:
    """``(H, W, 3)`` float32 RGB from an EXR over its display window (``in_display_window``): R,G,B channels, or a
    lone ``Y`` (or single) channel as grey."""
    return rgb_of(in_display_window(read_exr(path)))


def rgb_of(img: ExrImage) -> np.ndarray:
    """``(H, W, 3)`` float32 RGB of an image read by :func:`read_exr` (as :func:`read_rgb`), in Rec. 709's primaries
    (``rec709_transform`` of ``img.chromaticities`` applied; only colour is converted, so a height field's or a normal
    map's odd chromaticities are never read): its own pixels when they are R,G,B in that order and need no
    conversion (no copy), else a new array.  A grey Y is luminance, the same in any primaries, and is not
    converted."""
    if not isinstance(img, ExrImage):   # a numpy array: an AttributeError ('channels')
        raise WarpbwError(f"rgb_of: expected an ExrImage (read_exr's), got {type(img).__name__}")
    ch = img.channels
    if all(c in ch for c in ("R", "G", "B")):
        rgb = img.pixels if ch == ["R", "G", "B"] else \
            np.ascontiguousarray(img.pixels[..., [ch.index("R"), ch.index("G"), ch.index("B")]])
        m = None if img.chromaticities is None else rec709_transform(img.chromaticities, img.path)
        return rgb if m is None else np.ascontiguousarray(rgb @ m.T.astype(np.float32))
    grey = "Y" if "Y" in ch else (ch[0] if len(ch) == 1 else None)
    chroma = [c for c in CHROMA_CHANNELS if c in ch]
    if grey == "Y" and chroma:   # read as its luminance, a coloured probe was grey without a word
        raise WarpbwError(f"{img.path}: channels {ch} are luminance and chroma ({', '.join(chroma)}: OpenEXR's "
                          "luminance / chroma encoding), not R,G,B or a grey Y; expected R,G,B (save it as RGB)")
    if grey is None:
        raise WarpbwError(f"{img.path}: channels {ch} hold no colour (expected R,G,B or Y)")
    if grey != "Y":   # a lone Z (depth) read as a grey probe without a word (scene fuzzing, session 63)
        warnings.warn(f"{img.path}: its one channel {grey!r} is read as grey radiance (expected R,G,B or Y)",
                      RuntimeWarning, stacklevel=3)
    return np.ascontiguousarray(np.repeat(img.pixels[..., [ch.index(grey)]], 3, axis=-1))


def _default_channels(c: int) -> list[str]:
    return {1: ["Y"], 3: ["R", "G", "B"], 4: ["R", "G", "B", "A"]}.get(c, [])


def write_exr(path, pixels, channels=None, notes: dict | None = None) -> Path:
    """Write ``pixels`` (H, W) or (H, W, C) as float32 EXR (ZIP, lossless); returns the path.

    ``channels`` defaults to Y, RGB or RGBA for C = 1, 3, 4; other C need explicit names.  ``notes`` (str keys
    and values) go into the header and come back as ``read_exr(path).notes``.
    """
    import OpenEXR

    path = check_path(path, "write_exr: path")
    arr = np.asarray(pixels)
    if arr.dtype.kind not in "buif":   # strings, None, objects: numpy's cast error below
        raise WarpbwError(f"{path}: cannot write pixels of type {arr.dtype} (expected numbers)")
    if arr.ndim == 2:
        arr = arr[..., None]
    if arr.ndim != 3 or arr.shape[0] == 0 or arr.shape[1] == 0:
        raise WarpbwError(f"{path}: cannot write pixels of shape {arr.shape} (expected (H, W) or (H, W, C))")
    names = list(channels) if channels is not None else _default_channels(arr.shape[2])
    if len(names) != arr.shape[2] or len(set(names)) != len(names) or any(
        not isinstance(n, str) or not n or "," in n for n in names
    ):
        raise WarpbwError(
            f"{path}: channel names {names} do not match {arr.shape[2]} channels "
            "(expected that many distinct, non-empty names without commas)"
        )
    wide = arr.dtype.kind == "f" and arr.dtype.itemsize > 4   # only float64 (and wider) can exceed float32
    with np.errstate(invalid="ignore"):
        big = np.isfinite(arr) & (np.abs(arr) > FLOAT32_MAX) if wide else np.zeros(arr.shape, bool)
    if big.any():   # written as inf, with only numpy's cast warning
        raise WarpbwError(f"{path}: values up to {np.abs(arr[big]).max():.3g} are beyond float32 ({FLOAT32_MAX:.3g}), "
                          "in which EXR stores them")
    data = {n: np.ascontiguousarray(arr[..., i], dtype=np.float32) for i, n in enumerate(names)}
    header = {
        "compression": OpenEXR.ZIP_COMPRESSION,
        "type": OpenEXR.scanlineimage,
        _ORDER_ATTRIBUTE: ",".join(names),
        **{_NOTE_PREFIX + str(k): str(v) for k, v in (notes or {}).items()},
    }
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with contextlib.ExitStack() as stack:
            target = _binding_name(path, stack, "wb")
            if isinstance(target, str):
                OpenEXR.File(header, data).write(target)
            else:   # no /proc: encoded in memory (a newer binding writes to a stream), then written to the file
                encoded = io.BytesIO()
                OpenEXR.File(header, data).write(encoded)
                target.write(encoded.getbuffer())
    except Exception as exc:
        raise WarpbwError(f"{path}: cannot write OpenEXR file ({one_line(exc)})") from None
    return path


# Pixels a preview PNG (write_png, write_false_colour_png) is encoded in at a time (ours): its float64 temporaries
# are then a few tens of MB whatever the image's size (session 79: the whole image's took 144 and 80 bytes per pixel,
# more than the frame itself).
PREVIEW_BLOCK_PIXELS = 1 << 18


def linear_to_srgb(x):
    """sRGB-encode linear values (IEC 61966-2-1); no clamping, works elementwise on any array."""
    x = np.asarray(x, dtype=np.float64)
    hi = (1.0 + SRGB_A) * np.power(np.maximum(x, SRGB_LINEAR_THRESHOLD), 1.0 / SRGB_GAMMA) - SRGB_A
    return np.where(x <= SRGB_LINEAR_THRESHOLD, SRGB_LINEAR_SLOPE * x, hi)


def _to_png(path: Path, rgb8: np.ndarray, text: dict | None = None) -> Path:
    """``rgb8`` as a PNG, with ``text`` as its tEXt chunks (keyword -> Latin-1 value)."""
    from PIL import Image, PngImagePlugin

    info = PngImagePlugin.PngInfo()
    for key, value in (text or {}).items():
        info.add_text(key, value)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        Image.fromarray(rgb8).save(str(path), format="PNG", pnginfo=info)
    except Exception as exc:
        raise WarpbwError(f"{path}: cannot write PNG ({one_line(exc)})") from None
    return path


def _row_blocks(height: int, width: int):
    """Row slices of an image of ``height`` x ``width``, each of about ``PREVIEW_BLOCK_PIXELS`` pixels (one row at
    least): the previews are encoded a block at a time."""
    rows = max(1, PREVIEW_BLOCK_PIXELS // max(1, width))
    return [slice(r, min(height, r + rows)) for r in range(0, height, rows)]


def write_png(path, rgb, exposure: float = 0.0) -> Path:
    """Linear ``rgb`` (H, W, 3) (or (H, W) grey) -> 8-bit sRGB PNG after scaling by ``2**exposure``.

    Values are clipped to [0, 1] before encoding; NaN shows as 0 (black), +inf as 1.  Encoded in float64, a block of
    rows at a time (``PREVIEW_BLOCK_PIXELS``).
    """
    path = check_path(path, "write_png: path")
    arr = np.asarray(rgb)
    if arr.dtype.kind not in "biuf":   # what the float64 cast refuses, refused as before; else cast block by block
        arr = np.asarray(rgb, dtype=np.float64)
    if arr.ndim == 3 and arr.shape[2] == 1:
        arr = arr[..., 0]
    if arr.ndim not in (2, 3) or (arr.ndim == 3 and arr.shape[2] != 3):
        raise WarpbwError(f"{path}: cannot write a preview of shape {arr.shape} (expected (H, W, 3))")
    try:
        gain = 2.0 ** float(exposure)
    except (OverflowError, TypeError, ValueError):   # 2.0 ** 1e6 overflows Python's float
        gain = math.nan
    if not (0.0 < gain < math.inf):
        raise WarpbwError(f"{path}: exposure {exposure!r}: expected a finite number of stops (2^exposure a finite "
                          "gain)")
    rgb8 = np.empty(arr.shape[:2] + (3,), np.uint8)
    for rows in _row_blocks(*arr.shape[:2]):   # the whole image's float64 temporaries took 144 bytes per pixel
        block = np.asarray(arr[rows], dtype=np.float64)
        if block.ndim == 2:
            block = np.repeat(block[..., None], 3, axis=-1)
        v = np.nan_to_num(block * gain, nan=0.0, posinf=1.0, neginf=0.0)
        enc = linear_to_srgb(np.clip(v, 0.0, 1.0))
        rgb8[rows] = np.round(enc * 255.0).astype(np.uint8)
    return _to_png(path, rgb8)


def write_false_colour_png(path, values, mask=None, vmin=None, vmax=None, log=False):
    """Scalar ``values`` (H, W) -> viridis PNG; pixels outside ``mask`` (or non-finite) are black.

    ``vmin``/``vmax`` default to the range of the shown values; ``log`` maps log10 of the values
    (non-positive values shown at ``vmin``). Returns the ``(vmin, vmax)`` used, in value units ((0, 0) for a log
    scale with no shown value above 0); the PNG's
    ``Description`` text chunk says the same (``colour_scale_text``), so the picture carries its scale.
    """
    from matplotlib import colormaps

    path = check_path(path, "write_false_colour_png: path")
    log = check_flag(log, f"{path}: log")   # "no" is truthy: a log scale, described as one
    v = np.asarray(values, dtype=np.float64)
    if v.ndim != 2:
        raise WarpbwError(f"{path}: cannot write a false-colour image of shape {v.shape} (expected (H, W))")
    for opt, x in (("vmin", vmin), ("vmax", vmax)):
        if x is not None and not (isinstance(x, (int, float, np.integer, np.floating)) and math.isfinite(x)):
            raise WarpbwError(f"{path}: {opt} of the colour scale: expected a finite number, got {x!r}")
    if vmin is not None and vmax is not None and vmin > vmax:
        raise WarpbwError(f"{path}: colour scale from vmin {vmin:g} to vmax {vmax:g}: expected vmin <= vmax")
    for opt, x in (("vmin", vmin), ("vmax", vmax)):
        if log and x is not None and x <= 0:   # -1 became 2.2e-308: a scale of 300 decades
            raise WarpbwError(f"{path}: {opt} {x:g} of a log colour scale: expected a number > 0")
    shown = np.isfinite(v)
    if mask is not None:
        m = np.asarray(mask, dtype=bool)
        if m.shape != v.shape:
            raise WarpbwError(f"{path}: mask shape {m.shape} differs from values shape {v.shape}")
        shown &= m
    ok = shown & (v > 0) if log else shown
    lo = float(vmin) if vmin is not None else (float(v[ok].min()) if ok.any() else (1.0 if log else 0.0))
    hi = float(vmax) if vmax is not None else (float(v[ok].max()) if ok.any() else lo)
    # one end given beyond every shown value: the other end meets it (vmin 5 over values <= 1 said "5 to 1")
    hi, lo = (max(hi, lo), lo) if vmax is None else (hi, min(lo, hi))
    if log:
        lo = max(lo, np.finfo(np.float64).tiny)
        hi = max(hi, lo)
        t_lo, t_hi = np.log10(lo), np.log10(hi)
    else:
        t_lo, t_hi = lo, hi
    rgb8 = np.zeros(v.shape + (3,), np.uint8)
    for rows in _row_blocks(*v.shape):   # a block at a time: the whole map's colours took 80 bytes per pixel
        vb, sb = v[rows], shown[rows]
        t_val = np.log10(np.maximum(np.where(sb, vb, lo), lo)) if log else np.where(sb, vb, lo)
        t = np.clip((t_val - t_lo) / (t_hi - t_lo), 0.0, 1.0) if t_hi > t_lo else np.zeros_like(t_val)
        block = np.round(colormaps["viridis"](t)[..., :3] * 255.0).astype(np.uint8)
        block[~sb] = 0
        rgb8[rows] = block
    if log and vmin is None and vmax is None and not ok.any():   # all 0 (a constant light's b_p): it said "1 to 1"
        # no pixel shown at all (a mask that leaves none, as the command line's for a black or empty frame): all
        # black, where the text once said "dark blue"
        text = ("no shown value is above 0, all drawn at the bottom (dark blue)" if shown.any() else
                "no value shown")
        _to_png(path, rgb8, {"Description": f"viridis colour scale, log10: {text}; black: not shown",
                             "Software": "warpbw"})
        return 0.0, 0.0
    _to_png(path, rgb8, {"Description": colour_scale_text(lo, hi, log), "Software": "warpbw"})
    return lo, hi


def colour_scale_text(lo: float, hi: float, log: bool) -> str:
    """How a false-colour PNG maps values to colours, in words (its ``Description`` text chunk)."""
    return (f"viridis colour scale, {'log10' if log else 'linear'}, from {lo:.6g} (dark blue) to {hi:.6g} "
            "(yellow); black: not shown")
