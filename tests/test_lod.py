"""Levels of detail (forest.lod): the automatic rule by projected size, manual distances, off — one rule for the
renderers (Scene.levels) and RIB's DetailRange."""

import math

import numpy as np
import pytest

from forest.camera import camera_at
from forest.config.schema import DEFAULT_LOD_PIXELS, LodConfig
from forest.errors import ConfigError
from forest.export.rib import export_rib
from forest.lod import LodPlan, lod_levels
from forest.render.render import RenderResult
from forest.scene import load_scene

import ribcheck
from export_support import FakeLibrary, fly_keys, make_config, make_instances

R = 150.0  # every tree of the threshold test stands this far from the camera


@pytest.fixture(scope="module")
def lib():
    return FakeLibrary()


def height(lib, name: str) -> float:
    b = np.asarray(lib.resolve(name).lods[0].bounds)
    return float(b[1, 1] - b[0, 1])


def along_view(cfg, r: np.ndarray) -> np.ndarray:
    """Points ``r`` metres from the camera along its view direction."""
    c = np.asarray(cfg.camera.position, float)
    d = np.asarray(cfg.camera.target, float) - c
    return c + np.asarray(r, float)[:, None] * (d / np.linalg.norm(d))


def scene_of(tmp_path, lib, extra: str, r, scale, species, width: int = 1280):
    cfg = make_config(tmp_path, extra).with_overrides({"render.width": width, "render.height": width * 9 // 16})
    inst = make_instances(len(r))
    inst.position[:] = along_view(cfg, np.asarray(r))
    inst.scale[:] = scale
    inst.species[:] = species
    return load_scene(cfg, inst, library=lib)


def test_defaults_and_modes():
    assert LodConfig().mode == "pixels" and LodConfig().thresholds == DEFAULT_LOD_PIXELS == (240.0, 80.0, 20.0)
    assert LodConfig(pixels=[100.0, 10.0]).thresholds == (100.0, 10.0)
    manual = LodConfig(distances=[40.0, 120.0])
    assert (manual.mode, manual.bands, manual.thresholds) == ("distances", (40.0, 120.0), ())
    off = LodConfig(auto=False)
    assert (off.mode, off.enabled, off.bands, off.thresholds) == ("off", False, (), ())


def test_auto_picks_the_level_of_the_projected_size(tmp_path, lib):
    """Trees of both species at 150 m, scaled so that p = σ·H·(H_px/2)/(r·tan(fov_v/2)) sits 0.1 % above and below
    each of [240, 80, 20] pixels: p ≥ t₀ high, t₁ ≤ p < t₀ medium, t₂ ≤ p < t₁ low, below far — clamped to the
    species' last level (pine has two)."""
    w, h_px = 1280, 720
    probe = make_config(tmp_path).with_overrides({"render.width": w, "render.height": h_px})
    fov_v = 2 * math.atan(math.tan(math.radians(probe.camera.fov) / 2) * h_px / w)
    f_v = (h_px / 2) / math.tan(fov_v / 2)
    scale, species, want_p = [], [], []
    for s, name in enumerate(("oak", "pine")):
        H = height(lib, name)
        for t in DEFAULT_LOD_PIXELS:
            for p in (t * 1.001, t / 1.001):  # just above, just below
                scale.append(p * R / (H * f_v))
                species.append(s)
                want_p.append(p)
        scale.append(1000.0 * R / (H * f_v))  # 1000 px: high
        species.append(s)
        want_p.append(1000.0)
    scene = scene_of(tmp_path, lib, "", np.full(len(scale), R), scale, species, width=w)
    got = scene.levels(1.0)
    # the formula, independently: p from the vertical fov and the image height
    inst = scene.instances
    for k in range(len(inst)):
        H = height(lib, inst.species_names[inst.species[k]])
        r = float(np.linalg.norm(inst.position[k] - np.asarray(probe.camera.position)))
        p = inst.scale[k] * H * f_v / r
        assert p == pytest.approx(want_p[k], rel=1e-4)
        level = sum(p < t for t in DEFAULT_LOD_PIXELS)
        last = len(lib.resolve(inst.species_names[inst.species[k]]).lods) - 1
        assert got[k] == min(level, last), (k, p, got[k])
    oak = got[np.asarray(species) == 0].tolist()
    assert oak == [0, 1, 1, 2, 2, 3, 0]  # above/below 240, 80, 20, then 1000 px
    assert got[np.asarray(species) == 1].tolist() == [0, 1, 1, 1, 1, 1, 0]
    assert scene.lod.describe() == "auto: pixels 240, 80, 20"


def test_auto_levels_are_the_bands_at_r_over_scale():
    """LodPlan's automatic levels equal its per-species bands (scale 1) looked up at r/σ; the bands scale with
    the focal length, so a narrower fov pushes every boundary out."""
    plan = LodPlan((), (4, 2), (240.0, 80.0, 20.0), (12.0, 18.0), 1280, 50.0)
    rng = np.random.default_rng(1)
    r = rng.uniform(1.0, 3000.0, 400)
    sigma = rng.uniform(0.3, 3.0, 400)
    species = rng.integers(0, 2, 400)
    pos = np.stack([r, np.zeros_like(r), np.zeros_like(r)], 1)
    for fov in (50.0, 20.0):
        levels = plan.levels(pos, species, np.zeros(3), sigma, fov)
        for d, s, sp, level in zip(r, sigma, species, levels):
            band = next(b for b in plan.bands(int(sp), fov) if b.near <= d / s < b.far)
            assert band.level == level
    f = 640 / math.tan(math.radians(50.0) / 2)
    assert plan.bands(0)[1].near == pytest.approx(12.0 * f / 240.0)
    assert plan.bands(1) == plan.bands(1, 50.0) and len(plan.bands(1)) == 2
    assert plan.bands(0, 20.0)[1].near > plan.bands(0, 50.0)[1].near


def test_small_trees_seen_from_above_take_the_far_level_like_any_other():
    """The far level has a card seen from above (forest.library.lod.impostor), so the automatic rule makes no
    exception for steep views: a tree twice past the far boundary is far from 10°, 60° and 89° above its horizon."""
    plan = LodPlan((), (4,), (240.0, 80.0, 20.0), (12.0,), 320, 60.0)
    far = 12.0 * (160 / math.tan(math.radians(30.0))) / 20.0 * 2
    angles = np.radians([10.0, 60.0, 89.0])
    pos = np.stack([far * np.cos(angles), -far * np.sin(angles), np.zeros(3)], 1)
    assert plan.levels(pos, np.zeros(3, np.int64), np.zeros(3)).tolist() == [3, 3, 3]


def test_manual_distances_ignore_scale_and_species_size(tmp_path, lib):
    r = np.array([10.0, 39.0, 41.0, 119.0, 121.0, 299.0, 301.0, 2000.0] * 2)
    scale = np.linspace(0.5, 3.0, len(r))
    species = np.repeat([0, 1], 8)
    scene = scene_of(tmp_path, lib, "\n[lod]\ndistances = [40.0, 120.0, 300.0]\n", r, scale, species)
    cam = np.asarray(scene.config.camera.position, float)
    want = lod_levels(scene.instances.position, cam, (40.0, 120.0, 300.0), np.where(species == 0, 4, 2))
    np.testing.assert_array_equal(scene.levels(1.0), want)
    assert scene.levels(1.0)[:8].tolist() == [0, 0, 1, 1, 2, 2, 3, 3]
    assert scene.lod.describe() == "distances 40, 120, 300 m"
    plan = scene.lod  # manual: the distances decide the levels; sizes and the image only the solid cards
    assert (plan.distances, plan.n_lods, plan.pixels, plan.solid_pixels) == ((40.0, 120.0, 300.0), (4, 2), (), 80.0)
    assert plan.levels(scene.instances.position, species, cam, scale).tolist() == scene.levels(1.0).tolist()


def test_solid_cards_go_to_the_trees_of_at_most_solid_pixels_whatever_their_level(tmp_path, lib):
    """Trees of both species at 150 m scaled to 0.1 % above and below 80 px (the default) and 30 px (set): solid
    iff p = σ·H·f/r ≤ solid_pixels, under the automatic rule and under manual distances alike; 0 turns it off; a
    tree at its highest level never is."""
    w, h_px = 1280, 720
    probe = make_config(tmp_path).with_overrides({"render.width": w, "render.height": h_px})
    f = (w / 2) / math.tan(math.radians(probe.camera.fov) / 2)
    scale, species, want = [], [], []
    for s, name in enumerate(("oak", "pine")):
        H = height(lib, name)
        for p in (300.0, 80.0 * 1.001, 80.0 / 1.001, 30.0 * 1.001, 30.0 / 1.001, 5.0):
            scale.append(p * R / (H * f))
            species.append(s)
            want.append(p)
    want = np.asarray(want)
    for lod, limit in (
        ("", 80.0),
        ("\n[lod]\nsolid_pixels = 30.0\n", 30.0),
        ("\n[lod]\ndistances = [40.0, 120.0, 300.0]\n", 80.0),
        ("\n[lod]\nsolid_pixels = 0\n", 0.0),
    ):
        scene = scene_of(tmp_path, lib, lod, np.full(len(scale), R), scale, species, width=w)
        got = scene.solid_cards(1.0)
        np.testing.assert_array_equal(got, (want <= limit) if limit > 0 else np.zeros(len(want), bool))
    # At the highest level (here: level of detail off) the cards are the full model's leaves: never solid.
    scene = scene_of(tmp_path, lib, "\n[lod]\nauto = false\n", np.full(len(scale), R), scale, species, width=w)
    assert not scene.solid_cards(1.0).any()


def test_lod_off_puts_every_tree_at_its_highest_level(tmp_path, lib):
    r = np.array([5.0, 50.0, 500.0, 5000.0])
    scene = scene_of(tmp_path, lib, "\n[lod]\nauto = false\n", r, 0.1, [0, 1, 0, 1])
    assert scene.levels(1.0).tolist() == [0, 0, 0, 0]
    assert scene.lod.describe() == "off" and all(len(scene.lod.bands(s)) == 1 for s in (0, 1))


@pytest.mark.parametrize(
    ("lod", "field", "words"),
    [
        ("distances = [40.0, 120.0]\npixels = [200.0, 50.0]", "lod.pixels", "not both"),
        ("pixels = [50.0, 200.0]", "lod.pixels", "strictly decreasing"),
        ("auto = false\npixels = [200.0]", "lod.pixels", "auto = false"),
        ("pixels = []", "lod.pixels", "at least 1"),
    ],
)
def test_lod_config_errors_name_the_file_and_field(tmp_path, lod, field, words):
    with pytest.raises(ConfigError) as e:
        make_config(tmp_path, f"\n[lod]\n{lod}\n")
    text = str(e.value)
    assert "scene.toml" in text and field in text and words in text, text


def test_rib_detail_range_picks_the_renderers_level(tmp_path, lib):
    """Automatic LOD (no [lod]) through RIB: the raster area RenderMan measures for each tree — its scaled detail
    bound at the camera's distance, σ²·h·w·(f/r)² — falls in the DetailRange band of the level the renderer picks,
    in every frame of a fly-through whose fov changes (the bands follow the frame's fov; the areas do not)."""
    cfg = make_config(tmp_path, fly_keys(last_frame=3)).with_overrides({"render.width": 1920, "render.height": 1080})
    inst = make_instances(300)
    scene = load_scene(cfg, inst, library=lib)
    res = export_rib(scene, tmp_path / "out")
    by_id = {int(i): k for k, i in enumerate(inst.id)}
    seen, fovs, ranges_by_frame = set(), set(), []
    for frame in (1, 2, 3):
        cam = camera_at(cfg.camera, frame)
        fovs.add(round(float(cam.fov), 6))
        f_px = (cfg.render.width / 2) / math.tan(math.radians(cam.fov) / 2)
        levels = scene.levels(float(frame))
        ranges = {}
        checked = 0
        for path in res.frame_instance_files[frame]:
            for t in ribcheck.read_trees(ribcheck.parse(path.read_bytes())):
                k = by_id[int(t["name"][5:])]
                ranges[k] = np.array(t["ranges"])
                if not t["ranges"]:  # a single level: nothing to switch
                    assert levels[k] == 0
                    continue
                d = t["detail"]
                area = (d[3] - d[2]) * max(d[1] - d[0], d[5] - d[4])
                sigma = float(np.linalg.norm(t["matrix"][:3, 0]))
                r = float(np.linalg.norm(t["matrix"][:3, 3] - cam.position))
                a = sigma**2 * area * (f_px / r) ** 2
                full = [b for b, rng in enumerate(t["ranges"]) if rng[1] <= a <= rng[2]]
                if not full:  # inside a cross-fade (± lod_transition): both neighbours draw
                    continue
                level = archive_level(t["archives"][full[0]][0])
                sp = lib.resolve(inst.species_names[inst.species[k]])
                assert level == sp.lods[levels[k]].name, (frame, k, a, t["ranges"])
                seen.add(level)
                checked += 1
        assert checked > 0.7 * len(inst)
        ranges_by_frame.append(ranges)
    assert len(fovs) == 3 and len(seen) >= 3, (fovs, seen)
    for k, rng in ranges_by_frame[0].items():  # the automatic rule's areas are the same whatever the fov
        np.testing.assert_allclose(ranges_by_frame[2][k], rng, rtol=1e-5)


def archive_level(archive: str) -> str:
    """The level an archive path names: ``archives/<species>_<level>.rib``."""
    return archive.rsplit("/", 1)[-1][: -len(".rib")].rsplit("_", 1)[1]


def test_render_summary_says_which_rule_chose_the_levels():
    res = RenderResult(
        paths=[],
        frames=[1],
        variant="llvm_ad_rgb",
        variant_reason="",
        width=64,
        height=36,
        spp=4,
        subframes=1,
        trees=10,
        instanced_triangles=100,
        unique_triangles=50,
        shapegroups=2,
        load_seconds=0.1,
        render_seconds=0.2,
        peak_memory_gb=0.5,
        lod_counts={"high": 3, "far": 7},
        lod_rule="auto: pixels 240, 80, 20",
    )
    assert res.summary().endswith("; LOD high 3, far 7 (auto: pixels 240, 80, 20)")
