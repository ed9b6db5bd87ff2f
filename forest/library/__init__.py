"""The tree library: species as procedural recipes or imported meshes, with levels of detail.

```python
lib = open_library()                      # library/ in the checkout, or $FOREST_LIBRARY
sp = lib.resolve("broadleaf", base_dir)   # a name, "NAME@SEED", or a mesh path imported on the fly
for lod in sp.lods:                       # high, medium, low, far
    lod.name, lod.triangles, lod.bounds   # bounds: (2, 3) float64 [min, max], object space
    for part in lod.parts:                # kind leaf | bark | surface; PLY path; colour; texture; tinted
        mesh = part.load()                # MeshData(vertices, faces, normals, uv)
sp.preview                                # preview PNG (rendered with Mitsuba on first use)
individual(lib, "broadleaf", 3)           # the 3rd individual: "broadleaf@<manifest seed + 3>"
```

Meshes are binary little-endian PLY (``x y z nx ny nz u v``), Y up, base at the
origin, metres.  UVs follow Mitsuba's image convention (``v = 0`` is the
image's top row); writers for conventions with ``v = 0`` at the bottom use
``1 − v``.  Reflectance of a part is ``colour × texture.rgb`` (PNG textures
sRGB-decoded, the bark's EXR linear; every detail factor has mean 1, so
``colour`` is the part's mean albedo), times the colour map's tint where
``tinted``; a leaf's opacity
is its texture's alpha and ``translucency`` is the share of its diffuse
albedo that is transmitted.
"""

from __future__ import annotations

from .core import Library, Lod, Part, Species, open_library
from .individuals import individual, individuals
from .lod import BUDGETS, LODS
from .mesh import MeshData

__all__ = [
    "BUDGETS",
    "LODS",
    "Library",
    "Lod",
    "MeshData",
    "Part",
    "Species",
    "individual",
    "individuals",
    "open_library",
]
