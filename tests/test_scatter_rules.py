"""Both scatter methods obey every rule the README lists; counts add up; results are deterministic."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import write_png, write_scene
from scipy.spatial import cKDTree

from forest.config import load_config
from forest.scatter import scatter

METHODS = ("random", "ecosystem")
N = 16000
MIN_DISTANCE = 1.5

# A 100 m × 100 m terrain: flat at y = 0 where x < 0, a 45° ramp (y = x) where x > 0.
# Maps (row 0 at z = −50): no trees where z > 30; half density where z < −20;
# region "south" where z < 0, "north" where z > 0.
SCENE = """
seed = 11
[terrain]
heightmap = "ramp.png"
size = [100.0, 100.0]
height = 50.0
[maps]
presence = "presence.png"
density = "density.png"
partition = "partition.png"
[partitions]
"#ff0000" = "south"
"#00ff00" = "north"
[scatter]
method = "{method}"
count = {count}
min_distance = {min_distance}
[ecosystem]
steps = 6
[[species]]
model = "broadleaf"      # flat ground, southern region only
percent = 30
slope_max = 30.0
partitions = ["south"]
radius = 1.0
growth = 0.4
[[species]]
model = "conifer"        # steep ground only
percent = 30
slope_min = 40.0
radius = 0.8
growth = 0.4
[[species]]
model = "shrub"          # below 20 m
percent = 30
altitude = [0.0, 20.0]
radius = 0.5
growth = 0.6
shade_tolerance = 1.0
"""


def _maps(folder):
    n = 64
    x = np.linspace(-50, 50, n)
    write_png(folder / "ramp.png", np.tile(np.where(x > 0, x, 0.0) / 50.0, (n, 1)), bits=16)
    pres = np.ones((10, 10))
    pres[8:] = 0.0  # rows 8, 9: z in [30, 50]
    write_png(folder / "presence.png", pres)
    dens = np.ones((10, 10))
    dens[:3] = 0.5  # rows 0-2: z in [-50, -20]
    write_png(folder / "density.png", dens)
    part = np.zeros((2, 2, 3))
    part[0] = (1.0, 0.0, 0.0)
    part[1] = (0.0, 1.0, 0.0)
    write_png(folder / "partition.png", part)


def _config(folder, method, count=N, min_distance=MIN_DISTANCE, name=None, edit=lambda s: s):
    if not (folder / "ramp.png").exists():
        _maps(folder)
    text = edit(SCENE.format(method=method, count=count, min_distance=min_distance))
    return load_config(write_scene(folder, text, name or f"{method}.toml"))


@pytest.mark.parametrize("method", METHODS)
def test_every_tree_obeys_every_rule(tmp_path, method):
    inst, rep = scatter(_config(tmp_path, method))
    assert len(inst) > 500
    x, y, z = inst.position.T
    sp = inst.species
    # Presence: nothing where the map is black; partitions: broadleaf only in the south
    # (the regions as painted, not as the partition column says).
    assert z.max() <= 30.0
    assert (z[sp == 0] <= 0.0).all() and (z[sp != 0] > 0.0).any()
    # Slope windows (the crease at x = 0 blends normals over one grid cell, 1.6 m).
    assert (x[sp == 0] < 1.6).all() and (x[sp == 1] > -1.6).all()
    # Altitude window.
    assert (y[sp == 2] >= 0.0).all() and (y[sp == 2] <= 20.0).all() and (y[sp == 2] > 10.0).any()
    # min_distance: no pair of trees closer, whatever their species.
    d, _ = cKDTree(inst.position).query(inst.position, k=2)
    assert d[:, 1].min() >= MIN_DISTANCE
    # Each rule rejected something, and every candidate is accounted for once.
    for stage in ("presence", "density", "empty ground", "partition", "slope", "altitude", "min_distance"):
        assert rep.rejected[stage] > 0, stage
    assert rep.kept + sum(rep.rejected.values()) == rep.candidates == N
    for stage in ("partition", "slope", "altitude", "min_distance"):
        assert sum(d[stage] for d in rep.rejected_by_species.values()) == rep.rejected[stage]
    assert rep.rejected_by_species["broadleaf"]["partition"] == rep.rejected["partition"]


def test_both_methods_share_the_candidate_stages(tmp_path):
    _, r_random = scatter(_config(tmp_path, "random"))
    _, r_eco = scatter(_config(tmp_path, "ecosystem"))
    shared = ("presence", "density", "empty ground", "partition", "slope", "altitude")
    assert {s: r_random.rejected[s] for s in shared} == {s: r_eco.rejected[s] for s in shared}
    # Presence removes the 20 % of the surface where z > 30 (the ramp runs along x).
    assert r_random.rejected["presence"] == pytest.approx(0.2 * N, abs=5 * np.sqrt(0.16 * N))
    assert r_eco.rejected["competition"] > 0 and set(r_eco.rejected) >= {"site", "competition", "min_distance"}


def _window_ok(inst, config_species):
    """Which trees satisfy their species' partition, slope and altitude rules, from the painted maps."""
    x, y, z = inst.position.T
    # Smooth normals blend the slope over the grid cells either side of the crease (|x| < 2.4 m).
    slope = np.where(x > 2.4, 45.0, np.where(x < -2.4, 0.0, np.nan))
    ok = np.ones(len(inst), dtype=bool)
    for k, sp in enumerate(config_species):
        m = inst.species == k
        if sp.partitions is not None:
            ok[m] &= z[m] < 0 if sp.partitions == ("south",) else z[m] > 0
        ok[m] &= ~(slope[m] < sp.slope_min) & ~(slope[m] > sp.slope_max)
        if sp.altitude is not None:
            ok[m] &= (y[m] >= sp.altitude[0]) & (y[m] <= sp.altitude[1])
    crease = np.abs(x) <= 2.4
    return ok, crease


def test_the_rules_reject_exactly_the_trees_that_break_them(tmp_path):
    """Random method: removing the partition, slope and altitude rules adds back only trees that break them."""
    cfg = _config(tmp_path, "random", min_distance=0.0)
    with_rules, _ = scatter(cfg)
    rules = ('partitions = ["south"]', "slope_max = 30.0", "slope_min = 40.0", "altitude = [0.0, 20.0]")

    def drop_rules(text: str) -> str:
        for r in rules:
            text = text.replace(r, "")
        return text

    free = _config(tmp_path, "random", min_distance=0.0, name="free.toml", edit=drop_rules)
    without, _ = scatter(free)
    assert set(with_rules.id.tolist()) <= set(without.id.tolist())
    ok, crease = _window_ok(without, cfg.species)
    kept = np.isin(without.id, with_rules.id)
    away = ~crease
    np.testing.assert_array_equal(kept[away], ok[away])
    assert (~ok[away]).sum() > 1000


@pytest.mark.parametrize("method", METHODS)
def test_same_config_same_bytes(tmp_path, method):
    a, _ = scatter(_config(tmp_path, method, count=6000))
    b, _ = scatter(_config(tmp_path, method, count=6000, name="again.toml"))
    a.meta["source"] = b.meta["source"]  # the config's file name is recorded
    assert a.save(tmp_path / "a.npz").read_bytes() == b.save(tmp_path / "b.npz").read_bytes()
    c, _ = scatter(
        _config(tmp_path, method, count=6000, name="seed.toml", edit=lambda s: s.replace("seed = 11", "seed = 12"))
    )
    assert len(a) != len(c) or not np.array_equal(a.position, c.position)


def test_ecosystem_spacing_keeps_the_stronger_plant_and_is_maximal(tmp_path):
    """min_distance thins the ecosystem's survivors by dart throwing, strongest (r·vigour) first."""
    free, r_free = scatter(_config(tmp_path, "ecosystem", min_distance=0.0))
    spaced, rep = scatter(_config(tmp_path, "ecosystem", name="spaced.toml"))
    assert set(spaced.id.tolist()) <= set(free.id.tolist())
    dropped = ~np.isin(free.id, spaced.id)
    assert dropped.sum() == rep.rejected["min_distance"] > 0
    # Every dropped plant has a kept plant within min_distance that is at least as strong (vigour is 1).
    kept = ~dropped
    strength = r_free.columns["radius"]
    tree = cKDTree(free.position[kept])
    for i in np.flatnonzero(dropped):
        near = tree.query_ball_point(free.position[i], MIN_DISTANCE)
        assert near and strength[kept][near].max() >= strength[i]
