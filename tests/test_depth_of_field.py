"""``[camera] f_stop``: thin-lens depth of field in forest_path and scalar_rgb, its exports, and its mistakes.

The scene: a camera 0.15 m above a white ground under a white constant sky (so the ground and the horizon
vanish: a white Lambertian plane under a uniform sky has the sky's radiance), a small dark box at the focus
distance (5 m) and a large one far behind it (50 m), both seen side by side by a 200 mm lens.  At f/1.4 the
lens radius is 0.2 / 2.8 = 71 mm and the far box's circle of confusion about 4.6 pixels of 32.
"""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest
from test_render import trees

from forest.camera import camera_at
from forest.config import ConfigError, parse_config
from forest.render import render_scene
from forest.scene import load_scene

from render_fixtures import BoxLibrary

ROOT = Path(__file__).resolve().parents[1]

SCENE = """
seed = 3
[terrain]
flat = {{ size = 200.0 }}
[camera]
position = [0.0, 0.15, 0.0]
target = [0.0, 0.15, 5.0]
focal_length = 200.0
{lens}
[lights]
sky = {{ radiance = 0.5, colour = [1.0, 1.0, 1.0] }}
[render]
width = 32
height = 18
spp = {spp}
terrain_colour = [1.0, 1.0, 1.0]
[[species]]
model = "box"
percent = 100
[lod]
auto = false
"""
NEAR, FAR = 100, 101  # InstanceSet ids of the box in focus (5 m) and the one far behind (50 m)


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    return BoxLibrary(tmp_path_factory.mktemp("boxlib"))


def two_boxes():
    inst = trees([[-0.2, 0.0, 5.0], [2.0, 0.0, 50.0]])
    inst.scale[:] = [0.05, 0.5]  # 0.1 × 0.3 m and 1 × 3 m: about 4 × 10 pixels each
    inst.tint[:] = 0.1  # dark boxes on the white ground and sky
    return inst


def render(tmp_path: Path, library, name: str, lens: str = "", variant: str = "llvm_ad_rgb", spp: int = 16) -> Path:
    folder = tmp_path / name  # one file name for all: the EXR header names the config
    folder.mkdir()
    cfg = parse_config(SCENE.format(lens=lens, spp=spp), path=folder / "scene.toml", base_dir=folder)
    out = folder / "scene.exr"
    render_scene(load_scene(cfg, two_boxes(), library=library), output=out, variant=variant)
    return out


def read(path: Path) -> dict[str, np.ndarray]:
    inp = oiio.ImageInput.open(str(path))
    spec = inp.spec()
    data = np.asarray(inp.read_image(0, 0, 0, spec.nchannels, "float")).reshape(spec.height, spec.width, -1)
    names = list(spec.channelnames)
    inp.close()
    return {n: data[..., i] for i, n in enumerate(names)}


def edge_energy(image: dict[str, np.ndarray], box: int, ids: np.ndarray) -> float:
    """Σ (∂L/∂x)² of the box's rows averaged into one profile (less noise), over its columns ± 6 pixels."""
    rows = (ids == box).any(axis=1)
    cols = np.nonzero((ids == box).any(axis=0))[0]
    lum = (image["R"] + image["G"] + image["B"]) / 3.0
    profile = lum[rows].mean(axis=0)[max(cols.min() - 6, 0) : cols.max() + 7]
    return float((np.diff(profile) ** 2).sum())


def test_a_pinhole_render_is_byte_identical_with_the_lens_fields_given(tmp_path, library):
    """Without f_stop no lens sample is drawn: a focus setting alone changes no byte (nor the ray, r = 0)."""
    plain = render(tmp_path, library, "plain", spp=4)
    focused = render(tmp_path, library, "focused", "focus_distance = 7.0", spp=4)
    on = render(tmp_path, library, "on", "focus_on = [0.0, 0.0, 30.0]", spp=4)
    assert plain.read_bytes() == focused.read_bytes() == on.read_bytes()
    assert plain.with_suffix(".png").read_bytes() == focused.with_suffix(".png").read_bytes()


def test_thin_lens_rays_of_radius_zero_are_the_pinhole_rays_and_meet_on_the_focus_plane():
    import mitsuba as mi

    mi.set_variant("llvm_ad_rgb")
    import drjit as dr

    from forest.camera import look_at_matrix
    from forest.render.path.inputs import PathCamera
    from forest.render.path.lens import thin_lens_rays

    m = look_at_matrix([1.0, 2.0, 3.0], [4.0, 1.0, 9.0], [0.0, 1.0, 0.0])
    cam = PathCamera(m, 30.0, 8, 8, near=0.5, far=1000.0, lens_radius=0.05, focus_distance=6.0)
    sensor = mi.load_dict({"type": "perspective", "fov": 30.0, "fov_axis": "x", "near_clip": 0.5,
                           "far_clip": 1000.0, "to_world": mi.ScalarTransform4f(m),
                           "film": {"type": "hdrfilm", "width": 8, "height": 8}})  # fmt: skip
    pos = mi.Point2f(dr.linspace(mi.Float, 0.05, 0.95, 16), dr.linspace(mi.Float, 0.9, 0.1, 16))
    pin, _ = sensor.sample_ray(0.0, 0.5, pos, mi.Point2f(0.5, 0.5))
    same = thin_lens_rays(mi, PathCamera(m, 30.0, 8, 8, near=0.5, far=1000.0), pin, mi.Point2f(0.9, 0.1))
    assert np.allclose(np.asarray(same.d), np.asarray(pin.d), atol=1e-6)
    assert np.allclose(np.asarray(same.o), np.asarray(pin.o), atol=1e-5)
    axis = m[:3, 2]
    hits = []
    for u in ([0.1, 0.2], [0.9, 0.7], [0.5, 0.99]):
        ray = thin_lens_rays(mi, cam, pin, mi.Point2f(*u))
        o, d = np.asarray(ray.o, np.float64).T, np.asarray(ray.d, np.float64).T
        lens = o - d * (0.5 / (d @ axis))[:, None]  # back to the lens plane
        assert np.allclose((lens - m[:3, 3]) @ axis, 0.0, atol=1e-5)
        assert (np.linalg.norm(lens - m[:3, 3], axis=1) <= 0.05 + 1e-6).all()
        t = (6.0 - (o - m[:3, 3]) @ axis) / (d @ axis)
        hits.append(o + d * t[:, None])
    # every lens point's ray through one film point meets the others on the plane in focus
    assert np.allclose(hits[0], hits[1], atol=1e-4) and np.allclose(hits[0], hits[2], atol=1e-4)


@pytest.mark.parametrize("variant", ["llvm_ad_rgb", "scalar_rgb"])
def test_in_focus_stays_sharp_and_far_blurs(tmp_path, library, variant):
    """f/1.4 focused on the near box (the target, 5 m): its edges keep their energy, the far box's lose most."""
    pin = read(render(tmp_path, library, "pin", variant=variant))
    dof = read(render(tmp_path, library, "dof", "f_stop = 1.4", variant=variant))
    ids = pin["id.Z"]
    assert (ids == NEAR).any() and (ids == FAR).any()
    near = edge_energy(dof, NEAR, ids) / edge_energy(pin, NEAR, ids)
    far = edge_energy(dof, FAR, ids) / edge_energy(pin, FAR, ids)
    print(f"{variant}: edge energy kept, near {near:.2f}, far {far:.2f}")
    assert near > 0.6 and far < 0.35 and far < 0.4 * near
    # the pixel-centre layers stay the pinhole's: depth and ids from the ray through each pixel centre
    assert np.array_equal(dof["id.Z"], ids) and np.array_equal(dof["depth.Z"], pin["depth.Z"])
    # focused on the far box instead, the roles swap
    back = read(render(tmp_path, library, "back", "f_stop = 1.4\nfocus_on = [2.0, 1.5, 50.0]", variant=variant))
    assert edge_energy(back, FAR, ids) / edge_energy(pin, FAR, ids) > 0.6
    assert edge_energy(back, NEAR, ids) / edge_energy(pin, NEAR, ids) < 0.35


def lens_camera(lens: str, keys: str = ""):
    return parse_config(SCENE.format(lens=lens, spp=1) + keys).camera


def test_lens_radius_and_focus_distance():
    cam = camera_at(lens_camera("f_stop = 2.8"), 1)
    assert cam.lens_radius == pytest.approx(0.2 / 5.6, rel=1e-12)  # r = f / (2N), f = 200 mm
    assert cam.focus_distance == pytest.approx(5.0) and cam.depth_of_field  # default: on the target
    assert camera_at(lens_camera("f_stop = 2.8\nfocus_distance = 12.5"), 1).focus_distance == 12.5
    # focus_on: the point's depth along the view axis (+z here), not its distance
    assert camera_at(lens_camera("f_stop = 2.8\nfocus_on = [3.0, 4.0, 20.0]"), 1).focus_distance == 20.0
    pin = camera_at(lens_camera(""), 1)
    assert pin.lens_radius == 0.0 and not pin.depth_of_field and pin.f_stop is None
    # a fov-only lens: f from the fov on sensor_width (36 mm, 40°: 49.45 mm)
    text = SCENE.format(lens="f_stop = 2.0", spp=1).replace("focal_length = 200.0", "fov = 40.0")
    f = 18.0 / math.tan(math.radians(20.0))
    assert camera_at(parse_config(text).camera, 1).lens_radius == pytest.approx(f / 1000 / 4.0, rel=1e-12)


def test_keys_pull_focus_and_aperture_linearly():
    keys = """
[[camera.keys]]
frame = 1
position = [0.0, 0.15, 0.0]
target = [0.0, 0.15, 5.0]
focus_distance = 4.0
[[camera.keys]]
frame = 11
position = [0.0, 0.15, 0.0]
target = [0.0, 0.15, 5.0]
focus_distance = 24.0
f_stop = 8.0
"""
    cam = lens_camera("f_stop = 2.0", keys)
    mid = camera_at(cam, 6)
    assert mid.focus_distance == pytest.approx(14.0) and mid.f_stop == pytest.approx(5.0)
    assert camera_at(cam, 0).focus_distance == 4.0 and camera_at(cam, 20).f_stop == 8.0


def test_usd_round_trip_of_f_stop_and_focus_distance(tmp_path):
    from pxr import Usd, UsdGeom

    from forest.config.schema import CameraConfig
    from forest.export.usd import export_usd

    text = SCENE.format(lens="f_stop = 2.8\nfocus_distance = 7.5", spp=1)
    text = text.replace('model = "box"', 'model = "fern"')
    cfg = parse_config(text + "[scatter]\ncount = 3\n", path=tmp_path / "s.toml", base_dir=tmp_path)
    out = tmp_path / "shot.usda"
    export_usd(load_scene(cfg), out)
    stage = Usd.Stage.Open(str(out))
    cam = UsdGeom.Camera(next(p for p in stage.Traverse() if p.IsA(UsdGeom.Camera)))
    assert cam.GetFStopAttr().Get() == pytest.approx(2.8)
    assert cam.GetFocusDistanceAttr().Get() == pytest.approx(7.5)
    assert cam.GetFocalLengthAttr().Get() == pytest.approx(200.0)  # mm, as forest writes and reads it
    back = CameraConfig.model_validate({"usd": str(stage.GetRootLayer().realPath)})
    state = camera_at(back, 1)
    assert back.f_stop == pytest.approx(2.8)
    assert state.focus_distance == pytest.approx(7.5, rel=1e-6)
    assert state.lens_radius == pytest.approx(camera_at(cfg.camera, 1).lens_radius, rel=1e-6)


def test_rib_writes_depth_of_field_in_scene_units():
    from forest.export.rib import rib_options, scene_text

    cfg = parse_config(SCENE.format(lens="f_stop = 2.8\nfocus_distance = 7.5", spp=1))
    text = scene_text(cfg, 1, [], rib_options(cfg, renderman22=False))
    assert "  DepthOfField 2.8 0.2 7.5" in text.splitlines()
    plain = parse_config(SCENE.format(lens="", spp=1))
    assert "DepthOfField" not in scene_text(plain, 1, [], rib_options(plain, renderman22=False))


@pytest.mark.parametrize(
    "lens, field, words",
    [
        ("f_stop = 0.0", "camera.f_stop", "must be >= 0.7"),
        ("f_stop = 1000.0", "camera.f_stop", "must be <= 256"),
        ("f_stop = 2.8\nfocus_distance = -1.0", "camera.focus_distance", "must be > 0"),
        ("f_stop = 2.8\nfocus_distance = 5.0\nfocus_on = [0.0, 0.0, 9.0]", "camera.focus_on",
         "give focus_distance or focus_on, not both"),
        ("f_stop = 2.8\nfocus_on = [0.0, 0.0, -9.0]", "camera.focus_on", "behind the camera"),
    ],
)  # fmt: skip
def test_bad_lens_values_name_the_field(lens, field, words):
    with pytest.raises(ConfigError) as e:
        parse_config(SCENE.format(lens=lens, spp=1))
    assert e.value.field == field and words in e.value.message, str(e.value)


def test_a_keyed_aperture_on_a_pinhole_is_refused():
    keys = "[[camera.keys]]\nframe = 1\nposition = [0.0, 0.15, 0.0]\ntarget = [0.0, 0.15, 5.0]\nf_stop = 4.0\n"
    with pytest.raises(ConfigError) as e:
        lens_camera("", keys)
    assert e.value.field == "camera.keys[0].f_stop" and "give [camera] f_stop too" in e.value.message


def test_the_cli_refuses_a_bad_f_stop_in_one_line(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(SCENE.format(lens="f_stop = 0.1", spp=1))
    r = subprocess.run(
        [sys.executable, "-m", "forest.cli", "render", str(bad), "-o", str(tmp_path / "bad.exr"), "-q"],
        capture_output=True, text=True, cwd=ROOT, timeout=120,
    )  # fmt: skip
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert r.stderr.startswith(f"forest: error: {bad}: camera.f_stop: ") and not (tmp_path / "bad.exr").exists()


def test_blender_manifest_carries_the_lens(tmp_path, library):
    from forest.export.blender import write_manifest

    cfg = parse_config(SCENE.format(lens="f_stop = 2.8\nfocus_distance = 7.5", spp=1))
    got = write_manifest(load_scene(cfg, two_boxes(), library=library), tmp_path, [1])
    key = got["camera"]["keys"][0]
    assert key["dof"] == {"f_stop": 2.8, "focus_distance": 7.5}
    assert key["lens"] == pytest.approx(200.0) and got["camera"]["sensor_width"] == 36.0  # radius lens / (2N)
    plain = parse_config(SCENE.format(lens="", spp=1))
    assert (
        "dof" not in write_manifest(load_scene(plain, two_boxes(), library=library), tmp_path, [1])["camera"]["keys"][0]
    )
