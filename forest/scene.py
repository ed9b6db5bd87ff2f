"""The Scene: everything a backend needs, built once from a config and an InstanceSet.

Data flows one way::

    config ─► Terrain ─► maps ─► scatter ─► InstanceSet ─► Scene ─┬─► Mitsuba render
                                                                  ├─► RIB, USD
                                                                  └─► look-dev

:func:`load_scene` loads the terrain, reads the colour map (once, through
:func:`forest.maps.read_colour_map`), takes or scatters the InstanceSet,
resolves every species through the tree library and plans the levels of
detail.  Render, the exporters and look-dev take a :class:`Scene`; none of
them calls scatter, re-reads a map or resolves a species again.

The InstanceSet's ``tint`` column is each tree's colour (the colour map at
its base, bilinear, map convention, when scatter made it) and every backend
uses it as given.  When the colour map a config names is not the one the
InstanceSet was scattered from (look-dev writes a new map; an artist repaints
it), the Scene takes the tints from the new map: placement comes from the
InstanceSet, colour from the map it names now.
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
from .instances import InstanceSet, file_digest
from .library import Library, Species
from .lod import LodPlan
from .maps import read_colour_map, sample_bilinear
from .preflight import check_species
from .terrain import Terrain, load_terrain

Progress = Callable[[float, str], None]


def _silent(fraction: float, message: str = "") -> None:
    """A progress callback that reports nothing."""


@dataclass(frozen=True)
class ColourGrid:
    """The colour map: linear RGB ``(H, W, 3)`` laid over the terrain's extent (map convention).

    Pixel (i, j) covers x ∈ xmin + [j, j+1]·Δx, z ∈ zmin + [i, i+1]·Δz
    (column → +X, row → +Z, row 0 at the smallest Z); values are sRGB-decoded
    tints, 1 = the species' own colour.
    """

    rgb: np.ndarray
    extent: tuple[float, float, float, float]  # xmin, zmin, xmax, zmax
    path: Path | None = None

    def at(self, x: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Bilinear tint at world (x, z), clamped at the edges: ``(N, 3)`` float32."""
        xmin, zmin, xmax, zmax = self.extent
        u = (np.asarray(x, np.float64) - xmin) / max(xmax - xmin, 1e-12)
        v = (np.asarray(z, np.float64) - zmin) / max(zmax - zmin, 1e-12)
        return np.asarray(sample_bilinear(self.rgb, u, v), dtype=np.float32)


@dataclass(frozen=True)
class Scene:
    """A config with its terrain, colour map, InstanceSet, resolved species and LOD plan."""

    config: Config
    terrain: Terrain
    instances: InstanceSet
    colour: ColourGrid | None
    library: Library
    species: tuple[Species, ...]  # per species index of the InstanceSet
    lod: LodPlan

    @property
    def path(self) -> Path | None:
        return self.config.path

    def camera_at(self, frame: float) -> CameraState:
        """The camera at a (possibly fractional) frame of its path."""
        return camera_at(self.config.camera, frame)

    def levels(self, frame: float) -> np.ndarray:
        """Level of detail per tree seen from the camera at ``frame`` (:mod:`forest.lod`)."""
        inst = self.instances
        return self.lod.levels(inst.position, inst.species, self.camera_at(frame).position)

    def with_config(self, config: Config) -> Scene:
        """The same trees and terrain with another config's look (lights, camera, render, colour map).

        When ``config`` names another colour map, it is read and the trees take their tints from it.
        """
        if config.maps.colour == (self.colour.path if self.colour is not None else None):
            return dataclasses.replace(self, config=config)
        colour = _colour_grid(config, self.terrain)
        return dataclasses.replace(self, config=config, colour=colour, instances=retint(self.instances, colour))


def _colour_grid(config: Config, terrain: Terrain) -> ColourGrid | None:
    path = config.maps.colour
    if path is None:
        return None
    try:
        rgb = read_colour_map(path)
    except ForestError as e:
        raise ConfigError(config.path, "maps.colour", str(e)) from None
    return ColourGrid(rgb, terrain.extent, path)


def retint(instances: InstanceSet, colour: ColourGrid | None) -> InstanceSet:
    """The trees with their tints taken from ``colour`` at their bases (1 without a map)."""
    if colour is None:
        tint = np.ones((len(instances), 3), np.float32)
    else:
        tint = colour.at(instances.position[:, 0], instances.position[:, 2])
    if np.array_equal(tint, instances.tint):
        return instances
    return dataclasses.replace(instances, tint=tint)


def _scattered_with(instances: InstanceSet, colour: ColourGrid | None) -> bool:
    """Whether the InstanceSet's tints came from this colour map (or no record says otherwise).

    Scatter records the sha256 of each input file under ``meta["inputs"]``
    (:mod:`forest.scatter.provenance`); sets made elsewhere (another tool, a
    test) carry no record and keep their tints.
    """
    inputs = instances.meta.get("inputs") if isinstance(instances.meta, dict) else None
    if not isinstance(inputs, dict):
        return True
    entry = inputs.get("maps.colour")
    recorded = entry.get("sha256") if isinstance(entry, dict) else None
    if colour is None or colour.path is None:
        return recorded is None
    return recorded == file_digest(colour.path)


def resolve_species(config: Config, names: list[str], library: Library) -> tuple[Species, ...]:
    """The library species of each ``model`` in ``names``; a failure names ``species[i].model``."""
    models = [s.model for s in config.species]
    out = []
    for model in names:
        field = f"species[{models.index(model)}].model" if model in models else "species"
        try:
            sp = library.resolve(model, config.base_dir)
        except ForestError as e:
            raise ConfigError(config.path, field, e.message) from None
        except (OSError, KeyError, ValueError) as e:
            raise ConfigError(config.path, field, f"cannot resolve tree model {model!r}: {e}") from None
        if not sp.lods:
            raise ConfigError(config.path, field, f"tree model {model!r} has no levels of detail")
        out.append(sp)
    return tuple(out)


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
    step(0.0, "terrain")

    if library is None:
        from .library import open_library

        library = open_library()
    check_species(config, library)  # a misspelled species fails now, not after the trees are scattered
    terrain = load_terrain(config.terrain, config.path)
    if instances is None or isinstance(instances, (str, Path)):
        from .scatter import scene_instances

        inst = scene_instances(config, instances, progress=lambda f, m="": step(0.1 + 0.6 * f, m), terrain=terrain)
    else:
        inst = instances
        expected = [s.model for s in config.species]
        if list(inst.species_names) != expected:
            raise ForestError(
                f"instances: species {inst.species_names} do not match the config's [[species]] models "
                f"{expected}; scatter again"
            )
    step(0.75, "colour map")
    colour = _colour_grid(config, terrain)
    if not _scattered_with(inst, colour):
        inst = retint(inst, colour)
    step(0.8, "species")
    species = resolve_species(config, list(inst.species_names), library)
    lod = LodPlan(config.lod.bands, tuple(len(sp.lods) for sp in species))
    step(1.0, "scene")
    return Scene(config, terrain, inst, colour, library, species, lod)
