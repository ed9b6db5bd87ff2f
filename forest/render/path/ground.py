"""The ground as forest_path draws it: the Scene's albedo grid, faded past the terrain's edge, and its detail.

The ground is resolved once, on the Scene (``scene.terrain_albedo``,
:mod:`forest.ground`: ``[render] terrain_texture``, else ``terrain_colour``,
else the ``[ground]`` rules); this module only lays it out as
:class:`~forest.render.path.PathInputs` wants it.  With ``[render]
horizon_ground`` the grid is padded to fade to its mean colour on the skirt
(:func:`forest.skirt.fade_beyond_edge`).  The fitted ``ground_tint`` is not
folded in here: forest_path applies it as a parameter, which look-dev
differentiates.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ...skirt import fade_beyond_edge

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


def ground_look(scene: Scene) -> GroundLook:
    """The :class:`GroundLook` of a Scene (module docstring)."""
    albedo = scene.terrain_albedo
    grid = np.asarray(albedo.rgb, np.float32)
    xmin, zmin, xmax, zmax = (float(v) for v in albedo.extent)
    extent = (xmin, zmin, xmax, zmax)
    if scene.config.render.horizon_ground:
        grid, extent = fade_beyond_edge(grid, extent)
    tile = float(albedo.detail_tile_m or 0.0)
    if albedo.detail is None or tile <= 0:
        return GroundLook(grid, extent)
    return GroundLook(grid, extent, albedo.detail, tile)


def detail_rgb(detail: np.ndarray | Path | str) -> np.ndarray:
    """A detail texture as (h, w, 3) float32 linear RGB (an image path is read like a library texture)."""
    if isinstance(detail, (str, Path)):
        from .materials import texture_rgba

        return np.ascontiguousarray(texture_rgba(str(detail))[..., :3])
    a = np.asarray(detail, np.float32)
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, axis=2)
    return np.ascontiguousarray(a[..., :3])
