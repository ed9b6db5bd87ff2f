"""Fill :class:`~forest.render.path.PathInputs` from a :class:`~forest.scene.Scene`.

The forest path tracer itself takes plain data; this adapter reads the Scene
— its terrain, colour map, resolved species, LOD plan, camera path and wind —
so every renderer sees the same scene.  Differences from the ``scalar_rgb``
path, by design: the sun is a disc of
:data:`~forest.render.path.inputs.SUN_ANGULAR_DIAMETER` (the scalar path's
sun is a point), and ``sunsky`` is rotated to Y-up.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ...camera import camera_at, look_at_matrix
from ...images import read_map_rgb
from ...scene import Scene
from ..instancing import tree_matrices
from .inputs import PathCamera, PathInputs, SkyLight, SunLight, sun_direction


def path_camera(config, frame: float = 1.0, width: int | None = None, height: int | None = None) -> PathCamera:
    """The config's camera at ``frame`` (interpolated along its keys)."""
    cam = config.camera
    state = camera_at(cam, frame)
    rc = config.render
    return PathCamera(
        to_world=look_at_matrix(state.position, state.target, state.up),
        fov=float(state.fov),
        width=int(width or rc.width),
        height=int(height or rc.height),
        near=float(cam.near),
        far=float(cam.far),
    )


def path_lights(config) -> tuple[SunLight | None, SkyLight | None]:
    """``[lights]`` as a disc sun and a sky (``sunsky`` keeps the sun only for its direction)."""
    lights = config.lights
    sun = sky = None
    s = lights.sun
    if s is not None:
        direction = sun_direction(s.elevation, s.azimuth)
        irradiance = np.asarray(s.colour, np.float64) * float(s.irradiance)
        if s.elevation <= 0:
            irradiance = irradiance * 0.0
        sun = SunLight(tuple(direction.tolist()), tuple(irradiance.tolist()))
    k = lights.sky
    if k is not None:
        if k.kind == "sunsky":
            if sun is None:
                sun = SunLight(tuple(sun_direction(35.0, 120.0).tolist()), (0.0, 0.0, 0.0))
            sky = SkyLight(
                "sunsky",
                scale=float(k.sunsky.scale),
                turbidity=float(k.sunsky.turbidity),
                albedo=float(k.sunsky.albedo),
                sun_scale=float(k.sunsky.scale),
            )
        elif k.kind == "envmap":
            sky = SkyLight("envmap", envmap=k.envmap, scale=float(k.scale))
        else:
            sky = SkyLight("constant", radiance=tuple((np.asarray(k.colour) * float(k.radiance)).tolist()))
    if sun is not None and sky is not None and sky.kind != "sunsky" and max(sun.irradiance) <= 0:
        sun = None
    return sun, sky


def leaf_tints(config) -> np.ndarray | None:
    """``[lookdev] leaf_tint`` (written by ``forest match``) as (S, 3) per species index, or None.

    Keys are a species' ``name`` or ``model``; species it does not name keep 1.
    """
    table = config.lookdev.leaf_tint
    if not table:
        return None
    out = np.ones((len(config.species), 3))
    for i, sp in enumerate(config.species):
        for key in (sp.name, sp.model):
            if key is not None and key in table:
                out[i] = np.asarray(table[key], np.float64)
                break
    return out


def inputs_extent(extent) -> tuple[float, float, float, float]:
    xmin, zmin, xmax, zmax = (float(v) for v in extent)
    return (xmin, zmin, xmax, zmax)


def path_inputs(
    scene: Scene,
    *,
    frame: float = 1.0,
    width: int | None = None,
    height: int | None = None,
    spp: int | None = None,
    time_s: float | None = None,
) -> PathInputs:
    """PathInputs for frame ``frame`` of ``scene`` (LOD from the camera at ``frame``, wind at ``time_s``,
    default frame / fps)."""
    config, instances = scene.config, scene.instances
    rc = config.render
    camera = path_camera(config, frame, width, height)
    levels = scene.levels(frame) if len(instances) else np.zeros(0, np.int64)
    t = frame / config.camera.fps if time_s is None else time_s
    matrices = tree_matrices(instances, t, config.wind)
    terrain_colour: object = tuple(float(c) for c in rc.terrain_colour)
    tinted = True
    if rc.terrain_texture is not None:
        terrain_colour = read_map_rgb(rc.terrain_texture, what="terrain texture")
        tinted = False
    sun, sky = path_lights(config)
    return PathInputs(
        instances=instances,
        species=list(scene.species),
        levels=levels,
        matrices=matrices,
        camera=camera,
        terrain=scene.terrain,
        sun=sun,
        sky=sky,
        colour_grid=None if scene.colour is None else scene.colour.rgb,
        extent=inputs_extent(scene.terrain.extent),
        terrain_colour=terrain_colour,
        terrain_tinted=tinted,
        max_depth=int(rc.max_depth),
        spp=int(spp or rc.spp),
        seed=int(rc.seed),
        leaf_tint=_per_index(leaf_tints(config), instances),
    )


def _per_index(tints: np.ndarray | None, instances) -> np.ndarray | None:
    """Tints by config species → by the InstanceSet's species index (its ``species_names`` are the models)."""
    if tints is None:
        return None
    return tints[: len(instances.species_names)] if len(instances.species_names) <= len(tints) else None


def preview_size(config, preview_width: int = 480) -> tuple[int, int]:
    """The ``--preview`` size of a config: at most ``preview_width`` pixels wide, same aspect."""
    rc = config.render
    k = min(1.0, preview_width / rc.width)
    return max(1, round(rc.width * k)), max(1, round(rc.height * k))


def with_size(inputs: PathInputs, width: int, height: int) -> PathInputs:
    """The same inputs with another image size."""
    return replace(inputs, camera=replace(inputs.camera, width=int(width), height=int(height)))


__all__ = ["path_camera", "path_inputs", "path_lights", "preview_size", "with_size"]
