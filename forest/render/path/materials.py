"""forest's materials evaluated in drjit: albedo, alpha cut-outs, and the two BSDFs.

Albedo of a hit x with texture coordinates (u, v) on a part with material m
(the library's model, ``forest.render.materials``):

    a(x) = c_m · detail_m(u, v) · G(x)^[m tinted] · A(x)^[m terrain map]

with c_m the part's linear colour (times the tint of its row in the ``leaf_tint`` /
``ground_tint`` parameters: a species' leaves, the terrain; see :meth:`MaterialArrays.tinted_colours`), detail_m the RGB of its texture (a linear
detail factor, 1 without a texture), G the colour grid and A a terrain colour
map, both looked up at x's world X/Z with bilinear interpolation between texel
centres placed at pixel centres and clamped at the edges — the same lookup as
the ``gridvolume`` texture of the scalar renderer.  G is a ``dr.Texture2f`` over a
tensor that may carry gradients, so images differentiate with respect to it.

BSDFs, both two-sided, in a frame whose normal n faces the incoming direction ωi:

* surface (bark, terrain, buildings): Lambertian, f = a/π for ωo on ωi's side;
* leaf (a thin sheet): f = R/π on ωi's side
  and T/π on the other, R = (1 − τ)·a, T = τ·a.  Sampling picks the side with
  probability p = R̄ / (R̄ + T̄) (channel means), then a cosine-weighted
  direction, so pdf = p·|cos θo|/π (or (1 − p)·|cos θo|/π).

Opacity is the texture's alpha α.  All textures of a scene share one RGBA
atlas (one lookup instead of one masked lookup per texture, see
``bench/bench_forest_path.py``): each tile is padded with a two-texel border
copied with wrap-around, and a lookup maps (u, v) to
``origin + frac(u, v) · size`` so that a tile repeats exactly like Mitsuba's
``bitmap`` texture with ``wrap_mode = repeat`` under bilinear filtering.  UVs
follow Mitsuba's image convention (v = 0 is the image's top row).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from ...errors import ForestError
from ...images import read_image, srgb_to_linear
from .inputs import Material

KIND_SURFACE = 0
KIND_LEAF = 1
#: Border (texels) around each atlas tile, filled with the tile's wrapped-around texels.
ATLAS_PAD = 2
ATLAS_MAX_WIDTH = 4096


@lru_cache(maxsize=64)
def texture_rgba(path: str) -> np.ndarray:
    """(H, W, 4) float32: linear RGB detail and straight alpha (1 where the image has none)."""
    try:
        img = read_image(path, what="texture", unassociated=True)
    except ForestError:
        raise
    except Exception as e:  # an unreadable file is a user mistake, reported on one line
        raise ForestError(f"{path}: cannot read texture: {e}") from None
    c = img.shape[2]
    rgb = img[..., :3] if c >= 3 else np.repeat(img[..., :1], 3, axis=2)
    if Path(path).suffix.lower() not in (".exr", ".hdr"):
        rgb = srgb_to_linear(rgb)
    alpha = img[..., 3:4] if c == 4 else (img[..., 1:2] if c == 2 else np.ones(img.shape[:2] + (1,), np.float32))
    return np.ascontiguousarray(np.concatenate([rgb, alpha], axis=2), dtype=np.float32)


@dataclass
class Atlas:
    """RGBA tiles packed on shelves: ``image`` (H, W, 4) and per tile (u0, v0, su, sv) in atlas units."""

    image: np.ndarray
    rects: np.ndarray  # (T, 4) float32
    opaque: np.ndarray  # (T,) bool: alpha is 1 everywhere


def pack_atlas(images: list[np.ndarray], pad: int = ATLAS_PAD, max_width: int = ATLAS_MAX_WIDTH) -> Atlas:
    """Shelf-pack ``images`` (each (h, w, 4)) with a wrapped border of ``pad`` texels.

    Tiles are placed tallest first, left to right on shelves no wider than
    ``max_width``.  A tile's rect is the inner (unpadded) region, so a lookup
    at atlas coordinate ``u0 + frac(u)·su`` reads the tile and bilinear taps
    that fall off its edge read the opposite edge, as a repeating texture would.
    """
    if not images:
        return Atlas(np.ones((1, 1, 4), np.float32), np.zeros((0, 4), np.float32), np.zeros(0, bool))
    order = sorted(range(len(images)), key=lambda i: (-images[i].shape[0], i))
    width = min(max_width, max(im.shape[1] + 2 * pad for im in images))
    width = max(width, max(im.shape[1] + 2 * pad for im in images))
    x = y = shelf = 0
    pos: dict[int, tuple[int, int]] = {}
    for i in order:
        h, w = images[i].shape[0] + 2 * pad, images[i].shape[1] + 2 * pad
        if x + w > width:
            x, y, shelf = 0, y + shelf, 0
        pos[i] = (x, y)
        x += w
        shelf = max(shelf, h)
    height = y + shelf
    atlas = np.zeros((height, width, 4), np.float32)
    rects = np.zeros((len(images), 4), np.float32)
    for i, im in enumerate(images):
        px, py = pos[i]
        h, w = im.shape[:2]
        atlas[py : py + h + 2 * pad, px : px + w + 2 * pad] = np.pad(im, ((pad, pad), (pad, pad), (0, 0)), mode="wrap")
        rects[i] = ((px + pad) / width, (py + pad) / height, w / width, h / height)
    opaque = np.array([bool(im[..., 3].min() >= 1.0) for im in images])
    return Atlas(atlas, rects, opaque)


@dataclass
class MaterialTable:
    """Materials deduplicated into numpy columns (one row per material) and the texture atlas."""

    kind: np.ndarray  # (M,) uint32: KIND_SURFACE | KIND_LEAF
    colour: np.ndarray  # (M, 3) float32
    tau: np.ndarray  # (M,) float32, transmitted share (leaves)
    texture: np.ndarray  # (M,) int32, atlas tile or −1
    cutout: np.ndarray  # (M,) bool: has a texture whose alpha is below 1 somewhere
    tinted: np.ndarray  # (M,) bool: multiplied by the colour grid
    terrain_map: np.ndarray  # (M,) bool: multiplied by the terrain colour map
    atlas: Atlas
    tint_row: np.ndarray  # (M,) int32: row of the tint table (a species' leaves, the terrain) or −1


class MaterialStore:
    """Collects materials while the geometry is built; :meth:`table` freezes them."""

    def __init__(self) -> None:
        self._rows: list[tuple[Any, ...]] = []
        self._index: dict[tuple[Any, ...], int] = {}
        self._textures: list[str] = []
        self._arrays: dict[str, np.ndarray] = {}

    def add(self, m: Material | Any, *, terrain_map: bool = False, tint_row: int = -1) -> int:
        """Index of material ``m`` (a :class:`Material` or a library ``Part``), added on first use.

        ``tint_row``: the row of the tint table that multiplies its colour (−1: none); materials
        of different rows are kept apart even when equal, so each row tints only its own.

        A texture is an image path, or an (h, w, 3|4) array (linear RGB detail, optional alpha).
        """
        kind = KIND_LEAF if getattr(m, "kind", "surface") == "leaf" else KIND_SURFACE
        tex = getattr(m, "texture", None)
        if isinstance(tex, np.ndarray):
            tex = self._array_key(tex)
        tau = float(getattr(m, "translucency", 0.0) or 0.0) if kind == KIND_LEAF else 0.0
        if not 0.0 <= tau <= 1.0:
            raise ForestError(f"material translucency must be in [0, 1], got {tau}")
        colour = tuple(round(float(c), 7) for c in m.colour)
        if len(colour) != 3:
            raise ForestError(f"material colour must be RGB, got {m.colour!r}")
        key = (
            kind,
            colour,
            None if tex is None else str(tex),
            bool(getattr(m, "tinted", False)),
            tau,
            terrain_map,
            int(tint_row),
        )
        if key not in self._index:
            t = -1
            if tex is not None:
                if str(tex) not in self._textures:
                    self._textures.append(str(tex))
                t = self._textures.index(str(tex))
            self._index[key] = len(self._rows)
            self._rows.append((kind, colour, tau, t, key[3], terrain_map, int(tint_row)))
        return self._index[key]

    def _array_key(self, a: np.ndarray) -> str:
        import hashlib

        arr = np.asarray(a, np.float32)
        if arr.ndim == 2:
            arr = arr[..., None]
        if arr.ndim != 3 or arr.shape[2] not in (1, 3, 4) or not np.isfinite(arr).all():
            raise ForestError(f"a texture array must be a finite (h, w, 1|3|4) image, got shape {arr.shape}")
        if arr.shape[2] == 1:
            arr = np.repeat(arr, 3, axis=2)
        if arr.shape[2] == 3:
            arr = np.concatenate([arr, np.ones(arr.shape[:2] + (1,), np.float32)], axis=2)
        key = "array:" + hashlib.sha1(np.ascontiguousarray(arr).tobytes() + repr(arr.shape).encode()).hexdigest()
        self._arrays[key] = np.ascontiguousarray(arr, np.float32)
        return key

    def __len__(self) -> int:
        return len(self._rows)

    def table(self) -> MaterialTable:
        """The stored materials as a :class:`MaterialTable` with one texture atlas (empty: one grey surface)."""
        atlas = pack_atlas([self._arrays[p] if p in self._arrays else texture_rgba(p) for p in self._textures])
        rows = self._rows or [(KIND_SURFACE, (0.5, 0.5, 0.5), 0.0, -1, False, False, -1)]
        tex = np.array([r[3] for r in rows], np.int32)
        cut = np.array([t >= 0 and not atlas.opaque[t] for t in tex.tolist()], bool)
        return MaterialTable(
            kind=np.array([r[0] for r in rows], np.uint32),
            colour=np.array([r[1] for r in rows], np.float32).reshape(-1, 3),
            tau=np.array([r[2] for r in rows], np.float32),
            texture=tex,
            cutout=cut,
            tinted=np.array([r[4] for r in rows], bool),
            terrain_map=np.array([r[5] for r in rows], bool),
            atlas=atlas,
            tint_row=np.array([r[6] for r in rows], np.int32),
        )


def world_map_texture(mi: Any, data: Any, *, differentiable: bool = False) -> Any:
    """A bilinear, edge-clamped ``Texture2f`` over an (H, W, 3) map (numpy array or ``TensorXf``).

    Its (0, 0) corner is (xmin, zmin) and texel (i, j)'s centre lies at the
    centre of pixel (i, j) of the map convention; see :func:`world_map_uv`.
    ``differentiable``: the tensor may carry gradients (no hardware texture).
    """
    import drjit as dr

    t = data if isinstance(data, mi.TensorXf) else mi.TensorXf(np.ascontiguousarray(data, dtype=np.float32))
    return mi.Texture2f(
        t,
        use_accel=not differentiable,
        migrate=False,
        filter_mode=dr.FilterMode.Linear,
        wrap_mode=dr.WrapMode.Clamp,
    )


@dataclass
class MaterialArrays:
    """The material table as drjit arrays for one variant (built once per scene)."""

    kind: Any
    colour: Any
    tau: Any
    texture: Any
    cutout: Any
    tinted: Any
    terrain_map: Any
    rects: Any
    atlas: Any  # Texture2f (RGBA)
    has_cutouts: bool
    has_textures: bool
    tint_row: np.ndarray | None = None  # (M,) int32, numpy: the tint table row of each material, −1 none

    @classmethod
    def build(cls, mi: Any, table: MaterialTable) -> MaterialArrays:
        """``table`` as drjit arrays of ``mi``'s variant; the atlas a linear-filtered, clamped ``Texture2f``."""
        import drjit as dr

        atlas = mi.Texture2f(
            mi.TensorXf(table.atlas.image),
            use_accel=True,
            migrate=False,
            filter_mode=dr.FilterMode.Linear,
            wrap_mode=dr.WrapMode.Clamp,
        )
        rects = table.atlas.rects if len(table.atlas.rects) else np.zeros((1, 4), np.float32)
        return cls(
            kind=mi.UInt32(table.kind),
            colour=mi.Float(table.colour.ravel()),
            tau=mi.Float(table.tau),
            texture=mi.Int32(table.texture),
            cutout=mi.Bool(table.cutout),
            tinted=mi.Bool(table.tinted),
            terrain_map=mi.Bool(table.terrain_map),
            rects=mi.Float(rects.ravel().astype(np.float32)),
            atlas=atlas,
            has_cutouts=bool(table.cutout.any()),
            has_textures=bool((table.texture >= 0).any()),
            tint_row=table.tint_row.copy(),
        )

    def tinted_colours(self, mi: Any, table: Any) -> MaterialArrays:
        """The materials with their colours multiplied by a tint table: a copy whose ``colour`` is
        c_m ⊙ t[row_m] (rows −1 keep c_m).  ``table`` is a flat Float of R·3 values (R rows, RGB);
        gradients flow from it into every image rendered with the copy."""
        import dataclasses

        import drjit as dr

        rows = np.asarray(self.tint_row if self.tint_row is not None else [], np.int64)
        n_rows = dr.width(table) // 3
        if not len(rows) or not (rows >= 0).any():
            return self
        # Rows −1 gather a trailing 1: the table is extended by one white entry.
        ext = dr.concat([table, mi.Float(1.0, 1.0, 1.0)])
        idx = np.where(rows >= 0, rows, n_rows).astype(np.uint32)
        flat = np.repeat(idx * 3, 3) + np.tile(np.arange(3, dtype=np.uint32), len(idx))
        tint = dr.gather(mi.Float, ext, mi.UInt32(flat))
        return dataclasses.replace(self, colour=self.colour * tint)

    def tile_uv(self, mi: Any, tex: Any, uv: Any, active: Any) -> Any:
        """Atlas coordinates of ``uv`` on tile ``tex`` (repeat wrap)."""
        import drjit as dr

        r = dr.gather(mi.Vector4f, self.rects, mi.UInt32(dr.maximum(tex, 0)), active)
        f = uv - dr.floor(uv)
        return mi.Point2f(dr.fma(f.x, r.z, r.x), dr.fma(f.y, r.w, r.y))

    def alpha(self, mi: Any, material: Any, uv: Any, active: Any) -> Any:
        """Opacity α ∈ [0, 1] of the hit (1 for materials without cut-outs)."""
        import drjit as dr

        if not self.has_cutouts:
            return dr.full(mi.Float, 1.0, dr.width(material))
        cut = dr.gather(mi.Bool, self.cutout, material, active) & active
        tex = dr.gather(mi.Int32, self.texture, material, cut)
        a = mi.Float(1.0)
        texel = self.atlas.eval(self.tile_uv(mi, tex, uv, cut), active=cut)
        return dr.select(cut, dr.clip(texel[3], 0.0, 1.0), a)


@dataclass
class Shading:
    """What a BSDF needs at a hit: the albedo split into reflection and transmission, and the sampling split."""

    reflect: Any  # Color3f R (albedo a for surfaces)
    transmit: Any  # Color3f T (0 for surfaces)
    p_reflect: Any  # Float: probability of sampling the reflection lobe

    def detached(self) -> Shading:
        """The same shading with gradients cut (``dr.detach`` of each field)."""
        import drjit as dr

        return Shading(dr.detach(self.reflect), dr.detach(self.transmit), dr.detach(self.p_reflect))


def shading(
    mi: Any,
    mats: MaterialArrays,
    material: Any,
    uv: Any,
    p: Any,
    grid: Any,
    extent: Sequence[float],
    terrain_map: tuple[Any, Sequence[float]] | None,
    active: Any,
) -> Shading:
    """R, T and the lobe probability at a hit (see the module docstring).

    ``grid`` is a ``Texture2f`` over ``extent`` (xmin, zmin, xmax, zmax) or None;
    ``terrain_map`` a (``Texture2f``, its own extent) pair or None.  Gradients flow
    from ``grid``'s tensor into R and T.
    """
    import drjit as dr

    colour = dr.gather(mi.Color3f, mats.colour, material, active)
    a = mi.Color3f(colour)
    if mats.has_textures:
        tex = dr.gather(mi.Int32, mats.texture, material, active)
        textured = active & (tex >= 0)
        texel = mats.atlas.eval(mats.tile_uv(mi, tex, uv, textured), active=textured)
        a = dr.select(textured, a * mi.Color3f(texel[0], texel[1], texel[2]), a)
    xmin, zmin, xmax, zmax = extent
    pos = mi.Point2f((p.x - xmin) * (1.0 / (xmax - xmin)), (p.z - zmin) * (1.0 / (zmax - zmin)))
    if grid is not None:
        tinted = dr.gather(mi.Bool, mats.tinted, material, active) & active
        g = grid.eval(pos, active=tinted)
        a = dr.select(tinted, a * mi.Color3f(g[0], g[1], g[2]), a)
    if terrain_map is not None:
        tmap, (txmin, tzmin, txmax, tzmax) = terrain_map
        tpos = mi.Point2f((p.x - txmin) * (1.0 / (txmax - txmin)), (p.z - tzmin) * (1.0 / (tzmax - tzmin)))
        mapped = dr.gather(mi.Bool, mats.terrain_map, material, active) & active
        t = tmap.eval(tpos, active=mapped)
        a = dr.select(mapped, a * mi.Color3f(t[0], t[1], t[2]), a)
    leaf = dr.gather(mi.UInt32, mats.kind, material, active) == KIND_LEAF
    tau = dr.gather(mi.Float, mats.tau, material, active)
    R = a * (1.0 - tau)
    T = a * tau
    mr = dr.detach(R[0] + R[1] + R[2])
    mt = dr.detach(T[0] + T[1] + T[2])
    p_r = dr.select(leaf & (mr + mt > 0), mr / dr.maximum(mr + mt, 1e-12), 1.0)
    return Shading(reflect=R, transmit=T, p_reflect=p_r)


def bsdf_eval(sh: Shading, n: Any, wo: Any) -> tuple[Any, Any]:
    """(f·|cos θo|, pdf) of direction ``wo`` (world) with shading normal ``n`` (already facing ωi)."""
    import drjit as dr

    cos_o = dr.dot(n, wo)
    same = cos_o > 0.0
    c = dr.abs(cos_o) * dr.inv_pi
    value = dr.select(same, sh.reflect, sh.transmit) * c
    pdf = dr.select(same, sh.p_reflect, 1.0 - sh.p_reflect) * c
    return value, pdf


def bsdf_sample(mi: Any, sh: Shading, frame: Any, u1: Any, u2: Any) -> tuple[Any, Any, Any]:
    """Sample ωo: (direction (world), weight f·|cos|/pdf, pdf).  ``frame``'s normal faces ωi."""
    import drjit as dr

    reflect = u1 < sh.p_reflect
    local = mi.warp.square_to_cosine_hemisphere(u2)
    local = mi.Vector3f(local.x, local.y, dr.select(reflect, local.z, -local.z))
    wo = frame.to_world(local)
    cos_pdf = dr.abs(local.z) * dr.inv_pi
    p_lobe = dr.select(reflect, sh.p_reflect, 1.0 - sh.p_reflect)
    pdf = p_lobe * cos_pdf
    weight = dr.select(reflect, sh.reflect, sh.transmit) / dr.maximum(p_lobe, 1e-12)
    weight = dr.select(pdf > 0.0, weight, 0.0)
    return wo, weight, pdf
