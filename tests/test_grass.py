"""The grass preset: blades green to the tip, varied blade cards, a sward-like colour, within the budgets."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest

from forest.errors import ConfigError
from forest.library.generator import grow, validate_recipe
from forest.library.textures import BLADES, leaf_rgba

ROOT = Path(__file__).resolve().parents[1]


def _recipe() -> dict:
    return tomllib.loads((ROOT / "library/presets/grass.toml").read_text())


def test_blade_card_holds_two_unlike_blades_green_to_the_tip():
    """Two blades of different length, width and lean; the detail is as green at the tip as mid-blade."""
    tex = leaf_rgba("blade")
    alpha = tex[..., 3]
    n = len(alpha)

    def runs(row: np.ndarray) -> int:
        inside = row >= 0.5
        return int(np.count_nonzero(inside[1:] & ~inside[:-1]) + inside[0])

    assert runs(alpha[n // 2]) == 2  # two blades mid-card, apart
    assert runs(alpha[int(0.9 * n)]) == 1  # only the longer blade reaches the tip
    assert (
        len({b["length"] for b in BLADES}) == len({b["width"] for b in BLADES}) == len({b["lean"] for b in BLADES}) == 2
    )
    assert 0.2 < alpha.mean() < 0.3  # as much blade per card as the three-blade card had (0.25)
    covered = alpha >= 0.5
    mid = tex[int(0.4 * n) : int(0.6 * n), :, :3][covered[int(0.4 * n) : int(0.6 * n)]].mean(axis=0)
    tip = tex[int(0.8 * n) :, :, :3][covered[int(0.8 * n) :]].mean(axis=0)
    np.testing.assert_allclose(tip, mid, rtol=0.03)
    assert tip[0] / tip[1] <= mid[0] / mid[1] * 1.01  # no yellowing towards the tip


def test_grass_colour_is_a_green_blade_within_the_sward():
    """leaf_colour is a green (not senescent) blade, R/G ≤ 0.56; its reflected share (1 − translucency)·colour
    lies in the red and green of the built-in grass sward's measured albedo ±60 % (GROUND_MATERIALS)."""
    from forest.config.schema import GROUND_MATERIALS

    tree = validate_recipe(_recipe())["tree"]
    leaf = np.array(tree["leaf_colour"])
    assert leaf[0] / leaf[1] <= 0.56 and leaf[2] / leaf[1] >= 0.1
    reflected = (1.0 - tree["translucency"]) * leaf
    sward = np.array(GROUND_MATERIALS["grass"])
    assert (reflected[:2] >= sward[:2]).all() and (reflected[:2] <= 1.6 * sward[:2]).all(), reflected


def test_blade_cards_vary_and_stay_deterministic():
    """leaf_mirror and leaf_scale_x_var: about half the cards mirrored, widths varied ±30 %, the same
    for the same seed; every card still a rectangle (ŵ ⟂ d̂)."""
    recipe = validate_recipe(_recipe())
    a, b = grow(recipe, 1), grow(recipe, 1)
    np.testing.assert_array_equal(a.leaf_width, b.leaf_width)
    np.testing.assert_array_equal(a.leaf_size, b.leaf_size)
    np.testing.assert_allclose(np.sum(a.leaf_width * a.leaf_dir, axis=1), 0.0, atol=1e-6)
    down = np.cross(a.leaf_width, a.leaf_dir)[:, 1] < 0
    assert 0.4 < down.mean() < 0.6
    aspect = a.leaf_size[:, 1] / a.leaf_size[:, 0] / recipe["tree"]["leaf_scale_x"]
    assert aspect.min() < 0.8 and aspect.max() > 1.2 and abs(aspect.mean() - 1.0) < 0.03
    # Without them, every card faces up and keeps the preset's aspect.
    plain = _recipe()
    plain["tree"].update(leaf_mirror=0.0, leaf_scale_x_var=0.0)
    c = grow(validate_recipe(plain), 1)
    assert (np.cross(c.leaf_width, c.leaf_dir)[:, 1] >= -1e-9).all()
    np.testing.assert_allclose(c.leaf_size[:, 1] / c.leaf_size[:, 0], plain["tree"]["leaf_scale_x"], rtol=1e-6)
    np.testing.assert_array_equal(c.leaf_dir, a.leaf_dir)  # the same blades, only widths and sides drawn anew


@pytest.mark.parametrize("key,value", [("leaf_mirror", 1.5), ("leaf_scale_x_var", -0.1)])
def test_new_keys_are_checked(key, value):
    recipe = _recipe()
    recipe["tree"][key] = value
    with pytest.raises(ConfigError, match=rf"tree\.{key}: must be a number in \[0, 0\.9\]"):
        validate_recipe(recipe, "grass.toml")


def test_grass_builds_within_budget_and_byte_identical(tmp_path):
    """High 50–70 k triangles (HIGH_MAX), medium 5–20 k, low 0.5–2 k; two builds are byte-identical."""
    from forest.library import lod as lodmod
    from forest.library.build import generate

    metas = [generate(_recipe(), 1, tmp_path / k, name="grass") for k in ("a", "b")]
    tris = {lv["name"]: sum(p["triangles"] for p in lv["parts"]) for lv in metas[0]["lods"]}
    assert 50_000 <= tris["high"] <= lodmod.HIGH_MAX and 5_000 <= tris["medium"] <= 20_000
    assert 500 <= tris["low"] <= 2_000
    for f in sorted((tmp_path / "a").iterdir()):
        assert f.read_bytes() == (tmp_path / "b" / f.name).read_bytes(), f.name
