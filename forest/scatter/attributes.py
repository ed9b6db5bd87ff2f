"""Per-tree attributes of the survivors: yaw, scale, wind phase, tint, partition, orientation.

For a tree drawn as candidate i of species k:

* yaw ψ = 2π·ξ_yaw[i], snapped to multiples of the species' ``yaw_step`` when
  it is > 0 (street-aligned buildings);
* scale = lo_k + (hi_k − lo_k)·s with the species' ``scale = [lo, hi]`` and
  s = ξ_scale[i] uniform, or the survival rule's size in [0, 1] (the
  ecosystem's r / R), times an emergent's factor where ``[scatter]
  emergents`` selects the tree (:func:`forest.scatter.canopy.emergent_factors`), times the edge taper's
  factor where ``[scatter] edge_taper`` is set (:func:`forest.scatter.canopy.edge_taper_factors`);
* wind phase 2π·ξ_phase[i];
* individual ⌊n_k·ξ_individual[i]⌋ with n_k the species' ``individuals``
  (:attr:`forest.config.schema.SpeciesConfig.individual_count`), plus n_k for a
  snag (ξ_dead[i] < the species' ``dead``, :mod:`forest.scatter.canopy`);
* tint: the colour map's tint (mean 1, :func:`forest.maps.colour_tint_grid`)
  at the tree's stored (float32) position, bilinear in linear light, with the
  tree's hue/value jitter (:func:`forest.tint.tree_tints`) — the same
  function the Scene applies, so the column is what every backend uses;
  partition: the region under the tree (nearest pixel of the partition map);
* rotation: the quaternion q = q_tilt · q_yaw (yaw about +Y, then a tilt of +Y
  towards the terrain normal by the species' ``align`` or ``[scatter]
  align_to_normal``), :func:`forest.instances.yaw_tilt_quaternion`.

ξ are the candidate streams of :func:`forest.scatter.candidates.random_streams`,
indexed by candidate, so a tree's attributes never depend on which other
candidates survived.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..config import Config
from ..instances import InstanceSet, yaw_tilt_quaternion
from ..maps import MapSet
from ..terrain import Terrain
from ..tint import TintParams, Where
from .candidates import Candidates
from .canopy import edge_taper_factors, emergent_factors


def snap_yaw(yaw: np.ndarray, step_deg: np.ndarray) -> np.ndarray:
    """Round yaw to multiples of ``step_deg`` where it is > 0 (e.g. 90° for street-aligned blocks)."""
    if not (np.asarray(step_deg) > 0).any():
        return yaw
    step = np.radians(step_deg)
    snapped = np.round(yaw / np.where(step > 0, step, 1.0)) * step
    return np.where(step > 0, np.mod(snapped, 2 * np.pi), yaw)


def draw_individuals(xi: np.ndarray, count: np.ndarray) -> np.ndarray:
    """Individual ⌊count·ξ⌋ ∈ [0, count) of each tree from uniforms ξ ∈ [0, 1): uint8."""
    return np.minimum(np.floor(xi * count), count - 1).astype(np.uint8)


def tree_attributes(
    trees: Candidates,
    size: np.ndarray | None,
    config: Config,
    terrain: Terrain,
    maps: MapSet,
    rng: dict[str, np.random.Generator],
    meta: dict[str, Any],
    tints: TintParams,
    dead: np.ndarray | None = None,
) -> InstanceSet:
    """The InstanceSet of the surviving candidates ``trees`` (rows in candidate order = sorted ids).

    ``dead`` (per species, default none) is each species' share of snags.
    """
    species = config.species
    n = config.scatter.count
    sel = trees.index
    k = trees.species
    yaw = rng["yaw"].random(n)[sel] * (2 * np.pi)
    scale_xi = rng["scale"].random(n)[sel]
    phase = rng["phase"].random(n)[sel] * (2 * np.pi)
    n_ind = np.array([sp.individual_count for sp in species])[k]
    individual = draw_individuals(rng["individual"].random(n)[sel], n_ind)
    if dead is not None and (dead > 0).any():
        snags = rng["dead"].random(n)[sel] < dead[k]
        individual = np.where(snags, individual + n_ind, individual).astype(np.uint8)
    position = trees.position.astype(np.float32)
    s = scale_xi if size is None else size
    yaw = snap_yaw(yaw, np.array([sp.yaw_step for sp in species])[k])
    lo = np.array([sp.scale[0] for sp in species])[k]
    hi = np.array([sp.scale[1] for sp in species])[k]
    scale = lo + (hi - lo) * s
    emergents = config.scatter.emergents
    if emergents.fraction > 0:
        scale = scale * emergent_factors(emergents, rng["emergent"].random((2, n))[:, sel])
    taper = config.scatter.edge_taper
    if taper is not None:
        scale = scale * edge_taper_factors(taper, maps.edge_distance(trees.u, trees.v, terrain.extent))
    align = np.array([config.scatter.align_to_normal if sp.align is None else sp.align for sp in species])[k]
    return InstanceSet(
        id=sel.astype(np.uint64),
        position=position,
        rotation=yaw_tilt_quaternion(yaw, trees.normal, align),
        yaw=yaw,
        scale=scale,
        species=k,
        tint=tints.tints(
            maps.tint_at(position[:, 0], position[:, 2], terrain.extent), k, sel, Where.of(position, terrain.extent)
        ),
        partition=maps.partition_at(trees.u, trees.v),
        normal=trees.normal,
        phase=phase,
        individual=individual,
        species_names=[sp.model for sp in species],
        partition_names=maps.partition_names,
        extent=terrain.extent,
        seed=config.seed,
        meta=meta,
    )
