"""The tree library: presets, levels of detail, bounds, determinism, previews and mesh import."""

from __future__ import annotations

import shutil
import tomllib
from pathlib import Path

import numpy as np
import pytest

from forest.errors import ConfigError, ForestError
from forest.images import read_image
from forest.library import BUDGETS, LODS, open_library
from forest.library.build import generate
from forest.library.mesh import MeshData, cluster_decimate, decimate_to, read_ply
from forest.library.textures import read_texture

ROOT = Path(__file__).resolve().parents[1]
FIXTURES = Path(__file__).parent / "fixtures"
PRESETS = ("broadleaf", "conifer", "palm", "shrub", "fern", "grass")


@pytest.fixture(scope="module")
def lib():
    """The shipped library (built into library/cache/ if stale)."""
    lib = open_library(ROOT / "library")
    lib.build(previews=False, prune=False)
    return lib


@pytest.fixture()
def tmp_lib(tmp_path):
    """An empty library folder of its own."""
    return open_library(tmp_path / "lib")


def test_presets_are_listed(lib):
    assert set(PRESETS) <= set(lib.names())
    for name in PRESETS:
        sp = lib.resolve(name)
        assert sp.name == name and sp.source == "generated"
        assert [l.name for l in sp.lods] == list(LODS)


@pytest.mark.parametrize("name", PRESETS)
def test_budgets_bounds_and_files(lib, name):
    sp = lib.get(name)
    previous = None
    for lod in sp.lods:
        lo, hi = BUDGETS[lod.name]
        assert lo <= lod.triangles <= hi, (lod.name, lod.triangles)
        if previous is not None:
            assert lod.triangles < previous
        previous = lod.triangles
        verts, count = [], 0
        for part in lod.parts:
            assert part.kind in ("leaf", "bark")
            assert part.path.is_file() and part.path.suffix == ".ply"
            head = part.path.read_bytes()[:400]
            assert b"format binary_little_endian 1.0" in head
            for prop in (b"property float nx", b"property float u", b"property float v"):
                assert prop in head
            m = part.load()
            assert m.triangles == part.triangles and len(m.faces) > 0
            assert np.isfinite(m.vertices).all()
            assert np.allclose(np.linalg.norm(m.normals, axis=1), 1.0, atol=1e-3)
            assert m.faces.max() < len(m.vertices)
            used = m.vertices[np.unique(m.faces)].astype(np.float64)
            np.testing.assert_allclose(part.bounds, [used.min(0), used.max(0)], atol=1e-6)
            verts.append(used)
            count += m.triangles
            if part.kind == "leaf":
                assert part.tinted and 0 < part.translucency < 1
                tex = read_texture(part.texture)
                assert tex[..., 3].min() == 0.0 and tex[..., 3].max() == 1.0
                # Straight alpha: the detail stays near white right up to the card's edge.
                edge = (tex[..., 3] > 0.05) & (tex[..., 3] < 0.95)
                assert tex[..., :3][edge].mean() > 0.5
            else:
                assert not part.tinted and part.texture is None
        allv = np.concatenate(verts)
        assert count == lod.triangles
        # Exact bounds: the stored box is the vertices' box.
        np.testing.assert_allclose(lod.bounds, [allv.min(0), allv.max(0)], atol=1e-6)
    # Base at the origin, Y up: the trunk starts at y = 0 near the axis.
    high = sp.lods[0]
    assert abs(high.bounds[0][1]) < 0.1 and high.bounds[1][1] > 0.5
    bark = [p for p in high.parts if p.kind == "bark"][0].load()
    low_pts = bark.vertices[bark.vertices[:, 1] < 0.05]
    assert len(low_pts)
    if name in ("broadleaf", "conifer", "palm"):  # one trunk, standing on the origin
        assert np.linalg.norm(low_pts[:, [0, 2]].mean(axis=0)) < 0.05
    else:  # clumps: stems rise from around the origin
        assert np.linalg.norm(low_pts[:, [0, 2]], axis=1).min() < 0.3


def test_generation_is_deterministic(tmp_path):
    recipe = tomllib.loads((ROOT / "library/presets/fern.toml").read_text())
    recipe["tree"]["trunks"] = 4  # a smaller clump: same code paths, less time
    generate(recipe, 3, tmp_path / "a", name="fern")
    generate(recipe, 3, tmp_path / "b", name="fern")
    generate(recipe, 4, tmp_path / "c", name="fern")
    files = sorted(p.name for p in (tmp_path / "a").iterdir())
    assert "high_leaf.ply" in files and "far.png" in files and "species.json" in files
    for f in files:
        assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes(), f
    assert (tmp_path / "a/high_leaf.ply").read_bytes() != (tmp_path / "c/high_leaf.ply").read_bytes()
    # Seed variations are different individuals of one species, of similar size.
    a, c = read_ply(tmp_path / "a/high_bark.ply"), read_ply(tmp_path / "c/high_bark.ply")
    ha, hc = a.bounds()[1][1], c.bounds()[1][1]
    assert 0.6 < ha / hc < 1.6


@pytest.mark.parametrize("name", PRESETS)
def test_lower_levels_keep_silhouette_and_colour(lib, name):
    from forest.library.preview import render_lod

    sp = lib.get(name)
    imgs = {lod: render_lod(sp, lod, size=(40, 40), spp=4) for lod in ("high", "low", "far")}
    cov = {k: float(v[..., 3].mean()) for k, v in imgs.items()}
    assert cov["high"] > 0.01
    assert abs(cov["low"] - cov["high"]) / cov["high"] < 0.25, cov
    assert abs(cov["far"] - cov["high"]) / cov["high"] < 0.3, cov
    # Colour: premultiplied sums over alpha give the mean colour of the tree's pixels.
    mean = {k: v[..., :3].sum((0, 1)) / max(v[..., 3].sum(), 1e-9) for k, v in imgs.items()}
    chroma = {k: m / m.sum() for k, m in mean.items()}
    assert np.abs(chroma["low"] - chroma["high"]).max() < 0.06, chroma
    # Silhouette: the alpha masks overlap (intersection over union of the covered pixels).
    hi_m, lo_m = imgs["high"][..., 3] > 0.05, imgs["low"][..., 3] > 0.05
    assert (hi_m & lo_m).sum() / (hi_m | lo_m).sum() > 0.5


def test_resolve_names_seeds_and_errors(lib, tmp_path):
    with pytest.raises(ForestError, match="unknown species 'maple'"):
        lib.resolve("maple")
    with pytest.raises(ForestError, match="broadleaf"):
        lib.resolve("maple")
    # A mesh path is imported on the fly, relative to the config's folder.
    shutil.copy(FIXTURES / "tree.glb", tmp_path / "tree.glb")
    lib2 = open_library(tmp_path / "lib")
    sp = lib2.resolve("tree.glb", tmp_path)
    assert sp.source == "imported" and sp.lods[0].triangles == 352
    assert lib2.resolve("tree.glb", tmp_path).folder == sp.folder


def test_seed_variation_and_preview_follow_the_recipe(tmp_path):
    root = tmp_path / "lib"
    (root / "presets").mkdir(parents=True)
    recipe = tomllib.loads((ROOT / "library/presets/fern.toml").read_text())
    recipe["tree"]["trunks"] = 4
    import tomli_w

    (root / "presets/fern.toml").write_text(tomli_w.dumps(recipe))
    (root / "manifest.toml").write_text(
        'version = 1\n[species.fern]\nsource = "generated"\nrecipe = "presets/fern.toml"\nseed = 1\n'
    )
    lib = open_library(root)
    a = lib.get("fern")
    b = lib.resolve("fern@2")
    assert a.hash != b.hash and a.folder != b.folder
    pa = a.preview
    img = read_image(pa)
    assert img.shape == (192, 192, 4) and 0.005 < img[..., 3].mean() < 0.9
    # Editing the recipe gives a new hash, so a new folder and a new preview.
    recipe["tree"]["leaf_colour"] = [0.2, 0.1, 0.02]
    (root / "presets/fern.toml").write_text(tomli_w.dumps(recipe))
    fresh = open_library(root)
    assert not fresh.is_fresh("fern")
    from forest.library.build import recipe_hash
    from forest.library.generator import validate_recipe

    assert recipe_hash(validate_recipe(recipe), 1) != a.hash
    # A bad recipe names the file and the field.
    recipe["level"][0]["segmnts"] = 3
    (root / "presets/fern.toml").write_text(tomli_w.dumps(recipe))
    with pytest.raises(ConfigError, match=r"fern\.toml: level\[0\]\.segmnts: unknown key"):
        open_library(root).get("fern")


@pytest.mark.parametrize(
    "fixture,options",
    [
        ("tree.obj", {}),
        ("tree.ply", {}),
        ("tree.glb", {}),
        ("tree_zup_mm.stl", {"units": "mm"}),
    ],
)
def test_import_mesh_formats(tmp_lib, fixture, options):
    from forest.library.importer import add_species

    sp = add_species(tmp_lib, FIXTURES / fixture, "oak", preview=fixture == "tree.obj", **options)
    assert sp.name == "oak" and sp.source == "imported"
    # Normalised: Y up, base at the origin, metres (the fixture is a 4.2 m tree, 2.4 m crown).
    lo, hi = sp.bounds
    np.testing.assert_allclose(lo[1], 0.0, atol=1e-5)
    np.testing.assert_allclose(hi[1] - lo[1], 4.2, atol=0.01)
    np.testing.assert_allclose(hi[[0, 2]] - lo[[0, 2]], [2.4, 2.4], atol=0.05)
    np.testing.assert_allclose((lo + hi)[[0, 2]], [0, 0], atol=1e-5)
    assert [l.name for l in sp.lods] == list(LODS)
    if fixture == "tree.obj":
        assert sp.preview.is_file() and read_image(sp.preview).shape[2] == 4
    # The manifest knows it; a fresh Library resolves it by name.
    again = open_library(tmp_lib.root).resolve("oak")
    assert again.lods[0].triangles == sp.lods[0].triangles == 352
    assert tomllib.loads(tmp_lib.manifest_path.read_text())["species"]["oak"]["source"] == "imported"
    if fixture in ("tree.obj", "tree.glb"):
        parts = {p.kind: p for p in sp.lods[0].parts}
        assert set(parts) == {"leaf", "surface"}
        assert parts["leaf"].tinted and not parts["surface"].tinted
        if fixture == "tree.obj":  # MTL Kd values are linear colours
            np.testing.assert_allclose(parts["leaf"].colour, [0.06, 0.16, 0.03], atol=0.005)
            np.testing.assert_allclose(parts["surface"].colour, [0.12, 0.08, 0.05], atol=0.005)


def test_import_replaces_only_with_force(tmp_lib):
    from forest.library.importer import add_species

    add_species(tmp_lib, FIXTURES / "tree.obj", "oak", preview=False)
    with pytest.raises(ForestError, match="already exists"):
        add_species(tmp_lib, FIXTURES / "tree.glb", "oak", preview=False)
    sp = add_species(tmp_lib, FIXTURES / "tree.obj", "oak", height=10.0, force=True, preview=False)
    np.testing.assert_allclose(sp.bounds[1][1], 10.0, atol=1e-4)
    assert tmp_lib.manifest_path.read_text().count("[species.oak]") == 1


@pytest.mark.parametrize(
    "fixture,message",
    [
        ("empty.obj", "mesh is empty"),
        ("lines.obj", "only points or lines"),
        ("points.ply", "no triangles"),
        ("nan.obj", "NaN"),
        ("garbage.glb", "cannot read mesh"),
        ("missing.obj", "not found"),
        ("tree.mtl", "unsupported mesh format"),
    ],
)
def test_bad_meshes_are_rejected(tmp_lib, fixture, message):
    from forest.library.importer import add_species

    with pytest.raises(ForestError, match=message) as e:
        add_species(tmp_lib, FIXTURES / fixture, "bad")
    assert fixture in str(e.value) and "\n" not in str(e.value)
    assert not (tmp_lib.root / "imported" / "bad").exists()
    assert "bad" not in tmp_lib.names()


def test_size_limits(tmp_lib, monkeypatch):
    from forest.library import importer

    monkeypatch.setattr(importer, "MAX_FILE_BYTES", 4096)
    with pytest.raises(ForestError, match=r"tree\.obj: mesh file is 8\.\d KiB, over the 4\.0 KiB import limit"):
        importer.add_species(tmp_lib, FIXTURES / "tree.obj", "big")
    monkeypatch.setattr(importer, "MAX_FILE_BYTES", 1 << 30)
    monkeypatch.setattr(importer, "MAX_TRIANGLES", 100)
    with pytest.raises(ForestError, match="more than 100 triangles"):
        importer.add_species(tmp_lib, FIXTURES / "tree.obj", "big")
    assert not list((tmp_lib.root).glob("imported/*"))


def test_decimation_keeps_bounds_and_hits_the_budget():
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=6, radius=2.0)
    from forest.library.mesh import vertex_normals

    m = MeshData(
        sphere.vertices.astype(np.float32),
        sphere.faces.astype(np.uint32),
        vertex_normals(sphere.vertices, sphere.faces),
        np.zeros((len(sphere.vertices), 2), np.float32),
    )
    for target in (12_000, 1_500):
        d = decimate_to(m, target)
        assert 0.7 * target <= d.triangles <= target, d.triangles
        b, bd = m.bounds(), d.bounds()
        assert np.all(bd[0] >= b[0] - 1e-6) and np.all(bd[1] <= b[1] + 1e-6)
        assert np.all(bd[1] - bd[0] > 0.9 * (b[1] - b[0]))
    c = cluster_decimate(m, 10.0)
    assert c.triangles == 0


def run_cli(args: list[str]) -> int:
    from forest.cli import main

    try:
        main(args)
    except SystemExit as e:
        return int(e.code or 0)
    return 0


def test_cli_list_build_preview(lib, capsys, tmp_path):
    main = run_cli
    before = sorted(p.name for p in lib.cache.iterdir())
    assert main(["library", "build", "--quiet", "--no-previews"]) == 0
    assert capsys.readouterr().out == ""
    # Idempotent: a fresh cache is left as it is.
    assert all(lib.is_fresh(n) for n in PRESETS)
    assert set(before) >= {lib.get(n).folder.name for n in PRESETS}
    assert {lib.get(n).folder.name for n in PRESETS} <= {p.name for p in lib.cache.iterdir()}
    main(["library", "list", "--json"])
    import json

    rows = json.loads(capsys.readouterr().out)
    by = {r["name"]: r for r in rows}
    assert set(PRESETS) <= set(by)
    assert by["conifer"]["lods"]["high"] == lib.get("conifer").lods[0].triangles
    out = tmp_path / "p.png"
    main(["library", "preview", "shrub", "--lod", "low", "--size", "32", "--spp", "2", "-o", str(out)])
    assert read_image(out).shape == (32, 32, 4)
    assert main(["library", "add", str(FIXTURES / "nan.obj"), "--name", "x", "--library", str(tmp_path / "l")]) == 2
    err = capsys.readouterr().err
    assert "nan.obj" in err and err.count("\n") == 1


def test_import_leaf_cards_thin_as_cards(lib, tmp_lib, tmp_path):
    """A tree made of leaf cards (here: the shrub's high level as glTF) keeps its cover at low levels."""
    import trimesh

    from forest.library.importer import add_species
    from forest.library.preview import render_lod

    scene = trimesh.Scene()
    for part in lib.get("shrub").lods[0].parts:
        m = part.load()
        tm = trimesh.Trimesh(m.vertices, m.faces, process=False)
        tm.visual = trimesh.visual.TextureVisuals(
            material=trimesh.visual.material.PBRMaterial(
                baseColorFactor=[int(255 * c ** (1 / 2.2)) for c in part.colour] + [255]
            )
        )
        scene.add_geometry(tm, geom_name="leaves" if part.kind == "leaf" else "bark")
    path = tmp_path / "cards.glb"
    scene.export(path)
    sp = add_species(tmp_lib, path, "cards", preview=False)
    for lod in sp.lods:
        _lo, hi = BUDGETS[lod.name]
        assert lod.triangles <= hi, (lod.name, lod.triangles)
    leaf_high = [p for p in sp.lod("high").parts if p.kind == "leaf"][0].load()
    leaf_low = [p for p in sp.lod("low").parts if p.kind == "leaf"][0].load()
    # Whole cards survive: the kept pieces have the cards' vertex-to-face ratio (bent quads: 6 / 4).
    assert len(leaf_low.vertices) * len(leaf_high.faces) == len(leaf_high.vertices) * len(leaf_low.faces)
    cov = {k: float(render_lod(sp, k, size=(40, 40), spp=4)[..., 3].mean()) for k in ("high", "low")}
    assert abs(cov["low"] - cov["high"]) / cov["high"] < 0.3, cov


def test_import_textured_obj_keeps_alpha(tmp_lib):
    """An OBJ whose material has a map_Kd RGBA image: the texture and its alpha mask come along."""
    from forest.library.importer import add_species
    from forest.library.preview import render_lod

    sp = add_species(tmp_lib, FIXTURES / "cards.obj", "cards", preview=False)
    part = sp.lods[0].parts[0]
    assert part.kind == "leaf" and part.tinted and part.texture is not None
    src = read_texture(FIXTURES / "leaf.png")
    tex = read_texture(part.texture)
    assert tex.shape == src.shape
    np.testing.assert_allclose(tex[..., 3], src[..., 3], atol=1 / 255)
    m = part.load()
    assert m.uv.min() >= 0 and m.uv.max() <= 1 and np.ptp(m.uv, axis=0).min() > 0.9
    # The card's transparent texels stay transparent: coverage is well below a solid card's.
    img = render_lod(sp, "high", size=(32, 32), spp=4)
    far = render_lod(sp, "far", size=(32, 32), spp=4)
    solid = (img[..., 3] > 0).mean()
    assert 0.02 < img[..., 3].mean() < 0.9 * solid + 0.05
    assert abs(far[..., 3].mean() - img[..., 3].mean()) / img[..., 3].mean() < 0.35


def test_import_textured_glb(tmp_lib, tmp_path):
    """glTF binary with an embedded base-colour texture: texture, alpha and uv survive the import."""
    import trimesh

    from forest.library.importer import add_species

    scene = trimesh.load(FIXTURES / "cards.obj", force="scene")
    scene.export(tmp_path / "cards.glb")
    sp = add_species(tmp_lib, tmp_path / "cards.glb", "cards", preview=False)
    part = sp.lods[0].parts[0]
    assert part.kind == "leaf" and part.texture is not None
    src, tex = read_texture(FIXTURES / "leaf.png"), read_texture(part.texture)
    np.testing.assert_allclose(tex[..., 3], src[..., 3], atol=1 / 255)
    # uv keep the card upright: the leaf's stalk (v = 0) is at the bottom in both imports.
    obj = add_species(tmp_lib, FIXTURES / "cards.obj", "cards_obj", preview=False).lods[0].parts[0].load()
    glb = part.load()
    order_o, order_g = np.lexsort(obj.vertices.T), np.lexsort(glb.vertices.T)
    np.testing.assert_allclose(obj.uv[order_o], glb.uv[order_g], atol=1e-5)
