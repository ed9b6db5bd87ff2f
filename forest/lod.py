"""Levels of detail: the one rule from a tree's view to its species' level, for every backend.

Levels are 0 = high, 1 = medium, 2 = low, 3 = far, clamped to the species'
last level.  A species s has boundaries d₀ < d₁ < d₂ (metres, for a tree of
scale 1) and a tree of scale σ at distance r = |p − c| from the camera gets

    k = #{dᵢ ≤ r / σ}.

``[lod] pixels`` (the automatic rule, the default): a tree covers about

    p = σ · H_s · f / r   pixels high,   f = (W / 2) / tan(fov / 2)

(H_s the height of the species' highest level's bound, W ``[render] width``,
fov the camera's horizontal field of view at the frame; with square pixels f
is also (H_px / 2) / tan(fov_v / 2)).  With thresholds t₀ > t₁ > t₂ the level
is k = #{tᵢ ≥ p}, which is the rule above with per-species boundaries

    dᵢ = H_s · f / tᵢ.

**Seen from above**: the far level's crossed vertical cards are edge-on from
high above, so it also has a horizontal card textured with the crown seen from
above (:func:`forest.library.lod.impostor`); it covers what the high level
covers from any elevation, and the rule needs no exception for steep views
(RIB's ``DetailRange``, which measures raster area alone, agrees with it).

``[lod] distances`` (manual): the same boundaries dᵢ for every species and no
division by the scale, k = #{dᵢ ≤ r}.  ``[lod] auto = false``: every tree is
level 0.

The Mitsuba and forest_path renderers apply it per frame and tree
(:meth:`forest.scene.Scene.levels`); RIB writes the same rule as
``DetailRange`` bands (:meth:`LodPlan.bands`; RenderMan measures each tree's
own scaled bound, which is the division by σ); look-dev renders the
production scene with it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from .config import Config
    from .library import Species

LOD_NAMES = ("high", "medium", "low", "far")


def camera_distance(position: np.ndarray, camera: np.ndarray) -> np.ndarray:
    """|p − c| per tree: the distance from each position (N, 3) to the camera position (3,), metres."""
    r: np.ndarray = np.linalg.norm(np.asarray(position, np.float64) - np.asarray(camera, np.float64)[None, :], axis=1)
    return r


def lod_levels(
    position: np.ndarray, camera: np.ndarray, distances: tuple[float, ...] | list[float], n_lods: np.ndarray
) -> np.ndarray:
    """Level per tree: k = #{dᵢ ≤ |p − c|}, clamped to ``n_lods − 1`` (the manual rule)."""
    position = np.asarray(position, dtype=np.float64)
    n_lods = np.asarray(n_lods)
    if len(distances) == 0 or len(position) == 0:
        return np.zeros(len(position), dtype=np.int64)
    r = camera_distance(position, camera)
    k = np.searchsorted(np.asarray(distances, dtype=np.float64), r, side="right")
    out: np.ndarray = np.minimum(k, n_lods - 1).astype(np.int64)
    return out


def focal_pixels(width: int, fov: float) -> float:
    """Focal length in pixels of an image ``width`` pixels wide with horizontal field of view ``fov`` degrees."""
    return (width / 2) / math.tan(math.radians(fov) / 2)


def projected_pixels(height: np.ndarray, distance: np.ndarray, width: int, fov: float) -> np.ndarray:
    """Projected height in pixels, p = h · f / r, of objects ``height`` metres tall at ``distance`` metres."""
    f = focal_pixels(width, fov)
    return np.asarray(height, np.float64) * f / np.maximum(np.asarray(distance, np.float64), 1e-9)


@dataclass(frozen=True)
class Band:
    """Camera distances [near, far) metres (for a tree of scale 1) over which a species uses ``level``."""

    level: int
    near: float
    far: float  # math.inf for the last band


@dataclass(frozen=True)
class LodPlan:
    """The rule of ``[lod]`` (module docstring) and how many levels each species has.

    Manual: ``distances``.  Automatic: ``pixels`` with ``heights`` (each species'
    highest-level bound height, metres), the image ``width`` and the camera's
    ``fov`` (degrees, horizontal; the default of :meth:`bands` and :meth:`levels`).
    Neither: off, every tree at level 0.
    """

    distances: tuple[float, ...]
    n_lods: tuple[int, ...]  # per species index
    pixels: tuple[float, ...] = ()
    heights: tuple[float, ...] = ()  # per species index, the automatic rule's H_s
    width: int = 0
    fov: float = 40.0
    solid_pixels: float = 0.0  # forest_path's solid cards on trees at most this many pixels tall (0: none)

    @property
    def mode(self) -> str:
        """``"pixels"`` (automatic), ``"distances"`` (manual) or ``"off"``."""
        if self.pixels:
            return "pixels"
        return "distances" if self.distances else "off"

    def describe(self) -> str:
        """The rule in words, e.g. ``auto: pixels 240, 80, 20`` or ``distances 40, 120, 300 m``."""
        if self.mode == "pixels":
            return "auto: pixels " + ", ".join(f"{t:g}" for t in self.pixels)
        if self.mode == "distances":
            return "distances " + ", ".join(f"{d:g}" for d in self.distances) + " m"
        return "off"

    def boundaries(self, species: int, fov: float | None = None) -> tuple[float, ...]:
        """The boundaries d₀ < d₁ < … of one species for a tree of scale 1, metres (camera ``fov``: the plan's)."""
        if not self.pixels:
            return self.distances
        f = focal_pixels(self.width, self.fov if fov is None else fov)
        h = max(float(self.heights[species]), 1e-6)
        return tuple(h * f / t for t in self.pixels)

    def levels(
        self,
        position: np.ndarray,
        species: np.ndarray,
        camera: np.ndarray,
        scale: np.ndarray | None = None,
        fov: float | None = None,
    ) -> np.ndarray:
        """Level per tree for a camera position (and, automatic, the trees' ``scale`` and the camera's ``fov``)."""
        species = np.asarray(species, dtype=np.int64)
        n = np.asarray(self.n_lods or (1,), dtype=np.int64)[species]
        if not self.pixels:
            return lod_levels(position, camera, self.distances, n)
        position = np.asarray(position, dtype=np.float64)
        if len(position) == 0:
            return np.zeros(0, dtype=np.int64)
        r = camera_distance(position, camera)
        if scale is not None:
            r = r / np.asarray(scale, dtype=np.float64)
        edges = np.array([self.boundaries(s, fov) for s in range(len(self.n_lods))], dtype=np.float64)
        k = (r[:, None] >= edges[species]).sum(axis=1)
        out: np.ndarray = np.minimum(k, n - 1).astype(np.int64)
        return out

    def solid(
        self,
        position: np.ndarray,
        species: np.ndarray,
        camera: np.ndarray,
        scale: np.ndarray | None = None,
        fov: float | None = None,
    ) -> np.ndarray:
        """Per tree, whether forest_path draws its cut-out leaf cards solid: its projected height
        p = σ·H_s·f/r is at most ``solid_pixels`` (``[lod] solid_pixels``; any rule, any level)."""
        position = np.asarray(position, dtype=np.float64)
        if self.solid_pixels <= 0.0 or len(position) == 0 or not self.heights:
            return np.zeros(len(position), dtype=bool)
        r = camera_distance(position, camera)
        h = np.asarray(self.heights, dtype=np.float64)[np.asarray(species, dtype=np.int64)]
        if scale is not None:
            h = h * np.asarray(scale, dtype=np.float64)
        p = projected_pixels(h, r, self.width, self.fov if fov is None else fov)
        out: np.ndarray = p <= self.solid_pixels
        return out

    def bands(self, species: int, fov: float | None = None) -> list[Band]:
        """The distance bands of one species (scale 1), consecutive bands of the same level merged."""
        edges = [0.0, *self.boundaries(species, fov), math.inf]
        last = self.n_lods[species] - 1
        out: list[Band] = []
        for b in range(len(edges) - 1):
            level = min(b, last)
            if out and out[-1].level == level:
                out[-1] = Band(level, out[-1].near, edges[b + 1])
            else:
                out.append(Band(level, edges[b], edges[b + 1]))
        return out


def lod_plan(config: Config, species: Sequence[Species]) -> LodPlan:
    """The :class:`LodPlan` of a config's ``[lod]`` for the resolved species (per species index of the InstanceSet)."""
    lod = config.lod
    n_lods = tuple(len(sp.lods) for sp in species)
    heights = tuple(float(np.asarray(sp.lods[0].bounds)[1, 1] - np.asarray(sp.lods[0].bounds)[0, 1]) for sp in species)
    width, fov, solid = int(config.render.width), float(config.camera.fov), float(lod.solid_pixels)
    if lod.mode == "pixels":
        return LodPlan((), n_lods, lod.thresholds, heights, width, fov, solid)
    return LodPlan(lod.bands, n_lods, heights=heights, width=width, fov=fov, solid_pixels=solid)
