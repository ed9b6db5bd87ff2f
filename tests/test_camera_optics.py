"""``[camera] focal_length`` and ``sensor_width``: the lens a pipeline gives, turned into the horizontal fov every
backend reads — the render's EXR header, the RIB projection, the camera path — and the mistakes refused."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import OpenImageIO as oiio
import pytest

from forest.camera import camera_at
from forest.config import ConfigError, parse_config
from forest.config.schema import focal_length_from_fov, fov_from_focal_length

ROOT = Path(__file__).resolve().parents[1]

BASE = """
seed = 5
[terrain]
flat = { size = 60.0 }
[scatter]
count = 20
[[species]]
model = "fern"
percent = 100
[render]
width = 24
height = 16
spp = 1
"""

KEYS = """
[[camera.keys]]
frame = 1
position = [0.0, 10.0, -50.0]
target = [0.0, 0.0, 0.0]
[[camera.keys]]
frame = 11
position = [0.0, 10.0, -40.0]
target = [0.0, 0.0, 0.0]
focal_length = 100.0
"""


def config(camera: str, extra: str = ""):
    return parse_config(BASE + "[camera]\n" + camera + extra)


def test_50mm_on_full_frame_is_39_6_degrees():
    cam = config("focal_length = 50.0\n").camera
    assert cam.sensor_width == 36.0  # full frame unless given
    assert cam.fov == pytest.approx(39.5978, abs=1e-4)
    assert camera_at(cam, 1).fov == cam.fov
    # Super 35 (24.89 mm): the same lens sees less
    s35 = config("focal_length = 50.0\nsensor_width = 24.89\n").camera
    assert s35.fov == pytest.approx(math.degrees(2 * math.atan(24.89 / 100)), rel=1e-12)
    assert focal_length_from_fov(s35.fov, 24.89) == pytest.approx(50.0, rel=1e-12)


def test_a_zoom_keyed_in_focal_length_moves_linearly_in_millimetres():
    cam = config("focal_length = 24.0\n", KEYS).camera
    assert cam.keys[0].focal_length == 24.0  # a key without a lens takes the camera's
    assert camera_at(cam, 1).fov == pytest.approx(fov_from_focal_length(24.0, 36.0), rel=1e-12)
    assert camera_at(cam, 6).fov == pytest.approx(fov_from_focal_length(62.0, 36.0), rel=1e-12)
    assert camera_at(cam, 11).fov == pytest.approx(20.4079, abs=1e-4)
    # a key with a fov interpolates in degrees, as before
    fov_keys = config("fov = 60.0\n", KEYS.replace("focal_length = 100.0", "fov = 20.0")).camera
    assert camera_at(fov_keys, 6).fov == pytest.approx(40.0, rel=1e-12)


@pytest.mark.parametrize(
    "camera, extra, field, words",
    [
        ("fov = 40.0\nfocal_length = 50.0\n", "", "camera.focal_length", "give fov or focal_length, not both"),
        ("", KEYS.replace("focal_length = 100.0", "focal_length = 100.0\nfov = 30.0"), "camera.keys[1].focal_length",
         "give fov or focal_length, not both"),
        ("focal_length = 0.0\n", "", "camera.focal_length", "must be >= 0.1"),
        ("focal_length = 20000.0\n", "", "camera.focal_length", "must be <= 10000"),
        ("sensor_width = -36.0\n", "", "camera.sensor_width", "must be >= 0.1"),
        ("focal_length = 0.12\n", "", "camera.focal_length", "0.12 mm on a 36 mm sensor_width gives a 179.2°"),
        ("focal_length = 9000.0\nsensor_width = 1.0\n", "", "camera.focal_length", "field of view; it must be 0.1–179°"),
    ],
)  # fmt: skip
def test_lens_mistakes_name_the_field(camera, extra, field, words):
    with pytest.raises(ConfigError) as e:
        config(camera, extra)
    assert e.value.field == field and words in e.value.message, str(e.value)


def test_rib_projection_follows_the_focal_length():
    from forest.export.rib import ri_fov, rib_options, scene_text

    cfg = config("focal_length = 50.0\n", "")
    text = scene_text(cfg, 1, [], rib_options(cfg, renderman22=False))
    want = ri_fov(fov_from_focal_length(50.0, 36.0), 24, 16)  # the shorter side's fov, from the derived one
    line = next(line for line in text.splitlines() if "Projection" in line)
    assert float(line.split("[")[1].rstrip("]")) == pytest.approx(want, rel=1e-6)
    assert "# lens: 50 mm on a 36 mm filmback, horizontal fov 39.5978 deg" in text


def run(*args):
    cmd = [sys.executable, "-m", "forest.cli", *map(str, args)]
    return subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=300)


def test_render_header_carries_the_derived_fov_and_both_given_is_one_line(tmp_path):
    bad = tmp_path / "both.toml"
    bad.write_text(BASE + "[camera]\nfov = 40.0\nfocal_length = 50.0\n")
    r = run("render", bad, "-o", tmp_path / "bad.exr", "-q")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert (
        r.stderr.strip() == f"forest: error: {bad}: camera.focal_length: give fov or focal_length, not both (fov = 40)"
    )
    assert not (tmp_path / "bad.exr").exists()

    good = tmp_path / "lens.toml"
    good.write_text(BASE + "[camera]\nposition = [0.0, 8.0, -30.0]\ntarget = [0.0, 0.0, 0.0]\nfocal_length = 50.0\n")
    r = run("render", good, "-o", tmp_path / "lens.exr", "-q")  # scatters its 20 ferns first
    assert r.returncode == 0, r.stderr
    spec = oiio.ImageInput.open(str(tmp_path / "lens.exr")).spec()
    assert float(spec.getattribute("forest:fov")) == pytest.approx(39.5978, abs=1e-4)


def test_with_keys_every_frame_takes_the_keys_pose():
    """With keys every frame's pose comes from them, a still's too: a [camera] position left in the file from a
    still camera does not move frame 1 (files that have both keep rendering as before)."""
    keyed = config("position = [5.0, 10.0, -50.0]\ntarget = [0.0, 0.0, 0.0]\n", KEYS)
    assert tuple(camera_at(keyed.camera, 1.0).position) == (0.0, 10.0, -50.0)
    still = config("position = [5.0, 10.0, -50.0]\ntarget = [0.0, 0.0, 0.0]\n")
    assert tuple(camera_at(still.camera, 1.0).position) == (5.0, 10.0, -50.0)


def test_set_camera_position_on_a_keyed_scene_is_one_line_before_any_work(tmp_path, capsys):
    """`--set camera.position=…` on the demo (which has keys) changed nothing, silently: it is refused in one line
    naming the flag, before any work, and nothing is written; with `camera.keys=[]` it is the camera."""
    from conftest import run

    out = tmp_path / "x.exr"
    argv = ["render", str(ROOT / "configs" / "demo.toml"), "--preview", "-o", str(out)]
    assert run([*argv, "--set", "camera.position=[5.0, 75.0, -295.0]"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("forest: error: --set camera.position: is not used"), err
    assert not out.exists()
    # The first key's own pose is not a change; clearing the keys makes the position the camera.
    from forest.commands import load_with_flags

    demo = ROOT / "configs" / "demo.toml"
    assert load_with_flags(demo, {}, ["camera.position=[30.0, 80.0, -285.0]"]).camera.keys
    cfg = load_with_flags(demo, {}, ["camera.position=[5.0, 75.0, -295.0]", "camera.keys=[]"])
    assert tuple(camera_at(cfg.camera, 1.0).position) == (5.0, 75.0, -295.0)
