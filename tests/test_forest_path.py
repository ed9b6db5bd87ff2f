"""forest_path, forest's path tracer for the JIT variants: hits, layers, look, light, gradients, determinism.

Small scenes and tiny images; where an independent reference exists it is
the ``scalar_rgb`` renderer (Mitsuba's own surface interactions and BSDFs) or
a closed form.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from test_render import make_config, read_exr

from forest.config import parse_config
from forest.images import write_image
from forest.instances import InstanceSet, yaw_tilt_quaternion
from forest.lights import sun_vector
from forest.render import render_scene
from forest.render.path import Material, PathCamera, PathInputs, PathScene, SkyLight, SunLight, Surface
from forest.render.path.from_scene import path_inputs
from forest.scene import load_scene

from render_fixtures import BoxLibrary

VARIANT = "llvm_ad_rgb"


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    return BoxLibrary(tmp_path_factory.mktemp("pathlib"))


#: The second species of the sets below, for configs (scatter gives it no share).
CARD = '\n[[species]]\nmodel = "card"\npercent = 0\n'


def forest_set(positions, species, names=("box", "card"), scale=1.0) -> InstanceSet:
    p = np.asarray(positions, np.float32)
    n = len(p)
    up = np.tile([0.0, 1.0, 0.0], (n, 1))
    return InstanceSet(
        id=np.arange(500, 500 + n),
        position=p,
        rotation=yaw_tilt_quaternion(np.zeros(n), up, np.zeros(n)),
        yaw=np.zeros(n),
        scale=np.full(n, scale),
        species=np.asarray(species),
        tint=np.ones((n, 3)),
        partition=np.zeros(n),
        normal=up,
        phase=np.zeros(n),
        species_names=list(names),
        extent=(-50.0, -50.0, 50.0, 50.0),
    )


def quad(y: float, half: float, *, up: bool = True):
    """A horizontal square at height y (normals up), as MeshData."""
    from forest.library.mesh import MeshData

    v = np.array([[-half, y, -half], [half, y, -half], [half, y, half], [-half, y, half]], np.float32)
    f = np.array([[0, 2, 1], [0, 3, 2]] if up else [[0, 1, 2], [0, 2, 3]], np.uint32)
    n = np.tile(np.array([[0.0, 1.0 if up else -1.0, 0.0]], np.float32), (4, 1))
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32)
    return MeshData(v, f, n, uv)


def look(position, target, up=(0.0, 1.0, 0.0)) -> np.ndarray:
    from forest.camera import look_at_matrix

    return look_at_matrix(position, target, up)


# ---------------------------------------------------------------------------
# Stage 1: hits rebuilt from preliminary intersections; depth, id, species
# ---------------------------------------------------------------------------


def mitsuba_layers(scene, frame: float = 1.0) -> dict:
    """The reference: depth (from the near plane) and id per pixel centre from Mitsuba's own scalar_rgb
    ``Scene.ray_intersect`` on the scene Mitsuba's integrators render, looking past transparent texels."""
    from forest.render.frame import FrameRenderer, FrameSize

    rc = scene.config.render
    r = FrameRenderer(scene, "scalar_rgb", FrameSize(rc.width, rc.height, 1))
    mscene = r.scene_at(scene.levels(frame), frame / scene.config.camera.fps)
    mi = r.mi
    sensor = r.sensor(frame, 1)
    h, w = rc.height, rc.width
    depth = np.full((h, w), 1e5)
    ids = np.full((h, w), -1.0)
    for i in range(h):
        for j in range(w):
            ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f((j + 0.5) / w, (i + 0.5) / h), mi.Point2f(0.5, 0.5))
            travelled = 0.0
            for _ in range(32):
                si = mscene.ray_intersect(ray)
                if not si.is_valid():
                    break
                bsdf = si.bsdf()
                if (
                    mi.has_flag(bsdf.flags(), mi.BSDFFlags.Null)
                    and float(np.mean(bsdf.eval_null_transmission(si))) > 0.5
                ):
                    travelled += si.t
                    ray = si.spawn_ray(ray.d)
                    continue
                depth[i, j] = travelled + si.t
                if si.instance is not None and si.instance.id().startswith("tree_"):
                    ids[i, j] = scene.instances.id[int(si.instance.id()[5:])]
                break
    return {"depth": depth, "id": ids}


@pytest.mark.parametrize("flatten", [0, 10_000])
def test_layers_match_mitsubas_own_intersections(tmp_path, library, flatten):
    """Instanced (flatten 0) or merged (10 000) trees: forest_path's id/species/depth layers agree with
    Mitsuba's own scalar_rgb surface interactions on the scene its integrators render."""
    # Cut-out cards as Mitsuba draws them: solid cards (small trees) would be other surfaces to compare.
    cfg = make_config(
        tmp_path,
        extra="[lod]\ndistances = [221.0, 222.0, 223.0]\nsolid_pixels = 0\n" + CARD,
        render="horizon_ground = false",
    )
    pos = [[-20.0, 0.0, -20.0], [20.0, 0.0, -20.0], [-20.0, 0.0, 20.0], [20.0, 0.0, 22.0], [0.0, 0.0, 0.0]]
    inst = forest_set(pos, [0, 0, 0, 0, 1], scale=2.0)
    scene = load_scene(cfg, inst, library=library)
    ref = mitsuba_layers(scene)
    inputs = path_inputs(scene)
    inputs.flatten_triangles = flatten
    path = PathScene(inputs, VARIANT)
    stats = path.stats
    assert (stats.instances, stats.flattened_trees) == ((5, 0) if flatten == 0 else (0, 5))
    layers = path.layers()
    # The LOD plan gave some trees the high box (6 m) and others the low one (3 m): both kinds are seen.
    assert set(np.unique(layers["id"]).astype(int)) == {-1, 500, 501, 502, 503, 504}
    same = layers["id"] == ref["id"]
    assert same.mean() > 0.99  # a pixel centre exactly on a box edge may go either way
    species = {500: 0, 501: 0, 502: 0, 503: 0, 504: 1}
    tree = same & (ref["id"] >= 0)
    np.testing.assert_array_equal(layers["species"][tree], [species[int(i)] for i in ref["id"][tree]])
    hit = same & (ref["depth"] < 1e4)
    # Mitsuba's depth is measured from the near plane (0.5 m in front of the camera), ours from the camera:
    # they differ by 0.5 / cos θ along a ray θ off the view axis.
    cam = inputs.camera
    forward = np.asarray(cam.to_world)[:3, 2]
    cos = np.array([[pixel_direction(cam, i, j) @ forward for j in range(cam.width)] for i in range(cam.height)])
    np.testing.assert_allclose(layers["depth"][hit], ref["depth"][hit] + 0.5 / cos[hit], atol=0.01)
    assert (layers["depth"][ref["depth"] >= 1e4] >= 1e4).all()


def pixel_direction(camera: PathCamera, i: int, j: int) -> np.ndarray:
    """Unit world direction of the ray through the centre of pixel (row i, column j) (pinhole, fov along x)."""
    t = np.tan(np.radians(camera.fov) / 2)
    x = (1 - 2 * (j + 0.5) / camera.width) * t  # camera +X is image left
    y = (1 - 2 * (i + 0.5) / camera.height) * t * camera.height / camera.width
    d = np.asarray(camera.to_world)[:3, :3] @ np.array([x, y, 1.0])
    return d / np.linalg.norm(d)


def test_layers_on_a_known_layout(library):
    """Straight down from 100 m: box tops, the card's opaque half and, through its transparent half, the ground."""
    inst = forest_set([[-8.0, 0.0, 0.0], [8.0, 0.0, 0.0]], [0, 1])
    camera = PathCamera(look([0.0, 100.0, 0.0], [0.0, 0.0, 0.0], (0.0, 0.0, 1.0)), 30.0, 61, 61)
    inputs = PathInputs(
        instances=inst,
        species=[library.resolve("box"), library.resolve("card")],
        levels=np.array([3, 0]),  # the far box: 2×3×2 m
        matrices=inst.matrices(),
        camera=camera,
        surfaces=[Surface(quad(0.0, 15.0), Material("surface", (0.2, 0.2, 0.2)))],
        sun=SunLight((0.0, 1.0, 0.0), (1.0, 1.0, 1.0)),
    )
    layers = PathScene(inputs, VARIANT).layers()
    half = 100.0 * np.tan(np.radians(15.0))  # half the ground width seen at the image's centre row

    def pixel(x, z):  # the pixel looking at world (x, ·, z): image left is +X, image up is +Z
        return int(np.floor((1 - z / half) * 61 / 2)), int(np.floor((1 - x / half) * 61 / 2))

    def depth_at(i, j, height):
        d = pixel_direction(camera, i, j)
        return (100.0 - height) / -d[1]

    box, card_opaque, card_clear = pixel(-8.0, 0.0), pixel(11.0, 2.0), pixel(5.0, 2.0)
    assert layers["id"][box] == 500 and layers["species"][box] == 0
    assert layers["depth"][box] == pytest.approx(depth_at(*box, 3.0), abs=0.01)
    # The card (10×10 m at 5 m, centred on x = 8): its alpha is 0 for u < ½ (x < 8 m) and 1 beyond.
    assert layers["id"][card_opaque] == 501 and layers["species"][card_opaque] == 1
    assert layers["depth"][card_opaque] == pytest.approx(depth_at(*card_opaque, 5.0), abs=0.01)
    assert layers["id"][card_clear] == -1 and layers["species"][card_clear] == -1
    assert layers["depth"][card_clear] == pytest.approx(depth_at(*card_clear, 0.0), abs=0.01)
    # Outside the ground: nothing is hit, the far clip.
    assert layers["depth"][0, 0] == pytest.approx(1e5)


# ---------------------------------------------------------------------------
# Stage 2/3: materials, sun and sky, cut-outs; agreement with scalar_rgb
# ---------------------------------------------------------------------------


def no_trees() -> InstanceSet:
    return forest_set(np.zeros((0, 3)), np.zeros(0, np.int64), names=("box",))


def surfaces_only(surfaces, camera, *, sun=None, sky=None, max_depth=2, spp=16, library=None) -> PathInputs:
    inst = no_trees()
    return PathInputs(
        instances=inst,
        species=[library.resolve("box")] if library is not None else [None],
        levels=np.zeros(0, np.int64),
        matrices=np.zeros((0, 4, 4)),
        camera=camera,
        surfaces=surfaces,
        sun=sun,
        sky=sky,
        max_depth=max_depth,
        spp=spp,
    )


AGREEMENT_FEATURES = {
    # name: (extra config, translucency of the box leaves)
    "sun and sky, indirect light": ("", 0.0),
    "translucent leaves": ("", 0.4),
    "sunsky": ("", 0.0),
    "haze": ("", 0.0),
}


@pytest.mark.parametrize("feature", list(AGREEMENT_FEATURES))
def test_render_scene_agrees_in_both_variants_within_noise(tmp_path, library, feature):
    """Boxes on a ground under sun and sky, rendered by ``render_scene`` with Mitsuba's integrators
    (scalar_rgb) and with forest_path (llvm_ad_rgb): the same image up to noise, feature by feature.

    The noise level of each renderer is measured from two seeds; the mean of the
    two-seed averages must differ by less than that level, and their overall
    brightness by less than 2 %.
    """
    extra, tau = AGREEMENT_FEATURES[feature]
    lib = library if tau == 0 else BoxLibrary(tmp_path / "lib", translucency=tau)
    cam = "position = [0.0, 30.0, -60.0]\ntarget = [0.0, 2.0, 0.0]\nfov = 40.0"
    sun = "[lights.sun]\nelevation = 40.0\nazimuth = 30.0\nirradiance = 3.0\n"
    depth = 2 if feature == "haze" else 3  # haze: scalar_rgb hazes camera rays only (module forest.render.post)
    render = f"max_depth = {depth}\n"
    if feature == "haze":
        render += "haze = 0.004\nhaze_height = 40.0\n"
    inst = forest_set([[x, 0.0, z] for x in (-15.0, 0.0, 15.0) for z in (-10.0, 10.0)], [0] * 6, scale=1.5)
    images: dict[str, list[np.ndarray]] = {"scalar_rgb": [], VARIANT: []}
    for seed in (1, 2):
        text = render + f"seed = {seed}"
        cfg = make_config(tmp_path, camera=cam, replace_camera=True, render=text, extra=sun + extra + CARD)
        if feature == "sunsky":
            body = (tmp_path / "scene.toml").read_text()
            body = body.replace("sky = { radiance = 1.0, colour = [1.0, 1.0, 1.0] }", "sky = { sunsky = {} }")
            cfg = parse_config(body, path=tmp_path / "scene.toml", base_dir=tmp_path)
            assert cfg.lights.sky.kind == "sunsky"
        cfg = cfg.with_overrides({"render.width": 48, "render.height": 36, "render.spp": 48})
        for variant in images:
            out = tmp_path / f"{variant}_{seed}.exr"
            render_scene(load_scene(cfg, inst, library=lib), output=out, variant=variant)
            images[variant].append(read_exr(out)["rgb"].astype(np.float64))
    scalar, path = images["scalar_rgb"], images[VARIANT]
    noise_s = np.std(scalar[0] - scalar[1]) / np.sqrt(2)
    noise_p = np.std(path[0] - path[1]) / np.sqrt(2)
    mean_s, mean_p = (scalar[0] + scalar[1]) / 2, (path[0] + path[1]) / 2
    level = np.sqrt((noise_s**2 + noise_p**2) / 2)
    assert np.abs(mean_p - mean_s).mean() < level
    assert mean_p.mean() == pytest.approx(mean_s.mean(), rel=0.02)


def test_a_leaf_lit_from_behind_transmits(tmp_path):
    """A horizontal leaf under an overhead sun, seen from below: L = T/π · E with T = τ·a; black without τ."""
    camera = PathCamera(look([0.0, 0.0, 0.0], [0.0, 1.0, 0.0], (0.0, 0.0, 1.0)), 20.0, 8, 8)
    sun = SunLight((0.0, 1.0, 0.0), (2.0, 2.0, 2.0))
    values = {}
    for tau in (0.0, 0.4):
        leaf = Surface(quad(1.0, 5.0), Material("leaf", (0.5, 0.6, 0.3), translucency=tau))
        img = PathScene(surfaces_only([leaf], camera, sun=sun, spp=4), VARIANT).render().rgb
        values[tau] = img.reshape(-1, 3).mean(axis=0)
    np.testing.assert_allclose(values[0.0], 0.0, atol=1e-6)
    expected = 0.4 * np.array([0.5, 0.6, 0.3]) / np.pi * 2.0
    np.testing.assert_allclose(values[0.4], expected, rtol=1e-3)


def card_texture(path: Path, alpha_left: float, alpha_right: float) -> Path:
    rgba = np.ones((16, 16, 4), np.float32)
    rgba[:, :8, 3] = alpha_left
    rgba[:, 8:, 3] = alpha_right
    return write_image(path, rgba)


def ground_mask(camera: PathCamera, x_range, z_range) -> np.ndarray:
    """Pixels whose centre ray meets the plane y = 0 inside x_range × z_range."""
    o = np.asarray(camera.to_world)[:3, 3]
    mask = np.zeros((camera.height, camera.width), bool)
    for i in range(camera.height):
        for j in range(camera.width):
            d = pixel_direction(camera, i, j)
            if d[1] < 0:
                x, _, z = o + d * (-o[1] / d[1])
                mask[i, j] = x_range[0] <= x <= x_range[1] and z_range[0] <= z <= z_range[1]
    return mask


def test_cut_out_cards_cast_partial_shadows(tmp_path):
    """A card 5 m up, sun at 45° from +Z: its shadow falls 5 m towards −Z.  Under the transparent half the
    ground is lit, under the opaque half it is dark, under a half of opacity ½ it receives half the light."""
    camera = PathCamera(look([0.0, 60.0, -7.5], [0.0, 0.0, -7.5], (0.0, 0.0, 1.0)), 12.0, 24, 24)
    sun = SunLight((0.0, np.sqrt(0.5), np.sqrt(0.5)), (1.0, 1.0, 1.0))
    ground = Surface(quad(0.0, 20.0), Material("surface", (0.5, 0.5, 0.5)))
    lit = 0.5 / np.pi * np.sqrt(0.5)
    # The card covers x, z ∈ ±5 m (u < ½ ↔ x < 0); its shadow x ∈ ±5, z ∈ [−10, 0], seen where z < −5.
    under_left = ground_mask(camera, (-4.0, -1.0), (-9.5, -5.5))  # 1 m off the bilinear alpha edges
    under_right = ground_mask(camera, (1.0, 4.0), (-9.5, -5.5))
    outside = ground_mask(camera, (-9.0, 9.0), (-13.0, -10.5))
    assert under_left.sum() > 10 and under_right.sum() > 10 and outside.sum() > 10
    for alpha_left, alpha_right in ((0.0, 1.0), (0.5, 1.0)):
        tex = card_texture(tmp_path / f"card_{alpha_left}.png", alpha_left, alpha_right)
        card = Surface(quad(5.0, 5.0), Material("leaf", (0.8, 0.8, 0.8), texture=tex))
        img = PathScene(surfaces_only([ground, card], camera, sun=sun, spp=16), VARIANT).render().rgb[..., 0]
        np.testing.assert_allclose(img[outside], lit, rtol=5e-3)  # the 0.53° disc: cos varies ±0.5 %
        np.testing.assert_allclose(img[under_right], 0.0, atol=1e-6)
        stored = round(alpha_left * 255) / 255  # the PNG keeps 8 bits
        np.testing.assert_allclose(img[under_left], lit * (1.0 - stored), rtol=5e-3)


def test_camera_rays_see_through_cut_outs_in_proportion(tmp_path):
    """A card of opacity ½ over a black ground, lit from above: half the paths stop on it (stochastic alpha)."""
    camera = PathCamera(look([0.0, 30.0, 0.0], [0.0, 0.0, 0.0], (0.0, 0.0, 1.0)), 10.0, 8, 8)
    sun = SunLight((0.0, 1.0, 0.0), (1.0, 1.0, 1.0))
    tex = card_texture(tmp_path / "half.png", 0.5, 0.5)
    card = Surface(quad(5.0, 5.0), Material("leaf", (0.8, 0.8, 0.8), texture=tex))
    ground = Surface(quad(0.0, 20.0), Material("surface", (0.0, 0.0, 0.0)))
    img = PathScene(surfaces_only([ground, card], camera, sun=sun, spp=256), VARIANT).render()
    assert img.rgb[..., 0].mean() == pytest.approx(128 / 255 * 0.8 / np.pi, rel=0.03)  # α = 128/255 in the PNG
    np.testing.assert_allclose(img.alpha, 1.0)  # every path hit something (the card or the ground)


def test_sunsky_lights_the_scene_from_above(tmp_path):
    """Mitsuba's sunsky is Z-up; rotated to Y-up the sky is above the horizon and the sun lights the ground."""
    ground = Surface(quad(0.0, 50.0), Material("surface", (0.5, 0.5, 0.5)))
    down = PathCamera(look([0.0, 10.0, 0.0], [0.0, 0.0, 0.0], (0.0, 0.0, 1.0)), 20.0, 8, 8)
    up = PathCamera(look([0.0, 1.0, 0.0], [0.0, 2.0, 0.0], (0.0, 0.0, 1.0)), 20.0, 8, 8)
    sun = SunLight(sun_vector(40.0, 120.0), (0.0, 0.0, 0.0))
    scene = PathScene(surfaces_only([ground], down, sun=sun, sky=SkyLight("sunsky"), spp=16), VARIANT)
    lit = scene.render().rgb.reshape(-1, 3).mean(axis=0)
    zenith = scene.render(up).rgb.reshape(-1, 3).mean(axis=0)
    assert lit.min() > 0.01  # the ground is lit: sun and sky are above the horizon
    assert zenith[2] > zenith[0]  # a clear sky is blue at the zenith
    # Without its sun the ground is lit by the sky alone: much darker.
    scene.params["sun_scale"] = scene.mi.Color3f(0.0)
    assert scene.render().rgb.mean() < 0.5 * lit.mean()


def test_sun_and_sky_light_an_open_ground_exactly(tmp_path):
    """Ground of albedo a under a sun of irradiance E at elevation θ and a constant sky L:
    L_out = a·(E sin θ / π + L).  Light sampling and BSDF sampling combined by MIS converge to it."""
    camera = PathCamera(look([0.0, 10.0, 0.0], [0.0, 0.0, 0.0], (0.0, 0.0, 1.0)), 10.0, 6, 6)
    ground = Surface(quad(0.0, 1000.0), Material("surface", (0.5, 0.4, 0.3)))
    sun = SunLight(sun_vector(30.0, 45.0), (2.0, 2.0, 2.0))
    sky = SkyLight("constant", radiance=(0.2, 0.3, 0.5))
    img = PathScene(surfaces_only([ground], camera, sun=sun, sky=sky, spp=256, max_depth=2), VARIANT).render()
    expected = np.array([0.5, 0.4, 0.3]) * (2.0 * 0.5 / np.pi + np.array([0.2, 0.3, 0.5]))
    np.testing.assert_allclose(img.rgb.reshape(-1, 3).mean(axis=0), expected, rtol=0.01)


def test_white_furnace_with_leaves_and_indirect_light():
    """Two stacked leaves with R + T = 1 in a uniform sky: with enough bounces every leaf shows the sky's
    radiance (energy is conserved through reflection and transmission); with direct light only the lower
    leaf hides part of the sky from the upper one."""
    camera = PathCamera(look([0.0, 10.0, 0.0], [0.0, 0.0, 0.0], (0.0, 0.0, 1.0)), 10.0, 6, 6)
    leaves = [Surface(quad(y, 20.0), Material("leaf", (1.0, 1.0, 1.0), translucency=0.5)) for y in (0.0, 1.0)]
    sky = SkyLight("constant", radiance=(0.5, 0.5, 0.5))
    deep = PathScene(surfaces_only(leaves, camera, sky=sky, spp=256, max_depth=64), VARIANT).render()
    np.testing.assert_allclose(deep.rgb.mean(), 0.5, rtol=0.02)
    direct = PathScene(surfaces_only(leaves, camera, sky=sky, spp=64, max_depth=2), VARIANT).render()
    # The upper leaf, direct light only: it reflects the sky above, R·L; the lower leaf hides the sky below,
    # so nothing is transmitted.
    np.testing.assert_allclose(direct.rgb.mean(), 0.5 * 0.5, rtol=0.02)


def test_envmap_sky_is_y_up_and_scaled(tmp_path):
    """A latitude–longitude sky bright above the horizon, black below: an upward ground sees a·L·scale."""
    env = np.zeros((32, 64, 3), np.float32)
    env[:16] = 0.4  # the image's upper half is the sky above the horizon
    path = write_image(tmp_path / "sky.exr", env)
    camera = PathCamera(look([0.0, 10.0, 0.0], [0.0, 0.0, 0.0], (0.0, 0.0, 1.0)), 10.0, 6, 6)
    ground = Surface(quad(0.0, 1000.0), Material("surface", (0.5, 0.5, 0.5)))
    sky = SkyLight("envmap", envmap=path, scale=2.0)
    img = PathScene(surfaces_only([ground], camera, sky=sky, spp=256, max_depth=2), VARIANT).render()
    np.testing.assert_allclose(img.rgb.mean(), 0.5 * 0.4 * 2.0, rtol=0.02)


# ---------------------------------------------------------------------------
# Stage 4: derivatives (path replay) against finite differences
# ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def ad_scene(library):
    """Boxes (tinted leaves, τ = 0.3) on a tinted ground under sun and sky, a 2×2 colour grid, indirect light."""
    inst = forest_set([[x, 0.0, z] for x in (-12.0, 4.0) for z in (-8.0, 10.0)], [0] * 4, scale=2.0)
    lib = BoxLibrary(library.species["box"].lods[0].parts[0].path.parent / "ad", translucency=0.3)
    grid = np.array([[[0.9, 0.6, 0.4], [0.5, 0.9, 0.5]], [[0.4, 0.5, 0.9], [0.8, 0.8, 0.3]]], np.float32)
    from forest.terrain import grid_terrain

    inputs = PathInputs(
        instances=inst,
        species=[lib.resolve("box")],
        levels=np.zeros(4, np.int64),
        matrices=inst.matrices(),
        camera=PathCamera(look([0.0, 40.0, -50.0], [0.0, 0.0, 0.0]), 45.0, 24, 18),
        terrain=grid_terrain(np.zeros((5, 5)), (60.0, 60.0)),
        sun=SunLight(sun_vector(50.0, 20.0), (2.0, 1.8, 1.6)),
        sky=SkyLight("constant", radiance=(0.3, 0.35, 0.5)),
        colour_grid=grid,
        terrain_colour=(0.3, 0.25, 0.2),
        max_depth=3,
        rr_depth=100,  # no Russian roulette: its decisions would jump under finite differences
        spp=8,
    )
    return PathScene(inputs, VARIANT)


def backward_grads(scene, names, weights) -> dict[str, np.ndarray]:
    """d(Σ w · image)/d(parameter) for the scene's parameters ``names``, by path replay (seed 3)."""
    import drjit as dr

    params = {k: scene.params[k] for k in names}
    for v in params.values():
        dr.enable_grad(v)
    try:
        scene.render_backward(weights, seed=3)
        return {k: np.asarray(dr.grad(v), np.float64) for k, v in params.items()}
    finally:
        for v in params.values():
            dr.disable_grad(v)


def _loss(scene, weights, **values):
    """Σ w · image for parameter values set by name (numpy), same seed every time."""
    mi = scene.mi
    saved = dict(scene.params)
    try:
        for k, v in values.items():
            scene.params[k] = (
                mi.TensorXf(np.asarray(v, np.float32)) if k == "colour_grid" else mi.Color3f(*map(float, v))
            )
        return float((scene.render(seed=3).rgb.astype(np.float64) * weights).sum())
    finally:
        scene.params.update(saved)


def test_reverse_mode_gradients_match_finite_differences(ad_scene):

    scene = ad_scene
    rng = np.random.default_rng(5)
    weights = rng.uniform(0.5, 1.5, (18, 24, 3))
    grid0 = np.asarray(scene.params["colour_grid"], np.float64)
    sun0 = np.asarray(scene.params["sun_irradiance"], np.float64).ravel()
    sky0 = np.asarray(scene.params["sky_radiance"], np.float64).ravel()
    grads = backward_grads(scene, ("colour_grid", "sun_irradiance", "sky_radiance"), weights)
    # The colour grid: every cell and channel, central differences.
    h = 0.02
    for idx in np.ndindex(2, 2, 3):
        up, down = grid0.copy(), grid0.copy()
        up[idx] += h
        down[idx] -= h
        fd = (_loss(scene, weights, colour_grid=up) - _loss(scene, weights, colour_grid=down)) / (2 * h)
        assert grads["colour_grid"][idx] == pytest.approx(fd, rel=0.02, abs=1e-3), idx
    # Light scales: the image is linear in each, so the difference quotient is exact.
    for name, base in (("sun_irradiance", sun0), ("sky_radiance", sky0)):
        for c in range(3):
            up = base.copy()
            up[c] += 0.1
            fd = (_loss(scene, weights, **{name: up}) - _loss(scene, weights, **{name: base})) / 0.1
            assert grads[name].ravel()[c] == pytest.approx(fd, rel=0.01), (name, c)
    assert np.abs(grads["colour_grid"]).min() > 0  # every cell is seen (directly or by its light)


def test_forward_mode_derivative_matches_finite_differences(ad_scene):
    import drjit as dr

    scene = ad_scene
    mi = scene.mi
    rng = np.random.default_rng(8)
    weights = rng.uniform(0.5, 1.5, (18, 24, 3))
    grid0 = np.asarray(scene.params["colour_grid"], np.float64)
    tangent = rng.normal(size=grid0.shape)
    g = scene.params["colour_grid"]
    dr.enable_grad(g)
    dr.set_grad(g, mi.TensorXf(tangent.astype(np.float32)))
    image_tangent = scene.render_forward(seed=3)
    dr.disable_grad(g)
    h = 0.01
    fd = (
        _loss(scene, weights, colour_grid=grid0 + h * tangent) - _loss(scene, weights, colour_grid=grid0 - h * tangent)
    ) / (2 * h)
    assert float((image_tangent * weights).sum()) == pytest.approx(fd, rel=0.01)
    # The sun scale: the derivative image of a linear parameter is the image it lights.
    sun = scene.params["sun_irradiance"]
    dr.enable_grad(sun)
    dr.set_grad(sun, mi.Color3f(1.0, 0.0, 0.0))
    d_sun = scene.render_forward(seed=3)
    dr.disable_grad(sun)
    base = _loss(scene, weights)
    bumped = _loss(scene, weights, sun_irradiance=np.asarray(sun, np.float64).ravel() + [0.5, 0.0, 0.0])
    assert float((d_sun * weights).sum()) == pytest.approx((bumped - base) / 0.5, rel=0.01)


def test_render_ad_composes_with_a_loss(ad_scene):
    """``render_ad`` behaves like ``mi.render``: dr.backward of a loss built on it fills the parameters' grads."""
    import drjit as dr

    scene = ad_scene
    mi = scene.mi
    weights = np.random.default_rng(2).uniform(0.5, 1.5, (18, 24, 3)).astype(np.float32)
    sky = scene.params["sky_radiance"]
    dr.enable_grad(sky)
    img = scene.render_ad(spp=8, seed=3)
    loss = dr.sum(img.array * mi.Float(weights.ravel()))
    dr.backward(loss)
    via_op = np.asarray(dr.grad(sky), np.float64).ravel()
    dr.set_grad(sky, mi.Color3f(0.0))
    scene.render_backward(weights, spp=8, seed=3)
    direct = np.asarray(dr.grad(sky), np.float64).ravel()
    dr.disable_grad(sky)
    np.testing.assert_allclose(via_op, direct, rtol=1e-5)
    assert (via_op > 0).all()
    np.testing.assert_allclose(np.asarray(dr.detach(img)), scene.render(spp=8, seed=3).rgb, rtol=1e-6)


def test_registered_integrator_works_with_mi_render(ad_scene):
    """``forest_path`` as a Mitsuba integrator: ``mi.render`` gives the driver's image up to noise, and gradients."""
    import drjit as dr

    scene = ad_scene
    mi = scene.mi
    integrator = scene.integrator()
    sensor = scene.sensor()
    img = np.asarray(mi.render(scene.traversal.scene, sensor=sensor, integrator=integrator, spp=64, seed=1))
    ours = scene.render(spp=64, seed=1).rgb
    assert img[..., :3].mean() == pytest.approx(ours.mean(), rel=0.03)
    sky = scene.params["sky_radiance"]
    dr.enable_grad(sky)
    params = scene.scene_parameters()
    out = mi.render(scene.traversal.scene, params, sensor=sensor, integrator=integrator, spp=8, seed=1)
    dr.backward(dr.mean(out.array))
    assert (np.asarray(dr.grad(sky)) > 0).all()
    dr.disable_grad(sky)


def test_same_inputs_and_seed_give_identical_images(ad_scene, library):
    """Bit-identical images for the same inputs and seed (also from a freshly built scene); another seed differs."""
    a = ad_scene.render(spp=4, seed=11)
    b = ad_scene.render(spp=4, seed=11)
    fresh = PathScene(ad_scene.inputs, VARIANT).render(spp=4, seed=11)
    assert np.array_equal(a.rgb, b.rgb) and np.array_equal(a.rgb, fresh.rgb) and np.array_equal(a.alpha, fresh.alpha)
    assert not np.array_equal(a.rgb, ad_scene.render(spp=4, seed=12).rgb)
    # Passes: a wavefront cap that splits the samples gives another, equally valid, deterministic image.
    cap = ad_scene.max_lanes
    try:
        ad_scene.max_lanes = 24 * 18 * 2  # two samples per pixel per pass
        c = ad_scene.render(spp=4, seed=11)
        d = ad_scene.render(spp=4, seed=11)
    finally:
        ad_scene.max_lanes = cap
    assert np.array_equal(c.rgb, d.rgb) and c.spp == 4 and not np.array_equal(c.rgb, a.rgb)
    assert c.rgb.mean() == pytest.approx(a.rgb.mean(), rel=0.05)


def test_queued_passes_are_the_passes_taken_one_at_a_time(ad_scene):
    """``passes`` queues pass k on the device before it hands back pass k − 1: each pass's sums and per-sample
    first hits equal those of ``sample_pass`` taken alone with the same seed, and stay so after the later passes
    ran (the sums are float32 views of the device's memory, which those views keep alive)."""
    import drjit as dr

    from forest.render.path.frame import pass_seed, split_passes

    cap = ad_scene.max_lanes
    try:
        ad_scene.max_lanes = 24 * 18 * 2  # two samples per pixel per pass
        queued = list(ad_scene.passes(spp=6, seed=5, aux=True))
        kernel = ad_scene.kernel()
        camera = ad_scene.inputs.camera
        with dr.suspend_grad():
            plan = split_passes(24, 18, 6, ad_scene.max_lanes)
            alone = [ad_scene.sample_pass(kernel, camera, n, pass_seed(5, k), aux=True) for k, n in enumerate(plan)]
    finally:
        ad_scene.max_lanes = cap
    assert [p.spp for p in queued] == [2, 2, 2] == [p.spp for p in alone]
    for q, a in zip(queued, alone):
        for name in ("rgb", "alpha", "rows", "albedo", "normal", "segments"):
            assert np.array_equal(getattr(q, name), getattr(a, name)), name
        assert q.rgb.dtype == np.float32 and q.rgb.shape == (24 * 18, 3) and q.alpha.shape == (24 * 18,)
    # The passes differ (their own seeds), and the render sums them in float64 to the same image as before.
    assert not np.array_equal(queued[0].rgb, queued[1].rgb)
    total = sum(p.rgb.astype(np.float64) for p in queued) / 6
    cap = ad_scene.max_lanes
    try:
        ad_scene.max_lanes = 24 * 18 * 2
        image = ad_scene.render(spp=6, seed=5)
    finally:
        ad_scene.max_lanes = cap
    assert np.array_equal(image.rgb, total.reshape(18, 24, 3).astype(np.float32))


def test_on_pass_sees_the_running_image_when_it_asks(tmp_path, library):
    """``render_scene(on_pass=…)`` gets each pass's running mean (made only for such a callback): the last one
    is the written beauty, and the passes count up to the frame's."""
    cfg = make_config(tmp_path, extra=CARD).with_overrides({"render.width": 32, "render.height": 24, "render.spp": 8})
    seen: list[tuple[int, np.ndarray, int, int]] = []
    scene = load_scene(cfg, forest_set([[0.0, 0.0, 0.0], [6.0, 0.0, 4.0]], [0, 0]), library=library)
    out = tmp_path / "frame.exr"
    import forest.render.path.frame as path_frame

    cap = path_frame.MAX_LANES
    try:
        path_frame.MAX_LANES = 32 * 24 * 2  # four passes of two samples
        render_scene(scene, output=out, variant=VARIANT, on_pass=lambda *a: seen.append(a))
    finally:
        path_frame.MAX_LANES = cap
    assert [(f, done, n) for f, _, done, n in seen] == [(1, k, 4) for k in (1, 2, 3, 4)]
    assert all(img.shape == (24, 32, 3) and img.dtype == np.float32 for _, img, _, _ in seen)
    assert not np.array_equal(seen[0][1], seen[-1][1])
    np.testing.assert_array_equal(seen[-1][1], read_exr(out)["rgb"])


def test_a_rounded_sample_count_is_taken_and_reported(ad_scene):
    """multijitter rounds 34 samples to its 5 × 7 grid: the render takes 35 and says so."""
    import mitsuba as mi

    from forest.render.path.frame import sampler_count

    assert sampler_count(mi, "multijitter", 34) == 35 and sampler_count(mi, "multijitter", 16) == 16
    assert sampler_count(mi, "independent", 34) == 34
    assert ad_scene.render(spp=34, seed=3).spp == 35


def test_stratified_samples_leave_less_noise_than_independent_ones(ad_scene):
    """A pixel's samples are one stratified sequence: multijitter's per-pixel noise (two seeds) is well under
    independent sampling's at the same spp and the same mean (it was the same before the sampler was told)."""
    from dataclasses import replace

    def noise(scene):
        a, b = (np.asarray(scene.render(spp=16, seed=s).rgb, np.float64) for s in (21, 22))
        return float(np.var(a - b) / 2), float((a + b).mean() / 2)

    strat, mean_s = noise(ad_scene)
    indep, mean_i = noise(PathScene(replace(ad_scene.inputs, sampler="independent"), VARIANT))
    assert ad_scene.inputs.sampler == "multijitter"
    assert strat < 0.4 * indep, (strat, indep)  # 0.14 here; 0.76 when each lane was its own sequence
    assert mean_s == pytest.approx(mean_i, rel=0.03)


def test_a_forest_too_large_for_memory_fails_before_loading(library, monkeypatch):
    """The instance records' memory is checked against what is available: one line naming [lod] distances."""
    import forest.render.path.frame as frame
    from forest.errors import ForestError

    inst = forest_set([[x, 0.0, 0.0] for x in range(-20, 21, 4)], [0] * 11)
    inputs = PathInputs(
        instances=inst,
        species=[library.resolve("box")],
        levels=np.zeros(11, np.int64),
        matrices=inst.matrices(),
        camera=PathCamera(look([0.0, 10.0, -30.0], [0.0, 0.0, 0.0]), 40.0, 8, 8),
        sun=SunLight((0.0, 1.0, 0.0), (1.0, 1.0, 1.0)),
        flatten_triangles=0,
    )
    headroom = frame.memory_headroom(8, 8, inputs.spp)
    assert frame.MEMORY_MARGIN <= headroom < frame.MEMORY_HEADROOM  # a small image keeps a small headroom
    assert frame.memory_headroom(1920, 1080, 64) == frame.MEMORY_HEADROOM
    monkeypatch.setattr(frame, "available_bytes", lambda: headroom + 10 * 16 * 1024)
    with pytest.raises(ForestError, match=r"\[lod\] distances: 11 instanced trees .* GB") as err:
        PathScene(inputs, VARIANT)
    assert "\n" not in str(err.value)
    monkeypatch.setattr(frame, "available_bytes", lambda: headroom + 11 * 16 * 1024)
    assert PathScene(inputs, VARIANT).stats.instances == 11
    # The trees fit, a 1920×1080 image's film and passes beside them do not: the message names the image size.
    big = replace(inputs, camera=PathCamera(inputs.camera.to_world, 40.0, 1920, 1080))
    monkeypatch.setattr(frame, "available_bytes", lambda: frame.MEMORY_MARGIN + 11 * 16 * 1024 + (64 << 20))
    with pytest.raises(ForestError, match=r"^\[render\] width, height: a 1920x1080 image needs about 0\.8 GB") as err:
        PathScene(big, VARIANT)
    assert "[lod]" not in str(err.value)


def test_render_frame_returns_every_layer(ad_scene):
    """``render_frame``: beauty, coverage and the depth/id/species layers of one still, all (H, W)."""
    from forest.render.path import render_frame

    out = render_frame(ad_scene.inputs)
    h, w = 18, 24
    assert out["rgb"].shape == (h, w, 3) and out["alpha"].shape == (h, w)
    assert {k: out[k].shape for k in ("depth", "id", "species")} == {k: (h, w) for k in ("depth", "id", "species")}
    assert set(np.unique(out["id"]).astype(int)) <= {-1, 500, 501, 502, 503}
    assert (out["alpha"][out["id"] >= 0] > 0.5).all() and out["spp"] == 8


def test_colour_grid_follows_the_map_convention(library):
    """A 2×3 colour grid over the terrain: row i → +Z (row 0 at zmin), column j → +X, seen where each cell lies."""
    from forest.terrain import grid_terrain

    grid = np.array(
        [
            [[0.9, 0.1, 0.1], [0.1, 0.9, 0.1], [0.1, 0.1, 0.9]],  # z < 0: red, green, blue from −X to +X
            [[0.9, 0.9, 0.1], [0.1, 0.9, 0.9], [0.9, 0.1, 0.9]],  # z > 0: yellow, cyan, magenta
        ],
        np.float32,
    )
    camera = PathCamera(look([0.0, 200.0, 0.0], [0.0, 0.0, 0.0], (0.0, 0.0, 1.0)), 30.0, 60, 60)
    inputs = surfaces_only([], camera, sky=SkyLight("constant", radiance=(1.0, 1.0, 1.0)), spp=4, library=library)
    inputs.terrain = grid_terrain(np.zeros((9, 9)), (96.0, 96.0))
    inputs.terrain_colour = (1.0, 1.0, 1.0)
    inputs.colour_grid = grid
    img = PathScene(inputs, VARIANT).render().rgb
    for i, z in enumerate((-24.0, 24.0)):
        for j, x in enumerate((-32.0, 0.0, 32.0)):
            # Near a texel centre (bilinear weights ≥ 94 % on the cell itself).
            mask = ground_mask(camera, (x - 2.0, x + 2.0), (z - 2.0, z + 2.0))
            assert mask.any()
            colour = img[mask].mean(axis=0)
            np.testing.assert_allclose(colour / colour.max(), grid[i, j] / grid[i, j].max(), atol=0.07)


# ---------------------------------------------------------------------------
# Aerial perspective
# ---------------------------------------------------------------------------


def test_haze_closed_forms_agree_in_numpy_and_drjit():
    """The transmittance of the exponential height fog against a numerical integral, the numpy and drjit
    forms against each other, and the Henyey–Greenstein phase function integrating to 1 over the sphere."""
    import drjit as dr

    from forest.render.path.haze import HazeInputs, HazeModel, hg_np, transmittance_np
    from forest.runtime import mitsuba

    mi = mitsuba(VARIANT)
    haze = HazeInputs(density=0.003, height=80.0, colour=(0.2, 0.3, 0.4), anisotropy=0.6, ground=-5.0)
    rng = np.random.default_rng(1)
    oy = rng.uniform(-5.0, 300.0, 64)
    d = rng.normal(size=(64, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d[:4, 1] = [0.0, 1e-6, -1e-6, 1e-3]  # level rays: the series branch
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    ell = rng.uniform(1.0, 2000.0, 64)
    ref = []
    for y0, dy, length in zip(oy, d[:, 1], ell):
        s = np.linspace(0.0, length, 20_001)
        ref.append(np.exp(-np.trapezoid(0.003 * np.exp(-(y0 + s * dy + 5.0) / 80.0), s)))
    np.testing.assert_allclose(transmittance_np(oy, d[:, 1], ell, haze), ref, rtol=1e-6, atol=1e-9)
    model = HazeModel(mi, haze, HazeModel.initial_params(mi, haze), None)
    o = mi.Point3f(
        mi.Float(np.zeros(64, np.float32)), mi.Float(oy.astype(np.float32)), mi.Float(np.zeros(64, np.float32))
    )
    t = model.transmittance(o, mi.Vector3f(*[mi.Float(d[:, k].astype(np.float32)) for k in range(3)]), mi.Float(ell))
    np.testing.assert_allclose(np.asarray(t), ref, rtol=2e-4, atol=1e-6)
    mu = np.linspace(-1.0, 1.0, 200_001)
    for g in (0.0, 0.6, -0.3):
        assert 2 * np.pi * np.trapezoid(hg_np(mu, g), mu) == pytest.approx(1.0, rel=1e-4)
    assert dr.width(t) == 64


def test_haze_glows_toward_the_sun_and_fades_distant_ground(library):
    """Sky seen through a uniform haze: brighter looking toward the sun than away from it (forward
    scattering, g = 0.7); a dark ground far away tends to the haze's radiance J, near it stays dark."""
    from forest.render.path.haze import HazeInputs, hg_np

    sun = SunLight(sun_vector(10.0, 0.0), (3.0, 3.0, 3.0))  # low in the north (+Z)
    ground = Surface(quad(0.0, 5000.0), Material("surface", (0.0, 0.0, 0.0)))
    haze = HazeInputs(density=0.002, height=1e5, colour=(0.1, 0.1, 0.1), anisotropy=0.7, sky_distance=4000.0)
    images = {}
    for name, target in (("toward", (0.0, 12.0, 100.0)), ("away", (0.0, 12.0, -100.0))):
        camera = PathCamera(look([0.0, 10.0, 0.0], target), 30.0, 16, 16)
        inputs = surfaces_only([ground], camera, sun=sun, sky=None, spp=8, max_depth=2)
        inputs.haze = haze
        images[name] = PathScene(inputs, VARIANT).render().rgb
    assert images["toward"][:4].mean() > 3 * images["away"][:4].mean()  # the upper rows: sky
    # Sky rows looking away from the sun: J = C + E·p(μ) with μ ≈ −cos(10° + 1°), hazed over 4 km.
    mu = -np.cos(np.radians(11.0))
    j = 0.1 + 3.0 * hg_np(mu, 0.7)
    t = np.exp(-0.002 * 4000.0)
    assert images["away"][0].mean() == pytest.approx(j * (1 - t), rel=0.1)
    # The ground 10 m below: far rows (near the horizon) brighter than near ones, below J.
    assert images["away"][-1].mean() < images["away"][9].mean() < j


@pytest.fixture(scope="module")
def haze_scene(library):
    """Boxes on a tinted ground under sun and sky seen through a height-falloff haze."""
    from forest.render.path.haze import HazeInputs
    from forest.terrain import grid_terrain

    inst = forest_set([[x, 0.0, z] for x in (-12.0, 4.0) for z in (-8.0, 10.0)], [0] * 4, scale=2.0)
    inputs = PathInputs(
        instances=inst,
        species=[library.resolve("box")],
        levels=np.zeros(4, np.int64),
        matrices=inst.matrices(),
        camera=PathCamera(look([0.0, 40.0, -50.0], [0.0, 0.0, 0.0]), 45.0, 24, 18),
        terrain=grid_terrain(np.zeros((5, 5)), (60.0, 60.0)),
        sun=SunLight(sun_vector(50.0, 20.0), (2.0, 1.8, 1.6)),
        sky=SkyLight("constant", radiance=(0.3, 0.35, 0.5)),
        terrain_colour=(0.3, 0.25, 0.2),
        haze=HazeInputs(density=0.01, height=30.0, colour=(0.4, 0.45, 0.6), anisotropy=0.5, sky_distance=500.0),
        max_depth=3,
        rr_depth=100,
        spp=8,
    )
    return PathScene(inputs, VARIANT)


def test_haze_gradients_match_finite_differences(haze_scene):
    """Reverse and forward mode with respect to the haze's density, height, colour and anisotropy."""
    import drjit as dr

    scene = haze_scene
    mi = scene.mi
    weights = np.random.default_rng(3).uniform(0.5, 1.5, (18, 24, 3))
    names = ("haze_density", "haze_height", "haze_anisotropy", "haze_colour")
    base = {k: np.asarray(scene.params[k], np.float64).ravel().copy() for k in names}

    def loss(**values) -> float:
        saved = dict(scene.params)
        try:
            for k, v in values.items():
                scene.params[k] = mi.Color3f(*map(float, v)) if k == "haze_colour" else mi.Float(float(v[0]))
            return float((scene.render(seed=3).rgb.astype(np.float64) * weights).sum())
        finally:
            scene.params.update(saved)

    grads = {k: g.ravel() for k, g in backward_grads(scene, names, weights).items()}
    steps = {"haze_density": 1e-4, "haze_height": 0.5, "haze_anisotropy": 0.01, "haze_colour": 0.02}
    for k in names:
        for c in range(len(base[k])):
            up, down = base[k].copy(), base[k].copy()
            up[c] += steps[k]
            down[c] -= steps[k]
            fd = (loss(**{k: up}) - loss(**{k: down})) / (2 * steps[k])
            assert grads[k][c] == pytest.approx(fd, rel=0.02), (k, c)
    # Forward mode along the density.
    d = scene.params["haze_density"]
    dr.enable_grad(d)
    dr.set_grad(d, mi.Float(1.0))
    tangent = scene.render_forward(seed=3)
    dr.disable_grad(d)
    assert float((tangent * weights).sum()) == pytest.approx(grads["haze_density"][0], rel=0.01)


@pytest.mark.parametrize("exponent", [1.0, 6.5])
def test_the_gradient_sky_band_sends_its_stated_irradiance(exponent):
    """SkyBasis: each basis of the gradient sky, L = zenith·(1 − b) + horizon·b with b = (1 − μ)^k, delivers onto an
    upward plane what power() and horizon_irradiance() state (2π/((k + 1)(k + 2)) for the horizon, π minus it for the
    zenith): E = 2π∫ℓ(μ)μ dμ integrated over its evaluated radiance; it evaluates to gradient_radiance(), and its
    light samples carry the radiance of their direction."""
    import drjit as dr

    from forest.render.path.emitters import SkyBasis, gradient_radiance, horizon_irradiance
    from forest.runtime import mitsuba

    mi = mitsuba(VARIANT)
    n = 20000
    mu = (np.arange(n) + 0.5) / n
    d = mi.Vector3f(mi.Float(np.sqrt(1.0 - mu * mu)), mi.Float(mu), mi.Float(np.zeros(n)))
    g = (np.arange(32) + 0.5) / 32
    u = mi.Point2f(*(mi.Float(a.ravel()) for a in np.meshgrid(g, g)))
    a_k = horizon_irradiance(exponent)
    for zenith, expected in ((False, a_k), (True, np.pi - a_k)):
        light = SkyBasis(mi, "sky_zenith" if zenith else "sky_horizon", [1.0, 1.0, 1.0], zenith, exponent)
        ell = np.asarray(light.eval(mi.Color3f(1.0), d, mi.Bool(True)).x, np.float64)
        assert 2.0 * np.pi * float(np.sum(ell * mu)) / n == pytest.approx(expected, rel=1e-4)
        assert light.power(np.ones(3)) == pytest.approx(expected)
        z, h = (np.ones(3), np.zeros(3)) if zenith else (np.zeros(3), np.ones(3))
        assert np.allclose(ell, gradient_radiance(z, h, mu[:, None], exponent)[:, 0], atol=1e-5)
        ds, _, value = light.sample(mi.Color3f(1.0), u, mi.Bool(True))
        back = light.eval(mi.Color3f(1.0), ds, mi.Bool(True))
        assert np.allclose(np.asarray(value.x), np.asarray(back.x), atol=1e-6)
        assert float(dr.min(ds.y)[0]) >= 0.0


def test_a_sample_that_is_not_finite_counts_as_black(ad_scene):
    """One NaN or infinite sample (a path that met a degenerate surface) leaves its pixel finite: it adds 0 to
    the pixel's sum and the other samples are kept, where it used to turn the whole pixel NaN."""
    import drjit as dr

    from forest.render.path.frame import pass_seed

    kernel, camera = ad_scene.kernel(), ad_scene.inputs.camera

    class Poisoned:
        """The kernel, with the first sample of pixel 0 NaN and the first of pixel 1 infinite."""

        def sample(self, *args, **kwargs):
            out = kernel.sample(*args, **kwargs)
            idx = dr.arange(ad_scene.mi.UInt32, dr.width(out[0][0]))
            bad = dr.select(idx == 0, dr.nan, dr.select(idx == 4, dr.inf, 0.0))
            return (type(out[0])(out[0][0] + bad, out[0][1], out[0][2]), *out[1:])

    with dr.suspend_grad():
        clean = ad_scene.sample_pass(kernel, camera, 4, pass_seed(3, 0))
        poisoned = ad_scene.sample_pass(Poisoned(), camera, 4, pass_seed(3, 0))
    assert np.isfinite(poisoned.rgb).all()
    assert np.array_equal(poisoned.rgb[2:], clean.rgb[2:])
    assert (poisoned.rgb[:2] <= clean.rgb[:2] + 1e-6).all() and (poisoned.rgb[:2] > 0).any()
