"""Aerial perspective (forest.render.path.haze): visibility, the sky through the haze, the valley fog."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from forest.config import parse_config
from forest.errors import ConfigError
from forest.render.path.haze import (
    FogLayer,
    HazeInputs,
    HazeModel,
    density_from_visibility,
    fog_anchor_np,
    fog_depth_np,
    fog_top_np,
    phi_np,
    transmittance_np,
    visibility_from_density,
)

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))
VARIANT = "llvm_ad_rgb"
MINIMAL = '[terrain]\nflat = {}\n[[species]]\nmodel = "broadleaf"\npercent = 50\n'


def test_visibility_sets_the_haze_by_koschmieder():
    """σ₀ = 3.912 / V: at the visibility a black object keeps 2 % contrast (e^(−σ₀V) = 0.02)."""
    cfg = parse_config(MINIMAL + "[render]\nvisibility = 12.0\n")
    assert cfg.render.haze == pytest.approx(3.912 / 12_000.0)
    assert np.exp(-density_from_visibility(12.0) * 12_000.0) == pytest.approx(0.02, rel=1e-3)
    assert visibility_from_density(density_from_visibility(7.5)) == pytest.approx(7.5)
    assert visibility_from_density(0.0) == np.inf
    assert parse_config(MINIMAL).render.haze == 0.0  # neither given: no haze, as before
    assert parse_config(MINIMAL).render.valley_fog is None


@pytest.mark.parametrize(
    ("extra", "field", "words"),
    [
        ("haze = 0.001\nvisibility = 10.0\n", "render.visibility", "not both"),
        ("visibility = 0.0\n", "render.visibility", "> 0"),
        ("haze_height = -5.0\n", "render.haze_height", "> 0"),
        ("valley_fog = { density = -0.01 }\n", "render.valley_fog", "> 0"),
        ("valley_fog = { density = 0.01, falloff = 0.0 }\n", "render.valley_fog", "> 0"),
        ("valley_fog = { top = 10.0 }\n", "render.valley_fog", "required"),
        ("valley_fog = { density = 0.01, depth = 3 }\n", "render.valley_fog", "unknown key"),
    ],
)
def test_bad_values_are_one_line_naming_the_field(extra, field, words):
    with pytest.raises(ConfigError) as e:
        parse_config(MINIMAL + "[render]\n" + extra, path=Path("scene.toml"))
    msg = str(e.value)
    assert msg.startswith(f"scene.toml: {field}") and words in msg and "\n" not in msg, msg


def test_the_fog_optical_depth_matches_quadrature_in_numpy_and_drjit():
    """τ_f = ∫ ρ·min(1, e^(−(y(s) − y_t)/F)) ds in closed form, against the trapezoid rule; rays up, down,
    level, crossing the top, wholly inside, wholly above (from 400 m: the stable form)."""
    from forest.runtime import mitsuba

    fog = FogLayer(density=0.01, top=20.0, falloff=15.0)
    rng = np.random.default_rng(3)
    n = 64
    oy = rng.uniform(-10.0, 400.0, n)
    d = rng.normal(size=(n, 3))
    d[:4, 1] = [0.0, 1e-7, -1e-7, 1e-3]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    ell = rng.uniform(1.0, 3000.0, n)
    ref = []
    for y0, dy, length in zip(oy, d[:, 1], ell):
        s = np.linspace(0.0, length, 100_001)
        ref.append(np.trapezoid(0.01 * np.minimum(1.0, np.exp(-(y0 + s * dy - 20.0) / 15.0)), s))
    ref = np.asarray(ref)
    np.testing.assert_allclose(fog_depth_np(oy, d[:, 1], ell, fog), ref, rtol=1e-5, atol=1e-9)
    mi = mitsuba(VARIANT)
    haze = HazeInputs(density=0.0, height=150.0, colour=(0.1, 0.1, 0.1), fog=fog)
    model = HazeModel(mi, haze, HazeModel.initial_params(mi, haze), None)
    f32 = [mi.Float(v.astype(np.float32)) for v in (oy, d[:, 1], ell)]
    np.testing.assert_allclose(np.asarray(model.fog_depth(*f32)), ref, rtol=2e-4, atol=1e-5)
    # The fog adds to the haze: T = exp(−τ − τ_f).
    both = HazeInputs(density=0.002, height=150.0, fog=fog)
    alone = transmittance_np(oy, d[:, 1], ell, HazeInputs(density=0.002, height=150.0))
    np.testing.assert_allclose(transmittance_np(oy, d[:, 1], ell, both), alone * np.exp(-ref), rtol=1e-5, atol=1e-12)


def test_without_valley_fog_the_haze_is_the_former_formula_bit_for_bit():
    """Off ⇒ unchanged: fog None runs the former closed form exactly (the same float64 operations)."""
    rng = np.random.default_rng(5)
    oy, dy, ell = rng.uniform(0, 300, 500), rng.uniform(-1, 1, 500), rng.uniform(1, 5000, 500)
    haze = HazeInputs(density=0.0009, height=150.0)
    sigma = haze.density * np.exp(-(oy - haze.ground) / haze.height)
    former = np.exp(-(sigma * ell * phi_np(ell * dy / haze.height)))
    assert np.array_equal(transmittance_np(oy, dy, ell, haze), former)
    from forest.render.path.from_scene import haze_inputs
    from forest.terrain import grid_terrain

    terrain = grid_terrain(np.zeros((5, 5)), (60.0, 60.0))
    assert haze_inputs(parse_config(MINIMAL), terrain) is None
    hz = haze_inputs(parse_config(MINIMAL + "[render]\nhaze = 0.001\n"), terrain)
    assert hz is not None and hz.fog is None


def test_the_valley_fog_top_is_above_the_lowest_point_or_absolute():
    from forest.render.path.from_scene import haze_inputs
    from forest.terrain import grid_terrain

    terrain = grid_terrain(np.full((5, 5), 30.0) + np.eye(5) * 10.0, (60.0, 60.0))
    low = float(terrain.height_range[0])
    rel = haze_inputs(parse_config(MINIMAL + "[render]\nvalley_fog = { density = 0.01, top = 5.0 }\n"), terrain)
    ab = haze_inputs(
        parse_config(MINIMAL + "[render]\nvalley_fog = { density = 0.01, top = 5.0, absolute = true }\n"), terrain
    )
    assert rel is not None and rel.density == 0.0
    assert rel.fog == FogLayer(0.01, low + 5.0, 15.0, variation=6.0, variation_scale=150.0, seed=0)
    assert ab is not None and ab.fog is not None and ab.fog.top == 5.0


def wall(z: float, half: float = 400.0):
    """A vertical square facing −Z at distance ``z`` (y from −half to +half), as MeshData."""
    from forest.library.mesh import MeshData

    v = np.array([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]], np.float32)
    n = np.tile(np.array([[0.0, 0.0, -1.0]], np.float32), (4, 1))
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32)
    return MeshData(v, np.array([[0, 1, 2], [0, 2, 3]], np.uint32), n, uv)


def wall_view(haze: HazeInputs, extra=(), sun=None, spp: int = 16, clouds=None):
    """A black wall 200 m ahead of a camera 30 m up (12×24 pixels), the ``extra`` black surfaces, a black
    sky and ``sun``, seen through ``haze`` with max_depth 1 (the haze's light only): (RGB, the camera)."""
    from bench_atmosphere import look

    from forest.instances import InstanceSet
    from forest.render.path import Material, PathCamera, PathInputs, PathScene, SkyLight, Surface

    camera = PathCamera(look([0.0, 30.0, 0.0], [0.0, 30.0, 100.0]), 30.0, 12, 24)
    black = Material("surface", (0.0, 0.0, 0.0))
    inputs = PathInputs(
        instances=InstanceSet.empty(species_names=("none",)),
        species=[None],
        levels=np.zeros(0, np.int64),
        matrices=np.zeros((0, 4, 4)),
        camera=camera,
        surfaces=[Surface(m, black) for m in (wall(200.0), *extra)],
        sun=sun,
        sky=SkyLight("constant", radiance=(0.0, 0.0, 0.0), clouds=clouds),
        max_depth=1,
        spp=spp,
        haze=haze,
    )
    return np.asarray(PathScene(inputs, VARIANT).render().rgb, np.float64), camera


def test_valley_fog_hides_low_ground_more_than_high_and_the_render_is_the_closed_form():
    """A black wall 200 m ahead of a camera 30 m up, seen through a valley fog (top 20 m, falloff 10 m) and
    nothing else, under a constant sky with the haze colour C: every pixel is C·(1 − T) with T the closed
    form along its ray.  Rows the same angle below and above the horizon meet the wall at the same distance,
    the lower one in the fog (5 m), the upper one clear of it (55 m)."""
    from forest.render.post import pixel_directions

    fog = FogLayer(density=0.01, top=20.0, falloff=10.0)
    c = 0.5
    haze = HazeInputs(density=0.0, height=150.0, colour=(c, c, c), anisotropy=0.0, fog=fog)
    rgb, camera = wall_view(haze)
    d = pixel_directions(camera)
    ell = 200.0 / d[..., 2]
    expected = c * (1.0 - transmittance_np(30.0, d[..., 1], ell, haze))
    np.testing.assert_allclose(rgb[..., 1], expected, rtol=0.03, atol=2e-3)
    rows = np.arange(24)
    y_hit = 30.0 + ell[:, 6] * d[:, 6, 1]
    low, high = rows[np.argmin(np.abs(y_hit - 5.0))], rows[np.argmin(np.abs(y_hit - 55.0))]
    assert low + high == 23  # mirror rows: the same distance
    assert rgb[low].mean() > 3.0 * rgb[high].mean()
    assert expected[low].mean() > 3.0 * expected[high].mean()


def test_the_new_default_haze_height_keeps_a_clear_sky_blue():
    """The demo's sunsky looking up and away from the sun through a 12 km visibility: at the default scale
    height (150 m) the sky keeps nearly its clear saturation; at the former 600 m it turns greyer."""
    from bench_atmosphere import saturation_hue, sky_image

    from forest.config.schema import RenderConfig

    default = RenderConfig.model_fields["haze_height"].default
    sigma = density_from_visibility(12.0)
    clear = saturation_hue(sky_image(None, width=16, height=12, spp=2))[0]
    new = saturation_hue(
        sky_image(HazeInputs(sigma, height=default, sky_distance=30_000.0), width=16, height=12, spp=2)
    )
    old = saturation_hue(sky_image(HazeInputs(sigma, height=600.0, sky_distance=30_000.0), width=16, height=12, spp=2))
    assert default == 150.0
    assert new[0] > 0.9 * clear and old[0] < 0.9 * clear and new[0] > old[0] + 0.03, (clear, new, old)
    assert 180.0 < new[1] < 260.0  # still blue


@pytest.mark.parametrize("variation", [0.0, 15.0])
@pytest.mark.parametrize("variant", ["scalar_rgb", "llvm_ad_rgb"])
def test_both_renderers_fog_the_ground_as_the_closed_form(tmp_path, variant, variation):
    """A grey ground seen straight down from 220 m through a valley fog alone (top 20 m, falloff 10 m, red
    haze colour): L = 0.1·T + (1 − T) in red, T = exp(−τ_f) of the closed form — forest_path per segment,
    scalar_rgb in its post-process (which a valley fog without a haze must still run).  With a varying top
    both read it over the ground under the frame's centre (the segments' lowest ends)."""
    sys.path.insert(0, str(ROOT / "tests"))
    from test_render import make_config, read_exr, trees

    from forest.render import render_scene
    from forest.scene import load_scene

    from render_fixtures import BoxLibrary

    library = BoxLibrary(tmp_path / "lib")
    fog = f"valley_fog = {{ density = 0.01, top = 20.0, falloff = 10.0, variation = {variation}, variation_scale = 40.0 }}\n"
    extra = "haze_anisotropy = 0.0\nhaze_colour = [1.0, 0.0, 0.0]\nmax_depth = 2\n"
    centres = []
    for name, render in (("clear", extra), ("f", fog + extra)):
        (tmp_path / name).mkdir()
        cfg = make_config(tmp_path / name, render=render)
        out_path = tmp_path / name / "f.exr"
        render_scene(load_scene(cfg, trees(np.zeros((0, 3))), library=library), output=out_path, variant=variant)
        centres.append(read_exr(out_path)["rgb"][18:22, 18:22].reshape(-1, 3).mean(axis=0))
    # L0: the ground as this renderer lights it without fog (0.1 in forest_path; scalar_rgb's Mitsuba
    # integrator lights the same grey ground some 9 % darker at max_depth 2, a difference of its own).
    l0, centre = centres
    layer = FogLayer(0.01, 0.0 + 20.0, 10.0, variation=variation, variation_scale=40.0, seed=3)  # the config's seed
    t = float(np.exp(-fog_depth_np(220.0, -1.0, 220.0, layer, np.zeros(2))).ravel()[0])
    np.testing.assert_allclose(centre, [l0[0] * t + (1.0 - t), l0[1] * t, l0[2] * t], atol=0.004)
    if variation:  # the top over the centre is not the level one: the test sees the variation
        assert abs(float(np.ravel(fog_top_np(layer, np.zeros(2)))[0]) - 20.0) > 2.0


def test_a_fog_with_variation_lies_in_banks_the_same_in_numpy_and_drjit():
    """The top y_t + v·(2N − 1) spans about ±v over the ground, changes smoothly (banks ~ S across), follows
    the seed, and forest_path's drjit twin reads the same top and optical depth as the numpy model at each
    segment's lowest end; v = 0 is the level fog, bit for bit."""
    from forest.runtime import mitsuba

    fog = FogLayer(density=0.01, top=20.0, falloff=10.0, variation=8.0, variation_scale=100.0, seed=4)
    g = np.linspace(-2000.0, 2000.0, 201)
    xz = np.stack(np.meshgrid(g, g), axis=-1)
    top = fog_top_np(fog, xz)
    assert top.min() >= 12.0 and top.max() <= 28.0 and top.max() - top.min() > 12.0
    assert abs(float(top.mean()) - 20.0) < 1.0
    # Smooth: over 20 m steps the top moves at most 2v · 2.48 · 20/S (the quintic fade's slope 15/8 on each
    # octave, weighted), never a jump.
    assert np.abs(np.diff(top, axis=0)).max() < 2.0 * 8.0 * 2.48 * 20.0 / 100.0
    other = fog_top_np(FogLayer(0.01, 20.0, 10.0, variation=8.0, variation_scale=100.0, seed=5), xz)
    assert np.abs(other - top).mean() > 1.0
    # The segments' lowest ends: the end going down, the start going up.
    o = np.array([[10.0, 50.0, 20.0], [10.0, 50.0, 20.0]])
    d = np.array([[0.6, -0.8, 0.0], [0.6, 0.8, 0.0]])
    np.testing.assert_allclose(fog_anchor_np(o, d, np.array([10.0, 10.0])), [[16.0, 20.0], [10.0, 20.0]])
    # drjit against numpy, rays down into and over the fog.
    rng = np.random.default_rng(8)
    n = 256
    oy = rng.uniform(0.0, 200.0, n)
    org = np.stack([rng.uniform(-500, 500, n), oy, rng.uniform(-500, 500, n)], axis=1)
    dirs = rng.normal(size=(n, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    ell = rng.uniform(1.0, 800.0, n)
    anchor = fog_anchor_np(org, dirs, ell)
    ref = fog_depth_np(oy, dirs[:, 1], ell, fog, anchor)
    mi = mitsuba(VARIANT)
    haze = HazeInputs(density=0.0, height=150.0, colour=(0.1, 0.1, 0.1), fog=fog)
    model = HazeModel(mi, haze, HazeModel.initial_params(mi, haze), None)
    o3, d3 = (mi.Point3f(*[mi.Float(v.astype(np.float32)) for v in a.T]) for a in (org, dirs))
    length = mi.Float(ell.astype(np.float32))
    np.testing.assert_allclose(np.asarray(model.fog_top(o3, d3, length)), fog_top_np(fog, anchor), atol=2e-3)
    t_dr = np.asarray(model.transmittance(o3, mi.Vector3f(d3), length))
    np.testing.assert_allclose(t_dr, np.exp(-ref), rtol=2e-3, atol=2e-4)
    # No variation: the level fog's numbers exactly (the anchors are not even read).
    level = FogLayer(density=0.01, top=20.0, falloff=10.0)
    assert np.array_equal(fog_depth_np(oy, dirs[:, 1], ell, level, anchor), fog_depth_np(oy, dirs[:, 1], ell, level))


def _shaft_scene(roof: bool, shafts: bool, clouds=None):
    """:func:`wall_view` in a haze and a valley fog under a sun 60° high behind the camera, with an opaque
    black roof 150 m up over everything (out of view: the highest ray meets the wall at 133 m) or none;
    returns (the render's RGB, the camera, the haze)."""
    from forest.library.mesh import MeshData
    from forest.render.path.inputs import SunLight

    haze = HazeInputs(
        density=0.001, height=150.0, colour=(0.05, 0.05, 0.05), anisotropy=0.3, shafts=shafts,
        fog=FogLayer(density=0.01, top=20.0, falloff=10.0, variation=5.0, variation_scale=60.0),
    )  # fmt: skip
    extra = []
    if roof:
        h = 2000.0
        v = np.array([[-h, 150.0, -h], [h, 150.0, -h], [h, 150.0, h], [-h, 150.0, h]], np.float32)
        n = np.tile(np.array([[0.0, -1.0, 0.0]], np.float32), (4, 1))
        uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32)
        extra.append(MeshData(v, np.array([[0, 1, 2], [0, 2, 3]], np.uint32), n, uv))
    e = np.radians(60.0)
    sun = SunLight((0.0, float(np.sin(e)), -float(np.cos(e))), (3.0, 3.0, 3.0))
    rgb, camera = wall_view(haze, extra, sun, clouds=clouds)
    return rgb, camera, haze


def test_light_shafts_shadow_the_haze_and_change_nothing_where_the_sun_is_free():
    """Light shafts: under a roof that hides the sun the haze keeps only its ambient share, C·(1 − T) (the
    lit haze is (C + E·p)·(1 − T)); with nothing in the sun's way the shafts' estimate — a scattering point
    drawn with density σT per camera step, one kept per ray, one shadow ray — gives the lit haze (up to
    float rounding: every visibility is 1), so it adds no bias and no noise there.  The haze's bisection
    draws its points where σT says: their mean distance matches the density's."""
    from forest.render.post import pixel_directions

    lit, camera, haze = _shaft_scene(roof=False, shafts=False)
    free, _, _ = _shaft_scene(roof=False, shafts=True)
    shaded, _, _ = _shaft_scene(roof=True, shafts=True)
    unshaded, _, _ = _shaft_scene(roof=True, shafts=False)
    np.testing.assert_allclose(free, lit, rtol=1e-4, atol=1e-6)
    np.testing.assert_allclose(unshaded, lit, rtol=1e-4, atol=1e-6)  # without shafts the roof changes nothing
    d = pixel_directions(camera)
    ell = 200.0 / d[..., 2]
    anchor = fog_anchor_np(np.array([0.0, 30.0, 0.0]), d, ell)
    t = transmittance_np(30.0, d[..., 1], ell, haze, anchor)
    np.testing.assert_allclose(
        shaded[..., 1], 0.05 * (1.0 - t), rtol=0.03, atol=1e-5
    )  # the pixel centres against the pixels
    assert lit[..., 1].mean() > 3.0 * shaded[..., 1].mean()


def test_the_haze_draws_its_scattering_points_with_density_sigma_t():
    """:meth:`HazeModel.sample_distance` inverts the closed-form optical depth: the points' distribution
    function at s is (1 − T(s)) / (1 − T(ℓ)) (a Kolmogorov–Smirnov distance under 0.01 on 20 000 draws,
    through a haze and a fog with banks)."""
    from forest.runtime import mitsuba

    mi = mitsuba(VARIANT)
    fog = FogLayer(density=0.02, top=25.0, falloff=8.0, variation=6.0, variation_scale=80.0)
    haze = HazeInputs(density=0.002, height=100.0, colour=(0.1, 0.1, 0.1), fog=fog)
    model = HazeModel(mi, haze, HazeModel.initial_params(mi, haze), None)
    n = 20_000
    o = mi.Point3f(mi.Float(np.full(n, 15.0, np.float32)), mi.Float(np.full(n, 60.0, np.float32)), mi.Float(0.0))
    dv = np.array([0.8, -0.2, 0.5])
    dv /= np.linalg.norm(dv)
    d = mi.Vector3f(*[mi.Float(np.full(n, v, np.float32)) for v in dv])
    length = mi.Float(np.full(n, 600.0, np.float32))
    T = model.transmittance(o, d, length)
    u = mi.Float(((np.arange(n) + 0.5) / n).astype(np.float32))
    s = np.sort(np.asarray(model.sample_distance(o, d, length, T, u)))
    grid = np.linspace(0.0, 600.0, 61)
    top = model.fog_top(o, d, length)
    sub = [np.asarray(model.optical_depth(o, d, mi.Float(np.full(n, g, np.float32)), top))[0] for g in grid]
    cdf = (1.0 - np.exp(-np.asarray(sub))) / (1.0 - float(np.asarray(T)[0]))
    empirical = np.searchsorted(s, grid, side="right") / n
    assert np.abs(empirical - cdf).max() < 0.01
    assert s[0] >= 0.0 and s[-1] <= 600.0


def test_light_shafts_are_on_with_a_valley_fog_by_default_and_can_be_set():
    """``[render] haze_shafts``: "auto" (the default) shadows the haze where a valley fog is (where shafts
    show most: bench_atmosphere.py --case shafts, docs/rendering.md "Light shafts");
    true or false force it; anything else is one clear line."""
    from forest.render.path.from_scene import haze_inputs
    from forest.terrain import grid_terrain

    terrain = grid_terrain(np.zeros((5, 5)), (60.0, 60.0))
    fog = "valley_fog = { density = 0.01 }\n"

    def shafts(render: str) -> bool:
        hz = haze_inputs(parse_config(MINIMAL + "[render]\n" + render), terrain)
        assert hz is not None
        return hz.shafts

    assert parse_config(MINIMAL).render.haze_shafts == "auto"
    assert shafts(fog) and not shafts("haze = 0.001\n")
    assert shafts("haze = 0.001\nhaze_shafts = true\n") and not shafts(fog + "haze_shafts = false\n")
    with pytest.raises(ConfigError) as e:
        parse_config(MINIMAL + '[render]\nhaze_shafts = "yes"\n', path=Path("scene.toml"))
    assert str(e.value).startswith("scene.toml: render.haze_shafts") and '"auto"' in str(e.value)


def test_cloud_shadows_fall_on_the_shafts_as_on_the_ground():
    """Under an overcast layer (cover 1) the shafts' sun is the sun through the clouds, T_c = e^(−τ) of the layer
    along the sun's ray, the factor a surface's shadow ray takes (CloudLayer.transmittance): the render's sun share
    is the clear one times T_c; the lit haze without shafts ignores the clouds, as before."""
    from forest.lights import Clouds
    from forest.render.path.clouds import CloudLayer
    from forest.runtime import mitsuba

    overcast = Clouds(cover=1.0, altitude=3000.0, scale=800.0, density=0.5, softness=0.05, height=0.0)
    ambient, _, _ = _shaft_scene(roof=True, shafts=True)  # C·(1 − T): the haze without its sun
    clear, _, _ = _shaft_scene(roof=False, shafts=True)
    clouded, _, _ = _shaft_scene(roof=False, shafts=True, clouds=overcast)
    lit, _, _ = _shaft_scene(roof=False, shafts=False, clouds=overcast)
    np.testing.assert_allclose(lit, clear, rtol=1e-4, atol=1e-6)  # the closed form has no cloud shadows
    mi = mitsuba(VARIANT)
    e = np.radians(60.0)
    s = mi.Vector3f(0.0, float(np.sin(e)), -float(np.cos(e)))
    t_c = float(
        np.asarray(CloudLayer(mi, overcast).transmittance(mi.Point3f(0.0, 30.0, 100.0), s, mi.Bool(True))[0])[0]
    )
    assert 0.05 < t_c < 0.95  # a cloud layer the sun shines through, dimmed
    sun_share = clear[..., 1] - ambient[..., 1]
    np.testing.assert_allclose(clouded[..., 1] - ambient[..., 1], t_c * sun_share, rtol=0.06, atol=1e-5)


def test_the_shafts_shadow_rays_aim_at_the_suns_disc():
    """:meth:`HazeModel.sun_ray` draws directions uniformly in the sun's cone (0.53°, the disc the surfaces'
    soft shadows see): all within its half-angle, centred on the sun, cos θ uniform (its mean halfway)."""
    from forest.render.path.inputs import SUN_ANGULAR_DIAMETER
    from forest.runtime import mitsuba

    mi = mitsuba(VARIANT)
    s = np.array([0.3, 0.8, -0.5])
    s /= np.linalg.norm(s)
    haze = HazeInputs(density=0.001, colour=(0.1, 0.1, 0.1))
    model = HazeModel(mi, haze, HazeModel.initial_params(mi, haze), (tuple(s), lambda scale: mi.Color3f(1.0), 1.0))
    n = 4096
    rng = np.random.default_rng(2)
    u = mi.Point2f(*[mi.Float(rng.random(n).astype(np.float32)) for _ in range(2)])
    d = np.stack([np.asarray(c, np.float64) for c in model.sun_ray(u)], axis=1)
    cos = np.clip(d @ s, -1.0, 1.0)
    half = np.radians(SUN_ANGULAR_DIAMETER) / 2.0
    assert np.degrees(np.arccos(cos)).max() <= np.degrees(half) * 1.01
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-5)
    mean = d.mean(axis=0)
    assert np.degrees(np.arccos(min(1.0, float(mean @ s / np.linalg.norm(mean))))) < 0.02
    assert abs(float(np.mean(1.0 - cos)) / (1.0 - np.cos(half)) - 0.5) < 0.05
