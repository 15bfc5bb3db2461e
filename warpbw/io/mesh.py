"""Triangle meshes for the G-buffer: loading, smooth normals, mean curvature and its local magnitude.

Public functions:

- ``load_mesh(path, translate=(0, 0, 0), scale=1.0, rotate_y_deg=0.0) -> MeshData``: OBJ, PLY, STL, GLB
  (anything trimesh reads; a scene of several geometries is concatenated with its node transforms).
  The transform is applied in the order scale, then rotation about +Y, then translation.  Its mean curvature
  is derived on first use (``MeshData.mean_curvature``): only the bandwidth pass reads it.  A damaged file is a
  one-line ``WarpbwError`` naming its line or index where the format has one, not trimesh's words: a PLY's header
  (``_check_ply``), a GLB's or glTF's accessors and bufferViews (``_check_gltf``), before trimesh; an OBJ's face
  indices (``_obj_index_problem``: where trimesh stops, or would read another vertex or drop the texture
  coordinates) and an ASCII STL's facets (``_check_ascii_stl_read``: where trimesh stops or reads short).
- ``mesh_mean_curvature(vertices, faces, normals=None) -> (V,)``: mean curvature H = (k1 + k2) / 2 from the
  cotangent Laplace-Beltrami operator with mixed Voronoi areas (Meyer, Desbrun, Schroeder, Barr 2003,
  "Discrete Differential-Geometry Operators for Triangulated 2-Manifolds"), positive on a convex
  shape with outward normals (a sphere of radius r gives 1/r); ``normals`` None: ``vertex_normals``'.
- ``vertex_normals(vertices, faces) -> (V, 3)``: unit area-weighted vertex normals.

Every host helper checks its input first (a one-line ``WarpbwError``): vertices (V, 3) finite, faces (F, 3)
integer indices into them (a quad, a negative or an out-of-range index is refused, not wrapped or read as
another vertex).  Coordinates of any float64 magnitude work (1e200 or 1e-200): the geometry is computed at an
exact power-of-two scale, so the cross products cannot overflow or underflow.
- ``DEGENERATE_REL_AREA``, ``FALLBACK_NORMAL``: where a face stops counting, and a vertex's normal without
  area (shared with the device version, ``warpbw.mesh_normals``).
- ``boundary_neighbours(faces, nv) -> (on_boundary, x, y)``: the open boundary's vertices and their
  interior neighbours (x[k] on the boundary, y[k] interior), from the connectivity alone.
- ``normals_and_curvature(vertices, faces) -> (normals (V, 3), H (V,))``: ``vertex_normals`` and
  ``mesh_mean_curvature`` for a mesh whose vertices moved (dynamic geometry, 002 Sec. 4.3: recomputed every
  frame, nothing cached; about 55 ms for the 70k-triangle bunny on one core, all numpy;
  ``warpbw.mesh_normals`` does it on the device).
- ``checked_faces(faces, nv, what="faces") -> (F, 3) int64``: the faces check every helper here runs, for
  callers that take faces from elsewhere (``warpbw.gbuffer.build_geometry``): triangles of integer (or
  integral float) indices into ``nv`` vertices, else a one-line ``WarpbwError`` naming ``what``.
- ``local_curvature(mean_curvature, faces, passes=CURVATURE_SMOOTHING_PASSES) -> (V,)``: the curvature the
  bandwidth pass reads, |H| averaged over about two rings (12 ms on the bunny; ``warpbw.mesh_normals`` does
  it on the device).

Class: ``MeshData``.  Constant: ``CURVATURE_SMOOTHING_PASSES``.
"""
from __future__ import annotations

import hashlib
import json
import logging
import math
import re
import warnings
from collections import OrderedDict
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np

from warpbw.errors import (FLOAT32_MAX, WarpbwError, check_coordinate_spacing, check_count, check_input_file,
                           unit_directions)

# A triangle whose doubled area is below this fraction of its longest squared edge is treated as
# degenerate (no cotangent weight, no area): sin of its largest angle is < 1e-12, so its
# cotangents would overflow the float64 sums of well-shaped neighbours.
DEGENERATE_REL_AREA = 1e-12
# Normal given to a vertex with no incident area (unreferenced or only degenerate faces): +Y, "up"
# in the project's world convention (../shared/DESIGN.md).
FALLBACK_NORMAL = (0.0, 1.0, 0.0)
# Lazy one-ring passes (x <- (x + one-ring mean) / 2) that average |H| into the curvature the bandwidth pass
# reads (local_curvature): an RMS reach of about two rings (the bunny's edge is about 2 px at the validation
# scenes' 256x256).  Bandwidth rank correlation per pixel on the bunny (examples/validate_bandwidth.py;
# warpbw.bandwidth docstring): 0.351 with the signed H, 0.419 with |H|, 0.492 after 4 passes, 0.516 after 8.
CURVATURE_SMOOTHING_PASSES = 8
_SUPPORTED = "OBJ, PLY, STL or GLB"
# An OBJ face whose vertex index is 0 (OBJ counts from 1, and from -1 backwards): trimesh reads it as vertex 0,
# a different triangle from the one the file's author meant, so it is refused.
_OBJ_ZERO_INDEX = re.compile(rb"^[ \t]*f[ \t][^\n]*?(?<=[ \t])0(?:/\S*)?(?=\s|$)", re.M)
# An OBJ vertex line that is not 3 to 7 numbers (x y z [w], or x y z r g b [a]: colours as trimesh reads them),
# and nothing after them (trimesh reads no trailing comment): trimesh stopped in numpy's "could not be read to its
# end due to unmatched data".
_OBJ_NUMBER = rb"(?i:[-+]?(?:(?:\d+\.?\d*|\.\d+)(?:e[-+]?\d+)?|nan|inf(?:inity)?))"
_OBJ_BAD_VERTEX = re.compile(rb"^[ \t]*v[ \t](?![ \t]*(?:" + _OBJ_NUMBER + rb"[ \t]+){2,6}" + _OBJ_NUMBER
                             + rb"[ \t]*\r?$)[^\n]*", re.M)
# The indices of an OBJ face corner (v, v/vt, v//vn, v/vt/vn) that trimesh reads: the vertex's and the texture
# coordinate's (a normal's it drops when out of range, and warpbw derives its own), with the words and the lines
# defining what they index.  Each counts from 1, or back from -1: the last one defined so far (the OBJ format).
_OBJ_INDEXED = {b"v": ("face index", "vertices"), b"vt": ("face texture index", "texture coordinates")}
# A face line holding a minus sign, a negative index: found from the first face line on.
_OBJ_NEGATIVE_FACE = re.compile(rb"^f[ \t][^\n]*-", re.M)
# An OBJ face line of fewer than three vertices ("f 1 3", a line cut short): trimesh dropped it without a word.
_OBJ_SHORT_FACE = re.compile(rb"^[ \t]*f(?:[ \t]+\S+){0,2}[ \t]*\r?$", re.M)
# PLY property types and their sizes in bytes: the PLY format's char ... double (Turk 1994) and the sized names int8
# ... float64 that trimesh's reader also takes (trimesh/exchange/ply.py, _dtypes).
PLY_TYPE_BYTES = {"char": 1, "uchar": 1, "short": 2, "ushort": 2, "int": 4, "uint": 4, "float": 4, "double": 8,
                  "int8": 1, "uint8": 1, "int16": 2, "uint16": 2, "int32": 4, "uint32": 4, "int64": 8, "uint64": 8,
                  "float16": 2, "float32": 4, "float64": 8}
# The names trimesh's PLY reader looks for on the face element's list of vertex indices (_elements_to_kwargs).
PLY_FACE_INDEX_NAMES = ("vertex_indices", "vertex_index")
# A GLB (glTF 2.0's binary container, Khronos glTF 2.0 specification Sec. 4.4): a 12-byte header (magic, version,
# length), then chunks of an 8-byte head (the data's length, its type) and the data: JSON first, then BIN.
GLB_HEADER_BYTES, GLB_CHUNK_HEAD_BYTES = 12, 8
_GLB_MAGIC, _GLB_JSON, _GLB_BIN = b"glTF", b"JSON", b"BIN\0"
# glTF accessor component types and their sizes in bytes (glTF 2.0 Sec. 3.6.2.2: BYTE ... FLOAT; 5124 is none).
GLTF_COMPONENT_BYTES = {5120: 1, 5121: 1, 5122: 2, 5123: 2, 5125: 4, 5126: 4}
# glTF accessor types and their components per element (the same section; trimesh reads matrices unpadded).
GLTF_TYPE_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
# A binary STL: an 80-byte comment, a uint32 triangle count, then 50 bytes per triangle (an ASCII one starts "solid").
STL_HEADER_BYTES, STL_TRIANGLE_BYTES = 84, 50
# A line that is none of an ASCII STL's (solid and endsolid with a name, facet normal with anything after it: trimesh
# recomputes a normal it cannot read; outer loop, vertex and three numbers, endloop, endfacet, a blank line), or that
# holds a NUL byte: the first damaged line, named when trimesh stops or reads fewer triangles than the file holds.
_STL_DAMAGED_LINE = re.compile(
    rb"^(?!(?:\xef\xbb\xbf)?[ \t]*(?:(?:solid|endsolid|facet[ \t]+normal)(?:[ \t][^\n\0]*)?|outer[ \t]+loop|endloop"
    rb"|endfacet|vertex(?:[ \t]+" + _OBJ_NUMBER + rb"){3})?[ \t]*\r?$)[^\n]*", re.M | re.I)


@dataclass
class MeshData:
    """A loaded, transformed triangle mesh (world units).  ``mean_curvature`` is derived when first read
    (only the bandwidth pass needs it: 48 ms of the bunny's 0.66 s load, session 46), from the float64
    vertices and normals the load computed."""

    path: str
    vertices: np.ndarray  # (V, 3) float32
    faces: np.ndarray  # (F, 3) int32
    normals: np.ndarray  # (V, 3) float32 unit, smooth, area-weighted
    uv: np.ndarray | None = None  # (V, 2) float32
    # float64 (vertices, normals) for mean_curvature, dropped once it is derived
    _exact: tuple | None = field(default=None, repr=False, compare=False)

    @cached_property
    def mean_curvature(self) -> np.ndarray:
        """(V,) float32 mean curvature H, 1/(scene units), positive where convex (``mesh_mean_curvature``)."""
        verts, normals = self._exact if self._exact is not None else (self.vertices, self.normals)
        self._exact = None
        return np.ascontiguousarray(mesh_mean_curvature(verts, self.faces, normals), dtype=np.float32)


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def _checked_vertices(vertices, what: str = "vertices") -> np.ndarray:
    """``vertices`` as float64 (V, 3) when finite, else a one-line WarpbwError naming ``what`` (a NaN vertex gave
    its triangle's three vertices the fallback normal, without a word)."""
    try:
        v = np.asarray(vertices, dtype=np.float64)
    except (TypeError, ValueError):
        raise WarpbwError(f"{what}: expected an array of numbers of shape (V, 3), got {type(vertices).__name__}") \
            from None
    if v.ndim != 2 or v.shape[1] != 3:
        raise WarpbwError(f"{what}: expected shape (V, 3), got {v.shape}")
    bad = ~np.all(np.isfinite(v), axis=1)
    if bad.any():
        raise WarpbwError(f"{what}: {int(bad.sum())} of {len(v)} are NaN or infinite (first: vertex "
                          f"{int(np.argmax(bad))}); expected finite coordinates")
    return v


def checked_faces(faces, nv: int, what: str = "faces") -> np.ndarray:
    """``faces`` as int64 (F, 3) when they are triangles of integer indices in 0..nv-1, else a one-line
    WarpbwError naming ``what`` (an index out of range was numpy's IndexError, a negative one read a vertex from
    the end or failed in bincount, an (F, 4) array "weights and list don't have the same length")."""
    try:
        f = np.asarray(faces)
    except (TypeError, ValueError):   # ragged lists
        raise WarpbwError(f"{what}: expected integer vertex indices of shape (F, 3)") from None
    if f.size == 0 and f.ndim in (1, 2) and (f.ndim == 1 or f.shape[1] == 3):
        return np.zeros((0, 3), dtype=np.int64)   # no faces: [] or an empty (0, 3) array
    if f.dtype.kind not in "iuf" or (f.dtype.kind == "f" and not np.all(np.isfinite(f) & (f == np.round(f)))):
        raise WarpbwError(f"{what}: expected integer vertex indices, got {f.dtype} values")
    if f.ndim != 2 or f.shape[1] != 3:
        raise WarpbwError(f"{what}: expected triangles, shape (F, 3), got {f.shape}"
                          + (" (triangulate polygons first)" if f.ndim == 2 and f.shape[1] > 3 else ""))
    lo, hi = f.min(), f.max()
    if lo < 0 or hi >= nv:
        out = int(np.count_nonzero((f < 0) | (f >= nv)))
        raise WarpbwError(f"{what}: {out} vertex indices lie outside 0..{nv - 1} (the {nv} vertices; got {lo:.0f} to "
                          f"{hi:.0f})")
    return f.astype(np.int64)


def _exact_scale(v: np.ndarray) -> int:
    """The power of two ``e`` such that ``v * 2^-e`` has its largest coordinate in [0.5, 1): an exact scaling,
    under which the cross products of 1e200 coordinates (inf, then NaN normals) or 1e-200 ones (0) stay finite."""
    big = float(np.abs(v).max()) if v.size else 0.0
    return math.frexp(big)[1] if big > 0.0 else 0


def _face_geometry(vertices: np.ndarray, faces: np.ndarray):
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    p0, p1, p2 = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return v, f, p0, p1, p2


def _normal_sums(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per vertex, the area-weighted sum of its faces' normals (at the exact scale ``_exact_scale``), and
    whether a face with area touches it: (V, 3), (V,) bool."""
    v = np.ldexp(v, -_exact_scale(v))
    p0, p1, p2 = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    fn = np.cross(p1 - p0, p2 - p0)  # |fn| = 2 * area, so the sum is area weighted
    n = np.stack([np.bincount(f.ravel(), weights=np.repeat(fn[:, k], 3), minlength=len(v)) for k in range(3)], -1)
    has_area = np.any(fn != 0.0, axis=1)
    touched = np.bincount(f[has_area].ravel(), minlength=len(v)) > 0
    return n, touched


def vertex_normals(vertices, faces) -> np.ndarray:
    """Unit vertex normals (V, 3) float64: sum of incident face normals weighted by face area.  A vertex whose sum
    is zero gets ``FALLBACK_NORMAL``: one without incident area, or one whose faces cancel (coincident triangles
    wound in opposite directions; ``load_mesh`` refuses those)."""
    v = _checked_vertices(vertices)
    return _unit_normals(_normal_sums(v, checked_faces(faces, len(v)))[0])


def _unit_normals(sums: np.ndarray) -> np.ndarray:
    """``_normal_sums``' sums scaled to unit length; ``FALLBACK_NORMAL`` where a sum is zero."""
    length = np.linalg.norm(sums, axis=1, keepdims=True)
    ok = length[:, 0] > 0.0
    return np.where(ok[:, None], sums / np.where(length > 0.0, length, 1.0), np.asarray(FALLBACK_NORMAL))


def mesh_mean_curvature(vertices, faces, normals=None) -> np.ndarray:
    """Mean curvature per vertex (V,) float64, H = -(Laplace-Beltrami(x) . n) / 2.

    Cotangent weights and mixed Voronoi areas (Meyer et al. 2003). Vertices on an open boundary get
    the mean of their interior neighbours' H (0 if they have none); vertices without area get 0.
    ``normals`` (V, 3) are scaled to unit length; None derives them (``vertex_normals``).  (None was read as a NaN
    normal, and every H came out 0: the unit icosphere's is 1.)
    """
    vertices = _checked_vertices(vertices)
    faces = checked_faces(faces, len(vertices))
    if normals is None:
        nrm = _unit_normals(_normal_sums(vertices, faces)[0])   # vertex_normals', the mesh already checked
    else:
        try:
            nrm = np.asarray(normals, dtype=np.float64)
        except (TypeError, ValueError):
            raise WarpbwError(f"normals: expected an array of numbers of shape (V, 3), got "
                              f"{type(normals).__name__}") from None
        if nrm.shape != vertices.shape:
            raise WarpbwError(f"normals: expected one per vertex, shape {vertices.shape}, got {nrm.shape}")
        nrm = unit_directions(nrm, "normals")
    return _mean_curvature(vertices, faces, nrm)


def _mean_curvature(vertices: np.ndarray, faces: np.ndarray, nrm: np.ndarray) -> np.ndarray:
    """``mesh_mean_curvature`` of checked float64 vertices, int64 faces and unit normals."""
    e_scale = _exact_scale(vertices)   # H is computed at an exact scale and scaled back (H ~ 1 / length)
    v, f, p0, p1, p2 = _face_geometry(np.ldexp(vertices, -e_scale), faces)
    nv = len(v)
    # edge k is opposite corner k
    e0, e1, e2 = p2 - p1, p0 - p2, p1 - p0
    dbl_area = np.linalg.norm(np.cross(e2, -e1), axis=1)
    sq = np.stack([np.sum(e0 * e0, 1), np.sum(e1 * e1, 1), np.sum(e2 * e2, 1)], 1)
    good = dbl_area > DEGENERATE_REL_AREA * sq.max(axis=1)
    safe = np.where(good, dbl_area, 1.0)
    cot = np.stack([np.sum(e2 * -e1, 1), np.sum(e0 * -e2, 1), np.sum(e1 * -e0, 1)], 1) / safe[:, None]
    cot = np.where(good[:, None], cot, 0.0)

    # Laplacian numerator L_i = sum_j (cot a_ij + cot b_ij) (x_j - x_i): edge opposite corner k joins
    # corners k+1 and k+2.
    lap = np.zeros((nv, 3))
    edges_opp = (e0, e1, e2)
    for k in range(3):  # three corners of every triangle at once
        a, b = f[:, (k + 1) % 3], f[:, (k + 2) % 3]
        w = cot[:, k:k + 1] * edges_opp[k]  # edges_opp[k] = x_b - x_a
        for c in range(3):
            lap[:, c] += np.bincount(a, weights=w[:, c], minlength=nv)
            lap[:, c] -= np.bincount(b, weights=w[:, c], minlength=nv)

    # mixed Voronoi area of each corner
    area = 0.5 * dbl_area
    obtuse_at = cot < 0.0  # angle at corner > 90 degrees
    any_obtuse = obtuse_at.any(axis=1)
    # corner k: incident edges are opposite corners k+1 and k+2
    vor = np.stack(
        [(sq[:, (k + 1) % 3] * cot[:, (k + 1) % 3] + sq[:, (k + 2) % 3] * cot[:, (k + 2) % 3]) / 8.0 for k in range(3)],
        1,
    )
    corner_area = np.where(any_obtuse[:, None], np.where(obtuse_at, area[:, None] / 2.0, area[:, None] / 4.0), vor)
    corner_area = np.where(good[:, None], corner_area, 0.0)
    a_mixed = np.bincount(f.ravel(), weights=corner_area.ravel(), minlength=nv)

    dot = np.sum(lap * nrm, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        h = np.where(a_mixed > 0.0, -dot / (4.0 * a_mixed), 0.0)
    h = np.ldexp(np.where(np.isfinite(h), h, 0.0), -e_scale)

    # open boundary: the one-sided Laplacian is mostly tangential, so borrow from interior neighbours
    on_boundary, x, y = boundary_neighbours(f, nv)
    if on_boundary.any():
        s = np.bincount(x, weights=h[y], minlength=nv)
        c = np.bincount(x, minlength=nv)
        h = np.where(on_boundary, np.where(c > 0, s / np.maximum(c, 1), 0.0), h)
    return h


def boundary_neighbours(faces, nv: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The mesh's open boundary, from its connectivity alone: ``(on_boundary (V,) bool, x, y)`` with
    x[k] a boundary vertex and y[k] an interior vertex sharing an edge with it (each such pair once per
    direction it occurs in); a boundary edge belongs to one face only.  ``faces`` (F, 3) must index 0..nv-1 (an
    index beyond wrapped into another edge's key, a plausible but wrong boundary)."""
    nv = check_count(nv, "nv", 0)
    f = checked_faces(faces, nv)
    all_edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    uniq, counts = _unique_edges(all_edges, nv)
    on_boundary = np.zeros(nv, dtype=bool)
    on_boundary[uniq[counts == 1].ravel()] = True
    a, b = uniq[:, 0], uniq[:, 1]
    xs, ys = [], []
    for x, y in ((a, b), (b, a)):
        take = on_boundary[x] & ~on_boundary[y]
        xs.append(x[take])
        ys.append(y[take])
    return on_boundary, np.concatenate(xs), np.concatenate(ys)


def _unique_edges(edges: np.ndarray, nv: int):
    """``np.unique(edges, axis=0, return_counts=True)`` for (E, 2) vertex pairs in 0..nv-1, through a
    1-D int64 key a * nv + b (same lexicographic order; 11 ms against 130 ms on the bunny)."""
    keys, counts = np.unique(edges[:, 0] * np.int64(nv) + edges[:, 1], return_counts=True)
    return np.stack([keys // nv, keys % nv], axis=1), counts


def local_curvature(mean_curvature, faces, passes: int = CURVATURE_SMOOTHING_PASSES) -> np.ndarray:
    """The curvature c >= 0 that the bandwidth pass reads (002 Eq. 3) at each vertex, (V,) float32: |H|
    averaged over the vertex's neighbourhood by ``passes`` lazy one-ring passes, x <- (x + m) / 2, where m
    is the mean of x over the other two corners of every face incident to the vertex (an interior edge
    counts twice, once per face; a vertex without faces keeps its value).

    Why the magnitude, averaged (``warpbw.bandwidth`` docstring): on a scanned mesh H changes sign from
    vertex to vertex (32% of the bunny's edges join a convex to a concave vertex; neighbouring H correlate
    at 0.42), so the shading normal turns back and forth at the vertex scale.  A pixel sees how fast it
    turns, not which way: the signed H averaged cancels the bumps, the magnitude per vertex is noisy.
    A constant |H| (a sphere's 1 / r) is kept exactly; every value stays within the input's range."""
    passes = check_count(passes, "local_curvature: passes", 0)   # 2.7 ran as 2 and "3" as 3
    try:
        h = np.abs(np.asarray(mean_curvature, dtype=np.float64))
    except (TypeError, ValueError):
        raise WarpbwError("local_curvature: mean_curvature: expected an array of numbers, one per vertex") from None
    if h.ndim != 1:
        raise WarpbwError(f"local_curvature: mean_curvature: expected one value per vertex, shape (V,), got {h.shape}")
    bad = ~(h <= FLOAT32_MAX)   # NaN too (all came back NaN); float32 out: 1e39 came back inf
    if bad.any():
        raise WarpbwError(f"local_curvature: mean_curvature: {int(bad.sum())} of {len(h)} values are NaN, infinite or "
                          f"beyond float32 (expected finite values within +-{FLOAT32_MAX:.4g})")
    nv = len(h)
    f = checked_faces(faces, nv, "local_curvature: faces")
    # (to, from) for each face's six ordered corner pairs
    to = np.concatenate([f[:, 0], f[:, 1], f[:, 2], f[:, 1], f[:, 2], f[:, 0]])
    fr = np.concatenate([f[:, 1], f[:, 2], f[:, 0], f[:, 0], f[:, 1], f[:, 2]])
    deg = np.bincount(to, minlength=nv).astype(np.float64)
    has = deg > 0
    for _ in range(passes):
        m = np.bincount(to, weights=h[fr], minlength=nv)
        h = np.where(has, 0.5 * h + 0.5 * m / np.maximum(deg, 1.0), h)
    return h.astype(np.float32)


def normals_and_curvature(vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    """Unit area-weighted vertex normals (V, 3) and mean curvature H (V,), both float64, from the
    current vertex positions alone: what ``load_mesh`` derives, for a mesh deformed every frame.

    No state is kept between calls (nothing is precomputed from an earlier pose).  The mesh is checked once (it
    was checked three times: by each function, and the normals again)."""
    v = _checked_vertices(vertices)
    f = checked_faces(faces, len(v))
    normals = _unit_normals(_normal_sums(v, f)[0])
    # unit_directions as mesh_mean_curvature(v, f, normals) applies it: the same H, to the last bit
    return normals, _mean_curvature(v, f, unit_directions(normals, "normals"))


def _check_transform(path: Path, translate, scale, rotate_y_deg):
    try:
        t = np.asarray(translate, dtype=np.float64)
    except (TypeError, ValueError):   # "abc" was numpy's "could not convert string to float"
        t = np.full(1, np.nan)
    if t.shape != (3,) or not np.all(np.isfinite(t)):
        raise WarpbwError(f"{path}: translate {translate!r} is not 3 finite numbers")
    try:
        if isinstance(scale, (bool, np.bool_)) or isinstance(rotate_y_deg, (bool, np.bool_)):
            raise TypeError   # True was read as scale 1
        s = float(scale)
        r = float(rotate_y_deg)
    except (TypeError, ValueError):
        raise WarpbwError(f"{path}: scale {scale!r} / rotate_y_deg {rotate_y_deg!r} must be numbers") from None
    if not (math.isfinite(s) and s > 0.0):
        raise WarpbwError(f"{path}: scale {scale!r} must be a finite number > 0")
    if not math.isfinite(r):
        raise WarpbwError(f"{path}: rotate_y_deg {rotate_y_deg!r} must be finite")
    return t, s, r


# the largest coordinate trimesh's vertex merge is given (its int64 rounding at 1e-8 wraps beyond 9.2e10)
MERGE_MAX_COORD = 1e9
# Mesh files kept read and merged in memory (ours): a scene placing one mesh 20 times read it 20 times, 0.3 s each
# for the bunny (scene fuzzing, session 63).
MESH_CACHE_FILES = 4


def _check_float32(verts, path, when: str) -> None:
    """Refuse vertices (V, 3) beyond the float32 range, in which the kernels read them; ``when`` ends the
    phrase 'outside the float32 range' (e.g. ' after scale')."""
    n_big = int(np.count_nonzero(np.any(np.abs(verts) > FLOAT32_MAX, axis=1)))
    if n_big:
        raise WarpbwError(f"{path}: {n_big} vertices lie outside the float32 range{when} (expected coordinates "
                          f"within +-{FLOAT32_MAX:.4g})")


@dataclass(frozen=True)
class _PlyElement:
    """An element of a PLY header: its name, row count, the header line declaring it, and its properties (name ->
    (type, the list's count type or None))."""

    name: str
    count: int
    line: int
    props: dict


def _ply_header(path: Path, data: bytes) -> tuple[bool, list, int]:
    """The header of a PLY file (``data``, the bytes of ``path``) as trimesh's reader takes it: whether the body is
    ASCII, its elements (``_PlyElement``) and where the body starts.  What trimesh would stop on in its own words (a
    header cut short: "list index out of range"; an unknown type: "('float128')") or skip without a word (a property
    line of another shape: its column read as the next property's) is a one-line WarpbwError naming the line."""
    end = re.search(rb"(?<!\S)end_header(?!\S)", data)
    if end is None:
        raise WarpbwError(f"{path}: PLY header cut short (no 'end_header' line): truncated or corrupt")
    newline = data.find(b"\n", end.end())
    body = len(data) if newline < 0 else newline + 1
    lines = data[:data.rfind(b"\n", 0, end.start()) + 1].split(b"\n")[:-1]   # the lines before end_header's
    if not lines or b"ply" not in lines[0].lower():
        raise WarpbwError(f"{path}: not a PLY file (expected 'ply' on its first line)")
    if len(lines) < 2:
        raise WarpbwError(f"{path}:2: PLY header has no 'format' line (expected 'format ascii 1.0' or a binary one)")
    elements: dict[str, _PlyElement] = {}
    for number, raw in enumerate(lines[2:], start=3):
        try:
            words = raw.decode("utf-8").split()
        except UnicodeDecodeError:
            raise WarpbwError(f"{path}:{number}: PLY header line is not UTF-8 text: corrupt") from None
        said = " ".join(words)
        if not words:   # trimesh indexed the line's first word
            raise WarpbwError(f"{path}:{number}: blank line in the PLY header (expected element, property, comment "
                              "... lines up to 'end_header')")
        if "element" in words[0]:   # trimesh's test: the word holds "element"
            count = words[2] if len(words) == 3 else ""
            if not re.fullmatch(r"\d+", count):
                raise WarpbwError(f"{path}:{number}: PLY element line {said!r} (expected 'element NAME COUNT', COUNT "
                                  "a whole number 0 or more)")
            elements[words[1]] = _PlyElement(words[1], int(count), number, {})
        elif "property" in words[0]:
            elements_so_far = list(elements.values())
            if not elements_so_far:
                raise WarpbwError(f"{path}:{number}: PLY property line {said!r} before any element line")
            if len(words) == 5 and "list" in words[1]:
                types, name = (words[3], words[2]), words[4]
            elif len(words) == 3 and words[1] != "list":
                types, name = (words[1], None), words[2]
            else:   # trimesh skipped the line, and read its column as the next property's
                raise WarpbwError(f"{path}:{number}: PLY property line {said!r} (expected 'property TYPE NAME' or "
                                  "'property list COUNT_TYPE TYPE NAME')")
            for kind in types:
                if kind is not None and kind not in PLY_TYPE_BYTES:
                    raise WarpbwError(f"{path}:{number}: PLY property type {kind!r} unknown (expected one of "
                                      f"{', '.join(PLY_TYPE_BYTES)})")
            elements_so_far[-1].props[name] = types
    return b"ascii" in lines[1].lower(), list(elements.values()), body


def _check_ply_geometry(path: Path, ascii_body: bool, elements: list) -> None:
    """Refuse a PLY whose vertices lack x, y or z (trimesh's bare KeyError "('y')") or whose faces lack a list of
    vertex indices under a name trimesh looks for ("cannot access local variable 'faces'"; a binary file's only
    list property it takes whatever its name)."""
    named = {e.name: e for e in elements}
    vertex, face = named.get("vertex"), named.get("face")
    for axis in "xyz" if vertex is not None and vertex.count else "":
        if axis not in vertex.props:
            raise WarpbwError(f"{path}:{vertex.line}: PLY vertex element has no {axis!r} property (expected x, y "
                              "and z)")
    if face is None or not face.count:
        return
    lists = [name for name, (_, count_type) in face.props.items() if count_type is not None]
    if not (set(lists) & set(PLY_FACE_INDEX_NAMES) or (not ascii_body and len(face.props) == 1 and lists)):
        raise WarpbwError(f"{path}:{face.line}: PLY face element has no list property of vertex indices "
                          f"({' or '.join(map(repr, PLY_FACE_INDEX_NAMES))})")


def _check_ply(path: Path, data: bytes) -> None:
    """Refuse a PLY (``data``, the bytes of ``path``) whose header is damaged (``_ply_header``,
    ``_check_ply_geometry``) or declares more rows than its body holds: an ASCII body of another number of rows (trimesh
    read a file cut short as the faces it kept, and took a face count of 2147483647 on 80 faces, without a word), a
    binary one shorter than its rows take at the least (each list empty)."""
    ascii_body, elements, start = _ply_header(path, data)
    _check_ply_geometry(path, ascii_body, elements)
    said = ", ".join(f"{e.count} {e.name}" for e in elements)
    if ascii_body:
        rows = sum(1 for line in data[start:].splitlines() if line.strip())
        want = sum(e.count for e in elements)
        if rows != want:
            raise WarpbwError(f"{path}: ASCII PLY header declares {want} rows ({said}) but its body holds {rows}: "
                              "truncated or corrupt")
        return
    least = sum(e.count * sum(PLY_TYPE_BYTES[count_type or kind] for kind, count_type in e.props.values())
                for e in elements)
    if least > len(data) - start:
        raise WarpbwError(f"{path}: binary PLY header declares {said} rows (at least {least} bytes) but its body "
                          f"holds {len(data) - start} bytes: truncated or corrupt")


def _check_obj_lines(path: Path, data: bytes) -> None:
    """Refuse an OBJ (``data``, the bytes of ``path``) vertex line that is not 3 to 7 numbers (``_OBJ_BAD_VERTEX``), a
    face with vertex index 0 (``_OBJ_ZERO_INDEX``) and a face of fewer than three vertices (``_OBJ_SHORT_FACE``),
    naming the line."""
    for pattern, problem in (
            (_OBJ_BAD_VERTEX, lambda text: f"vertex line {text[:60]!r} (expected 'v x y z': three numbers, optionally "
                                           "a w or a colour, and nothing after them)"),
            (_OBJ_ZERO_INDEX, lambda text: "a face has vertex index 0 (OBJ indices count from 1, or back from -1)"),
            (_OBJ_SHORT_FACE, lambda text: f"face line {text[:60]!r} has {len(text.split()) - 1} vertices (expected "
                                           "3 or more; a line cut short?)")):
        m = pattern.search(data)
        if m is not None:
            line = data.count(b"\n", 0, m.start()) + 1
            raise WarpbwError(f"{path}:{line}: {problem(m.group(0).strip().decode('utf-8', 'replace'))}; "
                              "malformed mesh")


def _obj_corner_problem(text: bytes, kind: bytes, so_far: int, total: int) -> str | None:
    """What is wrong with one index of an OBJ face corner as written (``text``), into the items of ``kind`` (b"v",
    b"vt": ``_OBJ_INDEXED``), ``so_far`` of them defined before its face and ``total`` in the file; None when trimesh
    reads the item the file means."""
    (what, noun), keyword, shown = _OBJ_INDEXED[kind], f"'{kind.decode()}' line", text.decode("utf-8", "replace")
    try:
        i = int(text)
    except ValueError:
        return f"{what} {shown!r} is not a whole number"
    if i == 0:
        return f"{what} 0 (OBJ indices count from 1, or back from -1)"
    expected = f"expected 1 to {total}, or -1 to -{so_far} counting back"
    if i > total:
        return f"{what} {shown} is past the file's {total} {noun} ({expected})"
    if -i > so_far:
        return f"{what} {shown} counts back past the {so_far} {noun} defined before it ({expected})"
    if i < 0 and so_far < total:
        return (f"{what} {shown} counts back from the {so_far} {noun} defined so far, but trimesh counts back from the "
                f"file's {total}: another one (expected positive indices, or negative ones after the last {keyword})")
    return None


def _obj_index_problem(path: Path, data: bytes) -> str | None:
    """The first face corner of an OBJ (``data``, the bytes of ``path``) whose vertex or texture index, as written,
    lies outside those defined (trimesh's int64 parse made 99999999999999999999 "index 9223372036854775806"), or
    counts back from those defined so far where more follow (trimesh counts back from the file's last one: another
    vertex, without a word), with its line; else None.  A loop over the lines, run where trimesh failed or found no
    texture coordinates, or a face counts back before a definition (``_obj_may_count_back_early``): not on every
    load."""
    lines = data.split(b"\n")
    firsts = [line.split(None, 1)[:1] for line in lines]
    total = {kind: firsts.count([kind]) for kind in _OBJ_INDEXED}
    so_far = dict.fromkeys(total, 0)
    for number, (line, first) in enumerate(zip(lines, firsts), start=1):
        if first and first[0] in so_far:
            so_far[first[0]] += 1
        if first != [b"f"]:
            continue
        for corner in line.split()[1:]:
            for text, kind in zip(corner.split(b"/"), _OBJ_INDEXED):
                problem = text and _obj_corner_problem(text, kind, so_far[kind], total[kind])
                if problem:
                    return f"{path}:{number}: {problem}; malformed mesh"
    return None


def _obj_may_count_back_early(data: bytes) -> bool:
    """Whether an OBJ (``data``) has a vertex or texture coordinate defined after its first face, and a face with a
    negative index: the case a relative index may mean another item than trimesh reads (``_obj_index_problem``
    decides).  Found with trimesh's own markers ("\\nv ", "\\nf "), without a pass over every line."""
    first_face = 0 if data.startswith(b"f ") else data.find(b"\nf ")
    if first_face < 0 or max(data.rfind(b"\nv "), data.rfind(b"\nvt ")) < first_face:
        return False
    return _OBJ_NEGATIVE_FACE.search(data, first_face) is not None


def _stl_damage(path: Path, data: bytes) -> str | None:
    """What is wrong with an STL file (``data``, the bytes of ``path``) trimesh found no triangles in: an ASCII one
    that does not end in "endsolid" (cut short), or a binary one whose length is not what its triangle count says
    (cut short, bytes appended, the count damaged; trimesh then read it as ASCII); else None."""
    size, head = len(data), data[:STL_HEADER_BYTES]
    if head.lstrip(b" \t\r\n\xef\xbb\xbf")[:5].lower() == b"solid":   # ASCII
        if b"endsolid" not in data[-4096:].lower():
            return f"{path}: ASCII STL that does not end in 'endsolid': truncated or corrupt"
        return None
    start = data[:4096]
    if b"\0" not in start and re.search(rb"facet[ \t]+normal", start, re.I):   # text after all: its first line lost
        return f"{path}: ASCII STL that does not start with 'solid': cut at its start or corrupt"
    if size < STL_HEADER_BYTES:
        return None
    count = int.from_bytes(head[80:84], "little")
    want = STL_HEADER_BYTES + STL_TRIANGLE_BYTES * count
    if size == want:
        return None
    return (f"{path}: binary STL header says {count} triangles ({STL_HEADER_BYTES} + {STL_TRIANGLE_BYTES} x {count} "
            f"= {want} bytes) but the file is {size} bytes: truncated or corrupt")


def _stl_read_as_ascii(data: bytes) -> bool:
    """Whether trimesh reads an STL (``data``) as ASCII: it starts with "solid" and is not as long as a binary STL
    of the triangle count in its bytes 80 to 84 (trimesh tries binary first)."""
    head = data[:STL_HEADER_BYTES]
    binary = len(head) == STL_HEADER_BYTES and len(data) == STL_HEADER_BYTES + STL_TRIANGLE_BYTES * int.from_bytes(
        head[80:], "little")
    return not binary and head.lstrip(b" \t\r\n\xef\xbb\xbf")[:5].lower() == b"solid"


def _stl_damaged_line(data: bytes) -> tuple[int, str] | None:
    """The first damaged line of an ASCII STL (``data``; ``_STL_DAMAGED_LINE``): its number and what it holds, or
    None.  A pass over the file, run only where trimesh stopped or fell short."""
    m = _STL_DAMAGED_LINE.search(data) if _stl_read_as_ascii(data) else None
    if m is None:
        return None
    return data.count(b"\n", 0, m.start()) + 1, m.group(0).strip(b" \t\r").decode("utf-8", "replace")[:50]


def _stl_line_problem(path: Path, data: bytes) -> str | None:
    """An ASCII STL's first damaged line (``_stl_damaged_line``) named with what was expected there, or None."""
    damaged = _stl_damaged_line(data)
    if damaged is None:
        return None
    number, text = damaged
    expected = ("'vertex x y z': three numbers" if text[:6].lower() == "vertex" else
                "solid, facet normal, outer loop, vertex, endloop, endfacet or endsolid")
    return f"{path}:{number}: ASCII STL line {text!r} (expected {expected}): corrupt"


def _check_ascii_stl_read(path: Path, data: bytes, triangles: int) -> None:
    """Refuse an ASCII STL (``data``, the bytes of ``path``) trimesh read ``triangles`` from where its 'vertex' lines
    make another number, or its 'endfacet' lines say another, or that holds NUL bytes: trimesh reads the numbers after
    every 'vertex' up to the first that does not parse, and dropped whole facets without a word (a zeroed run: 76 of
    80).  Counted in the bytes as they are first, lower-cased only where that falls short."""
    if b"\0" not in data and data.count(b"vertex") == 3 * triangles and data.count(b"endfacet") == triangles:
        return
    low = data.lower()
    vertices, ends, nul = low.count(b"vertex"), low.count(b"endfacet"), b"\0" in data
    if nul or vertices != 3 * triangles or ends != triangles:
        number, text = _stl_damaged_line(data) or ("", "")
        raise WarpbwError(_stl_damage(path, data) or (
            f"{path}{f':{number}' if number else ''}: ASCII STL read as {triangles} triangles, but it has {ends} "
            f"'endfacet' and {vertices} 'vertex' lines{' and NUL bytes' if nul else ''}"
            f"{f' (first damaged line: {text!r})' if number else ''}: truncated or corrupt"))


def _gltf_document(path: Path, data: bytes) -> tuple[dict, list] | None:
    """The JSON document of a glTF file (``data``, the bytes of ``path``: a GLB, or a .gltf's text) and the length of
    each buffer as trimesh's reader holds it: a GLB's BIN chunks in turn, None for one read from a URI (not checked
    here).  None where the JSON does not parse or the GLB's first chunk is not JSON: trimesh's message says that.  A
    GLB chunk longer than the bytes after its head is refused (trimesh: "chunk was not expected length!")."""
    if path.suffix.lower() == ".gltf":
        text, chunks = data, []
    elif data[:4] == _GLB_MAGIC and data[16:20] == _GLB_JSON:
        start = GLB_HEADER_BYTES + GLB_CHUNK_HEAD_BYTES
        text = data[start:start + int.from_bytes(data[12:16], "little")]
        chunks, pos = [], start + len(text)
        while pos + GLB_CHUNK_HEAD_BYTES <= len(data):
            size, kind = int.from_bytes(data[pos:pos + 4], "little"), data[pos + 4:pos + 8]
            pos += GLB_CHUNK_HEAD_BYTES
            if pos + size > len(data):
                raise WarpbwError(f"{path}: GLB chunk {len(chunks) + 1} declares {size} bytes but {len(data) - pos} "
                                  "follow its head: truncated or corrupt")
            chunks.append(size if kind == _GLB_BIN else None)
            pos += size
    else:
        return None
    try:
        doc = json.loads(text)
    except (ValueError, UnicodeDecodeError):
        return None
    if not isinstance(doc, dict) or not isinstance(doc.get("buffers", []), list):
        return None
    bins = iter([size for size in chunks if size is not None])
    lengths = []
    for buffer in doc.get("buffers", []):   # trimesh: a buffer with a URI reads it, one without the next BIN chunk
        if isinstance(buffer, dict) and "uri" in buffer:
            lengths.append(None)
        elif (size := next(bins, None)) is not None:
            lengths.append(size)
    return doc, lengths + list(bins)


def _gltf_whole(path: Path, item: dict, key: str, what: str, default=None, least: int = 0) -> int:
    """``item[key]`` (``default`` when absent) when a whole number >= ``least``, else a one-line WarpbwError naming
    ``what`` (trimesh indexed lists with it: a negative one read another item, a float failed in Python's words)."""
    value = item.get(key, default)
    if value is None:
        raise WarpbwError(f"{path}: glTF {what} has no {key!r}")
    if isinstance(value, bool) or not isinstance(value, int) or value < least:
        raise WarpbwError(f"{path}: glTF {what}'s {key} {value!r} is not a whole number {least} or more")
    return value


def _check_gltf_views(path: Path, views: list, buffer_bytes: list) -> list:
    """Refuse a glTF bufferView that names a buffer the file lacks or passes its end (trimesh: "list index out of
    range", a bare AssertionError); the views' lengths in bytes."""
    lengths = []
    for i, view in enumerate(views):
        what = f"bufferView {i}"
        buffer = _gltf_whole(path, view, "buffer", what)
        start, size = _gltf_whole(path, view, "byteOffset", what, 0), _gltf_whole(path, view, "byteLength", what)
        if buffer >= len(buffer_bytes):
            raise WarpbwError(f"{path}: glTF {what} names buffer {buffer}, which the file does not hold (it has "
                              f"{len(buffer_bytes)})")
        held = buffer_bytes[buffer]
        if held is not None and start + size > held:
            raise WarpbwError(f"{path}: glTF {what} (bytes {start} to {start + size}) passes the end of buffer "
                              f"{buffer} ({held} bytes): truncated or corrupt")
        lengths.append(size)
    return lengths


def _check_gltf_accessors(path: Path, accessors: list, views: list, view_bytes: list) -> None:
    """Refuse a glTF accessor that names a bufferView the file lacks, has an unknown type, or whose elements pass its
    bufferView's end (trimesh: "list index out of range", a bare KeyError ('VEC7'), numpy's "cannot reshape")."""
    for i, acc in enumerate(accessors):
        what = f"accessor {i}"
        if "bufferView" not in acc:   # zeros, or data an extension or a sparse block supplies
            continue
        v = _gltf_whole(path, acc, "bufferView", what)
        if v >= len(views):
            raise WarpbwError(f"{path}: glTF {what} names bufferView {v}, which the file does not hold (it has "
                              f"{len(views)})")
        component, kind = acc.get("componentType"), acc.get("type")
        for key, value, known in (("componentType", component, GLTF_COMPONENT_BYTES),
                                  ("type", kind, GLTF_TYPE_COMPONENTS)):
            if isinstance(value, bool) or value not in known:
                raise WarpbwError(f"{path}: glTF {what}'s {key} {value!r} unknown (expected one of "
                                  f"{', '.join(map(str, known))})")
        count, start = _gltf_whole(path, acc, "count", what), _gltf_whole(path, acc, "byteOffset", what, 0)
        element = GLTF_COMPONENT_BYTES[component] * GLTF_TYPE_COMPONENTS[kind]
        stride = _gltf_whole(path, views[v], "byteStride", f"bufferView {v}", element, 1)
        end = start + (count - 1) * stride + element if count else start
        if end > view_bytes[v]:
            every = f", one every {stride} bytes" if stride != element else ""
            raise WarpbwError(f"{path}: glTF {what} ({count} {kind} of {element} bytes from byte {start}{every}) "
                              f"passes the end of bufferView {v} ({view_bytes[v]} bytes): truncated or corrupt")


def _check_gltf(path: Path, data: bytes) -> None:
    """Refuse a GLB or glTF (``data``, the bytes of ``path``) whose accessors or bufferViews reach past what it holds
    (``_check_gltf_views``, ``_check_gltf_accessors``), naming the index, before trimesh reads it."""
    parsed = _gltf_document(path, data)
    if parsed is None:
        return
    doc, buffer_bytes = parsed
    views, accessors = doc.get("bufferViews", []), doc.get("accessors", [])
    if not (isinstance(views, list) and isinstance(accessors, list)
            and all(isinstance(item, dict) for item in views + accessors)):
        return   # not a layout trimesh reads either: its message names it
    _check_gltf_accessors(path, accessors, views, _check_gltf_views(path, views, buffer_bytes))


@dataclass(frozen=True)
class _Merged:
    """A mesh file as read, checked and merged, before its transform: vertices (float64, read-only, times
    ``2**-k``: merged at a power-of-two scale), faces (int64, read-only), the uv coordinates or None, ``k`` and the
    largest coordinate ``big``."""

    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray | None
    k: int
    big: float


_MERGED: "OrderedDict[tuple, _Merged]" = OrderedDict()


def _merged_mesh(path: Path) -> _Merged:
    """``_read_merged(path)``, kept for the last ``MESH_CACHE_FILES`` files by their path and the digest of their
    bytes (a file rewritten since is read again, however soon)."""
    data = path.read_bytes()
    key = (str(path.resolve()), hashlib.blake2b(data, digest_size=16).digest())
    if key in _MERGED:
        _MERGED.move_to_end(key)
        return _MERGED[key]
    merged = _read_merged(path, data)
    _MERGED[key] = merged
    while len(_MERGED) > MESH_CACHE_FILES:
        _MERGED.popitem(last=False)
    return merged


def _read_failure(path: Path, data: bytes, exc: Exception) -> str:
    """The message for a file (``data``, the bytes of ``path``) trimesh stopped on with ``exc`` after the checks
    before it passed: the damage where an STL's check names it, else trimesh's words without a cause they do not give
    (a GLB's "list index out of range" was "a reference to something it does not hold", an accessor's bufferView)."""
    named = {".stl": lambda path, data: _stl_damage(path, data) or _stl_line_problem(path, data),
             ".obj": _obj_index_problem}.get(path.suffix.lower(), lambda path, data: None)
    problem = named(path, data)
    if problem:
        return problem
    if isinstance(exc, IndexError) and "out of bounds for axis 0" in str(exc):   # numpy's, trimesh indexing an array
        return f"{path}: an index in the file lies outside the array it indexes ({_one_line(exc)}); malformed mesh"
    return f"{path}: malformed or unsupported mesh file (trimesh: {_one_line(exc)}); expected {_SUPPORTED}"


def _read_merged(path: Path, data: bytes) -> _Merged:
    """Read a mesh file with trimesh, refuse what is malformed (naming the file; ``data``, its bytes, for the checks
    before and after trimesh), and merge coincident vertices."""
    import trimesh

    if path.suffix.lower() == ".obj":
        _check_obj_lines(path, data)
        problem = _obj_index_problem(path, data) if _obj_may_count_back_early(data) else None
        if problem:
            raise WarpbwError(problem)
    elif path.suffix.lower() == ".ply":
        _check_ply(path, data)
    elif path.suffix.lower() in (".glb", ".gltf"):
        _check_gltf(path, data)
    # trimesh logs tracebacks at WARNING (a facet normal it recomputes) that say nothing the user could act on
    was_disabled = logging.root.manager.disable
    logging.disable(logging.WARNING)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            mesh = trimesh.load_scene(str(path), process=False).to_mesh()
    except Exception as exc:  # trimesh raises ValueError, KeyError, IndexError... on malformed or unknown files
        raise WarpbwError(_read_failure(path, data, exc)) from None
    finally:
        logging.disable(was_disabled)
    faces = np.asarray(getattr(mesh, "faces", np.zeros((0, 3))))
    verts = np.asarray(getattr(mesh, "vertices", np.zeros((0, 3))), dtype=np.float64)
    if path.suffix.lower() == ".stl" and _stl_read_as_ascii(data):
        _check_ascii_stl_read(path, data, len(faces))
    if faces.ndim != 2 or faces.shape[0] == 0 or faces.shape[1] != 3:
        stl = _stl_damage(path, data) if path.suffix.lower() == ".stl" else None
        raise WarpbwError(stl or f"{path}: no triangles found (expected a mesh with faces: {_SUPPORTED})")
    if verts.ndim != 2 or verts.shape[1] != 3:   # an OBJ whose "v" lines hold two numbers: numpy's AxisError below
        raise WarpbwError(f"{path}: vertices read with {verts.shape[-1] if verts.ndim == 2 else 0} coordinates "
                          "each (expected x, y and z on every vertex line)")
    if faces.min() < 0 or faces.max() >= len(verts):
        raise WarpbwError((_obj_index_problem(path, data) if path.suffix.lower() == ".obj" else None)
                          or f"{path}: faces reference vertices outside 0..{len(verts) - 1} (malformed mesh)")
    if path.suffix.lower() == ".obj" and getattr(mesh.visual, "uv", None) is None and b"vt " in data:
        problem = _obj_index_problem(path, data)   # trimesh drops every texture coordinate for one out of range
        if problem:
            raise WarpbwError(problem)
    n_bad = int(np.count_nonzero(~np.all(np.isfinite(verts), axis=1)))
    if n_bad:
        raise WarpbwError(f"{path}: {n_bad} vertices have non-finite coordinates (expected finite numbers)")
    _check_float32(verts, path, "")  # before trimesh's vertex merge, which fails on them
    # trimesh merges vertices by rounding x * 10^8 to int64, which wraps beyond 9.2e10 and merged distinct
    # vertices (an icosphere of radius 1e12 kept 7 of its 162); larger meshes are merged at a power-of-two
    # scale (exact), so that the rounding stays in range
    big = float(np.abs(verts).max())
    k = math.ceil(math.log2(big / MERGE_MAX_COORD)) if big > MERGE_MAX_COORD else 0
    try:
        if k:
            mesh.vertices = np.asarray(mesh.vertices, dtype=np.float64) * 2.0**-k
        mesh.merge_vertices()
        mesh.remove_unreferenced_vertices()
    except Exception as exc:
        raise WarpbwError(f"{path}: malformed mesh ({_one_line(exc)})") from None
    uv = getattr(mesh.visual, "uv", None)
    uv = np.array(uv, dtype=np.float32) if uv is not None and np.shape(uv) == (len(mesh.vertices), 2) else None
    out = _Merged(np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64), uv, k, big)
    for a in (out.vertices, out.faces, out.uv):
        if a is not None:
            a.flags.writeable = False
    return out


def load_mesh(path, translate=(0.0, 0.0, 0.0), scale: float = 1.0, rotate_y_deg: float = 0.0) -> MeshData:
    """Load a triangle mesh, apply x' = R_y(rotate_y_deg) (scale * x) + translate, and derive
    smooth normals (and, when first read, the mean curvature) in the transformed (world) frame.

    Coincident vertices are merged (STL stores none shared); vertices split by texture seams stay split.  The file
    is read and merged once while it stays as it is (``MESH_CACHE_FILES``): a scene that places one mesh many times
    reads it once.
    """
    path = check_input_file(path, f"a mesh: {_SUPPORTED}")   # None too (check_path)
    if path.stat().st_size == 0:  # trimesh's answer depends on the suffix (for GLB: a face index out of bounds)
        raise WarpbwError(f"{path}: empty file (0 bytes): no triangles found (expected a mesh with faces: "
                          f"{_SUPPORTED})")
    t, s, r = _check_transform(path, translate, scale, rotate_y_deg)
    merged = _merged_mesh(path)
    k, big = merged.k, merged.big
    verts = merged.vertices * 2.0**k * s
    faces = merged.faces
    _, _, p0, p1, p2 = _face_geometry(verts, faces)
    if not np.any(np.linalg.norm(np.cross(p1 - p0, p2 - p0), axis=1) > 0.0):
        if k:   # the merge rounds at 1e-8 of 2^k: finer detail collapsed (a vertex at 1e30 beside one at 1)
            raise WarpbwError(f"{path}: every triangle collapses when vertices closer than {1e-8 * 2.0**k:.3g} are "
                              f"merged (coordinates reach {big:.3g}: detail finer than about 1e-17 of the largest "
                              "coordinate is lost; expected a mesh of one scale)")
        raise WarpbwError(f"{path}: every triangle has zero area (expected a mesh with a surface to render)")
    a = math.radians(r)
    ca, sa = math.cos(a), math.sin(a)
    # right-handed rotation about +Y: x' = x cos a + z sin a, z' = -x sin a + z cos a
    x, z = verts[:, 0].copy(), verts[:, 2].copy()
    verts[:, 0] = x * ca + z * sa
    verts[:, 2] = -x * sa + z * ca
    size = float(np.linalg.norm(verts.max(axis=0) - verts.min(axis=0)))
    verts += t
    _check_float32(verts, path, " after scale, rotate_y and translate")
    # a translate so far that the mesh's triangles collapse (at 1e16 in float64) was blamed on the file below; the
    # frame's own check (warpbw.gbuffer.check_reach) refuses the same spacing in float32
    check_coordinate_spacing(float(np.abs(verts).max()), size, f"a mesh of diagonal {size:.3g}",
                             f"{path} (after scale, rotate_y and translate)")
    sums, touched = _normal_sums(verts, faces)
    cancelled = touched & ~np.any(sums != 0.0, axis=1)
    if cancelled.any():   # they had the fallback normal (0, 1, 0), whatever the surface's direction
        i = int(np.argmax(cancelled))
        raise WarpbwError(f"{path}: {int(cancelled.sum())} vertices have no normal: the triangles around them cancel "
                          f"(coincident triangles wound in opposite directions, such as both sides of a sheet; first: "
                          f"vertex {i} at {tuple(round(float(x), 6) for x in verts[i])}); expected consistently wound "
                          "triangles (remove the oppositely wound copy)")
    normals = _unit_normals(sums)   # vertex_normals(verts, faces), from the sums just checked
    uv = merged.uv
    return MeshData(
        path=str(path),
        vertices=np.ascontiguousarray(verts, dtype=np.float32),
        faces=np.ascontiguousarray(faces, dtype=np.int32),
        normals=np.ascontiguousarray(normals, dtype=np.float32),
        uv=None if uv is None else np.ascontiguousarray(uv),
        _exact=(verts, normals),
    )
