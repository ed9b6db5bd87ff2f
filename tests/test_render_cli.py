"""``forest render`` on the command line, with the real tree library: outputs, summary, exit codes."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest

ROOT = Path(__file__).resolve().parents[1]
FOREST = [sys.executable, "-m", "forest.cli"]

SCENE = """
seed = 11
[terrain]
procedural = {{ size = 80.0, height = 6.0, resolution = 33 }}
[scatter]
count = 60
[[species]]
model = "shrub"
percent = 60
scale = [2.0, 3.0]
[[species]]
model = "fern"
percent = 40
scale = [3.0, 4.0]
[camera]
position = [0.0, 30.0, -60.0]
target = [0.0, 0.0, 0.0]
fov = 45.0
[lights]
sun = {{ elevation = 40.0, azimuth = 150.0, irradiance = 3.0 }}
sky = {{ radiance = 0.4 }}
[render]
width = 32
height = 24
spp = 2
{render}
[lod]
distances = [40.0, 70.0, 100.0]
"""


def run(*args, cwd=None):
    return subprocess.run([*FOREST, *map(str, args)], capture_output=True, text=True, cwd=cwd or ROOT, timeout=300)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    d = tmp_path_factory.mktemp("cli")
    (d / "scene.toml").write_text(SCENE.format(render=""))
    r = run("scatter", d / "scene.toml", "-o", d / "trees.npz", "-q")
    assert r.returncode == 0, r.stderr
    return d


def test_render_still_writes_exr_png_and_summary(scene):
    r = run("render", scene / "scene.toml", "-o", scene / "out" / "still.exr", "--instances", scene / "trees.npz")
    assert r.returncode == 0, r.stderr
    assert "variant: llvm_ad_rgb" in r.stderr and "forest_path" in r.stderr
    summary = [line for line in r.stdout.splitlines() if line.startswith("rendered")]
    assert len(summary) == 1 and "trees" in summary[0] and "instanced triangles" in summary[0] and "peak" in summary[0]
    exr, png = scene / "out" / "still.exr", scene / "out" / "still.png"
    assert exr.stat().st_size > 0 and png.stat().st_size > 0
    inp = oiio.ImageInput.open(str(exr))
    spec = inp.spec()
    attrs = {a.name: a.value for a in spec.extra_attribs}
    data = np.asarray(inp.read_image(0, 0, 0, spec.nchannels, "float")).reshape(24, 32, -1)
    inp.close()
    assert attrs["forest:trees"] > 0 and attrs["forest:unique_triangles"] > 0
    species = data[..., list(spec.channelnames).index("species.Z")]
    assert set(np.unique(species).tolist()) <= {-1.0, 0.0, 1.0} and (species >= 0).any()
    assert np.isfinite(data).all()
    assert {"A", "CryptoObject00.R", "CryptoAsset00.R"} <= set(spec.channelnames)
    assert attrs["forest:view"] == "agx" and attrs["forest:renderer"] == "forest_path"


def test_render_frames_and_preview(scene):
    (scene / "anim.toml").write_text(
        SCENE.format(render="").replace(
            "fov = 45.0",
            "fov = 45.0\nkeys = [ { frame = 1, position = [0.0, 30.0, -60.0], target = [0.0, 0.0, 0.0] },"
            " { frame = 3, position = [20.0, 25.0, -50.0], target = [0.0, 0.0, 0.0] } ]",
        )
    )
    r = run(
        "render",
        scene / "anim.toml",
        "--frames",
        "1-3",
        "-o",
        scene / "seq" / "f_####.exr",
        "--instances",
        scene / "trees.npz",
        "-q",
    )
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in (scene / "seq").iterdir()) == [
        f"f_000{i}.{e}" for i in (1, 2, 3) for e in ("exr", "png")
    ]
    r = run("render", scene / "scene.toml", "--preview", "-o", scene / "prev.exr", "--instances", scene / "trees.npz")
    assert r.returncode == 0, r.stderr
    assert "preview:" in r.stdout


@pytest.mark.parametrize(
    "args, message",
    [
        (("-o", "{d}/bad.jpg"), ".exr"),
        (("-o", "{d}/bad.exr", "--variant", "metal"), "--variant"),
        (("-o", "{d}/bad.exr", "--variant", "cuda_ad_rgb"), "--variant: cuda_ad_rgb needs an NVIDIA GPU"),
        (("-o", "{d}/bad.exr", "--frames", "9-2"), "--frames"),
        (("-o", "{d}/bad.exr", "--instances", "{d}/missing.npz"), "missing.npz"),
    ],
)
def test_render_bad_input_exits_2_without_output(scene, args, message):
    args = [a.format(d=scene) for a in args]
    r = run(
        "render",
        scene / "scene.toml",
        *args,
        *(["--instances", scene / "trees.npz"] if "--instances" not in args else []),
    )
    assert r.returncode == 2, (r.stdout, r.stderr)
    assert message in r.stderr and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert not list(scene.glob("bad*"))


@pytest.mark.parametrize(
    "render, field, words",
    [
        ("max_depth = 0", "render.max_depth", ""),
        ('view = "acescc"', "render.view", "unknown view 'acescc'; use one of "),
        ("exposure = 12.0", "render.exposure", "out of range; use -10 to 10"),
        ('terrain_texture = "notes.txt"', "render.terrain_texture", "notes.txt"),
    ],
)
def test_render_bad_config_value(scene, render, field, words):
    if "notes.txt" in render:
        (scene / "notes.txt").write_text("not an image\n")
    (scene / "bad.toml").write_text(SCENE.format(render=render))
    r = run("render", scene / "bad.toml", "-o", scene / "bad.exr", "--instances", scene / "trees.npz")
    assert r.returncode == 2, r.stderr
    assert f"bad.toml: {field}: " in r.stderr and words in r.stderr and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert not (scene / "bad.exr").exists()


def test_real_library_renders_the_same_forest_in_both_variants(scene):
    """Library leaves (textured, alpha-cut, tinted, translucent) in llvm_ad_rgb (forest_path) and scalar_rgb."""
    from forest.config import load_config
    from forest.instances import InstanceSet
    from forest.render import render_scene

    cfg = load_config(scene / "scene.toml", overrides={"render.width": 24, "render.height": 16})
    inst = InstanceSet.load(scene / "trees.npz")
    inst = inst.subset(np.argsort(np.linalg.norm(inst.position - [0.0, 30.0, -60.0], axis=1))[:4])
    out = {}
    for variant in ("llvm_ad_rgb", "scalar_rgb"):
        from forest.scene import load_scene

        res = render_scene(load_scene(cfg, inst), output=scene / f"lib_{variant}.exr", variant=variant)
        assert res.leaf_model.startswith("forest_path" if variant == "llvm_ad_rgb" else "principledthin")
        inp = oiio.ImageInput.open(str(scene / f"lib_{variant}.exr"))
        spec = inp.spec()
        out[variant] = (
            np.asarray(inp.read_image(0, 0, 0, spec.nchannels, "float")).reshape(16, 24, -1),
            list(spec.channelnames),
        )
        inp.close()
    (a, names), (b, _) = out["llvm_ad_rgb"], out["scalar_rgb"]
    ida, idb = a[..., names.index("id.Z")], b[..., names.index("id.Z")]
    assert (ida >= 0).any() and (ida == idb).mean() > 0.95  # the same trees in the same pixels
    assert np.isfinite(a).all() and a[..., :3].mean() > 0


MANY = """
seed = 4
[terrain]
flat = {{ size = 400.0 }}
[scatter]
count = {count}
clumping = {{ strength = 0.0, clearings = 0.0 }}
[[species]]
model = "shrub"
percent = 100
[camera]
position = [0.0, 30.0, -220.0]
target = [0.0, 0.0, 0.0]
fov = 45.0
[render]
width = 32
height = 24
spp = 2
[lod]
distances = {lod}
"""


def test_render_too_many_trees_for_memory_fails_before_rendering(tmp_path):
    """llvm_ad_rgb: trees that stay instances need ~16 KB each; with every tree an instance and the memory
    stated by $FOREST_MEMORY_GB, the render stops before rendering: one line naming scatter.count, how many
    trees fit, exit 2, nothing written.  With the far level near (most trees merged) the same count fits."""
    import os

    cfg = tmp_path / "many.toml"
    cfg.write_text(MANY.format(count=40_000, lod="[1000.0, 2000.0, 3000.0]"))
    env = {**os.environ, "FOREST_MEMORY_GB": "0.9"}
    out = tmp_path / "many.exr"
    r = subprocess.run(
        [*FOREST, "render", cfg, "-o", out, "--variant", "llvm_ad_rgb"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=300,
        env=env,
    )
    assert r.returncode == 2, (r.stdout, r.stderr)
    lines = [line for line in r.stderr.strip().splitlines() if line.strip()]
    error = lines[-1]
    assert "many.toml: scatter.count: " in error and "40,000 trees" in error and "Traceback" not in r.stderr
    fit = int(error.split("about ")[-1].split(" trees fit")[0].replace(",", ""))
    assert 1_000 < fit < 40_000  # (0.9 GiB − 0.3 GB base − 0.24 GB for 4 shrubs × 4 levels) / ~16.4 KB ≈ 25 000
    assert "[lod] distances" in error
    assert not out.exists() and not out.with_suffix(".png").exists()
    assert not any(line.startswith("rendered") for line in r.stdout.splitlines())


def test_far_plan_counts_the_trees_forest_path_merges(scene):
    """The pre-flight's far-level count is what forest_path's geometry then merges (its own statistics)."""
    from forest.config import load_config
    from forest.instances import InstanceSet
    from forest.preflight import render_memory
    from forest.render.path import PathScene
    from forest.render.path.from_scene import far_plan, path_inputs
    from forest.scene import load_scene

    cfg = load_config(scene / "scene.toml")
    sc = load_scene(cfg, InstanceSet.load(scene / "trees.npz"))
    far, far_tri = far_plan(sc, [1.0])
    built = PathScene(path_inputs(sc, width=8, height=6, spp=1), "llvm_ad_rgb")
    assert 0 < far < len(sc.instances)
    assert (far, far_tri) == (built.stats.flattened_trees, built.stats.flattened_triangles)
    assert built.stats.instances == len(sc.instances) - far
    n = len(sc.instances)
    merged = render_memory(64, 36, 1, n, "llvm_ad_rgb", far_trees=far, far_triangles=far_tri)
    assert merged < render_memory(64, 36, 1, n, "llvm_ad_rgb")  # merged far trees cost less than instances


def test_a_tiny_render_does_not_set_the_time_forecast(tmp_path, monkeypatch):
    """A test-sized render's seconds per sample (mostly kernel compilation) must not become the machine's rate."""
    from forest import preflight

    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path))
    before = preflight.render_estimate(1920, 1080, 64, 130_000, "llvm_ad_rgb")
    preflight.record_render("llvm_ad_rgb", samples=32 * 24 * 2, trees=60, render_seconds=3.0, load_seconds=1.0)
    after = preflight.render_estimate(1920, 1080, 64, 130_000, "llvm_ad_rgb")
    assert not after.measured and after.seconds == before.seconds
    preflight.record_render("llvm_ad_rgb", samples=480 * 270 * 64, trees=130_000, render_seconds=40.0, load_seconds=8)
    assert preflight.render_estimate(1920, 1080, 64, 130_000, "llvm_ad_rgb").measured
    preflight.record_render("llvm_ad_rgb", samples=32 * 24 * 2, trees=60, render_seconds=3.0, load_seconds=1.0)
    assert preflight.render_estimate(1920, 1080, 64, 130_000, "llvm_ad_rgb").measured  # the real render's rate kept


def test_a_camera_under_the_terrain_is_warned_about(scene):
    cfg = scene / "under.toml"
    cfg.write_text(SCENE.format(render="").replace("position = [0.0, 30.0, -60.0]", "position = [0.0, -20.0, -30.0]"))
    r = run("render", cfg, "--instances", scene / "trees.npz", "-o", scene / "under.exr", "-q")
    assert r.returncode == 0, r.stderr
    warning = [line for line in r.stderr.splitlines() if line.startswith("warning:")]
    assert len(warning) == 1 and "below the terrain" in warning[0] and "raise [camera] position" in warning[0]
    r = run("render", scene / "scene.toml", "--instances", scene / "trees.npz", "-o", scene / "over.exr", "-q")
    assert r.returncode == 0 and "warning" not in r.stderr


def test_under_ground_checks_every_frame_of_a_keyed_path():
    from forest.camera import under_ground
    from forest.config import CameraConfig

    cam = CameraConfig.model_validate(
        {"keys": [{"frame": 1, "position": [0, 10, 0], "target": [0, 0, 50]},
                  {"frame": 11, "position": [0, -10, 100], "target": [0, 0, 150]}]}
    )  # fmt: skip
    flat = lambda x, z: np.zeros_like(x)  # noqa: E731 - the ground at y = 0
    line = under_ground(cam, flat, range(1, 12))
    assert line is not None and "under the terrain at 5 of 11 frames checked, first at frame 7" in line
    assert "raise [camera] keys" in line
    assert under_ground(cam, flat, range(1, 6)) is None


def test_height_above_ground_stands_the_camera_on_the_terrain(scene):
    """``[camera] height_above_ground`` puts the camera (still and keys) that high above the ground under it, for
    the render and every backend that reads the Scene's camera."""
    from forest.config import load_config
    from forest.scene import load_scene

    text = SCENE.format(render="").replace("position = [0.0, 30.0, -60.0]", "position = [5.0, -50.0, -20.0]")
    cfg = scene / "eye.toml"
    cfg.write_text(text.replace("fov = 45.0", "fov = 45.0\nheight_above_ground = 1.7"))
    r = run("render", cfg, "--instances", scene / "trees.npz", "-o", scene / "eye.exr", "-q")
    assert r.returncode == 0 and "warning" not in r.stderr, r.stderr
    s = load_scene(load_config(cfg), scene / "trees.npz")
    ground = float(s.terrain.height_at(5.0, -20.0)[0])
    np.testing.assert_allclose(s.camera_at(1.0).position, [5.0, ground + 1.7, -20.0], atol=1e-9)
    header = oiio.ImageInput.open(str(scene / "eye.exr")).spec().getattribute("forest:camera_position")
    np.testing.assert_allclose([float(v) for v in header.split(",")], [5.0, ground + 1.7, -20.0], atol=1e-3)
    # keys too: each key's height comes from the ground under it
    keyed = text.replace("fov = 45.0", "fov = 45.0\nheight_above_ground = 2.0\nkeys = [{ frame = 1, position = "
                         "[-10.0, 0.0, -10.0], target = [0.0, 0.0, 0.0] }, { frame = 9, position = [10.0, 99.0, 10.0], "
                         "target = [0.0, 0.0, 0.0] }]")  # fmt: skip
    (scene / "keys.toml").write_text(keyed)
    k = load_scene(load_config(scene / "keys.toml"), scene / "trees.npz")
    for frame, (x, z) in ((1.0, (-10.0, -10.0)), (9.0, (10.0, 10.0))):
        np.testing.assert_allclose(k.camera_at(frame).position[1], float(k.terrain.height_at(x, z)[0]) + 2.0)


def test_the_summary_gives_the_gpus_peak_memory_in_cuda_only():
    from dataclasses import replace

    from forest.render.render import RenderResult, gpu_peak_gb

    assert gpu_peak_gb("llvm_ad_rgb") is None and gpu_peak_gb("scalar_rgb") is None
    r = RenderResult([], [1], "cuda_ad_rgb", "", 8, 6, 4, 1, 10, 100, 50, 1, 1.0, 2.0, 3.0)
    assert "peak 3.00 GiB;" not in r.summary() and r.summary().endswith("peak 3.00 GiB")
    assert replace(r, gpu_peak_gb=1.25).summary().endswith("peak 3.00 GiB (GPU 1.25 GiB)")


def test_render_denoise_cleans_a_final_frame_and_stays_deterministic(scene):
    """``[render] denoise = true``: the frame is denoised (header ``forest:denoised``), closer to a 64-spp render than
    the same samples left noisy, and the same bytes on a second run; ``"auto"`` denoises a 2-spp frame the same
    way (with Open Image Denoise installed) and leaves a 64-spp one alone."""
    from forest.imaging import oidn_available

    def frame(name: str, render: str, spp: int, denoised: bool) -> np.ndarray:
        cfg = scene / f"{name}.toml"
        cfg.write_text(SCENE.format(render=render).replace("width = 32\nheight = 24", "width = 64\nheight = 48"))
        r = run("render", cfg, "--instances", scene / "trees.npz", "-o", scene / f"{name}.exr", "--spp", spp)
        assert r.returncode == 0, r.stderr
        inp = oiio.ImageInput.open(str(scene / f"{name}.exr"))
        px = np.asarray(inp.read_image(0, 0, 0, 3, "float"))
        assert bool(inp.spec().getattribute("forest:denoised")) == denoised
        inp.close()
        return px

    ref = frame("ref", 'denoise = "auto"', 64, False)  # 64 spp > AUTO_MAX_SPP
    noisy = frame("noisy", "denoise = false", 2, False)
    clean = frame("clean", "denoise = true", 2, True)
    assert np.abs(clean - ref).mean() < 0.7 * np.abs(noisy - ref).mean()
    again = frame("clean2", "denoise = true", 2, True)
    assert np.array_equal(clean, again)
    assert (scene / "clean.exr").read_bytes() != (scene / "noisy.exr").read_bytes()
    auto = frame("auto", 'denoise = "auto"', 2, oidn_available())
    assert np.array_equal(auto, clean if oidn_available() else noisy)


def test_render_denoise_auto_without_open_image_denoise_is_silently_off(scene, monkeypatch):
    """``"auto"`` asks for nothing before work: without pyoidn the frame stays noisy, and the summary
    line says why; a value other than true, false or "auto" is refused naming the field."""
    import sys

    from forest.config import ConfigError, load_config
    from forest.render import render_scene
    from forest.render.scene import check_render_inputs
    from forest.scene import load_scene

    (scene / "dn_default.toml").write_text(SCENE.format(render=""))
    cfg = scene / "auto.toml"
    cfg.write_text(SCENE.format(render='denoise = "auto"'))
    config = load_config(cfg)
    assert config.render.denoise == "auto" and load_config(scene / "dn_default.toml").render.denoise is False
    monkeypatch.setitem(sys.modules, "pyoidn", None)  # as if the 'denoise' extra were not installed
    check_render_inputs(config)
    res = render_scene(load_scene(config, scene / "trees.npz"), output=scene / "auto.exr", variant="llvm_ad_rgb")
    assert not res.denoised
    assert res.summary().endswith("; not denoised (auto: Open Image Denoise (pyoidn) not installed)")
    bad = scene / "bad.toml"
    bad.write_text(SCENE.format(render='denoise = "sometimes"'))
    with pytest.raises(ConfigError) as e:
        load_config(bad)
    assert e.value.field == "render.denoise"


def test_render_denoise_without_open_image_denoise_is_refused_before_work(scene, monkeypatch):
    import sys

    from forest.config import ConfigError, load_config
    from forest.render.scene import check_render_inputs

    cfg = scene / "dn.toml"
    cfg.write_text(SCENE.format(render="denoise = true"))
    monkeypatch.setitem(sys.modules, "pyoidn", None)  # as if the 'denoise' extra were not installed
    with pytest.raises(ConfigError) as e:
        check_render_inputs(load_config(cfg))
    assert e.value.field == "render.denoise" and "pyoidn" in str(e.value)


def test_a_look_grades_the_png_and_leaves_the_exr_alone(scene):
    """``--set render.look=punchy``: a PNG that is the look of the (scene-linear) EXR — darker mid-tones than the
    plain view of the same EXR — and says so in its header; a look on another view stops before any work with
    exit 2 and no output."""
    out = scene / "look" / "punchy.exr"
    r = run("render", scene / "scene.toml", "-o", out, "--instances", scene / "trees.npz", "-q",
            "--set", "render.look=punchy")  # fmt: skip
    assert r.returncode == 0, r.stderr
    from forest.images import read_exr_channels, read_image
    from forest.imaging import to_display

    ch = read_exr_channels(out)[0]
    rgb = np.stack([ch[c] for c in "RGB"], axis=-1)
    png = read_image(out.with_suffix(".png"))[..., :3].astype(np.float64)  # sRGB code values, 0..1
    np.testing.assert_allclose(png, to_display(rgb, "agx", 0.0, "punchy"), atol=1.0 / 255 + 1e-6)
    assert png.mean() < to_display(rgb, "agx").mean() - 0.02
    inp = oiio.ImageInput.open(str(out.with_suffix(".png")))
    assert inp.spec().get_string_attribute("forest:look") == "punchy"
    inp.close()
    bad = scene / "look" / "bad.exr"
    r = run("render", scene / "scene.toml", "-o", bad, "--instances", scene / "trees.npz",
            "--set", "render.view=filmic", "--set", "render.look=punchy")  # fmt: skip
    assert r.returncode == 2 and not bad.exists() and not bad.with_suffix(".png").exists()
    assert r.stderr.strip().count("\n") == 0 and "render.look" in r.stderr and "grades the agx view" in r.stderr
