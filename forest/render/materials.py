"""Materials of library parts for the ``scalar_rgb`` renderer (Mitsuba's own BSDFs).

For a part with base colour c (linear RGB), optional texture (RGB = a linear
*detail factor*, alpha = card mask; see ``forest.library.textures``), tint
flag and translucency τ, the surface albedo at a hit x with uv (u, v) is

    a(x) = c · detail(u, v) · M(x)        (M = colour map at x's world position,
                                           1 where the part is not tinted)

Leaves split it into reflection R = (1 − τ)·a and diffuse transmission T = τ·a
(forest_path's leaf, :mod:`forest.render.path.materials`, does exactly this).
Here, without a Python plugin per sample (a Python BSDF runs once per sample
in ``scalar_rgb``: about 30× a native two-sided ``diffuse`` on a card scene,
which would turn a 3-minute frame into an hour and a half), leaves with τ > 0
are Mitsuba's native ``principledthin`` with ``base_color`` a and
``diff_trans`` = 2τ, which splits its diffuse lobe into reflection
(1 − τ)·a and transmission τ·a — the same split, measured at no cost over
``diffuse`` (its specular lobe, index 1.5, adds a sheen at grazing angles
only); leaves with τ = 0, bark and surfaces are two-sided ``diffuse``.  A
tinted textured part takes the map × c × mean(detail over the card) — the
texture's alpha still cuts the card; its detail modulation is averaged.
Opacity is the texture's alpha (``mask``).  A tinted part's c includes the
species' fitted leaf tint and, per shapegroup, a colour-jitter bin's factor
(:mod:`forest.render.instancing`); an untextured part's constant albedo is
clamped to 1 (Mitsuba refuses an RGB reflectance above 1).
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from ..images import read_image, srgb_to_linear
from ..runtime import mitsuba
from .scene import colour_grid_texture

if TYPE_CHECKING:
    from ..library.core import Part


@lru_cache(maxsize=64)
def _texture_arrays(path: str) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """(detail RGB linear (H, W, 3), alpha (H, W, 1) or None, mean detail where alpha ≥ ½)."""
    img = read_image(path, what="leaf texture", unassociated=True)  # straight alpha, as stored
    c = img.shape[2]
    rgb = img[..., :3] if c >= 3 else np.repeat(img[..., :1], 3, axis=2)
    rgb = srgb_to_linear(rgb) if Path(path).suffix.lower() not in (".exr", ".hdr") else rgb
    alpha = img[..., 3:4] if c == 4 else (img[..., 1:2] if c == 2 else None)
    mask = (alpha[..., 0] >= 0.5) if alpha is not None else np.ones(rgb.shape[:2], bool)
    mean = rgb[mask].mean(axis=0) if mask.any() else rgb.reshape(-1, 3).mean(axis=0)
    return (
        np.ascontiguousarray(rgb, np.float32),
        (None if alpha is None else np.ascontiguousarray(alpha, np.float32)),
        mean,
    )


def _bitmap(mi: Any, array: np.ndarray) -> dict[str, Any]:
    return {
        "type": "bitmap",
        "bitmap": mi.Bitmap(np.ascontiguousarray(array, dtype=np.float32)),
        "raw": True,
        "filter_type": "bilinear",
        "wrap_mode": "repeat",
    }


class MaterialBuilder:
    """Builds (and caches) the BSDF dict of each part for one variant and one colour map.

    ``colour_grid`` is the colour map as (H, W, 3) linear RGB in the map
    convention (None: no map, tints are 1); ``extent``/``height_range`` place
    it over the terrain.
    """

    def __init__(
        self, variant: str, colour_grid: np.ndarray | None, extent: Sequence[float], height_range: Sequence[float]
    ):
        self.variant = variant
        self.mi = mitsuba(variant)
        self.grid = None if colour_grid is None else np.asarray(colour_grid, np.float32)
        self.extent = extent
        self.height_range = height_range
        self.leaf_model = "principledthin (diff_trans = 2t)"

    # -- albedo textures ---------------------------------------------------------
    def _albedo(self, colour: npt.ArrayLike, tinted: bool, texture: Path | None, share: float) -> dict[str, Any]:
        mi = self.mi
        c = np.asarray(colour, np.float32) * np.float32(share)
        detail = None
        if texture is not None:
            detail, _, mean = _texture_arrays(str(texture))
        if tinted and self.grid is not None:
            scale = c * (mean if detail is not None else 1.0)
            return colour_grid_texture(self.grid * scale, self.extent, self.height_range, self.variant)
        if detail is not None:
            return _bitmap(mi, detail * c)
        # A constant reflectance above 1 (a light part × a tree's colour jitter or leaf tint) is refused by
        # Mitsuba's RGB reflectance spectrum: clamp it (a no-op for every colour that loaded before).
        return {"type": "rgb", "value": [min(float(x), 1.0) for x in c]}

    def _opacity(self, texture: Path | None) -> dict[str, Any] | None:
        if texture is None:
            return None
        _, alpha, _ = _texture_arrays(str(texture))
        if alpha is None or float(alpha.min()) >= 1.0:
            return None
        return _bitmap(self.mi, alpha)

    # -- BSDFs -------------------------------------------------------------------
    def part_bsdf(self, part: Part) -> dict[str, Any]:
        """The BSDF dict of one library part (see the module docstring)."""
        texture = getattr(part, "texture", None)
        tinted = bool(getattr(part, "tinted", False))
        tau = float(getattr(part, "translucency", 0.0) or 0.0)
        bsdf: dict[str, Any]
        if part.kind == "leaf" and tau > 0:
            bsdf = {
                "type": "principledthin",
                "base_color": self._albedo(part.colour, tinted, texture, 1.0),
                "diff_trans": float(min(2.0 * tau, 2.0)),
            }
        else:
            bsdf = {
                "type": "twosided",
                "material": {"type": "diffuse", "reflectance": self._albedo(part.colour, tinted, texture, 1.0)},
            }
        opacity = self._opacity(texture)
        if opacity is not None:
            bsdf = {"type": "mask", "opacity": opacity, "material": bsdf}
        return bsdf
