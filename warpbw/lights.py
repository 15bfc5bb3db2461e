"""Directional lights for the renderer of spheres and meshes (the ``[[light]]`` of issue 4, joined to 002).

Public:
    ``DirectionalLights`` (Warp struct: world directions towards the lights and their radiances)
    ``Lights`` / ``make_lights(scene_lights, device) -> Lights | None``   None when the scene has none
    ``directional_struct(directions, radiances, device) -> DirectionalLights``

A directional light of radiance E (RGB) from the unit world direction l adds to a pixel's radiance, exactly
and without sampling,

    L_p += E rho(x, l, wo) max(l . n, 0)          (002 Eq. 1 with L_i a Dirac delta at l)

so a surface facing the light receives irradiance E cos(theta), as in the scene format and in
``warpbw.filtering``.  Visibility is ignored, as it is for the environment (002 Eq. 1): a light is not
shadowed.  The term is deterministic: it adds no variance to the estimator, and a scene lit only by
lights renders the same at any sample count.  The kernel that uses it (``warpbw.shading``) loops over the
struct's arrays; a scene without lights compiles no such loop.  The adaptive method adds this term at
every pixel after up-sampling the environment's part (``warpbw.adaptive``), so the bandwidth pass leaves
lights out.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from warpbw.errors import FLOAT32_MAX, WarpbwError, check_device


@wp.struct
class DirectionalLights:
    direction: wp.array(dtype=wp.vec3)   # unit world vectors towards the lights
    radiance: wp.array(dtype=wp.vec3)    # RGB: irradiance E cos(theta) on a surface at angle theta


@dataclass
class Lights:
    """Device copies of a scene's directional lights; ``data`` is the struct the kernels take."""

    data: DirectionalLights
    count: int


def directional_struct(directions, radiances, device: str = "cpu") -> DirectionalLights:
    """The struct of ``(n, 3)`` unit directions and radiances."""
    check_device(device)
    s = DirectionalLights()
    s.direction = wp.array(np.asarray(directions, np.float32).reshape(-1, 3), dtype=wp.vec3, device=device)
    s.radiance = wp.array(np.asarray(radiances, np.float32).reshape(-1, 3), dtype=wp.vec3, device=device)
    return s


def make_lights(scene_lights, device: str = "cpu") -> Lights | None:
    """The scene's ``[[light]]`` tables (``warpbw.scene.DirectionalLight``) on ``device``; None without any."""
    lights = list(scene_lights or [])
    if not lights:
        return None
    d = np.array([li.direction for li in lights], np.float64).reshape(-1, 3)
    e = np.array([li.radiance for li in lights], np.float64).reshape(-1, 3)
    norm = np.linalg.norm(d, axis=1)
    if not (np.all(np.isfinite(norm)) and np.all(norm > 0.0)):
        raise WarpbwError("[[light]]: expected non-zero finite directions towards the lights")
    if not (np.all(np.isfinite(e)) and np.all(e >= 0.0) and np.all(e <= FLOAT32_MAX)):
        raise WarpbwError("[[light]]: expected radiances that are finite, >= 0 and within the float32 range")
    return Lights(directional_struct(d / norm[:, None], e, device), len(lights))
