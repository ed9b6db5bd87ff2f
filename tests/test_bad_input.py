"""A corpus of user mistakes: each gives exit 2, one clear line naming file and field, no output."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import run_forest, write_png

GOOD_SPECIES = """
[[species]]
model = "broadleaf"
percent = 60
[[species]]
model = "palm"
percent = 40
"""

CASES = {
    # name: (config text, extra files, expected fragments of the message)
    "invalid_toml": ("seed = = 1", {}, ["scene.toml", "invalid TOML"]),
    "unknown_top_key": (
        "colours = 1\n[terrain]\nflat = {}\n" + GOOD_SPECIES,
        {},
        ["scene.toml", "colours", "unknown key"],
    ),
    "unknown_section_key": (
        "[terrain]\nflat = {}\n[scatter]\ncuont = 5\n" + GOOD_SPECIES,
        {},
        ["scene.toml", "scatter.cuont", "unknown key"],
    ),
    "no_terrain": ("[scatter]\ncount = 5\n" + GOOD_SPECIES, {}, ["scene.toml", "terrain", "exactly one"]),
    "two_terrains": ("[terrain]\nflat = {}\nprocedural = {}\n" + GOOD_SPECIES, {}, ["terrain", "exactly one"]),
    "missing_heightmap": (
        '[terrain]\nheightmap = "nope.png"\n' + GOOD_SPECIES,
        {},
        ["scene.toml", "terrain.heightmap", "not found"],
    ),
    "corrupt_heightmap": (
        '[terrain]\nheightmap = "bad.png"\n' + GOOD_SPECIES,
        {"bad.png": b"\x89PNG garbage"},
        ["terrain.heightmap", "bad.png"],
    ),
    "empty_map": (
        '[terrain]\nflat = {}\n[maps]\ndensity = "d.png"\n' + GOOD_SPECIES,
        {"d.png": b""},
        ["maps.density", "d.png", "empty"],
    ),
    "percent_over_100": (
        "[terrain]\nflat = {}\n" + GOOD_SPECIES.replace("40", "50"),
        {},
        ["scene.toml", "species", "110", "more than 100"],
    ),
    "percent_negative": (
        "[terrain]\nflat = {}\n" + GOOD_SPECIES.replace("40", "-4"),
        {},
        ["species[1].percent", ">= 0"],
    ),
    "negative_size": (
        '[terrain]\nheightmap = "h.png"\nsize = [-10.0, 100.0]\n' + GOOD_SPECIES,
        {"h.png": "grey"},
        ["terrain.size", "> 0", "[-10, 100]"],
    ),
    "nan_height": (
        '[terrain]\nheightmap = "h.png"\nheight = nan\n' + GOOD_SPECIES,
        {"h.png": "grey"},
        ["terrain.height", "finite"],
    ),
    "nan_heightmap": (
        '[terrain]\nheightmap = "h.exr"\n' + GOOD_SPECIES,
        {"h.exr": "nan"},
        ["terrain.heightmap", "NaN"],
    ),
    "count_wrong_type": (
        '[terrain]\nflat = {}\n[scatter]\ncount = "many"\n' + GOOD_SPECIES,
        {},
        ["scatter.count", "whole number"],
    ),
    "count_negative": ("[terrain]\nflat = {}\n[scatter]\ncount = -5\n" + GOOD_SPECIES, {}, ["scatter.count", ">= 0"]),
    "species_without_model": (
        "[terrain]\nflat = {}\n[[species]]\npercent = 10\n",
        {},
        ["species[0].model", "required"],
    ),
    "no_species": ("[terrain]\nflat = {}\n", {}, ["species", "required"]),
    "scale_reversed": (
        "[terrain]\nflat = {}\n[[species]]\nmodel = 'a'\npercent = 5\nscale = [2.0, 1.0]\n",
        {},
        ["species[0].scale", "must not exceed"],
    ),
    "bad_partition_key": (
        '[terrain]\nflat = {}\n[maps]\npartition = "p.png"\n[partitions]\n"red" = "fg"\n' + GOOD_SPECIES,
        {"p.png": "grey"},
        ["partitions", "colours like"],
    ),
    "partition_map_without_labels": (
        '[terrain]\nflat = {}\n[maps]\npartition = "p.png"\n' + GOOD_SPECIES,
        {"p.png": "grey"},
        ["partitions", "no [partitions]"],
    ),
    "presence_all_black": (
        '[terrain]\nflat = {}\n[maps]\npresence = "p.png"\n' + GOOD_SPECIES,
        {"p.png": "black"},
        ["maps.presence", "allows no trees"],
    ),
    "mesh_with_nan": (
        '[terrain]\nmesh = "t.obj"\n' + GOOD_SPECIES,
        {"t.obj": "v 0 0 0\nv 1 0 0\nv nan 0 1\nf 1 2 3\n"},
        ["terrain.mesh", "NaN"],
    ),
    "placed_tree_of_no_species": (
        "[terrain]\nflat = {}\n" + GOOD_SPECIES + '[[tree]]\nspecies = "oak"\nposition = [0.0, 0.0]\n',
        {},
        ["tree[0].species", "no [[species]] is named 'oak'"],
    ),
    "placed_tree_off_the_terrain": (
        "[terrain]\nflat = { size = 100.0 }\n"
        + GOOD_SPECIES
        + '[[tree]]\nspecies = "broadleaf"\nposition = [80.0, 0.0]\n',
        {},
        ["tree[0].position", "outside the terrain"],
    ),
    "placed_tree_in_the_water": (
        "[terrain]\nflat = { size = 100.0 }\nwater = { level = 2.0 }\n"
        + GOOD_SPECIES
        + '[[tree]]\nspecies = "broadleaf"\nposition = [0.0, 0.0]\n',
        {},
        ["tree[0].position", "in [terrain] water"],
    ),
    "mesh_empty": ('[terrain]\nmesh = "t.obj"\n' + GOOD_SPECIES, {"t.obj": "# nothing\n"}, ["terrain.mesh", "t.obj"]),
}


def _materialise(tmp_path, files):
    for name, content in files.items():
        p = tmp_path / name
        if content == "grey":
            write_png(p, np.full((8, 8), 0.5))
        elif content == "black":
            write_png(p, np.zeros((8, 8)))
        elif content == "nan":
            import OpenImageIO as oiio

            a = np.full((4, 4, 1), np.nan, dtype=np.float32)
            out = oiio.ImageOutput.create(str(p))
            out.open(str(p), oiio.ImageSpec(4, 4, 1, oiio.FLOAT))
            out.write_image(a)
            out.close()
        elif isinstance(content, bytes):
            p.write_bytes(content)
        else:
            p.write_text(content)


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_config_is_one_clear_line(tmp_path, case):
    text, files, fragments = CASES[case]
    _materialise(tmp_path, files)
    cfg = tmp_path / "scene.toml"
    cfg.write_text(text)
    out = tmp_path / "out" / "trees.npz"
    r = run_forest("scatter", cfg, "-o", out)
    assert r.returncode == 2, (r.stdout, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert "Traceback" not in r.stderr
    for frag in fragments:
        assert frag in lines[0], (frag, lines[0])
    assert not out.exists()
    assert not list(tmp_path.rglob("*.npz")) and not list(tmp_path.rglob("*.tmp*"))


def test_missing_config_file(tmp_path):
    r = run_forest("scatter", tmp_path / "nope.toml", "-o", tmp_path / "t.npz")
    assert r.returncode == 2 and "nope.toml" in r.stderr and "not found" in r.stderr
    assert not (tmp_path / "t.npz").exists()


def test_wrong_output_extension(tmp_path, flat_scene):
    r = run_forest("scatter", flat_scene(), "-o", tmp_path / "t.csv")
    assert r.returncode == 2 and "t.csv" in r.stderr
    assert not (tmp_path / "t.csv").exists()


def test_failed_run_keeps_the_previous_output(tmp_path, flat_scene):
    out = tmp_path / "t.npz"
    assert run_forest("scatter", flat_scene(count=100), "-o", out).returncode == 0
    before = out.read_bytes()
    bad = tmp_path / "bad.toml"
    bad.write_text("[terrain]\nflat = {}\n[[species]]\nmodel='a'\npercent=101\n")
    assert run_forest("scatter", bad, "-o", out).returncode == 2
    assert out.read_bytes() == before


def test_help_everywhere():
    r = run_forest("--help")
    assert r.returncode == 0 and "scatter" in r.stdout
    r = run_forest("scatter", "--help")
    assert r.returncode == 0 and "--output" in r.stdout
