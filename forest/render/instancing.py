"""Instanced forests for the scalar renderer: level of detail and the shapegroup/instance scene graph.

One ``shapegroup`` per (species, individual, level of detail) holds that LOD's parts; each
tree is one ``instance`` record (a 4×4 transform and a reference), so memory
grows with the number of trees by the instance record only, never by their
triangles — the role ``DelayedReadArchive`` played in the original pipeline.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import ForestError
from ..lod import LOD_NAMES
from ..runtime import mitsuba
from .materials import MaterialBuilder

if TYPE_CHECKING:
    from ..library.core import Part
    from ..scene import Scene


_SHEEN_WARNED = False


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


@dataclass
class ForestGraph:
    """A forest as scene-dict entries plus what it cost."""

    entries: dict[str, Any] | None  # shapegroups, shared BSDFs and instances, ready for a scene dict (None once loaded)
    trees: int
    instanced_triangles: int
    unique_triangles: int
    shapegroups: int
    lod_counts: dict[str, int] = field(default_factory=dict)


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

    def _bsdf_ref(self, part: Part, s: int | None = None) -> dict[str, Any]:
        tinted = bool(getattr(part, "tinted", False))  # the leaf tint multiplies the parts the colour map tints
        if s is not None and tinted and s < len(self.leaf_tint) and not np.all(self.leaf_tint[s] == 1.0):
            r, g, b = (float(c) for c in np.asarray(part.colour, np.float64) * self.leaf_tint[s])
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

    def shapegroup(self, s: int, level: int, individual: int = 0) -> dict[str, Any]:
        """Mitsuba ``shapegroup`` of species ``s``, individual ``individual`` (cycled), LOD ``level`` (clamped)."""
        options = self.individuals[s]
        sp = options[individual % len(options)]
        lod = sp.lods[min(level, len(sp.lods) - 1)]
        group: dict[str, Any] = {"type": "shapegroup"}
        for k, part in enumerate(lod.parts):
            group[f"part_{k}"] = {"type": "ply", "filename": str(part.path), "bsdf": self._bsdf_ref(part, s)}
        if len(group) == 1:
            raise ForestError(f"species {self.instances.species_names[s]!r} LOD {lod.name} has no parts")
        return group

    def graph(self, levels: np.ndarray, matrices: np.ndarray) -> ForestGraph:
        """Scene entries for every tree: ``sg_<species>_<individual>_<lod>`` shapegroups and ``tree_<row>`` instances."""
        mi = mitsuba(self.variant)
        inst = self.instances
        species = inst.species.astype(np.int64)
        counts_per = np.array([len(o) for o in self.individuals], np.int64)
        individual = self.individual % counts_per[species] if len(species) else self.individual
        entries: dict[str, Any] = {}
        tris = {}
        keys = (species * 256 + individual) * 8 + levels
        used = np.unique(keys)
        names = {}
        for key in used.tolist():
            rest, level = divmod(key, 8)
            s, k = divmod(rest, 256)
            names[key] = f"sg_{s}_{k}_{level}"
            entries[names[key]] = self.shapegroup(s, level, k)
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
        )
