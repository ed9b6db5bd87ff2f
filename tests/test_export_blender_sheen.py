"""The leaf cuticle's lobe travels to Blender: Cycles shows the glint forest_path renders, by as much.

A leaf slab (one flat block of ``leaf`` material, dark green, translucent) under a sun in the mirror direction of
the camera's view of it, rendered by forest (forest_path, ``llvm_ad_rgb``) and by Cycles from the ``.blend``
export, with the cuticle's lobe (``sheen`` s = 1, GGX α = 0.3) and without it.  The slab's mean linear RGB with
the lobe over without, per renderer: the glint must show in both (a rise of more than half), by the same
factor within 15 % — the export's s·F(μ)·glossy mix against forest's s·F·D·G₂ lobe (docs/exports.md).  Skipped
where no Blender is installed.
"""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from test_export_blender_look import BlockLibrary, block, read_layers

from forest.config import parse_config
from forest.export.blender import export_blender
from forest.images import read_image, srgb_to_linear
from forest.render import render_scene
from forest.scene import load_scene

from export_support import FakeLod, FakePart, FakeSpecies, make_instances

pytestmark = pytest.mark.skipif(shutil.which("blender") is None, reason="Blender is not installed")

#: |(Cycles' with/without) ÷ (forest's with/without) − 1| on the slab, per channel.
RATIO_TOL = 0.15

SCENE = """
seed = 3
name = "sheen"
[terrain.flat]
size = 400.0
[[species]]
model = "slab"
percent = 100
[camera]
position = [0.0, 20.0, -35.0]
target = [0.0, 0.0, 0.0]
fov = 40.0
[lights.sun]
elevation = 29.7
azimuth = 0.0
irradiance = 3.0
[lights.sky]
radiance = 0.2
colour = [0.6, 0.75, 1.0]
[render]
width = 64
height = 36
spp = 64
max_depth = 3
horizon_ground = false
terrain_colour = [0.1, 0.1, 0.1]
view = "standard"
"""


class SlabLibrary(BlockLibrary):
    """``slab``: one flat leaf block 40 m square, with the cuticle lobe ``sheen`` (α 0.3) or without (0)."""

    def __init__(self, sheen: float):
        slab = block((-20, 0.0, -20), (20, 0.5, 20))
        part = FakePart("leaf", "slab_leaf.ply", (0.08, 0.2, 0.05), None, False, 0.3, slab, sheen, 0.3)
        bounds = np.stack([slab.vertices.min(0), slab.vertices.max(0)]).astype(np.float64)
        self.species = {"slab": FakeSpecies("slab", "generated", [FakeLod("high", 12, bounds, (part,))])}


@pytest.fixture(scope="module")
def slab_means(tmp_path_factory):
    """{(renderer, sheen): the slab's mean linear RGB}."""
    tmp = tmp_path_factory.mktemp("sheen")
    inst = make_instances(1, seed=1, partitions=("all",), empty_partition=None, species=("slab",), tilt=0.0)
    inst.position[:] = 0.0
    inst.scale[:] = 1.0
    inst.tint[:] = 1.0
    means = {}
    for sheen in (0.0, 1.0):
        path = tmp / f"s{sheen:g}.toml"
        path.write_text(SCENE)
        scene = load_scene(parse_config(SCENE, path=path), inst, library=SlabLibrary(sheen))
        render_scene(scene, output=tmp / f"forest_{sheen:g}.exr", variant="llvm_ad_rgb")
        layers = read_layers(tmp / f"forest_{sheen:g}.exr")
        if sheen == 0.0:
            mask = layers["id.Z"] >= 0
        forest = np.stack([layers["R"], layers["G"], layers["B"]], axis=-1)
        export_blender(scene, tmp / f"s{sheen:g}.blend", render=tmp / f"cycles_{sheen:g}.png")
        cycles = srgb_to_linear(read_image(tmp / f"cycles_{sheen:g}.png")[..., :3])
        means["forest", sheen], means["cycles", sheen] = forest[mask].mean(0), cycles[mask].mean(0)
    assert mask.mean() > 0.5, "the slab should fill most of the frame"
    return means


def test_the_cuticle_glint_shows_in_cycles_as_in_forest(slab_means):
    m = slab_means
    forest, cycles = m["forest", 1.0] / m["forest", 0.0], m["cycles", 1.0] / m["cycles", 0.0]
    print(f"slab with/without the lobe: forest {np.round(forest, 3)}, Cycles {np.round(cycles, 3)}")
    print(f"slab means with the lobe: forest {np.round(m['forest', 1.0], 4)}, Cycles {np.round(m['cycles', 1.0], 4)}")
    assert np.all(forest > 1.5) and np.all(cycles > 1.5)
    np.testing.assert_allclose(cycles / forest, 1.0, atol=RATIO_TOL)
