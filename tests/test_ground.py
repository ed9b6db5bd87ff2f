"""Terrain materials: rules by slope, altitude, canopy and maps give the documented albedo; detail; precedence."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import write_png, write_scene

from forest.config import load_config
from forest.config.schema import GROUND_MATERIALS
from forest.ground import TerrainAlbedo, grid_shape, terrain_albedo, texel_centres
from forest.scene import load_scene

RAMP = """
seed = 1
[terrain]
heightmap = "ramp.png"
size = [100.0, 100.0]
height = 50.0
[scatter]
count = 0
[[species]]
model = "broadleaf"
percent = 100
"""


def ramp_scene(tmp_path, ground: str, extra: str = ""):
    """Flat for x < 0, rising at 45° for x > 0 (height = x), no trees."""
    n = 65
    x = np.linspace(-50, 50, n)
    write_png(tmp_path / "ramp.png", np.tile(np.where(x > 0, x, 0.0) / 50.0, (n, 1)), bits=16)
    return load_config(write_scene(tmp_path, RAMP + extra + "[ground]\n" + ground))


def albedo(cfg):
    scene = load_scene(cfg)
    return scene, scene.terrain_albedo


def test_slope_windows_give_their_materials(tmp_path):
    cfg = ramp_scene(
        tmp_path,
        'detail_tile = 0.0\nvariation = 0.0\nresolution = 64\nbase = "soil"\n'
        'rules = [{ material = "grass", slope = [0.0, 20.0], noise = 0.0 },\n'
        '         { material = "rock", slope = [35.0, 90.0], noise = 0.0 }]\n',
    )
    _, ta = albedo(cfg)
    assert ta.rgb.shape == (64, 64, 3) and ta.detail is None
    x, _ = texel_centres(ta.extent, ta.rgb.shape[:2])
    np.testing.assert_allclose(ta.rgb[x < -5], np.broadcast_to(GROUND_MATERIALS["grass"], ta.rgb[x < -5].shape))
    np.testing.assert_allclose(ta.rgb[x > 5], np.broadcast_to(GROUND_MATERIALS["rock"], ta.rgb[x > 5].shape))


def test_altitude_window_and_later_rules_paint_over(tmp_path):
    """A ramp window [lo0, lo1, hi1, hi0]: 0 below lo0, 1 from lo1; the later rule covers the earlier."""
    cfg = ramp_scene(
        tmp_path,
        'detail_tile = 0.0\nvariation = 0.0\nresolution = 100\nbase = "soil"\n'
        'rules = [{ material = "rock", slope = [30.0, 90.0], noise = 0.0 },\n'
        '         { material = "snow", altitude = [30.0, 34.0, 1000.0, 1000.0], noise = 0.0 }]\n',
    )
    _, ta = albedo(cfg)
    x, _ = texel_centres(ta.extent, ta.rgb.shape[:2])
    rock, snow = (np.asarray(GROUND_MATERIALS[m], np.float32) for m in ("rock", "snow"))
    np.testing.assert_allclose(ta.rgb[(x > 3) & (x < 29)], np.broadcast_to(rock, ta.rgb[(x > 3) & (x < 29)].shape))
    np.testing.assert_allclose(ta.rgb[x > 35], np.broadcast_to(snow, ta.rgb[x > 35].shape), rtol=1e-6)
    # In the ramp (height 30 … 34 m) the snow's coverage rises smoothly from 0 to 1.
    row = ta.rgb[ta.rgb.shape[0] // 2, :, 0]
    band = (x[0] > 30) & (x[0] < 34)
    assert band.any() and (np.diff(row[band]) > 0).all() and rock[0] < row[band].min() <= row[band].max() < snow[0]


def test_map_weight_and_invert(tmp_path):
    write_png(tmp_path / "river.png", np.repeat((np.arange(8) < 4)[None, :].astype(float), 8, axis=0))
    cfg = ramp_scene(
        tmp_path,
        'detail_tile = 0.0\nvariation = 0.0\nresolution = 64\nbase = "soil"\n'
        'rules = [{ material = "wet", map = "river.png", invert = true }]\n',
    )
    _, ta = albedo(cfg)
    x, _ = texel_centres(ta.extent, ta.rgb.shape[:2])
    wet, soil = GROUND_MATERIALS["wet"], GROUND_MATERIALS["soil"]
    np.testing.assert_allclose(ta.rgb[x < -10], np.broadcast_to(soil, ta.rgb[x < -10].shape), rtol=1e-6)
    np.testing.assert_allclose(ta.rgb[x > 10], np.broadcast_to(wet, ta.rgb[x > 10].shape), rtol=1e-6)


def test_default_rules_put_litter_under_trees_and_grass_in_the_open(tmp_path):
    """Trees only on the west half: the crowns' cover gives litter there, grass on the open, flat east half."""
    write_png(tmp_path / "presence.png", np.repeat((np.arange(16) < 8)[None, :].astype(float), 16, axis=0))
    cfg = load_config(
        write_scene(
            tmp_path,
            """
            seed = 4
            [terrain]
            flat = { size = 200.0 }
            [maps]
            presence = "presence.png"
            [scatter]
            count = 4000
            [[species]]
            model = "broadleaf"
            percent = 100
            [ground]
            detail_tile = 0.0
            variation = 0.0
            resolution = 128
            """,
        )
    )
    scene, ta = albedo(cfg)
    x, _ = texel_centres(ta.extent, ta.rgb.shape[:2])
    west = ta.rgb[x < -30].mean(axis=0)
    np.testing.assert_allclose(west, GROUND_MATERIALS["litter"], atol=0.01)
    # Open flat ground: green grass (low and flat is moist, so no dry grass), all of it.
    np.testing.assert_allclose(ta.rgb[x > 30], np.broadcast_to(GROUND_MATERIALS["grass"], ta.rgb[x > 30].shape))
    assert len(scene.instances) > 1000 and (scene.instances.position[:, 0] < 5).all()
    # Deterministic.
    again = terrain_albedo(cfg, scene.terrain, scene.instances, scene.species)
    assert again.rgb.tobytes() == ta.rgb.tobytes()


def test_detail_has_mean_one_tiles_and_at_multiplies(tmp_path):
    cfg = ramp_scene(tmp_path, 'resolution = 32\ndetail_tile = 5.0\nvariation = 0.0\nbase = "rock"\nrules = []\n')
    _, ta = albedo(cfg)
    assert ta.detail is not None and ta.detail_tile_m == 5.0
    np.testing.assert_allclose(ta.detail.reshape(-1, 3).mean(axis=0), 1.0, rtol=1e-4)
    assert ta.detail.std() > 0.05
    # The tile wraps: a point and the same point one tile further look up the same value, and the
    # seam between the last and first texel is no larger a step than steps inside the tile.
    rng = np.random.default_rng(0)
    x, z = rng.uniform(-40, 40, 200), rng.uniform(-40, 40, 200)
    np.testing.assert_allclose(ta.at(x, z), ta.at(x + 5.0, z - 10.0), rtol=1e-5)
    d = ta.detail[..., 1]
    inner = np.abs(np.diff(d, axis=1)).max()
    assert np.abs(d[:, 0] - d[:, -1]).max() <= inner + 1e-6
    # Uniform rock × detail: the mean over many points is the rock's albedo.
    many = ta.at(rng.uniform(-45, 45, 40000), rng.uniform(-45, 45, 40000))
    np.testing.assert_allclose(many.mean(axis=0), GROUND_MATERIALS["rock"], rtol=0.02)


def test_texture_wins_and_a_colour_is_one_material(tmp_path):
    write_png(tmp_path / "tex.png", np.full((4, 6, 3), 0.5))
    cfg = ramp_scene(tmp_path, "detail_tile = 0.0\n")
    tex = albedo(cfg.with_overrides({"render.terrain_texture": "tex.png"}))[1]
    from forest.images import srgb_to_linear

    assert tex.rgb.shape == (4, 6, 3)
    np.testing.assert_allclose(tex.rgb, srgb_to_linear(np.full((4, 6, 3), 128 / 255)), rtol=1e-5)
    plain = load_config(write_scene(tmp_path, RAMP + "[render]\nterrain_colour = [0.3, 0.2, 0.1]\n", "c.toml"))
    one = albedo(plain)[1]
    assert one.rgb.shape == (1, 1, 3)
    np.testing.assert_allclose(one.rgb[0, 0], [0.3, 0.2, 0.1], rtol=1e-6)
    assert one.detail is not None  # the one material keeps the ground's detail (mean 1)


def test_grid_shape_follows_the_extent():
    assert grid_shape((-100.0, -50.0, 100.0, 50.0), 512) == (256, 512)
    assert grid_shape((0.0, 0.0, 10.0, 40.0), 400) == (400, 100)


def test_terrain_albedo_dataclass_lookup_matches_its_grid():
    rgb = np.arange(2 * 3 * 3, dtype=np.float32).reshape(2, 3, 3)
    ta = TerrainAlbedo(rgb, (0.0, 0.0, 30.0, 20.0))
    # Texel centres (map convention: column → +X, row → +Z) return the texel's value.
    x, z = texel_centres(ta.extent, (2, 3))
    np.testing.assert_allclose(ta.at(x.ravel(), z.ravel()), rgb.reshape(-1, 3))


@pytest.mark.parametrize("bad", ['base = "moss"', 'rules = [{ material = "rock", canopy = [0.5] }]'])
def test_bad_ground_names_the_field(tmp_path, bad):
    from forest.errors import ConfigError

    with pytest.raises(ConfigError, match=r"ground\.(base|rules\[0\]\.canopy)"):
        ramp_scene(tmp_path, bad + "\n")


FLAT = """
seed = {seed}
[terrain]
flat = {{ size = 400.0 }}
[scatter]
count = 0
[[species]]
model = "broadleaf"
percent = 100
[ground]
detail_tile = 0.0
resolution = 256
base = "{base}"
rules = []
{extra}
"""


def flat_albedo(tmp_path, base: str = "grass", extra: str = "", seed: int = 1) -> np.ndarray:
    (tmp_path / f"s{seed}").mkdir(exist_ok=True)
    cfg = load_config(write_scene(tmp_path / f"s{seed}", FLAT.format(seed=seed, base=base, extra=extra)))
    return albedo(cfg)[1].rgb.astype(np.float64)


def test_variation_patches_the_ground_and_keeps_each_materials_mean(tmp_path):
    """``[ground] variation``: a lognormal factor in luminance and a warm–cool shift, σ = 0.12 by default, in
    patches about ``variation_scale`` metres across; the material's mean albedo is kept, ``variation = 0`` is the
    material itself, water keeps its colour, and the seed picks the patches."""
    grass = np.asarray(GROUND_MATERIALS["grass"], np.float64)
    rgb = flat_albedo(tmp_path)
    log = np.log(rgb / grass)
    np.testing.assert_allclose(rgb.reshape(-1, 3).mean(axis=0), grass, rtol=0.04)
    assert 0.09 < float(log[..., 1].std()) < 0.15  # luminance alone on green
    warm = log[..., 0] - log[..., 2]  # red against blue: twice the shift
    assert 0.17 < float(warm.std()) < 0.31
    assert abs(float(np.corrcoef(log[..., 1].ravel(), warm.ravel())[0, 1])) < 0.2  # two independent fields
    # Patches: neighbours 1.6 m apart agree, texels 50 m apart do not.
    g = log[..., 1] - log[..., 1].mean()

    def corr(k: int) -> float:
        return float((g[:, k:] * g[:, :-k]).mean() / g.var())

    assert corr(1) > 0.9 and abs(corr(32)) < 0.3
    assert np.array_equal(
        flat_albedo(tmp_path, extra="variation = 0.0"), np.broadcast_to(grass, rgb.shape).astype(np.float32)
    )
    water = np.asarray(GROUND_MATERIALS["water"], np.float32)
    assert np.array_equal(flat_albedo(tmp_path, base="water"), np.broadcast_to(water, rgb.shape))
    assert np.array_equal(flat_albedo(tmp_path), rgb) and not np.array_equal(flat_albedo(tmp_path, seed=2), rgb)
    wide = np.log(flat_albedo(tmp_path, extra="variation_scale = 60.0")[..., 1] / grass[1])
    assert float((wide[:, 32:] * wide[:, :-32]).mean() / wide.var()) > corr(32) + 0.2


def test_bad_variation_is_refused_in_one_line(tmp_path):
    from forest.errors import ConfigError

    with pytest.raises(ConfigError, match=r"ground\.variation: must be <= 1"):
        flat_albedo(tmp_path, extra="variation = 1.5")
