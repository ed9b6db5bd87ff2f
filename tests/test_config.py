"""The scene schema: one declaration gives validation, messages by field, JSON Schema, file fields, overrides."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import jsonschema
import pytest
from conftest import run_forest, write_png

from forest.config import apply_overrides, file_fields, load_config, parse_config, referenced_files
from forest.config.schema import SceneConfig
from forest.errors import ConfigError, ParameterError

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = sorted((ROOT / "configs").glob("*.toml"))
MINIMAL = '[terrain]\nflat = {}\n[[species]]\nmodel = "broadleaf"\npercent = 50\n'


def schema() -> dict:
    return SceneConfig.model_json_schema()


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.stem)
def test_every_example_loads_and_satisfies_the_json_schema(path):
    cfg = load_config(path)  # validates, files included
    assert cfg.species and cfg.terrain.kind in ("heightmap", "mesh", "procedural", "flat")
    jsonschema.validate(tomllib.loads(path.read_text()), schema())


def test_json_schema_refuses_what_the_loader_refuses():
    """An editor checking against `forest schema` flags the mistakes forest itself refuses."""
    bad = [
        MINIMAL + "[render]\nwidth = '64'\n",  # a string where a whole number goes
        MINIMAL + "[render]\nspp = 0\n",
        MINIMAL + "[scatter]\ncuont = 5\n",  # unknown key
        MINIMAL + "[lights]\nsky = { sunsky = { turbidity = 20.0 } }\n",
        MINIMAL + "[partitions]\nred = 'fg'\n",
    ]
    for text in bad:
        with pytest.raises(jsonschema.ValidationError):
            jsonschema.validate(tomllib.loads(text), schema())
        with pytest.raises(ConfigError):
            parse_config(text)


def test_the_schema_command_prints_json_schema(tmp_path):
    r = run_forest("schema")
    assert r.returncode == 0, r.stderr
    printed = json.loads(r.stdout)
    assert printed["title"] == "forest scene" and "terrain" in printed["required"]
    out = tmp_path / "forest.schema.json"
    assert run_forest("schema", "-o", out).returncode == 0
    assert json.loads(out.read_text()) == printed


def test_messages_name_file_dotted_field_and_value():
    cases = {
        "[render]\nwidth = '64'\n": ("render.width", "must be a whole number, got '64'"),
        "[render]\nspp = 0\n": ("render.spp", "must be >= 1, got 0"),
        "[camera]\nup = [0.0, 0.0, 0.0]\n": ("camera.up", "must not be the zero vector"),
        "[camera]\nposition = [0.0, 1.0, 0.0]\ntarget = [0.0, 5.0, 0.0]\n": ("camera.up", "parallel"),
        "[render]\nhaze_colour = [1.0, -1.0, 0.0]\n": ("render.haze_colour", "values must be >= 0, got [1, -1, 0]"),
        "[render]\nhaze_colour = [1.0, 1.0]\n": ("render.haze_colour", "too few values"),
        "[scatter]\nmethod = 'grid'\n": ("scatter.method", "'random' or 'ecosystem'"),
        "[lights]\nsky = { envmap = 'nope.exr' }\n": ("lights.sky.envmap", "file not found: nope.exr"),
        "[lights]\nsky = { sunsky = {}, radiance = 2.0 }\n": ("lights.sky.radiance", "constant sky only"),
        "[ecosystem]\nseed = 3\n": ("ecosystem.seed", "unknown key (expected one of: establish, steps)"),
    }
    for extra, (field, words) in cases.items():
        with pytest.raises(ConfigError) as e:
            parse_config(MINIMAL + extra, path=Path("scene.toml"))
        assert e.value.field == field, (extra, str(e.value))
        assert str(e.value).startswith(f"scene.toml: {field}: ") and words in str(e.value), str(e.value)
    with pytest.raises(ConfigError, match=r"species\[0\]\.lifespan: unknown key"):
        parse_config(MINIMAL.replace("percent = 50", "percent = 50\nlifespan = 80"))


def test_hostile_structure_is_one_line(tmp_path):
    deep = "x = " + "[" * 2000 + "]" * 2000 + "\n"
    with pytest.raises(ConfigError, match="nested deeper"):
        parse_config(deep)
    big = MINIMAL + "# " + "x" * (1 << 20) + "\n"
    with pytest.raises(ConfigError, match="over 1024 KiB"):
        parse_config(big)
    p = tmp_path / "deep.toml"
    p.write_text(deep)
    r = run_forest("scatter", p, "-o", tmp_path / "t.npz")
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr


def test_file_fields_are_derived_from_the_schema():
    fields = set(file_fields())
    assert {"terrain.heightmap", "terrain.mesh", "maps.colour", "lights.sky.envmap", "lookdev.mask"} <= fields
    assert "render.width" not in fields and "species[].model" not in fields


def test_referenced_files_of_an_example(tmp_path):
    cfg = load_config(ROOT / "configs" / "demo.toml")
    names = sorted(p.name for p in referenced_files(cfg))
    assert names == ["colour.png", "demo_height.png", "density.png", "partition.png", "presence.png"]


def test_overrides_go_through_the_schema(tmp_path):
    data = tomllib.loads(MINIMAL)
    out = apply_overrides(data, {"render.spp": 4, "species[0].percent": 70.0, "lights.sun.irradiance": 2.0})
    assert data == tomllib.loads(MINIMAL)  # the input is not changed
    assert out["render"]["spp"] == 4 and out["species"][0]["percent"] == 70.0
    cfg = parse_config(MINIMAL).with_overrides({"render.spp": 4, "lights.sun.irradiance": 2.0})
    assert cfg.render.spp == 4 and cfg.lights.sun.irradiance == 2.0
    with pytest.raises(ConfigError, match=r"render\.spp: must be >= 1, got 0"):
        parse_config(MINIMAL).with_overrides({"render.spp": 0})
    with pytest.raises(Exception, match="species has no element 3"):
        apply_overrides(data, {"species[3].percent": 1.0})


def test_cli_reports_a_bad_flag_by_its_flag_not_the_file(tmp_path):
    cfg = tmp_path / "scene.toml"
    cfg.write_text(MINIMAL)
    out = tmp_path / "o.exr"
    r = run_forest("render", cfg, "-o", out, "--spp", "0")
    assert r.returncode == 2 and r.stderr.strip() == "forest: error: --spp: must be >= 1, got 0", r.stderr
    r = run_forest("scatter", cfg, "-o", tmp_path / "t.npz", "--count", "-5")
    assert r.returncode == 2 and r.stderr.strip() == "forest: error: --count: must be >= 0, got -5", r.stderr
    assert not out.exists() and not (tmp_path / "t.npz").exists()


def test_lookdev_arguments_name_their_parameter():
    from forest.lookdev import resolve_settings

    cfg = parse_config(MINIMAL + "[lookdev]\niterations = 30\nmode = 'statistics'\n")
    st = resolve_settings(cfg, spp=4)
    assert (st.iterations, st.spp, st.mode) == (30, 4, "statistics")
    assert "colour_map" not in st.params  # an unrelated photo cannot place the map's colours
    with pytest.raises(ParameterError) as e:
        resolve_settings(cfg, iterations=0)
    assert e.value.field == "lookdev.iterations" and "must be >= 1" in e.value.message


def test_partitions_and_species_regions(tmp_path):
    write_png(tmp_path / "p.png", [[[1, 0, 0]]])
    text = MINIMAL + '[maps]\npartition = "p.png"\n[partitions]\n"#ff0000" = "fg"\ntolerance = 10\n'
    cfg = parse_config(text, base_dir=tmp_path)
    assert [(p.colour, p.name) for p in cfg.partitions] == [((255, 0, 0), "fg")] and cfg.partition_tolerance == 10
    with pytest.raises(ConfigError, match=r"species\[0\]\.partitions: unknown region 'bg'"):
        parse_config(text.replace("percent = 50\n", 'percent = 50\npartitions = ["bg"]\n', 1), base_dir=tmp_path)
