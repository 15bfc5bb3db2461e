"""Triangle meshes for the G-buffer: loading, smooth normals, mean curvature and its local magnitude.

Public functions:

- ``load_mesh(path, translate=(0, 0, 0), scale=1.0, rotate_y_deg=0.0) -> MeshData``: OBJ, PLY, STL, GLB
  (anything trimesh reads; a scene of several geometries is concatenated with its node transforms).
  The transform is applied in the order scale, then rotation about +Y, then translation.  Its mean curvature
  is derived on first use (``MeshData.mean_curvature``): only the bandwidth pass reads it.  A damaged file is a
  one-line ``WarpbwError`` naming its line or index where the format has one, not trimesh's words
  (``warpbw.io.mesh_files``: a PLY's header, a GLB's accessors, an OBJ's face indices, an ASCII STL's facets).
  Conventions of the file it reads: coordinates are the scene's (+Y up, as glTF and most OBJ exports; a Z-up file,
  as many STL and PLY scans are, lies on its side: only ``rotate_y`` turns a mesh, so export it Y-up; a mesh in
  millimetres in a scene in metres takes ``scale = 0.001``, and nothing else depends on its units).  Normals are
  derived, smooth, from the faces: the file's own (OBJ ``vn``) are not read, and coincident vertices are merged, so a
  hard edge (a cube's) shades rounded.  Triangles are two-sided (``warpbw.gbuffer``): a mesh wound inward throughout
  renders as wound outward; triangles wound against their neighbours are turned to match them, with a warning
  (``consistent_winding``).
- ``consistent_winding(vertices, faces, surface=None) -> (faces, turned, unorientable)``: faces wound against their
  neighbours turned to match them.
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
  area (shared with the device version, ``warpbw.mesh_normals``); ``CANCEL_REL``: below it a vertex's faces cancel
  (``load_mesh`` and ``normals_and_curvature`` refuse such a vertex, and so does the device version);
  ``cancelled_pose(count, first=None) -> str``, the words both versions refuse a pose in.
- ``boundary_neighbours(faces, nv) -> (on_boundary, x, y)``: the open boundary's vertices and their
  interior neighbours (x[k] on the boundary, y[k] interior), from the connectivity alone.
- ``normals_and_curvature(vertices, faces, surface=None) -> (normals (V, 3), H (V,))``: ``vertex_normals`` and
  ``mesh_mean_curvature`` for a mesh whose vertices moved (dynamic geometry, 002 Sec. 4.3: recomputed every
  frame, nothing cached; about 55 ms for the 70k-triangle bunny on one core, all numpy;
  ``warpbw.mesh_normals`` does it on the device); ``surface`` (``MeshData.surface``): the copies of a vertex
  split by a texture seam are one vertex of the surface, as ``load_mesh`` derives them.
- ``checked_faces(faces, nv, what="faces") -> (F, 3) int64``: the faces check every helper here runs, for
  callers that take faces from elsewhere (``warpbw.gbuffer.build_geometry``): triangles of integer (or
  integral float) indices into ``nv`` vertices, else a one-line ``WarpbwError`` naming ``what``.
- ``local_curvature(mean_curvature, faces, passes=CURVATURE_SMOOTHING_PASSES, surface=None) -> (V,)``: the
  curvature the bandwidth pass reads, |H| averaged over about two rings (12 ms on the bunny; ``warpbw.mesh_normals``
  does it on the device); ``surface`` as for ``normals_and_curvature``; at most ``CURVATURE_PASSES_MAX`` passes.
- ``checked_surface(surface, nv, what="surface") -> (V,) int64 | None``: a seam map's check (``MeshData.surface``):
  per vertex, an index in 0..nv-1 that is its own (the surface vertex of a seam's copies), else a one-line
  ``WarpbwError`` naming ``what``.

- ``mesh_triangles(path) -> int | None``: how many triangles a mesh file holds, from its header or its face lines
  (``warpbw.io.mesh_files.triangle_count``), without reading its geometry: None where it does not say, or the file
  does not open.

Class: ``MeshData`` (``surface``: the seam map, computed once at load).  Constants: ``CURVATURE_SMOOTHING_PASSES``,
``WINDING_FOLD_DEG``.
"""
from __future__ import annotations

import hashlib
import logging
import math
import threading
import warnings
from collections import OrderedDict
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np

from warpbw.errors import (FLOAT32_MAX, WarpbwError, check_coordinate_spacing, check_count, check_input_file,
                           check_path,
                           one_line, unit_directions)
from warpbw.io.mesh_files import (SUPPORTED, check_after_reading, check_before_reading, format_damage,
                                  read_failure, suffix_problem, triangle_count)

# A triangle whose doubled area is below this fraction of its longest squared edge is treated as
# degenerate (no cotangent weight, no area): sin of its largest angle is < 1e-12, so its
# cotangents would overflow the float64 sums of well-shaped neighbours.
DEGENERATE_REL_AREA = 1e-12
# Normal given to a vertex with no incident area (unreferenced or only degenerate faces): +Y, "up"
# in the project's world convention (../shared/DESIGN.md).
FALLBACK_NORMAL = (0.0, 1.0, 0.0)
# A vertex whose area-weighted normal sum is shorter than this share of the sum of its faces' (doubled) areas has no
# direction: its faces cancel to rounding (coincident triangles wound in opposite directions, a closed surface pressed
# flat).  On a 162-vertex icosphere pressed onto x, y or z = 0 the 16 rim vertices' float64 sums came out exactly 0
# at 5, 10 or 14 of them and at 1e-17 of the areas, in no particular direction, at the others (the next vertex: 1.0;
# the least on the bunny: 0.48; on the icosphere pressed to 1e-6 of its radius: 7.6e-6).
CANCEL_REL = 1e-12
# Lazy one-ring passes (x <- (x + one-ring mean) / 2) that average |H| into the curvature the bandwidth pass
# reads (local_curvature): an RMS reach of about two rings (the bunny's edge is about 2 px at the validation
# scenes' 256x256).  Bandwidth rank correlation per pixel on the bunny (examples/validate_bandwidth.py;
# warpbw.bandwidth docstring): 0.351 with the signed H, 0.419 with |H|, 0.492 after 4 passes, 0.516 after 8.
CURVATURE_SMOOTHING_PASSES = 8
# The most passes local_curvature takes (ours, a sanity bound): 65536 passes reach far beyond any mesh's smoothing
# worth having and take about 20 s on the bunny's device pass; 10**30 ran until stopped (session 79's API audit)
CURVATURE_PASSES_MAX = 1 << 16
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
    # (V,) int64: per vertex, the vertex it is one point of the surface with (the first of the copies a texture seam
    # split, which uv alone tell apart; its own index elsewhere), or None where no vertex is split.  Computed once at
    # load; warpbw.gbuffer.update_mesh (MeshSpec.surface) derives a deformed pose's normals and H through it.
    surface: np.ndarray | None = None
    # float64 (vertices, normals, faces, surface) for mean_curvature, dropped once it is derived: the surface's
    # vertices, normals and faces, and each vertex's surface vertex (None: the vertices are the surface's)
    _exact: tuple | None = field(default=None, repr=False, compare=False)

    @cached_property
    def mean_curvature(self) -> np.ndarray:
        """(V,) float32 mean curvature H, 1/(scene units), positive where convex (``mesh_mean_curvature``); the
        copies of a vertex split by a texture seam share the surface's H (``load_mesh``)."""
        verts, normals, faces, surface = (self._exact if self._exact is not None
                                          else (self.vertices, self.normals, self.faces, None))
        self._exact = None
        h = mesh_mean_curvature(verts, faces, normals)
        return np.ascontiguousarray(h if surface is None else h[surface], dtype=np.float32)


def _checked_vertices(vertices) -> np.ndarray:
    """``vertices`` as float64 (V, 3) when finite, else a one-line WarpbwError naming them (a NaN vertex gave its
    triangle's three vertices the fallback normal, without a word)."""
    try:
        v = np.asarray(vertices, dtype=np.float64)
    except (TypeError, ValueError):
        raise WarpbwError(f"vertices: expected an array of numbers of shape (V, 3), got {type(vertices).__name__}") \
            from None
    if v.ndim != 2 or v.shape[1] != 3:
        raise WarpbwError(f"vertices: expected shape (V, 3), got {v.shape}")
    bad = ~np.all(np.isfinite(v), axis=1)
    if bad.any():
        raise WarpbwError(f"vertices: {int(bad.sum())} of {len(v)} are NaN or infinite (first: vertex "
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
    whether its faces cancel (``CANCEL_REL``; a vertex without a face of any area does not): (V, 3), (V,) bool."""
    v = np.ldexp(v, -_exact_scale(v))
    p0, p1, p2 = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    fn = np.cross(p1 - p0, p2 - p0)  # |fn| = 2 * area, so the sum is area weighted
    n = np.stack([np.bincount(f.ravel(), weights=np.repeat(fn[:, k], 3), minlength=len(v)) for k in range(3)], -1)
    areas = np.bincount(f.ravel(), weights=np.repeat(np.linalg.norm(fn, axis=1), 3), minlength=len(v))
    return n, (areas > 0.0) & (np.linalg.norm(n, axis=1) <= CANCEL_REL * areas)


def cancelled_pose(count: int, first: int | None = None) -> str:
    """The words refusing a pose whose faces cancel at ``count`` vertices (``first``: the first, where known), as
    ``normals_and_curvature`` here and on the device (``warpbw.mesh_normals``) say them."""
    at = "" if first is None else f"; first: vertex {first}"
    return (f"{count} vertices have no normal: the triangles around them cancel (coincident triangles wound in "
            f"opposite directions, such as a closed surface pressed flat{at}); expected a pose whose surface has a "
            "direction at every vertex")


def vertex_normals(vertices, faces) -> np.ndarray:
    """Unit vertex normals (V, 3) float64: sum of incident face normals weighted by face area.  A vertex whose sum
    is zero gets ``FALLBACK_NORMAL``: one without incident area, or one whose faces cancel (coincident triangles
    wound in opposite directions; ``load_mesh`` and ``normals_and_curvature`` refuse those, ``CANCEL_REL``)."""
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


def local_curvature(mean_curvature, faces, passes: int = CURVATURE_SMOOTHING_PASSES, surface=None) -> np.ndarray:
    """The curvature c >= 0 that the bandwidth pass reads (002 Eq. 3) at each vertex, (V,) float32: |H|
    averaged over the vertex's neighbourhood by ``passes`` lazy one-ring passes, x <- (x + m) / 2, where m
    is the mean of x over the other two corners of every face incident to the vertex (an interior edge
    counts twice, once per face; a vertex without faces keeps its value).

    Why the magnitude, averaged (``warpbw.bandwidth`` docstring): on a scanned mesh H changes sign from
    vertex to vertex (32% of the bunny's edges join a convex to a concave vertex; neighbouring H correlate
    at 0.42), so the shading normal turns back and forth at the vertex scale.  A pixel sees how fast it
    turns, not which way: the signed H averaged cancels the bumps, the magnitude per vertex is noisy.
    A constant |H| (a sphere's 1 / r) is kept exactly; every value stays within the input's range.

    ``surface`` (``MeshData.surface``, None: every vertex its own): the copies of a vertex split by a texture seam
    are averaged as one vertex, over the faces on both sides, and each copy takes its value (each copy averaged over
    its own side's ring alone, and the two came out different on a surface whose |H| varies)."""
    passes = check_count(passes, "local_curvature: passes", 0, CURVATURE_PASSES_MAX)   # 2.7 ran as 2, "3" as 3
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
    surface = checked_surface(surface, nv, "local_curvature: surface")
    if surface is not None:
        f = surface[f]   # the seam's copies as their surface vertex: the others keep no faces
    # (to, from) for each face's six ordered corner pairs
    to = np.concatenate([f[:, 0], f[:, 1], f[:, 2], f[:, 1], f[:, 2], f[:, 0]])
    fr = np.concatenate([f[:, 1], f[:, 2], f[:, 0], f[:, 0], f[:, 1], f[:, 2]])
    deg = np.bincount(to, minlength=nv).astype(np.float64)
    has = deg > 0
    for _ in range(passes):
        m = np.bincount(to, weights=h[fr], minlength=nv)
        h = np.where(has, 0.5 * h + 0.5 * m / np.maximum(deg, 1.0), h)
    return (h if surface is None else h[surface]).astype(np.float32)


def checked_surface(surface, nv: int, what: str = "surface") -> np.ndarray | None:
    """``surface`` (a seam map, ``MeshData.surface``) as int64 (nv,), or None for None: per vertex an integer index
    in 0..nv-1 naming a vertex that names itself (the surface vertex of the copies a texture seam split), else a
    one-line WarpbwError naming ``what`` (a copy naming another copy would take a value that is never computed)."""
    if surface is None:
        return None
    s = np.asarray(surface)
    if s.shape != (nv,) or s.dtype.kind not in "iu":
        raise WarpbwError(f"{what}: expected an integer vertex index per vertex, shape ({nv},), got "
                          f"{s.dtype} values of shape {s.shape}")
    s = s.astype(np.int64)
    if nv and (s.min() < 0 or s.max() >= nv):
        raise WarpbwError(f"{what}: indices from {s.min()} to {s.max()}; expected vertices in 0..{nv - 1}")
    loose = s[s] != s
    if loose.any():
        i = int(np.argmax(loose))
        raise WarpbwError(f"{what}: {int(loose.sum())} vertices name a vertex that is not its own surface vertex "
                          f"(first: vertex {i} names {s[i]}, which names {s[s[i]]}); expected each seam's copies to "
                          "name one of them that names itself")
    return s


def normals_and_curvature(vertices, faces, surface=None) -> tuple[np.ndarray, np.ndarray]:
    """Unit area-weighted vertex normals (V, 3) and mean curvature H (V,), both float64, from the
    current vertex positions alone: what ``load_mesh`` derives, for a mesh deformed every frame.

    ``surface`` (``MeshData.surface``, the seam map computed at load; None: every vertex its own): the copies of a
    vertex split by a texture seam take the normal and H of the surface there, from the faces on both sides, as
    ``load_mesh`` gives them (each copy took its own side's faces alone: 5.9 degrees off on a 32-column sphere).
    Vertices whose faces cancel (a closed surface pressed flat; ``CANCEL_REL``) are refused, as ``load_mesh`` refuses
    them: they took the fallback normal, or a direction made of rounding, without a word.  No state is kept between
    calls (nothing is precomputed from an earlier pose).  The mesh is checked once (it was checked three times: by
    each function, and the normals again)."""
    v = _checked_vertices(vertices)
    f = checked_faces(faces, len(v))
    surface = checked_surface(surface, len(v))
    if surface is not None:
        f = surface[f]   # the seam's copies as their surface vertex, whose faces meet there
    sums, cancelled = _normal_sums(v, f)
    if cancelled.any():   # as load_mesh refuses them: they took the fallback normal, whatever the surface's direction
        raise WarpbwError("vertices: " + cancelled_pose(int(cancelled.sum()), int(np.argmax(cancelled))))
    normals = _unit_normals(sums)
    # unit_directions as mesh_mean_curvature(v, f, normals) applies it: the same H, to the last bit
    h = _mean_curvature(v, f, unit_directions(normals, "normals"))
    return (normals, h) if surface is None else (normals[surface], h[surface])


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
# A mesh whose largest coordinate is below this is merged at a power-of-two scale that brings it to [1, 2): trimesh
# merges vertices closer than an absolute 1e-8, and an icosphere of radius 1e-8 (a file in kilometres, or a
# micro-geometry in metres) kept 26 of its 642 vertices, rendered as a crude polyhedron without a word.  From 1e-3 up
# (1e-5 of the mesh's size at most) the merge is as it was.
MERGE_MIN_COORD = 1e-3
# Two faces sharing an edge whose third vertices lie closer than this, seen along the edge, fold onto each other
# (coincident copies, a pentagon drawn over a quad): their windings say nothing of each other's (consistent_winding).
# Faces of a smooth surface lie about 180 degrees apart, a cube's at 90.
WINDING_FOLD_DEG = 60.0
# Mesh files kept read and merged in memory (ours): a scene placing one mesh 20 times read it 20 times, 0.3 s each
# for the bunny (scene fuzzing, session 63).
MESH_CACHE_FILES = 4
# One mesh file read at a time in a process: the read turns the process's logging down around trimesh and puts it
# back, and two threads reading at once each put back the other's setting (logging's warnings stayed off for the
# rest of the process); the kept files' OrderedDict is one for every thread too.
_MESH_LOCK = threading.Lock()


def _check_float32(verts, path, when: str) -> None:
    """Refuse vertices (V, 3) beyond the float32 range, in which the kernels read them; ``when`` ends the
    phrase 'outside the float32 range' (e.g. ' after scale')."""
    n_big = int(np.count_nonzero(np.any(np.abs(verts) > FLOAT32_MAX, axis=1)))
    if n_big:
        raise WarpbwError(f"{path}: {n_big} vertices lie outside the float32 range{when} (expected coordinates "
                          f"within +-{FLOAT32_MAX:.4g})")


@dataclass(frozen=True)
class _Merged:
    """A mesh file as read, checked and merged, before its transform: vertices (float64, read-only, times
    ``2**-k``: merged at a power-of-two scale), faces (int64, read-only), the uv coordinates or None, ``k`` and the
    largest coordinate ``big``; ``surface``: per vertex, the index of its first copy among the vertices split by
    their uv alone (a texture seam: one point of the surface), or None where none are; ``turned`` and
    ``unorientable``: what ``consistent_winding`` did to its faces (``load_mesh`` warns of them)."""

    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray | None
    k: int
    big: float
    surface: np.ndarray | None = None
    turned: int = 0
    unorientable: int = 0


_MERGED: "OrderedDict[tuple, _Merged]" = OrderedDict()


def _merged_mesh(path: Path) -> _Merged:
    """``_read_merged(path)``, kept for the last ``MESH_CACHE_FILES`` files by their path and the digest of their
    bytes (a file rewritten since is read again, however soon)."""
    data = path.read_bytes()
    key = (str(path.resolve()), hashlib.blake2b(data, digest_size=16).digest())
    with _MESH_LOCK:
        if key in _MERGED:
            _MERGED.move_to_end(key)
            return _MERGED[key]
        merged = _read_merged(path, data)
        _MERGED[key] = merged
        while len(_MERGED) > MESH_CACHE_FILES:
            _MERGED.popitem(last=False)
        return merged


def _read_merged(path: Path, data: bytes) -> _Merged:
    """Read a mesh file with trimesh, refuse what is malformed (naming the file; ``data``, its bytes, for the checks
    before and after trimesh), and merge coincident vertices."""
    import trimesh

    check_before_reading(path, data)
    # trimesh logs tracebacks at WARNING (a facet normal it recomputes) that say nothing the user could act on
    was_disabled = logging.root.manager.disable
    logging.disable(logging.WARNING)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            mesh = trimesh.load_scene(str(path), process=False).to_mesh()
    except Exception as exc:  # trimesh raises ValueError, KeyError, IndexError... on malformed or unknown files
        raise WarpbwError(read_failure(path, data, exc)) from None
    finally:
        logging.disable(was_disabled)
    faces = np.asarray(getattr(mesh, "faces", np.zeros((0, 3))))
    verts = np.asarray(getattr(mesh, "vertices", np.zeros((0, 3))), dtype=np.float64)
    check_after_reading(path, data, len(faces), getattr(mesh.visual, "uv", None) is None)
    if faces.ndim != 2 or faces.shape[0] == 0 or faces.shape[1] != 3:
        raise WarpbwError(format_damage(path, data)
                          or f"{path}: no triangles found (expected a mesh with faces: {SUPPORTED})")
    if verts.ndim != 2 or verts.shape[1] != 3:   # an OBJ whose "v" lines hold two numbers: numpy's AxisError below
        raise WarpbwError(f"{path}: vertices read with {verts.shape[-1] if verts.ndim == 2 else 0} coordinates "
                          "each (expected x, y and z on every vertex line)")
    if faces.min() < 0 or faces.max() >= len(verts):
        raise WarpbwError(format_damage(path, data)
                          or f"{path}: faces reference vertices outside 0..{len(verts) - 1} (malformed mesh)")
    n_bad = int(np.count_nonzero(~np.all(np.isfinite(verts), axis=1)))
    if n_bad:
        raise WarpbwError(f"{path}: {n_bad} vertices have non-finite coordinates (expected finite numbers)")
    _check_float32(verts, path, "")  # before trimesh's vertex merge, which fails on them
    uv = getattr(mesh.visual, "uv", None)
    n_bad = 0 if uv is None else int(np.count_nonzero(~np.all(np.abs(np.asarray(uv, np.float64)) <= FLOAT32_MAX,
                                                             axis=-1)))   # NaN too
    if n_bad:   # the merge rounds them to integers (numpy's "invalid value encountered in cast"), and build_geometry
        # refused them as "meshes[0] uv", naming no file
        raise WarpbwError(f"{path}: {n_bad} vertices have texture coordinates (uv) that are not finite or lie outside "
                          f"the float32 range (expected finite numbers within +-{FLOAT32_MAX:.4g})")
    # trimesh merges vertices by rounding x * 10^8 to int64, which wraps beyond 9.2e10 and merged distinct
    # vertices (an icosphere of radius 1e12 kept 7 of its 162); larger meshes are merged at a power-of-two
    # scale (exact), so that the rounding stays in range
    big = float(np.abs(verts).max())
    k = math.ceil(math.log2(big / MERGE_MAX_COORD)) if big > MERGE_MAX_COORD else 0
    if 0.0 < big < MERGE_MIN_COORD:   # merged at [1, 2): the tolerance as a unit mesh's, relative to its size
        k = math.floor(math.log2(big))
    try:
        if k:
            mesh.vertices = np.ldexp(np.asarray(mesh.vertices, dtype=np.float64), -k)
        mesh.merge_vertices()
        mesh.remove_unreferenced_vertices()
    except Exception as exc:
        raise WarpbwError(f"{path}: malformed mesh ({one_line(exc)})") from None
    uv = getattr(mesh.visual, "uv", None)
    uv = np.array(uv, dtype=np.float32) if uv is not None and np.shape(uv) == (len(mesh.vertices), 2) else None
    surface = _seam_copies(mesh) if uv is not None else None
    faces = np.asarray(mesh.faces, dtype=np.int64)
    # the winding across a texture seam is the surface's: its copies are one vertex there
    faces, turned, unorientable = consistent_winding(mesh.vertices, faces, surface)
    out = _Merged(np.asarray(mesh.vertices, dtype=np.float64), faces, uv, k, big, surface, turned, unorientable)
    for a in (out.vertices, out.faces, out.uv, out.surface):
        if a is not None:
            a.flags.writeable = False
    return out


def consistent_winding(vertices, faces, surface=None) -> tuple[np.ndarray, int, int]:
    """Faces (F, 3) turned, where some are wound against their neighbours, so that every edge two faces share is
    walked once each way: ``(faces, turned, unorientable)``.  Each connected piece (faces joined by edges two of them
    share) keeps the winding of most of its faces, ties its first face's; ``turned`` counts the faces turned
    (vertices 1 and 2 swapped).  A piece no winding fits (a Moebius strip) is left as it is, and its faces are
    counted in ``unorientable``.  Edges of one face (a border) or of three or more (non-manifold) join nothing, nor do
    two faces that fold onto each other (their third vertices less than ``WINDING_FOLD_DEG`` apart seen along the
    edge: coincident copies, a pentagon drawn over a quad) or a face without area.  ``surface``
    (``MeshData.surface``): per vertex, the vertex of the surface it is a copy of, so that a texture seam's copies
    join the faces on both sides.  Smooth normals are sums of face normals: a face wound the other way subtracts its
    normal, and the normals along the border between the two windings came out up to 90 degrees off (or flipped),
    without a word (an icosphere with its +X half turned: a Lambert sphere under a light off by 0.25, its peak 0.8)."""
    v = _checked_vertices(vertices)
    faces = checked_faces(faces, len(v))
    keyed = faces if surface is None else checked_surface(surface, len(v))[faces]
    nv = len(v)
    a = keyed.reshape(-1)
    b = np.roll(keyed, -1, axis=1).reshape(-1)       # the directed edges (f0, f1), (f1, f2), (f2, f0), per face
    c = np.roll(keyed, -2, axis=1).reshape(-1)       # and the vertex across from each
    edge_face = np.repeat(np.arange(len(faces)), 3)
    key = np.minimum(a, b) * np.int64(nv) + np.maximum(a, b)
    order = np.argsort(key, kind="stable")
    key = key[order]
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    counts = np.diff(np.r_[starts, len(key)])
    e0, e1 = order[starts[counts == 2]], order[starts[counts == 2] + 1]   # manifold edges: exactly two faces
    against = (a[e0] < b[e0]) == (a[e1] < b[e1])     # both faces walk the edge the same way
    if not against.any():
        return faces, 0, 0
    # each face's third vertex, seen from the edge: perpendicular to it (at the exact scale, as _normal_sums)
    x = np.ldexp(v, -_exact_scale(v))
    p, q = x[a[e0]], x[b[e0]]
    along = (q - p) / np.maximum(np.linalg.norm(q - p, axis=1, keepdims=True), np.finfo(float).tiny)

    def across(e):
        w = x[c[e]] - p
        return w - np.sum(w * along, axis=1, keepdims=True) * along

    wa, wb = across(e0), across(e1)
    norm = np.linalg.norm(wa, axis=1) * np.linalg.norm(wb, axis=1)
    joined = np.sum(wa * wb, axis=1) < math.cos(math.radians(WINDING_FOLD_DEG)) * norm
    joined &= norm > 0.0
    fa, fb, against = edge_face[e0][joined], edge_face[e1][joined], against[joined]
    if not against.any():
        return faces, 0, 0
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    # node 2 f + p: face f in winding p (0 as stored, 1 turned); an edge joins the two faces' windings that agree
    F = len(faces)
    link = against.astype(np.int64)
    rows = np.r_[2 * fa, 2 * fa + 1]
    cols = np.r_[2 * fb + link, 2 * fb + (1 - link)]
    graph = coo_matrix((np.ones(len(rows), dtype=np.int8), (rows, cols)), shape=(2 * F, 2 * F))
    _, label = connected_components(graph, directed=False)
    kept, other = label[0::2], label[1::2]           # each face's class as stored and turned
    unorientable = kept == other                     # a loop of the piece turns a face into itself
    lo = np.minimum(kept, other)                     # the piece's two windings: classes lo and hi
    as_lo = kept == lo
    n_lo = np.bincount(lo[~unorientable], weights=as_lo[~unorientable], minlength=2 * F)
    n_all = np.bincount(lo[~unorientable], minlength=2 * F)
    first = np.full(2 * F, F - 1, dtype=np.int64)
    np.minimum.at(first, lo, np.arange(F))
    # the winding of most of the piece's faces (ties: its first face's)
    keep_lo = (2 * n_lo > n_all) | ((2 * n_lo == n_all) & as_lo[first])
    turn = ~unorientable & (as_lo != keep_lo[lo])
    out = faces.copy()
    out[turn] = out[turn][:, [0, 2, 1]]
    return out, int(turn.sum()), int(unorientable.sum())


def _seam_copies(mesh) -> np.ndarray | None:
    """Per vertex of a merged trimesh mesh with uv, the index of the first vertex at its position, or None where
    every vertex is its own: trimesh's merge keeps apart the vertices whose uv differ, and those are one point of the
    surface, written once per side of a texture seam (their smooth normal and H come from the faces on both sides).
    Positions are keyed as trimesh's merge keys them (``trimesh.grouping.merge_vertices``, at ``tol.merge``).  The
    file's own normals split nothing: trimesh 5.2 kept none of an OBJ's, a PLY's or a GLB's (tried), and the normals
    here are derived, smooth, from the faces."""
    import trimesh

    verts = np.asarray(mesh.vertices, dtype=np.float64)
    key = np.round(verts * 10.0 ** trimesh.util.decimal_to_digits(trimesh.tol.merge))
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    if len(first) == len(verts):
        return None
    return first[inverse.reshape(-1)].astype(np.int64)


def mesh_triangles(path) -> int | None:
    """How many triangles the mesh file ``path`` holds, read through a memory map (a file larger than memory
    costs none); None where its format does not say, or it does not open (``load_mesh`` says why)."""
    import mmap

    path = check_path(path, "mesh_triangles: path")   # an int was open()'s file descriptor: read, then closed
    try:
        with open(path, "rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as data:
            return triangle_count(path, data)
    except (OSError, ValueError):   # missing, a folder, empty (mmap's ValueError)
        return None


def load_mesh(path, translate=(0.0, 0.0, 0.0), scale: float = 1.0, rotate_y_deg: float = 0.0) -> MeshData:
    """Load a triangle mesh, apply x' = R_y(rotate_y_deg) (scale * x) + translate, and derive
    smooth normals (and, when first read, the mean curvature) in the transformed (world) frame.

    Coincident vertices are merged (STL stores none shared); vertices split by texture seams stay split, each with
    its uv, but take the smooth normal and H of the surface, from the faces on both sides of the seam (a uv layout
    changes neither; each copy saw only its own side's faces, 5.9 degrees off on a 32-column sphere).  The file
    is read and merged once while it stays as it is (``MESH_CACHE_FILES``): a scene that places one mesh many times
    reads it once.
    """
    path = check_input_file(path, f"a mesh: {SUPPORTED}")   # None too (check_path)
    problem = suffix_problem(path)
    if problem:
        raise WarpbwError(problem)
    if path.stat().st_size == 0:  # trimesh's answer depends on the suffix (for GLB: a face index out of bounds)
        raise WarpbwError(f"{path}: empty file (0 bytes): no triangles found (expected a mesh with faces: "
                          f"{SUPPORTED})")
    t, s, r = _check_transform(path, translate, scale, rotate_y_deg)
    merged = _merged_mesh(path)
    k, big = merged.k, merged.big
    verts = np.ldexp(merged.vertices, k) * s
    faces = merged.faces
    _, _, p0, p1, p2 = _face_geometry(verts, faces)
    if not np.any(np.linalg.norm(np.cross(p1 - p0, p2 - p0), axis=1) > 0.0):
        if k > 0:   # the merge rounds at 1e-8 of 2^k: finer detail collapsed (a vertex at 1e30 beside one at 1)
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
    surface = merged.surface
    # the surface: each seam's copies as one vertex (their first), so that its faces on both sides meet there
    s_verts, s_faces = (verts, faces) if surface is None else (verts, surface[faces])
    sums, cancelled = _normal_sums(s_verts, s_faces)
    if cancelled.any():   # they had the fallback normal (0, 1, 0), whatever the surface's direction
        i = int(np.argmax(cancelled))
        raise WarpbwError(f"{path}: {int(cancelled.sum())} vertices have no normal: the triangles around them cancel "
                          f"(coincident triangles wound in opposite directions, such as both sides of a sheet; first: "
                          f"vertex {i} at {tuple(round(float(x), 6) for x in verts[i])}); expected consistently wound "
                          "triangles (remove the oppositely wound copy)")
    normals = _unit_normals(sums)   # vertex_normals(s_verts, s_faces), from the sums just checked
    if merged.turned:
        warnings.warn(f"{path}: {merged.turned} of {len(faces)} triangles were wound against their neighbours (a "
                      "mesh exported with some faces flipped); turned to match them, since the smooth normals, sums of "
                      "the faces' normals, cancel where two windings meet", stacklevel=2)
    if merged.unorientable:
        warnings.warn(f"{path}: {merged.unorientable} of {len(faces)} triangles form a surface no winding fits (a "
                      "Moebius strip, or one whose sides are joined crosswise): their smooth normals flip somewhere "
                      "across it", stacklevel=2)
    uv = merged.uv
    return MeshData(
        path=str(path),
        vertices=np.ascontiguousarray(verts, dtype=np.float32),
        faces=np.ascontiguousarray(faces, dtype=np.int32),
        normals=np.ascontiguousarray(normals if surface is None else normals[surface], dtype=np.float32),
        uv=None if uv is None else np.ascontiguousarray(uv),
        surface=surface,
        _exact=(s_verts, normals, s_faces, surface),
    )
