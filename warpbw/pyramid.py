"""Bandwidth-buffer pyramid (002 Sec. 3.1): the per-pixel shading level (Eq. 11) and its mip-maps.

Public:
    ``max_level(width, height)``          the coarsest level Eq. 11 can give: floor(log2(min(W, H)))
    ``pyramid_shapes(width, height)``     the (rows, cols) of every pyramid level, finest first
    ``image_level(b_p, coverage, width, height, device)`` -> ``wp.array2d(int32)`` (H, W)   Eq. 11
    ``image_level_kernel``                Eq. 11's kernel (warpbw.adaptive compiles it ahead)
    ``Pyramid`` / ``build_pyramid(values, op, device)``   min- or max-filtered mip-map of any size
    ``level_pyramid`` / ``variance_pyramid`` / ``curvature_pyramid``   the three the paper builds
    ``sanitize_f32_kernel``, ``reduce_f32_kernel``, ``reduce_i32_kernel``, ``abs_f32_kernel``   the pyramid's
                                          kernels

Level numbering.  Level 0 is the finest (full resolution); level ``l`` is the image reduced ``2**l``
times along each axis.  Eq. 11 stores, per pixel,

    level(p) = min(floor(log2(1 / b_p)), min(log2 W, log2 H))                       (002 Eq. 11)

with ``b_p`` the image-space bandwidth in cycles/pixel, so ``b_p = 1 -> 0``, ``b_p = 0.5 -> 1``,
``b_p = 1/3 -> 1``, ``b_p = 0.25 -> 2``.  We also clamp below at 0 (``b_p > 1`` gives 0, never a
negative level) and read ``min(log2 W, log2 H)`` as the integer ``floor(log2(min(W, H)))`` so that
images of any size get an integer top level (= ``max_level``).  The floor is computed exactly: the
level is the largest ``l <= max_level`` with ``b_p * 2**l <= 1`` (power-of-two scalings are exact in
float32), so ``b_p = 2**-k`` never lands one level off through a rounded ``log2``.

Inputs that are not a positive finite bandwidth:
    * ``b_p <= 0`` (and ``-inf``): no variation at all, the formula's limit: ``max_level``;
    * ``b_p = +inf``: the formula's limit, ``log2(0) = -inf``, clamped: level 0 (finest);
    * ``b_p = NaN``: no limit exists; ``nan_level="finest"`` (default) gives 0, the conservative
      choice (a failed estimate is shaded at full rate rather than blurred), ``"coarsest"`` gives
      ``max_level``;
    * pixels that the coverage mask marks as empty (no geometry): ``max_level`` whatever ``b_p``
      says, so that the min filter of the level pyramid never lets background force fine levels.

Size rule.  Level ``l + 1`` has ``ceil(h_l / 2)`` rows and ``ceil(w_l / 2)`` columns, down to and
including 1 x 1 (a 1 x 1 image has one level; ``W x H`` has ``1 + ceil(log2(max(W, H)))`` levels;
an axis that reached 1 stays 1).  Texel ``(x, y)`` of level ``l + 1`` reduces its parents' 2 x 2
block ``[2x, 2x + 1] x [2y, 2y + 1]`` of level ``l`` clipped at the border, so on odd sizes the last
row/column of texels reduces 2 x 1, 1 x 2 or 1 x 1 parents.  By induction texel ``(x, y)`` of level
``l`` is the min (max) over the finest pixels ``[x 2^l, min((x + 1) 2^l, W)) x [y 2^l, min((y + 1)
2^l, H))``; the pixel at finest ``(x, y)`` is covered at level ``l`` by texel ``(x >> l, y >> l)``.
Note the pyramid can have more levels than ``max_level + 1`` on non-square images (512 x 3: ten
levels, but Eq. 11 stops at level 1); those extra levels are harmless and cost little.

NaN in float values: the min filter reads NaN as ``-inf`` and the max filter as ``+inf`` (both the
conservative extreme: finest level, largest variance), from level 0 on; level 0 is a sanitised copy.

Arrays are ``wp.array2d`` of shape (rows = H, cols = W), row 0 at the top (../shared/DESIGN.md); flat
row-major buffers such as the G-buffer's (``index = y * W + x``) are accepted with ``width`` and
``height`` given.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import warp as wp

from warpbw.errors import WarpbwError, check_count, check_device, check_flag, is_int

wp.set_module_options({"enable_backward": False})  # no gradients are taken: halves compile time

OPS = {"min": 0, "max": 1}
NAN_LEVELS = ("finest", "coarsest")

_INF = wp.constant(math.inf)


# ---------------------------------------------------------------------------------------------
# Kernels
# ---------------------------------------------------------------------------------------------
@wp.kernel
def image_level_kernel(b_p: wp.array2d(dtype=wp.float32), coverage: wp.array2d(dtype=wp.int32),
                       top: int, nan_level: int, out: wp.array2d(dtype=wp.int32)):
    """Eq. 11 per pixel; ``top`` = max_level, ``nan_level`` the level given to NaN."""
    y, x = wp.tid()
    b = b_p[y, x]
    lvl = top
    if coverage[y, x] != 0:
        if wp.isnan(b):
            lvl = nan_level
        elif b > 0.0:
            # largest l <= top with b * 2^l <= 1, i.e. floor(log2(1 / b)) clamped to [0, top];
            # doubling is exact (s <= 0.5 before each step, so it never overflows)
            lvl = int(0)
            s = b
            while lvl < top and s * 2.0 <= 1.0:
                s = s * 2.0
                lvl = lvl + 1
    out[y, x] = lvl


@wp.func
def _sanitize_f32(v: float, op: int):
    r = v
    if wp.isnan(v):
        if op == 0:
            r = -_INF
        else:
            r = _INF
    return r


@wp.kernel
def sanitize_f32_kernel(src: wp.array2d(dtype=wp.float32), op: int, dst: wp.array2d(dtype=wp.float32)):
    y, x = wp.tid()
    dst[y, x] = _sanitize_f32(src[y, x], op)


@wp.kernel
def reduce_f32_kernel(src: wp.array2d(dtype=wp.float32), op: int, dst: wp.array2d(dtype=wp.float32)):
    """One pyramid step: dst[y, x] = op over src's 2 x 2 block at (2y, 2x), clipped at the border.
    Clipping repeats the last row/column, which leaves a min or max unchanged."""
    y, x = wp.tid()
    y0 = 2 * y
    x0 = 2 * x
    y1 = wp.min(y0 + 1, src.shape[0] - 1)
    x1 = wp.min(x0 + 1, src.shape[1] - 1)
    a = _sanitize_f32(src[y0, x0], op)
    b = _sanitize_f32(src[y0, x1], op)
    c = _sanitize_f32(src[y1, x0], op)
    d = _sanitize_f32(src[y1, x1], op)
    if op == 0:
        dst[y, x] = wp.min(wp.min(a, b), wp.min(c, d))
    else:
        dst[y, x] = wp.max(wp.max(a, b), wp.max(c, d))


@wp.kernel
def reduce_i32_kernel(src: wp.array2d(dtype=wp.int32), op: int, dst: wp.array2d(dtype=wp.int32)):
    """As ``reduce_f32_kernel`` for integer maps (the Eq. 11 level map)."""
    y, x = wp.tid()
    y0 = 2 * y
    x0 = 2 * x
    y1 = wp.min(y0 + 1, src.shape[0] - 1)
    x1 = wp.min(x0 + 1, src.shape[1] - 1)
    a = src[y0, x0]
    b = src[y0, x1]
    c = src[y1, x0]
    d = src[y1, x1]
    if op == 0:
        dst[y, x] = wp.min(wp.min(a, b), wp.min(c, d))
    else:
        dst[y, x] = wp.max(wp.max(a, b), wp.max(c, d))


@wp.kernel
def abs_f32_kernel(src: wp.array2d(dtype=wp.float32), dst: wp.array2d(dtype=wp.float32)):
    y, x = wp.tid()
    dst[y, x] = wp.abs(src[y, x])


# ---------------------------------------------------------------------------------------------
# Host side
# ---------------------------------------------------------------------------------------------
def max_level(width: int, height: int) -> int:
    """Coarsest level of Eq. 11: ``floor(log2(min(W, H)))`` (0 for an image one pixel wide or high)."""
    width, height = _check_size(width, height)
    return int(min(width, height)).bit_length() - 1


def pyramid_shapes(width: int, height: int) -> list[tuple[int, int]]:
    """(rows, cols) of every level, finest first: halve with ceil until 1 x 1 (see the module doc)."""
    w, h = _check_size(width, height)
    shapes = [(h, w)]
    while w > 1 or h > 1:
        w, h = (w + 1) // 2, (h + 1) // 2
        shapes.append((h, w))
    return shapes


@dataclass
class Pyramid:
    """A min- or max-filtered mip-map: ``levels[l]`` is a ``wp.array2d`` of shape ``shapes[l]``
    (rows, cols); level 0 is the (sanitised) input at full resolution."""
    levels: list = field(default_factory=list)
    shapes: list = field(default_factory=list)
    op: str = "min"

    @property
    def num_levels(self) -> int:
        return len(self.levels)

    @property
    def width(self) -> int:
        return self.shapes[0][1]

    @property
    def height(self) -> int:
        return self.shapes[0][0]

    def level(self, l: int) -> np.ndarray:
        """Level ``l`` as a numpy array of shape (rows, cols)."""
        return self.levels[check_count(l, "level", 0, self.num_levels - 1)].numpy()   # 99: an IndexError

    def numpy(self) -> list[np.ndarray]:
        """Every level as a numpy array, finest first."""
        return [a.numpy() for a in self.levels]


def _check_size(width, height) -> tuple[int, int]:
    if not (is_int(width) and is_int(height)) or width < 1 or height < 1:   # None: int()'s TypeError
        raise WarpbwError(f"image size must be positive integers, got {width} x {height}")
    return int(width), int(height)


def _device_of(values, device):
    if device is not None:
        return wp.get_device(check_device(device))
    if isinstance(values, wp.array):
        return values.device
    return wp.get_device("cpu")


def _as_2d(values, dtype, width, height, device, name):
    """``values`` (numpy or wp.array, 2D or flat row-major with width/height) as a contiguous
    ``wp.array2d`` of ``dtype`` on ``device``; the input itself is never written."""
    if isinstance(values, wp.array):
        if values.ndim == 2 and (width is None or (values.shape[0], values.shape[1]) == (height, width)) \
                and values.dtype == dtype and values.device == device and values.is_contiguous:
            return values
        arr = values.numpy()
    else:
        arr = np.asarray(values)
        if arr.dtype.kind not in "biuf":   # strings: numpy's "could not convert" from the cast below
            raise WarpbwError(f"{name}: expected numbers, got {arr.dtype} values")
    if arr.ndim == 1:
        if width is None or height is None:
            raise WarpbwError(f"{name}: a flat buffer needs width and height")
        w, h = _check_size(width, height)
        if arr.size != w * h:
            raise WarpbwError(f"{name}: {arr.size} values do not make a {w} x {h} image")
        arr = arr.reshape(h, w)
    elif arr.ndim != 2:
        raise WarpbwError(f"{name}: expected a 2D (rows, cols) array or a flat buffer, got shape {arr.shape}")
    elif width is not None and height is not None and arr.shape != (int(height), int(width)):
        raise WarpbwError(f"{name}: shape {arr.shape} is not (height, width) = ({height}, {width})")
    if arr.size == 0:
        raise WarpbwError(f"{name}: empty image {arr.shape}")
    if dtype == wp.int32:
        if arr.dtype.kind == "f":
            raise WarpbwError(f"{name}: expected integers, got {arr.dtype}")
        if arr.dtype.kind in "iu" and arr.size and (arr.min() < -2**31 or arr.max() >= 2**31):
            raise WarpbwError(f"{name}: values do not fit in int32")
        arr = arr.astype(np.int32)
    else:
        arr = arr.astype(np.float32)
    return wp.array(np.ascontiguousarray(arr), dtype=dtype, device=device)


def image_level(b_p, coverage=None, width: int | None = None, height: int | None = None,
                device=None, nan_level: str = "finest"):
    """Eq. 11 level map, ``wp.array2d(dtype=int32)`` of shape (H, W), level 0 = finest.

    ``b_p``: image-space bandwidth in cycles/pixel, (H, W) or flat row-major with width/height.
    ``coverage``: same shape, nonzero where geometry covers the pixel (from a G-buffer:
    ``gb.material.numpy() >= 0``); None means every pixel is covered.  Uncovered pixels and
    ``b_p <= 0`` get ``max_level(W, H)``; ``+inf`` gives 0; NaN gives ``nan_level`` (module doc).
    """
    if nan_level not in NAN_LEVELS:
        raise WarpbwError(f"nan_level must be one of {NAN_LEVELS}, got {nan_level!r}")
    device = _device_of(b_p, device)
    bp = _as_2d(b_p, wp.float32, width, height, device, "b_p")
    h, w = bp.shape
    if coverage is None:
        cov = wp.full((h, w), 1, dtype=wp.int32, device=device)
    else:
        if not isinstance(coverage, wp.array) and np.asarray(coverage).dtype == np.bool_:
            coverage = np.asarray(coverage).astype(np.int32)
        elif isinstance(coverage, wp.array) and coverage.dtype == wp.bool:
            coverage = coverage.numpy().astype(np.int32)
        cov = _as_2d(coverage, wp.int32, w, h, device, "coverage")
    top = max_level(w, h)
    out = wp.empty((h, w), dtype=wp.int32, device=device)
    wp.launch(image_level_kernel, dim=(h, w), inputs=[bp, cov, top, 0 if nan_level == "finest" else top, out],
              device=device)
    return out


def build_pyramid(values, op: str = "min", device=None, *, width: int | None = None,
                  height: int | None = None) -> Pyramid:
    """Mip-map ``values`` with a min or max filter, any size, down to 1 x 1.

    ``values``: ``wp.array2d`` / numpy (H, W), or flat row-major with ``width``/``height``.  Integer
    inputs (level maps) stay int32; float inputs become float32 (NaN -> -inf for min, +inf for max).
    One kernel launch per level.  Level 0 is a copy: the pyramid never aliases the input.
    """
    if op not in OPS:
        raise WarpbwError(f"op must be 'min' or 'max', got {op!r}")
    code = OPS[op]
    device = _device_of(values, device)
    if isinstance(values, wp.array):
        integer = values.dtype in (wp.int32, wp.int64, wp.int16, wp.int8, wp.uint8, wp.uint16, wp.uint32,
                                  wp.bool)
    else:
        integer = np.asarray(values).dtype.kind in "iub"
    dtype = wp.int32 if integer else wp.float32
    base = _as_2d(values, dtype, width, height, device, "values")
    h, w = base.shape
    shapes = pyramid_shapes(w, h)
    if integer:
        level0 = wp.clone(base, device=device)
        kernel = reduce_i32_kernel
    else:
        level0 = wp.empty((h, w), dtype=wp.float32, device=device)
        wp.launch(sanitize_f32_kernel, dim=(h, w), inputs=[base, code, level0], device=device)
        kernel = reduce_f32_kernel
    levels = [level0]
    for shape in shapes[1:]:
        dst = wp.empty(shape, dtype=dtype, device=device)
        wp.launch(kernel, dim=shape, inputs=[levels[-1], code, dst], device=device)
        levels.append(dst)
    return Pyramid(levels=levels, shapes=shapes, op=op)


def level_pyramid(level_map, device=None, **kw) -> Pyramid:
    """The Eq. 11 level map mip-mapped with a MIN filter (a coarse texel is as fine as its finest pixel); the
    levels are integers (a float map of 1.5 was mip-mapped as floats)."""
    if isinstance(level_map, wp.array):
        floats = level_map.dtype in (wp.float16, wp.float32, wp.float64)
    else:
        floats = np.asarray(level_map).dtype.kind not in "iub"
    if floats:
        raise WarpbwError("level_map: expected integer levels (Eq. 11), got other numbers")
    return build_pyramid(level_map, "min", device, **kw)


def variance_pyramid(variance, device=None, **kw) -> Pyramid:
    """The per-pixel variance estimate mip-mapped with a MAX filter."""
    return build_pyramid(variance, "max", device, **kw)


def curvature_pyramid(curvature, device=None, *, absolute: bool = True, width: int | None = None,
                      height: int | None = None) -> Pyramid:
    """Screen-space curvature mip-mapped with a MAX filter.  With ``absolute`` (default) the max is
    taken over ``|curvature|``, so concave (negative) regions are not hidden by flat ones."""
    device = _device_of(curvature, device)
    if not check_flag(absolute, "curvature_pyramid: absolute"):   # "no" is truthy: |curvature| was taken
        return build_pyramid(curvature, "max", device, width=width, height=height)
    c = _as_2d(curvature, wp.float32, width, height, device, "curvature")
    a = wp.empty(c.shape, dtype=wp.float32, device=device)
    wp.launch(abs_f32_kernel, dim=c.shape, inputs=[c, a], device=device)
    return build_pyramid(a, "max", device)
