"""The fitted look (``[lookdev] leaf_tint`` and ``ground_tint``, written by ``forest match``) reaches every backend:
the Scene resolves it once, and forest_path, the scalar renderer, RIB, USD, Blender and points write the same
numbers — a fitted scene no longer loses its look outside forest_path."""

import dataclasses
import json

import numpy as np
import pytest
from pxr import Usd, UsdGeom

from forest.config import parse_config
from forest.scene import load_scene

import ribcheck
from export_support import FakeLibrary, make_config, make_instances

OAK = (1.3, 0.7, 0.5)
GROUND = (0.6, 0.9, 1.4)
LOOK = f"\n[lookdev]\nground_tint = {list(GROUND)}\n[lookdev.leaf_tint]\noak = {list(OAK)}\n"


@pytest.fixture(scope="module")
def lib():
    return FakeLibrary()


@pytest.fixture(scope="module")
def scenes(tmp_path_factory, lib):
    """(plain Scene, fitted Scene): the same trees, the fitted one with an oak leaf tint and a ground tint."""
    tmp = tmp_path_factory.mktemp("look")
    inst = make_instances(300)
    plain = load_scene(make_config(tmp), inst, library=lib)
    fitted = load_scene(make_config(tmp, LOOK, name="fitted.toml"), inst, library=lib)
    return plain, fitted


def expected_factor(scene) -> np.ndarray:
    """(N, 3): the leaf tint each tree should carry — OAK for oaks, 1 for pines."""
    names = [str(n) for n in scene.instances.species_names]
    per_species = np.array([OAK if n == "oak" else (1.0, 1.0, 1.0) for n in names])
    return per_species[scene.instances.species]


def test_the_scene_resolves_the_look_once(scenes):
    plain, fitted = scenes
    np.testing.assert_array_equal(plain.tree_tints(), plain.instances.tint)  # nothing fitted: the column itself
    np.testing.assert_array_equal(plain.ground_tint, np.ones(3))
    np.testing.assert_allclose(fitted.ground_tint, GROUND)
    np.testing.assert_allclose(fitted.tree_tints(), fitted.instances.tint * expected_factor(fitted), rtol=1e-6)
    names = [str(n) for n in fitted.instances.species_names]
    np.testing.assert_allclose(fitted.leaf_tint[names.index("oak")], OAK)
    np.testing.assert_allclose(fitted.leaf_tint[names.index("pine")], 1.0)


def test_a_species_without_leaves_keeps_its_colour(tmp_path, lib):
    """A tint keyed to a species with no leaf part (a building's surfaces) changes nothing: forest_path would not
    apply it either."""
    from forest.scene import leaf_tint

    cfg = make_config(tmp_path, LOOK)
    sp = load_scene(cfg, make_instances(50), library=lib).species
    bare = [dataclasses.replace(s, lods=[dataclasses.replace(l, parts=l.parts[:1]) for l in s.lods]) for s in sp]
    assert all(p.kind != "leaf" for s in bare for l in s.lods for p in l.parts)
    np.testing.assert_array_equal(leaf_tint(cfg, tuple(bare)), 1.0)


def test_forest_path_gets_the_scene_tints(scenes):
    from forest.render.path.from_scene import path_inputs

    _plain, fitted = scenes
    inputs = path_inputs(fitted, width=32, height=18, spp=1)
    leaf, ground = inputs.tints()
    np.testing.assert_allclose(leaf, fitted.leaf_tint)
    np.testing.assert_allclose(ground, GROUND)


def test_the_scalar_renderer_tints_the_leaves_and_the_ground(scenes):
    """scalar_rgb builds each species' leaf BSDF with its colour × the leaf tint, and the terrain's × the ground
    tint (before: both dropped)."""
    from forest.render.instancing import ForestBuilder
    from forest.render.materials import MaterialBuilder
    from forest.render.scene import terrain_reflectance

    plain, fitted = scenes
    names = [str(n) for n in fitted.instances.species_names]
    oak = names.index("oak")
    leaf_part = next(p for p in fitted.species[oak].lods[0].parts if p.kind == "leaf")
    seen = {}
    for label, scene in (("plain", plain), ("fitted", fitted)):
        mats = MaterialBuilder("scalar_rgb", None, scene.terrain.extent, scene.terrain.height_range)
        builder = ForestBuilder(scene, mats)
        ref = builder._bsdf_ref(leaf_part, oak)
        seen[label] = builder._bsdfs[ref["id"]]
    colour = {k: np.array(_rgb_of(v)) for k, v in seen.items()}
    np.testing.assert_allclose(colour["fitted"] / colour["plain"], OAK, rtol=1e-5)
    base = terrain_reflectance(plain.terrain_albedo, plain.terrain, "scalar_rgb")
    tinted = terrain_reflectance(fitted.terrain_albedo, fitted.terrain, "scalar_rgb", tint=fitted.ground_tint)
    np.testing.assert_allclose(np.array(tinted["value"]) / np.array(base["value"]), GROUND, rtol=1e-5)


def _rgb_of(bsdf: dict) -> list[float]:
    """The constant RGB inside a (possibly masked, two-sided or leaf) BSDF dict."""
    for key in ("reflectance", "base_color", "material"):
        if key in bsdf:
            inner = bsdf[key]
            return inner["value"] if inner.get("type") == "rgb" else _rgb_of(inner)
    raise AssertionError(f"no constant colour in {bsdf}")


def test_rib_writes_the_fitted_tree_colours_and_ground(scenes, tmp_path):
    from forest.export.rib import export_rib

    plain, fitted = scenes
    colours = {}
    for label, scene in (("plain", plain), ("fitted", fitted)):
        res = export_rib(scene, tmp_path / label)
        by_id = {}
        for path in res.instance_files.values():
            for t in ribcheck.read_trees(ribcheck.parse(path.read_bytes())):
                by_id[int(t["name"][5:])] = np.asarray(t["color"], np.float64)
        colours[label] = np.array([by_id[int(i)] for i in scene.instances.id])
    np.testing.assert_allclose(colours["fitted"], fitted.instances.tint * expected_factor(fitted), atol=2e-6)
    np.testing.assert_allclose(colours["plain"], plain.instances.tint, atol=1e-7)


def test_usd_writes_the_fitted_tree_colours(scenes, tmp_path, lib):
    from forest.export.usd import export_usd

    _plain, fitted = scenes
    res = export_usd(fitted, tmp_path / "scene.usda")
    stage = Usd.Stage.Open(str(res.path))
    inst = fitted.instances
    factor = expected_factor(fitted)
    leaf = np.array([lib.resolve(n).lods[0].parts[1].colour for n in inst.species_names], np.float64)
    for path in res.instancers.values():
        pi = UsdGeom.PointInstancer(stage.GetPrimAtPath(path))
        rows = np.searchsorted(inst.id, np.array(pi.GetIdsAttr().Get()).astype(np.uint64))
        tint = np.array(UsdGeom.PrimvarsAPI(pi).GetPrimvar("forest:tint").Get(), np.float64)
        np.testing.assert_allclose(tint, inst.tint[rows] * factor[rows], rtol=1e-6)
        colour = np.array(UsdGeom.PrimvarsAPI(pi).GetPrimvar("displayColor").Get(), np.float64)
        np.testing.assert_allclose(colour, inst.tint[rows] * factor[rows] * leaf[inst.species[rows]], rtol=1e-5)


def test_blender_and_points_write_the_fitted_look(scenes, tmp_path):
    from forest.export.blender import write_manifest
    from forest.export.points import export_points

    _plain, fitted = scenes
    inst = fitted.instances
    write_manifest(fitted, tmp_path, [1])
    tint = np.fromfile(tmp_path / "points_tint.bin", "<f4").reshape(-1, 4)[:, :3]
    np.testing.assert_allclose(tint, inst.tint * expected_factor(fitted), rtol=1e-6)
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    from forest.export.common import ground_colour

    want = np.asarray(fitted.config.render.terrain_colour, np.float64) * np.asarray(GROUND)
    np.testing.assert_allclose(ground_colour(fitted), want, rtol=1e-6)
    np.testing.assert_allclose(manifest["terrain"]["colour"], want, rtol=1e-6)
    export_points(fitted, tmp_path / "points.csv")
    rows = np.genfromtxt(tmp_path / "points.csv", delimiter=",", names=True)
    cd = np.stack([rows[c] for c in rows.dtype.names if c.lower().startswith("cd")], axis=1)
    assert cd.shape == (len(inst), 3)
    np.testing.assert_allclose(cd, inst.tint * expected_factor(fitted), atol=1e-5)


def test_a_grid_ground_is_tinted_in_every_export(tmp_path, lib):
    """With the ground as an albedo grid (the [ground] rules), the texture every exporter writes is the
    renderers' grid × the ground tint."""
    from forest.export.common import terrain_texture

    inst = make_instances(40)
    plain = load_scene(make_config(tmp_path, ground_material=False), inst, library=lib)
    cfg = parse_config(
        make_config(tmp_path, LOOK, name="g.toml", ground_material=False).path.read_text(), path=tmp_path / "g.toml"
    )
    fitted = load_scene(cfg, inst, library=lib)
    a, b = terrain_texture(plain), terrain_texture(fitted)
    assert a is not None and b is not None
    np.testing.assert_allclose(b, a * np.asarray(GROUND, np.float32), rtol=1e-6)


#: The test scene's lights, and as ``forest match`` writes them back (fitted sun irradiance and colour, sky radiance
#: and colour).
PLAIN_LIGHTS = "[lights.sun]\nelevation = 40.0\nazimuth = 135.0\nirradiance = 3.0\n[lights.sky]\nradiance = 0.4\n"
FITTED_LIGHTS = (
    "[lights.sun]\nelevation = 41.0\nazimuth = 205.0\nirradiance = 4.3\ncolour = [1.0, 0.88, 0.74]\n"
    "[lights.sky]\nradiance = 0.42\ncolour = [0.52, 0.64, 0.95]\n"
)


def _rib_lights(text: str) -> dict[str, dict]:
    """``LightSource`` calls of RIB text by shader name: their parameters as name → value list."""
    out = {}
    for call in ribcheck.parse(text.encode()):
        if call.name == "LightSource":
            args = call.args
            out[args[0]] = {args[i]: args[i + 1] for i in range(2, len(args) - 1, 2)}
    return out


def test_the_fitted_sun_and_sky_reach_every_backend_as_numbers(tmp_path, lib):
    """The fitted light values, through Scene.lights, in the scalar renderer's emitters, forest_path's lights, the
    RIB light sources, the USD lights and the Blender manifest, each in its target's units
    (:mod:`forest.export.radiometry`)."""
    from forest.export import radiometry
    from forest.export.blender import write_manifest
    from forest.export.rib import lights_text
    from forest.export.usd import _lights
    from forest.render.path.from_scene import path_lights
    from forest.render.scene import emitter_dicts

    from export_support import SCENE

    assert PLAIN_LIGHTS in SCENE
    path = tmp_path / "lit.toml"
    path.write_text(SCENE.replace(PLAIN_LIGHTS, FITTED_LIGHTS) + "terrain_colour = [0.2, 0.18, 0.12]\n" + LOOK)
    scene = load_scene(parse_config(path.read_text(), path=path), make_instances(20), library=lib)
    e_sun = 4.3 * np.array([1.0, 0.88, 0.74])
    l_sky = 0.42 * np.array([0.52, 0.64, 0.95])
    d = scene.lights.sun.direction
    # scalar_rgb (a point sun here) and forest_path
    em = emitter_dicts(scene.config, "scalar_rgb")
    np.testing.assert_allclose(em["sun"]["irradiance"]["value"], e_sun, rtol=1e-9)
    np.testing.assert_allclose(em["sun"]["direction"], -d, atol=1e-12)
    np.testing.assert_allclose(em["sky"]["radiance"]["value"], l_sky, rtol=1e-9)
    sun, sky = path_lights(scene.lights)
    np.testing.assert_allclose(sun.irradiance, e_sun, rtol=1e-9)
    np.testing.assert_allclose(sky.radiance, l_sky, rtol=1e-9)
    # RIB, RI 3.2: distantlight intensity E/π with the colour, ambientlight intensity L with the colour
    calls = _rib_lights(lights_text(scene.config, renderman22=False))
    sun_rib = calls["distantlight"]
    assert sun_rib["intensity"][0] == pytest.approx(radiometry.distantlight_intensity(4.3), rel=1e-5)
    np.testing.assert_allclose(sun_rib["lightcolor"], [1.0, 0.88, 0.74], rtol=1e-5)
    np.testing.assert_allclose(sun_rib["from"], d, atol=1e-5)
    sky_rib = calls["ambientlight"]
    assert sky_rib["intensity"][0] == pytest.approx(radiometry.ambient_intensity(0.42), rel=1e-5)
    np.testing.assert_allclose(sky_rib["lightcolor"], [0.52, 0.64, 0.95], rtol=1e-5)
    # USD: DistantLight intensity = the sun disc's radiance, DomeLight intensity = L, colours as given
    stage = Usd.Stage.CreateInMemory()
    _lights(stage, scene.config, tmp_path)
    us, uk = stage.GetPrimAtPath("/World/Lights/Sun"), stage.GetPrimAtPath("/World/Lights/Sky")
    assert us.GetAttribute("inputs:intensity").Get() == pytest.approx(radiometry.disk_radiance(4.3), rel=1e-6)
    np.testing.assert_allclose(us.GetAttribute("inputs:color").Get(), [1.0, 0.88, 0.74], rtol=1e-6)
    assert uk.GetAttribute("inputs:intensity").Get() == pytest.approx(0.42, rel=1e-6)
    np.testing.assert_allclose(uk.GetAttribute("inputs:color").Get(), [0.52, 0.64, 0.95], rtol=1e-6)
    # Blender: sun strength E (W/m²), world strength L with the colour
    manifest = write_manifest(scene, tmp_path, [1])
    assert manifest["sun"]["strength"] == pytest.approx(radiometry.blender_sun_strength(4.3), rel=1e-9)
    np.testing.assert_allclose(manifest["sun"]["colour"], [1.0, 0.88, 0.74], rtol=1e-9)
    assert manifest["sky"]["strength"] == pytest.approx(0.42, rel=1e-9)
    np.testing.assert_allclose(manifest["sky"]["colour"], [0.52, 0.64, 0.95], rtol=1e-9)
