"""Look-dev on the production renderer: references and masks, the fit's renderer against production (trees
outside the frame shadow it), the aligned round trip on a production-rendered reference, statistics on a real
photograph, the guard rails (best iterate, never worse than the start), and bad input through the CLI.

Everything renders tiny images with few samples and iterations in ``llvm_ad_rgb``.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
from conftest import run_forest, write_png, write_scene

pytestmark = pytest.mark.filterwarnings("ignore::UserWarning")

PHOTOS = Path(__file__).parent / "fixtures" / "photos"
VARIANT = "llvm_ad_rgb"
#: The aligned round trip's size: the map is seen only through 60 small trees' pixels, and at 48×36 the reference
#: gave one or two of the 16 cells more than twice the prior's information, depending on the render's noise.
W, H, GRID = 192, 144, 4

#: A small forest on a 60 m hill seen from 20 m up, with the sky in the top rows.
SCENE = """
seed = 5
[terrain.procedural]
size = 60.0
height = 4.0
resolution = 16
[scatter]
count = 60
[[species]]
model = "broadleaf"
percent = 100
scale = [0.5, 0.7]
[camera]
position = [0.0, 20.0, -60.0]
target = [0.0, 0.0, 0.0]
fov = 68
[lights.sun]
elevation = 35
azimuth = 130
irradiance = {sun}
colour = [1.0, 0.95, 0.85]
[lights.sky]
radiance = {sky}
colour = {sky_colour}
[render]
width = 192
height = 144
spp = 16
max_depth = 3
[lookdev]
report_width = 96
"""
START = {"sun": 3.0, "sky": 0.4, "sky_colour": [0.6, 0.75, 1.0]}
TRUTH = {"sun": 2.4, "sky": 0.34, "sky_colour": [0.5, 0.72, 1.1]}


def hidden_map() -> np.ndarray:
    """A smooth painted tint (GRID × GRID): redder to the east, bluer to the north, ±25 %."""
    yy, xx = np.mgrid[0:GRID, 0:GRID] / (GRID - 1) - 0.5
    return np.exp(np.stack([0.5 * xx + 0.2 * yy, -0.3 * xx + 0.3 * yy, 0.4 * yy - 0.2 * xx], axis=-1))


@pytest.fixture(scope="module")
def aligned(tmp_path_factory):
    """(folder, start Scene, truth config, reference path): the reference is the production render of the truth
    (sun ×0.8, a bluer sky, a painted colour map) at 256 spp."""
    from forest.config import load_config
    from forest.images import write_image
    from forest.lookdev.report import Production
    from forest.scene import load_scene

    folder = tmp_path_factory.mktemp("lookdev")
    scene = load_scene(load_config(write_scene(folder, SCENE.format(**START))))
    write_image(folder / "map.exr", hidden_map().astype(np.float32), half=False)
    truth_text = SCENE.format(**TRUTH) + '[maps]\ncolour = "map.exr"\ncolour_normalise = "none"\n'
    truth = load_config(write_scene(folder, truth_text, "truth.toml"))
    ref = Production(load_scene(truth, scene.instances), VARIANT).image(width=W, height=H, spp=256, seed=9)
    write_image(folder / "reference.exr", ref.astype(np.float32), half=False)
    return folder, scene, truth, folder / "reference.exr"


# -- references and masks --------------------------------------------------------------------


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
    tiny = write_png(tmp_path / "tiny.png", np.full((4, 6, 3), 0.5))
    with pytest.raises(ForestError, match="needs at least"):
        load_reference(tiny, 96, 72)


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


def test_painted_mask_colours_become_regions(tmp_path):
    from forest.errors import ForestError
    from forest.lookdev.regions import AUTO, CANOPY, GROUND, IGNORE, SKY, read_mask

    img = np.zeros((4, 5, 3))
    img[0] = (0, 0, 1)  # sky
    img[1] = (0, 1, 0)  # canopy
    img[2] = (1, 0, 0)  # ground
    img[3, :2] = (1, 1, 1)  # automatic; the rest of the row black: ignored
    labels = read_mask(write_png(tmp_path / "mask.png", img))
    assert labels[0].tolist() == [SKY] * 5 and labels[1].tolist() == [CANOPY] * 5
    assert labels[2].tolist() == [GROUND] * 5 and labels[3].tolist() == [AUTO, AUTO, IGNORE, IGNORE, IGNORE]
    img[1] = (0.5, 0.3, 0.9)  # a colour of no region over a fifth of the mask
    with pytest.raises(ForestError, match=r"mask2\.png.*none of its colours"):
        read_mask(write_png(tmp_path / "mask2.png", img))


def test_the_shipped_painted_mask_fits_its_photo():
    """The evening-glow plate's mask (tests/fixtures/photos/README.md) reads as regions and fits the photo's frame:
    sky above, the hills as canopy, the lake and boats ignored, the shingle as ground below."""
    from forest.lookdev.reference import fit_labels, load_reference
    from forest.lookdev.regions import CANOPY, GROUND, IGNORE, SKY, read_mask

    ref = load_reference(PHOTOS / "evening_glow_hills.jpg", 64, 36)
    labels = fit_labels(read_mask(PHOTOS / "evening_glow_hills_mask.png"), ref.source_size, 64, 36, "crop")
    assert labels.shape == (36, 64)
    column = labels[:, 32].tolist()  # top to bottom through the middle of the frame
    firsts = [column.index(k) for k in (SKY, CANOPY, IGNORE, GROUND)]
    assert firsts == sorted(firsts) and firsts[0] == 0 and column[-1] == GROUND
    assert {SKY, CANOPY, GROUND, IGNORE} == set(np.unique(labels).tolist())


def test_a_textured_sky_above_the_land_is_found_near_the_renders_skyline():
    """A sunset sky of high-contrast clouds fails the smooth-sky test, but it is brighter than the land under it: the
    skyline step of the automatic segmentation finds it where the render's sky ends (within 15 % of the height),
    follows the photo's own skyline (a slope the render does not have) and leaves the land and a bright lake alone."""
    from forest.lookdev.regions import CANOPY, GROUND, SKY, segment_photo

    h, w = 40, 64
    rng = np.random.default_rng(3)
    rows = np.arange(h)[:, None]
    skyline = (14 + np.arange(w) * 4 // w)[None, :]  # the photo's land rises from row 14 to 17 across the frame
    clouds = np.exp(rng.normal(0.0, 0.6, (h, w)))  # ln-contrast 0.6: far from smooth
    photo = np.empty((h, w, 3))
    photo[...] = np.array([0.9, 0.5, 0.3]) * clouds[..., None]
    land = rows >= skyline
    photo[land] = [0.04, 0.05, 0.03]
    lake = np.broadcast_to(rows >= 24, (h, w))
    photo[lake] = [0.5, 0.45, 0.4]  # bright water below the land
    render = np.full((h, w), GROUND)
    render[:16] = SKY
    render[16:22] = CANOPY
    labels = segment_photo(photo, render)
    sky = labels == SKY
    assert sky[~land].mean() > 0.95
    assert not sky[land].any()
    # Without the skyline step (a render with no sky) the textured sky is not taken as sky.
    assert (segment_photo(photo, np.full((h, w), GROUND)) == SKY)[~land].mean() < 0.5


# -- the fit's renderer is the production renderer -------------------------------------------


def test_trees_outside_the_frame_shadow_it_in_fit_and_production(tmp_path):
    """A ring wall of boxes 12 m from the view's centre, all outside a narrow top-down frame, shadows the frame
    under a sun at 30°: the fit's renderer (all trees, no frustum culling) renders it as `forest render` does."""
    from test_render import trees

    from forest.config import parse_config
    from forest.images import read_image
    from forest.lookdev.renders import FitRenderer
    from forest.render import render_scene
    from forest.scene import load_scene

    from render_fixtures import BoxLibrary

    library = BoxLibrary(tmp_path / "lib")
    text = """
seed = 3
[terrain]
flat = { size = 100.0 }
[camera]
position = [0.0, 60.0, 0.0]
target = [0.0, 0.0, 0.0]
up = [0.0, 0.0, 1.0]
fov = 6.0
[lights]
sun = { elevation = 30.0, azimuth = 40.0, irradiance = 3.0, colour = [1.0, 1.0, 1.0] }
sky = { radiance = 0.3, colour = [1.0, 1.0, 1.0] }
[render]
width = 24
height = 24
spp = 64
terrain_colour = [0.5, 0.5, 0.5]
[[species]]
model = "box"
percent = 100
"""
    (tmp_path / "scene.toml").write_text(text)
    cfg = parse_config(text, path=tmp_path / "scene.toml", base_dir=tmp_path)
    angles = np.radians(np.arange(0.0, 360.0, 15.0))
    ring = np.stack([12.0 * np.cos(angles), np.zeros_like(angles), 12.0 * np.sin(angles)], axis=1)
    scene = load_scene(cfg, trees(ring, scale=4.0), library=library)
    fit = FitRenderer(scene, width=24, height=24, spp=64, variant=VARIANT, base_map=None)
    assert fit.layers["hit"].all() and (fit.layers["id"] < 0).all()  # only ground in frame
    fitted = fit.render(seed=1)
    render_scene(scene, output=tmp_path / "prod.exr", variant=VARIANT)
    production = read_image(tmp_path / "prod.exr")[..., :3]
    lit = 0.5 * (3.0 * np.sin(np.radians(30.0)) + np.pi * 0.3) / np.pi  # the open ground in sun and sky
    assert production.mean() < 0.3 * lit  # the frame is in the wall's shadow
    assert fitted.mean() == pytest.approx(production.mean(), rel=0.05)


# -- aligned round trip ----------------------------------------------------------------------


def test_aligned_round_trip_recovers_the_lights_and_the_map(aligned):
    """On a production render of the truth, the fit recovers the lights (exposure folded in) within 5 % and
    the painted map within a mean CIEDE2000 of 2 where the reference sees it."""
    from forest.config import load_config
    from forest.images import read_map_rgb
    from forest.lookdev import match
    from forest.lookdev.colour import delta_e2000

    folder, scene, truth, ref = aligned
    # 6 iterations: the fit's best iterate is its 6th (it stopped after 8 of 10), so the result is the same.
    r = match(
        scene, ref, folder / "out", iterations=6, spp=8, resolution=W, grid=GRID, params="camera,sun,sky,colour_map"
    )
    assert r.figures["objective_fitted"] < 0.05 * r.figures["objective_start"]
    fitted = load_config(r.scene_path)

    def sun(c):
        return np.asarray(c.lights.sun.colour) * c.lights.sun.irradiance

    def sky(c):
        return np.asarray(c.lights.sky.colour) * c.lights.sky.radiance

    assert np.allclose(sun(fitted) / sun(truth), 1.0, atol=0.05)
    assert np.allclose(sky(fitted) / sky(truth), 1.0, atol=0.05)
    # The map: as albedos of the species' leaves, on the cells the reference determines.  A cell's fitted value
    # moves a share I/(1 + I) of the way from the prior to what the data say, I its information over the prior's
    # (``cell_information``): a cell at I ≈ 1 is expected half way, so "determined" is I ≥ 2 (two thirds or more).
    seen = r.cell_information >= 2.0
    assert seen.sum() >= 2
    leaf = np.array([0.06, 0.12, 0.04])
    fitted_map = read_map_rgb(fitted.maps.colour)
    de = delta_e2000((fitted_map * leaf)[seen], (hidden_map() * leaf)[seen])
    de_start = delta_e2000(np.broadcast_to(leaf, (int(seen.sum()), 3)), (hidden_map() * leaf)[seen])
    assert de.mean() < 2.0 and de.mean() < de_start.mean()


# -- a sharp painted map, from above; the written scene from other views ------------------------

#: A forest seen from straight above: no sky in frame, the painted map seen through the crowns.  Every tree at its
#: highest level (``[lod] auto = false``): at 96 pixels the automatic rule would make them far cards, whose
#: vertical planes hide little of the ground seen from above.
TOP_DOWN = """
seed = 4
[terrain.procedural]
size = 80.0
height = 3.0
resolution = 16
[maps]
colour = "{map}"
{normalise}
[scatter]
count = 400
[[species]]
model = "broadleaf"
percent = 100
scale = [0.4, 0.6]
colour_jitter = {{ hue = 0.0, value = 0.0 }}
[camera]
position = [0.0, 110.0, 0.0]
target = [0.0, 0.0, 0.0]
up = [0.0, 0.0, 1.0]
fov = 44
[lights.sun]
elevation = 50
azimuth = 140
irradiance = {sun}
colour = {sun_colour}
[lights.sky]
radiance = {sky}
colour = {sky_colour}
[render]
width = 96
height = 96
spp = 16
max_depth = 3
[lod]
auto = false
[lookdev]
report_width = 96
"""
TD_START = {"sun": 3.0, "sun_colour": [1.0, 0.95, 0.85], "sky": 0.4, "sky_colour": [0.6, 0.75, 1.0]}
TD_TRUTH = {"sun": 2.2, "sun_colour": [1.0, 0.88, 0.7], "sky": 0.5, "sky_colour": [0.45, 0.65, 1.15]}
#: The written scene and the truth rendered alike, from the reference camera, low across the forest (the sky in
#: frame, never seen by the fit) and under another sun.
TD_VIEWS = {
    "reference camera": {},
    "new low camera": {
        "camera.position": [-30.0, 9.0, -45.0],
        "camera.target": [5.0, 2.0, 5.0],
        "camera.up": [0.0, 1.0, 0.0],
        "camera.fov": 60.0,
    },
    "new sun": {"lights.sun.elevation": 22.0, "lights.sun.azimuth": 230.0},
}


def sharp_map() -> np.ndarray:
    """8×8 patches of five foliage colours (as multipliers of the broadleaf's leaf colour), each patch two cells of
    a 16-cell grid wide: red next to green, yellow next to dark — edges a smooth field cannot make."""
    leaf = np.array([0.06, 0.12, 0.04])
    colours = np.array(
        [[0.06, 0.12, 0.04], [0.17, 0.06, 0.025], [0.18, 0.15, 0.03], [0.03, 0.06, 0.02], [0.09, 0.1, 0.03]]
    )
    pattern = np.random.default_rng(8).integers(0, len(colours), (8, 8))
    return (colours[pattern] / leaf).astype(np.float32)


@pytest.fixture(scope="module")
def top_down(tmp_path_factory):
    """(folder, start Scene, truth Scene, reference): the truth has the sharp map and other lights; the start a
    uniform grey map; the reference is the truth's production render at 96×96, 128 spp."""
    from forest.config import load_config
    from forest.images import write_image
    from forest.lookdev.report import Production
    from forest.scene import load_scene

    folder = tmp_path_factory.mktemp("top_down")
    write_png(folder / "grey.png", np.full((4, 4, 3), 0.3))
    write_image(folder / "truth_map.exr", sharp_map(), half=False)
    start = load_scene(load_config(write_scene(folder, TOP_DOWN.format(map="grey.png", normalise="", **TD_START))))
    truth_text = TOP_DOWN.format(map="truth_map.exr", normalise='colour_normalise = "none"', **TD_TRUTH)
    truth = load_scene(load_config(write_scene(folder, truth_text, "truth.toml")), start.instances)
    ref = Production(truth, VARIANT).image(width=96, height=96, spp=128, seed=9)
    write_image(folder / "reference.exr", ref.astype(np.float32), half=False)
    return folder, start, truth, folder / "reference.exr"


def test_a_sharp_painted_map_is_recovered_and_the_written_scene_holds_from_new_views(top_down):
    """From above, a sharp 8×8 painted map under other lights: the fit (defaults: auto grid, edge-preserving
    prior, the ground as anchor) recovers the map's pattern (correlation ≥ 0.9 on the cells the reference sees),
    the lights within 5 %, and the written scene rendered like the truth matches it at the reference camera, from a
    low camera whose frame is half sky and under another sun.  (bench/bench_lookdev.py fits the same kind of map
    with the smooth prior of earlier versions as its baseline: correlation 0.77 against 0.98.)"""
    from forest.config import load_config
    from forest.images import read_map_rgb
    from forest.lookdev import match
    from forest.lookdev.regions import render_labels
    from forest.lookdev.renders import FitRenderer
    from forest.lookdev.validation import compare, covered_cells, pattern_correlation

    folder, start, truth, ref = top_down
    # 3 iterations: the 4th was never the best iterate (the same map and lights are written).
    r = match(start, ref, folder / "edges", iterations=3, spp=8, resolution=96)
    assert r.anchor == "ground" and r.grid is not None and r.grid >= 8
    fitted_cfg = load_config(r.scene_path)
    lay = FitRenderer(truth, width=96, height=96, spp=1, variant=VARIANT, base_map=None).layers
    seen = covered_cells(lay, render_labels(lay), (8, 8))
    assert seen.mean() > 0.9
    corr = pattern_correlation(read_map_rgb(fitted_cfg.maps.colour), sharp_map(), seen)
    assert corr >= 0.9, corr

    def light(c, name):
        lt = getattr(c.lights, name)
        return np.multiply(lt.colour, lt.irradiance if name == "sun" else lt.radiance)

    for name in ("sun", "sky"):
        assert np.allclose(light(fitted_cfg, name) / light(truth.config, name), 1.0, atol=0.05), name
    # 16 spp: the two scenes share their random numbers, so their difference barely moves with the noise (ΔE 1.05,
    # 0.53, 1.16 against 1.00, 0.52, 1.12 at 64 spp).
    figures = {
        v.name: v
        for v in compare(start.with_config(fitted_cfg), truth, TD_VIEWS, width=64, height=64, spp=16, variant=VARIANT)
    }
    assert figures["reference camera"].delta_e <= 1.5, figures
    assert figures["new low camera"].delta_e <= 2.0, figures
    assert figures["new sun"].delta_e <= 2.0, figures


def test_a_degenerate_direction_is_reported_and_the_anchor_removes_it(top_down):
    """From above, with no sky in frame, a brighter light and darker leaves and ground render the same picture
    (only multiply scattered light tells them apart): with no anchor the fit reports that weak direction in the
    parameters' own terms; anchored on the ground the light level is determined and no such direction is left."""
    from forest.lookdev import match

    folder, start, _truth, ref = top_down
    free = match(
        start, ref, folder / "free", iterations=1, spp=4, resolution=48, params="sun,leaves,ground", anchor="none"
    )
    assert free.anchor == "none"
    js = __import__("json").loads(free.json_path.read_text())
    weak = [w["components"] for w in js["weak_directions"]]
    assert any(
        "light_level" in c and any(k.startswith(("leaves_", "ground_")) and c[k] * c["light_level"] < 0 for k in c)
        for c in weak
    ), weak
    assert free.weak and "light level" in " ".join(free.weak)
    anchored = match(start, ref, folder / "anchored", iterations=1, spp=4, resolution=48, params="sun,leaves,ground")
    assert anchored.anchor == "ground"
    js = __import__("json").loads(anchored.json_path.read_text())
    assert not any(abs(w["components"].get("light_level", 0.0)) > 0.5 for w in js["weak_directions"]), js


# -- guard rails ------------------------------------------------------------------------------


def test_the_best_iterate_is_kept_not_the_last(aligned, monkeypatch):
    """After a good first step every later step is absurd (lights +4 EV): the result is iterate 1, its held-out
    objective the lowest of the history."""
    import forest.lookdev.fit as fit_module
    from forest.lookdev import match

    folder, scene, _truth, ref = aligned
    real = fit_module.step
    calls = []

    def step(problem, lin, **kw):
        calls.append(1)
        look = real(problem, lin, **kw)
        if len(calls) > 1:
            look.values["light_level"] = min(look.values["light_level"] + 4.0, 10.0)
        return look

    monkeypatch.setattr(fit_module, "step", step)
    r = match(scene, ref, folder / "best", iterations=2, spp=4, resolution=W, params="camera,sun,sky")
    totals = [h["total"] for h in __import__("json").loads(r.json_path.read_text())["history"]]
    assert r.figures["best_iteration"] == 1
    assert len(totals) >= 3 and totals[1] == min(totals) and totals[-1] > totals[1]
    assert r.figures["objective_fitted"] == pytest.approx(totals[1], rel=1e-5)


def test_a_fit_never_writes_a_look_worse_than_the_start(aligned, monkeypatch):
    """Every step worse than the start: the start is written back (lights as the config had them), with a
    warning saying so."""
    import forest.lookdev.fit as fit_module
    from forest.config import load_config
    from forest.lookdev import match

    folder, scene, _truth, ref = aligned

    def step(problem, lin, **kw):
        look = lin.look.copy()
        look.values["light_level"] = 6.0
        return look

    monkeypatch.setattr(fit_module, "step", step)
    r = match(scene, ref, folder / "worse", iterations=2, spp=4, resolution=W, params="camera,sun,sky")
    assert r.figures["best_iteration"] == 0
    assert any("start's look is kept" in w for w in r.warnings)
    fitted, start = load_config(r.scene_path), scene.config
    for light in ("sun", "sky"):
        a, b = getattr(fitted.lights, light), getattr(start.lights, light)
        level = "irradiance" if light == "sun" else "radiance"
        assert np.allclose(
            np.multiply(a.colour, getattr(a, level)), np.multiply(b.colour, getattr(b, level)), rtol=1e-4
        )


# -- statistics on a real photograph ----------------------------------------------------------

HILLS = """
seed = 7
[terrain.procedural]
size = 400.0
height = 40.0
resolution = 24
[scatter]
count = 150
[[species]]
model = "conifer"
percent = 100
scale = [1.5, 2.5]
[camera]
position = [0.0, 45.0, -230.0]
target = [0.0, 20.0, 0.0]
fov = 60
[lights.sun]
elevation = 8
azimuth = 170
irradiance = 3.0
colour = [1.0, 0.9, 0.75]
[lights.sky]
radiance = 0.35
colour = [0.6, 0.75, 1.0]
[render]
width = 64
height = 36
spp = 8
max_depth = 3
[lookdev]
report_width = 96
"""


def test_statistics_on_a_real_photo_stays_in_range_and_lowers_the_loss(tmp_path):
    """Evening Glow (KDE wallpaper, LGPL-3.0): every fitted parameter ends inside its range and the held-out
    objective ends below the start's."""
    from forest.config import load_config
    from forest.lookdev import match
    from forest.scene import load_scene

    scene = load_scene(load_config(write_scene(tmp_path, HILLS)))
    r = match(
        scene,
        PHOTOS / "evening_glow_hills.jpg",
        tmp_path / "out",
        mode="statistics",
        iterations=3,
        spp=4,
        resolution=48,
    )
    assert r.figures["objective_fitted"] < r.figures["objective_start"]
    assert r.table
    for row in r.table:
        assert row["lo"] - 1e-9 <= row["fitted"] <= row["hi"] + 1e-9, row
    whole = "whole image"
    assert r.figures["fitted_regions"][whole] < r.figures["start_regions"][whole]
    assert (tmp_path / "out" / "report.png").stat().st_size > 0


def test_a_parameter_on_a_bound_says_which_observation_drove_it_there(tmp_path):
    """A "photo" of the scene whose canopy is ten times bluer than any leaf: the leaves' blue ends on its bound,
    and the warning names the canopy's blue/green as what pushed it there."""
    from forest.config import load_config
    from forest.images import write_image
    from forest.lookdev import match
    from forest.lookdev.regions import CANOPY, render_labels
    from forest.lookdev.renders import FitRenderer
    from forest.lookdev.report import Production
    from forest.scene import load_scene

    scene = load_scene(load_config(write_scene(tmp_path, HILLS)))
    img = Production(scene, VARIANT).image(width=64, height=36, spp=16, seed=3)
    lay = FitRenderer(scene, width=64, height=36, spp=1, variant=VARIANT, base_map=None).layers
    canopy = render_labels(lay) == CANOPY
    img[canopy, 2] *= 10.0
    write_image(tmp_path / "blue.exr", img.astype(np.float32), half=False)
    r = match(
        scene,
        tmp_path / "blue.exr",
        tmp_path / "out",
        mode="statistics",
        iterations=3,
        spp=4,
        resolution=64,
        params="leaves",
    )
    bound = [w for w in r.warnings if "leaves_b" in w and "bound" in w]
    assert bound, r.warnings
    assert "driven there by the canopy" in bound[0] and "blue/green" in bound[0], bound[0]


def test_the_automatic_segmentation_agrees_with_painted_masks():
    """Against masks painted by hand over real photos of three kinds — a top-down aerial of conifers, an autumn
    hillside under a sky, a spruce-forest interior — each with a scene that frames it (fixtures/photos/photo_scenes.py),
    every region's intersection over union reaches what the discriminant learnt from the render gives."""
    import sys
    import textwrap

    sys.path.insert(0, str(PHOTOS))
    from photo_scenes import PHOTO_SCENES

    from forest.config import parse_config
    from forest.lookdev.reference import load_reference, painted_labels
    from forest.lookdev.regions import label_iou, render_labels, segment_photo
    from forest.lookdev.renders import FitRenderer
    from forest.scene import load_scene

    floors = {
        "aerial_road_conifers.jpg": {"canopy": 0.85, "ground": 0.2},
        # the orange larches are told from the green meadow by what the render's canopy and ground differ in
        # (least-green-is-ground made 0.38 and 0.66 of them)
        "autumn_larch_hillside.jpg": {"sky": 0.9, "canopy": 0.7, "ground": 0.8},
        "path_spruce_forest.jpg": {"canopy": 0.85, "ground": 0.85},
    }
    for name, floor in floors.items():
        cfg = parse_config(textwrap.dedent(PHOTO_SCENES[name]), path=PHOTOS / "scene.toml", base_dir=PHOTOS)
        w, h = cfg.render.width, cfg.render.height
        ref = load_reference(PHOTOS / name, w, h, fit="crop")
        fr = FitRenderer(load_scene(cfg), width=w, height=h, spp=16, variant=VARIANT, base_map=None)
        auto = segment_photo(ref.rgb, render_labels(fr.layers), render_rgb=fr.render(seed=5))
        iou = label_iou(auto, painted_labels(PHOTOS / (name[:-4] + "_mask.png"), ref, w, h, "crop"))
        for region, least in floor.items():
            assert iou[region] >= least, (name, iou)


#: The hills of HILLS seen from farther and lower, under a sun at 4° (bench/bench_lookdev.py's evening-glow scene).
GLOW = {
    "terrain.procedural.height": 30.0,
    "scatter.count": 600,
    "camera.position": [0.0, 25.0, -700.0],
    "camera.target": [0.0, 22.0, 0.0],
    "lights.sun.elevation": 4,
    "lights.sun.azimuth": 180,
}


def test_a_low_sky_is_fitted_as_a_horizon_band(tmp_path):
    """The evening-glow plate with its painted mask, from a view whose sky reaches ~18° (the scene of
    bench/bench_lookdev.py): the sky's gradient is fitted as an orange band along the horizon under a cooler sky,
    and every region ends within the look-dev goal (CIEDE2000 of the mean colour ≤ 8, the whole image ≤ 5)."""
    from forest.config import load_config
    from forest.images import read_image
    from forest.lookdev import match
    from forest.scene import load_scene

    scene = load_scene(load_config(write_scene(tmp_path, HILLS)).with_overrides(GLOW))
    r = match(
        scene,
        PHOTOS / "evening_glow_hills.jpg",
        tmp_path / "out",
        mode="statistics",
        iterations=6,
        spp=8,
        resolution=64,
        mask=PHOTOS / "evening_glow_hills_mask.png",
    )
    assert any("fitted as a band" in w for w in r.warnings), r.warnings
    import json

    k = json.loads(r.json_path.read_text())["sky_band_exponent"]
    assert 3.0 < k < 12.0  # the band fades to 0.1 at the top of a sky about 18° high: k ≈ 6.5
    fitted = r.figures["fitted_regions"]
    for region in ("sky", "sky high", "sky low", "canopy", "ground"):
        assert fitted[region] <= 8.0, (region, fitted)
    assert fitted["whole image"] <= 5.0, fitted
    # The written sky (an environment map the production renderer reads): warm along the horizon, cooler above.
    sky = read_image(tmp_path / "out" / "sky.exr")[..., :3].mean(axis=1)
    h = len(sky)
    horizon, above = sky[h // 2 - 2], sky[h // 2 - int(h * 25 / 180)]  # rows just above the horizon and at 25°
    assert horizon[0] / horizon[2] > 1.3 * (above[0] / above[2]), (horizon, above)


# -- bad input through the CLI ------------------------------------------------------------------


def _one_line_exit_2(r, *needles: str) -> None:
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, lines
    for n in needles:
        assert n in lines[0], lines[0]


def test_cli_bad_input_names_the_option_and_exits_2(tmp_path):
    cfg = write_scene(tmp_path, SCENE.format(**START))
    out = tmp_path / "out"
    small = write_png(tmp_path / "small.png", np.full((4, 5, 3), 0.5))
    _one_line_exit_2(run_forest("match", cfg, "--reference", small, "-o", out), "reference", "small.png")
    text = tmp_path / "notes.png"
    text.write_text("this is not an image\n" * 20)
    _one_line_exit_2(run_forest("match", cfg, "--reference", text, "-o", out), "reference", "notes.png")
    ok = write_png(tmp_path / "ok.png", np.full((36, 48, 3), 0.5))
    wrong_size = write_png(tmp_path / "tall.png", np.zeros((48, 20, 3)))
    _one_line_exit_2(run_forest("match", cfg, "--reference", ok, "--mask", wrong_size, "-o", out), "mask", "tall.png")
    stray = np.zeros((36, 48, 3))
    stray[:, :24] = (0.5, 0.3, 0.9)
    odd = write_png(tmp_path / "odd.png", stray)
    _one_line_exit_2(run_forest("match", cfg, "--reference", ok, "--mask", odd, "-o", out), "mask", "odd.png")
    _one_line_exit_2(run_forest("match", cfg, "--reference", ok, "--anchor", "sky", "-o", out), "anchor")
    _one_line_exit_2(run_forest("match", cfg, "--reference", ok, "--grid", "fine", "-o", out), "grid")
    _one_line_exit_2(run_forest("match", cfg, "--reference", ok, "--grid", "65", "-o", out), "grid")
    _one_line_exit_2(run_forest("match", cfg, "--reference", ok, "--map-prior", "flat", "-o", out), "--map-prior")
    assert not out.exists()
