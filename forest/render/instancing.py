"""Instanced forests for the scalar renderer: level of detail and the shapegroup/instance scene graph.

One ``shapegroup`` per (species, individual, level of detail) holds that LOD's parts; each
tree is one ``instance`` record (a 4×4 transform and a reference), so memory
grows with the number of trees by the instance record only, never by their
triangles — the role ``DelayedReadArchive`` played in the original pipeline.

**Per-tree colour jitter.**  Tree i's tinted parts should show t_i = m(x_i) ⊙ j_i
(:mod:`forest.tint`): the colour map's tint at the tree times its own hue/value
jitter j_i = t_i ⊘ m(x_i) (:meth:`forest.scene.Scene.tree_jitter`).  The colour
map is looked up at every hit's world position by the shared BSDF
(:mod:`forest.render.materials`), so it already varies per tree; j_i cannot,
since every instance of a shapegroup shares its BSDFs.  So each species' trees
are put in at most K = :data:`JITTER_BINS` bins (:class:`JitterBins`) and a
tree of bin b is drawn by the shapegroup of its (species, individual, LOD, b),
whose tinted parts' colour is multiplied by the bin's mean factor
j̄_b = (1/|b|) Σ_{i∈b} j_i.  A tree's leaves then show m(x) ⊙ j̄_{b(i)}: its own
colour to within the spread of its bin, and each species' mean colour is kept.
Bins cost geometry (every shapegroup loads its own meshes), so a prototype of
T triangles gets k = min(K, max(1, ⌊:data:`JITTER_TRIANGLES`/T⌋)) bins
(:func:`jitter_bin_count`): its copies hold at most max(T, JITTER_TRIANGLES)
triangles.  With the default jitter (±18 % value, ±11° hue) lightness dominates
(σ_L ≈ 0.05 against σ_h ≈ 0.01 in Oklab for the library's greens), so the bins
split L only: on the demo, 95 % of the trees are within 2.3 % of their own L
with 8 bins (4.5 % with 4, 6 % with 3, 21 % with none) and the Oklab error is
0.014 rms (0.056 without bins); the hue jitter is averaged.  Measured on the
demo's first frame (8 501 trees, 3 species × 4 individuals × 4 levels; the high
levels, 53–68 k triangles, get 2–3 bins, the others 8): 48 → 279 shapegroups,
0.9 → 3.1 million loaded triangles, peak memory 580 → 1155 MiB and the
Mitsuba scene's build 2.7 → 5.7 s (a scene with wind is rebuilt every
sub-frame).  Without jitter (every j_i = 1) no bin is made and the graph is
the one without jitter, entry for entry (byte-identical renders).

**Bark.**  A tree's bark parts should show b_s ⊙ f_i, its own bark factor
(:meth:`forest.scene.Scene.bark_tints`: hue/value jitter and moss).  The same
bins carry it: the trees are binned over the leaves' coordinates and the
bark's (:class:`JitterBins`), and a bin's shapegroup multiplies its bark parts
by the bin's mean factor f̄_b.  The bark takes bins from the leaves rather than
adding shapegroups: on the demo's trees (8 bins, ``bench/bench_bark.py``) the
leaves' rms Oklab distance to their bin's colour goes 0.014 → 0.020 and the bark's
is 0.019 (0.040 to its species' mean, unbinned), for 363 → 366 shapegroups.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import ForestError
from ..lod import LOD_NAMES
from ..runtime import mitsuba
from ..tint import bark_colour, leaf_colour, oklab
from .materials import MaterialBuilder

if TYPE_CHECKING:
    from ..library import Species
    from ..library.core import Part
    from ..scene import Scene


_SHEEN_WARNED = False

#: Most colour-jitter bins per species (:class:`JitterBins`): each (prototype, bin) in use is one more shapegroup.
JITTER_BINS = 8
#: Triangles one prototype's jitter bins may hold together (:func:`jitter_bin_count`): a heavy prototype (a near
#: tree's high level) gets fewer bins than a light one.
JITTER_TRIANGLES = 200_000


def _warn_sheen_once() -> None:
    """scalar_rgb renders leaves without their cuticle sheen: say so once per process."""
    global _SHEEN_WARNED
    if not _SHEEN_WARNED:
        import warnings

        from ..errors import ForestWarning

        _SHEEN_WARNED = True
        warnings.warn(
            "scalar_rgb renders leaves without their cuticle sheen (leaf_sheen); forest_path "
            "(llvm_ad_rgb, cuda_ad_rgb) renders it",
            ForestWarning,
            stacklevel=3,
        )


def _grid_shape(k: int, *spreads: float) -> tuple[int, ...]:
    """(K_1, …, K_d) with ∏ K_j = ``k`` and the least residual variance Σ_j (σ_j/K_j)² of spreads σ_j.

    Equal-count bins of K values cut a coordinate's spread about K-fold, so
    this is the grid that leaves the trees closest to their bins' colours.
    Ties go to more bins on the earlier coordinates (shapes are tried from K_1 = k down).
    """

    def shapes(k: int, d: int) -> list[tuple[int, ...]]:
        if d == 1:
            return [(k,)]
        return [(a, *rest) for a in range(k, 0, -1) if k % a == 0 for rest in shapes(k // a, d - 1)]

    return min(shapes(k, len(spreads)), key=lambda p: sum((s / n) ** 2 for s, n in zip(spreads, p)))


def _equal_counts(values: np.ndarray, ids: np.ndarray, n_bins: int) -> np.ndarray:
    """Equal-count bins of ``values``: ⌊rank·n_bins/n⌋, ranks by (value, id) so that ties are deterministic."""
    rank = np.empty(len(values), np.int64)
    rank[np.lexsort((ids, values))] = np.arange(len(values))
    return (rank * n_bins) // max(len(values), 1)


def jitter_bin_count(triangles: int) -> int:
    """Colour-jitter bins of a prototype of ``triangles`` triangles: ⌊:data:`JITTER_TRIANGLES` / triangles⌋ in
    [1, :data:`JITTER_BINS`], so that its bins' copies hold at most max(triangles, JITTER_TRIANGLES) triangles.

    A function of the prototype alone (not of the frame or of how many trees use it), so a tree's
    colour does not change from frame to frame while it keeps its level of detail.
    """
    return int(min(JITTER_BINS, max(1, JITTER_TRIANGLES // max(int(triangles), 1))))


class JitterBins:
    """Deterministic quantisation of the trees' colour jitter and bark factors into k bins per species (no k-means).

    ``jitter`` (N, 3) is j_i = t_i ⊘ m(x_i), ``species`` (N,) the species indices,
    ``ids`` (N,) the tree ids (tie-breaks), ``base`` (S, 3) each species' leaf
    colour c_s, NaN for a species whose leaves are not to be binned (one without tinted parts).
    For the trees of species s with some j_i ≠ 1, the jittered leaf colours
    q_i = c_s ⊙ j_i in Oklab (Ottosson 2020, "A perceptual color space for image
    processing"; colour-science) give two coordinates: the lightness L_i and
    the hue offset h_i = d⊥·(a_i, b_i), d the unit direction of the species'
    mean (a, b), so h_i ≈ C·Δh_i for small hue angles (0 for a grey).
    ``bark`` (N, 3) (the trees' bark factors f_i, :meth:`forest.scene.Scene.bark_tints`, or None) and
    ``bark_base`` (S, 3) (each species' bark colour, NaN without bark) add a third: the bark colours
    b_s ⊙ f_i in Oklab projected on their principal axis (the direction of most variance: mostly
    lightness and the moss's green).  For k bins (:meth:`bins`) the trees are split into K_L
    equal-count groups by L, each group into K_h equal-count groups by h, each of those into K_b by
    the bark's coordinate (ranks by value, then id), K_L·K_h·K_b = k chosen by :func:`_grid_shape`
    from the coordinates' standard deviations (the default jitter, ±18 % value against ±11° hue,
    gives K_h = 1 for the library's greens up to k = 8).  Bin b has the factors j̄_b and f̄_b, the
    means of j_i and f_i over its trees, so the bins keep each species' mean colours; a species with
    fewer than k trees gets at most one bin per tree.  Trees of a species not binned get bin −1.

    ``accents`` (N,) (each tree's colour accent, −1 for none: :meth:`forest.scene.Scene.tree_accents`, or
    None) keeps accented crowns from being averaged into green bins: a few percent of a species, far
    from the rest in hue, they would shift their bins' means a little and vanish.  With k ≥ 2 bins the
    species' A largest accent groups, A ≤ k − 1, get one bin each (the last A), and the other trees
    share the first k − A bins as above.
    """

    def __init__(
        self,
        jitter: np.ndarray,
        species: np.ndarray,
        ids: np.ndarray,
        base: np.ndarray,
        bark: np.ndarray | None = None,
        bark_base: np.ndarray | None = None,
        accents: np.ndarray | None = None,
    ):
        self.jitter = np.asarray(jitter, np.float64).reshape(-1, 3)
        self.accents = None if accents is None else np.asarray(accents, np.int64).ravel()
        self.species = np.asarray(species, np.int64).ravel()
        self.ids = np.asarray(ids).astype(np.int64).ravel()
        self.n_species = len(base)
        n = len(self.jitter)
        self.bark = None if bark is None else np.asarray(bark, np.float64).reshape(-1, 3)
        self.coords = np.zeros((n, 3))  # L, h, bark (0 where a coordinate does not vary)
        self.binned = np.zeros(self.n_species, bool)
        for s in range(self.n_species):
            rows = np.flatnonzero(self.species == s)
            if not len(rows):
                continue
            c = np.asarray(base[s], np.float64)
            if np.all(np.isfinite(c)) and not np.all(np.abs(self.jitter[rows] - 1.0) < 1e-6):
                lab = oklab(np.maximum(c[None, :] * self.jitter[rows], 0.0))
                mean_ab = lab[:, 1:].mean(axis=0)
                norm = float(np.hypot(mean_ab[0], mean_ab[1]))
                self.coords[rows, 0] = lab[:, 0]
                if norm > 1e-6:
                    self.coords[rows, 1] = (lab[:, 2] * mean_ab[0] - lab[:, 1] * mean_ab[1]) / norm
                self.binned[s] = True
            cb = None if bark_base is None else np.asarray(bark_base[s], np.float64)
            if (
                self.bark is not None
                and cb is not None
                and np.all(np.isfinite(cb))
                and not np.all(np.abs(self.bark[rows] - 1.0) < 1e-6)
            ):
                self.coords[rows, 2] = _principal_coordinate(oklab(np.maximum(cb[None, :] * self.bark[rows], 0.0)))
                self.binned[s] = True
        self._cache: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}

    def _binned(self, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if k in self._cache:
            return self._cache[k]
        bins = np.full(len(self.jitter), -1, np.int64)
        factors = np.ones((self.n_species, k, 3), np.float64)
        bark = np.ones((self.n_species, k, 3), np.float64)
        for s in np.flatnonzero(self.binned).tolist():
            rows = np.flatnonzero(self.species == s)
            own, n_own = self._accent_bins(rows, k)  # each accent group's bin (offset into the last n_own), −1 else
            rest = np.flatnonzero(own < 0)
            b = np.zeros(len(rows), np.int64)
            b[rest] = self._grid_bins(rows[rest], k - n_own)
            b[own >= 0] = k - n_own + own[own >= 0]
            bins[rows] = b
            counts = np.bincount(b, minlength=k).astype(np.float64)
            for table, values in ((factors, self.jitter), (bark, self.bark)):
                if values is None:
                    continue
                for ch in range(3):
                    total = np.bincount(b, weights=values[rows, ch], minlength=k)
                    table[s, :, ch] = np.where(counts > 0, total / np.maximum(counts, 1.0), 1.0)
        self._cache[k] = (bins, factors, bark)
        return self._cache[k]

    def _grid_bins(self, rows: np.ndarray, k: int) -> np.ndarray:
        """The trees ``rows`` split into ``k`` bins over their coordinates (the class docstring's grid)."""
        coords, ids = self.coords[rows], self.ids[rows]
        b = np.zeros(len(rows), np.int64)
        if not len(rows):
            return b
        shape = _grid_shape(k, *(float(x) for x in coords.std(axis=0)))
        for d, n in enumerate(shape):  # split every group of the previous coordinates by this one
            sub = np.zeros(len(rows), np.int64)
            for g in np.unique(b).tolist():
                members = np.flatnonzero(b == g)
                sub[members] = _equal_counts(coords[members, d], ids[members], n)
            b = b * n + sub
        return b

    def _accent_bins(self, rows: np.ndarray, k: int) -> tuple[np.ndarray, int]:
        """(per row of ``rows``: the index among the species' kept accent groups, −1 for none; how many kept).

        At most k − 1 groups are kept, the largest first (ties: the lower accent index)."""
        own = np.full(len(rows), -1, np.int64)
        if self.accents is None or k < 2:
            return own, 0
        acc = self.accents[rows]
        groups, counts = np.unique(acc[acc >= 0], return_counts=True)
        if not len(groups):
            return own, 0
        kept = groups[np.lexsort((groups, -counts))][: k - 1]
        for j, g in enumerate(np.sort(kept).tolist()):
            own[acc == g] = j
        return own, len(kept)

    def bins(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """``(bin (N,) int64 in [0, k) or −1, leaf factors j̄ (S, k, 3) float64)`` for ``k`` bins per species
        (cached)."""
        bins, factors, _ = self._binned(k)
        return bins, factors

    def bark_factors(self, k: int) -> np.ndarray:
        """The bins' bark factors f̄ (S, k, 3) float64 (1 without bark) for ``k`` bins per species."""
        return self._binned(k)[2]


def _principal_coordinate(points: np.ndarray) -> np.ndarray:
    """Each point's coordinate along the points' direction of most variance (signed so that it grows with
    the first coordinate, Oklab's L, where that is not flat)."""
    centred = points - points.mean(axis=0)
    _, vectors = np.linalg.eigh(centred.T @ centred)
    axis = vectors[:, -1]
    if axis[0] < 0:
        axis = -axis
    out: np.ndarray = centred @ axis
    return out


def _has_tinted_parts(individuals: list[Species]) -> bool:
    """Whether any level of any individual has a tinted part (the parts the jitter multiplies)."""
    return any(getattr(p, "tinted", False) for sp in individuals for lod in sp.lods for p in lod.parts)


def _has_bark(individuals: list[Species]) -> bool:
    """Whether any level of any individual has a bark part (the parts the bark factor multiplies)."""
    return any(getattr(p, "kind", "") == "bark" for sp in individuals for lod in sp.lods for p in lod.parts)


@dataclass
class ForestGraph:
    """A forest as scene-dict entries plus what it cost."""

    entries: dict[str, Any] | None  # shapegroups, shared BSDFs and instances, ready for a scene dict (None once loaded)
    trees: int
    instanced_triangles: int
    unique_triangles: int
    shapegroups: int
    lod_counts: dict[str, int] = field(default_factory=dict)
    jittered_shapegroups: int = 0  # of ``shapegroups``, those of a colour-jitter bin (module docstring)


class ForestBuilder:
    """Builds per-frame instance graphs of a Scene's trees for one variant."""

    def __init__(self, scene: Scene, materials: MaterialBuilder):
        self.config = scene.config
        self.instances = scene.instances
        self.materials = materials
        self.variant = materials.variant
        self.species = list(scene.species)
        # Several library individuals per species (Scene.individuals, InstanceSet.individual) where the
        # Scene has them; element 0 is the species itself.
        individuals = getattr(scene, "individuals", None)
        self.individuals = (
            [list(i) if i else [sp] for i, sp in zip(individuals, self.species)]
            if individuals
            else [[sp] for sp in self.species]
        )
        column = getattr(self.instances, "individual", None)
        self.individual = (
            np.zeros(len(self.instances), np.int64) if column is None else np.asarray(column, np.int64).ravel()
        )
        self._bsdf_ids: dict[tuple[Any, ...], str] = {}
        self._bsdfs: dict[str, dict[str, Any]] = {}
        # The fitted leaf tint of each species index (Scene.leaf_tint; 1 without [lookdev] leaf_tint).
        tint = getattr(scene, "leaf_tint", None)
        self.leaf_tint = np.ones((len(self.species), 3)) if tint is None else np.asarray(tint, np.float64)
        # The trees' colour-jitter bins (module docstring); None without jitter.
        self.jitter: JitterBins | None = None
        tree_jitter = getattr(scene, "tree_jitter", None)
        jitter = tree_jitter() if tree_jitter is not None else None
        bark_tints = getattr(scene, "bark_tints", None)
        bark = bark_tints() if bark_tints is not None else None
        if jitter is not None or bark is not None:
            base = np.array(
                [
                    leaf_colour(sp) if _has_tinted_parts(ind) and jitter is not None else (np.nan,) * 3
                    for sp, ind in zip(self.species, self.individuals)
                ],
                np.float64,
            ).reshape(-1, 3)
            bark_base = np.array(
                [
                    (bark_colour(sp) or (np.nan,) * 3) if _has_bark(ind) else (np.nan,) * 3
                    for sp, ind in zip(self.species, self.individuals)
                ],
                np.float64,
            ).reshape(-1, 3)
            ones = np.ones((len(self.instances), 3))
            tree_accents = getattr(scene, "tree_accents", None)
            jb = JitterBins(
                ones if jitter is None else jitter,
                self.instances.species,
                self.instances.id,
                base,
                bark,
                bark_base,
                tree_accents() if tree_accents is not None else None,
            )
            self.jitter = jb if jb.binned.any() else None
        # Shapegroup slot 0: no jitter; slot off(k) + b (off(k) = 1 + k(k−1)/2): bin b of k.
        self._slots = [(0, -1)] + [(k, b) for k in range(1, JITTER_BINS + 1) for b in range(k)]

    def _bsdf_ref(
        self, part: Part, s: int | None = None, factor: np.ndarray | None = None, bark: np.ndarray | None = None
    ) -> dict[str, Any]:
        """A reference to the shared BSDF of ``part`` of species ``s``; a tinted part's colour × the species' leaf
        tint × ``factor`` (a colour-jitter bin's j̄_b, None for 1), a bark part's × ``bark`` (the bin's f̄_b)."""
        tinted = bool(getattr(part, "tinted", False))  # the leaf tint multiplies the parts the colour map tints
        scale = np.ones(3)
        if s is not None and tinted and s < len(self.leaf_tint) and not np.all(self.leaf_tint[s] == 1.0):
            scale = scale * self.leaf_tint[s]
        if tinted and factor is not None:
            scale = scale * np.asarray(factor, np.float64)
        if getattr(part, "kind", "") == "bark" and bark is not None:
            scale = scale * np.asarray(bark, np.float64)
        if not np.all(scale == 1.0):
            r, g, b = (float(c) for c in np.asarray(part.colour, np.float64) * scale)
            part = dataclasses.replace(part, colour=(r, g, b))
        key = (
            part.kind,
            tuple(np.round(np.asarray(part.colour, float), 6)),
            str(getattr(part, "texture", None)),
            bool(getattr(part, "tinted", False)),
            round(float(getattr(part, "translucency", 0.0) or 0.0), 6),
        )
        if part.kind == "leaf" and float(getattr(part, "sheen", 0.0) or 0.0) > 0:
            _warn_sheen_once()
        if key not in self._bsdf_ids:
            bid = f"bsdf_{len(self._bsdf_ids)}"
            self._bsdf_ids[key] = bid
            self._bsdfs[bid] = self.materials.part_bsdf(part)
        return {"type": "ref", "id": self._bsdf_ids[key]}

    def shapegroup(self, s: int, level: int, individual: int = 0, jitter: tuple[int, int] = (0, -1)) -> dict[str, Any]:
        """Mitsuba ``shapegroup`` of species ``s``, individual ``individual`` (cycled), LOD ``level`` (clamped);
        ``jitter`` = (k, b): its tinted parts × the factor of bin b of k colour-jitter bins ((0, −1): none)."""
        options = self.individuals[s]
        sp = options[individual % len(options)]
        lod = sp.lods[min(level, len(sp.lods) - 1)]
        n_bins, b = jitter
        factor = bark = None
        if self.jitter is not None and n_bins > 0 and b >= 0:
            factor, bark = self.jitter.bins(n_bins)[1][s, b], self.jitter.bark_factors(n_bins)[s, b]
        group: dict[str, Any] = {"type": "shapegroup"}
        for k, part in enumerate(lod.parts):
            ref = self._bsdf_ref(part, s, factor, bark)
            group[f"part_{k}"] = {"type": "ply", "filename": str(part.path), "bsdf": ref}
        if len(group) == 1:
            raise ForestError(f"species {self.instances.species_names[s]!r} LOD {lod.name} has no parts")
        return group

    def _jitter_slots(self, species: np.ndarray, individual: np.ndarray, levels: np.ndarray) -> np.ndarray:
        """Each tree's shapegroup slot: 0 without jitter, else off(k) + its bin of the k = :func:`jitter_bin_count`
        bins of its prototype (species, individual, level)."""
        slots = np.zeros(len(species), np.int64)
        if self.jitter is None or not len(species):
            return slots
        proto = (species * 256 + individual) * 8 + levels
        protos, inverse = np.unique(proto, return_inverse=True)
        per_proto = np.zeros(len(protos), np.int64)
        for i, key in enumerate(protos.tolist()):
            rest, level = divmod(key, 8)
            s, k = divmod(rest, 256)
            if self.jitter.binned[s]:
                sp = self.individuals[s][k]
                per_proto[i] = jitter_bin_count(int(sp.lods[min(level, len(sp.lods) - 1)].triangles))
        count = per_proto[inverse.ravel()]
        for k in np.unique(count[count > 0]).tolist():
            rows = np.flatnonzero(count == k)
            b = self.jitter.bins(k)[0][rows]
            slots[rows] = np.where(b >= 0, 1 + k * (k - 1) // 2 + b, 0)
        return slots

    def graph(self, levels: np.ndarray, matrices: np.ndarray) -> ForestGraph:
        """Scene entries for every tree: ``sg_<species>_<individual>_<lod>`` shapegroups (``…_j<slot>`` for a
        colour-jitter bin, :meth:`_jitter_slots`) and ``tree_<row>`` instances."""
        mi = mitsuba(self.variant)
        inst = self.instances
        species = inst.species.astype(np.int64)
        counts_per = np.array([len(o) for o in self.individuals], np.int64)
        individual = self.individual % counts_per[species] if len(species) else self.individual
        entries: dict[str, Any] = {}
        tris = {}
        nb = len(self._slots)
        keys = ((species * 256 + individual) * 8 + levels) * nb + self._jitter_slots(species, individual, levels)
        used = np.unique(keys)
        names = {}
        jittered = 0
        for key in used.tolist():
            rest, slot = divmod(key, nb)
            rest, level = divmod(rest, 8)
            s, k = divmod(rest, 256)
            names[key] = f"sg_{s}_{k}_{level}" if slot == 0 else f"sg_{s}_{k}_{level}_j{slot}"
            entries[names[key]] = self.shapegroup(s, level, k, self._slots[slot])
            jittered += int(slot > 0)
            sp = self.individuals[s][k]
            tris[key] = int(sp.lods[min(level, len(sp.lods) - 1)].triangles)
        counts = np.bincount(levels, minlength=4) if len(levels) else np.zeros(4, np.int64)
        lod_counts = {LOD_NAMES[i] if i < 4 else str(i): int(c) for i, c in enumerate(counts) if c}
        instanced = (
            int(sum(tris[key] * int(c) for key, c in zip(*np.unique(keys, return_counts=True)))) if len(keys) else 0
        )
        refs = {key: {"type": "ref", "id": names[key]} for key in used.tolist()}
        T, M4 = mi.ScalarTransform4f, mi.ScalarMatrix4f  # T(M4(array)): 3× faster than T(array)
        mats = np.ascontiguousarray(matrices, dtype=np.float64)
        for row, (key, m) in enumerate(zip(keys.tolist(), mats)):
            entries[f"tree_{row}"] = {"type": "instance", "shapegroup": refs[key], "to_world": T(M4(m))}
        # Shared BSDFs go first so references resolve.
        out = dict(self._bsdfs)
        out.update(entries)
        return ForestGraph(
            entries=out,
            trees=len(inst),
            instanced_triangles=instanced,
            unique_triangles=int(sum(tris.values())),
            shapegroups=len(used),
            lod_counts=lod_counts,
            jittered_shapegroups=jittered,
        )
