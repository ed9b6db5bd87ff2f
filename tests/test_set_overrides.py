"""``--set key.path=value`` on every command that reads a scene config: TOML values, its effect, its refusals."""

from __future__ import annotations

import numpy as np
import OpenImageIO as oiio
import pytest
from conftest import TINY_SCENE, run, write_png

from forest.commands import parse_sets
from forest.errors import ParameterError

SCENE = TINY_SCENE


@pytest.fixture
def scene(tmp_path):
    (tmp_path / "scene.toml").write_text(SCENE)
    return tmp_path / "scene.toml"


def test_values_are_read_as_toml_and_bare_words_as_strings():
    got = parse_sets(
        [
            "render.spp=16",
            "render.exposure=-0.5",
            "camera.position=[0,10,0]",
            'lookdev.mode="statistics"',
            "render.view=agx",
            "render.denoise=true",
            "species[0].percent = 40",
            "render.spp=8",  # a later setting wins
        ]
    )
    assert got == {
        "render.spp": 8,
        "render.exposure": -0.5,
        "camera.position": [0, 10, 0],
        "lookdev.mode": "statistics",
        "render.view": "agx",
        "render.denoise": True,
        "species[0].percent": 40,
    }


@pytest.mark.parametrize(
    "item, field, words",
    [
        ("render.spp", "--set", "KEY.PATH=VALUE"),
        ("=4", "--set", "KEY.PATH=VALUE"),
        ("render..spp=4", "--set render..spp", "not a config key"),
        ("camera.position=[0,10", "--set camera.position", "cannot read"),
        ('name="unclosed', "--set name", "cannot read"),
        ("render.spp=1\nseed = 4", "--set render.spp", "one TOML value"),
    ],
)
def test_malformed_items_are_refused_naming_the_flag(item, field, words):
    with pytest.raises(ParameterError) as e:
        parse_sets([item])
    assert e.value.field == field and words in e.value.message


def read_exr(path):
    inp = oiio.ImageInput.open(str(path))
    spec = inp.spec()
    attrs = {a.name: a.value for a in spec.extra_attribs}
    inp.close()
    return spec, attrs


def test_render_set_changes_what_it_names(scene, tmp_path):
    out = tmp_path / "out" / "a.exr"
    sets = ["render.width=24", "render.height=16", "render.spp=2", "camera.position=[0, 40, -50]"]
    assert run(["render", scene, "-o", out, "-q", *(x for s in sets for x in ("--set", s))]) == 0
    spec, attrs = read_exr(out)
    assert (spec.width, spec.height) == (24, 16)
    assert attrs["forest:spp"] == 2
    assert [float(x) for x in attrs["forest:camera_position"].split(",")] == [0.0, 40.0, -50.0]
    # the command's own flag wins over --set of the same field
    assert run(["render", scene, "-o", tmp_path / "b.exr", "-q", "--set", "render.width=24", "--width", "20"]) == 0
    assert read_exr(tmp_path / "b.exr")[0].width == 20


def test_scatter_set_is_the_same_as_editing_the_file(scene, tmp_path):
    assert run(["scatter", scene, "-o", tmp_path / "set.npz", "-q", "--set", "seed=5", "--set", "scatter.count=9"]) == 0
    edited = tmp_path / "edited.toml"
    edited.write_text(SCENE.replace("seed = 11", "seed = 5").replace("count = 12", "count = 9"))
    assert run(["scatter", edited, "-o", tmp_path / "edited.npz", "-q"]) == 0
    assert run(["scatter", scene, "-o", tmp_path / "plain.npz", "-q"]) == 0
    a, b, c = (np.load(tmp_path / f"{n}.npz") for n in ("set", "edited", "plain"))
    assert np.array_equal(a["position"], b["position"])
    assert not np.array_equal(a["position"], c["position"])


def test_export_set_changes_the_exported_trees(scene, tmp_path):
    assert run(["export", "points", scene, "-o", tmp_path / "a.csv", "-q"]) == 0
    assert run(["export", "points", scene, "-o", tmp_path / "b.csv", "-q", "--set", "seed=5"]) == 0
    assert (tmp_path / "a.csv").read_text() != (tmp_path / "b.csv").read_text()


@pytest.mark.parametrize(
    "command, item, words",
    [
        (["render", "{s}", "-o", "{d}/x.exr"], "render.sppp=4", "--set render.sppp: unknown key (expected one of:"),
        (["render", "{s}", "-o", "{d}/x.exr"], "render.spp=abc", "--set render.spp: must be a whole number, got 'abc'"),
        (["render", "{s}", "-o", "{d}/x.exr"], "render.exposure=40", "--set render.exposure: "),
        (["render", "{s}", "-o", "{d}/x.exr"], "species[4].percent=10", "--set species[4].percent: species has no"),
        (["render", "{s}", "-o", "{d}/x.exr"], "nothing.here=1", "--set nothing.here: unknown key"),
        (  # a field inside the table the flag sets is named too
            ["render", "{s}", "-o", "{d}/x.exr"],
            "render.valley_fog={density=0.01, variation=-2.0}",
            "--set render.valley_fog: variation: must be >= 0, got -2",
        ),
        (["render", "{s}", "-o", "{d}/x.exr"], "render.haze_shafts=maybe", "--set render.haze_shafts: must be true"),
        (["scatter", "{s}", "-o", "{d}/x.npz"], "scatter.count=-3", "--set scatter.count: "),
        (["export", "usd", "{s}", "-o", "{d}/x.usda"], "camera.fov=[1]", "--set camera.fov: "),
        (["export", "points", "{s}", "-o", "{d}/x.csv"], "terrain.colour=1", "--set terrain.colour: unknown key"),
        (["match", "{s}", "-r", "{d}/ref.png", "-o", "{d}/fit"], "lookdev.mode=sideways", "--set lookdev.mode: "),
    ],
)
def test_bad_keys_and_values_are_refused_in_one_line_before_any_work(scene, tmp_path, capsys, command, item, words):
    write_png(tmp_path / "ref.png", np.full((9, 16, 3), 0.5))
    before = sorted(tmp_path.iterdir())
    argv = [a.format(s=scene, d=tmp_path) for a in command]
    assert run([*argv, "--set", item]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"forest: error: {words}"), err
    assert len(err.strip().splitlines()) == 1
    assert sorted(tmp_path.iterdir()) == before
