"""Procedural buildings as library species: budgets, bounds, determinism, sizes, coverage, scenes."""

from __future__ import annotations

import json
import shutil
import tomllib
from pathlib import Path

import numpy as np
import pytest

from forest.errors import ConfigError
from forest.library import LODS, open_library
from forest.library import buildings as B
from forest.library.textures import read_texture
from forest.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]
TYPES = ("tower", "apartment", "house", "warehouse")


def preset(name: str) -> dict:
    return tomllib.loads((ROOT / f"library/presets/{name}.toml").read_text())


@pytest.fixture(scope="module")
def lib():
    """The shipped library; only the building species are built here."""
    lib = open_library(ROOT / "library")
    lib.build(list(TYPES), previews=False, prune=False)
    return lib


@pytest.fixture()
def building_lib(tmp_path):
    """A library of its own holding just the four building presets."""
    root = tmp_path / "lib"
    (root / "presets").mkdir(parents=True)
    text = "version = 1\n"
    for t in TYPES:
        shutil.copy(ROOT / f"library/presets/{t}.toml", root / "presets" / f"{t}.toml")
        text += f'[species.{t}]\nsource = "generated"\nrecipe = "presets/{t}.toml"\nseed = 1\n'
    (root / "manifest.toml").write_text(text)
    return root


@pytest.mark.parametrize("name", TYPES)
def test_budgets_bounds_parts_and_files(lib, name):
    sp = lib.resolve(name)
    assert sp.source == "generated" and [l.name for l in sp.lods] == list(LODS)
    meta = json.loads((sp.folder / "species.json").read_text())
    assert meta["kind"] == "building" and meta["building_type"] == name
    budgets = B.BUDGETS[name]
    previous = None
    for lod in sp.lods:
        lo, hi = budgets[lod.name]
        assert lo <= lod.triangles <= hi, (lod.name, lod.triangles)
        if previous is not None:
            assert lod.triangles < previous
        previous = lod.triangles
        used = []
        for part in lod.parts:
            assert part.kind == "surface" and part.translucency == 0.0
            m = part.load()
            assert m.triangles == part.triangles > 0 and np.isfinite(m.vertices).all()
            assert np.allclose(np.linalg.norm(m.normals, axis=1), 1.0, atol=1e-4)
            v = m.vertices[np.unique(m.faces)].astype(np.float64)
            np.testing.assert_allclose(part.bounds, [v.min(0), v.max(0)], atol=1e-6)
            used.append(v)
            # Materials: the façade texture on the walls of the modelled levels, roofs tinted.
            if part.path.stem.endswith("walls"):
                assert not part.tinted
                if lod.name != "far":
                    tex = read_texture(part.texture)
                    assert part.texture.name == "facade.png" and tex[..., 3].min() == 1.0
                    assert tex[..., :3].min() < 0.3 < 0.8 < tex[..., :3].max()  # dark glass, light wall
                else:
                    assert part.texture is None
            if part.path.stem.endswith("roof"):
                assert part.tinted
                assert (part.texture is None) == (lod.name == "far")
                if part.texture is not None:
                    assert part.texture.name == "roof.png" and read_texture(part.texture)[..., 3].min() == 1.0
        v = np.concatenate(used)
        np.testing.assert_allclose(lod.bounds, [v.min(0), v.max(0)], atol=1e-6)
        # Y up, base on the ground at the origin, footprint around it.
        assert lod.bounds[0][1] == 0.0
        size = lod.bounds[1] - lod.bounds[0]
        centre = 0.5 * (lod.bounds[0] + lod.bounds[1])
        assert np.all(np.abs(centre[[0, 2]]) <= 0.1 * size[[0, 2]])


def test_generation_is_deterministic(tmp_path):
    recipe = preset("apartment")
    B.generate(recipe, 3, tmp_path / "a", name="apartment")
    B.generate(recipe, 3, tmp_path / "b", name="apartment")
    B.generate(recipe, 4, tmp_path / "c", name="apartment")
    files = sorted(p.name for p in (tmp_path / "a").iterdir())
    assert {"high_walls.ply", "far_roof.ply", "facade.png", "roof.png", "species.json"} <= set(files)
    for f in files:
        assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes(), f
    assert (tmp_path / "a/high_walls.ply").read_bytes() != (tmp_path / "c/high_walls.ply").read_bytes()


@pytest.mark.parametrize("name", TYPES)
def test_sizes_and_budgets_over_seeds(name):
    """Every seed stays within the preset's footprint ranges, a plausible height and the budgets."""
    recipe = B.validate_recipe(preset(name), name)
    b = recipe["building"]
    heights = []
    for seed in range(16):
        meshes, colours, _ = B.build_meshes(recipe, seed)
        tris = [sum(m.triangles for m in meshes[lod].values()) for lod in LODS]
        assert tris == sorted(tris, reverse=True) and len(set(tris)) == 4, tris
        for lod, n in zip(LODS, tris):
            lo, hi = B.BUDGETS[name][lod]
            assert lo <= n <= hi, (seed, lod, n)
        # The far box stands on the drawn footprint (ridge along the long side for houses).
        far = np.concatenate([m.vertices for m in meshes["far"].values()]).astype(np.float64)
        W, D = far.max(0)[[0, 2]] - far.min(0)[[0, 2]]
        lo_w, hi_w = (
            (min(b["width"][0], b["depth"][0]), max(b["width"][1], b["depth"][1]))
            if name == "house"
            else (b["width"][0], b["width"][1])
        )
        assert lo_w - 1e-4 <= W <= hi_w + 1e-4
        if name != "house":
            assert b["depth"][0] - 1e-4 <= D <= b["depth"][1] + 1e-4
        high = np.concatenate([m.vertices for m in meshes["high"].values() if m.triangles]).astype(np.float64)
        heights.append(high[:, 1].max())
        for part, key in (("walls", "wall_colours"), ("roof", "roof_colours")):
            assert any(np.allclose(colours[part], c) for c in b[key])
        # Façade tiles: whole bays across every textured wall, floors aligned: v·floor_height = −y.
        walls = meshes["low"]["walls"]
        textured = ~np.all(np.isclose(walls.uv, B.PLAIN_UV), axis=1)
        fh = b["floor_height"] if name != "warehouse" else None
        if fh is not None:
            np.testing.assert_allclose(walls.uv[textured, 1] * fh, -walls.vertices[textured, 1], atol=1e-3)
        assert np.allclose(walls.uv[textured, 0], np.round(walls.uv[textured, 0]), atol=1e-5)
    heights = np.array(heights)
    expected = {"tower": (65, 230), "apartment": (14, 45), "house": (4, 13), "warehouse": (6, 15)}[name]
    assert expected[0] <= heights.min() and heights.max() <= expected[1], heights
    assert np.ptp(heights) > 0.1 * heights.mean()  # seeds make different buildings


def test_flat_roofed_warehouse_and_small_towers():
    """Other branches of the recipes: a flat roof with skylights; towers too low for setbacks."""
    w = preset("warehouse")
    w["building"]["roof"] = "flat"
    t = preset("tower")
    t["building"].update(floors=[2, 3], setbacks=[0, 0])
    for name, raw in (("warehouse", w), ("tower", t)):
        recipe = B.validate_recipe(raw, name)
        for seed in range(4):
            meshes, _, _ = B.build_meshes(recipe, seed)
            tris = [sum(m.triangles for m in meshes[lod].values()) for lod in LODS]
            assert tris == sorted(tris, reverse=True) and len(set(tris)) == 4, tris
            for lod in LODS:
                for m in meshes[lod].values():
                    if m.triangles:
                        assert np.allclose(np.linalg.norm(m.normals, axis=1), 1.0, atol=1e-4)
    # Flat roof: nothing of the low level stands above the eaves (no teeth).
    low = B.build_meshes(B.validate_recipe(w, "w"), 0)[0]["low"]
    assert float(low["walls"].vertices[:, 1].max()) == float(low["roof"].vertices[:, 1].max())


def test_types_are_ordered_by_height_and_footprint():
    med = {}
    for name in TYPES:
        recipe = B.validate_recipe(preset(name), name)
        dims = []
        for seed in range(8):
            far = np.concatenate([m.vertices for m in B.build_meshes(recipe, seed)[0]["low"].values()])
            dims.append(far.max(0) - far.min(0))
        med[name] = np.median(np.array(dims), axis=0)
    assert med["tower"][1] > med["apartment"][1] > med["warehouse"][1] > med["house"][1]
    area = {k: v[0] * v[2] for k, v in med.items()}
    assert area["warehouse"] > area["apartment"] > area["house"]
    assert med["warehouse"][0] > 3 * med["warehouse"][1]  # wide and low
    assert med["tower"][1] > 2 * max(med["tower"][0], med["tower"][2])


@pytest.mark.parametrize("name", TYPES)
def test_lower_levels_keep_coverage_silhouette_and_colour(lib, name):
    from forest.library.preview import render_lod

    sp = lib.get(name)
    imgs = {lod: render_lod(sp, lod, size=(40, 40), spp=4) for lod in LODS}
    cov = {k: float(v[..., 3].mean()) for k, v in imgs.items()}
    assert cov["high"] > 0.05
    for lod in ("medium", "low", "far"):
        assert abs(cov[lod] - cov["high"]) / cov["high"] < 0.1, cov
    mean = {k: v[..., :3].sum((0, 1)) / max(v[..., 3].sum(), 1e-9) for k, v in imgs.items()}
    chroma = {k: m / m.sum() for k, m in mean.items()}
    assert np.abs(chroma["low"] - chroma["high"]).max() < 0.04, chroma
    assert np.abs(chroma["far"] - chroma["high"]).max() < 0.08, chroma
    hi_m = imgs["high"][..., 3] > 0.05
    for lod in ("low", "far"):
        m = imgs[lod][..., 3] > 0.05
        assert (hi_m & m).sum() / (hi_m | m).sum() > 0.8, lod


def test_preview_cli_list_and_seeds(building_lib, capsys, tmp_path):
    from forest.cli import main

    def run(args):
        try:
            main(args)
        except SystemExit as e:
            return int(e.code or 0)
        return 0

    assert run(["library", "build", *TYPES, "--quiet", "--no-previews", "--library", str(building_lib)]) == 0
    capsys.readouterr()
    assert run(["library", "list", "--json", "--library", str(building_lib)]) == 0  # lists; builds nothing
    rows = {r["name"]: r for r in json.loads(capsys.readouterr().out)}
    assert set(TYPES) <= set(rows)  # its own copies, over the shipped presets
    assert all(rows[t]["preview"].startswith(str(building_lib)) for t in TYPES)
    assert rows["house"]["lods"]["far"] < rows["house"]["lods"]["high"]
    lib = open_library(building_lib)
    a, b = lib.get("house"), lib.resolve("house@2")
    assert a.hash != b.hash and a.folder != b.folder
    out = tmp_path / "p.png"
    assert (
        run(
            [
                "library",
                "preview",
                "house",
                "--library",
                str(building_lib),
                "--size",
                "32",
                "--spp",
                "2",
                "-o",
                str(out),
            ]
        )
        == 0
    )
    from forest.images import read_image

    img = read_image(out)
    assert img.shape == (32, 32, 4) and 0.1 < img[..., 3].mean() < 0.9


@pytest.mark.parametrize(
    "edit,field",
    [
        (lambda r: r["building"].update(type="castle"), r"building\.type"),
        (lambda r: r["building"].update(storeys=3), r"building\.storeys: unknown key"),
        (lambda r: r["building"].update(floors=[9, 3]), r"building\.floors"),
        (lambda r: r["building"].update(floors=[2.5, 3]), r"building\.floors"),
        (lambda r: r["building"].update(wall_colours=[[1.5, 0, 0]]), r"building\.wall_colours"),
        (lambda r: r["building"].update(tint_roof="yes"), r"building\.tint_roof"),
        (lambda r: r["building"].update(pitch=[30.0, 80.0]), r"building\.pitch"),
        (lambda r: r["building"].update(pitch=[0.0, 30.0]), r"building\.pitch"),
        (lambda r: r.update(kind="castle"), r"house\.toml: kind"),
    ],
)
def test_bad_recipes_name_file_and_field(building_lib, edit, field):
    import tomli_w

    recipe = preset("house")
    edit(recipe)
    (building_lib / "presets/house.toml").write_text(tomli_w.dumps(recipe))
    with pytest.raises(ConfigError, match=field):
        open_library(building_lib).get("house")
    assert not any((building_lib / "cache").glob("house-*"))


SCENE = """
seed = 3
[terrain]
flat = { size = 240.0 }
[scatter]
count = 12
min_distance = 60.0
[[species]]
model = "tower"
percent = 25
[[species]]
model = "apartment"
percent = 25
[[species]]
model = "house@4"
percent = 25
[[species]]
model = "warehouse"
percent = 25
[camera]
position = [0.0, 600.0, -1.0]
target = [0.0, 0.0, 0.0]
fov = 30.0
[lights]
sun = { elevation = 60.0, azimuth = 150.0, irradiance = 3.0 }
sky = { radiance = 0.5 }
[render]
width = 32
height = 24
spp = 2
variant = "scalar_rgb"
terrain_colour = [0.0, 0.0, 0.0]
"""


def test_buildings_scatter_and_render_in_a_scene(lib, tmp_path):
    from forest.config import parse_config
    from forest.images import read_image
    from forest.render import render_scene
    from forest.scatter import scatter

    cfg = parse_config(SCENE, path=tmp_path / "city.toml", base_dir=tmp_path)
    inst, _ = scatter(cfg)
    assert len(inst) > 0 and set(inst.species_names) == {"tower", "apartment", "house@4", "warehouse"}
    result = render_scene(load_scene(cfg, inst, library=lib), output=tmp_path / "city.exr")
    assert result.trees == len(inst) and result.instanced_triangles > 0
    img = read_image(tmp_path / "city.exr")
    lit = img[..., :3].max(axis=2) > 0.02  # black ground; roofs and walls are lit
    assert 0.01 < lit.mean() < 0.9
