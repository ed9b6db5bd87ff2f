"""TOML the product writes keeps the artist's document: the fitted scene.toml and the library manifest."""

from __future__ import annotations

import shutil
import tomllib
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from forest.config import load_config
from forest.images import write_image
from forest.library.core import Library, write_manifest_entry
from forest.lookdev.params import Start
from forest.lookdev.report import HEADER, fitted_data, write_toml

ROOT = Path(__file__).resolve().parents[1]

SCENE = """\
# my valley: keep this comment
name = "valley"
seed = 3  # the seed the client signed off

[terrain]
flat = { size = 100.0 }

[maps]
colour = "maps/colour.png"  # painted by hand

# --- lights -------------------------------------------------------------
[lights.sun]
elevation = 40.0
irradiance = 3.0  # W/m²
colour = [1.0, 0.95, 0.88]

[lights.sky]  # a flat sky
radiance = 0.35
colour = [0.6, 0.75, 1.0]

[[species]]
model = "broadleaf"  # the hero species
percent = 100

[render]
spp = 4  # fast previews
width = 64
height = 36
"""


def _start() -> Start:
    """A fit's start with a disc sun and a flat (tied) sky, as the renderer would report for SCENE."""
    return Start(
        sun_elevation=40.0,
        sun_azimuth=120.0,
        sun_on=True,
        sun_y=3.0,
        sun_kelvin=5600.0,
        sun_duv=0.0,
        sky_kind="constant",
        sky_rgb=np.array([0.21, 0.26, 0.35]),
        sky_power=1.1,
        sky_kelvin=9000.0,
        sky_duv=0.0,
        haze=0.0,
        haze_ratio=np.ones(3),
        terrain_colour=np.full(3, 0.2),
        leaf_colours=np.full((1, 3), 0.1),
        species=["broadleaf"],
        sky_tied=True,
    )


def test_fitted_scene_keeps_comments_and_order(tmp_path: Path) -> None:
    src = tmp_path / "in"
    (src / "maps").mkdir(parents=True)
    shutil.copy(ROOT / "configs" / "maps" / "colour.png", src / "maps" / "colour.png")
    (src / "scene.toml").write_text(SCENE, encoding="utf-8")
    config = load_config(src / "scene.toml")
    out = tmp_path / "out"
    out.mkdir()
    problem = SimpleNamespace(start=_start(), n_species=1, cells=None)
    look = {"exposure": 0.5, "light_level": 0.2, "ground_r": 0.1, "leaves_g": -0.2}
    data, _files = fitted_data(config, problem, look, out, fit_map=True)  # type: ignore[arg-type]
    path = write_toml(out / "scene.toml", data, config.path)
    text = path.read_text(encoding="utf-8")
    # The fitted values are there, exactly as the fit wrote them ...
    assert tomllib.loads(text) == data
    assert data["lights"]["sun"]["irradiance"] != 3.0 and data["maps"]["colour"] == "colour_map.exr"
    assert data["lookdev"]["ground_tint"] and data["lookdev"]["leaf_tint"]["broadleaf"]
    # ... and so is everything the artist wrote around them: comments (also after changed values), order.
    assert text.startswith(HEADER + "\n# my valley: keep this comment\n")
    for kept in (
        "seed = 3  # the seed the client signed off",
        "# --- lights ---",
        "[lights.sky]  # a flat sky",
        'model = "broadleaf"  # the hero species',
        "spp = 4  # fast previews",
        "  # W/m²",
        "  # painted by hand",
    ):
        assert kept in text, kept
    order = [text.index(s) for s in ("name =", "[maps]", "[lights.sun]", "[lights.sky]", "[[species]]", "[render]")]
    assert order == sorted(order)
    assert 'colour_normalise = "none"\n\n# --- lights' in text  # a new key joins its table, not the next one
    assert text.index("[render]") < text.index("[lookdev]")  # a new section goes after the artist's
    # The written scene validates, and writing it again gives the same bytes (header not repeated).
    write_image(out / "colour_map.exr", np.ones((4, 4, 3), np.float32), half=False)
    again = write_toml(out / "again.toml", data, path)
    assert load_config(again).lights.sun is not None and again.read_text(encoding="utf-8") == text
    assert text.count(HEADER) == 1


def test_fitted_scene_without_an_original(tmp_path: Path) -> None:
    data = {"seed": 1, "render": {"spp": 2}, "lights": {"sun": {"irradiance": 2.5}}}
    text = write_toml(tmp_path / "s.toml", data, None).read_text(encoding="utf-8")
    assert text.startswith(HEADER) and tomllib.loads(text) == data


def test_manifest_entry_with_backslash_and_quote_round_trips(tmp_path: Path) -> None:
    manifest = tmp_path / "manifest.toml"
    manifest.write_text('# my library\nversion = 1\n\n[species.oak]  # the old oak\nsource = "generated"\n')
    odd = 'C:\\trees\\"big" oak\\tree.obj'
    write_manifest_entry(manifest, "elm", {"source": "imported", "path": "imported/elm", "original": odd})
    write_manifest_entry(manifest, "oak", {"source": "imported", "path": "imported/oak", "original": "oak.obj"})
    text = manifest.read_text(encoding="utf-8")
    data = tomllib.loads(text)
    assert data["species"]["elm"]["original"] == odd
    assert data["species"]["oak"] == {"source": "imported", "path": "imported/oak", "original": "oak.obj"}
    assert text.startswith("# my library\n") and text.index("[species.oak]") < text.index("[species.elm]")
    assert Library(tmp_path).names() == ["elm", "oak"]


def test_manifest_created_when_missing(tmp_path: Path) -> None:
    manifest = tmp_path / "manifest.toml"
    write_manifest_entry(manifest, "a-b", {"source": "imported", "path": "imported/a-b"})
    assert tomllib.loads(manifest.read_text())["species"] == {"a-b": {"source": "imported", "path": "imported/a-b"}}
