"""Hills on the ground past the terrain's edge (``[render] horizon_hills``, forest.skirt "Hills")."""

from __future__ import annotations

import numpy as np
import pytest
from test_render import trees

from forest.config import parse_config
from forest.errors import ConfigError
from forest.images import read_exr_channels
from forest.render import render_scene
from forest.scene import load_scene
from forest.skirt import HILL_RINGS, Hills, hill_field, hills, skirt_mesh
from forest.terrain import fbm_heights, grid_terrain

from render_fixtures import BoxLibrary

#: A 100 m flat square seen from 2 m over its south edge, looking north just above the horizon.
SCENE = """
seed = 3
[terrain]
flat = {{ size = 100.0 }}
[camera]
position = [0.0, 2.0, -49.0]
target = [0.0, 2.0, 1000.0]
fov = 40.0
[lights]
sun = {{ elevation = 40.0, azimuth = 160.0, irradiance = 3.0 }}
sky = {{ radiance = 1.0, colour = [1.0, 1.0, 1.0] }}
[render]
width = 48
height = 32
spp = 4
max_depth = 2
{render}
[[species]]
model = "box"
percent = 100
"""


@pytest.fixture(scope="module")
def terrain():
    return grid_terrain(fbm_heights(33, 4, 0.5, 1) * 20.0, (200.0, 200.0))


def test_the_hills_join_the_terrain_and_rise_past_it(terrain):
    """The ring at the edge is the terrain's boundary, the hills stay under their height above the plain's
    profile, stay low within a tenth of their scale past the ramp, and every face winds upward."""
    plain = skirt_mesh(terrain, 30_000.0)
    hilly = skirt_mesh(terrain, 30_000.0, Hills(300.0, 1000.0, 4))
    assert plain is not None and hilly is not None
    k = len(plain.vertices) // 3
    np.testing.assert_array_equal(hilly.vertices[: 2 * k], plain.vertices[: 2 * k])  # edge and ramp unchanged
    assert len(hilly.vertices) == (2 + HILL_RINGS) * k
    rings = hilly.vertices[2 * k :].reshape(HILL_RINGS, k, 3).astype(np.float64)
    centre = np.array([0.0, 0.0])
    r = np.linalg.norm(rings[:, :, [0, 2]] - centre, axis=2)
    r0 = np.linalg.norm(plain.vertices[k : 2 * k, [0, 2]].astype(np.float64), axis=1)
    np.testing.assert_allclose(r[-1], 30_000.0, rtol=1e-5)  # the last ring is the plain's outer ring
    assert np.all(np.diff(r, axis=0) > 0)  # rings go outward
    mean_edge = float(plain.vertices[2 * k :, 1].mean())
    profile = plain.vertices[k : 2 * k, 1][None, :] + (mean_edge - plain.vertices[k : 2 * k, 1][None, :]) * (
        (r - r0[None, :]) / (30_000.0 - r0[None, :])
    )
    rise = rings[:, :, 1] - profile
    assert rise.min() > -1e-3 and rise.max() <= 300.0 + 1e-3
    assert rise.max() > 200.0  # they are hills: some come near their height
    near = (r - r0[None, :]) < 100.0
    assert near.any() and rise[near].max() < 300.0 * 0.03  # s(0.1) = 0.028: level with the edge at first
    v = hilly.vertices.astype(np.float64)
    f = hilly.faces
    up = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])[:, 1]
    assert np.all(up >= 0.0)
    assert np.all(hilly.normals[:, 1] > 0.5)  # gentle slopes, normals up


def test_the_hills_are_seeded_and_deterministic(terrain):
    a = skirt_mesh(terrain, 30_000.0, Hills(150.0, 1500.0, 0))
    b = skirt_mesh(terrain, 30_000.0, Hills(150.0, 1500.0, 0))
    c = skirt_mesh(terrain, 30_000.0, Hills(150.0, 1500.0, 1))
    assert a is not None and b is not None and c is not None
    assert a.vertices.tobytes() == b.vertices.tobytes() and a.normals.tobytes() == b.normals.tobytes()
    assert not np.array_equal(a.vertices, c.vertices)
    x = np.linspace(-20_000.0, 20_000.0, 4001)
    h = hill_field(x, np.full_like(x, 3_000.0), Hills(150.0, 1500.0, 0))
    assert h.min() >= 0.0 and h.max() <= 1.0
    assert np.percentile(h, 90) - np.percentile(h, 10) > 0.4  # hills and lowlands, not a constant
    # Correlated over a hill's scale, not over many: neighbours 50 m apart agree, points 5 km apart do not.
    assert np.corrcoef(h[:-5], h[5:])[0, 1] > 0.9
    assert abs(np.corrcoef(h[:-500], h[500:])[0, 1]) < 0.4


def test_hills_need_the_ground_and_none_is_the_plain():
    with pytest.raises(ConfigError, match="needs horizon_ground = true") as e:
        parse_config(SCENE.format(render="horizon_ground = false\nhorizon_hills = { height = 100.0 }"))
    assert e.value.field == "render.horizon_hills"
    assert hills(parse_config(SCENE.format(render=""))) is None
    assert hills(parse_config(SCENE.format(render="horizon_hills = { height = 0.0 }"))) is None
    got = hills(parse_config(SCENE.format(render="horizon_hills = { height = 90.0, scale = 700.0, seed = 2 }")))
    assert got == Hills(90.0, 700.0, 2)


@pytest.mark.parametrize("variant", ("scalar_rgb", "llvm_ad_rgb"))
def test_hills_stand_above_the_horizon_in_both_renderers(tmp_path, variant):
    """From 2 m over the edge, looking level: without hills the upper half of the frame is sky (coverage 0);
    with 100 m hills at 1.5 km scale (a few degrees high from there), ground covers the rows just above the
    horizon but not the top of the frame, and it is lit ground, not black."""
    library = BoxLibrary(tmp_path / "lib")
    covered = {}
    for name, render in (("plain", ""), ("hills", "horizon_hills = { height = 100.0, scale = 1500.0, seed = 1 }")):
        cfg = parse_config(SCENE.format(render=render), path=tmp_path / "scene.toml", base_dir=tmp_path)
        scene = load_scene(cfg, trees([[30.0, 0.0, 30.0]]), library=library)
        out = tmp_path / f"{name}.exr"
        render_scene(scene, output=out, variant=variant)
        layers = read_exr_channels(out)[0]
        alpha, green = layers["A"], layers["G"]
        upper = slice(2, 15)  # rows above the horizon (row 16)
        covered[name] = float(alpha[upper].mean())
        if name == "hills":
            ground = alpha[upper] > 0.99
            assert ground.any() and float(green[upper][ground].mean()) > 0.01
            assert float(alpha[2:5].mean()) < 0.02  # 10-13 degrees up: sky over the hills
            assert float(alpha[13:16].mean()) > 0.5  # 1-3 degrees up: the hills
    assert covered["plain"] < 0.02
    assert 0.1 < covered["hills"] < 0.6


def test_erosion_cuts_gullies_down_the_fall_line_and_leaves_level_ground_smooth():
    """The gullies (forest.erosion) are what erosion adds to the smooth hills: within their depth bound, zero where
    the flow field is level, and on steep ground they vary across the fall line (a comb of gullies and spurs)
    over four times as fast as along it."""
    from forest.erosion import FLOW_OCTAVES, GULLY_DEPTH, GULLY_OCTAVES, GULLY_SLOPE
    from forest.skirt import _squared_fbm

    height, scale = 1200.0, 3000.0
    smooth, eroded = Hills(height, scale, 0), Hills(height, scale, 0, 1.0)
    rng = np.random.default_rng(1)
    x, z = rng.uniform(-20_000.0, 20_000.0, 20_000), rng.uniform(-20_000.0, 20_000.0, 20_000)

    def cut(px: np.ndarray, pz: np.ndarray) -> np.ndarray:
        return hill_field(px, pz, eroded) - hill_field(px, pz, smooth)

    g = cut(x, z)
    assert np.abs(g).max() <= GULLY_DEPTH * sum(0.5**o for o in range(GULLY_OCTAVES))
    assert np.abs(g).max() > 0.5 * GULLY_DEPTH
    half = Hills(height, scale, 0, 0.5)
    np.testing.assert_allclose(hill_field(x, z, half) - hill_field(x, z, smooth), 0.5 * g, atol=1e-12)
    # The flow field's fall line, by central differences
    eps = scale / 200.0

    def flow(px: np.ndarray, pz: np.ndarray) -> np.ndarray:
        return _squared_fbm(px, pz, smooth, FLOW_OCTAVES)

    gx = (flow(x + eps, z) - flow(x - eps, z)) * height / (2.0 * eps)
    gz = (flow(x, z + eps) - flow(x, z - eps)) * height / (2.0 * eps)
    slope = np.hypot(gx, gz)
    level = slope == 0.0
    assert level.sum() > 100 and np.all(g[level] == 0.0)
    steep = slope > 1.2 * GULLY_SLOPE
    assert steep.sum() > 1000
    fu, fv = gx[steep] / slope[steep], gz[steep] / slope[steep]
    xs, zs, d = x[steep], z[steep], 2.0
    along = np.abs(cut(xs + d * fu, zs + d * fv) - cut(xs - d * fu, zs - d * fv))
    across = np.abs(cut(xs - d * fv, zs + d * fu) - cut(xs + d * fv, zs - d * fu))
    assert across.mean() > 4.0 * along.mean()


def test_eroded_hills_carry_more_rings_and_the_estimate_counts_them(terrain):
    from forest.skirt import ERODED_RINGS, skirt_triangles

    eroded = Hills(300.0, 1000.0, 4, 1.0)
    mesh = skirt_mesh(terrain, 30_000.0, eroded)
    plain = skirt_mesh(terrain, 30_000.0)
    assert mesh is not None and plain is not None
    k = len(plain.vertices) // 3
    assert len(mesh.vertices) == (2 + ERODED_RINGS) * k
    assert skirt_triangles(terrain, eroded) == len(mesh.faces)
    again = skirt_mesh(terrain, 30_000.0, eroded)
    assert again is not None and again.vertices.tobytes() == mesh.vertices.tobytes()


def test_erosion_is_read_from_the_config_and_bounded():
    """Set, it is the config's; unset, hills up to 300 m are smooth (the examples' far hills keep their bytes),
    mountains from 1 200 m fully eroded, linear between."""
    got = hills(parse_config(SCENE.format(render="horizon_hills = { height = 90.0, erosion = 0.7 }")))
    assert got is not None and got.erosion == 0.7
    for height, expected in ((90.0, 0.0), (300.0, 0.0), (750.0, 0.5), (1200.0, 1.0), (3000.0, 1.0)):
        unset = hills(parse_config(SCENE.format(render=f"horizon_hills = {{ height = {height} }}")))
        assert unset is not None and unset.erosion == pytest.approx(expected)
    smooth = hills(parse_config(SCENE.format(render="horizon_hills = { height = 3000.0, erosion = 0.0 }")))
    assert smooth is not None and smooth.erosion == 0.0
    with pytest.raises(ConfigError) as e:
        parse_config(SCENE.format(render="horizon_hills = { height = 90.0, erosion = 1.5 }"))
    assert e.value.field == "render.horizon_hills.erosion"


def test_lattice_at_gives_the_lattice_values_whether_it_tabulates_or_not():
    """The hills' and gullies' lattice values come from a table over the points' bounding box when it is smaller
    than the points asked for; they are the per-point hash's values either way."""
    from forest.scatter.canopy import lattice, lattice_at

    rng = np.random.default_rng(3)
    key = np.uint64(0x1234_5678_9ABC)
    dense = np.floor(rng.uniform(-20.0, 20.0, (2, 5000)))  # 41 × 41 cells for 5 000 points: tabulated
    sparse = np.floor(rng.uniform(-1e6, 1e6, (2, 50)))  # a huge box for 50 points: hashed per point
    for ix, iz in (dense, sparse):
        np.testing.assert_array_equal(lattice_at(ix, iz, key), lattice(ix, iz, key))
