"""Turn a recipe into a species' files: PLY per part per level of detail, textures, metadata.

A species' asset folder holds ``<lod>_<part>.ply``, ``leaf.png`` (single-leaf
card), ``cluster.png`` (leaf-cluster card of the lower levels), ``bark.exr`` (the
bark's tileable detail factor, mean 1), ``far.png`` (the crossed-card impostor
atlas) and ``species.json`` — the measured triangle
counts and bounds that :class:`forest.library.Library` reads without opening
any mesh.  ``species.json`` is written last, so a folder with it is complete.
"""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path

import numpy as np

from ..atomic import atomic_path
from ..images import write_image
from . import lod as lodmod
from .generator import grow, validate_recipe
from .mesh import MeshData, mesh_bounds, orient_faces, write_ply
from .outline import card_outlines
from .textures import bark_rgb, cluster_rgba, leaf_rgba, write_texture

_CODE_FILES = ("generator.py", "lod.py", "mesh.py", "outline.py", "textures.py", "build.py", "preview.py")


def source_hash(files) -> str:
    """sha256 over the named source files of this package (names and bytes)."""
    h = hashlib.sha256()
    here = Path(__file__).parent
    for name in files:
        h.update(name.encode())
        h.update((here / name).read_bytes())
    return h.hexdigest()


def recipe_digest(code: str, recipe: dict, seed: int) -> str:
    """``sha256(code hash, canonical JSON of the validated recipe, seed)`` as hex."""
    payload = json.dumps({"recipe": recipe, "seed": int(seed)}, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256((code + payload).encode()).hexdigest()


def code_hash() -> str:
    """Hash of the generator's source: a change to it invalidates every cached species."""
    return source_hash(_CODE_FILES)


def recipe_hash(recipe: dict, seed: int) -> str:
    """The cache key of a tree species (see :func:`recipe_digest`)."""
    return recipe_digest(code_hash(), recipe, seed)


def write_json(path: Path, data: dict) -> None:
    """Write ``data`` to ``path`` atomically as sorted, indented JSON (the same data, the same bytes)."""
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")


def part_entry(
    kind: str,
    file: str,
    mesh: MeshData,
    colour,
    texture: str | None,
    tinted: bool,
    translucency: float,
    sheen: tuple[float, float] | None = None,
) -> dict:
    """The metadata entry of one part: kind, file, colour (6 decimals), texture, tinted, translucency, size;
    a leaf's ``sheen`` (s, α) adds ``sheen`` and ``roughness`` (its cuticle lobe)."""
    extra = {} if sheen is None else {"sheen": float(sheen[0]), "roughness": float(sheen[1])}
    return extra | {
        "kind": kind,
        "file": file,
        "colour": [round(float(c), 6) for c in colour],
        "texture": texture,
        "tinted": bool(tinted),
        "translucency": float(translucency),
        "triangles": mesh.triangles,
        "bounds": mesh_bounds(mesh.vertices, mesh.faces).tolist(),
    }


def lod_entry(name: str, parts: list[dict]) -> dict:
    """The metadata entry of a level of detail: its ``parts``, their total triangles and the union of their bounds."""
    b = np.array([p["bounds"] for p in parts])
    return {
        "name": name,
        "triangles": int(sum(p["triangles"] for p in parts)),
        "bounds": [b[:, 0].min(axis=0).tolist(), b[:, 1].max(axis=0).tolist()],
        "parts": parts,
    }


def ground(mesh: MeshData) -> MeshData:
    """Clamp vertices to ``y ≥ 0``: drooping fronds and enlarged low-level cards lie on the ground."""
    if len(mesh.vertices) and float(mesh.vertices[:, 1].min()) < 0.0:
        v = mesh.vertices.copy()
        v[:, 1] = np.maximum(v[:, 1], 0.0)
        return MeshData(v, mesh.faces, mesh.normals, mesh.uv)
    return mesh


FAR_RES = 128  # the far atlas's resolution per view
COVER_STEPS = 3  # at most this many corrections of a cluster level's card scale
COVER_TOLERANCE = 0.04  # relative coverage difference accepted without a correction
COVER_EXPONENT = 0.7  # first guess of d ln(coverage) / d ln(card scale) for cluster cards


def far_coverage(folder: Path, level: dict, bounds: np.ndarray, res: int = FAR_RES, spp: int = 8) -> np.ndarray:
    """A level's exact coverage along each far card's normal, ``(FAR_TILES, res, res)`` (see :func:`far_views`)."""
    return far_views(folder, level, bounds, res, spp)[..., 3]


def far_views(
    folder: Path, level: dict, bounds: np.ndarray, res: int = FAR_RES, spp: int = 8, shaded: bool = False
) -> np.ndarray:
    """Render a level along each far card's normal (Mitsuba), framed by ``bounds``: RGBA ``(FAR_TILES, res, res, 4)``,
    the view from above last.

    Alpha is the exact coverage; with ``shaded`` the RGB is the level's radiance under a unit sky
    (:func:`forest.library.preview.card_views`).
    """
    from types import SimpleNamespace

    from .preview import card_views

    parts = [
        SimpleNamespace(
            kind=p["kind"],
            path=folder / p["file"],
            colour=tuple(p["colour"]),
            texture=(folder / p["texture"]) if p["texture"] else None,
        )
        for p in level["parts"]
    ]
    return card_views(parts, bounds, lodmod.FAR_VIEWS, res, spp, shaded=shaded, top=True)


def toned(level: str, tone: dict, colour, sheen: tuple[float, float]) -> tuple[list[float], tuple[float, float]]:
    """A level's leaf colour and sheen (weight, roughness) under the recipe's ``[lod_tone]``: the colour times the
    level's ``albedo`` factor, the sheen's weight times its ``sheen`` factor (at most 1); the high level as given."""
    t = tone.get(level)
    if t is None:
        return [float(c) for c in colour], sheen
    return [float(c) * f for c, f in zip(colour, t["albedo"])], (min(1.0, sheen[0] * t["sheen"]), sheen[1])


def generate(recipe: dict, seed: int, out: Path, *, name: str, where: str = "recipe") -> dict:
    """Grow ``recipe`` with ``seed`` and write every level of detail into folder ``out``.

    Returns the ``species.json`` dictionary (also written into ``out``).
    """
    recipe = validate_recipe(recipe, where)
    tree = recipe["tree"]
    sk = grow(recipe, seed)
    out.mkdir(parents=True, exist_ok=True)
    shape = tree["leaf_shape"]
    leaf_tex = leaf_rgba(shape)
    cluster_tex = cluster_rgba(shape)
    bark_tex = bark_rgb(tree["bark_texture"])
    write_texture(out / "leaf.png", leaf_tex)
    write_texture(out / "cluster.png", cluster_tex)
    write_image(out / "bark.exr", bark_tex)
    cov_leaf = float(leaf_tex[..., 3].mean())
    cov_cluster = float(cluster_tex[..., 3].mean())
    cut = tree["leaf_cut"] == "outline"
    segments = tree["leaf_segments"]
    # Outlines of the two card textures (computed once each; a level picks among them).
    leaf_options = card_outlines(leaf_tex[..., 3], lodmod.MAX_CARD_TRIANGLES["high"]) if cut else {}
    cluster_options = (
        card_outlines(cluster_tex[..., 3], max(lodmod.MAX_CARD_TRIANGLES[k] for k in ("medium", "low"))) if cut else {}
    )
    leaf_colour, bark_colour = tree["leaf_colour"], tree["bark_colour"]
    transl = tree["translucency"]
    sheen = (float(tree["leaf_sheen"]), float(tree["leaf_roughness"]))
    tone = recipe["lod_tone"]
    lods = []
    high_meshes: list[tuple[MeshData, np.ndarray, np.ndarray | None]] = []
    coverage = shading = None
    high_bounds = np.zeros((2, 3))
    for lod in ("high", "medium", "low"):
        target = lodmod.TARGETS[lod]
        bark = orient_faces(ground(lodmod.bark_mesh(sk, lod, target * lodmod.BARK_SHARE[lod])))
        budget = 2 * max(target // 8, (target - bark.triangles) // 2)
        if lod == "high":
            cap = {t: o for t, o in leaf_options.items() if t <= lodmod.MAX_CARD_TRIANGLES[lod]}
            outline = lodmod.pick_outline(
                cap,
                segments,
                len(sk.leaf_base),
                max(lodmod.HIGH_MAX - bark.triangles, 2 * segments * len(sk.leaf_base)),
            )
        else:
            outline = lodmod.pick_outline(
                {t: o for t, o in cluster_options.items() if t <= lodmod.MAX_CARD_TRIANGLES[lod]}
            )
        parts = []
        if bark.triangles:
            write_ply(out / f"{lod}_bark.ply", bark)
            parts.append(part_entry("bark", f"{lod}_bark.ply", bark, bark_colour, "bark.exr", False, 0.0))
        cover, seen = 1.0, []
        for step in range(COVER_STEPS + 1):
            leaves, clustered = lodmod.leaf_meshes(sk, lod, budget, seed, cov_leaf, cov_cluster, cover, outline)
            leaves = orient_faces(ground(leaves))
            write_ply(out / f"{lod}_leaf.ply", leaves)
            tex = "cluster.png" if clustered else "leaf.png"
            colour, level_sheen = toned(lod, tone, leaf_colour, sheen)
            entry = lod_entry(
                lod, parts + [part_entry("leaf", f"{lod}_leaf.ply", leaves, colour, tex, True, transl, level_sheen)]
            )
            if coverage is None or not clustered or step == COVER_STEPS:
                break
            # Cluster cards: match the high level's rendered coverage c.  Locally c ∝ cover^p;
            # p ≈ 0.7 on the presets (not 2: the cards overlap more as they grow), then the secant.
            got = float(far_coverage(out, entry, high_bounds, res=64, spp=4)[: lodmod.FAR_VIEWS].mean())
            want = float(coverage[: lodmod.FAR_VIEWS].mean())  # from the side, as the level's cards are made
            if got <= 0 or abs(got / want - 1.0) < COVER_TOLERANCE:
                break
            seen.append((math.log(cover), math.log(got)))
            p = COVER_EXPONENT
            if len(seen) >= 2 and abs(seen[-1][0] - seen[-2][0]) > 1e-6:
                p = float(np.clip((seen[-1][1] - seen[-2][1]) / (seen[-1][0] - seen[-2][0]), 0.3, 2.0))
            cover *= float(np.clip(want / got, 0.5, 2.0)) ** (1.0 / p)
        lods.append(entry)
        if lod == "high":
            high_bounds = np.array(entry["bounds"])
            coverage = far_coverage(out, entry, high_bounds)
            # The self-occlusion is smooth: half the resolution, repeated to the atlas's.
            views = far_views(out, entry, high_bounds, res=FAR_RES // 2, spp=8, shaded=True)
            a = views[..., 3:4]
            shading = np.where(a > 1e-4, views[..., :3] / np.maximum(a, 1e-4), 0.0).repeat(2, 1).repeat(2, 2)
            bark_rgba = np.concatenate([bark_tex, np.ones(bark_tex.shape[:2] + (1,), np.float32)], axis=2)
            high_meshes = [(bark, np.asarray(bark_colour), bark_rgba), (leaves, np.asarray(leaf_colour), leaf_tex)]
    far, atlas, scale = lodmod.impostor(
        high_meshes, high_bounds, seed=seed, coverage=coverage, shading=shading, cut=cut
    )
    write_texture(out / "far.png", atlas)
    # Two parts: the vertical cards and the horizontal one, each toned by its own [lod_tone] entry.
    far_parts = []
    for key, file, mesh in zip(("far", "far_top"), ("far_cards.ply", "far_top.ply"), lodmod.split_top(far)):
        if not len(mesh.faces):  # a crown that shows nothing from above (or only from above)
            continue
        write_ply(out / file, mesh)
        colour, level_sheen = toned(key, tone, scale, sheen)
        far_parts.append(part_entry("leaf", file, mesh, colour, "far.png", True, transl, level_sheen))
    lods.append(lod_entry("far", far_parts))
    meta = {
        "name": name,
        "source": "generated",
        "seed": int(seed),
        "hash": recipe_hash(recipe, seed),
        "leaf_shape": shape,
        "lods": lods,
    }
    write_json(out / "species.json", meta)
    return meta
