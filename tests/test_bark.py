"""Bark varies per tree: hue/value jitter and moss (``[[species]] bark``, forest.tint.bark_tints), in every backend.

The truth for the renderers is :meth:`forest.scene.Scene.bark_tints` (the factor every exporter
writes), checked itself against the closed form of a pure moss mix; a renderer's per-tree albedo
divided by it must be the same for every tree.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest
from scipy.ndimage import binary_erosion
from test_render import trees

from forest.config import parse_config
from forest.render import render_scene
from forest.scene import load_scene
from forest.tint import bark_tints

from render_fixtures import BoxLibrary

# Six grey bark boxes (scale 2: 4 × 12 × 4 m) seen from straight above (nearly orthographic: their tops only),
# under a white sky, on a black ground (``head``: top-level keys; ``species``: the [[species]] tables).
SCENE = """
seed = 5
{head}
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
spp = 4
max_depth = 2
terrain_colour = [0.0, 0.0, 0.0]
{render}
{species}
[lod]
auto = false
"""
STUMPS = '[[species]]\nmodel = "stump"\npercent = 100\nbark = {bark}\n'
STRONG = "{ hue = 30.0, value = 0.4, moss = [0.0, 0.8], moss_colour = [0.05, 0.3, 0.02] }"
NONE = "{ hue = 0.0, value = 0.0, moss = [0.0, 0.0] }"
POSITIONS = [[x, 0.0, z] for x in (-12.0, 0.0, 12.0) for z in (-6.0, 6.0)]


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    return BoxLibrary(tmp_path_factory.mktemp("barklib"))


def stump_scene(tmp_path: Path, library: BoxLibrary, bark: str = STRONG, render: str = ""):
    """The six stumps with ``bark`` (an inline TOML table) as a Scene."""
    text = SCENE.format(head="", render=render, species=STUMPS.format(bark=bark))
    cfg = parse_config(text, path=tmp_path / "scene.toml", base_dir=tmp_path)
    inst = dataclasses.replace(trees(POSITIONS, names=("stump",), scale=2.0), extent=(-30.0, -30.0, 30.0, 30.0))
    return load_scene(cfg, inst, library=library)


def tree_albedo(path: Path, ids: np.ndarray) -> np.ndarray:
    """Each tree's mean first-hit albedo (the ``albedo`` layer over the interior of its ``id`` pixels): (N, 3)."""
    inp = oiio.ImageInput.open(str(path))
    spec = inp.spec()
    data = np.asarray(inp.read_image(0, 0, 0, spec.nchannels, "float")).reshape(spec.height, spec.width, -1)
    inp.close()
    names = list(spec.channelnames)
    albedo = data[..., [names.index(f"albedo.{c}") for c in "RGB"]]
    tree = data[..., names.index("id.Z")]
    out = []
    for i in ids.tolist():
        px = binary_erosion(tree == float(i))
        assert px.sum() >= 4, f"tree {i} covers {px.sum()} pixels"
        out.append(albedo[px].mean(axis=0))
    return np.array(out)


def test_a_pure_moss_mix_is_the_closed_form_and_keyed_by_tree_id():
    """hue = value = 0: f_i = (1 − μ_i) + μ_i·g ⊘ b with μ_i in [lo, hi]; a tree's factor is its own (by id),
    whichever other trees are there; a species without bark (NaN colour) keeps 1."""
    base = np.array([[0.2, 0.15, 0.1], [np.nan] * 3])
    g = np.array([[0.05, 0.1, 0.02], [0.05, 0.1, 0.02]])
    moss = np.array([[0.2, 0.6], [0.2, 0.6]])
    ids = np.arange(1000, 3000)
    species = np.zeros(len(ids), np.int64)
    species[::2] = 1
    f = bark_tints(species, ids, 7, base, np.zeros(2), np.zeros(2), moss, g).astype(np.float64)
    assert np.all(f[species == 1] == 1.0)
    barked = f[species == 0]
    mu = (barked - 1.0) / (g[0] / base[0] - 1.0)  # the same μ from each channel
    np.testing.assert_allclose(mu, mu[:, :1].repeat(3, axis=1), atol=1e-5)
    assert mu.min() >= 0.2 - 1e-5 and mu.max() <= 0.6 + 1e-5 and np.ptp(mu) > 0.35
    # keyed by id: the last 10 trees alone get the same factors
    alone = bark_tints(species[-10:], ids[-10:], 7, base, np.zeros(2), np.zeros(2), moss, g)
    np.testing.assert_array_equal(alone, f[-10:].astype(np.float32))
    assert not np.array_equal(bark_tints(species, ids, 8, base, np.zeros(2), np.zeros(2), moss, g), f)


def test_the_default_bark_varies_and_none_gives_none(tmp_path, library):
    """The library default jitters bark (and the leaves' jitter is untouched by it); ``bark`` all zero gives None."""
    plain = stump_scene(tmp_path, library, NONE)
    assert plain.bark_tints() is None
    default = stump_scene(tmp_path, library, "{}")
    f = default.bark_tints()
    assert f is not None and f.shape == (6, 3) and np.ptp(f, axis=0).max() > 0.05


@pytest.mark.parametrize("variant", ["llvm_ad_rgb"])
def test_forest_path_shows_each_trees_bark(tmp_path, library, variant):
    """Albedo of each stump ÷ its bark factor is the species' bark colour for every tree."""
    out = {}
    for name, bark in (("strong", STRONG), ("none", NONE)):
        scene = stump_scene(tmp_path, library, bark, 'aovs = ["albedo"]')
        render_scene(scene, output=tmp_path / f"{name}.exr", variant=variant)
        out[name] = (scene, tree_albedo(tmp_path / f"{name}.exr", scene.instances.id))
    plain = out["none"][1]
    np.testing.assert_allclose(plain, 0.4, rtol=0.02)
    scene, strong = out["strong"]
    f = scene.bark_tints()
    np.testing.assert_allclose(strong / f, 0.4, rtol=0.03)
    assert np.ptp(strong, axis=0).max() > 0.3 * strong.mean()


def test_scalar_rgb_bins_the_bark_and_keeps_its_mean(tmp_path, library):
    """Six stumps get six bins (fewer trees than bins): each stump's colour ÷ its own bark factor is the bark
    colour, as in forest_path; without bark variation the graph has no bin."""
    from forest.render.instancing import ForestBuilder
    from forest.render.materials import MaterialBuilder

    colours = {}
    for name, bark in (("strong", STRONG), ("none", NONE)):
        scene = stump_scene(tmp_path, library, bark, 'aovs = ["albedo"]')
        builder = ForestBuilder(
            scene, MaterialBuilder("scalar_rgb", None, scene.terrain.extent, scene.terrain.height_range)
        )
        graph = builder.graph(np.zeros(len(scene.instances), np.int64), scene.instances.matrices())
        assert graph.jittered_shapegroups == (6 if name == "strong" else 0)
        render_scene(scene, output=tmp_path / f"s_{name}.exr", variant="scalar_rgb")
        colours[name] = (scene, tree_albedo(tmp_path / f"s_{name}.exr", scene.instances.id))
    np.testing.assert_allclose(colours["none"][1], 0.4, rtol=0.02)
    scene, strong = colours["strong"]
    np.testing.assert_allclose(strong / scene.bark_tints(), 0.4, rtol=0.03)


def test_bark_bins_share_the_bins_with_the_leaves():
    """Leaf jitter and bark factors binned together: k bins in all (no more shapegroups), a grid over the three
    coordinates, each species' mean leaf and bark factor kept."""
    from forest.render.instancing import JitterBins, _grid_shape

    rng = np.random.default_rng(3)
    n = 800
    ids = np.arange(n) + 11
    species = np.zeros(n, np.int64)
    jitter = (1.0 + rng.uniform(-0.3, 0.3, n))[:, None] * np.ones(3)
    base, bark_base = np.array([[0.1, 0.3, 0.05]]), np.array([[0.2, 0.15, 0.1]])
    bark = bark_tints(species, ids, 1, bark_base, np.array([0.0]), np.array([0.3]), np.array([[0.0, 0.0]]), base)
    jb = JitterBins(jitter, species, ids, base, bark, bark_base)
    bins, factors = jb.bins(8)
    barks = jb.bark_factors(8)
    counts = np.bincount(bins, minlength=8)
    assert counts.min() > 0 and counts.max() - counts.min() <= 1 and bins.max() == 7
    np.testing.assert_allclose(counts @ factors[0] / n, jitter.mean(axis=0), rtol=1e-12)
    np.testing.assert_allclose(counts @ barks[0] / n, bark.mean(axis=0), rtol=1e-6)
    assert np.ptp(barks[0, :, 1]) > 0.2 and np.ptp(factors[0, :, 1]) > 0.2  # both split
    # the grid: two comparable spreads share 8 bins (4 × 2 either way), a flat one gets none
    assert sorted(_grid_shape(8, 0.05, 0.0, 0.04)) == [1, 2, 4] and _grid_shape(8, 0.05, 0.0, 0.0) == (8, 1, 1)
    assert _grid_shape(8, 0.05, 0.01) == (8, 1)
