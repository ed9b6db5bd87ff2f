"""USD export: the stage opens and composes, and every tree's transform and colour round-trip."""

import math

import numpy as np
import pytest
from pxr import Usd, UsdGeom, UsdLux

from forest.camera import camera_at
from forest.errors import ConfigError, ForestError
from forest.export.usd import export_usd
from forest.lights import resolve_lights
from forest.scene import load_scene
from forest.terrain import load_terrain

from export_support import FakeLibrary, fly_keys, make_config, make_instances, validation_errors

FLY = fly_keys(last_frame=4)


@pytest.fixture(scope="module")
def lib():
    return FakeLibrary()


@pytest.fixture(scope="module")
def exported(tmp_path_factory, lib):
    tmp = tmp_path_factory.mktemp("usd")
    cfg = make_config(tmp, FLY)
    inst = make_instances(800)
    res = export_usd(load_scene(cfg, inst, library=lib), tmp / "out" / "forest.usda")
    stage = Usd.Stage.Open(str(res.path))
    return cfg, inst, res, stage


def test_stage_opens_and_composes(exported, lib):
    _cfg, _inst, res, stage = exported
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y and UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert stage.GetDefaultPrim().GetPath() == "/World"
    assert sorted(res.instancers) == ["north", "south"]  # no instancer for the empty partition
    assert not stage.GetPrimAtPath("/World/Forest/east")
    for _pname, path in res.instancers.items():
        pi = UsdGeom.PointInstancer(stage.GetPrimAtPath(path))
        for target in pi.GetPrototypesRel().GetTargets():
            proto = stage.GetPrimAtPath(target)
            assert proto.HasAuthoredReferences()
            vs = proto.GetVariantSets().GetVariantSet("lod")
            sp = lib.resolve(proto.GetName())
            assert vs.GetVariantNames() == sorted(l.name for l in sp.lods) or set(vs.GetVariantNames()) == {
                l.name for l in sp.lods
            }
            assert vs.GetVariantSelection() == sp.lods[0].name
            meshes = [UsdGeom.Mesh(p) for p in Usd.PrimRange(proto) if p.IsA(UsdGeom.Mesh)]
            assert len(meshes) == len(sp.lods[0].parts)
            for mesh, part in zip(meshes, sp.lods[0].parts):
                src = part.load()
                np.testing.assert_array_equal(np.array(mesh.GetPointsAttr().Get()), src.vertices)
                # the library's triangles, each wound counter-clockwise about its normals
                f = np.array(mesh.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3)
                np.testing.assert_array_equal(np.sort(f, axis=1), np.sort(src.faces.astype(np.int64), axis=1))
                v, n = src.vertices.astype(np.float64), src.normals.astype(np.float64)
                ng = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
                assert (np.einsum("ij,ij->i", ng, n[f].sum(axis=1)) > 0).all()
                st = np.array(UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st").Get())
                np.testing.assert_allclose(st, np.stack([src.uv[:, 0], 1 - src.uv[:, 1]], 1), atol=1e-7)
                colour = mesh.GetDisplayColorPrimvar()
                assert colour.HasAuthoredValue() == (not part.tinted)
            # switching the variant swaps in another level's geometry
            vs.SetVariantSelection(sp.lods[-1].name)
            meshes = [UsdGeom.Mesh(p) for p in Usd.PrimRange(proto) if p.IsA(UsdGeom.Mesh)]
            assert sum(len(m.GetFaceVertexIndicesAttr().Get()) // 3 for m in meshes) == sp.lods[-1].triangles
            vs.SetVariantSelection(sp.lods[0].name)


def test_stage_passes_usd_validation(exported):
    _cfg, _inst, _res, stage = exported
    assert validation_errors(stage) == []


def test_every_instance_round_trips(exported, lib):
    _cfg, inst, res, stage = exported
    M = inst.matrices()
    seen = []
    for pname, path in res.instancers.items():
        pi = UsdGeom.PointInstancer(stage.GetPrimAtPath(path))
        ids = np.array(pi.GetIdsAttr().Get())
        rows = np.searchsorted(inst.id, ids.astype(np.uint64))
        np.testing.assert_array_equal(inst.id[rows], ids.astype(np.uint64))
        assert np.all(inst.partition[rows] == inst.partition_names.index(pname))
        seen += rows.tolist()
        xf = np.array(pi.ComputeInstanceTransformsAtTime(Usd.TimeCode.Default(), Usd.TimeCode.Default()))
        got = np.transpose(xf, (0, 2, 1))  # USD row vectors → column vectors
        np.testing.assert_allclose(got, M[rows], rtol=0, atol=2e-6 * max(1.0, np.abs(M).max()))
        tint = UsdGeom.PrimvarsAPI(pi).GetPrimvar("forest:tint")
        assert tint.GetInterpolation() == UsdGeom.Tokens.vertex
        np.testing.assert_array_equal(np.array(tint.Get(), dtype=np.float32), inst.tint[rows])
        # displayColor: the tree's canopy colour, tint × the species' leaf colour (no texture here)
        colour = UsdGeom.PrimvarsAPI(pi).GetPrimvar("displayColor")
        assert colour.GetInterpolation() == UsdGeom.Tokens.vertex
        leaf = np.array([lib.resolve(n).lods[0].parts[1].colour for n in inst.species_names], np.float32)
        np.testing.assert_allclose(np.array(colour.Get()), inst.tint[rows] * leaf[inst.species[rows]], rtol=1e-6)
        # the instancer's extent contains the one USD computes from the prototypes
        ext = np.array(pi.GetExtentAttr().Get())
        exact = np.array(pi.ComputeExtentAtTime(Usd.TimeCode.Default(), Usd.TimeCode.Default()))
        assert np.all(ext[0] <= exact[0] + 1e-4) and np.all(ext[1] >= exact[1] - 1e-4)
        protos = [stage.GetPrimAtPath(t).GetName() for t in pi.GetPrototypesRel().GetTargets()]
        idx = np.array(pi.GetProtoIndicesAttr().Get())
        assert [protos[i] for i in idx] == [inst.species_names[s] for s in inst.species[rows]]
        q = np.array(pi.GetOrientationsfAttr().Get())
        np.testing.assert_array_equal(q[:, [3, 0, 1, 2]], inst.rotation[rows])
        qh = np.array(pi.GetOrientationsAttr().Get(), dtype=np.float64)  # half-precision copy
        np.testing.assert_allclose(qh[:, [3, 0, 1, 2]], inst.rotation[rows], atol=1e-3)
    assert sorted(seen) == list(range(len(inst)))


def test_camera_follows_the_fly_through(exported):
    cfg, _inst, _res, stage = exported
    cam = UsdGeom.Camera(stage.GetPrimAtPath("/World/Camera"))
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (1, 4)
    for f in (1, 2.0, 3, 4):
        state = camera_at(cfg.camera, f)
        xf = np.array(cam.ComputeLocalToWorldTransform(Usd.TimeCode(f))).T  # camera → world, column vectors
        np.testing.assert_allclose(xf[:3, 3], state.position, atol=1e-9)
        to_cam = np.linalg.inv(xf) @ np.append(state.target, 1.0)
        assert abs(to_cam[0]) < 1e-6 and abs(to_cam[1]) < 1e-6 and to_cam[2] < 0  # looks down −Z
        assert np.linalg.det(xf[:3, :3]) == pytest.approx(1.0)
        gc = cam.GetCamera(Usd.TimeCode(f))
        hfov = 2 * math.degrees(math.atan(gc.horizontalAperture / 2 / gc.focalLength))
        assert hfov == pytest.approx(state.fov, rel=1e-6)
        assert gc.verticalAperture / gc.horizontalAperture == pytest.approx(cfg.render.height / cfg.render.width)


def test_lights_and_terrain(exported):
    cfg, _inst, _res, stage = exported
    sun = UsdLux.DistantLight(stage.GetPrimAtPath("/World/Lights/Sun"))
    xf = np.array(UsdGeom.Xformable(sun).ComputeLocalToWorldTransform(Usd.TimeCode.Default())).T
    emission = xf[:3, :3] @ np.array([0.0, 0.0, -1.0])  # a DistantLight shines along −Z
    np.testing.assert_allclose(emission, -resolve_lights(cfg).sun.direction, atol=1e-12)
    # unnormalised disk radiance: E = L·π·sin²(α/2)
    half = math.radians(sun.GetAngleAttr().Get()) / 2
    assert not sun.GetNormalizeAttr().Get()
    assert sun.GetIntensityAttr().Get() * math.pi * math.sin(half) ** 2 == pytest.approx(cfg.lights.sun.irradiance)
    dome = UsdLux.DomeLight(stage.GetPrimAtPath("/World/Lights/Sky"))
    assert dome.GetIntensityAttr().Get() == pytest.approx(cfg.lights.sky.radiance)
    terrain = load_terrain(cfg.terrain, cfg.path)
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Terrain"))
    np.testing.assert_allclose(np.array(mesh.GetPointsAttr().Get()), terrain.vertices, atol=1e-5)
    np.testing.assert_array_equal(np.array(mesh.GetFaceVertexIndicesAttr().Get()), terrain.faces.ravel())


@pytest.mark.parametrize("suffix", [".usda", ".usdc"])
def test_same_input_gives_identical_files(tmp_path, lib, suffix):
    cfg = make_config(tmp_path, "")
    inst = make_instances(300, seed=9)
    a = export_usd(load_scene(cfg, inst, library=lib), tmp_path / "a" / f"f{suffix}")
    b = export_usd(load_scene(cfg, inst, library=lib), tmp_path / "b" / f"f{suffix}")
    assert len(a.files) == 3
    for fa, fb in zip(a.files, b.files):
        assert fa.relative_to(tmp_path / "a") == fb.relative_to(tmp_path / "b")
        assert fa.read_bytes() == fb.read_bytes(), fa


def test_usdc_round_trips_too(tmp_path, lib):
    cfg = make_config(tmp_path, "")
    inst = make_instances(200, seed=2, empty_partition=None)
    res = export_usd(load_scene(cfg, inst, library=lib), tmp_path / "f.usdc")
    stage = Usd.Stage.Open(str(res.path))
    total = 0
    for path in res.instancers.values():
        pi = UsdGeom.PointInstancer(stage.GetPrimAtPath(path))
        total += len(pi.GetIdsAttr().Get())
        assert all(stage.GetPrimAtPath(t).GetChildren() for t in pi.GetPrototypesRel().GetTargets())
    assert total == len(inst) and len(res.instancers) == 3


def test_bad_input(tmp_path, lib):
    cfg = make_config(tmp_path, "")
    with pytest.raises(ForestError, match=r"must end in \.usda, \.usdc or \.usd"):
        export_usd(load_scene(cfg, make_instances(10), library=lib), tmp_path / "f.abc")
    cfg = make_config(tmp_path, '[export]\nusd_lod = "tiny"\n')
    with pytest.raises(ConfigError, match=r"export.usd_lod: 'tiny' is not a level of 'oak'"):
        export_usd(load_scene(cfg, make_instances(10), library=lib), tmp_path / "f.usda")
    assert [p.name for p in tmp_path.iterdir()] == ["scene.toml"]


def test_usd_lod_selects_the_variant(tmp_path, lib):
    lib2 = FakeLibrary()
    cfg = make_config(tmp_path, '[export]\nusd_lod = "low"\n')
    res = export_usd(load_scene(cfg, make_instances(50), library=lib2), tmp_path / "f.usda")
    stage = Usd.Stage.Open(str(res.path))
    pi = UsdGeom.PointInstancer(stage.GetPrimAtPath(res.instancers["north"]))
    for t in pi.GetPrototypesRel().GetTargets():
        assert stage.GetPrimAtPath(t).GetVariantSets().GetVariantSet("lod").GetVariantSelection() == "low"


def test_crate_with_usd_suffix_and_an_empty_forest(tmp_path, lib):
    from forest.instances import InstanceSet

    cfg = make_config(tmp_path, "")
    res = export_usd(load_scene(cfg, InstanceSet.empty(["oak", "pine"]), library=lib), tmp_path / "empty.usd")
    assert res.path.read_bytes().startswith(b"PXR-USDC")
    stage = Usd.Stage.Open(str(res.path))
    assert res.instancers == {} and stage.GetPrimAtPath("/World/Terrain") and stage.GetPrimAtPath("/World/Camera")
    (tmp_path / "dir.usda").mkdir()
    with pytest.raises(ForestError, match="is a folder"):
        export_usd(load_scene(cfg, make_instances(5), library=lib), tmp_path / "dir.usda")
