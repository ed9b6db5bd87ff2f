"""Each tree's bark factor travels into every export: RIB (RI 3.2 and RenderMan 22+), USD and Blender.

Eight trees in two partitions: six grey bark stumps (``render_fixtures``' ``stump``, strong ``[[species]]
bark``) and two leaf boxes (no bark: factor 1).  The truth is :meth:`forest.scene.Scene.bark_tints`.  Per
exporter: the factor written for each tree is its row, read back from the files by the tree's id; the bark
material multiplies by it; with no bark variation no factor is written and the files are those the same scene
gives with its factors taken away; the same config and seed write the same bytes.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from pxr import Usd, UsdGeom, UsdShade
from test_bark import NONE, SCENE, STRONG
from test_render import trees

from forest.config import parse_config
from forest.export.blender import export_blender, write_manifest
from forest.export.rib import export_rib, shader_source
from forest.export.usd import export_usd
from forest.images import read_image, srgb_to_linear
from forest.scene import load_scene

import ribcheck
from export_support import validation_errors
from render_fixtures import BoxLibrary

needs_blender = pytest.mark.skipif(shutil.which("blender") is None, reason="Blender is not installed")

# test_bark's scene (seen from straight above, under a white sky, on a black ground; the Blender test renders it
# in Cycles) with these species.
SPECIES = """[[species]]
model = "stump"
percent = 75
bark = {bark}
[[species]]
model = "box"
percent = 25
"""
POSITIONS = [[x, 0.0, z] for z in (-6.0, 6.0) for x in (-15.0, -5.0, 5.0, 15.0)]
ROWS = [0, 1, 0, 0, 0, 0, 1, 0]  # the species of each tree: the boxes at (-5, -6) and (5, 6)
PARTITIONS = [0, 1, 1, 0, 1, 0, 0, 1]
BARK_NAMES = (b"barktint", b"barkTint", b"barkColor", b"bark_tint")
GREY = 0.4  # the stump's bark colour


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    return BoxLibrary(tmp_path_factory.mktemp("barklib"))


def bark_scene(tmp_path: Path, library: BoxLibrary, bark: str = STRONG):
    """The eight trees with the stumps' ``bark`` (an inline TOML table) as a Scene."""
    text = SCENE.format(head='name = "barkwood"', render="", species=SPECIES.format(bark=bark))
    cfg = parse_config(text, path=tmp_path / "scene.toml", base_dir=tmp_path)
    n = len(POSITIONS)
    inst = dataclasses.replace(
        trees(POSITIONS, names=("stump", "box"), scale=2.0),
        id=np.arange(40, 40 + 3 * n, 3),
        species=np.asarray(ROWS, np.uint16),
        partition=np.asarray(PARTITIONS, np.int16),
        partition_names=["a", "b"],
        extent=(-30.0, -30.0, 30.0, 30.0),
    )
    return load_scene(cfg, inst, library=library)


def by_id(scene, ids, values) -> np.ndarray:
    """``values`` (one per id in ``ids``) reordered into the InstanceSet's rows."""
    row = {int(i): k for k, i in enumerate(scene.instances.id)}
    out = np.full((len(scene.instances), 3), np.nan)
    for i, v in zip(ids, values):
        out[row[int(i)]] = v
    return out


def files(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` by its relative path."""
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def strong_factors(scene) -> np.ndarray:
    """The scene's bark factors, checked to be the test's: 1 for the boxes, far from 1 and varied for stumps."""
    f = scene.bark_tints()
    assert f is not None and f.shape == (8, 3)
    stumps = scene.instances.species == 0
    np.testing.assert_array_equal(f[~stumps], 1.0)
    assert np.ptp(f[stumps], axis=0).max() > 0.1
    return f


# ---------------------------------------------------------------------------------------------------------------
# RIB


def rib_barks(calls) -> tuple[list[int], list[list[float]]]:
    """Tree ids and their ``Attribute "user" "color barktint"`` of one instance file, in file order."""
    ids, values, tree = [], [], None
    for c in calls:
        if c.name == "Attribute" and c.args[0] == "identifier" and c.args[2][0].startswith("tree_"):
            tree = int(c.args[2][0][5:])
        elif c.name == "Attribute" and c.args[0] == "user":
            (decl, vals) = ribcheck.check_call(c)["barktint"]
            assert decl[:3] == ("uniform", "color", 1)
            ids.append(tree)
            values.append(vals)
    return ids, values


def params_of(call) -> dict:
    return {name: vals for name, (_decl, vals) in ribcheck.check_call(call).items()}


def test_rib_writes_each_trees_bark_factor(tmp_path, library):
    """Every tree block carries its own factor (7 decimals), read back by id; the RSL shader multiplies a bark
    part by it when the part's Surface says ``bark`` 1, and only the stump's bark part says so."""
    scene = bark_scene(tmp_path, library)
    f = strong_factors(scene)
    res = export_rib(scene, tmp_path / "out")
    calls = ribcheck.check_export(tmp_path / "out")  # also: Surface parameters are the shader source's own
    ids, values = [], []
    for path in res.instance_files.values():
        i, v = rib_barks(calls[path.name])
        ids += i
        values += v
    assert sorted(ids) == sorted(scene.instances.id.tolist())
    np.testing.assert_allclose(by_id(scene, ids, values), f, rtol=0, atol=5.1e-8)
    # (b) the materials: the stump's bark part multiplies, the box's leaves do not
    surfaces = {}
    for rel, cs in calls.items():
        if rel.startswith("archives/"):
            (surf,) = [c for c in cs if c.name == "Surface"]
            surfaces[rel] = params_of(surf)
    assert surfaces["archives/stump_high.rib"]["bark"] == [1.0]
    assert surfaces["archives/stump_high.rib"]["basecolour"] == [GREY] * 3
    assert "bark" not in surfaces["archives/box_high.rib"]
    kind, declared = ribcheck.shader_parameters(tmp_path / "out" / "shaders" / "forest_surface.sl")
    assert kind == "surface" and declared["bark"] == "float"
    sl = (tmp_path / "out" / "shaders" / "forest_surface.sl").read_text()
    assert sl == shader_source()
    assert 'attribute("user:barktint", f)' in sl and "albedo *= f;" in sl
    i = sl.index("if (bark != 0)")
    assert sl.index("color f = 1;", i) < sl.index('attribute("user:barktint", f)', i) < sl.index("albedo *= f;", i)


def test_renderman22_bark_networks_multiply_by_the_attribute(tmp_path, library):
    """RenderMan 22+: the stump's diffuse colour is base × PxrAttribute "user:barktint" (default 1) through a
    PxrBlend multiply; the trees carry the same factors as in RI 3.2 mode."""
    scene = bark_scene(tmp_path, library)
    f = strong_factors(scene)
    res = export_rib(scene, tmp_path / "r22", renderman22=True)
    calls = ribcheck.check_export(tmp_path / "r22")
    ids, values = [], []
    for path in res.instance_files.values():
        i, v = rib_barks(calls[path.name])
        ids += i
        values += v
    np.testing.assert_allclose(by_id(scene, ids, values), f, rtol=0, atol=5.1e-8)
    arch = calls["archives/stump_high.rib"]
    patterns = {c.args[1]: (c.args[0], params_of(c)) for c in arch if c.name == "Pattern"}
    (bxdf,) = [c for c in arch if c.name == "Bxdf"]
    blend_node, port = params_of(bxdf)["diffuseColor"][0].split(":")
    kind, blend = patterns[blend_node]
    assert kind == "PxrBlend" and port == "resultRGB" and blend["operation"] == [18.0]  # multiply
    assert blend["bottomRGB"] == [GREY] * 3
    attr_node, port = blend["topRGB"][0].split(":")
    kind, attr = patterns[attr_node]
    assert kind == "PxrAttribute" and port == "resultRGB"
    assert attr["varname"] == ["user:barktint"] and attr["type"] == ["color"] and attr["defaultFloat3"] == [1.0] * 3
    box = calls["archives/box_high.rib"]
    assert not [c for c in box if c.name == "Pattern" and c.args[0] == "PxrAttribute"]


# ---------------------------------------------------------------------------------------------------------------
# USD


def source_shader(inp):
    (src,) = inp.GetConnectedSources()[0]
    return UsdShade.Shader(src.source.GetPrim()), src.sourceName


def test_usd_writes_each_trees_bark_factor(tmp_path, library):
    """``primvars:forest:barkTint`` per instance is f_i (``forest:barkColor`` f_i × the bark colour); the
    stump's bark material reads the colour in UsdPreviewSurface and multiplies by the tint in MaterialX."""
    scene = bark_scene(tmp_path, library)
    f = strong_factors(scene)
    res = export_usd(scene, tmp_path / "out" / "forest.usda")
    stage = Usd.Stage.Open(str(res.path))
    assert validation_errors(stage) == []
    ids, tints, colours = [], [], []
    for path in res.instancers.values():
        pi = UsdGeom.PointInstancer(stage.GetPrimAtPath(path))
        pv = UsdGeom.PrimvarsAPI(pi)
        assert pv.GetPrimvar("forest:barkTint").GetInterpolation() == UsdGeom.Tokens.vertex
        ids += list(pi.GetIdsAttr().Get())
        tints += [tuple(v) for v in pv.GetPrimvar("forest:barkTint").Get()]
        colours += [tuple(v) for v in pv.GetPrimvar("forest:barkColor").Get()]
    assert sorted(ids) == sorted(scene.instances.id.tolist())
    np.testing.assert_array_equal(by_id(scene, ids, tints), f)
    bark_colour = np.where((scene.instances.species == 0)[:, None], GREY, 1.0)
    np.testing.assert_allclose(by_id(scene, ids, colours), f * bark_colour, rtol=1e-6)
    # (b) the stump's bark material, bound in the composed stage
    mesh = stage.GetPrimAtPath(f"{res.instancers['a']}/Prototypes/stump/Geom/bark0")
    mat, _ = UsdShade.MaterialBindingAPI(mesh).ComputeBoundMaterial()
    preview = mat.ComputeSurfaceSource()[0]
    reader, out = source_shader(preview.GetInput("diffuseColor"))
    assert reader.GetIdAttr().Get() == "UsdPrimvarReader_float3" and out == "result"
    assert reader.GetInput("varname").Get() == "forest:barkColor"
    np.testing.assert_allclose(reader.GetInput("fallback").Get(), [GREY] * 3, rtol=1e-6)
    (src,) = mat.GetSurfaceOutput("mtlx").GetConnectedSources()[0]
    mtlx = UsdShade.Shader(src.source.GetPrim())
    albedo, _ = source_shader(mtlx.GetInput("diffuseColor"))
    assert albedo.GetIdAttr().Get() == "ND_multiply_color3"
    np.testing.assert_allclose(albedo.GetInput("in2").Get(), [GREY] * 3, rtol=1e-6)
    tint, _ = source_shader(albedo.GetInput("in1"))
    assert tint.GetIdAttr().Get() == "ND_geompropvalue_color3"
    assert tint.GetInput("geomprop").Get() == "forest:barkTint" and tuple(tint.GetInput("default").Get()) == (1, 1, 1)


# ---------------------------------------------------------------------------------------------------------------
# Blender


def test_blender_manifest_writes_each_trees_bark_factor(tmp_path, library):
    """``points_bark_tint.bin`` holds f_i as RGBA (A = 1) in the points' order, the InstanceSet's; the stump's
    bark part is marked ``bark``, the box's leaves are not."""
    scene = bark_scene(tmp_path, library)
    f = strong_factors(scene)
    manifest = write_manifest(scene, tmp_path, [1])
    pts = manifest["points"]
    rgba = np.frombuffer((tmp_path / pts["bark_tint"]).read_bytes(), "<f4").reshape(pts["count"], 4)
    np.testing.assert_array_equal(rgba[:, :3], f)
    np.testing.assert_array_equal(rgba[:, 3], 1.0)
    parts = {(s["name"], p["kind"]): p for s in manifest["species"] for p in s["parts"]}
    assert parts[("stump", "bark")]["bark"] is True and "bark" not in parts[("box", "leaf")]


PROBE = """
import bpy, json, sys


def reaches(socket, idname, seen=()):
    # the node types along every path from an output socket to a node of type idname
    for link in socket.links:
        node = link.to_node
        if node.bl_idname == idname:
            return [[node.bl_idname]]
    paths = []
    for link in socket.links:
        node = link.to_node
        step = node.bl_idname + (":" + node.blend_type if node.bl_idname == "ShaderNodeMixRGB" else "")
        for out in node.outputs:
            paths += [[step] + p for p in reaches(out, idname)]
    return paths


mesh = bpy.data.objects["forest_points"].data
out = {"bark_tint": [list(a.color) for a in mesh.attributes["bark_tint"].data], "materials": {}}
for mat in bpy.data.materials:
    if mat.use_nodes:
        out["materials"][mat.name] = [
            [n.attribute_type, n.attribute_name, reaches(n.outputs["Color"], "ShaderNodeBsdfDiffuse")]
            for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeAttribute"
        ]
open(sys.argv[-1], "w").write(json.dumps(out))
"""


def tree_colours(image: np.ndarray, scene) -> np.ndarray:
    """Each tree's summed linear RGB over 7 × 7 pixels about its centre, seen from the scene's camera.

    The camera looks down −Y with up +Z: image right is world −X, image up +Z; the tops (4 m wide) are
    12 m up, where a pixel spans 2·388·tan(3°)/40 ≈ 1 m, and the trees stand 10 m apart on a black ground.
    """
    h, w = image.shape[:2]
    px = 2 * 388.0 * np.tan(np.radians(3.0)) / w
    out = []
    for x, _, z in scene.instances.position:
        c, r = int(w / 2 - x / px), int(h / 2 - z / px)
        out.append(image[r - 3 : r + 4, c - 3 : c + 4].reshape(-1, 3).sum(axis=0))
    return np.array(out)


@needs_blender
def test_blender_bark_material_multiplies_by_the_instance_attribute(tmp_path, library):
    """In the .blend the points carry ``bark_tint`` = f_i and the stump's bark material multiplies by the
    Instancer attribute on its way to the diffuse BSDF; in Cycles each stump shows its own factor's colour.

    Grey bark lit by a white sky through one bounce: every path's RGB is (grey × f_i) × a scalar, so a
    stump's rendered RGB ÷ f_i is grey, however its shading and noise fall.
    """
    scene = bark_scene(tmp_path, library)
    f = strong_factors(scene)
    res = export_blender(scene, tmp_path / "s.blend", render=tmp_path / "cycles.png")
    probe = tmp_path / "probe.py"
    probe.write_text(PROBE)
    cmd = ["blender", "-b", str(res.path), "--python-exit-code", "3", "--python", str(probe)]
    subprocess.run([*cmd, "--", str(tmp_path / "o.json")], check=True, capture_output=True)
    got = json.loads((tmp_path / "o.json").read_text())
    np.testing.assert_array_equal(np.array(got["bark_tint"])[:, :3], f)
    ((kind, name, paths),) = got["materials"]["stump_bark0"]
    assert (kind, name) == ("INSTANCER", "bark_tint")
    assert paths == [["ShaderNodeMixRGB:MULTIPLY", "ShaderNodeBsdfDiffuse"]]
    assert [a[1] for a in got["materials"]["box_leaf0"]] == ["tint"]
    stumps = scene.instances.species == 0
    rgb = tree_colours(srgb_to_linear(read_image(tmp_path / "cycles.png")[..., :3]), scene)[stumps]
    assert rgb.min() > 0.2 and (f[stumps].max(axis=1) / f[stumps].min(axis=1)).max() > 1.5  # far from grey
    grey = rgb / f[stumps]
    np.testing.assert_allclose(grey / grey.mean(axis=1, keepdims=True), 1.0, rtol=0.02)


# ---------------------------------------------------------------------------------------------------------------
# no variation, and determinism


def export_all(scene, out: Path) -> dict[str, bytes]:
    """Every exporter's files for ``scene`` under ``out`` (the Blender export's data files, not the .blend)."""
    export_rib(scene, out / "rib")
    export_rib(scene, out / "r22", renderman22=True)
    export_usd(scene, out / "usd" / "forest.usda")
    (out / "blender").mkdir()
    write_manifest(scene, out / "blender", [1])
    return files(out)


def test_no_bark_variation_writes_no_bark_factor(tmp_path, library, monkeypatch):
    """``bark`` all zero: no factor anywhere, and the files are byte for byte those of the strongly varied
    scene with its factors taken away — the factor is all that bark variation adds to an export."""
    plain = bark_scene(tmp_path, library, NONE)
    assert plain.bark_tints() is None
    got = export_all(plain, tmp_path / "plain")
    for rel, data in got.items():
        if not rel.endswith((".sl", ".png", ".tif")):
            assert not any(name in data for name in BARK_NAMES), rel
    assert b'"float bark"' not in got["rib/archives/stump_high.rib"]
    assert b"PxrAttribute" not in got["r22/archives/stump_high.rib"]
    assert "bark_tint" not in json.loads(got["blender/manifest.json"])["points"]
    strong = bark_scene(tmp_path, library)
    assert strong.bark_tints() is not None
    monkeypatch.setattr(type(strong), "bark_tints", lambda self: None)  # the same scene without its factors
    assert export_all(strong, tmp_path / "without") == got


def test_same_config_and_seed_give_the_same_bytes(tmp_path, library):
    """Two exports of the same scene, each from its own load, are byte-identical (bark factors included)."""
    a = export_all(bark_scene(tmp_path, library), tmp_path / "a")
    b = export_all(bark_scene(tmp_path, library), tmp_path / "b")
    assert a.keys() == b.keys() and b"barktint" in a["rib/instances_a.rib"]
    for rel in a:
        assert a[rel] == b[rel], rel
