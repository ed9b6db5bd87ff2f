"""The cloud layer of forest_path's sky: off by default, deterministic, lit by the sun, shadows, config."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from test_forest_path import VARIANT, backward_grads, look, quad, surfaces_only
from test_render_scene import TOP_DOWN

from forest.config import parse_config
from forest.errors import ConfigError, ForestWarning
from forest.lights import Clouds, resolve_lights, sun_vector
from forest.render.path import Material, PathCamera, PathScene, SkyLight, SunLight, Surface

SUN = SunLight(sun_vector(35.0, 180.0), (3.0, 2.85, 2.64))
GROUND = Surface(quad(0.0, 5000.0), Material("surface", (0.3, 0.3, 0.3)))
#: Looking up and north (−Z) from 20 m: the sky fills the frame.
SKYWARD = PathCamera(look([0.0, 20.0, 0.0], [0.0, 320.0, -400.0]), 70.0, 48, 27)


def render(clouds: Clouds | None, *, camera: PathCamera = SKYWARD, kind: str = "constant", spp: int = 2) -> np.ndarray:
    sky = SkyLight(kind, radiance=(0.2, 0.3, 0.5), clouds=clouds)
    return PathScene(surfaces_only([GROUND], camera, sun=SUN, sky=sky, spp=spp), VARIANT).render(seed=3).rgb


@pytest.fixture(scope="module")
def clear() -> np.ndarray:
    return render(None)


def test_no_clouds_and_no_cover_render_the_same_bytes(clear):
    """Clouds off is the clear sky; ``cover = 0`` is the same as off, byte for byte."""
    assert np.array_equal(render(Clouds(cover=0.0)), clear)


def test_more_cover_means_a_more_varied_sky_nearer_the_cloud_colour(clear):
    """The sky's pixels vary more with clouds, and their colour moves from the blue sky toward grey-white."""
    some, more = render(Clouds(cover=0.3, seed=5)), render(Clouds(cover=0.7, seed=5))
    lum = [float(np.std(img.mean(axis=2))) for img in (clear, some, more)]
    assert lum[0] < lum[1] and lum[0] < lum[2]
    blue = [float(np.mean(img[..., 2] / np.maximum(img.sum(axis=2), 1e-6))) for img in (clear, some, more)]
    assert blue[0] > blue[1] > blue[2]  # the sky's blue share falls as clouds cover it


def test_same_seed_same_clouds_another_seed_other_clouds():
    a = render(Clouds(cover=0.5, seed=1))
    assert np.array_equal(a, render(Clouds(cover=0.5, seed=1)))
    b = render(Clouds(cover=0.5, seed=2))
    assert float(np.abs(a - b).mean()) > 0.01


def test_wind_slides_the_layer():
    assert not np.array_equal(render(Clouds(cover=0.5)), render(Clouds(cover=0.5, wind=(300.0, 0.0))))


def test_the_sun_side_of_a_cloud_is_brighter_than_the_far_side():
    """Cloudy directions near the sun (silver lining, forward Henyey–Greenstein scattering) outshine cloudy
    directions facing away from it, at the same elevation."""
    import drjit as dr

    from forest.render.path.emitters import LightSet, make_lights

    scene = PathScene(surfaces_only([GROUND], SKYWARD, sun=SUN, sky=SkyLight("constant", clouds=Clouds(0.6))), VARIANT)
    mi = scene.mi
    lights = make_lights(mi, SUN, scene.inputs.sky)
    ls = LightSet(mi, lights, scene.params)
    s = np.asarray(SUN.direction, np.float64)
    az0 = np.degrees(np.arctan2(s[0], s[2]))
    rng = np.random.default_rng(0)
    out = {}
    for name, centre in (("near", az0), ("far", az0 + 180.0)):
        az = np.radians(centre + rng.uniform(-15, 15, 4000))
        el = np.radians(rng.uniform(25, 45, 4000))
        d = np.stack([np.sin(az) * np.cos(el), np.sin(el), np.cos(az) * np.cos(el)], 1).astype(np.float32)
        dv = mi.Vector3f(*[mi.Float(d[:, k]) for k in range(3)])
        o = mi.Point3f(0.0, 20.0, 0.0)
        far_from_disc = np.degrees(np.arccos(np.clip(d @ s, -1, 1))) > 3.0
        with dr.suspend_grad():
            L = np.asarray(ls.eval(dv, mi.Bool(True), o)).reshape(-1, 3).mean(axis=1)
            T = np.asarray(ls.clouds.transmittance(o, dv, mi.Bool(True))[0])
        out[name] = L[(T < 0.2) & far_from_disc].mean()
    assert out["near"] > 1.25 * out["far"]  # measured 1.39


def test_clouds_shade_the_ground():
    """Seen from above, the ground under a sun in an overcast-ish layer is darker, and patchy (cloud shadows).
    The view is 1.2 km across, smaller than a group of clouds, so the groups are off: ``cover`` holds there."""
    down = PathCamera(look([0.0, 600.0, 0.0], [0.0, 0.0, 0.0], (0.0, 0.0, 1.0)), 90.0, 32, 32)
    clear = render(None, camera=down, spp=4)
    shaded = render(Clouds(cover=0.6, scale=300.0, altitude=1000.0, clustering=0.0), camera=down, spp=4)
    assert shaded.mean() < 0.9 * clear.mean()
    assert shaded.mean(axis=2).std() > 1.5 * clear.mean(axis=2).std()


def test_sunsky_with_clouds_renders_finite():
    img = render(Clouds(cover=0.5), kind="sunsky")
    assert np.isfinite(img).all() and img.min() >= 0.0


def config(body: str):
    sky = "sky = { radiance = 1.0, colour = [1.0, 1.0, 1.0] }"
    return parse_config(TOP_DOWN.replace(sky, body))


def test_clouds_are_off_by_default_and_read_from_the_config():
    sky = "sky = { radiance = 1.0, colour = [1.0, 1.0, 1.0] }"
    assert resolve_lights(config(sky)).clouds is None
    c = resolve_lights(config(sky + "\nclouds = { cover = 0.3, altitude = 1500.0, seed = 7, wind = [5.0, 1.0] }"))
    assert c.clouds == Clouds(cover=0.3, altitude=1500.0, seed=7, wind=(5.0, 1.0))
    tall = resolve_lights(config(sky + "\nclouds = { cover = 0.3, height = 450.0 }")).clouds
    assert tall is not None and tall.height == 450.0
    assert tall.clustering == 0.5  # the default: groups of clouds
    even = resolve_lights(config(sky + "\nclouds = { cover = 0.3, clustering = 0.0 }")).clouds
    assert even is not None and even.clustering == 0.0
    assert resolve_lights(config(sky + "\nclouds = { cover = 0.0 }")).clouds is None
    # [lights] with only clouds keeps the default daylight
    only = resolve_lights(config("clouds = { cover = 0.5 }"))
    assert only.sunsky and only.clouds is not None


@pytest.mark.parametrize(
    "body, message",
    [
        ("clouds = { cover = 1.5 }", "lights.clouds.cover: must be <= 1"),
        ("clouds = { altitude = 0.0 }", "lights.clouds.altitude: must be > 0"),
        ("clouds = { scale = -800.0 }", "lights.clouds.scale: must be > 0"),
        ("clouds = { softness = 0.0 }", "lights.clouds.softness: must be > 0"),
        ("clouds = { seed = 1.5 }", "lights.clouds.seed"),
        ("clouds = { wind = [1.0] }", "lights.clouds.wind"),
        ("clouds = { colour = 1 }", "lights.clouds.colour: unknown key"),
        ("clouds = { height = -10.0 }", "lights.clouds.height: must be >= 0"),
        ("clouds = { clustering = 1.2 }", "lights.clouds.clustering: must be <= 1"),
    ],
)
def test_bad_cloud_values_are_refused_in_one_line(body, message):
    sky = "sky = { radiance = 1.0, colour = [1.0, 1.0, 1.0] }"
    with pytest.raises(ConfigError) as e:
        config(sky + "\n" + body)
    assert message in str(e.value) and "\n" not in str(e.value)


def test_clouds_without_a_sky_are_refused():
    with pytest.raises(ConfigError, match=r"lights.clouds: a cloud layer needs a sky"):
        config("sun = { elevation = 40.0 }\nclouds = { cover = 0.5 }")


def test_scalar_rgb_warns_that_it_renders_a_clear_sky():
    from forest.render.scene import emitter_dicts

    cfg = config("sky = { radiance = 1.0, colour = [1.0, 1.0, 1.0] }\nclouds = { cover = 0.5 }")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        emitter_dicts(cfg, "scalar_rgb")
    lines = [str(w.message) for w in caught if issubclass(w.category, ForestWarning)]
    assert len(lines) == 1 and "scalar_rgb" in lines[0] and "\n" not in lines[0]


def test_light_groups_split_the_clouded_sky_and_add_up_to_it():
    """The sun's group takes the sun through the layer and the cloud's sunlit light, the sky's the rest."""
    import drjit as dr

    from forest.render.path.emitters import LightSet, make_lights

    sky = SkyLight("constant", radiance=(0.2, 0.3, 0.5), clouds=Clouds(0.5))
    scene = PathScene(surfaces_only([GROUND], SKYWARD, sun=SUN, sky=sky), VARIANT)
    mi = scene.mi
    ls = LightSet(mi, make_lights(mi, SUN, sky), scene.params)
    rng = np.random.default_rng(1)
    d = rng.normal(size=(2000, 3)).astype(np.float32)
    d[:, 1] = np.abs(d[:, 1])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    dv = mi.Vector3f(*[mi.Float(d[:, k]) for k in range(3)])
    with dr.suspend_grad():
        total, parts = ls.eval_groups(dv, mi.Bool(True), mi.Point3f(0.0, 5.0, 0.0))
        alone = ls.eval(dv, mi.Bool(True), mi.Point3f(0.0, 5.0, 0.0))
    assert set(parts) == {"sun", "sky"}
    assert np.array_equal(np.asarray(total), np.asarray(alone))
    np.testing.assert_allclose(np.asarray(parts["sun"] + parts["sky"]), np.asarray(total), rtol=1e-6)


def _light_set(clouds: Clouds):
    from forest.render.path.emitters import LightSet, make_lights

    sky = SkyLight("constant", radiance=(0.2, 0.3, 0.5), clouds=clouds)
    scene = PathScene(surfaces_only([GROUND], SKYWARD, sun=SUN, sky=sky), VARIANT)
    return scene.mi, LightSet(scene.mi, make_lights(scene.mi, SUN, sky), scene.params)


def _directions(mi, rng, n: int, lo: float, hi: float):
    az = rng.uniform(0.0, 2.0 * np.pi, n)
    el = np.radians(rng.uniform(lo, hi, n))
    d = np.stack([np.sin(az) * np.cos(el), np.sin(el), np.cos(az) * np.cos(el)], 1).astype(np.float32)
    return d, mi.Vector3f(*[mi.Float(d[:, k]) for k in range(3)])


def test_camera_rays_see_cumulus_standing_on_the_layer():
    """Toward the horizon a camera ray sees the cumulus' sides, so more of the sky is cloud than the flat layer
    shows there; straight up it sees cloud only where the flat layer has some (the same footprint); bounce
    rays and light samples see the flat layer whatever the height, and ``height = 0`` shows it to the camera."""
    import drjit as dr

    clouds = Clouds(cover=0.35, scale=1500.0, altitude=2000.0, seed=4)
    mi, ls = _light_set(clouds)
    layer = ls.clouds
    assert layer.tall == pytest.approx(600.0)
    rng = np.random.default_rng(3)
    o = mi.Point3f(0.0, 80.0, 0.0)
    with dr.suspend_grad():
        _, low = _directions(mi, rng, 20000, 2.0, 8.0)
        flat_T = np.asarray(layer.transmittance(o, low, mi.Bool(True))[0])
        cum_T = np.asarray(layer.cumulus(o, low, mi.Bool(True))[0])
        assert float((cum_T < 0.5).mean()) > 1.3 * float((flat_T < 0.5).mean())
        # Straight up from points spread over 30 km: the same footprint.
        xz = rng.uniform(-15000.0, 15000.0, (4000, 2)).astype(np.float32)
        origin = mi.Point3f(mi.Float(xz[:, 0]), 10.0, mi.Float(xz[:, 1]))
        up = mi.Vector3f(0.0, 1.0, 0.0)
        _, tau, _, _ = layer.transmittance(origin, up, mi.Bool(True))
        tau, T_up = np.asarray(tau), np.asarray(layer.cumulus(origin, up, mi.Bool(True))[0])
        assert np.all(tau[T_up < 0.99] > 0.0)  # no cumulus where the flat layer is clear
        # where it is thick, a tower (a short one at a cloud's edge may fall between the march's points)
        assert float((T_up[np.exp(-tau) < 0.5] < 0.9).mean()) > 0.75
        assert 0.15 < float((T_up < 0.5).mean()) < 0.5
        # Bounce rays: the flat layer whatever the height; the camera: the flat layer at height 0.
        _, d = _directions(mi, rng, 4000, 1.0, 89.0)
        on = mi.Bool(True)
        cam = mi.Bool(np.ones(4000, bool))
        _, flat = _light_set(Clouds(cover=0.35, scale=1500.0, altitude=2000.0, seed=4, height=0.0))
        assert np.array_equal(np.asarray(ls.eval(d, on, o)), np.asarray(flat.eval(d, on, o)))
        assert np.array_equal(np.asarray(flat.eval(d, on, o, camera=cam)), np.asarray(flat.eval(d, on, o)))
        assert not np.array_equal(np.asarray(ls.eval(d, on, o, camera=cam)), np.asarray(ls.eval(d, on, o)))


def test_a_cumulus_is_sunlit_on_top_and_grey_below():
    """Camera rays that meet a cumulus high on its dome see it brighter than rays that meet it at its base
    (the sunlight reaching the front through the cloud, and the sky light a base receives)."""
    import drjit as dr

    mi, ls = _light_set(Clouds(cover=0.35, scale=1500.0, altitude=2000.0, seed=4))
    layer = ls.clouds
    rng = np.random.default_rng(5)
    o = mi.Point3f(0.0, 80.0, 0.0)
    d_np, d = _directions(mi, rng, 40000, 2.0, 20.0)
    s = np.asarray(SUN.direction, np.float64)
    with dr.suspend_grad():
        T, front, _ = layer.cumulus(o, d, mi.Bool(True))
        L = np.asarray(ls.eval(d, mi.Bool(True), o, camera=mi.Bool(np.ones(len(d_np), bool))))
        tower = np.asarray(layer.tower(front.x, front.z))  # each cumulus' own tallest, a fraction of H
    L = (L.T if L.shape[0] == 3 else L).reshape(-1, 3).mean(axis=1)
    eta = (np.asarray(front.y) - layer.altitude) / (layer.tall * tower)
    cloudy = (np.asarray(T) < 0.05) & (np.degrees(np.arccos(np.clip(d_np @ s, -1.0, 1.0))) > 30.0)
    top, base = cloudy & (eta > 0.6), cloudy & (eta < 0.25)
    assert top.sum() > 100 and base.sum() > 100
    assert float(L[top].mean()) > 1.15 * float(L[base].mean())


def test_light_gradients_through_the_cumulus_match_finite_differences():
    """Path replay through the cumulus a camera ray sees: the sky's and the sun's scale gradients equal the
    difference quotients (the image is linear in each, so the quotient is exact)."""

    horizon = PathCamera(look([0.0, 20.0, 0.0], [0.0, 120.0, -1000.0]), 70.0, 24, 14)
    sky = SkyLight("constant", radiance=(0.2, 0.3, 0.5), clouds=Clouds(cover=0.5, scale=600.0, seed=2))
    scene = PathScene(surfaces_only([GROUND], horizon, sun=SUN, sky=sky, spp=4), VARIANT)
    assert scene.lights.clouds.tall > 0.0
    weights = np.random.default_rng(2).uniform(0.5, 1.5, (14, 24, 3))
    grads = {k: g.ravel() for k, g in backward_grads(scene, ("sun_irradiance", "sky_radiance"), weights).items()}

    def loss() -> float:
        return float((scene.render(seed=3).rgb.astype(np.float64) * weights).sum())

    base = loss()
    for name, g in grads.items():
        saved = scene.params[name]
        value = np.asarray(saved, np.float64).ravel()
        for c in range(3):
            up = value.copy()
            up[c] += 0.1
            scene.params[name] = scene.mi.Color3f(*map(float, up))
            try:
                fd = (loss() - base) / 0.1
            finally:
                scene.params[name] = saved
            assert g[c] == pytest.approx(fd, rel=1e-3, abs=1e-3), (name, c)


def test_far_cumulus_fade_toward_the_sky_through_the_air():
    """Equation (8): the Rayleigh air between the camera and a cloud tens of kilometres away dims it and scatters
    the sky's light in, so far clouds lie nearer the clear sky's radiance than near ones, and they are redder
    (blue is scattered out of the cloud's brighter light the most)."""
    import drjit as dr

    # The even layer: near and far clouds alike, so what differs between them is the air.
    mi, ls = _light_set(Clouds(cover=0.35, scale=1500.0, altitude=2000.0, seed=4, clustering=0.0))
    layer = ls.clouds
    rng = np.random.default_rng(6)
    o = mi.Point3f(0.0, 80.0, 0.0)
    d_np, d = _directions(mi, rng, 40000, 1.5, 40.0)
    with dr.suspend_grad():
        T, front, _ = layer.cumulus(o, d, mi.Bool(True))
        L = np.asarray(ls.eval(d, mi.Bool(True), o, camera=mi.Bool(np.ones(len(d_np), bool))))
    L = (L.T if L.shape[0] == 3 else L).reshape(-1, 3).astype(np.float64)
    f = np.stack([np.asarray(c, np.float64) for c in (front.x, front.y, front.z)], 1)
    dist = np.linalg.norm(f - np.array([0.0, 80.0, 0.0]), axis=1)
    cloudy = np.asarray(T) < 0.05
    sky = np.array([0.2, 0.3, 0.5])  # the constant sky
    gap = np.linalg.norm(L - sky, axis=1) / np.linalg.norm(sky)
    near, far = cloudy & (dist < 8000.0), cloudy & (dist > 30000.0)
    assert near.sum() > 100 and far.sum() > 100
    assert float(np.median(gap[far])) < 0.8 * float(np.median(gap[near]))
    red = L[:, 0] / L[:, 2]
    assert float(np.median(red[far])) > float(np.median(red[near]))


def _layer(clouds: Clouds):
    """The drjit cloud layer of ``clouds`` in the tests' variant."""
    import mitsuba as mi

    from forest.render.path.clouds import CloudLayer

    mi.set_variant(VARIANT)
    return CloudLayer(mi, clouds)


def _grid(layer, span: float, n: int, offset: float) -> tuple[np.ndarray, np.ndarray]:
    """τ and the cumulus' profile over an n × n jittered grid ``span`` × ``scale`` wide, ``offset`` metres away
    (far from where the layer measures its threshold: a held-out patch of sky)."""
    import drjit as dr

    mi = layer.mi
    step = span * layer.scale / n
    g = np.arange(n) * step + offset
    x, z = (a.ravel() for a in np.meshgrid(g, g))
    j = np.random.default_rng(11).uniform(0.0, step, (2, x.size))
    x, z = mi.Float((x + j[0]).astype(np.float32)), mi.Float((z + j[1]).astype(np.float32))
    with dr.suspend_grad():
        return np.asarray(layer.thickness(x, z)).reshape(n, n), np.asarray(layer.profile(x, z)).reshape(n, n)


def test_clustering_gathers_the_clouds_into_groups_and_keeps_the_cover():
    """Equation (2'): with ``clustering`` the clouds gather into groups about 6 × scale across with clear sky
    between — the cover of 6-scale cells spreads far more than for the even layer — while the whole sky keeps
    its ``cover`` (held out: a patch 100 km from where the threshold was measured)."""
    spread, cover = {}, {}
    for c in (0.0, 0.5):
        layer = _layer(Clouds(cover=0.35, scale=1000.0, seed=4, clustering=c))
        tau, _ = _grid(layer, 192.0, 768, -100_000.0)
        cloud = tau > 0.0
        cover[c] = float(cloud.mean())
        spread[c] = float(cloud.reshape(32, 24, 32, 24).mean(axis=(1, 3)).std())
    assert cover[0.0] == pytest.approx(0.35, abs=0.03) and cover[0.5] == pytest.approx(0.35, abs=0.03)
    assert spread[0.5] > 1.4 * spread[0.0]  # measured 0.12 against 0.07


def test_clustered_cumulus_differ_in_height():
    """Equation (5'): each cumulus tops out at its own share of ``height``, between 1 − 0.6 c and 1, so the
    tallest points of separate clouds spread more than for the even layer; no cloud overtops its tower."""
    from scipy import ndimage

    cv = {}
    for c in (0.0, 0.5):
        layer = _layer(Clouds(cover=0.35, scale=1000.0, seed=4, clustering=c))
        tau, profile = _grid(layer, 48.0, 384, 40_000.0)
        labels, k = ndimage.label(tau > 0.0)
        size = ndimage.sum(tau > 0.0, labels, np.arange(1, k + 1))
        tops = ndimage.maximum(profile, labels, np.arange(1, k + 1))[size >= 20]
        assert len(tops) > 50
        cv[c] = float(tops.std() / tops.mean())
        if c > 0.0:
            import drjit as dr

            mi = layer.mi
            xz = np.random.default_rng(2).uniform(0.0, 40_000.0, (2, 20000)).astype(np.float32)
            with dr.suspend_grad():
                tower = np.asarray(layer.tower(mi.Float(xz[0]), mi.Float(xz[1])))
                top = np.asarray(layer.profile(mi.Float(xz[0]), mi.Float(xz[1])))
            assert tower.min() >= 1.0 - 0.6 * c - 1e-6 and tower.max() <= 1.0
            assert np.percentile(tower, 90) - np.percentile(tower, 10) > 0.1
            assert np.all(top <= tower + 1e-6)
    assert cv[0.5] > 1.3 * cv[0.0]  # measured 0.17 against 0.11


def test_clustering_breaks_the_even_band_of_far_clouds():
    """What a camera sees toward the horizon (1.5°–6° up, 24 sectors of azimuth): with clustering the share of
    clouded rays varies from sector to sector much more than the even layer's — groups and gaps instead of an
    even band."""
    import drjit as dr

    spread = {}
    for c in (0.0, 0.5):
        layer = _layer(Clouds(cover=0.35, scale=1500.0, altitude=2000.0, seed=4, clustering=c))
        mi = layer.mi
        d_np, d = _directions(mi, np.random.default_rng(3), 24000, 1.5, 6.0)
        with dr.suspend_grad():
            T = np.asarray(layer.cumulus(mi.Point3f(0.0, 80.0, 0.0), d, mi.Bool(True))[0])
        sector = (np.arctan2(d_np[:, 0], d_np[:, 2]) % (2.0 * np.pi) / (2.0 * np.pi) * 24).astype(int)
        spread[c] = float(np.std([(T[sector == k] < 0.5).mean() for k in range(24)]))
    assert spread[0.5] > 1.4 * spread[0.0]  # measured 0.10 against 0.05
