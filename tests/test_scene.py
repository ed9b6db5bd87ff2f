"""The Scene hub: one colour-map reader, tints that agree across backends, one level-of-detail rule."""

from __future__ import annotations

import numpy as np
import pytest
from test_render import make_config, read_exr, write_png

from forest.export.rib import export_rib
from forest.instances import InstanceSet, yaw_tilt_quaternion
from forest.lod import LodPlan
from forest.render import render_scene
from forest.scene import load_scene

import ribcheck
from render_fixtures import BoxLibrary

# A colour map of four flat quadrants (encoded sRGB), one tree at the centre of each.
QUADRANTS = np.array([[[0.9, 0.4, 0.4], [0.4, 0.9, 0.4]], [[0.4, 0.4, 0.9], [0.9, 0.9, 0.4]]])
CENTRES = [[-25.0, 0.0, -25.0], [25.0, 0.0, -25.0], [-25.0, 0.0, 25.0], [25.0, 0.0, 25.0]]


@pytest.fixture
def library(tmp_path):
    return BoxLibrary(tmp_path / "lib")


def four_trees() -> InstanceSet:
    n = len(CENTRES)
    return InstanceSet(
        id=np.arange(10, 10 + n, dtype=np.uint64),
        position=np.array(CENTRES, np.float32),
        rotation=yaw_tilt_quaternion(np.zeros(n), np.tile([0.0, 1.0, 0.0], (n, 1)), np.zeros(n)),
        yaw=np.zeros(n),
        scale=np.full(n, 2.0),
        species=np.zeros(n, np.uint16),
        tint=np.ones((n, 3)),
        partition=np.zeros(n, np.int16),
        normal=np.tile([0.0, 1.0, 0.0], (n, 1)),
        phase=np.zeros(n),
        species_names=["box"],
        extent=(-50.0, -50.0, 50.0, 50.0),
    )


def test_every_backend_takes_the_colour_map_from_the_one_reader(tmp_path, library, monkeypatch):
    """A counting fake of the image reader: the colour map is read once, by load_scene, whatever runs after."""
    import forest.images
    from forest.export.usd import export_usd
    from forest.lookdev.renders import FitRenderer

    write_png(tmp_path / "colour.png", np.repeat(np.repeat(QUADRANTS, 8, 0), 8, 1))
    cfg = make_config(tmp_path, maps='colour = "colour.png"')
    reads: list[str] = []
    real = forest.images.read_image

    def counting(path, *a, **k):
        reads.append(str(path))
        return real(path, *a, **k)

    monkeypatch.setattr(forest.images, "read_image", counting)
    scene = load_scene(cfg, four_trees(), library=library)
    colour_reads = [p for p in reads if p.endswith("colour.png")]
    assert len(colour_reads) == 1
    render_scene(scene, output=tmp_path / "r.exr", variant="scalar_rgb")
    render_scene(scene, output=tmp_path / "l.exr", variant="llvm_ad_rgb")
    export_rib(scene, tmp_path / "rib")
    export_usd(scene, tmp_path / "usd" / "f.usda")
    FitRenderer(scene, width=16, height=16, spp=1, variant="llvm_ad_rgb", base_map=None)  # look-dev's renders
    assert [p for p in reads if p.endswith("colour.png")] == colour_reads  # no backend read it again


def test_render_tints_agree_with_rib_colour(tmp_path, library):
    """Each tree's render colour over its untinted colour is the tint RIB writes as its ``Color``."""
    write_png(tmp_path / "colour.png", np.repeat(np.repeat(QUADRANTS, 16, 0), 16, 1))
    from forest.images import srgb_to_linear

    direct = {"render.max_depth": 2, "render.terrain_colour": [0.0, 0.0, 0.0], "render.width": 96, "render.height": 96}
    trees = four_trees()
    linear = srgb_to_linear(np.round(QUADRANTS.reshape(4, 3) * 255) / 255)
    trees.tint[:] = linear / linear.mean(axis=0)  # the map at each base, as a tint of mean 1 (equal quadrants)
    tinted_cfg = make_config(tmp_path, maps='colour = "colour.png"').with_overrides(direct)
    tinted = load_scene(tinted_cfg, trees, library=library)
    plain = load_scene(make_config(tmp_path).with_overrides(direct), four_trees(), library=library)
    export_rib(tinted, tmp_path / "rib")
    colour = {}
    for path in (tmp_path / "rib").glob("instances_*.rib"):
        for t in ribcheck.read_trees(ribcheck.parse(path.read_bytes())):
            colour[int(t["name"][5:])] = np.asarray(t["color"])
    a = read_exr(render_scene(tinted, output=tmp_path / "t.exr", variant="scalar_rgb").paths[0])
    b = read_exr(render_scene(plain, output=tmp_path / "p.exr", variant="scalar_rgb").paths[0])
    for tree_id, rib_colour in colour.items():
        px = (a["id"] == tree_id) & (b["id"] == tree_id)
        assert px.sum() > 10
        ratio = a["rgb"][px].mean(axis=0) / b["rgb"][px].mean(axis=0)
        np.testing.assert_allclose(ratio, rib_colour, rtol=0.03)


def test_instance_tints_are_kept_unless_the_set_was_scattered(tmp_path, library):
    """A set made elsewhere keeps its tints; a scatter's set takes its tints from the config's map (mean 1)."""
    inst = four_trees()
    inst.tint[:] = [[0.2, 0.5, 0.9]]
    scene = load_scene(make_config(tmp_path), inst, library=library)
    np.testing.assert_array_equal(scene.instances.tint, inst.tint)  # no record of a map: as given
    write_png(tmp_path / "colour.png", np.repeat(np.repeat(QUADRANTS, 8, 0), 8, 1))
    inst.meta["inputs"] = {"maps.colour": {"file": "old.png", "sha256": "0" * 64}}  # scattered from another map
    no_jitter = {"species[0].colour_jitter": {"hue": 0.0, "value": 0.0}}
    cfg = make_config(tmp_path, maps='colour = "colour.png"').with_overrides(no_jitter)
    scene = load_scene(cfg, inst, library=library)
    from forest.images import srgb_to_linear

    linear = srgb_to_linear(np.round(QUADRANTS.reshape(4, 3) * 255) / 255)
    np.testing.assert_allclose(scene.instances.tint, linear / linear.mean(axis=0), rtol=1e-5)


def test_lod_bands_and_levels_are_one_rule():
    plan = LodPlan((40.0, 100.0, 500.0), (4, 2))
    assert [(b.level, b.near, b.far) for b in plan.bands(0)] == [
        (0, 0.0, 40.0),
        (1, 40.0, 100.0),
        (2, 100.0, 500.0),
        (3, 500.0, np.inf),
    ]
    assert [(b.level, b.near) for b in plan.bands(1)] == [(0, 0.0), (1, 40.0)]  # levels past the last merge
    r = np.array([1.0, 39.9, 40.0, 99.0, 100.0, 499.0, 501.0, 9000.0])
    for species in (0, 1):
        pos = np.stack([r, np.zeros_like(r), np.zeros_like(r)], 1)
        levels = plan.levels(pos, np.full(len(r), species), np.zeros(3))
        for d, level in zip(r, levels):
            band = next(b for b in plan.bands(species) if b.near <= d < b.far)
            assert band.level == level
