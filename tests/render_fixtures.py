"""A tiny tree library built on the fly for render tests (boxes, cards), following the library contract."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from forest.library.mesh import MeshData, vertex_normals, write_ply


def box_mesh(lo, hi) -> MeshData:
    """An axis-aligned box as 12 triangles (outward winding)."""
    lo, hi = np.asarray(lo, np.float32), np.asarray(hi, np.float32)
    c = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], np.float32)
    v = lo + c * (hi - lo)
    f = np.array(
        [
            [0, 1, 3],
            [0, 3, 2],
            [4, 6, 7],
            [4, 7, 5],
            [0, 4, 5],
            [0, 5, 1],
            [2, 3, 7],
            [2, 7, 6],
            [0, 2, 6],
            [0, 6, 4],
            [1, 5, 7],
            [1, 7, 3],
        ],
        np.uint32,
    )
    return MeshData(v, f, vertex_normals(v, f).astype(np.float32), np.zeros((8, 2), np.float32))


@dataclass
class Part:
    kind: str
    path: Path
    colour: tuple
    texture: Path | None = None
    tinted: bool = True
    translucency: float = 0.0

    def load(self) -> MeshData:
        from forest.library.mesh import read_ply

        return read_ply(self.path)


@dataclass
class Lod:
    name: str
    triangles: int
    bounds: np.ndarray
    parts: list = field(default_factory=list)


@dataclass
class Species:
    name: str
    lods: list
    source: str = "generated"
    preview: Path | None = None


class BoxLibrary:
    """Species ``box``: LOD high is a 2×6×2 m white box, LODs low/far a 2×3×2 m blue one (both tinted); ``card``
    and ``stump`` (a bark box) below."""

    def __init__(self, root: Path, translucency: float = 0.0):
        root.mkdir(parents=True, exist_ok=True)
        self.species = {}
        lods = []
        specs = [
            ("high", (-1, 0, -1), (1, 6, 1), (0.8, 0.8, 0.8)),
            ("medium", (-1, 0, -1), (1, 6, 1), (0.8, 0.8, 0.8)),
            ("low", (-1, 0, -1), (1, 3, 1), (0.05, 0.05, 0.8)),
            ("far", (-1, 0, -1), (1, 3, 1), (0.05, 0.05, 0.8)),
        ]
        for name, lo, hi, colour in specs:
            m = box_mesh(lo, hi)
            path = write_ply(root / f"box_{name}.ply", m)
            lods.append(Lod(name, m.triangles, m.bounds(), [Part("leaf", path, colour, None, True, translucency)]))
        self.species["box"] = Species("box", lods)
        # Species "card": a horizontal 10×10 m leaf card 5 m up, its texture's alpha 0 on one half.
        from forest.images import write_image

        rgba = np.ones((16, 16, 4), np.float32)
        rgba[:, :8, 3] = 0.0
        tex = write_image(root / "card.png", rgba)
        v = np.array([[-5, 5, -5], [5, 5, -5], [5, 5, 5], [-5, 5, 5]], np.float32)
        f = np.array([[0, 2, 1], [0, 3, 2]], np.uint32)
        uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32)
        card = MeshData(v, f, np.tile(np.array([[0, 1, 0]], np.float32), (4, 1)), uv)
        path = write_ply(root / "card.ply", card)
        part = Part("leaf", path, (0.8, 0.8, 0.8), tex, False, 0.0)
        self.species["card"] = Species("card", [Lod("high", 2, card.bounds(), [part])])
        # Species "stump": a 2×6×2 m box of bark (untinted, grey), the parts a tree's bark factor multiplies.
        m = box_mesh((-1, 0, -1), (1, 6, 1))
        path = write_ply(root / "stump.ply", m)
        bark = Part("bark", path, (0.4, 0.4, 0.4), None, False, 0.0)
        self.species["stump"] = Species("stump", [Lod("high", m.triangles, m.bounds(), [bark])])

    def names(self):
        return sorted(self.species)

    def resolve(self, model, base_dir=None):
        from forest.errors import ForestError

        if model not in self.species:
            raise ForestError(f"unknown species {model!r}")
        return self.species[model]
