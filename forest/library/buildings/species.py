"""Building species files: draw the meshes of every level of detail, write PLYs, textures and metadata."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..mesh import MeshData, write_ply
from .designs import BUILDERS
from .facades import GLASS, facade_rgba, roof_rgba
from .kit import far_box
from .recipe import LODS, TAG, validate_recipe

_CODE_FILES = (
    "buildings/__init__.py",
    "buildings/recipe.py",
    "buildings/kit.py",
    "buildings/facades.py",
    "buildings/designs.py",
    "buildings/species.py",
    "mesh.py",
    "build.py",
    "preview.py",
    "textures.py",
)


def code_hash() -> str:
    """Hash of this generator's source (and the shared mesh/preview code): edits rebuild buildings."""
    from ..build import source_hash

    return source_hash(_CODE_FILES)


def recipe_hash(recipe: dict, seed: int) -> str:
    """The cache key of a building species (see :func:`forest.library.build.recipe_digest`)."""
    from ..build import recipe_digest

    return recipe_digest(code_hash(), recipe, seed)


def build_meshes(
    recipe: dict, seed: int
) -> tuple[dict[str, dict[str, MeshData]], dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Draw a building: ``({lod: {part: MeshData}}, colours, {"walls": façade tile, "roof": roof tile})``."""
    b = recipe["building"]
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, TAG])))
    wall = np.asarray(b["wall_colours"][int(rng.integers(len(b["wall_colours"])))], dtype=np.float64)
    roofc = np.asarray(b["roof_colours"][int(rng.integers(len(b["roof_colours"])))], dtype=np.float64)
    parts, h_far, h_wall, (W, D) = BUILDERS[b["type"]](b, rng)
    meshes = {lod: {k: v.mesh() for k, v in parts[lod].items()} for lod in LODS[:3]}
    fw, fr = far_box(W, D, h_far, h_wall)
    meshes["far"] = {"walls": fw, "roof": fr}
    # Drawn after the geometry, so the glazing varies without moving any vertex.
    glass = GLASS[int(rng.integers(len(GLASS)))]
    tex = facade_rgba(b["type"], glass=glass, band=float(rng.uniform(0.2, 0.4)))
    roof_tex = roof_rgba(b["type"])
    colours = {
        "walls": wall,
        "roof": roofc,
        "trim": np.asarray(b["trim_colour"], dtype=np.float64),
        "far_walls": wall * tex[..., :3].reshape(-1, 3).mean(axis=0),
        "far_roof": roofc * roof_tex[..., :3].reshape(-1, 3).mean(axis=0),
    }
    return meshes, colours, {"walls": tex, "roof": roof_tex}


def generate(recipe: dict, seed: int, out: Path, *, name: str, where: str = "recipe") -> dict:
    """Draw the building ``recipe`` with ``seed`` and write every level of detail into folder ``out``.

    Writes ``<lod>_<part>.ply``, ``facade.png``, ``roof.png`` and ``species.json`` (last);
    returns the ``species.json`` dictionary.
    """
    from ..build import lod_entry, part_entry, write_json
    from ..textures import write_texture

    recipe = validate_recipe(recipe, where)
    b = recipe["building"]
    meshes, colours, tex = build_meshes(recipe, seed)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    files = {"walls": "facade.png", "roof": "roof.png"}
    for part, file in files.items():
        write_texture(out / file, tex[part])
    tint = {"walls": b["tint_walls"], "roof": b["tint_roof"], "trim": False}
    lods = []
    for lod in LODS:
        entries = []
        for part, mesh in meshes[lod].items():
            if mesh.triangles == 0:
                continue
            file = f"{lod}_{part}.ply"
            write_ply(out / file, mesh)
            # The far box's parts take the texture's mean detail into their colour instead.
            texture = files.get(part) if lod != "far" else None
            colour = colours[f"far_{part}"] if lod == "far" else colours[part]
            entries.append(part_entry("surface", file, mesh, colour, texture, tint[part], 0.0))
        lods.append(lod_entry(lod, entries))
    meta = {
        "name": name,
        "source": "generated",
        "seed": int(seed),
        "hash": recipe_hash(recipe, seed),
        "kind": "building",
        "building_type": b["type"],
        "lods": lods,
    }
    write_json(out / "species.json", meta)
    return meta
