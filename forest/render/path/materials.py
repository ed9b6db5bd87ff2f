"""forest's materials evaluated in drjit: albedo, alpha cut-outs, and the two BSDFs.

Albedo of a hit x with texture coordinates (u, v) on a part with material m
(the library's model, ``forest.render.materials``):

    a(x) = c_m · detail_m(u, v) · (G(x) ⊙ j_r)^[m tinted] · A(x)^[m terrain map]

with j_r the tint of the hit's tree r beyond the colour map (its hue/value jitter,
:meth:`forest.scene.Scene.tree_jitter`; 1 for world-space parts and without jitter),
c_m the part's linear colour (times the tint of its row in the ``leaf_tint`` /
``ground_tint`` parameters: a species' leaves, the terrain; see :meth:`MaterialArrays.tinted_colours`), detail_m the RGB of its texture (a linear
detail factor, 1 without a texture), G the colour grid and A a terrain colour
map, both looked up at x's world X/Z with bilinear interpolation between texel
centres placed at pixel centres and clamped at the edges — the same lookup as
the ``gridvolume`` texture of the scalar renderer.  G is a ``dr.Texture2f`` over a
tensor that may carry gradients, so images differentiate with respect to it.

Water: where the terrain map carries a water coverage W (its fourth channel, :mod:`forest.ground`),
the detail fades with it, detail_m → (1 − W)·detail_m + W.  The ground's detail texture is the grain
of a soil surface (pebbles, litter) at metre scale; under water the bed is blurred by the rippled
surface's refraction and veiled by the water column's scattering, and the painted water colour is
already that bed seen through the water, so the water's share shows no grain (the scalar renderer,
which draws no detail at all, agrees).

BSDFs, both two-sided, in a frame whose normal n faces the incoming direction ωi:

* surface (bark, terrain, buildings): Lambertian, f = a/π for ωo on ωi's side;
* leaf (a thin sheet): f = R/π on ωi's side
  and T/π on the other, R = (1 − τ)·a, T = τ·a.  Sampling picks the side with
  probability p = R̄ / (R̄ + T̄) (channel means), then a cosine-weighted
  direction, so pdf = p·|cos θo|/π (or (1 − p)·|cos θo|/π).

Leaf cuticle sheen (a leaf of ``sheen`` s > 0 and ``roughness`` α): the wax cuticle reflects
specularly as a rough dielectric of refractive index n ≈ 1.5 (Jacquemoud & Ustin 2019, *Leaf
Optical Properties*, §3: n ≈ 1.45–1.5), white and strongest at grazing angles (Bousquet et al.
2005, "Leaf BRDF measurements and model for specular and diffuse components differentiation",
Remote Sens. Environ. 98: 201–211).  With h = (ωi + ωo)/‖ωi + ωo‖ and μ = cos θ:

    f(ωi, ωo) = s·F(ωi·h)·D(h)·G₂(ωi, ωo) / (4 μi μo)        (ωo on ωi's side only)
              + (1 − s·E(μi)) · (R/π on ωi's side, T/π on the other)

* D: GGX / Trowbridge–Reitz, D(h) = α² / (π ((n·h)²(α² − 1) + 1)²) (Walter et al. 2007,
  "Microfacet models for refraction through rough surfaces", EGSR);
* G₂ = 1 / (1 + Λ(ωi) + Λ(ωo)), Λ(ω) = (√(1 + α² tan²θ) − 1)/2, Smith's height-correlated
  masking–shadowing (Heitz 2014, JCGT 3(2));
* F: Schlick's approximation F = F₀ + (1 − F₀)(1 − ωi·h)⁵ with F₀ = ((n − 1)/(n + 1))² = 0.04;
* E(μi) = ∫ F·D·G₂/(4 μi) dωo, the lobe's directional albedo for s = 1 (tabulated per material
  at 33 values of μi by :func:`sheen_albedo_table`, linearly interpolated).  Scaling the diffuse
  lobes by 1 − s·E(μi) keeps the directional albedo s·E + (1 − s·E)·(R + T) ≤ 1 for
  s ∈ [0, 1] and R + T ≤ 1: the energy the cuticle reflects is taken from what enters the leaf.

Sampling is a one-sample mixture: the specular lobe with probability
p_s = s·E / (s·E + (1 − s·E)·mean(R + T)), its half-vector drawn from GGX's distribution of
visible normals (Heitz 2018, "Sampling the GGX distribution of visible normals", JCGT 7(4)),
pdf_s(ωo) = G₁(ωi)·D(h)/(4 μi); else the diffuse lobes as above.  The pdf returned (and used by
MIS) is the mixture's, p_s·pdf_s + (1 − p_s)·pdf_d, and the weight f·μo/pdf (Veach 1997 §9.2.2),
so a narrow lobe lit by the sun is found by both light sampling and BSDF sampling.  Materials
with s = 0 everywhere trace exactly the code without the lobe.

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
from typing import Any, NamedTuple

import numpy as np

from ...config.schema import WATER_IOR
from ...errors import ForestError
from ...images import read_image, srgb_to_linear
from .arrays import owned
from .inputs import Material, SeaMap

KIND_SURFACE = 0
KIND_LEAF = 1
#: Specular reflectance of the leaf cuticle at normal incidence, ((n − 1)/(n + 1))² for n = 1.5.
CUTICLE_F0 = 0.04
#: Smallest GGX roughness α accepted (a near-mirror lobe cannot be tabulated or sampled stably).
ROUGHNESS_MIN = 0.02
#: Values of μi = cos θi (0 … 1, evenly spaced) of the per-material directional-albedo table E(μi).
SHEEN_TABLE_SIZE = 33
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


def leaf_sheen(m: Any) -> tuple[float, float]:
    """(s, α) of a leaf material or library part: its ``sheen`` and ``roughness`` (0, 0 without a sheen).

    A value out of range is refused on one line (``ForestError``): s ∈ [0, 1], α ∈ [0.02, 1].
    """
    sheen = float(getattr(m, "sheen", 0.0) or 0.0)
    rough = float(getattr(m, "roughness", 0.0) or 0.0)
    if not 0.0 <= sheen <= 1.0:  # also refuses NaN
        raise ForestError(f"leaf sheen must be in [0, 1], got {sheen}")
    if sheen == 0.0:
        return 0.0, 0.0
    if not ROUGHNESS_MIN <= rough <= 1.0:
        raise ForestError(f"leaf roughness must be in [{ROUGHNESS_MIN}, 1], got {rough}")
    return round(sheen, 6), round(rough, 6)


def _ggx_lambda(alpha: Any, mu: Any, sqrt: Any) -> Any:
    """Smith's Λ(ω) = (√(1 + α² tan²θ) − 1)/2 for GGX, from μ = cos θ (numpy or drjit)."""
    mu2 = mu * mu
    return 0.5 * (sqrt(1.0 + alpha * alpha * (1.0 - mu2) / (mu2 + 1e-12)) - 1.0)


def sheen_albedo_table(alpha: float, n: int = SHEEN_TABLE_SIZE, grid: int = 96, *, fresnel: bool = True) -> np.ndarray:
    """E(μi) = ∫ F(ωi·h) D(h) G₂(ωi, ωo) / (4 μi) dωo at μi = k/(n − 1), k = 0 … n − 1 (float32).

    The integral is the expectation of F·G₂/G₁(ωi) over GGX's visible normals (Heitz 2018), taken
    on a deterministic ``grid`` × ``grid`` midpoint rule of the visible-normal warp (μi = 0 is
    evaluated at μi = 10⁻³): a pure function of α, so renders stay byte-reproducible.  With
    ``fresnel=False``, F = 1: the albedo of the bare GGX lobe (what a white glossy BSDF reflects).
    """
    mus = np.maximum(np.linspace(0.0, 1.0, n), 1e-3)
    u = (np.arange(grid) + 0.5) / grid
    u1, u2 = (a.ravel() for a in np.meshgrid(u, u, indexing="ij"))
    out = np.zeros(n, np.float64)
    for k, mu in enumerate(mus):
        wi = np.array([np.sqrt(max(0.0, 1.0 - mu * mu)), 0.0, mu])
        m = _vndf_numpy(wi, alpha, u1, u2)
        cos_im = m @ wi
        wo = 2.0 * cos_im[:, None] * m - wi
        mu_o = wo[:, 2]
        f = CUTICLE_F0 + (1.0 - CUTICLE_F0) * np.clip(1.0 - cos_im, 0.0, 1.0) ** 5 if fresnel else 1.0
        lam_i = _ggx_lambda(alpha, mu, np.sqrt)
        lam_o = _ggx_lambda(alpha, np.maximum(mu_o, 1e-9), np.sqrt)
        g2_over_g1 = (1.0 + lam_i) / (1.0 + lam_i + lam_o)
        out[k] = float(np.mean(np.where(mu_o > 0.0, f * g2_over_g1, 0.0)))
    return out.astype(np.float32)


def _vndf_numpy(wi: np.ndarray, alpha: float, u1: np.ndarray, u2: np.ndarray) -> np.ndarray:
    """Heitz (2018)'s visible-normal sampling of GGX in numpy (local frame, z the normal): (K, 3) normals."""
    vh = np.array([alpha * wi[0], alpha * wi[1], wi[2]])
    vh /= np.linalg.norm(vh)
    lensq = vh[0] ** 2 + vh[1] ** 2
    t1 = np.array([-vh[1], vh[0], 0.0]) / np.sqrt(lensq) if lensq > 0 else np.array([1.0, 0.0, 0.0])
    t2 = np.cross(vh, t1)
    r = np.sqrt(u1)
    phi = 2.0 * np.pi * u2
    p1 = r * np.cos(phi)
    p2 = r * np.sin(phi)
    s = 0.5 * (1.0 + vh[2])
    p2 = (1.0 - s) * np.sqrt(np.maximum(0.0, 1.0 - p1 * p1)) + s * p2
    p3 = np.sqrt(np.maximum(0.0, 1.0 - p1 * p1 - p2 * p2))
    nh = p1[:, None] * t1 + p2[:, None] * t2 + p3[:, None] * vh
    m = np.stack([alpha * nh[:, 0], alpha * nh[:, 1], np.maximum(1e-6, nh[:, 2])], axis=1)
    return m / np.linalg.norm(m, axis=1, keepdims=True)


@lru_cache(maxsize=256)
def _sheen_table_cached(alpha: float) -> np.ndarray:
    return sheen_albedo_table(alpha)


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
    sheen: np.ndarray | None = None  # (M,) float32: cuticle specular weight s (leaves; 0 none)
    roughness: np.ndarray | None = None  # (M,) float32: its GGX α
    bark: np.ndarray | None = None  # (M,) bool: a tree's bark (multiplied by the tree's bark factor)


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
        sheen, rough = leaf_sheen(m) if kind == KIND_LEAF else (0.0, 0.0)
        bark = getattr(m, "kind", "surface") == "bark"
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
            sheen,
            rough,
            bark,
        )
        if key not in self._index:
            t = -1
            if tex is not None:
                if str(tex) not in self._textures:
                    self._textures.append(str(tex))
                t = self._textures.index(str(tex))
            self._index[key] = len(self._rows)
            self._rows.append((kind, colour, tau, t, key[3], terrain_map, int(tint_row), sheen, rough, bark))
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
        rows = self._rows or [(KIND_SURFACE, (0.5, 0.5, 0.5), 0.0, -1, False, False, -1, 0.0, 0.0, False)]
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
            sheen=np.array([r[7] for r in rows], np.float32),
            roughness=np.array([r[8] for r in rows], np.float32),
            bark=np.array([r[9] for r in rows], bool),
        )


class FarCoverArrays(NamedTuple):
    """The far landscape's mosaic of woods and open ground (:mod:`forest.far_cover`) as drjit values.

    ``texture``: the periodic tile's weights (1 − C, C·g), wrapped; ``open``, ``canopy``: ρ_o/ρ_far and
    ρ_c/ρ_far; ``extent`` the terrain's; ``ramp`` P metres; ``tile_m`` the tile's side; ``treeline``,
    ``rockline``, ``rock``: the alpine bands (None: none; :meth:`forest.far_cover.FarCover.alpine`)."""

    texture: Any
    open: Any
    canopy: Any
    extent: tuple[float, float, float, float]
    ramp: float
    tile_m: float
    treeline: float | None = None
    rockline: float | None = None
    rock: Any = None
    snowline: float | None = None
    snow: Any = None

    @classmethod
    def build(cls, mi: Any, far: Any) -> FarCoverArrays:
        """From a :class:`forest.far_cover.FarCover`."""
        import drjit as dr

        tex = mi.Texture2f(
            owned(mi.TensorXf, np.asarray(far.tile, np.float32)),
            use_accel=True,
            migrate=False,
            filter_mode=dr.FilterMode.Linear,
            wrap_mode=dr.WrapMode.Repeat,
        )
        rock = None if far.rock is None else mi.Color3f(*far.rock)
        snow = None if far.snow is None else mi.Color3f(*far.snow)
        return cls(tex, mi.Color3f(*far.open), mi.Color3f(*far.canopy), tuple(far.extent), float(far.ramp),
                   float(far.tile_m), far.treeline, far.rockline, rock, far.snowline, snow)  # fmt: skip

    def factor(self, mi: Any, p: Any, active: Any, up: Any = None) -> Any:
        """m' (Color3f) at world ``p``: the mosaic's factor on the skirt's albedo, 1 on the terrain; ``up`` the
        shading normal's upward component there (None: level; steep faces above the treeline are rock)."""
        import drjit as dr

        from ...far_cover import ROCK_BAND_M, SNOW_BAND_M, STEEP_ROCK_DEG, STEEP_SNOW_DEG, TREELINE_BAND_M

        def smooth(t: Any) -> Any:
            t = dr.clip(t, 0.0, 1.0)
            return t * t * (3.0 - 2.0 * t)

        def band(centre: float, half: float) -> Any:
            return smooth((p.y - (centre - half)) * (0.5 / half))

        def steep(degrees: tuple[float, float]) -> Any:  # 0 on slopes under degrees[0], 1 over degrees[1]
            c0, c1 = (float(np.cos(np.radians(d))) for d in degrees)
            return smooth((c0 - dr.abs(up)) * (1.0 / (c0 - c1)))

        inv = 1.0 / self.tile_m
        w = self.texture.eval(mi.Point2f(p.x * inv, p.z * inv), active=active)
        if self.treeline is None and self.rock is None:
            m = self.open * w[0] + self.canopy * w[1]
        else:  # above the treeline the woods turn to open ground, above the rock line that ground to rock
            a = band(self.treeline, TREELINE_BAND_M) if self.treeline is not None else mi.Float(0.0)
            open_ = self.open
            if self.rock is not None and self.rockline is not None:
                r = band(self.rockline, ROCK_BAND_M)
                if up is not None:  # steep faces above the treeline: r' = 1 − (1 − r)(1 − a·q)
                    r = 1.0 - (1.0 - r) * (1.0 - a * steep(STEEP_ROCK_DEG))
                open_ = dr.lerp(self.open, self.rock, r)
            m = open_ * dr.fma(a, 1.0 - w[0], w[0]) + self.canopy * ((1.0 - a) * w[1])
        if self.snow is not None and self.snowline is not None:  # snow over it, off faces too steep to hold it
            sigma = band(self.snowline, SNOW_BAND_M)
            if up is not None:
                sigma = sigma * (1.0 - steep(STEEP_SNOW_DEG))
            m = dr.lerp(m, self.snow, sigma)
        xmin, zmin, xmax, zmax = self.extent
        d = dr.maximum(dr.maximum(xmin - p.x, p.x - xmax), dr.maximum(zmin - p.z, p.z - zmax))
        return dr.fma(smooth(d * (1.0 / self.ramp)), m - 1.0, 1.0)


class TerrainMap(NamedTuple):
    """The terrain map: a ``Texture2f`` (RGB, and the water coverage as a fourth channel where there is water)
    over ``extent``, the far landscape's mosaic on the skirt (None: one colour), and the sea on the skirt
    (:class:`SeaMap`; None: none)."""

    texture: Any
    extent: Sequence[float]
    far: FarCoverArrays | None = None
    sea: SeaMap | None = None


def sea_coverage(sea: SeaMap, p: Any, active: Any) -> Any:
    """The sea's coverage W at world ``p`` (:class:`SeaMap`): 0 on the terrain's own extent and off ``active``."""
    import drjit as dr

    from ...terrain import SHORE_RAMP

    xmin, zmin, xmax, zmax = sea.extent
    outside = (p.x < xmin) | (p.x > xmax) | (p.z < zmin) | (p.z > zmax)
    t = dr.clip((p.y - sea.level) * (1.0 / SHORE_RAMP), 0.0, 1.0)
    return dr.select(active & outside, 1.0 - t * t * (3.0 - 2.0 * t), 0.0)


def world_map_texture(mi: Any, data: Any, *, differentiable: bool = False) -> Any:
    """A bilinear, edge-clamped ``Texture2f`` over an (H, W, 3) map (numpy array or ``TensorXf``).

    Its (0, 0) corner is (xmin, zmin) and texel (i, j)'s centre lies at the
    centre of pixel (i, j) of the map convention; see :func:`world_map_uv`.
    ``differentiable``: the tensor may carry gradients (no hardware texture).
    """
    import drjit as dr

    t = data if isinstance(data, mi.TensorXf) else owned(mi.TensorXf, np.asarray(data, dtype=np.float32))
    return mi.Texture2f(
        t,
        use_accel=not differentiable,
        migrate=False,
        filter_mode=dr.FilterMode.Linear,
        wrap_mode=dr.WrapMode.Clamp,
    )


@dataclass(frozen=True)
class RowTints:
    """Per-row colour factors of the trees (row N: 1, the identity row of world-space parts), as flat Floats of
    3 values per row, or None for all 1: ``leaf`` multiplies tinted materials (the tree's colour jitter j_i,
    :meth:`forest.scene.Scene.tree_jitter`), ``bark`` its bark (f_i, :meth:`forest.scene.Scene.bark_tints`)."""

    leaf: Any = None
    bark: Any = None

    @classmethod
    def build(cls, mi: Any, leaf: np.ndarray | None, bark: np.ndarray | None) -> RowTints | None:
        """The tables from (N, 3) arrays (None for all 1), with the identity row appended; None when both are None."""
        if leaf is None and bark is None:
            return None

        def rows(x: np.ndarray | None) -> Any:
            if x is None:
                return None
            out = np.ones((len(x) + 1, 3), np.float32)
            out[:-1] = np.asarray(x, np.float32)
            return owned(mi.Float, out.ravel())

        return cls(rows(leaf), rows(bark))


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
    has_sheen: bool = False  # some leaf has a cuticle lobe (s > 0); else the lobe is not traced at all
    sheen: Any = None  # Float (M,): s
    roughness: Any = None  # Float (M,): α
    sheen_albedo: Any = None  # Float (M·SHEEN_TABLE_SIZE,): E(μi) of each material's lobe (s = 1)
    bark: Any = None  # Bool (M,): a tree's bark, multiplied by the tree's bark factor (RowTints.bark)

    @classmethod
    def build(cls, mi: Any, table: MaterialTable) -> MaterialArrays:
        """``table`` as drjit arrays of ``mi``'s variant; the atlas a linear-filtered, clamped ``Texture2f``."""
        import drjit as dr

        atlas = mi.Texture2f(
            owned(mi.TensorXf, table.atlas.image),
            use_accel=True,
            migrate=False,
            filter_mode=dr.FilterMode.Linear,
            wrap_mode=dr.WrapMode.Clamp,
        )
        rects = table.atlas.rects if len(table.atlas.rects) else np.zeros((1, 4), np.float32)
        sheen = table.sheen if table.sheen is not None else np.zeros(len(table.kind), np.float32)
        rough = table.roughness if table.roughness is not None else np.zeros(len(table.kind), np.float32)
        has_sheen = bool((sheen > 0).any())
        extra: dict[str, Any] = {}
        if has_sheen:
            albedo = np.zeros((len(sheen), SHEEN_TABLE_SIZE), np.float32)
            for i, (s_i, a_i) in enumerate(zip(sheen.tolist(), rough.tolist())):
                if s_i > 0:
                    albedo[i] = _sheen_table_cached(float(a_i))
            extra = dict(
                has_sheen=True,
                sheen=owned(mi.Float, sheen.astype(np.float32)),
                roughness=owned(mi.Float, np.maximum(rough, ROUGHNESS_MIN).astype(np.float32)),
                sheen_albedo=owned(mi.Float, albedo.ravel()),
            )
        return cls(
            kind=owned(mi.UInt32, table.kind),
            colour=owned(mi.Float, table.colour.ravel()),
            tau=owned(mi.Float, table.tau),
            texture=owned(mi.Int32, table.texture),
            cutout=mi.Bool(table.cutout),
            tinted=mi.Bool(table.tinted),
            terrain_map=mi.Bool(table.terrain_map),
            rects=owned(mi.Float, rects.ravel().astype(np.float32)),
            atlas=atlas,
            has_cutouts=bool(table.cutout.any()),
            has_textures=bool((table.texture >= 0).any()),
            tint_row=table.tint_row.copy(),
            bark=mi.Bool(table.bark if table.bark is not None else np.zeros(len(table.kind), bool)),
            **extra,
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
    """What a BSDF needs at a hit: the albedo split into reflection and transmission, and the sampling split.

    With a cuticle lobe (:attr:`MaterialArrays.has_sheen`): its weight s, roughness α, the hit's
    material and the table of E(μi) (see the module docstring); ``sheen`` is None otherwise.
    """

    reflect: Any  # Color3f R (albedo a for surfaces)
    transmit: Any  # Color3f T (0 for surfaces)
    p_reflect: Any  # Float: probability of sampling the reflection lobe
    sheen: Any = None  # Float s (0 off leaves), or None: no lobe anywhere
    alpha: Any = None  # Float GGX α
    material: Any = None  # UInt32: the material (row of ``albedo_table``)
    albedo_table: Any = None  # Float (M·SHEEN_TABLE_SIZE,): E(μi) per material

    def detached(self) -> Shading:
        """The same shading with gradients cut (``dr.detach`` of each field)."""
        import drjit as dr

        return Shading(
            dr.detach(self.reflect),
            dr.detach(self.transmit),
            dr.detach(self.p_reflect),
            self.sheen,
            self.alpha,
            self.material,
            self.albedo_table,
        )


def shading(
    mi: Any,
    mats: MaterialArrays,
    material: Any,
    uv: Any,
    p: Any,
    grid: Any,
    extent: Sequence[float],
    terrain_map: TerrainMap | None,
    active: Any,
    row: Any = None,
    row_tint: RowTints | None = None,
    up: Any = None,
) -> Shading:
    """R, T and the lobe probability at a hit (see the module docstring).

    ``grid`` is a ``Texture2f`` over ``extent`` (xmin, zmin, xmax, zmax) or None;
    ``terrain_map`` a :class:`TerrainMap` or None.  Gradients flow
    from ``grid``'s tensor into R and T.  ``row_tint`` (:class:`RowTints`, or None) holds
    each row's jitter j_r, gathered at the hit's ``row`` for tinted materials, and its bark
    factor f_r, gathered for bark materials.  ``up`` is the shading normal's upward component
    (the far mosaic's rock on steep faces, :meth:`FarCoverArrays.factor`; None: level).
    """
    import drjit as dr

    colour = dr.gather(mi.Color3f, mats.colour, material, active)
    a = mi.Color3f(colour)
    # With water on the terrain map (its fourth channel) ``plain`` follows a without the detail, so that
    # the water's share W of a hit can drop it (module docstring, "Water"); lanes with W = 0 keep a's bits.
    water_map = terrain_map is not None and len(terrain_map[0].shape) == 3 and terrain_map[0].shape[2] > 3
    plain = detail = None
    if mats.has_textures:
        tex = dr.gather(mi.Int32, mats.texture, material, active)
        textured = active & (tex >= 0)
        texel = mats.atlas.eval(mats.tile_uv(mi, tex, uv, textured), active=textured)
        if water_map:
            plain = mi.Color3f(a)
            detail = dr.select(textured, mi.Color3f(texel[0], texel[1], texel[2]), mi.Color3f(1.0))
        a = dr.select(textured, a * mi.Color3f(texel[0], texel[1], texel[2]), a)
    xmin, zmin, xmax, zmax = extent
    pos = mi.Point2f((p.x - xmin) * (1.0 / (xmax - xmin)), (p.z - zmin) * (1.0 / (zmax - zmin)))
    if grid is not None:
        tinted = dr.gather(mi.Bool, mats.tinted, material, active) & active
        g = mi.Color3f(*grid.eval(pos, active=tinted)[:3])
        a = dr.select(tinted, a * g, a)
        plain = None if plain is None else dr.select(tinted, plain * g, plain)
    if row_tint is not None and row is not None and row_tint.leaf is not None:
        jittered = dr.gather(mi.Bool, mats.tinted, material, active) & active
        j = dr.gather(mi.Color3f, row_tint.leaf, row, jittered)
        a = dr.select(jittered, a * j, a)
        plain = None if plain is None else dr.select(jittered, plain * j, plain)
    if row_tint is not None and row is not None and row_tint.bark is not None:
        barked = dr.gather(mi.Bool, mats.bark, material, active) & active
        a = dr.select(barked, a * dr.gather(mi.Color3f, row_tint.bark, row, barked), a)
    if terrain_map is not None:
        tmap, (txmin, tzmin, txmax, tzmax) = terrain_map.texture, terrain_map.extent
        tpos = mi.Point2f((p.x - txmin) * (1.0 / (txmax - txmin)), (p.z - tzmin) * (1.0 / (tzmax - tzmin)))
        mapped = dr.gather(mi.Bool, mats.terrain_map, material, active) & active
        t = tmap.eval(tpos, active=mapped)
        ground = mi.Color3f(t[0], t[1], t[2])
        if terrain_map.far is not None:  # woods and open ground on the skirt (forest.far_cover)
            ground = ground * terrain_map.far.factor(mi, p, mapped, up)
        sea = None
        if terrain_map.sea is not None:  # the water past the terrain's edge, by height (SeaMap)
            sea = sea_coverage(terrain_map.sea, p, mapped)
            ground = dr.lerp(ground, mi.Color3f(*terrain_map.sea.colour), sea)
        a = dr.select(mapped, a * ground, a)
        if plain is not None and detail is not None:
            w = dr.select(mapped, dr.clip(t[3], 0.0, 1.0), 0.0)
            if sea is not None:
                w = dr.maximum(w, sea)
            wet = dr.select(mapped, plain * ground, plain) * dr.fma(1.0 - detail, w, detail)
            a = dr.select(w > 0.0, wet, a)  # (1 − W)·detail + W in place of the detail
    leaf = dr.gather(mi.UInt32, mats.kind, material, active) == KIND_LEAF
    tau = dr.gather(mi.Float, mats.tau, material, active)
    R = a * (1.0 - tau)
    T = a * tau
    mr = dr.detach(R[0] + R[1] + R[2])
    mt = dr.detach(T[0] + T[1] + T[2])
    p_r = dr.select(leaf & (mr + mt > 0), mr / dr.maximum(mr + mt, 1e-12), 1.0)
    if not mats.has_sheen:
        return Shading(reflect=R, transmit=T, p_reflect=p_r)
    return Shading(
        reflect=R,
        transmit=T,
        p_reflect=p_r,
        sheen=dr.gather(mi.Float, mats.sheen, material, active),
        alpha=dr.gather(mi.Float, mats.roughness, material, active),
        material=mi.UInt32(material),
        albedo_table=mats.sheen_albedo,
    )


def _sheen_terms(sh: Shading, n: Any, wi: Any) -> tuple[Any, Any, Any]:
    """(μi, s·E(μi), p_s): the lobe's albedo at this incidence and its sampling probability."""
    import drjit as dr

    mu_i = dr.clip(dr.dot(n, wi), 1e-4, 1.0)
    last = SHEEN_TABLE_SIZE - 1
    x = mu_i * last
    k = dr.minimum(dr.floor(x), last - 1)
    t = x - k
    base = sh.material * SHEEN_TABLE_SIZE + type(sh.material)(k)
    e0 = dr.gather(type(mu_i), sh.albedo_table, base)
    e1 = dr.gather(type(mu_i), sh.albedo_table, base + 1)
    se = sh.sheen * dr.lerp(e0, e1, t)
    a = dr.detach(sh.reflect + sh.transmit)
    abar = (a[0] + a[1] + a[2]) * (1.0 / 3.0) * (1.0 - se)
    p_s = dr.select(se > 0.0, se / dr.maximum(se + abar, 1e-12), 0.0)
    return mu_i, se, p_s


def _ggx_reflection(sh: Shading, n: Any, wi: Any, wo: Any, mu_i: Any) -> tuple[Any, Any]:
    """(s·F·D·G₂/(4 μi), pdf of the visible-normal sample G₁·D/(4 μi)) for ωo on ωi's side, else (0, 0)."""
    import drjit as dr

    mu_o = dr.dot(n, wo)
    h = dr.normalize(wi + wo)
    nh = dr.dot(n, h)
    ih = dr.clip(dr.dot(wi, h), 0.0, 1.0)
    a2 = dr.square(sh.alpha)
    d = a2 / (dr.pi * dr.square(dr.fma(dr.square(nh), a2 - 1.0, 1.0)))
    lam_i = _ggx_lambda(sh.alpha, mu_i, dr.sqrt)
    lam_o = _ggx_lambda(sh.alpha, dr.maximum(mu_o, 1e-6), dr.sqrt)
    f = CUTICLE_F0 + (1.0 - CUTICLE_F0) * dr.power(1.0 - ih, 5.0)
    quarter = 0.25 / mu_i
    ok = (mu_o > 0.0) & (nh > 0.0) & (sh.sheen > 0.0)
    value = dr.select(ok, sh.sheen * f * d * quarter / (1.0 + lam_i + lam_o), 0.0)
    pdf = dr.select(ok, d * quarter / (1.0 + lam_i), 0.0)
    return value, pdf


def _vndf_sample(mi: Any, wi: Any, alpha: Any, u: Any) -> Any:
    """A GGX micro-normal from the distribution of normals visible from ``wi`` (local frame; Heitz 2018)."""
    import drjit as dr

    vh = dr.normalize(mi.Vector3f(alpha * wi.x, alpha * wi.y, wi.z))
    lensq = dr.square(vh.x) + dr.square(vh.y)
    inv = dr.rsqrt(dr.maximum(lensq, 1e-20))
    t1 = dr.select(lensq > 0.0, mi.Vector3f(-vh.y * inv, vh.x * inv, 0.0), mi.Vector3f(1.0, 0.0, 0.0))
    t2 = dr.cross(vh, t1)
    r = dr.sqrt(u.x)
    sin_phi, cos_phi = dr.sincos(2.0 * dr.pi * u.y)
    p1 = r * cos_phi
    s = 0.5 * (1.0 + vh.z)
    p2 = (1.0 - s) * dr.safe_sqrt(1.0 - dr.square(p1)) + s * (r * sin_phi)
    p3 = dr.safe_sqrt(1.0 - dr.square(p1) - dr.square(p2))
    nh = t1 * p1 + t2 * p2 + vh * p3
    return dr.normalize(mi.Vector3f(alpha * nh.x, alpha * nh.y, dr.maximum(nh.z, 1e-6)))


def bsdf_eval(sh: Shading, n: Any, wo: Any, wi: Any = None) -> tuple[Any, Any]:
    """(f·|cos θo|, pdf) of direction ``wo`` (world) with shading normal ``n`` (already facing ωi).

    ``wi`` (world, towards the viewer) is needed only by the cuticle lobe (``sh.sheen`` not None).
    """
    import drjit as dr

    cos_o = dr.dot(n, wo)
    same = cos_o > 0.0
    c = dr.abs(cos_o) * dr.inv_pi
    value = dr.select(same, sh.reflect, sh.transmit) * c
    pdf = dr.select(same, sh.p_reflect, 1.0 - sh.p_reflect) * c
    if sh.sheen is None:
        return value, pdf
    if wi is None:
        raise ValueError("bsdf_eval: a shading with a cuticle lobe needs wi")
    mu_i, se, p_s = _sheen_terms(sh, n, wi)
    spec, pdf_s = _ggx_reflection(sh, n, wi, wo, mu_i)
    return value * (1.0 - se) + spec, dr.lerp(pdf, pdf_s, p_s)


def bsdf_sample(mi: Any, sh: Shading, frame: Any, u1: Any, u2: Any, wi: Any = None) -> tuple[Any, Any, Any]:
    """Sample ωo: (direction (world), weight f·|cos|/pdf, pdf).  ``frame``'s normal faces ωi.

    With a cuticle lobe (``wi`` given, world), ``u1`` first picks the specular lobe with probability
    p_s and is then rescaled to pick reflection or transmission; pdf and weight are the mixture's.
    """
    import drjit as dr

    if sh.sheen is not None:
        if wi is None:
            raise ValueError("bsdf_sample: a shading with a cuticle lobe needs wi")
        _, _, p_s = _sheen_terms(sh, frame.n, wi)
        spec = u1 < p_s
        u1 = dr.select(spec, u1, (u1 - p_s) / dr.maximum(1.0 - p_s, 1e-12))
    reflect = u1 < sh.p_reflect
    local = mi.warp.square_to_cosine_hemisphere(u2)
    local = mi.Vector3f(local.x, local.y, dr.select(reflect, local.z, -local.z))
    if sh.sheen is not None:
        wi_l = frame.to_local(wi)
        wi_l = mi.Vector3f(wi_l.x, wi_l.y, dr.maximum(wi_l.z, 1e-4))
        m = _vndf_sample(mi, wi_l, sh.alpha, u2)
        local = dr.select(spec, 2.0 * dr.dot(wi_l, m) * m - wi_l, local)
        wo = frame.to_world(local)
        value, pdf = bsdf_eval(sh, frame.n, wo, wi)
        # A micro-normal that reflects ωi below the leaf gives no sample (its probability is lost, not moved).
        ok = (pdf > 0.0) & ~(spec & (local.z <= 0.0))
        weight = dr.select(ok, value / dr.maximum(pdf, 1e-30), 0.0)
        return wo, weight, dr.select(ok, pdf, 0.0)
    wo = frame.to_world(local)
    cos_pdf = dr.abs(local.z) * dr.inv_pi
    p_lobe = dr.select(reflect, sh.p_reflect, 1.0 - sh.p_reflect)
    pdf = p_lobe * cos_pdf
    weight = dr.select(reflect, sh.reflect, sh.transmit) / dr.maximum(p_lobe, 1e-12)
    weight = dr.select(pdf > 0.0, weight, 0.0)
    return wo, weight, pdf


# -- water: the ground's Fresnel mirror (rules of material ``water``, forest.ground) ------------------------

#: The ripples' plane waves: (wavelength in metres, direction in degrees from +X towards +Z, phase in radians).
#: Eight wavelengths spaced evenly in log from 0.37 to 3.7 m, their directions spread over the half circle by
#: the golden angle (no two within 20°), so their crests do not line up into a regular pattern.
RIPPLE_WAVES = (
    (0.37, 161.0, 0.3),
    (0.51, 22.5, 2.1),
    (0.71, 63.7, 4.4),
    (0.98, 104.9, 1.2),
    (1.35, 146.2, 5.6),
    (1.87, 7.4, 3.3),
    (2.67, 48.6, 0.9),
    (3.70, 89.8, 2.7),
)
#: The wind's patches over the water ("cat's paws"): plane waves of tens of metres whose sum g sets where the
#: ripples are (the slope scaled by m = max(g + :data:`PATCH_OFFSET`, 0) + :data:`PATCH_FLOOR`, normalised to
#: a mean square of 1), so a calm lake shows glassy stretches that mirror the shore between rippled ones.
PATCH_WAVES = ((37.0, 31.0, 0.7), (61.0, 118.0, 2.9), (97.0, 77.0, 5.1))
PATCH_OFFSET = 0.25
PATCH_FLOOR = 0.08


def _patch_field(x: np.ndarray, z: np.ndarray) -> np.ndarray:
    """g(x, z) = the mean of :data:`PATCH_WAVES`' sines (numpy, for the normalisation)."""
    g = np.zeros(np.broadcast(x, z).shape)
    for wavelength, direction, phase in PATCH_WAVES:
        d = np.radians(direction)
        g += np.sin(2.0 * np.pi / wavelength * (x * np.cos(d) + z * np.sin(d)) + phase)
    return g / len(PATCH_WAVES)


@lru_cache(maxsize=1)
def patch_norm() -> float:
    """N = 1 / √E[m²] of the patches' raw weight over a 2 km square (so the mean square tilt is the one asked);
    computed once, on the first traced water hit, not at import."""
    t = np.linspace(-1000.0, 1000.0, 1201)
    m = np.maximum(_patch_field(t[:, None], t[None, :]) + PATCH_OFFSET, 0.0) + PATCH_FLOOR
    return float(1.0 / np.sqrt(np.mean(m * m)))


@dataclass
class WaterLobe:
    """A terrain hit's water surface: the diffuse part and the mirror (see :func:`water_lobe`)."""

    shading: Shading  # the diffuse part: R·(1 − W·F), and p_reflect = 1 − p for water lanes
    p: Any  # Float: probability of sampling the mirror (0 off water)
    weight: Any  # Float: W·F / p, the mirror sample's weight (grey)
    wo: Any  # Vector3f: the mirror direction (world)
    keep: Any  # Float: 1 − W·F, the factor on the diffuse part (path replay re-applies it)


def water_coverage(mi: Any, mats: MaterialArrays, material: Any, p: Any, terrain_map: TerrainMap, active: Any) -> Any:
    """The water coverage W ∈ [0, 1] at a hit: the terrain map's fourth channel at its world X/Z (0 off the terrain),
    or the sea's on the skirt where that is more (:func:`sea_coverage`)."""
    import drjit as dr

    tmap, (txmin, tzmin, txmax, tzmax) = terrain_map.texture, terrain_map.extent
    tpos = mi.Point2f((p.x - txmin) * (1.0 / (txmax - txmin)), (p.z - tzmin) * (1.0 / (tzmax - tzmin)))
    mapped = dr.gather(mi.Bool, mats.terrain_map, material, active) & active
    t = tmap.eval(tpos, active=mapped)
    w = dr.select(mapped, dr.clip(t[3], 0.0, 1.0), 0.0)
    return w if terrain_map.sea is None else dr.maximum(w, sea_coverage(terrain_map.sea, p, mapped))


def ripple_normal(mi: Any, p: Any, ripple_deg: float) -> Any:
    """The water's normal at world ``p``: level (+Y) tilted by ripples, a sum of :data:`RIPPLE_WAVES` in patches.

    h(x, z) = m(x, z) Σ_k A_k sin(2π d_k·(x, z)/λ_k + φ_k) with every wave of the same slope amplitude
    s = tan(ripple)·√(2/K), so that E|∇h|² = K s²/2 = tan² ripple where m = 1; the wind's patch weight
    m = N·(max(g + :data:`PATCH_OFFSET`, 0) + :data:`PATCH_FLOOR`), g the mean of :data:`PATCH_WAVES`' sines and
    N = :func:`patch_norm` making E[m²] = 1, so the RMS tilt over the water is the one asked while some
    stretches are glassy and others rippled (m is tens of metres across, so ∇m is neglected).  The normal is
    (−∂h/∂x, 1, −∂h/∂z) normalised.  A fixed function of position: deterministic and free of noise
    textures (a cheap stand-in for a wave spectrum; Tessendorf 2001, "Simulating ocean water").
    """
    import drjit as dr

    if ripple_deg <= 0.0:
        return mi.Vector3f(0.0, 1.0, 0.0)
    g = mi.Float(0.0)
    for wavelength, direction, phase in PATCH_WAVES:
        k = 2.0 * np.pi / wavelength
        dx, dz = float(np.cos(np.radians(direction))), float(np.sin(np.radians(direction)))
        g += dr.sin(dr.fma(p.x, k * dx, dr.fma(p.z, k * dz, phase)))
    m = (dr.maximum(g * (1.0 / len(PATCH_WAVES)) + PATCH_OFFSET, 0.0) + PATCH_FLOOR) * patch_norm()
    s = m * float(np.tan(np.radians(ripple_deg)) * np.sqrt(2.0 / len(RIPPLE_WAVES)))
    gx = mi.Float(0.0)
    gz = mi.Float(0.0)
    for wavelength, direction, phase in RIPPLE_WAVES:
        k = 2.0 * np.pi / wavelength
        dx, dz = float(np.cos(np.radians(direction))), float(np.sin(np.radians(direction)))
        c = dr.cos(dr.fma(p.x, k * dx, dr.fma(p.z, k * dz, phase))) * s
        gx = dr.fma(c, dx, gx)
        gz = dr.fma(c, dz, gz)
    return dr.normalize(mi.Vector3f(-gx, 1.0, -gz))


def water_lobe(mi: Any, sh: Shading, water: Any, p: Any, wi: Any, ng: Any, ripple_deg: float) -> WaterLobe:
    """The water at a terrain hit of coverage W = ``water``: a delta mirror over the (dimmed) diffuse ground.

    With n_w the water's normal (:func:`ripple_normal`, level when the rippled mirror would leave below
    the geometric normal ``ng``, which faces ωi), μ = ωi·n_w and F(μ) the exact Fresnel reflectance of
    a smooth dielectric of n = :data:`WATER_IOR` (unpolarised; Born & Wolf §1.5; F(1) = 0.020), the
    vertex's BSDF is the mixture

        f(ωi, ωo) = W·F(μ)·δ(ωo − r)/|ωo·n_w| + (1 − W·F(μ))·R/π,    r = 2μ n_w − ωi,

    R the painted albedo (for water, the bed seen through it: :data:`forest.config.schema.GROUND_MATERIALS`'s
    ``water``, its Beer–Lambert tint included).  The share 1 − F that enters the water reaches the bed and
    comes back as that diffuse colour; keeping the whole diffuse term under 1 − W·F is exact where W is 0
    or 1 and conserves energy between (W·F + (1 − W·F)·R ≤ 1).  Sampling: the mirror with probability
    p = W·F / (W·F + (1 − W·F)·mean R), weight W·F/p, no light sampling on it (a delta lobe, as
    Mitsuba's ``dielectric``: the sun's glint comes from the reflected ray meeting the sun); else the
    diffuse part with pdf (1 − p)·cos/π, which is also the pdf next-event estimation weighs against.
    Lanes with W = 0 are left exactly as they were.
    """
    import dataclasses

    import drjit as dr

    up = mi.Vector3f(0.0, 1.0, 0.0)
    n_r = ripple_normal(mi, p, ripple_deg)
    mu_r = dr.dot(wi, n_r)
    r_r = dr.fma(n_r, 2.0 * mu_r, -wi)
    mu_f = wi.y
    r_f = mi.Vector3f(-wi.x, wi.y, -wi.z)
    rippled = (mu_r > 0.0) & (dr.dot(r_r, ng) > 0.0)
    mu = dr.select(rippled, mu_r, mu_f)
    wo = dr.select(rippled, r_r, r_f)
    on = (water > 0.0) & (mu > 0.0) & (dr.dot(wo, ng) > 0.0) & (dr.dot(wo, up) > 0.0)
    f_r = mi.fresnel(dr.clip(mu, 1e-6, 1.0), WATER_IOR)[0]
    s = dr.select(on, water * f_r, 0.0)
    keep = 1.0 - s
    diffuse = sh.reflect * keep
    d = dr.detach(diffuse)
    abar = (d[0] + d[1] + d[2]) * (1.0 / 3.0)
    p_m = dr.select(on, s / dr.maximum(s + abar, 1e-12), 0.0)
    weight = dr.select(on, s + abar, 0.0)
    shading_d = dataclasses.replace(sh, reflect=diffuse, p_reflect=dr.select(on, 1.0 - p_m, sh.p_reflect))
    return WaterLobe(shading_d, p_m, weight, wo, dr.detach(keep))
