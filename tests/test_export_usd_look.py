"""USD export with the look: materials read the per-tree colour and cut leaves by the texture's alpha."""

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from conftest import write_png
from pxr import Usd, UsdGeom, UsdShade

from forest.export.common import texture_mean_detail
from forest.export.usd import export_usd
from forest.images import read_image, srgb_to_linear
from forest.scene import load_scene

from export_support import FakeLibrary, make_config, make_instances, validation_errors


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("usdlook")
    lib = FakeLibrary(textures=tmp / "lib")
    for lod in lib.species["oak"].lods:  # the oak's leaves have a cuticle lobe, the pine's none
        lod.parts = tuple(
            dataclasses.replace(p, sheen=0.7, roughness=0.35) if p.kind == "leaf" else p for p in lod.parts
        )
    write_png(tmp / "colour.png", np.random.default_rng(2).uniform(0.3, 1.0, (6, 6, 3)))
    cfg = make_config(tmp, '\n[maps]\ncolour = "colour.png"\n', ground_material=False)
    inst = make_instances(300)
    scene = load_scene(cfg, inst, library=lib)
    res = export_usd(scene, tmp / "out" / "forest.usda")
    return scene, lib, res, Usd.Stage.Open(str(res.path))


def source_shader(inp):
    (src,) = inp.GetConnectedSources()[0]
    return UsdShade.Shader(src.source.GetPrim()), src.sourceName


def test_leaf_materials_read_display_colour_and_alpha(exported):
    scene, lib, res, stage = exported
    assert validation_errors(stage) == []
    checked = sheens = 0
    for path in res.instancers.values():
        pi = UsdGeom.PointInstancer(stage.GetPrimAtPath(path))
        for target in pi.GetPrototypesRel().GetTargets():
            proto = stage.GetPrimAtPath(target)
            sp = lib.resolve(proto.GetName())
            meshes = [p for p in Usd.PrimRange(proto) if p.IsA(UsdGeom.Mesh)]
            for prim, part in zip(meshes, sp.lods[0].parts):
                mat, _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()  # bound in the composed stage
                surf = mat.ComputeSurfaceSource()[0]
                assert surf.GetIdAttr().Get() == "UsdPreviewSurface"
                networks = [surf] + ([mat.ComputeSurfaceSource("mtlx")[0]] if part.tinted else [])
                for sh in networks:  # the cuticle lobe: the clearcoat (index 1.5, white), the base specular off
                    if part.sheen > 0:
                        assert sh.GetInput("clearcoat").Get() == pytest.approx(part.sheen)
                        assert sh.GetInput("clearcoatRoughness").Get() == pytest.approx(math.sqrt(part.roughness))
                        assert sh.GetInput("useSpecularWorkflow").Get() == 1
                        assert tuple(sh.GetInput("specularColor").Get()) == (0.0, 0.0, 0.0)
                        sheens += 1
                    else:
                        assert not sh.GetInput("clearcoat") and not sh.GetInput("useSpecularWorkflow")
                if not part.tinted:
                    continue
                reader, out = source_shader(surf.GetInput("diffuseColor"))
                assert reader.GetIdAttr().Get() == "UsdPrimvarReader_float3" and out == "result"
                assert reader.GetInput("varname").Get() == "displayColor"
                tex, out = source_shader(surf.GetInput("opacity"))
                assert tex.GetIdAttr().Get() == "UsdUVTexture" and out == "a"
                asset = tex.GetInput("file").Get()
                np.testing.assert_array_equal(
                    read_image(asset.resolvedPath, unassociated=True)[..., 3],
                    read_image(part.texture, unassociated=True)[..., 3],
                )
                assert surf.GetInput("opacityThreshold").Get() == pytest.approx(0.5)
                # MaterialX: image × base colour × the tree's tint, opacity = the image's alpha
                mx = mat.ComputeSurfaceSource("mtlx")[0]
                assert mx.GetIdAttr().Get() == "ND_UsdPreviewSurface_surfaceshader"
                albedo, _ = source_shader(mx.GetInput("diffuseColor"))
                tint, _ = source_shader(albedo.GetInput("in1"))
                assert tint.GetInput("geomprop").Get() == "forest:tint"
                detail, _ = source_shader(albedo.GetInput("in2"))
                assert tuple(detail.GetInput("in2").Get()) == pytest.approx(part.colour)
                rgb, _ = source_shader(detail.GetInput("in1"))
                image, _ = source_shader(rgb.GetInput("in"))
                assert image.GetInput("file").Get().resolvedPath == asset.resolvedPath
                assert image.GetInput("file").GetAttr().GetColorSpace() == "srgb_texture"
                alpha, _ = source_shader(mx.GetInput("opacity"))
                assert alpha.GetIdAttr().Get() == "ND_extract_color4" and alpha.GetInput("index").Get() == 3
                checked += 1
    assert checked >= 2 and sheens >= 2
    # displayColor: the tint × base colour × the texture's mean detail over the leaf's opaque texels
    inst = scene.instances
    tex = lib.resolve("oak").lods[0].parts[1].texture
    img = read_image(tex, unassociated=True)
    mean = srgb_to_linear(img[..., :3])[img[..., 3] >= 0.5].mean(axis=0)
    np.testing.assert_allclose(texture_mean_detail(tex), mean, rtol=1e-6)
    pi = UsdGeom.PointInstancer(stage.GetPrimAtPath(res.instancers["north"]))
    ids = np.array(pi.GetIdsAttr().Get()).astype(np.uint64)
    rows = np.searchsorted(inst.id, ids)
    base = np.array([lib.resolve(n).lods[0].parts[1].colour for n in inst.species_names], np.float32) * mean
    colour = np.array(UsdGeom.PrimvarsAPI(pi).GetPrimvar("displayColor").Get())
    np.testing.assert_allclose(colour, inst.tint[rows] * base[inst.species[rows]], rtol=1e-5)


def test_terrain_takes_the_grounds_albedo(exported):
    scene, _lib, res, stage = exported
    terrain = stage.GetPrimAtPath("/World/Terrain")
    mat, _ = UsdShade.MaterialBindingAPI(terrain).ComputeBoundMaterial()
    tex, _ = source_shader(mat.ComputeSurfaceSource()[0].GetInput("diffuseColor"))
    path = Path(tex.GetInput("file").Get().resolvedPath)
    assert path in res.textures
    got = srgb_to_linear(read_image(path))
    np.testing.assert_allclose(got, scene.terrain_albedo.rgb, atol=0.004)  # the renderers' ground, 8-bit sRGB


def test_stage_metadata(exported):
    _scene, _lib, res, stage = exported
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y and UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    for layer in res.species_layers:
        s = Usd.Stage.Open(str(layer))
        assert UsdGeom.GetStageUpAxis(s) == UsdGeom.Tokens.y and UsdGeom.GetStageMetersPerUnit(s) == 1.0
        root = s.GetDefaultPrim()
        for lod in root.GetVariantSets().GetVariantSet("lod").GetVariantNames():
            root.GetVariantSets().GetVariantSet("lod").SetVariantSelection(lod)
            assert len(UsdGeom.ModelAPI(root).GetExtentsHint()) == 2  # prototypes carry their extent
            for p in Usd.PrimRange(root):
                if p.IsA(UsdGeom.Mesh):
                    assert UsdGeom.Mesh(p).GetExtentAttr().HasAuthoredValue()
