"""Blender export: the .blend renders in Cycles with the trees where forest's own render has them.

Runs Debian's ``blender`` (installed by scripts/setup.sh); skipped where no Blender is installed.
"""

import re
import shutil
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest

from forest.errors import ForestError, ParameterError
from forest.export.blender import Y_UP_TO_Z_UP, euler_to_matrix, euler_xyz, export_blender, write_manifest
from forest.images import read_image
from forest.instances import InstanceSet, quaternion_to_matrix, yaw_tilt_quaternion
from forest.render import render_scene
from forest.scene import load_scene

from export_support import make_config, make_instances
from render_fixtures import BoxLibrary

needs_blender = pytest.mark.skipif(shutil.which("blender") is None, reason="Blender is not installed")

SCENE = """
[lod]
distances = [500.0]
"""


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    return BoxLibrary(tmp_path_factory.mktemp("boxlib"))


def forest_trees(n: int, seed: int = 5) -> InstanceSet:
    """Boxes and half-transparent cards, tilted and turned, tint 1 (forest renders no tint without a map)."""
    inst = make_instances(n, seed=seed, species=("box", "card"), tilt=0.3)
    inst.tint[:] = 1.0
    inst.scale[:] = np.random.default_rng(seed).uniform(0.8, 1.6, n)
    return inst


def read_layers(path: Path) -> dict:
    inp = oiio.ImageInput.open(str(path))
    spec = inp.spec()
    data = np.asarray(inp.read_image(0, 0, 0, spec.nchannels, "float")).reshape(spec.height, spec.width, -1)
    inp.close()
    return {name: data[..., k] for k, name in enumerate(spec.channelnames)}


def test_euler_angles_rebuild_the_rotations():
    rng = np.random.default_rng(1)
    n = 500
    normal = rng.normal(size=(n, 3)) + [0, 2, 0]
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    R = quaternion_to_matrix(yaw_tilt_quaternion(rng.uniform(0, 6.3, n), normal, rng.uniform(0, 1, n)))
    C = Y_UP_TO_Z_UP
    Rb = C @ R @ C.T
    np.testing.assert_allclose(euler_to_matrix(euler_xyz(Rb)), Rb, atol=1e-12)
    # gimbal lock (β = ±90°) still rebuilds the rotation
    lock = euler_to_matrix(np.array([[0.3, np.pi / 2, 0.2], [0.1, -np.pi / 2, -0.4]]))
    np.testing.assert_allclose(euler_to_matrix(euler_xyz(lock)), lock, atol=1e-9)
    assert np.linalg.det(C) == pytest.approx(1.0)  # a rotation: Y up → Z up, nothing mirrored
    np.testing.assert_array_equal(C @ [0, 1, 0], [0, 0, 1])


@needs_blender
def test_cycles_shows_the_trees_where_forest_does(tmp_path, library):
    """Coverage at 64×36: Cycles' alpha (terrain held out) against forest's id layer."""
    cfg = make_config(tmp_path, SCENE).with_overrides(
        {
            "species[0].model": "box",
            "species[1].model": "card",
            "render.width": 64,
            "render.height": 36,
            "render.spp": 4,
            "camera.position": [0.0, 60.0, -130.0],
        }
    )
    scene = load_scene(cfg, forest_trees(160), library=library)
    render_scene(scene, output=tmp_path / "forest.exr", variant="scalar_rgb")
    ours = read_layers(tmp_path / "forest.exr")["id.Z"] >= 0
    res = export_blender(
        scene.with_config(cfg.with_overrides({"render.spp": 16})),
        tmp_path / "scene.blend",
        render=tmp_path / "cycles.png",
        coverage=True,
    )
    assert res.path.is_file() and res.path.stat().st_size > 0 and res.species == ["box", "card"]
    assert not list(tmp_path.glob("*.blend1")) and not list(tmp_path.glob(".*"))
    alpha = read_image(tmp_path / "cycles.png")[..., 3]
    theirs = alpha >= 0.5
    assert ours.shape == theirs.shape == (36, 64)
    assert 0.05 < ours.mean() < 0.6  # a test with trees and ground in view
    iou = (ours & theirs).sum() / (ours | theirs).sum()
    agree = (ours == theirs).mean()
    print(f"coverage IoU {iou:.3f}, pixels agreeing {agree:.3f}, trees on {ours.mean():.2f} of the image")
    assert iou > 0.8 and agree > 0.95, (iou, agree)


@needs_blender
def test_scene_contents(tmp_path, library):
    """The .blend holds one mesh per species, a point per tree with its attributes, camera, sun and sky."""
    cfg = make_config(tmp_path, "").with_overrides({"species[0].model": "box", "species[1].model": "card"})
    inst = forest_trees(40)
    res = export_blender(load_scene(cfg, inst, library=library), tmp_path / "s.blend")
    probe = tmp_path / "probe.py"
    probe.write_text(
        """
import bpy, json, sys
pts = bpy.data.objects["forest_points"]
mesh = pts.data
out = {
    "species_objects": sorted(o.name for o in bpy.data.collections["forest_species"].objects),
    "points": len(mesh.vertices),
    "species": [a.value for a in mesh.attributes["species"].data],
    "position": [list(v.co) for v in mesh.vertices],
    "modifier": pts.modifiers[0].node_group.name,
    "nodes": sorted(n.bl_idname for n in pts.modifiers[0].node_group.nodes),
    "camera": bpy.context.scene.camera.name,
    "sun": bpy.data.objects["sun"].data.energy,
    "world": bpy.context.scene.world.node_tree.nodes["Background"].inputs["Strength"].default_value,
    "engine": bpy.context.scene.render.engine,
}
open(sys.argv[-1], "w").write(json.dumps(out))
"""
    )
    import json
    import subprocess

    subprocess.run(
        [
            "blender",
            "-b",
            str(res.path),
            "--python-exit-code",
            "3",
            "--python",
            str(probe),
            "--",
            str(tmp_path / "o.json"),
        ],
        check=True,
        capture_output=True,
    )
    got = json.loads((tmp_path / "o.json").read_text())
    assert got["species_objects"] == ["species_000_box", "species_001_card"]
    assert got["points"] == len(inst) and got["species"] == inst.species.tolist()
    np.testing.assert_allclose(np.array(got["position"]), inst.position @ Y_UP_TO_Z_UP.T, atol=1e-4)
    assert {"GeometryNodeInstanceOnPoints", "GeometryNodeCollectionInfo"} <= set(got["nodes"])
    assert got["camera"] == "camera" and got["engine"] == "CYCLES"
    assert got["sun"] == pytest.approx(cfg.lights.sun.irradiance) and got["world"] == pytest.approx(
        cfg.lights.sky.radiance
    )


def test_bad_input(tmp_path, library, monkeypatch):
    cfg = make_config(tmp_path, "").with_overrides({"species[0].model": "box", "species[1].model": "card"})
    scene = load_scene(cfg, forest_trees(5), library=library)
    with pytest.raises(ParameterError, match=r"must end in \.blend"):
        export_blender(scene, tmp_path / "x.usd")
    monkeypatch.setenv("FOREST_BLENDER", "no-such-blender")
    with pytest.raises(ForestError, match="Blender not found"):
        export_blender(scene, tmp_path / "x.blend")
    assert not (tmp_path / "x.blend").exists()
    bad = cfg.with_overrides({"export.blender_lod": "huge"})
    with pytest.raises(ForestError, match=r"export\.blender_lod: 'huge' is not a level of 'box'"):
        write_manifest(load_scene(bad, forest_trees(5), library=library), tmp_path, [1])


@needs_blender
def test_command_line(tmp_path, monkeypatch, capsys):
    import forest.library
    from forest.cli import main

    from export_support import FakeLibrary

    monkeypatch.setattr(forest.library, "open_library", lambda *a, **k: FakeLibrary(textures=tmp_path / "lib"))
    cfg = make_config(tmp_path, "")
    with pytest.raises(SystemExit) as e:
        main(
            [
                "export",
                "blender",
                str(cfg.path),
                "-o",
                str(tmp_path / "out" / "s.blend"),
                "--render",
                str(tmp_path / "s.png"),
            ]
        )
    assert (e.value.code or 0) == 0
    out = capsys.readouterr().out
    assert "trees as instances of 2 species" in out and "wrote" in out
    assert (tmp_path / "out" / "s.blend").stat().st_size > 0
    assert read_image(tmp_path / "s.png").shape == (48, 64, 4)
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["s.blend"]


def test_a_focal_length_goes_over_as_sensor_width_and_lens(tmp_path, library):
    """A lens given in mm is written as Blender's sensor_width + lens (horizontal fit); a fov stays an angle."""
    import importlib.util

    cfg = make_config(tmp_path, "").with_overrides({"species[0].model": "box", "species[1].model": "card"})
    plain = write_manifest(load_scene(cfg, forest_trees(5), library=library), tmp_path, [1])
    assert "sensor_width" not in plain["camera"] and "lens" not in plain["camera"]["keys"][0]
    from forest.config import parse_config

    text = (tmp_path / "scene.toml").read_text()  # make_config wrote it
    text = re.sub(r"(?m)^fov\s*=.*$", "focal_length = 35.0\nsensor_width = 24.0", text)
    lens = parse_config(text, path=tmp_path / "lens.toml").with_overrides(
        {"species[0].model": "box", "species[1].model": "card"}
    )
    got = write_manifest(load_scene(lens, forest_trees(5), library=library), tmp_path, [1])
    assert got["camera"]["sensor_width"] == 24.0
    assert got["camera"]["keys"][0]["lens"] == pytest.approx(35.0)
    spec = importlib.util.find_spec("forest.export.blender_build")  # runs inside Blender only (imports bpy)
    assert spec is not None and spec.origin is not None
    code = Path(spec.origin).read_text().split("def make_camera", 1)[1].split("\ndef ", 1)[0]
    assert 'cam.sensor_fit = "HORIZONTAL"' in code and 'cam.lens = key["lens"]' in code
    assert 'cam.sensor_width = c["sensor_width"]' in code
