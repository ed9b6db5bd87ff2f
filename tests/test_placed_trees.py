"""Trees placed by hand (``[[tree]]``): where and what they are, the scattered trees they clear, seeds, files."""

from __future__ import annotations

import numpy as np
import OpenImageIO as oiio
import pytest
from conftest import run_forest

from forest.config import load_config
from forest.errors import ConfigError
from forest.library import open_library
from forest.scatter import scatter, scene_instances
from forest.scatter.placed import crown_radius
from forest.terrain import load_terrain

SPECIES = """
[[species]]
model = "broadleaf"
percent = 60
[[species]]
model = "conifer"
name = "spruce"
percent = 30
individuals = 3
"""
HILL = "procedural = { size = 120.0, height = 14.0, octaves = 4, resolution = 64 }"
TREES = """
[[tree]]
species = "broadleaf"
position = [10.0, 20.0]
scale = 1.5
[[tree]]
species = "spruce"
position = [-30.0, -5.0]
yaw = 90.0
individual = 2
clear = 6.0
"""


@pytest.fixture
def make(tmp_path):
    """config(extra) → a loaded config of a hilly 120 m terrain with two species (and ``extra`` appended)."""

    def config(extra: str = "", name: str = "scene.toml"):
        path = tmp_path / name
        path.write_text(f"seed = 5\n[terrain]\n{HILL}\n[scatter]\ncount = 3000\nmin_distance = 1.5\n{SPECIES}{extra}")
        return load_config(path)

    return config


def test_placed_trees_stand_where_and_as_they_are_told(make):
    cfg = make(TREES)
    inst, report = scatter(cfg)
    terrain = load_terrain(cfg.terrain, cfg.path)
    a, b = inst.position[-2:], inst.species[-2:]
    np.testing.assert_allclose(a[:, [0, 2]], [[10.0, 20.0], [-30.0, -5.0]])
    np.testing.assert_allclose(a[:, 1], terrain.height_at(a[:, 0], a[:, 2]), atol=1e-4)
    assert b.tolist() == [0, 1]  # broadleaf by its model, spruce by its name
    assert inst.scale[-2:].tolist() == [1.5, 1.0]
    assert np.degrees(inst.yaw[-1]) == pytest.approx(90.0) and inst.individual[-1] == 2
    assert 0 <= inst.individual[-2] < 4  # drawn among the species' individuals
    # Ids after every scattered row's; rows still sorted by id; the report counts them apart.
    assert (np.diff(inst.id.astype(np.int64)) > 0).all() and inst.id[-2] >= cfg.scatter.count
    assert report.placed == 2 and report.kept == len(inst) - 2
    assert any("placed by hand: 2" in line for line in report.lines())
    # The terrain's normal, by the slope under the trunk (the procedural hill is not flat there).
    n = inst.normal[-2:]
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-5)
    assert (n[:, 1] < 0.9999).all()


def test_scattered_trees_around_a_placed_one_are_left_out_and_no_others(make):
    """Against the same scatter without ``[[tree]]``: exactly the trees within each ``clear`` radius are gone
    (by default the crown's radius times the scale), every other row is the same, and the report counts them."""
    plain, _ = scatter(make())
    placed, report = scatter(make(TREES))
    radius = 1.5 * crown_radius(open_library().resolve("broadleaf"))
    assert 3.0 < radius < 20.0  # a broadleaf's crown, metres
    xz = plain.position[:, [0, 2]].astype(np.float64)
    near = (np.hypot(*(xz - [10.0, 20.0]).T) <= radius) | (np.hypot(*(xz - [-30.0, -5.0]).T) <= 6.0)
    assert 5 <= near.sum() < len(plain) // 10
    ids = placed.id[:-2]
    np.testing.assert_array_equal(ids, plain.id[~near])
    for col in ("position", "scale", "yaw", "tint", "individual", "species"):
        np.testing.assert_array_equal(getattr(placed, col)[:-2], getattr(plain, col)[~near], err_msg=col)
    assert report.rejected["placed tree"] == near.sum()
    assert sum(d.get("placed tree", 0) for d in report.rejected_by_species.values()) == near.sum()
    assert report.kept + sum(report.rejected.values()) == report.candidates


def test_clear_zero_keeps_every_scattered_tree(make):
    plain, _ = scatter(make())
    inst, report = scatter(make('[[tree]]\nspecies = "broadleaf"\nposition = [0.0, 0.0]\nclear = 0.0\n'))
    np.testing.assert_array_equal(inst.id[:-1], plain.id)
    assert report.rejected["placed tree"] == 0


def test_drawn_yaw_and_individual_belong_to_the_tree_not_to_the_list(make):
    """Defaults are drawn from (seed, the tree's place): a tree added after it changes nothing of it, the same
    config gives the same file byte for byte, another seed draws anew."""
    one = '[[tree]]\nspecies = "broadleaf"\nposition = [0.0, 0.0]\nclear = 0.0\n'
    two = one + '[[tree]]\nspecies = "broadleaf"\nposition = [40.0, 40.0]\nclear = 0.0\n'
    a, _ = scatter(make(one))
    b, _ = scatter(make(two))
    assert a.yaw[-1] == b.yaw[-2] and a.individual[-1] == b.individual[-2] and a.phase[-1] == b.phase[-2]
    assert a.yaw[-1] != b.yaw[-1]
    first = a.save(make(one).path.parent / "a.npz").read_bytes()
    assert scatter(make(one))[0].save(make(one).path.parent / "b.npz").read_bytes() == first
    other = scatter(make(one).with_overrides({"seed": 6}))[0]
    assert other.yaw[-1] != a.yaw[-1]


def test_an_instance_file_is_refused_for_other_placed_trees(make, tmp_path):
    saved = scatter(make())[0].save(tmp_path / "trees.npz")
    with pytest.raises(ConfigError) as e:
        scene_instances(make(TREES, name="placed.toml"), saved)
    assert e.value.field == "tree" and "scatter again" in e.value.message
    again = scatter(make(TREES))[0].save(tmp_path / "placed.npz")
    assert len(scene_instances(make(TREES), again)) == len(scatter(make(TREES))[0])


@pytest.mark.parametrize(
    "tree, field, words",
    [
        ('species = "spruce"\nposition = [0.0, 0.0]\nindividual = 3', "tree[0].individual", "3 individuals"),
        ('species = "conifer"\nposition = [0.0, 0.0]\nscale = 0.0', "tree[0].scale", "> 0"),
        ('species = "broadleaf"\nposition = [0.0, 0.0]\nyaw = 400.0', "tree[0].yaw", "<= 360"),
        ('species = "broadleaf"\nposition = [0.0, 0.0]\nheight = 3.0', "tree[0].height", "unknown key"),
    ],
)
def test_a_bad_placed_tree_names_its_field(make, tree, field, words):
    with pytest.raises(ConfigError) as e:
        make(f"[[tree]]\n{tree}\n")
    assert e.value.field == field and words in e.value.message, e.value


def test_a_placed_tree_is_rendered(tmp_path):
    """End to end through the CLI: a meadow with no scattered trees, one placed in front of the camera; the
    frame's centre is the tree's (darker and greener than the sky and grass around it without it)."""
    base = """seed = 1
[terrain]
flat = { size = 100.0 }
[[species]]
model = "broadleaf"
percent = 0
[camera]
position = [0.0, 6.0, -25.0]
target = [0.0, 6.0, 0.0]
fov = 40.0
[render]
width = 48
height = 32
spp = 2
denoise = false
"""
    tree = '[[tree]]\nspecies = "broadleaf"\nposition = [0.0, 0.0]\nyaw = 0.0\n'
    images = {}
    for name, text in (("bare", base), ("tree", base + tree)):
        cfg = tmp_path / f"{name}.toml"
        cfg.write_text(text)
        r = run_forest("render", cfg, "-o", tmp_path / f"{name}.exr", "-q")
        assert r.returncode == 0, r.stderr
        images[name] = oiio.ImageBuf(str(tmp_path / f"{name}.exr")).get_pixels(oiio.FLOAT)[..., :3]
    centre = (slice(8, 24), slice(16, 32))
    bare, tree_img = images["bare"][centre].mean(axis=(0, 1)), images["tree"][centre].mean(axis=(0, 1))
    assert tree_img.sum() < 0.7 * bare.sum()  # the crown hides the bright sky
    assert tree_img[1] > tree_img[2]  # green leaves, not blue sky
    edge = (slice(0, 32), slice(0, 4))
    np.testing.assert_allclose(images["tree"][edge], images["bare"][edge], atol=0.05)


def test_cleared_is_every_tree_within_its_placed_trees_radius():
    """The grid-cell prefilter drops none: against brute force, radii of mixed sizes, coordinates of both signs."""
    from forest.config.schema import PlacedTree
    from forest.scatter.placed import cleared

    rng = np.random.default_rng(3)
    position = np.zeros((20000, 3))
    position[:, [0, 2]] = rng.uniform(-500.0, 500.0, (20000, 2))
    trees = [PlacedTree(species="a", position=tuple(p)) for p in rng.uniform(-520.0, 520.0, (40, 2))]
    radii = rng.choice([0.0, 3.0, 11.0, 60.0], 40)
    d = np.hypot(*(position[:, None, [0, 2]] - np.array([t.position for t in trees])[None]).transpose(2, 0, 1))
    np.testing.assert_array_equal(cleared(position, trees, radii), (d <= np.where(radii > 0, radii, -1.0)).any(axis=1))


def test_a_placed_tree_is_exported(tmp_path):
    """USD, from the same InstanceSet: a scene whose only tree is placed by hand exports one instance, there."""
    from pxr import Usd, UsdGeom

    cfg = tmp_path / "one.toml"
    cfg.write_text(
        "seed = 2\n[terrain]\nprocedural = { size = 100.0, height = 8.0, octaves = 3, resolution = 32 }\n"
        '[[species]]\nmodel = "broadleaf"\npercent = 0\n'
        '[[tree]]\nspecies = "broadleaf"\nposition = [12.5, -7.0]\nscale = 1.3\n'
    )
    out = tmp_path / "one.usda"
    r = run_forest("export", "usd", cfg, "-o", out)
    assert r.returncode == 0, r.stderr
    stage = Usd.Stage.Open(str(out))
    points = [
        np.array(UsdGeom.PointInstancer(p).GetPositionsAttr().Get())
        for p in stage.Traverse()
        if p.IsA(UsdGeom.PointInstancer)
    ]
    (pos,) = np.concatenate(points)
    cfg_loaded = load_config(cfg)
    ground = load_terrain(cfg_loaded.terrain, cfg_loaded.path).height_at([12.5], [-7.0])[0]
    np.testing.assert_allclose(pos, [12.5, ground, -7.0], atol=1e-3)


def test_a_placed_tree_can_stand_dead(make):
    """``dead = true``: a snag, individual n + k of its species, whose individuals then include the snags (the
    tree without its leaves) though the species itself draws none; a living placed tree stays below n."""
    from forest.scatter.canopy import has_leaves
    from forest.scene import load_scene

    cfg = make(
        '[[tree]]\nspecies = "spruce"\nposition = [0.0, 0.0]\nindividual = 1\ndead = true\nclear = 0.0\n'
        '[[tree]]\nspecies = "spruce"\nposition = [30.0, 0.0]\nindividual = 1\nclear = 0.0\n'
    )
    inst, _ = scatter(cfg)
    assert inst.individual[-2:].tolist() == [3 + 1, 1]  # the spruce has 3 individuals
    scene = load_scene(cfg, inst)
    spruce = scene.individuals[1]
    assert len(spruce) == 6 and not has_leaves(spruce[4]) and has_leaves(spruce[1])
    assert len(scene.individuals[0]) == 4  # the broadleaf, with no dead tree, has no snags
    with pytest.raises(ConfigError) as e:
        make('[[tree]]\nspecies = "broadleaf"\nposition = [0.0, 0.0]\ndead = true\n').with_overrides(
            {"species[0].individuals": 200}
        )
    assert e.value.field == "tree[0].dead"
