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
PRESETS = ("broadleaf", "birch", "conifer", "pine", "palm", "shrub", "fern", "grass")


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
                # Straight alpha: the colour stays as light at the card's edge as inside it
                # (premultiplied alpha would darken the edge texels towards black).
                edge = (tex[..., 3] > 0.05) & (tex[..., 3] < 0.95)
                inside = tex[..., 3] >= 0.95
                assert tex[..., :3][edge].mean() > 0.6 * tex[..., :3][inside].mean()
            else:  # bark: untinted, a tileable detail factor with mean 1 (colour stays the albedo)
                assert not part.tinted and part.texture.name == "bark.exr"
                tex = read_texture(part.texture)
                np.testing.assert_allclose(tex[..., :3].mean(axis=(0, 1)), 1.0, atol=0.01)
                assert tex[..., :3].max() > 1.2 and tex[..., :3].min() < 0.8 and tex[..., 3].min() == 1.0
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
    if name in ("broadleaf", "birch", "conifer", "pine", "palm"):  # one trunk, standing on the origin
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


@pytest.mark.parametrize("name", ["broadleaf", "conifer"])
def test_the_far_level_covers_the_crown_seen_from_above(lib, name):
    """The far impostor's horizontal card: from 45° and 80° above the horizon (views its build never renders) the
    far level covers what the high level covers, where three vertical cards alone covered 0.57 and 0.32 of a
    broadleaf crown from 60° and 85° (they are edge-on from above).  It is its own part, facing up."""
    from forest.library.preview import render_lod

    sp = lib.get(name)
    for elevation in (45.0, 80.0):
        cov = {lod: float(render_lod(sp, lod, size=(48, 48), spp=4, elevation=elevation)[..., 3].mean())
               for lod in ("high", "far")}  # fmt: skip
        assert abs(cov["far"] / cov["high"] - 1.0) < 0.2, (elevation, cov)
    cards, top = (p.load() for p in sp.lod("far").parts)  # two parts: the vertical cards, then the horizontal one
    assert [p.path.name for p in sp.lod("far").parts] == ["far_cards.ply", "far_top.ply"]

    def normals(m):
        n = np.cross(m.vertices[m.faces[:, 1]] - m.vertices[m.faces[:, 0]],
                     m.vertices[m.faces[:, 2]] - m.vertices[m.faces[:, 0]])  # fmt: skip
        return n / np.linalg.norm(n, axis=1, keepdims=True)

    assert len(top.faces) and (normals(top)[:, 1] > 0.99).all()
    assert len(cards.faces) and (np.abs(normals(cards)[:, 1]) < 0.01).all()
    y = top.vertices[:, 1]
    lo, hi = np.asarray(sp.lods[0].bounds)[:, 1]
    assert np.ptp(y) < 1e-4 and lo + 0.3 * (hi - lo) < y.mean() < hi


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
        assert set(parts) == {"leaf", "bark"}  # the trunk's material is named bark
        assert parts["leaf"].tinted and not parts["bark"].tinted
        if fixture == "tree.obj":  # MTL Kd values are linear colours
            np.testing.assert_allclose(parts["leaf"].colour, [0.06, 0.16, 0.03], atol=0.005)
            np.testing.assert_allclose(parts["bark"].colour, [0.12, 0.08, 0.05], atol=0.005)


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
        ("huge.obj", r"vertex coordinates up to 1e\+308, beyond ±1e\+09"),
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


def _faces_against_normals(m) -> tuple[int, int]:
    """(faces whose winding's normal points against their stored vertex normals, faces with area)."""
    v = m.vertices.astype(np.float64)
    f = m.faces.astype(np.int64)
    g = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    n = m.normals.astype(np.float64)[f].sum(axis=1)
    real = np.linalg.norm(g, axis=1) > 1e-12
    return int(((np.einsum("ij,ij->i", g, n) < 0) & real).sum()), int(real.sum())


@pytest.mark.parametrize("name", PRESETS + ("tower", "apartment", "house", "warehouse"))
def test_winding_agrees_with_normals(lib, name):
    """Every triangle of every part and level is wound counter-clockwise about its stored normals
    (renderers that take the front face from the winding see the side the normals describe)."""
    sp = lib.get(name)
    for lod in sp.lods:
        for part in lod.parts:
            bad, total = _faces_against_normals(part.load())
            assert total > 0 and bad == 0, (lod.name, part.path.name, bad, total)


def test_leaf_cards_are_rectangles_facing_up():
    """Leaf cards: width ⟂ length (no sheared cards) and the face normal ŵ × d̂ points up."""
    from forest.library.generator import grow, validate_recipe

    for name in ("broadleaf", "conifer", "palm"):
        sk = grow(validate_recipe(tomllib.loads((ROOT / f"library/presets/{name}.toml").read_text())), 1)
        np.testing.assert_allclose(np.sum(sk.leaf_width * sk.leaf_dir, axis=1), 0.0, atol=1e-6)
        assert (np.cross(sk.leaf_width, sk.leaf_dir)[:, 1] >= -1e-9).all()


def test_textures_keep_the_colour_the_albedo(lib):
    """Detail factors have mean 1 where the part is (leaves within 2 %, clipped at 1; bark exactly),
    and the bark tiles: its opposite edges continue each other as neighbouring rows do."""
    from forest.library.textures import BARK_STYLES, SHAPES, bark_rgb, cluster_rgba, leaf_rgba

    for shape in SHAPES:
        for tex in (leaf_rgba(shape), cluster_rgba(shape)):
            covered = tex[..., 3] >= 0.5
            mean = tex[..., :3][covered].mean(axis=0)
            assert (mean > 0.98).all() and tex[..., :3].max() <= 1.0, (shape, mean)
    for style in BARK_STYLES:
        b = bark_rgb(style).astype(np.float64)
        np.testing.assert_allclose(b.mean(axis=(0, 1)), 1.0, atol=1e-3)
        inner_v = np.abs(np.diff(b, axis=0)).mean()
        inner_u = np.abs(np.diff(b, axis=1)).mean()
        assert np.abs(b[0] - b[-1]).mean() < 2.0 * inner_v, style
        assert np.abs(b[:, 0] - b[:, -1]).mean() < 2.0 * inner_u, style


def test_bark_uv_tiles_along_the_stem(lib):
    """Trunk uv: u once around, v climbing one tile per circumference (∫ ds / 2πr), several tiles up."""
    bark = [p for p in lib.get("broadleaf").lod("high").parts if p.kind == "bark"][0].load()
    trunk = np.linalg.norm(bark.vertices[:, [0, 2]], axis=1) < 0.6
    u, v, y = bark.uv[trunk, 0], bark.uv[trunk, 1], bark.vertices[trunk, 1]
    assert u.min() == 0.0 and u.max() == 1.0
    low, high = v[y < 1.0], v[(y > 3.0) & (y < 4.0)]
    assert len(low) and len(high) and high.mean() > low.mean() + 1.0  # more than a tile in 3 m of a trunk


@pytest.mark.parametrize("name", PRESETS)
def test_calibrated_colours(name):
    """Presets hold measured albedos: green leaves of luminance 0.08–0.25 (PROSPECT-D / LOPEX93 range),
    translucency 0.15–0.6, bark of luminance 0.07–0.25 (0.3–0.5 for a birch's white "papery" bark, Juola et
    al. 2020); the cited sources are in the preset."""
    from forest.library.generator import validate_recipe

    text = (ROOT / f"library/presets/{name}.toml").read_text()
    tree = validate_recipe(tomllib.loads(text))["tree"]
    y = np.array([0.2126, 0.7152, 0.0722])  # Rec. 709 / sRGB luminance of linear RGB
    leaf, bark = np.array(tree["leaf_colour"]), np.array(tree["bark_colour"])
    assert leaf[1] > leaf[0] > leaf[2] and 0.08 <= leaf @ y <= 0.25, leaf
    assert 0.15 <= tree["translucency"] <= 0.6
    lo, hi = (0.3, 0.5) if tree["bark_texture"] == "papery" else (0.07, 0.25)
    assert lo <= bark @ y <= hi, bark
    assert "PROSPECT-D" in text and "Féret" in text


def test_individuals_are_deterministic_and_different(tmp_path):
    """individual(lib, name, k) is NAME@(seed + k); individuals differ in height, width and branch angles."""
    from forest.library import individual, individuals
    from forest.library.generator import grow, validate_recipe

    root = tmp_path / "lib"
    (root / "presets").mkdir(parents=True)
    recipe = tomllib.loads((ROOT / "library/presets/fern.toml").read_text())
    recipe["tree"]["trunks"] = 4
    import tomli_w

    (root / "presets/fern.toml").write_text(tomli_w.dumps(recipe))
    (root / "manifest.toml").write_text(
        'version = 1\n[species.fern]\nsource = "generated"\nrecipe = "presets/fern.toml"\nseed = 5\n'
    )
    lib = open_library(root, presets=False)
    a0, a2 = individual(lib, "fern", 0), individual(lib, "fern", 2)
    assert a0.folder == lib.get("fern").folder and a2.folder == lib.resolve("fern@7").folder
    assert individual(open_library(root, presets=False), "fern", 2).hash == a2.hash
    assert [s.hash for s in individuals(lib, "fern", 3)] == [a0.hash, lib.resolve("fern@6").hash, a2.hash]
    with pytest.raises(ForestError, match="whole number"):
        individual(lib, "fern", -1)
    # Individuals of the trees: heights, crown widths and limb angles spread over the seeds.
    for name in ("broadleaf", "conifer", "palm"):
        r = validate_recipe(tomllib.loads((ROOT / f"library/presets/{name}.toml").read_text()))
        stats = []
        for seed in range(1, 7):
            sk = grow(r, seed)
            pts = np.concatenate([lv.points.reshape(-1, 3) for lv in sk.levels] + [sk.leaf_base])
            limbs = sk.levels[1]
            angle = np.degrees(np.arccos(np.clip(limbs.tangents[:, 0, 1], -1, 1))).mean()
            stats.append([pts[:, 1].max(), np.ptp(pts[:, 0]) + np.ptp(pts[:, 2]), angle])
        s = np.array(stats)
        spread = np.ptp(s, axis=0) / s.mean(axis=0)
        assert spread[0] > 0.08 and spread[1] > 0.08 and np.ptp(s[:, 2]) > 3.0, (name, s)


def test_whorls_and_two_ranked_leaflets():
    """Conifer branches come in whorls (same height, evenly spread around); palm leaflets in two ranks."""
    from forest.library.generator import _children_offsets, grow, validate_recipe

    rng = np.random.default_rng(0)
    stem, t, _k, m, j = _children_offsets(np.array([10, 15]), np.array([0.1, 0.2]), rng, whorl=5)
    for s in (0, 1):
        tt = t[stem == s].reshape(-1, 5)
        assert np.ptp(tt, axis=1).max() == 0.0 and (np.diff(tt[:, 0]) > 0).all()
    assert list(j[:5]) == [0, 1, 2, 3, 4] and list(m[:10]) == [0] * 5 + [1] * 5
    r = validate_recipe(tomllib.loads((ROOT / "library/presets/palm.toml").read_text()))
    sk = grow(r, 1)
    # Leaflets in two ranks: the azimuth about their rachis (0 = horizontal, sideways) is ±leaf_lift
    # on either side, so a frond is a flat feather (a shallow V), not a bottle-brush.
    from scipy.spatial import cKDTree

    rachis = sk.levels[1]
    _, i = cKDTree(rachis.points.reshape(-1, 3)).query(sk.leaf_base)
    tan = rachis.tangents.reshape(-1, 3)[i]
    hs = np.cross(tan, [0.0, 1.0, 0.0])
    hs /= np.linalg.norm(hs, axis=1, keepdims=True)
    hb = np.cross(hs, tan)
    across = sk.leaf_dir - np.sum(sk.leaf_dir * tan, axis=1, keepdims=True) * tan
    phi = np.degrees(np.arctan2(np.sum(across * hb, axis=1), np.abs(np.sum(across * hs, axis=1))))
    lift = r["tree"]["leaf_lift"]
    assert np.mean(np.abs(phi - lift) < 20.0) > 0.8, np.percentile(phi, [10, 50, 90])


@pytest.mark.parametrize(
    "table,key,value,field",
    [
        ("tree", "bark_texture", "mossy", r"tree\.bark_texture: must be one of furrowed"),
        ("tree", "crown_var", 2.0, r"tree\.crown_var: must be a number in \[0, 0\.9\]"),
        ("tree", "leaf_lift", -5.0, r"tree\.leaf_lift"),
        ("level", "whorl", 0, r"level\[1\]\.whorl: must be a whole number"),
        ("level", "whorl", 2.5, r"level\[1\]\.whorl"),
        ("tree", "leaf_cut", "hull", r"tree\.leaf_cut: must be one of outline, quad"),
    ],
)
def test_new_recipe_keys_are_checked(table, key, value, field):
    from forest.library.generator import validate_recipe

    recipe = tomllib.loads((ROOT / "library/presets/conifer.toml").read_text())
    if table == "tree":
        recipe["tree"][key] = value
    else:
        recipe["level"][1][key] = value
    with pytest.raises(ConfigError, match=field):
        validate_recipe(recipe, "conifer.toml")


def test_build_prunes_stale_cache_folders_only_when_asked(tmp_path):
    """The build cache is shared by every install of a user: a build leaves others' folders unless --prune."""
    root = tmp_path / "lib"
    (root / "presets").mkdir(parents=True)
    shutil.copy(ROOT / "library/presets/grass.toml", root / "presets/grass.toml")
    (root / "manifest.toml").write_text(
        'version = 1\n[species.grass]\nsource = "generated"\nrecipe = "presets/grass.toml"\nseed = 1\n'
    )
    stale = root / "cache" / "grass-0123456789abcdef"
    stale.mkdir(parents=True)
    args = ["library", "build", "--library", str(root), "--quiet", "--no-previews"]
    assert run_cli(args) == 0
    assert stale.is_dir()  # another version's build is left alone
    assert run_cli([*args, "--prune"]) == 0
    assert not stale.exists() and open_library(root).is_fresh("grass")


# ---------------------------------------------------------------------------
# Cut cards
# ---------------------------------------------------------------------------


def _outline_texels(alpha: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Which texel centres lie inside the outline (matplotlib's point-in-polygon, not forest's)."""
    from matplotlib.path import Path as MPath

    n_r, n_c = alpha.shape
    yy, xx = np.mgrid[0:n_r, 0:n_c]
    pts = np.stack([(xx.ravel() + 0.5) / n_c, (yy.ravel() + 0.5) / n_r], axis=1)
    return MPath(uv).contains_points(pts, radius=1e-9).reshape(n_r, n_c)


@pytest.mark.parametrize("shape", ["broad", "needle", "frond", "blade", "fern"])
def test_card_outlines_hold_the_leaf(shape):
    """An outline is convex, inside the card, holds (almost) all of the texture's alpha, and the
    least-area outline of each triangle count shrinks as triangles are allowed."""
    from forest.library.outline import MAX_LOSS, card_outlines
    from forest.library.textures import cluster_rgba, leaf_rgba

    for rgba in (leaf_rgba(shape), cluster_rgba(shape)):
        alpha = rgba[..., 3].astype(np.float64)
        options = card_outlines(alpha, 4)
        areas = [options[t].area for t in (2, 3, 4)]
        assert areas[0] <= 1.0 and areas[0] >= areas[1] >= areas[2], areas
        for t, o in options.items():
            assert o.triangles <= t and o.fan().shape == (o.triangles, 3)
            assert (o.uv >= -1e-9).all() and (o.uv <= 1 + 1e-9).all()
            d = np.roll(o.uv, -1, axis=0) - o.uv
            turn = d[:, 0] * np.roll(d, -1, axis=0)[:, 1] - d[:, 1] * np.roll(d, -1, axis=0)[:, 0]
            assert (turn >= -1e-9).all()  # convex, counter-clockwise in (u, v)
            inside = _outline_texels(alpha, o.uv)
            lost = alpha[~inside].sum() / alpha.sum()
            assert lost <= MAX_LOSS + 2e-3, (shape, t, lost)
            # Area: the uv polygon's own area, against the texels it holds.
            assert abs(inside.mean() - o.area) < 0.02
            assert o.fill == pytest.approx(alpha.mean() / o.area)


def test_outlines_pay_where_cards_are_mostly_transparent():
    """A narrow leaflet, a leaf cluster and a needle cluster lose at least a third of their card at two triangles."""
    from forest.library.outline import card_outline
    from forest.library.textures import cluster_rgba, leaf_rgba

    assert card_outline(leaf_rgba("frond")[..., 3], 2).area < 0.4
    assert card_outline(cluster_rgba("broad")[..., 3], 2).area < 0.67
    assert card_outline(cluster_rgba("needle")[..., 3], 2).area < 0.67
    # An opaque texture has nothing to cut: the outline is the card.
    assert card_outline(np.ones((16, 16)), 4).area == 1.0


def _render_alpha(meshes: list, texture: np.ndarray, size: int = 96, spp: int = 64) -> np.ndarray:
    """Coverage of ``meshes`` seen from +Y (orthographic), alpha-tested by ``texture`` in Mitsuba's scalar_rgb."""
    from forest.runtime import mitsuba

    mi = mitsuba("scalar_rgb")
    scene: dict = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 64, "rr_depth": 64},
        "sensor": {
            "type": "orthographic",
            "to_world": mi.ScalarTransform4f().look_at(origin=[0, 10, 0], target=[0, 0, 0], up=[0, 0, 1]),
            "film": {"type": "hdrfilm", "width": size, "height": size, "pixel_format": "rgba"},
            "sampler": {"type": "independent", "sample_count": spp},
        },
    }
    opacity = {"type": "bitmap", "bitmap": mi.Bitmap(texture[..., 3:4].astype(np.float32)), "raw": True}
    for k, m in enumerate(meshes):
        mesh = mi.Mesh(f"m{k}", len(m.vertices), len(m.faces), has_vertex_texcoords=True)
        p = mi.traverse(mesh)
        p["vertex_positions"] = m.vertices.astype(np.float32).ravel()
        p["faces"] = m.faces.astype(np.uint32).ravel()
        p["vertex_texcoords"] = m.uv.astype(np.float32).ravel()
        p.update()
        scene[f"m{k}"] = mesh
        mesh.set_bsdf(mi.load_dict({"type": "mask", "opacity": opacity, "material": {"type": "diffuse"}}))
    img = np.array(mi.render(mi.load_dict(scene), spp=spp, seed=1))
    return img[..., 3]


@pytest.mark.parametrize("shape", ["frond", "needle"])
def test_cut_cards_render_what_quads_render(shape):
    """Leaf cards cut to their outline cover the same pixels as whole quads through Mitsuba's alpha test
    (flat and bent cards): the cut removes only transparent texels."""
    from forest.library.lod import bent_cards, cards
    from forest.library.outline import card_outline
    from forest.library.textures import cluster_rgba

    tex = cluster_rgba(shape)
    outline = card_outline(tex[..., 3], 2)
    assert outline.area < 0.8
    rng = np.random.default_rng(3)
    n = 6
    base = np.column_stack([rng.uniform(-2, 2, n), rng.uniform(0, 1, n), rng.uniform(-2, 2, n)])
    d = np.column_stack([rng.normal(size=n), 0.1 * rng.normal(size=n), rng.normal(size=n)])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    w = np.cross(d, [0.0, 1.0, 0.0])
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    size = np.column_stack([np.full(n, 2.0), np.full(n, 1.5)])
    for make in (lambda o: cards(base, d, w, size, outline=o), lambda o: bent_cards(base, d, w, size, 3, 30.0, o)):
        quad_mesh, cut_mesh = make(None), make(outline)
        assert cut_mesh.triangles <= quad_mesh.triangles
        a_quad, a_cut = _render_alpha([quad_mesh], tex), _render_alpha([cut_mesh], tex)
        assert a_quad.mean() > 0.02
        assert abs(a_cut.mean() - a_quad.mean()) < 0.01 * a_quad.mean() + 2e-3, (a_cut.mean(), a_quad.mean())
        assert np.abs(a_cut - a_quad).mean() < 0.03


def test_cut_cards_are_built_where_they_pay(lib):
    """The shipped trees cut their cluster and far cards (and the palm's leaflets); the high level stays
    within HIGH_MAX triangles, every leaf card stays one connected sheet with uv inside the card, and a
    recipe with leaf_cut = "quad" keeps whole quads."""
    from forest.library import lod as lodmod
    from forest.library.mesh import components

    for name in PRESETS:
        sp = lib.get(name)
        assert sp.lod("high").triangles <= lodmod.HIGH_MAX
        for lod in sp.lods:
            leaf = [p for p in lod.parts if p.kind == "leaf"][0].load()
            assert (leaf.uv >= -1e-6).all() and (leaf.uv <= 1 + 1e-6).all()
            if lod.name in ("medium", "low"):
                _, comp = components(leaf.faces, len(leaf.vertices))
                uv = leaf.uv.astype(np.float64)[leaf.faces.astype(np.int64)]
                e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
                area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
                assert np.bincount(comp, weights=area).max() < 0.75, name  # cut: less than 3/4 of each card
        assert sp.lod("far").triangles <= 4 * lodmod.FAR_TILES
    palm = lib.get("palm").lod("high").parts
    uv = [p for p in palm if p.kind == "leaf"][0].load().uv
    assert uv[:, 0].min() > 0.1 and uv[:, 0].max() < 0.9  # leaflets cut to the leaflet, not the card


def test_leaf_cut_quad_keeps_quads(tmp_path):
    from forest.library import lod as lodmod

    recipe = tomllib.loads((ROOT / "library/presets/fern.toml").read_text())
    recipe["tree"]["trunks"] = 3
    recipe["tree"]["leaf_cut"] = "quad"
    meta = generate(recipe, 2, tmp_path / "q", name="fern")
    for entry in meta["lods"]:
        leaf = [p for p in entry["parts"] if p["kind"] == "leaf"][0]
        m = read_ply(tmp_path / "q" / leaf["file"])
        corners = np.isin(np.round(m.uv[:, 0], 6), [0.0, 1.0]) | (entry["name"] == "far")
        assert corners.all(), entry["name"]
    assert meta["lods"][-1]["triangles"] == 2 * lodmod.FAR_TILES  # uncut: a quad per card, the top one included


def test_library_add_warns_of_missing_materials_and_textures(tmp_path, capsys):
    """An OBJ whose MTL, or a texture its MTL names, is missing still imports, with a warning naming the file."""
    import shutil

    work = tmp_path / "in"
    work.mkdir()
    shutil.copy(FIXTURES / "cards.obj", work / "cards.obj")
    lib = str(tmp_path / "lib")
    # No cards.mtl beside it: the material library is named.
    assert run_cli(["library", "add", str(work / "cards.obj"), "--name", "a", "--library", lib, "-q"]) == 0
    err = capsys.readouterr().err
    assert "warning: cards.obj: material library 'cards.mtl' not found" in err
    # The MTL is there but its texture is not: the texture is named.
    shutil.copy(FIXTURES / "cards.mtl", work / "cards.mtl")
    assert run_cli(["library", "add", str(work / "cards.obj"), "--name", "b", "--library", lib, "-q"]) == 0
    err = capsys.readouterr().err
    assert "warning: cards.mtl: texture 'leaf.png' (map_Kd) not found" in err
    # With everything in place: no warning.
    shutil.copy(FIXTURES / "leaf.png", work / "leaf.png")
    assert run_cli(["library", "add", str(work / "cards.obj"), "--name", "c", "--library", lib, "-q"]) == 0
    assert "warning" not in capsys.readouterr().err


def test_list_shows_unbuilt_species_without_building_them(tmp_lib, capsys):
    """``forest library list`` lists what is there: in an empty user library every shipped preset is
    "not built" and nothing is built by listing; after ``library build shrub`` the shrub is listed built."""
    import json

    folder = str(tmp_lib.root)
    assert run_cli(["library", "list", "--json", "--library", folder]) == 0
    rows = {r["name"]: r for r in json.loads(capsys.readouterr().out)}
    assert set(PRESETS) <= set(rows)
    assert not any(rows[n]["built"] for n in PRESETS) and rows["shrub"]["lods"] == {}
    assert not tmp_lib.cache.is_dir() or not any(tmp_lib.cache.iterdir())  # listing built nothing
    assert run_cli(["library", "list", "--library", folder]) == 0  # the table says so too
    assert "not built" in capsys.readouterr().out
    assert run_cli(["library", "build", "shrub", "--quiet", "--no-previews", "--library", folder]) == 0
    capsys.readouterr()
    assert run_cli(["library", "list", "--json", "--library", folder]) == 0
    rows = {r["name"]: r for r in json.loads(capsys.readouterr().out)}
    assert rows["shrub"]["built"] and rows["shrub"]["lods"]["high"] > rows["shrub"]["lods"]["far"] > 0
    assert not rows["conifer"]["built"]


def test_import_names_bark_and_leaves(tmp_lib, tmp_path):
    """An imported tree's part named "Trunk" is bark (multiplied by each tree's bark factor), "Leaves" leaf."""
    import trimesh

    from forest.library.importer import add_species

    scene = trimesh.Scene()
    for name, box, colour in (("Trunk", ((-0.2, 0, -0.2), (0.2, 3, 0.2)), [90, 70, 50, 255]),
                              ("Leaves", ((-1.5, 2, -1.5), (1.5, 5, 1.5)), [60, 140, 40, 255])):  # fmt: skip
        lo, hi = np.array(box, float)
        tm = trimesh.creation.box(bounds=np.array([lo, hi]))
        tm.visual = trimesh.visual.TextureVisuals(material=trimesh.visual.material.PBRMaterial(baseColorFactor=colour))
        scene.add_geometry(tm, geom_name=name)
    path = tmp_path / "tree.glb"
    scene.export(path)
    sp = add_species(tmp_lib, path, "tree", preview=False)
    kinds = {(p.kind, p.tinted) for p in sp.lods[0].parts}
    assert kinds == {("bark", False), ("leaf", True)}


@pytest.mark.parametrize(
    "tone,field",
    [
        ({"near": {"albedo": [1.0, 1.0, 1.0]}}, r"lod_tone\.near: unknown level"),
        ({"far": {"albedo": [1.0, 1.0]}}, r"lod_tone\.far\.albedo: must be three numbers in \(0, 4\]"),
        ({"low": {"albedo": [1.0, 0.0, 1.0]}}, r"lod_tone\.low\.albedo"),
        ({"medium": {"sheen": -0.5}}, r"lod_tone\.medium\.sheen: must be a number in \[0, 4\]"),
        ({"far": {"gloss": 1.0}}, r"lod_tone\.far: must be a table with `albedo`"),
        ([1.0], r"lod_tone: must be a table of levels"),
    ],
)
def test_lod_tone_is_checked(tone, field):
    from forest.library.generator import validate_recipe

    recipe = tomllib.loads((ROOT / "library/presets/conifer.toml").read_text())
    recipe["lod_tone"] = tone
    with pytest.raises(ConfigError, match=field):
        validate_recipe(recipe, "conifer.toml")


def test_lod_tone_scales_each_lower_levels_leaves(tmp_path):
    """``[lod_tone]`` multiplies a lower level's leaf albedo and its sheen's weight (the far level's horizontal
    card by ``far_top``), and nothing else: the same meshes and textures, the high level and the bark untouched;
    without the table every level is as built."""
    recipe = tomllib.loads((ROOT / "library/presets/fern.toml").read_text())
    recipe["tree"]["trunks"] = 3
    recipe.pop("lod_tone", None)
    plain = generate(recipe, 2, tmp_path / "plain", name="fern")
    tone = {
        "medium": {"albedo": [0.9, 0.8, 0.7]},
        "low": {"sheen": 0.5},
        "far": {"albedo": [1.2, 1.1, 0.6], "sheen": 0.25},
        "far_top": {"albedo": [1.5, 1.5, 1.5]},
    }
    toned = generate(recipe | {"lod_tone": tone}, 2, tmp_path / "toned", name="fern")
    for a, b in zip(plain["lods"], toned["lods"]):
        for pa, pb in zip(a["parts"], b["parts"]):
            t = tone["far_top"] if pa["file"] == "far_top.ply" else tone.get(a["name"], {})
            factor = np.array(t.get("albedo", [1.0, 1.0, 1.0])) if pa["kind"] == "leaf" else np.ones(3)
            np.testing.assert_allclose(pb["colour"], np.array(pa["colour"]) * factor, atol=2e-6)
            if pa["kind"] == "leaf":
                assert pb["sheen"] == pytest.approx(pa["sheen"] * t.get("sheen", 1.0))
                assert pb["roughness"] == pa["roughness"]
    for f in sorted(p.name for p in (tmp_path / "plain").iterdir() if p.name != "species.json"):
        assert (tmp_path / "plain" / f).read_bytes() == (tmp_path / "toned" / f).read_bytes(), f
