"""The ground to the horizon: a skirt around the terrain, and an albedo grid that fades on it.

**Skirt.**  A terrain ends at its extent; past it a camera saw the sky below
the horizon (a hard horizon line, a dark band, a city floating on a square).
:func:`skirt_mesh` extrudes every boundary edge of the terrain mesh (an edge
used by one face) outward, radially from the centre of the extent, to a ring
of radius R, and lowers or raises that ring to the mean height of the
boundary:

    v' = c + (v − c)_xz · R / |v − c|_xz,   y' = mean(y of the boundary vertices)

so the ground runs on from its own edge height and becomes one level plane
far away (a slope of (ȳ − y)/(R − r), a fraction of a degree).  A first,
narrow band level with the edge turns the shading normal from the terrain's
own to +Y (interpolating a tilted edge normal over the whole long band drew
stripes to the horizon); its faces wind upward.  R (:func:`skirt_radius`) reaches the camera's far clip
or at least :data:`MIN_SKIRT_RADIUS` metres (and 20 terrain widths): from
hundreds of metres up the ring lies a fraction of a pixel below the horizon.

**Hills** (``[render] horizon_hills``, off by default).  A level plane to the
horizon reads as a sea or a salt flat beyond a forest; real country rises in
hills whose silhouettes, hazed by distance, layer toward the horizon.  With
:class:`Hills` (height A, scale L, seed) the long band becomes
:data:`HILL_RINGS` rings (:func:`hill_rings`) at radii geometric from the ramp's end r₀ to R,
r_j = r₀ (R / r₀)^(j/M), and every ring vertex rises by

    y += A · s(min(d / L, 1)) · h(x / L, z / L),    d = r_j − r₀,   s(t) = t²(3 − 2t)

above the plane's profile, h a fractional Brownian motion of value noise
(:data:`HILL_OCTAVES` octaves, lacunarity 2, gain ½; Perlin 1985, "An image
synthesizer", SIGGRAPH; Ebert et al., *Texturing & Modeling: A Procedural
Approach*, 3rd ed. 2003, ch. 16), rescaled to [0, 1] and squared so that
hills stand out of broad lowlands.  The weight s(d/L) keeps the ground level
with the terrain's edge and lets the hills rise over one scale L past it, so
they never wall in the scene; normals are the area-weighted face normals.
With ``erosion`` (0–1) the hills are cut by gullies running down their slopes
(:mod:`forest.erosion`), and the band carries :data:`ERODED_RINGS` rings so that
the finest of them are held; unset, it follows the height
(:func:`default_erosion`): hills up to 300 m stay smooth rolling country,
mountains from 1 200 m are eroded.  Without hills the skirt is the two bands above, unchanged.  With the woods of
:mod:`forest.far_cover` (forest_path), the ramp's ring is first cut so that
neighbouring vertices are at most about 1.5 of the camera's pixels apart seen
from the centre (:func:`relief_step`), every ring carries those columns, and each vertex rises by the woods'
relief there; the normals stay those of the hills without it.

**The sea.**  With still water (``[terrain] water``, :func:`forest.terrain.flood`) that reaches the
terrain's edge, the water runs on past it: a sea, or a lake wider than the map.  Each column of the
skirt (a boundary vertex and the points radially out from it) takes the water's share w ∈ [0, 1] of
the edge around its angle θ from the centre (:class:`Sea`: the share of flooded boundary vertices in
bins of 1/:data:`SEA_BINS` of a turn, smoothed twice by a box of :data:`SEA_SMOOTH` radians, a
triangle window), and then

    y_far = ȳ_land + w·(level − ȳ_land),    hills and woods × (1 − w),    y ← max(y, level)

with ȳ_land the mean height of the boundary vertices (the far plane's height without water): the
far plane sinks to the water's level where the edge is water, hills and the woods' relief rise out of it only where the edge is land (over a few degrees, as headlands and islands
rather than walls; no woods within the water's ``shore`` metres of its level, as no trees there on the
terrain), and the skirt is flooded as the terrain is.  The water's coverage there follows
the height, W = 1 − s((y − level)/``SHORE_RAMP``) as on the terrain
(:meth:`forest.terrain.Terrain.water_cover`); forest_path draws it past the terrain's extent
(:class:`forest.render.path.inputs.SeaMap`), scalar_rgb draws the faces it covers by half or more
as water (:func:`wet_faces`).  Without water at the edge the skirt is as before.

**Fade.**  With the skirt, the ground's albedo grid (the Scene's
``terrain_albedo``, :mod:`forest.ground`) is padded so that past the terrain's
edge it fades to one colour, the far landscape's albedo ρ_far
(:func:`fade_beyond_edge`): clamped lookups would otherwise repeat every
border texel outward as a stripe running to the horizon.  Both renderers use
these; the exporters write the terrain alone.

**The far landscape.**  Seen from afar, a wooded landscape has the colour of
its canopy where crowns cover the ground and of the ground in the gaps, not of
the soil under the trees (fading to the ground grid's mean drew a brown bare
band at the horizon beyond a forest).  So the skirt fades to the terrain's own
landscape averaged over its extent (:func:`landscape`):

    ρ_far = ⟨(1 − c)·ρ_g⟩ + ⟨c⟩·ρ_c  =  ρ̄_g + ⟨c·(ρ_c − ρ_g)⟩

with ⟨·⟩ the mean over the terrain, ρ_g the ground's albedo grid, and c the
crowns' cover of the ground, the Boolean-model cover of
:func:`forest.ground.canopy_cover` (c = 1 − exp(−D), D the crowns' area per
ground area around a point, Nilson 1971), on a grid of
:data:`COVER_RESOLUTION` texels along the longer side (ρ_g bilinear at its
texel centres in the second form; ρ̄_g is the mean of the whole grid, so a
terrain without trees keeps exactly the former fade to its mean).  Trees
count, ground cover (``[[ground_cover]]``, under or between them) does not.

ρ_c is the canopy's reflectance: the crowns' mean foliage albedo ω, weighted
by crown area π(s_i·R_s)² (R_s the half width of species s's highest level,
s_i the tree's scale), each tree's ω_i its species' tinted colour (the
leaves' albedo, :func:`forest.tint.leaf_colour`; a species without tinted
parts, a building, its parts' mean colour) — the species' own colours, not the
colour map's tint, the trees' jitter or a fitted leaf tint: look-dev fits those
while the skirt stays as the Scene made it, so a skirt that followed them would
disagree with the fit (a fitted sky pulled to make up for a skirt painted with the
start's map), and the map's tint has mean 1 under the default normalisation —
turned into the reflectance of a deep canopy by the two-stream
result for a semi-infinite medium of isotropic scatterers (the diffusive
reflectance of Hapke 1981, "Bidirectional reflectance spectroscopy 1. Theory",
J. Geophys. Res. 86: 3039–3054; Kubelka–Munk's R∞):

    ρ_c = (1 − γ) / (1 + γ),    γ = √(1 − ω)

A crown is not a flat leaf: light that enters it is scattered many times and
partly absorbed, and its self-shadowing is in that reflectance too, so a
canopy of leaves of albedo 0.17 (green) reflects about 0.047, close to what
forest_path draws for the demo's forest seen from afar without haze.  A flat
skirt painted with the leaves' own albedo shone 3–4× brighter than that forest.

ρ_far is a property of the ground (in the grid's units, before the fitted
``ground_tint``, which multiplies the whole grid, skirt included, in both
renderers).  The Scene computes it once (:func:`horizon_albedo`: its
``terrain_albedo``'s ``far``), and both renderers take
it from there (:func:`far_colour`); an albedo built without a Scene fades to
its mean.  Deterministic: no random numbers, only sums over the trees and the
grid.

The same sums split it into the terrain's two kinds of land, for the woods and
fields that :mod:`forest.far_cover` draws on the hills: the wooded land, where
c ≥ :data:`WOODED` (the crowns cover half the ground or more), a share w̄ of the
texels with the mean albedo ρ_w = ⟨ρ_g + c·(ρ_c − ρ_g)⟩ there, and the open
land, the rest — so that (1 − w̄)·ρ_open + w̄·ρ_w = ρ_far (both take the whole
grid's mean ρ̄_g in place of the samples' mean, as ρ_far does).
"""

from __future__ import annotations

import weakref
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from .ground import TerrainAlbedo, canopy_cover, crown_radii, grid_shape, texel_centres
from .library.mesh import vertex_normals
from .maps import sample_bilinear
from .parallel import rowwise
from .tint import leaf_colour

if TYPE_CHECKING:
    from .config import Config
    from .far_cover import FarCover
    from .instances import InstanceSet
    from .library import Species
    from .scene import Scene

#: Smallest radius of the skirt, metres.
MIN_SKIRT_RADIUS = 30_000.0
#: The skirt reaches at least this many terrain widths from the centre.
SKIRT_WIDTHS = 20.0
#: Width of the skirt's first band, as a fraction of the terrain's width: its normal turns up over it.
SKIRT_RAMP = 0.03
#: Rings of the skirt's long band when it carries hills (geometric in radius from the ramp's end to R).
HILL_RINGS = 64
#: Rings of that band when the hills are eroded (:func:`hill_rings`).
ERODED_RINGS = 256
#: Hills up to this height (metres) are smooth unless the config sets ``erosion`` (:func:`default_erosion`) …
SMOOTH_HILLS_M = 300.0
#: … and hills from this height are fully eroded.
ERODED_HILLS_M = 1200.0
#: Octaves of the hills' fractional Brownian motion.
HILL_OCTAVES = 5
#: Finest angle between neighbouring vertices of the hills' rings seen from the terrain's centre where they carry
#: the woods' relief (:func:`skirt_mesh`), radians: 8 192 around, 4 m apart at 5 km.
RELIEF_STEP = 2.0 * np.pi / 8192
#: Coarsest such angle: 1 024 around.
RELIEF_STEP_MAX = 2.0 * np.pi / 1024
#: The relief's angle in pixels of the camera (:func:`relief_step`).
RELIEF_PIXELS = 1.5
#: Purpose tag of the hills' noise (a constant per purpose, CONTRIBUTING's seeding rule).
HILL_TAG = 0x4849_4C4C
#: Bins around the terrain (a whole turn) of the water's share of its edge (:class:`Sea`).
SEA_BINS = 1440
#: Width of each of the two box filters that smooth that share around the terrain, radians (together a
#: triangle window reaching this far each side): hills rise out of the sea over a few degrees, not as walls.
SEA_SMOOTH = float(np.radians(6.0))


@dataclass(frozen=True)
class Hills:
    """Hills on the skirt (module docstring): ``height`` A (metres, the highest), ``scale`` L (metres, the size of
    a hill and the distance over which they rise past the terrain's edge), ``seed`` (their pattern), ``erosion`` (the
    depth of their gullies, 0–1, :mod:`forest.erosion`)."""

    height: float
    scale: float
    seed: int = 0
    erosion: float = 0.0


def hill_field(x: np.ndarray, z: np.ndarray, hills: Hills) -> np.ndarray:
    """h(x/L, z/L) at world points (x, z): value-noise fBm rescaled to [0, 1], then squared; with ``erosion``,
    the gullies of :mod:`forest.erosion` cut into it (then a little outside [0, 1] where they are deepest)."""
    h = _squared_fbm(x, z, hills, HILL_OCTAVES)
    if hills.erosion > 0.0:
        from .erosion import FLOW_OCTAVES, gullies

        def smooth(px: np.ndarray, pz: np.ndarray) -> np.ndarray:
            return _squared_fbm(px, pz, hills, FLOW_OCTAVES)

        h = h + float(hills.erosion) * gullies(x, z, smooth, hills.height, hills.scale, hills.seed)
    return h


def _squared_fbm(x: np.ndarray, z: np.ndarray, hills: Hills, octaves: int) -> np.ndarray:
    """The hills' first ``octaves`` octaves of value-noise fBm, rescaled to [0, 1] and squared."""
    from .scatter.canopy import lattice_at as lattice

    key = np.uint64((int(hills.seed) * 0x9E3779B97F4A7C15 + HILL_TAG) % 2**64)
    u = np.asarray(x, np.float64) / float(hills.scale)
    v = np.asarray(z, np.float64) / float(hills.scale)
    total = np.zeros(np.shape(u))
    amplitude, norm = 1.0, 0.0
    for octave in range(octaves):
        f = 2.0**octave
        # Each octave offset by an irrational shift so that lattice points of the octaves do not line up.
        pu, pv = u * f + 0.618 * octave, v * f + 0.414 * octave
        iu, iv = np.floor(pu), np.floor(pv)
        fu, fv = pu - iu, pv - iv
        su, sv = fu * fu * (3.0 - 2.0 * fu), fv * fv * (3.0 - 2.0 * fv)
        k = np.uint64((int(key) + octave * 0xBF58476D1CE4E5B9) % 2**64)
        a, b = lattice(iu, iv, k), lattice(iu + 1, iv, k)
        c, d = lattice(iu, iv + 1, k), lattice(iu + 1, iv + 1, k)
        total += amplitude * ((a + (b - a) * su) * (1.0 - sv) + (c + (d - c) * su) * sv)
        norm += amplitude
        amplitude *= 0.5
    # fBm of value noise concentrates around ½: stretch its central range to [0, 1] before squaring.
    h = np.clip((total / norm - 0.25) / 0.5, 0.0, 1.0)
    return h * h


def hill_rings(hills: Hills) -> int:
    """Rings of the skirt's long band carrying ``hills``: :data:`HILL_RINGS`, :data:`ERODED_RINGS` with erosion
    (its finest gullies, L/32 apart, need rings closer than the smooth hills do)."""
    return ERODED_RINGS if hills.erosion > 0.0 else HILL_RINGS


def default_erosion(height: float) -> float:
    """The ``erosion`` of hills ``height`` metres high when the config leaves it unset: 0 up to
    :data:`SMOOTH_HILLS_M` (rolling country stays smooth), 1 from :data:`ERODED_HILLS_M` (mountains), linear
    between."""
    t = (float(height) - SMOOTH_HILLS_M) / (ERODED_HILLS_M - SMOOTH_HILLS_M)
    return float(min(max(t, 0.0), 1.0))


def hills(config: Config) -> Hills | None:
    """The config's ``[render] horizon_hills`` as :class:`Hills` (None when unset or 0 m high)."""
    h = config.render.horizon_hills
    if h is None or float(h.height) <= 0.0:
        return None
    erosion = default_erosion(h.height) if h.erosion is None else float(h.erosion)
    return Hills(float(h.height), float(h.scale), int(h.seed), erosion)


@dataclass(frozen=True)
class Sea:
    """Still water at the terrain's edge, carried onto the skirt (module docstring, "The sea"): the water's
    ``level`` and ``shore`` (metres above it kept free of trees, :meth:`forest.terrain.Terrain.dry`), the edge's
    mean height ``land`` (the far plane's height away from the sea), and ``share`` (:data:`SEA_BINS`,) the water's
    smoothed share of the edge in equal bins of angle around ``centre`` (x, z), from −π."""

    level: float
    shore: float
    land: float
    share: np.ndarray
    centre: np.ndarray

    @classmethod
    def at_edge(cls, terrain, boundary: np.ndarray, centre: np.ndarray) -> Sea | None:
        """The sea of ``terrain`` whose ``boundary`` vertices (k, 3) surround ``centre``; None without water or
        when none of them is flooded."""
        from .terrain import SHORE_RAMP

        if getattr(terrain, "water", None) is None:
            return None
        level = float(terrain.water[0])
        wet = np.asarray(boundary, np.float64)[:, 1] <= level + SHORE_RAMP
        if not wet.any():
            return None
        c = np.asarray(centre, np.float64)
        turn = 2.0 * np.pi
        ang = np.arctan2(boundary[:, 2] - c[1], boundary[:, 0] - c[0])
        bins = np.floor((ang + np.pi) / turn * SEA_BINS).astype(np.int64) % SEA_BINS
        count = np.bincount(bins, minlength=SEA_BINS).astype(np.float64)
        share = np.bincount(bins, wet.astype(np.float64), SEA_BINS)
        centres = (np.arange(SEA_BINS) + 0.5) * (turn / SEA_BINS) - np.pi
        held = count > 0
        share = np.interp(centres, centres[held], share[held] / count[held], period=turn)
        half = max(1, int(round(SEA_SMOOTH / 2.0 / (turn / SEA_BINS))))
        for _ in range(2):  # two boxes of 2·half + 1 bins: a triangle window
            padded = np.concatenate([share[-half:], share, share[:half]])
            run = np.concatenate([[0.0], np.cumsum(padded)])
            share = (run[2 * half + 1 :] - run[: -2 * half - 1]) / (2 * half + 1)
        land = float(np.asarray(boundary, np.float64)[:, 1].mean())  # the far plane's height without the sea
        return cls(level, float(terrain.water[1]), land, np.clip(share, 0.0, 1.0), c)

    def weight(self, points: np.ndarray) -> np.ndarray:
        """w ∈ [0, 1] at ``points`` (n, 3): the water's share of the edge toward them, seen from the centre."""
        p = np.asarray(points, np.float64)
        turn = 2.0 * np.pi
        ang = np.arctan2(p[:, 2] - self.centre[1], p[:, 0] - self.centre[0])
        centres = (np.arange(SEA_BINS) + 0.5) * (turn / SEA_BINS) - np.pi
        return np.interp(ang, centres, self.share, period=turn)

    def far_height(self, w: np.ndarray) -> np.ndarray:
        """The far plane's height for columns of sea share ``w``: ȳ_land + w·(level − ȳ_land)."""
        return self.land + np.asarray(w, np.float64) * (self.level - self.land)


def sea_at_edge(terrain) -> Sea | None:
    """The :class:`Sea` the skirt around ``terrain`` carries (module docstring, "The sea"), or None: without
    still water, or when it does not reach the terrain's edge."""
    boundary = _boundary(terrain)
    if boundary is None:
        return None
    used, _, c = boundary
    return Sea.at_edge(terrain, np.asarray(terrain.vertices, np.float64)[used], c)


def wet_faces(vertices: np.ndarray, faces: np.ndarray, level: float) -> np.ndarray:
    """Which ``faces`` of a flooded mesh the water covers by half or more at their centroid (W ≥ ½, that is
    y ≤ level + ``SHORE_RAMP``/2; :func:`forest.ground.water_triangles`' rule for the terrain), bool (F,)."""
    from .terrain import SHORE_RAMP

    y = np.asarray(vertices, np.float64)[np.asarray(faces, np.int64), 1].mean(axis=1)
    return y <= float(level) + 0.5 * SHORE_RAMP


def sea_side(sk: Skirt, level: float, wet: bool) -> Skirt:
    """``sk`` with only the faces still water at ``level`` covers (``wet``) or only the others (:func:`wet_faces`),
    its vertices as they were."""
    keep = wet_faces(sk.vertices, sk.faces, level) == bool(wet)
    return Skirt(sk.vertices, sk.faces[keep], sk.normals)


def skirt_radius(extent, far: float) -> float:
    """R: the camera's far clip, at least :data:`MIN_SKIRT_RADIUS` and :data:`SKIRT_WIDTHS` terrain widths."""
    xmin, zmin, xmax, zmax = (float(v) for v in extent)
    size = max(xmax - xmin, zmax - zmin, 1.0)
    return float(max(far, MIN_SKIRT_RADIUS, SKIRT_WIDTHS * size))


def boundary_edges(faces: np.ndarray) -> np.ndarray:
    """(E, 2) vertex pairs of the edges used by exactly one face, in the direction their face runs them."""
    f = np.asarray(faces, np.int64).reshape(-1, 3)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    lo, hi = np.sort(e, axis=1).T
    # One integer per undirected edge (lo·V + hi): np.unique of a 1-D key, not of (E, 2) rows (10× faster).
    key = lo * (int(f.max()) + 1 if len(f) else 1) + hi
    _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    return e[counts[inverse] == 1]


@dataclass(frozen=True)
class Skirt:
    """The skirt as a mesh: ``vertices`` (V, 3), ``faces`` (F, 3), ``normals`` (V, 3); ``uv`` as set by the caller."""

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    uv: np.ndarray | None = None


def relief_step(fov: float, width: int) -> float:
    """The angle (radians) the woods' relief is sampled at around the terrain for a camera of horizontal ``fov``
    degrees over ``width`` pixels: :data:`RELIEF_PIXELS` pixels, within [:data:`RELIEF_STEP`,
    :data:`RELIEF_STEP_MAX`] — crowns a pixel or two wide on a skyline seen from the terrain."""
    pixel = np.radians(float(fov)) / max(int(width), 1)
    return float(np.clip(RELIEF_PIXELS * pixel, RELIEF_STEP, RELIEF_STEP_MAX))


def skirt_mesh(
    terrain, radius: float, hills: Hills | None = None, woods: FarCover | None = None, step: float = RELIEF_STEP
) -> Skirt | None:
    """The skirt around ``terrain`` (see the module docstring); None for a terrain without a boundary.

    Two bands per boundary edge: a short one (:data:`SKIRT_RAMP` of the terrain's width, level with the edge)
    over which the shading normal turns from the terrain's to +Y, then the long one out to ``radius`` — with
    ``hills``, :func:`hill_rings` rings carrying them, and with ``woods`` (a
    :class:`forest.far_cover.FarCover` of a canopy taller than 0) the woods' relief on those rings, sampled
    every ``step`` radians around the terrain (:func:`relief_step`).  Without ``woods`` it is made once per
    terrain, radius and hills (:func:`_per_terrain`; its arrays read-only): scalar_rgb's land and sea and an
    export's horizon and water ask for the same one.
    """
    if woods is not None:
        return _skirt_mesh(terrain, radius, hills, woods, step)
    return _per_terrain(terrain, ("skirt", float(radius), hills), lambda: _frozen(_skirt_mesh(terrain, radius, hills)))


def _frozen(sk: Skirt | None) -> Skirt | None:
    """``sk`` with read-only arrays (a shared, cached skirt)."""
    if sk is not None:
        for a in (sk.vertices, sk.faces, sk.normals):
            a.setflags(write=False)
    return sk


def _skirt_mesh(
    terrain, radius: float, hills: Hills | None = None, woods: FarCover | None = None, step: float = RELIEF_STEP
) -> Skirt | None:
    """:func:`skirt_mesh` itself."""
    v = np.asarray(terrain.vertices, np.float64)
    boundary = _boundary(terrain)
    if boundary is None:
        return None
    used, (a, b), c = boundary
    xmin, zmin, xmax, zmax = terrain.extent
    inner = v[used]
    rel = inner[:, [0, 2]] - c
    dist = np.maximum(np.linalg.norm(rel, axis=1), 1e-9)
    unit = rel / dist[:, None]
    ramp = max(SKIRT_RAMP * max(xmax - xmin, zmax - zmin), 1.0)
    mid = inner.copy()
    mid[:, [0, 2]] = inner[:, [0, 2]] + unit * ramp
    outer = np.empty_like(inner)
    outer[:, [0, 2]] = c + unit * max(float(radius), float(dist.max()) + 2.0 * ramp)
    sea = Sea.at_edge(terrain, inner, c)
    outer[:, 1] = inner[:, 1].mean() if sea is None else sea.far_height(sea.weight(outer))
    k = len(used)
    if hills is not None and hills.height > 0:
        relief = woods if woods is not None and woods.height > 0.0 else None
        return _hilly_skirt(terrain, hills, (inner, mid, outer), c, (a, b), relief, step, sea)
    faces = np.concatenate(
        [
            np.stack([a, b, b + k], 1),
            np.stack([a, b + k, a + k], 1),
            np.stack([a + k, b + k, b + 2 * k], 1),
            np.stack([a + k, b + 2 * k, a + 2 * k], 1),
        ]
    )
    verts = np.concatenate([inner, mid, outer])
    if sea is not None:
        verts[:, 1] = np.maximum(verts[:, 1], sea.level)
    # Wind every face upward (+Y) whatever the terrain's own winding.
    p0, p1, p2 = (verts[faces[:, i]] for i in range(3))
    down = np.cross(p1 - p0, p2 - p0)[:, 1] < 0
    faces[down] = faces[down][:, [0, 2, 1]]
    up = np.tile([0.0, 1.0, 0.0], (2 * k, 1))
    normals = np.concatenate([np.asarray(terrain.vertex_normals, np.float64)[used], up])
    return Skirt(verts.astype(np.float32), faces.astype(np.uint32), normals.astype(np.float32))


#: What is made once per terrain object (:func:`_per_terrain`): its boundary — the skirt, its triangle count, the
#: sea and the exports all ask for it, and finding it is a sort of every edge (seconds on a 2049² heightmap) —
#: and its skirts without woods.  Weakly keyed: it goes with the terrain.
_PER_TERRAIN: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _per_terrain(terrain, key, make):
    """``make()``, made once per ``terrain`` object and ``key`` (:data:`_PER_TERRAIN`); an object that takes no weak
    reference gets it made each time."""
    try:
        held = _PER_TERRAIN.setdefault(terrain, {})
    except TypeError:
        return make()
    if key not in held:
        held[key] = make()
    return held[key]


def _boundary(terrain) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray], np.ndarray] | None:
    """The terrain's boundary: (its vertices' indices, its edges (a, b) as indices into those, the extent's centre
    (x, z)); None for a terrain without one.  Found once per terrain object (:func:`_per_terrain`)."""
    return _per_terrain(terrain, "boundary", lambda: _find_boundary(terrain))


def _find_boundary(terrain) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray], np.ndarray] | None:
    """:func:`_boundary` itself."""
    edges = boundary_edges(terrain.faces)
    if len(edges) == 0:
        return None
    used = np.unique(edges)
    xmin, zmin, xmax, zmax = terrain.extent
    local = np.searchsorted(used, edges)  # boundary vertex → 0..k-1
    return used, (local[:, 0], local[:, 1]), np.array([(xmin + xmax) / 2.0, (zmin + zmax) / 2.0])


def skirt_triangles(terrain, hills: Hills | None = None, relief: bool = False, step: float = RELIEF_STEP) -> int:
    """How many triangles :func:`skirt_mesh` makes around ``terrain`` (``relief``: with the woods' relief, its
    rings cut every ``step`` radians), counted without building it — for the pre-flight memory estimate:
    4 per boundary edge without hills, E·(s + 1) + 2·E·s·M with them (M = :func:`hill_rings`) (s pieces an edge)."""
    boundary = _boundary(terrain)
    if boundary is None:
        return 0
    used, edges, c = boundary
    e = len(edges[0])
    if hills is None or hills.height <= 0:
        return 4 * e
    s = ring_pieces(np.asarray(terrain.vertices, np.float64)[used], c, edges, step) if relief else 1
    return e * (s + 1) + 2 * e * s * hill_rings(hills)


def ring_pieces(points: np.ndarray, c: np.ndarray, edges: tuple[np.ndarray, np.ndarray], step: float) -> int:
    """The smallest count s of equal pieces that keeps every edge (a, b) of the ring ``points`` within ``step``
    radians seen from ``c`` (1 for an infinite step)."""
    a, b = edges
    ang = np.arctan2(points[:, 2] - c[1], points[:, 0] - c[0])
    turn = np.abs(np.angle(np.exp(1j * (ang[b] - ang[a]))))
    return max(1, int(np.ceil(float(turn.max(initial=0.0)) / step)))


def subdivide_ring(points: np.ndarray, c: np.ndarray, edges: tuple[np.ndarray, np.ndarray], step: float):
    """The ring ``points`` (k, 3) with every edge (a, b) cut into s equal pieces, s the smallest count that keeps
    each piece within ``step`` radians seen from ``c`` (:func:`ring_pieces`): (points (k + E·(s − 1), 3), chains
    (E, s + 1)), each edge's vertices from a to b, its new ones after the first k."""
    a, b = edges
    k, e = len(points), len(a)
    s = ring_pieces(points, c, edges, step)
    t = np.arange(1, s, dtype=np.float64) / s
    new = points[a][:, None, :] + (points[b] - points[a])[:, None, :] * t[None, :, None]  # (E, s−1, 3)
    chains = np.empty((e, s + 1), np.int64)
    chains[:, 0], chains[:, s] = a, b
    chains[:, 1:s] = k + np.arange(e * (s - 1)).reshape(e, s - 1)
    return np.concatenate([points, new.reshape(-1, 3)]), chains


def _hilly_skirt(
    terrain,
    hills: Hills,
    ring_points: tuple[np.ndarray, np.ndarray, np.ndarray],
    c: np.ndarray,
    edge: tuple[np.ndarray, np.ndarray],
    woods: FarCover | None = None,
    step: float = RELIEF_STEP,
    sea: Sea | None = None,
) -> Skirt:
    """The skirt with hills (module docstring): the boundary, the ramp's ring, then :func:`hill_rings` rings
    out to the outer ring's radius; ``edge`` the boundary edges as (a, b) indices into the boundary ring; with
    ``woods``, the ramp's ring and the hills' rings subdivided to ``step`` radians and raised by its relief; with
    ``sea``, sunk to the water's level, hills and relief weighed by 1 − w, and flooded ("The sea")."""
    inner, mid, outer = ring_points
    k = len(inner)
    a, b = edge
    mid, chains = subdivide_ring(mid, c, edge, step if woods is not None else np.inf)
    q, s = len(mid), chains.shape[1] - 1
    rel = mid[:, [0, 2]] - c
    r0 = np.maximum(np.linalg.norm(rel, axis=1), 1e-9)
    unit = rel / r0[:, None]
    r_end = float(np.linalg.norm(outer[0, [0, 2]] - c))
    m = hill_rings(hills)
    t = np.arange(1, m + 1, dtype=np.float64) / m
    radius = r0[None, :] * (r_end / r0[None, :]) ** t[:, None]  # (M, q)
    rings = np.empty((m, q, 3))
    rings[:, :, 0] = c[0] + unit[None, :, 0] * radius
    rings[:, :, 2] = c[1] + unit[None, :, 1] * radius
    level = (radius - r0[None, :]) / np.maximum(r_end - r0[None, :], 1e-9)
    wet = np.zeros(q) if sea is None else sea.weight(mid)  # (q,): each column's sea share w
    dryness = 1.0 - wet
    far_y = outer[0, 1] if sea is None else sea.far_height(wet)[None, :]
    rings[:, :, 1] = mid[None, :, 1] + (far_y - mid[None, :, 1]) * level
    w = np.clip((radius - r0[None, :]) / float(hills.scale), 0.0, 1.0)
    # Point by point, so in blocks of rows on the machine's cores (the same values as one call).
    field = rowwise(lambda px, pz: hill_field(px, pz, hills), rings[:, :, 0].ravel(), rings[:, :, 2].ravel())
    rise = w * w * (3.0 - 2.0 * w) * field.reshape(m, q)
    rings[:, :, 1] += float(hills.height) * (rise if sea is None else rise * dryness[None, :])
    verts = np.concatenate([inner, mid, rings.reshape(-1, 3)])
    if sea is not None:
        verts[:, 1] = np.maximum(verts[:, 1], sea.level)
    land = verts.copy()  # the hills without the woods: their normals shade the skirt (module docstring)
    if woods is not None:
        # Each ring's relief averaged over its spacing from the ring inside it (forest.far_cover, "Prefilter").
        spacing = np.diff(np.concatenate([r0[None, :], radius]), axis=0)  # (M, q)
        far = verts[k + q :]
        relief = rowwise(
            lambda px, pz, f, py: woods.relief(px, pz, f, y=py), far[:, 0], far[:, 2], spacing.ravel(), far[:, 1]
        )
        if sea is not None:  # no woods on the water or its shore, and fewer where the edge is sea
            relief = relief * np.tile(dryness, m) * (far[:, 1] > sea.level + sea.shore)
        verts[k + q :, 1] += relief
    # The ramp's band: each boundary edge (a, b) fans to its chain on the ramp's ring, half from a, half from b.
    half = (s + 1) // 2
    lo, hi = chains[:, :-1] + k, chains[:, 1:] + k
    fan_a = np.stack([np.repeat(a[:, None], half, 1), lo[:, :half], hi[:, :half]], -1).reshape(-1, 3)
    fan_b = np.stack([np.repeat(b[:, None], s - half, 1), lo[:, half:], hi[:, half:]], -1).reshape(-1, 3)
    bands = [fan_a, fan_b, np.stack([a, chains[:, half] + k, b], 1)]
    for j in range(1, m + 1):  # ring j−1 (the ramp's ring for j = 1) to ring j, piece by piece along each chain
        lo, hi = k + (j - 1) * q + chains[:, :-1], k + (j - 1) * q + chains[:, 1:]
        bands += [np.stack([lo, hi, hi + q], -1).reshape(-1, 3), np.stack([lo, hi + q, lo + q], -1).reshape(-1, 3)]
    faces = np.concatenate(bands)
    p0, p1, p2 = (verts[faces[:, i]] for i in range(3))
    down = np.cross(p1 - p0, p2 - p0)[:, 1] < 0
    faces[down] = faces[down][:, [0, 2, 1]]
    normals = vertex_normals(land, faces)  # area-weighted; every face winds upward, so they face +Y
    boundary = _boundary(terrain)
    assert boundary is not None  # skirt_mesh made the rings from it
    normals[:k] = np.asarray(terrain.vertex_normals, np.float64)[boundary[0]]
    normals[k : k + q] = (0.0, 1.0, 0.0)
    return Skirt(verts.astype(np.float32), faces.astype(np.uint32), normals.astype(np.float32))


#: Texels added around an albedo grid by :func:`fade_beyond_edge`, as a share of its longer side (at most
#: :data:`FADE_MAX_TEXELS`).
FADE_SHARE = 0.125
FADE_MAX_TEXELS = 128
#: Texels a side a one-colour grid is repeated to before it fades to another colour.
ONE_COLOUR_TEXELS = 16


def fade_beyond_edge(
    rgb: np.ndarray, extent, far: np.ndarray | Sequence[float] | None = None
) -> tuple[np.ndarray, tuple[float, float, float, float]]:
    """An (H, W, 3) albedo grid padded so that the ground past the terrain's edge fades to ``far``.

    ``far`` is the far landscape's albedo ρ_far (:func:`far_colour`; the module
    docstring); None fades to the grid's mean colour ρ̄.

    A grid looked up with edge clamping repeats its border texels outward, so
    on the skirt every border texel becomes a stripe running to the horizon
    (toward the vanishing point).  This adds P = ⌈FADE_SHARE · max(H, W)⌉
    texels (≤ FADE_MAX_TEXELS) on every side, of the same size as the grid's,
    whose colour blends from the clamped border texel to ρ_far:

        ρ(d) = (1 − s(d/P))·ρ_edge + s(d/P)·ρ_far,    s(t) = t²(3 − 2t)

    with d the distance in texels past the edge; the outermost ring is ρ_far, so
    everything beyond it is one colour.  The grid inside is untouched, and
    the extent grows by P texels on every side.  Returns the grid and its
    extent (xmin, zmin, xmax, zmax).  A one-texel grid (one material) is
    returned as it is when ρ_far is its colour, else first repeated to
    :data:`ONE_COLOUR_TEXELS` texels a side, so that it fades over the same
    share of the terrain's width as any grid (a texel the terrain's size would
    blend the fade into the terrain itself).
    """
    rgb = np.asarray(rgb, np.float32)
    h, w = rgb.shape[:2]
    xmin, zmin, xmax, zmax = (float(v) for v in extent)
    mean = ground_mean(rgb)
    target = mean if far is None else np.asarray(far, np.float32).reshape(mean.shape)
    if h * w <= 1:
        if np.array_equal(target, mean):
            return rgb, (xmin, zmin, xmax, zmax)
        h = w = ONE_COLOUR_TEXELS
        rgb = np.ascontiguousarray(np.broadcast_to(rgb.reshape(1, 1, -1), (h, w, rgb.shape[-1])))
    p = int(min(FADE_MAX_TEXELS, max(2, np.ceil(FADE_SHARE * max(h, w)))))
    padded = np.pad(rgb, ((p, p), (p, p), (0, 0)), mode="edge")
    rows = np.arange(h + 2 * p)
    cols = np.arange(w + 2 * p)
    dr = np.maximum(np.maximum(p - rows, rows - (h + p - 1)), 0)
    dc = np.maximum(np.maximum(p - cols, cols - (w + p - 1)), 0)
    t = np.clip(np.maximum(dr[:, None], dc[None, :]) / p, 0.0, 1.0)
    s = (t * t * (3.0 - 2.0 * t))[..., None]
    out = ((1.0 - s) * padded + s * target).astype(np.float32)
    dx, dz = (xmax - xmin) / w, (zmax - zmin) / h
    return out, (xmin - p * dx, zmin - p * dz, xmax + p * dx, zmax + p * dz)


#: Texels along the terrain's longer side of the canopy-cover grid that :func:`landscape` averages over.
COVER_RESOLUTION = 256
#: Crown cover from which a texel counts as wooded land (the Boolean model's c = 1 − e^(−D) at D = ln 2: the crowns
#: cover half the ground), below it open land (:func:`landscape`).
WOODED = 0.5


def canopy_reflectance(omega: np.ndarray | Sequence[float]) -> np.ndarray:
    """ρ_c = (1 − γ)/(1 + γ), γ = √(1 − ω): the reflectance of a deep canopy of foliage albedo ω (module docstring)."""
    gamma = np.sqrt(1.0 - np.clip(np.asarray(omega, np.float64), 0.0, 1.0))
    return np.asarray((1.0 - gamma) / (1.0 + gamma), np.float64)


def crown_colours(species: Sequence[Species]) -> np.ndarray:
    """(S, 3) float64: the colour each species' tint multiplies (:func:`forest.tint.leaf_colour`), or for a species
    without tinted parts the mean colour of its highest level's parts (grey without parts)."""
    out = np.empty((len(species), 3), np.float64)
    for k, sp in enumerate(species):
        parts = sp.lods[0].parts if sp.lods else ()
        if any(p.tinted for p in parts) or not parts:
            out[k] = leaf_colour(sp)
        else:
            out[k] = np.mean([np.asarray(p.colour, np.float64) for p in parts], axis=0)
    return out


@dataclass(frozen=True)
class Landscape:
    """The far landscape (module docstring): ``far`` ρ_far, ``canopy`` ρ_c (None without trees), ``cover`` ⟨c⟩,
    ``height``, the canopy's height in metres (the trees' heights weighted by crown area, as ρ_c), and its two
    kinds of land: ``wooded`` w̄, the share of the land whose cover is at least :data:`WOODED`, and ``woods`` ρ_w,
    that land's albedo (None without trees; the rest is open land, ρ_far = (1 − w̄)·ρ_open + w̄·ρ_w)."""

    far: np.ndarray
    canopy: np.ndarray | None = None
    cover: float = 0.0
    height: float = 0.0
    woods: np.ndarray | None = None
    wooded: float = 0.0


def landscape(
    ground: np.ndarray,
    extent: Sequence[float],
    instances: InstanceSet,
    species: Sequence[Species],
    tree_species: int,
    tints: np.ndarray,
) -> Landscape:
    """The far landscape of a terrain: ρ_far = ρ̄_g + ⟨c·(ρ_c − ρ_g)⟩, its canopy's ρ_c and mean cover ⟨c⟩.

    ``ground``: the (H, W, 3) albedo grid over ``extent`` (map convention); ``instances``
    with ``species`` per species index, of which the first ``tree_species`` are trees
    (``[[species]]``; the rest ground cover); ``tints`` (N, 3): each row's colour factor
    (``scene.tree_tints()``).
    """
    rgb = np.asarray(ground, np.float32)
    mean = np.asarray(ground_mean(rgb), np.float64)
    sp = np.asarray(instances.species, np.int64)
    trees = np.flatnonzero(sp < tree_species)
    if len(trees) == 0:
        return Landscape(mean)
    ext = (float(extent[0]), float(extent[1]), float(extent[2]), float(extent[3]))
    radii = crown_radii(species)
    area = np.pi * (radii[sp[trees]] * np.asarray(instances.scale, np.float64)[trees]) ** 2
    if not area.sum() > 0.0:
        return Landscape(mean)
    omega = crown_colours(species)[sp[trees]] * np.asarray(tints, np.float64)[trees]
    canopy = canopy_reflectance(area @ omega / area.sum())
    shape = grid_shape(ext, COVER_RESOLUTION)
    cover = canopy_cover(instances, radii, tree_species, ext, shape).reshape(-1, 1)
    x, z = texel_centres(ext, shape)
    u = (x.ravel() - ext[0]) / max(ext[2] - ext[0], 1e-12)
    v = (z.ravel() - ext[1]) / max(ext[3] - ext[1], 1e-12)
    under = np.asarray(sample_bilinear(rgb, u, v), np.float64).reshape(-1, rgb.shape[-1])
    land = under + cover * (canopy - under)  # each texel's albedo seen from afar: crowns over their gaps
    far = np.asarray(mean + (land - under).mean(axis=0), np.float64)
    tall = tree_heights(species)[sp[trees]] * np.asarray(instances.scale, np.float64)[trees]
    height = float(area @ tall / area.sum())
    # The two kinds of land; both take the whole grid's ground mean in place of the samples' (δ), so that
    # (1 − w̄)·ρ_open + w̄·ρ_w = ρ_far exactly.
    wooded = cover[:, 0] >= WOODED
    delta = mean - under.mean(axis=0)
    woods = land[wooded].mean(axis=0) + delta if wooded.any() else np.asarray(canopy, np.float64)
    return Landscape(far, np.asarray(canopy, np.float64), float(cover.mean()), height, woods, float(wooded.mean()))


def tree_heights(species: Sequence[Species]) -> np.ndarray:
    """(S,) metres: the height of each species' highest level at scale 1 (its bounds' Y extent)."""
    out = [float(np.ptp(np.asarray(sp.lods[0].bounds, np.float64).reshape(2, 3)[:, 1])) for sp in species]
    return np.asarray(out, np.float64)


def horizon_albedo(scene: Scene) -> TerrainAlbedo:
    """The Scene's ``terrain_albedo`` with ``far``, its far landscape's albedo, and its wooded land's albedo and
    share behind it (``far_canopy``, ``far_cover``: :func:`landscape` of its trees; :mod:`forest.far_cover`)."""
    albedo = scene.terrain_albedo
    ones = np.ones((len(scene.instances), 3))  # the species' own colours (module docstring)
    land = landscape(albedo.rgb, albedo.extent, scene.instances, scene.species, len(scene.config.species), ones)
    canopy = None if land.woods is None else (float(land.woods[0]), float(land.woods[1]), float(land.woods[2]))
    far = (float(land.far[0]), float(land.far[1]), float(land.far[2]))
    return replace(albedo, far=far, far_canopy=canopy, far_cover=float(land.wooded), far_height=float(land.height))


def far_colour(albedo: TerrainAlbedo) -> np.ndarray:
    """(3,) float32: the albedo the skirt fades to — the albedo's ``far`` (ρ_far), else the grid's mean."""
    far = getattr(albedo, "far", None)  # an albedo-like object without the field: its mean
    return ground_mean(albedo.rgb) if far is None else np.asarray(far, np.float32).reshape(3)


def ground_mean(rgb: np.ndarray) -> np.ndarray:
    """(C,) float32: the mean colour ρ̄ of an (H, W, C) albedo grid, summed in float32 as the fade always did."""
    a = np.asarray(rgb, np.float32)
    return np.asarray(a.reshape(-1, a.shape[-1]).mean(axis=0), np.float32)
