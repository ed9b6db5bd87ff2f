"""Levels of detail: the one rule from camera distance to a species' level, for every backend.

With boundaries d₀ < d₁ < d₂ (``[lod] distances``), a tree at distance
r = |p − c| from the camera gets level

    k = #{dᵢ ≤ r}        (0 = high, 1 = medium, 2 = low, 3 = far),

clamped to the species' last level.  Without ``[lod]`` every tree is level 0.
The Mitsuba renderer applies it per frame and tree; RIB writes the same rule
as ``DetailRange`` bands (:meth:`LodPlan.bands`); look-dev renders the
production scene with it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

LOD_NAMES = ("high", "medium", "low", "far")


def lod_levels(
    position: np.ndarray, camera: np.ndarray, distances: tuple[float, ...] | list[float], n_lods: np.ndarray
) -> np.ndarray:
    """Level per tree: k = #{dᵢ ≤ |p − c|}, clamped to ``n_lods − 1`` (the module's rule)."""
    position = np.asarray(position, dtype=np.float64)
    n_lods = np.asarray(n_lods)
    if len(distances) == 0 or len(position) == 0:
        return np.zeros(len(position), dtype=np.int64)
    r = np.linalg.norm(position - np.asarray(camera, dtype=np.float64)[None, :], axis=1)
    k = np.searchsorted(np.asarray(distances, dtype=np.float64), r, side="right")
    out: np.ndarray = np.minimum(k, n_lods - 1).astype(np.int64)
    return out


@dataclass(frozen=True)
class Band:
    """Camera distances [near, far) metres over which a species uses ``level``."""

    level: int
    near: float
    far: float  # math.inf for the last band


@dataclass(frozen=True)
class LodPlan:
    """The ``[lod]`` boundaries and how many levels each species has."""

    distances: tuple[float, ...]
    n_lods: tuple[int, ...]  # per species index

    def levels(self, position: np.ndarray, species: np.ndarray, camera: np.ndarray) -> np.ndarray:
        """Level per tree for a camera position (see the module docstring)."""
        n = np.asarray(self.n_lods or (1,), dtype=np.int64)[np.asarray(species, dtype=np.int64)]
        return lod_levels(position, camera, self.distances, n)

    def bands(self, species: int) -> list[Band]:
        """The distance bands of one species, consecutive bands of the same level merged."""
        edges = [0.0, *self.distances, math.inf]
        last = self.n_lods[species] - 1
        out: list[Band] = []
        for b in range(len(edges) - 1):
            level = min(b, last)
            if out and out[-1].level == level:
                out[-1] = Band(level, out[-1].near, edges[b + 1])
            else:
                out.append(Band(level, edges[b], edges[b + 1]))
        return out
