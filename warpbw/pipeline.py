"""The pipeline: assemble, from a scene, only the stages it needs, and run a frame.

Public:
    ``prepare_scene(scene, device, progress, sampling) -> PreparedScene``   load assets, build device data
    ``render_reference(scene, spp, seed, mis, device, progress) -> RenderResult`` (``scene``: a Scene or a
                                       PreparedScene; ``device``: where a Scene is prepared, the CPU by default; a
                                       PreparedScene renders where it lives, and another device is refused; so
                                       for render_adaptive)
    ``render_adaptive(scene, budget, seed, mis, n_b, n_min, n_max, ...) -> RenderResult``
    ``prepare_bandwidth(prep, progress, env_signal)``   the bandwidth pass's tables and the meshes' curvature
                                       (adaptive only, built once)
    ``split_planes(scene) -> (surfaces, planes)``   a scene's spheres and meshes, and its planes, as two scenes
    ``surface_geometry(scene, device) -> Geometry``   its spheres and meshes alone on the device (for depth)
    ``render_with_planes(scene, filter_method, spp, seed, method, budget, ...) -> RenderResult``
                                       a scene with both: the spheres and meshes, then the planes over them
    ``frame_memory(width, height, method) -> bytes``, ``FRAME_BYTES_PER_PIXEL``   what a frame takes beyond the
                                       assets (a render warns when its frame would not fit in
                                       ``warpbw.errors.available_memory()``)
    ``mesh_memory(triangles, file_triangles=0) -> bytes``, ``MESH_BYTES_PER_TRIANGLE``,
    ``MESH_FILE_BYTES_PER_TRIANGLE``   what the placed meshes take, read from files of ``file_triangles`` (a render
                                       warns when they would not fit, after loading one copy of each file; ``warpbw
                                       info`` gives it from the files' headers or face lines);
                                       ``CURVATURE_BYTES_PER_TRIANGLE`` what deriving a mesh's curvature takes (the
                                       adaptive method warns first where it would not fit)
    ``scene_summary(scene, method="reference") -> dict``   what the scene needs (for ``warpbw info``), without
                                       loading it; ``SUMMARY_METHODS``, the methods it describes
    ``stages_used(prep, mis, adaptive)``, ``PreparedScene``, ``RenderResult``   the stages a frame ran; the
                                       two results above
    ``RADIANCE_OVERFLOW_MIN``           above this radiance, a frame (reference or adaptive) that drops samples as
                                       non-finite is refused (float32 overflow of radiance times the BRDF)
    ``RADIANCE_UNDERFLOW_MAX``          below this median radiance, an adaptive frame whose allocation reads the
                                       pass's variances is refused (their float32 squares underflow)

A material kind the scene does not use is not compiled (its branch is removed from the kernels with ``wp.static``);
spheres and meshes each have their own G-buffer path; one table per tabulated material is in memory; a mesh's
curvature is derived only for the bandwidth pass.  The environment and the directional ``[[light]]``s are each
optional (a scene has at least one): a scene without an environment compiles no sampling loop and reads or builds no
MERL or NPF material's sampling table, one without lights no light loop.  The adaptive method needs an environment:
it adapts the environment's sampling, and adds the lights' exact term at every pixel.  ``RenderResult.stats`` says
which stages ran and how long each took.

Planes (004) render with :mod:`warpbw.filtering`.  In a scene that has planes beside spheres or meshes,
:func:`render_with_planes` renders the spheres and meshes here (reference or adaptive), then draws the planes
over that image: a pixel shows whichever surface its centre ray hits first (the G-buffer's depth against the
plane's), and each renderer shades only the pixels it wins (the spheres and meshes a plane hides are cut from
their G-buffer before the bandwidth pass and the shading).  Nothing casts a shadow and nothing is reflected in
another object: every surface sees the lights and the environment directly, as in each renderer alone.
"""
from __future__ import annotations

import contextlib
import math
import time
import warnings
from dataclasses import dataclass, field

import numpy as np
import warp as wp

from warpbw import brdf as brdf_mod
from warpbw import envmap
from warpbw.errors import (BRDF_VALUE_MAX, FLOAT32_MAX, INT32_MAX, WarpbwError, available_memory, check_device,
                           check_finite_image, check_flag, check_seed, is_int, warn_if_short_of_memory)
from warpbw.gbuffer import (GBuffer, MeshSpec, SphereSpec, build_geometry, check_reach, ensure_curvature,
                            hide_beyond, render_gbuffer, scene_camera)
from warpbw.scene import MeshObject, PlaneObject, Scene, SphereObject, check_scene


@dataclass
class PreparedScene:
    """A scene with its assets loaded onto a device, ready to render frames."""

    scene: Scene                                      # its checked copy (warpbw.scene.check_scene)
    device: str
    camera: object                                    # warpbw.gbuffer.CameraData of the scene's [camera]
    geometry: object                                  # warpbw.gbuffer.Geometry: its spheres and meshes
    env: object                                       # EnvMap, or None: the scene has [[light]]s only
    materials: brdf_mod.MaterialBuffers
    timings: dict = field(default_factory=dict)       # loading stage (load_environment, ...) -> seconds it took
    notes: dict = field(default_factory=dict)         # what each asset came from (the stats' "assets")
    sources: dict = field(default_factory=dict)      # material name -> BrdfSource (merl / npf only)
    bandwidth: object = None                          # BandwidthTables, built on first adaptive frame
    bandwidth_signal: str | None = None               # the env_signal its nu_a map was analysed on
    lights: object = None                             # warpbw.lights.Lights, or None without [[light]]s
    _keep: list = field(default_factory=list, repr=False)   # the arrays the bandwidth tables in use reference

    @property
    def env_data(self):
        """The environment's device struct, or None (lights only)."""
        return None if self.env is None else self.env.data

    @property
    def width(self) -> int:
        return self.scene.camera.width

    @property
    def height(self) -> int:
        return self.scene.camera.height


@dataclass
class RenderResult:
    image: np.ndarray          # (H, W, 3) float32 linear radiance, 0 where no geometry
    coverage: np.ndarray       # (H, W) bool: the pixel's centre ray hits a sphere or mesh (material >= 0)
    gbuffer: GBuffer           # the frame's G-buffer (warpbw.gbuffer: depth, normal, view, material, ...)
    stats: dict                # the render record (out.json's: stages, time_s in seconds, samples, ...)
    aovs: dict = field(default_factory=dict)   # name -> (H, W) array (adaptive: level, n_p, variance, ...)


@contextlib.contextmanager
def _timed(timings: dict, key: str):
    t0 = time.perf_counter()
    try:
        yield
    finally:
        timings[key] = timings.get(key, 0.0) + time.perf_counter() - t0


def _asset_file(key: str, origin: str, path) -> dict:
    """``{key_file: path}`` for the render record when a table came from the scene's own file (which one it was: two
    records of renders from different files read alike), else nothing."""
    return {f"{key}_file": str(path)} if origin == "file" and path is not None else {}


def _material_spec(m, progress: bool, notes: dict, sources: dict, where: str = "",
                   sampling: bool = True) -> brdf_mod.MaterialSpec:
    """The MaterialSpec of scene material ``m``; ``where`` (the scene file) starts the message of an NPF material
    name the table lacks, which named the table alone.  Without ``sampling`` (a scene lit by directional lights
    alone: no BRDF is sampled) a MERL or NPF material's sampling table is neither read nor built."""
    kind = brdf_mod.KIND_NAMES[m.type]
    if m.type == "lambert":
        return brdf_mod.MaterialSpec(m.name, kind, albedo=m.albedo)
    if m.type == "ggx":
        return brdf_mod.MaterialSpec(m.name, kind, alpha=m.alpha, specular=m.specular, eta=m.eta, k=m.k)
    from precompute.brdf_sampling import brdf_source

    if m.type == "merl":
        source = brdf_source(m.file)
        sources[m.name] = source
        merl = source.brdf
        table, origin = _sampling_table(source, m, progress, sampling)
        notes[f"material.{m.name}"] = {"type": "merl", "file": str(m.file), "unmeasured": int(merl.n_unmeasured),
                                       **_sampling_note(origin, m)}
        return brdf_mod.MaterialSpec(m.name, kind, merl=merl.data, linear=m.lookup == "linear", sampler=table)
    from warpbw.io.npf import UnknownNpfMaterial

    try:
        source = brdf_source(m.table, m.npf_name)
    except UnknownNpfMaterial as exc:
        raise WarpbwError(f"{where + ': ' if where else ''}[material.{m.name}].name: {exc}") from None
    sources[m.name] = source
    npf = source.brdf
    table, origin = _sampling_table(source, m, progress, sampling)
    notes[f"material.{m.name}"] = {"type": "npf", "name": npf.name, **_sampling_note(origin, m)}
    curves = brdf_mod.pack_npf_curves(npf.rho_d, npf.rho_s, npf.D, npf.G1, npf.F)
    return brdf_mod.MaterialSpec(m.name, kind, npf=curves, linear=m.lookup == "linear", sampler=table)


def _sampling_table(source, m, progress: bool, sampling: bool) -> tuple:
    """A tabulated material's sampling table and where it came from, or (None, None) without ``sampling``."""
    if not sampling:
        return None, None
    from precompute.brdf_sampling import load_or_build_sampling

    return load_or_build_sampling(source, m.sampling, progress=progress)


def _sampling_note(origin, m) -> dict:
    """The render record's word on a tabulated material's sampling table (none when none was loaded)."""
    return {} if origin is None else {"sampling": origin, **_asset_file("sampling", origin, m.sampling)}


def prepare_scene(scene: Scene, device: str = "cpu", progress: bool = False, sampling: bool = True) -> PreparedScene:
    """Load the scene's assets (environment, meshes, materials) onto ``device``.  The prepared scene holds a
    checked copy of ``scene`` (``warpbw.scene.check_scene``): a Scene built in Python is checked as a scene file
    is, and editing ``scene`` afterwards changes no frame of it (prepare the edited scene again).  Without
    ``sampling`` the environment's sampling distribution is built by the first frame that samples it (MIS, the
    bandwidth pass), not here: a reference frame without MIS needs none (render_reference of a Scene without MIS
    prepares it so).  Built while loading, its temporaries peak before the map's device copy is made: about 12 bytes
    per texel less than built afterwards."""
    from warpbw.lights import make_lights

    _check_scene(scene)
    scene = check_scene(scene)
    check_device(device)
    progress = check_flag(progress, "prepare_scene: progress")
    sampling = check_flag(sampling, "prepare_scene: sampling")   # "no" built the distribution, 0 deferred it
    if scene.has_planes:
        raise WarpbwError(f"{scene.source}: this renderer (spheres and meshes, 002) does not render planes; scenes "
                          "with planes render with warpbw.filtering.render_filtering, or, beside spheres and meshes, "
                          "with warpbw.pipeline.render_with_planes (warpbw render)")
    timings: dict = {}
    notes: dict = {}
    sources: dict = {}
    cam = scene_camera(scene.camera)
    env = None
    if scene.environment is not None:
        with _timed(timings, "load_environment"):   # without sampling, its distribution on first need (_env_data)
            env = envmap.load_environment(scene.environment, device, sampling=sampling)
        # channel values (not pixels) that were negative or non-finite and set to 0
        notes["environment"] = {"name": env.name, "size": [env.width, env.height],
                                "clamped_values": int(env.n_clamped)}
    lights = make_lights(scene.lights, device)
    if lights is not None:
        notes["lights"] = {"directional": lights.count}
    order = scene.material_order
    mat_id = {name: i for i, name in enumerate(order)}
    with _timed(timings, "load_materials"):
        # directional lights alone are exact: no BRDF is sampled, and no sampling table is read or built
        sampling = scene.environment is not None
        specs = [_material_spec(scene.materials[name], progress, notes, sources, scene.source, sampling)
                 for name in order]
        materials = brdf_mod.build_material_table(specs, device=device, sampling=sampling)
    with _timed(timings, "load_geometry"):   # spheres and meshes to the device, the BVH
        geometry = _geometry(scene, mat_id, device)
    check_reach(cam, geometry, scene.source)   # what each G-buffer pass checks, here with the scene's name
    return PreparedScene(scene, device, cam, geometry, env, materials, timings, notes, sources, lights=lights)


def _geometry(scene: Scene, mat_id: dict, device: str):
    """The scene's spheres and meshes on the device (its planes are left out), material indices from mat_id.  Where
    the meshes' copies would not fit in memory it warns before loading any where the files' headers or face lines
    give their triangles (:func:`_placed_triangles`), else after loading the first copy of each file."""
    from warpbw.io.mesh import load_mesh

    def load(o):
        return load_mesh(o.file, translate=o.translate, scale=o.scale, rotate_y_deg=o.rotate_y)

    def warn_for(triangles: int, file_triangles: int) -> None:
        warn_if_short_of_memory(mesh_memory(triangles, file_triangles), available_memory(),
                                f"placing {len(placed)} meshes ({triangles:,} triangles)",
                                "fewer copies, or a coarser mesh")

    placed = [o for o in scene.objects if isinstance(o, MeshObject)]
    said = _placed_triangles(placed) if placed else None
    if said is not None:
        warn_for(*said)
    first = {}
    for o in placed:
        if str(o.file) not in first:
            first[str(o.file)] = (o, load(o))
    if placed and said is None:
        warn_for(sum(len(first[str(o.file)][1].faces) for o in placed), sum(len(md.faces) for _, md in first.values()))
    spheres, meshes = [], []
    for o in scene.objects:
        if isinstance(o, SphereObject):
            spheres.append(SphereSpec(o.center, o.radius, mat_id[o.material]))
        elif isinstance(o, MeshObject):
            kept, md = first[str(o.file)]
            md = md if kept is o else load(o)
            # its curvature is derived only for a frame with the bandwidth pass (prepare_bandwidth)
            meshes.append(MeshSpec(md.vertices, md.faces, md.normals, lambda md=md: md.mean_curvature, md.uv,
                                   mat_id[o.material], md.surface))
    return build_geometry(spheres, meshes, device=device)


def surface_geometry(scene: Scene, device: str = "cpu"):
    """The scene's spheres and meshes on the device, and nothing else (no environment, material or light is
    loaded; planes are left out): what a G-buffer pass needs to find their depth, e.g. the depth that planes
    drawn over them are tested against (``warpbw bench-filtering``)."""
    return _geometry(scene, {name: i for i, name in enumerate(scene.material_order)}, device)


def stages_used(prep: PreparedScene, mis: bool, adaptive: bool = False) -> list:
    kinds = sorted(k for k, v in brdf_mod.KIND_NAMES.items() if v in prep.materials.kinds)
    s = ["gbuffer:" + "+".join(n for n, on in (("spheres", prep.geometry.has_spheres),
                                                ("mesh_bvh", prep.geometry.has_mesh)) if on),
         "brdf:" + "+".join(kinds)]
    if prep.env is not None and any(k in prep.materials.kinds for k in (brdf_mod.MERL, brdf_mod.NPF)):
        s.append("tabulated_sampling")
    s.append("light:" + "+".join(n for n, on in (("environment", prep.env is not None),
                                                   ("directional", prep.lights is not None)) if on))
    if adaptive:
        s += ["mesh_curvature"] if prep.geometry.has_mesh else []
        s += ["bandwidth_pass", "pyramid", "hierarchical_shading" + ("+mis" if mis else ""), "upsampling"]
    else:
        s.append("reference_shading" + ("+mis" if mis else ""))
    return s


def _load_kernels(prep: PreparedScene, kernels, timings: dict) -> None:
    """Compile (or load from Warp's kernel cache) ``kernels``, timed on their own ("compile") so that
    stage times and throughputs measure rendering only."""
    import warp as wp

    t0 = time.perf_counter()
    for kernel in kernels:
        wp.load_module(kernel.module, device=prep.device)
    timings["compile"] = timings.get("compile", 0.0) + time.perf_counter() - t0


def _env_data(prep: PreparedScene, sampled: bool, timings: dict):
    """The environment's struct for a frame (None without one): with its sampling distribution where the frame
    samples the environment (``sampled``: MIS, the bandwidth pass), built ahead of the frame's clock on the first such
    frame and timed as loading it; else as loaded (a reference frame without MIS only looks the radiance up)."""
    if prep.env is None:
        return None
    if not sampled:
        return prep.env.lookup_data
    if not prep.env.has_sampling:
        t0 = time.perf_counter()
        envmap.ensure_sampling(prep.env)
        for t in {id(d): d for d in (prep.timings, timings)}.values():   # a Scene's frame holds a copy of the first
            t["load_environment"] = t.get("load_environment", 0.0) + time.perf_counter() - t0
    return prep.env.data


def _check_scene(scene) -> None:
    if not isinstance(scene, Scene):   # a path or None failed on a missing attribute, deep inside
        raise WarpbwError(f"scene: expected a warpbw.scene.Scene (from load_scene / parse_scene) or a PreparedScene, "
                          f"got {type(scene).__name__}")


def _prepared(scene, device: str | None, progress: bool, sampling: bool = True) -> tuple[PreparedScene, dict]:
    """The renderers' ``device``: where a Scene is prepared (None: the CPU); a PreparedScene renders where it lives,
    and another device named for it is refused (it was ignored: "cuda" rendered on the CPU)."""
    if isinstance(scene, PreparedScene):
        if device is None:
            return scene, {}
        check_device(device)
        if wp.get_device(device) != wp.get_device(scene.device):
            raise WarpbwError(f"device {device}: the prepared scene {scene.scene.source} lives on {scene.device}; "
                              "prepare it on that device, or pass the Scene")
        return scene, {}
    prep = prepare_scene(scene, "cpu" if device is None else device, progress, sampling)
    return prep, dict(prep.timings)


def frame_memory(width: int, height: int, method: str) -> int:
    """Bytes a ``method`` frame ("reference" or "adaptive") of ``width`` x ``height`` takes beyond the scene's
    assets (``FRAME_BYTES_PER_PIXEL``; measured on the CPU)."""
    return FRAME_BYTES_PER_PIXEL[method] * int(width) * int(height)


def _warn_if_frame_exceeds_memory(prep: PreparedScene, method: str) -> None:
    """A frame larger than the memory left is killed by the system without a word (no error, no image): warn first,
    naming the resolution, so that a user who meant a smaller one can stop it."""
    warn_if_short_of_memory(frame_memory(prep.width, prep.height, method), available_memory(),
                            f"{prep.scene.source}: a {prep.width}x{prep.height} {method} frame",
                            "lower [camera].resolution", stacklevel=3)


def _clip_kernels(clip_distance) -> tuple:
    """The kernels a ``clip_distance`` adds to a frame (none without one)."""
    from warpbw.gbuffer import hide_beyond_kernel

    return (hide_beyond_kernel,) if clip_distance is not None else ()


def _gbuffer(prep: PreparedScene, timings: dict, threads: int | None = None, clip_distance=None,
             curvature: bool = True) -> tuple:
    """The G-buffer, and the number of its pixels ``clip_distance`` hid (None without one).  Without
    ``curvature`` a mesh's curvature is not derived for it (``warpbw.gbuffer.render_gbuffer``)."""
    import warp as wp

    t0 = time.perf_counter()
    gb = render_gbuffer(prep.camera, prep.geometry, device=prep.device, threads=threads, curvature=curvature,
                        attributes=False)   # geo_normal and uv: no stage reads them
    hidden = None
    if clip_distance is not None:
        hidden = hide_beyond(gb, prep.camera, clip_distance, device=prep.device, name="clip_distance")
    wp.synchronize_device(prep.device)
    timings["gbuffer"] = time.perf_counter() - t0
    return gb, hidden


# A sample multiplies the light's radiance by a BRDF value (up to BRDF_VALUE_MAX) in float32: above this radiance a
# sample the shading drops as non-finite is that product's overflow, and the frame, short of its light, is refused
# (reference and adaptive frames).
RADIANCE_OVERFLOW_MIN = FLOAT32_MAX / BRDF_VALUE_MAX
# The bandwidth pass's variances are float32 sums of squared radiance: below the square root of float32's smallest
# normal they underflow, and every allocation but "uniform" reads them.  A probe of one texel of 1e4 over a sky of 1,
# scaled by 1e-25, took other N_p than at scale 1 and rendered up to 0.999 of the brightest pixel away from 1e-25 times
# that frame, without a word (session 77); at 1e-19 and 1e-20 it still took the same.
RADIANCE_UNDERFLOW_MAX = math.sqrt(float(np.finfo(np.float32).tiny))
# Memory a frame takes per pixel, beyond the scene's assets: the slope of `warpbw render`'s peak RSS from 1024^2 to
# 2048^2 with every pixel covered (a sphere filling the frame, a MERL material; session 79: 104 and 256 bytes, its
# previews written a block at a time), rounded up.  Session 62's slope over the demo scene, whose spheres cover a
# fraction of it, read 93 and 228; its previews' whole-image temporaries then added 144 bytes per pixel (a 2048^2
# reference render peaked at 1.19 GB).  A 16384^2 frame (MAX_RESOLUTION) then needs 30 and 70 GB.
FRAME_BYTES_PER_PIXEL = {"reference": 110, "adaptive": 260}
# Bytes a placed mesh takes per triangle (its host copies, the merged device arrays, the BVH): 12.9 and 12.4 MB per
# copy of the 69,666-triangle bunny (peak RSS of `warpbw render`, reference and adaptive, with 10 and 40 copies;
# session 64), rounded up.
MESH_BYTES_PER_TRIANGLE = 200
# Bytes each mesh file's triangles take beyond its copies' (trimesh's parse and the first copy's host arrays): a
# 1,114,656-triangle OBJ (the bunny subdivided twice) placed once took 416 bytes per triangle, each copy more 124
# (peak RSS of a 64x64 reference render, session 79), rounded up.  MESH_BYTES_PER_TRIANGLE alone read it as 223 MB,
# where the render took 435 MB more than the original bunny's.
MESH_FILE_BYTES_PER_TRIANGLE = 300
# Bytes per triangle of a mesh whose curvature the bandwidth pass derives (adaptive only; one mesh at a time, on top
# of what is held): 479 MB at the peak for that 1.1M-triangle mesh (session 79), rounded up.
CURVATURE_BYTES_PER_TRIANGLE = 450


def mesh_memory(triangles: int, file_triangles: int = 0) -> int:
    """Bytes ``triangles`` placed triangles take (``MESH_BYTES_PER_TRIANGLE``), read from files of
    ``file_triangles`` triangles together (``MESH_FILE_BYTES_PER_TRIANGLE``, each file counted once)."""
    return MESH_BYTES_PER_TRIANGLE * int(triangles) + MESH_FILE_BYTES_PER_TRIANGLE * int(file_triangles)


def _check_overflowed_samples(prep: PreparedScene, n_bad: int, samples: int, pixels: int = 0) -> None:
    """Refuse a frame whose shading dropped samples, or the directional lights' terms at its ``pixels`` shaded, to
    float32 overflow (a white furnace at radiance 1e32 read 0.42 of its radiance, status 0); below
    RADIANCE_OVERFLOW_MIN the count stays a warning (warpbw render)."""
    if not n_bad:   # every frame: the probe's maximum is only read when a sample was dropped
        return
    env_max = float(np.max(prep.env.pixels)) if prep.env is not None else 0.0
    l_max = max([env_max] + [max(li.radiance) for li in prep.scene.lights])
    if l_max > RADIANCE_OVERFLOW_MIN:
        # the count holds the lights' terms too: a scene of lights alone said "1 of 0 samples", and named an
        # [environment] it does not have
        terms = pixels * len(prep.scene.lights)
        what = (f"{n_bad} of {samples + terms} terms ({samples} samples, {terms} of directional lights)" if terms
                else f"{n_bad} of {samples} samples")
        lower = " or ".join(w for w, on in (("[environment] scale", prep.env is not None),
                                            ("the lights' radiance", bool(prep.scene.lights))) if on)
        raise WarpbwError(f"{prep.scene.source}: {what} overflowed float32 (radiance up to {l_max:.3g}, times the "
                          f"BRDF, passes {FLOAT32_MAX:.3g}) and the image would be missing their light: lower {lower}")


def _check_mis(mis) -> None:
    check_flag(mis, "mis")   # "yes" (or "no") switched MIS on


def _check_spp(spp) -> None:
    if not is_int(spp) or spp < 1:
        raise WarpbwError(f"spp: expected a positive integer, got {spp!r}")
    if spp > INT32_MAX:  # the shading kernel's sample loop counts in int32
        raise WarpbwError(f"spp: expected a positive integer <= {INT32_MAX}, got {spp!r}")


def render_reference(scene, spp: int, seed: int = 0, mis: bool = False, device: str | None = None,
                     progress: bool = False, threads: int | None = None, clip_distance=None) -> RenderResult:
    """Render a frame with the forward reference estimator (002 Eq. 2) at ``spp`` samples per pixel.
    ``clip_distance`` (an (H, W) array, ``inf`` where nothing is nearer): per pixel, the distance along the
    centre ray of something nearer that will be drawn over this image; surfaces beyond it are not shaded and
    not covered (``stats["pixels_hidden"]`` counts them)."""
    from warpbw.gbuffer import make_gbuffer_kernel
    from warpbw.launch import progress_bar
    from warpbw.shading import make_reference_kernel, shade_reference

    _check_spp(spp)
    check_seed(seed)
    _check_mis(mis)
    prep, timings = _prepared(scene, device, progress, sampling=mis)   # without MIS: no environment sampling
    _warn_if_frame_exceeds_memory(prep, "reference")
    env_data = _env_data(prep, mis, timings)   # without MIS no environment direction is sampled
    _load_kernels(prep, (make_gbuffer_kernel(prep.geometry.has_spheres, prep.geometry.has_mesh, False),
                         make_reference_kernel(prep.materials.kinds, mis, has_env=prep.env is not None,
                                               has_lights=prep.lights is not None))
                  + _clip_kernels(clip_distance), timings)
    gb, hidden = _gbuffer(prep, timings, threads, clip_distance, curvature=False)   # no bandwidth pass reads it
    n_cov = int(gb.coverage.sum())
    spp_taken = spp if prep.env is not None else 0   # directional lights alone are exact: no sample is taken
    with progress_bar(n_cov, f"shading {spp} spp" if spp_taken else "shading (lights, exact)",
                      bool(progress and n_cov)) as step:
        t0 = time.perf_counter()   # the bar's making is not the frame's
        res = shade_reference(gb, prep.materials, env_data, spp, seed=seed, mis=mis, device=prep.device,
                              threads=threads, progress=step, lights=prep.lights)
    timings["shading"] = time.perf_counter() - t0
    timings["frame"] = timings["gbuffer"] + timings["shading"]   # as the adaptive frame's: no loading, no compiling
    _check_overflowed_samples(prep, res.non_finite, res.samples, res.pixels_shaded)
    image = res.radiance.numpy().reshape(prep.height, prep.width, 3)
    # MIS weighs environment samples: under directional lights alone there are none, and the record says so
    stats = _base_stats(prep, "reference", seed, mis and spp_taken > 0, timings, n_cov)
    stats.update({
        "spp": int(spp_taken),
        "pixels_shaded": res.pixels_shaded,
        "samples": res.samples,
        "environment_samples": res.samples if mis else 0,
        "samples_per_second": res.samples / timings["shading"] if timings["shading"] > 0 else None,
        "non_finite_samples": res.non_finite,
    })
    if hidden is not None:
        stats["pixels_hidden"] = hidden
    stats["time_s"] = {k: round(v, 6) for k, v in timings.items()}
    check_finite_image(image, prep.scene.source)
    _warn_samples(stats)
    return RenderResult(image, gb.coverage, gb, stats)


def _warn_samples(stats: dict) -> None:
    """A warning each (the command lines print it as one line): samples dropped as non-finite, and an adaptive
    budget below ``n_min`` per shaded pixel (every shaded pixel then takes ``n_min``: more samples than asked).
    Both were said by ``warpbw render`` only; from Python they were a stats entry to look for."""
    if stats.get("non_finite_samples"):
        warnings.warn(f"{stats['scene']}: {stats['non_finite_samples']} samples had a non-finite contribution and "
                      "were dropped", RuntimeWarning, stacklevel=3)
    a = stats.get("allocation")
    if a is not None and a["over_budget"]:
        warnings.warn(f"budget {a['budget_spp']:g} is below {a['n_min']} sample(s) per shaded pixel "
                      f"({a['planned_pixels']} pixels to shade, {a['budget_samples']} samples): every shaded pixel "
                      f"got {a['n_min']}, {a['planned_samples']} samples in all", RuntimeWarning, stacklevel=3)


def _base_stats(prep: PreparedScene, method: str, seed: int, mis: bool, timings: dict, n_cov: int,
                adaptive: bool = False) -> dict:
    return {
        "scene": prep.scene.source,
        "method": method,
        "device": prep.device,
        "resolution": [prep.width, prep.height],
        "seed": int(seed),
        "mis": bool(mis),
        "stages": stages_used(prep, mis, adaptive),
        "time_s": {},
        "pixels": prep.width * prep.height,
        "pixels_covered": n_cov,
        "assets": prep.notes,
    }


class _AnalyticSource:
    """An analytic material as a bandwidth-table source: evaluated by the renderer's own kernel,
    cached by its parameters (a Lambert lobe is constant: its table is 0 and is not built)."""

    path = None

    def __init__(self, prep: PreparedScene, index: int, m):
        import hashlib

        self._prep, self._index = prep, index
        params = (m.type, m.alpha, m.specular, m.eta, m.k)
        self.name = f"{m.type}:{m.name}"
        self.digest = "params:" + hashlib.blake2b(repr(params).encode(), digest_size=16).hexdigest()

    def evaluate(self, wi, wo):
        return brdf_mod.eval_brdf(self._prep.materials, self._index, wi, wo, device=self._prep.device)


def prepare_bandwidth(prep: PreparedScene, progress: bool = False, env_signal: str | None = None):
    """The bandwidth pass's inputs (adaptive method only; built once per prepared scene and ``env_signal``): the
    environment's nu_a map, analysed on ``env_signal`` (:func:`warpbw.bandwidth.env_signal`; default "log"),
    and one nu_rho table per material, from the scene's ``bandwidth`` file, the cache, or built (MERL and NPF
    materials: of the BRDF read with the material's ``lookup``; analytic materials: from the renderer's own BRDF
    evaluation).  Derives the meshes' curvature too (Eq. 3's c, which only this pass
    reads; timed as ``load_mesh_curvature``)."""
    from precompute.brdf_bandwidth import SHAPE as BW_TABLE_SHAPE, load_or_build_bandwidth
    from precompute.brdf_sampling import with_lookup
    from warpbw.bandwidth import (ENV_SIGNAL_DEFAULT, check_env_signal, env_bandwidth_map, make_bandwidth_tables,
                                  nu_env_table)

    env_signal = check_env_signal(ENV_SIGNAL_DEFAULT if env_signal is None else env_signal)
    if prep.bandwidth is not None and prep.bandwidth_signal == env_signal:
        return prep.bandwidth
    if prep.env is None:
        raise WarpbwError(f"{prep.scene.source}: the bandwidth pass needs an [environment] ([[light]]s are exact "
                          "and take no part in it)")
    with _timed(prep.timings, "load_env_bandwidth"):
        nu_env, origin = env_bandwidth_map(prep.env.pixels, prep.env.name, signal=env_signal, progress=progress,
                                           source=prep.env.source_digest or None)   # shared by every exposure
    prep.notes["environment"]["bandwidth"] = origin
    prep.notes["environment"]["bandwidth_signal"] = env_signal
    tables = []
    with _timed(prep.timings, "load_brdf_bandwidth"):
        for i, name in enumerate(prep.scene.material_order):
            m = prep.scene.materials[name]
            if name in prep.sources:   # the table of the BRDF as the material shades it: read with its lookup
                table, origin = load_or_build_bandwidth(with_lookup(prep.sources[name], m.lookup), m.bandwidth,
                                                        progress=progress)
            elif m.type == "lambert":
                table, origin = np.zeros(BW_TABLE_SHAPE, np.float32), "constant lobe"
            else:
                table, origin = load_or_build_bandwidth(_AnalyticSource(prep, i, m), progress=progress)
            prep.notes.setdefault(f"material.{name}", {"type": m.type}).update(
                bandwidth=origin, **_asset_file("bandwidth", origin, m.bandwidth))
            tables.append(table)
        struct, keep = make_bandwidth_tables(nu_env_table(nu_env), np.stack(tables),
                                             device=prep.device)
    prep.bandwidth, prep.bandwidth_signal = struct, env_signal
    prep._keep = keep   # the tables of a signal read before are let go (extended, every switch of signal kept its own)
    if prep.geometry.curvature_pending:
        largest = max(len(faces) for _, faces in prep.geometry.curvature_pending.values())
        warn_if_short_of_memory(CURVATURE_BYTES_PER_TRIANGLE * largest, available_memory(),
                                f"{prep.scene.source}: deriving the curvature of a mesh of {largest:,} triangles",
                                "a coarser mesh; the reference method does not derive it", stacklevel=2)
        with _timed(prep.timings, "load_mesh_curvature"):   # Eq. 3's c, for the G-buffer of this pass
            ensure_curvature(prep.geometry)
    return struct


def _check_pass_finite(buf, source: str, mis: bool = True) -> None:
    """Refuse a frame whose bandwidth pass overflowed.  The pass sums squared radiance in float32 (Eq. 9's
    chi * w and the second moments of MIS, or without ``mis`` of BRDF sampling), so radiance past
    ~sqrt(FLOAT32_MAX) = 1.8e19 (less where a BRDF peaks) gives inf sigma2: an inf variance AOV, and N_p =
    n_max on every pixel whatever the budget."""
    cov = buf.coverage.reshape(-1)
    bad = np.zeros(cov.shape, bool)
    # each array once: without MIS the estimator's variance and the allocation's key are the same one
    arrays = {id(a): a for a in (buf.sigma2, buf.sigma2_rel, buf.estimator_variance(mis), buf.measured_key(mis))
              if a is not None}
    for a in arrays.values():
        bad |= ~np.isfinite(a.numpy())
    n_bad = int((bad & cov).sum())
    if n_bad:
        raise WarpbwError(f"{source}: the bandwidth pass's variance (squared radiance) overflowed float32 at {n_bad} "
                          f"of {int(cov.sum())} covered pixels; --method adaptive expects radiance (the light's "
                          f"times the BRDF's) well below sqrt({FLOAT32_MAX:.3g}) = {math.sqrt(FLOAT32_MAX):.2g}: lower "
                          "[environment] scale or the map's values, or the material's BRDF values, or render with "
                          "--method reference")


def _check_pass_underflow(buf, source: str, allocation: str) -> None:
    """Refuse a frame so dark that the bandwidth pass's squares of radiance underflow float32 (the median of its
    lit pixels' radiance from the environment, the pass's own estimate, below ``RADIANCE_UNDERFLOW_MAX``), for an
    allocation that reads the pass's variances: its
    N_p would not be those of the same scene brighter (README, "Exposure").  A black frame (no lit pixel) and the
    "uniform" allocation are left alone."""
    if allocation == "uniform" or buf.mu is None:
        return
    m = buf.median_lit_mu()
    if 0.0 < m < RADIANCE_UNDERFLOW_MAX:
        raise WarpbwError(f"{source}: the frame's radiance from the environment (median {m:.3g} over its lit "
                          f"pixels) is below sqrt(float32's smallest normal) = {RADIANCE_UNDERFLOW_MAX:.2g}, where the "
                          f"bandwidth pass's squared radiance underflows and the {allocation!r} allocation is no "
                          "longer that of the scene brighter: raise [environment] scale, or use --allocation uniform "
                          "or --method reference")


def _nothing_to_adapt(scene: Scene) -> WarpbwError:
    """The adaptive method's refusal of a scene without an environment."""
    return WarpbwError(f"{scene.source}: the adaptive method needs an [environment] to adapt to: [[light]]s "
                       "alone are exact at any spp (use the reference method)")


def render_adaptive(scene, budget: float, seed: int = 0, mis: bool = False, n_b: int | None = None,
                    n_min: int | None = None, n_max: int | None = None, preconvolved: bool = False,
                    allocation: str | None = None, nyquist: float | None = None, stride: int | None = None,
                    pool_radius: int | None = None, device: str | None = None, progress: bool = False,
                    threads: int | None = None, clip_distance=None, upsample: str | None = None,
                    env_signal: str | None = None) -> RenderResult:
    """Render a frame with bandwidth prediction and hierarchical adaptive shading (002 Sec. 2-3).

    ``budget`` is the mean number of samples per covered pixel (the total is budget x covered pixels),
    spread over the pixels the hierarchy shades by ``allocation`` (default: in proportion to the standard
    deviation the bandwidth pass measures, :func:`warpbw.bandwidth.allocate_samples`).  ``aovs`` holds (H, W)
    maps: ``level`` (the pass's level, int32), ``n_p`` (the samples allocated per pixel, N_p), ``spp`` (the samples
    the frame took at a pixel: a texel shaded at a coarser level takes the largest N_p of its footprint, Sec. 3.1's
    max filter, at one pixel, and a pixel shaded at two levels the samples of both; up-sampled pixels take none;
    int32, summing to ``stats["samples"]``), ``variance`` (the predicted variance of an estimate of the pixel's
    allocated N_p samples, ``SampleAllocation.variance``: the plan's, not of the frame's pixel, which took the ``spp``
    map's samples, or none where up-sampled), ``shaded`` (the pixels shaded rather than up-sampled), ``shaded_level``
    (the finest level a pixel was shaded at, -1 where it was up-sampled or is empty; int32), ``b_p`` (image bandwidth,
    cycles per pixel, 002 Eq. 6) and ``sigma2`` (the pass's radiance variance).  ``stride`` and ``pool_radius`` set
    how the bandwidth pass shares its directions (:func:`warpbw.bandwidth.bandwidth_pass`);
    ``upsample`` how the hierarchy up-samples ("normal", the default, or "paper": :mod:`warpbw.upsample`);
    ``env_signal`` what the probe's angular bandwidth is analysed on ("log", the default, or "radiance", 002's:
    :func:`warpbw.bandwidth.env_signal`); ``preconvolved`` which bound the pass writes in ``sigma2``, 002 Eq. 10 (the
    light's nu_a replaced by the BRDF's nu_rho, Sec. 2.5) instead of Eq. 9: the frame is still shaded from the probe
    itself (pre-convolved shading is not built), so only an allocation that reads sigma2 ("variance", "sqrt",
    "relative") changes N_p and the frame with it; under the default ("measured") only the ``sigma2`` map changes.
    The scene needs an environment; its directional lights are added exactly
    at every pixel (:mod:`warpbw.adaptive`).  ``clip_distance`` hides what lies beyond it, as for
    :func:`render_reference`: a hidden pixel takes no part in the pass, the budget or the hierarchy."""
    from warpbw import adaptive, bandwidth
    from warpbw.gbuffer import make_gbuffer_kernel
    from warpbw.launch import progress_bar
    from warpbw.shading import make_reference_kernel
    from warpbw.upsample import UPSAMPLE_DEFAULT, check_upsample_mode

    n_b = bandwidth.N_B_DEFAULT if n_b is None else n_b
    n_min = bandwidth.N_P_MIN_DEFAULT if n_min is None else n_min
    allocation = bandwidth.ALLOCATION_DEFAULT if allocation is None else allocation
    nyquist = bandwidth.NYQUIST_FACTOR if nyquist is None else nyquist
    pool_radius = bandwidth.POOL_RADIUS_DEFAULT if pool_radius is None else pool_radius
    upsample = UPSAMPLE_DEFAULT if upsample is None else upsample
    check_upsample_mode(upsample)
    env_signal = bandwidth.check_env_signal(bandwidth.ENV_SIGNAL_DEFAULT if env_signal is None else env_signal)
    bandwidth.direction_set(n_b)  # validates n_b before any work
    check_seed(seed)
    _check_mis(mis)
    check_flag(preconvolved, "preconvolved")   # "no" once ran the Eq. 10 bound
    prep, timings = _prepared(scene, device, progress)
    if prep.env is None:
        raise _nothing_to_adapt(prep.scene)
    _warn_if_frame_exceeds_memory(prep, "adaptive")
    env_data = _env_data(prep, True, timings)   # the bandwidth pass samples the environment whatever mis is
    # the default block is no larger than the image (a 1 x 1 frame was refused with "stride: expected 1 to 1")
    stride = min(bandwidth.PASS_STRIDE_DEFAULT, max(prep.width, prep.height)) if stride is None else stride
    loads = prep.bandwidth is None or prep.bandwidth_signal != env_signal
    before = dict(prep.timings)
    tables = prepare_bandwidth(prep, progress, env_signal)
    if loads:   # this frame loaded or built the pass's inputs (the first on a prepared scene too): it says so
        for k in ("load_env_bandwidth", "load_brdf_bandwidth", "load_mesh_curvature"):
            if prep.timings.get(k) != before.get(k):
                # its own time: prep.timings sums every load (a frame that switched env_signal gave the sum of all
                # the switches so far, and the curvature a frame before it derived)
                timings[k] = prep.timings[k] - before.get(k, 0.0)
    _load_kernels(prep, (make_gbuffer_kernel(prep.geometry.has_spheres, prep.geometry.has_mesh, False),
                         bandwidth.make_bandwidth_kernel(prep.materials.kinds, preconvolved),
                         make_reference_kernel(prep.materials.kinds, mis, per_pixel_spp=True))
                  + ((make_reference_kernel(prep.materials.kinds, mis, has_env=False, has_lights=True),)
                     if prep.lights is not None else ()) + _clip_kernels(clip_distance), timings)
    t0 = time.perf_counter()
    adaptive.load_kernels(prep.device)
    bandwidth.load_kernels(prep.device, relative=allocation == "relative")
    timings["compile"] += time.perf_counter() - t0
    gb, hidden = _gbuffer(prep, timings, threads, clip_distance)
    t0 = time.perf_counter()
    buf = bandwidth.bandwidth_pass(gb, prep.camera, prep.materials, env_data, tables, n_b=n_b, seed=seed,
                                   preconvolved=preconvolved, nyquist=nyquist, stride=stride,
                                   pool_radius=pool_radius, device=prep.device, threads=threads,
                                   relative=allocation == "relative")   # only that allocation reads sigma2_rel
    _check_pass_finite(buf, prep.scene.source, mis)
    _check_pass_underflow(buf, prep.scene.source, allocation)
    t_pass = time.perf_counter() - t0
    t0 = time.perf_counter()
    plan = adaptive.plan_hierarchy(gb, prep.camera, buf.level, device=prep.device)
    t_plan = time.perf_counter() - t0
    t0 = time.perf_counter()
    alloc = bandwidth.allocate_samples(buf, budget, n_min=n_min, n_max=n_max, allocation=allocation,
                                       device=prep.device, mis=mis, plan=plan.shade_masks())
    timings["bandwidth"] = t_pass + time.perf_counter() - t0
    with progress_bar(plan.shaded_texels, f"shading adaptive, budget {budget:g} spp",
                      bool(progress and plan.shaded_texels)) as step:
        t0 = time.perf_counter()   # the bar's making is not the frame's, as in render_reference
        res = adaptive.shade_hierarchical(gb, prep.camera, prep.materials, env_data, buf.level, alloc.n_p,
                                          seed=seed, mis=mis, device=prep.device, threads=threads, lights=prep.lights,
                                          upsample=upsample, plan=plan, progress=step)
    t_h = time.perf_counter() - t0 + t_plan
    n_cov = int(gb.coverage.sum())
    # the lights' exact term is added after the hierarchy, outside the pass (whose overflow check sees no light): a
    # term that overflowed was dropped, and the frame is refused as the reference's is
    _check_overflowed_samples(prep, res.stats["non_finite_samples"], res.stats["samples"], n_cov)
    timings["shading"] = res.stats["time_s"]["shading"]
    timings["upsampling"] = res.stats["time_s"]["upsampling"]
    if prep.lights is not None:
        timings["lights"] = res.stats["time_s"]["lights"]
    timings["hierarchy"] = max(t_h - timings["shading"] - timings["upsampling"] - timings.get("lights", 0.0), 0.0)
    timings["frame"] = timings["gbuffer"] + timings["bandwidth"] + t_h
    H, W = prep.height, prep.width
    stats = _base_stats(prep, "adaptive", seed, mis, timings, n_cov, adaptive=True)
    stats.update({
        "budget_spp": float(budget),
        "n_b": int(n_b),
        "bandwidth_stride": int(stride),
        "bandwidth_pool_radius": int(pool_radius),
        "upsample": upsample,
        "env_signal": env_signal,
        "bandwidth_traced_pixels": int(buf.traced_pixels),
        "preconvolved_bound": bool(preconvolved),
        "allocation": alloc.stats,
        "levels": res.stats["levels"],
        "pixels_shaded": res.stats["pixels_shaded"],
        "unplanned_shaded": res.stats["unplanned_shaded"],
        "shaded_fraction": res.stats["shaded_fraction"],
        "samples": res.stats["samples"],
        "non_finite_samples": res.stats["non_finite_samples"],
        "samples_per_covered_pixel": res.stats["samples"] / n_cov if n_cov else 0.0,
        "environment_samples": res.stats["samples"] if mis else 0,
        "bandwidth_time_fraction": timings["bandwidth"] / timings["frame"] if timings["frame"] > 0 else 0.0,
    })
    if hidden is not None:
        stats["pixels_hidden"] = hidden
    stats["time_s"] = {k: round(v, 6) for k, v in timings.items()}
    aovs = {
        "level": buf.level.numpy().reshape(H, W),
        "n_p": alloc.n_p,
        "spp": res.spp,
        "variance": alloc.variance,
        "shaded": res.shaded,
        "shaded_level": res.shaded_level,
        "b_p": buf.b_p.numpy().reshape(H, W),
        "sigma2": buf.sigma2.numpy().reshape(H, W),
    }
    check_finite_image(res.image, prep.scene.source)
    _warn_samples(stats)
    return RenderResult(res.image, gb.coverage, gb, stats, aovs)


def split_planes(scene: Scene) -> tuple:
    """``(surfaces, planes)``: the scene's spheres and meshes, and its planes, each as a scene of its own with the
    same camera, environment and lights (None where the scene has no such object)."""
    from dataclasses import replace

    surf = [o for o in scene.objects if not isinstance(o, PlaneObject)]
    planes = [o for o in scene.objects if isinstance(o, PlaneObject)]
    return (replace(scene, objects=surf) if surf else None, replace(scene, objects=planes) if planes else None)


def render_with_planes(scene: Scene, filter_method: str, spp: int, seed: int = 0, method: str = "reference",
                       budget: float | None = None, mis: bool = False, n_b: int | None = None, device: str = "cpu",
                       progress: bool = False, threads: int | None = None, max_anisotropy: int | None = None,
                       **adaptive_options) -> RenderResult:
    """Render a scene with planes beside spheres or meshes (module docstring): the spheres and meshes with
    ``method`` ("reference" at ``spp``, or "adaptive" at ``budget`` with ``n_b`` and ``adaptive_options``, the
    keywords of :func:`render_adaptive`), then the planes in front of them with the filtering renderer's
    ``filter_method`` (``spp``: its ground truth's rays per pixel, else its environment pairs per pixel).

    The spheres and meshes a plane hides are not shaded: the planes' distances along the centre rays
    (:func:`warpbw.filtering.plane_distance`) clip their G-buffer first (:func:`warpbw.gbuffer.hide_beyond`).
    ``stats`` are the spheres and meshes' with ``planes`` (the filtering renderer's) added, ``pixels_covered``
    counting both, ``pixels_hidden`` the spheres and meshes' pixels a plane hides, and ``time_s.frame`` the sum
    of the two frames (the adaptive method's ``samples_per_covered_pixel`` and ``shaded_fraction`` stay per pixel
    of the spheres and meshes, ``pixels_covered - planes.pixels_covered``); ``aovs`` add ``mip_level``, the planes'
    filtering level (0 elsewhere), and ``plane``, True where a plane is in front (the adaptive method's maps speak
    of ``coverage & ~plane``: on a plane's pixels they hold the background's values).  The planes' arguments and
    ``gmm`` files are checked before the spheres and meshes are loaded (``warpbw.filtering.check_gmm_files``), and
    their mipmaps loaded (or built) before they are rendered."""
    from warpbw.filtering import (DEFAULT_ANISOTROPY, Background, check_gmm_files, check_render_args,
                                  plane_distance, prepare_filtering, render_filtering)

    check_seed(seed)
    surfaces, planes = split_planes(scene)
    if surfaces is None or planes is None:
        raise WarpbwError(f"{scene.source}: render_with_planes renders planes beside spheres or meshes; this scene "
                          f"has {'no plane' if planes is None else 'planes only'} (use "
                          f"{'render_reference / render_adaptive' if planes is None else 'render_filtering'})")
    if method not in ("reference", "adaptive"):
        raise WarpbwError(f"method: expected 'reference' or 'adaptive', got {method!r}")
    aniso = DEFAULT_ANISOTROPY if max_anisotropy is None else max_anisotropy
    check_render_args(planes, filter_method, spp, spp, aniso)
    if method == "adaptive" and budget is None:
        raise WarpbwError("method 'adaptive': expected a budget (mean samples per covered pixel)")
    ignored = [k for k, v in (("budget", budget), ("n_b", n_b), *adaptive_options.items()) if v is not None]
    if method == "reference" and ignored:   # taken without a word: the frame was the reference at spp
        raise WarpbwError(f"method 'reference': {', '.join(ignored)} apply to method 'adaptive' only")
    gmm_files = check_gmm_files(planes, filter_method)   # first: a wrong gmm file is refused before any work
    prep = prepare_scene(surfaces, device, progress)
    plane_prep = prepare_filtering(planes, (filter_method,), device, progress, env=prep.env,   # one environment
                                   gmm_files=gmm_files)
    nearer = plane_distance(planes, device)
    if method == "adaptive":
        res = render_adaptive(prep, budget, seed=seed, mis=mis, n_b=n_b, device=device, progress=progress,
                              threads=threads, clip_distance=nearer, **adaptive_options)
    else:
        res = render_reference(prep, spp, seed=seed, mis=mis, device=device, progress=progress, threads=threads,
                               clip_distance=nearer)
    behind = Background(res.image, res.gbuffer.numpy("depth"))
    fr = render_filtering(planes, filter_method, spp=spp, seed=seed, device=device, prepared=plane_prep,
                          progress=progress, threads=threads, env_spp=spp, max_anisotropy=aniso, background=behind)
    coverage = res.coverage | fr.coverage
    stats = dict(res.stats)
    stats["pixels_covered"] = int(coverage.sum())
    stats["planes"] = fr.stats
    stats["stages"] = list(res.stats["stages"]) + [f"planes:{st}" for st in fr.stats["stages"]]
    t = dict({k: round(v, 6) for k, v in prep.timings.items()}, **res.stats["time_s"])   # with the loading
    stats["time_s"] = dict(t, load_planes=round(plane_prep.precompute_time_s, 6), planes=round(fr.time_s, 6),
                           frame=round(t["frame"] + fr.time_s, 6))
    aovs = dict(res.aovs, mip_level=fr.level, plane=fr.coverage)
    return RenderResult(fr.image, coverage, res.gbuffer, stats, aovs)


SUMMARY_METHODS = ("reference", "adaptive")   # what scene_summary describes for the spheres and meshes


def scene_summary(scene: Scene, method: str = "reference") -> dict:
    """What the scene needs, from the scene file alone (no asset is loaded), rendered with ``method`` ("reference"
    or "adaptive": :func:`render_reference` or :func:`render_adaptive`).  A scene with planes beside spheres or
    meshes lists both renderers' stages (:func:`render_with_planes`); planes alone render with reflectance
    filtering only, and the adaptive method is refused there, as ``warpbw render`` refuses it."""
    if method not in SUMMARY_METHODS:
        raise WarpbwError(f"method {method!r}: expected one of {', '.join(SUMMARY_METHODS)}")
    surfaces, planes = split_planes(scene)
    if surfaces is None:
        from warpbw.filtering import filtering_summary

        if method == "adaptive":
            raise WarpbwError(f"{scene.source}: a scene of planes alone renders with reflectance filtering "
                              "(--filter, 004); the adaptive method applies to spheres and meshes")
        return filtering_summary(scene)
    kinds = sorted({surfaces.materials[n].type for n in surfaces.material_order})
    env = scene.environment
    has_mesh = any(isinstance(o, MeshObject) for o in surfaces.objects)
    stages = ["gbuffer (" + " + ".join(
        n for n, on in (("analytic spheres", any(isinstance(o, SphereObject) for o in surfaces.objects)),
                        ("mesh BVH", has_mesh)) if on) + ")",
              "brdf: " + ", ".join(kinds)]
    if env is not None and any(k in ("merl", "npf") for k in kinds):   # lights alone: no BRDF is sampled
        stages.append("tabulated importance sampling (002 Sec. 3.3)")
    light = ((", environment light (BRDF samples; with --mis also environment samples, MIS)" if env is not None
              else "") + (", directional lights exact" if scene.lights else ""))
    if method == "reference":
        stages.append("reference shading (002 Eq. 2)" + light)
    elif env is None:
        raise _nothing_to_adapt(scene)
    else:
        named = [n for n in surfaces.material_order if surfaces.materials[n].bandwidth is not None]
        given = (f" ({', '.join(named)}'s read from the scene's bandwidth file{'s' if len(named) > 1 else ''})"
                 if named else "")
        stages += (["mesh curvature (|H| over about two rings of vertices, 002 Eq. 3)"] if has_mesh else []) + [
            "bandwidth pass (002 Eq. 4-11): the probe's angular bandwidth (wavelets) and each glossy "
            f"material's nu_rho table, built once and cached{given}",
            "level pyramid (min filter) and variance (max filter) (002 Sec. 3.1)",
            "hierarchical shading (002 Sec. 3.2)" + light,
            "up-sampling (anisotropic bilateral weights, 002 Sec. 3.2)"]
    if planes is not None:
        from warpbw.filtering import filtering_summary

        stages = ([f"spheres and meshes: {st}" for st in stages]
                  + [f"planes: {st}" for st in filtering_summary(planes)["stages"]]
                  + ["composite: each pixel shows the surface its centre ray hits first; spheres and meshes behind "
                     "a plane are not shaded (no shadows)"])
    # a material's bandwidth table is read by the bandwidth pass alone (prepare_bandwidth)
    unread = set() if method == "adaptive" else {scene.materials[n].bandwidth for n in scene.material_order}
    if env is None:   # and a sampling table by a frame that samples no BRDF (prepare_scene)
        unread |= {surfaces.materials[n].sampling for n in surfaces.material_order}
    return {
        "scene": scene.source,
        "resolution": [scene.camera.width, scene.camera.height],
        "environment": _environment_text(env),
        "lights": [li.describe() for li in scene.lights],
        "objects": [o.describe() for o in scene.objects],
        "materials": {n: scene.materials[n].type for n in scene.material_order},
        "unused_materials": sorted(set(scene.materials) - set(scene.material_order)),
        "files": [str(p) for p in scene.files() if p not in unread],
        "stages": stages,
        # the spheres' and meshes' frame beyond the assets (a filtered plane frame's is not estimated)
        "frame_memory_bytes": frame_memory(scene.camera.width, scene.camera.height, method),
        **_probe_memory(env, method),
        **_mesh_memory(surfaces.objects),
    }


def _environment_text(env) -> str:
    """The environment as ``warpbw info`` describes it, saying when the probe's RGB is converted to Rec. 709 from
    the primaries its EXR declares (``warpbw.io.exr.colour_conversion``)."""
    if env is None:
        return "none (lit by the [[light]]s)"
    from warpbw.io.exr import colour_conversion

    converted = env.file is not None and colour_conversion(env.file) is not None
    return env.describe() + ("; its RGB converted to Rec. 709 from the chromaticities the file declares"
                             if converted else "")


def _placed_triangles(placed: list) -> tuple[int, int] | None:
    """The triangles of the placed meshes (``placed``: their objects), every copy counted, and of their files, each
    counted once, from the files' headers or face lines (``warpbw.io.mesh.mesh_triangles``, each file read once);
    None where a file does not say."""
    from warpbw.io.mesh import mesh_triangles

    counts = {str(o.file): None for o in placed}
    for f in counts:
        counts[f] = mesh_triangles(f)
        if counts[f] is None:
            return None
    return sum(counts[str(o.file)] for o in placed), sum(counts.values())


def _mesh_memory(objects) -> dict:
    """The placed meshes' triangles and what they take (:func:`mesh_memory`, :func:`_placed_triangles`): {} without
    meshes, or where a file does not say (the render then reads it, or says what is wrong with it)."""
    placed = [o for o in objects if isinstance(o, MeshObject)]
    said = _placed_triangles(placed) if placed else None
    return {} if said is None else {"mesh_triangles": said[0], "mesh_memory_bytes": mesh_memory(*said)}


def _probe_memory(env, method: str) -> dict:
    """The peaks of loading the scene's probe file and, for the adaptive method, of building its bandwidth map
    (when the cache lacks it), from the file's header: {} without a probe file, or where its header does not read
    (the render then says what is wrong with it)."""
    if env is None or env.file is None:
        return {}
    from warpbw.bandwidth import env_bandwidth_memory
    from warpbw.envmap import file_load_memory

    try:
        w, h, need = file_load_memory(env.file)   # w, h: the probe's texels (its display window)
    except WarpbwError:
        return {}
    out = {"probe_load_memory_bytes": need}
    if method == "adaptive":
        out["probe_bandwidth_memory_bytes"] = env_bandwidth_memory(w, h)
    return out
