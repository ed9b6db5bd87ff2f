"""The sea: still water (``[terrain] water``) that reaches the terrain's edge runs on over the skirt to the horizon
in both renderers and the exports (forest.skirt, "The sea"), where it used to end at the edge under land."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import run_forest, write_png, write_scene
from test_water import BED, VARIANT, fresnel, look, water_inputs

from forest.render.path import PathCamera, PathInputs, PathScene, SkyLight
from forest.skirt import SEA_SMOOTH, Hills, Sea, sea_at_edge, skirt_mesh, wet_faces
from forest.terrain import SHORE_RAMP, flood, grid_terrain

LEVEL = 5.0
HILLS = Hills(height=200.0, scale=2500.0, seed=3)


def coast(n: int = 33):
    """A 200 m terrain rising from 0 m at x = −100 to 20 m at x = +100, flooded to 5 m: its west quarter is sea."""
    h = np.tile(np.linspace(0.0, 20.0, n)[None, :], (n, 1))
    return flood(grid_terrain(h, (200.0, 200.0)), LEVEL, 0.5)


def columns(sk, radius: float = 20_000.0):
    """The skirt's vertices farther than ``radius`` from the centre: (their angle from +x in degrees, their y)."""
    v = np.asarray(sk.vertices, np.float64)
    far = np.linalg.norm(v[:, [0, 2]], axis=1) > radius
    return np.degrees(np.arctan2(v[far, 2], v[far, 0])), v[far, 1]


@pytest.mark.parametrize("hills", [None, HILLS], ids=["plain", "hills"])
def test_the_skirt_carries_the_sea_past_a_wet_edge(hills):
    """Toward the wet west edge the far skirt lies at the water's level (no hills rise there); toward the dry east
    edge it is land above it (with hills, hundreds of metres); nothing is below the level; the sea's share of the
    edge falls from 1 to 0 over the smoothing window, not at once."""
    terrain = coast()
    sk = skirt_mesh(terrain, 30_000.0, hills)
    assert sk is not None
    assert np.asarray(sk.vertices)[:, 1].min() >= LEVEL - 1e-4
    ang, y = columns(sk)
    west = np.abs(np.abs(ang) - 180.0) < 20.0
    east = np.abs(ang) < 20.0
    np.testing.assert_allclose(y[west], LEVEL, atol=1e-3)
    assert y[east].min() > LEVEL + 1.0
    if hills is not None:
        assert y[east].max() > LEVEL + 50.0
    sea = sea_at_edge(terrain)
    assert isinstance(sea, Sea) and sea.level == LEVEL
    w = sea.weight(np.array([[np.cos(a), 0.0, np.sin(a)] for a in np.radians(np.arange(-180.0, 180.0, 0.5))]))
    assert w.max() == pytest.approx(1.0) and w.min() == pytest.approx(0.0)
    assert np.abs(np.diff(w)).max() < 1.1 * np.radians(0.5) / SEA_SMOOTH  # at most a triangle window's slope
    wet = wet_faces(sk.vertices, sk.faces, LEVEL)
    assert 0.1 < wet.mean() < 0.9


def test_an_island_is_ringed_by_sea_to_the_horizon():
    """A terrain flooded all round its edge: the whole skirt is water at the level, hills or not."""
    h = np.zeros((17, 17))
    h[4:13, 4:13] = 10.0  # an island in the middle
    terrain = flood(grid_terrain(h, (100.0, 100.0)), 2.0)
    for hills in (None, HILLS):
        sk = skirt_mesh(terrain, 30_000.0, hills)
        np.testing.assert_allclose(np.asarray(sk.vertices)[:, 1], 2.0, atol=1e-4)
        assert wet_faces(sk.vertices, sk.faces, 2.0).all()


def test_a_dry_edge_keeps_the_skirt_as_it_was():
    """Water that does not reach the edge (a lake in a bowl) leaves the skirt exactly as without water."""
    t = np.linspace(-1.0, 1.0, 33)
    h = (t[None, :] ** 2 + t[:, None] ** 2) * 20.0
    dry = grid_terrain(h, (200.0, 200.0))
    lake = flood(dry, 6.0)
    assert lake.vertices[:, 1].min() == 6.0 and sea_at_edge(lake) is None
    for hills in (None, HILLS):
        a, b = skirt_mesh(dry, 30_000.0, hills), skirt_mesh(lake, 30_000.0, hills)
        for name in ("vertices", "faces", "normals"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


def sea_inputs(camera, sky, sea_colour, spp: int = 128) -> PathInputs:
    """tests/test_water.py's 400 m terrain of water, flooded everywhere (its edge all water) and carried to 30 km by
    the skirt."""
    from dataclasses import replace

    flooded = flood(grid_terrain(np.zeros((5, 5)), (400.0, 400.0)), 1.0)
    return replace(water_inputs(camera, sky, spp=spp), terrain=flooded, skirt_radius=30_000.0, sea_colour=sea_colour)


def test_the_sea_past_the_edge_reflects_the_sky():
    """Looking at the skirt 100 m past the terrain's edge at 80° from the normal, the sea shows the closed form of a
    smooth water surface, F(μ)·L(r) + (1 − F(μ))·R·E/π (tests/test_water.py), as the terrain's own water does."""
    theta = np.radians(80.0)
    x0 = 300.0  # the terrain ends at 200 m
    camera = PathCamera(look([x0, 11.0, -10.0 * np.tan(theta)], [x0, 1.0, 0.0]), 0.2, 4, 4)
    z, h = np.array([0.10, 0.20, 0.60]), np.array([0.50, 0.45, 0.40])
    sky = SkyLight("gradient", zenith=tuple(z), horizon=tuple(h))
    img = PathScene(sea_inputs(camera, sky, BED), VARIANT).render().rgb.reshape(-1, 3).mean(axis=0)
    mu = np.cos(theta)
    f = fresnel(mu)
    expected = f * (h + (z - h) * mu) + (1.0 - f) * np.asarray(BED) * (h + 2.0 / 3.0 * (z - h))
    np.testing.assert_allclose(img, expected, rtol=0.02)


SEA = """
seed = 3
[terrain]
flat = {{ size = 200.0 }}
water = {{ level = {level} }}
[scatter]
count = 10
[[species]]
model = "box.obj"
percent = 100
[camera]
position = [0.0, 6.0, 0.0]
target = [0.0, 6.0, 1000.0]
fov = 30.0
far = 20000.0
[lights]
sun = {{ elevation = 30.0, azimuth = 180.0 }}
sky = {{ sunsky = {{ turbidity = 3.0 }} }}
[render]
width = 48
height = 32
spp = 16
variant = "{variant}"
"""


@pytest.mark.parametrize("variant", ["llvm_ad_rgb", "scalar_rgb"])
def test_a_flooded_terrain_looks_out_over_sea_to_the_horizon(tmp_path, variant):
    """``forest render`` of a terrain under water seen from 6 m up, looking level, the sun behind: below the horizon
    (all of it past the terrain's edge at 100 m but the bottom rows) the sea mirrors the sky at grazing angles —
    the rows just below the horizon are at least half as bright as the sky just above it (F ≈ 0.3–0.9 there) and
    as blue; the same terrain dry (the level under it) shows land there, far darker and not blue."""
    import OpenImageIO as oiio
    import trimesh

    trimesh.creation.box(extents=(1.0, 2.0, 1.0)).apply_translation((0.0, 1.0, 0.0)).export(tmp_path / "box.obj")
    bands = {}
    for name, level in (("sea", 1.0), ("dry", -1.0)):
        cfg = write_scene(tmp_path, SEA.format(level=level, variant=variant), f"{name}.toml")
        r = run_forest("render", cfg, "-o", tmp_path / f"{name}.exr", "-q")
        assert r.returncode == 0, r.stderr
        rgb = oiio.ImageBuf(str(tmp_path / f"{name}.exr")).get_pixels(oiio.FLOAT)[..., :3]
        bands[name] = rgb[12:16].mean(axis=(0, 1)), rgb[17:21].mean(axis=(0, 1))  # sky above, ground below
    sky, sea = bands["sea"]
    assert sea.mean() > 0.5 * sky.mean() and sea[2] > sea[0]
    _, land = bands["dry"]
    assert land.mean() < 0.5 * sea.mean() or land[2] < land[0]


def test_scalar_rgb_draws_the_skirts_sea_as_water():
    """Mitsuba's own integrator: the skirt's sea joins the water mesh (plastic), its land stays on the terrain's."""
    import mitsuba as mi

    from forest.ground import TerrainAlbedo
    from forest.render.scene import ground_dicts

    mi.set_variant("scalar_rgb")
    terrain = coast()
    rgb = np.tile(np.asarray(BED, np.float32), (32, 32, 1))
    water = np.asarray(terrain.water_cover(terrain.vertices[:, 1].reshape(33, 33)[:-1, :-1]), np.float32)
    albedo = TerrainAlbedo(rgb, terrain.extent, water=water)
    sk = skirt_mesh(terrain, 30_000.0, None)
    sea = wet_faces(sk.vertices, sk.faces, LEVEL)
    ground, wet = ground_dicts(albedo, terrain, "scalar_rgb", skirt=30_000.0)
    alone, lake = ground_dicts(albedo, terrain, "scalar_rgb")  # no skirt: the terrain's own water only
    assert wet.face_count() == lake.face_count() + int(sea.sum())
    assert ground.face_count() == alone.face_count() + int((~sea).sum())
    p = np.asarray(mi.traverse(wet)["vertex_positions"]).reshape(-1, 3)
    f = np.asarray(mi.traverse(wet)["faces"]).reshape(-1, 3)
    out = (p[f][..., 0] < -100.0).all(axis=1)  # faces past the terrain's west edge: the skirt's sea, level
    assert out.any() and p[f][..., 0].min() < -1000.0
    assert np.abs(p[f[out]][..., 1] - LEVEL).max() < SHORE_RAMP


COAST = """
seed = 2
[terrain]
heightmap = "coast.png"
size = [200.0, 200.0]
height = 20.0
water = {{ level = {level} }}
[scatter]
count = 50
[[species]]
model = "box.obj"
percent = 100
[camera]
position = [0.0, 30.0, -90.0]
target = [-200.0, 5.0, 0.0]
far = 20000.0
[lights]
sky = {{ radiance = 1.0 }}
[render]
width = 24
height = 16
spp = 2
horizon_hills = {{ height = 200.0, scale = 2500.0 }}
"""


@pytest.mark.parametrize("level", [5.0, -1.0], ids=["sea", "dry"])
def test_exports_carry_the_sea_on_past_the_edge(tmp_path, level):
    """USD: the water runs on past the terrain's edge over the horizon's sea and the horizon leaves it out; with the
    level under the terrain nothing is water and the horizon is whole; without hills (no horizon written) the sea
    is written all the same."""
    import trimesh
    from pxr import Usd, UsdGeom

    write_png(tmp_path / "coast.png", np.tile(np.linspace(0.0, 1.0, 33)[None, :], (33, 1)), bits=16)
    trimesh.creation.box(extents=(1.0, 2.0, 1.0)).apply_translation((0.0, 1.0, 0.0)).export(tmp_path / "box.obj")
    cfg = write_scene(tmp_path, COAST.format(level=level))
    r = run_forest("export", "usd", cfg, "-o", tmp_path / "c.usda")
    assert r.returncode == 0, r.stderr
    stage = Usd.Stage.Open(str(tmp_path / "c.usda"))
    horizon = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Horizon"))
    hp = np.asarray(horizon.GetPointsAttr().Get())
    hf = np.asarray(horizon.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3)
    water = stage.GetPrimAtPath("/World/Water")
    if level < 0:
        assert not water.IsValid()
        assert hp[:, 0].min() < -1000.0  # the horizon all round
        return
    wp = np.asarray(UsdGeom.Mesh(water).GetPointsAttr().Get())
    wf = np.asarray(UsdGeom.Mesh(water).GetFaceVertexIndicesAttr().Get()).reshape(-1, 3)
    out = (wp[wf][..., 0] < -100.0).all(axis=1)  # faces past the terrain's west edge: the sea, far out
    assert wp[:, 0].min() < -1000.0 and out.any() and wet_faces(wp, wf[out], level).all()
    assert not wet_faces(hp, hf, level).any()  # the horizon is land only
    assert hp[:, 0].max() > 1000.0  # the land's horizon to the east
    without_hills = COAST.format(level=level).replace("horizon_hills = { height = 200.0, scale = 2500.0 }\n", "")
    flat = write_scene(tmp_path, without_hills, "flat.toml")
    r = run_forest("export", "usd", flat, "-o", tmp_path / "flat.usda")
    assert r.returncode == 0, r.stderr
    plain = Usd.Stage.Open(str(tmp_path / "flat.usda"))
    assert not plain.GetPrimAtPath("/World/Horizon").IsValid()
    fp = np.asarray(UsdGeom.Mesh(plain.GetPrimAtPath("/World/Water")).GetPointsAttr().Get())
    assert fp[:, 0].min() < -1000.0  # the sea to the far clip, without hills
