"""Scene pieces of the scalar renderer: camera, lights, colour grid, terrain, wind and LOD."""

from __future__ import annotations

import numpy as np
import pytest

from forest.camera import look_at_matrix
from forest.config import parse_config
from forest.errors import ForestError
from forest.ground import TerrainAlbedo, terrain_albedo
from forest.instances import InstanceSet
from forest.lights import sun_vector
from forest.lod import lod_levels
from forest.render.scene import colour_grid_texture, emitter_dicts, sensor_dict, terrain_dict
from forest.runtime import mitsuba
from forest.terrain import load_terrain
from forest.wind import sway_angles, sway_rotation

VARIANTS = ("scalar_rgb", "llvm_ad_rgb")


def ground_of(cfg, terrain) -> TerrainAlbedo:
    """The ground a Scene of ``cfg`` resolves on a bare terrain (no trees)."""
    return terrain_albedo(cfg, terrain, InstanceSet.empty(species_names=["box"]), ())


TOP_DOWN = """
[terrain]
flat = { size = 100.0 }
[camera]
position = [0.0, 200.0, 0.0]
target = [0.0, 0.0, 0.0]
up = [0.0, 0.0, 1.0]
fov = 30.0
[lights]
sky = { radiance = 1.0, colour = [1.0, 1.0, 1.0] }
[render]
width = 32
height = 32
spp = 4
terrain_colour = [1.0, 1.0, 1.0]
[[species]]
model = "box"
percent = 100
"""


def ground_points(config, width, height):
    """World (x, z) where each pixel centre's camera ray meets the plane y = 0 (pinhole model, fov along x)."""
    cam = config.camera
    m = look_at_matrix(cam.position, cam.target, cam.up)
    t = np.tan(np.radians(cam.fov) / 2)
    j, i = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    # Mitsuba: camera +X is image left, +Y image up, +Z forward.
    x = (1 - 2 * j / width) * t
    y = (1 - 2 * i / height) * t * height / width
    d = np.stack([x, y, np.ones_like(x)], -1) @ m[:3, :3].T
    o = m[:3, 3]
    s = -o[1] / d[..., 1]
    p = o + s[..., None] * d
    return p[..., 0], p[..., 2]


@pytest.mark.parametrize("variant", VARIANTS)
def test_colour_grid_follows_the_map_convention(variant):
    """A 2×2 albedo grid on the terrain: each quadrant renders in its colour (row → +Z, column → +X)."""
    mi = mitsuba(variant)
    cfg = parse_config(TOP_DOWN)
    terrain = load_terrain(cfg.terrain)
    grid = np.array(
        [
            [[0.8, 0.05, 0.05], [0.05, 0.8, 0.05]],  # row 0 (z < 0): red at x < 0, green at x > 0
            [[0.05, 0.05, 0.8], [0.8, 0.8, 0.05]],
        ],
        np.float32,
    )  # row 1 (z > 0): blue, yellow
    fine = np.repeat(np.repeat(grid, 4, axis=0), 4, axis=1)  # 8×8: quadrants stay flat inside
    scene = mi.load_dict(
        {
            "type": "scene",
            "integrator": {"type": "path", "max_depth": 2},
            "sensor": sensor_dict(cfg, variant=variant),
            **emitter_dicts(cfg, variant),
            "terrain": terrain_dict(TerrainAlbedo(fine, terrain.extent), terrain, variant),
        }
    )
    img = np.asarray(mi.render(scene, seed=3))[..., :3]
    gx, gz = ground_points(cfg, 32, 32)
    for row, zsel in ((0, gz < -8), (1, gz > 8)):
        for col, xsel in ((0, gx < -8), (1, gx > 8)):
            sel = zsel & xsel & (np.abs(gx) < 40) & (np.abs(gz) < 40)
            assert sel.sum() > 10
            got = img[sel].mean(axis=0)
            np.testing.assert_allclose(got, grid[row, col], atol=0.06)


def test_colour_grid_texture_layout_and_bad_input():
    mi = mitsuba("scalar_rgb")
    grid = np.zeros((3, 5, 3), np.float32)
    grid[2, 4] = [1.0, 0.5, 0.25]
    tex = mi.load_dict(colour_grid_texture(grid, (-10, -6, 10, 6), (0.0, 5.0), "scalar_rgb", filter_type="nearest"))
    si = mi.SurfaceInteraction3f()
    # Pixel (2, 4) covers x ∈ [6, 10], z ∈ [2, 6]; any height.
    for p in ([8.0, 1.0, 4.0], [8.0, 300.0, 4.0], [12.0, 0.0, 9.0]):
        si.p = mi.Point3f(p)
        np.testing.assert_allclose(np.asarray(tex.eval(si)), [1.0, 0.5, 0.25], atol=1e-6)
    si.p = mi.Point3f([-8.0, 1.0, -4.0])
    np.testing.assert_allclose(np.asarray(tex.eval(si)), [0, 0, 0], atol=1e-6)
    with pytest.raises(ForestError):
        colour_grid_texture(np.zeros((4, 4)), (0, 0, 1, 1), (0, 1), "scalar_rgb")
    with pytest.raises(ForestError):
        colour_grid_texture(np.full((2, 2, 3), np.nan), (0, 0, 1, 1), (0, 1), "scalar_rgb")


def test_colour_grid_is_differentiable_in_llvm():
    mi = mitsuba("llvm_ad_rgb")
    bsdf = mi.load_dict(
        {
            "type": "diffuse",
            "reflectance": colour_grid_texture(
                np.full((4, 4, 3), 0.5, np.float32), (0, 0, 1, 1), (0, 1), "llvm_ad_rgb"
            ),
        }
    )
    params = mi.traverse(bsdf)
    key = [k for k in params.keys() if k.endswith("volume.data")]  # noqa: SIM118
    assert key and params.flags(key[0]) & mi.ParamFlags.NonDifferentiable.value == 0


def test_sun_vector_and_emitters():
    np.testing.assert_allclose(sun_vector(90.0, 0.0), [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(sun_vector(0.0, 90.0), [1, 0, 0], atol=1e-12)  # east = +X
    np.testing.assert_allclose(sun_vector(0.0, 0.0), [0, 0, 1], atol=1e-12)  # north = +Z
    cfg = parse_config(
        TOP_DOWN.replace(
            "sky = { radiance = 1.0, colour = [1.0, 1.0, 1.0] }",
            "sun = { elevation = 30.0, azimuth = 90.0, irradiance = 2.0, colour = [1.0, 0.5, 0.25] }\n"
            "sky = { radiance = 0.5, colour = [0.2, 0.4, 1.0] }",
        )
    )
    e = emitter_dicts(cfg, "scalar_rgb")
    assert e["sun"]["type"] == "directional"
    np.testing.assert_allclose(e["sun"]["direction"], -sun_vector(30.0, 90.0))
    np.testing.assert_allclose(e["sun"]["irradiance"]["value"], [2.0, 1.0, 0.5])
    np.testing.assert_allclose(e["sky"]["radiance"]["value"], [0.1, 0.2, 0.5])
    lit = cfg.with_overrides(
        {"lights.sun.irradiance": 4.0, "lights.sky.colour": [1, 1, 1], "lights.sky.radiance": 0.25}
    )
    o = emitter_dicts(lit, "scalar_rgb")
    np.testing.assert_allclose(o["sun"]["irradiance"]["value"], [4.0, 2.0, 1.0])
    np.testing.assert_allclose(o["sky"]["radiance"]["value"], [0.25, 0.25, 0.25])
    with pytest.raises(ForestError, match=r"lights\.sun\.power: unknown key"):
        cfg.with_overrides({"lights.sun.power": 1.0})
    with pytest.raises(ForestError, match=r"lights\.sun\.colour"):
        cfg.with_overrides({"lights.sun.colour": [1, 2]})
    night = parse_config(
        TOP_DOWN.replace(
            "sky = { radiance = 1.0, colour = [1.0, 1.0, 1.0] }", "sun = { elevation = -5.0 }\nsky = { radiance = 0.1 }"
        )
    )
    assert set(emitter_dicts(night, "scalar_rgb")) == {"sky"}
    sunsky = parse_config(
        TOP_DOWN.replace(
            "sky = { radiance = 1.0, colour = [1.0, 1.0, 1.0] }",
            "sun = { elevation = 40.0 }\nsky = { sunsky = { turbidity = 4.0 } }",
        )
    )
    e = emitter_dicts(sunsky, "scalar_rgb")
    assert set(e) == {"sky"} and e["sky"]["type"] == "sunsky"
    mitsuba("scalar_rgb").load_dict(e["sky"])


def test_sensor_follows_camera_keys():
    cfg = parse_config(
        TOP_DOWN.replace(
            "fov = 30.0",
            "fov = 30.0\nkeys = [ { frame = 1, position = [0.0, 50.0, -100.0], "
            "target = [0.0, 0.0, 0.0] }, { frame = 10, position = [50.0, 50.0, -100.0], "
            "target = [0.0, 0.0, 0.0] } ]",
        )
    )
    a = sensor_dict(cfg, 1.0)
    b = sensor_dict(cfg, 10.0, width=8, height=6, spp=2)
    np.testing.assert_allclose(np.asarray(a["to_world"].matrix)[:3, 3], [0, 50, -100], atol=1e-5)
    np.testing.assert_allclose(np.asarray(b["to_world"].matrix)[:3, 3], [50, 50, -100], atol=1e-5)
    assert (a["film"]["width"], a["film"]["height"], a["sampler"]["sample_count"]) == (32, 32, 4)
    assert (b["film"]["width"], b["film"]["height"], b["sampler"]["sample_count"]) == (8, 6, 2)
    assert a["fov_axis"] == "x" and a["fov"] == 30.0


def test_lod_levels_by_distance():
    pos = np.array([[0, 0, 10], [0, 0, 50], [0, 0, 150], [0, 0, 1000], [0, 0, 1000]], float)
    levels = lod_levels(pos, [0, 0, 0], (40.0, 100.0, 500.0), np.array([4, 4, 4, 4, 2]))
    assert levels.tolist() == [0, 1, 2, 3, 1]  # the last species has only two LODs
    assert lod_levels(pos, [0, 0, 0], (), np.full(5, 4)).tolist() == [0] * 5


def test_wind_sway_is_a_rotation_towards_the_wind():
    theta = np.array([0.0, 0.1, -0.2])
    r = sway_rotation(theta, 90.0)  # wind towards +X
    for k in range(3):
        np.testing.assert_allclose(r[k] @ r[k].T, np.eye(3), atol=1e-12)
        np.testing.assert_allclose(r[k] @ [0, 1, 0], [np.sin(theta[k]), np.cos(theta[k]), 0], atol=1e-12)

    class Wind:
        strength, frequency, direction = 2.0, 0.5, 0.0

    phase = np.array([0.0, np.pi / 2])
    np.testing.assert_allclose(sway_angles(phase, 0.0, Wind), np.radians(2.0) * np.array([0.0, 1.0]), atol=1e-12)
    assert not np.allclose(sway_angles(phase, 0.3, Wind), sway_angles(phase, 0.0, Wind))


def test_envmap_dome_light(tmp_path):
    """An environment map lights the scene as a dome: a white-ish sky above makes the ground bright."""
    from forest.images import write_image

    sky = np.zeros((64, 128, 3), np.float32)
    sky[:32] = [0.5, 0.6, 0.9]  # upper half of the latitude–longitude map: the sky
    write_image(tmp_path / "sky.exr", sky)
    text = TOP_DOWN.replace(
        "sky = { radiance = 1.0, colour = [1.0, 1.0, 1.0] }", 'sky = { envmap = "sky.exr", scale = 2.0 }'
    )
    cfg = parse_config(text, path=tmp_path / "s.toml", base_dir=tmp_path)
    e = emitter_dicts(cfg, "scalar_rgb")
    assert e["sky"]["type"] == "envmap" and e["sky"]["scale"] == 2.0
    assert emitter_dicts(cfg.with_overrides({"lights.sky.scale": 0.5}), "scalar_rgb")["sky"]["scale"] == 0.5
    mi = mitsuba("scalar_rgb")
    terrain = load_terrain(cfg.terrain)
    scene = mi.load_dict(
        {
            "type": "scene",
            "integrator": {"type": "path", "max_depth": 2},
            "sensor": sensor_dict(cfg, width=8, height=8, spp=64),
            **e,
            "terrain": terrain_dict(ground_of(cfg, terrain), terrain, "scalar_rgb"),
        }
    )
    img = np.asarray(mi.render(scene))[..., :3]
    # White ground under a sky of radiance 2·(0.5, 0.6, 0.9) over the upper hemisphere: L = ρ·E/π = 2·c.
    # (central pixels: the outer ring looks past the 100 m terrain, down into the black lower hemisphere)
    np.testing.assert_allclose(img[1:7, 1:7].reshape(-1, 3).mean(axis=0), 2.0 * np.array([0.5, 0.6, 0.9]), rtol=0.05)


def test_terrain_texture_overrides_terrain_colour(tmp_path):
    from forest.images import write_image

    tex = np.zeros((8, 8, 3), np.float32)
    tex[:, :4] = [0.6, 0.1, 0.1]  # x < 0 red, x > 0 blue (linear EXR: no decoding)
    tex[:, 4:] = [0.1, 0.1, 0.6]
    write_image(tmp_path / "ground.exr", tex, half=False)
    text = TOP_DOWN.replace("terrain_colour = [1.0, 1.0, 1.0]", 'terrain_texture = "ground.exr"')
    cfg = parse_config(text, path=tmp_path / "s.toml", base_dir=tmp_path)
    mi = mitsuba("scalar_rgb")
    scene = mi.load_dict(
        {
            "type": "scene",
            "integrator": {"type": "path", "max_depth": 2},
            "sensor": sensor_dict(cfg),
            **emitter_dicts(cfg, "scalar_rgb"),
            "terrain": terrain_dict(ground_of(cfg, terrain := load_terrain(cfg.terrain)), terrain, "scalar_rgb"),
        }
    )
    img = np.asarray(mi.render(scene))[..., :3]
    gx, gz = ground_points(cfg, 32, 32)
    inner = np.abs(gz) < 40
    np.testing.assert_allclose(img[inner & (gx < -8) & (gx > -40)].mean(axis=0), [0.6, 0.1, 0.1], atol=0.04)
    np.testing.assert_allclose(img[inner & (gx > 8) & (gx < 40)].mean(axis=0), [0.1, 0.1, 0.6], atol=0.04)
