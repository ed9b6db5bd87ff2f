"""Still water (``[terrain] water = { level, shore }``): a lake's flat surface in the one terrain mesh,
painted with the ground's ``water`` material, kept free of trees and ground cover up to its shore."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from conftest import run_forest, write_png, write_scene

from forest.config import load_config
from forest.config.schema import GROUND_MATERIALS
from forest.scatter import scatter
from forest.scene import load_scene
from forest.terrain import SHORE_RAMP, flood, grid_terrain, load_terrain

from export_support import blender_probe, validation_errors

LEVEL = 4.0
BOWL = """
seed = 5
[terrain]
heightmap = "bowl.png"
size = [200.0, 200.0]
height = 20.0
water = {{ level = {level}, shore = {shore} }}
[scatter]
count = 6000
min_distance = 0.5
[[species]]
model = "box.obj"
percent = 100
[lights]
sky = {{ radiance = 1.0 }}
[render]
width = 24
height = 16
spp = 4
"""


def bowl_heights(n: int = 65) -> np.ndarray:
    """A round bowl in [0, 1]: 0 at the centre, rising with the square of the distance to 1 at the corners."""
    t = np.linspace(-1.0, 1.0, n)
    r2 = t[None, :] ** 2 + t[:, None] ** 2
    return r2 / r2.max()


def write_bowl(tmp_path) -> None:
    """The bowl's heightmap and a 1 m box as the trees' mesh."""
    import trimesh

    write_png(tmp_path / "bowl.png", bowl_heights(), bits=16)
    trimesh.creation.box(extents=(1.0, 2.0, 1.0)).apply_translation((0.0, 1.0, 0.0)).export(tmp_path / "box.obj")


def bowl_config(tmp_path, shore: float = 0.5, extra: str = ""):
    write_bowl(tmp_path)
    return load_config(write_scene(tmp_path, BOWL.format(level=LEVEL, shore=shore) + extra))


def test_flood_raises_what_lies_below_the_level_and_keeps_the_rest():
    rng = np.random.default_rng(1)
    h = rng.random((9, 9)) * 10.0
    dry = grid_terrain(h, (80.0, 80.0))
    wet = flood(dry, 5.0, 1.0)
    y0, y1 = dry.vertices[:, 1], wet.vertices[:, 1]
    assert np.array_equal(y1, np.maximum(y0, 5.0))
    assert np.array_equal(wet.vertices[:, [0, 2]], dry.vertices[:, [0, 2]])
    assert np.array_equal(wet.faces, dry.faces) and wet.grid_shape == dry.grid_shape
    assert wet.water == (5.0, 1.0) and dry.water is None
    # The surface is flat at the level, exactly, wherever all three corners were under it.
    under = (y0[dry.faces] < 5.0).all(axis=1)
    assert under.any()
    np.testing.assert_array_equal(wet.face_normals[under], np.tile([0.0, 1.0, 0.0], (int(under.sum()), 1)))
    # dry(): more than the shore above the level; without water everything is dry.
    assert list(wet.dry(np.array([5.0, 6.0, 6.01]))) == [False, False, True]
    assert dry.dry(np.array([-100.0])).all()
    # The water's coverage: 1 on the surface, 0 from SHORE_RAMP above it.
    np.testing.assert_allclose(wet.water_cover(np.array([5.0, 5.0 + SHORE_RAMP / 2, 5.0 + SHORE_RAMP])), [1, 0.5, 0])
    assert dry.water_cover(np.array([0.0])) is None


def test_no_tree_stands_in_the_water_or_on_its_shore(tmp_path):
    config = bowl_config(tmp_path, shore=0.5)
    inst, report = scatter(config)
    assert len(inst) > 500
    assert inst.position[:, 1].min() >= np.float32(LEVEL + 0.5)  # positions are float32
    # The share the water took is the flooded surface's share of the terrain (within sampling noise).
    terrain = load_terrain(config.terrain, config.path)
    y = terrain.vertices[terrain.faces, 1]
    wet_area = terrain.face_areas[(y <= LEVEL + 0.5).all(axis=1)].sum() / terrain.area
    n = report.candidates
    share = report.rejected["water"] / n
    assert share > 0.5 * wet_area and share < wet_area + 0.05  # shore triangles are partly dry
    # Without water the same bowl grows trees on its floor.
    dry = load_config(
        write_scene(tmp_path, BOWL.format(level=LEVEL, shore=0.5).replace("water = {", "# {"), "dry.toml")
    )
    inst_dry, report_dry = scatter(dry)
    assert report_dry.rejected["water"] == 0 and inst_dry.position[:, 1].min() < LEVEL


def test_ground_cover_keeps_out_of_the_water(tmp_path):
    extra = '[[ground_cover]]\nmodel = "box.obj"\ndensity = 0.5\nmax_distance = 500.0\n'
    config = bowl_config(tmp_path, shore=0.2, extra=extra)
    inst, _ = scatter(config)
    cover = inst.species == 1
    assert cover.sum() > 100
    assert inst.position[cover, 1].min() >= np.float32(LEVEL + 0.2)  # positions are float32


def test_water_edge_cover_grows_down_to_the_waterline(tmp_path):
    """``water_edge = true`` (reeds): the cover keeps off the water itself only — none on the flooded surface (W ≥ ½
    there), but plants within the shore's metre above it, down to a few centimetres of the level, at the density the
    shore's area there asks (a band of 0-1 m above the level, the altitude window)."""
    band = f"altitude = [{LEVEL}, {LEVEL + 1.0}]\n"
    extra = '[[ground_cover]]\nmodel = "box.obj"\ndensity = 4.0\nmax_distance = 500.0\n' + band
    config = bowl_config(tmp_path, shore=1.0, extra=extra + "water_edge = true\n")
    inst, _ = scatter(config)
    y = inst.position[inst.species == 1, 1].astype(np.float64)
    assert len(y) > 50
    assert y.min() > LEVEL + 0.5 * SHORE_RAMP - 1e-4  # never on the water
    assert y.min() < LEVEL + 0.1 and np.mean(y < LEVEL + 0.5) > 0.3  # down to the waterline
    # The same cover without it keeps the shore's metre free: nothing in the band at all.
    plain = bowl_config(tmp_path, shore=1.0, extra=extra)
    inst_plain, _ = scatter(plain)
    assert (inst_plain.species == 1).sum() == 0


def test_the_ground_paints_the_lake_as_water(tmp_path):
    config = bowl_config(tmp_path, extra='[ground]\nbase = "grass"\nrules = []\n')
    scene = load_scene(config)
    alb = scene.terrain_albedo
    assert alb.water is not None
    water_rgb = np.asarray(GROUND_MATERIALS["water"], np.float32)
    centre = alb.water_at(np.array([0.0]), np.array([0.0]))
    assert centre[0] == pytest.approx(1.0)
    h, w = alb.water.shape
    # The centre is LEVEL metres deep over grass (shallow water, tested below); optically deep water is the colour.
    deep = load_scene(bowl_config(tmp_path, extra='[ground]\nbase = "grass"\nrules = []\n'
                                  "water_attenuation = [50.0, 50.0, 50.0]\n")).terrain_albedo  # fmt: skip
    np.testing.assert_allclose(deep.rgb[h // 2, w // 2], water_rgb, rtol=1e-5)  # the grid, before the detail
    corner = alb.water_at(np.array([95.0]), np.array([95.0]))
    assert corner[0] == 0.0
    # The wet share of the grid is the flooded share of the plan: h = 20·r²/2 (r in half-sides, 2 at the
    # corners), so under the level r² < LEVEL/10, a disc of π·r² in the plan's 2 × 2.
    plan = np.pi * (LEVEL / 10.0) / 4.0
    assert float((alb.water > 0.5).mean()) == pytest.approx(plan, rel=0.1)
    # One colour for the whole ground (``[render] terrain_colour``) keeps the lake.
    one = load_config(write_scene(tmp_path, BOWL.format(level=LEVEL, shore=0.5).replace(
        "spp = 4", "spp = 4\nterrain_colour = [0.3, 0.2, 0.1]"), "one.toml"))  # fmt: skip
    alb1 = load_scene(one).terrain_albedo
    assert alb1.water is not None and alb1.water_at(np.array([0.0]), np.array([0.0]))[0] == pytest.approx(1.0)
    np.testing.assert_allclose(alb1.rgb[0, 0], [0.3, 0.2, 0.1], rtol=1e-5)  # a corner texel, dry


def test_the_lake_shows_its_bed_where_it_is_shallow(tmp_path):
    """Shallow water (forest.ground, "Shallow water"): each texel under the lake is painted
    R(H) = c + (A − c)·exp(−2KH) (Maritorena et al. 1994), A the grass under it, c the water's colour, K the
    attenuation and H its depth — checked against the bowl's closed-form depth, LEVEL − (x² + z²)/1000 (the
    heightmap is 20·(u² + v²)/2 over ±100 m), not against the terrain the code reads. The flooded terrain
    keeps its bed; K large is the water's colour, K = 0 the bed itself; a one-colour ground shows its colour."""
    from forest.ground import texel_centres

    k = np.array([0.40, 0.20, 0.45])
    config = bowl_config(tmp_path, extra='[ground]\nbase = "grass"\nrules = []\nvariation = 0.0\n'
                         f"water_attenuation = [{k[0]}, {k[1]}, {k[2]}]\n")  # fmt: skip
    scene = load_scene(config)
    alb, terrain = scene.terrain_albedo, scene.terrain
    x, z = texel_centres(alb.extent, alb.water.shape)
    depth = LEVEL - (x**2 + z**2) / 1000.0
    assert terrain.bed is not None and terrain.bed.height_range[0] == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(terrain.water_depth(x, z), np.maximum(depth, 0.0), atol=0.01)
    inside = alb.water == 1.0
    assert inside.sum() > 100 and depth[inside].max() > 3.5 and depth[inside].min() < 0.5
    c, grass = np.asarray(GROUND_MATERIALS["water"]), np.asarray(GROUND_MATERIALS["grass"])
    expected = c + (grass - c) * np.exp(-2.0 * depth[inside][:, None] * k)
    np.testing.assert_allclose(alb.rgb[inside], expected, rtol=0.01, atol=2e-4)
    # Shallower is nearer the grass: the texel nearest the shore is much nearer it than the centre's.
    shallow_row = alb.rgb[inside][np.argmin(depth[inside])]
    deep_row = alb.rgb[inside][np.argmax(depth[inside])]
    assert np.abs(shallow_row - grass).max() < np.abs(deep_row - grass).max() / 3
    clear = load_scene(bowl_config(tmp_path, extra='[ground]\nbase = "grass"\nrules = []\nvariation = 0.0\n'
                                   "water_attenuation = [0.0, 0.0, 0.0]\n")).terrain_albedo  # fmt: skip
    np.testing.assert_allclose(clear.rgb[inside], np.broadcast_to(grass, (inside.sum(), 3)), rtol=1e-5)
    one = load_config(write_scene(tmp_path, BOWL.format(level=LEVEL, shore=0.5).replace(
        "spp = 4", "spp = 4\nterrain_colour = [0.3, 0.2, 0.1]"), "one.toml"))  # fmt: skip
    alb1 = load_scene(one).terrain_albedo
    x1, z1 = texel_centres(alb1.extent, alb1.water.shape)
    d1 = LEVEL - (x1**2 + z1**2) / 1000.0
    in1 = alb1.water == 1.0
    want = c + (np.array([0.3, 0.2, 0.1]) - c) * np.exp(-2.0 * d1[in1][:, None] * np.asarray(k))
    np.testing.assert_allclose(alb1.rgb[in1], want, rtol=0.01, atol=2e-4)


@pytest.mark.parametrize("variant", ["llvm_ad_rgb", "scalar_rgb"])
def test_a_rendered_lake_mirrors_the_sky(tmp_path, variant):
    """Looking across the bowl at a low angle under a clear sky, the lake (the lower rows) is far bluer than
    the same bowl's dry brown floor: the water reflects the sky — in forest_path (its per-hit mirror) and in
    scalar_rgb (the water's triangles apart, Mitsuba's plastic of index 1.33)."""
    sky = "\n[lights.sky]\nsunsky = { turbidity = 3.0 }\n"
    cam = "[camera]\nposition = [0.0, 14.0, -70.0]\ntarget = [0.0, 4.0, 0.0]\nfov = 30.0\n"
    write_bowl(tmp_path)
    rows = []
    for name, water in (("wet", True), ("dry", False)):
        text = BOWL.format(level=LEVEL, shore=0.5).replace("count = 6000", "count = 0") + cam
        text = text.replace("[lights]\nsky = { radiance = 1.0 }\n", "") + sky
        if not water:
            text = text.replace("water = {", "# {")
        path = write_scene(tmp_path, text + '[ground]\nbase = "soil"\nrules = []\n', f"{name}.toml")
        out = tmp_path / f"{name}.exr"
        r = run_forest("render", str(path), "-o", str(out), "-q", "--variant", variant)
        assert r.returncode == 0, r.stderr
        import OpenImageIO as oiio

        rows.append(oiio.ImageBuf(str(out)).get_pixels(oiio.FLOAT)[10:16, 8:16, :3].reshape(-1, 3).mean(axis=0))
    wet, dry = rows
    assert wet[2] / wet[0] > 2.0 * dry[2] / dry[0]


def test_bad_water_names_the_field(tmp_path):
    write_bowl(tmp_path)
    path = write_scene(tmp_path, BOWL.format(level=LEVEL, shore=0.5).replace(f"level = {LEVEL}, ", ""))
    r = run_forest("scatter", str(path), "-o", str(tmp_path / "t.npz"))
    assert r.returncode == 2 and "terrain.water.level" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "t.npz").exists()
    # A misspelt required key is named as the unknown key it is, not as the missing one.
    path = write_scene(tmp_path, BOWL.format(level=LEVEL, shore=0.5).replace("level =", "levle ="), "typo.toml")
    r = run_forest("scatter", str(path), "-o", str(tmp_path / "t.npz"))
    assert r.returncode == 2 and "terrain.water.levle: unknown key (expected one of: level, shore)" in r.stderr
    path = write_scene(tmp_path, BOWL.format(level=LEVEL, shore=-1.0), "neg.toml")
    r = run_forest("scatter", str(path), "-o", str(tmp_path / "t.npz"))
    assert r.returncode == 2 and "terrain.water.shore" in r.stderr


def test_the_exports_write_the_water_apart_from_the_terrain(tmp_path):
    """split_water: the triangles under the water leave the terrain for a water surface (flat at the level,
    the water's colour, its index and a roughness from the ripples); USD writes it as /World/Water with a glossy
    UsdPreviewSurface, RIB as a ``water`` block (a Fresnel PxrSurface in RenderMan 22+), and a ground without water
    is the terrain's own arrays."""
    from pxr import Usd, UsdGeom, UsdShade

    from forest.export.common import split_water
    from forest.export.rib import export_rib
    from forest.export.usd import export_usd

    config = bowl_config(tmp_path, extra="[ground]\nwater_ripple = 1.0\nwater_attenuation = [50.0, 50.0, 50.0]\n")
    scene = load_scene(config)
    ground, water = split_water(scene)
    assert water is not None
    terrain = scene.terrain
    assert len(ground.faces) + len(water.faces) == len(terrain.faces)
    np.testing.assert_allclose(water.vertices[water.faces].mean(axis=1)[:, 1], LEVEL, atol=0.05)
    assert float(np.mean(water.vertices[:, 1] == LEVEL)) > 0.9  # the shore's own vertices rise above it
    np.testing.assert_allclose(water.colour, GROUND_MATERIALS["water"], rtol=0.01)  # shore texels blend a little
    assert water.ior == pytest.approx(1.33) and water.roughness == pytest.approx(np.sqrt(np.tan(np.radians(1.0))))

    res = export_usd(scene, tmp_path / "out" / "forest.usda")
    stage = Usd.Stage.Open(str(res.path))
    wet = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Water"))
    dry = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Terrain"))
    assert len(wet.GetFaceVertexCountsAttr().Get()) == len(water.faces)
    assert len(dry.GetFaceVertexCountsAttr().Get()) == len(ground.faces)
    surface = UsdShade.Shader(stage.GetPrimAtPath("/World/Looks/Water/Surface"))
    assert surface.GetInput("ior").Get() == pytest.approx(1.33)
    assert surface.GetInput("roughness").Get() == pytest.approx(water.roughness)
    assert surface.GetInput("metallic").Get() == 0.0
    assert validation_errors(stage) == []

    rib = export_rib(scene, tmp_path / "rib").terrain.read_text()
    assert '["water"]' in rib and f"{len(water.faces)} triangles" in rib
    rib22 = export_rib(scene, tmp_path / "rib22", renderman22=True).terrain.read_text()
    assert '"PxrSurface" "water"' in rib22 and '"int specularFresnelMode" [1]' in rib22

    dry_config = load_config(write_scene(tmp_path, BOWL.format(level=LEVEL, shore=0.5).replace("water = {", "# {"),
                                         "dry.toml"))  # fmt: skip
    plain = load_scene(dry_config)
    ground, water = split_water(plain)
    assert water is None and ground.faces is plain.terrain.faces and ground.vertices is plain.terrain.vertices


@pytest.mark.skipif(shutil.which("blender") is None, reason="Blender is not installed")
def test_the_blend_holds_the_water(tmp_path):
    """Blender: a ``water`` object with the water's triangles, its material a Fresnel mix of gloss over diffuse."""
    from forest.export.blender import export_blender
    from forest.export.common import split_water

    scene = load_scene(bowl_config(tmp_path))
    _, water = split_water(scene)
    assert water is not None
    res = export_blender(scene, tmp_path / "s.blend")
    got = blender_probe(
        res.path,
        "import bpy, json, sys\n"
        "o = bpy.data.objects['water']\n"
        "nodes = o.data.materials[0].node_tree.nodes\n"
        "fresnel = [n for n in nodes if n.bl_idname == 'ShaderNodeFresnel'][0]\n"
        "gloss = [n for n in nodes if n.bl_idname == 'ShaderNodeBsdfGlossy'][0]\n"
        "out = {'faces': len(o.data.polygons), 'ior': fresnel.inputs['IOR'].default_value,\n"
        "       'roughness': gloss.inputs['Roughness'].default_value,\n"
        "       'terrain': len(bpy.data.objects['terrain'].data.polygons)}\n"
        "open(sys.argv[-1], 'w').write(json.dumps(out))\n",
        tmp_path,
    )
    assert got["faces"] == len(water.faces)
    assert got["terrain"] == len(scene.terrain.faces) - len(water.faces)
    assert got["ior"] == pytest.approx(1.33) and got["roughness"] == pytest.approx(water.roughness, rel=1e-5)
