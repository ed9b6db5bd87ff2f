"""Trees placed by hand (``[[tree]]``): a specimen in a meadow, a hero tree by the camera.

A scattered forest has no tree an artist chose; a lone oak in a field, the tree whose shadow crosses the
foreground or the one the camera frames is placed.  Each ``[[tree]]`` is one of a ``[[species]]``' trees — its
individuals, colour jitter, accents and bark — standing at ``position`` = [x, z] on the terrain whatever the
maps say, and the scatter's trees within ``clear`` metres of its trunk are left out (the stage
``placed tree`` of the scatter report), so no scattered trunk grows through it.

For placed tree j (id ``first_id + j``, after every scattered tree's and ground cover plant's):

* y = the terrain's height under (x, z) (:meth:`forest.terrain.Terrain.height_at`), and the normal
  n ∝ (−∂h/∂x, 1, −∂h/∂z) by central differences over ±:data:`NORMAL_STEP` metres;
* yaw, individual and wind phase as given, else from three uniforms ξ of
  :func:`forest.tint.tree_uniforms` (id, seed, :data:`PLACED_TAG`): yaw 2πξ₀, individual ⌊n_k ξ₁⌋,
  phase 2πξ₂ — a pure function of the tree's place in the list, so editing one tree changes no other;
* tint, partition and rotation by the same functions as a scattered tree's
  (:mod:`forest.scatter.attributes`): the colour map's tint with the species' jitter, the partition
  under the trunk, yaw then the species' tilt toward the normal;
* ``clear`` defaults to the tree's crown radius r = s · max(|x|, |z|) over its highest level's bounds
  (the trunk's axis at the origin), so the crown has room;
* ``dead = true`` makes it a snag: individual n_k + k, whose species then carries its snags as a
  ``[[species]] dead`` does (:func:`forest.scatter.models.resolve_individuals`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.spatial import cKDTree

from ..config import Config
from ..config.schema import PlacedTree, species_index
from ..errors import ConfigError
from ..instances import yaw_tilt_quaternion
from ..library import Species
from ..maps import MapSet
from ..terrain import Terrain
from ..tint import TintParams, Where, tree_uniforms
from .attributes import draw_individuals

#: Seeds the placed trees' own uniforms (yaw, individual, phase).
PLACED_TAG = 0x504C_4143
#: Metres either side of a placed trunk over which the terrain's slope is taken.
NORMAL_STEP = 0.5
#: The scatter report's stage for scattered trees left out around a placed one.
STAGE = "placed tree"


def crown_radius(species: Species) -> float:
    """Horizontal reach of a species' highest level from its trunk's axis, metres (scale 1)."""
    lo, hi = np.asarray(species.bounds, dtype=np.float64)
    return float(np.max(np.abs([lo[0], lo[2], hi[0], hi[2]])))


def placed_species(config: Config) -> np.ndarray:
    """The ``[[species]]`` index of each ``[[tree]]`` (its ``species`` by name, else by model; validated)."""
    return np.array([species_index(config.species, t.species) for t in config.model.tree], dtype=np.int64)


def clear_radii(config: Config, models: Sequence[Species]) -> np.ndarray:
    """Each placed tree's ``clear`` in metres: as given, else its crown radius times its scale."""
    trees = config.model.tree
    return np.array(
        [
            t.scale * crown_radius(models[k]) if t.clear is None else t.clear
            for t, k in zip(trees, placed_species(config))
        ],
        dtype=np.float64,
    )


def cleared(position: np.ndarray, trees: Sequence[PlacedTree], radii: np.ndarray) -> np.ndarray:
    """Which of the scattered trees at ``position`` (N, 3) stand within a placed tree's radius (plan distance).

    Only the trees in the grid cells (side: the largest radius) around a placed tree go into the k-d tree, so a
    few placed trees cost little in a scatter of millions.
    """
    out = np.zeros(len(position), dtype=bool)
    radii = np.asarray(radii, dtype=np.float64)
    live = radii > 0
    if not len(position) or not live.any():
        return out
    centres = np.array([t.position for t in trees], dtype=np.float64)[live]
    radii = radii[live]
    xz = np.asarray(position, dtype=np.float64)[:, [0, 2]]
    side = float(radii.max())
    near = np.flatnonzero(np.isin(cell_codes(xz, side), _around(cell_codes(centres, side))))
    if not len(near):
        return out
    hits = cKDTree(xz[near]).query_ball_point(centres, radii)
    out[near[np.concatenate([np.asarray(h, dtype=np.int64) for h in hits])]] = True
    return out


def cell_codes(xz: np.ndarray, side: float) -> np.ndarray:
    """One integer per point for its cell of a square grid of ``side`` metres: column · 2³² + row (wrapping
    modulo 2⁶⁴ for absurd grids, where a collision only adds candidates: a cell's neighbours still match)."""
    c = np.floor(xz / side).astype(np.int64)
    return c[:, 0] * (1 << 32) + c[:, 1]


def _around(codes: np.ndarray) -> np.ndarray:
    """The codes of these cells and of their eight neighbours."""
    steps = np.array([dx * (1 << 32) + dz for dx in (-1, 0, 1) for dz in (-1, 0, 1)], dtype=np.int64)
    return np.unique((codes[:, None] + steps[None, :]).ravel())


def terrain_normals(terrain: Terrain, x: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Unit normals of the terrain at (x, z) by central differences of its height over ±:data:`NORMAL_STEP`."""
    d = NORMAL_STEP
    dx = (terrain.height_at(x + d, z) - terrain.height_at(x - d, z)) / (2 * d)
    dz = (terrain.height_at(x, z + d) - terrain.height_at(x, z - d)) / (2 * d)
    n = np.stack([-dx, np.ones_like(dx), -dz], axis=1)
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def check_places(config: Config, terrain: Terrain) -> np.ndarray:
    """The placed trees' heights, after checking each stands on the terrain and out of its water.

    A tree outside the terrain's X/Z extent or below ``[terrain] water``'s shore is a
    :class:`~forest.errors.ConfigError` naming ``tree[i].position``.
    """
    trees = config.model.tree
    xz = np.array([t.position for t in trees], dtype=np.float64).reshape(-1, 2)
    xmin, zmin, xmax, zmax = terrain.extent
    off = (xz[:, 0] < xmin) | (xz[:, 0] > xmax) | (xz[:, 1] < zmin) | (xz[:, 1] > zmax)
    if off.any():
        i = int(np.flatnonzero(off)[0])
        raise ConfigError(
            config.path,
            f"tree[{i}].position",
            f"[{xz[i, 0]:g}, {xz[i, 1]:g}] is outside the terrain (x {xmin:g} to {xmax:g}, z {zmin:g} to {zmax:g})",
        )
    y = terrain.height_at(xz[:, 0], xz[:, 1]) if len(xz) else np.zeros(0)
    wet = ~terrain.dry(y)
    if wet.any():
        i = int(np.flatnonzero(wet)[0])
        level = terrain.water[0] if terrain.water is not None else 0.0
        raise ConfigError(
            config.path,
            f"tree[{i}].position",
            f"[{xz[i, 0]:g}, {xz[i, 1]:g}] is in [terrain] water (ground {y[i]:.3g} m, water at {level:g} m)",
        )
    return y


def placed_columns(
    config: Config,
    terrain: Terrain,
    maps: MapSet,
    tints: TintParams,
    heights: np.ndarray,
    first_id: int,
) -> dict[str, np.ndarray]:
    """The ``[[tree]]`` entries as InstanceSet columns (module docstring), ids from ``first_id``."""
    trees = config.model.tree
    n = len(trees)
    k = placed_species(config)
    ids = first_id + np.arange(n, dtype=np.uint64)
    xi = tree_uniforms(ids, config.seed, PLACED_TAG, 3)
    x = np.array([t.position[0] for t in trees], dtype=np.float64)
    z = np.array([t.position[1] for t in trees], dtype=np.float64)
    position = np.stack([x, heights, z], axis=1).astype(np.float32)
    normal = terrain_normals(terrain, x, z).astype(np.float32)
    yaw = np.array([np.nan if t.yaw is None else np.radians(t.yaw) for t in trees], dtype=np.float64)
    yaw = np.where(np.isnan(yaw), xi[:, 0] * (2 * np.pi), yaw)
    count = np.array([config.species[j].individual_count for j in k], dtype=np.int64)
    drawn = draw_individuals(xi[:, 1], count)
    chosen = np.array([d if t.individual is None else t.individual for t, d in zip(trees, drawn)], dtype=np.int64)
    # A snag is individual n + k (forest.scatter.models.resolve_individuals), as a scattered one is.
    individual = (chosen + np.where([t.dead for t in trees], count, 0)).astype(np.uint8)
    species = config.species
    align = np.array([config.scatter.align_to_normal if species[j].align is None else species[j].align for j in k])
    u, v = terrain.to_uv(position[:, 0], position[:, 2])
    return {
        "id": ids,
        "position": position,
        "rotation": yaw_tilt_quaternion(yaw, normal, align),
        "yaw": yaw.astype(np.float32),
        "scale": np.array([t.scale for t in trees], dtype=np.float32),
        "species": k.astype(np.uint16),
        "tint": tints.tints(
            maps.tint_at(position[:, 0], position[:, 2], terrain.extent), k, ids, Where.of(position, terrain.extent)
        ),
        "partition": maps.partition_at(u, v),
        "normal": normal,
        "phase": (xi[:, 2] * (2 * np.pi)).astype(np.float32),
        "individual": individual,
    }
