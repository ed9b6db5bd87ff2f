"""Fill :class:`~forest.render.path.PathInputs` from a :class:`~forest.scene.Scene`.

The forest path tracer itself takes plain data; this adapter reads the Scene
— its terrain and ground (:mod:`forest.render.path.ground`), colour map,
resolved species and their individuals, LOD plan, camera path, wind, lights
and haze — so every renderer sees the same scene.  The sun is a disc of
:data:`~forest.render.path.inputs.SUN_ANGULAR_DIAMETER`; ``sunsky`` is rotated
to Y-up and normalised so its sun sends ``[lights.sun] irradiance``.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from ...camera import camera_at, look_at_matrix
from ...lights import Lights
from ...scene import Scene
from ...skirt import hills, skirt_radius
from ...wind import tree_matrices
from .ground import GroundLook, ground_look
from .haze import FogLayer, HazeInputs
from .inputs import PathCamera, PathInputs, SkyLight, SunLight

if TYPE_CHECKING:
    from ...config import Config
    from ...far_cover import FarCover
    from ...library.core import Species
    from ...terrain import Terrain


def path_camera(config: Config, frame: float = 1.0, width: int | None = None, height: int | None = None) -> PathCamera:
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
        lens_radius=float(state.lens_radius),
        focus_distance=float(state.focus_distance or 1.0),
    )


def path_lights(lights: Lights) -> tuple[SunLight | None, SkyLight | None]:
    """:class:`~forest.lights.Lights` as a disc sun and a sky.

    A ``sunsky`` sky keeps a :class:`SunLight` for the direction it is pointed at
    (:attr:`forest.lights.Sky.sun`; its irradiance zero when that sun is off) and
    is normalised (:attr:`SkyLight.sun_irradiance`): its sun sends that sun's
    irradiance facing it (luminance), the sky keeps the model's ratio to it, and
    ``[lights.sky.sunsky] scale`` multiplies both.
    """
    k = lights.sky
    if k is not None and k.kind == "sunsky":
        assert k.sun is not None  # resolve_lights always points a sun-sky at a sun
        on = lights.sun is not None
        irradiance = k.sun.rgb if on else np.zeros(3)
        sun = SunLight(tuple(k.sun.direction.tolist()), tuple(irradiance.tolist()))
        sky = SkyLight(
            "sunsky",
            scale=float(k.intensity),
            turbidity=float(k.turbidity),
            albedo=float(k.albedo),
            sun_scale=float(k.intensity),
            sun_irradiance=float(k.sun.irradiance),
        )
        return sun, sky
    disc = (
        None if lights.sun is None else SunLight(tuple(lights.sun.direction.tolist()), tuple(lights.sun.rgb.tolist()))
    )
    if k is None:
        return disc, None
    if k.kind == "envmap":
        return disc, SkyLight("envmap", envmap=k.envmap, scale=float(k.intensity), background=k.background)
    return disc, SkyLight("constant", radiance=tuple(k.radiance.tolist()))


def path_lights_clouded(lights: Lights) -> tuple[SunLight | None, SkyLight | None]:
    """:func:`path_lights` with ``[lights.clouds]`` on the sky (:attr:`SkyLight.clouds`)."""
    sun, sky = path_lights(lights)
    if sky is not None and lights.clouds is not None:
        sky = replace(sky, clouds=lights.clouds)
    return sun, sky


def haze_inputs(config: Config, terrain: Terrain) -> HazeInputs | None:
    """``[render] haze`` & co as :class:`HazeInputs` (None when ``haze`` is 0 and no ``valley_fog``): the ground is the terrain's
    lowest point; a camera ray that leaves the scene is hazed up to the end of the ground (the skirt's
    radius, else the far clip)."""
    rc = config.render
    if rc.haze <= 0 and rc.valley_fog is None:
        return None
    far = float(config.camera.far)
    distance = skirt_radius(terrain.extent, far) if rc.horizon_ground else far
    vf = rc.valley_fog
    fog = None
    if vf is not None:
        top = float(vf.top) + (0.0 if vf.absolute else float(terrain.height_range[0]))
        fog = FogLayer(
            density=float(vf.density),
            top=top,
            falloff=float(vf.falloff),
            variation=float(vf.variation),
            variation_scale=float(vf.variation_scale),
            seed=int(config.seed) & 0x7FFFFFFF,
        )
    return HazeInputs(
        fog=fog,
        density=float(rc.haze),
        height=float(rc.haze_height),
        colour=None if rc.haze_colour is None else tuple(float(c) for c in rc.haze_colour),
        anisotropy=float(rc.haze_anisotropy),
        ground=float(terrain.height_range[0]),
        sky_distance=min(distance, far),
        shafts=rc.valley_fog is not None if rc.haze_shafts == "auto" else bool(rc.haze_shafts),
    )


def scene_species(scene: Scene) -> tuple[list[list[Species]], np.ndarray | None]:
    """Per species index the list of its individuals (element 0 = the species itself) and each tree's individual.

    Reads ``Scene.individuals`` and ``InstanceSet.individual`` where the Scene has them; one individual
    per species otherwise.
    """
    individuals = getattr(scene, "individuals", None)
    species: list[list[Species]] = (
        [list(ind) if ind else [sp] for ind, sp in zip(individuals, scene.species)]
        if individuals
        else [[sp] for sp in scene.species]
    )
    column = getattr(scene.instances, "individual", None)
    if column is None or max((len(s) for s in species), default=1) <= 1:
        return species, None
    return species, np.asarray(column, np.int64)


def inputs_extent(extent: Iterable[float]) -> tuple[float, float, float, float]:
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
    look = ground_look(scene)
    sun, sky = path_lights_clouded(scene.lights.require(config.path))
    species, individuals = scene_species(scene)
    return PathInputs(
        instances=instances,
        species=species,
        individuals=individuals,
        levels=levels,
        matrices=matrices,
        camera=camera,
        terrain=scene.terrain,
        sun=sun,
        sky=sky,
        colour_grid=None if scene.colour is None else scene.colour.rgb,
        extent=inputs_extent(scene.terrain.extent),
        terrain_colour=look.colour,
        terrain_tinted=False,  # the ground is the Scene's albedo; the colour map does not tint it
        terrain_extent=look.extent,
        terrain_detail=look.detail,
        terrain_detail_tile=look.detail_tile,
        skirt_radius=skirt_radius(scene.terrain.extent, float(config.camera.far)) if rc.horizon_ground else 0.0,
        skirt_hills=hills(config),
        haze=haze_inputs(config, scene.terrain),
        max_depth=int(rc.max_depth),
        spp=int(spp or rc.spp),
        seed=int(rc.seed),
        leaf_tint=scene.leaf_tint if config.lookdev.leaf_tint else None,
        lod_setting={"pixels": "pixels", "off": "auto"}.get(scene.lod.mode, "distances"),
        solid=scene.solid_cards(frame, levels) if len(instances) else None,
        ground_tint=tuple(float(x) for x in scene.ground_tint),
        terrain_water=look.water,
        water_ripple=float(config.model.ground.water_ripple),
        tree_tint=scene.tree_jitter(),
        bark_tint=scene.bark_tints(),
        far_cover=far_mosaic(scene, look),
        sea_colour=sea_colour(scene),
    )


def sea_colour(scene: Scene) -> tuple[float, float, float] | None:
    """The painted water's colour for the sea past the terrain's edge (:mod:`forest.skirt`, "The sea"): its mean
    on the terrain's edge, which the sea continues; None without the skirt (``horizon_ground = false``) or without
    still water at the edge."""
    from ...ground import water_colour
    from ...skirt import sea_at_edge

    if not scene.config.render.horizon_ground or sea_at_edge(scene.terrain) is None:
        return None
    c = water_colour(scene.terrain_albedo, edge=True)
    return (float(c[0]), float(c[1]), float(c[2]))


def far_mosaic(scene: Scene, look: GroundLook) -> FarCover | None:
    """The woods and open ground on the skirt's hills (:mod:`forest.far_cover`), or None: without hills, with
    ``woods = false``, without a colour map on the ground, or without trees."""
    from ...far_cover import far_cover

    rc = scene.config.render
    albedo = scene.terrain_albedo
    h = rc.horizon_hills
    if not rc.horizon_ground or h is None or not h.woods or np.ndim(look.colour) != 3:
        return None
    if albedo.far is None or albedo.far_canopy is None:
        return None
    core, padded = albedo.extent, look.extent
    ramp = min(core[0] - padded[0], core[1] - padded[1], padded[2] - core[2], padded[3] - core[3])
    palette = scene.config.model.ground.palette()
    return far_cover(albedo.far, albedo.far_canopy, albedo.far_cover, core, ramp, int(h.seed), height=albedo.far_height,
                     treeline=h.treeline, rockline=h.rockline, rock=palette["rock"], snowline=h.snowline,
                     snow=palette["snow"])  # fmt: skip


def far_plan(scene: Scene, frames: list[float] | None = None, flatten_triangles: int | None = None) -> tuple[int, int]:
    """(trees merged at the far level, their triangles) for the pre-flight memory model.

    A tree is merged when its level's prototype has at most ``flatten_triangles`` triangles
    (:data:`~forest.render.path.inputs.FLATTEN_MAX_TRIANGLES`, as :mod:`.geometry` decides); of
    ``frames`` (default frame 1; at most the first, middle and last are looked at) the one with
    the fewest merged trees — the most instances — is reported."""
    from .inputs import FLATTEN_MAX_TRIANGLES

    limit = FLATTEN_MAX_TRIANGLES if flatten_triangles is None else int(flatten_triangles)
    inst = scene.instances
    if not len(inst):
        return 0, 0
    lists, individual = scene_species(scene)
    nlev = max(len(sp.lods) for group in lists for sp in group)
    nind = max(len(group) for group in lists)
    tri = np.zeros((len(lists), nind, nlev), np.int64)  # triangles of each (species, individual, level) prototype
    for s, group in enumerate(lists):
        for k in range(nind):
            sp = group[min(k, len(group) - 1)]
            for lv in range(nlev):
                tri[s, k, lv] = sum(p.triangles for p in sp.lods[min(lv, len(sp.lods) - 1)].parts)
    fl = sorted(set(frames or [1.0]))
    picks = sorted({fl[0], fl[len(fl) // 2], fl[-1]})
    species = np.asarray(inst.species, np.int64)
    ind = np.zeros(len(inst), np.int64) if individual is None else np.asarray(individual, np.int64)
    best: tuple[int, int] | None = None
    for f in picks:
        t = tri[species, ind, np.asarray(scene.levels(float(f)), np.int64)]
        merged = t <= limit
        plan = (int(merged.sum()), int(t[merged].sum()))
        if best is None or plan[0] < best[0]:
            best = plan
    assert best is not None
    return best


def preview_size(config: Config, preview_width: int = 480) -> tuple[int, int]:
    """The ``--preview`` size of a config: at most ``preview_width`` pixels wide, same aspect."""
    rc = config.render
    k = min(1.0, preview_width / rc.width)
    return max(1, round(rc.width * k)), max(1, round(rc.height * k))


def with_size(inputs: PathInputs, width: int, height: int) -> PathInputs:
    """The same inputs with another image size."""
    return replace(inputs, camera=replace(inputs.camera, width=int(width), height=int(height)))


__all__ = [
    "far_plan",
    "haze_inputs",
    "path_camera",
    "path_inputs",
    "path_lights",
    "preview_size",
    "scene_species",
    "with_size",
]
