"""RIB export with the look: textures, shaders, opacity, lights in each flavour's units, terrain colour,
wind, displays, re-exports, and the checker's cross-file rules."""

import math
from pathlib import Path

import numpy as np
import pytest
from conftest import write_png

from forest.camera import camera_at
from forest.config import ConfigError
from forest.errors import ParameterError
from forest.export import radiometry
from forest.export.rib import DOME_ORIENTATION, export_rib
from forest.images import read_image
from forest.lights import resolve_lights
from forest.scene import load_scene
from forest.wind import tree_matrices

import ribcheck
from export_support import FakeLibrary, fly_keys, make_config, make_instances

LOD = "\n[lod]\ndistances = [40.0, 120.0, 300.0]\n"


@pytest.fixture(scope="module")
def textured(tmp_path_factory):
    return FakeLibrary(textures=tmp_path_factory.mktemp("textures"))


def params_of(call) -> dict:
    return {decl[3]: vals for decl, vals in ((d, v) for d, v in ribcheck.check_call(call).values())}


def test_archives_reference_existing_textures_and_shaders(tmp_path, textured):
    res = export_rib(load_scene(make_config(tmp_path, LOD), make_instances(200), library=textured), tmp_path / "out")
    calls = ribcheck.check_export(tmp_path / "out")  # references, shader parameters, object scope, bounds
    assert (tmp_path / "out" / "shaders" / "forest_surface.sl").is_file()
    kind, declared = ribcheck.shader_parameters(tmp_path / "out" / "shaders" / "forest_surface.sl")
    assert kind == "surface" and declared["texturename"] == "string" and declared["basecolour"] == "color"
    leaves = 0
    for path in res.archives:
        for c in calls[path.relative_to(tmp_path / "out").as_posix()]:
            if c.name == "Surface":
                assert c.args[0] == "forest_surface"
                p = params_of(c)
                if "texturename" in p:  # the leaf parts: tinted by Cs and cut by the texture's alpha
                    leaves += 1
                    assert (tmp_path / "out" / p["texturename"][0]).is_file()
                    assert p["tinted"] == [1.0] and p["translucency"] == [pytest.approx(0.3)]
    assert leaves == len(res.archives)
    # prepare.sh compiles the shader with whichever RenderMan family is installed
    script = (tmp_path / "out" / "prepare.sh").read_text()
    assert "(cd shaders && $SL forest_surface.sl)" in script and "aqsl" in script and "txmake" in script


def test_textures_keep_the_library_pixels_and_alpha(tmp_path, textured):
    res = export_rib(load_scene(make_config(tmp_path, ""), make_instances(50), library=textured), tmp_path / "out")
    (tif,) = res.textures
    src = textured.resolve("oak").lods[0].parts[1].texture
    a = np.round(read_image(tif, unassociated=True) * 255)
    b = np.round(read_image(src, unassociated=True) * 255)
    assert a.shape == b.shape == (16, 16, 4)
    np.testing.assert_array_equal(a, b)  # the same 8-bit sRGB RGB and the same alpha
    # the shader's opacity is the texture's fourth channel, its colour the decoded RGB
    sl = (tmp_path / "out" / "shaders" / "forest_surface.sl").read_text()
    assert "alpha = float texture(texturename[3], s, t" in sl and "Oi = Os * alpha;" in sl


def test_renderman22_presence_follows_the_alpha(tmp_path, textured):
    cfg = make_config(tmp_path, LOD)
    export_rib(load_scene(cfg, make_instances(100), library=textured), tmp_path / "r22", renderman22=True)
    calls = ribcheck.check_export(tmp_path / "r22")
    arch = calls["archives/oak_high.rib"]
    tex = {c.args[1]: params_of(c) for c in arch if c.name == "Pattern" and c.args[0] == "PxrTexture"}
    (leaf,) = [c for c in arch if c.name == "Bxdf" and "reference float presence" in c.args]
    p = params_of(leaf)
    node, out = p["presence"][0].split(":")
    assert out == "resultA" and tex[node]["filename"][0].endswith(".tex")
    assert (tmp_path / "r22" / tex[node]["filename"][0]).with_suffix(".tif").is_file()
    assert tex[node]["linearize"] == [1.0] and tex[node]["invertT"] == [0.0]
    assert p["diffuseDoubleSided"] == [1.0]
    # the diffuse colour is texture × base × Cs, through PxrPrimvar "Cs"
    blends = {c.args[1]: params_of(c) for c in arch if c.name == "Pattern" and c.args[0] == "PxrBlend"}
    top = blends[p["diffuseColor"][0].split(":")[0]]
    cs_node = top["topRGB"][0].split(":")[0]
    prim = next(params_of(c) for c in arch if c.name == "Pattern" and c.args[1] == cs_node)
    assert prim["varname"] == ["Cs"]
    assert blends[top["bottomRGB"][0].split(":")[0]]["topRGB"] == [f"{node}:resultRGB"]
    i = arch.index(leaf)
    assert any(c.name == "Sides" and c.args[0] == 2 for c in arch[max(0, i - 8) : i])
    assert "$TX" in (tmp_path / "r22" / "prepare.sh").read_text()


def test_radiometry_matches_the_lambertian_integral():
    """E from a disk of radiance L and angular diameter α, integrated over the cone: L·π·sin²(α/2)."""
    E = 3.0
    for alpha in (0.53, 5.0, 40.0):
        L = radiometry.disk_radiance(E, alpha)
        half = math.radians(alpha) / 2
        theta = np.linspace(0, half, 200001)
        integrand = np.cos(theta) * np.sin(theta) * 2 * np.pi  # ∫ cos θ dω over the cone
        assert L * np.trapezoid(integrand, theta) == pytest.approx(E, rel=1e-6)
        assert radiometry.disk_irradiance(L, alpha) == pytest.approx(E, rel=1e-12)
    assert radiometry.disk_radiance(E) == pytest.approx(44650, rel=1e-3)  # RenderMan's default is 50 000
    # RSL diffuse() has no 1/π: a·(E/π)·cos θ is the Lambertian a/π·E·cos θ
    assert radiometry.distantlight_intensity(E) * math.pi == pytest.approx(E)


def test_lights_in_each_flavour(tmp_path, textured):
    cfg = make_config(tmp_path, "")
    scene = load_scene(cfg, make_instances(20), library=textured)
    E, L = cfg.lights.sun.irradiance, cfg.lights.sky.radiance
    export_rib(scene, tmp_path / "ri")
    calls = ribcheck.parse((tmp_path / "ri" / "scene_0001.rib").read_bytes())
    sun = next(c for c in calls if c.name == "LightSource" and c.args[0] == "distantlight")
    sky = next(c for c in calls if c.name == "LightSource" and c.args[0] == "ambientlight")
    assert params_of(sun)["intensity"][0] == pytest.approx(E / math.pi, rel=1e-8)
    assert params_of(sky)["intensity"][0] == pytest.approx(L, rel=1e-8)
    export_rib(scene, tmp_path / "r22", renderman22=True)
    calls = ribcheck.parse((tmp_path / "r22" / "scene_0001.rib").read_bytes())
    lights = {c.args[0]: c for c in calls if c.name == "Light"}
    p = params_of(lights["PxrDistantLight"])
    a = math.radians(p["angleExtent"][0]) / 2
    assert p["intensity"][0] * math.pi * math.sin(a) ** 2 == pytest.approx(E, rel=1e-6)
    assert p["exposure"] == [0.0]
    d = params_of(lights["PxrDomeLight"])
    assert d["intensity"][0] * np.array(d["lightColor"]) == pytest.approx(L * np.array(cfg.lights.sky.colour))
    i = calls.index(lights["PxrDomeLight"])
    R = np.array(next(c for c in reversed(calls[:i]) if c.name == "ConcatTransform").args[0]).reshape(4, 4).T
    np.testing.assert_allclose(R, DOME_ORIENTATION)
    np.testing.assert_allclose(R[:3, :3] @ [0, 0, 1], [0, 1, 0], atol=1e-12)  # the dome's pole is world +Y
    i = calls.index(lights["PxrDistantLight"])
    R = np.array(next(c for c in reversed(calls[:i]) if c.name == "ConcatTransform").args[0]).reshape(4, 4).T
    np.testing.assert_allclose(R[:3, 2], -resolve_lights(cfg).sun.direction, atol=1e-8)


def test_terrain_takes_the_grounds_albedo(tmp_path, textured):
    """The terrain texture is the renderers' ground: ``[ground]`` rules painted from a map."""
    rng = np.random.default_rng(4)
    write_png(tmp_path / "wet.png", rng.uniform(0.0, 1.0, (8, 12, 3)))
    ground = '\n[ground]\nbase = "soil"\n[[ground.rules]]\nmaterial = "grass"\nmap = "wet.png"\n'
    scene = load_scene(make_config(tmp_path, ground, ground_material=False), make_instances(30), library=textured)
    export_rib(scene, tmp_path / "out")
    calls = ribcheck.check_export(tmp_path / "out")
    surf = next(c for c in calls["terrain.rib"] if c.name == "Surface")
    assert params_of(surf)["texturename"] == ["textures/terrain.tif"] and params_of(surf)["tinted"] == [0.0]
    from forest.images import srgb_to_linear

    got = srgb_to_linear(read_image(tmp_path / "out" / "textures" / "terrain.tif"))
    want = scene.terrain_albedo.rgb
    assert want.shape[0] * want.shape[1] > 1 and np.ptp(want) > 0.05
    np.testing.assert_allclose(got, want, atol=0.004)  # 8-bit sRGB steps
    # st of the terrain are its map coordinates: row 0 of the texture at the smallest z
    (mesh,) = ribcheck.points_polygons(calls["terrain.rib"])
    v0 = int(np.argmin(mesh["P"][:, 2]))
    assert mesh["st"][v0, 1] == pytest.approx(0.0, abs=1e-6)


def test_displays(tmp_path, textured):
    scene = load_scene(make_config(tmp_path, ""), make_instances(10), library=textured)
    export_rib(scene, tmp_path / "a")
    disp = next(c for c in ribcheck.parse((tmp_path / "a" / "scene_0001.rib").read_bytes()) if c.name == "Display")
    assert disp.args[:3] == ["testwood_0001.tif", "file", "rgba"]  # the driver every renderer has
    export_rib(scene, tmp_path / "b", display="openexr")
    disp = next(c for c in ribcheck.parse((tmp_path / "b" / "scene_0001.rib").read_bytes()) if c.name == "Display")
    assert disp.args[:2] == ["testwood_0001.exr", "openexr"]
    with pytest.raises(ParameterError, match=r"display: unknown display 'nuke'; use one of file, tiff"):
        export_rib(scene, tmp_path / "c", display="nuke")
    with pytest.raises(ConfigError, match=r"scene\.toml: export\.rib_display"):
        make_config(tmp_path, '[export]\nrib_display = "nuke"\n')
    assert not (tmp_path / "c").exists()


def test_wind_sways_trees_per_frame(tmp_path, textured):
    cfg = make_config(tmp_path, "\n[wind]\nstrength = 8.0\nfrequency = 0.5\ndirection = 30.0\n")
    inst = make_instances(120)
    res = export_rib(load_scene(cfg, inst, library=textured), tmp_path / "out", frames="1-3")
    ribcheck.check_export(tmp_path / "out")
    by_id = {int(i): k for k, i in enumerate(inst.id)}
    mats = {}
    for f in (1, 2, 3):
        files = res.frame_instance_files[f]
        assert [p.name for p in files] == [f"instances_north_{f:04d}.rib", f"instances_south_{f:04d}.rib"]
        calls = ribcheck.parse((tmp_path / "out" / f"scene_{f:04d}.rib").read_bytes())
        assert [c.args[0] for c in calls if c.name == "ReadArchive"][2:] == [p.name for p in files]
        want = tree_matrices(inst, f / cfg.camera.fps, cfg.wind)
        for p in files:
            for t in ribcheck.read_trees(ribcheck.parse(p.read_bytes())):
                k = by_id[int(t["name"][5:])]
                np.testing.assert_allclose(t["matrix"], want[k], atol=2e-6)
                mats[(f, k)] = t["matrix"]
    k = next(iter(by_id.values()))
    assert not np.allclose(mats[(1, k)], mats[(2, k)], atol=1e-4)  # the trees move


def test_lod_areas_use_each_frames_fov(tmp_path, textured):
    cfg = make_config(tmp_path, LOD + fly_keys(last_frame=3))
    res = export_rib(load_scene(cfg, make_instances(200), library=textured), tmp_path / "out")
    for f in (1, 3):
        fov = camera_at(cfg.camera, f).fov
        path = next(p for p in res.frame_instance_files[f] if "north" in p.name)
        t = next(t for t in ribcheck.read_trees(ribcheck.parse(path.read_bytes())) if len(t["archives"]) == 4)
        d = t["detail"]
        area = (d[3] - d[2]) * max(d[1] - d[0], d[5] - d[4])
        focal = (cfg.render.width / 2) / math.tan(math.radians(fov) / 2)
        assert t["ranges"][0][0] == pytest.approx(area * (focal / (40.0 * 1.1)) ** 2, rel=1e-5)
    assert camera_at(cfg.camera, 1).fov != camera_at(cfg.camera, 3).fov


def test_trees_keep_their_identifiers(tmp_path, textured):
    cfg = make_config(tmp_path, LOD + '[export]\nrib_lod = "archive"\n')
    export_rib(load_scene(cfg, make_instances(60), library=textured), tmp_path / "out")
    calls = ribcheck.check_export(tmp_path / "out")
    for p in (tmp_path / "out").rglob("*.rib"):
        p.read_bytes().decode("ascii")  # RIB text is ASCII, comments included
    for rel, cs in calls.items():
        if rel.startswith(("archives/", "objects")):
            assert not [c for c in cs if c.name == "Attribute" and c.args[0] == "identifier"], rel


def test_reexport_removes_stale_files(tmp_path, textured):
    cfg = make_config(tmp_path, "\n[wind]\nstrength = 5.0\n")
    out = tmp_path / "out"
    export_rib(load_scene(cfg, make_instances(80), library=textured), out, frames="1-4")
    (out / "testwood_0001.tif").write_bytes(b"a render")  # the user's own files stay
    (out / "notes.txt").write_text("keep")
    first = {p.relative_to(out) for p in out.rglob("*") if p.is_file()}
    inst = make_instances(80, partitions=("north", "south", "east"), empty_partition="south")
    res = export_rib(load_scene(make_config(tmp_path, ""), inst, library=FakeLibrary()), out, frames="2")
    now = {p.relative_to(out) for p in out.rglob("*") if p.is_file()}
    assert {Path("testwood_0001.tif"), Path("notes.txt")} <= now
    written = {p.relative_to(out) for p in res.files + res.shaders + res.textures + [res.prepare]}
    assert now == written | {Path("testwood_0001.tif"), Path("notes.txt")}
    assert not (out / "textures").exists() and not list(out.glob("instances_north_*"))
    assert first - now  # the earlier frames' scenes and instance files are gone
    ribcheck.check_export(out)


def test_checker_rejects_what_a_renderer_would(tmp_path, textured):
    export_rib(load_scene(make_config(tmp_path, LOD), make_instances(40), library=textured), tmp_path / "out")
    out = tmp_path / "out"
    ribcheck.check_export(out)

    def broken(rel, old, new, match):
        path = out / rel
        keep = path.read_bytes()
        path.write_bytes(keep.replace(old, new, 1))
        with pytest.raises(ribcheck.RibError, match=match):
            ribcheck.check_export(out)
        path.write_bytes(keep)

    arch = next(p.name for p in (out / "archives").iterdir() if p.name.startswith("oak_high"))
    inst = (out / "instances_north.rib").read_bytes()
    bound = inst[inst.index(b'DelayedReadArchive" ["archives/oak_high') :].split(b"[", 2)[2].split(b"]")[0]
    smaller = b" ".join(str(float(v) * 0.5).encode() for v in bound.split())
    broken("instances_north.rib", bound, smaller, "does not contain")
    broken(f"archives/{arch}", b"ObjectInstance 1\n", b"ObjectInstance 999\n", "not defined before")
    broken(f"archives/{arch}", b'"string texturename" ["textures/', b'"string texturename" ["nowhere/', "missing")
    broken(f"archives/{arch}", b'"float tinted"', b'"float tainted"', "has no parameter 'tainted'")
    broken(f"archives/{arch}", b'"color basecolour"', b'"float basecolour"', "basecolour")
    broken("objects.rib", b"ObjectEnd", b'Surface "plastic"\nObjectEnd', "only geometric primitives")
