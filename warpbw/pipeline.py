"""The pipeline: assemble, from a scene, only the stages it needs, and run a frame.

Public:
    ``prepare_scene(scene, device, progress) -> PreparedScene``   load assets, build device data
    ``render_reference(scene_or_prepared, spp, seed, mis, device, progress) -> RenderResult``
    ``scene_summary(scene) -> dict``   what the scene needs (for ``warpbw info``), without loading it

A material kind the scene does not use is not compiled (its branch is removed from the kernels with
``wp.static``); spheres and meshes each have their own G-buffer path; one table per tabulated material
is in memory.  ``RenderResult.stats`` says which stages ran and how long each took.
"""
from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass, field

import numpy as np

from warpbw import brdf as brdf_mod
from warpbw.errors import WarpbwError
from warpbw.gbuffer import (GBuffer, MeshSpec, SphereSpec, build_geometry, make_camera, render_gbuffer)
from warpbw.scene import MeshObject, Scene, SphereObject

# Resolution of the built-in procedural sky (lat-long, 2:1).
PROCEDURAL_SKY_SIZE = (512, 256)


@dataclass
class PreparedScene:
    """A scene with its assets loaded onto a device, ready to render frames."""

    scene: Scene
    device: str
    camera: object
    geometry: object
    env: object
    materials: brdf_mod.MaterialBuffers
    timings: dict = field(default_factory=dict)
    notes: dict = field(default_factory=dict)

    @property
    def width(self) -> int:
        return self.scene.camera.width

    @property
    def height(self) -> int:
        return self.scene.camera.height


@dataclass
class RenderResult:
    image: np.ndarray          # (H, W, 3) float32 linear radiance, 0 where no geometry
    coverage: np.ndarray       # (H, W) bool
    gbuffer: GBuffer
    stats: dict


@contextlib.contextmanager
def _timed(timings: dict, key: str):
    t0 = time.perf_counter()
    try:
        yield
    finally:
        timings[key] = timings.get(key, 0.0) + time.perf_counter() - t0


def _load_environment(scene: Scene, device: str):
    from warpbw import envmap

    e = scene.environment
    if e.file is not None:
        return envmap.load_envmap(e.file, rotation_deg=e.rotation, scale=e.scale, device=device)
    if e.procedural == "sky":
        w, h = PROCEDURAL_SKY_SIZE
        return envmap.envmap_from_array(envmap.procedural_sky(w, h), rotation_deg=e.rotation, scale=e.scale,
                                        name="procedural sky", device=device)
    return envmap.constant_envmap(tuple(c * e.scale for c in e.constant), device=device)


def _material_spec(m, progress: bool, notes: dict) -> brdf_mod.MaterialSpec:
    kind = brdf_mod.KIND_NAMES[m.type]
    if m.type == "lambert":
        return brdf_mod.MaterialSpec(m.name, kind, albedo=m.albedo)
    if m.type == "ggx":
        return brdf_mod.MaterialSpec(m.name, kind, alpha=m.alpha, specular=m.specular, eta=m.eta, k=m.k)
    from precompute.brdf_sampling import brdf_source, load_or_build_sampling

    if m.type == "merl":
        source = brdf_source(m.file)
        merl = source.brdf
        table, origin = load_or_build_sampling(source, m.sampling, progress=progress)
        notes[f"material.{m.name}"] = {"type": "merl", "file": str(m.file), "unmeasured": int(merl.n_unmeasured),
                                       "sampling": origin}
        return brdf_mod.MaterialSpec(m.name, kind, merl=merl.data, linear=m.lookup == "linear", sampler=table)
    source = brdf_source(m.table, m.npf_name)
    npf = source.brdf
    table, origin = load_or_build_sampling(source, m.sampling, progress=progress)
    notes[f"material.{m.name}"] = {"type": "npf", "name": npf.name, "sampling": origin}
    curves = brdf_mod.pack_npf_curves(npf.rho_d, npf.rho_s, npf.D, npf.G1, npf.F)
    return brdf_mod.MaterialSpec(m.name, kind, npf=curves, linear=m.lookup == "linear", sampler=table)


def prepare_scene(scene: Scene, device: str = "cpu", progress: bool = False) -> PreparedScene:
    """Load the scene's assets (environment, meshes, materials) onto ``device``."""
    timings: dict = {}
    notes: dict = {}
    c = scene.camera
    cam = make_camera(c.position, c.look_at, c.up, c.fov, c.width, c.height)
    with _timed(timings, "load_environment"):
        env = _load_environment(scene, device)
    # channel values (not pixels) that were negative or non-finite and set to 0
    notes["environment"] = {"name": env.name, "size": [env.width, env.height], "clamped_values": int(env.n_clamped)}
    order = scene.material_order
    mat_id = {name: i for i, name in enumerate(order)}
    with _timed(timings, "load_materials"):
        specs = [_material_spec(scene.materials[name], progress, notes) for name in order]
        materials = brdf_mod.build_material_table(specs, device=device)
    spheres, meshes = [], []
    with _timed(timings, "load_meshes"):
        for o in scene.objects:
            if isinstance(o, SphereObject):
                spheres.append(SphereSpec(o.center, o.radius, mat_id[o.material]))
            elif isinstance(o, MeshObject):
                from warpbw.io.mesh import load_mesh

                md = load_mesh(o.file, translate=o.translate, scale=o.scale, rotate_y_deg=o.rotate_y)
                meshes.append(MeshSpec(md.vertices, md.faces, md.normals, md.mean_curvature, md.uv,
                                       mat_id[o.material]))
        geometry = build_geometry(spheres, meshes, device=device)
    return PreparedScene(scene, device, cam, geometry, env, materials, timings, notes)


def stages_used(prep: PreparedScene, mis: bool) -> list:
    kinds = sorted(k for k, v in brdf_mod.KIND_NAMES.items() if v in prep.materials.kinds)
    s = ["gbuffer:" + "+".join(n for n, on in (("spheres", prep.geometry.has_spheres),
                                                ("mesh_bvh", prep.geometry.has_mesh)) if on),
         "brdf:" + "+".join(kinds)]
    if any(k in prep.materials.kinds for k in (brdf_mod.MERL, brdf_mod.NPF)):
        s.append("tabulated_sampling")
    s.append("reference_shading" + ("+mis" if mis else ""))
    return s


def render_reference(scene, spp: int, seed: int = 0, mis: bool = False, device: str = "cpu",
                     progress: bool = False, threads: int | None = None) -> RenderResult:
    """Render a frame with the forward reference estimator (002 Eq. 2) at ``spp`` samples per pixel."""
    from warpbw.shading import shade_reference

    if isinstance(spp, bool) or not isinstance(spp, (int, np.integer)) or spp < 1:
        raise WarpbwError(f"spp: expected a positive integer, got {spp!r}")
    import warp as wp

    from warpbw.gbuffer import make_gbuffer_kernel
    from warpbw.shading import make_reference_kernel

    prep = scene if isinstance(scene, PreparedScene) else prepare_scene(scene, device, progress)
    timings = dict(prep.timings) if prep is not scene else {}
    # compile (or load from Warp's kernel cache) the kernels this scene needs, timed on their own so that
    # stage times and throughputs measure rendering only
    t0 = time.perf_counter()
    for kernel in (make_gbuffer_kernel(prep.geometry.has_spheres, prep.geometry.has_mesh),
                   make_reference_kernel(prep.materials.kinds, mis)):
        wp.load_module(kernel.module, device=prep.device)
    timings["compile"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    gb = render_gbuffer(prep.camera, prep.geometry, device=prep.device)
    wp.synchronize_device(prep.device)
    timings["gbuffer"] = time.perf_counter() - t0
    n_cov = int(gb.coverage.sum())
    bar = None
    if progress and n_cov:
        from tqdm import tqdm
        bar = tqdm(total=n_cov, desc=f"shading {spp} spp", unit="px", leave=False)
    t0 = time.perf_counter()
    res = shade_reference(gb, prep.materials, prep.env.data, spp, seed=seed, mis=mis, device=prep.device,
                          threads=threads, progress=bar.update if bar is not None else None)
    timings["shading"] = time.perf_counter() - t0
    if bar is not None:
        bar.close()
    image = res.radiance.numpy().reshape(prep.height, prep.width, 3)
    cov = gb.coverage
    stats = {
        "scene": prep.scene.source,
        "method": "reference",
        "device": prep.device,
        "resolution": [prep.width, prep.height],
        "spp": int(spp),
        "seed": int(seed),
        "mis": bool(mis),
        "stages": stages_used(prep, mis),
        "time_s": {k: round(v, 6) for k, v in timings.items()},
        "pixels": prep.width * prep.height,
        "pixels_covered": n_cov,
        "pixels_shaded": res.pixels_shaded,
        "samples": res.samples,
        "environment_samples": res.samples if mis else 0,
        "samples_per_second": res.samples / timings["shading"] if timings["shading"] > 0 else None,
        "non_finite_samples": res.non_finite,
        "assets": prep.notes,
    }
    return RenderResult(image, cov, gb, stats)


def scene_summary(scene: Scene) -> dict:
    """What the scene needs, from the scene file alone (no asset is loaded)."""
    kinds = sorted({scene.materials[n].type for n in scene.material_order})
    env = scene.environment
    light = (f"file {env.file}" if env.file else f"procedural {env.procedural}" if env.procedural
             else f"constant {list(env.constant)}")
    objects = []
    for o in scene.objects:
        if isinstance(o, SphereObject):
            objects.append(f"sphere r={o.radius:g} at {list(o.center)} material={o.material}")
        else:
            objects.append(f"mesh {o.file} material={o.material}")
    unused = sorted(set(scene.materials) - set(scene.material_order))
    has_mesh = any(isinstance(o, MeshObject) for o in scene.objects)
    stages = ["gbuffer (" + " + ".join(
        n for n, on in (("analytic spheres", any(isinstance(o, SphereObject) for o in scene.objects)),
                        ("mesh BVH", has_mesh)) if on) + ")",
              "brdf: " + ", ".join(kinds)]
    if any(k in ("merl", "npf") for k in kinds):
        stages.append("tabulated importance sampling (002 Sec. 3.3)")
    stages.append("reference shading (002 Eq. 2)")
    return {
        "scene": scene.source,
        "resolution": [scene.camera.width, scene.camera.height],
        "environment": light + f", rotation {env.rotation:g} deg, scale {env.scale:g}",
        "objects": objects,
        "materials": {n: scene.materials[n].type for n in scene.material_order},
        "unused_materials": unused,
        "files": [str(p) for p in scene.files()],
        "stages": stages,
    }
