"""The Scene: everything a backend needs, built once from a config and an InstanceSet.

Data flows one way::

    config ─► Terrain ─► maps ─► scatter ─► InstanceSet ─► Scene ─┬─► Mitsuba render
                                                                  ├─► RIB, USD
                                                                  └─► look-dev

:func:`load_scene` loads the terrain, reads the colour map (once, through
:func:`forest.maps.read_colour_map`), takes or scatters the InstanceSet,
resolves every species and its individuals through the tree library, computes
the trees' tints and the ground's albedo, and plans the levels of detail.
Render, the exporters and look-dev take a :class:`Scene`; none of them calls
scatter, re-reads a map or resolves a species again.

**The colour map is a tint around each species' leaf colour, of mean 1.**  The
map m (sRGB decoded to linear) is divided, per channel, by its mean over the
terrain's extent (``[maps] colour_normalise = "rgb"``, the default;
:func:`forest.maps.colour_tint_grid`): t = m / ⟨m⟩.  A tinted part's albedo is
its measured colour × t, so the canopy's mean colour is the species' own
(the library's PROSPECT-D leaf albedos) and painting a map never darkens a
forest: as painted, the example maps (linear values 0.01–0.5) darkened the
canopies 3–10× below measured canopy albedos.  Per channel in linear light
because albedo multiplies linearly and each channel's mean then stays the
species'; ``"luminance"`` keeps the map's overall hue (one divisor, the mean
luminance), ``"none"`` takes the values as they are (look-dev's fitted maps).
``scene.colour`` (:class:`ColourGrid`) holds the normalised tint, the grid a
renderer looks up per hit, and the divisor.

**Per-tree tint.**  ``scene.instances.tint`` is every tree's factor
t_i = J_i(c_s ⊙ m(x_i)) ⊘ c_s: the map's tint at the tree with its hue/value
jitter (:mod:`forest.tint`).  Scatter writes the column with the same function
and the Scene recomputes it for a set that scatter made (it records its
inputs), so a repainted map, a new jitter or a recalibrated leaf colour is
applied without scattering again — placement comes from the InstanceSet,
colour from the config.  Sets made elsewhere keep their tints.  The renderers
look the map up where a ray hits a tree and multiply it by
``scene.tree_jitter()``, t_i ⊘ m(x_i) (forest_path per tree; scalar_rgb
quantised to a few bins per species, :mod:`forest.render.instancing`), so a
tree renders in the colour every exporter writes for it.

**Individuals.**  ``scene.individuals[s]`` are the different trees of species
index s (element 0 is ``scene.species[s]``; the recipe grown with seed + k,
:func:`forest.library.individual`; one for a mesh or imported species), and
``scene.instances.individual`` picks one per tree, folded into range (k mod
the count) when the config asks for fewer than the set was scattered with.

**Ground.**  ``scene.terrain_albedo`` (:class:`forest.ground.TerrainAlbedo`) is
the terrain's own albedo by slope, altitude, moisture, canopy and maps, or
``[render] terrain_texture`` / ``terrain_colour``; the colour map does not
tint the ground.  It is the only place the ground is resolved: the scalar
renderer (:func:`forest.render.scene.terrain_reflectance`), forest_path
(:mod:`forest.render.path.ground`) and the exporters
(:func:`forest.export.common.terrain_texture`) read it, with the fitted
``ground_tint``; none reads ``[render] terrain_texture`` again.  It carries the
far landscape's albedo that the ground skirt fades to (canopy and ground mixed
by the crowns' cover, :mod:`forest.skirt`; ``terrain_albedo.far``).

**Lights.**  ``scene.lights`` (:class:`forest.lights.Lights`) is the sun and
sky by one rule for every backend.

**Ground cover** rows follow the trees' in the InstanceSet with their own
species indices (``species_names`` = :func:`forest.scatter.scatter_models`).

**The fitted look.**  ``forest match`` writes ``[lookdev] leaf_tint`` (an RGB
per species, keyed by its ``name`` or ``model``) and ``ground_tint``.  The Scene
resolves them once: ``scene.leaf_tint`` (S, 3) per species index (1 for a species
the table does not name and for one without leaf parts — a building — since
the tint multiplies the leaves' colour), ``scene.ground_tint`` (3,), and
``scene.tree_tints()``, each tree's colour factor t_i ⊙ leaf_tint[s_i], the
per-tree colour every exporter writes (a species' leaves are its tinted parts).
forest_path applies the same tints as parameters (look-dev differentiates
them), the scalar renderer multiplies the leaf colours and the ground albedo,
and the exporters write ``tree_tints()`` and a ground albedo times
``ground_tint`` — so a fitted look renders and exports the same everywhere.

**Bark.**  ``scene.bark_tints()`` is each tree's bark factor (its bark's
hue/value jitter and moss, ``[[species]] bark``, :func:`forest.tint.bark_tints`),
a pure function of the tree's id, the seed and the config, so it needs no
column: every renderer and exporter multiplies a tree's ``bark`` parts by it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .camera import CameraState, camera_at
from .config import Config
from .errors import ConfigError, ForestError
from .ground import TerrainAlbedo, terrain_albedo
from .instances import InstanceSet
from .library import Library, Species
from .lights import Lights, resolve_lights
from .lod import LodPlan, lod_plan
from .maps import colour_at, colour_tint_grid, read_colour_map
from .preflight import check_species
from .scatter.models import model_settings, resolve_individuals, resolve_models, scatter_models
from .skirt import horizon_albedo
from .terrain import Terrain, load_terrain
from .tint import TintParams, Where, accent_table, bark_params, tint_params

Progress = Callable[[float, str], None]


def _silent(fraction: float, message: str = "") -> None:
    """A progress callback that reports nothing."""


@dataclass(frozen=True)
class ColourGrid:
    """The colour map as a tint: linear RGB ``(H, W, 3)`` of mean 1 laid over the terrain's extent (map convention).

    Pixel (i, j) covers x ∈ xmin + [j, j+1]·Δx, z ∈ zmin + [i, i+1]·Δz
    (column → +X, row → +Z, row 0 at the smallest Z); ``rgb`` is the map
    sRGB-decoded and divided by ``divisor`` (its mean per channel with
    ``normalise = "rgb"``, :func:`forest.maps.colour_tint_grid`), so 1 = the
    species' own colour and the mean over the extent is 1.
    """

    rgb: np.ndarray
    extent: tuple[float, float, float, float]  # xmin, zmin, xmax, zmax
    path: Path | None = None
    divisor: tuple[float, float, float] = (1.0, 1.0, 1.0)
    normalise: str = "none"

    def at(self, x: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Bilinear tint at world (x, z), clamped at the edges: ``(N, 3)`` float32."""
        return colour_at(self.rgb, self.extent, x, z)


@dataclass(frozen=True)
class Scene:
    """A config with its terrain, colour map, InstanceSet, resolved species, LOD plan, individuals and ground."""

    config: Config
    terrain: Terrain
    instances: InstanceSet
    colour: ColourGrid | None
    library: Library
    species: tuple[Species, ...]  # per species index of the InstanceSet
    lod: LodPlan
    terrain_albedo: TerrainAlbedo  # the ground, resolved once (forest.ground)
    individuals: tuple[tuple[Species, ...], ...] = ()  # per species index; [s][0] is species[s]

    @property
    def path(self) -> Path | None:
        """The config file's path (None for a config built in memory)."""
        return self.config.path

    def camera_at(self, frame: float) -> CameraState:
        """The camera at a (possibly fractional) frame of its path."""
        return camera_at(self.config.camera, frame)

    def levels(self, frame: float) -> np.ndarray:
        """Level of detail per tree seen from the camera at ``frame`` (:mod:`forest.lod`: its position and fov,
        and each tree's scale)."""
        inst = self.instances
        cam = self.camera_at(frame)
        return self.lod.levels(inst.position, inst.species, cam.position, inst.scale, float(cam.fov))

    def solid_cards(self, frame: float, levels: np.ndarray | None = None) -> np.ndarray:
        """Per tree, whether forest_path draws its cut-out leaf cards solid from the camera at ``frame``: its
        projected height at most ``[lod] solid_pixels`` (:meth:`forest.lod.LodPlan.solid`) and its level
        (``levels``, default :meth:`levels` at ``frame``) below the highest."""
        inst = self.instances
        cam = self.camera_at(frame)
        solid = self.lod.solid(inst.position, inst.species, cam.position, inst.scale, float(cam.fov))
        # Not at the highest level: its cards are the full model's single leaves (52 000 on the broadleaf), which
        # take seconds to redraw per individual, and a small tree stays there only when [lod] asks for detail.
        level = self.levels(frame) if levels is None else np.asarray(levels)
        out: np.ndarray = solid & (level >= 1)
        return out

    @property
    def lights(self) -> Lights:
        """The sun and sky, resolved once by one rule for every backend (:mod:`forest.lights`)."""
        return resolve_lights(self.config)

    @property
    def leaf_tint(self) -> np.ndarray:
        """(S, 3) float64: the fitted tint of each species index's leaf colour (module docstring)."""
        return leaf_tint(self.config, self.species)

    @property
    def ground_tint(self) -> np.ndarray:
        """(3,) float64: the fitted tint of the ground's albedo (``[lookdev] ground_tint``, 1 without one)."""
        gt = self.config.lookdev.ground_tint
        return np.ones(3) if gt is None else np.asarray(gt, np.float64).reshape(3)

    def tree_tints(self) -> np.ndarray:
        """(N, 3) float32: each tree's colour factor with its species' fitted leaf tint, t_i ⊙ leaf_tint[s_i]; the
        InstanceSet's own column, unchanged, when no leaf tint is set."""
        tint = self.instances.tint
        if not self.config.lookdev.leaf_tint or not len(self.instances):
            return tint
        table = self.leaf_tint.astype(np.float32)
        return (tint * table[np.asarray(self.instances.species, np.int64)]).astype(np.float32)

    def bark_tints(self) -> np.ndarray | None:
        """(N, 3) float32: each tree's bark factor f_i (hue/value jitter and moss, :func:`forest.tint.bark_tints`,
        from ``[[species]] bark``); None when every f_i is 1.  Every renderer and exporter multiplies a tree's
        ``bark`` parts' colour by its row."""
        inst = self.instances
        if not len(inst):
            return None
        params = bark_params(model_settings(self.config), self.species, self.config.seed)
        f = params.tints(inst.species, inst.id)
        if np.all(np.abs(f - 1.0) < 1e-6):
            return None
        return f

    def tree_accents(self) -> np.ndarray | None:
        """(N,) int64: the colour accent each tree carries (``[[species]] accents``, :class:`forest.tint.Accents`;
        −1 for none), or None when no tree carries one or the set's tints were made elsewhere (then they are
        not this config's).  ``scalar_rgb`` gives accented trees their own colour bins
        (:class:`forest.render.instancing.JitterBins`)."""
        inst = self.instances
        if not len(inst) or not _scattered(inst):
            return None
        table = accent_table(model_settings(self.config))
        if not table.any:
            return None
        where = Where.of(inst.position, inst.extent)
        k, _ = table.draw(np.asarray(inst.species, np.int64), np.asarray(inst.id), self.config.seed, where)
        return k if (k >= 0).any() else None

    def tree_jitter(self) -> np.ndarray | None:
        """(N, 3) float32: each tree's tint beyond the colour map, j_i = t_i ⊘ m(x_i); None when every j_i is 1.

        A renderer that looks the colour map up where a ray hits a tree (forest_path, so
        that look-dev's gradients reach the map) multiplies that lookup by j_i to show
        the tree's colour t_i: the per-tree hue/value jitter, or the tint a set made
        elsewhere carries.  Where the map is (near) black at a tree, j_i = 1."""
        inst = self.instances
        if not len(inst):
            return None
        tint = np.asarray(inst.tint, np.float64).reshape(-1, 3)
        if self.colour is None:
            jitter = tint
        else:
            pos = np.asarray(inst.position, np.float64)
            m = np.asarray(self.colour.at(pos[:, 0], pos[:, 2]), np.float64)
            ok = m > 1e-4
            jitter = np.where(ok, tint / np.where(ok, m, 1.0), 1.0)
        if np.all(np.abs(jitter - 1.0) < 1e-6):
            return None
        return jitter.astype(np.float32)

    def with_config(self, config: Config) -> Scene:
        """The same trees and terrain with another config's look (lights, camera, render, colour map, jitter, ground).

        A colour map named or normalised differently is read again, the tints
        are recomputed (a set scatter made), and the ground's albedo is
        recomputed when ``[ground]`` or the terrain's texture or colour changed.
        The LOD plan follows the new config's ``[lod]``, ``[render] width`` and camera.
        """
        config.camera.stand_on(self.terrain.height_at)  # [camera] height_above_ground, as load_scene does
        colour = self.colour
        old = self.config
        if (config.maps.colour, config.maps.colour_normalise) != (old.maps.colour, old.maps.colour_normalise):
            colour = _colour_grid(config, self.terrain)
        inst = self.instances
        if _scattered(inst):
            inst = retint(inst, colour, tint_params(model_settings(config), self.species, config.seed))
        ground = self.terrain_albedo
        if _ground_inputs(config) != _ground_inputs(old):
            ground = terrain_albedo(config, self.terrain, inst, self.species)
        lod = lod_plan(config, self.species)
        scene = dataclasses.replace(self, config=config, colour=colour, instances=inst, terrain_albedo=ground, lod=lod)
        return dataclasses.replace(scene, terrain_albedo=horizon_albedo(scene))  # its trees' far look (forest.skirt)


def _ground_inputs(config: Config) -> tuple[object, ...]:
    rc = config.render
    colour = rc.terrain_colour if "terrain_colour" in rc.model_fields_set else None
    return (config.model.ground, rc.terrain_texture, colour, config.maps.moisture)


def _colour_grid(config: Config, terrain: Terrain) -> ColourGrid | None:
    path = config.maps.colour
    if path is None:
        return None
    try:
        raw = read_colour_map(path)
    except ForestError as e:
        raise ConfigError(config.path, "maps.colour", str(e)) from None
    mode = config.maps.colour_normalise
    rgb, divisor = colour_tint_grid(raw, mode)
    d = (float(divisor[0]), float(divisor[1]), float(divisor[2]))
    return ColourGrid(rgb, terrain.extent, path, d, mode)


def leaf_tint(config: Config, species: tuple[Species, ...] | None = None) -> np.ndarray:
    """``[lookdev] leaf_tint`` as (S, 3) per species index of :func:`forest.scatter.scatter_models` (``[[species]]``
    by ``name`` or ``model``, then ``[[ground_cover]]`` by ``model``); 1 for a species it does not name and, when
    ``species`` is given, for one whose levels have no leaf part."""
    settings = model_settings(config)
    out = np.ones((len(settings), 3))
    table = config.lookdev.leaf_tint or {}
    if not table:
        return out
    keys: list[tuple[str | None, ...]] = [(sp.name, sp.model) for sp in config.species]
    keys += [(gc.model,) for gc in config.model.ground_cover]
    for i, names in enumerate(keys[: len(out)]):
        for key in names:
            if key is not None and key in table:
                out[i] = np.asarray(table[key], np.float64)
                break
    if species is not None:
        for i, sp in enumerate(species[: len(out)]):
            if not any(getattr(part, "kind", "") == "leaf" for lod in sp.lods for part in lod.parts):
                out[i] = 1.0
    return out


def retint(instances: InstanceSet, colour: ColourGrid | None, params: TintParams) -> InstanceSet:
    """The trees with their tints computed from ``colour`` at their bases and their jitter (:mod:`forest.tint`).

    The same function scatter writes the column with; returns ``instances``
    itself when nothing changes.
    """
    pos = instances.position
    map_tint = np.ones((len(instances), 3), np.float32) if colour is None else colour.at(pos[:, 0], pos[:, 2])
    tint = params.tints(map_tint, instances.species, instances.id, Where.of(pos, instances.extent))
    if np.array_equal(tint, instances.tint):
        return instances
    return dataclasses.replace(instances, tint=tint)


def _scattered(instances: InstanceSet) -> bool:
    """Whether scatter made the set (it records its input files, :mod:`forest.scatter.provenance`).

    Sets made elsewhere (another tool, a test) carry no record and keep their tints.
    """
    return isinstance(instances.meta, dict) and isinstance(instances.meta.get("inputs"), dict)


def fold_individuals(instances: InstanceSet, individuals: tuple[tuple[Species, ...], ...]) -> InstanceSet:
    """The set with every ``individual`` index inside its species' individuals (k mod their count)."""
    counts = np.array([len(ind) for ind in individuals], dtype=np.int64)
    if not len(instances) or not len(counts):
        return instances
    n = counts[instances.species.astype(np.int64)]
    k = instances.individual.astype(np.int64)
    if (k < n).all():
        return instances
    return dataclasses.replace(instances, individual=(k % n).astype(np.uint8))


def resolve_species(config: Config, names: list[str], library: Library) -> tuple[Species, ...]:
    """The library species of every species index (``[[species]]`` then ``[[ground_cover]]`` models).

    ``names`` must be :func:`forest.scatter.scatter_models` of the config; a
    failure names ``species[i].model`` or ``ground_cover[j].model``.
    """
    expected = scatter_models(config)
    if list(names) != expected:
        raise ForestError(
            f"instances: species {list(names)} do not match the config's [[species]] and [[ground_cover]] "
            f"models {expected}; scatter again"
        )
    return resolve_models(config, library)


def load_scene(
    config: Config,
    instances: InstanceSet | str | Path | None = None,
    *,
    library: Library | None = None,
    progress: Progress | None = None,
) -> Scene:
    """Build the :class:`Scene` of ``config``.

    ``instances``: an InstanceSet, the path of a saved one (checked against the
    config: species and the maps it was scattered from), or None to scatter now.
    ``library`` defaults to :func:`forest.library.open_library`.  Every
    species is checked against it (:func:`forest.preflight.check_species`)
    before anything is loaded or scattered.
    """
    step: Progress = progress or _silent
    if library is None:
        from .library import open_library

        library = open_library()
    check_species(config, library)  # a misspelled species fails now, before any progress or work
    # So do an unreadable heightmap, terrain mesh or colour map: they are read before the first progress line,
    # which a render farm's log would show above the error.
    terrain = load_terrain(config.terrain, config.path)
    colour = _colour_grid(config, terrain)
    step(0.0, "terrain")
    config.camera.stand_on(terrain.height_at)  # [camera] height_above_ground: heights from the ground, once for all
    if instances is None or isinstance(instances, (str, Path)):
        from .scatter import scene_instances

        def scatter_step(f: float, m: str = "") -> None:
            step(0.1 + 0.6 * f, m)

        inst = scene_instances(
            config,
            instances,
            progress=scatter_step,
            terrain=terrain,
            library=library,
            colour=None if colour is None else colour.rgb,  # the map read once, above
        )
    else:
        inst = instances
    step(0.75, "species")
    species = resolve_species(config, list(inst.species_names), library)
    individuals = resolve_individuals(config, library, species)
    inst = fold_individuals(inst, individuals)
    step(0.8, "colour map")
    if _scattered(inst):
        inst = retint(inst, colour, tint_params(model_settings(config), species, config.seed))
    step(0.85, "ground")
    ground = terrain_albedo(config, terrain, inst, species)
    lod = lod_plan(config, species)
    step(1.0, "scene")
    scene = Scene(config, terrain, inst, colour, library, species, lod, ground, individuals)
    return dataclasses.replace(scene, terrain_albedo=horizon_albedo(scene))  # its trees' far look (forest.skirt)
