"""Per-tree tint: the colour map's tint around each species' leaf colour, with a per-tree colour jitter.

A tree ``i`` of species ``s`` standing at ``x_i`` gets the tint

    t_i = J_i(c_s ⊙ m(x_i)) ⊘ c_s

where ``c_s`` is the species' leaf colour (linear sRGB albedo, :func:`leaf_colour`),
``m`` the colour map as a tint of mean 1 (:func:`forest.maps.colour_tint_grid`,
1 without a map) and ``J_i`` the tree's jitter: in Oklab (Ottosson 2020, "A
perceptual color space for image processing", https://bottosson.github.io/posts/oklab/)
the colour's OkLCh hue h is rotated by Δh_i and its lightness L scaled by
(1 + Δv_i), chroma kept:

    (L, a, b) → (L·(1 + Δv_i), a cos Δh_i − b sin Δh_i, a sin Δh_i + b cos Δh_i)

with Δh_i = hue_s·ξ_i,1 (degrees) and Δv_i = value_s·ξ_i,2, ξ uniform in [−1, 1]
(``[[species]] colour_jitter = { hue, value }``).  A renderer multiplies every
*tinted* part's colour by t_i, so the tree's leaves show exactly J_i(c_s ⊙ m);
a species whose tinted parts differ in colour gets the same factor on each
(exact for the lightness scale, which is a per-channel factor in linear RGB
— Oklab's L is the cube root of a linear mix, so scaling L by k scales linear
RGB of a grey by k³ — and close for small hue angles).

**Accents** (``[[species]] accents``).  A share of a species' trees turns toward another
colour: crowns flushing red or bronze new leaves and flowering yellow in a tropical canopy
(young leaves of many tropical trees are red with anthocyanins: Lee & Collins 2001, "Phylogenetic
and ontogenetic influences on the distribution of anthocyanins and betacyanins in leaves of
tropical plants", *Int. J. Plant Sci.* 162), yellowing or beetle-killed brown crowns among summer
conifers, whole autumn crowns.  Accent k of species s has a share σ_sk, a colour a_sk and a
range of amounts [w_lo, w_hi]; a tree draws u_1, u_2 uniform in [0, 1) (its own hash, tag
:data:`ACCENT_TAG`) and carries accent k when Σ_{j<k} σ_sj ≤ u_1 < Σ_{j≤k} σ_sj, mixed by
w_i = w_lo + (w_hi − w_lo)·u_2 in Oklab before its jitter:

    t_i = J_i(mix(c_s ⊙ m(x_i), a_sk, w_i)) ⊘ c_s,   mix(x, y, w) = Lab⁻¹((1 − w)·Lab(x) + w·Lab(y))

so w = 1 is the accent itself (jittered like any tree), and the accented trees keep the
species' spread.  An accent of ``clustering`` c > 0 gathers its trees in patches: its share at a
tree standing at x becomes σ_sk·((1 − c) + c·(γ + 1)·U(x)^γ), U the area-ranked fBm stand field of
:func:`forest.scatter.canopy.stand_field` at wavelength ``patch_scale`` (uniform over the
terrain's area, its own stream per species and accent) and γ = :data:`PATCH_GAMMA`; the factor's
mean over the terrain is 1 ((γ + 1)·E[U^γ] = 1), so the share is kept while a fifth of the area
holds most of the accented trees (the shares at a tree are capped to add up to 1).  A species
without accents gets the same tints, to the bit, as before accents existed (the jitter's uniforms
are drawn for the same rows from the same hash).

ξ is a hash of the tree's id and the scene's seed (SplitMix64, Steele, Lea &
Flood 2014, "Fast splittable pseudorandom number generators", OOPSLA), not a
draw from a stream: a tree keeps its jitter whatever else is scattered, saved
or subset, and the Scene can recompute it from the InstanceSet alone.  Rows
whose species has no jitter (hue = value = 0) get the map's tint unchanged.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from .parallel import rowwise

if TYPE_CHECKING:
    from .config.schema import BarkLook, ColourJitter
    from .library import Species

JITTER_TAG = 0x7177E5
ACCENT_TAG = 0xACC3
#: The exponent γ of a clustered accent's patches (module docstring, "Accents"): the top fifth of the area by
#: U holds 1 − 0.8^(γ+1) = 67 % of the accented trees at γ = 4.
PATCH_GAMMA = 4.0
BARK_TAG = 0xBA2C
GREY = (0.18, 0.18, 0.18)  # the base of a species with no tinted part (its tint multiplies nothing)
_GAMMA = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)


def splitmix64(x: np.ndarray) -> np.ndarray:
    """SplitMix64's output function over uint64 ``x`` (the state after adding the golden gamma)."""
    with np.errstate(over="ignore"):
        z = np.asarray(x, dtype=np.uint64) + _GAMMA
        z = (z ^ (z >> np.uint64(30))) * _M1
        z = (z ^ (z >> np.uint64(27))) * _M2
        return z ^ (z >> np.uint64(31))


def tree_uniforms(ids: np.ndarray, seed: int, tag: int, count: int) -> np.ndarray:
    """``(N, count)`` uniforms in [0, 1), a pure function of (tree id, seed, tag): 53-bit SplitMix64 hashes.

    The key comes from ``SeedSequence([seed, tag])`` (the project's convention for
    seeding); value j of tree id is ``splitmix64(key + id·count + j) / 2⁶⁴``.
    """
    key = np.random.SeedSequence([seed, tag]).generate_state(1, np.uint64)[0]
    ids = np.asarray(ids, dtype=np.uint64)
    with np.errstate(over="ignore"):
        x = ids[:, None] * np.uint64(count) + np.arange(count, dtype=np.uint64)[None, :] + key
    return (splitmix64(x) >> np.uint64(11)).astype(np.float64) * 2.0**-53


#: Linear sRGB → LMS: Oklab's M₁ (XYZ → LMS) times the sRGB primaries' RGB → XYZ (D65), as colour-science
#: defines both (``colour.models.oklab.MATRIX_1_XYZ_TO_LMS``, ``RGB_COLOURSPACE_sRGB.matrix_RGB_to_XYZ``), kept
#: here to the bit so a scatter need not import colour-science (1–3 s a command); a test recomputes them.
SRGB_TO_LMS = np.array(
    [
        [0.41217385032507, 0.5362974607032, 0.05146302925248],
        [0.21187214048845002, 0.6807476834212001, 0.10740645682645002],
        [0.08831541121808, 0.2818663070584, 0.6302634466074201],
    ]
)
#: Oklab's M₂ (LMS′ → Lab), colour-science's ``MATRIX_2_LMS_TO_LAB``, likewise.
LMS_TO_LAB = np.array(
    [
        [0.2104542553, 0.793617785, -0.0040720468],
        [1.9779984951, -2.428592205, 0.4505937099],
        [0.0259040371, 0.7827717662, -0.808675766],
    ]
)


def _oklab_matrices() -> tuple[np.ndarray, np.ndarray]:
    """Linear sRGB → LMS and Oklab's LMS′ → Lab (:data:`SRGB_TO_LMS`, :data:`LMS_TO_LAB`)."""
    return SRGB_TO_LMS, LMS_TO_LAB


def oklab(rgb: np.ndarray) -> np.ndarray:
    """Linear sRGB rows (N, 3) → Oklab (N, 3): Lab = M₂ · ∛(M₁ · XYZ) (:func:`jitter_colours`'s matrices)."""
    to_lms, to_lab = _oklab_matrices()
    return _rows(to_lab, np.cbrt(_rows(to_lms, np.asarray(rgb, np.float64).reshape(-1, 3))))


def jitter_colours(rgb: np.ndarray, hue_deg: np.ndarray, value: np.ndarray) -> np.ndarray:
    """Rotate OkLCh hue by ``hue_deg`` and scale Oklab lightness by ``1 + value``, row-wise: linear sRGB in and out.

    Oklab is Lab = M₂ · ∛(M₁ · XYZ) with colour-science's M₁, M₂ and XYZ = M_sRGB · RGB
    (D65, the white of both); the two linear steps are folded into one matrix so a
    million colours take a few matrix products rather than colour-science's
    general per-call machinery.  Results outside the gamut are clipped at 0.
    """
    lab = oklab(rgb)
    h = np.radians(np.asarray(hue_deg, np.float64))
    c, s = np.cos(h), np.sin(h)
    a, b = lab[:, 1].copy(), lab[:, 2].copy()
    lab[:, 0] *= 1.0 + np.asarray(value, np.float64)
    lab[:, 1] = a * c - b * s
    lab[:, 2] = a * s + b * c
    return from_oklab(lab)


def from_oklab(lab: np.ndarray) -> np.ndarray:
    """Oklab rows (N, 3) → linear sRGB (N, 3), the inverse of :func:`oklab`; results outside the gamut clipped at 0."""
    to_lms, to_lab = _oklab_matrices()
    lms = _rows(np.linalg.inv(to_lab), np.asarray(lab, np.float64).reshape(-1, 3)) ** 3
    return np.maximum(_rows(np.linalg.inv(to_lms), lms), 0.0)


def mix_oklab(x: np.ndarray, y: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Linear sRGB rows ``x`` mixed toward ``y`` (N, 3) by ``w`` (N,) in Oklab: Lab⁻¹((1 − w)·Lab(x) + w·Lab(y))."""
    w = np.asarray(w, np.float64).reshape(-1, 1)
    return from_oklab((1.0 - w) * oklab(x) + w * oklab(y))


def _rows(m: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``m · x_n`` for every row of ``x`` (N, 3) (einsum: several times faster than BLAS for 3×3)."""
    return np.einsum("ij,nj->ni", m, x)


def first_part_colour(species: Species, kind: str | None = None) -> tuple[float, float, float] | None:
    """The colour of the first part of the species' highest level that is tinted (``kind`` None) or of that
    ``kind``; None if there is none."""
    for lod in species.lods[:1]:
        for part in lod.parts:
            if part.tinted if kind is None else getattr(part, "kind", "") == kind:
                r, g, b = (float(x) for x in part.colour)
                return (r, g, b)
    return None


def leaf_colour(species: Species) -> tuple[float, float, float]:
    """The colour the tint multiplies: the first tinted part of the species' highest level (grey if none)."""
    return first_part_colour(species) or GREY


def tree_tints(
    map_tint: np.ndarray,
    species: np.ndarray,
    ids: np.ndarray,
    seed: int,
    base: np.ndarray,
    hue: Sequence[float] | np.ndarray,
    value: Sequence[float] | np.ndarray,
    accents: Accents | None = None,
    where: Where | None = None,
) -> np.ndarray:
    """Every tree's tint t_i = J_i(mix(c_s ⊙ m_i, a_sk, w_i)) ⊘ c_s (module docstring): ``(N, 3)`` float32.

    ``map_tint`` (N, 3) the colour map's tint at each tree, ``species`` (N,)
    species indices, ``ids`` (N,) tree ids, ``base`` (S, 3) each species' leaf
    colour c_s, ``hue`` / ``value`` (S,) each species' jitter amplitudes,
    ``accents`` each species' accents (None: none), ``where`` the trees' places (needed by clustered accents).
    """
    tint = np.array(map_tint, dtype=np.float32, copy=True).reshape(-1, 3)
    k = np.asarray(species, dtype=np.int64)
    hue = np.asarray(hue, dtype=np.float64)
    value = np.asarray(value, dtype=np.float64)
    acc = accents if accents is not None and accents.any else None
    varies = (hue > 0) | (value > 0)
    if acc is not None:
        varies = varies | (acc.share.sum(axis=1) > 0)
    rows = np.flatnonzero(varies[k]) if len(k) else np.zeros(0, np.int64)
    if len(rows) == 0:
        return tint
    xi = 2.0 * tree_uniforms(np.asarray(ids)[rows], seed, JITTER_TAG, 2) - 1.0
    c = np.maximum(np.asarray(base, dtype=np.float64)[k[rows]], 1e-6)
    leaf = c * tint[rows]
    if acc is not None:
        leaf = acc.apply(leaf, k[rows], np.asarray(ids)[rows], seed, None if where is None else where.rows(rows))
    out = rowwise(jitter_colours, leaf, hue[k[rows]] * xi[:, 0], value[k[rows]] * xi[:, 1])
    tint[rows] = (out / c).astype(np.float32)
    return tint


@dataclass(frozen=True)
class Where:
    """Where the trees stand, for clustered accents: their world X and Z (N,) and the terrain's extent."""

    x: np.ndarray
    z: np.ndarray
    extent: tuple[float, float, float, float]

    @classmethod
    def of(cls, position: np.ndarray, extent: Sequence[float]) -> Where:
        """From (N, 3) positions (Y up) and (xmin, zmin, xmax, zmax)."""
        p = np.asarray(position)
        xmin, zmin, xmax, zmax = (float(v) for v in extent)
        return cls(p[:, 0], p[:, 2], (xmin, zmin, xmax, zmax))

    def rows(self, rows: np.ndarray) -> Where:
        """These trees only."""
        return Where(self.x[rows], self.z[rows], self.extent)


@dataclass(frozen=True)
class Accents:
    """Each species' colour accents (module docstring, "Accents"), padded to A per species with share 0."""

    share: np.ndarray  # (S, A) σ_sk
    colour: np.ndarray  # (S, A, 3) a_sk, linear sRGB
    amount: np.ndarray  # (S, A, 2) [w_lo, w_hi]
    clustering: np.ndarray | None = None  # (S, A) c, None for all 0
    scale: np.ndarray | None = None  # (S, A) the patches' wavelength, metres

    @property
    def any(self) -> bool:
        """Whether any species has an accent with a share above 0."""
        return bool(self.share.size and self.share.max() > 0)

    def shares(self, species: np.ndarray, seed: int, where: Where | None = None) -> np.ndarray:
        """(N, A): each tree's share of each accent of its species — σ_sk, or for a clustered accent σ_sk times
        its patches' factor at the tree (module docstring), capped to add up to 1."""
        s = np.asarray(species, np.int64)
        p = self.share[s].copy()
        if self.clustering is None or not (self.clustering > 0).any():
            return p
        if where is None:
            raise ValueError("clustered accents need the trees' places")
        from .scatter.canopy import stand_field

        for sp, k in zip(*np.nonzero(self.clustering > 0)):
            rows = np.flatnonzero(s == sp)
            if not len(rows):
                continue
            assert self.scale is not None
            field = stand_field(where.extent, float(self.scale[sp, k]), seed, (ACCENT_TAG, int(sp), int(k)))
            u = field.at(where.x[rows], where.z[rows])
            c = float(self.clustering[sp, k])
            p[rows, k] *= (1.0 - c) + c * (PATCH_GAMMA + 1.0) * u**PATCH_GAMMA
        total = p.sum(axis=1, keepdims=True)
        return np.where(total > 1.0, p / np.maximum(total, 1e-12), p)

    def draw(
        self, species: np.ndarray, ids: np.ndarray, seed: int, where: Where | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """(accent index k per tree, −1 for none; its weight w_i): the module docstring's draw."""
        s = np.asarray(species, np.int64)
        u = tree_uniforms(np.asarray(ids), seed, ACCENT_TAG, 2)
        cum = np.cumsum(self.shares(s, seed, where), axis=1)
        k = np.sum(u[:, :1] >= cum, axis=1)
        k = np.where(k < self.share.shape[1], k, -1)
        lo_hi = self.amount[s, np.maximum(k, 0)]
        w = lo_hi[:, 0] + (lo_hi[:, 1] - lo_hi[:, 0]) * u[:, 1]
        return k, np.where(k >= 0, w, 0.0)

    def apply(
        self, leaf: np.ndarray, species: np.ndarray, ids: np.ndarray, seed: int, where: Where | None = None
    ) -> np.ndarray:
        """``leaf`` (N, 3) linear colours with each accented tree's mixed toward its accent (others unchanged)."""
        s = np.asarray(species, np.int64)
        k, w = self.draw(s, ids, seed, where)
        out = np.array(leaf, np.float64, copy=True)
        hit = np.flatnonzero(k >= 0)
        if len(hit):
            out[hit] = mix_oklab(out[hit], self.colour[s[hit], k[hit]], w[hit])
        return out


class _Accented(Protocol):
    @property
    def accents(self) -> Sequence[Any]: ...


def accent_table(settings: Sequence[_Accented]) -> Accents:
    """The :class:`Accents` of ``settings[s].accents`` (``[[species]]`` / ``[[ground_cover]]`` ``accents``)."""
    n = max([len(s.accents) for s in settings] + [1])
    share = np.zeros((len(settings), n))
    colour = np.zeros((len(settings), n, 3))
    amount = np.ones((len(settings), n, 2))
    clustering = np.zeros((len(settings), n))
    scale = np.ones((len(settings), n))
    for i, s in enumerate(settings):
        for j, a in enumerate(s.accents):
            share[i, j], colour[i, j], amount[i, j] = a.share, a.colour, a.amount
            clustering[i, j], scale[i, j] = a.clustering, a.patch_scale
    clustered = clustering if (clustering > 0).any() else None
    return Accents(share=share, colour=colour, amount=amount, clustering=clustered, scale=scale)


@dataclass(frozen=True)
class TintParams:
    """What :func:`tree_tints` needs besides the trees: per species index its leaf colour, jitter and accents, and
    the seed."""

    base: np.ndarray  # (S, 3) leaf colour c_s, linear sRGB
    hue: np.ndarray  # (S,) degrees
    value: np.ndarray  # (S,) fraction of L
    seed: int
    accents: Accents | None = None

    def tints(
        self, map_tint: np.ndarray, species: np.ndarray, ids: np.ndarray, where: Where | None = None
    ) -> np.ndarray:
        """:func:`tree_tints` of these trees (``where``: their places, for clustered accents): ``(N, 3)`` float32."""
        return tree_tints(map_tint, species, ids, self.seed, self.base, self.hue, self.value, self.accents, where)


class _Jittered(_Accented, Protocol):
    @property
    def colour_jitter(self) -> ColourJitter: ...


def tint_params(settings: Sequence[_Jittered], species: Sequence[Species], seed: int) -> TintParams:
    """The :class:`TintParams` of a scene: ``settings[s]``'s ``colour_jitter`` and ``accents``, and
    :func:`leaf_colour` of ``species[s]``."""
    accents = accent_table(settings)
    return TintParams(
        base=np.array([leaf_colour(sp) for sp in species], dtype=np.float64).reshape(-1, 3),
        hue=np.array([s.colour_jitter.hue for s in settings], dtype=np.float64),
        value=np.array([s.colour_jitter.value for s in settings], dtype=np.float64),
        seed=int(seed),
        accents=accents if accents.any else None,
    )


# ---------------------------------------------------------------------------------------------------------------
# Bark: the same jitter around the bark's colour, and moss.


def bark_colour(species: Species) -> tuple[float, float, float] | None:
    """The colour the bark factor multiplies: the first ``bark`` part of the species' highest level, or None."""
    return first_part_colour(species, "bark")


def bark_tints(
    species: np.ndarray,
    ids: np.ndarray,
    seed: int,
    base: np.ndarray,
    hue: np.ndarray,
    value: np.ndarray,
    moss: np.ndarray,
    moss_colour: np.ndarray,
) -> np.ndarray:
    """Every tree's bark factor f_i = ((1 − μ_i)·J_i(b_s) + μ_i·g_s) ⊘ b_s: ``(N, 3)`` float32.

    ``b_s`` is the species' bark colour (``base`` (S, 3), NaN for a species
    without bark), J_i the tree's hue/value jitter exactly as the leaves'
    (module docstring) with amplitudes ``hue`` / ``value`` (S,) and its own
    uniforms (tag :data:`BARK_TAG`, so a tree's bark and leaves vary
    independently), μ_i = lo + (hi − lo)·ξ_i,3 the share of the bark under moss of
    albedo g_s (``moss`` (S, 2) = [lo, hi], ``moss_colour`` (S, 3)).  Mixing
    albedos by area share is the linear mix of a surface half-covered by
    each.  A renderer multiplies every bark part's colour (its texture's
    detail kept) by f_i.  Rows of a species without bark or without
    variation get 1.
    """
    k = np.asarray(species, np.int64).ravel()
    out = np.ones((len(k), 3), np.float32)
    base = np.asarray(base, np.float64).reshape(-1, 3)
    hue, value = np.asarray(hue, np.float64), np.asarray(value, np.float64)
    moss = np.asarray(moss, np.float64).reshape(-1, 2)
    varies = np.all(np.isfinite(base), axis=1) & ((hue > 0) | (value > 0) | (moss[:, 1] > 0))
    rows = np.flatnonzero(varies[k]) if len(k) else np.zeros(0, np.int64)
    if not len(rows):
        return out
    s = k[rows]
    xi = tree_uniforms(np.asarray(ids)[rows], seed, BARK_TAG, 3)
    c = np.maximum(base[s], 1e-6)
    jittered = rowwise(jitter_colours, c, hue[s] * (2.0 * xi[:, 0] - 1.0), value[s] * (2.0 * xi[:, 1] - 1.0))
    mu = (moss[s, 0] + (moss[s, 1] - moss[s, 0]) * xi[:, 2])[:, None]
    mixed = (1.0 - mu) * jittered + mu * np.asarray(moss_colour, np.float64).reshape(-1, 3)[s]
    out[rows] = (mixed / c).astype(np.float32)
    return out


@dataclass(frozen=True)
class BarkParams:
    """What :func:`bark_tints` needs besides the trees, per species index, and the seed."""

    base: np.ndarray  # (S, 3) bark colour b_s, NaN without bark
    hue: np.ndarray  # (S,)
    value: np.ndarray  # (S,)
    moss: np.ndarray  # (S, 2)
    moss_colour: np.ndarray  # (S, 3)
    seed: int

    def tints(self, species: np.ndarray, ids: np.ndarray) -> np.ndarray:
        """:func:`bark_tints` of these trees: ``(N, 3)`` float32."""
        return bark_tints(species, ids, self.seed, self.base, self.hue, self.value, self.moss, self.moss_colour)


class _Barked(Protocol):
    @property
    def bark(self) -> BarkLook: ...


def bark_params(settings: Sequence[_Barked], species: Sequence[Species], seed: int) -> BarkParams:
    """The :class:`BarkParams` of a scene: ``settings[s].bark`` and :func:`bark_colour` of ``species[s]``."""
    base = [bark_colour(sp) for sp in species]
    return BarkParams(
        base=np.array([(np.nan,) * 3 if b is None else b for b in base], np.float64).reshape(-1, 3),
        hue=np.array([s.bark.hue for s in settings], np.float64),
        value=np.array([s.bark.value for s in settings], np.float64),
        moss=np.array([s.bark.moss for s in settings], np.float64).reshape(-1, 2),
        moss_colour=np.array([s.bark.moss_colour for s in settings], np.float64).reshape(-1, 3),
        seed=int(seed),
    )
