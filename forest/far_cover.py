"""Woods and open ground on the far landscape: the skirt's land cover in patches.

:mod:`forest.skirt` paints the ground past the terrain's edge one colour, the
far landscape's albedo ρ_far, the mean over the terrain of what each point
looks like from afar, (1 − c)·ρ_g + c·ρ_c (c the crowns' cover there, ρ_c the
canopy's reflectance, ρ_g the ground's albedo; :func:`forest.skirt.landscape`).
Seen from a few hundred metres up, hills painted that mean are smooth green
humps: a real wooded landscape is a mosaic of woods and fields, and inside the
woods the crowns and their shadows give the canopy a grain (Forman, *Land
Mosaics: The Ecology of Landscapes and Regions*, 1995, ch. 1: patches,
corridors and matrix; the canopy grain of a forest seen from afar is what Li
and Strahler 1992, "Geometric-optical bidirectional reflectance modeling of
the discrete crown vegetation canopy", IEEE TGRS 30(2): 276–292, model as
sunlit and shaded crown and ground).

The mosaic's two kinds of land are the terrain's own: its wooded land, where
the crowns cover at least half the ground (c ≥ :data:`forest.skirt.WOODED`), a
share w̄ of it with the mean albedo ρ_w there (crowns over their gaps), and its
open land, the rest, with ρ_o = (ρ_far − w̄·ρ_w)/(1 − w̄) — the meadows, fields
and riverbeds the terrain has, not the litter between its crowns.  A terrain
that is all forest, or all open, stays one colour; a forest with clearings
gets fields of the clearings' ground.

So the skirt's albedo mixes them with a cover that varies across the land,
C(x, z) ∈ [0, 1], and a canopy grain g(x, z) of mean 1:

    ρ(x, z) = (1 − C)·ρ_o + C·g·ρ_w,    ⟨C⟩ = w̄,  ⟨C·g⟩ = w̄

whose mean over the land is ρ_far exactly: the far landscape keeps the colour
the Scene computed, and a terrain without wooded land (w̄ = 0) or all wooded
(w̄ ≈ 1) stays one colour.  C is a soft threshold of a fractional
Brownian motion of value noise (:data:`STAND_M`-metre stands down to
:data:`GRAIN_M`-metre crowns, lacunarity 2, gain ½; Perlin 1985, Ebert et al.
2003, ch. 16 as :mod:`forest.skirt`'s hills), C = s((f − t)/2ε + ½) with s
the smoothstep and t found by bisection so that ⟨C⟩ = w̄; g = 1 + a·(h − ⟨h⟩)
is a value noise h of :data:`GRAIN_M`-metre cells (a = :data:`GRAIN`), rescaled so that
⟨C·g⟩ = w̄.

The pattern is one periodic tile of :data:`TILE_M` metres on
:data:`TEXELS` × :data:`TEXELS` texels (:func:`cover_tile`), looked up by world
X/Z with wrapping, and stored as the two weights (1 − C, C·g), so that the
renderer's factor on ρ_far is

    m(x, z) = (1 − C)·ρ_o/ρ_far + C·g·ρ_w/ρ_far

It fades in past the terrain's edge over the same distance as the albedo grid
fades to ρ_far (:func:`forest.skirt.fade_beyond_edge`), so the terrain and its
padded edge keep their own albedo:

    m' = 1 + s(d / P)·(m − 1),    d = the Chebyshev distance past the extent

**Relief.**  Seen against the sky, a wooded hill's outline is not a smooth
curve: the woods stand a canopy's height above the fields, and their top is
crowns.  So forest_path's skirt rises, where the woods are, by

    Δy(x, z) = s(d / P) · C · H · (1 − a_c + a_c·k(x, z))

with H the canopy's height (:func:`forest.skirt.landscape`: the trees' heights
weighted by crown area, as ρ_c), a_c = :data:`CROWN_DEPTH` the share of it
that is crowns, and k a field of domes, one per jittered lattice cell of
:data:`CROWN_M` metres, k = √(1 − (F₁/r)²)⁺ (F₁ the distance to the nearest
cell's point, Worley 1996, "A cellular texture basis function", SIGGRAPH;
r = :data:`CROWN_RADIUS` cells).  The skirt's hill rings are cut every pixel
or two around the terrain (:func:`forest.skirt.skirt_mesh`), so the woods'
edges show on a skyline; the shading normals stay the smooth hills' own.

**Treeline.**  Far hills that rise into mountains are not wooded to the top: trees
end at a treeline, and above it lie alpine meadow, then scree and rock (Körner,
*Alpine Treelines*, Springer 2012: the forest thins out over a band of height,
the treeline ecotone).  With ``[render] horizon_hills`` ``treeline`` and
``rockline`` (world heights, metres), at a point of height y

    a = s((y − y_t + B_t) / 2B_t),    r = s((y − y_r + B_r) / 2B_r)

(B_t = :data:`TREELINE_BAND_M`, B_r = :data:`ROCK_BAND_M`), the woods' cover
becomes C·(1 − a) — the relief with it — and the mosaic's factor

    m = ρ'_o·(1 − C + a·C) + (1 − a)·C·g·ρ_w / ρ_far,    ρ'_o = (1 − r)·ρ_o/ρ_far + r·ρ_rock/ρ_far

with ρ_rock ``[ground]``'s rock.  Above the treeline steep faces are rock
too, whatever their height: loose rock comes to rest at about 35° (the angle
of repose of talus), and soil and alpine grass do not hold on steeper ground,
so with a rock line the open ground's rock share is

    r' = 1 − (1 − r)·(1 − a·q),    q = s((cos θ₀ − n_y) / (cos θ₀ − cos θ₁))

with n_y the shading normal's upward component (cos of the slope θ) and
θ₀, θ₁ = :data:`STEEP_ROCK_DEG` (meadow below 30°, rock above 45°): on
eroded hills (:mod:`forest.erosion`) the gullies' walls and the spurs between
them turn to rock and their gentler floors and shoulders stay grass.  Without
a normal (or below the treeline) q plays no part.  Below the treeline it is the mosaic above,
whose mean is ρ_far; above it the land is what it is there, not the terrain's
mean.  forest_path reads y at the hit, which the woods' relief (a canopy, a
few tens of metres) lifts a little inside the band.

**Snow.**  With ``snowline`` (a world height) the land above it lies under
``[ground]``'s snow, except where it is too steep to hold: snow sloughs off
faces steeper than about 50° (the steep rock bands of snowy mountains), so

    σ = s((y − y_s + B_s) / 2B_s) · (1 − q_s),    q_s = s((cos θ₂ − n_y) / (cos θ₂ − cos θ₃))

(B_s = :data:`SNOW_BAND_M`, θ₂, θ₃ = :data:`STEEP_SNOW_DEG`), and the factor
becomes (1 − σ)·m' + σ·ρ_snow/ρ_far over whatever lies below it — woods,
open ground or rock.  Without a normal every face holds snow.

**Prefilter.**  The skirt carries the relief on rings whose spacing grows
with the distance from the terrain (5 % of the radius: a hundred metres and
more), against columns cut a pixel or two apart.  Crowns :data:`CROWN_M`
metres apart, sampled every column but only every ring, became long ridges
running away from the camera, and with a low sun their shadows striped the
hills like eroded cliffs.  So at a vertex the domes are averaged over its ring
spacing f: their deviation from their mean k̄ is kept in proportion
CROWN_M / f, what a box of width f keeps of them,

    Δy_f = s(d / P) · C · H · (1 − a_c + a_c·(k̄ + min(1, CROWN_M / f)·(k − k̄)))

C itself is left sharp: the woods' edges are long curves, not a per-column
pattern, and a ring spacing turns a step across them into a slope, not a
ridge (averaging C too, tried, smoothed the stands away).  On the hills the
woods then stand as smooth-topped stands whose edges step up from the fields;
crowns show where the rings are close enough to hold them.

forest_path draws both (``[render] horizon_hills``' ``woods``, on by default
with hills); the scalar renderer keeps the one colour ρ_far and the smooth
hills, as it keeps the ground without its detail texture.  Deterministic: the
tile depends only on w̄ (rounded to 10⁻⁶) and the hills' seed, the domes on the
seed.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

#: Side of the periodic tile, metres (larger than a hill, so its repeats do not line up with them).
TILE_M = 4096.0
#: Texels along a side of the tile (4 m each).
TEXELS = 1024
#: Size of the largest patches of woods and open ground (the noise's lowest octave), metres.
STAND_M = 384.0
#: Size of the finest cover detail and of the canopy grain's cells, metres.
GRAIN_M = 24.0
#: Half-width ε of the soft threshold, in units of the fBm's value: the width of a wood's edge.
EDGE = 0.035
#: Standard deviation a of the canopy grain g (crowns against their shadows).
GRAIN = 0.4
#: Below this cover, or above 1 minus it, the land is one colour (no mosaic to draw).
MIN_CONTRAST = 1e-3
#: Purpose tag of the cover's noise (CONTRIBUTING's seeding rule: a constant per purpose).
COVER_TAG = 0x574F_4F44
#: Spacing of the crowns on the woods' relief (the lattice cell of the domes), metres.
CROWN_M = 9.0
#: Radius r of a crown's dome, in cells (wider than half a cell, so neighbouring crowns touch).
CROWN_RADIUS = 0.75
#: Share a_c of the canopy's height that is crowns (the relief's dome amplitude).
CROWN_DEPTH = 0.35
#: Purpose tag of the crowns' lattice points.
CROWN_TAG = 0x4352_4F57


def _periodic_noise(n: int, cells: int, key: np.uint64, shift: float) -> np.ndarray:
    """(n, n) value noise with ``cells`` lattice cells across, periodic over the tile (indices modulo ``cells``)."""
    from .scatter.canopy import fade, lattice

    x = (np.arange(n, dtype=np.float64) + 0.5) * (cells / n) + shift
    i0 = np.floor(x).astype(np.int64)
    f = fade(x - i0)
    g = np.arange(cells, dtype=np.int64)
    table = lattice(g[None, :], g[:, None], key)  # (cells, cells), row = z
    a0, a1 = i0 % cells, (i0 + 1) % cells
    top = table[a0[:, None], a0[None, :]] + (table[a0[:, None], a1[None, :]] - table[a0[:, None], a0[None, :]]) * f
    bot = table[a1[:, None], a0[None, :]] + (table[a1[:, None], a1[None, :]] - table[a1[:, None], a0[None, :]]) * f
    return top + (bot - top) * f[:, None]


def _fbm(n: int, first_cells: int, octaves: int, key: np.uint64) -> np.ndarray:
    """Periodic fBm (lacunarity 2, gain ½) normalised to amplitude sum 1."""
    total = np.zeros((n, n))
    amplitude, norm = 1.0, 0.0
    for octave in range(octaves):
        k = np.uint64((int(key) + octave * 0xBF58476D1CE4E5B9) % 2**64)
        total += amplitude * _periodic_noise(n, first_cells * 2**octave, k, 0.37 * octave)
        norm += amplitude
        amplitude *= 0.5
    return total / norm


def _soft_cover(f: np.ndarray, t: float) -> np.ndarray:
    """C = s((f − t)/2ε + ½), s the smoothstep: 0 below t − ε, 1 above t + ε."""
    u = np.clip((f - t) / (2.0 * EDGE) + 0.5, 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


@lru_cache(maxsize=4)
def cover_tile(cover: float, seed: int) -> np.ndarray:
    """(:data:`TEXELS`, :data:`TEXELS`, 2) float32: the weights (1 − C, C·g) of one tile, ⟨C⟩ = ⟨C·g⟩ = ``cover``.

    Row i covers z/TILE_M ∈ [i, i+1]/TEXELS and column j x/TILE_M ∈ [j, j+1]/TEXELS, modulo 1 (module docstring).
    """
    c = float(np.clip(cover, 0.0, 1.0))
    key = np.uint64((int(seed) * 0x9E3779B97F4A7C15 + COVER_TAG) % 2**64)
    first = max(1, round(TILE_M / STAND_M))
    octaves = max(1, round(np.log2(STAND_M / GRAIN_M)) + 1)
    f = _fbm(TEXELS, first, octaves, key)
    lo, hi = float(f.min()) - EDGE, float(f.max()) + EDGE  # ⟨C⟩ falls from 1 at lo to 0 at hi
    sample = f[::4, ::4]  # the threshold from every 16th texel; the exact mean by the rescaling below
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        if _soft_cover(sample, mid).mean() > c:
            lo = mid
        else:
            hi = mid
    cov = _soft_cover(f, 0.5 * (lo + hi))
    m = float(cov.mean())  # the exact mean: scale the woods down, or the gaps, so that C stays in [0, 1]
    cov = cov * (c / m) if m > c else 1.0 - (1.0 - cov) * ((1.0 - c) / max(1.0 - m, 1e-12))
    cells = max(1, round(TILE_M / GRAIN_M))
    h = _periodic_noise(TEXELS, cells, np.uint64((int(key) ^ 0xD1B54A32D192ED03) % 2**64), 0.0)
    g = 1.0 + GRAIN * (h - h.mean()) / max(float(h.std()), 1e-12)
    g = np.maximum(g, 0.05)
    woods = cov * g
    woods *= float(cov.mean()) / max(float(woods.mean()), 1e-12)  # ⟨C·g⟩ = ⟨C⟩
    tile = np.ascontiguousarray(np.stack([1.0 - cov, woods], axis=-1).astype(np.float32))
    tile.flags.writeable = False  # cached and shared by every FarCover of this cover and seed
    return tile


#: Half the band (metres of height) over which the woods give way to open ground at the treeline, and over which
#: open ground gives way to rock at the rock line (:meth:`FarCover.alpine`).
TREELINE_BAND_M = 40.0
ROCK_BAND_M = 80.0
#: Slopes (degrees) over which open ground above the treeline turns to rock (module docstring, "Treeline").
STEEP_ROCK_DEG = (30.0, 45.0)
#: Half the band (metres of height) over which the land gives way to snow at the snow line.
SNOW_BAND_M = 60.0
#: Slopes (degrees) over which snow gives way to the bare face below it (module docstring, "Snow").
STEEP_SNOW_DEG = (45.0, 60.0)


def _slope_share(up: np.ndarray, degrees: tuple[float, float]) -> np.ndarray:
    """s((cos θ₀ − |up|) / (cos θ₀ − cos θ₁)): 0 on slopes under θ₀, 1 over θ₁ (``up`` the normal's upward part)."""
    c0, c1 = (float(np.cos(np.radians(d))) for d in degrees)
    t = np.clip((c0 - np.abs(np.asarray(up, np.float64))) / (c0 - c1), 0.0, 1.0)
    out: np.ndarray = t * t * (3.0 - 2.0 * t)
    return out


def steep_share(up: np.ndarray) -> np.ndarray:
    """q: the share of open ground above the treeline that is rock for its slope, from the shading normal's upward
    component ``up`` (module docstring, "Treeline")."""
    return _slope_share(up, STEEP_ROCK_DEG)


def _smooth_band(y: np.ndarray, centre: float | None, half: float) -> np.ndarray:
    """s((y − centre + half) / 2·half): 0 well below ``centre``, 1 well above (0 everywhere when it is None)."""
    if centre is None:
        return np.zeros(np.shape(y))
    t = np.clip((np.asarray(y, np.float64) - centre + half) / (2.0 * half), 0.0, 1.0)
    out: np.ndarray = t * t * (3.0 - 2.0 * t)
    return out


@dataclass(frozen=True)
class FarCover:
    """What forest_path needs to draw the mosaic (module docstring).

    ``tile``: :func:`cover_tile`'s weights; ``open`` and ``canopy``: ρ_o/ρ_far and
    ρ_w/ρ_far (3,) each; ``extent``: the terrain's (xmin, zmin, xmax, zmax);
    ``ramp``: P, metres past it over which the mosaic fades in; ``tile_m``: the tile's side;
    ``height``: H, the canopy's height (metres; 0: no relief); ``seed``: the crowns' pattern;
    ``treeline``, ``rockline``: world heights (Y, metres) above which the woods give way to open ground
    and open ground to rock, ``rock`` ρ_rock/ρ_far (None: no such line; module docstring, "Treeline");
    ``snowline``, ``snow``: the height above which the land is under snow, ρ_snow/ρ_far ("Snow").
    """

    tile: np.ndarray
    open: tuple[float, float, float]
    canopy: tuple[float, float, float]
    extent: tuple[float, float, float, float]
    ramp: float
    tile_m: float = TILE_M
    height: float = 0.0
    seed: int = 0
    treeline: float | None = None
    rockline: float | None = None
    rock: tuple[float, float, float] | None = None
    snowline: float | None = None
    snow: tuple[float, float, float] | None = None

    def alpine(self, y: np.ndarray | None, up: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(a, r) at world heights ``y`` (and shading normals' upward components ``up``): the share of the woods
        turned to open ground, and of the open ground turned to rock (0 and 0 without the lines, or for ``y``
        None; r the height's alone for ``up`` None)."""
        if y is None:
            return np.zeros(()), np.zeros(())
        a = _smooth_band(y, self.treeline, TREELINE_BAND_M)
        r = _smooth_band(y, self.rockline, ROCK_BAND_M) if self.rock is not None else np.zeros(np.shape(y))
        if up is not None and self.rock is not None:
            r = 1.0 - (1.0 - r) * (1.0 - a * steep_share(up))
        return a, r

    def _ramp(self, x: np.ndarray, z: np.ndarray) -> np.ndarray:
        """s(d / P): 0 inside the terrain's extent, 1 from P past it."""
        xmin, zmin, xmax, zmax = self.extent
        d = np.maximum(np.maximum(xmin - x, x - xmax), np.maximum(zmin - z, z - zmax))
        t = np.clip(d / self.ramp, 0.0, 1.0)
        return t * t * (3.0 - 2.0 * t)

    def woods(self, x: np.ndarray, z: np.ndarray, y: np.ndarray | None = None) -> np.ndarray:
        """C at world (x, z): the woods' cover of the land (the tile's first weight is 1 − C), times 1 − a above the
        treeline where the ground's height ``y`` is given."""
        from .ground import wrapped_bilinear

        x = np.asarray(x, np.float64)
        z = np.asarray(z, np.float64)
        w = wrapped_bilinear(self.tile[..., :1], x.ravel() / self.tile_m, z.ravel() / self.tile_m)
        c: np.ndarray = (1.0 - w[:, 0]).reshape(x.shape)
        return c * (1.0 - self.alpine(y)[0])

    def relief(
        self,
        x: np.ndarray,
        z: np.ndarray,
        footprint: np.ndarray | float | None = None,
        y: np.ndarray | None = None,
    ) -> np.ndarray:
        """Δy at world (x, z), metres: how far the woods stand above the ground there (module docstring), its crowns
        averaged over ``footprint`` metres around each point (None or up to :data:`CROWN_M`: unfiltered) — the
        spacing of the mesh that carries it, so that crowns it cannot hold do not alias into ridges ("Prefilter");
        ``y`` the ground's height there (none above the treeline)."""
        x = np.asarray(x, np.float64)
        z = np.asarray(z, np.float64)
        if self.height <= 0.0:
            return np.zeros(x.shape)
        k = crown_domes(x, z, self.seed)
        if footprint is not None:
            f = np.broadcast_to(np.asarray(footprint, np.float64), x.shape)
            keep = np.clip(CROWN_M / np.maximum(f, 1e-9), 0.0, 1.0)  # a box of width f keeps ~CROWN_M/f of them
            k = dome_mean() + keep * (k - dome_mean())
        crowns = 1.0 - CROWN_DEPTH + CROWN_DEPTH * k
        return self._ramp(x, z) * self.woods(x, z, y) * self.height * crowns

    def factor(
        self, x: np.ndarray, z: np.ndarray, y: np.ndarray | None = None, up: np.ndarray | None = None
    ) -> np.ndarray:
        """m' (…, 3) at world (x, z) and height ``y`` (None: below any treeline), where the shading normal's upward
        component is ``up`` (None: level ground): the factor on the skirt's albedo (module docstring), on the
        host."""
        from .ground import wrapped_bilinear

        x = np.asarray(x, np.float64)
        z = np.asarray(z, np.float64)
        w = wrapped_bilinear(self.tile, x.ravel() / self.tile_m, z.ravel() / self.tile_m).reshape(*x.shape, 2)
        a, r = (v[..., None] for v in self.alpine(y, up))
        rock = np.asarray(self.open if self.rock is None else self.rock)
        open_ = np.asarray(self.open) + r * (rock - np.asarray(self.open))
        m = open_ * (w[..., :1] + a * (1.0 - w[..., :1])) + (1.0 - a) * w[..., 1:2] * np.asarray(self.canopy)
        if self.snow is not None and y is not None:
            sigma = self.snow_share(y, up)[..., None]
            m = m + sigma * (np.asarray(self.snow) - m)
        return 1.0 + self._ramp(x, z)[..., None] * (m - 1.0)

    def snow_share(self, y: np.ndarray, up: np.ndarray | None = None) -> np.ndarray:
        """σ at heights ``y`` (and shading normals' upward components ``up``): the share of the land under snow
        (module docstring, "Snow"; 0 without a snow line)."""
        if self.snow is None:
            return np.zeros(np.shape(y))
        sigma = _smooth_band(y, self.snowline, SNOW_BAND_M)
        return sigma if up is None else sigma * (1.0 - _slope_share(up, STEEP_SNOW_DEG))


@lru_cache(maxsize=1)
def dome_mean() -> float:
    """k̄, the mean of :func:`crown_domes` over the land (measured on a 512 × 512 grid over 64 × 64 cells)."""
    g = (np.arange(512) + 0.5) * (64.0 * CROWN_M / 512)
    x, z = np.meshgrid(g, g)
    return float(crown_domes(x, z, 0).mean())


def crown_domes(x: np.ndarray, z: np.ndarray, seed: int) -> np.ndarray:
    """k(x, z) ∈ [0, 1]: one dome √(1 − (F₁/r)²)⁺ per :data:`CROWN_M`-metre cell around a hashed point in it
    (module docstring, "Relief"); F₁ over the 3 × 3 cells around each point."""
    from .scatter.canopy import lattice

    key = np.uint64((int(seed) * 0x9E3779B97F4A7C15 + CROWN_TAG) % 2**64)
    key_z = np.uint64((int(key) ^ 0xD1B54A32D192ED03) % 2**64)
    u = np.asarray(x, np.float64).ravel() / CROWN_M
    v = np.asarray(z, np.float64).ravel() / CROWN_M
    iu, iv = np.floor(u).astype(np.int64), np.floor(v).astype(np.int64)
    nearest = np.full(u.shape, np.inf)
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            cu, cv = iu + di, iv + dj
            du = cu + lattice(cu, cv, key) - u
            dv = cv + lattice(cu, cv, key_z) - v
            np.minimum(nearest, du * du + dv * dv, out=nearest)
    k = np.sqrt(np.clip(1.0 - nearest / CROWN_RADIUS**2, 0.0, 1.0))
    return k.reshape(np.shape(x))


def far_cover(
    far: np.ndarray | tuple[float, float, float],
    canopy: np.ndarray | tuple[float, float, float],
    cover: float,
    extent: tuple[float, float, float, float],
    ramp: float,
    seed: int,
    height: float = 0.0,
    treeline: float | None = None,
    rockline: float | None = None,
    rock: np.ndarray | tuple[float, float, float] | None = None,
    snowline: float | None = None,
    snow: np.ndarray | tuple[float, float, float] | None = None,
) -> FarCover | None:
    """The :class:`FarCover` of a far landscape ρ_far = (1 − w̄)·ρ_o + w̄·ρ_w (``far``; ``canopy`` ρ_w, the wooded
    land's albedo; ``cover`` w̄, its share) whose canopy stands ``height`` metres, with the woods ending at
    ``treeline``, rock (albedo ``rock``) from ``rockline`` and snow (albedo ``snow``) from ``snowline`` (world
    heights, None: none); None where there is no
    mosaic to draw (w̄ within :data:`MIN_CONTRAST` of 0 or 1, or ρ_far black)."""
    rho_far = np.asarray(far, np.float64).reshape(3)
    rho_w = np.asarray(canopy, np.float64).reshape(3)
    c = float(cover)
    if not (MIN_CONTRAST < c < 1.0 - MIN_CONTRAST) or not np.all(rho_far > 0.0):
        return None
    rho_o = np.maximum((rho_far - c * rho_w) / (1.0 - c), 0.0)
    tile = cover_tile(round(c, 6), int(seed))
    return FarCover(
        tile,
        tuple(float(v) for v in rho_o / rho_far),  # type: ignore[arg-type]
        tuple(float(v) for v in rho_w / rho_far),  # type: ignore[arg-type]
        tuple(float(v) for v in extent),  # type: ignore[arg-type]
        max(float(ramp), 1e-6),
        height=max(float(height), 0.0),
        seed=int(seed),
        treeline=None if treeline is None else float(treeline),
        rockline=None if rockline is None or rock is None else float(rockline),
        rock=None
        if rock is None or rockline is None
        else tuple(float(v) for v in np.asarray(rock, np.float64) / rho_far),  # type: ignore[arg-type]
        snowline=None if snowline is None or snow is None else float(snowline),
        snow=None
        if snow is None or snowline is None
        else tuple(float(v) for v in np.asarray(snow, np.float64) / rho_far),  # type: ignore[arg-type]
    )
