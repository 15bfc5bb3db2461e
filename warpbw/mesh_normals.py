"""Smooth vertex normals and mean curvature of a deforming triangle mesh, on the device (002 Sec. 4.3).

Public:
    ``MeshTopology`` / ``mesh_topology(indices, first, count, device, surface=None)``   one mesh's faces and open
                                          boundary, from its connectivity alone (built once: a deformation keeps
                                          it), with the copies of a vertex a texture seam split as one vertex
    ``MeshShading`` / ``normals_and_curvature(points, topology, device, out)``  normals (V, 3) and H (V,) from the
                                          current vertex positions
    ``local_curvature(curvature, topology, device, passes, out)``  |H| averaged over the neighbourhood: the
                                          curvature the bandwidth pass reads (``warpbw.io.mesh.local_curvature``)
    Their kernels: ``face_terms_kernel``, ``cancelled_kernel``, ``vertex_finish_kernel``, ``boundary_sum_kernel``,
    ``boundary_mean_kernel`` (normals and H), ``one_ring_sum_kernel``, ``lazy_average_kernel``,
    ``magnitude_kernel`` (``local_curvature``), ``seam_copy_kernel``, ``seam_copy_scalar_kernel`` (both)

Their arrays are checked against the topology (shape, dtype, device) before any launch: the kernels index them by
vertex without bounds, and an ``out`` of 3 vertices for 162 was written past its end (the call returned, the process
aborted later), 10 points for 162 vertices read garbage.  The face kernel counts the faces with a vertex that is not
finite, and ``normals_and_curvature`` refuses them in one line (its neighbours got the fallback normal, and a
made-up H, without a word); so it refuses vertices whose faces cancel (a pose that presses a closed surface flat:
the rim took the fallback normal, up to 180 degrees off the surface's), as ``warpbw.io.mesh.load_mesh`` does.

The formulas are :mod:`warpbw.io.mesh`'s, which computes the same on the host when a mesh is loaded:
area-weighted vertex normals; mean curvature H = -(Laplace-Beltrami(x) . n) / 2 from cotangent weights and
mixed Voronoi areas (Meyer, Desbrun, Schroeder, Barr 2003), positive on a convex shape with outward normals;
vertices on an open boundary take the mean H of their interior neighbours.  The device version serves a mesh
deformed every frame, where the host version (numpy on one core) took about a third of the frame
(examples/dynamic_geometry.py).  Positions are float32; the per-face terms and their per-vertex sums are
float64, as on the host: the cotangent Laplacian is a small difference of large terms.

Small kernels: per face (the face normal, the cotangent weights and the corner areas, summed into
the vertices with atomic adds), per vertex (whether the faces cancel; normalise, divide), and per boundary pair
(the interior neighbours' mean); and for ``local_curvature``, per face (the one-ring sums) and per vertex (the lazy
average, dividing by the ring counts ``mesh_topology`` derives once), once per pass: 2.8 ms for 8 passes on the
bunny on the CPU (3.7 ms when the counts were re-summed every pass; a gather over each vertex's ring in
compressed rows, without atomics, took 6.7 ms in one launch per pass and 10.5 ms in tiles over threads).
Seams: a mesh whose uv split vertices (``warpbw.io.mesh.MeshData.surface``, the map computed at load) is
summed over its surface, each seam's copies as one vertex (the faces on both sides meet there), and one launch
over the copies then hands each the values of its surface vertex, as ``warpbw.io.mesh.load_mesh`` gives them
(each copy summed its own side's faces alone: 5.9 degrees off on a 32-column sphere, the fallback normal at the
poles); a mesh without seams (the bunny) launches nothing more.
Atomic adds are atomic on a GPU; on the CPU a launch runs on one thread, so these
launches are never split over threads (``warpbw.launch.launch_tiled`` would race on the sums).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from warpbw.errors import INT32_MAX, WarpbwError, check_count, check_device, check_warp_array
from warpbw.io import mesh as host_mesh
from warpbw.io.mesh import boundary_neighbours

# The host's (warpbw.io.mesh): a face whose doubled area is below this fraction of its longest squared edge
# adds no cotangent weight and no area; a vertex without incident area gets this normal.
DEGENERATE_REL_AREA = wp.constant(wp.float64(host_mesh.DEGENERATE_REL_AREA))
FALLBACK_NORMAL = wp.constant(wp.vec3(*host_mesh.FALLBACK_NORMAL))
# below this share of the summed (doubled) face areas, a vertex's normal sum has no direction: its faces cancel
CANCEL_REL = wp.constant(wp.float64(host_mesh.CANCEL_REL))


@wp.kernel(module="unique", enable_backward=False)
def face_terms_kernel(points: wp.array(dtype=wp.vec3), faces: wp.array(dtype=wp.int32), first: int,
                      n_sum: wp.array(dtype=wp.vec3d), lap: wp.array(dtype=wp.vec3d),
                      area: wp.array(dtype=wp.float64), n_len: wp.array(dtype=wp.float64),
                      counts: wp.array(dtype=wp.int32)):
    """One face's share of its corners' normal (area-weighted), Laplacian numerator
    sum_j (cot a_ij + cot b_ij)(x_j - x_i) and mixed Voronoi area (Meyer et al. 2003, Sec. 3.3-3.4); a face with
    a corner that is not finite adds nothing and is counted in ``counts[0]``; ``n_len`` sums the lengths of the
    face normals summed (``cancelled_kernel``)."""
    t = wp.tid()
    i0 = faces[3 * t] - first
    i1 = faces[3 * t + 1] - first
    i2 = faces[3 * t + 2] - first
    p0 = wp.vec3d(points[i0 + first])
    p1 = wp.vec3d(points[i1 + first])
    p2 = wp.vec3d(points[i2 + first])
    # squares of float32 coordinates cannot overflow float64: only NaN or inf reads as not finite
    if not wp.isfinite(wp.dot(p0, p0) + wp.dot(p1, p1) + wp.dot(p2, p2)):
        wp.atomic_add(counts, 0, 1)
        return
    e0 = p2 - p1                      # edge k is opposite corner k
    e1 = p0 - p2
    e2 = p1 - p0
    fn = wp.cross(e2, -e1)            # |fn| = twice the area: the sum is area-weighted
    wp.atomic_add(n_sum, i0, fn)
    wp.atomic_add(n_sum, i1, fn)
    wp.atomic_add(n_sum, i2, fn)
    dbl = wp.length(fn)
    wp.atomic_add(n_len, i0, dbl)
    wp.atomic_add(n_len, i1, dbl)
    wp.atomic_add(n_len, i2, dbl)
    sq0 = wp.dot(e0, e0)
    sq1 = wp.dot(e1, e1)
    sq2 = wp.dot(e2, e2)
    if dbl > DEGENERATE_REL_AREA * wp.max(sq0, wp.max(sq1, sq2)):
        c0 = wp.dot(e2, -e1) / dbl    # cotangent of the angle at corner k
        c1 = wp.dot(e0, -e2) / dbl
        c2 = wp.dot(e1, -e0) / dbl
        # the edge opposite corner k joins corners k+1 and k+2, edges_opp[k] = x_(k+2) - x_(k+1)
        w0 = c0 * e0
        w1 = c1 * e1
        w2 = c2 * e2
        wp.atomic_add(lap, i1, w0)
        wp.atomic_sub(lap, i2, w0)
        wp.atomic_add(lap, i2, w1)
        wp.atomic_sub(lap, i0, w1)
        wp.atomic_add(lap, i0, w2)
        wp.atomic_sub(lap, i1, w2)
        a = wp.float64(0.5) * dbl
        zero = wp.float64(0.0)
        if c0 < zero or c1 < zero or c2 < zero:   # obtuse: half the area to the obtuse corner, a quarter to each other
            q = wp.float64(0.25) * a
            a0 = q
            a1 = q
            a2 = q
            if c0 < zero:
                a0 = q + q
            if c1 < zero:
                a1 = q + q
            if c2 < zero:
                a2 = q + q
            wp.atomic_add(area, i0, a0)
            wp.atomic_add(area, i1, a1)
            wp.atomic_add(area, i2, a2)
        else:                                     # Voronoi area of each corner (Meyer et al. Eq. 7)
            eighth = wp.float64(0.125)
            wp.atomic_add(area, i0, eighth * (sq1 * c1 + sq2 * c2))
            wp.atomic_add(area, i1, eighth * (sq2 * c2 + sq0 * c0))
            wp.atomic_add(area, i2, eighth * (sq0 * c0 + sq1 * c1))


@wp.kernel(module="unique", enable_backward=False)
def cancelled_kernel(n_sum: wp.array(dtype=wp.vec3d), n_len: wp.array(dtype=wp.float64),
                     counts: wp.array(dtype=wp.int32)):
    """Count in ``counts[1]`` the vertices whose faces cancel: a face with area touches them and their normal sum is
    shorter than ``CANCEL_REL`` of the summed lengths (``warpbw.io.mesh``'s test): the fallback normal, or a direction
    made of rounding."""
    v = wp.tid()
    if n_len[v] > wp.float64(0.0) and wp.length(n_sum[v]) <= CANCEL_REL * n_len[v]:
        wp.atomic_add(counts, 1, 1)


@wp.kernel(module="unique", enable_backward=False)
def vertex_finish_kernel(n_sum: wp.array(dtype=wp.vec3d), lap: wp.array(dtype=wp.vec3d),
                         area: wp.array(dtype=wp.float64), normals: wp.array(dtype=wp.vec3),
                         curvature: wp.array(dtype=wp.float32)):
    """Unit normal (the fallback where no area is incident) and H = -(L . n) / (4 A_mixed)."""
    v = wp.tid()
    s = n_sum[v]
    length = wp.length(s)
    n = FALLBACK_NORMAL
    nd = wp.vec3d(FALLBACK_NORMAL)
    if length > wp.float64(0.0):
        nd = s / length
        n = wp.vec3(nd)
    normals[v] = n
    h = wp.float64(0.0)
    if area[v] > wp.float64(0.0):
        h = -wp.dot(lap[v], nd) / (wp.float64(4.0) * area[v])
    hf = float(h)
    if not wp.isfinite(hf):
        hf = 0.0
    curvature[v] = hf


@wp.kernel(module="unique", enable_backward=False)
def boundary_sum_kernel(x: wp.array(dtype=wp.int32), y: wp.array(dtype=wp.int32),
                        curvature: wp.array(dtype=wp.float32), s: wp.array(dtype=wp.float64),
                        c: wp.array(dtype=wp.int32)):
    """Boundary vertex x[k] gathers the H of its interior neighbour y[k]."""
    k = wp.tid()
    wp.atomic_add(s, x[k], wp.float64(curvature[y[k]]))
    wp.atomic_add(c, x[k], 1)


@wp.kernel(module="unique", enable_backward=False)
def boundary_mean_kernel(boundary: wp.array(dtype=wp.int32), s: wp.array(dtype=wp.float64),
                         c: wp.array(dtype=wp.int32), curvature: wp.array(dtype=wp.float32)):
    """A boundary vertex's H: its interior neighbours' mean (0 without any)."""
    v = boundary[wp.tid()]
    h = float(0.0)
    if c[v] > 0:
        h = float(s[v] / wp.float64(c[v]))
    curvature[v] = h


@wp.kernel(module="unique", enable_backward=False)
def one_ring_sum_kernel(faces: wp.array(dtype=wp.int32), first: int, x: wp.array(dtype=wp.float32),
                        s: wp.array(dtype=wp.float64)):
    """Each corner of one face gathers x at the face's other two corners (the one-ring sum of
    ``warpbw.io.mesh.local_curvature``: an interior edge counts twice, once per face)."""
    t = wp.tid()
    i0 = faces[3 * t] - first
    i1 = faces[3 * t + 1] - first
    i2 = faces[3 * t + 2] - first
    x0 = wp.float64(x[i0])
    x1 = wp.float64(x[i1])
    x2 = wp.float64(x[i2])
    wp.atomic_add(s, i0, x1 + x2)
    wp.atomic_add(s, i1, x2 + x0)
    wp.atomic_add(s, i2, x0 + x1)


@wp.kernel(module="unique", enable_backward=False)
def lazy_average_kernel(x: wp.array(dtype=wp.float32), s: wp.array(dtype=wp.float64),
                        deg: wp.array(dtype=wp.int32), y: wp.array(dtype=wp.float32)):
    """One lazy pass, y = (x + one-ring mean) / 2; a vertex without faces keeps x."""
    v = wp.tid()
    xv = wp.float64(x[v])
    if deg[v] > 0:
        xv = wp.float64(0.5) * xv + wp.float64(0.5) * s[v] / wp.float64(deg[v])
    y[v] = float(xv)


@wp.kernel(module="unique", enable_backward=False)
def magnitude_kernel(x: wp.array(dtype=wp.float32), y: wp.array(dtype=wp.float32)):
    v = wp.tid()
    y[v] = wp.abs(x[v])


@wp.kernel(module="unique", enable_backward=False)
def seam_copy_kernel(copies: wp.array(dtype=wp.int32), copy_of: wp.array(dtype=wp.int32),
                     normals: wp.array(dtype=wp.vec3), curvature: wp.array(dtype=wp.float32)):
    """Seam copy copies[k] takes the normal and H of its surface vertex copy_of[k] (which is no copy: the reads
    never meet the writes)."""
    k = wp.tid()
    normals[copies[k]] = normals[copy_of[k]]
    curvature[copies[k]] = curvature[copy_of[k]]


@wp.kernel(module="unique", enable_backward=False)
def seam_copy_scalar_kernel(copies: wp.array(dtype=wp.int32), copy_of: wp.array(dtype=wp.int32),
                            x: wp.array(dtype=wp.float32)):
    k = wp.tid()
    x[copies[k]] = x[copy_of[k]]


@dataclass
class MeshTopology:
    """One mesh of a concatenated vertex array: its faces (global vertex indices), its vertex range, its open
    boundary (``warpbw.io.mesh.boundary_neighbours``) and its one-ring counts, on the device."""
    faces: wp.array            # int32, 3 per face, indices into the concatenated points
    first: int                 # the mesh's first vertex in the concatenated points
    count: int                 # its vertices
    boundary: wp.array         # int32 boundary vertices (local indices)
    pair_x: wp.array           # int32 boundary vertex of each (boundary, interior neighbour) pair (local)
    pair_y: wp.array           # int32 its interior neighbour (local)
    ring_count: wp.array       # int32 (count,) terms of each vertex's one-ring sum: 2 per incident face
    # int32 seam copies (local) and the surface vertex each is one point with (local): the faces above name the
    # surface vertex only; empty where no vertex is split (mesh_topology's surface None)
    copies: wp.array = None
    copy_of: wp.array = None


@dataclass
class MeshShading:
    normals: wp.array          # (V,) vec3 unit vertex normals
    curvature: wp.array        # (V,) float32 mean curvature, 1 / scene units


def _check_topology(topology) -> None:
    if not isinstance(topology, MeshTopology):
        raise WarpbwError(f"topology: expected a MeshTopology (mesh_topology), got {type(topology).__name__}")


def mesh_topology(indices, first: int, count: int, device: str = "cpu", surface=None) -> MeshTopology:
    """The faces of ``indices`` (flat, 3 per face, into a concatenated vertex array) whose vertices lie in
    ``[first, first + count)``, their open boundary and each vertex's one-ring count.  Connectivity only: a
    deformation keeps it.  ``surface`` (count,) (``warpbw.io.mesh.MeshData.surface``, local indices; None: every
    vertex its own): the seam map, under which the faces name each seam's copies by their surface vertex, so that
    the sums meet over the seam and no seam edge reads as an open boundary; the copies take its values."""
    check_device(device)
    first = check_count(first, "first", 0, INT32_MAX)   # -1 was taken, and its faces' indices shifted
    # the kernels index vertices in int32; beyond, a range of 10^12 asked for terabytes of counts
    count = check_count(count, "count", 0, INT32_MAX - first)
    f = np.asarray(indices)
    if f.dtype.kind not in "iu" and not (f.size == 0 and f.dtype.kind == "f"):
        raise WarpbwError(f"indices: expected integer vertex indices, got {f.dtype} values (1.7 was taken as 1)")
    if f.size % 3:
        raise WarpbwError(f"indices: expected 3 vertex indices per face, got {f.size}")
    f = f.astype(np.int64).reshape(-1, 3)
    mine = (f >= first) & (f < first + count)
    if np.any(mine.any(axis=1) & ~mine.all(axis=1)):
        raise WarpbwError(f"mesh topology: a face joins vertices in [{first}, {first + count}) to others")
    f = f[mine.all(axis=1)] - first
    surface = host_mesh.checked_surface(surface, count, "mesh topology: surface")
    copies = np.zeros(0, np.int64) if surface is None else np.flatnonzero(surface != np.arange(count))
    if len(copies):
        f = surface[f]
    on_boundary, x, y = boundary_neighbours(f, count)

    def dev(a):
        return wp.array(np.ascontiguousarray(a, np.int32), dtype=wp.int32, device=device)
    ring_count = 2 * np.bincount(f.ravel(), minlength=count)
    return MeshTopology(dev((f + first).reshape(-1)), int(first), int(count), dev(np.flatnonzero(on_boundary)), dev(x),
                        dev(y), dev(ring_count), dev(copies), dev(copies if surface is None else surface[copies]))


def _copy_to_seams(topology: MeshTopology, device: str, *arrays) -> None:
    """Each seam copy takes the values its surface vertex has in ``arrays`` (normals and H, or one scalar)."""
    n = 0 if topology.copies is None else topology.copies.shape[0]
    if n:
        kernel = seam_copy_kernel if len(arrays) == 2 else seam_copy_scalar_kernel
        wp.launch(kernel, dim=n, inputs=[topology.copies, topology.copy_of, *arrays], device=device)


def normals_and_curvature(points: wp.array, topology: MeshTopology, device: str = "cpu",
                          out: MeshShading | None = None) -> MeshShading:
    """Area-weighted unit vertex normals and mean curvature of the mesh ``topology`` describes, from the
    vertex positions in ``points`` (the concatenated array, e.g. ``wp.Mesh.points``).  Written into ``out``
    when given (views of the G-buffer's per-vertex arrays, say), else into new arrays."""
    check_device(device)
    _check_topology(topology)
    n = topology.count
    if not isinstance(points, wp.array):   # numpy (V, 3): copied to the device, as Warp's launch did
        points = np.asarray(points, np.float32)
        if points.ndim != 2 or points.shape[1] != 3:
            raise WarpbwError(f"points: expected (V, 3) vertex positions, got shape {points.shape}")
        points = wp.array(points, dtype=wp.vec3, device=device)
    check_warp_array(points, "points", wp.vec3, topology.first + n, device,
                     f"the mesh's vertices {topology.first} to {topology.first + n - 1}", at_least=True)
    if out is None:
        out = MeshShading(wp.empty(n, dtype=wp.vec3, device=device), wp.empty(n, dtype=wp.float32, device=device))
    elif not isinstance(out, MeshShading):
        raise WarpbwError(f"out: expected a MeshShading of the mesh's {n} vertices, got {type(out).__name__}")
    else:
        check_warp_array(out.normals, "out.normals", wp.vec3, n, device, "the mesh's vertices")
        check_warp_array(out.curvature, "out.curvature", wp.float32, n, device, "the mesh's vertices")
    n_sum = wp.zeros(n, dtype=wp.vec3d, device=device)
    lap = wp.zeros(n, dtype=wp.vec3d, device=device)
    area = wp.zeros(n, dtype=wp.float64, device=device)
    n_faces = topology.faces.shape[0] // 3
    n_len = wp.zeros(n, dtype=wp.float64, device=device)
    counts = wp.zeros(2, dtype=wp.int32, device=device)   # faces with a vertex not finite, vertices whose faces cancel
    # one launch each (module docstring: the atomic sums must not be split over CPU threads)
    wp.launch(face_terms_kernel, dim=n_faces, inputs=[points, topology.faces, topology.first, n_sum, lap, area,
                                                     n_len, counts], device=device)
    wp.launch(cancelled_kernel, dim=n, inputs=[n_sum, n_len, counts], device=device)
    bad, cancelled = (int(c) for c in counts.numpy())
    if bad:   # the faces around a NaN vertex gave its neighbours (0, 1, 0) and a made-up H
        raise WarpbwError(f"points: {bad} of the mesh's {n_faces} faces have a vertex that is not finite (NaN or "
                          "infinite); expected finite positions")
    if cancelled:   # they took the fallback normal (0, 1, 0), whatever the surface's direction
        raise WarpbwError("points: " + host_mesh.cancelled_pose(cancelled))
    wp.launch(vertex_finish_kernel, dim=n, inputs=[n_sum, lap, area, out.normals, out.curvature], device=device)
    if topology.boundary.shape[0]:
        s = wp.zeros(n, dtype=wp.float64, device=device)
        c = wp.zeros(n, dtype=wp.int32, device=device)
        wp.launch(boundary_sum_kernel, dim=topology.pair_x.shape[0],
                  inputs=[topology.pair_x, topology.pair_y, out.curvature, s, c], device=device)
        wp.launch(boundary_mean_kernel, dim=topology.boundary.shape[0], inputs=[topology.boundary, s, c, out.curvature],
                  device=device)
    _copy_to_seams(topology, device, out.normals, out.curvature)
    return out


def local_curvature(curvature: wp.array, topology: MeshTopology, device: str = "cpu",
                    passes: int = host_mesh.CURVATURE_SMOOTHING_PASSES, out: wp.array | None = None) -> wp.array:
    """The curvature the bandwidth pass reads, from the mean curvature H (V,) of the mesh ``topology``
    describes: |H| averaged by ``passes`` lazy one-ring passes, as ``warpbw.io.mesh.local_curvature`` (each seam's
    copies as one vertex, where the topology has a seam map).
    Written into ``out`` when given (which may be ``curvature`` itself), else into a new array."""
    check_device(device)
    _check_topology(topology)
    n = topology.count
    passes = check_count(passes, "local_curvature: passes", 0, host_mesh.CURVATURE_PASSES_MAX)   # 2.5 ran as 2
    if not isinstance(curvature, wp.array):   # numpy: copied to the device
        curvature = np.asarray(curvature, np.float32)
        if curvature.shape != (n,):
            raise WarpbwError(f"local_curvature: curvature has shape {curvature.shape}, the mesh {n} vertices")
        curvature = wp.array(curvature, dtype=wp.float32, device=device)
    check_warp_array(curvature, "local_curvature: curvature", wp.float32, n, device, "the mesh's vertices")
    if out is None:
        out = wp.empty(n, dtype=wp.float32, device=device)
    else:
        check_warp_array(out, "local_curvature: out", wp.float32, n, device, "the mesh's vertices")
    x = wp.empty(n, dtype=wp.float32, device=device)
    y = wp.empty(n, dtype=wp.float32, device=device)
    wp.launch(magnitude_kernel, dim=n, inputs=[curvature, x], device=device)
    s = wp.empty(n, dtype=wp.float64, device=device)
    n_faces = topology.faces.shape[0] // 3
    for _ in range(passes):
        s.zero_()
        # one launch (module docstring: the atomic sums must not be split over CPU threads)
        wp.launch(one_ring_sum_kernel, dim=n_faces, inputs=[topology.faces, topology.first, x, s], device=device)
        wp.launch(lazy_average_kernel, dim=n, inputs=[x, s, topology.ring_count, y], device=device)
        x, y = y, x
    wp.copy(out, x)
    _copy_to_seams(topology, device, out)
    return out
