"""A saved InstanceSet records the files it was scattered from, and is refused for a config whose files differ."""

from __future__ import annotations

import hashlib
import shutil

import numpy as np
import pytest
from conftest import run_forest, write_png, write_scene

from forest.config import load_config
from forest.errors import ConfigError, ForestWarning
from forest.instances import InstanceSet
from forest.scatter import scatter, scene_instances

SCENE = """
seed = 4
[terrain]
heightmap = "maps/height.png"
size = [60.0, 60.0]
height = 10.0
[maps]
presence = "maps/presence.png"
colour = "maps/colour.png"
{extra_maps}
[scatter]
count = 400
[[species]]
model = "broadleaf"
percent = 100
[camera]
position = [0.0, 30.0, -60.0]
target = [0.0, 0.0, 0.0]
[render]
width = 16
height = 12
spp = 1
"""


@pytest.fixture
def scene(tmp_path):
    """A config with a heightmap, a presence and a colour map, scattered to trees.npz."""
    maps = tmp_path / "maps"
    yy, xx = np.mgrid[0:16, 0:16] / 15.0
    write_png(maps / "height.png", xx * yy, bits=16)
    write_png(maps / "presence.png", (xx > 0.2).astype(float))
    write_png(maps / "colour.png", np.stack([xx, yy, 0.5 * np.ones_like(xx)], axis=2))
    write_png(maps / "density.png", 0.5 + 0.5 * xx)
    cfg = write_scene(tmp_path, SCENE.format(extra_maps=""))
    r = run_forest("scatter", cfg, "-o", tmp_path / "trees.npz", "-q")
    assert r.returncode == 0, r.stderr
    return cfg


def _sha256(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_the_set_records_the_hash_of_every_input_file(scene):
    inst = InstanceSet.load(scene.parent / "trees.npz")
    maps = scene.parent / "maps"
    assert inst.meta["inputs"] == {
        "terrain.heightmap": {"file": "maps/height.png", "sha256": _sha256(maps / "height.png")},
        "maps.presence": {"file": "maps/presence.png", "sha256": _sha256(maps / "presence.png")},
        "maps.colour": {"file": "maps/colour.png", "sha256": _sha256(maps / "colour.png")},
    }
    assert inst.species_names == ["broadleaf"]
    # The unchanged scene loads the set as saved.
    loaded = scene_instances(load_config(scene), scene.parent / "trees.npz")
    np.testing.assert_array_equal(loaded.position, inst.position)


def test_render_refuses_a_set_whose_presence_map_changed(scene):
    write_png(scene.parent / "maps" / "presence.png", np.ones((4, 4)))
    out = scene.parent / "out" / "frame.exr"
    r = run_forest("render", scene, "--instances", scene.parent / "trees.npz", "-o", out)
    assert r.returncode == 2
    err = r.stderr.strip().splitlines()
    assert len(err) == 1, r.stderr
    assert err[0].startswith("forest: error: ") and err[0].endswith(
        "scene.toml: maps.presence: maps/presence.png changed since "
        f"{scene.parent / 'trees.npz'} was scattered; scatter again"
    )
    assert not out.parent.exists()


def test_a_repainted_colour_map_retints_a_saved_set(scene):
    """The colour map only tints: a saved set is accepted and its trees take the new map's colours."""
    from forest.images import srgb_to_linear
    from forest.scene import load_scene

    repainted = np.full((16, 16, 3), 0.3)
    repainted[:, 8:] = 0.6  # darker west half, lighter east half
    write_png(scene.parent / "maps" / "colour.png", repainted)
    cfg = load_config(scene).with_overrides({"species[0].colour_jitter": {"hue": 0.0, "value": 0.0}})
    sc = load_scene(cfg, scene.parent / "trees.npz")
    west, east = srgb_to_linear(np.array([round(0.3 * 255) / 255, round(0.6 * 255) / 255]))
    mean = 0.5 * (west + east)  # the tint has mean 1 over the terrain
    x = sc.instances.position[:, 0]
    np.testing.assert_allclose(sc.instances.tint[x < -5], west / mean, rtol=1e-5)
    np.testing.assert_allclose(sc.instances.tint[x > 5], east / mean, rtol=1e-5)


def test_a_moved_or_rewritten_map_with_the_same_content_is_accepted(scene):
    maps = scene.parent / "maps"
    shutil.copy(maps / "presence.png", scene.parent / "mask.png")
    (maps / "colour.png").write_bytes((maps / "colour.png").read_bytes())
    moved = write_scene(scene.parent, scene.read_text().replace("maps/presence.png", "mask.png"), "moved.toml")
    assert len(scene_instances(load_config(moved), scene.parent / "trees.npz")) > 0


def _replace(old: str, new: str):
    return lambda config, folder: config.write_text(config.read_text().replace(old, new))


@pytest.mark.parametrize(
    "edit, field, message",
    [
        (lambda c, d: None, None, None),
        (lambda c, d: write_png(d / "maps" / "presence.png", np.ones((4, 4))), "maps.presence", "changed since"),
        (lambda c, d: write_png(d / "maps" / "height.png", np.zeros((4, 4))), "terrain.heightmap", "changed since"),
        (
            _replace('colour = "maps/colour.png"', 'colour = "maps/colour.png"\ndensity = "maps/density.png"'),
            "maps.density",
            "maps/density.png was not used when",
        ),
        (
            _replace('presence = "maps/presence.png"', ""),
            "maps.presence",
            "was scattered with maps/presence.png, which this config does not use",
        ),
        (
            _replace('model = "broadleaf"', 'model = "conifer"'),
            "species",
            "models ['conifer'] differ from ['broadleaf']",
        ),
    ],
    ids=["unchanged", "presence changed", "heightmap changed", "map added", "map dropped", "species changed"],
)
def test_each_changed_input_is_named(scene, edit, field, message):
    edit(scene, scene.parent)
    config = load_config(scene)
    path = scene.parent / "trees.npz"
    if field is None:
        assert len(scene_instances(config, path)) > 0
        return
    with pytest.raises(ConfigError) as e:
        scene_instances(config, path)
    assert e.value.field == field and message in e.value.message and e.value.message.endswith("; scatter again")
    assert "\n" not in str(e.value)


def test_an_older_set_without_hashes_loads_with_one_warning_line(scene, tmp_path):
    inst = InstanceSet.load(tmp_path / "trees.npz")
    del inst.meta["inputs"]
    old = inst.save(tmp_path / "old.npz")
    with pytest.warns(ForestWarning, match="old.npz records no input hashes"):
        loaded = scene_instances(load_config(scene), old)
    np.testing.assert_array_equal(loaded.id, inst.id)
    # On the command line: one line on stderr, and the command goes on.
    write_png(tmp_path / "maps" / "colour.png", np.full((16, 16, 3), 0.3))  # not checked in an older file
    r = run_forest("render", scene, "--instances", old, "-o", tmp_path / "old.exr", "-q")
    assert r.returncode == 0, r.stderr
    assert r.stderr.strip().splitlines() == [
        f"forest: warning: {old} records no input hashes (written by an older forest): its maps are not "
        "checked against scene.toml; scatter again to record them"
    ]
    assert (tmp_path / "old.exr").stat().st_size > 0


def test_scatter_of_the_same_files_records_the_same_hashes(scene):
    a, _ = scatter(load_config(scene))
    assert a.meta["inputs"] == InstanceSet.load(scene.parent / "trees.npz").meta["inputs"]
