"""Water on the ground (issue 27): ``[ground]`` rules of material ``water`` are a Fresnel mirror in forest_path.

Tiny scenes over a flat terrain; the references are closed forms (the exact Fresnel reflectance of
n = 1.33 and the sky's radiance in the mirror direction) and a mirrored box.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from forest.config import parse_config
from forest.errors import ConfigError
from forest.render.path import Material, PathCamera, PathInputs, PathScene, SkyLight, Surface
from forest.render.path.materials import WATER_IOR
from forest.terrain import grid_terrain

from render_fixtures import box_mesh

VARIANT = "llvm_ad_rgb"
BED = (0.06, 0.07, 0.04)


def fresnel(mu: float, n: float = WATER_IOR) -> float:
    """Exact unpolarised Fresnel reflectance of a smooth dielectric (Born & Wolf §1.5)."""
    st = np.sqrt(max(0.0, 1.0 - mu * mu)) / n
    ct = np.sqrt(1.0 - st * st)
    rs = (mu - n * ct) / (mu + n * ct)
    rp = (n * mu - ct) / (n * mu + ct)
    return 0.5 * (rs * rs + rp * rp)


def look(position, target, up=(0.0, 1.0, 0.0)) -> np.ndarray:
    from forest.camera import look_at_matrix

    return look_at_matrix(position, target, up)


def water_inputs(
    camera, sky, *, water=1.0, surfaces=(), ripple=0.0, spp=64, max_depth=2, detail=None, tile=1.0
) -> PathInputs:
    """A flat 400 m terrain of albedo ``BED`` whose water coverage is ``water`` everywhere (None: no water),
    with an optional ground ``detail`` texture repeated every ``tile`` metres."""
    from forest.instances import InstanceSet

    colour = np.tile(np.asarray(BED, np.float32), (4, 4, 1))
    return PathInputs(
        instances=InstanceSet.empty(species_names=("box",)),
        species=[None],
        levels=np.zeros(0, np.int64),
        matrices=np.zeros((0, 4, 4)),
        camera=camera,
        terrain=grid_terrain(np.zeros((5, 5)), (400.0, 400.0)),
        terrain_colour=colour,
        terrain_tinted=False,
        surfaces=list(surfaces),
        sun=None,
        sky=sky,
        max_depth=max_depth,
        spp=spp,
        terrain_water=None if water is None else np.full((4, 4), water, np.float32),
        water_ripple=ripple,
        terrain_detail=detail,
        terrain_detail_tile=tile,
    )


def test_water_reflects_the_sky_at_a_grazing_angle():
    """Seen at 80° from the normal under a gradient sky (no sun), a flat water surface shows
    F(μ)·L(r) + (1 − F(μ))·R·E/π, r the mirror direction and E/π = h + (2/3)(z − h) the irradiance
    of the sky L(μ) = h + (z − h)·μ over π."""
    theta = np.radians(80.0)
    camera = PathCamera(look([0.0, 10.0, -10.0 * np.tan(theta)], [0.0, 0.0, 0.0]), 0.2, 4, 4)
    z, h = np.array([0.10, 0.20, 0.60]), np.array([0.50, 0.45, 0.40])
    sky = SkyLight("gradient", zenith=tuple(z), horizon=tuple(h))
    img = PathScene(water_inputs(camera, sky, spp=256), VARIANT).render().rgb.reshape(-1, 3).mean(axis=0)
    mu = np.cos(theta)
    f = fresnel(mu)
    assert 0.3 < f < 0.4
    mirror = h + (z - h) * mu  # the sky seen 10° above the horizon
    expected = f * mirror + (1.0 - f) * np.asarray(BED) * (h + 2.0 / 3.0 * (z - h))
    np.testing.assert_allclose(img, expected, rtol=0.02)
    # Without water the same ground is only its diffuse colour: far darker at this angle.
    dry = PathScene(water_inputs(camera, sky, water=None, spp=64), VARIANT).render().rgb.mean()
    assert dry < 0.3 * img.mean()


def test_water_is_dark_at_normal_incidence():
    """Looking straight down under a constant sky L: F(1)·L + (1 − F(1))·R·L, F(1) = 0.020."""
    camera = PathCamera(look([0.0, 10.0, 0.0], [0.0, 0.0, 0.0], (0.0, 0.0, 1.0)), 5.0, 4, 4)
    sky = SkyLight("constant", radiance=(1.0, 1.0, 1.0))
    img = PathScene(water_inputs(camera, sky, spp=256), VARIANT).render().rgb.reshape(-1, 3).mean(axis=0)
    f0 = fresnel(1.0)
    assert abs(f0 - 0.0201) < 2e-4
    np.testing.assert_allclose(img, f0 + (1.0 - f0) * np.asarray(BED), rtol=0.02)


def test_water_shows_no_ground_detail():
    """The ground's detail texture (soil grain) is drawn on dry ground and fades with the water's coverage
    W: a checker of 0.4 / 1.6 stripes the ground without water and at W = ½ halves its contrast, while full
    water is the flat F(1)·L + (1 − F(1))·R·L of an undetailed bed."""
    camera = PathCamera(look([0.0, 10.0, 0.0], [0.0, 0.0, 0.0], (0.0, 0.0, 1.0)), 5.0, 16, 16)
    sky = SkyLight("constant", radiance=(1.0, 1.0, 1.0))
    checker = np.where((np.arange(2)[:, None] + np.arange(2)[None, :]) % 2 == 0, 0.4, 1.6)
    detail = np.repeat(checker[..., None], 3, axis=2).astype(np.float32)

    def render(water):
        inputs = water_inputs(camera, sky, water=water, spp=64, detail=detail, tile=0.6)
        return PathScene(inputs, VARIANT).render(seed=1).rgb.reshape(16, 16, 3)

    dry, half, wet = render(0.0), render(0.5), render(1.0)
    f0 = fresnel(1.0)
    np.testing.assert_allclose(wet.reshape(-1, 3).mean(axis=0), f0 + (1.0 - f0) * np.asarray(BED), rtol=0.02)
    spread = [float(np.std(im[..., 1]) / np.mean(im[..., 1])) for im in (dry, half, wet)]
    assert spread[0] > 0.1
    assert 0.35 * spread[0] < spread[1] < 0.65 * spread[0]
    assert spread[2] < 0.03


def test_a_box_on_the_water_is_mirrored_below_the_waterline():
    """A red box standing in the water, seen from just above the surface: the rows below its foot
    see its red in the mirror, the columns beside it the grey sky."""
    camera = PathCamera(look([0.0, 1.0, -30.0], [0.0, 1.0, 0.0]), 20.0, 48, 32)
    box = Surface(box_mesh((-2.0, 0.0, -2.0), (2.0, 6.0, 2.0)), Material("surface", (0.8, 0.05, 0.05)))
    sky = SkyLight("constant", radiance=(1.0, 1.0, 1.0))
    # Depth 3: the mirror bounce is one vertex, the box it meets another that takes direct light.
    inputs = water_inputs(camera, sky, surfaces=[box], spp=32, ripple=1.0, max_depth=3)
    img = PathScene(inputs, VARIANT).render().rgb
    above, centre, side = img[4:14, 22:26], img[:, 22:26], img[:, 2:6]
    below = slice(22, 31)  # rows under the box's foot (the horizon is row 16), above the image's bottom
    assert centre[below, :, 0].mean() > 0.3 * above[..., 0].mean()  # F → 1 at grazing incidence
    red_centre = centre[below, :, 0].mean() / centre[below, :, 1].mean()
    red_side = side[below, :, 0].mean() / side[below, :, 1].mean()
    assert red_centre > 4.0
    assert 0.8 < red_side < 1.25  # the grey sky's reflection over a dark bed


def test_no_water_is_the_same_render_as_zero_coverage_and_as_before():
    """Coverage 0 everywhere traces the water code but leaves every lane's bits as they were; a config
    without water rules gives no coverage grid at all (the kernel without the water branch)."""
    camera = PathCamera(look([0.0, 5.0, -20.0], [0.0, 0.0, 0.0]), 40.0, 12, 8)
    sky = SkyLight("gradient", zenith=(0.1, 0.2, 0.6), horizon=(0.5, 0.45, 0.4))
    a = PathScene(water_inputs(camera, sky, water=None, spp=4, max_depth=3), VARIANT).render(seed=3).rgb
    b = PathScene(water_inputs(camera, sky, water=0.0, spp=4, max_depth=3), VARIANT).render(seed=3).rgb
    assert a.tobytes() == b.tobytes()
    c = PathScene(water_inputs(camera, sky, water=1.0, spp=4, max_depth=3), VARIANT).render(seed=3).rgb
    assert a.tobytes() != c.tobytes()
    d = PathScene(water_inputs(camera, sky, water=1.0, spp=4, max_depth=3), VARIANT).render(seed=3).rgb
    assert c.tobytes() == d.tobytes()


CONFIG = """
seed = 3
[terrain]
flat = { size = 100.0 }
[lights]
sky = { radiance = 1.0 }
[render]
width = 16
height = 16
[[species]]
model = "box"
percent = 100
"""


def make_config(tmp_path, extra: str):
    text = CONFIG + extra
    (tmp_path / "scene.toml").write_text(text)
    return parse_config(text, path=tmp_path / "scene.toml", base_dir=tmp_path)


def _scene(tmp_path, ground: str):
    from forest.ground import terrain_albedo
    from forest.instances import InstanceSet
    from forest.terrain import load_terrain

    config = make_config(tmp_path, ground)
    terrain = load_terrain(config.terrain, config.path)
    return config, terrain_albedo(config, terrain, InstanceSet.empty(species_names=("box",)), [])


def test_water_rules_paint_a_coverage_grid(tmp_path):
    """A rule of material ``water`` paints its colour and a coverage W composited like the colour;
    grounds without water carry no grid."""
    base = '\n[ground]\nbase = "soil"\n[[ground.rules]]\nmaterial = "grass"\n'
    _, dry = _scene(tmp_path, base)
    assert dry.water is None
    _, wet = _scene(tmp_path, base + '[[ground.rules]]\nmaterial = "water"\nopacity = 0.6\n'
                    '[[ground.rules]]\nmaterial = "rock"\nopacity = 0.5\n')  # fmt: skip
    assert wet.water is not None and wet.water.shape == wet.rgb.shape[:2]
    np.testing.assert_allclose(wet.water, 0.6 * 0.5, atol=1e-6)
    np.testing.assert_allclose(wet.water_at(np.array([0.0]), np.array([0.0])), [0.3], atol=1e-6)


@pytest.mark.parametrize(
    ("ground", "field"),
    [
        ("\n[ground]\nwater_ripple = -1.0\n", "water_ripple"),
        ("\n[ground]\nwater_ripple = 45.0\n", "water_ripple"),
        ("\n[ground.materials]\nwater = [0.1, 0.2]\n", "water"),
        ("\n[ground]\nwater_attenuation = [0.4, -0.2, 0.4]\n", "water_attenuation"),
        ("\n[ground]\nwater_depth = -1.0\n", "water_depth"),
    ],
)
def test_bad_water_values_are_refused_in_one_line(tmp_path, ground, field):
    with pytest.raises(ConfigError) as e:
        make_config(tmp_path, ground)
    message = str(e.value)
    assert "\n" not in message and field in message and "ground" in message


def test_scalar_rgb_draws_the_water_apart(tmp_path):
    """Mitsuba's own integrator gets the water as a mesh of its own (plastic of index 1.33 over the water's colour,
    roughplastic when it ripples) and the terrain without those triangles; no warning; a ground without water is
    one terrain mesh as before."""
    import mitsuba as mi

    from forest.ground import TerrainAlbedo
    from forest.render.scene import ground_dicts, terrain_dict

    mi.set_variant("scalar_rgb")
    terrain = grid_terrain(np.zeros((9, 9)), (60.0, 60.0))
    rgb = np.tile(np.asarray(BED, np.float32), (8, 8, 1))
    water = np.zeros((8, 8), np.float32)
    water[:, :4] = 1.0  # the half at x < 0
    albedo = TerrainAlbedo(rgb, terrain.extent, water=water)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ground, wet = ground_dicts(albedo, terrain, "scalar_rgb", ripple=0.0)
        _, rough = ground_dicts(albedo, terrain, "scalar_rgb", ripple=2.0)
        alone = terrain_dict(albedo, terrain, "scalar_rgb")
    assert not caught and wet is not None and rough is not None
    assert ground.face_count() + wet.face_count() == len(terrain.faces) and wet.face_count() == len(terrain.faces) // 2
    assert alone.face_count() == ground.face_count()  # terrain_dict leaves the water out too
    params = mi.traverse(wet)
    x = np.asarray(params["vertex_positions"]).reshape(-1, 3)[:, 0]
    assert x[np.asarray(params["faces"]).reshape(-1, 3)].max() <= 1e-6  # only the water's half
    assert "plastic" in str(wet.bsdf()).lower() and "1.33" in str(wet.bsdf())
    assert "roughplastic" in str(rough.bsdf()).lower() or "RoughPlastic" in str(rough.bsdf())
    dry = TerrainAlbedo(rgb, terrain.extent)
    assert ground_dicts(dry, terrain, "scalar_rgb", ripple=2.0)[1] is None
    assert terrain_dict(dry, terrain, "scalar_rgb").face_count() == len(terrain.faces)


def test_relief_is_the_height_above_the_valley_floor():
    """A V valley falling by 0.1 m per metre along +Z, sides rising 0.5 m per metre: within r = 20 m the
    lowest ground lies 20 m down the floor, so relief is the floor's fall over r (2 m; less near the lower
    end) along the whole floor, where no one altitude window would do, and 10 m + 2 m at 20 m up a side."""
    from forest.ground import terrain_relief

    x = np.linspace(-50.0, 50.0, 101)
    z = np.linspace(0.0, 100.0, 101)
    height = 0.5 * np.abs(x)[None, :] - 0.1 * z[:, None]
    relief = terrain_relief(height, (-50.5, -0.5, 50.5, 100.5), 20.0)
    np.testing.assert_allclose(relief[:, 50], 0.1 * np.minimum(20.0, 100.0 - z), atol=1e-9)
    np.testing.assert_allclose(relief[:81, 30], 10.0 + 2.0, atol=1e-9)


def test_gradients_through_water_match_the_closed_form():
    """Path replay through water, looking straight down at water under a constant sky L: each pixel is
    F(1)·L + (1 − F(1))·t·R·L, so d/dt = (1 − F)·R·L per pixel for the ground tint t (the mirror has no
    gradient) and d/dL = F + (1 − F)·t·R for the sky radiance.  (Finite differences of renders would
    not do: the mirror's sampling probability depends on R·t.)"""
    import drjit as dr

    camera = PathCamera(look([0.0, 10.0, 0.0], [0.0, 0.0, 0.0], (0.0, 0.0, 1.0)), 5.0, 8, 8)
    sky = (0.3, 0.4, 0.6)
    scene = PathScene(water_inputs(camera, SkyLight("constant", radiance=sky), spp=64), VARIANT)
    params = {k: scene.params[k] for k in ("ground_tint", "sky_radiance")}
    for v in params.values():
        dr.enable_grad(v)
    scene.render_backward(np.ones((8, 8, 3)), seed=3)
    grads = {k: np.asarray(dr.grad(v), np.float64).ravel() / 64.0 for k, v in params.items()}
    for v in params.values():
        dr.disable_grad(v)
    f0, bed = fresnel(1.0), np.asarray(BED)
    np.testing.assert_allclose(grads["ground_tint"], (1.0 - f0) * bed * np.asarray(sky), rtol=0.02)
    np.testing.assert_allclose(grads["sky_radiance"], f0 + (1.0 - f0) * bed, rtol=0.02)


def test_ripples_keep_their_rms_tilt_and_come_in_patches():
    """The ripples' normal over 400 m of water: the mean of tan² of its tilt is tan² of ``water_ripple`` (the
    wind's patches are normalised to a mean square of 1), while 20 m squares range from glassy to rippled."""
    import mitsuba as mi

    mi.set_variant(VARIANT)
    from forest.render.path.materials import ripple_normal

    t = (np.arange(800) + 0.5) * 0.5  # every 0.5 m over 400 m
    x, z = np.meshgrid(t, t)
    n = ripple_normal(mi, mi.Point3f(x.ravel(), 0.0, z.ravel()), 3.0)
    nx, ny, nz = (np.asarray(c) for c in (n.x, n.y, n.z))
    tan2 = ((nx * nx + nz * nz) / (ny * ny)).reshape(800, 800)
    assert tan2.mean() == pytest.approx(np.tan(np.radians(3.0)) ** 2, rel=0.15)
    local = tan2.reshape(20, 40, 20, 40).mean(axis=(1, 3))  # 20 m squares
    assert np.percentile(local, 90) > 5.0 * np.percentile(local, 10)
    flat = ripple_normal(mi, mi.Point3f(1.0, 0.0, 2.0), 0.0)
    assert (float(flat.x[0]), float(flat.y[0]), float(flat.z[0])) == (0.0, 1.0, 0.0)


def test_a_painted_river_shows_its_bed_at_its_edges(tmp_path):
    """A river painted by a rule (a 20 m stripe of a map over wet ground, 1 m texels) is R(H) = c + (A − c)·
    exp(−2KH) with A the wet ground under it and H = min(D, g·(d − ½ texel)), d the distance across the stripe
    to its nearest dry column, counted here along the row; ``water_depth = 0`` keeps the water's colour everywhere
    (as before shallow water), and the coverage is the same either way."""
    from conftest import write_png

    from forest.config.schema import BANK_GRADIENT, GROUND_MATERIALS

    stripe = np.zeros((100, 100))
    stripe[:, 40:60] = 1.0
    write_png(tmp_path / "river.png", stripe)
    rules = (
        '\n[ground]\nbase = "wet"\nresolution = 100\nvariation = 0.0\nwater_depth = {depth}\n'
        "water_attenuation = [0.8, 0.4, 0.9]\n"
        '[[ground.rules]]\nmaterial = "water"\nmap = "river.png"\nnoise = 0.0\n'
    )
    _, plain = _scene(tmp_path, rules.format(depth=0.0))
    np.testing.assert_allclose(plain.rgb[plain.water == 1.0], np.broadcast_to(GROUND_MATERIALS["water"], (2000, 3)),
                               rtol=1e-5)  # fmt: skip
    c, bed, k = (np.asarray(v) for v in (GROUND_MATERIALS["water"], GROUND_MATERIALS["wet"], (0.8, 0.4, 0.9)))
    for deepest in (5.0, 1.0):
        _, alb = _scene(tmp_path, rules.format(depth=deepest))
        np.testing.assert_array_equal(alb.water, plain.water)
        row = alb.water[50] >= 0.5
        cols = np.flatnonzero(row)
        assert len(cols) == 20 and np.all(np.diff(cols) == 1)
        d = np.minimum(cols - (cols[0] - 1), (cols[-1] + 1) - cols).astype(float)  # metres to the nearest dry column
        h = np.minimum(deepest, BANK_GRADIENT * (d - 0.5))
        assert np.all(alb.water[50, cols] == 1.0)  # every texel across the stripe is all water
        want = c + (bed - c) * np.exp(-2.0 * h[:, None] * k)
        np.testing.assert_allclose(alb.rgb[50, cols], want, rtol=1e-4, atol=1e-6)
        red = alb.rgb[50, cols[:10], 0]  # the wet bed is redder than the water: the red falls toward the middle
        if deepest == 5.0:
            assert np.all(np.diff(red) < 0)
        else:  # 1 m is reached 7.2 m from the edge: the middle's columns are all that deep
            assert np.all(np.diff(red[:7]) < 0) and np.ptp(red[7:]) < 1e-6 and h.max() == 1.0
