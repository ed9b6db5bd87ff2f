"""forest_path shows each tree's own colour: the InstanceSet's ``tint`` column beyond the colour map.

The truth is the tint column itself (what every exporter writes per tree), not the renderer's own
arithmetic: a tree's rendered albedo divided by its tint must be the same for every tree of a
species, and an untinted set must give equal albedos.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.ndimage import binary_erosion
from test_aovs import SKY, layer, read, render
from test_render import trees

from forest.scene import load_scene

from render_fixtures import BoxLibrary

#: Straight down from 45 m: each 4 m box top covers about 40 pixels of the 32×18 frame.
ABOVE = "position = [0.0, 45.0, 0.0]\ntarget = [0.0, 0.0, 0.0]\nup = [0.0, 0.0, 1.0]\nfov = 50.0"
POSITIONS = [[x, 0.0, z] for x in (-10.0, 0.0, 10.0) for z in (-5.0, 5.0)]
#: Six clearly different per-tree tints (hue and lightness), as a strong colour jitter gives.
TINTS = np.array(
    [[1.0, 1.0, 1.0], [0.55, 0.9, 1.3], [1.25, 1.0, 0.6], [0.7, 0.7, 0.7], [1.3, 1.2, 1.1], [0.9, 1.25, 0.8]],
    np.float32,
)


def _crown_albedo(tmp_path, library: BoxLibrary, name: str, tints: np.ndarray) -> np.ndarray:
    """Each tree's mean first-hit albedo (the EXR ``albedo`` layer over its ``id`` pixels' interior), (6, 3)."""
    inst = replace(trees(POSITIONS, scale=2.0), tint=tints)
    render(tmp_path, library, name, camera=ABOVE, lights=SKY, spp=4, render='aovs = ["albedo"]', inst=inst)
    d = read(tmp_path / f"{name}.exr")
    ids, albedo = d["id.Z"], layer(d, "albedo")
    means = []
    for tree_id in inst.id:
        px = binary_erosion(ids == float(tree_id))  # whole-box pixels, none shared with the ground
        assert px.sum() >= 4, f"tree {tree_id} covers {px.sum()} pixels"
        means.append(albedo[px].mean(axis=0))
    return np.array(means)


def test_each_tree_renders_with_its_own_tint(tmp_path):
    library = BoxLibrary(tmp_path / "lib")
    tinted = _crown_albedo(tmp_path, library, "tinted", TINTS)
    plain = _crown_albedo(tmp_path, library, "plain", np.ones_like(TINTS))
    # Untinted trees of one species look alike; the tinted ones differ by their tints.
    assert np.ptp(plain, axis=0).max() < 0.02 * plain.mean()
    ratio = tinted / TINTS
    assert np.allclose(ratio, plain.mean(axis=0), rtol=0.03), (ratio, plain.mean(axis=0))
    assert np.ptp(tinted, axis=0).max() > 0.3 * tinted.mean()


def test_tree_jitter_is_the_tint_beyond_the_colour_map(tmp_path):
    """``Scene.tree_jitter``: None for a map-only tint (no jitter), else the tint with the map divided out."""
    from test_scene import QUADRANTS, four_trees, make_config, write_png

    library = BoxLibrary(tmp_path / "lib")
    write_png(tmp_path / "colour.png", np.repeat(np.repeat(QUADRANTS, 8, 0), 8, 1))
    inst = four_trees()
    inst.meta["inputs"] = {"maps.colour": {"file": "colour.png", "sha256": "0" * 64}}  # a scatter's set: tints redone
    cfg = make_config(tmp_path, maps='colour = "colour.png"')
    plain = load_scene(
        cfg.with_overrides({"species[0].colour_jitter": {"hue": 0.0, "value": 0.0}}), inst, library=library
    )
    assert plain.tree_jitter() is None
    strong = {"species[0].colour_jitter": {"hue": 40.0, "value": 0.3}}
    scene = load_scene(cfg.with_overrides(strong), inst, library=library)
    jitter = scene.tree_jitter()
    assert jitter is not None and np.ptp(jitter, axis=0).max() > 0.1
    pos = scene.instances.position
    np.testing.assert_allclose(jitter * scene.colour.at(pos[:, 0], pos[:, 2]), scene.instances.tint, rtol=1e-5)
    np.testing.assert_allclose(plain.instances.tint, plain.colour.at(pos[:, 0], pos[:, 2]), rtol=1e-5)
