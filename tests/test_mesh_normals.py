"""Vertex normals and mean curvature on the device (warpbw.mesh_normals), for meshes deformed every frame.

Truth: closed forms (a sphere: radial normals and H = 1/r; a spherical band: H = 1/r on its open rims too;
a plane: H = 0), the invariance of normals and curvature under a rigid motion with uniform scaling
(normals turn with the motion, H scales by 1 / s), and warpbw.io.mesh's float64 numpy implementation of the
same formulas on the real bunny and on degenerate input (and of ``local_curvature``, on the bunny and an
open band).
"""
from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh
import warp as wp
from conftest import latlong_sphere_obj, shared_file
from hypothesis import given, settings
from hypothesis import strategies as st

from warpbw.errors import WarpbwError
from warpbw.io.mesh import load_mesh, local_curvature, mesh_mean_curvature, normals_and_curvature, vertex_normals
from warpbw.mesh_normals import local_curvature as device_local_curvature
from warpbw.mesh_normals import mesh_topology
from warpbw.mesh_normals import normals_and_curvature as device_normals_and_curvature


def on_device(verts, faces, first: int = 0, pad: int = 0):
    """(normals (V, 3), H (V,)) from the device, the mesh stored after ``first`` other points (and ``pad``
    after it), as a mesh in a concatenated array is."""
    v = np.asarray(verts, np.float32)
    pts = np.concatenate([np.full((first, 3), 7.0, np.float32), v, np.full((pad, 3), -7.0, np.float32)])
    topo = mesh_topology(np.asarray(faces).reshape(-1) + first, first, len(v))
    r = device_normals_and_curvature(wp.array(pts, dtype=wp.vec3), topo)
    return r.normals.numpy(), r.curvature.numpy()


def angle_between(a, b):
    """Angles between rows, from the cross product (arccos of float32 dots near 1 loses digits)."""
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.sum(a * b, axis=1))


def _band(r=1.5, n_phi=200, n_th=40):
    """A band of the sphere of radius r between polar angles 20 and 70 degrees: two open rims."""
    ph, th = np.meshgrid(2 * math.pi * np.arange(n_phi) / n_phi,
                         math.radians(20) + np.arange(n_th) * math.radians(50) / (n_th - 1), indexing="ij")
    verts = np.stack([r * np.sin(th) * np.cos(ph), r * np.cos(th), r * np.sin(th) * np.sin(ph)], -1).reshape(-1, 3)
    idx = np.arange(n_phi * n_th).reshape(n_phi, n_th)
    a, b = idx[:, :-1].ravel(), idx[:, 1:].ravel()
    c, d = np.roll(idx, -1, 0)[:, :-1].ravel(), np.roll(idx, -1, 0)[:, 1:].ravel()
    return verts, np.concatenate([np.stack([a, c, b], 1), np.stack([b, c, d], 1)])


def test_sphere_closed_form():
    r = 2.0
    ico = trimesh.creation.icosphere(subdivisions=4, radius=r)
    v = ico.vertices + np.array([0.3, -1.0, 2.0])
    n, h = on_device(v, ico.faces, first=5, pad=3)
    radial = ico.vertices / r
    assert np.degrees(angle_between(n, radial)).max() < 2.0
    assert abs(np.median(h) * r - 1.0) < 0.01 and np.all(np.abs(h * r - 1.0) < 0.05)


def test_open_band_rims_take_their_interior_neighbours_curvature():
    r = 1.5
    v, f = _band(r)
    n, h = on_device(v, f)
    assert np.min(np.sum(n * v / r, 1)) > 0.999
    np.testing.assert_allclose(h, 1 / r, rtol=0.01)
    # and what the host computes from the same (float32) positions, rims included
    v32 = v.astype(np.float32).astype(np.float64)
    np.testing.assert_allclose(h, mesh_mean_curvature(v32, f, vertex_normals(v32, f)), rtol=1e-5)


def test_plane_is_flat():
    x, z = np.meshgrid(np.arange(20) * 0.1, np.arange(30) * 0.07, indexing="ij")
    v = np.stack([x.ravel(), np.zeros(x.size), z.ravel()], -1)
    idx = np.arange(600).reshape(20, 30)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    n, h = on_device(v, np.concatenate([np.stack([a, b, c], 1), np.stack([b, d, c], 1)]))
    assert np.allclose(np.abs(n[:, 1]), 1.0) and np.all(np.abs(h) < 1e-5)


def _torus(R, r, nu, nv):
    """A torus about +Y (major radius R, minor r) on an nu x nv grid of (u, v), faces wound outwards; and the closed
    form of its mean curvature at each vertex, H = (R + 2 r cos v) / (2 r (R + r cos v)) (outward normals: positive
    on the outer equator, and on the inner one negative where R < 2 r)."""
    u, v = np.meshgrid(2 * np.pi * np.arange(nu) / nu, 2 * np.pi * np.arange(nv) / nv, indexing="ij")
    ring = R + r * np.cos(v)
    verts = np.stack([ring * np.cos(u), r * np.sin(v), ring * np.sin(u)], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    a, b, c, d = (i * nv + j), ((i + 1) % nu) * nv + j, ((i + 1) % nu) * nv + (j + 1) % nv, i * nv + (j + 1) % nv
    faces = np.concatenate([np.stack([a, d, c], -1).reshape(-1, 3), np.stack([a, c, b], -1).reshape(-1, 3)])
    return verts, faces, ((R + 2 * r * np.cos(v)) / (2 * r * ring)).reshape(-1)


@pytest.mark.parametrize("scale", [1.0, 1e-3, 1e3])
def test_torus_mean_curvature_changes_sign_as_the_closed_form_on_the_host_and_the_device(scale):
    """H varies and changes sign over a torus (R = 1.5, r = 1: 0.7 on the outer equator, -0.5 on the inner one):
    the cotangent formula's H, host and device, against the closed form, at two tessellations (its error falls about
    fourfold as the grid halves: 0.012 -> 0.003), and in 1 / length at scales 1e-3 and 1e3."""
    errs = []
    for nu, nv in ((48, 32), (96, 64)):
        verts, faces, want = _torus(1.5, 1.0, nu, nv)
        verts = verts * scale
        host = mesh_mean_curvature(verts, faces) * scale
        n_dev, h_dev = on_device(verts, faces, first=3)
        outward = verts / scale - 1.5 * np.stack([np.cos(np.arctan2(verts[:, 2], verts[:, 0])), 0 * verts[:, 1],
                                                  np.sin(np.arctan2(verts[:, 2], verts[:, 0]))], -1)
        assert np.all(np.sum(n_dev * outward, axis=1) > 0.99)   # normals outward, along the tube's radius
        np.testing.assert_allclose(h_dev * scale, host, atol=1e-4)
        assert host.min() < -0.48 and host.max() > 0.68   # the inner equator concave, the outer convex
        errs.append(np.abs(host - want).max())
    assert errs[0] < 0.015 and errs[1] < 0.004 and errs[1] < errs[0] / 3, errs


def test_real_bunny_against_the_host(shared):
    m = load_mesh(shared_file("meshes/bunny.obj"))
    v = m.vertices.astype(np.float64)
    n_host, h_host = normals_and_curvature(v, m.faces)
    n, h = on_device(m.vertices, m.faces)
    assert angle_between(n, n_host).max() < 1e-5
    assert np.abs(h - h_host).max() <= 1e-6 * np.abs(h_host).max() + 1e-5
    c_host = local_curvature(h_host, m.faces)
    topo = mesh_topology(np.asarray(m.faces).reshape(-1) + 4, 4, len(v))   # stored after 4 other points
    c = device_local_curvature(wp.array(h_host.astype(np.float32)), topo).numpy()
    np.testing.assert_allclose(c, c_host, rtol=1e-5)


def test_a_seam_map_makes_its_copies_one_vertex_on_the_device_as_on_the_host(tmp_path):
    """mesh_topology's surface (load_mesh's seam map): the device's normals, H and local curvature of a seamed,
    bumped lat-long sphere (stored after other points) are the host's with the same map, which are load_mesh's of
    the same file, and every seam copy holds exactly its surface vertex's values (a copy left with the split
    topology's: the faces of its own side, or none at a pole)."""
    (tmp_path / "s.obj").write_text(latlong_sphere_obj(32, 16, 2.0, deform=lambda p: p * (
        1.0 + 0.2 * np.sin(2.0 * p[:, :1] + 3.0 * p[:, 1:2] + 1.0))))
    m = load_mesh(tmp_path / "s.obj")
    v, f, s = m.vertices.astype(np.float64), m.faces, m.surface
    n_host, h_host = normals_and_curvature(v, f, s)
    assert angle_between(n_host, m.normals).max() < 1e-5
    np.testing.assert_allclose(h_host, m.mean_curvature, rtol=1e-4, atol=1e-5)   # from the float32 positions
    pts = np.concatenate([np.full((5, 3), 7.0, np.float32), m.vertices])
    topo = mesh_topology(np.asarray(f).reshape(-1) + 5, 5, len(v), surface=s)
    r = device_normals_and_curvature(wp.array(pts, dtype=wp.vec3), topo)
    n, h = r.normals.numpy(), r.curvature.numpy()
    assert angle_between(n, n_host).max() < 1e-5
    assert np.abs(h - h_host).max() <= 1e-6 * np.abs(h_host).max() + 1e-5
    c = device_local_curvature(r.curvature, topo).numpy()
    np.testing.assert_allclose(c, local_curvature(h_host, f, surface=s), rtol=1e-5)
    copies = s != np.arange(len(v))
    assert copies.sum() == 15 + 2 * 32
    for a in (n, h, c):
        np.testing.assert_array_equal(a[copies], a[s[copies]])
    c = int(np.flatnonzero(copies)[0])
    assert s[100] == 100 and not np.any(s[np.arange(len(v)) != 100] == 100)
    with pytest.raises(WarpbwError, match=rf"^mesh topology: surface: 1 vertices name a vertex that is not its own "
                                          rf"surface vertex \(first: vertex 100 names {c}, which names {s[c]}\)"):
        mesh_topology(np.asarray(f).reshape(-1), 0, len(v), surface=np.where(np.arange(len(v)) == 100, c, s))


def test_local_curvature_on_an_open_band_against_the_host():
    """A mesh with open rims (vertices of lower valence), stored after other points, in place (out = input)."""
    verts, faces = _band()
    h = np.random.default_rng(3).normal(0.0, 2.0, len(verts)).astype(np.float32)
    topo = mesh_topology(faces.reshape(-1) + 7, 7, len(verts))
    for passes in (0, 1, 5):
        arr = wp.array(h)
        out = device_local_curvature(arr, topo, passes=passes, out=arr)
        assert out is arr
        np.testing.assert_allclose(arr.numpy(), local_curvature(h, faces, passes=passes), rtol=1e-5, atol=1e-6)
    with pytest.raises(WarpbwError, match="passes"):
        device_local_curvature(wp.array(h), topo, passes=-2)
    with pytest.raises(WarpbwError, match="vertices"):
        device_local_curvature(wp.array(h[:-1]), topo)


@settings(max_examples=15, deadline=None)
@given(st.floats(0.0, 2 * math.pi), st.floats(0.0, 2 * math.pi), st.floats(0.05, 20.0),
       st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1)))
def test_rigid_motion_turns_normals_and_scaling_divides_curvature(yaw, pitch, s, t):
    """Moved by a rotation, scaled by s and shifted by up to 20 s, the band's normals turn with it and its H
    becomes 1 / (s r)."""
    r = 1.5
    v, f = _band(r)
    rot = trimesh.transformations.euler_matrix(pitch, yaw, 0.0)[:3, :3]
    n0, _ = on_device(v, f)
    n1, h1 = on_device(s * (v @ rot.T + 20.0 * np.asarray(t)), f)
    assert angle_between(n1, n0 @ rot.T).max() < 1e-4
    # float32 rounding of points shifted by up to 35 radii: over 40 random shifts and turns, the median error
    # was at most 0.13% and the largest 1.3% (a 1% bound on every vertex failed once: 1.07%)
    e = np.abs(h1 * s * r - 1.0)
    assert np.median(e) < 0.005 and e.max() < 0.03



def _bumpy_sphere(seed, amplitude):
    """An icosphere (162 vertices) with each vertex moved along its radius by up to +-amplitude of the radius:
    convex and concave spots, so H takes both signs."""
    ico = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    rng = np.random.default_rng(seed)
    v = ico.vertices * (1.0 + amplitude * rng.uniform(-1.0, 1.0, (len(ico.vertices), 1)))
    return v, np.asarray(ico.faces)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), amplitude=st.floats(0.0, 0.3))
def test_reversing_every_face_turns_the_normals_and_the_sign_of_h(seed, amplitude):
    """Orientation: the cotangent Laplacian and the mixed areas do not depend on the order of a face's corners, the
    face normal does, so reversing every face negates each vertex normal and H = -(L . n) / (4 A) (positive on a
    convex shape with outward normals, negative where it is concave), on any shape."""
    v, f = _bumpy_sphere(seed, amplitude)
    n, h = on_device(v, f)
    n_rev, h_rev = on_device(v, f[:, ::-1])
    np.testing.assert_allclose(n_rev, -n, atol=1e-6)
    np.testing.assert_allclose(h_rev, -h, rtol=1e-5, atol=1e-5 * np.abs(h).max())
    if amplitude > 0.1:
        assert h.min() < 0.0 < h.max()   # both signs were tested


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), passes=st.integers(0, 12), const=st.floats(-50.0, 50.0))
def test_local_curvature_stays_within_the_range_of_abs_h_and_keeps_a_constant(seed, passes, const):
    """Each lazy pass is a convex combination, y = x / 2 + (one-ring mean) / 2, of |H|: after any number of passes
    every vertex lies within [min |H|, max |H|] (float32 rounding aside), and a constant H of either sign comes back
    as its magnitude."""
    v, f = _bumpy_sphere(0, 0.0)
    topo = mesh_topology(f.reshape(-1), 0, len(v))
    h = np.random.default_rng(seed).normal(0.0, 3.0, len(v)).astype(np.float32)
    out = device_local_curvature(wp.array(h), topo, passes=passes).numpy()
    lo, hi = np.abs(h).min(), np.abs(h).max()
    assert out.min() >= lo * (1 - 1e-6) and out.max() <= hi * (1 + 1e-6)
    if passes > 0:
        assert np.ptp(out) < np.ptp(np.abs(h))   # and it does smooth
    flat = device_local_curvature(wp.array(np.full(len(v), const, np.float32)), topo, passes=passes).numpy()
    np.testing.assert_allclose(flat, abs(np.float32(const)), rtol=1e-6)

def test_degenerate_faces_and_unreferenced_vertices_are_finite_and_match_the_host():
    # vertex 4 is in no face, face 2 has no area (a repeated corner), face 3 is a sliver on a line
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 0, 1], [1, 0.5, 1], [5, 5, 5], [2, 0, 0]], float)
    f = np.array([[0, 2, 1], [1, 2, 3], [1, 1, 3], [0, 1, 5]])
    n, h = on_device(v, f)
    n_host, h_host = normals_and_curvature(v, f)
    assert np.isfinite(n).all() and np.isfinite(h).all()
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-6)
    np.testing.assert_allclose(n[4], [0.0, 1.0, 0.0])   # no incident area: the fallback, +Y
    np.testing.assert_allclose(n, n_host, atol=1e-6)
    np.testing.assert_allclose(h, h_host, rtol=1e-5, atol=1e-6)


def test_a_face_across_two_meshes_is_refused():
    with pytest.raises(WarpbwError, match=r"a face joins vertices in \[3, 6\) to others"):
        mesh_topology(np.array([3, 4, 5, 0, 4, 5]), 3, 3)


def _ico162():
    ico = trimesh.creation.icosphere(subdivisions=2, radius=2.0)
    v, f = np.asarray(ico.vertices, np.float32), np.asarray(ico.faces)
    return v, f, mesh_topology(f.reshape(-1), 0, len(v))


def _no_launch(monkeypatch):
    import warpbw.mesh_normals as MN

    def no_launch(*a, **k):
        raise AssertionError("launched")
    monkeypatch.setattr(MN.wp, "launch", no_launch)


def test_out_arrays_of_the_wrong_size_are_refused_before_the_launch(monkeypatch):
    """An ``out`` of 3 vertices for a 162-vertex mesh was written past its end: the call returned and the process
    aborted later ("double free or corruption").  Checked before any launch (a launch fails the test here, so
    that the old code cannot corrupt this process's heap); local_curvature's ``out`` failed inside wp.copy."""
    from warpbw.mesh_normals import MeshShading

    v, f, topo = _ico162()
    pts = wp.array(v, dtype=wp.vec3)
    curv = wp.zeros(162, dtype=wp.float32)
    _no_launch(monkeypatch)
    for out, name in ((MeshShading(wp.empty(3, dtype=wp.vec3), wp.empty(3, dtype=wp.float32)), "out.normals"),
                      (MeshShading(wp.empty(162, dtype=wp.vec3), wp.empty(3, dtype=wp.float32)), "out.curvature"),
                      (MeshShading(wp.empty(162, dtype=wp.vec3), wp.empty(162, dtype=wp.float64)), "out.curvature")):
        with pytest.raises(WarpbwError, match=rf"^{name}: expected a Warp array of 162 "):
            device_normals_and_curvature(pts, topo, out=out)
    with pytest.raises(WarpbwError, match=r"^out: expected a MeshShading"):
        device_normals_and_curvature(pts, topo, out=(pts, curv))
    with pytest.raises(WarpbwError, match=r"^local_curvature: out: expected a Warp array of 162 float32"):
        device_local_curvature(curv, topo, out=wp.zeros(3, dtype=wp.float32))


def test_points_and_curvature_that_do_not_fit_the_topology_are_refused(monkeypatch):
    """10 points for a 162-vertex topology were read past their end (garbage curvatures); float64 arrays failed
    inside Warp's launch (RuntimeError)."""
    v, f, topo = _ico162()
    _no_launch(monkeypatch)
    with pytest.raises(WarpbwError, match=r"^points: expected a Warp array of at least 162 vec3f \(the mesh's "
                                          r"vertices 0 to 161\), got a Warp array of shape \(10,\) vec3f"):
        device_normals_and_curvature(wp.array(v[:10], dtype=wp.vec3), topo)
    with pytest.raises(WarpbwError, match=r"^points: .*got a Warp array of shape \(162,\) vec3d"):
        device_normals_and_curvature(wp.array(v, dtype=wp.vec3d), topo)
    with pytest.raises(WarpbwError, match=r"^local_curvature: curvature: .*162 float32.*float64"):
        device_local_curvature(wp.zeros(162, dtype=wp.float64), topo)
    with pytest.raises(WarpbwError, match=r"^topology: expected a MeshTopology"):
        device_normals_and_curvature(wp.array(v, dtype=wp.vec3), f)
    with pytest.raises(WarpbwError, match=r"^local_curvature: passes: expected an integer >= 0, got 2.5"):
        device_local_curvature(wp.zeros(162, dtype=wp.float32), topo, passes=2.5)


def test_numpy_points_and_curvature_still_work():
    v, f, topo = _ico162()
    r = device_normals_and_curvature(v, topo)
    np.testing.assert_allclose(r.curvature.numpy(), 0.5, rtol=0.05)
    np.testing.assert_allclose(device_local_curvature(r.curvature.numpy(), topo).numpy(), 0.5, rtol=0.05)


def test_mesh_topology_refuses_ranges_and_indices_that_are_not_vertices():
    """first -1 was taken (its faces' indices shifted), float indices were truncated (1.7 read as 1), count -5
    said "negative dimensions are not allowed", and a count of 10^12 asked for terabytes of counts."""
    f = np.asarray(trimesh.creation.icosphere(subdivisions=1).faces).reshape(-1)
    for args, msg in (((f, -1, 43), r"^first: expected an integer >= 0, got -1"),
                      ((f, 0.0, 42), r"^first: expected an integer"),
                      ((f, 0, -5), r"^count: expected an integer >= 0, got -5"),
                      ((f, 0, 10**12), rf"^count: expected an integer from 0 to {2**31 - 1}"),
                      ((f, 5, 2**31 - 5), rf"^count: expected an integer from 0 to {2**31 - 6}"),
                      ((f + 0.7, 0, 42), r"^indices: expected integer vertex indices, got float64"),
                      ((np.arange(7), 0, 7), r"^indices: expected 3 vertex indices per face, got 7")):
        with pytest.raises(WarpbwError, match=msg):
            mesh_topology(*args)
    assert mesh_topology(np.zeros(0), 0, 3).faces.shape == (0,)   # no faces (an empty list is float64)


def test_a_needle_face_short_against_its_longest_edge_adds_no_curvature_on_the_device():
    """warpbw.mesh_normals: a face whose doubled area is below DEGENERATE_REL_AREA of its LONGEST squared edge adds
    no cotangent weight and no area, as on the host (warpbw.io.mesh, numpy).  Truth: the host's H on a closed mesh
    one of whose faces is a needle 1e6 long and 1e-7 wide (1e-7 of doubled area against a longest squared edge of
    1e12, but above 1e-12 of its shortest, 1): the tetrahedron (0, 2, A, B) with vertex 1 put on its edge 0-2 and the
    needle closing the gap.  (Session 77: it was a tetrahedron over the needle, whose three other faces lie in one
    plane and cancel at the apex to 1e-18 of their areas, a normal made of rounding that the functions now refuse.)"""


    v = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0e6, 1.0e-7, 0.0], [4.0e5, 3.0e5, 5.0e5],
                  [4.0e5, 3.0e5, -5.0e5]], np.float32)
    f = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [2, 0, 4], [3, 2, 4], [0, 3, 4]], np.int64)
    n_host, h_host = normals_and_curvature(v.astype(np.float64), f)
    got = device_normals_and_curvature(wp.array(v, dtype=wp.vec3), mesh_topology(f.reshape(-1), 0, len(v)))
    h = got.curvature.numpy()
    assert np.isfinite(h_host).all() and np.abs(h_host).max() < 1e-3     # the needle left out: H of a big solid
    np.testing.assert_allclose(h, h_host, rtol=1e-4, atol=1e-9)


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_a_vertex_that_is_not_finite_is_refused_naming_its_faces(value):
    """A NaN or infinite vertex gave the vertices around it the fallback normal (0, 1, 0) and a made-up curvature,
    without a word (the session 65 API audit); the host version refuses it, and so does the device one now, with
    the count of faces that touch it (an icosphere vertex has 5 or 6; trimesh's count is the truth).  Stored after
    other finite points, only the mesh's own are read."""
    ico = trimesh.creation.icosphere(subdivisions=2)
    v = np.array(ico.vertices, np.float32)
    v[7, 1] = value
    touching = int(np.count_nonzero(np.any(ico.faces == 7, axis=1)))
    with pytest.raises(WarpbwError, match=rf"^points: {touching} of the mesh's {len(ico.faces)} faces have a vertex "
                                          r"that is not finite \(NaN or infinite\); expected finite positions$"):
        on_device(v, ico.faces, first=4)
    with pytest.raises(WarpbwError):
        normals_and_curvature(v, ico.faces)


def _flattened_icosphere(axis: int):
    """The 162-vertex icosphere pressed flat onto the plane ``axis`` = 0 (a closed surface flattened by a deformation):
    the faces of its two halves now lie on each other, wound in opposite directions.  Returns (vertices, faces, its rim:
    the vertices on that plane before, where the faces of both halves meet and cancel)."""
    ico = trimesh.creation.icosphere(subdivisions=2)
    v = np.array(ico.vertices, np.float64)
    rim = np.abs(v[:, axis]) < 1e-9
    v[:, axis] = 0.0
    return v, np.asarray(ico.faces), rim


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_a_vertex_whose_faces_cancel_is_refused_on_the_device_and_the_host_as_load_mesh_refuses_it(tmp_path, axis):
    """A closed mesh flattened onto a plane (a squash to zero thickness): on its rim the faces of both halves cancel,
    and those vertices took the fallback normal (0, 1, 0) without a word, on the device and on the host.  Flattened
    onto x = 0, 15 of the 16 rim normals were 32 to 180 degrees from the radial ones a pose flattened to 1e-6 of the
    radius gives (within 1.4 degrees): the rim vertex at (0, -1, 0) got +Y.  load_mesh refuses such a pose; the
    per-frame functions now do too, naming the count (session 77): every rim vertex, though the float64 sums came out
    exactly 0 at 4 to 14 of the 16 (``warpbw.io.mesh.CANCEL_REL``).  Truth: the rim, the vertices on the plane before;
    the pose flattened to 1e-6 still passes."""
    v, f, cancelled = _flattened_icosphere(axis)
    assert cancelled.sum() == 16
    p = tmp_path / "flat.obj"
    p.write_text("".join("v %.9g %.9g %.9g\n" % tuple(x) for x in v)
                 + "".join("f %d %d %d\n" % tuple(t + 1) for t in f))
    with pytest.raises(WarpbwError, match="vertices have no normal: the triangles around them cancel"):
        load_mesh(p)   # (its vertex merge welds the halves' coincident vertices: another count)
    said = rf"{int(cancelled.sum())} vertices have no normal: the triangles around them cancel"
    with pytest.raises(WarpbwError, match=rf"^points: {said}"):
        on_device(v, f, first=5, pad=2)
    with pytest.raises(WarpbwError, match=rf"^vertices: {said}"):
        normals_and_curvature(v, f)
    ico = np.asarray(trimesh.creation.icosphere(subdivisions=2).vertices)
    thin = v.copy()
    thin[:, axis] = 1e-6 * ico[:, axis]
    n, _ = on_device(thin, f)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-6)
    np.testing.assert_allclose(n, normals_and_curvature(thin, f)[0], atol=1e-5)


@pytest.mark.parametrize("scale", [1e-4, 1.0, 1e4])
def test_cancelling_faces_are_found_relative_to_their_area_at_any_scale_and_at_any_corner(scale):
    """Round 11: ``cancelled_kernel``'s test is relative (``CANCEL_REL`` of the summed face-normal lengths, every corner
    of a face adding its length).  Truth: two coincident triangles wound in opposite directions cancel at all three
    vertices, the middle one at corner 1 of both faces; the flattened icosphere's 16 rim vertices cancel at every
    scale (float32 positions: their float64 sums are exactly 0), and the icosphere pressed to 1e-6 of its radius keeps
    a normal at every vertex at every scale (its rim's sums are about 1e-6 of the areas: 1e-14 at a scale of 1e-4).
    An absolute test (``CANCEL_REL`` itself) refused that pose at 1e-4, and a length summed at two corners of three
    missed the middle vertex."""
    pair = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]) * scale
    with pytest.raises(WarpbwError, match=r"^points: 3 vertices have no normal"):
        on_device(pair, np.array([[0, 1, 2], [2, 1, 0]]))
    v, f, rim = _flattened_icosphere(1)
    with pytest.raises(WarpbwError, match=rf"^points: {int(rim.sum())} vertices have no normal"):
        on_device(v * scale, f)
    thin = v.copy()   # pressed to 1e-6 of its radius: a surface with a direction at every vertex, at any scale
    thin[:, 1] = 1e-6 * np.asarray(trimesh.creation.icosphere(subdivisions=2).vertices)[:, 1]
    n, _ = on_device(thin * scale, f)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-6)
