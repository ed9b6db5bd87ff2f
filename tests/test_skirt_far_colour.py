"""The far landscape on the ground skirt: canopy and ground mixed by the crowns' cover (forest.skirt)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_render import trees

from forest.config import parse_config
from forest.ground import TerrainAlbedo, canopy_cover, crown_radii, grid_shape
from forest.images import read_exr_channels
from forest.instances import InstanceSet
from forest.library.mesh import write_ply
from forest.render import render_scene
from forest.render.path.ground import ground_look
from forest.scene import load_scene
from forest.skirt import (
    COVER_RESOLUTION,
    canopy_reflectance,
    fade_beyond_edge,
    far_colour,
    landscape,
)

from render_fixtures import Lod, Part, Species, box_mesh

GREEN = (0.1, 0.18, 0.03)  # a leaf's albedo, as the library's broadleaf
SOIL = (0.2, 0.12, 0.06)  # brown bare ground
EXTENT = (-50.0, -50.0, 50.0, 50.0)


class GreenLibrary:
    """Species ``tree``: a 4×6×4 m box of one tinted leaf part of albedo :data:`GREEN` (crown radius 2 m)."""

    def __init__(self, root):
        root.mkdir(parents=True, exist_ok=True)
        m = box_mesh((-2, 0, -2), (2, 6, 2))
        path = write_ply(root / "tree.ply", m)
        lods = [Lod(n, m.triangles, m.bounds(), [Part("leaf", path, GREEN, None, True)]) for n in LODS]
        self.species = {"tree": Species("tree", lods)}

    def names(self):
        return sorted(self.species)

    def resolve(self, model, base_dir=None):
        from forest.errors import ForestError

        if model not in self.species:
            raise ForestError(f"unknown species {model!r}")
        return self.species[model]


LODS = ("high", "medium", "low", "far")


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    return GreenLibrary(tmp_path_factory.mktemp("greenlib"))


def lattice(spacing: float, xmax: float = 50.0) -> np.ndarray:
    """Tree bases on a square lattice over x ∈ [−50, xmax], z ∈ [−50, 50] (y = 0)."""
    xs = np.arange(-50.0 + spacing / 2, xmax, spacing)
    zs = np.arange(-50.0 + spacing / 2, 50.0, spacing)
    x, z = np.meshgrid(xs, zs)
    return np.stack([x.ravel(), np.zeros(x.size), z.ravel()], 1)


def test_a_deep_canopy_reflects_less_than_its_leaves():
    """ρ_c = (1 − √(1 − ω))/(1 + √(1 − ω)): 0 and 1 stay, a green leaf of 0.18 gives a canopy of about 0.05."""
    np.testing.assert_allclose(canopy_reflectance([0.0, 1.0]), [0.0, 1.0])
    assert canopy_reflectance([0.18])[0] == pytest.approx(0.0497, abs=2e-4)
    w = np.linspace(0.0, 1.0, 11)
    assert np.all(np.diff(canopy_reflectance(w)) > 0) and np.all(canopy_reflectance(w) <= w)


def test_the_far_albedo_is_the_cover_weighted_mix_of_canopy_and_ground(library):
    """On a uniform ground ρ_g: ρ_far = (1 − c̄)·ρ_g + c̄·ρ_c with c̄ the crowns' mean Boolean cover and ρ_c the
    deep-canopy reflectance of the crown-area-weighted foliage albedo (leaf colour × each tree's tint); ground
    cover rows count for nothing."""
    sp = library.resolve("tree")
    ground = np.broadcast_to(np.asarray(SOIL, np.float32), (32, 32, 3)).copy()
    # trees on the left half only (4 m lattice, crowns of radius 2 and 2·1.5 m), half of them reddened
    pos = lattice(4.0, xmax=0.0)
    n = len(pos)
    inst = trees(pos, names=("tree", "moss"), scale=1.0)
    scale = np.where(np.arange(n) % 2 == 0, 1.0, 1.5)
    tint = np.ones((n, 3))
    tint[::3] = (1.3, 1.0, 0.7)
    inst = dataclasses.replace(inst, scale=scale.astype(inst.scale.dtype), tint=tint.astype(np.float32))
    far = landscape(ground, EXTENT, inst, (sp, sp), 1, inst.tint).far

    cover = canopy_cover(inst, crown_radii((sp, sp)), 1, EXTENT, grid_shape(EXTENT, COVER_RESOLUTION)).mean()
    area = np.pi * (2.0 * scale) ** 2
    omega = (area[:, None] * (np.asarray(GREEN) * tint)).sum(0) / area.sum()
    expected = (1.0 - cover) * np.asarray(SOIL) + cover * canopy_reflectance(omega)
    np.testing.assert_allclose(far, expected, rtol=1e-4)  # float32 ground and tints
    # the cover is the Boolean model's 1 − exp(−D) over the wooded half: D = crowns' area per ground area
    d = area.sum() / (50.0 * 100.0)
    assert cover == pytest.approx(0.5 * (1.0 - np.exp(-d)), abs=0.03)
    assert far[1] / far[0] > SOIL[1] / SOIL[0]  # greener than the soil
    # the canopy's height: the trees' heights (6 m boxes × scale) weighted by crown area, as ρ_c
    height = landscape(ground, EXTENT, inst, (sp, sp), 1, inst.tint).height
    assert height == pytest.approx(float(area @ (6.0 * scale) / area.sum()), rel=1e-12)
    assert 6.0 < height < 9.0

    # ground cover (species index ≥ the tree species' count) neither covers nor colours
    moss = dataclasses.replace(inst, species=np.ones(n, inst.species.dtype))
    bare = landscape(ground, EXTENT, moss, (sp, sp), 1, moss.tint).far
    np.testing.assert_array_equal(bare, far_colour(TerrainAlbedo(ground, EXTENT)))  # the ground's mean
    half = dataclasses.replace(inst, species=(np.arange(n) % 2).astype(inst.species.dtype))  # odd rows: moss
    only = inst.subset(np.arange(n) % 2 == 0)
    np.testing.assert_allclose(
        landscape(ground, EXTENT, half, (sp, sp), 1, half.tint).far,
        landscape(ground, EXTENT, only, (sp, sp), 1, only.tint).far,
        rtol=1e-6,
    )


def test_the_gaps_show_the_ground_that_is_there():
    """On a non-uniform ground the crowns hide the ground under them: a forest on the brown half and open grass on
    the green half give a far albedo of the grass, the canopy and a little soil, ρ̄_g + ⟨c·(ρ_c − ρ_g)⟩."""
    bounds = np.array([[-2.0, 0.0, -2.0], [2.0, 6.0, 2.0]])
    part = Part("leaf", None, GREEN, None, True)
    sp = Species("tree", [Lod("high", 12, bounds, [part])])
    grass = (0.05, 0.15, 0.04)
    ground = np.empty((32, 32, 3), np.float32)
    ground[:, :16] = SOIL  # x < 0
    ground[:, 16:] = grass
    inst = trees(lattice(3.0, xmax=0.0), names=("tree",))
    far = landscape(ground, EXTENT, inst, (sp,), 1, inst.tint).far
    cover = canopy_cover(inst, crown_radii((sp,)), 1, EXTENT, grid_shape(EXTENT, COVER_RESOLUTION))
    c_soil = cover[:, : cover.shape[1] // 2].mean()
    c_grass = cover[:, cover.shape[1] // 2 :].mean()
    canopy = canopy_reflectance(GREEN)
    expected = 0.5 * ((1 - c_soil) * np.asarray(SOIL) + (1 - c_grass) * np.asarray(grass))
    expected += 0.5 * (c_soil + c_grass) * canopy
    np.testing.assert_allclose(far, expected, rtol=0.02)  # the cover grid's texels straddle x = 0: a 2 % margin
    mean_mix = (1 - cover.mean()) * ground.reshape(-1, 3).mean(0) + cover.mean() * canopy
    assert far[0] < mean_mix[0]  # less soil than a mix with the ground's mean would show


def test_the_far_fields_are_the_terrains_open_land_not_the_litter_between_crowns():
    """The two kinds of land behind ρ_far: a forest on the brown half and open grass on the green half give wooded
    land on about half the texels with the crowns-over-soil albedo there, and open land of the grass — not the
    mean of the ground between the crowns (mostly soil), which the fields showed before; the split adds up to
    ρ_far exactly, and the mosaic built from it paints its open ground grass."""
    from forest.far_cover import far_cover
    from forest.skirt import WOODED

    bounds = np.array([[-2.0, 0.0, -2.0], [2.0, 6.0, 2.0]])
    sp = Species("tree", [Lod("high", 12, bounds, [Part("leaf", None, GREEN, None, True)])])
    grass = np.array([0.05, 0.15, 0.04])
    ground = np.empty((32, 32, 3), np.float32)
    ground[:, :16] = SOIL  # x < 0, under the trees
    ground[:, 16:] = grass
    inst = trees(lattice(3.0, xmax=0.0), names=("tree",))
    land = landscape(ground, EXTENT, inst, (sp,), 1, inst.tint)
    assert land.woods is not None and land.wooded == pytest.approx(0.5, abs=0.05)
    cover = canopy_cover(inst, crown_radii((sp,)), 1, EXTENT, grid_shape(EXTENT, COVER_RESOLUTION))
    assert float(cover[:, : cover.shape[1] // 2].mean()) > WOODED > float(cover[:, cover.shape[1] // 2 :].mean())
    rho_c = canopy_reflectance(GREEN)
    c_in = float(cover[cover >= WOODED].mean())
    np.testing.assert_allclose(land.woods, (1.0 - c_in) * np.asarray(SOIL) + c_in * rho_c, rtol=0.05)
    rho_open = (land.far - land.wooded * land.woods) / (1.0 - land.wooded)
    np.testing.assert_allclose(rho_open, grass, rtol=0.05)  # the open land is the grass
    gaps = (land.far - land.cover * rho_c) / (1.0 - land.cover)  # the former fields: the ground between crowns
    assert gaps[0] / gaps[1] > 1.5 * grass[0] / grass[1]  # … redder: soil between the crowns
    fc = far_cover(land.far, land.woods, land.wooded, EXTENT, 10.0, 0)
    assert fc is not None
    np.testing.assert_allclose(np.asarray(fc.open) * land.far, rho_open, rtol=1e-9)
    # The mosaic's mean over a tile is ρ_far: (1 − w̄)·ρ_open + w̄·ρ_w.
    np.testing.assert_allclose((1.0 - land.wooded) * rho_open + land.wooded * land.woods, land.far, rtol=1e-9)
    # A forest over the whole terrain is all wooded land: no fields to draw.
    full = trees(lattice(3.0), names=("tree",))
    whole = landscape(ground, EXTENT, full, (sp,), 1, full.tint)
    assert whole.wooded > 0.9


def test_a_bare_terrain_keeps_the_grounds_mean(tmp_path, library):
    """Without trees the far albedo is the grid's mean, bit for bit, and the fade is the former one."""
    rng = np.random.default_rng(3)
    grid = rng.uniform(0.02, 0.5, (24, 40, 3)).astype(np.float32)
    empty = InstanceSet.empty(species_names=["tree"])
    far = landscape(grid, EXTENT, empty, (library.resolve("tree"),), 1, empty.tint).far
    horizon = TerrainAlbedo(grid, EXTENT, far=(float(far[0]), float(far[1]), float(far[2])))
    np.testing.assert_array_equal(far_colour(horizon), far_colour(TerrainAlbedo(grid, EXTENT)))
    old, old_ext = fade_beyond_edge(grid, EXTENT)
    new, new_ext = fade_beyond_edge(grid, EXTENT, far_colour(horizon))
    np.testing.assert_array_equal(new, old)
    assert new_ext == old_ext
    # a one-colour ground with no trees stays one constant colour
    one = np.asarray(SOIL, np.float32).reshape(1, 1, 3)
    same, _ = fade_beyond_edge(one, EXTENT, far_colour(TerrainAlbedo(one, EXTENT)))
    assert same.shape == (1, 1, 3)

    cfg = forest_config(tmp_path)
    scene = load_scene(cfg, trees(np.zeros((0, 3)), names=("tree",)), library=library)
    assert scene.terrain_albedo.far is not None
    np.testing.assert_array_equal(far_colour(scene.terrain_albedo), np.asarray(SOIL, np.float32))


def test_a_one_colour_ground_fades_like_a_grid():
    """A one-texel ground under trees is repeated to texels a fraction of the terrain wide before it fades: the
    terrain keeps its colour and the outer ring is ρ_far."""
    one = np.asarray(SOIL, np.float32).reshape(1, 1, 3)
    far = np.array([0.04, 0.06, 0.02], np.float32)
    out, ext = fade_beyond_edge(one, EXTENT, far)
    p = (out.shape[0] - 16) // 2
    assert out.shape == (16 + 2 * p, 16 + 2 * p, 3) and p >= 2
    np.testing.assert_array_equal(out[p:-p, p:-p], np.broadcast_to(one, (16, 16, 3)))
    np.testing.assert_allclose(out[0, 0], far)
    assert ext[2] - ext[0] == pytest.approx(100.0 * (16 + 2 * p) / 16)


SCENE = """
seed = 3
[terrain]
flat = {{ size = 100.0 }}
[camera]
position = [0.0, 20.0, -60.0]
target = [0.0, 20.0, 0.0]
fov = 60.0
[lights]
sky = {{ radiance = 1.0, colour = [1.0, 1.0, 1.0] }}
[render]
width = 40
height = 40
spp = {spp}
max_depth = 3
terrain_colour = {soil}
[ground]
detail_tile = 0.0
[[species]]
model = "tree"
percent = 100
"""


def forest_config(tmp_path, spp: int = 4):
    text = SCENE.format(spp=spp, soil=list(SOIL))
    (tmp_path / "scene.toml").write_text(text)
    return parse_config(text, path=tmp_path / "scene.toml", base_dir=tmp_path)


def test_the_scene_carries_the_far_albedo_to_both_renderers(tmp_path, library):
    """load_scene computes ρ_far once from its trees; forest_path's grid and the scalar renderer's texture both
    fade to it (× the fitted ground tint); a fitted leaf tint leaves it as it is (look-dev holds the skirt)."""
    from forest.render.scene import terrain_reflectance

    cfg = forest_config(tmp_path)
    inst = trees(lattice(4.0), names=("tree",))
    scene = load_scene(cfg, inst, library=library)
    albedo = scene.terrain_albedo
    assert albedo.far is not None
    sp = scene.species
    ones = np.ones((len(scene.instances), 3))  # the species' own colours, not what look-dev fits
    land = landscape(albedo.rgb, albedo.extent, scene.instances, sp, 1, ones)
    np.testing.assert_allclose(albedo.far, land.far)
    # … and the wooded land behind it (the skirt's woods and open ground, forest.far_cover): a 4 m lattice of
    # 4 m crowns covers the ground about evenly, so all of it is wooded land: one colour, no fields.
    assert land.woods is not None and albedo.far_cover == land.wooded and land.wooded > 0.9
    np.testing.assert_allclose(albedo.far_canopy, land.woods)
    assert albedo.far[1] / albedo.far[0] > 1.2 * SOIL[1] / SOIL[0]  # greener than the soil: the canopy

    look = ground_look(scene)  # forest_path
    np.testing.assert_allclose(look.colour[0, 0], albedo.far, rtol=1e-6)
    np.testing.assert_allclose(look.colour[look.colour.shape[0] // 2, look.colour.shape[1] // 2], SOIL, rtol=1e-6)
    tex = terrain_reflectance(albedo, scene.terrain, "scalar_rgb", fade=True, tint=(1.0, 0.5, 1.0))
    assert tex["type"] != "rgb"  # a one-colour ground under trees fades: a texture, not a constant
    assert terrain_reflectance(albedo, scene.terrain, "scalar_rgb")["type"] == "rgb"  # no skirt: the constant

    darker = scene.with_config(cfg.with_overrides({"lookdev.leaf_tint": {"tree": [0.5, 0.5, 0.5]}}))
    np.testing.assert_allclose(darker.terrain_albedo.far, albedo.far)


@pytest.mark.parametrize("variant", ("scalar_rgb", "llvm_ad_rgb"))
def test_the_horizon_beyond_a_forest_is_greener_than_its_soil(tmp_path, library, variant):
    """A level view over a forested 100 m square on brown soil: the rows just below the horizon (the skirt, a
    few hundred metres out) are greener with the far landscape than with the former fade to the ground's mean."""
    cfg = forest_config(tmp_path, spp=8)
    scene = load_scene(cfg, trees(lattice(3.0), names=("tree",)), library=library)  # cover ≈ 0.75
    a = scene.terrain_albedo
    old = dataclasses.replace(scene, terrain_albedo=TerrainAlbedo(a.rgb, a.extent, a.detail, a.detail_tile_m))
    strips = {}
    for name, sc in (("new", scene), ("old", old)):
        render_scene(sc, output=tmp_path / f"{name}.exr", variant=variant)
        rgb = np.stack([read_exr_channels(tmp_path / f"{name}.exr")[0][c] for c in "RGB"], -1)
        strips[name] = rgb[20:22].reshape(-1, 3).mean(0)  # just below the horizon: the skirt far out
    new, old_ = strips["new"], strips["old"]
    assert old_[1] / old_[0] == pytest.approx(SOIL[1] / SOIL[0], rel=0.1)  # formerly: the soil
    assert new[1] / new[0] > 1.3 * old_[1] / old_[0]  # green over red: the canopy, not the soil
