"""The ground as forest_path draws it: the Scene's albedo grid, faded past the terrain's edge, and its detail.

The ground is resolved once, on the Scene (``scene.terrain_albedo``,
:mod:`forest.ground`: ``[render] terrain_texture``, else ``terrain_colour``,
else the ``[ground]`` rules); this module only lays it out as
:class:`~forest.render.path.PathInputs` wants it.  With ``[render]
horizon_ground`` the grid is padded to fade on the skirt to the far
landscape's albedo that the Scene computed — its canopy and ground mixed by the
crowns' cover (:func:`forest.skirt.far_colour`, :func:`forest.skirt.fade_beyond_edge`),
the same rule as the scalar renderer's.  The fitted ``ground_tint`` is not
folded in here: forest_path applies it as a parameter, which look-dev
differentiates (on the skirt too, as the scalar renderer multiplies it).

The water coverage W (``TerrainAlbedo.water``, None without water rules) rides
along on the same texels; past the terrain's edge it fades to 0 with the same
smoothstep as the colour (W(d) = (1 − s(d/P))·W_edge), so a river that reaches
the edge ends on the skirt instead of running to the horizon.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ...skirt import fade_beyond_edge, far_colour

if TYPE_CHECKING:
    from ...scene import Scene


@dataclass(frozen=True)
class GroundLook:
    """The terrain's reflectance for forest_path.

    ``colour``: an (H, W, 3) linear albedo grid over ``extent`` (map convention);
    ``detail``: a tileable RGB detail texture (an (h, w, 3|4) array or an image
    path) of mean 1 repeated every ``detail_tile`` metres, or None.
    """

    colour: np.ndarray
    extent: tuple[float, float, float, float]
    detail: np.ndarray | Path | None = None
    detail_tile: float = 1.0
    water: np.ndarray | None = None  # (H, W) water coverage over ``extent``, or None


def ground_look(scene: Scene) -> GroundLook:
    """The :class:`GroundLook` of a Scene (module docstring)."""
    albedo = scene.terrain_albedo
    grid = np.asarray(albedo.rgb, np.float32)
    xmin, zmin, xmax, zmax = (float(v) for v in albedo.extent)
    extent = (xmin, zmin, xmax, zmax)
    water = None if albedo.water is None else np.asarray(albedo.water, np.float32)
    if scene.config.render.horizon_ground:
        faded, extent = fade_beyond_edge(grid, extent, far_colour(albedo))
        if water is not None:
            water = fade_to_zero(water, faded.shape[:2])
        grid = faded
    tile = float(albedo.detail_tile_m or 0.0)
    if albedo.detail is None or tile <= 0:
        return GroundLook(grid, extent, water=water)
    return GroundLook(grid, extent, albedo.detail, tile, water)


def fade_to_zero(water: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """The (H, W) coverage padded to ``shape`` (P texels more on every side, as
    :func:`forest.skirt.fade_beyond_edge` pads the colour), fading from the clamped edge to 0."""
    h, w = water.shape
    p = (int(shape[0]) - h) // 2
    if p <= 0:
        return water
    padded = np.pad(water, p, mode="edge")
    rows, cols = np.arange(h + 2 * p), np.arange(w + 2 * p)
    dr = np.maximum(np.maximum(p - rows, rows - (h + p - 1)), 0)
    dc = np.maximum(np.maximum(p - cols, cols - (w + p - 1)), 0)
    t = np.clip(np.maximum(dr[:, None], dc[None, :]) / p, 0.0, 1.0)
    return ((1.0 - t * t * (3.0 - 2.0 * t)) * padded).astype(np.float32)


def detail_rgb(detail: np.ndarray | Path | str) -> np.ndarray:
    """A detail texture as (h, w, 3) float32 linear RGB (an image path is read like a library texture)."""
    if isinstance(detail, (str, Path)):
        from .materials import texture_rgba

        return np.ascontiguousarray(texture_rgba(str(detail))[..., :3])
    a = np.asarray(detail, np.float32)
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, axis=2)
    return np.ascontiguousarray(a[..., :3])
