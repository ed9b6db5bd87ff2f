"""Canopy structure: stands and clearings, emergent trees and standing dead trees (snags).

A forest seen from above is not an even blanket: trees grow in stands of
different density with gaps between them (natural disturbance, windthrow,
clearings; Watt 1947, "Pattern and process in the plant community", J. Ecol.
35: 1–22), a few emergents stand above the main canopy, and a few percent of
the stems are dead (snags; 1–5 % of standing stems in managed and natural
temperate forest, Vuidot et al. 2011, Biol. Conserv. 144: 441–450).  Four
seeded, vectorised additions give the scatter that structure:

**Stands and clearings** (``[scatter] clumping = {scale, strength, clearings}``).
A stand field f is fractal Brownian motion of value noise over world X/Z
(Perlin 1985, "An image synthesizer", SIGGRAPH; Musgrave in Ebert et al.,
*Texturing and Modeling*, 3rd ed. 2003, ch. 16):

    f(x) = Σ_{o<3} 2^{−o} V(2^o x / λ),   V = value noise on the unit lattice,

V interpolating SplitMix64 hashes of the lattice points (seeded by
``SeedSequence([seed, CLUMP_TAG])``, anchored to the world so it does not
depend on the terrain's resolution) with Perlin's quintic fade
6t⁵ − 15t⁴ + 10t³ (Perlin 2002, "Improving noise", SIGGRAPH).  f is evaluated
on a grid over the terrain's X/Z extent (spacing ≤ λ/8) and replaced by its
*area rank* U(x) = P(f ≤ f(x)) over that grid, so U is uniform in [0, 1] over
the terrain's plan area whatever the noise's distribution; trees are then kept
with probability

    p(x) = smoothstep(c, c + c/2, U) · min(1, 1 − s + 2 s U)

(c = ``clearings``, s = ``strength``, smoothstep(a, b, t) the cubic Hermite
step from 0 at a to 1 at b) — a share c of the area is bare, its edges fade
in over a ring of another c/2 of the area, the lower half of the rest thins
towards 1 − s and the upper half (the dense stands) keeps every candidate.
For c = 0 the expected share of candidates kept is 1 − s/4 (0.875 at the
default s = ½); with c > 0 it is slightly less.  p multiplies the density
map's value, so it is one more factor of the ``density`` stage.  With s = 0
and c = 0 nothing is drawn or changed.

**Emergents** (``[scatter] emergents = {fraction, scale}``).  A share φ of the
trees has its scale multiplied by a factor uniform in [a, b]: the scale
distribution becomes the species' uniform range with a tail reaching b times
its top (a mixture, not a lognormal, so the main canopy keeps the artist's
range exactly).  Draws come from the ``emergent`` candidate stream
(:data:`forest.scatter.candidates.STREAMS`): ξ₁ < φ selects, a + (b − a)·ξ₂
is the factor.

**Edge taper** (``[scatter] edge_taper = {width, scale}``, off by default).
A forest edge is not a wall of full-grown trees: along it the canopy steps
down through smaller trees and shrubs (the edge's mantle; edge influence on
structure reaches tens of metres into a stand, Harper et al. 2005, "Edge
influence on forest structure and composition in fragmented landscapes",
Conserv. Biol. 19: 768–782).  Each tree's scale is multiplied by

    g(d) = a + (1 − a) · smoothstep(0, W, d)

with d the signed distance from the tree to the presence map's edge
(positive inside, :meth:`forest.maps.MapSet.edge_distance`), W = ``width``
and a = ``scale``: a tree on the edge (or outside it, where a soft presence
map let it grow) is a times its drawn size, one W inside is full size.  The
draws are not touched, so each tree keeps its own place in the species'
range and the taper only lowers the edge's envelope.

**Species in groups** (``[scatter] grouping = {strength, scale}``, off by default).  Drawn independently,
the species of a mixed forest are evenly salted through it; real ones stand in groups and patches of
one species — a clump of spruce, a birch grove — whose colours and shapes break a canopy into
pieces (species patchiness at the scale of tens of metres: Pielou 1961, "Segregation and symmetry in
two-species populations as studied by nearest-neighbor relationships", J. Ecol. 49: 255–269).  The
species draw ξ_s (the ``species`` stream) is replaced by

    ξ'_s = Φ(√m · Φ⁻¹(π(U_g(x))) + √(1 − m) · Φ⁻¹(ξ_s))

with U_g the area rank of a stand field of its own (wavelength λ = ``scale``, stream
:data:`GROUP_TAG`), π a seeded permutation of :data:`GROUP_INTERVALS` equal intervals of [0, 1]
(so that which species border which is random, not the order of ``[[species]]``), m = ``strength``
and Φ the standard normal distribution function (a Gaussian copula): both terms are standard
normal, so ξ'_s is uniform whatever m — every species keeps its ``percent`` — while at m → 1 a
species fills whole patches of the field and at m = 0 the draw is ξ_s itself (nothing is changed).

**Snags** (``[[species]] dead``).  A share of each leafy species' trees is
drawn from the ``dead`` stream; such a tree's ``individual`` is n + k, n the
species' individual count and k its individual, and the Scene's individuals
of the species are n living trees followed by their n snags
(:func:`snag` — the same levels of detail without their leaf parts; a level
made only of leaves, the far card, takes the bark of the nearest level that
has some).  A species without leaf parts (a building, a leafless mesh) gets no
snags whatever ``dead`` says.
"""

from __future__ import annotations

import dataclasses
import hashlib
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, TypeVar

import numpy as np

from ..parallel import rowwise
from ..tint import splitmix64

if TYPE_CHECKING:
    from ..config.schema import Clumping, EdgeTaper, Emergents, Grouping
    from ..library import Species

_T = TypeVar("_T")
CLUMP_TAG = 0xC1A3B5
#: Purpose tag of the species groups' stand field and permutation (``[scatter] grouping``).
GROUP_TAG = 0x62A0F5
#: Equal intervals of the groups' field permuted so that neighbouring patches get unrelated species.
GROUP_INTERVALS = 16
OCTAVES = 3
MAX_GRID = 1024  # grid cells per side of the stand field at most


def fade(t: np.ndarray) -> np.ndarray:
    """Perlin's quintic fade 6t⁵ − 15t⁴ + 10t³ (zero first and second derivatives at 0 and 1)."""
    return t * t * t * (t * (t * 6.0 - 15.0) + 10.0)


def smoothstep(a: float, b: float, t: np.ndarray) -> np.ndarray:
    """The cubic Hermite step: 0 for t ≤ a, 1 for t ≥ b, 3x² − 2x³ in between (x = (t − a)/(b − a))."""
    if b <= a:
        return (t > a).astype(np.float64)
    x = np.clip((t - a) / (b - a), 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def lattice(ix: np.ndarray, iz: np.ndarray, key: np.uint64) -> np.ndarray:
    """Value noise's lattice values in [0, 1): a SplitMix64 hash of the integer point (ix, iz) and ``key``."""
    with np.errstate(over="ignore"):
        h = (ix.astype(np.int64).view(np.uint64) * np.uint64(0x9E3779B1)) ^ iz.astype(np.int64).view(np.uint64)
        h = splitmix64(splitmix64(h + key))
    return (h >> np.uint64(11)).astype(np.float64) * 2.0**-53


def lattice_at(ix: np.ndarray, iz: np.ndarray, key: np.uint64) -> np.ndarray:
    """:func:`lattice` at many integer points (given as floats or ints of one shape): the same values, hashed once
    per lattice point of their bounding box and gathered when that box holds fewer points than are asked for (the
    corners of noise cells shared by many samples), else hashed per point."""
    ix = np.asarray(ix)
    iz = np.asarray(iz)
    if ix.size == 0:
        return np.zeros(ix.shape)
    lo_x, hi_x = int(ix.min()), int(ix.max())
    lo_z, hi_z = int(iz.min()), int(iz.max())
    box = (hi_x - lo_x + 1) * (hi_z - lo_z + 1)
    if box >= ix.size:
        return lattice(ix, iz, key)
    table = lattice(
        np.arange(lo_x, hi_x + 1, dtype=np.int64)[None, :], np.arange(lo_z, hi_z + 1, dtype=np.int64)[:, None], key
    )
    return table[iz.astype(np.int64) - lo_z, ix.astype(np.int64) - lo_x]


def value_noise(x: np.ndarray, z: np.ndarray, key: np.uint64) -> np.ndarray:
    """Value noise V on the unit lattice at points (x, z) given as a separable grid (x (W,), z (D,)): (D, W)."""
    x0, z0 = np.floor(x), np.floor(z)
    fx, fz = fade(x - x0), fade(z - z0)
    ix, iz = x0.astype(np.int64), z0.astype(np.int64)
    lo, hi = ix.min(), ix.max() + 1
    zl, zh = iz.min(), iz.max() + 1
    gx, gz = np.arange(lo, hi + 1), np.arange(zl, zh + 1)
    table = lattice(gx[None, :], gz[:, None], key)  # (nz, nx) lattice values
    jx, jz = ix - lo, iz - zl
    a = table[jz[:, None], jx[None, :]]
    b = table[jz[:, None], jx[None, :] + 1]
    c = table[jz[:, None] + 1, jx[None, :]]
    d = table[jz[:, None] + 1, jx[None, :] + 1]
    top = a + (b - a) * fx[None, :]
    bottom = c + (d - c) * fx[None, :]
    return top + (bottom - top) * fz[:, None]


@dataclass(frozen=True)
class StandField:
    """The stand field's area rank U on a grid over the terrain's X/Z extent (module docstring)."""

    rank: np.ndarray  # (D, W) float64 in [0, 1]
    x0: float
    z0: float
    step: float

    def at(self, x: np.ndarray, z: np.ndarray) -> np.ndarray:
        """U at world points (x, z): bilinear in the grid, clamped at its edges (float32 arithmetic)."""
        d, w = self.rank.shape
        r = np.pad(self.rank.astype(np.float32), ((0, 1), (0, 1)), mode="edge").ravel()  # a guard row and column
        gx = np.clip((np.asarray(x, np.float32) - np.float32(self.x0)) / np.float32(self.step), 0, w - 1)
        gz = np.clip((np.asarray(z, np.float32) - np.float32(self.z0)) / np.float32(self.step), 0, d - 1)
        ix, iz = gx.astype(np.int32), gz.astype(np.int32)
        fx, fz = gx - ix, gz - iz
        i = iz * np.int32(w + 1) + ix
        a, b = r.take(i), r.take(i + 1)
        c, e = r.take(i + (w + 1)), r.take(i + (w + 2))
        top = a + (b - a) * fx
        return (top + (c + (e - c) * fx - top) * fz).astype(np.float64)


def stand_field(extent: Sequence[float], scale: float, seed: int, stream: Sequence[int] = ()) -> StandField:
    """The area-ranked fBm stand field over ``extent`` = (xmin, zmin, xmax, zmax) at wavelength ``scale`` metres.

    The lattice is seeded by ``SeedSequence([seed, CLUMP_TAG, *stream])``: the trees' stands use no
    ``stream``; another user of the field (ground cover's patches) passes its own so its noise is independent.
    """
    xmin, zmin, xmax, zmax = (float(e) for e in extent)
    side = max(xmax - xmin, zmax - zmin, 1e-9)
    step = max(scale / 8.0, side / MAX_GRID)
    x = xmin + step * np.arange(int(np.ceil((xmax - xmin) / step)) + 1)
    z = zmin + step * np.arange(int(np.ceil((zmax - zmin) / step)) + 1)
    keys = np.random.SeedSequence([seed, CLUMP_TAG, *stream]).generate_state(OCTAVES, np.uint64)
    f = np.zeros((len(z), len(x)))
    for o in range(OCTAVES):
        k = 2.0**o / scale
        f += 0.5**o * value_noise(x * k, z * k, keys[o])
    flat = f.ravel()
    rank = np.empty(flat.size)
    rank[np.argsort(flat, kind="stable")] = (np.arange(flat.size) + 0.5) / flat.size
    return StandField(rank.reshape(f.shape), xmin, zmin, step)


def stand_keep(u: np.ndarray, strength: float, clearings: float) -> np.ndarray:
    """p(U) = smoothstep(c, 1.5c, U) · min(1, 1 − s + 2sU): the probability of keeping a candidate at area rank U."""
    u = np.asarray(u, np.float64)
    p = np.minimum(1.0, 1.0 - strength + 2.0 * strength * u)
    if clearings > 0:
        p = p * smoothstep(clearings, 1.5 * clearings, u)
    return p


def clumping_on(c: Clumping) -> bool:
    """Whether ``[scatter] clumping`` changes anything (strength or clearings > 0)."""
    return c.strength > 0 or c.clearings > 0


def clumping_density(c: Clumping, extent: Sequence[float], seed: int, x: np.ndarray, z: np.ndarray) -> np.ndarray:
    """The stand factor p(x) at world points (x, z) for ``[scatter] clumping`` ``c`` and the scene's seed."""
    field = stand_field(extent, c.scale, seed)
    return rowwise(lambda xs, zs: stand_keep(field.at(xs, zs), c.strength, c.clearings), np.asarray(x), np.asarray(z))


def grouping_on(g: Grouping) -> bool:
    """Whether ``[scatter] grouping`` changes anything (strength > 0)."""
    return g.strength > 0


def grouped_draw(
    g: Grouping, extent: Sequence[float], seed: int, x: np.ndarray, z: np.ndarray, xi: np.ndarray
) -> np.ndarray:
    """The species draws ``xi`` at world points (x, z) coupled to the groups' field (module docstring, "Species in
    groups"): ξ' = Φ(√m Φ⁻¹(π(U)) + √(1 − m) Φ⁻¹(ξ)), uniform in (0, 1) like ξ."""
    from scipy.special import ndtr, ndtri

    field = stand_field(extent, g.scale, seed, (GROUP_TAG,))
    order = np.random.Generator(np.random.PCG64(np.random.SeedSequence([seed, GROUP_TAG]))).permutation(GROUP_INTERVALS)
    u = np.clip(field.at(np.asarray(x), np.asarray(z)), 0.0, 1.0) * GROUP_INTERVALS
    cell = np.minimum(u.astype(np.int64), GROUP_INTERVALS - 1)
    pu = (order[cell] + (u - cell)) / GROUP_INTERVALS
    eps = 1e-12
    m = float(g.strength)
    w = np.sqrt(m) * ndtri(np.clip(pu, eps, 1 - eps)) + np.sqrt(1.0 - m) * ndtri(np.clip(xi, eps, 1 - eps))
    return np.asarray(ndtr(w), np.float64)


def emergent_factors(e: Emergents, xi: np.ndarray) -> np.ndarray:
    """Scale factors from uniforms ``xi`` (2, N): a + (b − a)·ξ₂ where ξ₁ < fraction, else 1."""
    lo, hi = e.scale
    return np.where(xi[0] < e.fraction, lo + (hi - lo) * xi[1], 1.0)


def edge_taper_factors(taper: EdgeTaper, distance: np.ndarray) -> np.ndarray:
    """Scale factors g(d) = a + (1 − a)·smoothstep(0, W, d) at signed distances ``d`` (metres, positive inside)
    from the presence map's edge: ``taper.scale`` on and outside the edge, 1 from ``taper.width`` inside."""
    a = float(taper.scale)
    return a + (1.0 - a) * smoothstep(0.0, float(taper.width), np.asarray(distance, np.float64))


def has_leaves(species: Species) -> bool:
    """Whether any level of the species has a leaf part (only such a species can stand dead)."""
    return any(p.kind == "leaf" for lod in species.lods for p in lod.parts)


def dead_fractions(dead: Sequence[float], species: Sequence[Species]) -> np.ndarray:
    """Per ``[[species]]`` the share of snags: ``dead`` where the library species has leaves, else 0."""
    return np.array([d if has_leaves(sp) else 0.0 for d, sp in zip(dead, species)], dtype=np.float64)


def snag(species: Species) -> Species:
    """The species' dead tree: every level without its leaf parts (a leaves-only level: the bark of the nearest).

    Bounds and triangle counts are those of the parts kept; the name gains " (snag)" and the hash
    is derived from the living tree's, so caches keyed by hash never mix the two.  A species that is
    not a dataclass (a stand-in) is returned as it is.
    """
    if not dataclasses.is_dataclass(species) or not all(dataclasses.is_dataclass(lod) for lod in species.lods):
        return species  # a stand-in species (tests, plug-ins): nothing to strip
    bare = [tuple(p for p in lod.parts if p.kind != "leaf") for lod in species.lods]
    lods = []
    for i, lod in enumerate(species.lods):
        parts = bare[i]
        if not parts:
            near = [j for j in range(len(bare)) if bare[j]]
            if not near:
                return species
            parts = bare[min(near, key=lambda j: (abs(j - i), -j))]
        boxes = [np.asarray(b) for b in (getattr(p, "bounds", None) for p in parts) if b is not None]
        bounds = (
            np.array([np.min([b[0] for b in boxes], axis=0), np.max([b[1] for b in boxes], axis=0)])
            if len(boxes) == len(parts)
            else lod.bounds
        )
        triangles = sum(int(getattr(p, "triangles", 0)) for p in parts)
        lods.append(_replace(lod, parts=parts, triangles=triangles, bounds=bounds))
    digest = hashlib.sha256(f"{getattr(species, 'hash', species.name)}:snag".encode()).hexdigest()
    return _replace(species, name=f"{species.name} (snag)", lods=lods, hash=digest)


def _replace(obj: _T, **changes: object) -> _T:
    """``dataclasses.replace`` with only the changes ``obj`` has fields for."""
    names = {f.name for f in dataclasses.fields(obj)}  # type: ignore[arg-type]
    return dataclasses.replace(obj, **{k: v for k, v in changes.items() if k in names})  # type: ignore[type-var]
