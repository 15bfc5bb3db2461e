"""G-buffer pass: one primary ray per pixel against analytic spheres and a Warp mesh BVH.

Public:
    ``CameraData``                   Warp struct: pinhole camera
    ``make_camera(position, look_at, up, fov_deg, width, height)`` -> ``CameraData``
    ``scene_camera(camera) -> CameraData``   a scene's [camera] (``warpbw.scene.Camera``)
    ``camera_rays(cam) -> (origins, dirs)``  numpy, for tests and examples
    ``SphereSpec``, ``MeshSpec``     one sphere / mesh as ``build_geometry`` takes it
    ``Geometry`` / ``build_geometry(spheres, meshes, device)``  scene geometry on the device
    ``ensure_curvature(geometry) -> bool``   derive and upload the curvature a MeshSpec deferred (a callable);
                                     True when there was any (render_gbuffer calls it unless told not to)
    ``geometry_digest(geometry) -> str``   a hash of the spheres and of the meshes' points and normals as they are
                                     now (``Geometry.digest_built``: as built; ``warpbw.bench.ground_truth``
                                     tells a mesh deformed since from the scene's by it)
    ``update_mesh(geometry, mesh_index, vertices, normals=None, curvature=None)``  deform one mesh in place and
                                     refit the BVH (dynamic geometry, 002 Sec. 4.3, Fig. 18); a texture seam's
                                     copies must move together (``SEAM_GAP_REL``)
    ``GBufferData``                  Warp struct: the per-pixel buffers, as kernels read them (``GBUFFER_BUFFERS``,
                                     their names, as ``GBuffer.numpy(name)`` takes them)
    ``GBuffer`` / ``render_gbuffer(cam, geometry, device, threads, curvature=True, attributes=True)``   run the
                                     pass (without ``attributes``, no ``geo_normal`` or ``uv``: no stage reads them)
    ``make_gbuffer_kernel(has_spheres, has_mesh, attributes=True)``, ``allocate_gbuffer(width, height, device,
                                     attributes=True)``   its kernel (the pipeline compiles it ahead) and its buffers
    ``check_reach(cam, geometry)``   refuse a camera too far from (or, scaled down, too near) the geometry for
                                     float32 intersection (``SPHERE_REACH_MAX``, ``MESH_REACH_MAX``,
                                     ``SPHERE_REACH_MIN``, ``MESH_REACH_MIN``), or a scene so far from the origin
                                     that float32 cannot place it (``warpbw.errors.COORD_SPACING_REL_MAX``);
                                     render_gbuffer calls it
    ``check_camera_of(cam, gb, where)``   a CameraData of the G-buffer's size, else a one-line error (the
                                     passes read the pixel angle and rays from it)
    ``hide_beyond(gb, cam, distance, device, name) -> int``   empty the pixels whose surface lies beyond a
                                     per-pixel distance along the centre ray (hidden by something nearer);
                                     ``hide_beyond_kernel``, its kernel (the pipeline compiles it ahead)
    Warp structs ``SphereList``, ``MeshAttributes`` (in ``Geometry``) and functions ``primary_ray_dir``,
    ``intersect_sphere``, ``mesh_t_eps``, ``orthonormal_tangent``, ``sphere_tangent``, ``write_empty`` (the
    kernel's pieces)

Conventions (../shared/DESIGN.md): right-handed world, +Y up; the camera looks along ``forward`` with
``right = normalize(forward x up)`` to the right of the image and row 0 at the top; ``fov`` is the full
angle along the image width.  Pixel (x, y) is sampled at its centre.  Buffers are flat, row-major,
``index = y * width + x``.  ``depth`` is the distance along ``forward`` (camera-space z), 0 where no
geometry is hit; ``material`` is -1 there (the coverage mask is ``material >= 0``).  ``view`` is the unit
direction from the surface point to the camera (``wo`` in world space).  ``curvature`` is the curvature
c >= 0 that the bandwidth pass reads (002 Eq. 3): on a sphere of radius r, 1 / r; on a mesh, the magnitude of
the mean curvature H = (k1 + k2) / 2 that its ``MeshSpec`` (or ``update_mesh``) gives per vertex, averaged over
about two rings (``warpbw.io.mesh.local_curvature``; ``warpbw.mesh_normals`` on the device), interpolated.
Only the bandwidth pass reads it, so a MeshSpec may defer H (a callable): it is derived the first time a
G-buffer asks for curvature, and a G-buffer rendered with ``curvature=False`` reads 0 on that mesh.
The tangent is ``d position / d phi`` about +Y on spheres (its negative on the inner side a camera inside one
sees, as it is computed from the normal facing the camera) and a branchless orthonormal basis
(Duff et al. 2017) around the shading normal on meshes: shading here is isotropic.
"""
from __future__ import annotations

import functools
import hashlib
import math
import numbers
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
import warp as wp

from warpbw.errors import (FLOAT32_MAX, INT32_MAX, WarpbwError, check_camera_reach, check_coordinate_spacing,
                           check_count, check_device, check_flag, check_instance, is_int)
from warpbw.io.mesh import checked_faces, checked_surface, local_curvature
from warpbw.launch import launch_tiled

RAY_T_MAX = 1.0e30
# Primary rays are intersected in float32, and outside these distances from the camera (to an object's far
# side) a ray silently misses or lands wrong.  intersect_sphere squares lengths (r^2, |q|^2): they overflow
# beyond sqrt(FLOAT32_MAX) = 1.8e19 scene units (measured: a unit-scene sphere scaled by 1e19 renders, by 1e20
# vanishes) and underflow below sqrt(float32 tiny) = 1.1e-19.  Warp's mesh test (intersect_ray_tri_woop,
# warp/native/intersect.h) multiplies three lengths: beyond cbrt(FLOAT32_MAX) = 7.0e12 it overflows (an
# icosphere scaled by 1e12 renders, by 1e15 vanishes), below cbrt(tiny) = 2.3e-13 it turns subnormal (scaled
# by 1e-14, the image moved by 1.7% and the adaptive one by 45%).  Margins: 10 at the top, 1000 at the bottom
# (a fine mesh's edges are much shorter than its distance, so its products are smaller still).
_F32_TINY = float(np.finfo(np.float32).tiny)
SPHERE_REACH_MAX = math.sqrt(FLOAT32_MAX) / 10.0
MESH_REACH_MAX = FLOAT32_MAX ** (1.0 / 3.0) / 10.0
SPHERE_REACH_MIN = math.sqrt(_F32_TINY) * 1.0e3
MESH_REACH_MIN = _F32_TINY ** (1.0 / 3.0) * 1.0e3
# A texture seam's copies (MeshSpec.surface) are one vertex of the surface: update_mesh sums their normals and H from
# the faces on both sides at the surface vertex's position, and the copies take them.  A deformation that moves them
# apart (a displacement driven by the uv, which differ across the seam) tears the mesh, and those normals belong to
# no surface: a gap of 0.1 on a lat-long sphere of radius 2 (32 x 16) turned normals near the seam by 33 degrees from
# either side's own, 0.01 by 3.9 (1.9 where the copies stay together).  update_mesh refuses copies further apart than
# this share of the mesh's diagonal (or than twice their share in the MeshSpec built, or 4 float32 spacings of the
# largest coordinate, were either more): at 1e-6 the normals move by about 1e-6 of the diagonal over an edge length.
SEAM_GAP_REL = 1.0e-6
# the nearest t accepted on a sphere, relative to its distance and size (an absolute 1e-6 lost every sphere
# of a scene scaled by 1e-7), and on a mesh, relative to its half diagonal: a camera standing on a surface sees past
# the point it stands on (on a mesh it took it: every pixel showed that one point, session 77)
T_EPS_REL = 1.0e-6
# A sphere's root whose two terms cancel (a camera on the sphere: the point it stands on) carries the float32
# rounding of the discriminant, about eps r (|o| + |c| + r), over the roots' half gap s ~ |b|: at rays within about
# 12 degrees of the tangent plane that exceeded T_EPS_REL r, and the point the camera stands on was taken (session
# 78).  Such a root is also refused below this many float32 epsilons of that error.
SPHERE_ROOT_ULPS = 4.0
_F32_EPS = float(np.finfo(np.float32).eps)


@wp.struct
class CameraData:
    origin: wp.vec3
    forward: wp.vec3
    right: wp.vec3
    up: wp.vec3
    tan_half_x: float   # tan(fov / 2) along the width
    tan_half_y: float   # the same scaled by height / width (square pixels)
    width: int
    height: int


@wp.struct
class GBufferData:
    position: wp.array(dtype=wp.vec3)
    normal: wp.array(dtype=wp.vec3)       # shading normal (interpolated on meshes)
    geo_normal: wp.array(dtype=wp.vec3)   # geometric normal, facing the camera (with uv: empty without attributes)
    tangent: wp.array(dtype=wp.vec3)
    view: wp.array(dtype=wp.vec3)         # wo, world space, unit, towards the camera
    depth: wp.array(dtype=wp.float32)
    curvature: wp.array(dtype=wp.float32)
    # sphere: u = atan2(x, z) / 2 pi + 1/2, v = acos(y) / pi of the outward unit normal (x, y, z) (u = 1/2 at +Z,
    # 3/4 at +X; v = 0 at +Y); mesh: its vertex uv, interpolated (zeros when it has none)
    uv: wp.array(dtype=wp.vec2)
    material: wp.array(dtype=wp.int32)    # -1: no geometry (background)
    width: int
    height: int


# GBufferData's per-pixel arrays, in its order (GBuffer.numpy reads them by name)
GBUFFER_BUFFERS = ("position", "normal", "geo_normal", "tangent", "view", "depth", "curvature", "uv", "material")


@wp.struct
class SphereList:
    center: wp.array(dtype=wp.vec3)
    radius: wp.array(dtype=wp.float32)
    material: wp.array(dtype=wp.int32)
    count: int


@wp.struct
class MeshAttributes:
    id: wp.uint64
    indices: wp.array(dtype=wp.int32)        # 3 per face
    normal: wp.array(dtype=wp.vec3)          # per vertex, smooth
    curvature: wp.array(dtype=wp.float32)    # per vertex local |H| (local_curvature of MeshSpec.curvature)
    uv: wp.array(dtype=wp.vec2)              # per vertex (zeros when the mesh has none)
    face_material: wp.array(dtype=wp.int32)
    face_end: wp.array(dtype=wp.int32)       # per MeshSpec: one past its last face in the concatenated faces
    t_eps: wp.array(dtype=wp.float32)        # per MeshSpec: the nearest t taken on it (T_EPS_REL x its half diagonal)
    t_eps_max: float                         # the largest of them: a hit beyond it looks none up


# ---------------------------------------------------------------------------------------------
# Kernel helpers
# ---------------------------------------------------------------------------------------------

@wp.func
def primary_ray_dir(cam: CameraData, x: int, y: int):
    sx = (2.0 * (float(x) + 0.5) / float(cam.width) - 1.0) * cam.tan_half_x
    sy = (1.0 - 2.0 * (float(y) + 0.5) / float(cam.height)) * cam.tan_half_y
    return wp.normalize(cam.forward + sx * cam.right + sy * cam.up)


@wp.func
def intersect_sphere(o: wp.vec3, d: wp.vec3, c: wp.vec3, r: float):
    """Nearest t > 0 of a unit-direction ray with a sphere, or -1 (stable quadratic)."""
    oc = o - c
    b = wp.dot(oc, d)
    # discriminant computed as r^2 - |oc - b d|^2 to avoid cancellation far from the sphere
    q = oc - b * d
    disc = r * r - wp.dot(q, q)
    if disc < 0.0:
        return -1.0
    s = wp.sqrt(disc)
    t0 = -b - s
    t1 = -b + s
    eps = T_EPS_REL * wp.max(wp.abs(b), r)   # relative: a sphere of radius 1e-7 is the unit one, scaled
    # and above the rounding of a root whose terms cancel (SPHERE_ROOT_ULPS): err / |b|, an area over a length;
    # where |b| < sqrt(err) both roots lie within sqrt(err) of the ray's origin
    err = SPHERE_ROOT_ULPS * _F32_EPS * r * (wp.length(o) + wp.length(c) + r)
    den = wp.max(wp.abs(b), wp.sqrt(err))
    if den > 0.0:   # 0 only where err underflowed (a sphere near float32's tiny) and the ray is square to o - c
        eps = wp.max(eps, err / den)
    if t0 > eps:
        return t0
    if t1 > eps:
        return t1
    return -1.0


@wp.func
def mesh_t_eps(mesh: MeshAttributes, face: int):
    """The nearest t taken on the MeshSpec that holds ``face`` (``MeshAttributes.t_eps``)."""
    k = int(0)
    while k < mesh.face_end.shape[0] - 1 and face >= mesh.face_end[k]:
        k += 1
    return mesh.t_eps[k]


@wp.func
def orthonormal_tangent(n: wp.vec3):
    # Duff et al. 2017, "Building an orthonormal basis, revisited".
    sgn = wp.where(n[2] >= 0.0, 1.0, -1.0)
    a = -1.0 / (sgn + n[2])
    b = n[0] * n[1] * a
    return wp.vec3(1.0 + sgn * n[0] * n[0] * a, sgn * b, -sgn * n[0])


@wp.func
def sphere_tangent(n: wp.vec3):
    # d position / d phi for phi about +Y; the basis fallback at the poles.
    t = wp.vec3(n[2], 0.0, -n[0])
    l = wp.length(t)
    if l < 1.0e-6:
        return orthonormal_tangent(n)
    return t / l


@wp.func
def write_empty(gb: GBufferData, i: int):
    gb.position[i] = wp.vec3(0.0)
    gb.normal[i] = wp.vec3(0.0)
    if gb.geo_normal.shape[0] > 0:   # a G-buffer without attributes has neither geo_normal nor uv
        gb.geo_normal[i] = wp.vec3(0.0)
        gb.uv[i] = wp.vec2(0.0)
    gb.tangent[i] = wp.vec3(0.0)
    gb.view[i] = wp.vec3(0.0)
    gb.depth[i] = 0.0
    gb.curvature[i] = 0.0
    gb.material[i] = -1


def make_gbuffer_kernel(has_spheres: bool, has_mesh: bool, attributes: bool = True):
    """The G-buffer kernel for a scene with spheres and/or meshes (only those paths are compiled); with
    ``attributes``, it also writes ``geo_normal`` and ``uv``."""
    return _gbuffer_kernel(check_flag(has_spheres, "make_gbuffer_kernel: has_spheres"),
                           check_flag(has_mesh, "make_gbuffer_kernel: has_mesh"),
                           check_flag(attributes, "make_gbuffer_kernel: attributes"))   # "no" compiled them in


@functools.cache  # one kernel per combination: Warp compiles each once
def _gbuffer_kernel(has_spheres: bool, has_mesh: bool, attributes: bool):

    @wp.kernel(module="unique", enable_backward=False)
    def gbuffer_kernel(cam: CameraData, spheres: SphereList, mesh: MeshAttributes, gb: GBufferData, offset: int):
        i = wp.tid() + offset
        x = i % cam.width
        y = i // cam.width
        d = primary_ray_dir(cam, x, y)
        o = cam.origin
        t_best = float(RAY_T_MAX)
        hit_kind = int(0)   # 0 none, 1 sphere, 2 mesh
        hit_index = int(-1)
        bu = float(0.0)
        bv = float(0.0)
        gn = wp.vec3(0.0)
        if wp.static(has_spheres):
            for k in range(spheres.count):
                t = intersect_sphere(o, d, spheres.center[k], spheres.radius[k])
                if t > 0.0 and t < t_best:
                    t_best = t
                    hit_kind = 1
                    hit_index = k
        if wp.static(has_mesh):
            q = wp.mesh_query_ray(mesh.id, o, d, t_best)
            shift = float(0.0)
            if q.result and q.t <= mesh.t_eps_max:
                eps = mesh_t_eps(mesh, q.face)
                if q.t <= eps:   # the camera stands on the mesh (a vertex, a face): look past that point, as
                    # intersect_sphere does (every pixel showed the point under the camera, session 77)
                    shift = eps
                    q = wp.mesh_query_ray(mesh.id, o + eps * d, d, t_best - eps)
            if q.result:
                t_best = q.t + shift
                hit_kind = 2
                hit_index = q.face
                bu = q.u
                bv = q.v
                gn = q.normal
        if hit_kind == 0:
            write_empty(gb, i)
            return
        p = o + t_best * d
        n = wp.vec3(0.0)
        tan = wp.vec3(0.0)
        curv = float(0.0)
        uv = wp.vec2(0.0)
        mat = int(-1)
        if wp.static(has_spheres):
            if hit_kind == 1:
                c = spheres.center[hit_index]
                r = spheres.radius[hit_index]
                n = (p - c) / r
                n = wp.normalize(n)
                # of the point, not of the side seen: the outward normal's longitude and polar angle
                if wp.static(attributes):
                    uv = wp.vec2(wp.atan2(n[0], n[2]) / (2.0 * wp.pi) + 0.5,
                                 wp.acos(wp.clamp(n[1], -1.0, 1.0)) / wp.pi)
                if wp.dot(n, d) > 0.0:   # camera inside the sphere: see its inner side
                    n = -n
                gn = n
                tan = sphere_tangent(n)
                curv = 1.0 / r
                mat = spheres.material[hit_index]
        if wp.static(has_mesh):
            if hit_kind == 2:
                i0 = mesh.indices[hit_index * 3 + 0]
                i1 = mesh.indices[hit_index * 3 + 1]
                i2 = mesh.indices[hit_index * 3 + 2]
                w2 = 1.0 - bu - bv
                # Warp's barycentrics: p = u p0 + v p1 + (1 - u - v) p2
                n = wp.normalize(bu * mesh.normal[i0] + bv * mesh.normal[i1] + w2 * mesh.normal[i2])
                gn = wp.normalize(gn)
                if wp.dot(gn, d) > 0.0:   # two-sided: face the camera
                    gn = -gn
                    n = -n
                tan = orthonormal_tangent(n)
                curv = bu * mesh.curvature[i0] + bv * mesh.curvature[i1] + w2 * mesh.curvature[i2]
                if wp.static(attributes):
                    uv = bu * mesh.uv[i0] + bv * mesh.uv[i1] + w2 * mesh.uv[i2]
                mat = mesh.face_material[hit_index]
        gb.position[i] = p
        gb.normal[i] = n
        if wp.static(attributes):
            gb.geo_normal[i] = gn
            gb.uv[i] = uv
        gb.tangent[i] = tan
        gb.view[i] = -d
        gb.depth[i] = t_best * wp.dot(d, cam.forward)
        gb.curvature[i] = curv
        gb.material[i] = mat

    return gbuffer_kernel


@wp.kernel(module="unique", enable_backward=False)
def hide_beyond_kernel(cam: CameraData, t_max: wp.array(dtype=wp.float32), gb: GBufferData,
                       hidden: wp.array(dtype=wp.int32)):
    """Empty pixel i when its surface lies beyond t_max[i] along the centre ray (something nearer hides it)."""
    i = wp.tid()
    if gb.material[i] >= 0:
        d = primary_ray_dir(cam, i % cam.width, i // cam.width)
        if gb.depth[i] / wp.dot(d, cam.forward) > t_max[i]:   # depth = t (d . forward) for a unit d
            write_empty(gb, i)
            hidden[i] = 1


# ---------------------------------------------------------------------------------------------
# Host side
# ---------------------------------------------------------------------------------------------

def _unit(v) -> np.ndarray:
    v = np.asarray(v, np.float64)
    v = v / np.max(np.abs(v))     # first to unit size: the squares of a vector of 1e-300 would underflow to 0
    return v / np.linalg.norm(v)


def _camera_vector(v, name: str, point: bool = True) -> np.ndarray:
    """Three finite numbers; a point (not the up direction, whose length is divided out) within float32."""
    try:
        a = np.asarray(v, np.float64) if np.ndim(v) == 1 and np.size(v) == 3 else None
    except (TypeError, ValueError):   # ("a", "b", "c")
        a = None
    if a is None or not np.all(np.isfinite(a)) or (point and np.abs(a).max() > FLOAT32_MAX):
        raise WarpbwError(f"make_camera: {name}: expected three finite numbers{' within float32' if point else ''}, "
                          f"got {v!r}")
    return a


def make_camera(position, look_at, up, fov_deg: float, width: int, height: int) -> CameraData:
    """A pinhole camera; ``fov_deg`` is the full field of view along the image width.  The scene parser's checks
    (``[camera]``) hold here too: a NaN, coincident or parallel argument gave NaN rays and an empty image."""
    o = _camera_vector(position, "position")
    d = _camera_vector(look_at, "look_at") - o
    u = _camera_vector(up, "up", point=False)
    if not np.abs(d).max() > 0.0:
        raise WarpbwError("make_camera: look_at: must differ from position")
    if not (isinstance(fov_deg, (int, float, np.floating, np.integer)) and 0.0 < fov_deg < 180.0):
        raise WarpbwError(f"make_camera: fov_deg: expected degrees in (0, 180), got {fov_deg!r}")
    check_count(width, "make_camera: width", 1)
    check_count(height, "make_camera: height", 1)
    fwd = _unit(d)
    side = np.cross(fwd, _unit(u)) if np.abs(u).max() > 0.0 else np.zeros(3)
    if np.linalg.norm(side) < 1e-9:
        raise WarpbwError("make_camera: up: must not be zero or parallel to the viewing direction")
    right = _unit(side)
    cam_up = np.cross(right, fwd)
    cam = CameraData()
    cam.origin = wp.vec3(*o)
    cam.forward = wp.vec3(*fwd)
    cam.right = wp.vec3(*right)
    cam.up = wp.vec3(*cam_up)
    cam.tan_half_x = float(math.tan(math.radians(fov_deg) * 0.5))
    cam.tan_half_y = float(cam.tan_half_x * height / width)
    cam.width = int(width)
    cam.height = int(height)
    return cam


def scene_camera(camera) -> CameraData:
    """``make_camera`` of a scene's [camera] (``warpbw.scene.Camera``: position, look_at, up, fov, width, height)."""
    return make_camera(camera.position, camera.look_at, camera.up, camera.fov, camera.width, camera.height)


def camera_rays(cam: CameraData):
    """(origins, dirs) of every pixel's primary ray, each (H*W, 3) float64, row-major, row 0 at the top."""
    check_instance(cam, CameraData, "camera_rays: cam", "a CameraData (make_camera's)")   # None: an AttributeError
    w, h = cam.width, cam.height
    x, y = np.meshgrid(np.arange(w), np.arange(h))
    sx = (2.0 * (x.ravel() + 0.5) / w - 1.0) * cam.tan_half_x
    sy = (1.0 - 2.0 * (y.ravel() + 0.5) / h) * cam.tan_half_y
    fwd, right, up = (np.array(list(v), np.float64) for v in (cam.forward, cam.right, cam.up))
    d = fwd[None] + sx[:, None] * right[None] + sy[:, None] * up[None]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = np.broadcast_to(np.array(list(cam.origin), np.float64), d.shape)
    return o, d


@dataclass
class SphereSpec:
    center: tuple
    radius: float
    material: int


@dataclass
class MeshSpec:
    vertices: np.ndarray       # (V, 3)
    faces: np.ndarray          # (F, 3)
    normals: np.ndarray        # (V, 3)
    # (V,) mean curvature H (build_geometry stores its local magnitude), or a callable returning it, called only
    # when a G-buffer needs curvature (ensure_curvature): a frame without the bandwidth pass never derives it
    curvature: np.ndarray | Callable[[], np.ndarray]
    uv: np.ndarray | None      # (V, 2)
    material: int
    # (V,) the seam map (warpbw.io.mesh.MeshData.surface, computed at load): per vertex, the vertex it is one point
    # of the surface with, where a texture seam split it; None: every vertex its own.  The local curvature here and
    # update_mesh's normals and H treat each seam's copies as one vertex, as load_mesh does.
    surface: np.ndarray | None = None


@dataclass
class Geometry:
    """Scene geometry on the device.  ``mesh`` (a ``wp.Mesh`` over every mesh object, or None) can be
    deformed in place and refitted (``geometry.mesh.points`` then ``geometry.mesh.refit()``).  ``n_triangles`` is
    the triangles of every mesh together (0 without one), ``has_spheres`` / ``has_mesh`` whether there are any."""

    spheres: SphereList
    mesh_attr: MeshAttributes
    mesh: wp.Mesh | None
    has_spheres: bool
    has_mesh: bool
    n_triangles: int = 0
    _keep: list = field(default_factory=list, repr=False)
    # (first vertex, vertex count) of each MeshSpec in the concatenated vertex arrays, in the order given
    mesh_vertex_ranges: list = field(default_factory=list)
    # mesh index -> warpbw.mesh_normals.MeshTopology, built by the first update_mesh of that mesh
    topology: dict = field(default_factory=dict)
    # host copies for check_reach: (center, radius) of each sphere, (lower, upper) corners of each mesh
    sphere_bounds: list = field(default_factory=list)
    mesh_bounds: list = field(default_factory=list)
    # mesh index -> (callable returning H, its faces): curvature a MeshSpec deferred, not yet on the device
    curvature_pending: dict = field(default_factory=dict)
    # each MeshSpec's seam map (int64 (V,), local indices) or None, in the order given
    mesh_surface: list = field(default_factory=list)
    # each MeshSpec's largest distance between a seam's copies, as a share of its diagonal (0 without a seam map):
    # update_mesh allows twice it (a mesh file's copies may differ by its merge tolerance)
    mesh_seam_gap: list = field(default_factory=list)
    digest_built: str = ""   # geometry_digest as built (update_mesh, or points edited in place, change what it gives)


def _check_sphere_spec(k: int, s: SphereSpec) -> None:
    where = f"build_geometry: spheres[{k}]"
    if not isinstance(s, SphereSpec):
        raise WarpbwError(f"{where}: expected a SphereSpec, got {type(s).__name__}")
    try:
        c = np.asarray(s.center, np.float64)
    except (TypeError, ValueError):
        c = np.zeros(0)
    if c.shape != (3,) or not np.all(np.abs(c) < FLOAT32_MAX):
        raise WarpbwError(f"{where} center: expected three finite numbers, got {s.center!r}")
    if not (isinstance(s.radius, numbers.Real) and 0.0 < s.radius < FLOAT32_MAX):
        raise WarpbwError(f"{where} radius: expected a finite number > 0, got {s.radius!r}")
    # an id the material table lacks was read out of bounds (a black sphere, or a segfault); -1 is background
    check_count(s.material, f"{where} material", 0, INT32_MAX)


def _check_unit_normals(n: np.ndarray, where: str) -> np.ndarray:
    """``n`` (V, 3), unit vectors, else a one-line error: a zero normal shaded black without a word (build_geometry
    took it; update_mesh refused it), and the shading interpolates them as they are, weighting longer ones more."""
    length = np.linalg.norm(n, axis=1)
    if not np.all(np.abs(length - 1.0) < 1e-3):
        raise WarpbwError(f"{where}normals: expected unit vectors, got lengths from {length.min():.3g} to "
                          f"{length.max():.3g} (a zero normal shades black)")
    return n


def _check_mesh_spec(k: int, m: MeshSpec) -> np.ndarray | None:
    """Check meshes[k]; returns its seam map as checked (``warpbw.io.mesh.checked_surface``)."""
    where = f"build_geometry: meshes[{k}] "
    if not isinstance(m, MeshSpec):
        raise WarpbwError(f"{where.rstrip()}: expected a MeshSpec, got {type(m).__name__}")
    v = np.asarray(m.vertices)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) < 3:
        raise WarpbwError(f"{where}vertices: expected (V, 3) positions, V >= 3, got shape {v.shape}")
    n_v = len(v)
    _per_vertex("vertices", v, (n_v, 3), where)
    _check_unit_normals(_per_vertex("normals", m.normals, (n_v, 3), where), where)
    if m.uv is not None:
        _per_vertex("uv", m.uv, (n_v, 2), where)
    if not callable(m.curvature):
        _per_vertex("curvature", m.curvature, (n_v,), where)
    surface = checked_surface(m.surface, n_v, f"{where}surface")
    # Warp's BVH reads the vertices the faces index: one out of range crashed the process
    if len(checked_faces(m.faces, n_v, f"{where}faces")) == 0:
        raise WarpbwError(f"{where}faces: expected at least one triangle, got none")
    check_count(m.material, f"{where}material", 0, INT32_MAX)
    return surface


def build_geometry(spheres: Sequence[SphereSpec], meshes: Sequence[MeshSpec], device: str = "cpu") -> Geometry:
    """Upload spheres and one BVH over all meshes (concatenated, with a material id per face); a mesh's
    curvature is stored as ``warpbw.io.mesh.local_curvature`` of the H its MeshSpec gives (0 until
    ``ensure_curvature`` where the MeshSpec defers it), each seam's copies as one vertex (``MeshSpec.surface``).
    Material ids index the table the shading is given (``shade_reference`` checks them against it)."""
    check_device(device)
    for name, specs, kind in (("spheres", spheres, "SphereSpec"), ("meshes", meshes, "MeshSpec")):
        if not isinstance(specs, (list, tuple)):   # None, or one spec: "not iterable" from below
            raise WarpbwError(f"build_geometry: {name}: expected a list of {kind} (empty for none), got "
                              f"{type(specs).__name__}")
    for k, s in enumerate(spheres):
        _check_sphere_spec(k, s)
    surfaces = [_check_mesh_spec(k, m) for k, m in enumerate(meshes)]
    sl = SphereList()
    sl.center = wp.array(np.array([s.center for s in spheres], np.float32).reshape(-1, 3), dtype=wp.vec3,
                         device=device)
    sl.radius = wp.array(np.array([s.radius for s in spheres], np.float32), dtype=wp.float32, device=device)
    sl.material = wp.array(np.array([s.material for s in spheres], np.int32), dtype=wp.int32, device=device)
    sl.count = len(spheres)

    ma = MeshAttributes()
    mesh = None
    n_tri = 0
    ranges = []
    pending = {}
    bounds, seam_gaps = [], []
    if meshes:
        verts, faces, norms, curv, uvs, fmat = [], [], [], [], [], []
        base = 0
        for k, m in enumerate(meshes):
            v = np.asarray(m.vertices, np.float32)
            ranges.append((base, len(v)))
            verts.append(v)
            bounds.append(_bounds(v))
            # the copies' largest distance as built, a share of the diagonal (update_mesh allows twice it)
            seam_gaps.append(0.0 if surfaces[k] is None else _seam_gap(v.astype(np.float64), surfaces[k])[0]
                             / max(float(np.linalg.norm(bounds[-1][1] - bounds[-1][0])), 1e-300))
            faces.append(np.asarray(m.faces, np.int64) + base)
            norms.append(np.asarray(m.normals, np.float32))
            if callable(m.curvature):
                pending[k] = (m.curvature, m.faces)
                curv.append(np.zeros(len(v), np.float32))
            else:
                curv.append(local_curvature(m.curvature, m.faces, surface=surfaces[k]))
            uvs.append(np.zeros((len(v), 2), np.float32) if m.uv is None else np.asarray(m.uv, np.float32))
            fmat.append(np.full(len(m.faces), m.material, np.int32))
            base += len(v)
        faces_all = np.concatenate(faces).astype(np.int32)
        n_tri = len(faces_all)
        points = wp.array(np.concatenate(verts), dtype=wp.vec3, device=device)
        indices = wp.array(faces_all.reshape(-1), dtype=wp.int32, device=device)
        mesh = wp.Mesh(points=points, indices=indices)
        ma.id = mesh.id
        ma.indices = indices
        ma.normal = wp.array(np.concatenate(norms), dtype=wp.vec3, device=device)
        ma.curvature = wp.array(np.concatenate(curv), dtype=wp.float32, device=device)
        ma.uv = wp.array(np.concatenate(uvs), dtype=wp.vec2, device=device)
        ma.face_material = wp.array(np.concatenate(fmat), dtype=wp.int32, device=device)
        ma.face_end = wp.array(np.cumsum([len(f) for f in faces]).astype(np.int32), dtype=wp.int32, device=device)
        _set_t_eps(ma, bounds, device)
    else:
        ma.id = wp.uint64(0)
        ma.indices = wp.zeros(0, dtype=wp.int32, device=device)
        ma.normal = wp.zeros(0, dtype=wp.vec3, device=device)
        ma.curvature = wp.zeros(0, dtype=wp.float32, device=device)
        ma.uv = wp.zeros(0, dtype=wp.vec2, device=device)
        ma.face_material = wp.zeros(0, dtype=wp.int32, device=device)
        ma.face_end = wp.zeros(0, dtype=wp.int32, device=device)
        ma.t_eps = wp.zeros(0, dtype=wp.float32, device=device)
        ma.t_eps_max = 0.0
    geometry = Geometry(sl, ma, mesh, bool(spheres), bool(meshes), n_tri, mesh_vertex_ranges=ranges,
                        sphere_bounds=[(np.asarray(s.center, np.float64), float(s.radius)) for s in spheres],
                        mesh_bounds=bounds, curvature_pending=pending, mesh_surface=surfaces, mesh_seam_gap=seam_gaps)
    geometry.digest_built = geometry_digest(geometry)
    return geometry


def geometry_digest(geometry: Geometry) -> str:
    """blake2b of what a frame reads of ``geometry`` that may change after it is built: the spheres' centres, radii
    and materials, and the meshes' points and normals (``update_mesh``; or ``geometry.mesh.points`` edited in place
    and refitted).  Not the curvature, which a deferred MeshSpec fills in later and only the bandwidth pass reads."""
    check_instance(geometry, Geometry, "geometry_digest: geometry", "a Geometry (build_geometry's)")
    h = hashlib.blake2b(digest_size=16)
    arrays = [geometry.spheres.center, geometry.spheres.radius, geometry.spheres.material]
    if geometry.mesh is not None:
        arrays += [geometry.mesh.points, geometry.mesh_attr.normal]
    for a in arrays:
        h.update(np.ascontiguousarray(a.numpy()).data)   # no copy of the bytes (a host array's own on the CPU)
    return h.hexdigest()


def ensure_curvature(geometry: Geometry) -> bool:
    """Derive the curvature that ``build_geometry`` deferred (a MeshSpec whose curvature is a callable) and
    upload it, as ``build_geometry`` stores a given one; then nothing is pending.  Returns True when there was
    anything to derive."""
    check_instance(geometry, Geometry, "ensure_curvature: geometry", "a Geometry (build_geometry's)")
    pending = geometry.curvature_pending
    derived = bool(pending)
    for k in sorted(pending):   # each mesh stays pending until its curvature is on the device
        mean_curvature, faces = pending[k]
        start, count = geometry.mesh_vertex_ranges[k]
        c = local_curvature(_per_vertex("curvature", mean_curvature(), (count,), f"MeshSpec {k}: "), faces,
                            surface=geometry.mesh_surface[k])
        dest = geometry.mesh_attr.curvature
        wp.copy(dest, wp.array(c, dtype=wp.float32, device=dest.device), dest_offset=start, count=count)
        del pending[k]
    return derived


def _bounds(vertices) -> tuple:
    v = np.asarray(vertices, np.float64).reshape(-1, 3)
    return v.min(axis=0), v.max(axis=0)


def _set_t_eps(ma: MeshAttributes, bounds: list, device) -> None:
    """``ma.t_eps`` and ``t_eps_max`` of the meshes of ``bounds`` (lower, upper corners per MeshSpec): the nearest t a
    ray takes on each, ``T_EPS_REL`` of its half diagonal, as ``intersect_sphere`` takes ``T_EPS_REL`` of a sphere's
    radius."""
    t_eps = np.array([T_EPS_REL * 0.5 * np.linalg.norm(np.asarray(hi) - np.asarray(lo)) for lo, hi in bounds],
                     np.float32)
    ma.t_eps = wp.array(t_eps, dtype=wp.float32, device=device)
    ma.t_eps_max = float(t_eps.max())


def _seam_gap(vertices: np.ndarray, surface) -> tuple:
    """(largest distance, distances (C,), copies (C,)) between each seam copy of ``vertices`` (V, 3) and the vertex the
    seam map ``surface`` says it is one point with: (0.0, 0, -1) without a map or a copy."""
    if surface is None:
        return 0.0, 0, -1
    copies = np.flatnonzero(surface != np.arange(len(surface)))
    gap = np.linalg.norm(vertices[copies] - vertices[surface[copies]], axis=1)
    if not len(gap):
        return 0.0, 0, -1
    return float(gap.max()), gap, copies


def check_reach(cam: CameraData, geometry: Geometry, source: str = "") -> None:
    """Refuse a camera whose rays would reach an object beyond what float32 intersection can compute
    (``SPHERE_REACH_MAX``, ``MESH_REACH_MAX``), or nearer than it can (``SPHERE_REACH_MIN``,
    ``MESH_REACH_MIN``, a scene scaled far down), and a camera or object so far from the origin that float32
    spaces coordinates there by more than ``warpbw.errors.COORD_SPACING_REL_MAX`` of the object's size (a scene
    translated far away): those pixels would come out empty or wrong without a word.  ``source`` (the scene file)
    starts the message when given."""
    check_instance(cam, CameraData, "check_reach: cam", "a CameraData (make_camera's)")
    check_instance(geometry, Geometry, "check_reach: geometry", "a Geometry (build_geometry's)")
    o = np.array([cam.origin[0], cam.origin[1], cam.origin[2]], np.float64)
    reaches = ([("sphere", np.linalg.norm(c - o) + r) for c, r in geometry.sphere_bounds]
               + [("mesh", np.linalg.norm(np.where(o < (lo + hi) / 2, hi, lo) - o))    # the farthest corner
                  for lo, hi in geometry.mesh_bounds])
    for kind, reach in reaches:   # the distance to the object's far side
        lo, hi, why = ((SPHERE_REACH_MIN, SPHERE_REACH_MAX, "it squares lengths") if kind == "sphere"
                       else (MESH_REACH_MIN, MESH_REACH_MAX, "Warp's test multiplies three lengths"))
        check_camera_reach(reach, lo, hi, f"the far side of a {kind}", kind, why, source)
    # each object's largest coordinate, its size and its name
    extents = ([(float(np.abs(c).max()) + r, r, "a sphere of radius") for c, r in geometry.sphere_bounds]
               + [(float(np.abs(np.stack([lo, hi])).max()), float(np.linalg.norm(hi - lo)), "a mesh of diagonal")
                  for lo, hi in geometry.mesh_bounds])
    for extent, size, name in extents:
        check_coordinate_spacing(max(float(np.abs(o).max()), extent), size, f"{name} {size:.3g}", source)


def _per_vertex(name: str, values, shape: tuple, where: str) -> np.ndarray:
    """``values`` as a float32 array of ``shape``, or a WarpbwError naming ``where`` (the message's start, e.g.
    "update_mesh: mesh 0 "), ``name`` and what was expected."""
    a = np.asarray(values)
    if a.shape != shape:
        raise WarpbwError(f"{where}{name}: expected shape {shape} ({shape[0]} vertices), got {a.shape}")
    if not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
        raise WarpbwError(f"{where}{name}: expected numbers, got dtype {a.dtype}")
    with np.errstate(over="ignore"):   # beyond float32 becomes inf, refused below (numpy's warning came first)
        a = np.ascontiguousarray(a, dtype=np.float32)
    n_bad = int(np.count_nonzero(~np.isfinite(a)))
    if n_bad:
        raise WarpbwError(f"{where}{name}: expected finite values, {n_bad} are NaN or infinite (or overflow float32)")
    return a


def update_mesh(geometry: Geometry, mesh_index: int, vertices, normals=None, curvature=None) -> None:
    """Deform mesh ``mesh_index`` (its position in ``build_geometry``'s ``meshes``) in place.

    Copies the new vertex positions (V, 3), in world space as ``build_geometry`` took them (a scene's mesh
    ``scale``, ``rotate_y`` and ``translate`` are not applied here), into the device arrays the G-buffer kernel
    reads, at that mesh's offset in the concatenated arrays, with its smooth normals (V, 3) and mean curvatures
    H (V,): given, or, when both are None, computed on the device from the new positions
    (:mod:`warpbw.mesh_normals`, the formulas of :mod:`warpbw.io.mesh`).  A mesh whose ``MeshSpec.surface`` (the seam
    map ``load_mesh`` computes once) names vertices split by a texture seam is summed over its surface: each seam's
    copies are one vertex, from the faces on both sides, and take the same normal and H, as ``load_mesh`` gives a
    mesh loaded in this pose.  The copies must move together: a deformation that moves them apart (say a
    displacement driven by the uv, which differ across the seam) tears the mesh, and the normals summed at one of
    them belong to no surface (33 degrees off either side's on a sphere of radius 2 opened by 0.1), so copies further
    apart than ``SEAM_GAP_REL`` of the diagonal (or twice as far as in the MeshSpec built) are a one-line error and
    nothing is changed (rebuild the geometry without ``MeshSpec.surface`` for a mesh that tears).  H is stored as
    its local magnitude, as ``build_geometry`` stores it (``warpbw.mesh_normals.local_curvature``, over the surface
    too).  A pose whose faces cancel at a vertex (a closed surface pressed flat; ``warpbw.io.mesh.CANCEL_REL``) has no
    normal there and is refused, as ``load_mesh`` refuses it.  Then refits the BVH over the moved points
    (``wp.Mesh.refit``: same topology, new bounds).  The connectivity, uv, seam map and materials stay as built.
    Nothing is derived from the old geometry, so a frame rendered after this is what ``build_geometry`` with the new
    vertices would give: the bandwidth pass needs only the G-buffer (002 Sec. 4.3, "Dynamic geometry").
    """
    ranges = geometry.mesh_vertex_ranges
    if geometry.mesh is None or not ranges:
        raise WarpbwError("update_mesh: the geometry has no mesh to update (built with meshes=[])")
    if not is_int(mesh_index) or not 0 <= mesh_index < len(ranges):
        raise WarpbwError(f"update_mesh: mesh_index: expected an integer in 0..{len(ranges) - 1}, "
                          f"got {mesh_index!r}")
    if (normals is None) != (curvature is None):
        raise WarpbwError("update_mesh: give both normals and curvature, or neither (then both are computed on "
                          "the device)")
    start, count = ranges[int(mesh_index)]
    where = f"update_mesh: mesh {mesh_index} "
    copies = [(geometry.mesh.points, _per_vertex("vertices", vertices, (count, 3), where), wp.vec3)]
    bounds = _bounds(copies[0][1])
    if not np.any(bounds[1] > bounds[0]):   # no extent: the next frame would divide by its size
        raise WarpbwError(f"{where}vertices: every vertex lies at one point, {bounds[0].tolist()}; expected a mesh "
                          "with extent")
    surface = geometry.mesh_surface[int(mesh_index)]
    if surface is not None:   # a seam's copies are summed as one vertex: they must still be one point
        verts = copies[0][1].astype(np.float64)
        gap, gaps, seam = _seam_gap(verts, surface)
        diag = float(np.linalg.norm(bounds[1] - bounds[0]))
        built = geometry.mesh_seam_gap[int(mesh_index)] if geometry.mesh_seam_gap else 0.0
        tol = max(max(SEAM_GAP_REL, 2.0 * built) * diag,
                  4.0 * float(np.spacing(np.float32(np.abs(verts).max()))))
        if gap > tol:
            far = gaps > tol
            i = int(seam[np.argmax(far)])
            raise WarpbwError(f"{where}vertices: {int(far.sum())} texture-seam copies (MeshSpec.surface) lie up to "
                              f"{gap:.3g} from the vertex they are one point with (first: vertex {i}, "
                              f"{float(gaps[np.argmax(far)]):.3g} from vertex {int(surface[i])}); expected each seam's "
                              f"copies to move together (within {tol:.3g}, SEAM_GAP_REL of the diagonal): their "
                              "normals and H are the surface's, summed as one vertex's")
    ma = geometry.mesh_attr
    if normals is not None:
        n = _check_unit_normals(_per_vertex("normals", normals, (count, 3), where), where)
        copies += [(ma.normal, n, wp.vec3),
                   (ma.curvature, _per_vertex("curvature", curvature, (count,), where), wp.float32)]
    # nothing is changed until everything given has been checked: a refused call leaves the mesh as it was
    from warpbw.mesh_normals import MeshShading, local_curvature, mesh_topology, normals_and_curvature

    device = geometry.mesh.points.device
    topo = geometry.topology.get(int(mesh_index))
    if topo is None:   # connectivity only, built on the first call
        topo = geometry.topology[int(mesh_index)] = mesh_topology(ma.indices.numpy(), start, count, device,
                                                                  geometry.mesh_surface[int(mesh_index)])
    # the device checks the new pose's normals (faces that cancel) only once it holds the positions: the old ones are
    # kept until then
    old = wp.clone(geometry.mesh.points[start:start + count]) if normals is None else None
    for dest, src, dtype in copies:
        wp.copy(dest, wp.array(src, dtype=dtype, device=device), dest_offset=start, count=count)
    shading = MeshShading(ma.normal[start:start + count], ma.curvature[start:start + count])
    if normals is None:
        try:
            normals_and_curvature(geometry.mesh.points, topo, device, out=shading)
        except WarpbwError as e:   # it refuses before it writes: only the positions go back
            wp.copy(geometry.mesh.points, old, dest_offset=start, count=count)
            raise WarpbwError(f"{where}vertices: {str(e).removeprefix('points: ')}") from None
    geometry.mesh_bounds[int(mesh_index)] = bounds
    _set_t_eps(ma, geometry.mesh_bounds, device)
    local_curvature(shading.curvature, topo, device, out=shading.curvature)
    geometry.curvature_pending.pop(int(mesh_index), None)   # replaced by the new pose's
    geometry.mesh.refit()


@dataclass
class GBuffer:
    """The G-buffer on the device; ``data`` is what kernels take, the arrays are views of it."""

    data: GBufferData
    width: int
    height: int

    def numpy(self, name: str) -> np.ndarray:
        """A buffer as an (H, W, ...) numpy array, e.g. ``gb.numpy("normal")`` (``GBUFFER_BUFFERS``)."""
        if not (isinstance(name, str) and name in GBUFFER_BUFFERS):   # "normals" was Warp's AttributeError
            raise WarpbwError(f"G-buffer: expected a buffer name, one of {', '.join(GBUFFER_BUFFERS)}, got {name!r}")
        a = getattr(self.data, name).numpy()
        if a.shape[0] == 0:
            raise WarpbwError(f"G-buffer {name}: not rendered (render_gbuffer(..., attributes=True) writes it; the "
                              "renderer's frames leave it out, as no stage reads it)")
        return a.reshape((self.height, self.width) + a.shape[1:])

    @property
    def coverage(self) -> np.ndarray:
        return self.numpy("material") >= 0


def check_camera_of(cam, gb, where: str) -> None:
    """``cam`` a CameraData of ``gb``'s size (a GBuffer or its GBufferData: the camera it was rendered from), else a
    one-line ``WarpbwError`` naming ``where``: the bandwidth pass reads the pixel angle from the camera, and a 48x32
    camera over a 24x16 G-buffer halved b_p without a word."""
    check_instance(cam, CameraData, f"{where}: cam", "a CameraData (make_camera's)")
    if (int(cam.width), int(cam.height)) != (int(gb.width), int(gb.height)):
        raise WarpbwError(f"{where}: cam: {cam.width}x{cam.height}, but the G-buffer is {gb.width}x{gb.height} "
                          "(expected the camera it was rendered from)")


def allocate_gbuffer(width: int, height: int, device: str = "cpu", attributes: bool = True) -> GBuffer:
    """The G-buffer's arrays; without ``attributes`` ``geo_normal`` and ``uv`` are empty (no renderer stage reads
    them: 20 of its 80 bytes per pixel)."""
    check_device(device)
    # a size of 8.5 or -3 failed inside Warp, and 0 gave an empty G-buffer
    width, height = check_count(width, "allocate_gbuffer: width", 1), check_count(height, "allocate_gbuffer: height", 1)
    n = width * height
    g = GBufferData()
    g.position = wp.zeros(n, dtype=wp.vec3, device=device)
    g.normal = wp.zeros(n, dtype=wp.vec3, device=device)
    attributes = check_flag(attributes, "allocate_gbuffer: attributes")
    g.geo_normal = wp.zeros(n if attributes else 0, dtype=wp.vec3, device=device)
    g.tangent = wp.zeros(n, dtype=wp.vec3, device=device)
    g.view = wp.zeros(n, dtype=wp.vec3, device=device)
    g.depth = wp.zeros(n, dtype=wp.float32, device=device)
    g.curvature = wp.zeros(n, dtype=wp.float32, device=device)
    g.uv = wp.zeros(n if attributes else 0, dtype=wp.vec2, device=device)
    g.material = wp.zeros(n, dtype=wp.int32, device=device)
    g.width = int(width)
    g.height = int(height)
    return GBuffer(g, width, height)


def render_gbuffer(cam: CameraData, geometry: Geometry, device: str = "cpu", out: GBuffer | None = None,
                   threads: int | None = None, curvature: bool = True, attributes: bool = True) -> GBuffer:
    """Cast one primary ray per pixel and fill the G-buffer (reusing ``out`` when given); on the CPU the
    pixels are tiled over ``threads`` (default: the cores, as the shading does).  With ``curvature=False`` a
    mesh whose curvature is still deferred (``ensure_curvature``) is not made to derive it, and reads 0: for a
    frame that no bandwidth pass reads.  Without ``attributes`` ``geo_normal`` and ``uv`` are neither allocated
    nor written (``allocate_gbuffer``): the renderer's frames, whose stages read neither."""

    check_device(device)
    check_instance(cam, CameraData, "render_gbuffer: cam", "a CameraData (make_camera's)")
    check_instance(geometry, Geometry, "render_gbuffer: geometry", "a Geometry (build_geometry's)")
    curvature = check_flag(curvature, "render_gbuffer: curvature")   # "no" was truthy
    attributes = check_flag(attributes, "render_gbuffer: attributes")
    check_reach(cam, geometry)
    if curvature:
        ensure_curvature(geometry)
    if out is not None and not (isinstance(out, GBuffer) and (out.width, out.height) == (cam.width, cam.height)):
        got = f"{out.width}x{out.height}" if isinstance(out, GBuffer) else type(out).__name__
        raise WarpbwError(f"render_gbuffer: out: expected a GBuffer of the camera's {cam.width}x{cam.height}, got "
                          f"{got}")
    if out is not None and (out.data.uv.shape[0] > 0) != attributes:   # the kernel would write past empty arrays
        raise WarpbwError(f"render_gbuffer: out: allocated {'without' if attributes else 'with'} geo_normal and uv, "
                          f"expected a G-buffer allocated with attributes={attributes}")
    gb = out if out is not None else allocate_gbuffer(cam.width, cam.height, device, attributes)
    kernel = make_gbuffer_kernel(geometry.has_spheres, geometry.has_mesh, attributes)
    launch_tiled(kernel, cam.width * cam.height,
                 lambda o, c: [cam, geometry.spheres, geometry.mesh_attr, gb.data, o], device, threads)
    return gb


def hide_beyond(gb: GBuffer, cam: CameraData, distance, device: str = "cpu", name: str = "distance") -> int:
    """Empty the G-buffer's pixels whose surface lies beyond ``distance`` (an (H, W) array: per pixel, the
    distance along its centre ray of something nearer that the G-buffer does not hold, ``inf`` where there is
    none), so that no later stage shades a surface that will be drawn over.  A surface exactly at the distance
    stays.  Returns the number of pixels emptied.  ``name``: what errors call ``distance`` (the caller's name
    for it)."""
    check_device(device)
    dist = np.asarray(distance)
    if dist.shape != (gb.height, gb.width):
        raise WarpbwError(f"{name}: expected an ({gb.height}, {gb.width}) array (the camera's "
                          f"{gb.width}x{gb.height}), got shape {dist.shape}")
    if not np.issubdtype(dist.dtype, np.number) or np.isnan(dist).any() or (dist <= 0).any():
        raise WarpbwError(f"{name}: expected positive distances along the centre rays (inf where nothing is "
                          "nearer), got non-positive or NaN values")
    t_max = wp.array(np.minimum(dist, np.float32(RAY_T_MAX)).astype(np.float32).reshape(-1), dtype=wp.float32,
                     device=device)
    hidden = wp.zeros(gb.width * gb.height, dtype=wp.int32, device=device)
    wp.launch(hide_beyond_kernel, dim=gb.width * gb.height, inputs=[cam, t_max, gb.data, hidden], device=device)
    return int(hidden.numpy().sum())
