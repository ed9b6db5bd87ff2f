"""Look-dev: references, losses, gradients through the proxy, a synthetic round trip, outputs, transfer.

Everything renders tiny images in ``llvm_ad_rgb`` (the proxy) and ``scalar_rgb``
(the production render the fitted values must transfer to).
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from conftest import run_forest, write_png, write_scene

pytestmark = pytest.mark.filterwarnings("ignore::UserWarning")

SCENE = """
seed = 5
[terrain.procedural]
size = 60.0
height = 4.0
resolution = 16
[scatter]
count = 30
[[species]]
model = "broadleaf"
percent = 100
scale = [0.5, 0.7]
[camera]
position = [0.0, 52.0, -50.0]
target = [0.0, 0.0, 2.0]
fov = 68
[lights.sun]
elevation = 35
azimuth = 130
irradiance = 3.0
colour = [1.0, 0.95, 0.85]
[lights.sky]
radiance = 0.4
colour = [0.6, 0.75, 1.0]
[render]
width = 48
height = 36
spp = 32
max_depth = 4
"""
W, H = 48, 36
GRID = 4


def _hidden_grid() -> np.ndarray:
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([11, 1])))
    return rng.uniform(0.35, 1.0, (GRID, GRID, 3))


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    """(config, instances, terrain, proxy, truth state): built once for the module."""
    from forest.config import load_config
    from forest.lookdev.forest_proxy import build_proxy
    from forest.lookdev.state import state_from_config
    from forest.scene import load_scene

    folder = tmp_path_factory.mktemp("lookdev")
    cfg = load_config(write_scene(folder, SCENE))
    scene = load_scene(cfg)
    truth = state_from_config(cfg, _hidden_grid())
    proxy = build_proxy(scene, width=W, height=H, grid_shape=(GRID, GRID), variant="llvm_ad_rgb", state=truth)
    return cfg, scene.instances, scene, proxy, truth


def _reference(proxy, state, spp=64, passes=8):
    proxy.set_state(state)
    return proxy.render_numpy(spp, 4242, passes=passes)


# -- references -----------------------------------------------------------------------------


def test_reference_errors_name_the_file(tmp_path):
    from forest.errors import ForestError
    from forest.lookdev.reference import load_reference

    with pytest.raises(ForestError, match="not found"):
        load_reference(tmp_path / "missing.png", 16, 12)
    bad = tmp_path / "garbage.png"
    bad.write_bytes(b"not an image at all" * 10)
    with pytest.raises(ForestError, match=r"garbage\.png"):
        load_reference(bad, 16, 12)
    black = write_png(tmp_path / "black.png", np.zeros((12, 16, 3)))
    with pytest.raises(ForestError, match="all black"):
        load_reference(black, 16, 12)
    ok = write_png(tmp_path / "ok.png", np.full((12, 16, 3), 0.5))
    with pytest.raises(ForestError, match="over the"):
        load_reference(ok, 16, 12, max_bytes=10)
    mask = write_png(tmp_path / "mask.png", np.zeros((12, 16)))
    with pytest.raises(ForestError, match="mask excludes"):
        load_reference(ok, 16, 12, mask=mask)


def test_reference_wrong_aspect_is_cropped_with_a_warning(tmp_path):
    from forest.lookdev.reference import load_reference

    img = np.zeros((20, 40, 3))
    img[:, 10:30] = 0.5  # the centre 20×20 is grey, the sides black
    p = write_png(tmp_path / "wide.png", img)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ref = load_reference(p, 8, 8)
    assert any("centre-cropped" in str(w.message) for w in caught)
    assert ref.rgb.shape == (8, 8, 3)
    # Only the grey centre survives the crop; 0.5 sRGB-encoded decodes to linear ≈ 0.214.
    assert np.allclose(ref.rgb, 0.2140, atol=2e-3)


# -- losses ---------------------------------------------------------------------------------


@pytest.mark.parametrize("mode", ["aligned", "statistics"])
def test_loss_gradient_points_back_to_the_reference(mode):
    from forest.runtime import mitsuba

    mi = mitsuba("llvm_ad_rgb")
    import drjit as dr

    from forest.lookdev.losses import make_loss
    from forest.lookdev.reference import load_reference

    rng = np.random.default_rng(1)
    ref = (rng.random((12, 16, 3)) * 0.5).astype(np.float32)
    loss = make_loss(mode, load_reference(ref, 16, 12), bands=2)
    assert loss.numpy(ref) < 1e-9
    for scale, sign in ((1.5, 1.0), (0.6, -1.0)):
        x = mi.Float(scale)
        dr.enable_grad(x)
        value = loss(mi.TensorXf(mi.Float(ref.ravel()) * x, (12, 16, 3)))
        dr.backward(value)
        assert float(value[0]) > 0
        assert sign * float(dr.grad(x)[0]) > 0  # descending moves the scale back towards 1


def test_statistics_loss_ignores_where_colours_are():
    from forest.lookdev.losses import StatisticsLoss
    from forest.lookdev.reference import load_reference

    rng = np.random.default_rng(2)
    ref = (rng.random((12, 16, 3)) * 0.6).astype(np.float32)
    loss = StatisticsLoss(load_reference(ref, 16, 12), bands=1, pool=1)
    shuffled = rng.permutation(ref.reshape(-1, 3)).reshape(ref.shape)
    assert loss.numpy(shuffled) < 1e-9
    assert loss.numpy(ref * 1.3) > 1e-4


# -- gradients through the proxy --------------------------------------------------------------


def test_proxy_merges_trees_into_few_meshes(setup):
    _cfg, inst, _terrain, proxy, _truth = setup
    st = proxy.stats
    assert st["trees"] == len(inst) and 0 < st["kept"] <= st["trees"]
    assert st["meshes"] <= 4  # one mesh per material, not per tree
    keys = [t.key for t in proxy.grid_targets]
    assert any(k.startswith("terrain.") for k in keys) and any(k.startswith("forest_") for k in keys)


def _grads(proxy, loss, state, seeds=4):
    import drjit as dr

    from forest.lookdev.optimise import _Variables

    var = _Variables(proxy.mi, proxy, state, {"colour_map", "sun", "sky"}, "aligned", state.grid)
    proxy.set_state(state)
    out = {}
    for seed in range(seeds):
        var.apply()
        dr.backward(loss(proxy.render(8, seed=seed, grad=True)))
        for k in var.opt.keys():  # noqa: SIM118 - mi.ad.Optimizer
            out[k] = out.get(k, 0.0) + np.asarray(dr.grad(var.opt[k]), dtype=np.float64).ravel()
            dr.set_grad(var.opt[k], 0)
    return out


def test_gradients_are_nonzero_and_point_the_right_way(setup):
    from forest.lookdev.losses import AlignedLoss
    from forest.lookdev.reference import load_reference

    _cfg, _inst, _terrain, proxy, truth = setup
    loss = AlignedLoss(load_reference(_reference(proxy, truth), W, H))
    bright_sun = truth.copy()
    bright_sun.sun_irradiance *= 1.5
    assert _grads(proxy, loss, bright_sun)["sun_log"][0] > 0  # descending lowers the sun
    dark_sky = truth.copy()
    dark_sky.sky_radiance *= 0.6
    assert _grads(proxy, loss, dark_sky)["sky_log"][0] < 0  # descending raises the sky
    dark_map = truth.copy()
    dark_map.grid = truth.grid * 0.6
    g = _grads(proxy, loss, dark_map)["grid"]
    seen = np.abs(g) > 0
    assert seen.mean() > 0.5  # most cells are seen and get a gradient
    assert (g[seen] < 0).mean() > 0.8  # descending brightens the map


def test_grid_jacobian_agrees_with_reverse_mode(setup):
    """The nine forward-mode passes give J = ∂I/∂g; summed over pixels it is the reverse-mode gradient of ΣI."""
    import drjit as dr

    from forest.lookdev.optimise import _grid_jacobian

    _cfg, _inst, _terrain, proxy, truth = setup
    mi = proxy.mi
    proxy.set_state(truth)
    grid = truth.grid.ravel()
    jac = _grid_jacobian(proxy, grid, spp=32, seed=3)  # (pixels, cells, 3)
    assert jac.shape == (W * H, GRID * GRID, 3)
    sky = proxy.sky_mask().ravel()
    assert sky.any() and np.abs(jac[sky]).max() == 0.0  # the sky does not depend on the map
    g = mi.Float(grid.astype(np.float32))
    dr.enable_grad(g)
    proxy.set_grid(g)
    proxy.params.update()
    dr.backward(dr.sum(proxy.render(32, seed=5, grad=True).array))
    reverse = np.asarray(dr.grad(g), np.float64).reshape(-1, 3)
    forward = jac.sum(axis=0)
    assert np.corrcoef(reverse.ravel(), forward.ravel())[0, 1] > 0.98
    assert abs(forward.sum() / reverse.sum() - 1) < 0.08
    proxy.set_state(truth)


def test_noise_weights_weigh_noisy_pixels_down():
    from forest.lookdev.losses import AlignedLoss
    from forest.lookdev.reference import load_reference
    from forest.runtime import mitsuba

    mi = mitsuba("llvm_ad_rgb")
    rng = np.random.Generator(np.random.PCG64(3))
    ref = rng.uniform(0.2, 0.8, (12, 16, 3)).astype(np.float32)
    loss = AlignedLoss(load_reference(ref, 16, 12))
    before = loss.value_weight.copy()
    variance = np.full(ref.shape, 1e-4)
    variance[:4, :4] = 1e-1  # a noisy corner (an edge, say)
    loss.set_noise(variance)
    after = loss.value_weight
    assert np.isclose(after.sum(), before.sum())  # the loss keeps its scale
    ratio = after / before
    assert ratio[:4, :4].max() < 0.05 * ratio[6:, 6:].min()
    img = rng.uniform(0.2, 0.8, ref.shape).astype(np.float32)
    value = loss(mi.TensorXf(mi.Float(img.ravel()), img.shape))
    assert np.isclose(float(value[0]), loss.numpy(img), rtol=1e-4)  # drjit and numpy losses agree


def test_calibration_gain_scales_the_scene_not_the_sky(setup):
    from forest.lookdev.calibrate import channel_gain

    _cfg, _inst, _terrain, proxy, truth = setup
    proxy.set_state(truth)
    plain = proxy.render_numpy(16, 7)
    hit = ~proxy.sky_mask()
    k = channel_gain(plain * np.array([1.2, 1.0, 0.5]), plain, hit)
    assert np.allclose(k, [1.2, 1.0, 0.5], rtol=1e-6)
    proxy.set_gain(k)
    try:
        gained = proxy.render_numpy(16, 7)
    finally:
        proxy.set_gain(None)
    assert np.allclose(gained[hit], plain[hit] * k, rtol=1e-4, atol=1e-6)
    assert np.allclose(gained[~hit], plain[~hit])


# -- synthetic round trip -----------------------------------------------------------------------


def test_round_trip_recovers_known_values(setup):
    from forest.lookdev.colour import delta_e2000
    from forest.lookdev.losses import AlignedLoss
    from forest.lookdev.optimise import optimise
    from forest.lookdev.reference import load_reference

    _cfg, _inst, _terrain, proxy, truth = setup
    loss = AlignedLoss(load_reference(_reference(proxy, truth), W, H))
    start = truth.copy()
    start.grid = np.full_like(truth.grid, 0.7)
    start.sun_irradiance *= 1.3
    start.sky_radiance *= 0.75
    fit = optimise(proxy, loss, start, groups={"colour_map", "sun", "sky"}, iterations=150, spp=4, seed=1)
    res = fit.result
    assert fit.losses[-1] < 0.5 * fit.losses[0]
    seen = ~np.isclose(res.grid, start.grid).all(axis=2)
    de = delta_e2000(res.grid[seen], truth.grid[seen])
    de_start = delta_e2000(start.grid[seen], truth.grid[seen])
    assert seen.mean() > 0.7
    assert np.median(de) < 0.4 * np.median(de_start)
    assert abs(res.sky_radiance / truth.sky_radiance - 1) < 0.03
    assert abs(res.sun_irradiance / truth.sun_irradiance - 1) < 0.12
    assert abs(res.sun_irradiance / truth.sun_irradiance - 1) < abs(start.sun_irradiance / truth.sun_irradiance - 1)


def test_polish_walks_the_sun_against_map_direction(setup, monkeypatch):
    """Start on the nearly flat "brighter sun, darker map" direction: the Gauss–Newton polish walks back along
    it, further than Adam alone in the same number of iterations."""
    import forest.lookdev.optimise as opt
    from forest.lookdev.losses import AlignedLoss
    from forest.lookdev.reference import load_reference

    _cfg, _inst, _terrain, proxy, truth = setup
    loss = AlignedLoss(load_reference(_reference(proxy, truth), W, H))
    start = truth.copy()
    start.sun_irradiance *= 1.25
    start.grid = truth.grid / 1.25

    def sun_error(polish: bool) -> tuple[float, object]:
        monkeypatch.setattr(opt, "POLISH_FRACTION", 0.6 if polish else 0.0)
        assert (opt.polish_iterations(40) > 0) == polish
        fit = opt.optimise(proxy, loss, start, groups={"colour_map", "sun", "sky"}, iterations=40, spp=4, seed=2)
        return abs(fit.result.sun_irradiance / truth.sun_irradiance - 1), fit.result

    err_adam, _ = sun_error(False)
    err, res = sun_error(True)
    assert err < 0.6 * 0.25
    assert err < 0.7 * err_adam
    ratio = res.grid.mean(axis=(0, 1)) / truth.grid.mean(axis=(0, 1))
    assert np.all(ratio > 1 / 1.25 + 0.05)  # the map brightened back with it
    assert abs(res.sky_radiance / truth.sky_radiance - 1) < 0.03


# -- match(): outputs, CLI, transfer to the production render --------------------------------------


@pytest.mark.xfail(
    reason="the merged look-dev proxy no longer renders like production (haze per path segment, ground rules, "
    "individuals); look-dev moves onto the production renderer",
    strict=False,
)
def test_match_writes_a_scene_that_renders_like_the_reference(setup, tmp_path):
    """Aligned fit on the proxy; the full scalar_rgb render of the written scene.toml matches as well."""
    from forest.config import load_config
    from forest.images import read_image, read_map_rgb
    from forest.lookdev import match
    from forest.lookdev.colour import delta_e2000
    from forest.render import render_scene
    from forest.scene import load_scene

    cfg, inst, _scene, _proxy, _truth = setup
    # The reference: the production renderer with a hidden colour map and other light values.
    hidden = tmp_path / "hidden"
    hidden.mkdir()
    from forest.images import write_image

    write_image(hidden / "map.exr", _hidden_grid().astype(np.float32), half=False)
    text = SCENE.replace("irradiance = 3.0", "irradiance = 3.6").replace("radiance = 0.4", "radiance = 0.34")
    hcfg = load_config(write_scene(hidden, text + '\n[maps]\ncolour = "map.exr"\n'))
    render_scene(load_scene(hcfg, inst), output=hidden / "ref.exr", variant="scalar_rgb")
    ref_path = hidden / "ref.exr"

    out = tmp_path / "lookdev"
    r = match(load_scene(cfg, inst), ref_path, out, iterations=60, spp=4, resolution=W, grid=GRID)
    assert sorted(p.name for p in out.iterdir()) == ["colour_map.exr", "match.json", "report.png", "scene.toml"]
    assert r.figures["result_delta_e_mean"] < r.figures["start_delta_e_mean"]
    fitted = load_config(r.scene_path)
    assert fitted.maps.colour == out / "colour_map.exr"
    assert np.allclose(read_map_rgb(fitted.maps.colour), r.result.grid, atol=1e-4)
    assert math.isclose(fitted.lights.sun.irradiance, r.result.sun_irradiance, rel_tol=1e-5)
    # Transfer: the full render of the fitted scene is about as close to the reference as the proxy was.
    render_scene(load_scene(fitted, inst), output=tmp_path / "full.exr", variant="scalar_rgb")
    full = read_image(tmp_path / "full.exr")[..., :3]
    ref = read_image(ref_path)[..., :3]
    full_de = float(delta_e2000(full.reshape(-1, 3), ref.reshape(-1, 3)).mean())
    start_full = tmp_path / "start.exr"
    render_scene(load_scene(cfg, inst), output=start_full, variant="scalar_rgb")
    start_de = float(delta_e2000(read_image(start_full)[..., :3].reshape(-1, 3), ref.reshape(-1, 3)).mean())
    print(f"transfer: proxy {r.figures['result_delta_e_mean']:.2f} full {full_de:.2f} start {start_de:.2f}")
    assert full_de < r.figures["result_delta_e_mean"] + 1.5
    assert full_de < 0.5 * start_de


def test_cli_bad_reference_exits_2_without_output(tmp_path):
    cfg = write_scene(tmp_path, SCENE)
    black = write_png(tmp_path / "black.png", np.zeros((36, 48, 3)))
    r = run_forest("match", cfg, "--reference", black, "-o", tmp_path / "out", "--iterations", "2")
    assert r.returncode == 2
    assert "all black" in r.stderr and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()
    r = run_forest("match", cfg, "--reference", black, "-o", tmp_path / "out", "--params", "colour_map,moon")
    assert r.returncode == 2 and "moon" in r.stderr


def test_sun_direction_search_finds_the_shadows(setup):
    """No gradient for a directional sun's direction in 3.9.1: the pattern search must find it."""
    from forest.lookdev.losses import AlignedLoss
    from forest.lookdev.optimise import optimise
    from forest.lookdev.reference import load_reference

    _cfg, _inst, _terrain, proxy, truth = setup
    loss = AlignedLoss(load_reference(_reference(proxy, truth), W, H))
    start = truth.copy()
    start.sun_azimuth += 8.0
    start.sun_elevation -= 4.0
    fit = optimise(proxy, loss, start, groups={"sun_direction"}, iterations=4, spp=4, seed=2)
    assert fit.search
    assert abs(fit.result.sun_azimuth - truth.sun_azimuth) <= 2.0 + 1e-9
    assert abs(fit.result.sun_elevation - truth.sun_elevation) <= 2.0 + 1e-9
    proxy.set_state(truth)


@pytest.mark.xfail(
    reason="the merged look-dev proxy no longer renders like production (haze per path segment, ground rules, "
    "individuals); look-dev moves onto the production renderer",
    strict=False,
)
def test_proxy_applies_the_renderers_haze(tmp_path):
    """[render] haze is part of the production image, so the proxy must render it too."""
    from forest.config import load_config
    from forest.images import read_image
    from forest.lookdev.colour import delta_e2000
    from forest.lookdev.forest_proxy import build_proxy
    from forest.lookdev.state import state_from_config
    from forest.render import render_scene
    from forest.scene import load_scene

    cfg = load_config(write_scene(tmp_path, SCENE.replace("max_depth = 4", "max_depth = 4\nhaze = 0.01")))
    scene = load_scene(cfg)
    st = state_from_config(cfg, np.ones((GRID, GRID, 3)))
    proxy = build_proxy(scene, width=W, height=H, grid_shape=(GRID, GRID), variant="llvm_ad_rgb", state=st)
    proxy.set_state(st)
    hazed = proxy.render_numpy(32, 1, passes=2)
    proxy.haze = 0.0
    clear = proxy.render_numpy(32, 1, passes=2)
    render_scene(scene, output=tmp_path / "full.exr", variant="scalar_rgb")
    full = read_image(tmp_path / "full.exr")[..., :3].reshape(-1, 3)
    assert delta_e2000(hazed.reshape(-1, 3), full).mean() < 0.3 * delta_e2000(clear.reshape(-1, 3), full).mean()
