"""The lights are resolved once (forest.lights) and every backend follows the same rule for the sun and sky."""

from __future__ import annotations

import numpy as np
import pytest
from test_render_scene import TOP_DOWN

from forest.config import parse_config
from forest.errors import ConfigError
from forest.export.rib import lights_text
from forest.lights import DEFAULT_SUN, SUNSKY_DOME, resolve_lights, sun_vector
from forest.render.path.from_scene import path_lights
from forest.render.scene import emitter_dicts

SKY = "sky = { radiance = 1.0, colour = [1.0, 1.0, 1.0] }"


def lights_config(text: str):
    """TOP_DOWN with its ``[lights]`` table replaced by ``text``."""
    return parse_config(TOP_DOWN.replace(SKY, text))


CASES = {
    # name: ([lights] body, sun on?, sky kind)
    "sun and constant sky": ("sun = { elevation = 30.0, azimuth = 90.0 }\n" + SKY, True, "constant"),
    "sun below the horizon": ("sun = { elevation = -5.0 }\n" + SKY, False, "constant"),
    "sun that sends nothing": ("sun = { elevation = 40.0, irradiance = 0.0 }\n" + SKY, False, "constant"),
    "sun alone": ("sun = { elevation = 50.0, azimuth = 10.0 }", True, None),
    "sunsky with a sun": ("sun = { elevation = 25.0, azimuth = 200.0 }\nsky = { sunsky = {} }", True, "sunsky"),
    "sunsky without a sun": ("sky = { sunsky = { scale = 2.0 } }", True, "sunsky"),
    "sunsky at night": ("sun = { elevation = -3.0 }\nsky = { sunsky = {} }", False, "sunsky"),
}


def _usd_lights(config, tmp_path):
    from pxr import Usd, UsdLux

    from forest.export.usd import _lights

    stage = Usd.Stage.CreateInMemory()
    _lights(stage, config, tmp_path)
    sun = stage.GetPrimAtPath("/World/Lights/Sun")
    sky = stage.GetPrimAtPath("/World/Lights/Sky")
    rotation = None
    if sun:
        m = UsdLux.DistantLight(sun).GetPrim().GetAttribute("xformOp:transform").Get()
        rotation = np.array(m).T[:3, :3]  # Gf matrices are row-vector: transpose to columns
    return rotation, bool(sky)


@pytest.mark.parametrize("name", list(CASES))
def test_every_backend_has_the_same_sun_and_sky(name, tmp_path):
    body, sun_on, sky_kind = CASES[name]
    cfg = lights_config(body)
    lights = resolve_lights(cfg)
    assert (lights.sun is not None) == sun_on
    assert (None if lights.sky is None else lights.sky.kind) == sky_kind
    d = None if lights.sun is None else lights.sun.direction

    # Mitsuba (scalar): a sun-sky draws its own sun; otherwise a directional sun iff the sun is on.
    e = emitter_dicts(cfg, "scalar_rgb")
    if sky_kind == "sunsky":
        assert set(e) == {"sky"}
        np.testing.assert_allclose(e["sky"]["sun_direction"], lights.sky.sun.direction, atol=1e-12)
    else:
        assert ("sun" in e) == sun_on
        if sun_on:
            np.testing.assert_allclose(e["sun"]["direction"], -d, atol=1e-12)

    # forest_path: the same directions; a sun-sky keeps its sun's direction, its irradiance zero when off.
    sun, sky = path_lights(lights)
    if sky_kind == "sunsky":
        np.testing.assert_allclose(sun.direction, lights.sky.sun.direction, atol=1e-12)
        assert (max(sun.irradiance) > 0) == sun_on
        assert sky.sun_irradiance == pytest.approx(lights.sky.sun.irradiance)
    else:
        assert (sun is not None) == sun_on
        if sun_on:
            np.testing.assert_allclose(sun.direction, d, atol=1e-12)
    assert (None if sky is None else sky.kind) == sky_kind

    # RIB and USD: a distant light iff the sun is on (a sun-sky's sun too), a dome iff there is a sky.
    rib = lights_text(cfg, renderman22=False)
    assert ('"distantlight"' in rib) == sun_on
    assert ('"ambientlight"' in rib) == (sky_kind is not None)
    rotation, usd_sky = _usd_lights(cfg, tmp_path)
    assert (rotation is not None) == sun_on
    assert usd_sky == (sky_kind is not None)
    if sun_on:
        np.testing.assert_allclose(rotation[:, 2], d, atol=1e-6)  # local +Z onto d: it shines along −d


def test_sunsky_without_a_sun_points_at_the_default_sun_everywhere():
    cfg = lights_config("sky = { sunsky = { scale = 2.0 } }")
    lights = resolve_lights(cfg)
    assert lights.sun == DEFAULT_SUN and lights.sky.sun == DEFAULT_SUN
    assert lights.sky.dome() == (2.0 * SUNSKY_DOME[0], SUNSKY_DOME[1])
    np.testing.assert_allclose(DEFAULT_SUN.direction, sun_vector(35.0, 120.0), atol=1e-12)
    # The exported sun is the one the renderers draw (before, the exporters had none here).
    rib = lights_text(cfg, renderman22=False)
    frm = [line for line in rib.splitlines() if '"distantlight"' in line][0].split('"from" [')[1].split("]")[0]
    np.testing.assert_allclose([float(x) for x in frm.split()], DEFAULT_SUN.direction, atol=1e-5)


def test_no_light_left_is_one_clear_error_for_every_renderer():
    cfg = lights_config("sun = { elevation = -10.0 }")
    with pytest.raises(ConfigError, match=r"lights: no light left"):
        emitter_dicts(cfg, "scalar_rgb")
    with pytest.raises(ConfigError, match=r"lights: no light left"):
        path_lights(resolve_lights(cfg).require(cfg.path))
