"""Fill :class:`~forest.render.path.PathInputs` from a scene config, the way ``forest render`` reads it.

The forest path tracer itself takes plain data; this adapter reads a
``Config`` with the same functions the ``scalar_rgb`` renderer uses (terrain,
colour map, camera path, levels of detail, wind), so both renderers see the
same scene.  Differences, by design: the sun is a disc of
:data:`~forest.render.path.inputs.SUN_ANGULAR_DIAMETER` (the scalar path's
sun is a point), and ``sunsky`` is rotated to Y-up.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ...camera import camera_at, look_at_matrix
from ...errors import ForestError
from ...images import read_map_rgb
from ...terrain import load_terrain
from ..instancing import lod_levels, tree_matrices
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
                scale=float(k.scale),
                turbidity=float(k.turbidity),
                albedo=float(k.albedo),
                sun_scale=float(k.scale),
            )
        elif k.kind == "envmap":
            sky = SkyLight("envmap", envmap=k.envmap, scale=float(k.scale))
        else:
            sky = SkyLight("constant", radiance=tuple((np.asarray(k.colour) * float(k.radiance)).tolist()))
    if sun is not None and sky is not None and sky.kind != "sunsky" and max(sun.irradiance) <= 0:
        sun = None
    return sun, sky


def inputs_extent(extent) -> tuple[float, float, float, float]:
    xmin, zmin, xmax, zmax = (float(v) for v in extent)
    return (xmin, zmin, xmax, zmax)


def path_inputs(
    config,
    instances,
    library,
    *,
    frame: float = 1.0,
    width: int | None = None,
    height: int | None = None,
    spp: int | None = None,
    time_s: float | None = None,
    terrain=None,
    colour_grid: np.ndarray | None = None,
) -> PathInputs:
    """PathInputs for frame ``frame`` of ``config`` (wind at ``time_s``, default frame / fps)."""
    rc = config.render
    terrain = terrain if terrain is not None else load_terrain(config.terrain, config.path)
    if colour_grid is None and config.maps.colour is not None:
        colour_grid = read_map_rgb(config.maps.colour, what="colour map")
    species = []
    for model in instances.species_names:
        try:
            sp = library.resolve(model, config.base_dir)
        except ForestError as e:
            raise ForestError(f"{config.path}: species model {model!r}: {e}") from None
        species.append(sp)
    camera = path_camera(config, frame, width, height)
    state = camera_at(config.camera, frame)
    n_lods = np.array([len(sp.lods) for sp in species] or [1], dtype=np.int64)
    sp_idx = np.asarray(instances.species, dtype=np.int64)
    levels = (
        lod_levels(instances.position, state.position, config.lod.distances, n_lods[sp_idx])
        if len(instances)
        else np.zeros(0, np.int64)
    )
    t = frame / config.camera.fps if time_s is None else time_s
    matrices = tree_matrices(instances, t, config.wind)
    terrain_colour: object = tuple(float(c) for c in rc.terrain_colour)
    tinted = True
    if getattr(rc, "terrain_texture", None) is not None:
        terrain_colour = read_map_rgb(rc.terrain_texture, what="terrain texture")
        tinted = False
    sun, sky = path_lights(config)
    return PathInputs(
        instances=instances,
        species=species,
        levels=levels,
        matrices=matrices,
        camera=camera,
        terrain=terrain,
        sun=sun,
        sky=sky,
        colour_grid=colour_grid,
        extent=inputs_extent(terrain.extent),
        terrain_colour=terrain_colour,
        terrain_tinted=tinted,
        max_depth=int(rc.max_depth),
        spp=int(spp or rc.spp),
        seed=int(rc.seed),
    )


def preview_size(config, preview_width: int = 480) -> tuple[int, int]:
    """The ``--preview`` size of a config: at most ``preview_width`` pixels wide, same aspect."""
    rc = config.render
    k = min(1.0, preview_width / rc.width)
    return max(1, round(rc.width * k)), max(1, round(rc.height * k))


def with_size(inputs: PathInputs, width: int, height: int) -> PathInputs:
    """The same inputs with another image size."""
    return replace(inputs, camera=replace(inputs.camera, width=int(width), height=int(height)))


__all__ = ["path_camera", "path_inputs", "path_lights", "preview_size", "with_size"]
