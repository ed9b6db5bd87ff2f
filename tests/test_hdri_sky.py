"""HDRI skies (forest.hdri): the shipped maps, the sun found in a map and taken out, the disc sun that replaces it."""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_forest_path import pixel_direction
from test_render import make_config, trees

from forest import hdri
from forest.cli import main
from forest.config import parse_config
from forest.errors import ConfigError
from forest.images import read_image, write_image
from forest.lights import resolve_lights, sun_vector

from render_fixtures import BoxLibrary

FLAT = '[terrain]\nflat = { size = 100.0 }\n[[species]]\nmodel = "broadleaf"\npercent = 100\n'


@pytest.fixture(autouse=True)
def cache(tmp_path, monkeypatch):
    """A fresh cache folder and memo for every test."""
    monkeypatch.setenv("FOREST_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(hdri, "_memo", {})
    return tmp_path / "cache" / "skies"


def synthetic_map(elevation: float, azimuth: float, radius_deg: float = 1.0, radiance: float = 5000.0):
    """A 1024×512 lat-long sky brightening towards the zenith, plus a disc of ``radiance`` and angular radius
    ``radius_deg`` towards (elevation, azimuth), each pixel's coverage of the disc from 8×8 sub-samples.
    Returns (map, sky alone, the disc's irradiance facing it, 2π(1 − cos r)·L)."""
    h, w, n = 512, 1024, 8
    d = hdri.directions(h, w)
    sky = (0.3 + 0.7 * np.clip(d[..., 1:2], 0.0, 1.0)) * np.array([0.6, 0.8, 1.0])
    s = sun_vector(elevation, azimuth)
    # Coverage only near the disc (its rows), by sub-sampling each pixel n×n.
    sub = (np.arange(n) + 0.5) / n
    theta = np.pi * (np.arange(h)[:, None] + sub[None, :]) / h  # (h, n)
    phi = 2 * np.pi * (np.arange(w)[:, None] + sub[None, :]) / w  # (w, n)
    st, ct = np.sin(theta), np.cos(theta)
    dots = (
        st[:, None, :, None] * np.sin(phi)[None, :, None, :] * s[0]
        + ct[:, None, :, None] * s[1]
        - st[:, None, :, None] * np.cos(phi)[None, :, None, :] * s[2]
    )
    coverage = (dots >= math.cos(math.radians(radius_deg))).mean(axis=(2, 3))
    img = sky + radiance * coverage[..., None]
    return img, sky, radiance * 2 * math.pi * (1 - math.cos(math.radians(radius_deg)))


def test_the_shipped_skies_resolve_and_load():
    for name in hdri.SKIES:
        path = hdri.sky_path(name)
        assert path.is_file() and path.stat().st_size < 2 * 2**20
        img = read_image(path)
        assert img.shape == (512, 1024, 3) and np.isfinite(img).all() and img.min() >= 0.0
        assert img.max() > 1000.0  # the sun is there, unclipped by us
    assert (hdri.sky_path("sunrise").parent / "README.md").is_file()
    with pytest.raises(Exception, match="unknown sky 'moon'"):
        hdri.sky_path("moon")


@pytest.mark.parametrize(("elevation", "azimuth"), [(30.0, 200.0), (12.0, 180.0), (55.0, 81.0)])
def test_the_sun_finder_recovers_a_known_disc(elevation, azimuth):
    """Direction within a degree and irradiance within 2 % (azimuth 180° lies on the map's seam); after the
    removal no pixel is brighter than the sky's top quantile."""
    img, sky, e_true = synthetic_map(elevation, azimuth)
    sun, filled = hdri.find_sun(img)
    assert sun is not None
    cos = float(sun_vector(sun.elevation, sun.azimuth) @ sun_vector(elevation, azimuth))
    assert math.degrees(math.acos(min(cos, 1.0))) < 1.0
    assert sun.irradiance == pytest.approx(e_true * float(hdri.LUMINANCE @ np.ones(3)), rel=0.02)
    np.testing.assert_allclose(sun.colour, (1.0, 1.0, 1.0), rtol=0.02)  # a white disc on a blue sky: white
    y, y_sky = filled @ hdri.LUMINANCE, sky @ hdri.LUMINANCE
    top = hdri.weighted_quantile(y_sky, hdri.solid_angles(512, 1024), 0.999)
    assert float(y[sun.region].max()) <= top and float(y.max()) <= float(y_sky.max())
    # What the map lost is what the sun carries.
    omega = hdri.solid_angles(512, 1024)[..., None]
    lost = ((img - filled) * omega).sum(axis=(0, 1))
    np.testing.assert_allclose(lost, sun.rgb, rtol=1e-9)


def test_a_map_without_a_sun_is_left_as_it_is(tmp_path):
    _, sky, _ = synthetic_map(30.0, 0.0)
    sun, filled = hdri.find_sun(sky)
    assert sun is None and filled is not None and np.array_equal(filled, sky)
    path = write_image(tmp_path / "overcast.exr", sky)
    split = hdri.split_sun(path)
    assert split.path == path and split.elevation is None


def test_the_processed_map_is_cached_byte_identical(tmp_path, cache, monkeypatch):
    img, _, _ = synthetic_map(25.0, 300.0)
    src = write_image(tmp_path / "clear.exr", img)
    first = hdri.split_sun(src)
    assert first.path.parent == cache and first.path.is_file()
    data = first.path.read_bytes()
    monkeypatch.setattr(hdri, "_memo", {})
    first.path.unlink()
    again = hdri.split_sun(src)
    assert again == first and again.path.read_bytes() == data
    monkeypatch.setattr(hdri, "_memo", {})
    assert hdri.split_sun(src) == first  # from the cached file's header
    assert first.elevation == pytest.approx(25.0, abs=0.5) and first.azimuth == pytest.approx(300.0, abs=0.5)


def test_lights_take_the_sun_from_the_map_unless_the_config_gives_one():
    lights = resolve_lights(parse_config(FLAT + '[lights]\nsky = { hdri = "sunrise", scale = 2.0 }\n'))
    sky = lights.sky
    assert sky is not None and sky.kind == "envmap" and sky.map_sun is not None
    assert sky.source == hdri.sky_path("sunrise") and sky.envmap != sky.source
    assert lights.sun == sky.map_sun
    one = resolve_lights(parse_config(FLAT + '[lights]\nsky = { hdri = "sunrise" }\n'))
    assert one.sun is not None and lights.sun.irradiance == pytest.approx(2.0 * one.sun.irradiance)
    assert 5.0 < one.sun.elevation < 11.0  # a low morning sun
    # The user's sun wins; the map is still the one without its sun.
    mine = resolve_lights(parse_config(FLAT + '[lights]\nsun = { elevation = 40.0 }\nsky = { hdri = "sunrise" }\n'))
    assert mine.sun is not None and mine.sun.elevation == 40.0
    assert mine.sky is not None and mine.sky.envmap == sky.envmap
    # map_sun = false keeps the shipped map as it is; an envmap keeps its sun unless asked.
    kept = resolve_lights(parse_config(FLAT + '[lights]\nsky = { hdri = "sunset", map_sun = false }\n'))
    assert kept.sun is None and kept.sky is not None and kept.sky.envmap == hdri.sky_path("sunset")


def test_a_turned_map_turns_its_sun(tmp_path):
    """``rotation`` Δ: the sun found in the turned map is at azimuth + Δ (within a degree, across the seam too),
    at the same elevation and irradiance; a turn with the sun kept writes a turned copy and no sun."""
    img, _, _ = synthetic_map(30.0, 200.0)
    src = write_image(tmp_path / "clear.exr", img)
    plain = hdri.split_sun(src)
    for turn in (45.0, -120.0, 172.5):
        t = hdri.split_sun(src, rotation=turn)
        assert t.azimuth is not None and plain.azimuth is not None and t.path != plain.path
        assert (t.azimuth - plain.azimuth - turn + 180.0) % 360.0 - 180.0 == pytest.approx(0.0, abs=1.0)
        assert t.elevation == pytest.approx(plain.elevation, abs=0.2)
        assert t.irradiance == pytest.approx(plain.irradiance, rel=0.02)
    kept = hdri.split_sun(src, rotation=90.0, take_sun=False)
    assert kept.elevation is None and kept.path != src
    turned = read_image(kept.path)
    assert turned.shape == img.shape and float(turned.max()) > 1000.0  # the sun is still in it
    np.testing.assert_allclose(turned.sum(axis=(0, 1)), read_image(src).sum(axis=(0, 1)), rtol=2e-3)  # energy kept
    lights = resolve_lights(parse_config(FLAT + '[lights]\nsky = { hdri = "sunrise", rotation = 90.0 }\n'))
    base = resolve_lights(parse_config(FLAT + '[lights]\nsky = { hdri = "sunrise" }\n'))
    assert lights.sun is not None and base.sun is not None
    assert (lights.sun.azimuth - base.sun.azimuth - 90.0 + 180.0) % 360.0 - 180.0 == pytest.approx(0.0, abs=1.0)


@pytest.mark.parametrize(
    ("sky", "field", "message"),
    [
        ('{ hdri = "moon" }', "lights.sky.hdri", "unknown sky 'moon'"),
        ('{ hdri = "sunrise", sunsky = {} }', "lights.sky", "give one of envmap, hdri or sunsky"),
        ("{ map_sun = true }", "lights.sky.map_sun", "environment map"),
        ("{ sunsky = {}, rotation = 90.0 }", "lights.sky.rotation", "environment map"),
        (
            '{ hdri = "sunset" }\nclouds = { cover = 0.4 }',
            "lights.clouds",
            r"not over an environment map \(lights\.sky\.hdri\)",
        ),
    ],
)
def test_bad_hdri_settings_are_one_line(sky, field, message):
    with pytest.raises(ConfigError, match=message) as e:
        parse_config(FLAT + f"[lights]\nsky = {sky}\n")
    assert e.value.field == field


def test_clouds_over_a_users_envmap_are_refused_through_the_cli(tmp_path, capsys):
    """A user's map with a cloud layer: one line naming the file and field, exit 2, nothing written."""
    cfg = tmp_path / "scene.toml"
    cfg.write_text(FLAT + '[lights]\nsky = { envmap = "sky.exr" }\nclouds = { cover = 0.3 }\n')
    out = tmp_path / "out.exr"
    write_image(tmp_path / "sky.exr", np.ones((8, 16, 3), np.float32))
    with pytest.raises(SystemExit) as e:
        main(["render", str(cfg), "-o", str(out)])
    err = capsys.readouterr().err
    assert e.value.code == 2, err
    assert "scene.toml" in err and "lights.clouds" in err and "(lights.sky.envmap)" in err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["scene.toml", "sky.exr"]


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    return BoxLibrary(tmp_path_factory.mktemp("hdrilib"))


def test_forest_path_renders_a_shipped_sky_with_shadows_away_from_its_sun(tmp_path, library):
    """One tall box, seen from above under the sunrise map: finite pixels, and the ground is darker on the
    side opposite the sun found in the map than on the sun's side."""
    from forest.render.path import PathScene
    from forest.render.path.from_scene import path_inputs
    from forest.scene import load_scene

    camera = "position = [0.0, 120.0, 0.0]\ntarget = [0.0, 0.0, 0.0]\nup = [0.0, 0.0, 1.0]\nfov = 40.0\n"
    cfg = make_config(tmp_path, camera=camera, replace_camera=True, ground="[0.5, 0.5, 0.5]")
    cfg = cfg.with_overrides({"lights": {"sky": {"hdri": "sunrise"}}})
    scene = load_scene(cfg, trees([[0.0, 0.0, 0.0]], scale=5.0), library=library)
    sun = scene.lights.sun
    assert sun is not None and scene.lights.sky is not None and scene.lights.sky.map_sun == sun
    inputs = path_inputs(scene, width=32, height=18, spp=8)
    rgb = PathScene(inputs, "llvm_ad_rgb").render().rgb
    assert np.isfinite(rgb).all() and rgb.mean() > 0
    # Ground point of each pixel; distance along the sun's horizontal direction and across it.
    s = sun.direction[[0, 2]] / np.linalg.norm(sun.direction[[0, 2]])
    cam = np.asarray(inputs.camera.to_world)[:3, 3]
    along = np.zeros(rgb.shape[:2])
    across = np.full(rgb.shape[:2], np.inf)
    for i in range(rgb.shape[0]):
        for j in range(rgb.shape[1]):
            d = pixel_direction(inputs.camera, i, j)
            x, _, z = cam + d * (-cam[1] / d[1])
            along[i, j] = x * s[0] + z * s[1]
            across[i, j] = -x * s[1] + z * s[0]
    y = rgb @ hdri.LUMINANCE
    strip = np.abs(across) < 3.5
    shadow, lit = strip & (along < -8) & (along > -28), strip & (along > 8) & (along < 28)
    assert shadow.sum() >= 4 and lit.sum() >= 4
    assert y[shadow].mean() < 0.6 * y[lit].mean()  # about 0.35: the box hides the low sun


def test_a_sunsky_background_hides_the_map_from_the_camera_but_not_from_the_light(tmp_path, library):
    """A map whose lower sky is a red band (a photographed horizon) over a blue sky, seen level from 2 m:
    with background = "map" the rows just above the horizon are red; with "sunsky" they are the sky model's
    (blue over red, at the map's mean brightness within 5 %), while the lit ground below the horizon — every
    path that leaves the scene after a bounce — is the same to the last bit."""
    from forest.render.path import PathScene
    from forest.render.path.emitters import luminance
    from forest.render.path.from_scene import path_inputs
    from forest.scene import load_scene

    h, w = 64, 128
    elevation = (0.5 - (np.arange(h) + 0.5) / h) * 180.0  # latitude-longitude rows, +Y up
    img = np.empty((h, w, 3), np.float32)
    img[:] = (0.3, 0.5, 1.0)
    img[(elevation > 0) & (elevation < 20)] = (1.2, 0.2, 0.1)  # the "photographed" horizon
    img[elevation <= 0] = (0.2, 0.2, 0.2)
    write_image(tmp_path / "sky.exr", img)
    camera = "position = [0.0, 2.0, -40.0]\ntarget = [0.0, 4.0, 100.0]\nfov = 50.0\n"
    seen = {}
    for background in ("map", "sunsky"):
        cfg = make_config(tmp_path, camera=camera, replace_camera=True, ground="[0.5, 0.5, 0.5]")
        sky = {"envmap": str(tmp_path / "sky.exr"), "background": background}
        cfg = cfg.with_overrides({"lights": {"sky": sky, "sun": {"elevation": 30.0, "azimuth": 180.0}}})
        scene = load_scene(cfg, trees([[0.0, 0.0, 30.0]]), library=library)
        inputs = path_inputs(scene, width=40, height=40, spp=4)
        path = PathScene(inputs, "llvm_ad_rgb")
        seen[background] = (path.render().rgb, path)
    (plain, _), (hidden, path) = seen["map"], seen["sunsky"]
    band = slice(8, 17)  # a few degrees above the horizon (row 20)
    assert plain[band, :, 0].mean() > 2.0 * plain[band, :, 2].mean()  # the red band
    assert hidden[band, :, 2].mean() > hidden[band, :, 0].mean()  # the model's sky: bluer than red
    np.testing.assert_array_equal(hidden[26:], plain[26:])  # the ground: lit by the map alike
    backdrop = path.backdrop
    assert backdrop is not None
    # The map's mean radiance over the upper hemisphere, per channel: rows weighted by their solid angle.
    up = elevation > 0
    weight = np.cos(np.radians(elevation[up]))
    mean_map = (img[up].mean(axis=1) * weight[:, None]).sum(axis=0) / weight.sum()
    light = next(x for x in path.lights if getattr(x, "direction", None) is None)
    np.testing.assert_allclose(light.mean_radiance, mean_map, rtol=0.03)  # each channel its own (not mixed)
    assert backdrop.k * luminance(backdrop.light.mean_radiance) == pytest.approx(luminance(mean_map), rel=0.03)


def test_background_applies_to_an_environment_map_only():
    with pytest.raises(ConfigError, match="environment map") as e:
        parse_config(FLAT + '[lights]\nsky = { sunsky = {}, background = "sunsky" }\n')
    assert e.value.field == "lights.sky.background"
