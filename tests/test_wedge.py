"""``forest wedge``: one render per value of a config field, named by the value, every value checked first."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest
from conftest import TINY_SCENE, run

from forest.commands.wedge import split_wedge, wedge_output
from forest.errors import ParameterError

SCENE = TINY_SCENE


def read(path: Path) -> tuple[np.ndarray, dict]:
    inp = oiio.ImageInput.open(str(path))
    spec = inp.spec()
    data = np.asarray(inp.read_image(0, 0, 0, spec.nchannels, "float"))
    attrs = {a.name: a.value for a in spec.extra_attribs}
    inp.close()
    return data, attrs


@pytest.fixture
def scene(tmp_path):
    (tmp_path / "scene.toml").write_text(SCENE)
    return tmp_path / "scene.toml"


def test_values_are_a_toml_list_or_bare_words():
    assert split_wedge("render.exposure=-1,0,1.5") == ("render.exposure", [("-1", -1), ("0", 0), ("1.5", 1.5)])
    assert split_wedge("render.view=agx,standard")[1] == [("agx", "agx"), ("standard", "standard")]
    assert split_wedge('render.view="agx", "filmic"')[1] == [("agx", "agx"), ("filmic", "filmic")]
    assert split_wedge("camera.position=[0,10,0],[0,20,0]")[1] == [
        ("[0, 10, 0]", [0, 10, 0]),
        ("[0, 20, 0]", [0, 20, 0]),
    ]
    for bad in ("render.exposure", "render.exposure=", "=1,2", "render..x=1"):
        with pytest.raises(ParameterError) as e:
            split_wedge(bad)
        assert e.value.field.startswith("--wedge")


@pytest.mark.parametrize(
    "output, key, value, name",
    [
        ("out/w.exr", "render.exposure", -1, "w_exposure_-1.exr"),
        ("out/w.png", "render.exposure", 0.5, "w_exposure_0p5.png"),
        ("out/w.exr", "render.view", "agx", "w_view_agx.exr"),
        ("out/w.exr", "camera.position", [0, 10.5, 0], "w_position_0_10p5_0.exr"),
        ("out/w.exr", "species[0].percent", 40, "w_percent_40.exr"),
        ("out/w.####.exr", "render.exposure", 1, "w_exposure_1.####.exr"),
        ("out/w_%04d.exr", "render.spp", 4, "w_spp_4_%04d.exr"),
    ],
)
def test_each_value_gets_a_file_name_of_its_own(output, key, value, name):
    assert wedge_output(Path(output), key, value) == Path("out") / name


def test_a_wedge_writes_one_render_per_value(scene, tmp_path, capsys):
    out = tmp_path / "out"
    assert run(["wedge", scene, "--wedge", "render.exposure=-1,1", "-o", out / "w.exr", "--set", "render.spp=2"]) == 0
    assert sorted(p.name for p in out.iterdir()) == sorted(
        f"w_exposure_{v}.{e}" for v in ("-1", "1") for e in ("exr", "png")
    )
    (lo, lo_attrs), (hi, hi_attrs) = read(out / "w_exposure_-1.exr"), read(out / "w_exposure_1.exr")
    assert (lo_attrs["forest:exposure"], hi_attrs["forest:exposure"]) == (-1.0, 1.0)
    assert lo_attrs["forest:spp"] == hi_attrs["forest:spp"] == 2  # --set applies to every value
    assert np.array_equal(lo, hi)  # exposure is a display setting: the linear EXR is the same
    lo_png, hi_png = read(out / "w_exposure_-1.png")[0], read(out / "w_exposure_1.png")[0]
    assert hi_png.mean() > lo_png.mean()  # two stops brighter on screen
    summary = capsys.readouterr().out
    assert "wedge render.exposure: 2 renders" in summary
    assert str(out / "w_exposure_-1.exr") in summary and str(out / "w_exposure_1.exr") in summary


def test_a_wedge_over_a_scene_field_renders_different_images(scene, tmp_path):
    out = tmp_path / "out"
    args = ["wedge", scene, "--wedge", "lights.sun.irradiance=1,4", "-o", out / "s.####.exr", "--frames", "2", "-q"]
    assert run(args) == 0
    dim, bright = read(out / "s_irradiance_1.0002.exr")[0], read(out / "s_irradiance_4.0002.exr")[0]
    assert bright[..., :3].mean() > dim[..., :3].mean()


@pytest.mark.parametrize(
    "wedge, extra, words",
    [
        ("render.exposure=0,40", [], "--wedge render.exposure=40: "),
        ("render.sppp=1,2", [], "--wedge render.sppp=1: unknown key"),
        ("render.spp=1,2", ["--spp", "3"], "--wedge render.spp: is also given by --spp"),
        ("render.exposure=1,1.0", [], "--wedge render.exposure: values 1 and 2"),
        ("render.exposure=-1,1", ["--set", "render.bogus=1"], "--set render.bogus: unknown key"),
        ("render.exposure=-1,1", ["--frames", "1-2", "-o", "{d}/w.%s.exr"], "-o: "),
    ],
)
def test_every_value_is_checked_before_the_first_render(scene, tmp_path, capsys, wedge, extra, words):
    extra = [a.format(d=tmp_path) for a in extra]
    out = ["-o", tmp_path / "w.exr"] if "-o" not in extra else []
    assert run(["wedge", scene, "--wedge", wedge, *out, *extra]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"forest: error: {words}"), err
    assert len(err.strip().splitlines()) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.toml"]
