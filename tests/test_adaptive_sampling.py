"""Adaptive sampling (``[render] noise_threshold``, ``min_spp``): the flat sky stops early, the trees take every
sample, the image stays within noise of the fixed-spp one, 0 changes nothing, same seed same bytes."""

from __future__ import annotations

import numpy as np
import OpenImageIO as oiio
import pytest
from test_render import trees

from forest.config import parse_config
from forest.errors import ConfigError
from forest.render import render_scene
from forest.render.adaptive import Convergence, dilate, relative_error, schedule
from forest.render.frame import FrameSize
from forest.render.loop import frame_seed
from forest.render.render import make_renderer
from forest.scene import load_scene

from render_fixtures import BoxLibrary

BASE = """
seed = 3
[terrain]
flat = {{ size = 100.0 }}
[camera]
position = [0.0, 4.0, -40.0]
target = [0.0, 4.0, 0.0]
fov = 40.0
[lights]
sun = {{ elevation = 35.0, azimuth = 40.0, irradiance = 3.0 }}
sky = {{ radiance = 0.5, colour = [0.6, 0.8, 1.0] }}
[render]
width = 32
height = 18
spp = {spp}
terrain_colour = [0.2, 0.2, 0.2]
aovs = {aovs}
{render}
[[species]]
model = "box"
percent = 100
[lod]
auto = false
"""
ADAPTIVE = "noise_threshold = 0.02\nmin_spp = 4"


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    return BoxLibrary(tmp_path_factory.mktemp("boxlib"))


def scene_of(tmp_path, library, render: str = "", spp: int = 16, aovs: str = "[]"):
    cfg = parse_config(BASE.format(spp=spp, render=render, aovs=aovs), path=tmp_path / "a.toml", base_dir=tmp_path)
    inst = trees([[x, 0.0, z] for x in (-6.0, 0.0, 6.0) for z in (-3.0, 3.0)], scale=1.0)
    return load_scene(cfg, inst, library=library)


def counts_and_image(scene, spp: int):
    """Per-pixel samples of the adaptive passes and the frame (llvm_ad_rgb, one sub-frame)."""
    r = make_renderer(scene, "llvm_ad_rgb", FrameSize(32, 18, spp, 1))
    counts = np.zeros(32 * 18)
    for p in r.samples(1.0, spp, frame_seed(scene.config, 1.0)):  # the frame's own passes
        counts += p.counts if getattr(p, "counts", None) is not None else p.spp
    return counts.reshape(18, 32), r.frame(1.0), r


def test_estimator_maths():
    # Samples 0 and 2 (mean 1, s² = 2): e = √(2/2)/(1 + ε); one sample: +inf; constant: 0.
    e = relative_error(np.array([2.0, 1.0, 3.0]), np.array([4.0, 1.0, 3.0]), np.array([2, 1, 3]))
    assert e[0] == pytest.approx(1.0 / 1.001) and e[1] == np.inf and e[2] == 0.0
    m = np.zeros((4, 5), bool)
    m[0, 0] = True
    assert dilate(m).sum() == 4 and dilate(m)[1, 1]
    assert schedule(32, 8) == [8, 8, 8, 8] and schedule(10, 4) == [4, 4, 2]
    c = Convergence(1, 3, 0.1)
    c.sum_y[:], c.sum_y2[:], c.count[:] = [4.0, 4.0, 4.0], [4.0, 4.0, 16.0], 4.0
    assert list(c.update()) == [1, 2]  # pixel 2 is noisy; its neighbour 1 goes on beside it, 0 stops
    c = Convergence(1, 4, 0.1)
    c.sum_y[:], c.sum_y2[:], c.count[:] = 4.0, [4.0, 4.0, 4.0, 16.0], 4.0
    assert list(c.update()) == [2, 3]


def test_sky_stops_early_and_trees_take_every_sample(tmp_path, library):
    counts, image, r = counts_and_image(scene_of(tmp_path, library, ADAPTIVE), 16)
    sky = dilate(image.alpha > 0) == 0  # no geometry within a pixel: flat constant sky
    sky &= ~dilate(~sky)
    assert sky.sum() > 50
    assert np.all(counts[sky] == 4)  # the flat sky stops after min_spp
    trees = image.id >= 0
    assert trees.sum() > 10 and np.median(counts[trees]) == 16  # the noisy boxes take the full spp
    assert 4 < r.samples_traced < 16
    assert r.stats()["samples_traced"] == pytest.approx(counts.mean(), abs=1e-3)  # the same passes


def test_within_noise_of_fixed_spp(tmp_path, library):
    _, adaptive, _ = counts_and_image(scene_of(tmp_path, library, ADAPTIVE), 16)
    _, fixed, _ = counts_and_image(scene_of(tmp_path, library), 16)
    a, f = np.asarray(adaptive.rgb, np.float64), np.asarray(fixed.rgb, np.float64)
    sky = adaptive.alpha == 0
    assert np.allclose(a[sky], f[sky], rtol=1e-5)  # a constant sky: exact whatever the samples
    assert abs(a.mean() / f.mean() - 1.0) < 0.03
    assert np.abs(adaptive.alpha - fixed.alpha).max() < 0.5


def test_threshold_zero_is_unchanged(tmp_path, library):
    scene = scene_of(tmp_path, library, "noise_threshold = 0.0")
    r = make_renderer(scene, "llvm_ad_rgb", FrameSize(32, 18, 8, 1))
    img = r.frame(1.0)
    # The frame as the loop made it before adaptive sampling: Σ of every pass's sums / Σ samples.
    rgb, n = np.zeros((32 * 18, 3)), 0
    for p in r.path.passes(r.path.inputs.camera, spp=8, seed=frame_seed(scene.config, 1.0)):
        rgb += p.rgb
        n += p.spp
    assert np.array_equal(img.rgb, (rgb / n).reshape(18, 32, 3).astype(np.float32))
    assert r.stats()["samples_traced"] == 8


def test_same_seed_same_bytes(tmp_path, library):
    out = []
    for k in range(2):
        res = render_scene(scene_of(tmp_path, library, ADAPTIVE), output=tmp_path / f"f{k}.exr", variant="llvm_ad_rgb")
        inp = oiio.ImageInput.open(str(res.paths[0]))
        spec = inp.spec()
        out.append(
            (np.asarray(inp.read_image(0, 0, 0, spec.nchannels, "float")), spec.getattribute("forest:samples_traced"))
        )
        inp.close()
    assert np.array_equal(out[0][0], out[1][0]) and out[0][1] == out[1][1] and 4 <= out[0][1] < 16


@pytest.mark.parametrize(
    ("text", "field"),
    [
        ("noise_threshold = -0.1", "render.noise_threshold"),
        ("noise_threshold = 1.5", "render.noise_threshold"),
        ("min_spp = 0", "render.min_spp"),
        ("min_spp = 32", "render.min_spp"),
    ],
)
def test_bad_values_refused_in_one_line(tmp_path, text, field):
    with pytest.raises(ConfigError) as e:
        parse_config(BASE.format(spp=16, render=text, aovs="[]"), path=tmp_path / "bad.toml", base_dir=tmp_path)
    msg = str(e.value)
    assert "\n" not in msg and "bad.toml" in msg and field in msg


def test_light_groups_sum_to_the_adaptive_beauty(tmp_path, library):
    scene = scene_of(tmp_path, library, ADAPTIVE, aovs='["lightgroups"]')
    r = make_renderer(scene, "llvm_ad_rgb", FrameSize(32, 18, 16, 1))
    img = r.frame(1.0)
    total = sum(np.asarray(img.aovs[f"lightgroup.{g}"], np.float64) for g in ("sun", "sky", "haze"))
    assert np.allclose(total, img.rgb, rtol=1e-4, atol=1e-6)


def test_subframes_are_each_adaptive(tmp_path, library):
    text = BASE.replace("fov = 40.0", "fov = 40.0\nshutter = 0.5")
    images = []
    for render in (ADAPTIVE + "\nsubframes = 2", "subframes = 2"):
        cfg = parse_config(text.format(spp=16, render=render, aovs="[]"), path=tmp_path / "m.toml", base_dir=tmp_path)
        inst = trees([[x, 0.0, z] for x in (-6.0, 0.0, 6.0) for z in (-3.0, 3.0)], scale=1.0)
        r = make_renderer(load_scene(cfg, inst, library=library), "llvm_ad_rgb", FrameSize(32, 18, 16, 2))
        images.append((np.asarray(r.frame(1.0).rgb, np.float64), r.samples_traced))
    (a, traced), (f, fixed) = images
    assert fixed == 16 and 8 < traced < 16  # 8 a sub-frame at most, 4 at least
    sky = np.all(a == a[0, 0], axis=-1)  # the constant sky's pixels
    assert sky.sum() > 50 and np.allclose(a[sky], f[sky], rtol=1e-5)
    assert abs(a.mean() / f.mean() - 1.0) < 0.03
