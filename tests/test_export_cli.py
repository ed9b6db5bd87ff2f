"""``forest export rib|usd`` end to end: scatter → export, exit codes, and the real tree library."""

import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import seed_library_cache
from pxr import Usd, UsdGeom, UsdShade

from forest.cli import main

import ribcheck
from export_support import FakeLibrary, make_config, validation_errors

ROOT = Path(__file__).resolve().parents[1]


def run(argv) -> int:
    with pytest.raises(SystemExit) as e:
        main([str(a) for a in argv])
    return e.value.code or 0


@pytest.fixture
def fake_library(monkeypatch):
    import forest.library

    monkeypatch.setattr(forest.library, "open_library", lambda *a, **k: FakeLibrary())


def test_rib_and_usd_from_the_command_line(tmp_path, fake_library, capsys):
    cfg = make_config(tmp_path, "\n[lod]\ndistances = [60.0]\n")
    assert run(["scatter", cfg.path, "-o", tmp_path / "trees.npz", "-q"]) == 0
    assert (
        run(
            [
                "export",
                "rib",
                cfg.path,
                "-o",
                tmp_path / "rib",
                "--instances",
                tmp_path / "trees.npz",
                "--frames",
                "2-3",
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert "instance file" in out and "scene file(s)" in out
    calls = ribcheck.check_export(tmp_path / "rib")
    assert sorted(k for k in calls if k.startswith("scene_")) == ["scene_0002.rib", "scene_0003.rib"]
    trees = sum(len(ribcheck.read_trees(v)) for k, v in calls.items() if k.startswith("instances_"))
    from forest.instances import InstanceSet

    assert trees == len(InstanceSet.load(tmp_path / "trees.npz")) > 0
    # without --instances the command scatters the config itself: same trees, same bytes
    assert run(["export", "rib", cfg.path, "-o", tmp_path / "rib2", "-q"]) == 0
    assert (tmp_path / "rib2" / "instances_default.rib").read_bytes() == (
        tmp_path / "rib" / "instances_default.rib"
    ).read_bytes()
    assert run(["export", "rib", cfg.path, "-o", tmp_path / "r22", "--renderman22", "-q"]) == 0
    ribcheck.check_export(tmp_path / "r22")
    assert run(["export", "points", cfg.path, "-o", tmp_path / "trees.csv", "-q"]) == 0
    assert len((tmp_path / "trees.csv").read_text().splitlines()) == trees + 1
    assert run(["export", "usd", cfg.path, "-o", tmp_path / "f.usdc", "-q"]) == 0
    stage = Usd.Stage.Open(str(tmp_path / "f.usdc"))
    pi = UsdGeom.PointInstancer(stage.GetPrimAtPath("/World/Forest/default"))
    assert len(pi.GetIdsAttr().Get()) == trees


@pytest.mark.parametrize(
    "argv,message",
    [
        (["export", "rib", "{cfg}", "-o", "{tmp}/out", "--frames", "9-1"], "--frames: bad range"),
        (["export", "usd", "{cfg}", "-o", "{tmp}/out.usda", "--frames", "x"], "--frames: cannot read 'x'"),
        (["export", "blender", "{cfg}", "-o", "{tmp}/o.blend", "--frames", "3-2"], "--frames: bad range"),
        (["export", "blender", "{cfg}", "-o", "{tmp}/o.blend", "--blender", "{tmp}/no/blender"], "Blender not found"),
        (["export", "usd", "{cfg}", "-o", "{tmp}/out.abc"], "must end in .usda, .usdc or .usd"),
        (["export", "rib", "{tmp}/missing.toml", "-o", "{tmp}/out"], "config file not found"),
        (["export", "fbx", "{cfg}", "-o", "{tmp}/out"], "forest export: unknown target 'fbx'; use one of rib, usd"),
        (["export", "rib", "{cfg}", "-o", "{tmp}/out", "--display", "nuke"], "--display: unknown display 'nuke'"),
        (["export", "points", "{cfg}", "-o", "{tmp}/out.abc"], "-o: {tmp}/out.abc: a points file must end in"),
        (["export", "blender", "{cfg}", "-o", "{tmp}/out.usd"], "-o: {tmp}/out.usd: a Blender file name must end"),
        (
            ["export", "usd", "{cfg}", "-o", "{tmp}/out.usda", "--instances", "{tmp}/nope.npz"],
            "instance file not found",
        ),
    ],
)
def test_bad_input_exits_2_with_one_line(tmp_path, fake_library, capsys, monkeypatch, argv, message):
    """Every option is checked before the scatter: the scene is never loaded."""
    import forest.scene

    def no_scene(*a, **k):
        raise AssertionError("the scene was loaded before the options were checked")

    monkeypatch.setattr(forest.scene, "load_scene", no_scene)
    cfg = make_config(tmp_path, "")
    argv = [a.format(cfg=cfg.path, tmp=tmp_path) for a in argv]
    message = message.format(tmp=tmp_path)
    assert run(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("forest: error:") and message in err[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.toml"]


def test_unknown_species_names_the_config_field(tmp_path, capsys, monkeypatch):
    import forest.library

    monkeypatch.setattr(forest.library, "open_library", lambda *a, **k: FakeLibrary())
    cfg = make_config(tmp_path, "")
    text = cfg.path.read_text().replace('model = "pine"', 'model = "baobab"')
    cfg.path.write_text(text)
    assert run(["export", "usd", cfg.path, "-o", tmp_path / "f.usda"]) == 2
    err = capsys.readouterr().err
    assert "scene.toml: species[1].model:" in err and "baobab" in err
    assert not (tmp_path / "f.usda").exists() and not (tmp_path / "f_species").exists()


REAL = """
seed = 3
[terrain.flat]
size = 120.0
[scatter]
count = 150
[[species]]
model = "broadleaf"
percent = 50
[[species]]
model = "shrub"
percent = 50
[camera]
position = [0.0, 20.0, -90.0]
target = [0.0, 5.0, 0.0]
[lod]
distances = [40.0, 80.0]
[render]
width = 32
height = 24
"""


@pytest.fixture(scope="module")
def real_library(tmp_path_factory):
    """A private copy of the shipped library (recipes), its broadleaf and shrub (the 4 individuals a scene draws
    from) seeded with existing builds of the same recipes (``seed_library_cache``: the export is the subject here,
    not the build; a species whose build is missing or stale is built on first use)."""
    root = tmp_path_factory.mktemp("library")
    shutil.copy(ROOT / "library" / "manifest.toml", root / "manifest.toml")
    shutil.copytree(ROOT / "library" / "presets", root / "presets")
    seed_library_cache(root, ("broadleaf", "shrub"), individuals=4)
    return root


def test_real_library_species_export(tmp_path, real_library):
    from forest.library import open_library

    (tmp_path / "scene.toml").write_text(REAL)
    assert run(["export", "rib", tmp_path / "scene.toml", "-o", tmp_path / "rib", "--library", real_library, "-q"]) == 0
    calls = ribcheck.check_export(tmp_path / "rib")
    objects = ribcheck.objects(calls["objects.rib"])
    lib = open_library(real_library)
    for name in ("broadleaf", "shrub"):
        sp = lib.resolve(name)
        for lod in sp.lods[:3]:  # two distances: three bands
            arch = calls[f"archives/{name}_{lod.name}.rib"]
            meshes = [objects[c.args[0]] for c in arch if c.name == "ObjectInstance"]
            assert sum(len(m["faces"]) for m in meshes) == lod.triangles
            lo, hi = np.asarray(lod.bounds)
            for m in meshes:
                assert np.all(m["P"] >= lo - 1e-6) and np.all(m["P"] <= hi + 1e-6)
    assert (
        run(["export", "usd", tmp_path / "scene.toml", "-o", tmp_path / "f.usda", "--library", real_library, "-q"]) == 0
    )
    stage = Usd.Stage.Open(str(tmp_path / "f.usda"))
    pi = UsdGeom.PointInstancer(stage.GetPrimAtPath("/World/Forest/default"))
    for t in pi.GetPrototypesRel().GetTargets():
        proto = stage.GetPrimAtPath(t)
        sp = lib.resolve(proto.GetName())
        tris = sum(
            len(UsdGeom.Mesh(p).GetFaceVertexIndicesAttr().Get()) // 3
            for p in Usd.PrimRange(proto)
            if p.IsA(UsdGeom.Mesh)
        )
        assert tris == sp.lods[0].triangles
        # every part has a bound material; textured parts read a copy of the library texture
        textured = 0
        for p, part in zip([p for p in Usd.PrimRange(proto) if p.IsA(UsdGeom.Mesh)], sp.lods[0].parts):
            mat, _ = UsdShade.MaterialBindingAPI(p).ComputeBoundMaterial()
            assert mat
            for sh in Usd.PrimRange(mat.GetPrim()):
                if sh.GetAttribute("info:id").Get() == "UsdUVTexture":
                    asset = sh.GetAttribute("inputs:file").Get()
                    assert Path(asset.resolvedPath).read_bytes() == Path(part.texture).read_bytes()
                    textured += 1
        assert textured == sum(1 for part in sp.lods[0].parts if part.texture)
    assert validation_errors(stage) == []
