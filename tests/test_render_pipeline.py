"""The render pipeline around the renderers: comp EXR, display PNG, coverage mattes, ground, sky, sun, haze, hooks."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from test_render import TOP_DOWN_CAMERA, read_exr, trees

from forest.config import parse_config
from forest.images import read_exr_channels, read_image
from forest.imaging import extract_matte, to_display
from forest.imaging.cryptomatte import NONE, TreeTable, rank_coverage
from forest.render import render_scene
from forest.render.coverage import TERRAIN, SampleCoverage, sample_ids
from forest.scene import load_scene

from render_fixtures import BoxLibrary

VARIANTS = ("scalar_rgb", "llvm_ad_rgb")


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    return BoxLibrary(tmp_path_factory.mktemp("pipelib"))


SCENE = """
seed = 3
[terrain]
flat = {{ size = 100.0 }}
[camera]
{camera}
[lights]
{lights}
[render]
{render}
[[species]]
model = "{model}"
percent = 100
"""


def scene_config(tmp_path, *, camera=TOP_DOWN_CAMERA, lights="", render="", model="box", name="scene.toml"):
    """A flat 100 m terrain of albedo 0.1 (unless ``render`` says otherwise; no detail texture), 40×40 px at
    4 spp by default."""
    keys = {"width": "40", "height": "40", "spp": "4", "terrain_colour": "[0.1, 0.1, 0.1]"}
    lines = [line for line in render.splitlines() if line.strip()]
    for line in lines:
        keys.pop(line.split("=")[0].strip(), None)
    render = "\n".join([f"{k} = {v}" for k, v in keys.items()] + lines)
    text = SCENE.format(camera=camera, lights=lights, render=render, model=model) + "\n[ground]\ndetail_tile = 0.0\n"
    (tmp_path / name).write_text(text)
    return parse_config(text, path=tmp_path / name, base_dir=tmp_path)


WHITE_SKY = "sky = { radiance = 1.0, colour = [1.0, 1.0, 1.0] }"


# ---------------------------------------------------------------------------
# The comp EXR and the PNG
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("variant", VARIANTS)
def test_the_exr_is_comp_ready_and_the_png_is_its_view(tmp_path, library, variant):
    """RGBA with coverage, Cryptomattes per tree and per species whose mattes cover each tree's pixels,
    camera matrices that project a tree onto its pixels, the colour space, and a PNG through the view."""
    cfg = scene_config(tmp_path, lights=WHITE_SKY, render='view = "filmic"\nexposure = 1.5\nspp = 16')
    inst = trees([[-20.0, 0.0, -10.0], [15.0, 0.0, 10.0]], scale=6.0)
    render_scene(load_scene(cfg, inst, library=library), output=tmp_path / "c.exr", variant=variant)
    ch, attrs = read_exr_channels(tmp_path / "c.exr")
    for name in ("R", "G", "B", "A", "depth.Z", "id.Z", "species.Z", "CryptoObject00.R", "CryptoAsset00.R"):
        assert name in ch, name
    assert attrs["forest:view"] == "filmic" and attrs["forest:exposure"] == 1.5
    assert json.loads(attrs["forest:species_names"]) == ["box"]
    assert "worldToCamera" in attrs and "worldToNDC" in attrs and "chromaticities" in attrs
    ids = ch["id.Z"]
    # Coverage: 1 where the pixel sees the ground or a tree (the ground runs on to the horizon).
    assert ch["A"].min() > 0.99
    for tree_id in (100, 101):
        matte = extract_matte(ch, "CryptoObject", [f"box/{tree_id}"])
        inside = ids == tree_id
        assert inside.sum() > 10
        assert matte[inside].min() > 0 and matte[inside].mean() > 0.85  # edge pixels are partly covered
        assert matte[~inside].sum() < 0.3 * inside.sum()
    species = extract_matte(ch, "CryptoAsset", ["box"])
    np.testing.assert_allclose(species, extract_matte(ch, "CryptoObject", ["box/100", "box/101"]), atol=1e-6)
    terrain = extract_matte(ch, "CryptoObject", ["terrain"])
    np.testing.assert_allclose(terrain + species, 1.0, atol=1e-6)  # every sample met a tree or the ground
    # worldToNDC (row vectors) takes tree 101's top (x = 15, y = 36, z = 10) into the pixel that shows it.
    m = np.asarray(attrs["worldToNDC"], np.float64).reshape(4, 4)
    p = np.array([15.0, 36.0, 10.0, 1.0]) @ m
    u, v = p[0] / p[3], p[1] / p[3]
    assert ids[int(v * 40), int(u * 40)] == 101
    # The PNG is the beauty through the filmic view at +1.5 EV.
    rgb = np.stack([ch["R"], ch["G"], ch["B"]], axis=-1)
    png = read_image(tmp_path / "c.png")
    np.testing.assert_allclose(png[..., :3], to_display(rgb, "filmic", 1.5), atol=1.0 / 255 + 1e-6)


def test_preview_denoises_with_albedo_and_normal_guides(tmp_path, library):
    from forest.render.render import frame_size, make_renderer

    # every box at its highest level (white): at 40 px the automatic LOD would draw the far level (blue)
    cfg = scene_config(tmp_path, lights=WHITE_SKY).with_overrides({"lod.auto": False})
    scene = load_scene(cfg, trees([[x, 0.0, 0.0] for x in (-20.0, 0.0, 20.0)], scale=6.0), library=library)
    r = make_renderer(scene, "llvm_ad_rgb", frame_size(cfg, preview=True), preview=True)
    out = r.frame(1.0)
    assert out.denoised and np.isfinite(out.rgb).all()
    # The guides: white boxes (albedo 0.8) and ground (0.1) where the id layer says; unit normals facing up.
    tree = out.id >= 0
    assert out.albedo[tree].mean() > 0.6 and out.albedo[~tree].mean() < 0.15
    np.testing.assert_allclose(out.normal[~tree][:, 1].mean(), 1.0, atol=0.02)


# ---------------------------------------------------------------------------
# Coverage
# ---------------------------------------------------------------------------


def test_sample_coverage_is_the_ranking_filter():
    """Pass by pass, the slot accumulator gives the Cryptomatte ranking of all samples at once (≤ 12 ids)."""
    rng = np.random.default_rng(4)
    h, w, passes, per = 6, 7, 5, 3
    samples = rng.choice(
        [NONE, TERRAIN, 3, 7, 11, 40, 41], size=(h * w, passes * per), p=[0.2, 0.2, 0.3, 0.1, 0.1, 0.05, 0.05]
    )
    acc = SampleCoverage(h, w)
    for k in range(passes):
        acc.add(samples[:, k * per : (k + 1) * per])
    ours = acc.ranking(6)
    ref = rank_coverage(samples.reshape(h, w, -1), ranks=6)
    np.testing.assert_array_equal(ours.ids, ref.ids)
    np.testing.assert_allclose(ours.coverage, ref.coverage, atol=1e-6)


def slot_reference(samples: np.ndarray, slots: int) -> tuple[list[dict[int, int]], np.ndarray]:
    """The slot rule sample by sample: a sample adds 1 to its id's slot, else takes a free slot, else is dropped."""
    kept: list[dict[int, int]] = [dict() for _ in range(len(samples))]
    for p, row in enumerate(samples):
        for x in row.tolist():
            if x != NONE and (x in kept[p] or len(kept[p]) < slots):
                kept[p][x] = kept[p].get(x, 0) + 1
    return kept, np.full(len(samples), samples.shape[1], float)


def test_sample_coverage_keeps_the_first_ids_met_when_a_pixel_sees_more_than_its_slots():
    """Pixels that meet up to 20 ids over 6 passes (4 slots): the slots hold the first 4 ids met, in sample
    order across passes, with their counts; the ranking sorts them (most samples, then smaller id), and the
    species ranking merges the kept trees' species."""
    rng = np.random.default_rng(11)
    h, w, passes, per, slots = 5, 8, 6, 4, 4
    samples = rng.choice([NONE, *range(20)], size=(h * w, passes * per))
    samples[:6] = 5  # pixels that meet one tree only
    samples[6:9] = NONE  # and pixels that meet nothing
    acc = SampleCoverage(h, w, slots=slots)
    for k in range(passes):
        acc.add(samples[:, k * per : (k + 1) * per])
    kept, total = slot_reference(samples, slots)
    ranking = acc.ranking(3)
    for p in range(h * w):
        order = sorted(kept[p].items(), key=lambda kv: (-kv[1], kv[0]))[:3]
        ids = [k for k, _ in order] + [NONE] * (3 - len(order))
        cov = [c / total[p] for _, c in order] + [0.0] * (3 - len(order))
        np.testing.assert_array_equal(ranking.ids.reshape(-1, 3)[p], ids)
        np.testing.assert_allclose(ranking.coverage.reshape(-1, 3)[p], cov, rtol=1e-6)
    species = np.arange(20) % 3
    table = TreeTable(np.arange(20), species, ["a", "b", "c"])
    by_species = acc.species_ranking(table, ranks=3)
    for p in range(h * w):
        merged: dict[int, int] = {}
        for k, c in kept[p].items():
            merged[int(species[k])] = merged.get(int(species[k]), 0) + c
        order = sorted(merged.items(), key=lambda kv: (-kv[1], kv[0]))[:3]
        ids = [k for k, _ in order] + [NONE] * (3 - len(order))
        cov = [c / total[p] for _, c in order] + [0.0] * (3 - len(order))
        np.testing.assert_array_equal(by_species.ids.reshape(-1, 3)[p], ids)
        np.testing.assert_allclose(by_species.coverage.reshape(-1, 3)[p], cov, rtol=1e-6)


def test_sample_ids_map_rows_to_tree_ids():
    rows = np.array([[0, 2, 3, 0xFFFFFFFF]], np.uint32)
    np.testing.assert_array_equal(sample_ids(rows, np.array([10, 20, 30]), n_trees=3, no_hit=0xFFFFFFFF),
                                  [[10, 30, TERRAIN, NONE]])  # fmt: skip


# ---------------------------------------------------------------------------
# Ground, sky and sun
# ---------------------------------------------------------------------------

HORIZON_CAMERA = "position = [0.0, 20.0, -40.0]\ntarget = [0.0, 20.0, 0.0]\nfov = 60.0\n"


@pytest.mark.parametrize("variant", VARIANTS)
def test_the_ground_runs_on_to_the_horizon(tmp_path, library, variant):
    """A 100 m terrain seen level from 20 m up: below the horizon every pixel is ground (no band of sky),
    above it sky; without ``horizon_ground`` the sky shows below the horizon past the terrain's edge."""
    out = {}
    for horizon in ("true", "false"):
        cfg = scene_config(tmp_path, camera=HORIZON_CAMERA, lights=WHITE_SKY, render=f"horizon_ground = {horizon}")
        render_scene(load_scene(cfg, trees(np.zeros((0, 3))), library=library), output=tmp_path / f"g{horizon}.exr",
                     variant=variant)  # fmt: skip
        out[horizon] = read_exr_channels(tmp_path / f"g{horizon}.exr")[0]["A"]
    below, above = out["true"][22:], out["true"][:18]  # the horizon is the image's middle row (level camera)
    assert below.min() > 0.99 and above.max() < 0.01
    assert out["false"][22:].min() < 0.01  # the bare terrain ends: sky below the horizon


@pytest.mark.parametrize("variant", VARIANTS)
def test_sunsky_lights_the_scene_from_above_in_both_renderers(tmp_path, library, variant):
    """Mitsuba's Z-up sunsky, rotated to Y-up: a grey ground is lit by a sun of the configured irradiance
    (E·sin e/π·ρ from the sun, plus the sky); a blue zenith."""
    lights = "sun = { elevation = 50.0, irradiance = 4.0 }\nsky = { sunsky = {} }"
    cfg = scene_config(tmp_path, lights=lights, render="max_depth = 2\nspp = 16")
    render_scene(load_scene(cfg, trees(np.zeros((0, 3))), library=library), output=tmp_path / "s.exr", variant=variant)
    ground = read_exr(tmp_path / "s.exr")["rgb"].reshape(-1, 3).mean(axis=0)
    sun_only = 0.1 * 4.0 * np.sin(np.radians(50.0)) / np.pi  # luminance of the sun's share on albedo 0.1
    lum = 0.2126 * ground[0] + 0.7152 * ground[1] + 0.0722 * ground[2]
    assert sun_only < lum < 1.6 * sun_only  # the sun, plus a sky a fraction of it


SUN_ONLY = "sun = { elevation = 90.0, irradiance = 3.0, colour = [1.0, 1.0, 1.0] }"


@pytest.mark.parametrize("variant", VARIANTS)
def test_the_sun_is_a_disc_that_casts_soft_shadows(tmp_path, library, variant):
    """A box held 10–16 m above the ground under a sun overhead: seen from below at a slant, the ground
    past the box's edge (x = 1 m) is lit (ρE/π, as from a point sun), under it dark, and between them
    a penumbra 2·16 m·tan(0.265°) ≈ 0.15 m wide — soft, not a step."""
    cam = "position = [1.0, 5.0, -30.0]\ntarget = [1.0, 0.0, 0.0]\nfov = 1.13\n"
    render = "max_depth = 2\nspp = 64\nwidth = 64\nheight = 8\nterrain_colour = [0.5, 0.5, 0.5]"
    cfg = scene_config(tmp_path, camera=cam, lights=SUN_ONLY, render=render)
    render_scene(
        load_scene(cfg, trees([[0.0, 10.0, 0.0]]), library=library), output=tmp_path / "p.exr", variant=variant
    )
    row = read_exr(tmp_path / "p.exr")["rgb"][4, :, 0]  # x from 1.3 m (image left) to 0.7 m (image right)
    lit = 0.5 * 3.0 / np.pi
    assert row[:4].mean() == pytest.approx(lit, rel=0.02)  # x ≈ 1.28 m: in full sun
    assert row[-4:].mean() == pytest.approx(0.0, abs=0.01 * lit)  # x ≈ 0.72 m: in the umbra
    penumbra = (row > 0.05 * lit) & (row < 0.95 * lit)
    # 0.15 m over 0.6 m / 64 px ≈ 16 px, of which the 5–95 % part about 12 (a point sun: 1 px)
    assert 7 <= penumbra.sum() <= 20


# ---------------------------------------------------------------------------
# Hooks for the ground's look and for several individuals per species
# ---------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class TerrainAlbedo:
    """The ground-albedo contract of ``Scene.terrain_albedo`` (as the Scene documents it)."""

    rgb: np.ndarray
    extent: tuple
    detail: np.ndarray | None
    detail_tile_m: float
    water: np.ndarray | None = None


@pytest.mark.parametrize("variant", VARIANTS)
def test_the_ground_takes_the_scenes_albedo_grid_and_detail(tmp_path, library, variant):
    """``Scene.terrain_albedo``: a 2×2 albedo grid (map convention) instead of terrain_colour × colour map, and
    in forest_path its detail texture (here stripes 0.5 / 1.5 along X, repeating every 20 m)."""
    cfg = scene_config(tmp_path, lights=WHITE_SKY, render="max_depth = 2\nspp = 8\nwidth = 80\nheight = 80")
    scene = load_scene(cfg, trees(np.zeros((0, 3))), library=library)
    grid = np.array([[[0.4, 0.1, 0.1], [0.1, 0.4, 0.1]], [[0.1, 0.1, 0.4], [0.3, 0.3, 0.3]]], np.float32)
    detail = np.ones((8, 8, 3), np.float32)
    detail[:, :4] = 0.5
    detail[:, 4:] = 1.5
    object.__setattr__(scene, "terrain_albedo", TerrainAlbedo(grid, scene.terrain.extent, detail, 20.0))
    render_scene(scene, output=tmp_path / "t.exr", variant=variant)
    rgb = read_exr(tmp_path / "t.exr")["rgb"]
    from test_render_scene import ground_points

    gx, gz = ground_points(cfg, 80, 80)
    for i, zr in enumerate(((-28, -22), (22, 28))):  # around the texel centres (bilinear between them)
        for j, xr in enumerate(((-28, -22), (22, 28))):
            m = (gx > xr[0]) & (gx < xr[1]) & (gz > zr[0]) & (gz < zr[1])
            colour = rgb[m].mean(axis=0)
            np.testing.assert_allclose(colour / colour.sum(), grid[i, j] / grid[i, j].sum(), atol=0.03)
    # Within one quadrant: the detail's stripes (forest_path) or its mean (scalar_rgb averages it).
    q = (gx > 10) & (gx < 40) & (gz > 10) & (gz < 40)
    phase = np.mod(gx, 20.0) / 20.0  # u along X; the image's columns run left to right
    dark, bright = q & (np.abs(phase - 0.25) < 0.15), q & (np.abs(phase - 0.75) < 0.15)
    ratio = rgb[bright].mean() / rgb[dark].mean()
    assert ratio == pytest.approx(3.0 if variant == "llvm_ad_rgb" else 1.0, rel=0.1)


@pytest.mark.parametrize("variant", VARIANTS)
def test_each_tree_is_drawn_as_its_own_individual(tmp_path, library, variant):
    """``Scene.individuals`` and ``InstanceSet.individual``: species 0 has a white and a red individual;
    each tree renders as the one its row names."""
    box = library.resolve("box")
    red_lods = [
        dataclasses.replace(lod, parts=[dataclasses.replace(p, colour=(0.8, 0.05, 0.05)) for p in lod.parts])
        for lod in box.lods
    ]
    red = dataclasses.replace(box, name="box@1", lods=red_lods)
    cfg = scene_config(tmp_path, lights=WHITE_SKY, render="max_depth = 2")
    inst = trees([[x, 0.0, z] for x in (-25.0, 0.0, 25.0) for z in (-20.0, 20.0)], scale=5.0)
    inst.individual = np.array([0, 1, 1, 0, 0, 1], np.uint8)
    scene = load_scene(cfg, inst, library=library)  # folds every row to the one individual the library has
    object.__setattr__(scene, "individuals", ((box, red),))
    scene.instances.individual = inst.individual
    render_scene(scene, output=tmp_path / "i.exr", variant=variant)
    out = read_exr(tmp_path / "i.exr")
    for row, tree_id in enumerate(inst.id):
        px = out["rgb"][out["id"] == tree_id]
        assert len(px) > 4
        r, g = px[:, 0].mean(), px[:, 1].mean()
        assert (r > 4 * g) if inst.individual[row] == 1 else (abs(r - g) < 0.05 * r)


def test_the_ground_past_the_terrain_fades_to_its_mean_colour():
    """The skirt's albedo: the grid inside untouched, each side padded with texels of the grid's size that blend
    from the border texel to the grid's mean, so clamped lookups far out give one colour, not stripes."""
    from forest.skirt import fade_beyond_edge

    rng = np.random.default_rng(5)
    grid = rng.uniform(0.05, 0.6, (40, 60, 3)).astype(np.float32)
    out, ext = fade_beyond_edge(grid, (-30.0, -20.0, 30.0, 20.0))
    p = (out.shape[0] - 40) // 2
    assert p >= 2 and out.shape == (40 + 2 * p, 60 + 2 * p, 3)
    np.testing.assert_array_equal(out[p:-p, p:-p], grid)
    assert ext == pytest.approx((-30.0 - p, -20.0 - p, 30.0 + p, 20.0 + p))  # 1 m texels kept
    mean = grid.reshape(-1, 3).mean(axis=0)
    ring = np.concatenate([out[0], out[-1], out[:, 0], out[:, -1]])
    np.testing.assert_allclose(ring, np.broadcast_to(mean, ring.shape), atol=1e-6)
    # half way out, a texel is between its border texel and the mean
    half = out[p // 2, p + 10]
    lo, hi = np.minimum(grid[0, 10], mean), np.maximum(grid[0, 10], mean)
    assert np.all(half >= lo - 1e-6) and np.all(half <= hi + 1e-6)
