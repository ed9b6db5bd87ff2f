"""scalar_rgb shows every tree's colour jitter: one shapegroup per (prototype, jitter bin) (forest.render.instancing)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest

from forest.config import parse_config
from forest.instances import InstanceSet, yaw_tilt_quaternion
from forest.render import render_scene
from forest.render.instancing import JITTER_BINS, ForestBuilder, JitterBins, jitter_bin_count
from forest.render.materials import MaterialBuilder
from forest.scatter.models import model_settings
from forest.scene import load_scene
from forest.tint import tint_params

from render_fixtures import BoxLibrary

# Six white boxes (scale 3: 6 × 18 × 6 m) seen from straight above (400 m, nearly orthographic: their tops only) under
# a white sky, on a black ground; their albedo 0.8 × the leaf tint 0.3 stays below 1 under a factor 4 of jitter.
SCENE = """
seed = 5
[terrain]
flat = {{ size = 60.0 }}
[camera]
position = [0.0, 400.0, 0.0]
target = [0.0, 0.0, 0.0]
up = [0.0, 0.0, 1.0]
fov = 6.0
[lights]
sky = {{ radiance = 1.0, colour = [1.0, 1.0, 1.0] }}
[render]
width = 40
height = 40
spp = 8
max_depth = 2
terrain_colour = [0.0, 0.0, 0.0]
[[species]]
model = "box"
percent = 100
colour_jitter = {{ hue = 0.0, value = {value} }}
[lod]
auto = false
[lookdev.leaf_tint]
box = [0.3, 0.3, 0.3]
"""

POSITIONS = [[x, 0.0, z] for x in (-12.0, 0.0, 12.0) for z in (-6.0, 6.0)]


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    return BoxLibrary(tmp_path_factory.mktemp("boxlib"))


def _scene(tmp_path: Path, library: BoxLibrary, value: float):
    text = SCENE.format(value=value)
    (tmp_path / "scene.toml").write_text(text)
    cfg = parse_config(text, path=tmp_path / "scene.toml", base_dir=tmp_path)
    p = np.asarray(POSITIONS, np.float32)
    n = len(p)
    up = np.tile([0.0, 1.0, 0.0], (n, 1))
    ids, species = np.arange(40, 40 + n), np.zeros(n, np.int64)
    # The tints scatter writes (no colour map: the jitter alone), forest.tint.
    params = tint_params(model_settings(cfg), (library.resolve("box"),), cfg.seed)
    trees = InstanceSet(
        id=ids,
        position=p,
        rotation=yaw_tilt_quaternion(np.zeros(n), up, np.zeros(n)),
        yaw=np.zeros(n),
        scale=np.full(n, 3.0),
        species=species,
        tint=params.tints(np.ones((n, 3), np.float32), species, ids),
        partition=np.zeros(n),
        normal=up,
        phase=np.zeros(n),
        species_names=["box"],
        extent=(-30.0, -30.0, 30.0, 30.0),
    )
    return load_scene(cfg, trees, library=library)


def _tree_colours(path: Path, ids: np.ndarray) -> np.ndarray:
    """The mean RGB over each tree's pixels (by the ``id`` layer): (N, 3)."""
    inp = oiio.ImageInput.open(str(path))
    spec = inp.spec()
    data = np.asarray(inp.read_image(0, 0, 0, spec.nchannels, "float")).reshape(spec.height, spec.width, -1)
    inp.close()
    rgb, tree = data[..., :3], data[..., list(spec.channelnames).index("id.Z")].astype(int)
    out = []
    for i in ids.tolist():
        px = rgb[tree == i]
        assert len(px) >= 16, f"tree {i} covers {len(px)} pixels"
        out.append(px.mean(axis=0))
    return np.array(out)


@pytest.fixture(scope="module")
def renders(tmp_path_factory, library):
    """{jitter value: (Scene, each tree's mean colour)} for value jitter 0 and ±60 %: the same trees and samples."""
    out = {}
    for value in (0.0, 0.6):
        tmp = tmp_path_factory.mktemp(f"jitter{value}")
        scene = _scene(tmp, library, value)
        render_scene(scene, output=tmp / "f.exr", variant="scalar_rgb")
        out[value] = (scene, _tree_colours(tmp / "f.exr", scene.instances.id))
    return out


def test_no_jitter_gives_equal_colours_and_the_plain_graph(renders):
    """Jitter 0: every tree the same colour, and the graph has no jitter shapegroup (the scene without the feature)."""
    scene, seen = renders[0.0]
    assert scene.tree_jitter() is None
    builder = ForestBuilder(
        scene, MaterialBuilder("scalar_rgb", None, scene.terrain.extent, scene.terrain.height_range)
    )
    graph = builder.graph(np.zeros(len(scene.instances), np.int64), scene.instances.matrices())
    assert graph.shapegroups == 1 and graph.jittered_shapegroups == 0
    assert [k for k in graph.entries or {} if k.startswith("sg_")] == ["sg_0_0_0"]
    np.testing.assert_allclose(seen, np.broadcast_to(seen.mean(axis=0), seen.shape), rtol=0.1)  # coverage differs
    np.testing.assert_allclose(seen[:, 0], seen[:, 1], rtol=1e-4)  # grey


def test_a_large_jitter_gives_each_tree_its_own_colour(renders):
    """Value jitter ±60 %: the six trees' foliage differs as their tints do (each tree is its own bin here).

    Direct light only, so a tree's pixels are linear in its albedo and, with the same
    samples, its colour over the plain render's is its factor exactly.
    """
    scene, seen = renders[0.6]
    _plain, base = renders[0.0]
    tint = scene.instances.tint.astype(np.float64)
    assert tint[:, 1].max() / tint[:, 1].min() > 4.0  # the jitter is large
    assert seen[:, 1].max() / seen[:, 1].min() > 4.0
    np.testing.assert_allclose(seen / base, tint, rtol=0.02)


def test_jittered_graph_has_one_shapegroup_per_bin_in_use(renders):
    scene, _ = renders[0.6]
    builder = ForestBuilder(
        scene, MaterialBuilder("scalar_rgb", None, scene.terrain.extent, scene.terrain.height_range)
    )
    graph = builder.graph(np.zeros(len(scene.instances), np.int64), scene.instances.matrices())
    assert graph.shapegroups == graph.jittered_shapegroups == len(scene.instances)  # 6 trees < 8 bins
    # A heavy prototype gets fewer bins: all six trees share the bins of its k.
    assert jitter_bin_count(12) == JITTER_BINS and jitter_bin_count(10**8) == 1
    assert jitter_bin_count(60_000) == 3


def test_jitter_bins_are_deterministic_equal_count_and_keep_the_mean():
    rng = np.random.default_rng(1)
    n = 1000
    species = rng.integers(0, 3, n)
    ids = rng.permutation(n) + 7
    light = 1.0 + rng.uniform(-0.4, 0.4, n)
    jitter = light[:, None] * np.array([1.0, 1.0, 1.0]) + rng.normal(0, 0.02, (n, 3))
    jitter[species == 2] = 1.0  # a species without jitter: not binned
    base = np.array([[0.1, 0.3, 0.05], [0.2, 0.25, 0.1], [0.1, 0.3, 0.05]])
    jb = JitterBins(jitter, species, ids, base)
    bins, factors = jb.bins(8)
    assert (bins[species == 2] == -1).all() and (bins[species < 2] >= 0).all()
    np.testing.assert_array_equal(factors[2], 1.0)
    for s in (0, 1):
        rows = species == s
        counts = np.bincount(bins[rows], minlength=8)
        assert counts.max() - counts.min() <= 1  # equal-count bins
        # the count-weighted mean of the bins' factors is the species' mean jitter
        np.testing.assert_allclose(counts @ factors[s] / counts.sum(), jitter[rows].mean(axis=0), rtol=1e-12)
        # lighter bins have larger factors: the bins split the lightness
        assert np.all(np.diff(factors[s, :, 1]) > 0)
    # the same trees in another order get the same bins: ranks tie-break on the tree id
    order = rng.permutation(n)
    again, factors2 = JitterBins(jitter[order], species[order], ids[order], base).bins(8)
    np.testing.assert_array_equal(again, bins[order])
    np.testing.assert_allclose(factors2, factors, rtol=1e-12)
    # fewer trees than bins: at most one bin per tree
    few, _ = JitterBins(jitter[:3], np.zeros(3), ids[:3], base[:1]).bins(8)
    assert len(set(few.tolist())) == 3
