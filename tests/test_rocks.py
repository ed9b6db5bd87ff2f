"""Procedural rocks as library species: budgets, closed meshes in the ground, sizes, determinism, a scene."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import numpy as np
import pytest
import trimesh
from conftest import write_scene

from forest.config.schema import GROUND_MATERIALS
from forest.errors import ConfigError
from forest.library import BUDGETS as TREE_BUDGETS
from forest.library import LODS, open_library
from forest.library import rocks as R

ROOT = Path(__file__).resolve().parents[1]


def preset() -> dict:
    return tomllib.loads((ROOT / "library/presets/rock.toml").read_text())


@pytest.fixture(scope="module")
def lib(tmp_path_factory):
    """A user library of its own over the shipped presets: only rocks are built into it."""
    return open_library(tmp_path_factory.mktemp("rocklib"))


def test_the_library_builds_the_rock_preset(lib):
    sp = lib.resolve("rock")
    assert sp.source == "generated" and [lod.name for lod in sp.lods] == list(LODS)
    meta = json.loads((sp.folder / "species.json").read_text())
    assert meta["kind"] == "rock" and meta["seed"] == 1
    previous = None
    for lod in sp.lods:
        lo, hi = R.BUDGETS[lod.name]
        assert lo <= lod.triangles <= hi, (lod.name, lod.triangles)
        if previous is not None:
            assert lod.triangles < previous
        previous = lod.triangles
        (part,) = lod.parts
        assert part.kind == "surface" and part.texture is None and not part.tinted and part.translucency == 0.0
        m = part.load()
        assert m.triangles == part.triangles and np.isfinite(m.vertices).all()
        np.testing.assert_allclose(part.bounds, m.bounds(), atol=1e-6)
    assert sp.lod("far").triangles <= TREE_BUDGETS["far"][1]  # within the library's far budget
    assert "rock" in lib.names() and lib.entry("rock")["description"]


@pytest.mark.parametrize("seed", range(6))
def test_closed_sitting_in_the_ground_and_sized_by_the_recipe(seed):
    """Every level is a closed, outward-wound surface; sink × height lies below y = 0, the rest above; the
    high level's size, flattening and footprint follow the recipe's ranges."""
    recipe = R.validate_recipe(preset())
    r = recipe["rock"]
    meshes, colour = R.build_meshes(recipe, seed)
    for lod in LODS:
        m = meshes[lod]
        tm = trimesh.Trimesh(m.vertices, m.faces, process=True)
        assert tm.is_watertight and tm.is_winding_consistent and tm.volume > 0, lod
        g = np.cross(*(m.vertices[m.faces[:, k]] - m.vertices[m.faces[:, 0]] for k in (1, 2)))
        assert (np.einsum("ij,ij->i", g, m.normals[m.faces].sum(axis=1)) >= 0).all()  # wound about the normals
        lo, hi = m.bounds()
        assert lo[1] < 0.0 < hi[1] and -lo[1] < 0.5 * (hi[1] - lo[1]), lod
        assert np.all(np.abs(0.5 * (lo + hi)[[0, 2]]) < 0.1 * (hi - lo)[[0, 2]])  # footprint around the origin
    lo, hi = meshes["high"].bounds()
    size, height = hi[0] - lo[0], hi[1] - lo[1]
    assert r["size"][0] - 1e-4 <= size <= r["size"][1] + 1e-4
    assert r["flatten"][0] - 1e-3 <= height / size <= r["flatten"][1] + 1e-3
    assert -lo[1] == pytest.approx(r["sink"] * height, rel=1e-3)
    assert size / r["elongation"][1] - 0.1 * size <= hi[2] - lo[2] <= size * 1.05
    # A colour of the recipe's list within ±value_var.
    assert any(np.all(np.abs(colour / np.asarray(c) - 1.0) <= r["value_var"] + 1e-9) for c in r["colours"])


def test_rock_colour_is_the_grounds_rock():
    """The preset's first colour is the ground's measured rock albedo; every colour is a plausible stone."""
    colours = np.asarray(preset()["rock"]["colours"])
    np.testing.assert_allclose(colours[0], GROUND_MATERIALS["rock"], atol=1e-6)
    lum = colours @ [0.2126, 0.7152, 0.0722]
    assert (lum >= 0.1).all() and (lum <= 0.3).all()


def test_generation_is_deterministic(tmp_path):
    recipe = preset()
    for name, seed in (("a", 3), ("b", 3), ("c", 4)):
        R.generate(recipe, seed, tmp_path / name, name="rock")
    files = sorted(p.name for p in (tmp_path / "a").iterdir())
    assert files == sorted([f"{lod}_rock.ply" for lod in LODS] + ["species.json"])
    for f in files:
        assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes(), f
    for lod in LODS:
        assert (tmp_path / "a" / f"{lod}_rock.ply").read_bytes() != (tmp_path / "c" / f"{lod}_rock.ply").read_bytes()


def test_seeds_make_different_rocks():
    recipe = R.validate_recipe(preset())
    sizes = [float(np.ptp(R.build_meshes(recipe, s)[0]["low"].vertices[:, 0])) for s in range(8)]
    assert np.ptp(sizes) > 0.2 * np.mean(sizes)


@pytest.mark.parametrize(
    "rock,field",
    [
        ({"colour": [0.2, 0.2, 0.2]}, "rock.colour"),
        ({"size": [1.0, 0.5]}, "rock.size"),
        ({"cuts": [1.5, 3]}, "rock.cuts"),
        ({"colours": [[0.2, 0.2]]}, "rock.colours"),
        ({"tinted": 1}, "rock.tinted"),
        ({"octaves": 2.5}, "rock.octaves"),
        ({"sink": 0.9}, "rock.sink"),
    ],
)
def test_bad_recipes_name_the_field(rock, field):
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        R.validate_recipe({"kind": "rock", "rock": rock}, "rock.toml")
    with pytest.raises(ConfigError, match=r"\[rock\] table"):
        R.validate_recipe({"kind": "rock"}, "rock.toml")


SCENE = """
seed = 2
[terrain]
flat = {{ size = 40.0 }}
[scatter]
count = 6
clumping = {{ strength = 0.0, clearings = 0.0 }}
emergents = {{ fraction = 0.0 }}
[[species]]
model = "rock"
percent = 100
scale = [2.0, 3.0]
[[ground_cover]]
model = "rock"
density = 0.8
max_distance = 12.0
presence = false
[camera]
position = [0.0, 2.0, -8.0]
target = [0.0, 0.0, 0.0]
fov = 50.0
[lights]
sun = {{ elevation = 35.0, azimuth = 150.0, irradiance = 3.0 }}
sky = {{ radiance = 0.3 }}
[render]
width = 24
height = 16
spp = 2
[lod]
distances = [6.0, 10.0, 14.0]
"""


def test_a_ground_cover_of_rocks_renders_in_both_variants(tmp_path, lib):
    """[[ground_cover]] model = "rock" scatters, resolves its individuals and renders like any species."""
    import OpenImageIO as oiio

    from forest.config import load_config
    from forest.render import render_scene
    from forest.scene import load_scene

    cfg = load_config(write_scene(tmp_path, SCENE.format()))
    scene = load_scene(cfg, library=lib)
    inst = scene.instances
    cover = inst.species == 1
    assert cover.sum() > 20 and len(scene.individuals[1]) > 1
    assert all(sp.name.startswith("rock") for ind in scene.individuals for sp in ind)
    for variant in ("llvm_ad_rgb", "scalar_rgb"):
        render_scene(scene, output=tmp_path / f"{variant}.exr", variant=variant)
        inp = oiio.ImageInput.open(str(tmp_path / f"{variant}.exr"))
        spec = inp.spec()
        img = np.asarray(inp.read_image(0, 0, 0, spec.nchannels, "float")).reshape(16, 24, -1)
        inp.close()
        ids = img[..., list(spec.channelnames).index("id.Z")]
        assert np.isfinite(img).all() and img[..., :3].mean() > 0
        assert (ids >= 0).mean() > 0.05, variant  # rocks in the picture
