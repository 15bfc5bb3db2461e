"""Directional lights for the renderer of spheres and meshes (the ``[[light]]`` of issue 4, joined to 002).

Public:
    ``DirectionalLights`` (Warp struct: world directions towards the lights and their radiances)
    ``Lights`` / ``make_lights(scene_lights, device) -> Lights | None``   None when the scene has none
    ``directional_struct(directions, radiances, device) -> DirectionalLights``   (n, 3) directions (scaled to unit
                                          length) and one radiance each; refuses NaN, zero or mismatched ones
    ``as_lights(lights, name) -> Lights | None``   what the shading takes: None, a Lights, or a DirectionalLights
                                          struct (wrapped); anything else is a one-line ``WarpbwError``

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

from warpbw.errors import FLOAT32_MAX, WarpbwError, check_device, unit_directions


@wp.struct
class DirectionalLights:
    direction: wp.array(dtype=wp.vec3)   # unit world vectors towards the lights
    radiance: wp.array(dtype=wp.vec3)    # RGB: irradiance E cos(theta) on a surface at angle theta


@dataclass
class Lights:
    """Device copies of a scene's directional lights; ``data`` is the struct the kernels take."""

    data: DirectionalLights
    count: int


def _struct(d: np.ndarray, e: np.ndarray, device: str, what_d: str, what_e: str) -> DirectionalLights:
    """The struct of (n, 3) float64 directions, scaled to unit length, and radiances, each checked once (messages
    start with ``what_d`` / ``what_e``), then the device."""
    d = unit_directions(d, what_d)
    if not (np.all(np.isfinite(e)) and np.all(e >= 0.0) and np.all(e <= FLOAT32_MAX)):
        raise WarpbwError(f"{what_e}: expected radiances that are finite, >= 0 and within the float32 range")
    check_device(device)
    s = DirectionalLights()
    s.direction = wp.array(d.astype(np.float32), dtype=wp.vec3, device=device)
    s.radiance = wp.array(e.astype(np.float32), dtype=wp.vec3, device=device)
    return s


def directional_struct(directions, radiances, device: str = "cpu") -> DirectionalLights:
    """The struct of ``(n, 3)`` directions towards the lights (scaled to unit length here: the shading takes them
    as they are) and their ``(n, 3)`` radiances, one per direction (the shading loops over the directions and reads
    the radiance of each: 2 directions with 1 radiance read past its end); else a one-line ``WarpbwError``."""
    check_device(device)   # first, as before the shapes
    try:
        d = np.asarray(directions, np.float64)
        e = np.asarray(radiances, np.float64)
    except (TypeError, ValueError):
        raise WarpbwError("directional_struct: expected (n, 3) numbers for the directions and the radiances") \
            from None
    if d.ndim != 2 or d.shape[1:] != (3,) or e.shape != d.shape:
        if not (d.size == 0 and e.size == 0):
            raise WarpbwError(f"directional_struct: expected (n, 3) directions and (n, 3) radiances, one per "
                              f"direction, got shapes {d.shape} and {e.shape}")
        d = e = np.zeros((0, 3))
    return _struct(d, e, device, "directional_struct: directions", "directional_struct: radiances")


def as_lights(lights, name: str = "lights") -> Lights | None:
    """``lights`` as the shading takes them: None (no lights), a ``Lights``, or ``directional_struct``'s struct
    (wrapped in a ``Lights``); else a one-line ``WarpbwError`` naming ``name`` (an EnvMap, whose ``.data`` the
    kernel read as the lights' struct, crashed the process)."""
    if lights is None:
        return None
    if isinstance(lights, DirectionalLights.instance_type) and lights.direction is not None \
            and lights.radiance is not None:
        return Lights(lights, int(lights.direction.shape[0]))
    if isinstance(lights, Lights) and isinstance(lights.data, DirectionalLights.instance_type):
        return lights
    raise WarpbwError(f"{name}: expected a Lights (make_lights's) or a DirectionalLights struct "
                      f"(directional_struct's), got {type(lights).__name__}")


def make_lights(scene_lights, device: str = "cpu") -> Lights | None:
    """The scene's ``[[light]]`` tables (``warpbw.scene.DirectionalLight``) on ``device``; None without any."""
    lights = list(scene_lights or [])
    if not lights:
        return None
    d, e = np.zeros((len(lights), 3)), np.zeros((len(lights), 3))
    for k, li in enumerate(lights):
        try:
            dk, ek = np.asarray(li.direction, np.float64), np.asarray(li.radiance, np.float64)
        except (AttributeError, TypeError, ValueError):
            dk = ek = np.zeros(0)
        if dk.shape != (3,) or ek.shape != (3,):
            raise WarpbwError(f"[[light]] {k}: expected a direction and a radiance of 3 numbers each")
        d[k], e[k] = dk, ek
    return Lights(_struct(d, e, device, "[[light]]", "[[light]]"), len(lights))   # checked once, as a scene's
