"""``[camera] usd``: a camera read from a USD stage — pose, lens, clipping, animation, units and axes, mistakes,
and forest's own USD export read back as the same camera."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pxr import Gf, Usd, UsdGeom

from forest.camera import camera_at, look_at_matrix
from forest.config import ConfigError, parse_config
from forest.config.schema import fov_from_focal_length

BASE = """
[terrain]
flat = { size = 100.0 }
[[species]]
model = "broadleaf"
percent = 100
"""

#: The shot (metres, Y up): frame → (position, target, focal length mm).
SHOT = {
    1.0: ((0.0, 12.0, -80.0), (0.0, 2.0, 0.0), 35.0),
    12.0: ((20.0, 10.0, -60.0), (5.0, 2.0, 0.0), 50.0),
    24.0: ((40.0, 8.0, -40.0), (10.0, 2.0, 0.0), 85.0),
}


def usd_matrix(position, target, world_up=(0.0, 1.0, 0.0)) -> Gf.Matrix4d:
    """A USD camera's local-to-world (looks down −Z, +Y up) at ``position`` looking at ``target``."""
    m = look_at_matrix(position, target, world_up) @ np.diag([-1.0, 1.0, -1.0, 1.0])  # Mitsuba +Z forward → USD −Z
    return Gf.Matrix4d(m.T.tolist())  # USD: row vectors


def author_shot(path, *, z_up_cm: bool = False, still: bool = False) -> None:
    """The :data:`SHOT` camera at /World/rig/cam (the rig moves it; the camera prim zooms), authored with pxr alone.

    ``z_up_cm``: the same shot in a Z-up, centimetre stage (a Maya/Blender-style layout), so it must import
    as the same camera in forest's Y-up metres."""
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z if z_up_cm else UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 0.01 if z_up_cm else 1.0)
    stage.SetTimeCodesPerSecond(25.0)
    # forest (x, y, z) in metres → a Z-up centimetre stage: (x, −z, y), positions × 100
    to_z_up = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    UsdGeom.Xform.Define(stage, "/World")
    UsdGeom.Mesh.Define(stage, "/World/ground")  # not a camera
    rig = UsdGeom.Xform.Define(stage, "/World/rig")
    rig_op = rig.AddTransformOp()
    cam = UsdGeom.Camera.Define(stage, "/World/rig/cam")
    cam.CreateHorizontalApertureAttr(36.0)
    cam.CreateVerticalApertureAttr(24.0)
    cam.CreateClippingRangeAttr(Gf.Vec2f(10.0, 500000.0) if z_up_cm else Gf.Vec2f(0.1, 5000.0))
    focal = cam.CreateFocalLengthAttr()
    for frame, (position, target, mm) in SHOT.items():
        m = np.array(usd_matrix(position, target)).T  # column vectors, forest world
        if z_up_cm:
            m[:3, :3], m[:3, 3] = to_z_up @ m[:3, :3], 100.0 * to_z_up @ m[:3, 3]
        t = Usd.TimeCode.Default() if still else Usd.TimeCode(frame)
        rig_op.Set(Gf.Matrix4d(m.T.tolist()), t)
        focal.Set(mm, t)
        if still:
            break
    stage.GetRootLayer().Save()


def load(tmp_path, camera: str):
    path = tmp_path / "scene.toml"
    path.write_text(BASE + "[camera]\n" + camera)
    return parse_config(path.read_text(), path=path)


def test_an_animated_camera_from_another_tool_imports_with_lens_pose_and_keys(tmp_path):
    author_shot(tmp_path / "shot.usda")
    cam = load(tmp_path, 'usd = "shot.usda"\nusd_camera = "/World/rig/cam"\n').camera
    assert [k.frame for k in cam.keys] == [1.0, 12.0, 24.0]
    assert [k.focal_length for k in cam.keys] == [35.0, 50.0, 85.0] and cam.sensor_width == 36.0
    assert (cam.near, cam.far, cam.fps) == pytest.approx((0.1, 5000.0, 25.0))
    assert cam.up == (0.0, 1.0, 0.0)
    for frame, (position, target, mm) in SHOT.items():
        s = camera_at(cam, frame)
        np.testing.assert_allclose(s.position, position, atol=1e-9)
        look = (s.target - s.position) / np.linalg.norm(s.target - s.position)
        want = np.subtract(target, position) / np.linalg.norm(np.subtract(target, position))
        np.testing.assert_allclose(look, want, atol=1e-9)
        assert s.fov == pytest.approx(fov_from_focal_length(mm, 36.0), rel=1e-12)
    assert camera_at(cam, 1.0).fov == pytest.approx(54.4322, abs=1e-4)  # 35 mm on full frame
    # between keys the zoom moves linearly in focal length, as the stage's samples interpolate
    assert camera_at(cam, 6.5).fov == pytest.approx(fov_from_focal_length(42.5, 36.0), rel=1e-12)


def test_a_z_up_centimetre_stage_imports_as_the_same_camera_in_metres(tmp_path):
    author_shot(tmp_path / "yup.usda")
    author_shot(tmp_path / "zup.usda", z_up_cm=True)
    y = load(tmp_path, 'usd = "yup.usda"\n').camera  # one camera on the stage: no prim path needed
    z = load(tmp_path, 'usd = "zup.usda"\n').camera
    assert (z.near, z.far) == pytest.approx((0.1, 5000.0))
    for frame in SHOT:
        a, b = camera_at(y, frame), camera_at(z, frame)
        np.testing.assert_allclose(b.position, a.position, atol=1e-9)
        np.testing.assert_allclose(b.target, a.target, atol=1e-9)
        assert b.fov == a.fov
    # straight up in the Z-up stage is +Y in forest: the camera keeps its world up, no roll
    assert z.up == pytest.approx((0.0, 1.0, 0.0), abs=1e-12)


def test_a_still_camera_is_no_path(tmp_path):
    author_shot(tmp_path / "still.usda", still=True)
    cam = load(tmp_path, 'usd = "still.usda"\nnear = 1.0\n').camera
    assert cam.keys == [] and cam.focal_length == 35.0 and cam.near == 1.0  # near as the scene file gives it
    np.testing.assert_allclose(cam.position, SHOT[1.0][0], atol=1e-9)


def stage_with(path, *names: tuple[str, str]) -> None:
    stage = Usd.Stage.CreateNew(str(path))
    for prim, kind in names:
        stage.DefinePrim(prim, kind)
    stage.GetRootLayer().Save()


@pytest.mark.parametrize(
    "prims, camera, field, words",
    [
        ([("/World", "Xform")], "", "camera.usd", "shot.usda: the stage has no UsdGeom.Camera"),
        ([("/A", "Camera"), ("/B", "Camera")], "", "camera.usd_camera", "has 2 cameras (/A, /B); name one"),
        (
            [("/A", "Camera"), ("/B", "Xform")],
            'usd_camera = "/B"\n',
            "camera.usd_camera",
            "/B is a Xform, not a camera",
        ),
        ([("/A", "Camera")], 'usd_camera = "/C"\n', "camera.usd_camera", "no prim at /C (cameras on the stage: /A)"),
        ([("/A", "Camera")], 'usd_camera = "A"\n', "camera.usd_camera", "is not an absolute prim path"),
        ([("/A", "Camera")], "fov = 30.0\n", "camera.fov", "comes from the camera in usd (shot.usda)"),
    ],
)
def test_mistakes_name_the_file_and_field(tmp_path, prims, camera, field, words):
    stage_with(tmp_path / "shot.usda", *prims)
    with pytest.raises(ConfigError) as e:
        load(tmp_path, 'usd = "shot.usda"\n' + camera)
    assert e.value.field == field and words in e.value.message and "\n" not in str(e.value)
    assert str(e.value).startswith(str(tmp_path / "scene.toml"))


def test_unreadable_or_missing_stage(tmp_path):
    (tmp_path / "bad.usda").write_text("#usda 1.0\n( this is not usd\n")
    with pytest.raises(ConfigError, match=r"camera\.usd: bad\.usda: cannot open as a USD stage") as e:
        load(tmp_path, 'usd = "bad.usda"\n')
    assert "\n" not in str(e.value)
    with pytest.raises(ConfigError, match=r"camera\.usd: file not found: gone\.usda"):
        load(tmp_path, 'usd = "gone.usda"\n')
    with pytest.raises(ConfigError, match=r"camera\.usd_camera: names a camera prim, but usd .* is not given"):
        load(tmp_path, 'usd_camera = "/cam"\n')


def test_the_stage_is_an_input_file_of_the_config(tmp_path):
    author_shot(tmp_path / "shot.usda", still=True)
    cfg = load(tmp_path, 'usd = "shot.usda"\n')
    assert tmp_path / "shot.usda" in cfg.files()


# --- forest's own export read back ---------------------------------------------------------------


def test_export_then_import_gives_the_same_camera(tmp_path):
    from forest.export.usd import export_usd
    from forest.scene import load_scene

    from export_support import SCENE, FakeLibrary, make_instances

    lens = "focal_length = 35.0\nsensor_width = 24.89\nnear = 0.25\nfar = 9000.0\nfps = 30.0\n"
    keys = """
[[camera.keys]]
frame = 1
position = [0.0, 40.0, -150.0]
target = [0.0, 5.0, 0.0]
[[camera.keys]]
frame = 5
position = [60.0, 30.0, -120.0]
target = [10.0, 5.0, 0.0]
focal_length = 70.0
"""
    text = SCENE.replace("fov = 50.0\n", lens) + "terrain_colour = [0.2, 0.18, 0.12]\n" + keys
    src = tmp_path / "scene.toml"
    src.write_text(text)
    cfg = parse_config(text, path=src)
    res = export_usd(load_scene(cfg, make_instances(50), library=FakeLibrary()), tmp_path / "out" / "shot.usda")
    back = load(tmp_path, 'usd = "out/shot.usda"\n').camera
    assert [k.frame for k in back.keys] == [1.0, 2.0, 3.0, 4.0, 5.0]
    assert back.sensor_width == pytest.approx(24.89, rel=1e-7)  # horizontalAperture is a float attribute
    assert (back.near, back.far, back.fps) == pytest.approx((0.25, 9000.0, 30.0), rel=1e-7)
    for f in range(1, 6):
        a, b = camera_at(cfg.camera, f), camera_at(back, f)
        np.testing.assert_allclose(b.position, a.position, atol=1e-9)
        np.testing.assert_allclose(b.target, a.target, atol=1e-4)  # via focusDistance, a float
        assert b.fov == pytest.approx(a.fov, rel=1e-6)
    assert back.keys[0].focal_length == pytest.approx(35.0, rel=1e-6)
    assert back.keys[-1].focal_length == pytest.approx(70.0, rel=1e-6)
    # the stage's camera carries the lens the scene file gave, in millimetres
    stage = Usd.Stage.Open(str(res.path))
    cam = UsdGeom.Camera(stage.GetPrimAtPath("/World/Camera"))
    assert cam.GetFocalLengthAttr().Get(1) == pytest.approx(35.0, rel=1e-6)
    assert cam.GetVerticalApertureAttr().Get() == pytest.approx(24.89 * 48 / 64, rel=1e-6)


def test_a_still_export_round_trips_its_focal_length(tmp_path):
    from forest.export.usd import export_usd
    from forest.scene import load_scene

    from export_support import SCENE, FakeLibrary, make_instances

    text = SCENE.replace("fov = 50.0\n", "focal_length = 50.0\n") + "terrain_colour = [0.2, 0.18, 0.12]\n"
    cfg = parse_config(text, path=tmp_path / "scene.toml")
    export_usd(load_scene(cfg, make_instances(20), library=FakeLibrary()), tmp_path / "still.usdc")
    back = load(tmp_path, 'usd = "still.usdc"\n').camera
    assert back.keys == [] and back.focal_length == 50.0 and back.sensor_width == 36.0
    assert back.fov == pytest.approx(math.degrees(2 * math.atan(36 / 100)), rel=1e-12)
    np.testing.assert_allclose(back.position, cfg.camera.position, atol=1e-9)
    np.testing.assert_allclose(back.target, cfg.camera.target, atol=1e-4)


def test_a_rolling_camera_is_taken_with_a_warning(tmp_path):
    from forest.errors import ForestWarning

    stage = Usd.Stage.CreateNew(str(tmp_path / "roll.usda"))
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    op = UsdGeom.Camera.Define(stage, "/cam").AddTransformOp()
    level = np.array(usd_matrix((0.0, 2.0, 0.0), (0.0, 2.0, 10.0))).T
    for frame, degrees in ((1, 0.0), (10, 30.0)):
        c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
        roll = np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])  # about the view axis
        op.Set(Gf.Matrix4d((level @ roll).T.tolist()), Usd.TimeCode(frame))
    stage.GetRootLayer().Save()
    with pytest.warns(ForestWarning, match="roll.usda: the camera's roll changes over the shot"):
        cam = load(tmp_path, 'usd = "roll.usda"\n').camera
    assert cam.up == pytest.approx((0.0, 1.0, 0.0)) and [k.frame for k in cam.keys] == [1.0, 10.0]


def test_a_camera_under_a_payload_is_read_when_named(tmp_path):
    inner = Usd.Stage.CreateNew(str(tmp_path / "cam.usda"))
    UsdGeom.SetStageMetersPerUnit(inner, 1.0)
    cam = UsdGeom.Camera.Define(inner, "/cam")
    cam.AddTranslateOp().Set(Gf.Vec3d(1.0, 2.0, 3.0))
    inner.SetDefaultPrim(cam.GetPrim())
    inner.GetRootLayer().Save()
    outer = Usd.Stage.CreateNew(str(tmp_path / "shot.usda"))
    UsdGeom.SetStageMetersPerUnit(outer, 1.0)
    outer.DefinePrim("/World/cam").GetPayloads().AddPayload("cam.usda")
    outer.GetRootLayer().Save()
    assert load(tmp_path, 'usd = "shot.usda"\nusd_camera = "/World/cam"\n').camera.position == (1.0, 2.0, 3.0)
    with pytest.raises(ConfigError, match=r"no UsdGeom\.Camera loaded .*when usd_camera names it"):
        load(tmp_path, 'usd = "shot.usda"\n')
