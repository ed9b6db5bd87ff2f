"""Terrain materials: the ground's linear albedo over the terrain, from rules by slope, altitude, moisture, canopy and maps.

:func:`terrain_albedo` gives the Scene's :class:`TerrainAlbedo`: an ``(H, W, 3)``
grid of linear sRGB albedo laid over the terrain's X/Z extent (the map
convention: column → +X, row → +Z, row 0 at the smallest Z, texel (i, j)
covering ``x ∈ xmin + [j, j+1]·Δx``, ``z ∈ zmin + [i, i+1]·Δz``), plus a
tileable detail factor (mean 1 per channel) repeated every ``detail_tile_m``
metres.  A renderer's ground albedo at a hit (x, z) is :meth:`TerrainAlbedo.at`:

    ρ(x, z) = bilinear(rgb; x, z) ⊙ bilinear_wrapped(detail; x / tile, z / tile)

Where the albedo comes from, first match wins:

1. ``[render] terrain_texture`` — the image (sRGB decoded), as the map convention lays it, without
   the detail texture (:func:`read_terrain_texture`, the one reader of that setting);
2. ``[render] terrain_colour`` given in the file — one material of that colour;
3. ``[ground]`` — ``base`` everywhere, then every rule painted over it in order
   (the default rules when none are given, :data:`DEFAULT_RULES`).

**Rules.**  Rule r paints its material's albedo c_r over what lies beneath with
coverage α_r ∈ [0, 1] (a layer stack, as terrain splat maps are blended):

    ρ ← (1 − α_r)·ρ + α_r·c_r,    α_r = opacity · Π_v w_v(v(x)) · map(x)

over the windows it gives, each a trapezoid membership (0 below lo0, a
smoothstep s(t) = t²(3 − 2t) up to 1 at lo1, 1 until hi1, down to 0 at hi0);
``[lo, hi]`` is the trapezoid with a default ramp width (:data:`RAMP`) centred
on each edge, and an edge at the end of a variable's range (slope 0 or 90°,
moisture or canopy 0 or 1) is no edge at all.  The variables, per texel
centre:

* ``slope`` θ = arctan |∇h| in degrees, from central differences of the
  terrain's height h sampled at the texel centres (so the slope of the texel's
  neighbourhood, not of one triangle);
* ``altitude`` h in metres;
* ``moisture`` — ``[maps] moisture`` (grey, bilinear), else
  :func:`forest.maps.terrain_moisture` (low and flat ground is wet);
* ``canopy`` — the tree crowns' cover c = 1 − exp(−D), D the crowns' area per
  ground area around the texel: each tree (not ground cover) contributes its
  crown disc π(s·R)² (R the half width of its species' highest level, s its
  scale) to its texel, blurred by a Gaussian of the mean crown radius.  This is
  the gap fraction of crowns placed at random (a Boolean model: Nilson 1971,
  "A theoretical analysis of the frequency of gaps in plant stands",
  Agricultural Meteorology 8: 25–38), so c = 0.63 where crowns cover the
  ground once over.
* ``relief`` — the height in metres above the lowest ground within ``[ground] relief_radius``
  metres, h − min_{|y − x| ≤ r} h(y) (a square window of the texel grid; a local form of the
  "height above the nearest drainage", Rennó et al. 2008, Remote Sens. Environ. 112: 3469–3481):
  on a valley's floor it is the floor's fall over r (the lowest ground lies downstream), small
  against the sides' rise, so ``relief = [0, 3]`` finds a river's bed along a falling valley where
  no one altitude window does;
* ``map`` — a grey image (map convention, bilinear), or 1 − grey with ``invert``.

Edges are broken up by noise: each variable is offset by ``noise · n(x) · w``
before its window is applied, with w the window's ramp width and n a
unit-variance Gaussian field of correlation length ``noise_scale`` metres (two
octaves of spectrally filtered noise, :func:`forest.library.textures.periodic_noise`),
seeded by the scene's seed and the rule's index.  Same config, same trees ⇒
the same grid, bit for bit.

**Water.**  Rules of the material ``water`` (:data:`~forest.config.schema.WATER_MATERIAL`) paint
its colour like any other, and also a water coverage W ∈ [0, 1] per texel, composited the same way:

    W ← (1 − α_r)·W + α_r·[material_r = water]

so W is the share of the texel's albedo that came from water layers (None when no rule paints
water, and then nothing changes anywhere).  forest_path shades that share as a Fresnel mirror
over the painted colour (:mod:`forest.render.path.materials`, :func:`~forest.render.path.materials.water_lobe`),
without the detail texture on that share (the bed under water shows no soil grain); the other
renderers and the exports keep the painted colour alone.  ``[terrain] water`` (a lake or the sea at one
level, :func:`forest.terrain.flood`) is painted the same way as the top layer, whatever the source of the
albedo (:func:`paint_still_water`).

**Shallow water.**  Water shows its bed where it is shallow and its own colour where it is deep. The
colour painted for water at depth H is the irradiance reflectance of a shallow water column over a bed
(Maritorena, Morel & Gentili 1994, "Diffuse reflectance of oceanic shallow waters: influence of water
depth and bottom albedo", *Limnol. Oceanogr.* 39: 1689, eq. 9):

    R(H) = R_∞ + (A − R_∞)·exp(−2 K H)

with R_∞ the ``water`` material's colour (the deep water's), A the bed — the ground painted under the
water: the layers below a water rule, or everything under ``[terrain] water`` — and K
``[ground] water_attenuation`` (per metre, RGB; light goes down to the bed and back up, hence 2H).
A lake's or the sea's depth is exact, the level less the unflooded terrain's height
(:meth:`forest.terrain.Terrain.water_depth`); a painted river has no bed of its own, so its bed falls from
the water's edge at :data:`~forest.config.schema.BANK_GRADIENT` metres per metre to at most
``[ground] water_depth`` (H = min(D, g·δ), δ the distance from the texel to the nearest texel that is not
water, less half a texel: a Euclidean distance transform of W ≥ ½). So the shore is the bed's colour
running into the water, which darkens toward its middle, where the water had met the bank as one flat
colour. Composited like the coverage, the water's share of a texel is Σ_r w_r R(H, A_r) over the water
layers r with weights w_r, which is R_∞·W + e^{−2KH}·(B − R_∞·W) with B = Σ_r w_r A_r accumulated as W is
(B ← (1 − α_r)·B + α_r·[material_r = water]·A_r): one more (H, W, 3) grid while painting.

**Variation.**  A material painted one colour reads, from tens of metres away, as a flat sheet: real
ground varies in patches — thicker and thinner grass, drier and greener, more and less litter — which
the detail texture (a few metres across) averages away at a distance.  So the painted grid is varied,
for every material but water, by a lognormal factor in luminance and a warm–cool shift:

    ρ ← ρ ⊙ exp(σ n₁ − σ²/2) ⊙ (exp(σ n₂ − σ²/2), 1, exp(−σ n₂ − σ²/2))

n₁ and n₂ independent unit Gaussian fields of correlation length ``variation_scale`` (the edges' noise,
seeded apart), σ = ``variation``; E[exp(σn − σ²/2)] = 1, so every material keeps its mean albedo.  The
default σ = 0.12 follows a photographed meadow (``tests/fixtures/photos/autumn_larch_hillside.jpg``:
its field's 16- and 8-pixel blocks vary by 0.078–0.097 in log luminance and 0.093–0.142 in log
red/green, lighting included; ``bench/bench_ground.py`` prints them beside the grid's).

Built-in materials and their sources: :data:`forest.config.schema.GROUND_MATERIALS`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .config import Config
from .config.schema import BANK_GRADIENT, WATER_MATERIAL, GroundConfig, GroundRule
from .errors import ConfigError, ForestError
from .instances import InstanceSet
from .library import Species
from .maps import sample_bilinear, terrain_moisture
from .terrain import Terrain

TAG = 0x6A0D
#: Noise indices of the macro variation's two fields (after any rule's own index).
VARIATION_INDEX = 1 << 20
#: Default ramp width of a ``[lo, hi]`` window's edges, per variable (altitude: a share of the height range).
RAMP = {"slope": 6.0, "altitude": 0.05, "moisture": 0.1, "canopy": 0.15, "relief": 1.0}
#: Where each variable's range ends: a window edge at or beyond these is no edge.
RANGE = {
    "slope": (0.0, 90.0),
    "altitude": (-np.inf, np.inf),
    "moisture": (0.0, 1.0),
    "canopy": (0.0, 1.0),
    "relief": (0.0, np.inf),
}
MESH_RESOLUTION = 512
NOISE_TEXELS = 6  # texels per correlation length of the edge noise's finer octave (see edge_noise)  # mesh terrains: heights come from ray casts, so the grid is capped at this side

#: The rules of a ``[ground]`` that gives none (landscape defaults): green grass on gentle open ground,
#: straw-dry grass where that ground is dry (high, or sloping: :func:`forest.maps.terrain_moisture`),
#: leaf litter under the crowns, rock on the steepest slopes; bare soil shows between.
DEFAULT_RULES: tuple[dict, ...] = (
    {"material": "grass", "slope": [0.0, 0.0, 24.0, 34.0], "canopy": [0.0, 0.0, 0.35, 0.75], "noise_scale": 40.0},
    {
        "material": "dry_grass",
        "slope": [0.0, 0.0, 28.0, 38.0],
        "moisture": [0.0, 0.0, 0.3, 0.5],
        "canopy": [0.0, 0.0, 0.35, 0.75],
        "noise_scale": 60.0,
    },
    {"material": "litter", "canopy": [0.3, 0.7, 1.0, 1.0], "noise": 0.4},
    {"material": "rock", "slope": [30.0, 42.0, 90.0, 90.0], "noise": 1.0, "noise_scale": 15.0},
)


@dataclass(frozen=True)
class TerrainAlbedo:
    """The ground's albedo: ``rgb`` (H, W, 3) linear over ``extent`` (map convention) × a tileable ``detail``.

    ``detail`` (h, w, 3) float32 has mean 1 per channel and repeats every
    ``detail_tile_m`` metres along X and Z from the world origin (texel (i, j)
    of a tile covers ``x/tile ∈ [j, j+1]/w``, ``z/tile ∈ [i, i+1]/h`` modulo 1);
    None (and a tile of 0) without detail.  ``water`` (H, W) float32 is the water coverage W
    over the same texels (module docstring), None where no rule paints water.
    """

    rgb: np.ndarray
    extent: tuple[float, float, float, float]  # xmin, zmin, xmax, zmax
    detail: np.ndarray | None = None
    detail_tile_m: float = 0.0
    water: np.ndarray | None = None
    #: The far landscape's albedo ρ_far (3,) that the ground skirt fades to (:func:`forest.skirt.horizon_albedo`
    #: sets it on the Scene's albedo); None: the grid's mean.
    far: tuple[float, float, float] | None = None
    #: The far landscape's wooded land behind ``far``: its albedo ρ_w (crowns over their gaps) and its share w̄ of
    #: the land (None and 0 without trees; :func:`forest.skirt.landscape`): the woods and open ground of the
    #: skirt's mosaic (:mod:`forest.far_cover`), the open ground taking the rest of ``far``.
    far_canopy: tuple[float, float, float] | None = None
    far_cover: float = 0.0
    #: The canopy's height behind ``far_canopy``, metres (0 without trees): the woods' relief on the skirt.
    far_height: float = 0.0

    def water_at(self, x: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Water coverage W at world (x, z): the ``water`` grid bilinear, clamped at the edges (0 without water)."""
        x = np.asarray(x, np.float64)
        if self.water is None:
            return np.zeros(x.shape, np.float32)
        xmin, zmin, xmax, zmax = self.extent
        u = (x - xmin) / max(xmax - xmin, 1e-12)
        v = (np.asarray(z, np.float64) - zmin) / max(zmax - zmin, 1e-12)
        return np.asarray(sample_bilinear(self.water, u, v), np.float32)

    def at(self, x: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Albedo at world (x, z): the grid bilinear (clamped at the edges) × the detail bilinear (wrapped)."""
        xmin, zmin, xmax, zmax = self.extent
        x = np.asarray(x, np.float64)
        z = np.asarray(z, np.float64)
        u = (x - xmin) / max(xmax - xmin, 1e-12)
        v = (z - zmin) / max(zmax - zmin, 1e-12)
        rgb = np.asarray(sample_bilinear(self.rgb, u, v), np.float64)
        if self.detail is not None and self.detail_tile_m > 0:
            rgb = rgb * wrapped_bilinear(self.detail, x / self.detail_tile_m, z / self.detail_tile_m)
        return rgb.astype(np.float32)


def wrapped_bilinear(img: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Bilinear lookup of a tile at (u, v) modulo 1 (texel centres at (k + ½)/n), wrapping across the seams."""
    h, w = img.shape[:2]
    r = np.mod(np.asarray(v, np.float64), 1.0) * h - 0.5
    c = np.mod(np.asarray(u, np.float64), 1.0) * w - 0.5
    i0 = np.floor(r).astype(np.int64)
    j0 = np.floor(c).astype(np.int64)
    tr = (r - i0)[:, None]
    tc = (c - j0)[:, None]
    i0, j0 = i0 % h, j0 % w
    i1, j1 = (i0 + 1) % h, (j0 + 1) % w
    top = img[i0, j0] * (1 - tc) + img[i0, j1] * tc
    bot = img[i1, j0] * (1 - tc) + img[i1, j1] * tc
    return np.asarray(top * (1 - tr) + bot * tr, np.float64)


def grid_shape(extent: tuple[float, float, float, float], resolution: int) -> tuple[int, int]:
    """(rows along Z, columns along X) with ``resolution`` texels along the longer side, square-ish texels."""
    xmin, zmin, xmax, zmax = extent
    sx, sz = max(xmax - xmin, 1e-9), max(zmax - zmin, 1e-9)
    if sx >= sz:
        return max(2, round(resolution * sz / sx)), resolution
    return resolution, max(2, round(resolution * sx / sz))


def texel_centres(extent: tuple[float, float, float, float], shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """World X and Z ``(H, W)`` of every texel centre (map convention)."""
    xmin, zmin, xmax, zmax = extent
    h, w = shape
    x = xmin + (np.arange(w) + 0.5) * (xmax - xmin) / w
    z = zmin + (np.arange(h) + 0.5) * (zmax - zmin) / h
    return np.meshgrid(x, z)


def smoothstep(t: np.ndarray) -> np.ndarray:
    """s(t) = t²(3 − 2t) on t clipped to [0, 1]."""
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def ramp_points(window: Sequence[float], variable: str, unit: float) -> tuple[float, float, float, float]:
    """A window as its trapezoid (lo0, lo1, hi1, hi0); ``unit`` scales the default ramp (altitude: the height range)."""
    if len(window) == 4:
        a, b, c, d = (float(x) for x in window)
        return a, b, c, d
    lo, hi = (float(x) for x in window)
    half = 0.5 * RAMP[variable] * unit
    return lo - half, lo + half, hi - half, hi + half


def membership(x: np.ndarray, trapezoid: tuple[float, float, float, float], variable: str) -> np.ndarray:
    """The trapezoid's membership of ``x`` in [0, 1]; edges at the end of the variable's range are dropped."""
    a, b, c, d = trapezoid
    lo_end, hi_end = RANGE[variable]
    w = np.ones_like(x)
    if 0.5 * (a + b) > lo_end:
        w *= smoothstep((x - a) / (b - a)) if b > a else (x >= a).astype(x.dtype)
    if 0.5 * (c + d) < hi_end:
        w *= 1.0 - (smoothstep((x - c) / (d - c)) if d > c else (x > c).astype(x.dtype))
    return w


def edge_noise(
    shape: tuple[int, int], extent: tuple[float, float, float, float], scale_m: float, seed: int, index: int
) -> np.ndarray:
    """A unit-variance Gaussian field ``(H, W)`` with correlation length ``scale_m`` metres (two octaves).

    The field is synthesised on a square grid of n ≤ max(H, W) texels with at least
    :data:`NOISE_TEXELS` texels per correlation length of its finer octave (ℓ/3), then
    interpolated bilinearly (periodically) onto the albedo grid: a smooth field needs no
    more texels than that, and a 1024² grid's edges cost a tenth of the transforms.
    """
    from scipy.ndimage import zoom

    from .library.textures import periodic_noise

    xmin, zmin, xmax, zmax = extent
    side = max(xmax - xmin, zmax - zmin, 1e-9)
    full = max(shape)
    n = int(min(full, max(32, np.ceil(NOISE_TEXELS * side / max(scale_m / 3.0, 1e-9)))))
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([seed, TAG, index])))
    s = min(scale_m / side, 0.5)
    f = periodic_noise(n, rng, s, s) + 0.5 * periodic_noise(n, rng, s / 3.0, s / 3.0)
    if n < full:
        f = zoom(f, full / n, order=1, mode="grid-wrap", grid_mode=True)
    f = f[: shape[0], : shape[1]]
    return (f - f.mean()) / max(float(f.std()), 1e-12)


def terrain_slope(height: np.ndarray, extent: tuple[float, float, float, float]) -> np.ndarray:
    """Slope θ = arctan |∇h| in degrees of a height grid over ``extent`` (central differences)."""
    xmin, zmin, xmax, zmax = extent
    h, w = height.shape
    dz = (zmax - zmin) / h
    dx = (xmax - xmin) / w
    gz, gx = np.gradient(height, dz, dx)
    return np.degrees(np.arctan(np.hypot(gx, gz)))


def terrain_relief(height: np.ndarray, extent: tuple[float, float, float, float], radius_m: float) -> np.ndarray:
    """Height above the lowest ground within ``radius_m`` (module docstring): h − min filter of h (edges clamped)."""
    from scipy.ndimage import minimum_filter

    xmin, zmin, xmax, zmax = extent
    h, w = height.shape
    ri = max(1, round(radius_m / max((zmax - zmin) / h, 1e-12)))
    rj = max(1, round(radius_m / max((xmax - xmin) / w, 1e-12)))
    return height - minimum_filter(height, size=(2 * ri + 1, 2 * rj + 1), mode="nearest")


def canopy_cover(
    instances: InstanceSet,
    crown_radius: np.ndarray,
    tree_species: int,
    extent: tuple[float, float, float, float],
    shape: tuple[int, int],
) -> np.ndarray:
    """Crown cover c = 1 − exp(−D) per texel (module docstring); ``crown_radius`` (S,) per species at scale 1."""
    from scipy.ndimage import gaussian_filter

    trees = np.flatnonzero(instances.species < tree_species)
    h, w = shape
    if len(trees) == 0:
        return np.zeros(shape)
    xmin, zmin, xmax, zmax = extent
    dx, dz = (xmax - xmin) / w, (zmax - zmin) / h
    r = crown_radius[instances.species[trees].astype(np.int64)] * instances.scale[trees]
    j = np.clip(((instances.position[trees, 0] - xmin) / dx).astype(np.int64), 0, w - 1)
    i = np.clip(((instances.position[trees, 2] - zmin) / dz).astype(np.int64), 0, h - 1)
    area = np.bincount(i * w + j, weights=np.pi * r * r, minlength=h * w).reshape(h, w)
    sigma = float(np.mean(r)) / np.array([dz, dx])
    density = gaussian_filter(area / (dx * dz), sigma=np.maximum(sigma, 0.5), mode="nearest")
    return 1.0 - np.exp(-density)


def crown_radii(species: Sequence[Species]) -> np.ndarray:
    """Half the larger horizontal extent of each species' highest level, metres: (S,)."""
    out = []
    for sp in species:
        b = np.asarray(sp.lods[0].bounds, np.float64).reshape(2, 3)
        out.append(0.5 * max(b[1, 0] - b[0, 0], b[1, 2] - b[0, 2]))
    return np.array(out, dtype=np.float64)


def read_grey(path: Path, config: Config, field: str) -> np.ndarray:
    """A grey map as painted (:func:`forest.images.read_map_grey`); a bad file is a ``ConfigError`` on ``field``."""
    from .images import read_map_grey

    try:
        return read_map_grey(path, what="map")
    except ForestError as e:
        raise ConfigError(config.path, field, str(e)) from None


def detail_texture(ground: GroundConfig) -> tuple[np.ndarray | None, float]:
    """The detail tile at ``detail_strength`` (mean kept at 1) and its size, or (None, 0) without detail."""
    if ground.detail_tile <= 0 or ground.detail_strength <= 0:
        return None, 0.0
    from .library.textures import ground_detail_rgb

    d = 1.0 + ground.detail_strength * (ground_detail_rgb().astype(np.float64) - 1.0)
    d = np.clip(d, 0.05, None)
    d /= d.reshape(-1, 3).mean(axis=0)
    return d.astype(np.float32), float(ground.detail_tile)


def paint_rules(
    config: Config,
    terrain: Terrain,
    instances: InstanceSet,
    species: Sequence[Species],
    ground: GroundConfig,
) -> tuple[np.ndarray, np.ndarray | None]:
    """The ``[ground]`` layer stack (module docstring): an ``(H, W, 3)`` float32 albedo grid and the
    ``(H, W)`` float32 water coverage (None when no rule paints water)."""
    extent = terrain.extent
    resolution = ground.resolution if terrain.grid_shape is not None else min(ground.resolution, MESH_RESOLUTION)
    shape = grid_shape(extent, resolution)
    x, z = texel_centres(extent, shape)
    palette = ground.palette()
    rules = [GroundRule.model_validate(r) for r in DEFAULT_RULES] if ground.rules is None else list(ground.rules)
    rgb = np.empty((*shape, 3), np.float64)
    rgb[:] = palette[ground.base]
    water = np.zeros(shape, np.float64) if any(r.material == WATER_MATERIAL for r in rules) else None
    if ground.base == WATER_MATERIAL:
        water = np.ones(shape, np.float64)
    if not rules and terrain.water is None:
        return _finish(rgb, water, extent, ground, config.seed)
    # The dry layers' colour so far (what a water layer covers) and the water's share's bed B (module docstring),
    # in single precision: two more colour grids while painting, only for a ground with water rules.
    bed = rgb.astype(np.float32) if water is not None else None
    water_bed = (rgb * water[..., None]).astype(np.float32) if water is not None else None
    height = terrain.height_at(x.ravel(), z.ravel()).reshape(shape)
    hmin, hmax = terrain.height_range
    units = {"slope": 1.0, "altitude": max(hmax - hmin, 1.0), "moisture": 1.0, "canopy": 1.0, "relief": 1.0}
    cache: dict[str, np.ndarray] = {}

    def variable(name: str) -> np.ndarray:
        if name not in cache:
            if name == "altitude":
                cache[name] = height
            elif name == "slope":
                cache[name] = terrain_slope(height, extent)
            elif name == "relief":
                cache[name] = terrain_relief(height, extent, ground.relief_radius)
            elif name == "moisture":
                if config.maps.moisture is not None:
                    img = read_grey(config.maps.moisture, config, "maps.moisture")
                    u, v = terrain.to_uv(x.ravel(), z.ravel())
                    cache[name] = np.clip(sample_bilinear(img, u, v), 0.0, 1.0).reshape(shape)
                else:
                    cache[name] = terrain_moisture(height, variable("slope"), terrain.height_range)
            else:  # canopy
                n_trees = len(config.species)
                cache[name] = canopy_cover(instances, crown_radii(species), n_trees, extent, shape)
        return cache[name]

    for r, rule in enumerate(rules):
        where = "ground.rules" if ground.rules is None else f"ground.rules[{r}]"
        alpha = np.full(shape, rule.opacity, np.float64)
        noise = edge_noise(shape, extent, rule.noise_scale, config.seed, r) * rule.noise if rule.noise > 0 else None
        for name in ("slope", "altitude", "moisture", "canopy", "relief"):
            window = getattr(rule, name)
            if window is None:
                continue
            trap = ramp_points(window, name, units[name])
            value = variable(name)
            if noise is not None:
                width = 0.5 * ((trap[1] - trap[0]) + (trap[3] - trap[2])) or RAMP[name] * units[name]
                value = value + noise * width
            alpha *= membership(value, trap, name)
        if rule.map is not None:
            img = read_grey(rule.map, config, f"{where}.map")
            u, v = terrain.to_uv(x.ravel(), z.ravel())
            weight = np.clip(sample_bilinear(img, u, v), 0.0, 1.0).reshape(shape)
            alpha *= 1.0 - weight if rule.invert else weight
        c = np.asarray(palette[rule.material], np.float64)
        rgb += alpha[..., None] * (c - rgb)
        if water is not None and bed is not None and water_bed is not None:
            wet = rule.material == WATER_MATERIAL
            water += alpha * ((1.0 if wet else 0.0) - water)
            water_bed += alpha[..., None] * ((bed if wet else 0.0) - water_bed)
            if not wet:
                bed += alpha[..., None] * (c - bed)
    if water is not None and water_bed is not None and ground.water_depth > 0.0:
        depth = river_depth(water, extent, ground.water_depth)
        deep = np.asarray(palette[WATER_MATERIAL], np.float64)
        rgb += shallow(depth, ground.water_attenuation) * (water_bed - water[..., None] * deep)
    del bed, water_bed
    rgb, water = paint_still_water(
        rgb, water, terrain, height, (x, z), palette[WATER_MATERIAL], ground.water_attenuation
    )
    return _finish(rgb, water, extent, ground, config.seed)


def shallow(depth: np.ndarray, attenuation: Sequence[float]) -> np.ndarray:
    """(…, 3) exp(−2 K H): the share of the bed's colour in shallow water's, H = ``depth`` (…) metres and K =
    ``attenuation`` (3,) per metre (module docstring, "Shallow water")."""
    k = np.asarray(attenuation, np.float64).reshape(3)
    return np.exp(-2.0 * np.asarray(depth, np.float64)[..., None] * k)


def river_depth(water: np.ndarray, extent: tuple[float, float, float, float], deepest: float) -> np.ndarray:
    """(H, W) metres of painted water over its bed: min(D, g·δ) with g :data:`~forest.config.schema.BANK_GRADIENT`,
    D = ``deepest`` and δ the distance in metres from each texel of coverage W ≥ ½ to the nearest texel below ½,
    less half a texel (0 off the water; D everywhere when no texel is dry)."""
    from scipy.ndimage import distance_transform_edt

    mask = np.asarray(water) >= 0.5
    if mask.all():
        return np.full(mask.shape, float(deepest))
    xmin, zmin, xmax, zmax = extent
    dz, dx = (zmax - zmin) / mask.shape[0], (xmax - xmin) / mask.shape[1]
    delta = distance_transform_edt(mask, sampling=(dz, dx)) - 0.5 * min(dx, dz)
    return np.where(mask, np.clip(BANK_GRADIENT * delta, 0.0, float(deepest)), 0.0)


def paint_still_water(
    rgb: np.ndarray,
    water: np.ndarray | None,
    terrain: Terrain,
    height: np.ndarray,
    texels: tuple[np.ndarray, np.ndarray],
    colour: Sequence[float],
    attenuation: Sequence[float],
) -> tuple[np.ndarray, np.ndarray | None]:
    """``[terrain] water`` painted over a grid as the top layer: its coverage W_lake = the terrain's
    :meth:`~forest.terrain.Terrain.water_cover` at the texels' ``height`` (H, W), composited as a rule is,

        ρ ← (1 − W_lake)·ρ + W_lake·R(H),    W ← (1 − W_lake)·W + W_lake,

    R(H) = c + (ρ − c)·exp(−2 K H) the water of ``colour`` c and ``attenuation`` K at the depth H of the texel
    centres ``texels`` (world X, Z; :meth:`~forest.terrain.Terrain.water_depth`) over the ground painted under it
    (module docstring, "Shallow water"); the grids unchanged without water."""
    lake = terrain.water_cover(height)
    if lake is None:
        return rgb, water
    c = np.asarray(colour, np.float64)
    seen = c + (rgb - c) * shallow(terrain.water_depth(*texels), attenuation)
    rgb = rgb + lake[..., None] * (seen - rgb)
    water = lake if water is None else water + lake * (1.0 - water)
    return rgb, water


def _finish(
    rgb: np.ndarray,
    water: np.ndarray | None,
    extent: tuple[float, float, float, float],
    ground: GroundConfig,
    seed: int,
) -> tuple[np.ndarray, np.ndarray | None]:
    """The painted grid varied (:func:`vary`) and both grids as float32."""
    water = None if water is None else np.clip(water, 0.0, 1.0)
    if ground.variation > 0.0:
        rgb = vary(rgb, water, extent, ground.variation, ground.variation_scale, seed)
    return rgb.astype(np.float32), None if water is None else water.astype(np.float32)


def vary(
    rgb: np.ndarray,
    water: np.ndarray | None,
    extent: tuple[float, float, float, float],
    sigma: float,
    scale_m: float,
    seed: int,
) -> np.ndarray:
    """The painted grid ``rgb`` (H, W, 3) with the ground's macro variation (module docstring, "Variation"):
    ρ ⊙ exp(σ n₁ − σ²/2) ⊙ (exp(σ n₂ − σ²/2), 1, exp(−σ n₂ − σ²/2)), n₁ and n₂ unit Gaussian fields of correlation
    length ``scale_m`` (:func:`edge_noise`); the water's share W of a texel keeps its colour."""
    shape = rgb.shape[:2]
    n1 = edge_noise(shape, extent, scale_m, seed, VARIATION_INDEX)
    n2 = edge_noise(shape, extent, scale_m, seed, VARIATION_INDEX + 1)
    lum = np.exp(sigma * n1 - 0.5 * sigma * sigma)
    factor = np.stack([np.exp(sigma * n2), np.ones(shape), np.exp(-sigma * n2)], -1)
    factor[..., ::2] *= np.exp(-0.5 * sigma * sigma)
    factor *= lum[..., None]
    if water is not None:
        factor = 1.0 + (1.0 - water[..., None]) * (factor - 1.0)
    return np.clip(rgb * factor, 0.0, 1.0)


def water_triangles(terrain: Terrain, albedo: TerrainAlbedo) -> np.ndarray | None:
    """Which of the terrain's triangles are water: bool (F,), True where the water coverage W at the triangle's
    centroid is at least ½ (the renderers without forest_path's per-hit mirror and the exports draw those as a
    water surface of their own); None when the ground has no water or none of it reaches ½."""
    if albedo.water is None:
        return None
    centroid = terrain.vertices[terrain.faces].mean(axis=1)
    wet = albedo.water_at(centroid[:, 0], centroid[:, 2]) >= 0.5
    return wet if wet.any() else None


def water_colour(albedo: TerrainAlbedo, *, edge: bool = False) -> np.ndarray:
    """The water's colour (3,): the painted albedo's mean over the texels of coverage W ≥ ½ (zeros without);
    ``edge``: over those on the grid's border only (the sea that runs on past the terrain's edge continues them),
    all of them when none is."""
    if albedo.water is None:
        return np.zeros(3)
    mask = np.asarray(albedo.water) >= 0.5
    if edge:
        border = np.zeros_like(mask)
        border[[0, -1], :] = border[:, [0, -1]] = True
        if (mask & border).any():
            mask = mask & border
    return np.asarray(albedo.rgb, np.float64)[mask].mean(axis=0) if mask.any() else np.zeros(3)


def water_roughness(ripple_deg: float) -> float:
    """The ripples as a microfacet roughness r, with GGX α = r² = tan(ripple) (the RMS slope)."""
    return float(np.sqrt(np.tan(np.radians(ripple_deg))))


def read_terrain_texture(config: Config) -> np.ndarray | None:
    """``[render] terrain_texture`` as linear RGB (H, W, 3), or None without one; a file that cannot be read is a
    :class:`~forest.errors.ConfigError` on ``render.terrain_texture``.  The only reader of that setting."""
    path = config.render.terrain_texture
    if path is None:
        return None
    from .images import read_map_rgb

    try:
        return read_map_rgb(path, what="terrain texture")
    except ForestError as e:
        raise ConfigError(config.path, "render.terrain_texture", str(e)) from None


def terrain_albedo(
    config: Config, terrain: Terrain, instances: InstanceSet, species: Sequence[Species]
) -> TerrainAlbedo:
    """The Scene's :class:`TerrainAlbedo` (module docstring: texture, single colour or ``[ground]`` rules)."""
    ground = config.model.ground
    detail, tile = detail_texture(ground)
    rc = config.render
    texture = read_terrain_texture(config)
    water = None
    if texture is not None:
        rgb, detail, tile = texture, None, 0.0  # a painted ground texture is used as it is
    elif "terrain_colour" in rc.model_fields_set:
        rgb = np.asarray(rc.terrain_colour, np.float32).reshape(1, 1, 3)
    else:
        rgb, water = paint_rules(config, terrain, instances, species, ground)
    if terrain.water is not None and water is None:  # a texture or one colour: the still water over it
        shape = rgb.shape[:2] if rgb.shape[0] > 1 else grid_shape(terrain.extent, ground.resolution)
        x, z = texel_centres(terrain.extent, shape)
        height = terrain.height_at(x.ravel(), z.ravel()).reshape(shape)
        base = np.broadcast_to(np.asarray(rgb, np.float64), (*shape, 3))
        rgb, lake = paint_still_water(
            base,
            None,
            terrain,
            height,
            (x, z),
            ground.palette()[WATER_MATERIAL],
            ground.water_attenuation,
        )
        water = None if lake is None else lake.astype(np.float32)
    return TerrainAlbedo(np.ascontiguousarray(rgb, dtype=np.float32), terrain.extent, detail, tile, water)
