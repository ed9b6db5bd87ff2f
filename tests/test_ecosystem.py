"""Ecosystem scatter: competition, self-thinning, undergrowth and site preferences."""

from __future__ import annotations

import numpy as np
from conftest import write_scene
from scipy.spatial import cKDTree

from forest.config import load_config
from forest.scatter import scatter

SCENE = """
seed = 3
[terrain]
procedural = {{ size = 400.0, height = 100.0, octaves = 5, resolution = 96 }}
[scatter]
method = "ecosystem"
count = {count}
[ecosystem]
steps = {steps}
[[species]]
model = "conifer"
percent = 30
radius = 3.5
growth = 0.2
altitude = [55.0, 100.0]
[[species]]
model = "broadleaf"
percent = 40
radius = 5.0
growth = 0.3
moisture = [0.3, 1.0]
[[species]]
model = "fern"
percent = 30
radius = 0.6
growth = 0.8
shade_tolerance = 1.0
moisture = [0.6, 1.0]
"""


def _run(tmp_path, count=20000, steps=12, name="eco.toml"):
    cfg = write_scene(tmp_path, SCENE.format(count=count, steps=steps), name)
    return scatter(load_config(cfg))


def test_canopy_circles_do_not_overlap_but_undergrowth_may(tmp_path):
    inst, rep = _run(tmp_path)
    r = rep.columns["radius"]
    shade = rep.columns["shade_tolerant"]
    assert rep.rejected["competition"] > 0 and len(inst) > 500
    tree = cKDTree(inst.position)
    pairs = tree.query_pairs(2 * r.max(), output_type="ndarray")
    d = np.linalg.norm(inst.position[pairs[:, 0]] - inst.position[pairs[:, 1]], axis=1)
    over = r[pairs[:, 0]] + r[pairs[:, 1]] > d + 1e-9
    a, b = pairs[over, 0], pairs[over, 1]
    # Every overlap left standing involves shade-tolerant undergrowth.
    assert (shade[a] | shade[b]).all()
    assert over.sum() > 0  # and there is undergrowth beneath canopies


def test_self_thinning_fewer_larger_plants_with_time(tmp_path):
    _young, ry = _run(tmp_path, steps=3, name="a.toml")
    _old, ro = _run(tmp_path, steps=25, name="b.toml")
    canopy_y = ~ry.columns["shade_tolerant"]
    canopy_o = ~ro.columns["shade_tolerant"]
    assert canopy_o.sum() < canopy_y.sum()
    assert ro.columns["radius"][canopy_o].mean() > ry.columns["radius"][canopy_y].mean()


def test_site_preferences_place_species(tmp_path):
    inst, rep = _run(tmp_path)
    y = inst.position[:, 1]
    conifer, fern = inst.species == 0, inst.species == 2
    assert conifer.any() and fern.any()
    # Conifers keep to their altitude window (with a soft shoulder); wet-loving ferns sit lower.
    assert np.percentile(y[conifer], 5) > 45.0
    assert y[fern].mean() < y[conifer].mean() - 15.0
    assert rep.rejected["site"] > 0


def test_ecosystem_is_deterministic(tmp_path):
    a, _ = _run(tmp_path, count=5000, name="a.toml")
    b, _ = _run(tmp_path, count=5000, name="b.toml")
    np.testing.assert_array_equal(a.id, b.id)
    np.testing.assert_array_equal(a.position, b.position)
    np.testing.assert_array_equal(a.scale, b.scale)
