"""The hills past the terrain's edge (``[render] horizon_hills``) reach the RIB, USD and Blender exports.

The truth is what forest's own renderers build (:func:`forest.skirt.skirt_mesh` with the config's hills, out
to :func:`forest.skirt.skirt_radius`) and the far colour the Scene computed
(:func:`forest.skirt.far_colour`): each export must carry that mesh, vertex for vertex, in that colour, and
nothing more when no hills are asked for.
"""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from pxr import Usd, UsdGeom

from forest.export.blender import Y_UP_TO_Z_UP, export_blender, write_manifest
from forest.export.common import horizon
from forest.export.rib import export_rib, nums
from forest.export.usd import export_usd
from forest.scene import load_scene
from forest.skirt import far_colour, hills, skirt_mesh, skirt_radius

import ribcheck
from export_support import FakeLibrary, blender_probe, make_config, make_instances, validation_errors

HILLS = "horizon_hills = { height = 120.0, scale = 600.0 }\n"


@pytest.fixture(scope="module")
def lib():
    return FakeLibrary()


def _scene(tmp_path, lib, extra: str = HILLS, ground_material: bool = True):
    cfg = make_config(tmp_path, extra, ground_material=ground_material)
    return load_scene(cfg, make_instances(60), library=lib)


def test_the_horizon_is_the_renderers_skirt_in_the_far_colour(tmp_path, lib):
    scene = _scene(tmp_path, lib, ground_material=False)
    far = horizon(scene)
    assert far is not None
    sk = skirt_mesh(scene.terrain, skirt_radius(scene.terrain.extent, scene.config.camera.far), hills(scene.config))
    assert sk is not None
    np.testing.assert_array_equal(far.vertices, sk.vertices)
    np.testing.assert_array_equal(far.faces, sk.faces)
    np.testing.assert_allclose(far.colour, far_colour(scene.terrain_albedo), rtol=1e-6)
    assert np.ptp(far.vertices[:, 1]) > 50.0  # hills, not a level plain
    assert far.uv.shape == (len(far.vertices), 2) and np.abs(far.uv).max() > 1.0  # past the terrain's map
    assert horizon(_scene(tmp_path, lib, extra="")) is None  # no hills: the exports write the terrain alone


def test_rib_writes_the_hills_after_the_terrain(tmp_path, lib):
    scene = _scene(tmp_path, lib)
    far = horizon(scene)
    assert far is not None
    res = export_rib(scene, tmp_path / "rib")
    calls = ribcheck.check_export(tmp_path / "rib")  # every file passes the RI 3.2 checker
    assert "terrain.rib" in calls
    text = res.terrain.read_text()
    assert text.count("PointsPolygons") == 2 and '["horizon"]' in text
    block = text[text.index('["horizon"]') :]
    assert f"Color [{nums(far.colour)}]" in block  # the far colour, not the terrain's
    assert f"{len(far.vertices)} vertices, {len(far.faces)} triangles" in text
    plain = export_rib(_scene(tmp_path, lib, extra=""), tmp_path / "plain")
    assert plain.terrain.read_text().count("PointsPolygons") == 1


def test_usd_has_a_horizon_prim_with_the_mesh_and_colour(tmp_path, lib):
    scene = _scene(tmp_path, lib)
    far = horizon(scene)
    assert far is not None
    res = export_usd(scene, tmp_path / "out" / "forest.usda")
    stage = Usd.Stage.Open(str(res.path))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Horizon"))
    assert mesh
    np.testing.assert_allclose(np.array(mesh.GetPointsAttr().Get()), far.vertices, rtol=1e-6)
    assert len(mesh.GetFaceVertexCountsAttr().Get()) == len(far.faces)
    np.testing.assert_allclose(np.array(mesh.GetDisplayColorPrimvar().Get()[0]), far.colour, rtol=1e-6)
    assert validation_errors(stage) == []
    plain = export_usd(_scene(tmp_path, lib, extra=""), tmp_path / "plain" / "forest.usda")
    assert not Usd.Stage.Open(str(plain.path)).GetPrimAtPath("/World/Horizon")


def test_blender_manifest_carries_the_hills(tmp_path, lib):
    scene = _scene(tmp_path, lib)
    far = horizon(scene)
    assert far is not None
    manifest = write_manifest(scene, tmp_path, [1])
    h = manifest["horizon"]
    assert h["colour"] == pytest.approx(list(far.colour))
    v = np.fromfile(tmp_path / h["vertices"], "<f4").reshape(-1, 3)
    np.testing.assert_allclose(v, far.vertices.astype(np.float64) @ Y_UP_TO_Z_UP.T, atol=1e-3)
    (tmp_path / "plain").mkdir()
    assert write_manifest(_scene(tmp_path, lib, extra=""), tmp_path / "plain", [1])["horizon"] is None


@pytest.mark.skipif(shutil.which("blender") is None, reason="Blender is not installed")
def test_the_blend_holds_the_hills(tmp_path, lib):
    scene = _scene(tmp_path, lib)
    far = horizon(scene)
    assert far is not None
    res = export_blender(scene, tmp_path / "s.blend")
    got = blender_probe(
        res.path,
        "import bpy, json, sys\n"
        "o = bpy.data.objects['horizon']\n"
        "rgb = [n for n in o.data.materials[0].node_tree.nodes if n.bl_idname == 'ShaderNodeRGB'][0]\n"
        "out = {'faces': len(o.data.polygons), 'colour': list(rgb.outputs[0].default_value)[:3]}\n"
        "open(sys.argv[-1], 'w').write(json.dumps(out))\n",
        tmp_path,
    )
    assert got["faces"] == len(far.faces)
    np.testing.assert_allclose(got["colour"], far.colour, rtol=1e-6)
