"""Comp AOVs (``[render] aovs``): light groups that sum to the beauty, N, P, albedo and motion vectors."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest
from scipy.ndimage import binary_dilation
from test_render import trees

from forest.config import parse_config
from forest.errors import ForestError
from forest.imaging import write_comp_exr
from forest.render import render_scene
from forest.scene import load_scene

from render_fixtures import BoxLibrary

BASE = """
seed = 3
[terrain]
flat = {{ size = 100.0 }}
[camera]
{camera}
[lights]
{lights}
[render]
width = 32
height = 18
spp = {spp}
terrain_colour = [0.2, 0.2, 0.2]
{render}
[[species]]
model = "box"
percent = 100
[lod]
auto = false
{extra}
"""
SIDE = "position = [0.0, 30.0, -60.0]\ntarget = [0.0, 0.0, 0.0]\nfov = 50.0"
TOP = "position = [0.0, 220.0, 0.0]\ntarget = [0.0, 0.0, 0.0]\nup = [0.0, 0.0, 1.0]\nfov = 28.0"
SUNSKY = "sun = { elevation = 35.0, azimuth = 40.0, irradiance = 3.0 }\nsky = { sunsky = {} }"
SKY = "sky = { radiance = 0.5, colour = [0.6, 0.8, 1.0] }"
DISC_SUN = "sun = { elevation = 35.0, azimuth = 40.0, irradiance = 3.0 }"
ALL = 'aovs = ["N", "P", "albedo", "motion", "lightgroups"]'
GROUPS = ("sun", "sky", "haze")


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    return BoxLibrary(tmp_path_factory.mktemp("boxlib"))


def read(path: Path) -> dict[str, np.ndarray]:
    inp = oiio.ImageInput.open(str(path))
    spec = inp.spec()
    data = np.asarray(inp.read_image(0, 0, 0, spec.nchannels, "float")).reshape(spec.height, spec.width, -1)
    names = list(spec.channelnames)
    inp.close()
    return {n: data[..., i] for i, n in enumerate(names)}


def layer(d: dict[str, np.ndarray], name: str, channels: str = "RGB") -> np.ndarray:
    prefix = "" if not name else name + "."
    return np.stack([d[prefix + c] for c in channels], axis=-1)


def render(tmp_path, library, name, *, camera=SIDE, lights=SUNSKY, render="", spp=8, extra="", inst=None, **kw):
    text = BASE.format(camera=camera, lights=lights, render=render, spp=spp, extra=extra)
    cfg = parse_config(text, path=tmp_path / f"{name}.toml", base_dir=tmp_path)
    inst = (
        inst if inst is not None else trees([[x, 0.0, z] for x in (-10.0, 0.0, 10.0) for z in (-5.0, 5.0)], scale=2.0)
    )
    kw.setdefault("variant", "llvm_ad_rgb")
    render_scene(load_scene(cfg, inst, library=library), output=tmp_path / f"{name}.exr", **kw)
    return cfg


def test_light_groups_sum_to_the_beauty_which_they_leave_unchanged(tmp_path, library):
    """Sun-sky and haze: sun + sky + haze = beauty to float rounding (the same samples), every group carries
    light, and the beauty is bit for bit the one rendered without AOVs.  N, P and albedo come along."""
    render(tmp_path, library, "plain", render="haze = 0.004\naovs = []")
    render(tmp_path, library, "aovs", render="haze = 0.004\n" + ALL)
    plain, out = read(tmp_path / "plain.exr"), read(tmp_path / "aovs.exr")
    assert not any(k.startswith(("lightgroup.", "N.", "P.", "albedo.", "forward.")) for k in plain)
    beauty = layer(out, "")
    np.testing.assert_array_equal(beauty, layer(plain, ""))
    parts = {g: layer(out, f"lightgroup.{g}") for g in GROUPS}
    np.testing.assert_allclose(sum(parts.values()), beauty, rtol=1e-5, atol=1e-7)
    for g, v in parts.items():
        assert v.min() >= 0.0 and v.mean() > 0.02 * beauty.mean(), g
    # N: unit normals where a surface is seen (everywhere: the ground runs to the horizon)
    n = layer(out, "N", "XYZ")
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0, atol=1e-5)
    # P: the pixel-centre hit, as far from the camera as depth.Z says
    p = layer(out, "P", "XYZ")
    np.testing.assert_allclose(np.linalg.norm(p - [0.0, 30.0, -60.0], axis=-1), out["depth.Z"], rtol=1e-4)
    tree = out["id.Z"] >= 0
    assert tree.any() and p[tree][:, 1].max() > 1.0 and np.abs(p[~tree][:, 1]).max() < 1e-3  # boxes stand up
    # albedo: the boxes' white against the grey ground
    albedo = layer(out, "albedo")
    assert albedo[tree].mean() > 2.0 * albedo[~tree].mean()
    # a still: no motion
    assert not layer(out, "forward", "uv").any()


def test_beauty_without_the_sun_is_the_sky_group(tmp_path, library):
    """An independent check of the split: turning the sun off renders (within noise) the sky group of the
    render with it."""
    render(tmp_path, library, "on", lights=DISC_SUN + "\n" + SKY, render='aovs = ["lightgroups"]', spp=32)
    render(tmp_path, library, "off", lights=SKY, render='aovs = ["lightgroups"]', spp=32)
    on, off = read(tmp_path / "on.exr"), read(tmp_path / "off.exr")
    sky, beauty_off = layer(on, "lightgroup.sky"), layer(off, "")
    assert layer(on, "lightgroup.sun").mean() > 0.5 * sky.mean()  # the sun matters here
    np.testing.assert_allclose(sky.mean(axis=(0, 1)), beauty_off.mean(axis=(0, 1)), rtol=0.01)
    assert np.abs(sky - beauty_off).mean() < 0.05 * beauty_off.mean()  # per pixel: noise only
    assert not layer(off, "lightgroup.sun").any() and not layer(off, "lightgroup.haze").any()


def test_haze_group_is_the_closed_form_in_scattering(tmp_path, library):
    """Uniform isotropic haze seen from 220 m, direct light only: at ground pixels the haze group is
    (1 − e^(−σd))·(C + E_sun/4π) and the sun group e^(−σd)·ρ·E_sun/π with ρ the albedo layer (d from depth.Z)."""
    haze = "haze = 0.004\nhaze_height = 100000.0\nhaze_anisotropy = 0.0\nhaze_colour = [0.3, 0.2, 0.1]\nmax_depth = 2\n"
    sun = "sun = { elevation = 90.0, azimuth = 0.0, irradiance = 3.0, colour = [1.0, 1.0, 1.0] }\n" + SKY
    render(tmp_path, library, "h", camera=TOP, lights=sun, render=haze + 'aovs = ["lightgroups", "albedo"]', spp=16)
    out = read(tmp_path / "h.exr")
    ground = ~binary_dilation(out["id.Z"] >= 0, iterations=2)
    assert ground.sum() > 300
    t = np.exp(-0.004 * out["depth.Z"][ground])[:, None]
    expected = (1.0 - t) * (np.array([0.3, 0.2, 0.1]) + 3.0 / (4.0 * math.pi))
    np.testing.assert_allclose(layer(out, "lightgroup.haze")[ground], expected, rtol=0.01)
    sun = t * layer(out, "albedo")[ground] * 3.0 / math.pi
    # the sun group is noisy per pixel (next-event estimation picks the sun or the sky): compare the means
    np.testing.assert_allclose(layer(out, "lightgroup.sun")[ground].mean(axis=0), sun.mean(axis=0), rtol=0.03)


def test_motion_vectors_follow_the_camera_and_the_wind(tmp_path, library):
    """A camera flying over at 20 m a frame: the ground moves by 20 m / (metres per pixel), the same for every
    pixel, and the box's vectors match how far its pixels move from one frame to the next.  A still camera
    in wind: the trees' vectors move, the ground's are 0."""
    keys = ", ".join(
        f"{{ frame = {k}, position = [{-50.0 + 20.0 * k}, 120.0, 0.0], target = [{-50.0 + 20.0 * k}, 0.0, 1.0] }}"
        for k in range(1, 7)
    )
    camera = f"fov = 50.0\nkeys = [ {keys} ]"
    box = trees([[0.0, 0.0, 0.0]], scale=6.0)
    render(tmp_path, library, "m_#", camera=camera, render='aovs = ["motion"]', spp=2, inst=box, frames=[3, 4])
    a, b = read(tmp_path / "m_3.exr"), read(tmp_path / "m_4.exr")
    fwd = layer(a, "forward", "uv")
    ground = ~binary_dilation(a["id.Z"] >= 0, iterations=1)
    px = 20.0 / (2.0 * 120.0 * math.tan(math.radians(25.0)) / 32.0)
    # (the view is tilted by atan(1/120) toward +z: the scale varies by ±0.2 % down the image)
    np.testing.assert_allclose(np.abs(fwd[ground][:, 0]), px, rtol=3e-3)
    np.testing.assert_allclose(fwd[ground][:, 1], 0.0, atol=1e-3)

    def centroid(d):
        rows, cols = np.nonzero(d["id.Z"] >= 0)
        return cols.mean(), rows.mean()

    (c0, r0), (c1, r1) = centroid(a), centroid(b)
    tree = fwd[a["id.Z"] >= 0]
    assert abs(c1 - c0) > 4.0 and np.sign(tree[:, 0].mean()) == np.sign(c1 - c0)  # the way the pixels move
    assert abs(tree[:, 1].mean()) < 0.05 and abs(r1 - r0) < 0.5
    # the box's top, 36 m up, is 84 m from the camera: it moves faster than the ground
    top = 20.0 / (2.0 * 84.0 * math.tan(math.radians(25.0)) / 32.0)
    np.testing.assert_allclose(np.abs(tree[:, 0]).max(), top, rtol=3e-3)
    # wind, still camera
    wind = "[wind]\nstrength = 20.0\nfrequency = 2.0\ndirection = 90.0"
    render(tmp_path, library, "w", render='aovs = ["motion"]', spp=2, extra=wind)
    w = read(tmp_path / "w.exr")
    speed = np.linalg.norm(layer(w, "forward", "uv"), axis=-1)
    tree = w["id.Z"] >= 0
    assert speed[tree].mean() > 0.3 and not speed[~tree].any()


def test_scalar_rgb_writes_the_geometric_aovs_and_warns_on_light_groups(tmp_path, library):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        render(tmp_path, library, "s", render=ALL, spp=4, variant="scalar_rgb")
    messages = [str(c.message) for c in caught if "render.aovs" in str(c.message)]
    assert len(messages) == 1 and "scalar_rgb" in messages[0]
    out = read(tmp_path / "s.exr")
    assert not any(k.startswith("lightgroup.") for k in out)
    assert {"N.X", "P.Y", "albedo.G", "forward.u", "forward.v"} <= set(out)
    np.testing.assert_allclose(np.linalg.norm(layer(out, "N", "XYZ"), axis=-1), 1.0, atol=1e-5)


def test_unknown_aov_is_refused_naming_the_setting(tmp_path):
    text = BASE.format(camera=SIDE, lights=SKY, render='aovs = ["N", "Z"]', spp=1, extra="")
    with pytest.raises(ForestError, match=r"render\.aovs: unknown AOV 'Z'"):
        parse_config(text, path=tmp_path / "bad.toml", base_dir=tmp_path)
    cfg = parse_config(BASE.format(camera=SIDE, lights=SKY, render="", spp=1, extra=""), base_dir=tmp_path)
    assert cfg.render.aovs == []  # opt-in: the default EXR keeps its size


def test_exr_channel_names_are_the_compositors(tmp_path):
    h, w = 2, 3
    aovs = {
        "N": np.zeros((h, w, 3)),
        "P": np.zeros((h, w, 3)),
        "albedo": np.zeros((h, w, 3)),
        "forward": np.zeros((h, w, 2)),
        "lightgroup.sun": np.ones((h, w, 3)),
    }
    write_comp_exr(tmp_path / "c.exr", np.ones((h, w, 3)), aovs=aovs)
    names = set(read(tmp_path / "c.exr"))
    expected = {"N.X", "N.Y", "N.Z", "P.X", "P.Y", "P.Z", "albedo.R", "albedo.G", "albedo.B", "forward.u"}
    assert expected | {"forward.v", "lightgroup.sun.R", "lightgroup.sun.G", "lightgroup.sun.B"} <= names
    with pytest.raises(ValueError, match="forward"):
        write_comp_exr(tmp_path / "d.exr", np.ones((h, w, 3)), aovs={"forward": np.zeros((h, w, 3))})
